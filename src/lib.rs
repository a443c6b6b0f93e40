//! candeck: a gateway and web dashboard for CANopen machines.
//!
//! One process owns the CAN bus(es) and a model of every device on them, and
//! exposes them over REST and WebSocket. Without hardware it runs an emulated
//! bus whose virtual devices behave like the real ones.
//!
//! # Layout
//!
//! The adapters ([`api`], [`ascii`], [`cia309`], [`cli`]) sit on the
//! gateway service ([`gateway::Gateway`]) and never on each other (only the
//! wiring of `candeck serve` puts REST and CiA 309-3 side by side);
//! `tests/layering.rs` checks the rule.
//!
//! - [`api`]: the REST interface (axum): buses, nodes, NMT, the object
//!   dictionary over SDO, with one error type mapped to HTTP statuses, and
//!   the CiA 309-5 routes.
//! - [`ascii`]: CiA 309-3, the ASCII gateway protocol (TCP and
//!   stdin/stdout), through the same gateway service as REST.
//! - [`cia309`]: what the CiA 309 adapters share: command lines, data
//!   types, replies, and what a request does on the gateway service.
//! - [`can`]: frames, the [`can::Bus`] attachment and its backends (virtual
//!   hub, socketcand client and server, SocketCAN, candump replay), and candump
//!   logs.
//! - [`canopen`]: the CANopen protocol (CiA 301, CiA 306) as sans-I/O state
//!   machines: NMT, heartbeat, SYNC, EMCY, PDO, SDO, object dictionaries, EDS.
//! - [`gateway`]: the CANopen master as one service: the served buses, SDO
//!   transfers, the EDS catalog and the node registry of a bus
//!   (identification, heartbeat supervision, EMCY history), the operations
//!   the adapters run (PDOs, drives, LED segments, DCF), motion leases and
//!   the safe stops, tokens and roles, the history, and the producers of
//!   the stream's value topics; its own error type, no HTTP.
//! - [`profiles`]: what each product means (built-in EDS, LED effects, ...).
//! - [`sim`]: virtual devices on an emulated bus.
//! - [`sparkplug`]: the Sparkplug B edge node on an MQTT broker (rumqttc),
//!   each CANopen node a device; an adapter on the gateway service.
//! - [`web`]: the browser dashboard served at `/` (askama templates and
//!   the static files of `web/`, compiled into the binary).
//! - [`cli`]: the command line (`candeck serve`, `candeck vbus`, `candeck dump`, ...); `main.rs`
//!   only calls it.

pub mod api;
pub mod ascii;
pub use candeck_can as can;
pub use candeck_canopen as canopen;
pub mod cia309;
pub mod cli;
#[cfg(test)]
mod door_audit;
#[cfg(test)]
mod door_parity;
/// One sample of every `GatewayError` (REST's error tests keep the list), for
/// every door's test of its mapping.
#[cfg(test)]
mod error_samples {
    pub(crate) use crate::api::error::{VARIANTS, samples};
}
pub mod emulator;
pub mod opcua;
pub use candeck_gateway as gateway;
pub use candeck_profiles as profiles;
pub use candeck_sim as sim;
pub mod sparkplug;
pub mod web;
