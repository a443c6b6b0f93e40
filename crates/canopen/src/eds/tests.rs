//! The project's own EDS files, a small file with what vendors' files do
//! (`tests/data/reader.eds`), hand-made files for what they lack (compact
//! storage, DCF), malformed files, and a parser that never panics. The
//! vendor's real files are optional test inputs: read from the directory
//! `CANDECK_VENDOR_EDS` names, and skipped (saying so) without it.

use std::collections::BTreeMap;
use std::path::PathBuf;

use proptest::prelude::*;

use super::*;
use crate::od::{AccessType, DataType, ObjectType, Value, ValueError};

/// What vendors' files do, in a few objects, written for these tests.
const READER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/reader.eds");
/// The EDS files candeck carries.
const OWN_FILES: [&str; 4] = [
    concat!(env!("CARGO_MANIFEST_DIR"), "/../../eds/umc1bds32.eds"),
    concat!(env!("CARGO_MANIFEST_DIR"), "/../../eds/umc1bd90.eds"),
    concat!(env!("CARGO_MANIFEST_DIR"), "/../../eds/uio1led.eds"),
    concat!(env!("CARGO_MANIFEST_DIR"), "/../../eds/jmc_stepper.eds"),
];
const UMC1BDS32_OURS: &str = OWN_FILES[0];

/// The vendor's files, by name in `CANDECK_VENDOR_EDS`.
const UIO1LED: &str = "uio1led_v1.0.0.eds";
const UMC1BD90: &str = "umc1bd90_v1.0.4.eds";
const UMC1BDS32: &str = "umc1bds32_v1.0.4.eds";
const VENDOR_FILES: [&str; 3] = [UIO1LED, UMC1BD90, UMC1BDS32];

/// The path of one of the vendor's files, or `None` when
/// `CANDECK_VENDOR_EDS` is not set: then `test` says it was skipped.
fn vendor_file(file: &str, test: &str) -> Option<PathBuf> {
    use std::io::Write as _;
    let Some(dir) = std::env::var_os("CANDECK_VENDOR_EDS") else {
        // Straight to stderr, past the test harness's capture, so that the
        // skip shows in every run.
        let _ = writeln!(
            std::io::stderr(),
            "skipped: {test}: CANDECK_VENDOR_EDS is not set (the directory of the vendor's EDS files; see docs/testing.md)"
        );
        return None;
    };
    let path = PathBuf::from(dir).join(file);
    assert!(
        path.is_file(),
        "CANDECK_VENDOR_EDS is set but {} is not a file",
        path.display()
    );
    Some(path)
}

/// Every vendor file's path, or `None` (and `test` skipped).
fn vendor_files(test: &str) -> Option<Vec<PathBuf>> {
    VENDOR_FILES
        .iter()
        .map(|file| vendor_file(file, test))
        .collect()
}

fn load(path: impl AsRef<std::path::Path>) -> Eds {
    read_eds_file(path).unwrap_or_else(|error| panic!("{error}"))
}

fn node(id: u8) -> Option<NodeId> {
    NodeId::new(id).ok()
}

/// The line of `text` that contains `needle`, counted from 1.
/// A needle ending in a line break is the whole line.
fn line_of(text: &str, needle: &str) -> usize {
    let whole = needle.strip_suffix('\n');
    text.lines()
        .position(|line| match whole {
            Some(whole) => line == whole,
            None => line.contains(needle),
        })
        .expect(needle)
        + 1
}

/// No warning, an EDS and not a DCF, and the objects every device has.
fn assert_loads_without_surprises(path: &str) {
    let text = std::fs::read_to_string(path).unwrap();
    let (eds, warnings) = Eds::parse_with_warnings(&text, path).unwrap();
    assert!(warnings.is_empty(), "{path}: {warnings:#?}");
    assert!(!eds.is_dcf());
    for index in [0x1000, 0x1001, 0x1018, 0x1800, 0x1A00] {
        assert!(
            eds.dictionary.get(index).is_some(),
            "{path} lacks 0x{index:04X}"
        );
    }
}

#[test]
fn every_own_file_loads_without_surprises() {
    for path in OWN_FILES.into_iter().chain([READER]) {
        assert_loads_without_surprises(path);
    }
    assert_eq!(load(READER).dictionary.len(), 17);
}

#[test]
fn every_vendor_file_loads_without_surprises() {
    let Some(paths) = vendor_files("every_vendor_file_loads_without_surprises") else {
        return;
    };
    for path in &paths {
        assert_loads_without_surprises(path.to_str().unwrap());
    }
    assert_eq!(load(&paths[0]).dictionary.len(), 187);
    assert_eq!(load(&paths[1]).dictionary.len(), 188);
    assert_eq!(load(&paths[2]).dictionary.len(), 320);
}

/// What vendors' files do (`tests/data/reader.eds` reproduces it from the
/// UniSwarm files), read as they mean it.
#[test]
fn reader_spot_checks() {
    let eds = load(READER);
    let info = &eds.file_info;
    assert_eq!(info.file_name.as_deref(), Some("reader.eds"));
    // MM-DD-YYYY, kept as written.
    assert_eq!(info.creation_date.as_deref(), Some("12-20-2021"));
    assert_eq!(info.creation_time.as_deref(), Some("01:36PM"));
    assert_eq!(info.eds_version.as_deref(), Some("4.0"));
    let device = &eds.device_info;
    assert_eq!(device.vendor_name.as_deref(), Some("Example SASU"));
    assert_eq!(device.vendor_number, Some(0x4A2));
    assert_eq!(device.product_number, Some(0x4101));
    assert_eq!(device.revision_number, Some(1));
    assert_eq!(device.order_code.as_deref(), Some("0"));
    assert_eq!(
        device.baud_rates.iter().copied().collect::<Vec<_>>(),
        [10, 20, 50, 125, 250, 500, 1000]
    );
    assert_eq!(
        (device.nr_of_rx_pdo, device.nr_of_tx_pdo),
        (Some(1), Some(1))
    );
    assert_eq!(device.granularity, Some(8));
    assert_eq!(device.simple_boot_up_slave, Some(true));
    assert_eq!(device.lss_supported, Some(false));
    // A bit field in decimal: which PDO parameters the compact PDO form
    // leaves out.
    assert_eq!(device.compact_pdo, Some(0x37));
    assert!(device.other.is_empty(), "{:?}", device.other);
    assert_eq!(
        eds.dummy_usage.iter().copied().collect::<Vec<_>>(),
        [2, 3, 4, 5, 6, 7]
    );
    assert_eq!(eds.comments, ["Reader test device"]);

    let device_type = eds.dictionary.get(0x1000).unwrap();
    assert_eq!(device_type.object_type, ObjectType::Var);
    assert_eq!(device_type.name, "Device Type");
    let sub = device_type.sub(0).unwrap();
    assert_eq!(
        (sub.data_type, sub.access, sub.pdo_mappable),
        (DataType::Unsigned32, AccessType::Ro, false)
    );
    assert_eq!(sub.default_value(None), Ok(Some(Value::Unsigned32(428))));

    // The API's name for it, though this file spells it "Vendor Id".
    let identity = eds.dictionary.resolve_index("Identity_Object").unwrap();
    let vendor = identity.resolve_sub("Vendor_ID").unwrap();
    assert_eq!((vendor.sub_index, vendor.name.as_str()), (1, "Vendor Id"));
    assert_eq!(
        vendor.default_value(None),
        Ok(Some(Value::Unsigned32(0x4A2)))
    );
    assert_eq!(identity.resolve_sub("vendor_id").unwrap().sub_index, 1);

    // TPDO 1 starts invalid (bit 31), its COB-ID needs a node id.
    let cob_id = eds.dictionary.sub(0x1800, 1).unwrap();
    assert_eq!(cob_id.default.as_deref(), Some("$NODEID+0x80000180"));
    assert_eq!(
        cob_id.default_value(node(3)),
        Ok(Some(Value::Unsigned32(0x8000_0183)))
    );
    assert!(matches!(
        cob_id.default_value(None),
        Err(ValueError::NodeIdRequired { .. })
    ));
    let mapping = eds.dictionary.sub(0x1A00, 1).unwrap();
    assert_eq!(
        mapping.default_value(None),
        Ok(Some(Value::Unsigned32(0x6041_0010)))
    );
    // The RPDO communication objects have no sub 4 (CiA 301 reserves it).
    let rpdo = eds.dictionary.get(0x1400).unwrap();
    assert_eq!(
        rpdo.subs.keys().copied().collect::<Vec<_>>(),
        [0, 1, 2, 3, 5]
    );

    let voltage = eds.dictionary.get(0x2000).unwrap();
    assert_eq!(
        (voltage.name.as_str(), voltage.object_type),
        ("Board_voltage", ObjectType::Array)
    );
    assert_eq!(voltage.sub(1).unwrap().name, "Board_voltage_input");
    assert!(voltage.sub(1).unwrap().pdo_mappable);
    // A UNICODE_STRING whose default is quoted ASCII.
    let date = eds.dictionary.sub(0x2001, 0).unwrap();
    assert_eq!(date.data_type, DataType::UnicodeString);
    assert_eq!(
        date.default_value(None),
        Ok(Some(Value::UnicodeString("XXXX/XX/XX XX:XX:XX".into())))
    );
    let errors = eds.dictionary.get(0x1003).unwrap();
    assert_eq!(errors.object_type, ObjectType::Array);
    assert_eq!(errors.sub(0).unwrap().access, AccessType::Rw);
    // A bare $NODEID default.
    let node_id = eds
        .dictionary
        .get(0x2040)
        .unwrap()
        .resolve_sub("Node_ID")
        .unwrap();
    assert_eq!(
        node_id.default_value(node(42)),
        Ok(Some(Value::Unsigned8(42)))
    );
    let board = eds.dictionary.get(0x2800).unwrap();
    assert_eq!(
        (board.name.as_str(), board.object_type),
        ("Board_status", ObjectType::Record)
    );
    let torque_pid = eds.dictionary.get(0x4020).unwrap();
    assert_eq!(torque_pid.name, "a1_Torque_PID_status");
    assert_eq!(torque_pid.resolve_sub("Integrator").unwrap().sub_index, 3);

    // Names by index and index by names, in any case.
    let status = eds.dictionary.resolve_index("a1_Statusword").unwrap();
    assert_eq!(status.index, 0x6041);
    let sub = status.sub(0).unwrap();
    assert_eq!(
        (sub.data_type, sub.pdo_mappable),
        (DataType::Unsigned16, true)
    );
    assert_eq!(
        eds.dictionary.resolve_index("A2_STATUSWORD").unwrap().index,
        0x6841
    );
    assert_eq!(
        eds.dictionary.resolve_index("0x6041").unwrap().name,
        "a1_Statusword"
    );
    assert!(
        eds.dictionary
            .subs()
            .any(|(_, sub)| sub.name == "Set-point" && sub.access == AccessType::Rww)
    );
    // Limits in hex, negative hex, and a signed default at INTEGER32's minimum.
    let low_limited = eds
        .dictionary
        .subs()
        .find(|(_, sub)| sub.low.as_deref() == Some("-0x7FFFFFFF"))
        .map(|(_, sub)| sub)
        .unwrap();
    assert_eq!(
        low_limited.low_value(None),
        Ok(Some(Value::Integer32(-0x7FFF_FFFF)))
    );
    assert_eq!(
        low_limited.high_value(None),
        Ok(Some(Value::Integer32(0x7FFF_FFFF)))
    );
    assert!(
        eds.dictionary
            .subs()
            .any(|(_, sub)| sub.default.as_deref() == Some("-2147483648")
                && sub.default_value(None) == Ok(Some(Value::Integer32(i32::MIN))))
    );
}

#[test]
fn every_default_and_limit_of_our_files_is_a_value_of_its_type() {
    for path in OWN_FILES.into_iter().chain([READER]) {
        let eds = load(path);
        for (object, sub) in eds.dictionary.subs() {
            for text in [&sub.default, &sub.low, &sub.high].into_iter().flatten() {
                assert!(
                    Value::parse_text(sub.data_type, text, node(127)).is_ok(),
                    "{path}: 0x{:04X}sub{}: {text}",
                    object.index,
                    sub.sub_index
                );
            }
        }
    }
}

#[test]
fn uio1led_spot_checks() {
    let Some(path) = vendor_file(UIO1LED, "uio1led_spot_checks") else {
        return;
    };
    let eds = load(path);
    let info = &eds.file_info;
    assert_eq!(info.file_name.as_deref(), Some("uio1led.eds"));
    // MM-DD-YYYY, kept as written.
    assert_eq!(info.creation_date.as_deref(), Some("12-20-2021"));
    assert_eq!(info.creation_time.as_deref(), Some("01:36PM"));
    assert_eq!(info.eds_version.as_deref(), Some("4.0"));
    let device = &eds.device_info;
    assert_eq!(device.vendor_name.as_deref(), Some("UniSwarm SASU"));
    assert_eq!(device.vendor_number, Some(0x4A2));
    assert_eq!(device.product_number, Some(0x4101));
    assert_eq!(device.revision_number, Some(1));
    assert_eq!(device.order_code.as_deref(), Some("0"));
    assert_eq!(
        device.baud_rates.iter().copied().collect::<Vec<_>>(),
        [10, 20, 50, 125, 250, 500, 1000]
    );
    assert_eq!(
        (device.nr_of_rx_pdo, device.nr_of_tx_pdo),
        (Some(4), Some(4))
    );
    assert_eq!(device.granularity, Some(8));
    assert_eq!(device.simple_boot_up_slave, Some(true));
    assert_eq!(device.lss_supported, Some(false));
    assert!(device.other.is_empty(), "{:?}", device.other);
    assert_eq!(
        eds.dummy_usage.iter().copied().collect::<Vec<_>>(),
        [2, 3, 4, 5, 6, 7]
    );
    assert_eq!(eds.comments, ["UIO1LED LEDs controller"]);

    let device_type = eds.dictionary.get(0x1000).unwrap();
    assert_eq!(device_type.object_type, ObjectType::Var);
    assert_eq!(device_type.name, "Device Type");
    let sub = device_type.sub(0).unwrap();
    assert_eq!(
        (sub.data_type, sub.access, sub.pdo_mappable),
        (DataType::Unsigned32, AccessType::Ro, false)
    );
    assert_eq!(sub.default_value(None), Ok(Some(Value::Unsigned32(428))));

    // The API's name for it, though this file spells it "Vendor Id".
    let identity = eds.dictionary.resolve_index("Identity_Object").unwrap();
    let vendor = identity.resolve_sub("Vendor_ID").unwrap();
    assert_eq!((vendor.sub_index, vendor.name.as_str()), (1, "Vendor Id"));
    assert_eq!(
        vendor.default_value(None),
        Ok(Some(Value::Unsigned32(0x4A2)))
    );

    // TPDO 1 starts invalid (bit 31) on this device.
    let cob_id = eds.dictionary.sub(0x1800, 1).unwrap();
    assert_eq!(cob_id.default.as_deref(), Some("$NODEID+0x80000180"));
    assert_eq!(
        cob_id.default_value(node(3)),
        Ok(Some(Value::Unsigned32(0x8000_0183)))
    );
    // The RPDO communication objects have no sub 4 (CiA 301 reserves it).
    let rpdo = eds.dictionary.get(0x1400).unwrap();
    assert_eq!(
        rpdo.subs.keys().copied().collect::<Vec<_>>(),
        [0, 1, 2, 3, 5]
    );

    let voltage = eds.dictionary.get(0x2000).unwrap();
    assert_eq!(
        (voltage.name.as_str(), voltage.object_type),
        ("Board_voltage", ObjectType::Array)
    );
    assert_eq!(voltage.sub(1).unwrap().name, "Board_voltage_input");
    assert!(voltage.sub(1).unwrap().pdo_mappable);
    // A UNICODE_STRING whose default is quoted ASCII.
    let date = eds.dictionary.sub(0x2001, 0).unwrap();
    assert_eq!(date.data_type, DataType::UnicodeString);
    assert_eq!(
        date.default_value(None),
        Ok(Some(Value::UnicodeString("XXXX/XX/XX XX:XX:XX".into())))
    );
    let errors = eds.dictionary.get(0x1003).unwrap();
    assert_eq!(errors.object_type, ObjectType::Array);
    assert_eq!(errors.sub(0).unwrap().access, AccessType::Rw);
    // A bare $NODEID default.
    let node_id = eds
        .dictionary
        .get(0x2040)
        .unwrap()
        .resolve_sub("Node_ID")
        .unwrap();
    assert_eq!(
        node_id.default_value(node(42)),
        Ok(Some(Value::Unsigned8(42)))
    );
}

#[test]
fn umc1bds32_spot_checks() {
    let Some(path) = vendor_file(UMC1BDS32, "umc1bds32_spot_checks") else {
        return;
    };
    let eds = load(path);
    // A bit field: which PDO parameters the compact PDO form leaves out.
    assert_eq!(eds.device_info.compact_pdo, Some(0x37));
    let status = eds.dictionary.resolve_index("a1_Statusword").unwrap();
    assert_eq!(status.index, 0x6041);
    let sub = status.sub(0).unwrap();
    assert_eq!(
        (sub.data_type, sub.pdo_mappable),
        (DataType::Unsigned16, true)
    );
    assert_eq!(
        eds.dictionary.resolve_index("A2_STATUSWORD").unwrap().index,
        0x6841
    );
    let vendor = eds
        .dictionary
        .get(0x1018)
        .unwrap()
        .resolve_sub("vendor_id")
        .unwrap();
    assert_eq!(vendor.name, "Vendor_ID");

    let cob_id = eds.dictionary.sub(0x1800, 1).unwrap();
    assert_eq!(cob_id.default.as_deref(), Some("$NODEID+0x00000180"));
    assert_eq!(
        cob_id.default_value(node(1)),
        Ok(Some(Value::Unsigned32(0x181)))
    );
    assert!(matches!(
        cob_id.default_value(None),
        Err(ValueError::NodeIdRequired { .. })
    ));
    let mapping = eds.dictionary.sub(0x1A00, 1).unwrap();
    assert_eq!(
        mapping.default_value(None),
        Ok(Some(Value::Unsigned32(0x6041_0010)))
    );

    let board = eds.dictionary.get(0x2800).unwrap();
    assert_eq!(
        (board.name.as_str(), board.object_type),
        ("Board_status", ObjectType::Record)
    );
    // Limits in hex, negative hex, and a signed default at INTEGER32's minimum.
    let low_limited = eds
        .dictionary
        .subs()
        .find(|(_, sub)| sub.low.as_deref() == Some("-0x7FFFFFFF"))
        .map(|(_, sub)| sub)
        .unwrap();
    assert_eq!(
        low_limited.low_value(None),
        Ok(Some(Value::Integer32(-0x7FFF_FFFF)))
    );
    assert!(
        eds.dictionary
            .subs()
            .any(|(_, sub)| sub.default.as_deref() == Some("-2147483648")
                && sub.default_value(None) == Ok(Some(Value::Integer32(i32::MIN))))
    );
    // Every default and limit of the file is a value of its type.
    for (object, sub) in eds.dictionary.subs() {
        for text in [&sub.default, &sub.low, &sub.high].into_iter().flatten() {
            assert!(
                Value::parse_text(sub.data_type, text, node(127)).is_ok(),
                "0x{:04X}sub{}: {text}",
                object.index,
                sub.sub_index
            );
        }
    }
}

#[test]
fn umc1bd90_spot_checks() {
    let Some(path) = vendor_file(UMC1BD90, "umc1bd90_spot_checks") else {
        return;
    };
    let eds = load(path);
    assert_eq!(eds.device_info.vendor_number, Some(0x4A2));
    let status = eds.dictionary.resolve_index("0x6041").unwrap();
    assert_eq!(status.name, "a1_Statusword");
    let torque_pid = eds.dictionary.get(0x4020).unwrap();
    assert_eq!(torque_pid.name, "a1_Torque_PID_status");
    assert_eq!(torque_pid.resolve_sub("Integrator").unwrap().sub_index, 3);
    let set_point = eds
        .dictionary
        .subs()
        .find(|(_, sub)| sub.name == "Set-point");
    assert!(set_point.is_some());
}

/// Written out, read back the same, and the text stable from then on.
fn assert_round_trips(path: &std::path::Path) {
    let eds = load(path);
    let written = eds.write();
    let (again, warnings) = Eds::parse_with_warnings(&written, "written.eds").unwrap();
    let path = path.display();
    assert!(warnings.is_empty(), "{path}: {warnings:#?}");
    assert_eq!(again, eds, "{path}");
    assert_eq!(again.write(), written);
    assert!(written.contains("\r\n[1018sub1]\r\n"));
}

#[test]
fn own_files_round_trip() {
    for path in OWN_FILES.into_iter().chain([READER]) {
        assert_round_trips(path.as_ref());
    }
}

#[test]
fn vendor_files_round_trip() {
    let Some(paths) = vendor_files("vendor_files_round_trip") else {
        return;
    };
    for path in &paths {
        assert_round_trips(path);
    }
}

#[test]
fn python_canopen_reads_what_we_write_the_same_way() {
    // What python-canopen's configparser-based reader needs: keys it looks
    // up by exact case, lists with decimal keys, hex DataType.
    let written = load(UMC1BDS32_OURS).write();
    for needle in [
        "[MandatoryObjects]\r\nSupportedObjects=3\r\n1=0x1000\r\n2=0x1001\r\n3=0x1018\r\n",
        "[1000]\r\nParameterName=Device_type\r\nObjectType=0x7\r\nDataType=0x0007\r\nAccessType=ro\r\n",
        "DefaultValue=$NODEID+0x00000180\r\n",
        "[6041]\r\nParameterName=a1_Statusword\r\n",
        "[DeviceInfo]\r\nVendorName=UniSwarm SASU\r\nVendorNumber=0x4A2\r\n",
    ] {
        assert!(written.contains(needle), "{needle}");
    }
}

const COMPACT: &str = "\
[DeviceInfo]
VendorNumber=0x123
[MandatoryObjects]
SupportedObjects=1
1=0x1000
[1000]
ParameterName=Device Type
DataType=0x0007
AccessType=ro
DefaultValue=0x191
[ManufacturerObjects]
SupportedObjects=1
1=0x2100
[2100]
ParameterName=Gain
ObjectType=0x8
DataType=0x0003
AccessType=rw
DefaultValue=-5
LowLimit=-100
HighLimit=100
PDOMapping=1
CompactSubObj=3
[2100Name]
NrOfEntries=1
2=Gain of axis 2
";

#[test]
fn compact_sub_objects_are_generated_from_the_parent() {
    let eds = Eds::parse(COMPACT, "compact.eds").unwrap();
    let gain = eds.dictionary.get(0x2100).unwrap();
    assert_eq!(gain.object_type, ObjectType::Array);
    assert_eq!(gain.subs.len(), 4);
    let count = gain.sub(0).unwrap();
    assert_eq!(
        (count.name.as_str(), count.data_type, count.access),
        ("NrOfObjects", DataType::Unsigned8, AccessType::Ro)
    );
    assert_eq!(count.default_value(None), Ok(Some(Value::Unsigned8(3))));
    let names: Vec<_> = gain.subs.values().map(|sub| sub.name.as_str()).collect();
    assert_eq!(names, ["NrOfObjects", "Gain1", "Gain of axis 2", "Gain3"]);
    for sub in gain.subs.values().skip(1) {
        assert_eq!(
            (sub.data_type, sub.access, sub.pdo_mappable),
            (DataType::Integer16, AccessType::Rw, true)
        );
        assert_eq!(sub.default_value(None), Ok(Some(Value::Integer16(-5))));
        assert_eq!(sub.parameter_value, None);
    }
    assert!(
        gain.sub(3)
            .unwrap()
            .check(&Value::Integer16(101), None)
            .is_err()
    );
    // A VAR without ObjectType, per CiA 306.
    assert_eq!(
        eds.dictionary.get(0x1000).unwrap().object_type,
        ObjectType::Var
    );

    // Written out with explicit sub-objects, read back the same.
    let written = eds.write();
    assert!(written.contains("[2100sub2]\r\nParameterName=Gain of axis 2\r\n"));
    assert_eq!(Eds::parse(&written, "again.eds").unwrap(), eds);
}

#[test]
fn compact_values_and_denotations_of_a_dcf() {
    let dcf = format!(
        "{COMPACT}[2100Value]\nNrOfEntries=2\n1=7\n3=0x10\n[2100Denotation]\nNrOfEntries=1\n1=Left\n\
         [DeviceComissioning]\nNodeID=0x05\nNodeName=Left arm\nBaudrate=500\nNetNumber=1\nCANopenManager=0\n"
    );
    let eds = Eds::parse(&dcf, "compact.dcf").unwrap();
    assert!(eds.is_dcf());
    assert_eq!(eds.node_id(), node(5));
    let commissioning = eds.commissioning.as_ref().unwrap();
    assert_eq!(commissioning.node_name.as_deref(), Some("Left arm"));
    assert_eq!(commissioning.baudrate, Some(500));
    assert_eq!(commissioning.canopen_manager, Some(false));
    let gain = eds.dictionary.get(0x2100).unwrap();
    assert_eq!(
        gain.sub(1).unwrap().parameter_value(None),
        Ok(Some(Value::Integer16(7)))
    );
    assert_eq!(gain.sub(2).unwrap().parameter_value, None);
    assert_eq!(
        gain.sub(3).unwrap().parameter_value(None),
        Ok(Some(Value::Integer16(16)))
    );
    assert_eq!(gain.sub(1).unwrap().denotation.as_deref(), Some("Left"));
    assert_eq!(Eds::parse(&eds.write(), "again.dcf").unwrap(), eds);

    // A value that is none of its type is dropped, with its line.
    let bad = dcf.replace("3=0x10", "3=0xZZ");
    let warning = warning_at(&bad, "3=0xZZ", Action::Dropped);
    assert!(warning.message.contains("bad hex digits"), "{warning}");
    let eds = Eds::parse(&bad, "compact.dcf").unwrap();
    assert_eq!(eds.dictionary.sub(0x2100, 3).unwrap().parameter_value, None);
}

#[test]
fn a_dcf_carries_current_values_and_reads_back() {
    let eds = load(UMC1BDS32_OURS);
    let values = BTreeMap::from([
        ((0x1017, 0), Value::Unsigned16(250)),
        ((0x1800, 1), Value::Unsigned32(0x182)),
        (
            (0x1008, 0),
            Value::VisibleString("UMC1BDS32 \"axis\" ; x".into()),
        ),
        ((0x6060, 0), Value::Integer8(-3)),
    ]);
    let commissioning = DeviceCommissioning {
        node_id: Some(2),
        node_name: Some("umc-2".into()),
        baudrate: Some(1000),
        ..DeviceCommissioning::default()
    };
    let dcf = eds.to_dcf(commissioning, &values).unwrap();
    let text = dcf.write();
    assert!(
        text.contains("[DeviceComissioning]\r\nNodeID=2\r\nNodeName=umc-2\r\nBaudrate=1000\r\n")
    );
    assert!(text.contains("ParameterValue=386\r\n"));
    let again = Eds::parse(&text, "umc-2.dcf").unwrap();
    assert_eq!(again, dcf);
    assert_eq!(again.node_id(), node(2));
    for ((index, sub), value) in &values {
        let entry = again.dictionary.sub(*index, *sub).unwrap();
        assert_eq!(
            entry.parameter_value(again.node_id()),
            Ok(Some(value.clone())),
            "0x{index:04X}"
        );
    }

    let unknown = BTreeMap::from([((0x7777, 0), Value::Unsigned8(1))]);
    assert!(
        eds.to_dcf(DeviceCommissioning::default(), &unknown)
            .is_err()
    );
    let wrong_type = BTreeMap::from([((0x1017, 0), Value::Unsigned32(1))]);
    assert!(
        eds.to_dcf(DeviceCommissioning::default(), &wrong_type)
            .is_err()
    );
}

/// A small valid EDS to break in the tests below.
const MINI: &str = "\
[FileInfo]
FileName=mini.eds
FileVersion=1.0.2
CreationDate=20-12-2021
[DeviceInfo]
VendorNumber=0x4A2
RevisionNumber=1.0.2
[MandatoryObjects]
SupportedObjects=2
1=0x1000
2=0x1018
[1000]
ParameterName=Device Type
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=0x191
[1018]
ParameterName=Identity Object
ObjectType=0x9
SubNumber=2
[1018sub0]
ParameterName=Number of Entries
ObjectType=0x7
DataType=0x0005
AccessType=ro
DefaultValue=1
[1018sub1]
ParameterName=Vendor Id
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=0x4A2
";

#[test]
fn odd_but_readable_files_give_warnings() {
    let (eds, warnings) = Eds::parse_with_warnings(MINI, "mini.eds").unwrap();
    // A version where a number belongs: kept as text.
    assert_eq!(eds.device_info.revision_number, None);
    assert_eq!(
        eds.device_info.other,
        [("RevisionNumber".to_string(), "1.0.2".to_string())]
    );
    assert_eq!(eds.file_info.file_version.as_deref(), Some("1.0.2"));
    assert_eq!(eds.file_info.creation_date.as_deref(), Some("20-12-2021"));
    let shown: Vec<_> = warnings.iter().map(ToString::to_string).collect();
    assert_eq!(
        shown,
        [
            "mini.eds:5: no ProductNumber in [DeviceInfo] nor a 0x1018 sub 2 default: the file \
             matches no device by identity (assign it to a node by hand)",
            "mini.eds:7: RevisionNumber=1.0.2 is not a number; kept as text",
        ]
    );
    assert_eq!(warnings[1].key, "[DeviceInfo] RevisionNumber");
    assert_eq!(warnings[1].action, Action::Kept);
    assert_eq!(eds.warnings, warnings);
    assert_eq!(Eds::parse(&eds.write(), "again.eds").unwrap(), eds);

    // An unlisted object, a miscounted SubNumber, limits against the default.
    let odd = format!(
        "{}[2000]\nParameterName=Extra\nDataType=0x0005\nAccessType=rw\nDefaultValue=9\nLowLimit=10\nHighLimit=20\n",
        MINI.replace("SubNumber=2", "SubNumber=5")
    );
    let (eds, warnings) = Eds::parse_with_warnings(&odd, "odd.eds").unwrap();
    assert!(eds.dictionary.get(0x2000).is_some());
    let messages: Vec<_> = warnings.iter().map(|w| w.message.as_str()).collect();
    assert!(
        messages.contains(&"SubNumber=5 but there are 2 sub-object sections"),
        "{messages:?}"
    );
    assert!(
        messages.contains(&"object 0x2000 is in no object list; read anyway"),
        "{messages:?}"
    );
    assert!(
        messages
            .iter()
            .any(|m| m.contains("DefaultValue 9 is below the low limit 10")),
        "{messages:?}"
    );
}

#[test]
fn vendor_quirks_in_spelling_are_accepted() {
    let quirky = MINI
        .replace("[1018sub1]", "[1018SUB1]")
        .replace(
            "AccessType=ro\nDefaultValue=0x191",
            "accesstype = RO ; read only\ndefaultvalue=0x191",
        )
        .replace("[FileInfo]", "; made by hand\n[fileinfo]")
        .replace('\n', "\r\n");
    let eds = Eds::parse(&quirky, "quirky.eds").unwrap();
    let reference = Eds::parse(MINI, "mini.eds").unwrap();
    assert_eq!(eds.dictionary, reference.dictionary);
    assert_eq!(eds.file_info.file_name.as_deref(), Some("mini.eds"));
    // Latin-1 bytes (a Windows tool's "°") are read, not refused.
    let mut latin1 = MINI.replace("Device Type", "Temperature XC").into_bytes();
    let at = latin1.windows(2).position(|w| w == b"XC").unwrap();
    latin1[at] = 0xB0;
    let eds = Eds::parse_bytes(&latin1, "latin1.eds").unwrap();
    assert_eq!(
        eds.dictionary.get(0x1000).unwrap().name,
        "Temperature \u{B0}C"
    );
}

/// Reads `text`, which must load, and returns its one warning at the line
/// containing `at`, which must name the file, the line and `action`.
fn warning_at(text: &str, at: &str, action: Action) -> EdsWarning {
    let eds = Eds::parse(text, "odd.eds").unwrap_or_else(|error| panic!("{error}"));
    let line = line_of(text, at);
    let here: Vec<_> = eds.warnings.iter().filter(|w| w.line == line).collect();
    assert_eq!(here.len(), 1, "line {line}: {:#?}", eds.warnings);
    let warning = here[0].clone();
    assert_eq!(warning.file, "odd.eds");
    assert_eq!(warning.action, action, "{warning}");
    assert!(
        warning
            .to_string()
            .starts_with(&format!("odd.eds:{line}: ")),
        "{warning}"
    );
    warning
}

/// Reads `text`, which must load, and checks that the round trip through
/// the writer keeps what was read.
fn load_odd(text: &str) -> Eds {
    let eds = Eds::parse(text, "odd.eds").unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(Eds::parse(&eds.write(), "again.eds").unwrap(), eds);
    eds
}

/// MINI with one more object, `[2000]` made of `keys`, listed as optional.
fn with_2000(keys: &str) -> String {
    format!(
        "{MINI}[OptionalObjects]\nSupportedObjects=1\n1=0x2000\n[2000]\nParameterName=Extra\n{keys}"
    )
}

#[test]
fn an_empty_access_type_is_read_as_rw() {
    // UniSwarm's umckin1.eds, umc1bds32.eds (old) and uio8ad.eds.
    let text = with_2000("ObjectType=0x7\nDataType=0x0007\nAccessType=\nDefaultValue=5\n");
    let warning = warning_at(&text, "AccessType=\n", Action::Defaulted);
    assert_eq!(warning.key, "[2000] AccessType");
    assert_eq!(warning.message, "AccessType is empty; read as rw");
    let eds = load_odd(&text);
    let entry = eds.dictionary.sub(0x2000, 0).unwrap();
    assert_eq!(
        (entry.access, entry.default.as_deref()),
        (AccessType::Rw, Some("5"))
    );

    let missing = text.replace("AccessType=\n", "");
    let warning = warning_at(&missing, "[2000]", Action::Defaulted);
    assert_eq!(warning.message, "[2000] has no AccessType; read as rw");
    assert_eq!(
        load_odd(&missing).dictionary.sub(0x2000, 0).unwrap().access,
        AccessType::Rw
    );
}

#[test]
fn access_types_r_and_w_are_read_as_ro_and_wo() {
    // 658 entries of 16 files of the second set of real files.
    for (token, access) in [
        ("R", AccessType::Ro),
        ("r", AccessType::Ro),
        ("W", AccessType::Wo),
    ] {
        let text = with_2000(&format!(
            "ObjectType=0x7\nDataType=0x0007\nAccessType={token}\nDefaultValue=5\n"
        ));
        let warning = warning_at(&text, &format!("AccessType={token}\n"), Action::Corrected);
        assert_eq!(warning.key, "[2000] AccessType");
        assert_eq!(
            warning.message,
            format!("AccessType={token} is no access type of CiA 306; read as {access}")
        );
        let eds = load_odd(&text);
        let entry = eds.dictionary.sub(0x2000, 0).unwrap();
        assert_eq!(entry.access, access, "{token}");
        assert!(!(access == AccessType::Ro && entry.access.is_writable()));
    }
    // The tokens of CiA 306 in any case are no warning.
    let text = with_2000("ObjectType=0x7\nDataType=0x0007\nAccessType=RO\n");
    let eds = load_odd(&text);
    assert_eq!(
        eds.dictionary.sub(0x2000, 0).unwrap().access,
        AccessType::Ro
    );
    assert!(!eds.warnings.iter().any(|w| w.key.starts_with("[2000]")));
}

#[test]
fn an_access_token_that_means_nothing_refuses_the_entry() {
    for token in ["UNKNOWN", "readable", "RX"] {
        // A VAR: the object is the entry.
        let text = with_2000(&format!(
            "ObjectType=0x7\nDataType=0x0007\nAccessType={token}\nDefaultValue=5\n"
        ));
        let warning = warning_at(&text, &format!("AccessType={token}\n"), Action::Dropped);
        assert_eq!(
            warning.message,
            format!(
                "AccessType={token} is no access type (ro, wo, rw, rwr, rww, const): what the \
                 entry allows is not known; [2000] dropped"
            )
        );
        let eds = load_odd(&text);
        assert!(eds.dictionary.get(0x2000).is_none(), "{token}");
    }
    // A sub-object of a record: that sub only.
    let text = MINI.replace(
        "[1018sub1]\nParameterName=Vendor Id\nObjectType=0x7\nDataType=0x0007\nAccessType=ro",
        "[1018sub1]\nParameterName=Vendor Id\nObjectType=0x7\nDataType=0x0007\nAccessType=UNKNOWN",
    );
    warning_at(&text, "AccessType=UNKNOWN", Action::Dropped);
    let eds = load_odd(&text);
    assert!(eds.dictionary.sub(0x1018, 0).is_some());
    assert!(eds.dictionary.sub(0x1018, 1).is_none());
}

#[test]
fn a_comment_after_a_number_or_token_is_cut_and_said() {
    // A CiA profile file shipped by a master library.
    let text = with_2000(
        "ObjectType=0x07 # VAR\nDataType=0x0007 # UNSIGNED32\nAccessType=ro # read only\n\
         DefaultValue=0x10 # sixteen\nLowLimit=1 # at least\nPDOMapping=1 # mappable\n",
    )
    .replace(
        "SupportedObjects=1\n1=0x2000",
        "SupportedObjects=1 # one\n1=0x2000 # extra",
    );
    for (at, key, comment) in [
        ("ObjectType=0x07", "ObjectType", "# VAR"),
        ("DataType=0x0007 #", "DataType", "# UNSIGNED32"),
        ("AccessType=ro #", "AccessType", "# read only"),
        ("DefaultValue=0x10", "DefaultValue", "# sixteen"),
        ("LowLimit=1", "LowLimit", "# at least"),
        ("PDOMapping=1", "PDOMapping", "# mappable"),
    ] {
        let warning = warning_at(&text, at, Action::Corrected);
        assert_eq!(warning.key, format!("[2000] {key}"));
        assert!(
            warning
                .message
                .ends_with(&format!("'{comment}' after the value is read as a comment")),
            "{warning}"
        );
    }
    warning_at(&text, "SupportedObjects=1 #", Action::Corrected);
    warning_at(&text, "1=0x2000 #", Action::Corrected);
    let eds = load_odd(&text);
    let reference = load_odd(&with_2000(
        "ObjectType=0x07\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x10\nLowLimit=1\n\
         PDOMapping=1\n",
    ));
    assert_eq!(eds.dictionary, reference.dictionary);
    // The identity of [DeviceInfo] too.
    let text = MINI.replace("VendorNumber=0x4A2", "VendorNumber=0x4A2 # the maker");
    warning_at(&text, "VendorNumber", Action::Corrected);
    assert_eq!(load_odd(&text).device_info.vendor_number, Some(0x4A2));
}

#[test]
fn a_hash_in_a_name_or_a_string_is_kept() {
    // As a Systec file's "Consumer Heartbeat Time #1": names and strings
    // read as written, so their `#` is no comment.
    let text =
        with_2000("ObjectType=0x7\nDataType=0x0009\nAccessType=ro\nDefaultValue=Vendor #1\n")
            .replace("ParameterName=Extra", "ParameterName=Extra #1");
    let eds = load_odd(&text);
    let entry = eds.dictionary.sub(0x2000, 0).unwrap();
    assert_eq!(entry.name, "Extra #1");
    assert_eq!(entry.default.as_deref(), Some("Vendor #1"));
    assert!(
        !eds.warnings.iter().any(|w| w.key.starts_with("[2000]")),
        "{:#?}",
        eds.warnings
    );
    // A `#` with no white space before it is no comment: the value is
    // dropped as before.
    let text = with_2000("ObjectType=0x7\nDataType=0x0007\nAccessType=ro\nDefaultValue=5#x\n");
    warning_at(&text, "DefaultValue=5#x", Action::Dropped);
    // Nor is the text before a `#` that does not read: the value is not
    // cut to something else that does not read either.
    let text = with_2000("ObjectType=0x7\nDataType=0x0007\nAccessType=ro\nDefaultValue=x # 5\n");
    let warning = warning_at(&text, "DefaultValue=x # 5", Action::Dropped);
    assert!(warning.message.contains("x # 5"), "{warning}");
}

#[test]
fn comment_lines_that_start_with_a_hash_are_read_as_comments() {
    let text = MINI
        .replace("[1000]\n", "# Category: Mandatory\n[1000]\n")
        .replace("[1018]\n", "# Category: Mandatory\n[1018]\n")
        .replace(
            "DefaultValue=0x191\n",
            "DefaultValue=0x191\n#DefaultValue=0x192\n",
        );
    let warning = warning_at(&text, "# Category", Action::Kept);
    assert_eq!(
        warning.message,
        "a line that starts with '#' is read as a comment (CiA 306 comments start with ';'), \
         and so are the 2 more below"
    );
    let eds = load_odd(&text);
    let reference = Eds::parse(MINI, "mini.eds").unwrap();
    assert_eq!(eds, reference);
    // One warning for the file.
    assert_eq!(eds.warnings.len(), reference.warnings.len() + 1);
}

#[test]
fn spelled_out_object_types_are_read_as_their_numbers() {
    for (name, object_type) in [
        ("VAR", ObjectType::Var),
        ("var", ObjectType::Var),
        ("DOMAIN", ObjectType::Domain),
    ] {
        let text = with_2000(&format!(
            "ObjectType={name}\nDataType=0x0007\nAccessType=ro\n"
        ));
        let warning = warning_at(&text, &format!("ObjectType={name}"), Action::Corrected);
        assert_eq!(
            warning.message,
            format!(
                "ObjectType={name} is a name where CiA 306 writes a number; read as 0x{:X}",
                object_type.raw()
            )
        );
        let eds = load_odd(&text);
        assert_eq!(eds.dictionary.get(0x2000).unwrap().object_type, object_type);
    }
    for (name, object_type) in [
        ("ARRAY", ObjectType::Array),
        ("RECORD", ObjectType::Record),
        ("DEFSTRUCT", ObjectType::DefStruct),
    ] {
        let text = MINI.replace("ObjectType=0x9", &format!("ObjectType={name}"));
        warning_at(&text, &format!("ObjectType={name}"), Action::Corrected);
        let eds = load_odd(&text);
        let object = eds.dictionary.get(0x1018).unwrap();
        assert_eq!((object.object_type, object.subs.len()), (object_type, 2));
    }
    let text = MINI.replace(
        "ObjectType=0x7\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x191",
        "ObjectType=DEFTYPE\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x191",
    );
    warning_at(&text, "ObjectType=DEFTYPE", Action::Corrected);
    assert_eq!(
        load_odd(&text).dictionary.get(0x1000).unwrap().object_type,
        ObjectType::DefType
    );
    // A name that is no object type is dropped as before, and a comment
    // after a name is cut.
    let text = MINI.replace("ObjectType=0x9", "ObjectType=STRUCT");
    warning_at(&text, "ObjectType=STRUCT", Action::Dropped);
    let text = MINI.replace("ObjectType=0x9", "ObjectType=RECORD # identity");
    let eds = Eds::parse(&text, "odd.eds").unwrap();
    let here = eds
        .warnings
        .iter()
        .filter(|w| w.line == line_of(&text, "RECORD"))
        .count();
    assert_eq!(here, 2, "{:#?}", eds.warnings);
    assert_eq!(
        eds.dictionary.get(0x1018).unwrap().object_type,
        ObjectType::Record
    );
}

#[test]
fn empty_obj_flags_are_one_warning_for_the_file() {
    // 106 lines in 29 files of the second set of real files.
    let text = MINI
        .replace("DefaultValue=0x191\n", "DefaultValue=0x191\nObjFlags=\n")
        .replace("SubNumber=2\n", "SubNumber=2\nObjFlags=\n")
        .replace("DefaultValue=1\n", "DefaultValue=1\nObjFlags=\n");
    // At the first, [1000]'s.
    let warning = warning_at(&text, "ObjFlags=", Action::Kept);
    assert_eq!(warning.key, "[1000] ObjFlags");
    assert_eq!(
        warning.message,
        "ObjFlags= is empty here and in 2 more sections; each is read as no flags"
    );
    let eds = load_odd(&text);
    let reference = Eds::parse(MINI, "mini.eds").unwrap();
    assert_eq!(eds.warnings.len(), reference.warnings.len() + 1);
    assert_eq!(eds, reference);
    // One alone.
    let text = MINI.replace("SubNumber=2\n", "SubNumber=2\nObjFlags=\n");
    let warning = warning_at(&text, "ObjFlags=", Action::Kept);
    assert_eq!(warning.message, "ObjFlags= is empty; read as no flags");
    // A value that is no number is still dropped, with a warning of its own.
    let text = MINI.replace("SubNumber=2\n", "SubNumber=2\nObjFlags=x\n");
    warning_at(&text, "ObjFlags=x", Action::Dropped);
}

#[test]
fn a_file_that_yields_no_object_is_not_usable() {
    // Its lists name objects no section defines.
    let text = MINI.split("[1000]").next().unwrap().to_string();
    let eds = Eds::parse(&text, "lists.eds").unwrap();
    assert!(eds.dictionary.is_empty());
    let error = eds.why_unusable("lists.eds").unwrap();
    assert_eq!(error.line, line_of(&text, "1=0x1000"));
    assert_eq!(
        error.to_string(),
        format!(
            "lists.eds:{}: no object could be read: object 0x1000 is listed but there is no \
             [1000] section; dropped from the list",
            error.line
        )
    );
    // Every object dropped: the first reason is the first object's.
    let text = MINI
        .replace(
            "ObjectType=0x7\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x191",
            "ObjectType=0x7\nDataType=bad\nAccessType=ro\nDefaultValue=0x191",
        )
        .replace("ObjectType=0x9", "ObjectType=0x3");
    let eds = Eds::parse(&text, "dropped.eds").unwrap();
    let error = eds.why_unusable("dropped.eds").unwrap();
    assert_eq!(error.line, line_of(&text, "DataType=bad"));
    assert!(
        error
            .message
            .starts_with("no object could be read: DataType: "),
        "{error}"
    );
    // No object section at all.
    let eds = Eds::parse(
        "[DeviceInfo]\nVendorNumber=1\n[FileInfo]\nFileName=x\n",
        "bare.eds",
    )
    .unwrap();
    let error = eds.why_unusable("bare.eds").unwrap();
    assert_eq!(
        error.to_string(),
        "bare.eds: no object could be read: the file has no object section ([1000], [1018], ...)"
    );
    // A file with objects is usable, warnings or not.
    assert!(
        Eds::parse(MINI, "mini.eds")
            .unwrap()
            .why_unusable("mini.eds")
            .is_none()
    );
}

#[test]
fn a_domain_default_that_is_no_hex_bytes_is_dropped() {
    // CANopenNode's editor writes DefaultValue=0 for every DOMAIN.
    for default in ["0", "not hex", "0x123"] {
        let text = with_2000(&format!(
            "ObjectType=0x7\nDataType=0x000F\nAccessType=rw\nDefaultValue={default}\n"
        ));
        let warning = warning_at(&text, &format!("DefaultValue={default}\n"), Action::Dropped);
        assert!(
            warning.message.contains("a DOMAIN value is hex bytes"),
            "{warning}"
        );
        let eds = load_odd(&text);
        let entry = eds.dictionary.sub(0x2000, 0).unwrap();
        assert_eq!(
            (entry.data_type, entry.default.as_deref()),
            (DataType::Domain, None)
        );
    }
    // Hex bytes are a DOMAIN default.
    let text = with_2000("ObjectType=0x7\nDataType=0x000F\nAccessType=rw\nDefaultValue=0A0B\n");
    let eds = load_odd(&text);
    assert_eq!(
        eds.dictionary.sub(0x2000, 0).unwrap().default.as_deref(),
        Some("0A0B")
    );
    assert_eq!(
        eds.warnings
            .iter()
            .filter(|w| w.key.starts_with("[2000]"))
            .count(),
        0
    );
}

#[test]
fn a_type_that_is_no_basic_type_is_read_as_domain() {
    // Manufacturers' and structure types (0x0020 PDO parameter, 0x0040 and
    // up), and 0x0000, seen in vendor files.
    for raw in ["0x0020", "0x0040", "0x0000", "0x0099"] {
        let text = with_2000(&format!(
            "ObjectType=0x7\nDataType={raw}\nAccessType=ro\nDefaultValue=0102\n"
        ));
        let warning = warning_at(&text, &format!("DataType={raw}"), Action::Corrected);
        assert!(warning.message.contains("read as DOMAIN"), "{warning}");
        let eds = load_odd(&text);
        let entry = eds.dictionary.sub(0x2000, 0).unwrap();
        assert_eq!(entry.data_type, DataType::Domain);
        assert_eq!(entry.access, AccessType::Ro);
        assert_eq!(entry.default.as_deref(), Some("0102"));
    }
    // A DataType that is no number at all: the entry cannot be used.
    let text = with_2000("ObjectType=0x7\nDataType=0xQ7\nAccessType=ro\n");
    warning_at(&text, "0xQ7", Action::Dropped);
    assert!(load_odd(&text).dictionary.get(0x2000).is_none());
}

#[test]
fn an_object_listed_without_a_section_is_dropped_from_the_list() {
    let text = with_2000("ObjectType=0x7\nDataType=0x0005\nAccessType=rw\n").replace(
        "SupportedObjects=1\n1=0x2000",
        "SupportedObjects=2\n1=0x2000\n2=0x2001",
    );
    let warning = warning_at(&text, "2=0x2001", Action::Dropped);
    assert_eq!(warning.key, "[OptionalObjects] 2");
    assert_eq!(
        warning.message,
        "object 0x2001 is listed but there is no [2001] section; dropped from the list"
    );
    let eds = load_odd(&text);
    assert!(eds.dictionary.get(0x2000).is_some());
    assert!(eds.dictionary.get(0x2001).is_none());
    // The rest of the file is as without the defect.
    let clean = Eds::parse(
        &with_2000("ObjectType=0x7\nDataType=0x0005\nAccessType=rw\n"),
        "x",
    )
    .unwrap();
    assert_eq!(eds.dictionary, clean.dictionary);
}

#[test]
fn an_array_with_neither_sub_sections_nor_compact_storage_is_kept_empty() {
    let text = with_2000("ObjectType=0x8\nSubNumber=3\n");
    let warning = warning_at(&text, "[2000]", Action::Kept);
    assert_eq!(
        warning.message,
        "array 0x2000 has neither [2000subN] sections nor CompactSubObj; kept with no sub-objects"
    );
    let eds = load_odd(&text);
    let object = eds.dictionary.get(0x2000).unwrap();
    assert_eq!(
        (object.object_type, object.subs.len()),
        (ObjectType::Array, 0)
    );
    assert_eq!(object.name, "Extra");
}

#[test]
fn c_literal_suffixes_are_dropped() {
    for (data_type, written, read) in [
        ("0x001B", "0x1234567890ABCDEFLL", "0x1234567890ABCDEF"),
        ("0x0007", "100U", "100"),
        ("0x0007", "0xFFUL", "0xFF"),
        ("0x0004", "-5L", "-5"),
        // A C float literal (Faulhaber's files).
        ("0x0008", "1.5f", "1.5"),
    ] {
        let text = with_2000(&format!(
            "ObjectType=0x7\nDataType={data_type}\nAccessType=rw\nDefaultValue={written}\n"
        ));
        let warning = warning_at(&text, written, Action::Corrected);
        assert!(
            warning.message.contains(&format!("read as {read}")),
            "{warning}"
        );
        let eds = load_odd(&text);
        assert_eq!(
            eds.dictionary.sub(0x2000, 0).unwrap().default.as_deref(),
            Some(read)
        );
    }
    let eds = load_odd(&with_2000(
        "ObjectType=0x7\nDataType=0x001B\nAccessType=rw\nDefaultValue=0x1234567890ABCDEFLL\n",
    ));
    assert_eq!(
        eds.dictionary.sub(0x2000, 0).unwrap().default_value(None),
        Ok(Some(Value::Unsigned64(0x1234_5678_90AB_CDEF)))
    );
}

#[test]
fn a_negative_default_of_an_unsigned_type_is_its_twos_complement() {
    let text = with_2000("ObjectType=0x7\nDataType=0x0007\nAccessType=rw\nDefaultValue=-1\n");
    let warning = warning_at(&text, "DefaultValue=-1", Action::Corrected);
    assert_eq!(
        warning.message,
        "DefaultValue=-1 is read as 0xFFFFFFFF (UNSIGNED32)"
    );
    let eds = load_odd(&text);
    assert_eq!(
        eds.dictionary.sub(0x2000, 0).unwrap().default_value(None),
        Ok(Some(Value::Unsigned32(u32::MAX)))
    );
    // Beyond what the type's bits hold, it is no value of it: dropped.
    let text = with_2000("ObjectType=0x7\nDataType=0x0005\nAccessType=rw\nDefaultValue=-300\n");
    warning_at(&text, "DefaultValue=-300", Action::Dropped);
    assert_eq!(
        load_odd(&text).dictionary.sub(0x2000, 0).unwrap().default,
        None
    );
}

#[test]
fn code_page_bytes_are_read_as_windows_1252_else_latin_1() {
    // Faulhaber's files: "Schönaich" in CP1252/Latin-1, and a "’" (0x92),
    // which Latin-1 would make a control character.
    let mut bytes = MINI
        .replace("FileName=mini.eds", "Description=Sch_naich X")
        .into_bytes();
    let at = bytes.iter().position(|&b| b == b'_').unwrap();
    bytes[at] = 0xF6;
    let at = bytes.iter().position(|&b| b == b'X').unwrap();
    bytes[at] = 0x92;
    let eds = Eds::parse_bytes(&bytes, "cp1252.eds").unwrap();
    assert_eq!(
        eds.file_info.description.as_deref(),
        Some("Sch\u{F6}naich \u{2019}")
    );
    let warning = eds
        .warnings
        .iter()
        .find(|w| w.message.contains("not UTF-8"))
        .unwrap();
    assert_eq!(warning.line, 2);
    assert_eq!(
        warning.message,
        "not UTF-8: the file is read as Windows-1252"
    );
    assert_eq!(
        eds.dictionary,
        Eds::parse(MINI, "mini.eds").unwrap().dictionary
    );
    // 0x81 is no character of Windows-1252: the file is Latin-1 then.
    bytes[at] = 0x81;
    let eds = Eds::parse_bytes(&bytes, "latin1.eds").unwrap();
    assert_eq!(
        eds.file_info.description.as_deref(),
        Some("Sch\u{F6}naich \u{81}")
    );
    assert!(
        eds.warnings
            .iter()
            .any(|w| w.message.ends_with("read as Latin-1"))
    );
}

#[test]
fn a_file_without_mandatory_objects_loads() {
    let text = MINI.replace(
        "[MandatoryObjects]\nSupportedObjects=2\n1=0x1000\n2=0x1018\n",
        "",
    );
    let eds = load_odd(&text);
    let warning = eds
        .warnings
        .iter()
        .find(|w| w.key == "[MandatoryObjects]")
        .unwrap();
    assert_eq!(warning.line, text.lines().count());
    assert_eq!(warning.action, Action::Kept);
    assert_eq!(
        eds.dictionary,
        Eds::parse(MINI, "mini.eds").unwrap().dictionary
    );
    // Each object now is in no list, and says so.
    assert!(
        eds.warnings
            .iter()
            .any(|w| w.message == "object 0x1018 is in no object list; read anyway")
    );
}

#[test]
fn identity_numbers_come_from_0x1018_when_device_info_lacks_them() {
    // Technosoft iPOS, SCHUNK, Pilz: no VendorNumber/ProductNumber.
    let text = MINI.replace("VendorNumber=0x4A2\n", "");
    let eds = load_odd(&text);
    assert_eq!(eds.device_info.vendor_number, Some(0x4A2));
    let warning = eds
        .warnings
        .iter()
        .find(|w| w.key == "[DeviceInfo] VendorNumber")
        .unwrap();
    assert_eq!(warning.line, line_of(&text, "[DeviceInfo]"));
    assert_eq!(warning.action, Action::Defaulted);
    assert_eq!(
        warning.message,
        "no VendorNumber in [DeviceInfo]; the default of 0x1018 sub 1 (0x000004A2) is used"
    );
    // Neither: the file is said to match no device (product, in MINI).
    let eds = Eds::parse(MINI, "mini.eds").unwrap();
    assert_eq!(eds.device_info.product_number, None);
    let warning = eds
        .warnings
        .iter()
        .find(|w| w.key == "[DeviceInfo] ProductNumber")
        .unwrap();
    assert_eq!(warning.action, Action::Kept);
    assert!(warning.message.contains("matches no device by identity"));
}

#[test]
fn a_revision_that_is_no_number_is_kept_as_text_or_taken_from_0x1018() {
    // MINI: RevisionNumber=1.0.2 and no 0x1018 sub 3: kept as text.
    let eds = Eds::parse(MINI, "mini.eds").unwrap();
    assert_eq!(eds.device_info.revision_number, None);
    // With a 0x1018 sub 3 default, that is the revision; the text goes.
    let text = MINI
        .replace("SubNumber=2", "SubNumber=3")
        .replace("DefaultValue=1\n", "DefaultValue=3\n")
        + "[1018sub3]\nParameterName=Revision\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x00010002\n";
    let eds = load_odd(&text);
    assert_eq!(eds.device_info.revision_number, Some(0x0001_0002));
    assert!(eds.device_info.other.is_empty());
    let warning = warning_at(&text, "RevisionNumber=1.0.2", Action::Defaulted);
    assert_eq!(
        warning.message,
        "RevisionNumber=1.0.2 is not a number; the default of 0x1018 sub 3 (0x00010002) is used"
    );
}

#[test]
fn a_sub_number_that_does_not_count_the_sections_is_a_warning() {
    let text = MINI.replace("SubNumber=2", "SubNumber=5");
    let warning = warning_at(&text, "SubNumber=5", Action::Kept);
    assert_eq!(
        warning.message,
        "SubNumber=5 but there are 2 sub-object sections"
    );
    assert_eq!(
        load_odd(&text).dictionary.get(0x1018).unwrap().subs.len(),
        2
    );
}

#[test]
fn inverted_limits_are_dropped() {
    let text = with_2000(
        "ObjectType=0x7\nDataType=0x0005\nAccessType=rw\nDefaultValue=5\nLowLimit=20\nHighLimit=10\n",
    );
    let warning = warning_at(&text, "LowLimit=20", Action::Dropped);
    assert_eq!(
        warning.message,
        "[2000]: LowLimit 20 is above HighLimit 10; both dropped"
    );
    let eds = load_odd(&text);
    let entry = eds.dictionary.sub(0x2000, 0).unwrap();
    assert_eq!((entry.low.as_deref(), entry.high.as_deref()), (None, None));
    assert_eq!(entry.check(&Value::Unsigned8(200), None), Ok(()));
    // A default outside sound limits is kept, with a warning.
    let text = text.replace("LowLimit=20\nHighLimit=10", "LowLimit=10\nHighLimit=20");
    let warning = warning_at(&text, "DefaultValue=5", Action::Kept);
    assert!(
        warning.message.contains("below the low limit 10"),
        "{warning}"
    );
}

#[test]
fn every_problem_of_a_file_is_reported_together() {
    // As UniSwarm's uio44.eds: six problems, each with its own line.
    let text = with_2000(
        "ObjectType=0x7\nDataType=0x0007\nAccessType=\nDefaultValue=-1\nLowLimit=9\nHighLimit=1\n",
    )
    .replace(
        "SupportedObjects=1\n1=0x2000",
        "SupportedObjects=2\n1=0x2000\n2=0x2001",
    )
    .replace("SubNumber=2", "SubNumber=4")
        + "[2002]\nParameterName=Blob\nDataType=0x000F\nAccessType=rw\nDefaultValue=0\n";
    let eds = load_odd(&text);
    let lines: Vec<_> = eds.warnings.iter().map(|w| (w.line, w.action)).collect();
    let expected = [
        (line_of(&text, "SubNumber=4"), Action::Kept),
        // MINI names no product, and its revision is a version.
        (line_of(&text, "[DeviceInfo]"), Action::Kept),
        (line_of(&text, "RevisionNumber=1.0.2"), Action::Kept),
        (line_of(&text, "2=0x2001"), Action::Dropped),
        (line_of(&text, "AccessType=\n"), Action::Defaulted),
        (line_of(&text, "DefaultValue=-1"), Action::Corrected),
        (line_of(&text, "LowLimit=9"), Action::Dropped),
        (line_of(&text, "[2002]"), Action::Kept),
        (text.lines().count(), Action::Dropped),
    ];
    let mut expected = expected.to_vec();
    expected.sort_by_key(|&(line, _)| line);
    assert_eq!(lines, expected, "{:#?}", eds.warnings);
}

/// Every deviation, one edit of MINI each, loads with a warning at the
/// line of the defect, and the rest of the file as it was.
#[test]
fn each_deviation_is_a_warning_at_its_line() {
    let cases: [(String, &str, Action); 14] = [
        (
            MINI.replace("DefaultValue=0x4A2", "DefaultValue=0x4G2"),
            "0x4G2",
            Action::Dropped,
        ),
        (
            MINI.replace("DefaultValue=1\n", "DefaultValue=256\n"),
            "DefaultValue=256",
            Action::Dropped,
        ),
        (
            MINI.replace("[1018sub1]", "[1018sub100]"),
            "[1018sub100]",
            Action::Dropped,
        ),
        (
            MINI.replace("[1000]", "[10000]"),
            "[10000]",
            Action::Dropped,
        ),
        (
            MINI.replace(
                "AccessType=ro\nDefaultValue=0x191",
                "AccessType=ro\naccesstype=rw",
            ),
            "accesstype=rw",
            Action::Dropped,
        ),
        (
            format!("{MINI}[1000]\nParameterName=Again\n"),
            "ParameterName=Again",
            Action::Dropped,
        ),
        (
            format!("{MINI}[01000]\nParameterName=Again\n"),
            "[01000]",
            Action::Dropped,
        ),
        (
            MINI.replace("SupportedObjects=2", "SupportedObjects=3"),
            "SupportedObjects",
            Action::Kept,
        ),
        (
            MINI.replace("ParameterName=Vendor Id\n", ""),
            "[1018sub1]",
            Action::Defaulted,
        ),
        (
            MINI.replace("DataType=0x0005\n", ""),
            "[1018sub0]",
            Action::Dropped,
        ),
        (
            MINI.replace("ObjectType=0x9", "ObjectType=0x3"),
            "ObjectType=0x3",
            Action::Dropped,
        ),
        (format!("NoSection=1\n{MINI}"), "NoSection", Action::Dropped),
        (
            MINI.replace("[DeviceInfo]", "[DeviceInfo"),
            "[DeviceInfo",
            Action::Kept,
        ),
        (
            MINI.replace("FileVersion=1.0.2", "just some words"),
            "just some words",
            Action::Dropped,
        ),
    ];
    let reference = Eds::parse(MINI, "mini.eds").unwrap();
    for (text, at, action) in &cases {
        // A repeated section's warning sits on its header.
        let at = if *at == "ParameterName=Again" {
            "[1000]\nParameterName=Again"
        } else {
            at
        };
        let line = match at.split_once('\n') {
            Some((_, _)) => text.lines().count() - 1,
            None => line_of(text, at),
        };
        let eds = load_odd(text);
        // MINI names no product: that warning is always there.
        let here: Vec<_> = eds
            .warnings
            .iter()
            .filter(|w| w.line == line && w.key != "[DeviceInfo] ProductNumber")
            .collect();
        assert_eq!(here.len(), 1, "{at}: {:#?}", eds.warnings);
        assert_eq!(here[0].action, *action, "{}", here[0]);
        // Everything the defect does not touch is read as before.
        for object in reference.dictionary.iter() {
            let Some(read) = eds.dictionary.get(object.index) else {
                continue;
            };
            for sub in object.subs.values() {
                if let Some(same) = read.sub(sub.sub_index)
                    && same.name == sub.name
                {
                    assert_eq!(
                        (same.data_type, same.access),
                        (sub.data_type, sub.access),
                        "{at}"
                    );
                }
            }
        }
    }
    // A sub-object section whose index is no number is no object section.
    let eds = load_odd(&MINI.replace("[1018sub1]", "[1018subx]"));
    assert!(eds.dictionary.sub(0x1018, 1).is_none());
}

#[test]
fn empty_garbage_and_huge_inputs_give_errors_not_panics() {
    for empty in ["", "\n\n", "; only a comment\n", "\u{FEFF}"] {
        let error = Eds::parse(empty, "empty.eds").unwrap_err();
        assert_eq!(error.line, 1.max(empty.lines().count()), "{empty:?}");
        assert!(error.to_string().starts_with("empty.eds:"));
    }
    let garbage: Vec<u8> = (0..=255u8).cycle().take(4096).collect();
    let error = Eds::parse_bytes(&garbage, "garbage.bin").unwrap_err();
    assert_eq!((error.file.as_str(), error.line), ("garbage.bin", 1));
    let error = Eds::parse_bytes(b"[FileInfo]\nFileName=x\xFF\x00\x01\n", "nul.eds").unwrap_err();
    assert_eq!(error.line, 2);

    // Text with no CiA 306 section is no EDS.
    let error = Eds::parse("[Settings]\nColour=blue\n", "other.ini").unwrap_err();
    assert_eq!(error.line, 2);
    assert!(error.message.contains("not an EDS"), "{error}");

    // A 10 MB line, in a value and as a line of its own: dropped quickly, and
    // the warning quotes only the start of it.
    let huge = "9".repeat(10 << 20);
    let in_value = MINI.replace("DefaultValue=0x191", &format!("DefaultValue={huge}"));
    let warning = warning_at(&in_value, &huge[..100], Action::Dropped);
    assert!(
        warning.to_string().len() < 200,
        "{} bytes",
        warning.to_string().len()
    );
    let as_line = MINI.replace("FileVersion=1.0.2", &huge);
    let warning = warning_at(&as_line, &huge[..100], Action::Dropped);
    assert!(warning.to_string().len() < 200);

    let missing = read_eds_file("/nonexistent/dir/x.eds").unwrap_err();
    assert_eq!(missing.line, 0);
    assert!(
        missing.to_string().starts_with("/nonexistent/dir/x.eds: "),
        "{missing}"
    );
}

#[test]
fn a_written_eds_of_a_built_dictionary_reads_back() {
    use crate::od::{Object, ObjectDictionary, SubObject};
    let mut dictionary = ObjectDictionary::new();
    let mut device_type = SubObject::new(0, "Device type", DataType::Unsigned32, AccessType::Ro);
    device_type.default = Some("0x00020192".into());
    dictionary.insert(Object::var(0x1000, device_type));
    let mut record = Object::new(0x2001, "Every type", ObjectType::Record);
    let mut count = SubObject::new(
        0,
        "Highest sub-index",
        DataType::Unsigned8,
        AccessType::Const,
    );
    count.default = Some(DataType::ALL.len().to_string());
    record.insert_sub(count);
    for (n, data_type) in DataType::ALL.into_iter().enumerate() {
        let mut sub = SubObject::new(
            n as u8 + 1,
            data_type.to_string(),
            data_type,
            AccessType::Rw,
        );
        // An empty DefaultValue= means none, so the zero of a string type is
        // no default.
        sub.default = Value::zero(data_type)
            .map(|zero| zero.to_text())
            .filter(|text| !text.is_empty());
        sub.obj_flags = Some(3);
        record.insert_sub(sub);
    }
    dictionary.insert(record);
    dictionary.insert(Object::new(0x2002, "Nothing", ObjectType::Null));
    let mut eds = Eds::new(dictionary);
    eds.dummy_usage.insert(5);
    eds.device_info.baud_rates.insert(83);
    eds.comments = vec!["first".into(), String::new(), "third".into()];
    let (again, warnings) = Eds::parse_with_warnings(&eds.write(), "built.eds").unwrap();
    assert_eq!(again, eds);
    // It names no vendor or product (nor does its 0x1018): said, nothing else.
    let keys: Vec<_> = warnings.iter().map(|w| w.key.as_str()).collect();
    assert_eq!(
        keys,
        ["[DeviceInfo] VendorNumber", "[DeviceInfo] ProductNumber"],
        "{warnings:?}"
    );
}

/// A mutation of a vendor file: bytes changed, lines dropped or repeated,
/// values swapped for ones that trouble parsers.
#[derive(Debug, Clone)]
enum Edit {
    Byte { at: usize, byte: u8 },
    DeleteLine(usize),
    RepeatLine(usize),
    Value { line: usize, value: &'static str },
}

const NASTY_VALUES: [&str; 16] = [
    "",
    "0x",
    "0xFFFFFFFFFFFFFFFFFFFF",
    "-1",
    "4294967296",
    "$NODEID",
    "$NODEID+$NODEID",
    "\"",
    "0x9999",
    "255",
    "1000000",
    "rww",
    ";",
    "[",
    "0x0020",
    "1e400",
];

fn apply(text: &str, edits: &[Edit]) -> Vec<u8> {
    let mut lines: Vec<String> = text.split('\n').map(str::to_string).collect();
    let mut bytes_edits = Vec::new();
    for edit in edits {
        let n = lines.len();
        match *edit {
            Edit::DeleteLine(at) => {
                lines.remove(at % n);
            }
            Edit::RepeatLine(at) => {
                let line = lines[at % n].clone();
                lines.insert(at % n, line);
            }
            Edit::Value { line, value } => {
                let line = &mut lines[line % n];
                if let Some((key, _)) = line.split_once('=') {
                    *line = format!("{key}={value}\r");
                }
            }
            Edit::Byte { at, byte } => bytes_edits.push((at, byte)),
        }
    }
    let mut bytes = lines.join("\n").into_bytes();
    for (at, byte) in bytes_edits {
        let n = bytes.len().max(1);
        if let Some(slot) = bytes.get_mut(at % n) {
            *slot = byte;
        }
    }
    bytes
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(at, byte)| Edit::Byte { at, byte }),
        any::<usize>().prop_map(Edit::DeleteLine),
        any::<usize>().prop_map(Edit::RepeatLine),
        (any::<usize>(), prop::sample::select(NASTY_VALUES.to_vec()))
            .prop_map(|(line, value)| Edit::Value { line, value }),
    ]
}

/// Whatever reads must write out and read back the same.
fn check_round_trip(eds: &Eds) {
    let written = eds.write();
    let again = Eds::parse(&written, "again.eds").unwrap_or_else(|error| panic!("{error}\n"));
    assert_eq!(&again, eds);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: crate::can::test_support::fuzz_cases(128), ..ProptestConfig::default() })]

    #[test]
    fn the_parser_never_panics_on_arbitrary_text(text in "(?s).{0,600}") {
        if let Ok(eds) = Eds::parse(&text, "arbitrary.eds") {
            check_round_trip(&eds);
        }
    }

    #[test]
    fn the_parser_never_panics_on_ini_shaped_text(
        lines in prop::collection::vec(
            prop_oneof![
                prop::sample::select(vec![
                    "[MandatoryObjects]", "SupportedObjects=1", "1=0x1000", "[1000]", "[1000sub0]",
                    "[1000sub1]", "[1000Name]", "[1000Value]", "[DeviceInfo]", "[DeviceComissioning]",
                    "[Comments]", "Lines=2", "Line1=x", "ParameterName=P", "ObjectType=0x8",
                    "ObjectType=0x7", "ObjectType=0x2", "ObjectType=0x0", "DataType=0x0007",
                    "DataType=0x0009", "DataType=0x000F", "AccessType=rw", "CompactSubObj=3",
                    "SubNumber=2", "DefaultValue=$NODEID+0x180", "LowLimit=5", "HighLimit=1",
                    "ParameterValue=0x10", "NrOfEntries=1", "2=Second", "NodeID=5", "BaudRate_10=2",
                    "[DummyUsage]", "Dummy0001=1", "DummyX=1", "Granularity=abc",
                ]).prop_map(str::to_string),
                "[A-Za-z0-9_=\\[\\]$+ ;\"-]{0,20}",
            ],
            0..40,
        )
    ) {
        let text = lines.join("\n");
        if let Ok(eds) = Eds::parse(&text, "shaped.eds") {
            check_round_trip(&eds);
        }
    }

    #[test]
    fn the_parser_never_panics_on_mutated_real_files(
        file in 0..OWN_FILES.len() + 1,
        edits in prop::collection::vec(edit(), 1..6),
    ) {
        let path = OWN_FILES.get(file).copied().unwrap_or(READER);
        let text = std::fs::read_to_string(path).unwrap();
        let bytes = apply(&text, &edits);
        if let Ok(eds) = Eds::parse_bytes(&bytes, "mutated.eds") {
            check_round_trip(&eds);
        }
    }
}
