//! One operation of the gateway, "end the motion on a node", for what is
//! about to change a node under its axes: a renumbering (LSS configure, the
//! vendor node-ID 0x2040, by its route or by a raw OD write) and the
//! network manager's reconfiguration (a boot-up that writes its motion
//! objects).
//!
//! Every axis of the node that is leased or that the gateway enabled is
//! stopped through the motion authority (every command admitted before is
//! void, then quick stop, NMT stop if the drive does not confirm), its
//! lease ends, and for each the `nodes` topic ([`NodeEvent::MotionEnded`]
//! with the caller's reason) and the audit log (as the gateway's) say so,
//! naming the lease's holder. An axis whose stop is not confirmed ends it
//! with a failure: the caller does not change the node under it.
//!
//! [`NodeEvent::MotionEnded`]: super::registry::NodeEvent::MotionEnded

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use crate::can::Bus;
use crate::canopen::NodeId;

use super::audit::{AuditRow, AuditTarget};
use super::authority::MotionAuthority;
use super::caller::Caller;
use super::drive::Drive;
use super::history::{History, OK};
use super::leases::MotionLeases;
use super::motion_lease::{AxisKey, mask};
use super::registry::NodeRegistry;
use super::safe_stop::{EnabledAxes, StopFailure, StopOutcome, stop_axes};
use super::service::{Gateway, ServedBus};

/// Why the motion on a node ends: what is about to change it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum MotionEnd {
    /// The device is being given the node-ID `new` (its old one is
    /// forgotten, its axes' records with it).
    Renumbered { new: NodeId },
    /// The network manager is about to write the node's configuration
    /// (its motion objects); the device keeps its node-ID.
    Reconfigured,
}

impl MotionEnd {
    /// The reason of the `motion_ended` event.
    pub(crate) fn reason(self) -> &'static str {
        match self {
            Self::Renumbered { .. } => "node_id_changed",
            Self::Reconfigured => "reconfiguration",
        }
    }

    /// What the event and the row say of one axis of `node`.
    /// `lease`: what ended of the axis's lease, if one was held.
    fn detail(self, node: NodeId, stopped: bool, lease: Option<String>) -> String {
        match self {
            Self::Renumbered { new } => format!(
                "{} before node {node} was given the node-ID {new}; {}",
                if stopped {
                    "quick-stopped"
                } else {
                    "not enabled"
                },
                lease.unwrap_or_else(|| "its record as enabled ended".to_string())
            ),
            // The record as enabled stays: the device keeps its node-ID,
            // and "enable all" brings the axis back.
            Self::Reconfigured => format!(
                "{} before the network manager writes the node's configuration (its motion objects){}",
                if stopped { "quick stop" } else { "not enabled" },
                lease.map_or_else(String::new, |ended| format!("; {ended}"))
            ),
        }
    }

    /// The audit row of one axis (its words as they have always been for
    /// each reason, so that the history reads the same).
    fn audit_target(self, bus: &str, node: NodeId, axis: u8, detail: String) -> AuditTarget {
        let target = match self {
            Self::Renumbered { .. } => {
                AuditTarget::new("motion ended: node renumbered").item(detail)
            }
            Self::Reconfigured => {
                AuditTarget::new(format!("network manager: axis {axis} stopped: {detail}"))
            }
        };
        target.bus(bus).node(node.get()).axis(axis)
    }
}

/// What ending the motion on a node needs of the gateway, for one bus.
/// The network manager's stopper holds one: holding the whole gateway, it
/// would keep itself alive through the bus it serves.
#[derive(Clone)]
pub(crate) struct NodeMotion {
    bus_name: String,
    bus: Bus,
    registry: NodeRegistry,
    leases: Arc<MotionLeases>,
    enabled: Arc<EnabledAxes>,
    authority: Arc<MotionAuthority>,
    history: History,
}

impl NodeMotion {
    /// Stops every leased or enabled axis of `node`, ends its lease (and,
    /// for a renumbering, the node's records as enabled), tells the `nodes`
    /// topic and the audit log; the axes it ended. The first axis whose
    /// stop was not confirmed fails it (nothing is ended then: the node is
    /// not to be changed).
    pub(crate) async fn end(&self, node: NodeId, why: MotionEnd) -> Result<Vec<u8>, StopFailure> {
        let bus = self.bus_name.as_str();
        let leases = self.leases.on_node(bus, node.get());
        let mut drives = self.enabled.on_node(bus, node.get());
        for lease in &leases {
            if drives.contains_key(&lease.axis.axis) {
                continue;
            }
            let drive = self.registry.node(node).and_then(|info| {
                Drive::new(&self.registry, &info, &lease.axis.axis.to_string()).ok()
            });
            if let Some(drive) = drive {
                drives.insert(lease.axis.axis, drive);
            }
        }
        // A stop wins (the motion authority): nothing admitted before it is
        // sent to the node's axes after it, known to the gateway or not.
        self.authority.cancel_node(bus, node.get());
        if drives.is_empty() && leases.is_empty() {
            return Ok(Vec::new());
        }
        let report = self.stop(&drives).await?;
        let axes: BTreeSet<u8> = drives
            .keys()
            .copied()
            .chain(leases.iter().map(|lease| lease.axis.axis))
            .collect();
        for &axis in &axes {
            let key = AxisKey {
                bus: bus.to_string(),
                node: node.get(),
                axis,
            };
            let ended = self.leases.release(&key).map(|lease| {
                format!(
                    "the {} lease {} of {} ended",
                    lease.mode,
                    mask(&lease.id),
                    lease.holder
                )
            });
            let detail = why.detail(node, report.contains(&axis), ended);
            tracing::warn!("{key}: {detail}");
            let target = why.audit_target(bus, node, axis, detail.clone());
            AuditRow::new(&self.history, &Caller::system(), target, None)
                .finish_as(OK)
                .await;
            self.registry.motion_ended(node, axis, why.reason(), detail);
        }
        if matches!(why, MotionEnd::Renumbered { .. }) {
            self.enabled.forget_node(bus, node.get());
        }
        Ok(axes.into_iter().collect())
    }

    /// Stops `drives`: the axes that confirmed a stop (those that were not
    /// enabled are not among them), or the first that could not be stopped.
    async fn stop(&self, drives: &BTreeMap<u8, Drive>) -> Result<BTreeSet<u8>, StopFailure> {
        let targets = drives
            .values()
            .map(|drive| (self.bus_name.clone(), self.bus.clone(), drive.clone()))
            .collect();
        let report = match stop_axes(self.authority.clone(), targets).await {
            Ok(report) => report,
            Err(error) => {
                return Err(StopFailure {
                    bus: self.bus_name.clone(),
                    node: drives.values().next().map_or(0, Drive::node),
                    axis: None,
                    error,
                    attempts: Vec::new(),
                });
            }
        };
        if let Some(failed) = report.failed.into_iter().next() {
            return Err(failed);
        }
        Ok(report
            .stopped
            .iter()
            .filter(|stopped| {
                stopped
                    .attempts
                    .iter()
                    .any(|attempt| attempt.outcome == StopOutcome::Confirmed)
            })
            .map(|stopped| stopped.axis.axis)
            .collect())
    }
}

impl Gateway {
    /// What ending the motion on a node of `served` needs.
    pub(crate) fn node_motion(&self, served: &ServedBus) -> NodeMotion {
        NodeMotion {
            bus_name: served.name.clone(),
            bus: served.bus.clone(),
            registry: served.registry.clone(),
            leases: self.leases.clone(),
            enabled: self.enabled_axes.clone(),
            authority: self.authority.clone(),
            history: self.history.clone(),
        }
    }

    /// Ends the motion on `node` of `served` before `why` changes it
    /// ([`NodeMotion::end`]); a stop that was not confirmed is
    /// `stop_not_confirmed`, with its attempts.
    pub(crate) async fn end_motion_on_node(
        &self,
        served: &ServedBus,
        node: NodeId,
        why: MotionEnd,
    ) -> Result<Vec<u8>, super::GatewayError> {
        self.node_motion(served)
            .end(node, why)
            .await
            .map_err(|failed| super::GatewayError::StopNotConfirmed {
                source: Box::new(failed.error),
                attempts: failed.attempts,
            })
    }
}
