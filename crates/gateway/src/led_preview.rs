//! The LED preview of each UIO1LED for the telemetry stream
//! (`docs/websocket.md`, `buses/{bus}/nodes/{id}/segments`): the
//! same [`Preview`](super::uioled::Preview) as `GET .../segments/preview`,
//! drawn by the one renderer of [`crate::profiles::uioled`].
//!
//! While someone reads, the segment parameters are read over the node's SDO
//! channel every [`TelemetryConfig::segments_read_period`] (and at once
//! after the node confirms a write, whichever door or task sent it:
//! [`NodeRegistry::subscribe_writes`]);
//! between reads the pixels are drawn from them at the rate the readers
//! want, each segment as far on from its read as the time since (Speed
//! moves Value every millisecond on the device, and the renderer is that
//! movement's closed form), so an animated effect moves smoothly without an
//! SDO transfer per frame. A read that fails leaves the last parameters in
//! use, and the samples say why in `"error"`. Nobody reading, no task.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::broadcast::error::RecvError;
use tokio::time::Instant;

use super::producers::{IDLE_CHECK, Lease, TelemetryConfig, TopicSet, idle, period, unreachable};
use super::profile::Profile;
use super::registry::{Identification, NodeRegistry, RegistryError};
use super::telemetry::{TopicReceiver, ValueTopic};
use super::uioled::{ReadSegment, preview, read_preview};
use crate::canopen::NodeId;

/// Why a preview cannot be subscribed to.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PreviewError {
    #[error(transparent)]
    Registry(#[from] RegistryError),
    #[error("node {node} is no LED controller (profile {profile}): it has no segments")]
    NotAnLedController { node: NodeId, profile: Profile },
}

/// The LED previews of one bus; cheap to clone. The tasks stop when the
/// last clone is dropped.
#[derive(Clone)]
pub struct LedPreviews {
    inner: Arc<Inner>,
}

struct Inner {
    registry: NodeRegistry,
    read_period: Duration,
    topics: TopicSet<NodeId>,
}

impl LedPreviews {
    pub fn new(registry: NodeRegistry, config: &TelemetryConfig) -> Self {
        Self {
            inner: Arc::new(Inner {
                registry,
                // Never a busy loop of reads, whatever the configuration.
                read_period: config.segments_read_period.max(Duration::from_millis(10)),
                topics: TopicSet::new(),
            }),
        }
    }

    /// A reader of the preview of `node` wanting `rate_hz`; an unknown node
    /// and a node that is no LED controller are errors, but a node still
    /// being identified is not known to be none: its topic waits for it
    /// (see [`AxisTelemetry::subscribe`](super::axis_telemetry::AxisTelemetry::subscribe)).
    pub fn subscribe(&self, node: NodeId, rate_hz: f64) -> Result<TopicReceiver, PreviewError> {
        let registry = &self.inner.registry;
        let info = registry
            .node(node)
            .ok_or_else(|| RegistryError::UnknownNode {
                bus: registry.bus_name().to_string(),
                node,
            })?;
        if info.profile != Profile::Uioled && info.identification != Identification::Pending {
            return Err(PreviewError::NotAnLedController {
                node,
                profile: info.profile,
            });
        }
        let task = PreviewTask {
            registry: registry.clone(),
            read_period: self.inner.read_period,
            node,
        };
        Ok(self
            .inner
            .topics
            .subscribe(node, rate_hz, move |topic, lease| task.run(topic, lease)))
    }

    /// The preview topic of `node`, if anyone ever subscribed to it.
    pub fn topic(&self, node: NodeId) -> Option<ValueTopic> {
        self.inner.topics.topic(&node)
    }

    /// Whether the task of `node`'s preview runs (it does while someone
    /// reads).
    pub fn is_running(&self, node: NodeId) -> bool {
        self.inner.topics.is_running(&node)
    }
}

struct PreviewTask {
    registry: NodeRegistry,
    read_period: Duration,
    node: NodeId,
}

impl PreviewTask {
    async fn run(self, topic: ValueTopic, lease: Lease<NodeId>) {
        let mut segments: Option<Vec<ReadSegment>> = None;
        let mut error: Option<String> = None;
        let mut last_read: Option<Instant> = None;
        // Subscribed before the first read: no write is missed after it.
        let mut writes = self.registry.subscribe_writes();
        let mut written = false;
        while lease.keep_going() {
            let now = Instant::now();
            if written || last_read.is_none_or(|at| now >= at + self.read_period) {
                let info = self
                    .registry
                    .node(self.node)
                    .filter(|info| info.profile == Profile::Uioled);
                let Some(info) = info else {
                    // Gone, or no LED controller any more: wait for it.
                    last_read = None;
                    idle(&topic, IDLE_CHECK).await;
                    continue;
                };
                written = false;
                last_read = Some(now);
                let read = match unreachable(&info) {
                    Some(why) => Err(why),
                    None => match self.registry.sdo(self.node) {
                        Ok(channel) => read_preview(&channel).await.map_err(|err| err.to_string()),
                        Err(err) => Err(err.to_string()),
                    },
                };
                match read {
                    Ok(read) => {
                        segments = Some(read);
                        error = None;
                    }
                    Err(why) => error = Some(why),
                }
            }
            let now = Instant::now();
            let mut data = match &segments {
                // Plain numbers and strings: nothing that fails to
                // serialize.
                Some(segments) => {
                    serde_json::to_value(preview(segments, now)).unwrap_or(serde_json::Value::Null)
                }
                None => serde_json::json!({}),
            };
            if let (Some(why), Some(object)) = (&error, data.as_object_mut()) {
                object.insert("error".into(), why.clone().into());
            }
            topic.publish(data);
            let wanted = topic.wanted_rate_hz().unwrap_or(1.0);
            let next_read = last_read.map_or(now, |at| at + self.read_period);
            let next = (now + period(wanted)).min(next_read);
            tokio::select! {
                () = tokio::time::sleep_until(next) => {}
                write = writes.recv() => match write {
                    Ok(write) => written |= write.node == self.node,
                    // Writes were missed: this node's may be among them.
                    Err(RecvError::Lagged(_)) => written = true,
                    // The registry lives as long as this task's handle of it.
                    Err(RecvError::Closed) => return,
                },
                () = topic.readers_changed() => {}
            }
        }
    }
}
