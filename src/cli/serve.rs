//! `candeck serve`: the gateway, its REST interface over HTTP
//! (`../shared/API.md`, "Command line" and "REST").

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

use clap::Args;

use super::{CliError, shutdown_signal};
use crate::api::{AppState, ServedBus};
use crate::can::spec::BusSpec;
use crate::gateway::profile::EdsCatalog;
use crate::gateway::registry::RegistryConfig;

/// The bit rate of a bus when none is given: the most common CANopen rate,
/// used only to express the measured bits per second as a load.
pub const DEFAULT_BITRATE: u32 = 500_000;

fn default_serve_listen() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], 8080))
}

/// A bus to serve: `NAME=SPEC`, or `SPEC` with its default name.
#[derive(Debug, Clone)]
pub struct NamedBus {
    pub name: String,
    pub spec: BusSpec,
}

impl std::str::FromStr for NamedBus {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        // A spec starts with its kind and a colon; a name has neither.
        let (name, spec) = match text.split_once('=') {
            Some((name, spec)) if !name.contains(':') => (Some(name), spec),
            _ => (None, text),
        };
        let spec: BusSpec = spec.parse().map_err(|err| format!("{err}"))?;
        let name = name.map_or_else(|| spec.default_name(), str::to_string);
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            return Err(format!(
                "bus name '{name}' is not a name: letters, digits, '-' and '_' only"
            ));
        }
        Ok(Self { name, spec })
    }
}

#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Address the HTTP server listens on (port 0 picks a free port).
    #[arg(long, default_value_t = default_serve_listen())]
    pub listen: SocketAddr,
    /// A bus to serve, as NAME=SPEC or SPEC (virtual:demo, virtual:empty,
    /// socketcan:can0, socketcand:HOST:PORT/CHANNEL); repeat for more.
    /// Default: demo=virtual:demo, the demo devices on an emulated bus.
    #[arg(long = "bus", value_name = "NAME=SPEC")]
    pub buses: Vec<NamedBus>,
    /// A directory of EDS files, matched to nodes before the built-in ones.
    #[arg(long, value_name = "DIR")]
    pub eds_dir: Option<PathBuf>,
    /// The buses' bit rate in bit/s, which the load in GET /buses is a
    /// fraction of.
    #[arg(long, default_value_t = DEFAULT_BITRATE, value_parser = clap::value_parser!(u32).range(1..))]
    pub bitrate: u32,
}

impl ServeArgs {
    /// The buses to serve: those given, or the demo bus.
    fn buses(&self) -> Vec<NamedBus> {
        if self.buses.is_empty() {
            vec![NamedBus {
                name: "demo".to_string(),
                spec: BusSpec::Virtual {
                    preset: "demo".to_string(),
                },
            }]
        } else {
            self.buses.clone()
        }
    }

    /// What clap cannot check one argument at a time: two buses of one name.
    pub fn validate(&self) -> Result<(), String> {
        let mut seen = std::collections::BTreeSet::new();
        for bus in &self.buses {
            if !seen.insert(bus.name.as_str()) {
                return Err(format!(
                    "invalid value for '--bus': two buses are named '{}'; name them NAME=SPEC",
                    bus.name
                ));
            }
        }
        Ok(())
    }
}

pub async fn run(args: ServeArgs) -> Result<(), CliError> {
    let catalog = match &args.eds_dir {
        Some(dir) => EdsCatalog::with_dir(dir),
        None => EdsCatalog::builtin(),
    }
    .map_err(CliError::new)?;
    let catalog = Arc::new(catalog);
    let mut served = Vec::new();
    for bus in args.buses() {
        let opened = ServedBus::open(
            &bus.name,
            &bus.spec,
            catalog.clone(),
            RegistryConfig::default(),
            args.bitrate,
        )
        .await
        .map_err(|err| CliError::new(format!("bus {}: {err}", bus.name)))?;
        served.push(opened);
    }
    let listener = tokio::net::TcpListener::bind(args.listen)
        .await
        .map_err(|err| CliError::new(format!("cannot listen on {}: {err}", args.listen)))?;
    let local = listener
        .local_addr()
        .map_err(|err| CliError::new(format!("cannot listen on {}: {err}", args.listen)))?;
    let described: Vec<String> = served
        .iter()
        .map(|bus| format!("{}: {}", bus.name, bus.spec))
        .collect();
    let label = if described.len() == 1 { "bus" } else { "buses" };
    // One line on stdout that people and scripts read (the port, when 0 was asked).
    println!(
        "candeck: serving http://{local}/ ({label} {})",
        described.join(", ")
    );
    // Nodes that booted before the gateway listened, and nodes without
    // heartbeat, are found by a scan; the API answers meanwhile.
    for bus in &served {
        let registry = bus.registry.clone();
        let name = bus.name.clone();
        tokio::spawn(async move {
            match registry.scan().await {
                Ok(nodes) => tracing::info!("bus {name}: {} nodes found", nodes.len()),
                Err(err) => tracing::warn!("bus {name}: first scan failed: {err}"),
            }
        });
    }
    let state = AppState::new(served);
    axum::serve(listener, crate::api::app(state))
        .with_graceful_shutdown(shutdown_signal())
        .await
        .map_err(|err| CliError::new(format!("HTTP server on {local}: {err}")))?;
    tracing::info!("serve: stopped");
    Ok(())
}
