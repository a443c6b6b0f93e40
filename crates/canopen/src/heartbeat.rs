//! NMT error control (CiA 301 §7.2.8.3.2): the heartbeat protocol, producer
//! (0x1017) and consumer (0x1016), and the older node-guarding protocol with
//! life guarding (0x100C guard time, 0x100D life time factor).
//!
//! Both run on COB-ID 0x700 + node, the COB-ID of the boot-up message.
//! A heartbeat is one data byte: the NMT state, bit 7 reserved. In node
//! guarding the master sends a remote frame and the slave replies with one
//! byte: bit 7 a toggle bit that alternates with every reply (0 in the first
//! one after a reset), bits 0–6 its NMT state.
//!
//! The heartbeat consumer and the node-guarding master report the same
//! [`HeartbeatEvent`]s, so whoever supervises nodes handles both alike.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use super::cob::{Function, NodeId};
use super::nmt::NmtState;
use crate::can::{CanId, Frame};

/// Bit 7 of a node-guarding reply; reserved (0) in a heartbeat.
const TOGGLE_BIT: u8 = 0x80;
/// Bits 0–6: the NMT state.
const STATE_BITS: u8 = 0x7F;

/// Why a frame is not a well-formed heartbeat or node-guarding reply.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum HeartbeatError {
    #[error("identifier {0} is not a heartbeat COB-ID (701 to 77F)")]
    NotHeartbeat(CanId),
    #[error("a remote frame on {0} is a node-guarding request, not a state")]
    Remote(CanId),
    #[error("a heartbeat or node-guarding reply has 1 data byte, not {0}")]
    Length(usize),
}

/// The node a heartbeat COB-ID belongs to.
pub fn heartbeat_node(id: CanId) -> Option<NodeId> {
    match Function::classify(id) {
        Some((Function::Heartbeat, node)) => node,
        _ => None,
    }
}

/// The one state byte of a heartbeat or node-guarding reply, and its node.
fn state_byte(frame: &Frame) -> Result<(NodeId, u8), HeartbeatError> {
    let node = heartbeat_node(frame.id()).ok_or(HeartbeatError::NotHeartbeat(frame.id()))?;
    if frame.is_remote() {
        return Err(HeartbeatError::Remote(frame.id()));
    }
    match frame.data() {
        &[byte] => Ok((node, byte)),
        data => Err(HeartbeatError::Length(data.len())),
    }
}

fn one_byte_frame(node: NodeId, byte: u8) -> Frame {
    Frame::new(Function::Heartbeat.can_id(node), &[byte]).expect("one byte fits a frame")
}

/// A heartbeat (or boot-up, state [`NmtState::BootUp`]) message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Heartbeat {
    pub node: NodeId,
    pub state: NmtState,
}

impl Heartbeat {
    pub fn new(node: NodeId, state: NmtState) -> Self {
        Self { node, state }
    }

    pub fn encode(self) -> Frame {
        one_byte_frame(self.node, self.state.raw())
    }

    /// Reads a heartbeat. Bit 7 is reserved in a heartbeat but is the toggle
    /// bit of a node-guarding reply on the same COB-ID, so it is ignored:
    /// either way bits 0–6 are the state.
    pub fn decode(frame: &Frame) -> Result<Self, HeartbeatError> {
        let (node, byte) = state_byte(frame)?;
        Ok(Self {
            node,
            state: NmtState::from_raw(byte & STATE_BITS),
        })
    }
}

/// The node-guarding request a master sends: a remote frame on 0x700 + node
/// asking for the one-byte reply.
pub fn guard_request(node: NodeId) -> Frame {
    Frame::remote(Function::Heartbeat.can_id(node), 1).expect("a DLC of 1 is valid")
}

/// A node-guarding reply: toggle bit and NMT state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct GuardReply {
    pub node: NodeId,
    pub toggle: bool,
    pub state: NmtState,
}

impl GuardReply {
    pub fn encode(self) -> Frame {
        let toggle = if self.toggle { TOGGLE_BIT } else { 0 };
        one_byte_frame(self.node, toggle | (self.state.raw() & STATE_BITS))
    }

    pub fn decode(frame: &Frame) -> Result<Self, HeartbeatError> {
        let (node, byte) = state_byte(frame)?;
        Ok(Self {
            node,
            toggle: byte & TOGGLE_BIT != 0,
            state: NmtState::from_raw(byte & STATE_BITS),
        })
    }
}

/// The next deadline of a periodic timer that fired at `due`, seen at `now`:
/// one period on, or one period from `now` if it fell a whole period or more
/// behind, so a late caller gets one message, not a burst of the missed ones.
fn next_period(due: Instant, period: Duration, now: Instant) -> Instant {
    let next = due + period;
    if next <= now { now + period } else { next }
}

/// The heartbeat producer of a device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HeartbeatProducer {
    node: NodeId,
    period: Option<Duration>,
    next: Option<Instant>,
}

impl HeartbeatProducer {
    /// A producer that is off (0x1017 = 0).
    pub fn new(node: NodeId) -> Self {
        Self {
            node,
            period: None,
            next: None,
        }
    }

    /// Sets the producer heartbeat time (0x1017, in ms; 0 turns it off). The
    /// next heartbeat is one period from `now`: the boot-up message, or the
    /// previous period's heartbeat, stands for the one at `now`.
    pub fn set_period_ms(&mut self, period_ms: u16, now: Instant) {
        self.period = (period_ms > 0).then(|| Duration::from_millis(u64::from(period_ms)));
        self.next = self.period.map(|period| now + period);
    }

    pub fn period(&self) -> Option<Duration> {
        self.period
    }

    /// When the next heartbeat is due; `None` while off.
    pub fn deadline(&self) -> Option<Instant> {
        self.next
    }

    /// The heartbeat to send if one is due at `now`, carrying `state`.
    #[must_use = "the frame must be sent"]
    pub fn poll(&mut self, now: Instant, state: NmtState) -> Option<Frame> {
        let (period, due) = (self.period?, self.next?);
        if now < due {
            return None;
        }
        self.next = Some(next_period(due, period, now));
        Some(Heartbeat::new(self.node, state).encode())
    }
}

/// One entry of the consumer heartbeat time array 0x1016: bits 16–23 the
/// node id, bits 0–15 the consumer time in ms. Bits 24–31 are reserved and
/// dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ConsumerTime {
    pub node: u8,
    pub time_ms: u16,
}

impl ConsumerTime {
    pub fn from_raw(raw: u32) -> Self {
        Self {
            node: (raw >> 16) as u8,
            time_ms: raw as u16,
        }
    }

    pub fn raw(self) -> u32 {
        u32::from(self.node) << 16 | u32::from(self.time_ms)
    }

    /// The node and timeout this entry asks to monitor; `None` for an unused
    /// entry (node id or time 0) or a node id above 127.
    pub fn monitored(self) -> Option<(NodeId, Duration)> {
        let node = NodeId::new(self.node).ok()?;
        (self.time_ms > 0).then(|| (node, Duration::from_millis(u64::from(self.time_ms))))
    }
}

/// What the supervision of a node (heartbeat consumer or node-guarding
/// master) saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HeartbeatEvent {
    /// The node sent its boot-up message: it was (re)started.
    BootUp { node: NodeId },
    /// The node reported another state than before (`from` is `None` the
    /// first time it is heard).
    StateChanged {
        node: NodeId,
        from: Option<NmtState>,
        to: NmtState,
    },
    /// Nothing was heard from the node within its timeout (heartbeat event /
    /// node guarding event of CiA 301).
    Lost { node: NodeId },
    /// A node that was lost was heard again, in `state`.
    Recovered { node: NodeId, state: NmtState },
}

impl HeartbeatEvent {
    pub fn node(&self) -> NodeId {
        match *self {
            Self::BootUp { node }
            | Self::StateChanged { node, .. }
            | Self::Lost { node }
            | Self::Recovered { node, .. } => node,
        }
    }
}

#[derive(Debug, Clone, Default, PartialEq, Eq)]
struct Watched {
    /// `None`: the state is tracked, but silence is not a fault.
    timeout: Option<Duration>,
    state: Option<NmtState>,
    last_seen: Option<Instant>,
    /// Since when the timeout runs: the last heartbeat, or [`HeartbeatConsumer::arm`].
    since: Option<Instant>,
    lost: bool,
}

impl Watched {
    fn deadline(&self) -> Option<Instant> {
        if self.lost {
            return None;
        }
        Some(self.since? + self.timeout?)
    }
}

/// The heartbeat consumer: the state of every node it hears, and a timeout
/// per monitored node.
///
/// As CiA 301 specifies, a node's timeout runs from its first heartbeat on
/// (or from [`arm`](Self::arm), for a master that knows the node is there).
/// A boot-up message stops it until the next heartbeat, because a node that
/// has just reset sends heartbeats only once it is configured again.
/// Heartbeats of nodes that are not monitored are tracked without a timeout,
/// so a master learns of nodes that boot.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct HeartbeatConsumer {
    nodes: BTreeMap<NodeId, Watched>,
}

impl HeartbeatConsumer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Monitors `node` with `timeout` (the consumer heartbeat time of 0x1016;
    /// zero tracks the state without a timeout). What was already seen of the
    /// node is kept.
    pub fn monitor(&mut self, node: NodeId, timeout: Duration) {
        self.nodes.entry(node).or_default().timeout = (!timeout.is_zero()).then_some(timeout);
    }

    /// Monitors `node` whose producer heartbeat time (its 0x1017) is
    /// `period`, with half a period of margin for bus load and jitter.
    pub fn monitor_producer(&mut self, node: NodeId, period: Duration) {
        self.monitor(node, period + period / 2);
    }

    /// Forgets `node` altogether.
    pub fn unmonitor(&mut self, node: NodeId) {
        self.nodes.remove(&node);
    }

    /// Starts the timeout of a monitored node at `now`, before its first
    /// heartbeat.
    pub fn arm(&mut self, node: NodeId, now: Instant) {
        if let Some(watched) = self.nodes.get_mut(&node) {
            watched.since = Some(now);
        }
    }

    /// Takes any received frame. Frames of other services and node-guarding
    /// requests (remote frames) give nothing; a malformed heartbeat is an
    /// error and is otherwise ignored.
    pub fn on_frame(
        &mut self,
        frame: &Frame,
        now: Instant,
    ) -> Result<Vec<HeartbeatEvent>, HeartbeatError> {
        if heartbeat_node(frame.id()).is_none() || frame.is_remote() {
            return Ok(Vec::new());
        }
        Ok(self.on_heartbeat(Heartbeat::decode(frame)?, now))
    }

    /// Takes a decoded heartbeat or boot-up message.
    pub fn on_heartbeat(&mut self, heartbeat: Heartbeat, now: Instant) -> Vec<HeartbeatEvent> {
        let Heartbeat { node, state } = heartbeat;
        let watched = self.nodes.entry(node).or_default();
        let mut events = Vec::new();
        if std::mem::take(&mut watched.lost) {
            events.push(HeartbeatEvent::Recovered { node, state });
        }
        let from = watched.state.replace(state);
        watched.last_seen = Some(now);
        if state == NmtState::BootUp {
            watched.since = None;
            events.push(HeartbeatEvent::BootUp { node });
        } else {
            watched.since = Some(now);
            if from != Some(state) {
                events.push(HeartbeatEvent::StateChanged {
                    node,
                    from,
                    to: state,
                });
            }
        }
        events
    }

    /// Reports the monitored nodes whose timeout has passed at `now`, once
    /// each until they are heard again.
    pub fn poll(&mut self, now: Instant) -> Vec<HeartbeatEvent> {
        let mut events = Vec::new();
        for (&node, watched) in &mut self.nodes {
            if watched.deadline().is_some_and(|deadline| now >= deadline) {
                watched.lost = true;
                events.push(HeartbeatEvent::Lost { node });
            }
        }
        events
    }

    /// The earliest timeout of a monitored node that is not lost.
    pub fn deadline(&self) -> Option<Instant> {
        self.nodes.values().filter_map(Watched::deadline).min()
    }

    /// The last state `node` reported.
    pub fn state(&self, node: NodeId) -> Option<NmtState> {
        self.nodes.get(&node)?.state
    }

    pub fn last_seen(&self, node: NodeId) -> Option<Instant> {
        self.nodes.get(&node)?.last_seen
    }

    pub fn is_lost(&self, node: NodeId) -> bool {
        self.nodes.get(&node).is_some_and(|watched| watched.lost)
    }

    /// Every node heard or monitored.
    pub fn nodes(&self) -> impl Iterator<Item = NodeId> + '_ {
        self.nodes.keys().copied()
    }
}

/// What [`NodeGuardMaster::poll`] gives out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GuardPoll {
    /// The remote frame to send.
    pub request: Option<Frame>,
    /// [`HeartbeatEvent::Lost`] when the node's life time has passed.
    pub event: Option<HeartbeatEvent>,
}

/// The master side of node guarding for one node: a remote request every
/// guard time; the node is lost when no valid reply came for the node life
/// time, guard time × life time factor (CiA 301 §7.2.8.3.2.1), counted from
/// its last valid reply (or from the start). So a node that falls silent is
/// reported lost within the node life time of its last word, whenever in
/// the guard cycle that was; [`deadline`](Self::deadline) includes the
/// instant it will be.
///
/// A reply is valid when its toggle bit is the opposite of the previous
/// valid reply's. The first reply is taken whatever its toggle (the master
/// may have started after the node). A reply lost on the bus makes the next
/// one look repeated, but the one after it is valid again, so it costs one
/// missed request, not the node. A boot-up message (0x00) means the node
/// restarted: its next reply has toggle 0.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeGuardMaster {
    node: NodeId,
    guard_time: Option<Duration>,
    life_time_factor: u8,
    next_request: Option<Instant>,
    awaiting_reply: bool,
    /// The last valid reply, boot-up or start: the node life time runs from
    /// here.
    alive_since: Option<Instant>,
    expected_toggle: Option<bool>,
    state: Option<NmtState>,
    last_seen: Option<Instant>,
    lost: bool,
}

impl NodeGuardMaster {
    /// Guarding of `node` with the guard time (ms) and life time factor
    /// written to its 0x100C and 0x100D; either 0 turns guarding off. It
    /// starts with [`start`](Self::start).
    pub fn new(node: NodeId, guard_time_ms: u16, life_time_factor: u8) -> Self {
        let on = guard_time_ms > 0 && life_time_factor > 0;
        Self {
            node,
            guard_time: on.then(|| Duration::from_millis(u64::from(guard_time_ms))),
            life_time_factor,
            next_request: None,
            awaiting_reply: false,
            alive_since: None,
            expected_toggle: None,
            state: None,
            last_seen: None,
            lost: false,
        }
    }

    pub fn node(&self) -> NodeId {
        self.node
    }

    /// Guard time × life time factor; `None` when guarding is off.
    pub fn life_time(&self) -> Option<Duration> {
        Some(self.guard_time? * u32::from(self.life_time_factor))
    }

    /// Starts guarding: the first request is due at `now`.
    pub fn start(&mut self, now: Instant) {
        if self.guard_time.is_some() {
            self.next_request = Some(now);
            self.alive_since = Some(now);
        }
    }

    pub fn stop(&mut self) {
        self.next_request = None;
        self.awaiting_reply = false;
        self.alive_since = None;
    }

    /// After the master reset the node: its next reply has toggle 0.
    pub fn reset_toggle(&mut self) {
        self.expected_toggle = Some(false);
    }

    /// When [`poll`](Self::poll) has work next: the next request, or the
    /// end of the node life time if that comes first.
    pub fn deadline(&self) -> Option<Instant> {
        let request = self.next_request?;
        Some(match self.loss_deadline() {
            Some(loss) => request.min(loss),
            None => request,
        })
    }

    /// When the node will be lost if nothing valid comes; `None` once lost.
    fn loss_deadline(&self) -> Option<Instant> {
        if self.lost {
            return None;
        }
        Some(self.alive_since? + self.life_time()?)
    }

    #[must_use = "the frame must be sent"]
    pub fn poll(&mut self, now: Instant) -> GuardPoll {
        let (Some(period), Some(due)) = (self.guard_time, self.next_request) else {
            return GuardPoll::default();
        };
        let mut event = None;
        if self.loss_deadline().is_some_and(|loss| now >= loss) {
            self.lost = true;
            event = Some(HeartbeatEvent::Lost { node: self.node });
        }
        if now < due {
            return GuardPoll {
                request: None,
                event,
            };
        }
        self.awaiting_reply = true;
        self.next_request = Some(next_period(due, period, now));
        GuardPoll {
            request: Some(guard_request(self.node)),
            event,
        }
    }

    /// Takes any received frame; only this node's one-byte replies and
    /// boot-up count. Unsolicited bytes other than boot-up (the node's
    /// heartbeat, say) are ignored.
    pub fn on_frame(
        &mut self,
        frame: &Frame,
        now: Instant,
    ) -> Result<Vec<HeartbeatEvent>, HeartbeatError> {
        if heartbeat_node(frame.id()) != Some(self.node) || frame.is_remote() {
            return Ok(Vec::new());
        }
        let reply = GuardReply::decode(frame)?;
        let node = self.node;
        let mut events = Vec::new();
        if !reply.toggle && reply.state == NmtState::BootUp {
            // A node replies only once initialised, so 0x00 is its boot-up:
            // it is alive, and counts its toggle from 0 again.
            self.expected_toggle = Some(false);
            self.awaiting_reply = false;
            self.alive_since = Some(now);
            self.last_seen = Some(now);
            if std::mem::take(&mut self.lost) {
                events.push(HeartbeatEvent::Recovered {
                    node,
                    state: NmtState::BootUp,
                });
            }
            self.state = Some(NmtState::BootUp);
            events.push(HeartbeatEvent::BootUp { node });
            return Ok(events);
        }
        if !self.awaiting_reply {
            return Ok(events);
        }
        if self
            .expected_toggle
            .is_some_and(|expected| expected != reply.toggle)
        {
            return Ok(events);
        }
        self.expected_toggle = Some(!reply.toggle);
        self.awaiting_reply = false;
        self.alive_since = Some(now);
        self.last_seen = Some(now);
        if std::mem::take(&mut self.lost) {
            events.push(HeartbeatEvent::Recovered {
                node,
                state: reply.state,
            });
        }
        let from = self.state.replace(reply.state);
        if from != Some(reply.state) {
            events.push(HeartbeatEvent::StateChanged {
                node,
                from,
                to: reply.state,
            });
        }
        Ok(events)
    }

    /// The state of the last valid reply.
    pub fn state(&self) -> Option<NmtState> {
        self.state
    }

    /// When the last valid reply (or boot-up) came.
    pub fn last_seen(&self) -> Option<Instant> {
        self.last_seen
    }

    pub fn is_lost(&self) -> bool {
        self.lost
    }
}

/// A life guarding event of a slave (CiA 301 §7.2.8.3.2.1). A device
/// signals `Lost` with EMCY 0x8130 (life guard error) and `Recovered` with
/// an error reset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LifeGuardEvent {
    /// No guarding request within the node life time.
    Lost,
    /// Requests came again after `Lost`.
    Recovered,
}

/// What [`LifeGuard::on_frame`] gives out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LifeGuardOutput {
    /// The node-guarding reply to send.
    pub reply: Option<Frame>,
    pub event: Option<LifeGuardEvent>,
}

/// The slave side of node guarding: it answers every request with the
/// toggled state byte, and, when guard time and life time factor are both
/// set, watches that requests keep coming (life guarding). Watching starts
/// with the first request, as CiA 301 specifies.
///
/// The heartbeat takes precedence (UMC manual §4.2): a device whose 0x1017
/// is not 0 does not feed requests to this guard.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LifeGuard {
    node: NodeId,
    life_time: Option<Duration>,
    toggle: bool,
    deadline: Option<Instant>,
    lost: bool,
}

impl LifeGuard {
    /// Answers requests; life guarding off until [`configure`](Self::configure).
    pub fn new(node: NodeId) -> Self {
        Self {
            node,
            life_time: None,
            toggle: false,
            deadline: None,
            lost: false,
        }
    }

    /// Sets the guard time (0x100C, ms) and life time factor (0x100D); either
    /// 0 turns life guarding off. If it is watching, the new life time runs
    /// from `now`.
    pub fn configure(&mut self, guard_time_ms: u16, life_time_factor: u8, now: Instant) {
        let life_time = u64::from(guard_time_ms) * u64::from(life_time_factor);
        self.life_time = (life_time > 0).then(|| Duration::from_millis(life_time));
        self.deadline = match self.life_time {
            Some(life_time) if self.deadline.is_some() => Some(now + life_time),
            _ => None,
        };
    }

    pub fn life_time(&self) -> Option<Duration> {
        self.life_time
    }

    /// After an NMT reset: the next reply has toggle 0, and life guarding
    /// waits for the first request again.
    pub fn reset(&mut self) {
        self.toggle = false;
        self.deadline = None;
        self.lost = false;
    }

    /// Takes any received frame; a remote frame on 0x700 + node is a request,
    /// answered in every `state` but initialisation.
    pub fn on_frame(&mut self, frame: &Frame, now: Instant, state: NmtState) -> LifeGuardOutput {
        let is_request = frame.is_remote() && heartbeat_node(frame.id()) == Some(self.node);
        if !is_request || state == NmtState::BootUp {
            return LifeGuardOutput::default();
        }
        let reply = GuardReply {
            node: self.node,
            toggle: self.toggle,
            state,
        };
        self.toggle = !self.toggle;
        let mut event = None;
        if let Some(life_time) = self.life_time {
            self.deadline = Some(now + life_time);
            if std::mem::take(&mut self.lost) {
                event = Some(LifeGuardEvent::Recovered);
            }
        }
        LifeGuardOutput {
            reply: Some(reply.encode()),
            event,
        }
    }

    /// `Lost` once the life time has passed without a request.
    pub fn poll(&mut self, now: Instant) -> Option<LifeGuardEvent> {
        let deadline = self.deadline?;
        if now < deadline {
            return None;
        }
        self.deadline = None;
        self.lost = true;
        Some(LifeGuardEvent::Lost)
    }

    pub fn deadline(&self) -> Option<Instant> {
        self.deadline
    }

    pub fn is_lost(&self) -> bool {
        self.lost
    }
}

#[cfg(test)]
mod tests;
