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
use crate::canopen::od::{DictionaryError, ValueError};
use crate::canopen::sdo::{AbortCode, SdoError};

use super::drive::DriveError;
use super::logger::LoggerError;
use super::motion_lease::LeaseError;
use super::recording::RecordingError;
use super::registry::RegistryError;
use super::safe_stop::StopAttempt;
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
    /// A position step test whose step (or move to its start) is not
    /// inside the drive's following error window (0x6065): the drive would
    /// fault on it.
    #[error("{0}")]
    StepBeyondFollowingWindow(String),
    /// The drive did not reach a state (mode, acknowledge) in time.
    #[error("{message}")]
    StateChangeTimeout { message: String, state: String },
    /// The axis is held by another client's motion lease.
    #[error("{0}")]
    LeaseConflict(String),
    /// A lease that is not held (lapsed, ended, or never granted).
    #[error("{0}")]
    UnknownLease(String),
    /// A motion command admitted before a stop of its axis: not sent
    /// (`crate::authority`).
    #[error("{0}")]
    MotionStopped(String),
    /// The node runs something that excludes the request (a program
    /// download): motion commands and a second download wait for its end.
    #[error("{0}")]
    NodeBusy(String),
    /// An axis of the node is enabled or moving: a program download (or a
    /// write that would change its motion) is refused until it is stopped.
    #[error("{0}")]
    AxisEnabled(String),
    /// The client of a sequence went away before a step that needs it
    /// there (a program's start): the step was not sent.
    #[error("{0}")]
    ClientGone(String),
    /// No token, or one the gateway does not know, where it asks for one.
    #[error("{0}")]
    Unauthenticated(String),
    /// The client's role is below what the request needs.
    #[error("{0}")]
    Forbidden(String),
    /// A write that would switch off a device's protection against the
    /// gateway's death (docs/security.md, "Watchdog policy"): an admin's
    /// only.
    #[error("{0}")]
    WatchdogProtected(String),
    /// The token sends writes faster than its rate limit
    /// (`crate::access::WriteLimiter`).
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
    /// An upload that would take the uploaded EDS files over their quota
    /// (count or bytes, `crate::profile::EdsQuota`).
    #[error("{0}")]
    EdsQuota(String),
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
    /// An object index (or sub-index) that is no number or name.
    #[error("{0}")]
    InvalidIndex(String),
    /// An object the node's dictionary does not have (or a node without
    /// EDS, whose objects are not known).
    #[error("{0}")]
    UnknownObject(String),
    #[error("{0}")]
    UnknownSubObject(String),
    /// A request with more entries (a batch, a logger's channels) than one
    /// may carry.
    #[error("{0}")]
    TooManyEntries(String),
    /// A command larger than a door takes (a Sparkplug command message
    /// over its byte limit): refused whole, nothing of it run.
    #[error("{size} bytes: over the limit of {limit} bytes for one command")]
    CommandTooLarge { size: usize, limit: usize },
    /// A node's PDOs.
    #[error(transparent)]
    Pdo(#[from] PdoError),
    /// A node's LED segments.
    #[error(transparent)]
    Led(#[from] LedError),
    /// The virtual devices of a bus.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// A DCF that cannot be read or does not fit the node; nothing was
    /// written.
    #[error("{message}")]
    InvalidDcf {
        message: String,
        line: Option<usize>,
    },
    /// A sequence of transfers stopped at `step`: the error of that step,
    /// with the step named (the steps before it took effect).
    #[error("step {step} failed: {source}")]
    FailedAt {
        step: String,
        source: Box<GatewayError>,
    },
    /// A stop the drive did not confirm: the error of the stop asked for,
    /// with every step tried (the fallbacks included) and its outcome.
    #[error("{source}")]
    StopNotConfirmed {
        source: Box<GatewayError>,
        attempts: Vec<StopAttempt>,
    },
    /// A recording of the bus runs already.
    #[error("{0}")]
    RecordingRunning(String),
    /// The bus's recording has stopped already.
    #[error("{0}")]
    RecordingNotRunning(String),
    /// The bus has no recording (none since the gateway started, or its
    /// file is gone).
    #[error("{0}")]
    NoRecording(String),
    /// The recording's file could not be made or read (disk full, no
    /// permission): the gateway's machine, not the request.
    #[error("{0}")]
    RecordingFailed(String),
    /// No data logger has this id.
    #[error("{0}")]
    UnknownLogger(String),
    /// Every data logger kept still runs.
    #[error("{0}")]
    TooManyLoggers(String),
    /// An object a data logger cannot sample (write-only, no number).
    #[error("{0}")]
    NotLoggable(String),
    /// The history database failed (disk full, file damaged): the
    /// gateway's machine, not the request.
    #[error("{0}")]
    HistoryFailed(String),
    /// No alarm has this id (or it went back to normal long ago and only
    /// the history database keeps it).
    #[error("{0}")]
    UnknownAlarm(String),
    /// A fault of the gateway itself; the detail is for the log.
    #[error("{0}")]
    Internal(String),
}

impl GatewayError {
    /// The error's code, as every door names it (REST's `code`, the audit
    /// log's): `sdo_abort`, `bus_down`, ... A failed step's and an
    /// unconfirmed stop's are their cause's.
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
            Self::StepBeyondFollowingWindow(_) => "step_beyond_following_window",
            Self::StateChangeTimeout { .. } => "state_change_timeout",
            Self::LeaseConflict(_) => "lease_conflict",
            Self::UnknownLease(_) => "unknown_lease",
            Self::MotionStopped(_) => "motion_stopped",
            Self::NodeBusy(_) => "node_busy",
            Self::AxisEnabled(_) => "axis_enabled",
            Self::ClientGone(_) => "client_gone",
            Self::Unauthenticated(_) => "unauthenticated",
            Self::Forbidden(_) => "forbidden",
            Self::WatchdogProtected(_) => "watchdog_protected",
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
            Self::EdsQuota(_) => "eds_quota",
            Self::NotAnIoModule(_) => "not_an_io_module",
            Self::UnknownChannel(_) => "unknown_channel",
            Self::ProgramNotVerified(_) => "program_not_verified",
            Self::InvalidIndex(_) => "invalid_index",
            Self::UnknownObject(_) => "unknown_object",
            Self::UnknownSubObject(_) => "unknown_sub_object",
            Self::TooManyEntries(_) => "too_many_entries",
            Self::CommandTooLarge { .. } => "command_too_large",
            Self::Pdo(PdoError::UnknownPdo(_)) => "unknown_pdo",
            Self::Pdo(PdoError::InvalidMapping(_)) => "invalid_mapping",
            Self::Pdo(PdoError::PdoDisabled(_)) => "pdo_disabled",
            Self::Led(LedError::NotAnLedController(_)) => "not_an_led_controller",
            Self::Led(LedError::UnknownSegment(_)) => "unknown_segment",
            Self::Sim(SimError::NotVirtual(_)) => "not_virtual",
            // A virtual device is a node of its bus.
            Self::Sim(SimError::UnknownDevice { .. }) => "unknown_node",
            Self::Sim(SimError::NodeTaken(_)) => "node_taken",
            Self::Sim(SimError::FaultNotApplicable(_)) => "fault_not_applicable",
            Self::InvalidDcf { .. } => "invalid_dcf",
            Self::FailedAt { source, .. } | Self::StopNotConfirmed { source, .. } => source.code(),
            Self::RecordingRunning(_) => "recording_running",
            Self::RecordingNotRunning(_) => "recording_not_running",
            Self::NoRecording(_) => "no_recording",
            Self::RecordingFailed(_) => "recording_failed",
            Self::UnknownLogger(_) => "unknown_logger",
            Self::UnknownAlarm(_) => "unknown_alarm",
            Self::TooManyLoggers(_) => "too_many_loggers",
            Self::NotLoggable(_) => "not_loggable",
            Self::HistoryFailed(_) => "history_failed",
            Self::Internal(_) => "internal_error",
        }
    }

    /// The SDO abort code of a transfer the device (or the gateway, on a
    /// protocol error) aborted.
    pub fn abort_code(&self) -> Option<AbortCode> {
        match self {
            Self::SdoAbort { code, .. } | Self::SdoProtocol { code, .. } => Some(*code),
            Self::FailedAt { source, .. } | Self::StopNotConfirmed { source, .. } => {
                source.abort_code()
            }
            _ => None,
        }
    }
}

/// Why a request about a node's PDOs failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PdoError {
    /// A PDO number (or kind) the node does not have.
    #[error("{0}")]
    UnknownPdo(String),
    /// A PDO mapping or communication parameter the node's EDS rules out
    /// (or a node without EDS, whose mapping cannot be checked).
    #[error("{0}")]
    InvalidMapping(String),
    /// The PDO is not valid (COB-ID bit 31 set): the node ignores its frames.
    #[error("{0}")]
    PdoDisabled(String),
}

/// Why a request about a node's LED segments failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LedError {
    /// The node has no segments (its profile is not uioled).
    #[error("{0}")]
    NotAnLedController(String),
    #[error("{0}")]
    UnknownSegment(String),
}

/// Why a request about the virtual devices of a bus failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SimError {
    /// The bus has no virtual devices.
    #[error("bus {0} is no virtual bus: it has no virtual devices to control")]
    NotVirtual(String),
    /// No virtual device at this node id of a virtual bus.
    #[error("no virtual device is at node {node} of bus {bus}")]
    UnknownDevice { bus: String, node: u8 },
    /// A virtual device is added at a node id another one has.
    #[error("{0}")]
    NodeTaken(String),
    /// The virtual device's product cannot have this fault.
    #[error("{0}")]
    FaultNotApplicable(String),
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
            DriveError::StepBeyondFollowingWindow(message) => {
                Self::StepBeyondFollowingWindow(message)
            }
            DriveError::Invalid(message) => Self::InvalidValue(message),
            DriveError::Stopped(message) => Self::MotionStopped(message),
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

impl From<DictionaryError> for GatewayError {
    fn from(error: DictionaryError) -> Self {
        match error {
            DictionaryError::UnknownObject(_) | DictionaryError::UnknownName(_) => {
                Self::UnknownObject(error.to_string())
            }
            DictionaryError::UnknownSubObject { .. } | DictionaryError::UnknownSubName { .. } => {
                Self::UnknownSubObject(error.to_string())
            }
            DictionaryError::InvalidIndex(_) | DictionaryError::InvalidSubIndex(_) => {
                Self::InvalidIndex(error.to_string())
            }
            DictionaryError::WrongType { .. } => Self::InvalidValue(error.to_string()),
        }
    }
}

impl From<ValueError> for GatewayError {
    fn from(error: ValueError) -> Self {
        if error.is_out_of_range() {
            Self::ValueOutOfRange(error.to_string())
        } else {
            Self::InvalidValue(error.to_string())
        }
    }
}

impl From<RecordingError> for GatewayError {
    fn from(error: RecordingError) -> Self {
        let message = error.to_string();
        match error {
            RecordingError::LimitOutOfRange { .. } => Self::ValueOutOfRange(message),
            RecordingError::Running { .. } => Self::RecordingRunning(message),
            RecordingError::NotRunning { .. } => Self::RecordingNotRunning(message),
            RecordingError::NoRecording(_) => Self::NoRecording(message),
            RecordingError::Io { .. } => {
                tracing::error!("recording: {message}");
                Self::RecordingFailed(message)
            }
        }
    }
}

/// A logger's errors; a channel's say which channel (0-based).
impl From<LoggerError> for GatewayError {
    fn from(error: LoggerError) -> Self {
        let message = error.to_string();
        match error {
            LoggerError::ChannelCount(_) => Self::TooManyEntries(message),
            LoggerError::Period(_) | LoggerError::Duration(_) => Self::ValueOutOfRange(message),
            LoggerError::Channel { .. } => Self::InvalidIndex(message),
            LoggerError::NotLoggable { .. } => Self::NotLoggable(message),
            LoggerError::Dictionary { source, .. } => match Self::from(source) {
                Self::UnknownObject(_) => Self::UnknownObject(message),
                Self::UnknownSubObject(_) => Self::UnknownSubObject(message),
                Self::InvalidIndex(_) => Self::InvalidIndex(message),
                other => other,
            },
            // The gateway's own words (unknown_bus, unknown_node, an SDO
            // error of a trial read), with the channel's number.
            LoggerError::Gateway { channel, source } => match source {
                Self::FailedAt { .. } => Self::Internal(message),
                other => Self::FailedAt {
                    step: format!("channel {channel}"),
                    source: Box::new(other),
                },
            },
            LoggerError::TooMany => Self::TooManyLoggers(message),
            LoggerError::Unknown(_) => Self::UnknownLogger(message),
        }
    }
}
