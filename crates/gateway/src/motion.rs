//! The motion operations every door runs (REST's drive routes, the
//! Sparkplug edge node's DCMDs): an axis's state, halt, fault reset, moves,
//! the step test, and their motion leases. Each operation does the whole
//! job — the checks, the lease check or grant ([`super::leases`]), the
//! axis remembered as enabled (stopped on shutdown), the drive sequence in
//! a task of its own, the in-flight guard, the release or renewal — so that
//! a door only parses its request, calls one operation and maps its
//! outcome.
//!
//! The lease rule: a velocity, torque or duty-cycle move, and halt released
//! in such a mode, holds a lease its caller renews; an interpolated move
//! (and a step test) holds one while it runs. While a lease is held, a
//! move, halt released or the target operation enabled from a caller who
//! does not present it (or presents it but is not its holder) is refused
//! (`lease_conflict`), unless the caller takes the axis over explicitly
//! (operators and admins). Halt, quick stop and a walk out of operation
//! enabled are never refused, and end the lease.
//!
//! How a caller presents its lease ([`LeaseClaim`]): REST presents the id
//! the gateway made and answered; MQTT has no answer to carry an id back,
//! so its host chooses the id (at least [`MIN_CHOSEN_ID`] characters of a
//! safe set) and the first grant on the axis binds the lease to it. As MQTT
//! carries no sender identity either, the id is the capability: whoever
//! does not present it is refused.

use crate::policy::Operation;
use std::future::Future;

use super::GatewayError;
use super::audit::{AuditRow, AuditTarget, Finishing, spawn_audited};
use super::authority::AxisTicket;
use super::caller::Caller;
use super::drive::{AxisStatus, Drive, DriveError, MoveMode, MoveRequest, TargetState};
use super::leases::InFlight;
use super::motion_lease::{AxisKey, MotionLease, mask};
use super::safe_stop::{AxisStopFailed, AxisStopped, StopAttempt};
use super::service::Gateway;
use super::step_test::{self, StepTestRequest, StepTestResult};

/// The shortest lease id a caller may choose: guessing it must be out of
/// reach, as it is the only credential an MQTT command carries.
pub(crate) const MIN_CHOSEN_ID: usize = 16;
/// The longest (an id is kept, compared and logged masked).
pub(crate) const MAX_CHOSEN_ID: usize = 128;

/// The lease a caller presents with a motion command, and how a lease
/// granted to it is named and renewed.
#[derive(Debug, Clone, Default)]
pub struct LeaseClaim {
    /// The lease id presented (REST's `Candeck-Lease`, Sparkplug's `Axis
    /// {n}/Lease Id`), if any.
    pub id: Option<String>,
    /// The caller chose `id` (checked against the safe set), and a lease
    /// granted to it takes that id; else the gateway makes new ids.
    pub chosen: bool,
    /// An explicit take-over of the axis from the lease held on it.
    pub takeover: bool,
    pub promise: Promise,
}

/// Whether the caller will renew a lease it is granted.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub enum Promise {
    /// It is answered the lease and renews it (REST).
    #[default]
    Answered,
    /// It says so in its command, or the motion is refused (MQTT, where no
    /// answer tells the caller a lease was granted); `how` says, in the
    /// door's words, how to give the promise and the id.
    Asked { given: bool, how: String },
}

impl LeaseClaim {
    /// A gateway-made lease id presented (or none), as REST does.
    pub fn presented(id: Option<&str>, takeover: bool) -> Self {
        Self {
            id: id.map(str::to_string),
            chosen: false,
            takeover,
            promise: Promise::Answered,
        }
    }

    /// A lease id the caller chose (or none), with its promise to renew.
    pub fn chosen(id: Option<String>, promised: bool, how: String) -> Self {
        Self {
            id,
            chosen: true,
            takeover: false,
            promise: Promise::Asked {
                given: promised,
                how,
            },
        }
    }

    /// The id presented, a chosen one checked first.
    fn id(&self) -> Result<Option<&str>, GatewayError> {
        match self.id.as_deref() {
            Some(id) if self.chosen => {
                check_chosen_id(id)?;
                Ok(Some(id))
            }
            id => Ok(id),
        }
    }

    /// The id a lease granted now takes: the caller's, when it chooses.
    fn new_id(&self) -> Option<&str> {
        if self.chosen {
            self.id.as_deref()
        } else {
            None
        }
    }

    /// Refuses a motion that needs a lease (in `mode`) the caller cannot
    /// hold: no promise to renew it, or no id of its choosing to present
    /// later.
    fn terms(&self, mode: &str) -> Result<(), GatewayError> {
        let Promise::Asked { given, how } = &self.promise else {
            return Ok(());
        };
        if !given || (self.chosen && self.id.is_none()) {
            return Err(GatewayError::InvalidRequest(format!(
                "a {mode} motion has no end of its own and holds a motion lease: {how}"
            )));
        }
        Ok(())
    }

    /// Whether halt released needs the axis's mode before it is sent (for
    /// [`Self::terms`]).
    fn needs_terms(&self) -> bool {
        matches!(&self.promise, Promise::Asked { given, .. }
            if !given || (self.chosen && self.id.is_none()))
    }
}

/// A lease id a caller chose: long enough not to be guessed, and of
/// characters that travel and log safely.
pub(crate) fn check_chosen_id(id: &str) -> Result<(), GatewayError> {
    let safe = |c: char| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.' | '~');
    if (MIN_CHOSEN_ID..=MAX_CHOSEN_ID).contains(&id.len()) && id.chars().all(safe) {
        return Ok(());
    }
    Err(GatewayError::InvalidRequest(format!(
        "a lease id chosen by the caller is {MIN_CHOSEN_ID} to {MAX_CHOSEN_ID} characters of \
         A-Z, a-z, 0-9, '-', '_', '.' and '~' (this one has {} characters{})",
        id.chars().count(),
        if id.chars().all(safe) {
            ""
        } else {
            ", some outside that set"
        }
    )))
}

/// What a motion operation did.
#[derive(Debug)]
pub struct MotionOutcome<T = AxisStatus> {
    /// The axis after it (or the step test's result).
    pub status: T,
    /// The lease the caller holds now and renews, if the motion has no end
    /// of its own.
    pub lease: Option<MotionLease>,
    /// A stop's steps and their outcome.
    pub attempts: Option<Vec<StopAttempt>>,
    /// The lease an explicit take-over ended, for the audit log.
    pub took_over: Option<MotionLease>,
}

/// Why a motion operation failed: the error, what a stop tried, and the
/// lease a take-over ended before it failed (it stays ended).
#[derive(Debug)]
pub struct MotionFailed {
    pub error: GatewayError,
    pub attempts: Vec<StopAttempt>,
    /// Boxed: seldom there, and it would make every error large.
    pub took_over: Option<Box<MotionLease>>,
}

impl From<GatewayError> for MotionFailed {
    fn from(error: GatewayError) -> Self {
        Self {
            error,
            attempts: Vec::new(),
            took_over: None,
        }
    }
}

impl From<DriveError> for MotionFailed {
    fn from(error: DriveError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<AxisStopFailed> for MotionFailed {
    fn from(failed: AxisStopFailed) -> Self {
        Self {
            error: failed.error,
            attempts: failed.attempts,
            took_over: None,
        }
    }
}

/// Whether a motion in this mode runs until told otherwise, and so needs a
/// lease its caller renews.
pub(crate) fn endless(mode: MoveMode) -> bool {
    matches!(
        mode,
        MoveMode::Velocity | MoveMode::Torque | MoveMode::DutyCycle
    )
}

/// The same for the mode an axis displays (its `mode` name).
fn endless_displayed(mode: Option<&str>) -> Option<&'static str> {
    match mode? {
        "velocity" | "profile_velocity" => Some("velocity"),
        "torque" | "profile_torque" => Some("torque"),
        "duty_cycle" => Some("duty_cycle"),
        _ => None,
    }
}

/// Runs `sequence` on the drive in a task of its own: a caller that goes
/// away (a client hanging up drops its request) never cuts a walk or a move
/// half way.
pub async fn spawned<T, F, Fut>(drive: Drive, sequence: F) -> Result<T, GatewayError>
where
    T: Send + 'static,
    F: FnOnce(Drive) -> Fut + Send + 'static,
    Fut: Future<Output = Result<T, DriveError>> + Send + 'static,
{
    tokio::spawn(sequence(drive))
        .await
        .map_err(|err| GatewayError::Internal(format!("drive task: {err}")))?
        .map_err(GatewayError::from)
}

fn key(bus: &str, drive: &Drive) -> AxisKey {
    AxisKey {
        bus: bus.to_string(),
        node: drive.node(),
        axis: drive.axis(),
    }
}

/// An operation's result with the take-over that came before it.
fn finish<T>(
    result: Result<(T, Option<MotionLease>), GatewayError>,
    took_over: Option<MotionLease>,
) -> Result<MotionOutcome<T>, MotionFailed> {
    match result {
        Ok((status, lease)) => Ok(MotionOutcome {
            status,
            lease,
            attempts: None,
            took_over,
        }),
        Err(error) => Err(MotionFailed {
            error,
            attempts: Vec::new(),
            took_over: took_over.map(Box::new),
        }),
    }
}

fn stopped(stopped: AxisStopped) -> MotionOutcome {
    MotionOutcome {
        status: stopped.status,
        lease: None,
        attempts: Some(stopped.attempts),
        took_over: None,
    }
}

impl Gateway {
    /// An explicit take-over, when the claim asks for one: the lease held
    /// on `axis` ends (the axis is not stopped: the caller's own command
    /// follows). Operators and admins only, on a gateway with tokens.
    fn take_over_claimed(
        &self,
        caller: &Caller,
        axis: &AxisKey,
        claim: &LeaseClaim,
    ) -> Result<Option<MotionLease>, GatewayError> {
        if !claim.takeover {
            return Ok(None);
        }
        if self.tokens.required() && self.require(caller, Operation::Motion).is_err() {
            return Err(GatewayError::Forbidden(
                "a take-over of a held axis needs the operator role".to_string(),
            ));
        }
        Ok(self.leases.take_over(axis))
    }

    /// A stop was asked for (confirmed or not): the axis's lease is over.
    fn release_stopped(&self, bus: &str, node: &str, axis: &str) {
        if let (Ok(node), Ok(axis)) = (node.parse::<u8>(), axis.parse::<u8>()) {
            self.leases.release(&AxisKey {
                bus: bus.to_string(),
                node,
                axis,
            });
        }
    }

    /// The caller's policy for a motion command on an axis, the same from
    /// every door: the operator's role and, unless the command is a stop,
    /// one write of its rate, drawn from the bucket of the lease it presents
    /// when that lease is the one held on the axis
    /// ([`Gateway::take_write_presenting`]), so that commands presenting
    /// none cannot starve the lease's holder. A stop is never refused for
    /// the rate.
    fn motion_policy(
        &self,
        caller: &Caller,
        (bus, node, axis): (&str, &str, &str),
        claim: Option<&LeaseClaim>,
        stop: bool,
    ) -> Result<(), GatewayError> {
        self.require(caller, Operation::Motion)?;
        if stop {
            return Ok(());
        }
        let presented = claim.and_then(|claim| claim.id.as_deref());
        match (node.parse::<u8>(), axis.parse::<u8>()) {
            (Ok(node), Ok(axis)) => {
                let axis = AxisKey {
                    bus: bus.to_string(),
                    node,
                    axis,
                };
                self.take_write_presenting(caller, &axis, presented)
            }
            _ => self.take_write(caller),
        }
    }

    /// Walks an axis's CiA 402 state machine to `target`. Quick stop active
    /// is sent whatever the gateway believes of the node, never refused,
    /// and ends the lease, as does any walk out of operation enabled;
    /// operation enabled is a motion command, checked against the lease.
    ///
    /// Audited as `drive state change`, in a task of its own with its row.
    pub async fn set_axis_state(
        &self,
        caller: &Caller,
        axis: (&str, &str, &str),
        target: TargetState,
        claim: &LeaseClaim,
    ) -> Result<MotionOutcome, MotionFailed> {
        let request = serde_json::json!({ "target": target }).to_string();
        let row = self.motion_row(caller, "drive state change", axis, request);
        let (gateway, caller, claim) = (self.clone(), caller.clone(), claim.clone());
        let axis = owned(axis);
        spawn_motion(row, async move {
            let axis = (axis.0.as_str(), axis.1.as_str(), axis.2.as_str());
            gateway.set_state(&caller, axis, target, &claim).await
        })
        .await
    }

    async fn set_state(
        &self,
        caller: &Caller,
        (bus, node, axis): (&str, &str, &str),
        target: TargetState,
        claim: &LeaseClaim,
    ) -> Result<MotionOutcome, MotionFailed> {
        let stop = target != TargetState::OperationEnabled;
        self.motion_policy(caller, (bus, node, axis), Some(claim), stop)?;
        if target == TargetState::QuickStopActive {
            let result = self.quick_stop_axis(bus, node, axis).await;
            self.release_stopped(bus, node, axis);
            return Ok(stopped(result?));
        }
        let drive = self.drive(bus, node, axis)?;
        let axis_key = key(bus, &drive);
        let enable = target == TargetState::OperationEnabled;
        // A walk out of operation enabled is a stop: whatever was admitted
        // on the axis before it sends nothing after it.
        let gates = self.gates(bus);
        let ticket = if enable {
            Some(self.authority.ticket(&axis_key)?)
        } else {
            gates.cancel(&drive);
            None
        };
        let took_over = if enable {
            self.take_over_claimed(caller, &axis_key, claim)?
        } else {
            None
        };
        let result = async {
            if enable {
                self.leases.check(&axis_key, claim.id()?, &caller.who)?;
                // Before the walk, not after it: a walk that fails half way
                // may have powered the axis already.
                self.enabled_axes.insert(bus, &drive);
            }
            let state = target.state();
            let drive = match ticket {
                // Each write of the walk under the axis's gate, none after
                // a stop.
                Some(ticket) => drive.with_ticket(ticket),
                None => {
                    // A command's write on the wire goes first.
                    drop(gates.authority.stop_gate(&axis_key).await);
                    drive
                }
            };
            let status = spawned(
                drive,
                move |drive| async move { drive.set_state(state).await },
            )
            .await?;
            if !enable {
                // Out of operation enabled nothing moves: the motion is over.
                self.leases.release(&axis_key);
            }
            Ok((status, None))
        }
        .await;
        finish(result, took_over)
    }

    /// Sets (a stop: never refused, sent whatever the gateway believes of
    /// the node, quick stop then NMT stop if it cannot be given; it ends the
    /// lease) or releases halt. Releasing it resumes the set-point the axis
    /// has: in a mode without an end, that is a motion like any other, and
    /// it is leased.
    ///
    /// Audited as `halt`, in a task of its own with its row.
    pub async fn set_axis_halt(
        &self,
        caller: &Caller,
        axis: (&str, &str, &str),
        halt: bool,
        claim: &LeaseClaim,
    ) -> Result<MotionOutcome, MotionFailed> {
        let request = serde_json::json!({ "halt": halt }).to_string();
        let row = self.motion_row(caller, "halt", axis, request);
        let (gateway, caller, claim) = (self.clone(), caller.clone(), claim.clone());
        let axis = owned(axis);
        spawn_motion(row, async move {
            let axis = (axis.0.as_str(), axis.1.as_str(), axis.2.as_str());
            gateway.set_halt(&caller, axis, halt, &claim).await
        })
        .await
    }

    async fn set_halt(
        &self,
        caller: &Caller,
        (bus, node, axis): (&str, &str, &str),
        halt: bool,
        claim: &LeaseClaim,
    ) -> Result<MotionOutcome, MotionFailed> {
        self.motion_policy(caller, (bus, node, axis), Some(claim), halt)?;
        if halt {
            let result = self.halt_axis(bus, node, axis).await;
            self.release_stopped(bus, node, axis);
            return Ok(stopped(result?));
        }
        let drive = self.drive(bus, node, axis)?;
        let axis_key = key(bus, &drive);
        let ticket = self.authority.ticket(&axis_key)?;
        let took_over = self.take_over_claimed(caller, &axis_key, claim)?;
        let result = async {
            let presented = claim.id()?;
            self.leases.check(&axis_key, presented, &caller.who)?;
            if claim.needs_terms() {
                let before =
                    spawned(drive.clone(), |drive| async move { drive.status().await }).await?;
                if let Some(mode) = endless_displayed(before.mode.as_deref()) {
                    claim.terms(mode)?;
                }
            }
            // Motion the gateway resumes is motion it stops on shutdown.
            self.enabled_axes.insert(bus, &drive);
            let status = spawned(drive.with_ticket(ticket), |drive| async move {
                drive.halt(false).await
            })
            .await?;
            let lease = match endless_displayed(status.mode.as_deref()) {
                Some(mode) if status.state == "operation_enabled" => Some(self.leases.grant(
                    self,
                    axis_key.clone(),
                    presented,
                    claim.new_id(),
                    &caller.who,
                    mode,
                )?),
                _ => {
                    self.leases.release(&axis_key);
                    None
                }
            };
            Ok((status, lease))
        }
        .await;
        finish(result, took_over)
    }

    /// Resets an axis's fault (not a motion: no lease is involved).
    /// Audited as `fault reset`, its row written in the drive's task.
    pub async fn reset_axis_fault(
        &self,
        caller: &Caller,
        axis: (&str, &str, &str),
    ) -> Result<AxisStatus, GatewayError> {
        let row = self.axis_row(caller, "fault reset", axis, None);
        let admitted = self
            .motion_policy(caller, axis, None, false)
            .and_then(|()| self.drive(axis.0, axis.1, axis.2))
            .and_then(|drive| {
                let ticket = self.authority.ticket(&key(axis.0, &drive))?;
                Ok((drive, ticket))
            });
        let (drive, ticket) = match admitted {
            Ok(admitted) => admitted,
            Err(error) => {
                let result = Err(error);
                row.finish(&result).await;
                return result;
            }
        };
        let drive = drive.with_ticket(ticket);
        spawn_audited(row, async move {
            drive.fault_reset().await.map_err(GatewayError::from)
        })
        .await
    }

    /// Starts a motion. A move with an end of its own (profile position,
    /// homing, ...) is given by the lease's holder or on a free axis, and
    /// ends the lease; a move without one is granted (or, presented, keeps)
    /// the lease its caller renews; an interpolated move holds one while
    /// its points are fed, and lapses it at once if its caller goes away.
    ///
    /// Audited as `move`. The move runs in the caller's future, so that a
    /// caller that goes away lapses the lease it holds: its row then says
    /// `INTERRUPTED`.
    pub async fn move_axis(
        &self,
        caller: &Caller,
        axis: (&str, &str, &str),
        request: &MoveRequest,
        claim: &LeaseClaim,
    ) -> Result<MotionOutcome, MotionFailed> {
        let row = self.motion_row(caller, "move", axis, move_summary(request));
        let result = self.run_move(caller, axis, request, claim).await;
        finish_motion(row, &result).await;
        result
    }

    async fn run_move(
        &self,
        caller: &Caller,
        (bus, node, axis): (&str, &str, &str),
        request: &MoveRequest,
        claim: &LeaseClaim,
    ) -> Result<MotionOutcome, MotionFailed> {
        self.motion_policy(caller, (bus, node, axis), Some(claim), false)?;
        let drive = self.drive(bus, node, axis)?;
        drive.validate(request)?;
        let axis_key = key(bus, &drive);
        // Each write of the move goes under the axis's gate, none after a
        // stop.
        let drive = drive.with_ticket(self.authority.ticket(&axis_key)?);
        let took_over = self.take_over_claimed(caller, &axis_key, claim)?;
        let result = async {
            let presented = claim.id()?;
            let mode = request.mode();
            let request = request.clone();
            if !(endless(mode) || mode == MoveMode::InterpolatedPosition) {
                self.leases.check(&axis_key, presented, &caller.who)?;
                self.enabled_axes.insert(bus, &drive);
                let status = spawned(
                    drive,
                    move |drive| async move { drive.run_move(&request).await },
                )
                .await?;
                self.leases.release(&axis_key);
                return Ok((status, None));
            }
            if endless(mode) {
                // A caller the lease refuses hears that first.
                self.leases.check(&axis_key, presented, &caller.who)?;
                claim.terms(mode.name())?;
            }
            let lease = self.leases.grant(
                self,
                axis_key.clone(),
                presented,
                claim.new_id(),
                &caller.who,
                mode.name(),
            )?;
            self.enabled_axes.insert(bus, &drive);
            // While the caller waits it keeps the lease alive; if it goes
            // away, the lease lapses at once.
            let status = InFlight::new(&self.leases, &lease)
                .run(spawned(drive, move |drive| async move {
                    drive.run_move(&request).await
                }))
                .await
                .inspect_err(|_| {
                    // A failed move halted the axis: nothing is left to lease.
                    self.leases.release(&axis_key);
                })?;
            if !endless(mode) {
                // The interpolated points are all in the buffer: the drive
                // stops at the last one by itself.
                self.leases.release(&axis_key);
                return Ok((status, None));
            }
            let lease = self.leases.renew(&lease.id, None, None)?;
            Ok((status, Some(lease)))
        }
        .await;
        finish(result, took_over)
    }

    /// A step test of an axis's control loop: the axis holds a lease while
    /// it runs (lapsed at once if the caller goes away) and is halted at
    /// the end. Audited as `step test`, its row finished in the caller's
    /// future as a move's.
    pub async fn step_test_axis(
        &self,
        caller: &Caller,
        axis: (&str, &str, &str),
        request: &StepTestRequest,
        claim: &LeaseClaim,
    ) -> Result<MotionOutcome<StepTestResult>, MotionFailed> {
        let row = self.axis_row(caller, "step test", axis, None);
        let result = self.run_step_test(caller, axis, request, claim).await;
        finish_motion(row, &result).await;
        result
    }

    async fn run_step_test(
        &self,
        caller: &Caller,
        (bus, node, axis): (&str, &str, &str),
        request: &StepTestRequest,
        claim: &LeaseClaim,
    ) -> Result<MotionOutcome<StepTestResult>, MotionFailed> {
        self.motion_policy(caller, (bus, node, axis), Some(claim), false)?;
        let drive = self.drive(bus, node, axis)?;
        request.validate()?;
        let node_handle = self.node_handle(bus, node)?;
        let axis_key = key(bus, &drive);
        let ticket = self.authority.ticket(&axis_key)?;
        let took_over = self.take_over_claimed(caller, &axis_key, claim)?;
        let result = async {
            let lease = self.leases.grant(
                self,
                axis_key.clone(),
                claim.id()?,
                claim.new_id(),
                &caller.who,
                "step_test",
            )?;
            self.enabled_axes.insert(bus, &drive);
            let request = request.clone();
            // Each step is sent through the ticket: a stop of the axis (a
            // halt, the lapse when this caller goes away) ends the test,
            // and no later step is sent.
            // What the test lifts and restores is the gateway's own doing,
            // on the axis: rows of its own, the caller's row unchanged.
            let history = self.history.clone();
            let target = AuditTarget::new("")
                .bus(bus)
                .node(drive.node())
                .axis(drive.axis());
            let test = tokio::spawn(async move {
                let drive = drive.with_ticket(ticket.clone());
                let audit = |operation: &str, request: String| {
                    let target = AuditTarget {
                        operation: operation.to_string(),
                        ..target.clone()
                    };
                    AuditRow::new(&history, &Caller::system(), target, Some(request))
                };
                step_test::run(&drive, &node_handle, &request, &ticket, &audit).await
            });
            let result = InFlight::new(&self.leases, &lease)
                .run(async {
                    test.await
                        .map_err(|err| GatewayError::Internal(format!("step test task: {err}")))?
                })
                .await;
            self.leases.release(&axis_key);
            Ok((result?, None))
        }
        .await;
        finish(result, took_over)
    }

    /// Renews the lease `id` held on `axis`, for its holder. Audited as
    /// `renew motion lease`, every time.
    pub async fn renew_axis_lease(
        &self,
        caller: &Caller,
        axis: &AxisKey,
        id: &str,
    ) -> Result<MotionLease, GatewayError> {
        let row = self.lease_row(caller, "renew motion lease", axis, id);
        let result = self
            .require(caller, Operation::RenewLease)
            .and_then(|()| self.leases.renew_on(axis, id, &caller.who));
        row.finish(&result).await;
        result
    }

    /// [`Gateway::renew_axis_lease`] sent as a heartbeat (a Sparkplug
    /// host's `Axis {n}/Lease` = true): audited the first time and then
    /// once a minute ([`super::leases::RENEWAL_AUDIT_EVERY`]), a refusal
    /// always.
    pub async fn keep_axis_lease(
        &self,
        caller: &Caller,
        axis: &AxisKey,
        id: &str,
    ) -> Result<MotionLease, GatewayError> {
        let row = self.lease_row(caller, "renew motion lease", axis, id);
        let result = self
            .require(caller, Operation::RenewLease)
            .and_then(|()| self.leases.renew_on(axis, id, &caller.who));
        if result.is_ok() && !self.leases.renewal_audit_due(id) {
            row.skip();
        } else {
            row.finish(&result).await;
        }
        result
    }

    /// Gives up the lease `id` held on `axis`: it lapses now, and the
    /// supervisor halts the axis. Only its holder, presenting it. Audited
    /// as `end motion lease`.
    pub async fn give_up_axis_lease(
        &self,
        caller: &Caller,
        axis: &AxisKey,
        id: &str,
    ) -> Result<(), GatewayError> {
        let row = self.lease_row(caller, "end motion lease", axis, id);
        let result = self
            .require(caller, Operation::RenewLease)
            .and_then(|()| self.leases.lapse_on(axis, id, &caller.who));
        row.finish(&result).await;
        result
    }

    /// The audit row of a motion operation on an axis given by the door's
    /// words (`bus`, `node`, `axis`).
    fn axis_row(
        &self,
        caller: &Caller,
        operation: &str,
        (bus, node, axis): (&str, &str, &str),
        request: Option<String>,
    ) -> AuditRow {
        let target = AuditTarget::new(operation)
            .bus(bus)
            .node(node.parse::<u8>().ok())
            .axis(axis.parse::<u8>().ok());
        self.audit_row(caller, target, request)
    }

    fn motion_row(
        &self,
        caller: &Caller,
        operation: &str,
        axis: (&str, &str, &str),
        request: String,
    ) -> AuditRow {
        self.axis_row(caller, operation, axis, Some(request))
    }

    fn lease_row(&self, caller: &Caller, operation: &str, axis: &AxisKey, id: &str) -> AuditRow {
        let target = AuditTarget::new(operation)
            .bus(axis.bus.clone())
            .node(axis.node)
            .axis(axis.axis);
        let request = serde_json::json!({ "lease": mask(id) }).to_string();
        self.audit_row(caller, target, Some(request))
    }
}

/// What a write of an object (an OD write through REST or CiA 309) is to
/// an axis's motion, by the one authority of the axis.
pub(crate) enum MotionWrite {
    /// No object that commands an axis's motion.
    Free,
    /// A stop in an axis's controlword (halt set, or a command out of
    /// operation enabled): never refused; every ticket of the axis was
    /// voided when it was admitted, it is sent under the axis's gate, and
    /// once written it ends the axis's lease as a halt does.
    Stop { axis: AxisKey },
    /// A command that may set an axis moving (a controlword that enables
    /// operation, resets a fault or releases halt; the mode; a target):
    /// held to the lease rule (none can be presented in an OD write: while
    /// a lease is held, use the drive routes) and sent with its ticket.
    Command { ticket: AxisTicket },
}

impl MotionWrite {
    /// Sends `work` (the write's transfers) as the authority says.
    pub(crate) async fn send<T>(
        self,
        gateway: &Gateway,
        work: impl Future<Output = Result<T, GatewayError>>,
    ) -> Result<T, GatewayError> {
        match self {
            MotionWrite::Free => work.await,
            MotionWrite::Stop { axis } => {
                let gate = gateway.authority.stop_gate(&axis).await;
                let result = work.await;
                drop(gate);
                if result.is_ok() {
                    gateway.leases.release(&axis);
                }
                result
            }
            MotionWrite::Command { ticket } => ticket.send(work).await,
        }
    }
}

/// Whether a controlword stops an axis: halt set, or any command but
/// enable operation (and fault reset, which moves nothing but is no stop
/// either) — shutdown, switch on, disable voltage, quick stop all take the
/// axis out of operation enabled.
fn controlword_stops(word: u16) -> bool {
    const HALT: u16 = 0x0100;
    const FAULT_RESET: u16 = 0x0080;
    const ENABLE_OPERATION: u16 = 0x000F;
    if word & FAULT_RESET != 0 {
        return false;
    }
    word & HALT != 0 || word & ENABLE_OPERATION != ENABLE_OPERATION
}

impl Gateway {
    /// What writing `bytes` to `index`:`sub` of the node `info` of `served`
    /// is to its axes' motion ([`MotionWrite`]): a stop in a controlword is
    /// never refused (and voids every ticket of its axis now); a command
    /// in a controlword, the mode or a target of a leased axis is refused
    /// (`lease_conflict`), and on a node closed to motion (`node_busy`).
    pub(crate) fn motion_write(
        &self,
        caller: &Caller,
        served: &super::service::ServedBus,
        info: &super::registry::NodeInfo,
        (index, sub): (u16, u8),
        bytes: &[u8],
    ) -> Result<MotionWrite, GatewayError> {
        use crate::profiles::cia402::objects as obj;
        let Some(kind) = super::drive::DriveKind::from_profile(info.profile) else {
            return Ok(MotionWrite::Free);
        };
        if sub != 0 {
            return Ok(MotionWrite::Free);
        }
        for number in 1..=super::drive::axis_count(kind, info.eds_entry.as_deref()) {
            let Ok(drive) = Drive::new(&served.registry, info, &number.to_string()) else {
                continue;
            };
            let axis = key(&served.name, &drive);
            let command = || {
                self.leases.check(&axis, None, &caller.who)?;
                Ok::<_, GatewayError>(MotionWrite::Command {
                    ticket: self.authority.ticket(&axis)?,
                })
            };
            if index == drive.object(obj::CONTROLWORD) {
                let word = <[u8; 2]>::try_from(bytes).map(u16::from_le_bytes);
                if let Ok(word) = word
                    && controlword_stops(word)
                {
                    self.authority.cancel(&axis);
                    return Ok(MotionWrite::Stop { axis });
                }
                let write = command()?;
                // Motion the gateway let through is motion it stops on
                // shutdown.
                self.enabled_axes.insert(&served.name, &drive);
                return Ok(write);
            }
            let targets = [
                obj::MODES_OF_OPERATION,
                obj::VL_TARGET,
                obj::TARGET_VELOCITY,
                obj::TARGET_POSITION,
                obj::TQ_TARGET,
            ];
            if targets.iter().any(|&object| index == drive.object(object)) {
                return command();
            }
        }
        Ok(MotionWrite::Free)
    }
}

/// A move as its row summarises it: the request's fields that are set.
fn move_summary(request: &MoveRequest) -> String {
    match serde_json::to_value(request) {
        Ok(serde_json::Value::Object(mut fields)) => {
            fields.retain(|_, value| !value.is_null());
            serde_json::Value::Object(fields).to_string()
        }
        _ => format!("{{\"mode\":\"{}\"}}", request.mode().name()),
    }
}

fn owned((bus, node, axis): (&str, &str, &str)) -> (String, String, String) {
    (bus.to_string(), node.to_string(), axis.to_string())
}

/// Finishes a motion operation's row: its outcome, and the lease a
/// take-over ended, named.
fn finish_motion<T>(
    mut row: AuditRow,
    result: &Result<MotionOutcome<T>, MotionFailed>,
) -> Finishing {
    let took_over = match result {
        Ok(outcome) => outcome.took_over.as_ref(),
        Err(failed) => failed.took_over.as_deref(),
    };
    if let Some(previous) = took_over {
        row.note(&format!(
            "took over the {} lease {} of {}",
            previous.mode,
            mask(&previous.id),
            previous.holder
        ));
    }
    let outcome = match result {
        Ok(_) => Ok(()),
        Err(failed) => Err(failed.error.clone()),
    };
    row.finish(&outcome)
}

/// Runs a motion operation that does not need its caller to stay (no lease
/// held in flight) in a task of its own, and its row with it.
async fn spawn_motion<T, Fut>(row: AuditRow, work: Fut) -> Result<MotionOutcome<T>, MotionFailed>
where
    T: Send + 'static,
    Fut: Future<Output = Result<MotionOutcome<T>, MotionFailed>> + Send + 'static,
{
    tokio::spawn(async move {
        let result = work.await;
        finish_motion(row, &result).await;
        result
    })
    .await
    .map_err(|err| GatewayError::Internal(format!("motion task: {err}")))?
}

#[cfg(test)]
mod tests;
