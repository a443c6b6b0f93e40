//! The edge node's session state, sans I/O (Sparkplug 3.0 §5 "Operational
//! Behavior", §6.4 "Payloads"): the birth and death certificates with
//! `bdSeq` (§6.4.18, the will of each MQTT connection and the birth that
//! follows it carry the same number), the message sequence number `seq`
//! (0–255, NBIRTH 0, every later message one more, wrapping; NDEATH none),
//! metric aliases (§6.4.14: named in the births, aliases alone in the data
//! messages) and report by exception with a deadband and a maximum rate per
//! metric.
//!
//! Time comes in: `now_ms` is a monotonic clock (rates), samples carry
//! their own timestamps (milliseconds since 1970).

use std::collections::{BTreeMap, HashMap};

use super::metric::{MetricValue, READ_ONLY, Sample};
use super::proto::payload::{Metric, PropertySet, PropertyValue, property_value};
use super::proto::{DataType, Payload};
use super::topic::{MessageType, Topic};

/// The `bdSeq` metric of NBIRTH and NDEATH (§6.4.18), an Int64 as
/// Sparkplug 3.0 wants it (its value 0–255).
pub const BD_SEQ: &str = "bdSeq";
/// The rebirth request of NCMD (§6.4.19.1: a host writes true).
pub const REBIRTH: &str = "Node Control/Rebirth";

/// How one metric is reported by exception.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reporting {
    /// A number is reported when it moved more than this from the value
    /// last reported (0: on any change).
    pub deadband: f64,
    /// At most one report per this many milliseconds (0: every change);
    /// the newest value of a quicker change is reported when the interval
    /// is up.
    pub min_interval_ms: u64,
}

impl Default for Reporting {
    fn default() -> Self {
        Self {
            deadband: 0.0,
            min_interval_ms: 0,
        }
    }
}

/// A rule for the metrics of one name: the whole metric name
/// (`"Axis 1/Position"`) or its last element (`"Position"`).
#[derive(Debug, Clone, PartialEq)]
pub struct MetricRule {
    pub metric: String,
    pub reporting: Reporting,
}

/// Which reporting each metric gets: the first rule that names it, else
/// the default.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Policy {
    pub default: Reporting,
    pub rules: Vec<MetricRule>,
}

impl Policy {
    pub fn reporting(&self, name: &str) -> Reporting {
        let last = name.rsplit('/').next().unwrap_or(name);
        self.rules
            .iter()
            .find(|rule| rule.metric == name || rule.metric == last)
            .map_or(self.default, |rule| rule.reporting)
    }
}

/// A message for the broker: its topic and payload (serialized with
/// `prost::Message::encode_to_vec` by whoever publishes it).
#[derive(Debug, Clone, PartialEq)]
pub struct Outgoing {
    pub topic: Topic,
    pub payload: Payload,
}

/// One reported metric of a born node or device.
#[derive(Debug, Clone)]
struct Tracked {
    alias: u64,
    reporting: Reporting,
    /// What the host was last told.
    sent: MetricValue,
    /// When (`now_ms`); `None`: in the birth only.
    sent_at: Option<u64>,
    /// A change held back by the maximum rate: the newest one.
    pending: Option<Sample>,
}

impl Tracked {
    /// Whether `value` differs from what was sent by more than the
    /// deadband.
    fn changed(&self, value: &MetricValue) -> bool {
        match (self.sent.as_f64(), value.as_f64()) {
            (Some(sent), Some(new))
                if self.reporting.deadband > 0.0 && self.sent.datatype() == value.datatype() =>
            {
                (new - sent).abs() > self.reporting.deadband
            }
            _ => self.sent != *value,
        }
    }

    /// The `now_ms` from which the next report may go.
    fn free_at(&self) -> u64 {
        self.sent_at
            .map_or(0, |at| at.saturating_add(self.reporting.min_interval_ms))
    }
}

/// The metrics of the edge node or of one device, by name.
#[derive(Debug, Clone, Default)]
struct Table {
    metrics: HashMap<String, Tracked>,
    /// The names by alias (a command may carry the alias alone).
    names: HashMap<u64, String>,
}

impl Table {
    /// How many of its metrics hold a change back.
    fn held(&self) -> usize {
        self.metrics
            .values()
            .filter(|tracked| tracked.pending.is_some())
            .count()
    }
}

/// The edge node's session.
#[derive(Debug, Clone)]
pub struct EdgeSession {
    group: String,
    edge_node: String,
    policy: Policy,
    /// The `bdSeq` of the current (or next) MQTT connection.
    bd_seq: u8,
    /// Whether the broker accepted the CONNECT that carried `bd_seq`: only
    /// then does the next one carry a new number.
    accepted: bool,
    /// The `seq` of the next message.
    seq: u8,
    next_alias: u64,
    node: Table,
    devices: BTreeMap<String, Table>,
    /// How many metrics hold a change back, in all tables: with none (no
    /// maximum rate, or none reached), [`EdgeSession::next_due`] answers
    /// at once instead of looking at every metric of every device.
    held: usize,
}

impl EdgeSession {
    /// A session whose first connection's `bdSeq` is `bd_seq`.
    pub fn new(group: &str, edge_node: &str, bd_seq: u8, policy: Policy) -> Self {
        Self {
            group: group.to_string(),
            edge_node: edge_node.to_string(),
            policy,
            bd_seq,
            accepted: true,
            seq: 0,
            next_alias: 1,
            node: Table::default(),
            devices: BTreeMap::new(),
            held: 0,
        }
    }

    pub fn group(&self) -> &str {
        &self.group
    }

    pub fn edge_node(&self) -> &str {
        &self.edge_node
    }

    /// The `bdSeq` of the current connection.
    pub fn bd_seq(&self) -> u8 {
        self.bd_seq
    }

    /// A new MQTT connection: the next `bdSeq` (0–255, wrapping).
    pub fn next_connection(&mut self) -> u8 {
        self.bd_seq = self.bd_seq.wrapping_add(1);
        self.bd_seq
    }

    /// The `bdSeq` of a CONNECT about to be sent: one more than the last
    /// one the broker accepted; a CONNECT refused or lost before its
    /// CONNACK leaves the number to the next attempt (Sparkplug 3.0: the
    /// number goes up by one per session the broker took).
    pub fn connect_attempt(&mut self) -> u8 {
        if self.accepted {
            self.accepted = false;
            self.next_connection()
        } else {
            self.bd_seq
        }
    }

    /// The broker accepted the CONNECT (its CONNACK came).
    pub fn connection_accepted(&mut self) {
        self.accepted = true;
    }

    /// The topic of a message of the edge node (`device` `None`) or of a
    /// device.
    pub fn topic(&self, kind: MessageType, device: Option<&str>) -> Topic {
        match device {
            Some(device) => Topic::device(&self.group, kind, &self.edge_node, device),
            None => Topic::node(&self.group, kind, &self.edge_node),
        }
    }

    /// The NDEATH of the current connection (its MQTT will, and what a
    /// clean stop publishes): the `bdSeq` alone, no `seq` (§6.4.18).
    pub fn death(&self, now: u64) -> Outgoing {
        let mut bd_seq = Metric {
            name: Some(BD_SEQ.to_string()),
            timestamp: Some(now),
            ..Metric::default()
        };
        MetricValue::Int64(self.bd_seq.into()).fill(&mut bd_seq);
        Outgoing {
            topic: self.topic(MessageType::NDeath, None),
            payload: Payload {
                timestamp: Some(now),
                metrics: vec![bd_seq],
                ..Payload::default()
            },
        }
    }

    /// The NBIRTH: `seq` 0, `bdSeq`, `Node Control/Rebirth` and the edge
    /// node's own `metrics`. Every device is unborn again (their DBIRTHs
    /// follow) and the aliases start over.
    pub fn birth(&mut self, metrics: Vec<Sample>, now: u64) -> Outgoing {
        self.devices.clear();
        self.node = Table::default();
        self.next_alias = 1;
        self.seq = 0;
        let mut all = vec![
            Sample::new(BD_SEQ, MetricValue::Int64(self.bd_seq.into()), now),
            Sample::new(REBIRTH, MetricValue::Boolean(false), now).writable(),
        ];
        all.extend(metrics);
        let metrics = self.register(None, all);
        let mut payload = Payload {
            timestamp: Some(now),
            metrics,
            ..Payload::default()
        };
        self.sequence(&mut payload);
        Outgoing {
            topic: self.topic(MessageType::NBirth, None),
            payload,
        }
    }

    /// A device's DBIRTH with all its `metrics` (again, if it was born:
    /// its aliases are kept for the names it had).
    pub fn device_birth(&mut self, device: &str, metrics: Vec<Sample>, now: u64) -> Outgoing {
        let metrics = self.register(Some(device), metrics);
        let mut payload = Payload {
            timestamp: Some(now),
            metrics,
            ..Payload::default()
        };
        self.sequence(&mut payload);
        Outgoing {
            topic: self.topic(MessageType::DBirth, Some(device)),
            payload,
        }
    }

    /// Whether a device has been born in this session.
    pub fn is_born(&self, device: &str) -> bool {
        self.devices.contains_key(device)
    }

    /// Whether the birth of `device` named the metric `name`.
    pub fn knows(&self, device: &str, name: &str) -> bool {
        self.devices
            .get(device)
            .is_some_and(|table| table.metrics.contains_key(name))
    }

    /// Completes a command's metric as its birth named it (Sparkplug 3.0:
    /// a command carries the alias alone when aliases are in use, and
    /// SHOULD NOT carry the datatype): the name of its alias, and the
    /// datatype of its birth. A metric its birth did not name is left as
    /// it came.
    pub fn complete_command(&self, device: Option<&str>, metric: &mut Metric) {
        let table = match device {
            Some(device) => match self.devices.get(device) {
                Some(table) => table,
                None => return,
            },
            None => &self.node,
        };
        if metric.name.is_none()
            && let Some(name) = metric.alias.and_then(|alias| table.names.get(&alias))
        {
            metric.name = Some(name.clone());
        }
        if metric.datatype.is_none()
            && let Some(tracked) = metric
                .name
                .as_ref()
                .and_then(|name| table.metrics.get(name))
        {
            metric.datatype = Some(tracked.sent.datatype() as u32);
        }
    }

    /// The devices born in this session.
    pub fn born(&self) -> impl Iterator<Item = &str> {
        self.devices.keys().map(String::as_str)
    }

    /// A device's DDEATH; `None` when it was not born.
    pub fn device_death(&mut self, device: &str, now: u64) -> Option<Outgoing> {
        let table = self.devices.remove(device)?;
        self.held -= table.held();
        let mut payload = Payload {
            timestamp: Some(now),
            ..Payload::default()
        };
        self.sequence(&mut payload);
        Some(Outgoing {
            topic: self.topic(MessageType::DDeath, Some(device)),
            payload,
        })
    }

    /// The metrics of `device` (the edge node's own with `None`) that
    /// changed by more than their deadband and whose maximum rate allows,
    /// as an NDATA or DDATA without `seq` ([`EdgeSession::sequence`] gives
    /// it when it is sent); changes held back by the rate wait for
    /// [`EdgeSession::due`]. With `names`, the metrics carry their names as
    /// well as their aliases (a message that may be sent in a later
    /// session, whose aliases may differ). Metrics the births did not name
    /// are left out; `None` when nothing is to be reported.
    pub fn data(
        &mut self,
        device: Option<&str>,
        samples: Vec<Sample>,
        now_ms: u64,
        names: bool,
    ) -> Option<Outgoing> {
        let table = match device {
            Some(device) => self.devices.get_mut(device)?,
            None => &mut self.node,
        };
        let mut metrics = Vec::new();
        for sample in samples {
            let Some(tracked) = table.metrics.get_mut(&sample.name) else {
                continue;
            };
            if !tracked.changed(&sample.value) {
                // Back within the deadband: a held change is void.
                if tracked.pending.take().is_some() {
                    self.held -= 1;
                }
                continue;
            }
            if now_ms < tracked.free_at() {
                if tracked.pending.replace(sample).is_none() {
                    self.held += 1;
                }
                continue;
            }
            if tracked.pending.take().is_some() {
                self.held -= 1;
            }
            metrics.push(report(tracked, sample, now_ms, names));
        }
        self.data_message(device, metrics)
    }

    /// The changes held back by a maximum rate whose interval is up at
    /// `now_ms`, one message per device.
    pub fn due(&mut self, now_ms: u64, names: bool) -> Vec<Outgoing> {
        let mut out = Vec::new();
        if self.held == 0 {
            return out;
        }
        let node = flush(&mut self.node, now_ms, names);
        self.held -= node.len();
        if let Some(message) = self.data_message(None, node) {
            out.push(message);
        }
        let devices: Vec<String> = self.devices.keys().cloned().collect();
        for device in devices {
            let metrics = match self.devices.get_mut(&device) {
                Some(table) => flush(table, now_ms, names),
                None => continue,
            };
            self.held -= metrics.len();
            if let Some(message) = self.data_message(Some(&device), metrics) {
                out.push(message);
            }
        }
        out
    }

    /// When the next held change falls due (`now_ms`), if any.
    pub fn next_due(&self) -> Option<u64> {
        if self.held == 0 {
            return None;
        }
        std::iter::once(&self.node)
            .chain(self.devices.values())
            .flat_map(|table| table.metrics.values())
            .filter(|tracked| tracked.pending.is_some())
            .map(Tracked::free_at)
            .min()
    }

    /// Gives a message the next `seq` (0–255, wrapping).
    pub fn sequence(&mut self, payload: &mut Payload) {
        payload.seq = Some(self.seq.into());
        self.seq = self.seq.wrapping_add(1);
    }

    fn data_message(&self, device: Option<&str>, metrics: Vec<Metric>) -> Option<Outgoing> {
        if metrics.is_empty() {
            return None;
        }
        let kind = if device.is_some() {
            MessageType::DData
        } else {
            MessageType::NData
        };
        let timestamp = metrics.iter().filter_map(|metric| metric.timestamp).max();
        Some(Outgoing {
            topic: self.topic(kind, device),
            payload: Payload {
                timestamp,
                metrics,
                ..Payload::default()
            },
        })
    }

    /// Tracks `samples` as born (a device's table replaced), each named
    /// with its alias.
    fn register(&mut self, device: Option<&str>, samples: Vec<Sample>) -> Vec<Metric> {
        let old = match device {
            Some(device) => self.devices.remove(device).unwrap_or_default(),
            None => {
                // The edge node's metrics get new aliases in each NBIRTH.
                self.held -= self.node.held();
                Table::default()
            }
        };
        self.held -= old.held();
        let mut table = Table::default();
        let mut metrics = Vec::with_capacity(samples.len());
        for sample in samples {
            let alias = match old.metrics.get(&sample.name) {
                Some(tracked) => tracked.alias,
                None => {
                    let alias = self.next_alias;
                    self.next_alias += 1;
                    alias
                }
            };
            let mut metric = Metric {
                name: Some(sample.name.clone()),
                // Sparkplug 3.0: no alias for the rebirth request, so that
                // any host can send it knowing no alias.
                alias: (device.is_some() || sample.name != REBIRTH).then_some(alias),
                timestamp: Some(sample.timestamp),
                properties: Some(read_only(!sample.writable)),
                ..Metric::default()
            };
            sample.value.fill(&mut metric);
            metrics.push(metric);
            table.names.insert(alias, sample.name.clone());
            table.metrics.insert(
                sample.name.clone(),
                Tracked {
                    alias,
                    reporting: self.policy.reporting(&sample.name),
                    sent: sample.value,
                    sent_at: None,
                    pending: None,
                },
            );
        }
        match device {
            Some(device) => {
                self.devices.insert(device.to_string(), table);
            }
            None => self.node = table,
        }
        metrics
    }
}

/// The birth's property of a metric: whether a host may write it.
fn read_only(read_only: bool) -> PropertySet {
    PropertySet {
        keys: vec![READ_ONLY.to_string()],
        values: vec![PropertyValue {
            r#type: Some(DataType::Boolean as u32),
            is_null: None,
            value: Some(property_value::Value::BooleanValue(read_only)),
        }],
    }
}

/// A change reported: remembered as sent at `now_ms`, as its metric.
fn report(tracked: &mut Tracked, sample: Sample, now_ms: u64, names: bool) -> Metric {
    let mut metric = Metric {
        name: names.then(|| sample.name.clone()),
        alias: Some(tracked.alias),
        timestamp: Some(sample.timestamp),
        ..Metric::default()
    };
    sample.value.fill(&mut metric);
    // Sparkplug 3.0: the datatype SHOULD NOT be repeated in NDATA and
    // DDATA (the birth said it).
    metric.datatype = None;
    tracked.sent = sample.value;
    tracked.sent_at = Some(now_ms);
    tracked.pending = None;
    metric
}

/// The held changes of a table whose interval is up.
fn flush(table: &mut Table, now_ms: u64, names: bool) -> Vec<Metric> {
    let mut metrics = Vec::new();
    for tracked in table.metrics.values_mut() {
        if now_ms >= tracked.free_at()
            && let Some(sample) = tracked.pending.take()
        {
            metrics.push(report(tracked, sample, now_ms, names));
        }
    }
    metrics.sort_by_key(|metric| metric.alias);
    metrics
}

/// Rebirth requests coalesced, sans I/O: at most one birth run per
/// `min_interval_ms`; the requests that come sooner make one more run when
/// the interval is up (so that 2,000 forged NCMDs are one or two runs, not
/// 2,000).
#[derive(Debug, Clone)]
pub struct RebirthGate {
    min_interval_ms: u64,
    last_birth: Option<u64>,
    pending: bool,
}

impl RebirthGate {
    pub fn new(min_interval_ms: u64) -> Self {
        Self {
            min_interval_ms,
            last_birth: None,
            pending: false,
        }
    }

    /// A rebirth asked at `now_ms`: true when the births go now, false when
    /// one run is due later ([`RebirthGate::due`]).
    pub fn request(&mut self, now_ms: u64) -> bool {
        if self
            .last_birth
            .is_none_or(|at| now_ms >= at + self.min_interval_ms)
        {
            return true;
        }
        self.pending = true;
        false
    }

    /// A birth run went out at `now_ms` (whatever caused it): it answers
    /// every request before it.
    pub fn born(&mut self, now_ms: u64) {
        self.last_birth = Some(now_ms);
        self.pending = false;
    }

    /// When the coalesced run is due, if one is.
    pub fn due(&self) -> Option<u64> {
        self.pending
            .then(|| self.last_birth.unwrap_or(0) + self.min_interval_ms)
    }
}
