//! The Sparkplug B edge node under load (issue 23): release `candeck`
//! gateways, each attached over socketcand to a `candeck vbus` process of
//! its own with N UMC1BDS32 drives (default 127), so that the gateway's CPU
//! is its own and the drives' is the vbus's. SYNC every 10 ms; each drive's
//! TPDO3 and TPDO4 are mapped (over the gateway's REST API) to axis 1's and
//! axis 2's position actual value and position demand value, and both axes
//! run a velocity move, so that each drive sends 4 values that change on
//! every SYNC (plus its statuswords, mode and velocities, which do not).
//! Every gateway's edge node publishes to one Mosquitto on loopback
//! (Debian's `mosquitto`, started here on a free port). A subscriber in
//! this process (rumqttc, the same prost types) counts the metrics of every
//! DDATA delivered and the latency of each metric: the time it was received
//! here less its timestamp (when the gateway received the TPDO frame), both
//! on this machine's clock, in whole milliseconds. Each process's CPU time
//! (`/proc/PID/stat`) over the measured window and its resident memory
//! (`VmRSS`) at the end are read; the gateway's `/metrics` counters of the
//! edge node (messages, metrics, drops) are printed.
//!
//! Run: `cargo bench --bench sparkplug -- --nodes 127 --gateways 1 --tick-ms 10 --seconds 20 --warmup 5`
//! (`--tick-ms`: the gateways' `sparkplug_publish_tick_ms`). A smoke run
//! (`CANDECK_BENCH_SMOKE`) has 2 drives, 0.5 s of warm-up and 1 s measured.
//! Without `mosquitto` it is skipped (said on stderr), unless
//! `CANDECK_REQUIRE_PEERS` is set; no DDATA metric received in the window
//! ends the run with status 1.

mod common;

use common::process::{Killed, arg, cpu_seconds, free_port, http, lines_until, rss_mib, umc_vbus};

use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use candeck::sparkplug::proto::Payload;
use prost::Message;
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};

fn unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |elapsed| elapsed.as_millis() as u64)
}

#[derive(Default)]
struct Counts {
    metrics: u64,
    messages: u64,
    latencies: Vec<u64>,
}

/// One line of the plant: a vbus with `nodes` drives, and a gateway
/// attached to it, edge node `gw{k}`.
struct Line {
    vbus: Killed,
    gateway: Killed,
    addr: String,
}

impl Line {
    fn start(dir: &std::path::Path, k: usize, nodes: u8, broker: u16, tick_ms: u64) -> Self {
        let (vbus, share) = umc_vbus(dir, &format!("vbus{k}.log"), nodes);
        let config = dir.join(format!("candeck{k}.toml"));
        std::fs::write(
            &config,
            format!(
                "listen = \"127.0.0.1:0\"\nbuses = [\"bench=socketcand:127.0.0.1:{share}/can0\"]\n\
                 sync_period_ms = 10\nlease_ms = 60000\n\
                 mqtt_url = \"mqtt://127.0.0.1:{broker}\"\nsparkplug_group_id = \"bench\"\n\
                 sparkplug_edge_node_id = \"gw{k}\"\nsparkplug_publish_tick_ms = {tick_ms}\n"
            ),
        )
        .unwrap();
        let mut child = Command::new(env!("CARGO_BIN_EXE_candeck"))
            .args(["serve", "--config", config.to_str().unwrap()])
            .env("CANDECK_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(dir.join(format!("candeck{k}.log"))).unwrap())
            .spawn()
            .expect("candeck serve starts");
        let first = lines_until(&mut child, "").remove(0);
        let addr = first
            .split("http://")
            .nth(1)
            .and_then(|rest| rest.split('/').next())
            .expect("the serving line")
            .to_string();
        Self {
            vbus,
            gateway: Killed(child),
            addr,
        }
    }

    /// Every drive identified, TPDO3 and TPDO4 remapped to 4 changing
    /// values, started, both axes enabled and moving.
    fn set_up(&self, nodes: u8) {
        let addr = &self.addr;
        let deadline = Instant::now() + Duration::from_secs(300);
        loop {
            let (_, body) = http(addr, "GET", "/buses/bench/nodes", None);
            let done = body.matches("\"state\":\"done\"").count();
            if done >= usize::from(nodes) {
                break;
            }
            assert!(
                Instant::now() < deadline,
                "{addr}: only {done} nodes identified"
            );
            std::thread::sleep(Duration::from_millis(200));
        }
        let (status, body) = http(
            addr,
            "POST",
            "/buses/bench/nmt",
            Some("{\"command\":\"pre_operational\"}"),
        );
        assert!(status < 300, "NMT pre_operational: {status} {body}");
        for id in 1..=nodes {
            for (tpdo, axis) in [(3, "0x60"), (4, "0x68")] {
                let body = format!(
                    "{{\"transmission_type\":1,\"mapping\":[{{\"index\":\"{axis}64\"}},{{\"index\":\"{axis}62\"}}]}}"
                );
                // On a loaded machine an SDO may time out: tried 3 times.
                let path = format!("/buses/bench/nodes/{id}/pdos/tpdo/{tpdo}");
                let (mut status, mut answer) = http(addr, "PUT", &path, Some(&body));
                for _ in 0..2 {
                    if status < 300 {
                        break;
                    }
                    std::thread::sleep(Duration::from_secs(1));
                    (status, answer) = http(addr, "PUT", &path, Some(&body));
                }
                assert!(
                    status < 300,
                    "map TPDO{tpdo} of node {id}: {status} {answer}"
                );
            }
        }
        let (status, body) = http(
            addr,
            "POST",
            "/buses/bench/nmt",
            Some("{\"command\":\"start\"}"),
        );
        assert!(status < 300, "NMT start: {status} {body}");
        for id in 1..=nodes {
            for axis in 1..=2 {
                let base = format!("/buses/bench/nodes/{id}/axes/{axis}");
                let (status, body) = http(
                    addr,
                    "POST",
                    &format!("{base}/state"),
                    Some("{\"target\":\"operation_enabled\"}"),
                );
                assert!(
                    status < 300,
                    "enable node {id} axis {axis}: {status} {body}"
                );
                let (status, body) = http(
                    addr,
                    "POST",
                    &format!("{base}/move"),
                    Some("{\"mode\":\"velocity\",\"velocity\":20000}"),
                );
                assert!(status < 300, "move node {id} axis {axis}: {status} {body}");
            }
        }
    }

    fn edge_counters(&self) -> Vec<String> {
        let mut stream = TcpStream::connect(&self.addr).unwrap();
        write!(
            stream,
            "GET /metrics HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"
        )
        .unwrap();
        let mut text = String::new();
        let _ = stream.read_to_string(&mut text);
        text.lines()
            .filter(|line| line.starts_with("candeck_sparkplug_") && !line.starts_with('#'))
            .map(str::to_string)
            .collect()
    }
}

fn main() {
    common::announce_smoke("sparkplug");
    let options = common::Options::from_args(
        common::pick(Duration::from_secs(5), Duration::from_millis(500)),
        common::pick(Duration::from_secs(20), Duration::from_secs(1)),
    );
    let nodes: u8 = arg("--nodes", common::pick(127, 2));
    let lines_wanted: usize = arg("--gateways", 1);
    let tick_ms: u64 = arg("--tick-ms", 10);
    let Some(mosquitto) = common::peers::mosquitto("sparkplug bench") else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("candeck-spb-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let port = free_port();
    let conf = dir.join("mosquitto.conf");
    std::fs::write(
        &conf,
        format!("listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n"),
    )
    .unwrap();
    let broker = Killed(
        Command::new(mosquitto)
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("mosquitto starts"),
    );
    let broker_pid = broker.0.id();
    std::thread::sleep(Duration::from_millis(300));

    // The subscriber first: it sees the births.
    let counts = Arc::new(Mutex::new(Counts::default()));
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let counting = counts.clone();
    let subscriber = std::thread::spawn(move || {
        runtime.block_on(async move {
            let mut options = MqttOptions::new("bench-host", "127.0.0.1", port);
            options.set_max_packet_size(16 << 20, 16 << 20);
            let (client, mut events) = AsyncClient::new(options, 100);
            client
                .subscribe("spBv1.0/bench/#", QoS::AtMostOnce)
                .await
                .unwrap();
            while let Ok(event) = events.poll().await {
                let Event::Incoming(Packet::Publish(publish)) = event else {
                    continue;
                };
                if !publish.topic.contains("/DDATA/") {
                    continue;
                }
                let now = unix_ms();
                let Ok(payload) = Payload::decode(publish.payload.as_ref()) else {
                    continue;
                };
                let mut counts = counting.lock().unwrap();
                counts.messages += 1;
                counts.metrics += payload.metrics.len() as u64;
                for metric in &payload.metrics {
                    if let Some(at) = metric.timestamp {
                        counts.latencies.push(now.saturating_sub(at));
                    }
                }
            }
        })
    });

    let setup = Instant::now();
    let lines: Vec<Line> = (1..=lines_wanted)
        .map(|k| Line::start(&dir, k, nodes, port, tick_ms))
        .collect();
    for line in &lines {
        line.set_up(nodes);
    }
    println!(
        "sparkplug: {lines_wanted} gateway(s) x {nodes} nodes identified, remapped, started, enabled and moving after {:.1} s",
        setup.elapsed().as_secs_f64()
    );
    std::thread::sleep(options.warmup);
    {
        let mut counts = counts.lock().unwrap();
        *counts = Counts::default();
    }
    let pids = |pick: fn(&Line) -> u32| lines.iter().map(pick).collect::<Vec<u32>>();
    let gateway_pids = pids(|line| line.gateway.0.id());
    let vbus_pids = pids(|line| line.vbus.0.id());
    let cpu = |pids: &[u32]| {
        pids.iter()
            .map(|pid| cpu_seconds(*pid))
            .collect::<Vec<f64>>()
    };
    let (gw_start, vbus_start, broker_start) =
        (cpu(&gateway_pids), cpu(&vbus_pids), cpu_seconds(broker_pid));
    let start = Instant::now();
    std::thread::sleep(options.measure);
    let elapsed = start.elapsed().as_secs_f64();
    let used = |now: Vec<f64>, then: &[f64]| {
        now.iter()
            .zip(then)
            .map(|(now, then)| (now - then) / elapsed)
            .collect::<Vec<f64>>()
    };
    let gw_cpu = used(cpu(&gateway_pids), &gw_start);
    let vbus_cpu = used(cpu(&vbus_pids), &vbus_start);
    let broker_cpu = (cpu_seconds(broker_pid) - broker_start) / elapsed;
    let gw_rss: Vec<f64> = gateway_pids.iter().map(|pid| rss_mib(*pid)).collect();
    let mut counts = std::mem::take(&mut *counts.lock().unwrap());
    counts.latencies.sort_unstable();
    let pct = |p: f64| {
        let at = ((counts.latencies.len() as f64 - 1.0) * p).round() as usize;
        counts.latencies.get(at).copied().unwrap_or(0)
    };
    let sum = |v: &[f64]| v.iter().sum::<f64>();
    let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
    println!(
        "sparkplug: {lines_wanted} gateway(s) x {nodes} nodes, SYNC 10 ms, publish tick {tick_ms} ms: {:.0} metrics/s in {:.0} DDATA/s delivered to the subscriber; \
         latency p50 {} ms, p99 {} ms, max {} ms; gateway CPU {:.2} cores in all (max {:.2} per gateway), \
         gateway RSS max {:.1} MiB; vbus CPU {:.2} cores in all; mosquitto CPU {:.2} cores (over {elapsed:.1} s)",
        counts.metrics as f64 / elapsed,
        counts.messages as f64 / elapsed,
        pct(0.5),
        pct(0.99),
        counts.latencies.last().copied().unwrap_or(0),
        sum(&gw_cpu),
        max(&gw_cpu),
        max(&gw_rss),
        sum(&vbus_cpu),
        broker_cpu,
    );
    for (k, line) in lines.iter().enumerate() {
        println!(
            "  gw{}: CPU {:.2} cores, RSS {:.1} MiB; vbus CPU {:.2} cores",
            k + 1,
            gw_cpu[k],
            gw_rss[k],
            vbus_cpu[k]
        );
        for counter in line.edge_counters() {
            println!("    {counter}");
        }
    }
    drop(lines);
    // exit() below runs no destructor: the broker is stopped here.
    drop(broker);
    drop(subscriber);
    std::fs::remove_dir_all(&dir).ok();
    if counts.metrics == 0 {
        eprintln!("sparkplug: FAIL: no DDATA metric reached the subscriber in the window");
        std::process::exit(1);
    }
    std::process::exit(0);
}
