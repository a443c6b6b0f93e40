use super::*;
use crate::cia309::reply::Reply;

fn text() -> String {
    "text".to_string()
}

/// The gateway's domain errors, each with the answer CiA 309 gives it.
fn domain_errors() -> Vec<(GatewayError, Failure)> {
    let abort = |raw| Failure::Abort(AbortCode::from_raw(raw));
    vec![
        (PdoError::InvalidMapping(text()).into(), abort(0x0604_0041)),
        (PdoError::UnknownPdo(text()).into(), abort(0x0602_0000)),
        (PdoError::PdoDisabled(text()).into(), abort(0x0800_0022)),
        (GatewayError::UnknownObject(text()), abort(0x0602_0000)),
        (GatewayError::UnknownSubObject(text()), abort(0x0609_0011)),
        (GatewayError::ValueOutOfRange(text()), abort(0x0609_0030)),
        (GatewayError::InvalidValue(text()), abort(0x0607_0010)),
        (GatewayError::ProgramNotVerified(text()), abort(0x0800_0020)),
        (
            LedError::UnknownSegment(text()).into(),
            Failure::Error(ErrorCode::RequestNotSupported),
        ),
        (
            LedError::NotAnLedController(text()).into(),
            Failure::Error(ErrorCode::RequestNotSupported),
        ),
        (
            GatewayError::NotAnIoModule(text()),
            Failure::Error(ErrorCode::RequestNotSupported),
        ),
        (
            GatewayError::UnknownChannel(text()),
            Failure::Error(ErrorCode::RequestNotSupported),
        ),
        (
            GatewayError::NotADrive(text()),
            Failure::Error(ErrorCode::RequestNotSupported),
        ),
        (
            SimError::UnknownDevice {
                bus: "demo".to_string(),
                node: 9,
            }
            .into(),
            Failure::Error(ErrorCode::UnsupportedNode),
        ),
        (
            GatewayError::InvalidIndex(text()),
            Failure::Error(ErrorCode::Syntax),
        ),
        (
            GatewayError::InvalidDcf {
                message: text(),
                line: Some(3),
            },
            Failure::Error(ErrorCode::Syntax),
        ),
        (
            GatewayError::NodeOffline(text()),
            Failure::Error(ErrorCode::HeartbeatLost),
        ),
        (
            GatewayError::StateChangeTimeout {
                message: text(),
                state: "fault".to_string(),
            },
            Failure::Error(ErrorCode::TimeOut),
        ),
        (
            GatewayError::NoRecording(text()),
            Failure::Error(ErrorCode::RequestNotSupported),
        ),
        (
            GatewayError::NotLoggable(text()),
            Failure::Error(ErrorCode::RequestNotSupported),
        ),
    ]
}

/// Each domain error is answered with its own code, not with 102
/// ("internal state"), which says nothing of what went wrong.
#[test]
fn domain_errors_get_their_own_answer() {
    for (error, expected) in domain_errors() {
        assert_eq!(Failure::of(&error), expected, "{error:?}");
        assert_ne!(
            Failure::of(&error),
            Failure::Error(ErrorCode::InternalState),
            "{error:?}"
        );
    }
}

/// An invalid PDO mapping, as a CiA 309-3 client reads it: the abort a
/// device gives for an object it cannot map.
#[test]
fn an_invalid_mapping_reads_as_the_device_s_abort() {
    let error = GatewayError::from(PdoError::InvalidMapping(
        "mapping entry 1: 0x6041 sub 0 cannot be mapped into an RPDO".to_string(),
    ));
    let reply = match Failure::of(&error) {
        Failure::Abort(code) => Reply::Abort(7, code),
        Failure::Error(code) => Reply::Error(7, code),
    };
    assert_eq!(
        reply.to_wire(),
        "[7] ERROR:0x06040041 #Object cannot be mapped to the PDO.\r\n"
    );
}

/// A failed step and an unconfirmed stop answer as their cause.
#[test]
fn a_failed_step_answers_as_its_cause() {
    let cause = GatewayError::SdoTimeout { node: 3 };
    let failed = GatewayError::FailedAt {
        step: "validate".to_string(),
        source: Box::new(cause.clone()),
    };
    let unconfirmed = GatewayError::StopNotConfirmed {
        source: Box::new(LedError::UnknownSegment(text()).into()),
        attempts: Vec::new(),
    };
    assert_eq!(Failure::of(&failed), Failure::of(&cause));
    assert_eq!(
        Failure::of(&unconfirmed),
        Failure::Error(ErrorCode::RequestNotSupported)
    );
}

/// The gateway's own refusals and faults stay 102, as before.
#[test]
fn states_and_faults_are_the_internal_state() {
    for error in [
        GatewayError::Internal(text()),
        GatewayError::LeaseConflict(text()),
        GatewayError::RecordingRunning(text()),
        GatewayError::BusDown(text()),
    ] {
        assert_eq!(
            Failure::of(&error),
            Failure::Error(ErrorCode::InternalState),
            "{error:?}"
        );
    }
}
