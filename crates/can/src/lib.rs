//! The CAN layer: frames and buses, nothing CANopen.
//!
//! # Layout
//!
//! - [`frame`]: [`Frame`] (ISO 11898-1 classic and FD, remote and error
//!   frames), [`Timestamp`], [`TimedFrame`].
//! - [`bus`]: the [`Bus`] attachment every backend hands out: send, receive,
//!   state, counters.
//! - [`hub`]: [`VirtualHub`], the in-process emulated bus.
//! - [`fault`]: fault confinement (ISO 11898-1): error counters and the
//!   error-active / error-passive / bus-off states (sans-I/O).
//! - [`timing`]: the virtual bus's wire: bit rate, frame lengths with
//!   stuffing, arbitration by identifier (sans-I/O, driven by the hub).
//! - [`socketcand`]: the socketcand protocol (linux-can/socketcand
//!   `doc/protocol.md`, raw mode): its line codec, a server that shares a
//!   virtual hub over TCP, and a client backend that joins a remote server.
//! - [`socketcan`]: Linux SocketCAN through the `socketcan` crate (frame
//!   conversions always; the I/O backend behind the `socketcan` feature).
//! - [`candump`]: candump `-L` logs: writing a bus to a log and replaying one.
//! - [`spec`]: bus specs (`virtual:demo`, `socketcand:HOST:PORT/CHANNEL`, ...)
//!   and opening a bus from one.

pub mod bus;
pub mod candump;
pub mod fault;
pub mod frame;
pub mod hub;
pub mod socketcan;
pub mod socketcand;
pub mod timing;

pub use bus::{
    Bus, BusError, BusKind, BusState, BusStatus, CounterSnapshot, FrameReceiver, RecvError,
};
pub use fault::{ControllerStatus, ErrorState, FaultConfinement};
pub use frame::{CanId, Direction, FdFlags, Frame, FrameError, FrameKind, TimedFrame, Timestamp};
pub use hub::{ControllerFault, VirtualHub};
pub use timing::Bitrate;
pub mod spec;

#[doc(hidden)]
pub mod test_support;
