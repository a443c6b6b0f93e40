use serde_json::json;

use super::*;
use crate::canopen::eds::Eds;

fn umc_eds() -> Eds {
    let text = include_str!("../../../../eds/umc1bds32.eds");
    Eds::parse(text, "umc1bds32.eds").unwrap()
}

fn jmc_eds() -> Eds {
    let text = include_str!("../../../../eds/jmc_stepper.eds");
    Eds::parse(text, "jmc_stepper.eds").unwrap()
}

fn umc() -> ObjectDictionary {
    umc_eds().dictionary
}

fn jmc() -> ObjectDictionary {
    jmc_eds().dictionary
}

fn entry(index: Json) -> EntryRequest {
    EntryRequest {
        index,
        sub: None,
        bits: None,
    }
}

fn mapping_request(entries: Vec<EntryRequest>) -> PdoRequest {
    PdoRequest {
        mapping: Some(entries),
        ..PdoRequest::default()
    }
}

#[test]
fn the_eds_says_which_pdos_a_node_has() {
    let dict = umc();
    assert_eq!(pdo_numbers(Some(&dict), PdoKind::Tpdo), [1, 2, 3, 4]);
    assert_eq!(pdo_numbers(Some(&dict), PdoKind::Rpdo), [1, 2, 3, 4]);
    assert_eq!(pdo_numbers(None, PdoKind::Rpdo), [1, 2, 3, 4]);
    assert!(has_pdo(Some(&dict), PdoKind::Tpdo, 4));
    assert!(!has_pdo(Some(&dict), PdoKind::Tpdo, 5));
    assert_eq!(max_entries(Some(&dict), PdoKind::Tpdo, 1), 8);
    // The JMC's PDOs have a COB-ID and a transmission type only.
    let jmc = jmc();
    assert!(has_comm_sub(Some(&jmc), PdoKind::Tpdo, 1, 2));
    assert!(!has_comm_sub(Some(&jmc), PdoKind::Tpdo, 1, 3));
    assert!(has_comm_sub(Some(&dict), PdoKind::Tpdo, 1, 6));
    assert!(!has_comm_sub(Some(&dict), PdoKind::Rpdo, 1, 6));
}

#[test]
fn a_plan_resolves_names_and_checks_every_entry() {
    let eds = umc_eds();
    let request = PdoRequest {
        transmission_type: Some(1),
        ..mapping_request(vec![
            entry(json!("a1_Statusword")),
            EntryRequest {
                index: json!("0x6064"),
                sub: Some(json!(0)),
                bits: None,
            },
        ])
    };
    let plan = plan(&eds, PdoKind::Tpdo, 1, &request).unwrap();
    assert_eq!(
        plan.mapping.as_ref().unwrap().raw(),
        [0x6041_0010, 0x6064_0020]
    );
    assert_eq!(plan.comm_writes, [(2, Value::Unsigned8(1))]);
    assert!(plan.enabled);

    let refused =
        |kind, number, request: PdoRequest| super::plan(&eds, kind, number, &request).unwrap_err();
    // Not mappable (a communication parameter), the wrong direction (a
    // read-only statusword in an RPDO), unknown, too long.
    assert!(matches!(
        refused(
            PdoKind::Tpdo,
            1,
            mapping_request(vec![entry(json!("0x1017"))])
        ),
        PdoPlanError::NotMappable { position: 1, .. }
    ));
    assert!(matches!(
        refused(
            PdoKind::Rpdo,
            1,
            mapping_request(vec![entry(json!("a1_Statusword"))])
        ),
        PdoPlanError::NotMappable { .. }
    ));
    assert!(matches!(
        refused(
            PdoKind::Tpdo,
            1,
            mapping_request(vec![entry(json!("a1_Statusword")), entry(json!("no_such"))])
        ),
        PdoPlanError::UnknownEntry { position: 2, .. }
    ));
    let too_long = refused(
        PdoKind::Tpdo,
        1,
        mapping_request(vec![
            entry(json!("0x6064")),
            entry(json!("0x606C")),
            entry(json!("a1_Statusword")),
        ]),
    );
    assert_eq!(
        too_long,
        PdoPlanError::Mapping(MappingError::TooLong { bits: 80 })
    );
    // More bits than the type has.
    let wide = EntryRequest {
        bits: Some(32),
        ..entry(json!("a1_Statusword"))
    };
    assert!(matches!(
        refused(PdoKind::Tpdo, 1, mapping_request(vec![wide])),
        PdoPlanError::Bits { bits: 32, .. }
    ));
    // A PDO number the node does not have.
    let unknown = refused(PdoKind::Tpdo, 5, PdoRequest::default());
    assert!(unknown.is_unknown_pdo());
    assert!(unknown.to_string().contains("1, 2, 3, 4"), "{unknown}");
    // Reserved and RTR-only transmission types.
    for (kind, raw) in [(PdoKind::Tpdo, 245), (PdoKind::Rpdo, 253)] {
        let request = PdoRequest {
            transmission_type: Some(raw),
            ..PdoRequest::default()
        };
        assert!(refused(kind, 1, request).is_out_of_range());
    }
    // A restricted or flagged COB-ID.
    for raw in [0x601, 0x8000_0181, 0x800] {
        let request = PdoRequest {
            cob_id: Some(raw),
            ..PdoRequest::default()
        };
        assert!(
            matches!(
                refused(PdoKind::Tpdo, 1, request),
                PdoPlanError::CobId { .. }
            ),
            "0x{raw:X}"
        );
    }
    // Whole bytes only (Granularity=8); 16 bits of the 32-bit position are.
    let narrow = EntryRequest {
        bits: Some(12),
        ..entry(json!("0x6064"))
    };
    assert!(matches!(
        refused(PdoKind::Tpdo, 1, mapping_request(vec![narrow])),
        PdoPlanError::Granularity { bits: 12, .. }
    ));
    let window = EntryRequest {
        bits: Some(16),
        ..entry(json!("0x6064"))
    };
    assert!(super::plan(&eds, PdoKind::Tpdo, 1, &mapping_request(vec![window])).is_ok());
    // Dummies: any type on the UMC (no [DummyUsage]), not BOOLEAN on the JMC.
    let dummy = |index: u16| EntryRequest {
        index: json!(index),
        sub: None,
        bits: None,
    };
    let jmc_eds = jmc_eds();
    let with_dummy = |index| mapping_request(vec![dummy(index), entry(json!("0x6040"))]);
    assert!(super::plan(&jmc_eds, PdoKind::Rpdo, 1, &with_dummy(5)).is_ok());
    assert!(matches!(
        super::plan(&jmc_eds, PdoKind::Rpdo, 1, &with_dummy(1)),
        Err(PdoPlanError::NotMappable { position: 1, .. })
    ));
    // The JMC has no inhibit time.
    let jmc = jmc_eds;
    let request = PdoRequest {
        inhibit_time_100us: Some(10),
        ..PdoRequest::default()
    };
    assert_eq!(
        super::plan(&jmc, PdoKind::Tpdo, 1, &request).unwrap_err(),
        PdoPlanError::NoSuchParameter("inhibit time")
    );
}

#[test]
fn a_tpdo_decodes_byte_exact_by_the_eds() {
    let dict = umc();
    let mapping = PdoMapping::from_raw(&[0x6041_0010, 0x6064_0020]).unwrap();
    let decoder = TpdoDecoder::new(CanId::Standard(0x181), mapping, Some(&dict));
    // Statusword 0x0637, position -2 (0xFFFFFFFE).
    let data = [0x37, 0x06, 0xFE, 0xFF, 0xFF, 0xFF];
    let values = decoder.decode(&data).unwrap();
    assert_eq!(values.len(), 2);
    assert_eq!(values[0].name.as_deref(), Some("a1_Statusword"));
    assert_eq!(values[0].value, Some(Value::Unsigned16(0x0637)));
    assert_eq!(values[0].raw, 0x0637);
    assert_eq!(
        values[1].name.as_deref(),
        Some("a1_pc_Position_actual_value")
    );
    assert_eq!(values[1].value, Some(Value::Integer32(-2)));
    assert_eq!(values[1].raw, 0xFFFF_FFFE);
    // Bytes beyond the mapping are ignored; fewer are an error.
    assert_eq!(
        decoder
            .decode(&[data.as_slice(), &[9, 9]].concat())
            .unwrap(),
        values
    );
    assert_eq!(
        decoder.decode(&data[..5]),
        Err(PdoDataError::TooShort {
            expected: 6,
            got: 5
        })
    );
    assert_eq!(
        decoder.decode(&[]),
        Err(PdoDataError::TooShort {
            expected: 6,
            got: 0
        })
    );
    // Only frames on its COB-ID.
    let frame = Frame::new(CanId::Standard(0x181), &data).unwrap();
    assert_eq!(decoder.decode_frame(&frame), Some(Ok(values)));
    let other = Frame::new(CanId::Standard(0x182), &data).unwrap();
    assert_eq!(decoder.decode_frame(&other), None);
    let short = Frame::new(CanId::Standard(0x181), &data[..2]).unwrap();
    assert!(matches!(decoder.decode_frame(&short), Some(Err(_))));
}

#[test]
fn a_tpdo_with_dummies_and_narrow_fields_decodes_each_at_its_offset() {
    let dict = umc();
    // 8 bits of gap (a dummy UNSIGNED8), the mode (i8), a 16-bit window of
    // the 32-bit position (sign-extended), and an object the EDS lacks.
    let mapping =
        PdoMapping::from_raw(&[0x0005_0008, 0x6060_0008, 0x6064_0010, 0x5FFF_0108]).unwrap();
    let decoder = TpdoDecoder::new(CanId::Standard(0x281), mapping, Some(&dict));
    let values = decoder.decode(&[0xAA, 0xFD, 0x00, 0x80, 0x42]).unwrap();
    assert_eq!(values.len(), 3, "the dummy is left out");
    assert_eq!(values[0].value, Some(Value::Integer8(-3)));
    assert_eq!(values[1].value, Some(Value::Integer32(-32768)));
    assert_eq!(values[1].raw, 0x8000);
    assert_eq!(values[2].name, None);
    assert_eq!(values[2].value, None);
    assert_eq!(values[2].raw, 0x42);
    // Without EDS: raw values only.
    let bare = TpdoDecoder::new(
        CanId::Standard(0x281),
        PdoMapping::from_raw(&[0x6041_0010]).unwrap(),
        None,
    );
    let values = bare.decode(&[0x01, 0x02]).unwrap();
    assert_eq!((values[0].raw, values[0].value.clone()), (0x0201, None));
}

#[test]
fn an_rpdo_encodes_every_mapped_value_by_name_or_index() {
    let dict = umc();
    let mapping = PdoMapping::from_raw(&[0x6040_0010, 0x607A_0020]).unwrap();
    let node = NodeId::new(1).ok();
    let encoder = RpdoEncoder::new(CanId::Standard(0x401), mapping, Some(&dict), node);
    let values = json!({"a1_Controlword": 15, "0x607A": -2});
    let (frame, sent) = encoder
        .encode(values.as_object().unwrap(), Some(&dict))
        .unwrap();
    assert_eq!(frame.id(), CanId::Standard(0x401));
    assert_eq!(frame.data(), [0x0F, 0x00, 0xFE, 0xFF, 0xFF, 0xFF]);
    assert_eq!(sent[1].value, Some(Value::Integer32(-2)));
    assert_eq!(sent[1].raw, 0xFFFF_FFFE);
    let encode = |values: Json| encoder.encode(values.as_object().unwrap(), Some(&dict));
    assert!(encode(json!({"0x6040:0": 6, "a1_pp_Position_target": 7})).is_ok());
    assert!(matches!(
        encode(json!({"a1_Controlword": 15})),
        Err(RpdoValueError::Missing(name)) if name == "a1_pp_Position_target"
    ));
    assert!(matches!(
        encode(json!({"a1_Controlword": 15, "0x607A": 1, "a1_Statusword": 1})),
        Err(RpdoValueError::NotMapped(..))
    ));
    assert!(matches!(
        encode(json!({"a1_Controlword": 70000, "0x607A": 1})),
        Err(RpdoValueError::OutOfRange { .. })
    ));
    assert!(matches!(
        encode(json!({"a1_Controlword": "x", "0x607A": 1})),
        Err(RpdoValueError::Invalid { .. })
    ));
}
