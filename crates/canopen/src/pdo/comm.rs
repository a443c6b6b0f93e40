//! PDO communication parameters (CiA 301 §7.5.2.35 RPDO 0x1400–0x15FF,
//! §7.5.2.37 TPDO 0x1800–0x19FF): COB-ID, transmission type, inhibit time,
//! event timer and SYNC start value, with the rules for changing them.

use std::time::Duration;

use super::{ABORT_NO_SUB, ABORT_READ_ONLY, ABORT_VALUE_RANGE, PdoKind};
use crate::can::CanId;
use crate::cob::{Function, NodeId};
use crate::sync::COUNTER_MAX;

/// COB-ID bit 31: set when the PDO does not exist (is not valid).
const INVALID_BIT: u32 = 1 << 31;
/// COB-ID bit 30: set when no remote request is allowed for the PDO.
const NO_RTR_BIT: u32 = 1 << 30;
/// COB-ID bit 29: set for a 29-bit (extended) identifier.
const EXTENDED_BIT: u32 = 1 << 29;
/// COB-ID bits 0–28: the identifier.
const ID_BITS: u32 = 0x1FFF_FFFF;

/// Why a communication parameter value is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CommError {
    #[error("COB-ID 0x{0:08X} has an 11-bit identifier above 0x7FF")]
    CobId(u32),
    #[error("the identifier and flags of a valid PDO's COB-ID cannot change")]
    CobIdWhileValid,
    #[error("identifier {0:03X} is reserved for other services")]
    RestrictedId(u16),
    #[error("transmission type {0} is reserved for this PDO")]
    TransmissionType(u8),
    #[error("sub-index {0} cannot change while the PDO is valid")]
    WhileValid(u8),
    #[error("value {value} is out of range for sub-index {sub}")]
    OutOfRange { sub: u8, value: u32 },
    #[error("the PDO communication parameter has no sub-index {0}")]
    NoSubIndex(u8),
    #[error("sub-index {0} is read only")]
    ReadOnly(u8),
}

impl CommError {
    /// The SDO abort code a device answers with (CANopenNode's choice for
    /// each: "invalid value" 0x06090030 for any refused value).
    pub fn abort_code(&self) -> u32 {
        match self {
            Self::NoSubIndex(_) => ABORT_NO_SUB,
            Self::ReadOnly(_) => ABORT_READ_ONLY,
            _ => ABORT_VALUE_RANGE,
        }
    }
}

/// The COB-ID entry (sub-index 1): bit 31 set = not valid, bit 30 set = no
/// RTR allowed, bit 29 set = 29-bit identifier, bits 0–28 the identifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PdoCobId {
    pub id: CanId,
    pub valid: bool,
    pub rtr_allowed: bool,
}

impl PdoCobId {
    /// A valid PDO on `id` that answers remote requests.
    pub fn new(id: CanId) -> Self {
        Self {
            id,
            valid: true,
            rtr_allowed: true,
        }
    }

    /// The COB-ID of the predefined connection set, such as
    /// `Function::Tpdo(1)` → 0x180 + node.
    pub fn predefined(function: Function, node: NodeId) -> Self {
        Self::new(function.can_id(node))
    }

    /// Reads the u32. With bit 29 clear, bits 11–28 must be 0.
    pub fn from_raw(raw: u32) -> Result<Self, CommError> {
        let id = raw & ID_BITS;
        let id = if raw & EXTENDED_BIT != 0 {
            CanId::Extended(id)
        } else {
            CanId::standard(id).map_err(|_| CommError::CobId(raw))?
        };
        Ok(Self {
            id,
            valid: raw & INVALID_BIT == 0,
            rtr_allowed: raw & NO_RTR_BIT == 0,
        })
    }

    pub fn raw(self) -> u32 {
        let mut raw = self.id.raw() & ID_BITS;
        if self.id.is_extended() {
            raw |= EXTENDED_BIT;
        }
        if !self.valid {
            raw |= INVALID_BIT;
        }
        if !self.rtr_allowed {
            raw |= NO_RTR_BIT;
        }
        raw
    }
}

/// The transmission type (sub-index 2). The doc of each variant gives its
/// wire value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TransmissionType {
    /// 0: synchronous, acyclic: a TPDO goes out at the first SYNC after an
    /// event; an RPDO is applied at the next SYNC.
    SyncAcyclic,
    /// 1–240: synchronous, cyclic: a TPDO goes out at every nth SYNC; an
    /// RPDO is applied at the next SYNC.
    SyncCyclic(u8),
    /// 252: synchronous, RTR-only (TPDO): sent at the SYNC after a remote
    /// request.
    SyncRtr,
    /// 253: asynchronous, RTR-only (TPDO): sent when remotely requested.
    AsyncRtr,
    /// 254: event-driven, manufacturer-specific.
    EventManufacturer,
    /// 255: event-driven, device and application profile.
    EventProfile,
    /// 241–251: reserved.
    Reserved(u8),
}

impl TransmissionType {
    pub fn from_raw(raw: u8) -> Self {
        match raw {
            0 => Self::SyncAcyclic,
            1..=240 => Self::SyncCyclic(raw),
            252 => Self::SyncRtr,
            253 => Self::AsyncRtr,
            254 => Self::EventManufacturer,
            255 => Self::EventProfile,
            reserved => Self::Reserved(reserved),
        }
    }

    pub fn raw(self) -> u8 {
        match self {
            Self::SyncAcyclic => 0,
            Self::SyncCyclic(n) | Self::Reserved(n) => n,
            Self::SyncRtr => 252,
            Self::AsyncRtr => 253,
            Self::EventManufacturer => 254,
            Self::EventProfile => 255,
        }
    }

    /// Types 0–240: tied to SYNC (for an RPDO: applied at the next SYNC).
    pub fn is_synchronous(self) -> bool {
        matches!(self, Self::SyncAcyclic | Self::SyncCyclic(_))
    }

    /// Types 254 and 255.
    pub fn is_event_driven(self) -> bool {
        matches!(self, Self::EventManufacturer | Self::EventProfile)
    }

    /// Types 252 and 253: sent only when remotely requested.
    pub fn is_rtr_only(self) -> bool {
        matches!(self, Self::SyncRtr | Self::AsyncRtr)
    }

    /// Whether a PDO of `kind` may have this type: RTR-only types are for
    /// TPDOs, reserved ones for none.
    pub fn allowed_for(self, kind: PdoKind) -> bool {
        match self {
            Self::Reserved(_) => false,
            Self::SyncRtr | Self::AsyncRtr => kind == PdoKind::Tpdo,
            _ => true,
        }
    }
}

/// Whether a PDO may not use the 11-bit identifier `id`: the restricted
/// identifiers of CiA 301 table 73 (NMT, SDO and NMT error control defaults,
/// reserved ranges).
pub fn is_restricted(id: u16) -> bool {
    match id {
        // NMT and reserved; reserved.
        0x000..=0x07F | 0x101..=0x180 => true,
        // Default SDO server to client, client to server.
        0x581..=0x5FF | 0x601..=0x67F => true,
        // Reserved; NMT error control; reserved.
        0x6E0..=0x6FF | 0x701..=0x77F | 0x780..=0x7FF => true,
        _ => false,
    }
}

/// The communication parameter record of one PDO. The field names are the
/// ones the REST API uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PdoCommParams {
    /// Sub-index 1.
    pub cob_id: PdoCobId,
    /// Sub-index 2.
    pub transmission_type: TransmissionType,
    /// Sub-index 3: minimum time between two transmissions of an
    /// event-driven TPDO, in 100 µs; 0 = none.
    pub inhibit_time_100us: u16,
    /// Sub-index 5: a TPDO's event timer, an RPDO's deadline, in ms; 0 = off.
    pub event_timer_ms: u16,
    /// Sub-index 6 (TPDO): the SYNC counter value of the first SYNC a cyclic
    /// TPDO counts; 0 = any.
    pub sync_start: u8,
}

impl PdoCommParams {
    /// An event-driven (255) PDO on `cob_id` without inhibit time, event
    /// timer or SYNC start value.
    pub fn new(cob_id: PdoCobId) -> Self {
        Self {
            cob_id,
            transmission_type: TransmissionType::EventProfile,
            inhibit_time_100us: 0,
            event_timer_ms: 0,
            sync_start: 0,
        }
    }

    pub fn inhibit_time(&self) -> Duration {
        Duration::from_micros(100 * u64::from(self.inhibit_time_100us))
    }

    /// The event timer; `None` when 0.
    pub fn event_timer(&self) -> Option<Duration> {
        (self.event_timer_ms > 0).then(|| Duration::from_millis(u64::from(self.event_timer_ms)))
    }

    /// The highest sub-index (sub-index 0): 6 for a TPDO, 5 for an RPDO.
    pub fn highest_sub(kind: PdoKind) -> u8 {
        match kind {
            PdoKind::Tpdo => 6,
            PdoKind::Rpdo => 5,
        }
    }

    /// An SDO read of sub-index `sub` of a PDO of `kind`.
    pub fn read(&self, kind: PdoKind, sub: u8) -> Result<u32, CommError> {
        match sub {
            0 => Ok(u32::from(Self::highest_sub(kind))),
            1 => Ok(self.cob_id.raw()),
            2 => Ok(u32::from(self.transmission_type.raw())),
            3 => Ok(u32::from(self.inhibit_time_100us)),
            5 => Ok(u32::from(self.event_timer_ms)),
            6 if kind == PdoKind::Tpdo => Ok(u32::from(self.sync_start)),
            _ => Err(CommError::NoSubIndex(sub)),
        }
    }

    /// An SDO write of sub-index `sub` of a PDO of `kind`, with CiA 301's
    /// rules: while the PDO is valid, its COB-ID may only be made invalid
    /// (bit 31), and the inhibit time and SYNC start value are fixed. The
    /// re-mapping procedure therefore starts by setting bit 31.
    pub fn write(&mut self, kind: PdoKind, sub: u8, value: u32) -> Result<(), CommError> {
        let narrow = |bits: u32| -> Result<u32, CommError> {
            if value >> bits == 0 {
                Ok(value)
            } else {
                Err(CommError::OutOfRange { sub, value })
            }
        };
        match sub {
            0 => Err(CommError::ReadOnly(0)),
            1 => {
                let cob_id = PdoCobId::from_raw(value)?;
                if let CanId::Standard(id) = cob_id.id
                    && cob_id.valid
                    && is_restricted(id)
                {
                    return Err(CommError::RestrictedId(id));
                }
                let fixed = !INVALID_BIT;
                if self.cob_id.valid
                    && cob_id.valid
                    && cob_id.raw() & fixed != self.cob_id.raw() & fixed
                {
                    return Err(CommError::CobIdWhileValid);
                }
                self.cob_id = cob_id;
                Ok(())
            }
            2 => {
                let raw = narrow(8)? as u8;
                let transmission_type = TransmissionType::from_raw(raw);
                if !transmission_type.allowed_for(kind) {
                    return Err(CommError::TransmissionType(raw));
                }
                self.transmission_type = transmission_type;
                Ok(())
            }
            3 => {
                let inhibit = narrow(16)? as u16;
                if self.cob_id.valid && inhibit != self.inhibit_time_100us {
                    return Err(CommError::WhileValid(3));
                }
                self.inhibit_time_100us = inhibit;
                Ok(())
            }
            5 => {
                self.event_timer_ms = narrow(16)? as u16;
                Ok(())
            }
            6 if kind == PdoKind::Tpdo => {
                let start = narrow(8)? as u8;
                if start > COUNTER_MAX {
                    return Err(CommError::OutOfRange { sub, value });
                }
                if self.cob_id.valid && start != self.sync_start {
                    return Err(CommError::WhileValid(6));
                }
                self.sync_start = start;
                Ok(())
            }
            _ => Err(CommError::NoSubIndex(sub)),
        }
    }
}

#[cfg(test)]
mod tests;
