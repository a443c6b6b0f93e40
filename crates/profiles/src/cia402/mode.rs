//! Modes of operation, 0x6060 and 0x6061 (INT8; UMC manual §1.4.5, Figure
//! 2.5), and the supported drive modes bit field 0x6502 (§1.4.7, Figure
//! 2.6). The positive values are CiA 402's; negative ones are each
//! manufacturer's, here the UMC's.

/// A mode of operation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Mode {
    /// 0: no mode change / no mode assigned.
    NoMode,
    /// 1: profile position (PP).
    ProfilePosition,
    /// 2: velocity (VL). The JMC stepper uses 2 for its own "pulse
    /// direction mode" instead.
    Velocity,
    /// 3: profile velocity (PV).
    ProfileVelocity,
    /// 4: profile torque (TQ).
    Torque,
    /// 6: homing (HM).
    Homing,
    /// 7: interpolated position (IP).
    InterpolatedPosition,
    /// 8: cyclic synchronous position (CSP).
    CyclicSyncPosition,
    /// 9: cyclic synchronous velocity (CSV).
    CyclicSyncVelocity,
    /// 10: cyclic synchronous torque (CST).
    CyclicSyncTorque,
    /// −1: UMC duty cycle (DTY), the power stage's PWM directly.
    DutyCycle,
    /// −16: UMC continuous position (CP).
    ContinuousPosition,
    /// Any other value (another manufacturer's negative modes included).
    Unknown(i8),
}

impl Mode {
    /// Every mode with a name.
    pub const ALL: [Mode; 12] = [
        Mode::NoMode,
        Mode::ProfilePosition,
        Mode::Velocity,
        Mode::ProfileVelocity,
        Mode::Torque,
        Mode::Homing,
        Mode::InterpolatedPosition,
        Mode::CyclicSyncPosition,
        Mode::CyclicSyncVelocity,
        Mode::CyclicSyncTorque,
        Mode::DutyCycle,
        Mode::ContinuousPosition,
    ];

    pub fn from_raw(raw: i8) -> Self {
        match raw {
            0 => Self::NoMode,
            1 => Self::ProfilePosition,
            2 => Self::Velocity,
            3 => Self::ProfileVelocity,
            4 => Self::Torque,
            6 => Self::Homing,
            7 => Self::InterpolatedPosition,
            8 => Self::CyclicSyncPosition,
            9 => Self::CyclicSyncVelocity,
            10 => Self::CyclicSyncTorque,
            -1 => Self::DutyCycle,
            -16 => Self::ContinuousPosition,
            other => Self::Unknown(other),
        }
    }

    pub fn raw(self) -> i8 {
        match self {
            Self::NoMode => 0,
            Self::ProfilePosition => 1,
            Self::Velocity => 2,
            Self::ProfileVelocity => 3,
            Self::Torque => 4,
            Self::Homing => 6,
            Self::InterpolatedPosition => 7,
            Self::CyclicSyncPosition => 8,
            Self::CyclicSyncVelocity => 9,
            Self::CyclicSyncTorque => 10,
            Self::DutyCycle => -1,
            Self::ContinuousPosition => -16,
            Self::Unknown(raw) => raw,
        }
    }

    /// The name in the HTTP API (`profile_position`), `None` for
    /// [`Mode::Unknown`].
    pub fn name(self) -> Option<&'static str> {
        Some(match self {
            Self::NoMode => "none",
            Self::ProfilePosition => "profile_position",
            Self::Velocity => "velocity",
            Self::ProfileVelocity => "profile_velocity",
            Self::Torque => "torque",
            Self::Homing => "homing",
            Self::InterpolatedPosition => "interpolated_position",
            Self::CyclicSyncPosition => "cyclic_sync_position",
            Self::CyclicSyncVelocity => "cyclic_sync_velocity",
            Self::CyclicSyncTorque => "cyclic_sync_torque",
            Self::DutyCycle => "duty_cycle",
            Self::ContinuousPosition => "continuous_position",
            Self::Unknown(_) => return None,
        })
    }

    pub fn from_name(name: &str) -> Option<Mode> {
        Mode::ALL.into_iter().find(|mode| mode.name() == Some(name))
    }

    /// The bit of 0x6502 that says the drive supports this mode: CiA 402's
    /// for the standard modes, the UMC manual's (Figure 2.6) for its own.
    pub fn supported_bit(self) -> Option<u32> {
        match self {
            Self::ProfilePosition => Some(0),
            Self::Velocity => Some(1),
            Self::ProfileVelocity => Some(2),
            Self::Torque => Some(3),
            Self::Homing => Some(5),
            Self::InterpolatedPosition => Some(6),
            Self::CyclicSyncPosition => Some(7),
            Self::CyclicSyncVelocity => Some(8),
            Self::CyclicSyncTorque => Some(9),
            Self::DutyCycle => Some(16),
            Self::ContinuousPosition => Some(20),
            Self::NoMode | Self::Unknown(_) => None,
        }
    }

    /// The modes a 0x6502 value lists, in [`Mode::ALL`] order; bits no mode
    /// here claims are left out.
    pub fn supported(bits: u32) -> Vec<Mode> {
        Mode::ALL
            .into_iter()
            .filter(|mode| {
                mode.supported_bit()
                    .is_some_and(|bit| bits & (1 << bit) != 0)
            })
            .collect()
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.name() {
            Some(name) => f.write_str(name),
            None => write!(f, "mode {}", self.raw()),
        }
    }
}
