//! The network manager of a bus at work: the sans-I/O
//! [`Manager`] of CiA 302-2 driven by one
//! task per bus, which feeds it what the bus's one supervisor decided (the
//! registry's [`NodeRegistry::subscribe_supervision`]: boot-ups, nodes
//! heard, lost and heard again, NMT states, written 0x1017s), the
//! registry's news (nodes found, gone) and the answers of its SDO
//! requests, and carries out what it asks: SDO transfers through each
//! node's [`SdoChannel`](super::sdo::SdoChannel) (queued fairly with
//! everyone else's), NMT commands, the gateway's own heartbeat (0x700 +
//! `manager_node_id`), node guarding (handed to the supervisor). It keeps
//! no supervision timer of its own: the node list, the machine view and
//! the stream say what the one supervisor decided, and cannot disagree.
//! Nor does it identify nodes itself: each boot-up begins by waiting for
//! the registry's identification ([`NodeRegistry::identify`]), so a node
//! the machine calls `ready` has the profile and EDS every route that
//! depends on what the node is reads from the registry.
//!
//! Every step is visible: the machine's status ([`Machine::status`], for
//! `GET /buses/{bus}/machine` and the `machine` topic of the stream) and
//! the audit log (as the gateway: boot-ups begun, ended, failed; nodes
//! lost; the machine's state).

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use crate::can::Bus;
use crate::canopen::NodeId;
use crate::canopen::eds::Eds;
use crate::canopen::manager::{
    Action, ConfigWrite, MachineStatus, Manager, ManagerConfig, ManagerEvent, NodeDescription,
    SdoOutcome,
};

use super::audit::{AuditRow, AuditTarget};
use super::caller::Caller;
use super::history::{History, OK};
use super::registry::{NodeEvent, NodeRegistry, OfflineReason};
use super::sdo::SdoRequestError;
use tokio::sync::broadcast::error::RecvError;

/// How long an SDO request of the manager waits for the registry to list
/// a node it has just heard (both read the same frame, in two tasks).
const REGISTRY_WAIT: Duration = Duration::from_secs(1);

/// What the network manager of every bus runs with (`manager_node_id`,
/// `manager_heartbeat_ms`, `[[nodes]]`).
#[derive(Debug, Clone, Default)]
pub struct MachineSettings {
    pub manager: ManagerConfig,
    /// The descriptions of this bus's nodes; none: every node found is
    /// booted with the defaults.
    pub nodes: Vec<NodeDescription>,
}

/// Refuses `node` as a device's new node-ID when it is the network
/// manager's own on `served` (`manager_node_id`): the device would be
/// unsupervised, and its neighbours' 0x1016 would take its heartbeat for
/// the gateway's. LSS and the node-ID change ask it first.
pub(crate) fn check_not_manager_id(
    served: &super::service::ServedBus,
    node: NodeId,
) -> Result<(), super::GatewayError> {
    match &served.machine {
        Some(machine) if machine.manager().node_id == node => {
            Err(super::GatewayError::NodeIdInUse(format!(
                "node {node} is the gateway's own node-ID on bus {} (manager_node_id): its network manager's heartbeat goes out under it",
                served.name
            )))
        }
        _ => Ok(()),
    }
}

/// The gateway's [`MotionStopper`] of bus `bus_name`: the gateway's one
/// "end the motion on a node" ([`NodeMotion::end`](super::end_motion::NodeMotion::end),
/// reason `reconfiguration`): every axis of the node that is leased or
/// that the gateway enabled is stopped, its lease ended, and the `nodes`
/// topic, the history and the audit log say so. An axis that cannot be
/// stopped keeps the configuration from being written (it is retried).
pub(crate) fn motion_stopper(gateway: &super::Gateway, bus_name: &str) -> Option<MotionStopper> {
    use super::end_motion::MotionEnd;
    let motion = gateway.node_motion(gateway.buses.get(bus_name)?);
    Some(Arc::new(move |node: NodeId| {
        let motion = motion.clone();
        Box::pin(async move {
            match motion.end(node, MotionEnd::Reconfigured).await {
                Ok(_) => Ok(()),
                Err(failed) => Err(format!(
                    "axis {} is enabled and could not be stopped ({}): its motion objects are not written under it",
                    failed
                        .axis
                        .map_or_else(|| "?".to_string(), |axis| axis.to_string()),
                    failed.error
                )),
            }
        }) as std::pin::Pin<Box<dyn Future<Output = Result<(), String>> + Send>>
    }))
}

/// Refuses a machine description that expects a node at the network
/// manager's own node-ID, at start.
pub(crate) fn check_descriptions(bus: &str, settings: &MachineSettings) -> Result<(), String> {
    let manager = settings.manager.node_id;
    match settings.nodes.iter().find(|node| node.id == manager) {
        Some(_) => Err(format!(
            "config [[nodes]] bus {bus} id {manager}: that is the gateway's own node id (manager_node_id); give the network manager another one"
        )),
        None => Ok(()),
    }
}

/// Reads a DCF's `ParameterValue` entries for `node`, in file order, as
/// the writes of a configuration download.
pub fn load_dcf(path: &Path, node: NodeId) -> Result<Vec<ConfigWrite>, String> {
    let text =
        std::fs::read_to_string(path).map_err(|err| format!("DCF {}: {err}", path.display()))?;
    let file = path.file_name().map_or_else(
        || path.display().to_string(),
        |name| name.to_string_lossy().into_owned(),
    );
    // Checked as a whole first: a DCF that does not read is refused at start.
    Eds::parse(&text, &file).map_err(|err| format!("DCF {}: {err}", path.display()))?;
    let values = Eds::parameter_values_in_file_order(&text, &file, node)?;
    Ok(values
        .into_iter()
        .map(|(index, sub, value, label)| ConfigWrite {
            index,
            sub,
            data: value.to_bytes(),
            label,
        })
        .collect())
}

/// A request to the task.
enum Command {
    Boot(NodeId, tokio::sync::oneshot::Sender<Result<(), String>>),
    ScanDone,
}

/// Stops the task when the last handle goes.
struct TaskGuard(tokio::task::AbortHandle);

impl Drop for TaskGuard {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// What stops a node's enabled axes before the network manager writes its
/// motion objects ([`Action::StopMotion`]): `Ok` once none moves, `Err`
/// with why not. The gateway sets it ([`Machine::set_motion_stopper`]).
pub(crate) type MotionStopper = Arc<
    dyn Fn(NodeId) -> std::pin::Pin<Box<dyn Future<Output = Result<(), String>> + Send>>
        + Send
        + Sync,
>;

/// The network manager of one bus. Cheap to clone.
#[derive(Clone)]
pub struct Machine {
    status: watch::Receiver<MachineStatus>,
    commands: mpsc::UnboundedSender<Command>,
    manager: ManagerConfig,
    /// The nodes the description expects started (`[[nodes]]` with `start
    /// = true`): their axes are the machine's to put back in operation.
    started: Arc<[NodeId]>,
    stopper: Arc<std::sync::OnceLock<MotionStopper>>,
    _task: Arc<TaskGuard>,
}

impl std::fmt::Debug for Machine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Machine").finish_non_exhaustive()
    }
}

impl Machine {
    /// Starts the manager of `bus` (needs a tokio runtime): its heartbeat
    /// from now on, and the boot-up of every node the registry knows or
    /// finds.
    pub fn spawn(
        bus_name: &str,
        bus: Bus,
        registry: NodeRegistry,
        settings: MachineSettings,
        history: Option<History>,
    ) -> Self {
        let now = Instant::now();
        let started = settings
            .nodes
            .iter()
            .filter(|node| node.expected && node.start)
            .map(|node| node.id)
            .collect();
        let manager = Manager::new(settings.manager.clone(), settings.nodes, now.into_std());
        let (status_tx, status) = watch::channel(manager.status());
        let (commands, commands_rx) = mpsc::unbounded_channel();
        let stopper = Arc::new(std::sync::OnceLock::new());
        let driver = Driver {
            bus_name: bus_name.to_string(),
            bus,
            registry,
            manager,
            status: status_tx,
            history,
            stopper: stopper.clone(),
        };
        let task = tokio::spawn(driver.run(commands_rx));
        Self {
            status,
            commands,
            manager: settings.manager,
            started,
            stopper,
            _task: Arc::new(TaskGuard(task.abort_handle())),
        }
    }

    /// How the gateway stops a node's enabled axes before the manager
    /// writes its motion objects; set once (without one, nothing is
    /// stopped: a bus without drives the gateway moves).
    pub(crate) fn set_motion_stopper(&self, stopper: MotionStopper) {
        let _ = self.stopper.set(stopper);
    }

    /// The machine now.
    pub fn status(&self) -> MachineStatus {
        self.status.borrow().clone()
    }

    /// Every change of the machine from now on.
    pub fn watch(&self) -> watch::Receiver<MachineStatus> {
        self.status.clone()
    }

    /// The manager's settings.
    pub fn manager(&self) -> &ManagerConfig {
        &self.manager
    }

    /// The nodes the machine description expects in operation (described,
    /// and started after their boot-up), in the order described.
    pub fn described_started(&self) -> &[NodeId] {
        &self.started
    }

    /// Runs a node's boot-up again; an error names why it cannot. A door
    /// asks for it by [`crate::Gateway::boot_node`].
    pub(crate) async fn boot(&self, node: NodeId) -> Result<(), String> {
        let (reply, answer) = tokio::sync::oneshot::channel();
        self.commands
            .send(Command::Boot(node, reply))
            .map_err(|_| "the network manager has stopped".to_string())?;
        answer
            .await
            .map_err(|_| "the network manager has stopped".to_string())?
    }

    /// The first scan of the bus is over: expected nodes it did not find
    /// are missing.
    pub fn scan_done(&self) {
        let _ = self.commands.send(Command::ScanDone);
    }

    /// Waits until the machine is in `state` or `timeout` passed; the last
    /// status seen.
    pub async fn wait_for(
        &self,
        state: crate::canopen::manager::MachineState,
        timeout: Duration,
    ) -> MachineStatus {
        let mut watch = self.status.clone();
        let _ = tokio::time::timeout(timeout, watch.wait_for(|status| status.state == state)).await;
        self.status()
    }
}

/// Supervision events a driver takes in one turn of its loop beyond the
/// one it waited for, before it looks at its other inputs again.
const EVENT_BATCH: usize = 256;

struct Driver {
    bus_name: String,
    bus: Bus,
    registry: NodeRegistry,
    manager: Manager,
    status: watch::Sender<MachineStatus>,
    history: Option<History>,
    stopper: Arc<std::sync::OnceLock<MotionStopper>>,
}

impl Driver {
    async fn run(mut self, mut commands: mpsc::UnboundedReceiver<Command>) {
        let mut supervision = self.registry.subscribe_supervision();
        let mut nodes = self.registry.subscribe();
        let mut bus_status = self.bus.watch_status();
        let (results_tx, mut results) = mpsc::unbounded_channel::<(NodeId, SdoOutcome)>();
        if let Some(frame) = self.manager.heartbeat_now() {
            let _ = self.bus.send(frame).await;
        }
        self.manager.bus_up(self.bus.state().can_send());
        for node in self.registry.nodes() {
            self.manager.node_found(node.id);
        }
        // One timer for the loop, moved when the manager's next deadline
        // moves: a new timer per frame cost more than the frame's work.
        let mut deadline = self.manager.deadline().map(Instant::from_std);
        let timer = tokio::time::sleep_until(deadline.unwrap_or_else(Instant::now));
        tokio::pin!(timer);
        loop {
            tokio::select! {
                received = supervision.recv() => {
                    match received {
                        Ok(event) => self.manager.on_supervision(&event),
                        Err(RecvError::Lagged(lost)) => self.lagged(lost),
                        Err(RecvError::Closed) => return,
                    }
                    // What else is queued goes in the same turn.
                    for _ in 0..EVENT_BATCH {
                        match supervision.try_recv() {
                            Ok(event) => self.manager.on_supervision(&event),
                            Err(tokio::sync::broadcast::error::TryRecvError::Empty) => break,
                            Err(tokio::sync::broadcast::error::TryRecvError::Lagged(lost)) => {
                                self.lagged(lost);
                            }
                            Err(tokio::sync::broadcast::error::TryRecvError::Closed) => return,
                        }
                    }
                },
                event = nodes.recv() => match event {
                    Ok(NodeEvent::Appeared { node }) => self.manager.node_found(node),
                    Ok(NodeEvent::Offline { node, reason: OfflineReason::NodeIdChanged }) => {
                        self.manager.node_left(node, "its device moved to another node-ID");
                    }
                    Ok(_) => {}
                    Err(RecvError::Lagged(_)) => {
                        for node in self.registry.nodes() {
                            self.manager.node_found(node.id);
                        }
                    }
                    Err(RecvError::Closed) => return,
                },
                Some((node, outcome)) = results.recv() => {
                    // What the supervisor decided before the transfer ended
                    // (a loss, the write of 0x1017 this answer confirms)
                    // goes first: the manager sees them in the order they
                    // happened.
                    loop {
                        match supervision.try_recv() {
                            Ok(event) => self.manager.on_supervision(&event),
                            Err(tokio::sync::broadcast::error::TryRecvError::Lagged(lost)) => {
                                self.lagged(lost);
                            }
                            Err(_) => break,
                        }
                    }
                    self.manager.on_sdo(node, outcome, Instant::now().into_std());
                }
                command = commands.recv() => match command {
                    Some(Command::Boot(node, reply)) => {
                        let _ = reply.send(self.manager.reboot(node));
                    }
                    Some(Command::ScanDone) => {
                        // The registry lists what the scan found; its news
                        // of them may still be on the way here, and the
                        // machine is not to be ready without them.
                        for node in self.registry.nodes() {
                            self.manager.node_found(node.id);
                        }
                        self.manager.scan_done();
                    }
                    None => return,
                },
                changed = bus_status.changed() => {
                    if changed.is_err() {
                        return;
                    }
                    let up = bus_status.borrow_and_update().state.can_send();
                    self.manager.bus_up(up);
                }
                () = &mut timer, if deadline.is_some() => {}
            }
            let now = Instant::now();
            for action in self.manager.poll(now.into_std()) {
                self.carry_out(action, &results_tx).await;
            }
            for event in self.manager.take_events() {
                self.report(event);
            }
            let status = self.manager.status();
            self.status.send_if_modified(|current| {
                if *current == status {
                    false
                } else {
                    *current = status;
                    true
                }
            });
            deadline = self.manager.deadline().map(Instant::from_std);
            if let Some(at) = deadline {
                timer.as_mut().reset(at);
            }
        }
    }

    /// The manager missed `lost` of the supervisor's events: every node
    /// the registry knows is found again (booted if it is not already).
    fn lagged(&mut self, lost: u64) {
        tracing::warn!(
            bus = self.bus_name,
            lost,
            "network manager fell behind the supervisor"
        );
        for node in self.registry.nodes() {
            self.manager.node_found(node.id);
        }
    }

    async fn carry_out(
        &self,
        action: Action,
        results: &mpsc::UnboundedSender<(NodeId, SdoOutcome)>,
    ) {
        match action {
            Action::Send(frame) => {
                // A bus that is down is reported by the bus; the manager
                // sees it through the bus status.
                let _ = self.bus.send(frame).await;
            }
            Action::Guard {
                node,
                guard_time_ms,
                life_time_factor,
            } => self.registry.guard(node, guard_time_ms, life_time_factor),
            Action::Unguard { node } => self.registry.unguard(node),
            Action::StopMotion { node } => {
                let stopper = self.stopper.get().cloned();
                let results = results.clone();
                tokio::spawn(async move {
                    let outcome = match stopper {
                        Some(stop) => match stop(node).await {
                            Ok(()) => SdoOutcome::Done(Vec::new()),
                            Err(why) => SdoOutcome::Failed(why),
                        },
                        None => SdoOutcome::Done(Vec::new()),
                    };
                    let _ = results.send((node, outcome));
                });
            }
            Action::Identify { node } => {
                let registry = self.registry.clone();
                let results = results.clone();
                tokio::spawn(async move {
                    // Once the registry lists the node (both read its
                    // first frame, in two tasks).
                    let identified = match channel(&registry, node).await {
                        Ok(_) => registry.identify(node).await,
                        Err(reason) => Err(reason),
                    };
                    let outcome = match identified {
                        Ok(()) => SdoOutcome::Done(Vec::new()),
                        Err(why) => SdoOutcome::Failed(format!(
                            "the gateway could not identify the node (0x1000, 0x1018): {why}"
                        )),
                    };
                    let _ = results.send((node, outcome));
                });
            }
            Action::Read { node, index, sub } => {
                let registry = self.registry.clone();
                let results = results.clone();
                tokio::spawn(async move {
                    let outcome = match channel(&registry, node).await {
                        Ok(channel) => outcome(channel.upload(index, sub).await),
                        Err(reason) => SdoOutcome::Failed(reason),
                    };
                    let _ = results.send((node, outcome));
                });
            }
            Action::Write {
                node,
                index,
                sub,
                data,
            } => {
                let registry = self.registry.clone();
                let results = results.clone();
                tokio::spawn(async move {
                    let outcome = match channel(&registry, node).await {
                        Ok(channel) => outcome(
                            channel
                                .download(index, sub, &data)
                                .await
                                .map(|()| Vec::new()),
                        ),
                        Err(reason) => SdoOutcome::Failed(reason),
                    };
                    let _ = results.send((node, outcome));
                });
            }
        }
    }

    /// Logs an event and writes it to the audit log as the gateway's.
    fn report(&self, event: ManagerEvent) {
        let bus = &self.bus_name;
        let (node, operation, outcome) = match &event {
            ManagerEvent::BootStarted { node, why } => {
                tracing::info!("bus {bus}: node {node}: boot-up started ({why})");
                (
                    Some(*node),
                    format!("network manager: boot-up started ({why})"),
                    OK,
                )
            }
            ManagerEvent::Step { node, step } => {
                tracing::debug!("bus {bus}: node {node}: {}", step.name());
                return;
            }
            ManagerEvent::Booted { node } => {
                tracing::info!("bus {bus}: node {node}: booted");
                (Some(*node), "network manager: node booted".to_string(), OK)
            }
            ManagerEvent::Failed {
                node,
                step,
                reason,
                retry,
            } => {
                let retry = retry.map_or_else(
                    || "not retried until it boots again".to_string(),
                    |after| format!("retried in {} ms", after.as_millis()),
                );
                tracing::warn!(
                    "bus {bus}: node {node}: boot-up failed at {}: {reason}; {retry}",
                    step.name()
                );
                (
                    Some(*node),
                    format!(
                        "network manager: boot-up failed at {}: {reason}; {retry}",
                        step.name()
                    ),
                    "boot_failed",
                )
            }
            ManagerEvent::ResyncStarted { node, why } => {
                tracing::info!("bus {bus}: node {node}: resynchronisation started ({why})");
                (
                    Some(*node),
                    format!("network manager: resynchronisation started ({why})"),
                    OK,
                )
            }
            ManagerEvent::Resynchronised { node } => {
                tracing::info!(
                    "bus {bus}: node {node}: resynchronised, its configuration kept (nothing written)"
                );
                (
                    Some(*node),
                    "network manager: node resynchronised, its configuration kept (nothing written)"
                        .to_string(),
                    OK,
                )
            }
            ManagerEvent::Lost { node, reason } => {
                tracing::warn!("bus {bus}: node {node} lost: {reason}");
                (
                    Some(*node),
                    format!("network manager: node lost: {reason}"),
                    "node_lost",
                )
            }
            ManagerEvent::Machine { from, to } => {
                tracing::info!("bus {bus}: machine {from} -> {to}");
                (None, format!("network manager: machine {from} -> {to}"), OK)
            }
        };
        let Some(history) = self.history.clone() else {
            return;
        };
        let target = AuditTarget::new(operation)
            .bus(bus.clone())
            .node(node.map(NodeId::get));
        let row = AuditRow::new(&history, &Caller::system(), target, None);
        tokio::spawn(row.finish_as(outcome));
    }
}

/// The node's SDO channel, once the registry lists it.
async fn channel(registry: &NodeRegistry, node: NodeId) -> Result<super::sdo::SdoChannel, String> {
    let until = Instant::now() + REGISTRY_WAIT;
    loop {
        match registry.sdo(node) {
            Ok(channel) => return Ok(channel),
            Err(err) if Instant::now() >= until => return Err(err.to_string()),
            Err(_) => tokio::time::sleep(Duration::from_millis(5)).await,
        }
    }
}

fn outcome(result: Result<Vec<u8>, SdoRequestError>) -> SdoOutcome {
    match result {
        Ok(data) => SdoOutcome::Done(data),
        Err(error) => match error.device_abort() {
            Some(code) => SdoOutcome::Aborted(code),
            None => SdoOutcome::Failed(error.to_string()),
        },
    }
}

#[cfg(test)]
mod tests;
