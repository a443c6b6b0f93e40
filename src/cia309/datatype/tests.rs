use super::*;

#[test]
fn mnemonics_round_trip_case_insensitively() {
    for datatype in Datatype::ALL {
        assert_eq!(Datatype::from_mnemonic(datatype.mnemonic()), Some(datatype));
    }
    assert_eq!(Datatype::from_mnemonic("U16"), Some(Datatype::U16));
    assert_eq!(Datatype::from_mnemonic("u24"), None);
    assert_eq!(Datatype::from_mnemonic(""), None);
}

#[test]
fn integers_are_read_as_strtoul_base_0() {
    assert_eq!(Datatype::U16.encode("0x1234"), Ok(vec![0x34, 0x12]));
    assert_eq!(Datatype::U16.encode("0X1234"), Ok(vec![0x34, 0x12]));
    assert_eq!(Datatype::U8.encode("017"), Ok(vec![15]));
    assert_eq!(Datatype::U8.encode("0"), Ok(vec![0]));
    assert_eq!(Datatype::U32.encode("+7"), Ok(vec![7, 0, 0, 0]));
    assert_eq!(
        Datatype::U64.encode("18446744073709551615"),
        Ok(vec![0xFF; 8])
    );
    assert_eq!(Datatype::I8.encode("-128"), Ok(vec![0x80]));
    assert_eq!(Datatype::I16.encode("-0x10"), Ok(vec![0xF0, 0xFF]));
    assert_eq!(Datatype::I32.encode("-2"), Ok(vec![0xFE, 0xFF, 0xFF, 0xFF]));
    assert_eq!(
        Datatype::I64.encode("-9223372036854775808"),
        Ok(vec![0, 0, 0, 0, 0, 0, 0, 0x80])
    );
    assert_eq!(Datatype::X8.encode("0xAb"), Ok(vec![0xAB]));
    assert_eq!(Datatype::Boolean.encode("1"), Ok(vec![1]));
}

#[test]
fn malformed_and_out_of_range_numbers_are_refused() {
    assert!(matches!(
        Datatype::U8.encode("256"),
        Err(ValueError::OutOfRange(_))
    ));
    assert!(matches!(
        Datatype::U8.encode("-1"),
        Err(ValueError::NotANumber(_))
    ));
    assert!(matches!(
        Datatype::I8.encode("128"),
        Err(ValueError::OutOfRange(_))
    ));
    assert!(matches!(
        Datatype::U16.encode("12a"),
        Err(ValueError::NotANumber(_))
    ));
    assert!(matches!(
        Datatype::U16.encode("0x"),
        Err(ValueError::NotANumber(_))
    ));
    assert!(matches!(
        Datatype::U16.encode("08"),
        Err(ValueError::NotANumber(_))
    ));
    assert!(matches!(
        Datatype::U64.encode("18446744073709551616"),
        Err(ValueError::OutOfRange(_))
    ));
    assert_eq!(Datatype::U32.encode(""), Err(ValueError::Missing));
    assert!(matches!(
        Datatype::R32.encode("1e39"),
        Err(ValueError::OutOfRange(_))
    ));
    assert!(matches!(
        Datatype::R32.encode("abc"),
        Err(ValueError::NotANumber(_))
    ));
}

#[test]
fn reals_are_ieee_little_endian() {
    assert_eq!(
        Datatype::R32.encode("1.5"),
        Ok(1.5f32.to_le_bytes().to_vec())
    );
    assert_eq!(
        Datatype::R64.encode("-2.25e3"),
        Ok((-2250.0f64).to_le_bytes().to_vec())
    );
}

#[test]
fn strings_quoted_or_one_word() {
    assert_eq!(Datatype::VisibleString.encode("abc"), Ok(b"abc".to_vec()));
    assert_eq!(
        Datatype::VisibleString.encode("\"two words\""),
        Ok(b"two words".to_vec())
    );
    assert_eq!(
        Datatype::VisibleString.encode("\"say \"\"hi\"\"\""),
        Ok(b"say \"hi\"".to_vec())
    );
    assert_eq!(Datatype::VisibleString.encode("\"\""), Ok(Vec::new()));
    assert_eq!(
        Datatype::VisibleString.encode("\"open"),
        Err(ValueError::BadString("no closing quote"))
    );
    assert_eq!(
        Datatype::VisibleString.encode("two words"),
        Err(ValueError::Trailing)
    );
    assert_eq!(
        Datatype::VisibleString.encode("\"a\" b"),
        Err(ValueError::Trailing)
    );
}

#[test]
fn base64_and_hex() {
    assert_eq!(Datatype::OctetString.encode("AQID"), Ok(vec![1, 2, 3]));
    assert_eq!(Datatype::Domain.encode("AQI="), Ok(vec![1, 2]));
    assert_eq!(
        Datatype::UnicodeString.encode("QQBCAA=="),
        Ok(vec![b'A', 0, b'B', 0])
    );
    assert_eq!(Datatype::Domain.encode("A*=="), Err(ValueError::BadBase64));
    assert_eq!(Datatype::Hex.encode("01 ab FF"), Ok(vec![1, 0xAB, 0xFF]));
    assert_eq!(Datatype::Hex.encode("01abFF"), Ok(vec![1, 0xAB, 0xFF]));
    assert_eq!(Datatype::Hex.encode("1 ab"), Err(ValueError::BadHex));
    assert_eq!(Datatype::Hex.encode("zz"), Err(ValueError::BadHex));
}

#[test]
fn replies_write_each_type_as_canopennode() {
    assert_eq!(Datatype::U8.format(&[200]), "200");
    assert_eq!(Datatype::Boolean.format(&[1]), "1");
    assert_eq!(Datatype::U16.format(&[0x34, 0x12]), "4660");
    assert_eq!(Datatype::U32.format(&[0xFF; 4]), "4294967295");
    assert_eq!(Datatype::U64.format(&[0xFF; 8]), "18446744073709551615");
    assert_eq!(Datatype::I8.format(&[0xFF]), "-1");
    assert_eq!(Datatype::I16.format(&[0x00, 0x80]), "-32768");
    assert_eq!(Datatype::I32.format(&[0xFE, 0xFF, 0xFF, 0xFF]), "-2");
    assert_eq!(
        Datatype::I64.format(&[0, 0, 0, 0, 0, 0, 0, 0x80]),
        "-9223372036854775808"
    );
    assert_eq!(Datatype::X8.format(&[0x0A]), "0x0A");
    assert_eq!(Datatype::X16.format(&[0x0A, 0x00]), "0x000A");
    assert_eq!(
        Datatype::X32.format(&[0x78, 0x56, 0x34, 0x12]),
        "0x12345678"
    );
    assert_eq!(
        Datatype::X64.format(&[1, 0, 0, 0, 0, 0, 0, 0]),
        "0x0000000000000001"
    );
    assert_eq!(Datatype::R32.format(&1.5f32.to_le_bytes()), "1.5");
    assert_eq!(Datatype::R64.format(&1e6f64.to_le_bytes()), "1e+06");
    assert_eq!(Datatype::VisibleString.format(b"UMC"), "\"UMC\"");
    assert_eq!(Datatype::VisibleString.format(b"a\"b\0\r"), "\"a\"\"b\"");
    assert_eq!(Datatype::VisibleString.format(b""), "\"\"");
    assert_eq!(Datatype::OctetString.format(&[1, 2, 3, 4]), "AQIDBA==");
    assert_eq!(Datatype::Domain.format(&[]), "");
    assert_eq!(Datatype::Hex.format(&[0x01, 0xAB]), "01 AB");
    assert_eq!(Datatype::Hex.format(&[]), "");
}

#[test]
fn a_length_that_does_not_fit_the_type_is_written_in_hex() {
    assert_eq!(Datatype::U16.format(&[1, 2, 3]), "01 02 03");
    assert_eq!(Datatype::R32.format(&[1]), "01");
    assert_eq!(Datatype::X8.format(&[]), "");
}

#[test]
fn g_formats_like_c() {
    let cases: [(f64, &str); 14] = [
        (0.0, "0"),
        (1.0, "1"),
        (-1.5, "-1.5"),
        (0.1, "0.1"),
        (123456.0, "123456"),
        (1234567.0, "1.23457e+06"),
        (0.0001, "0.0001"),
        (0.00001, "1e-05"),
        (1.23456789, "1.23457"),
        (100.0, "100"),
        (999999.5, "1e+06"),
        (1e100, "1e+100"),
        (f64::INFINITY, "inf"),
        (2.5e-7, "2.5e-07"),
    ];
    for (value, text) in cases {
        assert_eq!(format_g(value), text, "{value}");
    }
}
