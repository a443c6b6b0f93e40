//! Bus specs, as the command line and the configuration write them
//! (`docs/cli.md`, "Bus specs"), and opening a bus from one.
//!
//! | spec | bus |
//! |---|---|
//! | `virtual:empty[?bitrate=N\|unlimited]` | a new in-process bus with no devices |
//! | `virtual:demo[?bitrate=N\|unlimited]` | a new in-process bus with the demo devices |
//! | `virtual:DEVICES[?bitrate=…]` | a new in-process bus with a device list, `umc1bds32@1,uio1led@lss`; a UMC's load as in `--devices`, `umc1bds32@1?inertia=0.001&friction=0.0002` (then `&bitrate=…`) |
//! | `socketcan:can0` | a Linux SocketCAN interface |
//! | `socketcand:HOST:PORT/CHANNEL` | a channel of a socketcand server (HOST may be `[v6]`) |
//! | `replay:FILE[?speed=N\|max&loop&iface=can0]` | a candump `-L` log played back |

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

use super::bus::Bus;
use super::hub::VirtualHub;
use super::socketcand::{ClientConfig, open_socketcand};
use super::timing::Bitrate;

/// A parsed bus spec.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BusSpec {
    /// An in-process emulated bus with a device preset (`demo`, `empty`)
    /// and its bit rate when the spec gives one (`?bitrate=125k`); without
    /// it, the bit rate of whoever opens it (500 kbit/s unless told).
    Virtual {
        preset: String,
        bitrate: Option<Bitrate>,
    },
    Socketcan {
        interface: String,
    },
    Socketcand {
        host: String,
        port: u16,
        channel: String,
    },
    /// A candump log; `options` is the text after `?`, if any.
    Replay {
        path: PathBuf,
        options: Option<String>,
    },
}

/// A spec that cannot be read, or a bus that cannot be opened.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SpecError {
    #[error(
        "bus spec '{0}' is not one of virtual:demo, virtual:empty, socketcan:IFACE, socketcand:HOST:PORT/CHANNEL, replay:FILE"
    )]
    UnknownKind(String),
    #[error("bus spec '{spec}': {problem}")]
    Invalid { spec: String, problem: String },
    #[error("cannot open bus '{spec}': {problem}")]
    Open { spec: String, problem: String },
}

impl SpecError {
    fn invalid(spec: &str, problem: impl Into<String>) -> Self {
        Self::Invalid {
            spec: spec.to_string(),
            problem: problem.into(),
        }
    }
}

impl FromStr for BusSpec {
    type Err = SpecError;

    fn from_str(spec: &str) -> Result<Self, SpecError> {
        let (kind, rest) = spec
            .split_once(':')
            .ok_or_else(|| SpecError::UnknownKind(spec.to_string()))?;
        match kind {
            "virtual" => parse_virtual(spec, rest),
            "socketcan" => {
                // Linux interface names: at most 15 bytes, no '/' or space.
                if rest.is_empty() || rest.len() > 15 || rest.contains(['/', ' ', ':']) {
                    return Err(SpecError::invalid(
                        spec,
                        "expected a network interface name such as can0",
                    ));
                }
                Ok(Self::Socketcan {
                    interface: rest.to_string(),
                })
            }
            "socketcand" => parse_socketcand(spec, rest),
            "replay" => {
                let (path, options) = match rest.split_once('?') {
                    Some((path, options)) => (path, Some(options.to_string())),
                    None => (rest, None),
                };
                if path.is_empty() {
                    return Err(SpecError::invalid(spec, "expected replay:FILE"));
                }
                Ok(Self::Replay {
                    path: PathBuf::from(path),
                    options,
                })
            }
            _ => Err(SpecError::UnknownKind(spec.to_string())),
        }
    }
}

/// `virtual:PRESET[?bitrate=…]`: `demo`, `empty` or a device list, whose
/// devices may each carry their load (`umc1bds32@1?inertia=0.001&friction=0.0002`);
/// the bus's `bitrate` comes after the last device (`…&bitrate=125k`, or
/// `?bitrate=125k` after a device without options).
fn parse_virtual(spec: &str, rest: &str) -> Result<BusSpec, SpecError> {
    let items: Vec<&str> = rest.split(',').collect();
    let mut bitrate = None;
    let mut devices = Vec::with_capacity(items.len());
    let mut bare = Vec::with_capacity(items.len());
    for (position, item) in items.iter().enumerate() {
        let (device, options) = match item.split_once('?') {
            Some((device, options)) => (device, Some(options)),
            None => (*item, None),
        };
        let last = position + 1 == items.len();
        let mut kept = Vec::new();
        for option in options.into_iter().flat_map(|options| options.split('&')) {
            match option.split_once('=') {
                Some(("bitrate", value)) if last && bitrate.is_none() => {
                    bitrate = Some(
                        value
                            .parse::<Bitrate>()
                            .map_err(|err| SpecError::invalid(spec, err.to_string()))?,
                    );
                }
                Some(("bitrate", _)) => {
                    return Err(SpecError::invalid(
                        spec,
                        "bitrate is the bus's option, given once after the last device",
                    ));
                }
                // The emulator, which knows the products, checks the range.
                Some((key @ ("inertia" | "friction"), value)) if device.contains('@') => {
                    if !value.trim().parse::<f64>().is_ok_and(f64::is_finite) {
                        return Err(SpecError::invalid(
                            spec,
                            format!("{key} '{value}' of {device} is not a number"),
                        ));
                    }
                    kept.push(option);
                }
                _ => {
                    return Err(SpecError::invalid(
                        spec,
                        format!(
                            "'{option}': a virtual bus takes ?bitrate=N|unlimited, and each \
                             device of a list ?inertia=KGM2&friction=NMS"
                        ),
                    ));
                }
            }
        }
        bare.push(device);
        devices.push(if kept.is_empty() {
            device.to_string()
        } else {
            format!("{device}?{}", kept.join("&"))
        });
    }
    // A device list is read by the emulator, which knows the products;
    // here only its shape.
    let bare = bare.join(",");
    let device_list = bare.contains('@')
        && bare
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '@' | ',' | '/'));
    if !matches!(bare.as_str(), "demo" | "empty") && !device_list {
        return Err(SpecError::invalid(
            spec,
            "a virtual bus is 'virtual:demo', 'virtual:empty' or a device list \
             such as 'virtual:umc1bds32@1,uio1led@lss'",
        ));
    }
    Ok(BusSpec::Virtual {
        preset: devices.join(","),
        bitrate,
    })
}

fn parse_socketcand(spec: &str, rest: &str) -> Result<BusSpec, SpecError> {
    let usage =
        "expected socketcand:HOST:PORT/CHANNEL, for example socketcand:127.0.0.1:29536/can0";
    let (address, channel) = rest
        .rsplit_once('/')
        .ok_or_else(|| SpecError::invalid(spec, usage))?;
    if channel.is_empty() || channel.len() > 16 || channel.contains([' ', '<', '>']) {
        return Err(SpecError::invalid(
            spec,
            "the channel is a bus name of at most 16 characters, such as can0",
        ));
    }
    let (host, port) = if let Some(v6) = address.strip_prefix('[') {
        let (host, port) = v6
            .split_once("]:")
            .ok_or_else(|| SpecError::invalid(spec, usage))?;
        (host, port)
    } else {
        address
            .rsplit_once(':')
            .ok_or_else(|| SpecError::invalid(spec, usage))?
    };
    if host.is_empty() {
        return Err(SpecError::invalid(spec, usage));
    }
    let port: u16 = port
        .parse()
        .ok()
        .filter(|&p| p != 0)
        .ok_or_else(|| SpecError::invalid(spec, format!("port '{port}' is not 1 to 65535")))?;
    Ok(BusSpec::Socketcand {
        host: host.to_string(),
        port,
        channel: channel.to_string(),
    })
}

impl fmt::Display for BusSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Virtual {
                preset,
                bitrate: None,
            } => write!(f, "virtual:{preset}"),
            Self::Virtual {
                preset,
                bitrate: Some(bitrate),
            } => {
                // After the last device's own options, if it has some.
                let joint = match preset.rsplit(',').next() {
                    Some(last) if last.contains('?') => '&',
                    _ => '?',
                };
                write!(f, "virtual:{preset}{joint}bitrate={bitrate}")
            }
            Self::Socketcan { interface } => write!(f, "socketcan:{interface}"),
            Self::Socketcand {
                host,
                port,
                channel,
            } if host.contains(':') => write!(f, "socketcand:[{host}]:{port}/{channel}"),
            Self::Socketcand {
                host,
                port,
                channel,
            } => write!(f, "socketcand:{host}:{port}/{channel}"),
            Self::Replay { path, options } => {
                write!(f, "replay:{}", path.display())?;
                match options {
                    Some(options) => write!(f, "?{options}"),
                    None => Ok(()),
                }
            }
        }
    }
}

impl BusSpec {
    /// The bus name used when none is given: `demo` for `virtual:demo`,
    /// otherwise the channel, interface or log name.
    pub fn default_name(&self) -> String {
        match self {
            Self::Virtual { preset, .. } if preset.contains('@') => "virtual".to_string(),
            Self::Virtual { preset, .. } => preset.clone(),
            Self::Socketcan { interface } => interface.clone(),
            Self::Socketcand { channel, .. } => channel.clone(),
            Self::Replay { path, .. } => path
                .file_stem()
                .map(|stem| stem.to_string_lossy().into_owned())
                .unwrap_or_else(|| "replay".to_string()),
        }
    }

    /// Opens the bus. A socketcand bus is returned at once and connects in
    /// the background (see [`Bus::wait_up`]); the others fail here if they
    /// cannot be opened. A virtual bus comes with its hub, for the devices
    /// that will live on it.
    pub async fn open(&self, name: &str) -> Result<OpenedBus, SpecError> {
        self.open_with_bitrate(name, Bitrate::default()).await
    }

    /// [`BusSpec::open`], a virtual bus at `bitrate` unless its spec says.
    pub async fn open_with_bitrate(
        &self,
        name: &str,
        bitrate: Bitrate,
    ) -> Result<OpenedBus, SpecError> {
        match self {
            // The devices of `virtual:demo` live above this layer: whoever
            // opened the bus puts them on the hub it gets back.
            Self::Virtual {
                bitrate: spec_bitrate,
                ..
            } => {
                let hub = VirtualHub::with_bitrate(name, spec_bitrate.unwrap_or(bitrate));
                Ok(OpenedBus {
                    bus: hub.attach(),
                    hub: Some(hub),
                })
            }
            Self::Socketcand {
                host,
                port,
                channel,
            } => Ok(OpenedBus {
                bus: open_socketcand(
                    name,
                    ClientConfig::new(host.clone(), *port, channel.clone()),
                ),
                hub: None,
            }),
            Self::Socketcan { interface } => open_socketcan_bus(self, name, interface).await,
            Self::Replay { path, options } => {
                open_replay_bus(self, name, path, options.as_deref()).await
            }
        }
    }
}

/// A bus just opened, with its hub when it is virtual.
#[derive(Debug)]
pub struct OpenedBus {
    pub bus: Bus,
    pub hub: Option<VirtualHub>,
}

#[cfg(feature = "socketcan")]
async fn open_socketcan_bus(
    spec: &BusSpec,
    name: &str,
    interface: &str,
) -> Result<OpenedBus, SpecError> {
    let _ = name;
    super::socketcan::open_socketcan(interface)
        .await
        .map(|bus| OpenedBus { bus, hub: None })
        .map_err(|err| SpecError::Open {
            spec: spec.to_string(),
            problem: err.to_string(),
        })
}

#[cfg(not(feature = "socketcan"))]
async fn open_socketcan_bus(
    spec: &BusSpec,
    _name: &str,
    _interface: &str,
) -> Result<OpenedBus, SpecError> {
    Err(SpecError::Open {
        spec: spec.to_string(),
        problem: "this candeck was built without SocketCAN support; rebuild with `cargo build --features socketcan`".into(),
    })
}

async fn open_replay_bus(
    spec: &BusSpec,
    _name: &str,
    path: &std::path::Path,
    options: Option<&str>,
) -> Result<OpenedBus, SpecError> {
    let open_error = |problem: String| SpecError::Open {
        spec: spec.to_string(),
        problem,
    };
    let options = match options {
        Some(query) => super::candump::ReplayOptions::parse_query(query).map_err(open_error)?,
        None => super::candump::ReplayOptions::default(),
    };
    super::candump::open_replay(path, options)
        .await
        .map(|bus| OpenedBus { bus, hub: None })
        .map_err(|err| open_error(err.to_string()))
}

#[cfg(test)]
mod tests;
