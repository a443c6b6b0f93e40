//! The status of each drive axis for the telemetry stream (`docs/websocket.md`,
//! `buses/{bus}/nodes/{id}/axes/{axis}`): statusword and the
//! CiA 402 state it encodes (CiA 402-2 §8.1.2), mode, position, velocity and
//! torque, with where they came from (`"source": "tpdo" | "sdo"`).
//!
//! - From the node's TPDOs when they carry the axis's statusword and
//!   position actual value (0x6041 and 0x6064, at the axis's offset on a
//!   UMC: 0x6841 and 0x6864 for axis 2) and both came within
//!   [`TPDO_FRESH`]: published as frames come, at most at the rate the
//!   readers want, the newest always last. Mode (0x6061), velocity (0x606C)
//!   and torque (0x6077) are given when the TPDOs carry them too, else
//!   null. A TPDO mapped but not sent (the node is not operational, its
//!   SYNC is off) is no source: the status is polled instead.
//! - Otherwise by SDO polling through the node's [`SdoChannel`](super::sdo::SdoChannel): one
//!   cycle (statusword, mode, position, velocity, torque) at a time, each
//!   transfer queued with every other on the node, at the readers' rate but
//!   at most [`TelemetryConfig::axis_poll_hz`]. A node known to be offline
//!   or stopped is not asked; a poll that fails publishes the last status
//!   read with an `"error"` saying why, never stale data silently.
//!
//! One task per axis that someone reads; it ends when its last reader goes,
//! and polls nothing meanwhile. A node the registry does not know (or no
//! longer, or not yet, as a drive) ends nothing: the topic waits for it.

use std::sync::Arc;
use std::time::Duration;

use serde::Serialize;
use tokio::time::Instant;

use super::drive::{AxisReading, Drive, DriveError};
use super::producers::{IDLE_CHECK, Lease, TelemetryConfig, TopicSet, idle, period, unreachable};
use super::registry::{Identification, NodeRegistry, RegistryError};
use super::telemetry::{TopicReceiver, ValueTopic};
use super::values::TpdoValues;
use crate::canopen::NodeId;
use crate::profiles::cia402::objects as obj;
use crate::profiles::cia402::{Mode, State, Statusword};
use crate::profiles::umc;

/// How recent the TPDO values of an axis must be to be its source: a
/// dashboard sees a TPDO that stopped within a second, and then the status
/// is polled.
pub(crate) const TPDO_FRESH: Duration = Duration::from_secs(1);

/// Where a status came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum Source {
    Tpdo,
    Sdo,
}

/// One sample of the axis topic.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub(crate) struct AxisSample {
    pub axis: u8,
    pub source: Source,
    /// The PDS state by its API name (`operation_enabled`, ...), `unknown`
    /// for a statusword CiA 402 does not define; null before anything was
    /// read.
    pub state: Option<&'static str>,
    pub statusword: Option<u16>,
    /// The mode displayed (0x6061) by its name; null when not read or
    /// without a name.
    pub mode: Option<&'static str>,
    pub mode_raw: Option<i8>,
    pub position: Option<i32>,
    pub velocity: Option<i32>,
    pub torque: Option<i16>,
    pub target_reached: Option<bool>,
    pub fault: Option<bool>,
    /// Why this sample is not new: the poll failed, the node is offline or
    /// stopped. The other fields are then the last ones read.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl AxisSample {
    fn new(axis: u8, source: Source, reading: &AxisReading) -> Self {
        let statusword = Statusword(reading.statusword);
        Self {
            axis,
            source,
            state: Some(statusword.state().map_or("unknown", State::name)),
            statusword: Some(reading.statusword),
            mode: reading
                .mode_raw
                .and_then(|mode| Mode::from_raw(mode).name()),
            mode_raw: reading.mode_raw,
            position: reading.position,
            velocity: reading.velocity,
            torque: reading.torque,
            target_reached: Some(statusword.target_reached()),
            fault: Some(statusword.fault()),
            error: None,
        }
    }

    /// `last` (or nothing known) with `error`.
    fn failed(axis: u8, source: Source, last: Option<&AxisSample>, error: String) -> Self {
        let mut sample = last.cloned().unwrap_or(Self {
            axis,
            source,
            state: None,
            statusword: None,
            mode: None,
            mode_raw: None,
            position: None,
            velocity: None,
            torque: None,
            target_reached: None,
            fault: None,
            error: None,
        });
        sample.source = source;
        sample.error = Some(error);
        sample
    }

    fn to_json(&self) -> serde_json::Value {
        // Plain numbers, strings and options: nothing that fails to
        // serialize.
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }
}

/// The axis topics of one bus; cheap to clone. The tasks stop when the
/// last clone is dropped.
#[derive(Clone)]
pub struct AxisTelemetry {
    inner: Arc<Inner>,
}

struct Inner {
    registry: NodeRegistry,
    values: TpdoValues,
    config: TelemetryConfig,
    topics: TopicSet<(NodeId, u8)>,
}

impl AxisTelemetry {
    /// The axes of the drives `registry` knows, fed by `values` (the TPDOs
    /// of the same bus) or SDO polling.
    pub fn new(registry: NodeRegistry, values: TpdoValues, config: TelemetryConfig) -> Self {
        Self {
            inner: Arc::new(Inner {
                registry,
                values,
                config,
                topics: TopicSet::new(),
            }),
        }
    }

    /// A reader of axis `axis` of `node` wanting `rate_hz`. An unknown
    /// node, a node that is no drive and an axis the drive does not have
    /// are errors, as they are for `GET .../axes/{axis}`; but a node the
    /// gateway is still identifying (it has just booted: the gateway
    /// started, or the node was reset or plugged back) is no drive *yet*,
    /// so its topic is made and waits for it, as it waits for a drive that
    /// goes and comes back. Refusing it sent a client that subscribed in
    /// that window one error and then nothing, for good.
    pub fn subscribe(
        &self,
        node: NodeId,
        axis: u8,
        rate_hz: f64,
    ) -> Result<TopicReceiver, DriveError> {
        let registry = &self.inner.registry;
        let info = registry
            .node(node)
            .ok_or_else(|| RegistryError::UnknownNode {
                bus: registry.bus_name().to_string(),
                node,
            })?;
        if info.identification != Identification::Pending {
            Drive::new(registry, &info, &axis.to_string())?;
        } else if !(1..=umc::MAX_AXES).contains(&axis) {
            // No drive has more axes than a UMC can.
            return Err(DriveError::UnknownAxis {
                node: node.get(),
                axis: axis.to_string(),
                axes: umc::MAX_AXES,
            });
        }
        let task = AxisTask {
            registry: registry.clone(),
            values: self.inner.values.clone(),
            max_poll_hz: self.inner.config.axis_poll_hz,
            node,
            axis,
        };
        Ok(self
            .inner
            .topics
            .subscribe((node, axis), rate_hz, move |topic, lease| {
                task.run(topic, lease)
            }))
    }

    /// The topic of an axis, if anyone ever subscribed to it.
    pub fn topic(&self, node: NodeId, axis: u8) -> Option<ValueTopic> {
        self.inner.topics.topic(&(node, axis))
    }

    /// Whether the task of an axis runs (it does while someone reads).
    pub fn is_running(&self, node: NodeId, axis: u8) -> bool {
        self.inner.topics.is_running(&(node, axis))
    }
}

/// What the task of one axis works with.
struct AxisTask {
    registry: NodeRegistry,
    values: TpdoValues,
    max_poll_hz: f64,
    node: NodeId,
    axis: u8,
}

impl AxisTask {
    async fn run(self, topic: ValueTopic, lease: Lease<(NodeId, u8)>) {
        let mut frames = self.values.watch_frames(self.node);
        let mut last: Option<AxisSample> = None;
        let mut tpdo_due: Option<Instant> = None;
        let mut last_poll: Option<Instant> = None;
        while lease.keep_going() {
            let wanted = topic.wanted_rate_hz().unwrap_or(1.0);
            let drive = self.registry.node(self.node).and_then(|info| {
                Some((
                    Drive::new(&self.registry, &info, &self.axis.to_string()).ok()?,
                    info,
                ))
            });
            let Some((drive, info)) = drive else {
                // Gone, or no drive any more: wait for it.
                idle(&topic, IDLE_CHECK).await;
                continue;
            };

            if self.tpdo_sample(&drive, Instant::now()).is_some() {
                if let Some(due) = tpdo_due {
                    tokio::time::sleep_until(due).await;
                }
                // Seen before reading: a frame from here on calls for the
                // next publish.
                frames.borrow_and_update();
                if let Some(sample) = self.tpdo_sample(&drive, Instant::now()) {
                    topic.publish(sample.to_json());
                    // On a steady cadence, as the values topic (see
                    // `publish_values`).
                    let every = period(wanted);
                    let now = Instant::now();
                    tpdo_due = Some(tpdo_due.map_or(now, |due| due.max(now - every)) + every);
                    last = Some(sample);
                }
                tokio::select! {
                    changed = frames.changed() => if changed.is_err() { return },
                    () = topic.readers_changed() => {}
                    () = tokio::time::sleep(TPDO_FRESH) => {}
                }
                continue;
            }

            let poll_period = period(wanted.min(self.max_poll_hz));
            let now = Instant::now();
            let due = last_poll.map_or(now, |polled| polled + poll_period);
            if now < due {
                idle(&topic, due - now).await;
                continue;
            }
            // On schedule unless a cycle ran late by a whole period: the
            // rate holds however long each cycle takes.
            last_poll = Some(if now - due < poll_period { due } else { now });
            let sample = match unreachable(&info) {
                Some(why) => AxisSample::failed(self.axis, Source::Sdo, last.as_ref(), why),
                None => match drive.reading().await {
                    Ok(reading) => AxisSample::new(self.axis, Source::Sdo, &reading),
                    Err(err) => {
                        AxisSample::failed(self.axis, Source::Sdo, last.as_ref(), err.to_string())
                    }
                },
            };
            topic.publish(sample.to_json());
            if sample.error.is_none() {
                last = Some(sample);
            }
        }
    }

    /// The status from the TPDO values, if they carry the axis's statusword
    /// and position and both are fresh at `now`.
    fn tpdo_sample(&self, drive: &Drive, now: Instant) -> Option<AxisSample> {
        let value = |index: u16| self.values.value(self.node, drive.object(index), 0);
        let fresh = |at: Instant| now.saturating_duration_since(at) <= TPDO_FRESH;
        let statusword = value(obj::STATUSWORD).filter(|value| fresh(value.at))?;
        let position = value(obj::POSITION_ACTUAL).filter(|value| fresh(value.at))?;
        let optional = |index: u16, signed: bool| {
            value(index)
                .filter(|value| fresh(value.at))
                .map(|value| value.as_i64(signed))
        };
        let reading = AxisReading {
            statusword: statusword.as_i64(false) as u16,
            mode_raw: optional(obj::MODES_OF_OPERATION_DISPLAY, true).map(|mode| mode as i8),
            position: Some(position.as_i64(true) as i32),
            velocity: optional(obj::VELOCITY_ACTUAL, true).map(|v| v as i32),
            torque: optional(obj::TQ_ACTUAL, true).map(|v| v as i16),
        };
        Some(AxisSample::new(self.axis, Source::Tpdo, &reading))
    }
}
