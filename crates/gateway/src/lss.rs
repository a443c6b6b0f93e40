//! LSS on a served bus (CiA 305), and the UniSwarm way of changing a node's
//! node-ID (0x2040), as operations of the gateway every door calls
//! ([`Gateway::lss_scan`], [`Gateway::lss_configure`],
//! [`Gateway::change_node_id`]): each writes its audit row, requires its
//! caller's role (the administrator's for LSS, which reconfigures the
//! bus's node-IDs; the operator's for one node's change, as its NMT reset
//! is) and one write of its rate, and runs in a task of its own, so that a
//! client that hangs up does not leave a device half configured.
//!
//! The protocol is [`crate::canopen::lss`]'s master, driven here over the
//! bus with tokio's clock. One LSS transaction runs per bus at a time
//! ([`BusLss::begin`]): a second is refused rather than queued, since two
//! masters' selections would mix on the wire. A configured device boots up
//! under its new node-ID, which the registry hears like any boot-up; these
//! operations end once the registry knows it.
//!
//! Leases and enabled axes follow the device, not its number: before a
//! device that has an axis leased or enabled through the gateway is given
//! another node-ID, that axis is stopped (quick stop, NMT stop if the drive
//! does not confirm) and its lease and its record as enabled are ended,
//! with an audit row and a `motion_ended` event on the `nodes` topic. If
//! the stop is not confirmed, the node-ID is not changed (the gateway can
//! still reach the device at the number it knows). While it is renumbered,
//! the node takes no motion command (`node_busy`). Its old node-ID is
//! forgotten once it has booted under the new one, so that no supervisor
//! or STOP ALL addresses a number where the device no longer is. (Moving
//! the lease to the new ID instead would keep a motion running through a
//! reset communication whose effect on the drive the gateway cannot know.)
//!
//! A raw OD write of 0x2040 sub 1 is the same renumbering
//! ([`Gateway::before_node_id_write`]): checked, the motion ended first,
//! the node closed to motion until its NMT reset, after which the gateway
//! follows the device ([`ServedBus::send_nmt_following_node_ids`]).

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{Mutex, OwnedMutexGuard};

use crate::can::{Bus, CanId, Frame, FrameReceiver, RecvError};
use crate::canopen::NodeId;
use crate::canopen::lss::{
    Inquiry, LssAddress, LssError, LssMaster, LssOutcome, LssService, LssState, UNCONFIGURED,
};
use crate::canopen::nmt::{NmtCommand, NmtTarget};

use super::GatewayError;
use super::audit::AuditTarget;
use super::authority::NodeClosed;
use super::caller::Caller;
use super::end_motion::MotionEnd;
use super::policy::Operation;
use super::profile::Profile;
use super::registry::{Identification, NodeInfo};
use super::service::{Gateway, ServedBus};

/// How long the master waits for each LSS answer. CANopenNode's master
/// uses 10 ms on a wire; a bus bridged over TCP (socketcand) takes a few
/// ms more per round trip.
pub(crate) const LSS_TIMEOUT: Duration = Duration::from_millis(25);
/// How long a configured device has to boot up under its new node-ID.
pub(crate) const BOOT_UP_TIMEOUT: Duration = Duration::from_secs(3);
/// How long the registry has to take a node that booted up and read its
/// identity.
const REGISTRY_TIMEOUT: Duration = Duration::from_secs(2);

/// The LSS master of one bus, and the node-IDs written to 0x2040 by an
/// OD write that await their node's reset.
pub struct BusLss {
    bus: Bus,
    busy: Arc<Mutex<()>>,
    timeout: Duration,
    pending: std::sync::Mutex<std::collections::BTreeMap<u8, PendingNodeId>>,
}

/// A node-ID written to a node's 0x2040 sub 1 by an OD write: the device
/// takes it at its next reset (once stored). Until then the node is
/// closed to motion commands (`node_busy`).
#[derive(Debug)]
pub(crate) struct PendingNodeId {
    new: NodeId,
    _closed: NodeClosed,
}

/// The one LSS transaction of a bus, while it is held.
pub struct LssTransaction<'a> {
    lss: &'a BusLss,
    _held: OwnedMutexGuard<()>,
}

impl BusLss {
    pub fn new(bus: Bus) -> Self {
        Self {
            bus,
            busy: Arc::new(Mutex::new(())),
            timeout: LSS_TIMEOUT,
            pending: Default::default(),
        }
    }

    fn pending(&self) -> std::sync::MutexGuard<'_, std::collections::BTreeMap<u8, PendingNodeId>> {
        // A map of plain values is never left half-written.
        self.pending
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Starts the bus's LSS transaction; `LssBusy` while another runs.
    pub fn begin(&self) -> Result<LssTransaction<'_>, GatewayError> {
        let held = self.busy.clone().try_lock_owned().map_err(|_| {
            GatewayError::LssBusy("another LSS transaction runs on this bus".to_string())
        })?;
        Ok(LssTransaction {
            lss: self,
            _held: held,
        })
    }
}

impl LssTransaction<'_> {
    /// Runs one service of the master to its end.
    pub async fn run(
        &self,
        service: LssService,
    ) -> Result<Result<LssOutcome, LssError>, GatewayError> {
        let bus = &self.lss.bus;
        let mut frames = bus.subscribe();
        let now = || tokio::time::Instant::now().into_std();
        let mut master = LssMaster::new(self.lss.timeout);
        let mut step = master.start(service, now());
        loop {
            for frame in step.send.drain(..) {
                bus.send(frame).await?;
            }
            if let Some(done) = step.done {
                return Ok(done);
            }
            let deadline = master
                .deadline()
                .map(tokio::time::Instant::from_std)
                .unwrap_or_else(tokio::time::Instant::now);
            step = tokio::select! {
                received = frames.recv() => match received {
                    Ok(frame) => master.on_frame(&frame.frame, now()),
                    Err(RecvError::Lagged(_)) => continue,
                    Err(RecvError::Closed) => {
                        return Err(GatewayError::BusDown("bus closed".to_string()));
                    }
                },
                _ = tokio::time::sleep_until(deadline) => master.handle_timeout(now()),
            };
        }
    }
}

impl Gateway {
    /// Every unconfigured device on `bus`, by Fastscan; they stay
    /// unconfigured and waiting. Audited as `lss scan`.
    pub async fn lss_scan(
        &self,
        caller: &Caller,
        bus: &str,
    ) -> Result<Vec<LssAddress>, GatewayError> {
        let target = AuditTarget::new("lss scan");
        self.on_bus(
            caller,
            Operation::Lss,
            bus,
            target,
            None,
            |served| async move { scan(&served).await },
        )
        .await
    }

    /// Gives the device of `bus` with `address` the node-ID `node_id` (1 to
    /// 127), stores it if `store`, and switches it back to waiting: it
    /// boots up under that ID (an unconfigured one at once, a configured
    /// one at the NMT reset communication sent to its old ID). The node,
    /// once the registry knows it. Audited as `lss configure`.
    pub async fn lss_configure(
        &self,
        caller: &Caller,
        bus: &str,
        address: LssAddress,
        node_id: i64,
        store: bool,
    ) -> Result<NodeInfo, GatewayError> {
        let target = AuditTarget::new("lss configure");
        let summary = format!(
            "{{\"vendor_id\":{},\"product_code\":{},\"revision\":{},\"serial\":{},\"node_id\":{node_id},\"store\":{store}}}",
            address.vendor_id, address.product_code, address.revision, address.serial
        );
        let gateway = self.clone();
        self.on_bus(
            caller,
            Operation::Lss,
            bus,
            target,
            Some(summary),
            |served| async move { configure(&gateway, &served, address, node_id, store).await },
        )
        .await
    }

    /// Changes the node-ID of node `id` of `bus` to `node_id` the UniSwarm
    /// way (0x2040, store, reset: only a UMC or UIO1LED has it); the node,
    /// booted up under its new ID. Audited as `change node-id`.
    pub async fn change_node_id(
        &self,
        caller: &Caller,
        bus: &str,
        id: &str,
        node_id: i64,
    ) -> Result<NodeInfo, GatewayError> {
        let target = AuditTarget::new("change node-id").node(id.parse::<u8>().ok());
        let summary = format!("{{\"node_id\":{node_id}}}");
        let (gateway, bus_name, id) = (self.clone(), bus.to_string(), id.to_string());
        self.on_bus(
            caller,
            Operation::ChangeNodeId,
            bus,
            target,
            Some(summary),
            |_| async move {
                let (served, info) = gateway.node(&bus_name, &id)?;
                change_node_id(&gateway, &served, &info, node_id).await
            },
        )
        .await
    }
}

/// Every unconfigured device on the bus, by Fastscan; they stay
/// unconfigured and waiting.
async fn scan(served: &ServedBus) -> Result<Vec<LssAddress>, GatewayError> {
    let transaction = served.lss.begin()?;
    match transaction.run(LssService::FastscanAll).await? {
        Ok(LssOutcome::FoundAll(found)) => Ok(found),
        Ok(other) => Err(GatewayError::Internal(format!(
            "Fastscan ended with {other:?}"
        ))),
        Err(error) => Err(GatewayError::LssTimeout(format!(
            "Fastscan lost the device it was scanning: {error}"
        ))),
    }
}

/// A node-ID as a request gives it: 1 to 127.
fn new_node_id(raw: i64) -> Result<NodeId, GatewayError> {
    NodeId::try_from(raw).map_err(|err| GatewayError::InvalidValue(err.to_string()))
}

/// Refuses a node-ID a node on the bus has.
fn check_free(served: &ServedBus, node: NodeId) -> Result<(), GatewayError> {
    // Nor the gateway's own (manager_node_id; issue 30, finding 4).
    super::machine::check_not_manager_id(served, node)?;
    match served.registry.node(node) {
        Some(info) if info.online => Err(GatewayError::NodeIdInUse(format!(
            "node {node} is in use on bus {}",
            served.name
        ))),
        _ => Ok(()),
    }
}

impl Gateway {
    /// Before the device at `old` on `served` is given the node-ID `new`:
    /// closes the node to motion commands (until the guard is dropped),
    /// then ends the motion on it ([`Gateway::end_motion_on_node`]: every
    /// axis leased or enabled is stopped, its lease and record ended, with
    /// an audit row and a `motion_ended` event each). An axis whose stop is
    /// not confirmed refuses the renumbering (the error of its stop).
    pub(crate) async fn stop_for_renumbering(
        &self,
        served: &ServedBus,
        old: NodeId,
        new: NodeId,
    ) -> Result<NodeClosed, GatewayError> {
        let closed = self
            .authority
            .close_node(
                &served.name,
                old.get(),
                format!("node {old} is being given the node-ID {new}"),
            )
            .map_err(|why| GatewayError::NodeBusy(format!("node {old}: {why}")))?;
        self.end_motion_on_node(served, old, MotionEnd::Renumbered { new })
            .await?;
        Ok(closed)
    }
}

/// Whether an OD write of `index` sub `sub` to the node `info` writes its
/// node-ID (UniSwarm's 0x2040 sub 1): a renumbering, under the same rule
/// as the node-ID route's.
pub(crate) fn writes_node_id(info: &NodeInfo, index: u16, sub: u8) -> bool {
    has_node_id_object(info) && index == COMMUNICATION_CONFIG && sub == 1
}

/// What an OD write of a node's 0x2040 sub 1 does, once checked.
#[derive(Debug)]
pub(crate) enum NodeIdWrite {
    /// Another node-ID: taken at the node's next reset; the node closed to
    /// motion until then.
    Renumbers(PendingNodeId),
    /// The node's own: a renumbering pending on it ends.
    KeepsItsOwn,
}

impl Gateway {
    /// Before an OD write of `bytes` to the node-ID (0x2040 sub 1) of the
    /// node `info` of `served`: the renumbering rule of the node-ID route.
    /// The new node-ID is checked (1 to 127, not in use, not the gateway's
    /// own), the node is closed to motion commands (`node_busy`) and the
    /// motion on it ended ([`Gateway::stop_for_renumbering`]); the write
    /// hands the answer to [`BusLss::node_id_written`] once the device
    /// confirmed it.
    pub(crate) async fn before_node_id_write(
        &self,
        served: &ServedBus,
        info: &NodeInfo,
        bytes: &[u8],
    ) -> Result<NodeIdWrite, GatewayError> {
        let [raw] = bytes else {
            return Err(GatewayError::InvalidValue(format!(
                "0x2040 sub 1 (Node_ID) is one byte, 1 to 127; {} bytes given",
                bytes.len()
            )));
        };
        let new = new_node_id(i64::from(*raw))?;
        if new == info.id {
            return Ok(NodeIdWrite::KeepsItsOwn);
        }
        check_free(served, new)?;
        // A renumbering pending already gives way to this one.
        served.lss.pending().remove(&info.id.get());
        let closed = self.stop_for_renumbering(served, info.id, new).await?;
        Ok(NodeIdWrite::Renumbers(PendingNodeId {
            new,
            _closed: closed,
        }))
    }
}

impl BusLss {
    /// The device confirmed the write of node `node`'s 0x2040 sub 1.
    pub(crate) fn node_id_written(&self, node: NodeId, write: NodeIdWrite) {
        let mut pending = self.pending();
        match write {
            NodeIdWrite::Renumbers(renumbering) => {
                pending.insert(node.get(), renumbering);
            }
            NodeIdWrite::KeepsItsOwn => {
                pending.remove(&node.get());
            }
        }
    }
}

impl ServedBus {
    /// Sends an NMT command (a door's, to a node or to all) and, when it
    /// resets a node with a node-ID written to its 0x2040 pending, follows
    /// the device: it boots up under its new node-ID (the old one is
    /// forgotten, as after the node-ID route) or under its old one (the new
    /// one was not stored); either way the node is open to motion again.
    pub(crate) async fn send_nmt_following_node_ids(
        &self,
        command: NmtCommand,
        target: NmtTarget,
    ) -> Result<(), GatewayError> {
        let resets = matches!(
            command,
            NmtCommand::ResetNode | NmtCommand::ResetCommunication
        );
        let renumbered: Vec<(u8, PendingNodeId)> = if resets {
            let mut pending = self.lss.pending();
            let nodes: Vec<u8> = pending
                .keys()
                .copied()
                .filter(|node| match target {
                    NmtTarget::All => true,
                    NmtTarget::Node(id) => id.get() == *node,
                })
                .collect();
            nodes
                .into_iter()
                .filter_map(|node| pending.remove(&node).map(|p| (node, p)))
                .collect()
        } else {
            Vec::new()
        };
        if renumbered.is_empty() {
            return self.send_nmt(command, target).await;
        }
        let mut frames = self.bus.subscribe();
        self.send_nmt(command, target).await?;
        let mut waiting: std::collections::BTreeMap<u8, PendingNodeId> =
            renumbered.into_iter().collect();
        let until = tokio::time::Instant::now() + BOOT_UP_TIMEOUT;
        let mut moved = Vec::new();
        while !waiting.is_empty() {
            let frame = match tokio::time::timeout_at(until, frames.recv()).await {
                Ok(Ok(frame)) => frame.frame,
                Ok(Err(RecvError::Lagged(_))) => continue,
                Ok(Err(RecvError::Closed)) => {
                    return Err(GatewayError::BusDown("bus closed".to_string()));
                }
                // Not heard: the node is open again; the registry follows
                // whatever it does.
                Err(_) => break,
            };
            let Some(booted) = boot_up_of(&frame) else {
                continue;
            };
            if waiting.remove(&booted).is_some() {
                // Under its old node-ID: the new one was not stored.
                continue;
            }
            let took = waiting
                .iter()
                .find(|(_, pending)| pending.new.get() == booted)
                .map(|(old, _)| *old);
            if let Some(old) = took {
                let pending = waiting.remove(&old).expect("found just now");
                moved.push((old, pending));
            }
        }
        for (old, pending) in moved {
            wait_for_registry(self, pending.new).await?;
            if let Ok(old) = NodeId::new(old) {
                self.registry
                    .retire(old, super::registry::OfflineReason::NodeIdChanged);
            }
        }
        Ok(())
    }
}

/// The node a frame is the boot-up message of.
fn boot_up_of(frame: &Frame) -> Option<u8> {
    match frame.id() {
        CanId::Standard(id) if (0x701..=0x77F).contains(&id) && frame.data() == [0] => {
            Some((id - 0x700) as u8)
        }
        _ => None,
    }
}

/// Gives the device with `address` the node-ID `node_id`, stores it if
/// `store`, and switches it back to waiting: it boots up under that ID
/// (an unconfigured one at once, a configured one at the NMT reset
/// communication sent to its old ID). Ends once the registry knows it. A
/// device that had a node-ID has its leased or enabled axes stopped first
/// ([`Gateway::stop_for_renumbering`]), and its old node-ID forgotten.
async fn configure(
    gateway: &Gateway,
    served: &ServedBus,
    address: LssAddress,
    node_id: i64,
    store: bool,
) -> Result<NodeInfo, GatewayError> {
    let node = new_node_id(node_id)?;
    check_free(served, node)?;
    let transaction = served.lss.begin()?;
    let selected = transaction
        .run(LssService::SwitchSelective(address))
        .await?;
    if selected.is_err() {
        return Err(GatewayError::LssNotFound(format!(
            "no device with {address} answered on bus {}",
            served.name
        )));
    }
    let result = configure_selected(gateway, served, &transaction, node, store).await;
    // Whatever happened, nobody is left in the configuration state.
    let waiting = transaction
        .run(LssService::SwitchGlobal(LssState::Waiting))
        .await;
    let (old, mut boot_up, _closed) = result?;
    // Switch state global has no answer: only the bus can fail it.
    let _ = waiting?;
    if let Some(old) = old
        && old != node
    {
        // A configured device takes its pending node-ID at reset
        // communication (CiA 305 §5.2).
        served
            .send_nmt(NmtCommand::ResetCommunication, NmtTarget::Node(old))
            .await?;
    }
    let moved = wait_for_boot_up(served, &mut boot_up, node).await?;
    if let Some(old) = old
        && old != node
    {
        // Nothing answers at the old ID any more (as after a change by
        // 0x2040).
        served
            .registry
            .retire(old, super::registry::OfflineReason::NodeIdChanged);
    }
    Ok(moved)
}

/// The configuration services on the selected device: its old node-ID
/// (`None`: unconfigured), a receiver that hears its boot-up, and its old
/// node closed to motion until the end.
async fn configure_selected(
    gateway: &Gateway,
    served: &ServedBus,
    transaction: &LssTransaction<'_>,
    node: NodeId,
    store: bool,
) -> Result<(Option<NodeId>, FrameReceiver, Option<NodeClosed>), GatewayError> {
    let lss_error = |step: &str, error: LssError| match error {
        LssError::Refused { .. } => GatewayError::LssRefused(format!("{step}: {error}")),
        other => GatewayError::LssTimeout(format!("{step}: {other}")),
    };
    let old = match transaction
        .run(LssService::Inquire(Inquiry::NodeId))
        .await?
    {
        Ok(LssOutcome::Inquired(raw)) if raw != u32::from(UNCONFIGURED) => {
            NodeId::new(raw as u8).ok()
        }
        Ok(_) => None,
        Err(error) => return Err(lss_error("inquire node-ID", error)),
    };
    // Before the device takes another number: what moves on it is stopped.
    let closed = match old {
        Some(old) if old != node => Some(gateway.stop_for_renumbering(served, old, node).await?),
        _ => None,
    };
    transaction
        .run(LssService::ConfigureNodeId(node.get()))
        .await?
        .map_err(|error| lss_error("configure node-ID", error))?;
    if store {
        transaction
            .run(LssService::StoreConfiguration)
            .await?
            .map_err(|error| lss_error("store configuration", error))?;
    }
    // Listening before the switch to waiting that makes it boot.
    Ok((old, served.bus.subscribe(), closed))
}

/// Waits for the boot-up message of `node`, then for the registry to know
/// it.
async fn wait_for_boot_up(
    served: &ServedBus,
    frames: &mut FrameReceiver,
    node: NodeId,
) -> Result<NodeInfo, GatewayError> {
    let boot_up = Frame::new(CanId::Standard(0x700 + u16::from(node.get())), &[0])
        .expect("a boot-up message is a frame");
    let until = tokio::time::Instant::now() + BOOT_UP_TIMEOUT;
    loop {
        match tokio::time::timeout_at(until, frames.recv()).await {
            Ok(Ok(frame)) if frame.frame == boot_up => break,
            Ok(Ok(_)) | Ok(Err(RecvError::Lagged(_))) => {}
            Ok(Err(RecvError::Closed)) => {
                return Err(GatewayError::BusDown("bus closed".to_string()));
            }
            Err(_) => {
                return Err(GatewayError::LssTimeout(format!(
                    "no boot-up from node {node} within {} s",
                    BOOT_UP_TIMEOUT.as_secs()
                )));
            }
        }
    }
    wait_for_registry(served, node).await
}

/// Waits for the registry to know `node`, which booted up, and to have read
/// its identity (or failed to).
async fn wait_for_registry(served: &ServedBus, node: NodeId) -> Result<NodeInfo, GatewayError> {
    let until = tokio::time::Instant::now() + REGISTRY_TIMEOUT;
    loop {
        let info = served.registry.node(node);
        // Answered once its identity is read (or could not be).
        if let Some(info) = &info
            && info.identification != Identification::Pending
        {
            return Ok(info.clone());
        }
        if tokio::time::Instant::now() >= until {
            return info.ok_or_else(|| {
                GatewayError::Internal(format!(
                    "node {node} booted up but the registry did not take it"
                ))
            });
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

/// Whether a node's product changes its node-ID by 0x2040 (the UniSwarm
/// products: UMC manual §2.3, UIO1LED manual §4.2).
pub(crate) fn has_node_id_object(info: &NodeInfo) -> bool {
    matches!(info.profile, Profile::Umc | Profile::Uioled)
}

/// The UniSwarm way of changing a node-ID: the new one into 0x2040 sub 1,
/// NMT pre-operational (where it may store), store the manufacturer
/// parameters (0x1010 sub 4, `save`), reset node;
/// the device boots up under the new ID. Ends once the registry knows it.
async fn change_node_id(
    gateway: &Gateway,
    served: &ServedBus,
    info: &NodeInfo,
    node_id: i64,
) -> Result<NodeInfo, GatewayError> {
    let node = new_node_id(node_id)?;
    if !has_node_id_object(info) {
        // The JMC's manual sets the node-ID by its switches and has no LSS.
        let how = if info.profile == Profile::JmcStepper {
            format!(
                "it takes its node-ID from {}",
                crate::profiles::jmc::NODE_ID_SETTING
            )
        } else {
            "use LSS if the device offers it".to_string()
        };
        return Err(GatewayError::NodeIdNotSupported(format!(
            "node {} ({}) has no 0x2040 Node_ID: only UniSwarm UMC and UIO1LED change their node-ID that way; {how}",
            info.id,
            info.profile.name()
        )));
    }
    if node == info.id {
        return Ok(info.clone());
    }
    check_free(served, node)?;
    super::check_sdo_allowed(served, info)?;
    let _closed = gateway.stop_for_renumbering(served, info.id, node).await?;
    let sdo = served.registry.sdo(info.id)?;
    // UniSwarm devices store their parameters in pre-operational only
    // (abort 0x08000021 otherwise), and the reset below ends whatever it
    // was doing anyway.
    served
        .send_nmt(NmtCommand::EnterPreOperational, NmtTarget::Node(info.id))
        .await?;
    sdo.download(COMMUNICATION_CONFIG, 1, &[node.get()]).await?;
    sdo.download(STORE_PARAMETERS, MANUFACTURER_AREA, b"save")
        .await?;
    let mut frames = served.bus.subscribe();
    served
        .send_nmt(NmtCommand::ResetNode, NmtTarget::Node(info.id))
        .await?;
    let moved = wait_for_boot_up(served, &mut frames, node).await?;
    // Nothing answers at the old ID any more: left listed, it would only
    // time out every request and be supervised (and lost) for ever.
    served
        .registry
        .retire(info.id, super::registry::OfflineReason::NodeIdChanged);
    Ok(moved)
}

/// 0x2040: UniSwarm's communication configuration, sub 1 Node_ID.
const COMMUNICATION_CONFIG: u16 = crate::profiles::umc::COMMUNICATION_CONFIG;
/// 0x1010: store parameters.
const STORE_PARAMETERS: u16 = 0x1010;
/// 0x1010 sub 4: the manufacturer area (0x2000–0x5FFF), where 0x2040 is.
const MANUFACTURER_AREA: u8 = 4;
