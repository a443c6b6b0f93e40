//! The gateway service's one error type: what went wrong on the way to a
//! device, for every adapter (REST, WebSocket, CiA 309-3 and 309-5) to
//! answer in its own terms. The REST status of each variant is given in one
//! place, `crate::api::error`; CiA 309 gives its error numbers in
//! `crate::cia309`.
//!
//! What the device said (an SDO abort), what the clock said (a timeout) and
//! what the bus did (down) stay apart, as they do in [`SdoRequestError`].

use crate::can::BusError;
use crate::canopen::nmt::NmtState;
use crate::canopen::sdo::{AbortCode, SdoError};

use super::drive::DriveError;
use super::motion_lease::LeaseError;
use super::registry::RegistryError;
use super::sdo::SdoRequestError;

/// Why a request to the gateway failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GatewayError {
    /// A request that cannot be read (a node id that is no node id).
    #[error("{0}")]
    InvalidRequest(String),
    /// A value that does not fit (found before the bus).
    #[error("{0}")]
    InvalidValue(String),
    #[error("{0}")]
    ValueOutOfRange(String),
    #[error("no bus is named '{0}'")]
    UnknownBus(String),
    /// The node is not in the bus's registry (never heard, never found by a
    /// scan).
    #[error("node {node} is not known on bus {bus}")]
    UnknownNode { bus: String, node: String },
    /// CiA 301 allows no SDO in this NMT state; refused before the bus.
    #[error("node {node} is {state}: SDO is not allowed in this NMT state", state = .state.name())]
    WrongNmtState { node: u8, state: NmtState },
    /// The device aborted the transfer.
    #[error("node {node} refused: {}", .code.text())]
    SdoAbort { node: u8, code: AbortCode },
    /// The device answered, but not by the protocol; the gateway aborted.
    #[error("node {node} broke the SDO protocol ({detail}); the gateway aborted with {code}")]
    SdoProtocol {
        node: u8,
        code: AbortCode,
        detail: String,
    },
    /// The device did not answer in time.
    #[error("node {node} did not answer in time")]
    SdoTimeout { node: u8 },
    /// The bus cannot carry the request (down, closed).
    #[error("{0}")]
    BusDown(String),
    /// A drive node whose heartbeat is lost: refused at once rather than
    /// after an SDO timeout per transfer.
    #[error("{0}")]
    NodeOffline(String),
    /// The node has no axes (its profile is not umc, jmc_stepper or
    /// cia402).
    #[error("{0}")]
    NotADrive(String),
    #[error("{0}")]
    UnknownAxis(String),
    /// The drive is in fault (or went there during a state walk).
    #[error("{message}")]
    DriveFault { message: String, state: String },
    /// A move asks for operation enabled.
    #[error("{message}")]
    DriveNotEnabled { message: String, state: String },
    #[error("{0}")]
    ModeNotSupported(String),
    /// The drive did not reach a state (mode, acknowledge) in time.
    #[error("{message}")]
    StateChangeTimeout { message: String, state: String },
    /// The axis is held by another client's motion lease.
    #[error("{0}")]
    LeaseConflict(String),
    /// A lease that is not held (lapsed, ended, or never granted).
    #[error("{0}")]
    UnknownLease(String),
    /// No token, or one the gateway does not know, where it asks for one.
    #[error("{0}")]
    Unauthenticated(String),
    /// The client's role is below what the request needs.
    #[error("{0}")]
    Forbidden(String),
    /// The token sends writes faster than its rate limit
    /// ([`crate::access::WriteLimiter`]).
    #[error("{message}")]
    RateLimited { message: String, retry_after_s: u64 },
    /// Another LSS transaction runs on the bus.
    #[error("{0}")]
    LssBusy(String),
    /// No device with the LSS address asked for answered.
    #[error("{0}")]
    LssNotFound(String),
    /// An LSS answer (or the boot-up after one) did not come in time.
    #[error("{0}")]
    LssTimeout(String),
    /// The LSS slave refused a configuration service.
    #[error("{0}")]
    LssRefused(String),
    /// The node-ID asked for is in use on the bus.
    #[error("{0}")]
    NodeIdInUse(String),
    /// The node's product cannot change its node-ID over SDO (no 0x2040).
    #[error("{0}")]
    NodeIdNotSupported(String),
    /// No EDS file of the catalog has this name.
    #[error("no EDS file is named '{0}'")]
    UnknownEds(String),
    /// An uploaded file that is no EDS (the reader's error, with its line).
    #[error("{message}")]
    InvalidEds {
        message: String,
        line: Option<usize>,
    },
    /// An EDS file that cannot be added or deleted now: its name is taken,
    /// it is not an uploaded one, or a node is assigned to it.
    #[error("{0}")]
    EdsConflict(String),
    /// The node is no CiA 401 I/O module (its profile is not cia401).
    #[error("{0}")]
    NotAnIoModule(String),
    /// The I/O module has no such channel.
    #[error("{0}")]
    UnknownChannel(String),
    /// A program download whose image the device does not identify as
    /// the one sent (0x1F56 is not its CRC-32).
    #[error("{0}")]
    ProgramNotVerified(String),
    /// A fault of the gateway itself; the detail is for the log.
    #[error("{0}")]
    Internal(String),
}

impl GatewayError {
    /// The error's code, as the REST API and the audit log name it
    /// (`sdo_abort`, `bus_down`, ...): an audit row's outcome when the
    /// operation failed. The HTTP status that goes with it is REST's
    /// business (`crate::api::error`).
    pub fn code(&self) -> &'static str {
        match self {
            Self::InvalidRequest(_) => "invalid_request",
            Self::InvalidValue(_) => "invalid_value",
            Self::ValueOutOfRange(_) => "value_out_of_range",
            Self::UnknownBus(_) => "unknown_bus",
            Self::UnknownNode { .. } => "unknown_node",
            Self::WrongNmtState { .. } => "wrong_nmt_state",
            Self::SdoAbort { .. } => "sdo_abort",
            Self::SdoProtocol { .. } => "sdo_protocol_error",
            Self::SdoTimeout { .. } => "sdo_timeout",
            Self::BusDown(_) => "bus_down",
            Self::NodeOffline(_) => "node_offline",
            Self::NotADrive(_) => "not_a_drive",
            Self::UnknownAxis(_) => "unknown_axis",
            Self::DriveFault { .. } => "drive_fault",
            Self::DriveNotEnabled { .. } => "drive_not_enabled",
            Self::ModeNotSupported(_) => "mode_not_supported",
            Self::StateChangeTimeout { .. } => "state_change_timeout",
            Self::LeaseConflict(_) => "lease_conflict",
            Self::UnknownLease(_) => "unknown_lease",
            Self::Unauthenticated(_) => "unauthenticated",
            Self::Forbidden(_) => "forbidden",
            Self::RateLimited { .. } => "rate_limited",
            Self::LssBusy(_) => "lss_busy",
            Self::LssNotFound(_) => "lss_not_found",
            Self::LssTimeout(_) => "lss_timeout",
            Self::LssRefused(_) => "lss_refused",
            Self::NodeIdInUse(_) => "node_id_in_use",
            Self::NodeIdNotSupported(_) => "node_id_change_not_supported",
            Self::UnknownEds(_) => "unknown_eds",
            Self::InvalidEds { .. } => "invalid_eds",
            Self::EdsConflict(_) => "eds_conflict",
            Self::NotAnIoModule(_) => "not_an_io_module",
            Self::UnknownChannel(_) => "unknown_channel",
            Self::ProgramNotVerified(_) => "program_not_verified",
            Self::Internal(_) => "internal_error",
        }
    }

    /// The SDO abort code of a transfer the device (or the gateway, on a
    /// protocol error) aborted.
    pub fn abort_code(&self) -> Option<AbortCode> {
        match self {
            Self::SdoAbort { code, .. } | Self::SdoProtocol { code, .. } => Some(*code),
            _ => None,
        }
    }
}

impl From<SdoRequestError> for GatewayError {
    fn from(error: SdoRequestError) -> Self {
        match error {
            SdoRequestError::Sdo { node, error } => {
                let node = node.get();
                match error {
                    SdoError::ServerAborted(code) => Self::SdoAbort { node, code },
                    SdoError::Timeout => Self::SdoTimeout { node },
                    SdoError::Protocol { code, detail } => Self::SdoProtocol { node, code, detail },
                    SdoError::TooLarge(len) => {
                        Self::InvalidValue(format!("{len} bytes do not fit an SDO transfer"))
                    }
                    // The channel runs one transfer at a time; a busy client
                    // is a fault of the gateway.
                    SdoError::Busy => Self::Internal(format!("node {node}: SDO client busy")),
                }
            }
            SdoRequestError::Bus { error, .. } => Self::from(error),
        }
    }
}

impl From<BusError> for GatewayError {
    fn from(error: BusError) -> Self {
        Self::BusDown(error.to_string())
    }
}

impl From<RegistryError> for GatewayError {
    fn from(error: RegistryError) -> Self {
        match error {
            RegistryError::UnknownNode { bus, node } => Self::UnknownNode {
                bus,
                node: node.to_string(),
            },
            RegistryError::Bus(error) => Self::from(error),
            RegistryError::Sdo(error) => Self::from(error),
            other => Self::Internal(other.to_string()),
        }
    }
}

impl From<DriveError> for GatewayError {
    fn from(error: DriveError) -> Self {
        let state = error.state().map_or("unknown", |s| s.name()).to_string();
        match error {
            DriveError::NotADrive { .. } => Self::NotADrive(error.to_string()),
            DriveError::UnknownAxis { .. } => Self::UnknownAxis(error.to_string()),
            DriveError::Sdo(error) => Self::from(error),
            DriveError::Registry(error) => Self::from(error),
            DriveError::Fault { .. } => Self::DriveFault {
                message: error.to_string(),
                state,
            },
            DriveError::Timeout { .. } => Self::StateChangeTimeout {
                message: error.to_string(),
                state,
            },
            DriveError::ModeNotSupported { .. } | DriveError::NotTunable(_) => {
                Self::ModeNotSupported(error.to_string())
            }
            DriveError::NotEnabled { .. } | DriveError::Interrupted { .. } => {
                Self::DriveNotEnabled {
                    message: error.to_string(),
                    state,
                }
            }
            DriveError::OutOfRange(message) => Self::ValueOutOfRange(message),
            DriveError::Invalid(message) => Self::InvalidValue(message),
        }
    }
}

impl From<LeaseError> for GatewayError {
    fn from(error: LeaseError) -> Self {
        match error {
            LeaseError::Conflict { .. }
            | LeaseError::NotHolder { .. }
            | LeaseError::IdInUse { .. } => Self::LeaseConflict(error.to_string()),
            LeaseError::Unknown(_) => Self::UnknownLease(error.to_string()),
        }
    }
}
