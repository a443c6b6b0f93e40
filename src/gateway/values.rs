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
//! it, and the telemetry stream will publish it.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::sync::broadcast::error::RecvError as EventRecvError;
use tokio::task::JoinHandle;
use tokio::time::Instant;

use super::pdo::{TpdoDecoder, pdo_numbers, read_config};
use super::registry::{NodeEvent, NodeRegistry};
use crate::can::{Bus, CanId, RecvError};
use crate::canopen::NodeId;
use crate::canopen::nmt::NmtState;
use crate::canopen::od::Value;
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

/// One node's TPDOs as the gateway decodes them.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeTpdos {
    /// The valid TPDOs: number and decoder.
    pub decoders: Vec<(u16, TpdoDecoder)>,
    /// When they were read.
    pub read_at: Instant,
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
        Self {
            shared,
            _tasks: Arc::new(TaskGuard(vec![frames, events])),
        }
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
        let values = state.values.entry(node).or_default();
        for field in decoded {
            let key = (field.entry.index, field.entry.sub);
            let count = values.get(&key).map_or(0, |old| old.count) + 1;
            values.insert(
                key,
                TpdoValue {
                    index: field.entry.index,
                    sub: field.entry.sub,
                    name: field.name,
                    value: field.value,
                    raw: field.raw,
                    bits: field.entry.bits,
                    pdo,
                    at: now,
                    count,
                },
            );
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
