//! Whether one client can slow REST for others (issue 30, "per-client
//! bounds": no one client may slow REST for others by more than a small
//! factor).
//!
//! Two processes as in `stream_fanout`: `candeck vbus --bitrate unlimited`
//! with one virtual UMC1BDS32 (node 1), and `candeck serve` on it through
//! socketcand, with two tokens (`viewer`, `operator`). A generator on the
//! vbus sends 8,000 frames/s (0x181) for the whole run. An operator reads
//! node 1's statusword over REST (`GET .../od/0x6041/0`, one request after
//! another, each on a connection of its own) in three phases:
//! - idle: no WebSocket client;
//! - readers: 200 WebSocket sessions of the viewer token, each subscribed
//!   to `buses/bench/frames` and reading everything;
//! - non-readers: 20 sessions of the viewer token that subscribe and never
//!   read.
//!
//! Each phase prints the REST read's p50 and p99, the ratio of its p99 to
//! the idle p99, the sessions the gateway refused (429 `too_many_streams`
//! beyond `stream_max_per_token`, `stream_max_per_peer`), the gateway's
//! resident memory (`VmRSS`) and its growth since idle, and the CPU (in
//! cores: CPU seconds over wall seconds, from `/proc/PID/stat`) that the
//! gateway, the vbus and the benchmark process itself took over the
//! measured window. The benchmark's WebSocket readers (one runtime thread
//! for them, one for the REST client, one for the generator) run on the
//! same cores as the gateway and compete with it: its column says how much
//! of the machine the load generator took. The REST client has a thread
//! and a runtime of its own, as another program would: on the readers'
//! thread its latency would include its wait behind their messages. "bus frames/s" is what the
//! gateway read of the bus over the window (`/metrics`,
//! `candeck_bus_frames_total` rx): about the generator's 8,000 plus node 1's
//! answers and heartbeats while the gateway keeps up; less when it falls
//! behind and the vbus's socketcand server drops the oldest frames it has
//! for the gateway (SDO answers among them). The run is made
//! twice: with the default stream limits (32 per token, 64 per address: most
//! of the 200 are refused) and with both raised to 1000, so that the 200
//! connect.
//!
//! Run: `cargo bench --bench rest_fairness -- --seconds N` (N: each
//! phase's measured seconds, default 5; `--warmup`: after the sessions
//! connect, default 1), or `scripts/bench`. A smoke run
//! (`CANDECK_BENCH_SMOKE`) has 4 readers and 2 non-readers, 0.2 s of
//! warm-up and 0.5 s measured per phase. No figure is asserted; the run
//! ends with status 1 when a REST read fails.

mod common;
#[path = "../tests/common/mod.rs"]
mod http;

use common::Options;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use candeck::can::spec::BusSpec;
use candeck::can::{CanId, Frame};
use futures_util::{SinkExt, StreamExt};
use serde_json::json;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

const FRAMES_PER_SECOND: u64 = 8_000;
const VIEWER: &str = "v1ewer-7f3c9a2e41b8d065c7e9a1f2";
const OPERATOR: &str = "0perator-5d2b8e4f19a7c306b1d8e9f4";
/// The slow readers and the clients that never read, of a full run.
const READERS: usize = 200;
const NON_READERS: usize = 20;

/// A child process, killed when dropped.
struct Process(Child);

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn spawn(args: &[&str], env: &[(&str, &str)]) -> (Process, String) {
    let mut command = Command::new(env!("CARGO_BIN_EXE_candeck"));
    command
        .args(args)
        .env_remove("CANDECK_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::null());
    for (key, value) in env {
        command.env(key, value);
    }
    let mut child = command.spawn().expect("candeck starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    (Process(child), line)
}

fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap_or_default()
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|value| value.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or(0)
}

fn percentile_us(sorted: &[u64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1] as f64 / 1_000.0
}

/// Sends 0x181 frames at [`FRAMES_PER_SECOND`] (a smoke run: 500) until
/// `done`.
async fn generate(vbus: String, done: Arc<AtomicBool>) {
    let rate = common::pick(FRAMES_PER_SECOND, 500);
    let spec: BusSpec = format!("socketcand:{vbus}/can0").parse().unwrap();
    let bus = spec.open("generator").await.unwrap().bus;
    bus.wait_up(Duration::from_secs(10)).await.unwrap();
    let start = Instant::now();
    let mut sent: u64 = 0;
    let mut ticker = tokio::time::interval(Duration::from_millis(1));
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    while !done.load(Ordering::Relaxed) {
        ticker.tick().await;
        let due = (start.elapsed().as_secs_f64() * rate as f64) as u64;
        while sent < due {
            let frame = Frame::new(CanId::standard(0x181).unwrap(), &sent.to_le_bytes()).unwrap();
            let _ = bus.send(frame).await;
            sent += 1;
        }
    }
}

/// A viewer's session subscribed to the bus's frames: reads everything
/// (`read`) or nothing until `done`. `None` when the gateway refused it.
async fn session(
    address: String,
    read: bool,
    received: Arc<AtomicU64>,
    done: Arc<AtomicBool>,
) -> Option<()> {
    let mut request = format!("ws://{address}/api/v1/stream")
        .into_client_request()
        .unwrap();
    request
        .headers_mut()
        .insert("Authorization", format!("Bearer {VIEWER}").parse().unwrap());
    let (mut socket, _) = tokio_tungstenite::connect_async(request).await.ok()?;
    let subscribe =
        json!({"op": "subscribe", "topics": ["buses/bench/frames"], "max_rate_hz": 1000});
    socket
        .send(Message::text(subscribe.to_string()))
        .await
        .ok()?;
    while !done.load(Ordering::Relaxed) {
        if read {
            if let Ok(Some(Ok(_))) =
                tokio::time::timeout(Duration::from_millis(200), socket.next()).await
            {
                received.fetch_add(1, Ordering::Relaxed);
            }
        } else {
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    }
    Some(())
}

/// The CPU seconds of the gateway, the vbus and this process, and the
/// frames the gateway had read of its bus, at the start of a window.
struct CpuWindow {
    pids: [u32; 3],
    start: [f64; 3],
    frames: f64,
    wall: Instant,
}

impl CpuWindow {
    fn start(gateway: u32, vbus: u32, frames: f64) -> Self {
        let pids = [gateway, vbus, std::process::id()];
        Self {
            pids,
            start: pids.map(common::process::cpu_seconds),
            frames,
            wall: Instant::now(),
        }
    }

    /// Cores each process used since the start (CPU seconds over wall
    /// seconds), and the frames per second the gateway read of its bus.
    fn end(&self, frames: f64) -> ([f64; 3], f64) {
        let wall = self.wall.elapsed().as_secs_f64();
        let mut cores = [0.0; 3];
        for (at, pid) in self.pids.iter().enumerate() {
            cores[at] = (common::process::cpu_seconds(*pid) - self.start[at]) / wall;
        }
        (cores, (frames - self.frames) / wall)
    }
}

/// The frames the gateway has read of its bus so far (`/metrics`).
async fn bus_frames_read(address: &str) -> f64 {
    let response = http::request_with_headers(
        address,
        "GET",
        "/metrics",
        "text/plain",
        None,
        Duration::from_secs(30),
        &format!("Authorization: Bearer {OPERATOR}\r\n"),
    )
    .await;
    response
        .body
        .lines()
        .find(|line| {
            line.starts_with("candeck_bus_frames_total{") && line.contains("direction=\"rx\"")
        })
        .and_then(|line| line.rsplit_once(' '))
        .and_then(|(_, value)| value.parse().ok())
        .unwrap_or(f64::NAN)
}

/// What one phase measured.
struct Phase {
    latencies: Vec<u64>,
    failed: u64,
    /// The first failure's status and body.
    first_failure: Option<String>,
}

/// REST reads of node 1's statusword, one after another, for `window`, on
/// a thread and a runtime of their own (not the WebSocket readers').
async fn rest_reads(address: &str, window: Duration) -> Phase {
    let address = address.to_string();
    tokio::task::spawn_blocking(move || {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
            .block_on(rest_reads_here(&address, window))
    })
    .await
    .expect("the REST client's thread ends")
}

async fn rest_reads_here(address: &str, window: Duration) -> Phase {
    let start = Instant::now();
    let mut latencies = Vec::new();
    let mut failed = 0;
    let mut first_failure = None;
    while start.elapsed() < window {
        let sent = Instant::now();
        let (status, body) = http::json_with_token(
            address,
            "GET",
            "/api/v1/buses/bench/nodes/1/od/0x6041/0",
            OPERATOR,
        )
        .await;
        if status == 200 {
            latencies.push(sent.elapsed().as_nanos() as u64);
        } else {
            failed += 1;
            first_failure.get_or_insert_with(|| format!("{status} {body}"));
        }
    }
    latencies.sort_unstable();
    Phase {
        latencies,
        failed,
        first_failure,
    }
}

/// Opens `count` sessions and returns the handles and how many were
/// refused, once every one has connected or been refused.
async fn open_sessions(
    address: &str,
    count: usize,
    read: bool,
    received: &Arc<AtomicU64>,
    done: &Arc<AtomicBool>,
) -> (Vec<tokio::task::JoinHandle<Option<()>>>, usize) {
    let handles: Vec<_> = (0..count)
        .map(|_| {
            tokio::spawn(session(
                address.to_string(),
                read,
                received.clone(),
                done.clone(),
            ))
        })
        .collect();
    // A refused session ends at once; give the accepted ones time to
    // subscribe.
    tokio::time::sleep(common::pick(
        Duration::from_secs(2),
        Duration::from_millis(300),
    ))
    .await;
    let refused = handles.iter().filter(|handle| handle.is_finished()).count();
    (handles, refused)
}

async fn close(handles: Vec<tokio::task::JoinHandle<Option<()>>>, done: &Arc<AtomicBool>) {
    done.store(true, Ordering::Relaxed);
    for handle in handles {
        let _ = tokio::time::timeout(Duration::from_secs(5), handle).await;
    }
}

/// One run against a gateway started with `limits` (extra arguments).
fn run(label: &str, limits: &[&str], options: Options, failures: &mut Vec<String>) {
    let (vbus_process, line) = spawn(
        &[
            "vbus",
            "--listen",
            "127.0.0.1:0",
            "--bitrate",
            "unlimited",
            "--devices",
            "umc1bds32@1",
        ],
        &[],
    );
    let vbus = line
        .split_whitespace()
        .nth(4)
        .unwrap_or_else(|| panic!("vbus said: {line}"))
        .to_string();
    let bus = format!("bench=socketcand:{vbus}/can0");
    let tokens = format!("viewer:viewer:{VIEWER},operator:operator:{OPERATOR}");
    let mut args = vec!["serve", "--listen", "127.0.0.1:0", "--bus", &bus];
    args.extend_from_slice(limits);
    let (gateway, line) = spawn(&args, &[("CANDECK_TOKENS", &tokens)]);
    let address = line
        .strip_prefix("candeck: serving http://")
        .and_then(|rest| rest.split_once('/'))
        .map(|(address, _)| address.to_string())
        .unwrap_or_else(|| panic!("serve said: {line}"));
    let pid = gateway.0.id();
    let vbus_pid = vbus_process.0.id();

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    runtime.block_on(async move {
        // Node 1 answers.
        let mut answered = false;
        for _ in 0..300 {
            let (status, _) = http::json_with_token(
                &address,
                "GET",
                "/api/v1/buses/bench/nodes/1/od/0x6041/0",
                OPERATOR,
            )
            .await;
            if status == 200 {
                answered = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        assert!(answered, "node 1 answers within 30 s");
        let generator_done = Arc::new(AtomicBool::new(false));
        let generator = std::thread::spawn({
            let done = generator_done.clone();
            move || {
                tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                    .unwrap()
                    .block_on(generate(vbus, done));
            }
        });
        tokio::time::sleep(options.warmup).await;

        println!("\n{label}\n");
        println!(
            "CPU in cores (of the machine's {}): the gateway, the vbus, and this benchmark \
             (its generator, REST client and WebSocket readers run on the same cores and \
             compete with the gateway)\n",
            std::thread::available_parallelism().map_or(0, usize::from)
        );
        println!("| phase | sessions asked | refused | REST reads | p50 ms | p99 ms | p99 / idle p99 | failed | bus frames/s | gateway CPU | vbus CPU | bench CPU | RSS MiB | RSS growth MiB | frames messages received |");
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
        let idle_rss = rss_kib(pid);
        let idle_cpu = CpuWindow::start(pid, vbus_pid, bus_frames_read(&address).await);
        let idle = rest_reads(&address, options.measure).await;
        let idle_cpu = idle_cpu.end(bus_frames_read(&address).await);
        let idle_p99 = percentile_us(&idle.latencies, 99.0);
        let row = |phase: &str,
                   asked: usize,
                   refused: usize,
                   figures: &Phase,
                   cpu: ([f64; 3], f64),
                   received: u64| {
            let (cpu, frames_per_s) = cpu;
            let rss = rss_kib(pid);
            let p99 = percentile_us(&figures.latencies, 99.0);
            println!(
                "| {phase} | {asked} | {refused} | {} | {:.2} | {:.2} | {:.1} | {} | {frames_per_s:.0} | {:.2} | {:.2} | {:.2} | {:.0} | {:+.0} | {received} |",
                figures.latencies.len(),
                percentile_us(&figures.latencies, 50.0) / 1_000.0,
                p99 / 1_000.0,
                p99 / idle_p99,
                figures.failed,
                cpu[0],
                cpu[1],
                cpu[2],
                rss as f64 / 1024.0,
                (rss as f64 - idle_rss as f64) / 1024.0,
            );
        };
        row("idle", 0, 0, &idle, idle_cpu, 0);

        for (phase, count, read) in [
            ("readers (frames topic)", common::pick(READERS, 4), true),
            ("non-readers", common::pick(NON_READERS, 2), false),
        ] {
            let received = Arc::new(AtomicU64::new(0));
            let done = Arc::new(AtomicBool::new(false));
            let (handles, refused) = open_sessions(&address, count, read, &received, &done).await;
            tokio::time::sleep(options.warmup).await;
            let cpu = CpuWindow::start(pid, vbus_pid, bus_frames_read(&address).await);
            let figures = rest_reads(&address, options.measure).await;
            let cpu = cpu.end(bus_frames_read(&address).await);
            row(phase, count, refused, &figures, cpu, received.load(Ordering::Relaxed));
            if figures.failed > 0 || figures.latencies.is_empty() {
                failures.push(format!(
                    "{label}, {phase}: {} REST reads failed (the first: {})",
                    figures.failed,
                    figures.first_failure.as_deref().unwrap_or("none; no read ended")
                ));
            }
            close(handles, &done).await;
            // The gateway sees the sessions go.
            tokio::time::sleep(Duration::from_secs(1)).await;
        }
        println!(
            "\nRSS after the sessions closed: {:.0} MiB",
            rss_kib(pid) as f64 / 1024.0
        );
        generator_done.store(true, Ordering::Relaxed);
        generator.join().unwrap();
    });
    drop(gateway);
}

fn main() {
    common::announce_smoke("rest_fairness");
    let options = Options::from_args(
        common::pick(Duration::from_secs(1), Duration::from_millis(200)),
        common::pick(Duration::from_secs(5), Duration::from_millis(500)),
    );
    let mut failures = Vec::new();
    run(
        "Default stream limits (32 per token, 64 per address)",
        &[],
        options,
        &mut failures,
    );
    run(
        "Stream limits raised to 1000 per token and per address",
        &[
            "--stream-max-per-token",
            "1000",
            "--stream-max-per-peer",
            "1000",
        ],
        options,
        &mut failures,
    );
    common::exit_on_failures("rest_fairness", &failures);
}
