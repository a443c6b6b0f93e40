//! The OPC UA door under load (issue 34): value changes delivered to
//! monitored-item subscribers, and reads of a dictionary variable against
//! REST's of the same object.
//!
//! Two processes as in the Sparkplug benchmark, so that the gateway's CPU
//! is its own: `candeck vbus --bitrate unlimited` with N UMC1BDS32 drives
//! (`--nodes`, default 127), and `candeck serve` attached to it over
//! socketcand with its OPC UA server on loopback (anonymous over the `None`
//! endpoint, as loopback allows without tokens). SYNC every 10 ms; each
//! drive's TPDO1 and TPDO2 are mapped (over REST) to axis 1's and axis 2's
//! position and velocity actual values and TPDO3 to both statuswords, so
//! that both axes are fed from the TPDOs (`source: tpdo`, no SDO polling);
//! both axes are enabled and run a long profile-position move (no motion
//! lease to renew), so that every position changes on every SYNC.
//!
//! Subscribers: for each count of `--subscribers` (default `10,100`), that
//! many OPC UA sessions (async-opcua's client, each its own connection),
//! each with one subscription (publishing interval 100 ms) monitoring
//! `Position` and `Velocity` of every axis of every drive (4 x N items,
//! sampling interval 0, queue 10). The server raises the sampling interval
//! to its minimum, printed as granted (async-opcua's default is 100 ms: at
//! most 10 changes a second of each item, while the feed writes a moving
//! axis's position 50 times a second). Each data change delivered to a client
//! is counted, and its latency taken: the time the client got it less the
//! value's source timestamp (when the gateway's feed wrote it), both on
//! this machine's clock, so it includes up to one publishing interval.
//!
//! Reads: one OPC UA session reads `Nodes/bench/1/Dictionary/0x1017sub0`
//! (the producer heartbeat time, one SDO upload per read) one read after
//! another, then one REST client reads `GET .../nodes/1/od/0x1017/0` on a
//! kept-alive connection the same way, each for the measured time, with
//! the drives still moving and no subscriber.
//!
//! Each phase prints the gateway's CPU (`/proc/PID/stat`, cores used over
//! the measured window) and its resident memory at the end, and the vbus's
//! CPU.
//!
//! Run: `cargo bench --bench opcua -- --nodes 127 --subscribers 10,100 --seconds 10 --warmup 3`,
//! or `scripts/bench`. A smoke run (`CANDECK_BENCH_SMOKE`) has 2 drives
//! and 2 subscribers, 0.5 s of warm-up and 1 s measured. No figure is
//! asserted; a monitored item the server refuses, a subscriber phase with
//! no value change delivered, or a failed read ends the run with status 1.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use common::Options;
use common::process::{
    KeepAlive, Killed, arg, cpu_seconds, free_port, http, lines_until, rss_mib, umc_vbus,
};
use opcua::client::{Client, ClientBuilder, DataChangeCallback, IdentityToken, Session};
use opcua::types::{
    DataValue, DateTime, ExtensionObject, MessageSecurityMode, MonitoredItemCreateRequest,
    MonitoringMode, MonitoringParameters, NodeId, ReadValueId, TimestampsToReturn, UserTokenPolicy,
};

const BUS: &str = "bench";
const PUBLISHING_INTERVAL: Duration = Duration::from_millis(100);
const QUEUE_SIZE: u32 = 10;
/// The values each subscriber monitors on every axis.
const AXIS_VALUES: [&str; 2] = ["Position", "Velocity"];
/// The dictionary object both doors read: the producer heartbeat time.
const READ_INDEX: u16 = 0x1017;

/// The two processes: the virtual bus with the drives, and the gateway.
struct Plant {
    vbus: Killed,
    gateway: Killed,
    /// The REST API's address.
    rest: String,
    /// The OPC UA endpoint's URL.
    opcua: String,
}

impl Plant {
    fn start(dir: &Path, nodes: u8, max_sessions: usize) -> Self {
        let (vbus, share) = umc_vbus(dir, "vbus.log", nodes);
        let opcua_port = free_port();
        let config = dir.join("candeck.toml");
        std::fs::write(
            &config,
            format!(
                "listen = \"127.0.0.1:0\"\nbuses = [\"{BUS}=socketcand:127.0.0.1:{share}/can0\"]\n\
                 sync_period_ms = 10\n\
                 opcua_listen = \"127.0.0.1:{opcua_port}\"\nopcua_pki_dir = \"{}\"\n\
                 opcua_max_sessions = {max_sessions}\n",
                dir.join("opcua-pki").display()
            ),
        )
        .unwrap();
        let mut gateway = Command::new(env!("CARGO_BIN_EXE_candeck"))
            .args(["serve", "--config", config.to_str().unwrap()])
            .current_dir(dir)
            .env("CANDECK_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(dir.join("candeck.log")).unwrap())
            .spawn()
            .expect("candeck serve starts");
        let lines = lines_until(&mut gateway, "candeck: OPC UA server on ");
        let rest = lines[0]
            .split("http://")
            .nth(1)
            .and_then(|rest| rest.split('/').next())
            .expect("the serving line")
            .to_string();
        Self {
            vbus,
            gateway: Killed(gateway),
            rest,
            opcua: format!("opc.tcp://127.0.0.1:{opcua_port}/"),
        }
    }

    fn gateway_pid(&self) -> u32 {
        self.gateway.0.id()
    }

    fn vbus_pid(&self) -> u32 {
        self.vbus.0.id()
    }

    /// One REST request, tried 3 times (on a loaded machine an SDO may
    /// time out); panics with the answer when all fail.
    fn must(&self, method: &str, path: &str, body: &str) {
        let (mut status, mut answer) = http(&self.rest, method, path, Some(body));
        for _ in 0..2 {
            if status < 300 {
                return;
            }
            std::thread::sleep(Duration::from_secs(1));
            (status, answer) = http(&self.rest, method, path, Some(body));
        }
        assert!(status < 300, "{method} {path} {body}: {status} {answer}");
    }

    /// Every drive identified; its TPDOs remapped so that both axes' status
    /// comes from them; started; both axes enabled and moving.
    fn set_up(&self, nodes: u8) {
        let deadline = Instant::now() + Duration::from_secs(300);
        loop {
            let (_, body) = http(&self.rest, "GET", &format!("/buses/{BUS}/nodes"), None);
            let done = body.matches("\"state\":\"done\"").count();
            if done >= usize::from(nodes) {
                break;
            }
            assert!(
                Instant::now() < deadline,
                "only {done} of {nodes} nodes identified"
            );
            std::thread::sleep(Duration::from_millis(200));
        }
        let nmt = format!("/buses/{BUS}/nmt");
        self.must("POST", &nmt, "{\"command\":\"pre_operational\"}");
        // Axis 2 of a UMC is axis 1's objects at +0x800.
        let mappings = [
            (1, ["0x6064", "0x606C"]),
            (2, ["0x6864", "0x686C"]),
            (3, ["0x6041", "0x6841"]),
        ];
        for id in 1..=nodes {
            for (tpdo, objects) in mappings {
                let mapping: Vec<String> = objects
                    .iter()
                    .map(|index| format!("{{\"index\":\"{index}\"}}"))
                    .collect();
                self.must(
                    "PUT",
                    &format!("/buses/{BUS}/nodes/{id}/pdos/tpdo/{tpdo}"),
                    &format!(
                        "{{\"transmission_type\":1,\"mapping\":[{}]}}",
                        mapping.join(",")
                    ),
                );
            }
        }
        self.must("POST", &nmt, "{\"command\":\"start\"}");
        for id in 1..=nodes {
            for axis in 1..=2 {
                let base = format!("/buses/{BUS}/nodes/{id}/axes/{axis}");
                self.must(
                    "POST",
                    &format!("{base}/state"),
                    "{\"target\":\"operation_enabled\"}",
                );
                // A far target: the axis moves for the whole run.
                self.must(
                    "POST",
                    &format!("{base}/move"),
                    "{\"mode\":\"profile_position\",\"target\":2000000000,\"velocity\":2000}",
                );
            }
        }
    }
}

/// The CPU the gateway and the vbus used over a measured window.
struct Cpu {
    gateway: f64,
    vbus: f64,
    gateway_rss: f64,
}

fn measure_cpu(plant: &Plant, window: impl FnOnce()) -> (Cpu, f64) {
    let (gateway, vbus) = (plant.gateway_pid(), plant.vbus_pid());
    let (gateway_start, vbus_start) = (cpu_seconds(gateway), cpu_seconds(vbus));
    let start = Instant::now();
    window();
    let elapsed = start.elapsed().as_secs_f64();
    let cpu = Cpu {
        gateway: (cpu_seconds(gateway) - gateway_start) / elapsed,
        vbus: (cpu_seconds(vbus) - vbus_start) / elapsed,
        gateway_rss: rss_mib(gateway),
    };
    (cpu, elapsed)
}

/// Latencies in whole milliseconds, counted per millisecond up to 10 s
/// (the last bucket takes the rest): lock-free for the clients'
/// callbacks.
struct Histogram(Vec<AtomicU64>);

impl Histogram {
    fn new() -> Self {
        Self((0..=10_000).map(|_| AtomicU64::new(0)).collect())
    }

    fn add(&self, ms: u64) {
        let at = usize::try_from(ms).map_or(self.0.len() - 1, |ms| ms.min(self.0.len() - 1));
        self.0[at].fetch_add(1, Ordering::Relaxed);
    }

    fn clear(&self) {
        for bucket in &self.0 {
            bucket.store(0, Ordering::Relaxed);
        }
    }

    /// The latency at fraction `p` of the values counted (0 when none).
    fn percentile(&self, p: f64) -> u64 {
        let counts: Vec<u64> = self.0.iter().map(|b| b.load(Ordering::Relaxed)).collect();
        let total: u64 = counts.iter().sum();
        let rank = ((total as f64) * p).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (ms, count) in counts.iter().enumerate() {
            seen += count;
            if seen >= rank {
                return ms as u64;
            }
        }
        0
    }
}

/// What the subscribers received.
struct Tally {
    changes: AtomicU64,
    latency: Histogram,
}

impl Tally {
    fn record(&self, value: &DataValue) {
        if value.value.is_none() || value.status.is_some_and(|status| !status.is_good()) {
            return;
        }
        self.changes.fetch_add(1, Ordering::Relaxed);
        if let Some(at) = value.source_timestamp.or(value.server_timestamp) {
            let ticks = DateTime::now().checked_ticks() - at.checked_ticks();
            // Ticks of 100 ns.
            self.latency.add(u64::try_from(ticks / 10_000).unwrap_or(0));
        }
    }
}

/// One anonymous session over the `None` endpoint, its event loop running.
async fn connect(client: &mut Client, url: &str) -> Result<Arc<Session>, String> {
    let endpoint = (
        url,
        "None",
        MessageSecurityMode::None,
        UserTokenPolicy::anonymous(),
    );
    let (session, event_loop) = client
        .connect_to_matching_endpoint(endpoint, IdentityToken::Anonymous)
        .await
        .map_err(|err| format!("connect to {url}: {err}"))?;
    event_loop.spawn();
    if !session.wait_for_connection().await {
        return Err(format!("connect to {url}: no session"));
    }
    Ok(session)
}

/// The value `name` of axis `axis` of node `id`.
fn axis_value(ns: u16, id: u8, axis: u8, name: &str) -> NodeId {
    NodeId::new(ns, format!("candeck/Nodes/{BUS}/{id}/Axes/{axis}/{name}"))
}

/// One subscriber: a session with one subscription monitoring every axis
/// value of `AXIS_VALUES` of every node; the session and the sampling
/// interval the server granted (it raises 0 to its minimum).
async fn subscribe(
    client: &mut Client,
    url: &str,
    nodes: u8,
    tally: Arc<Tally>,
    counting: Arc<AtomicBool>,
) -> Result<(Arc<Session>, f64), String> {
    let session = connect(client, url).await?;
    let ns = session
        .get_namespace_index("urn:candeck")
        .await
        .map_err(|err| format!("namespace urn:candeck: {err}"))?;
    let subscription = session
        .create_subscription(
            PUBLISHING_INTERVAL,
            60,
            10,
            0,
            0,
            true,
            DataChangeCallback::new(move |value, _item| {
                if counting.load(Ordering::Relaxed) {
                    tally.record(&value);
                }
            }),
        )
        .await
        .map_err(|err| format!("create a subscription: {err}"))?;
    let items: Vec<MonitoredItemCreateRequest> = (1..=nodes)
        .flat_map(|id| (1..=2).map(move |axis| (id, axis)))
        .flat_map(|(id, axis)| AXIS_VALUES.map(|name| axis_value(ns, id, axis, name)))
        .map(|node| {
            MonitoredItemCreateRequest::new(
                ReadValueId::from(node),
                MonitoringMode::Reporting,
                MonitoringParameters {
                    client_handle: 0,
                    sampling_interval: 0.0,
                    filter: ExtensionObject::null(),
                    queue_size: QUEUE_SIZE,
                    discard_oldest: true,
                },
            )
        })
        .collect();
    let created = session
        .create_monitored_items(subscription, TimestampsToReturn::Both, items)
        .await
        .map_err(|err| format!("create monitored items: {err}"))?;
    if let Some(refused) = created
        .iter()
        .find(|item| !item.result.status_code.is_good())
    {
        return Err(format!(
            "a monitored item refused: {}",
            refused.result.status_code
        ));
    }
    let granted = created
        .iter()
        .map(|item| item.result.revised_sampling_interval)
        .fold(0.0, f64::max);
    Ok((session, granted))
}

/// `count` subscribers for the measured window: the row of the table.
fn subscribers_phase(
    runtime: &tokio::runtime::Runtime,
    client: &mut Client,
    plant: &Plant,
    nodes: u8,
    count: usize,
    options: Options,
) -> Result<(), String> {
    let tally = Arc::new(Tally {
        changes: AtomicU64::new(0),
        latency: Histogram::new(),
    });
    let counting = Arc::new(AtomicBool::new(false));
    let connected = Instant::now();
    let (sessions, granted) = runtime.block_on(async {
        let mut sessions = Vec::new();
        let mut granted: f64 = 0.0;
        for _ in 0..count {
            let (session, interval) =
                subscribe(client, &plant.opcua, nodes, tally.clone(), counting.clone()).await?;
            sessions.push(session);
            granted = granted.max(interval);
        }
        Ok::<_, String>((sessions, granted))
    })?;
    let items = count * usize::from(nodes) * 2 * AXIS_VALUES.len();
    println!(
        "opcua: {count} subscribers with {items} monitored items in all, created in {:.1} s; \
         sampling interval granted {granted} ms",
        connected.elapsed().as_secs_f64()
    );
    std::thread::sleep(options.warmup);
    counting.store(true, Ordering::Relaxed);
    let (cpu, elapsed) = measure_cpu(plant, || std::thread::sleep(options.measure));
    counting.store(false, Ordering::Relaxed);
    let changes = tally.changes.load(Ordering::Relaxed);
    println!(
        "opcua: {count} subscribers x {} items ({nodes} nodes x 2 axes x Position, Velocity): \
         {:.0} value changes/s delivered in all, {:.0} per subscriber; latency p50 {} ms, \
         p99 {} ms, max {} ms; gateway CPU {:.2} cores, RSS {:.1} MiB; vbus CPU {:.2} cores \
         (over {elapsed:.1} s)",
        items / count,
        changes as f64 / elapsed,
        changes as f64 / elapsed / count as f64,
        tally.latency.percentile(0.5),
        tally.latency.percentile(0.99),
        tally.latency.percentile(1.0),
        cpu.gateway,
        cpu.gateway_rss,
        cpu.vbus,
    );
    runtime.block_on(async {
        for session in sessions {
            let _ = session.disconnect().await;
        }
    });
    tally.latency.clear();
    if changes == 0 {
        return Err(format!("{count} subscribers: no value change delivered"));
    }
    Ok(())
}

/// Reads for the measured window, one after another: how many, and each
/// one's time.
struct Reads {
    done: u64,
    times: Vec<Duration>,
}

impl Reads {
    fn row(&mut self, door: &str, cpu: &Cpu, elapsed: f64) {
        self.times.sort_unstable();
        let pct = |p: f64| {
            let at = ((self.times.len() as f64 - 1.0) * p).round() as usize;
            self.times
                .get(at)
                .map_or(0.0, |time| time.as_secs_f64() * 1000.0)
        };
        println!(
            "opcua: reads of 0x{READ_INDEX:04X}:0 of node 1 over {door}: {:.0} reads/s, \
             p50 {:.2} ms, p99 {:.2} ms; gateway CPU {:.2} cores; vbus CPU {:.2} cores \
             (over {elapsed:.1} s)",
            self.done as f64 / elapsed,
            pct(0.5),
            pct(0.99),
            cpu.gateway,
            cpu.vbus,
        );
    }
}

/// Reads over OPC UA for `window`, one at a time.
async fn read_opcua(session: &Session, ns: u16, window: Duration) -> Result<Reads, String> {
    let node = NodeId::new(
        ns,
        format!("candeck/Nodes/{BUS}/1/Dictionary/0x{READ_INDEX:04X}sub0"),
    );
    let read = [ReadValueId::from(node)];
    let mut reads = Reads {
        done: 0,
        times: Vec::new(),
    };
    let end = Instant::now() + window;
    while Instant::now() < end {
        let start = Instant::now();
        let values = session
            .read(&read, TimestampsToReturn::Neither, 0.0)
            .await
            .map_err(|err| format!("OPC UA read: {err}"))?;
        match values.first() {
            Some(value) if value.value.is_some() && value.status.is_none_or(|s| s.is_good()) => {}
            other => return Err(format!("OPC UA read: {other:?}")),
        }
        reads.times.push(start.elapsed());
        reads.done += 1;
    }
    Ok(reads)
}

/// Reads over REST for `window`, one at a time on one connection.
fn read_rest(addr: &str, window: Duration) -> Result<Reads, String> {
    let path = format!("/buses/{BUS}/nodes/1/od/0x{READ_INDEX:04X}/0");
    let mut connection = KeepAlive::connect(addr).map_err(|err| format!("REST: {err}"))?;
    let mut reads = Reads {
        done: 0,
        times: Vec::new(),
    };
    let end = Instant::now() + window;
    while Instant::now() < end {
        let start = Instant::now();
        let (status, body) = connection
            .get(&path)
            .map_err(|err| format!("REST read: {err}"))?;
        if status != 200 {
            return Err(format!("REST read: {status} {body}"));
        }
        reads.times.push(start.elapsed());
        reads.done += 1;
    }
    Ok(reads)
}

fn reads_phase(
    runtime: &tokio::runtime::Runtime,
    client: &mut Client,
    plant: &Plant,
    options: Options,
) -> Result<(), String> {
    let session = runtime.block_on(connect(client, &plant.opcua))?;
    let ns = runtime
        .block_on(session.get_namespace_index("urn:candeck"))
        .map_err(|err| format!("namespace urn:candeck: {err}"))?;
    runtime.block_on(read_opcua(&session, ns, options.warmup))?;
    let mut result = Ok(Reads {
        done: 0,
        times: Vec::new(),
    });
    let (cpu, elapsed) = measure_cpu(plant, || {
        result = runtime.block_on(read_opcua(&session, ns, options.measure));
    });
    result?.row("OPC UA", &cpu, elapsed);
    let _ = runtime.block_on(session.disconnect());
    read_rest(&plant.rest, options.warmup)?;
    let mut result = Ok(Reads {
        done: 0,
        times: Vec::new(),
    });
    let (cpu, elapsed) = measure_cpu(plant, || {
        result = read_rest(&plant.rest, options.measure);
    });
    result?.row("REST", &cpu, elapsed);
    Ok(())
}

fn main() {
    common::announce_smoke("opcua");
    let options = Options::from_args(
        common::pick(Duration::from_secs(3), Duration::from_millis(500)),
        common::pick(Duration::from_secs(10), Duration::from_secs(1)),
    );
    let nodes: u8 = arg("--nodes", common::pick(127, 2));
    let subscribers: String = arg("--subscribers", common::pick("10,100", "2").to_string());
    let subscribers: Vec<usize> = subscribers
        .split(',')
        .map(|count| {
            count
                .trim()
                .parse()
                .unwrap_or_else(|_| panic!("--subscribers: '{count}' is no count"))
        })
        .collect();
    assert!(
        (1..=127).contains(&nodes),
        "--nodes: {nodes} is not 1 to 127"
    );
    let dir = std::env::temp_dir().join(format!("candeck-opcua-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let max_subscribers = subscribers.iter().copied().max().unwrap_or(1);
    let setup = Instant::now();
    // The subscribers, the reader, and room for a session not yet closed.
    let plant = Plant::start(&dir, nodes, max_subscribers + 4);
    plant.set_up(nodes);
    println!(
        "opcua: {nodes} nodes identified, remapped, started, enabled and moving after {:.1} s",
        setup.elapsed().as_secs_f64()
    );
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .unwrap();
    let mut client = ClientBuilder::new()
        .application_name("candeck opcua bench")
        .application_uri("urn:candeck-opcua-bench")
        .pki_dir(dir.join("client-pki"))
        .create_sample_keypair(true)
        .trust_server_certs(true)
        .session_retry_limit(3)
        // One publish response may hold up to QUEUE_SIZE values of each of
        // a subscriber's 508 items: beyond the client's defaults (1,000
        // array elements, 320 KiB); the server's own bound is 4 MiB.
        .max_array_length(1 << 20)
        .max_message_size(4 << 20)
        .max_chunk_count(128)
        .client()
        .unwrap_or_else(|errors| panic!("the OPC UA client: {errors:?}"));
    let mut failures = Vec::new();
    for count in subscribers {
        if let Err(failure) =
            subscribers_phase(&runtime, &mut client, &plant, nodes, count, options)
        {
            failures.push(failure);
        }
    }
    if let Err(failure) = reads_phase(&runtime, &mut client, &plant, options) {
        failures.push(failure);
    }
    drop(runtime);
    drop(plant);
    std::fs::remove_dir_all(&dir).ok();
    common::exit_on_failures("opcua", &failures);
}
