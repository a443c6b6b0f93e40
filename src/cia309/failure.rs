//! A [`GatewayError`] as CiA 309 says it, for both of its doors (309-3
//! replies `ERROR:<number>` or `ERROR:0x<abort code>`, 309-5 the same in
//! its JSON): one mapping, each error to the closest answer CiA 309-1
//! §5 / 309-3 §8 has.
//!
//! - What the device would answer for the same object or value (an object
//!   it does not have, a value out of range, an object it cannot map) is
//!   its abort code: a CiA 309 client reads it as if the device had said it.
//! - A node, a net, a time-out, an NMT state: their error numbers (107,
//!   106, 103, 204; 203 for a node whose heartbeat is lost).
//! - A request the node cannot serve (no drive, no LED segment, no such
//!   channel): 100, request not supported; one that cannot be read: 101.
//! - A request refused for a state of the gateway or of the device (a
//!   lease held by another, a drive in fault, a recording running, the
//!   caller's role or rate) and a fault of the gateway itself: 102,
//!   "request not processed due to internal state", which says exactly
//!   that.

use crate::canopen::sdo::AbortCode;
use crate::gateway::GatewayError;
use crate::gateway::{LedError, PdoError, SimError};

use super::reply::ErrorCode;

/// Why a request failed, as CiA 309 answers it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Failure {
    /// `ERROR:0x<abort code>`: the device's abort, or the client's
    /// (0x05040000 on a timeout).
    Abort(AbortCode),
    /// `ERROR:<number>`.
    Error(ErrorCode),
}

/// CiA 301 abort codes (§7.2.4.3.17) the gateway answers with for a device.
const TIMED_OUT: u32 = 0x0504_0000;
const NO_OBJECT: u32 = 0x0602_0000;
const NOT_MAPPABLE: u32 = 0x0604_0041;
const TYPE_MISMATCH: u32 = 0x0607_0010;
const NO_SUB_INDEX: u32 = 0x0609_0011;
const VALUE_RANGE: u32 = 0x0609_0030;
const NOT_STORED: u32 = 0x0800_0020;
const DEVICE_STATE: u32 = 0x0800_0022;

impl Failure {
    /// A gateway error as CiA 309 says it. No wildcard: a new error does
    /// not compile until it is given its answer here.
    pub fn of(error: &GatewayError) -> Self {
        use ErrorCode::*;
        let abort = |raw| Self::Abort(AbortCode::from_raw(raw));
        match error {
            GatewayError::SdoAbort { code, .. } | GatewayError::SdoProtocol { code, .. } => {
                Self::Abort(*code)
            }
            GatewayError::SdoTimeout { .. } => abort(TIMED_OUT),
            GatewayError::FailedAt { source, .. }
            | GatewayError::StopNotConfirmed { source, .. } => Self::of(source),
            // What the device would answer for the object or value.
            GatewayError::UnknownObject(_) | GatewayError::Pdo(PdoError::UnknownPdo(_)) => {
                abort(NO_OBJECT)
            }
            GatewayError::UnknownSubObject(_) => abort(NO_SUB_INDEX),
            GatewayError::InvalidValue(_) => abort(TYPE_MISMATCH),
            GatewayError::ValueOutOfRange(_) => abort(VALUE_RANGE),
            GatewayError::Pdo(PdoError::InvalidMapping(_)) => abort(NOT_MAPPABLE),
            GatewayError::Pdo(PdoError::PdoDisabled(_)) => abort(DEVICE_STATE),
            GatewayError::ProgramNotVerified(_) => abort(NOT_STORED),
            // The node, the net, the clock, the NMT state.
            GatewayError::UnknownNode { .. }
            | GatewayError::InvalidRequest(_)
            | GatewayError::LssNotFound(_)
            | GatewayError::Sim(SimError::UnknownDevice { .. }) => Self::Error(UnsupportedNode),
            GatewayError::UnknownBus(_) => Self::Error(UnsupportedNet),
            GatewayError::StateChangeTimeout { .. } | GatewayError::LssTimeout(_) => {
                Self::Error(TimeOut)
            }
            GatewayError::WrongNmtState { .. } => Self::Error(WrongNmtState),
            GatewayError::NodeOffline(_) => Self::Error(HeartbeatLost),
            // What the node (or the bus) cannot serve.
            GatewayError::NotADrive(_)
            | GatewayError::UnknownAxis(_)
            | GatewayError::ModeNotSupported(_)
            | GatewayError::StepBeyondFollowingWindow(_)
            | GatewayError::NotAnIoModule(_)
            | GatewayError::UnknownChannel(_)
            | GatewayError::Led(LedError::NotAnLedController(_) | LedError::UnknownSegment(_))
            | GatewayError::Sim(SimError::NotVirtual(_) | SimError::FaultNotApplicable(_))
            | GatewayError::NodeIdNotSupported(_)
            | GatewayError::UnknownLease(_)
            | GatewayError::UnknownEds(_)
            | GatewayError::NoRecording(_)
            | GatewayError::UnknownLogger(_)
            | GatewayError::UnknownAlarm(_)
            | GatewayError::NotLoggable(_) => Self::Error(RequestNotSupported),
            // What cannot be read.
            GatewayError::InvalidIndex(_)
            | GatewayError::InvalidDcf { .. }
            | GatewayError::InvalidEds { .. }
            | GatewayError::TooManyEntries(_)
            | GatewayError::CommandTooLarge { .. } => Self::Error(Syntax),
            // Refused for a state (the gateway's, the device's, the
            // caller's), or a fault of the gateway.
            GatewayError::BusDown(_)
            | GatewayError::DriveFault { .. }
            | GatewayError::DriveNotEnabled { .. }
            | GatewayError::LeaseConflict(_)
            | GatewayError::MotionStopped(_)
            | GatewayError::NodeBusy(_)
            | GatewayError::AxisEnabled(_)
            | GatewayError::ClientGone(_)
            | GatewayError::Unauthenticated(_)
            | GatewayError::Forbidden(_)
            | GatewayError::WatchdogProtected(_)
            | GatewayError::RateLimited { .. }
            | GatewayError::LssBusy(_)
            | GatewayError::LssRefused(_)
            | GatewayError::NodeIdInUse(_)
            | GatewayError::EdsConflict(_)
            | GatewayError::EdsQuota(_)
            | GatewayError::Sim(SimError::NodeTaken(_))
            | GatewayError::RecordingRunning(_)
            | GatewayError::RecordingNotRunning(_)
            | GatewayError::TooManyLoggers(_)
            | GatewayError::RecordingFailed(_)
            | GatewayError::HistoryFailed(_)
            | GatewayError::Internal(_) => Self::Error(InternalState),
        }
    }
}

#[cfg(test)]
mod tests;
