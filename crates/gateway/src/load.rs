//! The load of a served bus, measured, not assumed: every second a task
//! reads the attachment's bit counters (each frame counted by
//! [`Frame::wire_bits`](crate::can::Frame::wire_bits), sent or received,
//! stuff bits left out) and divides the bits of the last second by the
//! bus's bit rate.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use crate::can::Bus;

/// How often the bit counters are sampled, and so the window the load is
/// averaged over.
const LOAD_WINDOW: Duration = Duration::from_secs(1);

/// The frame and bit counts of a served bus: its attachment's counters
/// (what the gateway sent, and everything it heard from the others).
#[derive(Clone)]
pub struct Traffic {
    bus: Bus,
}

/// Counts of a bus at one moment, as the gateway's attachment sees them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TrafficSample {
    /// Frames from other nodes.
    pub rx_frames: u64,
    /// Frames the gateway sent.
    pub tx_frames: u64,
    /// Every bit on the bus, both ways.
    pub bits: u64,
}

impl Traffic {
    pub fn new(bus: &Bus) -> Self {
        Self { bus: bus.clone() }
    }

    pub fn sample(&self) -> TrafficSample {
        let counters = self.bus.counters();
        TrafficSample {
            rx_frames: counters.rx_frames,
            tx_frames: counters.tx_frames,
            bits: counters.rx_bits + counters.tx_bits,
        }
    }
}

/// The bits a bus carried in the last second, sampled by a task
/// that ends when the meter is dropped.
pub struct LoadMeter {
    bits_last_window: Arc<AtomicU64>,
    bitrate: u32,
    sampler: tokio::task::AbortHandle,
}

impl LoadMeter {
    /// Starts sampling `bus`, whose nominal bit rate is `bitrate` bit/s.
    /// Needs a tokio runtime.
    pub fn spawn(traffic: Traffic, bitrate: u32) -> Self {
        let bits_last_window = Arc::new(AtomicU64::new(0));
        let out = bits_last_window.clone();
        let sampler = tokio::spawn(async move {
            let mut previous = traffic.sample().bits;
            let mut ticks = tokio::time::interval(LOAD_WINDOW);
            ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            ticks.tick().await;
            loop {
                ticks.tick().await;
                let now = traffic.sample().bits;
                out.store(now.saturating_sub(previous), Ordering::Relaxed);
                previous = now;
            }
        })
        .abort_handle();
        Self {
            bits_last_window,
            bitrate: bitrate.max(1),
            sampler,
        }
    }

    pub fn bits_per_second(&self) -> u64 {
        self.bits_last_window.load(Ordering::Relaxed) * 1000 / LOAD_WINDOW.as_millis() as u64
    }

    pub fn bitrate(&self) -> u32 {
        self.bitrate
    }

    /// The fraction of the bit rate used in the last window.
    pub fn load(&self) -> f64 {
        self.bits_per_second() as f64 / f64::from(self.bitrate)
    }
}

impl Drop for LoadMeter {
    fn drop(&mut self) {
        self.sampler.abort();
    }
}
