//! A log played back as a read-only bus.

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::time::Instant;

use crate::bus::{
    Bus, BusKind, BusState, BusStatus, DEFAULT_RX_QUEUE, DriverSide, attach_driver, driver_channels,
};
use crate::frame::{Frame, Timestamp};

use super::format::*;

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

pub(super) fn parse_speed(text: &str) -> Result<f64, String> {
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

pub(super) fn valid_speed(speed: f64) -> bool {
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
pub(super) const SUBSCRIBER_POLL: Duration = Duration::from_millis(1);
/// Used for the pause between loop passes when the log gives no frame gap
/// to copy (a single frame, or all at one time), so a loop never spins.
pub(super) const MIN_LOOP_GAP_US: u64 = 1_000;

/// Opens a candump `-L` log as a read-only bus that plays it back: frames
/// at their recorded spacing divided by `options.speed`, stamped with the
/// time they are played. The whole log is read first, so a bad line fails
/// here, naming the file and line.
///
/// The bus is named after the file stem, its spec is `replay:PATH` with the
/// options as a `?` query. Sending fails with
/// [`BusError::ReadOnly`](crate::bus::BusError::ReadOnly). Playback starts
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
pub(super) struct Schedule {
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
pub(super) fn scaled(micros: u64, speed: f64) -> Option<Duration> {
    Duration::try_from_secs_f64(micros as f64 / 1e6 / speed).ok()
}

pub(super) async fn play(schedule: Schedule, speed: f64, looping: bool, driver: DriverSide) {
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
pub(super) async fn make_room(driver: &DriverSide) {
    while driver.backlog() >= DEFAULT_RX_QUEUE / 2 {
        tokio::time::sleep(SUBSCRIBER_POLL).await;
    }
    tokio::task::coop::consume_budget().await;
}
