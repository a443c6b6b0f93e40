//! Stopping motion whoever asks: STOP ALL (quick stop of every enabled axis
//! on every bus) and the stop on shutdown (quick stop of the axes the
//! gateway itself enabled, for SIGTERM and Ctrl-C: a drive must not be
//! left moving because the gateway went away). Both end every motion lease.

use std::collections::BTreeSet;
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use tokio::task::JoinSet;

use super::GatewayError;
use super::drive::{Drive, DriveKind, axis_count};
use super::motion_lease::AxisKey;
use super::registry::NodeInfo;
use super::service::{Gateway, ServedBus, check_sdo_allowed};

/// A node or axis that could not be stopped (or not asked).
#[derive(Debug, Clone, PartialEq)]
pub struct StopFailure {
    pub bus: String,
    pub node: u8,
    /// `None` when the node as a whole failed (offline, wrong NMT state).
    pub axis: Option<u8>,
    pub error: GatewayError,
}

/// What a stop did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StopReport {
    /// The axes that were in operation enabled and were sent quick stop.
    pub stopped: Vec<AxisKey>,
    pub failed: Vec<StopFailure>,
}

/// The axes the gateway itself enabled or set moving, by bus, node and
/// axis: the ones it stops before it exits. Axes another master enabled are
/// not the gateway's to touch.
#[derive(Debug, Default)]
pub struct EnabledAxes(Mutex<BTreeSet<(String, u8, u8)>>);

impl EnabledAxes {
    fn lock(&self) -> MutexGuard<'_, BTreeSet<(String, u8, u8)>> {
        // A set of plain keys is never left half-written.
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Records the axis of `drive` on `bus`.
    pub fn insert(&self, bus: &str, drive: &Drive) {
        self.lock()
            .insert((bus.to_string(), drive.node(), drive.axis()));
    }

    /// Every axis recorded, in order.
    pub fn list(&self) -> Vec<(String, u8, u8)> {
        self.lock().iter().cloned().collect()
    }
}

/// How long the gateway's shutdown waits for its axes to be stopped.
pub const SHUTDOWN_STOP_TIMEOUT: Duration = Duration::from_secs(5);

fn task_failed(err: tokio::task::JoinError) -> GatewayError {
    GatewayError::Internal(format!("drive task: {err}"))
}

impl Gateway {
    /// Quick stop of every enabled axis on every bus (STOP ALL): every
    /// drive node that is online is asked, all at once; an axis in
    /// operation enabled gets the quick stop command. Every lease ends.
    ///
    /// In a task of its own: dropping a `JoinSet` aborts its tasks, so the
    /// set must not live in the caller's future (a request handler's is
    /// dropped when its client hangs up).
    pub async fn stop_all(&self) -> Result<StopReport, GatewayError> {
        let report = tokio::spawn(stop_everything(self.clone()))
            .await
            .map_err(task_failed)??;
        // Every enabled axis got quick stop: no motion is left to lease.
        self.leases.release_all();
        Ok(report)
    }

    /// Quick stop of every axis the gateway enabled that is still in
    /// operation enabled, all nodes at once (for SIGTERM and Ctrl-C).
    /// Bounded by [`SHUTDOWN_STOP_TIMEOUT`]; what could not be stopped is
    /// in the report.
    pub async fn stop_enabled_axes(&self) -> StopReport {
        let mut report = StopReport::default();
        let mut tasks = JoinSet::new();
        for (bus, node, axis) in self.enabled_axes.list() {
            let prepared = (|| {
                let (served, info) = self.node(&bus, &node.to_string())?;
                Ok::<_, GatewayError>(Drive::new(&served.registry, &info, &axis.to_string())?)
            })();
            match prepared {
                Ok(drive) => {
                    tasks.spawn(
                        async move { (bus, node, axis, drive.quick_stop_if_enabled().await) },
                    );
                }
                Err(error) => report.failed.push(StopFailure {
                    bus,
                    node,
                    axis: Some(axis),
                    error,
                }),
            }
        }
        let collect = async {
            while let Some(joined) = tasks.join_next().await {
                let Ok((bus, node, axis, result)) = joined else {
                    continue;
                };
                match result {
                    Ok(Some(_)) => report.stopped.push(AxisKey { bus, node, axis }),
                    Ok(None) => {}
                    Err(error) => report.failed.push(StopFailure {
                        bus,
                        node,
                        axis: Some(axis),
                        error: error.into(),
                    }),
                }
            }
        };
        let timed_out = tokio::time::timeout(SHUTDOWN_STOP_TIMEOUT, collect)
            .await
            .is_err();
        self.leases.release_all();
        if timed_out {
            tracing::error!(
                "shutdown: axes still being stopped after {SHUTDOWN_STOP_TIMEOUT:?}; exiting anyway"
            );
        }
        report
    }
}

async fn stop_everything(gateway: Gateway) -> Result<StopReport, GatewayError> {
    let mut tasks = JoinSet::new();
    let mut report = StopReport::default();
    for (name, served) in gateway.buses.iter() {
        for info in served.registry.nodes() {
            let Some(kind) = DriveKind::from_profile(info.profile) else {
                continue;
            };
            let node = info.id.get();
            let fail = |error: GatewayError| StopFailure {
                bus: name.clone(),
                node,
                axis: None,
                error,
            };
            if !info.online {
                report.failed.push(fail(GatewayError::NodeOffline(format!(
                    "node {node} is offline"
                ))));
                continue;
            }
            if let Err(error) = check_sdo_allowed(served, &info) {
                report.failed.push(fail(error));
                continue;
            }
            let drives = match axes_of(served, &info, kind) {
                Ok(drives) => drives,
                Err(error) => {
                    report.failed.push(fail(error));
                    continue;
                }
            };
            let name = name.clone();
            tasks.spawn(async move {
                let mut results = Vec::new();
                for drive in drives {
                    results.push((drive.axis(), drive.quick_stop_if_enabled().await));
                }
                (name, node, results)
            });
        }
    }
    while let Some(joined) = tasks.join_next().await {
        let (bus, node, results) = joined.map_err(task_failed)?;
        for (axis, result) in results {
            match result {
                Ok(Some(_)) => report.stopped.push(AxisKey {
                    bus: bus.clone(),
                    node,
                    axis,
                }),
                Ok(None) => {}
                Err(error) => report.failed.push(StopFailure {
                    bus: bus.clone(),
                    node,
                    axis: Some(axis),
                    error: error.into(),
                }),
            }
        }
    }
    Ok(report)
}

fn axes_of(
    served: &ServedBus,
    info: &NodeInfo,
    kind: DriveKind,
) -> Result<Vec<Drive>, GatewayError> {
    (1..=axis_count(kind, info.eds_entry.as_deref()))
        .map(|axis| Ok(Drive::new(&served.registry, info, &axis.to_string())?))
        .collect()
}
