//! SDO, the service data object (CiA 301 §7.2.4): confirmed reads (upload)
//! and writes (download) of one object dictionary entry, which a client asks
//! of a server on a pair of COB-IDs (0x600 + node and 0x580 + node in the
//! predefined connection set).
//!
//! All three transfer kinds of CiA 301 are here, on both sides: expedited
//! (up to 4 bytes inside the initiate frame), segmented (7 bytes per frame,
//! each confirmed, a toggle bit alternating) and block (up to 127 segments
//! per confirmation, sequence numbers, a CRC over the data, and the upload's
//! protocol switch for short values).
//!
//! Both machines are sans I/O: they take frames and the current time in, give
//! frames and a deadline out, and never read a clock. The caller delivers
//! every frame it receives, sends what the machine gives back, and calls
//! `handle_timeout` once `deadline()` has passed.
//!
//! Block transfers survive lost segments: the receiver acknowledges the last
//! segment that arrived in order and the sender resumes after it; if a
//! block's final segment is lost, the receiver acknowledges what it has after
//! half the timeout (as CANopenNode does) instead of letting the transfer
//! die. Every other loss ends in the timeout abort.
//!
//! Errors keep three things apart (see [`SdoError`]): the device refused
//! ([`SdoError::ServerAborted`]), the device stayed silent
//! ([`SdoError::Timeout`]), and the device broke the protocol
//! ([`SdoError::Protocol`]). A bus that fails is the caller's to report.
//!
//! # Layout
//!
//! - [`abort`]: [`AbortCode`], every abort code of CiA 301 with its text.
//! - [`wire`]: the frame formats of §7.2.4.3, decoded and encoded byte for
//!   byte, and the block transfer CRC.
//! - `block`: what the two sides of a block transfer share: cutting blocks,
//!   tracking sequence numbers, acknowledging.
//! - [`client`]: [`SdoClient`], one transfer at a time to one server.
//! - [`server`]: [`SdoServer`], serving an [`ObjectAccess`] implementation.

pub mod abort;
mod block;
pub mod client;
pub mod server;
pub mod wire;

#[cfg(test)]
mod tests;

use std::fmt;

pub use abort::AbortCode;
pub use client::{ClientConfig, SdoClient, Step, Transfer};
pub use server::{ObjectAccess, SdoServer, ServerConfig};

/// Why a client transfer failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SdoError {
    /// The device refused: it sent an abort with this code.
    ServerAborted(AbortCode),
    /// The device did not answer within the timeout; the client sent abort
    /// 0x05040000.
    Timeout,
    /// The device answered something the protocol does not allow at this
    /// point (wrong command, toggle bit, sequence number, CRC, length, or a
    /// malformed frame); the client sent an abort with `code`.
    Protocol { code: AbortCode, detail: String },
    /// A transfer is already running; CiA 301 allows one at a time per
    /// server. Nothing was sent.
    Busy,
    /// The value is longer than the 32-bit size field of an SDO transfer can
    /// announce. Nothing was sent.
    TooLarge(usize),
}

impl fmt::Display for SdoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::ServerAborted(code) => write!(
                f,
                "the device refused the SDO transfer: {} (abort code 0x{:08X})",
                code.text(),
                code.raw()
            ),
            Self::Timeout => f.write_str(
                "the device did not answer the SDO request in time, so the transfer was aborted",
            ),
            Self::Protocol { code, detail } => write!(
                f,
                "the device broke the SDO protocol ({detail}), so the transfer was aborted with \
                 0x{:08X} ({})",
                code.raw(),
                code.text()
            ),
            Self::Busy => f.write_str(
                "another SDO transfer with this device is still running; CiA 301 allows one at a time",
            ),
            Self::TooLarge(len) => write!(
                f,
                "{len} bytes do not fit an SDO transfer, whose size field has 32 bits"
            ),
        }
    }
}

impl std::error::Error for SdoError {}
