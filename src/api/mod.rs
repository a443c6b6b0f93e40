//! The REST interface (`docs/rest-api.md`, base `/api/v1`).
//!
//! [`app`] merges one router per resource; every handler fails with
//! [`AppError`], the one place where errors become HTTP statuses. Handlers
//! that talk to a device run each SDO transfer in a task of its own and
//! wait for it, so that a client that hangs up never cuts a transfer
//! halfway (axum drops the handler's future when the connection closes).
//!
//! # Layout
//!
//! - [`error`]: [`AppError`], its status mapping, and [`ApiJson`] and
//!   [`ApiPath`], extractors whose rejections have the API's error shape.
//! - [`buses`]: `/health`, `/buses` (with the bus-load estimate).
//! - [`nodes`]: the node list, one node, scan, NMT.
//! - [`od`]: the object dictionary of a node and SDO reads and writes.
//! - [`segments`]: LED controllers: segments, scenes, the strip's preview.
//! - [`config`]: store, restore, DCF backup and restore of a node.
//! - [`drives`]: CiA 402 drives: axes, state walk, fault reset, halt,
//!   moves, stop-all.
//! - [`pdos`]: a node's PDOs (read, re-map, RPDO send) and the bus's SYNC
//!   producer.
//! - [`values`]: the TPDO values the gateway decodes, by node.
//! - [`frames`]: a bus's recent frames, and one frame sent.
//! - [`recording`]: recording a bus to a candump `-L` log, and its
//!   download.
//! - [`sim`]: the virtual devices of a virtual bus: add, remove, faults.
//! - [`auth`]: tokens and roles, the table of the least role of every
//!   route, and the layer that applies it (origin check, CORS, body
//!   limits, rate limit); `/auth/whoami`.
//! - [`audit`]: the layer that writes every state-changing request to the
//!   audit log before its response leaves.
//! - [`events`]: `/events`, the persisted history (audit, EMCY, NMT).
//! - [`eds`]: `/eds`, the EDS catalog with each file's warnings and the
//!   files left out.
//! - [`metrics`]: `/metrics` (at the root, not under `/api/v1`) in the
//!   Prometheus text format.
//! - [`stream`]: `/stream`, the live telemetry over WebSocket, and each
//!   client's session (subscriptions, rates, coalescing, lagged events).
//! - [`cia309_5`]: CiA 309-5, CANopen over HTTP (`/cia309-5/1.0/...`, at
//!   the root, outside `/api/v1`), through the CiA 309 gateway of
//!   [`crate::ascii`].
//! - [`doc`]: the OpenAPI document (`/api/openapi.json`, the docs UI at
//!   `/api/docs`) and the schemas the routers share.

pub mod audit;
pub mod auth;
pub mod buses;
pub mod cia309_5;
pub mod config;
pub mod doc;
pub mod drives;
pub mod eds;
pub mod error;
pub mod events;
pub mod frames;
pub mod leases;
pub mod metrics;
pub mod nodes;
pub mod od;
pub mod pdos;
pub mod recording;
pub mod segments;
pub mod sim;
pub mod stream;
pub mod values;

#[cfg(test)]
mod tests;

use std::collections::BTreeMap;
use std::sync::Arc;

use axum::Router;
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_swagger_ui::{Config, SwaggerUi};

use crate::can::spec::BusSpec;
use crate::can::{Bus, VirtualHub};
use crate::gateway::axis_telemetry::AxisTelemetry;
use crate::gateway::frames::FrameLog;
use crate::gateway::history::History;
use crate::gateway::led_preview::LedPreviews;
use crate::gateway::profile::EdsCatalog;
use crate::gateway::recording::Recorder;
use crate::gateway::registry::{NodeEvent, NodeRegistry, RegistryConfig};
use crate::gateway::sync::SyncService;
use crate::gateway::telemetry::StreamCounters;
use crate::gateway::values::TpdoValues;
use crate::sim::rack::Rack;

pub use buses::{LoadMeter, Traffic};
pub use error::{ApiJson, ApiPath, AppError};

/// One bus the gateway serves.
pub struct ServedBus {
    pub name: String,
    /// The spec it was opened from, as the user wrote it (`virtual:demo`).
    pub spec: String,
    pub bus: Bus,
    pub registry: NodeRegistry,
    /// The hub of a virtual bus, which counts every frame on it (an
    /// attachment to a hub counts only what it sends).
    pub hub: Option<VirtualHub>,
    /// The virtual devices of a virtual bus (`virtual:demo` starts with
    /// the demo devices, `virtual:empty` with none); `None` elsewhere.
    pub rack: Option<Rack>,
    pub load: LoadMeter,
    /// The gateway's SYNC producer on this bus (`PUT /buses/{bus}/sync`).
    pub sync: SyncService,
    /// The nodes' TPDO values, decoded by the mappings read from them; the
    /// `values` topics of the stream ([`TpdoValues::subscribe`]).
    pub values: TpdoValues,
    /// The `axes/{axis}` topics of the stream
    /// ([`AxisTelemetry::subscribe`]).
    pub axes: AxisTelemetry,
    /// The `segments` topics of the stream ([`LedPreviews::subscribe`]).
    pub previews: LedPreviews,
    /// The bus's recent frames.
    pub frames: FrameLog,
    /// Records the bus to a candump log on request (`/buses/{bus}/recording`).
    pub recorder: Recorder,
    /// The registry's events from the moment it started (the devices'
    /// boot-ups included), until [`AppState::with_history`] takes it to
    /// write them to the history.
    history_events: std::sync::Mutex<Option<tokio::sync::broadcast::Receiver<NodeEvent>>>,
}

impl ServedBus {
    /// Opens `spec` as the bus `name` and starts its registry; a
    /// `virtual:demo` bus gets the demo devices, booted after the registry
    /// listens so that it hears their boot-up messages.
    pub async fn open(
        name: &str,
        spec: &BusSpec,
        catalog: Arc<EdsCatalog>,
        config: RegistryConfig,
        bitrate: u32,
    ) -> Result<Self, String> {
        Self::open_with_data_dir(name, spec, catalog, config, bitrate, None).await
    }

    /// [`ServedBus::open`], and the virtual devices of a virtual bus keep
    /// what they save (0x1010) under `data_dir` (see
    /// [`Rack::with_data_dir`]).
    pub async fn open_with_data_dir(
        name: &str,
        spec: &BusSpec,
        catalog: Arc<EdsCatalog>,
        config: RegistryConfig,
        bitrate: u32,
        data_dir: Option<std::path::PathBuf>,
    ) -> Result<Self, String> {
        let opened = spec.open(name).await.map_err(|err| err.to_string())?;
        let telemetry = config.telemetry.clone();
        let registry = NodeRegistry::spawn(opened.bus.clone(), catalog, config);
        let history_events = std::sync::Mutex::new(Some(registry.subscribe()));
        let values = TpdoValues::spawn(opened.bus.clone(), registry.clone());
        // Recording starts before the devices boot: their boot-ups are the
        // first frames of the log.
        let frames = FrameLog::spawn(&opened.bus);
        let rack = match (spec, &opened.hub) {
            (BusSpec::Virtual { preset }, Some(hub)) => {
                let rack = Rack::with_data_dir(hub.clone(), data_dir);
                if preset == "demo" {
                    rack.add_all(&crate::sim::products::demo())
                        .map_err(|err| err.to_string())?;
                }
                Some(rack)
            }
            _ => None,
        };
        Ok(Self {
            // In a private temporary directory until told otherwise.
            recorder: Recorder::new(&opened.bus, None),
            frames,
            name: name.to_string(),
            spec: spec.to_string(),
            load: LoadMeter::spawn(Traffic::new(&opened.bus), bitrate),
            sync: SyncService::spawn(opened.bus.clone()),
            axes: AxisTelemetry::new(registry.clone(), values.clone(), telemetry.clone()),
            previews: LedPreviews::new(registry.clone(), &telemetry),
            values,
            hub: opened.hub,
            bus: opened.bus,
            registry,
            rack,
            history_events,
        })
    }
}

impl ServedBus {
    /// Keeps this bus's recordings in `dir` (`--data-dir DIR` gives
    /// `DIR/recordings`) instead of a temporary directory. Call before any
    /// recording starts.
    pub fn with_recordings_dir(mut self, dir: std::path::PathBuf) -> Self {
        self.recorder = Recorder::new(&self.bus, Some(dir));
        self
    }
}

/// What every handler shares: the buses by name.
#[derive(Clone)]
pub struct AppState {
    pub buses: Arc<BTreeMap<String, Arc<ServedBus>>>,
    /// The WebSocket stream's numbers, for `/metrics`.
    pub stream_counters: Arc<StreamCounters>,
    /// The axes the gateway enabled, which it stops before it exits.
    pub enabled_axes: Arc<drives::EnabledAxes>,
    /// The audit log and the EMCY/NMT history (`/events`).
    pub history: History,
    /// The motion leases of velocity, torque and duty-cycle moves.
    pub leases: Arc<leases::MotionLeases>,
    /// The bus names in the order they were given (`--bus`, the config
    /// file): CiA 309 net 1 is the first.
    pub bus_order: Arc<Vec<String>>,
    /// Tokens, roles and limits ([`auth::guard`]); open by default.
    pub guard: Arc<auth::Guard>,
}

impl AppState {
    /// The buses, with a history in memory (lost on exit).
    pub fn new(buses: impl IntoIterator<Item = ServedBus>) -> Self {
        // An in-memory SQLite database fails to open only when memory is
        // exhausted, when nothing else would work either.
        let history = History::in_memory().expect("an in-memory SQLite database opens");
        Self::with_history(buses, history)
    }

    /// The buses, their registry events written to `history` by a task per
    /// bus (call within a tokio runtime when there are buses).
    pub fn with_history(buses: impl IntoIterator<Item = ServedBus>, history: History) -> Self {
        let buses: Vec<ServedBus> = buses.into_iter().collect();
        let bus_order: Vec<String> = buses.iter().map(|bus| bus.name.clone()).collect();
        let buses: BTreeMap<String, Arc<ServedBus>> = buses
            .into_iter()
            .map(|bus| (bus.name.clone(), Arc::new(bus)))
            .collect();
        for bus in buses.values() {
            let taken = bus
                .history_events
                .lock()
                .unwrap_or_else(|poison| poison.into_inner())
                .take();
            let events = taken.unwrap_or_else(|| bus.registry.subscribe());
            history.spawn_recorder(&bus.name, events);
        }
        Self {
            buses: Arc::new(buses),
            stream_counters: Arc::new(StreamCounters::default()),
            enabled_axes: Arc::new(drives::EnabledAxes::default()),
            history,
            leases: Arc::new(leases::MotionLeases::default()),
            bus_order: Arc::new(bus_order),
            guard: Arc::new(auth::Guard::default()),
        }
    }

    /// The same, granting motion leases of `period` (`--lease-ms`).
    pub fn with_lease_period(mut self, period: std::time::Duration) -> Self {
        self.leases = Arc::new(leases::MotionLeases::new(period));
        self
    }

    /// The buses in the order they were given: CiA 309 net `n` is the
    /// `n`-th (1-based).
    pub fn buses_in_order(&self) -> Vec<Arc<ServedBus>> {
        self.bus_order
            .iter()
            .filter_map(|name| self.buses.get(name).cloned())
            .collect()
    }

    /// The same state with these access settings (tokens, CORS, limits).
    pub fn with_auth(mut self, config: auth::AuthConfig) -> Self {
        self.guard = Arc::new(auth::Guard::new(config));
        self
    }

    /// The bus named in a path, or 404 `unknown_bus`.
    pub fn bus(&self, name: &str) -> Result<Arc<ServedBus>, AppError> {
        self.buses
            .get(name)
            .cloned()
            .ok_or_else(|| AppError::UnknownBus(name.to_string()))
    }
}

/// The API's router under `/api/v1` and `/metrics` at the root (without
/// state and without the audit and access layers, which [`app`] puts
/// around everything), and its OpenAPI document, from every resource's
/// router.
pub fn routers(state: AppState) -> (Router, utoipa::openapi::OpenApi) {
    let (api, api_doc) = OpenApiRouter::new()
        .merge(buses::router())
        .merge(nodes::router())
        .merge(od::router())
        .merge(segments::router())
        .merge(config::router())
        .merge(drives::router())
        .merge(leases::router())
        .merge(values::router())
        .merge(pdos::router())
        .merge(frames::router())
        .merge(recording::router())
        .merge(sim::router())
        .merge(stream::router())
        .merge(events::router())
        .merge(eds::router())
        .merge(auth::router())
        .split_for_parts();
    let api = api.method_not_allowed_fallback(error::method_not_allowed);
    let (metrics, metrics_doc) = metrics::router().split_for_parts();
    let mut doc = doc::ApiDoc::openapi().nest("/api/v1", api_doc);
    doc.merge(metrics_doc);
    let router = Router::new()
        .nest("/api/v1", api)
        .merge(metrics.method_not_allowed_fallback(error::method_not_allowed))
        .merge(cia309_5::router().method_not_allowed_fallback(error::method_not_allowed))
        .fallback(error::no_route)
        .with_state(state);
    (router, doc)
}

/// The whole REST interface under `/api/v1`, its OpenAPI document at
/// `/api/openapi.json` and the docs UI at `/api/docs`, served from the
/// binary (no request leaves the machine; the online validator is off).
/// The dashboard ([`crate::web`]) is at `/`, outside the API and its
/// document. Paths no router has answer 404 in the API's error shape.
pub fn app(state: AppState) -> Router {
    let (router, doc) = routers(state.clone());
    let docs = SwaggerUi::new("/api/docs")
        .url("/api/openapi.json", doc)
        .config(Config::default().validator_url("none"));
    let largest_body = state.guard.config.largest_body();
    router
        .merge(docs)
        .merge(crate::web::router())
        // The extractors' own limit, above the guard's per-route limits
        // (a body without Content-Length is cut there).
        .layer(axum::extract::DefaultBodyLimit::max(largest_body))
        // Who may do what, inside the audit: refused requests are audited
        // with who tried.
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::guard,
        ))
        // Outside every route and fallback: refused and unknown requests
        // are audited too.
        .layer(axum::middleware::from_fn_with_state(state, audit::record))
}
