//! Stopping motion whoever asks (CiA 402-2 §6.3, quick stop; CiA 301
//! §7.2.8.3.2.1, NMT stop): STOP ALL, the quick stop and halt of one axis,
//! the stop on shutdown (SIGTERM, Ctrl-C: a drive must not be left moving
//! because the gateway went away) and the stop of a lapsed motion lease.
//!
//! A stop is always sent, whatever the gateway believes of the node:
//! offline (its heartbeat lost), in an NMT state that allows no SDO, not
//! identified yet. Each step has a short timeout of its own, the wait in
//! the node's SDO queue included, and each falls back to the next:
//!
//! 1. quick stop by controlword (0x6040 of the axis, at the product's axis
//!    offset), confirmed when the statusword (0x6041) shows the axis out of
//!    operation enabled;
//! 2. if the drive does not confirm, or does not answer, or the transfer
//!    fails: NMT stop of the node, after which the drive reacts as its
//!    0x6007 (abort connection option) says.
//!
//! What was tried and what the drive confirmed is reported axis by axis as
//! [`StopAttempt`]s.

use crate::policy::Operation;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use serde::Serialize;
use tokio::task::JoinSet;

use super::GatewayError;
use super::audit::AuditTarget;
use super::authority::MotionAuthority;
use super::caller::Caller;
use super::drive::{AxisStatus, Drive, DriveKind, axis_count};
use super::motion_lease::AxisKey;
use super::service::Gateway;
use crate::can::Bus;
use crate::canopen::NodeId;
use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};
use crate::canopen::sdo::ClientConfig;
use crate::profiles::cia402::objects as obj;
use crate::profiles::cia402::{Command, State, Statusword};

/// How long one SDO transfer of a stop may take, its wait in the node's
/// queue included.
pub(crate) const STOP_STEP_TIMEOUT: Duration = Duration::from_millis(500);
/// How long the statusword is read back for the drive to show a quick
/// stop (it enters quick stop active at once and ramps down there).
pub(crate) const STOP_CONFIRM_TIMEOUT: Duration = Duration::from_millis(500);
/// How long a halt (statusword, controlword read back, controlword
/// written, status) may take before the quick stop takes over.
pub(crate) const HALT_TIMEOUT: Duration = Duration::from_secs(1);
/// The statusword is read this often while a quick stop is confirmed.
const CONFIRM_POLL: Duration = Duration::from_millis(10);
/// How long the gateway's shutdown waits for its axes to be stopped.
pub(crate) const SHUTDOWN_STOP_TIMEOUT: Duration = Duration::from_secs(5);

/// How a stop was tried.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopMethod {
    /// Controlword bit 8 (halt), the rest of the controlword kept.
    Halt,
    /// The quick stop command in the axis's controlword.
    QuickStop,
    /// NMT stop of the whole node.
    NmtStop,
}

/// What came of one [`StopMethod`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopOutcome {
    /// The drive showed it: the statusword out of operation enabled after a
    /// quick stop; the controlword written and the axis read back after a
    /// halt.
    Confirmed,
    /// Sent, but not confirmed: the controlword was written and the
    /// statusword did not show the stop in time; an NMT stop is never
    /// confirmed.
    Sent,
    /// The node did not answer in time.
    Timeout,
    /// The node refused the transfer (`detail` has the abort code).
    SdoAbort,
    /// The node broke the SDO protocol.
    SdoProtocolError,
    /// The bus could not carry the frame.
    BusDown,
    /// Not tried: the node did not answer an earlier axis's transfer.
    Skipped,
    /// Anything else (`detail` says what).
    Failed,
}

/// One step of a stop.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct StopAttempt {
    pub method: StopMethod,
    pub outcome: StopOutcome,
    /// What the drive showed or why the step failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub detail: Option<String>,
}

impl StopAttempt {
    fn new(method: StopMethod, outcome: StopOutcome, detail: impl Into<String>) -> Self {
        Self {
            method,
            outcome,
            detail: Some(detail.into()),
        }
    }

    fn failed(method: StopMethod, error: &GatewayError, context: &str) -> Self {
        let outcome = match error {
            GatewayError::SdoTimeout { .. } => StopOutcome::Timeout,
            GatewayError::SdoAbort { .. } => StopOutcome::SdoAbort,
            GatewayError::SdoProtocol { .. } => StopOutcome::SdoProtocolError,
            GatewayError::BusDown(_) => StopOutcome::BusDown,
            _ => StopOutcome::Failed,
        };
        Self::new(method, outcome, format!("{context}{error}"))
    }
}

/// How the stop of one axis ended.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum AxisStop {
    /// The drive said the axis was not in operation enabled: nothing
    /// moved under power to be stopped. Its state, if the statusword names
    /// one.
    NotEnabled(Option<State>),
    /// The drive confirmed the stop (the last attempt).
    Stopped(Vec<StopAttempt>),
    /// The drive did not confirm: the first failure, and every attempt
    /// (an NMT stop last, when it was sent).
    Failed {
        error: GatewayError,
        attempts: Vec<StopAttempt>,
    },
}

/// An axis a stop confirmed.
#[derive(Debug, Clone, PartialEq)]
pub struct StoppedAxis {
    pub axis: AxisKey,
    pub attempts: Vec<StopAttempt>,
}

/// A node or axis that could not be stopped (or not asked).
#[derive(Debug, Clone, PartialEq)]
pub struct StopFailure {
    pub bus: String,
    pub node: u8,
    /// `None` when the node as a whole failed (its axes could not be
    /// named).
    pub axis: Option<u8>,
    pub error: GatewayError,
    /// What was tried, in order.
    pub attempts: Vec<StopAttempt>,
}

/// What a stop did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StopReport {
    /// The axes that were in operation enabled and confirmed the stop.
    pub stopped: Vec<StoppedAxis>,
    pub failed: Vec<StopFailure>,
}

impl StopReport {
    fn add(&mut self, bus: &str, node: u8, axis: u8, stop: AxisStop) {
        match stop {
            AxisStop::NotEnabled(_) => {}
            AxisStop::Stopped(attempts) => self.stopped.push(StoppedAxis {
                axis: AxisKey {
                    bus: bus.to_string(),
                    node,
                    axis,
                },
                attempts,
            }),
            AxisStop::Failed { error, attempts } => self.failed.push(StopFailure {
                bus: bus.to_string(),
                node,
                axis: Some(axis),
                error,
                attempts,
            }),
        }
    }
}

/// The axes the gateway itself enabled or set moving, by bus, node and
/// axis, with the drive as it was then: the ones it stops before it exits
/// and in every STOP ALL, even when the registry no longer knows the node
/// as a drive (a node rebooting is not identified yet).
#[derive(Default)]
pub(crate) struct EnabledAxes(Mutex<BTreeMap<(String, u8, u8), Drive>>);

impl std::fmt::Debug for EnabledAxes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_set().entries(self.lock().keys()).finish()
    }
}

impl EnabledAxes {
    fn lock(&self) -> MutexGuard<'_, BTreeMap<(String, u8, u8), Drive>> {
        // A map of plain keys and handles is never left half-written.
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Records the axis of `drive` on `bus`.
    pub(crate) fn insert(&self, bus: &str, drive: &Drive) {
        self.lock()
            .insert((bus.to_string(), drive.node(), drive.axis()), drive.clone());
    }

    /// The drive recorded for an axis.
    pub(crate) fn get(&self, bus: &str, node: u8, axis: u8) -> Option<Drive> {
        self.lock().get(&(bus.to_string(), node, axis)).cloned()
    }

    /// The axes of `node` of `bus` recorded, by number.
    pub(crate) fn on_node(&self, bus: &str, node: u8) -> BTreeMap<u8, Drive> {
        self.lock()
            .iter()
            .filter(|((b, n, _), _)| b == bus && *n == node)
            .map(|((_, _, axis), drive)| (*axis, drive.clone()))
            .collect()
    }

    /// Forgets the axes of `node` of `bus` (the device no longer has that
    /// node-ID: nothing is to be stopped there).
    pub(crate) fn forget_node(&self, bus: &str, node: u8) {
        self.lock().retain(|(b, n, _), _| !(b == bus && *n == node));
    }

    /// The axes recorded on `bus`, as (node, axis): what "enable all" of
    /// the machine's recovery enables again (issue 31, `alarms/recovery.rs`).
    pub(crate) fn axes_on(&self, bus: &str) -> Vec<(u8, u8)> {
        self.lock()
            .keys()
            .filter(|(on, _, _)| on == bus)
            .map(|(_, node, axis)| (*node, *axis))
            .collect()
    }

    fn drives(&self) -> Vec<(String, Drive)> {
        self.lock()
            .iter()
            .map(|((bus, _, _), drive)| (bus.clone(), drive.clone()))
            .collect()
    }
}

fn task_failed(err: tokio::task::JoinError) -> GatewayError {
    GatewayError::Internal(format!("stop task: {err}"))
}

/// One axis to stop, with bounded transfers of its own.
struct Stopper {
    drive: Drive,
    config: ClientConfig,
}

impl Stopper {
    fn new(drive: Drive) -> Self {
        let mut config = drive.channel().config().clone();
        config.timeout = config.timeout.min(STOP_STEP_TIMEOUT);
        Self { drive, config }
    }

    fn node(&self) -> u8 {
        self.drive.node()
    }

    /// A transfer bounded by [`STOP_STEP_TIMEOUT`], the queue included.
    async fn bounded<T>(
        &self,
        transfer: impl Future<Output = Result<T, super::sdo::SdoRequestError>>,
    ) -> Result<T, GatewayError> {
        match tokio::time::timeout(STOP_STEP_TIMEOUT, transfer).await {
            Ok(result) => result.map_err(GatewayError::from),
            Err(_) => Err(GatewayError::SdoTimeout { node: self.node() }),
        }
    }

    async fn statusword(&self) -> Result<Statusword, GatewayError> {
        let index = self.drive.object(obj::STATUSWORD);
        let data = self
            .bounded(
                self.drive
                    .channel()
                    .upload_with(index, 0, Some(&self.config)),
            )
            .await?;
        let mut bytes = [0u8; 2];
        for (byte, value) in bytes.iter_mut().zip(&data) {
            *byte = *value;
        }
        Ok(Statusword(u16::from_le_bytes(bytes)))
    }

    async fn controlword(&self, word: u16) -> Result<(), GatewayError> {
        let index = self.drive.object(obj::CONTROLWORD);
        self.bounded(self.drive.channel().download_with(
            index,
            0,
            &word.to_le_bytes(),
            Some(&self.config),
        ))
        .await
    }

    /// Quick stop by controlword, confirmed in the statusword; no fallback.
    async fn quick_stop(&self) -> AxisStop {
        let method = StopMethod::QuickStop;
        let fail = |error: GatewayError, context: &str| AxisStop::Failed {
            attempts: vec![StopAttempt::failed(method, &error, context)],
            error,
        };
        match self.statusword().await {
            Ok(statusword) => match statusword.state() {
                Some(State::OperationEnabled) | None => {}
                state => return AxisStop::NotEnabled(state),
            },
            // Not heard at all: the write would wait as long for nothing.
            Err(error @ (GatewayError::SdoTimeout { .. } | GatewayError::BusDown(_))) => {
                return fail(error, "statusword not read: ");
            }
            // It answers, and refused the read: the write may still work.
            Err(_) => {}
        }
        if let Err(error) = self.controlword(Command::QuickStop.bits()).await {
            return fail(error, "controlword not written: ");
        }
        let deadline = tokio::time::Instant::now() + STOP_CONFIRM_TIMEOUT;
        loop {
            let last = match self.statusword().await {
                Ok(statusword) => match statusword.state() {
                    Some(state) if state != State::OperationEnabled => {
                        return AxisStop::Stopped(vec![StopAttempt::new(
                            method,
                            StopOutcome::Confirmed,
                            format!("statusword 0x{:04X}: {}", statusword.raw(), state.name()),
                        )]);
                    }
                    state => format!(
                        "statusword 0x{:04X}: still {}",
                        statusword.raw(),
                        state.map_or("unknown", State::name)
                    ),
                },
                Err(error) => format!("statusword not read: {error}"),
            };
            if tokio::time::Instant::now() >= deadline {
                let error = GatewayError::StateChangeTimeout {
                    message: format!(
                        "node {} axis {}: the quick stop did not show in the statusword within {} ms ({last})",
                        self.node(),
                        self.drive.axis(),
                        STOP_CONFIRM_TIMEOUT.as_millis()
                    ),
                    state: "unknown".into(),
                };
                return AxisStop::Failed {
                    error,
                    attempts: vec![StopAttempt::new(method, StopOutcome::Sent, last)],
                };
            }
            tokio::time::sleep(CONFIRM_POLL).await;
        }
    }
}

/// Whether a failed step says the node is not heard at all (then its
/// other axes are not asked: each would wait out the same timeout).
fn unanswered(stop: &AxisStop) -> Option<GatewayError> {
    match stop {
        AxisStop::Failed {
            error: error @ (GatewayError::SdoTimeout { .. } | GatewayError::BusDown(_)),
            ..
        } => Some(error.clone()),
        _ => None,
    }
}

/// NMT stop of `node`, bounded like every step.
async fn nmt_stop(bus: &Bus, node: NodeId) -> StopAttempt {
    let frame = NmtMessage::new(NmtCommand::Stop, NmtTarget::Node(node)).encode();
    match tokio::time::timeout(STOP_STEP_TIMEOUT, bus.send(frame)).await {
        Ok(Ok(())) => StopAttempt {
            method: StopMethod::NmtStop,
            outcome: StopOutcome::Sent,
            detail: None,
        },
        Ok(Err(error)) => StopAttempt::failed(StopMethod::NmtStop, &GatewayError::from(error), ""),
        Err(_) => StopAttempt::new(
            StopMethod::NmtStop,
            StopOutcome::BusDown,
            format!(
                "the frame was not taken within {} ms",
                STOP_STEP_TIMEOUT.as_millis()
            ),
        ),
    }
}

/// The motion authority a stop takes each axis's gate from, and the name of
/// the bus its axes are on (see [`crate::authority`]): every ticket of the
/// axes was voided before the stop began; the gate makes the step on the
/// wire, if any, finish before the stop goes out.
#[derive(Clone)]
pub(crate) struct Gates {
    pub(crate) authority: Arc<MotionAuthority>,
    pub(crate) bus: String,
}

impl Gates {
    fn key(&self, drive: &Drive) -> AxisKey {
        AxisKey {
            bus: self.bus.clone(),
            node: drive.node(),
            axis: drive.axis(),
        }
    }

    /// Voids every ticket of `drive`'s axis (before the stop awaits).
    pub(crate) fn cancel(&self, drive: &Drive) {
        self.authority.cancel(&self.key(drive));
    }

    pub(crate) async fn gate(&self, drive: &Drive) -> Option<tokio::sync::OwnedMutexGuard<()>> {
        self.authority.stop_gate(&self.key(drive)).await
    }
}

/// Quick stop of the axes of one node, one after another (they share its
/// SDO channel); then, if any of them did not confirm, one NMT stop of the
/// node. Once the node is not heard, its remaining axes are not asked.
/// Each axis's quick stop is sent under its gate (`gates`), unless the
/// caller holds it already (`None`).
async fn stop_node(bus: Bus, drives: Vec<Drive>, gates: Option<Gates>) -> Vec<(u8, AxisStop)> {
    let Some(node) = drives.first().map(|drive| drive.channel().node()) else {
        return Vec::new();
    };
    let mut results = Vec::new();
    let mut silent: Option<GatewayError> = None;
    for drive in drives {
        let axis = drive.axis();
        if let Some(error) = &silent {
            results.push((
                axis,
                AxisStop::Failed {
                    error: error.clone(),
                    attempts: vec![StopAttempt::new(
                        StopMethod::QuickStop,
                        StopOutcome::Skipped,
                        format!("node {node} did not answer another axis's transfer"),
                    )],
                },
            ));
            continue;
        }
        let _gate = match &gates {
            Some(gates) => gates.gate(&drive).await,
            None => None,
        };
        let stop = Stopper::new(drive).quick_stop().await;
        silent = unanswered(&stop);
        results.push((axis, stop));
    }
    if results
        .iter()
        .any(|(_, stop)| matches!(stop, AxisStop::Failed { .. }))
    {
        let attempt = nmt_stop(&bus, node).await;
        tracing::warn!("node {node}: a quick stop was not confirmed; NMT stop {attempt:?}");
        for (_, stop) in &mut results {
            if let AxisStop::Failed { attempts, .. } = stop {
                attempts.push(attempt.clone());
            }
        }
    }
    results
}

/// Stops every axis of `targets` (bus name, bus, drive), each node in a
/// task of its own, all at once; every ticket of theirs voided first.
pub(crate) async fn stop_axes(
    authority: Arc<MotionAuthority>,
    targets: Vec<(String, Bus, Drive)>,
) -> Result<StopReport, GatewayError> {
    let mut by_node: BTreeMap<(String, u8), (Bus, Vec<Drive>)> = BTreeMap::new();
    let mut seen = BTreeSet::new();
    for (name, bus, drive) in targets {
        if !seen.insert((name.clone(), drive.node(), drive.axis())) {
            continue;
        }
        authority.cancel(&AxisKey {
            bus: name.clone(),
            node: drive.node(),
            axis: drive.axis(),
        });
        by_node
            .entry((name, drive.node()))
            .or_insert_with(|| (bus, Vec::new()))
            .1
            .push(drive);
    }
    let mut tasks = JoinSet::new();
    for ((name, node), (bus, mut drives)) in by_node {
        drives.sort_by_key(Drive::axis);
        let gates = Gates {
            authority: authority.clone(),
            bus: name.clone(),
        };
        tasks.spawn(async move { (name, node, stop_node(bus, drives, Some(gates)).await) });
    }
    let mut report = StopReport::default();
    while let Some(joined) = tasks.join_next().await {
        let (bus, node, results) = joined.map_err(task_failed)?;
        for (axis, stop) in results {
            report.add(&bus, node, axis, stop);
        }
    }
    report.stopped.sort_by(|a, b| a.axis.cmp(&b.axis));
    Ok(report)
}

/// What the stop of one axis asked for by a client did.
#[derive(Debug)]
pub struct AxisStopped {
    /// The axis read after the stop.
    pub status: AxisStatus,
    pub attempts: Vec<StopAttempt>,
}

/// Why the stop of one axis asked for by a client was not confirmed: the
/// first failure, and what was tried (fallbacks included).
#[derive(Debug)]
pub struct AxisStopFailed {
    pub error: GatewayError,
    pub attempts: Vec<StopAttempt>,
}

impl From<GatewayError> for AxisStopFailed {
    fn from(error: GatewayError) -> Self {
        Self {
            error,
            attempts: Vec::new(),
        }
    }
}

impl Gateway {
    /// A node's axis for a stop: none of the checks of [`Gateway::drive`]
    /// (a stop is sent whatever the gateway believes of the node); a node
    /// the registry does not know as a drive (not identified yet) is
    /// stopped as the gateway knew it when it enabled the axis.
    pub fn stop_target(
        &self,
        bus: &str,
        id: &str,
        axis: &str,
    ) -> Result<(Bus, Drive), GatewayError> {
        let served = self.bus(bus)?;
        let recorded = || {
            let node = id.parse::<u8>().ok()?;
            let axis = axis.parse::<u8>().ok()?;
            self.enabled_axes.get(bus, node, axis)
        };
        let drive = match self.node(bus, id) {
            Ok((_, info)) => match Drive::new(&served.registry, &info, axis) {
                Ok(drive) => drive,
                Err(error) => recorded().ok_or(error)?,
            },
            Err(error) => recorded().ok_or(error)?,
        };
        Ok((served.bus.clone(), drive))
    }

    /// Quick stop of one axis (`quick_stop_active`), NMT stop of its node
    /// if the drive does not confirm. An axis not in operation enabled is
    /// not touched: 409 `drive_not_enabled` (quick stop active already is
    /// no error).
    pub async fn quick_stop_axis(
        &self,
        bus: &str,
        id: &str,
        axis: &str,
    ) -> Result<AxisStopped, AxisStopFailed> {
        let gates = self.gates(bus);
        let (bus, drive) = self.stop_target(bus, id, axis)?;
        // Before anything is awaited: whatever was admitted on the axis
        // before this stop sends nothing after it.
        gates.cancel(&drive);
        tokio::spawn(async move {
            let number = drive.axis();
            let stop = stop_node(bus, vec![drive.clone()], Some(gates)).await;
            let stop = stop.into_iter().next().map(|(_, stop)| stop);
            let attempts = match stop {
                Some(AxisStop::Stopped(attempts)) => attempts,
                Some(AxisStop::NotEnabled(Some(State::QuickStopActive))) => Vec::new(),
                Some(AxisStop::NotEnabled(state)) => {
                    return Err(AxisStopFailed::from(GatewayError::from(
                        super::drive::DriveError::NotEnabled {
                            axis: number,
                            state,
                        },
                    )));
                }
                Some(AxisStop::Failed { error, attempts }) => {
                    return Err(AxisStopFailed { error, attempts });
                }
                None => Vec::new(),
            };
            match drive.status().await {
                Ok(status) => Ok(AxisStopped { status, attempts }),
                Err(error) => Err(AxisStopFailed {
                    error: error.into(),
                    attempts,
                }),
            }
        })
        .await
        .map_err(|err| AxisStopFailed::from(task_failed(err)))?
    }

    /// Halt of one axis (controlword bit 8), bounded by `HALT_TIMEOUT`;
    /// if it cannot be given, quick stop, then NMT stop of the node.
    pub async fn halt_axis(
        &self,
        bus: &str,
        id: &str,
        axis: &str,
    ) -> Result<AxisStopped, AxisStopFailed> {
        let gates = self.gates(bus);
        let (bus, drive) = self.stop_target(bus, id, axis)?;
        gates.cancel(&drive);
        tokio::spawn(async move {
            // A command's write on the wire goes first; the halt then (not
            // under the gate: the halt waits for the node's procedure,
            // which a command holds until its next write finds the stop).
            drop(gates.gate(&drive).await);
            let error = match tokio::time::timeout(HALT_TIMEOUT, drive.halt(true)).await {
                Ok(Ok(status)) => {
                    return Ok(AxisStopped {
                        status,
                        attempts: vec![StopAttempt {
                            method: StopMethod::Halt,
                            outcome: StopOutcome::Confirmed,
                            detail: None,
                        }],
                    });
                }
                Ok(Err(error)) => GatewayError::from(error),
                Err(_) => GatewayError::SdoTimeout { node: drive.node() },
            };
            tracing::warn!(
                "node {} axis {}: halt failed ({error}); quick stop instead",
                drive.node(),
                drive.axis()
            );
            let mut attempts = vec![StopAttempt::failed(StopMethod::Halt, &error, "")];
            match stop_node(bus, vec![drive], Some(gates))
                .await
                .into_iter()
                .next()
            {
                Some((_, AxisStop::Stopped(more) | AxisStop::Failed { attempts: more, .. })) => {
                    attempts.extend(more);
                }
                Some((_, AxisStop::NotEnabled(state))) => attempts.push(StopAttempt::new(
                    StopMethod::QuickStop,
                    StopOutcome::Skipped,
                    format!(
                        "the axis is in {}: nothing to stop",
                        state.map_or("unknown", State::name)
                    ),
                )),
                None => {}
            }
            Err(AxisStopFailed { error, attempts })
        })
        .await
        .map_err(|err| AxisStopFailed::from(task_failed(err)))?
    }

    /// Quick stop of every enabled axis on every bus (STOP ALL), all nodes
    /// at once: every axis of every node the registry knows as a drive,
    /// online or not, whatever its NMT state, and every axis the gateway
    /// enabled; an axis in operation enabled gets the quick stop, and its
    /// node an NMT stop if the drive does not confirm. Every lease ends.
    ///
    /// In a task of its own, with its audit row (`stop all axes`):
    /// dropping a `JoinSet` aborts its tasks, so the set must not live in
    /// the caller's future (a request handler's is dropped when its client
    /// hangs up).
    pub async fn stop_all(&self, caller: &Caller) -> Result<StopReport, GatewayError> {
        let row = self.audit_row(caller, AuditTarget::new("stop all axes"), None);
        // Anyone the gateway knows may stop everything (a viewer too); it
        // is never refused for the write rate.
        if let Err(error) = self.require(caller, Operation::StopAll) {
            let result = Err(error);
            row.finish(&result).await;
            return result;
        }
        let gateway = self.clone();
        crate::audit::spawn_audited(row, async move { gateway.stop_everything().await }).await
    }

    async fn stop_everything(&self) -> Result<StopReport, GatewayError> {
        // Every sequence on any axis ends before anything is awaited.
        self.authority.cancel_all();
        let gateway = self.clone();
        let report = tokio::spawn(async move {
            let mut targets = Vec::new();
            let mut failed = Vec::new();
            for (name, served) in gateway.buses.iter() {
                for info in served.registry.nodes() {
                    let Some(kind) = DriveKind::from_profile(info.profile) else {
                        continue;
                    };
                    let node = info.id.get();
                    for axis in 1..=axis_count(kind, info.eds_entry.as_deref()) {
                        match Drive::new(&served.registry, &info, &axis.to_string()) {
                            Ok(drive) => targets.push((name.clone(), served.bus.clone(), drive)),
                            Err(error) => failed.push(StopFailure {
                                bus: name.clone(),
                                node,
                                axis: None,
                                error: error.into(),
                                attempts: Vec::new(),
                            }),
                        }
                    }
                }
            }
            targets.extend(gateway.recorded_targets());
            let mut report = stop_axes(gateway.authority.clone(), targets).await?;
            report.failed.extend(failed);
            Ok::<_, GatewayError>(report)
        })
        .await
        .map_err(task_failed)??;
        // Every enabled axis got quick stop: no motion is left to lease.
        self.leases.release_all();
        Ok(report)
    }

    /// The axes the gateway enabled, with their bus.
    fn recorded_targets(&self) -> Vec<(String, Bus, Drive)> {
        self.enabled_axes
            .drives()
            .into_iter()
            .filter_map(|(name, drive)| {
                let bus = self.buses.get(&name)?.bus.clone();
                Some((name, bus, drive))
            })
            .collect()
    }

    /// Quick stop of every axis the gateway enabled that is still in
    /// operation enabled, all nodes at once, NMT stop where the drive does
    /// not confirm (for SIGTERM and Ctrl-C). Bounded by
    /// `SHUTDOWN_STOP_TIMEOUT`; what could not be stopped is in the
    /// report.
    pub async fn stop_enabled_axes(&self) -> StopReport {
        self.authority.cancel_all();
        let task = tokio::spawn(stop_axes(self.authority.clone(), self.recorded_targets()));
        let report = match tokio::time::timeout(SHUTDOWN_STOP_TIMEOUT, task).await {
            Ok(Ok(Ok(report))) => report,
            Ok(Ok(Err(error))) => {
                tracing::error!("shutdown: stopping the axes failed: {error}");
                StopReport::default()
            }
            Ok(Err(error)) => {
                tracing::error!("shutdown: stopping the axes failed: {error}");
                StopReport::default()
            }
            Err(_) => {
                tracing::error!(
                    "shutdown: axes still being stopped after {SHUTDOWN_STOP_TIMEOUT:?}; exiting anyway"
                );
                StopReport::default()
            }
        };
        self.leases.release_all();
        report
    }

    /// The gates of the axes of bus `bus` for a stop.
    pub(crate) fn gates(&self, bus: &str) -> Gates {
        Gates {
            authority: self.authority.clone(),
            bus: bus.to_string(),
        }
    }

    /// Stops one axis after a lapsed lease or a failed halt: quick stop,
    /// then NMT stop of its node (under the axis's gate, unless the caller
    /// holds it: `gates` `None`).
    pub(super) async fn quick_stop_or_nmt(
        bus: Bus,
        drive: Drive,
        gates: Option<Gates>,
    ) -> AxisStop {
        stop_node(bus, vec![drive], gates)
            .await
            .into_iter()
            .next()
            .map_or(AxisStop::NotEnabled(None), |(_, stop)| stop)
    }
}
