//! The OPC UA server (IEC 62541): the machine as an address space that MES
//! and SCADA clients browse, subscribe to and command (docs/opcua.md). A
//! door on the gateway service like REST and Sparkplug: every method call
//! and write is one gateway operation with the session's caller (channel
//! `opcua`), so roles, leases, the write limiter and the audit log apply
//! as for REST; nothing here decides who may do what.
//!
//! # Layout
//!
//! - [`config`]: the settings (`opcua_listen`, `opcua_*`) and who may log
//!   in where (always compiled, so that the config file's keys are known).
//! - [`browse`]: the browse tree's node ids and the methods' arguments as
//!   the gateway's requests, sans I/O.
//! - [`status`]: a `GatewayError` as a status code, once.
//! - [`values`]: CANopen values as OPC UA values.
//! - [`users`]: candeck's tokens as user names and passwords.
//! - [`tree`]: the nodes of the tree, built into an address space.
//! - [`space`]: the node manager: reads, writes and calls.
//! - [`feed`]: the values, fed from the gateway's views and telemetry.
//! - [`io`]: LED segments and CiA 401 channels as variables, read and
//!   written through the gateway's segment and I/O operations.
//! - [`events`]: NMT changes, EMCYs and alarms as OPC UA events.
//! - [`leases`]: motion leases bound to the session that took them, lapsing
//!   when it closes or stops talking.
//! - [`revisions`]: each node's hardware and software versions, read once
//!   per identification.
//! - [`sampling`]: monitored dictionary, I/O and LED variables: what each
//!   watches, asked of the gateway's sampling (its per-node bound, its
//!   TPDO-carried objects), and its samples turned into values.
//! - [`server`]: async-opcua's server with all of it.
//!
//! Built with the `opcua` cargo feature (default).

pub mod config;

#[cfg(feature = "opcua")]
pub mod browse;
#[cfg(feature = "opcua")]
pub mod events;
#[cfg(feature = "opcua")]
pub mod feed;
#[cfg(feature = "opcua")]
pub mod io;
#[cfg(feature = "opcua")]
pub mod leases;
#[cfg(feature = "opcua")]
pub mod revisions;
#[cfg(feature = "opcua")]
pub mod sampling;
#[cfg(feature = "opcua")]
pub mod server;
#[cfg(feature = "opcua")]
pub mod space;
#[cfg(feature = "opcua")]
pub mod status;
#[cfg(feature = "opcua")]
pub mod tree;
#[cfg(feature = "opcua")]
pub mod users;
#[cfg(feature = "opcua")]
pub mod values;

pub use config::OpcUaConfig;
#[cfg(feature = "opcua")]
pub use server::OpcUaServer;
