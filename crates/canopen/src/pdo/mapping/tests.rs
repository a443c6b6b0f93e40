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
