//! The EDS catalog (CiA 306) the gateway matches nodes against: `GET /eds`
//! lists every built-in, `--eds-dir` and uploaded file with what its reader
//! said (docs/eds.md), the files left out and why, and which nodes each
//! describes; admins upload (`POST /eds?name=FILE`) and delete
//! (`DELETE /eds/{name}`) files; operators assign a file to a node by hand
//! (`PUT/DELETE /buses/{bus}/nodes/{id}/eds`). The operations are the
//! gateway's (`crate::gateway::eds_files`).

use axum::body::Bytes;
use axum::extract::{Query, State};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{ErrorBody, NodePath};
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::canopen::NodeId;
use crate::canopen::eds::EdsWarning;
use crate::gateway::EdsUser;
use crate::gateway::GatewayError;
use crate::gateway::NodeInfo;
use crate::gateway::{EdsEntry, SkippedFile};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_eds, upload_eds))
        .routes(routes!(delete_eds))
        .routes(routes!(assign_eds, unassign_eds))
}

/// The catalog's files.
#[derive(Debug, Serialize, ToSchema)]
pub struct EdsList {
    /// Where uploads are kept: `data_dir` (the data directory's `eds/`) or
    /// `memory` (no data directory: lost when the gateway stops).
    #[schema(example = "data_dir")]
    pub uploads_kept_in: &'static str,
    pub files: Vec<EdsFile>,
}

/// One EDS or DCF file of the catalog.
#[derive(Debug, Serialize, ToSchema)]
pub struct EdsFile {
    /// The file name: what a node's `eds` shows.
    #[schema(example = "umc1bds32.eds")]
    pub name: String,
    /// `built_in` (carried by candeck), `dir` (from `--eds-dir`) or
    /// `uploaded` (`POST /eds`).
    #[schema(example = "built_in")]
    pub source: &'static str,
    /// False when the file was left out of the catalog (`errors` say why).
    pub usable: bool,
    /// Whether a device can be matched to it by identity; a file that
    /// names no vendor or product describes only the nodes it is assigned
    /// to by hand.
    pub matches_by_identity: bool,
    /// Vendor, product and revision (`[DeviceInfo]` or 0x1018's defaults);
    /// null when the file does not give them.
    #[schema(example = 0x4A2)]
    pub vendor_id: Option<u32>,
    #[schema(example = 0x1001)]
    pub product_code: Option<u32>,
    #[schema(example = 0x0100_0004)]
    pub revision: Option<u32>,
    /// The vendor's and the product's names (`[DeviceInfo]` `VendorName`,
    /// `ProductName`); null when the file gives none.
    #[schema(example = "UniSwarm SASU")]
    pub vendor_name: Option<String>,
    #[schema(example = "UMC1BDS32")]
    pub product_name: Option<String>,
    /// The device type (0x1000's default).
    #[schema(example = 0x0002_0192)]
    pub device_type: Option<u32>,
    /// The profile a node matched to this file gets.
    #[schema(example = "umc")]
    pub profile: Option<&'static str>,
    /// The number of objects of its dictionary.
    #[schema(example = 320)]
    pub objects: Option<usize>,
    /// What the reader got past (file, line, key, what was done).
    pub warnings: Vec<EdsProblem>,
    /// Why the file is not in the catalog.
    pub errors: Vec<EdsProblem>,
    /// The nodes it describes now (or is assigned to).
    pub nodes: Vec<EdsNode>,
}

/// A node an EDS file describes.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)] // The schema of what EdsUser serializes to.
pub struct EdsNode {
    #[schema(example = "demo")]
    pub bus: String,
    #[schema(example = 5)]
    pub node: u8,
    /// Assigned by hand rather than matched by identity.
    pub assigned: bool,
}

/// A warning or error of a file.
#[derive(Debug, Serialize, ToSchema)]
pub struct EdsProblem {
    /// The line it is about; null when it is about the whole file.
    #[schema(example = 11)]
    pub line: Option<usize>,
    /// `[section] Key`, when it is about one.
    #[schema(example = "[2000] AccessType")]
    pub key: Option<String>,
    /// `kept`, `corrected`, `defaulted` or `dropped` (warnings only).
    #[schema(example = "defaulted")]
    pub action: Option<&'static str>,
    #[schema(example = "AccessType is empty; read as rw")]
    pub message: String,
}

fn warning(warning: &EdsWarning) -> EdsProblem {
    EdsProblem {
        line: Some(warning.line),
        key: Some(warning.key.clone()).filter(|key| !key.is_empty()),
        action: Some(warning.action.as_str()),
        message: warning.message.clone(),
    }
}

fn skipped(file: &SkippedFile) -> EdsFile {
    EdsFile {
        name: file.path.file_name().map_or_else(
            || file.path.display().to_string(),
            |name| name.to_string_lossy().into_owned(),
        ),
        source: "dir",
        usable: false,
        matches_by_identity: false,
        vendor_id: None,
        product_code: None,
        revision: None,
        vendor_name: None,
        product_name: None,
        device_type: None,
        profile: None,
        objects: None,
        warnings: file.warnings.iter().map(warning).collect(),
        errors: vec![EdsProblem {
            line: None,
            key: None,
            action: None,
            message: file.message.clone(),
        }],
        nodes: Vec::new(),
    }
}

fn file(entry: &EdsEntry, nodes: Vec<EdsUser>) -> EdsFile {
    EdsFile {
        name: entry.name.clone(),
        source: entry.source.name(),
        usable: true,
        matches_by_identity: entry.matches_by_identity(),
        vendor_id: entry.vendor_id,
        product_code: entry.product_code,
        revision: entry.revision,
        vendor_name: entry.eds.device_info.vendor_name.clone(),
        product_name: entry.eds.device_info.product_name.clone(),
        device_type: entry.device_type,
        profile: Some(entry.profile.name()),
        objects: Some(entry.eds.dictionary.len()),
        warnings: entry.eds.warnings.iter().map(warning).collect(),
        errors: Vec::new(),
        nodes: nodes
            .into_iter()
            .map(|user| EdsNode {
                bus: user.bus,
                node: user.node.get(),
                assigned: user.assigned,
            })
            .collect(),
    }
}

/// Every EDS file the gateway knows: the built-in ones, then those of
/// `--eds-dir` in file name order, then the uploaded ones, then the files
/// it left out, each with its identity, device type, object count,
/// warnings, errors and the nodes it describes.
#[utoipa::path(get, path = "/eds", tag = "eds",
    responses((status = 200, description = "The catalog's files", body = EdsList)))]
async fn list_eds(State(state): State<AppState>) -> ApiJson<EdsList> {
    let Some(catalog) = state.gateway.eds_catalog() else {
        return ApiJson(EdsList {
            uploads_kept_in: "memory",
            files: Vec::new(),
        });
    };
    let mut files: Vec<EdsFile> = catalog
        .entries()
        .iter()
        .map(|entry| file(entry, state.gateway.eds_users(&entry.name)))
        .collect();
    files.extend(catalog.skipped().iter().map(skipped));
    ApiJson(EdsList {
        uploads_kept_in: if catalog.uploads_dir().is_some() {
            "data_dir"
        } else {
            "memory"
        },
        files,
    })
}

/// The name of an uploaded file.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct UploadQuery {
    /// The file's name in the catalog (required): letters, digits, `.`,
    /// `_`, `-`, `+`, at most 100 characters, ending in `.eds` or `.dcf`.
    #[param(example = "my_drive.eds", required = true)]
    pub name: Option<String>,
}

/// The name of a file of the catalog.
#[derive(Debug, Deserialize, IntoParams)]
#[allow(dead_code)] // The path's documentation.
pub struct EdsPath {
    #[param(example = "my_drive.eds")]
    pub name: String,
}

/// Uploads an EDS or DCF file (the body, as sent), named by the `name`
/// query parameter.
///
/// The file is read as the gateway reads every EDS (docs/eds.md): one
/// that is no EDS at all is refused with 400 `invalid_eds` and its
/// problem (with `line`); one with warnings is kept, and its warnings are
/// in the answer. It is kept in the data directory's `eds/` (0600, written
/// to a temporary name and renamed), or in memory only when the gateway has
/// no data directory. Nodes whose identity it matches are described by it
/// at once. At most `dcf_body_limit` bytes (4 MiB by default).
#[utoipa::path(post, path = "/eds", tag = "eds", params(UploadQuery),
    request_body(content = String, content_type = "text/plain", description = "An EDS or DCF (CiA 306)"),
    responses(
        (status = 201, description = "Kept; its warnings are listed", body = EdsFile),
        (status = 400, description = "`invalid_eds` (with `line`): not an EDS; `invalid_request`: a name that is no EDS file name", body = ErrorBody),
        (status = 409, description = "`eds_conflict`: a file of the catalog has the name; `eds_quota`: the uploaded files are at their quota of files or bytes (eds_max_files, eds_max_mb)", body = ErrorBody),
        (status = 413, description = "`payload_too_large`", body = ErrorBody),
    ))]
async fn upload_eds(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    query: Result<Query<UploadQuery>, axum::extract::rejection::QueryRejection>,
    body: Bytes,
) -> Result<(axum::http::StatusCode, ApiJson<EdsFile>), AppError> {
    let name = query
        .ok()
        .and_then(|Query(query)| query.name)
        .ok_or_else(|| {
            AppError::InvalidRequest("give the file's name: POST /api/v1/eds?name=FILE.eds".into())
        })?;
    let entry = state.gateway.upload_eds(&caller, &name, body).await?;
    let users = state.gateway.eds_users(&entry.name);
    Ok((
        axum::http::StatusCode::CREATED,
        ApiJson(file(&entry, users)),
    ))
}

/// Deletes an uploaded EDS file (from the data directory too).
///
/// Built-in files and those of `--eds-dir` cannot be deleted (409). A file
/// assigned to a node by hand is refused with 409 `eds_conflict` naming the
/// nodes: unassign it first. Nodes matched to it by identity are matched
/// again without it.
#[utoipa::path(delete, path = "/eds/{name}", tag = "eds", params(EdsPath),
    responses(
        (status = 204, description = "Deleted"),
        (status = 404, description = "`unknown_eds`", body = ErrorBody),
        (status = 409, description = "`eds_conflict`: not an uploaded file, or assigned to a node", body = ErrorBody),
    ))]
async fn delete_eds(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(name): ApiPath<String>,
) -> Result<axum::http::StatusCode, AppError> {
    state.gateway.delete_eds(&caller, &name).await?;
    Ok(axum::http::StatusCode::NO_CONTENT)
}

/// The file to describe a node by.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct AssignRequest {
    /// The name of a file of the catalog (`GET /eds`).
    #[schema(example = "my_drive.eds")]
    pub file: String,
}

/// Assigns an EDS file of the catalog to a node by hand: the node is then
/// described by that file (its OD listing, reads and writes by that file's
/// names), whatever its identity says, and its profile follows the file's
/// device type (0x1000), else the device's. For a file that names no
/// vendor or product this is the only way it describes a node.
///
/// The node id need not be known yet: a node heard later takes the file.
/// The assignment holds through the node's boot-ups, until `DELETE` or the
/// gateway stops (the config file's `[[nodes]]` `eds` key makes one for
/// good).
#[utoipa::path(put, path = "/buses/{bus}/nodes/{id}/eds", tag = "eds", params(NodePath),
    request_body = AssignRequest,
    responses(
        (status = 200, description = "Assigned: the node as it is now (null when it is not known yet)", body = Option<super::nodes::Node>),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_eds`", body = ErrorBody),
    ))]
async fn assign_eds(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<AssignRequest>,
) -> Result<ApiJson<serde_json::Value>, AppError> {
    let node = node_id(&id)?;
    let info = state
        .gateway
        .assign_eds(&caller, &bus, node, Some(&request.file))
        .await?;
    node_json(info)
}

/// Removes a node's EDS assignment: the node is matched by its identity
/// again.
#[utoipa::path(delete, path = "/buses/{bus}/nodes/{id}/eds", tag = "eds", params(NodePath),
    responses(
        (status = 200, description = "Unassigned: the node as it is now (null when it is not known yet)", body = Option<super::nodes::Node>),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn unassign_eds(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<ApiJson<serde_json::Value>, AppError> {
    let node = node_id(&id)?;
    let info = state.gateway.assign_eds(&caller, &bus, node, None).await?;
    node_json(info)
}

fn node_id(id: &str) -> Result<NodeId, AppError> {
    id.parse()
        .map_err(|err| AppError::InvalidRequest(format!("node id '{id}': {err}")))
}

/// The node as it is now (null when it is not known yet).
fn node_json(info: Option<NodeInfo>) -> Result<ApiJson<serde_json::Value>, AppError> {
    Ok(ApiJson(serde_json::to_value(info).map_err(|err| {
        GatewayError::Internal(format!("node JSON: {err}"))
    })?))
}
