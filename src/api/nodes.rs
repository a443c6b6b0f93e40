//! The nodes of a bus (`GET /buses/{bus}/nodes[/{id}]`, `POST .../scan`)
//! and NMT node control (CiA 301 §7.2.8.3.1, `POST .../nmt`).

use std::sync::Arc;

use axum::extract::State;
use serde::{Deserialize, Serialize};
use serde_json::Value as Json;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{BusPath, ErrorBody, ErrorDetail, NodePath};
use super::{ApiJson, ApiPath, AppError, AppState, ServedBus};
use crate::canopen::nmt::NmtCommand;
use crate::gateway::GatewayError;
use crate::gateway::Profile;
use crate::gateway::{Caller, NodeInfo};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_nodes))
        .routes(routes!(one_node))
        .routes(routes!(scan))
        .routes(routes!(nmt_all))
        .routes(routes!(nmt_node))
}

/// A node as the registry knows it (the JSON of
/// [`NodeInfo`]).
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)] // The schema of what NodeInfo serializes to.
pub struct Node {
    #[schema(example = 1, minimum = 1, maximum = 127)]
    pub id: u8,
    /// The NMT state the node last reported; `unknown` for a node found
    /// by a scan that sends no heartbeat.
    pub nmt: NmtStateName,
    /// Heard within its heartbeat supervision (or answering, without one).
    pub online: bool,
    /// Milliseconds since the last frame from it.
    #[schema(example = 40)]
    pub last_seen_ms: u64,
    /// 0x1018, once read.
    pub identity: Option<IdentityDoc>,
    /// 0x1000.
    #[schema(example = 131474)]
    pub device_type: Option<u32>,
    /// 0x1008, the manufacturer device name.
    #[schema(example = "UMC1BDS32")]
    pub name: Option<String>,
    pub profile: ProfileName,
    /// The EDS file the node is described by.
    #[schema(example = "umc1bds32.eds")]
    pub eds: Option<String>,
    /// Whether `eds` was assigned by hand (`PUT .../eds`) rather than
    /// matched by the node's identity.
    pub eds_assigned: bool,
    /// The heartbeat period it is supervised with; null without heartbeat.
    #[schema(example = 100)]
    pub heartbeat_ms: Option<u64>,
    pub identification: IdentificationDoc,
}

/// NMT states by name (CiA 301 §7.3.2.2).
#[derive(Debug, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
#[allow(dead_code)]
pub enum NmtStateName {
    BootUp,
    PreOperational,
    Operational,
    Stopped,
    Unknown,
}

/// What the gateway knows to do with a node.
#[derive(Debug, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
#[allow(dead_code)]
pub enum ProfileName {
    Umc,
    JmcStepper,
    Uioled,
    Cia402,
    Cia401,
    Generic,
}

/// The identity object 0x1018.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)]
pub struct IdentityDoc {
    #[schema(example = 1192)]
    pub vendor_id: u32,
    pub product_code: Option<u32>,
    pub revision: Option<u32>,
    pub serial: Option<u32>,
}

/// Where reading the node's identity stands.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)]
pub struct IdentificationDoc {
    /// `pending`, `done` or `failed`.
    #[schema(example = "done")]
    pub state: String,
    /// With `failed`: why.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// One emergency message, decoded (CiA 301 §7.2.7).
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)]
pub struct Emergency {
    /// The error code.
    #[schema(example = "0x4310")]
    pub code: String,
    #[schema(example = "Temperature device: over temperature")]
    pub text: String,
    /// The error register 0x1001 sent with it.
    #[schema(example = 9)]
    pub register: u8,
    /// The 5 manufacturer-specific bytes, hex.
    #[schema(example = "0100000000")]
    pub manufacturer: String,
    /// When it was received, microseconds on the gateway's clock.
    pub timestamp_us: u64,
    /// The axis (1-based) of a multi-axis drive the EMCY belongs to, where
    /// the product says (the UMC: its first manufacturer byte); null for
    /// the whole node.
    #[schema(example = 1)]
    pub axis: Option<u8>,
}

/// One node with its recent emergencies.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)]
pub struct NodeDetail {
    #[serde(flatten)]
    pub node: Node,
    /// The last 32 emergencies, oldest first.
    pub emcy: Vec<Emergency>,
    /// A drive's axes, read now (profiles umc, jmc_stepper, cia402).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Vec<super::schema::AxisStatus>>)]
    pub axes: Option<Vec<crate::gateway::AxisStatus>>,
    /// An LED controller's segments, read now (profile uioled).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub segments: Option<Vec<super::segments::SegmentState>>,
    /// Why the profile's summary (`axes` or `segments`) could not be read:
    /// the node is stopped, or did not answer. The rest of the answer stands.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub summary_error: Option<ErrorDetail>,
}

/// The bus and the registry's view of the node a path names: 400 for an id
/// that is no node id (1–127), 404 for a bus or node not known.
pub(super) fn known_node(
    state: &AppState,
    bus: &str,
    id: &str,
) -> Result<(Arc<ServedBus>, NodeInfo), AppError> {
    Ok(state.gateway.node(bus, id)?)
}

pub(super) fn to_json<T: serde::Serialize>(value: &T) -> Result<Json, GatewayError> {
    serde_json::to_value(value).map_err(|err| GatewayError::Internal(err.to_string()))
}

/// The nodes of a bus.
///
/// Nodes are found by their boot-up, heartbeat or EMCY messages and by
/// `POST /buses/{bus}/scan`.
#[utoipa::path(get, path = "/buses/{bus}/nodes", tag = "nodes", params(BusPath),
    responses(
        (status = 200, description = "Every node known on the bus", body = [Node]),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn list_nodes(
    State(state): State<AppState>,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<Json>, AppError> {
    let served = state.bus(&bus)?;
    Ok(ApiJson(to_json(&served.nodes())?))
}

/// One node, with its recent emergencies and its profile's summary.
///
/// A drive's answer has its `axes` and an LED controller's its `segments`,
/// read over SDO now; when they cannot be read (a stopped node, a timeout)
/// `summary_error` says why and the rest of the answer stands.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}", tag = "nodes", params(NodePath),
    responses(
        (status = 200, description = "The node", body = NodeDetail),
        (status = 400, description = "`invalid_request`: no node id", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`", body = ErrorBody),
    ))]
async fn one_node(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<ApiJson<Json>, AppError> {
    let (served, info) = known_node(&state, &bus, &id)?;
    let mut body = to_json(&info)?;
    let emcy = served.emcy(info.id);
    body["emcy"] = to_json(&emcy)?;
    let summary = match info.profile {
        Profile::Umc | Profile::JmcStepper | Profile::Cia402 => Some(
            axes_summary(&state, &caller, &bus, &info)
                .await
                .and_then(|axes| Ok(("axes", to_json(&axes)?))),
        ),
        Profile::Uioled => Some(
            super::segments::summary(&state, &caller, &bus, &id)
                .await
                .and_then(|segments| Ok(("segments", to_json(&segments)?))),
        ),
        // The I/O view is GET .../io: a read of every channel.
        Profile::Cia401 | Profile::Generic => None,
    };
    match summary {
        Some(Ok((key, value))) => body[key] = value,
        Some(Err(err)) => body["summary_error"] = err.to_json(),
        None => {}
    }
    Ok(ApiJson(body))
}

/// Probes node ids 1 to 127 and returns the node list.
///
/// Each id is asked for its device type (0x1000) over SDO, 8 at a time, with
/// a 100 ms timeout.
#[utoipa::path(post, path = "/buses/{bus}/scan", tag = "nodes", params(BusPath),
    responses(
        (status = 200, description = "Every node known after the scan", body = [Node]),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
    ))]
async fn scan(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<Json>, AppError> {
    let nodes = state.gateway.scan(&caller, &bus).await?;
    Ok(ApiJson(to_json(&nodes)?))
}

/// An NMT command (CiA 301 §7.2.8.3.1).
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NmtRequest {
    /// `start`, `stop`, `pre_operational`, `reset_node` or
    /// `reset_communication`.
    #[schema(example = "start")]
    pub command: String,
}

/// The command was sent. NMT is unconfirmed: the node's new state shows in
/// the node list once it reports it.
#[derive(Debug, Serialize, ToSchema)]
pub struct NmtSent {
    #[schema(example = "start")]
    pub command: &'static str,
    /// The node id, or `all`.
    #[schema(value_type = String, example = "1")]
    pub node: String,
    pub sent: bool,
}

fn nmt_command(request: &NmtRequest) -> Result<NmtCommand, GatewayError> {
    NmtCommand::from_name(&request.command).ok_or_else(|| {
        GatewayError::InvalidValue(format!(
            "NMT command '{}' is not one of start, stop, pre_operational, reset_node, reset_communication",
            request.command
        ))
    })
}

/// Sends an NMT command to one node.
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/nmt", tag = "nodes", params(NodePath),
    request_body = NmtRequest,
    responses(
        (status = 200, description = "Sent", body = NmtSent),
        (status = 400, description = "`invalid_value`: no such command; `invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
    ))]
async fn nmt_node(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<NmtRequest>,
) -> Result<ApiJson<NmtSent>, AppError> {
    let command = nmt_command(&request)?;
    let node = state.gateway.node_handle(&bus, &id)?;
    node.nmt(&caller, command).await?;
    Ok(ApiJson(NmtSent {
        command: command.name(),
        node: node.id().to_string(),
        sent: true,
    }))
}

/// Sends an NMT command to every node of the bus.
#[utoipa::path(post, path = "/buses/{bus}/nmt", tag = "nodes", params(BusPath),
    request_body = NmtRequest,
    responses(
        (status = 200, description = "Sent", body = NmtSent),
        (status = 400, description = "`invalid_value`: no such command; `invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
    ))]
async fn nmt_all(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
    ApiJson(request): ApiJson<NmtRequest>,
) -> Result<ApiJson<NmtSent>, AppError> {
    let command = nmt_command(&request)?;
    state.gateway.bus_nmt(&caller, &bus, command).await?;
    Ok(ApiJson(NmtSent {
        command: command.name(),
        node: "all".to_string(),
        sent: true,
    }))
}

/// A drive's axes, read in a task of its own.
async fn axes_summary(
    state: &AppState,
    caller: &Caller,
    bus: &str,
    info: &NodeInfo,
) -> Result<Vec<crate::gateway::AxisStatus>, AppError> {
    let node = state.gateway.node_handle(bus, &info.id.to_string())?;
    Ok(node.read_axes(caller).await?)
}
