//! The alarms of the machine (ISA-18.2 / IEC 62682): one model that every
//! door reads, so that REST, the stream, the dashboard, Sparkplug and
//! `/metrics` show the same alarms.
//!
//! An alarm is raised by a source (a bus, a node, an axis where known) for
//! a kind of cause ([`AlarmKind`]: a CiA 402 axis fault, an EMCY code, a
//! node offline, missing, of the wrong identity or whose configuration
//! failed, a heartbeat or node guarding lost, bus off or error passive, a
//! lease halted because its client went away, a program download that
//! failed), with the severity, text and help the product's table gives
//! ([`crate::profiles::alarm`]). Its state follows ISA-18.2:
//!
//! | state | cause | acknowledged | goes to |
//! |---|---|---|---|
//! | `active_unacknowledged` | present | no | `active_acknowledged` (ack), `cleared_unacknowledged` (cause gone) |
//! | `active_acknowledged` | present | yes | `normal` (cause gone) |
//! | `cleared_unacknowledged` | gone | no | `normal` (ack), `active_unacknowledged` (back: `count` + 1) |
//! | `normal` | gone | yes | (history) |
//!
//! A cause that comes back while its alarm is not yet `normal` raises no
//! second alarm: the one there is counts it (`count`, chattering). Once
//! `normal`, the same cause raises a new alarm.
//!
//! [`AlarmBook`] is the model without I/O (time passed in, µs since the
//! Unix epoch); `alarms/service.rs` runs it: its sources, the history
//! database it persists to, the stream of changes, the operations.

mod recovery;
mod service;
mod sources;
pub(crate) use sources::WorkDone;
#[cfg(test)]
mod tests;

use std::collections::{BTreeMap, HashMap, HashSet, VecDeque};

use crate::canopen::manager::{MachineState, MachineStatus, NodeStatus};
use crate::profiles::alarm::{AlarmKind, AlarmText, Severity};

pub use recovery::{AxisRecovery, RecoveryOutcome, RecoveryReport};
pub use service::{AckFilter, AlarmChange, AlarmPage, AlarmSummary, Alarms, MAX_COMMENT};

/// The most alarms a page lists.
pub const PAGE_SIZE: usize = 50;
/// The alarms back to `normal` the book keeps in memory (the newest);
/// older ones stay in the history database.
pub(crate) const NORMAL_KEPT: usize = 1000;
/// The entries of one alarm's history kept (the oldest go; `count` still
/// counts every raise).
pub(crate) const HISTORY_KEPT: usize = 100;

/// The ISA-18.2 state of an alarm.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum AlarmState {
    ActiveUnacknowledged,
    ActiveAcknowledged,
    ClearedUnacknowledged,
    Normal,
}

impl AlarmState {
    pub const ALL: [Self; 4] = [
        Self::ActiveUnacknowledged,
        Self::ActiveAcknowledged,
        Self::ClearedUnacknowledged,
        Self::Normal,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::ActiveUnacknowledged => "active_unacknowledged",
            Self::ActiveAcknowledged => "active_acknowledged",
            Self::ClearedUnacknowledged => "cleared_unacknowledged",
            Self::Normal => "normal",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|state| state.name() == name)
    }

    /// Its cause is present.
    pub fn is_active(self) -> bool {
        matches!(self, Self::ActiveUnacknowledged | Self::ActiveAcknowledged)
    }

    /// Waits for an operator's acknowledgement.
    pub fn is_unacknowledged(self) -> bool {
        matches!(
            self,
            Self::ActiveUnacknowledged | Self::ClearedUnacknowledged
        )
    }
}

/// What one alarm is about: at most one alarm that is not `normal` exists
/// per source.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) struct AlarmSource {
    pub(crate) bus: String,
    pub(crate) node: Option<u8>,
    pub(crate) axis: Option<u8>,
    pub(crate) kind: AlarmKindKey,
}

/// [`AlarmKind`] with an order, for keys.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) struct AlarmKindKey(pub(crate) &'static str, pub(crate) Option<u16>);

impl From<AlarmKind> for AlarmKindKey {
    fn from(kind: AlarmKind) -> Self {
        let code = match kind {
            AlarmKind::Emcy(code) => Some(code),
            _ => None,
        };
        Self(kind.name(), code)
    }
}

impl AlarmSource {
    pub(crate) fn new(bus: &str, node: Option<u8>, axis: Option<u8>, kind: AlarmKind) -> Self {
        Self {
            bus: bus.to_string(),
            node,
            axis,
            kind: kind.into(),
        }
    }
}

/// One step of an alarm's life.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AlarmStep {
    Raised,
    /// Its cause came back while it was `cleared_unacknowledged`.
    Returned,
    Cleared,
    Acknowledged,
    /// Active before a restart and its cause still present after it.
    Restored,
}

impl AlarmStep {
    pub fn name(self) -> &'static str {
        match self {
            Self::Raised => "raised",
            Self::Returned => "returned",
            Self::Cleared => "cleared",
            Self::Acknowledged => "acknowledged",
            Self::Restored => "restored",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        [
            Self::Raised,
            Self::Returned,
            Self::Cleared,
            Self::Acknowledged,
            Self::Restored,
        ]
        .into_iter()
        .find(|step| step.name() == name)
    }
}

/// One entry of an alarm's history.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AlarmEvent {
    pub time_us: i64,
    pub step: AlarmStep,
    /// The state it left the alarm in.
    pub state: AlarmState,
    /// Who acknowledged.
    pub who: Option<String>,
    pub comment: Option<String>,
}

/// One alarm.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Alarm {
    pub id: u64,
    pub bus: String,
    pub node: Option<u8>,
    pub axis: Option<u8>,
    pub kind: AlarmKind,
    pub severity: Severity,
    pub state: AlarmState,
    pub text: String,
    pub help: String,
    /// When it was raised, µs since the Unix epoch.
    pub raised_us: i64,
    /// When its cause last went; `None` while active.
    pub cleared_us: Option<i64>,
    pub acknowledged_by: Option<String>,
    pub acknowledged_at_us: Option<i64>,
    pub comment: Option<String>,
    /// How many times its cause came (1, and one more each time it came
    /// back before the alarm was `normal`).
    pub count: u32,
    /// Its life, oldest first (at most `HISTORY_KEPT` entries).
    pub history: Vec<AlarmEvent>,
}

impl Alarm {
    pub(crate) fn source(&self) -> AlarmSource {
        AlarmSource::new(&self.bus, self.node, self.axis, self.kind)
    }

    fn step(&mut self, time_us: i64, step: AlarmStep, state: AlarmState) -> AlarmEvent {
        self.state = state;
        let event = AlarmEvent {
            time_us,
            step,
            state,
            who: None,
            comment: None,
        };
        self.push(event.clone());
        event
    }

    fn push(&mut self, event: AlarmEvent) {
        if self.history.len() >= HISTORY_KEPT {
            self.history.remove(0);
        }
        self.history.push(event);
    }

    /// The line the machine's reasons give it.
    pub fn reason(&self) -> String {
        let mut at = String::new();
        if let Some(node) = self.node {
            at.push_str(&format!("node {node}"));
        }
        if let Some(axis) = self.axis {
            at.push_str(&format!(" axis {axis}"));
        }
        if !at.is_empty() {
            at.push_str(": ");
        }
        format!(
            "alarm {} ({}): {at}{}",
            self.id,
            self.severity.name(),
            self.text
        )
    }
}

/// One change of the book: the alarm as it is now and the step that made
/// it so; what the history database and the stream are told.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Changed {
    pub(crate) alarm: Alarm,
    pub(crate) event: AlarmEvent,
}

/// Which alarms (`GET /alarms`' filters; every one optional).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct AlarmFilter {
    pub state: Option<AlarmState>,
    pub severity: Option<Severity>,
    pub bus: Option<String>,
    pub node: Option<u8>,
    /// Alarms whose cause was present at or after this time (µs since the
    /// Unix epoch): active ones, and the ones cleared since.
    pub since_us: Option<i64>,
}

impl AlarmFilter {
    pub fn matches(&self, alarm: &Alarm) -> bool {
        self.state.is_none_or(|state| alarm.state == state)
            && self
                .severity
                .is_none_or(|severity| alarm.severity == severity)
            && self.bus.as_ref().is_none_or(|bus| &alarm.bus == bus)
            && self.node.is_none_or(|node| alarm.node == Some(node))
            && self
                .since_us
                .is_none_or(|since| alarm.cleared_us.is_none_or(|cleared| cleared >= since))
    }
}

/// The alarms, sans I/O.
#[derive(Debug, Default)]
pub(crate) struct AlarmBook {
    alarms: BTreeMap<u64, Alarm>,
    /// The alarm of each source that is not `normal`.
    open: HashMap<AlarmSource, u64>,
    /// The `normal` alarms kept, oldest first.
    normal: VecDeque<u64>,
    /// Alarms active before a restart whose cause no source has reported
    /// present since.
    unconfirmed: HashSet<u64>,
    next_id: u64,
}

impl AlarmBook {
    /// The book of the alarms read back from the history database: the
    /// active ones wait for their source to report their cause again
    /// ([`Self::raise`] confirms it) until [`Self::settle_restored`].
    pub(crate) fn restore(alarms: Vec<Alarm>) -> Self {
        let mut book = Self::default();
        for alarm in alarms {
            book.next_id = book.next_id.max(alarm.id);
            if alarm.state == AlarmState::Normal {
                book.normal.push_back(alarm.id);
            } else {
                book.open.insert(alarm.source(), alarm.id);
                if alarm.state.is_active() {
                    book.unconfirmed.insert(alarm.id);
                }
            }
            book.alarms.insert(alarm.id, alarm);
        }
        book.trim_normal();
        book
    }

    /// The cause of `source` is present: a new alarm, or the one there is
    /// (counted again if its cause had gone). `None` when nothing changed
    /// (the alarm was active already).
    /// `text` is asked for only when a new alarm is raised.
    pub(crate) fn raise(
        &mut self,
        source: AlarmSource,
        text: impl FnOnce() -> AlarmText,
        now_us: i64,
    ) -> Option<Changed> {
        let kind = kind_of(&source)?;
        if let Some(&id) = self.open.get(&source) {
            let alarm = self.alarms.get_mut(&id)?;
            if self.unconfirmed.remove(&id) {
                let event = alarm.step(now_us, AlarmStep::Restored, alarm.state);
                return Some(Changed {
                    alarm: alarm.clone(),
                    event,
                });
            }
            if alarm.state.is_active() {
                return None;
            }
            alarm.count = alarm.count.saturating_add(1);
            alarm.cleared_us = None;
            let event = alarm.step(
                now_us,
                AlarmStep::Returned,
                AlarmState::ActiveUnacknowledged,
            );
            return Some(Changed {
                alarm: alarm.clone(),
                event,
            });
        }
        self.next_id += 1;
        let id = self.next_id;
        let text = text();
        let mut alarm = Alarm {
            id,
            bus: source.bus.clone(),
            node: source.node,
            axis: source.axis,
            kind,
            severity: text.severity,
            state: AlarmState::ActiveUnacknowledged,
            text: text.text.clone(),
            help: text.help.clone(),
            raised_us: now_us,
            cleared_us: None,
            acknowledged_by: None,
            acknowledged_at_us: None,
            comment: None,
            count: 1,
            history: Vec::new(),
        };
        let event = alarm.step(now_us, AlarmStep::Raised, AlarmState::ActiveUnacknowledged);
        self.open.insert(source, id);
        self.alarms.insert(id, alarm.clone());
        Some(Changed { alarm, event })
    }

    /// The cause of `source` went. `None` when it had no active alarm.
    pub(crate) fn clear(&mut self, source: &AlarmSource, now_us: i64) -> Option<Changed> {
        let id = *self.open.get(source)?;
        let alarm = self.alarms.get_mut(&id)?;
        let next = match alarm.state {
            AlarmState::ActiveUnacknowledged => AlarmState::ClearedUnacknowledged,
            AlarmState::ActiveAcknowledged => AlarmState::Normal,
            AlarmState::ClearedUnacknowledged | AlarmState::Normal => return None,
        };
        self.unconfirmed.remove(&id);
        alarm.cleared_us = Some(now_us);
        let event = alarm.step(now_us, AlarmStep::Cleared, next);
        let changed = Changed {
            alarm: alarm.clone(),
            event,
        };
        if next == AlarmState::Normal {
            self.make_normal(id);
        }
        Some(changed)
    }

    /// Clears every active alarm whose source `which` picks.
    pub(crate) fn clear_where(
        &mut self,
        which: impl Fn(&AlarmSource) -> bool,
        now_us: i64,
    ) -> Vec<Changed> {
        let sources: Vec<AlarmSource> = self.open.keys().filter(|s| which(s)).cloned().collect();
        sources
            .iter()
            .filter_map(|source| self.clear(source, now_us))
            .collect()
    }

    /// The sources of the active alarms `which` picks.
    pub(crate) fn active_sources(&self, which: impl Fn(&AlarmSource) -> bool) -> Vec<AlarmSource> {
        self.open
            .iter()
            .filter(|(source, id)| {
                which(source) && self.alarms.get(id).is_some_and(|a| a.state.is_active())
            })
            .map(|(source, _)| source.clone())
            .collect()
    }

    /// Clears every alarm restored at start whose cause no source has
    /// reported since: its cause went while the gateway was not looking.
    pub(crate) fn settle_restored(&mut self, now_us: i64) -> Vec<Changed> {
        let ids: Vec<u64> = self.unconfirmed.drain().collect();
        let sources: Vec<AlarmSource> = ids
            .iter()
            .filter_map(|id| self.alarms.get(id).map(Alarm::source))
            .collect();
        sources
            .iter()
            .filter_map(|source| self.clear(source, now_us))
            .collect()
    }

    /// An operator acknowledges alarm `id`: `None` for an alarm the book
    /// does not have; the alarm unchanged (no [`Changed`]) when it waited
    /// for no acknowledgement.
    pub(crate) fn acknowledge(
        &mut self,
        id: u64,
        who: &str,
        comment: Option<&str>,
        now_us: i64,
    ) -> Option<(Alarm, Option<Changed>)> {
        let alarm = self.alarms.get_mut(&id)?;
        let next = match alarm.state {
            AlarmState::ActiveUnacknowledged => AlarmState::ActiveAcknowledged,
            AlarmState::ClearedUnacknowledged => AlarmState::Normal,
            AlarmState::ActiveAcknowledged | AlarmState::Normal => {
                return Some((alarm.clone(), None));
            }
        };
        alarm.state = next;
        alarm.acknowledged_by = Some(who.to_string());
        alarm.acknowledged_at_us = Some(now_us);
        alarm.comment = comment.map(str::to_string);
        let event = AlarmEvent {
            time_us: now_us,
            step: AlarmStep::Acknowledged,
            state: next,
            who: Some(who.to_string()),
            comment: comment.map(str::to_string),
        };
        alarm.push(event.clone());
        let changed = Changed {
            alarm: alarm.clone(),
            event,
        };
        if next == AlarmState::Normal {
            self.make_normal(id);
        }
        Some((changed.alarm.clone(), Some(changed)))
    }

    /// Acknowledges every unacknowledged alarm `filter` matches.
    pub(crate) fn acknowledge_matching(
        &mut self,
        filter: &AlarmFilter,
        who: &str,
        comment: Option<&str>,
        now_us: i64,
    ) -> Vec<Changed> {
        let ids: Vec<u64> = self
            .open
            .values()
            .filter(|id| {
                self.alarms
                    .get(id)
                    .is_some_and(|alarm| alarm.state.is_unacknowledged() && filter.matches(alarm))
            })
            .copied()
            .collect();
        let mut ids = ids;
        ids.sort_unstable();
        ids.into_iter()
            .filter_map(|id| self.acknowledge(id, who, comment, now_us)?.1)
            .collect()
    }

    pub(crate) fn get(&self, id: u64) -> Option<&Alarm> {
        self.alarms.get(&id)
    }

    /// The alarms `filter` matches: the active ones first, then the
    /// cleared unacknowledged ones, then the history; newest first within
    /// each; `page` (from 1) of [`PAGE_SIZE`], and how many match.
    pub(crate) fn list(&self, filter: &AlarmFilter, page: usize) -> (Vec<Alarm>, usize) {
        let mut matching: Vec<&Alarm> = self
            .alarms
            .values()
            .filter(|alarm| filter.matches(alarm))
            .collect();
        matching.sort_by_key(|alarm| {
            let rank = match alarm.state {
                AlarmState::ActiveUnacknowledged | AlarmState::ActiveAcknowledged => 0,
                AlarmState::ClearedUnacknowledged => 1,
                AlarmState::Normal => 2,
            };
            (
                rank,
                std::cmp::Reverse(alarm.severity),
                std::cmp::Reverse(alarm.raised_us),
                std::cmp::Reverse(alarm.id),
            )
        });
        let total = matching.len();
        let start = page.saturating_sub(1).saturating_mul(PAGE_SIZE);
        let alarms = matching
            .into_iter()
            .skip(start)
            .take(PAGE_SIZE)
            .cloned()
            .collect();
        (alarms, total)
    }

    /// The alarms that are not `normal`, of `bus` or of every bus.
    pub(crate) fn open_alarms(&self, bus: Option<&str>) -> Vec<&Alarm> {
        let mut open: Vec<&Alarm> = self
            .open
            .values()
            .filter_map(|id| self.alarms.get(id))
            .filter(|alarm| bus.is_none_or(|bus| alarm.bus == bus))
            .collect();
        open.sort_by_key(|alarm| alarm.id);
        open
    }

    fn make_normal(&mut self, id: u64) {
        self.open.retain(|_, open| *open != id);
        self.unconfirmed.remove(&id);
        self.normal.push_back(id);
        self.trim_normal();
    }

    fn trim_normal(&mut self) {
        while self.normal.len() > NORMAL_KEPT {
            if let Some(id) = self.normal.pop_front() {
                self.alarms.remove(&id);
            }
        }
    }
}

/// The kind a source names.
fn kind_of(source: &AlarmSource) -> Option<AlarmKind> {
    AlarmKind::from_name(source.kind.0, source.kind.1)
}

/// The state of a machine with its alarms (`GET .../machine`, the
/// stream's `machine` topic).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MachineCondition {
    Ready,
    Booting,
    Degraded,
    Down,
    /// The network manager would say `ready`, but a `critical` or `high`
    /// alarm is active.
    Alarm,
}

impl MachineCondition {
    pub fn name(self) -> &'static str {
        match self {
            Self::Ready => "ready",
            Self::Booting => "booting",
            Self::Degraded => "degraded",
            Self::Down => "down",
            Self::Alarm => "alarm",
        }
    }

    /// From the worst (0) to the best: down, degraded, alarm, booting,
    /// ready: the worst of several buses is the one a SCADA host sees.
    /// An alarm needs someone; a machine booting is on its way.
    pub fn rank(self) -> u8 {
        match self {
            Self::Down => 0,
            Self::Degraded => 1,
            Self::Alarm => 2,
            Self::Booting => 3,
            Self::Ready => 4,
        }
    }
}

impl serde::Serialize for MachineCondition {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

/// The machine of a bus as the doors show it: the network manager's
/// status, with its alarms.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct MachineView {
    pub state: MachineCondition,
    /// Why it is not ready: the network manager's reasons, then one line
    /// per active `critical` or `high` alarm.
    pub reasons: Vec<String>,
    pub nodes: Vec<NodeStatus>,
}

impl MachineView {
    /// The machine `status` with the `alarms` of its bus: never `ready`
    /// while a `critical` or `high` alarm is active.
    pub fn new(status: MachineStatus, alarms: &[&Alarm]) -> Self {
        let stopping: Vec<&&Alarm> = alarms
            .iter()
            .filter(|alarm| alarm.state.is_active() && alarm.severity.stops_machine())
            .collect();
        let state = match status.state {
            MachineState::Ready if !stopping.is_empty() => MachineCondition::Alarm,
            MachineState::Ready => MachineCondition::Ready,
            MachineState::Booting => MachineCondition::Booting,
            MachineState::Degraded => MachineCondition::Degraded,
            MachineState::Down => MachineCondition::Down,
        };
        let mut reasons = status.reasons;
        reasons.extend(stopping.iter().map(|alarm| alarm.reason()));
        Self {
            state,
            reasons,
            nodes: status.nodes,
        }
    }
}

/// Follows `bus`'s sources, and keeps its machine's view with its alarms.
pub(crate) fn follow_bus(alarms: &Alarms, bus: &crate::service::ServedBus) {
    sources::BusSources::spawn(alarms.clone(), bus, bus.registry.subscribe());
    if let Some(machine) = &bus.machine {
        alarms.follow_machine(&bus.name, machine.watch());
    }
}
