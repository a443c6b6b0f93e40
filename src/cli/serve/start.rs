//! The start-up of `candeck serve`: the buses opened, the gateway service
//! and its adapters (REST over HTTP, CiA 309-3 over TCP, socketcand shares)
//! started, and on shutdown the axes the gateway enabled stopped.

use crate::api::AppState;
use crate::can::socketcand::{ServerConfig, SocketcandServer};
use crate::cli::{CliError, shutdown_signal};

use super::args::*;

pub async fn run(args: ServeArgs) -> Result<(), CliError> {
    let mut args = args.settings().map_err(CliError::new)?;
    // Every listener's connections within the limit of open files.
    let others = args
        .ascii_listen
        .map_or(0, |_| args.ascii_limits.max_connections)
        + args.shared_addresses() * args.share_max_connections;
    let wanted = (args.http_limits.max_connections + others) as u64
        + super::open_files::FILES_FOR_THE_GATEWAY;
    if let Some(limit) = super::open_files::raised_limit(wanted) {
        match super::open_files::fit(limit, args.http_limits.max_connections, others)
            .map_err(CliError::new)?
        {
            super::open_files::Fit::Fits => {}
            super::open_files::Fit::Lowered(room, warning) => {
                tracing::warn!("{warning}");
                args.http_limits.max_connections = room;
            }
        }
    }
    // Refused by settings() already when it is an error; warned about once
    // the gateway listens (a start that fails says one line only).
    let exposure = args.exposure().map_err(CliError::new)?;
    let listener_warnings = args.listeners().map_err(CliError::new)?;
    let gateway = crate::gateway::Gateway::start(
        args.gateway_config(),
        &crate::emulator::racks(args.data_dir.clone()),
    )
    .await
    .map_err(|err| CliError::new(err.to_string()))?;
    if let Some(catalog) = gateway.eds_catalog() {
        catalog.set_quota(args.eds_quota);
    }
    let served = gateway.buses_in_order();
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
        .map(|bus| format!("{}: {}", bus.name(), bus.spec()))
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
    let state = AppState::from_gateway(gateway)
        .with_guard(args.auth.clone())
        .with_stream_limits(args.stream_limits)
        .with_allowed_hosts(args.allowed_hosts.clone());
    // The Sparkplug B edge node (mqtt_url), on the same gateway service.
    let edge_node = match args.sparkplug.clone() {
        Some(config) => {
            // Allowed by sparkplug_insecure only (refused otherwise when the
            // settings were read): said loudly, at every start.
            if let Ok(Some(warning)) = config.command_exposure() {
                tracing::warn!("{warning}");
            }
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
    // The OPC UA server (opcua_listen), on the same gateway service.
    let opcua = start_opcua(&state, args.opcua.as_ref()).await?;
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
            stop_opcua(opcua).await;
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
    // axis moving again: the gateway's end stops them all once more, and
    // ends a running recording with all it received written to its file
    // (temporary recordings are removed when the buses are dropped).
    log_stops(&state.gateway.shutdown().await);
    // NDEATH published, then DISCONNECT (the will is for an unclean end).
    if let Some(edge_node) = edge_node {
        edge_node.stop(std::time::Duration::from_secs(2)).await;
    }
    // The OPC UA sessions are closed (their leases lapse with them).
    stop_opcua(opcua).await;
    if let Some(ascii) = ascii {
        ascii.abort();
    }
    drop(state);
    drop(shares);
    tracing::info!("serve: stopped");
    Ok(())
}

#[cfg(feature = "opcua")]
type OpcUa = Option<crate::opcua::OpcUaServer>;
#[cfg(not(feature = "opcua"))]
type OpcUa = Option<std::convert::Infallible>;

/// The OPC UA server of `config`, if any, started; its address said on
/// stdout (the port, when 0 was asked).
#[cfg(feature = "opcua")]
async fn start_opcua(
    state: &AppState,
    config: Option<&crate::opcua::OpcUaConfig>,
) -> Result<OpcUa, CliError> {
    let Some(config) = config else {
        return Ok(None);
    };
    let server = crate::opcua::OpcUaServer::start(state.gateway.clone(), config)
        .await
        .map_err(|err| CliError::new(format!("--opcua-listen: {err}")))?;
    crate::cli::say(format_args!(
        "candeck: OPC UA server on opc.tcp://{}/ (PKI {})",
        server.local_addr(),
        config.pki_dir.display()
    ));
    Ok(Some(server))
}

/// Without the `opcua` feature the settings refuse `opcua_listen`.
#[cfg(not(feature = "opcua"))]
async fn start_opcua(
    _: &AppState,
    _: Option<&crate::opcua::OpcUaConfig>,
) -> Result<OpcUa, CliError> {
    Ok(None)
}

#[cfg(feature = "opcua")]
async fn stop_opcua(server: OpcUa) {
    if let Some(server) = server {
        server.stop(std::time::Duration::from_secs(2)).await;
    }
}

#[cfg(not(feature = "opcua"))]
async fn stop_opcua(_: OpcUa) {}

/// The stop on shutdown ([`crate::gateway::Gateway::stop_enabled_axes`]),
/// logged axis by axis.
async fn stop_axes(state: &AppState) {
    log_stops(&state.gateway.stop_enabled_axes().await);
}

/// A stop report, logged axis by axis.
fn log_stops(report: &crate::gateway::StopReport) {
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
