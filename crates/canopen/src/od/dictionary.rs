//! The object dictionary of one device (CiA 301 §7.4): objects by 16-bit
//! index, each with sub-objects by 8-bit sub-index, as its EDS describes
//! them; lookups by number and by EDS name.

use std::collections::BTreeMap;

use serde_json::Value as Json;

use super::value::snippet;
use super::{AccessType, DataType, ObjectType, Value, ValueError};
use crate::NodeId;

/// One entry of the dictionary: what an EDS says about `index`/`sub`. A VAR
/// object has one sub-object, at sub-index 0, with the object's name.
///
/// `default`, `low`, `high` and `parameter_value` keep the text of the EDS
/// (`$NODEID+0x180`, `"quoted string"`), because a `$NODEID` value has no
/// meaning until a node id is known; the `*_value` methods resolve them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SubObject {
    pub sub_index: u8,
    pub name: String,
    pub data_type: DataType,
    pub access: AccessType,
    pub pdo_mappable: bool,
    /// `DefaultValue`: the value after a reset.
    pub default: Option<String>,
    /// `LowLimit`.
    pub low: Option<String>,
    /// `HighLimit`.
    pub high: Option<String>,
    /// `ParameterValue` (DCF only): the value configured for this device.
    pub parameter_value: Option<String>,
    /// `Denotation` (DCF only): a name given by the system integrator.
    pub denotation: Option<String>,
    /// `ObjFlags` (CiA 306 §4.6.3.2): bit 0 "refuse write on download", bit
    /// 1 "refuse read on scan", for configuration tools.
    pub obj_flags: Option<u32>,
}

/// An object: a VAR, an ARRAY or a RECORD (or one of the rarer codes) at one
/// index, with its sub-objects.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Object {
    pub index: u16,
    pub name: String,
    pub object_type: ObjectType,
    pub subs: BTreeMap<u8, SubObject>,
    pub obj_flags: Option<u32>,
}

/// The objects of one device, by index.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ObjectDictionary {
    pub objects: BTreeMap<u16, Object>,
}

/// A lookup that found nothing, or a reference that is no index or sub-index.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DictionaryError {
    #[error("object {} is not in the object dictionary", format_index(*.0))]
    UnknownObject(u16),
    #[error("object {} has no sub-index {sub}", format_index(*.index))]
    UnknownSubObject { index: u16, sub: u8 },
    #[error("no object is named '{0}'")]
    UnknownName(String),
    #[error("object {} has no sub-object named '{name}'", format_index(*.index))]
    UnknownSubName { index: u16, name: String },
    #[error("'{0}' is no object index: give 0x6041, 6041h, a decimal number or an EDS name")]
    InvalidIndex(String),
    #[error("'{0}' is no sub-index: give 0 to 255 or an EDS name")]
    InvalidSubIndex(String),
    #[error("{}sub{sub} is a {expected}, the value is a {got}", format_index(*.index))]
    WrongType {
        index: u16,
        sub: u8,
        expected: DataType,
        got: DataType,
    },
}

impl DictionaryError {
    /// True when the reference was well-formed but names nothing (404 rather
    /// than 400 for the API).
    pub fn is_not_found(&self) -> bool {
        matches!(
            self,
            DictionaryError::UnknownObject(_)
                | DictionaryError::UnknownSubObject { .. }
                | DictionaryError::UnknownName(_)
                | DictionaryError::UnknownSubName { .. }
        )
    }
}

/// An index as the API returns it: `0x6041`, four upper-case hex digits.
pub fn format_index(index: u16) -> String {
    format!("0x{index:04X}")
}

/// An index as requests write it: `0x6041`, `6041h`, or decimal. `None`
/// for anything else, which may still be an EDS name.
pub fn parse_index(text: &str) -> Option<u16> {
    let text = text.trim();
    if let Some(hex) = text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        return hex_u16(hex);
    }
    if let Some(hex) = text.strip_suffix('h').or_else(|| text.strip_suffix('H')) {
        return hex_u16(hex);
    }
    if !text.is_empty() && text.bytes().all(|b| b.is_ascii_digit()) {
        return text.parse().ok();
    }
    None
}

fn hex_u16(hex: &str) -> Option<u16> {
    // from_str_radix alone would take a sign.
    if hex.is_empty() || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    u16::from_str_radix(hex, 16).ok()
}

/// EDS names compare without case, and with space, `-` and `_` alike: the
/// API's `Vendor_ID` is the UIO1LED's `Vendor Id`, and `a1_Set_point` finds
/// `a1_Set-point`.
pub fn names_match(a: &str, b: &str) -> bool {
    fn folded(name: &str) -> impl Iterator<Item = char> + '_ {
        name.trim().chars().map(|c| match c {
            ' ' | '-' | '_' => '_',
            c => c.to_ascii_lowercase(),
        })
    }
    folded(a).eq(folded(b))
}

fn resolve(
    text: Option<&str>,
    data_type: DataType,
    node: Option<NodeId>,
) -> Result<Option<Value>, ValueError> {
    text.map(|text| Value::parse_text(data_type, text, node))
        .transpose()
}

impl SubObject {
    /// A plain entry: no default, no limits, not mappable.
    pub fn new(
        sub_index: u8,
        name: impl Into<String>,
        data_type: DataType,
        access: AccessType,
    ) -> Self {
        SubObject {
            sub_index,
            name: name.into(),
            data_type,
            access,
            pdo_mappable: false,
            default: None,
            low: None,
            high: None,
            parameter_value: None,
            denotation: None,
            obj_flags: None,
        }
    }

    /// The default value, `$NODEID` resolved with `node`.
    pub fn default_value(&self, node: Option<NodeId>) -> Result<Option<Value>, ValueError> {
        resolve(self.default.as_deref(), self.data_type, node)
    }

    pub fn low_value(&self, node: Option<NodeId>) -> Result<Option<Value>, ValueError> {
        resolve(self.low.as_deref(), self.data_type, node)
    }

    pub fn high_value(&self, node: Option<NodeId>) -> Result<Option<Value>, ValueError> {
        resolve(self.high.as_deref(), self.data_type, node)
    }

    /// The DCF `ParameterValue`, `$NODEID` resolved with `node`.
    pub fn parameter_value(&self, node: Option<NodeId>) -> Result<Option<Value>, ValueError> {
        resolve(self.parameter_value.as_deref(), self.data_type, node)
    }

    /// True when a default or a limit depends on the node id.
    pub fn uses_node_id(&self) -> bool {
        [&self.default, &self.low, &self.high, &self.parameter_value]
            .into_iter()
            .flatten()
            .any(|text| text.to_ascii_uppercase().contains("$NODEID"))
    }

    /// Checks that `value` is of this entry's type and within its limits.
    pub fn check(&self, value: &Value, node: Option<NodeId>) -> Result<(), ValueError> {
        if value.data_type() != self.data_type {
            return Err(ValueError::WrongType {
                expected: self.data_type,
                got: value.data_type(),
            });
        }
        value.check_limits(
            self.low_value(node)?.as_ref(),
            self.high_value(node)?.as_ref(),
        )
    }

    /// The value of a request's JSON for this entry, type- and range-checked.
    pub fn value_from_json(&self, json: &Json, node: Option<NodeId>) -> Result<Value, ValueError> {
        let value = Value::from_json(self.data_type, json)?;
        self.check(&value, node)?;
        Ok(value)
    }

    /// The value of text (command line, DCF) for this entry, type- and
    /// range-checked.
    pub fn value_from_text(&self, text: &str, node: Option<NodeId>) -> Result<Value, ValueError> {
        let value = Value::parse_text(self.data_type, text, node)?;
        self.check(&value, node)?;
        Ok(value)
    }

    /// The bytes of a transfer read as this entry's type.
    pub fn decode(&self, bytes: &[u8]) -> Result<Value, ValueError> {
        Value::from_bytes(self.data_type, bytes)
    }

    /// The API's description of the entry: `{"sub", "name", "data_type",
    /// "access", "pdo_mappable", "default", "low", "high"}`, with values as
    /// typed JSON when `node` resolves them, as the EDS text otherwise.
    pub fn to_json(&self, node: Option<NodeId>) -> Json {
        let value = |text: &Option<String>| match text {
            None => Json::Null,
            Some(text) => Value::parse_text(self.data_type, text, node)
                .map_or_else(|_| Json::String(text.clone()), |value| value.to_json()),
        };
        serde_json::json!({
            "sub": self.sub_index,
            "name": self.name,
            "data_type": self.data_type,
            "access": self.access,
            "pdo_mappable": self.pdo_mappable,
            "default": value(&self.default),
            "low": value(&self.low),
            "high": value(&self.high),
        })
    }
}

impl Object {
    /// An object with no sub-objects yet.
    pub fn new(index: u16, name: impl Into<String>, object_type: ObjectType) -> Self {
        Object {
            index,
            name: name.into(),
            object_type,
            subs: BTreeMap::new(),
            obj_flags: None,
        }
    }

    /// A VAR object holding `sub` at sub-index 0, named after it.
    pub fn var(index: u16, mut sub: SubObject) -> Self {
        sub.sub_index = 0;
        let mut object = Object::new(index, sub.name.clone(), ObjectType::Var);
        object.subs.insert(0, sub);
        object
    }

    /// Adds or replaces a sub-object.
    pub fn insert_sub(&mut self, sub: SubObject) -> Option<SubObject> {
        self.subs.insert(sub.sub_index, sub)
    }

    pub fn sub(&self, sub: u8) -> Option<&SubObject> {
        self.subs.get(&sub)
    }

    /// The sub-object with this EDS name (see [`names_match`]).
    pub fn sub_by_name(&self, name: &str) -> Option<&SubObject> {
        self.subs.values().find(|sub| names_match(&sub.name, name))
    }

    /// A sub-object by number (`1`, `0x01`) or EDS name (`Vendor_ID`).
    pub fn resolve_sub(&self, text: &str) -> Result<&SubObject, DictionaryError> {
        let trimmed = text.trim();
        let number = match trimmed
            .strip_prefix("0x")
            .or_else(|| trimmed.strip_prefix("0X"))
        {
            Some(hex) if !hex.is_empty() && hex.bytes().all(|b| b.is_ascii_hexdigit()) => {
                Some(u8::from_str_radix(hex, 16))
            }
            _ if !trimmed.is_empty() && trimmed.bytes().all(|b| b.is_ascii_digit()) => {
                Some(trimmed.parse::<u8>())
            }
            _ => None,
        };
        match number {
            Some(Ok(sub)) => self.sub(sub).ok_or(DictionaryError::UnknownSubObject {
                index: self.index,
                sub,
            }),
            Some(Err(_)) => Err(DictionaryError::InvalidSubIndex(snippet(text))),
            None if trimmed.is_empty() => Err(DictionaryError::InvalidSubIndex(snippet(text))),
            None => self
                .sub_by_name(trimmed)
                .ok_or_else(|| DictionaryError::UnknownSubName {
                    index: self.index,
                    name: snippet(trimmed),
                }),
        }
    }

    /// A sub-object from a request's JSON: an integer or a string.
    pub fn resolve_sub_json(&self, json: &Json) -> Result<&SubObject, DictionaryError> {
        match json {
            Json::Number(n) => {
                let sub = n
                    .as_u64()
                    .and_then(|n| u8::try_from(n).ok())
                    .ok_or_else(|| DictionaryError::InvalidSubIndex(n.to_string()))?;
                self.sub(sub).ok_or(DictionaryError::UnknownSubObject {
                    index: self.index,
                    sub,
                })
            }
            Json::String(text) => self.resolve_sub(text),
            other => Err(DictionaryError::InvalidSubIndex(snippet(
                &other.to_string(),
            ))),
        }
    }

    /// The API's description: `{"index", "name", "object_type", "subs"}`.
    pub fn to_json(&self, node: Option<NodeId>) -> Json {
        serde_json::json!({
            "index": format_index(self.index),
            "name": self.name,
            "object_type": self.object_type,
            "subs": self.subs.values().map(|sub| sub.to_json(node)).collect::<Vec<_>>(),
        })
    }
}

impl ObjectDictionary {
    pub fn new() -> Self {
        ObjectDictionary::default()
    }

    /// Adds or replaces the object at its index.
    pub fn insert(&mut self, object: Object) -> Option<Object> {
        self.objects.insert(object.index, object)
    }

    pub fn get(&self, index: u16) -> Option<&Object> {
        self.objects.get(&index)
    }

    pub fn get_mut(&mut self, index: u16) -> Option<&mut Object> {
        self.objects.get_mut(&index)
    }

    pub fn sub(&self, index: u16, sub: u8) -> Option<&SubObject> {
        self.get(index)?.sub(sub)
    }

    pub fn sub_mut(&mut self, index: u16, sub: u8) -> Option<&mut SubObject> {
        self.get_mut(index)?.subs.get_mut(&sub)
    }

    /// The object with this EDS name (see [`names_match`]); the lowest index
    /// wins if a careless EDS repeats a name.
    pub fn find(&self, name: &str) -> Option<&Object> {
        self.objects
            .values()
            .find(|object| names_match(&object.name, name))
    }

    /// An object by `0x6041`, `6041h`, decimal or EDS name.
    pub fn resolve_index(&self, text: &str) -> Result<&Object, DictionaryError> {
        if let Some(index) = parse_index(text) {
            return self.get(index).ok_or(DictionaryError::UnknownObject(index));
        }
        let trimmed = text.trim();
        let looks_numeric = trimmed.starts_with(|c: char| c.is_ascii_digit());
        if trimmed.is_empty() || (looks_numeric && self.find(trimmed).is_none()) {
            return Err(DictionaryError::InvalidIndex(snippet(text)));
        }
        self.find(trimmed)
            .ok_or_else(|| DictionaryError::UnknownName(snippet(trimmed)))
    }

    /// An object from a request's JSON: an integer or a string.
    pub fn resolve_index_json(&self, json: &Json) -> Result<&Object, DictionaryError> {
        match json {
            Json::Number(n) => {
                let index = n
                    .as_u64()
                    .and_then(|n| u16::try_from(n).ok())
                    .ok_or_else(|| DictionaryError::InvalidIndex(n.to_string()))?;
                self.get(index).ok_or(DictionaryError::UnknownObject(index))
            }
            Json::String(text) => self.resolve_index(text),
            other => Err(DictionaryError::InvalidIndex(snippet(&other.to_string()))),
        }
    }

    /// A sub-object from a request's `[index, sub]` pair, as the REST API writes
    /// them (`["0x6041", 0]`, `["a1_Motor_status", "Current"]`).
    pub fn resolve_json(
        &self,
        index: &Json,
        sub: &Json,
    ) -> Result<(&Object, &SubObject), DictionaryError> {
        let object = self.resolve_index_json(index)?;
        Ok((object, object.resolve_sub_json(sub)?))
    }

    pub fn len(&self) -> usize {
        self.objects.len()
    }

    pub fn is_empty(&self) -> bool {
        self.objects.is_empty()
    }

    pub fn iter(&self) -> impl Iterator<Item = &Object> {
        self.objects.values()
    }

    /// Every sub-object of every object, in index order.
    pub fn subs(&self) -> impl Iterator<Item = (&Object, &SubObject)> {
        self.objects
            .values()
            .flat_map(|object| object.subs.values().map(move |sub| (object, sub)))
    }

    /// Sets the DCF `ParameterValue` of an entry to `value`.
    pub fn set_parameter_value(
        &mut self,
        index: u16,
        sub: u8,
        value: &Value,
    ) -> Result<(), DictionaryError> {
        if self.get(index).is_none() {
            return Err(DictionaryError::UnknownObject(index));
        }
        let entry = self
            .sub_mut(index, sub)
            .ok_or(DictionaryError::UnknownSubObject { index, sub })?;
        if entry.data_type != value.data_type() {
            return Err(DictionaryError::WrongType {
                index,
                sub,
                expected: entry.data_type,
                got: value.data_type(),
            });
        }
        entry.parameter_value = Some(value.to_text());
        Ok(())
    }

    /// The API's listing of the dictionary (`GET .../od`).
    pub fn to_json(&self, node: Option<NodeId>) -> Json {
        Json::Array(self.iter().map(|object| object.to_json(node)).collect())
    }
}

#[cfg(test)]
mod tests;
