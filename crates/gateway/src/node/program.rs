//! Program download (CiA 302-3) as an operation of a node's handle:
//! [`NodeHandle::download_program`] does the whole job for its [`Caller`],
//! whichever door asks: the role (the administrator's: a new program
//! replaces what the device runs), a write from the caller's write rate,
//! the node's state checked, the sequence of [`crate::program`] in a task
//! the client cannot cancel (a download cut half way leaves the device
//! without a program), its progress published on the node's topic, and a
//! failed step named ([`GatewayError::FailedAt`]).

use super::NodeHandle;
use super::transfer::{audited, spawned};
use crate::GatewayError;
use crate::caller::Caller;
use crate::check_sdo_allowed;
use crate::policy::Operation;
use crate::program::{ProgramError, ProgramReport, download_program};

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
        audited(
            row,
            async move { this.download(&caller, image, start).await },
        )
        .await
    }

    async fn download(
        &self,
        caller: &Caller,
        image: Vec<u8>,
        start: bool,
    ) -> Result<ProgramDownload, GatewayError> {
        self.gateway.admit(caller, Operation::DownloadProgram)?;
        if image.is_empty() {
            return Err(GatewayError::InvalidRequest(
                "the body is the program image; it is empty".into(),
            ));
        }
        check_sdo_allowed(&self.served, &self.info)?;
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
        let report = spawned(async move {
            download_program(&channel, &image, start, &|progress| run.publish(progress))
                .await
                .map_err(|ProgramError { step, error }| GatewayError::FailedAt {
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
}
