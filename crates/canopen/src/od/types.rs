//! The attributes of an object dictionary entry (CiA 301 §7.4): data type,
//! access type and object code.

use std::fmt;
use std::str::FromStr;

/// A CiA 301 data type (§7.1), named by the index of its definition in
/// the object dictionary (§7.4). That index is the wire value: it is
/// what an EDS `DataType=` line carries and what a PDO dummy mapping entry
/// points at. The doc of each variant gives it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum DataType {
    /// 0x0001 BOOLEAN.
    Boolean,
    /// 0x0002 INTEGER8.
    Integer8,
    /// 0x0003 INTEGER16.
    Integer16,
    /// 0x0004 INTEGER32.
    Integer32,
    /// 0x0005 UNSIGNED8.
    Unsigned8,
    /// 0x0006 UNSIGNED16.
    Unsigned16,
    /// 0x0007 UNSIGNED32.
    Unsigned32,
    /// 0x0008 REAL32 (IEEE 754 single precision).
    Real32,
    /// 0x0009 VISIBLE_STRING.
    VisibleString,
    /// 0x000A OCTET_STRING.
    OctetString,
    /// 0x000B UNICODE_STRING (UTF-16, little-endian code units).
    UnicodeString,
    /// 0x000C TIME_OF_DAY.
    TimeOfDay,
    /// 0x000D TIME_DIFFERENCE.
    TimeDifference,
    /// 0x000F DOMAIN.
    Domain,
    /// 0x0010 INTEGER24.
    Integer24,
    /// 0x0011 REAL64 (IEEE 754 double precision).
    Real64,
    /// 0x0012 INTEGER40.
    Integer40,
    /// 0x0013 INTEGER48.
    Integer48,
    /// 0x0014 INTEGER56.
    Integer56,
    /// 0x0015 INTEGER64.
    Integer64,
    /// 0x0016 UNSIGNED24.
    Unsigned24,
    /// 0x0018 UNSIGNED40.
    Unsigned40,
    /// 0x0019 UNSIGNED48.
    Unsigned48,
    /// 0x001A UNSIGNED56.
    Unsigned56,
    /// 0x001B UNSIGNED64.
    Unsigned64,
    /// Any other index: a complex type (0x0020 PDO_COMMUNICATION_PARAMETER, ...),
    /// a manufacturer-defined type, or nothing at all.
    Unknown(u16),
}

/// One row of the type table: everything that is constant about a type.
struct TypeInfo {
    data_type: DataType,
    raw: u16,
    cia_name: &'static str,
    short_name: &'static str,
    /// `None` for the types whose length is only known from the transfer.
    bits: Option<u32>,
    signed: bool,
}

const fn row(
    data_type: DataType,
    raw: u16,
    cia_name: &'static str,
    short_name: &'static str,
    bits: Option<u32>,
    signed: bool,
) -> TypeInfo {
    TypeInfo {
        data_type,
        raw,
        cia_name,
        short_name,
        bits,
        signed,
    }
}

/// The basic types of CiA 301, as the UniSwarm manual's
/// table 3.8 lists them. TIME_OF_DAY and TIME_DIFFERENCE are 48 bits in
/// CiA 301 §7.1 (28 bits of milliseconds, 4 reserved, 16 bits of days);
/// the manual's "Variable" for them is a slip.
const TYPES: [TypeInfo; 25] = [
    row(DataType::Boolean, 0x0001, "BOOLEAN", "bool", Some(1), false),
    row(DataType::Integer8, 0x0002, "INTEGER8", "i8", Some(8), true),
    row(
        DataType::Integer16,
        0x0003,
        "INTEGER16",
        "i16",
        Some(16),
        true,
    ),
    row(
        DataType::Integer32,
        0x0004,
        "INTEGER32",
        "i32",
        Some(32),
        true,
    ),
    row(
        DataType::Unsigned8,
        0x0005,
        "UNSIGNED8",
        "u8",
        Some(8),
        false,
    ),
    row(
        DataType::Unsigned16,
        0x0006,
        "UNSIGNED16",
        "u16",
        Some(16),
        false,
    ),
    row(
        DataType::Unsigned32,
        0x0007,
        "UNSIGNED32",
        "u32",
        Some(32),
        false,
    ),
    row(DataType::Real32, 0x0008, "REAL32", "r32", Some(32), true),
    row(
        DataType::VisibleString,
        0x0009,
        "VISIBLE_STRING",
        "vs",
        None,
        false,
    ),
    row(
        DataType::OctetString,
        0x000A,
        "OCTET_STRING",
        "os",
        None,
        false,
    ),
    row(
        DataType::UnicodeString,
        0x000B,
        "UNICODE_STRING",
        "us",
        None,
        false,
    ),
    row(
        DataType::TimeOfDay,
        0x000C,
        "TIME_OF_DAY",
        "tod",
        Some(48),
        false,
    ),
    row(
        DataType::TimeDifference,
        0x000D,
        "TIME_DIFFERENCE",
        "td",
        Some(48),
        false,
    ),
    row(DataType::Domain, 0x000F, "DOMAIN", "d", None, false),
    row(
        DataType::Integer24,
        0x0010,
        "INTEGER24",
        "i24",
        Some(24),
        true,
    ),
    row(DataType::Real64, 0x0011, "REAL64", "r64", Some(64), true),
    row(
        DataType::Integer40,
        0x0012,
        "INTEGER40",
        "i40",
        Some(40),
        true,
    ),
    row(
        DataType::Integer48,
        0x0013,
        "INTEGER48",
        "i48",
        Some(48),
        true,
    ),
    row(
        DataType::Integer56,
        0x0014,
        "INTEGER56",
        "i56",
        Some(56),
        true,
    ),
    row(
        DataType::Integer64,
        0x0015,
        "INTEGER64",
        "i64",
        Some(64),
        true,
    ),
    row(
        DataType::Unsigned24,
        0x0016,
        "UNSIGNED24",
        "u24",
        Some(24),
        false,
    ),
    row(
        DataType::Unsigned40,
        0x0018,
        "UNSIGNED40",
        "u40",
        Some(40),
        false,
    ),
    row(
        DataType::Unsigned48,
        0x0019,
        "UNSIGNED48",
        "u48",
        Some(48),
        false,
    ),
    row(
        DataType::Unsigned56,
        0x001A,
        "UNSIGNED56",
        "u56",
        Some(56),
        false,
    ),
    row(
        DataType::Unsigned64,
        0x001B,
        "UNSIGNED64",
        "u64",
        Some(64),
        false,
    ),
];

impl DataType {
    /// Every known type, in order of wire value.
    pub const ALL: [DataType; 25] = {
        let mut all = [DataType::Boolean; 25];
        let mut i = 0;
        while i < TYPES.len() {
            all[i] = TYPES[i].data_type;
            i += 1;
        }
        all
    };

    fn info(self) -> Option<&'static TypeInfo> {
        TYPES.iter().find(|info| info.data_type == self)
    }

    pub fn from_raw(raw: u16) -> Self {
        TYPES
            .iter()
            .find(|info| info.raw == raw)
            .map_or(DataType::Unknown(raw), |info| info.data_type)
    }

    pub fn raw(self) -> u16 {
        match self {
            DataType::Unknown(raw) => raw,
            known => known.info().map_or(0, |info| info.raw),
        }
    }

    pub fn is_known(self) -> bool {
        !matches!(self, DataType::Unknown(_))
    }

    /// The name CiA 301 gives it (`UNSIGNED32`); `None` when unknown.
    pub fn cia_name(self) -> Option<&'static str> {
        self.info().map(|info| info.cia_name)
    }

    /// The short name of the REST API (`u32`, `vs`, `os`, ...); `None` when
    /// unknown.
    pub fn short_name(self) -> Option<&'static str> {
        self.info().map(|info| info.short_name)
    }

    /// The size in bits for fixed-size types (BOOLEAN is 1 bit when mapped
    /// into a PDO); `None` for strings, domains and unknown types.
    pub fn bits(self) -> Option<u32> {
        self.info().and_then(|info| info.bits)
    }

    /// The number of bytes a value takes in an SDO transfer, for fixed-size
    /// types (BOOLEAN takes a whole byte there).
    pub fn byte_len(self) -> Option<usize> {
        self.bits().map(|bits| bits.div_ceil(8) as usize)
    }

    pub fn is_variable_size(self) -> bool {
        self.is_known() && self.bits().is_none()
    }

    /// True for the signed integers and the reals.
    pub fn is_signed(self) -> bool {
        self.info().is_some_and(|info| info.signed)
    }

    /// True for BOOLEAN and the signed and unsigned integers of 8 to 64 bits.
    pub fn is_integer(self) -> bool {
        self.integer_range().is_some()
    }

    pub fn is_real(self) -> bool {
        matches!(self, DataType::Real32 | DataType::Real64)
    }

    /// The smallest and largest value of an integer type (BOOLEAN is 0 to 1).
    pub fn integer_range(self) -> Option<(i128, i128)> {
        if matches!(self, DataType::Boolean) {
            return Some((0, 1));
        }
        if self.is_real() || matches!(self, DataType::TimeOfDay | DataType::TimeDifference) {
            return None;
        }
        let bits = self.bits()?;
        Some(if self.is_signed() {
            (-(1i128 << (bits - 1)), (1i128 << (bits - 1)) - 1)
        } else {
            (0, (1i128 << bits) - 1)
        })
    }
}

impl fmt::Display for DataType {
    /// The CiA 301 name, or the index in hex when unknown.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.cia_name() {
            Some(name) => f.write_str(name),
            None => write!(f, "0x{:04X}", self.raw()),
        }
    }
}

/// A type name that is none of the forms [`DataType::from_str`] reads.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("'{0}' is not a data type (u8, i16, u32, r32, vs, os, us, d, ... or UNSIGNED32 or 0x0007)")]
pub struct UnknownDataType(pub String);

impl FromStr for DataType {
    type Err = UnknownDataType;

    /// The short name (`u32`), the CiA 301 name in any case with `_` or a
    /// space (`UNSIGNED32`, `visible string`), or the index (`0x0007`, `7`).
    /// An index that names no basic type gives [`DataType::Unknown`].
    fn from_str(text: &str) -> Result<Self, UnknownDataType> {
        let trimmed = text.trim();
        let by_name = TYPES.iter().find(|info| {
            info.short_name.eq_ignore_ascii_case(trimmed)
                || info
                    .cia_name
                    .eq_ignore_ascii_case(&trimmed.replace(' ', "_"))
        });
        if let Some(info) = by_name {
            return Ok(info.data_type);
        }
        let raw = match trimmed
            .strip_prefix("0x")
            .or_else(|| trimmed.strip_prefix("0X"))
        {
            Some(hex) => u16::from_str_radix(hex, 16).ok(),
            None => trimmed.parse::<u16>().ok(),
        };
        raw.map(DataType::from_raw)
            .ok_or_else(|| UnknownDataType(text.to_string()))
    }
}

/// In JSON a type is its short name (`"u32"`), or `"0x0020"` when unknown.
impl serde::Serialize for DataType {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self.short_name() {
            Some(name) => serializer.serialize_str(name),
            None => serializer.serialize_str(&format!("0x{:04X}", self.raw())),
        }
    }
}

impl<'de> serde::Deserialize<'de> for DataType {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = String::deserialize(deserializer)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// Who may read and write an entry (CiA 306 §4.6.3.2 `AccessType`, CiA 301
/// §7.4). `rwr` and `rww` are read-write entries meant for TPDOs and
/// RPDOs respectively.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AccessType {
    /// `ro`: read only.
    Ro,
    /// `wo`: write only.
    Wo,
    /// `rw`: read and write.
    Rw,
    /// `rwr`: read and write, mapped into TPDOs (the device changes it).
    Rwr,
    /// `rww`: read and write, mapped into RPDOs (the master changes it).
    Rww,
    /// `const`: read only, never changes.
    Const,
}

impl AccessType {
    /// The spelling of CiA 306, lower case.
    pub fn as_str(self) -> &'static str {
        match self {
            AccessType::Ro => "ro",
            AccessType::Wo => "wo",
            AccessType::Rw => "rw",
            AccessType::Rwr => "rwr",
            AccessType::Rww => "rww",
            AccessType::Const => "const",
        }
    }

    pub fn is_readable(self) -> bool {
        !matches!(self, AccessType::Wo)
    }

    pub fn is_writable(self) -> bool {
        !matches!(self, AccessType::Ro | AccessType::Const)
    }
}

impl fmt::Display for AccessType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// An access type other than ro, wo, rw, rwr, rww, const.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("'{0}' is not an access type (ro, wo, rw, rwr, rww, const)")]
pub struct UnknownAccessType(pub String);

impl FromStr for AccessType {
    type Err = UnknownAccessType;

    /// Case-insensitive: vendors write `RW` and `Const` too.
    fn from_str(text: &str) -> Result<Self, UnknownAccessType> {
        let all = [
            AccessType::Ro,
            AccessType::Wo,
            AccessType::Rw,
            AccessType::Rwr,
            AccessType::Rww,
            AccessType::Const,
        ];
        all.into_iter()
            .find(|access| access.as_str().eq_ignore_ascii_case(text.trim()))
            .ok_or_else(|| UnknownAccessType(text.to_string()))
    }
}

impl serde::Serialize for AccessType {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.as_str())
    }
}

impl<'de> serde::Deserialize<'de> for AccessType {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = String::deserialize(deserializer)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// What kind of entry sits at an index: the object code (CiA 301 §7.4,
/// CiA 306 `ObjectType`). The doc of each variant gives its wire value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ObjectType {
    /// 0x00 NULL: an entry with no data.
    Null,
    /// 0x02 DOMAIN: a large block of data of no fixed size.
    Domain,
    /// 0x05 DEFTYPE: the definition of a basic type (its bit size).
    DefType,
    /// 0x06 DEFSTRUCT: the definition of a record type.
    DefStruct,
    /// 0x07 VAR: a single value, at sub-index 0.
    Var,
    /// 0x08 ARRAY: sub 0 the number of entries, the others of one type.
    Array,
    /// 0x09 RECORD: sub 0 the highest sub-index, the others of any type.
    Record,
    /// Any other code.
    Unknown(u8),
}

impl ObjectType {
    pub fn from_raw(raw: u8) -> Self {
        match raw {
            0x00 => ObjectType::Null,
            0x02 => ObjectType::Domain,
            0x05 => ObjectType::DefType,
            0x06 => ObjectType::DefStruct,
            0x07 => ObjectType::Var,
            0x08 => ObjectType::Array,
            0x09 => ObjectType::Record,
            other => ObjectType::Unknown(other),
        }
    }

    pub fn raw(self) -> u8 {
        match self {
            ObjectType::Null => 0x00,
            ObjectType::Domain => 0x02,
            ObjectType::DefType => 0x05,
            ObjectType::DefStruct => 0x06,
            ObjectType::Var => 0x07,
            ObjectType::Array => 0x08,
            ObjectType::Record => 0x09,
            ObjectType::Unknown(raw) => raw,
        }
    }

    /// True for the codes whose entries live in sub-objects 0 to n rather
    /// than in the object itself.
    pub fn has_sub_objects(self) -> bool {
        matches!(
            self,
            ObjectType::Array | ObjectType::Record | ObjectType::DefStruct
        )
    }

    /// The lower-case name used in JSON (`"var"`, `"array"`, `"record"`, ...).
    pub fn name(self) -> &'static str {
        match self {
            ObjectType::Null => "null",
            ObjectType::Domain => "domain",
            ObjectType::DefType => "deftype",
            ObjectType::DefStruct => "defstruct",
            ObjectType::Var => "var",
            ObjectType::Array => "array",
            ObjectType::Record => "record",
            ObjectType::Unknown(_) => "unknown",
        }
    }
}

impl fmt::Display for ObjectType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ObjectType::Unknown(raw) => write!(f, "0x{raw:02X}"),
            known => f.write_str(known.name()),
        }
    }
}

impl serde::Serialize for ObjectType {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_types_of_table_3_8_with_their_cia_301_index() {
        let table = [
            (0x0001, DataType::Boolean, "bool", Some(1), false),
            (0x0002, DataType::Integer8, "i8", Some(8), true),
            (0x0003, DataType::Integer16, "i16", Some(16), true),
            (0x0004, DataType::Integer32, "i32", Some(32), true),
            (0x0005, DataType::Unsigned8, "u8", Some(8), false),
            (0x0006, DataType::Unsigned16, "u16", Some(16), false),
            (0x0007, DataType::Unsigned32, "u32", Some(32), false),
            (0x0008, DataType::Real32, "r32", Some(32), true),
            (0x0009, DataType::VisibleString, "vs", None, false),
            (0x000A, DataType::OctetString, "os", None, false),
            (0x000B, DataType::UnicodeString, "us", None, false),
            (0x000C, DataType::TimeOfDay, "tod", Some(48), false),
            (0x000D, DataType::TimeDifference, "td", Some(48), false),
            (0x000F, DataType::Domain, "d", None, false),
            (0x0010, DataType::Integer24, "i24", Some(24), true),
            (0x0011, DataType::Real64, "r64", Some(64), true),
            (0x0012, DataType::Integer40, "i40", Some(40), true),
            (0x0013, DataType::Integer48, "i48", Some(48), true),
            (0x0014, DataType::Integer56, "i56", Some(56), true),
            (0x0015, DataType::Integer64, "i64", Some(64), true),
            (0x0016, DataType::Unsigned24, "u24", Some(24), false),
            (0x0018, DataType::Unsigned40, "u40", Some(40), false),
            (0x0019, DataType::Unsigned48, "u48", Some(48), false),
            (0x001A, DataType::Unsigned56, "u56", Some(56), false),
            (0x001B, DataType::Unsigned64, "u64", Some(64), false),
        ];
        assert_eq!(table.len(), DataType::ALL.len());
        for (raw, data_type, short, bits, signed) in table {
            assert_eq!(DataType::from_raw(raw), data_type);
            assert_eq!(data_type.raw(), raw);
            assert_eq!(data_type.short_name(), Some(short));
            assert_eq!(short.parse::<DataType>(), Ok(data_type));
            assert_eq!(data_type.to_string().parse::<DataType>(), Ok(data_type));
            assert_eq!(format!("{raw:#06x}").parse::<DataType>(), Ok(data_type));
            assert_eq!(data_type.bits(), bits, "{data_type}");
            assert_eq!(data_type.is_signed(), signed, "{data_type}");
            assert_eq!(serde_json::to_value(data_type).unwrap(), short);
        }
        assert_eq!(DataType::Boolean.byte_len(), Some(1));
        assert_eq!(DataType::Integer24.byte_len(), Some(3));
        assert_eq!(DataType::TimeOfDay.byte_len(), Some(6));
        assert_eq!(DataType::Domain.byte_len(), None);
    }

    #[test]
    fn unknown_data_types_keep_their_index() {
        // 0x000E is not assigned; 0x0017 is reserved; 0x0020 is a record type.
        for raw in [0x0000, 0x000E, 0x0017, 0x0020, 0x9999] {
            let data_type = DataType::from_raw(raw);
            assert_eq!(data_type, DataType::Unknown(raw));
            assert_eq!(data_type.raw(), raw);
            assert_eq!(data_type.short_name(), None);
            assert!(!data_type.is_integer() && !data_type.is_variable_size());
        }
        assert_eq!(DataType::Unknown(0x20).to_string(), "0x0020");
        assert_eq!("visible string".parse(), Ok(DataType::VisibleString));
        assert_eq!("Unsigned16".parse(), Ok(DataType::Unsigned16));
        assert!("u33".parse::<DataType>().is_err());
        assert!("".parse::<DataType>().is_err());
        assert!("0x10000".parse::<DataType>().is_err());
    }

    #[test]
    fn integer_ranges_follow_the_bit_size() {
        assert_eq!(
            DataType::Integer24.integer_range(),
            Some((-0x80_0000, 0x7F_FFFF))
        );
        assert_eq!(
            DataType::Unsigned56.integer_range(),
            Some((0, (1 << 56) - 1))
        );
        assert_eq!(
            DataType::Integer64.integer_range(),
            Some((i64::MIN.into(), i64::MAX.into()))
        );
        assert_eq!(DataType::Boolean.integer_range(), Some((0, 1)));
        assert_eq!(DataType::Real32.integer_range(), None);
        assert_eq!(DataType::TimeOfDay.integer_range(), None);
        assert_eq!(DataType::VisibleString.integer_range(), None);
    }

    #[test]
    fn access_types_as_eds_spells_them() {
        for (text, access, read, write) in [
            ("ro", AccessType::Ro, true, false),
            ("wo", AccessType::Wo, false, true),
            ("rw", AccessType::Rw, true, true),
            ("rwr", AccessType::Rwr, true, true),
            ("rww", AccessType::Rww, true, true),
            ("const", AccessType::Const, true, false),
        ] {
            assert_eq!(text.parse(), Ok(access));
            assert_eq!(text.to_uppercase().parse(), Ok(access));
            assert_eq!(access.to_string(), text);
            assert_eq!((access.is_readable(), access.is_writable()), (read, write));
        }
        assert_eq!(" Const ".parse(), Ok(AccessType::Const));
        assert!("r".parse::<AccessType>().is_err());
        assert!("readwrite".parse::<AccessType>().is_err());
    }

    #[test]
    fn object_types_with_their_codes() {
        for (raw, object_type) in [
            (0, ObjectType::Null),
            (2, ObjectType::Domain),
            (5, ObjectType::DefType),
            (6, ObjectType::DefStruct),
            (7, ObjectType::Var),
            (8, ObjectType::Array),
            (9, ObjectType::Record),
            (3, ObjectType::Unknown(3)),
        ] {
            assert_eq!(ObjectType::from_raw(raw), object_type);
            assert_eq!(object_type.raw(), raw);
        }
        assert!(ObjectType::Array.has_sub_objects());
        assert!(!ObjectType::Var.has_sub_objects());
        assert_eq!(serde_json::to_value(ObjectType::Record).unwrap(), "record");
    }
}
