//! LSS (CiA 305) on a bus: `POST /buses/{bus}/lss/scan` finds the
//! unconfigured devices by Fastscan, `POST /buses/{bus}/lss/configure`
//! gives one a node-ID; and the UniSwarm node-ID change of one node,
//! `POST /buses/{bus}/nodes/{id}/node-id` (0x2040, save, reset). Each is one
//! operation of the gateway (`crate::gateway::lss`), which holds the
//! caller to the policy, writes the audit row and runs in a task of its
//! own, so that a client that hangs up does not leave a device half
//! configured.

use axum::extract::State;
use serde::{Deserialize, Serialize};
use serde_json::Value as Json;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{BusPath, ErrorBody, NodePath};
use super::nodes::{Node, to_json};
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::canopen::lss::LssAddress;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(scan))
        .routes(routes!(configure))
        .routes(routes!(change_node_id))
}

/// A device's LSS address: its identity object 0x1018 sub 1 to 4.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, ToSchema)]
pub struct LssIdentity {
    #[schema(example = 1186)]
    pub vendor_id: u32,
    #[schema(example = 16641)]
    pub product_code: u32,
    #[schema(example = 1)]
    pub revision: u32,
    #[schema(example = 257)]
    pub serial: u32,
}

impl From<LssAddress> for LssIdentity {
    fn from(address: LssAddress) -> Self {
        Self {
            vendor_id: address.vendor_id,
            product_code: address.product_code,
            revision: address.revision,
            serial: address.serial,
        }
    }
}

/// The unconfigured devices Fastscan found.
#[derive(Debug, Serialize, ToSchema)]
pub struct LssScan {
    pub found: Vec<LssIdentity>,
}

/// Finds every unconfigured device on the bus (LSS Fastscan, CiA 305 §6.7).
///
/// Devices with no node-ID (0xFF) answer; each is found bit by bit (133
/// LSS requests, about 70 of which wait for the 25 ms timeout) and left
/// unconfigured. Configured devices take no part.
#[utoipa::path(post, path = "/buses/{bus}/lss/scan", tag = "lss", params(BusPath),
    responses(
        (status = 200, description = "The unconfigured devices, possibly none", body = LssScan),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
        (status = 409, description = "`lss_busy`: another LSS transaction runs on the bus", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`lss_timeout`: a device stopped answering mid-scan", body = ErrorBody),
    ))]
async fn scan(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<LssScan>, AppError> {
    let found = state.gateway.lss_scan(&caller, &bus).await?;
    Ok(ApiJson(LssScan {
        found: found.into_iter().map(LssIdentity::from).collect(),
    }))
}

/// Which device gets which node-ID.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct LssConfigure {
    #[schema(example = 1186)]
    pub vendor_id: u32,
    #[schema(example = 16641)]
    pub product_code: u32,
    #[schema(example = 1)]
    pub revision: u32,
    #[schema(example = 257)]
    pub serial: u32,
    /// 1 to 127.
    #[schema(example = 10)]
    pub node_id: i64,
    /// Store the node-ID in the device (LSS store configuration), so that
    /// it keeps it after a reset or power cycle. Default false.
    #[serde(default)]
    pub store: bool,
}

/// Gives the device with this LSS address a node-ID.
///
/// Selects it (switch state selective), configures the node-ID, stores it
/// if `store`, and switches it back to waiting: an unconfigured device
/// then boots up under the new node-ID (a configured one is sent NMT reset
/// communication at its old one). Answers the node once it booted up and
/// is in the node list.
#[utoipa::path(post, path = "/buses/{bus}/lss/configure", tag = "lss", params(BusPath),
    request_body = LssConfigure,
    responses(
        (status = 200, description = "The device, booted up under its new node-ID", body = Node),
        (status = 400, description = "`invalid_value`: no node-ID; `invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`; `lss_not_found`: no device with that identity answered", body = ErrorBody),
        (status = 409, description = "`lss_busy`; `node_id_in_use`: a node on the bus has it; `node_busy`: a program download runs on the device's node", body = ErrorBody),
        (status = 422, description = "`lss_refused`: the device refused the node-ID or the store", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`lss_timeout`: no answer, or no boot-up", body = ErrorBody),
    ))]
async fn configure(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
    ApiJson(request): ApiJson<LssConfigure>,
) -> Result<ApiJson<Json>, AppError> {
    let address = LssAddress {
        vendor_id: request.vendor_id,
        product_code: request.product_code,
        revision: request.revision,
        serial: request.serial,
    };
    let info = state
        .gateway
        .lss_configure(&caller, &bus, address, request.node_id, request.store)
        .await?;
    Ok(ApiJson(to_json(&info)?))
}

/// The new node-ID of a node.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NodeIdChange {
    /// 1 to 127.
    #[schema(example = 9)]
    pub node_id: i64,
}

/// Changes a UniSwarm node's node-ID (UMC manual §2.3, 0x2040).
///
/// Writes the new node-ID to 0x2040 sub 1, stores the manufacturer
/// parameters (0x1010 sub 4 `save`), resets the node and waits for its
/// boot-up under the new node-ID. Only the UniSwarm UMC and UIO1LED have
/// 0x2040; other products change their node-ID by LSS
/// (`POST /buses/{bus}/lss/configure`).
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/node-id", tag = "lss", params(NodePath),
    request_body = NodeIdChange,
    responses(
        (status = 200, description = "The node, booted up under its new node-ID", body = Node),
        (status = 400, description = "`invalid_value`: no node-ID; `invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`", body = ErrorBody),
        (status = 409, description = "`node_id_in_use`; `wrong_nmt_state`; `node_busy`: a program download runs on the node", body = ErrorBody),
        (status = 422, description = "`node_id_change_not_supported`: no 0x2040; `sdo_abort`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`; `lss_timeout`: no boot-up under the new node-ID", body = ErrorBody),
    ))]
async fn change_node_id(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<NodeIdChange>,
) -> Result<ApiJson<Json>, AppError> {
    let changed = state
        .gateway
        .change_node_id(&caller, &bus, &id, request.node_id)
        .await?;
    Ok(ApiJson(to_json(&changed)?))
}
