//! Why a drive request failed.

use crate::profile::Profile;
use crate::profiles::cia402::State;
use crate::registry::RegistryError;
use crate::sdo::SdoRequestError;

use super::*;

/// Why a drive request failed.
#[derive(Debug, thiserror::Error)]
pub enum DriveError {
    #[error("node {node} is no drive (profile {profile})")]
    NotADrive { node: u8, profile: Profile },
    #[error("node {node} has no axis {axis} (it has {axes})")]
    UnknownAxis { node: u8, axis: String, axes: u8 },
    #[error(transparent)]
    Sdo(#[from] SdoRequestError),
    #[error(transparent)]
    Registry(#[from] RegistryError),
    /// The drive is (or went) in fault or fault reaction active.
    #[error("axis {axis} is in {state} (statusword 0x{statusword:04X}){detail}")]
    Fault {
        axis: u8,
        state: State,
        statusword: u16,
        detail: &'static str,
    },
    /// The drive did not reach the state (or mode, or acknowledge) in time.
    #[error("axis {axis}: {what} did not happen in time; the drive stopped in {state}", state = state_name(.state))]
    Timeout {
        axis: u8,
        what: String,
        state: Option<State>,
    },
    #[error("axis {axis} does not support mode {mode} (it supports: {supported})", supported = names(.supported))]
    ModeNotSupported {
        axis: u8,
        mode: MoveMode,
        supported: Vec<MoveMode>,
    },
    /// A walk's step saw the drive stopped by another command meanwhile
    /// (STOP ALL, a quick stop, a lapsed lease): it is not late, it is
    /// over.
    #[error("axis {axis}: {what} was interrupted: another command stopped the drive meanwhile (STOP ALL, a quick stop or a lapsed lease), which is now in {state}", state = state_name(.state))]
    Interrupted {
        axis: u8,
        what: String,
        state: Option<State>,
    },
    /// A move (or a quick stop) asks for operation enabled.
    #[error("axis {axis} is in {state}; a move or a quick stop needs operation_enabled", state = state_name(.state))]
    NotEnabled { axis: u8, state: Option<State> },
    /// A value does not fit its object, or a request the drive cannot take
    /// (found before the bus is touched).
    #[error("{0}")]
    OutOfRange(String),
    #[error("{0}")]
    Invalid(String),
    /// A request only a UMC-class drive's control loops can take.
    #[error("{0}")]
    NotTunable(String),
    /// A position step the drive would fault on (beyond 0x6065).
    #[error("{0}")]
    StepBeyondFollowingWindow(String),
    /// A stop of the axis came after the command was admitted: its
    /// remaining writes were not sent (`crate::authority`).
    #[error("{0}")]
    Stopped(String),
}

pub(super) fn state_name(state: &Option<State>) -> &'static str {
    state.map_or("unknown", State::name)
}

pub(super) fn names(modes: &[MoveMode]) -> String {
    let names: Vec<&str> = modes.iter().map(|mode| mode.name()).collect();
    if names.is_empty() {
        "none".into()
    } else {
        names.join(", ")
    }
}

impl DriveError {
    /// The state the drive was left in, for the error body.
    pub fn state(&self) -> Option<State> {
        match self {
            Self::Fault { state, .. } => Some(*state),
            Self::Timeout { state, .. }
            | Self::NotEnabled { state, .. }
            | Self::Interrupted { state, .. } => *state,
            _ => None,
        }
    }
}
