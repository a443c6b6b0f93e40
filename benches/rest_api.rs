//! REST object dictionary reads per second and their latency, over real
//! HTTP/1.1 keep-alive connections on loopback, and what the gateway adds
//! to one SDO (issue 5).
//!
//! The gateway is `candeck serve`'s own: the demo bus (`virtual:demo`, its
//! three virtual devices and registry) and [`candeck::api::app`] served by
//! axum, on a single-threaded tokio runtime as in the binary, on a thread of
//! its own. The clients run on another thread and runtime: N connections,
//! each sending one request and reading its whole response before the next
//! (no pipelining), with a minimal HTTP/1.1 client written here.
//!
//! Rows:
//! - `GET .../nodes/1/od/0x6041/0`: every client reads node 1's statusword;
//! - mix: client i reads nodes 1–3 (UMC1BDS32, JMC, UIO1LED) in turn, six
//!   objects, starting at the i-th;
//! - `GET /api/v1/health`: no SDO at all, the gateway's HTTP door alone;
//! - bare axum `GET /api/v1/health`: the same request answered by a router
//!   of one route and no layer, served the same way on the same thread: the
//!   HTTP stack's (and this machine's) own floor, so that the door's cost is
//!   the difference and a slower machine is told from a slower door;
//! - bare SDO: the same reads through `SdoChannel`s of the bench's own
//!   (the gateway keeps its registry's to itself) on another attachment to
//!   the bus's hub, the same SDO client, on the server's runtime, without HTTP.
//!
//! Each level runs `--warmup` seconds unmeasured, then `--seconds` measured
//! (defaults 1 and 3; a smoke run, `CANDECK_BENCH_SMOKE`, has 0.05 and 0.1,
//! and 1 and 16 clients only).
//! Every answer must be 200: a level with a failed request, or none
//! answered at all, ends the run with status 1 after its row. The requests are
//! sent to the gateway's bound address (`Host: 127.0.0.1:PORT`), as a client
//! of it does: the gateway answers other names 421 (`api::host`).
//!
//! The server thread's CPU per read is its CPU time over the window divided
//! by the reads completed in it (`/proc/<pid>/task/<tid>/stat`, 10 ms
//! ticks): the gateway's cost of one read, whatever the load.
//!
//! Run: `cargo bench --bench rest_api` (or `scripts/bench`).

mod common;

use common::Options;
use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use candeck::api::{AppState, app};
use candeck::canopen::NodeId;
use candeck::gateway::EdsCatalog;
use candeck::gateway::RegistryConfig;
use candeck::gateway::SdoChannel;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Clients per level; a smoke run leaves out 64 (the same code as 16).
const LEVELS: [usize; 3] = [1, 16, 64];
const SMOKE_LEVELS: [usize; 2] = [1, 16];

/// The objects of the mix: (node, index, sub), read through REST as
/// `/api/v1/buses/demo/nodes/{node}/od/0x{index:04X}/{sub}`.
const MIX: [(u8, u16, u8); 6] = [
    (1, 0x6041, 0), // UMC1BDS32 axis 1 statusword
    (2, 0x6041, 0), // JMC statusword
    (3, 0x1001, 0), // UIO1LED error register
    (1, 0x6064, 0), // UMC1BDS32 axis 1 position actual value
    (2, 0x6064, 0), // JMC position actual value
    (3, 0x1018, 1), // UIO1LED vendor id
];
const SINGLE: [(u8, u16, u8); 1] = [(1, 0x6041, 0)];

/// What one level measured.
struct Figures {
    completed: u64,
    errors: u64,
    /// Requests answered 200 and requests failed in the whole level,
    /// warm-up and requests across the window's edges included.
    answered_in_level: u64,
    failed_in_level: u64,
    seconds: f64,
    /// Every measured request's latency, in ns, sorted.
    latencies: Vec<u64>,
    /// CPU time of the server's thread and of the clients' thread during
    /// the measured window, as a fraction of the window.
    server_cpu: f64,
    client_cpu: f64,
}

impl Figures {
    fn per_second(&self) -> f64 {
        self.completed as f64 / self.seconds
    }

    fn percentile_us(&self, p: f64) -> f64 {
        if self.latencies.is_empty() {
            return f64::NAN;
        }
        let rank = ((p / 100.0) * self.latencies.len() as f64).ceil() as usize;
        self.latencies[rank.clamp(1, self.latencies.len()) - 1] as f64 / 1_000.0
    }

    /// CPU time of the server's thread per request completed, µs.
    fn server_cpu_per_request_us(&self) -> f64 {
        self.server_cpu * self.seconds / self.completed as f64 * 1e6
    }

    /// Prints the row; why the level failed, if it did.
    fn row(&self, label: &str, clients: usize) -> Option<String> {
        println!(
            "| {label} | {clients} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} % | {:.1} | {:.0} % | {} |",
            self.per_second(),
            self.percentile_us(50.0),
            self.percentile_us(90.0),
            self.percentile_us(99.0),
            self.latencies
                .last()
                .map_or(f64::NAN, |&ns| ns as f64 / 1_000.0),
            self.server_cpu * 100.0,
            self.server_cpu_per_request_us(),
            self.client_cpu * 100.0,
            self.errors,
        );
        if self.failed_in_level > 0 || self.answered_in_level == 0 {
            Some(format!(
                "{label}, {clients} clients: {} requests failed, {} answered (warm-up included)",
                self.failed_in_level, self.answered_in_level
            ))
        } else {
            None
        }
    }
}

/// CPU time (user + system) of one thread, from `/proc/<pid>/task/<tid>/stat`.
fn thread_cpu(task: &str) -> Duration {
    let stat = std::fs::read_to_string(format!("/proc/{task}/stat")).unwrap_or_default();
    // After the command name (in parentheses, may contain spaces) come the
    // state (field 3), ...; utime and stime are fields 14 and 15, in clock
    // ticks (USER_HZ, 100 on Linux).
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest.split_whitespace().collect())
        .unwrap_or_default();
    let field = |n: usize| {
        fields
            .get(n - 3)
            .and_then(|f| f.parse::<u64>().ok())
            .unwrap_or(0)
    };
    let ticks = field(14) + field(15);
    Duration::from_millis(ticks * 10)
}

/// The `<pid>/task/<tid>` of the calling thread.
fn this_task() -> String {
    std::fs::read_link("/proc/thread-self")
        .map(|path| path.display().to_string())
        .unwrap_or_default()
}

/// Runs `clients` loops of `op` (client `i` runs `op(i, n)` for its n-th
/// request) for warm-up plus measure, on the current runtime, and returns
/// what the measured window saw. `op` returns whether the request
/// succeeded.
async fn load<F, Fut>(clients: usize, options: Options, server_task: &str, op: F) -> Figures
where
    F: Fn(usize, usize) -> Fut + Clone + 'static,
    Fut: Future<Output = bool> + 'static,
{
    let start = Instant::now();
    let from = start + options.warmup;
    let until = from + options.measure;
    let client_task = this_task();
    let mut workers = tokio::task::JoinSet::new();
    for client in 0..clients {
        let op = op.clone();
        workers.spawn_local(async move {
            let mut latencies = Vec::new();
            let mut errors = 0u64;
            let mut answered_and_failed = [0u64; 2];
            let mut n = client;
            loop {
                let began = Instant::now();
                if began >= until {
                    break;
                }
                let ok = op(client, n).await;
                n += 1;
                let ended = Instant::now();
                answered_and_failed[usize::from(!ok)] += 1;
                // Requests that began after the warm-up and ended within
                // the window.
                if began >= from && ended <= until {
                    if ok {
                        latencies.push((ended - began).as_nanos() as u64);
                    } else {
                        errors += 1;
                    }
                }
            }
            (latencies, errors, answered_and_failed)
        });
    }
    tokio::time::sleep_until(from.into()).await;
    let cpu_from = (thread_cpu(server_task), thread_cpu(&client_task));
    tokio::time::sleep_until(until.into()).await;
    let cpu_until = (thread_cpu(server_task), thread_cpu(&client_task));
    let mut latencies = Vec::new();
    let mut errors = 0;
    let mut in_level = [0u64; 2];
    while let Some(joined) = workers.join_next().await {
        let (mut some, failed, [answered, failed_in_level]) = joined.expect("client task");
        latencies.append(&mut some);
        errors += failed;
        in_level[0] += answered;
        in_level[1] += failed_in_level;
    }
    latencies.sort_unstable();
    let seconds = options.measure.as_secs_f64();
    Figures {
        completed: latencies.len() as u64,
        errors,
        answered_in_level: in_level[0],
        failed_in_level: in_level[1],
        seconds,
        latencies,
        server_cpu: (cpu_until.0 - cpu_from.0).as_secs_f64() / seconds,
        client_cpu: (cpu_until.1 - cpu_from.1).as_secs_f64() / seconds,
    }
}

/// One keep-alive HTTP/1.1 connection, one request at a time.
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

    /// Sends a GET and reads the whole response; returns its status.
    async fn get(&mut self, request: &[u8]) -> u16 {
        self.stream.write_all(request).await.expect("send request");
        loop {
            if let Some((status, length)) = complete_response(&self.buffer) {
                self.buffer.drain(..length);
                return status;
            }
            let read = self
                .stream
                .read_buf(&mut self.buffer)
                .await
                .expect("read response");
            assert!(read > 0, "the server closed a keep-alive connection");
        }
    }
}

/// The status and whole length of the response at the start of `buffer`,
/// once all of it is there.
fn complete_response(buffer: &[u8]) -> Option<(u16, usize)> {
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
        .expect("Content-Length (no chunked answers from axum for JSON)");
    (buffer.len() >= head_end + body).then_some((status, head_end + body))
}

/// A GET of `path` sent to `address`, named in `Host` as a client names it.
fn get_request(address: SocketAddr, path: &str) -> Vec<u8> {
    format!("GET {path} HTTP/1.1\r\nHost: {address}\r\n\r\n").into_bytes()
}

fn od_path(&(node, index, sub): &(u8, u16, u8)) -> String {
    format!("/api/v1/buses/demo/nodes/{node}/od/0x{index:04X}/{sub}")
}

/// Runs `clients` HTTP clients, each on its own connection, walking
/// `paths` from its own offset.
async fn http_level(
    address: SocketAddr,
    paths: &[String],
    clients: usize,
    options: Options,
    server_task: &str,
) -> Figures {
    let requests: Arc<Vec<Vec<u8>>> =
        Arc::new(paths.iter().map(|p| get_request(address, p)).collect());
    let mut connections = Vec::new();
    for _ in 0..clients {
        connections.push(Arc::new(tokio::sync::Mutex::new(
            Connection::open(address).await,
        )));
    }
    let connections = Arc::new(connections);
    load(clients, options, server_task, move |client, n| {
        let requests = requests.clone();
        let connections = connections.clone();
        async move {
            let request = &requests[n % requests.len()];
            connections[client].lock().await.get(request).await == 200
        }
    })
    .await
}

/// What the clients ask of the server's thread.
struct BareSdo {
    objects: Vec<(u8, u16, u8)>,
    clients: usize,
    options: Options,
    answer: std::sync::mpsc::Sender<Figures>,
}

/// The gateway on a thread and single-threaded runtime of its own, as in
/// `candeck serve`. Returns its address, its thread's `/proc` task, and a
/// way to run bare SDO loads on its runtime.
fn spawn_gateway() -> (
    SocketAddr,
    SocketAddr,
    String,
    tokio::sync::mpsc::UnboundedSender<BareSdo>,
) {
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    // Named, so that `perf report --comms gateway` shows its time alone.
    let thread = std::thread::Builder::new().name("gateway".into());
    let _ = thread.spawn(move || {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        let local = tokio::task::LocalSet::new();
        local.block_on(&runtime, async move {
            let served = candeck::emulator::open_bus(
                "demo",
                // The software is measured, not the wire.
                &"virtual:demo?bitrate=unlimited".parse().expect("spec"),
                Arc::new(EdsCatalog::builtin().expect("catalog")),
                RegistryConfig::default(),
                500_000,
            )
            .await
            .expect("demo bus");
            let nodes = served.scan().await.expect("scan");
            assert_eq!(nodes.len(), 3, "the demo's three nodes");
            let channels: Vec<SdoChannel> = (1..=3)
                .map(|id| {
                    SdoChannel::new(
                        served.hub().expect("a virtual bus").attach(),
                        NodeId::new(id).expect("id"),
                        candeck::canopen::sdo::ClientConfig::default(),
                    )
                })
                .collect();
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                .await
                .expect("bind");
            let address = listener.local_addr().expect("address");
            let router = app(AppState::new([served]));
            tokio::spawn(async move { axum::serve(listener, router).await.expect("serve") });
            let floor_listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                .await
                .expect("bind");
            let floor_address = floor_listener.local_addr().expect("address");
            let floor = axum::Router::new().route(
                "/api/v1/health",
                axum::routing::get(|| async { axum::Json(serde_json::json!({"status": "ok"})) }),
            );
            tokio::spawn(async move { axum::serve(floor_listener, floor).await.expect("serve") });
            let (bare_tx, mut bare_rx) = tokio::sync::mpsc::unbounded_channel::<BareSdo>();
            ready_tx
                .send((address, floor_address, this_task(), bare_tx))
                .expect("ready");
            let task = this_task();
            while let Some(request) = bare_rx.recv().await {
                let channels = channels.clone();
                let objects = Arc::new(request.objects);
                let figures = load(request.clients, request.options, &task, move |client, n| {
                    let (node, index, sub) = objects[(client + n) % objects.len()];
                    let channel = channels[usize::from(node) - 1].clone();
                    async move { channel.upload(index, sub).await.is_ok() }
                })
                .await;
                let _ = request.answer.send(figures);
            }
        });
    });
    ready_rx.recv().expect("gateway thread")
}

fn bare_sdo(
    gateway: &tokio::sync::mpsc::UnboundedSender<BareSdo>,
    objects: &[(u8, u16, u8)],
    clients: usize,
    options: Options,
) -> Figures {
    let (answer, figures) = std::sync::mpsc::channel();
    gateway
        .send(BareSdo {
            objects: objects.to_vec(),
            clients,
            options,
            answer,
        })
        .expect("gateway runs");
    figures.recv().expect("bare SDO figures")
}

fn main() {
    common::announce_smoke("rest_api");
    let options = Options::from_args(
        common::pick(Duration::from_secs(1), Duration::from_millis(50)),
        common::pick(Duration::from_secs(3), Duration::from_millis(100)),
    );
    let levels = common::pick(&LEVELS[..], &SMOKE_LEVELS[..]);
    // `--only TEXT`: the rows whose "what clients" contains TEXT (to
    // profile one of them).
    let only = std::env::args().skip_while(|arg| arg != "--only").nth(1);
    let wanted = |label: &str, clients: usize| {
        only.as_deref()
            .is_none_or(|only| format!("{label} {clients}").contains(only))
    };
    let (address, floor_address, server_task, gateway) = spawn_gateway();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    let local = tokio::task::LocalSet::new();
    println!(
        "gateway on http://{address}/ (demo bus), {} s warm-up and {} s measured per level",
        options.warmup.as_secs_f64(),
        options.measure.as_secs_f64()
    );
    // Every object of the mix answers 200 before anything is measured.
    local.block_on(&runtime, async {
        let mut connection = Connection::open(address).await;
        for object in &MIX {
            let status = connection
                .get(&get_request(address, &od_path(object)))
                .await;
            assert_eq!(status, 200, "{}", od_path(object));
        }
    });
    println!();
    println!(
        "| what | clients | reads/s | p50 µs | p90 µs | p99 µs | max µs | server thread CPU | server thread CPU µs per read | client thread CPU | errors |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let mut failures = Vec::new();
    let mut rest_p50 = [f64::NAN; 2];
    let mut bare_p50 = [f64::NAN; 2];
    for (k, (label, objects)) in [
        ("REST node 1 0x6041/0", &SINGLE[..]),
        ("REST mix nodes 1-3", &MIX[..]),
    ]
    .into_iter()
    .enumerate()
    {
        let paths: Vec<String> = objects.iter().map(od_path).collect();
        for clients in levels.iter().copied().filter(|&c| wanted(label, c)) {
            let figures = local.block_on(
                &runtime,
                http_level(address, &paths, clients, options, &server_task),
            );
            failures.extend(figures.row(label, clients));
            if clients == 1 {
                rest_p50[k] = figures.percentile_us(50.0);
            }
        }
    }
    let health = "REST GET /health (no SDO)";
    for clients in levels.iter().copied().filter(|&c| wanted(health, c)) {
        let figures = local.block_on(
            &runtime,
            http_level(
                address,
                &["/api/v1/health".to_string()],
                clients,
                options,
                &server_task,
            ),
        );
        failures.extend(figures.row(health, clients));
    }
    let floor = "bare axum GET /health (one route, no layer)";
    for clients in levels.iter().copied().filter(|&c| wanted(floor, c)) {
        let figures = local.block_on(
            &runtime,
            http_level(
                floor_address,
                &["/api/v1/health".to_string()],
                clients,
                options,
                &server_task,
            ),
        );
        failures.extend(figures.row(floor, clients));
    }
    for (k, (label, objects)) in [
        ("bare SDO node 1 0x6041/0", &SINGLE[..]),
        ("bare SDO mix nodes 1-3", &MIX[..]),
    ]
    .into_iter()
    .enumerate()
    {
        for clients in levels.iter().copied().filter(|&c| wanted(label, c)) {
            let figures = bare_sdo(&gateway, objects, clients, options);
            failures.extend(figures.row(label, clients));
            if clients == 1 {
                bare_p50[k] = figures.percentile_us(50.0);
            }
        }
    }
    println!();
    for (k, label) in ["node 1 0x6041/0", "mix"].into_iter().enumerate() {
        println!(
            "gateway overhead per SDO ({label}, 1 client, p50): REST {:.1} µs - bare SDO {:.1} µs = {:.1} µs",
            rest_p50[k],
            bare_p50[k],
            rest_p50[k] - bare_p50[k]
        );
    }
    common::exit_on_failures("rest_api", &failures);
}
