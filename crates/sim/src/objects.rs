//! The values of a virtual device's object dictionary, as its SDO server
//! sees them (CiA 301 §7.2.4.3: which abort answers which request).
//!
//! A store starts from the dictionary's default values for its node id
//! (`$NODEID+0x180` resolved) and checks every access the way a device does:
//! existence (0x06020000, 0x06090011), access type (0x06010001, 0x06010002),
//! length (0x06070010/12/13) and range (0x06090030/31/32).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use crate::canopen::NodeId;
use crate::canopen::od::{
    AccessType, DataType, Object, ObjectDictionary, SubObject, Value, ValueError,
};
use crate::canopen::sdo::{AbortCode, ObjectAccess};

/// Why a dictionary cannot be made into a store.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("object 0x{index:04X} sub {sub} ({name}): default value: {error}")]
pub struct StoreError {
    pub index: u16,
    pub sub: u8,
    pub name: String,
    pub error: ValueError,
}

/// A dictionary with a current value for every sub-object.
#[derive(Debug, Clone)]
pub struct ObjectStore {
    node: NodeId,
    /// Shared by the devices of one product, and by a device's factory
    /// values and current values: only the values are each device's own.
    dictionary: Arc<ObjectDictionary>,
    values: BTreeMap<(u16, u8), Value>,
}

impl ObjectStore {
    /// Every sub-object at its default for `node`; a sub-object without a
    /// default starts at zero (an empty string for strings and domains).
    pub fn new(
        dictionary: impl Into<Arc<ObjectDictionary>>,
        node: NodeId,
    ) -> Result<Self, StoreError> {
        let dictionary = dictionary.into();
        let mut values = BTreeMap::new();
        for object in dictionary.objects.values() {
            for sub in object.subs.values() {
                let error = |error| StoreError {
                    index: object.index,
                    sub: sub.sub_index,
                    name: sub.name.clone(),
                    error,
                };
                let value = match sub.default_value(Some(node)).map_err(error)? {
                    Some(value) => value,
                    None => match zero(sub.data_type) {
                        Some(value) => value,
                        // A type with no encoding cannot be transferred; leave it out.
                        None => continue,
                    },
                };
                values.insert((object.index, sub.sub_index), value);
            }
        }
        Ok(Self {
            node,
            dictionary,
            values,
        })
    }

    pub fn node(&self) -> NodeId {
        self.node
    }

    pub fn dictionary(&self) -> &ObjectDictionary {
        &self.dictionary
    }

    /// The dictionary, shared (to build another store of it).
    pub fn shared_dictionary(&self) -> Arc<ObjectDictionary> {
        self.dictionary.clone()
    }

    /// The current value of `index`:`sub`.
    pub fn get(&self, index: u16, sub: u8) -> Option<&Value> {
        self.values.get(&(index, sub))
    }

    /// An integer (or BOOLEAN) value as one number; `None` for an object
    /// the dictionary lacks or that is no integer.
    pub fn int(&self, index: u16, sub: u8) -> Option<i64> {
        self.get(index, sub)
            .and_then(Value::as_i128)
            .map(|value| value as i64)
    }

    /// Sets a value from the device's side (no access check: a device
    /// updates its own read-only objects).
    pub fn set(&mut self, index: u16, sub: u8, value: Value) -> Result<(), AbortCode> {
        let entry = self.entry(index, sub)?;
        if value.data_type() != entry.data_type {
            return Err(AbortCode::LengthMismatch);
        }
        self.values.insert((index, sub), value);
        Ok(())
    }

    /// Sets an integer (or BOOLEAN) object from the device's side, clamped
    /// to its type's range; REAL objects take the number as it is. Returns
    /// false, changing nothing, for an object the dictionary lacks or of
    /// another type.
    pub fn set_int_saturating(&mut self, index: u16, sub: u8, value: i64) -> bool {
        let Ok(entry) = self.entry(index, sub) else {
            return false;
        };
        let data_type = entry.data_type;
        let value = match data_type {
            DataType::Real32 => Value::Real32(value as f32),
            DataType::Real64 => Value::Real64(value as f64),
            _ => {
                let Some((min, max)) = data_type.integer_range() else {
                    return false;
                };
                match Value::from_i128(data_type, i128::from(value).clamp(min, max)) {
                    Ok(value) => value,
                    Err(_) => return false,
                }
            }
        };
        self.values.insert((index, sub), value);
        true
    }

    /// Sets a REAL32/REAL64 object, or an integer one rounded and clamped.
    /// Returns false, changing nothing, for an object the dictionary lacks
    /// or that is no number.
    pub fn set_real(&mut self, index: u16, sub: u8, value: f64) -> bool {
        let Ok(entry) = self.entry(index, sub) else {
            return false;
        };
        match entry.data_type {
            DataType::Real32 => {
                self.values
                    .insert((index, sub), Value::Real32(value as f32));
                true
            }
            DataType::Real64 => {
                self.values.insert((index, sub), Value::Real64(value));
                true
            }
            // `as` saturates and maps NaN to 0, which is what a device's
            // conversion of a measurement does.
            _ => self.set_int_saturating(index, sub, value.round() as i64),
        }
    }

    fn entry(&self, index: u16, sub: u8) -> Result<&SubObject, AbortCode> {
        let object = self
            .dictionary
            .get(index)
            .ok_or(AbortCode::ObjectDoesNotExist)?;
        object.sub(sub).ok_or(AbortCode::SubIndexDoesNotExist)
    }

    fn writable_entry(&self, index: u16, sub: u8) -> Result<&SubObject, AbortCode> {
        let entry = self.entry(index, sub)?;
        if !entry.access.is_writable() {
            return Err(AbortCode::ReadOnlyObject);
        }
        Ok(entry)
    }
}

/// Bits 0–28 of a COB-ID: the CAN-ID (29 bits for an extended frame).
const CAN_ID_BITS: u32 = 0x1FFF_FFFF;

/// The COB-ID entries of CiA 301: SYNC 0x1005, TIME 0x1012, EMCY 0x1014,
/// the SDO channels' (0x1200–0x12FF sub 1 and 2) and the PDOs' (sub 1).
fn is_cob_id(index: u16, sub: u8) -> bool {
    matches!(
        (index, sub),
        (0x1005 | 0x1012 | 0x1014, 0)
            | (0x1200..=0x12FF, 1 | 2)
            | (0x1400..=0x15FF | 0x1800..=0x19FF, 1)
    )
}

/// The dummy objects an EDS's `[DummyUsage]` declares (CiA 306 §4.5.4):
/// the data types 0x0001–0x0007 a device accepts in an RPDO mapping, which
/// it also answers when read (CiA 301 §7.4.7.1): the type's length in bits,
/// an UNSIGNED32 const.
pub fn add_dummy_objects(dictionary: &mut ObjectDictionary, usage: &BTreeSet<u16>) {
    for &index in usage {
        let data_type = DataType::from_raw(index);
        let Some(bits) = data_type.bits() else {
            continue;
        };
        if dictionary.get(index).is_some() {
            continue;
        }
        let name = format!("Dummy{index:04X}");
        let mut sub = SubObject::new(0, name, DataType::Unsigned32, AccessType::Const);
        sub.default = Some(bits.to_string());
        dictionary.insert(Object::var(index, sub));
    }
}

fn zero(data_type: DataType) -> Option<Value> {
    Value::zero(data_type)
}

fn abort(error: &ValueError) -> AbortCode {
    AbortCode::from(error.sdo_abort_code())
}

impl ObjectAccess for ObjectStore {
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
        let entry = self.entry(index, sub)?;
        if !entry.access.is_readable() {
            return Err(AbortCode::WriteOnlyObject);
        }
        self.values
            .get(&(index, sub))
            .map(Value::to_bytes)
            .ok_or(AbortCode::NoDataAvailable)
    }

    fn check_write(&mut self, index: u16, sub: u8, size: Option<usize>) -> Result<(), AbortCode> {
        let entry = self.writable_entry(index, sub)?;
        match (size, entry.data_type.byte_len()) {
            (Some(size), Some(len)) if size > len => Err(AbortCode::LengthTooHigh),
            (Some(size), Some(len)) if size < len => Err(AbortCode::LengthTooLow),
            _ => Ok(()),
        }
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        let node = self.node;
        let entry = self.writable_entry(index, sub)?;
        let value = Value::from_bytes(entry.data_type, data).map_err(|e| abort(&e))?;
        // A COB-ID's limits are its CAN-ID's: its flags (valid, RTR,
        // frame format, generate) are no part of the number they bound.
        let limited = match value {
            Value::Unsigned32(cob_id) if is_cob_id(index, sub) => {
                Value::Unsigned32(cob_id & CAN_ID_BITS)
            }
            _ => value.clone(),
        };
        entry.check(&limited, Some(node)).map_err(|e| abort(&e))?;
        self.values.insert((index, sub), value);
        Ok(())
    }

    fn fixed_size(&mut self, index: u16, sub: u8) -> Option<usize> {
        self.entry(index, sub).ok()?.data_type.byte_len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::od::{AccessType, Object};

    fn store() -> ObjectStore {
        let mut dictionary = ObjectDictionary::new();
        let mut cob = SubObject::new(0, "COB-ID EMCY", DataType::Unsigned32, AccessType::Rw);
        cob.default = Some("$NODEID+0x80".into());
        dictionary.insert(Object::var(0x1014, cob));
        let mut limited = SubObject::new(0, "Limited", DataType::Integer16, AccessType::Rw);
        limited.low = Some("-100".into());
        limited.high = Some("100".into());
        limited.default = Some("5".into());
        dictionary.insert(Object::var(0x2000, limited));
        dictionary.insert(Object::var(
            0x2001,
            SubObject::new(0, "Fixed", DataType::Unsigned32, AccessType::Ro),
        ));
        dictionary.insert(Object::var(
            0x2002,
            SubObject::new(0, "Command", DataType::Unsigned8, AccessType::Wo),
        ));
        dictionary.insert(Object::var(
            0x2003,
            SubObject::new(0, "Name", DataType::VisibleString, AccessType::Rw),
        ));
        ObjectStore::new(dictionary, NodeId::new(5).unwrap()).unwrap()
    }

    #[test]
    fn defaults_are_resolved_for_the_node() {
        let mut store = store();
        assert_eq!(store.read(0x1014, 0), Ok(vec![0x85, 0, 0, 0]));
        assert_eq!(store.read(0x2000, 0), Ok(vec![5, 0]));
        assert_eq!(store.read(0x2003, 0), Ok(vec![]));
    }

    #[test]
    fn every_refusal_has_its_abort_code() {
        let mut store = store();
        assert_eq!(store.read(0x3000, 0), Err(AbortCode::ObjectDoesNotExist));
        assert_eq!(store.read(0x2000, 1), Err(AbortCode::SubIndexDoesNotExist));
        assert_eq!(store.read(0x2002, 0), Err(AbortCode::WriteOnlyObject));
        assert_eq!(
            store.write(0x2001, 0, &[1, 0, 0, 0]),
            Err(AbortCode::ReadOnlyObject)
        );
        assert_eq!(
            store.check_write(0x2001, 0, Some(4)),
            Err(AbortCode::ReadOnlyObject)
        );
        assert_eq!(
            store.check_write(0x2000, 0, Some(4)),
            Err(AbortCode::LengthTooHigh)
        );
        assert_eq!(
            store.check_write(0x2000, 0, Some(1)),
            Err(AbortCode::LengthTooLow)
        );
        assert_eq!(
            store.write(0x2000, 0, &[1, 0, 0]),
            Err(AbortCode::LengthTooHigh)
        );
        assert_eq!(store.write(0x2000, 0, &[1]), Err(AbortCode::LengthTooLow));
        assert_eq!(
            store.write(0x2000, 0, &101i16.to_le_bytes()),
            Err(AbortCode::ValueTooHigh)
        );
        assert_eq!(
            store.write(0x2000, 0, &(-101i16).to_le_bytes()),
            Err(AbortCode::ValueTooLow)
        );
        // Nothing refused was stored.
        assert_eq!(store.read(0x2000, 0), Ok(vec![5, 0]));
    }

    #[test]
    fn accepted_writes_are_read_back() {
        let mut store = store();
        store.write(0x2000, 0, &(-100i16).to_le_bytes()).unwrap();
        assert_eq!(store.read(0x2000, 0), Ok((-100i16).to_le_bytes().to_vec()));
        store.write(0x2002, 0, &[9]).unwrap();
        store
            .write(0x2003, 0, b"a name longer than four bytes")
            .unwrap();
        assert_eq!(
            store.read(0x2003, 0),
            Ok(b"a name longer than four bytes".to_vec())
        );
        assert_eq!(store.fixed_size(0x2000, 0), Some(2));
        assert_eq!(store.fixed_size(0x2003, 0), None);
    }

    #[test]
    fn the_device_updates_its_read_only_values() {
        let mut store = store();
        store.set(0x2001, 0, Value::Unsigned32(77)).unwrap();
        assert_eq!(store.read(0x2001, 0), Ok(vec![77, 0, 0, 0]));
        assert_eq!(
            store.set(0x2001, 0, Value::Unsigned8(1)),
            Err(AbortCode::LengthMismatch)
        );
    }
}
