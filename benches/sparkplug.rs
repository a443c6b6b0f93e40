//! The Sparkplug B edge node under load (issue 23): the release
//! `candeck serve` with a virtual bus of N UMC1BDS32 drives (default 127),
//! SYNC every 10 ms (each drive sends its four TPDOs on every SYNC), axis 1
//! of each in a velocity move (its position changes with every SYNC), and
//! the edge node publishing to a Mosquitto on loopback (Debian's
//! `mosquitto`, started here on a free port). A subscriber in this process
//! (rumqttc, the same prost types) counts the metrics of every DDATA
//! delivered and the latency of each TPDO metric: the time it was received
//! here less its timestamp (when the gateway received the TPDO frame),
//! both on this machine's clock, in whole milliseconds. The gateway's CPU
//! time (`/proc/PID/stat`) over the measured window and its resident
//! memory (`VmRSS`) at the end are read too. The virtual drives run inside
//! the gateway process: its CPU includes them.
//!
//! Run: `cargo bench --bench sparkplug -- --nodes 127 --seconds 20 --warmup 5`.

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
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

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|listener| listener.local_addr())
        .map(|addr| addr.port())
        .expect("a free port")
}

/// One HTTP request (Connection: close): the status and the body.
fn http(addr: &str, method: &str, path: &str, body: Option<&str>) -> (u16, String) {
    let mut stream = TcpStream::connect(addr).expect("connect to the gateway");
    stream
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    let body = body.unwrap_or("");
    write!(
        stream,
        "{method} /api/v1{path} HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    // The server may reset the connection once it has answered: what was
    // read is the answer.
    let mut bytes = Vec::new();
    let mut buf = [0u8; 8192];
    while let Ok(n) = stream.read(&mut buf) {
        if n == 0 {
            break;
        }
        bytes.extend_from_slice(&buf[..n]);
    }
    let answer = String::from_utf8_lossy(&bytes).into_owned();
    let status = answer
        .split(' ')
        .nth(1)
        .and_then(|code| code.parse().ok())
        .unwrap_or(0);
    let body = answer
        .split_once("\r\n\r\n")
        .map(|(_, body)| body.to_string())
        .unwrap_or_default();
    (status, body)
}

struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn cpu_seconds(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
    let fields: Vec<&str> = after.split_whitespace().collect();
    // utime and stime: fields 14 and 15 of stat, 12 and 13 after the ')'.
    let ticks: f64 = [11, 12]
        .iter()
        .filter_map(|at| fields.get(*at).and_then(|v| v.parse::<f64>().ok()))
        .sum();
    ticks / 100.0
}

fn rss_mib(pid: u32) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap_or_default()
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|kb| kb.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}

#[derive(Default)]
struct Counts {
    metrics: u64,
    messages: u64,
    latencies: Vec<u64>,
}

fn main() {
    let options = common::Options::from_args(Duration::from_secs(5), Duration::from_secs(20));
    let args: Vec<String> = std::env::args().collect();
    let nodes: u8 = args
        .iter()
        .position(|arg| arg == "--nodes")
        .and_then(|at| args.get(at + 1))
        .and_then(|n| n.parse().ok())
        .unwrap_or(127);
    let mosquitto = ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"]
        .into_iter()
        .find(|path| std::path::Path::new(path).exists());
    let Some(mosquitto) = mosquitto else {
        eprintln!("sparkplug bench: no mosquitto (Debian: apt-get install mosquitto): skipped");
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
    std::thread::sleep(Duration::from_millis(300));
    let config = dir.join("candeck.toml");
    std::fs::write(
        &config,
        format!(
            "listen = \"127.0.0.1:0\"\nbuses = [\"bench=virtual:empty?bitrate=unlimited\"]\n\
             sync_period_ms = 10\nlease_ms = 60000\n\
             mqtt_url = \"mqtt://127.0.0.1:{port}\"\nsparkplug_group_id = \"bench\"\n\
             sparkplug_edge_node_id = \"gw1\"\n"
        ),
    )
    .unwrap();
    let log = std::fs::File::create(dir.join("candeck.log")).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(["serve", "--config", config.to_str().unwrap()])
        .env("CANDECK_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(log)
        .spawn()
        .expect("candeck serve starts");
    let mut first = String::new();
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    stdout.read_line(&mut first).unwrap();
    // Its later lines are read too (a closed pipe would end it).
    std::thread::spawn(move || std::io::copy(&mut stdout, &mut std::io::sink()));
    let pid = child.id();
    let gateway = Killed(child);
    let addr = first
        .split("http://")
        .nth(1)
        .and_then(|rest| rest.split('/').next())
        .expect("the serving line")
        .to_string();

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
    for id in 1..=nodes {
        let (status, body) = http(
            &addr,
            "POST",
            "/buses/bench/sim/nodes",
            Some(&format!("{{\"product\":\"umc1bds32\",\"id\":{id}}}")),
        );
        assert!(status < 300, "add node {id}: {status} {body}");
    }
    // Identified, and their TPDO mappings read.
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let (_, body) = http(&addr, "GET", "/buses/bench/nodes", None);
        let done = body.matches("\"state\":\"done\"").count();
        if done >= usize::from(nodes) {
            break;
        }
        assert!(Instant::now() < deadline, "only {done} nodes identified");
        std::thread::sleep(Duration::from_millis(200));
    }
    http(
        &addr,
        "POST",
        "/buses/bench/nmt",
        Some("{\"command\":\"start\"}"),
    );
    for id in 1..=nodes {
        let base = format!("/buses/bench/nodes/{id}/axes/1");
        let (status, body) = http(
            &addr,
            "POST",
            &format!("{base}/state"),
            Some("{\"target\":\"operation_enabled\"}"),
        );
        assert!(status < 300, "enable node {id}: {status} {body}");
        let (status, body) = http(
            &addr,
            "POST",
            &format!("{base}/move"),
            Some("{\"mode\":\"velocity\",\"velocity\":20000}"),
        );
        assert!(status < 300, "move node {id}: {status} {body}");
    }
    println!(
        "sparkplug: {nodes} nodes identified, started, enabled and moving after {:.1} s",
        setup.elapsed().as_secs_f64()
    );
    std::thread::sleep(options.warmup);
    {
        let mut counts = counts.lock().unwrap();
        *counts = Counts::default();
    }
    let cpu_start = cpu_seconds(pid);
    let start = Instant::now();
    std::thread::sleep(options.measure);
    let elapsed = start.elapsed().as_secs_f64();
    let cpu = (cpu_seconds(pid) - cpu_start) / elapsed;
    let rss = rss_mib(pid);
    let mut counts = std::mem::take(&mut *counts.lock().unwrap());
    counts.latencies.sort_unstable();
    let pct = |p: f64| {
        let at = ((counts.latencies.len() as f64 - 1.0) * p).round() as usize;
        counts.latencies.get(at).copied().unwrap_or(0)
    };
    let (_, metrics_text) = {
        let mut stream = TcpStream::connect(&addr).unwrap();
        write!(
            stream,
            "GET /metrics HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n"
        )
        .unwrap();
        let mut text = String::new();
        stream.read_to_string(&mut text).unwrap();
        (0, text)
    };
    let published: Vec<&str> = metrics_text
        .lines()
        .filter(|line| line.starts_with("candeck_sparkplug_") && !line.starts_with('#'))
        .collect();
    println!(
        "sparkplug: {nodes} nodes, SYNC 10 ms: {:.0} metrics/s in {:.0} DDATA/s delivered to the subscriber; \
         latency p50 {} ms, p99 {} ms, max {} ms; gateway CPU {:.2} cores, RSS {:.1} MiB (over {elapsed:.1} s)",
        counts.metrics as f64 / elapsed,
        counts.messages as f64 / elapsed,
        pct(0.5),
        pct(0.99),
        counts.latencies.last().copied().unwrap_or(0),
        cpu,
        rss,
    );
    for line in published {
        println!("  {line}");
    }
    drop(gateway);
    // exit() below runs no destructor: the broker is stopped here.
    drop(broker);
    drop(subscriber);
    std::fs::remove_dir_all(&dir).ok();
    std::process::exit(0);
}
