//! Program download (CiA 302-3) as an operation of a node's handle:
//! [`NodeHandle::download_program`] does the whole job for its [`Caller`],
//! whichever door asks: the role (the administrator's: a new program
//! replaces what the device runs), a write from the caller's write rate,
//! the node's state checked, the sequence of [`crate::program`] in a task
//! the client cannot cancel (a download cut half way leaves the device
//! without a program), its progress published on the node's topic, and a
//! failed step named ([`GatewayError::FailedAt`]).
//!
//! The download is interlocked with motion (`crate::authority`): it is
//! refused while a program download or a renumbering runs on the node
//! (`node_busy`, never queued), and while an axis of the node is in
//! operation enabled or leased (`axis_enabled`); while it runs, the node
//! takes no motion command (stops are always taken). A client that goes
//! away during the download does not get its program started: the start
//! (0x1F51 = 1) is not sent (`client_gone` in the audit row and the
//! progress topic); the steps before it run to their end, so the device is
//! not left half-written.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use super::NodeHandle;
use super::transfer::{audited, spawned};
use crate::GatewayError;
use crate::caller::Caller;
use crate::check_sdo_allowed;
use crate::drive::{Drive, DriveKind, axis_count};
use crate::motion_lease::mask;
use crate::policy::Operation;
use crate::profiles::cia402::State;
use crate::program::{ProgramError, ProgramReport, download_program_for};

/// Whether the client of a download still waits for its answer: false
/// once its future is dropped (it hung up).
struct ClientWaits(Arc<AtomicBool>);

impl Drop for ClientWaits {
    fn drop(&mut self) {
        self.0.store(false, Ordering::Relaxed);
    }
}

/// A program download that ended well: its run number on the node (as the
/// progress reports carry it) and what it did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProgramDownload {
    pub run: u64,
    pub report: ProgramReport,
}

impl ProgramDownload {
    /// The image's size over the download's time, in bytes a second.
    pub fn bytes_per_s(&self) -> u64 {
        let seconds = self.report.download_ms.max(1) as f64 / 1000.0;
        (self.report.bytes as f64 / seconds) as u64
    }
}

impl NodeHandle {
    /// Downloads `image` to the node, verifies it and, if `start`, starts
    /// it (the administrator's; one write of the caller's rate). An empty
    /// image is refused before the bus.
    ///
    /// Audited as `download program`, in a task of its own with its row.
    pub async fn download_program(
        &self,
        caller: &Caller,
        image: Vec<u8>,
        start: bool,
    ) -> Result<ProgramDownload, GatewayError> {
        let summary = format!("{} bytes, start {start}", image.len());
        let row = self.audit_row(caller, "download program", None, Some(summary));
        let (this, caller) = (self.clone(), caller.clone());
        // Lives in the caller's future: dropped when its client hangs up.
        let waits = ClientWaits(Arc::new(AtomicBool::new(true)));
        let still = waits.0.clone();
        let result = audited(row, async move {
            this.download(&caller, image, start, still).await
        })
        .await;
        drop(waits);
        result
    }

    async fn download(
        &self,
        caller: &Caller,
        image: Vec<u8>,
        start: bool,
        client_waits: Arc<AtomicBool>,
    ) -> Result<ProgramDownload, GatewayError> {
        self.gateway.admit(caller, Operation::DownloadProgram)?;
        if image.is_empty() {
            return Err(GatewayError::InvalidRequest(
                "the body is the program image; it is empty".into(),
            ));
        }
        check_sdo_allowed(&self.served, &self.info)?;
        // Closed to motion first, so that nothing is enabled between the
        // check below and the download's end.
        let _closed = self
            .gateway
            .authority
            .close_node(
                &self.served.name,
                self.id(),
                format!("a program download runs on node {}", self.info.id),
            )
            .map_err(|why| GatewayError::NodeBusy(format!("node {}: {why}", self.info.id)))?;
        self.check_no_motion().await?;
        let channel = self.served.registry.sdo(self.info.id)?;
        let run = self.served.programs.begin(self.info.id);
        let number = run.run;
        tracing::info!(
            "node {} of bus {}: program download {number} ({} bytes) by {} ({})",
            self.info.id,
            self.served.name,
            image.len(),
            caller.who,
            caller.channel
        );
        let (gateway, bus, node) = (self.gateway.clone(), self.served.name.clone(), self.id());
        let report = spawned(async move {
            let waits = || client_waits.load(Ordering::Relaxed);
            let report = download_program_for(&channel, &image, start, &waits, &|progress| {
                run.publish(progress)
            })
            .await;
            // It reached the device: the alarms hear how it ended.
            gateway.work_done(crate::alarms::WorkDone::ProgramDownload {
                bus,
                node,
                failed: report.is_err(),
            });
            report.map_err(|ProgramError { step, error }| GatewayError::FailedAt {
                step: step.to_string(),
                source: Box::new(error),
            })
        })
        .await?;
        Ok(ProgramDownload {
            run: number,
            report,
        })
    }

    /// Refuses a download (`axis_enabled`) while a lease is held on an axis
    /// of the node, or an axis is in operation enabled (a new program
    /// replaces what controls the motor).
    async fn check_no_motion(&self) -> Result<(), GatewayError> {
        let node = self.info.id;
        if let Some(lease) = self
            .gateway
            .leases
            .on_node(&self.served.name, node.get())
            .first()
        {
            return Err(GatewayError::AxisEnabled(format!(
                "node {node} axis {} is held by the {} lease {} of {}: stop it before a program download",
                lease.axis.axis,
                lease.mode,
                mask(&lease.id),
                lease.holder
            )));
        }
        let Some(kind) = DriveKind::from_profile(self.info.profile) else {
            return Ok(());
        };
        for axis in 1..=axis_count(kind, self.info.eds_entry.as_deref()) {
            let drive = Drive::new(&self.served.registry, &self.info, &axis.to_string())?;
            let state = drive.statusword().await?.state();
            if matches!(
                state,
                Some(State::OperationEnabled | State::QuickStopActive)
            ) {
                return Err(GatewayError::AxisEnabled(format!(
                    "node {node} axis {axis} is in {}: stop it (halt, then leave operation enabled) before a program download",
                    state.map_or("unknown", State::name)
                )));
            }
        }
        Ok(())
    }
}
