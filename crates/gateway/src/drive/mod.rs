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
//!
//! # Layout
//!
//! - this module: [`Drive`], one axis, and what every sequence uses
//!   (encoded writes, reads, the statusword, waits); [`axis_count`] and
//!   [`axes_summary`].
//! - `kind`: [`DriveKind`], what differs between products.
//! - `types`: the requests (moves, target states) and the axis status the
//!   master answers with.
//! - `error`: why a request failed, [`DriveError`].
//! - `state`: the state walk, fault reset, halt and quick stop.
//! - `moves`: a move in each mode: its mode, its writes, its controlwords.

mod error;
mod kind;
mod moves;
mod state;
mod types;

pub use error::DriveError;
pub use kind::DriveKind;
pub use types::{AxisLimits, AxisStatus, AxisUnits, MoveMode, MoveRequest, TargetState};
pub(crate) use types::{AxisReading, MAX_IP_DURATION_MS, MAX_IP_POINTS};

use std::sync::Arc;
use std::time::Duration;

use crate::canopen::od::DataType;
use crate::profile::EdsEntry;
use crate::profiles::cia402::objects as obj;
use crate::profiles::cia402::{Mode, State, Statusword};
use crate::profiles::{jmc, umc};
use crate::registry::{NodeInfo, NodeRegistry};
use crate::sdo::SdoChannel;

/// How long one step of the state walk may take to show in the
/// statusword: a quick stop or a disable may run a deceleration ramp first.
pub(crate) const STEP_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a mode change may take (a UMC stops on its halt ramp first).
pub(crate) const MODE_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a drive may take to acknowledge a set-point or start homing.
pub(crate) const ACK_TIMEOUT: Duration = Duration::from_secs(1);
/// The statusword is read this often while waiting.
pub(super) const POLL: Duration = Duration::from_millis(5);

/// Controlword bit 4: PP new set-point, VL ramp enable, IP interpolation
/// enable, HM start, UMC DTY slope.
pub(super) const CW_BIT4: u16 = 1 << 4;
/// Controlword bit 5: PP change immediately, VL ramp unlock.
pub(super) const CW_BIT5: u16 = 1 << 5;
/// Controlword bit 6: PP and CP relative, VL use reference.
pub(super) const CW_BIT6: u16 = 1 << 6;
/// Controlword bit 8, halt.
pub(super) const CW_HALT: u16 = 1 << 8;
/// Statusword bit 12 in PP: set-point acknowledge.
pub(super) const SW_BIT12: u16 = 1 << 12;

/// One SDO write, encoded and checked before the bus is touched.
#[derive(Debug, Clone)]
pub(super) struct Write {
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
pub(crate) async fn axes_summary(
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
            ticket: None,
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
    /// The command's right to the axis, when it runs for one: each write
    /// goes under the axis's gate, and none after a stop
    /// (`crate::authority`). A stop's drive has none.
    ticket: Option<crate::authority::AxisTicket>,
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
            ticket: None,
        })
    }

    /// The same axis for a command holding `ticket`: every write it sends
    /// goes under the axis's gate, and none once a stop voided the ticket
    /// (`DriveError::Stopped`).
    pub(crate) fn with_ticket(mut self, ticket: crate::authority::AxisTicket) -> Self {
        self.ticket = Some(ticket);
        self
    }

    /// The same axis without a ticket: what a command must put back after
    /// it ends (a step test's lifted ramps) is written even once a stop
    /// voided the command's ticket.
    pub(crate) fn untethered(&self) -> Self {
        Self {
            ticket: None,
            ..self.clone()
        }
    }

    /// One download to the node, through the ticket when there is one.
    pub(super) async fn download(
        &self,
        index: u16,
        sub: u8,
        data: &[u8],
    ) -> Result<(), DriveError> {
        let transfer = self.channel.download(index, sub, data);
        match &self.ticket {
            None => Ok(transfer.await?),
            Some(ticket) => match ticket.gated(transfer).await {
                Some(result) => Ok(result?),
                None => Err(DriveError::Stopped(ticket.refusal_text())),
            },
        }
    }

    /// The node's id.
    pub fn node(&self) -> u8 {
        self.channel.node().get()
    }

    pub fn node_id(&self) -> crate::canopen::NodeId {
        self.channel.node()
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
    pub(super) fn index(&self, index: u16) -> u16 {
        match self.kind {
            DriveKind::Umc => umc::axis_index(self.axis, index).unwrap_or(index),
            DriveKind::Jmc | DriveKind::Cia402 => index,
        }
    }

    /// Whether the EDS says the object exists (true without an EDS).
    pub(super) fn has(&self, index: u16) -> bool {
        self.eds
            .as_ref()
            .is_none_or(|entry| entry.eds.dictionary.get(self.index(index)).is_some())
    }

    /// `value` as the object's bytes: the EDS's type for it, else
    /// `default`; out of range is an error before the bus.
    pub(super) fn encode(
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

    pub(super) async fn write(&self, write: &Write) -> Result<(), DriveError> {
        self.download(write.index, write.sub, &write.data).await
    }

    pub(super) async fn read_int(
        &self,
        index: u16,
        sub: u8,
        signed: bool,
    ) -> Result<i64, DriveError> {
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
    pub(super) async fn read_optional(
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

    pub(super) async fn controlword(&self, value: u16) -> Result<(), DriveError> {
        self.download(self.index(obj::CONTROLWORD), 0, &value.to_le_bytes())
            .await
    }

    /// The CiA 402 modes the drive says it supports (0x6502); the JMC's
    /// fixed three.
    pub(super) async fn supported(&self) -> Result<Vec<Mode>, DriveError> {
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

    pub(super) fn move_modes(&self, supported: &[Mode]) -> Vec<MoveMode> {
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

    /// The limits the axis applies to requests and its factor group, read
    /// now; each `None` where the drive lacks the object.
    pub async fn limits(&self) -> Result<AxisLimits, DriveError> {
        let u32_of = |value: Option<i64>| value.map(|v| v as u32);
        let pair = |a: Option<i64>, b: Option<i64>| a.zip(b).map(|(a, b)| [a as u32, b as u32]);
        let software = self
            .read_optional(obj::SOFTWARE_POSITION_LIMIT, 1, true)
            .await?
            .zip(
                self.read_optional(obj::SOFTWARE_POSITION_LIMIT, 2, true)
                    .await?,
            )
            .map(|(min, max)| [min as i32, max as i32])
            .filter(|limits| *limits != [0, 0]);
        let dimension = self
            .read_optional(obj::VL_DIMENSION_FACTOR, 1, true)
            .await?
            .zip(
                self.read_optional(obj::VL_DIMENSION_FACTOR, 2, true)
                    .await?,
            )
            .map(|(n, d)| [n as i32, d as i32]);
        Ok(AxisLimits {
            max_profile_velocity: u32_of(
                self.read_optional(obj::MAX_PROFILE_VELOCITY, 0, false)
                    .await?,
            ),
            max_motor_speed: u32_of(self.read_optional(obj::MAX_MOTOR_SPEED, 0, false).await?),
            profile_velocity: u32_of(self.read_optional(obj::PROFILE_VELOCITY, 0, false).await?),
            profile_acceleration: u32_of(
                self.read_optional(obj::PROFILE_ACCELERATION, 0, false)
                    .await?,
            ),
            vl_min: u32_of(self.read_optional(obj::VL_MIN_MAX, 1, false).await?),
            vl_max: u32_of(self.read_optional(obj::VL_MIN_MAX, 2, false).await?),
            vl_dimension_factor: dimension,
            software_position_limit: software,
            encoder_resolution: pair(
                self.read_optional(obj::POSITION_ENCODER_RESOLUTION, 1, false)
                    .await?,
                self.read_optional(obj::POSITION_ENCODER_RESOLUTION, 2, false)
                    .await?,
            ),
            gear_ratio: pair(
                self.read_optional(obj::GEAR_RATIO, 1, false).await?,
                self.read_optional(obj::GEAR_RATIO, 2, false).await?,
            ),
        })
    }

    /// The units of the axis's values (its product's).
    pub fn units(&self) -> AxisUnits {
        self.kind.units()
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

    pub(super) fn fault(&self, statusword: Statusword, detail: &'static str) -> DriveError {
        DriveError::Fault {
            axis: self.axis,
            state: statusword.state().unwrap_or(State::Fault),
            statusword: statusword.raw(),
            detail,
        }
    }

    /// Polls the statusword until `done` says so; a fault ends the wait
    /// (unless `fault_ok`), so does `timeout`.
    pub(super) async fn wait(
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
}
