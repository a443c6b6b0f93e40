//! `GET /health` and `GET /buses`.
//!
//! The bus load is measured, not assumed: every second a task reads the
//! attachment's bit counters (each frame counted by
//! [`frame_bits`](crate::can::timing::frame_bits), sent or received, with
//! the worst-case stuff bits) and divides the bits of the last second by the
//! bus's bit rate (a virtual bus's own, otherwise `candeck serve --bitrate`,
//! 500 kbit/s unless told). `load` is that fraction: on a virtual bus, whose
//! frames take exactly those bits, the occupancy (1.0 saturated); on a wire,
//! whose frames have fewer stuff bits, a little high. `bits_per_second` is
//! the measurement itself.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use axum::extract::State;
use serde::Serialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{ApiJson, AppState};
use crate::can::Bus;

/// How often the bit counters are sampled, and so the window the load is
/// averaged over.
const LOAD_WINDOW: Duration = Duration::from_secs(1);

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(health))
        .routes(routes!(list_buses))
}

/// The gateway is up.
#[derive(Debug, Serialize, ToSchema)]
pub struct Health {
    #[schema(example = "ok")]
    pub status: &'static str,
    /// The version of candeck.
    #[schema(example = "0.1.0")]
    pub version: &'static str,
}

/// The gateway is up, and its version.
#[utoipa::path(get, path = "/health", tag = "buses",
    responses((status = 200, description = "The gateway answers", body = Health)))]
async fn health() -> ApiJson<Health> {
    ApiJson(Health {
        status: "ok",
        version: env!("CARGO_PKG_VERSION"),
    })
}

/// One bus the gateway serves.
#[derive(Debug, Serialize, ToSchema)]
pub struct BusInfo {
    /// The bus name used in paths.
    #[schema(example = "demo")]
    pub name: String,
    /// The spec it was opened from.
    #[schema(example = "virtual:demo")]
    pub spec: String,
    /// `virtual`, `socketcan` or `socketcand`.
    #[schema(example = "virtual")]
    pub kind: &'static str,
    /// `up` or `down`.
    #[schema(example = "up")]
    pub state: &'static str,
    /// Frames received from other nodes.
    #[schema(example = 1520)]
    pub rx_frames: u64,
    /// Frames the gateway sent.
    #[schema(example = 310)]
    pub tx_frames: u64,
    /// The share of the bit rate used over the last second (0.0 to 1.0; stuff
    /// bits not counted).
    #[schema(example = 0.012)]
    pub load: f64,
    /// The bits counted over the last second.
    #[schema(example = 6000)]
    pub bits_per_second: u64,
    /// The bit rate the load is measured against (`--bitrate`).
    #[schema(example = 500000)]
    pub bitrate: u32,
    /// Why the bus is down (or what its backend last reported); null when
    /// there is nothing to say.
    #[schema(example = json!(null))]
    pub reason: Option<String>,
    /// How often the backend has reconnected (socketcand, socketcan).
    #[schema(example = 0)]
    pub reconnects: u64,
}

/// The buses the gateway serves, with their traffic and measured load.
#[utoipa::path(get, path = "/buses", tag = "buses",
    responses((status = 200, description = "Every bus", body = [BusInfo])))]
async fn list_buses(State(state): State<AppState>) -> ApiJson<Vec<BusInfo>> {
    let buses = state
        .buses
        .values()
        .map(|served| {
            let traffic = Traffic::new(&served.bus).sample();
            let status = served.bus.status();
            let state = if status.state.can_send() {
                "up"
            } else {
                "down"
            };
            BusInfo {
                name: served.name.clone(),
                spec: served.spec.clone(),
                kind: served.bus.kind().as_str(),
                state,
                rx_frames: traffic.rx_frames,
                tx_frames: traffic.tx_frames,
                load: served.load.load(),
                bits_per_second: served.load.bits_per_second(),
                bitrate: served.load.bitrate(),
                reason: status.reason,
                reconnects: served.bus.counters().reconnects,
            }
        })
        .collect();
    ApiJson(buses)
}

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
