//! candump `-L` log files, the format of linux-can/can-utils `candump -L`
//! that `canplayer` reads back: one frame per line,
//! `(SECONDS.MICROSECONDS) INTERFACE FRAME`, for example
//! `(1436509052.249713) can0 123#1122334455667788`.
//!
//! Lines are parsed and printed by the `socketcan` crate's `dump` module, so
//! this module and can-utils agree on every spelling (`123#R2`, `123##5AABB`,
//! error frames with `CAN_ERR_FLAG` in the identifier).
//!
//! # Layout
//!
//! - [`format`](mod@format): [`read_log`], a whole log as [`LoggedFrame`]s, or an error
//!   naming the file, the line and what is wrong with it; [`LogWriter`], a
//!   frame as a line;
//! - [`record`]: the one record loop ([`LogRecorder`]), a bus written out
//!   as a log, by `candeck dump` ([`record_bus`]) and the gateway's
//!   recorder;
//! - [`replay`]: [`open_replay`], a log played back as a read-only
//!   [`Bus`](crate::Bus), at its recorded pace or scaled
//!   ([`ReplayOptions`]).

pub mod format;
pub mod record;
pub mod replay;

#[cfg(test)]
mod tests;

pub use format::{LogError, LogWriter, LoggedFrame, MAX_LINE, read_log, read_log_from};
pub use record::{
    Ended, FlushPolicy, LogRecorder, RecordEnd, RecordProgress, RecordSummary, record_bus,
};
pub use replay::{ReplayError, ReplayOptions, open_replay};
