//! The schemas of `crate::gateway::drive`'s requests and answers.

use utoipa::ToSchema;

/// The modes a `move` request names.
#[derive(Debug, ToSchema)]
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

/// A motion to run (`POST .../axes/{axis}/move`); values are device units.
#[derive(Debug, ToSchema)]
#[serde(tag = "mode", rename_all = "snake_case", deny_unknown_fields)]
pub enum MoveRequest {
    /// Profile position: `target` (0x607A), absolute or relative,
    /// immediately or after the running set-point; the profile's velocity
    /// (0x6081), acceleration (0x6083) and deceleration (0x6084) when given.
    #[schema(example = json!({"mode": "profile_position", "target": 65536, "relative": false, "immediate": true}))]
    ProfilePosition {
        target: i32,
        #[serde(default)]
        relative: bool,
        // True when not given (the gateway's default): utoipa reads only
        // that it may be left out.
        #[serde(default)]
        immediate: bool,
        velocity: Option<i64>,
        acceleration: Option<i64>,
        deceleration: Option<i64>,
    },
    /// Velocity: UMC VL 0x6042 (acceleration and deceleration as 0x6048.1
    /// and 0x6049.1 per 0x6048.2 = 1 ms); JMC 0x6081 in 0.1 rps with
    /// 0x6083/0x6084 in 0.1 rps/s (16 bits).
    #[schema(example = json!({"mode": "velocity", "velocity": 100}))]
    Velocity {
        velocity: i32,
        acceleration: Option<i64>,
        deceleration: Option<i64>,
    },
    /// Profile torque: 0x6071 in per mille of the rated torque, slope 0x6087.
    #[schema(example = json!({"mode": "torque", "torque": 100}))]
    Torque { torque: i16, slope: Option<i64> },
    /// UMC duty cycle: 0x41FA (±32767 = ±100 %), ramped by 0x41FD when a
    /// slope is given.
    #[schema(example = json!({"mode": "duty_cycle", "duty": 8192}))]
    DutyCycle { duty: i16, slope: Option<i64> },
    /// UMC continuous position: 0x41F0, processed at once.
    #[schema(example = json!({"mode": "continuous_position", "target": 32768, "relative": false}))]
    ContinuousPosition {
        target: i32,
        #[serde(default)]
        relative: bool,
    },
    /// Interpolated position: one point every `period_ms` (0x60C2), fed
    /// into the drive's buffer (0x60C1) as it drains; the answer comes
    /// when the last point is in the buffer.
    #[schema(example = json!({"mode": "interpolated_position", "period_ms": 10, "points": [0, 1000, 2000, 3000]}))]
    InterpolatedPosition { period_ms: u8, points: Vec<i32> },
    /// Homing: method 0x6098, speeds 0x6099.1 (search) and .2 (slow),
    /// acceleration 0x609A, home offset 0x607C.
    #[schema(example = json!({"mode": "homing", "method": 3, "speeds": [100, 20]}))]
    Homing {
        method: i8,
        speeds: Option<[i64; 2]>,
        acceleration: Option<i64>,
        offset: Option<i32>,
    },
}

/// The targets of `POST .../axes/{axis}/state`: the states a master can
/// command.
#[derive(Debug, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum TargetState {
    OperationEnabled,
    SwitchedOn,
    ReadyToSwitchOn,
    SwitchOnDisabled,
    QuickStopActive,
}

/// One axis as read from the drive.
#[derive(Debug, ToSchema)]
pub struct AxisStatus {
    /// 1-based.
    #[schema(example = 1)]
    pub axis: u8,
    /// The PDS state (`not_ready_to_switch_on`, `switch_on_disabled`,
    /// `ready_to_switch_on`, `switched_on`, `operation_enabled`,
    /// `quick_stop_active`, `fault_reaction_active`, `fault`), `unknown` for a
    /// statusword CiA 402 does not define.
    #[schema(example = "operation_enabled")]
    pub state: String,
    /// 0x6041.
    #[schema(example = 1063)]
    pub statusword: u16,
    /// The mode the drive displays (0x6061) by its CiA 402 name
    /// (`profile_position`, `velocity`, `profile_velocity`, `torque`,
    /// `homing`, `interpolated_position`, `duty_cycle`,
    /// `continuous_position`, `none`, ...); null for a number without a name.
    #[schema(example = "profile_position")]
    pub mode: Option<String>,
    /// 0x6061 as the number the drive sent.
    #[schema(example = 1)]
    pub mode_raw: i8,
    /// The `mode`s `move` accepts on this axis.
    pub supported_modes: Vec<MoveMode>,
    /// 0x6064, position units; null where the drive has no such object.
    #[schema(example = 65536)]
    pub position: Option<i32>,
    /// 0x606C, velocity units.
    #[schema(example = 0)]
    pub velocity: Option<i32>,
    /// 0x6077, per mille of the rated torque (the JMC has none: null).
    #[schema(example = 0)]
    pub torque: Option<i16>,
    /// Statusword bit 10.
    pub target_reached: bool,
    /// Statusword bit 3.
    pub fault: bool,
}

/// The units an axis's values are in, as its product's manual defines
/// them (product knowledge from `profiles`), for a page to label them.
#[derive(Debug, ToSchema)]
pub struct AxisUnits {
    /// Of 0x6064, 0x607A, 0x607D, 0x607C (`steps`, `increments`).
    #[schema(example = "increments")]
    pub position: String,
    /// Of 0x606C, 0x6081, 0x607F, 0x6080 (`0.1 rps`, `increments/ms`).
    #[schema(example = "increments/ms")]
    pub velocity: String,
    /// Of 0x6083, 0x6084 (`0.1 rps/s`, `increments/ms²`).
    #[schema(example = "increments/ms²")]
    pub acceleration: String,
    /// Of the VL objects 0x6042, 0x6044, 0x6046 where the velocity move
    /// uses them (`vl units`), else null.
    #[schema(example = "vl units")]
    pub vl_velocity: Option<String>,
    /// Revolutions per second of one `velocity` unit, where the manual
    /// fixes it (JMC 0.1; UMC 1000/65536), else null.
    #[schema(example = 0.0152587890625)]
    pub rps_per_velocity_unit: Option<f64>,
    /// Position units per motor revolution, where the manual fixes it
    /// (UMC 65536), else null (the JMC's steps depend on its subdivision).
    #[schema(example = 65536.0)]
    pub position_per_revolution: Option<f64>,
    /// Of 0x6077, 0x6071.
    #[schema(example = "‰ of rated torque")]
    pub torque: String,
}

/// The limits an axis applies to a request, read from the drive; each null
/// where the drive has no such object (or the EDS lacks it).
#[derive(Debug, ToSchema)]
pub struct AxisLimits {
    /// 0x607F, max profile velocity: caps 0x6081.
    #[schema(example = 16384)]
    pub max_profile_velocity: Option<u32>,
    /// 0x6080, max motor speed: caps 0x6081 as well.
    #[schema(example = 16384)]
    pub max_motor_speed: Option<u32>,
    /// 0x6081, the profile velocity set now.
    #[schema(example = 16384)]
    pub profile_velocity: Option<u32>,
    /// 0x6083, the profile acceleration set now.
    #[schema(example = 1)]
    pub profile_acceleration: Option<u32>,
    /// 0x6046 sub 1, vl velocity min amount.
    #[schema(example = 0)]
    pub vl_min: Option<u32>,
    /// 0x6046 sub 2, vl velocity max amount: caps 0x6042.
    #[schema(example = 1000)]
    pub vl_max: Option<u32>,
    /// 0x604C, vl dimension factor `[numerator, denominator]`: velocity
    /// units in increments/ms per vl unit.
    #[schema(example = json!([1, 1]))]
    pub vl_dimension_factor: Option<[i32; 2]>,
    /// 0x607D, software position limits `[min, max]`; null also when both
    /// are 0 (which switches them off).
    #[schema(example = json!([-1000000, 1000000]))]
    pub software_position_limit: Option<[i32; 2]>,
    /// 0x608F, position encoder resolution `[encoder increments, motor
    /// revolutions]`.
    #[schema(example = json!([65536, 1]))]
    pub encoder_resolution: Option<[u32; 2]>,
    /// 0x6091, gear ratio `[motor revolutions, shaft revolutions]`.
    #[schema(example = json!([1, 1]))]
    pub gear_ratio: Option<[u32; 2]>,
}
