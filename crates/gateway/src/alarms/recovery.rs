//! Machine-level recovery: every faulted axis of a bus reset, and every
//! axis the machine description or the gateway's last enable put in
//! operation enabled again, in one operation each (`POST
//! /buses/{bus}/machine/reset-faults`, `/enable`).
//!
//! "Enable all" takes every axis of every drive node the description
//! expects started (`[[nodes]]` with `start = true`), with the axes the
//! gateway enabled since it started: after a restart of the gateway, which
//! forgets what it enabled, the described machine still comes back.
//!
//! Each axis is taken on its own, by the axis operations a door would call
//! ([`Gateway::reset_axis_fault`], [`Gateway::set_axis_state`]: their role,
//! write, lease and audit rules, and their rows), and refused with its
//! reason where its cause is still present: a node offline, missing, of the
//! wrong identity, unconfigured, its heartbeat lost, the bus off; a fault
//! that does not reset; an axis still in fault when it is to be enabled.
//! One axis refused does not keep the others from recovering.

use crate::audit::AuditTarget;
use crate::caller::Caller;
use crate::drive::{DriveKind, TargetState, axis_count};
use crate::error::GatewayError;
use crate::motion::{LeaseClaim, spawned};
use crate::policy::Operation;
use crate::service::Gateway;

use super::Alarm;

/// What happened to one axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RecoveryOutcome {
    /// Reset, or enabled.
    Done,
    /// Nothing to do: not in fault (reset), already enabled (enable).
    NotNeeded,
    /// Not done: `reason` says why.
    Refused,
}

impl RecoveryOutcome {
    pub fn name(self) -> &'static str {
        match self {
            Self::Done => "done",
            Self::NotNeeded => "not_needed",
            Self::Refused => "refused",
        }
    }
}

/// One axis of a recovery.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AxisRecovery {
    pub node: u8,
    pub axis: u8,
    pub outcome: RecoveryOutcome,
    /// Why it was refused: the cause still present, the error.
    pub reason: Option<String>,
    /// The error's code when an operation refused it (`drive_fault`,
    /// `node_offline`, `lease_conflict`).
    pub code: Option<String>,
    /// Its PDS state after it, where read.
    pub state: Option<String>,
}

impl AxisRecovery {
    fn new(node: u8, axis: u8, outcome: RecoveryOutcome) -> Self {
        Self {
            node,
            axis,
            outcome,
            reason: None,
            code: None,
            state: None,
        }
    }

    fn done(node: u8, axis: u8, state: String) -> Self {
        Self {
            state: Some(state),
            ..Self::new(node, axis, RecoveryOutcome::Done)
        }
    }

    fn refused(node: u8, axis: u8, reason: String, code: Option<&str>) -> Self {
        Self {
            reason: Some(reason),
            code: code.map(str::to_string),
            ..Self::new(node, axis, RecoveryOutcome::Refused)
        }
    }
}

/// What a recovery did, axis by axis.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecoveryReport {
    pub bus: String,
    pub axes: Vec<AxisRecovery>,
}

/// The alarm kinds whose cause keeps a node's axes from recovering.
const BLOCKING: &[&str] = &[
    "heartbeat_lost",
    "guarding_lost",
    "node_offline",
    "node_missing",
    "wrong_identity",
    "config_failed",
    "bus_off",
];

/// The two machine-level recoveries.
#[derive(Debug, Clone, Copy)]
enum Recovery {
    /// Every axis of every drive node that is in fault.
    ResetFaults,
    /// Every axis of the drive nodes the description expects started, and
    /// every axis the gateway last enabled.
    Enable,
}

impl Gateway {
    /// Resets the fault of every axis of `bus` that is in fault.
    ///
    /// Audited as `machine reset faults`; each axis reset writes its own
    /// `fault reset` row and takes its own write.
    pub async fn reset_machine_faults(
        &self,
        caller: &Caller,
        bus: &str,
    ) -> Result<RecoveryReport, GatewayError> {
        self.recover(caller, bus, Recovery::ResetFaults).await
    }

    /// Puts every axis of `bus` the machine description expects in
    /// operation (every axis of each described drive node it starts), and
    /// every axis the gateway last enabled, back in operation enabled.
    ///
    /// Audited as `machine enable`; each axis writes its own `drive state
    /// change` row.
    pub async fn enable_machine(
        &self,
        caller: &Caller,
        bus: &str,
    ) -> Result<RecoveryReport, GatewayError> {
        self.recover(caller, bus, Recovery::Enable).await
    }

    /// One machine-level recovery: its row, the caller admitted, then each
    /// of its axes through the axis's own operation.
    async fn recover(
        &self,
        caller: &Caller,
        bus: &str,
        recovery: Recovery,
    ) -> Result<RecoveryReport, GatewayError> {
        let words = match recovery {
            Recovery::ResetFaults => "machine reset faults",
            Recovery::Enable => "machine enable",
        };
        let row = self.audit_row(caller, AuditTarget::new(words).bus(bus), None);
        let result = async {
            self.admit(caller, Operation::RecoverMachine)?;
            let axes = match recovery {
                Recovery::ResetFaults => self.drive_axes(bus)?,
                Recovery::Enable => self.axes_to_enable(bus)?,
            };
            let mut report = Vec::new();
            for (node, axis) in axes {
                report.push(match recovery {
                    Recovery::ResetFaults => self.reset_one(caller, bus, node, axis).await,
                    Recovery::Enable => self.enable_one(caller, bus, node, axis).await,
                });
            }
            Ok(RecoveryReport {
                bus: bus.to_string(),
                axes: report,
            })
        }
        .await;
        row.finish(&result).await;
        result
    }

    /// Every axis of every drive node of `bus`, in node order.
    fn drive_axes(&self, bus: &str) -> Result<Vec<(u8, u8)>, GatewayError> {
        let served = self.bus(bus)?;
        let mut axes = Vec::new();
        for info in served.registry.nodes() {
            if let Some(kind) = DriveKind::from_profile(info.profile) {
                let count = axis_count(kind, info.eds_entry.as_deref());
                axes.extend((1..=count).map(|axis| (info.id.get(), axis)));
            }
        }
        Ok(axes)
    }

    /// The axes "Enable all" takes on `bus`, in node and axis order: those
    /// of every drive node the machine description expects started, and
    /// those the gateway last enabled (a node not described, enabled by
    /// hand).
    fn axes_to_enable(&self, bus: &str) -> Result<Vec<(u8, u8)>, GatewayError> {
        let served = self.bus(bus)?;
        let mut axes = std::collections::BTreeSet::new();
        if let Some(machine) = &served.machine {
            for &node in machine.described_started() {
                let Some(info) = served.registry.node(node) else {
                    // Not heard: its `node_missing` alarm says so.
                    continue;
                };
                if let Some(kind) = DriveKind::from_profile(info.profile) {
                    let count = axis_count(kind, info.eds_entry.as_deref());
                    axes.extend((1..=count).map(|axis| (node.get(), axis)));
                }
            }
        }
        axes.extend(self.enabled_axes.axes_on(bus));
        Ok(axes.into_iter().collect())
    }

    /// The active alarms whose cause keeps `node` of `bus` from recovering.
    fn blocking_causes(&self, bus: &str, node: u8) -> Vec<Alarm> {
        self.alarms.active(|source| {
            source.bus == bus
                && (source.node == Some(node) || source.node.is_none())
                && BLOCKING.contains(&source.kind.0)
        })
    }

    async fn reset_one(&self, caller: &Caller, bus: &str, node: u8, axis: u8) -> AxisRecovery {
        let refused =
            |reason: String, code: Option<&str>| AxisRecovery::refused(node, axis, reason, code);
        if let Some(reason) = self.cause_present(bus, node) {
            return refused(reason, None);
        }
        let (node_text, axis_text) = (node.to_string(), axis.to_string());
        let in_fault = match self.read_fault(bus, &node_text, &axis_text).await {
            Ok(in_fault) => in_fault,
            Err(error) => return refused(error.to_string(), Some(error.code())),
        };
        if !in_fault {
            return AxisRecovery::new(node, axis, RecoveryOutcome::NotNeeded);
        }
        match self
            .reset_axis_fault(caller, (bus, &node_text, &axis_text))
            .await
        {
            Ok(status) => AxisRecovery::done(node, axis, status.state),
            Err(error) => refused(
                format!("the cause is still present: {error}"),
                Some(error.code()),
            ),
        }
    }

    async fn enable_one(&self, caller: &Caller, bus: &str, node: u8, axis: u8) -> AxisRecovery {
        let refused =
            |reason: String, code: Option<&str>| AxisRecovery::refused(node, axis, reason, code);
        if let Some(reason) = self.cause_present(bus, node) {
            return refused(reason, None);
        }
        let (node_text, axis_text) = (node.to_string(), axis.to_string());
        match self.read_fault(bus, &node_text, &axis_text).await {
            Ok(true) => {
                return refused(
                    "the axis is in fault: reset the faults first".to_string(),
                    Some("drive_fault"),
                );
            }
            Ok(false) => {}
            Err(error) => return refused(error.to_string(), Some(error.code())),
        }
        let claim = LeaseClaim::presented(None, false);
        match self
            .set_axis_state(
                caller,
                (bus, &node_text, &axis_text),
                TargetState::OperationEnabled,
                &claim,
            )
            .await
        {
            Ok(outcome) => AxisRecovery::done(node, axis, outcome.status.state),
            Err(failed) => refused(failed.error.to_string(), Some(failed.error.code())),
        }
    }

    /// The reason a node's axes cannot recover now, if its cause is
    /// present.
    fn cause_present(&self, bus: &str, node: u8) -> Option<String> {
        let causes = self.blocking_causes(bus, node);
        (!causes.is_empty()).then(|| {
            let texts: Vec<String> = causes.iter().map(Alarm::reason).collect();
            format!("the cause is still present: {}", texts.join("; "))
        })
    }

    /// Whether the axis is in fault (its statusword, read now).
    async fn read_fault(&self, bus: &str, node: &str, axis: &str) -> Result<bool, GatewayError> {
        let drive = self.drive(bus, node, axis)?;
        let statusword = spawned(drive, |drive| async move { drive.statusword().await }).await?;
        Ok(statusword.fault())
    }
}
