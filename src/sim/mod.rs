//! Virtual devices on an emulated bus: built from a dictionary and a
//! behaviour per product, driven by the same protocol code as the gateway.
//!
//! # Layout
//!
//! - [`objects`]: [`ObjectStore`](objects::ObjectStore), a dictionary's
//!   current values with the checks and aborts of a device's SDO server.
//! - [`sdo_node`]: a task answering SDO requests for a store on a bus.
//! - [`device`]: the device core every product shares: NMT slave and
//!   boot-up, heartbeat from 0x1017, SDO server, resets.

pub mod device;
pub mod objects;
pub mod sdo_node;
