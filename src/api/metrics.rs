//! `GET /metrics`: the gateway's numbers in the Prometheus text exposition
//! format, version 0.0.4 (`docs/deployment.md`, "Metrics";
//! the format: prometheus.io, "Exposition formats").
//!
//! Nothing here counts: every number is read when the page is asked for,
//! from the counters the layers below keep anyway (the bus attachment's,
//! the load meter's, each node's [`SdoChannel`](crate::gateway::SdoChannel)
//! statistics, the frame log's and the TPDO decoder's losses, the stream's
//! [`StreamCounters`](crate::gateway::StreamCounters)) and, on
//! Linux, from `/proc/self`. A scrape takes each registry's lock once,
//! briefly, and never waits on a device.
//!
//! Names follow the Prometheus conventions: `candeck_` before the
//! gateway's own, `_total` on counters, base units (seconds, bytes), labels
//! `bus` and `node`. The process's numbers use the standard `process_`
//! names that every client library exports, so that stock dashboards find
//! them; the one without a standard name (peak memory) is candeck's.

use std::fmt::{self, Write as _};
use std::sync::atomic::Ordering;

use axum::extract::State;
use axum::http::header::CONTENT_TYPE;
use axum::response::IntoResponse;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::AppState;
use crate::can::CounterSnapshot;
use crate::gateway::NodeMetrics;
use crate::gateway::{LATENCY_BUCKETS, SdoStatsSnapshot};

/// The content type of the text format, version 0.0.4.
pub const CONTENT_TYPE_TEXT: &str = "text/plain; version=0.0.4; charset=utf-8";

/// Clock ticks per second of the times in `/proc/self/stat`. It is the
/// kernel's USER_HZ, 100 on every architecture Linux runs on today
/// (prometheus/procfs hard-codes it for the same reason: asking sysconf
/// needs libc).
const USER_HZ: f64 = 100.0;

/// `/metrics`, at the root (where Prometheus looks), not under `/api/v1`.
pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(metrics))
}

/// The gateway's metrics for Prometheus.
///
/// Text exposition format 0.0.4: per bus its frames, bits, load, state and
/// losses; per node its SDO transactions, aborts, timeouts and latency
/// histogram; the WebSocket stream's clients and counts; the process's
/// memory, file descriptors, CPU time and start time.
#[utoipa::path(get, path = "/metrics", tag = "metrics",
    responses((status = 200, description = "The metrics, in the Prometheus text format (version 0.0.4)",
        content_type = "text/plain", body = String)))]
async fn metrics(State(state): State<AppState>) -> impl IntoResponse {
    ([(CONTENT_TYPE, CONTENT_TYPE_TEXT)], render(&state))
}

/// One bus's numbers, read at once.
struct BusSnapshot {
    name: String,
    kind: &'static str,
    spec: String,
    up: bool,
    /// The controller's error state; `None` while down.
    error_state: Option<crate::can::ErrorState>,
    counters: CounterSnapshot,
    rx_frames: u64,
    tx_frames: u64,
    bits: u64,
    load: f64,
    bitrate: u32,
    frame_log_lost: u64,
    tpdo_malformed: u64,
    nodes: Vec<NodeMetrics>,
    /// The network manager's machine, when the bus has one.
    machine: Option<crate::canopen::manager::MachineStatus>,
}

impl BusSnapshot {
    fn labels(&self) -> [(&'static str, &str); 1] {
        [("bus", &self.name)]
    }
}

/// The page: every family, in a fixed order.
pub fn render(state: &AppState) -> String {
    let buses: Vec<BusSnapshot> = state
        .gateway
        .buses()
        .map(|served| {
            // The same figures GET /buses shows.
            let traffic = served.traffic();
            BusSnapshot {
                name: served.name().to_string(),
                kind: served.kind().as_str(),
                spec: served.spec().to_string(),
                up: served.status().state.can_send(),
                error_state: served.status().state.error_state(),
                counters: served.counters(),
                rx_frames: traffic.rx_frames,
                tx_frames: traffic.tx_frames,
                bits: traffic.bits,
                load: served.load().load(),
                bitrate: served.load().bitrate(),
                frame_log_lost: served.frames().lost(),
                tpdo_malformed: served.values().malformed(),
                nodes: served.node_metrics(),
                machine: served.machine().ok().map(|machine| machine.status()),
            }
        })
        .collect();
    let mut out = Exposition::default();

    out.family(
        "candeck_build_info",
        Kind::Gauge,
        "The candeck version, as a label; always 1.",
    );
    out.sample(
        "candeck_build_info",
        &[("version", env!("CARGO_PKG_VERSION"))],
        1,
    );

    render_buses(&mut out, &buses);
    render_nodes(&mut out, &buses);
    render_machine(&mut out, &buses);
    render_alarms(&mut out, state);
    render_stream(&mut out, state);
    render_sparkplug(&mut out, state);
    render_http(&mut out, state);
    render_process(&mut out, &ProcessStats::read());
    out.text
}

fn render_buses(out: &mut Exposition, buses: &[BusSnapshot]) {
    out.family(
        "candeck_bus_info",
        Kind::Gauge,
        "A bus the gateway serves, with its kind and spec as labels; always 1.",
    );
    for bus in buses {
        out.sample(
            "candeck_bus_info",
            &[("bus", &bus.name), ("kind", bus.kind), ("spec", &bus.spec)],
            1,
        );
    }
    let per_bus =
        |out: &mut Exposition, name, kind, help, value: &dyn Fn(&BusSnapshot) -> Value| {
            out.family(name, kind, help);
            for bus in buses {
                out.sample(name, &bus.labels(), value(bus));
            }
        };
    per_bus(
        out,
        "candeck_bus_up",
        Kind::Gauge,
        "1 when frames flow on the bus (up or error passive), 0 when it is down or bus-off.",
        &|bus| Value::from(u64::from(bus.up)),
    );
    out.family(
        "candeck_bus_frames_total",
        Kind::Counter,
        "Frames on the bus seen by the gateway: direction=\"rx\" from other nodes, \"tx\" sent by the gateway.",
    );
    for bus in buses {
        for (direction, frames) in [("rx", bus.rx_frames), ("tx", bus.tx_frames)] {
            out.sample(
                "candeck_bus_frames_total",
                &[("bus", &bus.name), ("direction", direction)],
                frames,
            );
        }
    }
    per_bus(
        out,
        "candeck_bus_bits_total",
        Kind::Counter,
        "Bits of every frame on the bus, both ways, stuff bits not counted.",
        &|bus| Value::from(bus.bits),
    );
    per_bus(
        out,
        "candeck_bus_load_ratio",
        Kind::Gauge,
        "Share of the bit rate used over the last second (0 to 1), as GET /api/v1/buses shows it.",
        &|bus| Value::Float(bus.load),
    );
    per_bus(
        out,
        "candeck_bus_bitrate_bits_per_second",
        Kind::Gauge,
        "The nominal bit rate the load is measured against (--bitrate).",
        &|bus| Value::from(u64::from(bus.bitrate)),
    );
    per_bus(
        out,
        "candeck_bus_reconnects_total",
        Kind::Counter,
        "Times the bus's backend re-established a lost connection.",
        &|bus| Value::from(bus.counters.reconnects),
    );
    per_bus(
        out,
        "candeck_bus_malformed_total",
        Kind::Counter,
        "Malformed input from the bus's transport (a socketcand line that is no frame): counted and skipped.",
        &|bus| Value::from(bus.counters.malformed),
    );
    per_bus(
        out,
        "candeck_bus_error_frames_total",
        Kind::Counter,
        "Error frames reported by the CAN controller.",
        &|bus| Value::from(bus.counters.error_frames),
    );
    out.family(
        "candeck_bus_error_state",
        Kind::Gauge,
        "The error state of the gateway's CAN controller on the bus: 1 for the state it is in (error_active, error_passive, bus_off), 0 for the others; all 0 while the bus is down.",
    );
    for bus in buses {
        for state in [
            crate::can::ErrorState::ErrorActive,
            crate::can::ErrorState::ErrorPassive,
            crate::can::ErrorState::BusOff,
        ] {
            out.sample(
                "candeck_bus_error_state",
                &[("bus", &bus.name), ("state", state.as_str())],
                u64::from(bus.error_state == Some(state)),
            );
        }
    }
    per_bus(
        out,
        "candeck_bus_tx_error_counter",
        Kind::Gauge,
        "The CAN controller's transmit error counter (TEC), as last reported.",
        &|bus| Value::from(bus.counters.tec),
    );
    per_bus(
        out,
        "candeck_bus_rx_error_counter",
        Kind::Gauge,
        "The CAN controller's receive error counter (REC), as last reported.",
        &|bus| Value::from(bus.counters.rec),
    );
    per_bus(
        out,
        "candeck_bus_send_errors_total",
        Kind::Counter,
        "Frames the gateway could not send (bus down, write failed).",
        &|bus| Value::from(bus.counters.tx_errors),
    );
    per_bus(
        out,
        "candeck_bus_tx_queue_overflows_total",
        Kind::Counter,
        "Frames refused because their sender's transmit queue was full (on a virtual bus, any sender's).",
        &|bus| Value::from(bus.counters.tx_queue_overflows),
    );
    per_bus(
        out,
        "candeck_bus_receive_overruns_total",
        Kind::Counter,
        "Frames lost by the gateway's receivers that fell behind the bus.",
        &|bus| Value::from(bus.counters.rx_overruns),
    );
    per_bus(
        out,
        "candeck_frame_log_lost_frames_total",
        Kind::Counter,
        "Frames the recent-frames log (GET .../frames) missed because it fell behind the bus.",
        &|bus| Value::from(bus.frame_log_lost),
    );
    per_bus(
        out,
        "candeck_tpdo_malformed_frames_total",
        Kind::Counter,
        "TPDO frames that did not fit the mapping read from their node.",
        &|bus| Value::from(bus.tpdo_malformed),
    );
    per_bus(
        out,
        "candeck_nodes_known",
        Kind::Gauge,
        "Nodes in the bus's registry (heard, or found by a scan).",
        &|bus| Value::from(bus.nodes.len() as u64),
    );
    per_bus(
        out,
        "candeck_nodes_online",
        Kind::Gauge,
        "Nodes of the registry that are online.",
        &|bus| Value::from(bus.nodes.iter().filter(|node| node.online).count() as u64),
    );
}

/// The network manager: the machine state of each bus, and each node's
/// boot-ups.
fn render_machine(out: &mut Exposition, buses: &[BusSnapshot]) {
    out.family(
        "candeck_machine_state",
        Kind::Gauge,
        "The machine state of the bus's network manager: 3 ready, 2 booting, 1 degraded, 0 down.",
    );
    for bus in buses {
        if let Some(machine) = &bus.machine {
            out.sample(
                "candeck_machine_state",
                &bus.labels(),
                u64::from(machine.state.metric()),
            );
        }
    }
    type NodeValue = fn(&crate::canopen::manager::NodeStatus) -> u64;
    let families: [(&str, Kind, &str, NodeValue); 3] = [
        (
            "candeck_machine_node_boots_total",
            Kind::Counter,
            "Boot-ups of the node the network manager began (boot-up message, found, back, request, retry).",
            |node| node.boots,
        ),
        (
            "candeck_machine_node_boots_ok_total",
            Kind::Counter,
            "Boot-ups of the node that ended supervised (and started).",
            |node| node.boots_ok,
        ),
        (
            "candeck_machine_node_ready",
            Kind::Gauge,
            "1 while the network manager has the node ready, 0 otherwise.",
            |node| u64::from(node.state == crate::canopen::manager::NodeState::Ready),
        ),
    ];
    for (name, kind, help, value) in families {
        out.family(name, kind, help);
        for bus in buses {
            for node in bus.machine.iter().flat_map(|machine| &machine.nodes) {
                let id = node.id.to_string();
                out.sample(name, &[("bus", &bus.name), ("node", &id)], value(node));
            }
        }
    }
}

/// The alarms: how many are active, and how many wait for an
/// acknowledgement, by bus and severity (every severity, 0 included, so
/// that a rule can compare).
fn render_alarms(out: &mut Exposition, state: &AppState) {
    let alarms = state.gateway.alarm_book();
    let summaries: Vec<(&str, crate::gateway::AlarmSummary)> = state
        .gateway
        .buses()
        .map(|served| (served.name(), alarms.summary(Some(served.name()), None)))
        .collect();
    type Counts = fn(&crate::gateway::AlarmSummary) -> [u32; 4];
    let families: [(&str, &str, Counts); 2] = [
        (
            "candeck_alarms_active",
            "Alarms whose cause is present (active_unacknowledged or active_acknowledged), by severity.",
            |summary| summary.active,
        ),
        (
            "candeck_alarms_unacknowledged",
            "Alarms waiting for an acknowledgement (active_unacknowledged or cleared_unacknowledged), by severity.",
            |summary| summary.unacknowledged,
        ),
    ];
    for (name, help, counts) in families {
        out.family(name, Kind::Gauge, help);
        for (bus, summary) in &summaries {
            for (severity, count) in crate::gateway::Severity::ALL.iter().zip(counts(summary)) {
                out.sample(
                    name,
                    &[("bus", bus), ("severity", severity.name())],
                    u64::from(count),
                );
            }
        }
    }
}

fn render_nodes(out: &mut Exposition, buses: &[BusSnapshot]) {
    let per_node = |out: &mut Exposition, name, kind, help, value: &dyn Fn(&NodeMetrics) -> u64| {
        out.family(name, kind, help);
        for bus in buses {
            for node in &bus.nodes {
                let id = node.id.get().to_string();
                out.sample(name, &[("bus", &bus.name), ("node", &id)], value(node));
            }
        }
    };
    per_node(
        out,
        "candeck_node_online",
        Kind::Gauge,
        "1 while the node is online (heartbeat on time, or answering), 0 when it is not.",
        &|node| u64::from(node.online),
    );
    let sdo = |stats: fn(&SdoStatsSnapshot) -> u64| move |node: &NodeMetrics| stats(&node.sdo);
    per_node(
        out,
        "candeck_sdo_transactions_total",
        Kind::Counter,
        "SDO transfers to the node that ended, whatever the outcome.",
        &sdo(|sdo| sdo.transactions),
    );
    per_node(
        out,
        "candeck_sdo_aborts_total",
        Kind::Counter,
        "SDO transfers the device refused (abort from the device).",
        &sdo(|sdo| sdo.aborts),
    );
    per_node(
        out,
        "candeck_sdo_timeouts_total",
        Kind::Counter,
        "SDO transfers the device did not answer in time.",
        &sdo(|sdo| sdo.timeouts),
    );
    per_node(
        out,
        "candeck_sdo_protocol_errors_total",
        Kind::Counter,
        "SDO transfers the device answered against the protocol (the gateway aborted them).",
        &sdo(|sdo| sdo.protocol_errors),
    );
    per_node(
        out,
        "candeck_sdo_bus_errors_total",
        Kind::Counter,
        "SDO transfers the bus could not carry (down, closed).",
        &sdo(|sdo| sdo.bus_errors),
    );
    per_node(
        out,
        "candeck_sdo_abandoned_total",
        Kind::Counter,
        "SDO transfers their caller gave up halfway (aborted on the bus before the next one).",
        &sdo(|sdo| sdo.abandoned),
    );

    let name = "candeck_sdo_duration_seconds";
    out.family(
        name,
        Kind::Histogram,
        "Time of an SDO transfer from the node's turn in its queue to its end (answer, abort or timeout).",
    );
    let bounds: Vec<String> = LATENCY_BUCKETS
        .iter()
        .map(|bound| Value::Float(bound.as_secs_f64()).to_string())
        .chain(["+Inf".to_string()])
        .collect();
    for bus in buses {
        for node in &bus.nodes {
            let id = node.id.get().to_string();
            let latency = &node.sdo.latency;
            for (bound, count) in bounds.iter().zip(latency.cumulative) {
                out.sample(
                    "candeck_sdo_duration_seconds_bucket",
                    &[("bus", &bus.name), ("node", &id), ("le", bound)],
                    count,
                );
            }
            let labels = [("bus", bus.name.as_str()), ("node", &id)];
            out.sample(
                "candeck_sdo_duration_seconds_sum",
                &labels,
                Value::Float(latency.sum.as_secs_f64()),
            );
            out.sample(
                "candeck_sdo_duration_seconds_count",
                &labels,
                latency.count(),
            );
        }
    }
}

fn render_stream(out: &mut Exposition, state: &AppState) {
    let counters = &state.stream_counters;
    for (name, kind, help, counter) in [
        (
            "candeck_stream_clients",
            Kind::Gauge,
            "WebSocket clients of /api/v1/stream connected now.",
            &counters.clients,
        ),
        (
            "candeck_stream_messages_total",
            Kind::Counter,
            "Messages sent to WebSocket clients.",
            &counters.messages,
        ),
        (
            "candeck_stream_coalesced_total",
            Kind::Counter,
            "Values a WebSocket client never saw because a newer one replaced them first.",
            &counters.coalesced,
        ),
        (
            "candeck_stream_lagged_total",
            Kind::Counter,
            "Events and frames a WebSocket client lost because it fell behind (each reported to it as lagged).",
            &counters.lagged,
        ),
    ] {
        out.family(name, kind, help);
        out.sample(name, &[], counter.load(Ordering::Relaxed));
    }
}

/// The Sparkplug B edge node's figures (docs/sparkplug.md), when it runs.
fn render_sparkplug(out: &mut Exposition, state: &AppState) {
    let stats = &state.gateway.edge_node_stats();
    if !stats.enabled.load(Ordering::Relaxed) {
        return;
    }
    for (name, help, flag) in [
        (
            "candeck_sparkplug_connected",
            "1 while the Sparkplug edge node is connected to its MQTT broker.",
            &stats.connected,
        ),
        (
            "candeck_sparkplug_publishing",
            "1 while it publishes (connected, births sent, the primary host online).",
            &stats.publishing,
        ),
    ] {
        out.family(name, Kind::Gauge, help);
        out.sample(name, &[], u64::from(flag.load(Ordering::Relaxed)));
    }
    out.family(
        "candeck_sparkplug_queued_messages",
        Kind::Gauge,
        "Data messages in the store-and-forward queue now.",
    );
    out.sample(
        "candeck_sparkplug_queued_messages",
        &[],
        stats.queued.load(Ordering::Relaxed),
    );
    for (name, help, counter) in [
        (
            "candeck_sparkplug_connects_total",
            "Connections made to the MQTT broker.",
            &stats.connects,
        ),
        (
            "candeck_sparkplug_messages_total",
            "Sparkplug messages published.",
            &stats.messages,
        ),
        (
            "candeck_sparkplug_metrics_total",
            "Metrics in the published messages.",
            &stats.metrics,
        ),
        (
            "candeck_sparkplug_historical_messages_total",
            "Messages sent from the store-and-forward queue (historical).",
            &stats.historical,
        ),
        (
            "candeck_sparkplug_dropped_messages_total",
            "Messages dropped from the full store-and-forward queue (the oldest first).",
            &stats.dropped,
        ),
        (
            "candeck_sparkplug_lost_changes_total",
            "TPDO frames the edge node fell too far behind to report one by one (it reported their devices' newest values instead).",
            &stats.lost_changes,
        ),
        (
            "candeck_sparkplug_commands_total",
            "NCMD and DCMD command metrics received.",
            &stats.commands,
        ),
        (
            "candeck_sparkplug_commands_failed_total",
            "Of those, refused or failed.",
            &stats.commands_failed,
        ),
    ] {
        out.family(name, Kind::Counter, help);
        out.sample(name, &[], counter.load(Ordering::Relaxed));
    }
}

fn render_http(out: &mut Exposition, state: &AppState) {
    let refusals = &state.connection_refusals;
    let name = "candeck_http_connections_refused_total";
    out.family(
        name,
        Kind::Counter,
        "HTTP connections the connection limit (max_connections) turned away: answered 503 on a reserve place (answered_503), closed as soon as accepted (closed), pushed out of the reserve by a newer one (evicted).",
    );
    for (how, counter) in [
        ("answered_503", &refusals.answered_503),
        ("closed", &refusals.closed),
        ("evicted", &refusals.evicted),
    ] {
        out.sample(name, &[("how", how)], counter.load(Ordering::Relaxed));
    }
}

fn render_process(out: &mut Exposition, process: &ProcessStats) {
    let families: [(&str, Kind, &str, Option<Value>); 5] = [
        (
            "process_resident_memory_bytes",
            Kind::Gauge,
            "Resident memory size in bytes (VmRSS).",
            process.resident_bytes.map(Value::from),
        ),
        (
            "candeck_process_resident_memory_peak_bytes",
            Kind::Gauge,
            "Peak resident memory size in bytes since the process started (VmHWM).",
            process.peak_resident_bytes.map(Value::from),
        ),
        (
            "process_open_fds",
            Kind::Gauge,
            "Open file descriptors.",
            process.open_fds.map(Value::from),
        ),
        (
            "process_cpu_seconds_total",
            Kind::Counter,
            "User and system CPU time spent, in seconds.",
            process.cpu_seconds.map(Value::Float),
        ),
        (
            "process_start_time_seconds",
            Kind::Gauge,
            "Start time of the process since the Unix epoch, in seconds.",
            process.start_time_seconds.map(Value::Float),
        ),
    ];
    // A system without /proc has none of them: the families are left out,
    // not shown empty or as zero.
    for (name, kind, help, value) in families {
        if let Some(value) = value {
            out.family(name, kind, help);
            out.sample(name, &[], value);
        }
    }
}

/// What `/proc` tells of this process; `None` for what it does not (no
/// `/proc`, another layout).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct ProcessStats {
    resident_bytes: Option<u64>,
    peak_resident_bytes: Option<u64>,
    open_fds: Option<u64>,
    cpu_seconds: Option<f64>,
    start_time_seconds: Option<f64>,
}

impl ProcessStats {
    /// Reads `/proc/self`. These files are made by the kernel on the
    /// spot, in memory: reading them in the handler does not block on a
    /// disk.
    fn read() -> Self {
        let status = std::fs::read_to_string("/proc/self/status").ok();
        let stat = std::fs::read_to_string("/proc/self/stat").ok();
        let boot = std::fs::read_to_string("/proc/stat").ok();
        let times = stat.as_deref().and_then(parse_stat);
        let boot_time = boot.as_deref().and_then(parse_boot_time);
        Self {
            resident_bytes: status.as_deref().and_then(|s| status_kb(s, "VmRSS")),
            peak_resident_bytes: status.as_deref().and_then(|s| status_kb(s, "VmHWM")),
            open_fds: std::fs::read_dir("/proc/self/fd")
                .ok()
                .map(|entries| entries.count() as u64),
            cpu_seconds: times.map(|times| times.cpu_seconds),
            start_time_seconds: times
                .zip(boot_time)
                .map(|(times, boot)| boot as f64 + times.start_after_boot_seconds),
        }
    }
}

/// A `Name:   1234 kB` line of `/proc/self/status`, in bytes.
fn status_kb(status: &str, key: &str) -> Option<u64> {
    status.lines().find_map(|line| {
        let rest = line.strip_prefix(key)?.strip_prefix(':')?;
        let mut words = rest.split_whitespace();
        let kb: u64 = words.next()?.parse().ok()?;
        (words.next() == Some("kB")).then_some(kb.checked_mul(1024)?)
    })
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct StatTimes {
    cpu_seconds: f64,
    start_after_boot_seconds: f64,
}

/// utime, stime and starttime of `/proc/self/stat` (fields 14, 15 and 22,
/// proc(5)). The command name (field 2) is in parentheses and may hold
/// spaces and parentheses itself: the fields are counted after the last
/// `)`.
fn parse_stat(stat: &str) -> Option<StatTimes> {
    let (_, after_name) = stat.rsplit_once(')')?;
    let fields: Vec<&str> = after_name.split_whitespace().collect();
    // `fields[0]` is field 3 (state).
    let field = |n: usize| -> Option<u64> { fields.get(n - 3)?.parse().ok() };
    let (utime, stime, start) = (field(14)?, field(15)?, field(22)?);
    Some(StatTimes {
        cpu_seconds: (utime + stime) as f64 / USER_HZ,
        start_after_boot_seconds: start as f64 / USER_HZ,
    })
}

/// The `btime` line of `/proc/stat`: the boot time, Unix seconds.
fn parse_boot_time(stat: &str) -> Option<u64> {
    stat.lines()
        .find_map(|line| line.strip_prefix("btime ")?.trim().parse().ok())
}

/// A metric family's type.
#[derive(Debug, Clone, Copy)]
enum Kind {
    Counter,
    Gauge,
    Histogram,
}

impl Kind {
    fn as_str(self) -> &'static str {
        match self {
            Self::Counter => "counter",
            Self::Gauge => "gauge",
            Self::Histogram => "histogram",
        }
    }
}

/// A sample's value: counts exactly as integers (an `f64` would round them
/// past 2^53), the rest as floats.
#[derive(Debug, Clone, Copy)]
enum Value {
    Int(u64),
    Float(f64),
}

impl From<u64> for Value {
    fn from(value: u64) -> Self {
        Self::Int(value)
    }
}

impl fmt::Display for Value {
    /// Go's float syntax as Prometheus reads it: `+Inf`, `-Inf`, `NaN`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Int(value) => write!(f, "{value}"),
            Self::Float(value) if value.is_nan() => f.write_str("NaN"),
            Self::Float(value) if value == f64::INFINITY => f.write_str("+Inf"),
            Self::Float(value) if value == f64::NEG_INFINITY => f.write_str("-Inf"),
            Self::Float(value) => write!(f, "{value}"),
        }
    }
}

/// The page being written.
#[derive(Default)]
struct Exposition {
    text: String,
}

impl Exposition {
    /// `# HELP` and `# TYPE` of a family; its samples follow, together.
    fn family(&mut self, name: &str, kind: Kind, help: &str) {
        let help = help.replace('\\', "\\\\").replace('\n', "\\n");
        // Writing to a String cannot fail.
        let _ = writeln!(self.text, "# HELP {name} {help}");
        let _ = writeln!(self.text, "# TYPE {name} {}", kind.as_str());
    }

    fn sample(&mut self, name: &str, labels: &[(&str, &str)], value: impl Into<Value>) {
        self.text.push_str(name);
        if !labels.is_empty() {
            self.text.push('{');
            for (i, (label, value)) in labels.iter().enumerate() {
                if i > 0 {
                    self.text.push(',');
                }
                self.text.push_str(label);
                self.text.push_str("=\"");
                for c in value.chars() {
                    match c {
                        '\\' => self.text.push_str("\\\\"),
                        '"' => self.text.push_str("\\\""),
                        '\n' => self.text.push_str("\\n"),
                        c => self.text.push(c),
                    }
                }
                self.text.push('"');
            }
            self.text.push('}');
        }
        let _ = writeln!(self.text, " {}", value.into());
    }
}

#[cfg(test)]
mod tests;
