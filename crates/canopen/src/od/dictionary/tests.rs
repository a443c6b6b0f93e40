use super::*;
use serde_json::json;

fn sample() -> ObjectDictionary {
    let mut od = ObjectDictionary::new();
    let mut device_type = SubObject::new(0, "Device Type", DataType::Unsigned32, AccessType::Ro);
    device_type.default = Some("0x00020192".into());
    od.insert(Object::var(0x1000, device_type));

    let mut identity = Object::new(0x1018, "Identity Object", ObjectType::Record);
    let mut count = SubObject::new(0, "Number of Entries", DataType::Unsigned8, AccessType::Ro);
    count.default = Some("4".into());
    identity.insert_sub(count);
    let mut vendor = SubObject::new(1, "Vendor Id", DataType::Unsigned32, AccessType::Ro);
    vendor.default = Some("0x000004A2".into());
    identity.insert_sub(vendor);
    od.insert(identity);

    let mut tpdo = Object::new(0x1800, "TPDO_parameter_1", ObjectType::Record);
    let mut cob_id = SubObject::new(1, "COB_ID", DataType::Unsigned32, AccessType::Rw);
    cob_id.default = Some("$NODEID+0x00000180".into());
    tpdo.insert_sub(cob_id);
    od.insert(tpdo);

    let mut target = SubObject::new(0, "a1_Target_torque", DataType::Integer16, AccessType::Rww);
    target.pdo_mappable = true;
    target.low = Some("-1000".into());
    target.high = Some("0x03E8".into());
    od.insert(Object::var(0x6071, target));
    let set_point = SubObject::new(0, "a1_Set-point", DataType::Integer32, AccessType::Rw);
    od.insert(Object::var(0x60C1, set_point));
    od
}

#[test]
fn indexes_in_every_form_the_api_accepts() {
    assert_eq!(parse_index("0x6041"), Some(0x6041));
    assert_eq!(parse_index("0X6041"), Some(0x6041));
    assert_eq!(parse_index("6041h"), Some(0x6041));
    assert_eq!(parse_index("6041H"), Some(0x6041));
    assert_eq!(parse_index("24641"), Some(0x6041));
    assert_eq!(parse_index(" 4096 "), Some(0x1000));
    for bad in [
        "",
        "0x",
        "h",
        "0x10000",
        "65536",
        "-1",
        "0x+1",
        "+5",
        "a1_Statusword",
    ] {
        assert_eq!(parse_index(bad), None, "{bad}");
    }
    assert_eq!(format_index(0x6041), "0x6041");
    assert_eq!(format_index(0x1A), "0x001A");
}

#[test]
fn lookups_by_number_and_by_eds_name() {
    let od = sample();
    assert_eq!(od.resolve_index("0x1000").unwrap().name, "Device Type");
    assert_eq!(od.resolve_index("1018h").unwrap().index, 0x1018);
    assert_eq!(od.resolve_index("4096").unwrap().index, 0x1000);
    assert_eq!(od.resolve_index("device_type").unwrap().index, 0x1000);
    assert_eq!(od.resolve_index("A1_TARGET_TORQUE").unwrap().index, 0x6071);
    assert_eq!(od.resolve_index("a1_set_point").unwrap().index, 0x60C1);
    assert_eq!(
        od.resolve_index("0x2000"),
        Err(DictionaryError::UnknownObject(0x2000))
    );
    assert_eq!(
        od.resolve_index("nope"),
        Err(DictionaryError::UnknownName("nope".into()))
    );
    assert!(matches!(
        od.resolve_index("0x1g"),
        Err(DictionaryError::InvalidIndex(_))
    ));
    assert!(matches!(
        od.resolve_index(""),
        Err(DictionaryError::InvalidIndex(_))
    ));
    assert!(od.resolve_index("0x2000").unwrap_err().is_not_found());
    assert!(!od.resolve_index("0x1g").unwrap_err().is_not_found());

    let identity = od.get(0x1018).unwrap();
    assert_eq!(identity.resolve_sub("Vendor_ID").unwrap().sub_index, 1);
    assert_eq!(identity.resolve_sub("1").unwrap().name, "Vendor Id");
    assert_eq!(identity.resolve_sub("0x01").unwrap().name, "Vendor Id");
    assert_eq!(
        identity.resolve_sub("5"),
        Err(DictionaryError::UnknownSubObject {
            index: 0x1018,
            sub: 5
        })
    );
    assert!(matches!(
        identity.resolve_sub("256"),
        Err(DictionaryError::InvalidSubIndex(_))
    ));
    assert!(matches!(
        identity.resolve_sub("Serial"),
        Err(DictionaryError::UnknownSubName { .. })
    ));
    assert_eq!(
        identity.resolve_sub("5").unwrap_err().to_string(),
        "object 0x1018 has no sub-index 5"
    );

    let (object, sub) = od
        .resolve_json(&json!("Identity_Object"), &json!("vendor id"))
        .unwrap();
    assert_eq!((object.index, sub.sub_index), (0x1018, 1));
    let (_, sub) = od.resolve_json(&json!(0x1018), &json!(0)).unwrap();
    assert_eq!(sub.name, "Number of Entries");
    assert!(od.resolve_json(&json!(-1), &json!(0)).is_err());
    assert!(od.resolve_json(&json!(0x1018), &json!(300)).is_err());
    assert!(od.resolve_json(&json!(null), &json!(0)).is_err());
    assert!(od.resolve_json(&json!("0x1018"), &json!([1])).is_err());
    assert_eq!(od.sub(0x1018, 1).unwrap().name, "Vendor Id");
    assert_eq!(od.subs().count(), 6);
}

#[test]
fn defaults_and_limits_resolve_for_a_node() {
    let od = sample();
    let node = NodeId::new(5).ok();
    let cob_id = od.sub(0x1800, 1).unwrap();
    assert!(cob_id.uses_node_id());
    assert_eq!(
        cob_id.default_value(node),
        Ok(Some(Value::Unsigned32(0x185)))
    );
    assert!(matches!(
        cob_id.default_value(None),
        Err(ValueError::NodeIdRequired { .. })
    ));

    let torque = od.sub(0x6071, 0).unwrap();
    assert!(!torque.uses_node_id());
    assert_eq!(torque.high_value(None), Ok(Some(Value::Integer16(1000))));
    assert_eq!(
        torque.value_from_json(&json!(1000), None),
        Ok(Value::Integer16(1000))
    );
    assert_eq!(
        torque.value_from_text("-1000", None),
        Ok(Value::Integer16(-1000))
    );
    let too_high = torque.value_from_json(&json!(1001), None).unwrap_err();
    assert_eq!(too_high.sdo_abort_code(), 0x0609_0031);
    let too_low = torque.value_from_json(&json!("-1001"), None).unwrap_err();
    assert_eq!(too_low.sdo_abort_code(), 0x0609_0032);
    let out_of_type = torque.value_from_json(&json!(40000), None).unwrap_err();
    assert_eq!(out_of_type.sdo_abort_code(), 0x0609_0030);
    assert_eq!(
        torque.check(&Value::Unsigned16(1), None),
        Err(ValueError::WrongType {
            expected: DataType::Integer16,
            got: DataType::Unsigned16
        })
    );
    assert_eq!(torque.decode(&[0xE8, 0x03]), Ok(Value::Integer16(1000)));
}

#[test]
fn json_listing_as_api_md_shows_it() {
    let od = sample();
    let listing = od.to_json(NodeId::new(5).ok());
    assert_eq!(
        listing[1],
        json!({
            "index": "0x1018",
            "name": "Identity Object",
            "object_type": "record",
            "subs": [
                {"sub": 0, "name": "Number of Entries", "data_type": "u8", "access": "ro",
                 "pdo_mappable": false, "default": 4, "low": null, "high": null},
                {"sub": 1, "name": "Vendor Id", "data_type": "u32", "access": "ro",
                 "pdo_mappable": false, "default": 0x4A2, "low": null, "high": null},
            ],
        })
    );
    assert_eq!(listing[2]["subs"][0]["default"], json!(0x185));
    // Without a node id the expression stays text.
    let unresolved = od.get(0x1800).unwrap().to_json(None);
    assert_eq!(
        unresolved["subs"][0]["default"],
        json!("$NODEID+0x00000180")
    );
    assert_eq!(
        od.get(0x6071).unwrap().to_json(None)["subs"][0]["low"],
        json!(-1000)
    );
}

#[test]
fn parameter_values_are_typed() {
    let mut od = sample();
    od.set_parameter_value(0x6071, 0, &Value::Integer16(-5))
        .unwrap();
    assert_eq!(
        od.sub(0x6071, 0).unwrap().parameter_value.as_deref(),
        Some("-5")
    );
    assert_eq!(
        od.sub(0x6071, 0).unwrap().parameter_value(None),
        Ok(Some(Value::Integer16(-5)))
    );
    assert_eq!(
        od.set_parameter_value(0x6071, 0, &Value::Unsigned8(1)),
        Err(DictionaryError::WrongType {
            index: 0x6071,
            sub: 0,
            expected: DataType::Integer16,
            got: DataType::Unsigned8
        })
    );
    assert_eq!(
        od.set_parameter_value(0x7000, 0, &Value::Unsigned8(1)),
        Err(DictionaryError::UnknownObject(0x7000))
    );
    assert_eq!(
        od.set_parameter_value(0x1018, 9, &Value::Unsigned8(1)),
        Err(DictionaryError::UnknownSubObject {
            index: 0x1018,
            sub: 9
        })
    );
}

#[test]
fn name_folding() {
    assert!(names_match("Vendor Id", "Vendor_ID"));
    assert!(names_match("a1_Set-point", "A1_SET_POINT"));
    assert!(names_match(" Device Type ", "device_type"));
    assert!(!names_match("Device Type", "DeviceType"));
    assert!(!names_match("a1_Statusword", "a2_Statusword"));
}
