//! A client and a server wired together: every transfer kind and size, lost
//! frames, aborts from either side.

use super::*;
use crate::sdo::{ClientConfig, ServerConfig};

/// How a value travels in each direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Method {
    /// Expedited for 1–4 bytes, segmented otherwise.
    Plain,
    /// Block download, or block upload with this protocol switch threshold.
    Block { switch_threshold: u8 },
}

pub(super) const METHODS: [Method; 3] = [
    Method::Plain,
    Method::Block {
        switch_threshold: 0,
    },
    Method::Block {
        switch_threshold: 21,
    },
];

pub(super) fn link(
    method: Method,
    client_block: u8,
    server_block: u8,
    client_crc: bool,
    server_crc: bool,
) -> Link {
    let client = ClientConfig {
        timeout: TIMEOUT,
        block_size: client_block,
        use_block_download_from: matches!(method, Method::Block { .. }).then_some(0),
        use_block_upload: matches!(method, Method::Block { .. }),
        switch_threshold: match method {
            Method::Block { switch_threshold } => switch_threshold,
            Method::Plain => 0,
        },
        crc: client_crc,
    };
    let server = ServerConfig {
        timeout: TIMEOUT,
        block_size: server_block,
        crc: server_crc,
        ..ServerConfig::default()
    };
    Link::new(
        SdoClient::new(node(), client),
        SdoServer::new(node(), server),
    )
}

/// Frames a lossless transfer of `len` bytes takes, requests and answers.
fn frames(
    method: Method,
    upload: bool,
    len: usize,
    client_block: usize,
    server_block: usize,
) -> usize {
    let segments = len.div_ceil(7).max(1);
    let blocks = |size: usize| segments.div_ceil(size);
    match method {
        Method::Plain if (1..=4).contains(&len) => 2,
        Method::Plain => 2 + 2 * segments,
        Method::Block { switch_threshold }
            if upload && switch_threshold > 0 && len <= usize::from(switch_threshold) =>
        {
            frames(Method::Plain, true, len, 0, 0)
        }
        // initiate ×2, start, segments, one ack per block, end ×2.
        Method::Block { .. } if upload => 5 + segments + blocks(client_block),
        // initiate ×2, segments, one ack per block, end ×2.
        Method::Block { .. } => 4 + segments + blocks(server_block),
    }
}

#[test]
fn every_kind_and_size_from_0_to_300_bytes() {
    let block_sizes = [1u8, 2, 7, 127];
    for len in 0..=300usize {
        let value: Vec<u8> = (0..len).map(|i| (i * 7 + len) as u8).collect();
        for (m, method) in METHODS.into_iter().enumerate() {
            let client_block = block_sizes[(len + m) % 4];
            let server_block = block_sizes[(len / 4 + m) % 4];
            let mut link = link(
                method,
                client_block,
                server_block,
                len % 2 == 0,
                len % 3 != 0,
            );
            assert_eq!(
                link.download(0x2000, 0, &value),
                Ok(Transfer::Downloaded),
                "{method:?} {len}"
            );
            assert_eq!(link.objects.value(0x2000, 0), &value[..]);
            let expected = frames(method, false, len, client_block.into(), server_block.into());
            assert_eq!(
                link.log.len(),
                expected,
                "download {method:?} {len}: {:?}",
                link.log
            );

            link.log.clear();
            assert_eq!(
                link.upload(0x2000, 0),
                Ok(Transfer::Uploaded(value.clone())),
                "{method:?} {len}"
            );
            let expected = frames(method, true, len, client_block.into(), server_block.into());
            assert_eq!(
                link.log.len(),
                expected,
                "upload {method:?} {len}: {:?}",
                link.log
            );
            assert!(link.client.is_idle() && link.server.is_idle());
        }
    }
}

#[test]
fn device_refusals_reach_the_client_with_their_codes() {
    for method in METHODS {
        let mut link = link(method, 127, 127, true, true);
        assert_eq!(
            link.upload(0x2FFF, 0),
            Err(SdoError::ServerAborted(AbortCode::ObjectDoesNotExist))
        );
        assert_eq!(
            link.download(0x1008, 0, b"not writable, read only"),
            Err(SdoError::ServerAborted(AbortCode::ReadOnlyObject))
        );
        assert_eq!(
            link.download(0x2002, 0, &counting(10)),
            Err(SdoError::ServerAborted(AbortCode::LengthTooHigh))
        );
        assert_eq!(
            link.upload(0x2003, 0),
            Err(SdoError::ServerAborted(AbortCode::WriteOnlyObject))
        );
        assert!(link.client.is_idle() && link.server.is_idle());
    }
}

#[test]
fn a_lost_block_segment_is_resent() {
    let value = counting(100);
    // Block download, blocks of 5: frame 0 is the initiate, 1 its answer,
    // 2.. the segments. Lose segment 2 of the first block, then the last
    // segment of the second block (the sub-block timeout recovers that one).
    for lost in [3usize, 12] {
        let mut link = link(
            Method::Block {
                switch_threshold: 0,
            },
            127,
            5,
            true,
            true,
        );
        let first = link.client.download(0x2000, 0, &value, link.now).unwrap();
        let result = link.run(first, &mut |n, _| n == lost);
        assert_eq!(result, Ok(Transfer::Downloaded), "lost {lost}");
        assert_eq!(link.objects.value(0x2000, 0), &value[..]);
    }
    // Block upload, blocks of 5: frames 0–2 are initiate, answer and start.
    link_upload_with_loss(&value, 4);
    link_upload_with_loss(&value, 7);
}

fn link_upload_with_loss(value: &[u8], lost: usize) {
    let mut link = link(
        Method::Block {
            switch_threshold: 0,
        },
        5,
        127,
        true,
        true,
    );
    link.objects
        .add(0x2100, 0, value.to_vec(), Access::ReadOnly, None);
    let first = link.client.upload(0x2100, 0, link.now).unwrap();
    let result = link.run(first, &mut |n, _| n == lost);
    assert_eq!(
        result,
        Ok(Transfer::Uploaded(value.to_vec())),
        "lost {lost}"
    );
}

#[test]
fn any_single_lost_frame_ends_in_the_right_value_or_an_error() {
    for method in METHODS {
        for len in [3, 20, 60] {
            let value = counting(len);
            for upload in [false, true] {
                for lost in 0..frames(method, upload, len, 4, 4) {
                    let mut link = link(method, 4, 4, true, true);
                    link.objects
                        .add(0x2100, 0, value.clone(), Access::ReadWrite, None);
                    let first = if upload {
                        link.client.upload(0x2100, 0, link.now).unwrap()
                    } else {
                        link.client.download(0x2100, 0, &value, link.now).unwrap()
                    };
                    let result = link.run(first, &mut |n, _| n == lost);
                    let case = format!("{method:?} upload {upload} len {len} lost {lost}");
                    match result {
                        Ok(Transfer::Uploaded(got)) => assert_eq!(got, value, "{case}"),
                        Ok(Transfer::Downloaded) => {
                            assert_eq!(link.objects.value(0x2100, 0), &value[..], "{case}")
                        }
                        Err(SdoError::Timeout) => {}
                        // The server gave up first, or saw the client's abort.
                        Err(SdoError::ServerAborted(AbortCode::TimedOut)) => {}
                        Err(other) => panic!("{case}: {other:?}"),
                    }
                    assert!(link.settle(), "{case}: both idle at last");
                }
            }
        }
    }
}

#[test]
fn the_client_aborts_mid_transfer_and_the_server_lets_go() {
    let mut link = link(
        Method::Block {
            switch_threshold: 0,
        },
        127,
        3,
        true,
        true,
    );
    let first = link
        .client
        .download(0x2000, 0, &counting(100), link.now)
        .unwrap();
    // Initiate and its answer, and the first block: the server acknowledges.
    let mut bus = first;
    for _ in 0..3 {
        let mut next = Vec::new();
        for frame in &bus {
            if frame.id() == link.client.request_id() {
                next.extend(link.server.handle_frame(frame, link.now, &mut link.objects));
            } else {
                next.extend(link.client.handle_frame(frame, link.now).send);
            }
        }
        bus = next;
    }
    assert!(!link.server.is_idle());
    let abort = link.client.abort(AbortCode::GeneralError);
    assert_eq!(
        abort,
        vec![req(abort_bytes(0x2000, 0, AbortCode::GeneralError))]
    );
    assert_eq!(
        link.server
            .handle_frame(&abort[0], link.now, &mut link.objects),
        Vec::new()
    );
    assert!(link.server.is_idle());
    assert!(link.objects.writes.is_empty());
    // Both are ready for the next transfer.
    assert_eq!(link.upload(0x1001, 0), Ok(Transfer::Uploaded(vec![0])));
}

#[test]
fn the_server_aborts_mid_transfer_when_the_client_goes_silent() {
    let mut link = link(Method::Plain, 127, 127, true, true);
    let first = link
        .client
        .download(0x2000, 0, &counting(50), link.now)
        .unwrap();
    // Every frame after the fourth is lost: the client's and the server's
    // timers both run out; whoever is first, both end idle.
    let result = link.run(first, &mut |n, _| n >= 4);
    assert!(matches!(result, Err(SdoError::Timeout)), "{result:?}");
    assert!(link.settle());
    assert!(link.objects.writes.is_empty());
}

/// A program image's size (CiA 302-3 0x1F50 is a DOMAIN written by block
/// download, CiA 301 §7.2.4.3.9 ff.): 64 KiB in 75 blocks of 127 segments,
/// with and without the CRC, and the value read back by block upload.
#[test]
fn a_64_kib_domain_goes_by_block_download_and_comes_back() {
    let value: Vec<u8> = (0..64 * 1024u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8)
        .collect();
    for crc in [true, false] {
        let mut link = link(
            Method::Block {
                switch_threshold: 0,
            },
            127,
            127,
            crc,
            crc,
        );
        assert_eq!(
            link.download(0x2000, 0, &value),
            Ok(Transfer::Downloaded),
            "crc {crc}"
        );
        assert_eq!(link.objects.value(0x2000, 0), &value[..]);
        // Initiate and its answer, 9363 segments, a confirmation per block
        // of 127 (74 full blocks and one of 92), end and its answer.
        let segments = value.len().div_ceil(7);
        assert_eq!(segments, 9363);
        assert_eq!(link.log.len(), 2 + segments + segments.div_ceil(127) + 2);
        link.log.clear();
        assert_eq!(
            link.upload(0x2000, 0),
            Ok(Transfer::Uploaded(value.clone())),
            "crc {crc}"
        );
        assert!(link.client.is_idle() && link.server.is_idle());
    }
}
