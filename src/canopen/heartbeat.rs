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
/// guard time; the node is lost after `life_time_factor` requests in a row
/// without a valid reply (the node life time, guard time × factor, of CiA
/// 301).
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
    missed: u8,
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
            missed: 0,
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
        }
    }

    pub fn stop(&mut self) {
        self.next_request = None;
        self.awaiting_reply = false;
        self.missed = 0;
    }

    /// After the master reset the node: its next reply has toggle 0.
    pub fn reset_toggle(&mut self) {
        self.expected_toggle = Some(false);
    }

    /// When the next request is due.
    pub fn deadline(&self) -> Option<Instant> {
        self.next_request
    }

    #[must_use = "the frame must be sent"]
    pub fn poll(&mut self, now: Instant) -> GuardPoll {
        let (Some(period), Some(due)) = (self.guard_time, self.next_request) else {
            return GuardPoll::default();
        };
        if now < due {
            return GuardPoll::default();
        }
        let mut event = None;
        if self.awaiting_reply {
            self.missed = self.missed.saturating_add(1);
            if self.missed >= self.life_time_factor && !self.lost {
                self.lost = true;
                event = Some(HeartbeatEvent::Lost { node: self.node });
            }
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
            self.missed = 0;
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
        self.missed = 0;
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
mod tests {
    use super::*;

    fn node(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }

    fn ms(ms: u64) -> Duration {
        Duration::from_millis(ms)
    }

    fn hb(id: u16, data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(id), data).unwrap()
    }

    #[test]
    fn heartbeats_encode_byte_exact() {
        let cases = [
            (NmtState::BootUp, "705#00"),
            (NmtState::Stopped, "705#04"),
            (NmtState::Operational, "705#05"),
            (NmtState::PreOperational, "705#7F"),
        ];
        for (state, text) in cases {
            let frame = Heartbeat::new(node(5), state).encode();
            assert_eq!(frame.to_string(), text);
            assert_eq!(
                Heartbeat::decode(&frame),
                Ok(Heartbeat::new(node(5), state))
            );
        }
        assert_eq!(
            Heartbeat::new(node(127), NmtState::Operational)
                .encode()
                .to_string(),
            "77F#05"
        );
    }

    #[test]
    fn heartbeats_decode_and_reject_malformed_ones() {
        // Bit 7 is reserved (or a toggle bit): the state is bits 0-6.
        assert_eq!(
            Heartbeat::decode(&hb(0x701, &[0x85])),
            Ok(Heartbeat::new(node(1), NmtState::Operational))
        );
        assert_eq!(
            Heartbeat::decode(&hb(0x701, &[0x03])),
            Ok(Heartbeat::new(node(1), NmtState::Unknown(3)))
        );
        assert_eq!(
            Heartbeat::decode(&hb(0x701, &[])),
            Err(HeartbeatError::Length(0))
        );
        assert_eq!(
            Heartbeat::decode(&hb(0x701, &[0x05, 0x00])),
            Err(HeartbeatError::Length(2))
        );
        assert_eq!(
            Heartbeat::decode(&hb(0x700, &[0x05])),
            Err(HeartbeatError::NotHeartbeat(CanId::Standard(0x700)))
        );
        assert_eq!(
            Heartbeat::decode(&hb(0x181, &[0x05])),
            Err(HeartbeatError::NotHeartbeat(CanId::Standard(0x181)))
        );
        assert_eq!(
            Heartbeat::decode(&Frame::new(CanId::Extended(0x701), &[5]).unwrap()),
            Err(HeartbeatError::NotHeartbeat(CanId::Extended(0x701)))
        );
        assert_eq!(
            Heartbeat::decode(&guard_request(node(1))),
            Err(HeartbeatError::Remote(CanId::Standard(0x701)))
        );
    }

    #[test]
    fn guarding_frames_encode_byte_exact() {
        assert_eq!(guard_request(node(0x10)).to_string(), "710#R1");
        let reply = |toggle, state| GuardReply {
            node: node(0x10),
            toggle,
            state,
        };
        assert_eq!(
            reply(false, NmtState::PreOperational).encode().to_string(),
            "710#7F"
        );
        assert_eq!(
            reply(true, NmtState::PreOperational).encode().to_string(),
            "710#FF"
        );
        assert_eq!(
            reply(true, NmtState::Operational).encode().to_string(),
            "710#85"
        );
        assert_eq!(
            reply(false, NmtState::Stopped).encode().to_string(),
            "710#04"
        );
        assert_eq!(
            GuardReply::decode(&hb(0x710, &[0x84])),
            Ok(reply(true, NmtState::Stopped))
        );
        assert_eq!(
            GuardReply::decode(&hb(0x710, &[0x84, 0])),
            Err(HeartbeatError::Length(2))
        );
    }

    #[test]
    fn consumer_time_entries_of_0x1016() {
        let entry = ConsumerTime::from_raw(0x0005_01F4);
        assert_eq!(
            entry,
            ConsumerTime {
                node: 5,
                time_ms: 500
            }
        );
        assert_eq!(entry.raw(), 0x0005_01F4);
        assert_eq!(entry.monitored(), Some((node(5), ms(500))));
        // Reserved bits 24-31 are dropped.
        assert_eq!(ConsumerTime::from_raw(0xFF05_01F4), entry);
        assert_eq!(ConsumerTime::from_raw(0x0000_01F4).monitored(), None);
        assert_eq!(ConsumerTime::from_raw(0x0005_0000).monitored(), None);
        assert_eq!(ConsumerTime::from_raw(0x0080_0064).monitored(), None);
    }

    #[test]
    fn the_producer_sends_the_state_every_period() {
        let t0 = Instant::now();
        let mut producer = HeartbeatProducer::new(node(3));
        assert_eq!(producer.deadline(), None);
        assert_eq!(producer.poll(t0 + ms(5000), NmtState::Operational), None);

        producer.set_period_ms(100, t0);
        assert_eq!(producer.period(), Some(ms(100)));
        assert_eq!(producer.deadline(), Some(t0 + ms(100)));
        assert_eq!(producer.poll(t0 + ms(99), NmtState::PreOperational), None);
        let frame = producer
            .poll(t0 + ms(100), NmtState::PreOperational)
            .unwrap();
        assert_eq!(frame.to_string(), "703#7F");
        assert_eq!(producer.deadline(), Some(t0 + ms(200)));
        // Polled a little late: the period does not drift.
        let frame = producer.poll(t0 + ms(230), NmtState::Operational).unwrap();
        assert_eq!(frame.to_string(), "703#05");
        assert_eq!(producer.deadline(), Some(t0 + ms(300)));
        // Polled very late: one heartbeat, not a burst.
        assert!(producer.poll(t0 + ms(1000), NmtState::Stopped).is_some());
        assert_eq!(producer.poll(t0 + ms(1000), NmtState::Stopped), None);
        assert_eq!(producer.deadline(), Some(t0 + ms(1100)));

        producer.set_period_ms(0, t0 + ms(1050));
        assert_eq!(producer.deadline(), None);
        assert_eq!(producer.poll(t0 + ms(5000), NmtState::Operational), None);
    }

    #[test]
    fn the_consumer_reports_state_changes_and_boot_up() {
        let t0 = Instant::now();
        let mut consumer = HeartbeatConsumer::new();
        consumer.monitor(node(5), ms(150));
        // Not timed until the first heartbeat.
        assert_eq!(consumer.deadline(), None);
        assert_eq!(consumer.poll(t0 + ms(10_000)), []);

        assert_eq!(
            consumer.on_frame(&hb(0x705, &[0x00]), t0),
            Ok(vec![HeartbeatEvent::BootUp { node: node(5) }])
        );
        assert_eq!(consumer.state(node(5)), Some(NmtState::BootUp));
        // Boot-up does not start the timeout.
        assert_eq!(consumer.deadline(), None);
        assert_eq!(
            consumer.on_frame(&hb(0x705, &[0x7F]), t0 + ms(10)),
            Ok(vec![HeartbeatEvent::StateChanged {
                node: node(5),
                from: Some(NmtState::BootUp),
                to: NmtState::PreOperational
            }])
        );
        assert_eq!(consumer.deadline(), Some(t0 + ms(160)));
        // The same state again: nothing to report, the timeout restarts.
        assert_eq!(
            consumer.on_frame(&hb(0x705, &[0x7F]), t0 + ms(110)),
            Ok(vec![])
        );
        assert_eq!(consumer.deadline(), Some(t0 + ms(260)));
        assert_eq!(consumer.last_seen(node(5)), Some(t0 + ms(110)));
        assert_eq!(
            consumer.on_frame(&hb(0x705, &[0x05]), t0 + ms(210)),
            Ok(vec![HeartbeatEvent::StateChanged {
                node: node(5),
                from: Some(NmtState::PreOperational),
                to: NmtState::Operational
            }])
        );
    }

    #[test]
    fn the_consumer_reports_a_lost_node_once_and_its_recovery() {
        let t0 = Instant::now();
        let mut consumer = HeartbeatConsumer::new();
        consumer.monitor_producer(node(2), ms(100));
        let _ = consumer.on_frame(&hb(0x702, &[0x05]), t0);
        assert_eq!(consumer.deadline(), Some(t0 + ms(150)));
        assert_eq!(consumer.poll(t0 + ms(149)), []);
        assert_eq!(
            consumer.poll(t0 + ms(150)),
            [HeartbeatEvent::Lost { node: node(2) }]
        );
        assert!(consumer.is_lost(node(2)));
        assert_eq!(consumer.deadline(), None);
        assert_eq!(consumer.poll(t0 + ms(1000)), []);
        // It comes back in another state.
        assert_eq!(
            consumer.on_frame(&hb(0x702, &[0x04]), t0 + ms(2000)),
            Ok(vec![
                HeartbeatEvent::Recovered {
                    node: node(2),
                    state: NmtState::Stopped
                },
                HeartbeatEvent::StateChanged {
                    node: node(2),
                    from: Some(NmtState::Operational),
                    to: NmtState::Stopped
                }
            ])
        );
        assert!(!consumer.is_lost(node(2)));
        assert_eq!(consumer.deadline(), Some(t0 + ms(2150)));
        // A lost node that reboots recovers in boot-up.
        assert_eq!(consumer.poll(t0 + ms(2150)).len(), 1);
        assert_eq!(
            consumer.on_frame(&hb(0x702, &[0x00]), t0 + ms(3000)),
            Ok(vec![
                HeartbeatEvent::Recovered {
                    node: node(2),
                    state: NmtState::BootUp
                },
                HeartbeatEvent::BootUp { node: node(2) }
            ])
        );
    }

    #[test]
    fn the_consumer_can_be_armed_before_the_first_heartbeat() {
        let t0 = Instant::now();
        let mut consumer = HeartbeatConsumer::new();
        consumer.monitor(node(9), ms(500));
        consumer.arm(node(9), t0);
        // Arming a node that is not monitored does nothing.
        consumer.arm(node(10), t0);
        assert_eq!(consumer.deadline(), Some(t0 + ms(500)));
        assert_eq!(
            consumer.poll(t0 + ms(500)),
            [HeartbeatEvent::Lost { node: node(9) }]
        );
        assert_eq!(consumer.state(node(9)), None);
    }

    #[test]
    fn the_consumer_tracks_unmonitored_nodes_without_a_timeout() {
        let t0 = Instant::now();
        let mut consumer = HeartbeatConsumer::new();
        assert_eq!(
            consumer.on_frame(&hb(0x77F, &[0x7F]), t0),
            Ok(vec![HeartbeatEvent::StateChanged {
                node: node(127),
                from: None,
                to: NmtState::PreOperational
            }])
        );
        assert_eq!(consumer.deadline(), None);
        assert_eq!(consumer.poll(t0 + ms(100_000)), []);
        assert_eq!(consumer.nodes().collect::<Vec<_>>(), [node(127)]);
        // Monitoring it now times it from its last heartbeat.
        consumer.monitor(node(127), ms(200));
        assert_eq!(consumer.deadline(), Some(t0 + ms(200)));
        consumer.monitor(node(127), Duration::ZERO);
        assert_eq!(consumer.deadline(), None);
        consumer.unmonitor(node(127));
        assert_eq!(consumer.state(node(127)), None);
    }

    #[test]
    fn the_consumer_ignores_other_frames_and_reports_malformed_heartbeats() {
        let t0 = Instant::now();
        let mut consumer = HeartbeatConsumer::new();
        assert_eq!(consumer.on_frame(&hb(0x185, &[1, 2]), t0), Ok(vec![]));
        assert_eq!(consumer.on_frame(&guard_request(node(5)), t0), Ok(vec![]));
        assert_eq!(
            consumer.on_frame(&hb(0x705, &[0x05, 0x05]), t0),
            Err(HeartbeatError::Length(2))
        );
        assert_eq!(consumer.nodes().count(), 0);
    }

    #[test]
    fn several_nodes_time_out_independently() {
        let t0 = Instant::now();
        let mut consumer = HeartbeatConsumer::new();
        consumer.monitor(node(1), ms(100));
        consumer.monitor(node(2), ms(300));
        let _ = consumer.on_frame(&hb(0x701, &[0x05]), t0);
        let _ = consumer.on_frame(&hb(0x702, &[0x05]), t0);
        assert_eq!(consumer.deadline(), Some(t0 + ms(100)));
        assert_eq!(
            consumer.poll(t0 + ms(100)),
            [HeartbeatEvent::Lost { node: node(1) }]
        );
        assert_eq!(consumer.deadline(), Some(t0 + ms(300)));
        assert_eq!(
            consumer.poll(t0 + ms(300)),
            [HeartbeatEvent::Lost { node: node(2) }]
        );
        assert_eq!(consumer.deadline(), None);
    }

    #[test]
    fn the_guarding_master_polls_checks_the_toggle_and_loses_a_silent_node() {
        let t0 = Instant::now();
        let mut guard = NodeGuardMaster::new(node(4), 100, 3);
        assert_eq!(guard.life_time(), Some(ms(300)));
        assert_eq!(guard.deadline(), None);
        guard.start(t0);
        let poll = guard.poll(t0);
        assert_eq!(poll.request.unwrap().to_string(), "704#R1");
        assert_eq!(poll.event, None);
        assert_eq!(guard.deadline(), Some(t0 + ms(100)));
        // First reply: toggle taken as it comes.
        assert_eq!(
            guard.on_frame(&hb(0x704, &[0x7F]), t0 + ms(1)),
            Ok(vec![HeartbeatEvent::StateChanged {
                node: node(4),
                from: None,
                to: NmtState::PreOperational
            }])
        );
        let _ = guard.poll(t0 + ms(100));
        assert_eq!(
            guard.on_frame(&hb(0x704, &[0xFF]), t0 + ms(101)),
            Ok(vec![])
        );
        let _ = guard.poll(t0 + ms(200));
        assert_eq!(
            guard.on_frame(&hb(0x704, &[0x05]), t0 + ms(201)),
            Ok(vec![HeartbeatEvent::StateChanged {
                node: node(4),
                from: Some(NmtState::PreOperational),
                to: NmtState::Operational
            }])
        );
        assert_eq!(guard.state(), Some(NmtState::Operational));
        assert_eq!(guard.last_seen(), Some(t0 + ms(201)));
        // Silence: requests at 300, 400, 500 unanswered; at 600 the third
        // miss is counted.
        for t in [300, 400, 500] {
            let poll = guard.poll(t0 + ms(t));
            assert!(poll.request.is_some());
            assert_eq!(poll.event, None, "at {t} ms");
        }
        let poll = guard.poll(t0 + ms(600));
        assert!(poll.request.is_some());
        assert_eq!(poll.event, Some(HeartbeatEvent::Lost { node: node(4) }));
        assert!(guard.is_lost());
        assert_eq!(guard.poll(t0 + ms(700)).event, None);
        // It answers again, toggle continuing from the last valid reply (1).
        assert_eq!(
            guard.on_frame(&hb(0x704, &[0x85]), t0 + ms(701)),
            Ok(vec![HeartbeatEvent::Recovered {
                node: node(4),
                state: NmtState::Operational
            }])
        );
        assert!(!guard.is_lost());
    }

    #[test]
    fn a_wrong_toggle_costs_one_request() {
        let t0 = Instant::now();
        let mut guard = NodeGuardMaster::new(node(4), 100, 2);
        guard.start(t0);
        let _ = guard.poll(t0);
        let _ = guard.on_frame(&hb(0x704, &[0x05]), t0);
        let _ = guard.poll(t0 + ms(100));
        // Expected toggle 1, got 0: not a valid reply.
        assert_eq!(
            guard.on_frame(&hb(0x704, &[0x05]), t0 + ms(101)),
            Ok(vec![])
        );
        assert_eq!(guard.poll(t0 + ms(200)).event, None);
        // The node toggles on: 1 is what was expected, the node is back in step.
        assert_eq!(
            guard.on_frame(&hb(0x704, &[0x85]), t0 + ms(201)),
            Ok(vec![])
        );
        assert_eq!(guard.poll(t0 + ms(300)).event, None);
        assert_eq!(guard.poll(t0 + ms(400)).event, None);
        assert_eq!(
            guard.poll(t0 + ms(500)).event,
            Some(HeartbeatEvent::Lost { node: node(4) })
        );
    }

    #[test]
    fn the_guarding_master_sees_boot_up_and_ignores_unsolicited_bytes() {
        let t0 = Instant::now();
        let mut guard = NodeGuardMaster::new(node(4), 100, 1);
        guard.start(t0);
        // No request outstanding: a heartbeat-like byte is not a reply.
        assert_eq!(guard.on_frame(&hb(0x704, &[0x05]), t0), Ok(vec![]));
        let _ = guard.poll(t0);
        let _ = guard.on_frame(&hb(0x704, &[0x85]), t0);
        assert_eq!(
            guard.on_frame(&hb(0x704, &[0x00]), t0 + ms(50)),
            Ok(vec![HeartbeatEvent::BootUp { node: node(4) }])
        );
        let _ = guard.poll(t0 + ms(100));
        // After boot-up the toggle restarts at 0: 0x80 is wrong.
        assert_eq!(
            guard.on_frame(&hb(0x704, &[0xFF]), t0 + ms(101)),
            Ok(vec![])
        );
        assert_eq!(
            guard.poll(t0 + ms(200)).event,
            Some(HeartbeatEvent::Lost { node: node(4) })
        );
        // Other nodes' frames are not ours.
        assert_eq!(guard.on_frame(&hb(0x705, &[0x00]), t0), Ok(vec![]));
        assert_eq!(
            guard.on_frame(&hb(0x704, &[]), t0),
            Err(HeartbeatError::Length(0))
        );
        guard.stop();
        assert_eq!(guard.deadline(), None);
        assert_eq!(guard.poll(t0 + ms(1000)), GuardPoll::default());
    }

    #[test]
    fn guarding_is_off_when_guard_time_or_factor_is_zero() {
        let t0 = Instant::now();
        for (time, factor) in [(0, 3), (100, 0)] {
            let mut guard = NodeGuardMaster::new(node(4), time, factor);
            guard.start(t0);
            assert_eq!(guard.life_time(), None);
            assert_eq!(guard.deadline(), None);
            assert_eq!(guard.poll(t0 + ms(1000)), GuardPoll::default());
        }
    }

    #[test]
    fn the_slave_answers_with_a_toggling_state_byte() {
        let t0 = Instant::now();
        let mut guard = LifeGuard::new(node(6));
        let request = guard_request(node(6));
        let reply = |guard: &mut LifeGuard, state| {
            guard
                .on_frame(&request, t0, state)
                .reply
                .map(|f| f.to_string())
        };
        assert_eq!(
            reply(&mut guard, NmtState::PreOperational).as_deref(),
            Some("706#7F")
        );
        assert_eq!(
            reply(&mut guard, NmtState::PreOperational).as_deref(),
            Some("706#FF")
        );
        assert_eq!(
            reply(&mut guard, NmtState::Operational).as_deref(),
            Some("706#05")
        );
        assert_eq!(
            reply(&mut guard, NmtState::Stopped).as_deref(),
            Some("706#84")
        );
        // Not while initialising; no toggle is used up.
        assert_eq!(reply(&mut guard, NmtState::BootUp), None);
        assert_eq!(
            reply(&mut guard, NmtState::Stopped).as_deref(),
            Some("706#04")
        );
        guard.reset();
        assert_eq!(
            reply(&mut guard, NmtState::PreOperational).as_deref(),
            Some("706#7F")
        );
        // Another node's request, or a data frame, is not ours.
        assert_eq!(
            guard.on_frame(&guard_request(node(7)), t0, NmtState::Operational),
            LifeGuardOutput::default()
        );
        assert_eq!(
            guard.on_frame(&hb(0x706, &[0x05]), t0, NmtState::Operational),
            LifeGuardOutput::default()
        );
        // Life guarding is off: no deadline.
        assert_eq!(guard.deadline(), None);
    }

    #[test]
    fn the_slave_signals_life_guarding_when_the_master_stops() {
        let t0 = Instant::now();
        let mut guard = LifeGuard::new(node(6));
        guard.configure(100, 3, t0);
        assert_eq!(guard.life_time(), Some(ms(300)));
        // Watching starts with the first request.
        assert_eq!(guard.deadline(), None);
        assert_eq!(guard.poll(t0 + ms(10_000)), None);
        let request = guard_request(node(6));
        let out = guard.on_frame(&request, t0, NmtState::Operational);
        assert!(out.reply.is_some());
        assert_eq!(out.event, None);
        assert_eq!(guard.deadline(), Some(t0 + ms(300)));
        let _ = guard.on_frame(&request, t0 + ms(100), NmtState::Operational);
        assert_eq!(guard.poll(t0 + ms(399)), None);
        assert_eq!(guard.poll(t0 + ms(400)), Some(LifeGuardEvent::Lost));
        assert!(guard.is_lost());
        assert_eq!(guard.poll(t0 + ms(800)), None);
        let out = guard.on_frame(&request, t0 + ms(900), NmtState::Operational);
        assert_eq!(out.event, Some(LifeGuardEvent::Recovered));
        assert!(!guard.is_lost());
        // A new life time while watching runs from now.
        guard.configure(50, 2, t0 + ms(950));
        assert_eq!(guard.deadline(), Some(t0 + ms(1050)));
        guard.configure(0, 2, t0 + ms(960));
        assert_eq!(guard.deadline(), None);
    }
}
