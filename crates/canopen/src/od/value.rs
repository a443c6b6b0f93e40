//! Typed values of the object dictionary and their three encodings: the
//! little-endian bytes of an SDO or PDO transfer (CiA 301 §7.1), the text of
//! an EDS or DCF (CiA 306, with `$NODEID`), and the JSON of the REST API
//! (`docs/rest-api.md`, "Conventions").

use std::fmt;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD as BASE64;
use serde_json::Value as Json;

use super::DataType;
use crate::NodeId;

/// The value of a TIME_OF_DAY or TIME_DIFFERENCE (CiA 301 §7.1): 28
/// bits of milliseconds and 16 bits of days. For TIME_OF_DAY that is the
/// time since midnight and the days since 1 January 1984.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct TimeOfDay {
    pub ms: u32,
    pub days: u16,
}

impl TimeOfDay {
    const MS_MASK: u32 = 0x0FFF_FFFF;

    /// The 48 bits on the wire read as one little-endian number: milliseconds
    /// in bits 0–27, days in bits 32–47. The 4 reserved bits are dropped.
    pub fn from_raw(raw: u64) -> Self {
        TimeOfDay {
            ms: (raw as u32) & Self::MS_MASK,
            days: (raw >> 32) as u16,
        }
    }

    pub fn raw(self) -> u64 {
        u64::from(self.ms & Self::MS_MASK) | (u64::from(self.days) << 32)
    }
}

/// A value of one of the basic types. Each variant holds exactly one
/// [`DataType`]; the 24-, 40-, 48- and 56-bit integers sit in the next wider
/// Rust integer, and their constructors check the range.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    Boolean(bool),
    Integer8(i8),
    Integer16(i16),
    Integer24(i32),
    Integer32(i32),
    Integer40(i64),
    Integer48(i64),
    Integer56(i64),
    Integer64(i64),
    Unsigned8(u8),
    Unsigned16(u16),
    Unsigned24(u32),
    Unsigned32(u32),
    Unsigned40(u64),
    Unsigned48(u64),
    Unsigned56(u64),
    Unsigned64(u64),
    Real32(f32),
    Real64(f64),
    VisibleString(String),
    OctetString(Vec<u8>),
    UnicodeString(String),
    TimeOfDay(TimeOfDay),
    TimeDifference(TimeOfDay),
    Domain(Vec<u8>),
}

/// Why bytes, text or JSON are no value of a type, or a value is outside its
/// limits. [`ValueError::sdo_abort_code`] gives the CiA 301 abort code an SDO
/// server answers with.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ValueError {
    #[error("{data_type} takes {expected} bytes, got {got}")]
    Length {
        data_type: DataType,
        expected: usize,
        got: usize,
    },
    #[error("{data_type} takes an even number of bytes, got {got}")]
    OddLength { data_type: DataType, got: usize },
    #[error("'{text}' is not a valid {data_type}: {reason}")]
    Invalid {
        data_type: DataType,
        text: String,
        reason: String,
    },
    #[error("{value} is outside the range of {data_type} ({min} to {max})")]
    OutOfRange {
        data_type: DataType,
        value: String,
        min: String,
        max: String,
    },
    #[error("{value} is above the high limit {high}")]
    TooHigh { value: String, high: String },
    #[error("{value} is below the low limit {low}")]
    TooLow { value: String, low: String },
    #[error("expected a {expected} value, got a {got}")]
    WrongType { expected: DataType, got: DataType },
    #[error("'{text}' depends on $NODEID and no node id is known")]
    NodeIdRequired { text: String },
    #[error("data type {0} has no known encoding")]
    UnsupportedType(DataType),
}

impl ValueError {
    /// The SDO abort code (CiA 301 table 22) for this error, as a server
    /// refusing the transfer would send it.
    pub fn sdo_abort_code(&self) -> u32 {
        match self {
            // Length of service parameter too high / too low.
            ValueError::Length { expected, got, .. } if got > expected => 0x0607_0012,
            ValueError::Length { .. } => 0x0607_0013,
            // Data type does not match, length of service parameter does not match.
            ValueError::OddLength { .. }
            | ValueError::WrongType { .. }
            | ValueError::UnsupportedType(_) => 0x0607_0010,
            // Value range of parameter exceeded.
            ValueError::Invalid { .. } | ValueError::OutOfRange { .. } => 0x0609_0030,
            ValueError::TooHigh { .. } => 0x0609_0031,
            ValueError::TooLow { .. } => 0x0609_0032,
            // General error: the device is missing what the value depends on.
            ValueError::NodeIdRequired { .. } => 0x0800_0000,
        }
    }

    /// True for the errors of a well-formed value outside its type's range
    /// or its limits (the API's `value_out_of_range` rather than
    /// `invalid_value`).
    pub fn is_out_of_range(&self) -> bool {
        matches!(
            self,
            ValueError::OutOfRange { .. } | ValueError::TooHigh { .. } | ValueError::TooLow { .. }
        )
    }
}

/// Input quoted in an error: long enough to recognise, short enough that a
/// 10 MB line does not become a 10 MB message.
pub(crate) fn snippet(text: &str) -> String {
    const MAX: usize = 40;
    match text.char_indices().nth(MAX) {
        Some((end, _)) => format!("{}...", &text[..end]),
        None => text.to_string(),
    }
}

fn invalid(data_type: DataType, text: &str, reason: impl Into<String>) -> ValueError {
    ValueError::Invalid {
        data_type,
        text: snippet(text),
        reason: reason.into(),
    }
}

/// A number as CiA 306 writes it: decimal, hex after `0x`, or octal after a
/// leading `0`, with an optional sign. The flag tells whether it was hex.
fn parse_number(text: &str) -> Result<(i128, bool), &'static str> {
    let text = text.trim();
    let (negative, unsigned) = match text.as_bytes().first() {
        Some(b'-') => (true, &text[1..]),
        Some(b'+') => (false, &text[1..]),
        _ => (false, text),
    };
    let (digits, radix) = if let Some(hex) = unsigned
        .strip_prefix("0x")
        .or_else(|| unsigned.strip_prefix("0X"))
    {
        (hex, 16)
    } else if unsigned.len() > 1
        && unsigned.starts_with('0')
        && unsigned.bytes().all(|b| (b'0'..=b'7').contains(&b))
    {
        (&unsigned[1..], 8)
    } else {
        // A leading zero followed by 8 or 9 is no octal number; vendors who
        // write `09` mean nine.
        (unsigned, 10)
    };
    if digits.is_empty() {
        return Err("no digits");
    }
    if !digits.bytes().all(|b| char::from(b).is_digit(radix)) {
        return Err(match radix {
            16 => "bad hex digits",
            _ => "not a number",
        });
    }
    let magnitude = u128::from_str_radix(digits, radix).map_err(|_| "too large")?;
    let magnitude = i128::try_from(magnitude).map_err(|_| "too large")?;
    Ok((if negative { -magnitude } else { magnitude }, radix == 16))
}

/// An integer with an optional `$NODEID` term (`$NODEID+0x180`,
/// `0x180 + $NODEID`, `$NODEID`), the node id given as a number.
fn parse_integer_expression(
    data_type: DataType,
    text: &str,
    node: Option<u8>,
) -> Result<(i128, bool), ValueError> {
    let trimmed = text.trim();
    // ASCII upper-casing keeps byte offsets, so positions found in `upper`
    // are valid in it.
    let upper = trimmed.to_ascii_uppercase();
    const NODEID: &str = "$NODEID";
    let Some(position) = upper.find(NODEID) else {
        return parse_number(trimmed).map_err(|reason| invalid(data_type, text, reason));
    };
    let before = upper[..position].trim();
    let after = upper[position + NODEID.len()..].trim();
    let term = match (before.is_empty(), after.is_empty()) {
        (true, true) => None,
        (true, false) => after.strip_prefix('+'),
        (false, true) => before.strip_suffix('+'),
        (false, false) => None,
    };
    let bad_expression = || invalid(data_type, text, "expected $NODEID, $NODEID+n or n+$NODEID");
    if (!before.is_empty() || !after.is_empty()) && term.is_none() {
        return Err(bad_expression());
    }
    let (offset, hex) = match term {
        Some(term) if term.contains(NODEID) => return Err(bad_expression()),
        Some(term) => parse_number(term).map_err(|reason| invalid(data_type, text, reason))?,
        None => (0, false),
    };
    let node = node.ok_or_else(|| ValueError::NodeIdRequired {
        text: snippet(text),
    })?;
    Ok((offset + i128::from(node), hex))
}

impl Value {
    pub fn data_type(&self) -> DataType {
        match self {
            Value::Boolean(_) => DataType::Boolean,
            Value::Integer8(_) => DataType::Integer8,
            Value::Integer16(_) => DataType::Integer16,
            Value::Integer24(_) => DataType::Integer24,
            Value::Integer32(_) => DataType::Integer32,
            Value::Integer40(_) => DataType::Integer40,
            Value::Integer48(_) => DataType::Integer48,
            Value::Integer56(_) => DataType::Integer56,
            Value::Integer64(_) => DataType::Integer64,
            Value::Unsigned8(_) => DataType::Unsigned8,
            Value::Unsigned16(_) => DataType::Unsigned16,
            Value::Unsigned24(_) => DataType::Unsigned24,
            Value::Unsigned32(_) => DataType::Unsigned32,
            Value::Unsigned40(_) => DataType::Unsigned40,
            Value::Unsigned48(_) => DataType::Unsigned48,
            Value::Unsigned56(_) => DataType::Unsigned56,
            Value::Unsigned64(_) => DataType::Unsigned64,
            Value::Real32(_) => DataType::Real32,
            Value::Real64(_) => DataType::Real64,
            Value::VisibleString(_) => DataType::VisibleString,
            Value::OctetString(_) => DataType::OctetString,
            Value::UnicodeString(_) => DataType::UnicodeString,
            Value::TimeOfDay(_) => DataType::TimeOfDay,
            Value::TimeDifference(_) => DataType::TimeDifference,
            Value::Domain(_) => DataType::Domain,
        }
    }

    /// The zero of a type: false, 0, 0.0, empty. `None` for unknown types.
    pub fn zero(data_type: DataType) -> Option<Value> {
        Some(match data_type {
            DataType::Real32 => Value::Real32(0.0),
            DataType::Real64 => Value::Real64(0.0),
            DataType::VisibleString => Value::VisibleString(String::new()),
            DataType::OctetString => Value::OctetString(Vec::new()),
            DataType::UnicodeString => Value::UnicodeString(String::new()),
            DataType::TimeOfDay => Value::TimeOfDay(TimeOfDay::default()),
            DataType::TimeDifference => Value::TimeDifference(TimeOfDay::default()),
            DataType::Domain => Value::Domain(Vec::new()),
            DataType::Unknown(_) => return None,
            integer => return Value::from_i128(integer, 0).ok(),
        })
    }

    /// An integer (or BOOLEAN, 0 or 1) of `data_type`, checked against the
    /// type's range.
    pub fn from_i128(data_type: DataType, value: i128) -> Result<Value, ValueError> {
        let Some((min, max)) = data_type.integer_range() else {
            return Err(invalid(
                data_type,
                &value.to_string(),
                "not an integer type",
            ));
        };
        if value < min || value > max {
            return Err(ValueError::OutOfRange {
                data_type,
                value: value.to_string(),
                min: min.to_string(),
                max: max.to_string(),
            });
        }
        // The range check above makes every `as` below lossless.
        Ok(match data_type {
            DataType::Boolean => Value::Boolean(value != 0),
            DataType::Integer8 => Value::Integer8(value as i8),
            DataType::Integer16 => Value::Integer16(value as i16),
            DataType::Integer24 => Value::Integer24(value as i32),
            DataType::Integer32 => Value::Integer32(value as i32),
            DataType::Integer40 => Value::Integer40(value as i64),
            DataType::Integer48 => Value::Integer48(value as i64),
            DataType::Integer56 => Value::Integer56(value as i64),
            DataType::Integer64 => Value::Integer64(value as i64),
            DataType::Unsigned8 => Value::Unsigned8(value as u8),
            DataType::Unsigned16 => Value::Unsigned16(value as u16),
            DataType::Unsigned24 => Value::Unsigned24(value as u32),
            DataType::Unsigned32 => Value::Unsigned32(value as u32),
            DataType::Unsigned40 => Value::Unsigned40(value as u64),
            DataType::Unsigned48 => Value::Unsigned48(value as u64),
            DataType::Unsigned56 => Value::Unsigned56(value as u64),
            DataType::Unsigned64 => Value::Unsigned64(value as u64),
            other => return Err(invalid(other, &value.to_string(), "not an integer type")),
        })
    }

    /// The value of BOOLEAN and the integer types as one number.
    pub fn as_i128(&self) -> Option<i128> {
        Some(match *self {
            Value::Boolean(b) => i128::from(b),
            Value::Integer8(v) => v.into(),
            Value::Integer16(v) => v.into(),
            Value::Integer24(v) | Value::Integer32(v) => v.into(),
            Value::Integer40(v)
            | Value::Integer48(v)
            | Value::Integer56(v)
            | Value::Integer64(v) => v.into(),
            Value::Unsigned8(v) => v.into(),
            Value::Unsigned16(v) => v.into(),
            Value::Unsigned24(v) | Value::Unsigned32(v) => v.into(),
            Value::Unsigned40(v)
            | Value::Unsigned48(v)
            | Value::Unsigned56(v)
            | Value::Unsigned64(v) => v.into(),
            _ => return None,
        })
    }

    /// Numbers (integers and reals) as a float, for display and scaling.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Value::Real32(v) => Some(v.into()),
            Value::Real64(v) => Some(v),
            _ => self.as_i128().map(|v| v as f64),
        }
    }

    /// The bytes on the wire, little-endian (CiA 301 §7.1). An out-of-range
    /// 24/40/48/56-bit integer built by hand is cut to its width.
    pub fn to_bytes(&self) -> Vec<u8> {
        fn low<const N: usize>(bytes: [u8; N], len: usize) -> Vec<u8> {
            bytes[..len].to_vec()
        }
        match self {
            Value::Boolean(b) => vec![u8::from(*b)],
            Value::Integer8(v) => v.to_le_bytes().to_vec(),
            Value::Integer16(v) => v.to_le_bytes().to_vec(),
            Value::Integer24(v) => low(v.to_le_bytes(), 3),
            Value::Integer32(v) => v.to_le_bytes().to_vec(),
            Value::Integer40(v) => low(v.to_le_bytes(), 5),
            Value::Integer48(v) => low(v.to_le_bytes(), 6),
            Value::Integer56(v) => low(v.to_le_bytes(), 7),
            Value::Integer64(v) => v.to_le_bytes().to_vec(),
            Value::Unsigned8(v) => vec![*v],
            Value::Unsigned16(v) => v.to_le_bytes().to_vec(),
            Value::Unsigned24(v) => low(v.to_le_bytes(), 3),
            Value::Unsigned32(v) => v.to_le_bytes().to_vec(),
            Value::Unsigned40(v) => low(v.to_le_bytes(), 5),
            Value::Unsigned48(v) => low(v.to_le_bytes(), 6),
            Value::Unsigned56(v) => low(v.to_le_bytes(), 7),
            Value::Unsigned64(v) => v.to_le_bytes().to_vec(),
            Value::Real32(v) => v.to_le_bytes().to_vec(),
            Value::Real64(v) => v.to_le_bytes().to_vec(),
            Value::VisibleString(s) => s.as_bytes().to_vec(),
            Value::UnicodeString(s) => s.encode_utf16().flat_map(u16::to_le_bytes).collect(),
            Value::OctetString(b) | Value::Domain(b) => b.clone(),
            Value::TimeOfDay(t) | Value::TimeDifference(t) => low(t.raw().to_le_bytes(), 6),
        }
    }

    /// Reads the bytes of a transfer as `data_type`. Fixed-size types need
    /// exactly their size ([`ValueError::Length`] says which way it is off).
    /// A VISIBLE_STRING loses the NUL padding devices put after the text, and
    /// bytes that are not UTF-8 are read as Latin-1 rather than refused.
    pub fn from_bytes(data_type: DataType, bytes: &[u8]) -> Result<Value, ValueError> {
        if let Some(expected) = data_type.byte_len()
            && bytes.len() != expected
        {
            return Err(ValueError::Length {
                data_type,
                expected,
                got: bytes.len(),
            });
        }
        // The first 8 bytes as one number, for the integer and time types.
        let unsigned = {
            let mut wide = [0u8; 8];
            let n = bytes.len().min(8);
            wide[..n].copy_from_slice(&bytes[..n]);
            u64::from_le_bytes(wide)
        };
        Ok(match data_type {
            DataType::Boolean => Value::Boolean(bytes[0] != 0),
            DataType::Real32 => {
                Value::Real32(f32::from_le_bytes(bytes.try_into().unwrap_or([0; 4])))
            }
            DataType::Real64 => {
                Value::Real64(f64::from_le_bytes(bytes.try_into().unwrap_or([0; 8])))
            }
            DataType::TimeOfDay => Value::TimeOfDay(TimeOfDay::from_raw(unsigned)),
            DataType::TimeDifference => Value::TimeDifference(TimeOfDay::from_raw(unsigned)),
            DataType::VisibleString => {
                let text = match bytes.iter().rposition(|&b| b != 0) {
                    Some(last) => &bytes[..=last],
                    None => &[],
                };
                Value::VisibleString(match std::str::from_utf8(text) {
                    Ok(utf8) => utf8.to_string(),
                    Err(_) => text.iter().map(|&b| char::from(b)).collect(),
                })
            }
            DataType::UnicodeString => {
                if !bytes.len().is_multiple_of(2) {
                    return Err(ValueError::OddLength {
                        data_type,
                        got: bytes.len(),
                    });
                }
                let units: Vec<u16> = bytes
                    .chunks_exact(2)
                    .map(|pair| u16::from_le_bytes([pair[0], pair[1]]))
                    .collect();
                let text = String::from_utf16(&units)
                    .map_err(|_| invalid(data_type, &hex(bytes), "not UTF-16"))?;
                Value::UnicodeString(text.trim_end_matches('\0').to_string())
            }
            DataType::OctetString => Value::OctetString(bytes.to_vec()),
            DataType::Domain => Value::Domain(bytes.to_vec()),
            DataType::Unknown(_) => return Err(ValueError::UnsupportedType(data_type)),
            integer => {
                let bits = integer.bits().unwrap_or(64);
                let raw = unsigned;
                let value = if integer.is_signed() {
                    // Sign-extend from the type's width.
                    let shift = 64 - bits;
                    i128::from(((raw << shift) as i64) >> shift)
                } else {
                    i128::from(raw)
                };
                Value::from_i128(integer, value)?
            }
        })
    }

    /// Reads the text of an EDS `DefaultValue`, `LowLimit`, `HighLimit` or
    /// DCF `ParameterValue` (CiA 306): integers in decimal, `0x` hex or
    /// octal with a leading 0, negative, or `$NODEID+n` resolved with `node`;
    /// hex integers wider than a signed type's maximum read as two's
    /// complement (`0xFFFF` is -1 for INTEGER16); reals in decimal, or in hex
    /// as their IEEE bits; strings with or without quotes; octet strings and
    /// domains as hex digits.
    pub fn parse_text(
        data_type: DataType,
        text: &str,
        node: Option<NodeId>,
    ) -> Result<Value, ValueError> {
        Value::parse_text_with_node(data_type, text, node.map(NodeId::get))
    }

    /// [`Value::parse_text`] with the node id as a bare number, so that an
    /// EDS reader can check `$NODEID` expressions without a real node.
    pub(crate) fn parse_text_with_node(
        data_type: DataType,
        text: &str,
        node: Option<u8>,
    ) -> Result<Value, ValueError> {
        let trimmed = text.trim();
        match data_type {
            DataType::Boolean if trimmed.eq_ignore_ascii_case("true") => Ok(Value::Boolean(true)),
            DataType::Boolean if trimmed.eq_ignore_ascii_case("false") => Ok(Value::Boolean(false)),
            DataType::Real32 | DataType::Real64 => parse_real(data_type, trimmed),
            DataType::VisibleString => Ok(Value::VisibleString(unquote(trimmed).to_string())),
            DataType::UnicodeString => Ok(Value::UnicodeString(unquote(trimmed).to_string())),
            DataType::OctetString => Ok(Value::OctetString(parse_hex_bytes(data_type, trimmed)?)),
            DataType::Domain => Ok(Value::Domain(parse_hex_bytes(data_type, trimmed)?)),
            DataType::TimeOfDay | DataType::TimeDifference => {
                let (raw, _) = parse_integer_expression(data_type, trimmed, node)?;
                let raw = u64::try_from(raw)
                    .ok()
                    .filter(|raw| *raw < 1 << 48)
                    .ok_or_else(|| invalid(data_type, text, "not a 48-bit number"))?;
                let time = TimeOfDay::from_raw(raw);
                Ok(match data_type {
                    DataType::TimeOfDay => Value::TimeOfDay(time),
                    _ => Value::TimeDifference(time),
                })
            }
            DataType::Unknown(_) => Err(ValueError::UnsupportedType(data_type)),
            integer => {
                let (mut value, hex) = parse_integer_expression(integer, trimmed, node)?;
                if let (true, Some((_, max)), Some(bits)) = (
                    hex && integer.is_signed(),
                    integer.integer_range(),
                    integer.bits(),
                ) && value > max
                    && value < 1i128 << bits
                {
                    value -= 1i128 << bits;
                }
                Value::from_i128(integer, value)
            }
        }
    }

    /// The text of a DCF `ParameterValue` that [`Value::parse_text`] reads
    /// back to the same value: integers in decimal, reals in the shortest
    /// decimal that round-trips, strings bare (in quotes when an INI reader
    /// would change them), octet strings and domains in hex.
    pub fn to_text(&self) -> String {
        match self {
            Value::Real32(v) => v.to_string(),
            Value::Real64(v) => v.to_string(),
            Value::VisibleString(s) | Value::UnicodeString(s) => quote_if_needed(s),
            Value::OctetString(b) | Value::Domain(b) => hex(b),
            Value::TimeOfDay(t) | Value::TimeDifference(t) => t.raw().to_string(),
            Value::Boolean(b) => u8::from(*b).to_string(),
            integer => integer.as_i128().unwrap_or_default().to_string(),
        }
    }

    /// The JSON of the REST API: integers as numbers, except INTEGER64 and
    /// UNSIGNED64 as decimal strings (JSON readers in browsers keep 53 bits);
    /// reals as numbers (`"NaN"`, `"inf"`, `"-inf"` as strings, which JSON
    /// numbers cannot be); booleans as true/false; strings as strings; octet
    /// strings and domains in base64; times as `{"ms", "days"}`.
    ///
    /// INTEGER56/UNSIGNED56 stay numbers as the REST API says, though a browser
    /// rounds those above 2^53.
    pub fn to_json(&self) -> Json {
        match self {
            Value::Boolean(b) => Json::Bool(*b),
            Value::Integer64(v) => Json::String(v.to_string()),
            Value::Unsigned64(v) => Json::String(v.to_string()),
            Value::Real32(v) if v.is_finite() => {
                // Through the shortest decimal text, so that 0.1f32 shows as
                // 0.1 rather than 0.10000000149011612.
                v.to_string().parse::<f64>().map_or(Json::Null, Json::from)
            }
            Value::Real64(v) if v.is_finite() => Json::from(*v),
            Value::Real32(_) | Value::Real64(_) => Json::String(self.to_text()),
            Value::VisibleString(s) | Value::UnicodeString(s) => Json::String(s.clone()),
            Value::OctetString(b) | Value::Domain(b) => Json::String(BASE64.encode(b)),
            Value::TimeOfDay(t) | Value::TimeDifference(t) => {
                serde_json::json!({ "ms": t.ms, "days": t.days })
            }
            integer => match integer.as_i128().and_then(|v| i64::try_from(v).ok()) {
                Some(v) => Json::from(v),
                None => Json::Null,
            },
        }
    }

    /// Reads the JSON of a request as `data_type`: numbers and strings for
    /// integers and reals (strings in any [`Value::parse_text`] form, so
    /// `"0x180"` and `"18446744073709551615"` both work), true/false or 0/1
    /// for booleans, base64 for octet strings and domains.
    pub fn from_json(data_type: DataType, json: &Json) -> Result<Value, ValueError> {
        let shown = || snippet(&json.to_string());
        let wrong_kind = |expected: &str| ValueError::Invalid {
            data_type,
            text: shown(),
            reason: format!("expected {expected}"),
        };
        match data_type {
            DataType::Unknown(_) => Err(ValueError::UnsupportedType(data_type)),
            DataType::VisibleString | DataType::UnicodeString => match json {
                Json::String(s) if data_type == DataType::VisibleString => {
                    Ok(Value::VisibleString(s.clone()))
                }
                Json::String(s) => Ok(Value::UnicodeString(s.clone())),
                _ => Err(wrong_kind("a string")),
            },
            DataType::OctetString | DataType::Domain => match json {
                Json::String(s) => {
                    let bytes = BASE64
                        .decode(s.trim())
                        .map_err(|_| invalid(data_type, s, "not base64"))?;
                    Ok(match data_type {
                        DataType::OctetString => Value::OctetString(bytes),
                        _ => Value::Domain(bytes),
                    })
                }
                _ => Err(wrong_kind("a base64 string")),
            },
            DataType::Real32 | DataType::Real64 => match json {
                Json::Number(n) => {
                    let v = n.as_f64().ok_or_else(|| wrong_kind("a number"))?;
                    real_from_f64(data_type, v, &n.to_string())
                }
                Json::String(s) => parse_real(data_type, s.trim()),
                _ => Err(wrong_kind("a number")),
            },
            DataType::TimeOfDay | DataType::TimeDifference => match json {
                Json::Object(fields) => {
                    let field = |name: &str| fields.get(name).and_then(Json::as_u64).unwrap_or(0);
                    let (ms, days) = (field("ms"), field("days"));
                    if ms > u64::from(TimeOfDay::MS_MASK) || days > u64::from(u16::MAX) {
                        return Err(invalid(data_type, &shown(), "ms or days out of range"));
                    }
                    let time = TimeOfDay {
                        ms: ms as u32,
                        days: days as u16,
                    };
                    Ok(match data_type {
                        DataType::TimeOfDay => Value::TimeOfDay(time),
                        _ => Value::TimeDifference(time),
                    })
                }
                Json::Number(n) => Value::parse_text(data_type, &n.to_string(), None),
                Json::String(s) => Value::parse_text(data_type, s, None),
                _ => Err(wrong_kind("{\"ms\", \"days\"}")),
            },
            integer => match json {
                Json::Bool(b) if integer == DataType::Boolean => Ok(Value::Boolean(*b)),
                Json::Number(n) => {
                    let value = if let Some(v) = n.as_i64() {
                        i128::from(v)
                    } else if let Some(v) = n.as_u64() {
                        i128::from(v)
                    } else {
                        // A float: accepted when it is a whole number (2.0),
                        // as JSON writers in some languages produce.
                        let v = n.as_f64().unwrap_or(f64::NAN);
                        if !(v.is_finite() && v.fract() == 0.0 && v.abs() < 1e20) {
                            return Err(invalid(integer, &n.to_string(), "not a whole number"));
                        }
                        v as i128
                    };
                    Value::from_i128(integer, value)
                }
                Json::String(s) => Value::parse_text(integer, s, None),
                _ if integer == DataType::Boolean => Err(wrong_kind("true, false, 0 or 1")),
                _ => Err(wrong_kind("a number or a string")),
            },
        }
    }

    /// Checks a number against a sub-object's limits (CiA 306 `LowLimit`,
    /// `HighLimit`); values that are not numbers have none.
    pub fn check_limits(
        &self,
        low: Option<&Value>,
        high: Option<&Value>,
    ) -> Result<(), ValueError> {
        let below = |limit: &Value| match (self.as_i128(), limit.as_i128()) {
            (Some(v), Some(l)) => v < l,
            _ => matches!((self.as_f64(), limit.as_f64()), (Some(v), Some(l)) if v < l),
        };
        let above = |limit: &Value| match (self.as_i128(), limit.as_i128()) {
            (Some(v), Some(l)) => v > l,
            _ => matches!((self.as_f64(), limit.as_f64()), (Some(v), Some(l)) if v > l),
        };
        if let Some(low) = low.filter(|low| below(low)) {
            return Err(ValueError::TooLow {
                value: self.to_text(),
                low: low.to_text(),
            });
        }
        if let Some(high) = high.filter(|high| above(high)) {
            return Err(ValueError::TooHigh {
                value: self.to_text(),
                high: high.to_text(),
            });
        }
        Ok(())
    }
}

/// Serializes as [`Value::to_json`] does, so that values can sit in API
/// response structs.
impl serde::Serialize for Value {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serde::Serialize::serialize(&self.to_json(), serializer)
    }
}

impl fmt::Display for Value {
    /// The text of [`Value::to_text`].
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.to_text())
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect()
}

/// A string as EDS text: bare, as CiA 306 and most tools read it, unless an
/// INI reader would change it (lose the spaces at its ends, take `;` for a
/// comment, read empty as "no value") or [`unquote`] would strip its quotes.
fn quote_if_needed(s: &str) -> String {
    let needs_quotes = s.is_empty()
        || s.trim() != s
        || s.contains(" ;")
        || s.contains("\t;")
        || (s.len() >= 2 && s.starts_with('"') && s.ends_with('"'));
    if needs_quotes {
        format!("\"{s}\"")
    } else {
        s.to_string()
    }
}

fn unquote(text: &str) -> &str {
    match text
        .strip_prefix('"')
        .and_then(|rest| rest.strip_suffix('"'))
    {
        Some(inner) => inner,
        None => text,
    }
}

fn parse_hex_bytes(data_type: DataType, text: &str) -> Result<Vec<u8>, ValueError> {
    let inner = unquote(text).trim();
    let inner = inner
        .strip_prefix("0x")
        .or_else(|| inner.strip_prefix("0X"))
        .unwrap_or(inner);
    let digits: Vec<u8> = inner.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
    if !digits.len().is_multiple_of(2) {
        return Err(invalid(data_type, text, "an odd number of hex digits"));
    }
    digits
        .chunks_exact(2)
        .map(|pair| {
            let pair = std::str::from_utf8(pair).unwrap_or("zz");
            u8::from_str_radix(pair, 16).map_err(|_| invalid(data_type, text, "bad hex digits"))
        })
        .collect()
}

fn parse_real(data_type: DataType, text: &str) -> Result<Value, ValueError> {
    if let Some(hex) = text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        // Hex is read as the IEEE bits: the only meaning hex has for a real.
        let bad = || invalid(data_type, text, "bad hex digits");
        if !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(bad());
        }
        return match data_type {
            DataType::Real32 => {
                u32::from_str_radix(hex, 16).map(|bits| Value::Real32(f32::from_bits(bits)))
            }
            _ => u64::from_str_radix(hex, 16).map(|bits| Value::Real64(f64::from_bits(bits))),
        }
        .map_err(|_| bad());
    }
    let v: f64 = text
        .parse()
        .map_err(|_| invalid(data_type, text, "not a number"))?;
    match data_type {
        // Parsed as f32 directly, so that the rounding is the shortest
        // decimal's rather than a double rounding through f64.
        DataType::Real32 => real32(text.parse().unwrap_or(v as f32), v, text),
        _ => Ok(Value::Real64(v)),
    }
}

/// A REAL32 whose f32 is infinite only if the number was: a finite number
/// too large for f32 is out of range, not infinity.
fn real32(v32: f32, v64: f64, text: &str) -> Result<Value, ValueError> {
    if v32.is_infinite() && v64.is_finite() {
        return Err(ValueError::OutOfRange {
            data_type: DataType::Real32,
            value: snippet(text),
            min: f32::MIN.to_string(),
            max: f32::MAX.to_string(),
        });
    }
    Ok(Value::Real32(v32))
}

fn real_from_f64(data_type: DataType, v: f64, text: &str) -> Result<Value, ValueError> {
    match data_type {
        // Through the shortest decimal text, for the same rounding as
        // parse_text.
        DataType::Real32 => real32(v.to_string().parse().unwrap_or(v as f32), v, text),
        _ => Ok(Value::Real64(v)),
    }
}

#[cfg(test)]
mod tests;
