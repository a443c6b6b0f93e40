//! `candeck nmt`: an NMT node-control command (CiA 301 §7.2.8.3.1) to one
//! node or to all.

use std::time::Duration;

use clap::{Args, ValueEnum};

use super::{CliError, CommandBus, open_bus};
use crate::can::spec::BusSpec;
use crate::canopen::NodeId;
use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};

#[derive(Debug, Args)]
pub struct NmtArgs {
    /// The bus: socketcand:HOST:PORT/CHANNEL, socketcan:IFACE, virtual:empty.
    #[arg(long, value_name = "SPEC")]
    pub bus: BusSpec,
    /// The node id (1 to 127), or `all`.
    #[arg(long, value_name = "ID|all", value_parser = parse_target)]
    pub node: NmtTarget,
    /// The NMT command: start (operational), stop, pre-operational,
    /// reset-node (the application), reset-communication.
    pub command: Command,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Command {
    Start,
    Stop,
    PreOperational,
    ResetNode,
    ResetCommunication,
}

impl From<Command> for NmtCommand {
    fn from(command: Command) -> Self {
        match command {
            Command::Start => NmtCommand::Start,
            Command::Stop => NmtCommand::Stop,
            Command::PreOperational => NmtCommand::EnterPreOperational,
            Command::ResetNode => NmtCommand::ResetNode,
            Command::ResetCommunication => NmtCommand::ResetCommunication,
        }
    }
}

fn parse_target(text: &str) -> Result<NmtTarget, String> {
    if text.eq_ignore_ascii_case("all") {
        return Ok(NmtTarget::All);
    }
    text.parse::<NodeId>().map(NmtTarget::Node)
}

pub async fn run(args: NmtArgs) -> Result<(), CliError> {
    // This must be the bus's only handle: closing the last one writes what
    // is queued (the demo devices of virtual:demo keep their own).
    let CommandBus {
        bus,
        devices: _devices,
    } = open_bus(&args.bus).await?;
    bus.wait_up(Duration::from_secs(5))
        .await
        .map_err(CliError::new)?;
    let command = NmtCommand::from(args.command);
    let frame = NmtMessage::new(command, args.node).encode();
    bus.send(frame).await.map_err(CliError::new)?;
    // NMT is unconfirmed: once the frame is written there is nothing to wait for.
    bus.close().await;
    let target = match args.node {
        NmtTarget::All => "all nodes".to_string(),
        NmtTarget::Node(node) => format!("node {node}"),
    };
    tracing::info!("nmt: sent {} to {target}", command.name());
    Ok(())
}
