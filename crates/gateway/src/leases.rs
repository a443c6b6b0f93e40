//! The motion leases the gateway grants, and their supervisor (the policy
//! and its table are [`super::motion_lease`]): a velocity, torque or
//! duty-cycle move holds a lease that its client renews; an interpolated
//! move holds one while its request feeds points. A supervisor task halts
//! the axis of every lease that lapses, and quick-stops it if it is not
//! stopped one period later; the audit log records what it did.

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, OnceLock};
use std::time::Duration;

use tokio::sync::Notify;
use tokio::time::Instant;

use super::GatewayError;
use super::audit::AuditTarget;
use super::caller::Caller;
use super::motion_lease::{AxisKey, LeaseError, LeaseTable, MotionLease, mask};
use super::policy::Operation;
use super::safe_stop::{AxisStop, HALT_TIMEOUT, StopAttempt, StopMethod, StopOutcome};
use super::service::Gateway;

/// How often the status of a lapsed lease's axis is read while it slows
/// down under halt.
const STOPPING_POLL: Duration = Duration::from_millis(50);
/// Stream renewals of one lease are audited once, then at most once per
/// this interval (a client renews every second or so); so are a stream
/// session's refused renewals.
pub const RENEWAL_AUDIT_EVERY: Duration = Duration::from_secs(60);

/// The gateway's leases and the task that stops the lapsed ones.
#[derive(Debug)]
pub(crate) struct MotionLeases {
    table: Mutex<LeaseTable>,
    period: Duration,
    /// Wakes the supervisor when the earliest expiry may have moved closer.
    wake: Notify,
    supervisor: OnceLock<()>,
    next_session: AtomicU64,
}

impl MotionLeases {
    pub(crate) fn new(period: Duration) -> Self {
        Self {
            table: Mutex::new(LeaseTable::new()),
            period,
            wake: Notify::new(),
            supervisor: OnceLock::new(),
            next_session: AtomicU64::new(1),
        }
    }

    pub(crate) fn period(&self) -> Duration {
        self.period
    }

    fn table(&self) -> MutexGuard<'_, LeaseTable> {
        self.table
            .lock()
            .unwrap_or_else(|poison| poison.into_inner())
    }

    /// Refuses a command on a held axis that does not present its lease,
    /// or that `by` presents who is not its holder.
    pub(crate) fn check(
        &self,
        axis: &AxisKey,
        presented: Option<&str>,
        by: &str,
    ) -> Result<(), GatewayError> {
        Ok(self.table().check(axis, presented, by, Instant::now())?)
    }

    /// An explicit take-over of `axis` (audited by the caller): the lease
    /// held on it ends and is returned; the axis is not stopped.
    pub(crate) fn take_over(&self, axis: &AxisKey) -> Option<MotionLease> {
        let previous = self.table().take_over(axis, Instant::now());
        if let Some(lease) = &previous {
            tracing::warn!(
                "motion lease {} of {} on {} ({}) taken over",
                mask(&lease.id),
                lease.holder,
                lease.axis,
                lease.mode
            );
        }
        previous
    }

    /// Whether a stream renewal of `id` is to be audited now (the first,
    /// then one per [`RENEWAL_AUDIT_EVERY`]).
    pub(crate) fn renewal_audit_due(&self, id: &str) -> bool {
        self.table()
            .audit_due(id, RENEWAL_AUDIT_EVERY, Instant::now())
    }

    /// Grants (or, presented, renews) the lease for a move on `axis`, and
    /// starts the supervisor on the first one. A new lease's id is
    /// `chosen` (a caller that gets no answer names it: MQTT), else made
    /// here.
    pub(crate) fn grant(
        &self,
        gateway: &Gateway,
        axis: AxisKey,
        presented: Option<&str>,
        chosen: Option<&str>,
        holder: &str,
        mode: &str,
    ) -> Result<MotionLease, GatewayError> {
        let lease = self.table().grant(
            axis,
            presented,
            chosen.map_or_else(fresh_id, str::to_string),
            holder,
            mode,
            self.period,
            Instant::now(),
        )?;
        self.supervisor.get_or_init(|| {
            tokio::spawn(supervise(gateway.clone()));
        });
        self.wake.notify_one();
        Ok(lease)
    }

    /// Renews the lease `id` for `by`, its holder (`None`: the gateway
    /// itself), binding it to a stream session when given.
    pub(crate) fn renew(
        &self,
        id: &str,
        by: Option<&str>,
        session: Option<u64>,
    ) -> Result<MotionLease, GatewayError> {
        Ok(self.table().renew(id, by, session, Instant::now())?)
    }

    /// Renews the lease `id` held on `axis` for `by`: a lease id is not
    /// renewed through a request that names another axis.
    pub(crate) fn renew_on(
        &self,
        axis: &AxisKey,
        id: &str,
        by: &str,
    ) -> Result<MotionLease, GatewayError> {
        let held = self.table().get(axis, Instant::now()).map(|l| l.id.clone());
        if held.as_deref() != Some(id) {
            return Err(LeaseError::Unknown(id.to_string()).into());
        }
        self.renew(id, Some(by), None)
    }

    /// Lapses the lease `id` held on `axis` now, for `by`, its holder: its
    /// client gives it up, and the supervisor stops the axis.
    pub(crate) fn lapse_on(&self, axis: &AxisKey, id: &str, by: &str) -> Result<(), GatewayError> {
        let held = self.table().get(axis, Instant::now()).cloned();
        match held {
            Some(lease) if lease.id == id && lease.holder != by => Err(LeaseError::NotHolder {
                id: id.to_string(),
                axis: axis.clone(),
                holder: lease.holder,
                by: by.to_string(),
            }
            .into()),
            Some(lease) if lease.id == id => {
                self.lapse_now(id);
                Ok(())
            }
            _ => Err(LeaseError::Unknown(id.to_string()).into()),
        }
    }

    /// The lease on `axis` is over: its motion was stopped (or is bounded).
    pub(crate) fn release(&self, axis: &AxisKey) -> Option<MotionLease> {
        self.table().release(axis)
    }

    /// The leases held on the axes of `node` of `bus`, lapsed ones too
    /// (their stop may not have begun).
    pub(crate) fn on_node(&self, bus: &str, node: u8) -> Vec<MotionLease> {
        self.table().on_node(bus, node)
    }

    /// Ends every lease (STOP ALL, shutdown): their axes are being stopped.
    pub(crate) fn release_all(&self) -> usize {
        self.table().release_all().len()
    }

    /// Lapses the lease `id` now (its client went away), so that the
    /// supervisor stops its axis; an unknown id is nothing to do.
    pub(crate) fn lapse_now(&self, id: &str) {
        let now = Instant::now();
        let mut table = self.table();
        if let Ok(lease) = table.release_id(id) {
            // Put back, expired: the supervisor takes it as lapsed.
            let axis = lease.axis.clone();
            let _ = table.grant(
                axis,
                None,
                lease.id,
                &lease.holder,
                &lease.mode,
                Duration::ZERO,
                now,
            );
        }
        drop(table);
        self.wake.notify_one();
    }

    /// A number for a new stream session.
    pub(crate) fn new_session(&self) -> u64 {
        self.next_session.fetch_add(1, Ordering::Relaxed)
    }

    /// The stream session ended: the leases it renewed lapse now.
    pub(crate) fn session_ended(&self, session: u64) {
        if self.table().session_ended(session, Instant::now()) > 0 {
            self.wake.notify_one();
        }
    }

    /// Whether `id` is the lease held on `axis` now.
    pub(crate) fn holds(&self, axis: &AxisKey, id: &str) -> bool {
        self.table()
            .get(axis, Instant::now())
            .is_some_and(|lease| lease.id == id)
    }

    /// How many leases are held.
    pub(crate) fn held(&self) -> usize {
        self.table().len()
    }
}

impl Default for MotionLeases {
    fn default() -> Self {
        Self::new(super::motion_lease::DEFAULT_PERIOD)
    }
}

/// 128 bits from the operating system's generator, as hex: a lease is the
/// right to move an axis, so its id must not be guessable.
fn fresh_id() -> String {
    use std::io::Read;
    let mut bytes = [0u8; 16];
    let read = std::fs::File::open("/dev/urandom").and_then(|mut f| f.read_exact(&mut bytes));
    if read.is_err() {
        // No /dev/urandom (not Linux): the standard library's hasher keys
        // are drawn from the system's generator too.
        use std::hash::{BuildHasher, Hasher};
        for chunk in bytes.chunks_mut(8) {
            let mut hasher = std::collections::hash_map::RandomState::new().build_hasher();
            hasher.write_u128(Instant::now().elapsed().as_nanos());
            chunk.copy_from_slice(&hasher.finish().to_le_bytes());
        }
    }
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Sleeps until the next lease expires (or the table changes), then stops
/// the axes of the lapsed ones, each in a task of its own.
async fn supervise(gateway: Gateway) {
    let leases = gateway.leases.clone();
    loop {
        let next = leases.table().next_expiry();
        match next {
            Some(at) => {
                tokio::select! {
                    () = tokio::time::sleep_until(at) => {}
                    () = leases.wake.notified() => {}
                }
            }
            None => leases.wake.notified().await,
        }
        let lapsed = leases.table().lapsed(Instant::now());
        for lease in lapsed {
            tokio::spawn(stop_lapsed(gateway.clone(), lease));
        }
    }
}

/// How a lapsed lease's axis was stopped.
#[derive(Debug, Clone, PartialEq)]
enum LapseStop {
    /// Halted, and at rest (or no longer enabled) within a period.
    Halted,
    /// Still moving a period after halt, or halt could not be given:
    /// quick-stopped (confirmed by the drive), or found not enabled.
    QuickStopped,
    /// The drive did not confirm the quick stop: the node was sent NMT stop.
    NotConfirmed {
        error: GatewayError,
        attempts: Vec<StopAttempt>,
    },
}

async fn stop_lapsed(gateway: Gateway, lease: MotionLease) {
    tracing::warn!(
        "motion lease {} of {} on {} ({}) lapsed: halting the axis",
        mask(&lease.id),
        lease.holder,
        lease.axis,
        lease.mode
    );
    let result = halt_then_quick_stop(&gateway, &lease).await;
    let (error, outcome) = match &result {
        Ok(LapseStop::Halted) => (None, "halted"),
        Ok(LapseStop::QuickStopped) => (None, "quick-stopped"),
        Ok(LapseStop::NotConfirmed { error, attempts }) => {
            tracing::error!(
                "lapsed lease on {}: the quick stop was not confirmed ({error}); attempts: {attempts:?}",
                lease.axis
            );
            let nmt = attempts
                .iter()
                .any(|a| a.method == StopMethod::NmtStop && a.outcome == StopOutcome::Sent);
            let outcome = if nmt {
                "not confirmed, node sent NMT stop"
            } else {
                "not stopped"
            };
            (Some(error), outcome)
        }
        Err(error) => {
            tracing::error!(
                "lapsed lease on {}: the axis could not be stopped: {error}",
                lease.axis
            );
            (Some(error), "not stopped")
        }
    };
    let AxisKey { bus, node, axis } = lease.axis.clone();
    gateway.work_done(crate::alarms::WorkDone::LeaseHalted {
        bus: bus.clone(),
        node,
        axis,
    });
    let item = format!(
        "{} lease of {} ({} ms)",
        lease.mode,
        lease.holder,
        lease.period.as_millis()
    );
    let target = AuditTarget::new(format!("motion lease lapsed: axis {outcome}"))
        .bus(bus)
        .node(node)
        .axis(axis)
        .item(item);
    let row = gateway.audit_row(&Caller::system(), target, None);
    match error {
        Some(error) => row.finish(&Err::<(), _>(error.clone())).await,
        None => row.finish_ok().await,
    }
}

/// Halt, then wait up to one lease period for the axis to come to rest;
/// quick stop if it has not (NMT stop of the node if the drive does not
/// confirm). If halt cannot be given, or the axis cannot be read, the
/// quick stop is tried at once. Whatever the gateway believes of the node.
async fn halt_then_quick_stop(
    gateway: &Gateway,
    lease: &MotionLease,
) -> Result<LapseStop, GatewayError> {
    let AxisKey { bus, node, axis } = &lease.axis;
    let gates = gateway.gates(bus);
    let (bus, drive) = gateway.stop_target(bus, &node.to_string(), &axis.to_string())?;
    // A lapse is a stop: whatever runs on the axis (a step test whose
    // client went away) sends nothing more.
    gates.cancel(&drive);
    // In a task of its own, like every drive sequence: nothing cancels it
    // half way.
    let period = lease.period;
    let task = tokio::spawn(async move {
        // A command's write on the wire goes first; the halt then (not
        // under the gate: the halt waits for the node's procedure, which a
        // command holds until its next write finds the stop).
        drop(gates.gate(&drive).await);
        match tokio::time::timeout(HALT_TIMEOUT, drive.halt(true)).await {
            Ok(Ok(_)) => {
                let deadline = Instant::now() + period;
                loop {
                    let Ok(Ok(status)) = tokio::time::timeout(HALT_TIMEOUT, drive.status()).await
                    else {
                        break;
                    };
                    let at_rest = status.velocity.map_or(status.target_reached, |v| v == 0);
                    if status.state != "operation_enabled" || at_rest {
                        return LapseStop::Halted;
                    }
                    if Instant::now() >= deadline {
                        break;
                    }
                    tokio::time::sleep(STOPPING_POLL).await;
                }
            }
            Ok(Err(error)) => tracing::error!("halt failed ({error}); quick stop instead"),
            Err(_) => tracing::error!("halt not given in time; quick stop instead"),
        }
        match Gateway::quick_stop_or_nmt(bus, drive, Some(gates)).await {
            AxisStop::Stopped(_) | AxisStop::NotEnabled(_) => LapseStop::QuickStopped,
            AxisStop::Failed { error, attempts } => LapseStop::NotConfirmed { error, attempts },
        }
    });
    task.await
        .map_err(|err| GatewayError::Internal(format!("stopping a lapsed axis: {err}")))
}

/// Keeps a lease alive while a request that holds it runs (an interpolated
/// move feeding its points); if the request is dropped — its client hung
/// up — the lease lapses at once and the axis is stopped.
pub(crate) struct InFlight {
    leases: Arc<MotionLeases>,
    id: String,
    done: bool,
}

impl InFlight {
    pub(crate) fn new(leases: &Arc<MotionLeases>, lease: &MotionLease) -> Self {
        Self {
            leases: leases.clone(),
            id: lease.id.clone(),
            done: false,
        }
    }

    /// Renews the lease every third of a period until `work` ends.
    pub(crate) async fn run<T>(mut self, work: impl Future<Output = T>) -> T {
        let leases = self.leases.clone();
        let every = (leases.period() / 3).max(Duration::from_millis(10));
        let work = std::pin::pin!(work);
        let mut work = work;
        let result = loop {
            tokio::select! {
                result = &mut work => break result,
                () = tokio::time::sleep(every) => {
                    // Lapsed already (a stop ended it): nothing to keep.
                    let _ = leases.renew(&self.id, None, None);
                }
            }
        };
        self.done = true;
        result
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        if !self.done {
            tracing::warn!(
                "the client of lease {} went away mid-request",
                mask(&self.id)
            );
            self.leases.lapse_now(&self.id);
        }
    }
}

/// A stream session's hold on the leases it renews: they lapse when it
/// is dropped (the client went away), so that their axes stop. It keeps
/// the session's refused renewals too, audited one row per
/// [`RENEWAL_AUDIT_EVERY`] (a client may send a thousand a second).
#[derive(Debug)]
pub struct LeaseSession {
    leases: Arc<MotionLeases>,
    session: u64,
    refusals: RefusalAudit,
}

impl Drop for LeaseSession {
    fn drop(&mut self) {
        self.leases.session_ended(self.session);
    }
}

/// When a session's refused renewal was last audited, and how many were
/// left out since.
#[derive(Debug, Default)]
struct RefusalAudit {
    last: Option<Instant>,
    left_out: u64,
}

impl RefusalAudit {
    /// A refusal at `now`: `Some(left out since the last row)` when it is
    /// due a row, else counted into the next.
    fn due(&mut self, now: Instant) -> Option<u64> {
        let due = self
            .last
            .is_none_or(|last| now.saturating_duration_since(last) >= RENEWAL_AUDIT_EVERY);
        if !due {
            self.left_out += 1;
            return None;
        }
        self.last = Some(now);
        Some(std::mem::take(&mut self.left_out))
    }
}

/// The leases as the doors see them: their period, how many are held, and
/// a door's own session of renewals (the stream's); the grant and the
/// check are `crate::motion`'s.
impl Gateway {
    /// The period a lease lasts without a renewal (`--lease-ms`).
    pub fn lease_period(&self) -> Duration {
        self.leases.period()
    }

    /// How many leases are held.
    pub fn leases_held(&self) -> usize {
        self.leases.held()
    }

    /// Lapses the lease `id` now (its client can renew it no more: a lost
    /// broker), so that the supervisor stops its axis; an unknown id is
    /// nothing to do.
    pub fn lapse_lease(&self, id: &str) {
        self.leases.lapse_now(id);
    }

    /// A new session of renewals (a stream client's): the leases it renews
    /// lapse when it is dropped.
    pub fn lease_session(&self) -> LeaseSession {
        LeaseSession {
            session: self.leases.new_session(),
            leases: self.leases.clone(),
            refusals: RefusalAudit::default(),
        }
    }

    /// Renews the lease `id` for `caller` (a stream client's, channel
    /// `websocket`) and binds it to `session`, so that it lapses when the
    /// session ends. An operator's ([`Operation::RenewLease`]), and only
    /// the lease's holder renews it (another caller: `lease_conflict`; an
    /// id not held: `unknown_lease`). It takes no write of the caller's
    /// rate, as no renewal does: a renewal refused for the rate would
    /// lapse the lease and halt the axis under a busy client.
    ///
    /// Audited as `renew motion lease (stream)`, in a task (the session
    /// never waits for the disk): the first renewal of each lease, then
    /// one a minute ([`RENEWAL_AUDIT_EVERY`]); refusals one a minute per
    /// session, the row counting those left out.
    pub fn renew_in_session(
        &self,
        caller: &Caller,
        session: &mut LeaseSession,
        id: &str,
    ) -> Result<MotionLease, GatewayError> {
        let result = self.require(caller, Operation::RenewLease).and_then(|()| {
            self.leases
                .renew(id, Some(&caller.who), Some(session.session))
        });
        match &result {
            Ok(lease) => {
                if self.leases.renewal_audit_due(id) {
                    self.audit_stream_renewal(caller, id, &Ok(lease.clone()), 0);
                }
            }
            Err(error) => {
                if let Some(left_out) = session.refusals.due(Instant::now()) {
                    self.audit_stream_renewal(caller, id, &Err(error.clone()), left_out);
                }
            }
        }
        result
    }

    /// One audit row of a stream renewal, written in a task.
    fn audit_stream_renewal(
        &self,
        caller: &Caller,
        id: &str,
        result: &Result<MotionLease, GatewayError>,
        left_out: u64,
    ) {
        let mut item = format!("lease {}", mask(id));
        let mut target = AuditTarget::new("renew motion lease (stream)");
        if let Ok(lease) = result {
            let _ = write!(item, " ({} lease of {})", lease.mode, lease.holder);
            target = target
                .bus(lease.axis.bus.clone())
                .node(lease.axis.node)
                .axis(lease.axis.axis);
        }
        if left_out > 0 {
            let _ = write!(item, "; {left_out} more refused renewals not logged");
        }
        let request = serde_json::json!({"op": "renew", "leases": [mask(id)]}).to_string();
        let row = self.audit_row(caller, target.item(item), Some(request));
        tokio::spawn(row.finish(result));
    }
}

#[cfg(test)]
mod tests;
