//! SDO server (CiA 301 §7.2.4.3): an arbitrary sequence of request frames
//! and timeouts into the sans-I/O machine, on a small dictionary with
//! read-only, write-only, fixed-size and domain objects. Nothing may panic;
//! every answer is an 8-byte frame on the response COB-ID; the machine has a
//! deadline exactly when a transfer is open; nothing larger than `max_size`
//! is ever stored.

use std::time::{Duration, Instant};

use super::{Event, Input};
use candeck::can::{CanId, Frame};
use candeck::canopen::NodeId;
use candeck::canopen::sdo::{AbortCode, ObjectAccess, SdoServer, ServerConfig};

/// One input: what the fuzz target and the seed replay run.
pub fn run(data: &[u8]) {
    let mut input = Input::new(data);
    let max_size = usize::from(input.byte()) * 8;
    let config = ServerConfig {
        timeout: Duration::from_millis(1000),
        block_size: input.byte(),
        crc: input.byte() & 1 == 1,
        max_size,
    };
    let mut server = SdoServer::new(NodeId::new(5).unwrap(), config);
    let mut objects = Objects::default();
    let mut now = Instant::now();
    while let Some(event) = input.event() {
        let sent = match event {
            Event::Frame(bytes) => {
                let frame = Frame::new(CanId::Standard(0x605), &bytes).unwrap();
                server.handle_frame(&frame, now, &mut objects)
            }
            Event::Wait(ms) => {
                now += Duration::from_millis(ms);
                server.handle_timeout(now)
            }
        };
        for frame in &sent {
            assert_eq!(frame.id(), CanId::Standard(0x585));
            assert_eq!(frame.data().len(), 8);
        }
        assert_eq!(server.is_idle(), server.deadline().is_none());
        assert!(
            objects.domain.len() <= max_size.max(4),
            "{} bytes stored",
            objects.domain.len()
        );
    }
}

/// 0x1000:00 read-only UNSIGNED32, 0x2000:00 a domain, 0x2001:00 a
/// read-write UNSIGNED8, 0x2002:00 write-only; nothing else exists.
#[derive(Default)]
struct Objects {
    domain: Vec<u8>,
    byte: u8,
}

impl ObjectAccess for Objects {
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
        match (index, sub) {
            (0x1000, 0) => Ok(0x0004_0192u32.to_le_bytes().to_vec()),
            (0x2000, 0) => Ok(self.domain.clone()),
            (0x2001, 0) => Ok(vec![self.byte]),
            (0x2002, 0) => Err(AbortCode::from_raw(0x0601_0001)),
            (0x1000 | 0x2000..=0x2002, _) => Err(AbortCode::from_raw(0x0609_0011)),
            _ => Err(AbortCode::from_raw(0x0602_0000)),
        }
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        match (index, sub) {
            (0x1000, 0) => Err(AbortCode::from_raw(0x0601_0002)),
            (0x2000, 0) => {
                self.domain = data.to_vec();
                Ok(())
            }
            (0x2001, 0) | (0x2002, 0) => match data {
                [byte] => {
                    self.byte = *byte;
                    Ok(())
                }
                _ => Err(AbortCode::from_raw(0x0607_0010)),
            },
            (0x1000 | 0x2000..=0x2002, _) => Err(AbortCode::from_raw(0x0609_0011)),
            _ => Err(AbortCode::from_raw(0x0602_0000)),
        }
    }

    fn fixed_size(&mut self, index: u16, sub: u8) -> Option<usize> {
        match (index, sub) {
            (0x1000, 0) => Some(4),
            (0x2001 | 0x2002, 0) => Some(1),
            _ => None,
        }
    }
}
