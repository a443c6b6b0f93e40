//! The CiA 402 power drive system (PDS): its finite state automaton, the
//! controlword that commands it and the statusword that reports it, the
//! option codes that shape its stops, and the modes of operation (UniSwarm
//! UMC firmware manual, chapter 1.2 "Power drive system (PDS)" and §1.4;
//! JMC CANopen stepper manual, 0x6040/0x6041/0x605A/0x605D/0x6060).
//!
//! Pure code, shared by both ends: a virtual drive runs a
//! [`DriveStateMachine`], the gateway [`plan()`]s the controlwords that walk a
//! real (or virtual) drive to the state asked for and checks each step
//! against the statusword. Nothing here does I/O or reads a clock: the
//! drive reports when its ramps have ended through [`Event`]s.
//!
//! # Layout
//!
//! - [`state`]: [`State`] (Figure 2.1), the [`Statusword`] (Tables 2.7, 2.8)
//!   and the [`StatusFlags`] beside the state bits.
//! - [`command`]: [`Command`] and the [`Controlword`] (Figure 2.4), with the
//!   0→1 edge of fault reset.
//! - [`options`]: the option codes 0x6007, 0x605A–0x605E (Tables 2.10–2.15)
//!   and the [`StopKind`] each asks for.
//! - [`drive`]: [`DriveStateMachine`], transitions 0–16 (Table 2.2) as the
//!   drive sees them, and the [`Reaction`] each asks of the drive.
//! - [`plan`](mod@plan): [`plan()`] and [`expected_state`], the master's walk.
//! - [`mode`]: [`Mode`], 0x6060/0x6061 (Figure 2.5) and 0x6502 (Figure 2.6).
//! - [`objects`]: the one table of the CiA 402 object indexes.

pub mod command;
pub mod drive;
pub mod mode;
pub mod objects;
pub mod options;
pub mod plan;
pub mod state;

#[cfg(test)]
mod tests;

pub use command::{Command, Controlword};
pub use drive::{DriveStateMachine, Event, Options, Reaction};
pub use mode::Mode;
pub use options::{
    AbortConnectionOption, DisableOption, FaultReactionOption, HaltOption, QuickStopOption,
    StopKind,
};
pub use plan::{PlanError, expected_state, plan};
pub use state::{State, StatusFlags, Statusword};
