//! Tests of the SDO client and server: byte-exact exchanges with each machine
//! alone ([`client`], [`server`]), both machines wired together ([`wired`]),
//! and properties over arbitrary frames and values ([`props`]).

mod client;
mod props;
mod server;
mod wired;

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use crate::NodeId;
use crate::can::{CanId, Frame};

use super::{AbortCode, ObjectAccess, SdoClient, SdoError, SdoServer, Transfer};

/// The node every test talks to: requests on 0x605, responses on 0x585.
const NODE: u8 = 5;
const TIMEOUT: Duration = Duration::from_millis(1000);

fn node() -> NodeId {
    NodeId::new(NODE).unwrap()
}

/// A request frame (client to server, 0x605).
fn req(data: [u8; 8]) -> Frame {
    Frame::new(CanId::Standard(0x605), &data).unwrap()
}

/// A response frame (server to client, 0x585).
fn resp(data: [u8; 8]) -> Frame {
    Frame::new(CanId::Standard(0x585), &data).unwrap()
}

fn ms(ms: u64) -> Duration {
    Duration::from_millis(ms)
}

/// An abort frame's eight bytes.
fn abort_bytes(index: u16, sub: u8, code: AbortCode) -> [u8; 8] {
    let [lo, hi] = index.to_le_bytes();
    let [a, b, c, d] = code.raw().to_le_bytes();
    [0x80, lo, hi, sub, a, b, c, d]
}

/// Bytes 0, 1, 2, ... as a value.
fn counting(len: usize) -> Vec<u8> {
    (0..len).map(|i| i as u8).collect()
}

/// Seven bytes of `data` from `start`, zero-padded.
fn seven(data: &[u8], start: usize) -> [u8; 7] {
    let mut out = [0; 7];
    let end = (start + 7).min(data.len());
    out[..end - start].copy_from_slice(&data[start..end]);
    out
}

/// A segment frame: first byte, then seven data bytes.
fn seg(first: u8, data: [u8; 7]) -> [u8; 8] {
    let mut out = [first; 8];
    out[1..].copy_from_slice(&data);
    out
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Access {
    ReadWrite,
    ReadOnly,
    WriteOnly,
}

#[derive(Debug, Clone)]
struct Entry {
    value: Vec<u8>,
    access: Access,
    /// The size of a fixed-size type; `None` for strings and domains.
    fixed: Option<usize>,
}

/// A small object dictionary in memory, refusing as a device would.
#[derive(Debug, Clone)]
struct Objects {
    entries: BTreeMap<(u16, u8), Entry>,
    writes: Vec<(u16, u8, Vec<u8>)>,
}

impl Objects {
    fn new() -> Self {
        let mut objects = Self {
            entries: BTreeMap::new(),
            writes: Vec::new(),
        };
        let ro = Access::ReadOnly;
        let rw = Access::ReadWrite;
        objects.add(
            0x1000,
            0,
            0x0002_0192u32.to_le_bytes().to_vec(),
            ro,
            Some(4),
        );
        objects.add(0x1001, 0, vec![0], ro, Some(1));
        objects.add(0x1008, 0, b"candeck virtual device".to_vec(), ro, None);
        objects.add(0x2000, 0, Vec::new(), rw, None);
        objects.add(0x2001, 0, vec![0], rw, Some(1));
        objects.add(0x2002, 0, vec![0, 0], rw, Some(2));
        objects.add(0x2003, 0, vec![0; 4], Access::WriteOnly, Some(4));
        objects.add(0x2004, 0, vec![0; 8], rw, Some(8));
        objects
    }

    fn add(&mut self, index: u16, sub: u8, value: Vec<u8>, access: Access, fixed: Option<usize>) {
        self.entries.insert(
            (index, sub),
            Entry {
                value,
                access,
                fixed,
            },
        );
    }

    fn value(&self, index: u16, sub: u8) -> &[u8] {
        &self.entries[&(index, sub)].value
    }

    fn entry(&self, index: u16, sub: u8) -> Result<&Entry, AbortCode> {
        self.entries.get(&(index, sub)).ok_or_else(|| {
            if self.entries.keys().any(|&(i, _)| i == index) {
                AbortCode::SubIndexDoesNotExist
            } else {
                AbortCode::ObjectDoesNotExist
            }
        })
    }
}

impl ObjectAccess for Objects {
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
        let entry = self.entry(index, sub)?;
        if entry.access == Access::WriteOnly {
            return Err(AbortCode::WriteOnlyObject);
        }
        Ok(entry.value.clone())
    }

    fn check_write(&mut self, index: u16, sub: u8, size: Option<usize>) -> Result<(), AbortCode> {
        let entry = self.entry(index, sub)?;
        if entry.access == Access::ReadOnly {
            return Err(AbortCode::ReadOnlyObject);
        }
        match (entry.fixed, size) {
            (Some(fixed), Some(size)) if size > fixed => Err(AbortCode::LengthTooHigh),
            (Some(fixed), Some(size)) if size < fixed => Err(AbortCode::LengthTooLow),
            _ => Ok(()),
        }
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        self.check_write(index, sub, Some(data.len()))?;
        self.writes.push((index, sub, data.to_vec()));
        self.entries.get_mut(&(index, sub)).unwrap().value = data.to_vec();
        Ok(())
    }

    fn fixed_size(&mut self, index: u16, sub: u8) -> Option<usize> {
        self.entry(index, sub).ok()?.fixed
    }
}

/// A client and a server on one bus, frames delivered in the order sent and
/// time advanced only to the next deadline: no real waiting.
struct Link {
    client: SdoClient,
    server: SdoServer,
    objects: Objects,
    now: Instant,
    /// Every frame sent, lost ones included.
    log: Vec<Frame>,
}

impl Link {
    fn new(client: SdoClient, server: SdoServer) -> Self {
        Self {
            client,
            server,
            objects: Objects::new(),
            now: Instant::now(),
            log: Vec::new(),
        }
    }

    fn upload(&mut self, index: u16, sub: u8) -> Result<Transfer, SdoError> {
        let first = self.client.upload(index, sub, self.now).unwrap();
        self.run(first, &mut |_, _| false)
    }

    fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<Transfer, SdoError> {
        let first = self.client.download(index, sub, data, self.now).unwrap();
        self.run(first, &mut |_, _| false)
    }

    /// Carries frames until the client's transfer ends, then delivers what is
    /// still on the bus. `lose(n, frame)` says whether the `n`th frame sent
    /// (counting from the start of the log) is lost.
    fn run(
        &mut self,
        first: Vec<Frame>,
        lose: &mut dyn FnMut(usize, &Frame) -> bool,
    ) -> Result<Transfer, SdoError> {
        let mut bus: VecDeque<Frame> = first.into();
        let mut outcome = None;
        for _ in 0..1_000_000 {
            if let Some(frame) = bus.pop_front() {
                let n = self.log.len();
                self.log.push(frame);
                if lose(n, &frame) {
                    continue;
                }
                if frame.id() == self.client.request_id() {
                    let answer = self
                        .server
                        .handle_frame(&frame, self.now, &mut self.objects);
                    bus.extend(answer);
                } else {
                    let step = self.client.handle_frame(&frame, self.now);
                    assert!(step.done.is_none() || self.client.is_idle());
                    bus.extend(step.send);
                    if step.done.is_some() {
                        outcome = step.done;
                    }
                }
                continue;
            }
            if let Some(done) = outcome.take() {
                return done;
            }
            let next = [self.client.deadline(), self.server.deadline()]
                .into_iter()
                .flatten()
                .min()
                .expect("a transfer under way has a deadline");
            self.now = self.now.max(next);
            let step = self.client.handle_timeout(self.now);
            bus.extend(step.send);
            if step.done.is_some() {
                outcome = step.done;
            }
            bus.extend(self.server.handle_timeout(self.now));
        }
        panic!("the transfer did not end");
    }

    /// Lets the server's deadline pass if it still waits for a client that
    /// gave up (its abort lost), and says whether both are idle then.
    fn settle(&mut self) -> bool {
        if let Some(deadline) = self.server.deadline() {
            self.now = self.now.max(deadline);
            self.server.handle_timeout(self.now);
        }
        self.client.is_idle() && self.server.is_idle()
    }
}
