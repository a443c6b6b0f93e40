//! Recording a bus to a candump `-L` log (linux-can/can-utils `candump -L`,
//! the format of [`crate::can::candump`]), started and stopped at will,
//! for `POST|GET|DELETE /buses/{bus}/recording` and the download of
//! `GET /buses/{bus}/recording.log`. `--bus replay:FILE` plays such a log
//! back ([`crate::can::candump::open_replay`]).
//!
//! A recording reads the same subscription as the frame log
//! ([`crate::frames`]): the bus's [`monitor`](Bus::monitor), so the
//! gateway's own frames (SDO requests, NMT, SYNC) are in it with the
//! others'. Frames go straight to a file through a [`BufWriter`], never to
//! a growing buffer in memory; the buffer is flushed every
//! [`FLUSH_EVERY`], before a download and when the recording stops, so the
//! file on disk is never more than that behind. A recording stops when
//! asked, after its frame or time limit ([`Limits`], at most
//! [`MAX_FRAMES`] and [`MAX_SECONDS`]), when the bus closes, or on a write
//! error; frames it missed because it fell behind the bus are counted in
//! [`RecordingStatus::lost`], never dropped silently.
//!
//! Where the files go: with `--data-dir DIR`, into `DIR/recordings/`, where
//! they stay up to a quota (`recordings_quota_mb`, [`prune`]: the oldest
//! go first, each removal audited by the gateway service). Without it, into a private directory under the system's
//! temporary directory, made on the first recording, which is removed with
//! the [`Recorder`] (the gateway's exit); there a new recording of the bus
//! deletes the one before.
//!
//! Measured (`frames_per_second`, release, this 2-core machine under
//! load): one sender offering 2.2 million 8-byte frames/s, the recorder
//! wrote 1.9 million/s (450 ns per frame, about 47 bytes per line) and
//! counted the rest as lost: a hundred times what a saturated 1 Mbit/s
//! bus carries.
//!
//! The lines name the bus as their interface when the bus name is a valid
//! Linux interface name (at most 15 characters of letters, digits, `-`,
//! `_`, `.`), `can0` otherwise, so that `canplayer` can map them
//! (`canplayer vcan0=demo`) and `replay:FILE` plays them without options.

use std::fmt;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::io::{AsyncWrite, BufWriter};
use tokio::sync::{mpsc, oneshot};
use tokio::time::Instant;

use crate::can::candump::{Ended, FlushPolicy, LogRecorder, RecordEnd, RecordProgress};
use crate::can::{Bus, FrameReceiver, Timestamp};

/// The most frames one recording may be asked for, and its default limit.
pub(crate) const MAX_FRAMES: u64 = 1_000_000;
/// The longest a recording may be asked to run, and its default limit.
pub(crate) const MAX_SECONDS: u64 = 3600;
/// How often a running recording flushes its buffer to the file.
pub(crate) const FLUSH_EVERY: Duration = Duration::from_secs(1);
/// The write buffer: a few thousand lines between flushes at most.
const BUFFER: usize = 64 * 1024;
/// Linux interface names are at most this long (`IFNAMSIZ` - 1), and
/// `canplayer` maps interfaces by such names.
const IFACE_MAX: usize = 15;

/// Why a recording could not be started, stopped or read.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// A limit outside 1..=max.
    #[error("{what} {value}: a recording takes 1 to {max}")]
    LimitOutOfRange {
        what: &'static str,
        value: u64,
        max: u64,
    },
    /// A recording of the bus is running already.
    #[error("bus {bus} is being recorded already (to {file}); stop that recording first (DELETE)")]
    Running { bus: String, file: String },
    /// The bus's last recording has stopped already.
    #[error("the recording of bus {bus} has stopped already ({reason})")]
    NotRunning { bus: String, reason: String },
    /// The bus has never been recorded, or its log is gone.
    #[error("{0}")]
    NoRecording(String),
    /// The file could not be made, written or read.
    #[error("recording of bus {bus}: {source}")]
    Io {
        bus: String,
        #[source]
        source: io::Error,
    },
}

/// How much a recording may take: it stops at whichever comes first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    pub max_frames: u64,
    pub max_seconds: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_frames: MAX_FRAMES,
            max_seconds: MAX_SECONDS,
        }
    }
}

impl Limits {
    /// The limits asked for, the defaults (`MAX_FRAMES`, `MAX_SECONDS`)
    /// for those not given; 0 or above the maximum is an error.
    pub fn new(max_frames: Option<u64>, max_seconds: Option<u64>) -> Result<Self, RecordingError> {
        let check = |what, value: Option<u64>, max| match value {
            None => Ok(max),
            Some(value) if (1..=max).contains(&value) => Ok(value),
            Some(value) => Err(RecordingError::LimitOutOfRange { what, value, max }),
        };
        Ok(Self {
            max_frames: check("max_frames", max_frames, MAX_FRAMES)?,
            max_seconds: check("max_seconds", max_seconds, MAX_SECONDS)?,
        })
    }
}

/// Whether a bus is being recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordingState {
    Recording,
    Stopped,
    /// The bus has not been recorded since the gateway started.
    None,
}

/// Why a recording stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// Someone stopped it (or the gateway is stopping).
    Asked,
    MaxFrames,
    MaxSeconds,
    /// The bus's attachment closed: no frame will come any more.
    BusClosed,
    /// Writing the file failed (see [`RecordingStatus::error`]).
    DiskError,
}

impl StopReason {
    /// The snake_case name the API gives it.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Asked => "asked",
            Self::MaxFrames => "max_frames",
            Self::MaxSeconds => "max_seconds",
            Self::BusClosed => "bus_closed",
            Self::DiskError => "disk_error",
        }
    }
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What a recording is doing or did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordingStatus {
    pub state: RecordingState,
    pub stop_reason: Option<StopReason>,
    /// With [`StopReason::DiskError`]: what the system said.
    pub error: Option<String>,
    /// The log's file name (what a download is called).
    pub file: Option<String>,
    /// Frames written (lines in the log).
    pub frames: u64,
    /// Frames missed because the recorder fell behind the bus.
    pub lost: u64,
    /// Bytes written (some may wait in the buffer while it runs).
    pub bytes: u64,
    pub started: Option<Timestamp>,
    pub stopped: Option<Timestamp>,
    pub limits: Option<Limits>,
}

impl RecordingStatus {
    fn none() -> Self {
        Self {
            state: RecordingState::None,
            stop_reason: None,
            error: None,
            file: None,
            frames: 0,
            lost: 0,
            bytes: 0,
            started: None,
            stopped: None,
            limits: None,
        }
    }
}

/// A recording's log as it stands: read the first `len` bytes of `path`
/// (whole lines; the recording may go on writing after them).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordingLog {
    pub path: PathBuf,
    pub file_name: String,
    pub len: u64,
}

/// A recording's log opened to be read: `len` bytes of `reader`.
#[derive(Debug)]
pub struct OpenedLog {
    pub file_name: String,
    pub len: u64,
    pub reader: tokio::io::Take<tokio::fs::File>,
}

/// The end of a recording, as its task saw it.
#[derive(Debug, Default)]
struct End {
    reason: Option<StopReason>,
    error: Option<String>,
    stopped: Option<Timestamp>,
}

/// What the recording task and the [`Recorder`] share.
#[derive(Debug, Default)]
struct Progress {
    frames: AtomicU64,
    lost: AtomicU64,
    bytes: AtomicU64,
    end: Mutex<End>,
}

/// What the recording task is asked; each answers when done.
enum Command {
    Flush(oneshot::Sender<()>),
    Stop(oneshot::Sender<()>),
}

/// One recording, running or done.
struct Session {
    path: PathBuf,
    file_name: String,
    started: Timestamp,
    limits: Limits,
    progress: Arc<Progress>,
    /// Dropping the last sender ends the task (writing what is queued).
    commands: mpsc::Sender<Command>,
}

impl Session {
    fn status(&self) -> RecordingStatus {
        let end = lock(&self.progress.end);
        RecordingStatus {
            state: if end.reason.is_some() {
                RecordingState::Stopped
            } else {
                RecordingState::Recording
            },
            stop_reason: end.reason,
            error: end.error.clone(),
            file: Some(self.file_name.clone()),
            frames: self.progress.frames.load(Ordering::Relaxed),
            lost: self.progress.lost.load(Ordering::Relaxed),
            bytes: self.progress.bytes.load(Ordering::Relaxed),
            started: Some(self.started),
            stopped: end.stopped,
            limits: Some(self.limits),
        }
    }

    fn running(&self) -> bool {
        lock(&self.progress.end).reason.is_none()
    }
}

/// Asks a recording task and waits for its answer; a task that has ended
/// has nothing left to do.
async fn ask(commands: mpsc::Sender<Command>, command: fn(oneshot::Sender<()>) -> Command) {
    let (reply, done) = oneshot::channel();
    if commands.send(command(reply)).await.is_ok() {
        let _ = done.await;
    }
}

/// Where a bus's recordings go.
enum Place {
    /// `--data-dir DIR/recordings`: kept.
    Kept(PathBuf),
    /// A private temporary directory, made on first use and removed with
    /// the recorder.
    Temporary(Option<TempDir>),
}

/// The recorder of one bus: at most one recording at a time, and the last
/// one kept for its status and its download.
pub struct Recorder {
    bus: Bus,
    iface: String,
    /// Serialises start and stop (they await file and task).
    control: tokio::sync::Mutex<Place>,
    current: Mutex<Option<Session>>,
}

impl Recorder {
    /// The recorder of `bus`; `dir` is where recordings are kept (created
    /// when the first one starts), `None` for a private temporary
    /// directory.
    pub fn new(bus: &Bus, dir: Option<PathBuf>) -> Self {
        Self {
            bus: bus.clone(),
            iface: iface_name(bus.name()),
            control: tokio::sync::Mutex::new(match dir {
                Some(dir) => Place::Kept(dir),
                None => Place::Temporary(None),
            }),
            current: Mutex::new(None),
        }
    }

    /// The interface name the log's lines carry.
    pub fn iface(&self) -> &str {
        &self.iface
    }

    /// Starts recording from now: every frame the bus carries after this
    /// returns is in the log (up to the limits).
    ///
    /// A door starts one by [`crate::Gateway::start_recording`].
    pub(crate) async fn start(&self, limits: Limits) -> Result<RecordingStatus, RecordingError> {
        let mut place = self.control.lock().await;
        if let Some(session) = lock(&self.current).as_ref()
            && session.running()
        {
            return Err(RecordingError::Running {
                bus: self.bus.name().to_string(),
                file: session.file_name.clone(),
            });
        }
        let io_error = |source| RecordingError::Io {
            bus: self.bus.name().to_string(),
            source,
        };
        let dir = match &mut *place {
            Place::Kept(dir) => dir.clone(),
            Place::Temporary(Some(temp)) => temp.0.clone(),
            Place::Temporary(empty) => {
                let temp = TempDir::new(self.bus.name()).map_err(io_error)?;
                empty.insert(temp).0.clone()
            }
        };
        // Only the gateway's user reads what the bus carried (0700, and
        // each log 0600).
        crate::files::create_private_dir(&dir).map_err(io_error)?;
        let started = Timestamp::now();
        let (file, path) = create_log(&dir, &file_stem(self.bus.name()), started)
            .await
            .map_err(io_error)?;
        // Subscribed before returning: nothing sent after the answer is missed.
        let frames = self.bus.monitor();
        let progress = Arc::new(Progress::default());
        let (commands, inbox) = mpsc::channel(4);
        let job = Job {
            bus: self.bus.name().to_string(),
            iface: self.iface.clone(),
            limits,
            since: Instant::now(),
        };
        tokio::spawn(record(frames, file, job, progress.clone(), inbox));
        let session = Session {
            file_name: path
                .file_name()
                .map(|name| name.to_string_lossy().into_owned())
                .unwrap_or_default(),
            path,
            started,
            limits,
            progress,
            commands,
        };
        let status = session.status();
        let before = lock(&self.current).replace(session);
        if let (Some(before), Place::Temporary(_)) = (before, &*place) {
            // Its task has ended (it was not running); only the file is left.
            if let Err(err) = tokio::fs::remove_file(&before.path).await {
                tracing::warn!(bus = self.bus.name(), "removing the last recording: {err}");
            }
        }
        tracing::info!(bus = self.bus.name(), file = %status.file.as_deref().unwrap_or(""), "recording started");
        Ok(status)
    }

    /// Stops the running recording, with everything it had received
    /// written and flushed; its final status.
    ///
    /// A door stops one by [`crate::Gateway::stop_recording`].
    pub(crate) async fn stop(&self) -> Result<RecordingStatus, RecordingError> {
        let _serial = self.control.lock().await;
        let commands = {
            let current = lock(&self.current);
            let Some(session) = current.as_ref() else {
                return Err(self.no_recording());
            };
            if !session.running() {
                let status = session.status();
                return Err(RecordingError::NotRunning {
                    bus: self.bus.name().to_string(),
                    reason: status
                        .stop_reason
                        .map_or("stopped", StopReason::as_str)
                        .to_string(),
                });
            }
            session.commands.clone()
        };
        ask(commands, Command::Stop).await;
        Ok(self.status())
    }

    /// The file of the running or last recording, which pruning keeps.
    pub fn current_path(&self) -> Option<PathBuf> {
        lock(&self.current)
            .as_ref()
            .map(|session| session.path.clone())
    }

    /// The running or last recording's status.
    pub fn status(&self) -> RecordingStatus {
        lock(&self.current)
            .as_ref()
            .map_or_else(RecordingStatus::none, Session::status)
    }

    /// The log of the running or last recording, flushed first when it
    /// runs.
    pub async fn log(&self) -> Result<RecordingLog, RecordingError> {
        let (path, file_name, commands) = {
            let current = lock(&self.current);
            let session = current.as_ref().ok_or_else(|| self.no_recording())?;
            (
                session.path.clone(),
                session.file_name.clone(),
                session.commands.clone(),
            )
        };
        ask(commands, Command::Flush).await;
        match tokio::fs::metadata(&path).await {
            Ok(meta) => Ok(RecordingLog {
                path,
                file_name,
                len: meta.len(),
            }),
            Err(err) if err.kind() == io::ErrorKind::NotFound => {
                Err(RecordingError::NoRecording(format!(
                    "the log of bus {}'s last recording ({file_name}) is gone from the disk",
                    self.bus.name()
                )))
            }
            Err(source) => Err(RecordingError::Io {
                bus: self.bus.name().to_string(),
                source,
            }),
        }
    }

    /// The last recording's log opened to be read, as far as it is
    /// flushed ([`Recorder::log`]): whole lines, even while the recording
    /// goes on.
    pub async fn open_log(&self) -> Result<OpenedLog, RecordingError> {
        let log = self.log().await?;
        let file = tokio::fs::File::open(&log.path).await.map_err(|source| {
            if source.kind() == io::ErrorKind::NotFound {
                // A new recording replaced it meanwhile.
                RecordingError::NoRecording(format!(
                    "the log {} of bus {} is gone from the disk",
                    log.file_name,
                    self.bus.name()
                ))
            } else {
                RecordingError::Io {
                    bus: self.bus.name().to_string(),
                    source,
                }
            }
        })?;
        Ok(OpenedLog {
            reader: tokio::io::AsyncReadExt::take(file, log.len),
            file_name: log.file_name,
            len: log.len,
        })
    }

    fn no_recording(&self) -> RecordingError {
        RecordingError::NoRecording(format!(
            "bus {} has not been recorded: start a recording of it first",
            self.bus.name()
        ))
    }
}

/// The most the kept recordings (`--data-dir DIR/recordings`) may take
/// together by default, in MiB (`recordings_quota_mb`).
pub const DEFAULT_QUOTA_MB: u64 = 1024;

/// The quota of the kept recordings: the directory they are in, and the
/// most bytes its logs may take together.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordingsQuota {
    pub dir: PathBuf,
    pub bytes: u64,
}

/// A log removed by [`prune`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pruned {
    pub file_name: String,
    pub bytes: u64,
}

/// Removes the oldest logs (`*.log`, by modification time, then name) of
/// `quota.dir` until together they take at most `quota.bytes`; never one
/// of `keep` (the running and the last recording of each bus), so that
/// the quota may be exceeded by those. What it removed, oldest first.
pub(crate) fn prune(quota: &RecordingsQuota, keep: &[PathBuf]) -> io::Result<Vec<Pruned>> {
    let entries = match std::fs::read_dir(&quota.dir) {
        Ok(entries) => entries,
        // No recording yet.
        Err(err) if err.kind() == io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(err) => return Err(err),
    };
    let mut logs = Vec::new();
    for entry in entries {
        let entry = entry?;
        let path = entry.path();
        let meta = entry.metadata()?;
        if !meta.is_file() || path.extension().is_none_or(|ext| ext != "log") {
            continue;
        }
        let modified = meta.modified().unwrap_or(std::time::UNIX_EPOCH);
        logs.push((modified, path, meta.len()));
    }
    logs.sort();
    let mut total: u64 = logs.iter().map(|(_, _, len)| len).sum();
    let mut pruned = Vec::new();
    for (_, path, len) in logs {
        if total <= quota.bytes {
            break;
        }
        if keep.contains(&path) {
            continue;
        }
        std::fs::remove_file(&path)?;
        total -= len;
        pruned.push(Pruned {
            file_name: path
                .file_name()
                .map(|name| name.to_string_lossy().into_owned())
                .unwrap_or_default(),
            bytes: len,
        });
    }
    Ok(pruned)
}

/// What a recording task is to do.
struct Job {
    bus: String,
    /// The interface its lines name.
    iface: String,
    limits: Limits,
    /// When it started: the time limit counts from here.
    since: Instant,
}

/// The recording task: `frames` to `file` until a limit, a stop, a closed
/// bus or a write error, by the one record loop of
/// [`crate::can::candump::LogRecorder`]. Writes what is queued before it
/// stops for a command or the time limit, so a stop loses nothing already
/// received.
async fn record<W: AsyncWrite + Unpin>(
    mut frames: FrameReceiver,
    file: W,
    job: Job,
    progress: Arc<Progress>,
    mut commands: mpsc::Receiver<Command>,
) {
    let Job {
        bus,
        iface,
        limits,
        since,
    } = job;
    let mut recorder = LogRecorder::new(
        BufWriter::with_capacity(BUFFER, file),
        &iface,
        &bus,
        Some(limits.max_frames),
        FlushPolicy::Every(FLUSH_EVERY),
        since,
    );
    let deadline = tokio::time::sleep_until(since + Duration::from_secs(limits.max_seconds));
    tokio::pin!(deadline);
    let mut answer: Option<oneshot::Sender<()>> = None;
    let outcome: Result<StopReason, io::Error> = loop {
        // Commands first: a busy bus would otherwise never let one in.
        let control = async {
            tokio::select! {
                biased;
                command = commands.recv() => Some(command),
                () = &mut deadline => None,
            }
        };
        let (control, ended) = match recorder.run(&mut frames, &*progress, control).await {
            Err(err) => break Err(err),
            Ok(RecordEnd::Ended(ended)) => (None, Some(ended)),
            Ok(RecordEnd::Control(control)) => (Some(control), recorder.ended()),
        };
        // A limit or the bus's end reached meanwhile is the reason to stop.
        let or_ended = |reason| match ended {
            Some(Ended::MaxFrames) => StopReason::MaxFrames,
            Some(Ended::Closed) => StopReason::BusClosed,
            None => reason,
        };
        let reason = match control {
            None => or_ended(StopReason::Asked),
            Some(None) => or_ended(StopReason::MaxSeconds),
            Some(Some(Some(Command::Flush(reply)))) => {
                let done = recorder.flush().await;
                let _ = reply.send(());
                match (done, ended) {
                    (Err(err), _) => break Err(err),
                    (Ok(()), None) => continue,
                    (Ok(()), Some(_)) => or_ended(StopReason::Asked),
                }
            }
            Some(Some(Some(Command::Stop(reply)))) => {
                answer = Some(reply);
                or_ended(StopReason::Asked)
            }
            // The recorder is gone.
            Some(Some(None)) => or_ended(StopReason::Asked),
        };
        break recorder.flush().await.map(|()| reason);
    };
    let mut end = lock(&progress.end);
    end.stopped = Some(Timestamp::now());
    match outcome {
        Ok(reason) => end.reason = Some(reason),
        Err(err) => {
            tracing::warn!(bus, "recording stopped: cannot write the log: {err}");
            end.reason = Some(StopReason::DiskError);
            end.error = Some(err.to_string());
        }
    }
    drop(end);
    // Answered once the status is final.
    if let Some(reply) = answer {
        let _ = reply.send(());
    }
    // Commands sent meanwhile find the task ended.
    commands.close();
    while let Ok(command) = commands.try_recv() {
        match command {
            Command::Flush(reply) | Command::Stop(reply) => {
                let _ = reply.send(());
            }
        }
    }
}

impl RecordProgress for Progress {
    fn written(&self, bytes: usize) {
        self.bytes.fetch_add(bytes as u64, Ordering::Relaxed);
        self.frames.fetch_add(1, Ordering::Relaxed);
    }

    fn lost(&self, frames: u64) {
        self.lost.fetch_add(frames, Ordering::Relaxed);
    }
}

/// A new log file in `dir`: `STEM-YYYYMMDDTHHMMSSZ.log`, with `-2`, `-3`,
/// ... when that name is taken (two recordings in one second).
async fn create_log(
    dir: &Path,
    stem: &str,
    at: Timestamp,
) -> io::Result<(tokio::fs::File, PathBuf)> {
    let base = format!("{stem}-{}", utc_stamp(at));
    for n in 1..=100 {
        let name = if n == 1 {
            format!("{base}.log")
        } else {
            format!("{base}-{n}.log")
        };
        let path = dir.join(name);
        let mut options = tokio::fs::OpenOptions::new();
        #[cfg(unix)]
        options.mode(crate::files::FILE_MODE);
        match options.write(true).create_new(true).open(&path).await {
            Ok(file) => return Ok((file, path)),
            Err(err) if err.kind() == io::ErrorKind::AlreadyExists => {}
            Err(err) => return Err(err),
        }
    }
    Err(io::Error::new(
        io::ErrorKind::AlreadyExists,
        format!("{base}.log and 99 more names are taken"),
    ))
}

/// The interface name of a bus's log lines: the bus name when Linux would
/// take it as an interface name, `can0` otherwise.
pub(crate) fn iface_name(bus: &str) -> String {
    let valid = !bus.is_empty()
        && bus.len() <= IFACE_MAX
        && bus
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
        && bus != "."
        && bus != "..";
    if valid {
        bus.to_string()
    } else {
        "can0".to_string()
    }
}

/// The bus name made safe for a file name (and for a replay bus named
/// after it): letters, digits, `-` and `_`.
fn file_stem(bus: &str) -> String {
    let stem: String = bus
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .take(64)
        .collect();
    if stem.is_empty() {
        "bus".to_string()
    } else {
        stem
    }
}

/// `YYYYMMDDTHHMMSSZ`, UTC.
fn utc_stamp(at: Timestamp) -> String {
    let secs = at.secs();
    let (days, rest) = (secs / 86_400, secs % 86_400);
    let (year, month, day) = civil_from_days(days as i64);
    format!(
        "{year:04}{month:02}{day:02}T{:02}{:02}{:02}Z",
        rest / 3600,
        rest % 3600 / 60,
        rest % 60
    )
}

/// The proleptic Gregorian date of a day count since 1970-01-01
/// (H. Hinnant, "chrono-Compatible Low-Level Date Algorithms").
pub fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let month = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let year = yoe + era * 400 + i64::from(month <= 2);
    (year, month, day)
}

/// A private directory under the system's temporary directory, removed
/// with everything in it when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new(bus: &str) -> io::Result<Self> {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let base = std::env::temp_dir();
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        loop {
            let n = NEXT.fetch_add(1, Ordering::Relaxed);
            let path = base.join(format!(
                "candeck-recordings-{}-{}-{nanos:x}-{n}",
                std::process::id(),
                file_stem(bus)
            ));
            let mut builder = std::fs::DirBuilder::new();
            #[cfg(unix)]
            {
                use std::os::unix::fs::DirBuilderExt;
                // Only the gateway's user reads what the bus carried.
                builder.mode(0o700);
            }
            match builder.create(&path) {
                Ok(()) => return Ok(Self(path)),
                Err(err) if err.kind() == io::ErrorKind::AlreadyExists && n < 1000 => {}
                Err(err) => return Err(err),
            }
        }
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if let Err(err) = std::fs::remove_dir_all(&self.0) {
            tracing::warn!("removing {}: {err}", self.0.display());
        }
    }
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

#[cfg(test)]
mod tests;
