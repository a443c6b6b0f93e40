//! `candeck ascii`: the CiA 309-3 ASCII gateway protocol on stdin/stdout
//! (as CANopenNode's `canopend` with its gateway on standard I/O): command
//! lines in, replies and event lines out, until the input ends.

use std::sync::Arc;
use std::time::Duration;

use clap::Args;

use super::CliError;
use super::serve::NamedBus;
use crate::ascii::serve_connection;
use crate::cia309::{Cia309Gateway, Identity};
use crate::gateway::EdsCatalog;
use crate::gateway::Gateway;
use crate::gateway::RegistryConfig;

#[derive(Debug, Args)]
pub struct AsciiArgs {
    /// A bus, as NAME=SPEC or SPEC (virtual:demo, socketcan:can0,
    /// socketcand:HOST:PORT/CHANNEL); repeat for more: net 1 is the first.
    /// Default: demo=virtual:demo.
    #[arg(long = "bus", value_name = "NAME=SPEC")]
    pub buses: Vec<NamedBus>,
    /// A directory of EDS files, matched to nodes before the built-in ones.
    #[arg(long, value_name = "DIR")]
    pub eds_dir: Option<std::path::PathBuf>,
}

pub async fn run(args: AsciiArgs) -> Result<(), CliError> {
    let catalog = match &args.eds_dir {
        Some(dir) => EdsCatalog::with_dir(dir),
        None => EdsCatalog::builtin(),
    }
    .map_err(CliError::new)?;
    let catalog = Arc::new(catalog);
    let mut buses = args.buses;
    if buses.is_empty() {
        buses.push("demo=virtual:demo".parse().map_err(CliError::new)?);
    }
    let mut served = Vec::new();
    for bus in &buses {
        let opened = crate::emulator::open_bus(
            &bus.name,
            &bus.spec,
            catalog.clone(),
            RegistryConfig::default(),
            super::serve::DEFAULT_BITRATE,
        )
        .await
        .map_err(|err| CliError::new(format!("bus {}: {err}", bus.name)))?;
        served.push(opened);
    }
    // Nodes that booted before the gateway listened are found by a scan,
    // before the first command is read: a script's first read finds them.
    for bus in &served {
        if bus.wait_up(Duration::from_secs(5)).await.is_ok()
            && let Err(err) = bus.scan().await
        {
            tracing::warn!("bus {}: scan failed: {err}", bus.name());
        }
    }
    let gateway = Cia309Gateway::new(&Gateway::new(served));
    let identity = Identity::anonymous("ascii-stdio", None);
    serve_connection(gateway, identity, tokio::io::stdin(), tokio::io::stdout()).await;
    Ok(())
}
