//! `candeck serve`: the gateway, its REST interface over HTTP
//! (`docs/cli.md`, `docs/rest-api.md`).
//!
//! # Layout
//!
//! - `args`: the arguments (clap) and what each accepts.
//! - `config`: the config file merged under the flags, the tokens, the
//!   checks of the whole.
//! - `open_files`: the connection limits against the process's limit of
//!   open files.
//! - `start`: the start-up: the buses, the gateway service and its
//!   adapters, and the stop on shutdown. The one place in `cli` that wires
//!   the REST adapter (`crate::api`) to the gateway service.

mod args;
mod config;
mod open_files;
mod start;

#[cfg(test)]
mod tests;

pub use args::{DEFAULT_BITRATE, NamedBus, ServeArgs, Share, TOKENS_ENV};
pub use start::run;
