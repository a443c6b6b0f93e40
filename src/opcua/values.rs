//! CANopen values as OPC UA values, sans I/O: each CiA 301 data type as
//! the built-in type that holds it (Part 6 §5.1.2), and a client's value
//! back as the entry's type, checked by the EDS as a REST write is.

use opcua::types::{ByteString, DataTypeId, Variant};
use serde_json::Value as Json;

use crate::canopen::od::{AccessType, DataType, Value};
use opcua::server::address_space::AccessLevel;

/// The built-in type a CiA 301 type is read as. The odd integer widths get
/// the next wider type; times of day are their bytes.
pub fn data_type_id(data_type: DataType) -> DataTypeId {
    match data_type {
        DataType::Boolean => DataTypeId::Boolean,
        DataType::Integer8 => DataTypeId::SByte,
        DataType::Integer16 => DataTypeId::Int16,
        DataType::Integer24 | DataType::Integer32 => DataTypeId::Int32,
        DataType::Integer40 | DataType::Integer48 | DataType::Integer56 | DataType::Integer64 => {
            DataTypeId::Int64
        }
        DataType::Unsigned8 => DataTypeId::Byte,
        DataType::Unsigned16 => DataTypeId::UInt16,
        DataType::Unsigned24 | DataType::Unsigned32 => DataTypeId::UInt32,
        DataType::Unsigned40
        | DataType::Unsigned48
        | DataType::Unsigned56
        | DataType::Unsigned64 => DataTypeId::UInt64,
        DataType::Real32 => DataTypeId::Float,
        DataType::Real64 => DataTypeId::Double,
        DataType::VisibleString | DataType::UnicodeString => DataTypeId::String,
        _ => DataTypeId::ByteString,
    }
}

/// A value read from the device, as [`data_type_id`] types it.
pub fn variant_of(value: &Value) -> Variant {
    match value {
        Value::Boolean(v) => Variant::Boolean(*v),
        Value::Integer8(v) => Variant::SByte(*v),
        Value::Integer16(v) => Variant::Int16(*v),
        Value::Integer24(v) | Value::Integer32(v) => Variant::Int32(*v),
        Value::Integer40(v) | Value::Integer48(v) | Value::Integer56(v) | Value::Integer64(v) => {
            Variant::Int64(*v)
        }
        Value::Unsigned8(v) => Variant::Byte(*v),
        Value::Unsigned16(v) => Variant::UInt16(*v),
        Value::Unsigned24(v) | Value::Unsigned32(v) => Variant::UInt32(*v),
        Value::Unsigned40(v)
        | Value::Unsigned48(v)
        | Value::Unsigned56(v)
        | Value::Unsigned64(v) => Variant::UInt64(*v),
        Value::Real32(v) => Variant::Float(*v),
        Value::Real64(v) => Variant::Double(*v),
        Value::VisibleString(v) | Value::UnicodeString(v) => Variant::String(v.as_str().into()),
        other => Variant::ByteString(ByteString::from(other.to_bytes())),
    }
}

/// A client's value as the JSON REST takes for an entry (numbers,
/// booleans, strings; bytes as hex, as REST's `raw`), for
/// `SubObject::value_from_json` to type and range-check; `None` for a
/// value of no such kind (an array, a structure).
pub fn json_of(variant: &Variant) -> Option<Json> {
    Some(match variant {
        Variant::Boolean(v) => Json::Bool(*v),
        Variant::SByte(v) => (*v).into(),
        Variant::Byte(v) => (*v).into(),
        Variant::Int16(v) => (*v).into(),
        Variant::UInt16(v) => (*v).into(),
        Variant::Int32(v) => (*v).into(),
        Variant::UInt32(v) => (*v).into(),
        Variant::Int64(v) => (*v).into(),
        Variant::UInt64(v) => (*v).into(),
        Variant::Float(v) => serde_json::Number::from_f64(f64::from(*v))?.into(),
        Variant::Double(v) => serde_json::Number::from_f64(*v)?.into(),
        Variant::String(v) => Json::String(v.as_ref().to_string()),
        Variant::ByteString(v) => Json::String(
            v.value
                .as_deref()
                .unwrap_or_default()
                .iter()
                .map(|byte| format!("{byte:02x}"))
                .collect(),
        ),
        _ => return None,
    })
}

/// The access level of an entry, from its EDS access type.
pub fn access_level(access: AccessType) -> AccessLevel {
    let mut level = AccessLevel::empty();
    if access.is_readable() {
        level |= AccessLevel::CURRENT_READ;
    }
    if access.is_writable() {
        level |= AccessLevel::CURRENT_WRITE;
    }
    level
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_value_is_read_as_its_built_in_type() {
        let cases = [
            (Value::Unsigned16(1000), DataType::Unsigned16),
            (Value::Integer32(-5), DataType::Integer32),
            (Value::Unsigned8(7), DataType::Unsigned8),
            (Value::Real32(1.5), DataType::Real32),
            (Value::Boolean(true), DataType::Boolean),
            (Value::VisibleString("UMC".into()), DataType::VisibleString),
            (Value::Unsigned24(70000), DataType::Unsigned24),
        ];
        for (value, data_type) in cases {
            let variant = variant_of(&value);
            let type_id = variant.data_type().map(|id| id.node_id);
            assert_eq!(
                type_id,
                Some(data_type_id(data_type).into()),
                "{value:?} as {variant:?}"
            );
        }
    }

    #[test]
    fn a_clients_value_goes_to_the_entry_as_json() {
        assert_eq!(json_of(&Variant::UInt16(1000)), Some(Json::from(1000)));
        assert_eq!(json_of(&Variant::Int32(-3)), Some(Json::from(-3)));
        assert_eq!(json_of(&Variant::Boolean(true)), Some(Json::Bool(true)));
        assert_eq!(
            json_of(&Variant::String("abc".into())),
            Some(Json::String("abc".into()))
        );
        assert_eq!(json_of(&Variant::Double(f64::NAN)), None);
        assert_eq!(json_of(&Variant::Empty), None);
        // Through the entry: typed and range-checked as REST's body.
        let value = Value::from_json(
            DataType::Unsigned16,
            &json_of(&Variant::UInt32(1000)).unwrap(),
        );
        assert_eq!(value.unwrap(), Value::Unsigned16(1000));
        let refused =
            Value::from_json(DataType::Unsigned8, &json_of(&Variant::Int32(300)).unwrap());
        assert!(refused.is_err());
    }

    #[test]
    fn the_eds_access_type_gives_the_access_level() {
        let bits = |access| access_level(access).bits();
        assert_eq!(bits(AccessType::Ro), AccessLevel::CURRENT_READ.bits());
        assert_eq!(
            bits(AccessType::Rw),
            (AccessLevel::CURRENT_READ | AccessLevel::CURRENT_WRITE).bits()
        );
        assert_eq!(bits(AccessType::Wo), AccessLevel::CURRENT_WRITE.bits());
    }
}
