//! A node's configuration: store and restore of its parameters (CiA 301
//! §7.5.2.13 0x1010 and §7.5.2.14 0x1011, with the UniSwarm subs 5–8 that
//! restore the saved rather than the factory values), and a backup of
//! every parameter as a DCF (CiA 306 §4.6.5) that can be written back to
//! the same or a replacement device (see [`crate::gateway::dcf`]).

use axum::body::Bytes;
use axum::extract::State;
use axum::http::header;
use axum::response::IntoResponse;
use serde::{Deserialize, Serialize};
use serde_json::Value as Json;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::doc::{ErrorBody, ErrorDetail, NodePath};
use super::nodes::known_node;
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::canopen::eds::{Action, Eds};
use crate::canopen::od::format_index;
use crate::gateway::GatewayError;
use crate::gateway::check_sdo_allowed;
use crate::gateway::dcf;
use crate::gateway::registry::NodeInfo;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(store))
        .routes(routes!(restore))
        .routes(routes!(get_dcf, put_dcf))
}

/// 0x1010: store parameters.
const STORE_PARAMETERS: u16 = 0x1010;
/// 0x1011: restore default parameters.
const RESTORE_PARAMETERS: u16 = 0x1011;
/// The signatures CiA 301 asks for: "save" and "load", as little-endian
/// UNSIGNED32 (0x65766173, 0x64616F6C).
const SAVE: [u8; 4] = *b"save";
const LOAD: [u8; 4] = *b"load";

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

impl Area {
    fn sub(self) -> u8 {
        match self {
            Area::All => 1,
            Area::Communication => 2,
            Area::Application => 3,
            Area::Manufacturer => 4,
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

fn task_failed(err: tokio::task::JoinError) -> GatewayError {
    GatewayError::Internal(format!("SDO task: {err}"))
}

/// Writes a signature to `index`/`sub` after checking that the node's EDS
/// has the sub-object (a node without EDS is asked all the same).
async fn command(
    state: &AppState,
    bus: &str,
    id: &str,
    (index, sub): (u16, u8),
    signature: [u8; 4],
    what: &str,
    refresh_tpdos: bool,
) -> Result<Option<String>, AppError> {
    let (served, info) = known_node(state, bus, id)?;
    let name = match info.eds_entry.as_ref().map(|entry| &entry.eds.dictionary) {
        Some(dictionary) => match dictionary.sub(index, sub) {
            Some(described) => Some(described.name.clone()),
            None => {
                return Err(GatewayError::InvalidValue(format!(
                    "node {} cannot {what}: its EDS has no {} sub {sub}",
                    info.id,
                    format_index(index)
                ))
                .into());
            }
        },
        None => None,
    };
    check_sdo_allowed(&served, &info)?;
    let channel = served.registry.sdo(info.id)?;
    let values = served.values.clone();
    let node = info.id;
    tokio::spawn(async move {
        channel.download(index, sub, &signature).await?;
        // Devices that restore at once (UniSwarm's) may have other TPDO
        // mappings now: decode by what they have.
        if refresh_tpdos && let Err(err) = values.refresh(node).await {
            tracing::warn!("node {node}: TPDO mappings not read again: {err}");
        }
        Ok(())
    })
    .await
    .map_err(task_failed)?
    .map_err(AppError::from_sdo)?;
    Ok(name)
}

fn area_name(area: Area) -> &'static str {
    match area {
        Area::All => "all parameters",
        Area::Communication => "communication parameters",
        Area::Application => "application parameters",
        Area::Manufacturer => "manufacturer parameters",
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
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<StoreRequest>,
) -> Result<ApiJson<CommandDone>, AppError> {
    let target = (STORE_PARAMETERS, request.what.sub());
    let what = format!("store {}", area_name(request.what));
    let name = command(&state, &bus, &id, target, SAVE, &what, false).await?;
    Ok(ApiJson(CommandDone {
        what: request.what,
        source: None,
        index: format_index(target.0),
        sub: target.1,
        name,
        signature: "save".into(),
    }))
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
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<RestoreRequest>,
) -> Result<ApiJson<CommandDone>, AppError> {
    let source = request.source.unwrap_or_default();
    let sub = match source {
        Source::Factory => request.what.sub(),
        Source::Saved => request.what.sub() + 4,
    };
    let what = format!(
        "restore the {} {}",
        match source {
            Source::Factory => "factory",
            Source::Saved => "saved",
        },
        area_name(request.what)
    );
    let communication = matches!(request.what, Area::All | Area::Communication);
    let target = (RESTORE_PARAMETERS, sub);
    let name = command(&state, &bus, &id, target, LOAD, &what, communication).await?;
    Ok(ApiJson(CommandDone {
        what: request.what,
        source: Some(source),
        index: format_index(RESTORE_PARAMETERS),
        sub,
        name,
        signature: "load".into(),
    }))
}

/// The node's EDS, which a DCF needs.
fn node_eds(info: &NodeInfo) -> Result<std::sync::Arc<Eds>, GatewayError> {
    info.eds_entry
        .as_ref()
        .map(|entry| entry.eds.clone())
        .ok_or_else(|| {
            GatewayError::UnknownObject(format!(
                "node {} has no EDS: its parameters are not known",
                info.id
            ))
        })
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
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<impl IntoResponse, AppError> {
    let (served, info) = known_node(&state, &bus, &id)?;
    let eds = node_eds(&info)?;
    check_sdo_allowed(&served, &info)?;
    let channel = served.registry.sdo(info.id)?;
    let node = info.id;
    let name = info.name.clone();
    let (mut dcf, unread) =
        tokio::spawn(async move { dcf::backup(&channel, &eds, node, name).await })
            .await
            .map_err(task_failed)?
            .map_err(AppError::from_sdo)?;
    for entry in &unread {
        dcf.comments.push(format!(
            "{}sub{:X} not read: {}",
            format_index(entry.index),
            entry.sub,
            entry.abort.text()
        ));
    }
    let file = format!("attachment; filename=\"node{}.dcf\"", node.get());
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
    ApiPath((bus, id)): ApiPath<(String, String)>,
    body: Bytes,
) -> Result<ApiJson<RestoreReport>, AppError> {
    let (served, info) = known_node(&state, &bus, &id)?;
    let eds = node_eds(&info)?;
    let parsed =
        Eds::parse_bytes(&body, "config.dcf").map_err(|error| GatewayError::InvalidDcf {
            message: error.to_string(),
            line: Some(error.line).filter(|line| *line > 0),
        })?;
    // A restore writes the device: what the tolerant reader had to drop or
    // correct is refused rather than guessed.
    if let Some(warning) = parsed
        .warnings
        .iter()
        .find(|warning| matches!(warning.action, Action::Dropped | Action::Corrected))
    {
        return Err(GatewayError::InvalidDcf {
            message: warning.to_string(),
            line: Some(warning.line),
        }
        .into());
    }
    let invalid = |message: String| GatewayError::InvalidDcf {
        message,
        line: None,
    };
    let (dcf_device, node_device) = (&parsed.device_info, &eds.device_info);
    if let (Some(a), Some(b)) = (dcf_device.vendor_number, node_device.vendor_number)
        && let (Some(c), Some(d)) = (dcf_device.product_number, node_device.product_number)
        && (a, c) != (b, d)
    {
        return Err(invalid(format!(
            "the DCF is of vendor 0x{a:X} product 0x{c:X}, node {} is vendor 0x{b:X} product 0x{d:X}",
            info.id
        ))
        .into());
    }
    let dcf::Plan { entries, writes } =
        dcf::plan(&parsed, &eds.dictionary, info.id).map_err(|error| invalid(error.0))?;
    check_sdo_allowed(&served, &info)?;
    let channel = served.registry.sdo(info.id)?;
    let values = served.values.clone();
    let node = info.id;
    let results = tokio::spawn(async move {
        let results = dcf::restore(&channel, &writes).await;
        // The gateway decodes the node's TPDOs by the mappings restored; if
        // reading them fails, the old ones stay until the next
        // identification, and the restore's report stands.
        let tpdo_written = writes
            .iter()
            .any(|write| (0x1800..=0x1BFF).contains(&write.index));
        if tpdo_written && let Err(err) = values.refresh(node).await {
            tracing::warn!("node {node}: TPDO mappings not read again: {err}");
        }
        results
    })
    .await
    .map_err(task_failed)?;
    let mut report = RestoreReport {
        written: 0,
        failed: 0,
        entries: Vec::with_capacity(entries.len()),
    };
    for (index, sub) in entries {
        let name = parsed
            .dictionary
            .get(index)
            .map(|object| match object.sub(sub) {
                Some(described) if object.object_type.has_sub_objects() => {
                    format!("{}/{}", object.name, described.name)
                }
                _ => object.name.clone(),
            })
            .unwrap_or_default();
        let error = match results.get(&(index, sub)) {
            Some(Some(Ok(()))) => None,
            Some(Some(Err(error))) => Some(AppError::from_sdo(error.clone()).to_json()),
            _ => Some(serde_json::json!({
                "code": "not_written",
                "message": "the restore stopped before this entry",
            })),
        };
        if error.is_none() {
            report.written += 1;
        } else {
            report.failed += 1;
        }
        report.entries.push(EntryResult {
            index: format_index(index),
            sub,
            name,
            ok: error.is_none(),
            error,
        });
    }
    Ok(ApiJson(report))
}
