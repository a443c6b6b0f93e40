//! What the host application asks of the edge node (Sparkplug 3.0 §6.4.19
//! NCMD, §6.4.20 DCMD), read from the command's metrics, sans I/O. The
//! metrics candeck takes (docs/sparkplug.md):
//!
//! - NCMD `Node Control/Rebirth` = true: the births again.
//! - DCMD `NMT` (String): `start`, `stop`, `pre_operational`,
//!   `reset_node`, `reset_communication`.
//! - DCMD `OD/0x1017:0` (any type): an object write, checked against the
//!   node's EDS as a REST write is.

use super::edge::REBIRTH;
use super::metric::MetricValue;
use super::proto::Payload;
use crate::canopen::nmt::NmtCommand;

/// One command of a message.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    Rebirth,
    Nmt(NmtCommand),
    Write {
        index: u16,
        sub: u8,
        value: MetricValue,
    },
    /// A metric candeck does not take (named, for the log and the audit).
    Unsupported(String),
}

impl Command {
    /// As the audit log names the operation.
    pub fn operation(&self) -> &'static str {
        match self {
            Self::Rebirth => "rebirth",
            Self::Nmt(_) => "nmt command",
            Self::Write { .. } => "write object",
            Self::Unsupported(_) => "unsupported command",
        }
    }
}

/// The commands of an NCMD (`device` false) or a DCMD payload, in order.
pub fn parse(payload: &Payload, device: bool) -> Vec<Command> {
    payload
        .metrics
        .iter()
        .map(|metric| {
            let name = metric.name.clone().unwrap_or_default();
            let value = MetricValue::from_metric(metric);
            match (device, name.as_str(), value) {
                (false, REBIRTH, Some(MetricValue::Boolean(true))) => Command::Rebirth,
                (true, "NMT", Some(MetricValue::String(text))) => match nmt_command(&text) {
                    Some(command) => Command::Nmt(command),
                    None => Command::Unsupported(format!("NMT {text}")),
                },
                (true, name, Some(value)) if name.starts_with("OD/") => {
                    match parse_object(&name[3..]) {
                        Some((index, sub)) => Command::Write { index, sub, value },
                        None => Command::Unsupported(name.to_string()),
                    }
                }
                _ => Command::Unsupported(name),
            }
        })
        .collect()
}

/// An NMT command by the name candeck's REST API gives it.
pub fn nmt_command(text: &str) -> Option<NmtCommand> {
    Some(match text.trim() {
        "start" | "operational" => NmtCommand::Start,
        "stop" | "stopped" => NmtCommand::Stop,
        "pre_operational" | "preoperational" => NmtCommand::EnterPreOperational,
        "reset_node" => NmtCommand::ResetNode,
        "reset_communication" => NmtCommand::ResetCommunication,
        _ => return None,
    })
}

/// `0x1017:0` (or `1017:0`, sub decimal).
pub fn parse_object(text: &str) -> Option<(u16, u8)> {
    let (index, sub) = text.split_once(':')?;
    let index = index.trim_start_matches("0x").trim_start_matches("0X");
    Some((u16::from_str_radix(index, 16).ok()?, sub.parse().ok()?))
}

/// A device ID (`{bus}-{node}`, e.g. `demo-1`) as bus and node; the bus
/// name may hold `-` itself.
pub fn parse_device(device: &str) -> Option<(&str, u8)> {
    let (bus, node) = device.rsplit_once('-')?;
    let node: u8 = node.parse().ok()?;
    (!bus.is_empty() && (1..=127).contains(&node)).then_some((bus, node))
}

/// The device ID of a node of a bus.
pub fn device_id(bus: &str, node: u8) -> String {
    format!("{bus}-{node}")
}
