//! The edge node at work: the [`EdgeSession`] fed from the gateway service
//! (the registry's node events, the decoded TPDO values, the buses'
//! states) and connected to the broker with rumqttc. One task owns the
//! session, the MQTT client and the store-and-forward [`Spool`]; the
//! commands run in tasks of their own (an SDO transfer must not hold up
//! the data).
//!
//! Each MQTT connection has its own `bdSeq`: its will is the NDEATH with
//! that number, and the NBIRTH after it carries the same. A connection
//! lost is dropped with its client (nothing half-sent of the old session
//! leaks into the next); the data made meanwhile goes to the spool, and
//! after the next births it is sent in order, historical.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use prost::Message;
use rumqttc::{AsyncClient, Event, EventLoop, LastWill, MqttOptions, Packet, QoS};
use tokio::sync::{Notify, broadcast, mpsc, oneshot};
use tokio::time::Instant;

use super::command::{self, Command, device_id, parse_device, segment_request};
use super::config::SparkplugConfig;
use super::edge::{EdgeSession, Outgoing, RebirthGate};
use super::metric::{MetricValue, Sample};
use super::motion::HeldLeases;
use super::spool::Spool;
use super::topic::{HostVerdict, MessageType, PrimaryHost, Topic, parse_host_state, state_topic};
use crate::canopen::NodeId;
use crate::gateway::EdgeNodeStats;
use crate::gateway::TpdoFrame;
use crate::gateway::object_item;
use crate::gateway::unix_ms;
use crate::gateway::{AuditTarget, DoorDetail, DoorRequest};
use crate::gateway::{Caller, Channel};
use crate::gateway::{Gateway, GatewayError};
use crate::gateway::{Identification, NodeEvent, NodeInfo};

/// How long to wait before connecting again after a connection failed or
/// was lost.
const RECONNECT_AFTER: Duration = Duration::from_secs(1);
/// The shortest time between two birth runs a host asked for (NCMD
/// `Node Control/Rebirth`): requests within it are one more run after it.
const REBIRTH_INTERVAL_MS: u64 = 1000;
/// How many requests the MQTT client queues for its event loop.
const CLIENT_QUEUE: usize = 10_000;

/// The machine state of the NBIRTH metric `Machine State`: the worst of the
/// buses' machines (down, degraded, alarm, booting, ready), as
/// `GET /api/v1/buses/{bus}/machine` gives each, with its alarms; `None`
/// when no bus has a network manager.
pub fn machine_state(gateway: &Gateway) -> Option<String> {
    gateway
        .buses_in_order()
        .iter()
        .filter_map(|bus| gateway.machine_view(bus.name()).ok().map(|view| view.state))
        .min_by_key(|state| state.rank())
        .map(|state| state.name().to_string())
}

/// A running edge node; [`EdgeNode::stop`] publishes its NDEATH and
/// disconnects.
pub struct EdgeNode {
    stop: Option<oneshot::Sender<oneshot::Sender<()>>>,
    task: tokio::task::JoinHandle<()>,
}

impl EdgeNode {
    /// Starts the edge node of `gateway`.
    /// Fails, before anything connects, when the TLS files of `mqtts://`
    /// cannot be read (a missing or bad CA file, client certificate or key)
    /// or the spool file cannot be opened.
    pub fn spawn(gateway: Gateway, config: SparkplugConfig) -> std::io::Result<Self> {
        let tls = if config.broker.tls {
            let tls = super::tls::client_config(&config.tls).map_err(std::io::Error::other)?;
            Some(Arc::new(tls))
        } else {
            None
        };
        let store = |err: std::io::Error| {
            std::io::Error::new(err.kind(), format!("store and forward: {err}"))
        };
        let spool = match &config.spool_file {
            Some(file) => Spool::with_file(config.queue_messages, file.clone()).map_err(store)?,
            None => Spool::new(config.queue_messages),
        };
        let (stop, stopped) = oneshot::channel();
        let stats = gateway.edge_node_stats().clone();
        stats
            .enabled
            .store(true, std::sync::atomic::Ordering::Relaxed);
        let mut runner = Runner::new(gateway, config, spool);
        runner.tls = tls;
        let task = tokio::spawn(runner.run(stopped, None));
        Ok(Self {
            stop: Some(stop),
            task,
        })
    }

    /// Publishes the NDEATH (a clean stop), disconnects, and ends the task
    /// (within `grace` at most).
    pub async fn stop(mut self, grace: Duration) {
        if let Some(stop) = self.stop.take() {
            let (done, finished) = oneshot::channel();
            if stop.send(done).is_ok() {
                let _ = tokio::time::timeout(grace, finished).await;
            }
        }
        self.task.abort();
    }
}

impl Drop for EdgeNode {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// What the feeders tell the runner.
enum Input {
    Node { bus: String, event: NodeEvent },
}

/// The nodes whose TPDO values (or axes, or segments) changed since the
/// runner last looked, and the newest axis and segment metrics of each.
#[derive(Default)]
struct Dirty {
    nodes: Mutex<HashSet<(String, NodeId)>>,
    /// The newest `Axis {n}/...` and `Segments` metrics, by node and name.
    extra: Mutex<HashMap<(String, NodeId), BTreeMap<String, Sample>>>,
    /// Of those, the ones that came since the runner last looked (a pass
    /// takes these, not every axis metric of the node again).
    fresh: Mutex<HashMap<(String, NodeId), BTreeMap<String, Sample>>>,
    /// Changes each reported in the next DDATA, every one, in order (the
    /// NMT states the registry reported).
    reported: Mutex<HashMap<(String, NodeId), Vec<Sample>>>,
    /// Told when a node is marked, and by the buses' TPDO values when a
    /// frame was decoded ([`TpdoValues::follow`]).
    notify: Arc<Notify>,
}

impl Dirty {
    fn mark(&self, key: (String, NodeId)) {
        lock(&self.nodes).insert(key);
        self.notify.notify_one();
    }

    /// Keeps `metrics` as the newest of node `key`, and marks it.
    fn update(&self, key: &(String, NodeId), metrics: Vec<Sample>) {
        let mut fresh = lock(&self.fresh);
        let fresh = fresh.entry(key.clone()).or_default();
        let mut extra = lock(&self.extra);
        let node = extra.entry(key.clone()).or_default();
        for metric in metrics {
            fresh.insert(metric.name.clone(), metric.clone());
            node.insert(metric.name.clone(), metric);
        }
        drop(extra);
        self.mark(key.clone());
    }

    /// Reports `metrics` of node `key` in its next DDATA, each of them
    /// (a change that is no state kept for its births: an NMT state the
    /// registry reported), and marks it.
    fn report(&self, key: &(String, NodeId), metrics: Vec<Sample>) {
        lock(&self.reported)
            .entry(key.clone())
            .or_default()
            .extend(metrics);
        self.mark(key.clone());
    }

    /// The metrics of node `key` that came since the last call: those
    /// reported, in order, then the newest of the others.
    fn take_fresh(&self, key: &(String, NodeId)) -> Vec<Sample> {
        let mut metrics = lock(&self.reported).remove(key).unwrap_or_default();
        if let Some(fresh) = lock(&self.fresh).remove(key) {
            metrics.extend(fresh.into_values());
        }
        metrics
    }

    /// Keeps `metrics` as the newest of node `key` without marking it
    /// (what a birth names, with no DDATA due).
    fn keep(&self, key: &(String, NodeId), metrics: Vec<Sample>) {
        let mut extra = lock(&self.extra);
        let node = extra.entry(key.clone()).or_default();
        for metric in metrics {
            node.insert(metric.name.clone(), metric);
        }
    }

    fn extra(&self, key: &(String, NodeId)) -> Vec<Sample> {
        lock(&self.extra)
            .get(key)
            .map(|metrics| metrics.values().cloned().collect())
            .unwrap_or_default()
    }
}

fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|poison| poison.into_inner())
}

/// How often the axes (state, statusword, position, velocity, fault) and
/// the LED segments are read for their metrics: the stream's topics at
/// this rate (from the TPDOs where the drive sends them, else by SDO at
/// the gateway's `axis_poll_hz` at most).
const AXIS_RATE_HZ: f64 = 10.0;

/// The MQTT connection of the moment. Its event loop runs in a task of
/// its own (rumqttc's `poll` is not to be dropped halfway: a connect cut
/// short would be made again, and the broker would end the first one with
/// its will); the events come over a channel, an error last.
struct Connection {
    client: AsyncClient,
    events: mpsc::Receiver<Result<Event, rumqttc::ConnectionError>>,
    task: tokio::task::JoinHandle<()>,
    /// The CONNACK came.
    connected: bool,
}

impl Connection {
    fn new(client: AsyncClient, mut events: EventLoop) -> Self {
        let (tx, rx) = mpsc::channel(256);
        let task = tokio::spawn(async move {
            loop {
                let event = events.poll().await;
                let failed = event.is_err();
                if tx.send(event).await.is_err() || failed {
                    return;
                }
            }
        });
        Self {
            client,
            events: rx,
            task,
            connected: false,
        }
    }
}

impl Drop for Connection {
    fn drop(&mut self) {
        self.task.abort();
    }
}

struct Runner {
    gateway: Gateway,
    config: SparkplugConfig,
    session: EdgeSession,
    spool: Spool,
    stats: Arc<EdgeNodeStats>,
    dirty: Arc<Dirty>,
    /// Whether the births of the current connection are out (and data is
    /// published rather than queued).
    live: bool,
    /// The primary host's STATE, as the edge node follows it.
    host: PrimaryHost,
    /// The state each bus was last reported in.
    bus_states: BTreeMap<String, String>,
    started: Instant,
    watchers: Vec<tokio::task::JoinHandle<()>>,
    /// Every decoded TPDO frame of each bus, in order, by bus name.
    frames: Vec<(String, broadcast::Receiver<TpdoFrame>)>,
    /// When each device's birth was made: a frame decoded before it is in
    /// the birth's values.
    born_at: HashMap<String, Instant>,
    /// Nodes whose axes or segments are followed.
    followed: HashSet<(String, NodeId)>,
    /// The spool's drops already added to the stats.
    spool_dropped: u64,
    /// The motion leases of moves commanded over MQTT.
    held: Arc<HeldLeases>,
    /// The TLS configuration of `mqtts://`, read once at the start.
    tls: Option<Arc<rustls::ClientConfig>>,
    /// The log lines of refused commands, sampled.
    refusals: Arc<Refusals>,
    /// Rebirth requests, coalesced.
    rebirths: RebirthGate,
}

impl Runner {
    fn new(gateway: Gateway, config: SparkplugConfig, spool: Spool) -> Self {
        let session = EdgeSession::new(
            &config.group_id,
            &config.edge_node_id,
            // The first connection's is 0: one more per accepted CONNECT.
            u8::MAX,
            config.policy.clone(),
        );
        let stats = gateway.edge_node_stats().clone();
        Self {
            host: PrimaryHost::default(),
            gateway,
            config,
            session,
            spool,
            stats,
            dirty: Arc::new(Dirty::default()),
            live: false,
            bus_states: BTreeMap::new(),
            started: Instant::now(),
            watchers: Vec::new(),
            frames: Vec::new(),
            born_at: HashMap::new(),
            followed: HashSet::new(),
            spool_dropped: 0,
            held: Arc::new(HeldLeases::default()),
            tls: None,
            refusals: Arc::new(Refusals::default()),
            rebirths: RebirthGate::new(REBIRTH_INTERVAL_MS),
        }
    }

    fn now_ms(&self) -> u64 {
        self.started.elapsed().as_millis() as u64
    }

    /// The edge node's loop; `connection`: one made already (a test's),
    /// else the runner connects.
    async fn run(
        mut self,
        mut stop: oneshot::Receiver<oneshot::Sender<()>>,
        mut connection: Option<Connection>,
    ) {
        let (inputs, mut input) = mpsc::channel::<Input>(1024);
        for bus in self.gateway.buses() {
            let mut events = bus.node_events();
            let inputs = inputs.clone();
            let name = bus.name().to_string();
            self.watchers.push(tokio::spawn(async move {
                loop {
                    match events.recv().await {
                        Ok(event) => {
                            if inputs
                                .send(Input::Node {
                                    bus: name.clone(),
                                    event,
                                })
                                .await
                                .is_err()
                            {
                                return;
                            }
                        }
                        Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => continue,
                        Err(tokio::sync::broadcast::error::RecvError::Closed) => return,
                    }
                }
            }));
        }
        drop(inputs);
        self.watchers.push(self.follow_alarms());
        for bus in self.gateway.buses_in_order() {
            let frames = bus.values().follow(self.dirty.notify.clone());
            self.frames.push((bus.name().to_string(), frames));
        }
        let mut reconnect_at = Instant::now();
        let mut last_values = Instant::now();
        let mut values_at: Option<Instant> = None;
        let mut node_check = tokio::time::interval(self.config.node_check);
        node_check.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            if connection.is_none() && Instant::now() >= reconnect_at {
                connection = Some(self.connect());
            }
            let due = self
                .session
                .next_due()
                .map(|at| self.started + Duration::from_millis(at));
            let dirty = self.dirty.clone();
            let rebirth_at = self
                .rebirths
                .due()
                .map(|at| self.started + Duration::from_millis(at));
            tokio::select! {
                biased;
                stopped = &mut stop => {
                    if let Some(connection) = connection.as_mut() {
                        self.clean_stop(connection).await;
                    }
                    if let Ok(done) = stopped {
                        let _ = done.send(());
                    }
                    break;
                }
                event = poll(&mut connection) => {
                    if let Err(err) = self.on_mqtt(&mut connection, event).await {
                        tracing::warn!("sparkplug: broker {}:{}: {err}", self.config.broker.host, self.config.broker.port);
                        connection = None;
                        self.disconnected();
                        reconnect_at = Instant::now() + RECONNECT_AFTER;
                    }
                }
                Some(Input::Node { bus, event }) = input.recv() => {
                    self.on_node_event(&mut connection, &bus, event);
                }
                // At most one pass per tick, and every DDATA in a pass: what
                // changes meanwhile (the TPDOs of a SYNC, an NMT state, a
                // change a maximum rate held back) goes in the next one, one
                // DDATA per device per tick.
                () = dirty.notify.notified(), if values_at.is_none() => {
                    let at = last_values + self.config.publish_tick;
                    if Instant::now() >= at {
                        last_values = Instant::now();
                        self.on_values(&mut connection);
                    } else {
                        values_at = Some(at);
                    }
                }
                () = sleep_until(due), if values_at.is_none() => {
                    let at = (last_values + self.config.publish_tick).max(Instant::now());
                    values_at = Some(at);
                }
                () = sleep_until(values_at) => {
                    values_at = None;
                    last_values = Instant::now();
                    self.on_values(&mut connection);
                }
                _ = node_check.tick() => {
                    self.check_buses(&mut connection);
                }
                () = tokio::time::sleep_until(reconnect_at), if connection.is_none() => {}
                () = sleep_until(rebirth_at) => {
                    // The rebirths asked within the interval: one run.
                    self.rebirths.born(self.now_ms());
                    if self.host_online() {
                        self.go_live(&mut connection);
                    }
                }
            }
        }
        for watcher in self.watchers.drain(..) {
            watcher.abort();
        }
    }

    /// A new MQTT connection, its will the NDEATH of the next `bdSeq`.
    fn connect(&mut self) -> Connection {
        let bd_seq = self.session.connect_attempt();
        let config = &self.config;
        let mut options = MqttOptions::new(
            config.client_id(),
            config.broker.host.clone(),
            config.broker.port,
        );
        options.set_keep_alive(config.keep_alive);
        // Sparkplug 3.0 §7.1: a clean session for edge nodes.
        options.set_clean_session(true);
        // Any packet the broker delivers is read (rumqttc ends the
        // connection over one beyond its limit: a 20 MB DCMD from anyone
        // would end the session); a command over max_command_bytes is
        // refused after it is read.
        options.set_max_packet_size(super::config::MAX_PACKET, 16 * 1024 * 1024);
        if let Some(user) = &config.username {
            options.set_credentials(user.clone(), config.password.clone().unwrap_or_default());
        }
        if let Some(tls) = &self.tls {
            options.set_transport(rumqttc::Transport::tls_with_config(
                rumqttc::TlsConfiguration::Rustls(tls.clone()),
            ));
        }
        let death = self.session.death(unix_ms());
        options.set_last_will(LastWill::new(
            death.topic.to_string(),
            death.payload.encode_to_vec(),
            QoS::AtLeastOnce,
            false,
        ));
        tracing::debug!("sparkplug: connecting with bdSeq {bd_seq}");
        let (client, events) = AsyncClient::new(options, CLIENT_QUEUE);
        Connection::new(client, events)
    }

    fn disconnected(&mut self) {
        self.live = false;
        // The host can renew nothing now: the motion it commanded stops.
        self.held
            .lapse_all(&self.gateway, "the broker connection is gone");
        // The primary host's state is learnt anew on the next connection
        // (its retained STATE, or its next message), against the newest
        // timestamp seen.
        self.host.connection_lost();
        self.stats
            .connected
            .store(false, std::sync::atomic::Ordering::Relaxed);
        self.stats
            .publishing
            .store(false, std::sync::atomic::Ordering::Relaxed);
    }

    /// What the broker sent, or the connection's error.
    async fn on_mqtt(
        &mut self,
        connection: &mut Option<Connection>,
        event: Result<Event, rumqttc::ConnectionError>,
    ) -> Result<(), rumqttc::ConnectionError> {
        match event? {
            Event::Incoming(Packet::ConnAck(_)) => {
                if let Some(conn) = connection.as_mut() {
                    conn.connected = true;
                    self.session.connection_accepted();
                    self.stats
                        .connected
                        .store(true, std::sync::atomic::Ordering::Relaxed);
                    EdgeNodeStats::add(&self.stats.connects, 1);
                    tracing::info!(
                        "sparkplug: connected to {}:{} as edge node {}/{} (bdSeq {})",
                        self.config.broker.host,
                        self.config.broker.port,
                        self.config.group_id,
                        self.config.edge_node_id,
                        self.session.bd_seq()
                    );
                    let group = &self.config.group_id;
                    let node = &self.config.edge_node_id;
                    let mut topics = vec![
                        Topic::node(group, MessageType::NCmd, node).to_string(),
                        format!("spBv1.0/{group}/DCMD/{node}/+"),
                    ];
                    if let Some(host) = &self.config.primary_host {
                        topics.push(state_topic(host));
                    }
                    for topic in topics {
                        let _ = conn.client.try_subscribe(topic, QoS::AtLeastOnce);
                    }
                }
                if self.host_online() {
                    self.go_live(connection);
                }
            }
            Event::Incoming(Packet::Publish(publish)) => {
                if self.on_publish(connection, &publish.topic, &publish.payload)
                    == Some(HostVerdict::WentOffline)
                    && let Some(conn) = connection.as_mut()
                {
                    // Sparkplug 3.0: NDEATH, disconnect, and start over
                    // (the next connection waits for the host's STATE).
                    self.end_session(conn, "the primary host went offline")
                        .await;
                    *connection = None;
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// Whether data may be published: no primary host, or it is online.
    fn host_online(&self) -> bool {
        self.config.primary_host.is_none() || self.host.online()
    }

    /// A message from the broker: the primary host's STATE (what it meant
    /// is returned), or a command.
    fn on_publish(
        &mut self,
        connection: &mut Option<Connection>,
        topic: &str,
        payload: &[u8],
    ) -> Option<HostVerdict> {
        if let Some(host) = &self.config.primary_host
            && topic == state_topic(host)
        {
            let Some(state) = parse_host_state(payload) else {
                tracing::warn!("sparkplug: {topic}: not a STATE payload");
                return None;
            };
            let verdict = self.host.on_state(state);
            match verdict {
                HostVerdict::Stale => tracing::info!(
                    "sparkplug: primary host {host}: a STATE older than the newest (timestamp {:?}) ignored",
                    state.timestamp
                ),
                HostVerdict::CameOnline => {
                    tracing::info!("sparkplug: primary host {host} is online");
                    // Sparkplug 3.0: (re)birth when the host comes (back).
                    self.go_live(connection);
                }
                HostVerdict::WentOffline => {
                    tracing::info!("sparkplug: primary host {host} is offline");
                }
                HostVerdict::StillOnline | HostVerdict::StillOffline => {}
            }
            return Some(verdict);
        }
        let topic = Topic::parse(topic)?;
        if !matches!(topic.kind, MessageType::NCmd | MessageType::DCmd) {
            return None;
        }
        if let Some(refused) = oversized(&self.config, payload.len()) {
            self.refuse(topic, refused);
            return None;
        }
        let Ok(mut payload) = super::proto::Payload::decode(payload) else {
            self.refuse(
                topic,
                GatewayError::InvalidRequest("not a Sparkplug B payload".to_string()),
            );
            return None;
        };
        if payload.metrics.len() > self.config.max_command_metrics {
            self.refuse(
                topic,
                GatewayError::TooManyEntries(format!(
                    "{} metrics: over sparkplug_max_command_metrics ({})",
                    payload.metrics.len(),
                    self.config.max_command_metrics
                )),
            );
            return None;
        }
        // Alias-only metrics without a datatype, as the spec wants them:
        // named and typed by their birth.
        for metric in &mut payload.metrics {
            self.session
                .complete_command(topic.device.as_deref(), metric);
        }
        let device = topic.kind == MessageType::DCmd;
        let summary = command::summary(&payload.metrics);
        let mut commands = Vec::new();
        for command in command::parse(&payload, device) {
            EdgeNodeStats::add(&self.stats.commands, 1);
            if command == Command::Rebirth {
                tracing::debug!("sparkplug: rebirth asked");
                if self.host_online() && self.rebirths.request(self.now_ms()) {
                    self.go_live(connection);
                }
                continue;
            }
            commands.push(command);
        }
        if commands.is_empty() {
            return None;
        }
        // The commands of one message run in order (a move after the state
        // change that enables its axis), in a task of their own, one audit
        // row for them all.
        let gateway = self.gateway.clone();
        let config = self.config.clone();
        let stats = self.stats.clone();
        let held = self.held.clone();
        let refusals = self.refusals.clone();
        tokio::spawn(async move {
            let results = run_message(&gateway, &config, &held, &topic, &commands, summary).await;
            for (command, result) in commands.iter().zip(results) {
                if let Err(err) = result {
                    EdgeNodeStats::add(&stats.commands_failed, 1);
                    refusals.warn(&format!("{topic}: {}: {err}", command.operation()));
                }
            }
        });
        None
    }

    /// A command message refused whole (too large, too many metrics, not a
    /// payload): counted, its one audit row written (the error's code its
    /// outcome, its text the request), sampled in the log; nothing of it
    /// runs, and the session is untouched.
    fn refuse(&mut self, topic: Topic, error: GatewayError) {
        EdgeNodeStats::add(&self.stats.commands_failed, 1);
        // The setting to look at, for whoever reads the log.
        let setting = match &error {
            GatewayError::CommandTooLarge { .. } => " (sparkplug_max_command_bytes)",
            _ => "",
        };
        self.refusals
            .warn(&format!("{topic}: refused: {error}{setting}"));
        let gateway = self.gateway.clone();
        let config = self.config.clone();
        tokio::spawn(async move {
            let _ = refuse_message(&gateway, &config, &topic, error).await;
        });
    }

    /// The births (NBIRTH, a DBIRTH per identified node online), then the
    /// queued data, historical; from then on data is published.
    fn go_live(&mut self, connection: &mut Option<Connection>) {
        if !connection.as_ref().is_some_and(|conn| conn.connected) {
            return;
        }
        // The changes not yet taken belong to the session the births end:
        // taken now, they go out before the births (or, offline, to the
        // spool, sent after them as historical), not lost with the old
        // session's devices.
        self.on_values(connection);
        let now = unix_ms();
        self.rebirths.born(self.now_ms());
        let metrics = self.node_metrics(now);
        let birth = self.session.birth(metrics, now);
        self.live = true;
        self.stats
            .publishing
            .store(true, std::sync::atomic::Ordering::Relaxed);
        self.publish(connection, birth);
        for bus in self.gateway.buses_in_order() {
            for info in bus.nodes() {
                if born_device(&info) {
                    let message = self.device_birth(bus.name(), &info);
                    self.publish(connection, message);
                }
            }
        }
        self.send_history(connection);
    }

    /// The queued data whose births are out (the edge node's, and those of
    /// the devices born in this session), historical, in order; a device's
    /// waits for its DBIRTH (after a restart, a node is identified after the
    /// NBIRTH: its history must not come before the birth that names it).
    fn send_history(&mut self, connection: &mut Option<Connection>) {
        if !self.live || self.spool.is_empty() {
            return;
        }
        let session = &self.session;
        let queued = self.spool.drain_where(|topic| {
            topic
                .device
                .as_deref()
                .is_none_or(|device| session.is_born(device))
        });
        EdgeNodeStats::add(&self.stats.historical, queued.len() as u64);
        self.stats.queued.store(
            self.spool.len() as u64,
            std::sync::atomic::Ordering::Relaxed,
        );
        for mut message in queued {
            self.session.sequence(&mut message.payload);
            self.publish(connection, message);
        }
    }

    /// The edge node's own metrics: version, buses and their states, the
    /// machine state when the gateway has one.
    fn node_metrics(&mut self, now: u64) -> Vec<Sample> {
        let mut metrics = vec![Sample::new(
            "Properties/Version",
            MetricValue::String(env!("CARGO_PKG_VERSION").to_string()),
            now,
        )];
        metrics.push(Sample::new(
            "Properties/Lease Period",
            MetricValue::UInt32(self.gateway.lease_period().as_millis() as u32),
            now,
        ));
        if let Some(state) = machine_state(&self.gateway) {
            metrics.push(Sample::new(
                "Machine State",
                MetricValue::String(state),
                now,
            ));
        }
        for bus in self.gateway.buses_in_order() {
            let state = bus.status().state.as_str().to_string();
            metrics.push(Sample::new(
                format!("Buses/{}/State", bus.name()),
                MetricValue::String(state.clone()),
                now,
            ));
            metrics.push(Sample::new(
                format!("Buses/{}/Spec", bus.name()),
                MetricValue::String(bus.spec().to_string()),
                now,
            ));
            self.bus_states.insert(bus.name().to_string(), state);
        }
        metrics
    }

    /// The buses' states (and the machine state), NDATA when they changed.
    fn check_buses(&mut self, connection: &mut Option<Connection>) {
        let now = unix_ms();
        let mut samples = Vec::new();
        for bus in self.gateway.buses_in_order() {
            let state = bus.status().state.as_str().to_string();
            if self.bus_states.get(bus.name()) != Some(&state) {
                self.bus_states
                    .insert(bus.name().to_string(), state.clone());
                samples.push(Sample::new(
                    format!("Buses/{}/State", bus.name()),
                    MetricValue::String(state),
                    now,
                ));
            }
        }
        if let Some(state) = machine_state(&self.gateway) {
            samples.push(Sample::new(
                "Machine State",
                MetricValue::String(state),
                now,
            ));
        }
        if samples.is_empty() {
            return;
        }
        let names = !self.live;
        if let Some(message) = self.session.data(None, samples, self.now_ms(), names) {
            self.send_data(connection, message);
        }
    }

    /// A node's DBIRTH: online, NMT state, identity, every TPDO-mapped
    /// value by its EDS name, typed.
    fn device_birth(&mut self, bus: &str, info: &NodeInfo) -> Outgoing {
        let now = unix_ms();
        let mut metrics = vec![
            Sample::new("Online", MetricValue::Boolean(info.online), now),
            Sample::new(
                "NMT State",
                MetricValue::String(info.nmt.map_or("unknown", |state| state.name()).to_string()),
                now,
            ),
            Sample::new(
                "Profile",
                MetricValue::String(info.profile.name().to_string()),
                now,
            ),
        ];
        if let Some(name) = &info.name {
            metrics.push(Sample::new(
                "Identity/Device Name",
                MetricValue::String(name.clone()),
                now,
            ));
        }
        if let Some(eds) = &info.eds {
            metrics.push(Sample::new(
                "Identity/EDS",
                MetricValue::String(eds.clone()),
                now,
            ));
        }
        if let Some(identity) = &info.identity {
            metrics.push(Sample::new(
                "Identity/Vendor ID",
                MetricValue::UInt32(identity.vendor_id),
                now,
            ));
            for (name, value) in [
                ("Identity/Product Code", identity.product_code),
                ("Identity/Revision", identity.revision),
                ("Identity/Serial Number", identity.serial),
            ] {
                let value = value.map_or(
                    MetricValue::Null(super::proto::DataType::UInt32),
                    MetricValue::UInt32,
                );
                metrics.push(Sample::new(name, value, now));
            }
        }
        self.follow_profile(bus, info);
        let key = (bus.to_string(), info.id);
        let alarms = self
            .gateway
            .alarm_book()
            .summary(Some(bus), Some(info.id.get()));
        self.dirty.keep(&key, alarm_samples(&alarms, now));
        metrics.extend(self.dirty.extra(&key));
        if let Ok(served) = self.gateway.bus(bus) {
            let values = tpdo_samples(&served.values().values(info.id));
            // Mapped values that have not come yet: null, typed by the
            // mapping (their first frame is a DDATA).
            if let Some(tpdos) = served.values().tpdos(info.id) {
                for (_, decoder) in &tpdos.decoders {
                    let Ok(fields) = decoder.decode(&[0; 8]) else {
                        continue;
                    };
                    for field in fields {
                        let name = format!(
                            "TPDO/{}",
                            field.name.clone().unwrap_or_else(|| format!(
                                "{}:{}",
                                crate::canopen::od::format_index(field.entry.index),
                                field.entry.sub
                            ))
                        );
                        if values.iter().any(|sample| sample.name == name) {
                            continue;
                        }
                        let datatype = field
                            .value
                            .as_ref()
                            .map_or(super::proto::DataType::UInt64, |value| {
                                MetricValue::from_canopen(value).datatype()
                            });
                        metrics.push(Sample::new(name, MetricValue::Null(datatype), now));
                    }
                }
            }
            metrics.extend(values);
        }
        metrics.extend(command_samples(info, now));
        let device = device_id(bus, info.id.get());
        self.born_at.insert(device.clone(), Instant::now());
        self.session.device_birth(&device, one_each(metrics), now)
    }

    fn on_node_event(&mut self, connection: &mut Option<Connection>, bus: &str, event: NodeEvent) {
        let node = event.node();
        let device = device_id(bus, node.get());
        let Some(info) = self
            .gateway
            .bus(bus)
            .ok()
            .and_then(|served| served.node(node))
        else {
            return;
        };
        if !self.live {
            // The births of the next session will say it.
            return;
        }
        match event {
            // One DBIRTH per device per birth run: a node born already (by
            // the births of this session) is not born again for the events
            // of its identification.
            NodeEvent::Identified { .. } | NodeEvent::Online { .. }
                if born_device(&info) && !self.session.is_born(&device) =>
            {
                let message = self.device_birth(bus, &info);
                self.publish(connection, message);
                self.send_history(connection);
            }
            NodeEvent::Identified { .. } | NodeEvent::Online { .. } => {}
            NodeEvent::Offline { .. } => {
                if let Some(message) = self.session.device_death(&device, unix_ms()) {
                    self.publish(connection, message);
                }
            }
            NodeEvent::NmtChanged { to, .. } => {
                // In the device's DDATA of the next pass, with its other
                // changes.
                let sample = Sample::new(
                    "NMT State",
                    MetricValue::String(to.name().to_string()),
                    unix_ms(),
                );
                self.dirty.report(&(bus.to_string(), node), vec![sample]);
            }
            _ => {}
        }
    }

    /// Follows the alarms: each change's node gets its `Alarms/...`
    /// metrics again (a DDATA).
    fn follow_alarms(&self) -> tokio::task::JoinHandle<()> {
        let alarms = self.gateway.alarm_book().clone();
        let mut changes = alarms.subscribe();
        let dirty = self.dirty.clone();
        let gateway = self.gateway.clone();
        tokio::spawn(async move {
            use tokio::sync::broadcast::error::RecvError;
            loop {
                let nodes: Vec<(String, u8)> = match changes.recv().await {
                    Ok(change) => change
                        .alarm
                        .node
                        .map(|node| (change.alarm.bus.clone(), node))
                        .into_iter()
                        .collect(),
                    // Every node's metrics again.
                    Err(RecvError::Lagged(_)) => gateway
                        .buses()
                        .flat_map(|bus| {
                            let name = bus.name().to_string();
                            bus.nodes()
                                .into_iter()
                                .map(move |info| (name.clone(), info.id.get()))
                        })
                        .collect(),
                    Err(RecvError::Closed) => return,
                };
                for (bus, node) in nodes {
                    let Ok(id) = NodeId::new(node) else {
                        continue;
                    };
                    let summary = alarms.summary(Some(&bus), Some(node));
                    dirty.update(&(bus, id), alarm_samples(&summary, unix_ms()));
                }
            }
        })
    }

    /// Follows a drive's axes and an LED controller's segments (once per
    /// node): their metrics go to [`Dirty::extra`].
    fn follow_profile(&mut self, bus: &str, info: &NodeInfo) {
        let key = (bus.to_string(), info.id);
        if !self.followed.insert(key.clone()) {
            return;
        }
        let Ok(served) = self.gateway.bus(bus) else {
            return;
        };
        if let Some(kind) = crate::gateway::DriveKind::from_profile(info.profile) {
            for axis in 1..=crate::gateway::axis_count(kind, info.eds_entry.as_deref()) {
                let Ok(mut topic) = served.axes().subscribe(info.id, axis, AXIS_RATE_HZ) else {
                    break;
                };
                let dirty = self.dirty.clone();
                let key = key.clone();
                self.watchers.push(tokio::spawn(async move {
                    while let Some(sample) = topic.changed().await {
                        let now = unix_ms();
                        let metrics = axis_samples(axis, &sample.data, now);
                        if metrics.is_empty() {
                            continue;
                        }
                        dirty.update(&key, metrics);
                    }
                }));
            }
        } else if info.profile == crate::gateway::Profile::Uioled {
            let Ok(mut topic) = served.previews().subscribe(info.id, 1.0) else {
                return;
            };
            let dirty = self.dirty.clone();
            self.watchers.push(tokio::spawn(async move {
                while let Some(sample) = topic.changed().await {
                    let Some(segments) = sample.data.get("segments") else {
                        continue;
                    };
                    let metric = Sample::new(
                        "Segments",
                        MetricValue::String(segments.to_string()),
                        unix_ms(),
                    );
                    dirty.update(&key, vec![metric]);
                }
            }));
        }
    }

    /// A pass: every TPDO change since the last pass, in order, the axes'
    /// and segments' newest metrics, the NMT states reported and the
    /// changes a maximum rate held back whose interval is up, as ONE DDATA
    /// per device (a metric that changed twice is in it twice, in order,
    /// each change with its frame's timestamp, as Sparkplug allows); a
    /// DBIRTH again for a node with a value its birth did not name (its
    /// mapping was read since). A bus whose frames came faster than this
    /// pass could take them has its devices' newest values reported
    /// instead, the frames lost counted.
    fn on_values(&mut self, connection: &mut Option<Connection>) {
        let names = !self.live;
        let mut out = PassOut::default();
        for message in self.session.due(self.now_ms(), names) {
            out.add(message);
        }
        let mut changes: BTreeMap<(usize, NodeId), Vec<TpdoFrame>> = BTreeMap::new();
        let mut behind = HashSet::new();
        for (at, (_, frames)) in self.frames.iter_mut().enumerate() {
            loop {
                match frames.try_recv() {
                    Ok(frame) => changes.entry((at, frame.node)).or_default().push(frame),
                    Err(broadcast::error::TryRecvError::Lagged(lost)) => {
                        EdgeNodeStats::add(&self.stats.lost_changes, lost);
                        behind.insert(at);
                    }
                    Err(
                        broadcast::error::TryRecvError::Empty
                        | broadcast::error::TryRecvError::Closed,
                    ) => break,
                }
            }
        }
        let mut marked: BTreeSet<(usize, NodeId)> = lock(&self.dirty.nodes)
            .drain()
            .filter_map(|(bus, node)| {
                let at = self.frames.iter().position(|(name, _)| *name == bus)?;
                Some((at, node))
            })
            .collect();
        marked.extend(changes.keys().copied());
        for &at in &behind {
            let bus = &self.frames[at].0;
            if let Ok(served) = self.gateway.bus(bus) {
                marked.extend(served.nodes().iter().map(|info| (at, info.id)));
            }
        }
        for (at, node) in marked {
            let bus = self.frames[at].0.clone();
            let device = device_id(&bus, node.get());
            if !self.session.is_born(&device) {
                continue;
            }
            let Ok(served) = self.gateway.bus(&bus) else {
                continue;
            };
            let mut batches: Vec<Vec<Sample>> = if behind.contains(&at) {
                vec![tpdo_samples(&served.values().values(node))]
            } else {
                let born_at = self.born_at.get(&device).copied();
                changes
                    .remove(&(at, node))
                    .unwrap_or_default()
                    .iter()
                    .filter(|frame| {
                        born_at.is_none_or(|born| frame.values.iter().any(|value| value.at > born))
                    })
                    .map(|frame| tpdo_samples(&frame.values))
                    .collect()
            };
            batches.push(self.dirty.take_fresh(&(bus.clone(), node)));
            if self.live
                && batches
                    .iter()
                    .flatten()
                    .any(|sample| !self.session.knows(&device, &sample.name))
            {
                if let Some(info) = served.node(node) {
                    let message = self.device_birth(&bus, &info);
                    self.publish(connection, message);
                    self.send_history(connection);
                }
                continue;
            }
            let samples: Vec<Sample> = batches.into_iter().flatten().collect();
            if let Some(message) = self
                .session
                .data(Some(&device), samples, self.now_ms(), names)
            {
                out.add(message);
            }
        }
        for message in out.messages {
            self.send_data(connection, message);
        }
    }

    /// A data message: published when live, else queued.
    fn send_data(&mut self, connection: &mut Option<Connection>, mut message: Outgoing) {
        if self.live {
            self.session.sequence(&mut message.payload);
            self.publish(connection, message);
        } else {
            self.spool.push(message);
            self.stats.queued.store(
                self.spool.len() as u64,
                std::sync::atomic::Ordering::Relaxed,
            );
            let dropped = self.spool.dropped();
            EdgeNodeStats::add(&self.stats.dropped, dropped - self.spool_dropped);
            self.spool_dropped = dropped;
        }
    }

    fn publish(&mut self, connection: &mut Option<Connection>, message: Outgoing) {
        let Some(conn) = connection.as_mut() else {
            return;
        };
        let metrics = message.payload.metrics.len() as u64;
        let bytes = message.payload.encode_to_vec();
        match conn
            .client
            .try_publish(message.topic.to_string(), QoS::AtMostOnce, false, bytes)
        {
            Ok(()) => {
                EdgeNodeStats::add(&self.stats.messages, 1);
                EdgeNodeStats::add(&self.stats.metrics, metrics);
            }
            // The client's queue is full (the broker does not keep up):
            // counted as dropped, as the spool's are.
            Err(err) => {
                EdgeNodeStats::add(&self.stats.dropped, 1);
                tracing::debug!("sparkplug: {}: not published: {err}", message.topic);
            }
        }
    }

    /// The NDEATH of a clean stop (the will is not sent on a clean
    /// DISCONNECT), then DISCONNECT, the client's queue flushed.
    async fn clean_stop(&mut self, connection: &mut Connection) {
        self.end_session(connection, "the edge node stops").await;
    }

    /// Ends the session: every lease granted over MQTT lapses, the NDEATH
    /// is published (a clean DISCONNECT sends no will), then DISCONNECT,
    /// the client's queue flushed (2 s at most).
    async fn end_session(&mut self, connection: &mut Connection, why: &str) {
        self.held.lapse_all(&self.gateway, why);
        if connection.connected {
            let death = self.session.death(unix_ms());
            let _ = connection.client.try_publish(
                death.topic.to_string(),
                QoS::AtLeastOnce,
                false,
                death.payload.encode_to_vec(),
            );
            let _ = connection.client.try_disconnect();
            let flushed = async {
                loop {
                    match connection.events.recv().await {
                        Some(Ok(Event::Outgoing(rumqttc::Outgoing::Disconnect)))
                        | Some(Err(_))
                        | None => break,
                        Some(Ok(_)) => {}
                    }
                }
            };
            let _ = tokio::time::timeout(Duration::from_secs(2), flushed).await;
        }
        self.disconnected();
    }
}

/// A device's alarm metrics (born in its DBIRTH, a DDATA on each change):
/// `Alarms/Active` and `Alarms/Unacknowledged` (counts), `Alarms/Highest
/// Severity` (`critical`, `high`, `medium`, `low`, or `none`) of the
/// alarms that are not `normal`, so that a SCADA host can alarm on them.
pub(super) fn alarm_samples(summary: &crate::gateway::AlarmSummary, now: u64) -> Vec<Sample> {
    vec![
        Sample::new(
            "Alarms/Active",
            MetricValue::UInt32(summary.active_total()),
            now,
        ),
        Sample::new(
            "Alarms/Unacknowledged",
            MetricValue::UInt32(summary.unacknowledged_total()),
            now,
        ),
        Sample::new(
            "Alarms/Highest Severity",
            MetricValue::String(
                summary
                    .highest
                    .map_or("none", crate::gateway::Severity::name)
                    .to_string(),
            ),
            now,
        ),
    ]
}

/// The metrics a host may write to a device (docs/sparkplug.md,
/// "Commands"), born typed and writable, null until read: `NMT`; each
/// writable object of its EDS as `OD/0xIIII:S`; a drive's `Axis {n}/...`
/// commands, and its read metrics, typed before their first value comes;
/// an LED controller's `Segment {n}/...`.
pub(crate) fn command_samples(info: &NodeInfo, now: u64) -> Vec<Sample> {
    use super::proto::DataType;
    let null =
        |name: String, datatype: DataType| Sample::new(name, MetricValue::Null(datatype), now);
    let mut metrics = vec![null("NMT".to_string(), DataType::String).writable()];
    if let Some(entry) = &info.eds_entry {
        for (object, sub) in entry.eds.dictionary.subs() {
            if !sub.access.is_writable() {
                continue;
            }
            let Some(zero) = crate::canopen::od::Value::zero(sub.data_type) else {
                continue;
            };
            let datatype = MetricValue::from_canopen(&zero).datatype();
            metrics.push(
                null(
                    format!("OD/0x{:04X}:{}", object.index, sub.sub_index),
                    datatype,
                )
                .writable(),
            );
        }
    }
    if let Some(kind) = crate::gateway::DriveKind::from_profile(info.profile) {
        for axis in 1..=crate::gateway::axis_count(kind, info.eds_entry.as_deref()) {
            let name = |what: &str| format!("Axis {axis}/{what}");
            metrics.extend([
                null(name("State"), DataType::String).writable(),
                null(name("Statusword"), DataType::UInt16),
                null(name("Position"), DataType::Int32),
                null(name("Velocity"), DataType::Int32),
                null(name("Fault"), DataType::Boolean),
                null(name("Halt"), DataType::Boolean).writable(),
                null(name("Fault Reset"), DataType::Boolean).writable(),
                null(name("Move"), DataType::String).writable(),
                null(name("Lease"), DataType::Boolean).writable(),
                null(name("Lease Id"), DataType::String).writable(),
            ]);
        }
    } else if info.profile == crate::gateway::Profile::Uioled {
        for segment in 1..=crate::profiles::uioled::SEGMENTS {
            let name = |what: &str| format!("Segment {segment}/{what}");
            metrics.push(null(name("Effect"), DataType::String).writable());
            for color in 1..=3 {
                metrics.push(null(name(&format!("Color {color}")), DataType::String).writable());
            }
            for field in [
                "Led Count",
                "Dimmer",
                "Value",
                "Min Value",
                "Max Value",
                "Speed",
                "Smooth",
            ] {
                metrics.push(null(name(field), DataType::Int32).writable());
            }
        }
    }
    metrics
}

/// A birth's metrics, one of each name: a value read stands for the null
/// that typed it beforehand, and a command metric stays writable.
fn one_each(metrics: Vec<Sample>) -> Vec<Sample> {
    let mut at: HashMap<String, usize> = HashMap::with_capacity(metrics.len());
    let mut out: Vec<Sample> = Vec::with_capacity(metrics.len());
    for sample in metrics {
        match at.get(&sample.name) {
            Some(&i) => {
                let kept = &mut out[i];
                let writable = kept.writable || sample.writable;
                if !matches!(sample.value, MetricValue::Null(_))
                    || matches!(kept.value, MetricValue::Null(_))
                {
                    *kept = sample;
                }
                kept.writable = writable;
            }
            None => {
                at.insert(sample.name.clone(), out.len());
                out.push(sample);
            }
        }
    }
    out
}

/// The data messages of one pass, one per topic: a device's metrics from
/// several sources (its frames, a held change now due) in one DDATA.
#[derive(Default)]
pub(super) struct PassOut {
    pub(super) messages: Vec<Outgoing>,
}

impl PassOut {
    pub(super) fn add(&mut self, message: Outgoing) {
        match self
            .messages
            .iter_mut()
            .find(|kept| kept.topic == message.topic)
        {
            Some(kept) => kept.payload.metrics.extend(message.payload.metrics),
            None => self.messages.push(message),
        }
    }
}

/// Whether a node gets a DBIRTH: identified and online.
fn born_device(info: &NodeInfo) -> bool {
    info.online && info.identification == Identification::Done
}

/// A node's TPDO values as metrics `TPDO/{EDS name}`, typed (an object the
/// EDS does not describe: its raw bits as UInt64).
fn tpdo_samples(values: &[crate::gateway::TpdoValue]) -> Vec<Sample> {
    let now = unix_ms();
    values
        .iter()
        .map(|value| {
            let age = value.at.elapsed().as_millis() as u64;
            let metric = match &value.value {
                Some(typed) => MetricValue::from_canopen(typed),
                None => MetricValue::UInt64(value.raw),
            };
            Sample::new(
                format!("TPDO/{}", value.key()),
                metric,
                now.saturating_sub(age),
            )
        })
        .collect()
}

/// An axis's metrics from its stream sample (`AxisSample` as JSON):
/// `Axis {n}/State`, `Statusword`, `Position`, `Velocity`, `Fault`; fields
/// not read yet are left out.
fn axis_samples(axis: u8, data: &serde_json::Value, now: u64) -> Vec<Sample> {
    let name = |field: &str| format!("Axis {axis}/{field}");
    let mut metrics = Vec::new();
    if let Some(state) = data.get("state").and_then(serde_json::Value::as_str) {
        metrics.push(Sample::new(
            name("State"),
            MetricValue::String(state.to_string()),
            now,
        ));
    }
    if let Some(word) = data.get("statusword").and_then(serde_json::Value::as_u64) {
        metrics.push(Sample::new(
            name("Statusword"),
            MetricValue::UInt16(word as u16),
            now,
        ));
    }
    for field in ["position", "velocity"] {
        if let Some(value) = data.get(field).and_then(serde_json::Value::as_i64) {
            let mut title = field.to_string();
            title[..1].make_ascii_uppercase();
            metrics.push(Sample::new(
                name(&title),
                MetricValue::Int32(value as i32),
                now,
            ));
        }
    }
    if let Some(fault) = data.get("fault").and_then(serde_json::Value::as_bool) {
        metrics.push(Sample::new(name("Fault"), MetricValue::Boolean(fault), now));
    }
    metrics
}

async fn poll(connection: &mut Option<Connection>) -> Result<Event, rumqttc::ConnectionError> {
    match connection {
        Some(connection) => match connection.events.recv().await {
            Some(event) => event,
            None => Err(rumqttc::ConnectionError::RequestsDone),
        },
        None => std::future::pending().await,
    }
}

async fn sleep_until(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// The commands of one NCMD or DCMD message (`summary`: its metrics as
/// [`command::summary`] gives them), in order, each through the gateway's
/// operations and checks as REST runs them: the role (the edge node's
/// `sparkplug_role`, checked by each operation), the motion lease, the
/// write rate limit, the node's checks, the EDS's. The message is ONE
/// audit row, whatever its commands' outcomes (the gateway folds the rows
/// of their operations into it: [`Gateway::audited_together`]), `who` the
/// edge node's broker account, with the message type and topic as the
/// door's words. The result of each command, in order.
pub(crate) async fn run_message(
    gateway: &Gateway,
    config: &SparkplugConfig,
    held: &HeldLeases,
    topic: &Topic,
    commands: &[Command],
    summary: String,
) -> Vec<Result<(), GatewayError>> {
    let caller = command_caller(config, topic, Some(summary));
    let mut target = AuditTarget::new("command");
    if let Some((bus, node)) = topic.device.as_deref().and_then(parse_device) {
        target = target.bus(bus).node(node);
    }
    let mut results = Vec::with_capacity(commands.len());
    let work = async {
        for command in commands {
            // The command's own summary, for a message of it alone.
            let part = match &caller.door {
                Some(door) => caller
                    .clone()
                    .with_door(door.part(command_summary(command))),
                None => caller.clone(),
            };
            results.push(run_command(gateway, config, held, topic, &part, command).await);
        }
        Ok::<_, GatewayError>(())
    };
    let _ = gateway.audited_together(&caller, target, None, work).await;
    results
}

/// One command of a message, for `caller` (the message's): audited as a
/// part of the message's row, by the gateway's operation it calls, or here
/// when none audited it (a refusal of the door's own).
async fn run_command(
    gateway: &Gateway,
    config: &SparkplugConfig,
    held: &HeldLeases,
    topic: &Topic,
    caller: &Caller,
    command: &Command,
) -> Result<(), GatewayError> {
    let device = topic.device.as_deref().and_then(parse_device);
    let (bus, node) = match device {
        Some((bus, node)) => (Some(bus.to_string()), Some(node)),
        None => (None, None),
    };
    // What the command acts on, known before any check: a refused write
    // is logged with its object, as every door logs it.
    let item = match command {
        Command::Write { index, sub, .. } => Some(object_item(*index, *sub)),
        Command::Segment { segment, .. } => Some(format!("segment {segment}")),
        _ => None,
    };
    let mut target = AuditTarget::new(command.operation())
        .node(node)
        .axis(command.axis())
        .item(item);
    target.bus = bus.clone();
    let work = async {
        // `candeck serve` refuses such settings at start; an edge node made
        // otherwise takes no command either.
        config.command_exposure().map_err(GatewayError::Forbidden)?;
        let (Some(bus), Some(node)) = (&bus, node) else {
            return Err(GatewayError::InvalidRequest(format!(
                "{topic}: not a device of this edge node"
            )));
        };
        // Object writes, NMT, segment and motion commands take their write
        // in the gateway's operation (none for a stop or a lease renewal;
        // one presenting the lease held on its axis from that lease's
        // bucket: `crate::gateway::policy`); what runs no operation (a
        // rebirth, an unsupported metric) takes one here.
        let operation = matches!(
            command,
            Command::Write { .. } | Command::Nmt(_) | Command::Segment { .. }
        ) || command.axis().is_some();
        if !operation {
            gateway.take_write(caller)?;
        }
        match command {
            Command::Write { index, sub, value } => {
                let handle = gateway.node_handle(bus, &node.to_string())?;
                let info = handle.info();
                let bytes = match info
                    .eds_entry
                    .as_ref()
                    .and_then(|entry| entry.eds.dictionary.sub(*index, *sub))
                {
                    Some(described) => described
                        .value_from_json(&value.to_json(), Some(info.id))
                        .map_err(|err| GatewayError::InvalidRequest(err.to_string()))?
                        .to_bytes(),
                    None => {
                        return Err(GatewayError::InvalidRequest(format!(
                            "the EDS of node {node} does not describe 0x{index:04X} sub {sub}"
                        )));
                    }
                };
                handle.write_object(caller, *index, *sub, bytes).await
            }
            Command::Nmt(nmt) => {
                gateway
                    .node_handle(bus, &node.to_string())?
                    .nmt(caller, *nmt)
                    .await
            }
            Command::Unsupported(what) => Err(GatewayError::InvalidRequest(format!(
                "unsupported command metric '{what}'"
            ))),
            Command::Rebirth => Ok(()),
            _ => super::motion::run(gateway, caller, held, bus, node, command).await,
        }
    };
    gateway.audited_by_door(caller, target, None, work).await
}

/// The refusal of a command message of `size` bytes over the edge node's
/// `sparkplug_max_command_bytes`, if it is.
pub(crate) fn oversized(config: &SparkplugConfig, size: usize) -> Option<GatewayError> {
    (size > config.max_command_bytes).then_some(GatewayError::CommandTooLarge {
        size,
        limit: config.max_command_bytes,
    })
}

/// Writes the one audit row of a command message refused whole for
/// `error`; returns it.
pub(crate) async fn refuse_message(
    gateway: &Gateway,
    config: &SparkplugConfig,
    topic: &Topic,
    error: GatewayError,
) -> Result<(), GatewayError> {
    let caller = command_caller(config, topic, Some(error.to_string()));
    let mut target = AuditTarget::new("command");
    if let Some((bus, node)) = topic.device.as_deref().and_then(parse_device) {
        target = target.bus(bus).node(node);
    }
    gateway
        .audited_together(&caller, target, None, async { Err(error) })
        .await
}

/// Who a command message from MQTT runs as: the edge node's own broker
/// account and role (MQTT names no sender), the broker as its peer, the
/// message type and topic as the door's words, `summary` (bounded) as its
/// request; its commands' rows gathered into one.
fn command_caller(config: &SparkplugConfig, topic: &Topic, summary: Option<String>) -> Caller {
    let detail = DoorDetail::new(topic.kind.as_str(), topic.to_string())
        .summary(summary.map(|text| bounded(&text)));
    Caller::new(Channel::Sparkplug, config.who(), Some(config.role))
        .with_peer(format!("{}:{}", config.broker.host, config.broker.port))
        .with_door(DoorRequest::gathered(detail))
}

/// `text`, cut to [`command::SUMMARY_CHARS`] characters with its length
/// said: an audit row keeps a summary, never a whole payload.
pub(crate) fn bounded(text: &str) -> String {
    use command::SUMMARY_CHARS;
    if text.chars().count() <= SUMMARY_CHARS {
        return text.to_string();
    }
    let head: String = text.chars().take(SUMMARY_CHARS).collect();
    format!("{head}… ({} bytes)", text.len())
}

/// Refusals in the log, sampled: the first of each 10 s, then how many
/// more there were, so that a flood of bad commands is not a flood of
/// lines (each is counted on /metrics and audited).
#[derive(Debug, Default)]
pub(crate) struct Refusals {
    window: Mutex<(Option<Instant>, u64)>,
}

impl Refusals {
    const WINDOW: Duration = Duration::from_secs(10);

    pub(crate) fn warn(&self, line: &str) {
        let mut window = lock(&self.window);
        let now = Instant::now();
        match window.0 {
            Some(since) if now.duration_since(since) < Self::WINDOW => window.1 += 1,
            _ => {
                if window.1 > 0 {
                    tracing::warn!(
                        "sparkplug: {} more commands refused or failed in the last {} s",
                        window.1,
                        Self::WINDOW.as_secs()
                    );
                }
                *window = (Some(now), 0);
                tracing::warn!("sparkplug: {line}");
            }
        }
    }
}

/// A command's request as the edge node summarises it (bounded), where it
/// has its own words (the value of a write as the metric gave it, a
/// segment's writes); the gateway's operations summarise the others.
fn command_summary(command: &Command) -> Option<String> {
    match command {
        Command::Write { value, .. } => Some(bounded(&value.to_json().to_string())),
        Command::Segment { segment, update } => Some(segment_request(*segment, update)),
        _ => None,
    }
}

#[cfg(test)]
mod tests;
