//! Frames per second through the in-process hub and through the socketcand
//! server on loopback (one sender; one and ten receivers), and the same
//! traffic between two python-can clients through the same server, in one run.
//!
//! Run: `scripts/bench` (or `cargo bench --bench can_throughput`; the
//! python-can comparison uses `.venv` or `CANDECK_PYTHON`, and is skipped
//! without them unless `CANDECK_REQUIRE_PEERS` is set). A smoke run
//! (`CANDECK_BENCH_SMOKE`) sends a few thousand frames a row. A failed
//! python-can pair ends the run with status 1.
//! Frames: standard id 0x181, 8 data bytes (a TPDO), a counter in the data.
//!
//! The sender keeps at most `WINDOW` frames ahead of the slowest receiver,
//! so the figure is the rate every receiver sustains without loss, not how
//! fast frames can be dropped.

mod common;

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use candeck::can::socketcand::{
    ClientConfig, ServerConfig, ServerHandle, SocketcandServer, open_socketcand,
};
use candeck::can::{Bus, CanId, Frame, RecvError, VirtualHub};

const WINDOW: u64 = 4096;

fn frame(i: u64) -> Frame {
    Frame::new(CanId::Standard(0x181), &i.to_le_bytes()).expect("8 bytes fit")
}

fn rss_kib() -> (u64, u64) {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

struct Result {
    label: String,
    frames: u64,
    receivers: usize,
    seconds: f64,
}

impl Result {
    fn print(&self) {
        let rate = self.frames as f64 / self.seconds;
        println!(
            "| {} | {} | {} | {:.0} | {:.0} |",
            self.label,
            self.receivers,
            self.frames,
            rate,
            rate * self.receivers as f64
        );
    }
}

/// Sends `total` frames on `sender` while `receivers` count them; returns
/// the seconds until every receiver has every frame, checking order.
async fn run(sender: Bus, receivers: Vec<Bus>, total: u64) -> f64 {
    let progress: Vec<Arc<AtomicU64>> = receivers
        .iter()
        .map(|_| Arc::new(AtomicU64::new(0)))
        .collect();
    let mut tasks = Vec::new();
    for (bus, done) in receivers.iter().zip(&progress) {
        let mut rx = bus.subscribe();
        let done = done.clone();
        tasks.push(tokio::spawn(async move {
            let mut expected = 0u64;
            while expected < total {
                match rx.recv().await {
                    Ok(f) => {
                        let got = u64::from_le_bytes(f.frame.data().try_into().expect("8 bytes"));
                        assert_eq!(got, expected, "frames out of order or lost");
                        expected += 1;
                        if expected.is_multiple_of(256) || expected == total {
                            done.store(expected, Ordering::Release);
                        }
                    }
                    Err(RecvError::Lagged(n)) => panic!("receiver lost {n} frames"),
                    Err(RecvError::Closed) => panic!("bus closed"),
                }
            }
        }));
    }
    let start = Instant::now();
    for i in 0..total {
        loop {
            let slowest = progress
                .iter()
                .map(|p| p.load(Ordering::Acquire))
                .min()
                .unwrap_or(total);
            if i < slowest + WINDOW {
                break;
            }
            tokio::task::yield_now().await;
        }
        sender.send(frame(i)).await.expect("send");
    }
    for task in tasks {
        task.await.expect("receiver");
    }
    start.elapsed().as_secs_f64()
}

async fn hub_case(receivers: usize, total: u64) -> Result {
    let hub = VirtualHub::new("bench");
    let sender = hub.attach();
    let rx: Vec<Bus> = (0..receivers).map(|_| hub.attach()).collect();
    let seconds = run(sender, rx, total).await;
    Result {
        label: "in-process hub".into(),
        frames: total,
        receivers,
        seconds,
    }
}

/// A socketcand server on loopback sharing a new, empty virtual bus `can0`.
async fn serve_empty_bus() -> ServerHandle {
    SocketcandServer::bind(
        SocketAddr::from(([127, 0, 0, 1], 0)),
        [("can0".to_string(), VirtualHub::new("can0"))],
        ServerConfig::default(),
    )
    .await
    .expect("bind")
    .spawn()
    .expect("spawn")
}

/// One receiver at full speed while another client completes the handshake
/// and never reads again: reports the stalled client's fate and how much
/// the process grew, to show that it buffers nothing without bound.
async fn stalled_case(total: u64) -> (Result, u64, u64) {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let server = serve_empty_bus().await;
    let port = server.local_addr().port();
    let mut stalled = tokio::net::TcpStream::connect(server.local_addr())
        .await
        .expect("connect");
    stalled
        .write_all(b"< open can0 >< rawmode >")
        .await
        .expect("handshake");
    let mut greeting = [0u8; 64];
    let _ = stalled.read(&mut greeting).await;
    let join = || open_socketcand("can0", ClientConfig::new("127.0.0.1", port, "can0"));
    let sender = join();
    let receiver = join();
    for bus in [&sender, &receiver] {
        bus.wait_up(Duration::from_secs(5)).await.expect("up");
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let (before, _) = rss_kib();
    let seconds = run(sender, vec![receiver], total).await;
    let (after, _) = rss_kib();
    // Its writer notices when the blocked write times out (5 s) at the
    // latest; a smoke run sends too few frames to fill its buffers.
    let wait_start = Instant::now();
    let wait = common::pick(Duration::from_secs(10), Duration::ZERO);
    while server.stats().slow_clients_dropped.load(Ordering::Relaxed) == 0
        && wait_start.elapsed() < wait
    {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let dropped = server.stats().slow_clients_dropped.load(Ordering::Relaxed);
    drop(stalled);
    (
        Result {
            label: "socketcand, loopback, with a stalled client".into(),
            frames: total,
            receivers: 1,
            seconds,
        },
        after.saturating_sub(before),
        dropped,
    )
}

async fn socketcand_case(receivers: usize, total: u64) -> Result {
    let server = serve_empty_bus().await;
    let port = server.local_addr().port();
    let join = || open_socketcand("can0", ClientConfig::new("127.0.0.1", port, "can0"));
    let sender = join();
    let rx: Vec<Bus> = (0..receivers).map(|_| join()).collect();
    for bus in std::iter::once(&sender).chain(&rx) {
        bus.wait_up(Duration::from_secs(5)).await.expect("up");
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let seconds = run(sender, rx, total).await;
    Result {
        label: "socketcand, loopback (candeck clients)".into(),
        frames: total,
        receivers,
        seconds,
    }
}

/// python-can sender → candeck socketcand server → python-can receiver;
/// why it failed, if it did.
async fn python_case(python: &std::path::Path, total: u64) -> std::result::Result<Result, String> {
    let server = serve_empty_bus().await;
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/python_can_pair.py");
    let output = tokio::process::Command::new(python)
        .arg(script)
        .arg(server.local_addr().port().to_string())
        .arg(total.to_string())
        .output()
        .await
        .map_err(|err| format!("{}: {err}", python.display()))?;
    if !output.status.success() {
        return Err(format!(
            "python-can pair failed ({}): {}",
            output.status,
            String::from_utf8_lossy(&output.stderr)
        ));
    }
    let text = String::from_utf8_lossy(&output.stdout);
    let seconds: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("python-can pair printed no seconds: {text}"))?;
    Ok(Result {
        label: "socketcand, loopback (python-can clients)".into(),
        frames: total,
        receivers: 1,
        seconds,
    })
}

fn main() {
    common::announce_smoke("can_throughput");
    let size = |frames: u64| common::pick(frames, 5_000);
    // The runtime of the candeck binary; BENCH_MULTI_THREAD=1 for tokio's
    // multi-thread scheduler instead.
    let runtime = if std::env::var_os("BENCH_MULTI_THREAD").is_some() {
        tokio::runtime::Runtime::new()
    } else {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
    }
    .expect("runtime");
    runtime.block_on(async {
        let (rss_start, _) = rss_kib();
        println!("| path | receivers | frames | frames/s per receiver | frames/s delivered |");
        println!("|---|---|---|---|---|");
        hub_case(1, size(2_000_000)).await.print();
        hub_case(10, size(1_000_000)).await.print();
        socketcand_case(1, size(1_000_000)).await.print();
        socketcand_case(10, size(300_000)).await.print();
        let (stalled, growth, dropped) = stalled_case(size(1_000_000)).await;
        stalled.print();
        let mut failures = Vec::new();
        match common::peers::python("can_throughput, python-can row") {
            Some(python) => match python_case(&python, common::pick(50_000, 2_000)).await {
                Ok(result) => result.print(),
                Err(err) => {
                    println!("| python-can clients | - | - | failed | - |");
                    failures.push(err);
                }
            },
            None => println!("| python-can clients | - | - | skipped: no Python peers | - |"),
        }
        let (rss_end, hwm) = rss_kib();
        println!();
        println!("process memory: {rss_start} KiB at start, {rss_end} KiB at end, peak {hwm} KiB");
        println!(
            "stalled client: dropped {dropped} time(s); resident memory grew {growth} KiB during the run"
        );
        common::exit_on_failures("can_throughput", &failures);
    });
}
