//! What `candeck serve` runs with: the config file (`--config`, TOML or
//! JSON), merged under the command line's flags, the tokens of the file
//! and of the environment, and the checks of the whole.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use std::time::Duration;

use crate::api::auth::{AuthConfig, DEFAULT_BODY_LIMIT, DEFAULT_DCF_BODY_LIMIT, RateLimit};
use crate::api::host::AllowedHosts;
use crate::api::serve::Limits as HttpLimits;
use crate::ascii::Limits as AsciiLimits;
use crate::can::VirtualHub;
use crate::can::spec::BusSpec;
use crate::canopen::NodeId;
use crate::canopen::manager::{
    ConsumerFactor, DEFAULT_HEARTBEAT_MS, DEFAULT_MANAGER_HEARTBEAT_MS, DEFAULT_MANAGER_NODE_ID,
    IdentityCheck, ManagerConfig, NodeDescription,
};
use crate::gateway::DEFAULT_AXIS_POLL_HZ;
use crate::gateway::ServedBus;
use crate::gateway::Token;
use crate::gateway::{DEFAULT_RETENTION_DAYS, DEFAULT_RETENTION_ROWS, Retention};
use crate::gateway::{MachineSettings, load_dcf};

use crate::sparkplug::SparkplugConfig;
use crate::sparkplug::config::{BrokerUrl, TlsFiles};
use crate::sparkplug::edge::{MetricRule, Policy, Reporting};

use super::args::*;

/// One token of the config file.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct TokenEntry {
    pub(super) name: String,
    pub(super) role: String,
    pub(super) token: String,
}

/// One expected node of the machine description (`[[nodes]]`).
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct NodeEntry {
    pub(super) bus: Option<String>,
    pub(super) id: u8,
    pub(super) name: Option<String>,
    pub(super) vendor_id: Option<u32>,
    pub(super) product_code: Option<u32>,
    pub(super) revision_min: Option<u32>,
    pub(super) revision_max: Option<u32>,
    pub(super) serial: Option<u32>,
    pub(super) mandatory: Option<bool>,
    pub(super) eds: Option<String>,
    pub(super) dcf: Option<PathBuf>,
    pub(super) heartbeat_ms: Option<u16>,
    pub(super) consume_manager_heartbeat: Option<bool>,
    pub(super) start: Option<bool>,
}

/// The settings of a config file (`--config`).
#[derive(Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ConfigFile {
    pub(super) listen: Option<SocketAddr>,
    #[serde(default)]
    pub(super) buses: Vec<NamedBus>,
    pub(super) eds_dir: Option<PathBuf>,
    pub(super) data_dir: Option<PathBuf>,
    pub(super) bitrate: Option<u32>,
    #[serde(default)]
    pub(super) share: Vec<Share>,
    pub(super) axis_poll_hz: Option<f64>,
    pub(super) retention_days: Option<u32>,
    pub(super) retention_rows: Option<u64>,
    pub(super) recordings_quota_mb: Option<u64>,
    pub(super) logger_max_values: Option<u64>,
    pub(super) lease_ms: Option<u64>,
    pub(super) shutdown_grace_ms: Option<u64>,
    pub(super) ascii_listen: Option<SocketAddr>,
    #[serde(default)]
    pub(super) tokens: Vec<TokenEntry>,
    #[serde(default)]
    pub(super) cors_origins: Vec<String>,
    pub(super) write_rate: Option<f64>,
    pub(super) write_burst: Option<u32>,
    pub(super) body_limit: Option<usize>,
    pub(super) dcf_body_limit: Option<usize>,
    pub(super) sync_period_ms: Option<u32>,
    pub(super) insecure: Option<bool>,
    #[serde(default)]
    pub(super) allowed_hosts: Vec<String>,
    pub(super) share_public: Option<bool>,
    pub(super) header_timeout_ms: Option<u64>,
    pub(super) idle_timeout_ms: Option<u64>,
    pub(super) max_connections: Option<usize>,
    pub(super) ascii_idle_timeout_ms: Option<u64>,
    pub(super) ascii_max_connections: Option<usize>,
    pub(super) ascii_unauthenticated_timeout_ms: Option<u64>,
    pub(super) eds_max_files: Option<usize>,
    pub(super) eds_max_mb: Option<u64>,
    pub(super) stream_max_per_token: Option<usize>,
    pub(super) stream_max_per_peer: Option<usize>,
    // The Sparkplug B edge node (docs/sparkplug.md); off without mqtt_url.
    pub(super) mqtt_url: Option<String>,
    pub(super) mqtt_username: Option<String>,
    pub(super) mqtt_password: Option<String>,
    pub(super) mqtt_ca_file: Option<PathBuf>,
    pub(super) mqtt_client_cert: Option<PathBuf>,
    pub(super) mqtt_client_key: Option<PathBuf>,
    pub(super) sparkplug_group_id: Option<String>,
    pub(super) sparkplug_edge_node_id: Option<String>,
    pub(super) sparkplug_primary_host: Option<String>,
    pub(super) sparkplug_role: Option<String>,
    pub(super) sparkplug_insecure: Option<bool>,
    pub(super) sparkplug_max_command_bytes: Option<usize>,
    pub(super) sparkplug_max_command_metrics: Option<usize>,
    pub(super) sparkplug_queue_messages: Option<usize>,
    pub(super) sparkplug_deadband: Option<f64>,
    pub(super) sparkplug_max_rate_hz: Option<f64>,
    pub(super) sparkplug_publish_tick_ms: Option<u64>,
    pub(super) share_max_connections: Option<usize>,
    #[serde(default)]
    pub(super) sparkplug_metrics: Vec<SparkplugMetric>,
    // The OPC UA server (docs/opcua.md); off without opcua_listen.
    pub(super) opcua_listen: Option<SocketAddr>,
    pub(super) opcua_pki_dir: Option<PathBuf>,
    pub(super) opcua_max_sessions: Option<usize>,
    pub(super) opcua_max_subscriptions: Option<usize>,
    pub(super) opcua_max_monitored_items: Option<usize>,
    pub(super) opcua_max_message_size: Option<usize>,
    pub(super) opcua_session_timeout_ms: Option<u64>,
    // The SDO samples a second per node that sampled objects may take,
    // whichever door asks them; its first name, from when only OPC UA
    // sampled, still works.
    #[serde(alias = "opcua_sdo_samples_per_s")]
    pub(super) sdo_samples_per_s: Option<u32>,
    pub(super) manager_node_id: Option<u8>,
    pub(super) manager_heartbeat_ms: Option<u16>,
    pub(super) heartbeat_consumer_factor: Option<f64>,
    #[serde(default)]
    pub(super) nodes: Vec<NodeEntry>,
}

/// A `[[sparkplug_metrics]]` entry: how the metrics of one name are
/// reported.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct SparkplugMetric {
    /// The whole metric name (`TPDO/a1_Position_actual_value`) or its last
    /// element (`a1_Position_actual_value`).
    pub(super) metric: String,
    pub(super) deadband: Option<f64>,
    pub(super) max_rate_hz: Option<f64>,
}

/// The reporting of a deadband and a maximum rate (0 or none: every
/// change).
fn reporting(deadband: Option<f64>, max_rate_hz: Option<f64>) -> Result<Reporting, String> {
    let deadband = deadband.unwrap_or(0.0);
    if !deadband.is_finite() || deadband < 0.0 {
        return Err(format!("deadband {deadband}: a number of at least 0"));
    }
    let min_interval_ms = match max_rate_hz {
        None | Some(0.0) => 0,
        Some(hz) if hz.is_finite() && hz > 0.0 => (1000.0 / hz).round() as u64,
        Some(hz) => return Err(format!("max_rate_hz {hz}: a rate of at least 0")),
    };
    Ok(Reporting {
        deadband,
        min_interval_ms,
    })
}

impl ConfigFile {
    /// The edge node's settings; `None` without `mqtt_url`.
    pub(super) fn sparkplug(
        &self,
        data_dir: Option<&Path>,
    ) -> Result<Option<SparkplugConfig>, String> {
        let Some(url) = &self.mqtt_url else {
            return Ok(None);
        };
        let broker: BrokerUrl = url.parse()?;
        let group = self
            .sparkplug_group_id
            .as_deref()
            .ok_or("mqtt_url needs sparkplug_group_id (the Sparkplug group of this edge node)")?;
        let edge_node = self
            .sparkplug_edge_node_id
            .clone()
            .unwrap_or_else(crate::sparkplug::config::host_name);
        let mut config = SparkplugConfig::new(broker, group, &edge_node);
        config.username = self.mqtt_username.clone();
        config.password = self.mqtt_password.clone();
        config.tls = TlsFiles {
            ca_file: self.mqtt_ca_file.clone(),
            client_cert: self.mqtt_client_cert.clone(),
            client_key: self.mqtt_client_key.clone(),
        };
        config.primary_host = self.sparkplug_primary_host.clone();
        if let Some(role) = &self.sparkplug_role {
            config.role = role
                .parse()
                .map_err(|err| format!("sparkplug_role: {err}"))?;
        }
        config.insecure = self.sparkplug_insecure.unwrap_or(false);
        if let Some(bytes) = self.sparkplug_max_command_bytes {
            config.max_command_bytes = bytes;
        }
        if let Some(metrics) = self.sparkplug_max_command_metrics {
            config.max_command_metrics = metrics;
        }
        if let Some(messages) = self.sparkplug_queue_messages {
            config.queue_messages = messages;
        }
        if let Some(ms) = self.sparkplug_publish_tick_ms {
            config.publish_tick = std::time::Duration::from_millis(ms);
        }
        config.policy = Policy {
            default: reporting(self.sparkplug_deadband, self.sparkplug_max_rate_hz)
                .map_err(|err| format!("sparkplug_{err}"))?,
            rules: self
                .sparkplug_metrics
                .iter()
                .map(|rule| {
                    Ok(MetricRule {
                        metric: rule.metric.clone(),
                        reporting: reporting(rule.deadband, rule.max_rate_hz)
                            .map_err(|err| format!("sparkplug_metrics {}: {err}", rule.metric))?,
                    })
                })
                .collect::<Result<_, String>>()?,
        };
        config.spool_file = data_dir.map(|dir| dir.join("sparkplug-spool.bin"));
        config.validate()?;
        Ok(Some(config))
    }

    /// Reads `path`: JSON when named `*.json`, TOML otherwise. The error
    /// names the file and the line.
    pub(super) fn read(path: &Path) -> Result<Self, String> {
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
        if let Some(n) = config.logger_max_values
            && !(1000..=100_000_000).contains(&n)
        {
            return Err(format!(
                "config {}: logger_max_values {n}: give 1000 to 100000000",
                path.display()
            ));
        }
        if let Some(n) = config.sdo_samples_per_s
            && !(1..=crate::gateway::MAX_SDO_SAMPLES_PER_S).contains(&n)
        {
            return Err(format!(
                "config {}: sdo_samples_per_s (or opcua_sdo_samples_per_s) {n} is not between 1 \
                 and {}",
                path.display(),
                crate::gateway::MAX_SDO_SAMPLES_PER_S
            ));
        }
        if let Some(ms) = config.shutdown_grace_ms {
            check_shutdown_grace_ms(ms)
                .map_err(|err| format!("config {}: shutdown_grace_ms {err}", path.display()))?;
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
        for dir in [
            &mut config.eds_dir,
            &mut config.data_dir,
            &mut config.mqtt_ca_file,
            &mut config.mqtt_client_cert,
            &mut config.mqtt_client_key,
            &mut config.opcua_pki_dir,
        ]
        .into_iter()
        .chain(config.nodes.iter_mut().map(|node| &mut node.dcf))
        .flatten()
        {
            if dir.is_relative() {
                *dir = base.join(&*dir);
            }
        }
        Ok(config)
    }
}

impl ConfigFile {
    /// The OPC UA server's limits: the file's keys over the defaults.
    fn opcua_limits(&self) -> crate::opcua::config::OpcUaLimits {
        let defaults = crate::opcua::config::OpcUaLimits::default();
        crate::opcua::config::OpcUaLimits {
            max_sessions: self.opcua_max_sessions.unwrap_or(defaults.max_sessions),
            max_subscriptions: self
                .opcua_max_subscriptions
                .unwrap_or(defaults.max_subscriptions),
            max_monitored_items: self
                .opcua_max_monitored_items
                .unwrap_or(defaults.max_monitored_items),
            max_message_size: self
                .opcua_max_message_size
                .unwrap_or(defaults.max_message_size),
            session_timeout: self
                .opcua_session_timeout_ms
                .map_or(defaults.session_timeout, Duration::from_millis),
        }
    }
}

/// The OPC UA server on `listen` (`--opcua-listen`, `opcua_listen`): its
/// PKI in the data directory unless `opcua_pki_dir` says; it takes the
/// tokens REST takes.
fn opcua(
    listen: SocketAddr,
    pki_dir: Option<PathBuf>,
    limits: crate::opcua::config::OpcUaLimits,
    data_dir: Option<&Path>,
    tokens_required: bool,
    insecure: bool,
) -> Result<crate::opcua::OpcUaConfig, String> {
    if !cfg!(feature = "opcua") {
        return Err("opcua_listen: this candeck was built without the opcua feature".to_string());
    }
    let pki_dir = pki_dir.unwrap_or_else(|| crate::opcua::config::default_pki_dir(data_dir));
    crate::opcua::OpcUaConfig::new(listen, pki_dir, limits, tokens_required, insecure)
}

/// The 1-based line and column of byte `offset` of `text`.
pub(super) fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.len() - before.rfind('\n').map_or(0, |at| at + 1) + 1;
    (line, column)
}

/// What `candeck serve` runs with: the command line over the config file
/// over the defaults.
#[derive(Debug)]
pub(super) struct Settings {
    pub(super) listen: SocketAddr,
    pub(super) buses: Vec<NamedBus>,
    pub(super) eds_dir: Option<PathBuf>,
    pub(super) data_dir: Option<PathBuf>,
    pub(super) bitrate: u32,
    pub(super) share: Vec<Share>,
    pub(super) axis_poll_hz: f64,
    pub(super) retention: Retention,
    /// Bytes; `None`: no quota.
    pub(super) recordings_quota: Option<u64>,
    /// Values one data logger keeps in memory.
    pub(super) logger_max_values: usize,
    pub(super) lease_period: std::time::Duration,
    /// How long open HTTP connections may take to finish once the axes
    /// are stopped on shutdown.
    pub(super) shutdown_grace: std::time::Duration,
    pub(super) ascii_listen: Option<SocketAddr>,
    pub(super) auth: AuthConfig,
    pub(super) insecure: bool,
    pub(super) sync_period: std::time::Duration,
    /// The SDO samples a second per node of every door's sampling.
    pub(super) sdo_samples_per_s: u32,
    pub(super) allowed_hosts: AllowedHosts,
    pub(super) share_public: bool,
    pub(super) http_limits: HttpLimits,
    pub(super) ascii_limits: AsciiLimits,
    /// The Sparkplug B edge node; `None`: off.
    pub(super) sparkplug: Option<SparkplugConfig>,
    /// The OPC UA server; `None`: off.
    pub(super) opcua: Option<crate::opcua::OpcUaConfig>,
    /// socketcand clients at once per share.
    pub(super) share_max_connections: usize,
    /// The uploaded EDS files the catalog takes.
    pub(super) eds_quota: crate::gateway::EdsQuota,
    /// WebSocket streams per token and per peer.
    pub(super) stream_limits: crate::api::stream::StreamLimits,
    /// The network manager of every bus, and the nodes described for each
    /// (by bus name).
    pub(super) machine: MachineSettings,
    pub(super) machine_nodes: std::collections::BTreeMap<String, Vec<NodeDescription>>,
}

impl Settings {
    /// What the gateway is started with ([`Gateway::start`](crate::gateway::Gateway::start)).
    pub(super) fn gateway_config(&self) -> crate::gateway::GatewayConfig {
        crate::gateway::GatewayConfig {
            buses: self
                .buses
                .iter()
                .map(|bus| (bus.name.clone(), bus.spec.clone()))
                .collect(),
            data_dir: self.data_dir.clone(),
            eds_dir: self.eds_dir.clone(),
            bitrate: self.bitrate,
            telemetry: crate::gateway::TelemetryConfig {
                axis_poll_hz: self.axis_poll_hz,
                ..Default::default()
            },
            retention: self.retention,
            recordings_quota: self.recordings_quota,
            logger_max_values: self.logger_max_values,
            lease_period: self.lease_period,
            tokens: self.auth.tokens.clone(),
            write_limit: self.auth.rate_limit,
            sync_period: self.sync_period,
            sdo_samples_per_s: self.sdo_samples_per_s,
            machine: self.machine.clone(),
            machine_nodes: self.machine_nodes.clone(),
        }
    }
}

impl ServeArgs {
    /// The settings: each option from the command line, else from the
    /// config file, else its default (the demo bus when no bus is given);
    /// tokens from the file and [`TOKENS_ENV`].
    pub(super) fn settings(&self) -> Result<Settings, String> {
        self.settings_with(std::env::var(TOKENS_ENV).ok().as_deref())
    }

    /// [`ServeArgs::settings`] with `tokens_env` as the environment's tokens.
    pub(super) fn settings_with(&self, tokens_env: Option<&str>) -> Result<Settings, String> {
        let file = match &self.config {
            Some(path) => ConfigFile::read(path)?,
            None => ConfigFile::default(),
        };
        let data_dir = self.data_dir.clone().or(file.data_dir.clone());
        let sparkplug = file.sparkplug(data_dir.as_deref())?;
        // Checked once the tokens are known (below).
        let opcua_limits = file.opcua_limits();
        let opcua_listen = self.opcua_listen.or(file.opcua_listen);
        let opcua_pki_dir = file.opcua_pki_dir.clone();
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
        let machine = MachineSettings {
            manager: ManagerConfig {
                node_id: NodeId::new(file.manager_node_id.unwrap_or(DEFAULT_MANAGER_NODE_ID))
                    .map_err(|err| format!("config manager_node_id: {err}"))?,
                heartbeat_ms: file
                    .manager_heartbeat_ms
                    .unwrap_or(DEFAULT_MANAGER_HEARTBEAT_MS),
                consumer_factor: file
                    .heartbeat_consumer_factor
                    .map(ConsumerFactor::new)
                    .transpose()
                    .map_err(|err| format!("config {err}"))?
                    .unwrap_or_default(),
                ..ManagerConfig::default()
            },
            nodes: Vec::new(),
        };
        let machine_nodes = machine_nodes(&file.nodes, &buses, machine.manager.node_id)?;
        let mut settings = Settings {
            sparkplug,
            opcua: None,
            machine,
            machine_nodes,
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
                    .unwrap_or(crate::gateway::DEFAULT_PERIOD.as_millis() as u64),
            ),
            shutdown_grace: std::time::Duration::from_millis(
                self.shutdown_grace_ms
                    .or(file.shutdown_grace_ms)
                    .unwrap_or(DEFAULT_SHUTDOWN_GRACE_MS),
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
            logger_max_values: self
                .logger_max_values
                .or(file.logger_max_values)
                .map_or(crate::gateway::DEFAULT_MAX_VALUES, |n| {
                    usize::try_from(n).unwrap_or(usize::MAX)
                }),
            recordings_quota: Some(
                self.recordings_quota_mb
                    .or(file.recordings_quota_mb)
                    .unwrap_or(crate::gateway::DEFAULT_QUOTA_MB),
            )
            .filter(|mb| *mb > 0)
            .map(|mb| mb.saturating_mul(1024 * 1024)),
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
            sdo_samples_per_s: file
                .sdo_samples_per_s
                .unwrap_or(crate::gateway::DEFAULT_SDO_SAMPLES_PER_S),
            allowed_hosts: AllowedHosts::new(if self.allowed_hosts.is_empty() {
                &file.allowed_hosts
            } else {
                &self.allowed_hosts
            })?,
            // Like --insecure, a flag can only say yes.
            share_public: self.share_public || file.share_public.unwrap_or(false),
            http_limits: {
                let defaults = HttpLimits::default();
                let ms = |flag: Option<u64>, key: Option<u64>, default: Duration| {
                    flag.or(key).map_or(default, Duration::from_millis)
                };
                HttpLimits::new(
                    ms(
                        self.header_timeout_ms,
                        file.header_timeout_ms,
                        defaults.header_timeout,
                    ),
                    ms(
                        self.idle_timeout_ms,
                        file.idle_timeout_ms,
                        defaults.idle_timeout,
                    ),
                    self.max_connections
                        .or(file.max_connections)
                        .unwrap_or(defaults.max_connections),
                )?
            },
            ascii_limits: {
                let defaults = AsciiLimits::default();
                AsciiLimits::new(
                    self.ascii_idle_timeout_ms
                        .or(file.ascii_idle_timeout_ms)
                        .map_or(defaults.idle_timeout, Duration::from_millis),
                    self.ascii_max_connections
                        .or(file.ascii_max_connections)
                        .unwrap_or(defaults.max_connections),
                    self.ascii_unauthenticated_timeout_ms
                        .or(file.ascii_unauthenticated_timeout_ms)
                        .map_or(defaults.unauthenticated_timeout, Duration::from_millis),
                )?
            },
            stream_limits: {
                let defaults = crate::api::stream::StreamLimits::default();
                crate::api::stream::StreamLimits::new(
                    self.stream_max_per_token
                        .or(file.stream_max_per_token)
                        .unwrap_or(defaults.per_token),
                    self.stream_max_per_peer
                        .or(file.stream_max_per_peer)
                        .unwrap_or(defaults.per_peer),
                )?
            },
            eds_quota: {
                let defaults = crate::gateway::EdsQuota::default();
                let max_files = self
                    .eds_max_files
                    .or(file.eds_max_files)
                    .unwrap_or(defaults.max_files);
                let max_mb = self.eds_max_mb.or(file.eds_max_mb);
                if max_files == 0 || max_mb == Some(0) {
                    return Err(
                        "eds_max_files, eds_max_mb: at least 1 (refuse uploads with tokens: only admins upload)"
                            .to_string(),
                    );
                }
                crate::gateway::EdsQuota {
                    max_files,
                    max_bytes: max_mb
                        .map_or(defaults.max_bytes, |mb| mb.saturating_mul(1024 * 1024)),
                }
            },
            share_max_connections: match self.share_max_connections.or(file.share_max_connections) {
                Some(0) => return Err("share_max_connections: at least 1".to_string()),
                Some(n) => n,
                None => crate::can::socketcand::DEFAULT_SHARE_MAX_CONNECTIONS,
            },
        };
        settings.opcua = match opcua_listen {
            Some(listen) => Some(opcua(
                listen,
                opcua_pki_dir,
                opcua_limits,
                data_dir.as_deref(),
                settings.auth.required(),
                settings.insecure,
            )?),
            None => None,
        };
        settings.validate()?;
        Ok(settings)
    }

    /// Tokens from the file and the environment, the rest from the command
    /// line over the file over the defaults.
    pub(super) fn auth_config(
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
}

impl Settings {
    pub(super) fn validate(&self) -> Result<(), String> {
        unique_names(&self.buses, "buses")?;
        self.exposure()?;
        self.listeners()?;
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
    pub(super) fn exposure(&self) -> Result<Option<String>, String> {
        if self.auth.required() {
            return Ok(None);
        }
        let listen = self.listen;
        if listen.ip().is_loopback() {
            return Ok(Some(format!(
                "no tokens: the API on {listen} is open to every program and user of this machine (docs/security.md)"
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

    /// Whether the other listeners may listen where they are told (issue
    /// 19, point 6), and the warnings to give: the CiA 309-3 port moves
    /// motors as the API does, so it follows the API's rule (loopback, or
    /// tokens, or `--insecure`); a socketcand share is raw bus access that
    /// no token guards, so an address other than loopback needs
    /// `--share-public` whatever the tokens.
    pub(super) fn listeners(&self) -> Result<Vec<String>, String> {
        let mut warnings = Vec::new();
        if let Some(ascii) = self.ascii_listen
            && !ascii.ip().is_loopback()
            && !self.auth.required()
        {
            if !self.insecure {
                return Err(format!(
                    "refusing --ascii-listen {ascii} without tokens: anyone who reaches it could move motors; configure tokens (config file [[tokens]] or {TOKENS_ENV}), listen on 127.0.0.1, or pass --insecure"
                ));
            }
            warnings.push(format!(
                "--insecure: no tokens, the CiA 309-3 port on {ascii} is open to anyone who reaches it, and may move motors"
            ));
        }
        if let Some(opcua) = &self.opcua
            && opcua.logins.anonymous
            && !opcua.listen.ip().is_loopback()
        {
            warnings.push(format!(
                "--insecure: no tokens, the OPC UA server on {} serves anonymous sessions to every client whose certificate is trusted, and may move motors",
                opcua.listen
            ));
        }
        for share in &self.share {
            if share.addr.ip().is_loopback() {
                continue;
            }
            if !self.share_public {
                return Err(format!(
                    "refusing --share {}: a socketcand share is raw bus access (SDO, NMT, any frame) without tokens or audit; share on 127.0.0.1, or pass --share-public to open it to anyone who reaches {}",
                    share.addr, share.addr
                ));
            }
            warnings.push(format!(
                "--share-public: the socketcand share on {} gives raw bus access, without tokens or audit, to anyone who reaches it",
                share.addr
            ));
        }
        if !self.listen.ip().is_loopback()
            && !self.allowed_hosts.any()
            && self.allowed_hosts.names().is_empty()
        {
            warnings.push(format!(
                "{} is no loopback address and allowed_hosts is empty: the gateway cannot know the names it is reached by, so it answers requests sent to localhost and IP addresses only (421 for any other name); list its names in allowed_hosts (--allowed-host)",
                self.listen
            ));
        }
        Ok(warnings)
    }

    /// The socketcand servers to start: each address with the virtual
    /// buses it shares, as (channel, hub).
    /// How many socketcand share addresses the gateway listens on.
    pub(super) fn shared_addresses(&self) -> usize {
        let addresses: std::collections::BTreeSet<SocketAddr> =
            self.share.iter().map(|share| share.addr).collect();
        addresses.len()
    }

    pub(super) fn shared(
        &self,
        served: &[std::sync::Arc<ServedBus>],
    ) -> std::collections::BTreeMap<SocketAddr, Vec<(String, VirtualHub)>> {
        let mut servers: std::collections::BTreeMap<SocketAddr, Vec<(String, VirtualHub)>> =
            std::collections::BTreeMap::new();
        for share in &self.share {
            let channels = servers.entry(share.addr).or_default();
            for bus in served {
                let Some(hub) = bus.hub() else { continue };
                let wanted = share.bus.as_ref().is_none_or(|name| name == bus.name());
                if wanted && !channels.iter().any(|(name, _)| name == bus.name()) {
                    channels.push((bus.name().to_string(), hub.clone()));
                }
            }
        }
        servers
    }
}

/// The shortest heartbeat period a `[[nodes]]` entry may ask (0 turns
/// supervision off): shorter ones load the bus for nothing and, with a
/// consumer time of 1.5 periods, report a node lost whenever the host is
/// briefly busy.
pub(super) const MIN_NODE_HEARTBEAT_MS: u16 = 50;

/// The ranges and the consistency of one `[[nodes]]` entry's values
/// (issue 30, finding 8).
pub(super) fn check_node_entry(entry: &NodeEntry) -> Result<(), String> {
    if let Some(ms) = entry.heartbeat_ms
        && ms != 0
        && ms < MIN_NODE_HEARTBEAT_MS
    {
        return Err(format!(
            "heartbeat_ms {ms}: give 0 (not supervised) or {MIN_NODE_HEARTBEAT_MS} to {} ms",
            u16::MAX
        ));
    }
    if let (Some(min), Some(max)) = (entry.revision_min, entry.revision_max)
        && min > max
    {
        return Err(format!(
            "revision_min {min:#010x} is above revision_max {max:#010x}: the range matches no revision"
        ));
    }
    if entry
        .name
        .as_deref()
        .is_some_and(|name| name.trim().is_empty())
    {
        return Err("name: empty; leave the key out for none".to_string());
    }
    Ok(())
}

/// The `[[nodes]]` of the config file by bus (the first bus when a node
/// names none), each checked and its DCF read for its node id.
fn machine_nodes(
    entries: &[NodeEntry],
    buses: &[NamedBus],
    manager: NodeId,
) -> Result<std::collections::BTreeMap<String, Vec<NodeDescription>>, String> {
    let mut out: std::collections::BTreeMap<String, Vec<NodeDescription>> =
        std::collections::BTreeMap::new();
    for entry in entries {
        let bus = match &entry.bus {
            Some(name) => buses.iter().find(|bus| &bus.name == name).ok_or_else(|| {
                format!("config [[nodes]] id {}: no bus is named '{name}'", entry.id)
            })?,
            None => buses
                .first()
                .ok_or_else(|| format!("config [[nodes]] id {}: no bus", entry.id))?,
        };
        let id = NodeId::new(entry.id)
            .map_err(|err| format!("config [[nodes]] id {}: {err}", entry.id))?;
        check_node_entry(entry).map_err(|err| format!("config [[nodes]] id {id}: {err}"))?;
        if id == manager {
            return Err(format!(
                "config [[nodes]] id {id}: that is the gateway's own node id (manager_node_id)"
            ));
        }
        let nodes = out.entry(bus.name.clone()).or_default();
        if nodes.iter().any(|node| node.id == id) {
            return Err(format!(
                "config [[nodes]]: node {id} of bus {} is described twice",
                bus.name
            ));
        }
        let config = match &entry.dcf {
            Some(path) => {
                // Bounded before it is read (issue 30: `/dev/zero`).
                crate::canopen::eds::check_file(path).map_err(|err| {
                    format!("config [[nodes]] id {id}: DCF {}: {err}", path.display())
                })?;
                load_dcf(path, id).map_err(|err| format!("config [[nodes]] id {id}: {err}"))?
            }
            None => Vec::new(),
        };
        nodes.push(NodeDescription {
            id,
            name: entry.name.clone(),
            identity: IdentityCheck {
                vendor_id: entry.vendor_id,
                product_code: entry.product_code,
                revision_min: entry.revision_min,
                revision_max: entry.revision_max,
                serial: entry.serial,
            },
            mandatory: entry.mandatory.unwrap_or(true),
            eds: entry.eds.clone(),
            dcf: entry
                .dcf
                .as_ref()
                .and_then(|path| path.file_name())
                .map(|name| name.to_string_lossy().into_owned()),
            config,
            heartbeat_ms: entry.heartbeat_ms.unwrap_or(DEFAULT_HEARTBEAT_MS),
            consume_manager_heartbeat: entry.consume_manager_heartbeat,
            start: entry.start.unwrap_or(true),
            expected: true,
        });
    }
    Ok(out)
}
