//! A [`GatewayError`] as OPC UA answers it (IEC 62541-4 §7.39, the status
//! codes of Part 6's list): one mapping, each error to the code a client's
//! code already branches on. The error's text (with the SDO abort code and
//! its meaning) goes into the operation's diagnostics where the client asks
//! for them.
//!
//! - The caller's identity: `BadUserAccessDenied` (a role too low, or no
//!   token); the caller's write rate: `BadTooManyOperations`.
//! - What the device would answer for the object or value: the abort code's
//!   closest status (`BadNotWritable`, `BadNotReadable`, `BadTypeMismatch`,
//!   `BadOutOfRange`, `BadNodeIdUnknown`, `BadInvalidState`), any other
//!   abort `BadDeviceFailure`.
//! - A value or argument the gateway refuses before the device sees it:
//!   `BadTypeMismatch`, `BadOutOfRange`, `BadInvalidArgument`.
//! - Something that is not there (a node, an axis, a lease): `BadNotFound`;
//!   what the node cannot do: `BadNotSupported`.
//! - A refusal for a state of the drive, the node, the bus or the gateway:
//!   `BadInvalidState`; a node that does not answer: `BadTimeout`, one that
//!   is offline or a bus that is down: `BadNoCommunication`.

use crate::canopen::sdo::AbortCode;
use crate::gateway::GatewayError;
use crate::gateway::{LedError, PdoError, SimError};
use opcua::types::{DiagnosticInfo, StatusCode};

/// The status of an abort the device sent.
fn of_abort(code: AbortCode) -> StatusCode {
    match code {
        AbortCode::ReadOnlyObject => StatusCode::BadNotWritable,
        AbortCode::WriteOnlyObject => StatusCode::BadNotReadable,
        AbortCode::ObjectDoesNotExist | AbortCode::SubIndexDoesNotExist => {
            StatusCode::BadNodeIdUnknown
        }
        AbortCode::LengthMismatch | AbortCode::LengthTooHigh | AbortCode::LengthTooLow => {
            StatusCode::BadTypeMismatch
        }
        AbortCode::InvalidValue
        | AbortCode::ValueTooHigh
        | AbortCode::ValueTooLow
        | AbortCode::MaxLessThanMin => StatusCode::BadOutOfRange,
        AbortCode::CannotStoreLocalControl | AbortCode::CannotStoreDeviceState => {
            StatusCode::BadInvalidState
        }
        AbortCode::TimedOut => StatusCode::BadTimeout,
        _ => StatusCode::BadDeviceFailure,
    }
}

/// A gateway error as OPC UA says it. No wildcard: a new error does not
/// compile until it is given its status here.
pub fn status_of(error: &GatewayError) -> StatusCode {
    match error {
        GatewayError::SdoAbort { code, .. } => of_abort(*code),
        GatewayError::SdoProtocol { .. } => StatusCode::BadCommunicationError,
        GatewayError::SdoTimeout { .. }
        | GatewayError::StateChangeTimeout { .. }
        | GatewayError::LssTimeout(_) => StatusCode::BadTimeout,
        GatewayError::FailedAt { source, .. } | GatewayError::StopNotConfirmed { source, .. } => {
            status_of(source)
        }
        GatewayError::Unauthenticated(_)
        | GatewayError::Forbidden(_)
        | GatewayError::WatchdogProtected(_) => StatusCode::BadUserAccessDenied,
        GatewayError::RateLimited { .. } => StatusCode::BadTooManyOperations,
        GatewayError::InvalidValue(_) => StatusCode::BadTypeMismatch,
        GatewayError::ValueOutOfRange(_) | GatewayError::StepBeyondFollowingWindow(_) => {
            StatusCode::BadOutOfRange
        }
        GatewayError::InvalidRequest(_)
        | GatewayError::InvalidIndex(_)
        | GatewayError::InvalidDcf { .. }
        | GatewayError::InvalidEds { .. }
        | GatewayError::TooManyEntries(_)
        | GatewayError::Pdo(PdoError::InvalidMapping(_)) => StatusCode::BadInvalidArgument,
        GatewayError::CommandTooLarge { .. } => StatusCode::BadRequestTooLarge,
        GatewayError::UnknownObject(_) | GatewayError::UnknownSubObject(_) => {
            StatusCode::BadNodeIdUnknown
        }
        GatewayError::UnknownBus(_)
        | GatewayError::UnknownNode { .. }
        | GatewayError::UnknownAxis(_)
        | GatewayError::UnknownLease(_)
        | GatewayError::UnknownEds(_)
        | GatewayError::UnknownChannel(_)
        | GatewayError::UnknownLogger(_)
        | GatewayError::UnknownAlarm(_)
        | GatewayError::NoRecording(_)
        | GatewayError::LssNotFound(_)
        | GatewayError::Pdo(PdoError::UnknownPdo(_))
        | GatewayError::Led(LedError::UnknownSegment(_))
        | GatewayError::Sim(SimError::UnknownDevice { .. }) => StatusCode::BadNotFound,
        GatewayError::NotADrive(_)
        | GatewayError::ModeNotSupported(_)
        | GatewayError::NotAnIoModule(_)
        | GatewayError::NotLoggable(_)
        | GatewayError::NodeIdNotSupported(_)
        | GatewayError::Led(LedError::NotAnLedController(_))
        | GatewayError::Sim(SimError::NotVirtual(_) | SimError::FaultNotApplicable(_)) => {
            StatusCode::BadNotSupported
        }
        GatewayError::BusDown(_) | GatewayError::NodeOffline(_) => StatusCode::BadNoCommunication,
        GatewayError::WrongNmtState { .. }
        | GatewayError::DriveFault { .. }
        | GatewayError::DriveNotEnabled { .. }
        | GatewayError::LeaseConflict(_)
        | GatewayError::MotionStopped(_)
        | GatewayError::NodeBusy(_)
        | GatewayError::AxisEnabled(_)
        | GatewayError::LssBusy(_)
        | GatewayError::LssRefused(_)
        | GatewayError::NodeIdInUse(_)
        | GatewayError::EdsConflict(_)
        | GatewayError::Pdo(PdoError::PdoDisabled(_))
        | GatewayError::Sim(SimError::NodeTaken(_))
        | GatewayError::RecordingRunning(_)
        | GatewayError::RecordingNotRunning(_)
        | GatewayError::ProgramNotVerified(_) => StatusCode::BadInvalidState,
        GatewayError::EdsQuota(_) | GatewayError::TooManyLoggers(_) => {
            StatusCode::BadResourceUnavailable
        }
        GatewayError::ClientGone(_) => StatusCode::BadRequestInterrupted,
        GatewayError::RecordingFailed(_)
        | GatewayError::HistoryFailed(_)
        | GatewayError::Internal(_) => StatusCode::BadInternalError,
    }
}

/// The operation's diagnostics for `error` (a write's, a call's): the
/// error's text, with the SDO abort's code and meaning where the device
/// aborted, so that a client sees why the device refused.
pub fn diagnostic_of(error: &GatewayError) -> DiagnosticInfo {
    let text = match error.abort_code() {
        Some(code) => format!("SDO abort 0x{:08X}: {} ({error})", code.raw(), code.text()),
        None => error.to_string(),
    };
    DiagnosticInfo {
        additional_info: Some(text.into()),
        inner_status_code: Some(status_of(error)),
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_device_abort_is_in_the_diagnostics_with_its_code_and_text() {
        let error = GatewayError::FailedAt {
            step: "write".into(),
            source: Box::new(GatewayError::SdoAbort {
                node: 3,
                code: AbortCode::from_raw(0x0601_0002),
            }),
        };
        let info = diagnostic_of(&error);
        let text = info.additional_info.expect("additional info");
        assert!(
            text.as_ref().starts_with("SDO abort 0x06010002: "),
            "{text}"
        );
        assert!(
            text.as_ref().contains(AbortCode::ReadOnlyObject.text()),
            "{text}"
        );
        assert_eq!(info.inner_status_code, Some(StatusCode::BadNotWritable));
        let refused = diagnostic_of(&GatewayError::ValueOutOfRange(
            "0x1017: 70000 > 65535".into(),
        ));
        assert!(refused.additional_info.unwrap().as_ref().contains("70000"),);
    }

    #[test]
    fn every_gateway_error_has_a_bad_status() {
        let samples = crate::error_samples::samples();
        assert_eq!(samples.len(), crate::error_samples::VARIANTS);
        for error in &samples {
            let status = status_of(error);
            assert!(status.is_bad(), "{error:?} maps to {status}");
        }
    }

    #[test]
    fn refusals_of_the_caller_and_of_values_get_the_codes_clients_branch_on() {
        let text = || "text".to_string();
        let cases = [
            (
                GatewayError::Forbidden(text()),
                StatusCode::BadUserAccessDenied,
            ),
            (
                GatewayError::Unauthenticated(text()),
                StatusCode::BadUserAccessDenied,
            ),
            (
                GatewayError::RateLimited {
                    message: text(),
                    retry_after_s: 1,
                },
                StatusCode::BadTooManyOperations,
            ),
            (
                GatewayError::InvalidValue(text()),
                StatusCode::BadTypeMismatch,
            ),
            (
                GatewayError::ValueOutOfRange(text()),
                StatusCode::BadOutOfRange,
            ),
            (
                GatewayError::DriveFault {
                    message: text(),
                    state: "fault".into(),
                },
                StatusCode::BadInvalidState,
            ),
            (GatewayError::SdoTimeout { node: 3 }, StatusCode::BadTimeout),
            (
                GatewayError::NodeOffline(text()),
                StatusCode::BadNoCommunication,
            ),
        ];
        for (error, status) in cases {
            assert_eq!(status_of(&error), status, "{error:?}");
        }
    }

    #[test]
    fn a_device_abort_maps_by_its_code_and_a_failed_step_as_its_cause() {
        let abort = |raw| GatewayError::SdoAbort {
            node: 3,
            code: AbortCode::from_raw(raw),
        };
        assert_eq!(status_of(&abort(0x0601_0002)), StatusCode::BadNotWritable);
        assert_eq!(status_of(&abort(0x0601_0001)), StatusCode::BadNotReadable);
        assert_eq!(status_of(&abort(0x0607_0010)), StatusCode::BadTypeMismatch);
        assert_eq!(status_of(&abort(0x0609_0031)), StatusCode::BadOutOfRange);
        assert_eq!(status_of(&abort(0x0800_0022)), StatusCode::BadInvalidState);
        assert_eq!(status_of(&abort(0x0606_0000)), StatusCode::BadDeviceFailure);
        let step = GatewayError::FailedAt {
            step: "write".into(),
            source: Box::new(abort(0x0601_0002)),
        };
        assert_eq!(status_of(&step), StatusCode::BadNotWritable);
    }
}
