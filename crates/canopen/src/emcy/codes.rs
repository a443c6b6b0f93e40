//! The texts of EMCY error codes: CiA 301's general codes (table 21, as the
//! UniSwarm UMC firmware manual restates it in table 3.9) and the drive codes
//! of CiA 402 as the same manual lists them in table 2.16, each worded
//! exactly as the manual words it.

/// The error codes of CiA 301 (UMC manual table 3.9, "General emergency
/// error codes").
pub const GENERAL_CODES: &[(u16, &str)] = &[
    (0x0000, "Error reset or no error"),
    (0x1000, "Generic error"),
    (0x2000, "Current generic error"),
    (0x2100, "Current, CANOpen device input side generic"),
    (0x2200, "Current inside the CANOpen device generic"),
    (0x2300, "Current, CANOpen device output side generic"),
    (0x3000, "Voltage generic error"),
    (0x3100, "Mains voltage generic"),
    (0x3200, "Voltage inside the CANOpen device generic"),
    (0x3300, "Output voltage generic"),
    (0x4000, "Temperature generic error"),
    (0x4100, "Ambient temperature generic"),
    (0x4200, "Device temperature generic"),
    (0x5000, "CANOpen device hardware generic error"),
    (0x6000, "CANOpen device software generic error"),
    (0x6100, "Internal software generic"),
    (0x6200, "User software generic"),
    (0x6300, "Data set generic"),
    (0x7000, "Additional modules generic error"),
    (0x8000, "Monitoring generic error"),
    (0x8100, "Communication generic"),
    (0x8110, "CAN overrun (objects lost)"),
    (0x8120, "CAN in error passive mode"),
    (0x8130, "Life guard error or heartbeat error"),
    (0x8140, "Recovered from bus off"),
    (0x8150, "CAN-ID collision"),
    (0x8200, "Protocol error - generic"),
    (0x8210, "PDO not processed due to length error"),
    (0x8220, "PDO length exceeded"),
    (
        0x8230,
        "DAM MPDO not processed, destination object not available",
    ),
    (0x8240, "Unexpected SYNC data length"),
    (0x8250, "RPDO timeout"),
    (0x9000, "External error generic error"),
    (0xF000, "Additional functions generic error"),
    (0xFF00, "Device specific generic error"),
];

/// The drive error codes of the UMC manual's table 2.16 ("Emergency error
/// codes", the CiA 402 codes the UMC uses). Where a code is also a general
/// one, this text is the one given: 0x6300 is "Data Set" here, "Data set
/// generic" in table 3.9.
pub const DRIVE_CODES: &[(u16, &str)] = &[
    (0x2000, "Current generic error"),
    (0x2100, "Current, CANOpen device input side generic"),
    (0x2130, "Short circuit (input)"),
    (0x2200, "Current inside the CANOpen device generic"),
    (0x2213, "Over-current in ramp function"),
    (0x2214, "Over-current in the sequence"),
    (0x2220, "Continuous over current (device internal)"),
    (0x2250, "Short circuit (device internal)"),
    (0x2300, "Current, CANOpen device output side generic"),
    (0x2310, "Continuous over current (device output side)"),
    (0x2340, "Short circuit (motor-side)"),
    (0x3000, "Voltage generic error"),
    (0x3100, "Mains voltage generic"),
    (0x3110, "Mains over-voltage"),
    (0x3120, "Mains under-voltage"),
    (0x3130, "Phase failure"),
    (0x3134, "Phase sequence"),
    (0x3200, "Voltage inside the CANOpen device generic"),
    (0x3210, "DC link over-voltage"),
    (0x3211, "Over-voltage no. 1"),
    (0x3212, "Over-voltage no. 2"),
    (0x3220, "DC link under-voltage"),
    (0x3221, "Under-voltage no. 1"),
    (0x3222, "Under-voltage no. 2"),
    (0x3230, "Load error"),
    (0x3300, "Output voltage generic"),
    (0x3310, "Output over-voltage"),
    (0x4000, "Temperature generic error"),
    (0x4200, "Device temperature generic"),
    (0x4210, "Excess temperature device"),
    (0x4220, "Too low temperature device"),
    (0x4300, "Temperature drive"),
    (0x4310, "Excess temperature drive"),
    (0x4320, "Too low temperature drive"),
    (0x5000, "CANOpen device hardware generic error"),
    (0x5200, "Control device hardware"),
    (0x5210, "Measurement circuit"),
    (0x5220, "Computing circuit"),
    (0x5300, "Operating unit"),
    (0x5400, "Power section"),
    (0x5410, "Output stages"),
    (0x5420, "Chopper"),
    (0x5440, "Contacts"),
    (0x5450, "Fuses"),
    (0x5500, "Hardware memory"),
    (0x6000, "CANOpen device software generic error"),
    (0x6010, "Software reset (watchdog)"),
    (0x6300, "Data Set"),
    (0x6310, "Loss of parameters"),
    (0x6320, "Parameter error"),
    (0x7000, "Additional modules generic error"),
    (0x7100, "Power additional modules"),
    (0x7110, "Brake chopper"),
    (0x7111, "Failure brake chopper"),
    (0x7112, "Over current brake chopper"),
    (0x7120, "Motor"),
    (0x7121, "Motor blocked"),
    (0x7122, "Motor error or commutation malfunc."),
    (0x7123, "Motor tilted"),
    (0x7200, "Measurement circuit"),
    (0x7300, "Sensor"),
    (0x7301, "Tacho fault"),
    (0x7305, "Incremental sensor 1 fault"),
    (0x7310, "Speed"),
    (0x7320, "Position"),
    (0x7380, "Torque"),
    (0x7400, "Computation circuit"),
    (0x7500, "Communication"),
    (0x7600, "Data storage (external)"),
    (0x8000, "Monitoring generic error"),
    (0x8300, "Torque controller"),
    (0x8311, "Excess torque"),
    (0x8312, "Difficult start up"),
    (0x8313, "Standstill torque"),
    (0x8321, "Insufficient torque"),
    (0x8331, "Torque fault"),
    (0x8400, "Velocity controller"),
    (0x8500, "Position controller"),
    (0x8600, "Positioning controller"),
    (0x8611, "Following error"),
    (0x8612, "Reference limit"),
    (0x8613, "Homing error"),
    (0x8700, "Sync controller"),
    (0x8800, "Winding controller"),
];

fn lookup(code: u16) -> Option<&'static str> {
    DRIVE_CODES
        .iter()
        .chain(GENERAL_CODES)
        .find(|&&(known, _)| known == code)
        .map(|&(_, text)| text)
}

/// The generic code of the class `code` belongs to (CiA 301 table 21):
/// 00xx, 1xxx–9xxx by their first digit, F0xx and FFxx. `None` for the
/// reserved ranges 01xx–0Fxx, Axxx–Exxx and F1xx–FExx.
fn class_of(code: u16) -> Option<u16> {
    match code >> 12 {
        0x0 => (code < 0x0100).then_some(0x0000),
        0x1..=0x9 => Some(code & 0xF000),
        0xF => match code >> 8 {
            0xF0 => Some(0xF000),
            0xFF => Some(0xFF00),
            _ => None,
        },
        _ => None,
    }
}

/// The most specific text known for an EMCY error code: the code itself,
/// then the code it refines (its last digit, then its last two digits
/// zeroed: 0x2311 falls back to 0x2310, then 0x2300), then its class.
/// Codes in reserved ranges are named as unknown.
pub fn emcy_text(code: u16) -> String {
    [
        Some(code),
        Some(code & 0xFFF0),
        Some(code & 0xFF00),
        class_of(code),
    ]
    .into_iter()
    .flatten()
    .find_map(lookup)
    .map_or_else(|| format!("Unknown error code 0x{code:04X}"), str::to_owned)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_of_both_tables_gives_its_own_text() {
        assert_eq!(DRIVE_CODES.len(), 84);
        assert_eq!(GENERAL_CODES.len(), 35);
        for table in [DRIVE_CODES, GENERAL_CODES] {
            assert!(table.windows(2).all(|pair| pair[0].0 < pair[1].0));
        }
        for &(code, text) in DRIVE_CODES {
            assert_eq!(emcy_text(code), text, "0x{code:04X}");
        }
        for &(code, text) in GENERAL_CODES {
            if code != 0x6300 {
                assert_eq!(emcy_text(code), text, "0x{code:04X}");
            }
        }
    }

    #[test]
    fn texts_are_worded_as_the_manual_words_them() {
        let cases = [
            (0x0000, "Error reset or no error"),
            (0x1000, "Generic error"),
            (0x2130, "Short circuit (input)"),
            (0x2340, "Short circuit (motor-side)"),
            (0x3211, "Over-voltage no. 1"),
            (0x4310, "Excess temperature drive"),
            (0x6010, "Software reset (watchdog)"),
            (0x6300, "Data Set"),
            (0x7122, "Motor error or commutation malfunc."),
            (0x8110, "CAN overrun (objects lost)"),
            (0x8120, "CAN in error passive mode"),
            (0x8130, "Life guard error or heartbeat error"),
            (0x8140, "Recovered from bus off"),
            (0x8150, "CAN-ID collision"),
            (0x8210, "PDO not processed due to length error"),
            (0x8220, "PDO length exceeded"),
            (0x8240, "Unexpected SYNC data length"),
            (0x8250, "RPDO timeout"),
            (0x8611, "Following error"),
            (0x8800, "Winding controller"),
            (0x9000, "External error generic error"),
            (0xF000, "Additional functions generic error"),
            (0xFF00, "Device specific generic error"),
        ];
        for (code, text) in cases {
            assert_eq!(emcy_text(code), text, "0x{code:04X}");
        }
    }

    #[test]
    fn unknown_codes_fall_back_to_what_they_refine_then_their_class() {
        let cases = [
            (0x2311, "Continuous over current (device output side)"),
            (0x2399, "Current, CANOpen device output side generic"),
            (0x2999, "Current generic error"),
            (0x3135, "Phase failure"),
            (0x4111, "Ambient temperature generic"),
            (0x5FFF, "CANOpen device hardware generic error"),
            (0x6201, "User software generic"),
            (0x7FFF, "Additional modules generic error"),
            (0x8614, "Positioning controller"),
            (0x8F00, "Monitoring generic error"),
            (0x0001, "Error reset or no error"),
            (0x10FF, "Generic error"),
            (0x9123, "External error generic error"),
            (0xF0AB, "Additional functions generic error"),
            (0xFF42, "Device specific generic error"),
        ];
        for (code, text) in cases {
            assert_eq!(emcy_text(code), text, "0x{code:04X}");
        }
    }

    #[test]
    fn reserved_ranges_are_unknown() {
        for code in [0x0100, 0x0FFF, 0xA000, 0xE123, 0xF100, 0xFE00] {
            assert_eq!(emcy_text(code), format!("Unknown error code 0x{code:04X}"));
        }
    }
}
