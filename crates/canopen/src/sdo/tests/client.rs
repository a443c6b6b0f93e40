//! The client alone, against scripted server frames, byte for byte.

use super::*;
use crate::sdo::wire::crc16;
use crate::sdo::{ClientConfig, Step};

fn config() -> ClientConfig {
    ClientConfig {
        timeout: TIMEOUT,
        ..ClientConfig::default()
    }
}

fn block_download_config(block_size: u8) -> ClientConfig {
    ClientConfig {
        use_block_download_from: Some(0),
        block_size,
        ..config()
    }
}

fn block_upload_config(block_size: u8, switch_threshold: u8) -> ClientConfig {
    ClientConfig {
        use_block_upload: true,
        block_size,
        switch_threshold,
        ..config()
    }
}

/// A step that sends these requests and goes on.
fn sends(frames: &[[u8; 8]]) -> Step {
    Step {
        send: frames.iter().map(|&f| req(f)).collect(),
        done: None,
    }
}

fn finished(frames: &[[u8; 8]], transfer: Transfer) -> Step {
    Step {
        send: frames.iter().map(|&f| req(f)).collect(),
        done: Some(Ok(transfer)),
    }
}

/// The step of a client that aborts with `code` because the server broke the
/// protocol.
fn violation(step: &Step, index: u16, sub: u8, code: AbortCode) {
    assert_eq!(
        step.send,
        vec![req(abort_bytes(index, sub, code))],
        "{step:?}"
    );
    match &step.done {
        Some(Err(SdoError::Protocol { code: got, .. })) => assert_eq!(*got, code),
        other => panic!("expected a protocol error {code}, got {other:?}"),
    }
}

fn uploaded(data: &[u8]) -> Transfer {
    Transfer::Uploaded(data.to_vec())
}

#[test]
fn expedited_upload_of_one_to_four_bytes() {
    let t0 = Instant::now();
    for len in 1..=4u8 {
        let mut client = SdoClient::new(node(), config());
        assert_eq!(
            client.upload(0x2000, 0x01, t0),
            Ok(vec![req([0x40, 0x00, 0x20, 0x01, 0, 0, 0, 0])])
        );
        assert!(!client.is_idle());
        let value = [0x11, 0x22, 0x33, 0x44];
        let command = 0x43 | (4 - len) << 2;
        let step = client.handle_frame(
            &resp([command, 0x00, 0x20, 0x01, 0x11, 0x22, 0x33, 0x44]),
            t0,
        );
        assert_eq!(step, finished(&[], uploaded(&value[..usize::from(len)])));
        assert!(client.is_idle());
        assert_eq!(client.deadline(), None);
    }
}

#[test]
fn expedited_upload_without_size_gives_all_four_bytes() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1000, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0x42, 0x00, 0x10, 0x00, 1, 2, 3, 4]), t0);
    assert_eq!(step, finished(&[], uploaded(&[1, 2, 3, 4])));
}

#[test]
fn expedited_download_of_one_to_four_bytes() {
    let t0 = Instant::now();
    let cases: [(&[u8], u8); 4] = [
        (&[0xAA], 0x2F),
        (&[0xAA, 0xBB], 0x2B),
        (&[0xAA, 0xBB, 0xCC], 0x27),
        (&[0xAA, 0xBB, 0xCC, 0xDD], 0x23),
    ];
    for (value, command) in cases {
        let mut client = SdoClient::new(node(), config());
        let mut expected = [command, 0x40, 0x60, 0x00, 0, 0, 0, 0];
        expected[4..4 + value.len()].copy_from_slice(value);
        assert_eq!(
            client.download(0x6040, 0, value, t0),
            Ok(vec![req(expected)])
        );
        let step = client.handle_frame(&resp([0x60, 0x40, 0x60, 0x00, 0, 0, 0, 0]), t0);
        assert_eq!(step, finished(&[], Transfer::Downloaded));
        assert!(client.is_idle());
    }
}

#[test]
fn segmented_upload_of_seven_bytes() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0x41, 0x08, 0x10, 0x00, 7, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[[0x60, 0, 0, 0, 0, 0, 0, 0]]));
    // Toggle 0, n = 0, last.
    let step = client.handle_frame(&resp([0x01, 1, 2, 3, 4, 5, 6, 7]), t0);
    assert_eq!(step, finished(&[], uploaded(&[1, 2, 3, 4, 5, 6, 7])));
}

#[test]
fn segmented_upload_of_eight_bytes() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0x41, 0x08, 0x10, 0x00, 8, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[[0x60, 0, 0, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp([0x00, 1, 2, 3, 4, 5, 6, 7]), t0);
    assert_eq!(step, sends(&[[0x70, 0, 0, 0, 0, 0, 0, 0]]));
    // Toggle 1, n = 6 (0x0C), last.
    let step = client.handle_frame(&resp([0x1D, 8, 0, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, finished(&[], uploaded(&[1, 2, 3, 4, 5, 6, 7, 8])));
}

#[test]
fn segmented_upload_of_twenty_bytes_alternates_the_toggle_bit() {
    let t0 = Instant::now();
    let value = b"candeck virtual dev.";
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0x41, 0x08, 0x10, 0x00, 20, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[[0x60, 0, 0, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp(seg(0x00, seven(value, 0))), t0);
    assert_eq!(step, sends(&[[0x70, 0, 0, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp(seg(0x10, seven(value, 7))), t0);
    assert_eq!(step, sends(&[[0x60, 0, 0, 0, 0, 0, 0, 0]]));
    // Toggle 0, n = 1, last: 0x03.
    let step = client.handle_frame(&resp(seg(0x03, seven(value, 14))), t0);
    assert_eq!(step, finished(&[], uploaded(value)));
}

#[test]
fn segmented_upload_without_size_indicated() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[[0x60, 0, 0, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp([0x00, 1, 2, 3, 4, 5, 6, 7]), t0);
    assert_eq!(step, sends(&[[0x70, 0, 0, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp([0x1B, 8, 9, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, finished(&[], uploaded(&[1, 2, 3, 4, 5, 6, 7, 8, 9])));
}

#[test]
fn segmented_upload_of_an_empty_value() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    client.upload(0x2000, 0, t0).unwrap();
    client.handle_frame(&resp([0x41, 0x00, 0x20, 0x00, 0, 0, 0, 0]), t0);
    let step = client.handle_frame(&resp([0x0F, 0, 0, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, finished(&[], uploaded(&[])));
}

#[test]
fn segmented_download_of_seven_eight_twenty_and_zero_bytes() {
    let t0 = Instant::now();
    let ok = resp([0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0]);
    let seg_ok = |toggle: bool| resp([if toggle { 0x30 } else { 0x20 }, 0, 0, 0, 0, 0, 0, 0]);

    // 7 bytes: one segment, toggle 0, n = 0, last.
    let value = counting(7);
    let mut client = SdoClient::new(node(), config());
    assert_eq!(
        client.download(0x2000, 0, &value, t0),
        Ok(vec![req([0x21, 0x00, 0x20, 0x00, 7, 0, 0, 0])])
    );
    assert_eq!(
        client.handle_frame(&ok, t0),
        sends(&[seg(0x01, seven(&value, 0))])
    );
    assert_eq!(
        client.handle_frame(&seg_ok(false), t0),
        finished(&[], Transfer::Downloaded)
    );

    // 8 bytes: a full segment, then one byte with toggle 1, n = 6, last.
    let value = counting(8);
    let mut client = SdoClient::new(node(), config());
    assert_eq!(
        client.download(0x2000, 0, &value, t0),
        Ok(vec![req([0x21, 0x00, 0x20, 0x00, 8, 0, 0, 0])])
    );
    assert_eq!(
        client.handle_frame(&ok, t0),
        sends(&[seg(0x00, seven(&value, 0))])
    );
    assert_eq!(
        client.handle_frame(&seg_ok(false), t0),
        sends(&[seg(0x1D, seven(&value, 7))])
    );
    assert_eq!(
        client.handle_frame(&seg_ok(true), t0),
        finished(&[], Transfer::Downloaded)
    );

    // 20 bytes: toggles 0, 1, 0; the last segment has 6 bytes (n = 1).
    let value = counting(20);
    let mut client = SdoClient::new(node(), config());
    assert_eq!(
        client.download(0x2000, 0, &value, t0),
        Ok(vec![req([0x21, 0x00, 0x20, 0x00, 20, 0, 0, 0])])
    );
    assert_eq!(
        client.handle_frame(&ok, t0),
        sends(&[seg(0x00, seven(&value, 0))])
    );
    assert_eq!(
        client.handle_frame(&seg_ok(false), t0),
        sends(&[seg(0x10, seven(&value, 7))])
    );
    assert_eq!(
        client.handle_frame(&seg_ok(true), t0),
        sends(&[seg(0x03, seven(&value, 14))])
    );
    assert_eq!(
        client.handle_frame(&seg_ok(false), t0),
        finished(&[], Transfer::Downloaded)
    );

    // 0 bytes: segmented with size 0, then one empty last segment (n = 7).
    let mut client = SdoClient::new(node(), config());
    assert_eq!(
        client.download(0x2000, 0, &[], t0),
        Ok(vec![req([0x21, 0x00, 0x20, 0x00, 0, 0, 0, 0])])
    );
    assert_eq!(
        client.handle_frame(&ok, t0),
        sends(&[[0x0F, 0, 0, 0, 0, 0, 0, 0]])
    );
    assert_eq!(
        client.handle_frame(&seg_ok(false), t0),
        finished(&[], Transfer::Downloaded)
    );
}

#[test]
fn a_wrong_toggle_bit_aborts_with_0x05030000() {
    let t0 = Instant::now();
    // Upload: the first segment must have toggle 0.
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    client.handle_frame(&resp([0x41, 0x08, 0x10, 0x00, 20, 0, 0, 0]), t0);
    let step = client.handle_frame(&resp([0x10, 1, 2, 3, 4, 5, 6, 7]), t0);
    violation(&step, 0x1008, 0, AbortCode::ToggleBitNotAlternated);
    assert!(client.is_idle());

    // Download: the confirmation echoes the segment's toggle.
    let mut client = SdoClient::new(node(), config());
    client.download(0x2000, 0, &counting(10), t0).unwrap();
    client.handle_frame(&resp([0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0]), t0);
    let step = client.handle_frame(&resp([0x30, 0, 0, 0, 0, 0, 0, 0]), t0);
    violation(&step, 0x2000, 0, AbortCode::ToggleBitNotAlternated);
}

#[test]
fn uploads_longer_or_shorter_than_announced_abort() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    client.handle_frame(&resp([0x41, 0x08, 0x10, 0x00, 5, 0, 0, 0]), t0);
    let step = client.handle_frame(&resp([0x01, 1, 2, 3, 4, 5, 6, 7]), t0);
    violation(&step, 0x1008, 0, AbortCode::LengthTooHigh);

    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    client.handle_frame(&resp([0x41, 0x08, 0x10, 0x00, 9, 0, 0, 0]), t0);
    let step = client.handle_frame(&resp([0x05, 1, 2, 3, 4, 5, 0, 0]), t0);
    violation(&step, 0x1008, 0, AbortCode::LengthTooLow);
}

#[test]
fn a_server_abort_mid_transfer_ends_it_without_a_frame() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    client.handle_frame(&resp([0x41, 0x08, 0x10, 0x00, 20, 0, 0, 0]), t0);
    client.handle_frame(&resp([0x00, 1, 2, 3, 4, 5, 6, 7]), t0);
    let step = client.handle_frame(&resp(abort_bytes(0x1008, 0, AbortCode::HardwareError)), t0);
    assert_eq!(
        step,
        Step {
            send: Vec::new(),
            done: Some(Err(SdoError::ServerAborted(AbortCode::HardwareError))),
        }
    );
    assert!(client.is_idle());

    // At initiate, with a code CiA 301 does not define.
    let mut client = SdoClient::new(node(), config());
    client.upload(0x2FFF, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0x80, 0xFF, 0x2F, 0x00, 0x78, 0x56, 0x34, 0x12]), t0);
    assert_eq!(
        step.done,
        Some(Err(SdoError::ServerAborted(AbortCode::Unknown(
            0x1234_5678
        ))))
    );
}

#[test]
fn no_answer_times_out_with_0x05040000() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    assert_eq!(client.deadline(), None);
    client.upload(0x1008, 0, t0).unwrap();
    assert_eq!(client.deadline(), Some(t0 + TIMEOUT));
    assert_eq!(client.handle_timeout(t0 + ms(999)), Step::default());
    // Each answer restarts the clock.
    client.handle_frame(&resp([0x41, 0x08, 0x10, 0x00, 20, 0, 0, 0]), t0 + ms(500));
    assert_eq!(client.deadline(), Some(t0 + ms(1500)));
    assert_eq!(client.handle_timeout(t0 + ms(1000)), Step::default());
    let step = client.handle_timeout(t0 + ms(1500));
    assert_eq!(
        step,
        Step {
            send: vec![req([0x80, 0x08, 0x10, 0x00, 0x00, 0x00, 0x04, 0x05])],
            done: Some(Err(SdoError::Timeout)),
        }
    );
    assert!(client.is_idle());
    assert_eq!(client.deadline(), None);
    assert_eq!(client.handle_timeout(t0 + ms(5000)), Step::default());
}

#[test]
fn unknown_or_unexpected_responses_abort_with_0x05040001() {
    let t0 = Instant::now();
    // scs 7 does not exist.
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0xE0, 0x08, 0x10, 0x00, 0, 0, 0, 0]), t0);
    violation(&step, 0x1008, 0, AbortCode::InvalidCommandSpecifier);

    // A download response to an upload.
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0x60, 0x08, 0x10, 0x00, 0, 0, 0, 0]), t0);
    violation(&step, 0x1008, 0, AbortCode::InvalidCommandSpecifier);
    let Some(Err(error)) = step.done else {
        unreachable!()
    };
    assert_eq!(
        error.to_string(),
        "the device broke the SDO protocol (it sent an initiate download response while the \
         client waited for an initiate upload response), so the transfer was aborted with \
         0x05040001 (Client/server command specifier not valid or unknown)"
    );
}

#[test]
fn truncated_responses_abort_with_0x05040001() {
    let t0 = Instant::now();
    for len in [0, 1, 4, 7] {
        let mut client = SdoClient::new(node(), config());
        client.upload(0x1000, 0, t0).unwrap();
        let data = [0x43, 0x00, 0x10, 0x00, 1, 2, 3, 4];
        let frame = Frame::new(CanId::Standard(0x585), &data[..len]).unwrap();
        let step = client.handle_frame(&frame, t0);
        violation(&step, 0x1000, 0, AbortCode::InvalidCommandSpecifier);
    }
    // A short abort is still an abort, and is not answered.
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1000, 0, t0).unwrap();
    let frame = Frame::new(CanId::Standard(0x585), &[0x80, 0x00, 0x10, 0x00]).unwrap();
    let step = client.handle_frame(&frame, t0);
    assert_eq!(step.send, Vec::new());
    assert_eq!(
        step.done,
        Some(Err(SdoError::ServerAborted(AbortCode::Unknown(0))))
    );
}

#[test]
fn an_answer_for_another_object_aborts_with_0x06040043() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0x4F, 0x09, 0x10, 0x00, 1, 0, 0, 0]), t0);
    violation(&step, 0x1008, 0, AbortCode::ParameterIncompatible);
}

#[test]
fn one_transfer_at_a_time() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    client.upload(0x1008, 0, t0).unwrap();
    assert_eq!(client.upload(0x1000, 0, t0), Err(SdoError::Busy));
    assert_eq!(client.download(0x2000, 0, &[1], t0), Err(SdoError::Busy));
    // The running transfer is untouched.
    let step = client.handle_frame(&resp([0x4F, 0x08, 0x10, 0x00, 9, 0, 0, 0]), t0);
    assert_eq!(step, finished(&[], uploaded(&[9])));
}

#[test]
fn foreign_frames_are_ignored() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    // Idle: even a valid response is none of its business.
    assert_eq!(
        client.handle_frame(&resp([0x4F, 0x08, 0x10, 0x00, 9, 0, 0, 0]), t0),
        Step::default()
    );
    client.upload(0x1008, 0, t0).unwrap();
    for frame in [
        Frame::new(
            CanId::Standard(0x586),
            &[0x4F, 0x08, 0x10, 0x00, 9, 0, 0, 0],
        )
        .unwrap(),
        Frame::new(
            CanId::Extended(0x585),
            &[0x4F, 0x08, 0x10, 0x00, 9, 0, 0, 0],
        )
        .unwrap(),
        req([0x4F, 0x08, 0x10, 0x00, 9, 0, 0, 0]),
        Frame::remote(CanId::Standard(0x585), 8).unwrap(),
    ] {
        assert_eq!(client.handle_frame(&frame, t0), Step::default(), "{frame}");
    }
    assert!(!client.is_idle());
}

#[test]
fn the_caller_can_abort() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), config());
    assert_eq!(client.abort(AbortCode::GeneralError), Vec::new());
    client.download(0x2000, 0, &counting(30), t0).unwrap();
    assert_eq!(
        client.abort(AbortCode::GeneralError),
        vec![req(abort_bytes(0x2000, 0, AbortCode::GeneralError))]
    );
    assert!(client.is_idle());
    assert!(client.upload(0x1000, 0, t0).is_ok());
}

#[test]
fn custom_cob_ids() {
    let t0 = Instant::now();
    let mut client =
        SdoClient::with_cob_ids(CanId::Standard(0x641), CanId::Standard(0x5C1), config());
    let frames = client.upload(0x1000, 0, t0).unwrap();
    assert_eq!(frames[0].id(), CanId::Standard(0x641));
    let answer = Frame::new(
        CanId::Standard(0x5C1),
        &[0x4F, 0x00, 0x10, 0x00, 7, 0, 0, 0],
    )
    .unwrap();
    assert_eq!(
        client.handle_frame(&answer, t0),
        finished(&[], uploaded(&[7]))
    );
}

#[test]
fn block_download_of_twenty_bytes() {
    let t0 = Instant::now();
    let value = counting(20);
    let mut client = SdoClient::new(node(), block_download_config(127));
    assert_eq!(
        client.download(0x2000, 0, &value, t0),
        Ok(vec![req([0xC6, 0x00, 0x20, 0x00, 20, 0, 0, 0])])
    );
    let step = client.handle_frame(&resp([0xA4, 0x00, 0x20, 0x00, 127, 0, 0, 0]), t0);
    assert_eq!(
        step,
        sends(&[
            seg(0x01, seven(&value, 0)),
            seg(0x02, seven(&value, 7)),
            seg(0x83, seven(&value, 14)),
        ])
    );
    let [lo, hi] = crc16(&value).to_le_bytes();
    // n = 1: the last segment held 6 bytes.
    let step = client.handle_frame(&resp([0xA2, 3, 127, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[[0xC5, lo, hi, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp([0xA1, 0, 0, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, finished(&[], Transfer::Downloaded));
}

#[test]
fn block_download_with_blocks_of_one_segment() {
    let t0 = Instant::now();
    let value = counting(15);
    let mut client = SdoClient::new(node(), block_download_config(127));
    client.download(0x2000, 0, &value, t0).unwrap();
    let step = client.handle_frame(&resp([0xA0, 0x00, 0x20, 0x00, 1, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[seg(0x01, seven(&value, 0))]));
    let step = client.handle_frame(&resp([0xA2, 1, 1, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[seg(0x01, seven(&value, 7))]));
    let step = client.handle_frame(&resp([0xA2, 1, 1, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[seg(0x81, seven(&value, 14))]));
    let step = client.handle_frame(&resp([0xA2, 1, 1, 0, 0, 0, 0, 0]), t0);
    // The server offered no CRC; the client sends the real one all the same.
    let [lo, hi] = crc16(&value).to_le_bytes();
    assert_eq!(step, sends(&[[0xC1 | 6 << 2, lo, hi, 0, 0, 0, 0, 0]]));
}

#[test]
fn block_download_last_segment_of_one_to_seven_bytes() {
    let t0 = Instant::now();
    for last in 1..=7 {
        let value = counting(7 + last);
        let mut client = SdoClient::new(node(), block_download_config(127));
        client.download(0x2000, 0, &value, t0).unwrap();
        let step = client.handle_frame(&resp([0xA4, 0x00, 0x20, 0x00, 127, 0, 0, 0]), t0);
        assert_eq!(
            step,
            sends(&[seg(0x01, seven(&value, 0)), seg(0x82, seven(&value, 7))])
        );
        let step = client.handle_frame(&resp([0xA2, 2, 127, 0, 0, 0, 0, 0]), t0);
        let [lo, hi] = crc16(&value).to_le_bytes();
        let n = (7 - last) as u8;
        assert_eq!(
            step,
            sends(&[[0xC1 | n << 2, lo, hi, 0, 0, 0, 0, 0]]),
            "{last}"
        );
    }
}

#[test]
fn block_download_of_an_empty_value_sends_one_empty_segment() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), block_download_config(127));
    assert_eq!(
        client.download(0x2000, 0, &[], t0),
        Ok(vec![req([0xC6, 0x00, 0x20, 0x00, 0, 0, 0, 0])])
    );
    let step = client.handle_frame(&resp([0xA4, 0x00, 0x20, 0x00, 127, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[[0x81, 0, 0, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp([0xA2, 1, 127, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[[0xDD, 0, 0, 0, 0, 0, 0, 0]]));
}

#[test]
fn block_download_resends_after_the_last_acknowledged_segment() {
    let t0 = Instant::now();
    let value = counting(35);
    let mut client = SdoClient::new(node(), block_download_config(127));
    client.download(0x2000, 0, &value, t0).unwrap();
    let step = client.handle_frame(&resp([0xA4, 0x00, 0x20, 0x00, 4, 0, 0, 0]), t0);
    assert_eq!(step.send.len(), 4);
    // Segment 2 was lost: the server had 1, and wants blocks of 3 now.
    let step = client.handle_frame(&resp([0xA2, 1, 3, 0, 0, 0, 0, 0]), t0);
    assert_eq!(
        step,
        sends(&[
            seg(0x01, seven(&value, 7)),
            seg(0x02, seven(&value, 14)),
            seg(0x03, seven(&value, 21)),
        ])
    );
    let step = client.handle_frame(&resp([0xA2, 3, 3, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[seg(0x81, seven(&value, 28))]));
    // Nothing of that block arrived: all of it again.
    let step = client.handle_frame(&resp([0xA2, 0, 3, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[seg(0x81, seven(&value, 28))]));
    let step = client.handle_frame(&resp([0xA2, 1, 3, 0, 0, 0, 0, 0]), t0);
    let [lo, hi] = crc16(&value).to_le_bytes();
    assert_eq!(step, sends(&[[0xC1, lo, hi, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp([0xA1, 0, 0, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, finished(&[], Transfer::Downloaded));
}

#[test]
fn block_download_checks_block_size_and_acknowledged_sequence() {
    let t0 = Instant::now();
    for bad in [0, 128, 255] {
        let mut client = SdoClient::new(node(), block_download_config(127));
        client.download(0x2000, 0, &counting(20), t0).unwrap();
        let step = client.handle_frame(&resp([0xA4, 0x00, 0x20, 0x00, bad, 0, 0, 0]), t0);
        violation(&step, 0x2000, 0, AbortCode::InvalidBlockSize);
    }
    let mut client = SdoClient::new(node(), block_download_config(127));
    client.download(0x2000, 0, &counting(20), t0).unwrap();
    client.handle_frame(&resp([0xA4, 0x00, 0x20, 0x00, 127, 0, 0, 0]), t0);
    let step = client.handle_frame(&resp([0xA2, 4, 127, 0, 0, 0, 0, 0]), t0);
    violation(&step, 0x2000, 0, AbortCode::InvalidSequenceNumber);

    let mut client = SdoClient::new(node(), block_download_config(127));
    client.download(0x2000, 0, &counting(20), t0).unwrap();
    client.handle_frame(&resp([0xA4, 0x00, 0x20, 0x00, 127, 0, 0, 0]), t0);
    let step = client.handle_frame(&resp([0xA2, 3, 0, 0, 0, 0, 0, 0]), t0);
    violation(&step, 0x2000, 0, AbortCode::InvalidBlockSize);
}

#[test]
fn block_download_refused_for_its_crc() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), block_download_config(127));
    client.download(0x2000, 0, &counting(10), t0).unwrap();
    client.handle_frame(&resp([0xA4, 0x00, 0x20, 0x00, 127, 0, 0, 0]), t0);
    client.handle_frame(&resp([0xA2, 2, 127, 0, 0, 0, 0, 0]), t0);
    let step = client.handle_frame(&resp(abort_bytes(0x2000, 0, AbortCode::CrcError)), t0);
    assert_eq!(
        step.done,
        Some(Err(SdoError::ServerAborted(AbortCode::CrcError)))
    );
    assert_eq!(step.send, Vec::new());
}

#[test]
fn block_download_below_the_threshold_goes_expedited_or_segmented() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(
        node(),
        ClientConfig {
            use_block_download_from: Some(8),
            ..config()
        },
    );
    assert_eq!(
        client.download(0x2000, 0, &counting(7), t0),
        Ok(vec![req([0x21, 0x00, 0x20, 0x00, 7, 0, 0, 0])])
    );
    client.abort(AbortCode::GeneralError);
    assert_eq!(
        client.download(0x2000, 0, &counting(8), t0),
        Ok(vec![req([0xC6, 0x00, 0x20, 0x00, 8, 0, 0, 0])])
    );
}

#[test]
fn block_upload_of_twenty_bytes() {
    let t0 = Instant::now();
    let value = counting(20);
    let [lo, hi] = crc16(&value).to_le_bytes();
    let mut client = SdoClient::new(node(), block_upload_config(127, 21));
    assert_eq!(
        client.upload(0x2000, 0, t0),
        Ok(vec![req([0xA4, 0x00, 0x20, 0x00, 127, 21, 0, 0])])
    );
    let step = client.handle_frame(&resp([0xC6, 0x00, 0x20, 0x00, 20, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[[0xA3, 0, 0, 0, 0, 0, 0, 0]]));
    assert_eq!(
        client.handle_frame(&resp(seg(0x01, seven(&value, 0))), t0),
        Step::default()
    );
    assert_eq!(
        client.handle_frame(&resp(seg(0x02, seven(&value, 7))), t0),
        Step::default()
    );
    let step = client.handle_frame(&resp(seg(0x83, seven(&value, 14))), t0);
    assert_eq!(step, sends(&[[0xA2, 3, 127, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp([0xC5, lo, hi, 0, 0, 0, 0, 0]), t0);
    assert_eq!(
        step,
        finished(&[[0xA1, 0, 0, 0, 0, 0, 0, 0]], uploaded(&value))
    );
    assert!(client.is_idle());
}

#[test]
fn block_upload_with_blocks_of_one_segment() {
    let t0 = Instant::now();
    let value = counting(9);
    let [lo, hi] = crc16(&value).to_le_bytes();
    let mut client = SdoClient::new(node(), block_upload_config(1, 0));
    assert_eq!(
        client.upload(0x2000, 0, t0),
        Ok(vec![req([0xA4, 0x00, 0x20, 0x00, 1, 0, 0, 0])])
    );
    client.handle_frame(&resp([0xC6, 0x00, 0x20, 0x00, 9, 0, 0, 0]), t0);
    let step = client.handle_frame(&resp(seg(0x01, seven(&value, 0))), t0);
    assert_eq!(step, sends(&[[0xA2, 1, 1, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp(seg(0x81, seven(&value, 7))), t0);
    assert_eq!(step, sends(&[[0xA2, 1, 1, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp([0xC1 | 5 << 2, lo, hi, 0, 0, 0, 0, 0]), t0);
    assert_eq!(
        step,
        finished(&[[0xA1, 0, 0, 0, 0, 0, 0, 0]], uploaded(&value))
    );
}

#[test]
fn block_upload_last_segment_of_one_to_seven_bytes_without_size_or_crc() {
    let t0 = Instant::now();
    for last in 1..=7usize {
        let value = counting(7 + last);
        let mut client = SdoClient::new(node(), block_upload_config(127, 0));
        client.upload(0x2000, 0, t0).unwrap();
        // No size indicated, no CRC offered.
        client.handle_frame(&resp([0xC0, 0x00, 0x20, 0x00, 0, 0, 0, 0]), t0);
        client.handle_frame(&resp(seg(0x01, seven(&value, 0))), t0);
        let step = client.handle_frame(&resp(seg(0x82, seven(&value, 7))), t0);
        assert_eq!(step, sends(&[[0xA2, 2, 127, 0, 0, 0, 0, 0]]));
        let n = (7 - last) as u8;
        let step = client.handle_frame(&resp([0xC1 | n << 2, 0xFF, 0xFF, 0, 0, 0, 0, 0]), t0);
        assert_eq!(
            step,
            finished(&[[0xA1, 0, 0, 0, 0, 0, 0, 0]], uploaded(&value)),
            "{last}"
        );
    }
}

#[test]
fn block_upload_with_a_wrong_crc_aborts_with_0x05040004() {
    let t0 = Instant::now();
    let value = counting(10);
    let [lo, hi] = (crc16(&value) ^ 1).to_le_bytes();
    let mut client = SdoClient::new(node(), block_upload_config(127, 0));
    client.upload(0x2000, 0, t0).unwrap();
    client.handle_frame(&resp([0xC6, 0x00, 0x20, 0x00, 10, 0, 0, 0]), t0);
    client.handle_frame(&resp(seg(0x01, seven(&value, 0))), t0);
    client.handle_frame(&resp(seg(0x82, seven(&value, 7))), t0);
    let step = client.handle_frame(&resp([0xC1 | 4 << 2, lo, hi, 0, 0, 0, 0, 0]), t0);
    violation(&step, 0x2000, 0, AbortCode::CrcError);
}

#[test]
fn block_upload_acknowledges_the_last_segment_received_in_order() {
    let t0 = Instant::now();
    let value = counting(20);
    let [lo, hi] = crc16(&value).to_le_bytes();
    let mut client = SdoClient::new(node(), block_upload_config(127, 0));
    client.upload(0x2000, 0, t0).unwrap();
    client.handle_frame(&resp([0xC6, 0x00, 0x20, 0x00, 20, 0, 0, 0]), t0);
    client.handle_frame(&resp(seg(0x01, seven(&value, 0))), t0);
    // Segment 2 lost; the last one arrives out of order.
    let step = client.handle_frame(&resp(seg(0x83, seven(&value, 14))), t0);
    assert_eq!(step, sends(&[[0xA2, 1, 127, 0, 0, 0, 0, 0]]));
    // The server resends from segment 2, numbering from 1.
    assert_eq!(
        client.handle_frame(&resp(seg(0x01, seven(&value, 7))), t0),
        Step::default()
    );
    let step = client.handle_frame(&resp(seg(0x82, seven(&value, 14))), t0);
    assert_eq!(step, sends(&[[0xA2, 2, 127, 0, 0, 0, 0, 0]]));
    let step = client.handle_frame(&resp([0xC5, lo, hi, 0, 0, 0, 0, 0]), t0);
    assert_eq!(
        step,
        finished(&[[0xA1, 0, 0, 0, 0, 0, 0, 0]], uploaded(&value))
    );
}

#[test]
fn block_upload_rescues_a_lost_final_segment_on_the_sub_block_timeout() {
    let t0 = Instant::now();
    let value = counting(30);
    let mut client = SdoClient::new(node(), block_upload_config(4, 0));
    client.upload(0x2000, 0, t0).unwrap();
    client.handle_frame(&resp([0xC6, 0x00, 0x20, 0x00, 30, 0, 0, 0]), t0);
    // Before any segment, silence is only a slow server: the full timeout.
    assert_eq!(client.deadline(), Some(t0 + TIMEOUT));
    client.handle_frame(&resp(seg(0x01, seven(&value, 0))), t0);
    client.handle_frame(&resp(seg(0x02, seven(&value, 7))), t0 + ms(10));
    // Segments 3 and 4 are lost: after half the timeout, acknowledge 2.
    assert_eq!(client.deadline(), Some(t0 + ms(510)));
    assert_eq!(client.handle_timeout(t0 + ms(509)), Step::default());
    let step = client.handle_timeout(t0 + ms(510));
    assert_eq!(step, sends(&[[0xA2, 2, 4, 0, 0, 0, 0, 0]]));
    assert_eq!(client.deadline(), Some(t0 + ms(1510)));
    // The server resends from segment 3.
    client.handle_frame(&resp(seg(0x01, seven(&value, 14))), t0 + ms(520));
    client.handle_frame(&resp(seg(0x02, seven(&value, 21))), t0 + ms(520));
    let step = client.handle_frame(&resp(seg(0x83, seven(&value, 28))), t0 + ms(520));
    assert_eq!(step, sends(&[[0xA2, 3, 4, 0, 0, 0, 0, 0]]));
    let [lo, hi] = crc16(&value).to_le_bytes();
    let step = client.handle_frame(&resp([0xC1 | 5 << 2, lo, hi, 0, 0, 0, 0, 0]), t0 + ms(530));
    assert_eq!(
        step,
        finished(&[[0xA1, 0, 0, 0, 0, 0, 0, 0]], uploaded(&value))
    );

    // A server that goes silent for good: one rescue, then the timeout.
    let mut client = SdoClient::new(node(), block_upload_config(4, 0));
    client.upload(0x2000, 0, t0).unwrap();
    client.handle_frame(&resp([0xC6, 0x00, 0x20, 0x00, 30, 0, 0, 0]), t0);
    client.handle_frame(&resp(seg(0x01, seven(&value, 0))), t0);
    let step = client.handle_timeout(t0 + ms(500));
    assert_eq!(step, sends(&[[0xA2, 1, 4, 0, 0, 0, 0, 0]]));
    let step = client.handle_timeout(t0 + ms(1500));
    assert_eq!(
        step.send,
        vec![req(abort_bytes(0x2000, 0, AbortCode::TimedOut))]
    );
    assert_eq!(step.done, Some(Err(SdoError::Timeout)));
}

#[test]
fn block_upload_rejects_impossible_sequence_numbers() {
    let t0 = Instant::now();
    for first in [0x00, 0x05, 0x7F] {
        let mut client = SdoClient::new(node(), block_upload_config(4, 0));
        client.upload(0x2000, 0, t0).unwrap();
        client.handle_frame(&resp([0xC6, 0x00, 0x20, 0x00, 30, 0, 0, 0]), t0);
        let step = client.handle_frame(&resp(seg(first, [0; 7])), t0);
        violation(&step, 0x2000, 0, AbortCode::InvalidSequenceNumber);
    }
}

#[test]
fn block_upload_with_more_segments_than_announced_aborts() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), block_upload_config(127, 0));
    client.upload(0x2000, 0, t0).unwrap();
    client.handle_frame(&resp([0xC6, 0x00, 0x20, 0x00, 7, 0, 0, 0]), t0);
    client.handle_frame(&resp(seg(0x01, [1; 7])), t0);
    let step = client.handle_frame(&resp(seg(0x02, [2; 7])), t0);
    violation(&step, 0x2000, 0, AbortCode::LengthTooHigh);
}

#[test]
fn block_upload_end_must_match_the_announced_size() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), block_upload_config(127, 0));
    client.upload(0x2000, 0, t0).unwrap();
    client.handle_frame(&resp([0xC2, 0x00, 0x20, 0x00, 7, 0, 0, 0]), t0);
    client.handle_frame(&resp(seg(0x81, [1; 7])), t0);
    // n = 2 leaves 5 bytes of the 7 announced.
    let step = client.handle_frame(&resp([0xC9, 0, 0, 0, 0, 0, 0, 0]), t0);
    violation(&step, 0x2000, 0, AbortCode::LengthTooLow);
}

#[test]
fn block_upload_accepts_the_servers_switch_to_a_plain_upload() {
    let t0 = Instant::now();
    // Expedited.
    let mut client = SdoClient::new(node(), block_upload_config(127, 21));
    client.upload(0x1001, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0x4F, 0x01, 0x10, 0x00, 0x2A, 0, 0, 0]), t0);
    assert_eq!(step, finished(&[], uploaded(&[0x2A])));
    // Segmented, even above the threshold: python-canopen switches always.
    let mut client = SdoClient::new(node(), block_upload_config(127, 0));
    client.upload(0x1008, 0, t0).unwrap();
    let step = client.handle_frame(&resp([0x41, 0x08, 0x10, 0x00, 9, 0, 0, 0]), t0);
    assert_eq!(step, sends(&[[0x60, 0, 0, 0, 0, 0, 0, 0]]));
    client.handle_frame(&resp([0x00, 1, 2, 3, 4, 5, 6, 7]), t0);
    let step = client.handle_frame(&resp([0x1B, 8, 9, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, finished(&[], uploaded(&[1, 2, 3, 4, 5, 6, 7, 8, 9])));
}

#[test]
fn a_server_abort_inside_a_block_ends_the_upload() {
    let t0 = Instant::now();
    let mut client = SdoClient::new(node(), block_upload_config(127, 0));
    client.upload(0x2000, 0, t0).unwrap();
    client.handle_frame(&resp([0xC6, 0x00, 0x20, 0x00, 30, 0, 0, 0]), t0);
    client.handle_frame(&resp(seg(0x01, [1; 7])), t0);
    let step = client.handle_frame(
        &resp(abort_bytes(0x2000, 0, AbortCode::CannotStoreDeviceState)),
        t0,
    );
    assert_eq!(
        step,
        Step {
            send: Vec::new(),
            done: Some(Err(SdoError::ServerAborted(
                AbortCode::CannotStoreDeviceState
            ))),
        }
    );
}

#[test]
fn errors_read_as_sentences() {
    assert_eq!(
        SdoError::ServerAborted(AbortCode::ObjectDoesNotExist).to_string(),
        "the device refused the SDO transfer: Object does not exist in the object dictionary \
         (abort code 0x06020000)"
    );
    assert_eq!(
        SdoError::Timeout.to_string(),
        "the device did not answer the SDO request in time, so the transfer was aborted"
    );
    assert_eq!(
        SdoError::Protocol {
            code: AbortCode::ToggleBitNotAlternated,
            detail: "its toggle bit was 1 where 0 was due".into(),
        }
        .to_string(),
        "the device broke the SDO protocol (its toggle bit was 1 where 0 was due), so the \
         transfer was aborted with 0x05030000 (Toggle bit not alternated)"
    );
    assert_eq!(
        SdoError::Busy.to_string(),
        "another SDO transfer with this device is still running; CiA 301 allows one at a time"
    );
    assert_eq!(
        SdoError::TooLarge(5_000_000_000).to_string(),
        "5000000000 bytes do not fit an SDO transfer, whose size field has 32 bits"
    );
}

#[test]
fn download_progress_moves_with_each_block_acknowledgement() {
    let t0 = Instant::now();
    let value = counting(20);
    // Blocks of one segment: 7 bytes confirmed per acknowledgement.
    let mut client = SdoClient::new(node(), block_download_config(127));
    assert_eq!(client.download_progress(), None);
    client.download(0x2000, 0, &value, t0).unwrap();
    assert_eq!(client.download_progress(), Some((0, 20)));
    client.handle_frame(&resp([0xA0, 0x00, 0x20, 0x00, 1, 0, 0, 0]), t0);
    assert_eq!(client.download_progress(), Some((0, 20)));
    client.handle_frame(&resp([0xA2, 1, 1, 0, 0, 0, 0, 0]), t0);
    assert_eq!(client.download_progress(), Some((7, 20)));
    // A block acknowledged without its segment: no further.
    client.handle_frame(&resp([0xA2, 0, 1, 0, 0, 0, 0, 0]), t0);
    assert_eq!(client.download_progress(), Some((7, 20)));
    client.handle_frame(&resp([0xA2, 1, 1, 0, 0, 0, 0, 0]), t0);
    assert_eq!(client.download_progress(), Some((14, 20)));
    client.handle_frame(&resp([0xA2, 1, 1, 0, 0, 0, 0, 0]), t0);
    assert_eq!(client.download_progress(), Some((20, 20)));
    let step = client.handle_frame(&resp([0xA1, 0, 0, 0, 0, 0, 0, 0]), t0);
    assert_eq!(step, finished(&[], Transfer::Downloaded));
    assert_eq!(client.download_progress(), None);
}

#[test]
fn download_progress_of_a_segmented_download_and_none_for_an_upload() {
    let t0 = Instant::now();
    let value = counting(20);
    let mut client = SdoClient::new(node(), config());
    client.download(0x2000, 0, &value, t0).unwrap();
    assert_eq!(client.download_progress(), Some((0, 20)));
    client.handle_frame(&resp([0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0]), t0);
    // The first segment is sent, not yet confirmed.
    assert_eq!(client.download_progress(), Some((0, 20)));
    client.handle_frame(&resp([0x20, 0, 0, 0, 0, 0, 0, 0]), t0);
    assert_eq!(client.download_progress(), Some((7, 20)));
    client.handle_frame(&resp([0x30, 0, 0, 0, 0, 0, 0, 0]), t0);
    assert_eq!(client.download_progress(), Some((14, 20)));
    client.handle_frame(&resp([0x20, 0, 0, 0, 0, 0, 0, 0]), t0);
    assert_eq!(client.download_progress(), None);

    client.upload(0x2000, 0, t0).unwrap();
    assert_eq!(client.download_progress(), None);
}
