//! Layer setting services, LSS (CiA 305 version 3.0): how a master gives a
//! node its node-ID and bit timing over the bus, identifying it by its LSS
//! address, the four values of 0x1018 (vendor-ID, product code, revision
//! number, serial number).
//!
//! Every LSS message is 8 bytes, byte 0 the command specifier (CiA 305
//! §4.3); the master sends on COB-ID 0x7E5, the slaves answer on 0x7E4
//! (§4.2). The services, by section of CiA 305:
//!
//! - switch state global (§6.3.2) and selective (§6.3.3): a slave is in the
//!   LSS waiting state or the configuration state; configuration services
//!   are obeyed only in the latter;
//! - configure node-ID (§6.4.2), configure and activate bit timing
//!   (§6.4.3, §6.4.4), store configuration (§6.4.5);
//! - inquire identity and node-ID (§6.5);
//! - identify remote slave, identify non-configured remote slave (§6.6.1,
//!   §6.6.2) and Fastscan (§6.7), the bit-by-bit search that finds an
//!   unconfigured slave's whole LSS address.
//!
//! As the rest of [crate], nothing here does I/O or reads a
//! clock: [`LssSlave`] takes a frame and gives its answer and what the
//! device must do; [`LssMaster`] takes frames and the current time and gives
//! frames, a deadline and the outcome.
//!
//! # Layout
//!
//! - this file: the command specifiers and the codec of the messages.
//! - [`slave`]: the slave's state machine (waiting/configuration, active,
//!   pending and stored node-ID).
//! - [`master`]: the master's state machine, one service at a time, with
//!   timeouts, and Fastscan for every unconfigured slave on the bus.

use std::fmt;

use crate::can::{CanId, Frame};

pub mod master;
pub mod slave;

pub use master::{LssError, LssMaster, LssOutcome, LssService, LssStep};
pub use slave::{LssSlave, LssSlaveEvent};

/// COB-ID of the LSS master's requests (CiA 305 §4.2).
pub const LSS_MASTER_COB_ID: u16 = 0x7E5;
/// COB-ID of the LSS slaves' answers.
pub const LSS_SLAVE_COB_ID: u16 = 0x7E4;
/// Every LSS message has 8 bytes.
pub const LSS_FRAME_LEN: usize = 8;
/// The node-ID of an unconfigured slave.
pub const UNCONFIGURED: u8 = 0xFF;
/// Fastscan's `BitChecked` value that resets every unconfigured slave's
/// scan and asks whether there is one (§6.7).
pub const FASTSCAN_CONFIRM: u8 = 0x80;

/// An LSS command specifier, byte 0 of every LSS message. The doc of each
/// variant gives its wire value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CommandSpecifier {
    /// 0x04: switch state global (request only).
    SwitchStateGlobal,
    /// 0x11: configure node-ID (request and answer).
    ConfigureNodeId,
    /// 0x13: configure bit timing parameters.
    ConfigureBitTiming,
    /// 0x15: activate bit timing parameters (request only).
    ActivateBitTiming,
    /// 0x17: store configuration.
    StoreConfiguration,
    /// 0x40: switch state selective, vendor-ID.
    SwitchSelectiveVendor,
    /// 0x41: switch state selective, product code.
    SwitchSelectiveProduct,
    /// 0x42: switch state selective, revision number.
    SwitchSelectiveRevision,
    /// 0x43: switch state selective, serial number.
    SwitchSelectiveSerial,
    /// 0x44: switch state selective answer.
    SwitchSelectiveResponse,
    /// 0x46: identify remote slave, vendor-ID.
    IdentifyVendor,
    /// 0x47: identify remote slave, product code.
    IdentifyProduct,
    /// 0x48: identify remote slave, lowest revision number.
    IdentifyRevisionLow,
    /// 0x49: identify remote slave, highest revision number.
    IdentifyRevisionHigh,
    /// 0x4A: identify remote slave, lowest serial number.
    IdentifySerialLow,
    /// 0x4B: identify remote slave, highest serial number.
    IdentifySerialHigh,
    /// 0x4C: identify non-configured remote slave.
    IdentifyNonConfigured,
    /// 0x4F: identify slave (answer to identify remote slave and Fastscan).
    IdentifySlave,
    /// 0x50: identify non-configured slave (answer).
    IdentifyNonConfiguredSlave,
    /// 0x51: Fastscan.
    Fastscan,
    /// 0x5A: inquire identity vendor-ID.
    InquireVendor,
    /// 0x5B: inquire identity product code.
    InquireProduct,
    /// 0x5C: inquire identity revision number.
    InquireRevision,
    /// 0x5D: inquire identity serial number.
    InquireSerial,
    /// 0x5E: inquire node-ID.
    InquireNodeId,
    /// Any other value.
    Unknown(u8),
}

impl CommandSpecifier {
    pub fn from_raw(raw: u8) -> Self {
        match raw {
            0x04 => Self::SwitchStateGlobal,
            0x11 => Self::ConfigureNodeId,
            0x13 => Self::ConfigureBitTiming,
            0x15 => Self::ActivateBitTiming,
            0x17 => Self::StoreConfiguration,
            0x40 => Self::SwitchSelectiveVendor,
            0x41 => Self::SwitchSelectiveProduct,
            0x42 => Self::SwitchSelectiveRevision,
            0x43 => Self::SwitchSelectiveSerial,
            0x44 => Self::SwitchSelectiveResponse,
            0x46 => Self::IdentifyVendor,
            0x47 => Self::IdentifyProduct,
            0x48 => Self::IdentifyRevisionLow,
            0x49 => Self::IdentifyRevisionHigh,
            0x4A => Self::IdentifySerialLow,
            0x4B => Self::IdentifySerialHigh,
            0x4C => Self::IdentifyNonConfigured,
            0x4F => Self::IdentifySlave,
            0x50 => Self::IdentifyNonConfiguredSlave,
            0x51 => Self::Fastscan,
            0x5A => Self::InquireVendor,
            0x5B => Self::InquireProduct,
            0x5C => Self::InquireRevision,
            0x5D => Self::InquireSerial,
            0x5E => Self::InquireNodeId,
            other => Self::Unknown(other),
        }
    }

    pub fn raw(self) -> u8 {
        match self {
            Self::SwitchStateGlobal => 0x04,
            Self::ConfigureNodeId => 0x11,
            Self::ConfigureBitTiming => 0x13,
            Self::ActivateBitTiming => 0x15,
            Self::StoreConfiguration => 0x17,
            Self::SwitchSelectiveVendor => 0x40,
            Self::SwitchSelectiveProduct => 0x41,
            Self::SwitchSelectiveRevision => 0x42,
            Self::SwitchSelectiveSerial => 0x43,
            Self::SwitchSelectiveResponse => 0x44,
            Self::IdentifyVendor => 0x46,
            Self::IdentifyProduct => 0x47,
            Self::IdentifyRevisionLow => 0x48,
            Self::IdentifyRevisionHigh => 0x49,
            Self::IdentifySerialLow => 0x4A,
            Self::IdentifySerialHigh => 0x4B,
            Self::IdentifyNonConfigured => 0x4C,
            Self::IdentifySlave => 0x4F,
            Self::IdentifyNonConfiguredSlave => 0x50,
            Self::Fastscan => 0x51,
            Self::InquireVendor => 0x5A,
            Self::InquireProduct => 0x5B,
            Self::InquireRevision => 0x5C,
            Self::InquireSerial => 0x5D,
            Self::InquireNodeId => 0x5E,
            Self::Unknown(raw) => raw,
        }
    }
}

/// The two LSS states of a slave (CiA 305 §5.3). The doc of each variant
/// gives the mode byte of switch state global.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LssState {
    /// 0x00: waiting: only switch state, identification and Fastscan.
    Waiting,
    /// 0x01: configuration: node-ID, bit timing, store and inquiry too.
    Configuration,
}

impl LssState {
    pub fn from_raw(raw: u8) -> Option<Self> {
        match raw {
            0 => Some(Self::Waiting),
            1 => Some(Self::Configuration),
            _ => None,
        }
    }

    pub fn raw(self) -> u8 {
        match self {
            Self::Waiting => 0,
            Self::Configuration => 1,
        }
    }
}

/// A slave's LSS address: 0x1018 sub 1 to 4.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, PartialOrd, Ord)]
pub struct LssAddress {
    pub vendor_id: u32,
    pub product_code: u32,
    pub revision: u32,
    pub serial: u32,
}

impl LssAddress {
    /// The four parts in wire order (Fastscan's `LSSSub` 0 to 3).
    pub fn parts(self) -> [u32; 4] {
        [
            self.vendor_id,
            self.product_code,
            self.revision,
            self.serial,
        ]
    }

    pub fn from_parts(parts: [u32; 4]) -> Self {
        Self {
            vendor_id: parts[0],
            product_code: parts[1],
            revision: parts[2],
            serial: parts[3],
        }
    }
}

impl fmt::Display for LssAddress {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "vendor 0x{:08X} product 0x{:08X} revision 0x{:08X} serial 0x{:08X}",
            self.vendor_id, self.product_code, self.revision, self.serial
        )
    }
}

/// One part of an LSS address, as inquiry and switch state selective name
/// it (0 vendor-ID … 3 serial number).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AddressPart {
    Vendor,
    Product,
    Revision,
    Serial,
}

impl AddressPart {
    pub const ALL: [AddressPart; 4] = [Self::Vendor, Self::Product, Self::Revision, Self::Serial];

    /// 0 to 3: Fastscan's `LSSSub`, the sub-index of 0x1018 minus one.
    pub fn position(self) -> usize {
        self as usize
    }

    pub fn of(self, address: LssAddress) -> u32 {
        address.parts()[self.position()]
    }
}

/// A bound of identify remote slave (CiA 305 §6.6.1): vendor and product
/// must be equal, revision and serial within [low, high].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum IdentifyPart {
    Vendor,
    Product,
    RevisionLow,
    RevisionHigh,
    SerialLow,
    SerialHigh,
}

impl IdentifyPart {
    pub const ALL: [IdentifyPart; 6] = [
        Self::Vendor,
        Self::Product,
        Self::RevisionLow,
        Self::RevisionHigh,
        Self::SerialLow,
        Self::SerialHigh,
    ];
}

/// What can be inquired (CiA 305 §6.5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Inquiry {
    Address(AddressPart),
    NodeId,
}

/// A request of the master, on COB-ID 0x7E5.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LssRequest {
    SwitchStateGlobal(LssState),
    SwitchStateSelective(AddressPart, u32),
    /// 1 to 127, or 0xFF to make the slave unconfigured.
    ConfigureNodeId(u8),
    /// A table selector (0: the CiA 301 table) and an index into it.
    ConfigureBitTiming {
        table: u8,
        index: u8,
    },
    ActivateBitTiming {
        delay_ms: u16,
    },
    StoreConfiguration,
    IdentifyRemoteSlave(IdentifyPart, u32),
    IdentifyNonConfigured,
    /// `bit_checked` is 0–31 or [`FASTSCAN_CONFIRM`]; `sub` and `next` 0–3.
    Fastscan {
        id_number: u32,
        bit_checked: u8,
        sub: u8,
        next: u8,
    },
    Inquire(Inquiry),
}

/// The result of a configuration service: 0 success, 1 not supported /
/// out of range, 2 (store) storage media error, 0xFF implementation
/// specific with `specific` set (CiA 305 §6.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ConfigResult {
    pub error: u8,
    pub specific: u8,
}

impl ConfigResult {
    pub const OK: ConfigResult = ConfigResult {
        error: 0,
        specific: 0,
    };

    pub fn error(error: u8) -> Self {
        Self { error, specific: 0 }
    }

    pub fn is_ok(self) -> bool {
        self.error == 0
    }
}

/// An answer of a slave, on COB-ID 0x7E4.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LssResponse {
    SwitchStateSelective,
    ConfigureNodeId(ConfigResult),
    ConfigureBitTiming(ConfigResult),
    StoreConfiguration(ConfigResult),
    IdentifySlave,
    IdentifyNonConfiguredSlave,
    /// The inquired value; a node-ID is 1–127 or 0xFF.
    Inquired(Inquiry, u32),
}

/// An LSS frame that cannot be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LssDecodeError {
    #[error("an LSS message has 8 bytes, not {0}")]
    Length(usize),
    #[error("unknown LSS command specifier 0x{0:02X}")]
    UnknownCommand(u8),
    #[error("switch state global mode {0} is neither 0 (waiting) nor 1 (configuration)")]
    Mode(u8),
    #[error("Fastscan BitChecked {0} is not 0 to 31 or 0x80")]
    BitChecked(u8),
    #[error("Fastscan LSSSub/LSSNext {0} is not 0 to 3")]
    Sub(u8),
    #[error("not an LSS frame")]
    NotLss,
}

fn u32_at(data: &[u8]) -> u32 {
    u32::from_le_bytes([data[1], data[2], data[3], data[4]])
}

fn lss_data(frame: &Frame, cob_id: u16) -> Result<[u8; 8], LssDecodeError> {
    if frame.id() != CanId::Standard(cob_id) || frame.is_remote() {
        return Err(LssDecodeError::NotLss);
    }
    <[u8; 8]>::try_from(frame.data()).map_err(|_| LssDecodeError::Length(frame.data().len()))
}

fn frame(cob_id: u16, data: [u8; 8]) -> Frame {
    Frame::new(CanId::Standard(cob_id), &data).expect("8 bytes fit a classic frame")
}

impl LssRequest {
    pub fn command(self) -> CommandSpecifier {
        use CommandSpecifier as C;
        match self {
            Self::SwitchStateGlobal(_) => C::SwitchStateGlobal,
            Self::SwitchStateSelective(part, _) => match part {
                AddressPart::Vendor => C::SwitchSelectiveVendor,
                AddressPart::Product => C::SwitchSelectiveProduct,
                AddressPart::Revision => C::SwitchSelectiveRevision,
                AddressPart::Serial => C::SwitchSelectiveSerial,
            },
            Self::ConfigureNodeId(_) => C::ConfigureNodeId,
            Self::ConfigureBitTiming { .. } => C::ConfigureBitTiming,
            Self::ActivateBitTiming { .. } => C::ActivateBitTiming,
            Self::StoreConfiguration => C::StoreConfiguration,
            Self::IdentifyRemoteSlave(part, _) => match part {
                IdentifyPart::Vendor => C::IdentifyVendor,
                IdentifyPart::Product => C::IdentifyProduct,
                IdentifyPart::RevisionLow => C::IdentifyRevisionLow,
                IdentifyPart::RevisionHigh => C::IdentifyRevisionHigh,
                IdentifyPart::SerialLow => C::IdentifySerialLow,
                IdentifyPart::SerialHigh => C::IdentifySerialHigh,
            },
            Self::IdentifyNonConfigured => C::IdentifyNonConfigured,
            Self::Fastscan { .. } => C::Fastscan,
            Self::Inquire(inquiry) => inquire_command(inquiry),
        }
    }

    pub fn encode(self) -> Frame {
        let mut data = [0u8; 8];
        data[0] = self.command().raw();
        match self {
            Self::SwitchStateGlobal(state) => data[1] = state.raw(),
            Self::SwitchStateSelective(_, value) | Self::IdentifyRemoteSlave(_, value) => {
                data[1..5].copy_from_slice(&value.to_le_bytes());
            }
            Self::ConfigureNodeId(node) => data[1] = node,
            Self::ConfigureBitTiming { table, index } => {
                data[1] = table;
                data[2] = index;
            }
            Self::ActivateBitTiming { delay_ms } => {
                data[1..3].copy_from_slice(&delay_ms.to_le_bytes());
            }
            Self::Fastscan {
                id_number,
                bit_checked,
                sub,
                next,
            } => {
                data[1..5].copy_from_slice(&id_number.to_le_bytes());
                data[5] = bit_checked;
                data[6] = sub;
                data[7] = next;
            }
            Self::StoreConfiguration | Self::IdentifyNonConfigured | Self::Inquire(_) => {}
        }
        frame(LSS_MASTER_COB_ID, data)
    }

    /// Reads a frame of COB-ID 0x7E5; [`LssDecodeError::NotLss`] for any
    /// other frame.
    pub fn decode(frame: &Frame) -> Result<Self, LssDecodeError> {
        use CommandSpecifier as C;
        let data = lss_data(frame, LSS_MASTER_COB_ID)?;
        let value = u32_at(&data);
        Ok(match CommandSpecifier::from_raw(data[0]) {
            C::SwitchStateGlobal => Self::SwitchStateGlobal(
                LssState::from_raw(data[1]).ok_or(LssDecodeError::Mode(data[1]))?,
            ),
            C::SwitchSelectiveVendor => Self::SwitchStateSelective(AddressPart::Vendor, value),
            C::SwitchSelectiveProduct => Self::SwitchStateSelective(AddressPart::Product, value),
            C::SwitchSelectiveRevision => Self::SwitchStateSelective(AddressPart::Revision, value),
            C::SwitchSelectiveSerial => Self::SwitchStateSelective(AddressPart::Serial, value),
            C::ConfigureNodeId => Self::ConfigureNodeId(data[1]),
            C::ConfigureBitTiming => Self::ConfigureBitTiming {
                table: data[1],
                index: data[2],
            },
            C::ActivateBitTiming => Self::ActivateBitTiming {
                delay_ms: u16::from_le_bytes([data[1], data[2]]),
            },
            C::StoreConfiguration => Self::StoreConfiguration,
            C::IdentifyVendor => Self::IdentifyRemoteSlave(IdentifyPart::Vendor, value),
            C::IdentifyProduct => Self::IdentifyRemoteSlave(IdentifyPart::Product, value),
            C::IdentifyRevisionLow => Self::IdentifyRemoteSlave(IdentifyPart::RevisionLow, value),
            C::IdentifyRevisionHigh => Self::IdentifyRemoteSlave(IdentifyPart::RevisionHigh, value),
            C::IdentifySerialLow => Self::IdentifyRemoteSlave(IdentifyPart::SerialLow, value),
            C::IdentifySerialHigh => Self::IdentifyRemoteSlave(IdentifyPart::SerialHigh, value),
            C::IdentifyNonConfigured => Self::IdentifyNonConfigured,
            C::Fastscan => {
                let (bit_checked, sub, next) = (data[5], data[6], data[7]);
                if bit_checked > 31 && bit_checked != FASTSCAN_CONFIRM {
                    return Err(LssDecodeError::BitChecked(bit_checked));
                }
                if let Some(bad) = [sub, next].into_iter().find(|v| *v > 3) {
                    return Err(LssDecodeError::Sub(bad));
                }
                Self::Fastscan {
                    id_number: value,
                    bit_checked,
                    sub,
                    next,
                }
            }
            C::InquireVendor => Self::Inquire(Inquiry::Address(AddressPart::Vendor)),
            C::InquireProduct => Self::Inquire(Inquiry::Address(AddressPart::Product)),
            C::InquireRevision => Self::Inquire(Inquiry::Address(AddressPart::Revision)),
            C::InquireSerial => Self::Inquire(Inquiry::Address(AddressPart::Serial)),
            C::InquireNodeId => Self::Inquire(Inquiry::NodeId),
            // Answers are no requests.
            other => return Err(LssDecodeError::UnknownCommand(other.raw())),
        })
    }
}

fn inquire_command(inquiry: Inquiry) -> CommandSpecifier {
    use CommandSpecifier as C;
    match inquiry {
        Inquiry::Address(AddressPart::Vendor) => C::InquireVendor,
        Inquiry::Address(AddressPart::Product) => C::InquireProduct,
        Inquiry::Address(AddressPart::Revision) => C::InquireRevision,
        Inquiry::Address(AddressPart::Serial) => C::InquireSerial,
        Inquiry::NodeId => C::InquireNodeId,
    }
}

impl LssResponse {
    pub fn command(self) -> CommandSpecifier {
        use CommandSpecifier as C;
        match self {
            Self::SwitchStateSelective => C::SwitchSelectiveResponse,
            Self::ConfigureNodeId(_) => C::ConfigureNodeId,
            Self::ConfigureBitTiming(_) => C::ConfigureBitTiming,
            Self::StoreConfiguration(_) => C::StoreConfiguration,
            Self::IdentifySlave => C::IdentifySlave,
            Self::IdentifyNonConfiguredSlave => C::IdentifyNonConfiguredSlave,
            Self::Inquired(inquiry, _) => inquire_command(inquiry),
        }
    }

    pub fn encode(self) -> Frame {
        let mut data = [0u8; 8];
        data[0] = self.command().raw();
        match self {
            Self::ConfigureNodeId(result)
            | Self::ConfigureBitTiming(result)
            | Self::StoreConfiguration(result) => {
                data[1] = result.error;
                data[2] = result.specific;
            }
            Self::Inquired(Inquiry::NodeId, node) => data[1] = node as u8,
            Self::Inquired(_, value) => data[1..5].copy_from_slice(&value.to_le_bytes()),
            Self::SwitchStateSelective | Self::IdentifySlave | Self::IdentifyNonConfiguredSlave => {
            }
        }
        frame(LSS_SLAVE_COB_ID, data)
    }

    /// Reads a frame of COB-ID 0x7E4; [`LssDecodeError::NotLss`] for any
    /// other frame.
    pub fn decode(frame: &Frame) -> Result<Self, LssDecodeError> {
        use CommandSpecifier as C;
        let data = lss_data(frame, LSS_SLAVE_COB_ID)?;
        let result = ConfigResult {
            error: data[1],
            specific: data[2],
        };
        let value = u32_at(&data);
        Ok(match CommandSpecifier::from_raw(data[0]) {
            C::SwitchSelectiveResponse => Self::SwitchStateSelective,
            C::ConfigureNodeId => Self::ConfigureNodeId(result),
            C::ConfigureBitTiming => Self::ConfigureBitTiming(result),
            C::StoreConfiguration => Self::StoreConfiguration(result),
            C::IdentifySlave => Self::IdentifySlave,
            C::IdentifyNonConfiguredSlave => Self::IdentifyNonConfiguredSlave,
            C::InquireVendor => Self::Inquired(Inquiry::Address(AddressPart::Vendor), value),
            C::InquireProduct => Self::Inquired(Inquiry::Address(AddressPart::Product), value),
            C::InquireRevision => Self::Inquired(Inquiry::Address(AddressPart::Revision), value),
            C::InquireSerial => Self::Inquired(Inquiry::Address(AddressPart::Serial), value),
            C::InquireNodeId => Self::Inquired(Inquiry::NodeId, u32::from(data[1])),
            other => return Err(LssDecodeError::UnknownCommand(other.raw())),
        })
    }
}

/// Whether `frame` is an LSS request (COB-ID 0x7E5), which a slave reads.
pub fn is_lss_request(frame: &Frame) -> bool {
    frame.id() == CanId::Standard(LSS_MASTER_COB_ID)
}

/// The bit rates of the CiA 301 bit timing table (table selector 0), by
/// index; index 9 is automatic bit rate detection.
pub const BIT_TIMING_TABLE: [Option<u32>; 10] = [
    Some(1_000_000),
    Some(800_000),
    Some(500_000),
    Some(250_000),
    Some(125_000),
    Some(100_000),
    Some(50_000),
    Some(20_000),
    Some(10_000),
    None,
];

#[cfg(test)]
mod tests;
