use super::*;

/// The check value of CRC-32/ISO-HDLC ("123456789"), the empty input, and
/// known values of short strings.
#[test]
fn crc32_matches_the_ieee_check_values() {
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    assert_eq!(crc32(b""), 0);
    assert_eq!(crc32(b"a"), 0xE8B7_BE43);
    assert_eq!(
        crc32(b"The quick brown fox jumps over the lazy dog"),
        0x414F_A339
    );
    assert_eq!(crc32(&[0u8; 32]), 0x190A_55AD);
}

/// Piece by piece gives the same as all at once, wherever the cut falls.
#[test]
fn crc32_in_pieces_is_crc32_at_once() {
    let data: Vec<u8> = (0..1000u32).map(|i| (i * 7 + 3) as u8).collect();
    for cut in [0, 1, 7, 500, 999, 1000] {
        let mut crc = Crc32::new();
        crc.update(&data[..cut]);
        crc.update(&data[cut..]);
        assert_eq!(crc.finish(), crc32(&data), "cut at {cut}");
    }
}
