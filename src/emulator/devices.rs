//! The virtual devices of a virtual bus as operations every door calls
//! (REST's `/buses/{bus}/sim/...`): a device added or removed, a device's
//! fault injected or cleared, and the faults of the gateway's own CAN
//! controller on the bus. They live beside the rack's wiring because the
//! gateway does not know the `sim` crate; they apply the gateway's policy
//! all the same: an admin's ([`Operation::VirtualDevices`]), one write of
//! the caller's rate, the work in a task a caller that goes away cannot
//! cut, and one audit row each.
//!
//! Only a virtual bus has devices: any other is refused `not_virtual`. A
//! fault the product does not have is `fault_not_applicable`.

use crate::can::ControllerFault;
use crate::canopen::NodeId;
use crate::canopen::lss::LssAddress;
use crate::gateway::AuditTarget;
use crate::gateway::Caller;
use crate::gateway::Operation;
use crate::gateway::SimError;
use crate::gateway::{Gateway, GatewayError, spawn_audited};
use crate::sim::behaviour::Fault;
use crate::sim::products::{DeviceSpec, Product};
use crate::sim::rack::{Rack, RackError};

use super::RackOf;

/// A virtual device of a bus, as the rack lists it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VirtualDevice {
    /// `None` for a device without a node id of its own (an unconfigured
    /// LSS device).
    pub id: Option<NodeId>,
    /// `None` for a device built from a dictionary of its own (tests).
    pub product: Option<Product>,
    /// Whether its cable is in.
    pub plugged: bool,
    /// The serial number LSS finds a device without a node id by.
    pub serial: Option<u32>,
}

impl VirtualDevice {
    fn of((id, product, plugged): (NodeId, Option<Product>, bool)) -> Self {
        Self {
            id: Some(id),
            product,
            plugged,
            serial: None,
        }
    }

    fn loose((id, product, address): (Option<NodeId>, Option<Product>, LssAddress)) -> Self {
        Self {
            id,
            product,
            plugged: true,
            serial: Some(address.serial),
        }
    }
}

/// The rack of the virtual bus `bus`: `unknown_bus`, or `not_virtual` for
/// a bus without virtual devices.
pub fn rack_of(gateway: &Gateway, bus: &str) -> Result<Rack, GatewayError> {
    gateway
        .bus(bus)?
        .rack()
        .cloned()
        .ok_or_else(|| GatewayError::Sim(SimError::NotVirtual(bus.to_string())))
}

/// The virtual devices of `bus`: by node id, then those without a node id
/// of their own (LSS).
pub fn devices(gateway: &Gateway, bus: &str) -> Result<Vec<VirtualDevice>, GatewayError> {
    let rack = rack_of(gateway, bus)?;
    let placed = rack.devices().into_iter().map(VirtualDevice::of);
    let loose = rack.loose_devices().into_iter().map(VirtualDevice::loose);
    Ok(placed.chain(loose).collect())
}

/// Adds the device `spec` to `bus` for `caller`; it boots at once (with
/// `--data-dir`, with the parameters a device of its product and node id
/// saved there). Audited as `add virtual device`.
pub async fn add_device(
    gateway: &Gateway,
    caller: &Caller,
    bus: &str,
    spec: DeviceSpec,
) -> Result<VirtualDevice, GatewayError> {
    let summary = serde_json::json!({
        "product": spec.product.name(),
        "id": spec.node.map(NodeId::get),
        "lss": spec.node.is_none(),
    });
    let target = AuditTarget::new("add virtual device").bus(bus);
    on_rack(
        gateway,
        caller,
        target,
        Some(summary.to_string()),
        move |rack, bus| {
            rack.add_spec(&spec).map_err(|err| rack_error(bus, err))?;
            added(rack, &spec)
        },
    )
    .await
}

/// Takes the device `node` off `bus` for good (its id is free again): the
/// gateway sees it fall silent. Audited as `remove virtual device`.
pub async fn remove_device(
    gateway: &Gateway,
    caller: &Caller,
    bus: &str,
    node: NodeId,
) -> Result<(), GatewayError> {
    let target = AuditTarget::new("remove virtual device")
        .bus(bus)
        .node(node.get());
    on_rack(gateway, caller, target, None, move |rack, bus| {
        rack.remove(node).map_err(|err| rack_error(bus, err))
    })
    .await
}

/// Injects `fault` into the device `node` of `bus`: it reacts as the
/// product does (EMCY, error register, a drive's axes fault). Audited as
/// `inject fault`.
pub async fn inject_fault(
    gateway: &Gateway,
    caller: &Caller,
    bus: &str,
    node: NodeId,
    fault: Fault,
) -> Result<(), GatewayError> {
    device_fault(gateway, caller, bus, node, fault, false).await
}

/// Ends the fault condition `fault` of the device `node` of `bus` (a drive
/// stays in its fault state until a fault reset). Audited as `clear
/// fault`.
pub async fn clear_fault(
    gateway: &Gateway,
    caller: &Caller,
    bus: &str,
    node: NodeId,
    fault: Fault,
) -> Result<(), GatewayError> {
    device_fault(gateway, caller, bus, node, fault, true).await
}

/// A device's fault injected, or cleared (`clear`), as one audited
/// operation on the rack.
async fn device_fault(
    gateway: &Gateway,
    caller: &Caller,
    bus: &str,
    node: NodeId,
    fault: Fault,
    clear: bool,
) -> Result<(), GatewayError> {
    let words = if clear { "clear fault" } else { "inject fault" };
    let target = AuditTarget::new(words).bus(bus).node(node.get());
    on_rack(
        gateway,
        caller,
        target,
        Some(kind(fault.name())),
        move |rack, bus| {
            let done = if clear {
                rack.clear_fault(node, fault)
            } else {
                rack.inject_fault(node, fault)
            };
            done.map_err(|err| rack_error(bus, err))
        },
    )
    .await
}

/// Injects (`BitErrors`, `BusOff`) or clears (`NoBitErrors`, `Recover`) a
/// fault of the gateway's own CAN controller on the virtual bus `bus`.
/// Audited as `inject fault` or `clear fault`, with no node: the fault is
/// the gateway's.
pub async fn controller_fault(
    gateway: &Gateway,
    caller: &Caller,
    bus: &str,
    fault: ControllerFault,
) -> Result<(), GatewayError> {
    let (words, name) = match fault {
        ControllerFault::BitErrors => ("inject fault", "bit_errors"),
        ControllerFault::BusOff => ("inject fault", "bus_off"),
        ControllerFault::NoBitErrors => ("clear fault", "bit_errors"),
        ControllerFault::Recover => ("clear fault", "bus_off"),
    };
    let target = AuditTarget::new(words).bus(bus);
    let served = gateway.bus(bus);
    on_rack(gateway, caller, target, Some(kind(name)), move |_, _| {
        served?.controller_fault(fault)
    })
    .await
}

/// A fault as a request summary names it.
fn kind(name: &str) -> String {
    serde_json::json!({ "kind": name }).to_string()
}

/// Runs `work` on the rack of `target`'s bus for `caller`: its row opened
/// first, then the policy, then the work, all in a task of their own.
async fn on_rack<T, W>(
    gateway: &Gateway,
    caller: &Caller,
    target: AuditTarget,
    summary: Option<String>,
    work: W,
) -> Result<T, GatewayError>
where
    T: Send + 'static,
    W: FnOnce(&Rack, &str) -> Result<T, GatewayError> + Send + 'static,
{
    let bus = target.bus.clone().unwrap_or_default();
    let row = gateway.audit_row(caller, target, summary);
    let (gateway, caller) = (gateway.clone(), caller.clone());
    spawn_audited(row, async move {
        gateway.admit(&caller, Operation::VirtualDevices)?;
        let rack = rack_of(&gateway, &bus)?;
        work(&rack, &bus)
    })
    .await
}

fn rack_error(bus: &str, error: RackError) -> GatewayError {
    match error {
        RackError::UnknownNode(node) => GatewayError::Sim(SimError::UnknownDevice {
            bus: bus.to_string(),
            node: node.get(),
        }),
        RackError::NodeTaken(..) => GatewayError::Sim(SimError::NodeTaken(error.to_string())),
        RackError::Fault(fault) => {
            GatewayError::Sim(SimError::FaultNotApplicable(fault.to_string()))
        }
        RackError::Device(detail) => GatewayError::Internal(format!("virtual device: {detail}")),
    }
}

/// The device `spec` added to `rack`, as the rack lists it now.
fn added(rack: &Rack, spec: &DeviceSpec) -> Result<VirtualDevice, GatewayError> {
    match spec.node {
        None => rack
            .loose_devices()
            .pop()
            .map(VirtualDevice::loose)
            .ok_or_else(|| {
                GatewayError::Internal("the LSS device added is not in the rack".to_string())
            }),
        Some(node) => Ok(rack
            .devices()
            .into_iter()
            .find(|(id, _, _)| *id == node)
            .map_or_else(
                || VirtualDevice {
                    id: Some(node),
                    product: Some(spec.product),
                    plugged: true,
                    serial: None,
                },
                VirtualDevice::of,
            )),
    }
}

#[cfg(test)]
mod tests;
