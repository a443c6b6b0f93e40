//! Virtual devices on an emulated bus: built from a dictionary and a
//! behaviour per product, driven by the same protocol code as the gateway.
//!
//! # Layout
//!
//! - [`objects`]: [`ObjectStore`](objects::ObjectStore), a dictionary's
//!   current values with the checks and aborts of a device's SDO server.
//! - [`sdo_node`]: a task answering SDO requests for a store on a bus.

pub mod objects;
pub mod sdo_node;
