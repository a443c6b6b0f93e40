//! The nodes of a bus (`GET /buses/{bus}/nodes[/{id}]`, `POST .../scan`)
//! and NMT node control (CiA 301 §7.2.8.3.1, `POST .../nmt`).

use std::sync::Arc;

use axum::Router;
use axum::extract::State;
use axum::routing::{get, post};
use serde_json::{Value as Json, json};

use super::{ApiJson, ApiPath, AppError, AppState, ServedBus};
use crate::canopen::NodeId;
use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};
use crate::gateway::registry::NodeInfo;

pub fn router() -> Router<AppState> {
    Router::new()
        .route("/buses/{bus}/nodes", get(list_nodes))
        .route("/buses/{bus}/nodes/{id}", get(one_node))
        .route("/buses/{bus}/scan", post(scan))
        .route("/buses/{bus}/nmt", post(nmt_all))
        .route("/buses/{bus}/nodes/{id}/nmt", post(nmt_node))
}

/// The bus and the registry's view of the node a path names: 400 for an id
/// that is no node id (1–127), 404 for a bus or node not known.
pub(super) fn known_node(
    state: &AppState,
    bus: &str,
    id: &str,
) -> Result<(Arc<ServedBus>, NodeInfo), AppError> {
    let served = state.bus(bus)?;
    let node: NodeId = id
        .parse()
        .map_err(|err| AppError::InvalidRequest(format!("node id '{id}': {err}")))?;
    let info = served
        .registry
        .node(node)
        .ok_or_else(|| AppError::UnknownNode {
            bus: bus.to_string(),
            node: id.to_string(),
        })?;
    Ok((served, info))
}

fn to_json<T: serde::Serialize>(value: &T) -> Result<Json, AppError> {
    serde_json::to_value(value).map_err(|err| AppError::Internal(err.to_string()))
}

async fn list_nodes(
    State(state): State<AppState>,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<Json>, AppError> {
    let served = state.bus(&bus)?;
    Ok(ApiJson(to_json(&served.registry.nodes())?))
}

async fn one_node(
    State(state): State<AppState>,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<ApiJson<Json>, AppError> {
    let (served, info) = known_node(&state, &bus, &id)?;
    let mut body = to_json(&info)?;
    let emcy = served.registry.emcy(info.id).unwrap_or_default();
    body["emcy"] = to_json(&emcy)?;
    Ok(ApiJson(body))
}

async fn scan(
    State(state): State<AppState>,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<Json>, AppError> {
    let served = state.bus(&bus)?;
    // The scan runs in a task of its own: a client that hangs up must not
    // cut the probes under way.
    let registry = served.registry.clone();
    let nodes = tokio::spawn(async move { registry.scan().await })
        .await
        .map_err(|err| AppError::Internal(format!("scan task: {err}")))??;
    Ok(ApiJson(to_json(&nodes)?))
}

#[derive(Debug, serde::Deserialize)]
struct NmtRequest {
    command: String,
}

fn nmt_command(request: &NmtRequest) -> Result<NmtCommand, AppError> {
    NmtCommand::from_name(&request.command).ok_or_else(|| {
        AppError::InvalidValue(format!(
            "NMT command '{}' is not one of start, stop, pre_operational, reset_node, reset_communication",
            request.command
        ))
    })
}

/// NMT is unconfirmed (CiA 301 §7.2.8.2.1): the answer says the command
/// was sent; the node's new state shows in the node list once it reports it.
async fn send_nmt(
    served: &ServedBus,
    command: NmtCommand,
    target: NmtTarget,
) -> Result<(), AppError> {
    served
        .bus
        .send(NmtMessage::new(command, target).encode())
        .await
        .map_err(AppError::from)
}

async fn nmt_node(
    State(state): State<AppState>,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<NmtRequest>,
) -> Result<ApiJson<Json>, AppError> {
    let command = nmt_command(&request)?;
    let (served, info) = known_node(&state, &bus, &id)?;
    send_nmt(&served, command, NmtTarget::Node(info.id)).await?;
    Ok(ApiJson(
        json!({ "command": command.name(), "node": info.id.get(), "sent": true }),
    ))
}

async fn nmt_all(
    State(state): State<AppState>,
    ApiPath(bus): ApiPath<String>,
    ApiJson(request): ApiJson<NmtRequest>,
) -> Result<ApiJson<Json>, AppError> {
    let command = nmt_command(&request)?;
    let served = state.bus(&bus)?;
    send_nmt(&served, command, NmtTarget::All).await?;
    Ok(ApiJson(
        json!({ "command": command.name(), "node": "all", "sent": true }),
    ))
}
