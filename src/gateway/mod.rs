//! The CANopen master: what candeck does on a bus with the protocol of
//! [`crate::canopen`].
//!
//! # Layout
//!
//! - [`sdo`]: SDO transfers to one node over a [`Bus`](crate::can::Bus), one at
//!   a time, with a fair queue.
//! - [`frames`]: the recent frames of a bus, in a bounded ring.
//! - [`profile`]: the [`Profile`](profile::Profile) of a node and the EDS
//!   catalog (built-in and `--eds-dir` files) its identity is matched to.
//! - [`registry`]: the node registry of one bus: nodes found by boot-up,
//!   heartbeat and scan, identified, supervised, with their EMCY history.

pub mod frames;
pub mod profile;
pub mod registry;
pub mod sdo;
