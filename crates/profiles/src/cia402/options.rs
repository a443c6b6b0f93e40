//! The option codes that choose how the PDS stops (UMC manual §1.4.8–1.4.13,
//! Tables 2.10–2.15), all INT16. Values the UMC manual leaves out (3, 4, 7,
//! 8 of the quick stop option, 3 and 4 of halt and fault reaction) are the
//! CiA 402 ones; negative values are the manufacturer's and read as
//! `Unknown`.

/// How the motor is brought to rest.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum StopKind {
    /// On the slow down ramp: the mode's deceleration (0x6084 in profile
    /// position).
    SlowDownRamp,
    /// On the quick stop ramp (0x6085).
    QuickStopRamp,
    /// At the current limit.
    CurrentLimit,
    /// At the voltage limit.
    VoltageLimit,
}

impl StopKind {
    /// The stop the common codes 1–4 (8 for the "stay" variants) give.
    fn from_code(code: i16) -> Option<StopKind> {
        match code {
            1 => Some(StopKind::SlowDownRamp),
            2 => Some(StopKind::QuickStopRamp),
            3 => Some(StopKind::CurrentLimit),
            4 => Some(StopKind::VoltageLimit),
            _ => None,
        }
    }

    fn code(self) -> i16 {
        match self {
            StopKind::SlowDownRamp => 1,
            StopKind::QuickStopRamp => 2,
            StopKind::CurrentLimit => 3,
            StopKind::VoltageLimit => 4,
        }
    }
}

/// 0x605A, quick stop option code (Table 2.11): transition 11 and whether
/// transition 12 follows by itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum QuickStopOption {
    /// 0: disable the drive function at once (the motor coasts); the drive
    /// goes on to switch on disabled.
    DisableDriveFunction,
    /// 1–4: stop, then switch on disabled.
    StopThenDisable(StopKind),
    /// 5–8: stop, then stay in quick stop active, holding (transition 16
    /// may enable operation again).
    StopAndStay(StopKind),
    /// Any other value (the manufacturer's below 0). Treated as
    /// [`QuickStopOption::DisableDriveFunction`]: when unsure how to stop,
    /// taking power away is the safe side.
    Unknown(i16),
}

impl Default for QuickStopOption {
    /// 2, the CiA 402 and UMC default.
    fn default() -> Self {
        QuickStopOption::StopThenDisable(StopKind::QuickStopRamp)
    }
}

impl QuickStopOption {
    pub fn from_raw(raw: i16) -> Self {
        match raw {
            0 => Self::DisableDriveFunction,
            1..=4 => StopKind::from_code(raw).map_or(Self::Unknown(raw), Self::StopThenDisable),
            5..=8 => StopKind::from_code(raw - 4).map_or(Self::Unknown(raw), Self::StopAndStay),
            other => Self::Unknown(other),
        }
    }

    pub fn raw(self) -> i16 {
        match self {
            Self::DisableDriveFunction => 0,
            Self::StopThenDisable(kind) => kind.code(),
            Self::StopAndStay(kind) => kind.code() + 4,
            Self::Unknown(raw) => raw,
        }
    }

    /// The stop to run, or `None` to disable the drive function at once.
    pub fn stop(self) -> Option<StopKind> {
        match self {
            Self::StopThenDisable(kind) | Self::StopAndStay(kind) => Some(kind),
            Self::DisableDriveFunction | Self::Unknown(_) => None,
        }
    }

    /// Whether the drive stays in quick stop active once stopped (5–8).
    pub fn stays(self) -> bool {
        matches!(self, Self::StopAndStay(_))
    }
}

/// 0x605B shutdown option code (Table 2.12, transition 8) and 0x605C
/// disable operation option code (Table 2.13, transition 5): both coded
/// alike.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum DisableOption {
    /// 0: disable the drive function at once.
    DisableDriveFunction,
    /// 1 (default): slow down ramp, then disable the drive function.
    #[default]
    SlowDownRamp,
    /// Any other value. Treated as [`DisableOption::DisableDriveFunction`].
    Unknown(i16),
}

impl DisableOption {
    pub fn from_raw(raw: i16) -> Self {
        match raw {
            0 => Self::DisableDriveFunction,
            1 => Self::SlowDownRamp,
            other => Self::Unknown(other),
        }
    }

    pub fn raw(self) -> i16 {
        match self {
            Self::DisableDriveFunction => 0,
            Self::SlowDownRamp => 1,
            Self::Unknown(raw) => raw,
        }
    }

    /// The stop to run before the drive function is disabled, if any.
    pub fn stop(self) -> Option<StopKind> {
        match self {
            Self::SlowDownRamp => Some(StopKind::SlowDownRamp),
            Self::DisableDriveFunction | Self::Unknown(_) => None,
        }
    }
}

/// 0x605D halt option code (Table 2.14): how controlword bit 8 stops the
/// motor. The state stays operation enabled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HaltOption {
    /// 1–4.
    Stop(StopKind),
    /// Any other value. Treated as the quick stop ramp: halt never takes
    /// power away, and the firmest ramp is the cautious reading.
    Unknown(i16),
}

impl Default for HaltOption {
    /// 1, the CiA 402 and UMC default.
    fn default() -> Self {
        HaltOption::Stop(StopKind::SlowDownRamp)
    }
}

impl HaltOption {
    pub fn from_raw(raw: i16) -> Self {
        StopKind::from_code(raw).map_or(Self::Unknown(raw), Self::Stop)
    }

    pub fn raw(self) -> i16 {
        match self {
            Self::Stop(kind) => kind.code(),
            Self::Unknown(raw) => raw,
        }
    }

    pub fn stop(self) -> StopKind {
        match self {
            Self::Stop(kind) => kind,
            Self::Unknown(_) => StopKind::QuickStopRamp,
        }
    }
}

/// 0x605E fault reaction option code (Table 2.15): transition 13.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FaultReactionOption {
    /// 0: disable the drive function, the motor free to rotate.
    DisableDriveFunction,
    /// 1–4.
    Stop(StopKind),
    /// Any other value. Treated as [`FaultReactionOption::DisableDriveFunction`].
    Unknown(i16),
}

impl Default for FaultReactionOption {
    /// 2, the UMC default.
    fn default() -> Self {
        FaultReactionOption::Stop(StopKind::QuickStopRamp)
    }
}

impl FaultReactionOption {
    pub fn from_raw(raw: i16) -> Self {
        match raw {
            0 => Self::DisableDriveFunction,
            other => StopKind::from_code(other).map_or(Self::Unknown(other), Self::Stop),
        }
    }

    pub fn raw(self) -> i16 {
        match self {
            Self::DisableDriveFunction => 0,
            Self::Stop(kind) => kind.code(),
            Self::Unknown(raw) => raw,
        }
    }

    pub fn stop(self) -> Option<StopKind> {
        match self {
            Self::Stop(kind) => Some(kind),
            Self::DisableDriveFunction | Self::Unknown(_) => None,
        }
    }
}

/// 0x6007 abort connection option code (Table 2.10): what the drive does
/// when it loses its master (bus-off, heartbeat or node guarding lost, an
/// NMT state change or reset).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum AbortConnectionOption {
    /// 0.
    NoAction,
    /// 1 (UMC default): a fault signal, transition 13.
    #[default]
    FaultSignal,
    /// 2: as if a disable voltage command had come.
    DisableVoltage,
    /// 3: as if a quick stop command had come.
    QuickStop,
    /// Any other value. Treated as [`AbortConnectionOption::FaultSignal`].
    Unknown(i16),
}

impl AbortConnectionOption {
    pub fn from_raw(raw: i16) -> Self {
        match raw {
            0 => Self::NoAction,
            1 => Self::FaultSignal,
            2 => Self::DisableVoltage,
            3 => Self::QuickStop,
            other => Self::Unknown(other),
        }
    }

    pub fn raw(self) -> i16 {
        match self {
            Self::NoAction => 0,
            Self::FaultSignal => 1,
            Self::DisableVoltage => 2,
            Self::QuickStop => 3,
            Self::Unknown(raw) => raw,
        }
    }
}
