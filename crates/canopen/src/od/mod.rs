//! The object dictionary (CiA 301 §7.4): the data types of §7.1 and their
//! encodings, the access types and object codes, and the dictionary of a
//! device as its EDS (CiA 306, see [`super::eds`]) describes it.
//!
//! # Layout
//!
//! - [`DataType`], [`AccessType`], [`ObjectType`]: the attributes of an entry,
//!   with their wire values and their EDS and API spellings.
//! - [`Value`]: a typed value, to and from the bytes of a transfer, the text
//!   of an EDS/DCF (with `$NODEID`) and the JSON of the REST API; range
//!   checks. Every [`ValueError`] knows its SDO abort code.
//! - [`ObjectDictionary`], [`Object`], [`SubObject`]: the entries of one
//!   device, looked up by index and sub-index or by EDS name.

mod dictionary;
mod types;
mod value;

pub use dictionary::{
    DictionaryError, Object, ObjectDictionary, SubObject, format_index, names_match, parse_index,
};
pub use types::{AccessType, DataType, ObjectType, UnknownAccessType, UnknownDataType};
pub(crate) use value::snippet;
pub use value::{TimeOfDay, Value, ValueError};
