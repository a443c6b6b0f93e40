//! The values the nodes of a bus send in their TPDOs (CiA 301 §7.2.2),
//! decoded by each node's mapping as read from the node.
//!
//! A [`TpdoValues`] task follows the bus and the node registry. When a node
//! is identified (and whenever [`TpdoValues::refresh`] is asked, after a
//! re-mapping), it reads the node's TPDO configurations over the node's SDO
//! channel (queued with every other transfer to it) and keeps a
//! [`TpdoDecoder`] per valid TPDO. Every TPDO frame is then decoded, and the
//! newest value of each mapped object is kept with when it came. A node
//! that boots again forgets its decoders and values until it is read again:
//! its mapping may be another one after a reset.
//!
//! This is the gateway's own view of the process data; the REST API shows
//! it, and [`TpdoValues::subscribe`] publishes it for the telemetry stream
//! (`docs/websocket.md`, `buses/{bus}/nodes/{id}/values`): one
//! topic per node, made on its first reader, whose producer publishes the
//! node's values by name at most at the rate its readers want however many
//! frames come (8,000 TPDOs a second are not 8,000 JSON objects), the
//! newest values always last (a publish follows the last frame of a burst),
//! and nothing while nobody reads.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use serde_json::Value as Json;
use tokio::sync::broadcast::error::RecvError as EventRecvError;
use tokio::sync::{Notify, broadcast, watch};
use tokio::task::JoinHandle;
use tokio::time::Instant;

use super::pdo::{TpdoDecoder, pdo_numbers, read_config};
use super::producers::{IDLE_CHECK, Lease, TopicSet, period};
use super::registry::{NodeEvent, NodeRegistry};
use super::telemetry::{TopicReceiver, ValueTopic};
use crate::can::{Bus, CanId, RecvError};
use crate::canopen::NodeId;
use crate::canopen::nmt::NmtState;
use crate::canopen::od::{Value, format_index};
use crate::canopen::pdo::PdoKind;

/// How long to wait before trying a node's TPDOs again after a read failed
/// (the node was busy booting, or stopped).
const RETRY_AFTER: Duration = Duration::from_secs(2);

/// The newest value of one mapped object.
#[derive(Debug, Clone, PartialEq)]
pub struct TpdoValue {
    pub index: u16,
    pub sub: u8,
    /// The EDS name (`"a1_Statusword"`); `None` without EDS.
    pub name: Option<String>,
    /// Typed by the EDS; `None` for an object the EDS does not describe.
    pub value: Option<Value>,
    /// The field's bits as sent, zero-extended.
    pub raw: u64,
    /// The field's width in bits.
    pub bits: u8,
    /// The TPDO it came in (1–512).
    pub pdo: u16,
    /// When its last frame came.
    pub at: Instant,
    /// Frames it came in since the mapping was read.
    pub count: u64,
}

impl TpdoValue {
    /// The value as JSON, typed by the EDS (64-bit integers as strings);
    /// null for an object the EDS does not describe.
    pub fn value_json(&self) -> Json {
        self.value.as_ref().map_or(Json::Null, Value::to_json)
    }

    /// The field's bytes as sent, little-endian.
    pub fn raw_bytes(&self) -> Vec<u8> {
        let bytes = self.raw.to_le_bytes();
        let len = usize::from(self.bits).div_ceil(8).min(bytes.len());
        bytes[..len].to_vec()
    }

    /// [`TpdoValue::raw_bytes`] as hex, as the API writes raw values.
    pub fn raw_hex(&self) -> String {
        self.raw_bytes()
            .iter()
            .map(|byte| format!("{byte:02x}"))
            .collect()
    }

    /// The key of the value in the `values` topic: its EDS name, else
    /// `"0x6041:0"`.
    pub fn key(&self) -> String {
        self.name
            .clone()
            .unwrap_or_else(|| format!("{}:{}", format_index(self.index), self.sub))
    }

    /// The value in the `values` topic: typed as [`TpdoValue::value_json`],
    /// or `{"raw": "hex"}` for an object the EDS does not describe.
    pub fn topic_json(&self) -> Json {
        match &self.value {
            Some(value) => value.to_json(),
            None => serde_json::json!({ "raw": self.raw_hex() }),
        }
    }

    /// The value as a whole number: typed, else its raw bits sign-extended
    /// when `signed`.
    pub fn as_i64(&self, signed: bool) -> i64 {
        if let Some(value) = self.value.as_ref().and_then(Value::as_i128) {
            return value as i64;
        }
        let bits = u32::from(self.bits.clamp(1, 64));
        if signed && bits < 64 {
            let shift = 64 - bits;
            ((self.raw << shift) as i64) >> shift
        } else {
            self.raw as i64
        }
    }
}

/// The values of one TPDO frame as decoded, for a follower that wants every
/// change rather than the newest value (`TpdoValues::follow`).
#[derive(Debug, Clone)]
pub struct TpdoFrame {
    pub node: NodeId,
    /// The frame's mapped values, dummies left out, as
    /// `TpdoValues::values` keeps them.
    pub values: Vec<TpdoValue>,
}

/// How many decoded frames a follower may fall behind before it loses the
/// oldest: a third of a second of 127 nodes each sending four TPDOs every
/// 10 ms.
pub(crate) const FOLLOW_QUEUE: usize = 16_384;

/// One node's TPDOs as the gateway decodes them.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeTpdos {
    /// The valid TPDOs: number and decoder.
    pub decoders: Vec<(u16, TpdoDecoder)>,
    /// When they were read.
    pub read_at: Instant,
}

impl NodeTpdos {
    /// The valid TPDO (its number) that carries object `index`:`sub`, the
    /// lowest numbered when several do.
    pub fn carrier(&self, index: u16, sub: u8) -> Option<u16> {
        self.decoders
            .iter()
            .filter(|(_, decoder)| {
                decoder
                    .mapping()
                    .entries()
                    .iter()
                    .any(|entry| entry.index == index && entry.sub == sub)
            })
            .map(|(number, _)| *number)
            .min()
    }
}

#[derive(Default)]
struct State {
    /// The TPDOs read, by node.
    nodes: HashMap<NodeId, NodeTpdos>,
    /// Which node and TPDO a COB-ID belongs to.
    by_cob_id: HashMap<CanId, (NodeId, usize)>,
    values: HashMap<NodeId, BTreeMap<(u16, u8), TpdoValue>>,
    /// Frames on a known TPDO COB-ID whose data did not fit the mapping.
    malformed: u64,
    /// Counts each node's decoded TPDO frames, for whoever follows them
    /// (made on the first request: a node nobody follows costs a lookup).
    frames: HashMap<NodeId, watch::Sender<u64>>,
    /// Every decoded frame, for the followers (made on the first one).
    followers: Option<broadcast::Sender<TpdoFrame>>,
    /// Told when a frame went to the followers.
    wakes: Vec<Arc<Notify>>,
}

impl State {
    fn index(&mut self) {
        self.by_cob_id = self
            .nodes
            .iter()
            .flat_map(|(&node, tpdos)| {
                tpdos
                    .decoders
                    .iter()
                    .enumerate()
                    .map(move |(slot, (_, decoder))| (decoder.cob_id(), (node, slot)))
            })
            .collect();
    }

    fn forget(&mut self, node: NodeId) {
        self.nodes.remove(&node);
        self.values.remove(&node);
        self.index();
    }
}

/// The decoded TPDO values of every node of one bus; cheap to clone. The
/// tasks stop when the last clone is dropped.
#[derive(Clone)]
pub struct TpdoValues {
    shared: Arc<Shared>,
    /// The `values` topics by node; dropped (and their producers ended)
    /// with the last handle.
    topics: Arc<TopicSet<NodeId>>,
    _tasks: Arc<TaskGuard>,
}

/// What the tasks share with the handle (not the handle itself, so that
/// dropping the last handle stops them).
struct Shared {
    state: Mutex<State>,
    registry: NodeRegistry,
}

struct TaskGuard(Vec<JoinHandle<()>>);

impl Drop for TaskGuard {
    fn drop(&mut self) {
        for task in &self.0 {
            task.abort();
        }
    }
}

impl TpdoValues {
    /// Follows `bus` and the nodes `registry` identifies.
    pub fn spawn(bus: Bus, registry: NodeRegistry) -> Self {
        let shared = Arc::new(Shared {
            state: Mutex::new(State::default()),
            registry,
        });
        let frames = tokio::spawn(decode_frames(bus, shared.clone()));
        let events = tokio::spawn(follow_nodes(shared.clone()));
        let writes = tokio::spawn(follow_writes(shared.clone()));
        Self {
            shared,
            topics: Arc::new(TopicSet::new()),
            _tasks: Arc::new(TaskGuard(vec![frames, events, writes])),
        }
    }

    /// A reader of the `values` topic of `node` wanting `rate_hz`: a JSON
    /// object of the newest value of every object the node's TPDOs carry,
    /// by EDS name (`"0x6041:0"` without one), typed as
    /// [`TpdoValue::topic_json`]. A node not known yet, or without TPDOs,
    /// has a topic that stays quiet until its values come.
    pub fn subscribe(&self, node: NodeId, rate_hz: f64) -> TopicReceiver {
        let shared = self.shared.clone();
        self.topics.subscribe(node, rate_hz, move |topic, lease| {
            publish_values(shared, node, topic, lease)
        })
    }

    /// The `values` topic of `node`, if anyone ever subscribed to it.
    pub fn topic(&self, node: NodeId) -> Option<ValueTopic> {
        self.topics.topic(&node)
    }

    /// Changes whenever a TPDO frame of `node` has been decoded (the value
    /// counts them); the newest values are then in [`TpdoValues::values`].
    pub fn watch_frames(&self, node: NodeId) -> watch::Receiver<u64> {
        self.shared.watch_frames(node)
    }

    /// Every TPDO frame decoded from now on, in order, with `wake` told
    /// (a permit kept if nobody waits) after each: a follower that drains
    /// the receiver when woken sees every change however many come between
    /// its turns, up to [`FOLLOW_QUEUE`] frames, beyond which it is told
    /// how many it lost. Costs nothing until someone follows.
    pub fn follow(&self, wake: Arc<Notify>) -> broadcast::Receiver<TpdoFrame> {
        let mut state = self.lock();
        state.wakes.retain(|wake| Arc::strong_count(wake) > 1);
        state.wakes.push(wake);
        state
            .followers
            .get_or_insert_with(|| broadcast::channel(FOLLOW_QUEUE).0)
            .subscribe()
    }

    /// The newest value of one mapped object of `node`.
    pub fn value(&self, node: NodeId, index: u16, sub: u8) -> Option<TpdoValue> {
        self.lock()
            .values
            .get(&node)
            .and_then(|values| values.get(&(index, sub)))
            .cloned()
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.shared.lock()
    }

    /// Reads `node`'s TPDO configurations again and decodes by them from
    /// now on; the values of objects no longer mapped are forgotten.
    pub async fn refresh(&self, node: NodeId) -> Result<(), super::sdo::SdoRequestError> {
        self.shared.refresh(node).await
    }

    /// The TPDOs of `node` as last read; `None` before they were read.
    pub fn tpdos(&self, node: NodeId) -> Option<NodeTpdos> {
        self.lock().nodes.get(&node).cloned()
    }

    /// The TPDO of `node` whose mapping carries object `index`:`sub` (the
    /// first by number when several do); `None` when none does or the
    /// node's TPDOs were not read yet. A door that wants the object's value
    /// takes it from [`TpdoValues::value`] then, with no SDO transfer.
    pub fn carrier(&self, node: NodeId, index: u16, sub: u8) -> Option<u16> {
        self.lock().nodes.get(&node)?.carrier(index, sub)
    }

    /// The newest value of every object `node`'s TPDOs carry, by index and
    /// sub-index.
    pub fn values(&self, node: NodeId) -> Vec<TpdoValue> {
        self.lock()
            .values
            .get(&node)
            .map(|values| values.values().cloned().collect())
            .unwrap_or_default()
    }

    /// Frames on a TPDO COB-ID too short for its mapping.
    pub fn malformed(&self) -> u64 {
        self.lock().malformed
    }
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // The state stays consistent between statements: a panic elsewhere
        // leaves nothing half-written to protect against.
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn watch_frames(&self, node: NodeId) -> watch::Receiver<u64> {
        self.lock()
            .frames
            .entry(node)
            .or_insert_with(|| watch::Sender::new(0))
            .subscribe()
    }

    /// The `values` topic's data for `node`; `None` before any value came.
    fn values_json(&self, node: NodeId) -> Option<Json> {
        let state = self.lock();
        let values = state
            .values
            .get(&node)
            .filter(|values| !values.is_empty())?;
        Some(Json::Object(
            values
                .values()
                .map(|value| (value.key(), value.topic_json()))
                .collect(),
        ))
    }

    async fn refresh(&self, node: NodeId) -> Result<(), super::sdo::SdoRequestError> {
        let Some(info) = self.registry.node(node) else {
            return Ok(());
        };
        let channel = match self.registry.sdo(node) {
            Ok(channel) => channel,
            Err(_) => return Ok(()),
        };
        let dict = info.eds_entry.as_ref().map(|entry| &entry.eds.dictionary);
        let mut decoders = Vec::new();
        for number in pdo_numbers(dict, PdoKind::Tpdo) {
            let config = read_config(&channel, dict, PdoKind::Tpdo, number).await?;
            if !config.enabled() || config.mapping.is_empty() {
                continue;
            }
            if let Ok(decoder) = config.decoder(dict) {
                decoders.push((number, decoder));
            }
        }
        let mut state = self.lock();
        let kept: Vec<(u16, u8)> = decoders
            .iter()
            .flat_map(|(_, decoder)| {
                decoder
                    .mapping()
                    .entries()
                    .iter()
                    .map(|entry| (entry.index, entry.sub))
                    .collect::<Vec<_>>()
            })
            .collect();
        if let Some(values) = state.values.get_mut(&node) {
            values.retain(|key, _| kept.contains(key));
        }
        state.nodes.insert(
            node,
            NodeTpdos {
                decoders,
                read_at: Instant::now(),
            },
        );
        state.index();
        Ok(())
    }
}

async fn decode_frames(bus: Bus, shared: Arc<Shared>) {
    let mut frames = bus.subscribe();
    loop {
        let frame = match frames.recv().await {
            Ok(timed) => timed.frame,
            Err(RecvError::Lagged(_)) => continue,
            Err(RecvError::Closed) => return,
        };
        if frame.is_remote() {
            continue;
        }
        let now = Instant::now();
        let mut state = shared.lock();
        let Some(&(node, slot)) = state.by_cob_id.get(&frame.id()) else {
            continue;
        };
        let Some((pdo, decoded)) = state
            .nodes
            .get(&node)
            .and_then(|tpdos| tpdos.decoders.get(slot))
            .map(|(pdo, decoder)| (*pdo, decoder.decode(frame.data())))
        else {
            continue;
        };
        let decoded = match decoded {
            Ok(decoded) => decoded,
            Err(_) => {
                state.malformed += 1;
                continue;
            }
        };
        let followed = state
            .followers
            .as_ref()
            .is_some_and(|followers| followers.receiver_count() > 0);
        let mut frame_values = Vec::new();
        let values = state.values.entry(node).or_default();
        for field in decoded {
            let key = (field.entry.index, field.entry.sub);
            let count = values.get(&key).map_or(0, |old| old.count) + 1;
            let value = TpdoValue {
                index: field.entry.index,
                sub: field.entry.sub,
                name: field.name,
                value: field.value,
                raw: field.raw,
                bits: field.entry.bits,
                pdo,
                at: now,
                count,
            };
            if followed {
                frame_values.push(value.clone());
            }
            values.insert(key, value);
        }
        if followed && let Some(followers) = &state.followers {
            let _ = followers.send(TpdoFrame {
                node,
                values: frame_values,
            });
            for wake in &state.wakes {
                wake.notify_one();
            }
        }
        if let Some(frames) = state.frames.get(&node) {
            frames.send_modify(|count| *count = count.wrapping_add(1));
        }
    }
}

/// The producer of `node`'s `values` topic: a publish when a frame came,
/// at most one per period of the fastest reader's rate; frames that come
/// meanwhile are in the next one, which follows when the period is over.
async fn publish_values(
    shared: Arc<Shared>,
    node: NodeId,
    topic: ValueTopic,
    lease: Lease<NodeId>,
) {
    let mut frames = shared.watch_frames(node);
    // A first reader gets the values known at once.
    let mut pending = true;
    let mut readers = 0;
    // When the next publish may go: one period after the last one's due
    // time, on a steady cadence (one period after the publish itself would
    // drift by the scheduling delay and the timer's rounding every time).
    let mut due: Option<Instant> = None;
    loop {
        if !lease.keep_going() {
            return;
        }
        // A reader that joins gets the values known now, not only the next
        // ones (which may be long in coming).
        let now_readers = topic.receivers();
        pending |= now_readers > readers;
        readers = now_readers;
        if pending {
            if let Some(due) = due {
                tokio::time::sleep_until(due).await;
            }
            // Seen before reading: a frame decoded from here on is in this
            // publish or calls for the next one.
            frames.borrow_and_update();
            if let Some(data) = shared.values_json(node) {
                topic.publish(data);
                let every = period(topic.wanted_rate_hz().unwrap_or(1.0));
                let now = Instant::now();
                // Behind by more than a period (a stall, or frames after a
                // pause): start the cadence again from now.
                due = Some(due.map_or(now, |due| due.max(now - every)) + every);
            }
            pending = false;
        }
        tokio::select! {
            changed = frames.changed() => match changed {
                Ok(()) => pending = true,
                Err(_) => return,
            },
            () = topic.readers_changed() => {}
            () = tokio::time::sleep(IDLE_CHECK) => {}
        }
    }
}

/// Reads a node's TPDOs once it is identified; forgets them when it boots.
async fn follow_nodes(values: Arc<Shared>) {
    let mut events = values.registry.subscribe();
    // Nodes identified before the task subscribed.
    for info in values.registry.nodes() {
        if info.eds_entry.is_some() || info.identity.is_some() {
            spawn_refresh(&values, info.id);
        }
    }
    loop {
        match events.recv().await {
            Ok(NodeEvent::Identified { node, .. }) => spawn_refresh(&values, node),
            Ok(NodeEvent::NmtChanged {
                node,
                to: NmtState::BootUp,
                ..
            }) => values.lock().forget(node),
            Ok(_) => {}
            Err(EventRecvError::Lagged(_)) => {}
            Err(EventRecvError::Closed) => return,
        }
    }
}

/// How long the TPDO parameters of a node stay unwritten before the
/// decoders follow what was written: a re-mapping (CiA 301 §7.3.4) is a
/// burst of writes, read once when it is over.
pub(crate) const WRITES_SETTLE: Duration = Duration::from_millis(100);

/// Whether `index` is a TPDO's communication or mapping parameter (CiA 301
/// §7.5.2.35 to §7.5.2.38: 0x1800-0x19FF, 0x1A00-0x1BFF).
fn is_tpdo_parameter(index: u16) -> bool {
    (0x1800..=0x1BFF).contains(&index)
}

/// Reads a node's TPDOs again once a write to their parameters settled,
/// whichever door or task wrote them (a CiA 309 write of 0x1A00 as much as
/// the PDO editor's), unless they were read since (the PDO editor reads
/// them itself at the end of its procedure).
async fn follow_writes(values: Arc<Shared>) {
    let mut writes = values.registry.subscribe_writes();
    // The last write to each node's TPDO parameters not followed yet.
    let mut written: BTreeMap<NodeId, Instant> = BTreeMap::new();
    loop {
        let settled = written.values().min().map(|last| *last + WRITES_SETTLE);
        tokio::select! {
            write = writes.recv() => match write {
                Ok(write) if is_tpdo_parameter(write.index) => {
                    written.insert(write.node, Instant::now());
                }
                Ok(_) => {}
                // Writes were missed: every node with TPDOs is read again.
                Err(EventRecvError::Lagged(_)) => {
                    let now = Instant::now();
                    for node in values.lock().nodes.keys() {
                        written.insert(*node, now);
                    }
                }
                Err(EventRecvError::Closed) => return,
            },
            () = sleep_until_some(settled) => {
                let now = Instant::now();
                let due: Vec<(NodeId, Instant)> = written
                    .iter()
                    .filter(|(_, last)| **last + WRITES_SETTLE <= now)
                    .map(|(node, last)| (*node, *last))
                    .collect();
                for (node, last) in due {
                    written.remove(&node);
                    let read_since = values
                        .lock()
                        .nodes
                        .get(&node)
                        .is_some_and(|tpdos| tpdos.read_at > last);
                    if !read_since {
                        spawn_refresh(&values, node);
                    }
                }
            }
        }
    }
}

/// Sleeps until `deadline`; forever without one.
async fn sleep_until_some(deadline: Option<Instant>) {
    match deadline {
        Some(deadline) => tokio::time::sleep_until(deadline).await,
        None => std::future::pending().await,
    }
}

/// Reads the node's TPDOs in a task of its own, trying again a few times
/// while the node cannot answer (stopped, or busy).
fn spawn_refresh(values: &Arc<Shared>, node: NodeId) {
    let values = values.clone();
    tokio::spawn(async move {
        for _ in 0..3 {
            match values.refresh(node).await {
                Ok(()) => return,
                Err(err) => {
                    tracing::debug!("node {node}: TPDO mapping not read: {err}");
                    tokio::time::sleep(RETRY_AFTER).await;
                }
            }
        }
    });
}

#[cfg(test)]
mod carrier_tests {
    use super::*;
    use crate::canopen::pdo::{MappingEntry, PdoMapping};

    #[test]
    fn the_tpdo_that_maps_an_object_carries_it() {
        let decoder = |cob: u32, entries: Vec<MappingEntry>| {
            TpdoDecoder::new(
                CanId::standard(cob).unwrap(),
                PdoMapping::new(entries).unwrap(),
                None,
            )
        };
        let tpdos = NodeTpdos {
            decoders: vec![
                (
                    3,
                    decoder(
                        0x381,
                        vec![
                            MappingEntry::new(0x6064, 0, 32),
                            MappingEntry::new(0x6041, 0, 16),
                        ],
                    ),
                ),
                (1, decoder(0x181, vec![MappingEntry::new(0x6041, 0, 16)])),
            ],
            read_at: Instant::now(),
        };
        assert_eq!(tpdos.carrier(0x6064, 0), Some(3));
        // Carried by two: the lowest numbered.
        assert_eq!(tpdos.carrier(0x6041, 0), Some(1));
        // Another sub-index, another object: not carried.
        assert_eq!(tpdos.carrier(0x6064, 1), None);
        assert_eq!(tpdos.carrier(0x1017, 0), None);
    }
}
