//! `candeck serve`: the gateway, its REST interface over HTTP
//! (`../shared/API.md`, "Command line" and "REST").

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use clap::Args;

use super::{CliError, shutdown_signal};
use crate::api::auth::{AuthConfig, DEFAULT_BODY_LIMIT, DEFAULT_DCF_BODY_LIMIT, RateLimit, Token};
use crate::api::{AppState, ServedBus};
use crate::can::VirtualHub;
use crate::can::socketcand::{ServerConfig, SocketcandServer};
use crate::can::spec::BusSpec;
use crate::gateway::history::{DEFAULT_RETENTION_DAYS, DEFAULT_RETENTION_ROWS, History, Retention};
use crate::gateway::producers::{DEFAULT_AXIS_POLL_HZ, MAX_PUBLISH_HZ, TelemetryConfig};
use crate::gateway::profile::EdsCatalog;
use crate::gateway::registry::RegistryConfig;
use crate::gateway::sync::MAX_PERIOD_MS;

/// How long the first scan of a bus waits for the bus to come up.
const FIRST_SCAN_WAIT: std::time::Duration = std::time::Duration::from_secs(30);

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
    /// axis_poll_hz, retention_days, retention_rows, lease_ms, ascii_listen,
    /// tokens (a list of {name, role, token}), cors_origins, write_rate,
    /// write_burst, body_limit, dcf_body_limit, sync_period_ms, insecure
    /// (candeck.example.toml is an annotated example of every key).
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
    /// The period of a motion lease, in milliseconds: a velocity, torque
    /// or duty-cycle move must be renewed by its client within it, or the
    /// gateway halts the axis (and quick-stops it one period later if it
    /// still moves). 200 to 60000. Default: 3000.
    #[arg(long, value_name = "MS", value_parser = parse_lease_ms)]
    pub lease_ms: Option<u64>,
    /// Also serve the CiA 309-3 ASCII gateway protocol (CANopenNode's
    /// canopend/cocomm) over TCP on ADDR (port 0 picks a free port); net 1
    /// is the first bus given.
    #[arg(long, value_name = "ADDR")]
    pub ascii_listen: Option<SocketAddr>,
    /// Serve without tokens on an address other than loopback: anyone who
    /// reaches it may move the motors. Without tokens (config `tokens`,
    /// CANDECK_TOKENS) candeck refuses such an address unless told this.
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
}

/// A SYNC period in milliseconds: 0 (off) up to what 0x1006 holds.
fn parse_sync_period_ms(text: &str) -> Result<u32, String> {
    let ms: u64 = text
        .trim()
        .parse()
        .map_err(|_| format!("'{text}' is no number of milliseconds"))?;
    check_sync_period_ms(ms)
}

fn check_sync_period_ms(ms: u64) -> Result<u32, String> {
    u32::try_from(ms)
        .ok()
        .filter(|ms| *ms <= MAX_PERIOD_MS)
        .ok_or_else(|| {
            format!("{ms} ms: a SYNC period is at most {MAX_PERIOD_MS} ms (0x1006 in µs)")
        })
}

/// A lease period in milliseconds, within the gateway's bounds.
fn parse_lease_ms(text: &str) -> Result<u64, String> {
    let ms: u64 = text
        .trim()
        .parse()
        .map_err(|_| format!("'{text}' is no number of milliseconds"))?;
    check_lease_ms(ms)
}

fn check_lease_ms(ms: u64) -> Result<u64, String> {
    let (min, max) = (
        crate::gateway::motion_lease::MIN_PERIOD.as_millis(),
        crate::gateway::motion_lease::MAX_PERIOD.as_millis(),
    );
    if (min..=max).contains(&u128::from(ms)) {
        Ok(ms)
    } else {
        Err(format!("{ms} ms: a lease period is {min} to {max} ms"))
    }
}

/// The environment variable of tokens: `NAME:ROLE:TOKEN,...`.
pub const TOKENS_ENV: &str = "CANDECK_TOKENS";

/// One token of the config file.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct TokenEntry {
    name: String,
    role: String,
    token: String,
}

/// A polling rate: a positive number of hertz, at most what a producer
/// publishes ([`MAX_PUBLISH_HZ`]).
fn parse_poll_hz(text: &str) -> Result<f64, String> {
    let hz: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("'{text}' is no number of hertz"))?;
    check_poll_hz(hz)
}

fn check_poll_hz(hz: f64) -> Result<f64, String> {
    if hz.is_finite() && hz > 0.0 && hz <= MAX_PUBLISH_HZ {
        Ok(hz)
    } else {
        Err(format!(
            "{hz} Hz: a polling rate is more than 0 and at most {MAX_PUBLISH_HZ}"
        ))
    }
}

/// The settings of a config file (`--config`).
#[derive(Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ConfigFile {
    listen: Option<SocketAddr>,
    #[serde(default)]
    buses: Vec<NamedBus>,
    eds_dir: Option<PathBuf>,
    data_dir: Option<PathBuf>,
    bitrate: Option<u32>,
    #[serde(default)]
    share: Vec<Share>,
    axis_poll_hz: Option<f64>,
    retention_days: Option<u32>,
    retention_rows: Option<u64>,
    lease_ms: Option<u64>,
    ascii_listen: Option<SocketAddr>,
    #[serde(default)]
    tokens: Vec<TokenEntry>,
    #[serde(default)]
    cors_origins: Vec<String>,
    write_rate: Option<f64>,
    write_burst: Option<u32>,
    body_limit: Option<usize>,
    dcf_body_limit: Option<usize>,
    sync_period_ms: Option<u32>,
    insecure: Option<bool>,
}

impl ConfigFile {
    /// Reads `path`: JSON when named `*.json`, TOML otherwise. The error
    /// names the file and the line.
    fn read(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|err| format!("config {}: {err}", path.display()))?;
        let is_json = path
            .extension()
            .is_some_and(|ext| ext.eq_ignore_ascii_case("json"));
        let mut config: Self = if is_json {
            serde_json::from_str(&text)
                .map_err(|err| format!("config {}: {err}", path.display()))?
        } else {
            toml::from_str(&text).map_err(|err| {
                // toml's message is several lines (the line quoted, a
                // caret); one line for the terminal: where, then what.
                let message = err.message();
                match err.span().map(|span| line_column(&text, span.start)) {
                    Some((line, column)) => format!(
                        "config {}: line {line}, column {column}: {message}",
                        path.display()
                    ),
                    None => format!("config {}: {message}", path.display()),
                }
            })?
        };
        if let Some(hz) = config.axis_poll_hz {
            check_poll_hz(hz)
                .map_err(|err| format!("config {}: axis_poll_hz {err}", path.display()))?;
        }
        if let Some(ms) = config.lease_ms {
            check_lease_ms(ms)
                .map_err(|err| format!("config {}: lease_ms {err}", path.display()))?;
        }
        if let Some(ms) = config.sync_period_ms {
            check_sync_period_ms(u64::from(ms))
                .map_err(|err| format!("config {}: sync_period_ms {err}", path.display()))?;
        }
        if config.bitrate == Some(0) {
            return Err(format!(
                "config {}: bitrate 0: a bit rate is at least 1",
                path.display()
            ));
        }
        // Relative paths are the file's: the same wherever candeck starts.
        let base = path.parent().unwrap_or(Path::new(""));
        for dir in [&mut config.eds_dir, &mut config.data_dir]
            .into_iter()
            .flatten()
        {
            if dir.is_relative() {
                *dir = base.join(&*dir);
            }
        }
        Ok(config)
    }
}

/// The 1-based line and column of byte `offset` of `text`.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.len() - before.rfind('\n').map_or(0, |at| at + 1) + 1;
    (line, column)
}

/// What `candeck serve` runs with: the command line over the config file
/// over the defaults.
#[derive(Debug)]
struct Settings {
    listen: SocketAddr,
    buses: Vec<NamedBus>,
    eds_dir: Option<PathBuf>,
    data_dir: Option<PathBuf>,
    bitrate: u32,
    share: Vec<Share>,
    axis_poll_hz: f64,
    retention: Retention,
    lease_period: std::time::Duration,
    ascii_listen: Option<SocketAddr>,
    auth: AuthConfig,
    insecure: bool,
    sync_period: std::time::Duration,
}

impl ServeArgs {
    /// The settings: each option from the command line, else from the
    /// config file, else its default (the demo bus when no bus is given);
    /// tokens from the file and [`TOKENS_ENV`].
    fn settings(&self) -> Result<Settings, String> {
        self.settings_with(std::env::var(TOKENS_ENV).ok().as_deref())
    }

    /// [`ServeArgs::settings`] with `tokens_env` as the environment's tokens.
    fn settings_with(&self, tokens_env: Option<&str>) -> Result<Settings, String> {
        let file = match &self.config {
            Some(path) => ConfigFile::read(path)?,
            None => ConfigFile::default(),
        };
        let pick = |flag: &Vec<NamedBus>, file: Vec<NamedBus>| {
            if flag.is_empty() { file } else { flag.clone() }
        };
        let mut buses = pick(&self.buses, file.buses);
        if buses.is_empty() {
            buses.push(NamedBus {
                name: "demo".to_string(),
                spec: BusSpec::Virtual {
                    preset: "demo".to_string(),
                    bitrate: None,
                },
            });
        }
        let settings = Settings {
            ascii_listen: self.ascii_listen.or(file.ascii_listen),
            listen: self
                .listen
                .or(file.listen)
                .unwrap_or_else(default_serve_listen),
            buses,
            eds_dir: self.eds_dir.clone().or(file.eds_dir),
            data_dir: self.data_dir.clone().or(file.data_dir),
            bitrate: self.bitrate.or(file.bitrate).unwrap_or(DEFAULT_BITRATE),
            share: if self.share.is_empty() {
                file.share
            } else {
                self.share.clone()
            },
            axis_poll_hz: self
                .axis_poll_hz
                .or(file.axis_poll_hz)
                .unwrap_or(DEFAULT_AXIS_POLL_HZ),
            lease_period: std::time::Duration::from_millis(
                self.lease_ms
                    .or(file.lease_ms)
                    .unwrap_or(crate::gateway::motion_lease::DEFAULT_PERIOD.as_millis() as u64),
            ),
            // 0 lifts a limit.
            retention: Retention {
                days: Some(
                    self.retention_days
                        .or(file.retention_days)
                        .unwrap_or(DEFAULT_RETENTION_DAYS),
                )
                .filter(|days| *days > 0),
                rows: Some(
                    self.retention_rows
                        .or(file.retention_rows)
                        .unwrap_or(DEFAULT_RETENTION_ROWS),
                )
                .filter(|rows| *rows > 0),
            },
            auth: self.auth_config(
                file.tokens,
                file.cors_origins,
                (file.write_rate, file.write_burst),
                (file.body_limit, file.dcf_body_limit),
                tokens_env,
            )?,
            // A flag can only say yes: the file's `insecure = true` stands
            // unless the flag is given too.
            insecure: self.insecure || file.insecure.unwrap_or(false),
            sync_period: std::time::Duration::from_millis(u64::from(
                self.sync_period_ms.or(file.sync_period_ms).unwrap_or(0),
            )),
        };
        settings.validate()?;
        Ok(settings)
    }

    /// Tokens from the file and the environment, the rest from the command
    /// line over the file over the defaults.
    fn auth_config(
        &self,
        file_tokens: Vec<TokenEntry>,
        file_origins: Vec<String>,
        (rate, burst): (Option<f64>, Option<u32>),
        (body, dcf_body): (Option<usize>, Option<usize>),
        tokens_env: Option<&str>,
    ) -> Result<AuthConfig, String> {
        let mut tokens = Vec::new();
        for entry in file_tokens {
            let role = entry
                .role
                .parse()
                .map_err(|err| format!("config tokens: token {}: {err}", entry.name))?;
            tokens.push(
                Token::new(&entry.name, role, &entry.token)
                    .map_err(|err| format!("config tokens: {err}"))?,
            );
        }
        for entry in tokens_env
            .unwrap_or("")
            .split(',')
            .filter(|entry| !entry.trim().is_empty())
        {
            tokens.push(Token::parse_entry(entry).map_err(|err| format!("{TOKENS_ENV}: {err}"))?);
        }
        let origins = if self.cors_origins.is_empty() {
            file_origins
        } else {
            self.cors_origins.clone()
        };
        let defaults = RateLimit::default();
        let per_second = self.write_rate.or(rate).unwrap_or(defaults.per_second);
        // 0 turns the limit off.
        let rate_limit = (per_second != 0.0).then(|| RateLimit {
            per_second,
            burst: self.write_burst.or(burst).unwrap_or(defaults.burst),
        });
        AuthConfig::new(
            tokens,
            origins,
            rate_limit,
            self.body_limit.or(body).unwrap_or(DEFAULT_BODY_LIMIT),
            self.dcf_body_limit
                .or(dcf_body)
                .unwrap_or(DEFAULT_DCF_BODY_LIMIT),
        )
    }

    /// What clap cannot check one argument at a time: two buses of one name.
    pub fn validate(&self) -> Result<(), String> {
        unique_names(&self.buses, "--bus")
    }
}

fn unique_names(buses: &[NamedBus], source: &str) -> Result<(), String> {
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

impl Settings {
    fn validate(&self) -> Result<(), String> {
        unique_names(&self.buses, "buses")?;
        self.exposure()?;
        for share in &self.share {
            match &share.bus {
                Some(name) => {
                    let bus = self
                        .buses
                        .iter()
                        .find(|bus| &bus.name == name)
                        .ok_or_else(|| format!("--share {name}=...: no bus is named '{name}'"))?;
                    if !matches!(bus.spec, BusSpec::Virtual { .. }) {
                        return Err(format!(
                            "--share {name}=...: bus {name} is {}, not a virtual bus; only a virtual bus can be shared",
                            bus.spec
                        ));
                    }
                }
                None => {
                    if !self
                        .buses
                        .iter()
                        .any(|bus| matches!(bus.spec, BusSpec::Virtual { .. }))
                    {
                        return Err(format!("--share {}: no virtual bus to share", share.addr));
                    }
                }
            }
        }
        Ok(())
    }

    /// Whether the gateway may listen where it is told, and the warning to
    /// give: without tokens anyone who reaches the port may move motors, so
    /// an address other than loopback needs tokens or `--insecure`.
    fn exposure(&self) -> Result<Option<String>, String> {
        if self.auth.required() {
            return Ok(None);
        }
        let listen = self.listen;
        if listen.ip().is_loopback() {
            return Ok(Some(format!(
                "no tokens: the API on {listen} is open to every program and user of this machine (README, \"Authentication and roles\")"
            )));
        }
        if self.insecure {
            return Ok(Some(format!(
                "--insecure: no tokens, the API on {listen} is open to anyone who reaches it, and may move motors"
            )));
        }
        Err(format!(
            "refusing to listen on {listen} without tokens: anyone who reaches it could move motors; configure tokens (config file [[tokens]] or {TOKENS_ENV}), listen on 127.0.0.1, or pass --insecure"
        ))
    }

    /// The socketcand servers to start: each address with the virtual
    /// buses it shares, as (channel, hub).
    fn shared(
        &self,
        served: &[ServedBus],
    ) -> std::collections::BTreeMap<SocketAddr, Vec<(String, VirtualHub)>> {
        let mut servers: std::collections::BTreeMap<SocketAddr, Vec<(String, VirtualHub)>> =
            std::collections::BTreeMap::new();
        for share in &self.share {
            let channels = servers.entry(share.addr).or_default();
            for bus in served {
                let Some(hub) = &bus.hub else { continue };
                let wanted = share.bus.as_ref().is_none_or(|name| name == &bus.name);
                if wanted && !channels.iter().any(|(name, _)| name == &bus.name) {
                    channels.push((bus.name.clone(), hub.clone()));
                }
            }
        }
        servers
    }
}

pub async fn run(args: ServeArgs) -> Result<(), CliError> {
    let args = args.settings().map_err(CliError::new)?;
    // Refused by settings() already when it is an error; warned about once
    // the gateway listens (a start that fails says one line only).
    let exposure = args.exposure().map_err(CliError::new)?;
    if let Some(dir) = &args.data_dir {
        std::fs::create_dir_all(dir)
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
        let mut opened = ServedBus::open_with_data_dir(
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
        served.push(opened);
    }
    let mut shares = Vec::new();
    for (addr, channels) in args.shared(&served) {
        let names: Vec<String> = channels.iter().map(|(name, _)| name.clone()).collect();
        let server = SocketcandServer::bind(addr, channels, ServerConfig::default())
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
    println!(
        "candeck: serving http://{local}/ ({label} {})",
        described.join(", ")
    );
    for (server, names) in &shares {
        let label = if names.len() == 1 { "bus" } else { "buses" };
        println!(
            "candeck: sharing {label} {} over socketcand on {} (channel = bus name)",
            names.join(", "),
            server.local_addr()
        );
    }
    if let Some((_, addr)) = &ascii_listener {
        println!("candeck: CiA 309-3 ASCII gateway on {addr} (net 1 = the first bus)");
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
    // Nodes that booted before the gateway listened, and nodes without
    // heartbeat, are found by a scan; the API answers meanwhile.
    for bus in &served {
        let registry = bus.registry.clone();
        let attachment = bus.bus.clone();
        let name = bus.name.clone();
        tokio::spawn(async move {
            // A socketcand bus is still connecting: scanning a bus that is
            // down finds nothing, so wait for it (the API answers meanwhile).
            if let Err(err) = attachment.wait_up(FIRST_SCAN_WAIT).await {
                tracing::warn!("bus {name}: not up for the first scan ({err}); POST /scan later");
                return;
            }
            match registry.scan().await {
                Ok(nodes) => tracing::info!("bus {name}: {} nodes found", nodes.len()),
                Err(err) => tracing::warn!("bus {name}: first scan failed: {err}"),
            }
        });
    }
    let state = AppState::with_history(served, history)
        .with_lease_period(args.lease_period)
        .with_auth(args.auth.clone());
    let ascii = ascii_listener.map(|(listener, _)| {
        tokio::spawn(crate::ascii::listen(
            listener,
            crate::ascii::Gateway::new(&state),
        ))
    });
    // The peer's address goes into the audit log.
    let app = crate::api::app(state.clone()).into_make_service_with_connect_info::<SocketAddr>();
    axum::serve(listener, app)
        .with_graceful_shutdown(shutdown_signal())
        .await
        .map_err(|err| CliError::new(format!("HTTP server on {local}: {err}")))?;
    // No drive is left moving because the gateway went away: every axis it
    // enabled is stopped before it exits.
    let report = crate::api::drives::stop_enabled_axes(&state).await;
    for stopped in &report.stopped {
        tracing::info!(
            "shutdown: quick stop of bus {} node {} axis {}",
            stopped.bus,
            stopped.node,
            stopped.axis
        );
    }
    for failed in &report.failed {
        tracing::error!(
            "shutdown: could not stop bus {} node {} axis {:?}: {}",
            failed.bus,
            failed.node,
            failed.axis,
            failed.error
        );
    }
    // A running recording ends with all it received written to its file;
    // temporary recordings are removed when the buses are dropped.
    for bus in state.buses.values() {
        if bus.recorder.status().state == crate::gateway::recording::RecordingState::Recording {
            let _ = bus.recorder.stop().await;
        }
    }
    pruner.abort();
    if let Some(ascii) = ascii {
        ascii.abort();
    }
    drop(state);
    drop(shares);
    tracing::info!("serve: stopped");
    Ok(())
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;
    use crate::api::auth::Role;
    use crate::cli::{Cli, Command};

    fn serve_args(args: &[&str]) -> Result<ServeArgs, String> {
        let cli = Cli::try_parse_from(["candeck", "serve"].iter().chain(args))
            .map_err(|err| err.to_string())?;
        match cli.command {
            Some(Command::Serve(args)) => Ok(args),
            other => Err(format!("not serve: {other:?}")),
        }
    }

    /// The config key of a `candeck serve` option: its long name with
    /// underscores; the repeated options' keys are plural.
    fn config_key(long: &str) -> String {
        match long {
            "bus" => "buses".to_string(),
            "cors-origin" => "cors_origins".to_string(),
            long => long.replace('-', "_"),
        }
    }

    #[test]
    fn the_example_config_parses_and_has_a_key_for_every_option() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("candeck.example.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        // "#= " lines are settings left out on purpose: with them too.
        let full: String = text
            .lines()
            .map(|line| line.strip_prefix("#= ").unwrap_or(line))
            .collect::<Vec<_>>()
            .join("\n");
        let dir = std::env::temp_dir().join(format!("candeck-example-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let full_path = dir.join("full.toml");
        std::fs::write(&full_path, &full).unwrap();

        // As shipped (tokens from the environment, as the systemd unit
        // gives them) and with every setting.
        let shipped = serve_args(&["--config", path.to_str().unwrap()])
            .unwrap()
            .settings_with(Some("hmi:viewer:3f9c2a7be81d4c06a5e9"))
            .unwrap();
        assert_eq!(shipped.buses.len(), 2);
        assert_eq!(shipped.data_dir, Some(PathBuf::from("/var/lib/candeck")));
        let settings = serve_args(&["--config", full_path.to_str().unwrap()])
            .unwrap()
            .settings_with(None)
            .unwrap();
        assert_eq!(settings.auth.tokens[0].name, "line-plc");
        assert_eq!(
            settings.ascii_listen,
            Some("127.0.0.1:60000".parse().unwrap())
        );

        // Every option of `candeck serve` but --config itself has a key in
        // the example: a new flag without one fails here.
        let keys: toml::Table = toml::from_str(&full).unwrap();
        let command = <Cli as clap::CommandFactory>::command();
        let serve = command.find_subcommand("serve").unwrap();
        let mut missing = Vec::new();
        for arg in serve.get_arguments() {
            let Some(long) = arg.get_long() else { continue };
            if ["config", "log", "help", "version"].contains(&long) {
                continue;
            }
            let key = config_key(long);
            if !keys.contains_key(&key) {
                missing.push(key);
            }
        }
        assert!(
            missing.is_empty(),
            "no key in candeck.example.toml: {missing:?}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn every_option_of_every_command_has_its_help() {
        fn check(command: &clap::Command, path: &str, missing: &mut Vec<String>) {
            if command.get_about().is_none() && !path.is_empty() {
                missing.push(format!("{path} (the command)"));
            }
            for arg in command.get_arguments() {
                let id = arg.get_id().as_str();
                if !["help", "version"].contains(&id) && arg.get_help().is_none() {
                    missing.push(format!("{path} {id}"));
                }
            }
            for sub in command.get_subcommands() {
                check(sub, &format!("{path} {}", sub.get_name()), missing);
            }
        }
        let mut missing = Vec::new();
        check(&<Cli as clap::CommandFactory>::command(), "", &mut missing);
        assert!(missing.is_empty(), "without help: {missing:?}");
    }

    #[test]
    fn the_sync_period_and_insecure_come_from_the_file_and_the_command_line() {
        let dir = std::env::temp_dir().join(format!("candeck-sync-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("sync.toml");
        std::fs::write(
            &file,
            "listen = \"0.0.0.0:8080\"\ninsecure = true\nsync_period_ms = 10\n",
        )
        .unwrap();
        let file = file.to_str().unwrap();

        let settings = serve_args(&[]).unwrap().settings_with(None).unwrap();
        assert_eq!(settings.sync_period, std::time::Duration::ZERO);
        let settings = serve_args(&["--config", file])
            .unwrap()
            .settings_with(None)
            .unwrap();
        assert_eq!(settings.sync_period, std::time::Duration::from_millis(10));
        assert!(settings.insecure);
        let settings = serve_args(&["--config", file, "--sync-period-ms", "0"])
            .unwrap()
            .settings_with(None)
            .unwrap();
        assert_eq!(settings.sync_period, std::time::Duration::ZERO);

        let err = serve_args(&["--sync-period-ms", "5000000"]).unwrap_err();
        assert!(err.contains("a SYNC period is at most"), "{err}");
        let bad = dir.join("bad.toml");
        std::fs::write(&bad, "sync_period_ms = 4294968\n").unwrap();
        let err = serve_args(&["--config", bad.to_str().unwrap()])
            .unwrap()
            .settings_with(None)
            .unwrap_err();
        assert!(err.contains("sync_period_ms"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_ascii_listener_comes_from_the_command_line_over_the_file() {
        let dir = std::env::temp_dir().join(format!("candeck-ascii-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("ascii.toml");
        std::fs::write(&file, "ascii_listen = \"127.0.0.1:6000\"\n").unwrap();
        let file = file.to_str().unwrap();

        assert_eq!(
            serve_args(&[]).unwrap().settings().unwrap().ascii_listen,
            None
        );
        let settings = serve_args(&["--config", file]).unwrap().settings().unwrap();
        assert_eq!(
            settings.ascii_listen,
            Some("127.0.0.1:6000".parse().unwrap())
        );
        let settings = serve_args(&["--config", file, "--ascii-listen", "0.0.0.0:6001"])
            .unwrap()
            .settings()
            .unwrap();
        assert_eq!(settings.ascii_listen, Some("0.0.0.0:6001".parse().unwrap()));
        assert!(serve_args(&["--ascii-listen", "nowhere"]).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn retention_comes_from_the_command_line_over_the_file_over_the_default() {
        let dir = std::env::temp_dir().join(format!("candeck-retention-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("retention.toml");
        std::fs::write(&file, "retention_days = 7\nretention_rows = 500\n").unwrap();
        let file = file.to_str().unwrap();

        let settings = serve_args(&[]).unwrap().settings().unwrap();
        assert_eq!(settings.retention, Retention::default());
        let settings = serve_args(&["--config", file]).unwrap().settings().unwrap();
        assert_eq!(
            settings.retention,
            Retention {
                days: Some(7),
                rows: Some(500)
            }
        );
        // 0 lifts a limit.
        let settings = serve_args(&["--config", file, "--retention-days", "0"])
            .unwrap()
            .settings()
            .unwrap();
        assert_eq!(
            settings.retention,
            Retention {
                days: None,
                rows: Some(500)
            }
        );
        let bad = dir.join("bad.toml");
        std::fs::write(&bad, "retention_rows = -1\n").unwrap();
        let err = serve_args(&["--config", bad.to_str().unwrap()])
            .unwrap()
            .settings()
            .unwrap_err();
        assert!(err.contains("line 1"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_axis_poll_rate_comes_from_the_command_line_over_the_file_over_the_default() {
        let dir = std::env::temp_dir().join(format!("candeck-serve-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("poll.toml");
        std::fs::write(&file, "axis_poll_hz = 50\n").unwrap();
        let file = file.to_str().unwrap();

        let settings = serve_args(&[]).unwrap().settings().unwrap();
        assert_eq!(settings.axis_poll_hz, DEFAULT_AXIS_POLL_HZ);
        let settings = serve_args(&["--config", file]).unwrap().settings().unwrap();
        assert_eq!(settings.axis_poll_hz, 50.0);
        let settings = serve_args(&["--config", file, "--axis-poll-hz", "12.5"])
            .unwrap()
            .settings()
            .unwrap();
        assert_eq!(settings.axis_poll_hz, 12.5);

        for bad in ["0", "-3", "nan", "fast", "150"] {
            let err = serve_args(&[&format!("--axis-poll-hz={bad}")]).unwrap_err();
            assert!(err.contains("--axis-poll-hz"), "{bad}: {err}");
        }
        let bad = dir.join("bad.toml");
        std::fs::write(&bad, "axis_poll_hz = 0\n").unwrap();
        let err = serve_args(&["--config", bad.to_str().unwrap()])
            .unwrap()
            .settings()
            .unwrap_err();
        assert!(err.contains("axis_poll_hz"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn without_tokens_only_loopback_is_served_unless_insecure() {
        let settings = serve_args(&[]).unwrap().settings_with(None).unwrap();
        assert!(settings.exposure().unwrap().unwrap().contains("no tokens"));
        let err = serve_args(&["--listen", "0.0.0.0:8080"])
            .unwrap()
            .settings_with(None)
            .unwrap_err();
        assert!(
            err.contains("refusing to listen on 0.0.0.0:8080 without tokens"),
            "{err}"
        );
        let settings = serve_args(&["--listen", "0.0.0.0:8080", "--insecure"])
            .unwrap()
            .settings_with(None)
            .unwrap();
        assert!(settings.exposure().unwrap().unwrap().contains("--insecure"));
        let settings = serve_args(&["--listen", "[::]:8080"])
            .unwrap()
            .settings_with(Some("plc:operator:3f9c2a7be81d4c06a5e9"))
            .unwrap();
        assert_eq!(settings.exposure(), Ok(None));
        assert_eq!(settings.auth.tokens[0].name, "plc");
    }

    #[test]
    fn tokens_and_limits_come_from_the_file_and_the_environment() {
        let dir = std::env::temp_dir().join(format!("candeck-auth-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("auth.toml");
        std::fs::write(
            &file,
            "cors_origins = [\"https://scada.example\"]\nwrite_rate = 5\nbody_limit = 2048\n\
             [[tokens]]\nname = \"line-plc\"\nrole = \"operator\"\ntoken = \"3f9c2a7be81d4c06a5e9\"\n",
        )
        .unwrap();
        let path = file.to_str().unwrap();
        let settings = serve_args(&["--config", path])
            .unwrap()
            .settings_with(Some("hmi:viewer:0123456789abcdefghij"))
            .unwrap();
        let names: Vec<(&str, Role)> = settings
            .auth
            .tokens
            .iter()
            .map(|t| (t.name.as_str(), t.role))
            .collect();
        assert_eq!(names, [("line-plc", Role::Operator), ("hmi", Role::Viewer)]);
        assert_eq!(settings.auth.cors_origins, ["https://scada.example"]);
        assert_eq!(settings.auth.rate_limit.unwrap().per_second, 5.0);
        assert_eq!(settings.auth.body_limit, 2048);
        // The command line wins; 0 turns the rate limit off.
        let settings = serve_args(&["--config", path, "--write-rate", "0"])
            .unwrap()
            .settings_with(None)
            .unwrap();
        assert_eq!(settings.auth.rate_limit, None);
        // The same token twice, a weak one, an unknown role: refused.
        let err = serve_args(&["--config", path])
            .unwrap()
            .settings_with(Some("other:admin:3f9c2a7be81d4c06a5e9"))
            .unwrap_err();
        assert!(err.contains("the same token"), "{err}");
        let err = serve_args(&[])
            .unwrap()
            .settings_with(Some("plc:operator:secret"))
            .unwrap_err();
        assert!(
            err.starts_with("CANDECK_TOKENS: token plc:") && err.contains("too weak"),
            "{err}"
        );
        std::fs::write(
            &file,
            "[[tokens]]\nname = \"x\"\nrole = \"root\"\ntoken = \"3f9c2a7be81d4c06a5e9\"\n",
        )
        .unwrap();
        let err = serve_args(&["--config", path])
            .unwrap()
            .settings_with(None)
            .unwrap_err();
        assert!(err.contains("unknown role 'root'"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
