//! CiA 309, access to CANopen from other networks: what its two adapters
//! share. The command interpreter of CiA 309-3 (the ASCII protocol of
//! CANopenNode's `canopend`/`cocomm` and Lely's `coctl`) and the requests
//! of CiA 309-5 (CANopen over HTTP) both run through [`Cia309Gateway`] on
//! the gateway service ([`crate::gateway::Gateway`]). The adapters are
//! [`crate::ascii`] (309-3 over TCP and stdin/stdout) and the 309-5 routes
//! of the REST server; they do not depend on each other.
//!
//! # Layout
//!
//! - [`command`]: a command line parsed into a typed request (sans-I/O).
//! - [`datatype`]: values per CiA 309-3 data type, both ways (sans-I/O).
//! - [`reply`]: replies, error numbers, help and event lines (sans-I/O).
//! - [`gateway`]: what a request does: SDO on the node's shared queue, NMT,
//!   the audit log.
//! - [`failure`]: a [`GatewayError`](crate::gateway::GatewayError) said as
//!   CiA 309 says it ([`Failure`]), for both doors.

pub mod command;
pub mod datatype;
pub mod failure;
pub mod gateway;
pub mod reply;

pub use failure::Failure;
pub use gateway::{Cia309Gateway, Identity, Origin, TransferOptions};
