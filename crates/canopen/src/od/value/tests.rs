use super::*;
use serde_json::json;

fn node(id: u8) -> Option<NodeId> {
    Some(NodeId::new(id).unwrap())
}

fn parse(data_type: DataType, text: &str) -> Result<Value, ValueError> {
    Value::parse_text(data_type, text, None)
}

/// Each type at its limits (and zero), with the bytes CiA 301 puts on the wire.
fn limits_table() -> Vec<(Value, Vec<u8>)> {
    vec![
        (Value::Boolean(false), vec![0]),
        (Value::Boolean(true), vec![1]),
        (Value::Integer8(i8::MIN), vec![0x80]),
        (Value::Integer8(i8::MAX), vec![0x7F]),
        (Value::Integer8(-1), vec![0xFF]),
        (Value::Integer16(i16::MIN), vec![0x00, 0x80]),
        (Value::Integer16(i16::MAX), vec![0xFF, 0x7F]),
        (Value::Integer24(-0x80_0000), vec![0x00, 0x00, 0x80]),
        (Value::Integer24(0x7F_FFFF), vec![0xFF, 0xFF, 0x7F]),
        (Value::Integer24(-2), vec![0xFE, 0xFF, 0xFF]),
        (Value::Integer32(i32::MIN), vec![0, 0, 0, 0x80]),
        (Value::Integer32(i32::MAX), vec![0xFF, 0xFF, 0xFF, 0x7F]),
        (Value::Integer40(-(1 << 39)), vec![0, 0, 0, 0, 0x80]),
        (
            Value::Integer40((1 << 39) - 1),
            vec![0xFF, 0xFF, 0xFF, 0xFF, 0x7F],
        ),
        (Value::Integer48(-(1 << 47)), vec![0, 0, 0, 0, 0, 0x80]),
        (
            Value::Integer48((1 << 47) - 1),
            vec![0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x7F],
        ),
        (Value::Integer48(-1), vec![0xFF; 6]),
        (Value::Integer56(-(1 << 55)), vec![0, 0, 0, 0, 0, 0, 0x80]),
        (
            Value::Integer56((1 << 55) - 1),
            vec![0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x7F],
        ),
        (Value::Integer64(i64::MIN), vec![0, 0, 0, 0, 0, 0, 0, 0x80]),
        (
            Value::Integer64(i64::MAX),
            vec![0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x7F],
        ),
        (Value::Unsigned8(0), vec![0]),
        (Value::Unsigned8(u8::MAX), vec![0xFF]),
        (Value::Unsigned16(0x1234), vec![0x34, 0x12]),
        (Value::Unsigned16(u16::MAX), vec![0xFF, 0xFF]),
        (Value::Unsigned24(0xFF_FFFF), vec![0xFF, 0xFF, 0xFF]),
        (Value::Unsigned24(0x01_0203), vec![0x03, 0x02, 0x01]),
        (Value::Unsigned32(0x6041_0010), vec![0x10, 0x00, 0x41, 0x60]),
        (Value::Unsigned32(u32::MAX), vec![0xFF; 4]),
        (Value::Unsigned40((1 << 40) - 1), vec![0xFF; 5]),
        (Value::Unsigned48((1 << 48) - 1), vec![0xFF; 6]),
        (Value::Unsigned56((1 << 56) - 1), vec![0xFF; 7]),
        (
            Value::Unsigned56(0x01_0203_0405_0607),
            vec![7, 6, 5, 4, 3, 2, 1],
        ),
        (Value::Unsigned64(u64::MAX), vec![0xFF; 8]),
        (Value::Unsigned64(0), vec![0; 8]),
        (Value::Real32(1.0), vec![0x00, 0x00, 0x80, 0x3F]),
        (Value::Real32(-2.5), vec![0x00, 0x00, 0x20, 0xC0]),
        (Value::Real32(f32::MAX), vec![0xFF, 0xFF, 0x7F, 0x7F]),
        (Value::Real64(1.0), vec![0, 0, 0, 0, 0, 0, 0xF0, 0x3F]),
        (
            Value::Real64(f64::MIN),
            vec![0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xEF, 0xFF],
        ),
        (
            Value::VisibleString("UMC1BDS32".into()),
            b"UMC1BDS32".to_vec(),
        ),
        (Value::VisibleString(String::new()), vec![]),
        (Value::OctetString(vec![0, 1, 0xFE]), vec![0, 1, 0xFE]),
        (
            Value::UnicodeString("vé".into()),
            vec![0x76, 0x00, 0xE9, 0x00],
        ),
        (
            Value::TimeOfDay(TimeOfDay {
                ms: 0x0FFF_FFFF,
                days: 0xFFFF,
            }),
            vec![0xFF, 0xFF, 0xFF, 0x0F, 0xFF, 0xFF],
        ),
        (
            Value::TimeDifference(TimeOfDay { ms: 1000, days: 2 }),
            vec![0xE8, 0x03, 0, 0, 2, 0],
        ),
        (
            Value::Domain(vec![0xDE, 0xAD, 0xBE, 0xEF]),
            vec![0xDE, 0xAD, 0xBE, 0xEF],
        ),
    ]
}

#[test]
fn bytes_round_trip_for_every_type_at_its_limits() {
    let table = limits_table();
    for data_type in DataType::ALL {
        assert!(
            table
                .iter()
                .any(|(value, _)| value.data_type() == data_type),
            "{data_type} is missing from the table"
        );
    }
    for (value, bytes) in table {
        assert_eq!(value.to_bytes(), bytes, "{value:?}");
        assert_eq!(
            Value::from_bytes(value.data_type(), &bytes),
            Ok(value.clone())
        );
    }
}

#[test]
fn wrong_lengths_say_which_way_and_map_to_sdo_aborts() {
    let short = Value::from_bytes(DataType::Unsigned32, &[1, 2]).unwrap_err();
    assert_eq!(
        short,
        ValueError::Length {
            data_type: DataType::Unsigned32,
            expected: 4,
            got: 2
        }
    );
    assert_eq!(short.to_string(), "UNSIGNED32 takes 4 bytes, got 2");
    assert_eq!(short.sdo_abort_code(), 0x0607_0013);
    let long = Value::from_bytes(DataType::Integer24, &[1, 2, 3, 4]).unwrap_err();
    assert_eq!(long.sdo_abort_code(), 0x0607_0012);
    assert!(Value::from_bytes(DataType::Boolean, &[]).is_err());
    assert!(Value::from_bytes(DataType::TimeOfDay, &[0; 4]).is_err());
    let odd = Value::from_bytes(DataType::UnicodeString, &[0x41, 0x00, 0x42]).unwrap_err();
    assert_eq!(odd.sdo_abort_code(), 0x0607_0010);
    // An unpaired surrogate is no text.
    assert!(Value::from_bytes(DataType::UnicodeString, &[0x00, 0xD8]).is_err());
    assert_eq!(
        Value::from_bytes(DataType::Unknown(0x20), &[1]),
        Err(ValueError::UnsupportedType(DataType::Unknown(0x20)))
    );
}

#[test]
fn strings_from_devices_lose_their_padding() {
    assert_eq!(
        Value::from_bytes(DataType::VisibleString, b"v1.0.4\0\0\0"),
        Ok(Value::VisibleString("v1.0.4".into()))
    );
    // Not UTF-8: read as Latin-1 rather than refused.
    assert_eq!(
        Value::from_bytes(DataType::VisibleString, &[0x32, 0x35, 0xB0, 0x43]),
        Ok(Value::VisibleString("25°C".into()))
    );
    assert_eq!(
        Value::from_bytes(DataType::UnicodeString, &[0x41, 0, 0, 0]),
        Ok(Value::UnicodeString("A".into()))
    );
    // A non-zero byte is true, as CiA 301 has no other meaning for it.
    assert_eq!(
        Value::from_bytes(DataType::Boolean, &[2]),
        Ok(Value::Boolean(true))
    );
}

#[test]
fn eds_text_in_every_form_vendors_write() {
    assert_eq!(
        parse(DataType::Unsigned32, "428"),
        Ok(Value::Unsigned32(428))
    );
    assert_eq!(
        parse(DataType::Unsigned32, "0x000004A2"),
        Ok(Value::Unsigned32(0x4A2))
    );
    assert_eq!(
        parse(DataType::Unsigned32, " 0X4a2 "),
        Ok(Value::Unsigned32(0x4A2))
    );
    assert_eq!(
        parse(DataType::Unsigned8, "010"),
        Ok(Value::Unsigned8(8)),
        "octal"
    );
    assert_eq!(parse(DataType::Unsigned8, "09"), Ok(Value::Unsigned8(9)));
    assert_eq!(parse(DataType::Unsigned8, "0"), Ok(Value::Unsigned8(0)));
    assert_eq!(
        parse(DataType::Integer32, "-2147483648"),
        Ok(Value::Integer32(i32::MIN))
    );
    assert_eq!(
        parse(DataType::Integer32, "-0x7FFFFFFF"),
        Ok(Value::Integer32(-i32::MAX))
    );
    assert_eq!(
        parse(DataType::Integer16, "0xFFFF"),
        Ok(Value::Integer16(-1))
    );
    assert_eq!(
        parse(DataType::Integer24, "0x800000"),
        Ok(Value::Integer24(-0x80_0000))
    );
    assert_eq!(parse(DataType::Integer8, "+5"), Ok(Value::Integer8(5)));
    assert_eq!(parse(DataType::Boolean, "1"), Ok(Value::Boolean(true)));
    assert_eq!(parse(DataType::Boolean, "FALSE"), Ok(Value::Boolean(false)));
    assert_eq!(parse(DataType::Real32, "1.5"), Ok(Value::Real32(1.5)));
    assert_eq!(parse(DataType::Real32, "-2e3"), Ok(Value::Real32(-2000.0)));
    assert_eq!(
        parse(DataType::Real32, "0x3F800000"),
        Ok(Value::Real32(1.0))
    );
    assert_eq!(parse(DataType::Real64, "0.1"), Ok(Value::Real64(0.1)));
    assert_eq!(parse(DataType::Real64, "7"), Ok(Value::Real64(7.0)));
    assert_eq!(
        parse(DataType::VisibleString, "\"https://uniswarm.eu/\""),
        Ok(Value::VisibleString("https://uniswarm.eu/".into()))
    );
    assert_eq!(
        parse(DataType::VisibleString, "bare"),
        Ok(Value::VisibleString("bare".into()))
    );
    assert_eq!(
        parse(DataType::UnicodeString, "\"vXX.XX.XXX\""),
        Ok(Value::UnicodeString("vXX.XX.XXX".into()))
    );
    assert_eq!(
        parse(DataType::OctetString, "01 02 ab"),
        Ok(Value::OctetString(vec![1, 2, 0xAB]))
    );
    assert_eq!(parse(DataType::Domain, ""), Ok(Value::Domain(vec![])));
    assert_eq!(
        parse(DataType::TimeOfDay, "0x0002000003E8"),
        Ok(Value::TimeOfDay(TimeOfDay { ms: 1000, days: 2 }))
    );
}

#[test]
fn malformed_text_is_refused_with_a_reason() {
    let error = parse(DataType::Unsigned32, "0xZZ").unwrap_err();
    assert_eq!(
        error.to_string(),
        "'0xZZ' is not a valid UNSIGNED32: bad hex digits"
    );
    assert!(parse(DataType::Unsigned32, "").is_err());
    assert!(parse(DataType::Unsigned32, "0x").is_err());
    assert!(parse(DataType::Unsigned32, "0x+5").is_err());
    assert!(parse(DataType::Unsigned32, "12abc").is_err());
    assert!(parse(DataType::Unsigned32, "1.5").is_err());
    assert!(parse(DataType::Real32, "fast").is_err());
    assert!(parse(DataType::Real32, "0xG").is_err());
    assert!(parse(DataType::OctetString, "123").is_err());
    assert!(parse(DataType::OctetString, "zz").is_err());
    assert!(parse(DataType::Boolean, "2").unwrap_err().is_out_of_range());
    let too_big = parse(DataType::Unsigned8, "256").unwrap_err();
    assert_eq!(
        too_big.to_string(),
        "256 is outside the range of UNSIGNED8 (0 to 255)"
    );
    assert_eq!(too_big.sdo_abort_code(), 0x0609_0030);
    assert!(parse(DataType::Unsigned8, "-1").is_err());
    // Two's complement only for hex that fits the width.
    assert!(parse(DataType::Integer16, "0x10000").is_err());
    assert!(parse(DataType::Integer16, "65535").is_err());
    assert!(
        parse(DataType::Real32, "1e39")
            .unwrap_err()
            .is_out_of_range()
    );
    assert!(parse(DataType::Unsigned64, &"9".repeat(100)).is_err());
    assert!(parse(DataType::Unknown(0x40), "1").is_err());
    let long = parse(DataType::Unsigned32, &"x".repeat(1000))
        .unwrap_err()
        .to_string();
    assert!(long.len() < 100, "the message quotes a snippet: {long}");
}

#[test]
fn nodeid_expressions_resolve_against_the_node() {
    let parse = |text, id| Value::parse_text(DataType::Unsigned32, text, node(id));
    assert_eq!(parse("$NODEID+0x180", 5), Ok(Value::Unsigned32(0x185)));
    assert_eq!(
        parse("$NODEID+0x00000180", 127),
        Ok(Value::Unsigned32(0x1FF))
    );
    assert_eq!(
        parse("$NODEID+0x80000180", 1),
        Ok(Value::Unsigned32(0x8000_0181))
    );
    assert_eq!(parse("0x600 + $NODEID", 3), Ok(Value::Unsigned32(0x603)));
    assert_eq!(parse("$nodeid + 128", 2), Ok(Value::Unsigned32(130)));
    assert_eq!(parse("$NODEID", 42), Ok(Value::Unsigned32(42)));
    assert_eq!(
        Value::parse_text(DataType::Unsigned8, "$NODEID", node(42)),
        Ok(Value::Unsigned8(42))
    );
    let unresolved = Value::parse_text(DataType::Unsigned32, "$NODEID+0x180", None);
    assert_eq!(
        unresolved,
        Err(ValueError::NodeIdRequired {
            text: "$NODEID+0x180".into()
        })
    );
    for bad in [
        "$NODEID+",
        "$NODEID 5",
        "$NODEID+$NODEID",
        "1+$NODEID+2",
        "$NODEID-1",
        "+$NODEID",
    ] {
        assert!(parse(bad, 1).is_err(), "{bad}");
    }
    // The sum is range-checked like any value.
    assert!(Value::parse_text(DataType::Unsigned8, "$NODEID+0xFF", node(1)).is_err());
}

#[test]
fn text_round_trips_through_to_text() {
    for (value, _) in limits_table() {
        let text = value.to_text();
        assert_eq!(
            Value::parse_text(value.data_type(), &text, None),
            Ok(value.clone()),
            "{text}"
        );
    }
    assert_eq!(Value::Real32(0.1).to_text(), "0.1");
    assert_eq!(Value::OctetString(vec![0xAB, 1]).to_text(), "AB01");
    for (text, written) in [
        ("a b", "a b"),
        ("https://uniswarm.eu/", "https://uniswarm.eu/"),
        ("", "\"\""),
        (" padded ", "\" padded \""),
        ("a ; b", "\"a ; b\""),
        ("\"quoted\"", "\"\"quoted\"\""),
        ("say \"hi\" now", "say \"hi\" now"),
    ] {
        let value = Value::VisibleString(text.into());
        assert_eq!(value.to_text(), written);
        assert_eq!(parse(DataType::VisibleString, written), Ok(value));
    }
}

#[test]
fn json_as_api_md_says() {
    let cases = [
        (Value::Boolean(true), json!(true)),
        (Value::Unsigned8(200), json!(200)),
        (Value::Integer16(-300), json!(-300)),
        (Value::Integer24(-5), json!(-5)),
        (Value::Unsigned32(u32::MAX), json!(4294967295u32)),
        (Value::Integer48((1 << 47) - 1), json!(140737488355327i64)),
        (Value::Integer64(i64::MIN), json!("-9223372036854775808")),
        (Value::Unsigned64(u64::MAX), json!("18446744073709551615")),
        (
            Value::Unsigned56((1 << 56) - 1),
            json!(72057594037927935u64),
        ),
        (Value::Integer56(-1), json!(-1)),
        (Value::Real32(0.1), json!(0.1)),
        (Value::Real64(-1.25), json!(-1.25)),
        (Value::VisibleString("UMC1BDS32".into()), json!("UMC1BDS32")),
        (Value::UnicodeString("é".into()), json!("é")),
        (Value::OctetString(vec![0, 1, 2, 0xFF]), json!("AAEC/w==")),
        (Value::Domain(vec![]), json!("")),
        (
            Value::TimeOfDay(TimeOfDay { ms: 5, days: 6 }),
            json!({"ms": 5, "days": 6}),
        ),
    ];
    for (value, expected) in cases {
        assert_eq!(value.to_json(), expected, "{value:?}");
        assert_eq!(Value::from_json(value.data_type(), &expected), Ok(value));
    }
    for (value, _) in limits_table() {
        assert_eq!(
            Value::from_json(value.data_type(), &value.to_json()),
            Ok(value)
        );
    }
    assert_eq!(
        serde_json::to_value(Value::Unsigned64(7)).unwrap(),
        json!("7"),
        "Serialize is to_json"
    );
    let non_finite = Value::Real32(f32::INFINITY).to_json();
    assert_eq!(non_finite, json!("inf"));
    assert_eq!(
        Value::from_json(DataType::Real32, &non_finite),
        Ok(Value::Real32(f32::INFINITY))
    );
}

#[test]
fn json_accepts_strings_and_numbers_alike() {
    let from = |data_type, json: Json| Value::from_json(data_type, &json);
    assert_eq!(
        from(DataType::Unsigned64, json!(5)),
        Ok(Value::Unsigned64(5))
    );
    assert_eq!(
        from(DataType::Unsigned64, json!(u64::MAX)),
        Ok(Value::Unsigned64(u64::MAX))
    );
    assert_eq!(
        from(DataType::Unsigned16, json!("0x1234")),
        Ok(Value::Unsigned16(0x1234))
    );
    assert_eq!(
        from(DataType::Integer8, json!("-7")),
        Ok(Value::Integer8(-7))
    );
    assert_eq!(
        from(DataType::Integer32, json!(3.0)),
        Ok(Value::Integer32(3))
    );
    assert_eq!(from(DataType::Real32, json!("2.5")), Ok(Value::Real32(2.5)));
    assert_eq!(from(DataType::Real64, json!(3)), Ok(Value::Real64(3.0)));
    assert_eq!(from(DataType::Boolean, json!(1)), Ok(Value::Boolean(true)));
    assert_eq!(from(DataType::Boolean, json!(0)), Ok(Value::Boolean(false)));
    assert_eq!(
        from(DataType::Boolean, json!("true")),
        Ok(Value::Boolean(true))
    );
    for (data_type, bad) in [
        (DataType::Boolean, json!(2)),
        (DataType::Boolean, json!(null)),
        (DataType::Unsigned8, json!(256)),
        (DataType::Unsigned8, json!(-1)),
        (DataType::Unsigned8, json!(1.5)),
        (DataType::Unsigned8, json!([1])),
        (DataType::Unsigned8, json!("$NODEID")),
        (DataType::Integer64, json!("9223372036854775808")),
        (DataType::Real32, json!(1e39)),
        (DataType::Real32, json!(true)),
        (DataType::VisibleString, json!(5)),
        (DataType::OctetString, json!("not base64!")),
        (DataType::OctetString, json!([1, 2])),
        (
            DataType::TimeOfDay,
            json!({"ms": 0x1000_0000u32, "days": 0}),
        ),
        (DataType::Unknown(7), json!(1)),
    ] {
        assert!(from(data_type, bad.clone()).is_err(), "{data_type} {bad}");
    }
    let error = from(DataType::Unsigned8, json!(300)).unwrap_err();
    assert!(error.is_out_of_range());
}

#[test]
fn limits_give_too_high_and_too_low() {
    let low = Value::Integer16(-10);
    let high = Value::Integer16(100);
    assert_eq!(
        Value::Integer16(0).check_limits(Some(&low), Some(&high)),
        Ok(())
    );
    assert_eq!(
        Value::Integer16(-10).check_limits(Some(&low), Some(&high)),
        Ok(())
    );
    assert_eq!(
        Value::Integer16(100).check_limits(Some(&low), Some(&high)),
        Ok(())
    );
    let too_high = Value::Integer16(101)
        .check_limits(Some(&low), Some(&high))
        .unwrap_err();
    assert_eq!(
        too_high,
        ValueError::TooHigh {
            value: "101".into(),
            high: "100".into()
        }
    );
    assert_eq!(too_high.sdo_abort_code(), 0x0609_0031);
    let too_low = Value::Integer16(-11)
        .check_limits(Some(&low), None)
        .unwrap_err();
    assert_eq!(too_low.sdo_abort_code(), 0x0609_0032);
    assert_eq!(too_low.to_string(), "-11 is below the low limit -10");
    assert!(
        Value::Real32(1.5)
            .check_limits(None, Some(&Value::Real32(1.0)))
            .is_err()
    );
    assert_eq!(
        Value::Unsigned64(u64::MAX).check_limits(None, Some(&Value::Unsigned64(u64::MAX))),
        Ok(())
    );
    // Strings have no limits.
    assert_eq!(
        Value::VisibleString("z".into()).check_limits(Some(&low), Some(&high)),
        Ok(())
    );
}

#[test]
fn zero_and_conversions() {
    for data_type in DataType::ALL {
        let zero = Value::zero(data_type).unwrap();
        assert_eq!(zero.data_type(), data_type);
    }
    assert_eq!(Value::zero(DataType::Unknown(0x20)), None);
    assert_eq!(Value::Integer24(-3).as_i128(), Some(-3));
    assert_eq!(Value::Real32(0.5).as_f64(), Some(0.5));
    assert_eq!(Value::VisibleString("1".into()).as_f64(), None);
    assert!(Value::from_i128(DataType::Real32, 1).is_err());
    assert_eq!(
        TimeOfDay::from_raw(0xFFFF_FFFF_FFFF),
        TimeOfDay {
            ms: 0x0FFF_FFFF,
            days: 0xFFFF
        }
    );
}
