//! Our UIO1LED EDS (`eds/uio1led.eds`, written from the UIOLed firmware
//! manual) against the vendor's file: it loads cleanly, what it says agrees
//! with the device, and it leaves out nothing the manual describes. The
//! vendor's file (`uio1led_v1.0.0.eds`) is an optional test input read from the
//! directory `CANDECK_VENDOR_EDS` names; without it the comparisons say they
//! were skipped and the checks against the manual still run.

mod common;

use candeck::canopen::NodeId;
use candeck::canopen::eds::{Eds, compare, read_eds_file};
use candeck::canopen::od::{AccessType, DataType};
use candeck::profiles::builtin;

const VENDOR: &str = "uio1led_v1.0.0.eds";

fn ours() -> Eds {
    let (eds, warnings) = Eds::parse_with_warnings(builtin::UIO1LED, "eds/uio1led.eds")
        .unwrap_or_else(|error| panic!("{error}"));
    assert!(warnings.is_empty(), "{warnings:#?}");
    eds
}

/// The vendor's file, or `None` (and the test said skipped) without
/// `CANDECK_VENDOR_EDS`.
fn vendor(test: &str) -> Option<Eds> {
    let path = common::vendor_eds(VENDOR, test)?;
    Some(read_eds_file(path).unwrap_or_else(|error| panic!("{error}")))
}

/// The communication objects the manual describes (§2.6, §2.8.4, §2.9.1),
/// including 0x1005 and 0x1014, which it names as the SYNC and EMCY COB-IDs.
const COMMUNICATION: [u16; 30] = [
    0x1000, 0x1001, 0x1005, 0x1008, 0x1009, 0x100A, 0x100C, 0x100D, 0x1010, 0x1011, 0x1014, 0x1017,
    0x1018, 0x1029, 0x1400, 0x1401, 0x1402, 0x1403, 0x1600, 0x1601, 0x1602, 0x1603, 0x1800, 0x1801,
    0x1802, 0x1803, 0x1A00, 0x1A01, 0x1A02, 0x1A03,
];

/// The board, CPU and communication objects of the manual's §1.4. 0x2041
/// `Board_voltage_config` is left out: the manual describes it but the
/// device's own EDS has no such object.
const BOARD: [u16; 12] = [
    0x2000, 0x2001, 0x2002, 0x2003, 0x2004, 0x2020, 0x2021, 0x2022, 0x2023, 0x2024, 0x2025, 0x2040,
];

/// The per-segment objects of the manual's §1.3, as offsets from the
/// segment's base 0x6000 + 0x100 × (n − 1), with their names after `sNN_`.
const SEGMENT: [(u16, &str); 12] = [
    (0x00, "Led_type"),
    (0x01, "Led_count"),
    (0x10, "Value"),
    (0x11, "MinValue"),
    (0x12, "MaxValue"),
    (0x13, "Speed"),
    (0x20, "Effect"),
    (0x24, "Smooth"),
    (0x25, "Dimmer"),
    (0x30, "Color_01"),
    (0x31, "Color_02"),
    (0x32, "Color_03"),
];

fn manual_objects() -> Vec<u16> {
    let mut objects: Vec<u16> = COMMUNICATION.iter().chain(&BOARD).copied().collect();
    for segment in 0..10u16 {
        objects.extend(
            SEGMENT
                .iter()
                .map(|(offset, _)| 0x6000 + 0x100 * segment + offset),
        );
    }
    objects
}

#[test]
fn ours_loads_without_warnings() {
    let eds = ours();
    assert!(!eds.is_dcf());
    assert_eq!(eds.device_info.vendor_number, Some(0x4A2));
    assert_eq!(eds.device_info.nr_of_rx_pdo, Some(4));
    // Table 1.4: every bit rate but 800 kbit/s.
    let rates: Vec<u32> = eds.device_info.baud_rates.iter().copied().collect();
    assert_eq!(rates, [10, 20, 50, 100, 125, 250, 500, 1000]);
}

#[test]
fn ours_is_the_builtin_file_on_disk() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/eds/uio1led.eds");
    assert_eq!(read_eds_file(path).unwrap(), ours());
}

#[test]
fn ours_agrees_with_the_vendor_file() {
    let Some(vendor) = vendor("ours_agrees_with_the_vendor_file") else {
        return;
    };
    for id in [1, 3, 127] {
        let node = NodeId::new(id).unwrap();
        let differences = compare(&ours().dictionary, &vendor.dictionary, node);
        let text: Vec<String> = differences
            .iter()
            .map(ToString::to_string)
            .filter(|difference| {
                !CANDECK_PROGRAM
                    .iter()
                    .any(|index| difference.starts_with(&format!("0x{index:04X} ")))
            })
            .collect();
        assert!(text.is_empty(), "node {id}: {text:#?}");
    }
}

/// Objects the device answers but the manual does not describe, written in
/// our file from CiA 301 (0x1003 pre-defined error field, 0x1016 consumer
/// heartbeat, 0x1200 the default SDO server's COB-IDs) and CiA 302 (0x1F51
/// program control), and 0x2050, the device's bootloader record.
const STANDARD: [u16; 5] = [0x1003, 0x1016, 0x1200, 0x1F51, 0x2050];

/// Objects candeck's virtual device has for the program download of CiA
/// 302-3 (docs/virtual-devices.md), which the vendor file does not list.
const CANDECK_PROGRAM: [u16; 3] = [0x1F50, 0x1F56, 0x1F57];

/// Per-segment objects the manual does not describe, as offsets from the
/// segment's base: the value's profile (+0x14) and the effect's width (+0x23).
const SEGMENT_UNDESCRIBED: [(u16, &str); 2] = [(0x14, "Profile"), (0x23, "Width")];

fn added_objects() -> Vec<u16> {
    let mut objects = STANDARD.to_vec();
    for segment in 0..10u16 {
        objects.extend(
            SEGMENT_UNDESCRIBED
                .iter()
                .map(|(offset, _)| 0x6000 + 0x100 * segment + offset),
        );
    }
    objects
}

#[test]
fn ours_has_every_object_the_manual_describes() {
    let ours = ours();
    let vendor = vendor("ours_has_every_object_the_manual_describes (the vendor file's part)");
    let objects = manual_objects();
    assert_eq!(objects.len(), 30 + 12 + 10 * 12);
    let added = added_objects();
    assert_eq!(added.len(), 5 + 10 * 2);
    for &index in objects.iter().chain(&added).chain(&CANDECK_PROGRAM) {
        let object = ours
            .dictionary
            .get(index)
            .unwrap_or_else(|| panic!("ours lacks 0x{index:04X}"));
        let Some(vendor) = &vendor else { continue };
        if CANDECK_PROGRAM.contains(&index) {
            continue;
        }
        let theirs = vendor
            .dictionary
            .get(index)
            .unwrap_or_else(|| panic!("the vendor file lacks 0x{index:04X}"));
        let subs: Vec<u8> = object.subs.keys().copied().collect();
        let their_subs: Vec<u8> = theirs.subs.keys().copied().collect();
        assert_eq!(
            subs, their_subs,
            "sub-objects of 0x{index:04X} {}",
            theirs.name
        );
    }
    // Nothing else: what neither the manual nor the standards describe is
    // not ours to claim.
    let mut expected: Vec<u16> = objects.into_iter().chain(added).collect();
    expected.extend(CANDECK_PROGRAM);
    expected.sort_unstable();
    let indices: Vec<u16> = ours.dictionary.objects.keys().copied().collect();
    assert_eq!(indices, expected);
}

#[test]
fn undescribed_segment_objects_are_named_per_segment() {
    let ours = ours();
    for n in 1..=10u16 {
        let base = 0x6000 + 0x100 * (n - 1);
        for (offset, name) in SEGMENT_UNDESCRIBED {
            let object = ours.dictionary.get(base + offset).unwrap();
            assert_eq!(object.name, format!("s{n:02}_{name}"));
        }
    }
}

#[test]
fn segment_objects_are_named_and_typed_as_the_manual_says() {
    let ours = ours();
    for n in 1..=10u16 {
        let base = 0x6000 + 0x100 * (n - 1);
        for (offset, name) in SEGMENT {
            let object = ours.dictionary.get(base + offset).unwrap();
            assert_eq!(object.name, format!("s{n:02}_{name}"));
        }
        let value = ours.dictionary.sub(base + 0x10, 0).unwrap();
        assert_eq!(value.data_type, DataType::Integer16);
        assert_eq!(value.access, AccessType::Rww);
        let effect = ours.dictionary.sub(base + 0x20, 0).unwrap();
        assert_eq!(effect.data_type, DataType::Unsigned16);
        let max = ours.dictionary.sub(base + 0x12, 0).unwrap();
        assert_eq!(max.default.as_deref(), Some("32767"));
        let dimmer = ours.dictionary.sub(base + 0x25, 0).unwrap();
        assert_eq!(dimmer.default.as_deref(), Some("255"));
        for colour in 0x30..=0x32 {
            let names: Vec<&str> = (1..=4)
                .map(|sub| {
                    ours.dictionary
                        .sub(base + colour, sub)
                        .unwrap()
                        .name
                        .as_str()
                })
                .collect();
            assert_eq!(names, ["R", "G", "B", "W"]);
        }
    }
}
