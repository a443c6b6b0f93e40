//! Objects of a node sampled for any caller at the intervals they ask,
//! bounded per node ([`Gateway::sample_objects`]).
//!
//! A node has one SDO server channel, shared by every door and the
//! gateway's own transfers, so the SDO samples of its objects are bounded
//! per node (`sdo_samples_per_s` of [`crate::GatewayConfig`]), whichever
//! callers and doors ask them: one sampler task per node with sampled
//! objects reads them one at a time, never two uploads closer than
//! `1 / bound`. When the requests ask more than the bound gives, the bound
//! is shared fairly (max-min: an object asking less than its share gets
//! what it asks, the others the rest in equal parts) and the samples of
//! the objects read slower than asked say so (`slowed`). An object is read
//! at the fastest interval its requests ask, with the rights of the
//! caller who asked it (the earliest among equals), and every request on
//! it gets each sample.
//!
//! An object a running TPDO of the node carries (the decoded TPDOs,
//! [`crate::ServedBus::values`]) takes no SDO at all: its sample is the
//! TPDO's, each time a frame brings it. Nothing is sampled unless asked:
//! the node's task ends with its last request (its handle dropped).
//!
//! [`NodeSchedule`] and [`fair_interval`] are sans I/O; the task reads
//! through [`NodeReads`], the gateway's own (the node's read operation, its
//! decoded TPDOs), a fake in the tests.

use std::collections::{BTreeMap, HashMap};
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, SystemTime};

use tokio::sync::watch;
use tokio::time::Instant;

use crate::canopen::NodeId;
use crate::canopen::nmt::NmtState;
use crate::{Caller, Gateway, GatewayError};

/// The default `sdo_samples_per_s`: the SDO uploads a second that sampled
/// objects may take of one node.
pub const DEFAULT_SDO_SAMPLES_PER_S: u32 = 20;
/// The largest `sdo_samples_per_s`: about what an expedited upload's round
/// trip allows at 1 Mbit/s.
pub const MAX_SDO_SAMPLES_PER_S: u32 = 1000;

/// An object of a node's dictionary: index and sub-index.
type Object = (u16, u8);

/// A node of a bus: its bus's name and its node ID.
type NodeKey = (String, u8);

/// One sample of an object, as every request on it gets it.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectSample {
    /// Index and sub-index.
    pub object: (u16, u8),
    /// Its bytes, or the read's error.
    pub data: Result<Vec<u8>, GatewayError>,
    /// Read slower than asked: the node's bound gave it less.
    pub slowed: bool,
    /// Brought by a TPDO frame (no SDO).
    pub carried: bool,
    /// When it was taken: the upload's start, or when the frame came.
    pub at: SystemTime,
}

/// Where a request's samples go, called from the node's sampler task.
pub type SampleSink = Arc<dyn Fn(ObjectSample) + Send + Sync>;

/// A TPDO-carried object's newest bytes: `seen` changes with each frame
/// that brought them.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Carried {
    pub(crate) seen: (Instant, u64),
    pub(crate) data: Vec<u8>,
}

type ReadFuture<'a> = Pin<Box<dyn Future<Output = Result<Vec<u8>, GatewayError>> + Send + 'a>>;

/// What a node's sampler reads through: the gateway's reads and decoded
/// TPDOs, a fake in the tests.
pub(crate) trait NodeReads: Send + Sync + 'static {
    /// `Some` when a running TPDO of the node carries the object (its
    /// newest bytes, `None` before a frame brought them): no SDO for it.
    fn carried(&self, node: &NodeKey, object: Object) -> Option<Option<Carried>>;
    /// One SDO upload of the object, with `caller`'s rights.
    fn read<'a>(&'a self, node: &'a NodeKey, object: Object, caller: &'a Caller) -> ReadFuture<'a>;
    /// Changes with each TPDO frame of the node; `None`: no TPDOs.
    fn frames(&self, node: &NodeKey) -> Option<watch::Receiver<u64>>;
}

/// The gateway's reads: the node's read operation (its policy and audit)
/// and the bus's decoded TPDOs.
struct GatewayReads(Gateway);

impl NodeReads for GatewayReads {
    fn carried(&self, node: &NodeKey, object: Object) -> Option<Option<Carried>> {
        let bus = self.0.bus(&node.0).ok()?;
        let id = NodeId::new(node.1).ok()?;
        bus.values().carrier(id, object.0, object.1)?;
        // A TPDO runs only while the node is operational: before, the
        // object is read over SDO.
        let running = bus
            .node(id)
            .is_some_and(|info| info.nmt == Some(NmtState::Operational));
        if !running {
            return None;
        }
        let value = bus.values().value(id, object.0, object.1);
        Some(value.map(|value| Carried {
            seen: (value.at, value.count),
            data: value.raw_bytes(),
        }))
    }

    fn read<'a>(&'a self, node: &'a NodeKey, object: Object, caller: &'a Caller) -> ReadFuture<'a> {
        Box::pin(async move {
            self.0
                .node_handle(&node.0, &node.1.to_string())?
                .read_object(caller, object.0, object.1)
                .await
        })
    }

    fn frames(&self, node: &NodeKey) -> Option<watch::Receiver<u64>> {
        let bus = self.0.bus(&node.0).ok()?;
        Some(bus.values().watch_frames(NodeId::new(node.1).ok()?))
    }
}

/// The sampling interval every object gets at most as often as, when the
/// objects ask `asked` (their intervals) of a node bounded to
/// `samples_per_s`: `None` when the bound gives each what it asks, else the
/// max-min fair share (the objects asking less keep their rate, the others
/// share the rest equally).
pub(crate) fn fair_interval(asked: &[Duration], samples_per_s: u32) -> Option<Duration> {
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
pub(crate) struct NodeSchedule {
    spacing: Duration,
    samples_per_s: u32,
    asked: BTreeMap<Object, Duration>,
    due: BTreeMap<Object, Instant>,
    share: Option<Duration>,
    last: Option<Instant>,
}

impl NodeSchedule {
    pub(crate) fn new(samples_per_s: u32) -> Self {
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
    pub(crate) fn plan(&mut self, asked: BTreeMap<Object, Duration>, now: Instant) {
        self.due.retain(|object, _| asked.contains_key(object));
        for object in asked.keys() {
            self.due.entry(*object).or_insert(now);
        }
        let intervals: Vec<Duration> = asked.values().copied().collect();
        self.share = fair_interval(&intervals, self.samples_per_s);
        self.asked = asked;
    }

    /// The interval `object` is sampled at.
    pub(crate) fn interval(&self, object: Object) -> Duration {
        let asked = self.asked.get(&object).copied().unwrap_or_default();
        self.share.map_or(asked, |share| asked.max(share))
    }

    /// Sampled slower than its requests ask.
    pub(crate) fn overloaded(&self, object: Object) -> bool {
        self.interval(object) > self.asked.get(&object).copied().unwrap_or_default()
    }

    /// The next object to read and when: the one due first (the earliest
    /// asked first among equals), not before the bound allows.
    pub(crate) fn next(&self) -> Option<(Object, Instant)> {
        let (object, due) = self
            .due
            .iter()
            .min_by_key(|(object, due)| (**due, **object))?;
        let allowed = self
            .last
            .map_or(*due, |last| (last + self.spacing).max(*due));
        Some((*object, allowed))
    }

    /// `object` was read at `at` (when its upload started).
    pub(crate) fn sampled(&mut self, object: Object, at: Instant) {
        self.last = Some(at);
        let interval = self.interval(object);
        if let Some(due) = self.due.get_mut(&object) {
            *due = at + interval;
        }
    }
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|poison| poison.into_inner())
}

/// One caller's request on a node.
#[derive(Clone)]
struct Request {
    caller: Caller,
    objects: Vec<Object>,
    interval: Duration,
    sink: SampleSink,
}

/// The requests on a node, by their number (the earliest first).
type Requests = BTreeMap<u64, Request>;

/// The newest sample of each object a node's sampler took.
type Latest = Arc<Mutex<HashMap<Object, ObjectSample>>>;

struct NodeSampler {
    requests: watch::Sender<Requests>,
    latest: Latest,
    task: tokio::task::JoinHandle<()>,
}

/// Every node's sampler: the bound and the requests, for every caller.
pub(crate) struct Samplers {
    samples_per_s: u32,
    next: Mutex<u64>,
    nodes: Mutex<HashMap<NodeKey, NodeSampler>>,
}

impl std::fmt::Debug for Samplers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Samplers")
            .field("samples_per_s", &self.samples_per_s)
            .finish_non_exhaustive()
    }
}

impl Default for Samplers {
    fn default() -> Self {
        Self::new(DEFAULT_SDO_SAMPLES_PER_S)
    }
}

impl Samplers {
    /// At most `samples_per_s` SDO samples a second per node.
    pub(crate) fn new(samples_per_s: u32) -> Self {
        Self {
            samples_per_s: samples_per_s.max(1),
            next: Mutex::new(0),
            nodes: Mutex::default(),
        }
    }

    /// A request on `node`, read through `reads` when it starts the node's
    /// sampler.
    fn request(
        self: &Arc<Self>,
        reads: Arc<dyn NodeReads>,
        node: NodeKey,
        request: Request,
    ) -> ObjectSampling {
        let id = {
            let mut next = lock(&self.next);
            *next += 1;
            *next
        };
        let mut nodes = lock(&self.nodes);
        if let Some(sampler) = nodes.get(&node)
            && !sampler.task.is_finished()
        {
            sampler.requests.send_modify(|requests| {
                requests.insert(id, request);
            });
        } else {
            let (sender, receiver) = watch::channel(Requests::from([(id, request)]));
            let latest = Latest::default();
            let task = tokio::spawn(sample_node(
                reads.clone(),
                node.clone(),
                receiver,
                self.samples_per_s,
                latest.clone(),
            ));
            nodes.insert(
                node.clone(),
                NodeSampler {
                    requests: sender,
                    latest,
                    task,
                },
            );
        }
        ObjectSampling {
            samplers: self.clone(),
            reads,
            node,
            id,
        }
    }

    fn change(&self, node: &NodeKey, id: u64, change: impl FnOnce(&mut Requests)) {
        let mut nodes = lock(&self.nodes);
        let Some(sampler) = nodes.get(node) else {
            return;
        };
        let mut empty = false;
        sampler.requests.send_modify(|requests| {
            if requests.contains_key(&id) {
                change(requests);
            }
            empty = requests.is_empty();
        });
        if empty && let Some(sampler) = nodes.remove(node) {
            sampler.task.abort();
        }
    }

    fn nodes(&self) -> Vec<(String, u8)> {
        let mut nodes = lock(&self.nodes);
        nodes.retain(|_, sampler| !sampler.task.is_finished());
        let mut sampled: Vec<(String, u8)> = nodes.keys().cloned().collect();
        sampled.sort();
        sampled
    }
}

impl Drop for Samplers {
    fn drop(&mut self) {
        for sampler in lock(&self.nodes).values() {
            sampler.task.abort();
        }
    }
}

/// One caller's objects of a node sampled ([`Gateway::sample_objects`]),
/// until [`ObjectSampling::end`] or its drop.
pub struct ObjectSampling {
    samplers: Arc<Samplers>,
    reads: Arc<dyn NodeReads>,
    node: NodeKey,
    id: u64,
}

impl std::fmt::Debug for ObjectSampling {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ObjectSampling")
            .field("node", &self.node)
            .field("id", &self.id)
            .finish_non_exhaustive()
    }
}

impl ObjectSampling {
    /// The objects sampled every `interval` from now.
    pub fn set_interval(&self, interval: Duration) {
        self.samplers.change(&self.node, self.id, |requests| {
            if let Some(request) = requests.get_mut(&self.id) {
                request.interval = interval;
            }
        });
    }

    /// The newest sample of each of its objects the gateway holds (taken
    /// for any request on the node, or the carrying TPDO's newest), for a
    /// value to start with.
    pub fn latest(&self) -> Vec<ObjectSample> {
        let objects = {
            let nodes = lock(&self.samplers.nodes);
            let Some(sampler) = nodes.get(&self.node) else {
                return Vec::new();
            };
            let objects = sampler
                .requests
                .borrow()
                .get(&self.id)
                .map(|request| request.objects.clone())
                .unwrap_or_default();
            let latest = lock(&sampler.latest);
            objects
                .into_iter()
                .map(|object| (object, latest.get(&object).cloned()))
                .collect::<Vec<_>>()
        };
        objects
            .into_iter()
            .filter_map(|(object, sample)| {
                sample.or_else(|| {
                    let carried = self.reads.carried(&self.node, object).flatten()?;
                    Some(ObjectSample {
                        object,
                        data: Ok(carried.data),
                        slowed: false,
                        carried: true,
                        at: SystemTime::now(),
                    })
                })
            })
            .collect()
    }

    /// Ends the request (as its drop does): the node's sampler ends with
    /// its last one.
    pub fn end(self) {}
}

impl Drop for ObjectSampling {
    fn drop(&mut self) {
        self.samplers.change(&self.node, self.id, |requests| {
            requests.remove(&self.id);
        });
    }
}

impl Gateway {
    /// `objects` of `node` on `bus` sampled every `interval` for `caller`,
    /// each sample handed to `sink` (from the node's sampler task) until
    /// the returned handle is dropped or ended. The SDO reads are the
    /// node's read operation with `caller`'s rights; the node's samples of
    /// every caller and door together stay within the gateway's
    /// `sdo_samples_per_s`, shared fairly, and an object a running TPDO
    /// carries takes no SDO. An unknown bus or an id that is no node ID is
    /// an error; a node not (yet) heard is sampled, each read its error.
    pub fn sample_objects(
        &self,
        caller: &Caller,
        bus: &str,
        node: u8,
        objects: Vec<(u16, u8)>,
        interval: Duration,
        sink: SampleSink,
    ) -> Result<ObjectSampling, GatewayError> {
        NodeId::new(node)
            .map_err(|err| GatewayError::InvalidRequest(format!("node id {node}: {err}")))?;
        if objects.is_empty() {
            return Err(GatewayError::InvalidRequest(
                "no objects to sample".to_string(),
            ));
        }
        self.bus(bus)?;
        let request = Request {
            caller: caller.clone(),
            objects,
            interval,
            sink,
        };
        Ok(self.samplers.request(
            Arc::new(GatewayReads(self.clone())),
            (bus.to_string(), node),
            request,
        ))
    }

    /// The nodes sampled now (bus, node ID), in order.
    pub fn sampled_nodes(&self) -> Vec<(String, u8)> {
        self.samplers.nodes()
    }

    /// The bound on the SDO samples a second per node.
    pub fn sdo_samples_per_s(&self) -> u32 {
        self.samplers.samples_per_s
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

/// Hands `sample` to every request on its object, and keeps it as the
/// newest.
fn deliver(requests: &Requests, latest: &Latest, sample: ObjectSample) {
    lock(latest).insert(sample.object, sample.clone());
    for request in requests.values() {
        if request.objects.contains(&sample.object) {
            (request.sink)(sample.clone());
        }
    }
}

/// One node's sampler: until its requests are gone, the TPDO-carried
/// objects taken as their frames come, the others read over SDO as the
/// [`NodeSchedule`] says.
async fn sample_node(
    reads: Arc<dyn NodeReads>,
    node: NodeKey,
    mut requests: watch::Receiver<Requests>,
    samples_per_s: u32,
    latest: Latest,
) {
    let mut schedule = NodeSchedule::new(samples_per_s);
    let mut frames = reads.frames(&node);
    let mut seen: HashMap<Object, (Instant, u64)> = HashMap::new();
    loop {
        let asked = requests.borrow_and_update().clone();
        if asked.is_empty() {
            return;
        }
        // Each object at the fastest interval of the requests on it, read
        // with that request's caller (the earliest among equals).
        let mut objects: BTreeMap<Object, &Request> = BTreeMap::new();
        for request in asked.values() {
            for object in &request.objects {
                match objects.get(object) {
                    Some(fastest) if fastest.interval <= request.interval => {}
                    _ => {
                        objects.insert(*object, request);
                    }
                }
            }
        }
        seen.retain(|object, _| objects.contains_key(object));
        lock(&latest).retain(|object, _| objects.contains_key(object));
        let mut over_sdo = BTreeMap::new();
        // The frames wake the task only while it has objects they carry.
        let mut tpdo_fed = false;
        for (object, request) in &objects {
            match reads.carried(&node, *object) {
                Some(carried) => {
                    tpdo_fed = true;
                    let Some(carried) = carried else { continue };
                    if seen.get(object) == Some(&carried.seen) {
                        continue;
                    }
                    seen.insert(*object, carried.seen);
                    let sample = ObjectSample {
                        object: *object,
                        data: Ok(carried.data),
                        slowed: false,
                        carried: true,
                        at: SystemTime::now(),
                    };
                    deliver(&asked, &latest, sample);
                }
                None => {
                    seen.remove(object);
                    over_sdo.insert(*object, request.interval);
                }
            }
        }
        schedule.plan(over_sdo, Instant::now());
        let next = schedule.next();
        let at = next.map_or_else(Instant::now, |(_, at)| at);
        tokio::select! {
            changed = requests.changed() => {
                if changed.is_err() {
                    return;
                }
            }
            () = frame_changed(&mut frames), if tpdo_fed => {}
            () = tokio::time::sleep_until(at), if next.is_some() => {
                let Some((object, _)) = next else { continue };
                let Some(request) = objects.get(&object) else { continue };
                let started = Instant::now();
                let taken = SystemTime::now();
                let data = reads.read(&node, object, &request.caller).await;
                if let Err(error) = &data {
                    tracing::debug!(
                        "sample of {} on {}/{}: {error}",
                        crate::object_item(object.0, object.1),
                        node.0,
                        node.1
                    );
                }
                let slowed = schedule.overloaded(object);
                schedule.sampled(object, started);
                let sample = ObjectSample { object, data, slowed, carried: false, at: taken };
                deliver(&asked, &latest, sample);
            }
        }
    }
}

#[cfg(test)]
mod tests;
