use std::time::Duration;

use super::*;
use crate::can::CanId;
use crate::pdo::{
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
