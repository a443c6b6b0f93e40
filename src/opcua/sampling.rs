//! Monitored variables read from a node's dictionary, sampled over SDO at
//! the items' sampling intervals, bounded per node, or fed from the node's
//! TPDOs where a running one carries their objects: the dictionary's
//! variables (`Nodes/{bus}/{id}/Dictionary/{entry}`), a CiA 401 module's
//! channels (`Io/{channel}`) and a UIO1LED's segment fields
//! (`Leds/{n}/{field}`).
//!
//! What an item watches ([`Watched`]) is made of objects: a dictionary
//! variable of its entry, a channel of the object its profile puts it in
//! (a digital channel is a bit of an 8-bit group, [`Channel::location`]),
//! a segment field of the object the UIO1LED's profile gives it
//! ([`crate::profiles::uioled::address`]; a colour of its four, red, green,
//! blue and white). The sampler reads objects, not variables: the items on
//! one object are one sample (`di1` to `di8` of one group too), and a
//! variable's value goes out when it changed (a change of another bit of
//! its group sends nothing); a colour's once its four objects were read.
//!
//! A node has one SDO server channel, shared by every door and the
//! gateway's own transfers, so the samples of its monitored variables are
//! bounded per node (`opcua_sdo_samples_per_s`), dictionary, I/O and LED
//! alike: one sampler task per node with monitored variables reads their
//! objects one at a time, never two uploads closer than `1 / bound`. When
//! the items ask more than the bound gives, the bound is shared fairly
//! (max-min: an object asking less than its share gets what it asks, the
//! others the rest in equal parts) and the values of the objects sampled
//! slower than asked carry `GoodOverload` ("sampling has slowed down due to
//! resource limitations"). An object a running TPDO of the node carries
//! (the gateway's decoded TPDOs, `TpdoValues::carrier`) takes no SDO at
//! all: its value is the TPDO's, sent as each frame brings a change; a
//! faster sampling interval is answered by the last value. Nothing is
//! sampled unless monitored: the node's task ends with its last item
//! (deleted, or its subscription or session gone).
//!
//! [`NodeSchedule`] and [`fair_interval`] are sans I/O; the task reads and
//! publishes through a [`Backend`], the gateway's in the server.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

use async_trait::async_trait;
use opcua::server::{MonitoredItemHandle, SubscriptionCache};
use opcua::types::{AttributeId, DataValue, DateTime, NodeId, StatusCode, Variant};
use tokio::sync::watch;
use tokio::time::Instant;

use super::browse::NodePath;
use super::io::LedField;
use super::status::status_of;
use crate::canopen::NodeId as CanNodeId;
use crate::canopen::nmt::NmtState;
use crate::gateway::{Caller, Gateway, GatewayError};
use crate::profiles::cia401::{Channel, Level};
use crate::profiles::uioled;

/// An object of a node's dictionary: index and sub-index.
pub type Entry = (u16, u8);

/// The sampling interval taken for an item that asks the subscription's
/// (a negative interval): async-opcua does not tell a node manager the
/// subscription's publishing interval.
pub const SUBSCRIPTION_INTERVAL: Duration = Duration::from_secs(1);

/// What a monitored item watches on its node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Watched {
    /// A dictionary variable: its entry, typed by the node's EDS.
    Entry(Entry),
    /// A CiA 401 channel (`Io/{channel}`).
    Channel(Channel),
    /// A field of a UIO1LED segment (`Leds/{segment}/{field}`).
    Led { segment: u8, field: LedField },
}

impl Watched {
    /// The objects its value is read from, in the order they are read:
    /// the last one completes a value.
    pub fn objects(self) -> Vec<Entry> {
        match self {
            Self::Entry(entry) => vec![entry],
            Self::Channel(channel) => {
                let (index, sub, _) = channel.location();
                vec![(index, sub)]
            }
            Self::Led { segment, field } => field
                .fields()
                .into_iter()
                .filter_map(|of| uioled::address(segment, of))
                .collect(),
        }
    }
}

/// What one object of a node is wanted at: the fastest interval its items
/// ask, and the caller whose reads sample it (the session that asked it).
#[derive(Debug, Clone, PartialEq)]
pub struct Want {
    pub interval: Duration,
    pub caller: Caller,
}

/// A TPDO-carried object's newest bytes: `seen` changes with each frame
/// that brought them.
#[derive(Debug, Clone, PartialEq)]
pub struct Carried {
    pub seen: (Instant, u64),
    pub data: Vec<u8>,
}

/// Where a node's sampler reads and writes: the gateway and the
/// subscriptions in the server, a fake in the tests.
#[async_trait]
pub trait Backend: Send + Sync + 'static {
    /// `Some` when a running TPDO of the node carries the object (its
    /// newest bytes, `None` before a frame brought them): no SDO for it.
    fn carried(&self, node: &NodePath, entry: Entry) -> Option<Option<Carried>>;
    /// One SDO upload of the object, with `caller`'s rights.
    async fn read(
        &self,
        node: &NodePath,
        entry: Entry,
        caller: &Caller,
    ) -> Result<Vec<u8>, GatewayError>;
    /// A dictionary entry's bytes as its value, typed by the node's EDS.
    fn decode(&self, node: &NodePath, entry: Entry, data: &[u8]) -> Result<Variant, GatewayError>;
    /// Changes with each TPDO frame of the node; `None`: no TPDOs.
    fn frames(&self, node: &NodePath) -> Option<watch::Receiver<u64>>;
    /// A value to the items monitoring `watched` on the node.
    fn publish(&self, node: &NodePath, watched: Watched, value: DataValue);
}

/// The sampling interval every object gets at most as often as, when the
/// objects ask `asked` (their intervals) of a node bounded to
/// `samples_per_s`: `None` when the bound gives each what it asks, else the
/// max-min fair share (the objects asking less keep their rate, the others
/// share the rest equally).
pub fn fair_interval(asked: &[Duration], samples_per_s: u32) -> Option<Duration> {
    let mut rates: Vec<f64> = asked
        .iter()
        .map(|interval| 1.0 / interval.as_secs_f64().max(1e-6))
        .collect();
    let mut left = f64::from(samples_per_s);
    if rates.iter().sum::<f64>() <= left {
        return None;
    }
    rates.sort_by(f64::total_cmp);
    let mut others = rates.len() as f64;
    for rate in rates {
        let share = left / others;
        if rate > share {
            return Some(Duration::from_secs_f64(1.0 / share));
        }
        left -= rate;
        others -= 1.0;
    }
    None
}

/// When each SDO-sampled object of one node is due, sans I/O: at its own
/// interval, or its fair share's when the node is asked more than its
/// bound; two uploads never closer than `1 / bound`.
#[derive(Debug)]
pub struct NodeSchedule {
    spacing: Duration,
    samples_per_s: u32,
    asked: BTreeMap<Entry, Duration>,
    due: BTreeMap<Entry, Instant>,
    share: Option<Duration>,
    last: Option<Instant>,
}

impl NodeSchedule {
    pub fn new(samples_per_s: u32) -> Self {
        let samples_per_s = samples_per_s.max(1);
        Self {
            spacing: Duration::from_secs(1) / samples_per_s,
            samples_per_s,
            asked: BTreeMap::new(),
            due: BTreeMap::new(),
            share: None,
            last: None,
        }
    }

    /// The objects to sample and their intervals from now: a new one is
    /// due at once, one no longer asked is forgotten.
    pub fn plan(&mut self, asked: BTreeMap<Entry, Duration>, now: Instant) {
        self.due.retain(|entry, _| asked.contains_key(entry));
        for entry in asked.keys() {
            self.due.entry(*entry).or_insert(now);
        }
        let intervals: Vec<Duration> = asked.values().copied().collect();
        self.share = fair_interval(&intervals, self.samples_per_s);
        self.asked = asked;
    }

    /// The interval `entry` is sampled at.
    pub fn interval(&self, entry: Entry) -> Duration {
        let asked = self.asked.get(&entry).copied().unwrap_or_default();
        self.share.map_or(asked, |share| asked.max(share))
    }

    /// Sampled slower than its items ask.
    pub fn overloaded(&self, entry: Entry) -> bool {
        self.interval(entry) > self.asked.get(&entry).copied().unwrap_or_default()
    }

    /// The next object to read and when: the one due first (the earliest
    /// asked first among equals), not before the bound allows.
    pub fn next(&self) -> Option<(Entry, Instant)> {
        let (entry, due) = self
            .due
            .iter()
            .min_by_key(|(entry, due)| (**due, **entry))?;
        let allowed = self
            .last
            .map_or(*due, |last| (last + self.spacing).max(*due));
        Some((*entry, allowed))
    }

    /// `entry` was read at `at` (when its upload started).
    pub fn sampled(&mut self, entry: Entry, at: Instant) {
        self.last = Some(at);
        let interval = self.interval(entry);
        if let Some(due) = self.due.get_mut(&entry) {
            *due = at + interval;
        }
    }
}

/// The newest read of one object: its bytes or the status of the error
/// that kept them, and whether it was sampled slower than asked.
#[derive(Debug, Clone)]
struct Read {
    data: Result<Vec<u8>, StatusCode>,
    slowed: bool,
}

/// A value that is an error's status, stamped now (a read's failure).
fn failed(status: StatusCode) -> DataValue {
    DataValue {
        status: Some(status),
        source_timestamp: Some(DateTime::now()),
        server_timestamp: Some(DateTime::now()),
        ..Default::default()
    }
}

/// `watched`'s value from the newest reads of its objects: `None` until
/// each was read; the status of a failed read; `GoodOverload` when one was
/// sampled slower than asked.
fn value_of(
    backend: &dyn Backend,
    node: &NodePath,
    watched: Watched,
    reads: &HashMap<Entry, Read>,
) -> Option<DataValue> {
    let mut data: Vec<&[u8]> = Vec::new();
    let mut slowed = false;
    for entry in watched.objects() {
        let read = reads.get(&entry)?;
        match &read.data {
            Ok(bytes) => data.push(bytes),
            Err(status) => return Some(failed(*status)),
        }
        slowed |= read.slowed;
    }
    let value = match watched {
        Watched::Entry(entry) => backend.decode(node, entry, data.first()?),
        Watched::Channel(channel) => match channel.level_in(data.first()?) {
            Some(Level::Digital(on)) => Ok(Variant::Boolean(on)),
            Some(Level::Analog(level)) => Ok(Variant::Int16(level)),
            None => Err(GatewayError::Internal(format!(
                "{channel}: {} bytes",
                data.first().map_or(0, |bytes| bytes.len())
            ))),
        },
        Watched::Led { field, .. } => Ok(field.value_from(&data)),
    };
    Some(match value {
        Ok(value) => {
            let mut value = DataValue::new_now(value);
            if slowed {
                value.status = Some(StatusCode::GoodOverload);
            }
            value
        }
        Err(error) => {
            tracing::debug!("opcua: {watched:?} on {}/{}: {error}", node.bus, node.node);
            failed(status_of(&error))
        }
    })
}

/// The value last sent per variable of a node: what an item that joins
/// starts with.
type Sent = Arc<Mutex<HashMap<Watched, DataValue>>>;

fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|poison| poison.into_inner())
}

type Wanted = BTreeMap<Watched, Want>;

struct Monitored {
    node: NodePath,
    watched: Watched,
    want: Want,
}

struct Sampler {
    wanted: watch::Sender<Wanted>,
    sent: Sent,
    task: tokio::task::JoinHandle<()>,
}

#[derive(Default)]
struct State {
    items: HashMap<MonitoredItemHandle, Monitored>,
    samplers: HashMap<NodePath, Sampler>,
}

/// The monitored variables read from the nodes' dictionaries (dictionary,
/// I/O and LED variables) and their nodes' samplers.
pub struct Sampling {
    samples_per_s: u32,
    backend: OnceLock<Arc<dyn Backend>>,
    state: Mutex<State>,
}

fn interval_of(interval_ms: f64) -> Duration {
    if interval_ms.is_finite() && interval_ms >= 0.0 {
        Duration::from_secs_f64(interval_ms / 1000.0)
    } else {
        SUBSCRIPTION_INTERVAL
    }
}

impl Sampling {
    /// Samples at most `samples_per_s` objects a second per node over SDO.
    pub fn new(samples_per_s: u32) -> Self {
        Self {
            samples_per_s: samples_per_s.max(1),
            backend: OnceLock::new(),
            state: Mutex::default(),
        }
    }

    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        lock(&self.state)
    }

    /// Starts sampling through `backend` (the server, once built): the
    /// items monitored before are sampled from now.
    pub fn start(&self, backend: Arc<dyn Backend>) {
        if self.backend.set(backend).is_err() {
            return;
        }
        let nodes: Vec<NodePath> = {
            let state = self.state();
            state.items.values().map(|item| item.node.clone()).collect()
        };
        for node in nodes {
            self.update(&node);
        }
    }

    /// The value an item on `watched` starts with: the one last sent to
    /// the items on it, else the carrying TPDOs' newest, else none (the
    /// sampler's first sample, due at once, brings it).
    pub fn initial(&self, node: &NodePath, watched: Watched) -> Option<DataValue> {
        let backend = self.backend.get()?;
        let sent = self
            .state()
            .samplers
            .get(node)
            .and_then(|sampler| lock(&sampler.sent).get(&watched).cloned());
        if sent.is_some() {
            return sent;
        }
        let mut reads = HashMap::new();
        for entry in watched.objects() {
            let carried = backend.carried(node, entry).flatten()?;
            reads.insert(
                entry,
                Read {
                    data: Ok(carried.data),
                    slowed: false,
                },
            );
        }
        value_of(backend.as_ref(), node, watched, &reads)
    }

    /// A monitored item on `watched` of `node`, sampled every `interval_ms`
    /// (negative: the subscription's, [`SUBSCRIPTION_INTERVAL`]) with
    /// `caller`'s reads.
    pub fn monitor(
        &self,
        handle: MonitoredItemHandle,
        node: NodePath,
        watched: Watched,
        interval_ms: f64,
        caller: Caller,
    ) {
        let want = Want {
            interval: interval_of(interval_ms),
            caller,
        };
        self.state().items.insert(
            handle,
            Monitored {
                node: node.clone(),
                watched,
                want,
            },
        );
        self.update(&node);
    }

    /// The item's new sampling interval (ModifyMonitoredItems).
    pub fn modify(&self, handle: MonitoredItemHandle, interval_ms: f64) {
        let node = {
            let mut state = self.state();
            let Some(item) = state.items.get_mut(&handle) else {
                return;
            };
            item.want.interval = interval_of(interval_ms);
            item.node.clone()
        };
        self.update(&node);
    }

    /// An item deleted (by the client, or with its subscription or
    /// session): its node's sampler ends with its last item.
    pub fn unmonitor(&self, handle: MonitoredItemHandle) {
        let node = self.state().items.remove(&handle).map(|item| item.node);
        if let Some(node) = node {
            self.update(&node);
        }
    }

    /// The nodes sampled now.
    pub fn sampled_nodes(&self) -> Vec<NodePath> {
        let mut state = self.state();
        state
            .samplers
            .retain(|_, sampler| !sampler.task.is_finished());
        state.samplers.keys().cloned().collect()
    }

    /// Tells `node`'s sampler what its items want; starts it or ends it.
    fn update(&self, node: &NodePath) {
        let mut state = self.state();
        let mut wanted = Wanted::new();
        for item in state.items.values().filter(|item| &item.node == node) {
            match wanted.get(&item.watched) {
                Some(want) if want.interval <= item.want.interval => {}
                _ => {
                    wanted.insert(item.watched, item.want.clone());
                }
            }
        }
        if wanted.is_empty() {
            if let Some(sampler) = state.samplers.remove(node) {
                sampler.task.abort();
            }
            return;
        }
        if let Some(sampler) = state.samplers.get(node)
            && !sampler.task.is_finished()
        {
            sampler.wanted.send_replace(wanted);
            return;
        }
        let Some(backend) = self.backend.get().cloned() else {
            return;
        };
        let (sender, receiver) = watch::channel(wanted);
        let sent = Sent::default();
        let task = tokio::spawn(sample_node(
            backend,
            node.clone(),
            receiver,
            self.samples_per_s,
            sent.clone(),
        ));
        state.samplers.insert(
            node.clone(),
            Sampler {
                wanted: sender,
                sent,
                task,
            },
        );
    }
}

impl Drop for Sampling {
    fn drop(&mut self) {
        for sampler in self.state().samplers.values() {
            sampler.task.abort();
        }
    }
}

/// Changes of the node's TPDO frames, or never without them.
async fn frame_changed(frames: &mut Option<watch::Receiver<u64>>) {
    match frames {
        Some(receiver) => {
            if receiver.changed().await.is_err() {
                *frames = None;
            }
        }
        None => std::future::pending().await,
    }
}

/// Sends the value of each wanted variable that a new read of `entry`
/// completes (every variable made of it when a TPDO brought it, else those
/// whose last object it is) and that changed since it was last sent.
fn send(
    backend: &dyn Backend,
    node: &NodePath,
    wants: &Wanted,
    reads: &HashMap<Entry, Read>,
    entry: Entry,
    from_tpdo: bool,
    sent: &Sent,
) {
    for watched in wants.keys() {
        let objects = watched.objects();
        let completes = if from_tpdo {
            objects.contains(&entry)
        } else {
            objects.last() == Some(&entry)
        };
        if !completes {
            continue;
        }
        let Some(value) = value_of(backend, node, *watched, reads) else {
            continue;
        };
        {
            let mut sent = lock(sent);
            let unchanged = sent
                .get(watched)
                .is_some_and(|last| last.value == value.value && last.status() == value.status());
            if unchanged {
                continue;
            }
            sent.insert(*watched, value.clone());
        }
        backend.publish(node, *watched, value);
    }
}

/// One node's sampler: until its items are gone, the TPDO-carried objects
/// taken as their frames come, the others read over SDO as the
/// [`NodeSchedule`] says; each variable's changes sent.
async fn sample_node(
    backend: Arc<dyn Backend>,
    node: NodePath,
    mut wanted: watch::Receiver<Wanted>,
    samples_per_s: u32,
    sent: Sent,
) {
    let mut schedule = NodeSchedule::new(samples_per_s);
    let mut frames = backend.frames(&node);
    let mut reads: HashMap<Entry, Read> = HashMap::new();
    let mut seen: HashMap<Entry, (Instant, u64)> = HashMap::new();
    loop {
        let wants = wanted.borrow_and_update().clone();
        if wants.is_empty() {
            return;
        }
        // Each object at the fastest interval of the variables made of it,
        // read with that item's caller.
        let mut objects: BTreeMap<Entry, &Want> = BTreeMap::new();
        for (watched, want) in &wants {
            for entry in watched.objects() {
                match objects.get(&entry) {
                    Some(fastest) if fastest.interval <= want.interval => {}
                    _ => {
                        objects.insert(entry, want);
                    }
                }
            }
        }
        reads.retain(|entry, _| objects.contains_key(entry));
        seen.retain(|entry, _| objects.contains_key(entry));
        lock(&sent).retain(|watched, _| wants.contains_key(watched));
        let mut over_sdo = BTreeMap::new();
        // The frames wake the task only while it has objects they carry.
        let mut tpdo_fed = false;
        for (entry, want) in &objects {
            match backend.carried(&node, *entry) {
                Some(carried) => {
                    tpdo_fed = true;
                    let Some(carried) = carried else { continue };
                    if seen.get(entry) == Some(&carried.seen) {
                        continue;
                    }
                    seen.insert(*entry, carried.seen);
                    let read = Read {
                        data: Ok(carried.data),
                        slowed: false,
                    };
                    reads.insert(*entry, read);
                    send(&*backend, &node, &wants, &reads, *entry, true, &sent);
                }
                None => {
                    seen.remove(entry);
                    over_sdo.insert(*entry, want.interval);
                }
            }
        }
        schedule.plan(over_sdo, Instant::now());
        let next = schedule.next();
        let at = next.map_or_else(Instant::now, |(_, at)| at);
        tokio::select! {
            changed = wanted.changed() => {
                if changed.is_err() {
                    return;
                }
            }
            () = frame_changed(&mut frames), if tpdo_fed => {}
            () = tokio::time::sleep_until(at), if next.is_some() => {
                let Some((entry, _)) = next else { continue };
                let Some(want) = objects.get(&entry) else { continue };
                let started = Instant::now();
                let data = backend
                    .read(&node, entry, &want.caller)
                    .await
                    .map_err(|error| {
                        tracing::debug!(
                            "opcua: sample of {} on {}/{}: {error}",
                            crate::gateway::object_item(entry.0, entry.1),
                            node.bus,
                            node.node
                        );
                        status_of(&error)
                    });
                let slowed = schedule.overloaded(entry);
                reads.insert(entry, Read { data, slowed });
                schedule.sampled(entry, started);
                send(&*backend, &node, &wants, &reads, entry, false, &sent);
            }
        }
    }
}

/// A dictionary entry read over SDO now, as a value or its error's status
/// (a client's read).
pub async fn read_entry(
    gateway: &Gateway,
    caller: &Caller,
    node: &NodePath,
    index: u16,
    sub: u8,
) -> DataValue {
    let item = crate::gateway::object_item(index, sub);
    let result = async {
        let handle = gateway.node_handle(&node.bus, &node.node.to_string())?;
        let entry = super::space::entry(&handle, index, sub)?;
        let bytes = handle.read_object(caller, index, sub).await?;
        let value = entry
            .decode(&bytes)
            .map_err(|err| GatewayError::InvalidValue(format!("{item}: {err}")))?;
        Ok::<_, GatewayError>(super::values::variant_of(&value))
    }
    .await;
    match result {
        Ok(value) => DataValue::new_now(value),
        Err(error) => {
            tracing::debug!(
                "opcua: read of {item} on {}/{}: {error}",
                node.bus,
                node.node
            );
            failed(status_of(&error))
        }
    }
}

/// The server's backend: SDO uploads through the gateway (the node's read
/// operation with the session's caller), the gateway's decoded TPDOs, and
/// the subscriptions of namespace `ns`.
pub struct GatewayBackend {
    pub gateway: Gateway,
    pub subscriptions: Arc<SubscriptionCache>,
    pub ns: u16,
}

impl GatewayBackend {
    fn node_id(node: &NodePath) -> Option<CanNodeId> {
        CanNodeId::new(node.node).ok()
    }

    fn handle(&self, node: &NodePath) -> Result<crate::gateway::NodeHandle, GatewayError> {
        self.gateway.node_handle(&node.bus, &node.node.to_string())
    }
}

#[async_trait]
impl Backend for GatewayBackend {
    fn carried(&self, node: &NodePath, entry: Entry) -> Option<Option<Carried>> {
        let bus = self.gateway.bus(&node.bus).ok()?;
        let id = Self::node_id(node)?;
        bus.values().carrier(id, entry.0, entry.1)?;
        // A TPDO runs only while the node is operational: before, the
        // object is read over SDO.
        let running = bus
            .node(id)
            .is_some_and(|info| info.nmt == Some(NmtState::Operational));
        if !running {
            return None;
        }
        let value = bus.values().value(id, entry.0, entry.1);
        Some(value.map(|value| Carried {
            seen: (value.at, value.count),
            data: value.raw_bytes(),
        }))
    }

    async fn read(
        &self,
        node: &NodePath,
        entry: Entry,
        caller: &Caller,
    ) -> Result<Vec<u8>, GatewayError> {
        self.handle(node)?
            .read_object(caller, entry.0, entry.1)
            .await
    }

    fn decode(&self, node: &NodePath, entry: Entry, data: &[u8]) -> Result<Variant, GatewayError> {
        let described = super::space::entry(&self.handle(node)?, entry.0, entry.1)?;
        let value = described.decode(data).map_err(|err| {
            GatewayError::InvalidValue(format!(
                "{}: {err}",
                crate::gateway::object_item(entry.0, entry.1)
            ))
        })?;
        Ok(super::values::variant_of(&value))
    }

    fn frames(&self, node: &NodePath) -> Option<watch::Receiver<u64>> {
        let bus = self.gateway.bus(&node.bus).ok()?;
        Some(bus.values().watch_frames(Self::node_id(node)?))
    }

    fn publish(&self, node: &NodePath, watched: Watched, value: DataValue) {
        let path = match watched {
            Watched::Entry((index, sub)) => node.object(index, sub),
            Watched::Channel(channel) => super::io::channel_path(node, channel),
            Watched::Led { segment, field } => super::io::segment_path(node, segment, field),
        };
        let id = NodeId::new(self.ns, path);
        self.subscriptions
            .notify_data_change(std::iter::once((value, &id, AttributeId::Value)));
    }
}

#[cfg(test)]
mod tests;
