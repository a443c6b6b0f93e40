//! SDO client (CiA 301 §7.2.4.3): an arbitrary sequence of response frames
//! and timeouts into the sans-I/O machine while it runs downloads and
//! uploads by every method (expedited, segmented, block, with and without
//! CRC). Nothing may panic; every request is an 8-byte frame on the request
//! COB-ID; the machine has a deadline exactly when a transfer runs, and is
//! idle once it reports an outcome.

use std::time::{Duration, Instant};

use super::{Event, Input};
use candeck::can::{CanId, Frame};
use candeck::canopen::NodeId;
use candeck::canopen::sdo::{ClientConfig, SdoClient};

/// One input: what the fuzz target and the seed replay run.
pub fn run(data: &[u8]) {
    let mut input = Input::new(data);
    let flags = input.byte();
    let block = flags & 1 == 1;
    let config = ClientConfig {
        timeout: Duration::from_millis(1000),
        block_size: input.byte(),
        use_block_download_from: block.then_some(usize::from(input.byte() % 16)),
        use_block_upload: block,
        switch_threshold: input.byte(),
        crc: flags & 2 == 2,
    };
    let lengths = [input.byte(), input.byte()].map(usize::from);
    let mut client = SdoClient::new(NodeId::new(5).unwrap(), config);
    let mut now = Instant::now();
    let mut started = 0usize;
    while let Some(event) = input.event() {
        if client.is_idle() {
            // Keep a transfer running: downloads and uploads in turn.
            let frames = if started.is_multiple_of(2) {
                let value: Vec<u8> = (0..lengths[started / 2 % 2]).map(|i| i as u8).collect();
                client.download(0x2000, 0, &value, now)
            } else {
                client.upload(0x2000, 0, now)
            };
            assert_eq!(frames.map(|f| f.len()), Ok(1));
            started += 1;
        }
        let step = match event {
            Event::Frame(bytes) => {
                let frame = Frame::new(CanId::Standard(0x585), &bytes).unwrap();
                client.handle_frame(&frame, now)
            }
            Event::Wait(ms) => {
                now += Duration::from_millis(ms);
                client.handle_timeout(now)
            }
        };
        for frame in &step.send {
            assert_eq!(frame.id(), CanId::Standard(0x605));
            assert_eq!(frame.data().len(), 8);
        }
        if step.done.is_some() {
            assert!(client.is_idle());
        }
        assert_eq!(client.is_idle(), client.deadline().is_none());
    }
}
