//! The gateway service: the buses it serves, each with its registry,
//! telemetry, SYNC producer, recorder and (on a virtual bus) virtual
//! devices, and what every adapter shares on top of them: the history, the
//! motion leases, the axes the gateway enabled, the tokens. REST
//! (`crate::api`), CiA 309 (`crate::cia309`, `crate::ascii`) and the
//! command line use it; it knows none of them.
//!
//! The rules that hold whichever adapter asks are here: no SDO to a node
//! known to be stopped or on a bus that is down ([`check_sdo_allowed`]), no
//! drive command to a drive whose heartbeat is lost ([`Gateway::drive`]).

use std::collections::BTreeMap;
use std::sync::Arc;

use crate::can::spec::BusSpec;
use crate::can::{Bus, VirtualHub};
use crate::canopen::NodeId;
use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtService, NmtState, NmtTarget};

use super::GatewayError;
use super::access::{RateLimit, Tokens, WriteLimiter};
use super::audit::AuditTarget;
use super::axis_telemetry::AxisTelemetry;
use super::caller::Caller;
use super::drive::Drive;
use super::frames::FrameLog;
use super::history::History;
use super::leases::MotionLeases;
use super::led_preview::LedPreviews;
use super::load::{LoadMeter, Traffic};
use super::profile::EdsCatalog;
use super::recording::{Pruned, Recorder, RecordingsQuota, prune};
use super::registry::{NodeEvent, NodeInfo, NodeRegistry, RegistryConfig};
use super::safe_stop::EnabledAxes;
use super::sync::SyncService;
use super::values::TpdoValues;

/// The virtual devices of a bus, opaque to the gateway: the emulator that
/// put them there (the binary's wiring) and the door that manages them
/// (`/sim`) know their type.
pub type BusDevices = Arc<dyn std::any::Any + Send + Sync>;

/// Puts the devices of the virtual bus `name` (`virtual:PRESET`) on its
/// hub: `(name, preset, hub)`, the devices or an error for a preset it
/// does not know.
pub(crate) type AttachDevices<'a> =
    &'a (dyn Fn(&str, &str, &VirtualHub) -> Result<Option<BusDevices>, String> + Sync);

/// One bus the gateway serves.
pub struct ServedBus {
    pub(crate) name: String,
    /// The spec it was opened from, as the user wrote it (`virtual:demo`).
    spec: String,
    pub(crate) bus: Bus,
    pub(crate) registry: NodeRegistry,
    /// The hub of a virtual bus, which counts every frame on it (an
    /// attachment to a hub counts only what it sends).
    hub: Option<VirtualHub>,
    /// The virtual devices of a virtual bus, which the gateway drives like
    /// real ones and does not otherwise know: what [`AttachDevices`] put on
    /// the bus's hub (the binary wires its emulator there); `None`
    /// elsewhere.
    devices: Option<BusDevices>,
    load: LoadMeter,
    /// The gateway's SYNC producer on this bus (`PUT /buses/{bus}/sync`).
    pub(crate) sync: SyncService,
    /// The nodes' TPDO values, decoded by the mappings read from them; the
    /// `values` topics of the stream ([`TpdoValues::subscribe`]).
    pub(crate) values: TpdoValues,
    /// The `axes/{axis}` topics of the stream
    /// ([`AxisTelemetry::subscribe`]).
    axes: AxisTelemetry,
    /// The `segments` topics of the stream ([`LedPreviews::subscribe`]).
    previews: LedPreviews,
    /// The `program` topics of the stream: each node's program download
    /// progress.
    pub(crate) programs: super::program::ProgramTopics,
    /// The bus's recent frames.
    frames: FrameLog,
    /// The bus's LSS master, one transaction at a time.
    pub(crate) lss: super::lss::BusLss,
    /// Records the bus to a candump log on request (`/buses/{bus}/recording`).
    pub(crate) recorder: Recorder,
    /// The network manager of the bus (CiA 302-2): `None` until
    /// [`ServedBus::with_machine`] starts it (`candeck serve` always does).
    pub(crate) machine: Option<super::machine::Machine>,
    /// The registry's events from the moment it started (the devices'
    /// boot-ups included), until [`Gateway::with_history`] takes it to
    /// write them to the history.
    history_events: std::sync::Mutex<Option<tokio::sync::broadcast::Receiver<NodeEvent>>>,
}

impl ServedBus {
    /// Opens `spec` as the bus `name` and starts its registry; a virtual
    /// bus gets the devices `attach` puts on its hub (none: `|_, _, _|
    /// Ok(None)`), after the registry listens so that it hears their
    /// boot-up messages.
    pub async fn open_with_devices(
        name: &str,
        spec: &BusSpec,
        catalog: Arc<EdsCatalog>,
        config: RegistryConfig,
        bitrate: u32,
        attach: AttachDevices<'_>,
    ) -> Result<Self, String> {
        let opened = spec
            .open_with_bitrate(name, crate::can::Bitrate::bits_per_second(bitrate))
            .await
            .map_err(|err| err.to_string())?;
        // A virtual bus's load is measured against its own bit rate.
        let bitrate = opened
            .hub
            .as_ref()
            .and_then(|hub| hub.bitrate().get())
            .unwrap_or(bitrate);
        let telemetry = config.telemetry.clone();
        let registry = NodeRegistry::spawn(opened.bus.clone(), catalog, config);
        let history_events = std::sync::Mutex::new(Some(registry.subscribe()));
        let values = TpdoValues::spawn(opened.bus.clone(), registry.clone());
        // Recording starts before the devices boot: their boot-ups are the
        // first frames of the log.
        let frames = FrameLog::spawn(&opened.bus);
        let devices = match (spec, &opened.hub) {
            (BusSpec::Virtual { preset, .. }, Some(hub)) => attach(name, preset, hub)?,
            _ => None,
        };
        Ok(Self {
            // In a private temporary directory until told otherwise.
            recorder: Recorder::new(&opened.bus, None),
            frames,
            lss: super::lss::BusLss::new(opened.bus.clone()),
            name: name.to_string(),
            spec: spec.to_string(),
            load: LoadMeter::spawn(Traffic::new(&opened.bus), bitrate),
            sync: SyncService::spawn(opened.bus.clone()),
            axes: AxisTelemetry::new(registry.clone(), values.clone(), telemetry.clone()),
            previews: LedPreviews::new(registry.clone(), &telemetry),
            programs: Default::default(),
            values,
            hub: opened.hub,
            bus: opened.bus,
            registry,
            devices,
            history_events,
            machine: None,
        })
    }
}

impl ServedBus {
    /// Keeps this bus's recordings in `dir` (`--data-dir DIR` gives
    /// `DIR/recordings`) instead of a temporary directory. Call before any
    /// recording starts.
    pub fn with_recordings_dir(mut self, dir: std::path::PathBuf) -> Self {
        self.recorder = Recorder::new(&self.bus, Some(dir));
        self
    }
}

impl ServedBus {
    /// The same with these virtual devices instead (`None`: a bus that
    /// has none, as a real one).
    pub fn with_devices(mut self, devices: Option<BusDevices>) -> Self {
        self.devices = devices;
        self
    }
}

impl ServedBus {
    /// Starts the bus's network manager with `settings` (its audit entries
    /// into `history`): the gateway's heartbeat, and the boot-up of every
    /// node.
    pub fn with_machine(
        mut self,
        settings: super::machine::MachineSettings,
        history: Option<super::history::History>,
    ) -> Self {
        self.machine = Some(super::machine::Machine::spawn(
            &self.name,
            self.bus.clone(),
            self.registry.clone(),
            settings,
            history,
        ));
        self
    }

    /// The bus's network manager; an error when it has none.
    pub fn machine(&self) -> Result<&super::machine::Machine, GatewayError> {
        self.machine.as_ref().ok_or_else(|| {
            GatewayError::InvalidRequest(format!("bus {} has no network manager", self.name))
        })
    }

    /// Sends an NMT command. NMT is unconfirmed (CiA 301 §7.2.8.2.1): this
    /// says the command was sent; the node's new state shows in the
    /// registry once it reports it.
    pub async fn send_nmt(
        &self,
        command: NmtCommand,
        target: NmtTarget,
    ) -> Result<(), GatewayError> {
        self.bus
            .send(NmtMessage::new(command, target).encode())
            .await
            .map_err(GatewayError::from)
    }
}

/// What a door may see of a bus and ask of it. The bus's parts stay
/// the gateway's: a door reads their state and subscribes to their topics
/// here, and asks for work by the gateway's operations (a node's by
/// [`Gateway::node_handle`]); it never holds the bus's CAN attachment or a
/// node's SDO channel.
impl ServedBus {
    /// The bus's name (`--bus NAME=SPEC`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The spec it was opened from, as the user wrote it (`virtual:demo`).
    pub fn spec(&self) -> &str {
        &self.spec
    }

    /// What kind of bus it is (SocketCAN, virtual, socketcand).
    pub fn kind(&self) -> crate::can::BusKind {
        self.bus.kind()
    }

    /// Its state (up, down, error passive, …) and why.
    pub fn status(&self) -> crate::can::BusStatus {
        self.bus.status()
    }

    /// Its status from now on: changes as they happen.
    pub fn watch_status(&self) -> tokio::sync::watch::Receiver<crate::can::BusStatus> {
        self.bus.watch_status()
    }

    /// Its frame and error counters.
    pub fn counters(&self) -> crate::can::CounterSnapshot {
        self.bus.counters()
    }

    /// The traffic counted on it so far (frames and bits, by direction).
    pub fn traffic(&self) -> super::load::TrafficSample {
        Traffic::new(&self.bus).sample()
    }

    /// Every frame on the bus from now on, the gateway's own included.
    pub fn monitor(&self) -> crate::can::FrameReceiver {
        self.bus.monitor()
    }

    /// Waits until the bus can send, at most `timeout`.
    pub async fn wait_up(&self, timeout: std::time::Duration) -> Result<(), GatewayError> {
        self.bus.wait_up(timeout).await.map_err(GatewayError::from)
    }

    /// Sends a raw frame, as the gateway itself (a test's rig); a door's
    /// caller sends one by [`Gateway::send_frame`], which holds it to the
    /// policy and audits it.
    pub async fn send_frame(&self, frame: crate::can::Frame) -> Result<(), GatewayError> {
        self.bus.send(frame).await.map_err(GatewayError::from)
    }

    /// Injects a fault into the gateway's own CAN controller on a virtual
    /// bus; elsewhere, not virtual.
    pub fn controller_fault(&self, fault: crate::can::ControllerFault) -> Result<(), GatewayError> {
        self.bus
            .controller_fault(fault)
            .map_err(|_| GatewayError::Sim(super::error::SimError::NotVirtual(self.name.clone())))
    }

    /// The nodes the registry knows, by id.
    pub fn nodes(&self) -> Vec<NodeInfo> {
        self.registry.nodes()
    }

    /// The registry's view of node `id`; `None`: not known.
    pub fn node(&self, id: NodeId) -> Option<NodeInfo> {
        self.registry.node(id)
    }

    /// The EMCY history of node `id` (empty for a node not known).
    pub fn emcy(&self, id: NodeId) -> Vec<super::registry::EmcyRecord> {
        self.registry.emcy(id).unwrap_or_default()
    }

    /// Each node's SDO transfers counted by outcome, for `/metrics`.
    pub fn node_metrics(&self) -> Vec<super::registry::NodeMetrics> {
        self.registry.metrics()
    }

    /// The registry's node events (boot-up, online, offline, EMCY, …)
    /// from now on.
    pub fn node_events(&self) -> tokio::sync::broadcast::Receiver<NodeEvent> {
        self.registry.subscribe()
    }

    /// Scans the bus for nodes (node-ID 1–127) and returns what the
    /// registry then knows, as the gateway itself (a first scan, a test's
    /// rig); a door's caller scans by [`Gateway::scan`], which holds it to
    /// the policy and audits it. The probes run in a task of their own: a
    /// caller that goes away does not cut them half way.
    pub async fn scan(&self) -> Result<Vec<NodeInfo>, GatewayError> {
        let registry = self.registry.clone();
        tokio::spawn(async move { registry.scan().await })
            .await
            .map_err(|err| GatewayError::Internal(format!("scan task: {err}")))?
            .map_err(GatewayError::from)
    }

    /// Returns once the registry has handled every frame and event so far
    /// (the identification of the nodes heard included).
    pub async fn settle(&self) {
        self.registry.settle().await
    }

    /// The bus's load, measured.
    pub fn load(&self) -> &LoadMeter {
        &self.load
    }

    /// The bus's recent frames.
    pub fn frames(&self) -> &FrameLog {
        &self.frames
    }

    /// The nodes' TPDO values, decoded by the mappings read from them; the
    /// `values` topics of the stream (`TpdoValues::subscribe`).
    pub fn values(&self) -> &TpdoValues {
        &self.values
    }

    /// The `axes/{axis}` topics of the stream
    /// (`AxisTelemetry::subscribe`).
    pub fn axes(&self) -> &AxisTelemetry {
        &self.axes
    }

    /// The `segments` topics of the stream (`LedPreviews::subscribe`).
    pub fn previews(&self) -> &LedPreviews {
        &self.previews
    }

    /// The `program` topics of the stream: each node's program download
    /// progress.
    pub fn programs(&self) -> &super::program::ProgramTopics {
        &self.programs
    }

    /// The gateway's SYNC producer on this bus.
    pub fn sync(&self) -> &SyncService {
        &self.sync
    }

    /// The bus's recorder to a candump log.
    pub fn recorder(&self) -> &Recorder {
        &self.recorder
    }

    /// The bus's LSS master, one transaction at a time.
    pub fn lss(&self) -> &super::lss::BusLss {
        &self.lss
    }

    /// The hub of a virtual bus (`None` elsewhere), which counts every
    /// frame on it and takes more attachments (another master, a
    /// candump).
    pub fn hub(&self) -> Option<&VirtualHub> {
        self.hub.as_ref()
    }

    /// The virtual devices of a virtual bus, which the binary's emulator
    /// put on its hub (`AttachDevices`); `None` elsewhere.
    pub fn devices(&self) -> Option<&BusDevices> {
        self.devices.as_ref()
    }
}

/// Refuses before the bus what cannot succeed on it: an SDO transfer on a
/// bus that is down, or to a node known to be stopped.
pub fn check_sdo_allowed(served: &ServedBus, info: &NodeInfo) -> Result<(), GatewayError> {
    if !served.bus.state().can_send() {
        let status = served.bus.status();
        return Err(GatewayError::BusDown(format!(
            "bus {} is {}{}",
            served.name,
            status.state.as_str(),
            status.reason.map(|r| format!(": {r}")).unwrap_or_default()
        )));
    }
    match info.nmt {
        // A node whose last word was its boot-up message is pre-operational
        // by then (CiA 301 §7.3.2.2.1: it enters pre-operational on its own
        // once initialised); a state byte the gateway does not know may
        // allow SDO: only a node known to be stopped is refused.
        Some(state @ NmtState::Stopped) if !state.allows(NmtService::Sdo) => {
            Err(GatewayError::WrongNmtState {
                node: info.id.get(),
                state,
            })
        }
        _ => Ok(()),
    }
}

/// Refuses before the bus a write the node's EDS rules out: an entry it
/// describes as `ro` or `const` is answered with the abort the device
/// would give (CiA 301 §7.2.4.3.17, 0x06010002 "Attempt to write a read
/// only object"), whichever door asks, so that what the dictionary shows
/// as read-only stays so without a transfer. An entry the EDS does not
/// describe is the device's to judge.
pub fn check_writable(info: &NodeInfo, index: u16, sub: u8) -> Result<(), GatewayError> {
    let described = info
        .eds_entry
        .as_ref()
        .and_then(|entry| entry.eds.dictionary.sub(index, sub));
    match described {
        Some(described) if !described.access.is_writable() => Err(GatewayError::SdoAbort {
            node: info.id.get(),
            code: crate::canopen::sdo::AbortCode::ReadOnlyObject,
        }),
        _ => Ok(()),
    }
}

/// The gateway service every adapter holds: the buses by name, and what
/// they share. A `Clone` of `Arc`s.
#[derive(Clone)]
pub struct Gateway {
    pub(crate) buses: Arc<BTreeMap<String, Arc<ServedBus>>>,
    /// The bus names in the order they were given (`--bus`, the config
    /// file): CiA 309 net 1 is the first.
    bus_order: Arc<Vec<String>>,
    /// The audit log and the EMCY/NMT history.
    pub(crate) history: History,
    /// The alarms of every bus (`crate::alarms`).
    pub(crate) alarms: super::alarms::Alarms,
    /// The motion leases of velocity, torque and duty-cycle moves.
    pub(crate) leases: Arc<MotionLeases>,
    /// The axes the gateway enabled, which it stops before it exits.
    pub(crate) enabled_axes: Arc<EnabledAxes>,
    /// Every axis's motion authority: the order of stops and commands.
    pub(crate) authority: Arc<super::authority::MotionAuthority>,
    /// The tokens and their roles; none: the gateway is open.
    pub(crate) tokens: Arc<Tokens>,
    /// The write rate limit of every token, whichever adapter its writes
    /// come through (REST, CiA 309-5, CiA 309-3).
    pub(crate) writes: Arc<WriteLimiter>,
    /// The quota of the kept recordings (`--data-dir`); `None`: none.
    recordings_quota: Option<Arc<RecordingsQuota>>,
    /// The Sparkplug B edge node's counters (`mqtt_url`).
    edge_node: Arc<super::edge_node::EdgeNodeStats>,
    /// The data loggers (`/loggers`).
    loggers: super::logger::Loggers,
    /// The tasks [`Gateway::start`] started beside the doors (pruners,
    /// first scans), ended by [`Gateway::shutdown`].
    pub(crate) background: Arc<super::start::BackgroundTasks>,
    /// The turns at fanning the streams out to their clients, for every
    /// door's sessions together.
    stream_turns: super::telemetry::StreamTurns,
    /// Every node's sampled objects, bounded per node for every door.
    pub(crate) samplers: Arc<super::sampling::Samplers>,
}

impl Gateway {
    /// The buses, with a history in memory (lost on exit).
    pub fn new(buses: impl IntoIterator<Item = ServedBus>) -> Self {
        // An in-memory SQLite database fails to open only when memory is
        // exhausted, when nothing else would work either.
        let history = History::in_memory().expect("an in-memory SQLite database opens");
        Self::with_history(buses, history)
    }

    /// The buses, their registry events written to `history` by a task per
    /// bus (call within a tokio runtime when there are buses).
    pub fn with_history(buses: impl IntoIterator<Item = ServedBus>, history: History) -> Self {
        let buses: Vec<ServedBus> = buses.into_iter().collect();
        let bus_order: Vec<String> = buses.iter().map(|bus| bus.name.clone()).collect();
        let buses: BTreeMap<String, Arc<ServedBus>> = buses
            .into_iter()
            .map(|bus| (bus.name.clone(), Arc::new(bus)))
            .collect();
        for bus in buses.values() {
            let taken = bus
                .history_events
                .lock()
                .unwrap_or_else(|poison| poison.into_inner())
                .take();
            let events = taken.unwrap_or_else(|| bus.registry.subscribe());
            history.spawn_recorder(&bus.name, events);
        }
        let alarms = super::alarms::Alarms::start(history.clone());
        for bus in buses.values() {
            super::alarms::follow_bus(&alarms, bus);
        }
        Self {
            buses: Arc::new(buses),
            bus_order: Arc::new(bus_order),
            history,
            alarms,
            leases: Arc::new(MotionLeases::default()),
            enabled_axes: Arc::new(EnabledAxes::default()),
            authority: Arc::default(),
            tokens: Arc::new(Tokens::default()),
            writes: Arc::new(WriteLimiter::default()),
            recordings_quota: None,
            edge_node: Arc::default(),
            background: Arc::default(),
            loggers: super::logger::Loggers::default(),
            stream_turns: super::telemetry::StreamTurns::default(),
            samplers: Arc::default(),
        }
    }

    /// The same with these loggers (`logger_max_values`, and those kept in
    /// the data directory: `Loggers::load`).
    pub fn with_loggers(mut self, loggers: super::logger::Loggers) -> Self {
        self.loggers = loggers;
        self
    }

    /// The same, granting motion leases of `period` (`--lease-ms`).
    pub fn with_lease_period(mut self, period: std::time::Duration) -> Self {
        self.leases = Arc::new(MotionLeases::new(period));
        self
    }

    /// The same, sampling at most `samples_per_s` objects a second per
    /// node over SDO ([`Gateway::sample_objects`]).
    pub fn with_sdo_samples_per_s(mut self, samples_per_s: u32) -> Self {
        self.samplers = Arc::new(super::sampling::Samplers::new(samples_per_s));
        self
    }

    /// The same with these tokens.
    pub fn with_tokens(mut self, tokens: Tokens) -> Self {
        self.tokens = Arc::new(tokens);
        self
    }

    /// The same with this write rate limit per token (`None`: none).
    pub fn with_write_limit(mut self, limit: Option<RateLimit>) -> Self {
        self.writes = Arc::new(WriteLimiter::new(limit));
        self
    }

    /// The same, keeping the recordings within `quota`
    /// ([`Gateway::prune_recordings`]).
    pub fn with_recordings_quota(mut self, quota: RecordingsQuota) -> Self {
        self.recordings_quota = Some(Arc::new(quota));
        self
    }

    /// Removes the oldest kept recordings beyond the quota (never a bus's
    /// running or last one), each removal written to the audit log as the
    /// gateway's; what it removed.
    pub async fn prune_recordings(&self) -> Vec<Pruned> {
        let Some(quota) = self.recordings_quota.clone() else {
            return Vec::new();
        };
        let keep: Vec<_> = self
            .buses
            .values()
            .filter_map(|bus| bus.recorder.current_path())
            .collect();
        let pruned = match tokio::task::spawn_blocking(move || prune(&quota, &keep)).await {
            Ok(Ok(pruned)) => pruned,
            Ok(Err(err)) => {
                tracing::warn!("recordings: pruning failed: {err}");
                return Vec::new();
            }
            Err(err) => {
                tracing::error!("recordings: pruning task: {err}");
                return Vec::new();
            }
        };
        for removed in &pruned {
            tracing::info!(
                "recordings: {} ({} bytes) removed: over recordings_quota_mb",
                removed.file_name,
                removed.bytes
            );
            let target =
                AuditTarget::new("prune recording (over quota)").item(removed.file_name.clone());
            let request = format!("{{\"bytes\":{}}}", removed.bytes);
            self.audit_row(&Caller::system(), target, Some(request))
                .finish_ok()
                .await;
        }
        pruned
    }

    /// Prunes the recordings now and then every `period`, until the task
    /// is aborted.
    pub fn spawn_recordings_pruner(
        &self,
        period: std::time::Duration,
    ) -> tokio::task::JoinHandle<()> {
        let gateway = self.clone();
        tokio::spawn(async move {
            let mut ticks = tokio::time::interval(period);
            loop {
                ticks.tick().await;
                gateway.prune_recordings().await;
            }
        })
    }

    /// The buses, by name.
    pub fn buses(&self) -> impl ExactSizeIterator<Item = &Arc<ServedBus>> {
        self.buses.values()
    }

    /// The audit log and the EMCY/NMT history.
    pub fn history(&self) -> &History {
        &self.history
    }

    /// The tokens and their roles (none: the gateway is open).
    pub fn tokens(&self) -> &Tokens {
        &self.tokens
    }

    /// The turns at fanning the streams out: a door's stream session takes
    /// one before it renders and writes to its client.
    pub fn stream_turns(&self) -> &super::telemetry::StreamTurns {
        &self.stream_turns
    }

    /// The data loggers.
    pub fn loggers(&self) -> &super::logger::Loggers {
        &self.loggers
    }

    /// The Sparkplug B edge node's counters, which the edge node counts
    /// into and `/metrics` reads.
    pub fn edge_node_stats(&self) -> &Arc<super::edge_node::EdgeNodeStats> {
        &self.edge_node
    }

    /// The buses in the order they were given: CiA 309 net `n` is the
    /// `n`-th (1-based).
    pub fn buses_in_order(&self) -> Vec<Arc<ServedBus>> {
        self.bus_order
            .iter()
            .filter_map(|name| self.buses.get(name).cloned())
            .collect()
    }

    /// The bus named `name`.
    pub fn bus(&self, name: &str) -> Result<Arc<ServedBus>, GatewayError> {
        self.buses
            .get(name)
            .cloned()
            .ok_or_else(|| GatewayError::UnknownBus(name.to_string()))
    }

    /// The bus and the registry's view of a node: an id that is no node id
    /// (1–127) is an invalid request; a bus or node not known, unknown.
    pub fn node(&self, bus: &str, id: &str) -> Result<(Arc<ServedBus>, NodeInfo), GatewayError> {
        let served = self.bus(bus)?;
        let node: NodeId = id
            .parse()
            .map_err(|err| GatewayError::InvalidRequest(format!("node id '{id}': {err}")))?;
        let info = served
            .registry
            .node(node)
            .ok_or_else(|| GatewayError::UnknownNode {
                bus: bus.to_string(),
                node: id.to_string(),
            })?;
        Ok((served, info))
    }

    /// A node's axis, after the checks that need no bus: the node is a
    /// drive with that axis, SDO is allowed, and a drive supervised by
    /// heartbeat is heard (else every transfer would wait out its timeout,
    /// and a motion command could not be followed up).
    pub fn drive(&self, bus: &str, id: &str, axis: &str) -> Result<Drive, GatewayError> {
        let (served, info) = self.node(bus, id)?;
        let drive = Drive::new(&served.registry, &info, axis)?;
        check_sdo_allowed(&served, &info)?;
        if !info.online && info.heartbeat_ms.is_some() {
            return Err(GatewayError::NodeOffline(format!(
                "node {} is offline (no heartbeat within 1.5 periods of {} ms): \
                 drive operations wait until it is heard again",
                info.id,
                info.heartbeat_ms.unwrap_or_default()
            )));
        }
        Ok(drive)
    }
}
