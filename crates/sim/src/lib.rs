//! Virtual devices on an emulated bus: built from a dictionary and a
//! behaviour per product, driven by the same protocol code as the gateway.
//!
//! # Layout
//!
//! - [`behaviour`]: [`Behaviour`](behaviour::Behaviour), a product's
//!   application on the simulation clock, and the faults it can be given.
//! - [`board`]: a UniSwarm board's supply, CPUs and thermal model, shared
//!   by the UMC and the UIO1LED.
//! - [`objects`]: [`ObjectStore`](objects::ObjectStore), a dictionary's
//!   current values with the checks and aborts of a device's SDO server.
//! - [`device`]: the device core every product shares: NMT slave and
//!   boot-up, heartbeat from 0x1017, SDO server, resets.
//! - [`pdo`]: the device's PDOs from their parameters, SYNC, re-mapping.
//! - [`products`]: the emulated products and the `--devices` lists.
//! - [`umc`], [`jmc`], [`uioled`], [`io401`]: the behaviour of each
//!   product.
//! - [`rack`]: [`Rack`](rack::Rack), the devices of one virtual bus on one
//!   runner and one simulation clock, with unplug, plug and fault injection.
//! - [`persist`]: saved parameters on disk under `--data-dir`.
//! - [`program`]: program download (CiA 302-3): 0x1F50, 0x1F51, 0x1F56,
//!   0x1F57 and the software version of the image's header.

use candeck_can as can;
use candeck_canopen as canopen;
use candeck_profiles as profiles;

pub mod behaviour;
pub mod board;
pub mod device;
pub mod io401;
pub mod jmc;
pub mod objects;
pub mod pdo;
pub mod persist;
pub mod products;
pub mod program;
pub mod rack;
pub mod uioled;
pub mod umc;
