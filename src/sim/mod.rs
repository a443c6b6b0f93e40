//! Virtual devices on an emulated bus: built from a dictionary and a
//! behaviour per product, driven by the same protocol code as the gateway.
//!
//! # Layout
//!
//! - [`objects`]: [`ObjectStore`](objects::ObjectStore), a dictionary's
//!   current values with the checks and aborts of a device's SDO server.
//! - [`device`]: the device core every product shares: NMT slave and
//!   boot-up, heartbeat from 0x1017, SDO server, resets.
//! - [`products`]: the emulated products and the `--devices` lists.
//! - [`persist`]: saved parameters on disk under `--data-dir`.

pub mod device;
pub mod objects;
pub mod persist;
pub mod products;
