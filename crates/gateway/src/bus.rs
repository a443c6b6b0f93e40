//! The operations on a bus as a whole, as every door reaches them: a scan
//! ([`Gateway::scan`]), the SYNC period ([`Gateway::set_sync_period`]), a
//! raw frame ([`Gateway::send_frame`]), a recording started and stopped
//! ([`Gateway::start_recording`], [`Gateway::stop_recording`]), a node's
//! boot-up run again by the network manager ([`Gateway::boot_node`]); the
//! LSS operations are [`crate::lss`]'s, the outputs of an I/O module
//! [`crate::io`]'s, on the same pattern.
//!
//! Each does the whole job for its [`Caller`]: its audit row (refusals
//! included, with the words the audit log has always had for it), the
//! role and a write of the caller's write rate ([`crate::policy`]), and
//! its work in a task of its own with its row, so that a client that goes
//! away cannot cut a scan's probes, a recording's file or an LSS
//! transaction half way.

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use crate::can::Frame;
use crate::canopen::NodeId;
use crate::recording::{Limits, RecordingStatus};
use crate::sync::{MAX_PERIOD_MS, SyncStatus};

use super::GatewayError;
use super::audit::{AuditRow, AuditTarget, spawn_audited};
use super::caller::Caller;
use super::policy::Operation;
use super::registry::NodeInfo;
use super::service::{Gateway, ServedBus};

impl Gateway {
    /// Runs `work` on `bus` for `caller` as an operation of `kind`: its
    /// row on `target` opened first (the bus named), the role required
    /// and, where the kind draws on it, one write of the caller's rate
    /// taken, then the bus found (each refusal finishing the row; a
    /// request for a bus not known costs a write, as any other request
    /// does); then `work` and the row in a task of their own.
    pub(crate) async fn on_bus<T, Fut>(
        &self,
        caller: &Caller,
        kind: Operation,
        bus: &str,
        target: AuditTarget,
        request: Option<String>,
        work: impl FnOnce(Arc<ServedBus>) -> Fut,
    ) -> Result<T, GatewayError>
    where
        T: Send + 'static,
        Fut: Future<Output = Result<T, GatewayError>> + Send + 'static,
    {
        let row = self.audit_row(caller, target.bus(bus), request);
        let checked = self.admit(caller, kind).and_then(|()| self.bus(bus));
        match checked {
            Ok(served) => spawn_audited(row, work(served)).await,
            Err(error) => refused(row, error).await,
        }
    }

    /// Scans `bus` for nodes (node-ID 1–127) and returns what the registry
    /// then knows (the operator's: a scan adds nodes and marks silent ones
    /// offline). Audited as `scan`.
    pub async fn scan(&self, caller: &Caller, bus: &str) -> Result<Vec<NodeInfo>, GatewayError> {
        let target = AuditTarget::new("scan");
        self.on_bus(caller, Operation::Scan, bus, target, None, |served| {
            let registry = served.registry.clone();
            async move { registry.scan().await.map_err(GatewayError::from) }
        })
        .await
    }

    /// Sets the period of the bus's SYNC producer (zero turns it off; at
    /// most [`MAX_PERIOD_MS`], 0x1006's range); its new setting (the
    /// operator's). Audited as `set sync period`.
    pub async fn set_sync_period(
        &self,
        caller: &Caller,
        bus: &str,
        period: Duration,
    ) -> Result<SyncStatus, GatewayError> {
        let target = AuditTarget::new("set sync period");
        let summary = format!("{{\"period_ms\":{}}}", period.as_millis());
        self.on_bus(caller, Operation::SetSync, bus, target, Some(summary), |served| {
            async move {
                if period > Duration::from_millis(u64::from(MAX_PERIOD_MS)) {
                    return Err(GatewayError::ValueOutOfRange(format!(
                        "a SYNC period of {} ms is beyond 0x1006's range (at most {MAX_PERIOD_MS} ms)",
                        period.as_millis()
                    )));
                }
                served.sync.set_period(period);
                Ok(served.sync.status())
            }
        })
        .await
    }

    /// Sends a raw frame on `bus`, as the gateway (the operator's).
    /// Audited as `send frame`.
    pub async fn send_frame(
        &self,
        caller: &Caller,
        bus: &str,
        frame: Frame,
    ) -> Result<(), GatewayError> {
        let target = AuditTarget::new("send frame");
        let summary = format!("{{\"frame\":\"{frame}\"}}");
        self.on_bus(
            caller,
            Operation::SendFrame,
            bus,
            target,
            Some(summary),
            |served| async move { served.bus.send(frame).await.map_err(GatewayError::from) },
        )
        .await
    }

    /// Starts recording `bus` to a candump log within `limits` (the
    /// administrator's: the file holds everything the bus carries).
    /// Audited as `start recording`.
    pub async fn start_recording(
        &self,
        caller: &Caller,
        bus: &str,
        limits: Limits,
    ) -> Result<RecordingStatus, GatewayError> {
        let target = AuditTarget::new("start recording");
        // The defaults asked for say nothing (REST's request without a body).
        let summary = (limits != Limits::default()).then(|| {
            format!(
                "{{\"max_frames\":{},\"max_seconds\":{}}}",
                limits.max_frames, limits.max_seconds
            )
        });
        self.on_bus(
            caller,
            Operation::Record,
            bus,
            target,
            summary,
            |served| async move { Ok(served.recorder.start(limits).await?) },
        )
        .await
    }

    /// Stops the recording of `bus`, everything received written and
    /// flushed; its final status (the administrator's). Audited as `stop
    /// recording`.
    pub async fn stop_recording(
        &self,
        caller: &Caller,
        bus: &str,
    ) -> Result<RecordingStatus, GatewayError> {
        let target = AuditTarget::new("stop recording");
        self.on_bus(
            caller,
            Operation::Record,
            bus,
            target,
            None,
            |served| async move { Ok(served.recorder.stop().await?) },
        )
        .await
    }

    /// Runs the boot-up of node `id` of `bus` again by the bus's network
    /// manager (identity check, configuration download, error control,
    /// NMT start); it returns once the boot-up has begun (the operator's).
    /// The node need not be in the registry: a node described but missing
    /// may be booted. Audited as `boot node again`.
    pub async fn boot_node(
        &self,
        caller: &Caller,
        bus: &str,
        id: &str,
    ) -> Result<NodeId, GatewayError> {
        let target = AuditTarget::new("boot node again").node(id.parse::<u8>().ok());
        let id = id.to_string();
        self.on_bus(
            caller,
            Operation::BootNode,
            bus,
            target,
            None,
            |served| async move {
                let node: NodeId = id.parse().map_err(|err| {
                    GatewayError::InvalidRequest(format!("node id '{id}': {err}"))
                })?;
                served
                    .machine()?
                    .boot(node)
                    .await
                    .map_err(GatewayError::InvalidRequest)?;
                Ok(node)
            },
        )
        .await
    }
}

/// An operation refused before its work: `row` says why.
pub(crate) async fn refused<T>(row: AuditRow, error: GatewayError) -> Result<T, GatewayError> {
    let result = Err(error);
    row.finish(&result).await;
    result
}

#[cfg(test)]
mod tests;
