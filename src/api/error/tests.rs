use super::*;
use crate::canopen::nmt::NmtState;
use crate::canopen::sdo::AbortCode;
use crate::gateway::{LedError, PdoError, SimError};

/// Every variant of [`GatewayError`], by number (no wildcard: a new
/// variant does not compile until it is numbered here, and then the test
/// below wants a sample of it).
fn variant(error: &GatewayError) -> usize {
    match error {
        GatewayError::InvalidRequest(_) => 0,
        GatewayError::InvalidValue(_) => 1,
        GatewayError::ValueOutOfRange(_) => 2,
        GatewayError::UnknownBus(_) => 3,
        GatewayError::UnknownNode { .. } => 4,
        GatewayError::WrongNmtState { .. } => 5,
        GatewayError::SdoAbort { .. } => 6,
        GatewayError::SdoProtocol { .. } => 7,
        GatewayError::SdoTimeout { .. } => 8,
        GatewayError::BusDown(_) => 9,
        GatewayError::NodeOffline(_) => 10,
        GatewayError::NotADrive(_) => 11,
        GatewayError::UnknownAxis(_) => 12,
        GatewayError::DriveFault { .. } => 13,
        GatewayError::DriveNotEnabled { .. } => 14,
        GatewayError::ModeNotSupported(_) => 15,
        GatewayError::StateChangeTimeout { .. } => 16,
        GatewayError::LeaseConflict(_) => 17,
        GatewayError::UnknownLease(_) => 18,
        GatewayError::Unauthenticated(_) => 19,
        GatewayError::Forbidden(_) => 20,
        GatewayError::Internal(_) => 21,
        GatewayError::RateLimited { .. } => 22,
        GatewayError::LssBusy(_) => 23,
        GatewayError::LssNotFound(_) => 24,
        GatewayError::LssTimeout(_) => 25,
        GatewayError::LssRefused(_) => 26,
        GatewayError::NodeIdInUse(_) => 27,
        GatewayError::NodeIdNotSupported(_) => 28,
        GatewayError::UnknownEds(_) => 29,
        GatewayError::InvalidEds { .. } => 30,
        GatewayError::EdsConflict(_) => 31,
        GatewayError::NotAnIoModule(_) => 32,
        GatewayError::UnknownChannel(_) => 33,
        GatewayError::ProgramNotVerified(_) => 34,
        GatewayError::InvalidIndex(_) => 35,
        GatewayError::UnknownObject(_) => 36,
        GatewayError::UnknownSubObject(_) => 37,
        GatewayError::TooManyEntries(_) => 38,
        GatewayError::Pdo(PdoError::UnknownPdo(_)) => 39,
        GatewayError::Pdo(PdoError::InvalidMapping(_)) => 40,
        GatewayError::Pdo(PdoError::PdoDisabled(_)) => 41,
        GatewayError::Led(LedError::NotAnLedController(_)) => 42,
        GatewayError::Led(LedError::UnknownSegment(_)) => 43,
        GatewayError::Sim(SimError::NotVirtual(_)) => 44,
        GatewayError::Sim(SimError::UnknownDevice { .. }) => 45,
        GatewayError::Sim(SimError::NodeTaken(_)) => 46,
        GatewayError::Sim(SimError::FaultNotApplicable(_)) => 47,
        GatewayError::InvalidDcf { .. } => 48,
        GatewayError::FailedAt { .. } => 49,
        GatewayError::StopNotConfirmed { .. } => 50,
        GatewayError::RecordingRunning(_) => 51,
        GatewayError::RecordingNotRunning(_) => 52,
        GatewayError::NoRecording(_) => 53,
        GatewayError::RecordingFailed(_) => 54,
        GatewayError::UnknownLogger(_) => 55,
        GatewayError::TooManyLoggers(_) => 56,
        GatewayError::NotLoggable(_) => 57,
        GatewayError::HistoryFailed(_) => 58,
        GatewayError::MotionStopped(_) => 59,
        GatewayError::NodeBusy(_) => 60,
        GatewayError::AxisEnabled(_) => 61,
        GatewayError::ClientGone(_) => 62,
        GatewayError::EdsQuota(_) => 63,
        GatewayError::UnknownAlarm(_) => 64,
        GatewayError::WatchdogProtected(_) => 65,
        GatewayError::StepBeyondFollowingWindow(_) => 66,
        GatewayError::CommandTooLarge { .. } => 67,
    }
}

pub(crate) const VARIANTS: usize = 68;

pub(crate) fn samples() -> Vec<GatewayError> {
    let text = || "text".to_string();
    let abort = AbortCode::from_raw(0x0609_0011);
    vec![
        GatewayError::InvalidRequest(text()),
        GatewayError::InvalidValue(text()),
        GatewayError::ValueOutOfRange(text()),
        GatewayError::UnknownBus("can9".to_string()),
        GatewayError::UnknownNode {
            bus: "demo".to_string(),
            node: "9".to_string(),
        },
        GatewayError::WrongNmtState {
            node: 3,
            state: NmtState::Stopped,
        },
        GatewayError::SdoAbort {
            node: 3,
            code: abort,
        },
        GatewayError::SdoProtocol {
            node: 3,
            code: AbortCode::from_raw(0x0504_0001),
            detail: text(),
        },
        GatewayError::SdoTimeout { node: 3 },
        GatewayError::BusDown(text()),
        GatewayError::NodeOffline(text()),
        GatewayError::NotADrive(text()),
        GatewayError::UnknownAxis(text()),
        GatewayError::DriveFault {
            message: text(),
            state: "fault".to_string(),
        },
        GatewayError::DriveNotEnabled {
            message: text(),
            state: "switched_on".to_string(),
        },
        GatewayError::ModeNotSupported(text()),
        GatewayError::StepBeyondFollowingWindow(text()),
        GatewayError::StateChangeTimeout {
            message: text(),
            state: "ready_to_switch_on".to_string(),
        },
        GatewayError::LeaseConflict(text()),
        GatewayError::MotionStopped(text()),
        GatewayError::NodeBusy(text()),
        GatewayError::AxisEnabled(text()),
        GatewayError::ClientGone(text()),
        GatewayError::LssBusy(text()),
        GatewayError::LssNotFound(text()),
        GatewayError::LssTimeout(text()),
        GatewayError::LssRefused(text()),
        GatewayError::NodeIdInUse(text()),
        GatewayError::NodeIdNotSupported(text()),
        GatewayError::UnknownLease(text()),
        GatewayError::Unauthenticated(text()),
        GatewayError::Forbidden(text()),
        GatewayError::WatchdogProtected(text()),
        GatewayError::Internal(text()),
        GatewayError::ProgramNotVerified(text()),
        GatewayError::RateLimited {
            message: text(),
            retry_after_s: 2,
        },
        GatewayError::UnknownEds("x.eds".to_string()),
        GatewayError::InvalidEds {
            message: text(),
            line: Some(3),
        },
        GatewayError::EdsConflict(text()),
        GatewayError::EdsQuota(text()),
        GatewayError::NotAnIoModule(text()),
        GatewayError::UnknownChannel(text()),
        GatewayError::InvalidIndex(text()),
        GatewayError::UnknownObject(text()),
        GatewayError::UnknownSubObject(text()),
        GatewayError::TooManyEntries(text()),
        GatewayError::CommandTooLarge {
            size: 70_000,
            limit: 65_536,
        },
        PdoError::UnknownPdo(text()).into(),
        PdoError::InvalidMapping(text()).into(),
        PdoError::PdoDisabled(text()).into(),
        LedError::NotAnLedController(text()).into(),
        LedError::UnknownSegment(text()).into(),
        SimError::NotVirtual("demo".to_string()).into(),
        SimError::UnknownDevice {
            bus: "demo".to_string(),
            node: 9,
        }
        .into(),
        SimError::NodeTaken(text()).into(),
        SimError::FaultNotApplicable(text()).into(),
        GatewayError::InvalidDcf {
            message: text(),
            line: Some(12),
        },
        GatewayError::FailedAt {
            step: "clear the mapping".to_string(),
            source: Box::new(GatewayError::SdoAbort {
                node: 3,
                code: abort,
            }),
        },
        GatewayError::StopNotConfirmed {
            source: Box::new(GatewayError::SdoTimeout { node: 3 }),
            attempts: Vec::new(),
        },
        GatewayError::RecordingRunning(text()),
        GatewayError::RecordingNotRunning(text()),
        GatewayError::NoRecording(text()),
        GatewayError::RecordingFailed(text()),
        GatewayError::UnknownLogger(text()),
        GatewayError::TooManyLoggers(text()),
        GatewayError::NotLoggable(text()),
        GatewayError::HistoryFailed(text()),
        GatewayError::UnknownAlarm(text()),
    ]
}

/// The audit log records a gateway error (a CiA 309 request, a lapsed
/// lease) with the code REST answers the same error with.
#[test]
fn the_gateway_errors_audit_as_rest_answers_them() {
    let samples = samples();
    let mut seen: Vec<usize> = samples.iter().map(variant).collect();
    seen.sort_unstable();
    seen.dedup();
    assert_eq!(
        seen,
        (0..VARIANTS).collect::<Vec<_>>(),
        "a variant has no sample"
    );
    for error in samples {
        let rest = AppError::from(error.clone());
        let body = rest.to_json();
        assert_eq!(error.code(), body["code"].as_str().unwrap(), "{error:?}");
        assert_eq!(
            error
                .abort_code()
                .map(|code| format!("0x{:08X}", code.raw())),
            body["abort_code"].as_str().map(str::to_string),
            "{error:?}"
        );
    }
}

/// The REST messages are the gateway's, but for the hint of where to look
/// for a node the registry does not know.
#[test]
fn rest_keeps_the_gateway_s_message() {
    for error in samples() {
        let rest = AppError::from(error.clone());
        match error {
            GatewayError::UnknownNode { .. } => assert_eq!(
                rest.to_string(),
                "node 9 is not known on bus demo (try POST /api/v1/buses/demo/scan)"
            ),
            GatewayError::Internal(_) => assert_eq!(rest.to_string(), "internal error"),
            _ => assert_eq!(rest.to_string(), error.to_string()),
        }
    }
}

/// A failed step answers as its cause, with the step named, and keeps the
/// REST hint of its cause (a logger's channel on an unknown node).
#[test]
fn a_failed_step_answers_as_its_cause() {
    let error = AppError::from(GatewayError::FailedAt {
        step: "channel 0".to_string(),
        source: Box::new(GatewayError::UnknownNode {
            bus: "demo".to_string(),
            node: "9".to_string(),
        }),
    });
    assert_eq!(error.status(), StatusCode::NOT_FOUND);
    assert_eq!(
        error.to_json(),
        json!({
            "code": "unknown_node",
            "message": "step channel 0 failed: node 9 is not known on bus demo (try POST /api/v1/buses/demo/scan)",
            "step": "channel 0",
        })
    );
}

/// A command over a door's size limit (a Sparkplug DCMD over
/// `sparkplug_max_command_bytes`) is HTTP's 413, with its code.
#[test]
fn a_command_too_large_is_payload_too_large() {
    let error = AppError::from(GatewayError::CommandTooLarge {
        size: 70_000,
        limit: 65_536,
    });
    assert_eq!(error.status(), StatusCode::PAYLOAD_TOO_LARGE);
    assert_eq!(error.to_json()["code"], "command_too_large");
    assert_eq!(
        error.to_string(),
        "70000 bytes: over the limit of 65536 bytes for one command"
    );
}
