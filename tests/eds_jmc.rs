//! Our EDS of the JMC CANopen stepper drive (`eds/jmc_stepper.eds`, embedded
//! as `profiles::builtin::JMC_STEPPER`), checked against what its manual
//! (Rev. 2.3) states.
//! There is no vendor EDS to compare with, so the manual's tables are
//! written out here.
//!
//! Where the manual contradicts itself, the tests pin the choice made in the
//! EDS: the object sections over the summary table for the data types (the
//! summary says UNSIGNED32 for the accelerations, the sections, the default
//! PDO mappings and the SDO examples all say 2 bytes).

use candeck::canopen::NodeId;
use candeck::canopen::eds::{Eds, read_eds_file};
use candeck::canopen::od::{AccessType, DataType, ObjectType, SubObject, Value};
use candeck::profiles::builtin::JMC_STEPPER;

fn eds() -> Eds {
    let (eds, warnings) = Eds::parse_with_warnings(JMC_STEPPER, "eds/jmc_stepper.eds")
        .unwrap_or_else(|error| panic!("{error}"));
    assert!(warnings.is_empty(), "warnings: {warnings:#?}");
    eds
}

fn node(id: u8) -> Option<NodeId> {
    Some(NodeId::new(id).unwrap())
}

fn sub(eds: &Eds, index: u16, sub: u8) -> &SubObject {
    eds.dictionary
        .sub(index, sub)
        .unwrap_or_else(|| panic!("0x{index:04X}sub{sub} is missing"))
}

/// The default with `$NODEID` resolved for `id`.
fn default_for(eds: &Eds, index: u16, sub_index: u8, id: u8) -> Value {
    sub(eds, index, sub_index)
        .default_value(node(id))
        .unwrap()
        .unwrap_or_else(|| panic!("0x{index:04X}sub{sub_index} has no default"))
}

fn default(eds: &Eds, index: u16, sub_index: u8) -> Value {
    default_for(eds, index, sub_index, 1)
}

use AccessType::{Const, Ro, Rw, Wo};
use DataType::{
    Integer8 as I8, Integer16 as I16, Integer32 as I32, Unsigned8 as U8, Unsigned16 as U16,
    Unsigned32 as U32, VisibleString as Vs,
};

/// Every object of the manual's object tables ("EDS file" and the sections
/// of "Object dictionary description"), with its object type and its number
/// of sub-objects (sub 0 included). Each PDO mapping has room for 8 entries
/// (a full 64-bit PDO at byte granularity), more than its default uses: the
/// manual's own TPDO routine maps two objects into 0x1A01. Left out on purpose, because the manual
/// marks them "not available" and its EDS table does not list them: 0x1002,
/// 0x1015, 0x1019, 0x1029, 0x603F.
const MANUAL_OBJECTS: &[(u16, ObjectType, usize)] = &[
    (0x1000, ObjectType::Var, 1),
    (0x1001, ObjectType::Var, 1),
    (0x1003, ObjectType::Array, 4),
    (0x1005, ObjectType::Var, 1),
    (0x1006, ObjectType::Var, 1),
    (0x1007, ObjectType::Var, 1),
    (0x1008, ObjectType::Var, 1),
    (0x1009, ObjectType::Var, 1),
    (0x100A, ObjectType::Var, 1),
    (0x1010, ObjectType::Array, 4),
    (0x1011, ObjectType::Array, 4),
    (0x1014, ObjectType::Var, 1),
    (0x1017, ObjectType::Var, 1),
    (0x1018, ObjectType::Record, 5),
    (0x1200, ObjectType::Record, 4),
    (0x1400, ObjectType::Record, 3),
    (0x1401, ObjectType::Record, 3),
    (0x1402, ObjectType::Record, 3),
    (0x1403, ObjectType::Record, 3),
    (0x1600, ObjectType::Record, 9),
    (0x1601, ObjectType::Record, 9),
    (0x1602, ObjectType::Record, 9),
    (0x1603, ObjectType::Record, 9),
    (0x1800, ObjectType::Record, 3),
    (0x1801, ObjectType::Record, 3),
    (0x1802, ObjectType::Record, 3),
    (0x1803, ObjectType::Record, 3),
    (0x1A00, ObjectType::Record, 9),
    (0x1A01, ObjectType::Record, 9),
    // The manual gives no default mapping for TPDO 3 and 4.
    (0x1A02, ObjectType::Record, 9),
    (0x1A03, ObjectType::Record, 9),
    (0x6040, ObjectType::Var, 1),
    (0x6041, ObjectType::Var, 1),
    (0x605A, ObjectType::Var, 1),
    (0x605D, ObjectType::Var, 1),
    (0x6060, ObjectType::Var, 1),
    (0x6061, ObjectType::Var, 1),
    (0x6064, ObjectType::Var, 1),
    (0x606C, ObjectType::Var, 1),
    (0x607A, ObjectType::Var, 1),
    (0x607C, ObjectType::Var, 1),
    (0x6081, ObjectType::Var, 1),
    (0x6083, ObjectType::Var, 1),
    (0x6084, ObjectType::Var, 1),
    (0x6085, ObjectType::Var, 1),
    (0x6098, ObjectType::Var, 1),
    (0x6099, ObjectType::Array, 3),
    (0x609A, ObjectType::Var, 1),
    (0x60C5, ObjectType::Var, 1),
    (0x60C6, ObjectType::Var, 1),
];

#[test]
fn loads_without_warnings_from_the_binary_and_from_disk() {
    let embedded = eds();
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/eds/jmc_stepper.eds");
    let on_disk = read_eds_file(path).unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(embedded, on_disk);
    assert!(!embedded.is_dcf());
}

#[test]
fn writing_and_reading_back_gives_the_same_file() {
    let eds = eds();
    let (again, warnings) = Eds::parse_with_warnings(&eds.write(), "written").unwrap();
    assert!(warnings.is_empty(), "warnings: {warnings:#?}");
    assert_eq!(again, eds);
}

#[test]
fn every_object_of_the_manual_is_present_and_nothing_else() {
    let eds = eds();
    for &(index, object_type, subs) in MANUAL_OBJECTS {
        let object = eds
            .dictionary
            .get(index)
            .unwrap_or_else(|| panic!("0x{index:04X} is missing"));
        assert_eq!(object.object_type, object_type, "0x{index:04X}");
        assert_eq!(
            object.subs.len(),
            subs,
            "0x{index:04X}: number of sub-objects"
        );
        if object_type.has_sub_objects() {
            // Sub 0 of an ARRAY or RECORD counts the others (for the PDO
            // mappings: the entries mapped by default, checked below).
            let sub0 = sub(&eds, index, 0);
            assert_eq!(sub0.data_type, U8, "0x{index:04X}sub0");
            let highest = object.subs.keys().max().copied().unwrap();
            assert_eq!(highest as usize, subs - 1, "0x{index:04X}: gaps");
            if !(0x1600..=0x1A03).contains(&index) && index != 0x1003 {
                assert_eq!(
                    default(&eds, index, 0),
                    Value::Unsigned8(highest),
                    "0x{index:04X}sub0"
                );
            }
        }
    }
    let ours: Vec<u16> = eds.dictionary.iter().map(|object| object.index).collect();
    let manual: Vec<u16> = MANUAL_OBJECTS.iter().map(|&(index, _, _)| index).collect();
    assert_eq!(ours, manual, "objects the manual does not list");
    for not_available in [0x1002, 0x1015, 0x1019, 0x1029, 0x603F] {
        assert!(eds.dictionary.get(not_available).is_none());
    }
    // The manual lists no manufacturer-specific (0x2000–0x5FFF) objects.
    assert!(ours.iter().all(|&index| !(0x2000..0x6000).contains(&index)));
}

#[test]
fn device_info_names_jmc_and_the_bit_rates_of_switch_s2() {
    let eds = eds();
    let info = &eds.device_info;
    assert_eq!(info.vendor_number, Some(0x2D9));
    assert_eq!(default(&eds, 0x1018, 1), Value::Unsigned32(0x2D9));
    // S2: 12.5k (no CiA 306 key), 20k, 50k, 100k, 125k, 250k, 500k, 1M.
    assert_eq!(
        info.baud_rates.iter().copied().collect::<Vec<_>>(),
        [20, 50, 100, 125, 250, 500, 1000]
    );
    assert_eq!(info.nr_of_rx_pdo, Some(4));
    assert_eq!(info.nr_of_tx_pdo, Some(4));
    assert_eq!(info.granularity, Some(8));
    assert_eq!(info.simple_boot_up_slave, Some(true));
    assert_eq!(info.lss_supported, Some(false));
}

/// (index, sub, type, access, PDO mappable, default) as the manual's
/// sections give them.
type Expected = (u16, u8, DataType, AccessType, bool, Value);

fn check_all(eds: &Eds, expected: &[Expected]) {
    for (index, sub_index, data_type, access, mappable, value) in expected {
        let entry = sub(eds, *index, *sub_index);
        let at = format!("0x{index:04X}sub{sub_index} ({})", entry.name);
        assert_eq!(entry.data_type, *data_type, "{at}: type");
        assert_eq!(entry.access, *access, "{at}: access");
        assert_eq!(entry.pdo_mappable, *mappable, "{at}: PDO mapping");
        assert_eq!(
            default_for(eds, *index, *sub_index, 1),
            *value,
            "{at}: default"
        );
    }
}

#[test]
fn communication_objects_match_the_manual() {
    let eds = eds();
    let text = |s: &str| Value::VisibleString(s.into());
    check_all(
        &eds,
        &[
            // Device type as printed in the manual.
            (0x1000, 0, U32, Ro, false, Value::Unsigned32(0x0006_0912)),
            (0x1001, 0, U8, Ro, true, Value::Unsigned8(0)),
            (0x1003, 0, U8, Rw, false, Value::Unsigned8(0)),
            (0x1003, 1, U32, Ro, false, Value::Unsigned32(0)),
            (0x1003, 3, U32, Ro, false, Value::Unsigned32(0)),
            (0x1005, 0, U32, Rw, false, Value::Unsigned32(0x80)),
            (0x1006, 0, U32, Rw, false, Value::Unsigned32(0)),
            (0x1007, 0, U32, Rw, false, Value::Unsigned32(0)),
            (
                0x1008,
                0,
                Vs,
                Const,
                false,
                text("AMA CANopen Motor Driver"),
            ),
            (0x1009, 0, Vs, Const, false, text("A001")),
            (0x100A, 0, Vs, Const, false, text("2.00A")),
            (0x1010, 0, U8, Ro, false, Value::Unsigned8(3)),
            (0x1010, 1, U32, Rw, false, Value::Unsigned32(0)),
            (0x1010, 2, U32, Rw, false, Value::Unsigned32(3)),
            (0x1010, 3, U32, Rw, false, Value::Unsigned32(3)),
            (0x1011, 1, U32, Rw, false, Value::Unsigned32(0xFFFF_FFFF)),
            (0x1011, 3, U32, Rw, false, Value::Unsigned32(0xFFFF_FFFF)),
            (0x1014, 0, U32, Ro, false, Value::Unsigned32(0x81)),
            (0x1017, 0, U16, Rw, false, Value::Unsigned16(1000)),
            (0x1018, 0, U8, Ro, false, Value::Unsigned8(4)),
            (0x1018, 1, U32, Ro, false, Value::Unsigned32(0x2D9)),
            (0x1018, 2, U32, Ro, false, Value::Unsigned32(0)),
            (0x1018, 3, U32, Ro, false, Value::Unsigned32(0)),
            (0x1018, 4, U32, Ro, false, Value::Unsigned32(0)),
        ],
    );
    // Only 0 may be written to 1003sub0 (anything else: abort 0609 0030h).
    let errors = sub(&eds, 0x1003, 0);
    assert!(errors.check(&Value::Unsigned8(0), None).is_ok());
    assert!(errors.check(&Value::Unsigned8(1), None).is_err());
    assert_eq!(default_for(&eds, 0x1014, 0, 0x7F), Value::Unsigned32(0xFF));
}

#[test]
fn sdo_server_parameter_follows_the_node_id() {
    let eds = eds();
    check_all(
        &eds,
        &[
            (0x1200, 0, U8, Ro, false, Value::Unsigned8(3)),
            (0x1200, 1, U32, Ro, false, Value::Unsigned32(0x601)),
            (0x1200, 2, U32, Ro, false, Value::Unsigned32(0x581)),
            (0x1200, 3, U8, Ro, false, Value::Unsigned8(1)),
        ],
    );
    assert_eq!(default_for(&eds, 0x1200, 1, 3), Value::Unsigned32(0x603));
    assert_eq!(default_for(&eds, 0x1200, 2, 3), Value::Unsigned32(0x583));
    assert_eq!(default_for(&eds, 0x1200, 3, 3), Value::Unsigned8(3));
}

#[test]
fn pdo_communication_parameters_have_the_manuals_cob_ids_and_types() {
    let eds = eds();
    // Node 3, as in the manual's programming routines.
    for n in 0..4u16 {
        let rpdo = 0x1400 + n;
        assert_eq!(default(&eds, rpdo, 0), Value::Unsigned8(2));
        assert_eq!(
            default_for(&eds, rpdo, 1, 3),
            Value::Unsigned32(0x203 + 0x100 * u32::from(n)),
            "0x{rpdo:04X}"
        );
        assert_eq!(
            default(&eds, rpdo, 2),
            Value::Unsigned8(254),
            "0x{rpdo:04X}"
        );
        let tpdo = 0x1800 + n;
        assert_eq!(default(&eds, tpdo, 0), Value::Unsigned8(2));
        assert_eq!(
            default_for(&eds, tpdo, 1, 3),
            Value::Unsigned32(0x183 + 0x100 * u32::from(n)),
            "0x{tpdo:04X}"
        );
        assert_eq!(default(&eds, tpdo, 2), Value::Unsigned8(1), "0x{tpdo:04X}");
        for index in [rpdo, tpdo] {
            assert_eq!(sub(&eds, index, 0).access, Ro);
            for sub_index in 1..=2 {
                let entry = sub(&eds, index, sub_index);
                assert_eq!(entry.access, Rw, "0x{index:04X}sub{sub_index}");
                assert!(!entry.pdo_mappable);
            }
            assert_eq!(sub(&eds, index, 1).data_type, U32);
            assert_eq!(sub(&eds, index, 2).data_type, U8);
        }
    }
}

/// The manual's default mappings, entry by entry.
const DEFAULT_MAPPINGS: &[(u16, &[u32])] = &[
    (0x1600, &[0x6081_0020, 0x6083_0010, 0x6084_0010]),
    (0x1601, &[0x607C_0020, 0x6099_0220]),
    // The manual maps homing acceleration twice; kept as printed.
    (0x1602, &[0x6099_0120, 0x609A_0010, 0x609A_0010]),
    (
        0x1603,
        &[0x6060_0008, 0x6098_0008, 0x607A_0020, 0x6040_0010],
    ),
    (0x1A00, &[0x6041_0010, 0x6064_0020]),
    (0x1A01, &[0x606C_0020]),
    (0x1A02, &[]),
    (0x1A03, &[]),
];

#[test]
fn default_pdo_mappings_are_the_manuals_entry_by_entry() {
    let eds = eds();
    for &(index, entries) in DEFAULT_MAPPINGS {
        let count = sub(&eds, index, 0);
        assert_eq!(
            (count.data_type, count.access),
            (U8, Rw),
            "0x{index:04X}sub0"
        );
        assert_eq!(
            default(&eds, index, 0),
            Value::Unsigned8(entries.len() as u8),
            "0x{index:04X}sub0"
        );
        let object = eds.dictionary.get(index).unwrap();
        for (&sub_index, entry) in object.subs.iter().skip(1) {
            assert_eq!(
                (entry.data_type, entry.access),
                (U32, Rw),
                "0x{index:04X}sub{sub_index}"
            );
            let expected = entries
                .get(usize::from(sub_index) - 1)
                .copied()
                .unwrap_or(0);
            assert_eq!(
                default(&eds, index, sub_index),
                Value::Unsigned32(expected),
                "0x{index:04X}sub{sub_index}"
            );
        }
        // Each mapped object exists, is mappable, has the mapped length and
        // a direction that fits the PDO; a PDO holds at most 64 bits.
        let receive = index < 0x1800;
        let mut bits = 0;
        for &entry in entries {
            let (target, target_sub, length) =
                ((entry >> 16) as u16, (entry >> 8) as u8, entry & 0xFF);
            let mapped = sub(&eds, target, target_sub);
            let at = format!("0x{index:04X} maps 0x{entry:08X}");
            assert!(mapped.pdo_mappable, "{at}: not mappable");
            assert_eq!(mapped.data_type.bits(), Some(length), "{at}: length");
            if receive {
                assert!(mapped.access.is_writable(), "{at}: not writable");
            } else {
                assert!(mapped.access.is_readable(), "{at}: not readable");
            }
            bits += length;
        }
        assert!(bits <= 64, "0x{index:04X}: {bits} bits");
    }
}

#[test]
fn cia402_objects_have_the_manuals_types_access_and_mapping() {
    let eds = eds();
    check_all(
        &eds,
        &[
            // Controlword and "modes of operation" are write-only on this drive.
            (0x6040, 0, U16, Wo, true, Value::Unsigned16(0)),
            (0x6041, 0, U16, Ro, true, Value::Unsigned16(0)),
            (0x605A, 0, I16, Rw, false, Value::Integer16(0)),
            (0x605D, 0, I16, Rw, false, Value::Integer16(0)),
            (0x6060, 0, I8, Wo, true, Value::Integer8(0)),
            (0x6061, 0, I8, Ro, true, Value::Integer8(0)),
            (0x6064, 0, I32, Ro, true, Value::Integer32(0)),
            (0x606C, 0, I32, Ro, true, Value::Integer32(0)),
            (0x607A, 0, I32, Rw, true, Value::Integer32(0)),
            (0x607C, 0, I32, Rw, true, Value::Integer32(0)),
            // "Target velocity", signed, in 0.1 rps.
            (0x6081, 0, I32, Rw, true, Value::Integer32(0)),
            (0x6083, 0, U16, Rw, true, Value::Unsigned16(0)),
            (0x6084, 0, U16, Rw, true, Value::Unsigned16(0)),
            (0x6085, 0, U16, Rw, true, Value::Unsigned16(0)),
            (0x6098, 0, I8, Rw, true, Value::Integer8(0)),
            (0x6099, 0, U8, Ro, false, Value::Unsigned8(2)),
            (0x6099, 1, U32, Rw, true, Value::Unsigned32(0)),
            (0x6099, 2, U32, Rw, true, Value::Unsigned32(0)),
            (0x609A, 0, U16, Rw, true, Value::Unsigned16(0)),
            (0x60C5, 0, U32, Rw, true, Value::Unsigned32(0)),
            (0x60C6, 0, U32, Rw, true, Value::Unsigned32(0)),
        ],
    );
    // The drive has no CiA 402 "target velocity" 0x60FF of its own: its
    // velocity mode runs at 0x6081.
    assert!(eds.dictionary.get(0x60FF).is_none());
}

#[test]
fn accelerations_are_two_bytes_and_refuse_four() {
    let eds = eds();
    for index in [0x6083, 0x6084, 0x6085, 0x609A] {
        let entry = sub(&eds, index, 0);
        assert_eq!(entry.data_type.byte_len(), Some(2), "0x{index:04X}");
        // 100 rps/s is written as 1000 (the drive divides by 10).
        assert_eq!(entry.decode(&[0xE8, 0x03]), Ok(Value::Unsigned16(1000)));
        assert!(
            entry.decode(&[0xE8, 0x03, 0x00, 0x00]).is_err(),
            "0x{index:04X}"
        );
        assert!(entry.check(&Value::Unsigned32(1000), None).is_err());
    }
}

/// Expedited SDO downloads of the manual's programming routines (node 3):
/// command byte, index, sub-index. The command byte gives the size.
const MANUAL_DOWNLOADS: &[(u8, u16, u8)] = &[
    (0x23, 0x1402, 1),
    (0x2F, 0x1402, 2),
    (0x2F, 0x1602, 0),
    (0x23, 0x1602, 1),
    (0x23, 0x1602, 2),
    (0x23, 0x1801, 1),
    (0x2F, 0x1801, 2),
    (0x2F, 0x1A01, 0),
    (0x23, 0x1A01, 1),
    (0x23, 0x1A01, 2),
    (0x2B, 0x6040, 0),
    (0x2F, 0x6060, 0),
    (0x23, 0x6081, 0),
    (0x2B, 0x6083, 0),
    (0x2B, 0x6084, 0),
    (0x23, 0x607A, 0),
    (0x2F, 0x6098, 0),
    (0x2B, 0x609A, 0),
    (0x23, 0x6099, 1),
    (0x23, 0x6099, 2),
];

#[test]
fn the_manuals_sdo_examples_write_each_object_at_its_size() {
    let eds = eds();
    for &(command, index, sub_index) in MANUAL_DOWNLOADS {
        let size = 4 - usize::from((command >> 2) & 0x3);
        let entry = sub(&eds, index, sub_index);
        assert_eq!(
            entry.data_type.byte_len(),
            Some(size),
            "0x{index:04X}sub{sub_index} written with command 0x{command:02X}"
        );
        assert!(entry.access.is_writable(), "0x{index:04X}sub{sub_index}");
    }
    // The routines' RPDO and TPDO remappings fit the dictionary, too.
    for (mapping, length) in [
        (0x6040_0010u32, 16),
        (0x607A_0020, 32),
        (0x6041_0010, 16),
        (0x6064_0020, 32),
    ] {
        let entry = sub(&eds, (mapping >> 16) as u16, (mapping >> 8) as u8);
        assert!(entry.pdo_mappable);
        assert_eq!(entry.data_type.bits(), Some(length));
    }
}

#[test]
fn homing_method_is_0_to_12() {
    let eds = eds();
    let method = sub(&eds, 0x6098, 0);
    assert_eq!(method.low_value(None), Ok(Some(Value::Integer8(0))));
    assert_eq!(method.high_value(None), Ok(Some(Value::Integer8(12))));
    for ok in 0..=12 {
        assert!(
            method.check(&Value::Integer8(ok), None).is_ok(),
            "method {ok}"
        );
    }
    for refused in [-1, 13, 35] {
        assert!(
            method.check(&Value::Integer8(refused), None).is_err(),
            "method {refused}"
        );
    }
}

#[test]
fn comments_carry_the_manuals_bits_modes_and_units() {
    let eds = eds();
    let comments = eds.comments.join("\n");
    for needle in [
        "1 position, 3 velocity, 6 homing",
        "Controlword 0x6040 bit 4",
        "bit 6 (position): 0 absolute, 1 relative",
        "Bit 9 (position)",
        "Statusword 0x6041 bit 9",
        "Bit 14 CW limit switch, bit 15 CCW limit switch",
        "0.1 rps",
        "UNSIGNED16 in 0.1 rps/s",
    ] {
        assert!(comments.contains(needle), "comments lack '{needle}'");
    }
}
