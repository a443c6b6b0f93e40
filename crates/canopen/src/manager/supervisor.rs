//! The error-control supervisor of a bus, without I/O: the one place that
//! decides, per node, whether it is heard or lost, its NMT state, its
//! producer heartbeat period and the deadline it must be heard by
//! (CiA 301 §7.2.8.3.2). The node registry and the network manager both
//! follow its events instead of keeping timers of their own, so what the
//! node list, the machine view and the stream say cannot disagree.
//!
//! - **Frames.** Every data frame on 0x700 + node (boot-up, heartbeat,
//!   node-guarding reply) sets the node's NMT state; any other frame of the
//!   node ([`Supervisor::heard`]) only says it is there.
//! - **Heartbeat period.** Its 0x1017 as read ([`Supervisor::heartbeat_read`])
//!   or written through the gateway ([`Supervisor::heartbeat_written`]),
//!   else learnt from its heartbeats: the shortest of the last few
//!   intervals, so that a changed 0x1017 is followed and one lost heartbeat
//!   does not double it. A boot-up forgets it (the node reloads its 0x1017).
//! - **Lost.** A node with a period is lost when no heartbeat comes within
//!   [`ConsumerFactor`] periods (3 by default) of the last one (or of the write or read that set the
//!   period); a node guarded by the manager ([`Supervisor::guard`]) when no
//!   valid reply comes within its life time. It is heard again with its
//!   next heartbeat (or valid reply).
//! - **Online.** A supervised node (a period, or guarded) is online by its
//!   error-control frames only; one without is online from any frame and
//!   offline when it does not answer a probe ([`Supervisor::no_answer`]).
//!   While the bus is down every node is offline.
//!
//! Like the manager, the supervisor takes frames and the current time in
//! and gives [`SupervisorEvent`]s, guarding requests and a deadline out
//! ([`Supervisor::poll`], [`Supervisor::deadline`]).

use std::collections::{BTreeMap, VecDeque};
use std::time::{Duration, Instant};

use super::super::cob::NodeId;
use super::super::heartbeat::{Heartbeat, HeartbeatEvent, NodeGuardMaster, heartbeat_node};
use super::super::nmt::NmtState;
use crate::can::Frame;

#[cfg(test)]
mod tests;

/// Heartbeat intervals the period is learnt from.
const HEARTBEAT_WINDOW: usize = 8;
/// This many intervals in a row all longer than the supervision timeout
/// ([`ConsumerFactor`] periods) say that the producer slowed down (its 0x1017 was
/// written): the period follows at once, rather than after the window,
/// while the node flapped offline and online at every heartbeat.
const SLOWER_AFTER: usize = 3;
/// A learnt period within this part (a quarter) of the one the supervisor
/// has is the jitter of a loaded sender or bus, not a new 0x1017: kept.
/// (Followed, a heartbeat 60 ms early on a loaded host shortened the
/// period, and with it the timeout, until on-time heartbeats were lost.)
const JITTER_PART: u32 = 4;
/// This many intervals in a row all shorter than the period (by more than
/// the jitter) say that the producer got faster (its 0x1017 was written).
const FASTER_AFTER: usize = 3;
/// Intervals shorter than this are two frames of one burst, not a period.
const MIN_HEARTBEAT_INTERVAL: Duration = Duration::from_millis(1);

/// How many producer periods the gateway waits for a node's heartbeat
/// before it is lost (its heartbeat consumer time, CiA 301 §7.2.8.3.2.2):
/// `heartbeat_consumer_factor` of the configuration, 1.5 to 10 in tenths.
/// The margin above one period is for bus load and the jitter of both
/// ends: a loaded host delays the heartbeat's sender and the gateway
/// alike, and a loss is no small thing (the network manager takes the
/// node up again). Lely's `dcfgen` sets consumer times at 3 × the
/// producer's (its `heartbeat_multiplier`); so does candeck by default.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ConsumerFactor {
    tenths: u16,
}

impl ConsumerFactor {
    /// The default: 3 periods.
    pub const DEFAULT: Self = Self { tenths: 30 };
    /// The least: one period and a half (less is lost at every jitter).
    pub const MIN: Self = Self { tenths: 15 };
    /// The most: 10 periods.
    pub const MAX: Self = Self { tenths: 100 };

    /// The factor `value`, to a tenth; an error names the range.
    pub fn new(value: f64) -> Result<Self, String> {
        let range = || {
            format!(
                "heartbeat_consumer_factor = {value}: must be {} to {} (periods of a node's heartbeat before it is lost)",
                Self::MIN,
                Self::MAX
            )
        };
        if !value.is_finite() {
            return Err(range());
        }
        let tenths = (value * 10.0).round();
        if tenths < f64::from(Self::MIN.tenths) || tenths > f64::from(Self::MAX.tenths) {
            return Err(range());
        }
        Ok(Self {
            tenths: tenths as u16,
        })
    }

    /// The factor as a number.
    pub fn get(self) -> f64 {
        f64::from(self.tenths) / 10.0
    }

    /// How long after its last heartbeat a node with producer period
    /// `period` is lost.
    pub fn timeout(self, period: Duration) -> Duration {
        period * u32::from(self.tenths) / 10
    }
}

impl Default for ConsumerFactor {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl std::fmt::Display for ConsumerFactor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{}", self.tenths / 10, self.tenths % 10)
    }
}

/// What lost a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LostBy {
    /// No heartbeat within the consumer factor × `period`.
    Heartbeat { period: Duration },
    /// No valid node-guarding reply within the node life time.
    Guarding { life_time: Duration },
}

/// Why a node went offline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum OfflineCause {
    Lost(LostBy),
    /// The bus went down: nothing can reach the node.
    BusDown,
    /// A node without heartbeat did not answer a probe.
    NoAnswer,
}

/// What the supervisor decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SupervisorEvent {
    /// A heartbeat or a valid node-guarding reply (not a boot-up) came.
    Heard {
        node: NodeId,
        nmt: NmtState,
    },
    /// The node sent its boot-up message: it was (re)started.
    BootUp {
        node: NodeId,
    },
    /// Its NMT state changed (`from` is `None` the first time).
    Nmt {
        node: NodeId,
        from: Option<NmtState>,
        to: NmtState,
    },
    /// Its supervision deadline passed; reported once until it is heard
    /// again or its supervision is set anew.
    Lost {
        node: NodeId,
        by: LostBy,
    },
    /// A lost node was heard again (not by a boot-up, which says more).
    Recovered {
        node: NodeId,
    },
    Online {
        node: NodeId,
    },
    Offline {
        node: NodeId,
        cause: OfflineCause,
    },
    /// Its producer heartbeat time (0x1017) was written `ms` and the node
    /// confirmed it: it is supervised with that period from now on (0:
    /// none).
    HeartbeatWritten {
        node: NodeId,
        heartbeat_ms: u16,
    },
}

impl SupervisorEvent {
    pub fn node(&self) -> NodeId {
        match *self {
            Self::Heard { node, .. }
            | Self::BootUp { node }
            | Self::Nmt { node, .. }
            | Self::Lost { node, .. }
            | Self::Recovered { node }
            | Self::Online { node }
            | Self::Offline { node, .. }
            | Self::HeartbeatWritten { node, .. } => node,
        }
    }
}

/// The producer period of a node, learnt from its heartbeats.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
struct HeartbeatLearner {
    last: Option<Instant>,
    intervals: VecDeque<Duration>,
    period: Option<Duration>,
}

impl HeartbeatLearner {
    /// Takes a heartbeat at `now`; the new period if it changed.
    fn on_heartbeat(&mut self, now: Instant, factor: ConsumerFactor) -> Option<Duration> {
        let last = self.last.replace(now);
        let interval = now.saturating_duration_since(last?);
        if interval < MIN_HEARTBEAT_INTERVAL {
            return None;
        }
        if self.intervals.len() == HEARTBEAT_WINDOW {
            self.intervals.pop_front();
        }
        self.intervals.push_back(interval);
        if let Some(period) = self.period
            && self.intervals.len() >= SLOWER_AFTER
            && self
                .intervals
                .iter()
                .rev()
                .take(SLOWER_AFTER)
                .all(|&recent| recent > factor.timeout(period))
        {
            let keep = self.intervals.len() - SLOWER_AFTER;
            self.intervals.drain(..keep);
        }
        if let Some(period) = self.period {
            // Faster only when several intervals in a row say so: after a
            // stall the late heartbeat and the next one on time come close
            // together, and one short interval taken as the period lost
            // the node at every heartbeat until it left the window.
            let faster = period - period / JITTER_PART;
            if self.intervals.iter().any(|&interval| interval < faster) {
                if self.intervals.len() < FASTER_AFTER
                    || self
                        .intervals
                        .iter()
                        .rev()
                        .take(FASTER_AFTER)
                        .any(|&recent| recent >= faster)
                {
                    // Not (yet) a faster producer: a burst (it leaves
                    // the window in time), or the start of a change.
                    return None;
                }
                let keep = self.intervals.len() - FASTER_AFTER;
                self.intervals.drain(..keep);
            }
        }
        let shortest = self.intervals.iter().min().copied();
        if shortest == self.period {
            return None;
        }
        if let (Some(period), Some(shortest)) = (self.period, shortest)
            && shortest.abs_diff(period) <= period / JITTER_PART
        {
            return None;
        }
        self.period = shortest;
        shortest
    }

    /// The node's 0x1017 says `period`: it replaces what was learnt.
    fn set_period(&mut self, period: Duration) {
        self.intervals.clear();
        self.period = Some(period);
    }

    /// The node's 0x1017 was written `period` (0: off, `None`): it
    /// replaces what was learnt, and the interval that spans the change
    /// (half old period, half new) does not count.
    fn written(&mut self, period: Option<Duration>) {
        self.last = None;
        self.intervals.clear();
        self.period = period;
    }

    /// The next interval does not count (the bus was down): what was
    /// learnt of the period stays. A heartbeat that is merely late is no
    /// reason: its interval is the producer's, maybe a new one.
    fn restart(&mut self) {
        self.last = None;
        self.intervals.clear();
    }
}

/// What the supervisor knows of one node.
#[derive(Debug, Clone)]
struct Watch {
    nmt: Option<NmtState>,
    online: bool,
    /// The last frame of any kind from the node.
    last_seen: Instant,
    learner: HeartbeatLearner,
    /// Since when its heartbeat timeout runs: its last heartbeat, or the
    /// read or write of its 0x1017; `None` after a boot-up, until it sends
    /// heartbeats again.
    since: Option<Instant>,
    /// Its heartbeat deadline passed and it was not heard since.
    lost: bool,
    /// Node guarding, set up by the manager: it decides loss instead of
    /// the heartbeat.
    guard: Option<NodeGuardMaster>,
}

impl Watch {
    fn new(now: Instant) -> Self {
        Self {
            nmt: None,
            online: true,
            last_seen: now,
            learner: HeartbeatLearner::default(),
            since: None,
            lost: false,
            guard: None,
        }
    }

    fn supervised(&self) -> bool {
        self.learner.period.is_some() || self.guard.is_some()
    }

    /// When the node's heartbeat is due at the latest; `None` when it is
    /// not timed by its heartbeat (guarded, no period, lost, booting).
    fn heartbeat_deadline(&self, factor: ConsumerFactor) -> Option<Instant> {
        if self.lost || self.guard.is_some() {
            return None;
        }
        Some(self.since? + factor.timeout(self.learner.period?))
    }
}

/// One node's supervision, as the supervisor sees it now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NodeSupervision {
    /// The last NMT state it reported (or, after its boot-up and an SDO
    /// answer, is known to be in).
    pub nmt: Option<NmtState>,
    pub online: bool,
    /// When its last frame of any kind came.
    pub last_seen: Instant,
    /// The producer heartbeat period it is supervised with; `None` while it
    /// sends no heartbeat.
    pub heartbeat: Option<Duration>,
    /// Its supervision deadline passed and it was not heard since.
    pub lost: bool,
    /// When it must be heard at the latest; `None` when not timed.
    pub deadline: Option<Instant>,
    /// Guarded by the manager.
    pub guarded: bool,
}

/// The supervisor of a bus's nodes. See the module documentation.
#[derive(Debug, Clone)]
pub struct Supervisor {
    nodes: BTreeMap<NodeId, Watch>,
    bus_up: bool,
    events: Vec<SupervisorEvent>,
    /// Heartbeat periods a node may be silent before it is lost.
    factor: ConsumerFactor,
}

impl Default for Supervisor {
    fn default() -> Self {
        Self::new(true)
    }
}

impl Supervisor {
    /// A supervisor of no node yet, on a bus that is up (or not).
    pub fn new(bus_up: bool) -> Self {
        Self {
            nodes: BTreeMap::new(),
            bus_up,
            events: Vec::new(),
            factor: ConsumerFactor::DEFAULT,
        }
    }

    /// The supervisor, losing a node after `factor` heartbeat periods of
    /// silence.
    pub fn with_consumer_factor(mut self, factor: ConsumerFactor) -> Self {
        self.factor = factor;
        self
    }

    /// Heartbeat periods a node may be silent before it is lost.
    pub fn consumer_factor(&self) -> ConsumerFactor {
        self.factor
    }

    /// Whether [`Supervisor::on_frame`] takes `frame`: the error-control
    /// frames (boot-up, heartbeat, node-guarding reply) only.
    pub fn hears(frame: &Frame) -> bool {
        heartbeat_node(frame.id()).is_some() && !frame.is_remote()
    }

    /// Starts following `node` at `now` (heard, or found by a probe);
    /// whether it is new. A new node is online.
    pub fn watch(&mut self, node: NodeId, now: Instant) -> bool {
        let mut new = false;
        self.nodes.entry(node).or_insert_with(|| {
            new = true;
            Watch::new(now)
        });
        new
    }

    /// Forgets `node` altogether (its device moved to another node-ID).
    pub fn forget(&mut self, node: NodeId) {
        self.nodes.remove(&node);
    }

    /// The node as the supervisor sees it; `None` if never watched.
    pub fn node(&self, node: NodeId) -> Option<NodeSupervision> {
        let watch = self.nodes.get(&node)?;
        Some(NodeSupervision {
            nmt: watch.nmt,
            online: watch.online,
            last_seen: watch.last_seen,
            heartbeat: watch.learner.period,
            lost: watch.lost || watch.guard.as_ref().is_some_and(NodeGuardMaster::is_lost),
            deadline: Self::node_deadline(watch, self.factor),
            guarded: watch.guard.is_some(),
        })
    }

    /// Takes an error-control frame of the bus (others are ignored); a
    /// malformed one is an error and changes nothing.
    pub fn on_frame(
        &mut self,
        frame: &Frame,
        now: Instant,
    ) -> Result<(), super::super::heartbeat::HeartbeatError> {
        if !Self::hears(frame) {
            return Ok(());
        }
        let Heartbeat { node, state } = Heartbeat::decode(frame)?;
        let bus_up = self.bus_up;
        let factor = self.factor;
        let watch = self.nodes.entry(node).or_insert_with(|| Watch::new(now));
        watch.last_seen = now;
        let boot_up = state == NmtState::BootUp;
        // A guarded node is heard by its valid replies (and its boot-up).
        let mut valid = true;
        let mut recovered = false;
        if let Some(guard) = watch.guard.as_mut() {
            let before = guard.last_seen();
            let guard_events = guard.on_frame(frame, now).unwrap_or_default();
            recovered = guard_events
                .iter()
                .any(|event| matches!(event, HeartbeatEvent::Recovered { .. }));
            valid = boot_up || guard.last_seen() != before;
        } else if std::mem::take(&mut watch.lost) {
            recovered = true;
        }
        let from = watch.nmt.replace(state);
        if boot_up {
            // Its 0x1017 is reloaded: not timed until it sends heartbeats
            // again, with a period to learn.
            watch.learner = HeartbeatLearner::default();
            watch.since = None;
            watch.lost = false;
        } else {
            watch.learner.on_heartbeat(now, factor);
            if valid {
                watch.since = Some(now);
            }
        }
        let online = !watch.online && bus_up && valid;
        if online {
            watch.online = true;
        }
        if recovered && !boot_up {
            self.events.push(SupervisorEvent::Recovered { node });
        }
        if from != Some(state) {
            self.events.push(SupervisorEvent::Nmt {
                node,
                from,
                to: state,
            });
        }
        if boot_up {
            self.events.push(SupervisorEvent::BootUp { node });
        } else if valid {
            self.events
                .push(SupervisorEvent::Heard { node, nmt: state });
        }
        if online {
            self.events.push(SupervisorEvent::Online { node });
        }
        Ok(())
    }

    /// Another frame of `node` (a PDO, an SDO answer, an EMCY) came at
    /// `now`: it is there. Online by it only when not supervised.
    pub fn heard(&mut self, node: NodeId, now: Instant) {
        let bus_up = self.bus_up;
        let watch = self.nodes.entry(node).or_insert_with(|| Watch::new(now));
        watch.last_seen = now;
        if !watch.online && bus_up && !watch.supervised() {
            watch.online = true;
            self.events.push(SupervisorEvent::Online { node });
        }
    }

    /// A probe of `node` got no answer: a node without supervision that
    /// is online goes offline (a stopped node does no SDO: its silence
    /// says nothing).
    pub fn no_answer(&mut self, node: NodeId) {
        if let Some(watch) = self.nodes.get_mut(&node)
            && watch.online
            && !watch.supervised()
            && watch.nmt != Some(NmtState::Stopped)
        {
            watch.online = false;
            self.events.push(SupervisorEvent::Offline {
                node,
                cause: OfflineCause::NoAnswer,
            });
        }
    }

    /// The node answered an SDO request: a node that sent its boot-up is
    /// pre-operational (the boot-up is sent on entering that state, and a
    /// stopped node does no SDO).
    pub fn answered(&mut self, node: NodeId) {
        if let Some(watch) = self.nodes.get_mut(&node)
            && watch.nmt == Some(NmtState::BootUp)
        {
            watch.nmt = Some(NmtState::PreOperational);
            self.events.push(SupervisorEvent::Nmt {
                node,
                from: Some(NmtState::BootUp),
                to: NmtState::PreOperational,
            });
        }
    }

    /// The node's 0x1017 was read `ms` at `now` (0: no heartbeat, which
    /// changes nothing): it is supervised with that period, its next
    /// heartbeat due within the consumer factor × the period.
    pub fn heartbeat_read(&mut self, node: NodeId, ms: u16, now: Instant) {
        if ms == 0 {
            return;
        }
        let watch = self.nodes.entry(node).or_insert_with(|| Watch::new(now));
        watch
            .learner
            .set_period(Duration::from_millis(u64::from(ms)));
        watch.since = Some(now);
    }

    /// The node confirmed a write of `ms` into its 0x1017 at `now`: it is
    /// supervised with that period from now on, at once (its next heartbeat
    /// is one new period away), rather than lost at every heartbeat until
    /// the slower period is learnt; 0 (no heartbeat): unsupervised by
    /// heartbeat, online from any frame it sends.
    pub fn heartbeat_written(&mut self, node: NodeId, ms: u16, now: Instant) {
        let Some(watch) = self.nodes.get_mut(&node) else {
            return;
        };
        let period = (ms > 0).then(|| Duration::from_millis(u64::from(ms)));
        watch.learner.written(period);
        // It answered the write: the new deadline runs from now.
        watch.since = period.map(|_| now);
        watch.lost = false;
        self.events.push(SupervisorEvent::HeartbeatWritten {
            node,
            heartbeat_ms: ms,
        });
    }

    /// The manager guards `node` from `now` on with the guard time (ms)
    /// and life time factor it wrote to 0x100C and 0x100D: the node is lost
    /// when no valid reply comes within the life time, and its heartbeat
    /// is not timed meanwhile.
    pub fn guard(&mut self, node: NodeId, guard_time_ms: u16, life_time_factor: u8, now: Instant) {
        let watch = self.nodes.entry(node).or_insert_with(|| Watch::new(now));
        let mut guard = NodeGuardMaster::new(node, guard_time_ms, life_time_factor);
        guard.start(now);
        watch.guard = Some(guard);
        watch.lost = false;
    }

    /// The manager stopped guarding `node` (it boots it again).
    pub fn unguard(&mut self, node: NodeId, now: Instant) {
        if let Some(watch) = self.nodes.get_mut(&node)
            && watch.guard.take().is_some()
        {
            // Timed by its heartbeat again, if it has a period, from now.
            watch.since = Some(now);
        }
    }

    /// The bus went down (`false`) or came up at `now`. Down, every node is
    /// offline; what was learnt of a period stays, but the interval that
    /// spans the outage does not count.
    pub fn bus_up(&mut self, up: bool) {
        if self.bus_up == up {
            return;
        }
        self.bus_up = up;
        if up {
            return;
        }
        for (&node, watch) in &mut self.nodes {
            watch.learner.restart();
            if watch.online {
                watch.online = false;
                self.events.push(SupervisorEvent::Offline {
                    node,
                    cause: OfflineCause::BusDown,
                });
            }
        }
    }

    /// Whether the bus is up, as last told.
    pub fn is_bus_up(&self) -> bool {
        self.bus_up
    }

    /// Due work at `now`: node-guarding requests to send, and the nodes
    /// whose deadline passed (as events).
    #[must_use = "the guarding requests must be sent"]
    pub fn poll(&mut self, now: Instant) -> Vec<Frame> {
        let mut requests = Vec::new();
        for (&node, watch) in &mut self.nodes {
            let mut lost = None;
            if let Some(guard) = watch.guard.as_mut() {
                let polled = guard.poll(now);
                requests.extend(polled.request);
                if polled.event.is_some() {
                    lost = Some(LostBy::Guarding {
                        life_time: guard.life_time().unwrap_or_default(),
                    });
                }
            } else if watch
                .heartbeat_deadline(self.factor)
                .is_some_and(|deadline| now >= deadline)
            {
                watch.lost = true;
                lost = watch
                    .learner
                    .period
                    .map(|period| LostBy::Heartbeat { period });
            }
            let Some(by) = lost else {
                continue;
            };
            self.events.push(SupervisorEvent::Lost { node, by });
            if watch.online {
                watch.online = false;
                self.events.push(SupervisorEvent::Offline {
                    node,
                    cause: OfflineCause::Lost(by),
                });
            }
        }
        requests
    }

    fn node_deadline(watch: &Watch, factor: ConsumerFactor) -> Option<Instant> {
        match &watch.guard {
            Some(guard) => guard.deadline(),
            None => watch.heartbeat_deadline(factor),
        }
    }

    /// When [`Supervisor::poll`] has work next.
    pub fn deadline(&self) -> Option<Instant> {
        self.nodes
            .values()
            .filter_map(|watch| Self::node_deadline(watch, self.factor))
            .min()
    }

    /// What the supervisor decided since the last call, in order.
    pub fn take_events(&mut self) -> Vec<SupervisorEvent> {
        std::mem::take(&mut self.events)
    }
}
