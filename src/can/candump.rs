//! candump `-L` log files, the format of linux-can/can-utils `candump -L`
//! that `canplayer` reads back: one frame per line,
//! `(SECONDS.MICROSECONDS) INTERFACE FRAME`, for example
//! `(1436509052.249713) can0 123#1122334455667788`.
//!
//! Lines are parsed and printed by the `socketcan` crate's `dump` module, so
//! this module and can-utils agree on every spelling (`123#R2`, `123##5AABB`,
//! error frames with `CAN_ERR_FLAG` in the identifier). Around it:
//! - [`read_log`]: a whole log as [`LoggedFrame`]s, or an error naming the
//!   file, the line and what is wrong with it;
//! - [`LogWriter`] and [`record_bus`]: a bus written out as a log;
//! - [`open_replay`]: a log played back as a read-only [`Bus`], at its
//!   recorded pace or scaled ([`ReplayOptions`]).

use std::fmt;
use std::future::Future;
use std::io::{self, BufRead, Read};
use std::path::{Path, PathBuf};
use std::time::Duration;

use socketcan_rs::dump::{CanDumpRecord, ParseError, Reader};
use socketcan_rs::id::CAN_ERR_FLAG;
use socketcan_rs::{CanAnyFrame, CanDataFrame};
use tokio::io::{AsyncWrite, AsyncWriteExt, BufWriter};
use tokio::time::Instant;

use super::bus::{
    Bus, BusKind, BusState, BusStatus, DEFAULT_RX_QUEUE, DriverSide, RecvError, attach_driver,
    driver_channels,
};
use super::frame::{EXTENDED_ID_MAX, FD_MAX_LEN, Frame, STANDARD_ID_MAX, TimedFrame, Timestamp};
use super::socketcan::{from_socketcan, to_socketcan};

/// Longest line read, the `socketcan` crate's own limit. A 64-byte FD frame
/// takes about 170 bytes.
pub const MAX_LINE: usize = 64 * 1024;

/// One line of a candump log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LoggedFrame {
    pub timestamp: Timestamp,
    /// The interface the frame was logged on (`can0`, ...).
    pub iface: String,
    pub frame: Frame,
}

impl LoggedFrame {
    fn record(&self) -> CanDumpRecord {
        CanDumpRecord {
            t_us: self.timestamp.as_micros(),
            device: self.iface.clone(),
            frame: to_socketcan(&self.frame),
            direction: None,
        }
    }
}

impl fmt::Display for LoggedFrame {
    /// The log line, without its newline.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.record().fmt(f)
    }
}

/// Why a log could not be read.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error("cannot read {}: {source}", .path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    /// `line` counts from 1.
    #[error("{}:{line}: {problem}", .path.display())]
    Line {
        path: PathBuf,
        line: usize,
        problem: String,
    },
}

/// Reads a whole candump `-L` log. Blank lines are skipped; anything else
/// that is not a frame is an error naming the line.
pub fn read_log(path: impl AsRef<Path>) -> Result<Vec<LoggedFrame>, LogError> {
    let path = path.as_ref();
    let file = std::fs::File::open(path).map_err(|source| LogError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    read_log_from(io::BufReader::new(file), path)
}

/// Reads a candump `-L` log from `input`; `path` names it in errors.
pub fn read_log_from(mut input: impl BufRead, path: &Path) -> Result<Vec<LoggedFrame>, LogError> {
    let mut frames = Vec::new();
    let mut buf = Vec::new();
    let mut line = 0;
    loop {
        buf.clear();
        // One byte over the limit tells a line of exactly the limit from a
        // longer one, without ever holding more than that in memory.
        let read = (&mut input)
            .take(MAX_LINE as u64 + 1)
            .read_until(b'\n', &mut buf)
            .map_err(|source| LogError::Read {
                path: path.to_path_buf(),
                source,
            })?;
        if read == 0 {
            return Ok(frames);
        }
        line += 1;
        let fail = |problem: String| LogError::Line {
            path: path.to_path_buf(),
            line,
            problem,
        };
        let content = buf.strip_suffix(b"\n").unwrap_or(&buf);
        if content.len() > MAX_LINE {
            return Err(fail(format!("line is longer than {} KiB", MAX_LINE / 1024)));
        }
        let text = std::str::from_utf8(content)
            .map_err(|_| fail("line is not UTF-8 text".to_string()))?
            .trim();
        if text.is_empty() {
            continue;
        }
        frames.push(parse_line(text).map_err(fail)?);
    }
}

/// One non-blank line, trimmed.
fn parse_line(text: &str) -> Result<LoggedFrame, String> {
    let record = match Reader::from_reader(text.as_bytes()).next_record() {
        Ok(Some(record)) => record,
        Ok(None) => return Err("line is empty".to_string()),
        Err(err) => return Err(explain(text, err)),
    };
    let frame = from_socketcan(&record.frame)
        .map_err(|err| format!("frame `{}`: {err}", excerpt(field(text, 2))))?;
    Ok(LoggedFrame {
        timestamp: Timestamp::from_micros(record.t_us),
        iface: record.device,
        frame,
    })
}

/// The `index`th space-separated field, as the `socketcan` parser splits.
fn field(text: &str, index: usize) -> &str {
    text.split(' ').nth(index).unwrap_or("")
}

/// At most 40 characters of `text`, for error messages.
fn excerpt(text: &str) -> String {
    const LIMIT: usize = 40;
    if text.chars().count() <= LIMIT {
        text.to_string()
    } else {
        format!("{}...", text.chars().take(LIMIT).collect::<String>())
    }
}

/// What the `socketcan` parser's terse error means for this line.
fn explain(text: &str, err: ParseError) -> String {
    match err {
        ParseError::UnexpectedEndOfLine => format!(
            "line ends early: expected `(SECONDS.MICROSECONDS) INTERFACE FRAME`, found `{}`",
            excerpt(text)
        ),
        ParseError::InvalidTimestamp => format!(
            "timestamp `{}` is not `(SECONDS.MICROSECONDS)` with six digits after the point",
            excerpt(field(text, 0))
        ),
        ParseError::InvalidDeviceName => {
            format!("interface name `{}` is not valid", excerpt(field(text, 1)))
        }
        ParseError::InvalidCanFrame => explain_frame(field(text, 2)),
        ParseError::InvalidFrameDirection => format!(
            "`{}` after the frame is not a direction (`R` or `T`)",
            excerpt(field(text, 3))
        ),
        ParseError::ConstructionError(err) => {
            format!("frame `{}` cannot be built: {err}", excerpt(field(text, 2)))
        }
        ParseError::Io(err) => err.to_string(),
    }
}

/// Says what is wrong with a frame field the parser rejected.
fn explain_frame(frame: &str) -> String {
    frame_problem(frame).unwrap_or_else(|| format!("frame `{}` is not valid", excerpt(frame)))
}

fn frame_problem(frame: &str) -> Option<String> {
    let Some((id, body)) = frame.split_once('#') else {
        return Some(format!(
            "frame `{}` has no `#` between identifier and data",
            excerpt(frame)
        ));
    };
    if id.is_empty() || !id.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Some(format!("identifier `{}` is not hexadecimal", excerpt(id)));
    }
    if id.len() != 3 && id.len() != 8 {
        return Some(format!(
            "identifier `{id}` has {} hex digits; candump writes 3 (standard) or 8 (extended)",
            id.len()
        ));
    }
    let raw = u32::from_str_radix(id, 16).ok()?;
    let is_error = raw & CAN_ERR_FLAG != 0;
    if !is_error && id.len() == 3 && raw > u32::from(STANDARD_ID_MAX) {
        return Some(format!(
            "standard identifier 0x{raw:03X} is above 0x7FF (write it with 8 digits if it is extended)"
        ));
    }
    if !is_error && raw > EXTENDED_ID_MAX {
        return Some(format!(
            "extended identifier 0x{raw:08X} is above 0x1FFFFFFF"
        ));
    }
    if let Some(fd) = body.strip_prefix('#') {
        if is_error {
            return Some("an error frame cannot be a CAN FD frame".to_string());
        }
        let mut chars = fd.chars();
        if !chars.next().is_some_and(|c| c.is_ascii_hexdigit()) {
            return Some(format!(
                "CAN FD frame `{}` lacks the flags digit after `##`",
                excerpt(frame)
            ));
        }
        return data_problem(chars.as_str(), FD_MAX_LEN, "a CAN FD frame");
    }
    if !is_error && let Some(dlc) = body.strip_prefix('R') {
        return Some(match u8::from_str_radix(dlc, 16) {
            Ok(dlc) if dlc > 8 => format!("a remote frame requests at most 8 bytes, not {dlc}"),
            _ => format!(
                "remote frame length `{}` is not one hex digit",
                excerpt(dlc)
            ),
        });
    }
    if body.contains('_') {
        return Some("the `_DLC` suffix (a raw DLC above 8) is not supported".to_string());
    }
    let what = if is_error {
        "an error frame"
    } else {
        "a classic CAN frame"
    };
    data_problem(body, 8, what)
}

fn data_problem(hex: &str, max: usize, what: &str) -> Option<String> {
    if !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Some(format!("data `{}` is not hexadecimal", excerpt(hex)));
    }
    if !hex.len().is_multiple_of(2) {
        return Some(format!(
            "data `{}` has an odd number of hex digits",
            excerpt(hex)
        ));
    }
    let len = hex.len() / 2;
    (len > max).then(|| format!("{what} carries at most {max} data bytes, not {len}"))
}

/// Writes frames as candump `-L` lines. Unbuffered: wrap `out` in a
/// [`BufWriter`] and [`flush`](Self::flush) when a batch is written.
pub struct LogWriter<W> {
    out: W,
    /// Reused for every line, so writing allocates nothing per frame.
    record: CanDumpRecord,
    line: String,
}

impl<W: AsyncWrite + Unpin> LogWriter<W> {
    /// Lines name `iface` as the interface. White space in it would make
    /// the lines unreadable, so it is written as `_`.
    pub fn new(out: W, iface: &str) -> Self {
        let mut device: String = iface
            .chars()
            .map(|c| if c.is_whitespace() { '_' } else { c })
            .collect();
        if device.is_empty() {
            device = "can".to_string();
        }
        Self {
            out,
            record: CanDumpRecord {
                t_us: 0,
                device,
                // Replaced before every line.
                frame: CanAnyFrame::Normal(CanDataFrame::default()),
                direction: None,
            },
            line: String::new(),
        }
    }

    /// Writes one line; returns its length in bytes (newline included).
    pub async fn write(&mut self, frame: &TimedFrame) -> io::Result<usize> {
        use fmt::Write as _;
        self.record.t_us = frame.timestamp.as_micros();
        self.record.frame = to_socketcan(&frame.frame);
        self.line.clear();
        // Writing to a String cannot fail.
        let _ = writeln!(self.line, "{}", self.record);
        self.out.write_all(self.line.as_bytes()).await?;
        Ok(self.line.len())
    }

    pub async fn flush(&mut self) -> io::Result<()> {
        self.out.flush().await
    }

    pub fn into_inner(self) -> W {
        self.out
    }
}

/// What [`record_bus`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RecordSummary {
    /// Lines written.
    pub written: u64,
    /// Frames lost because the writer fell behind the bus.
    pub lost: u64,
}

/// Writes everything on `bus` (its [`monitor`](Bus::monitor): frames sent
/// through it too) to `out` as candump `-L` lines naming `iface`, until
/// `max_frames` are written or `stop` completes (Ctrl-C, say); frames
/// already queued when `stop` completes are still written. Output is
/// flushed whenever no more frames are waiting, so a terminal or pipe sees
/// each burst at once.
///
/// Frames lost because the writer fell behind are not written, only counted
/// and logged.
///
/// To end a replay's dump when the replay is over, let `stop` wait for the
/// bus to go down:
/// `async move { let _ = status.wait_for(|s| s.state == BusState::Down).await; }`
/// with `status = bus.watch_status()`.
pub async fn record_bus<W, S>(
    bus: &Bus,
    iface: &str,
    out: W,
    max_frames: Option<u64>,
    stop: S,
) -> io::Result<RecordSummary>
where
    W: AsyncWrite + Unpin,
    S: Future<Output = ()>,
{
    let mut rx = bus.monitor();
    let mut recorder = Recorder {
        writer: LogWriter::new(BufWriter::new(out), iface),
        summary: RecordSummary::default(),
        max_frames,
        bus: bus.name(),
    };
    tokio::pin!(stop);
    while !recorder.full() {
        let next = tokio::select! {
            // Stop first: a busy bus would otherwise never let it be seen.
            biased;
            () = &mut stop => {
                recorder.drain(&mut rx).await?;
                break;
            }
            next = rx.recv() => next,
        };
        if recorder.take(next).await?.is_break() {
            break;
        }
        recorder.drain(&mut rx).await?;
    }
    recorder.writer.flush().await?;
    Ok(recorder.summary)
}

struct Recorder<'a, W> {
    writer: LogWriter<BufWriter<W>>,
    summary: RecordSummary,
    max_frames: Option<u64>,
    bus: &'a str,
}

impl<W: AsyncWrite + Unpin> Recorder<'_, W> {
    fn full(&self) -> bool {
        self.max_frames
            .is_some_and(|max| self.summary.written >= max)
    }

    /// Handles one receive result; `Break` when the bus is closed.
    async fn take(
        &mut self,
        next: Result<TimedFrame, RecvError>,
    ) -> io::Result<std::ops::ControlFlow<()>> {
        match next {
            Ok(frame) => {
                self.writer.write(&frame).await?;
                self.summary.written += 1;
            }
            Err(RecvError::Lagged(lost)) => {
                self.summary.lost += lost;
                tracing::warn!(bus = self.bus, lost, "log writer fell behind; frames lost");
            }
            Err(RecvError::Closed) => return Ok(std::ops::ControlFlow::Break(())),
        }
        Ok(std::ops::ControlFlow::Continue(()))
    }

    /// Writes what is queued without waiting, then flushes.
    async fn drain(&mut self, rx: &mut super::bus::FrameReceiver) -> io::Result<()> {
        while !self.full() {
            let next = match rx.try_recv() {
                Ok(Some(frame)) => Ok(frame),
                Ok(None) => break,
                Err(err) => Err(err),
            };
            if self.take(next).await?.is_break() {
                break;
            }
        }
        self.writer.flush().await
    }
}

/// How a log is played back.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayOptions {
    /// How much faster than recorded: 1.0 is real time, 2.0 twice as fast,
    /// [`f64::INFINITY`] ([`ReplayOptions::MAX_SPEED`], spelled `max`) as fast
    /// as the readers take the frames.
    pub speed: f64,
    /// Start over when the log ends.
    pub looping: bool,
    /// Only frames logged on this interface.
    pub iface: Option<String>,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self {
            speed: 1.0,
            looping: false,
            iface: None,
        }
    }
}

impl ReplayOptions {
    /// As fast as possible.
    pub const MAX_SPEED: f64 = f64::INFINITY;

    /// The options of a replay spec after its `?`: `&`-separated `speed=N`
    /// (a factor above 0, or `max`), `loop` (or `loop=true|false`) and
    /// `iface=NAME`, e.g. `speed=4&loop&iface=can0`. An empty string gives
    /// the defaults.
    pub fn parse_query(query: &str) -> Result<ReplayOptions, String> {
        let mut options = ReplayOptions::default();
        let mut seen: Vec<&str> = Vec::new();
        for item in query.split('&').filter(|item| !item.is_empty()) {
            let (key, value) = match item.split_once('=') {
                Some((key, value)) => (key, Some(value)),
                None => (item, None),
            };
            if seen.contains(&key) {
                return Err(format!("replay option `{key}` is given twice"));
            }
            seen.push(key);
            match (key, value) {
                ("speed", Some(value)) => options.speed = parse_speed(value)?,
                ("loop", None) => options.looping = true,
                ("loop", Some("true" | "1" | "yes")) => options.looping = true,
                ("loop", Some("false" | "0" | "no")) => options.looping = false,
                ("loop", Some(value)) => {
                    return Err(format!("`loop={value}`: loop takes true or false"));
                }
                ("iface", Some(value)) if !value.is_empty() => {
                    options.iface = Some(value.to_string());
                }
                ("speed" | "iface", _) => {
                    return Err(format!("replay option `{key}` needs a value: `{key}=...`"));
                }
                _ => {
                    return Err(format!(
                        "unknown replay option `{}` (known: speed, loop, iface)",
                        excerpt(key)
                    ));
                }
            }
        }
        Ok(options)
    }
}

fn parse_speed(text: &str) -> Result<f64, String> {
    let speed = if text.eq_ignore_ascii_case("max") {
        ReplayOptions::MAX_SPEED
    } else {
        text.parse::<f64>()
            .map_err(|_| format!("replay speed `{}` is not a number or `max`", excerpt(text)))?
    };
    if valid_speed(speed) {
        Ok(speed)
    } else {
        Err(format!(
            "replay speed must be above 0, not {}",
            excerpt(text)
        ))
    }
}

fn valid_speed(speed: f64) -> bool {
    // NaN fails the comparison too.
    speed > 0.0
}

impl fmt::Display for ReplayOptions {
    /// The query [`parse_query`](Self::parse_query) reads back, naming only
    /// what differs from the defaults (empty when nothing does).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut parts = Vec::new();
        if self.speed.is_infinite() {
            parts.push("speed=max".to_string());
        } else if self.speed != 1.0 {
            parts.push(format!("speed={}", self.speed));
        }
        if self.looping {
            parts.push("loop".to_string());
        }
        if let Some(iface) = &self.iface {
            parts.push(format!("iface={iface}"));
        }
        f.write_str(&parts.join("&"))
    }
}

/// Why a replay could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Log(#[from] LogError),
    #[error("replay speed must be above 0, not {0}")]
    Speed(f64),
    #[error("{}: the log has no frames to replay", .path.display())]
    Empty { path: PathBuf },
    #[error("{}: no frames from interface {iface}; the log has {}", .path.display(), .found.join(", "))]
    NoSuchIface {
        path: PathBuf,
        iface: String,
        found: Vec<String>,
    },
}

/// Waits between checks for a first reader of a new replay.
const SUBSCRIBER_POLL: Duration = Duration::from_millis(1);
/// Used for the pause between loop passes when the log gives no frame gap
/// to copy (a single frame, or all at one time), so a loop never spins.
const MIN_LOOP_GAP_US: u64 = 1_000;

/// Opens a candump `-L` log as a read-only bus that plays it back: frames
/// at their recorded spacing divided by `options.speed`, stamped with the
/// time they are played. The whole log is read first, so a bad line fails
/// here, naming the file and line.
///
/// The bus is named after the file stem, its spec is `replay:PATH` with the
/// options as a `?` query. Sending fails with
/// [`BusError::ReadOnly`](super::bus::BusError::ReadOnly). Playback starts
/// when the first receiver subscribes, so nothing is played before anyone
/// can listen. When looping, each pass starts one average frame gap after
/// the last frame, so a periodic log repeats without a hiccup. At the end
/// (without looping) the status turns [`BusState::Down`], "replay finished".
///
/// At `max` speed frames are held back while the fullest reader is half a
/// receive queue behind, so a reader that keeps reading loses nothing.
/// Must run inside a tokio runtime.
pub async fn open_replay(
    path: impl AsRef<Path>,
    options: ReplayOptions,
) -> Result<Bus, ReplayError> {
    let path = path.as_ref();
    if !valid_speed(options.speed) {
        return Err(ReplayError::Speed(options.speed));
    }
    let bytes = tokio::fs::read(path)
        .await
        .map_err(|source| LogError::Read {
            path: path.to_path_buf(),
            source,
        })?;
    let log = read_log_from(&bytes[..], path)?;
    drop(bytes);
    let schedule = Schedule::new(log, path, options.iface.as_deref())?;

    let name = path
        .file_stem()
        .map(|stem| stem.to_string_lossy().into_owned())
        .filter(|stem| !stem.is_empty())
        .unwrap_or_else(|| "replay".to_string());
    let query = options.to_string();
    let spec = if query.is_empty() {
        format!("replay:{}", path.display())
    } else {
        format!("replay:{}?{query}", path.display())
    };
    let (parts, driver) = driver_channels(&name, &spec, BusKind::Replay, BusStatus::up(), true);
    let task = tokio::spawn(play(schedule, options.speed, options.looping, driver));
    Ok(attach_driver(parts, task))
}

/// The frames of a replay with their offsets from the first, in log
/// microseconds.
struct Schedule {
    frames: Vec<(u64, Frame)>,
    /// From the first frame of one pass to the first of the next.
    period_us: u64,
}

impl Schedule {
    fn new(log: Vec<LoggedFrame>, path: &Path, iface: Option<&str>) -> Result<Self, ReplayError> {
        let mut found: Vec<String> = Vec::new();
        let mut frames = Vec::with_capacity(log.len());
        let mut first = None;
        let mut last_offset = 0;
        for logged in log {
            if let Some(wanted) = iface
                && logged.iface != wanted
            {
                if !found.contains(&logged.iface) {
                    found.push(logged.iface);
                }
                continue;
            }
            let start = *first.get_or_insert(logged.timestamp.as_micros());
            // A log merged from several sources can step back in time; such
            // a frame is played with the one before it, never earlier.
            let offset = logged
                .timestamp
                .as_micros()
                .saturating_sub(start)
                .max(last_offset);
            last_offset = offset;
            frames.push((offset, logged.frame));
        }
        if frames.is_empty() {
            return Err(match iface {
                Some(iface) if !found.is_empty() => ReplayError::NoSuchIface {
                    path: path.to_path_buf(),
                    iface: iface.to_string(),
                    found,
                },
                _ => ReplayError::Empty {
                    path: path.to_path_buf(),
                },
            });
        }
        let gaps = frames.len() as u64 - 1;
        let mean_gap = last_offset.checked_div(gaps).unwrap_or(0);
        Ok(Self {
            frames,
            period_us: last_offset.saturating_add(mean_gap.max(MIN_LOOP_GAP_US)),
        })
    }
}

/// `micros` of log time at `speed`, or `None` when that lies beyond what a
/// clock can hold.
fn scaled(micros: u64, speed: f64) -> Option<Duration> {
    Duration::try_from_secs_f64(micros as f64 / 1e6 / speed).ok()
}

async fn play(schedule: Schedule, speed: f64, looping: bool, driver: DriverSide) {
    // Opening and subscribing are two steps; without this wait the first
    // frames would be played to nobody.
    while driver.receivers() == 0 {
        tokio::time::sleep(SUBSCRIBER_POLL).await;
    }
    let max_speed = speed.is_infinite();
    let mut pass_start = Instant::now();
    let mut pass_wall = Timestamp::now();
    loop {
        for &(offset, frame) in &schedule.frames {
            let timestamp = if max_speed {
                make_room(&driver).await;
                Timestamp::now()
            } else {
                let due = scaled(offset, speed);
                // A frame due past the end of time is never played.
                match due.and_then(|due| pass_start.checked_add(due)) {
                    Some(deadline) => tokio::time::sleep_until(deadline).await,
                    None => std::future::pending::<()>().await,
                }
                let due_us = due.map_or(u64::MAX, |d| {
                    u64::try_from(d.as_micros()).unwrap_or(u64::MAX)
                });
                Timestamp::from_micros(pass_wall.as_micros().saturating_add(due_us))
            };
            driver.received(frame, timestamp);
        }
        if !looping {
            break;
        }
        if !max_speed {
            let period = scaled(schedule.period_us, speed);
            match period.and_then(|period| pass_start.checked_add(period)) {
                Some(next) => pass_start = next,
                None => std::future::pending::<()>().await,
            }
            let period_us = period.map_or(u64::MAX, |d| {
                u64::try_from(d.as_micros()).unwrap_or(u64::MAX)
            });
            pass_wall = Timestamp::from_micros(pass_wall.as_micros().saturating_add(period_us));
        }
    }
    driver.set_status(BusStatus::new(BusState::Down, "replay finished"));
}

/// Holds a max-speed replay back while its readers are half a queue behind,
/// and lets other tasks run between frames.
async fn make_room(driver: &DriverSide) {
    while driver.backlog() >= DEFAULT_RX_QUEUE / 2 {
        tokio::time::sleep(SUBSCRIBER_POLL).await;
    }
    tokio::task::coop::consume_budget().await;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::bus::BusError;
    use crate::can::frame::{CanId, Direction, FdFlags};
    use crate::can::hub::VirtualHub;

    fn std_id(raw: u32) -> CanId {
        CanId::standard(raw).unwrap()
    }

    fn data(id: u32, bytes: &[u8]) -> Frame {
        Frame::new(std_id(id), bytes).unwrap()
    }

    fn timed(frame: Frame, micros: u64) -> TimedFrame {
        TimedFrame {
            frame,
            timestamp: Timestamp::from_micros(micros),
            direction: Direction::Rx,
        }
    }

    /// A log file in the temporary directory, removed when dropped.
    struct TempLog(PathBuf);

    impl TempLog {
        fn new(name: &str, contents: &[u8]) -> Self {
            let dir = std::env::temp_dir().join(format!("candeck-candump-{}", std::process::id()));
            std::fs::create_dir_all(&dir).unwrap();
            let path = dir.join(name);
            std::fs::write(&path, contents).unwrap();
            Self(path)
        }
    }

    impl Drop for TempLog {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }

    fn every_kind() -> Vec<Frame> {
        let fd_data: Vec<u8> = (0..64).collect();
        vec![
            data(0x123, &[0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88]),
            data(0x000, &[]),
            data(0x7FF, &[0xFF]),
            Frame::new(CanId::Extended(0x1FFF_FFFF), &[1, 2]).unwrap(),
            Frame::new(CanId::Extended(0x123), &[]).unwrap(),
            Frame::remote(std_id(0x701), 0).unwrap(),
            Frame::remote(CanId::Extended(0x1ABCDE), 8).unwrap(),
            Frame::fd(std_id(0x10), &[0xAA, 0xBB], FdFlags::default()).unwrap(),
            Frame::fd(
                CanId::Extended(0x1234),
                &fd_data,
                FdFlags {
                    brs: true,
                    esi: true,
                },
            )
            .unwrap(),
            Frame::fd(
                std_id(0x11),
                &[0x5A; 12],
                FdFlags {
                    brs: true,
                    esi: false,
                },
            )
            .unwrap(),
            Frame::error(0x004, [0, 0x0C, 0, 0, 0, 0, 0, 0]).unwrap(),
            Frame::error(0x040, [0; 8]).unwrap(),
        ]
    }

    async fn written(iface: &str, frames: &[TimedFrame]) -> String {
        let mut writer = LogWriter::new(Vec::new(), iface);
        for frame in frames {
            writer.write(frame).await.unwrap();
        }
        writer.flush().await.unwrap();
        String::from_utf8(writer.into_inner()).unwrap()
    }

    #[tokio::test]
    async fn writes_frames_in_candump_spelling() {
        let frames: Vec<TimedFrame> = every_kind()
            .into_iter()
            .enumerate()
            .map(|(i, frame)| timed(frame, 1_436_509_052_249_713 + i as u64))
            .collect();
        let text = written("can0", &frames).await;
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[..8],
            [
                "(1436509052.249713) can0 123#1122334455667788",
                "(1436509052.249714) can0 000#",
                "(1436509052.249715) can0 7FF#FF",
                "(1436509052.249716) can0 1FFFFFFF#0102",
                "(1436509052.249717) can0 00000123#",
                "(1436509052.249718) can0 701#R",
                "(1436509052.249719) can0 001ABCDE#R8",
                // candump shows CANFD_FDF (0x4) in the flags digit.
                "(1436509052.249720) can0 010##4AABB",
            ]
        );
        assert!(lines[8].starts_with("(1436509052.249721) can0 00001234##7000102"));
        assert_eq!(
            lines[9],
            format!("(1436509052.249722) can0 011##5{}", "5A".repeat(12))
        );
        assert_eq!(
            lines[10],
            "(1436509052.249723) can0 20000004#000C000000000000"
        );
        assert_eq!(
            lines[11],
            "(1436509052.249724) can0 20000040#0000000000000000"
        );
        assert!(text.ends_with('\n'));
        assert_eq!(lines.len(), 12);
    }

    #[tokio::test]
    async fn interface_names_with_white_space_stay_readable() {
        let text = written("my bus", &[timed(data(1, &[]), 0)]).await;
        assert_eq!(text, "(0.000000) my_bus 001#\n");
        let text = written("", &[timed(data(1, &[]), 0)]).await;
        assert_eq!(text, "(0.000000) can 001#\n");
    }

    #[tokio::test]
    async fn every_frame_kind_survives_a_write_and_read_round_trip() {
        let frames: Vec<TimedFrame> = every_kind()
            .into_iter()
            .enumerate()
            .map(|(i, frame)| timed(frame, 1_000_000 * i as u64 + 999_999))
            .collect();
        let text = written("vcan0", &frames).await;
        let read = read_log_from(text.as_bytes(), Path::new("round.log")).unwrap();
        assert_eq!(read.len(), frames.len());
        for (logged, original) in read.iter().zip(&frames) {
            assert_eq!(logged.frame, original.frame);
            assert_eq!(logged.timestamp, original.timestamp);
            assert_eq!(logged.iface, "vcan0");
        }
        // And a line prints back as it was read.
        let line = read[8].to_string();
        assert_eq!(
            format!("{line}\n"),
            text.lines().nth(8).unwrap().to_string() + "\n"
        );
    }

    #[test]
    fn reads_candump_logs_skipping_blank_lines() {
        let text = "\n(1436509052.249713) can0 123#1122334455667788\r\n   \n\
                    (1436509052.250000) can1 00000123#R4 T\n\
                    (1436509053.000001) can0 701#7F";
        let read = read_log_from(text.as_bytes(), Path::new("x.log")).unwrap();
        assert_eq!(
            read,
            vec![
                LoggedFrame {
                    timestamp: Timestamp::from_micros(1_436_509_052_249_713),
                    iface: "can0".into(),
                    frame: data(0x123, &[0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88]),
                },
                LoggedFrame {
                    timestamp: Timestamp::from_micros(1_436_509_052_250_000),
                    iface: "can1".into(),
                    frame: Frame::remote(CanId::Extended(0x123), 4).unwrap(),
                },
                LoggedFrame {
                    timestamp: Timestamp::from_micros(1_436_509_053_000_001),
                    iface: "can0".into(),
                    frame: data(0x701, &[0x7F]),
                },
            ]
        );
    }

    #[test]
    fn empty_logs_read_as_no_frames() {
        for text in ["", "\n", "  \n\r\n\n"] {
            assert_eq!(
                read_log_from(text.as_bytes(), Path::new("e.log")).unwrap(),
                vec![]
            );
        }
        let file = TempLog::new("empty.log", b"");
        assert_eq!(read_log(&file.0).unwrap(), vec![]);
    }

    fn problem_with(line: &[u8]) -> String {
        let mut text = b"(1.000000) can0 123#00\n\n".to_vec();
        text.extend_from_slice(line);
        text.extend_from_slice(b"\n(2.000000) can0 123#00\n");
        let err = read_log_from(&text[..], Path::new("logs/bad.log")).unwrap_err();
        let message = err.to_string();
        let LogError::Line {
            line,
            path,
            problem,
        } = err
        else {
            panic!("expected a line error, got {message}");
        };
        assert_eq!((line, path.as_path()), (3, Path::new("logs/bad.log")));
        assert!(message.starts_with("logs/bad.log:3: "), "{message}");
        problem
    }

    #[test]
    fn malformed_lines_name_the_file_the_line_and_the_problem() {
        let cases: &[(&[u8], &str)] = &[
            (
                b"(1436509052.24971) can0 123#00",
                "timestamp `(1436509052.24971)` is not `(SECONDS.MICROSECONDS)`",
            ),
            (b"(abc.000000) can0 123#00", "timestamp `(abc.000000)`"),
            (
                b"1436509052.249713 can0 123#00",
                "timestamp `1436509052.249713`",
            ),
            (
                b"(1.000000) can0 1234#00",
                "identifier `1234` has 4 hex digits; candump writes 3 (standard) or 8 (extended)",
            ),
            (b"(1.000000) can0 12#00", "identifier `12` has 2 hex digits"),
            (
                b"(1.000000) can0 800#00",
                "standard identifier 0x800 is above 0x7FF",
            ),
            (
                b"(1.000000) can0 20000004#000C00000000000000",
                "an error frame carries at most 8 data bytes, not 9",
            ),
            (
                b"(1.000000) can0 123#112233445566778899",
                "a classic CAN frame carries at most 8 data bytes, not 9",
            ),
            (
                b"(1.000000) can0 123#R9",
                "a remote frame requests at most 8 bytes, not 9",
            ),
            (
                b"(1.000000) can0 123#RX",
                "remote frame length `X` is not one hex digit",
            ),
            (
                b"(1.000000) can0 123#112",
                "data `112` has an odd number of hex digits",
            ),
            (b"(1.000000) can0 123#GG", "data `GG` is not hexadecimal"),
            (
                b"(1.000000) can0 XYZ#00",
                "identifier `XYZ` is not hexadecimal",
            ),
            (
                b"(1.000000) can0 12300",
                "frame `12300` has no `#` between identifier and data",
            ),
            (
                b"(1.000000) can0 123#1122334455667788_E",
                "the `_DLC` suffix",
            ),
            (
                b"(1.000000) can0 123##",
                "CAN FD frame `123##` lacks the flags digit after `##`",
            ),
            (b"(1.000000) can0", "line ends early"),
            (b"hello world", "timestamp `hello`"),
            (
                b"(1.000000) can0 123#00 X",
                "`X` after the frame is not a direction (`R` or `T`)",
            ),
            (b"(1.000000) can0 123#\xff\xfe", "line is not UTF-8 text"),
        ];
        for (line, expected) in cases {
            let problem = problem_with(line);
            assert!(
                problem.contains(expected),
                "{:?}: {problem:?} lacks {expected:?}",
                String::from_utf8_lossy(line)
            );
        }
        let fd_too_long = format!("(1.000000) can0 123##1{}", "00".repeat(65));
        assert_eq!(
            problem_with(fd_too_long.as_bytes()),
            "a CAN FD frame carries at most 64 data bytes, not 65"
        );
    }

    #[test]
    fn overlong_lines_are_refused_without_reading_them_whole() {
        let long = vec![b'A'; MAX_LINE + 10];
        assert_eq!(problem_with(&long), "line is longer than 64 KiB");
        // Exactly at the limit is read, and found wanting on its own terms.
        let mut at_limit = b"(1.000000) can0 123#".to_vec();
        at_limit.resize(MAX_LINE, b'0');
        assert!(problem_with(&at_limit).contains("classic CAN frame carries at most 8"));
    }

    #[test]
    fn garbage_never_panics() {
        let inputs: &[&[u8]] = &[
            b"(",
            b")",
            b"()",
            b"(.)",
            b"(1.)",
            b"(.000000)",
            b"(99999999999999999999.000000) a 1#",
            b"(1.000000) a #",
            b"(1.000000) a ##",
            b"(1.000000) a ###",
            b"(1.000000) a 123#R",
            b"(1.000000) a \xc3\xa9#00",
            b"\0\0\0",
            b"(1.000000)  can0 123#00",
            b"\t",
            b"(1.000000) a 20000000#",
            b"(1.000000) a 20000000#R",
            b"(1.000000) a 20000000##0",
        ];
        for input in inputs {
            let _ = read_log_from(*input, Path::new("g.log"));
        }
        // Every single byte value on its own line.
        let all: Vec<u8> = (0..=255u8).flat_map(|b| [b, b'\n']).collect();
        let _ = read_log_from(&all[..], Path::new("g.log"));
    }

    #[test]
    fn a_missing_file_is_named() {
        let err = read_log("/nonexistent/candeck/missing.log").unwrap_err();
        assert!(matches!(err, LogError::Read { .. }));
        assert!(
            err.to_string()
                .starts_with("cannot read /nonexistent/candeck/missing.log: "),
            "{err}"
        );
    }

    async fn wait_for_receiver(hub: &VirtualHub) {
        while hub.receivers() == 0 {
            tokio::task::yield_now().await;
        }
    }

    #[tokio::test]
    async fn record_bus_writes_what_the_monitor_sees_and_counts_losses() {
        let hub = VirtualHub::with_queue("line", 4);
        let recorded = hub.attach();
        let other = hub.attach();
        let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn({
            let recorded = recorded.clone();
            async move {
                let mut out = Vec::new();
                let stop = async move {
                    let _ = stop_rx.await;
                };
                let summary = record_bus(&recorded, "can0", &mut out, None, stop)
                    .await
                    .unwrap();
                (summary, String::from_utf8(out).unwrap())
            }
        });
        wait_for_receiver(&hub).await;
        // Ten frames before the recorder runs again: it can only keep four.
        for i in 0..10 {
            other.send(data(0x100 + i, &[i as u8])).await.unwrap();
        }
        recorded.send(data(0x7FF, &[])).await.unwrap();
        tokio::task::yield_now().await;
        stop_tx.send(()).unwrap();
        let (summary, text) = task.await.unwrap();
        assert_eq!(
            summary,
            RecordSummary {
                written: 4,
                lost: 7
            }
        );
        let bodies: Vec<&str> = text.lines().map(|l| field(l, 2)).collect();
        assert_eq!(bodies, ["107#07", "108#08", "109#09", "7FF#"]);
        assert!(text.lines().all(|l| field(l, 1) == "can0"));
        assert_eq!(recorded.counters().rx_overruns, 7);
    }

    #[tokio::test]
    async fn record_bus_stops_after_max_frames() {
        let hub = VirtualHub::new("line");
        let recorded = hub.attach();
        let other = hub.attach();
        let task = tokio::spawn({
            let recorded = recorded.clone();
            async move {
                let mut out = Vec::new();
                let summary = record_bus(&recorded, "x", &mut out, Some(3), std::future::pending())
                    .await
                    .unwrap();
                (summary, out)
            }
        });
        wait_for_receiver(&hub).await;
        for i in 0..5 {
            other.send(data(i, &[])).await.unwrap();
        }
        let (summary, out) = task.await.unwrap();
        assert_eq!(
            summary,
            RecordSummary {
                written: 3,
                lost: 0
            }
        );
        assert_eq!(String::from_utf8(out).unwrap().lines().count(), 3);
    }

    #[test]
    fn replay_query_reads_speed_loop_and_iface() {
        assert_eq!(ReplayOptions::parse_query(""), Ok(ReplayOptions::default()));
        assert_eq!(
            ReplayOptions::parse_query("speed=4&loop&iface=can0"),
            Ok(ReplayOptions {
                speed: 4.0,
                looping: true,
                iface: Some("can0".into())
            })
        );
        let max = ReplayOptions::parse_query("speed=max").unwrap();
        assert_eq!(max.speed, f64::INFINITY);
        assert_eq!(
            ReplayOptions::parse_query("speed=MAX").unwrap().speed,
            f64::INFINITY
        );
        assert_eq!(
            ReplayOptions::parse_query("speed=0.25").unwrap().speed,
            0.25
        );
        assert!(ReplayOptions::parse_query("loop=true").unwrap().looping);
        assert!(!ReplayOptions::parse_query("loop=false").unwrap().looping);
        // Stray separators are harmless.
        assert!(ReplayOptions::parse_query("&loop&").unwrap().looping);
    }

    #[test]
    fn replay_query_refuses_what_it_does_not_understand() {
        let cases = [
            ("speed=0", "replay speed must be above 0, not 0"),
            ("speed=-2", "replay speed must be above 0, not -2"),
            ("speed=NaN", "replay speed must be above 0, not NaN"),
            ("speed=fast", "replay speed `fast` is not a number or `max`"),
            ("speed", "replay option `speed` needs a value: `speed=...`"),
            ("iface=", "replay option `iface` needs a value: `iface=...`"),
            ("loop=maybe", "`loop=maybe`: loop takes true or false"),
            ("speed=2&speed=3", "replay option `speed` is given twice"),
            (
                "rate=2",
                "unknown replay option `rate` (known: speed, loop, iface)",
            ),
        ];
        for (query, message) in cases {
            assert_eq!(
                ReplayOptions::parse_query(query),
                Err(message.to_string()),
                "{query}"
            );
        }
    }

    #[test]
    fn replay_options_print_as_the_query_they_come_from() {
        for query in [
            "",
            "speed=4",
            "speed=0.5&loop",
            "speed=max&iface=can1",
            "loop&iface=vcan0",
        ] {
            let options = ReplayOptions::parse_query(query).unwrap();
            assert_eq!(options.to_string(), query);
        }
    }

    const TIMED_LOG: &str = "(1000.000000) can0 100#01\n\
                             (1000.100000) can1 200#02\n\
                             (1000.350000) can0 300#03\n";

    /// Receives `count` frames, each with the paused-clock time it came at,
    /// counted from `start`.
    async fn receive(bus: &Bus, count: usize) -> Vec<(u64, TimedFrame)> {
        let start = Instant::now();
        let mut rx = bus.subscribe();
        let mut got = Vec::new();
        for _ in 0..count {
            let frame = rx.recv().await.unwrap();
            got.push((start.elapsed().as_micros() as u64, frame));
        }
        got
    }

    fn ids(got: &[(u64, TimedFrame)]) -> Vec<(u64, u32)> {
        got.iter()
            .map(|(at, f)| (*at, f.frame.id().raw()))
            .collect()
    }

    #[tokio::test(start_paused = true)]
    async fn replay_plays_frames_at_their_recorded_times() {
        let log = TempLog::new("timed.log", TIMED_LOG.as_bytes());
        let bus = open_replay(&log.0, ReplayOptions::default()).await.unwrap();
        let got = receive(&bus, 3).await;
        assert_eq!(ids(&got), [(0, 0x100), (100_000, 0x200), (350_000, 0x300)]);
        // Stamped with play time, spaced as recorded.
        let stamps: Vec<u64> = got.iter().map(|(_, f)| f.timestamp.as_micros()).collect();
        assert_eq!(stamps[1] - stamps[0], 100_000);
        assert_eq!(stamps[2] - stamps[0], 350_000);
        assert!(got.iter().all(|(_, f)| f.direction == Direction::Rx));
    }

    #[tokio::test(start_paused = true)]
    async fn replay_speed_scales_the_time_between_frames() {
        let log = TempLog::new("scaled.log", TIMED_LOG.as_bytes());
        let options = ReplayOptions::parse_query("speed=2").unwrap();
        let bus = open_replay(&log.0, options).await.unwrap();
        assert_eq!(
            ids(&receive(&bus, 3).await),
            [(0, 0x100), (50_000, 0x200), (175_000, 0x300)]
        );

        let options = ReplayOptions::parse_query("speed=0.5").unwrap();
        let bus = open_replay(&log.0, options).await.unwrap();
        assert_eq!(
            ids(&receive(&bus, 3).await),
            [(0, 0x100), (200_000, 0x200), (700_000, 0x300)]
        );
    }

    #[tokio::test(start_paused = true)]
    async fn replay_at_max_speed_does_not_wait() {
        let log = TempLog::new("max.log", TIMED_LOG.as_bytes());
        let options = ReplayOptions {
            speed: ReplayOptions::MAX_SPEED,
            ..ReplayOptions::default()
        };
        let bus = open_replay(&log.0, options).await.unwrap();
        assert_eq!(
            ids(&receive(&bus, 3).await),
            [(0, 0x100), (0, 0x200), (0, 0x300)]
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_max_speed_replay_waits_for_a_reader_that_keeps_reading() {
        let mut text = String::new();
        let total = DEFAULT_RX_QUEUE * 3;
        for i in 0..total {
            text.push_str(&format!(
                "(1.{:06}) can0 123#{:02X}\n",
                i % 1_000_000,
                i % 256
            ));
        }
        let log = TempLog::new("many.log", text.as_bytes());
        let bus = open_replay(&log.0, ReplayOptions::parse_query("speed=max").unwrap())
            .await
            .unwrap();
        let mut rx = bus.subscribe();
        for i in 0..total {
            let frame = rx.recv().await.unwrap();
            assert_eq!(frame.frame.data(), [(i % 256) as u8]);
            if i % 1000 == 0 {
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
        }
        assert_eq!(bus.counters().rx_overruns, 0);
    }

    #[tokio::test(start_paused = true)]
    async fn a_looping_replay_starts_over_one_average_gap_after_the_end() {
        let log = TempLog::new("loop.log", TIMED_LOG.as_bytes());
        let bus = open_replay(&log.0, ReplayOptions::parse_query("loop").unwrap())
            .await
            .unwrap();
        let got = receive(&bus, 7).await;
        // 350 ms over two gaps: the next pass starts 175 ms after the last frame.
        assert_eq!(
            ids(&got),
            [
                (0, 0x100),
                (100_000, 0x200),
                (350_000, 0x300),
                (525_000, 0x100),
                (625_000, 0x200),
                (875_000, 0x300),
                (1_050_000, 0x100),
            ]
        );
        let stamps: Vec<u64> = got.iter().map(|(_, f)| f.timestamp.as_micros()).collect();
        assert_eq!(stamps[6] - stamps[0], 1_050_000);
        assert_eq!(bus.state(), BusState::Up);
    }

    #[tokio::test(start_paused = true)]
    async fn a_looping_single_frame_log_does_not_spin() {
        let log = TempLog::new("single.log", b"(5.000000) can0 001#\n");
        let options = ReplayOptions::parse_query("loop").unwrap();
        let bus = open_replay(&log.0, options).await.unwrap();
        let got = receive(&bus, 3).await;
        assert_eq!(ids(&got), [(0, 1), (1_000, 1), (2_000, 1)]);
    }

    #[tokio::test(start_paused = true)]
    async fn an_interface_filter_plays_only_that_interface() {
        let log = TempLog::new("filter.log", TIMED_LOG.as_bytes());
        let options = ReplayOptions::parse_query("iface=can1").unwrap();
        let bus = open_replay(&log.0, options).await.unwrap();
        // The log's time starts at the first frame played.
        assert_eq!(ids(&receive(&bus, 1).await), [(0, 0x200)]);
        let mut status = bus.watch_status();
        status
            .wait_for(|s| s.state == BusState::Down)
            .await
            .unwrap();

        let options = ReplayOptions::parse_query("iface=can0").unwrap();
        let bus = open_replay(&log.0, options).await.unwrap();
        assert_eq!(ids(&receive(&bus, 2).await), [(0, 0x100), (350_000, 0x300)]);
    }

    #[tokio::test(start_paused = true)]
    async fn a_finished_replay_goes_down() {
        let log = TempLog::new("finish.log", TIMED_LOG.as_bytes());
        let bus = open_replay(&log.0, ReplayOptions::default()).await.unwrap();
        assert_eq!(bus.status(), BusStatus::up());
        let start = Instant::now();
        let mut rx = bus.subscribe();
        let mut status = bus.watch_status();
        status
            .wait_for(|s| s.state == BusState::Down)
            .await
            .unwrap();
        assert_eq!(start.elapsed(), Duration::from_millis(350));
        assert_eq!(
            bus.status(),
            BusStatus::new(BusState::Down, "replay finished")
        );
        // Every frame is still there to read.
        for id in [0x100, 0x200, 0x300] {
            assert_eq!(rx.recv().await.unwrap().frame.id().raw(), id);
        }
        assert_eq!(bus.counters().rx_frames, 3);
    }

    #[tokio::test(start_paused = true)]
    async fn playback_waits_for_its_first_reader() {
        let log = TempLog::new("late.log", TIMED_LOG.as_bytes());
        let bus = open_replay(&log.0, ReplayOptions::default()).await.unwrap();
        tokio::time::sleep(Duration::from_secs(10)).await;
        assert_eq!(ids(&receive(&bus, 2).await), [(0, 0x100), (100_000, 0x200)]);
    }

    #[tokio::test(start_paused = true)]
    async fn a_replay_is_read_only_and_named_after_its_file() {
        let log = TempLog::new("bench-run.log", TIMED_LOG.as_bytes());
        let options = ReplayOptions::parse_query("speed=4&loop").unwrap();
        let bus = open_replay(&log.0, options).await.unwrap();
        assert_eq!(bus.name(), "bench-run");
        assert_eq!(bus.kind(), BusKind::Replay);
        assert_eq!(
            bus.spec(),
            format!("replay:{}?speed=4&loop", log.0.display())
        );
        assert_eq!(
            bus.send(data(1, &[])).await,
            Err(BusError::ReadOnly("bench-run".into()))
        );
        assert_eq!(
            bus.try_send(data(1, &[])),
            Err(BusError::ReadOnly("bench-run".into()))
        );
        let plain = open_replay(&log.0, ReplayOptions::default()).await.unwrap();
        assert_eq!(plain.spec(), format!("replay:{}", log.0.display()));
    }

    #[tokio::test]
    async fn opening_a_bad_replay_names_the_file_and_line() {
        let log = TempLog::new("broken.log", b"(1.000000) can0 123#00\n(1.5) can0 123#00\n");
        let err = open_replay(&log.0, ReplayOptions::default())
            .await
            .unwrap_err();
        assert!(matches!(
            err,
            ReplayError::Log(LogError::Line { line: 2, .. })
        ));
        assert!(
            err.to_string()
                .starts_with(&format!("{}:2: timestamp `(1.5)`", log.0.display())),
            "{err}"
        );

        let missing = open_replay("/nonexistent/x.log", ReplayOptions::default())
            .await
            .unwrap_err();
        assert!(
            missing
                .to_string()
                .starts_with("cannot read /nonexistent/x.log: "),
            "{missing}"
        );

        let empty = TempLog::new("nothing.log", b"\n\n");
        let err = open_replay(&empty.0, ReplayOptions::default())
            .await
            .unwrap_err();
        assert_eq!(
            err.to_string(),
            format!("{}: the log has no frames to replay", empty.0.display())
        );

        let log = TempLog::new("ifaces.log", TIMED_LOG.as_bytes());
        let options = ReplayOptions::parse_query("iface=can7").unwrap();
        let err = open_replay(&log.0, options).await.unwrap_err();
        assert_eq!(
            err.to_string(),
            format!(
                "{}: no frames from interface can7; the log has can0, can1",
                log.0.display()
            )
        );

        for speed in [0.0, -1.0, f64::NAN, f64::NEG_INFINITY] {
            let options = ReplayOptions {
                speed,
                ..ReplayOptions::default()
            };
            let err = open_replay(&log.0, options).await.unwrap_err();
            assert!(matches!(err, ReplayError::Speed(_)), "{speed}");
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_replayed_log_records_back_to_the_same_frames() {
        let log = TempLog::new("again.log", TIMED_LOG.as_bytes());
        let bus = open_replay(&log.0, ReplayOptions::default()).await.unwrap();
        let mut status = bus.watch_status();
        let stop = async move {
            let _ = status.wait_for(|s| s.state == BusState::Down).await;
        };
        let mut out = Vec::new();
        let summary = record_bus(&bus, "can0", &mut out, None, stop)
            .await
            .unwrap();
        assert_eq!(
            summary,
            RecordSummary {
                written: 3,
                lost: 0
            }
        );
        let read = read_log_from(&out[..], Path::new("out.log")).unwrap();
        let frames: Vec<Frame> = read.iter().map(|l| l.frame).collect();
        assert_eq!(
            frames,
            [data(0x100, &[1]), data(0x200, &[2]), data(0x300, &[3])]
        );
    }
}
