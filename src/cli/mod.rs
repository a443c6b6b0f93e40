//! The command line (`docs/cli.md`).
//!
//! Every failure a user can cause ends in one line on stderr and a non-zero
//! exit status: 2 for a command line that cannot be read, 1 for anything that
//! went wrong while running (an unreachable bus, a port in use).
//!
//! # Layout
//!
//! - [`serve`]: `candeck serve` (and `candeck` alone), the gateway and its
//!   REST interface.
//! - [`vbus`]: `candeck vbus`, an emulated bus served over socketcand.
//! - [`dump`]: `candeck dump`, a bus printed as a candump `-L` log.
//! - [`od`]: `candeck od read|write`, one object of one node over SDO.
//! - [`nmt`]: `candeck nmt`, NMT node control.
//! - [`ascii`]: `candeck ascii`, the CiA 309-3 ASCII gateway on
//!   stdin/stdout.
//! - [`eds`]: `candeck eds check`, EDS/DCF files read as the gateway reads
//!   them, with every warning.

pub mod ascii;
pub mod dump;
pub mod eds;
pub mod nmt;
pub mod od;
pub mod serve;
pub mod vbus;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// candeck: a gateway and dashboard for CANopen machines.
#[derive(Debug, Parser)]
#[command(
    name = "candeck",
    version,
    about,
    long_about = None,
    propagate_version = true,
    args_conflicts_with_subcommands = true
)]
pub struct Cli {
    /// Log filter, as RUST_LOG takes it (error, warn, info, debug, trace, or
    /// per module). Default: info for servers (serve, vbus, dump), warn for one-shot
    /// commands (od, nmt).
    #[arg(long, global = true, env = "CANDECK_LOG")]
    pub log: Option<String>,

    /// `candeck [serve] ...`: the serve options are taken without the
    /// command's name, since serving is what `candeck` does by default.
    #[command(flatten)]
    pub serve: serve::ServeArgs,

    #[command(subcommand)]
    pub command: Option<Command>,
}

// Parsed once at start and matched once: the size of `serve`'s many
// options costs nothing worth a box.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the gateway: the REST API over HTTP for one or more buses (the
    /// default command; without --bus, the demo devices on virtual:demo).
    Serve(serve::ServeArgs),
    /// Run an emulated CAN bus and share it over the socketcand protocol, so
    /// that candeck, python-can, python-canopen and can-utils join it.
    Vbus(vbus::VbusArgs),
    /// Print everything on a bus as a candump -L log on stdout.
    Dump(dump::DumpArgs),
    /// Read or write an object of a node's dictionary over SDO.
    Od(od::OdArgs),
    /// Send an NMT command to a node or to all nodes.
    Nmt(nmt::NmtArgs),
    /// Serve the CiA 309-3 ASCII gateway protocol (CANopenNode's
    /// canopend/cocomm) on stdin/stdout until the input ends.
    Ascii(ascii::AsciiArgs),
    /// Check EDS and DCF files (CiA 306): every warning and error, one
    /// summary line per file.
    Eds(eds::EdsArgs),
}

/// A failure while running a command: printed as one line.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct CliError(pub String);

impl CliError {
    pub fn new(message: impl std::fmt::Display) -> Self {
        Self(message.to_string())
    }
}

/// Parses the command line, runs the command, and returns the exit status.
pub fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(err) => return usage_error(err),
    };
    // stdin/stdout belong to the protocol in `ascii`: only warnings go to
    // stderr.
    let one_shot = matches!(
        cli.command,
        Some(Command::Od(_) | Command::Nmt(_) | Command::Ascii(_) | Command::Eds(_))
    );
    let default_log = if one_shot { "warn" } else { "info" };
    init_logging(cli.log.as_deref().unwrap_or(default_log));
    let command = cli.command.unwrap_or(Command::Serve(cli.serve));
    if let Command::Serve(args) = &command
        && let Err(message) = args.validate()
    {
        eprintln!("candeck: error: {message} (see 'candeck --help')");
        return ExitCode::from(2);
    }
    // One thread: request/response traffic (SDO) is 20 times faster than on
    // tokio's multi-thread scheduler, whose cross-thread wake-ups dominate
    // such short exchanges (see BENCHMARKS.md), and frames still flow at
    // several hundred thousand per second.
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(runtime) => runtime,
        Err(err) => {
            eprintln!("candeck: error: cannot start the async runtime: {err}");
            return ExitCode::from(1);
        }
    };
    let result = runtime.block_on(async {
        match command {
            Command::Serve(args) => serve::run(args).await,
            Command::Vbus(args) => vbus::run(args).await,
            Command::Dump(args) => dump::run(args).await,
            Command::Od(args) => od::run(args).await,
            Command::Nmt(args) => nmt::run(args).await,
            Command::Ascii(args) => ascii::run(args).await,
            Command::Eds(args) => eds::run(args).await,
        }
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("candeck: error: {err}");
            ExitCode::from(1)
        }
    }
}

/// `--help` and `--version` print as clap writes them; a command line that
/// cannot be read gives clap's first line (what is wrong) and exit status 2.
fn usage_error(err: clap::Error) -> ExitCode {
    use clap::error::ErrorKind;
    match err.kind() {
        ErrorKind::DisplayHelp
        | ErrorKind::DisplayVersion
        | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => {
            let _ = err.print();
            ExitCode::SUCCESS
        }
        _ => {
            // clap's message is its first paragraph (the argument missing may
            // be on a line of its own); usage and tips follow a blank line.
            let text = err.render().to_string();
            let message: Vec<&str> = text
                .lines()
                .take_while(|line| !line.trim().is_empty())
                .map(str::trim)
                .collect();
            let message = message.join(" ");
            let message = message.strip_prefix("error: ").unwrap_or(&message);
            eprintln!("candeck: error: {message} (see 'candeck --help')");
            ExitCode::from(2)
        }
    }
}

fn init_logging(filter: &str) {
    let filter = tracing_subscriber::EnvFilter::try_new(filter).unwrap_or_else(|err| {
        eprintln!("candeck: warning: log filter '{filter}' is not valid ({err}); using 'info'");
        tracing_subscriber::EnvFilter::new("info")
    });
    // Logs go to stderr: stdout belongs to the command's output (dump logs).
    use std::io::IsTerminal;
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr)
        .with_target(false)
        .try_init();
}

/// A bus a command works on, with the devices of `virtual:demo` running
/// for as long as it is kept.
pub struct CommandBus {
    pub bus: crate::can::Bus,
    /// The demo devices of `virtual:demo`; `None` on other buses.
    pub devices: Option<crate::sim::rack::Rack>,
}

/// Opens `spec` for a command; `virtual:demo` comes with the demo devices
/// booted on it, as the bus spec promises.
pub async fn open_bus(spec: &crate::can::spec::BusSpec) -> Result<CommandBus, CliError> {
    let name = spec.default_name();
    let opened = spec.open(&name).await.map_err(CliError::new)?;
    let devices = match (spec, &opened.hub) {
        (crate::can::spec::BusSpec::Virtual { preset, .. }, Some(hub)) if preset != "empty" => {
            let rack = crate::sim::rack::Rack::new(hub.clone());
            let devices = crate::sim::products::parse_devices(preset).map_err(CliError::new)?;
            rack.add_all(&devices).map_err(CliError::new)?;
            Some(rack)
        }
        _ => None,
    };
    Ok(CommandBus {
        bus: opened.bus,
        devices,
    })
}

/// Resolves on Ctrl-C or SIGTERM (how `docker stop` and systemd end us).
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut signal) => {
                signal.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let terminate = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {}
        _ = terminate => {}
    }
}

/// A line on stdout for people and scripts (the address a server listens
/// on). A long-running server whose reader went away (`| head -1`, a closed
/// pipe) must keep running: a failed write is ignored where `println!`
/// would panic.
pub(crate) fn say(line: std::fmt::Arguments<'_>) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    let _ = out
        .write_fmt(line)
        .and_then(|()| out.write_all(b"\n"))
        .and_then(|()| out.flush());
}
