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
mod tests {
    use super::*;

    const SYNC: CanId = CanId::Standard(SYNC_COB_ID);

    fn us(us: u64) -> Duration {
        Duration::from_micros(us)
    }

    fn sync(data: &[u8]) -> Frame {
        Frame::new(SYNC, data).unwrap()
    }

    #[test]
    fn sync_frames_encode_byte_exact() {
        assert_eq!(SyncMessage::new(None).encode(SYNC).to_string(), "080#");
        assert_eq!(SyncMessage::new(Some(1)).encode(SYNC).to_string(), "080#01");
        assert_eq!(
            SyncMessage::new(Some(240)).encode(SYNC).to_string(),
            "080#F0"
        );
        assert_eq!(
            SyncMessage::new(None)
                .encode(CanId::Extended(0x1000_0080))
                .to_string(),
            "10000080#"
        );
    }

    #[test]
    fn sync_frames_decode_and_reject_malformed_ones() {
        assert_eq!(SyncMessage::decode(&sync(&[])), Ok(SyncMessage::new(None)));
        assert_eq!(
            SyncMessage::decode(&sync(&[0x01])),
            Ok(SyncMessage::new(Some(1)))
        );
        assert_eq!(
            SyncMessage::decode(&sync(&[0xF0])),
            Ok(SyncMessage::new(Some(240)))
        );
        assert_eq!(
            SyncMessage::decode(&sync(&[0x00])),
            Err(SyncError::Counter(0))
        );
        assert_eq!(
            SyncMessage::decode(&sync(&[0xF1])),
            Err(SyncError::Counter(241))
        );
        assert_eq!(
            SyncMessage::decode(&sync(&[1, 2])),
            Err(SyncError::Length(2))
        );
        assert_eq!(
            SyncMessage::decode(&sync(&[0; 8])),
            Err(SyncError::Length(8))
        );
        assert_eq!(
            SyncMessage::decode(&Frame::remote(SYNC, 0).unwrap()),
            Err(SyncError::Remote)
        );
        assert_eq!(SyncError::Length(2).emcy_code(), Some(0x8240));
        assert_eq!(SyncError::Counter(0).emcy_code(), None);
    }

    #[test]
    fn the_producer_sends_every_period_without_counter() {
        let t0 = Instant::now();
        let mut producer = SyncProducer::new();
        assert_eq!(producer.poll(t0 + us(1_000_000)), None);
        producer.set_period_us(10_000, t0);
        assert_eq!(producer.period(), Some(us(10_000)));
        assert_eq!(producer.deadline(), Some(t0 + us(10_000)));
        assert_eq!(producer.poll(t0 + us(9_999)), None);
        assert_eq!(producer.poll(t0 + us(10_000)).unwrap().to_string(), "080#");
        assert_eq!(producer.deadline(), Some(t0 + us(20_000)));
        // Late by less than a period: no drift.
        assert!(producer.poll(t0 + us(21_000)).is_some());
        assert_eq!(producer.deadline(), Some(t0 + us(30_000)));
        // Late by several periods: one SYNC, not a burst.
        assert!(producer.poll(t0 + us(95_000)).is_some());
        assert_eq!(producer.poll(t0 + us(95_000)), None);
        assert_eq!(producer.deadline(), Some(t0 + us(105_000)));
        producer.set_period_us(0, t0 + us(100_000));
        assert_eq!(producer.deadline(), None);
        assert_eq!(producer.poll(t0 + us(1_000_000)), None);
    }

    #[test]
    fn the_counter_runs_from_1_to_the_overflow_value() {
        let t0 = Instant::now();
        let mut producer = SyncProducer::new();
        producer.set_counter_overflow(3).unwrap();
        assert_eq!(producer.counter_overflow(), 3);
        producer.set_period_us(1_000, t0);
        let sent: Vec<String> = (1..=7)
            .map(|n| producer.poll(t0 + us(1_000 * n)).unwrap().to_string())
            .collect();
        assert_eq!(
            sent,
            [
                "080#01", "080#02", "080#03", "080#01", "080#02", "080#03", "080#01"
            ]
        );
        producer.reset_counter();
        assert_eq!(producer.poll(t0 + us(8_000)).unwrap().to_string(), "080#01");
    }

    #[test]
    fn the_overflow_value_is_checked_and_fixed_while_running() {
        let t0 = Instant::now();
        let mut producer = SyncProducer::new();
        assert_eq!(
            producer.set_counter_overflow(1),
            Err(SyncError::Overflow(1))
        );
        assert_eq!(
            producer.set_counter_overflow(241),
            Err(SyncError::Overflow(241))
        );
        assert_eq!(SyncError::Overflow(1).abort_code(), Some(0x0609_0030));
        assert_eq!(producer.set_counter_overflow(240), Ok(()));
        assert_eq!(producer.set_counter_overflow(0), Ok(()));
        producer.set_period(us(500), t0);
        assert_eq!(
            producer.set_counter_overflow(10),
            Err(SyncError::WhileRunning)
        );
        assert_eq!(SyncError::WhileRunning.abort_code(), Some(0x0800_0022));
        producer.set_period(Duration::ZERO, t0);
        assert_eq!(producer.set_counter_overflow(10), Ok(()));
        // Restarting starts the counter at 1 again.
        producer.set_period(us(500), t0);
        let _ = producer.poll(t0 + us(500));
        let _ = producer.poll(t0 + us(1000));
        producer.set_period(Duration::ZERO, t0 + us(1000));
        producer.set_period(us(500), t0 + us(1000));
        assert_eq!(producer.poll(t0 + us(1500)).unwrap().to_string(), "080#01");
    }

    #[test]
    fn a_producer_on_another_cob_id() {
        let t0 = Instant::now();
        let mut producer = SyncProducer::with_cob_id(CanId::Standard(0x081));
        assert_eq!(producer.cob_id(), CanId::Standard(0x081));
        producer.set_period(us(100), t0);
        assert_eq!(producer.poll(t0 + us(100)).unwrap().to_string(), "081#");
    }

    #[test]
    fn the_consumer_extracts_the_counter() {
        let mut consumer = SyncConsumer::new();
        assert_eq!(
            consumer.on_frame(&sync(&[])),
            Ok(Some(SyncMessage::new(None)))
        );
        consumer.set_counter_overflow(10).unwrap();
        assert_eq!(
            consumer.on_frame(&sync(&[7])),
            Ok(Some(SyncMessage::new(Some(7))))
        );
        let other = Frame::new(CanId::Standard(0x081), &[1, 2, 3]).unwrap();
        assert_eq!(consumer.on_frame(&other), Ok(None));
        assert_eq!(
            consumer.set_counter_overflow(1),
            Err(SyncError::Overflow(1))
        );
    }

    #[test]
    fn the_consumer_reports_a_sync_of_the_wrong_length() {
        let mut consumer = SyncConsumer::new();
        let error = consumer.on_frame(&sync(&[5])).unwrap_err();
        assert_eq!(
            error,
            SyncError::UnexpectedLength {
                expected: 0,
                got: 1
            }
        );
        assert_eq!(error.emcy_code(), Some(0x8240));
        assert_eq!(consumer.on_frame(&sync(&[1, 2])), Err(SyncError::Length(2)));
        consumer.set_counter_overflow(5).unwrap();
        assert_eq!(
            consumer.on_frame(&sync(&[])),
            Err(SyncError::UnexpectedLength {
                expected: 1,
                got: 0
            })
        );
        assert_eq!(consumer.on_frame(&sync(&[0])), Err(SyncError::Counter(0)));
        assert_eq!(
            SyncError::UnexpectedLength {
                expected: 1,
                got: 0
            }
            .to_string(),
            "a SYNC with 0 data bytes where 1 is expected"
        );
    }
}
