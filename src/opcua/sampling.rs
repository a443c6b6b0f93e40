//! Monitored variables read from a node's dictionary: the dictionary's
//! variables (`Nodes/{bus}/{id}/Dictionary/{entry}`), a CiA 401 module's
//! channels (`Io/{channel}`) and a UIO1LED's segment fields
//! (`Leds/{n}/{field}`), sampled by the gateway
//! ([`Gateway::sample_objects`]) and turned into values here.
//!
//! What an item watches ([`Watched`]) is made of objects: a dictionary
//! variable of its entry, a channel of the object its profile puts it in
//! (a digital channel is a bit of an 8-bit group, [`Channel::location`]),
//! a segment field of the object the UIO1LED's profile gives it
//! ([`crate::profiles::uioled::address`]; a colour of its four, red, green,
//! blue and white). The gateway samples objects, not variables: the items
//! on one variable are one request (at the fastest interval they ask, with
//! that item's session as the caller), the requests on one object one
//! sample (`di1` to `di8` of one group too), and a variable's value goes
//! out when it changed (a change of another bit of its group sends
//! nothing); a colour's once its four objects were read.
//!
//! The bound on a node's SDO samples, its fair share, the schedule and
//! the TPDO-carried objects (no SDO) are the gateway's, one per node for
//! every door (`crate::gateway::sampling`'s docs, docs/opcua.md
//! "Subscriptions"): here a sample read slower than asked ("slowed") is a
//! value with `GoodOverload` ("sampling has slowed down due to resource
//! limitations"), a failed read a value with its error's status. Nothing
//! is sampled unless monitored: a variable's request ends with its last
//! item (deleted, or its subscription or session gone).

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

use opcua::server::{MonitoredItemHandle, SubscriptionCache};
use opcua::types::{AttributeId, DataValue, DateTime, NodeId, StatusCode, Variant};

use super::browse::NodePath;
use super::io::LedField;
use super::status::status_of;
use crate::gateway::{Caller, Gateway, GatewayError, ObjectSample, ObjectSampling, SampleSink};
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

/// A dictionary entry's bytes as its value, typed by the node's EDS.
type Decode<'a> = &'a dyn Fn(Entry, &[u8]) -> Result<Variant, GatewayError>;

/// The newest read of one object: its bytes or the status of the error
/// that kept them, and whether it was sampled slower than asked.
#[derive(Debug, Clone)]
struct Read {
    data: Result<Vec<u8>, StatusCode>,
    slowed: bool,
}

/// A value that is an error's status, stamped now (a read's failure).
pub(super) fn failed(status: StatusCode) -> DataValue {
    DataValue {
        status: Some(status),
        source_timestamp: Some(DateTime::now()),
        server_timestamp: Some(DateTime::now()),
        ..Default::default()
    }
}

/// One monitored variable's newest reads of its objects and the value
/// last sent, sans I/O.
#[derive(Debug, Default)]
struct Variable {
    reads: HashMap<Entry, Read>,
    sent: Option<DataValue>,
}

impl Variable {
    /// Takes `sample` of one of `watched`'s objects: the value to send
    /// when it completes one (any of its objects when a TPDO brought it,
    /// else its last) that differs from the one last sent.
    fn take(
        &mut self,
        watched: Watched,
        sample: &ObjectSample,
        decode: Decode<'_>,
    ) -> Option<DataValue> {
        let objects = watched.objects();
        if !objects.contains(&sample.object) {
            return None;
        }
        let data = sample.data.clone().map_err(|error| {
            let (index, sub) = sample.object;
            tracing::debug!(
                "opcua: sample of {}: {error}",
                crate::gateway::object_item(index, sub)
            );
            status_of(&error)
        });
        self.reads.insert(
            sample.object,
            Read {
                data,
                slowed: sample.slowed,
            },
        );
        let completes = sample.carried || objects.last() == Some(&sample.object);
        if !completes {
            return None;
        }
        let value = self.value(watched, decode)?;
        let unchanged = self
            .sent
            .as_ref()
            .is_some_and(|last| last.value == value.value && last.status() == value.status());
        if unchanged {
            return None;
        }
        self.sent = Some(value.clone());
        Some(value)
    }

    /// `watched`'s value from the newest reads of its objects: `None`
    /// until each was read; the status of a failed read; `GoodOverload`
    /// when one was sampled slower than asked.
    fn value(&self, watched: Watched, decode: Decode<'_>) -> Option<DataValue> {
        let mut data: Vec<&[u8]> = Vec::new();
        let mut slowed = false;
        for entry in watched.objects() {
            let read = self.reads.get(&entry)?;
            match &read.data {
                Ok(bytes) => data.push(bytes),
                Err(status) => return Some(failed(*status)),
            }
            slowed |= read.slowed;
        }
        let value = match watched {
            Watched::Entry(entry) => decode(entry, data.first()?),
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
                tracing::debug!("opcua: {watched:?}: {error}");
                failed(status_of(&error))
            }
        })
    }

    /// The value an item that joins starts with: the one last sent, else
    /// one made of the gateway's newest samples (a carrying TPDO's, say),
    /// else none (the first sample, due at once, brings it).
    fn initial(
        &mut self,
        watched: Watched,
        latest: &[ObjectSample],
        decode: Decode<'_>,
    ) -> Option<DataValue> {
        if self.sent.is_some() {
            return self.sent.clone();
        }
        for sample in latest {
            if self.reads.contains_key(&sample.object) {
                continue;
            }
            let data = sample.data.clone().map_err(|error| status_of(&error));
            self.reads.insert(
                sample.object,
                Read {
                    data,
                    slowed: sample.slowed,
                },
            );
        }
        self.sent = self.value(watched, decode);
        self.sent.clone()
    }
}

fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|poison| poison.into_inner())
}

/// What one item asks: its interval and the caller whose reads sample it
/// (the session that asked it).
#[derive(Debug, Clone, PartialEq)]
struct Want {
    interval: Duration,
    caller: Caller,
}

struct Monitored {
    node: NodePath,
    watched: Watched,
    want: Want,
}

/// A monitored variable's request to the gateway: what it asks (its
/// fastest item's), and its values, shared with the request's sink.
struct Requested {
    want: Want,
    request: Option<ObjectSampling>,
    variable: Arc<Mutex<Variable>>,
}

#[derive(Default)]
struct State {
    items: HashMap<MonitoredItemHandle, Monitored>,
    variables: HashMap<(NodePath, Watched), Requested>,
}

/// Where the values go: the gateway (the requests, the EDS that types an
/// entry) and the subscriptions of namespace `ns`.
#[derive(Clone)]
struct Server {
    gateway: Gateway,
    subscriptions: Arc<SubscriptionCache>,
    ns: u16,
}

impl Server {
    fn decode(&self, node: &NodePath, entry: Entry, data: &[u8]) -> Result<Variant, GatewayError> {
        let handle = self
            .gateway
            .node_handle(&node.bus, &node.node.to_string())?;
        value_of(
            &super::space::entry(&handle, entry.0, entry.1)?,
            entry,
            data,
        )
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

    /// The gateway's request for `watched`, its samples turned into the
    /// variable's values and sent.
    fn request(
        &self,
        node: &NodePath,
        watched: Watched,
        want: &Want,
        variable: &Arc<Mutex<Variable>>,
    ) -> Option<ObjectSampling> {
        let sink: SampleSink = {
            let (server, node, variable) = (self.clone(), node.clone(), variable.clone());
            Arc::new(move |sample: ObjectSample| {
                let decode = |entry: Entry, data: &[u8]| server.decode(&node, entry, data);
                let value = lock(&variable).take(watched, &sample, &decode);
                if let Some(value) = value {
                    server.publish(&node, watched, value);
                }
            })
        };
        let request = self.gateway.sample_objects(
            &want.caller,
            &node.bus,
            node.node,
            watched.objects(),
            want.interval,
            sink,
        );
        match request {
            Ok(request) => Some(request),
            Err(error) => {
                tracing::debug!("opcua: {watched:?} on {}/{}: {error}", node.bus, node.node);
                None
            }
        }
    }
}

/// The monitored variables read from the nodes' dictionaries (dictionary,
/// I/O and LED variables) and their requests to the gateway.
#[derive(Default)]
pub struct Sampling {
    server: OnceLock<Server>,
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
    pub fn new() -> Self {
        Self::default()
    }

    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        lock(&self.state)
    }

    /// Starts sampling through `gateway`, sending to `subscriptions` (the
    /// server, once built): the items monitored before are sampled from
    /// now.
    pub fn start(&self, gateway: Gateway, subscriptions: Arc<SubscriptionCache>, ns: u16) {
        let server = Server {
            gateway,
            subscriptions,
            ns,
        };
        if self.server.set(server).is_err() {
            return;
        }
        let variables: Vec<(NodePath, Watched)> = {
            let state = self.state();
            state
                .items
                .values()
                .map(|item| (item.node.clone(), item.watched))
                .collect()
        };
        for (node, watched) in variables {
            self.update(&node, watched);
        }
    }

    /// A monitored item on `watched` of `node`, sampled every `interval_ms`
    /// (negative: the subscription's, [`SUBSCRIPTION_INTERVAL`]) with
    /// `caller`'s reads; the value it starts with, when there is one (the
    /// one last sent to the items on it, else the gateway's newest
    /// samples, else none: the first sample, due at once, brings it).
    pub fn monitor(
        &self,
        handle: MonitoredItemHandle,
        node: NodePath,
        watched: Watched,
        interval_ms: f64,
        caller: Caller,
    ) -> Option<DataValue> {
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
        self.update(&node, watched);
        let server = self.server.get()?;
        let state = self.state();
        let requested = state.variables.get(&(node.clone(), watched))?;
        let latest = requested
            .request
            .as_ref()
            .map(ObjectSampling::latest)
            .unwrap_or_default();
        let decode = |entry: Entry, data: &[u8]| server.decode(&node, entry, data);
        lock(&requested.variable).initial(watched, &latest, &decode)
    }

    /// The item's new sampling interval (ModifyMonitoredItems).
    pub fn modify(&self, handle: MonitoredItemHandle, interval_ms: f64) {
        let variable = {
            let mut state = self.state();
            let Some(item) = state.items.get_mut(&handle) else {
                return;
            };
            item.want.interval = interval_of(interval_ms);
            (item.node.clone(), item.watched)
        };
        self.update(&variable.0, variable.1);
    }

    /// An item deleted (by the client, or with its subscription or
    /// session): its variable's request ends with its last item.
    pub fn unmonitor(&self, handle: MonitoredItemHandle) {
        let item = self.state().items.remove(&handle);
        if let Some(item) = item {
            self.update(&item.node, item.watched);
        }
    }

    /// Asks the gateway what the items on `watched` of `node` want: the
    /// fastest one's interval with its caller; ends the request with the
    /// last item.
    fn update(&self, node: &NodePath, watched: Watched) {
        let mut state = self.state();
        let mut wanted: Option<Want> = None;
        for item in state
            .items
            .values()
            .filter(|item| &item.node == node && item.watched == watched)
        {
            if wanted
                .as_ref()
                .is_none_or(|want| item.want.interval < want.interval)
            {
                wanted = Some(item.want.clone());
            }
        }
        let key = (node.clone(), watched);
        let Some(want) = wanted else {
            state.variables.remove(&key);
            return;
        };
        let requested = state.variables.entry(key).or_insert_with(|| Requested {
            want: want.clone(),
            request: None,
            variable: Arc::default(),
        });
        if requested.request.is_some() && requested.want == want {
            return;
        }
        if let Some(request) = &requested.request
            && requested.want.caller == want.caller
        {
            request.set_interval(want.interval);
            requested.want = want;
            return;
        }
        let Some(server) = self.server.get() else {
            requested.want = want;
            return;
        };
        // The new request before the old one ends: the node's sampler
        // goes on.
        let request = server.request(node, watched, &want, &requested.variable);
        requested.request = request;
        requested.want = want;
    }
}

/// A dictionary entry's bytes as its value, typed by its EDS description
/// `described` (a client's read and a sample alike).
fn value_of(
    described: &crate::canopen::od::SubObject,
    (index, sub): Entry,
    data: &[u8],
) -> Result<Variant, GatewayError> {
    let value = described.decode(data).map_err(|err| {
        GatewayError::InvalidValue(format!(
            "{}: {err}",
            crate::gateway::object_item(index, sub)
        ))
    })?;
    Ok(super::values::variant_of(&value))
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
    let result = async {
        let handle = gateway.node_handle(&node.bus, &node.node.to_string())?;
        let described = super::space::entry(&handle, index, sub)?;
        let bytes = handle.read_object(caller, index, sub).await?;
        value_of(&described, (index, sub), &bytes)
    }
    .await;
    match result {
        Ok(value) => DataValue::new_now(value),
        Err(error) => {
            tracing::debug!(
                "opcua: read of {} on {}/{}: {error}",
                crate::gateway::object_item(index, sub),
                node.bus,
                node.node
            );
            failed(status_of(&error))
        }
    }
}

#[cfg(test)]
mod tests;
