//! One `candeck vbus` process with 127 virtual devices of mixed products,
//! each heartbeating every 100 ms and sending a TPDO every 10 ms: does the
//! simulation keep real time, and what does it cost?
//!
//! The benchmark runs the release binary as a user would, configures every
//! device over its socketcand server as a master would (SDO writes to 0x1017
//! and TPDO1's communication parameters, every drive's axes enabled and
//! moving at a constant velocity, then NMT start), and listens for
//! `--seconds` (default 20). It reports the frames received per node and
//! product, the vbus process's CPU time and resident memory (from /proc), and
//! the simulation clock's own count of ticks that ran more than one tick
//! late (the process logs it when it stops).
//!
//! Run: `cargo bench --bench vbus_realtime` (or `scripts/bench`);
//! `-- --seconds 60` for a longer run. A smoke run (`CANDECK_BENCH_SMOKE`)
//! has one device of each product and measures 0.5 s. A device that sent no
//! heartbeat or no TPDO1 in the window ends the run with status 1.

mod common;

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use candeck::can::socketcand::{ClientConfig, open_socketcand};
use candeck::can::{Bus, CanId, Frame};
use candeck::canopen::NodeId;
use candeck::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};
use candeck::canopen::sdo;
use candeck::gateway::SdoChannel;

const PRODUCTS: [&str; 4] = ["umc1bds32", "umc1bd90", "uio1led", "jmc"];
const HEARTBEAT_MS: u16 = 100;
const TPDO_MS: u16 = 10;

fn product_of(node: u8) -> &'static str {
    PRODUCTS[usize::from(node - 1) % PRODUCTS.len()]
}

/// utime + stime of a process, in seconds, and its resident memory in KiB
/// (now and peak).
fn process_usage(pid: u32) -> (f64, u64, u64) {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command name (which may hold spaces) in parentheses.
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest.split_whitespace().collect())
        .unwrap_or_default();
    let ticks_per_s = 100.0; // USER_HZ on Linux
    let cpu = fields
        .get(11)
        .and_then(|u| u.parse::<f64>().ok())
        .unwrap_or(0.0)
        + fields
            .get(12)
            .and_then(|s| s.parse::<f64>().ok())
            .unwrap_or(0.0);
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let kib = |key: &str| {
        status
            .lines()
            .find(|line| line.starts_with(key))
            .and_then(|line| line.split_whitespace().nth(1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(0)
    };
    (cpu / ticks_per_s, kib("VmRSS:"), kib("VmHWM:"))
}

/// Heartbeat and a TPDO1 with an event timer (where the product has one;
/// otherwise sent on change of its mapped values, which a moving drive
/// changes every millisecond).
async fn configure(bus: &Bus, node: NodeId) -> Result<(), String> {
    let channel = SdoChannel::new(bus.clone(), node, sdo::ClientConfig::default());
    let write = |index: u16, sub: u8, data: Vec<u8>| {
        let channel = &channel;
        async move {
            channel
                .download(index, sub, &data)
                .await
                .map_err(|err| format!("node {node} 0x{index:04X} sub {sub}: {err}"))
        }
    };
    write(0x1017, 0, HEARTBEAT_MS.to_le_bytes().to_vec()).await?;
    let cob = 0x180 + u32::from(node.get());
    write(0x1800, 1, (cob | 0x8000_0000).to_le_bytes().to_vec()).await?;
    write(0x1800, 2, vec![254]).await?;
    let has_timer = write(0x1800, 5, TPDO_MS.to_le_bytes().to_vec())
        .await
        .is_ok();
    write(0x1800, 1, cob.to_le_bytes().to_vec()).await?;
    // Every drive moves, so that its model does its most work: the UMC's
    // axes in VL (0x6042), the JMC in its velocity mode.
    let axes: &[u16] = match product_of(node.get()) {
        "umc1bds32" => &[0, 0x800],
        "umc1bd90" => &[0],
        _ => &[],
    };
    for &offset in axes {
        write(0x6060 + offset, 0, vec![2]).await?;
        write(0x6042 + offset, 0, 300i16.to_le_bytes().to_vec()).await?;
        for controlword in [6u16, 7, 15] {
            write(0x6040 + offset, 0, controlword.to_le_bytes().to_vec()).await?;
        }
    }
    if !has_timer {
        // The JMC has no event timer (its manual gives TPDOs sub 0-2 only):
        // a velocity move changes its position, and so its TPDO1, all the time.
        write(0x6060, 0, vec![3]).await?;
        write(0x6083, 0, 100u16.to_le_bytes().to_vec()).await?;
        write(0x6084, 0, 100u16.to_le_bytes().to_vec()).await?;
        // Its velocity mode runs at 0x6081, in 0.1 rps (manual §5).
        write(0x6081, 0, 50u32.to_le_bytes().to_vec()).await?;
        for controlword in [6u16, 7, 15] {
            write(0x6040, 0, controlword.to_le_bytes().to_vec()).await?;
        }
    }
    Ok(())
}

fn main() {
    common::announce_smoke("vbus_realtime");
    let seconds: f64 = std::env::args()
        .skip_while(|arg| arg != "--seconds")
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(common::pick(20.0, 0.5));
    // Node ids 1 to this, the products in turn.
    let count: u8 = common::pick(127, PRODUCTS.len() as u8);
    let devices: Vec<String> = (1..=count)
        .map(|node| format!("{}@{node}", product_of(node)))
        .collect();
    let mut vbus = Command::new(env!("CARGO_BIN_EXE_candeck"))
        // The simulation is measured, not the wire.
        .args(["vbus", "--listen", "127.0.0.1:0", "--bitrate", "unlimited"])
        .arg("--devices")
        .arg(devices.join(","))
        .env("CANDECK_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("candeck vbus starts");
    let pid = vbus.id();
    let mut first = String::new();
    BufReader::new(vbus.stdout.take().expect("stdout"))
        .read_line(&mut first)
        .expect("first line");
    let port: u16 = first
        .split("socketcand on 127.0.0.1:")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|port| port.parse().ok())
        .unwrap_or_else(|| panic!("unexpected first line: {first}"));
    let (_, rss_idle, _) = process_usage(pid);

    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    let (counts, elapsed, cpu, rss, hwm) = runtime.block_on(async {
        let bus = open_socketcand("can0", ClientConfig::new("127.0.0.1", port, "can0"));
        bus.wait_up(Duration::from_secs(5)).await.expect("bus up");
        for node in 1..=count {
            let node = NodeId::new(node).expect("node id");
            if let Err(err) = configure(&bus, node).await {
                panic!("configuring {node}: {err}");
            }
        }
        let mut frames = bus.subscribe();
        let start_all = NmtMessage::new(NmtCommand::Start, NmtTarget::All).encode();
        bus.send(start_all).await.expect("NMT start");
        // Let every TPDO start, then measure.
        tokio::time::sleep(Duration::from_millis(500)).await;
        while let Ok(Some(_)) = frames.try_recv() {}
        let (cpu_start, _, _) = process_usage(pid);
        let started = Instant::now();
        let until = tokio::time::Instant::now() + Duration::from_secs_f64(seconds);
        let mut counts: BTreeMap<(u8, &'static str), u64> = BTreeMap::new();
        loop {
            match tokio::time::timeout_at(until, frames.recv()).await {
                Ok(Ok(received)) => {
                    let frame: Frame = received.frame;
                    let CanId::Standard(id) = frame.id() else {
                        continue;
                    };
                    let (base, node) = (id & 0x780, (id & 0x7F) as u8);
                    let kind = match base {
                        0x180 => "tpdo1",
                        0x700 => "heartbeat",
                        _ => "other",
                    };
                    *counts.entry((node, kind)).or_default() += 1;
                }
                Ok(Err(err)) => panic!("receiving: {err}"),
                Err(_) => break,
            }
        }
        let elapsed = started.elapsed().as_secs_f64();
        let (cpu_end, rss, hwm) = process_usage(pid);
        (counts, elapsed, cpu_end - cpu_start, rss, hwm)
    });

    // SIGTERM: vbus logs its simulation clock's figures and exits.
    let _ = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status();
    let mut log = String::new();
    vbus.stderr
        .take()
        .expect("stderr")
        .read_to_string(&mut log)
        .expect("log");
    let _ = vbus.wait();
    let clock = log
        .lines()
        .find(|line| line.contains("simulation:"))
        .unwrap_or("(no simulation figures in the log)");

    println!("## vbus: {count} devices, {seconds} s measured\n");
    println!(
        "| product | devices | heartbeats/s per device (min · mean · max) | TPDO1/s per device (min · mean · max) |"
    );
    println!("|---|---|---|---|");
    for product in PRODUCTS {
        let nodes: Vec<u8> = (1..=count).filter(|n| product_of(*n) == product).collect();
        let rate = |kind: &'static str| {
            let rates: Vec<f64> = nodes
                .iter()
                .map(|n| *counts.get(&(*n, kind)).unwrap_or(&0) as f64 / elapsed)
                .collect();
            let min = rates.iter().cloned().fold(f64::INFINITY, f64::min);
            let max = rates.iter().cloned().fold(0.0, f64::max);
            let mean = rates.iter().sum::<f64>() / rates.len() as f64;
            format!("{min:.1} · {mean:.1} · {max:.1}")
        };
        println!(
            "| {product} | {} | {} | {} |",
            nodes.len(),
            rate("heartbeat"),
            rate("tpdo1")
        );
    }
    let total: u64 = counts.values().sum();
    println!();
    println!(
        "- frames received: {total} in {elapsed:.1} s ({:.0}/s)",
        total as f64 / elapsed
    );
    println!(
        "- vbus CPU: {cpu:.2} s in {elapsed:.1} s = {:.1} % of one core",
        100.0 * cpu / elapsed
    );
    println!(
        "- vbus resident memory: {rss_idle} KiB after start, {rss} KiB at the end, peak {hwm} KiB"
    );
    println!("- vbus log: {}", clock.trim());
    for line in log
        .lines()
        .filter(|line| line.contains("WARN") || line.contains("ERROR"))
    {
        println!("- vbus log: {}", line.trim());
    }
    let silent: Vec<String> = (1..=count)
        .flat_map(|node| ["heartbeat", "tpdo1"].map(|kind| (node, kind)))
        .filter(|key| !counts.contains_key(key))
        .map(|(node, kind)| format!("node {node} ({}) sent no {kind}", product_of(node)))
        .collect();
    common::exit_on_failures("vbus_realtime", &silent);
}
