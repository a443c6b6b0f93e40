use super::*;

fn node(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

#[test]
fn cob_ids_read_their_flag_bits() {
    let plain = PdoCobId::from_raw(0x0000_0185).unwrap();
    assert_eq!(plain, PdoCobId::new(CanId::Standard(0x185)));
    assert_eq!(plain, PdoCobId::predefined(Function::Tpdo(1), node(5)));
    let invalid = PdoCobId::from_raw(0x8000_0185).unwrap();
    assert!(!invalid.valid && invalid.rtr_allowed);
    let no_rtr = PdoCobId::from_raw(0x4000_0285).unwrap();
    assert!(no_rtr.valid && !no_rtr.rtr_allowed);
    let extended = PdoCobId::from_raw(0x2012_3456).unwrap();
    assert_eq!(extended.id, CanId::Extended(0x0012_3456));
    let all = PdoCobId::from_raw(0xFFFF_FFFF).unwrap();
    assert_eq!(all.id, CanId::Extended(0x1FFF_FFFF));
    assert!(!all.valid && !all.rtr_allowed);
    for raw in [
        0x0000_0185,
        0x8000_0185,
        0x4000_0285,
        0xC000_0000,
        0x2012_3456,
        0xFFFF_FFFF,
    ] {
        assert_eq!(PdoCobId::from_raw(raw).unwrap().raw(), raw, "0x{raw:08X}");
    }
    // An 11-bit identifier with bits 11-28 set.
    assert_eq!(
        PdoCobId::from_raw(0x0000_0800),
        Err(CommError::CobId(0x800))
    );
    assert_eq!(
        PdoCobId::from_raw(0x8100_0181),
        Err(CommError::CobId(0x8100_0181))
    );
    assert_eq!(CommError::CobId(0x800).abort_code(), 0x0609_0030);
}

#[test]
fn transmission_types_by_wire_value() {
    let cases = [
        (0, TransmissionType::SyncAcyclic),
        (1, TransmissionType::SyncCyclic(1)),
        (240, TransmissionType::SyncCyclic(240)),
        (241, TransmissionType::Reserved(241)),
        (251, TransmissionType::Reserved(251)),
        (252, TransmissionType::SyncRtr),
        (253, TransmissionType::AsyncRtr),
        (254, TransmissionType::EventManufacturer),
        (255, TransmissionType::EventProfile),
    ];
    for (raw, kind) in cases {
        assert_eq!(TransmissionType::from_raw(raw), kind);
        assert_eq!(kind.raw(), raw);
    }
    for raw in 0..=u8::MAX {
        let kind = TransmissionType::from_raw(raw);
        assert_eq!(kind.raw(), raw);
        let classes = [
            kind.is_synchronous(),
            kind.is_event_driven(),
            kind.is_rtr_only(),
        ];
        let expected = usize::from(!matches!(kind, TransmissionType::Reserved(_)));
        assert_eq!(classes.iter().filter(|&&c| c).count(), expected, "{raw}");
    }
    assert!(TransmissionType::SyncRtr.allowed_for(PdoKind::Tpdo));
    assert!(!TransmissionType::SyncRtr.allowed_for(PdoKind::Rpdo));
    assert!(!TransmissionType::Reserved(245).allowed_for(PdoKind::Tpdo));
    assert!(TransmissionType::SyncCyclic(3).allowed_for(PdoKind::Rpdo));
}

#[test]
fn params_in_their_units() {
    let mut params = PdoCommParams::new(PdoCobId::new(CanId::Standard(0x181)));
    assert_eq!(params.transmission_type, TransmissionType::EventProfile);
    assert_eq!(params.event_timer(), None);
    params.inhibit_time_100us = 25;
    params.event_timer_ms = 100;
    assert_eq!(params.inhibit_time(), Duration::from_micros(2_500));
    assert_eq!(params.event_timer(), Some(Duration::from_millis(100)));
}

#[test]
fn sdo_reads_of_the_record() {
    let mut params = PdoCommParams::new(PdoCobId::from_raw(0x4000_0181).unwrap());
    params.inhibit_time_100us = 10;
    params.event_timer_ms = 500;
    params.sync_start = 3;
    let tpdo: Vec<_> = (0..=6).map(|sub| params.read(PdoKind::Tpdo, sub)).collect();
    assert_eq!(
        tpdo,
        [
            Ok(6),
            Ok(0x4000_0181),
            Ok(255),
            Ok(10),
            Err(CommError::NoSubIndex(4)),
            Ok(500),
            Ok(3)
        ]
    );
    assert_eq!(params.read(PdoKind::Rpdo, 0), Ok(5));
    assert_eq!(params.read(PdoKind::Rpdo, 6), Err(CommError::NoSubIndex(6)));
    assert_eq!(CommError::NoSubIndex(6).abort_code(), 0x0609_0011);
}

#[test]
fn sdo_writes_follow_the_rules_of_cia_301() {
    let mut params = PdoCommParams::new(PdoCobId::from_raw(0x0000_0181).unwrap());
    let kind = PdoKind::Tpdo;
    // While valid: the COB-ID may only be invalidated.
    assert_eq!(
        params.write(kind, 1, 0x0000_0182),
        Err(CommError::CobIdWhileValid)
    );
    assert_eq!(
        params.write(kind, 1, 0x4000_0181),
        Err(CommError::CobIdWhileValid)
    );
    assert_eq!(params.write(kind, 3, 10), Err(CommError::WhileValid(3)));
    assert_eq!(params.write(kind, 6, 2), Err(CommError::WhileValid(6)));
    // Writing the same value is no change.
    assert_eq!(params.write(kind, 1, 0x0000_0181), Ok(()));
    assert_eq!(params.write(kind, 3, 0), Ok(()));
    // Type and event timer may change at any time.
    assert_eq!(params.write(kind, 2, 1), Ok(()));
    assert_eq!(params.write(kind, 5, 250), Ok(()));

    assert_eq!(params.write(kind, 1, 0x8000_0181), Ok(()));
    assert!(!params.cob_id.valid);
    assert_eq!(params.write(kind, 1, 0xC000_0281), Ok(()));
    assert_eq!(params.write(kind, 3, 10), Ok(()));
    assert_eq!(params.write(kind, 6, 2), Ok(()));
    assert_eq!(params.write(kind, 1, 0x4000_0281), Ok(()));
    assert_eq!(params.cob_id.raw(), 0x4000_0281);
    assert_eq!(params.inhibit_time_100us, 10);
    assert_eq!(params.sync_start, 2);
    assert_eq!(params.event_timer_ms, 250);
    assert_eq!(params.transmission_type, TransmissionType::SyncCyclic(1));
}

#[test]
fn sdo_writes_of_bad_values_are_refused() {
    let mut params = PdoCommParams::new(PdoCobId::from_raw(0x8000_0201).unwrap());
    assert_eq!(
        params.write(PdoKind::Rpdo, 0, 5),
        Err(CommError::ReadOnly(0))
    );
    assert_eq!(CommError::ReadOnly(0).abort_code(), 0x0601_0002);
    assert_eq!(
        params.write(PdoKind::Rpdo, 4, 0),
        Err(CommError::NoSubIndex(4))
    );
    assert_eq!(
        params.write(PdoKind::Rpdo, 6, 0),
        Err(CommError::NoSubIndex(6))
    );
    assert_eq!(
        params.write(PdoKind::Rpdo, 7, 0),
        Err(CommError::NoSubIndex(7))
    );
    assert_eq!(
        params.write(PdoKind::Rpdo, 2, 252),
        Err(CommError::TransmissionType(252))
    );
    assert_eq!(
        params.write(PdoKind::Tpdo, 2, 245),
        Err(CommError::TransmissionType(245))
    );
    assert_eq!(
        params.write(PdoKind::Tpdo, 2, 0x100),
        Err(CommError::OutOfRange {
            sub: 2,
            value: 0x100
        })
    );
    assert_eq!(
        params.write(PdoKind::Rpdo, 3, 0x1_0000),
        Err(CommError::OutOfRange {
            sub: 3,
            value: 0x1_0000
        })
    );
    assert_eq!(
        params.write(PdoKind::Tpdo, 6, 241),
        Err(CommError::OutOfRange { sub: 6, value: 241 })
    );
    assert_eq!(
        params.write(PdoKind::Rpdo, 1, 0x0000_0900),
        Err(CommError::CobId(0x900))
    );
    // Made valid on an identifier of another service.
    for id in [
        0x000, 0x07F, 0x101, 0x180, 0x581, 0x601, 0x6E0, 0x701, 0x77F, 0x7FF,
    ] {
        assert_eq!(
            params.write(PdoKind::Rpdo, 1, id),
            Err(CommError::RestrictedId(id as u16))
        );
        // Invalid, it may hold any.
        assert_eq!(params.write(PdoKind::Rpdo, 1, 0x8000_0000 | id), Ok(()));
    }
    for id in [
        0x080, 0x0FF, 0x100, 0x181, 0x57F, 0x580, 0x600, 0x680, 0x6DF, 0x700,
    ] {
        assert!(!is_restricted(id), "0x{id:03X}");
    }
    assert_eq!(params.transmission_type, TransmissionType::EventProfile);
}
