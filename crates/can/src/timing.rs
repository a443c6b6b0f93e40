//! Time on the wire of a virtual bus (ISO 11898-1 classic CAN): a bit
//! rate, the length of each frame in bits, and arbitration.
//!
//! Sans-I/O like the protocol layer: [`Wire`] takes the frames senders
//! queue and the current time, and gives back the frames that have finished
//! crossing the bus and the instant the next one will. The hub
//! ([`VirtualHub`](super::VirtualHub)) drives it on tokio's clock.
//!
//! The model:
//!
//! - Each frame occupies the bus for [`frame_bits`] bit times: the frame
//!   with the **worst-case** number of stuff bits (one per four bits of the
//!   stuffed part, SOF to CRC), its CRC delimiter, ACK, end of frame and the
//!   three bits of intermission. The worst case is what bus-load planning
//!   uses, and it does not depend on the data, so a frame's time is known
//!   before it is sent: an 8-byte standard frame is 135 bits, 270 µs at
//!   500 kbit/s. FD frames are counted at the arbitration rate throughout.
//! - A frame waits while the bus is busy. When it is free, the frames at the
//!   head of every sender's queue arbitrate and the lowest identifier wins
//!   (a standard identifier beats an extended one with the same first 11
//!   bits, a data frame the remote frame with the same identifier), as the
//!   bitwise arbitration of ISO 11898-1 §10.4 decides. Frames that were not
//!   yet queued when the bus became free wait for the next round.
//! - Each sender's frames leave in the order it queued them: a FIFO
//!   transmit queue, as SocketCAN's, so that a master's RPDOs are not
//!   overtaken by its own SYNC.
//! - A frame reaches the receivers when its last bit has crossed the bus.

use std::collections::VecDeque;
use std::fmt;
use std::num::NonZeroU32;
use std::str::FromStr;
use std::time::{Duration, Instant};

use super::frame::{CanId, Frame, FrameKind};

/// The bit rate of `virtual:` buses and of `candeck vbus` unless told.
pub const DEFAULT_BITRATE: u32 = 500_000;

/// The bit rate of a virtual bus: a number of bit/s, or unlimited (every
/// frame crosses at once, as before the bus had a bit rate; for benchmarks
/// that measure the software rather than the wire).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Bitrate {
    Unlimited,
    BitsPerSecond(NonZeroU32),
}

impl Bitrate {
    /// `bits` bit/s; 0 is unlimited.
    pub fn bits_per_second(bits: u32) -> Self {
        NonZeroU32::new(bits).map_or(Self::Unlimited, Self::BitsPerSecond)
    }

    /// The rate in bit/s; `None` when unlimited.
    pub fn get(self) -> Option<u32> {
        match self {
            Self::Unlimited => None,
            Self::BitsPerSecond(bits) => Some(bits.get()),
        }
    }

    /// How long `bits` bit times last at this rate (zero when unlimited).
    pub fn duration_of(self, bits: u32) -> Duration {
        match self {
            Self::Unlimited => Duration::ZERO,
            Self::BitsPerSecond(rate) => {
                Duration::from_nanos(u64::from(bits) * 1_000_000_000 / u64::from(rate.get()))
            }
        }
    }
}

impl Default for Bitrate {
    fn default() -> Self {
        Self::bits_per_second(DEFAULT_BITRATE)
    }
}

impl fmt::Display for Bitrate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Unlimited => f.write_str("unlimited"),
            Self::BitsPerSecond(bits) => write!(f, "{bits}"),
        }
    }
}

/// A bit rate that is neither a number of bit/s nor `unlimited`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "bit rate '{0}' is not a number of bit/s from 1 to 1000000 (500000, 500k, 1M) or 'unlimited'"
)]
pub struct BitrateError(String);

impl FromStr for Bitrate {
    type Err = BitrateError;

    /// `unlimited`, or bit/s: `125000`, `125k`, `1M`. Classic CAN goes up
    /// to 1 Mbit/s.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let error = || BitrateError(text.to_string());
        let text = text.trim();
        if text.eq_ignore_ascii_case("unlimited") {
            return Ok(Self::Unlimited);
        }
        let (digits, factor) = match text.char_indices().last() {
            Some((at, 'k' | 'K')) => (&text[..at], 1_000),
            Some((at, 'm' | 'M')) => (&text[..at], 1_000_000),
            _ => (text, 1),
        };
        let bits = digits
            .parse::<u32>()
            .ok()
            .and_then(|n| n.checked_mul(factor))
            .filter(|bits| (1..=1_000_000).contains(bits))
            .ok_or_else(error)?;
        Ok(Self::bits_per_second(bits))
    }
}

/// Bit times a frame occupies the bus, with worst-case bit stuffing and
/// the 3 bits of intermission (see the module documentation): standard
/// data frames 47 + 8n + ⌊(33 + 8n) / 4⌋, extended 67 + 8n + ⌊(53 + 8n) /
/// 4⌋, remote frames as data frames without data. An error frame is its
/// flag and delimiter (14 bits) and the intermission.
pub fn frame_bits(frame: &Frame) -> u32 {
    if frame.is_error() {
        return frame.wire_bits() + 3;
    }
    let bits = frame.wire_bits();
    // Everything from SOF to the end of the CRC is stuffed; the CRC
    // delimiter, ACK, EOF and intermission (13 bits) are not.
    let stuffed = bits - 13;
    bits + (stuffed - 1) / 4
}

/// The frame's place in arbitration: lower wins. The bits in the order they
/// go on the wire (ISO 11898-1): identifier (the base 11 bits), then RTR or
/// SRR, IDE, the 18 extension bits and the extended frame's RTR.
pub fn arbitration_key(frame: &Frame) -> u64 {
    let remote = u64::from(frame.kind() == FrameKind::Remote);
    match frame.id() {
        CanId::Standard(id) => u64::from(id) << 21 | remote << 20,
        CanId::Extended(id) => {
            let base = u64::from(id >> 18);
            let extension = u64::from(id & 0x3_FFFF);
            base << 21 | 1 << 20 | 1 << 19 | extension << 1 | remote
        }
    }
}

/// A frame that has crossed the bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Crossed<S> {
    pub sender: S,
    pub frame: Frame,
    /// When its first bit went on the wire, after waiting for the bus.
    pub start: Instant,
    /// When its last bit did: when receivers have it.
    pub end: Instant,
}

struct Queued {
    frame: Frame,
    queued_at: Instant,
}

struct OnWire<S> {
    sender: S,
    frame: Frame,
    start: Instant,
    end: Instant,
}

/// The wire of one bus: the senders' transmit queues and the frame being
/// transmitted. `S` names a sender.
pub struct Wire<S> {
    bitrate: Bitrate,
    queues: Vec<(S, VecDeque<Queued>)>,
    on_wire: Option<OnWire<S>>,
    /// When the last frame's intermission ended: the bus is free from then.
    free_from: Option<Instant>,
    /// Bit times the bus has been busy since it was made.
    busy_bits: u64,
}

impl<S: Copy + Eq> Wire<S> {
    pub fn new(bitrate: Bitrate) -> Self {
        Self {
            bitrate,
            queues: Vec::new(),
            on_wire: None,
            free_from: None,
            busy_bits: 0,
        }
    }

    pub fn bitrate(&self) -> Bitrate {
        self.bitrate
    }

    /// Bit times the bus has been occupied, frames and intermissions.
    pub fn busy_bits(&self) -> u64 {
        self.busy_bits
    }

    /// `sender` queues `frame` at `now`.
    pub fn queue(&mut self, sender: S, frame: Frame, now: Instant) {
        let queued = Queued {
            frame,
            queued_at: now,
        };
        match self.queues.iter_mut().find(|(s, _)| *s == sender) {
            Some((_, queue)) => queue.push_back(queued),
            None => self.queues.push((sender, VecDeque::from([queued]))),
        }
    }

    /// Replaces the frame with `frame`'s identifier that `sender` has
    /// queued (the last one, if several) by `frame`; `false` when there is
    /// none. It keeps its place in the queue.
    pub fn replace_queued(&mut self, sender: S, frame: Frame) -> bool {
        let Some((_, queue)) = self.queues.iter_mut().find(|(s, _)| *s == sender) else {
            return false;
        };
        match queue.iter_mut().rev().find(|q| q.frame.id() == frame.id()) {
            Some(queued) => {
                queued.frame = frame;
                true
            }
            None => false,
        }
    }

    /// Frames `sender` has queued that have not gone on the wire yet.
    pub fn queued(&self, sender: S) -> usize {
        self.queues
            .iter()
            .find(|(s, _)| *s == sender)
            .map_or(0, |(_, queue)| queue.len())
    }

    /// `sender` left the bus: its queued frames go with it (one on the wire
    /// finishes).
    pub fn remove(&mut self, sender: S) -> usize {
        let before = self.queues.len();
        let mut dropped = 0;
        self.queues.retain(|(s, queue)| {
            if *s == sender {
                dropped = queue.len();
            }
            *s != sender
        });
        debug_assert!(self.queues.len() + 1 >= before);
        dropped
    }

    /// Runs the bus up to `now`: the frames whose last bit crossed it by
    /// then, in the order they did. A caller that wakes late gets every
    /// frame the bus carried meanwhile, each with the instants it had.
    pub fn poll(&mut self, now: Instant) -> Vec<Crossed<S>> {
        let mut crossed = Vec::new();
        loop {
            if let Some(frame) = &self.on_wire {
                if frame.end > now {
                    break;
                }
                let frame = self.on_wire.take().expect("checked above");
                self.free_from = Some(frame.end);
                crossed.push(Crossed {
                    sender: frame.sender,
                    frame: frame.frame,
                    start: frame.start,
                    end: frame.end,
                });
            }
            if !self.start_next(now) {
                break;
            }
        }
        crossed
    }

    /// Arbitration when the bus is free: the round starts when the bus is
    /// free and a frame waits; the frames queued by then contend. `false`
    /// when no frame can start by `now`.
    fn start_next(&mut self, now: Instant) -> bool {
        let Some(first_queued) = self
            .queues
            .iter()
            .filter_map(|(_, queue)| queue.front().map(|q| q.queued_at))
            .min()
        else {
            return false;
        };
        let start = self
            .free_from
            .map_or(first_queued, |free| free.max(first_queued));
        if start > now {
            return false;
        }
        let winner = self
            .queues
            .iter()
            .enumerate()
            .filter_map(|(at, (_, queue))| {
                let head = queue.front()?;
                (head.queued_at <= start).then(|| (arbitration_key(&head.frame), at))
            })
            .min()
            .map(|(_, at)| at)
            .expect("the earliest queued frame contends");
        let (sender, queue) = &mut self.queues[winner];
        let sender = *sender;
        let frame = queue.pop_front().expect("a winner has a frame").frame;
        if queue.is_empty() {
            self.queues.swap_remove(winner);
        }
        let bits = frame_bits(&frame);
        self.busy_bits += u64::from(bits);
        self.on_wire = Some(OnWire {
            sender,
            frame,
            start,
            end: start + self.bitrate.duration_of(bits),
        });
        true
    }

    /// When [`Wire::poll`] has something next: the end of the frame on the
    /// wire, or the start of the next one's transmission (`None`: idle).
    pub fn deadline(&self) -> Option<Instant> {
        if let Some(frame) = &self.on_wire {
            return Some(frame.end);
        }
        let first_queued = self
            .queues
            .iter()
            .filter_map(|(_, queue)| queue.front().map(|q| q.queued_at))
            .min()?;
        Some(
            self.free_from
                .map_or(first_queued, |free| free.max(first_queued)),
        )
    }
}

#[cfg(test)]
mod tests;
