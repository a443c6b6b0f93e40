//! The CiA 402 master (CiA 402-2; UMC firmware manual chapter 2; JMC
//! CANopen manual "Control word", "Status word", "Motion control mode",
//! "Homing mode"): one axis of a drive node, reached through the node's
//! [`SdoChannel`].
//!
//! What differs between products is said once, in [`DriveKind`]: where an
//! axis's objects are (a UMC's axis `n` at `+0x800 * (n - 1)` in the
//! profile area, `+0x200 * (n - 1)` in its manufacturer axis area; one
//! axis elsewhere), which modes exist and which objects and mode numbers a
//! move uses (UMC velocity is VL, 0x6042; JMC velocity is its profile
//! velocity mode 3 with 0x6081 and 16-bit accelerations). Every value is
//! encoded with the type the node's EDS gives its object, so the JMC's
//! UNSIGNED16 accelerations and the UMC's UNSIGNED32 ones need no special
//! case; without an EDS the CiA 402 types are used.
//!
//! Each sequence (state walk, fault reset, halt, the set-up of a move)
//! holds the node's [`SdoChannel::procedure`], so two cannot interleave
//! their controlwords; the quick stops of [`Drive::quick_stop_if_enabled`]
//! do not wait for it. Every wait polls the statusword on tokio's clock with a bound, so a
//! paused clock runs the walks in tests. Callers run each sequence in a
//! task of its own (a sequence cut half way could leave a drive moving).

use std::sync::Arc;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::sync::OwnedMutexGuard;
use utoipa::ToSchema;

use super::profile::{EdsEntry, Profile};
use super::registry::{NodeInfo, NodeRegistry, RegistryError};
use super::sdo::{SdoChannel, SdoRequestError};
use crate::canopen::od::DataType;
use crate::profiles::cia402::objects as obj;
use crate::profiles::cia402::{Command, Mode, PlanError, State, Statusword, expected_state, plan};
use crate::profiles::{jmc, umc};

/// How long one step of the state walk may take to show in the
/// statusword: a quick stop or a disable may run a deceleration ramp first.
pub const STEP_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a mode change may take (a UMC stops on its halt ramp first).
pub const MODE_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a drive may take to acknowledge a set-point or start homing.
pub const ACK_TIMEOUT: Duration = Duration::from_secs(1);
/// The statusword is read this often while waiting.
const POLL: Duration = Duration::from_millis(5);

/// Controlword bit 4: PP new set-point, VL ramp enable, IP interpolation
/// enable, HM start, UMC DTY slope.
const CW_BIT4: u16 = 1 << 4;
/// Controlword bit 5: PP change immediately, VL ramp unlock.
const CW_BIT5: u16 = 1 << 5;
/// Controlword bit 6: PP and CP relative, VL use reference.
const CW_BIT6: u16 = 1 << 6;
/// Controlword bit 8, halt.
const CW_HALT: u16 = 1 << 8;
/// Statusword bit 12 in PP: set-point acknowledge.
const SW_BIT12: u16 = 1 << 12;

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
            Profile::Uioled | Profile::Generic => None,
        }
    }

    /// Whether the product can have `mode` at all (before asking 0x6502).
    fn may_support(self, mode: MoveMode) -> bool {
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

/// The modes a `move` request names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
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
    fn modes(self) -> &'static [Mode] {
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
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, ToSchema)]
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
        #[serde(default = "yes")]
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

fn yes() -> bool {
    true
}

/// The most points one interpolated move takes.
pub const MAX_IP_POINTS: usize = 100_000;
/// The longest interpolated move one request feeds (the request lasts as
/// long as the feeding): 10 minutes.
pub const MAX_IP_DURATION_MS: u64 = 600_000;

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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
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
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
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
    /// A move (or a quick stop) asks for operation enabled.
    #[error("axis {axis} is in {state}; a move or a quick stop needs operation_enabled", state = state_name(.state))]
    NotEnabled { axis: u8, state: Option<State> },
    /// A value does not fit its object, or a request the drive cannot take
    /// (found before the bus is touched).
    #[error("{0}")]
    OutOfRange(String),
    #[error("{0}")]
    Invalid(String),
}

fn state_name(state: &Option<State>) -> &'static str {
    state.map_or("unknown", State::name)
}

fn names(modes: &[MoveMode]) -> String {
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
            Self::Timeout { state, .. } | Self::NotEnabled { state, .. } => *state,
            _ => None,
        }
    }
}

/// One SDO write, encoded and checked before the bus is touched.
#[derive(Debug, Clone)]
struct Write {
    index: u16,
    sub: u8,
    data: Vec<u8>,
}

/// The axes of a node: a UMC has as many as its EDS describes statuswords
/// for (0x6041, 0x6841, ...), other drives one.
pub fn axis_count(kind: DriveKind, eds: Option<&EdsEntry>) -> u8 {
    match (kind, eds) {
        (DriveKind::Umc, Some(entry)) => (1..=umc::MAX_AXES)
            .take_while(|&axis| {
                umc::axis_index(axis, obj::STATUSWORD)
                    .is_some_and(|index| entry.eds.dictionary.get(index).is_some())
            })
            .count()
            .max(1) as u8,
        _ => 1,
    }
}

/// Every axis of a drive node, read now: the profile summary of
/// `GET /buses/{bus}/nodes/{id}`. A node that is no drive has none.
pub async fn axes_summary(
    registry: &NodeRegistry,
    info: &NodeInfo,
) -> Result<Vec<AxisStatus>, DriveError> {
    let Some(kind) = DriveKind::from_profile(info.profile) else {
        return Ok(Vec::new());
    };
    let channel = registry.sdo(info.id)?;
    let count = axis_count(kind, info.eds_entry.as_deref());
    let mut axes = Vec::new();
    for axis in 1..=count {
        let drive = Drive {
            channel: channel.clone(),
            kind,
            eds: info.eds_entry.clone(),
            axis,
        };
        axes.push(drive.status().await?);
    }
    Ok(axes)
}

/// One axis of a drive node.
#[derive(Clone)]
pub struct Drive {
    channel: SdoChannel,
    kind: DriveKind,
    eds: Option<Arc<EdsEntry>>,
    axis: u8,
}

impl Drive {
    /// Axis `axis` (the path's text) of the node `info`.
    pub fn new(registry: &NodeRegistry, info: &NodeInfo, axis: &str) -> Result<Self, DriveError> {
        let node = info.id.get();
        let kind = DriveKind::from_profile(info.profile).ok_or(DriveError::NotADrive {
            node,
            profile: info.profile,
        })?;
        let axes = axis_count(kind, info.eds_entry.as_deref());
        let number = axis
            .parse::<u8>()
            .ok()
            .filter(|n| (1..=axes).contains(n))
            .ok_or_else(|| DriveError::UnknownAxis {
                node,
                axis: axis.to_string(),
                axes,
            })?;
        Ok(Self {
            channel: registry.sdo(info.id)?,
            kind,
            eds: info.eds_entry.clone(),
            axis: number,
        })
    }

    /// The node's id.
    pub fn node(&self) -> u8 {
        self.channel.node().get()
    }

    pub fn axis(&self) -> u8 {
        self.axis
    }

    pub fn kind(&self) -> DriveKind {
        self.kind
    }

    /// The node's SDO channel (the stops of [`super::safe_stop`] use it
    /// with their own short timeouts).
    pub fn channel(&self) -> &SdoChannel {
        &self.channel
    }

    /// The axis's copy of the axis-1 CiA 402 object `index` (a UMC's axis
    /// 2 has its statusword at 0x6841).
    pub fn object(&self, index: u16) -> u16 {
        self.index(index)
    }

    /// The axis's copy of the axis-1 object `index`.
    fn index(&self, index: u16) -> u16 {
        match self.kind {
            DriveKind::Umc => umc::axis_index(self.axis, index).unwrap_or(index),
            DriveKind::Jmc | DriveKind::Cia402 => index,
        }
    }

    /// Whether the EDS says the object exists (true without an EDS).
    fn has(&self, index: u16) -> bool {
        self.eds
            .as_ref()
            .is_none_or(|entry| entry.eds.dictionary.get(self.index(index)).is_some())
    }

    /// `value` as the object's bytes: the EDS's type for it, else
    /// `default`; out of range is an error before the bus.
    fn encode(
        &self,
        index: u16,
        sub: u8,
        default: DataType,
        value: i64,
        what: &str,
    ) -> Result<Write, DriveError> {
        let index = self.index(index);
        let data_type = self
            .eds
            .as_ref()
            .and_then(|entry| entry.eds.dictionary.sub(index, sub))
            .map(|sub| sub.data_type)
            .filter(|data_type| data_type.is_integer())
            .unwrap_or(default);
        let len = data_type.byte_len().unwrap_or(4).clamp(1, 8);
        let bits = (len * 8) as u32;
        let (low, high) = if data_type.is_signed() {
            (-(1i128 << (bits - 1)), (1i128 << (bits - 1)) - 1)
        } else {
            (0, (1i128 << bits) - 1)
        };
        if !(low..=high).contains(&i128::from(value)) {
            return Err(DriveError::OutOfRange(format!(
                "{what} {value} does not fit 0x{index:04X}.{sub} ({low} to {high})"
            )));
        }
        Ok(Write {
            index,
            sub,
            data: value.to_le_bytes()[..len].to_vec(),
        })
    }

    async fn write(&self, write: &Write) -> Result<(), DriveError> {
        Ok(self
            .channel
            .download(write.index, write.sub, &write.data)
            .await?)
    }

    async fn read_int(&self, index: u16, sub: u8, signed: bool) -> Result<i64, DriveError> {
        let data = self.channel.upload(self.index(index), sub).await?;
        let mut bytes = [0u8; 8];
        let len = data.len().min(8);
        bytes[..len].copy_from_slice(&data[..len]);
        let value = i64::from_le_bytes(bytes);
        Ok(if signed && (1..8).contains(&len) {
            let shift = 64 - 8 * len as u32;
            (value << shift) >> shift
        } else {
            value
        })
    }

    /// An optional object: `None` if the EDS lacks it or the drive aborts.
    async fn read_optional(
        &self,
        index: u16,
        sub: u8,
        signed: bool,
    ) -> Result<Option<i64>, DriveError> {
        if !self.has(index) {
            return Ok(None);
        }
        match self.read_int(index, sub, signed).await {
            Ok(value) => Ok(Some(value)),
            Err(DriveError::Sdo(error)) if error.device_abort().is_some() => Ok(None),
            Err(error) => Err(error),
        }
    }

    pub async fn statusword(&self) -> Result<Statusword, DriveError> {
        Ok(Statusword(
            self.read_int(obj::STATUSWORD, 0, false).await? as u16,
        ))
    }

    async fn controlword(&self, value: u16) -> Result<(), DriveError> {
        self.channel
            .download(self.index(obj::CONTROLWORD), 0, &value.to_le_bytes())
            .await?;
        Ok(())
    }

    /// The CiA 402 modes the drive says it supports (0x6502); the JMC's
    /// fixed three.
    async fn supported(&self) -> Result<Vec<Mode>, DriveError> {
        Ok(match self.kind {
            DriveKind::Jmc => jmc::CIA402_MODES.to_vec(),
            DriveKind::Umc | DriveKind::Cia402 => {
                match self
                    .read_optional(obj::SUPPORTED_DRIVE_MODES, 0, false)
                    .await?
                {
                    Some(bits) => Mode::supported(bits as u32),
                    // No 0x6502: let the drive refuse what it lacks.
                    None => vec![
                        Mode::ProfilePosition,
                        Mode::Velocity,
                        Mode::ProfileVelocity,
                        Mode::Torque,
                        Mode::Homing,
                        Mode::InterpolatedPosition,
                    ],
                }
            }
        })
    }

    fn move_modes(&self, supported: &[Mode]) -> Vec<MoveMode> {
        MoveMode::ALL
            .into_iter()
            .filter(|mode| self.kind.may_support(*mode))
            .filter(|mode| mode.modes().iter().any(|m| supported.contains(m)))
            .collect()
    }

    /// The axis, read now.
    pub async fn status(&self) -> Result<AxisStatus, DriveError> {
        let statusword = self.statusword().await?;
        let mode_raw = self
            .read_optional(obj::MODES_OF_OPERATION_DISPLAY, 0, true)
            .await?
            .unwrap_or(0) as i8;
        let supported = self.supported().await?;
        let position = self.read_optional(obj::POSITION_ACTUAL, 0, true).await?;
        let velocity = self.read_optional(obj::VELOCITY_ACTUAL, 0, true).await?;
        let torque = self.read_optional(obj::TQ_ACTUAL, 0, true).await?;
        Ok(AxisStatus {
            axis: self.axis,
            state: statusword.state().map_or("unknown", State::name).into(),
            statusword: statusword.raw(),
            mode: Mode::from_raw(mode_raw).name().map(str::to_string),
            mode_raw,
            supported_modes: self.move_modes(&supported),
            position: position.map(|v| v as i32),
            velocity: velocity.map(|v| v as i32),
            torque: torque.map(|v| v as i16),
            target_reached: statusword.target_reached(),
            fault: statusword.fault(),
        })
    }

    /// The axis's statusword, mode, position, velocity and torque, read now:
    /// one SDO transfer after another, each queued on the node's channel
    /// with everyone else's.
    pub async fn reading(&self) -> Result<AxisReading, DriveError> {
        let statusword = self.statusword().await?.raw();
        let mode_raw = self
            .read_optional(obj::MODES_OF_OPERATION_DISPLAY, 0, true)
            .await?
            .map(|mode| mode as i8);
        let position = self.read_optional(obj::POSITION_ACTUAL, 0, true).await?;
        let velocity = self.read_optional(obj::VELOCITY_ACTUAL, 0, true).await?;
        let torque = self.read_optional(obj::TQ_ACTUAL, 0, true).await?;
        Ok(AxisReading {
            statusword,
            mode_raw,
            position: position.map(|v| v as i32),
            velocity: velocity.map(|v| v as i32),
            torque: torque.map(|v| v as i16),
        })
    }

    fn fault(&self, statusword: Statusword, detail: &'static str) -> DriveError {
        DriveError::Fault {
            axis: self.axis,
            state: statusword.state().unwrap_or(State::Fault),
            statusword: statusword.raw(),
            detail,
        }
    }

    /// Polls the statusword until `done` says so; a fault ends the wait
    /// (unless `fault_ok`), so does `timeout`.
    async fn wait(
        &self,
        what: &str,
        timeout: Duration,
        fault_ok: bool,
        done: impl Fn(Statusword) -> bool,
    ) -> Result<Statusword, DriveError> {
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            let statusword = self.statusword().await?;
            if done(statusword) {
                return Ok(statusword);
            }
            let state = statusword.state();
            if !fault_ok && matches!(state, Some(State::Fault | State::FaultReactionActive)) {
                return Err(self.fault(statusword, ""));
            }
            if tokio::time::Instant::now() >= deadline {
                return Err(DriveError::Timeout {
                    axis: self.axis,
                    what: what.to_string(),
                    state,
                });
            }
            tokio::time::sleep(POLL).await;
        }
    }

    /// Walks the PDS to `target`, one transition at a time, each checked
    /// in the statusword. A drive in fault is not reset here (that is
    /// [`Drive::fault_reset`]'s, asked for on purpose).
    pub async fn set_state(&self, target: State) -> Result<AxisStatus, DriveError> {
        let _procedure = self.channel.procedure().await;
        let mut statusword = self.statusword().await?;
        // A drive initialising leaves that state by itself.
        if statusword.state() == Some(State::NotReadyToSwitchOn) {
            statusword = self
                .wait("initialisation", STEP_TIMEOUT, false, |sw| {
                    sw.state() != Some(State::NotReadyToSwitchOn)
                })
                .await?;
        }
        let Some(current) = statusword.state() else {
            return Err(DriveError::Timeout {
                axis: self.axis,
                what: format!("statusword 0x{:04X} names a state", statusword.raw()),
                state: None,
            });
        };
        if matches!(current, State::Fault | State::FaultReactionActive) {
            return Err(self.fault(statusword, ": reset the fault first (POST .../fault-reset)"));
        }
        // Transition 11 starts only from operation enabled: climbing there
        // first would power a motor only to stop it.
        if target == State::QuickStopActive
            && !matches!(current, State::OperationEnabled | State::QuickStopActive)
        {
            return Err(DriveError::NotEnabled {
                axis: self.axis,
                state: Some(current),
            });
        }
        let commands = plan(current, target).map_err(|error| match error {
            PlanError::TargetNotCommandable(_) | PlanError::Transient(_) => {
                DriveError::Invalid(error.to_string())
            }
        })?;
        for command in commands {
            self.controlword(command.bits()).await?;
            let expected = expected_state(command);
            self.wait(
                &format!("{command} (expecting {expected})"),
                STEP_TIMEOUT,
                false,
                |sw| {
                    let state = sw.state();
                    state == Some(expected)
                        // Quick stop options 1–4 end in switch on disabled.
                        || (command == Command::QuickStop && state == Some(State::SwitchOnDisabled))
                },
            )
            .await?;
        }
        self.status().await
    }

    /// Fault reset (transition 15): a 0→1 edge of controlword bit 7, then
    /// switch on disabled must show. A drive whose fault is still present
    /// stays in fault: 409.
    pub async fn fault_reset(&self) -> Result<AxisStatus, DriveError> {
        let _procedure = self.channel.procedure().await;
        let statusword = self.statusword().await?;
        if statusword.state() == Some(State::Fault) {
            self.controlword(Command::DisableVoltage.bits()).await?;
            self.controlword(Command::FaultReset.bits()).await?;
            let deadline = tokio::time::Instant::now() + ACK_TIMEOUT;
            loop {
                let statusword = self.statusword().await?;
                if statusword.state() != Some(State::Fault) {
                    break;
                }
                if tokio::time::Instant::now() >= deadline {
                    return Err(self.fault(statusword, ": the fault is still present"));
                }
                tokio::time::sleep(POLL).await;
            }
        } else if statusword.state() == Some(State::FaultReactionActive) {
            return Err(self.fault(statusword, ": the fault reaction is still running"));
        }
        self.status().await
    }

    /// The controlword the drive runs with now: read back where it can be
    /// read (UMC), else the one its state implies (the JMC's is write only).
    async fn current_controlword(&self, statusword: Statusword) -> Result<u16, DriveError> {
        let readable = self.eds.as_ref().is_none_or(|entry| {
            entry
                .eds
                .dictionary
                .sub(self.index(obj::CONTROLWORD), 0)
                .is_some_and(|sub| sub.access.is_readable())
        });
        if readable && let Some(value) = self.read_optional(obj::CONTROLWORD, 0, false).await? {
            return Ok(value as u16);
        }
        Ok(match statusword.state() {
            Some(State::OperationEnabled) => Command::EnableOperation.bits(),
            Some(State::SwitchedOn) => Command::SwitchOn.bits(),
            Some(State::ReadyToSwitchOn) => Command::Shutdown.bits(),
            _ => Command::DisableVoltage.bits(),
        })
    }

    /// Sets or clears the halt bit (controlword bit 8), the rest of the
    /// controlword kept.
    pub async fn halt(&self, halt: bool) -> Result<AxisStatus, DriveError> {
        let _procedure = self.channel.procedure().await;
        let statusword = self.statusword().await?;
        let word = self.current_controlword(statusword).await? & !0x0080;
        let word = if halt {
            word | CW_HALT
        } else {
            word & !CW_HALT
        };
        self.controlword(word).await?;
        self.status().await
    }

    /// Quick stop of an axis in operation enabled; `Ok(None)` for an axis
    /// that was not enabled (nothing to stop), else the state it was in.
    pub async fn quick_stop_if_enabled(&self) -> Result<Option<State>, DriveError> {
        let statusword = self.statusword().await?;
        if statusword.state() != Some(State::OperationEnabled) {
            return Ok(None);
        }
        self.controlword(Command::QuickStop.bits()).await?;
        Ok(Some(State::OperationEnabled))
    }

    /// What a failed move leaves: an axis still in operation enabled is
    /// halted, and quick-stopped if the halt cannot be written; an axis in
    /// any other state is not driving (a quick stop or fault got there
    /// first) and is left alone, as a halt's enable-operation bits could
    /// take it out of quick stop active again (transition 16). Best effort:
    /// the move's own error is what the caller reports.
    async fn stop_after_failure(&self) {
        let state = match self.statusword().await {
            Ok(statusword) => statusword.state(),
            // Unknown: assume the worst.
            Err(_) => Some(State::OperationEnabled),
        };
        if state != Some(State::OperationEnabled) {
            return;
        }
        let halt = Command::EnableOperation.bits() | CW_HALT;
        if let Err(error) = self.controlword(halt).await {
            tracing::warn!("axis {}: halt after a failed move: {error}", self.axis);
            if let Err(error) = self.controlword(Command::QuickStop.bits()).await {
                tracing::error!(
                    "axis {}: quick stop after a failed move: {error}",
                    self.axis
                );
            }
        }
    }

    /// The CiA 402 mode number a move uses on this drive, or 422.
    async fn mode_for(&self, mode: MoveMode) -> Result<Mode, DriveError> {
        let refuse = |supported: Vec<MoveMode>| DriveError::ModeNotSupported {
            axis: self.axis,
            mode,
            supported,
        };
        if !self.kind.may_support(mode) {
            return Err(refuse(self.move_modes(&self.supported().await?)));
        }
        let supported = self.supported().await?;
        mode.modes()
            .iter()
            .copied()
            .find(|m| supported.contains(m))
            .ok_or_else(|| refuse(self.move_modes(&supported)))
    }

    /// Checks a move before the bus: values against their objects. (A
    /// generic drive's velocity mode is known only once 0x6502 is read:
    /// [`Drive::run_move`] checks VL's 16-bit target again before writing.)
    pub fn validate(&self, request: &MoveRequest) -> Result<(), DriveError> {
        let mode = match (request, self.kind) {
            (MoveRequest::Velocity { .. }, DriveKind::Umc) => Mode::Velocity,
            (MoveRequest::Velocity { .. }, _) => Mode::ProfileVelocity,
            _ => Mode::ProfilePosition,
        };
        self.writes(request, mode).map(|_| ())
    }

    /// The parameter writes of a move (before its controlwords), for the
    /// CiA 402 `mode` it runs in.
    fn writes(&self, request: &MoveRequest, mode: Mode) -> Result<Vec<Write>, DriveError> {
        use DataType as T;
        let mut writes = Vec::new();
        let mut put = |index: u16, sub: u8, default: DataType, value: i64, what: &str| {
            writes.push(self.encode(index, sub, default, value, what)?);
            Ok::<(), DriveError>(())
        };
        match request {
            MoveRequest::ProfilePosition {
                target,
                velocity,
                acceleration,
                deceleration,
                ..
            } => {
                put(
                    obj::TARGET_POSITION,
                    0,
                    T::Integer32,
                    (*target).into(),
                    "target",
                )?;
                if let Some(v) = velocity {
                    put(obj::PROFILE_VELOCITY, 0, T::Unsigned32, *v, "velocity")?;
                }
                if let Some(a) = acceleration {
                    put(
                        obj::PROFILE_ACCELERATION,
                        0,
                        T::Unsigned32,
                        *a,
                        "acceleration",
                    )?;
                }
                if let Some(d) = deceleration {
                    put(
                        obj::PROFILE_DECELERATION,
                        0,
                        T::Unsigned32,
                        *d,
                        "deceleration",
                    )?;
                }
            }
            MoveRequest::Velocity {
                velocity,
                acceleration,
                deceleration,
            } => {
                let velocity = i64::from(*velocity);
                if mode == Mode::Velocity {
                    put(obj::VL_TARGET, 0, T::Integer16, velocity, "velocity")?;
                    if let Some(a) = acceleration {
                        put(obj::VL_ACCELERATION, 1, T::Unsigned32, *a, "acceleration")?;
                        put(obj::VL_ACCELERATION, 2, T::Unsigned16, 1, "delta time")?;
                    }
                    if let Some(d) = deceleration {
                        put(obj::VL_DECELERATION, 1, T::Unsigned32, *d, "deceleration")?;
                        put(obj::VL_DECELERATION, 2, T::Unsigned16, 1, "delta time")?;
                    }
                } else {
                    let target = match self.kind {
                        DriveKind::Jmc => jmc::VELOCITY_MOVE_TARGET,
                        _ => obj::TARGET_VELOCITY,
                    };
                    put(target, 0, T::Integer32, velocity, "velocity")?;
                    if let Some(a) = acceleration {
                        put(
                            obj::PROFILE_ACCELERATION,
                            0,
                            T::Unsigned32,
                            *a,
                            "acceleration",
                        )?;
                    }
                    if let Some(d) = deceleration {
                        put(
                            obj::PROFILE_DECELERATION,
                            0,
                            T::Unsigned32,
                            *d,
                            "deceleration",
                        )?;
                    }
                }
            }
            MoveRequest::Torque { torque, slope } => {
                put(obj::TQ_TARGET, 0, T::Integer16, (*torque).into(), "torque")?;
                if let Some(s) = slope {
                    put(obj::TQ_SLOPE, 0, T::Unsigned32, *s, "slope")?;
                }
            }
            MoveRequest::DutyCycle { duty, slope } => {
                if let Some(s) = slope {
                    put(umc::axis::DTY_SLOPE, 0, T::Unsigned16, *s, "slope")?;
                }
                put(
                    umc::axis::DTY_TARGET,
                    0,
                    T::Integer16,
                    (*duty).into(),
                    "duty",
                )?;
            }
            MoveRequest::ContinuousPosition { target, .. } => {
                // Validated only: 0x41F0 is written after the controlword.
                self.encode(
                    umc::axis::CP_TARGET,
                    0,
                    T::Integer32,
                    (*target).into(),
                    "target",
                )?;
            }
            MoveRequest::InterpolatedPosition { period_ms, points } => {
                if *period_ms == 0 {
                    return Err(DriveError::Invalid("period_ms must be 1 to 255".into()));
                }
                if points.is_empty() || points.len() > MAX_IP_POINTS {
                    return Err(DriveError::Invalid(format!(
                        "points: 1 to {MAX_IP_POINTS} positions"
                    )));
                }
                let total_ms = points.len() as u64 * u64::from(*period_ms);
                if total_ms > MAX_IP_DURATION_MS {
                    return Err(DriveError::Invalid(format!(
                        "{} points every {period_ms} ms take {total_ms} ms; at most {MAX_IP_DURATION_MS} ms in one request",
                        points.len()
                    )));
                }
                put(
                    obj::IP_TIME_PERIOD,
                    1,
                    T::Unsigned8,
                    (*period_ms).into(),
                    "period",
                )?;
                put(obj::IP_TIME_PERIOD, 2, T::Integer8, -3, "period index")?;
                put(
                    obj::IP_DATA_CONFIGURATION,
                    6,
                    T::Unsigned8,
                    0,
                    "buffer clear",
                )?;
            }
            MoveRequest::Homing {
                method,
                speeds,
                acceleration,
                offset,
            } => {
                if self.kind == DriveKind::Jmc && jmc::HomingMethod::from_raw(*method).is_none() {
                    return Err(DriveError::OutOfRange(format!(
                        "homing method {method}: the JMC has methods 0 to 12"
                    )));
                }
                put(
                    obj::HOMING_METHOD,
                    0,
                    T::Integer8,
                    (*method).into(),
                    "method",
                )?;
                if let Some([fast, slow]) = speeds {
                    put(obj::HOMING_SPEEDS, 1, T::Unsigned32, *fast, "search speed")?;
                    put(obj::HOMING_SPEEDS, 2, T::Unsigned32, *slow, "slow speed")?;
                }
                if let Some(a) = acceleration {
                    put(
                        obj::HOMING_ACCELERATION,
                        0,
                        T::Unsigned32,
                        *a,
                        "acceleration",
                    )?;
                }
                if let Some(o) = offset {
                    put(obj::HOME_OFFSET, 0, T::Integer32, (*o).into(), "offset")?;
                }
            }
        }
        Ok(writes)
    }

    /// Runs a move: checks the mode and the state, switches the mode
    /// (waiting for 0x6061 to show it), writes the parameters and gives the
    /// controlwords the mode needs. If anything fails after the first
    /// write, the axis is halted (or quick-stopped) before the error is
    /// returned.
    pub async fn run_move(&self, request: &MoveRequest) -> Result<AxisStatus, DriveError> {
        let mode = self.mode_for(request.mode()).await?;
        let writes = self.writes(request, mode)?;
        let procedure = self.channel.procedure().await;
        let statusword = self.statusword().await?;
        match statusword.state() {
            Some(State::OperationEnabled) => {}
            Some(State::Fault | State::FaultReactionActive) => {
                return Err(self.fault(statusword, ": reset the fault first"));
            }
            state => {
                return Err(DriveError::NotEnabled {
                    axis: self.axis,
                    state,
                });
            }
        }
        match self.run_steps(request, mode, &writes, procedure).await {
            Ok(()) => self.status().await,
            Err(error) => {
                self.stop_after_failure().await;
                Err(error)
            }
        }
    }

    async fn run_steps(
        &self,
        request: &MoveRequest,
        mode: Mode,
        writes: &[Write],
        procedure: OwnedMutexGuard<()>,
    ) -> Result<(), DriveError> {
        let enable = Command::EnableOperation.bits();
        self.set_mode(mode).await?;
        for write in writes {
            self.write(write).await?;
        }
        match request {
            MoveRequest::ProfilePosition {
                relative,
                immediate,
                ..
            } => {
                let word = enable
                    | if *immediate { CW_BIT5 } else { 0 }
                    | if *relative { CW_BIT6 } else { 0 };
                // Bit 4 low first, so that the next write is an edge.
                self.controlword(word).await?;
                self.controlword(word | CW_BIT4).await?;
                self.wait("set-point acknowledge", ACK_TIMEOUT, false, |sw| {
                    sw.raw() & SW_BIT12 != 0
                })
                .await?;
                self.controlword(word).await?;
            }
            MoveRequest::Velocity { .. } => {
                let word = if mode == Mode::Velocity {
                    // Ramp enabled, unlocked, on the reference (Table 2.28).
                    enable | CW_BIT4 | CW_BIT5 | CW_BIT6
                } else {
                    enable
                };
                self.controlword(word).await?;
            }
            MoveRequest::Torque { .. } => self.controlword(enable).await?,
            MoveRequest::DutyCycle { slope, .. } => {
                let word = enable | if slope.is_some() { CW_BIT4 } else { 0 };
                self.controlword(word).await?;
            }
            MoveRequest::ContinuousPosition { target, relative } => {
                self.controlword(enable | if *relative { CW_BIT6 } else { 0 })
                    .await?;
                let write = self.encode(
                    umc::axis::CP_TARGET,
                    0,
                    DataType::Integer32,
                    (*target).into(),
                    "target",
                )?;
                self.write(&write).await?;
            }
            MoveRequest::InterpolatedPosition { period_ms, points } => {
                self.interpolate(*period_ms, points, procedure).await?;
            }
            MoveRequest::Homing { .. } => {
                self.controlword(enable).await?;
                self.controlword(enable | CW_BIT4).await?;
            }
        }
        Ok(())
    }

    /// Writes 0x6060 unless the drive runs `mode` already, and waits for
    /// 0x6061 to show it.
    async fn set_mode(&self, mode: Mode) -> Result<(), DriveError> {
        let display = || async {
            self.read_int(obj::MODES_OF_OPERATION_DISPLAY, 0, true)
                .await
                .map(|raw| raw as i8)
        };
        if display().await? == mode.raw() {
            return Ok(());
        }
        self.channel
            .download(
                self.index(obj::MODES_OF_OPERATION),
                0,
                &mode.raw().to_le_bytes(),
            )
            .await?;
        let deadline = tokio::time::Instant::now() + MODE_TIMEOUT;
        while display().await? != mode.raw() {
            // A drive changing mode while it moves stops first (CiA 402
            // §5.1.5); a fault or a quick stop (STOP ALL) during that stop
            // leaves the change pending for good, and the move ends with
            // what happened, not with a timeout seconds later.
            let statusword = self.statusword().await?;
            match statusword.state() {
                Some(State::OperationEnabled) => {}
                Some(State::Fault | State::FaultReactionActive) => {
                    return Err(self.fault(statusword, " during the change of mode"));
                }
                state => {
                    return Err(DriveError::NotEnabled {
                        axis: self.axis,
                        state,
                    });
                }
            }
            if tokio::time::Instant::now() >= deadline {
                return Err(DriveError::Timeout {
                    axis: self.axis,
                    what: format!("the change to mode {mode}"),
                    state: self.statusword().await?.state(),
                });
            }
            tokio::time::sleep(POLL).await;
        }
        Ok(())
    }

    /// Interpolated position: fills the buffer, enables interpolation
    /// (bit 4), and tops the buffer up as the drive drains it, one period
    /// at a time, until every point is in.
    async fn interpolate(
        &self,
        period_ms: u8,
        points: &[i32],
        procedure: OwnedMutexGuard<()>,
    ) -> Result<(), DriveError> {
        let mut procedure = Some(procedure);
        let enable = Command::EnableOperation.bits();
        self.controlword(enable).await?;
        let capacity = self
            .read_optional(obj::IP_DATA_CONFIGURATION, 1, false)
            .await?
            .filter(|&n| n > 0)
            .unwrap_or(32)
            .min(1024) as usize;
        let mut queued = 0usize;
        let mut enabled = false;
        let period = Duration::from_millis(u64::from(period_ms));
        // Every point drains in a period; a drive that stops draining for
        // longer than the whole buffer's time is stuck.
        let stall = period * (capacity as u32 + 10) + STEP_TIMEOUT;
        let mut last_progress = tokio::time::Instant::now();
        while queued < points.len() {
            let in_buffer = self
                .read_optional(obj::IP_DATA_CONFIGURATION, 2, false)
                .await?
                .unwrap_or(0) as usize;
            let free = capacity.saturating_sub(in_buffer);
            let batch = free.min(points.len() - queued);
            for point in &points[queued..queued + batch] {
                self.channel
                    .download(self.index(obj::IP_DATA_RECORD), 1, &point.to_le_bytes())
                    .await?;
            }
            queued += batch;
            if batch > 0 {
                last_progress = tokio::time::Instant::now();
            }
            if !enabled {
                self.controlword(enable | CW_BIT4).await?;
                enabled = true;
                // The set-up is done; feeding the buffer is single
                // transfers, which must not hold off the node's other axes
                // for the whole move.
                procedure.take();
            }
            if queued < points.len() {
                let statusword = self.statusword().await?;
                if statusword.state() != Some(State::OperationEnabled) {
                    return Err(match statusword.state() {
                        Some(State::Fault | State::FaultReactionActive) => {
                            self.fault(statusword, "")
                        }
                        state => DriveError::NotEnabled {
                            axis: self.axis,
                            state,
                        },
                    });
                }
                if tokio::time::Instant::now() - last_progress > stall {
                    return Err(DriveError::Timeout {
                        axis: self.axis,
                        what: "the interpolation buffer to drain".into(),
                        state: statusword.state(),
                    });
                }
                tokio::time::sleep(period).await;
            }
        }
        Ok(())
    }
}
