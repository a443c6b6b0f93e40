//! The audit row of an operation, written by the operation itself, once,
//! whichever door called it ([`Gateway::audited`], [`AuditRow`]).
//!
//! An operation opens its row when it starts ([`Gateway::audit_row`]: the
//! caller, what it acts on, the request summarised) and finishes it with
//! its result ([`AuditRow::finish`]): the policy's refusals (role, write
//! rate, lease) as well as the device's and the successes. A row is part of
//! what a vanished client cannot cut: an operation whose transfer runs in a
//! task of its own finishes its row in that task
//! ([`crate::node::NodeHandle`]'s), and a row dropped before it was
//! finished (the caller's future dropped while the operation was under way
//! in it) is written anyway, outcome [`INTERRUPTED`].
//!
//! A door says what it knows of the request through the caller's
//! [`DoorRequest`] (its method and path or topic, its own request summary
//! where it has a better one), and learns from it whether an operation
//! audited the request ([`DoorRequest::audited`]): what no operation
//! audited (a door's own refusal, an operation not yet audited by the
//! gateway) the door writes itself through [`Gateway::audited_by_door`] or
//! an [`AuditRow`] of its own. A door that adds words known only once the
//! operation has answered (REST's status) asks for the rows to be handed
//! to it ([`DoorRequest::handed_over`]) and writes them with
//! [`Gateway::write_audit`]; rows it never takes are written when the last
//! holder of the request lets go.
//!
//! One request of a door may carry several commands, each its own
//! operation (a Sparkplug DCMD's metrics: each takes its role, lease and
//! write as it would alone), and still be one row: the door gathers the
//! operations' rows ([`DoorRequest::gathered`]) and
//! [`Gateway::audited_together`] folds them into the request's one row (its
//! operations named, the first failure its outcome), so that a message of
//! many metrics is not many rows.

use std::future::Future;
use std::sync::{Arc, Mutex, MutexGuard};

use crate::caller::Caller;
use crate::error::GatewayError;
use crate::history::{AuditEntry, History};
use crate::service::Gateway;

/// The outcome of an operation whose caller went away before it ended: its
/// transfers run to their end, but what came after them did not.
pub(crate) const INTERRUPTED: &str = "interrupted";

/// What an operation acts on, as its audit row names it.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct AuditTarget {
    /// In words: `write object`, `nmt command`, `move`.
    pub operation: String,
    pub bus: Option<String>,
    pub node: Option<u8>,
    pub axis: Option<u8>,
    /// The object (`0x6040:0`), PDO (`tpdo 1`), segment, lease named.
    pub item: Option<String>,
}

impl AuditTarget {
    pub fn new(operation: impl Into<String>) -> Self {
        Self {
            operation: operation.into(),
            ..Self::default()
        }
    }

    pub fn bus(mut self, bus: impl Into<String>) -> Self {
        self.bus = Some(bus.into());
        self
    }

    pub fn node(mut self, node: impl Into<Option<u8>>) -> Self {
        self.node = node.into();
        self
    }

    pub fn axis(mut self, axis: impl Into<Option<u8>>) -> Self {
        self.axis = axis.into();
        self
    }

    pub fn item(mut self, item: impl Into<Option<String>>) -> Self {
        self.item = item.into();
        self
    }
}

/// What a door knows of the request its caller makes: its own words for
/// it (REST's method and path, CiA 309-3's `ASCII` and command line,
/// Sparkplug's message type and topic) and its own summary of the request
/// where it has one (REST's JSON body, masked; a CiA 309 value as `u16
/// 1000`), which the row takes over the operation's.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DoorDetail {
    pub method: Option<String>,
    pub path: Option<String>,
    pub summary: Option<String>,
}

impl DoorDetail {
    pub fn new(method: impl Into<String>, path: impl Into<String>) -> Self {
        Self {
            method: Some(method.into()),
            path: Some(path.into()),
            summary: None,
        }
    }

    pub fn summary(mut self, summary: Option<String>) -> Self {
        self.summary = summary;
        self
    }
}

/// One request of a door, shared by the door and the caller it hands the
/// gateway (clones of a [`Caller`] share it): the door's [`DoorDetail`],
/// and how many operations audited the request.
#[derive(Clone)]
pub struct DoorRequest(Arc<Shared>);

struct Shared {
    detail: DoorDetail,
    /// Rows are handed to the door (or gathered into the request's one
    /// row) rather than written.
    hand_over: bool,
    /// Several operations' rows are gathered into one
    /// ([`DoorRequest::gathered`]).
    gathered: bool,
    /// Shared with the request's parts ([`DoorRequest::part`]).
    state: Arc<Held>,
}

/// What the operations of a request left; what no door took is written
/// when the last holder lets go.
struct Held(Mutex<State>);

#[derive(Default)]
struct State {
    /// Rows the operations finished (written or handed over), and
    /// operations that decided none was due (a renewal between two
    /// audited ones).
    audited: usize,
    /// Rows handed over and not taken yet, and where to write them if the
    /// door never does.
    held: Vec<AuditEntry>,
    /// A door's own row whose future was dropped: written when the request
    /// ends, unless an operation audited it by then.
    fallback: Option<AuditEntry>,
    history: Option<History>,
}

impl DoorRequest {
    /// A request whose rows the operations write.
    pub fn new(detail: DoorDetail) -> Self {
        Self::build(detail, false, false)
    }

    /// A request whose rows are handed to the door, which writes them with
    /// its own words added ([`DoorRequest::take_rows`]).
    pub fn handed_over(detail: DoorDetail) -> Self {
        Self::build(detail, true, false)
    }

    /// A request of several operations that is one row: their rows are
    /// gathered, and [`Gateway::audited_together`] writes the one row that
    /// stands for them all (rows it never takes are written as they are
    /// when the last holder of the request lets go).
    pub fn gathered(detail: DoorDetail) -> Self {
        Self::build(detail, true, true)
    }

    fn build(detail: DoorDetail, hand_over: bool, gathered: bool) -> Self {
        Self(Arc::new(Shared {
            detail,
            hand_over,
            gathered,
            state: Arc::new(Held(Mutex::new(State::default()))),
        }))
    }

    /// One command of a gathered request, with its own summary (the
    /// door's words for that command, bounded): its operation's row is a
    /// part of the request's, and a request of that command alone has
    /// that summary as its request, as the command's row would.
    pub fn part(&self, summary: Option<String>) -> Self {
        Self(Arc::new(Shared {
            detail: self.0.detail.clone().summary(summary),
            hand_over: self.0.hand_over,
            gathered: self.0.gathered,
            state: self.0.state.clone(),
        }))
    }

    pub fn detail(&self) -> &DoorDetail {
        &self.0.detail
    }

    /// Whether an operation audited the request (or decided it was not due
    /// a row): the door writes none for it.
    pub fn audited(&self) -> bool {
        self.audits() > 0
    }

    /// How many operations audited the request so far (rows finished, or
    /// decided not due).
    fn audits(&self) -> usize {
        self.state().audited
    }

    /// The rows handed over so far, taken: the door writes them.
    pub fn take_rows(&self) -> Vec<AuditEntry> {
        std::mem::take(&mut self.state().held)
    }

    fn state(&self) -> MutexGuard<'_, State> {
        self.0
            .state
            .0
            .lock()
            .unwrap_or_else(|poison| poison.into_inner())
    }

    /// Counts an operation's row; `Some(entry)` when it is to be written
    /// now, `None` when the door takes it.
    fn count(&self, entry: Option<AuditEntry>, history: &History) -> Option<AuditEntry> {
        let mut state = self.state();
        state.audited += 1;
        let entry = entry?;
        if !self.0.hand_over {
            return Some(entry);
        }
        state.held.push(entry);
        state.history.get_or_insert_with(|| history.clone());
        None
    }

    /// Keeps a door's own row whose future was dropped until the request
    /// ends.
    fn park(&self, entry: AuditEntry, history: &History) {
        let mut state = self.state();
        state.fallback = Some(entry);
        state.history.get_or_insert_with(|| history.clone());
    }
}

impl Drop for Held {
    fn drop(&mut self) {
        let state = self
            .0
            .get_mut()
            .unwrap_or_else(|poison| poison.into_inner());
        let mut held = std::mem::take(&mut state.held);
        if state.audited == 0 {
            held.extend(state.fallback.take());
        }
        if let (false, Some(history)) = (held.is_empty(), state.history.take()) {
            // The door went away before it wrote them: written as they are.
            spawn_write(history, held);
        }
    }
}

impl std::fmt::Debug for DoorRequest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DoorRequest")
            .field("detail", &self.0.detail)
            .field("hand_over", &self.0.hand_over)
            .finish_non_exhaustive()
    }
}

/// One request is equal to itself only.
impl PartialEq for DoorRequest {
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.0, &other.0)
    }
}

impl Eq for DoorRequest {}

/// A row being written ([`AuditRow::finish`]): it holds nothing of the
/// result it was finished with.
pub(crate) type Finishing = std::pin::Pin<Box<dyn Future<Output = ()> + Send + 'static>>;

/// The audit row of one operation under way: finished with its result,
/// written once. Dropped unfinished, it is written with the outcome
/// `INTERRUPTED`.
#[must_use = "an audit row is written when it is finished"]
pub struct AuditRow {
    entry: Option<AuditEntry>,
    history: History,
    door: Option<DoorRequest>,
    /// A door's own row: written only if no operation audited the request
    /// (since `audits_before`).
    fallback: bool,
    audits_before: usize,
}

impl AuditRow {
    /// The row of `caller`'s operation on `target`, started now; `request`
    /// is the operation's summary of its request, unless the caller's door
    /// has its own.
    pub fn new(
        history: &History,
        caller: &Caller,
        target: AuditTarget,
        request: Option<String>,
    ) -> Self {
        let AuditTarget {
            operation,
            bus,
            node,
            axis,
            item,
        } = target;
        let mut entry = AuditEntry::new(caller, operation).target(bus, node, axis, item);
        let detail = caller.door.as_ref().map(DoorRequest::detail);
        entry.request = detail.and_then(|d| d.summary.clone()).or(request);
        if let Some(detail) = detail {
            entry.method = detail.method.clone();
            entry.path = detail.path.clone();
        }
        Self {
            entry: Some(entry),
            history: history.clone(),
            door: caller.door.clone(),
            fallback: false,
            audits_before: 0,
        }
    }

    /// A door's own row: written only if no operation audited the request
    /// (in a gathered request, none since the row was opened: an earlier
    /// command's operation does not stand for this one).
    fn door_own(mut self) -> Self {
        self.fallback = true;
        self.audits_before = match &self.door {
            Some(door) if door.0.gathered => door.audits(),
            _ => 0,
        };
        self
    }

    /// Words added to the operation (`took over the velocity lease 3f2a…
    /// of hmi`).
    pub fn note(&mut self, words: &str) {
        if let Some(entry) = &mut self.entry {
            entry.operation = format!("{}; {words}", entry.operation);
        }
    }

    /// The item, once the operation knows it.
    pub fn set_item(&mut self, item: String) {
        if let Some(entry) = &mut self.entry {
            entry.item = Some(item);
        }
    }

    /// Writes the row with `result`'s outcome (the future borrows nothing
    /// of it).
    pub fn finish<T>(mut self, result: &Result<T, GatewayError>) -> Finishing {
        let entry = self.entry.take().map(|entry| entry.outcome(result));
        Box::pin(async move {
            if let Some(entry) = entry {
                self.commit(entry).await;
            }
        })
    }

    /// Writes the row with an outcome that is no [`GatewayError`] (the
    /// network manager's `boot_failed`).
    pub async fn finish_as(mut self, outcome: &str) {
        if let Some(entry) = self.entry.take() {
            self.commit(entry.failed(outcome, None)).await;
        }
    }

    /// Writes the row of an operation that succeeded.
    pub async fn finish_ok(self) {
        self.finish_as(crate::history::OK).await;
    }

    /// The operation decided no row is due (a renewal between two audited
    /// ones): none is written, and the door writes none either.
    pub fn skip(mut self) {
        self.entry = None;
        if let Some(door) = &self.door {
            door.count(None, &self.history);
        }
    }

    async fn commit(&self, entry: AuditEntry) {
        if self.fallback
            && self
                .door
                .as_ref()
                .is_some_and(|door| door.audits() > self.audits_before)
        {
            return;
        }
        let entry = match &self.door {
            Some(door) => door.count(Some(entry), &self.history),
            None => Some(entry),
        };
        if let Some(entry) = entry {
            write(&self.history, entry).await;
        }
    }
}

impl Drop for AuditRow {
    fn drop(&mut self) {
        let Some(entry) = self.entry.take() else {
            return;
        };
        let entry = entry.failed(INTERRUPTED, None);
        if self.fallback {
            // An operation it called may still be finishing its own row.
            match &self.door {
                Some(door) => door.park(entry, &self.history),
                None => spawn_write(self.history.clone(), vec![entry]),
            }
            return;
        }
        let entry = match &self.door {
            Some(door) => door.count(Some(entry), &self.history),
            None => Some(entry),
        };
        if let Some(entry) = entry {
            spawn_write(self.history.clone(), vec![entry]);
        }
    }
}

/// Runs `work` and finishes `row` with its outcome, both in a task of their
/// own: a caller that goes away cuts neither.
pub async fn spawn_audited<T, Fut>(row: AuditRow, work: Fut) -> Result<T, GatewayError>
where
    T: Send + 'static,
    Fut: Future<Output = Result<T, GatewayError>> + Send + 'static,
{
    tokio::spawn(async move {
        let result = work.await;
        row.finish(&result).await;
        result
    })
    .await
    .map_err(|err| GatewayError::Internal(format!("operation task: {err}")))?
}

async fn write(history: &History, entry: AuditEntry) {
    let what = format!("{} ({})", entry.operation, entry.channel);
    if let Err(err) = history.audit(entry).await {
        tracing::error!("audit: {what}: not recorded: {err}");
    }
}

/// The one row of a request (`whole`, its outcome the door's work's) that
/// stands for the rows of its operations (`parts`): see
/// [`Gateway::audited_together`].
fn together(mut whole: AuditEntry, parts: Vec<AuditEntry>) -> AuditEntry {
    let shared = |field: fn(&AuditEntry) -> &Option<String>| {
        let first = parts.first().and_then(|part| field(part).clone());
        parts
            .iter()
            .all(|part| *field(part) == first)
            .then_some(first)
            .flatten()
    };
    let item = shared(|part| &part.item);
    let axis = parts.first().and_then(|part| part.axis);
    let axis = parts
        .iter()
        .all(|part| part.axis == axis)
        .then_some(axis)
        .flatten();
    let mut operations: Vec<&str> = Vec::new();
    for part in &parts {
        if !operations.contains(&part.operation.as_str()) {
            operations.push(&part.operation);
        }
    }
    if !operations.is_empty() {
        whole.operation = operations.join(", ");
    }
    whole.item = item.or(whole.item);
    whole.axis = axis.or(whole.axis);
    if let Some(part) = parts.first() {
        whole.bus = part.bus.clone().or(whole.bus);
        whole.node = part.node.or(whole.node);
    }
    if let [part] = parts.as_slice() {
        whole.request = part.request.clone().or(whole.request);
    }
    let failed: Vec<&AuditEntry> = parts
        .iter()
        .filter(|part| part.outcome != crate::history::OK)
        .collect();
    if let Some(first) = failed.first() {
        whole.outcome = first.outcome.clone();
        whole.abort_code = first.abort_code.clone();
        // The count goes with the request, not into the operation's words:
        // a row is found by what was done (`move`) however it ended.
        if parts.len() > 1 {
            let count = format!("{} of {} failed", failed.len(), parts.len());
            whole.request = Some(match whole.request.take() {
                Some(request) => format!("{request} ({count})"),
                None => count,
            });
        }
    }
    whole
}

/// Writes `entries` in a task: from a `Drop`, which cannot wait.
fn spawn_write(history: History, entries: Vec<AuditEntry>) {
    match tokio::runtime::Handle::try_current() {
        Ok(runtime) => {
            runtime.spawn(async move {
                for entry in entries {
                    write(&history, entry).await;
                }
            });
        }
        Err(_) => {
            for entry in entries {
                tracing::error!(
                    "audit: {} ({}): not recorded: no runtime left to write it",
                    entry.operation,
                    entry.channel
                );
            }
        }
    }
}

impl Gateway {
    /// Opens the audit row of `caller`'s operation on `target`.
    pub fn audit_row(
        &self,
        caller: &Caller,
        target: AuditTarget,
        request: Option<String>,
    ) -> AuditRow {
        AuditRow::new(&self.history, caller, target, request)
    }

    /// Runs `operation` and writes its row, once, with its outcome (also
    /// if the caller goes away before it ends: `INTERRUPTED`).
    pub async fn audited<T>(
        &self,
        caller: &Caller,
        target: AuditTarget,
        request: Option<String>,
        operation: impl Future<Output = Result<T, GatewayError>>,
    ) -> Result<T, GatewayError> {
        let row = self.audit_row(caller, target, request);
        let result = operation.await;
        row.finish(&result).await;
        result
    }

    /// For a door: runs `work` (which may call audited operations) and
    /// writes a row of `target` only if no operation audited the request
    /// (`caller` carries a [`DoorRequest`]; without one, the row is always
    /// written). A door's own refusal, or a command the gateway does not
    /// audit yet, is written so; an operation's row never twice.
    pub async fn audited_by_door<T>(
        &self,
        caller: &Caller,
        target: AuditTarget,
        request: Option<String>,
        work: impl Future<Output = Result<T, GatewayError>>,
    ) -> Result<T, GatewayError> {
        let row = self.audit_row(caller, target, request).door_own();
        let result = work.await;
        row.finish(&result).await;
        result
    }

    /// For a door whose one request carries several commands (a Sparkplug
    /// DCMD's metrics), `caller` carrying a [`DoorRequest::gathered`]: runs
    /// `work`, in which each command runs its own operation (or the door's
    /// own refusal, [`Gateway::audited_by_door`]) with a clone of
    /// `caller`, and writes ONE row for the request, of `target` and the
    /// door's summary: one operation's row is the request's (its words,
    /// axis, item); several are named together (`write object, nmt
    /// command`), the axis and item kept where they share them, the first
    /// failure is the outcome and the request says how many failed
    /// (`… (2 of 3 failed)`); a request of one command has its summary
    /// ([`DoorRequest::part`]) or its operation's as its request, as that
    /// command's row alone would. When every
    /// operation decided no row was due (lease renewals between two
    /// audited ones) and nothing failed, none is written.
    pub async fn audited_together<T>(
        &self,
        caller: &Caller,
        target: AuditTarget,
        request: Option<String>,
        work: impl Future<Output = Result<T, GatewayError>>,
    ) -> Result<T, GatewayError> {
        // Written here, not gathered with the parts (a dropped future
        // still writes it, interrupted).
        let mut whole = self.audit_row(caller, target, request);
        let door = whole.door.take();
        let result = work.await;
        let (parts, audits) = match &door {
            Some(door) => (door.take_rows(), door.audits()),
            None => (Vec::new(), 0),
        };
        let Some(entry) = whole.entry.take() else {
            return result;
        };
        if parts.is_empty() && audits > 0 && result.is_ok() {
            return result;
        }
        write(&self.history, together(entry.outcome(&result), parts)).await;
        result
    }

    /// The row of a door's own on `target`, written with
    /// [`AuditRow::finish`] only if no operation audited the request (as
    /// [`Gateway::audited_by_door`]).
    pub fn door_audit_row(
        &self,
        caller: &Caller,
        target: AuditTarget,
        request: Option<String>,
    ) -> AuditRow {
        self.audit_row(caller, target, request).door_own()
    }

    /// Writes a row a door finished (REST's, with its status): see
    /// [`DoorRequest::handed_over`].
    pub async fn write_audit(&self, entry: AuditEntry) {
        write(&self.history, entry).await;
    }
}

#[cfg(test)]
pub(crate) mod tests;
