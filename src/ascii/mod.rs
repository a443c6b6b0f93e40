//! CiA 309-3: CANopen access over ASCII (the text protocol of
//! CANopenNode's `canopend`/`cocomm` and Lely's `coctl`), served over TCP
//! (`candeck serve --ascii-listen ADDR`) and on stdin/stdout (`candeck
//! ascii`), through the same gateway as REST.
//!
//! # Layout
//!
//! - [`command`]: a command line parsed into a typed request (sans-I/O).
//! - [`datatype`]: values per CiA 309-3 data type, both ways (sans-I/O).
//! - [`reply`]: replies, error numbers, help and event lines (sans-I/O).
//! - [`gateway`]: what a request does: SDO on the node's shared queue, NMT,
//!   the audit log; shared with the CiA 309-5 routes
//!   ([`crate::api::cia309_5`]).
//! - [`serve`]: a connection's session, the TCP listener and the
//!   stdin/stdout mode.

pub mod command;
pub mod datatype;
pub mod gateway;
pub mod reply;
pub mod serve;

pub use gateway::{Gateway, Identity};
pub use serve::{Session, listen, serve_connection};
