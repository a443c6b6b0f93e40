use super::*;

#[test]
fn every_cia_301_code_round_trips_through_its_wire_value() {
    assert_eq!(AbortCode::ALL.len(), 31);
    for &code in AbortCode::ALL {
        assert_eq!(AbortCode::from_raw(code.raw()), code);
        assert!(!matches!(code, AbortCode::Unknown(_)));
    }
    let mut raws: Vec<u32> = AbortCode::ALL.iter().map(|c| c.raw()).collect();
    raws.dedup();
    assert_eq!(raws.len(), 31, "no value twice");
    assert!(raws.is_sorted(), "table in numeric order");
}

#[test]
fn wire_values_and_texts_match_cia_301() {
    let table = [
        (
            AbortCode::ToggleBitNotAlternated,
            0x0503_0000,
            "Toggle bit not alternated",
        ),
        (AbortCode::TimedOut, 0x0504_0000, "SDO protocol timed out"),
        (
            AbortCode::InvalidCommandSpecifier,
            0x0504_0001,
            "Client/server command specifier not valid or unknown",
        ),
        (
            AbortCode::InvalidBlockSize,
            0x0504_0002,
            "Invalid block size (block mode only)",
        ),
        (
            AbortCode::InvalidSequenceNumber,
            0x0504_0003,
            "Invalid sequence number (block mode only)",
        ),
        (
            AbortCode::CrcError,
            0x0504_0004,
            "CRC error (block mode only)",
        ),
        (AbortCode::OutOfMemory, 0x0504_0005, "Out of memory"),
        (
            AbortCode::UnsupportedAccess,
            0x0601_0000,
            "Unsupported access to an object",
        ),
        (
            AbortCode::WriteOnlyObject,
            0x0601_0001,
            "Attempt to read a write only object",
        ),
        (
            AbortCode::ReadOnlyObject,
            0x0601_0002,
            "Attempt to write a read only object",
        ),
        (
            AbortCode::ObjectDoesNotExist,
            0x0602_0000,
            "Object does not exist in the object dictionary",
        ),
        (
            AbortCode::CannotMapToPdo,
            0x0604_0041,
            "Object cannot be mapped to the PDO",
        ),
        (
            AbortCode::PdoLengthExceeded,
            0x0604_0042,
            "The number and length of the objects to be mapped would exceed PDO length",
        ),
        (
            AbortCode::ParameterIncompatible,
            0x0604_0043,
            "General parameter incompatibility reason",
        ),
        (
            AbortCode::InternalIncompatible,
            0x0604_0047,
            "General internal incompatibility in the device",
        ),
        (
            AbortCode::HardwareError,
            0x0606_0000,
            "Access failed due to a hardware error",
        ),
        (
            AbortCode::LengthMismatch,
            0x0607_0010,
            "Data type does not match, length of service parameter does not match",
        ),
        (
            AbortCode::LengthTooHigh,
            0x0607_0012,
            "Data type does not match, length of service parameter too high",
        ),
        (
            AbortCode::LengthTooLow,
            0x0607_0013,
            "Data type does not match, length of service parameter too low",
        ),
        (
            AbortCode::SubIndexDoesNotExist,
            0x0609_0011,
            "Sub-index does not exist",
        ),
        (
            AbortCode::InvalidValue,
            0x0609_0030,
            "Invalid value for parameter (download only)",
        ),
        (
            AbortCode::ValueTooHigh,
            0x0609_0031,
            "Value of parameter written too high (download only)",
        ),
        (
            AbortCode::ValueTooLow,
            0x0609_0032,
            "Value of parameter written too low (download only)",
        ),
        (
            AbortCode::MaxLessThanMin,
            0x0609_0036,
            "Maximum value is less than minimum value",
        ),
        (
            AbortCode::NoSdoConnection,
            0x060A_0023,
            "Resource not available: SDO connection",
        ),
        (AbortCode::GeneralError, 0x0800_0000, "General error"),
        (
            AbortCode::CannotStore,
            0x0800_0020,
            "Data cannot be transferred or stored to the application",
        ),
        (
            AbortCode::CannotStoreLocalControl,
            0x0800_0021,
            "Data cannot be transferred or stored to the application because of local control",
        ),
        (
            AbortCode::CannotStoreDeviceState,
            0x0800_0022,
            "Data cannot be transferred or stored to the application because of the present device state",
        ),
        (
            AbortCode::NoObjectDictionary,
            0x0800_0023,
            "Object dictionary dynamic generation fails or no object dictionary is present",
        ),
        (AbortCode::NoDataAvailable, 0x0800_0024, "No data available"),
    ];
    assert_eq!(table.len(), AbortCode::ALL.len());
    for (code, raw, text) in table {
        assert_eq!(code.raw(), raw, "{code:?}");
        assert_eq!(AbortCode::from_raw(raw), code);
        assert_eq!(code.text(), text);
    }
}

#[test]
fn display_gives_number_and_text() {
    assert_eq!(
        AbortCode::ObjectDoesNotExist.to_string(),
        "0x06020000: Object does not exist in the object dictionary"
    );
    assert_eq!(
        AbortCode::from_raw(0x1234_5678).to_string(),
        "0x12345678: Abort code not defined by CiA 301"
    );
    assert_eq!(AbortCode::from(0x0800_0000), AbortCode::GeneralError);
    assert_eq!(u32::from(AbortCode::Unknown(7)), 7);
}
