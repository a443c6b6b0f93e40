//! The start-up of `candeck serve`: the buses opened, the gateway service
//! and its adapters (REST over HTTP, CiA 309-3 over TCP, socketcand shares)
//! started, and on shutdown the axes the gateway enabled stopped.

use std::sync::Arc;

use crate::api::AppState;
use crate::can::socketcand::{ServerConfig, SocketcandServer};
use crate::cli::{CliError, shutdown_signal};
use crate::gateway::history::History;
use crate::gateway::producers::TelemetryConfig;
use crate::gateway::profile::EdsCatalog;
use crate::gateway::recording::RecordingsQuota;
use crate::gateway::registry::RegistryConfig;

use super::args::*;

/// How long the first scan of a bus waits for the bus to come up.
pub(super) const FIRST_SCAN_WAIT: std::time::Duration = std::time::Duration::from_secs(30);

pub async fn run(args: ServeArgs) -> Result<(), CliError> {
    let args = args.settings().map_err(CliError::new)?;
    // Refused by settings() already when it is an error; warned about once
    // the gateway listens (a start that fails says one line only).
    let exposure = args.exposure().map_err(CliError::new)?;
    let listener_warnings = args.listeners().map_err(CliError::new)?;
    if let Some(dir) = &args.data_dir {
        // 0700 when candeck makes it (docs/security.md, "Files").
        crate::gateway::files::create_private_dir(dir)
            .map_err(|err| CliError::new(format!("--data-dir {}: {err}", dir.display())))?;
    }
    // Opened before the buses, so that their first events are kept.
    let history = match &args.data_dir {
        Some(dir) => History::open(dir),
        None => History::in_memory(),
    }
    .map_err(|err| CliError::new(err.to_string()))?;
    let pruner = history.spawn_pruner(args.retention);
    let catalog = match &args.eds_dir {
        Some(dir) => EdsCatalog::with_dir(dir),
        None => EdsCatalog::builtin(),
    }
    .map_err(CliError::new)?;
    // Uploaded EDS files are kept in DATA/eds; without a data directory,
    // in memory.
    let catalog = match &args.data_dir {
        Some(dir) => catalog.with_uploads(dir.join("eds")),
        None => Ok(catalog),
    }
    .map_err(CliError::new)?;
    let catalog = Arc::new(catalog);
    let mut served = Vec::new();
    for bus in &args.buses {
        let data_dir = args
            .data_dir
            .as_ref()
            .map(|dir| dir.join("sim").join(&bus.name));
        let config = RegistryConfig {
            telemetry: TelemetryConfig {
                axis_poll_hz: args.axis_poll_hz,
                ..TelemetryConfig::default()
            },
            ..RegistryConfig::default()
        };
        let mut opened = crate::emulator::open_bus_with_data_dir(
            &bus.name,
            &bus.spec,
            catalog.clone(),
            config,
            args.bitrate,
            data_dir,
        )
        .await
        .map_err(|err| CliError::new(format!("bus {}: {err}", bus.name)))?;
        if let Some(dir) = &args.data_dir {
            opened = opened.with_recordings_dir(dir.join("recordings"));
        }
        // What PUT /buses/{bus}/sync would set, from the start.
        opened.sync.set_period(args.sync_period);
        // The network manager (CiA 302-2): the gateway's heartbeat, and
        // every node booted, supervised and started.
        let machine = crate::gateway::machine::MachineSettings {
            nodes: args
                .machine_nodes
                .get(&bus.name)
                .cloned()
                .unwrap_or_default(),
            ..args.machine.clone()
        };
        // A description's `eds` describes its node from the start, before
        // it is heard, as `PUT .../nodes/{id}/eds` would.
        for node in &machine.nodes {
            if let Some(name) = &node.eds {
                let entry = opened.registry.catalog().find(name).ok_or_else(|| {
                    CliError::new(format!(
                        "config: [[nodes]] bus {} id {}: eds \"{name}\" is no file of the EDS catalog (built-in, --eds-dir or uploaded; `candeck eds check` tells why a file is left out)",
                        bus.name, node.id
                    ))
                })?;
                opened.registry.assign_eds(node.id, Some(entry));
            }
        }
        opened = opened.with_machine(machine, Some(history.clone()));
        served.push(opened);
    }
    let mut shares = Vec::new();
    for (addr, channels) in args.shared(&served) {
        let names: Vec<String> = channels.iter().map(|(name, _)| name.clone()).collect();
        let config = ServerConfig {
            max_connections: args.share_max_connections,
            ..ServerConfig::default()
        };
        let server = SocketcandServer::bind(addr, channels, config)
            .await
            .and_then(SocketcandServer::spawn)
            .map_err(|err| CliError::new(format!("--share: cannot listen on {addr}: {err}")))?;
        shares.push((server, names));
    }
    let listener = tokio::net::TcpListener::bind(args.listen)
        .await
        .map_err(|err| CliError::new(format!("cannot listen on {}: {err}", args.listen)))?;
    let local = listener
        .local_addr()
        .map_err(|err| CliError::new(format!("cannot listen on {}: {err}", args.listen)))?;
    let ascii_listener = match args.ascii_listen {
        Some(addr) => {
            let listener = tokio::net::TcpListener::bind(addr).await.map_err(|err| {
                CliError::new(format!("--ascii-listen: cannot listen on {addr}: {err}"))
            })?;
            let local = listener.local_addr().map_err(|err| {
                CliError::new(format!("--ascii-listen: cannot listen on {addr}: {err}"))
            })?;
            Some((listener, local))
        }
        None => None,
    };
    let described: Vec<String> = served
        .iter()
        .map(|bus| format!("{}: {}", bus.name, bus.spec))
        .collect();
    let label = if described.len() == 1 { "bus" } else { "buses" };
    // One line on stdout that people and scripts read (the port, when 0 was asked).
    crate::cli::say(format_args!(
        "candeck: serving http://{local}/ ({label} {})",
        described.join(", ")
    ));
    for (server, names) in &shares {
        let label = if names.len() == 1 { "bus" } else { "buses" };
        crate::cli::say(format_args!(
            "candeck: sharing {label} {} over socketcand on {} (channel = bus name)",
            names.join(", "),
            server.local_addr()
        ));
    }
    if let Some((_, addr)) = &ascii_listener {
        crate::cli::say(format_args!(
            "candeck: CiA 309-3 ASCII gateway on {addr} (net 1 = the first bus)"
        ));
    }
    match exposure {
        // The address as it listens (the port, when 0 was asked).
        Some(warning) => tracing::warn!(
            "{}",
            warning.replace(&args.listen.to_string(), &local.to_string())
        ),
        None => tracing::info!(
            "tokens: {}; every request but the health check and the dashboard's pages needs one",
            args.auth.tokens.len()
        ),
    }
    for warning in &listener_warnings {
        tracing::warn!("{warning}");
    }
    // Nodes that booted before the gateway listened, and nodes without
    // heartbeat, are found by a scan; the API answers meanwhile.
    for bus in &served {
        let registry = bus.registry.clone();
        let attachment = bus.bus.clone();
        let name = bus.name.clone();
        let machine = bus.machine.clone();
        tokio::spawn(async move {
            // A socketcand bus is still connecting: scanning a bus that is
            // down finds nothing, so wait for it (the API answers meanwhile).
            if let Err(err) = attachment.wait_up(FIRST_SCAN_WAIT).await {
                tracing::warn!("bus {name}: not up for the first scan ({err}); POST /scan later");
            } else {
                match registry.scan().await {
                    Ok(nodes) => tracing::info!("bus {name}: {} nodes found", nodes.len()),
                    Err(err) => tracing::warn!("bus {name}: first scan failed: {err}"),
                }
            }
            // Expected nodes the scan did not find are missing from now on.
            if let Some(machine) = machine {
                machine.scan_done();
            }
        });
    }
    let mut state = AppState::with_history(served, history)
        .with_lease_period(args.lease_period)
        .with_auth(args.auth.clone())
        .with_allowed_hosts(args.allowed_hosts.clone());
    // Kept recordings within recordings_quota_mb, checked every minute.
    if let (Some(dir), Some(bytes)) = (&args.data_dir, args.recordings_quota) {
        let quota = RecordingsQuota {
            dir: dir.join("recordings"),
            bytes,
        };
        state.gateway = state.gateway.with_recordings_quota(quota);
    }
    // The data loggers, with those a run before kept in DIR/loggers.
    let loggers = crate::gateway::logger::Loggers::load(crate::gateway::logger::LoggerConfig {
        max_values: args.logger_max_values,
        dir: args.data_dir.as_ref().map(|dir| dir.join("loggers")),
    });
    state.gateway = state.gateway.with_loggers(loggers);
    let recordings_pruner = state
        .gateway
        .spawn_recordings_pruner(std::time::Duration::from_secs(60));
    // The Sparkplug B edge node (mqtt_url), on the same gateway service.
    let edge_node = match args.sparkplug.clone() {
        Some(config) => {
            crate::cli::say(format_args!(
                "candeck: Sparkplug B edge node {}/{} on {}://{}:{}",
                config.group_id,
                config.edge_node_id,
                if config.broker.tls { "mqtts" } else { "mqtt" },
                config.broker.host,
                config.broker.port
            ));
            Some(
                crate::sparkplug::EdgeNode::spawn(state.gateway.clone(), config)
                    .map_err(|err| CliError::new(format!("sparkplug: {err}")))?,
            )
        }
        None => None,
    };
    let ascii = ascii_listener.map(|(listener, _)| {
        tokio::spawn(crate::ascii::listen(
            listener,
            crate::cia309::Cia309Gateway::new(&state.gateway),
            args.ascii_limits,
        ))
    });
    // Timeouts and a connection limit (the peer's address goes into the
    // audit log); the server stops accepting when `drain` is sent.
    let (drain, draining) = tokio::sync::oneshot::channel::<()>();
    let mut server = tokio::spawn(crate::api::serve::serve(
        listener,
        crate::api::app(state.clone()),
        args.http_limits,
        state.connection_refusals.clone(),
        async {
            let _ = draining.await;
        },
    ));
    tokio::select! {
        () = shutdown_signal() => {}
        ended = &mut server => {
            // The server ended by itself: an error (it never does otherwise
            // before the signal). The axes are stopped all the same.
            stop_axes(&state).await;
            if let Some(edge_node) = edge_node {
                edge_node.stop(std::time::Duration::from_secs(2)).await;
            }
            return Err(match ended {
                Ok(()) => CliError::new(format!("HTTP server on {local} ended")),
                Err(err) => CliError::new(format!("HTTP server on {local}: {err}")),
            });
        }
    }
    let grace_ends = tokio::time::Instant::now() + args.shutdown_grace;
    // No new connection from now on; the open ones are told to finish.
    let _ = drain.send(());
    // No drive is left moving because the gateway went away: every axis it
    // enabled is stopped first, whatever the connections still open are
    // doing (a client holding a half-sent request must not hold up the
    // stop).
    tracing::info!("shutdown: stopping the axes the gateway enabled");
    stop_axes(&state).await;
    // The open connections get what is left of the grace period to finish
    // their requests; then they are closed.
    match tokio::time::timeout_at(grace_ends, &mut server).await {
        Ok(Ok(())) => {}
        Ok(Err(err)) => tracing::warn!("shutdown: HTTP server on {local}: {err}"),
        Err(_) => {
            tracing::warn!(
                "shutdown: HTTP connections still open after the grace period of {} ms: closed",
                args.shutdown_grace.as_millis()
            );
            server.abort();
        }
    }
    // A request that finished during the grace period may have set an
    // axis moving again.
    stop_axes(&state).await;
    // A running recording ends with all it received written to its file;
    // temporary recordings are removed when the buses are dropped.
    for bus in state.gateway.buses.values() {
        if bus.recorder.status().state == crate::gateway::recording::RecordingState::Recording {
            let _ = bus.recorder.stop().await;
        }
    }
    // NDEATH published, then DISCONNECT (the will is for an unclean end).
    if let Some(edge_node) = edge_node {
        edge_node.stop(std::time::Duration::from_secs(2)).await;
    }
    pruner.abort();
    recordings_pruner.abort();
    if let Some(ascii) = ascii {
        ascii.abort();
    }
    drop(state);
    drop(shares);
    tracing::info!("serve: stopped");
    Ok(())
}

/// The stop on shutdown ([`crate::gateway::Gateway::stop_enabled_axes`]),
/// logged axis by axis.
async fn stop_axes(state: &AppState) {
    let report = state.gateway.stop_enabled_axes().await;
    for stopped in &report.stopped {
        tracing::info!(
            "shutdown: quick stop of bus {} node {} axis {}",
            stopped.axis.bus,
            stopped.axis.node,
            stopped.axis.axis
        );
    }
    for failed in &report.failed {
        tracing::error!(
            "shutdown: could not stop bus {} node {} axis {:?}: {}; tried: {}",
            failed.bus,
            failed.node,
            failed.axis,
            crate::api::AppError::from(failed.error.clone()).to_json(),
            serde_json::json!(failed.attempts)
        );
    }
}
