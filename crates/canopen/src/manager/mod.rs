//! The network manager of CiA 302-2 (network management of a CANopen
//! manager), without I/O: the expected nodes of a bus (the machine), the
//! boot-up of each slave, the error control the manager sets up and
//! supervises, and the manager's own heartbeat.
//!
//! - **Boot slave** (CiA 302-2 §5, "boot slave process"), run for a node at
//!   every boot-up message, when it is found present, when it comes back
//!   after being lost before it was ever configured, and on request:
//!   the gateway's identification of the node ([`Action::Identify`]: what
//!   it is, hence its profile; a failure is retried like any other step)
//!   → identity check against 0x1018 sub
//!   1–4 (each key the description gives must match; a mismatch or an
//!   entry the node refuses is `wrong_identity`, and the node is neither
//!   configured nor started) → configuration download (the DCF's
//!   `ParameterValue` entries in file order, each failure naming the entry
//!   and the abort) → error control (§5, "start error control service"):
//!   the node's producer heartbeat time into 0x1017; where 0x1017 is not
//!   writable, node guarding with 0x100C (guard time) and 0x100D (life time
//!   factor) driven by the manager; the manager's heartbeat into 0x1016 sub 1
//!   (consumer time 3 × the manager's period) where the node has a 0x1016
//!   → NMT start (§5, "start slave"), if the description says so.
//! - **Resynchronisation**: a node heard again after a loss whose last
//!   boot-up ended well (and that sent no boot-up message since) is not
//!   configured again: the gateway's identification (as at a boot-up),
//!   its identity (0x1018), its producer heartbeat time
//!   (0x1017) and the 0x1016 entry watching the manager are read and
//!   compared with what its boot-up left; all as they were, it is ready
//!   again with nothing written (an NMT start only if it is not
//!   operational), so a drive moving through a heartbeat glitch keeps its
//!   mode. Anything else (a value that differs or cannot be read) means it
//!   restarted unheard: it is booted in full.
//! - A step that fails is retried with a backoff (from [`ManagerConfig::retry_min`],
//!   doubling up to [`ManagerConfig::retry_max`]) and reported with the
//!   step and the reason; a node with the wrong identity is not retried
//!   until it boots again or someone asks.
//! - **Error control** (CiA 301 §7.2.8.3.2, CiA 302-2 §7): every booted
//!   node is supervised by its heartbeat or by node guarding; where
//!   neither could be set up the node says `supervision: none` and why.
//!   The timing is the bus's one [`Supervisor`]'s, not the manager's: it
//!   hears the frames, times the heartbeats ([`ConsumerFactor`] periods,
//!   3 by default) and does the
//!   guarding the manager hands it ([`Action::Guard`]), and the manager
//!   follows its events ([`Manager::on_supervision`]). A ready node lost is
//!   `offline`; a node heard again after it was lost is booted again by
//!   itself. A producer heartbeat time written into a node's 0x1017 by
//!   someone else ([`SupervisorEvent::HeartbeatWritten`]) becomes the
//!   node's: its supervision follows at once, and its next boot-up writes
//!   it.
//! - **Machine state**: `ready` when every mandatory node is booted
//!   (identified by the gateway included), supervised and in the NMT
//!   state it should have; `booting` while a
//!   mandatory node is on its way there (or the first scan is under way);
//!   `degraded` when a mandatory node is missing, lost or failed; `down`
//!   when no mandatory node is ready and at least one is expected (or
//!   the bus is down). Without descriptions the nodes found are the
//!   machine: `booting` while one of them is on its way.
//!
//! Without any description every node found is booted as an unexpected,
//! non-mandatory node with the defaults ([`NodeDescription::default_for`]).
//! With descriptions, a node found that is not described is `unexpected`
//! and left alone.
//!
//! Like the SDO client, the manager takes the current time and what
//! happened in ([`Manager::on_supervision`], [`Manager::on_sdo`],
//! [`Manager::node_found`], ...) and gives [`Action`]s out
//! ([`Manager::poll`]) with a deadline: SDO requests (one at a time per
//! node), NMT commands and frames (its heartbeat), guarding to hand to the
//! supervisor. The gateway carries them out.

use std::collections::BTreeMap;
use std::fmt;
use std::time::{Duration, Instant};

use super::cob::NodeId;
use super::heartbeat::HeartbeatProducer;
use super::nmt::{NmtCommand, NmtState};
use super::sdo::AbortCode;
use crate::can::Frame;

pub mod supervisor;
#[cfg(test)]
mod tests;

pub use supervisor::{
    ConsumerFactor, LostBy, NodeSupervision, OfflineCause, Supervisor, SupervisorEvent,
};

/// Guard time object (ms).
pub const GUARD_TIME: u16 = 0x100C;
/// Life time factor object.
pub const LIFE_TIME_FACTOR: u16 = 0x100D;
/// Consumer heartbeat time array.
pub const CONSUMER_HEARTBEAT_TIME: u16 = 0x1016;
/// Producer heartbeat time (ms).
pub const PRODUCER_HEARTBEAT_TIME: u16 = 0x1017;
/// Identity object: sub 1 vendor, 2 product code, 3 revision, 4 serial.
pub const IDENTITY: u16 = 0x1018;
/// The life time factor the manager writes when it guards a node.
pub const LIFE_TIME_FACTOR_DEFAULT: u8 = 3;
/// The producer heartbeat time of a node without description, ms.
pub const DEFAULT_HEARTBEAT_MS: u16 = 500;
/// The manager's node id by default.
pub const DEFAULT_MANAGER_NODE_ID: u8 = 127;
/// The manager's heartbeat period by default, ms.
pub const DEFAULT_MANAGER_HEARTBEAT_MS: u16 = 100;

/// The identity checks of a description, against 0x1018.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct IdentityCheck {
    pub vendor_id: Option<u32>,
    pub product_code: Option<u32>,
    pub revision_min: Option<u32>,
    pub revision_max: Option<u32>,
    pub serial: Option<u32>,
}

impl IdentityCheck {
    /// The 0x1018 sub-indices that must be read, in order.
    fn subs(&self) -> Vec<u8> {
        let mut subs = Vec::new();
        if self.vendor_id.is_some() {
            subs.push(1);
        }
        if self.product_code.is_some() {
            subs.push(2);
        }
        if self.revision_min.is_some() || self.revision_max.is_some() {
            subs.push(3);
        }
        if self.serial.is_some() {
            subs.push(4);
        }
        subs
    }

    /// Why `value` read from 0x1018 `sub` does not match; `None` when it does.
    fn mismatch(&self, sub: u8, value: u32) -> Option<String> {
        let expect = |name: &str, want: Option<u32>| {
            want.filter(|want| *want != value)
                .map(|want| format!("{name} is 0x{value:08X}, expected 0x{want:08X}"))
        };
        match sub {
            1 => expect("vendor_id (0x1018 sub 1)", self.vendor_id),
            2 => expect("product_code (0x1018 sub 2)", self.product_code),
            3 => {
                let low = self.revision_min.unwrap_or(0);
                let high = self.revision_max.unwrap_or(u32::MAX);
                (!(low..=high).contains(&value)).then(|| {
                    format!(
                        "revision (0x1018 sub 3) is 0x{value:08X}, expected 0x{low:08X} to 0x{high:08X}"
                    )
                })
            }
            4 => expect("serial (0x1018 sub 4)", self.serial),
            _ => None,
        }
    }
}

/// One value of the configuration download.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigWrite {
    pub index: u16,
    pub sub: u8,
    pub data: Vec<u8>,
    /// How a failure names it: the file, the entry and its name.
    pub label: String,
}

/// What the machine description says of one node (`[[nodes]]`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeDescription {
    pub id: NodeId,
    pub name: Option<String>,
    pub identity: IdentityCheck,
    /// The machine is not ready without it.
    pub mandatory: bool,
    /// The EDS that describes the node, when its identity cannot pick one
    /// (kept here and shown; the gateway assigns it).
    pub eds: Option<String>,
    /// The DCF it came from, for display.
    pub dcf: Option<String>,
    /// The configuration download, in order.
    pub config: Vec<ConfigWrite>,
    /// The producer heartbeat time written to 0x1017 (or the guard time of
    /// node guarding), ms; 0 leaves the node unsupervised (said so).
    pub heartbeat_ms: u16,
    /// `Some(true)`: 0x1016 must take the manager's heartbeat; `None`:
    /// where it exists; `Some(false)`: not written.
    pub consume_manager_heartbeat: Option<bool>,
    /// NMT start after a good boot-up.
    pub start: bool,
    /// Described in the configuration (`false`: booted with the defaults
    /// because there is no description at all).
    pub expected: bool,
}

impl NodeDescription {
    /// An expected node with the defaults: mandatory, heartbeat 500 ms,
    /// the manager's heartbeat consumed where 0x1016 exists, started.
    pub fn new(id: NodeId) -> Self {
        Self {
            id,
            name: None,
            identity: IdentityCheck::default(),
            mandatory: true,
            eds: None,
            dcf: None,
            config: Vec::new(),
            heartbeat_ms: DEFAULT_HEARTBEAT_MS,
            consume_manager_heartbeat: None,
            start: true,
            expected: true,
        }
    }

    /// A node found on a bus without description: unexpected, not
    /// mandatory, booted with the defaults.
    pub fn default_for(id: NodeId) -> Self {
        Self {
            mandatory: false,
            expected: false,
            ..Self::new(id)
        }
    }
}

/// The manager's settings of one bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ManagerConfig {
    /// The manager's own node id (its heartbeat is on 0x700 + id).
    pub node_id: NodeId,
    /// Its heartbeat period, ms; 0: none.
    pub heartbeat_ms: u16,
    /// The first retry of a failed boot-up comes this long after it.
    pub retry_min: Duration,
    /// Retries back off (doubling) up to this.
    pub retry_max: Duration,
    /// SDO requests of boot-ups in flight at once on the bus (a node has
    /// at most one): a whole bus booting at once does not flood it, and
    /// every transfer is answered well within its timeout.
    pub max_requests: usize,
    /// Heartbeat periods a node may be silent before it is lost
    /// (`heartbeat_consumer_factor`): the supervisor's, named in the
    /// reason of a loss.
    pub consumer_factor: ConsumerFactor,
}

impl Default for ManagerConfig {
    fn default() -> Self {
        Self {
            node_id: NodeId::new(DEFAULT_MANAGER_NODE_ID).expect("127 is a node id"),
            heartbeat_ms: DEFAULT_MANAGER_HEARTBEAT_MS,
            retry_min: Duration::from_millis(200),
            retry_max: Duration::from_secs(10),
            max_requests: 16,
            consumer_factor: ConsumerFactor::DEFAULT,
        }
    }
}

/// The step of a node's boot-up (`step` of the API).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Step {
    /// Waiting to be found (or for the next try).
    Waiting,
    /// Reading 0x1018.
    Identity,
    /// Writing the DCF's values.
    Configuration,
    /// Setting up heartbeat or guarding, and the manager's heartbeat.
    ErrorControl,
    /// NMT start.
    Start,
    /// Booted; supervised from now on.
    Supervised,
}

impl Step {
    pub fn name(self) -> &'static str {
        match self {
            Self::Waiting => "waiting",
            Self::Identity => "identity",
            Self::Configuration => "configuration",
            Self::ErrorControl => "error_control",
            Self::Start => "start",
            Self::Supervised => "supervised",
        }
    }
}

/// Where a node of the machine stands (`state` of a node in the API).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum NodeState {
    Ready,
    Booting,
    Missing,
    WrongIdentity,
    ConfigFailed,
    Offline,
    Unexpected,
}

impl NodeState {
    pub fn name(self) -> &'static str {
        match self {
            Self::Ready => "ready",
            Self::Booting => "booting",
            Self::Missing => "missing",
            Self::WrongIdentity => "wrong_identity",
            Self::ConfigFailed => "config_failed",
            Self::Offline => "offline",
            Self::Unexpected => "unexpected",
        }
    }
}

/// How the manager supervises a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Supervision {
    Heartbeat,
    Guarding,
    None,
}

/// The state of the whole machine of a bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MachineState {
    Ready,
    Booting,
    Degraded,
    Down,
}

impl MachineState {
    pub fn name(self) -> &'static str {
        match self {
            Self::Ready => "ready",
            Self::Booting => "booting",
            Self::Degraded => "degraded",
            Self::Down => "down",
        }
    }

    /// The value of `candeck_machine_state`: 0 down, 1 degraded, 2
    /// booting, 3 ready.
    pub fn metric(self) -> u8 {
        match self {
            Self::Down => 0,
            Self::Degraded => 1,
            Self::Booting => 2,
            Self::Ready => 3,
        }
    }
}

/// How an SDO request of the manager ended. What the device said (an
/// abort) is kept apart from no answer (timeout, bus).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoOutcome {
    /// Read: the value bytes; written: empty.
    Done(Vec<u8>),
    Aborted(AbortCode),
    /// No answer, or the bus failed; the text says which.
    Failed(String),
}

/// What the manager asks the gateway to do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Action {
    /// Read an object of `node`; answer with [`Manager::on_sdo`].
    Read { node: NodeId, index: u16, sub: u8 },
    /// Write an object of `node`; answer with [`Manager::on_sdo`].
    Write {
        node: NodeId,
        index: u16,
        sub: u8,
        data: Vec<u8>,
    },
    /// Send this frame (an NMT command, the manager's heartbeat).
    Send(Frame),
    /// Guard `node` from now on ([`Supervisor::guard`]): the 0x100C and
    /// 0x100D it was written.
    Guard {
        node: NodeId,
        guard_time_ms: u16,
        life_time_factor: u8,
    },
    /// Stop guarding `node` ([`Supervisor::unguard`]).
    Unguard { node: NodeId },
    /// Wait until the gateway knows what `node` is since its last boot-up
    /// message (its own reading of 0x1000 and 0x1018, which gives the
    /// node its profile and EDS), starting that reading again if it
    /// failed. Answer with [`Manager::on_sdo`]: `Done` once known,
    /// `Failed` with why not. Every boot-up and resynchronisation begins
    /// with it, so that a node is never `ready` while the gateway still
    /// takes it for a generic one.
    Identify { node: NodeId },
    /// The configuration download is about to write `node`'s motion
    /// objects (a drive's profile area, 0x6000–0x9FFF: its modes, its
    /// targets): stop every axis of it that is enabled first, and tell
    /// whoever moved it. Answer with [`Manager::on_sdo`]: `Done` once
    /// nothing of it moves, `Failed` with why not (the download waits and
    /// is retried).
    StopMotion { node: NodeId },
}

/// What happened, for the audit log, the stream and the log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ManagerEvent {
    /// A boot-up began (`why`: boot-up message, found, back, request).
    BootStarted { node: NodeId, why: String },
    /// A step began.
    Step { node: NodeId, step: Step },
    /// The boot-up ended well: the node is supervised (and started).
    Booted { node: NodeId },
    /// The boot-up failed at `step`; retried after `retry` (`None`: not
    /// retried until the node boots again or is asked to).
    Failed {
        node: NodeId,
        step: Step,
        reason: String,
        retry: Option<Duration>,
    },
    /// A node heard again after it was lost is checked, not configured
    /// again (`why`: heard again, retry).
    ResyncStarted { node: NodeId, why: String },
    /// The resynchronisation found the node as its boot-up left it: ready
    /// again, nothing written.
    Resynchronised { node: NodeId },
    /// Supervision lost the node.
    Lost { node: NodeId, reason: String },
    /// The machine state changed.
    Machine {
        from: MachineState,
        to: MachineState,
    },
}

/// One node of the machine, as the API shows it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct NodeStatus {
    pub id: u8,
    pub name: Option<String>,
    pub mandatory: bool,
    pub expected: bool,
    pub state: NodeState,
    pub step: Step,
    pub reason: Option<String>,
    pub supervision: Supervision,
    /// The node's producer heartbeat time, ms: its description's, or what
    /// was last written to its 0x1017 through the gateway (its heartbeat
    /// consumer times out after `heartbeat_consumer_factor` × this); 0: no
    /// heartbeat.
    pub heartbeat_ms: u16,
    /// The last NMT state the node reported; `"unknown"` before any.
    pub nmt: String,
    /// The EDS the description names.
    pub eds: Option<String>,
    /// The DCF the description names.
    pub dcf: Option<String>,
    /// Boot-ups begun and completed.
    pub boots: u64,
    pub boots_ok: u64,
}

/// The machine of a bus, as `GET /buses/{bus}/machine` shows it.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct MachineStatus {
    pub state: MachineState,
    pub reasons: Vec<String>,
    pub nodes: Vec<NodeStatus>,
}

/// An operation of a boot-up, one SDO request or one frame.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Op {
    /// NMT enter pre-operational, first, for a node that reports itself
    /// stopped: a stopped node does no SDO (CiA 301 §7.3.2.2), so its
    /// boot-up could not read or write anything.
    EnterPreOperational,
    /// The gateway's identification of the node ([`Action::Identify`]).
    Identify,
    CheckIdentity(u8),
    /// Before the first motion object of the configuration: the node's
    /// enabled axes stopped ([`Action::StopMotion`]).
    StopMotion,
    Configure(usize),
    SetHeartbeat,
    SetGuardTime,
    SetLifeFactor,
    /// Reads 0x1016 sub 0: how many consumer entries the node has.
    CountConsumers,
    /// Reads 0x1016 sub `sub` of `count`, looking for the entry that
    /// already watches the manager, else the first `free` one: the others
    /// watch other nodes (a drive following its neighbour) and are kept.
    FindConsumer {
        sub: u8,
        count: u8,
        free: Option<u8>,
    },
    /// Writes the manager's heartbeat into 0x1016 sub `.0`.
    ConsumeManager(u8),
    Start,
    /// Resynchronisation after a loss: reads 0x1018 sub `.0`, compared
    /// with the description and with what the node said before.
    VerifyIdentity(u8),
    /// Resynchronisation: reads 0x1017, compared with what the boot-up
    /// wrote (a node that restarted has its stored value back).
    VerifyHeartbeat,
    /// Resynchronisation: reads 0x1016 sub `.0`, where the boot-up wrote
    /// the manager's heartbeat.
    VerifyConsumer(u8),
    /// Resynchronisation: NMT start, only if the node is not operational.
    StartIfNeeded,
}

impl Op {
    /// The object a resynchronisation reads (index, sub).
    fn object(&self) -> (u16, u8) {
        match *self {
            Self::VerifyIdentity(sub) => (IDENTITY, sub),
            Self::VerifyConsumer(sub) => (CONSUMER_HEARTBEAT_TIME, sub),
            _ => (PRODUCER_HEARTBEAT_TIME, 0),
        }
    }

    fn step(&self) -> Step {
        match self {
            // Reaching the node is the first thing its identity check needs.
            Self::EnterPreOperational
            | Self::Identify
            | Self::CheckIdentity(_)
            | Self::VerifyIdentity(_) => Step::Identity,
            Self::Configure(_) | Self::StopMotion => Step::Configuration,
            Self::SetHeartbeat
            | Self::SetGuardTime
            | Self::SetLifeFactor
            | Self::CountConsumers
            | Self::FindConsumer { .. }
            | Self::ConsumeManager(_)
            | Self::VerifyHeartbeat
            | Self::VerifyConsumer(_) => Step::ErrorControl,
            Self::Start | Self::StartIfNeeded => Step::Start,
        }
    }
}

#[derive(Debug)]
struct Node {
    description: NodeDescription,
    /// Managed: booted by the manager (expected, or no description at all).
    managed: bool,
    state: NodeState,
    step: Step,
    reason: Option<String>,
    supervision: Supervision,
    /// Why the supervision is `none`.
    supervision_reason: Option<String>,
    /// The operations still to do in this boot-up, front first.
    ops: std::collections::VecDeque<Op>,
    /// The SDO request sent, waiting for [`Manager::on_sdo`].
    in_flight: Option<Op>,
    /// The request in flight belongs to a boot-up that was started again
    /// meanwhile: its answer is dropped, and the new boot-up waits for it
    /// (one SDO transfer at a time per node).
    stale: bool,
    /// A try is due at this time (backoff, or the first one).
    retry_at: Option<Instant>,
    backoff: Duration,
    /// The node answered an SDO request in this boot (to tell `missing`
    /// from a failure halfway).
    answered: bool,
    /// The supervisor guards the node for the manager.
    guarded: bool,
    /// The last NMT state the supervisor reported.
    nmt: Option<NmtState>,
    /// The supervisor reported it lost, and not heard since.
    lost: bool,
    /// Heard at least once (boot-up, heartbeat, found).
    present: bool,
    /// 0x1017 could be written: heartbeat supervision.
    heartbeat_set: bool,
    /// Its last boot-up ended well and no boot-up message came since: its
    /// configuration is in place, and a loss is followed by a
    /// resynchronisation, not a new configuration download.
    configured: bool,
    /// The run under way (or retried) is a resynchronisation.
    resync: bool,
    /// What the node answered for 0x1018, by sub-index, since its last
    /// boot-up message.
    identity: BTreeMap<u8, u32>,
    /// The 0x1016 entry that carries the manager's heartbeat: its sub and
    /// the value written.
    consumer: Option<(u8, u32)>,
    boots: u64,
    boots_ok: u64,
}

impl Node {
    fn new(description: NodeDescription, managed: bool) -> Self {
        Self {
            state: if managed {
                NodeState::Missing
            } else {
                NodeState::Unexpected
            },
            description,
            managed,
            step: Step::Waiting,
            reason: None,
            supervision: Supervision::None,
            supervision_reason: Some("not booted yet".into()),
            ops: Default::default(),
            in_flight: None,
            stale: false,
            retry_at: None,
            backoff: Duration::ZERO,
            answered: false,
            guarded: false,
            nmt: None,
            lost: false,
            present: false,
            heartbeat_set: false,
            configured: false,
            resync: false,
            identity: BTreeMap::new(),
            consumer: None,
            boots: 0,
            boots_ok: 0,
        }
    }
}

impl Node {
    /// No boot-up under way, and none due: a retry waits for its time (a
    /// node heard meanwhile, each heartbeat of a stopped node, does not cut
    /// the back-off short).
    fn idle(&self) -> bool {
        self.in_flight.is_none() && self.ops.is_empty() && self.retry_at.is_none()
    }

    /// The NMT state the node should be in once booted.
    fn wanted_nmt(&self) -> NmtState {
        if self.description.start {
            NmtState::Operational
        } else {
            NmtState::PreOperational
        }
    }

    /// Booted and supervised, but the node has not (yet) confirmed the NMT
    /// state it should have: not `ready` (docs/network-manager.md), still
    /// on its way, at the start step.
    fn unconfirmed(&self) -> bool {
        self.state == NodeState::Ready
            && self.supervision != Supervision::None
            && self.nmt != Some(self.wanted_nmt())
    }

    /// The state the API shows: `ready` only once the node confirmed it.
    fn shown_state(&self) -> NodeState {
        if self.unconfirmed() {
            NodeState::Booting
        } else {
            self.state
        }
    }

    /// The reason the API shows for the node's state.
    fn shown_reason(&self) -> Option<String> {
        if self.unconfirmed() {
            return Some(format!(
                "the node reports {}, not yet {}",
                self.nmt.map_or("unknown", NmtState::name),
                self.wanted_nmt().name()
            ));
        }
        match self.state {
            NodeState::Ready if self.supervision == Supervision::None => {
                self.supervision_reason.clone()
            }
            NodeState::Unexpected => Some("present, but not in the machine description".into()),
            NodeState::Missing if self.reason.is_none() => Some("not found on the bus".into()),
            _ => self.reason.clone(),
        }
    }
}

/// The network manager of one bus. See the module documentation.
#[derive(Debug)]
pub struct Manager {
    config: ManagerConfig,
    /// Some nodes are described: the others are unexpected.
    described: bool,
    nodes: BTreeMap<NodeId, Node>,
    producer: HeartbeatProducer,
    /// The first scan is over: expected nodes not found are missing.
    scanned: bool,
    bus_up: bool,
    machine: MachineState,
    events: Vec<ManagerEvent>,
    /// Frames to send at the next poll (NMT commands).
    outbox: Vec<Action>,
    /// A device was heard or found at the manager's own node-ID: it is not
    /// supervised, and whoever consumes the manager's heartbeat may take
    /// its for the gateway's. The machine is not ready while it is there.
    own_id_taken: bool,
}

impl Manager {
    /// The manager of a bus with these descriptions (none: every node
    /// found is booted with the defaults), its heartbeat starting at `now`.
    pub fn new(config: ManagerConfig, descriptions: Vec<NodeDescription>, now: Instant) -> Self {
        let mut producer = HeartbeatProducer::new(config.node_id);
        producer.set_period_ms(config.heartbeat_ms, now);
        let described = !descriptions.is_empty();
        let nodes = descriptions
            .into_iter()
            .map(|description| (description.id, Node::new(description, true)))
            .collect();
        let mut manager = Self {
            config,
            described,
            nodes,
            producer,
            scanned: false,
            bus_up: true,
            machine: MachineState::Booting,
            events: Vec::new(),
            outbox: Vec::new(),
            own_id_taken: false,
        };
        manager.machine = manager.compute_state().0;
        manager
    }

    pub fn config(&self) -> &ManagerConfig {
        &self.config
    }

    /// The manager's heartbeat, sent now (at start: the first one is not
    /// one period late).
    pub fn heartbeat_now(&self) -> Option<Frame> {
        (self.config.heartbeat_ms > 0).then(|| {
            super::heartbeat::Heartbeat::new(self.config.node_id, NmtState::Operational).encode()
        })
    }

    fn node_mut(&mut self, id: NodeId) -> Option<&mut Node> {
        if !self.nodes.contains_key(&id) {
            if id == self.config.node_id {
                return None;
            }
            let (description, managed) = if self.described {
                (NodeDescription::default_for(id), false)
            } else {
                (NodeDescription::default_for(id), true)
            };
            self.nodes.insert(id, Node::new(description, managed));
        }
        self.nodes.get_mut(&id)
    }

    /// The node is there (found by a scan, or heard for the first time):
    /// booted unless it is already booting or booted.
    pub fn node_found(&mut self, id: NodeId) {
        if id == self.config.node_id {
            self.own_id_taken = true;
        }
        let Some(node) = self.node_mut(id) else {
            return;
        };
        node.present = true;
        if node.managed
            && node.idle()
            && matches!(node.state, NodeState::Missing | NodeState::Offline)
        {
            self.begin_boot(id, "found on the bus");
        }
    }

    /// The device at `id` moved to another node-ID for good (its node-ID
    /// was changed): an expected node is missing again, to be booted when
    /// a device answers there; one that was only found is forgotten, so
    /// that its old ID is not supervised (and lost) for ever.
    pub fn node_left(&mut self, id: NodeId, why: &str) {
        let Some(node) = self.nodes.get_mut(&id) else {
            return;
        };
        if std::mem::take(&mut node.guarded) {
            self.outbox.push(Action::Unguard { node: id });
        }
        if !node.description.expected {
            self.nodes.remove(&id);
            return;
        }
        node.present = false;
        node.state = NodeState::Missing;
        node.step = Step::Waiting;
        node.reason = Some(why.to_string());
        node.ops.clear();
        node.heartbeat_set = false;
        node.configured = false;
        node.resync = false;
        node.identity.clear();
        node.consumer = None;
        node.supervision = Supervision::None;
        node.supervision_reason = None;
        node.retry_at = None;
        // An answer still to come belongs to the device that left.
        node.stale = node.in_flight.is_some();
    }

    /// The first scan of the bus is over: the expected nodes it did not
    /// find are missing (no longer "booting").
    pub fn scan_done(&mut self) {
        self.scanned = true;
    }

    /// The bus went down (`false`) or came back up. Back up, every node
    /// that was present is booted again: what happened to it meanwhile
    /// (a reset whose boot-up message nobody heard, a power cycle that
    /// cleared its 0x1017) cannot be known, and a node that is gone shows
    /// as missing when it does not answer.
    pub fn bus_up(&mut self, up: bool) {
        let back = up && !self.bus_up;
        self.bus_up = up;
        if !back {
            return;
        }
        let again: Vec<NodeId> = self
            .nodes
            .values()
            .filter(|node| node.managed && node.present)
            .map(|node| node.description.id)
            .collect();
        for id in again {
            self.begin_boot(id, "the bus is back up");
        }
    }

    /// Runs a node's boot-up again (operator request); an error when the
    /// node is not known to the manager.
    pub fn reboot(&mut self, id: NodeId) -> Result<(), String> {
        match self.nodes.get(&id) {
            Some(node) if node.managed || node.present => {}
            Some(_) | None => {
                return Err(format!("node {id} is neither described nor present"));
            }
        }
        if let Some(node) = self.nodes.get_mut(&id) {
            node.managed = true;
        }
        self.begin_boot(id, "requested");
        Ok(())
    }

    /// The descriptions of the nodes (expected or booted with the defaults).
    pub fn description(&self, id: NodeId) -> Option<&NodeDescription> {
        self.nodes.get(&id).map(|node| &node.description)
    }

    fn begin_boot(&mut self, id: NodeId, why: &str) {
        let manager_heartbeat = self.config.heartbeat_ms;
        let Some(node) = self.nodes.get_mut(&id) else {
            return;
        };
        node.present = true;
        node.boots += 1;
        node.state = NodeState::Booting;
        node.reason = None;
        node.answered = false;
        node.heartbeat_set = false;
        node.configured = false;
        node.resync = false;
        node.consumer = None;
        if std::mem::take(&mut node.guarded) {
            self.outbox.push(Action::Unguard { node: id });
        }
        node.supervision = Supervision::None;
        node.supervision_reason = Some("booting".into());
        // A request in flight is answered to the old boot: dropped.
        node.stale = node.in_flight.is_some();
        node.retry_at = None;
        let description = &node.description;
        let mut ops: std::collections::VecDeque<Op> = std::iter::once(Op::Identify)
            .chain(
                description
                    .identity
                    .subs()
                    .into_iter()
                    .map(Op::CheckIdentity),
            )
            .collect();
        for (at, write) in description.config.iter().enumerate() {
            if is_motion_object(write.index) && !ops.contains(&Op::StopMotion) {
                ops.push_back(Op::StopMotion);
            }
            ops.push_back(Op::Configure(at));
        }
        if description.heartbeat_ms > 0 {
            ops.push_back(Op::SetHeartbeat);
        }
        if manager_heartbeat > 0 && description.consume_manager_heartbeat != Some(false) {
            ops.push_back(Op::CountConsumers);
        }
        if description.start {
            ops.push_back(Op::Start);
        }
        if node.nmt == Some(NmtState::Stopped) {
            ops.push_front(Op::EnterPreOperational);
        }
        node.ops = ops;
        node.step = node.ops.front().map_or(Step::Supervised, Op::step);
        self.events.push(ManagerEvent::BootStarted {
            node: id,
            why: why.to_string(),
        });
    }

    /// A configured node heard again after it was lost: resynchronised
    /// rather than booted (CiA 302-2 boots a slave that restarted; one
    /// whose heartbeat was only late keeps its configuration, and a drive
    /// moving under it must not have its modes written back). Its identity
    /// is read (0x1018: the description's keys and the vendor-ID,
    /// compared with what it answered before), then what its boot-up set
    /// up and a restart would have undone: its producer heartbeat time
    /// (0x1017) and the entry of 0x1016 that watches the manager. Where
    /// all match the node is ready again with nothing written (an NMT
    /// start only if it is not operational); where one differs, or cannot
    /// be read, it restarted meanwhile and is booted in full.
    fn begin_resync(&mut self, id: NodeId, why: &str) {
        let Some(node) = self.nodes.get_mut(&id) else {
            return;
        };
        node.state = NodeState::Booting;
        node.reason = None;
        node.resync = true;
        node.stale = node.in_flight.is_some();
        node.retry_at = None;
        let description = &node.description;
        let mut subs = description.identity.subs();
        if !subs.contains(&1) {
            // The vendor-ID: every node has it (CiA 301 0x1018).
            subs.insert(0, 1);
        }
        let mut ops: std::collections::VecDeque<Op> = std::iter::once(Op::Identify)
            .chain(subs.into_iter().map(Op::VerifyIdentity))
            .collect();
        if node.heartbeat_set {
            ops.push_back(Op::VerifyHeartbeat);
        }
        if let Some((sub, _)) = node.consumer {
            ops.push_back(Op::VerifyConsumer(sub));
        }
        if description.start {
            ops.push_back(Op::StartIfNeeded);
        }
        if node.nmt == Some(NmtState::Stopped) {
            ops.push_front(Op::EnterPreOperational);
        }
        node.ops = ops;
        node.step = node.ops.front().map_or(Step::Supervised, Op::step);
        self.events.push(ManagerEvent::ResyncStarted {
            node: id,
            why: why.to_string(),
        });
    }

    /// Takes what the bus's [`Supervisor`] decided (the one supervision of
    /// the nodes: the manager keeps no timer of its own): a boot-up message
    /// or a node heard for the first time (or heard again after it was
    /// lost, or while missing) boots it; a ready node lost goes offline;
    /// a written 0x1017 becomes the node's.
    pub fn on_supervision(&mut self, event: &SupervisorEvent) {
        let id = event.node();
        if id == self.config.node_id
            && matches!(
                event,
                SupervisorEvent::BootUp { .. } | SupervisorEvent::Heard { .. }
            )
        {
            self.own_id_taken = true;
        }
        match *event {
            SupervisorEvent::HeartbeatWritten { heartbeat_ms, .. } => {
                // The supervisor times it anew from the write.
                if let Some(node) = self.nodes.get_mut(&id) {
                    node.lost = false;
                }
                self.producer_heartbeat_written(id, heartbeat_ms);
            }
            SupervisorEvent::Lost { by, .. } => self.lost(id, by),
            // A node it does not know yet is added by what follows.
            SupervisorEvent::Nmt { to, .. } => {
                if let Some(node) = self.nodes.get_mut(&id) {
                    node.nmt = Some(after_boot_up(to));
                }
            }
            SupervisorEvent::BootUp { .. } => {
                let Some(node) = self.node_mut(id) else {
                    return;
                };
                // The boot-up message is sent on entering pre-operational
                // (CiA 301 §7.3.2.1): that is the state it is in.
                node.nmt = Some(NmtState::PreOperational);
                node.present = true;
                node.lost = false;
                // It restarted: what it said of itself may have changed.
                node.configured = false;
                node.identity.clear();
                if node.managed {
                    self.begin_boot(id, "boot-up message");
                }
            }
            SupervisorEvent::Recovered { .. } => {
                let Some(node) = self.node_mut(id) else {
                    return;
                };
                node.present = true;
                node.lost = false;
                // Only a node the manager had lost is taken up again: one
                // on its way goes on. One whose configuration is in place
                // is resynchronised, not configured again.
                if node.managed && node.state == NodeState::Offline {
                    if node.configured {
                        self.begin_resync(id, "heard again after it was lost");
                    } else {
                        self.begin_boot(id, "heard again after it was lost");
                    }
                }
            }
            SupervisorEvent::Heard { nmt, .. } => {
                let new = !self.nodes.contains_key(&id);
                let Some(node) = self.node_mut(id) else {
                    return;
                };
                node.nmt = Some(after_boot_up(nmt));
                node.present = true;
                node.lost = false;
                let why = if new {
                    Some("heard for the first time")
                } else if node.state == NodeState::Missing && node.idle() {
                    Some("heard")
                } else {
                    None
                };
                if let Some(why) = why
                    && node.managed
                {
                    self.begin_boot(id, why);
                }
            }
            SupervisorEvent::Online { .. } | SupervisorEvent::Offline { .. } => {}
        }
    }

    /// The supervisor lost the node: a ready node goes offline (one on its
    /// way is not lost for the manager until its boot-up ends).
    fn lost(&mut self, id: NodeId, by: LostBy) {
        let factor = self.config.consumer_factor;
        let Some(node) = self.nodes.get_mut(&id) else {
            return;
        };
        node.lost = true;
        if node.state != NodeState::Ready {
            return;
        }
        let reason = match by {
            LostBy::Heartbeat { period } => format!(
                "no heartbeat within {} ms ({} × {} ms)",
                factor.timeout(period).as_millis(),
                factor,
                period.as_millis()
            ),
            LostBy::Guarding { life_time } => {
                format!("no node-guarding reply within {} ms", life_time.as_millis())
            }
        };
        node.state = NodeState::Offline;
        node.reason = Some(reason.clone());
        self.events.push(ManagerEvent::Lost { node: id, reason });
    }

    /// The answer to the SDO request of `node` the manager asked for.
    pub fn on_sdo(&mut self, id: NodeId, outcome: SdoOutcome, now: Instant) {
        let retry_min = self.config.retry_min;
        let retry_max = self.config.retry_max;
        let Some(node) = self.nodes.get_mut(&id) else {
            return;
        };
        let Some(op) = node.in_flight.take() else {
            return;
        };
        if std::mem::take(&mut node.stale) {
            return;
        }
        let fail = |node: &mut Node, reason: String, retry: bool| -> ManagerEvent {
            let step = op.step();
            node.ops.clear();
            node.reason = Some(format!("{}: {reason}", step.name()));
            node.step = step;
            let retry = retry.then(|| {
                node.backoff = if node.backoff.is_zero() {
                    retry_min
                } else {
                    (node.backoff * 2).min(retry_max)
                };
                node.retry_at = Some(now + node.backoff);
                node.backoff
            });
            ManagerEvent::Failed {
                node: node.description.id,
                step,
                reason,
                retry,
            }
        };
        match outcome {
            SdoOutcome::Done(data) => {
                // The gateway's identification is not an answer to the
                // manager.
                node.answered |= op != Op::Identify;
                if let Op::CheckIdentity(sub) = op {
                    let value = unsigned(&data);
                    let mismatch = match value {
                        Some(value) => node.description.identity.mismatch(sub, value),
                        None => Some(format!("0x1018 sub {sub}: {} bytes read", data.len())),
                    };
                    if let Some(reason) = mismatch {
                        node.state = NodeState::WrongIdentity;
                        let event = fail(node, reason, false);
                        self.events.push(event);
                        return;
                    }
                    if let Some(value) = value {
                        node.identity.insert(sub, value);
                    }
                }
                let manager = (self.config.node_id, self.config.heartbeat_ms);
                if let Some(what) = verify(node, &op, &data, manager) {
                    self.restarted(id, &what);
                    return;
                }
                match op {
                    Op::CountConsumers | Op::FindConsumer { .. } => {
                        let manager = self.config.node_id;
                        match next_consumer_op(&op, &data, manager) {
                            Ok(Some(next)) => node.ops.push_front(next),
                            Ok(None) => {}
                            Err(reason) => {
                                if node.description.consume_manager_heartbeat == Some(true) {
                                    node.state = NodeState::ConfigFailed;
                                    let event = fail(node, reason, true);
                                    self.events.push(event);
                                    return;
                                }
                                // Where it can: this node cannot.
                            }
                        }
                    }
                    Op::SetHeartbeat => node.heartbeat_set = true,
                    Op::ConsumeManager(sub) => {
                        node.consumer = Some((sub, consumer_entry(manager.0, manager.1)));
                    }
                    _ => {}
                }
                if op == Op::SetGuardTime {
                    // Guarding instead of heartbeat: the factor follows.
                    node.ops.push_front(Op::SetLifeFactor);
                }
                if op == Op::SetLifeFactor {
                    // The supervisor guards it from now on, for the manager,
                    // afresh: what it lost before is past.
                    node.guarded = true;
                    node.lost = false;
                    self.outbox.push(Action::Guard {
                        node: id,
                        guard_time_ms: node.description.heartbeat_ms,
                        life_time_factor: LIFE_TIME_FACTOR_DEFAULT,
                    });
                }
                self.next(id);
            }
            SdoOutcome::Aborted(code) => {
                node.answered = true;
                match op {
                    Op::CheckIdentity(sub) => {
                        node.state = NodeState::WrongIdentity;
                        let event = fail(
                            node,
                            format!("0x1018 sub {sub} cannot be read: abort {code}"),
                            false,
                        );
                        self.events.push(event);
                    }
                    Op::Configure(at) => {
                        let label = node.description.config[at].label.clone();
                        node.state = NodeState::ConfigFailed;
                        let event = fail(node, format!("{label}: abort {code}"), true);
                        self.events.push(event);
                    }
                    Op::SetHeartbeat => {
                        // No writable 0x1017: node guarding instead.
                        node.ops.push_front(Op::SetGuardTime);
                        node.supervision_reason =
                            Some(format!("0x1017 not writable (abort {code})"));
                        self.next(id);
                    }
                    Op::SetGuardTime | Op::SetLifeFactor => {
                        node.supervision_reason = Some(format!(
                            "neither heartbeat (0x1017) nor node guarding (0x{:04X}) can be set: abort {code}",
                            if op == Op::SetGuardTime {
                                GUARD_TIME
                            } else {
                                LIFE_TIME_FACTOR
                            }
                        ));
                        self.next(id);
                    }
                    Op::CountConsumers | Op::FindConsumer { .. } | Op::ConsumeManager(_) => {
                        if node.description.consume_manager_heartbeat == Some(true) {
                            node.state = NodeState::ConfigFailed;
                            let what = match op {
                                Op::ConsumeManager(sub) => format!(
                                    "0x1016 sub {sub} (the manager's heartbeat) cannot be written"
                                ),
                                Op::FindConsumer { sub, .. } => {
                                    format!("0x1016 sub {sub} cannot be read")
                                }
                                _ => "0x1016 cannot be read".to_string(),
                            };
                            let event = fail(node, format!("{what}: abort {code}"), true);
                            self.events.push(event);
                        } else {
                            // Where 0x1016 exists: this node has none.
                            self.next(id);
                        }
                    }
                    Op::Start => self.next(id),
                    Op::VerifyIdentity(_) | Op::VerifyHeartbeat | Op::VerifyConsumer(_) => {
                        let (index, sub) = op.object();
                        self.restarted(
                            id,
                            &format!("0x{index:04X} sub {sub} cannot be read (abort {code})"),
                        );
                    }
                    // Frames: never answered.
                    Op::StartIfNeeded | Op::EnterPreOperational => self.next(id),
                    Op::StopMotion | Op::Identify => {
                        node.state = NodeState::ConfigFailed;
                        let event = fail(node, format!("abort {code}"), true);
                        self.events.push(event);
                    }
                }
            }
            SdoOutcome::Failed(reason) => {
                node.state = if node.resync {
                    // Retried as a resynchronisation: nothing says it
                    // restarted.
                    NodeState::Offline
                } else if op == Op::StopMotion {
                    // Its axes could not be stopped: its motion objects
                    // are not written under a moving axis.
                    NodeState::ConfigFailed
                } else if node.answered {
                    NodeState::ConfigFailed
                } else {
                    NodeState::Missing
                };
                let event = fail(node, reason, true);
                self.events.push(event);
            }
        }
    }

    /// After an operation succeeded: the next one, or the end of the boot.
    fn next(&mut self, id: NodeId) {
        let Some(node) = self.nodes.get_mut(&id) else {
            return;
        };
        match node.ops.front() {
            Some(op) => {
                let step = op.step();
                if step != node.step {
                    node.step = step;
                    self.events.push(ManagerEvent::Step { node: id, step });
                }
            }
            None => self.finished(id),
        }
    }

    /// The boot-up or the resynchronisation under way ended well.
    fn finished(&mut self, id: NodeId) {
        if self.nodes.get(&id).is_some_and(|node| node.resync) {
            self.resynced(id);
        } else {
            self.booted(id);
        }
    }

    /// The node was found as its boot-up left it: ready again, supervised
    /// as before, nothing written.
    fn resynced(&mut self, id: NodeId) {
        let Some(node) = self.nodes.get_mut(&id) else {
            return;
        };
        node.resync = false;
        node.step = Step::Supervised;
        node.state = NodeState::Ready;
        node.reason = None;
        node.retry_at = None;
        node.backoff = Duration::ZERO;
        self.events.push(ManagerEvent::Resynchronised { node: id });
        self.lost_meanwhile(id, "since before its resynchronisation ended");
    }

    /// A node that the supervisor lost while its boot-up or
    /// resynchronisation ran is offline, not ready.
    fn lost_meanwhile(&mut self, id: NodeId, since: &str) {
        let Some(node) = self.nodes.get_mut(&id) else {
            return;
        };
        if node.lost && node.supervision != Supervision::None {
            let by = if node.supervision == Supervision::Guarding {
                "no node-guarding reply"
            } else {
                "no heartbeat"
            };
            let reason = format!("{by} {since}");
            node.state = NodeState::Offline;
            node.reason = Some(reason.clone());
            self.events.push(ManagerEvent::Lost { node: id, reason });
        }
    }

    /// A resynchronisation found the node not as its boot-up left it
    /// (`what`): it restarted meanwhile, and is booted in full.
    fn restarted(&mut self, id: NodeId, what: &str) {
        self.begin_boot(
            id,
            &format!("heard again after it was lost, and {what}: it restarted"),
        );
    }

    fn booted(&mut self, id: NodeId) {
        let Some(node) = self.nodes.get_mut(&id) else {
            return;
        };
        node.step = Step::Supervised;
        node.state = NodeState::Ready;
        node.reason = None;
        node.backoff = Duration::ZERO;
        node.boots_ok += 1;
        node.configured = true;
        Self::supervise(node, "heartbeat_ms is 0");
        self.events.push(ManagerEvent::Booted { node: id });
        // The supervisor lost it while it booted: it is not ready.
        self.lost_meanwhile(id, "since before its boot-up ended");
    }

    /// How a booted node is supervised, from what its boot-up (or a later
    /// write of its 0x1017) set up: its heartbeat (timed by the
    /// supervisor from the write), else node guarding, else nothing, and
    /// why (`off`: the reason when its heartbeat time is 0).
    fn supervise(node: &mut Node, off: &str) {
        let period = node.description.heartbeat_ms;
        if node.heartbeat_set && period > 0 {
            node.supervision = Supervision::Heartbeat;
            node.supervision_reason = None;
        } else if node.guarded {
            node.supervision = Supervision::Guarding;
            node.supervision_reason = None;
        } else {
            node.supervision = Supervision::None;
            if node.supervision_reason.is_none() || period == 0 {
                node.supervision_reason = Some(off.into());
            }
        }
    }

    /// Someone (an operator, a client of the gateway, the manager itself)
    /// wrote `ms` into the node's producer heartbeat time (0x1017 sub 0)
    /// and the node confirmed it ([`SupervisorEvent::HeartbeatWritten`]).
    /// The node's description follows (a later boot-up writes `ms`, not
    /// the old value, until the gateway restarts), and so does its
    /// supervision at once: by heartbeat (the supervisor times it from the
    /// write), or, for 0 (heartbeat off), node guarding where it is set
    /// up, else `supervision: none` with the reason, as at a boot-up. The
    /// node is neither lost nor booted again for it. Writing the value the
    /// description already has (the manager's own boot-up write) does
    /// nothing.
    fn producer_heartbeat_written(&mut self, id: NodeId, ms: u16) {
        let Some(node) = self.nodes.get_mut(&id) else {
            return;
        };
        if node.description.heartbeat_ms == ms {
            return;
        }
        node.description.heartbeat_ms = ms;
        if ms > 0 && !node.guarded {
            node.heartbeat_set = true;
        } else if ms == 0 {
            node.heartbeat_set = false;
        }
        // A node on its way writes the new value itself (or has it: its
        // supervision is decided when its boot-up ends); a lost one is
        // booted again when it is heard, with the new value.
        if node.state == NodeState::Ready {
            Self::supervise(node, "0x1017 was written 0: the node sends no heartbeat");
        }
    }

    /// Due work at `now`: the next SDO request of each node that waits for
    /// none, retries, NMT commands, the manager's heartbeat, what the
    /// supervisor is to guard.
    pub fn poll(&mut self, now: Instant) -> Vec<Action> {
        let mut actions = std::mem::take(&mut self.outbox);
        if let Some(frame) = self.producer.poll(now, NmtState::Operational) {
            actions.push(Action::Send(frame));
        }
        let ids: Vec<NodeId> = self.nodes.keys().copied().collect();
        let mut in_flight = self
            .nodes
            .values()
            .filter(|node| node.in_flight.is_some())
            .count();
        for id in ids {
            if self
                .nodes
                .get(&id)
                .is_some_and(|node| node.retry_at.is_some_and(|at| at <= now))
            {
                if self.nodes.get(&id).is_some_and(|node| node.resync) {
                    self.begin_resync(id, "retry");
                } else {
                    self.begin_boot(id, "retry");
                }
            }
            let manager = (self.config.node_id, self.config.heartbeat_ms);
            let Some(node) = self.nodes.get_mut(&id) else {
                continue;
            };
            if node.in_flight.is_some() || !self.bus_up {
                continue;
            }
            // A node already on its way goes on; one that has not begun
            // waits for a free place (an NMT start needs none).
            let waits = in_flight >= self.config.max_requests.max(1)
                && !matches!(node.ops.front(), Some(Op::Start | Op::StartIfNeeded) | None);
            if waits {
                continue;
            }
            while let Some(op) = node.ops.pop_front() {
                let description = &node.description;
                let action = match &op {
                    Op::CheckIdentity(sub) => Action::Read {
                        node: id,
                        index: IDENTITY,
                        sub: *sub,
                    },
                    Op::Identify => Action::Identify { node: id },
                    Op::StopMotion => Action::StopMotion { node: id },
                    Op::Configure(at) => {
                        let write = &description.config[*at];
                        Action::Write {
                            node: id,
                            index: write.index,
                            sub: write.sub,
                            data: write.data.clone(),
                        }
                    }
                    Op::SetHeartbeat => Action::Write {
                        node: id,
                        index: PRODUCER_HEARTBEAT_TIME,
                        sub: 0,
                        data: description.heartbeat_ms.to_le_bytes().to_vec(),
                    },
                    Op::SetGuardTime => Action::Write {
                        node: id,
                        index: GUARD_TIME,
                        sub: 0,
                        data: description.heartbeat_ms.to_le_bytes().to_vec(),
                    },
                    Op::SetLifeFactor => Action::Write {
                        node: id,
                        index: LIFE_TIME_FACTOR,
                        sub: 0,
                        data: vec![LIFE_TIME_FACTOR_DEFAULT],
                    },
                    Op::CountConsumers => Action::Read {
                        node: id,
                        index: CONSUMER_HEARTBEAT_TIME,
                        sub: 0,
                    },
                    Op::FindConsumer { sub, .. } => Action::Read {
                        node: id,
                        index: CONSUMER_HEARTBEAT_TIME,
                        sub: *sub,
                    },
                    Op::ConsumeManager(sub) => Action::Write {
                        node: id,
                        index: CONSUMER_HEARTBEAT_TIME,
                        sub: *sub,
                        data: consumer_entry(manager.0, manager.1).to_le_bytes().to_vec(),
                    },
                    Op::VerifyIdentity(sub) => Action::Read {
                        node: id,
                        index: IDENTITY,
                        sub: *sub,
                    },
                    Op::VerifyHeartbeat => Action::Read {
                        node: id,
                        index: PRODUCER_HEARTBEAT_TIME,
                        sub: 0,
                    },
                    Op::VerifyConsumer(sub) => Action::Read {
                        node: id,
                        index: CONSUMER_HEARTBEAT_TIME,
                        sub: *sub,
                    },
                    Op::StartIfNeeded => {
                        if node.nmt != Some(NmtState::Operational) {
                            let frame = super::nmt::NmtMessage::new(
                                NmtCommand::Start,
                                super::nmt::NmtTarget::Node(id),
                            )
                            .encode();
                            actions.push(Action::Send(frame));
                        }
                        continue;
                    }
                    Op::EnterPreOperational => {
                        // Unconfirmed: the SDO request that follows is
                        // answered once the node took it.
                        let frame = super::nmt::NmtMessage::new(
                            NmtCommand::EnterPreOperational,
                            super::nmt::NmtTarget::Node(id),
                        )
                        .encode();
                        actions.push(Action::Send(frame));
                        continue;
                    }
                    Op::Start => {
                        // Unconfirmed: sent, and the boot is done; the
                        // heartbeat says when the node is operational.
                        let frame = super::nmt::NmtMessage::new(
                            NmtCommand::Start,
                            super::nmt::NmtTarget::Node(id),
                        )
                        .encode();
                        actions.push(Action::Send(frame));
                        continue;
                    }
                };
                node.in_flight = Some(op);
                in_flight += 1;
                actions.push(action);
                break;
            }
            if node.in_flight.is_none() && node.ops.is_empty() && node.state == NodeState::Booting {
                // The last operation was the NMT start (or there was none).
                self.finished(id);
            }
        }
        let (machine, _) = self.compute_state();
        if machine != self.machine {
            self.events.push(ManagerEvent::Machine {
                from: self.machine,
                to: machine,
            });
            self.machine = machine;
        }
        actions
    }

    /// When [`Manager::poll`] has work next.
    pub fn deadline(&self) -> Option<Instant> {
        // Work that is ready (the next request of a boot-up) is handed out
        // by the poll that follows every input, so only timers count here.
        self.nodes
            .values()
            .filter_map(|node| node.retry_at)
            .chain(self.producer.deadline())
            .min()
    }

    /// What happened since the last call.
    pub fn take_events(&mut self) -> Vec<ManagerEvent> {
        std::mem::take(&mut self.events)
    }

    fn compute_state(&self) -> (MachineState, Vec<String>) {
        let mut reasons = Vec::new();
        if !self.bus_up {
            return (MachineState::Down, vec!["the bus is down".into()]);
        }
        // Until the first scan is over the manager does not know what is
        // on the bus, described or not.
        let mut booting = !self.scanned;
        let mut bad = 0;
        let mut mandatory = 0;
        let mut ready = 0;
        for node in self
            .nodes
            .values()
            .filter(|node| node.description.mandatory)
        {
            mandatory += 1;
            let id = node.description.id;
            match node.state {
                NodeState::Ready if node.supervision == Supervision::None => {
                    bad += 1;
                    reasons.push(format!(
                        "node {id} is not supervised: {}",
                        node.supervision_reason.as_deref().unwrap_or("no reason")
                    ));
                }
                NodeState::Ready if node.unconfirmed() => {
                    booting = true;
                    reasons.push(format!(
                        "node {id} is {}, not yet {}",
                        node.nmt.map_or("unknown", NmtState::name),
                        node.wanted_nmt().name()
                    ));
                }
                NodeState::Ready => ready += 1,
                NodeState::Booting => {
                    booting = true;
                    reasons.push(format!("node {id} is booting ({})", node.step.name()));
                }
                NodeState::Missing if !self.scanned && !node.present => booting = true,
                state => {
                    bad += 1;
                    reasons.push(format!(
                        "node {id} {}{}",
                        state.name(),
                        node.shown_reason()
                            .map(|reason| format!(": {reason}"))
                            .unwrap_or_default()
                    ));
                }
            }
        }
        if !self.described {
            // Without a description the nodes found are the machine: it is
            // not ready while one of them is on its way for the first time
            // (one that failed does not degrade it, nor do its retries take
            // the machine back to `booting` at each back-off).
            for node in self.nodes.values().filter(|node| {
                node.managed && node.backoff.is_zero() && node.shown_state() == NodeState::Booting
            }) {
                booting = true;
                reasons.push(format!(
                    "node {} is booting ({})",
                    node.description.id,
                    if node.unconfirmed() {
                        Step::Start.name()
                    } else {
                        node.step.name()
                    }
                ));
            }
        }
        if self.own_id_taken {
            reasons.push(format!(
                "a device answers at the gateway's own node ID {} (manager_node_id): it is not supervised, and devices watching the gateway's heartbeat may take its for the gateway's",
                self.config.node_id
            ));
        }
        let state = if mandatory > 0 && ready == 0 && bad == mandatory {
            MachineState::Down
        } else if bad > 0 || self.own_id_taken {
            MachineState::Degraded
        } else if booting {
            MachineState::Booting
        } else {
            MachineState::Ready
        };
        (state, reasons)
    }

    /// The machine as the API shows it.
    pub fn status(&self) -> MachineStatus {
        let (state, reasons) = self.compute_state();
        let nodes = self
            .nodes
            .values()
            .map(|node| {
                let id = node.description.id;
                NodeStatus {
                    id: id.get(),
                    name: node.description.name.clone(),
                    mandatory: node.description.mandatory,
                    expected: node.description.expected,
                    state: node.shown_state(),
                    step: if node.unconfirmed() {
                        Step::Start
                    } else {
                        node.step
                    },
                    reason: node.shown_reason(),
                    supervision: node.supervision,
                    heartbeat_ms: node.description.heartbeat_ms,
                    nmt: node.nmt.map_or("unknown", NmtState::name).to_string(),
                    eds: node.description.eds.clone(),
                    dcf: node.description.dcf.clone(),
                    boots: node.boots,
                    boots_ok: node.boots_ok,
                }
            })
            .collect();
        MachineStatus {
            state,
            reasons,
            nodes,
        }
    }

    pub fn state(&self) -> MachineState {
        self.machine
    }
}

impl fmt::Display for MachineState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The NMT state a node reporting `state` is in: a boot-up message is
/// sent on entering pre-operational (CiA 301 §7.3.2.1), so a node that
/// sent one is pre-operational, never "boot-up".
fn after_boot_up(state: NmtState) -> NmtState {
    if state == NmtState::BootUp {
        NmtState::PreOperational
    } else {
        state
    }
}

/// What a resynchronisation's read `op` (answered `data`) found differs
/// from what the node's boot-up left (`None`: as it was, or not such a
/// read). An identity read the node never answered before is kept, to be
/// compared the next time.
fn verify(node: &mut Node, op: &Op, data: &[u8], manager: (NodeId, u16)) -> Option<String> {
    let (index, sub) = op.object();
    let value = match op {
        Op::VerifyIdentity(_) | Op::VerifyHeartbeat | Op::VerifyConsumer(_) => unsigned(data),
        _ => return None,
    };
    let Some(value) = value else {
        return Some(format!(
            "0x{index:04X} sub {sub}: {} bytes read where a number was expected",
            data.len()
        ));
    };
    match *op {
        Op::VerifyIdentity(sub) => {
            if let Some(reason) = node.description.identity.mismatch(sub, value) {
                return Some(reason);
            }
            match node.identity.insert(sub, value) {
                Some(before) if before != value => Some(format!(
                    "0x1018 sub {sub} is 0x{value:08X}, was 0x{before:08X}"
                )),
                _ => None,
            }
        }
        Op::VerifyHeartbeat => {
            let written = node.description.heartbeat_ms;
            (value != u32::from(written))
                .then(|| format!("0x1017 is {value} ms, {written} ms was written"))
        }
        _ => {
            let want = consumer_entry(manager.0, manager.1);
            (value != want).then(|| {
                format!("0x1016 sub {sub} is 0x{value:08X}, 0x{want:08X} (the manager's heartbeat) was written")
            })
        }
    }
}

/// Whether a configuration write to `index` changes how a drive moves:
/// the device profile area (CiA 402's modes, targets and limits, each axis
/// at its offset).
pub fn is_motion_object(index: u16) -> bool {
    (0x6000..=0x9FFF).contains(&index)
}

/// The 0x1016 entry that watches the manager (node-ID in bits 16–23, the
/// consumer time in ms below): 3 × its heartbeat period.
fn consumer_entry(manager: NodeId, heartbeat_ms: u16) -> u32 {
    let time = u16::try_from(u32::from(heartbeat_ms) * 3).unwrap_or(u16::MAX);
    u32::from(manager.get()) << 16 | u32::from(time)
}

/// What follows a read of 0x1016 (sub 0, or an entry) in the search for
/// the entry the manager's heartbeat goes to: the next read, the write, or
/// nothing more to do (`Ok(None)`: the node has no entries). An entry is
/// free when its node-ID or its time is 0 (CiA 301 §7.5.2.32: not used).
/// `Err` says why the manager's heartbeat cannot be consumed.
fn next_consumer_op(op: &Op, data: &[u8], manager: NodeId) -> Result<Option<Op>, String> {
    let value = unsigned(data).ok_or_else(|| {
        format!(
            "0x1016: {} bytes read where a number was expected",
            data.len()
        )
    })?;
    let (sub, count, free) = match *op {
        Op::CountConsumers => {
            let count = u8::try_from(value)
                .map_err(|_| format!("0x1016 sub 0 = {value}: more entries than a sub-index"))?;
            if count == 0 {
                return Err("0x1016 has no entries".to_string());
            }
            return Ok(Some(Op::FindConsumer {
                sub: 1,
                count,
                free: None,
            }));
        }
        Op::FindConsumer { sub, count, free } => (sub, count, free),
        _ => return Ok(None),
    };
    let node = (value >> 16) & 0xFF;
    let time = value & 0xFFFF;
    if node == u32::from(manager.get()) {
        return Ok(Some(Op::ConsumeManager(sub)));
    }
    let free = free.or((node == 0 || time == 0).then_some(sub));
    if sub < count {
        return Ok(Some(Op::FindConsumer {
            sub: sub + 1,
            count,
            free,
        }));
    }
    match free {
        Some(sub) => Ok(Some(Op::ConsumeManager(sub))),
        None => Err(format!(
            "0x1016: all {count} entries watch other nodes; none is free for the manager's heartbeat"
        )),
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
