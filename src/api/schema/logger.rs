//! The schemas of `crate::gateway::logger`'s request and status.

use serde_json::Value as Json;
use utoipa::ToSchema;

/// One channel as a request names it: the object by number
/// (`"0x6064"`, `24676`) or by EDS name, the sub-index by number or name
/// (0 when not given).
#[derive(Debug, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(as = LoggerChannelRequest)]
pub struct ChannelRequest {
    #[schema(example = "demo")]
    pub bus: String,
    #[schema(minimum = 1, maximum = 127, example = 1)]
    pub node: u8,
    /// `0x6064`, `6064h`, a decimal number, or the EDS name.
    #[schema(value_type = String, example = "0x6064")]
    pub index: Json,
    /// A number or the sub-object's EDS name; 0 when not given.
    #[serde(default)]
    #[schema(value_type = Option<String>, example = "0")]
    pub sub: Option<Json>,
}

/// What a logger is asked for.
#[derive(Debug, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"channels": [{"bus": "demo", "node": 1, "index": "0x6064", "sub": 0},
    {"bus": "demo", "node": 1, "index": "0x606C", "sub": 0}], "period_ms": 10, "duration_s": 2}))]
pub struct LoggerRequest {
    /// 1 to 16 channels.
    pub channels: Vec<ChannelRequest>,
    /// 1 to 60000.
    #[schema(minimum = 1, maximum = 60000, example = 10)]
    pub period_ms: u64,
    /// 1 to 86400.
    #[schema(minimum = 1, maximum = 86400, example = 2)]
    pub duration_s: u64,
}

/// Where a channel's samples came from.
#[derive(Debug, ToSchema)]
#[serde(rename_all = "snake_case")]
#[schema(as = LoggerSource)]
pub enum Source {
    Sdo,
    Tpdo,
}

/// A channel, resolved against its node's dictionary.
#[derive(Debug, ToSchema)]
#[schema(as = LoggerChannel)]
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
    /// product's manual names them); the CSV's header gives it as
    /// `name [unit]`. Null elsewhere.
    #[schema(example = "increments")]
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
#[derive(Debug, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum LoggerState {
    Running,
    /// Ran its whole duration.
    Done,
    /// Stopped before (the gateway stopped, or its task failed).
    Stopped,
}

/// A logger's status and statistics.
#[derive(Debug, ToSchema)]
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
