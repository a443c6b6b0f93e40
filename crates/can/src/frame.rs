//! CAN frames as ISO 11898-1 defines them: classic data and remote frames with
//! 11-bit or 29-bit identifiers and 0–8 data bytes, CAN FD data frames of up to
//! 64 bytes, and the error frames a controller reports (SocketCAN's
//! `CAN_ERR_FLAG` frames, `linux/can/error.h`).
//!
//! A [`Frame`] is a plain value (`Copy`, no heap) because every frame on a bus is
//! fanned out to several readers; a [`TimedFrame`] adds when it was seen and in
//! which direction.

use std::fmt;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// Largest standard (11-bit) identifier, 0x7FF.
pub const STANDARD_ID_MAX: u16 = 0x7FF;
/// Largest extended (29-bit) identifier, 0x1FFF_FFFF.
pub const EXTENDED_ID_MAX: u32 = 0x1FFF_FFFF;
/// Data bytes of a classic CAN frame.
pub const CLASSIC_MAX_LEN: usize = 8;
/// Data bytes of a CAN FD frame.
pub const FD_MAX_LEN: usize = 64;
/// Payload length of an error frame (SocketCAN `CAN_ERR_DLC`).
pub const ERROR_FRAME_LEN: usize = 8;
/// The lengths a CAN FD frame can have: 0–8, then the DLC steps 9–15.
pub const FD_LENGTHS: [usize; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];

/// Why a frame could not be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("standard CAN identifier 0x{0:X} is above 0x7FF")]
    StandardIdOutOfRange(u32),
    #[error("extended CAN identifier 0x{0:X} is above 0x1FFFFFFF")]
    ExtendedIdOutOfRange(u32),
    #[error("a classic CAN frame carries at most 8 data bytes, not {0}")]
    ClassicTooLong(usize),
    #[error("a CAN FD frame carries 0-8, 12, 16, 20, 24, 32, 48 or 64 data bytes, not {0}")]
    FdLength(usize),
    #[error("a remote frame requests 0 to 8 bytes, not {0}")]
    RemoteDlc(u8),
    #[error("error class 0x{0:X} is above 0x1FFFFFFF")]
    ErrorClassOutOfRange(u32),
}

/// A CAN identifier. The format is part of the identity: standard 0x123 and
/// extended 0x123 are different identifiers on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum CanId {
    /// 11-bit identifier (CAN 2.0A), 0x000–0x7FF.
    Standard(u16),
    /// 29-bit identifier (CAN 2.0B), 0x0000_0000–0x1FFF_FFFF.
    Extended(u32),
}

impl CanId {
    /// A standard identifier, checked against 0x7FF.
    pub fn standard(raw: u32) -> Result<Self, FrameError> {
        if raw > u32::from(STANDARD_ID_MAX) {
            return Err(FrameError::StandardIdOutOfRange(raw));
        }
        Ok(Self::Standard(raw as u16))
    }

    /// An extended identifier, checked against 0x1FFFFFFF.
    pub fn extended(raw: u32) -> Result<Self, FrameError> {
        if raw > EXTENDED_ID_MAX {
            return Err(FrameError::ExtendedIdOutOfRange(raw));
        }
        Ok(Self::Extended(raw))
    }

    /// The identifier's numeric value, without any format flag.
    pub fn raw(self) -> u32 {
        match self {
            Self::Standard(id) => u32::from(id),
            Self::Extended(id) => id,
        }
    }

    pub fn is_extended(self) -> bool {
        matches!(self, Self::Extended(_))
    }
}

impl fmt::Display for CanId {
    /// candump spelling: three hex digits for standard, eight for extended.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Standard(id) => write!(f, "{id:03X}"),
            Self::Extended(id) => write!(f, "{id:08X}"),
        }
    }
}

/// CAN FD flags (SocketCAN `canfd_frame.flags`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct FdFlags {
    /// Bit rate switch: the data phase ran at the data bit rate (wire value 0x01).
    pub brs: bool,
    /// Error state indicator: the sender was error passive (wire value 0x02).
    pub esi: bool,
}

impl FdFlags {
    /// The flag byte as SocketCAN and socketcand write it (BRS 0x01, ESI 0x02).
    pub fn raw(self) -> u8 {
        u8::from(self.brs) | (u8::from(self.esi) << 1)
    }

    /// Reads a flag byte; other bits (such as SocketCAN's FDF 0x04) are ignored.
    pub fn from_raw(raw: u8) -> Self {
        Self {
            brs: raw & 0x01 != 0,
            esi: raw & 0x02 != 0,
        }
    }
}

/// What kind of frame this is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FrameKind {
    /// Classic data frame, 0–8 bytes.
    Data,
    /// Classic remote transmission request; the DLC is the length requested.
    Remote,
    /// CAN FD data frame, up to 64 bytes.
    Fd(FdFlags),
    /// An error reported by a CAN controller. The identifier carries the error
    /// class bits (`CAN_ERR_*` of `linux/can/error.h`) and the 8 data bytes
    /// their details.
    Error,
}

/// One CAN frame. See the module documentation.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Frame {
    id: CanId,
    kind: FrameKind,
    /// Data length for data/FD/error frames, requested DLC for remote frames.
    len: u8,
    data: [u8; FD_MAX_LEN],
}

impl Frame {
    /// A classic data frame with 0–8 bytes.
    pub fn new(id: CanId, data: &[u8]) -> Result<Self, FrameError> {
        if data.len() > CLASSIC_MAX_LEN {
            return Err(FrameError::ClassicTooLong(data.len()));
        }
        Ok(Self::build(id, FrameKind::Data, data))
    }

    /// A remote frame requesting `dlc` (0–8) bytes.
    pub fn remote(id: CanId, dlc: u8) -> Result<Self, FrameError> {
        if usize::from(dlc) > CLASSIC_MAX_LEN {
            return Err(FrameError::RemoteDlc(dlc));
        }
        let mut frame = Self::build(id, FrameKind::Remote, &[]);
        frame.len = dlc;
        Ok(frame)
    }

    /// A CAN FD data frame. The length must be one a DLC can express.
    pub fn fd(id: CanId, data: &[u8], flags: FdFlags) -> Result<Self, FrameError> {
        if !FD_LENGTHS.contains(&data.len()) {
            return Err(FrameError::FdLength(data.len()));
        }
        Ok(Self::build(id, FrameKind::Fd(flags), data))
    }

    /// An error frame: `class` holds the `CAN_ERR_*` class bits (without
    /// `CAN_ERR_FLAG`), `data` their details.
    pub fn error(class: u32, data: [u8; ERROR_FRAME_LEN]) -> Result<Self, FrameError> {
        if class > EXTENDED_ID_MAX {
            return Err(FrameError::ErrorClassOutOfRange(class));
        }
        Ok(Self::build(CanId::Extended(class), FrameKind::Error, &data))
    }

    fn build(id: CanId, kind: FrameKind, data: &[u8]) -> Self {
        let mut buf = [0u8; FD_MAX_LEN];
        buf[..data.len()].copy_from_slice(data);
        Self {
            id,
            kind,
            len: data.len() as u8,
            data: buf,
        }
    }

    pub fn id(&self) -> CanId {
        self.id
    }

    pub fn kind(&self) -> FrameKind {
        self.kind
    }

    /// The data bytes (empty for a remote frame).
    pub fn data(&self) -> &[u8] {
        match self.kind {
            FrameKind::Remote => &[],
            _ => &self.data[..usize::from(self.len)],
        }
    }

    /// The data length code: the byte count for classic frames, the requested
    /// length for remote frames, the 4-bit code for FD frames.
    pub fn dlc(&self) -> u8 {
        match self.kind {
            FrameKind::Fd(_) => FD_LENGTHS
                .iter()
                .position(|&l| l == usize::from(self.len))
                .unwrap_or(15) as u8,
            _ => self.len,
        }
    }

    pub fn is_remote(&self) -> bool {
        self.kind == FrameKind::Remote
    }

    pub fn is_error(&self) -> bool {
        self.kind == FrameKind::Error
    }

    pub fn is_fd(&self) -> bool {
        matches!(self.kind, FrameKind::Fd(_))
    }

    /// The error class bits of an error frame.
    pub fn error_class(&self) -> Option<u32> {
        self.is_error().then(|| self.id.raw())
    }

    /// Bits this frame occupies on the wire, without stuff bits: the basis of
    /// a bus-load estimate. Error frames count as the 14 bits of an error flag
    /// and delimiter; FD frames at the arbitration rate throughout.
    pub fn wire_bits(&self) -> u32 {
        let header = if self.id.is_extended() { 67 } else { 47 };
        match self.kind {
            FrameKind::Error => 14,
            FrameKind::Remote => header,
            FrameKind::Data | FrameKind::Fd(_) => header + 8 * u32::from(self.len),
        }
    }
}

impl fmt::Debug for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Frame({self})")
    }
}

impl fmt::Display for Frame {
    /// The candump frame spelling: `123#11223344`, `123#R2`, `123##1AABB`,
    /// and error frames with `CAN_ERR_FLAG` set in the identifier.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.kind {
            FrameKind::Error => write!(f, "{:08X}#", self.id.raw() | 0x2000_0000)?,
            FrameKind::Remote => {
                write!(f, "{}#R", self.id)?;
                if self.len > 0 {
                    write!(f, "{:X}", self.len)?;
                }
                return Ok(());
            }
            FrameKind::Fd(flags) => write!(f, "{}##{:X}", self.id, flags.raw())?,
            FrameKind::Data => write!(f, "{}#", self.id)?,
        }
        for byte in self.data() {
            write!(f, "{byte:02X}")?;
        }
        Ok(())
    }
}

/// Wall-clock time of a frame, in microseconds since the Unix epoch (the
/// resolution of candump logs and of socketcand's `SECS.USECS`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Timestamp(pub u64);

impl Timestamp {
    pub fn now() -> Self {
        Self::from(SystemTime::now())
    }

    pub fn from_micros(micros: u64) -> Self {
        Self(micros)
    }

    pub fn as_micros(self) -> u64 {
        self.0
    }

    pub fn secs(self) -> u64 {
        self.0 / 1_000_000
    }

    pub fn subsec_micros(self) -> u32 {
        (self.0 % 1_000_000) as u32
    }
}

impl From<SystemTime> for Timestamp {
    fn from(time: SystemTime) -> Self {
        let since = time.duration_since(UNIX_EPOCH).unwrap_or(Duration::ZERO);
        Self(since.as_micros() as u64)
    }
}

impl fmt::Display for Timestamp {
    /// `SECS.USECS` with six fractional digits.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}.{:06}", self.secs(), self.subsec_micros())
    }
}

/// Which way a frame went through a bus attachment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Sent by someone else and received here.
    Rx,
    /// Sent through this attachment (seen only by monitors).
    Tx,
}

/// A frame with the time it was seen and its direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimedFrame {
    pub frame: Frame,
    pub timestamp: Timestamp,
    pub direction: Direction,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn std_id(raw: u32) -> CanId {
        CanId::standard(raw).unwrap()
    }

    #[test]
    fn identifiers_are_range_checked() {
        assert_eq!(CanId::standard(0x7FF), Ok(CanId::Standard(0x7FF)));
        assert_eq!(
            CanId::standard(0x800),
            Err(FrameError::StandardIdOutOfRange(0x800))
        );
        assert_eq!(
            CanId::extended(0x1FFF_FFFF),
            Ok(CanId::Extended(0x1FFF_FFFF))
        );
        assert_eq!(
            CanId::extended(0x2000_0000),
            Err(FrameError::ExtendedIdOutOfRange(0x2000_0000))
        );
        assert_ne!(CanId::Standard(0x123), CanId::Extended(0x123));
    }

    #[test]
    fn classic_frames_hold_zero_to_eight_bytes() {
        for len in 0..=8 {
            let data: Vec<u8> = (0..len as u8).collect();
            let frame = Frame::new(std_id(0x123), &data).unwrap();
            assert_eq!(frame.data(), &data[..]);
            assert_eq!(usize::from(frame.dlc()), len);
        }
        assert_eq!(
            Frame::new(std_id(1), &[0; 9]),
            Err(FrameError::ClassicTooLong(9))
        );
    }

    #[test]
    fn remote_frames_carry_a_dlc_and_no_data() {
        let frame = Frame::remote(std_id(0x701), 1).unwrap();
        assert!(frame.is_remote());
        assert_eq!(frame.dlc(), 1);
        assert!(frame.data().is_empty());
        assert_eq!(Frame::remote(std_id(1), 9), Err(FrameError::RemoteDlc(9)));
    }

    #[test]
    fn fd_frames_take_only_dlc_lengths() {
        let flags = FdFlags {
            brs: true,
            esi: false,
        };
        let frame = Frame::fd(CanId::Extended(0x1234), &[0xAA; 64], flags).unwrap();
        assert_eq!(frame.data().len(), 64);
        assert_eq!(frame.dlc(), 15);
        assert_eq!(Frame::fd(std_id(1), &[0; 12], flags).unwrap().dlc(), 9);
        assert_eq!(
            Frame::fd(std_id(1), &[0; 10], flags),
            Err(FrameError::FdLength(10))
        );
        assert_eq!(FdFlags::from_raw(0x07).raw(), 0x03);
    }

    #[test]
    fn error_frames_keep_class_and_details() {
        let frame = Frame::error(0x004, [0, 0x10, 0, 0, 0, 0, 0, 0]).unwrap();
        assert!(frame.is_error());
        assert_eq!(frame.error_class(), Some(0x004));
        assert_eq!(frame.data()[1], 0x10);
        assert!(Frame::error(0x2000_0000, [0; 8]).is_err());
    }

    #[test]
    fn display_uses_candump_spelling() {
        let cases = [
            (
                Frame::new(std_id(0x123), &[0x11, 0x22]).unwrap(),
                "123#1122",
            ),
            (Frame::new(std_id(0x5), &[]).unwrap(), "005#"),
            (
                Frame::new(CanId::Extended(0x1ABC), &[0xFF]).unwrap(),
                "00001ABC#FF",
            ),
            (Frame::remote(std_id(0x701), 0).unwrap(), "701#R"),
            (Frame::remote(std_id(0x701), 3).unwrap(), "701#R3"),
            (
                Frame::fd(std_id(0x10), &[1, 2], FdFlags::from_raw(1)).unwrap(),
                "010##10102",
            ),
            (
                Frame::error(0x40, [0; 8]).unwrap(),
                "20000040#0000000000000000",
            ),
        ];
        for (frame, text) in cases {
            assert_eq!(frame.to_string(), text);
        }
    }

    #[test]
    fn wire_bits_grow_with_payload() {
        let empty = Frame::new(std_id(1), &[]).unwrap();
        let full = Frame::new(std_id(1), &[0; 8]).unwrap();
        let ext = Frame::new(CanId::Extended(1), &[0; 8]).unwrap();
        assert_eq!(empty.wire_bits(), 47);
        assert_eq!(full.wire_bits(), 111);
        assert_eq!(ext.wire_bits(), 131);
    }

    #[test]
    fn timestamps_print_six_fraction_digits() {
        assert_eq!(
            Timestamp(1_436_509_052_249_713).to_string(),
            "1436509052.249713"
        );
        assert_eq!(Timestamp(5).to_string(), "0.000005");
    }
}
