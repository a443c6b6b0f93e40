//! Emergency messages, EMCY (CiA 301 §7.2.7): the 8-byte EMCY frame, the
//! error register (0x1001), the texts of error codes, and what a device
//! needs to produce EMCYs: the inhibit time (0x1015) between them and the
//! pre-defined error field (0x1003).
//!
//! An EMCY is COB-ID 0x080 + node (0x1014 may move it), 8 bytes: the error
//! code (u16, little-endian), the error register, 5 manufacturer-specific
//! bytes. Code 0x0000 (the whole 0x00xx class, as CiA 301 table 21 words it)
//! is "error reset or no error": the device sends it when its errors are
//! gone.
//!
//! # Layout
//!
//! - [`codes`]: the texts of CiA 301's and the UMC manual's error codes.

pub mod codes;

use std::collections::VecDeque;
use std::fmt;
use std::time::{Duration, Instant};

pub use codes::emcy_text;

use super::cob::{Function, NodeId};
use crate::can::{CanId, Frame};

/// Data bytes of an EMCY.
pub const EMCY_LEN: usize = 8;
/// EMCYs a producer keeps waiting for the inhibit time to pass.
pub const QUEUE_LEN: usize = 16;

/// Why a frame is not a well-formed EMCY.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EmcyError {
    #[error("identifier {0} is not an EMCY COB-ID (081 to 0FF)")]
    NotEmcy(CanId),
    #[error("an EMCY is a data frame, not a remote request")]
    Remote,
    #[error("an EMCY has 8 data bytes, not {0}")]
    Length(usize),
}

/// One bit of the error register (0x1001; UMC manual table 3.10).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorBit {
    /// Bit 0 (0x01): generic error; set whenever any error is present.
    Generic,
    /// Bit 1 (0x02): current.
    Current,
    /// Bit 2 (0x04): voltage.
    Voltage,
    /// Bit 3 (0x08): temperature.
    Temperature,
    /// Bit 4 (0x10): communication error (overrun, error state).
    Communication,
    /// Bit 5 (0x20): device profile specific.
    DeviceProfile,
    /// Bit 6 (0x40): reserved, always 0.
    Reserved,
    /// Bit 7 (0x80): manufacturer-specific.
    Manufacturer,
}

impl ErrorBit {
    /// Every bit, from bit 0 up.
    pub const ALL: [ErrorBit; 8] = [
        Self::Generic,
        Self::Current,
        Self::Voltage,
        Self::Temperature,
        Self::Communication,
        Self::DeviceProfile,
        Self::Reserved,
        Self::Manufacturer,
    ];

    /// The bit number, 0–7.
    pub fn bit(self) -> u8 {
        self as u8
    }

    pub fn mask(self) -> u8 {
        1 << self.bit()
    }

    /// A snake_case name for JSON: `generic`, `current`, `voltage`,
    /// `temperature`, `communication`, `device_profile`, `reserved`,
    /// `manufacturer`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Generic => "generic",
            Self::Current => "current",
            Self::Voltage => "voltage",
            Self::Temperature => "temperature",
            Self::Communication => "communication",
            Self::DeviceProfile => "device_profile",
            Self::Reserved => "reserved",
            Self::Manufacturer => "manufacturer",
        }
    }

    /// The description of UMC manual table 3.10.
    pub fn text(self) -> &'static str {
        match self {
            Self::Generic => "Generic error",
            Self::Current => "Current",
            Self::Voltage => "Voltage",
            Self::Temperature => "Temperature",
            Self::Communication => "Communication error (overrun, error state)",
            Self::DeviceProfile => "Device profile specific",
            Self::Reserved => "reserved (always 0 b)",
            Self::Manufacturer => "manufacturer-specific",
        }
    }
}

/// The error register (0x1001), sent in every EMCY.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ErrorRegister(u8);

impl ErrorRegister {
    /// No error.
    pub const NONE: ErrorRegister = ErrorRegister(0);

    pub fn from_raw(raw: u8) -> Self {
        Self(raw)
    }

    pub fn raw(self) -> u8 {
        self.0
    }

    pub fn is_empty(self) -> bool {
        self.0 == 0
    }

    pub fn contains(self, bit: ErrorBit) -> bool {
        self.0 & bit.mask() != 0
    }

    pub fn with(self, bit: ErrorBit) -> Self {
        Self(self.0 | bit.mask())
    }

    pub fn without(self, bit: ErrorBit) -> Self {
        Self(self.0 & !bit.mask())
    }

    /// The bits set, from bit 0 up.
    pub fn bits(self) -> impl Iterator<Item = ErrorBit> {
        ErrorBit::ALL
            .into_iter()
            .filter(move |&bit| self.contains(bit))
    }

    /// The names of the bits set, from bit 0 up.
    pub fn names(self) -> Vec<&'static str> {
        self.bits().map(ErrorBit::name).collect()
    }
}

impl fmt::Display for ErrorRegister {
    /// `0x03 (generic, current)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:02X}", self.0)?;
        if !self.is_empty() {
            write!(f, " ({})", self.names().join(", "))?;
        }
        Ok(())
    }
}

/// One emergency message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Emcy {
    /// The emergency error code ([`emcy_text`] gives its text).
    pub code: u16,
    pub register: ErrorRegister,
    /// Manufacturer-specific error information.
    pub manufacturer: [u8; 5],
}

impl Emcy {
    /// An EMCY without manufacturer-specific information.
    pub fn new(code: u16, register: ErrorRegister) -> Self {
        Self {
            code,
            register,
            manufacturer: [0; 5],
        }
    }

    /// "Error reset or no error" (code 0x0000) with the register as it is now.
    pub fn error_reset(register: ErrorRegister) -> Self {
        Self::new(0x0000, register)
    }

    /// Whether this is an error reset (class 0x00xx).
    pub fn is_reset(&self) -> bool {
        self.code & 0xFF00 == 0
    }

    /// The most specific text known for the error code.
    pub fn text(&self) -> String {
        emcy_text(self.code)
    }

    pub fn to_bytes(&self) -> [u8; EMCY_LEN] {
        let [code_lo, code_hi] = self.code.to_le_bytes();
        let [m0, m1, m2, m3, m4] = self.manufacturer;
        [code_lo, code_hi, self.register.raw(), m0, m1, m2, m3, m4]
    }

    pub fn from_bytes(data: &[u8]) -> Result<Self, EmcyError> {
        let &[code_lo, code_hi, register, m0, m1, m2, m3, m4] = data else {
            return Err(EmcyError::Length(data.len()));
        };
        Ok(Self {
            code: u16::from_le_bytes([code_lo, code_hi]),
            register: ErrorRegister(register),
            manufacturer: [m0, m1, m2, m3, m4],
        })
    }

    /// The frame of `node` in the predefined connection set (0x080 + node).
    pub fn encode(&self, node: NodeId) -> Frame {
        self.encode_on(Function::Emcy.can_id(node))
    }

    /// The frame on another COB-ID (0x1014).
    pub fn encode_on(&self, cob_id: CanId) -> Frame {
        Frame::new(cob_id, &self.to_bytes()).expect("8 bytes fit a frame")
    }

    /// Reads an EMCY of the predefined connection set, and whose it is.
    pub fn decode(frame: &Frame) -> Result<(NodeId, Self), EmcyError> {
        let Some((Function::Emcy, Some(node))) = Function::classify(frame.id()) else {
            return Err(EmcyError::NotEmcy(frame.id()));
        };
        if frame.is_remote() {
            return Err(EmcyError::Remote);
        }
        Ok((node, Self::from_bytes(frame.data())?))
    }
}

impl fmt::Display for Emcy {
    /// `0x4310 Excess temperature drive, register 0x09 (generic, temperature)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "0x{:04X} {}, register {}",
            self.code,
            self.text(),
            self.register
        )
    }
}

/// SDO abort code "sub-index does not exist".
const ABORT_NO_SUB: u32 = 0x0609_0011;
/// SDO abort code "no data available".
const ABORT_NO_DATA: u32 = 0x0800_0024;
/// SDO abort code "value range of parameter exceeded".
const ABORT_VALUE_RANGE: u32 = 0x0609_0030;
/// SDO abort code "attempt to write a read only object".
const ABORT_READ_ONLY: u32 = 0x0601_0002;

/// Why an access to the pre-defined error field (0x1003) is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ErrorHistoryError {
    #[error("0x1003 has no sub-index {0}")]
    NoSubIndex(u8),
    #[error("0x1003 sub-index {sub} holds no error: {count} are recorded")]
    NoData { sub: u8, count: u8 },
    #[error("only 0 may be written to 0x1003 sub-index 0, not {0}")]
    NotZero(u32),
    #[error("0x1003 sub-index {0} is read only")]
    ReadOnly(u8),
}

impl ErrorHistoryError {
    /// The SDO abort code a device answers with.
    pub fn abort_code(&self) -> u32 {
        match self {
            Self::NoSubIndex(_) => ABORT_NO_SUB,
            Self::NoData { .. } => ABORT_NO_DATA,
            Self::NotZero(_) => ABORT_VALUE_RANGE,
            Self::ReadOnly(_) => ABORT_READ_ONLY,
        }
    }
}

/// The pre-defined error field (0x1003): the errors that occurred, newest
/// at sub-index 1, at most `capacity` of them (the oldest falls out); sub 0
/// is the count, and writing 0 to it clears the field. Each entry is the
/// error code in bits 0–15 and manufacturer-specific information in bits
/// 16–31.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ErrorHistory {
    entries: VecDeque<u32>,
    capacity: u8,
}

impl ErrorHistory {
    /// A field of `capacity` entries: sub-indexes 1 to `capacity`, at most
    /// 254; 0 is taken as 1.
    pub fn new(capacity: u8) -> Self {
        let capacity = capacity.clamp(1, 254);
        Self {
            entries: VecDeque::with_capacity(usize::from(capacity)),
            capacity,
        }
    }

    pub fn capacity(&self) -> u8 {
        self.capacity
    }

    /// Sub-index 0: how many errors are recorded.
    pub fn count(&self) -> u8 {
        self.entries.len() as u8
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Records an error as the newest entry.
    pub fn push(&mut self, code: u16, info: u16) {
        if self.entries.len() == usize::from(self.capacity) {
            self.entries.pop_back();
        }
        self.entries
            .push_front(u32::from(info) << 16 | u32::from(code));
    }

    pub fn clear(&mut self) {
        self.entries.clear();
    }

    /// The entries, newest first.
    pub fn iter(&self) -> impl Iterator<Item = u32> + '_ {
        self.entries.iter().copied()
    }

    /// An SDO read of sub-index `sub`: 0 the count, 1 the newest error.
    pub fn read(&self, sub: u8) -> Result<u32, ErrorHistoryError> {
        if sub == 0 {
            return Ok(u32::from(self.count()));
        }
        if sub > self.capacity {
            return Err(ErrorHistoryError::NoSubIndex(sub));
        }
        self.entries
            .get(usize::from(sub - 1))
            .copied()
            .ok_or(ErrorHistoryError::NoData {
                sub,
                count: self.count(),
            })
    }

    /// An SDO write: only 0 to sub-index 0, which clears the field.
    pub fn write(&mut self, sub: u8, value: u32) -> Result<(), ErrorHistoryError> {
        match (sub, value) {
            (0, 0) => {
                self.clear();
                Ok(())
            }
            (0, value) => Err(ErrorHistoryError::NotZero(value)),
            (sub, _) if sub > self.capacity => Err(ErrorHistoryError::NoSubIndex(sub)),
            (sub, _) => Err(ErrorHistoryError::ReadOnly(sub)),
        }
    }
}

/// The EMCY producer of a device: it records errors in 0x1003 and sends
/// EMCYs no closer together than the inhibit time (0x1015). EMCYs raised
/// within the inhibit time wait, in order, up to [`QUEUE_LEN`] of them;
/// beyond that the newest are dropped (and counted), because the first
/// EMCYs name the cause and the later ones its consequences.
///
/// The device sends EMCYs only in pre-operational and operational
/// ([`NmtService::Emcy`](super::nmt::NmtService::Emcy)): it raises errors in
/// any state, and polls only when it may send.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EmcyProducer {
    cob_id: CanId,
    inhibit: Duration,
    last_sent: Option<Instant>,
    queue: VecDeque<(Emcy, Instant)>,
    dropped: u32,
    history: ErrorHistory,
}

impl EmcyProducer {
    /// A producer for `node` (COB-ID 0x080 + node) without inhibit time,
    /// with a 0x1003 of `history_len` entries.
    pub fn new(node: NodeId, history_len: u8) -> Self {
        Self::with_cob_id(Function::Emcy.can_id(node), history_len)
    }

    pub fn with_cob_id(cob_id: CanId, history_len: u8) -> Self {
        Self {
            cob_id,
            inhibit: Duration::ZERO,
            last_sent: None,
            queue: VecDeque::new(),
            dropped: 0,
            history: ErrorHistory::new(history_len),
        }
    }

    pub fn cob_id(&self) -> CanId {
        self.cob_id
    }

    /// Sets the inhibit time (0x1015, in units of 100 µs; 0 = none).
    pub fn set_inhibit_time_100us(&mut self, inhibit: u16) {
        self.inhibit = Duration::from_micros(100 * u64::from(inhibit));
    }

    pub fn inhibit_time(&self) -> Duration {
        self.inhibit
    }

    /// An error occurred at `now`: it is recorded in 0x1003 (with no
    /// manufacturer information) and queued to be sent. An error reset
    /// (0x00xx) is queued but not recorded.
    pub fn raise(&mut self, emcy: Emcy, now: Instant) {
        if !emcy.is_reset() {
            self.history.push(emcy.code, 0);
        }
        if self.queue.len() == QUEUE_LEN {
            self.dropped = self.dropped.saturating_add(1);
        } else {
            self.queue.push_back((emcy, now));
        }
    }

    /// Queues "error reset or no error" with the register as it is now.
    pub fn reset(&mut self, register: ErrorRegister, now: Instant) {
        self.raise(Emcy::error_reset(register), now);
    }

    /// When the next queued EMCY may be sent; `None` when none waits.
    pub fn deadline(&self) -> Option<Instant> {
        let &(_, raised) = self.queue.front()?;
        Some(match self.last_sent {
            Some(sent) => raised.max(sent + self.inhibit),
            None => raised,
        })
    }

    /// The next EMCY to send, if one waits and the inhibit time has passed.
    #[must_use = "the frame must be sent"]
    pub fn poll(&mut self, now: Instant) -> Option<Frame> {
        if self.deadline()? > now {
            return None;
        }
        let (emcy, _) = self.queue.pop_front()?;
        self.last_sent = Some(now);
        Some(emcy.encode_on(self.cob_id))
    }

    /// EMCYs waiting to be sent.
    pub fn pending(&self) -> usize {
        self.queue.len()
    }

    /// EMCYs dropped because the queue was full.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }

    /// The pre-defined error field (0x1003).
    pub fn history(&self) -> &ErrorHistory {
        &self.history
    }

    /// For SDO writes to 0x1003.
    pub fn history_mut(&mut self) -> &mut ErrorHistory {
        &mut self.history
    }
}

#[cfg(test)]
mod tests;
