//! socketcand: CAN over TCP (linux-can/socketcand, `doc/protocol.md`).
//!
//! # Layout
//!
//! - [`protocol`]: the message codec, sans I/O: [`protocol::Framer`] cuts
//!   the byte stream, parsers and writers for both directions.
//! - [`session`]: a server-side client session as a state machine (modes
//!   NO_BUS, BCM, RAW), sans I/O.
//! - [`server`]: the TCP server that shares virtual hubs.
//! - [`client`]: a [`Bus`](crate::Bus) backend on a remote server.

pub mod client;
pub mod protocol;
pub mod server;
pub mod session;

pub use client::{ClientConfig, open_socketcand};
pub use server::{
    DEFAULT_MAX_CONNECTIONS as DEFAULT_SHARE_MAX_CONNECTIONS, ServerConfig, ServerHandle,
    ServerStats, SocketcandServer,
};

/// The port socketcand listens on by default.
pub const DEFAULT_PORT: u16 = 29536;
