//! `candeck od read|write`: one object of one node over SDO, on any bus.

use std::path::PathBuf;
use std::time::Duration;

use clap::{Args, Subcommand};

use super::{CliError, CommandBus, open_bus};
use crate::can::spec::BusSpec;
use crate::canopen::NodeId;
use crate::canopen::eds::read_eds_file;
use crate::canopen::od::{DataType, Value, parse_index};
use crate::canopen::sdo::ClientConfig;
use crate::gateway::SdoChannel;

#[derive(Debug, Args)]
pub struct OdArgs {
    #[command(subcommand)]
    pub action: OdAction,
}

#[derive(Debug, Subcommand)]
pub enum OdAction {
    /// Read an object and print its value.
    Read(ReadArgs),
    /// Write a value to an object.
    Write(WriteArgs),
}

/// Where the object is and how to reach it.
#[derive(Debug, Args)]
pub struct Target {
    /// The bus: socketcand:HOST:PORT/CHANNEL, socketcan:IFACE, virtual:empty.
    #[arg(long, value_name = "SPEC")]
    pub bus: BusSpec,
    /// The node id, 1 to 127.
    #[arg(long, value_name = "ID")]
    pub node: NodeId,
    /// The node's EDS or DCF: gives types, and lets INDEX and SUB be names.
    #[arg(long, value_name = "FILE")]
    pub eds: Option<PathBuf>,
    /// The value's type (u8, i16, u32, i64, r32, vs, os, ...); overrides the EDS.
    #[arg(long = "type", value_name = "T")]
    pub data_type: Option<DataType>,
    /// How long the node may take for each answer, in milliseconds.
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    pub timeout: u64,
    /// Print the result as JSON (`{"index","sub","data_type","value","raw"}`).
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ReadArgs {
    #[command(flatten)]
    pub target: Target,
    /// 0x6041, 6041h, 24641, or a name from the EDS.
    pub index: String,
    /// 0 to 255, or a sub-object name from the EDS.
    pub sub: String,
}

#[derive(Debug, Args)]
pub struct WriteArgs {
    #[command(flatten)]
    pub target: Target,
    /// 0x6041, 6041h, 24641, or a name from the EDS.
    pub index: String,
    /// 0 to 255, or a sub-object name from the EDS.
    pub sub: String,
    /// The value, as the type reads it: 42, -7, 0x1F, 1.5, text, hex bytes for os.
    #[arg(allow_hyphen_values = true)]
    pub value: String,
}

/// An object address resolved to numbers, with its type when known.
struct Resolved {
    index: u16,
    sub: u8,
    data_type: Option<DataType>,
}

fn resolve(target: &Target, index: &str, sub: &str) -> Result<Resolved, CliError> {
    let resolved = match &target.eds {
        Some(path) => {
            let dictionary = read_eds_file(path).map_err(CliError::new)?.dictionary;
            let object = dictionary.resolve_index(index).map_err(CliError::new)?;
            let sub = object.resolve_sub(sub).map_err(CliError::new)?;
            Resolved {
                index: object.index,
                sub: sub.sub_index,
                data_type: Some(sub.data_type),
            }
        }
        None => Resolved {
            index: parse_index(index).ok_or_else(|| {
                CliError::new(format!(
                    "index '{index}' is not a number (0x6041, 6041h, 24641); names need --eds"
                ))
            })?,
            sub: sub.parse().map_err(|_| {
                CliError::new(format!(
                    "sub-index '{sub}' is not 0 to 255; names need --eds"
                ))
            })?,
            data_type: None,
        },
    };
    Ok(Resolved {
        data_type: target.data_type.or(resolved.data_type),
        ..resolved
    })
}

/// The bus (with the demo devices of `virtual:demo`, kept running while
/// it is held) and the node's SDO channel.
async fn connect(target: &Target) -> Result<(CommandBus, SdoChannel), CliError> {
    let opened = open_bus(&target.bus).await?;
    let bus = opened.bus.clone();
    bus.wait_up(Duration::from_secs(5))
        .await
        .map_err(CliError::new)?;
    let config = ClientConfig {
        timeout: Duration::from_millis(target.timeout.max(1)),
        ..ClientConfig::default()
    };
    let channel = SdoChannel::new(bus, target.node, config);
    Ok((opened, channel))
}

pub async fn run(args: OdArgs) -> Result<(), CliError> {
    match args.action {
        OdAction::Read(args) => read(args).await,
        OdAction::Write(args) => write(args).await,
    }
}

async fn read(args: ReadArgs) -> Result<(), CliError> {
    let object = resolve(&args.target, &args.index, &args.sub)?;
    let (bus, channel) = connect(&args.target).await?;
    let result = channel.upload(object.index, object.sub).await;
    bus.bus.close().await;
    let raw = result.map_err(CliError::new)?;
    let value = match object.data_type {
        Some(data_type) => Some(Value::from_bytes(data_type, &raw).map_err(|err| {
            CliError::new(format!(
                "0x{:04X} sub {}: the node sent {} bytes ({}) that are no {data_type}: {err}",
                object.index,
                object.sub,
                raw.len(),
                hex(&raw)
            ))
        })?),
        None => None,
    };
    if args.target.json {
        let json = serde_json::json!({
            "index": format!("0x{:04X}", object.index),
            "sub": object.sub,
            "data_type": object.data_type.and_then(DataType::short_name),
            "value": value.as_ref().map(Value::to_json),
            "raw": hex(&raw),
        });
        println!("{json}");
    } else {
        match value {
            Some(value) => println!("{}", plain(&value)),
            None => println!("{}", untyped(&raw)),
        }
    }
    Ok(())
}

async fn write(args: WriteArgs) -> Result<(), CliError> {
    let object = resolve(&args.target, &args.index, &args.sub)?;
    let data_type = object.data_type.ok_or_else(|| {
        CliError::new(
            "the value's type is unknown: give --type (u8, i16, u32, r32, vs, ...) or --eds",
        )
    })?;
    let value = Value::parse_text(data_type, &args.value, Some(args.target.node))
        .map_err(|err| CliError::new(format!("value '{}': {err}", args.value)))?;
    let (bus, channel) = connect(&args.target).await?;
    let result = channel
        .download(object.index, object.sub, &value.to_bytes())
        .await;
    bus.bus.close().await;
    result.map_err(CliError::new)?;
    if args.target.json {
        let json = serde_json::json!({
            "index": format!("0x{:04X}", object.index),
            "sub": object.sub,
            "data_type": data_type.short_name(),
            "value": value.to_json(),
            "raw": hex(&value.to_bytes()),
        });
        println!("{json}");
    }
    Ok(())
}

/// A value as a person reads it: strings without quotes.
fn plain(value: &Value) -> String {
    match value {
        Value::VisibleString(text) | Value::UnicodeString(text) => text.clone(),
        other => other.to_text(),
    }
}

/// Bytes of unknown type: hex, and what they most likely are.
fn untyped(raw: &[u8]) -> String {
    let hex = hex(raw);
    match raw.len() {
        0 => "(no data)".to_string(),
        1 | 2 | 4 | 8 => {
            let mut bytes = [0u8; 8];
            bytes[..raw.len()].copy_from_slice(raw);
            format!(
                "{} (0x{hex}; unsigned little-endian, give --type for another reading)",
                u64::from_le_bytes(bytes)
            )
        }
        _ if raw.iter().all(|b| b.is_ascii_graphic() || *b == b' ') => {
            format!("{} (as text; raw {hex})", String::from_utf8_lossy(raw))
        }
        _ => hex,
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn untyped_values_show_hex_and_a_reading() {
        assert_eq!(
            untyped(&[0x92, 0x01, 0, 0]),
            "402 (0x92010000; unsigned little-endian, give --type for another reading)"
        );
        assert_eq!(
            untyped(b"UMC1BDS32"),
            "UMC1BDS32 (as text; raw 554D43314244533332)"
        );
        assert_eq!(untyped(&[1, 2, 3]), "010203");
        assert_eq!(untyped(&[]), "(no data)");
    }
}
