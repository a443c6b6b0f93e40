//! Data logger channels × rate against REST reads (issue 22): how many
//! channels at what period the logger samples while REST clients read the
//! same nodes, and what that does to the REST reads' latency.
//!
//! The method is `rest_api`'s: the gateway is `candeck serve`'s own code in
//! process (`virtual:demo?bitrate=unlimited`, its three devices identified
//! by a scan, `api::app` on a loopback port, a single-threaded runtime on a
//! thread of its own, as in the binary); the clients run on another thread:
//! N HTTP/1.1 keep-alive connections, each sending one request and reading
//! its whole answer before the next, walking `rest_api`'s six objects of
//! nodes 1–3. For each logger level (none, then 1, 4 and 16 channels of
//! node 1 at 100 Hz and at 1 kHz, by SDO: the demo UMC sends no TPDO until
//! started) a logger is made with `POST /loggers`, given `--warmup` seconds,
//! then the REST reads are measured for `--seconds`; then the logger's
//! status gives the rows it sampled in that window and the grid points it
//! missed, and it is deleted.
//!
//! Run: `cargo bench --bench logger` (`-- --seconds N --warmup N`,
//! defaults 3 and 1; a smoke run, `CANDECK_BENCH_SMOKE`, has 0.2 and 0.05,
//! and three of the seven logger levels). A
//! level with a failed REST read, none answered, or a logger read error
//! ends the run with status 1 after its row.

mod common;

use common::Options;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use candeck::api::{AppState, app};
use candeck::gateway::EdsCatalog;
use candeck::gateway::RegistryConfig;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// The REST objects (`rest_api`'s mix): (node, index, sub).
const MIX: [(u8, u16, u8); 6] = [
    (1, 0x6041, 0),
    (2, 0x6041, 0),
    (3, 0x1001, 0),
    (1, 0x6064, 0),
    (2, 0x6064, 0),
    (3, 0x1018, 1),
];

/// Sixteen readable numbers of node 1 (the UMC1BDS32): its two axes'
/// status, position, velocity, torque and mode, and its identity.
const CHANNELS: [(u16, u8); 16] = [
    (0x6064, 0),
    (0x606C, 0),
    (0x6041, 0),
    (0x6077, 0),
    (0x6061, 0),
    (0x6864, 0),
    (0x686C, 0),
    (0x6841, 0),
    (0x6877, 0),
    (0x6861, 0),
    (0x1001, 0),
    (0x1018, 1),
    (0x1018, 2),
    (0x1018, 3),
    (0x1018, 4),
    (0x1017, 0),
];

const CLIENTS: [usize; 2] = [1, 16];

/// One keep-alive connection, one request at a time.
struct Connection {
    stream: TcpStream,
    buffer: Vec<u8>,
}

impl Connection {
    async fn open(address: SocketAddr) -> Self {
        let stream = TcpStream::connect(address).await.expect("connect");
        stream.set_nodelay(true).expect("nodelay");
        Self {
            stream,
            buffer: Vec::with_capacity(4096),
        }
    }

    /// Sends a request and reads the whole answer: status and body.
    async fn send(&mut self, request: &[u8]) -> (u16, Vec<u8>) {
        self.stream.write_all(request).await.expect("send request");
        loop {
            if let Some((status, head, length)) = complete_response(&self.buffer) {
                let body = self.buffer[head..length].to_vec();
                self.buffer.drain(..length);
                return (status, body);
            }
            let read = self
                .stream
                .read_buf(&mut self.buffer)
                .await
                .expect("read response");
            assert!(read > 0, "the server closed a keep-alive connection");
        }
    }

    async fn json(&mut self, method: &str, path: &str, body: &str) -> (u16, serde_json::Value) {
        let request = format!(
            "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        );
        let (status, body) = self.send(request.as_bytes()).await;
        (status, serde_json::from_slice(&body).expect("JSON answer"))
    }
}

/// Status, head length and whole length of the answer at the start of
/// `buffer`, once all of it is there.
fn complete_response(buffer: &[u8]) -> Option<(u16, usize, usize)> {
    let head_end = buffer.windows(4).position(|w| w == b"\r\n\r\n")? + 4;
    let head = std::str::from_utf8(&buffer[..head_end]).expect("ASCII head");
    let status = head
        .strip_prefix("HTTP/1.1 ")
        .and_then(|rest| rest.get(..3))
        .and_then(|code| code.parse().ok())
        .unwrap_or_else(|| panic!("response head: {head}"));
    let body = head
        .lines()
        .filter_map(|line| line.split_once(':'))
        .find(|(name, _)| name.trim().eq_ignore_ascii_case("content-length"))
        .and_then(|(_, value)| value.trim().parse::<usize>().ok())
        .expect("Content-Length");
    (buffer.len() >= head_end + body).then_some((status, head_end, head_end + body))
}

/// The gateway on a thread and runtime of its own; its address.
fn spawn_gateway() -> SocketAddr {
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let thread = std::thread::Builder::new().name("gateway".into());
    let _ = thread.spawn(move || {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        runtime.block_on(async move {
            let served = candeck::emulator::open_bus(
                "demo",
                &"virtual:demo?bitrate=unlimited".parse().expect("spec"),
                Arc::new(EdsCatalog::builtin().expect("catalog")),
                RegistryConfig::default(),
                500_000,
            )
            .await
            .expect("demo bus");
            let nodes = served.scan().await.expect("scan");
            assert_eq!(nodes.len(), 3, "the demo's three nodes");
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                .await
                .expect("bind");
            ready_tx
                .send(listener.local_addr().expect("address"))
                .expect("ready");
            axum::serve(listener, app(AppState::new([served])))
                .await
                .expect("serve");
        });
    });
    ready_rx.recv().expect("gateway thread")
}

/// What the REST clients saw.
struct Rest {
    /// Latencies (ns, sorted) of the reads in the window.
    latencies: Vec<u64>,
    /// Reads failed in the window.
    errors: u64,
    /// Reads answered 200 and failed, the last one that ended after the
    /// window included.
    answered: u64,
    failed: u64,
}

/// The REST reads over the window, one client on each of `connections`.
async fn rest_load(connections: Vec<Connection>, from: Instant, until: Instant) -> Rest {
    let requests: Arc<Vec<Vec<u8>>> = Arc::new(
        MIX.iter()
            .map(|(node, index, sub)| {
                format!("GET /api/v1/buses/demo/nodes/{node}/od/0x{index:04X}/{sub} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
                    .into_bytes()
            })
            .collect(),
    );
    let mut workers = tokio::task::JoinSet::new();
    for (client, mut connection) in connections.into_iter().enumerate() {
        let requests = requests.clone();
        workers.spawn(async move {
            let mut latencies = Vec::new();
            let mut errors = 0u64;
            let mut answered_and_failed = [0u64; 2];
            let mut n = client;
            loop {
                let began = Instant::now();
                if began >= until {
                    break;
                }
                let (status, _) = connection.send(&requests[n % requests.len()]).await;
                n += 1;
                let ended = Instant::now();
                answered_and_failed[usize::from(status != 200)] += 1;
                if began >= from && ended <= until {
                    if status == 200 {
                        latencies.push((ended - began).as_nanos() as u64);
                    } else {
                        errors += 1;
                    }
                }
            }
            (latencies, errors, answered_and_failed)
        });
    }
    let mut rest = Rest {
        latencies: Vec::new(),
        errors: 0,
        answered: 0,
        failed: 0,
    };
    while let Some(joined) = workers.join_next().await {
        let (mut some, errors, [answered, failed]) = joined.expect("client");
        rest.latencies.append(&mut some);
        rest.errors += errors;
        rest.answered += answered;
        rest.failed += failed;
    }
    rest.latencies.sort_unstable();
    rest
}

fn percentile_us(latencies: &[u64], p: f64) -> f64 {
    if latencies.is_empty() {
        return f64::NAN;
    }
    let rank = ((p / 100.0) * latencies.len() as f64).ceil() as usize;
    latencies[rank.clamp(1, latencies.len()) - 1] as f64 / 1_000.0
}

fn logger_body(channels: usize, period_ms: u64, duration_s: u64) -> String {
    let channels: Vec<String> = CHANNELS[..channels]
        .iter()
        .map(|(index, sub)| {
            format!(r#"{{"bus":"demo","node":1,"index":"0x{index:04X}","sub":{sub}}}"#)
        })
        .collect();
    format!(
        r#"{{"channels":[{}],"period_ms":{period_ms},"duration_s":{duration_s}}}"#,
        channels.join(",")
    )
}

/// Runs and prints one level; why it failed, if it did.
async fn level(
    address: SocketAddr,
    logger: Option<(usize, u64)>,
    clients: usize,
    options: Options,
) -> Option<String> {
    let mut control = Connection::open(address).await;
    // The REST clients' connections, open before the window.
    let mut connections = Vec::new();
    for _ in 0..clients {
        connections.push(Connection::open(address).await);
    }
    let total = options.warmup + options.measure;
    let id = match logger {
        Some((channels, period_ms)) => {
            let body = logger_body(channels, period_ms, total.as_secs() + 5);
            let (status, created) = control.json("POST", "/api/v1/loggers", &body).await;
            assert_eq!(status, 201, "{created}");
            Some(created["id"].as_u64().expect("id"))
        }
        None => None,
    };
    let start = Instant::now();
    let from = start + options.warmup;
    let until = from + options.measure;
    tokio::time::sleep_until(from.into()).await;
    let before = match id {
        Some(id) => Some(
            control
                .json("GET", &format!("/api/v1/loggers/{id}"), "")
                .await
                .1,
        ),
        None => None,
    };
    let rest = rest_load(connections, from, until).await;
    let (latencies, errors) = (&rest.latencies, rest.errors);
    let seconds = options.measure.as_secs_f64();
    let (sampled, missed, channel_errors) = match (id, before) {
        (Some(id), Some(before)) => {
            let (_, after) = control
                .json("GET", &format!("/api/v1/loggers/{id}"), "")
                .await;
            let delta =
                |key: &str| after[key].as_u64().unwrap_or(0) - before[key].as_u64().unwrap_or(0);
            let errors: u64 = after["channels"]
                .as_array()
                .map(|list| list.iter().map(|c| c["errors"].as_u64().unwrap_or(0)).sum())
                .unwrap_or(0);
            let (status, _) = control
                .json("DELETE", &format!("/api/v1/loggers/{id}"), "")
                .await;
            assert_eq!(status, 200);
            (Some(delta("samples")), Some(delta("missed")), errors)
        }
        _ => (None, None, 0),
    };
    let what = match logger {
        Some((channels, period_ms)) => format!("{channels} ch × {} Hz", 1000 / period_ms),
        None => "no logger".to_string(),
    };
    let rows = |v: Option<u64>| v.map_or("".to_string(), |n| format!("{:.0}", n as f64 / seconds));
    println!(
        "| {what} | {clients} | {} | {} | {} | {:.0} | {:.0} | {:.0} | {} | {channel_errors} |",
        rows(sampled),
        rows(missed),
        sampled.map_or("".to_string(), |n| format!(
            "{:.0}",
            n as f64 / seconds * logger.map_or(0.0, |(c, _)| c as f64)
        )),
        latencies.len() as f64 / seconds,
        percentile_us(latencies, 50.0),
        percentile_us(latencies, 99.0),
        errors,
    );
    (rest.failed > 0 || rest.answered == 0 || channel_errors > 0).then(|| {
        format!(
            "{what}, {clients} REST clients: {} REST reads failed, {} answered; {channel_errors} logger read errors",
            rest.failed, rest.answered
        )
    })
}

fn main() {
    common::announce_smoke("logger");
    let options = Options::from_args(
        common::pick(Duration::from_secs(1), Duration::from_millis(50)),
        common::pick(Duration::from_secs(3), Duration::from_millis(200)),
    );
    let address = spawn_gateway();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    println!(
        "gateway on http://{address}/ (demo bus), {} s warm-up and {} s measured per level",
        options.warmup.as_secs_f64(),
        options.measure.as_secs_f64()
    );
    println!();
    println!(
        "| logger | REST clients | logger rows/s | missed/s | SDO reads/s of the logger | REST reads/s | REST p50 µs | REST p99 µs | REST errors | logger read errors |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let levels: [Option<(usize, u64)>; 7] = [
        None,
        Some((1, 10)),
        Some((4, 10)),
        Some((16, 10)),
        Some((1, 1)),
        Some((4, 1)),
        Some((16, 1)),
    ];
    // A smoke run: no logger, the most channels at each rate.
    let smoke_levels = [levels[0], levels[3], levels[6]];
    let levels = common::pick(&levels[..], &smoke_levels[..]);
    let mut failures = Vec::new();
    for clients in CLIENTS {
        for &logger in levels {
            failures.extend(runtime.block_on(level(address, logger, clients, options)));
        }
    }
    common::exit_on_failures("logger", &failures);
}
