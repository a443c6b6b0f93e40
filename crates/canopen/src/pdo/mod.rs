//! Process data objects, PDO (CiA 301 §7.2.2): up to 64 bits of mapped
//! object values in one frame, without protocol overhead.
//!
//! A PDO is described by two records: the communication parameters
//! (0x1400 + n − 1 for RPDO n, 0x1800 + n − 1 for TPDO n) say on which
//! COB-ID and when it goes, the mapping parameters (0x1600…, 0x1A00…) what
//! it carries. The gateway uses [`PdoMapping`] to decode its nodes' TPDOs and
//! to encode the RPDOs it sends; a virtual device also runs a [`TpdoTrigger`]
//! per TPDO and an [`Rpdo`] per RPDO.
//!
//! # Layout
//!
//! - [`mapping`]: mapping entries and mappings, bit-level packing (§7.2.2.3).
//! - [`comm`]: COB-ID, transmission type, inhibit time, event timer, SYNC
//!   start value (§7.5.2.35, §7.5.2.37).
//! - [`tpdo`]: when a TPDO is sent.
//! - [`rpdo`]: when and where a received RPDO is applied.

pub mod comm;
pub mod mapping;
pub mod rpdo;
pub mod tpdo;

pub use comm::{CommError, PdoCobId, PdoCommParams, TransmissionType};
pub use mapping::{
    BitsError, MappedValue, MappingEntry, MappingError, PdoDataError, PdoMapping, read_bits,
    sign_extend, write_bits,
};
pub use rpdo::{Rpdo, RpdoError, RpdoReceived};
pub use tpdo::TpdoTrigger;

/// EMCY error code "PDO not processed due to length error".
pub const EMCY_PDO_LENGTH: u16 = 0x8210;
/// EMCY error code "PDO length exceeded".
pub const EMCY_PDO_LENGTH_EXCEEDED: u16 = 0x8220;
/// EMCY error code "RPDO timeout".
pub const EMCY_RPDO_TIMEOUT: u16 = 0x8250;

/// SDO abort code "the number and length of the objects to be mapped would
/// exceed the PDO length".
pub const ABORT_PDO_LENGTH: u32 = 0x0604_0042;
/// SDO abort code "object cannot be mapped to the PDO".
pub const ABORT_NOT_MAPPABLE: u32 = 0x0604_0041;
/// SDO abort code "invalid value for parameter / value range exceeded".
const ABORT_VALUE_RANGE: u32 = 0x0609_0030;
/// SDO abort code "sub-index does not exist".
const ABORT_NO_SUB: u32 = 0x0609_0011;
/// SDO abort code "attempt to write a read only object".
const ABORT_READ_ONLY: u32 = 0x0601_0002;

/// Which way a PDO goes, seen from the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PdoKind {
    /// Received by the device (the gateway sends it).
    Rpdo,
    /// Transmitted by the device.
    Tpdo,
}

impl PdoKind {
    /// CiA 301 numbers PDOs 1 to 512.
    pub const MAX_NUMBER: u16 = 512;

    /// `rpdo` or `tpdo`, as the REST API spells them in paths.
    pub fn name(self) -> &'static str {
        match self {
            Self::Rpdo => "rpdo",
            Self::Tpdo => "tpdo",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "rpdo" => Some(Self::Rpdo),
            "tpdo" => Some(Self::Tpdo),
            _ => None,
        }
    }

    /// The index of PDO `number`'s communication parameters: 0x1400 + n − 1
    /// or 0x1800 + n − 1. `None` outside 1–512.
    pub fn comm_index(self, number: u16) -> Option<u16> {
        let base = match self {
            Self::Rpdo => 0x1400,
            Self::Tpdo => 0x1800,
        };
        (1..=Self::MAX_NUMBER)
            .contains(&number)
            .then(|| base + number - 1)
    }

    /// The index of PDO `number`'s mapping parameters: 0x1600 + n − 1 or
    /// 0x1A00 + n − 1. `None` outside 1–512.
    pub fn mapping_index(self, number: u16) -> Option<u16> {
        Some(self.comm_index(number)? + 0x200)
    }

    /// Which PDO a communication or mapping parameter index belongs to.
    pub fn from_index(index: u16) -> Option<(Self, u16)> {
        match index {
            0x1400..=0x15FF => Some((Self::Rpdo, index - 0x1400 + 1)),
            0x1600..=0x17FF => Some((Self::Rpdo, index - 0x1600 + 1)),
            0x1800..=0x19FF => Some((Self::Tpdo, index - 0x1800 + 1)),
            0x1A00..=0x1BFF => Some((Self::Tpdo, index - 0x1A00 + 1)),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameter_indexes_of_each_pdo() {
        assert_eq!(PdoKind::Rpdo.comm_index(1), Some(0x1400));
        assert_eq!(PdoKind::Rpdo.mapping_index(1), Some(0x1600));
        assert_eq!(PdoKind::Tpdo.comm_index(4), Some(0x1803));
        assert_eq!(PdoKind::Tpdo.mapping_index(4), Some(0x1A03));
        assert_eq!(PdoKind::Tpdo.mapping_index(512), Some(0x1BFF));
        assert_eq!(PdoKind::Tpdo.comm_index(0), None);
        assert_eq!(PdoKind::Rpdo.comm_index(513), None);
        assert_eq!(PdoKind::from_index(0x1A03), Some((PdoKind::Tpdo, 4)));
        assert_eq!(PdoKind::from_index(0x1400), Some((PdoKind::Rpdo, 1)));
        assert_eq!(PdoKind::from_index(0x17FF), Some((PdoKind::Rpdo, 512)));
        assert_eq!(PdoKind::from_index(0x1C00), None);
        assert_eq!(PdoKind::from_name("tpdo"), Some(PdoKind::Tpdo));
        assert_eq!(PdoKind::Rpdo.name(), "rpdo");
        assert_eq!(PdoKind::from_name("pdo"), None);
    }
}
