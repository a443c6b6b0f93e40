//! The arguments of `candeck serve` (clap), and what each one accepts.

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::Args;

use crate::can::spec::BusSpec;
use crate::gateway::MAX_PERIOD_MS;
use crate::gateway::MAX_PUBLISH_HZ;

/// The bit rate of a bus when none is given: the most common CANopen rate,
/// used only to express the measured bits per second as a load.
pub const DEFAULT_BITRATE: u32 = 500_000;

pub(super) fn default_serve_listen() -> SocketAddr {
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

impl<'de> serde::Deserialize<'de> for NamedBus {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = String::deserialize(deserializer)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// A bus to share over socketcand: `ADDR` (every virtual bus) or
/// `NAME=ADDR` (that one).
#[derive(Debug, Clone)]
pub struct Share {
    pub bus: Option<String>,
    pub addr: SocketAddr,
}

impl std::str::FromStr for Share {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let (bus, addr) = match text.split_once('=') {
            Some((name, addr)) => (Some(name.to_string()), addr),
            None => (None, text),
        };
        let addr = addr
            .trim()
            .parse()
            .map_err(|_| format!("'{addr}' is no address like 127.0.0.1:29536"))?;
        Ok(Self { bus, addr })
    }
}

impl<'de> serde::Deserialize<'de> for Share {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let text = String::deserialize(deserializer)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Address the HTTP server listens on (port 0 picks a free port).
    /// Default: 127.0.0.1:8080.
    #[arg(long)]
    pub listen: Option<SocketAddr>,
    /// A bus to serve, as NAME=SPEC or SPEC (virtual:demo, virtual:empty,
    /// socketcan:can0, socketcand:HOST:PORT/CHANNEL,
    /// replay:FILE[?speed=N|max&loop]); repeat for more.
    /// Default: demo=virtual:demo, the demo devices on an emulated bus.
    #[arg(long = "bus", value_name = "NAME=SPEC")]
    pub buses: Vec<NamedBus>,
    /// A directory of EDS files, matched to nodes before the built-in ones.
    #[arg(long, value_name = "DIR")]
    pub eds_dir: Option<PathBuf>,
    /// The buses' bit rate in bit/s, which the load in GET /buses is a
    /// fraction of. Default: 500000.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub bitrate: Option<u32>,
    /// A TOML (or, named *.json, JSON) file of settings: listen, buses
    /// (a list of NAME=SPEC), eds_dir, data_dir, bitrate, share (a list),
    /// axis_poll_hz, retention_days, retention_rows, lease_ms,
    /// shutdown_grace_ms, ascii_listen, opcua_listen (and opcua_pki_dir,
    /// opcua_max_sessions, opcua_max_subscriptions, opcua_max_monitored_items,
    /// opcua_max_message_size, opcua_session_timeout_ms),
    /// sdo_samples_per_s (or opcua_sdo_samples_per_s),
    /// tokens (a list of {name, role, token}), cors_origins, write_rate,
    /// write_burst, body_limit, dcf_body_limit, sync_period_ms, insecure,
    /// recordings_quota_mb, logger_max_values, allowed_hosts, share_public, header_timeout_ms, idle_timeout_ms,
    /// max_connections, ascii_idle_timeout_ms, ascii_max_connections,
    /// ascii_unauthenticated_timeout_ms, eds_max_files, eds_max_mb,
    /// stream_max_per_token, stream_max_per_peer,
    /// share_max_connections (candeck.example.toml is an annotated example of every key).
    /// Options given on the command line override it; relative paths in it
    /// are relative to the file. Tokens also come from the environment:
    /// CANDECK_TOKENS="NAME:ROLE:TOKEN,..." (roles: viewer, operator, admin).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Where candeck keeps its data (created if missing): the virtual
    /// devices of bus NAME keep what they save (0x1010) under DIR/sim/NAME,
    /// across restarts, and bus recordings (POST /buses/{bus}/recording)
    /// are kept in DIR/recordings. Without it, saved values last until
    /// candeck stops and recordings go to a temporary directory removed then.
    /// The history (audit log, EMCY and NMT events) is DIR/history.sqlite3;
    /// without it, the history is kept in memory and lost on exit.
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// Share virtual buses over the socketcand protocol, so that other
    /// programs (candeck --bus socketcand:..., python-can, can-utils) join
    /// them: ADDR shares every virtual bus, NAME=ADDR bus NAME; the channel
    /// of a bus is its name. Repeat for more.
    #[arg(long, value_name = "[NAME=]ADDR")]
    pub share: Vec<Share>,
    /// The fastest an axis status is polled over SDO for the WebSocket
    /// stream, when the drive sends no TPDO with its statusword and
    /// position; readers that ask less get less. Default: 20.
    #[arg(long, value_name = "HZ", value_parser = parse_poll_hz)]
    pub axis_poll_hz: Option<f64>,
    /// How many days the history (audit log, EMCY, NMT events; GET
    /// /api/v1/events) keeps its entries; 0 keeps them whatever their age.
    /// Default: 90.
    #[arg(long, value_name = "DAYS")]
    pub retention_days: Option<u32>,
    /// How many entries of each kind (audit, emcy, nmt) the history keeps
    /// at most, the newest; 0: no limit. Default: 1000000.
    #[arg(long, value_name = "ROWS")]
    pub retention_rows: Option<u64>,
    /// How much the recordings kept in DIR/recordings (--data-dir) may take
    /// together, in MiB: beyond it the oldest are removed (checked every
    /// minute and at start; never a bus's running or last recording), each
    /// removal in the audit log; 0: no limit. Default: 1024.
    #[arg(long, value_name = "MIB")]
    pub recordings_quota_mb: Option<u64>,
    /// The values (rows × channels) one data logger (POST /api/v1/loggers)
    /// keeps in memory: beyond it its oldest rows go. 1000 to 100000000.
    /// Default: 1000000. With --data-dir, finished loggers are kept in
    /// DIR/loggers.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1000..=100_000_000))]
    pub logger_max_values: Option<u64>,
    /// The period of a motion lease, in milliseconds: a velocity, torque
    /// or duty-cycle move must be renewed by its client within it, or the
    /// gateway halts the axis (and quick-stops it one period later if it
    /// still moves). 200 to 60000. Default: 3000.
    #[arg(long, value_name = "MS", value_parser = parse_lease_ms)]
    pub lease_ms: Option<u64>,
    /// On SIGTERM or Ctrl-C the axes the gateway enabled are stopped first;
    /// then the HTTP connections still open get this long to finish their
    /// requests before they are closed, in milliseconds. 0 to 600000.
    /// Default: 5000.
    #[arg(long, value_name = "MS", value_parser = parse_shutdown_grace_ms)]
    pub shutdown_grace_ms: Option<u64>,
    /// Also serve the CiA 309-3 ASCII gateway protocol (CANopenNode's
    /// canopend/cocomm) over TCP on ADDR (port 0 picks a free port); net 1
    /// is the first bus given.
    #[arg(long, value_name = "ADDR")]
    pub ascii_listen: Option<SocketAddr>,
    /// Also serve OPC UA on ADDR (opc.tcp, port 0 picks a free port;
    /// 4840 is OPC UA's): the machine as an address space (docs/opcua.md).
    /// Anonymous sessions and the unsecured endpoint only on loopback; an
    /// address other than loopback needs tokens (user: the token's name,
    /// password: its secret). Default: off.
    #[arg(long, value_name = "ADDR")]
    pub opcua_listen: Option<SocketAddr>,
    /// Serve without tokens on an address other than loopback (--listen,
    /// --ascii-listen): anyone who reaches it may move the motors. Without
    /// tokens (config `tokens`, CANDECK_TOKENS) candeck refuses such an
    /// address unless told this.
    #[arg(long)]
    pub insecure: bool,
    /// An origin (scheme://host:port, exactly) whose web pages may call the
    /// API (CORS); repeat for more. Default: none, only the gateway's own
    /// pages.
    #[arg(long = "cors-origin", value_name = "ORIGIN")]
    pub cors_origins: Vec<String>,
    /// Writes per second one token may send (a token bucket; stop-all is
    /// never limited); 0 turns the limit off. Default: 10.
    #[arg(long, value_name = "PER_SECOND")]
    pub write_rate: Option<f64>,
    /// How many writes a token may send at once before its rate applies.
    /// Default: 40.
    #[arg(long, value_name = "N")]
    pub write_burst: Option<u32>,
    /// The largest request body in bytes (413 above). Default: 1048576.
    #[arg(long, value_name = "BYTES")]
    pub body_limit: Option<usize>,
    /// The largest DCF upload (PUT .../config.dcf) in bytes. Default:
    /// 4194304.
    #[arg(long, value_name = "BYTES")]
    pub dcf_body_limit: Option<usize>,
    /// The period in milliseconds of the gateway's SYNC producer (COB-ID
    /// 0x080) on every bus from the start, as PUT /api/v1/buses/{bus}/sync
    /// sets it later; 0: no SYNC. Default: 0.
    #[arg(long, value_name = "MS", value_parser = parse_sync_period_ms)]
    pub sync_period_ms: Option<u32>,
    /// A host name the gateway is served as, besides localhost and IP
    /// addresses; requests sent to another name (a DNS rebinding page) are
    /// refused with 421. Repeat for more; `*` allows any. Default: none.
    #[arg(long = "allowed-host", value_name = "NAME")]
    pub allowed_hosts: Vec<String>,
    /// Allow --share on an address other than loopback: the socketcand
    /// share is raw bus access (SDO, NMT, any frame) without tokens or
    /// audit, to anyone who reaches it.
    #[arg(long)]
    pub share_public: bool,
    /// How long an HTTP request's head may take from its first byte before
    /// the connection is closed, in milliseconds. Default: 10000.
    #[arg(long, value_name = "MS")]
    pub header_timeout_ms: Option<u64>,
    /// How long an HTTP connection may sit with nothing in flight before
    /// it is closed, in milliseconds. Default: 30000.
    #[arg(long, value_name = "MS")]
    pub idle_timeout_ms: Option<u64>,
    /// HTTP connections at once; the last 16 answer GET /api/v1/health and
    /// POST /api/v1/stop-all only. Default: 512.
    #[arg(long, value_name = "N")]
    pub max_connections: Option<usize>,
    /// How long a CiA 309-3 client (--ascii-listen) may send nothing
    /// before it is closed, in milliseconds. Default: 300000.
    #[arg(long, value_name = "MS")]
    pub ascii_idle_timeout_ms: Option<u64>,
    /// CiA 309-3 connections at once (--ascii-listen). Default: 32.
    #[arg(long, value_name = "N")]
    pub ascii_max_connections: Option<usize>,
    /// How long a CiA 309-3 client may go without a valid `auth` line (on
    /// a gateway without tokens: without a command) before it is closed,
    /// in milliseconds; when every place is taken, a new connection takes
    /// the place of the oldest such client. Default: 10000.
    #[arg(long, value_name = "MS")]
    pub ascii_unauthenticated_timeout_ms: Option<u64>,
    /// Uploaded EDS files (POST /api/v1/eds) the catalog takes at most;
    /// one more is refused (409 eds_quota). Default: 256.
    #[arg(long, value_name = "N")]
    pub eds_max_files: Option<usize>,
    /// How much the uploaded EDS files may take together, in MiB; an
    /// upload beyond is refused (409 eds_quota). Default: 64.
    #[arg(long, value_name = "MIB")]
    pub eds_max_mb: Option<u64>,
    /// WebSocket streams (GET /api/v1/stream) one token may hold at once;
    /// one more is answered 429 too_many_streams. Default: 32.
    #[arg(long, value_name = "N")]
    pub stream_max_per_token: Option<usize>,
    /// WebSocket streams one client address may hold at once (behind a
    /// reverse proxy every client has the proxy's address). Default: 64.
    #[arg(long, value_name = "N")]
    pub stream_max_per_peer: Option<usize>,
    /// socketcand clients at once, per --share address; one more is
    /// refused. Default: 32.
    #[arg(long, value_name = "N")]
    pub share_max_connections: Option<usize>,
}

/// A SYNC period in milliseconds: 0 (off) up to what 0x1006 holds.
pub(super) fn parse_sync_period_ms(text: &str) -> Result<u32, String> {
    let ms: u64 = text
        .trim()
        .parse()
        .map_err(|_| format!("'{text}' is no number of milliseconds"))?;
    check_sync_period_ms(ms)
}

pub(super) fn check_sync_period_ms(ms: u64) -> Result<u32, String> {
    u32::try_from(ms)
        .ok()
        .filter(|ms| *ms <= MAX_PERIOD_MS)
        .ok_or_else(|| {
            format!("{ms} ms: a SYNC period is at most {MAX_PERIOD_MS} ms (0x1006 in µs)")
        })
}

/// The longest shutdown grace period: 10 minutes.
pub(super) const MAX_SHUTDOWN_GRACE_MS: u64 = 600_000;
/// The default shutdown grace period.
pub(super) const DEFAULT_SHUTDOWN_GRACE_MS: u64 = 5_000;

/// A shutdown grace period in milliseconds.
pub(super) fn parse_shutdown_grace_ms(text: &str) -> Result<u64, String> {
    let ms: u64 = text
        .parse()
        .map_err(|_| format!("'{text}': a shutdown grace period is a number of milliseconds"))?;
    check_shutdown_grace_ms(ms)
}

pub(super) fn check_shutdown_grace_ms(ms: u64) -> Result<u64, String> {
    if ms <= MAX_SHUTDOWN_GRACE_MS {
        Ok(ms)
    } else {
        Err(format!(
            "{ms} ms: a shutdown grace period is 0 to {MAX_SHUTDOWN_GRACE_MS} ms"
        ))
    }
}

/// A lease period in milliseconds, within the gateway's bounds.
pub(super) fn parse_lease_ms(text: &str) -> Result<u64, String> {
    let ms: u64 = text
        .trim()
        .parse()
        .map_err(|_| format!("'{text}' is no number of milliseconds"))?;
    check_lease_ms(ms)
}

pub(super) fn check_lease_ms(ms: u64) -> Result<u64, String> {
    let (min, max) = (
        crate::gateway::MIN_PERIOD.as_millis(),
        crate::gateway::MAX_PERIOD.as_millis(),
    );
    if (min..=max).contains(&u128::from(ms)) {
        Ok(ms)
    } else {
        Err(format!("{ms} ms: a lease period is {min} to {max} ms"))
    }
}

/// The environment variable of tokens: `NAME:ROLE:TOKEN,...`.
pub const TOKENS_ENV: &str = "CANDECK_TOKENS";

/// A polling rate: a positive number of hertz, at most what a producer
/// publishes ([`MAX_PUBLISH_HZ`]).
pub(super) fn parse_poll_hz(text: &str) -> Result<f64, String> {
    let hz: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("'{text}' is no number of hertz"))?;
    check_poll_hz(hz)
}

pub(super) fn check_poll_hz(hz: f64) -> Result<f64, String> {
    if hz.is_finite() && hz > 0.0 && hz <= MAX_PUBLISH_HZ {
        Ok(hz)
    } else {
        Err(format!(
            "{hz} Hz: a polling rate is more than 0 and at most {MAX_PUBLISH_HZ}"
        ))
    }
}

impl ServeArgs {
    /// What clap cannot check one argument at a time: two buses of one name.
    pub fn validate(&self) -> Result<(), String> {
        unique_names(&self.buses, "--bus")
    }
}

pub(super) fn unique_names(buses: &[NamedBus], source: &str) -> Result<(), String> {
    let mut seen = std::collections::BTreeSet::new();
    for bus in buses {
        if !seen.insert(bus.name.as_str()) {
            return Err(format!(
                "invalid value for '{source}': two buses are named '{}'; name them NAME=SPEC",
                bus.name
            ));
        }
    }
    Ok(())
}
