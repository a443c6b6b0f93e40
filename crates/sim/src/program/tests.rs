use super::*;

/// The header is `CDKI`, a length of 1–64, that many printable ASCII bytes;
/// anything else is no header.
#[test]
fn the_image_header_names_a_version_or_is_not_one() {
    let mut image = ImageHeader::encode("1.2.3");
    assert_eq!(image, b"CDKI\x051.2.3");
    image.extend_from_slice(&[0xFF; 16]);
    assert_eq!(
        ImageHeader::parse(&image),
        Some(ImageHeader {
            version: "1.2.3".into()
        })
    );
    for bad in [
        &b""[..],
        b"CDKI",
        b"CDKI\x00",
        b"CDKI\x051.2",
        b"CDKX\x051.2.3",
        b"CDKI\x031\x002",
        b"CDKI\x41AAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAA",
    ] {
        assert_eq!(ImageHeader::parse(bad), None, "{bad:?}");
    }
}
