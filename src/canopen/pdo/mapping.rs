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
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn entry(raw: u32) -> MappingEntry {
        MappingEntry::from_raw(raw)
    }

    #[test]
    fn entries_are_index_sub_and_length() {
        let statusword = entry(0x6041_0010);
        assert_eq!(statusword, MappingEntry::new(0x6041, 0x00, 16));
        assert_eq!(statusword.raw(), 0x6041_0010);
        assert_eq!(statusword.to_string(), "0x6041:00/16");
        let sub = entry(0x2001_0A08);
        assert_eq!((sub.index, sub.sub, sub.bits), (0x2001, 0x0A, 8));
        for raw in [0u32, 0xFFFF_FFFF, 0x1234_5678, 0x0007_0020] {
            assert_eq!(entry(raw).raw(), raw);
        }
        assert!(entry(0x0001_0001).is_dummy());
        assert!(entry(0x0007_0020).is_dummy());
        assert!(!entry(0x0008_0020).is_dummy());
        assert!(!entry(0x0000_0008).is_dummy());
    }

    #[test]
    fn a_mapping_is_validated() {
        let mapping = PdoMapping::from_raw(&[0x6041_0010, 0x6064_0020, 0x6061_0008]).unwrap();
        assert_eq!(mapping.len(), 3);
        assert_eq!(mapping.total_bits(), 56);
        assert_eq!(mapping.byte_len(), 7);
        assert_eq!(mapping.raw(), [0x6041_0010, 0x6064_0020, 0x6061_0008]);
        assert_eq!(
            mapping
                .layout()
                .map(|(_, offset)| offset)
                .collect::<Vec<_>>(),
            [0, 16, 48]
        );
        // Exactly 64 bits is fine; 65 is not.
        assert!(PdoMapping::from_raw(&[0x6064_0020, 0x606C_0020]).is_ok());
        let too_long = PdoMapping::from_raw(&[0x6064_0020, 0x606C_0020, 0x0001_0001]);
        assert_eq!(too_long, Err(MappingError::TooLong { bits: 65 }));
        assert_eq!(too_long.unwrap_err().abort_code(), 0x0604_0042);
        assert_eq!(
            PdoMapping::from_raw(&[0x2000_0041]),
            Err(MappingError::TooLong { bits: 65 })
        );
        assert_eq!(
            PdoMapping::from_raw(&[0x0001_0001; 65]),
            Err(MappingError::TooManyEntries(65))
        );
        assert_eq!(
            PdoMapping::from_raw(&[0x6041_0000]),
            Err(MappingError::ZeroLength(entry(0x6041_0000)))
        );
        assert_eq!(
            MappingError::ZeroLength(entry(0x6041_0000)).abort_code(),
            0x0604_0041
        );
        assert_eq!(
            PdoMapping::from_raw(&[0x0000_0008]),
            Err(MappingError::NoObject(entry(0x0000_0008)))
        );
        assert_eq!(
            PdoMapping::from_raw(&[0x0005_0108]),
            Err(MappingError::NoObject(entry(0x0005_0108)))
        );
        assert_eq!(
            MappingError::TooLong { bits: 72 }.to_string(),
            "the mapped objects take 72 bits, a PDO carries at most 64"
        );
        assert!(PdoMapping::empty().is_empty());
        assert_eq!(PdoMapping::empty().byte_len(), 0);
    }

    #[test]
    fn dummy_entries_are_allowed() {
        // 1 bit of BOOLEAN, a 7-bit gap of UNSIGNED8 type, then 16 bits.
        let mapping = PdoMapping::from_raw(&[0x2000_0101, 0x0005_0007, 0x6041_0010]).unwrap();
        assert_eq!(mapping.total_bits(), 24);
        let data = mapping.pack(&[1, 0, 0x1234]).unwrap();
        assert_eq!(data, [0x01, 0x34, 0x12]);
    }

    #[test]
    fn packing_is_byte_exact() {
        // Controlword 0x000F and target position -2 (INTEGER32).
        let mapping = PdoMapping::from_raw(&[0x6040_0010, 0x607A_0020]).unwrap();
        let data = mapping.pack(&[0x000F, (-2i32) as u32 as u64]).unwrap();
        assert_eq!(data, [0x0F, 0x00, 0xFE, 0xFF, 0xFF, 0xFF]);
        // Wider values are truncated: -2 as i64 packs the same.
        assert_eq!(mapping.pack(&[0x000F, (-2i64) as u64]).unwrap(), data);
        let frame = mapping
            .encode(CanId::Standard(0x201), &[0x000F, 0xFFFF_FFFE])
            .unwrap();
        assert_eq!(frame.to_string(), "201#0F00FEFFFFFF");

        // Bit fields across byte boundaries: 3, 12, 1 and 8 bits.
        let mapping =
            PdoMapping::from_raw(&[0x2000_0103, 0x2000_020C, 0x2000_0301, 0x2000_0408]).unwrap();
        let data = mapping.pack(&[0b101, 0xABC, 1, 0x5A]).unwrap();
        // bits 0-2 = 101, bits 3-14 = 0xABC, bit 15 = 1, bits 16-23 = 0x5A
        assert_eq!(data, [0xE5, 0xD5, 0x5A]);
        let values: Vec<u64> = mapping
            .unpack(&data)
            .unwrap()
            .iter()
            .map(|v| v.value)
            .collect();
        assert_eq!(values, [0b101, 0xABC, 1, 0x5A]);

        assert_eq!(
            mapping.pack(&[1, 2]),
            Err(PdoDataError::ValueCount {
                expected: 4,
                got: 2
            })
        );
    }

    #[test]
    fn unpacking_checks_the_length() {
        let mapping = PdoMapping::from_raw(&[0x6041_0010, 0x6064_0020]).unwrap();
        let values = mapping
            .unpack(&[0x37, 0x06, 0x10, 0x27, 0x00, 0x00])
            .unwrap();
        assert_eq!(
            values,
            [
                MappedValue {
                    entry: entry(0x6041_0010),
                    value: 0x0637
                },
                MappedValue {
                    entry: entry(0x6064_0020),
                    value: 10_000
                },
            ]
        );
        // Longer is fine: the first bytes are used.
        assert_eq!(
            mapping.unpack(&[0x37, 0x06, 0x10, 0x27, 0x00, 0x00, 0xFF, 0xFF]),
            Ok(values)
        );
        let short = mapping.unpack(&[0x37, 0x06, 0x10, 0x27, 0x00]);
        assert_eq!(
            short,
            Err(PdoDataError::TooShort {
                expected: 6,
                got: 5
            })
        );
        assert_eq!(short.unwrap_err().emcy_code(), Some(0x8210));
        assert_eq!(PdoMapping::empty().unpack(&[]), Ok(vec![]));
    }

    #[test]
    fn bit_fields_at_the_edges() {
        let mut data = [0u8; 8];
        write_bits(&mut data, 0, 64, 0x0123_4567_89AB_CDEF).unwrap();
        assert_eq!(data, [0xEF, 0xCD, 0xAB, 0x89, 0x67, 0x45, 0x23, 0x01]);
        assert_eq!(read_bits(&data, 0, 64), Ok(0x0123_4567_89AB_CDEF));
        assert_eq!(read_bits(&data, 63, 1), Ok(0));
        assert_eq!(read_bits(&data, 4, 8), Ok(0xDE));
        let mut data = [0u8; 9];
        write_bits(&mut data, 7, 64, u64::MAX).unwrap();
        assert_eq!(data, [0x80, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x7F]);
        assert_eq!(read_bits(&data, 7, 64), Ok(u64::MAX));
        assert_eq!(read_bits(&data, 0, 0), Err(BitsError::Width(0)));
        assert_eq!(read_bits(&data, 0, 65), Err(BitsError::Width(65)));
        assert_eq!(
            read_bits(&data, 66, 7),
            Err(BitsError::OutOfRange {
                offset: 66,
                width: 7,
                len: 9
            })
        );
        assert_eq!(
            write_bits(&mut data, u32::MAX, 64, 0),
            Err(BitsError::OutOfRange {
                offset: u32::MAX,
                width: 64,
                len: 9
            })
        );
        assert!(read_bits(&[], 0, 1).is_err());
    }

    #[test]
    fn sign_extension_of_any_width() {
        assert_eq!(sign_extend(0xFFFE, 16), -2);
        assert_eq!(sign_extend(0x7FFF, 16), 32767);
        assert_eq!(sign_extend(0x8000, 16), -32768);
        assert_eq!(sign_extend(0b1, 1), -1);
        assert_eq!(sign_extend(0b0, 1), 0);
        assert_eq!(sign_extend(0b100, 3), -4);
        assert_eq!(sign_extend(0x80_0000, 24), -8_388_608);
        assert_eq!(sign_extend(u64::MAX, 64), -1);
        // Bits above the width do not matter.
        assert_eq!(sign_extend(0xFFFF_0001, 16), 1);
        assert_eq!(sign_extend(0x1234, 0), 0);
        assert_eq!(sign_extend(5, 200), 5);
    }

    /// Fields of 1–64 bits whose widths add up to at most 64, each with a
    /// value.
    fn fields() -> impl Strategy<Value = Vec<(u8, u64)>> {
        prop::collection::vec((1u8..=64, any::<u64>()), 1..=16).prop_map(|mut fields| {
            let mut total = 0u32;
            fields.retain(|&(bits, _)| {
                total += u32::from(bits);
                total <= MAX_BITS
            });
            fields
        })
    }

    proptest! {
        #[test]
        fn a_field_reads_back_at_every_offset_and_width(
            width in 1u32..=64,
            offset in 0u32..=64,
            value: u64,
            background: [u8; 16],
        ) {
            let mut data = background;
            write_bits(&mut data, offset, width, value).unwrap();
            prop_assert_eq!(read_bits(&data, offset, width).unwrap(), value & low_bits(width));
            // Every bit outside the field is untouched.
            for bit in (0..128).filter(|bit| !(offset..offset + width).contains(bit)) {
                let before = background[bit as usize / 8] >> (bit % 8) & 1;
                let after = data[bit as usize / 8] >> (bit % 8) & 1;
                prop_assert_eq!(before, after, "bit {}", bit);
            }
        }

        #[test]
        fn fields_side_by_side_pack_and_unpack(fields in fields()) {
            let entries: Vec<_> = fields
                .iter()
                .enumerate()
                .map(|(i, &(bits, _))| MappingEntry::new(0x2000, i as u8 + 1, bits))
                .collect();
            let values: Vec<u64> = fields.iter().map(|&(_, value)| value).collect();
            let mapping = PdoMapping::new(entries).unwrap();
            let data = mapping.pack(&values).unwrap();
            prop_assert_eq!(data.len(), mapping.byte_len());
            let unpacked = mapping.unpack(&data).unwrap();
            for (got, &(bits, value)) in unpacked.iter().zip(&fields) {
                prop_assert_eq!(got.value, value & low_bits(u32::from(bits)));
            }
            // Packing the unpacked values gives the same bytes.
            let again: Vec<u64> = unpacked.iter().map(|v| v.value).collect();
            prop_assert_eq!(mapping.pack(&again).unwrap(), data);
        }

        #[test]
        fn signed_values_survive_packing(value: i64, width in 1u32..=64) {
            let min = if width == 64 { i64::MIN } else { -(1i64 << (width - 1)) };
            let max = if width == 64 { i64::MAX } else { (1i64 << (width - 1)) - 1 };
            let value = value.clamp(min, max);
            let mut data = [0u8; 9];
            write_bits(&mut data, 3, width, value as u64).unwrap();
            prop_assert_eq!(sign_extend(read_bits(&data, 3, width).unwrap(), width), value);
        }

        #[test]
        fn bit_access_never_panics(
            mut data in prop::collection::vec(any::<u8>(), 0..20),
            offset: u32,
            width: u32,
            value: u64,
        ) {
            let read = read_bits(&data, offset, width);
            let write = write_bits(&mut data, offset, width, value);
            prop_assert_eq!(read.is_ok(), write.is_ok());
            let _ = sign_extend(value, width);
        }

        #[test]
        fn mappings_never_panic(
            raw in prop::collection::vec(any::<u32>(), 0..70),
            data in prop::collection::vec(any::<u8>(), 0..10),
            values in prop::collection::vec(any::<u64>(), 0..10),
        ) {
            if let Ok(mapping) = PdoMapping::from_raw(&raw) {
                prop_assert!(mapping.total_bits() <= MAX_BITS);
                let _ = mapping.unpack(&data);
                let _ = mapping.pack(&values);
            }
        }

        #[test]
        fn small_mappings_of_real_entries_validate(
            raw in prop::collection::vec((0x1000u32..=0xFFFF, any::<u8>(), 1u32..=64), 0..5),
        ) {
            let raw: Vec<u32> = raw
                .iter()
                .map(|&(index, sub, bits)| MappingEntry::new(index as u16, sub, bits as u8).raw())
                .collect();
            let bits: u32 = raw.iter().map(|r| r & 0xFF).sum();
            prop_assert_eq!(PdoMapping::from_raw(&raw).is_ok(), bits <= MAX_BITS);
        }
    }
}
