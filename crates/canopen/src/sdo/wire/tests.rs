use super::*;

fn round_trip_request(request: Request, bytes: [u8; 8]) {
    assert_eq!(request.encode(), bytes, "{request:?}");
    assert_eq!(Request::decode(&bytes), Ok(request), "{bytes:02X?}");
}

fn round_trip_response(response: Response, bytes: [u8; 8]) {
    assert_eq!(response.encode(), bytes, "{response:?}");
    assert_eq!(Response::decode(&bytes), Ok(response), "{bytes:02X?}");
}

#[test]
fn command_specifiers_round_trip() {
    for raw in 0..8 {
        assert_eq!(ClientCommand::from_raw(raw).raw(), raw);
        assert_eq!(ServerCommand::from_raw(raw).raw(), raw);
    }
    assert_eq!(ClientCommand::of(0xE0), ClientCommand::Unknown(7));
    assert_eq!(ServerCommand::of(0x80), ServerCommand::Abort);
    assert_eq!(ClientCommand::of(0x43), ClientCommand::InitiateUpload);
}

#[test]
fn requests_are_byte_exact() {
    round_trip_request(
        Request::InitiateUpload {
            index: 0x1018,
            sub: 1,
        },
        [0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0],
    );
    round_trip_request(
        Request::InitiateDownload {
            index: 0x6040,
            sub: 0,
            data: Initiate::expedited(&[0x0F, 0x00]),
        },
        [0x2B, 0x40, 0x60, 0x00, 0x0F, 0x00, 0, 0],
    );
    round_trip_request(
        Request::InitiateDownload {
            index: 0x2000,
            sub: 0,
            data: Initiate::expedited(&[1]),
        },
        [0x2F, 0x00, 0x20, 0x00, 1, 0, 0, 0],
    );
    round_trip_request(
        Request::InitiateDownload {
            index: 0x2000,
            sub: 0,
            data: Initiate::expedited(&[1, 2, 3, 4]),
        },
        [0x23, 0x00, 0x20, 0x00, 1, 2, 3, 4],
    );
    round_trip_request(
        Request::InitiateDownload {
            index: 0x2000,
            sub: 5,
            data: Initiate::Expedited {
                data: [9, 8, 7, 6],
                len: None,
            },
        },
        [0x22, 0x00, 0x20, 0x05, 9, 8, 7, 6],
    );
    round_trip_request(
        Request::InitiateDownload {
            index: 0x1008,
            sub: 0,
            data: Initiate::Segmented { size: Some(20) },
        },
        [0x21, 0x08, 0x10, 0x00, 20, 0, 0, 0],
    );
    round_trip_request(
        Request::InitiateDownload {
            index: 0x1008,
            sub: 0,
            data: Initiate::Segmented { size: None },
        },
        [0x20, 0x08, 0x10, 0x00, 0, 0, 0, 0],
    );
    round_trip_request(
        Request::DownloadSegment {
            toggle: true,
            chunk: Chunk::new(b"abc"),
            last: true,
        },
        [0x19, b'a', b'b', b'c', 0, 0, 0, 0],
    );
    round_trip_request(
        Request::DownloadSegment {
            toggle: false,
            chunk: Chunk::new(b"1234567"),
            last: false,
        },
        [0x00, b'1', b'2', b'3', b'4', b'5', b'6', b'7'],
    );
    round_trip_request(
        Request::UploadSegment { toggle: true },
        [0x70, 0, 0, 0, 0, 0, 0, 0],
    );
    round_trip_request(
        Request::Abort {
            index: 0x1234,
            sub: 0x56,
            code: AbortCode::TimedOut,
        },
        [0x80, 0x34, 0x12, 0x56, 0x00, 0x00, 0x04, 0x05],
    );
    round_trip_request(
        Request::InitiateBlockDownload {
            index: 0x1F50,
            sub: 1,
            crc: true,
            size: Some(0x0001_0203),
        },
        [0xC6, 0x50, 0x1F, 0x01, 0x03, 0x02, 0x01, 0x00],
    );
    round_trip_request(
        Request::InitiateBlockDownload {
            index: 0x1F50,
            sub: 1,
            crc: false,
            size: None,
        },
        [0xC0, 0x50, 0x1F, 0x01, 0, 0, 0, 0],
    );
    round_trip_request(
        Request::EndBlockDownload {
            unused: 3,
            crc: 0xBEEF,
        },
        [0xCD, 0xEF, 0xBE, 0, 0, 0, 0, 0],
    );
    round_trip_request(
        Request::InitiateBlockUpload {
            index: 0x1F50,
            sub: 1,
            crc: true,
            block_size: 127,
            switch_threshold: 21,
        },
        [0xA4, 0x50, 0x1F, 0x01, 127, 21, 0, 0],
    );
    round_trip_request(Request::StartBlockUpload, [0xA3, 0, 0, 0, 0, 0, 0, 0]);
    round_trip_request(
        Request::BlockUploadAck {
            ackseq: 5,
            block_size: 10,
        },
        [0xA2, 5, 10, 0, 0, 0, 0, 0],
    );
    round_trip_request(Request::EndBlockUpload, [0xA1, 0, 0, 0, 0, 0, 0, 0]);
}

#[test]
fn responses_are_byte_exact() {
    round_trip_response(
        Response::InitiateUpload {
            index: 0x1000,
            sub: 0,
            data: Initiate::expedited(&[0x92, 0x01, 0x02, 0x00]),
        },
        [0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00],
    );
    round_trip_response(
        Response::InitiateUpload {
            index: 0x1001,
            sub: 0,
            data: Initiate::expedited(&[0x00]),
        },
        [0x4F, 0x01, 0x10, 0x00, 0, 0, 0, 0],
    );
    round_trip_response(
        Response::InitiateUpload {
            index: 0x1008,
            sub: 0,
            data: Initiate::Segmented { size: Some(27) },
        },
        [0x41, 0x08, 0x10, 0x00, 27, 0, 0, 0],
    );
    round_trip_response(
        Response::UploadSegment {
            toggle: false,
            chunk: Chunk::new(b"candeck"),
            last: false,
        },
        [0x00, b'c', b'a', b'n', b'd', b'e', b'c', b'k'],
    );
    round_trip_response(
        Response::UploadSegment {
            toggle: true,
            chunk: Chunk::new(b""),
            last: true,
        },
        [0x1F, 0, 0, 0, 0, 0, 0, 0],
    );
    round_trip_response(
        Response::InitiateDownload {
            index: 0x6040,
            sub: 0,
        },
        [0x60, 0x40, 0x60, 0x00, 0, 0, 0, 0],
    );
    round_trip_response(
        Response::DownloadSegment { toggle: true },
        [0x30, 0, 0, 0, 0, 0, 0, 0],
    );
    round_trip_response(
        Response::Abort {
            index: 0x2FFF,
            sub: 0,
            code: AbortCode::ObjectDoesNotExist,
        },
        [0x80, 0xFF, 0x2F, 0x00, 0x00, 0x00, 0x02, 0x06],
    );
    round_trip_response(
        Response::InitiateBlockDownload {
            index: 0x1F50,
            sub: 1,
            crc: true,
            block_size: 127,
        },
        [0xA4, 0x50, 0x1F, 0x01, 127, 0, 0, 0],
    );
    round_trip_response(
        Response::BlockDownloadAck {
            ackseq: 127,
            block_size: 64,
        },
        [0xA2, 127, 64, 0, 0, 0, 0, 0],
    );
    round_trip_response(Response::EndBlockDownload, [0xA1, 0, 0, 0, 0, 0, 0, 0]);
    round_trip_response(
        Response::InitiateBlockUpload {
            index: 0x1F50,
            sub: 1,
            crc: true,
            size: Some(300),
        },
        [0xC6, 0x50, 0x1F, 0x01, 0x2C, 0x01, 0, 0],
    );
    round_trip_response(
        Response::EndBlockUpload {
            unused: 6,
            crc: 0x1234,
        },
        [0xD9, 0x34, 0x12, 0, 0, 0, 0, 0],
    );
}

#[test]
fn block_segments_are_byte_exact() {
    let segment = BlockSegment::new(0x7F, true, b"xy");
    assert_eq!(segment.encode(), [0xFF, b'x', b'y', 0, 0, 0, 0, 0]);
    assert_eq!(BlockSegment::decode(&segment.encode()), Ok(segment));
    let segment = BlockSegment::new(1, false, b"1234567");
    assert_eq!(
        segment.encode(),
        [0x01, b'1', b'2', b'3', b'4', b'5', b'6', b'7']
    );
    assert_eq!(BlockSegment::decode(&segment.encode()), Ok(segment));
}

#[test]
fn reserved_bits_are_ignored_on_decode() {
    // Bit 4 of an initiate download is reserved.
    assert_eq!(
        Request::decode(&[0x3F, 0, 0x20, 0, 7, 0, 0, 0]),
        Ok(Request::InitiateDownload {
            index: 0x2000,
            sub: 0,
            data: Initiate::expedited(&[7]),
        })
    );
    // Bytes 1-7 of an upload segment request are reserved.
    assert_eq!(
        Request::decode(&[0x60, 1, 2, 3, 4, 5, 6, 7]),
        Ok(Request::UploadSegment { toggle: false })
    );
}

#[test]
fn malformed_frames_do_not_decode() {
    for len in [0, 1, 4, 7, 9] {
        let data = vec![0x40; len];
        assert_eq!(Request::decode(&data), Err(DecodeError::Length(len)));
        assert_eq!(Response::decode(&data), Err(DecodeError::Length(len)));
        assert_eq!(BlockSegment::decode(&data), Err(DecodeError::Length(len)));
    }
    assert_eq!(
        Request::decode(&[0xE0, 0, 0, 0, 0, 0, 0, 0]),
        Err(DecodeError::Command(0xE0))
    );
    assert_eq!(
        Response::decode(&[0xFF, 0, 0, 0, 0, 0, 0, 0]),
        Err(DecodeError::Command(0xFF))
    );
    // scs 5 with ss 3 does not exist.
    assert_eq!(
        Response::decode(&[0xA3, 0, 0, 0, 0, 0, 0, 0]),
        Err(DecodeError::Command(0xA3))
    );
    assert_eq!(
        DecodeError::Length(5).to_string(),
        "an SDO frame has 8 data bytes, this one has 5"
    );
}

#[test]
fn aborts_are_recognised_in_and_out_of_blocks() {
    assert!(is_abort(&[0x80, 0, 0, 0, 0, 0, 4, 5], false));
    assert!(is_abort(&[0x80], true));
    assert!(is_abort(&[0x81], false));
    // Segment 1, last of its block: not an abort inside a block.
    assert!(!is_abort(&[0x81, 0, 0, 0, 0, 0, 0, 0], true));
    assert!(!is_abort(&[], false));
    assert_eq!(
        abort_code_of(&[0x80, 0, 0, 0, 0x11, 0, 9, 6]),
        AbortCode::SubIndexDoesNotExist
    );
    assert_eq!(
        abort_code_of(&[0x80, 0, 0, 0, 0x24]),
        AbortCode::Unknown(0x24)
    );
}

#[test]
fn crc_is_the_ccitt_xmodem_variant() {
    // The check value of CRC-16/XMODEM.
    assert_eq!(crc16(b"123456789"), 0x31C3);
    assert_eq!(crc16(b""), 0);
    assert_eq!(crc16_update(crc16(b"1234"), b"56789"), 0x31C3);
}

#[test]
fn every_value_takes_at_least_one_segment() {
    assert_eq!(segment_count(0), 1);
    assert_eq!(segment_count(7), 1);
    assert_eq!(segment_count(8), 2);
    assert_eq!(segment_count(889), 127);
}
