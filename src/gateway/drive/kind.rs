//! What differs between the drive products the master knows.

use crate::gateway::profile::Profile;
use crate::profiles::jmc;

use super::*;

/// The drive products the master knows, from the node's profile.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DriveKind {
    /// UniSwarm UMC: up to 8 axes at the manual's offsets, the modes 0x6502
    /// lists, DTY and CP of its own.
    Umc,
    /// JMC stepper: one axis, modes 1, 3, 6, no 0x6502, no torque.
    Jmc,
    /// Any other CiA 402 drive: one axis, the standard modes 0x6502 lists.
    Cia402,
}

impl DriveKind {
    pub fn from_profile(profile: Profile) -> Option<Self> {
        match profile {
            Profile::Umc => Some(Self::Umc),
            Profile::JmcStepper => Some(Self::Jmc),
            Profile::Cia402 => Some(Self::Cia402),
            Profile::Uioled | Profile::Cia401 | Profile::Generic => None,
        }
    }

    /// Whether the product can have `mode` at all (before asking 0x6502).
    pub(super) fn may_support(self, mode: MoveMode) -> bool {
        match self {
            Self::Umc => true,
            Self::Jmc => mode
                .modes()
                .iter()
                .any(|mode| jmc::CIA402_MODES.contains(mode)),
            Self::Cia402 => !matches!(mode, MoveMode::DutyCycle | MoveMode::ContinuousPosition),
        }
    }
}
