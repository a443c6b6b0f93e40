//! The values of the address space, fed from the gateway's views: the
//! machine with its alarms, the buses, the nodes the registries know (their
//! subtrees added as they are identified), and each axis from the gateway's
//! axis telemetry: the drive's TPDOs where they carry its statusword and
//! position, else the telemetry's own SDO polling, bounded by
//! `axis_poll_hz`; never a poll of the door's own. An axis is fed only
//! while a client monitors one of its values, or read one in the last
//! [`KEEP_AFTER_READ`].

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use opcua::server::node_manager::memory::InMemoryNodeManager;
use opcua::server::{MonitoredItemHandle, SubscriptionCache};
use opcua::types::{DataValue, NodeId, Variant};
use tokio::time::Instant;

use super::browse::{self, NodePath, ROOT};
use super::revisions::{Revision, Revisions};
use super::space::CandeckNodes;
use crate::canopen::NodeId as CanNodeId;
use crate::gateway::{DriveKind, Gateway, Identification, NodeInfo, ServedBus, Severity};

/// How often the machine, buses and nodes are looked at.
pub const TICK: Duration = Duration::from_millis(200);
/// How long an axis is fed after a read of one of its values.
pub const KEEP_AFTER_READ: Duration = Duration::from_secs(10);
/// How long a read of an axis value waits for the feed's first sample.
pub const FIRST_SAMPLE: Duration = Duration::from_secs(1);
/// The rate an axis is asked of the telemetry at.
pub const AXIS_RATE_HZ: f64 = 50.0;

type AxisId = (NodePath, u8);

#[derive(Default)]
struct DemandState {
    monitored: HashMap<MonitoredItemHandle, AxisId>,
    last_read: HashMap<AxisId, Instant>,
    fed: BTreeSet<AxisId>,
}

/// Which axes clients want, from their reads and monitored items.
pub struct AxisDemand {
    ns: u16,
    state: Mutex<DemandState>,
    /// Wakes the feed (a new want) and the reads waiting for a sample.
    wanted: tokio::sync::Notify,
    sampled: tokio::sync::Notify,
}

impl AxisDemand {
    pub fn new(ns: u16) -> Self {
        Self {
            ns,
            state: Mutex::default(),
            wanted: tokio::sync::Notify::new(),
            sampled: tokio::sync::Notify::new(),
        }
    }

    fn state(&self) -> std::sync::MutexGuard<'_, DemandState> {
        self.state
            .lock()
            .unwrap_or_else(|poison| poison.into_inner())
    }

    /// The axis whose value `id` is, if it is one of this namespace.
    pub fn axis_of(&self, id: &NodeId) -> Option<AxisId> {
        if id.namespace != self.ns {
            return None;
        }
        match &id.identifier {
            opcua::types::Identifier::String(text) => browse::axis_value(text.as_ref()),
            _ => None,
        }
    }

    /// A read of `axis`: it is fed from now, and the read waits for its
    /// first sample, at most [`FIRST_SAMPLE`].
    pub async fn read(&self, axis: &AxisId) {
        let deadline = Instant::now() + FIRST_SAMPLE;
        self.state().last_read.insert(axis.clone(), Instant::now());
        self.wanted.notify_one();
        loop {
            let sampled = self.sampled.notified();
            if self.state().fed.contains(axis) {
                return;
            }
            if tokio::time::timeout_at(deadline, sampled).await.is_err() {
                return;
            }
        }
    }

    pub fn monitor(&self, axis: AxisId, handle: MonitoredItemHandle) {
        self.state().monitored.insert(handle, axis);
        self.wanted.notify_one();
    }

    pub fn unmonitor(&self, handle: MonitoredItemHandle) {
        self.state().monitored.remove(&handle);
    }

    /// The axes wanted at `now`.
    fn wanted_at(&self, now: Instant) -> BTreeSet<AxisId> {
        let mut state = self.state();
        state
            .last_read
            .retain(|_, at| now.saturating_duration_since(*at) < KEEP_AFTER_READ);
        let mut wanted: BTreeSet<AxisId> = state.last_read.keys().cloned().collect();
        wanted.extend(state.monitored.values().cloned());
        wanted
    }

    fn fed(&self, axis: &AxisId, fed: bool) {
        let mut state = self.state();
        if fed {
            state.fed.insert(axis.clone());
        } else {
            state.fed.remove(axis);
        }
        drop(state);
        if fed {
            self.sampled.notify_waiters();
        }
    }
}

/// Where the feed writes: the node manager's address space, telling the
/// subscriptions what changed; a value is written only when it changed.
#[derive(Clone)]
pub struct Sink {
    ns: u16,
    manager: Arc<InMemoryNodeManager<CandeckNodes>>,
    subscriptions: Arc<SubscriptionCache>,
    last: Arc<Mutex<HashMap<String, Variant>>>,
}

impl Sink {
    pub fn new(
        ns: u16,
        manager: Arc<InMemoryNodeManager<CandeckNodes>>,
        subscriptions: Arc<SubscriptionCache>,
    ) -> Self {
        Self {
            ns,
            manager,
            subscriptions,
            last: Arc::default(),
        }
    }

    fn set(&self, values: Vec<(String, Variant)>) {
        let changed: Vec<(NodeId, DataValue)> = {
            let mut last = self
                .last
                .lock()
                .unwrap_or_else(|poison| poison.into_inner());
            let mut changed = Vec::new();
            for (path, value) in values {
                if last.get(&path) != Some(&value) {
                    last.insert(path.clone(), value.clone());
                    changed.push((NodeId::new(self.ns, path), DataValue::new_now(value)));
                }
            }
            changed
        };
        if changed.is_empty() {
            return;
        }
        let updates = changed.iter().map(|(id, value)| (id, None, value.clone()));
        if let Err(status) = self.manager.set_values(&self.subscriptions, updates) {
            // A node not in the tree yet (the server not started): sent
            // again next time.
            tracing::debug!("opcua: feed: {status}");
            let mut last = self
                .last
                .lock()
                .unwrap_or_else(|poison| poison.into_inner());
            for (id, _) in &changed {
                if let opcua::types::Identifier::String(path) = &id.identifier {
                    last.remove(path.as_ref());
                }
            }
        }
    }

    fn with_space(&self, build: impl FnOnce(&mut opcua::server::address_space::AddressSpace)) {
        let space = self.manager.address_space();
        let mut space = space.write();
        build(&mut space);
    }
}

fn text(value: impl Into<String>) -> Variant {
    Variant::String(value.into().into())
}

/// The machine: the worst state of its buses' machines, their reasons,
/// and the alarm book's counts.
fn machine_values(gateway: &Gateway) -> Vec<(String, Variant)> {
    let mut worst: Option<crate::gateway::MachineCondition> = None;
    let mut reasons = Vec::new();
    for bus in gateway.buses_in_order() {
        if let Ok(view) = gateway.machine_view(bus.name()) {
            if worst.is_none_or(|worst| view.state.rank() < worst.rank()) {
                worst = Some(view.state);
            }
            reasons.extend(
                view.reasons
                    .iter()
                    .map(|reason| format!("{}: {reason}", bus.name())),
            );
        }
    }
    let summary = gateway.alarm_book().summary(None, None);
    let path = |name: &str| format!("{ROOT}/Machine/{name}");
    vec![
        (
            path("State"),
            text(worst.map_or("unknown", |state| state.name())),
        ),
        (path("Reasons"), text(reasons.join("; "))),
        (
            path("ActiveAlarms"),
            Variant::UInt32(summary.active.iter().sum()),
        ),
        (
            path("UnacknowledgedAlarms"),
            Variant::UInt32(summary.unacknowledged.iter().sum()),
        ),
        (
            path("HighestSeverity"),
            text(summary.highest.map_or("none", Severity::name)),
        ),
    ]
}

fn bus_values(bus: &ServedBus) -> Vec<(String, Variant)> {
    let path = |name: &str| format!("{}/{name}", browse::bus_id(bus.name()));
    let counters = bus.counters();
    vec![
        (path("State"), text(bus.status().state.as_str())),
        (path("Load"), Variant::Double(bus.load().load())),
        (path("RxFrames"), Variant::UInt64(counters.rx_frames)),
        (path("TxFrames"), Variant::UInt64(counters.tx_frames)),
        (path("ErrorFrames"), Variant::UInt64(counters.error_frames)),
        (path("RxOverruns"), Variant::UInt64(counters.rx_overruns)),
        (path("TxErrors"), Variant::UInt64(counters.tx_errors)),
    ]
}

/// A node's values and its identification (0x1018, the EDS's
/// `[DeviceInfo]`, 0x1009 and 0x100A as [`Revisions`] read them).
fn node_values(node: &NodePath, info: &NodeInfo, versions: Revision) -> Vec<(String, Variant)> {
    let device = info
        .eds_entry
        .as_ref()
        .map(|entry| entry.eds.device_info.clone())
        .unwrap_or_default();
    let identity = info.identity.as_ref();
    let id = |name: &str| node.child(&format!("Identification/{name}"));
    let revision = identity
        .and_then(|identity| identity.revision)
        .map_or(String::new(), |revision| {
            format!("{}.{}", revision >> 16, revision & 0xFFFF)
        });
    vec![
        (
            node.child("NmtState"),
            text(info.nmt.map_or("unknown", |state| state.name())),
        ),
        (node.child("Online"), Variant::Boolean(info.online)),
        (node.child("Profile"), text(info.profile.name())),
        (
            id("Manufacturer"),
            text(device.vendor_name.unwrap_or_else(|| {
                identity.map_or(String::new(), |identity| {
                    format!("vendor 0x{:08X}", identity.vendor_id)
                })
            })),
        ),
        (
            id("Model"),
            text(
                device
                    .product_name
                    .or(info.name.clone())
                    .unwrap_or_default(),
            ),
        ),
        (
            id("SerialNumber"),
            text(
                identity
                    .and_then(|identity| identity.serial)
                    .map_or(String::new(), |serial| format!("{serial:08X}")),
            ),
        ),
        (id("HardwareRevision"), text(versions.hardware)),
        (id("SoftwareRevision"), text(versions.software)),
        (id("DeviceRevision"), text(revision)),
        (
            id("VendorId"),
            Variant::UInt32(identity.map_or(0, |identity| identity.vendor_id)),
        ),
        (
            id("ProductCode"),
            Variant::UInt32(
                identity
                    .and_then(|identity| identity.product_code)
                    .unwrap_or(0),
            ),
        ),
    ]
}

/// One sample of the axis topic (its JSON, `docs/websocket.md`) as the
/// axis's values; the fault's code and text from the node's last EMCY of
/// the axis while the drive says fault.
fn axis_values(
    node: &NodePath,
    axis: u8,
    sample: &serde_json::Value,
    emcy: Option<&crate::gateway::EmcyRecord>,
) -> Vec<(String, Variant)> {
    let path = |name: &str| format!("{}/{name}", node.axis(axis));
    let number = |key: &str| sample.get(key).and_then(serde_json::Value::as_i64);
    let word = |key: &str| {
        sample
            .get(key)
            .and_then(serde_json::Value::as_str)
            .map_or(Variant::Empty, |text| Variant::String(text.into()))
    };
    let fault = sample.get("fault").and_then(serde_json::Value::as_bool);
    let (code, fault_text) = match (fault, emcy) {
        (Some(true), Some(emcy)) => (emcy.code, emcy.text.clone()),
        (Some(true), None) => (0, "fault".to_string()),
        _ => (0, String::new()),
    };
    vec![
        (path("State"), word("state")),
        (path("Mode"), word("mode")),
        (
            path("Statusword"),
            number("statusword").map_or(Variant::Empty, |v| Variant::UInt16(v as u16)),
        ),
        (
            path("Position"),
            number("position").map_or(Variant::Empty, |v| Variant::Int32(v as i32)),
        ),
        (
            path("Velocity"),
            number("velocity").map_or(Variant::Empty, |v| Variant::Int32(v as i32)),
        ),
        (
            path("Torque"),
            number("torque").map_or(Variant::Empty, |v| Variant::Int16(v as i16)),
        ),
        (path("FaultCode"), Variant::UInt16(code)),
        (path("FaultText"), text(fault_text)),
        (
            path("TargetReached"),
            sample
                .get("target_reached")
                .and_then(serde_json::Value::as_bool)
                .map_or(Variant::Empty, Variant::Boolean),
        ),
    ]
}

/// Feeds one axis from the telemetry until aborted (its topic's task ends
/// with its last reader).
async fn feed_axis(gateway: Gateway, sink: Sink, demand: Arc<AxisDemand>, axis: AxisId) {
    let (node, number) = axis.clone();
    let Ok(bus) = gateway.bus(&node.bus) else {
        return;
    };
    let Ok(id) = CanNodeId::new(node.node) else {
        return;
    };
    let Ok(mut receiver) = bus.axes().subscribe(id, number, AXIS_RATE_HZ) else {
        return;
    };
    while let Some(sample) = receiver.changed().await {
        let emcy = bus
            .emcy(id)
            .into_iter()
            .rev()
            .find(|record| record.axis.is_none_or(|of| of == number));
        sink.set(axis_values(&node, number, &sample.data, emcy.as_ref()));
        demand.fed(&axis, true);
    }
    demand.fed(&axis, false);
}

/// The feed: every [`TICK`] (and when a client wants a new axis), the
/// machine, the buses and the nodes, the subtrees of nodes newly
/// identified, and the axis feeds started or ended by what is wanted.
pub async fn run(gateway: Gateway, sink: Sink, demand: Arc<AxisDemand>, revisions: Arc<Revisions>) {
    let mut built: BTreeMap<NodePath, (bool, u8)> = BTreeMap::new();
    let mut axes: HashMap<AxisId, tokio::task::JoinHandle<()>> = HashMap::new();
    loop {
        sink.set(machine_values(&gateway));
        for bus in gateway.buses_in_order() {
            sink.set(bus_values(&bus));
            for info in bus.nodes() {
                let node = NodePath {
                    bus: bus.name().to_string(),
                    node: info.id.get(),
                };
                let identified = info.identification != Identification::Pending;
                let drive = DriveKind::from_profile(info.profile);
                let axis_count = match (identified, drive) {
                    (true, Some(kind)) => {
                        crate::gateway::axis_count(kind, info.eds_entry.as_deref())
                    }
                    _ => 0,
                };
                let seen = built.get(&node).copied();
                if seen != Some((identified, axis_count)) {
                    let dictionary = info.eds_entry.as_ref().map(|entry| &entry.eds.dictionary);
                    sink.with_space(|space| {
                        super::tree::build_node(space, sink.ns, &node, dictionary);
                        super::io::build(space, sink.ns, &node, info.profile, dictionary);
                        if let (Some(kind), true) = (drive, axis_count > 0) {
                            super::tree::build_axes(
                                space,
                                sink.ns,
                                &node,
                                axis_count,
                                &kind.units(),
                            );
                        }
                    });
                    built.insert(node.clone(), (identified, axis_count));
                }
                sink.set(node_values(&node, &info, revisions.of(&node)));
            }
        }
        let wanted = demand.wanted_at(Instant::now());
        axes.retain(|axis, task| {
            let keep = wanted.contains(axis) && !task.is_finished();
            if !keep {
                task.abort();
                demand.fed(axis, false);
            }
            keep
        });
        for axis in wanted {
            axes.entry(axis.clone()).or_insert_with(|| {
                tokio::spawn(feed_axis(
                    gateway.clone(),
                    sink.clone(),
                    demand.clone(),
                    axis,
                ))
            });
        }
        tokio::select! {
            () = tokio::time::sleep(TICK) => {}
            () = demand.wanted.notified() => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node() -> NodePath {
        NodePath {
            bus: "demo".into(),
            node: 3,
        }
    }

    #[test]
    fn an_axis_sample_becomes_its_typed_values_with_the_fault_of_its_emcy() {
        let sample = serde_json::json!({
            "axis": 1, "source": "tpdo", "state": "fault", "statusword": 0x0208,
            "mode": "velocity", "mode_raw": 2, "position": -1200, "velocity": 300,
            "torque": null, "target_reached": false, "fault": true
        });
        let emcy = crate::gateway::EmcyRecord {
            code: 0x2310,
            text: "Continuous over-current".into(),
            register: 0x03,
            manufacturer: [0; 5],
            timestamp: Default::default(),
            axis: Some(1),
        };
        let values: BTreeMap<String, Variant> = axis_values(&node(), 1, &sample, Some(&emcy))
            .into_iter()
            .collect();
        let at = |name: &str| values[&format!("{}/{name}", node().axis(1))].clone();
        assert_eq!(at("State"), Variant::String("fault".into()));
        assert_eq!(at("Statusword"), Variant::UInt16(0x0208));
        assert_eq!(at("Position"), Variant::Int32(-1200));
        assert_eq!(at("Velocity"), Variant::Int32(300));
        assert_eq!(at("Torque"), Variant::Empty);
        assert_eq!(at("FaultCode"), Variant::UInt16(0x2310));
        assert_eq!(
            at("FaultText"),
            Variant::String("Continuous over-current".into())
        );
        assert_eq!(at("TargetReached"), Variant::Boolean(false));
        // Out of fault: no code, whatever the last EMCY said.
        let healthy = serde_json::json!({"state": "operation_enabled", "fault": false});
        let values: BTreeMap<String, Variant> = axis_values(&node(), 1, &healthy, Some(&emcy))
            .into_iter()
            .collect();
        assert_eq!(
            values[&format!("{}/FaultCode", node().axis(1))],
            Variant::UInt16(0)
        );
    }

    #[tokio::test(start_paused = true)]
    async fn an_axis_is_wanted_while_monitored_and_a_while_after_a_read() {
        let demand = AxisDemand::new(2);
        let axis = (node(), 1);
        let start = Instant::now();
        assert!(demand.wanted_at(start).is_empty());
        // A read nobody feeds gives up after its wait.
        demand.read(&axis).await;
        assert_eq!(Instant::now() - start, FIRST_SAMPLE);
        assert!(demand.wanted_at(Instant::now()).contains(&axis));
        tokio::time::advance(KEEP_AFTER_READ).await;
        assert!(demand.wanted_at(Instant::now()).is_empty());
        let handle = MonitoredItemHandle {
            subscription_id: 1,
            monitored_item_id: 7,
        };
        demand.monitor(axis.clone(), handle);
        tokio::time::advance(KEEP_AFTER_READ * 3).await;
        assert!(demand.wanted_at(Instant::now()).contains(&axis));
        demand.unmonitor(handle);
        assert!(demand.wanted_at(Instant::now()).is_empty());
        // A fed axis answers a read at once.
        demand.fed(&axis, true);
        let before = Instant::now();
        demand.read(&axis).await;
        assert_eq!(Instant::now(), before);
        let id = NodeId::new(2, format!("{}/Position", node().axis(1)));
        assert_eq!(demand.axis_of(&id), Some(axis));
        assert_eq!(demand.axis_of(&NodeId::new(3, "x")), None);
    }
}
