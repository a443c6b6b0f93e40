//! What differs between the drive products the master knows.

use crate::profile::Profile;
use crate::profiles::{jmc, umc};

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

    /// The units of the axis's values, as the product's manual has them.
    pub fn units(self) -> AxisUnits {
        match self {
            Self::Jmc => AxisUnits {
                position: jmc::units::POSITION_UNIT.into(),
                velocity: jmc::units::VELOCITY_UNIT.into(),
                acceleration: jmc::units::ACCELERATION_UNIT.into(),
                vl_velocity: None,
                rps_per_velocity_unit: Some(1.0 / jmc::units::VELOCITY_PER_RPS),
                position_per_revolution: None,
                torque: TORQUE_UNIT.into(),
            },
            Self::Umc => AxisUnits {
                position: umc::units::POSITION_UNIT.into(),
                velocity: umc::units::VELOCITY_UNIT.into(),
                acceleration: umc::units::ACCELERATION_UNIT.into(),
                vl_velocity: Some(umc::units::VL_VELOCITY_UNIT.into()),
                rps_per_velocity_unit: Some(umc::units::rps_per_increment_per_ms()),
                position_per_revolution: Some(umc::units::INCREMENTS_PER_REV),
                torque: TORQUE_UNIT.into(),
            },
            // CiA 402's own words: the factor group decides what they are.
            Self::Cia402 => AxisUnits {
                position: "position units".into(),
                velocity: "velocity units".into(),
                acceleration: "acceleration units".into(),
                vl_velocity: Some("vl units".into()),
                rps_per_velocity_unit: None,
                position_per_revolution: None,
                torque: TORQUE_UNIT.into(),
            },
        }
    }
}

/// 0x6071, 0x6077 (CiA 402-2).
const TORQUE_UNIT: &str = "‰ of rated torque";
