//! The test bench of a virtual bus (`/buses/{bus}/sim/...`): add a virtual
//! device, take one off the bus, inject and clear faults. What the devices
//! do then reaches the gateway as on a real bus: an added device boots
//! (its boot-up puts it in the node list), a removed one falls silent (its
//! heartbeat is missed), a fault sends its EMCY.
//!
//! Only a virtual bus (`virtual:demo`, `virtual:empty`) has devices to
//! control; on any other bus these paths answer 409 `not_virtual` (the bus
//! exists; what it is forbids the request).
//!
//! A fault the product does not have (an LED controller has no following
//! error) is 422 `fault_not_applicable`: the request is well formed, the
//! device refuses it, as a device refuses an SDO write with an abort.
//!
//! The operations are the emulator's ([`crate::emulator::devices`]: the
//! policy, the work and the audit row); a handler parses, calls one and
//! maps its answer.

use axum::extract::State;
use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{BusPath, ErrorBody, NodePath};
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::can::ControllerFault;
use crate::canopen::NodeId;
use crate::emulator::devices::{self, VirtualDevice};
use crate::gateway::GatewayError;
use crate::sim::behaviour::Fault;
use crate::sim::products::{DeviceSpec, Product};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_devices, add_device))
        .routes(routes!(remove_device))
        .routes(routes!(inject_fault, clear_fault))
        .routes(routes!(inject_gateway_fault, clear_gateway_fault))
}

/// A fault of the gateway's own CAN controller on a virtual bus.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"kind": "bit_errors"}))]
pub struct GatewayFaultRequest {
    /// `bit_errors` or `bus_off`.
    #[schema(example = "bit_errors")]
    pub kind: String,
}

impl GatewayFaultRequest {
    /// The fault to inject, or to clear (`clear`).
    fn fault(&self, clear: bool) -> Result<ControllerFault, GatewayError> {
        match (self.kind.trim(), clear) {
            ("bit_errors", false) => Ok(ControllerFault::BitErrors),
            ("bit_errors", true) => Ok(ControllerFault::NoBitErrors),
            ("bus_off", false) => Ok(ControllerFault::BusOff),
            ("bus_off", true) => Ok(ControllerFault::Recover),
            _ => Err(GatewayError::InvalidValue(format!(
                "fault '{}' is none of bit_errors, bus_off",
                self.kind
            ))),
        }
    }
}

/// Injects a fault into the gateway's own CAN controller on a virtual bus
/// (its attachment to the bus).
///
/// `bit_errors`: each frame the gateway sends meets one bit error (the
/// others see an error frame) and is sent again, so its transmit error
/// counter rises by 7 a frame: error passive after 19 frames, bus-off at
/// the 37th. `bus_off`: bus-off at once. The gateway reports it as it
/// reports a SocketCAN interface's: `error_state` and the counters in
/// `GET /buses`, `candeck_bus_error_state` in `/metrics`, a `bus_state`
/// event on the `nodes` topic; bus-off, the bus is down for the gateway
/// and its nodes go offline.
#[utoipa::path(post, path = "/buses/{bus}/sim/faults", tag = "sim", params(BusPath),
    request_body = GatewayFaultRequest,
    responses(
        (status = 204, description = "Injected"),
        (status = 400, description = "`invalid_request` (malformed body), `invalid_value` (unknown fault)", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
        (status = 409, description = "`not_virtual`: the bus is no virtual bus", body = ErrorBody),
    ))]
async fn inject_gateway_fault(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
    ApiJson(request): ApiJson<GatewayFaultRequest>,
) -> Result<StatusCode, AppError> {
    let fault = request.fault(false)?;
    devices::controller_fault(&state.gateway, &caller, &bus, fault).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// Ends a fault of the gateway's own CAN controller on a virtual bus.
///
/// Clearing `bus_off` is the recovery request: the controller is error
/// active again, counters 0, after 128 × 11 recessive bit times at the
/// bus's bit rate. Clearing `bit_errors` stops the bit errors.
#[utoipa::path(delete, path = "/buses/{bus}/sim/faults", tag = "sim", params(BusPath),
    request_body = GatewayFaultRequest,
    responses(
        (status = 204, description = "Cleared"),
        (status = 400, description = "`invalid_request` (malformed body), `invalid_value` (unknown fault)", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
        (status = 409, description = "`not_virtual`: the bus is no virtual bus", body = ErrorBody),
    ))]
async fn clear_gateway_fault(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
    ApiJson(request): ApiJson<GatewayFaultRequest>,
) -> Result<StatusCode, AppError> {
    let fault = request.fault(true)?;
    devices::controller_fault(&state.gateway, &caller, &bus, fault).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// A virtual device on a bus.
#[derive(Debug, Serialize, ToSchema)]
pub struct SimDevice {
    /// Its node id; null for a device without one (an unconfigured LSS
    /// device, `"lss": true`).
    #[schema(example = 4, minimum = 1, maximum = 127)]
    pub id: Option<u8>,
    /// `umc1bds32`, `umc1bd90`, `jmc`, `uio1led` or `io401`; null for a device
    /// built from a dictionary of its own (tests).
    #[schema(example = "uio1led")]
    pub product: Option<String>,
    /// Whether its cable is in.
    pub plugged: bool,
    /// The serial number (0x1018 sub 4) of a device with no node id of its
    /// own, which LSS finds it by.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(example = 257)]
    pub serial: Option<u32>,
}

/// A virtual device to add.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"product": "uio1led", "id": 4}))]
pub struct AddDevice {
    /// `umc1bds32`, `umc1bd90`, `jmc`, `uio1led` or `io401`.
    #[schema(example = "uio1led")]
    pub product: String,
    /// The node id, 1 to 127; absent with `lss`.
    #[schema(example = 4)]
    pub id: Option<i64>,
    /// A device without a node id, waiting for an LSS master (as
    /// `PRODUCT@lss` in a device list). Default false.
    #[serde(default)]
    pub lss: bool,
    /// With `lss`: its serial number (0x1018 sub 4); by default the rack
    /// gives 0x100 + the how-manieth `lss` device it is.
    pub serial: Option<u32>,
    /// A UMC's load: the inertia at each motor's shaft, kg·m² (rotor
    /// included; 0.00002 to 1, default 0.0003: a mechanical time constant
    /// of 33 ms). As `?inertia=` in a device list.
    #[schema(example = 0.0003)]
    pub inertia: Option<f64>,
    /// A UMC's load: its viscous friction, N·m·s (0 to 0.1, default
    /// 0.0001). As `?friction=` in a device list.
    #[schema(example = 0.0001)]
    pub friction: Option<f64>,
}

/// A fault to inject or clear.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"kind": "over_temperature"}))]
pub struct FaultRequest {
    /// `over_temperature`, `under_voltage`, `following_error`,
    /// `over_current`, `heartbeat_loss`, `bit_errors` or `bus_off`.
    #[schema(example = "over_temperature")]
    pub kind: String,
}

impl FaultRequest {
    fn fault(&self) -> Result<Fault, GatewayError> {
        Fault::from_name(self.kind.trim()).ok_or_else(|| {
            let known: Vec<&str> = Fault::ALL.iter().map(|fault| fault.name()).collect();
            GatewayError::InvalidValue(format!(
                "fault '{}' is none of {}",
                self.kind,
                known.join(", ")
            ))
        })
    }
}

fn node_id(id: &str) -> Result<NodeId, AppError> {
    id.parse()
        .map_err(|err| AppError::InvalidRequest(format!("node id '{id}': {err}")))
}

fn to_doc(device: VirtualDevice) -> SimDevice {
    SimDevice {
        id: device.id.map(NodeId::get),
        product: device.product.map(|product| product.name().to_string()),
        plugged: device.plugged,
        serial: device.serial,
    }
}

/// The virtual devices of the bus.
#[utoipa::path(get, path = "/buses/{bus}/sim/nodes", tag = "sim", params(BusPath),
    responses(
        (status = 200, description = "The devices, by node id, then those without a node id of their own (LSS)", body = [SimDevice]),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
        (status = 409, description = "`not_virtual`: the bus has no virtual devices", body = ErrorBody),
    ))]
async fn list_devices(
    State(state): State<AppState>,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<Vec<SimDevice>>, AppError> {
    let list = devices::devices(&state.gateway, &bus)?;
    Ok(ApiJson(list.into_iter().map(to_doc).collect()))
}

/// Adds a virtual device; it boots at once.
///
/// With `--data-dir`, it starts with the parameters a device of this
/// product and node id saved there before. With `"lss": true` it has no
/// node id: it waits, silent, for an LSS master (`POST .../lss/configure`).
#[utoipa::path(post, path = "/buses/{bus}/sim/nodes", tag = "sim", params(BusPath),
    request_body = AddDevice,
    responses(
        (status = 201, description = "The device, booted", body = SimDevice),
        (status = 400, description = "`invalid_request` (malformed body; `id` missing, or given with `lss`; `inertia` or `friction` for a product without motors), `invalid_value` (unknown product), `value_out_of_range` (id not 1 to 127, `inertia` or `friction` out of range)", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
        (status = 409, description = "`not_virtual`: the bus has no virtual devices; `node_taken`: a device has this id", body = ErrorBody),
    ))]
async fn add_device(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
    ApiJson(request): ApiJson<AddDevice>,
) -> Result<(StatusCode, ApiJson<SimDevice>), AppError> {
    let spec = request.spec()?;
    let added = devices::add_device(&state.gateway, &caller, &bus, spec).await?;
    Ok((StatusCode::CREATED, ApiJson(to_doc(added))))
}

impl AddDevice {
    /// The device to add: a product at a node id, or without one, waiting
    /// for LSS; a UMC with its load.
    fn spec(&self) -> Result<DeviceSpec, AppError> {
        let spec = self.placed()?;
        if (self.inertia.is_some() || self.friction.is_some()) && !spec.product.has_motors() {
            return Err(AppError::InvalidRequest(format!(
                "{} drives no motor: \"inertia\" and \"friction\" are for umc1bds32 and umc1bd90",
                spec.product
            )));
        }
        Ok(spec
            .with_load(self.inertia, self.friction)
            .map_err(GatewayError::ValueOutOfRange)?)
    }

    /// The product at its node id, or waiting for LSS.
    fn placed(&self) -> Result<DeviceSpec, AppError> {
        let product = Product::from_name(&self.product).ok_or_else(|| {
            let known: Vec<&str> = Product::ALL.iter().map(|product| product.name()).collect();
            GatewayError::InvalidValue(format!(
                "product '{}' is none of {}",
                self.product,
                known.join(", ")
            ))
        })?;
        let id = match (self.id, self.lss) {
            (None, true) => {
                return Ok(DeviceSpec {
                    product,
                    node: None,
                    serial: self.serial,
                    load: None,
                });
            }
            (Some(_), true) => {
                return Err(AppError::InvalidRequest(
                    "a device with \"lss\": true has no \"id\": LSS gives it one".to_string(),
                ));
            }
            (None, false) => {
                return Err(AppError::InvalidRequest(
                    "\"id\" is missing (or \"lss\": true for a device without one)".to_string(),
                ));
            }
            (Some(id), false) => id,
        };
        let node = u8::try_from(id)
            .ok()
            .and_then(|id| NodeId::new(id).ok())
            .ok_or_else(|| {
                GatewayError::ValueOutOfRange(format!("node id {id} is not 1 to 127"))
            })?;
        Ok(DeviceSpec::at(product, node))
    }
}

/// Takes a virtual device off the bus for good (its id is free again).
///
/// The gateway sees it as on a real bus: it falls silent, and the node goes
/// offline when its heartbeat is missed.
#[utoipa::path(delete, path = "/buses/{bus}/sim/nodes/{id}", tag = "sim", params(NodePath),
    responses(
        (status = 204, description = "Removed"),
        (status = 400, description = "`invalid_request`: the id is no node id", body = ErrorBody),
        (status = 404, description = "`unknown_bus`; `unknown_node`: no virtual device has this id", body = ErrorBody),
        (status = 409, description = "`not_virtual`: the bus has no virtual devices", body = ErrorBody),
    ))]
async fn remove_device(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<StatusCode, AppError> {
    let node = node_id(&id)?;
    devices::remove_device(&state.gateway, &caller, &bus, node).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// Injects a fault into a virtual device.
///
/// The device reacts as the product does (EMCY, error register 0x1001,
/// error history 0x1003; a drive's axes fault). `heartbeat_loss` stops its
/// heartbeat while it runs on. The CAN faults act on its CAN controller
/// (ISO 11898-1 fault confinement): `bit_errors` makes each frame it sends
/// meet one bit error (the others see an error frame, the frame is sent
/// again): its transmit error counter rises by 7 a frame, error passive
/// after 19 frames (EMCY 0x8120, error register bit 4; it keeps working),
/// bus-off at the 37th. `bus_off` takes it bus-off at once. Bus-off, it
/// neither sends nor hears anything, so its heartbeat stops.
#[utoipa::path(post, path = "/buses/{bus}/sim/nodes/{id}/faults", tag = "sim", params(NodePath),
    request_body = FaultRequest,
    responses(
        (status = 204, description = "Injected"),
        (status = 400, description = "`invalid_request` (malformed body, bad id), `invalid_value` (unknown fault)", body = ErrorBody),
        (status = 404, description = "`unknown_bus`; `unknown_node`: no virtual device has this id", body = ErrorBody),
        (status = 409, description = "`not_virtual`: the bus has no virtual devices", body = ErrorBody),
        (status = 422, description = "`fault_not_applicable`: the product has no such fault", body = ErrorBody),
    ))]
async fn inject_fault(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<FaultRequest>,
) -> Result<StatusCode, AppError> {
    let node = node_id(&id)?;
    let fault = request.fault()?;
    devices::inject_fault(&state.gateway, &caller, &bus, node, fault).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// Ends an injected fault condition.
///
/// A drive stays in its fault state until a fault reset, as a real one
/// does; the error reset EMCY follows that. Clearing `bus_off` is the
/// recovery request: the device is error active again after 128 × 11
/// recessive bit times at the bus's bit rate (2.8 ms at 500 kbit/s), sends
/// EMCY 0x8140 "recovered from bus-off" and an error reset, and its
/// heartbeat resumes. Clearing `bit_errors` stops the bit errors (a
/// bus-off device stays bus-off until `bus_off` is cleared).
#[utoipa::path(delete, path = "/buses/{bus}/sim/nodes/{id}/faults", tag = "sim", params(NodePath),
    request_body = FaultRequest,
    responses(
        (status = 204, description = "Cleared"),
        (status = 400, description = "`invalid_request` (malformed body, bad id), `invalid_value` (unknown fault)", body = ErrorBody),
        (status = 404, description = "`unknown_bus`; `unknown_node`: no virtual device has this id", body = ErrorBody),
        (status = 409, description = "`not_virtual`: the bus has no virtual devices", body = ErrorBody),
        (status = 422, description = "`fault_not_applicable`: the product has no such fault", body = ErrorBody),
    ))]
async fn clear_fault(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<FaultRequest>,
) -> Result<StatusCode, AppError> {
    let node = node_id(&id)?;
    let fault = request.fault()?;
    devices::clear_fault(&state.gateway, &caller, &bus, node, fault).await?;
    Ok(StatusCode::NO_CONTENT)
}

#[cfg(test)]
mod tests;
