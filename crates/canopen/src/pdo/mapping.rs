//! PDO mapping (CiA 301 §7.2.2.3, mapping parameters 0x1600–0x17FF and
//! 0x1A00–0x1BFF): which objects a PDO carries, and packing their values at
//! bit level.
//!
//! A mapping entry is a u32 0xIIIISSLL: object index, sub-index, length in
//! bits. The entries lie one after the other from bit 0 of the first byte,
//! each little-endian (least significant bit first), at any bit offset: a
//! 1-bit flag followed by a 16-bit value puts the value across three bytes.
//! Values are handed in and out as raw bit fields in a `u64`; what they mean
//! (signed, float, …) is the object dictionary's business, with
//! [`sign_extend`] for signed types of any width.

use std::fmt;

use super::{ABORT_NOT_MAPPABLE, ABORT_PDO_LENGTH, EMCY_PDO_LENGTH};
use crate::can::{CanId, Frame};

/// The most bits a (classic CAN) PDO carries.
pub const MAX_BITS: u32 = 64;
/// The most entries a mapping parameter has (sub-indexes 1 to 0x40).
pub const MAX_ENTRIES: usize = 64;

/// One mapping entry, 0xIIIISSLL.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct MappingEntry {
    pub index: u16,
    pub sub: u8,
    /// The length in bits.
    pub bits: u8,
}

impl MappingEntry {
    pub fn new(index: u16, sub: u8, bits: u8) -> Self {
        Self { index, sub, bits }
    }

    pub fn from_raw(raw: u32) -> Self {
        Self {
            index: (raw >> 16) as u16,
            sub: (raw >> 8) as u8,
            bits: raw as u8,
        }
    }

    pub fn raw(self) -> u32 {
        u32::from(self.index) << 16 | u32::from(self.sub) << 8 | u32::from(self.bits)
    }

    /// Whether this maps a data type (indexes 0x0001–0x0007: BOOLEAN to
    /// UNSIGNED32) rather than an object: a placeholder whose bits a receiver
    /// skips and a transmitter leaves as given.
    pub fn is_dummy(self) -> bool {
        (0x0001..=0x0007).contains(&self.index)
    }
}

impl fmt::Display for MappingEntry {
    /// `0x6041:00/16` (index, sub-index, bits).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X}:{:02X}/{}", self.index, self.sub, self.bits)
    }
}

/// Why a list of entries is not a valid mapping.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MappingError {
    #[error("the mapped objects take {bits} bits, a PDO carries at most 64")]
    TooLong { bits: u32 },
    #[error("{0} mapping entries, a PDO has at most 64")]
    TooManyEntries(usize),
    #[error("mapping entry {0} has no length")]
    ZeroLength(MappingEntry),
    #[error("mapping entry {0} maps no object (index 0, or a dummy with a sub-index)")]
    NoObject(MappingEntry),
}

impl MappingError {
    /// The SDO abort code a device answers with: 0x06040042 ("the number
    /// and length of the objects to be mapped would exceed the PDO length")
    /// for too much, 0x06040041 ("object cannot be mapped to the PDO") for
    /// an entry that maps nothing.
    pub fn abort_code(&self) -> u32 {
        match self {
            Self::TooLong { .. } | Self::TooManyEntries(_) => ABORT_PDO_LENGTH,
            Self::ZeroLength(_) | Self::NoObject(_) => ABORT_NOT_MAPPABLE,
        }
    }
}

/// Why values cannot be packed into, or unpacked from, a PDO.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PdoDataError {
    #[error("{got} values for a mapping of {expected} entries")]
    ValueCount { expected: usize, got: usize },
    #[error("a PDO of {got} bytes where the mapping needs {expected}")]
    TooShort { expected: usize, got: usize },
}

impl PdoDataError {
    /// The EMCY error code a device signals: 0x8210 (PDO not processed due
    /// to length error) for a PDO too short for its mapping.
    pub fn emcy_code(&self) -> Option<u16> {
        match self {
            Self::TooShort { .. } => Some(EMCY_PDO_LENGTH),
            Self::ValueCount { .. } => None,
        }
    }
}

/// One mapped object and its raw value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct MappedValue {
    pub entry: MappingEntry,
    /// The field's bits, zero-extended.
    pub value: u64,
}

/// A validated PDO mapping: at most 64 entries of 1 bit or more each, at
/// most 64 bits in all. Whether each object exists and may be mapped is the
/// object dictionary's to check.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Default)]
pub struct PdoMapping {
    entries: Vec<MappingEntry>,
}

impl PdoMapping {
    /// A mapping of nothing (sub 0 = 0: the PDO carries no data).
    pub fn empty() -> Self {
        Self::default()
    }

    pub fn new(entries: Vec<MappingEntry>) -> Result<Self, MappingError> {
        if entries.len() > MAX_ENTRIES {
            return Err(MappingError::TooManyEntries(entries.len()));
        }
        for &entry in &entries {
            if entry.bits == 0 {
                return Err(MappingError::ZeroLength(entry));
            }
            if entry.index == 0 || (entry.is_dummy() && entry.sub != 0) {
                return Err(MappingError::NoObject(entry));
            }
        }
        let bits = entries.iter().map(|entry| u32::from(entry.bits)).sum();
        if bits > MAX_BITS {
            return Err(MappingError::TooLong { bits });
        }
        Ok(Self { entries })
    }

    /// A mapping from the raw values of sub-indexes 1 to n.
    pub fn from_raw(raw: &[u32]) -> Result<Self, MappingError> {
        Self::new(raw.iter().copied().map(MappingEntry::from_raw).collect())
    }

    /// The raw values of sub-indexes 1 to n.
    pub fn raw(&self) -> Vec<u32> {
        self.entries.iter().map(|entry| entry.raw()).collect()
    }

    pub fn entries(&self) -> &[MappingEntry] {
        &self.entries
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    pub fn total_bits(&self) -> u32 {
        self.entries.iter().map(|entry| u32::from(entry.bits)).sum()
    }

    /// The bytes a PDO of this mapping has: the bits rounded up.
    pub fn byte_len(&self) -> usize {
        self.total_bits().div_ceil(8) as usize
    }

    /// Each entry with its bit offset in the PDO.
    pub fn layout(&self) -> impl Iterator<Item = (MappingEntry, u32)> + '_ {
        self.entries.iter().scan(0, |offset, &entry| {
            let at = *offset;
            *offset += u32::from(entry.bits);
            Some((entry, at))
        })
    }

    /// The PDO data for one value per entry (dummies included), each
    /// truncated to its width, so a negative value packs as its two's
    /// complement. Bits after the last entry are 0.
    pub fn pack(&self, values: &[u64]) -> Result<Vec<u8>, PdoDataError> {
        if values.len() != self.entries.len() {
            return Err(PdoDataError::ValueCount {
                expected: self.entries.len(),
                got: values.len(),
            });
        }
        let mut data = vec![0; self.byte_len()];
        for ((entry, offset), &value) in self.layout().zip(values) {
            write_bits(&mut data, offset, u32::from(entry.bits), value)
                .expect("a validated mapping fits its own bytes");
        }
        Ok(data)
    }

    /// The PDO frame on `cob_id` for one value per entry.
    pub fn encode(&self, cob_id: CanId, values: &[u64]) -> Result<Frame, PdoDataError> {
        let data = self.pack(values)?;
        Ok(Frame::new(cob_id, &data).expect("at most 8 bytes"))
    }

    /// Every entry's value (dummies included) from PDO data. Bytes beyond
    /// the mapping are ignored (CiA 301 uses the first ones); fewer bytes
    /// than the mapping needs are an error.
    pub fn unpack(&self, data: &[u8]) -> Result<Vec<MappedValue>, PdoDataError> {
        if data.len() < self.byte_len() {
            return Err(PdoDataError::TooShort {
                expected: self.byte_len(),
                got: data.len(),
            });
        }
        Ok(self
            .layout()
            .map(|(entry, offset)| MappedValue {
                entry,
                value: read_bits(data, offset, u32::from(entry.bits))
                    .expect("checked against the mapping's length"),
            })
            .collect())
    }
}

/// Why a bit field cannot be read or written.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BitsError {
    #[error("a field is 1 to 64 bits wide, not {0}")]
    Width(u32),
    #[error("a field of {width} bits at bit {offset} does not fit in {len} bytes")]
    OutOfRange { offset: u32, width: u32, len: usize },
}

/// The lowest `width` bits set.
fn low_bits(width: u32) -> u64 {
    if width >= 64 {
        u64::MAX
    } else {
        (1 << width) - 1
    }
}

/// The bytes a field covers, after checking it lies within `len` bytes.
fn field_bytes(len: usize, offset: u32, width: u32) -> Result<(usize, usize), BitsError> {
    if !(1..=64).contains(&width) {
        return Err(BitsError::Width(width));
    }
    let end = u64::from(offset) + u64::from(width);
    if end > len as u64 * 8 {
        return Err(BitsError::OutOfRange { offset, width, len });
    }
    Ok(((offset / 8) as usize, ((end - 1) / 8) as usize))
}

/// Reads the `width`-bit field (1–64) at bit `offset` of `data`, least
/// significant bit first, zero-extended.
pub fn read_bits(data: &[u8], offset: u32, width: u32) -> Result<u64, BitsError> {
    let (first, last) = field_bytes(data.len(), offset, width)?;
    // A 64-bit field at an odd offset spans 9 bytes: gather them in 128 bits.
    let gathered = data[first..=last]
        .iter()
        .rev()
        .fold(0u128, |acc, &byte| acc << 8 | u128::from(byte));
    Ok((gathered >> (offset % 8)) as u64 & low_bits(width))
}

/// Writes the low `width` bits (1–64) of `value` at bit `offset` of `data`,
/// least significant bit first; the bits around the field keep their value.
pub fn write_bits(data: &mut [u8], offset: u32, width: u32, value: u64) -> Result<(), BitsError> {
    let (first, last) = field_bytes(data.len(), offset, width)?;
    let shift = offset % 8;
    let mask = u128::from(low_bits(width)) << shift;
    let bits = u128::from(value & low_bits(width)) << shift;
    for (i, byte) in data[first..=last].iter_mut().enumerate() {
        let byte_mask = (mask >> (8 * i)) as u8;
        let byte_bits = (bits >> (8 * i)) as u8;
        *byte = (*byte & !byte_mask) | byte_bits;
    }
    Ok(())
}

/// A `width`-bit two's complement field as a signed value: bit `width - 1`
/// is the sign. Widths of 64 or more take the value as it is; 0 gives 0.
pub fn sign_extend(value: u64, width: u32) -> i64 {
    match width {
        0 => 0,
        64.. => value as i64,
        _ => {
            let unused = 64 - width;
            ((value << unused) as i64) >> unused
        }
    }
}

#[cfg(test)]
mod tests;
