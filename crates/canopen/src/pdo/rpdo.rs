//! What a device does with a received RPDO (CiA 301 §7.2.2.2, §7.5.2.35):
//! which mapped objects get which value, and when.
//!
//! A synchronous RPDO (types 0–240) is applied at the next SYNC, so every
//! device acts on the same instant's data; the newest frame before that SYNC
//! wins. An event-driven one (254, 255) is applied at once. A frame shorter
//! than the mapping is not applied (EMCY 0x8210); a longer one is, from its
//! first bytes (EMCY 0x8220 if the device reports it). The event timer,
//! when set, is a deadline: no RPDO within it after the last one is a
//! timeout (EMCY 0x8250), as the UMC manual describes for 0x1400.5.

use std::time::Instant;

use super::comm::PdoCommParams;
use super::mapping::{MappedValue, PdoDataError, PdoMapping};
use crate::can::Frame;

/// Why a received RPDO is not applied.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RpdoError {
    /// Too short for the mapping: EMCY 0x8210.
    #[error(transparent)]
    Data(#[from] PdoDataError),
    #[error("transmission type {0} is not one an RPDO can have")]
    TransmissionType(u8),
}

impl RpdoError {
    /// The EMCY error code a device signals.
    pub fn emcy_code(&self) -> Option<u16> {
        match self {
            Self::Data(error) => error.emcy_code(),
            Self::TransmissionType(_) => None,
        }
    }
}

/// What a received RPDO asks of the device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RpdoReceived {
    /// The objects to write now, in mapping order; dummies left out. Empty
    /// when the values wait for the next SYNC.
    pub apply: Vec<MappedValue>,
    /// The values wait for the next SYNC ([`Rpdo::on_sync`] gives them).
    pub buffered: bool,
    /// The frame was longer than the mapping (EMCY
    /// [`EMCY_PDO_LENGTH_EXCEEDED`](super::EMCY_PDO_LENGTH_EXCEEDED) if the device reports it).
    pub length_exceeded: bool,
}

/// One RPDO of a device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rpdo {
    params: PdoCommParams,
    mapping: PdoMapping,
    buffered: Option<Vec<MappedValue>>,
    last_received: Option<Instant>,
    timed_out: bool,
}

impl Rpdo {
    pub fn new(params: PdoCommParams, mapping: PdoMapping) -> Self {
        Self {
            params,
            mapping,
            buffered: None,
            last_received: None,
            timed_out: false,
        }
    }

    pub fn params(&self) -> &PdoCommParams {
        &self.params
    }

    pub fn mapping(&self) -> &PdoMapping {
        &self.mapping
    }

    /// New configuration (after the re-mapping procedure): buffered values
    /// are dropped and deadline monitoring waits for the next RPDO.
    pub fn configure(&mut self, params: PdoCommParams, mapping: PdoMapping) {
        *self = Self::new(params, mapping);
    }

    /// Takes any received frame: `Ok(None)` unless it is a data frame on
    /// this valid RPDO's COB-ID.
    pub fn on_frame(
        &mut self,
        frame: &Frame,
        now: Instant,
    ) -> Result<Option<RpdoReceived>, RpdoError> {
        let cob_id = self.params.cob_id;
        if !cob_id.valid || frame.id() != cob_id.id || frame.is_remote() {
            return Ok(None);
        }
        let transmission_type = self.params.transmission_type;
        if !(transmission_type.is_synchronous() || transmission_type.is_event_driven()) {
            return Err(RpdoError::TransmissionType(transmission_type.raw()));
        }
        let data = frame.data();
        let values: Vec<MappedValue> = self
            .mapping
            .unpack(data)?
            .into_iter()
            .filter(|value| !value.entry.is_dummy())
            .collect();
        self.last_received = Some(now);
        self.timed_out = false;
        let length_exceeded = data.len() > self.mapping.byte_len();
        Ok(Some(if transmission_type.is_synchronous() {
            self.buffered = Some(values);
            RpdoReceived {
                apply: Vec::new(),
                buffered: true,
                length_exceeded,
            }
        } else {
            RpdoReceived {
                apply: values,
                buffered: false,
                length_exceeded,
            }
        }))
    }

    /// A SYNC was received: the values of a synchronous RPDO received since
    /// the previous SYNC, to write now (empty if none came).
    pub fn on_sync(&mut self) -> Vec<MappedValue> {
        self.buffered.take().unwrap_or_default()
    }

    /// `true` once when the event timer has passed since the last RPDO:
    /// the device signals EMCY [`EMCY_RPDO_TIMEOUT`](super::EMCY_RPDO_TIMEOUT).
    pub fn poll(&mut self, now: Instant) -> bool {
        if self.deadline().is_some_and(|deadline| now >= deadline) {
            self.timed_out = true;
            return true;
        }
        false
    }

    /// When the RPDO times out; `None` without event timer, before the first
    /// RPDO, or once timed out.
    pub fn deadline(&self) -> Option<Instant> {
        if self.timed_out || !self.params.cob_id.valid {
            return None;
        }
        Some(self.last_received? + self.params.event_timer()?)
    }

    /// Whether the RPDO has timed out and not been received since.
    pub fn is_timed_out(&self) -> bool {
        self.timed_out
    }
}

#[cfg(test)]
mod tests;
