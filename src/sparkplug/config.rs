//! The edge node's settings (config keys `mqtt_url`, `sparkplug_*`;
//! docs/configuration.md) and the broker's address read from `mqtt_url`.

use std::path::PathBuf;
use std::time::Duration;

use super::edge::Policy;
use super::topic::valid_element;
use crate::gateway::Role;

/// The default size of the store-and-forward queue, in messages.
pub const DEFAULT_QUEUE_MESSAGES: usize = 100_000;

/// The default `sparkplug_max_command_bytes`: a command is a few metrics
/// (a move, its lease), far below this.
pub const DEFAULT_MAX_COMMAND_BYTES: usize = 64 * 1024;

/// The default `sparkplug_max_command_metrics`.
pub const DEFAULT_MAX_COMMAND_METRICS: usize = 64;

/// The default `sparkplug_publish_tick_ms`.
pub const DEFAULT_PUBLISH_TICK: Duration = Duration::from_millis(10);

/// The largest MQTT packet there is (3.1.1: a remaining length of at most
/// 268,435,455 bytes, and its fixed header): the edge node reads any packet
/// the broker delivers rather than ending its session over one (rumqttc
/// drops the connection on a packet over its limit), and refuses a command
/// over `sparkplug_max_command_bytes` itself. The broker's own limit
/// (Mosquitto's `message_size_limit`) bounds what reaches it.
pub const MAX_PACKET: usize = 268_435_455 + 5;

/// A broker address: `mqtt://host[:port]` (1883) or `mqtts://host[:port]`
/// (8883, TLS).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BrokerUrl {
    pub host: String,
    pub port: u16,
    pub tls: bool,
}

impl std::str::FromStr for BrokerUrl {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let (tls, rest) = if let Some(rest) = text.strip_prefix("mqtt://") {
            (false, rest)
        } else if let Some(rest) = text.strip_prefix("mqtts://") {
            (true, rest)
        } else {
            return Err(format!(
                "mqtt_url '{text}': give mqtt://host:port or mqtts://host:port"
            ));
        };
        let rest = rest.trim_end_matches('/');
        let (host, port) = match rest.rsplit_once(':') {
            Some((host, port)) if !host.ends_with(']') || host.starts_with('[') => (
                host,
                port.parse::<u16>()
                    .map_err(|err| format!("mqtt_url '{text}': port '{port}': {err}"))?,
            ),
            _ => (rest, if tls { 8883 } else { 1883 }),
        };
        let host = host.trim_start_matches('[').trim_end_matches(']');
        if host.is_empty() || host.contains(['/', '@', '?']) {
            return Err(format!(
                "mqtt_url '{text}': give mqtt://host:port (credentials go in mqtt_username and mqtt_password)"
            ));
        }
        Ok(Self {
            host: host.to_string(),
            port,
            tls,
        })
    }
}

/// TLS files for `mqtts://`.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct TlsFiles {
    /// The CA certificate(s) the broker's certificate is checked against
    /// (PEM).
    pub ca_file: Option<PathBuf>,
    /// A client certificate (PEM) and its key (PEM), for brokers that
    /// authenticate clients by certificate.
    pub client_cert: Option<PathBuf>,
    pub client_key: Option<PathBuf>,
}

/// Everything the edge node runs with.
#[derive(Debug, Clone, PartialEq)]
pub struct SparkplugConfig {
    pub broker: BrokerUrl,
    pub tls: TlsFiles,
    pub username: Option<String>,
    pub password: Option<String>,
    pub group_id: String,
    pub edge_node_id: String,
    /// The primary host application to wait for (`STATE/{host_id}`).
    pub primary_host: Option<String>,
    /// The role the commands from MQTT run with (`viewer`: refused).
    pub role: Role,
    /// `sparkplug_insecure`: commands without broker credentials, or off
    /// loopback without TLS (logged loudly at start). MQTT carries no
    /// sender identity, so only the broker can decide who may send a
    /// command: without a password (and TLS where the network can see
    /// it) anyone who reaches the broker could move the machine.
    pub insecure: bool,
    /// The largest NCMD/DCMD payload taken, in bytes
    /// (`sparkplug_max_command_bytes`): a larger one is refused whole,
    /// audited, and the session stays up.
    pub max_command_bytes: usize,
    /// The most metrics of one NCMD/DCMD (`sparkplug_max_command_metrics`):
    /// a message with more is refused whole, audited once.
    pub max_command_metrics: usize,
    /// How metrics are reported by exception.
    pub policy: Policy,
    /// The store-and-forward queue's size, in messages.
    pub queue_messages: usize,
    /// Where the queue is mirrored (the data directory's
    /// `sparkplug-spool.bin`), if anywhere.
    pub spool_file: Option<PathBuf>,
    /// How often the edge node's own metrics (bus states) are checked.
    pub node_check: Duration,
    /// The MQTT keep-alive.
    pub keep_alive: Duration,
    /// The shortest time between two passes over the nodes whose TPDO
    /// values changed (`sparkplug_publish_tick_ms`): each pass sends one
    /// DDATA per device with all its changes, so the TPDOs of one SYNC
    /// make one message; the price is this much latency at most.
    pub publish_tick: Duration,
}

impl SparkplugConfig {
    /// The settings for `broker`, group and edge node ID, the rest by
    /// default.
    pub fn new(broker: BrokerUrl, group_id: &str, edge_node_id: &str) -> Self {
        Self {
            broker,
            tls: TlsFiles::default(),
            username: None,
            password: None,
            group_id: group_id.to_string(),
            edge_node_id: edge_node_id.to_string(),
            primary_host: None,
            role: Role::Viewer,
            insecure: false,
            max_command_bytes: DEFAULT_MAX_COMMAND_BYTES,
            max_command_metrics: DEFAULT_MAX_COMMAND_METRICS,
            policy: Policy::default(),
            queue_messages: DEFAULT_QUEUE_MESSAGES,
            spool_file: None,
            node_check: Duration::from_secs(1),
            keep_alive: Duration::from_secs(10),
            publish_tick: DEFAULT_PUBLISH_TICK,
        }
    }

    /// The IDs are topic elements: no `/`, `+` or `#`.
    pub fn validate(&self) -> Result<(), String> {
        for (key, value) in [
            ("sparkplug_group_id", Some(&self.group_id)),
            ("sparkplug_edge_node_id", Some(&self.edge_node_id)),
            ("sparkplug_primary_host", self.primary_host.as_ref()),
        ] {
            if let Some(value) = value
                && !valid_element(value)
            {
                return Err(format!(
                    "{key} '{value}': a Sparkplug ID is not empty and has no '/', '+' or '#'"
                ));
            }
        }
        if self.broker.tls && self.tls.ca_file.is_none() {
            return Err("mqtt_url mqtts://: give mqtt_ca_file (the broker's CA, PEM)".to_string());
        }
        if self.tls.client_cert.is_some() != self.tls.client_key.is_some() {
            return Err("mqtt_client_cert and mqtt_client_key go together".to_string());
        }
        if self.publish_tick > Duration::from_secs(1) {
            return Err("sparkplug_publish_tick_ms: 0 to 1000".to_string());
        }
        if self.queue_messages == 0 {
            return Err("sparkplug_queue_messages: at least 1".to_string());
        }
        if !(64..=MAX_PACKET).contains(&self.max_command_bytes) {
            return Err(format!("sparkplug_max_command_bytes: 64 to {MAX_PACKET}"));
        }
        if !(1..=10_000).contains(&self.max_command_metrics) {
            return Err("sparkplug_max_command_metrics: 1 to 10000".to_string());
        }
        self.command_exposure()?;
        Ok(())
    }

    /// Whether commands are taken at all (`sparkplug_role` above viewer).
    pub fn commands_enabled(&self) -> bool {
        self.role > Role::Viewer
    }

    /// Whether the broker is on this machine (`localhost`, 127.0.0.0/8,
    /// `::1`): nothing of its traffic crosses a network.
    pub fn broker_is_loopback(&self) -> bool {
        let host = self.broker.host.as_str();
        host.eq_ignore_ascii_case("localhost")
            || host
                .parse::<std::net::IpAddr>()
                .is_ok_and(|ip| ip.is_loopback())
    }

    /// The rule for commands, as the REST listener's for tokens: the
    /// broker decides who may publish a command (MQTT carries no sender
    /// identity), so commands are taken only when the edge node logs in
    /// to it (`mqtt_username`, `mqtt_password`) and, on anything but
    /// loopback, over TLS (`mqtts://`); `sparkplug_insecure = true`
    /// overrides. `Ok(Some(warning))`: allowed by that override, to be
    /// logged loudly at start.
    pub fn command_exposure(&self) -> Result<Option<String>, String> {
        if !self.commands_enabled() {
            return Ok(None);
        }
        let mut missing = Vec::new();
        if self.username.is_none() {
            missing.push("broker credentials (mqtt_username, mqtt_password)");
        }
        if !self.broker.tls && !self.broker_is_loopback() {
            missing.push("TLS (an mqtts:// mqtt_url with mqtt_ca_file)");
        }
        if missing.is_empty() {
            return Ok(None);
        }
        let missing = missing.join(" and ");
        let broker = format!("{}:{}", self.broker.host, self.broker.port);
        if self.insecure {
            return Ok(Some(format!(
                "sparkplug_insecure = true: commands (sparkplug_role = \"{}\") are taken from broker {broker} without {missing}: anyone who can publish there may move motors",
                self.role
            )));
        }
        Err(format!(
            "refusing Sparkplug commands (sparkplug_role = \"{}\") from broker {broker} without {missing}: MQTT carries no sender identity, so only the broker (its passwords and ACL) can decide who may send one; configure them, set sparkplug_role = \"viewer\", or set sparkplug_insecure = true",
            self.role
        ))
    }

    /// The MQTT client ID: unique per edge node of a group.
    pub fn client_id(&self) -> String {
        format!("candeck-{}-{}", self.group_id, self.edge_node_id)
    }

    /// Who the commands from MQTT are, in the audit log: the broker
    /// account the edge node logs in with (`mqtt:{mqtt_username}`), else
    /// its client ID. Not the sender: MQTT does not say who published a
    /// command; the broker's ACL decided that it might.
    pub fn who(&self) -> String {
        format!(
            "mqtt:{}",
            self.username.clone().unwrap_or_else(|| self.client_id())
        )
    }
}

/// The host name, the default edge node ID (`sparkplug_edge_node_id`).
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())
        .map(|name| name.trim().replace(['/', '+', '#', '.'], "_"))
        .filter(|name| !name.is_empty())
        .unwrap_or_else(|| "candeck".to_string())
}
