//! The virtual bus's wire (`candeck::can::timing`): frames a second at
//! saturation at 125, 250, 500 and 1000 kbit/s against the arithmetic
//! (bit rate / 135 bits, an 8-byte standard frame with worst-case stuffing),
//! and what the timing model costs: the sans-I/O `Wire` alone (ns a frame),
//! and the process's CPU while a timed hub is saturated, against an
//! unlimited hub carrying the same frames.
//!
//! Run: `cargo bench --bench vbus_wire` (`-- --seconds N` for longer runs;
//! 0.1 s a row and 10,000 frames for the `Wire` in a smoke run,
//! `CANDECK_BENCH_SMOKE`). One tokio current-thread runtime, one sender that
//! keeps its transmit queue full, one receiver; real time, not a paused
//! clock. A row whose receiver got no frame ends the run with status 1.

mod common;

use std::time::{Duration, Instant};

use candeck::can::timing::{Bitrate, Wire, frame_bits};
use candeck::can::{CanId, Frame, VirtualHub};

fn frame(i: u64) -> Frame {
    Frame::new(CanId::Standard(0x181), &i.to_le_bytes()).expect("8 bytes fit")
}

/// User + system CPU time of this process so far (from /proc, 10 ms ticks).
fn cpu_time() -> Duration {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command's closing parenthesis; utime and stime are
    // the 14th and 15th of the whole line.
    let rest = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
    let fields: Vec<u64> = rest
        .split_whitespace()
        .map(|f| f.parse().unwrap_or(0))
        .collect();
    let ticks = fields.get(11).copied().unwrap_or(0) + fields.get(12).copied().unwrap_or(0);
    Duration::from_millis(ticks * 10)
}

struct Run {
    frames: u64,
    wall: Duration,
    cpu: Duration,
}

/// A sender keeps the hub's transmit queue full for `seconds`; the frames
/// the receiver got, the time and the CPU it took.
async fn saturate(hub: VirtualHub, seconds: f64) -> Run {
    let sender = hub.attach();
    let receiver = hub.attach();
    let mut rx = receiver.subscribe();
    let run_for = Duration::from_secs_f64(seconds);
    let cpu0 = cpu_time();
    let t0 = Instant::now();
    let send = tokio::spawn(async move {
        let mut i = 0;
        while t0.elapsed() < run_for {
            sender.send(frame(i)).await.expect("send");
            i += 1;
            if i % 256 == 0 {
                // An unlimited hub never makes the sender wait.
                tokio::task::yield_now().await;
            }
        }
    });
    let mut frames = 0;
    while t0.elapsed() < run_for {
        match tokio::time::timeout(Duration::from_millis(50), rx.recv()).await {
            Ok(Ok(_)) => frames += 1,
            Ok(Err(candeck::can::RecvError::Lagged(n))) => frames += n,
            Ok(Err(_)) => break,
            Err(_) => {}
        }
    }
    let wall = t0.elapsed();
    let cpu = cpu_time() - cpu0;
    send.abort();
    Run { frames, wall, cpu }
}

fn main() {
    common::announce_smoke("vbus_wire");
    let seconds = std::env::args()
        .skip_while(|a| a != "--seconds")
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(common::pick(2.0, 0.1));
    let mut failures = Vec::new();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    let bits = frame_bits(&frame(0));
    println!("8-byte standard frame: {bits} bits with worst-case stuffing");
    println!();
    println!("| bit rate | arithmetic frames/s | measured frames/s | ratio | CPU |");
    println!("|---|---|---|---|---|");
    for rate in [125_000u32, 250_000, 500_000, 1_000_000] {
        let run = runtime.block_on(async {
            saturate(
                VirtualHub::with_bitrate("bench", Bitrate::bits_per_second(rate)),
                seconds,
            )
            .await
        });
        if run.frames == 0 {
            failures.push(format!("{} kbit/s: no frame received", rate / 1000));
        }
        let measured = run.frames as f64 / run.wall.as_secs_f64();
        let arithmetic = f64::from(rate) / f64::from(bits);
        println!(
            "| {} kbit/s | {arithmetic:.0} | {measured:.0} | {:.4} | {:.1} % |",
            rate / 1000,
            measured / arithmetic,
            100.0 * run.cpu.as_secs_f64() / run.wall.as_secs_f64()
        );
    }
    let unlimited = runtime.block_on(async {
        saturate(
            VirtualHub::with_bitrate("bench", Bitrate::Unlimited),
            seconds,
        )
        .await
    });
    if unlimited.frames == 0 {
        failures.push("unlimited: no frame received".to_string());
    }
    println!(
        "| unlimited | - | {:.0} | - | {:.1} % |",
        unlimited.frames as f64 / unlimited.wall.as_secs_f64(),
        100.0 * unlimited.cpu.as_secs_f64() / unlimited.wall.as_secs_f64()
    );

    // The model alone: queue and carry 1,000,000 frames from 4 senders.
    let n: u64 = common::pick(1_000_000, 10_000);
    let mut wire = Wire::new(Bitrate::bits_per_second(1_000_000));
    let t0 = Instant::now();
    let start = Instant::now();
    let mut now = start;
    let mut carried = 0;
    for i in 0..n {
        wire.queue((i % 4) as u8, frame(i), now);
        if i % 4 == 3 {
            now += Duration::from_micros(540);
            carried += wire.poll(now).len() as u64;
        }
    }
    carried += wire.poll(now + Duration::from_secs(10)).len() as u64;
    let elapsed = t0.elapsed();
    assert_eq!(carried, n);
    println!();
    println!(
        "Wire alone: {n} frames queued and carried in {:.3} s: {:.0} ns a frame",
        elapsed.as_secs_f64(),
        elapsed.as_nanos() as f64 / n as f64
    );
    common::exit_on_failures("vbus_wire", &failures);
}
