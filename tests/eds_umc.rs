//! Our EDS files of the UniSwarm UMC motion controllers (`eds/umc1bds32.eds`,
//! `eds/umc1bd90.eds`), written from the UMC firmware manual, checked against
//! the vendor's own EDS files (`umc1bds32_v1.0.4.eds`, `umc1bd90_v1.0.4.eds`):
//! optional test inputs read from the directory `CANDECK_VENDOR_EDS` names,
//! never part of the repository. Without it the comparisons with the vendor
//! files say they were skipped, and the checks against the manual still run.
//!
//! Where the vendor file contradicts the manual, our files follow the vendor
//! file for what a device shows on the bus (type, access, PDO mapping,
//! default), because that is what the firmware answers:
//!
//! - 0x605E `a1_Fault_reaction_option`: the manual says UINT16, RW, RPDO; the
//!   vendor file says INTEGER16, rw, not mappable (as CiA 402 does).
//! - 0x607D `a1_pc_Software_position_Limit`: the manual gives UINT32 for Min
//!   and Max; the vendor file INTEGER32 (as CiA 402 does: positions are signed).
//! - 0x60C1.1 `Set-point`: rww and mappable in the vendor file (the manual
//!   gives no table for it, but says it is sent as the set point of each cycle).
//! - 0x4040.0 `Number_of_entries` of `a1_Velocity_PID_status` is mappable in
//!   the vendor file.
//! - The defaults in which the two disagree are listed in
//!   `defaults_follow_the_vendor_file_where_the_manual_disagrees`: the
//!   manual gives PDO COB-IDs without the node id (512, 384), 0x2040.1
//!   Node_ID 0, the revision 0x01000003 and, for the UMC1BD90, the product
//!   code and motor currents of the UMC1BDS32; it documents the sensor and
//!   filter defaults of the torque loop (0x4023/0x4024) for all three loops;
//!   0x605E defaults to 2 in the vendor file, 0 in the manual; the PDO mapping
//!   counts of PDOs 2–4 are 2 in the vendor file, 1 in the manual.
//!
//! Where the manual is silent (sub-index 0 entries, the defaults and limits of
//! status objects, 0x2000 Board_voltage whose table is missing, 0x1005 and 0x1014
//! which the manual only names, the access of 0x60C4.3–5, the number of bridges
//! of the UMC1BD90, which the manual says varies by model), the values are the
//! vendor file's, so that the two agree.
//!
//! Objects the device answers but the manual does not describe (0x1003,
//! 0x1016, 0x1200, 0x1F5x, the CiA 402 objects of modes the manual leaves
//! out, 0x2050, 0x2800, 0x4081, 0x4083, and the sub-objects 0x4009.2
//! Phase_advance of the UMC1BDS32 and 0x4020.5/0x4040.5/0x4060.5 Target)
//! are written from CiA 301/302/402 and the objects' meaning;
//! they are listed in `STANDARD_COMMUNICATION`, `STANDARD_CIA402` and
//! `UNDESCRIBED_AXIS`, and each file holds those and the manual's objects,
//! nothing else.

mod common;

use candeck::canopen::NodeId;
use candeck::canopen::eds::{Eds, compare, read_eds_file};
use candeck::profiles::builtin;

const VENDOR_UMC1BDS32: &str = "umc1bds32_v1.0.4.eds";
const VENDOR_UMC1BD90: &str = "umc1bd90_v1.0.4.eds";

fn ours(text: &str, file: &str) -> Eds {
    let (eds, warnings) = Eds::parse_with_warnings(text, file).expect("our EDS reads");
    let warnings: Vec<String> = warnings.iter().map(ToString::to_string).collect();
    assert!(warnings.is_empty(), "{file}: {warnings:#?}");
    eds
}

/// The vendor's file, or `None` (and the test said skipped) without
/// `CANDECK_VENDOR_EDS`.
fn vendor(file: &str, test: &str) -> Option<Eds> {
    let path = common::vendor_eds(file, test)?;
    Some(read_eds_file(&path).unwrap_or_else(|error| panic!("the vendor EDS reads: {error}")))
}

/// Objects candeck's virtual device has for the program download of CiA
/// 302-3 (docs/virtual-devices.md), which the vendor file does not list.
const CANDECK_PROGRAM: &[u16] = &[0x1F50];

fn is_candeck_program(difference: &str) -> bool {
    CANDECK_PROGRAM
        .iter()
        .any(|index| difference.starts_with(&format!("0x{index:04X} ")))
}

/// The PID configurations (0x4021, 0x4041, 0x4061; axis 2 at +0x200)
/// whose defaults are candeck's factory tuning of the virtual motor
/// (docs/virtual-devices.md): the vendor file's gains are all 0, with which
/// no virtual drive would move.
const CANDECK_TUNING: &[u16] = &[0x4021, 0x4041, 0x4061, 0x4221, 0x4241, 0x4261];

fn is_candeck_tuning(difference: &str) -> bool {
    difference.contains(": default differs:")
        && CANDECK_TUNING
            .iter()
            .any(|index| difference.starts_with(&format!("0x{index:04X} ")))
}

fn assert_agrees(ours: &Eds, theirs: &Eds) {
    for node in [1, 5, 127] {
        let node = NodeId::new(node).unwrap();
        let differences: Vec<String> = compare(&ours.dictionary, &theirs.dictionary, node)
            .iter()
            .map(ToString::to_string)
            .filter(|difference| !is_candeck_program(difference) && !is_candeck_tuning(difference))
            .collect();
        assert!(differences.is_empty(), "{differences:#?}");
    }
}

#[test]
fn umc1bds32_loads_without_warnings() {
    let eds = ours(builtin::UMC1BDS32, "eds/umc1bds32.eds");
    assert_eq!(eds.device_info.product_name.as_deref(), Some("UMC1BDS32"));
}

#[test]
fn umc1bd90_loads_without_warnings() {
    let eds = ours(builtin::UMC1BD90, "eds/umc1bd90.eds");
    assert_eq!(eds.device_info.product_name.as_deref(), Some("UMC1BD90"));
}

#[test]
fn umc1bds32_agrees_with_the_vendor_file() {
    let Some(vendor) = vendor(VENDOR_UMC1BDS32, "umc1bds32_agrees_with_the_vendor_file") else {
        return;
    };
    let ours = ours(builtin::UMC1BDS32, "eds/umc1bds32.eds");
    assert_agrees(&ours, &vendor);
}

#[test]
fn umc1bd90_agrees_with_the_vendor_file() {
    let Some(vendor) = vendor(VENDOR_UMC1BD90, "umc1bd90_agrees_with_the_vendor_file") else {
        return;
    };
    let ours = ours(builtin::UMC1BD90, "eds/umc1bd90.eds");
    assert_agrees(&ours, &vendor);
}

/// The CiA 402 objects of each mode the manual documents, per axis (axis 1
/// at 0x6000, axis 2 at +0x200).
const CIA402: &[(u16, &str)] = &[
    (0x6007, "Abort_connection_option"),
    (0x6040, "Controlword"),
    (0x6041, "Statusword"),
    (0x6042, "vl_Velocity_target"),
    (0x6043, "vl_Velocity_demand"),
    (0x6044, "vl_Velocity_actual_value"),
    (0x6046, "vl_Min_max"),
    (0x6048, "vl_Acceleration"),
    (0x6049, "vl_Deceleration"),
    (0x604A, "vl_Quick_stop"),
    (0x604B, "vl_Set_point_factor"),
    (0x604C, "vl_Dimension_factor"),
    (0x605A, "Quick_stop_option"),
    (0x605B, "Shutdown_option"),
    (0x605C, "Disable_operation_option"),
    (0x605D, "Halt_option"),
    (0x605E, "Fault_reaction_option"),
    (0x6060, "Modes_of_operation"),
    (0x6061, "Modes_of_operation_display"),
    (0x6062, "pc_Position_demand_value"),
    (0x6064, "pc_Position_actual_value"),
    (0x6071, "tq_Torque_target"),
    (0x6072, "tq_Max_torque"),
    (0x6074, "tq_Torque_demand"),
    (0x6077, "tq_Torque_actual_value"),
    (0x6078, "tq_Current_actual_value"),
    (0x607A, "pp_Position_target"),
    (0x607B, "pc_Position_range_limit"),
    (0x607C, "hm_Home_offset"),
    (0x607D, "pc_Software_position_Limit"),
    (0x607E, "fg_Polarity"),
    (0x607F, "pc_Max_profile_velocity"),
    (0x6080, "pc_Max_motor_speed"),
    (0x6081, "pc_Profile_velocity"),
    (0x6083, "pc_Profile_acceleration"),
    (0x6084, "pc_Profile_deceleration"),
    (0x6085, "pc_Quick_stop_deceleration"),
    (0x6086, "pp_Motion_profile_type"),
    (0x6087, "tq_Torque_slope"),
    (0x6088, "tq_Torque_profile_type"),
    (0x60C0, "ip_Sub_mode_select"),
    (0x60C1, "ip_Data_record"),
    (0x60C2, "ip_Time_period"),
    (0x60C4, "ip_Data_configuration"),
    (0x60C5, "pc_Max_acceleration"),
    (0x60C6, "pc_Max_deceleration"),
    (0x6502, "Supported_drive_modes"),
];

/// The manufacturer objects of each axis (axis 2 at +0x200): motion and motor
/// status and configuration, control loops and their sensors, brake, duty
/// cycle and continuous position targets.
const AXIS: &[(u16, &str)] = &[
    (0x4000, "Motion_status"),
    (0x4006, "Motor_status"),
    (0x4007, "Motor_config"),
    (0x4008, "BLDC_status"),
    (0x4009, "BLDC_config"),
    (0x4020, "Torque_PID_status"),
    (0x4021, "Torque_PID_config"),
    (0x4022, "Torque_sensor_status"),
    (0x4023, "Torque_sensor_config"),
    (0x4024, "Torque_sensor_filter"),
    (0x4025, "Torque_sensor_conditioning"),
    (0x4040, "Velocity_PID_status"),
    (0x4041, "Velocity_PID_config"),
    (0x4042, "Velocity_sensor_status"),
    (0x4043, "Velocity_sensor_config"),
    (0x4044, "Velocity_sensor_filter"),
    (0x4045, "Velocity_sensor_conditioning"),
    (0x4060, "Position_PID_status"),
    (0x4061, "Position_PID_config"),
    (0x4062, "Position_sensor_status"),
    (0x4063, "Position_sensor_config"),
    (0x4064, "Position_sensor_filter"),
    (0x4065, "Position_sensor_conditioning"),
    (0x4082, "Brake_config"),
    (0x41F0, "cp_target"),
    (0x41FA, "dty_target"),
    (0x41FB, "dty_demand"),
    (0x41FC, "dty_max"),
    (0x41FD, "dty_slope"),
];

/// The board objects (0x2xxx) and communication objects the manual lists.
const BOARD_AND_COMMUNICATION: &[(u16, &str)] = &[
    (0x1000, "Device_type"),
    (0x1001, "Error_register"),
    (0x1005, "COB_ID_SYNC"),
    (0x1008, "Manufacturer_device_name"),
    (0x1009, "Manufacturer_hardware_version"),
    (0x100A, "Manufacturer_software_version"),
    (0x100C, "Guard_time"),
    (0x100D, "Life_time_factor"),
    (0x1010, "Store_parameters"),
    (0x1011, "Restore_default_parameters"),
    (0x1014, "COB_ID_EMCY"),
    (0x1017, "Producer_heartbeat_time"),
    (0x1018, "Identity_object"),
    (0x1029, "Error_behaviour"),
    (0x1400, "RPDO_parameter_1"),
    (0x1403, "RPDO_parameter_4"),
    (0x1600, "RPDO_mapping_1"),
    (0x1603, "RPDO_mapping_4"),
    (0x1800, "TPDO_parameter_1"),
    (0x1803, "TPDO_parameter_4"),
    (0x1A00, "TPDO_mapping_1"),
    (0x1A03, "TPDO_mapping_4"),
    (0x2000, "Board_voltage"),
    (0x2001, "Manufacture_date"),
    (0x2002, "Calibration_date"),
    (0x2003, "Firmware_build_date"),
    (0x2004, "Board_led"),
    (0x2020, "CPU_temperature"),
    (0x2021, "CPU_life_cycle"),
    (0x2022, "CPU_error"),
    (0x2023, "CPU_min_cycle_us"),
    (0x2024, "CPU_max_cycle_us"),
    (0x2025, "CPU_mean_cycle_us"),
    (0x2040, "Communication_config"),
    (0x2041, "Board_voltage_config"),
    (0x2801, "Driver_temperature"),
    (0x2802, "Currents_HL"),
    (0x2803, "Currents_LL"),
    (0x2804, "PWM"),
    (0x2805, "Back_EMF"),
    (0x2810, "Driver_temperature_config"),
];

/// Communication and board objects the device answers but the manual does
/// not describe, written in our files from CiA 301 (0x1003, 0x1016, 0x1200),
/// CiA 302 (0x1F51, 0x1F55–0x1F57) and the device (0x2050 Bootloader,
/// 0x2800 Board_status).
const STANDARD_COMMUNICATION: &[(u16, &str)] = &[
    (0x1003, "Predefined_error_field"),
    (0x1016, "Consumer_heartbeat"),
    (0x1200, "Server_SDO_parameter_0"),
    (0x1F51, "Program_control"),
    (0x1F55, "Expected_program_software_identification"),
    (0x1F56, "Program_software_identification"),
    (0x1F57, "Flash_status_identification"),
    (0x2050, "Bootloader"),
    (0x2800, "Board_status"),
];

/// CiA 402 objects of each axis (axis 2 at +0x200) the manual does not
/// describe, written in our files from the standard.
const STANDARD_CIA402: &[(u16, &str)] = &[
    (0x6063, "pc_Position_actual_internal_value"),
    (0x6065, "pc_Following_error_window"),
    (0x6066, "pc_Following_error_time_out"),
    (0x6067, "pc_Position_window"),
    (0x6068, "pc_Position_window_time"),
    (0x6069, "pv_Velocity_sensor_actual_value"),
    (0x606A, "pv_Sensor_selection_code"),
    (0x606B, "pv_Velocity_demand_value"),
    (0x606C, "pv_Velocity_actual_value"),
    (0x606D, "pv_Velocity_window"),
    (0x606E, "pv_Velocity_window_time"),
    (0x606F, "pv_Velocity_threshold"),
    (0x6070, "pv_Velocity_threshold_time"),
    (0x6073, "tq_Max_current"),
    (0x6075, "tq_Motor_rated_current"),
    (0x6076, "tq_Motor_rated_torque"),
    (0x6079, "tq_Dc_link_circuit_voltage"),
    (0x6082, "pc_End_velocity"),
    (0x608F, "fg_Position_encoder_resolution"),
    (0x6090, "fg_Velocity_encoder_resolution"),
    (0x6091, "fg_Gear_ratio"),
    (0x6092, "fg_Feed_constant"),
    (0x6098, "hm_Homing_method"),
    (0x6099, "hm_Homing_speeds"),
    (0x609A, "hm_Homing_acceleration"),
    (0x60A3, "pp_Profile_jerk_use"),
    (0x60A4, "pp_Profile_jerk"),
    (0x60B0, "csp_Position_offset"),
    (0x60B1, "csp_Velocity_offset"),
    (0x60B2, "cst_Torque_offset"),
    (0x60B8, "tp_Touch_probe_function"),
    (0x60B9, "tp_Touch_probe_status"),
    (0x60BA, "tp_Touch_probe_pos_1_pos_value"),
    (0x60BB, "tp_Touch_probe_pos_1_neg_value"),
    (0x60BC, "tp_Touch_probe_pos_2_pos_value"),
    (0x60BD, "tp_Touch_probe_pos_2_neg_value"),
    (0x60EA, "cstca_Commutation_angle"),
    (0x60F2, "pc_Positioning_option_code"),
    (0x60F4, "pc_Following_error_actual_value"),
    (0x60F8, "pv_Max_slippage"),
    (0x60FA, "pc_Control_effort"),
    (0x60FD, "Digital_inputs"),
    (0x60FE, "Digital_outputs"),
    (0x60FF, "pv_Velocity_target"),
    (0x6403, "Motor_catalogue_number"),
    (0x6404, "Motor_manufacturer"),
    (0x6405, "http_motor_catalogue_address"),
    (0x6407, "Motor_service_period"),
    (0x6503, "Drive_catalogue_number"),
    (0x6505, "http_drive_catalogue_address"),
    (0x67FE, "Version_number"),
    (0x67FF, "Single_device_type"),
];

/// Manufacturer objects of each axis (axis 2 at +0x200) the manual does not
/// describe: motor temperature sensing and limit/home switches.
const UNDESCRIBED_AXIS: &[(u16, &str)] = &[
    (0x4081, "Motor_temperature_config"),
    (0x4083, "Limit_switches_config"),
];

fn assert_has_the_added_objects(eds: &Eds, axes: u16) {
    for &(index, name) in STANDARD_COMMUNICATION {
        assert_has(eds, index, name);
    }
    for axis in 0..axes {
        let prefix = format!("a{}_", axis + 1);
        for &(index, name) in STANDARD_CIA402 {
            assert_has(eds, index + axis * 0x800, &format!("{prefix}{name}"));
        }
        for &(index, name) in UNDESCRIBED_AXIS {
            assert_has(eds, index + axis * 0x200, &format!("{prefix}{name}"));
        }
    }
}

/// Every object of ours is one the manual describes or one listed above,
/// and (when the vendor file is at hand) every object of the vendor file is
/// in ours.
fn assert_exactly(eds: &Eds, vendor: Option<&Eds>, axes: u16) {
    let mut expected: Vec<u16> = Vec::new();
    let communication = BOARD_AND_COMMUNICATION.iter().chain(STANDARD_COMMUNICATION);
    expected.extend(communication.map(|&(index, _)| index));
    // The manual's PDO ranges name their first and last objects.
    expected.extend([
        0x1401, 0x1402, 0x1601, 0x1602, 0x1801, 0x1802, 0x1A01, 0x1A02,
    ]);
    for axis in 0..axes {
        let cia402 = CIA402.iter().chain(STANDARD_CIA402);
        expected.extend(cia402.map(|&(index, _)| index + axis * 0x800));
        let manufacturer = AXIS.iter().chain(UNDESCRIBED_AXIS);
        expected.extend(manufacturer.map(|&(index, _)| index + axis * 0x200));
    }
    if axes == 2 {
        expected.extend([0x2A00, 0x2A01]);
    }
    expected.extend(CANDECK_PROGRAM);
    expected.sort_unstable();
    let mut indices: Vec<u16> = eds.dictionary.objects.keys().copied().collect();
    assert_eq!(indices, expected);
    if let Some(vendor) = vendor {
        indices.retain(|index| !CANDECK_PROGRAM.contains(index));
        let theirs: Vec<u16> = vendor.dictionary.objects.keys().copied().collect();
        assert_eq!(indices, theirs, "the vendor file's objects");
    }
}

#[test]
fn umc1bds32_has_the_standard_objects_and_nothing_else() {
    let eds = ours(builtin::UMC1BDS32, "eds/umc1bds32.eds");
    assert_has_the_added_objects(&eds, 2);
    let vendor = vendor(
        VENDOR_UMC1BDS32,
        "umc1bds32_has_the_standard_objects_and_nothing_else (the vendor file's part)",
    );
    assert_exactly(&eds, vendor.as_ref(), 2);
}

#[test]
fn umc1bd90_has_the_standard_objects_and_nothing_else() {
    let eds = ours(builtin::UMC1BD90, "eds/umc1bd90.eds");
    assert_has_the_added_objects(&eds, 1);
    let vendor = vendor(
        VENDOR_UMC1BD90,
        "umc1bd90_has_the_standard_objects_and_nothing_else (the vendor file's part)",
    );
    assert_exactly(&eds, vendor.as_ref(), 1);
}

fn assert_has(eds: &Eds, index: u16, name: &str) {
    let object = eds
        .dictionary
        .get(index)
        .unwrap_or_else(|| panic!("0x{index:04X} {name} missing"));
    assert_eq!(object.name, name, "0x{index:04X}");
}

fn assert_has_the_manuals_objects(eds: &Eds, axes: u16) {
    for &(index, name) in BOARD_AND_COMMUNICATION {
        assert_has(eds, index, name);
    }
    for axis in 0..axes {
        let prefix = format!("a{}_", axis + 1);
        for &(index, name) in CIA402 {
            assert_has(eds, index + axis * 0x800, &format!("{prefix}{name}"));
        }
        for &(index, name) in AXIS {
            assert_has(eds, index + axis * 0x200, &format!("{prefix}{name}"));
        }
    }
}

#[test]
fn umc1bds32_has_the_manuals_objects_for_both_axes() {
    let eds = ours(builtin::UMC1BDS32, "eds/umc1bds32.eds");
    assert_has_the_manuals_objects(&eds, 2);
    assert_has(&eds, 0x2A00, "S12_Synchro_status");
    assert_has(&eds, 0x2A01, "S12_Synchro_config");
    // Two axes and no more.
    assert!(eds.dictionary.get(0x7040).is_none());
    assert!(eds.dictionary.get(0x4400).is_none());
}

#[test]
fn umc1bd90_has_the_manuals_objects_for_its_axis() {
    let eds = ours(builtin::UMC1BD90, "eds/umc1bd90.eds");
    assert_has_the_manuals_objects(&eds, 1);
    // One axis: nothing of a second one, and no axis synchronization.
    assert!(eds.dictionary.get(0x6840).is_none());
    assert!(eds.dictionary.get(0x4200).is_none());
    assert!(eds.dictionary.get(0x2A00).is_none());
}

#[test]
fn attributes_from_the_manual() {
    for (text, file) in [
        (builtin::UMC1BDS32, "eds/umc1bds32.eds"),
        (builtin::UMC1BD90, "eds/umc1bd90.eds"),
    ] {
        let eds = ours(text, file);
        let sub = |index, sub| eds.dictionary.sub(index, sub).unwrap();
        // 0x6040 controlword: UINT16, RW, RPDO, default 0.
        let controlword = sub(0x6040, 0);
        assert_eq!(controlword.data_type.to_string(), "UNSIGNED16");
        assert_eq!(controlword.access.to_string(), "rww");
        assert_eq!(controlword.default.as_deref(), Some("0"));
        // 0x6060 modes of operation: INT8, default -1 (duty cycle), range -128..10.
        let modes = sub(0x6060, 0);
        assert_eq!(modes.default.as_deref(), Some("-1"));
        // 0x6502: PP, VL, TQ, IP, DTY and CP.
        assert_eq!(sub(0x6502, 0).default.as_deref(), Some("1115211"));
        // 0x4006.3 Torque is a Q15.16, carried as an INTEGER32.
        assert_eq!(sub(0x4006, 3).data_type.to_string(), "INTEGER32");
        assert_eq!(sub(0x4006, 3).name, "Torque");
    }
}

#[test]
fn defaults_follow_the_vendor_file_where_the_manual_disagrees() {
    let node = NodeId::new(5).unwrap();
    // (index, sub, the manual's default, ours = the vendor file's, for node 5)
    let both: &[(u16, u8, &str, &str)] = &[
        (0x1018, 3, "16777219", "16777220"),
        (0x1400, 1, "512", "517"),
        (0x1800, 1, "384", "389"),
        (0x1601, 0, "1", "2"),
        (0x2040, 1, "0", "5"),
        (0x4043, 1, "4352", "0"),
        (0x4064, 2, "1048576", "0"),
        (0x605E, 0, "0", "2"),
    ];
    for (text, file) in [
        (builtin::UMC1BDS32, "eds/umc1bds32.eds"),
        (builtin::UMC1BD90, "eds/umc1bd90.eds"),
    ] {
        let eds = ours(text, file);
        for &(index, sub, manual, vendor) in both {
            let value = eds
                .dictionary
                .sub(index, sub)
                .unwrap()
                .default_value(Some(node))
                .unwrap()
                .unwrap()
                .to_text();
            assert_ne!(value, manual, "0x{index:04X}.{sub}");
            assert_eq!(value, vendor, "0x{index:04X}.{sub}");
        }
    }
    // The UMC1BD90's own identity and currents (the manual gives the UMC1BDS32's).
    let bd90 = ours(builtin::UMC1BD90, "eds/umc1bd90.eds");
    let default = |index, sub| bd90.dictionary.sub(index, sub).unwrap().default.clone();
    assert_eq!(default(0x1018, 2).as_deref(), Some("0x00001002"));
    assert_eq!(default(0x4007, 2).as_deref(), Some("9000"));
}
