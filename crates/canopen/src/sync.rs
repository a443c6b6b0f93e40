//! The SYNC object (CiA 301 §7.2.5): a producer that broadcasts SYNC every
//! communication cycle period (0x1006, µs), optionally with a counter
//! (0x1019, synchronous counter overflow value), and the consumer side that
//! reads it.
//!
//! A SYNC is COB-ID 0x080 (0x1005 may move it) with no data, or with one byte:
//! a counter that runs 1, 2, … up to the overflow value and starts again at 1.
//! A consumer configured for one form that receives the other reports it
//! (EMCY 0x8240, unexpected SYNC data length) and does not act on it, as
//! CANopenNode does.

use std::time::{Duration, Instant};

use crate::can::{CanId, Frame};

/// The COB-ID of SYNC in the predefined connection set.
pub const SYNC_COB_ID: u16 = 0x080;
/// The highest SYNC counter overflow value (0x1019) and counter value.
pub const COUNTER_MAX: u8 = 240;
/// EMCY error code for a SYNC of the wrong length.
pub const EMCY_UNEXPECTED_SYNC_LENGTH: u16 = 0x8240;
/// SDO abort code "value range of parameter exceeded".
const ABORT_VALUE_RANGE: u32 = 0x0609_0030;
/// SDO abort code "data cannot be transferred or stored because of the
/// present device state".
const ABORT_DEVICE_STATE: u32 = 0x0800_0022;

/// Why a SYNC or a SYNC setting is not acceptable.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SyncError {
    #[error("a SYNC is a data frame, not a remote request")]
    Remote,
    #[error("a SYNC has 0 or 1 data bytes, not {0}")]
    Length(usize),
    #[error("SYNC counter {0} is not 1 to 240")]
    Counter(u8),
    #[error("a SYNC with {got} data bytes where {expected} is expected")]
    UnexpectedLength { expected: usize, got: usize },
    #[error("SYNC counter overflow value {0} is not 0 or 2 to 240")]
    Overflow(u8),
    #[error("the SYNC counter overflow value can be changed only while the SYNC period is 0")]
    WhileRunning,
}

impl SyncError {
    /// The EMCY error code a device signals for a received SYNC with this
    /// error: 0x8240 for a wrong length.
    pub fn emcy_code(&self) -> Option<u16> {
        match self {
            Self::Length(_) | Self::UnexpectedLength { .. } => Some(EMCY_UNEXPECTED_SYNC_LENGTH),
            _ => None,
        }
    }

    /// The SDO abort code for a rejected write of 0x1019.
    pub fn abort_code(&self) -> Option<u32> {
        match self {
            Self::Overflow(_) => Some(ABORT_VALUE_RANGE),
            Self::WhileRunning => Some(ABORT_DEVICE_STATE),
            _ => None,
        }
    }
}

/// One SYNC message: no data, or a counter 1–240.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SyncMessage {
    pub counter: Option<u8>,
}

impl SyncMessage {
    pub fn new(counter: Option<u8>) -> Self {
        Self { counter }
    }

    /// The frame on `cob_id` (normally [`SYNC_COB_ID`]).
    pub fn encode(self, cob_id: CanId) -> Frame {
        let data = self.counter.as_slice();
        Frame::new(cob_id, data).expect("a SYNC has at most one byte")
    }

    /// Reads the data of a SYNC; which COB-ID carries SYNC is the caller's
    /// configuration. A counter outside 1–240 is an error.
    pub fn decode(frame: &Frame) -> Result<Self, SyncError> {
        if frame.is_remote() {
            return Err(SyncError::Remote);
        }
        match *frame.data() {
            [] => Ok(Self { counter: None }),
            [counter @ 1..=COUNTER_MAX] => Ok(Self {
                counter: Some(counter),
            }),
            [counter] => Err(SyncError::Counter(counter)),
            ref data => Err(SyncError::Length(data.len())),
        }
    }
}

/// Checks a synchronous counter overflow value (0x1019): 0 means no counter,
/// 1 and 241–255 are reserved.
fn check_overflow(overflow: u8) -> Result<(), SyncError> {
    match overflow {
        0 | 2..=COUNTER_MAX => Ok(()),
        other => Err(SyncError::Overflow(other)),
    }
}

/// The SYNC producer (of a device whose 0x1005 bit 30 is set, or of the
/// gateway).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SyncProducer {
    cob_id: CanId,
    period: Option<Duration>,
    overflow: u8,
    /// The counter of the next SYNC, 1..=overflow.
    counter: u8,
    next: Option<Instant>,
}

impl Default for SyncProducer {
    fn default() -> Self {
        Self::new()
    }
}

impl SyncProducer {
    /// A producer on 0x080 that is off, without counter.
    pub fn new() -> Self {
        Self::with_cob_id(CanId::Standard(SYNC_COB_ID))
    }

    /// A producer on another COB-ID (0x1005 bits 0–28).
    pub fn with_cob_id(cob_id: CanId) -> Self {
        Self {
            cob_id,
            period: None,
            overflow: 0,
            counter: 1,
            next: None,
        }
    }

    pub fn cob_id(&self) -> CanId {
        self.cob_id
    }

    /// Sets the communication cycle period (0x1006, µs; 0 turns SYNC off).
    pub fn set_period_us(&mut self, period_us: u32, now: Instant) {
        self.set_period(Duration::from_micros(u64::from(period_us)), now);
    }

    /// Sets the period (zero turns SYNC off). The first SYNC is one period
    /// from `now`; starting from off also starts the counter at 1 again.
    pub fn set_period(&mut self, period: Duration, now: Instant) {
        if self.period.is_none() {
            self.counter = 1;
        }
        self.period = (!period.is_zero()).then_some(period);
        self.next = self.period.map(|period| now + period);
    }

    pub fn period(&self) -> Option<Duration> {
        self.period
    }

    /// Sets the synchronous counter overflow value (0x1019): 0 for SYNC
    /// without counter, 2–240 for a counter running 1 to that value. CiA 301
    /// allows the change only while the period is 0.
    pub fn set_counter_overflow(&mut self, overflow: u8) -> Result<(), SyncError> {
        check_overflow(overflow)?;
        if self.period.is_some() {
            return Err(SyncError::WhileRunning);
        }
        self.overflow = overflow;
        self.counter = 1;
        Ok(())
    }

    pub fn counter_overflow(&self) -> u8 {
        self.overflow
    }

    /// The next SYNC's counter is 1 again (CiA 301: on the NMT transition
    /// from stopped to pre-operational or operational).
    pub fn reset_counter(&mut self) {
        self.counter = 1;
    }

    /// When the next SYNC is due; `None` while off.
    pub fn deadline(&self) -> Option<Instant> {
        self.next
    }

    /// The SYNC to send if one is due at `now`. A caller late by a period or
    /// more gets one SYNC, and the cycle restarts from `now`.
    #[must_use = "the frame must be sent"]
    pub fn poll(&mut self, now: Instant) -> Option<Frame> {
        let (period, due) = (self.period?, self.next?);
        if now < due {
            return None;
        }
        let next = due + period;
        self.next = Some(if next <= now { now + period } else { next });
        let counter = (self.overflow > 0).then_some(self.counter);
        if self.overflow > 0 {
            self.counter = if self.counter >= self.overflow {
                1
            } else {
                self.counter + 1
            };
        }
        Some(SyncMessage { counter }.encode(self.cob_id))
    }
}

/// The SYNC consumer of a device: which frames are SYNC, and whether they
/// have the length the counter overflow value (0x1019) implies.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SyncConsumer {
    cob_id: CanId,
    overflow: u8,
}

impl Default for SyncConsumer {
    fn default() -> Self {
        Self::new()
    }
}

impl SyncConsumer {
    /// A consumer of SYNC on 0x080 without counter.
    pub fn new() -> Self {
        Self::with_cob_id(CanId::Standard(SYNC_COB_ID))
    }

    pub fn with_cob_id(cob_id: CanId) -> Self {
        Self {
            cob_id,
            overflow: 0,
        }
    }

    pub fn cob_id(&self) -> CanId {
        self.cob_id
    }

    /// Sets the counter overflow value (0x1019) the SYNC producer uses: 0
    /// expects SYNC without data, 2–240 with a one-byte counter.
    pub fn set_counter_overflow(&mut self, overflow: u8) -> Result<(), SyncError> {
        check_overflow(overflow)?;
        self.overflow = overflow;
        Ok(())
    }

    /// Takes any received frame: `Ok(None)` for frames that are not SYNC, the
    /// SYNC (with its counter) otherwise, or why it is malformed; a device
    /// does not act on a malformed SYNC and signals EMCY
    /// [`SyncError::emcy_code`].
    pub fn on_frame(&self, frame: &Frame) -> Result<Option<SyncMessage>, SyncError> {
        if frame.id() != self.cob_id {
            return Ok(None);
        }
        let message = SyncMessage::decode(frame)?;
        let expected = usize::from(self.overflow > 0);
        let got = usize::from(message.counter.is_some());
        if got != expected {
            return Err(SyncError::UnexpectedLength { expected, got });
        }
        Ok(Some(message))
    }
}

#[cfg(test)]
mod tests;
