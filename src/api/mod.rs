//! The REST interface (`docs/rest-api.md`, base `/api/v1`).
//!
//! An adapter over the gateway service ([`crate::gateway::Gateway`], held
//! in [`AppState`] with what only HTTP needs).
//!
//! [`app`] merges one router per resource; every handler fails with
//! [`AppError`], the one place where errors (the gateway's
//! [`GatewayError`](crate::gateway::GatewayError) among them) become HTTP
//! statuses. Handlers
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
//! - [`machine`]: the network manager's machine of a bus, and a node's
//!   boot-up run again.
//! - [`od`]: the object dictionary of a node and SDO reads and writes.
//! - [`segments`]: LED controllers: segments, scenes, the strip's preview.
//! - [`config`]: store, restore, DCF backup and restore of a node.
//! - [`drives`]: CiA 402 drives: axes, state walk, fault reset, halt,
//!   moves, stop-all (the stops themselves are
//!   `crate::gateway::safe_stop`).
//! - [`io`]: a CiA 401 I/O module's channels: inputs live, outputs set
//!   and read back.
//! - [`leases`]: renewing a motion lease (the leases and their supervisor
//!   are `crate::gateway::leases`).
//! - [`program`]: program download (CiA 302-3) to a node.
//! - [`pdos`]: a node's PDOs (read, re-map, RPDO send) and the bus's SYNC
//!   producer.
//! - [`values`]: the TPDO values the gateway decodes, by node.
//! - [`frames`]: a bus's recent frames, and one frame sent.
//! - [`recording`]: recording a bus to a candump `-L` log, and its
//!   download.
//! - [`sim`]: the virtual devices of a virtual bus: add, remove, faults.
//! - [`alarms`]: the alarms (list, one, acknowledge) and the machine's
//!   recovery (reset faults, enable all).
//! - [`loggers`]: the data loggers: start, status, CSV, delete.
//! - [`lss`]: LSS (CiA 305): Fastscan for unconfigured devices, node-ID
//!   assignment; the UniSwarm node-ID change (0x2040).
//! - [`auth`]: the table of the least role of every route (tokens and
//!   roles are `crate::gateway::access`), and the layer that applies it (origin check, CORS, body
//!   limits, rate limit); `/auth/whoami`.
//! - [`host`]: the `Host` check against DNS rebinding, on every route.
//! - [`headers`]: the anti-framing and content headers of every answer.
//! - [`serve`]: the HTTP server: timeouts, the connection limit and its
//!   reserve for `/health` and `stop-all`.
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
//!   [`crate::cia309`].
//! - [`doc`]: the OpenAPI document (`/api/openapi.json`, the docs UI at
//!   `/api/docs`) and the schemas the routers share.

pub mod alarms;
pub mod audit;
pub mod auth;
pub mod buses;
pub mod caller;
pub mod cia309_5;
pub mod config;
pub mod doc;
pub mod drives;
pub mod eds;
pub mod error;
pub mod events;
pub mod frames;
pub mod headers;
pub mod host;
pub mod io;
pub mod leases;
pub mod loggers;
pub mod lss;
pub mod machine;
pub mod metrics;
pub mod nodes;
pub mod od;
pub mod pdos;
pub mod program;
pub mod recording;
pub mod schema;
pub mod segments;
pub mod serve;
pub mod sim;
pub mod stream;
pub mod values;

#[cfg(test)]
pub(crate) mod tests;

use std::sync::Arc;

use axum::Router;
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_swagger_ui::{Config, SwaggerUi};

use crate::gateway::History;
use crate::gateway::StreamCounters;
use crate::gateway::{Gateway, ServedBus};

pub use error::{ApiJson, ApiPath, AppError};

/// What every handler shares: the gateway service, and what only HTTP
/// needs (the guard's tokens, CORS and limits; the stream's counters).
///
/// One `Arc`: every middleware layer and every handler takes the state by
/// value, so a request clones it several times; cloning the fields
/// themselves (the gateway's dozen `Arc`s among them) was among the door's
/// largest costs of its own in a profile of `GET /health`.
#[derive(Clone)]
pub struct AppState(Arc<Shared>);

/// The fields of [`AppState`] (read through `Deref`).
#[derive(Clone)]
pub struct Shared {
    /// The buses, the history, the leases: all the adapters share it.
    pub gateway: Gateway,
    /// The WebSocket stream's numbers, for `/metrics`.
    pub stream_counters: Arc<StreamCounters>,
    /// The connections the HTTP server's limit turned away, for `/metrics`.
    pub connection_refusals: Arc<serve::ConnectionRefusals>,
    /// The WebSocket streams open, by token and by peer, within their
    /// limits.
    pub open_streams: Arc<stream::OpenStreams>,
    /// The frames topics' feeds: each bus's frames batched and rendered
    /// once for every session.
    pub frame_feeds: Arc<stream::FrameFeeds>,
    /// Tokens, roles and limits ([`auth::guard`]); open by default.
    pub guard: Arc<auth::Guard>,
    /// The names the gateway is served as ([`host::refusal`]); loopback
    /// names and addresses by default.
    pub allowed_hosts: Arc<host::AllowedHosts>,
}

impl AppState {
    /// The REST state over a gateway service, open (no tokens).
    pub fn from_gateway(gateway: Gateway) -> Self {
        Self(Arc::new(Shared {
            gateway,
            stream_counters: Arc::new(StreamCounters::default()),
            connection_refusals: Arc::default(),
            open_streams: Arc::default(),
            frame_feeds: Arc::default(),
            guard: Arc::new(auth::Guard::default()),
            allowed_hosts: Arc::new(host::AllowedHosts::default()),
        }))
    }

    /// The fields, to change while the state is being built (a copy of
    /// them if a clone of this state is already out).
    fn shared_mut(&mut self) -> &mut Shared {
        Arc::make_mut(&mut self.0)
    }

    /// The buses, with a history in memory (lost on exit).
    pub fn new(buses: impl IntoIterator<Item = ServedBus>) -> Self {
        Self::from_gateway(Gateway::new(buses))
    }

    /// The buses, their registry events written to `history` (see
    /// [`Gateway::with_history`]).
    pub fn with_history(buses: impl IntoIterator<Item = ServedBus>, history: History) -> Self {
        Self::from_gateway(Gateway::with_history(buses, history))
    }

    /// The same, granting motion leases of `period` (`--lease-ms`).
    pub fn with_lease_period(mut self, period: std::time::Duration) -> Self {
        let shared = self.shared_mut();
        shared.gateway = shared.gateway.clone().with_lease_period(period);
        self
    }

    /// The same state with these access settings (tokens, CORS, limits);
    /// the gateway service gets the tokens and the write rate limit, for
    /// its other adapters.
    pub fn with_auth(mut self, config: auth::AuthConfig) -> Self {
        let shared = self.shared_mut();
        shared.gateway = shared
            .gateway
            .clone()
            .with_tokens(config.tokens.clone())
            .with_write_limit(config.rate_limit);
        self.with_guard(config)
    }

    /// The same state with the REST door's own access settings (tokens,
    /// CORS, limits): for a gateway started with the same tokens and
    /// write limit ([`Gateway::start`]).
    pub fn with_guard(mut self, config: auth::AuthConfig) -> Self {
        self.shared_mut().guard = Arc::new(auth::Guard::new(config));
        self
    }

    /// The same state with these limits of WebSocket streams per token and
    /// per peer.
    pub fn with_stream_limits(mut self, limits: stream::StreamLimits) -> Self {
        self.shared_mut().open_streams = Arc::new(stream::OpenStreams::new(limits));
        self
    }

    /// The same state answering to these names too (`allowed_hosts`).
    pub fn with_allowed_hosts(mut self, hosts: host::AllowedHosts) -> Self {
        self.shared_mut().allowed_hosts = Arc::new(hosts);
        self
    }

    /// The bus named in a path, or 404 `unknown_bus`.
    pub fn bus(&self, name: &str) -> Result<Arc<ServedBus>, AppError> {
        Ok(self.gateway.bus(name)?)
    }
}

impl std::ops::Deref for AppState {
    type Target = Shared;

    fn deref(&self) -> &Shared {
        &self.0
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
        .merge(machine::router())
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
        .merge(lss::router())
        .merge(loggers::router())
        .merge(alarms::router())
        .merge(stream::router())
        .merge(events::router())
        .merge(eds::router())
        .merge(io::router())
        .merge(program::router())
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
        .merge(Router::from(docs).layer(axum::middleware::from_fn(doc::docs_index)))
        .merge(crate::web::router())
        // The extractors' own limit, above the guard's per-route limits
        // (a body without Content-Length is cut there).
        .layer(axum::extract::DefaultBodyLimit::max(largest_body))
        // The Host check, then who may do what, inside the audit: refused
        // requests are audited with who tried.
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::guard,
        ))
        // Outside every route and fallback: refused and unknown requests
        // are audited too.
        .layer(axum::middleware::from_fn_with_state(state, audit::record))
        // On every answer, refusals included.
        .layer(axum::middleware::from_fn(headers::layer))
}
