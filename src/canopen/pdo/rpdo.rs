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
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::can::CanId;
    use crate::canopen::pdo::{
        EMCY_PDO_LENGTH_EXCEEDED, EMCY_RPDO_TIMEOUT, MappingEntry, PdoCobId, TransmissionType,
    };

    fn ms(ms: u64) -> Duration {
        Duration::from_millis(ms)
    }

    const COB: CanId = CanId::Standard(0x201);

    /// Controlword (16 bits), an 8-bit dummy, modes of operation (8 bits).
    fn rpdo_of_type(transmission_type: u8) -> Rpdo {
        let mut params = PdoCommParams::new(PdoCobId::new(COB));
        params.transmission_type = TransmissionType::from_raw(transmission_type);
        let mapping = PdoMapping::from_raw(&[0x6040_0010, 0x0005_0008, 0x6060_0008]).unwrap();
        Rpdo::new(params, mapping)
    }

    fn frame(data: &[u8]) -> Frame {
        Frame::new(COB, data).unwrap()
    }

    fn value(raw: u32, value: u64) -> MappedValue {
        MappedValue {
            entry: MappingEntry::from_raw(raw),
            value,
        }
    }

    #[test]
    fn event_driven_rpdos_are_applied_at_once() {
        let t0 = Instant::now();
        let mut rpdo = rpdo_of_type(254);
        let received = rpdo
            .on_frame(&frame(&[0x0F, 0x00, 0xAA, 0x03]), t0)
            .unwrap();
        assert_eq!(
            received,
            Some(RpdoReceived {
                apply: vec![value(0x6040_0010, 0x000F), value(0x6060_0008, 3)],
                buffered: false,
                length_exceeded: false,
            })
        );
        assert_eq!(rpdo.on_sync(), []);
    }

    #[test]
    fn synchronous_rpdos_wait_for_the_next_sync() {
        let t0 = Instant::now();
        for transmission_type in [0, 1, 240] {
            let mut rpdo = rpdo_of_type(transmission_type);
            assert!(rpdo.params().transmission_type.is_synchronous());
            assert_eq!(rpdo.on_sync(), []);
            let received = rpdo
                .on_frame(&frame(&[0x06, 0x00, 0, 0x01]), t0)
                .unwrap()
                .unwrap();
            assert!(received.buffered);
            assert!(received.apply.is_empty());
            // A newer frame before the SYNC replaces it.
            let _ = rpdo.on_frame(&frame(&[0x0F, 0x00, 0, 0x01]), t0 + ms(1));
            assert_eq!(
                rpdo.on_sync(),
                [value(0x6040_0010, 0x000F), value(0x6060_0008, 1)]
            );
            // Applied once.
            assert_eq!(rpdo.on_sync(), []);
        }
    }

    #[test]
    fn a_short_rpdo_is_not_applied() {
        let t0 = Instant::now();
        let mut rpdo = rpdo_of_type(255);
        let error = rpdo.on_frame(&frame(&[0x0F, 0x00, 0xAA]), t0).unwrap_err();
        assert_eq!(
            error,
            RpdoError::Data(PdoDataError::TooShort {
                expected: 4,
                got: 3
            })
        );
        assert_eq!(error.emcy_code(), Some(0x8210));
        assert_eq!(
            error.to_string(),
            "a PDO of 3 bytes where the mapping needs 4"
        );
        let mut rpdo = rpdo_of_type(1);
        assert!(rpdo.on_frame(&frame(&[]), t0).is_err());
        assert_eq!(rpdo.on_sync(), []);
    }

    #[test]
    fn a_long_rpdo_is_applied_from_its_first_bytes() {
        let t0 = Instant::now();
        let mut rpdo = rpdo_of_type(255);
        let received = rpdo
            .on_frame(&frame(&[0x0F, 0x00, 0xAA, 0x03, 0xFF]), t0)
            .unwrap()
            .unwrap();
        assert!(received.length_exceeded);
        assert_eq!(received.apply.len(), 2);
        assert_eq!(EMCY_PDO_LENGTH_EXCEEDED, 0x8220);
    }

    #[test]
    fn other_frames_are_not_this_rpdo() {
        let t0 = Instant::now();
        let mut rpdo = rpdo_of_type(255);
        let other = Frame::new(CanId::Standard(0x202), &[0; 4]).unwrap();
        assert_eq!(rpdo.on_frame(&other, t0), Ok(None));
        assert_eq!(rpdo.on_frame(&Frame::remote(COB, 4).unwrap(), t0), Ok(None));
        let extended = Frame::new(CanId::Extended(0x201), &[0; 4]).unwrap();
        assert_eq!(rpdo.on_frame(&extended, t0), Ok(None));
        let mut params = *rpdo.params();
        params.cob_id.valid = false;
        rpdo.configure(params, rpdo.mapping().clone());
        assert_eq!(rpdo.on_frame(&frame(&[0; 4]), t0), Ok(None));
    }

    #[test]
    fn reserved_transmission_types_are_refused() {
        let t0 = Instant::now();
        for transmission_type in [241, 252, 253] {
            let mut rpdo = rpdo_of_type(transmission_type);
            assert_eq!(
                rpdo.on_frame(&frame(&[0; 4]), t0),
                Err(RpdoError::TransmissionType(transmission_type))
            );
        }
    }

    #[test]
    fn the_event_timer_is_a_deadline() {
        let t0 = Instant::now();
        let mut rpdo = rpdo_of_type(255);
        let mut params = *rpdo.params();
        params.event_timer_ms = 100;
        rpdo.configure(params, rpdo.mapping().clone());
        // Monitoring starts with the first RPDO.
        assert_eq!(rpdo.deadline(), None);
        assert!(!rpdo.poll(t0 + ms(1000)));
        let _ = rpdo.on_frame(&frame(&[0; 4]), t0);
        assert_eq!(rpdo.deadline(), Some(t0 + ms(100)));
        let _ = rpdo.on_frame(&frame(&[0; 4]), t0 + ms(50));
        assert!(!rpdo.poll(t0 + ms(149)));
        assert!(rpdo.poll(t0 + ms(150)));
        assert!(rpdo.is_timed_out());
        assert_eq!(EMCY_RPDO_TIMEOUT, 0x8250);
        // Reported once.
        assert!(!rpdo.poll(t0 + ms(500)));
        assert_eq!(rpdo.deadline(), None);
        let _ = rpdo.on_frame(&frame(&[0; 4]), t0 + ms(600));
        assert!(!rpdo.is_timed_out());
        assert_eq!(rpdo.deadline(), Some(t0 + ms(700)));
        // A short frame does not count as received.
        let _ = rpdo.on_frame(&frame(&[0; 2]), t0 + ms(650));
        assert_eq!(rpdo.deadline(), Some(t0 + ms(700)));
    }
}
