//! Program download (CiA 302-3 §4.2): a new program image into a node's
//! program object, verified and started. The sequence: stop the program
//! (0x1F51 sub 1 = 0), clear it (3), download the image to 0x1F50 sub 1 by
//! SDO block transfer (with the block CRC), read the program software
//! identification 0x1F56 sub 1 and compare it with the image's CRC-32
//! (IEEE) computed here, then start the program (1) unless asked to leave
//! it stopped. Each step's failure is reported with the step's name, and
//! the device's abort code when it refused. Progress is reported as it
//! goes ([`ProgramProgress`]): each step, and the bytes of the image the
//! device has confirmed, block by block; the gateway publishes it per node
//! ([`ProgramTopics`]).

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use crate::canopen::NodeId;
use crate::canopen::crc32::crc32;
use crate::canopen::sdo::{AbortCode, ClientConfig};

use super::error::GatewayError;
use super::sdo::SdoChannel;
use super::telemetry::ValueTopic;

/// 0x1F50 sub 1: the program data.
const PROGRAM_DATA: (u16, u8) = (0x1F50, 1);
/// 0x1F51 sub 1: program control.
const PROGRAM_CONTROL: (u16, u8) = (0x1F51, 1);
/// 0x1F56 sub 1: program software identification.
const PROGRAM_SOFTWARE_ID: (u16, u8) = (0x1F56, 1);

/// The steps of a program download, by the name an error reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgramStep {
    /// 0x1F51 = 0.
    Stop,
    /// 0x1F51 = 3.
    Clear,
    /// The image to 0x1F50.
    Download,
    /// 0x1F56 read and compared.
    Verify,
    /// 0x1F51 = 1.
    Start,
}

impl ProgramStep {
    /// The step's short name in progress reports.
    pub fn key(self) -> &'static str {
        match self {
            ProgramStep::Stop => "stop",
            ProgramStep::Clear => "clear",
            ProgramStep::Download => "download",
            ProgramStep::Verify => "verify",
            ProgramStep::Start => "start",
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            ProgramStep::Stop => "stop program (0x1F51 = 0)",
            ProgramStep::Clear => "clear program (0x1F51 = 3)",
            ProgramStep::Download => "download image (0x1F50)",
            ProgramStep::Verify => "verify (0x1F56)",
            ProgramStep::Start => "start program (0x1F51 = 1)",
        }
    }
}

impl std::fmt::Display for ProgramStep {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A program download that stopped at a step.
#[derive(Debug, thiserror::Error)]
#[error("step {step}: {error}")]
pub(crate) struct ProgramError {
    pub step: ProgramStep,
    pub error: GatewayError,
}

/// What a program download did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProgramReport {
    /// The image's size.
    pub bytes: usize,
    /// The image's CRC-32, which 0x1F56 sub 1 gave back.
    pub crc32: u32,
    /// Whether the program was started at the end.
    pub started: bool,
    /// The whole sequence, and the download of 0x1F50 alone, in ms.
    pub elapsed_ms: u64,
    pub download_ms: u64,
}

/// Where a program download is, as its progress reports say it (the
/// `buses/{bus}/nodes/{id}/program` topic of the stream).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProgramProgress {
    /// The step running, or the one that failed, or the last one done.
    pub step: ProgramStep,
    pub state: ProgramState,
    /// The bytes of the image the device has confirmed (block by block).
    pub bytes_sent: usize,
    pub bytes_total: usize,
}

/// Whether a program download runs, succeeded or failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ProgramState {
    Running,
    Done,
    /// Stopped at `step`: the error's text, and the device's abort code
    /// when it refused.
    Failed {
        message: String,
        abort_code: Option<AbortCode>,
    },
}

impl ProgramProgress {
    /// The report as the stream gives it (`docs/websocket.md`).
    pub fn to_json(&self, run: u64) -> serde_json::Value {
        let (state, error, abort_code) = match &self.state {
            ProgramState::Running => ("running", None, None),
            ProgramState::Done => ("done", None, None),
            ProgramState::Failed {
                message,
                abort_code,
            } => ("failed", Some(message.as_str()), *abort_code),
        };
        // Whole percents, and 100 only once every byte is confirmed.
        let percent = (self.bytes_sent * 100)
            .checked_div(self.bytes_total)
            .unwrap_or(0);
        serde_json::json!({
            "run": run,
            "state": state,
            "step": self.step.key(),
            "step_name": self.step.name(),
            "bytes_sent": self.bytes_sent,
            "bytes_total": self.bytes_total,
            "percent": percent,
            "error": error,
            "abort_code": abort_code.map(|code| format!("0x{:08X}", code.raw())),
            "abort_text": abort_code.map(AbortCode::text),
        })
    }
}

/// The program download progress of each node of a bus: one stream topic
/// per node, made when first asked for (by a reader or a download), which
/// keeps the newest report, so that a reader that comes late still sees
/// how the last download ended.
#[derive(Default)]
pub struct ProgramTopics {
    topics: Mutex<BTreeMap<NodeId, (ValueTopic, u64)>>,
    /// The nodes a download runs on now (their SDO channel is held by it).
    running: std::sync::Arc<Mutex<std::collections::BTreeSet<NodeId>>>,
}

impl ProgramTopics {
    /// The progress topic of `node`.
    pub fn topic(&self, node: NodeId) -> ValueTopic {
        self.lock().entry(node).or_default().0.clone()
    }

    /// A new download on `node`: its run number (1, 2, ... per node, which
    /// each report carries) and what publishes its reports.
    pub fn begin(&self, node: NodeId) -> ProgramRun {
        let mut topics = self.lock();
        let (topic, runs) = topics.entry(node).or_default();
        *runs += 1;
        running(&self.running).insert(node);
        ProgramRun {
            run: *runs,
            topic: topic.clone(),
            node,
            running: self.running.clone(),
        }
    }

    /// Whether a download runs on `node` now.
    pub fn runs_on(&self, node: NodeId) -> bool {
        running(&self.running).contains(&node)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, BTreeMap<NodeId, (ValueTopic, u64)>> {
        // A map of handles is never left half-written.
        self.topics
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

fn running(
    set: &Mutex<std::collections::BTreeSet<NodeId>>,
) -> std::sync::MutexGuard<'_, std::collections::BTreeSet<NodeId>> {
    // A set of plain values is never left half-written.
    set.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// One download's progress reports into its node's topic; the node's
/// download runs while it lives.
pub struct ProgramRun {
    pub run: u64,
    topic: ValueTopic,
    node: NodeId,
    running: std::sync::Arc<Mutex<std::collections::BTreeSet<NodeId>>>,
}

impl Drop for ProgramRun {
    fn drop(&mut self) {
        running(&self.running).remove(&self.node);
    }
}

impl ProgramRun {
    pub fn publish(&self, progress: &ProgramProgress) {
        self.topic.publish(progress.to_json(self.run));
    }
}

/// Downloads `image` to the node of `channel` (see the module
/// documentation); `start`: start the program at the end. `progress` is
/// told each step as it begins, the bytes of the image as the device
/// confirms them, and the end: done, or failed with the step.
#[cfg(test)]
pub(crate) async fn download_program(
    channel: &SdoChannel,
    image: &[u8],
    start: bool,
    progress: &(dyn Fn(&ProgramProgress) + Sync),
) -> Result<ProgramReport, ProgramError> {
    download_program_for(channel, image, start, &|| true, progress).await
}

/// [`download_program`] for a client that may go away: `client_waits` is
/// asked before the start (0x1F51 = 1), which is not sent once it says no
/// (the program is left stopped, and the download fails at the start step
/// with `client_gone`).
pub(crate) async fn download_program_for(
    channel: &SdoChannel,
    image: &[u8],
    start: bool,
    client_waits: &(dyn Fn() -> bool + Sync),
    progress: &(dyn Fn(&ProgramProgress) + Sync),
) -> Result<ProgramReport, ProgramError> {
    let sent = AtomicUsize::new(0);
    let at = |step: ProgramStep| ProgramProgress {
        step,
        state: ProgramState::Running,
        bytes_sent: sent.load(Ordering::Relaxed),
        bytes_total: image.len(),
    };
    let result = run_steps(channel, image, start, client_waits, &|step, confirmed| {
        if let Some(confirmed) = confirmed {
            sent.store(confirmed, Ordering::Relaxed);
        }
        progress(&at(step));
    })
    .await;
    let last = match &result {
        Ok(report) if report.started => at(ProgramStep::Start),
        Ok(_) => at(ProgramStep::Verify),
        Err(error) => at(error.step),
    };
    progress(&ProgramProgress {
        state: match &result {
            Ok(_) => ProgramState::Done,
            Err(error) => ProgramState::Failed {
                message: error.error.to_string(),
                abort_code: error.error.abort_code(),
            },
        },
        ..last
    });
    result
}

/// The steps; `report(step, confirmed)` at each step's beginning and as
/// the device confirms bytes of the image.
async fn run_steps(
    channel: &SdoChannel,
    image: &[u8],
    start: bool,
    client_waits: &(dyn Fn() -> bool + Sync),
    report: &(dyn Fn(ProgramStep, Option<usize>) + Sync),
) -> Result<ProgramReport, ProgramError> {
    let began = Instant::now();
    // One procedure on the node at a time.
    let _procedure = channel.procedure().await;
    let at = |step: ProgramStep| move |error: GatewayError| ProgramError { step, error };
    let control = |step: ProgramStep, command: u8| async move {
        report(step, None);
        channel
            .download(PROGRAM_CONTROL.0, PROGRAM_CONTROL.1, &[command])
            .await
            .map_err(|error| at(step)(error.into()))
    };
    control(ProgramStep::Stop, 0).await?;
    control(ProgramStep::Clear, 3).await?;
    let block = ClientConfig {
        use_block_download_from: Some(1),
        crc: true,
        ..channel.config().clone()
    };
    let download_began = Instant::now();
    // The channel reports 0 bytes once the transfer has begun.
    channel
        .download_reporting(
            PROGRAM_DATA.0,
            PROGRAM_DATA.1,
            image,
            Some(&block),
            &|confirmed, _| report(ProgramStep::Download, Some(confirmed)),
        )
        .await
        .map_err(|error| at(ProgramStep::Download)(error.into()))?;
    let download_ms = download_began.elapsed().as_millis() as u64;
    report(ProgramStep::Verify, Some(image.len()));
    let expected = crc32(image);
    let raw = channel
        .upload(PROGRAM_SOFTWARE_ID.0, PROGRAM_SOFTWARE_ID.1)
        .await
        .map_err(|error| at(ProgramStep::Verify)(error.into()))?;
    let given = <[u8; 4]>::try_from(raw.as_slice())
        .map(u32::from_le_bytes)
        .map_err(|_| {
            at(ProgramStep::Verify)(GatewayError::ProgramNotVerified(format!(
                "0x1F56 sub 1 gave {} bytes, not the 4 of a CRC-32",
                raw.len()
            )))
        })?;
    if given != expected {
        return Err(at(ProgramStep::Verify)(GatewayError::ProgramNotVerified(
            format!(
                "0x1F56 sub 1 is 0x{given:08X}, the image's CRC-32 is 0x{expected:08X}; the program was left stopped"
            ),
        )));
    }
    if start {
        if !client_waits() {
            // Nobody is there to see a program started, or to stop it.
            return Err(at(ProgramStep::Start)(GatewayError::ClientGone(
                "the client went away during the download: the program was verified and left stopped"
                    .to_string(),
            )));
        }
        control(ProgramStep::Start, 1).await?;
    }
    Ok(ProgramReport {
        bytes: image.len(),
        crc32: expected,
        started: start,
        elapsed_ms: began.elapsed().as_millis() as u64,
        download_ms,
    })
}

#[cfg(test)]
mod tests;
