//! Typed values of the object dictionary and their three encodings: the
//! little-endian bytes of an SDO or PDO transfer (CiA 301 §7.1), the text of
//! an EDS or DCF (CiA 306, with `$NODEID`), and the JSON of the REST API
//! (`docs/rest-api.md`, "Conventions").

use std::fmt;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD as BASE64;
use serde_json::Value as Json;

use super::DataType;
use crate::canopen::NodeId;

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
mod tests {
    use super::*;
    use serde_json::json;

    fn node(id: u8) -> Option<NodeId> {
        Some(NodeId::new(id).unwrap())
    }

    fn parse(data_type: DataType, text: &str) -> Result<Value, ValueError> {
        Value::parse_text(data_type, text, None)
    }

    /// Each type at its limits (and zero), with the bytes CiA 301 puts on the wire.
    fn limits_table() -> Vec<(Value, Vec<u8>)> {
        vec![
            (Value::Boolean(false), vec![0]),
            (Value::Boolean(true), vec![1]),
            (Value::Integer8(i8::MIN), vec![0x80]),
            (Value::Integer8(i8::MAX), vec![0x7F]),
            (Value::Integer8(-1), vec![0xFF]),
            (Value::Integer16(i16::MIN), vec![0x00, 0x80]),
            (Value::Integer16(i16::MAX), vec![0xFF, 0x7F]),
            (Value::Integer24(-0x80_0000), vec![0x00, 0x00, 0x80]),
            (Value::Integer24(0x7F_FFFF), vec![0xFF, 0xFF, 0x7F]),
            (Value::Integer24(-2), vec![0xFE, 0xFF, 0xFF]),
            (Value::Integer32(i32::MIN), vec![0, 0, 0, 0x80]),
            (Value::Integer32(i32::MAX), vec![0xFF, 0xFF, 0xFF, 0x7F]),
            (Value::Integer40(-(1 << 39)), vec![0, 0, 0, 0, 0x80]),
            (
                Value::Integer40((1 << 39) - 1),
                vec![0xFF, 0xFF, 0xFF, 0xFF, 0x7F],
            ),
            (Value::Integer48(-(1 << 47)), vec![0, 0, 0, 0, 0, 0x80]),
            (
                Value::Integer48((1 << 47) - 1),
                vec![0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x7F],
            ),
            (Value::Integer48(-1), vec![0xFF; 6]),
            (Value::Integer56(-(1 << 55)), vec![0, 0, 0, 0, 0, 0, 0x80]),
            (
                Value::Integer56((1 << 55) - 1),
                vec![0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x7F],
            ),
            (Value::Integer64(i64::MIN), vec![0, 0, 0, 0, 0, 0, 0, 0x80]),
            (
                Value::Integer64(i64::MAX),
                vec![0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x7F],
            ),
            (Value::Unsigned8(0), vec![0]),
            (Value::Unsigned8(u8::MAX), vec![0xFF]),
            (Value::Unsigned16(0x1234), vec![0x34, 0x12]),
            (Value::Unsigned16(u16::MAX), vec![0xFF, 0xFF]),
            (Value::Unsigned24(0xFF_FFFF), vec![0xFF, 0xFF, 0xFF]),
            (Value::Unsigned24(0x01_0203), vec![0x03, 0x02, 0x01]),
            (Value::Unsigned32(0x6041_0010), vec![0x10, 0x00, 0x41, 0x60]),
            (Value::Unsigned32(u32::MAX), vec![0xFF; 4]),
            (Value::Unsigned40((1 << 40) - 1), vec![0xFF; 5]),
            (Value::Unsigned48((1 << 48) - 1), vec![0xFF; 6]),
            (Value::Unsigned56((1 << 56) - 1), vec![0xFF; 7]),
            (
                Value::Unsigned56(0x01_0203_0405_0607),
                vec![7, 6, 5, 4, 3, 2, 1],
            ),
            (Value::Unsigned64(u64::MAX), vec![0xFF; 8]),
            (Value::Unsigned64(0), vec![0; 8]),
            (Value::Real32(1.0), vec![0x00, 0x00, 0x80, 0x3F]),
            (Value::Real32(-2.5), vec![0x00, 0x00, 0x20, 0xC0]),
            (Value::Real32(f32::MAX), vec![0xFF, 0xFF, 0x7F, 0x7F]),
            (Value::Real64(1.0), vec![0, 0, 0, 0, 0, 0, 0xF0, 0x3F]),
            (
                Value::Real64(f64::MIN),
                vec![0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xEF, 0xFF],
            ),
            (
                Value::VisibleString("UMC1BDS32".into()),
                b"UMC1BDS32".to_vec(),
            ),
            (Value::VisibleString(String::new()), vec![]),
            (Value::OctetString(vec![0, 1, 0xFE]), vec![0, 1, 0xFE]),
            (
                Value::UnicodeString("vé".into()),
                vec![0x76, 0x00, 0xE9, 0x00],
            ),
            (
                Value::TimeOfDay(TimeOfDay {
                    ms: 0x0FFF_FFFF,
                    days: 0xFFFF,
                }),
                vec![0xFF, 0xFF, 0xFF, 0x0F, 0xFF, 0xFF],
            ),
            (
                Value::TimeDifference(TimeOfDay { ms: 1000, days: 2 }),
                vec![0xE8, 0x03, 0, 0, 2, 0],
            ),
            (
                Value::Domain(vec![0xDE, 0xAD, 0xBE, 0xEF]),
                vec![0xDE, 0xAD, 0xBE, 0xEF],
            ),
        ]
    }

    #[test]
    fn bytes_round_trip_for_every_type_at_its_limits() {
        let table = limits_table();
        for data_type in DataType::ALL {
            assert!(
                table
                    .iter()
                    .any(|(value, _)| value.data_type() == data_type),
                "{data_type} is missing from the table"
            );
        }
        for (value, bytes) in table {
            assert_eq!(value.to_bytes(), bytes, "{value:?}");
            assert_eq!(
                Value::from_bytes(value.data_type(), &bytes),
                Ok(value.clone())
            );
        }
    }

    #[test]
    fn wrong_lengths_say_which_way_and_map_to_sdo_aborts() {
        let short = Value::from_bytes(DataType::Unsigned32, &[1, 2]).unwrap_err();
        assert_eq!(
            short,
            ValueError::Length {
                data_type: DataType::Unsigned32,
                expected: 4,
                got: 2
            }
        );
        assert_eq!(short.to_string(), "UNSIGNED32 takes 4 bytes, got 2");
        assert_eq!(short.sdo_abort_code(), 0x0607_0013);
        let long = Value::from_bytes(DataType::Integer24, &[1, 2, 3, 4]).unwrap_err();
        assert_eq!(long.sdo_abort_code(), 0x0607_0012);
        assert!(Value::from_bytes(DataType::Boolean, &[]).is_err());
        assert!(Value::from_bytes(DataType::TimeOfDay, &[0; 4]).is_err());
        let odd = Value::from_bytes(DataType::UnicodeString, &[0x41, 0x00, 0x42]).unwrap_err();
        assert_eq!(odd.sdo_abort_code(), 0x0607_0010);
        // An unpaired surrogate is no text.
        assert!(Value::from_bytes(DataType::UnicodeString, &[0x00, 0xD8]).is_err());
        assert_eq!(
            Value::from_bytes(DataType::Unknown(0x20), &[1]),
            Err(ValueError::UnsupportedType(DataType::Unknown(0x20)))
        );
    }

    #[test]
    fn strings_from_devices_lose_their_padding() {
        assert_eq!(
            Value::from_bytes(DataType::VisibleString, b"v1.0.4\0\0\0"),
            Ok(Value::VisibleString("v1.0.4".into()))
        );
        // Not UTF-8: read as Latin-1 rather than refused.
        assert_eq!(
            Value::from_bytes(DataType::VisibleString, &[0x32, 0x35, 0xB0, 0x43]),
            Ok(Value::VisibleString("25°C".into()))
        );
        assert_eq!(
            Value::from_bytes(DataType::UnicodeString, &[0x41, 0, 0, 0]),
            Ok(Value::UnicodeString("A".into()))
        );
        // A non-zero byte is true, as CiA 301 has no other meaning for it.
        assert_eq!(
            Value::from_bytes(DataType::Boolean, &[2]),
            Ok(Value::Boolean(true))
        );
    }

    #[test]
    fn eds_text_in_every_form_vendors_write() {
        assert_eq!(
            parse(DataType::Unsigned32, "428"),
            Ok(Value::Unsigned32(428))
        );
        assert_eq!(
            parse(DataType::Unsigned32, "0x000004A2"),
            Ok(Value::Unsigned32(0x4A2))
        );
        assert_eq!(
            parse(DataType::Unsigned32, " 0X4a2 "),
            Ok(Value::Unsigned32(0x4A2))
        );
        assert_eq!(
            parse(DataType::Unsigned8, "010"),
            Ok(Value::Unsigned8(8)),
            "octal"
        );
        assert_eq!(parse(DataType::Unsigned8, "09"), Ok(Value::Unsigned8(9)));
        assert_eq!(parse(DataType::Unsigned8, "0"), Ok(Value::Unsigned8(0)));
        assert_eq!(
            parse(DataType::Integer32, "-2147483648"),
            Ok(Value::Integer32(i32::MIN))
        );
        assert_eq!(
            parse(DataType::Integer32, "-0x7FFFFFFF"),
            Ok(Value::Integer32(-i32::MAX))
        );
        assert_eq!(
            parse(DataType::Integer16, "0xFFFF"),
            Ok(Value::Integer16(-1))
        );
        assert_eq!(
            parse(DataType::Integer24, "0x800000"),
            Ok(Value::Integer24(-0x80_0000))
        );
        assert_eq!(parse(DataType::Integer8, "+5"), Ok(Value::Integer8(5)));
        assert_eq!(parse(DataType::Boolean, "1"), Ok(Value::Boolean(true)));
        assert_eq!(parse(DataType::Boolean, "FALSE"), Ok(Value::Boolean(false)));
        assert_eq!(parse(DataType::Real32, "1.5"), Ok(Value::Real32(1.5)));
        assert_eq!(parse(DataType::Real32, "-2e3"), Ok(Value::Real32(-2000.0)));
        assert_eq!(
            parse(DataType::Real32, "0x3F800000"),
            Ok(Value::Real32(1.0))
        );
        assert_eq!(parse(DataType::Real64, "0.1"), Ok(Value::Real64(0.1)));
        assert_eq!(parse(DataType::Real64, "7"), Ok(Value::Real64(7.0)));
        assert_eq!(
            parse(DataType::VisibleString, "\"https://uniswarm.eu/\""),
            Ok(Value::VisibleString("https://uniswarm.eu/".into()))
        );
        assert_eq!(
            parse(DataType::VisibleString, "bare"),
            Ok(Value::VisibleString("bare".into()))
        );
        assert_eq!(
            parse(DataType::UnicodeString, "\"vXX.XX.XXX\""),
            Ok(Value::UnicodeString("vXX.XX.XXX".into()))
        );
        assert_eq!(
            parse(DataType::OctetString, "01 02 ab"),
            Ok(Value::OctetString(vec![1, 2, 0xAB]))
        );
        assert_eq!(parse(DataType::Domain, ""), Ok(Value::Domain(vec![])));
        assert_eq!(
            parse(DataType::TimeOfDay, "0x0002000003E8"),
            Ok(Value::TimeOfDay(TimeOfDay { ms: 1000, days: 2 }))
        );
    }

    #[test]
    fn malformed_text_is_refused_with_a_reason() {
        let error = parse(DataType::Unsigned32, "0xZZ").unwrap_err();
        assert_eq!(
            error.to_string(),
            "'0xZZ' is not a valid UNSIGNED32: bad hex digits"
        );
        assert!(parse(DataType::Unsigned32, "").is_err());
        assert!(parse(DataType::Unsigned32, "0x").is_err());
        assert!(parse(DataType::Unsigned32, "0x+5").is_err());
        assert!(parse(DataType::Unsigned32, "12abc").is_err());
        assert!(parse(DataType::Unsigned32, "1.5").is_err());
        assert!(parse(DataType::Real32, "fast").is_err());
        assert!(parse(DataType::Real32, "0xG").is_err());
        assert!(parse(DataType::OctetString, "123").is_err());
        assert!(parse(DataType::OctetString, "zz").is_err());
        assert!(parse(DataType::Boolean, "2").unwrap_err().is_out_of_range());
        let too_big = parse(DataType::Unsigned8, "256").unwrap_err();
        assert_eq!(
            too_big.to_string(),
            "256 is outside the range of UNSIGNED8 (0 to 255)"
        );
        assert_eq!(too_big.sdo_abort_code(), 0x0609_0030);
        assert!(parse(DataType::Unsigned8, "-1").is_err());
        // Two's complement only for hex that fits the width.
        assert!(parse(DataType::Integer16, "0x10000").is_err());
        assert!(parse(DataType::Integer16, "65535").is_err());
        assert!(
            parse(DataType::Real32, "1e39")
                .unwrap_err()
                .is_out_of_range()
        );
        assert!(parse(DataType::Unsigned64, &"9".repeat(100)).is_err());
        assert!(parse(DataType::Unknown(0x40), "1").is_err());
        let long = parse(DataType::Unsigned32, &"x".repeat(1000))
            .unwrap_err()
            .to_string();
        assert!(long.len() < 100, "the message quotes a snippet: {long}");
    }

    #[test]
    fn nodeid_expressions_resolve_against_the_node() {
        let parse = |text, id| Value::parse_text(DataType::Unsigned32, text, node(id));
        assert_eq!(parse("$NODEID+0x180", 5), Ok(Value::Unsigned32(0x185)));
        assert_eq!(
            parse("$NODEID+0x00000180", 127),
            Ok(Value::Unsigned32(0x1FF))
        );
        assert_eq!(
            parse("$NODEID+0x80000180", 1),
            Ok(Value::Unsigned32(0x8000_0181))
        );
        assert_eq!(parse("0x600 + $NODEID", 3), Ok(Value::Unsigned32(0x603)));
        assert_eq!(parse("$nodeid + 128", 2), Ok(Value::Unsigned32(130)));
        assert_eq!(parse("$NODEID", 42), Ok(Value::Unsigned32(42)));
        assert_eq!(
            Value::parse_text(DataType::Unsigned8, "$NODEID", node(42)),
            Ok(Value::Unsigned8(42))
        );
        let unresolved = Value::parse_text(DataType::Unsigned32, "$NODEID+0x180", None);
        assert_eq!(
            unresolved,
            Err(ValueError::NodeIdRequired {
                text: "$NODEID+0x180".into()
            })
        );
        for bad in [
            "$NODEID+",
            "$NODEID 5",
            "$NODEID+$NODEID",
            "1+$NODEID+2",
            "$NODEID-1",
            "+$NODEID",
        ] {
            assert!(parse(bad, 1).is_err(), "{bad}");
        }
        // The sum is range-checked like any value.
        assert!(Value::parse_text(DataType::Unsigned8, "$NODEID+0xFF", node(1)).is_err());
    }

    #[test]
    fn text_round_trips_through_to_text() {
        for (value, _) in limits_table() {
            let text = value.to_text();
            assert_eq!(
                Value::parse_text(value.data_type(), &text, None),
                Ok(value.clone()),
                "{text}"
            );
        }
        assert_eq!(Value::Real32(0.1).to_text(), "0.1");
        assert_eq!(Value::OctetString(vec![0xAB, 1]).to_text(), "AB01");
        for (text, written) in [
            ("a b", "a b"),
            ("https://uniswarm.eu/", "https://uniswarm.eu/"),
            ("", "\"\""),
            (" padded ", "\" padded \""),
            ("a ; b", "\"a ; b\""),
            ("\"quoted\"", "\"\"quoted\"\""),
            ("say \"hi\" now", "say \"hi\" now"),
        ] {
            let value = Value::VisibleString(text.into());
            assert_eq!(value.to_text(), written);
            assert_eq!(parse(DataType::VisibleString, written), Ok(value));
        }
    }

    #[test]
    fn json_as_api_md_says() {
        let cases = [
            (Value::Boolean(true), json!(true)),
            (Value::Unsigned8(200), json!(200)),
            (Value::Integer16(-300), json!(-300)),
            (Value::Integer24(-5), json!(-5)),
            (Value::Unsigned32(u32::MAX), json!(4294967295u32)),
            (Value::Integer48((1 << 47) - 1), json!(140737488355327i64)),
            (Value::Integer64(i64::MIN), json!("-9223372036854775808")),
            (Value::Unsigned64(u64::MAX), json!("18446744073709551615")),
            (
                Value::Unsigned56((1 << 56) - 1),
                json!(72057594037927935u64),
            ),
            (Value::Integer56(-1), json!(-1)),
            (Value::Real32(0.1), json!(0.1)),
            (Value::Real64(-1.25), json!(-1.25)),
            (Value::VisibleString("UMC1BDS32".into()), json!("UMC1BDS32")),
            (Value::UnicodeString("é".into()), json!("é")),
            (Value::OctetString(vec![0, 1, 2, 0xFF]), json!("AAEC/w==")),
            (Value::Domain(vec![]), json!("")),
            (
                Value::TimeOfDay(TimeOfDay { ms: 5, days: 6 }),
                json!({"ms": 5, "days": 6}),
            ),
        ];
        for (value, expected) in cases {
            assert_eq!(value.to_json(), expected, "{value:?}");
            assert_eq!(Value::from_json(value.data_type(), &expected), Ok(value));
        }
        for (value, _) in limits_table() {
            assert_eq!(
                Value::from_json(value.data_type(), &value.to_json()),
                Ok(value)
            );
        }
        assert_eq!(
            serde_json::to_value(Value::Unsigned64(7)).unwrap(),
            json!("7"),
            "Serialize is to_json"
        );
        let non_finite = Value::Real32(f32::INFINITY).to_json();
        assert_eq!(non_finite, json!("inf"));
        assert_eq!(
            Value::from_json(DataType::Real32, &non_finite),
            Ok(Value::Real32(f32::INFINITY))
        );
    }

    #[test]
    fn json_accepts_strings_and_numbers_alike() {
        let from = |data_type, json: Json| Value::from_json(data_type, &json);
        assert_eq!(
            from(DataType::Unsigned64, json!(5)),
            Ok(Value::Unsigned64(5))
        );
        assert_eq!(
            from(DataType::Unsigned64, json!(u64::MAX)),
            Ok(Value::Unsigned64(u64::MAX))
        );
        assert_eq!(
            from(DataType::Unsigned16, json!("0x1234")),
            Ok(Value::Unsigned16(0x1234))
        );
        assert_eq!(
            from(DataType::Integer8, json!("-7")),
            Ok(Value::Integer8(-7))
        );
        assert_eq!(
            from(DataType::Integer32, json!(3.0)),
            Ok(Value::Integer32(3))
        );
        assert_eq!(from(DataType::Real32, json!("2.5")), Ok(Value::Real32(2.5)));
        assert_eq!(from(DataType::Real64, json!(3)), Ok(Value::Real64(3.0)));
        assert_eq!(from(DataType::Boolean, json!(1)), Ok(Value::Boolean(true)));
        assert_eq!(from(DataType::Boolean, json!(0)), Ok(Value::Boolean(false)));
        assert_eq!(
            from(DataType::Boolean, json!("true")),
            Ok(Value::Boolean(true))
        );
        for (data_type, bad) in [
            (DataType::Boolean, json!(2)),
            (DataType::Boolean, json!(null)),
            (DataType::Unsigned8, json!(256)),
            (DataType::Unsigned8, json!(-1)),
            (DataType::Unsigned8, json!(1.5)),
            (DataType::Unsigned8, json!([1])),
            (DataType::Unsigned8, json!("$NODEID")),
            (DataType::Integer64, json!("9223372036854775808")),
            (DataType::Real32, json!(1e39)),
            (DataType::Real32, json!(true)),
            (DataType::VisibleString, json!(5)),
            (DataType::OctetString, json!("not base64!")),
            (DataType::OctetString, json!([1, 2])),
            (
                DataType::TimeOfDay,
                json!({"ms": 0x1000_0000u32, "days": 0}),
            ),
            (DataType::Unknown(7), json!(1)),
        ] {
            assert!(from(data_type, bad.clone()).is_err(), "{data_type} {bad}");
        }
        let error = from(DataType::Unsigned8, json!(300)).unwrap_err();
        assert!(error.is_out_of_range());
    }

    #[test]
    fn limits_give_too_high_and_too_low() {
        let low = Value::Integer16(-10);
        let high = Value::Integer16(100);
        assert_eq!(
            Value::Integer16(0).check_limits(Some(&low), Some(&high)),
            Ok(())
        );
        assert_eq!(
            Value::Integer16(-10).check_limits(Some(&low), Some(&high)),
            Ok(())
        );
        assert_eq!(
            Value::Integer16(100).check_limits(Some(&low), Some(&high)),
            Ok(())
        );
        let too_high = Value::Integer16(101)
            .check_limits(Some(&low), Some(&high))
            .unwrap_err();
        assert_eq!(
            too_high,
            ValueError::TooHigh {
                value: "101".into(),
                high: "100".into()
            }
        );
        assert_eq!(too_high.sdo_abort_code(), 0x0609_0031);
        let too_low = Value::Integer16(-11)
            .check_limits(Some(&low), None)
            .unwrap_err();
        assert_eq!(too_low.sdo_abort_code(), 0x0609_0032);
        assert_eq!(too_low.to_string(), "-11 is below the low limit -10");
        assert!(
            Value::Real32(1.5)
                .check_limits(None, Some(&Value::Real32(1.0)))
                .is_err()
        );
        assert_eq!(
            Value::Unsigned64(u64::MAX).check_limits(None, Some(&Value::Unsigned64(u64::MAX))),
            Ok(())
        );
        // Strings have no limits.
        assert_eq!(
            Value::VisibleString("z".into()).check_limits(Some(&low), Some(&high)),
            Ok(())
        );
    }

    #[test]
    fn zero_and_conversions() {
        for data_type in DataType::ALL {
            let zero = Value::zero(data_type).unwrap();
            assert_eq!(zero.data_type(), data_type);
        }
        assert_eq!(Value::zero(DataType::Unknown(0x20)), None);
        assert_eq!(Value::Integer24(-3).as_i128(), Some(-3));
        assert_eq!(Value::Real32(0.5).as_f64(), Some(0.5));
        assert_eq!(Value::VisibleString("1".into()).as_f64(), None);
        assert!(Value::from_i128(DataType::Real32, 1).is_err());
        assert_eq!(
            TimeOfDay::from_raw(0xFFFF_FFFF_FFFF),
            TimeOfDay {
                ms: 0x0FFF_FFFF,
                days: 0xFFFF
            }
        );
    }
}
