//! Where alarms come from: what the gateway already publishes, followed
//! (no module that emits it knows of alarms).
//!
//! | source | raises | clears |
//! |---|---|---|
//! | the registry's EMCYs (the UMC's axis from its manufacturer bytes) | `emcy` per code, node and axis | the node's error reset EMCY (0x00xx; of the axis where it names one) |
//! | the registry's supervision | `heartbeat_lost`, `guarding_lost`, `node_offline` (no heartbeat, no answer to a scan) | the node heard again |
//! | the network manager's machine | `node_missing`, `wrong_identity`, `config_failed` | the node's state no longer that one |
//! | the bus's status | `bus_off`, `error_passive` | the bus back up |
//! | the TPDOs carrying a drive's statusword (0x6041, the UMC's axis copies) | `axis_fault` (bit 3) | bit 3 clear |
//! | the gateway's own work ([`WorkDone`], told by the lease supervisor and the program download as they end) | `lease_halted` (a lapsed lease's stop: raised and cleared at once, waiting for an acknowledgement); `program_failed` (a download that failed on the device) | a later download to the node that succeeded |

use std::sync::Arc;

use tokio::sync::{Notify, broadcast, watch};

use super::AlarmSource;
use super::service::Alarms;
use crate::can::{BusState, BusStatus};
use crate::canopen::NodeId;
use crate::canopen::manager::{MachineState, MachineStatus, NodeState};
use crate::profile::Profile;
use crate::profiles::alarm::{AlarmKind, Product, describe};
use crate::profiles::umc;
use crate::registry::{NodeEvent, NodeRegistry, OfflineReason};
use crate::service::ServedBus;
use crate::values::TpdoFrame;

/// The statusword's fault bit (CiA 402 §8.4.1, bit 3).
const FAULT_BIT: u64 = 1 << 3;
/// The axis-1 statusword.
const STATUSWORD: u16 = 0x6041;

/// The product a profile is, as the alarm table tells them apart.
pub(crate) fn product(profile: Profile) -> Product {
    match profile {
        Profile::Umc => Product::Umc,
        Profile::JmcStepper => Product::Jmc,
        Profile::Cia402 => Product::Drive,
        Profile::Uioled | Profile::Cia401 | Profile::Generic => Product::Other,
    }
}

/// One bus's sources, followed by one task.
pub(crate) struct BusSources {
    alarms: Alarms,
    bus: String,
    registry: NodeRegistry,
}

impl BusSources {
    /// Follows `served`: its registry's events from `events` (subscribed
    /// when the bus was handed to the gateway, so nothing since is
    /// missed), its machine, its status and its TPDOs.
    pub(crate) fn spawn(
        alarms: Alarms,
        served: &ServedBus,
        events: broadcast::Receiver<NodeEvent>,
    ) -> tokio::task::JoinHandle<()> {
        let sources = Self {
            alarms,
            bus: served.name.clone(),
            registry: served.registry.clone(),
        };
        let machine = served.machine.as_ref().map(|machine| machine.watch());
        let status = served.bus.watch_status();
        let wake = Arc::new(Notify::new());
        let frames = served.values.follow(wake.clone());
        tokio::spawn(sources.run(events, machine, status, frames, wake))
    }

    async fn run(
        self,
        mut events: broadcast::Receiver<NodeEvent>,
        mut machine: Option<watch::Receiver<MachineStatus>>,
        mut status: watch::Receiver<BusStatus>,
        mut frames: broadcast::Receiver<TpdoFrame>,
        wake: Arc<Notify>,
    ) {
        use broadcast::error::{RecvError, TryRecvError};
        self.alarms.restored().await;
        // As they are now, then at each change.
        let bus_status = status.borrow_and_update().clone();
        self.on_bus_status(&bus_status);
        if let Some(machine) = &mut machine {
            let machine_status = machine.borrow_and_update().clone();
            self.on_machine(&machine_status);
        }
        loop {
            tokio::select! {
                event = events.recv() => match event {
                    Ok(event) => self.on_event(&event),
                    Err(RecvError::Lagged(lost)) => {
                        tracing::warn!("alarms: bus {}: {lost} registry events missed", self.bus);
                    }
                    Err(RecvError::Closed) => return,
                },
                changed = status.changed() => {
                    if changed.is_err() {
                        return;
                    }
                    let bus_status = status.borrow_and_update().clone();
                    self.on_bus_status(&bus_status);
                }
                changed = async {
                    match &mut machine {
                        Some(machine) => machine.changed().await,
                        None => std::future::pending().await,
                    }
                } => match (changed, &mut machine) {
                    (Ok(()), Some(watch)) => {
                        let machine_status = watch.borrow_and_update().clone();
                        self.on_machine(&machine_status);
                    }
                    _ => machine = None,
                },
                () = wake.notified() => loop {
                    match frames.try_recv() {
                        Ok(frame) => self.on_frame(&frame),
                        Err(TryRecvError::Lagged(_)) => {}
                        Err(TryRecvError::Empty | TryRecvError::Closed) => break,
                    }
                },
            }
        }
    }

    fn product(&self, node: NodeId) -> Product {
        self.registry
            .node(node)
            .map_or(Product::Other, |info| product(info.profile))
    }

    fn raise(&self, node: Option<NodeId>, axis: Option<u8>, kind: AlarmKind, emcy_text: &str) {
        let source = AlarmSource::new(&self.bus, node.map(NodeId::get), axis, kind);
        // Described only for a new alarm: a statusword in fault comes in
        // every TPDO of the axis.
        self.alarms.raise(source, || {
            let product = node.map_or(Product::Other, |node| self.product(node));
            describe(product, kind, axis, emcy_text)
        });
    }

    fn clear(&self, node: Option<NodeId>, axis: Option<u8>, kind: AlarmKind) {
        let source = AlarmSource::new(&self.bus, node.map(NodeId::get), axis, kind);
        self.alarms.clear(&source);
    }

    /// Clears the node's alarms of `kinds` (by name), every axis.
    fn clear_node(&self, node: NodeId, kinds: &[&str]) {
        let bus = self.bus.clone();
        self.alarms.apply(|book| {
            book.clear_where(
                |source| {
                    source.bus == bus
                        && source.node == Some(node.get())
                        && kinds.contains(&source.kind.0)
                },
                super::service::now_us(),
            )
        });
    }

    pub(crate) fn on_event(&self, event: &NodeEvent) {
        match event {
            NodeEvent::Emcy { node, emcy } if emcy.is_reset() => {
                let bus = self.bus.clone();
                let (node, axis) = (node.get(), emcy.axis);
                self.alarms.apply(|book| {
                    book.clear_where(
                        |source| {
                            source.bus == bus
                                && source.node == Some(node)
                                && source.kind.0 == "emcy"
                                && (axis.is_none() || source.axis == axis)
                        },
                        super::service::now_us(),
                    )
                });
            }
            NodeEvent::Emcy { node, emcy } => {
                self.raise(
                    Some(*node),
                    emcy.axis,
                    AlarmKind::Emcy(emcy.code),
                    &emcy.text,
                );
            }
            NodeEvent::Offline { node, reason } => {
                let kind = match reason {
                    OfflineReason::HeartbeatLost => AlarmKind::HeartbeatLost,
                    OfflineReason::GuardingLost => AlarmKind::GuardingLost,
                    OfflineReason::NoAnswer => AlarmKind::NodeOffline,
                    // The bus's own alarm says it; a moved node is no
                    // longer there to be offline.
                    OfflineReason::BusDown => return,
                    OfflineReason::NodeIdChanged => {
                        self.clear_node(*node, SUPERVISION_KINDS);
                        return;
                    }
                };
                self.raise(Some(*node), None, kind, "");
            }
            NodeEvent::Online { node } => self.clear_node(*node, SUPERVISION_KINDS),
            _ => {}
        }
    }

    pub(crate) fn on_machine(&self, status: &MachineStatus) {
        for node in &status.nodes {
            let Ok(id) = NodeId::new(node.id) else {
                continue;
            };
            let now = match node.state {
                // While the first scan is under way a described node not
                // heard yet is on its way (the machine reads booting, as
                // the manager counts it): it is missing once the scan has
                // not found it. Its alarms stay as they are meanwhile.
                NodeState::Missing if status.state == MachineState::Booting => continue,
                NodeState::Missing => Some(AlarmKind::NodeMissing),
                NodeState::WrongIdentity => Some(AlarmKind::WrongIdentity),
                NodeState::ConfigFailed => Some(AlarmKind::ConfigFailed),
                _ => None,
            };
            for kind in MACHINE_KINDS {
                if Some(kind) == now {
                    self.raise(Some(id), None, kind, "");
                } else {
                    self.clear(Some(id), None, kind);
                }
            }
        }
        // A node the machine no longer lists has none of these causes.
        let listed: Vec<u8> = status.nodes.iter().map(|node| node.id).collect();
        let bus = self.bus.clone();
        self.alarms.apply(|book| {
            book.clear_where(
                |source| {
                    source.bus == bus
                        && source.node.is_some_and(|node| !listed.contains(&node))
                        && MACHINE_KINDS
                            .iter()
                            .any(|kind| kind.name() == source.kind.0)
                },
                super::service::now_us(),
            )
        });
    }

    pub(crate) fn on_bus_status(&self, status: &BusStatus) {
        match status.state {
            BusState::BusOff => {
                self.clear(None, None, AlarmKind::ErrorPassive);
                self.raise(None, None, AlarmKind::BusOff, "");
            }
            BusState::ErrorPassive => {
                self.clear(None, None, AlarmKind::BusOff);
                self.raise(None, None, AlarmKind::ErrorPassive, "");
            }
            BusState::Up => {
                self.clear(None, None, AlarmKind::BusOff);
                self.clear(None, None, AlarmKind::ErrorPassive);
            }
            // Not connected: no controller to be off or passive; whatever
            // was seen last stands.
            BusState::Down => {}
        }
    }

    pub(crate) fn on_frame(&self, frame: &TpdoFrame) {
        for value in &frame.values {
            let axis = match umc::index_axis(value.index) {
                Some((axis, STATUSWORD)) if value.sub == 0 => axis,
                _ => continue,
            };
            if axis > 1 && self.product(frame.node) != Product::Umc {
                continue;
            }
            if value.raw & FAULT_BIT != 0 {
                self.raise(Some(frame.node), Some(axis), AlarmKind::AxisFault, "");
            } else {
                self.clear(Some(frame.node), Some(axis), AlarmKind::AxisFault);
            }
        }
    }
}

/// The kinds the node's supervision raises, cleared once it is heard.
const SUPERVISION_KINDS: &[&str] = &["heartbeat_lost", "guarding_lost", "node_offline"];
/// The kinds the network manager's machine raises.
const MACHINE_KINDS: [AlarmKind; 3] = [
    AlarmKind::NodeMissing,
    AlarmKind::WrongIdentity,
    AlarmKind::ConfigFailed,
];

/// What the gateway's own work tells the alarms as it ends, typed: the
/// operation that did it says so (no audit row's words are read back).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum WorkDone {
    /// A lapsed lease's axis was stopped (its client went away): raised
    /// and cleared at once, the alarm waits for an operator to see it.
    LeaseHalted { bus: String, node: u8, axis: u8 },
    /// A program download that reached the device ended, `failed` or not
    /// (one refused before the bus is none).
    ProgramDownload { bus: String, node: u8, failed: bool },
}

impl Alarms {
    /// Applies what `work` tells (of a node of `product`), once the last
    /// run's alarms are read back.
    pub(crate) fn work_done(&self, product: Product, work: WorkDone) {
        if self.is_restored() {
            on_work(self, product, &work);
        } else {
            let alarms = self.clone();
            tokio::spawn(async move {
                alarms.restored().await;
                on_work(&alarms, product, &work);
            });
        }
    }
}

fn on_work(alarms: &Alarms, product: Product, work: &WorkDone) {
    match work {
        WorkDone::LeaseHalted { bus, node, axis } => {
            let kind = AlarmKind::LeaseHalted;
            let source = AlarmSource::new(bus, Some(*node), Some(*axis), kind);
            alarms.raise(source.clone(), || describe(product, kind, Some(*axis), ""));
            alarms.clear(&source);
        }
        WorkDone::ProgramDownload { bus, node, failed } => {
            let kind = AlarmKind::ProgramFailed;
            let source = AlarmSource::new(bus, Some(*node), None, kind);
            if *failed {
                alarms.raise(source, || describe(product, kind, None, ""));
            } else {
                alarms.clear(&source);
            }
        }
    }
}

impl crate::service::Gateway {
    /// Tells the alarms what the gateway's own work did.
    pub(crate) fn work_done(&self, work: WorkDone) {
        let (bus, node) = match &work {
            WorkDone::LeaseHalted { bus, node, .. }
            | WorkDone::ProgramDownload { bus, node, .. } => (bus, *node),
        };
        let product = self
            .buses
            .get(bus)
            .and_then(|served| served.registry.node(NodeId::new(node).ok()?))
            .map_or(Product::Other, |info| product(info.profile));
        self.alarms.work_done(product, work);
    }
}
