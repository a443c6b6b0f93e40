//! What the host application asks of the edge node (Sparkplug 3.0 §6.4.19
//! NCMD, §6.4.20 DCMD), read from the command's metrics, sans I/O. The
//! metrics candeck takes (docs/sparkplug.md):
//!
//! - NCMD `Node Control/Rebirth` = true: the births again.
//! - DCMD `NMT` (String): `start`, `stop`, `pre_operational`,
//!   `reset_node`, `reset_communication`.
//! - DCMD `OD/0x1017:0` (any type): an object write, checked against the
//!   node's EDS as a REST write is.
//! - DCMD `Axis {n}/State` (String, a target of `POST .../axes/{n}/state`),
//!   `Axis {n}/Halt` (Boolean), `Axis {n}/Fault Reset` (Boolean true),
//!   `Axis {n}/Move` (String: the JSON body of `POST .../axes/{n}/move`),
//!   `Axis {n}/Lease` (Boolean: true renews the axis's motion lease, false
//!   gives it up and the axis is halted), `Axis {n}/Lease Id` (String: the
//!   id of the axis's lease, chosen by the host; it goes with the other
//!   commands of the axis in the same DCMD).
//! - DCMD `Segment {n}/{field}` of an LED controller: `Effect` (a name or
//!   its wire value), `Color 1`..`Color 3` (String `#rrggbb[ww]`), `Led
//!   Count`, `Dimmer`, `Value`, `Min Value`, `Max Value`, `Speed`, `Smooth`
//!   (numbers).
//!
//! A move without an end of its own (velocity, torque, duty cycle), and
//! releasing halt, is taken only with `Axis {n}/Lease` = true in the same
//! DCMD: the host says it will renew the lease, or the move is refused.
//! MQTT carries no sender identity, so the lease id is the capability: the
//! host chooses it (`Axis {n}/Lease Id`), the first grant binds the lease
//! to it, and every later motion command on the leased axis presents it
//! (`crate::gateway::motion`).

use super::edge::REBIRTH;
use super::metric::MetricValue;
use super::proto::Payload;
use super::proto::payload::Metric;
use crate::canopen::nmt::NmtCommand;
use crate::gateway::{MoveRequest, TargetState};
use crate::gateway::{SegmentUpdate, effect_by_name};
use crate::profiles::uioled::{SEGMENTS, address};

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
    /// A CiA 402 state to walk an axis to; `lease_id`: the `Axis {n}/Lease
    /// Id` of the same DCMD, if any (likewise below).
    AxisState {
        axis: u8,
        target: TargetState,
        lease_id: Option<String>,
    },
    /// Halt set (a stop) or released (motion resumed: `lease` says the host
    /// renews the lease it needs).
    Halt {
        axis: u8,
        halt: bool,
        lease: bool,
        lease_id: Option<String>,
    },
    FaultReset {
        axis: u8,
    },
    /// A move; `lease`: `Axis {n}/Lease` = true came with it.
    Move {
        axis: u8,
        request: Box<MoveRequest>,
        /// The request as the host gave it (for the audit log).
        body: String,
        lease: bool,
        lease_id: Option<String>,
    },
    /// `Axis {n}/Lease` alone: true renews, false gives the lease up.
    Lease {
        axis: u8,
        keep: bool,
        lease_id: Option<String>,
    },
    /// `Axis {n}/Lease Id`, before [`parse`] gives it to the axis's other
    /// commands of the DCMD.
    LeaseId {
        axis: u8,
        id: String,
    },
    /// Writes to one segment of an LED controller.
    Segment {
        segment: u8,
        update: SegmentUpdate,
    },
    /// A metric candeck does not take, or a value it cannot take (named,
    /// for the log and the audit).
    Unsupported(String),
}

impl Command {
    /// As the audit log names the operation.
    pub fn operation(&self) -> &'static str {
        match self {
            Self::Rebirth => "rebirth",
            Self::Nmt(_) => "nmt command",
            Self::Write { .. } => "write object",
            Self::AxisState { .. } => "drive state change",
            Self::Halt { .. } => "halt",
            Self::FaultReset { .. } => "fault reset",
            Self::Move { .. } => "move",
            Self::Lease { keep: true, .. } => "renew motion lease",
            Self::Lease { keep: false, .. } => "end motion lease",
            Self::LeaseId { .. } => "motion lease id",
            Self::Segment { .. } => "set segment",
            Self::Unsupported(_) => "unsupported command",
        }
    }

    /// The axis it commands, if any.
    pub fn axis(&self) -> Option<u8> {
        match self {
            Self::AxisState { axis, .. }
            | Self::Halt { axis, .. }
            | Self::FaultReset { axis }
            | Self::Move { axis, .. }
            | Self::Lease { axis, .. }
            | Self::LeaseId { axis, .. } => Some(*axis),
            _ => None,
        }
    }

    /// The motion lease id it presents (`Axis {n}/Lease Id` of its DCMD).
    pub fn lease_id(&self) -> Option<&str> {
        match self {
            Self::AxisState { lease_id, .. }
            | Self::Halt { lease_id, .. }
            | Self::Move { lease_id, .. }
            | Self::Lease { lease_id, .. } => lease_id.as_deref(),
            _ => None,
        }
    }

    /// Whether it stops motion (never refused by the write rate, as REST's
    /// halts and walks out of operation enabled are not).
    pub fn is_stop(&self) -> bool {
        match self {
            Self::AxisState { target, .. } => *target != TargetState::OperationEnabled,
            Self::Halt { halt, .. } => *halt,
            Self::Lease { keep: false, .. } => true,
            _ => false,
        }
    }
}

/// The commands of an NCMD (`device` false) or a DCMD payload, in order.
pub fn parse(payload: &Payload, device: bool) -> Vec<Command> {
    let commands: Vec<Command> = payload
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
                (true, name, Some(value)) if name.starts_with("Axis ") => axis_command(name, value),
                (true, name, Some(value)) if name.starts_with("Segment ") => {
                    segment_command(name, value)
                }
                _ => Command::Unsupported(name),
            }
        })
        .collect();
    fold_lease_ids(fold_leases(commands))
}

/// `Axis {n}/Lease` = true beside a move or a halt release of the same axis
/// is that command's lease promise, not a renewal of its own.
fn fold_leases(mut commands: Vec<Command>) -> Vec<Command> {
    let promised: Vec<u8> = commands
        .iter()
        .filter_map(|command| match command {
            Command::Lease {
                axis, keep: true, ..
            } => Some(*axis),
            _ => None,
        })
        .collect();
    let mut folded = Vec::new();
    for command in &mut commands {
        match command {
            Command::Move { axis, lease, .. }
            | Command::Halt {
                axis,
                lease,
                halt: false,
                ..
            } if promised.contains(axis) => {
                *lease = true;
                folded.push(*axis);
            }
            _ => {}
        }
    }
    commands.retain(
        |command| !matches!(command, Command::Lease { axis, keep: true, .. } if folded.contains(axis)),
    );
    commands
}

/// `Axis {n}/Lease Id` is presented by every other command of axis n in
/// the same DCMD (the last one given, if several); alone, it commands
/// nothing.
fn fold_lease_ids(commands: Vec<Command>) -> Vec<Command> {
    let mut ids = std::collections::BTreeMap::new();
    for command in &commands {
        if let Command::LeaseId { axis, id } = command {
            ids.insert(*axis, id.clone());
        }
    }
    let mut presented = std::collections::BTreeSet::new();
    let mut folded: Vec<Command> = commands
        .into_iter()
        .filter(|command| !matches!(command, Command::LeaseId { .. }))
        .map(|mut command| {
            match &mut command {
                Command::AxisState { axis, lease_id, .. }
                | Command::Halt { axis, lease_id, .. }
                | Command::Move { axis, lease_id, .. }
                | Command::Lease { axis, lease_id, .. } => {
                    if let Some(id) = ids.get(axis) {
                        *lease_id = Some(id.clone());
                        presented.insert(*axis);
                    }
                }
                _ => {}
            }
            command
        })
        .collect();
    for axis in ids.keys().filter(|axis| !presented.contains(*axis)) {
        folded.push(Command::Unsupported(format!(
            "Axis {axis}/Lease Id: no command of axis {axis} in the same DCMD presents it"
        )));
    }
    folded
}

/// `Axis {n}/{what}`.
fn axis_command(name: &str, value: MetricValue) -> Command {
    let unsupported = |why: &str| Command::Unsupported(format!("{name}: {why}"));
    let Some((axis, what)) = name["Axis ".len()..].split_once('/') else {
        return unsupported("no such metric");
    };
    let axis = match axis.parse::<u8>() {
        Ok(axis) if (1..=crate::profiles::umc::MAX_AXES).contains(&axis) => axis,
        _ => return unsupported("no such axis"),
    };
    match (what, value) {
        ("State", MetricValue::String(text)) => {
            match serde_json::from_value::<TargetState>(serde_json::Value::String(text.clone())) {
                Ok(target) => Command::AxisState {
                    axis,
                    target,
                    lease_id: None,
                },
                Err(_) => unsupported(&format!("no target state '{text}'")),
            }
        }
        ("Halt", MetricValue::Boolean(halt)) => Command::Halt {
            axis,
            halt,
            lease: false,
            lease_id: None,
        },
        ("Fault Reset", MetricValue::Boolean(true)) => Command::FaultReset { axis },
        ("Move", MetricValue::String(text)) => match serde_json::from_str::<MoveRequest>(&text) {
            Ok(request) => Command::Move {
                axis,
                request: Box::new(request),
                body: text,
                lease: false,
                lease_id: None,
            },
            Err(err) => unsupported(&format!("not a move: {err}")),
        },
        ("Lease", MetricValue::Boolean(keep)) => Command::Lease {
            axis,
            keep,
            lease_id: None,
        },
        ("Lease Id", MetricValue::String(id)) => Command::LeaseId { axis, id },
        _ => unsupported("no such metric, or not of its type"),
    }
}

/// `Segment {n}/{field}` of an LED controller, as an update of the
/// segment.
fn segment_command(name: &str, value: MetricValue) -> Command {
    let unsupported = |why: &str| Command::Unsupported(format!("{name}: {why}"));
    let Some((segment, what)) = name["Segment ".len()..].split_once('/') else {
        return unsupported("no such metric");
    };
    let segment = match segment.parse::<u8>() {
        Ok(n) if (1..=SEGMENTS).contains(&n) => n,
        _ => return unsupported("no such segment"),
    };
    let number = value
        .as_f64()
        .filter(|n| n.fract() == 0.0)
        .map(|n| n as i64);
    let mut update = SegmentUpdate::default();
    match (what, &value) {
        ("Effect", MetricValue::String(text)) => match effect_by_name(text) {
            Some(effect) => update.effect = Some(i64::from(effect.raw())),
            None => return unsupported(&format!("no effect '{text}'")),
        },
        (color, MetricValue::String(text)) if color.starts_with("Color ") => {
            let Ok(n @ 1..=3) = color["Color ".len()..].parse::<usize>() else {
                return unsupported("a segment has colours 1 to 3");
            };
            let Some(channels) = hex_color(text) else {
                return unsupported(&format!("'{text}' is not #rrggbb or #rrggbbww"));
            };
            update.colors[n - 1] = channels.map(Some);
        }
        (field, _) => {
            let given = match field {
                "Effect" => &mut update.effect,
                "Led Count" => &mut update.led_count,
                "Dimmer" => &mut update.dimmer,
                "Value" => &mut update.value,
                "Min Value" => &mut update.min_value,
                "Max Value" => &mut update.max_value,
                "Speed" => &mut update.speed,
                "Smooth" => &mut update.smooth,
                _ => return unsupported("no such field"),
            };
            match number {
                Some(number) => *given = Some(number),
                None => return unsupported("a whole number is wanted"),
            }
        }
    }
    Command::Segment { segment, update }
}

/// The most of a command message's words its audit row keeps.
pub const SUMMARY_CHARS: usize = 256;
/// The most of one metric's name or value the summary shows.
const PART_CHARS: usize = 64;
/// Room kept for the count of the metrics left out (`; … 49997 more`).
const TAIL_CHARS: usize = 16;

/// A command message's metrics as its one audit row summarises them (never
/// the whole payload): their count, then each one's name (or alias) and
/// value, in order, as many as fit in [`SUMMARY_CHARS`]: `3 metrics:
/// OD/0x1017:0=1000; NMT="start"; Axis 1/Halt=true`. A long name or value
/// is cut with its size said, the metrics left out are counted.
pub fn summary(metrics: &[Metric]) -> String {
    let count = metrics.len();
    let mut text = format!("{count} metric{}:", if count == 1 { "" } else { "s" });
    let mut length = text.chars().count();
    for (at, metric) in metrics.iter().enumerate() {
        let name = match (&metric.name, metric.alias) {
            (Some(name), _) => clip(name),
            (None, Some(alias)) => format!("alias {alias}"),
            (None, None) => "(no name)".to_string(),
        };
        let value = MetricValue::from_metric(metric).map_or_else(
            || "?".to_string(),
            |value| clip(&value.to_json().to_string()),
        );
        let part = format!("{} {name}={value}", if at == 0 { "" } else { ";" });
        let room = if at + 1 < count {
            SUMMARY_CHARS - TAIL_CHARS
        } else {
            SUMMARY_CHARS
        };
        let part_length = part.chars().count();
        if length + part_length > room {
            text.push_str(&format!(
                "{} … {} more",
                if at == 0 { "" } else { ";" },
                count - at
            ));
            break;
        }
        text.push_str(&part);
        length += part_length;
    }
    text
}

/// `text`, cut to [`PART_CHARS`] characters with its size said.
fn clip(text: &str) -> String {
    if text.chars().count() <= PART_CHARS {
        return text.to_string();
    }
    let head: String = text.chars().take(PART_CHARS).collect();
    format!("{head}… ({} bytes)", text.len())
}

/// What a segment command writes, as its audit entry's request says it:
/// `0x6231:1=10 0x6231:2=11`.
pub fn segment_request(segment: u8, update: &SegmentUpdate) -> String {
    update
        .fields()
        .into_iter()
        .filter_map(|(field, value)| {
            let (index, sub) = address(segment, field)?;
            Some(format!("0x{index:04X}:{sub}={value}"))
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// `#rrggbb` (white 0) or `#rrggbbww` as its four channels.
fn hex_color(text: &str) -> Option<[u8; 4]> {
    let hex = text.trim().strip_prefix('#')?;
    if !(hex.len() == 6 || hex.len() == 8) || !hex.is_ascii() {
        return None;
    }
    let mut channels = [0u8; 4];
    for (i, channel) in channels.iter_mut().enumerate().take(hex.len() / 2) {
        *channel = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(channels)
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
/// name may hold `-` itself. The node is in its canonical decimal form
/// only, as [`device_id`] writes it: `demo-01` or `demo-+1` is no device
/// (not node 1).
pub fn parse_device(device: &str) -> Option<(&str, u8)> {
    let (bus, node) = device.rsplit_once('-')?;
    let id: u8 = node.parse().ok()?;
    (!bus.is_empty() && (1..=127).contains(&id) && id.to_string() == node).then_some((bus, id))
}

/// The device ID of a node of a bus.
pub fn device_id(bus: &str, node: u8) -> String {
    format!("{bus}-{node}")
}
