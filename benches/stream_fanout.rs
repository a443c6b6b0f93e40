//! The telemetry stream under a saturated bus (issue 6): 8,000 TPDO
//! frames/s (what a 1 Mbit/s CAN bus carries at most) decoded by the
//! gateway and fanned out to 100 WebSocket clients.
//!
//! Three processes, as in the compose demo: `candeck vbus` with eight
//! virtual UMC1BDS32 (nodes 1–8) serves the emulated bus over socketcand;
//! `candeck serve` is the gateway, on that bus through its socketcand
//! client; this benchmark is the rest:
//! - it re-maps each node's TPDO1 through REST to carry 0x6064 (32 bits)
//!   and 0x6041 (16 bits), so the gateway decodes those frames by the
//!   mapping it read from the node (the nodes stay pre-operational and send
//!   no PDO of their own);
//! - a generator, attached to the vbus over socketcand, sends TPDO1 of the
//!   eight nodes at 8,000 frames/s in total, each frame carrying its send
//!   time (µs, in the 32 bits of 0x6064) and a sequence number, and an EMCY
//!   of a node ten times a second;
//! - 100 WebSocket clients each subscribe to one node's `values` (client i
//!   to node i mod 8 + 1) at `max_rate_hz` 50, and to `emcy`;
//! - one more client takes node 1's TPDO1 frames raw (`frames?ids=0x181`),
//!   for comparison: the bus path without the values producer.
//!
//! Measured over the window (`--seconds`, default 10, after `--warmup`,
//! default 2): frames sent; per client, values messages per second and
//! latency from frame sent to message received (from the timestamp in the
//! frame, same clock); EMCYs sent and received by each client (and
//! `lagged` notices: none expected); the gateway process's CPU (utime +
//! stime from `/proc/<pid>/stat`) and resident memory.
//!
//! Run: `cargo bench --bench stream_fanout` (or `scripts/bench`). A smoke
//! run (`CANDECK_BENCH_SMOKE`) has 8 clients, 0.3 s of warm-up and 0.5 s
//! measured. The run ends with status 1 when the nodes are not identified,
//! a remap fails, a client got an error reply or no values message, or no
//! frame was sent or seen on the frames topic.

mod common;
// The HTTP helpers of the tests against the binary.
#[path = "../tests/common/mod.rs"]
mod http;

use common::Options;
use http::json;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use candeck::can::spec::BusSpec;
use candeck::can::{CanId, Frame};
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value as Json, json};
use tokio_tungstenite::tungstenite::Message;

const NODES: u8 = 8;
const FRAMES_PER_SECOND: u64 = 8_000;
const EMCY_PER_SECOND: u64 = 10;
const RATE_HZ: f64 = 50.0;

/// A child process, killed when dropped.
struct Process(Child);

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `candeck ARGS` and returns it with its first stdout line.
fn spawn(args: &[&str]) -> (Process, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(args)
        .env_remove("CANDECK_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("candeck starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    (Process(child), line)
}

/// CPU time (user + system) of a process, from `/proc/<pid>/stat`.
fn process_cpu(pid: u32) -> Duration {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest.split_whitespace().collect())
        .unwrap_or_default();
    // utime and stime are fields 14 and 15, in USER_HZ (100) ticks.
    let ticks: u64 = [14, 15]
        .iter()
        .filter_map(|n| fields.get(n - 3)?.parse::<u64>().ok())
        .sum();
    Duration::from_millis(ticks * 10)
}

fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap_or_default()
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|value| value.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or(0)
}

/// What one client saw in the measured window.
#[derive(Default)]
struct ClientFigures {
    values: u64,
    /// Latency of each values message, µs.
    latencies: Vec<u64>,
    /// The sequence numbers of the EMCYs it got (any time).
    emcy: std::collections::HashSet<u32>,
    lagged: u64,
    errors: u64,
}

/// The send time carried in a values message: the 32 bits of 0x6064.
fn carried_time(data: &Json) -> Option<u32> {
    let object = data.as_object()?;
    object
        .iter()
        .find(|(key, _)| key.contains("Position_actual") || key.starts_with("0x6064"))
        .and_then(|(_, value)| value.as_i64())
        .map(|value| value as u32)
}

async fn client(
    address: String,
    node: u8,
    epoch: Instant,
    measuring: Arc<AtomicBool>,
    done: Arc<AtomicBool>,
) -> ClientFigures {
    let (mut socket, _) = tokio_tungstenite::connect_async(format!("ws://{address}/api/v1/stream"))
        .await
        .expect("connect");
    let request = json!({
        "op": "subscribe",
        "topics": [format!("buses/bench/nodes/{node}/values"), "emcy"],
        "max_rate_hz": RATE_HZ,
    });
    socket
        .send(Message::text(request.to_string()))
        .await
        .unwrap();
    let mut figures = ClientFigures::default();
    while !done.load(Ordering::Relaxed) {
        let Ok(Some(Ok(message))) =
            tokio::time::timeout(Duration::from_millis(200), socket.next()).await
        else {
            continue;
        };
        let Message::Text(text) = message else {
            continue;
        };
        let now = epoch.elapsed().as_micros() as u32;
        let message: Json = serde_json::from_str(&text).unwrap();
        if message["topic"] == "emcy" && message["data"].is_object() {
            // The sequence number is in the first four manufacturer bytes.
            let hex = message["data"]["manufacturer"].as_str().unwrap_or("");
            let bytes: Vec<u8> = (0..4)
                .filter_map(|i| u8::from_str_radix(hex.get(2 * i..2 * i + 2)?, 16).ok())
                .collect();
            if let Ok(bytes) = <[u8; 4]>::try_from(bytes) {
                figures.emcy.insert(u32::from_le_bytes(bytes));
            }
            continue;
        }
        if !measuring.load(Ordering::Relaxed) {
            continue;
        }
        if let Some(lagged) = message["lagged"].as_u64() {
            figures.lagged += lagged;
        } else if message["op"] == "error" {
            figures.errors += 1;
        } else if let Some(sent) = carried_time(&message["data"]) {
            figures.values += 1;
            figures.latencies.push(u64::from(now.wrapping_sub(sent)));
        }
    }
    figures
}

/// One client of the raw frames of node 1's TPDO1 at the highest rate:
/// the latency of the bus path without the values producer. Returns the
/// latency of each frame, µs.
async fn frames_probe(
    address: String,
    epoch: Instant,
    measuring: Arc<AtomicBool>,
    done: Arc<AtomicBool>,
) -> Vec<u64> {
    let (mut socket, _) = tokio_tungstenite::connect_async(format!("ws://{address}/api/v1/stream"))
        .await
        .expect("connect");
    let request = json!({
        "op": "subscribe",
        "topics": ["buses/bench/frames?ids=0x181"],
        "max_rate_hz": 1000,
    });
    socket
        .send(Message::text(request.to_string()))
        .await
        .unwrap();
    let mut latencies = Vec::new();
    while !done.load(Ordering::Relaxed) {
        let Ok(Some(Ok(Message::Text(text)))) =
            tokio::time::timeout(Duration::from_millis(200), socket.next()).await
        else {
            continue;
        };
        let now = epoch.elapsed().as_micros() as u32;
        if !measuring.load(Ordering::Relaxed) {
            continue;
        }
        let message: Json = serde_json::from_str(&text).unwrap();
        for frame in message["data"].as_array().into_iter().flatten() {
            let hex = frame["data"].as_str().unwrap_or("");
            let bytes: Vec<u8> = (0..4)
                .filter_map(|i| u8::from_str_radix(hex.get(2 * i..2 * i + 2)?, 16).ok())
                .collect();
            if let Ok(bytes) = <[u8; 4]>::try_from(bytes) {
                latencies.push(u64::from(now.wrapping_sub(u32::from_le_bytes(bytes))));
            }
        }
    }
    latencies
}

/// Sends the TPDO frames and EMCYs at their rates until `done`; counts
/// what it sent while `measuring`.
async fn generate(
    vbus: String,
    epoch: Instant,
    measuring: Arc<AtomicBool>,
    done: Arc<AtomicBool>,
    frames_sent: Arc<AtomicU64>,
    emcy_window: Arc<(AtomicU64, AtomicU64)>,
) {
    let spec: BusSpec = format!("socketcand:{vbus}/can0").parse().unwrap();
    let bus = spec.open("generator").await.unwrap().bus;
    bus.wait_up(Duration::from_secs(10)).await.unwrap();
    let start = Instant::now();
    let mut sent: u64 = 0;
    let mut emcys: u64 = 0;
    let mut ticker = tokio::time::interval(Duration::from_millis(1));
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    while !done.load(Ordering::Relaxed) {
        ticker.tick().await;
        let elapsed = start.elapsed().as_secs_f64();
        let due = (elapsed * FRAMES_PER_SECOND as f64) as u64;
        while sent < due {
            let node = (sent % u64::from(NODES)) as u32 + 1;
            let now = epoch.elapsed().as_micros() as u32;
            let mut data = now.to_le_bytes().to_vec();
            data.extend_from_slice(&(sent as u16).to_le_bytes());
            let frame = Frame::new(CanId::standard(0x180 + node).unwrap(), &data).unwrap();
            if bus.send(frame).await.is_ok() && measuring.load(Ordering::Relaxed) {
                frames_sent.fetch_add(1, Ordering::Relaxed);
            }
            sent += 1;
        }
        let emcy_due = (elapsed * EMCY_PER_SECOND as f64) as u64;
        while emcys < emcy_due {
            let node = (emcys % u64::from(NODES)) as u32 + 1;
            // A generic error (0x1000) with the error register's generic
            // bit, and its sequence number in the manufacturer bytes.
            let mut data = vec![0x00, 0x10, 0x01];
            data.extend_from_slice(&(emcys as u32).to_le_bytes());
            data.push(0);
            let frame = Frame::new(CanId::standard(0x80 + node).unwrap(), &data).unwrap();
            if bus.send(frame).await.is_ok() && measuring.load(Ordering::Relaxed) {
                emcy_window.0.fetch_min(emcys, Ordering::Relaxed);
                emcy_window.1.fetch_max(emcys, Ordering::Relaxed);
            }
            emcys += 1;
        }
    }
}

fn percentile(sorted: &[u64], p: f64) -> u64 {
    if sorted.is_empty() {
        return 0;
    }
    let rank = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

fn main() {
    common::announce_smoke("stream_fanout");
    let options = Options::from_args(
        common::pick(Duration::from_secs(2), Duration::from_millis(300)),
        common::pick(Duration::from_secs(10), Duration::from_millis(500)),
    );
    let client_count: usize = common::pick(100, usize::from(NODES));
    let devices: Vec<String> = (1..=NODES).map(|n| format!("umc1bds32@{n}")).collect();
    let devices = devices.join(",");
    let (_vbus, line) = spawn(&[
        "vbus",
        "--listen",
        "127.0.0.1:0",
        "--bitrate",
        "unlimited",
        "--devices",
        &devices,
    ]);
    let vbus = line
        .split_whitespace()
        .nth(4)
        .unwrap_or_else(|| panic!("vbus said: {line}"))
        .to_string();
    let bus = format!("bench=socketcand:{vbus}/can0");
    // The 100 clients come from one address and hold no token: beyond the
    // default per-address bound of streams (64), which protects a real
    // gateway from one client, not a benchmark's fan-out.
    let (gateway, line) = spawn(&[
        "serve",
        "--listen",
        "127.0.0.1:0",
        "--bus",
        &bus,
        "--stream-max-per-peer",
        "1000",
        "--stream-max-per-token",
        "1000",
    ]);
    let address = line
        .strip_prefix("candeck: serving http://")
        .and_then(|rest| rest.split_once('/'))
        .map(|(address, _)| address.to_string())
        .unwrap_or_else(|| panic!("serve said: {line}"));
    let pid = gateway.0.id();

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    runtime.block_on(async move {
        // The eight nodes, identified.
        let mut identified = 0;
        for _ in 0..300 {
            let (_, nodes) = json(&address, "POST", "/api/v1/buses/bench/scan", None).await;
            identified = nodes
                .as_array()
                .map_or(0, |nodes| nodes.iter().filter(|n| n["profile"] == "umc").count());
            if identified == usize::from(NODES) {
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        assert_eq!(identified, usize::from(NODES), "nodes identified as UMC within 30 s");
        for node in 1..=NODES {
            let (status, body) = json(
                &address,
                "PUT",
                &format!("/api/v1/buses/bench/nodes/{node}/pdos/tpdo/1"),
                Some(r#"{"transmission_type":255,"mapping":[{"index":"0x6064"},{"index":"0x6041"}]}"#),
            )
            .await;
            assert_eq!(status, 200, "TPDO1 of node {node}: {body}");
        }

        let epoch = Instant::now();
        let measuring = Arc::new(AtomicBool::new(false));
        let done = Arc::new(AtomicBool::new(false));
        let frames_sent = Arc::new(AtomicU64::new(0));
        // The first and last EMCY sent in the window.
        let emcy_window = Arc::new((AtomicU64::new(u64::MAX), AtomicU64::new(0)));
        let clients: Vec<_> = (0..client_count)
            .map(|i| {
                tokio::spawn(client(
                    address.clone(),
                    (i % usize::from(NODES)) as u8 + 1,
                    epoch,
                    measuring.clone(),
                    done.clone(),
                ))
            })
            .collect();
        let probe = tokio::spawn(frames_probe(
            address.clone(),
            epoch,
            measuring.clone(),
            done.clone(),
        ));
        // The generator runs on a thread and runtime of its own, so that the
        // clients' work does not pace it.
        let generator = std::thread::spawn({
            let (measuring, done) = (measuring.clone(), done.clone());
            let (frames_sent, emcy_window) = (frames_sent.clone(), emcy_window.clone());
            move || {
                tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                    .unwrap()
                    .block_on(generate(vbus, epoch, measuring, done, frames_sent, emcy_window));
            }
        });

        tokio::time::sleep(options.warmup).await;
        let rss_start = rss_kib(pid);
        let cpu_start = process_cpu(pid);
        let window_start = Instant::now();
        measuring.store(true, Ordering::Relaxed);
        tokio::time::sleep(options.measure).await;
        measuring.store(false, Ordering::Relaxed);
        let seconds = window_start.elapsed().as_secs_f64();
        let cpu = (process_cpu(pid) - cpu_start).as_secs_f64() / seconds;
        let rss_end = rss_kib(pid);
        // EMCYs sent at the end of the window are still on their way.
        tokio::time::sleep(common::pick(Duration::from_millis(500), Duration::from_millis(200))).await;
        done.store(true, Ordering::Relaxed);
        let mut figures = Vec::new();
        for client in clients {
            figures.push(client.await.unwrap());
        }
        generator.join().unwrap();
        let mut probe = probe.await.unwrap();
        probe.sort_unstable();

        let frames = frames_sent.load(Ordering::Relaxed);
        let (first, last) = (emcy_window.0.load(Ordering::Relaxed), emcy_window.1.load(Ordering::Relaxed));
        let emcys = if first <= last { last - first + 1 } else { 0 };
        let missing: Vec<usize> = figures
            .iter()
            .map(|f| (first..=last).filter(|seq| !f.emcy.contains(&(*seq as u32))).count())
            .collect();
        let missing_max = missing.iter().copied().max().unwrap_or(0);
        let missing_total: usize = missing.iter().sum();
        let mut rates: Vec<f64> = figures.iter().map(|f| f.values as f64 / seconds).collect();
        rates.sort_by(f64::total_cmp);
        let mut latencies: Vec<u64> = figures.iter().flat_map(|f| f.latencies.clone()).collect();
        latencies.sort_unstable();
        let lagged: u64 = figures.iter().map(|f| f.lagged).sum();
        let errors: u64 = figures.iter().map(|f| f.errors).sum();
        println!(
            "{client_count} clients, {NODES} nodes, {:.1} s measured after {:.1} s warm-up\n",
            seconds,
            options.warmup.as_secs_f64()
        );
        println!("| measure | value |");
        println!("|---|---|");
        println!("| TPDO frames sent | {:.0}/s ({frames} frames) |", frames as f64 / seconds);
        println!(
            "| values messages per client (asked {RATE_HZ} Hz) | min {:.1} · median {:.1} · max {:.1} /s |",
            rates[0],
            rates[rates.len() / 2],
            rates[rates.len() - 1]
        );
        println!(
            "| frame-to-client latency | p50 {:.1} ms · p99 {:.1} ms · max {:.1} ms ({} messages) |",
            percentile(&latencies, 50.0) as f64 / 1000.0,
            percentile(&latencies, 99.0) as f64 / 1000.0,
            latencies.last().copied().unwrap_or(0) as f64 / 1000.0,
            latencies.len()
        );
        println!(
            "| for comparison: frames topic, 1 client, node 1's TPDO1 (no values producer) | p50 {:.1} ms · p99 {:.1} ms · max {:.1} ms ({} frames) |",
            percentile(&probe, 50.0) as f64 / 1000.0,
            percentile(&probe, 99.0) as f64 / 1000.0,
            probe.last().copied().unwrap_or(0) as f64 / 1000.0,
            probe.len()
        );
        println!(
            "| EMCY events | {emcys} sent in the window; missing at any client: {missing_total} (at most {missing_max} at one); lagged notices {lagged}; error replies {errors} |"
        );
        println!("| gateway CPU (process) | {:.0} % of one core |", cpu * 100.0);
        println!("| gateway resident memory | {} KiB at start, {} KiB at end of window |", rss_start, rss_end);
        let mut failures = Vec::new();
        if frames == 0 {
            failures.push("the generator sent no frame in the window".to_string());
        }
        if errors > 0 {
            failures.push(format!("{errors} error replies to the clients"));
        }
        let silent = figures.iter().filter(|f| f.values == 0).count();
        if silent > 0 {
            failures.push(format!("{silent} of {client_count} clients got no values message"));
        }
        if probe.is_empty() {
            failures.push("the frames topic delivered no frame".to_string());
        }
        common::exit_on_failures("stream_fanout", &failures);
    });
}
