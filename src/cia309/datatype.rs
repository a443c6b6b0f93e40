//! The data types of CiA 309-3 (§5.2, "Data types"; CiA 301 §7.1.2 for
//! the encodings): how a value written in a command becomes the bytes of an
//! SDO download, and how the bytes of an upload are written in a reply.
//!
//! The forms follow CANopenNode's gateway (`309/CO_gateway_ascii.c` and the
//! `CO_fifo_*2a` / `CO_fifo_cpyTok2*` functions of `301/CO_fifo.c`):
//! numbers are read as C's `strtoul`/`strtol` with base 0 (`0x1A` hex, `017`
//! octal, `26` decimal); `x8`..`x64` are written `0x` and upper-case hex
//! padded to the type's width; `r32`/`r64` as C's `%g`; `vs` between double
//! quotes with inner quotes doubled; `os`, `us` and `d` as one line of
//! base64 (RFC 2045, no line breaks); `hex` (and every read without a type)
//! as upper-case bytes separated by one space. Bytes whose length is not
//! the type's are written as `hex`, as CANopenNode does.
//!
//! Where we are stricter than CANopenNode (it lets `strtoul` wrap): a
//! negative number for an unsigned type and a number out of the type's
//! range are refused (syntax error) rather than truncated.

use base64::Engine;
use base64::engine::general_purpose::STANDARD as BASE64;

/// A CiA 309-3 data type, by its mnemonic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Datatype {
    /// `b`: BOOLEAN, one byte (written as a number, as CANopenNode does).
    Boolean,
    I8,
    I16,
    I32,
    I64,
    U8,
    U16,
    U32,
    U64,
    /// `x8`..`x64`: unsigned, written in hex (non-standard, CANopenNode's).
    X8,
    X16,
    X32,
    X64,
    R32,
    R64,
    /// `vs`: VISIBLE_STRING.
    VisibleString,
    /// `os`: OCTET_STRING, base64.
    OctetString,
    /// `us`: UNICODE_STRING, base64.
    UnicodeString,
    /// `d`: DOMAIN, base64.
    Domain,
    /// `hex`: raw bytes in hex (non-standard, CANopenNode's).
    Hex,
}

/// Why a value could not be read; the reply is a syntax error (101).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ValueError {
    #[error("missing value")]
    Missing,
    #[error("'{0}' is not a number")]
    NotANumber(String),
    #[error("{0} is out of the type's range")]
    OutOfRange(String),
    #[error("bad string: {0}")]
    BadString(&'static str),
    #[error("bad base64")]
    BadBase64,
    #[error("bad hex")]
    BadHex,
    #[error("text after the value")]
    Trailing,
}

impl Datatype {
    /// Every type, in the order of `help datatype`.
    pub const ALL: [Self; 20] = [
        Self::Boolean,
        Self::I8,
        Self::I16,
        Self::I32,
        Self::I64,
        Self::U8,
        Self::U16,
        Self::U32,
        Self::U64,
        Self::X8,
        Self::X16,
        Self::X32,
        Self::X64,
        Self::R32,
        Self::R64,
        Self::VisibleString,
        Self::OctetString,
        Self::UnicodeString,
        Self::Domain,
        Self::Hex,
    ];

    /// The mnemonic (`u16`).
    pub fn mnemonic(self) -> &'static str {
        match self {
            Self::Boolean => "b",
            Self::I8 => "i8",
            Self::I16 => "i16",
            Self::I32 => "i32",
            Self::I64 => "i64",
            Self::U8 => "u8",
            Self::U16 => "u16",
            Self::U32 => "u32",
            Self::U64 => "u64",
            Self::X8 => "x8",
            Self::X16 => "x16",
            Self::X32 => "x32",
            Self::X64 => "x64",
            Self::R32 => "r32",
            Self::R64 => "r64",
            Self::VisibleString => "vs",
            Self::OctetString => "os",
            Self::UnicodeString => "us",
            Self::Domain => "d",
            Self::Hex => "hex",
        }
    }

    /// The type of a mnemonic, case-insensitive (CANopenNode lowers it).
    pub fn from_mnemonic(text: &str) -> Option<Self> {
        let text = text.to_ascii_lowercase();
        Self::ALL.into_iter().find(|t| t.mnemonic() == text)
    }

    /// The size of a value of fixed size; `None` for strings and `hex`.
    pub fn size(self) -> Option<usize> {
        match self {
            Self::Boolean | Self::I8 | Self::U8 | Self::X8 => Some(1),
            Self::I16 | Self::U16 | Self::X16 => Some(2),
            Self::I32 | Self::U32 | Self::X32 | Self::R32 => Some(4),
            Self::I64 | Self::U64 | Self::X64 | Self::R64 => Some(8),
            _ => None,
        }
    }

    /// Whether the value is the rest of the line rather than one token
    /// (`vs` may be quoted with spaces; `hex` may be space separated).
    pub fn takes_rest_of_line(self) -> bool {
        matches!(self, Self::VisibleString | Self::Hex)
    }

    /// The bytes (little-endian, CiA 301 §7.1.2) of `text`, the value as
    /// the command wrote it: one token for numbers and base64, the rest of
    /// the line (comment removed, outer blanks trimmed) for `vs` and `hex`.
    pub fn encode(self, text: &str) -> Result<Vec<u8>, ValueError> {
        let text = text.trim_matches(|c| c == ' ' || c == '\t');
        if text.is_empty() {
            return Err(ValueError::Missing);
        }
        let bytes = match self {
            Self::Boolean | Self::U8 | Self::X8 => vec![unsigned(text, u8::MAX.into())? as u8],
            Self::U16 | Self::X16 => (unsigned(text, u16::MAX.into())? as u16)
                .to_le_bytes()
                .to_vec(),
            Self::U32 | Self::X32 => (unsigned(text, u32::MAX.into())? as u32)
                .to_le_bytes()
                .to_vec(),
            Self::U64 | Self::X64 => unsigned(text, u64::MAX)?.to_le_bytes().to_vec(),
            Self::I8 => vec![signed(text, i8::MIN.into(), i8::MAX.into())? as i8 as u8],
            Self::I16 => (signed(text, i16::MIN.into(), i16::MAX.into())? as i16)
                .to_le_bytes()
                .to_vec(),
            Self::I32 => (signed(text, i32::MIN.into(), i32::MAX.into())? as i32)
                .to_le_bytes()
                .to_vec(),
            Self::I64 => signed(text, i64::MIN, i64::MAX)?.to_le_bytes().to_vec(),
            Self::R32 => {
                let value = real(text)?;
                let narrowed = value as f32;
                if value.is_finite() && !narrowed.is_finite() {
                    return Err(ValueError::OutOfRange(text.to_string()));
                }
                narrowed.to_le_bytes().to_vec()
            }
            Self::R64 => real(text)?.to_le_bytes().to_vec(),
            Self::VisibleString => visible_string(text)?,
            Self::OctetString | Self::UnicodeString | Self::Domain => {
                if text.contains(char::is_whitespace) {
                    return Err(ValueError::Trailing);
                }
                BASE64.decode(text).map_err(|_| ValueError::BadBase64)?
            }
            Self::Hex => hex_bytes(text)?,
        };
        Ok(bytes)
    }

    /// How a reply writes `bytes` read as this type: the type's form when
    /// the length fits it, else `hex` (as CANopenNode does).
    pub fn format(self, bytes: &[u8]) -> String {
        if let Some(size) = self.size()
            && bytes.len() != size
        {
            return hex_text(bytes);
        }
        let le = |n: usize| -> u64 {
            let mut buf = [0u8; 8];
            buf[..n].copy_from_slice(&bytes[..n]);
            u64::from_le_bytes(buf)
        };
        match self {
            Self::Boolean | Self::U8 | Self::U16 | Self::U32 | Self::U64 => {
                le(bytes.len()).to_string()
            }
            Self::I8 => (bytes[0] as i8).to_string(),
            Self::I16 => (le(2) as u16 as i16).to_string(),
            Self::I32 => (le(4) as u32 as i32).to_string(),
            Self::I64 => (le(8) as i64).to_string(),
            Self::X8 => format!("0x{:02X}", bytes[0]),
            Self::X16 => format!("0x{:04X}", le(2)),
            Self::X32 => format!("0x{:08X}", le(4)),
            Self::X64 => format!("0x{:016X}", le(8)),
            Self::R32 => format_g(f32::from_bits(le(4) as u32).into()),
            Self::R64 => format_g(f64::from_bits(le(8))),
            Self::VisibleString => {
                let mut out = String::with_capacity(bytes.len() + 2);
                out.push('"');
                // NUL and CR are left out, a quote doubled (CANopenNode's
                // readVs2a): the reply stays one line a parser can undo.
                for &byte in bytes {
                    match byte {
                        0 | b'\r' => {}
                        b'"' => out.push_str("\"\""),
                        _ => out.push(char::from(byte)),
                    }
                }
                out.push('"');
                out
            }
            Self::OctetString | Self::UnicodeString | Self::Domain => BASE64.encode(bytes),
            Self::Hex => hex_text(bytes),
        }
    }
}

/// Bytes as CANopenNode's `hex`: `01 AB FF`.
pub fn hex_text(bytes: &[u8]) -> String {
    let mut out = String::with_capacity(bytes.len() * 3);
    for (at, byte) in bytes.iter().enumerate() {
        if at > 0 {
            out.push(' ');
        }
        out.push_str(&format!("{byte:02X}"));
    }
    out
}

/// The digits and radix of a C integer literal with base 0.
fn radix(text: &str) -> (&str, u32) {
    if let Some(hex) = text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        (hex, 16)
    } else if text.len() > 1 && text.starts_with('0') {
        (&text[1..], 8)
    } else {
        (text, 10)
    }
}

/// A whole token as `strtoul(text, &end, 0)` with `*end == '\0'`, at most
/// `max`; a sign is refused (strtoul would wrap `-1` around).
pub fn unsigned(text: &str, max: u64) -> Result<u64, ValueError> {
    let bad = || ValueError::NotANumber(text.to_string());
    let text_no_plus = text.strip_prefix('+').unwrap_or(text);
    let (digits, radix) = radix(text_no_plus);
    if digits.is_empty() || !digits.chars().all(|c| c.is_digit(radix)) {
        return Err(bad());
    }
    let value =
        u64::from_str_radix(digits, radix).map_err(|_| ValueError::OutOfRange(text.to_string()))?;
    if value > max {
        return Err(ValueError::OutOfRange(text.to_string()));
    }
    Ok(value)
}

/// A whole token as `strtol(text, &end, 0)`, within `min..=max`.
fn signed(text: &str, min: i64, max: i64) -> Result<i64, ValueError> {
    let (negative, rest) = match text.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, text.strip_prefix('+').unwrap_or(text)),
    };
    let (digits, radix) = radix(rest);
    if digits.is_empty() || !digits.chars().all(|c| c.is_digit(radix)) {
        return Err(ValueError::NotANumber(text.to_string()));
    }
    let magnitude = i128::from(
        u64::from_str_radix(digits, radix).map_err(|_| ValueError::OutOfRange(text.to_string()))?,
    );
    let value = if negative { -magnitude } else { magnitude };
    if value < i128::from(min) || value > i128::from(max) {
        return Err(ValueError::OutOfRange(text.to_string()));
    }
    Ok(value as i64)
}

/// A real as `strtod` reads it (decimal, exponent, `inf`, `nan`).
fn real(text: &str) -> Result<f64, ValueError> {
    text.parse::<f64>()
        .map_err(|_| ValueError::NotANumber(text.to_string()))
}

/// A `vs` value: between double quotes (a doubled quote is one quote; the
/// string may hold blanks), or one word without quotes.
fn visible_string(text: &str) -> Result<Vec<u8>, ValueError> {
    let Some(quoted) = text.strip_prefix('"') else {
        if text.contains(char::is_whitespace) {
            return Err(ValueError::Trailing);
        }
        return Ok(text.as_bytes().to_vec());
    };
    let mut out = Vec::new();
    let mut chars = quoted.chars().peekable();
    loop {
        match chars.next() {
            None => return Err(ValueError::BadString("no closing quote")),
            Some('"') if chars.peek() == Some(&'"') => {
                chars.next();
                out.push(b'"');
            }
            Some('"') => break,
            Some(c) => {
                let mut buf = [0u8; 4];
                out.extend_from_slice(c.encode_utf8(&mut buf).as_bytes());
            }
        }
    }
    if chars.any(|c| !c.is_whitespace()) {
        return Err(ValueError::Trailing);
    }
    Ok(out)
}

/// `hex` bytes: pairs of hex digits, blanks between bytes allowed.
fn hex_bytes(text: &str) -> Result<Vec<u8>, ValueError> {
    let mut out = Vec::new();
    for group in text.split([' ', '\t']).filter(|g| !g.is_empty()) {
        if group.len() % 2 != 0 || !group.chars().all(|c| c.is_ascii_hexdigit()) {
            return Err(ValueError::BadHex);
        }
        for at in (0..group.len()).step_by(2) {
            out.push(u8::from_str_radix(&group[at..at + 2], 16).map_err(|_| ValueError::BadHex)?);
        }
    }
    Ok(out)
}

/// C's `printf("%g", value)`: 6 significant digits, trailing zeros
/// removed, exponent form (`1e+06`, `1.5e-05`) when the exponent is below
/// -4 or at least 6.
pub fn format_g(value: f64) -> String {
    if value.is_nan() {
        return if value.is_sign_negative() {
            "-nan"
        } else {
            "nan"
        }
        .to_string();
    }
    if value.is_infinite() {
        return if value < 0.0 { "-inf" } else { "inf" }.to_string();
    }
    if value == 0.0 {
        return if value.is_sign_negative() { "-0" } else { "0" }.to_string();
    }
    const PRECISION: i32 = 6;
    // The exponent after rounding to 6 significant digits.
    let scientific = format!("{:.*e}", (PRECISION - 1) as usize, value);
    let (mantissa, exponent) = scientific
        .split_once('e')
        .unwrap_or((scientific.as_str(), "0"));
    let exponent: i32 = exponent.parse().unwrap_or(0);
    if !(-4..PRECISION).contains(&exponent) {
        let mantissa = strip_zeros(mantissa);
        let sign = if exponent < 0 { '-' } else { '+' };
        format!("{mantissa}e{sign}{:02}", exponent.abs())
    } else {
        let decimals = (PRECISION - 1 - exponent).max(0) as usize;
        strip_zeros(&format!("{value:.decimals$}")).to_string()
    }
}

fn strip_zeros(text: &str) -> &str {
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.')
    } else {
        text
    }
}

#[cfg(test)]
mod tests;
