//! Monitored dictionary variables (`Nodes/{bus}/{id}/Dictionary/{entry}`):
//! sampled over SDO at the items' sampling intervals, bounded per node, or
//! fed from the node's TPDOs where a running one carries the object.
//!
//! A node has one SDO server channel, shared by every door and the
//! gateway's own transfers, so the samples of its monitored variables are
//! bounded per node (`opcua_sdo_samples_per_s`): one sampler task per node
//! with monitored variables reads them one at a time, never two uploads
//! closer than `1 / bound`. When the items ask more than the bound gives,
//! the bound is shared fairly (max-min: an object asking less than its share
//! gets what it asks, the others the rest in equal parts) and the values of
//! the objects sampled slower than asked carry `GoodOverload` ("sampling
//! has slowed down due to resource limitations"). An object a running TPDO
//! of the node carries (the gateway's decoded TPDOs,
//! `TpdoValues::carrier`) takes no SDO at all: its value is the TPDO's,
//! sent as each frame brings it; a faster sampling interval is answered by
//! the last value. Nothing is sampled unless monitored: the node's task
//! ends with its last item (deleted, or its subscription or session gone).
//!
//! [`NodeSchedule`] and [`fair_interval`] are sans I/O; the task reads and
//! publishes through a [`Backend`], the gateway's in the server.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

use async_trait::async_trait;
use opcua::server::{MonitoredItemHandle, SubscriptionCache};
use opcua::types::{AttributeId, DataValue, DateTime, NodeId, StatusCode};
use tokio::sync::watch;
use tokio::time::Instant;

use super::browse::NodePath;
use crate::canopen::NodeId as CanNodeId;
use crate::canopen::nmt::NmtState;
use crate::gateway::{Caller, Gateway, GatewayError};

/// An object of a node's dictionary: index and sub-index.
pub type Entry = (u16, u8);

/// The sampling interval taken for an item that asks the subscription's
/// (a negative interval): async-opcua does not tell a node manager the
/// subscription's publishing interval.
pub const SUBSCRIPTION_INTERVAL: Duration = Duration::from_secs(1);

/// What one object of a node is wanted at: the fastest interval its items
/// ask, and the caller whose reads sample it (the session that asked it).
#[derive(Debug, Clone, PartialEq)]
pub struct Want {
    pub interval: Duration,
    pub caller: Caller,
}

/// A TPDO-carried object's newest value: `seen` changes with each frame
/// that brought it.
#[derive(Debug, Clone, PartialEq)]
pub struct Carried {
    pub seen: (Instant, u64),
    pub value: DataValue,
}

/// Where a node's sampler reads and writes: the gateway and the
/// subscriptions in the server, a fake in the tests.
#[async_trait]
pub trait Backend: Send + Sync + 'static {
    /// `Some` when a running TPDO of the node carries the object (its
    /// newest value, `None` before a frame brought one): no SDO for it.
    fn carried(&self, node: &NodePath, entry: Entry) -> Option<Option<Carried>>;
    /// One SDO upload of the object, with `caller`'s rights.
    async fn read(&self, node: &NodePath, entry: Entry, caller: &Caller) -> DataValue;
    /// Changes with each TPDO frame of the node; `None`: no TPDOs.
    fn frames(&self, node: &NodePath) -> Option<watch::Receiver<u64>>;
    /// A sample to the items monitoring the object.
    fn publish(&self, node: &NodePath, entry: Entry, value: DataValue);
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

type Wanted = BTreeMap<Entry, Want>;

struct Monitored {
    node: NodePath,
    entry: Entry,
    want: Want,
}

struct Sampler {
    wanted: watch::Sender<Wanted>,
    task: tokio::task::JoinHandle<()>,
}

#[derive(Default)]
struct State {
    items: HashMap<MonitoredItemHandle, Monitored>,
    samplers: HashMap<NodePath, Sampler>,
}

/// The monitored dictionary variables and their nodes' samplers.
pub struct DictionarySampling {
    samples_per_s: u32,
    backend: OnceLock<Arc<dyn Backend>>,
    state: Mutex<State>,
}

impl DictionarySampling {
    /// Samples at most `samples_per_s` objects a second per node over SDO.
    pub fn new(samples_per_s: u32) -> Self {
        Self {
            samples_per_s: samples_per_s.max(1),
            backend: OnceLock::new(),
            state: Mutex::default(),
        }
    }

    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        self.state
            .lock()
            .unwrap_or_else(|poison| poison.into_inner())
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

    /// The value an item on `entry` starts with: a carrying TPDO's newest,
    /// else none (the sampler's first sample, due at once, brings it).
    pub fn initial(&self, node: &NodePath, entry: Entry) -> Option<DataValue> {
        let backend = self.backend.get()?;
        backend
            .carried(node, entry)
            .flatten()
            .map(|carried| carried.value)
    }

    /// A monitored item on `entry` of `node`, sampled every `interval_ms`
    /// (negative: the subscription's, [`SUBSCRIPTION_INTERVAL`]) with
    /// `caller`'s reads.
    pub fn monitor(
        &self,
        handle: MonitoredItemHandle,
        node: NodePath,
        entry: Entry,
        interval_ms: f64,
        caller: Caller,
    ) {
        let interval = if interval_ms.is_finite() && interval_ms >= 0.0 {
            Duration::from_secs_f64(interval_ms / 1000.0)
        } else {
            SUBSCRIPTION_INTERVAL
        };
        let want = Want { interval, caller };
        self.state().items.insert(
            handle,
            Monitored {
                node: node.clone(),
                entry,
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
            if interval_ms.is_finite() && interval_ms >= 0.0 {
                item.want.interval = Duration::from_secs_f64(interval_ms / 1000.0);
            } else {
                item.want.interval = SUBSCRIPTION_INTERVAL;
            }
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
            match wanted.get(&item.entry) {
                Some(want) if want.interval <= item.want.interval => {}
                _ => {
                    wanted.insert(item.entry, item.want.clone());
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
        let task = tokio::spawn(sample_node(
            backend,
            node.clone(),
            receiver,
            self.samples_per_s,
        ));
        state.samplers.insert(
            node.clone(),
            Sampler {
                wanted: sender,
                task,
            },
        );
    }
}

impl Drop for DictionarySampling {
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

/// One node's sampler: until its items are gone, the TPDO-carried objects
/// sent as their frames come, the others read over SDO as the
/// [`NodeSchedule`] says.
async fn sample_node(
    backend: Arc<dyn Backend>,
    node: NodePath,
    mut wanted: watch::Receiver<Wanted>,
    samples_per_s: u32,
) {
    let mut schedule = NodeSchedule::new(samples_per_s);
    let mut frames = backend.frames(&node);
    let mut sent: HashMap<Entry, (Instant, u64)> = HashMap::new();
    loop {
        let wants = wanted.borrow_and_update().clone();
        if wants.is_empty() {
            return;
        }
        let mut over_sdo = BTreeMap::new();
        // The frames wake the task only while it has objects they carry.
        let mut tpdo_fed = false;
        for (entry, want) in &wants {
            let carried = backend.carried(&node, *entry);
            tpdo_fed |= carried.is_some();
            match carried {
                Some(Some(carried)) => {
                    if sent.get(entry) != Some(&carried.seen) {
                        sent.insert(*entry, carried.seen);
                        backend.publish(&node, *entry, carried.value);
                    }
                }
                Some(None) => {}
                None => {
                    over_sdo.insert(*entry, want.interval);
                }
            }
        }
        sent.retain(|entry, _| wants.contains_key(entry));
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
                let Some(want) = wants.get(&entry) else { continue };
                let started = Instant::now();
                let mut value = backend.read(&node, entry, &want.caller).await;
                if schedule.overloaded(entry) && value.status().is_good() {
                    value.status = Some(StatusCode::GoodOverload);
                }
                backend.publish(&node, entry, value);
                schedule.sampled(entry, started);
            }
        }
    }
}

/// A dictionary entry read over SDO now, as a value or its error's status
/// (a client's read and a sample alike).
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
            DataValue {
                status: Some(super::status::status_of(&error)),
                source_timestamp: Some(DateTime::now()),
                server_timestamp: Some(DateTime::now()),
                ..Default::default()
            }
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
        Some(value.and_then(|value| {
            let typed = value.value.as_ref()?;
            Some(Carried {
                seen: (value.at, value.count),
                value: DataValue::new_now(super::values::variant_of(typed)),
            })
        }))
    }

    async fn read(&self, node: &NodePath, entry: Entry, caller: &Caller) -> DataValue {
        read_entry(&self.gateway, caller, node, entry.0, entry.1).await
    }

    fn frames(&self, node: &NodePath) -> Option<watch::Receiver<u64>> {
        let bus = self.gateway.bus(&node.bus).ok()?;
        Some(bus.values().watch_frames(Self::node_id(node)?))
    }

    fn publish(&self, node: &NodePath, entry: Entry, value: DataValue) {
        let id = NodeId::new(self.ns, node.object(entry.0, entry.1));
        self.subscriptions
            .notify_data_change(std::iter::once((value, &id, AttributeId::Value)));
    }
}

#[cfg(test)]
mod tests;
