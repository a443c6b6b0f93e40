//! One motion authority per axis: what orders every actor that changes an
//! axis's motion, so that a stop always wins.
//!
//! Each axis (bus, node, axis) has an epoch and a gate. A stop (halt,
//! quick stop, a walk out of operation enabled, STOP ALL, a lapsed lease,
//! a renumbering, shutdown, a stop written to the controlword) first moves
//! the epoch on — at once, before it awaits anything — and then waits for
//! the gate, so that a command's write already on the wire is done before
//! the stop goes out (which then overrides it). A command (a move, a state
//! walk, halt released, fault reset, each step of a step test, an OD write
//! of an axis's controlword, mode or target) holds an [`AxisTicket`] taken
//! when it was admitted, and sends each of its writes under the gate and
//! only while the epoch is still the ticket's ([`AxisTicket::gated`]; a
//! drive holding the ticket does so for every write:
//! `crate::drive::Drive::with_ticket`). So a write that lost the race to a
//! stop is not sent (`motion_stopped`), and a sequence's waits
//! ([`AxisTicket::hold`]) end as soon as a stop comes.
//!
//! The gate is held for one write at a time, never for a whole sequence:
//! a stop waits for at most that write (bounded again by
//! [`STOP_GATE_WAIT`], after which it goes out anyway: a stop is never held
//! back by what it stops), and reads (a sequence's polling) are not gated.
//!
//! A node can be closed to motion as a whole ([`MotionAuthority::close_node`]:
//! a program download, a renumbering): while it is, no ticket is issued for
//! its axes (`node_busy`; stops are no tickets and are never refused).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use tokio::sync::{Mutex as AsyncMutex, OwnedMutexGuard, watch};

use super::GatewayError;
use super::motion_lease::AxisKey;

/// How long a stop waits for a sequence's step on the wire to finish
/// before it goes out anyway.
pub(crate) const STOP_GATE_WAIT: Duration = Duration::from_secs(1);

/// One axis's epoch and gate.
#[derive(Debug)]
struct AxisControl {
    /// Moved on by every stop; a ticket of an older epoch sends nothing.
    epoch: watch::Sender<u64>,
    /// Held while a ticket's transfers (or a stop's) are on the wire.
    gate: Arc<AsyncMutex<()>>,
}

impl AxisControl {
    fn new() -> Self {
        Self {
            epoch: watch::Sender::new(0),
            gate: Arc::new(AsyncMutex::new(())),
        }
    }
}

/// Why a node is closed to motion, and by whom (for the refusal's text).
#[derive(Debug, Clone)]
struct Closed {
    why: String,
}

/// The gateway's axes under their authority.
#[derive(Debug, Default)]
pub(crate) struct MotionAuthority {
    axes: Mutex<BTreeMap<AxisKey, Arc<AxisControl>>>,
    closed: Mutex<BTreeMap<(String, u8), Closed>>,
}

impl MotionAuthority {
    fn axes(&self) -> MutexGuard<'_, BTreeMap<AxisKey, Arc<AxisControl>>> {
        // A map of handles is never left half-written.
        self.axes.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn closed(&self) -> MutexGuard<'_, BTreeMap<(String, u8), Closed>> {
        self.closed.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn control(&self, axis: &AxisKey) -> Arc<AxisControl> {
        self.axes()
            .entry(axis.clone())
            .or_insert_with(|| Arc::new(AxisControl::new()))
            .clone()
    }

    /// A ticket for a command on `axis` admitted now: it sends only while
    /// no stop comes. Refused while the axis's node is closed to motion.
    pub(crate) fn ticket(&self, axis: &AxisKey) -> Result<AxisTicket, GatewayError> {
        if let Some(closed) = self.closed().get(&(axis.bus.clone(), axis.node)) {
            return Err(GatewayError::NodeBusy(format!(
                "{axis}: {}; no motion command is taken until it ends",
                closed.why
            )));
        }
        let control = self.control(axis);
        let epoch = *control.epoch.borrow();
        Ok(AxisTicket {
            axis: axis.clone(),
            epoch,
            control,
        })
    }

    /// A stop of `axis` begins: every ticket taken before now is void.
    /// Called before the stop awaits anything.
    pub(crate) fn cancel(&self, axis: &AxisKey) {
        self.control(axis).epoch.send_modify(|epoch| *epoch += 1);
    }

    /// The same for every axis of `node` on `bus` (a renumbering).
    pub(crate) fn cancel_node(&self, bus: &str, node: u8) {
        for (key, control) in self.axes().iter() {
            if key.bus == bus && key.node == node {
                control.epoch.send_modify(|epoch| *epoch += 1);
            }
        }
    }

    /// The same for every axis the authority knows (STOP ALL, shutdown).
    pub(crate) fn cancel_all(&self) {
        for control in self.axes().values() {
            control.epoch.send_modify(|epoch| *epoch += 1);
        }
    }

    /// The gate of `axis` for a stop's own transfers, once the step on the
    /// wire (if any) is done; `None` if that took longer than
    /// [`STOP_GATE_WAIT`] (the stop goes out anyway).
    pub(crate) async fn stop_gate(&self, axis: &AxisKey) -> Option<OwnedMutexGuard<()>> {
        let gate = self.control(axis).gate.clone();
        match tokio::time::timeout(STOP_GATE_WAIT, gate.lock_owned()).await {
            Ok(guard) => Some(guard),
            Err(_) => {
                tracing::warn!(
                    "{axis}: a command's transfers held the axis for more than {} ms; \
                     the stop goes out anyway",
                    STOP_GATE_WAIT.as_millis()
                );
                None
            }
        }
    }

    /// Closes `node` of `bus` to motion commands while the guard lives
    /// (`why` says what runs, for the refusals); refused when it is closed
    /// already (by what the refusal names).
    pub(crate) fn close_node(
        self: &Arc<Self>,
        bus: &str,
        node: u8,
        why: String,
    ) -> Result<NodeClosed, String> {
        let mut closed = self.closed();
        let key = (bus.to_string(), node);
        if let Some(already) = closed.get(&key) {
            return Err(already.why.clone());
        }
        closed.insert(key.clone(), Closed { why });
        Ok(NodeClosed {
            authority: self.clone(),
            key,
        })
    }
}

/// A node closed to motion commands; opened again when dropped.
#[derive(Debug)]
pub(crate) struct NodeClosed {
    authority: Arc<MotionAuthority>,
    key: (String, u8),
}

impl Drop for NodeClosed {
    fn drop(&mut self) {
        self.authority.closed().remove(&self.key);
    }
}

/// The right of one admitted command (or sequence) to send to its axis,
/// until a stop comes.
#[derive(Debug, Clone)]
pub(crate) struct AxisTicket {
    axis: AxisKey,
    epoch: u64,
    control: Arc<AxisControl>,
}

impl AxisTicket {
    /// Whether a stop came since the ticket was taken.
    pub(crate) fn stopped(&self) -> bool {
        *self.control.epoch.borrow() != self.epoch
    }

    /// Why a transfer of a voided ticket was not sent.
    pub(crate) fn refusal_text(&self) -> String {
        format!(
            "{}: a stop came after this command was taken; it was not sent (a stop always wins)",
            self.axis
        )
    }

    fn refusal(&self) -> GatewayError {
        GatewayError::MotionStopped(self.refusal_text())
    }

    /// Runs `work` (one transfer of the command) under the axis's gate if
    /// no stop came since the ticket was taken; `None`, sending nothing,
    /// if one did. A drive holding the ticket sends each of its writes so
    /// (`crate::drive::Drive::with_ticket`): a stop waits for at most the
    /// one write on the wire, and the sequence's next write finds it.
    pub(crate) async fn gated<T>(&self, work: impl Future<Output = T>) -> Option<T> {
        let _gate = self.control.gate.clone().lock_owned().await;
        if self.stopped() {
            return None;
        }
        Some(work.await)
    }

    /// Runs `work` (the command's transfers) under the axis's gate if no
    /// stop came since the ticket was taken; else sends nothing and
    /// answers `motion_stopped`. The check and the transfers are under the
    /// same gate a stop takes, so a stop either finds them done (and
    /// overrides them) or they find the stop.
    pub(crate) async fn send<T, E>(
        &self,
        work: impl Future<Output = Result<T, E>>,
    ) -> Result<T, GatewayError>
    where
        E: Into<GatewayError>,
    {
        let _gate = self.control.gate.clone().lock_owned().await;
        if self.stopped() {
            return Err(self.refusal());
        }
        work.await.map_err(Into::into)
    }

    /// Waits `duration`, or until a stop comes (`motion_stopped`).
    pub(crate) async fn hold(&self, duration: Duration) -> Result<(), GatewayError> {
        let mut epoch = self.control.epoch.subscribe();
        let stopped = epoch.wait_for(|now| *now != self.epoch);
        tokio::select! {
            () = tokio::time::sleep(duration) => {}
            _ = stopped => {}
        }
        if self.stopped() {
            return Err(self.refusal());
        }
        Ok(())
    }

    /// The same refusal when a stop came, for a sequence that checks
    /// between its steps.
    pub(crate) fn check(&self) -> Result<(), GatewayError> {
        if self.stopped() {
            Err(self.refusal())
        } else {
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn axis() -> AxisKey {
        AxisKey {
            bus: "demo".into(),
            node: 1,
            axis: 1,
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_ticket_taken_before_a_stop_sends_nothing_after_it() {
        let authority = MotionAuthority::default();
        let before = authority.ticket(&axis()).unwrap();
        authority.cancel(&axis());
        let mut sent = false;
        let refused = before
            .send(async {
                sent = true;
                Ok::<_, GatewayError>(())
            })
            .await
            .unwrap_err();
        assert_eq!(refused.code(), "motion_stopped");
        assert!(!sent);
        // One taken after the stop sends.
        let after = authority.ticket(&axis()).unwrap();
        after
            .send(async { Ok::<_, GatewayError>(()) })
            .await
            .unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_hold_ends_when_a_stop_comes() {
        let authority = Arc::new(MotionAuthority::default());
        let ticket = authority.ticket(&axis()).unwrap();
        let began = tokio::time::Instant::now();
        let stopper = authority.clone();
        tokio::spawn(async move {
            tokio::time::sleep(Duration::from_secs(1)).await;
            stopper.cancel(&axis());
        });
        let refused = ticket.hold(Duration::from_secs(3)).await.unwrap_err();
        assert_eq!(refused.code(), "motion_stopped");
        assert_eq!(began.elapsed(), Duration::from_secs(1));
    }

    #[tokio::test(start_paused = true)]
    async fn a_stop_waits_for_the_step_on_the_wire_but_not_for_ever() {
        let authority = Arc::new(MotionAuthority::default());
        let ticket = authority.ticket(&axis()).unwrap();
        let (on_wire, wire) = tokio::sync::oneshot::channel();
        let step = tokio::spawn(async move {
            ticket
                .send(async {
                    on_wire.send(()).unwrap();
                    tokio::time::sleep(Duration::from_millis(300)).await;
                    Ok::<_, GatewayError>(())
                })
                .await
        });
        wire.await.unwrap();
        authority.cancel(&axis());
        let began = tokio::time::Instant::now();
        assert!(authority.stop_gate(&axis()).await.is_some());
        assert_eq!(began.elapsed(), Duration::from_millis(300));
        step.await.unwrap().unwrap();
        // A gate held for longer is not waited for past the bound.
        let _held = authority.control(&axis()).gate.clone().lock_owned().await;
        let began = tokio::time::Instant::now();
        assert!(authority.stop_gate(&axis()).await.is_none());
        assert_eq!(began.elapsed(), STOP_GATE_WAIT);
    }

    #[test]
    fn a_closed_node_issues_no_ticket_until_it_opens() {
        let authority = Arc::new(MotionAuthority::default());
        let closed = authority
            .close_node("demo", 1, "a program download runs on node 1".into())
            .unwrap();
        let refused = authority.ticket(&axis()).unwrap_err();
        assert_eq!(refused.code(), "node_busy");
        assert!(
            refused.to_string().contains("program download"),
            "{refused}"
        );
        assert!(authority.close_node("demo", 1, "again".into()).is_err());
        drop(closed);
        authority.ticket(&axis()).unwrap();
    }
}
