//! CiA 309-3: CANopen access over ASCII, served over TCP (`candeck serve
//! --ascii-listen ADDR`) and on stdin/stdout (`candeck ascii`), through the
//! same gateway service as REST. The protocol itself (command lines,
//! data types, replies) and what a request does are [`crate::cia309`],
//! which the CiA 309-5 routes share.
//!
//! # Layout
//!
//! - [`serve`]: a connection's session, the TCP listener and the
//!   stdin/stdout mode.

pub mod serve;

pub use serve::{Limits, Session, listen, serve_connection};
