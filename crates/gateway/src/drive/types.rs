//! The requests a drive takes (moves, target states) and the status of an
//! axis the master answers with.

use serde::{Deserialize, Serialize};

use crate::profiles::cia402::{Mode, State};

/// The modes a `move` request names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MoveMode {
    ProfilePosition,
    /// UMC: velocity mode VL (2, 0x6042); JMC: profile velocity (3, 0x6081);
    /// other drives: VL if they have it, else profile velocity (3, 0x60FF).
    Velocity,
    Torque,
    DutyCycle,
    ContinuousPosition,
    InterpolatedPosition,
    Homing,
}

impl MoveMode {
    pub const ALL: [MoveMode; 7] = [
        Self::ProfilePosition,
        Self::Velocity,
        Self::Torque,
        Self::DutyCycle,
        Self::ContinuousPosition,
        Self::InterpolatedPosition,
        Self::Homing,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::ProfilePosition => "profile_position",
            Self::Velocity => "velocity",
            Self::Torque => "torque",
            Self::DutyCycle => "duty_cycle",
            Self::ContinuousPosition => "continuous_position",
            Self::InterpolatedPosition => "interpolated_position",
            Self::Homing => "homing",
        }
    }

    /// The CiA 402 modes that can carry it, preferred first.
    pub(super) fn modes(self) -> &'static [Mode] {
        match self {
            Self::ProfilePosition => &[Mode::ProfilePosition],
            Self::Velocity => &[Mode::Velocity, Mode::ProfileVelocity],
            Self::Torque => &[Mode::Torque],
            Self::DutyCycle => &[Mode::DutyCycle],
            Self::ContinuousPosition => &[Mode::ContinuousPosition],
            Self::InterpolatedPosition => &[Mode::InterpolatedPosition],
            Self::Homing => &[Mode::Homing],
        }
    }
}

impl std::fmt::Display for MoveMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A motion to run (`POST .../axes/{axis}/move`); values are device units.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case", deny_unknown_fields)]
pub enum MoveRequest {
    /// Profile position: `target` (0x607A), absolute or relative,
    /// immediately or after the running set-point; the profile's velocity
    /// (0x6081), acceleration (0x6083) and deceleration (0x6084) when given.
    ProfilePosition {
        target: i32,
        #[serde(default)]
        relative: bool,
        #[serde(default = "yes")]
        immediate: bool,
        velocity: Option<i64>,
        acceleration: Option<i64>,
        deceleration: Option<i64>,
    },
    /// Velocity: UMC VL 0x6042 (acceleration and deceleration as 0x6048.1
    /// and 0x6049.1 per 0x6048.2 = 1 ms); JMC 0x6081 in 0.1 rps with
    /// 0x6083/0x6084 in 0.1 rps/s (16 bits).
    Velocity {
        velocity: i32,
        acceleration: Option<i64>,
        deceleration: Option<i64>,
    },
    /// Profile torque: 0x6071 in per mille of the rated torque, slope 0x6087.
    Torque { torque: i16, slope: Option<i64> },
    /// UMC duty cycle: 0x41FA (±32767 = ±100 %), ramped by 0x41FD when a
    /// slope is given.
    DutyCycle { duty: i16, slope: Option<i64> },
    /// UMC continuous position: 0x41F0, processed at once.
    ContinuousPosition {
        target: i32,
        #[serde(default)]
        relative: bool,
    },
    /// Interpolated position: one point every `period_ms` (0x60C2), fed
    /// into the drive's buffer (0x60C1) as it drains; the answer comes
    /// when the last point is in the buffer.
    InterpolatedPosition { period_ms: u8, points: Vec<i32> },
    /// Homing: method 0x6098, speeds 0x6099.1 (search) and .2 (slow),
    /// acceleration 0x609A, home offset 0x607C.
    Homing {
        method: i8,
        speeds: Option<[i64; 2]>,
        acceleration: Option<i64>,
        offset: Option<i32>,
    },
}

pub(super) fn yes() -> bool {
    true
}

/// The most points one interpolated move takes.
pub(crate) const MAX_IP_POINTS: usize = 100_000;
/// The longest interpolated move one request feeds (the request lasts as
/// long as the feeding): 10 minutes.
pub(crate) const MAX_IP_DURATION_MS: u64 = 600_000;

impl MoveRequest {
    pub fn mode(&self) -> MoveMode {
        match self {
            Self::ProfilePosition { .. } => MoveMode::ProfilePosition,
            Self::Velocity { .. } => MoveMode::Velocity,
            Self::Torque { .. } => MoveMode::Torque,
            Self::DutyCycle { .. } => MoveMode::DutyCycle,
            Self::ContinuousPosition { .. } => MoveMode::ContinuousPosition,
            Self::InterpolatedPosition { .. } => MoveMode::InterpolatedPosition,
            Self::Homing { .. } => MoveMode::Homing,
        }
    }
}

/// The targets of `POST .../axes/{axis}/state`: the states a master can
/// command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TargetState {
    OperationEnabled,
    SwitchedOn,
    ReadyToSwitchOn,
    SwitchOnDisabled,
    QuickStopActive,
}

impl TargetState {
    pub fn state(self) -> State {
        match self {
            Self::OperationEnabled => State::OperationEnabled,
            Self::SwitchedOn => State::SwitchedOn,
            Self::ReadyToSwitchOn => State::ReadyToSwitchOn,
            Self::SwitchOnDisabled => State::SwitchOnDisabled,
            Self::QuickStopActive => State::QuickStopActive,
        }
    }
}

/// One axis as read from the drive.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisStatus {
    /// 1-based.
    pub axis: u8,
    /// The PDS state (`not_ready_to_switch_on`, `switch_on_disabled`,
    /// `ready_to_switch_on`, `switched_on`, `operation_enabled`,
    /// `quick_stop_active`, `fault_reaction_active`, `fault`), `unknown` for a
    /// statusword CiA 402 does not define.
    pub state: String,
    /// 0x6041.
    pub statusword: u16,
    /// The mode the drive displays (0x6061) by its CiA 402 name
    /// (`profile_position`, `velocity`, `profile_velocity`, `torque`,
    /// `homing`, `interpolated_position`, `duty_cycle`,
    /// `continuous_position`, `none`, ...); null for a number without a name.
    pub mode: Option<String>,
    /// 0x6061 as the number the drive sent.
    pub mode_raw: i8,
    /// The `mode`s `move` accepts on this axis.
    pub supported_modes: Vec<MoveMode>,
    /// 0x6064, position units; null where the drive has no such object.
    pub position: Option<i32>,
    /// 0x606C, velocity units.
    pub velocity: Option<i32>,
    /// 0x6077, per mille of the rated torque (the JMC has none: null).
    pub torque: Option<i16>,
    /// Statusword bit 10.
    pub target_reached: bool,
    /// Statusword bit 3.
    pub fault: bool,
}

/// The units an axis's values are in, as its product's manual defines
/// them (product knowledge from `profiles`), for a page to label them.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisUnits {
    /// Of 0x6064, 0x607A, 0x607D, 0x607C (`steps`, `increments`).
    pub position: String,
    /// Of 0x606C, 0x6081, 0x607F, 0x6080 (`0.1 rps`, `increments/ms`).
    pub velocity: String,
    /// Of 0x6083, 0x6084 (`0.1 rps/s`, `increments/ms²`).
    pub acceleration: String,
    /// Of the VL objects 0x6042, 0x6044, 0x6046 where the velocity move
    /// uses them (`vl units`), else null.
    pub vl_velocity: Option<String>,
    /// Revolutions per second of one `velocity` unit, where the manual
    /// fixes it (JMC 0.1; UMC 1000/65536), else null.
    pub rps_per_velocity_unit: Option<f64>,
    /// Position units per motor revolution, where the manual fixes it
    /// (UMC 65536), else null (the JMC's steps depend on its subdivision).
    pub position_per_revolution: Option<f64>,
    /// Of 0x6077, 0x6071.
    pub torque: String,
}

/// The limits an axis applies to a request, read from the drive; each null
/// where the drive has no such object (or the EDS lacks it).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize)]
pub struct AxisLimits {
    /// 0x607F, max profile velocity: caps 0x6081.
    pub max_profile_velocity: Option<u32>,
    /// 0x6080, max motor speed: caps 0x6081 as well.
    pub max_motor_speed: Option<u32>,
    /// 0x6081, the profile velocity set now.
    pub profile_velocity: Option<u32>,
    /// 0x6083, the profile acceleration set now.
    pub profile_acceleration: Option<u32>,
    /// 0x6046 sub 1, vl velocity min amount.
    pub vl_min: Option<u32>,
    /// 0x6046 sub 2, vl velocity max amount: caps 0x6042.
    pub vl_max: Option<u32>,
    /// 0x604C, vl dimension factor `[numerator, denominator]`: velocity
    /// units in increments/ms per vl unit.
    pub vl_dimension_factor: Option<[i32; 2]>,
    /// 0x607D, software position limits `[min, max]`; null also when both
    /// are 0 (which switches them off).
    pub software_position_limit: Option<[i32; 2]>,
    /// 0x608F, position encoder resolution `[encoder increments, motor
    /// revolutions]`.
    pub encoder_resolution: Option<[u32; 2]>,
    /// 0x6091, gear ratio `[motor revolutions, shaft revolutions]`.
    pub gear_ratio: Option<[u32; 2]>,
}

/// What the telemetry of an axis reads at each poll: the status but the
/// supported modes (which do not change while the drive runs), each value
/// `None` where the drive has no such object.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AxisReading {
    pub statusword: u16,
    /// 0x6061.
    pub mode_raw: Option<i8>,
    /// 0x6064.
    pub position: Option<i32>,
    /// 0x606C.
    pub velocity: Option<i32>,
    /// 0x6077.
    pub torque: Option<i16>,
}
