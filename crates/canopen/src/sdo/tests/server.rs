//! The server alone, against scripted client frames, byte for byte.

use super::*;
use crate::sdo::ServerConfig;
use crate::sdo::wire::crc16;

fn config() -> ServerConfig {
    ServerConfig {
        timeout: TIMEOUT,
        ..ServerConfig::default()
    }
}

struct Fixture {
    server: SdoServer,
    objects: Objects,
    t0: Instant,
}

impl Fixture {
    fn new() -> Self {
        Self::with(config())
    }

    fn with(config: ServerConfig) -> Self {
        Self {
            server: SdoServer::new(node(), config),
            objects: Objects::new(),
            t0: Instant::now(),
        }
    }

    /// Sends one request at `t0` and gives the answer's bytes.
    fn send(&mut self, data: [u8; 8]) -> Vec<[u8; 8]> {
        self.send_frame(&req(data))
    }

    fn send_frame(&mut self, frame: &Frame) -> Vec<[u8; 8]> {
        let answer = self.server.handle_frame(frame, self.t0, &mut self.objects);
        answer
            .iter()
            .map(|f| {
                assert_eq!(f.id(), CanId::Standard(0x585));
                f.data().try_into().unwrap()
            })
            .collect()
    }

    fn set(&mut self, index: u16, sub: u8, value: &[u8]) {
        self.objects.entries.get_mut(&(index, sub)).unwrap().value = value.to_vec();
    }
}

#[test]
fn expedited_upload_of_one_to_four_bytes() {
    let mut f = Fixture::new();
    for (len, command) in [(1, 0x4F), (2, 0x4B), (3, 0x47), (4, 0x43)] {
        f.set(0x2000, 0, &[0xA1, 0xB2, 0xC3, 0xD4][..len]);
        let mut expected = [command, 0x00, 0x20, 0x00, 0, 0, 0, 0];
        expected[4..4 + len].copy_from_slice(&[0xA1, 0xB2, 0xC3, 0xD4][..len]);
        assert_eq!(f.send([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]), vec![expected]);
        assert!(f.server.is_idle());
        assert_eq!(f.server.deadline(), None);
    }
}

#[test]
fn segmented_upload_of_seven_eight_and_twenty_bytes() {
    let mut f = Fixture::new();
    let up = |toggle: bool| [if toggle { 0x70 } else { 0x60 }, 0, 0, 0, 0, 0, 0, 0];

    let value = counting(7);
    f.set(0x2000, 0, &value);
    assert_eq!(
        f.send([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]),
        vec![[0x41, 0x00, 0x20, 0x00, 7, 0, 0, 0]]
    );
    assert_eq!(f.server.deadline(), Some(f.t0 + TIMEOUT));
    assert_eq!(f.send(up(false)), vec![seg(0x01, seven(&value, 0))]);
    assert!(f.server.is_idle());

    let value = counting(8);
    f.set(0x2000, 0, &value);
    assert_eq!(
        f.send([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]),
        vec![[0x41, 0x00, 0x20, 0x00, 8, 0, 0, 0]]
    );
    assert_eq!(f.send(up(false)), vec![seg(0x00, seven(&value, 0))]);
    assert_eq!(f.send(up(true)), vec![seg(0x1D, seven(&value, 7))]);
    assert!(f.server.is_idle());

    let value = counting(20);
    f.set(0x2000, 0, &value);
    assert_eq!(
        f.send([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]),
        vec![[0x41, 0x00, 0x20, 0x00, 20, 0, 0, 0]]
    );
    assert_eq!(f.send(up(false)), vec![seg(0x00, seven(&value, 0))]);
    assert_eq!(f.send(up(true)), vec![seg(0x10, seven(&value, 7))]);
    assert_eq!(f.send(up(false)), vec![seg(0x03, seven(&value, 14))]);
    assert!(f.server.is_idle());
}

#[test]
fn an_empty_value_uploads_as_one_empty_segment() {
    let mut f = Fixture::new();
    assert_eq!(
        f.send([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]),
        vec![[0x41, 0x00, 0x20, 0x00, 0, 0, 0, 0]]
    );
    assert_eq!(
        f.send([0x60, 0, 0, 0, 0, 0, 0, 0]),
        vec![[0x0F, 0, 0, 0, 0, 0, 0, 0]]
    );
    assert!(f.server.is_idle());
}

#[test]
fn expedited_download_with_and_without_size() {
    let mut f = Fixture::new();
    // Size indicated: 2 bytes into the UNSIGNED16.
    assert_eq!(
        f.send([0x2B, 0x02, 0x20, 0x00, 0x34, 0x12, 0xEE, 0xEE]),
        vec![[0x60, 0x02, 0x20, 0x00, 0, 0, 0, 0]]
    );
    assert_eq!(f.objects.value(0x2002, 0), &[0x34, 0x12]);
    // Not indicated: the object's fixed size cuts the four bytes.
    assert_eq!(
        f.send([0x22, 0x01, 0x20, 0x00, 0x7B, 0xEE, 0xEE, 0xEE]),
        vec![[0x60, 0x01, 0x20, 0x00, 0, 0, 0, 0]]
    );
    assert_eq!(f.objects.value(0x2001, 0), &[0x7B]);
    // Not indicated, no fixed size: all four.
    assert_eq!(
        f.send([0x22, 0x00, 0x20, 0x00, 1, 2, 3, 4]),
        vec![[0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0]]
    );
    assert_eq!(f.objects.value(0x2000, 0), &[1, 2, 3, 4]);
    // Each length 1 to 4.
    for (len, command) in [(1u8, 0x2F), (2, 0x2B), (3, 0x27), (4, 0x23)] {
        f.send([command, 0x00, 0x20, 0x00, 9, 8, 7, 6]);
        assert_eq!(
            f.objects.value(0x2000, 0),
            &[9, 8, 7, 6][..usize::from(len)]
        );
    }
    assert!(f.server.is_idle());
}

#[test]
fn segmented_download_of_seven_eight_twenty_and_zero_bytes() {
    let mut f = Fixture::new();
    let ok = [0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0];
    let seg_ok = |toggle: bool| [if toggle { 0x30 } else { 0x20 }, 0, 0, 0, 0, 0, 0, 0];

    let value = counting(7);
    assert_eq!(f.send([0x21, 0x00, 0x20, 0x00, 7, 0, 0, 0]), vec![ok]);
    assert_eq!(f.send(seg(0x01, seven(&value, 0))), vec![seg_ok(false)]);
    assert_eq!(f.objects.value(0x2000, 0), &value[..]);

    let value = counting(8);
    assert_eq!(f.send([0x21, 0x00, 0x20, 0x00, 8, 0, 0, 0]), vec![ok]);
    assert_eq!(f.send(seg(0x00, seven(&value, 0))), vec![seg_ok(false)]);
    assert_eq!(f.send(seg(0x1D, seven(&value, 7))), vec![seg_ok(true)]);
    assert_eq!(f.objects.value(0x2000, 0), &value[..]);

    let value = counting(20);
    assert_eq!(f.send([0x21, 0x00, 0x20, 0x00, 20, 0, 0, 0]), vec![ok]);
    assert_eq!(f.send(seg(0x00, seven(&value, 0))), vec![seg_ok(false)]);
    assert_eq!(f.send(seg(0x10, seven(&value, 7))), vec![seg_ok(true)]);
    assert_eq!(
        f.objects.value(0x2000, 0),
        &counting(8)[..],
        "written only at the end"
    );
    assert_eq!(f.send(seg(0x03, seven(&value, 14))), vec![seg_ok(false)]);
    assert_eq!(f.objects.value(0x2000, 0), &value[..]);

    assert_eq!(f.send([0x21, 0x00, 0x20, 0x00, 0, 0, 0, 0]), vec![ok]);
    assert_eq!(f.send([0x0F, 0, 0, 0, 0, 0, 0, 0]), vec![seg_ok(false)]);
    assert_eq!(f.objects.value(0x2000, 0), &[] as &[u8]);

    // Size not indicated, as python-canopen sends when it does not know.
    assert_eq!(f.send([0x20, 0x00, 0x20, 0x00, 0, 0, 0, 0]), vec![ok]);
    assert_eq!(f.send(seg(0x00, seven(&value, 0))), vec![seg_ok(false)]);
    assert_eq!(f.send(seg(0x19, [1, 2, 3, 0, 0, 0, 0])), vec![seg_ok(true)]);
    assert_eq!(f.objects.value(0x2000, 0), &[0, 1, 2, 3, 4, 5, 6, 1, 2, 3]);
    assert!(f.server.is_idle());
}

#[test]
fn refusals_come_at_initiate_with_the_objects_multiplexer() {
    let mut f = Fixture::new();
    let cases = [
        // Upload of a missing object, a missing sub-index, a write-only one.
        (
            [0x40, 0xFF, 0x2F, 0x00, 0, 0, 0, 0],
            abort_bytes(0x2FFF, 0, AbortCode::ObjectDoesNotExist),
        ),
        (
            [0x40, 0x00, 0x20, 0x07, 0, 0, 0, 0],
            abort_bytes(0x2000, 7, AbortCode::SubIndexDoesNotExist),
        ),
        (
            [0x40, 0x03, 0x20, 0x00, 0, 0, 0, 0],
            abort_bytes(0x2003, 0, AbortCode::WriteOnlyObject),
        ),
        // Downloads to a read-only object, each kind.
        (
            [0x23, 0x00, 0x10, 0x00, 1, 2, 3, 4],
            abort_bytes(0x1000, 0, AbortCode::ReadOnlyObject),
        ),
        (
            [0x21, 0x08, 0x10, 0x00, 30, 0, 0, 0],
            abort_bytes(0x1008, 0, AbortCode::ReadOnlyObject),
        ),
        (
            [0xC6, 0x08, 0x10, 0x00, 30, 0, 0, 0],
            abort_bytes(0x1008, 0, AbortCode::ReadOnlyObject),
        ),
        // A size the object cannot take, indicated at initiate.
        (
            [0x21, 0x02, 0x20, 0x00, 4, 0, 0, 0],
            abort_bytes(0x2002, 0, AbortCode::LengthTooHigh),
        ),
        (
            [0x2F, 0x02, 0x20, 0x00, 4, 0, 0, 0],
            abort_bytes(0x2002, 0, AbortCode::LengthTooLow),
        ),
        // Block upload of a missing object.
        (
            [0xA4, 0xFF, 0x2F, 0x00, 127, 0, 0, 0],
            abort_bytes(0x2FFF, 0, AbortCode::ObjectDoesNotExist),
        ),
    ];
    for (request, abort) in cases {
        assert_eq!(f.send(request), vec![abort], "{request:02X?}");
        assert!(f.server.is_idle());
    }
    assert!(f.objects.writes.is_empty());
}

#[test]
fn downloads_longer_or_shorter_than_indicated_abort() {
    let mut f = Fixture::new();
    f.send([0x21, 0x00, 0x20, 0x00, 4, 0, 0, 0]);
    assert_eq!(
        f.send(seg(0x00, [1; 7])),
        vec![abort_bytes(0x2000, 0, AbortCode::LengthTooHigh)]
    );
    assert!(f.server.is_idle());

    f.send([0x21, 0x00, 0x20, 0x00, 10, 0, 0, 0]);
    assert_eq!(
        f.send(seg(0x01, [1; 7])),
        vec![abort_bytes(0x2000, 0, AbortCode::LengthTooLow)]
    );
    assert!(f.objects.writes.is_empty());
}

#[test]
fn downloads_beyond_the_memory_limit_abort_with_0x05040005() {
    let mut f = Fixture::with(ServerConfig {
        max_size: 10,
        ..config()
    });
    assert_eq!(
        f.send([0x21, 0x00, 0x20, 0x00, 11, 0, 0, 0]),
        vec![abort_bytes(0x2000, 0, AbortCode::OutOfMemory)]
    );
    assert_eq!(
        f.send([0xC2, 0x00, 0x20, 0x00, 11, 0, 0, 0]),
        vec![abort_bytes(0x2000, 0, AbortCode::OutOfMemory)]
    );
    // Without a size, the data itself hits the limit.
    f.send([0x20, 0x00, 0x20, 0x00, 0, 0, 0, 0]);
    f.send(seg(0x00, [1; 7]));
    assert_eq!(
        f.send(seg(0x10, [1; 7])),
        vec![abort_bytes(0x2000, 0, AbortCode::OutOfMemory)]
    );
}

#[test]
fn a_wrong_toggle_bit_aborts_with_0x05030000() {
    let mut f = Fixture::new();
    f.send([0x21, 0x00, 0x20, 0x00, 20, 0, 0, 0]);
    f.send(seg(0x00, [1; 7]));
    assert_eq!(
        f.send(seg(0x00, [1; 7])),
        vec![abort_bytes(0x2000, 0, AbortCode::ToggleBitNotAlternated)]
    );
    assert!(f.server.is_idle());

    f.set(0x2000, 0, &counting(20));
    f.send([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]);
    assert_eq!(
        f.send([0x70, 0, 0, 0, 0, 0, 0, 0]),
        vec![abort_bytes(0x2000, 0, AbortCode::ToggleBitNotAlternated)]
    );
}

#[test]
fn unknown_or_unexpected_requests_abort_with_0x05040001() {
    let mut f = Fixture::new();
    // ccs 7 does not exist.
    assert_eq!(
        f.send([0xE0, 0x00, 0x20, 0x00, 0, 0, 0, 0]),
        vec![abort_bytes(0, 0, AbortCode::InvalidCommandSpecifier)]
    );
    // Segments, block acknowledgements and ends with no transfer running.
    for request in [
        [0x00, 1, 2, 3, 4, 5, 6, 7],
        [0x60, 0, 0, 0, 0, 0, 0, 0],
        [0xA3, 0, 0, 0, 0, 0, 0, 0],
        [0xA2, 1, 127, 0, 0, 0, 0, 0],
        [0xC1, 0, 0, 0, 0, 0, 0, 0],
    ] {
        assert_eq!(
            f.send(request),
            vec![abort_bytes(0, 0, AbortCode::InvalidCommandSpecifier)],
            "{request:02X?}"
        );
    }
    // A new initiate in the middle of a transfer ends that transfer.
    f.set(0x2000, 0, &counting(20));
    f.send([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]);
    assert_eq!(
        f.send([0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0]),
        vec![abort_bytes(0x2000, 0, AbortCode::InvalidCommandSpecifier)]
    );
    assert!(f.server.is_idle());
    // A download segment in an upload.
    f.send([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]);
    assert_eq!(
        f.send([0x00, 0, 0, 0, 0, 0, 0, 0]),
        vec![abort_bytes(0x2000, 0, AbortCode::InvalidCommandSpecifier)]
    );
}

#[test]
fn frames_not_eight_bytes_long_are_aborted() {
    let mut f = Fixture::new();
    for len in [0usize, 1, 3, 4, 7] {
        let frame = Frame::new(
            CanId::Standard(0x605),
            &[0x40, 0x00, 0x20, 0x00, 0, 0, 0][..len],
        )
        .unwrap();
        assert_eq!(
            f.send_frame(&frame),
            vec![abort_bytes(0, 0, AbortCode::InvalidCommandSpecifier)],
            "{len}"
        );
    }
    // In a transfer, the abort names it and ends it.
    f.set(0x2000, 0, &counting(20));
    f.send([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]);
    let frame = Frame::new(CanId::Standard(0x605), &[0x60]).unwrap();
    assert_eq!(
        f.send_frame(&frame),
        vec![abort_bytes(0x2000, 0, AbortCode::InvalidCommandSpecifier)]
    );
    assert!(f.server.is_idle());
}

#[test]
fn a_client_abort_ends_the_transfer_silently() {
    let mut f = Fixture::new();
    f.send([0x21, 0x00, 0x20, 0x00, 20, 0, 0, 0]);
    f.send(seg(0x00, [1; 7]));
    assert_eq!(
        f.send(abort_bytes(0x2000, 0, AbortCode::GeneralError)),
        Vec::<[u8; 8]>::new()
    );
    assert!(f.server.is_idle());
    assert_eq!(f.server.deadline(), None);
    assert!(f.objects.writes.is_empty());
    // Even a short one; and one with no transfer at all.
    f.send([0x21, 0x00, 0x20, 0x00, 20, 0, 0, 0]);
    assert_eq!(
        f.send_frame(&Frame::new(CanId::Standard(0x605), &[0x80]).unwrap()),
        Vec::<[u8; 8]>::new()
    );
    assert!(f.server.is_idle());
    assert_eq!(
        f.send(abort_bytes(0, 0, AbortCode::TimedOut)),
        Vec::<[u8; 8]>::new()
    );
    // Inside a block download.
    f.send([0xC6, 0x00, 0x20, 0x00, 30, 0, 0, 0]);
    f.send(seg(0x01, [1; 7]));
    assert_eq!(
        f.send(abort_bytes(0x2000, 0, AbortCode::GeneralError)),
        Vec::<[u8; 8]>::new()
    );
    assert!(f.server.is_idle());
    // The next request is served.
    assert_eq!(
        f.send([0x40, 0x01, 0x10, 0x00, 0, 0, 0, 0]),
        vec![[0x4F, 0x01, 0x10, 0x00, 0, 0, 0, 0]]
    );
}

#[test]
fn a_stalled_transfer_times_out_with_0x05040000() {
    let mut f = Fixture::new();
    let t0 = f.t0;
    f.set(0x2000, 0, &counting(20));
    f.send([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]);
    assert_eq!(f.server.deadline(), Some(t0 + TIMEOUT));
    assert_eq!(f.server.handle_timeout(t0 + ms(999)), Vec::new());
    assert_eq!(
        f.server.handle_timeout(t0 + ms(1000)),
        vec![resp(abort_bytes(0x2000, 0, AbortCode::TimedOut))]
    );
    assert!(f.server.is_idle());
    assert_eq!(f.server.deadline(), None);
    assert_eq!(f.server.handle_timeout(t0 + ms(9000)), Vec::new());
    // The late request finds no transfer.
    assert_eq!(
        f.send([0x60, 0, 0, 0, 0, 0, 0, 0]),
        vec![abort_bytes(0, 0, AbortCode::InvalidCommandSpecifier)]
    );
}

#[test]
fn foreign_frames_are_ignored() {
    let mut f = Fixture::new();
    for frame in [
        resp([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0]),
        Frame::new(
            CanId::Standard(0x606),
            &[0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0],
        )
        .unwrap(),
        Frame::new(
            CanId::Extended(0x605),
            &[0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0],
        )
        .unwrap(),
        Frame::remote(CanId::Standard(0x605), 8).unwrap(),
    ] {
        assert_eq!(f.send_frame(&frame), Vec::<[u8; 8]>::new(), "{frame}");
    }
    let mut server =
        SdoServer::with_cob_ids(CanId::Standard(0x641), CanId::Standard(0x5C1), config());
    let frame = Frame::new(
        CanId::Standard(0x641),
        &[0x40, 0x01, 0x10, 0x00, 0, 0, 0, 0],
    )
    .unwrap();
    let answer = server.handle_frame(&frame, f.t0, &mut f.objects);
    assert_eq!(answer[0].id(), CanId::Standard(0x5C1));
}

#[test]
fn block_download_of_twenty_bytes() {
    let mut f = Fixture::new();
    let value = counting(20);
    let [lo, hi] = crc16(&value).to_le_bytes();
    assert_eq!(
        f.send([0xC6, 0x00, 0x20, 0x00, 20, 0, 0, 0]),
        vec![[0xA4, 0x00, 0x20, 0x00, 127, 0, 0, 0]]
    );
    assert_eq!(f.send(seg(0x01, seven(&value, 0))), Vec::<[u8; 8]>::new());
    assert_eq!(f.send(seg(0x02, seven(&value, 7))), Vec::<[u8; 8]>::new());
    assert_eq!(
        f.send(seg(0x83, seven(&value, 14))),
        vec![[0xA2, 3, 127, 0, 0, 0, 0, 0]]
    );
    assert_eq!(
        f.send([0xC5, lo, hi, 0, 0, 0, 0, 0]),
        vec![[0xA1, 0, 0, 0, 0, 0, 0, 0]]
    );
    assert_eq!(f.objects.value(0x2000, 0), &value[..]);
    assert!(f.server.is_idle());
}

#[test]
fn block_download_with_blocks_of_one_segment() {
    let mut f = Fixture::with(ServerConfig {
        block_size: 1,
        ..config()
    });
    let value = counting(15);
    let [lo, hi] = crc16(&value).to_le_bytes();
    assert_eq!(
        f.send([0xC6, 0x00, 0x20, 0x00, 15, 0, 0, 0]),
        vec![[0xA4, 0x00, 0x20, 0x00, 1, 0, 0, 0]]
    );
    assert_eq!(
        f.send(seg(0x01, seven(&value, 0))),
        vec![[0xA2, 1, 1, 0, 0, 0, 0, 0]]
    );
    assert_eq!(
        f.send(seg(0x01, seven(&value, 7))),
        vec![[0xA2, 1, 1, 0, 0, 0, 0, 0]]
    );
    assert_eq!(
        f.send(seg(0x81, seven(&value, 14))),
        vec![[0xA2, 1, 1, 0, 0, 0, 0, 0]]
    );
    assert_eq!(
        f.send([0xC1 | 6 << 2, lo, hi, 0, 0, 0, 0, 0]),
        vec![[0xA1, 0, 0, 0, 0, 0, 0, 0]]
    );
    assert_eq!(f.objects.value(0x2000, 0), &value[..]);
}

#[test]
fn block_download_last_segment_of_one_to_seven_bytes_and_its_crc() {
    for last in 1..=7usize {
        let value = counting(7 + last);
        let n = (7 - last) as u8;
        let [lo, hi] = crc16(&value).to_le_bytes();
        // Right CRC.
        let mut f = Fixture::new();
        f.send([0xC6, 0x00, 0x20, 0x00, value.len() as u8, 0, 0, 0]);
        f.send(seg(0x01, seven(&value, 0)));
        assert_eq!(
            f.send(seg(0x82, seven(&value, 7))),
            vec![[0xA2, 2, 127, 0, 0, 0, 0, 0]]
        );
        assert_eq!(
            f.send([0xC1 | n << 2, lo, hi, 0, 0, 0, 0, 0]),
            vec![[0xA1, 0, 0, 0, 0, 0, 0, 0]]
        );
        assert_eq!(f.objects.value(0x2000, 0), &value[..], "{last}");
        // Wrong CRC.
        let mut f = Fixture::new();
        f.send([0xC6, 0x00, 0x20, 0x00, value.len() as u8, 0, 0, 0]);
        f.send(seg(0x01, seven(&value, 0)));
        f.send(seg(0x82, seven(&value, 7)));
        assert_eq!(
            f.send([0xC1 | n << 2, lo ^ 0x01, hi, 0, 0, 0, 0, 0]),
            vec![abort_bytes(0x2000, 0, AbortCode::CrcError)]
        );
        assert!(f.objects.writes.is_empty());
        assert!(f.server.is_idle());
    }
}

#[test]
fn block_download_without_crc_or_size() {
    let mut f = Fixture::new();
    // cc = 0: the server offers none, and ignores the CRC bytes of the end.
    assert_eq!(
        f.send([0xC0, 0x00, 0x20, 0x00, 0, 0, 0, 0]),
        vec![[0xA0, 0x00, 0x20, 0x00, 127, 0, 0, 0]]
    );
    f.send(seg(0x81, [5, 6, 0, 0, 0, 0, 0]));
    assert_eq!(
        f.send([0xC1 | 5 << 2, 0, 0, 0, 0, 0, 0, 0]),
        vec![[0xA1, 0, 0, 0, 0, 0, 0, 0]]
    );
    assert_eq!(f.objects.value(0x2000, 0), &[5, 6]);
    // A server configured without CRC does not check it either.
    let mut f = Fixture::with(ServerConfig {
        crc: false,
        ..config()
    });
    assert_eq!(
        f.send([0xC4, 0x00, 0x20, 0x00, 0, 0, 0, 0]),
        vec![[0xA0, 0x00, 0x20, 0x00, 127, 0, 0, 0]]
    );
    f.send(seg(0x81, [5, 6, 0, 0, 0, 0, 0]));
    assert_eq!(
        f.send([0xC1 | 5 << 2, 0xAB, 0xCD, 0, 0, 0, 0, 0]),
        vec![[0xA1, 0, 0, 0, 0, 0, 0, 0]]
    );
}

#[test]
fn block_download_acknowledges_the_last_segment_before_a_gap() {
    let mut f = Fixture::with(ServerConfig {
        block_size: 4,
        ..config()
    });
    let value = counting(35);
    f.send([0xC6, 0x00, 0x20, 0x00, 35, 0, 0, 0]);
    f.send(seg(0x01, seven(&value, 0)));
    // Segment 2 is lost: 3 is dropped, and 4 ends the block with ack 1.
    assert_eq!(f.send(seg(0x03, seven(&value, 14))), Vec::<[u8; 8]>::new());
    assert_eq!(
        f.send(seg(0x04, seven(&value, 21))),
        vec![[0xA2, 1, 4, 0, 0, 0, 0, 0]]
    );
    // The client resends from segment 2, numbering from 1.
    f.send(seg(0x01, seven(&value, 7)));
    f.send(seg(0x02, seven(&value, 14)));
    f.send(seg(0x03, seven(&value, 21)));
    assert_eq!(
        f.send(seg(0x84, seven(&value, 28))),
        vec![[0xA2, 4, 4, 0, 0, 0, 0, 0]]
    );
    let [lo, hi] = crc16(&value).to_le_bytes();
    assert_eq!(
        f.send([0xC1, lo, hi, 0, 0, 0, 0, 0]),
        vec![[0xA1, 0, 0, 0, 0, 0, 0, 0]]
    );
    assert_eq!(f.objects.value(0x2000, 0), &value[..]);
}

#[test]
fn block_download_rejects_impossible_sequence_numbers() {
    for first in [0x00, 0x05, 0x7F, 0x85] {
        let mut f = Fixture::with(ServerConfig {
            block_size: 4,
            ..config()
        });
        f.send([0xC6, 0x00, 0x20, 0x00, 30, 0, 0, 0]);
        assert_eq!(
            f.send(seg(first, [0; 7])),
            vec![abort_bytes(0x2000, 0, AbortCode::InvalidSequenceNumber)],
            "{first:02X}"
        );
        assert!(f.server.is_idle());
    }
}

#[test]
fn block_download_must_match_its_indicated_size() {
    let mut f = Fixture::new();
    f.send([0xC6, 0x00, 0x20, 0x00, 7, 0, 0, 0]);
    f.send(seg(0x01, [1; 7]));
    assert_eq!(
        f.send(seg(0x02, [1; 7])),
        vec![abort_bytes(0x2000, 0, AbortCode::LengthTooHigh)]
    );

    let mut f = Fixture::new();
    f.send([0xC6, 0x00, 0x20, 0x00, 7, 0, 0, 0]);
    f.send(seg(0x81, [1; 7]));
    let crc = crc16(&[1; 6]).to_le_bytes();
    assert_eq!(
        f.send([0xC1 | 1 << 2, crc[0], crc[1], 0, 0, 0, 0, 0]),
        vec![abort_bytes(0x2000, 0, AbortCode::LengthTooLow)]
    );
    // Something other than the end request after the last segment.
    let mut f = Fixture::new();
    f.send([0xC6, 0x00, 0x20, 0x00, 7, 0, 0, 0]);
    f.send(seg(0x81, [1; 7]));
    assert_eq!(
        f.send(seg(0x01, [1; 7])),
        vec![abort_bytes(0x2000, 0, AbortCode::InvalidCommandSpecifier)]
    );
}

#[test]
fn block_download_rescues_a_lost_final_segment_on_the_sub_block_timeout() {
    let mut f = Fixture::with(ServerConfig {
        block_size: 4,
        ..config()
    });
    let t0 = f.t0;
    f.send([0xC6, 0x00, 0x20, 0x00, 30, 0, 0, 0]);
    assert_eq!(f.server.deadline(), Some(t0 + TIMEOUT));
    f.send(seg(0x01, [1; 7]));
    f.send(seg(0x02, [2; 7]));
    assert_eq!(f.server.deadline(), Some(t0 + ms(500)));
    assert_eq!(
        f.server.handle_timeout(t0 + ms(500)),
        vec![resp([0xA2, 2, 4, 0, 0, 0, 0, 0])]
    );
    assert_eq!(f.server.deadline(), Some(t0 + ms(1500)));
    assert_eq!(
        f.server.handle_timeout(t0 + ms(1500)),
        vec![resp(abort_bytes(0x2000, 0, AbortCode::TimedOut))]
    );
    assert!(f.server.is_idle());
}

#[test]
fn block_upload_of_twenty_bytes() {
    let mut f = Fixture::new();
    let value = counting(20);
    f.set(0x2000, 0, &value);
    let [lo, hi] = crc16(&value).to_le_bytes();
    // python-canopen's initiate: CRC, 127 segments, no protocol switch.
    assert_eq!(
        f.send([0xA4, 0x00, 0x20, 0x00, 0x7F, 0x00, 0, 0]),
        vec![[0xC6, 0x00, 0x20, 0x00, 20, 0, 0, 0]]
    );
    assert_eq!(
        f.send([0xA3, 0, 0, 0, 0, 0, 0, 0]),
        vec![
            seg(0x01, seven(&value, 0)),
            seg(0x02, seven(&value, 7)),
            seg(0x83, seven(&value, 14))
        ]
    );
    assert_eq!(
        f.send([0xA2, 3, 127, 0, 0, 0, 0, 0]),
        vec![[0xC5, lo, hi, 0, 0, 0, 0, 0]]
    );
    assert!(!f.server.is_idle());
    assert_eq!(f.send([0xA1, 0, 0, 0, 0, 0, 0, 0]), Vec::<[u8; 8]>::new());
    assert!(f.server.is_idle());
}

#[test]
fn block_upload_with_blocks_of_one_segment_and_an_empty_value() {
    let mut f = Fixture::new();
    let value = counting(9);
    f.set(0x2000, 0, &value);
    f.send([0xA4, 0x00, 0x20, 0x00, 1, 0, 0, 0]);
    assert_eq!(
        f.send([0xA3, 0, 0, 0, 0, 0, 0, 0]),
        vec![seg(0x01, seven(&value, 0))]
    );
    assert_eq!(
        f.send([0xA2, 1, 1, 0, 0, 0, 0, 0]),
        vec![seg(0x81, seven(&value, 7))]
    );
    let [lo, hi] = crc16(&value).to_le_bytes();
    assert_eq!(
        f.send([0xA2, 1, 1, 0, 0, 0, 0, 0]),
        vec![[0xC1 | 5 << 2, lo, hi, 0, 0, 0, 0, 0]]
    );
    f.send([0xA1, 0, 0, 0, 0, 0, 0, 0]);

    f.set(0x2000, 0, &[]);
    assert_eq!(
        f.send([0xA0, 0x00, 0x20, 0x00, 5, 0, 0, 0]),
        vec![[0xC2, 0x00, 0x20, 0x00, 0, 0, 0, 0]]
    );
    assert_eq!(
        f.send([0xA3, 0, 0, 0, 0, 0, 0, 0]),
        vec![[0x81, 0, 0, 0, 0, 0, 0, 0]]
    );
    assert_eq!(
        f.send([0xA2, 1, 5, 0, 0, 0, 0, 0]),
        vec![[0xDD, 0, 0, 0, 0, 0, 0, 0]]
    );
}

#[test]
fn block_upload_resends_after_the_acknowledged_segment() {
    let mut f = Fixture::new();
    let value = counting(30);
    f.set(0x2000, 0, &value);
    f.send([0xA4, 0x00, 0x20, 0x00, 3, 0, 0, 0]);
    assert_eq!(f.send([0xA3, 0, 0, 0, 0, 0, 0, 0]).len(), 3);
    // Only segment 1 arrived; the client wants blocks of 2 now.
    assert_eq!(
        f.send([0xA2, 1, 2, 0, 0, 0, 0, 0]),
        vec![seg(0x01, seven(&value, 7)), seg(0x02, seven(&value, 14))]
    );
    assert_eq!(
        f.send([0xA2, 2, 2, 0, 0, 0, 0, 0]),
        vec![seg(0x01, seven(&value, 21)), seg(0x82, seven(&value, 28))]
    );
    // Nothing of that block: all of it again.
    assert_eq!(
        f.send([0xA2, 0, 2, 0, 0, 0, 0, 0]),
        vec![seg(0x01, seven(&value, 21)), seg(0x82, seven(&value, 28))]
    );
    let [lo, hi] = crc16(&value).to_le_bytes();
    assert_eq!(
        f.send([0xA2, 2, 2, 0, 0, 0, 0, 0]),
        vec![[0xC1 | 5 << 2, lo, hi, 0, 0, 0, 0, 0]]
    );
}

#[test]
fn block_upload_checks_block_size_and_acknowledged_sequence() {
    let mut f = Fixture::new();
    f.set(0x2000, 0, &counting(30));
    for bad in [0, 128] {
        assert_eq!(
            f.send([0xA4, 0x00, 0x20, 0x00, bad, 0, 0, 0]),
            vec![abort_bytes(0x2000, 0, AbortCode::InvalidBlockSize)]
        );
    }
    f.send([0xA4, 0x00, 0x20, 0x00, 3, 0, 0, 0]);
    f.send([0xA3, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        f.send([0xA2, 4, 3, 0, 0, 0, 0, 0]),
        vec![abort_bytes(0x2000, 0, AbortCode::InvalidSequenceNumber)]
    );
    f.send([0xA4, 0x00, 0x20, 0x00, 3, 0, 0, 0]);
    f.send([0xA3, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        f.send([0xA2, 3, 200, 0, 0, 0, 0, 0]),
        vec![abort_bytes(0x2000, 0, AbortCode::InvalidBlockSize)]
    );
    // The start request only after an initiate.
    f.send([0xA4, 0x00, 0x20, 0x00, 3, 0, 0, 0]);
    f.send([0xA3, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        f.send([0xA3, 0, 0, 0, 0, 0, 0, 0]),
        vec![abort_bytes(0x2000, 0, AbortCode::InvalidCommandSpecifier)]
    );
}

#[test]
fn block_upload_switches_protocol_for_short_values_when_allowed() {
    let mut f = Fixture::new();
    // 4 bytes under a threshold of 21: expedited.
    assert_eq!(
        f.send([0xA4, 0x00, 0x10, 0x00, 127, 21, 0, 0]),
        vec![[0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00]]
    );
    assert!(f.server.is_idle());
    // 20 bytes under 21: segmented, then plain segment requests.
    f.set(0x2000, 0, &counting(20));
    assert_eq!(
        f.send([0xA4, 0x00, 0x20, 0x00, 127, 21, 0, 0]),
        vec![[0x41, 0x00, 0x20, 0x00, 20, 0, 0, 0]]
    );
    assert_eq!(
        f.send([0x60, 0, 0, 0, 0, 0, 0, 0]),
        vec![seg(0x00, seven(&counting(20), 0))]
    );
    f.send(abort_bytes(0x2000, 0, AbortCode::GeneralError));
    // 22 bytes over 21: block.
    f.set(0x2000, 0, &counting(22));
    assert_eq!(
        f.send([0xA4, 0x00, 0x20, 0x00, 127, 21, 0, 0]),
        vec![[0xC6, 0x00, 0x20, 0x00, 22, 0, 0, 0]]
    );
    f.send(abort_bytes(0x2000, 0, AbortCode::GeneralError));
    // Threshold 0: never, even for one byte.
    assert_eq!(
        f.send([0xA4, 0x01, 0x10, 0x00, 127, 0, 0, 0]),
        vec![[0xC6, 0x01, 0x10, 0x00, 1, 0, 0, 0]]
    );
}

#[test]
fn block_upload_answers_a_client_without_crc_without_the_flag() {
    let mut f = Fixture::new();
    f.set(0x2000, 0, &counting(10));
    assert_eq!(
        f.send([0xA0, 0x00, 0x20, 0x00, 127, 0, 0, 0]),
        vec![[0xC2, 0x00, 0x20, 0x00, 10, 0, 0, 0]]
    );
    f.send([0xA3, 0, 0, 0, 0, 0, 0, 0]);
    // The CRC still goes out in the end frame.
    let [lo, hi] = crc16(&counting(10)).to_le_bytes();
    assert_eq!(
        f.send([0xA2, 2, 127, 0, 0, 0, 0, 0]),
        vec![[0xC1 | 4 << 2, lo, hi, 0, 0, 0, 0, 0]]
    );
}

#[test]
fn an_empty_block_download_without_segments_as_python_canopen_sends_it() {
    let mut f = Fixture::new();
    f.set(0x2000, 0, b"old");
    assert_eq!(
        f.send([0xC6, 0x00, 0x20, 0x00, 0, 0, 0, 0]),
        vec![[0xA4, 0x00, 0x20, 0x00, 127, 0, 0, 0]]
    );
    // python-canopen: the end (n = 7, CRC of nothing) right after the initiate.
    assert_eq!(
        f.send([0xDD, 0, 0, 0, 0, 0, 0, 0]),
        vec![[0xA1, 0, 0, 0, 0, 0, 0, 0]]
    );
    assert_eq!(f.objects.value(0x2000, 0), &[] as &[u8]);
    assert!(f.server.is_idle());
    // CiA 301's way, one empty segment, works as well.
    f.set(0x2000, 0, b"old");
    f.send([0xC6, 0x00, 0x20, 0x00, 0, 0, 0, 0]);
    assert_eq!(
        f.send([0x81, 0, 0, 0, 0, 0, 0, 0]),
        vec![[0xA2, 1, 127, 0, 0, 0, 0, 0]]
    );
    assert_eq!(
        f.send([0xDD, 0, 0, 0, 0, 0, 0, 0]),
        vec![[0xA1, 0, 0, 0, 0, 0, 0, 0]]
    );
    assert_eq!(f.objects.value(0x2000, 0), &[] as &[u8]);
    // With a size announced, the same byte is a segment numbered 93, too
    // high for blocks of 10.
    let mut f = Fixture::with(ServerConfig {
        block_size: 10,
        ..config()
    });
    f.send([0xC6, 0x00, 0x20, 0x00, 5, 0, 0, 0]);
    assert_eq!(
        f.send([0xDD, 0, 0, 0, 0, 0, 0, 0]),
        vec![abort_bytes(0x2000, 0, AbortCode::InvalidSequenceNumber)]
    );
}
