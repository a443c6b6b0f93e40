//! The node registry of one bus: which nodes are there, what they are, and
//! whether they are alive. Fed by every frame of the bus: boot-up and
//! heartbeat (CiA 301 §7.2.8.3.2), EMCY (§7.2.7), and the answers to its own
//! SDO requests (§7.2.4) when it identifies a node or scans the bus.
//!
//! - A node heard for the first time (boot-up, heartbeat or EMCY), or found
//!   by [`NodeRegistry::scan`], is added and identified in the background
//!   through its [`SdoChannel`]: device type 0x1000, identity 0x1018 sub 1–4,
//!   device name 0x1008 and producer heartbeat time 0x1017. An object the
//!   node refuses (SDO abort) is only missing; a node that does not answer
//!   stays listed as `generic` with no identity, and is identified again on
//!   its next boot-up, when it leaves the stopped state (where CiA 301 allows
//!   no SDO), or when a scan finds it. Reads are retried on a timeout (they
//!   change nothing on the device).
//! - A boot-up message resets what is known of the node (identity, profile,
//!   heartbeat period) and identifies it again: a node that boots may be
//!   another device. Its EMCY history is kept.
//! - Supervision: the bus's one [`Supervisor`] (online, NMT state,
//!   heartbeat period and deadline, node guarding) lives here, fed by the
//!   registry's bus task: the producer period of a node is its 0x1017 as
//!   read during identification, and is learnt from its heartbeats (the
//!   shortest of the last few intervals, so that a changed 0x1017 is followed
//!   and one lost heartbeat does not double it); a write of its 0x1017
//!   through the gateway (any node's [`SdoChannel`] made here reports it)
//!   sets the period at once and is published as
//!   [`NodeEvent::HeartbeatWritten`]. The node goes offline when
//!   no heartbeat comes within 1.5 periods (a node the network manager
//!   guards: no valid reply within its life time), and online again with
//!   its next heartbeat. A node without heartbeat is online from any frame
//!   it sends, and offline when it does not answer a scan. The network
//!   manager follows the same decisions
//!   ([`NodeRegistry::subscribe_supervision`]) rather than timing the nodes
//!   itself, so the node list and the machine view cannot disagree.
//! - Bus down: nodes are kept (they are most likely still there, and the
//!   operator wants to see what was on the bus) but marked offline, since
//!   nothing can reach them. When the bus is up again, nodes with a
//!   heartbeat come back with it; the others are asked for their 0x1000 once.
//! - EMCYs are decoded with their texts, kept per node (the last
//!   [`RegistryConfig::emcy_history`]) and published as [`NodeEvent::Emcy`].
//!
//! One task per registry reads the bus; it never waits on a device. Every SDO
//! transfer runs in a task of its own that is never cancelled halfway, so a
//! node's [`SdoChannel`] is always left ready for the next transfer.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fmt;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::sync::{Notify, broadcast, watch};
use tokio::time::Instant;

use crate::can::{Bus, BusError, FrameReceiver, RecvError, TimedFrame, Timestamp};
use crate::canopen::NodeId;
use crate::canopen::cob::Function;
use crate::canopen::eds::EdsError;
use crate::canopen::emcy::{Emcy, emcy_text};
use crate::canopen::manager::{LostBy, NodeSupervision, OfflineCause, Supervisor, SupervisorEvent};
use crate::canopen::nmt::NmtState;
use crate::canopen::sdo::{ClientConfig, SdoError};

use super::profile::{EdsCatalog, EdsEntry, Identity, Profile};
use super::sdo::{SdoChannel, SdoRequestError, SdoStatsSnapshot};

#[cfg(test)]
mod tests;

/// Device type.
const DEVICE_TYPE: u16 = 0x1000;
/// Manufacturer device name.
const DEVICE_NAME: u16 = 0x1008;
/// Producer heartbeat time, in ms.
const PRODUCER_HEARTBEAT_TIME: u16 = 0x1017;
/// Identity object: sub 1 vendor, 2 product code, 3 revision, 4 serial.
const IDENTITY: u16 = 0x1018;

/// The longest device name kept (0x1008 is a VISIBLE_STRING of any length).
const MAX_NAME_LEN: usize = 256;

/// Why the registry could not do what was asked. Kept apart: what a file
/// said (EDS), what the bus did, what a device said (in [`SdoRequestError`]:
/// abort, timeout or bus).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RegistryError {
    /// An EDS file could not be read; the error names the file and line.
    #[error(transparent)]
    Eds(#[from] EdsError),
    /// An EDS file reads, but no device can be matched to it.
    #[error("{file}: {message}")]
    EdsUnmatchable { file: String, message: String },
    /// The EDS directory could not be listed.
    #[error("EDS directory {}: {message}", .dir.display())]
    EdsDir { dir: PathBuf, message: String },
    /// The node is not in the registry (never heard, never found by a scan).
    #[error("node {node} is not known on bus {bus}")]
    UnknownNode { bus: String, node: NodeId },
    /// The bus cannot carry the request (down, closed).
    #[error(transparent)]
    Bus(#[from] BusError),
    /// An SDO transfer failed: device abort, timeout or bus.
    #[error(transparent)]
    Sdo(#[from] SdoRequestError),
}

/// How the registry talks to nodes.
#[derive(Debug, Clone)]
pub struct RegistryConfig {
    /// The SDO client of each node's [`SdoChannel`].
    pub sdo: ClientConfig,
    /// How long a scan waits for a node id nobody has heard of: most ids
    /// are empty, and each costs this much.
    pub probe_timeout: Duration,
    /// Node ids a scan probes at once: enough to be quick, few enough to
    /// leave the bus to the machine.
    pub scan_concurrency: usize,
    /// Times a read of the identification is repeated after a timeout.
    pub read_retries: u32,
    /// EMCYs kept per node.
    pub emcy_history: usize,
    /// Events a subscriber may fall behind before it loses the oldest (and
    /// is told how many).
    pub event_capacity: usize,
    /// The producers of the telemetry topics that follow the registry's
    /// nodes (axis polling rate, LED parameter reads); the registry itself
    /// does not use it.
    pub telemetry: super::producers::TelemetryConfig,
    /// Heartbeat periods a node may be silent before its supervisor loses
    /// it (`heartbeat_consumer_factor`).
    pub consumer_factor: crate::canopen::manager::ConsumerFactor,
}

impl Default for RegistryConfig {
    fn default() -> Self {
        Self {
            sdo: ClientConfig::default(),
            probe_timeout: Duration::from_millis(100),
            scan_concurrency: 8,
            read_retries: 1,
            emcy_history: 32,
            event_capacity: 256,
            telemetry: super::producers::TelemetryConfig::default(),
            consumer_factor: crate::canopen::manager::ConsumerFactor::DEFAULT,
        }
    }
}

/// Where the identification of a node stands.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum Identification {
    /// Being read (or waiting for its turn on the node's SDO channel).
    Pending,
    /// Read; objects the node refused are `None` in [`NodeInfo`].
    Done,
    /// The node did not answer; it is tried again on its next boot-up.
    Failed { error: String },
}

/// Why a node went offline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OfflineReason {
    /// No heartbeat within 1.5 producer periods.
    HeartbeatLost,
    /// The bus went down: nothing can reach the node.
    BusDown,
    /// A node without heartbeat did not answer a scan.
    NoAnswer,
    /// The network manager's node guarding got no reply within the node
    /// life time.
    GuardingLost,
    /// Its device moved to another node-ID (0x2040 change): the old ID is
    /// forgotten.
    NodeIdChanged,
}

/// One emergency message, decoded, as the API shows it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EmcyRecord {
    /// The emergency error code.
    pub code: u16,
    /// The most specific text known for the code.
    pub text: String,
    /// The error register (0x1001) sent with it.
    pub register: u8,
    /// The 5 manufacturer-specific bytes.
    pub manufacturer: [u8; 5],
    /// When the frame was received.
    pub timestamp: Timestamp,
    /// The axis (1-based) the EMCY belongs to, where the node's profile
    /// says ([`Profile::emcy_axis`]); `None` for the whole node.
    pub axis: Option<u8>,
}

impl EmcyRecord {
    pub fn new(emcy: &Emcy, timestamp: Timestamp) -> Self {
        Self {
            code: emcy.code,
            text: emcy_text(emcy.code),
            register: emcy.register.raw(),
            manufacturer: emcy.manufacturer,
            timestamp,
            axis: None,
        }
    }

    /// Whether this is an error reset (the device's errors are gone).
    pub fn is_reset(&self) -> bool {
        self.code & 0xFF00 == 0
    }

    /// The manufacturer bytes as hex, as the API writes them.
    pub fn manufacturer_hex(&self) -> String {
        self.manufacturer
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    }
}

impl serde::Serialize for EmcyRecord {
    /// `{"code":"0x4310","text":..,"register":9,"manufacturer":"0102030405","timestamp_us":..,"axis":null}`
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut out = serializer.serialize_struct("EmcyRecord", 6)?;
        out.serialize_field("code", &format!("0x{:04X}", self.code))?;
        out.serialize_field("text", &self.text)?;
        out.serialize_field("register", &self.register)?;
        out.serialize_field("manufacturer", &self.manufacturer_hex())?;
        out.serialize_field("timestamp_us", &self.timestamp.as_micros())?;
        out.serialize_field("axis", &self.axis)?;
        out.end()
    }
}

/// What the registry knows of one node, at one moment.
#[derive(Debug, Clone, serde::Serialize)]
pub struct NodeInfo {
    #[serde(serialize_with = "node_id")]
    pub id: NodeId,
    /// The last NMT state the node reported; `None` ("unknown") for a node
    /// found by a scan that has sent no heartbeat.
    #[serde(serialize_with = "nmt_name")]
    pub nmt: Option<NmtState>,
    pub online: bool,
    /// Milliseconds since the last frame from the node.
    pub last_seen_ms: u64,
    pub identity: Option<Identity>,
    pub device_type: Option<u32>,
    /// The manufacturer device name, 0x1008.
    pub name: Option<String>,
    pub profile: Profile,
    /// The name of the EDS file that describes the node.
    pub eds: Option<String>,
    /// Whether that file was assigned to the node by hand
    /// ([`NodeRegistry::assign_eds`]) rather than matched by its identity.
    pub eds_assigned: bool,
    /// The EDS itself, shared with the catalog.
    #[serde(skip)]
    pub eds_entry: Option<Arc<EdsEntry>>,
    /// The producer heartbeat period the node is supervised with; `None`
    /// while it sends no heartbeat.
    pub heartbeat_ms: Option<u64>,
    pub identification: Identification,
}

fn node_id<S: serde::Serializer>(id: &NodeId, serializer: S) -> Result<S::Ok, S::Error> {
    serializer.serialize_u8(id.get())
}

fn nmt_name<S: serde::Serializer>(
    nmt: &Option<NmtState>,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    serializer.serialize_str(nmt.map_or("unknown", NmtState::name))
}

/// The numbers of one node, for `/metrics`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NodeMetrics {
    pub id: NodeId,
    pub online: bool,
    /// Its SDO transfers since it was first heard (its channel lives as
    /// long as the node is in the registry, across boot-ups).
    pub sdo: SdoStatsSnapshot,
}

/// What happened to a node, for whoever streams it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NodeEvent {
    /// A node was heard, or found by a scan, for the first time.
    Appeared {
        node: NodeId,
    },
    /// Its identification finished: the profile and EDS it was matched to.
    Identified {
        node: NodeId,
        profile: Profile,
        eds: Option<String>,
    },
    /// It did not answer its identification.
    IdentificationFailed {
        node: NodeId,
        error: String,
    },
    /// It reported (or, after its boot-up and an SDO answer, is known to be
    /// in) another NMT state.
    NmtChanged {
        node: NodeId,
        from: Option<NmtState>,
        to: NmtState,
    },
    Offline {
        node: NodeId,
        reason: OfflineReason,
    },
    Online {
        node: NodeId,
    },
    Emcy {
        node: NodeId,
        emcy: EmcyRecord,
    },
    /// Its producer heartbeat time (0x1017 sub 0) was written through the
    /// gateway (by anyone: a client, the network manager's boot-up) and
    /// the node confirmed it: the supervisor times it with this period
    /// from now on (0: no heartbeat), for the registry and the network
    /// manager alike.
    HeartbeatWritten {
        node: NodeId,
        heartbeat_ms: u16,
    },
    /// An admin's write switched off the node's protection against the
    /// gateway's death (docs/security.md, "Watchdog policy"): `warning`
    /// says which object, what it no longer does, and who wrote it.
    WatchdogOff {
        node: NodeId,
        warning: String,
    },
    /// The gateway stopped an axis of the node and ended what moved it (its
    /// lease, its record as enabled), for `reason` (`node_id_changed`: the
    /// device is being given another node-ID; `reconfiguration`: the network
    /// manager's boot-up is about to write its motion objects); `detail`
    /// says what ended.
    MotionEnded {
        node: NodeId,
        axis: u8,
        reason: &'static str,
        detail: String,
    },
}

impl NodeEvent {
    pub fn node(&self) -> NodeId {
        match self {
            Self::Appeared { node }
            | Self::Identified { node, .. }
            | Self::IdentificationFailed { node, .. }
            | Self::NmtChanged { node, .. }
            | Self::Offline { node, .. }
            | Self::Online { node }
            | Self::Emcy { node, .. }
            | Self::HeartbeatWritten { node, .. }
            | Self::WatchdogOff { node, .. }
            | Self::MotionEnded { node, .. } => *node,
        }
    }
}

impl fmt::Display for NodeEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Appeared { node } => write!(f, "node {node} appeared"),
            Self::Identified { node, profile, eds } => write!(
                f,
                "node {node} identified: {profile}, EDS {}",
                eds.as_deref().unwrap_or("none")
            ),
            Self::IdentificationFailed { node, error } => {
                write!(f, "node {node} not identified: {error}")
            }
            Self::NmtChanged { node, to, .. } => write!(f, "node {node} is {to}"),
            Self::Offline { node, reason } => write!(f, "node {node} offline ({reason:?})"),
            Self::Online { node } => write!(f, "node {node} online"),
            Self::Emcy { node, emcy } => write!(
                f,
                "node {node} EMCY 0x{:04X} {}, register 0x{:02X}",
                emcy.code, emcy.text, emcy.register
            ),
            Self::HeartbeatWritten { node, heartbeat_ms } => {
                write!(f, "node {node} heartbeat time written: {heartbeat_ms} ms")
            }
            Self::WatchdogOff { node, warning } => {
                write!(f, "node {node} watchdog switched off: {warning}")
            }
            Self::MotionEnded {
                node,
                axis,
                reason,
                detail,
            } => write!(
                f,
                "node {node} axis {axis}: motion ended ({reason}): {detail}"
            ),
        }
    }
}

struct Node {
    id: NodeId,
    channel: SdoChannel,
    identity: Option<Identity>,
    device_type: Option<u32>,
    name: Option<String>,
    profile: Profile,
    eds: Option<Arc<EdsEntry>>,
    eds_assigned: bool,
    identification: Identification,
    /// Bumped by every boot-up: an identification that started before it is
    /// out of date.
    generation: u64,
    /// An identification task is running for the node.
    identifying: bool,
    emcy: VecDeque<EmcyRecord>,
}

impl Node {
    /// The node as known now; its supervision is the supervisor's.
    fn info(&self, supervisor: &Supervisor, now: Instant) -> NodeInfo {
        let supervision = supervisor.node(self.id);
        let last_seen =
            supervision.map_or(now, |supervision| Instant::from_std(supervision.last_seen));
        NodeInfo {
            id: self.id,
            nmt: supervision.and_then(|supervision| supervision.nmt),
            online: supervision.is_some_and(|supervision| supervision.online),
            last_seen_ms: u64::try_from(now.saturating_duration_since(last_seen).as_millis())
                .unwrap_or(u64::MAX),
            identity: self.identity,
            device_type: self.device_type,
            name: self.name.clone(),
            profile: self.profile,
            eds: self.eds.as_ref().map(|entry| entry.name.clone()),
            eds_assigned: self.eds_assigned,
            eds_entry: self.eds.clone(),
            heartbeat_ms: supervision
                .and_then(|supervision| supervision.heartbeat)
                .map(|period| u64::try_from(period.as_millis()).unwrap_or(u64::MAX)),
            identification: self.identification.clone(),
        }
    }

    /// What an identification found goes; what the node is stays.
    fn forget_identity(&mut self) {
        self.identity = None;
        self.device_type = None;
        self.name = None;
        self.profile = Profile::Generic;
        self.eds = None;
        self.eds_assigned = false;
    }

    /// Its EDS and profile: the file assigned to it by hand if there is
    /// one (the profile from that file, else from the device's 0x1000),
    /// else the catalog's match for its identity. Whether they changed.
    fn describe(&mut self, catalog: &EdsCatalog, assigned: Option<&Arc<EdsEntry>>) -> bool {
        let (eds, profile) = match assigned {
            Some(entry) => (Some(entry.clone()), entry.profile_for(self.device_type)),
            None if self.identification == Identification::Done => (
                self.identity
                    .as_ref()
                    .and_then(|identity| catalog.lookup(identity)),
                catalog.profile(self.identity.as_ref(), self.device_type),
            ),
            None => (None, Profile::Generic),
        };
        let same_eds = match (&self.eds, &eds) {
            (Some(a), Some(b)) => Arc::ptr_eq(a, b),
            (None, None) => true,
            _ => false,
        };
        let changed = !same_eds || self.profile != profile;
        self.eds = eds;
        self.profile = profile;
        self.eds_assigned = assigned.is_some();
        changed
    }
}

struct State {
    nodes: BTreeMap<NodeId, Node>,
    /// The channels a scan probes unknown node ids with. A node that
    /// appears while its probe runs takes over that channel, so that
    /// everyone's transfers queue behind the probe: two SDO clients talking
    /// to one server at once see each other's answers.
    probe_channels: BTreeMap<NodeId, SdoChannel>,
    /// The one supervision of the bus's nodes: online, NMT state,
    /// heartbeat period and deadline, guarding.
    supervisor: Supervisor,
    /// The EDS files assigned to node ids by hand, whether or not the node
    /// has been heard yet.
    assigned: BTreeMap<NodeId, Arc<EdsEntry>>,
}

struct Shared {
    bus: Bus,
    catalog: Arc<EdsCatalog>,
    config: RegistryConfig,
    state: Mutex<State>,
    events: broadcast::Sender<NodeEvent>,
    /// Node ids a scan is probing with a channel of its own: their
    /// identification waits, so two clients never talk to one node at once.
    probing: watch::Sender<BTreeSet<NodeId>>,
    /// Bumped whenever an identification ends.
    identified: watch::Sender<u64>,
    /// Wakes the bus task when a heartbeat deadline changed elsewhere.
    rearm: Notify,
    /// Every download a node confirmed, through any of its channels.
    writes: broadcast::Sender<ObjectWritten>,
    /// What the supervisor decided, for the network manager.
    supervision: broadcast::Sender<SupervisorEvent>,
}

/// A download a node confirmed (CiA 301 §7.2.4.3: the server's response),
/// whichever door or task asked for it: what follows a write (the TPDO
/// decoders, an LED preview, the heartbeat supervision) follows it here,
/// once, instead of in each door.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ObjectWritten {
    pub node: NodeId,
    pub index: u16,
    pub sub: u8,
}

/// Confirmed writes kept for a slow follower before it lags (a lagging
/// follower refreshes what it follows as if every object were written).
const WRITES_CAPACITY: usize = 256;

/// Supervision events kept for a slow follower: one per heartbeat heard,
/// so room for a few seconds of a full bus.
const SUPERVISION_CAPACITY: usize = 4096;

/// Stops the bus task when the last handle goes.
struct TaskGuard(tokio::task::AbortHandle);

impl Drop for TaskGuard {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// The node registry of one bus. Cheap to clone; clones share it. The task
/// that reads the bus stops when the last handle is dropped.
#[derive(Clone)]
pub struct NodeRegistry {
    shared: Arc<Shared>,
    _task: Arc<TaskGuard>,
}

impl fmt::Debug for NodeRegistry {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("NodeRegistry")
            .field("bus", &self.shared.bus.name())
            .finish()
    }
}

/// What an SDO request of a probe told.
enum Probe {
    /// Something answered on the node's SDO COB-ID (a value, an abort,
    /// even a broken answer): the node is there.
    Answered,
    /// Nothing came back in time.
    Silent,
    /// The bus failed.
    BusFailed(SdoRequestError),
}

impl Probe {
    fn of<T>(result: &Result<T, SdoRequestError>) -> Self {
        match result {
            Ok(_) => Self::Answered,
            Err(SdoRequestError::Sdo {
                error: SdoError::Timeout,
                ..
            }) => Self::Silent,
            Err(error @ SdoRequestError::Bus { .. }) => Self::BusFailed(error.clone()),
            Err(SdoRequestError::Sdo { .. }) => Self::Answered,
        }
    }
}

/// What an identification read.
struct Identified {
    device_type: Option<u32>,
    identity: Option<Identity>,
    name: Option<String>,
    heartbeat_ms: Option<u16>,
}

/// Why an identification stopped before its end.
enum Abandon {
    /// The node booted meanwhile: start again.
    Stale,
    /// The node did not answer.
    Failed(SdoRequestError),
}

impl NodeRegistry {
    /// Starts the registry of `bus`: from now on every frame of the bus
    /// feeds it. Nodes that booted before are found by their heartbeat, an
    /// EMCY, or a [`scan`](Self::scan). Needs a tokio runtime.
    pub fn spawn(bus: Bus, catalog: Arc<EdsCatalog>, config: RegistryConfig) -> Self {
        let frames = bus.subscribe();
        let status = bus.watch_status();
        let bus_up = bus.state().can_send();
        let (events, _) = broadcast::channel(config.event_capacity.max(1));
        let shared = Arc::new(Shared {
            catalog,
            state: Mutex::new(State {
                nodes: BTreeMap::new(),
                probe_channels: BTreeMap::new(),
                supervisor: Supervisor::new(bus_up).with_consumer_factor(config.consumer_factor),
                assigned: BTreeMap::new(),
            }),
            events,
            probing: watch::Sender::new(BTreeSet::new()),
            identified: watch::Sender::new(0),
            rearm: Notify::new(),
            writes: broadcast::channel(WRITES_CAPACITY).0,
            supervision: broadcast::channel(SUPERVISION_CAPACITY).0,
            config,
            bus,
        });
        let task = tokio::spawn(run(shared.clone(), frames, status));
        Self {
            shared,
            _task: Arc::new(TaskGuard(task.abort_handle())),
        }
    }

    /// The bus's name.
    pub fn bus_name(&self) -> &str {
        self.shared.bus.name()
    }

    pub fn catalog(&self) -> &Arc<EdsCatalog> {
        &self.shared.catalog
    }

    /// Every node known, by id.
    pub fn nodes(&self) -> Vec<NodeInfo> {
        let now = Instant::now();
        let state = self.shared.lock();
        state
            .nodes
            .values()
            .map(|node| node.info(&state.supervisor, now))
            .collect()
    }

    pub fn node(&self, id: NodeId) -> Option<NodeInfo> {
        let state = self.shared.lock();
        state
            .nodes
            .get(&id)
            .map(|node| node.info(&state.supervisor, Instant::now()))
    }

    /// The node's supervision as the bus's one supervisor sees it now.
    pub fn supervision(&self, id: NodeId) -> Option<NodeSupervision> {
        self.shared.lock().supervisor.node(id)
    }

    /// Every node known, by id: whether it is online and the counts of its
    /// SDO channel. One short lock, nothing cloned but numbers (for
    /// `/metrics`).
    pub fn metrics(&self) -> Vec<NodeMetrics> {
        let state = self.shared.lock();
        state
            .nodes
            .values()
            .map(|node| NodeMetrics {
                id: node.id,
                online: state
                    .supervisor
                    .node(node.id)
                    .is_some_and(|supervision| supervision.online),
                sdo: node.channel.stats(),
            })
            .collect()
    }

    /// The node's recent EMCYs, oldest first; `None` for an unknown node.
    pub fn emcy(&self, id: NodeId) -> Option<Vec<EmcyRecord>> {
        self.shared
            .lock()
            .nodes
            .get(&id)
            .map(|node| node.emcy.iter().cloned().collect())
    }

    /// The node's SDO channel, shared by everyone who talks to the node, so
    /// that its transfers queue fairly, one at a time.
    pub(crate) fn sdo(&self, id: NodeId) -> Result<SdoChannel, RegistryError> {
        self.shared
            .lock()
            .nodes
            .get(&id)
            .map(|node| node.channel.clone())
            .ok_or_else(|| RegistryError::UnknownNode {
                bus: self.bus_name().to_string(),
                node: id,
            })
    }

    /// Describes node `id` by `entry` from now on, whatever its identity
    /// says (`None`: by its identity again, as the catalog matches it). The
    /// assignment holds for the node id: through the node's boot-ups, and
    /// for a node not heard yet, from when it is. The node's profile
    /// follows the file's device type (or the device's, when the file has
    /// none). Returns the node as it is now, if it is known; a change is
    /// published as [`NodeEvent::Identified`].
    pub fn assign_eds(&self, id: NodeId, entry: Option<Arc<EdsEntry>>) -> Option<NodeInfo> {
        let mut state = self.shared.lock();
        match entry {
            Some(entry) => state.assigned.insert(id, entry),
            None => state.assigned.remove(&id),
        };
        let State {
            nodes,
            assigned,
            supervisor,
            ..
        } = &mut *state;
        let node = nodes.get_mut(&id)?;
        if node.describe(&self.shared.catalog, assigned.get(&id)) {
            self.shared.emit(NodeEvent::Identified {
                node: id,
                profile: node.profile,
                eds: node.eds.as_ref().map(|entry| entry.name.clone()),
            });
        }
        Some(node.info(supervisor, Instant::now()))
    }

    /// The EDS files assigned by hand, by node id.
    pub fn assignments(&self) -> BTreeMap<NodeId, String> {
        self.shared
            .lock()
            .assigned
            .iter()
            .map(|(id, entry)| (*id, entry.name.clone()))
            .collect()
    }

    /// Matches every node to the catalog again (a file joined or left it);
    /// the nodes whose EDS or profile changed are published as
    /// [`NodeEvent::Identified`].
    pub fn rematch(&self) {
        let mut state = self.shared.lock();
        let State {
            nodes, assigned, ..
        } = &mut *state;
        for node in nodes.values_mut() {
            if node.describe(&self.shared.catalog, assigned.get(&node.id)) {
                self.shared.emit(NodeEvent::Identified {
                    node: node.id,
                    profile: node.profile,
                    eds: node.eds.as_ref().map(|entry| entry.name.clone()),
                });
            }
        }
    }

    /// Tells whoever streams the nodes that an admin switched off the
    /// node's watchdog ([`NodeEvent::WatchdogOff`]).
    pub(crate) fn watchdog_off(&self, node: NodeId, warning: String) {
        self.shared.emit(NodeEvent::WatchdogOff { node, warning });
    }

    /// The network manager guards node `id` from now on, with the guard
    /// time (ms) and life time factor it wrote: the supervisor sends the
    /// requests and loses the node when no valid reply comes within the
    /// life time.
    pub fn guard(&self, id: NodeId, guard_time_ms: u16, life_time_factor: u8) {
        let now = Instant::now().into_std();
        self.shared
            .lock()
            .supervisor
            .guard(id, guard_time_ms, life_time_factor, now);
        self.shared.rearm.notify_one();
    }

    /// The network manager stopped guarding node `id`.
    pub fn unguard(&self, id: NodeId) {
        let now = Instant::now().into_std();
        self.shared.lock().supervisor.unguard(id, now);
        self.shared.rearm.notify_one();
    }

    /// The device at `id` moved to another node-ID for good: the old ID
    /// goes offline (`reason`), then is forgotten (no longer listed nor
    /// supervised; requests to it are refused as for an unknown node). A
    /// device heard at that ID later is a new node.
    pub fn retire(&self, id: NodeId, reason: OfflineReason) {
        {
            let mut state = self.shared.lock();
            if state.nodes.remove(&id).is_none() {
                return;
            }
            state.supervisor.forget(id);
            // Sent even when it was offline already: those who follow the
            // node (the network manager, the stream) learn that it left for
            // good.
            self.shared.emit(NodeEvent::Offline { node: id, reason });
        }
        // Whoever waits for its identification stops waiting.
        self.shared.identified.send_modify(|count| *count += 1);
    }

    /// Waits until the node is identified since its last boot-up message
    /// (what it is: its identity, hence its profile and EDS), and says how
    /// that ended: `Err` with why when it did not answer, or when it left
    /// the bus meanwhile. An identification that had failed is started
    /// again first. The network manager asks it in every boot-up, so that
    /// a node is not `ready` while it is known only as `generic`.
    pub(crate) async fn identify(&self, id: NodeId) -> Result<(), String> {
        {
            let mut state = self.shared.lock();
            let Some(node) = state.nodes.get_mut(&id) else {
                return Err(format!("node {id} is not on the bus"));
            };
            if matches!(node.identification, Identification::Failed { .. }) {
                self.shared.start_identification(node);
            }
        }
        let mut outcome = Err(String::new());
        let mut identified = self.shared.identified.subscribe();
        // The sender lives in `shared`: waiting cannot fail.
        let _ = identified
            .wait_for(|_| {
                outcome = match self.shared.lock().nodes.get(&id) {
                    None => Err(format!("node {id} left the bus")),
                    Some(node) => match &node.identification {
                        Identification::Pending => return false,
                        Identification::Done => Ok(()),
                        Identification::Failed { error } => Err(error.clone()),
                    },
                };
                true
            })
            .await;
        outcome
    }

    /// Tells whoever follows the nodes that the gateway ended the motion
    /// of an axis of `node` ([`NodeEvent::MotionEnded`]).
    pub(crate) fn motion_ended(
        &self,
        node: NodeId,
        axis: u8,
        reason: &'static str,
        detail: String,
    ) {
        self.shared.emit(NodeEvent::MotionEnded {
            node,
            axis,
            reason,
            detail,
        });
    }

    /// What happens to the nodes from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<NodeEvent> {
        self.shared.events.subscribe()
    }

    /// What the bus's supervisor decides from now on, in order: every
    /// heartbeat heard, boot-up, loss and recovery (the network manager
    /// follows these instead of supervising on its own). The node events
    /// of [`subscribe`](Self::subscribe) are made from the same decisions.
    pub fn subscribe_supervision(&self) -> broadcast::Receiver<SupervisorEvent> {
        self.shared.supervision.subscribe()
    }

    /// Every download a node confirms from now on, through any of the
    /// gateway's channels (`ObjectWritten`).
    pub fn subscribe_writes(&self) -> broadcast::Receiver<ObjectWritten> {
        self.shared.writes.subscribe()
    }

    /// Probes node ids 1–127 with an SDO read of 0x1000,
    /// [`RegistryConfig::scan_concurrency`] at a time: known nodes through
    /// their own channel, unknown ids with
    /// [`RegistryConfig::probe_timeout`]. A node that answers is added (if
    /// new) and identified (if not yet); a known node without heartbeat
    /// that stays silent goes offline. Returns the node list once the
    /// identifications are done.
    ///
    /// Dropping the future leaves the probes under way to finish on their
    /// own (a transfer cut halfway would leave a node's channel busy).
    pub async fn scan(&self) -> Result<Vec<NodeInfo>, RegistryError> {
        let status = self.shared.bus.status();
        if !status.state.can_send() {
            return Err(RegistryError::Bus(BusError::NotUp {
                bus: self.bus_name().to_string(),
                state: status.state,
                reason: status.reason,
            }));
        }
        match self.shared.probe_all(NodeId::all().collect()).await {
            Some(SdoRequestError::Bus { error, .. }) => return Err(RegistryError::Bus(error)),
            Some(error) => return Err(RegistryError::Sdo(error)),
            None => {}
        }
        self.shared.settle().await;
        Ok(self.nodes())
    }

    /// Waits until no identification is under way (at most as long as the
    /// slowest one takes: each read ends with an answer or a timeout).
    pub async fn settle(&self) {
        self.shared.settle().await;
    }
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // Nothing panics while holding the lock; if something did, the
        // state is still a consistent set of nodes.
        self.state
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    fn emit(&self, event: NodeEvent) {
        // Nobody listening is fine.
        let _ = self.events.send(event);
    }

    async fn settle(&self) {
        let mut identified = self.identified.subscribe();
        // The sender lives in `self`: waiting cannot fail.
        let _ = identified
            .wait_for(|_| !self.lock().nodes.values().any(|node| node.identifying))
            .await;
    }

    /// A new SDO channel to node `id`, whose confirmed writes reach the
    /// followers of [`NodeRegistry::subscribe_writes`], and those of the
    /// producer heartbeat time [`Shared::heartbeat_written`].
    fn new_channel(self: &Arc<Self>, id: NodeId) -> SdoChannel {
        let shared = Arc::downgrade(self);
        let writes = self.writes.clone();
        let observer: super::sdo::WriteObserver = Arc::new(move |node, index, sub, data| {
            // Nobody following is fine.
            let _ = writes.send(ObjectWritten { node, index, sub });
            if index != PRODUCER_HEARTBEAT_TIME || sub != 0 {
                return;
            }
            let Some(ms) = unsigned(data).and_then(|ms| u16::try_from(ms).ok()) else {
                return;
            };
            if let Some(shared) = shared.upgrade() {
                shared.heartbeat_written(node, ms);
            }
        });
        SdoChannel::new(self.bus.clone(), id, self.config.sdo.clone()).with_observer(observer)
    }

    /// The node confirmed a write of `ms` into its 0x1017: it is
    /// supervised with that period from now on, at once (its next
    /// heartbeat is one new period away), rather than shown offline at
    /// every heartbeat until the slower period is learnt; 0 (no heartbeat):
    /// unsupervised, online from any frame it sends. Published as
    /// [`NodeEvent::HeartbeatWritten`], which the network manager follows.
    fn heartbeat_written(self: &Arc<Self>, id: NodeId, ms: u16) {
        {
            let mut state = self.lock();
            if !state.nodes.contains_key(&id) {
                return;
            }
            state
                .supervisor
                .heartbeat_written(id, ms, Instant::now().into_std());
            self.flush(&mut state);
        }
        self.rearm.notify_one();
    }

    /// Publishes what the supervisor decided, in order: as it is to the
    /// network manager, and as node events; and what follows for the
    /// registry (a node that booted is identified again, as is one whose
    /// identification failed while it was stopped).
    fn flush(self: &Arc<Self>, state: &mut State) {
        for event in state.supervisor.take_events() {
            // Nobody following is fine.
            let _ = self.supervision.send(event);
            match event {
                SupervisorEvent::Nmt { node, from, to } => {
                    self.emit(NodeEvent::NmtChanged { node, from, to });
                    let Some(known) = state.nodes.get_mut(&node) else {
                        continue;
                    };
                    // A node identified while stopped could not answer.
                    if from == Some(NmtState::Stopped)
                        && matches!(known.identification, Identification::Failed { .. })
                        && matches!(to, NmtState::PreOperational | NmtState::Operational)
                    {
                        self.start_identification(known);
                    }
                }
                SupervisorEvent::BootUp { node } => {
                    let assigned = state.assigned.get(&node).cloned();
                    if let Some(known) = state.nodes.get_mut(&node) {
                        known.forget_identity();
                        known.describe(&self.catalog, assigned.as_ref());
                        self.start_identification(known);
                    }
                }
                SupervisorEvent::Online { node } => self.emit(NodeEvent::Online { node }),
                SupervisorEvent::Offline { node, cause } => {
                    let reason = match cause {
                        OfflineCause::Lost(LostBy::Heartbeat { .. }) => {
                            OfflineReason::HeartbeatLost
                        }
                        OfflineCause::Lost(LostBy::Guarding { .. }) => OfflineReason::GuardingLost,
                        OfflineCause::BusDown => OfflineReason::BusDown,
                        OfflineCause::NoAnswer => OfflineReason::NoAnswer,
                    };
                    self.emit(NodeEvent::Offline { node, reason });
                }
                SupervisorEvent::HeartbeatWritten { node, heartbeat_ms } => {
                    self.emit(NodeEvent::HeartbeatWritten { node, heartbeat_ms });
                }
                SupervisorEvent::Heard { .. }
                | SupervisorEvent::Lost { .. }
                | SupervisorEvent::Recovered { .. } => {}
            }
        }
    }

    /// The node, added if it is new (the flag), with its [`NodeEvent::Appeared`].
    fn ensure_node<'a>(
        self: &Arc<Self>,
        state: &'a mut State,
        id: NodeId,
        now: Instant,
    ) -> (&'a mut Node, bool) {
        let mut new = false;
        let probing = state.probe_channels.get(&id).cloned();
        state.supervisor.watch(id, now.into_std());
        let node = state.nodes.entry(id).or_insert_with(|| {
            new = true;
            Node {
                id,
                channel: probing.unwrap_or_else(|| self.new_channel(id)),
                identity: None,
                device_type: None,
                name: None,
                profile: Profile::Generic,
                eds: None,
                eds_assigned: false,
                identification: Identification::Pending,
                generation: 0,
                identifying: false,
                emcy: VecDeque::new(),
            }
        });
        if new {
            node.describe(&self.catalog, state.assigned.get(&id));
            self.emit(NodeEvent::Appeared { node: id });
        }
        (node, new)
    }

    fn start_identification(self: &Arc<Self>, node: &mut Node) {
        node.generation += 1;
        node.identification = Identification::Pending;
        if !node.identifying {
            node.identifying = true;
            tokio::spawn(identify(self.clone(), node.id));
        }
    }

    /// Takes a frame of the bus; whether it may have moved the next
    /// supervision deadline (a heartbeat or an EMCY: a new node is watched).
    fn on_frame(self: &Arc<Self>, frame: &TimedFrame) -> bool {
        let Some((function, Some(id))) = Function::classify(frame.frame.id()) else {
            return false;
        };
        let now = Instant::now();
        let mut state = self.lock();
        match function {
            Function::Heartbeat if !frame.frame.is_remote() => {
                self.on_heartbeat(&mut state, id, frame, now);
                true
            }
            Function::Emcy => {
                self.on_emcy(&mut state, id, frame, now);
                true
            }
            Function::Tpdo(_) | Function::SdoTx => {
                if state.nodes.contains_key(&id) {
                    state.supervisor.heard(id, now.into_std());
                    self.flush(&mut state);
                }
                false
            }
            _ => false,
        }
    }

    fn on_heartbeat(
        self: &Arc<Self>,
        state: &mut State,
        id: NodeId,
        frame: &TimedFrame,
        now: Instant,
    ) {
        if let Err(error) = state.supervisor.on_frame(&frame.frame, now.into_std()) {
            tracing::debug!(bus = self.bus.name(), %error, "malformed heartbeat");
            return;
        }
        let (node, new) = self.ensure_node(state, id, now);
        if new {
            self.start_identification(node);
        }
        self.flush(state);
    }

    fn on_emcy(self: &Arc<Self>, state: &mut State, id: NodeId, frame: &TimedFrame, now: Instant) {
        let emcy = match Emcy::decode(&frame.frame) {
            Ok((_, emcy)) => emcy,
            Err(error) => {
                tracing::debug!(bus = self.bus.name(), %error, "malformed EMCY");
                return;
            }
        };
        let mut record = EmcyRecord::new(&emcy, frame.timestamp);
        let capacity = self.config.emcy_history;
        let (node, new) = self.ensure_node(state, id, now);
        record.axis = node.profile.emcy_axis(&emcy.manufacturer);
        if new {
            self.start_identification(node);
        }
        if capacity > 0 {
            if node.emcy.len() >= capacity {
                node.emcy.pop_front();
            }
            node.emcy.push_back(record.clone());
        }
        state.supervisor.heard(id, now.into_std());
        self.flush(state);
        self.emit(NodeEvent::Emcy {
            node: id,
            emcy: record,
        });
    }

    /// The supervision deadlines due: nodes lost; the guarding requests to
    /// send.
    fn poll_supervision(self: &Arc<Self>) -> Vec<crate::can::Frame> {
        let mut state = self.lock();
        let requests = state.supervisor.poll(Instant::now().into_std());
        self.flush(&mut state);
        requests
    }

    fn on_bus_status(self: &Arc<Self>, up: bool) {
        let recheck: Vec<NodeId> = {
            let mut state = self.lock();
            if state.supervisor.is_bus_up() == up {
                return;
            }
            state.supervisor.bus_up(up);
            self.flush(&mut state);
            if !up {
                return;
            }
            // Nodes with a heartbeat come back with it; the others are
            // asked.
            state
                .nodes
                .keys()
                .copied()
                .filter(|&id| {
                    !state.supervisor.node(id).is_some_and(|supervision| {
                        supervision.heartbeat.is_some() || supervision.guarded
                    })
                })
                .collect()
        };
        if !recheck.is_empty() {
            let shared = self.clone();
            tokio::spawn(async move {
                shared.probe_all(recheck).await;
            });
        }
    }

    /// Probes `ids`, [`RegistryConfig::scan_concurrency`] at a time, in
    /// tasks that finish even if the caller stops waiting. The first bus
    /// failure stops the probing and is returned.
    async fn probe_all(self: &Arc<Self>, ids: Vec<NodeId>) -> Option<SdoRequestError> {
        let queue = Arc::new(Mutex::new(ids.into_iter()));
        let stop = Arc::new(AtomicBool::new(false));
        let workers: Vec<_> = (0..self.config.scan_concurrency.max(1))
            .map(|_| {
                let (shared, queue, stop) = (self.clone(), queue.clone(), stop.clone());
                tokio::spawn(async move {
                    while !stop.load(Ordering::Relaxed) {
                        let next = queue
                            .lock()
                            .unwrap_or_else(|poisoned| poisoned.into_inner())
                            .next();
                        let id = next?;
                        if let Probe::BusFailed(error) = shared.probe(id).await {
                            stop.store(true, Ordering::Relaxed);
                            return Some(error);
                        }
                    }
                    None
                })
            })
            .collect();
        let mut failure = None;
        for worker in workers {
            if let Ok(Some(error)) = worker.await {
                failure.get_or_insert(error);
            }
        }
        failure
    }

    async fn probe(self: &Arc<Self>, id: NodeId) -> Probe {
        let (known, channel) = {
            let mut state = self.lock();
            match state.nodes.get(&id) {
                Some(node) => (Some(node.channel.clone()), node.channel.clone()),
                None => {
                    // Under the state lock: a node added from now on waits
                    // for this probe before it is identified, and takes
                    // this probe's channel as its own.
                    self.probing.send_modify(|probing| {
                        probing.insert(id);
                    });
                    let channel = self.new_channel(id);
                    state.probe_channels.insert(id, channel.clone());
                    (None, channel)
                }
            }
        };
        let result = match &known {
            Some(channel) => channel.upload(DEVICE_TYPE, 0).await,
            None => {
                let config = ClientConfig {
                    timeout: self.config.probe_timeout,
                    ..self.config.sdo.clone()
                };
                channel.upload_with(DEVICE_TYPE, 0, Some(&config)).await
            }
        };
        let probe = Probe::of(&result);
        let now = Instant::now();
        let mut state = self.lock();
        match probe {
            Probe::Answered => {
                let (node, new) = self.ensure_node(&mut state, id, now);
                if new || matches!(node.identification, Identification::Failed { .. }) {
                    self.start_identification(node);
                }
                state.supervisor.heard(id, now.into_std());
            }
            Probe::Silent => state.supervisor.no_answer(id),
            Probe::BusFailed(_) => {}
        }
        self.flush(&mut state);
        if known.is_none() {
            state.probe_channels.remove(&id);
            self.probing.send_modify(|probing| {
                probing.remove(&id);
            });
        }
        probe
    }

    /// Whether the node's identification that started at `generation` is
    /// still the one wanted.
    fn is_current(&self, id: NodeId, generation: u64) -> bool {
        self.lock()
            .nodes
            .get(&id)
            .is_some_and(|node| node.generation == generation)
    }

    /// Reads an object for the identification: `Ok(None)` when the node
    /// refused it, retried after a timeout.
    async fn read(
        &self,
        channel: &SdoChannel,
        generation: u64,
        index: u16,
        sub: u8,
    ) -> Result<Option<Vec<u8>>, Abandon> {
        let mut retries = self.config.read_retries;
        loop {
            if !self.is_current(channel.node(), generation) {
                return Err(Abandon::Stale);
            }
            match channel.upload(index, sub).await {
                Ok(data) => return Ok(Some(data)),
                Err(error) if error.device_abort().is_some() => return Ok(None),
                Err(SdoRequestError::Sdo {
                    error: SdoError::Timeout,
                    ..
                }) if retries > 0 => retries -= 1,
                Err(error) => return Err(Abandon::Failed(error)),
            }
        }
    }

    async fn read_identity(
        &self,
        channel: &SdoChannel,
        generation: u64,
    ) -> Result<Identified, Abandon> {
        let device_type = self
            .read(channel, generation, DEVICE_TYPE, 0)
            .await?
            .and_then(|data| unsigned(&data));
        let mut identity_subs = [None; 4];
        for (sub, value) in (1u8..).zip(identity_subs.iter_mut()) {
            *value = self
                .read(channel, generation, IDENTITY, sub)
                .await?
                .and_then(|data| unsigned(&data));
        }
        let [vendor, product_code, revision, serial] = identity_subs;
        let name = self
            .read(channel, generation, DEVICE_NAME, 0)
            .await?
            .map(|data| visible_string(&data));
        let heartbeat_ms = self
            .read(channel, generation, PRODUCER_HEARTBEAT_TIME, 0)
            .await?
            .and_then(|data| unsigned(&data))
            .and_then(|ms| u16::try_from(ms).ok());
        Ok(Identified {
            device_type,
            identity: vendor.map(|vendor_id| Identity {
                vendor_id,
                product_code,
                revision,
                serial,
            }),
            name,
            heartbeat_ms,
        })
    }

    fn apply_identity(
        self: &Arc<Self>,
        state: &mut State,
        id: NodeId,
        outcome: Result<Identified, SdoRequestError>,
    ) {
        let State {
            nodes,
            supervisor,
            assigned,
            ..
        } = state;
        let Some(node) = nodes.get_mut(&id) else {
            return;
        };
        match outcome {
            Ok(found) => {
                node.device_type = found.device_type;
                node.identity = found.identity;
                node.name = found.name;
                node.identification = Identification::Done;
                node.describe(&self.catalog, assigned.get(&id));
                // The boot-up message is sent on entering pre-operational,
                // and the node answered SDO, which it does not when stopped.
                supervisor.answered(id);
                if let Some(ms) = found.heartbeat_ms {
                    supervisor.heartbeat_read(id, ms, Instant::now().into_std());
                }
                let identified = NodeEvent::Identified {
                    node: id,
                    profile: node.profile,
                    eds: node.eds.as_ref().map(|entry| entry.name.clone()),
                };
                self.flush(state);
                self.emit(identified);
            }
            Err(error) => {
                node.forget_identity();
                node.describe(&self.catalog, assigned.get(&id));
                let error = error.to_string();
                node.identification = Identification::Failed {
                    error: error.clone(),
                };
                self.emit(NodeEvent::IdentificationFailed { node: id, error });
            }
        }
    }
}

/// Identifies a node, again while it boots again meanwhile.
async fn identify(shared: Arc<Shared>, id: NodeId) {
    let mut probing = shared.probing.subscribe();
    // The sender lives in `shared`: waiting cannot fail.
    let _ = probing.wait_for(|probing| !probing.contains(&id)).await;
    loop {
        let Some((channel, generation)) = shared
            .lock()
            .nodes
            .get(&id)
            .map(|node| (node.channel.clone(), node.generation))
        else {
            return;
        };
        let outcome = match shared.read_identity(&channel, generation).await {
            Ok(found) => Ok(found),
            Err(Abandon::Failed(error)) => Err(error),
            Err(Abandon::Stale) => continue,
        };
        {
            let mut state = shared.lock();
            let Some(node) = state.nodes.get_mut(&id) else {
                return;
            };
            if node.generation != generation {
                continue;
            }
            node.identifying = false;
            shared.apply_identity(&mut state, id, outcome);
        }
        shared.rearm.notify_one();
        shared.identified.send_modify(|count| *count += 1);
        return;
    }
}

/// An unsigned integer of 1 to 4 bytes, little-endian.
fn unsigned(data: &[u8]) -> Option<u32> {
    if data.is_empty() || data.len() > 4 {
        return None;
    }
    let mut bytes = [0u8; 4];
    bytes[..data.len()].copy_from_slice(data);
    Some(u32::from_le_bytes(bytes))
}

/// A VISIBLE_STRING as text: up to the first NUL (devices pad with them),
/// bytes outside ASCII replaced, bounded in length.
fn visible_string(data: &[u8]) -> String {
    let end = data.iter().position(|&b| b == 0).unwrap_or(data.len());
    let text = String::from_utf8_lossy(&data[..end.min(MAX_NAME_LEN)]);
    text.trim_end().to_string()
}

/// Reads the bus until it closes or the registry is dropped.
async fn run(
    shared: Arc<Shared>,
    mut frames: FrameReceiver,
    mut status: watch::Receiver<crate::can::BusStatus>,
) {
    let mut status_open = true;
    // One timer for the loop, moved when the next heartbeat timeout moves,
    // which only heartbeats, timeouts and rearming do: PDOs and SDOs (most
    // of a busy bus) neither make a timer nor scan the watched nodes.
    let mut deadline = shared.lock().supervisor.deadline().map(Instant::from_std);
    let timer = tokio::time::sleep_until(deadline.unwrap_or_else(Instant::now));
    tokio::pin!(timer);
    loop {
        tokio::select! {
            received = frames.recv() => {
                let mut supervision = match received {
                    Ok(frame) => shared.on_frame(&frame),
                    Err(RecvError::Lagged(lost)) => {
                        tracing::warn!(bus = shared.bus.name(), lost, "node registry fell behind the bus");
                        false
                    }
                    Err(RecvError::Closed) => {
                        shared.on_bus_status(false);
                        return;
                    }
                };
                // What else is queued goes in the same turn.
                for _ in 0..FRAME_BATCH {
                    match frames.try_recv() {
                        Ok(Some(frame)) => supervision |= shared.on_frame(&frame),
                        Ok(None) => break,
                        Err(RecvError::Lagged(lost)) => {
                            tracing::warn!(bus = shared.bus.name(), lost, "node registry fell behind the bus");
                        }
                        Err(RecvError::Closed) => {
                            shared.on_bus_status(false);
                            return;
                        }
                    }
                }
                if !supervision {
                    continue;
                }
            },
            changed = status.changed(), if status_open => match changed {
                Ok(()) => {
                    let up = status.borrow_and_update().state.can_send();
                    shared.on_bus_status(up);
                }
                Err(_) => status_open = false,
            },
            () = &mut timer, if deadline.is_some() => {
                for request in shared.poll_supervision() {
                    // A bus that is down is reported by the bus.
                    let _ = shared.bus.send(request).await;
                }
            }
            () = shared.rearm.notified() => {}
        }
        deadline = shared.lock().supervisor.deadline().map(Instant::from_std);
        if let Some(at) = deadline {
            timer.as_mut().reset(at);
        }
    }
}

/// Frames the registry takes in one turn of its loop beyond the one it
/// waited for, before it looks at its other inputs again.
const FRAME_BATCH: usize = 256;
