//! A node's configuration: store and restore of its parameters (CiA 301
//! §7.5.2.13 0x1010 and §7.5.2.14 0x1011, with the UniSwarm subs 5–8 that
//! restore the saved rather than the factory values), and a backup of
//! every parameter as a DCF (CiA 306 §4.6.5) that can be written back to
//! the same or a replacement device (see `crate::gateway::dcf`).

use axum::body::Bytes;
use axum::extract::State;
use axum::http::header;
use axum::response::IntoResponse;
use serde::{Deserialize, Serialize};
use serde_json::Value as Json;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{ErrorBody, ErrorDetail, NodePath};
use super::error::body_of;
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::canopen::od::format_index;
use crate::gateway::{ParameterArea, ParameterCommand, RestoreSource, RestoredEntry};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(store))
        .routes(routes!(restore))
        .routes(routes!(get_dcf, put_dcf))
}

/// Which parameters: every one, or one area.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Area {
    /// Sub 1: every parameter.
    All,
    /// Sub 2: the communication area, 0x1000–0x1FFF.
    Communication,
    /// Sub 3: the application (standardized profile) area, 0x6000–0x9FFF.
    Application,
    /// Sub 4: the manufacturer area, 0x2000–0x5FFF.
    Manufacturer,
}

impl From<Area> for ParameterArea {
    fn from(area: Area) -> Self {
        match area {
            Area::All => Self::All,
            Area::Communication => Self::Communication,
            Area::Application => Self::Application,
            Area::Manufacturer => Self::Manufacturer,
        }
    }
}

/// What to store.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"what": "all"}))]
pub struct StoreRequest {
    pub what: Area,
}

/// Where restored values come from.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// The factory defaults (0x1011 sub 1–4, CiA 301).
    #[default]
    Factory,
    /// The values last stored (0x1011 sub 5–8, UniSwarm devices).
    Saved,
}

/// What to restore.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"what": "all"}))]
pub struct RestoreRequest {
    pub what: Area,
    /// `factory` (the default) or `saved`, for devices that have both.
    pub source: Option<Source>,
}

/// The command written.
#[derive(Debug, Serialize, ToSchema)]
#[schema(example = json!({"what": "all", "index": "0x1010", "sub": 1, "name": "Save_all_parameters", "signature": "save"}))]
pub struct CommandDone {
    pub what: Area,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub source: Option<Source>,
    pub index: String,
    pub sub: u8,
    /// The sub-object's EDS name; null without an EDS.
    pub name: Option<String>,
    /// `save` or `load`.
    pub signature: String,
}

fn command_done(what: Area, source: Option<Source>, done: ParameterCommand) -> CommandDone {
    CommandDone {
        what,
        source,
        index: format_index(done.index),
        sub: done.sub,
        name: done.name,
        signature: done.signature.to_string(),
    }
}

/// Stores parameters in the device's non-volatile memory (writes `save`
/// to 0x1010).
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/store", tag = "config", params(NodePath),
    request_body = StoreRequest,
    responses(
        (status = 200, description = "The device confirmed", body = CommandDone),
        (status = 400, description = "`invalid_request` (`what` is not all, communication, application, manufacturer); `invalid_value`: the node's EDS has no such sub of 0x1010", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: the device refused (UniSwarm devices store in pre-operational only: 0x08000021)", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn store(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<StoreRequest>,
) -> Result<ApiJson<CommandDone>, AppError> {
    let done = state
        .gateway
        .node_handle(&bus, &id)?
        .store_parameters(&caller, request.what.into())
        .await?;
    Ok(ApiJson(command_done(request.what, None, done)))
}

/// Restores parameters (writes `load` to 0x1011): the factory defaults, or
/// on devices that keep both, the values last stored. CiA 301 devices
/// take them on at the next reset.
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/restore", tag = "config", params(NodePath),
    request_body = RestoreRequest,
    responses(
        (status = 200, description = "The device confirmed", body = CommandDone),
        (status = 400, description = "`invalid_request` (`what` or `source` unknown); `invalid_value`: the node's EDS has no such sub of 0x1011", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: the device refused (UniSwarm devices restore in pre-operational only: 0x08000021)", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn restore(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<RestoreRequest>,
) -> Result<ApiJson<CommandDone>, AppError> {
    let source = request.source.unwrap_or_default();
    let from = match source {
        Source::Factory => RestoreSource::Factory,
        Source::Saved => RestoreSource::Saved,
    };
    let done = state
        .gateway
        .node_handle(&bus, &id)?
        .restore_parameters(&caller, request.what.into(), from)
        .await?;
    Ok(ApiJson(command_done(request.what, Some(source), done)))
}

/// A backup of the node's configuration: a DCF (CiA 306) with the current
/// value of every readable and writable parameter.
///
/// Entries the device refused to read are left without a value and listed
/// in `[Comments]`. Values derived from the node id are written as
/// `$NODEID+...`, so that the file restores onto another node id.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}/config.dcf", tag = "config", params(NodePath),
    responses(
        (status = 200, description = "The DCF", body = String, content_type = "text/plain"),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`; `unknown_object`: the node has no EDS", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn get_dcf(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<impl IntoResponse, AppError> {
    let node = state.gateway.node_handle(&bus, &id)?;
    let dcf = node.backup_dcf(&caller).await?;
    let file = format!("attachment; filename=\"node{}.dcf\"", node.id());
    Ok((
        [
            (
                header::CONTENT_TYPE,
                "text/plain; charset=utf-8".to_string(),
            ),
            (header::CONTENT_DISPOSITION, file),
        ],
        dcf.write(),
    ))
}

/// The result of one entry of a restore.
#[derive(Debug, Serialize, ToSchema)]
#[schema(example = json!({"index": "0x1017", "sub": 0, "name": "Producer_heartbeat_time", "ok": true}))]
pub struct EntryResult {
    pub index: String,
    pub sub: u8,
    pub name: String,
    pub ok: bool,
    /// Why it failed: the device's abort (`sdo_abort`), or `not_written`
    /// when the restore stopped before it (the device stopped answering).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<ErrorDetail>)]
    pub error: Option<Json>,
}

/// What a restore did.
#[derive(Debug, Serialize, ToSchema)]
pub struct RestoreReport {
    /// Entries written.
    pub written: usize,
    /// Entries that failed.
    pub failed: usize,
    /// Every entry of the DCF with a value, in index order.
    pub entries: Vec<EntryResult>,
}

/// Writes a DCF's values back to the node (a restore, or the configuration
/// of a replacement device), PDOs by the CiA 301 re-mapping procedure, and
/// reports each entry's result.
///
/// The whole file is read and every value checked against the node's EDS
/// before the first write: a malformed DCF, or one with an entry the node
/// does not have, is refused with 400 `invalid_dcf` and nothing written.
/// `$NODEID` in values stands for this node.
#[utoipa::path(put, path = "/buses/{bus}/nodes/{id}/config.dcf", tag = "config", params(NodePath),
    request_body(content = String, content_type = "text/plain", description = "A DCF (CiA 306)"),
    responses(
        (status = 200, description = "Each entry's result", body = RestoreReport),
        (status = 400, description = "`invalid_dcf` (with `line` where the file is malformed), `invalid_request`; nothing was written", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`; `unknown_object`: the node has no EDS", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
    ))]
async fn put_dcf(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    body: Bytes,
) -> Result<ApiJson<RestoreReport>, AppError> {
    let restored = state
        .gateway
        .node_handle(&bus, &id)?
        .restore_dcf(&caller, &body)
        .await?;
    Ok(ApiJson(RestoreReport::from(restored)))
}

impl From<Vec<RestoredEntry>> for RestoreReport {
    fn from(restored: Vec<RestoredEntry>) -> Self {
        let entries: Vec<EntryResult> = restored.into_iter().map(EntryResult::from).collect();
        let written = entries.iter().filter(|entry| entry.ok).count();
        RestoreReport {
            written,
            failed: entries.len() - written,
            entries,
        }
    }
}

impl From<RestoredEntry> for EntryResult {
    fn from(entry: RestoredEntry) -> Self {
        let error = match &entry.result {
            Some(Ok(())) => None,
            Some(Err(error)) => Some(body_of(error)),
            None => Some(serde_json::json!({
                "code": "not_written",
                "message": "the restore stopped before this entry",
            })),
        };
        EntryResult {
            index: format_index(entry.index),
            sub: entry.sub,
            name: entry.name,
            ok: error.is_none(),
            error,
        }
    }
}
