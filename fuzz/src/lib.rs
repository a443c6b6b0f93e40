//! What the fuzz targets share: reading an event script for the sans-I/O
//! SDO machines out of libFuzzer's bytes.
//!
//! The bytes are read as a script so that libFuzzer's mutations stay
//! meaningful: a header byte per event, `0xF0..=0xFF` meaning "time passes"
//! (0–1500 ms, enough to cross the machines' 1 s timeout) and anything else
//! a frame of `header % 9` bytes taken from what follows. Frame bytes are
//! copied unchanged, so the comparison tracing of libFuzzer can find the
//! command bytes and indexes the machines test for.
//!
//! Each target's check is a module here with a `run(&[u8])`: the libFuzzer
//! binaries of `fuzz_targets/` call it, and `tests/fuzz_seeds.rs` of candeck
//! replays every seed (and the corpus, when there is one) through it in the
//! ordinary test build, without an instrumented build.

pub mod eds;
pub mod rest_bodies;
pub mod sdo_client;
pub mod sdo_server;
pub mod socketcand_lines;

/// Something that happens to a machine.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// A frame with these 0–8 data bytes arrives.
    Frame(Vec<u8>),
    /// This many milliseconds pass.
    Wait(u64),
}

/// A cursor over the fuzzer's bytes.
pub struct Input<'a> {
    bytes: &'a [u8],
}

impl<'a> Input<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        Self { bytes }
    }

    /// The next byte, 0 once the input is used up (configuration bytes
    /// read past the end are zeros rather than a reason to reject it).
    pub fn byte(&mut self) -> u8 {
        match self.bytes.split_first() {
            Some((&first, rest)) => {
                self.bytes = rest;
                first
            }
            None => 0,
        }
    }

    /// The next event, `None` at the end of the input.
    pub fn event(&mut self) -> Option<Event> {
        let header = *self.bytes.first()?;
        self.bytes = &self.bytes[1..];
        if header >= 0xF0 {
            return Some(Event::Wait(u64::from(header & 0x0F) * 100));
        }
        let len = usize::from(header % 9).min(self.bytes.len());
        let (frame, rest) = self.bytes.split_at(len);
        self.bytes = rest;
        Some(Event::Frame(frame.to_vec()))
    }
}
