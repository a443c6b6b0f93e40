//! The alarm book at work: shared by the gateway, fed by the sources
//! (`sources.rs`), persisted in the history database in the order it
//! changed, every change published (the stream's `alarms` topic, the
//! Sparkplug metrics), and the operations the doors call: list, one
//! alarm, acknowledge one, acknowledge all that match.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use tokio::sync::{broadcast, mpsc, oneshot, watch};

use super::{
    Alarm, AlarmBook, AlarmFilter, AlarmSource, AlarmState, AlarmStep, Changed, MachineView,
};
use crate::audit::AuditTarget;
use crate::caller::Caller;
use crate::can::Timestamp;
use crate::error::GatewayError;
use crate::history::History;
use crate::policy::Operation;
use crate::profiles::alarm::{AlarmText, Severity};
use crate::service::Gateway;

/// How long after start an alarm active before the restart waits for its
/// source to report its cause again before it is taken as gone: long
/// enough for the first scan, the network manager's boot-ups and a few
/// heartbeats.
pub(crate) const RESTORE_SETTLE: Duration = Duration::from_secs(10);
/// The changes a follower of [`Alarms::subscribe`] may fall behind by.
const CHANGES_QUEUE: usize = 1024;
/// The longest comment an acknowledgement keeps, in characters.
pub const MAX_COMMENT: usize = 500;

/// One change of an alarm, as the stream and Sparkplug are told.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AlarmChange {
    pub alarm: Alarm,
    pub step: AlarmStep,
}

/// A page of alarms and how many match.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AlarmPage {
    pub alarms: Vec<Alarm>,
    pub total: usize,
}

/// The alarms of a bus, a node or the whole gateway, counted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AlarmSummary {
    /// Active alarms, by severity ([`Severity::ALL`]'s order: critical,
    /// high, medium, low).
    pub active: [u32; 4],
    /// Alarms waiting for an acknowledgement (active or cleared), by
    /// severity.
    pub unacknowledged: [u32; 4],
    /// The most urgent severity of an alarm that is active or waits for
    /// an acknowledgement.
    pub highest: Option<Severity>,
}

impl AlarmSummary {
    fn of<'a>(alarms: impl IntoIterator<Item = &'a Alarm>) -> Self {
        let mut summary = Self::default();
        for alarm in alarms {
            let at = Severity::ALL
                .iter()
                .position(|severity| *severity == alarm.severity)
                .unwrap_or(0);
            if alarm.state.is_active() {
                summary.active[at] += 1;
            }
            if alarm.state.is_unacknowledged() {
                summary.unacknowledged[at] += 1;
            }
            if alarm.state != AlarmState::Normal {
                summary.highest = summary.highest.max(Some(alarm.severity));
            }
        }
        summary
    }

    pub fn active_total(&self) -> u32 {
        self.active.iter().sum()
    }

    pub fn unacknowledged_total(&self) -> u32 {
        self.unacknowledged.iter().sum()
    }
}

/// What the writer of the history is asked.
enum Persist {
    Changes(Vec<Changed>),
    /// Answered once everything sent before is committed.
    Flush(oneshot::Sender<()>),
}

/// The alarms of the gateway; clones share them.
#[derive(Clone)]
pub struct Alarms(Arc<Inner>);

struct Inner {
    book: Mutex<AlarmBook>,
    changes: broadcast::Sender<AlarmChange>,
    /// Counts the changes: what watches the alarms as a whole (the
    /// machines' views) wakes on it.
    version: watch::Sender<u64>,
    persist: mpsc::UnboundedSender<Persist>,
    /// The machine of each bus that has a network manager, with its
    /// alarms.
    machines: Mutex<BTreeMap<String, watch::Receiver<MachineView>>>,
    /// Whether the alarms of the last run were read back.
    restored: watch::Sender<bool>,
}

impl std::fmt::Debug for Alarms {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Alarms").finish_non_exhaustive()
    }
}

impl Alarms {
    /// The alarms persisted in `history`: read back (within a tokio
    /// runtime), the ones active before the restart kept active until
    /// [`RESTORE_SETTLE`] has passed without their cause.
    pub(crate) fn start(history: History) -> Self {
        let (persist, requests) = mpsc::unbounded_channel();
        let alarms = Self(Arc::new(Inner {
            book: Mutex::default(),
            changes: broadcast::channel(CHANGES_QUEUE).0,
            version: watch::channel(0).0,
            persist,
            machines: Mutex::default(),
            restored: watch::channel(false).0,
        }));
        match tokio::runtime::Handle::try_current() {
            Ok(runtime) => {
                runtime.spawn(write_history(history.clone(), requests));
                let restoring = alarms.clone();
                runtime.spawn(async move { restoring.restore(history).await });
            }
            // A gateway made outside a runtime serves no bus (one made for
            // its description only): nothing to follow, restore or write.
            Err(_) => {
                alarms.0.restored.send_replace(true);
            }
        }
        alarms
    }

    async fn restore(self, history: History) {
        match history.load_alarms().await {
            Ok(stored) => {
                let count = stored.iter().filter(|a| a.state.is_active()).count();
                if count > 0 {
                    tracing::info!("alarms: {count} active before the restart, re-evaluated");
                }
                *self.book() = AlarmBook::restore(stored);
            }
            Err(err) => tracing::warn!("alarms: the last run's could not be read: {err}"),
        }
        self.0.restored.send_replace(true);
        self.0.version.send_modify(|version| *version += 1);
        tokio::time::sleep(RESTORE_SETTLE).await;
        self.apply(|book| book.settle_restored(now_us()));
    }

    /// Whether the alarms of the last run are read back.
    pub(crate) fn is_restored(&self) -> bool {
        *self.0.restored.borrow()
    }

    /// Waits until the alarms of the last run are read back: the sources
    /// apply nothing before.
    pub(crate) async fn restored(&self) {
        let mut restored = self.0.restored.subscribe();
        let _ = restored.wait_for(|done| *done).await;
    }

    pub(super) fn book(&self) -> MutexGuard<'_, AlarmBook> {
        self.0.book.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Changes the book; what changed is persisted (in order) and
    /// published.
    pub(crate) fn apply(
        &self,
        change: impl FnOnce(&mut AlarmBook) -> Vec<Changed>,
    ) -> Vec<Changed> {
        let mut book = self.book();
        let changed = change(&mut book);
        if changed.is_empty() {
            return changed;
        }
        // Sent under the book's lock: the history gets the changes in the
        // order the book made them.
        let _ = self.0.persist.send(Persist::Changes(changed.clone()));
        drop(book);
        for change in &changed {
            let _ = self.0.changes.send(AlarmChange {
                alarm: change.alarm.clone(),
                step: change.event.step,
            });
        }
        self.0.version.send_modify(|version| *version += 1);
        changed
    }

    /// Raises the alarm of `source` (see [`AlarmBook::raise`]).
    pub(crate) fn raise(&self, source: AlarmSource, text: impl FnOnce() -> AlarmText) {
        self.apply(|book| book.raise(source, text, now_us()).into_iter().collect());
    }

    /// Clears the alarm of `source`.
    pub(crate) fn clear(&self, source: &AlarmSource) {
        self.apply(|book| book.clear(source, now_us()).into_iter().collect());
    }

    /// Waits until everything changed so far is in the history database.
    pub(crate) async fn flush(&self) {
        let (done, committed) = oneshot::channel();
        if self.0.persist.send(Persist::Flush(done)).is_ok() {
            let _ = committed.await;
        }
    }

    /// Every change from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<AlarmChange> {
        self.0.changes.subscribe()
    }

    /// Wakes on every change.
    pub fn watch(&self) -> watch::Receiver<u64> {
        self.0.version.subscribe()
    }

    /// The alarms that are not `normal` (of `bus`, or all), oldest first.
    pub fn open(&self, bus: Option<&str>) -> Vec<Alarm> {
        self.book().open_alarms(bus).into_iter().cloned().collect()
    }

    /// The counts of `bus`'s alarms (all buses: `None`), of `node` where
    /// given.
    pub fn summary(&self, bus: Option<&str>, node: Option<u8>) -> AlarmSummary {
        let book = self.book();
        let open = book.open_alarms(bus);
        AlarmSummary::of(
            open.into_iter()
                .filter(|alarm| node.is_none_or(|node| alarm.node == Some(node))),
        )
    }

    /// The active alarms whose source `which` picks.
    pub(crate) fn active(&self, which: impl Fn(&AlarmSource) -> bool) -> Vec<Alarm> {
        let book = self.book();
        book.active_sources(which)
            .into_iter()
            .filter_map(|source| {
                book.open_alarms(Some(&source.bus))
                    .into_iter()
                    .find(|alarm| alarm.source() == source)
                    .cloned()
            })
            .collect()
    }

    /// The machine view of `bus`, kept up to date from `machine` and the
    /// alarms by a task of its own.
    pub(crate) fn follow_machine(
        &self,
        bus: &str,
        mut machine: watch::Receiver<crate::canopen::manager::MachineStatus>,
    ) -> tokio::task::JoinHandle<()> {
        let view = |alarms: &Alarms, status| {
            let book = alarms.book();
            MachineView::new(status, &book.open_alarms(Some(bus)))
        };
        let (sender, receiver) = watch::channel(view(self, machine.borrow().clone()));
        self.0
            .machines
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .insert(bus.to_string(), receiver);
        let alarms = self.clone();
        let bus = bus.to_string();
        let mut version = self.watch();
        tokio::spawn(async move {
            loop {
                let status = machine.borrow_and_update().clone();
                let next = {
                    let book = alarms.book();
                    MachineView::new(status, &book.open_alarms(Some(&bus)))
                };
                sender.send_if_modified(|current| {
                    let changed = *current != next;
                    *current = next;
                    changed
                });
                tokio::select! {
                    changed = machine.changed() => if changed.is_err() { return },
                    changed = version.changed() => if changed.is_err() { return },
                }
            }
        })
    }

    fn machine(&self, bus: &str) -> Option<watch::Receiver<MachineView>> {
        self.0
            .machines
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .get(bus)
            .cloned()
    }
}

/// Writes the changes to the history in the order they came, a batch of
/// whatever arrived meanwhile per transaction.
async fn write_history(history: History, mut requests: mpsc::UnboundedReceiver<Persist>) {
    while let Some(first) = requests.recv().await {
        let mut batch = Vec::new();
        let mut flushes = Vec::new();
        let mut next = Some(first);
        while let Some(request) = next {
            match request {
                Persist::Changes(changes) => batch.extend(changes),
                Persist::Flush(done) => flushes.push(done),
            }
            next = requests.try_recv().ok();
        }
        if !batch.is_empty()
            && let Err(err) = history.record_alarms(batch).await
        {
            tracing::warn!("alarms: not written to the history: {err}");
        }
        for done in flushes {
            let _ = done.send(());
        }
    }
}

/// Now, µs since the Unix epoch.
pub(crate) fn now_us() -> i64 {
    i64::try_from(Timestamp::now().as_micros()).unwrap_or(i64::MAX)
}

/// Which alarms an acknowledgement of many takes (`POST /alarms/ack`):
/// every one optional.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct AckFilter {
    pub bus: Option<String>,
    pub node: Option<u8>,
    pub severity: Option<Severity>,
}

impl Gateway {
    /// The alarms `filter` matches, `page` (from 1) of
    /// [`super::PAGE_SIZE`].
    pub fn list_alarms(
        &self,
        caller: &Caller,
        filter: &AlarmFilter,
        page: usize,
    ) -> Result<AlarmPage, GatewayError> {
        self.require(caller, Operation::View)?;
        if page == 0 {
            return Err(GatewayError::InvalidRequest(
                "page counts from 1".to_string(),
            ));
        }
        let (alarms, total) = self.alarms.book().list(filter, page);
        Ok(AlarmPage { alarms, total })
    }

    /// One alarm with its history.
    pub fn alarm(&self, caller: &Caller, id: &str) -> Result<Alarm, GatewayError> {
        self.require(caller, Operation::View)?;
        let id = alarm_id(id)?;
        self.alarms
            .book()
            .get(id)
            .cloned()
            .ok_or_else(|| unknown(id))
    }

    /// An operator acknowledges alarm `id`, with a comment if they wish:
    /// who and when are kept with the alarm and in its history, and the
    /// answer comes once they are in the history database. An alarm that
    /// waits for no acknowledgement is answered as it is.
    ///
    /// Audited as `acknowledge alarm`. Acknowledging changes no device:
    /// it takes nothing from the caller's write rate.
    pub async fn acknowledge_alarm(
        &self,
        caller: &Caller,
        id: &str,
        comment: Option<String>,
    ) -> Result<Alarm, GatewayError> {
        let known = alarm_id(id)
            .ok()
            .and_then(|id| self.alarms.book().get(id).cloned());
        let mut target = AuditTarget::new("acknowledge alarm").item(format!("alarm {id}"));
        if let Some(alarm) = &known {
            target = target
                .bus(alarm.bus.clone())
                .node(alarm.node)
                .axis(alarm.axis);
        }
        let request = comment
            .as_ref()
            .map(|comment| serde_json::json!({ "comment": comment }).to_string());
        let row = self.audit_row(caller, target, request);
        let result = self.acknowledge_one(caller, id, comment).await;
        row.finish(&result).await;
        result
    }

    async fn acknowledge_one(
        &self,
        caller: &Caller,
        id: &str,
        comment: Option<String>,
    ) -> Result<Alarm, GatewayError> {
        self.admit(caller, Operation::AcknowledgeAlarm)?;
        let id = alarm_id(id)?;
        let comment = checked_comment(comment)?;
        let mut answer = None;
        self.alarms.apply(|book| {
            let Some((alarm, changed)) =
                book.acknowledge(id, &caller.who, comment.as_deref(), now_us())
            else {
                return Vec::new();
            };
            answer = Some(alarm);
            changed.into_iter().collect()
        });
        let alarm = answer.ok_or_else(|| unknown(id))?;
        self.alarms.flush().await;
        Ok(alarm)
    }

    /// Acknowledges every alarm `filter` matches that waits for an
    /// acknowledgement; the alarms acknowledged.
    ///
    /// Audited as `acknowledge alarms`, with the filter as the request.
    pub async fn acknowledge_alarms(
        &self,
        caller: &Caller,
        filter: AckFilter,
        comment: Option<String>,
    ) -> Result<Vec<Alarm>, GatewayError> {
        let target = AuditTarget::new("acknowledge alarms")
            .node(filter.node)
            .item(filter.severity.map(|s| format!("severity {s}")));
        let target = match &filter.bus {
            Some(bus) => target.bus(bus.clone()),
            None => target,
        };
        let request = serde_json::json!({
            "bus": filter.bus, "node": filter.node,
            "severity": filter.severity.map(Severity::name), "comment": comment,
        })
        .to_string();
        let row = self.audit_row(caller, target, Some(request));
        let result = async {
            self.admit(caller, Operation::AcknowledgeAlarm)?;
            if let Some(bus) = &filter.bus {
                self.bus(bus)?;
            }
            let comment = checked_comment(comment)?;
            let matching = AlarmFilter {
                bus: filter.bus.clone(),
                node: filter.node,
                severity: filter.severity,
                ..AlarmFilter::default()
            };
            let changed = self.alarms.apply(|book| {
                book.acknowledge_matching(&matching, &caller.who, comment.as_deref(), now_us())
            });
            self.alarms.flush().await;
            Ok(changed.into_iter().map(|change| change.alarm).collect())
        }
        .await;
        row.finish(&result).await;
        result
    }

    /// The alarms, to follow and count (the stream, Sparkplug, metrics).
    pub fn alarm_book(&self) -> &Alarms {
        &self.alarms
    }

    /// The machine of `bus` with its alarms: never `ready` while a
    /// `critical` or `high` alarm is active.
    pub fn machine_view(&self, bus: &str) -> Result<MachineView, GatewayError> {
        let served = self.bus(bus)?;
        let status = served.machine()?.status();
        let book = self.alarms.book();
        Ok(MachineView::new(status, &book.open_alarms(Some(bus))))
    }

    /// Every change of the machine of `bus` with its alarms; `None` for a
    /// bus without a network manager.
    pub fn watch_machine(&self, bus: &str) -> Option<watch::Receiver<MachineView>> {
        self.alarms.machine(bus)
    }
}

fn alarm_id(id: &str) -> Result<u64, GatewayError> {
    id.parse::<u64>()
        .ok()
        .filter(|id| *id > 0)
        .ok_or_else(|| GatewayError::InvalidRequest(format!("'{id}' is no alarm id (1, 2, ...)")))
}

fn unknown(id: u64) -> GatewayError {
    GatewayError::UnknownAlarm(format!("no alarm {id}"))
}

fn checked_comment(comment: Option<String>) -> Result<Option<String>, GatewayError> {
    match comment {
        Some(comment) if comment.chars().count() > MAX_COMMENT => {
            Err(GatewayError::InvalidRequest(format!(
                "the comment has {} characters; at most {MAX_COMMENT}",
                comment.chars().count()
            )))
        }
        Some(comment) if comment.trim().is_empty() => Ok(None),
        other => Ok(other),
    }
}
