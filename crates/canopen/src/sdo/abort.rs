//! SDO abort codes (CiA 301 §7.2.4.3.17, table 22): why a client or a server
//! ended a transfer, with the text CiA 301 gives each code.

use std::fmt;

/// Declares [`AbortCode`] from one table so that a variant, its wire value and
/// its text cannot drift apart.
macro_rules! abort_codes {
    ($($name:ident = $raw:literal, $text:literal;)*) => {
        /// An SDO abort code: the 32-bit value in bytes 4–7 (little-endian) of
        /// an abort frame. The doc of each variant gives its wire value and
        /// CiA 301 text; [`AbortCode::Unknown`] keeps any other value.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum AbortCode {
            $(
                #[doc = concat!("`", stringify!($raw), "`: ", $text, ".")]
                $name,
            )*
            /// A value CiA 301 does not define (manufacturer-specific or
            /// simply wrong). Build it only through [`AbortCode::from_raw`],
            /// so that a defined value always gets its named variant.
            Unknown(u32),
        }

        impl AbortCode {
            /// Every code CiA 301 defines, in numeric order.
            pub const ALL: &'static [AbortCode] = &[$(AbortCode::$name),*];

            /// The wire value.
            pub fn raw(self) -> u32 {
                match self {
                    $(Self::$name => $raw,)*
                    Self::Unknown(raw) => raw,
                }
            }

            /// Reads a wire value; values CiA 301 does not define become
            /// [`AbortCode::Unknown`].
            pub fn from_raw(raw: u32) -> Self {
                match raw {
                    $($raw => Self::$name,)*
                    other => Self::Unknown(other),
                }
            }

            /// The CiA 301 text of the code, without the number.
            pub fn text(self) -> &'static str {
                match self {
                    $(Self::$name => $text,)*
                    Self::Unknown(_) => "Abort code not defined by CiA 301",
                }
            }
        }
    };
}

abort_codes! {
    ToggleBitNotAlternated = 0x0503_0000, "Toggle bit not alternated";
    TimedOut = 0x0504_0000, "SDO protocol timed out";
    InvalidCommandSpecifier = 0x0504_0001, "Client/server command specifier not valid or unknown";
    InvalidBlockSize = 0x0504_0002, "Invalid block size (block mode only)";
    InvalidSequenceNumber = 0x0504_0003, "Invalid sequence number (block mode only)";
    CrcError = 0x0504_0004, "CRC error (block mode only)";
    OutOfMemory = 0x0504_0005, "Out of memory";
    UnsupportedAccess = 0x0601_0000, "Unsupported access to an object";
    WriteOnlyObject = 0x0601_0001, "Attempt to read a write only object";
    ReadOnlyObject = 0x0601_0002, "Attempt to write a read only object";
    ObjectDoesNotExist = 0x0602_0000, "Object does not exist in the object dictionary";
    CannotMapToPdo = 0x0604_0041, "Object cannot be mapped to the PDO";
    PdoLengthExceeded = 0x0604_0042, "The number and length of the objects to be mapped would exceed PDO length";
    ParameterIncompatible = 0x0604_0043, "General parameter incompatibility reason";
    InternalIncompatible = 0x0604_0047, "General internal incompatibility in the device";
    HardwareError = 0x0606_0000, "Access failed due to a hardware error";
    LengthMismatch = 0x0607_0010, "Data type does not match, length of service parameter does not match";
    LengthTooHigh = 0x0607_0012, "Data type does not match, length of service parameter too high";
    LengthTooLow = 0x0607_0013, "Data type does not match, length of service parameter too low";
    SubIndexDoesNotExist = 0x0609_0011, "Sub-index does not exist";
    InvalidValue = 0x0609_0030, "Invalid value for parameter (download only)";
    ValueTooHigh = 0x0609_0031, "Value of parameter written too high (download only)";
    ValueTooLow = 0x0609_0032, "Value of parameter written too low (download only)";
    MaxLessThanMin = 0x0609_0036, "Maximum value is less than minimum value";
    NoSdoConnection = 0x060A_0023, "Resource not available: SDO connection";
    GeneralError = 0x0800_0000, "General error";
    CannotStore = 0x0800_0020, "Data cannot be transferred or stored to the application";
    CannotStoreLocalControl = 0x0800_0021, "Data cannot be transferred or stored to the application because of local control";
    CannotStoreDeviceState = 0x0800_0022, "Data cannot be transferred or stored to the application because of the present device state";
    NoObjectDictionary = 0x0800_0023, "Object dictionary dynamic generation fails or no object dictionary is present";
    NoDataAvailable = 0x0800_0024, "No data available";
}

impl From<u32> for AbortCode {
    fn from(raw: u32) -> Self {
        Self::from_raw(raw)
    }
}

impl From<AbortCode> for u32 {
    fn from(code: AbortCode) -> Self {
        code.raw()
    }
}

impl fmt::Display for AbortCode {
    /// `0x06020000: Object does not exist in the object dictionary`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:08X}: {}", self.raw(), self.text())
    }
}

/// An abort code is the reason an object access failed, so
/// [`ObjectAccess`](super::ObjectAccess) implementations can return it with
/// `?` from code that expects an error type.
impl std::error::Error for AbortCode {}

#[cfg(test)]
mod tests;
