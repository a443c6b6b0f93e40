//! The data logger: any objects of any nodes (up to [`MAX_CHANNELS`]),
//! sampled together at a period for a duration, kept in memory within a
//! bound and, with `--data-dir DIR`, in `DIR/loggers/` once done
//! (`docs/data-logger.md`; `POST|GET|DELETE /loggers`, the `loggers/{id}`
//! stream topic).
//!
//! Where each sample comes from, per channel and per sample:
//!
//! - from a TPDO, when the node's TPDOs carry the object
//!   ([`TpdoValues`](super::values::TpdoValues)) and its value came within
//!   [`TPDO_FRESH`]: the newest value at the sample time, no bus traffic;
//! - otherwise by an SDO upload through the node's
//!   [`SdoChannel`](super::sdo::SdoChannel). Each upload takes the node's
//!   queue on its own, first come first served, so every other user of the
//!   node (a REST read, the axis telemetry, a PDO re-mapping) gets its turn
//!   between two of the logger's uploads; the channels of one node are read
//!   one after another, different nodes at the same time. A node the
//!   registry knows to be offline or stopped is not asked.
//!
//! Sample times are on a fixed grid (`period_ms` from the start). A round
//! of reads that ends after the next grid point but one skips the points it
//! overran, each counted in `missed`, rather than catching up with a
//! burst: the logger never asks a node faster than its period. A failed
//! read leaves its cell empty and is counted per channel with the last
//! error; it never stops the logger.
//!
//! Memory: a logger keeps at most `logger_max_values` values (rows ×
//! channels; [`DEFAULT_MAX_VALUES`]); beyond that the oldest rows go,
//! counted in `dropped`. At most [`MAX_LOGGERS`] loggers are kept: a new
//! one replaces the oldest finished one, and is refused when all of them
//! still run.

use std::collections::VecDeque;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use serde_json::{Value as Json, json};
use tokio::sync::watch;
use tokio::time::Instant;

use super::audit::{AuditTarget, spawn_audited};
use super::axis_telemetry::TPDO_FRESH;
use super::caller::Caller;
use super::drive::{AxisUnits, DriveKind, axis_count};
use super::policy::Operation;
use super::producers::unreachable;
use super::recording::civil_from_days;
use super::service::{Gateway, ServedBus};
use super::telemetry::{TopicReceiver, ValueTopic, unix_ms};
use super::{GatewayError, files};
use crate::canopen::NodeId;
use crate::canopen::od::{DataType, DictionaryError, Value, format_index, parse_index};

/// The most channels one logger samples.
pub(crate) const MAX_CHANNELS: usize = 16;
/// The shortest period a logger may ask for, in milliseconds.
pub(crate) const MIN_PERIOD_MS: u64 = 1;
/// The longest period, in milliseconds (a minute).
pub(crate) const MAX_PERIOD_MS: u64 = 60_000;
/// The longest a logger runs, in seconds (a day).
pub(crate) const MAX_DURATION_S: u64 = 86_400;
/// The loggers kept at once, running and finished.
pub(crate) const MAX_LOGGERS: usize = 16;
/// The default of `logger_max_values`: values (rows × channels) one logger
/// keeps in memory; 16 channels at 1 kHz for a minute, about 8 MB of
/// `f64`s.
pub const DEFAULT_MAX_VALUES: usize = 1_000_000;
/// How often a running logger publishes its new rows on its stream topic.
pub(crate) const PUBLISH_EVERY: Duration = Duration::from_millis(100);

/// Why a logger could not be made, read or removed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LoggerError {
    #[error("a logger takes 1 to {MAX_CHANNELS} channels, not {0}")]
    ChannelCount(usize),
    #[error("period_ms {0}: a logger samples every {MIN_PERIOD_MS} to {MAX_PERIOD_MS} ms")]
    Period(u64),
    #[error("duration_s {0}: a logger runs 1 to {MAX_DURATION_S} s")]
    Duration(u64),
    #[error("channel {channel}: {message}")]
    Channel { channel: usize, message: String },
    /// The object exists but cannot be logged: write-only, or no number.
    #[error("channel {channel}: {message}")]
    NotLoggable { channel: usize, message: String },
    /// A name or sub-index the node's dictionary does not have.
    #[error("channel {channel}: {source}")]
    Dictionary {
        channel: usize,
        source: DictionaryError,
    },
    /// The bus or node is not known, or the trial read of an object the
    /// EDS does not describe failed.
    #[error("channel {channel}: {source}")]
    Gateway {
        channel: usize,
        source: GatewayError,
    },
    #[error("{MAX_LOGGERS} loggers run already: delete one first")]
    TooMany,
    #[error("no logger has the id '{0}'")]
    Unknown(String),
}

/// One channel as a request names it: the object by number
/// (`"0x6064"`, `24676`) or by EDS name, the sub-index by number or name
/// (0 when not given).
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelRequest {
    pub bus: String,
    pub node: u8,
    /// `0x6064`, `6064h`, a decimal number, or the EDS name.
    pub index: Json,
    /// A number or the sub-object's EDS name; 0 when not given.
    #[serde(default)]
    pub sub: Option<Json>,
}

/// What a logger is asked for.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct LoggerRequest {
    /// 1 to 16 channels.
    pub channels: Vec<ChannelRequest>,
    /// 1 to 60000.
    pub period_ms: u64,
    /// 1 to 86400.
    pub duration_s: u64,
}

impl LoggerRequest {
    /// The checks that need no bus.
    fn check(&self) -> Result<(), LoggerError> {
        if self.channels.is_empty() || self.channels.len() > MAX_CHANNELS {
            return Err(LoggerError::ChannelCount(self.channels.len()));
        }
        if !(MIN_PERIOD_MS..=MAX_PERIOD_MS).contains(&self.period_ms) {
            return Err(LoggerError::Period(self.period_ms));
        }
        if !(1..=MAX_DURATION_S).contains(&self.duration_s) {
            return Err(LoggerError::Duration(self.duration_s));
        }
        Ok(())
    }
}

/// Where a channel's samples came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    Sdo,
    Tpdo,
}

/// A channel, resolved against its node's dictionary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChannelInfo {
    pub bus: String,
    pub node: u8,
    /// `0x6064`.
    pub index: String,
    pub sub: u8,
    /// The CSV column: `bus/node/EDS name` (`demo/1/a1_pc_Position_actual_value`),
    /// `bus/node/0x2000:1` for an object the EDS does not describe.
    pub name: String,
    /// The EDS type (`i32`, ...); null when the EDS does not describe it
    /// (the bytes are then read as an unsigned little-endian number).
    pub data_type: Option<String>,
    /// The unit of its raw values where candeck knows it (a drive's CiA
    /// 402 positions, velocities, accelerations and torques, as the
    /// product's manual names them: `increments`, `0.1 rps`); the CSV's
    /// header gives it as `name [unit]`. Null elsewhere.
    #[serde(default)]
    pub unit: Option<String>,
    /// Where its last sample came from; null before the first.
    pub source: Option<Source>,
    pub sdo_samples: u64,
    pub tpdo_samples: u64,
    /// Samples that failed (an empty cell each).
    pub errors: u64,
    pub last_error: Option<String>,
}

/// A logger's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LoggerState {
    Running,
    /// Ran its whole duration.
    Done,
    /// Stopped before (the gateway stopped, or its task failed).
    Stopped,
}

/// A logger's status and statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LoggerStatus {
    pub id: u64,
    pub state: LoggerState,
    pub period_ms: u64,
    pub duration_s: u64,
    /// When it started, milliseconds since the Unix epoch.
    pub started_ms: u64,
    /// Rows sampled so far.
    pub samples: u64,
    /// Grid points skipped because the reads of the one before overran.
    pub missed: u64,
    /// Oldest rows dropped to stay within `logger_max_values`.
    pub dropped: u64,
    /// Rows held now (what the CSV gives).
    pub rows: usize,
    /// Whether it is kept in the data directory.
    pub persisted: bool,
    pub channels: Vec<ChannelInfo>,
}

/// One row: its time since the start and a value per channel.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub time_ms: u64,
    pub values: Vec<Option<f64>>,
}

/// The settings of the loggers (`logger_max_values`, `--data-dir`).
#[derive(Debug, Clone, PartialEq)]
pub struct LoggerConfig {
    /// Values (rows × channels) one logger keeps in memory.
    pub max_values: usize,
    /// Where finished loggers are kept (`DIR/loggers`); `None`: memory
    /// only.
    pub dir: Option<PathBuf>,
}

impl Default for LoggerConfig {
    fn default() -> Self {
        Self {
            max_values: DEFAULT_MAX_VALUES,
            dir: None,
        }
    }
}

/// What a logger's task and its readers share.
struct Logger {
    status: LoggerStatus,
    rows: VecDeque<Row>,
    max_rows: usize,
    /// Rows counted from the start (so `samples - rows.len()` is the index
    /// of the first row held).
    topic: ValueTopic,
}

/// A logger held by [`Loggers`].
struct Held {
    logger: Arc<Mutex<Logger>>,
    /// Dropped (or set) to stop its task.
    stop: watch::Sender<bool>,
}

struct State {
    next_id: u64,
    loggers: Vec<(u64, Held)>,
}

/// The loggers of the gateway; a `Clone` of `Arc`s.
#[derive(Clone)]
pub struct Loggers {
    config: Arc<LoggerConfig>,
    state: Arc<Mutex<State>>,
}

impl Default for Loggers {
    fn default() -> Self {
        Self::new(LoggerConfig::default())
    }
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    // Plain data, never left half-written by a panic in between.
    mutex
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A channel ready to sample.
#[derive(Clone)]
struct Sampler {
    served: Arc<ServedBus>,
    node: NodeId,
    index: u16,
    sub: u8,
    data_type: Option<DataType>,
}

impl Sampler {
    /// The number in `raw`, by the EDS type, or as unsigned little-endian.
    fn decode(&self, raw: &[u8]) -> Result<f64, String> {
        match self.data_type {
            Some(data_type) => Value::from_bytes(data_type, raw)
                .map_err(|err| err.to_string())?
                .as_f64()
                .ok_or_else(|| format!("a {data_type} is no number")),
            None if raw.len() <= 8 => {
                let mut bytes = [0u8; 8];
                bytes[..raw.len()].copy_from_slice(raw);
                Ok(u64::from_le_bytes(bytes) as f64)
            }
            None => Err(format!("{} bytes are no number", raw.len())),
        }
    }

    /// The value from a fresh TPDO, if the node's TPDOs carry it.
    fn tpdo_value(&self, now: Instant) -> Option<f64> {
        let value = self.served.values.value(self.node, self.index, self.sub)?;
        if now.saturating_duration_since(value.at) > TPDO_FRESH {
            return None;
        }
        let signed = self.data_type.is_some_and(DataType::is_signed);
        Some(
            value
                .value
                .as_ref()
                .and_then(Value::as_f64)
                .unwrap_or_else(|| value.as_i64(signed) as f64),
        )
    }

    /// One sample by SDO.
    async fn sdo_value(&self) -> Result<f64, String> {
        if let Some(info) = self.served.registry.node(self.node)
            && let Some(why) = unreachable(&info)
        {
            return Err(why);
        }
        let channel = self
            .served
            .registry
            .sdo(self.node)
            .map_err(|err| err.to_string())?;
        let raw = channel
            .upload(self.index, self.sub)
            .await
            .map_err(|err| GatewayError::from(err).to_string())?;
        self.decode(&raw)
    }
}

type Sample = (Result<f64, String>, Source);

impl Loggers {
    pub fn new(config: LoggerConfig) -> Self {
        Self {
            config: Arc::new(config),
            state: Arc::new(Mutex::new(State {
                next_id: 1,
                loggers: Vec::new(),
            })),
        }
    }

    /// The loggers kept in `config.dir` by an earlier run, loaded (as
    /// stopped or done); files that cannot be read are skipped with a
    /// warning.
    pub fn load(config: LoggerConfig) -> Self {
        let loggers = Self::new(config);
        let Some(dir) = loggers.config.dir.clone() else {
            return loggers;
        };
        let mut found = Vec::new();
        if let Ok(entries) = std::fs::read_dir(&dir) {
            for entry in entries.flatten() {
                let path = entry.path();
                if path.extension().and_then(|e| e.to_str()) != Some("json") {
                    continue;
                }
                match read_kept(&path) {
                    Ok(kept) => found.push(kept),
                    Err(err) => {
                        tracing::warn!("logger {}: not loaded: {err}", path.display());
                    }
                }
            }
        }
        found.sort_by_key(|(status, _)| status.id);
        let excess = found.len().saturating_sub(MAX_LOGGERS);
        let mut state = lock(&loggers.state);
        for (mut status, rows) in found.into_iter().skip(excess) {
            state.next_id = state.next_id.max(status.id + 1);
            if status.state == LoggerState::Running {
                status.state = LoggerState::Stopped;
            }
            let max_rows = loggers.max_rows(status.channels.len());
            let mut rows: VecDeque<Row> = rows.into();
            while rows.len() > max_rows {
                rows.pop_front();
            }
            status.rows = rows.len();
            let topic = ValueTopic::new();
            let id = status.id;
            let logger = Logger {
                status,
                rows,
                max_rows,
                topic,
            };
            let (stop, _) = watch::channel(true);
            state.loggers.push((
                id,
                Held {
                    logger: Arc::new(Mutex::new(logger)),
                    stop,
                },
            ));
        }
        drop(state);
        loggers
    }

    fn max_rows(&self, channels: usize) -> usize {
        (self.config.max_values / channels.max(1)).max(1)
    }

    /// Resolves the channels, and starts the logger (its first sample at
    /// once).
    pub(crate) async fn create(
        &self,
        gateway: &Gateway,
        request: LoggerRequest,
    ) -> Result<LoggerStatus, LoggerError> {
        request.check()?;
        let mut samplers = Vec::with_capacity(request.channels.len());
        let mut infos = Vec::with_capacity(request.channels.len());
        for (n, channel) in request.channels.iter().enumerate() {
            let (sampler, info) = resolve(gateway, n, channel).await?;
            samplers.push(sampler);
            infos.push(info);
        }
        let max_rows = self.max_rows(samplers.len());
        let (status, logger, stop_rx) = {
            let mut state = lock(&self.state);
            if state.loggers.len() >= MAX_LOGGERS {
                let finished = state
                    .loggers
                    .iter()
                    .position(|(_, held)| lock(&held.logger).status.state != LoggerState::Running);
                match finished {
                    Some(at) => {
                        let (id, _) = state.loggers.remove(at);
                        self.forget_files(id);
                    }
                    None => return Err(LoggerError::TooMany),
                }
            }
            let id = state.next_id;
            state.next_id += 1;
            let status = LoggerStatus {
                id,
                state: LoggerState::Running,
                period_ms: request.period_ms,
                duration_s: request.duration_s,
                started_ms: unix_ms(),
                samples: 0,
                missed: 0,
                dropped: 0,
                rows: 0,
                persisted: false,
                channels: infos,
            };
            let logger = Arc::new(Mutex::new(Logger {
                status: status.clone(),
                rows: VecDeque::new(),
                max_rows,
                topic: ValueTopic::new(),
            }));
            let (stop, stop_rx) = watch::channel(false);
            state.loggers.push((
                id,
                Held {
                    logger: logger.clone(),
                    stop,
                },
            ));
            (status, logger, stop_rx)
        };
        let dir = self.config.dir.clone();
        tokio::spawn(run(logger, samplers, stop_rx, dir));
        Ok(status)
    }

    /// Every logger's status, oldest first.
    pub fn list(&self) -> Vec<LoggerStatus> {
        lock(&self.state)
            .loggers
            .iter()
            .map(|(_, held)| lock(&held.logger).status.clone())
            .collect()
    }

    fn held(&self, id: &str) -> Result<Arc<Mutex<Logger>>, LoggerError> {
        let number: Option<u64> = id.parse().ok();
        lock(&self.state)
            .loggers
            .iter()
            .find(|(held_id, _)| Some(*held_id) == number)
            .map(|(_, held)| held.logger.clone())
            .ok_or_else(|| LoggerError::Unknown(id.to_string()))
    }

    /// A logger's status.
    pub fn status(&self, id: &str) -> Result<LoggerStatus, LoggerError> {
        let logger = self.held(id)?;
        let status = lock(&logger).status.clone();
        Ok(status)
    }

    /// A logger's rows as CSV: `time_ms,<channel names>`, then a row per
    /// sample time (an empty cell for a failed read).
    pub fn csv(&self, id: &str) -> Result<String, LoggerError> {
        let logger = self.held(id)?;
        let logger = lock(&logger);
        Ok(to_csv(&logger.status, logger.rows.iter()))
    }

    /// The rows held now.
    pub fn rows(&self, id: &str) -> Result<Vec<Row>, LoggerError> {
        let logger = self.held(id)?;
        let rows = lock(&logger).rows.iter().cloned().collect();
        Ok(rows)
    }

    /// A reader of the logger's stream topic.
    pub fn subscribe(&self, id: &str, rate_hz: f64) -> Result<TopicReceiver, LoggerError> {
        let logger = self.held(id)?;
        let logger = lock(&logger);
        let receiver = logger.topic.subscribe(rate_hz);
        if logger.topic.latest().is_none() {
            // Something to show at once, even for a finished logger.
            logger.topic.publish(topic_json(&logger.status, 0, &[]));
        }
        Ok(receiver)
    }

    /// Stops a logger (if it runs) and forgets it, its kept files too; its
    /// last status.
    pub(crate) fn delete(&self, id: &str) -> Result<LoggerStatus, LoggerError> {
        let number: Option<u64> = id.parse().ok();
        let held = {
            let mut state = lock(&self.state);
            let at = state
                .loggers
                .iter()
                .position(|(held_id, _)| Some(*held_id) == number)
                .ok_or_else(|| LoggerError::Unknown(id.to_string()))?;
            state.loggers.remove(at).1
        };
        let _ = held.stop.send(true);
        let mut logger = lock(&held.logger);
        if logger.status.state == LoggerState::Running {
            logger.status.state = LoggerState::Stopped;
        }
        let status = logger.status.clone();
        drop(logger);
        self.forget_files(status.id);
        Ok(status)
    }

    fn forget_files(&self, id: u64) {
        if let Some(dir) = &self.config.dir {
            for path in [csv_path(dir, id), json_path(dir, id)] {
                match std::fs::remove_file(&path) {
                    Ok(()) => {}
                    Err(err) if err.kind() == std::io::ErrorKind::NotFound => {}
                    Err(err) => tracing::warn!("logger {id}: {}: {err}", path.display()),
                }
            }
        }
    }
}

/// The loggers as operations of the gateway: started and deleted by an
/// operator ([`Operation::Logger`]: sampling takes the nodes' SDO queues),
/// one write of the caller's rate each, in a task a caller that goes away
/// cannot cut (the trial reads of a start, the files of a delete), each
/// with its audit row.
impl Gateway {
    /// Resolves `request`'s channels and starts the logger for `caller`
    /// (its first sample at once).
    ///
    /// Audited as `start data logger`.
    pub async fn start_logger(
        &self,
        caller: &Caller,
        request: LoggerRequest,
    ) -> Result<LoggerStatus, GatewayError> {
        let summary = serde_json::to_string(&request).ok();
        let row = self.audit_row(caller, AuditTarget::new("start data logger"), summary);
        let (gateway, caller) = (self.clone(), caller.clone());
        spawn_audited(row, async move {
            gateway.admit(&caller, Operation::Logger)?;
            let status = gateway.loggers().create(&gateway, request).await?;
            tracing::info!(
                "logger {} started by {} ({}): {} channels every {} ms for {} s",
                status.id,
                caller.who,
                caller.channel,
                status.channels.len(),
                status.period_ms,
                status.duration_s
            );
            Ok(status)
        })
        .await
    }

    /// Stops the logger `id` (if it runs) and forgets it, its kept files
    /// too, for `caller`; its last status.
    ///
    /// Audited as `delete data logger`, the id its item.
    pub async fn delete_logger(
        &self,
        caller: &Caller,
        id: &str,
    ) -> Result<LoggerStatus, GatewayError> {
        let target = AuditTarget::new("delete data logger").item(id.to_string());
        let row = self.audit_row(caller, target, None);
        let (gateway, caller, id) = (self.clone(), caller.clone(), id.to_string());
        spawn_audited(row, async move {
            gateway.admit(&caller, Operation::Logger)?;
            let loggers = gateway.loggers().clone();
            // Its files go from the disk: blocking work.
            let status = tokio::task::spawn_blocking(move || loggers.delete(&id))
                .await
                .map_err(|err| GatewayError::Internal(format!("logger delete task: {err}")))??;
            tracing::info!(
                "logger {} deleted by {} ({})",
                status.id,
                caller.who,
                caller.channel
            );
            Ok(status)
        })
        .await
    }
}

/// Resolves one channel against its node: the bus and node known, the
/// object in its dictionary (by number or name), readable and a number.
async fn resolve(
    gateway: &Gateway,
    n: usize,
    channel: &ChannelRequest,
) -> Result<(Sampler, ChannelInfo), LoggerError> {
    let gateway_error = |source| LoggerError::Gateway { channel: n, source };
    let (served, info) = gateway
        .node(&channel.bus, &channel.node.to_string())
        .map_err(gateway_error)?;
    let dict = info.eds_entry.as_ref().map(|entry| &entry.eds.dictionary);
    let sub_json = channel.sub.clone().unwrap_or(json!(0));
    let numeric_index = match &channel.index {
        Json::String(text) => parse_index(text),
        Json::Number(number) => Some(
            number
                .as_u64()
                .and_then(|n| u16::try_from(n).ok())
                .ok_or_else(|| LoggerError::Channel {
                    channel: n,
                    message: format!("{number} is no object index"),
                })?,
        ),
        other => {
            return Err(LoggerError::Channel {
                channel: n,
                message: format!(
                    "{other} is no object index: give 0x6064, 6064h, a decimal number or an EDS name"
                ),
            });
        }
    };
    let dictionary_error = |source| LoggerError::Dictionary { channel: n, source };
    let object = match (dict, numeric_index) {
        (Some(dict), Some(index)) => dict.get(index),
        (Some(dict), None) => Some(
            dict.resolve_index_json(&channel.index)
                .map_err(dictionary_error)?,
        ),
        (None, Some(_)) => None,
        (None, None) => {
            return Err(LoggerError::Channel {
                channel: n,
                message: format!(
                    "node {} has no EDS, so no object has a name: give {} as a number",
                    channel.node, channel.index
                ),
            });
        }
    };
    let prefix = format!("{}/{}", channel.bus, channel.node);
    let (index, sub, name, data_type) = match object {
        Some(object) => {
            let described = object
                .resolve_sub_json(&sub_json)
                .map_err(dictionary_error)?;
            let label = if object.object_type.has_sub_objects() {
                format!("{}/{}", object.name, described.name)
            } else {
                object.name.clone()
            };
            let at = format!("{}:{}", format_index(object.index), described.sub_index);
            if !described.access.is_readable() {
                return Err(LoggerError::NotLoggable {
                    channel: n,
                    message: format!("{at} ({label}) is write-only: it cannot be read"),
                });
            }
            let data_type = described.data_type;
            if !(data_type.is_integer() || data_type.is_real() || data_type == DataType::Boolean) {
                return Err(LoggerError::NotLoggable {
                    channel: n,
                    message: format!("{at} ({label}) is a {data_type}: a logger records numbers"),
                });
            }
            (
                object.index,
                described.sub_index,
                format!("{prefix}/{label}"),
                Some(data_type),
            )
        }
        None => {
            let index = numeric_index.unwrap_or_default();
            let sub = match &sub_json {
                Json::Number(number) => number.as_u64().and_then(|s| u8::try_from(s).ok()),
                Json::String(text) => text.trim().parse().ok(),
                _ => None,
            }
            .ok_or_else(|| LoggerError::Channel {
                channel: n,
                message: format!(
                    "{sub_json} is no sub-index: give 0 to 255 (the EDS does not describe {}, so names are unknown)",
                    format_index(index)
                ),
            })?;
            (
                index,
                sub,
                format!("{prefix}/{}:{sub}", format_index(index)),
                None,
            )
        }
    };
    let sampler = Sampler {
        served: served.clone(),
        node: info.id,
        index,
        sub,
        data_type,
    };
    if data_type.is_none() {
        // Nothing says the object exists: ask the device once, so that a
        // mistyped index is an error now rather than an empty column.
        super::check_sdo_allowed(&served, &info).map_err(gateway_error)?;
        let channel_sdo = served
            .registry
            .sdo(info.id)
            .map_err(|err| gateway_error(err.into()))?;
        let raw = tokio::spawn(async move { channel_sdo.upload(index, sub).await })
            .await
            .map_err(|err| gateway_error(GatewayError::Internal(format!("SDO task: {err}"))))?
            .map_err(|err| gateway_error(err.into()))?;
        sampler
            .decode(&raw)
            .map_err(|message| LoggerError::NotLoggable {
                channel: n,
                message: format!("{}:{sub}: {message}", format_index(index)),
            })?;
    }
    let unit = DriveKind::from_profile(info.profile).and_then(|kind| {
        drive_unit(
            &kind.units(),
            index,
            axis_count(kind, info.eds_entry.as_deref()),
        )
    });
    let info = ChannelInfo {
        bus: channel.bus.clone(),
        node: channel.node,
        index: format_index(index),
        sub,
        name,
        data_type: data_type.map(|t| t.short_name().map_or_else(|| t.to_string(), str::to_string)),
        unit,
        source: None,
        sdo_samples: 0,
        tpdo_samples: 0,
        errors: 0,
        last_error: None,
    };
    Ok((sampler, info))
}

/// The unit of a drive's object `index` (any axis of `axes`, CiA 402's
/// 0x800 apart): the positions, velocities, accelerations and torques
/// whose units the product's manual fixes ([`AxisUnits`]); `None` for any
/// other object.
fn drive_unit(units: &AxisUnits, index: u16, axes: u8) -> Option<String> {
    const AXIS_STEP: u16 = 0x800;
    let end = 0x6000 + AXIS_STEP * u16::from(axes.max(1));
    if !(0x6000..end).contains(&index) {
        return None;
    }
    let unit = match 0x6000 + (index - 0x6000) % AXIS_STEP {
        // Actual, target, window and limit positions, following error.
        0x6062 | 0x6064 | 0x6065 | 0x6067 | 0x607A | 0x607C | 0x607D | 0x60F4 => &units.position,
        // Demand, actual, target and limit velocities.
        0x606B | 0x606C | 0x607F | 0x6080 | 0x6081 | 0x60FF => &units.velocity,
        0x6083..=0x6085 => &units.acceleration,
        0x6071 | 0x6072 | 0x6074 | 0x6077 => &units.torque,
        0x6042 | 0x6044 => units.vl_velocity.as_ref()?,
        _ => return None,
    };
    Some(unit.clone())
}

/// One round: every channel sampled, the channels of one node one after
/// another (each SDO upload queued on its own), the nodes at once. Each
/// node's reads run in a task of their own, so that a logger deleted
/// halfway never cuts a transfer.
async fn sample_round(samplers: &[Sampler]) -> Vec<Sample> {
    let mut groups: Vec<(String, NodeId, Vec<usize>)> = Vec::new();
    for (n, sampler) in samplers.iter().enumerate() {
        match groups
            .iter_mut()
            .find(|(bus, node, _)| *bus == sampler.served.name && *node == sampler.node)
        {
            Some((_, _, members)) => members.push(n),
            None => groups.push((sampler.served.name.clone(), sampler.node, vec![n])),
        }
    }
    let tasks: Vec<_> = groups
        .into_iter()
        .map(|(_, _, members)| {
            let group: Vec<(usize, Sampler)> = members
                .into_iter()
                .map(|n| (n, samplers[n].clone()))
                .collect();
            tokio::spawn(async move {
                let mut out = Vec::with_capacity(group.len());
                for (n, sampler) in group {
                    let sample = match sampler.tpdo_value(Instant::now()) {
                        Some(value) => (Ok(value), Source::Tpdo),
                        None => (sampler.sdo_value().await, Source::Sdo),
                    };
                    out.push((n, sample));
                }
                out
            })
        })
        .collect();
    let mut samples: Vec<Option<Sample>> = vec![None; samplers.len()];
    for task in tasks {
        match task.await {
            Ok(out) => {
                for (n, sample) in out {
                    samples[n] = Some(sample);
                }
            }
            Err(err) => tracing::error!("logger: sampling task: {err}"),
        }
    }
    samples
        .into_iter()
        .map(|sample| sample.unwrap_or((Err("sampling task failed".to_string()), Source::Sdo)))
        .collect()
}

/// The logger's task: a round per grid point until the duration is over or
/// it is stopped; then kept in `dir` if given.
async fn run(
    logger: Arc<Mutex<Logger>>,
    samplers: Vec<Sampler>,
    mut stop: watch::Receiver<bool>,
    dir: Option<PathBuf>,
) {
    let (period, duration) = {
        let logger = lock(&logger);
        (
            Duration::from_millis(logger.status.period_ms),
            Duration::from_secs(logger.status.duration_s),
        )
    };
    let start = Instant::now();
    let end = start + duration;
    let mut tick: u32 = 0;
    let mut published = 0u64;
    let mut last_publish = start;
    loop {
        let due = start + period * tick;
        if due >= end {
            break;
        }
        tokio::select! {
            () = tokio::time::sleep_until(due) => {}
            _ = stop.wait_for(|stopped| *stopped) => return,
        }
        let samples = sample_round(&samplers).await;
        if *stop.borrow() {
            return;
        }
        let now = Instant::now();
        // Grid points the round overran by a whole period are skipped.
        let mut next = tick + 1;
        let mut missed = 0;
        while start + period * (next + 1) <= now {
            next += 1;
            missed += 1;
        }
        let time_ms = (period * tick).as_millis() as u64;
        let mut logger = lock(&logger);
        logger.push(time_ms, samples, missed);
        if now.saturating_duration_since(last_publish) >= PUBLISH_EVERY {
            published = logger.publish(published);
            last_publish = now;
        }
        drop(logger);
        tick = next;
    }
    let kept = {
        let mut logger = lock(&logger);
        logger.status.state = LoggerState::Done;
        logger.status.persisted = dir.is_some();
        logger.publish(published);
        dir.map(|dir| {
            let csv = to_csv(&logger.status, logger.rows.iter());
            (dir, logger.status.clone(), csv)
        })
    };
    if let Some((dir, status, csv)) = kept {
        match tokio::task::spawn_blocking(move || keep(&dir, &status, &csv)).await {
            Ok(Ok(())) => {}
            Ok(Err(err)) => tracing::warn!("logger: not kept: {err}"),
            Err(err) => tracing::error!("logger: keeping task: {err}"),
        }
    }
}

impl Logger {
    fn push(&mut self, time_ms: u64, samples: Vec<Sample>, missed: u64) {
        let mut values = Vec::with_capacity(samples.len());
        for (channel, (result, source)) in self.status.channels.iter_mut().zip(samples) {
            match result {
                Ok(value) => {
                    channel.source = Some(source);
                    match source {
                        Source::Sdo => channel.sdo_samples += 1,
                        Source::Tpdo => channel.tpdo_samples += 1,
                    }
                    values.push(Some(value));
                }
                Err(error) => {
                    channel.errors += 1;
                    channel.last_error = Some(error);
                    values.push(None);
                }
            }
        }
        self.rows.push_back(Row { time_ms, values });
        while self.rows.len() > self.max_rows {
            self.rows.pop_front();
            self.status.dropped += 1;
        }
        self.status.samples += 1;
        self.status.missed += missed;
        self.status.rows = self.rows.len();
    }

    /// Publishes the rows from sample `from` on (those still held) on the
    /// stream topic; the next `from`.
    fn publish(&self, from: u64) -> u64 {
        let first_held = self.status.samples - self.rows.len() as u64;
        let skip = from.saturating_sub(first_held) as usize;
        let rows: Vec<&Row> = self.rows.iter().skip(skip).collect();
        let first = first_held + skip as u64;
        self.topic.publish(topic_json(&self.status, first, &rows));
        self.status.samples
    }
}

/// The stream topic's sample: the status's counters and the new rows
/// (`first` is the number of the first, counted from the start).
fn topic_json(status: &LoggerStatus, first: u64, rows: &[&Row]) -> Json {
    json!({
        "id": status.id,
        "state": status.state,
        "samples": status.samples,
        "missed": status.missed,
        "first": first,
        "columns": status.channels.iter().map(|c| c.name.as_str()).collect::<Vec<_>>(),
        "rows": rows
            .iter()
            .map(|row| {
                let mut cells = vec![json!(row.time_ms)];
                cells.extend(row.values.iter().map(|value| json!(value)));
                Json::Array(cells)
            })
            .collect::<Vec<_>>(),
    })
}

/// A CSV field, quoted when it must be (RFC 4180).
fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}

/// The header of the absolute time's column: ISO 8601, UTC, milliseconds.
const TIME_UTC: &str = "time_utc";

/// A CSV as spreadsheets take it: one header line, `time_ms` (since the
/// start), `time_utc` (the sample's time, ISO 8601 UTC to the
/// millisecond), then a column per channel named `name [unit]` where its
/// unit is known; then a row per sample, a failed sample an empty cell.
fn to_csv<'a>(status: &LoggerStatus, rows: impl Iterator<Item = &'a Row>) -> String {
    let mut out = format!("time_ms,{TIME_UTC}");
    for channel in &status.channels {
        out.push(',');
        let column = match &channel.unit {
            Some(unit) => format!("{} [{unit}]", channel.name),
            None => channel.name.clone(),
        };
        out.push_str(&csv_field(&column));
    }
    out.push('\n');
    for row in rows {
        let _ = write!(
            out,
            "{},{}",
            row.time_ms,
            iso8601_ms(status.started_ms.saturating_add(row.time_ms))
        );
        for value in &row.values {
            out.push(',');
            if let Some(value) = value {
                let _ = write!(out, "{value}");
            }
        }
        out.push('\n');
    }
    out
}

/// Milliseconds since the Unix epoch as ISO 8601, UTC:
/// `2026-11-29T12:00:00.125Z`.
fn iso8601_ms(unix_ms: u64) -> String {
    let (secs, millis) = (unix_ms / 1000, unix_ms % 1000);
    let (days, rest) = (secs / 86_400, secs % 86_400);
    let (year, month, day) = civil_from_days(days as i64);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}.{millis:03}Z",
        rest / 3600,
        rest % 3600 / 60,
        rest % 60
    )
}

/// The rows of a CSV [`to_csv`] wrote (or an earlier version, without the
/// `time_utc` column: files kept before it).
fn from_csv(text: &str, channels: usize) -> Result<Vec<Row>, String> {
    let mut lines = text.lines();
    let header = lines.next().ok_or("no header")?;
    let absolute = header.split(',').nth(1) == Some(TIME_UTC);
    lines
        .enumerate()
        .map(|(n, line)| {
            let mut cells = line.split(',');
            let time_ms = cells
                .next()
                .and_then(|cell| cell.parse().ok())
                .ok_or_else(|| format!("row {}: no time", n + 1))?;
            if absolute {
                cells
                    .next()
                    .ok_or_else(|| format!("row {}: no {TIME_UTC}", n + 1))?;
            }
            let values = cells
                .map(|cell| {
                    if cell.is_empty() {
                        Ok(None)
                    } else {
                        cell.parse()
                            .map(Some)
                            .map_err(|_| format!("row {}: '{cell}' is no number", n + 1))
                    }
                })
                .collect::<Result<Vec<_>, _>>()?;
            if values.len() != channels {
                return Err(format!("row {}: {} cells", n + 1, values.len()));
            }
            Ok(Row { time_ms, values })
        })
        .collect()
}

fn csv_path(dir: &Path, id: u64) -> PathBuf {
    dir.join(format!("logger-{id}.csv"))
}

fn json_path(dir: &Path, id: u64) -> PathBuf {
    dir.join(format!("logger-{id}.json"))
}

/// Writes a finished logger to `dir` (made private if new).
fn keep(dir: &Path, status: &LoggerStatus, csv: &str) -> std::io::Result<()> {
    use std::io::Write as _;
    files::create_private_dir(dir)?;
    let write = |path: PathBuf, bytes: &[u8]| {
        files::private_file_options()
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)?
            .write_all(bytes)
    };
    write(csv_path(dir, status.id), csv.as_bytes())?;
    let json = serde_json::to_vec_pretty(status).map_err(std::io::Error::other)?;
    // The status last: a kept logger is one whose status is there.
    write(json_path(dir, status.id), &json)
}

fn read_kept(json: &Path) -> Result<(LoggerStatus, Vec<Row>), String> {
    let text = std::fs::read(json).map_err(|err| err.to_string())?;
    let status: LoggerStatus = serde_json::from_slice(&text).map_err(|err| err.to_string())?;
    let dir = json.parent().unwrap_or(Path::new("."));
    let csv = std::fs::read_to_string(csv_path(dir, status.id)).map_err(|err| err.to_string())?;
    let rows = from_csv(&csv, status.channels.len())?;
    Ok((status, rows))
}

#[cfg(test)]
mod tests;
