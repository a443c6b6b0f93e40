//! The CANopen master: what candeck does on a bus with the protocol of
//! [`candeck_canopen`], as one service ([`Gateway`]) that every door
//! (REST, CiA 309-3 and 309-5, Sparkplug B, the command line: the
//! `candeck` package) holds. This crate builds on `candeck-can`,
//! `candeck-canopen` and `candeck-profiles` only: it knows no door, no
//! HTTP and no virtual device (the workspace's manifests, checked by
//! `tests/layering.rs`).
//!
//! # Layout
//!
//! The modules are private: what the doors use is re-exported at the
//! root, grouped by what it acts on (the service; who asks and what is
//! recorded; a node; motion; a bus; telemetry). The workspace's
//! `unreachable_pub` lint (an error under CI's `-D warnings`) flags a
//! `pub` item the root does not reach, so the surface stays what is
//! listed here.
//!
//! - `service`: the [`Gateway`] service and each [`ServedBus`] (its
//!   registry, telemetry, SYNC producer, recorder, virtual devices); the
//!   rules every adapter obeys ([`check_sdo_allowed`], a drive's checks),
//!   NMT.
//! - `bus`: the operations on a bus as a whole, each holding its caller
//!   to the policy and writing its audit row: scan, SYNC period, raw
//!   frame, recording, a node's boot-up again (`lss` and `io` add
//!   theirs on the same pattern).
//! - `start`: [`Gateway::start`] from a [`GatewayConfig`] (history,
//!   catalog, buses, network managers, pruners, first scans) and
//!   [`Gateway::shutdown`] (the safe stop, the recordings flushed).
//! - `error`: [`GatewayError`], the service's one error type.
//! - `access`: tokens and roles, and the write rate limit, for every
//!   adapter.
//! - `files`: the data directory's modes (0700 directories, 0600 files).
//! - `io`: the I/O of a CiA 401 module: every channel with its value
//!   and age, outputs set and read back.
//! - `leases`: the motion leases granted and the supervisor that stops
//!   the axis of a lapsed one (`motion_lease` is their table).
//! - `motion`: the motion operations every door calls (state, halt,
//!   moves, step test, lease renewal), with the lease policy whole.
//! - `node`: one node of a bus as a handle ([`NodeHandle`]) whose
//!   operations every door calls.
//! - `caller`: who asks, through which door ([`caller::Caller`]).
//! - `audit`: the audit row every operation writes of itself, once
//!   ([`Gateway::audited`]), and what a door adds to it
//!   ([`DoorRequest`]).
//! - `alarms`: the alarms of the machine (ISA-18.2): the model, its
//!   sources (what the gateway publishes, followed), its persistence, the
//!   machine's state with them, acknowledgement and the machine's
//!   recovery.
//! - `policy`: what the gateway asks of a caller before it acts: its
//!   role, and a write from its write rate limit.
//! - `safe_stop`: STOP ALL and the stop on shutdown.
//! - `load`: the measured load of a bus.
//! - `logger`: the data logger: objects of any nodes sampled at a
//!   period (TPDO or SDO), kept in memory and in the data directory.
//! - `lss`: LSS (CiA 305) on a bus: Fastscan for unconfigured devices,
//!   node-ID assignment, and the UniSwarm node-ID change by 0x2040.
//! - `machine`: the network manager of a bus (CiA 302-2) at work: the
//!   [`crate::canopen::manager`] driven by a task per bus, its heartbeat,
//!   the machine's status.
//! - `sampling`: objects of a node sampled for any caller at the
//!   intervals asked ([`Gateway::sample_objects`]), over SDO within the
//!   node's one bound for every door (fairly shared), or from the TPDOs
//!   that carry them.
//! - `sdo`: SDO transfers to one node over a [`Bus`](crate::can::Bus), one at
//!   a time, with a fair queue; each node's transfers counted by outcome,
//!   with a latency histogram (for `/metrics`).
//! - `drive`: the CiA 402 master of one axis of a drive node (state walk,
//!   fault reset, halt, moves in each mode of UMC, JMC and generic drives).
//! - `step_test`: the step test of a UMC axis's control loop and its
//!   metrics (rise time, overshoot, settling, steady-state error).
//! - `frames`: the recent frames of a bus, in a bounded ring.
//! - `eds_files`: EDS files uploaded and deleted, and assigned to nodes
//!   by hand, as operations of the [`Gateway`].
//! - `history`: the persisted audit log and EMCY/NMT history (SQLite).
//! - `profile`: the `Profile` of a node and the EDS
//!   catalog (built-in and `--eds-dir` files) its identity is matched to.
//! - `recording`: a bus recorded to a candump `-L` log file (by the record
//!   loop of [`crate::can::candump::LogRecorder`]), started and
//!   stopped at will.
//! - `registry`: the node registry of one bus: nodes found by boot-up,
//!   heartbeat and scan, identified, supervised, with their EMCY history.
//! - `uioled`: a UIO1LED's segments over SDO.
//! - `dcf`: configuration backup and restore as a CiA 306 DCF.
//! - `program`: program download (CiA 302-3): stop, clear, block
//!   download to 0x1F50, verify 0x1F56 against the image's CRC-32, start.
//! - `pdo`: a node's PDO configuration over SDO, the re-mapping
//!   procedure, TPDO decoding and RPDO encoding.
//! - `sync`: the gateway's SYNC producer on a bus.
//! - `values`: the nodes' TPDO values, decoded by the mappings read from
//!   them.
//! - `telemetry`: value topics (newest sample wins) for the stream, the
//!   stream's counters, and the turns at fanning it out.
//! - `producers`: what the producers of value topics share: a task per
//!   topic while someone reads, publishes paced to the readers' rate, the
//!   `TelemetryConfig`.
//! - `axis_telemetry`: each drive axis's status for the stream, from
//!   TPDOs or SDO polling.
//! - `led_preview`: each LED controller's preview for the stream.
//! - `edge_node`: the counters of the Sparkplug B edge node, for
//!   `/metrics`.

use candeck_can as can;
use candeck_canopen as canopen;
use candeck_profiles as profiles;

mod access;
mod alarms;
mod audit;
mod authority;
mod axis_telemetry;
mod bus;
mod caller;
mod dcf;
mod drive;
mod edge_node;
mod eds_files;
mod end_motion;
mod error;
mod files;
mod frames;
mod history;
mod io;
mod leases;
mod led_preview;
mod load;
mod logger;
mod lss;
mod machine;
mod motion;
mod motion_lease;
mod node;
mod pdo;
mod policy;
mod producers;
mod profile;
mod program;
mod recording;
mod registry;
mod safe_stop;
mod sampling;
mod sdo;
mod service;
mod start;
mod step_test;
mod sync;
mod telemetry;
#[cfg(test)]
mod test_rig;
mod uioled;
mod values;

// The service: started from its configuration, its buses, its errors.
pub use error::{GatewayError, LedError, PdoError, SimError};
pub use service::{BusDevices, Gateway, ServedBus, check_sdo_allowed, check_writable};
pub use start::{GatewayConfig, StartError};

// Who asks, what the gateway asks of them, and what it records.
pub use access::{RateLimit, Role, Token, Tokens, constant_time_eq};
pub use audit::{AuditRow, AuditTarget, DoorDetail, DoorRequest, spawn_audited};
pub use caller::{Caller, Channel};
pub use history::{
    AuditEntry, DEFAULT_RETENTION_DAYS, DEFAULT_RETENTION_ROWS, EventKind, History, OK, Query,
    Retention, StoredEvent,
};
pub use policy::Operation;

// The alarms: the model, the machine with them, its recovery.
pub use alarms::{
    AckFilter, Alarm, AlarmChange, AlarmEvent, AlarmFilter, AlarmPage, AlarmState, AlarmStep,
    AlarmSummary, Alarms, AxisRecovery, MAX_COMMENT, MachineCondition, MachineView, PAGE_SIZE,
    RecoveryOutcome, RecoveryReport,
};
pub use profiles::alarm::{AlarmKind, Severity};

// A node and its operations: objects, NMT, configuration, LEDs, programs,
// PDOs, I/O, its EDS.
pub use eds_files::EdsUser;
pub use io::{IoState, OutputSet};
pub use node::NodeHandle;
pub use node::config::{ParameterArea, ParameterCommand, RestoreSource, RestoredEntry};
pub use node::led::{ColorChannels, LedController, Others, Scene, SegmentUpdate, effect_by_name};
pub use node::objects::{nmt_summary, object_item};
pub use node::program::ProgramDownload;
pub use pdo::{DecodedValue, EntryRequest, PdoConfig, PdoRequest, entry_name, tpdo_decoders};
pub use profile::{
    DEFAULT_EDS_MAX_BYTES, DEFAULT_EDS_MAX_FILES, EdsCatalog, EdsEntry, EdsQuota, EdsSource,
    Identity, Profile, SkippedFile,
};
pub use registry::{
    EmcyRecord, Identification, NodeEvent, NodeInfo, NodeMetrics, NodeRegistry, OfflineReason,
    RegistryConfig, RegistryError,
};
pub use sampling::{
    DEFAULT_SDO_SAMPLES_PER_S, MAX_SDO_SAMPLES_PER_S, ObjectSample, ObjectSampling, SampleSink,
};
pub use sdo::{LATENCY_BUCKETS, SdoChannel, SdoRequestError, SdoStatsSnapshot};
pub use uioled::{Color, Preview, PreviewSegment, effect_name, fits, is_segment, read_segment};

// Motion: the facade, its leases, the drives' types, step tests, STOP ALL.
pub use drive::{
    AxisLimits, AxisStatus, AxisUnits, DriveError, DriveKind, MoveMode, MoveRequest, TargetState,
    axis_count,
};
pub use leases::{LeaseSession, RENEWAL_AUDIT_EVERY};
pub use motion::{LeaseClaim, MotionFailed, MotionOutcome, spawned};
pub use motion_lease::{
    AxisKey, DEFAULT_PERIOD, LeaseError, MAX_PERIOD, MIN_PERIOD, MotionLease, mask,
};
pub use safe_stop::{StopAttempt, StopMethod, StopOutcome, StopReport};
pub use step_test::{LoopGains, SampleSource, Sampling, StepLoop, StepTestRequest, StepTestResult};

// A bus: its frames, recording, SYNC, LSS, network manager, loggers.
pub use frames::{CAPACITY, FrameLog};
pub use logger::{
    ChannelInfo, ChannelRequest, DEFAULT_MAX_VALUES, LoggerError, LoggerRequest, LoggerState,
    LoggerStatus, Source,
};
pub use lss::BusLss;
pub use machine::{MachineSettings, load_dcf};
pub use recording::{
    DEFAULT_QUOTA_MB, Limits, RecordingError, RecordingState, RecordingStatus, StopReason,
    civil_from_days,
};
pub use sync::{MAX_PERIOD_MS, SyncStatus};

// Telemetry for the stream and the edge node.
pub use edge_node::EdgeNodeStats;
pub use led_preview::PreviewError;
pub use producers::{
    DEFAULT_AXIS_POLL_HZ, MAX_PUBLISH_HZ, MAX_RATE_HZ, MIN_RATE_HZ, TelemetryConfig, period_at_most,
};
pub use telemetry::{
    STREAM_TURNS, Sample, StreamCounters, StreamTurn, StreamTurns, TopicReceiver, unix_ms,
};
pub use values::{TpdoFrame, TpdoValue};
