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

use axum::extract::State;
use serde::Serialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{ApiJson, AppState, ServedBus};

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
    /// The error state of the gateway's CAN controller on this bus (ISO
    /// 11898-1 fault confinement): `error_active`, `error_passive` (frames
    /// still flow) or `bus_off`; null while the bus is down. From the
    /// kernel's error frames on SocketCAN, from the attachment's own
    /// controller on a virtual bus; socketcand reports none (always
    /// `error_active` while connected).
    #[schema(example = "error_active")]
    pub error_state: Option<&'static str>,
    /// The controller's transmit error counter (TEC), as last reported.
    #[schema(example = 0)]
    pub tx_error_counter: u64,
    /// The controller's receive error counter (REC), as last reported.
    #[schema(example = 0)]
    pub rx_error_counter: u64,
    /// Frames refused because their sender's transmit queue (1024 frames)
    /// was full: the gateway's own on a SocketCAN bus; on a virtual bus
    /// every sender's (the gateway, the virtual devices, socketcand
    /// clients are held back instead). Each loss is counted, never silent.
    #[schema(example = 0)]
    pub tx_queue_overflows: u64,
}

/// The buses the gateway serves, with their traffic and measured load.
#[utoipa::path(get, path = "/buses", tag = "buses",
    responses((status = 200, description = "Every bus", body = [BusInfo])))]
async fn list_buses(State(state): State<AppState>) -> ApiJson<Vec<BusInfo>> {
    let buses = state.gateway.buses().map(|served| BusInfo::of(served));
    ApiJson(buses.collect())
}

impl BusInfo {
    /// A served bus as the list gives it: its traffic, state and load now.
    fn of(served: &ServedBus) -> Self {
        let traffic = served.traffic();
        let status = served.status();
        let counters = served.counters();
        let state = if status.state.can_send() {
            "up"
        } else {
            "down"
        };
        BusInfo {
            name: served.name().to_string(),
            spec: served.spec().to_string(),
            kind: served.kind().as_str(),
            state,
            rx_frames: traffic.rx_frames,
            tx_frames: traffic.tx_frames,
            load: served.load().load(),
            bits_per_second: served.load().bits_per_second(),
            bitrate: served.load().bitrate(),
            reason: status.reason,
            reconnects: counters.reconnects,
            error_state: status.state.error_state().map(|s| s.as_str()),
            tx_error_counter: counters.tec,
            rx_error_counter: counters.rec,
            tx_queue_overflows: counters.tx_queue_overflows,
        }
    }
}
