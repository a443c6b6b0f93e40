//! The CANopen master: what candeck does on a bus with the protocol of
//! [`crate::canopen`].
//!
//! # Layout
//!
//! - [`sdo`]: SDO transfers to one node over a [`Bus`](crate::can::Bus), one at
//!   a time, with a fair queue.

pub mod sdo;
