//! `GET /eds`: the EDS catalog (CiA 306) the gateway matches nodes against:
//! every built-in file and every file of `--eds-dir`, with what its reader
//! said (docs/eds.md), including the files that were left out and why.

use axum::extract::State;
use serde::Serialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{ApiJson, AppState};
use crate::canopen::eds::{Eds, EdsWarning};
use crate::gateway::profile::{EdsSource, SkippedFile};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(list_eds))
}

/// The catalog's files.
#[derive(Debug, Serialize, ToSchema)]
pub struct EdsList {
    pub files: Vec<EdsFile>,
}

/// One EDS or DCF file of the catalog.
#[derive(Debug, Serialize, ToSchema)]
pub struct EdsFile {
    /// The file name: what a node's `eds` shows.
    #[schema(example = "umc1bds32.eds")]
    pub name: String,
    /// `built_in` (carried by candeck) or `dir` (from `--eds-dir`).
    #[schema(example = "built_in")]
    pub source: &'static str,
    /// False when the file was left out of the catalog (`errors` say why).
    pub usable: bool,
    /// Vendor, product and revision (`[DeviceInfo]` or 0x1018's defaults);
    /// null when the file does not give them.
    #[schema(example = 0x4A2)]
    pub vendor_id: Option<u32>,
    #[schema(example = 0x1001)]
    pub product_code: Option<u32>,
    #[schema(example = 0x0100_0004)]
    pub revision: Option<u32>,
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

fn device_type(eds: &Eds) -> Option<u32> {
    let value = eds.dictionary.sub(0x1000, 0)?.default_value(None).ok()??;
    u32::try_from(value.as_i128()?).ok()
}

fn skipped(file: &SkippedFile) -> EdsFile {
    EdsFile {
        name: file.path.file_name().map_or_else(
            || file.path.display().to_string(),
            |name| name.to_string_lossy().into_owned(),
        ),
        source: "dir",
        usable: false,
        vendor_id: None,
        product_code: None,
        revision: None,
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
    }
}

/// Every EDS file the gateway knows: the built-in ones, then those of
/// `--eds-dir` in file name order, then the files it left out, each with its
/// identity, device type, object count, warnings and errors.
#[utoipa::path(get, path = "/eds", tag = "eds",
    responses((status = 200, description = "The catalog's files", body = EdsList)))]
async fn list_eds(State(state): State<AppState>) -> ApiJson<EdsList> {
    // Every bus shares one catalog.
    let Some(served) = state.gateway.buses.values().next() else {
        return ApiJson(EdsList { files: Vec::new() });
    };
    let catalog = served.registry.catalog();
    let mut files: Vec<EdsFile> = catalog
        .entries()
        .iter()
        .map(|entry| EdsFile {
            name: entry.name.clone(),
            source: match entry.source {
                EdsSource::BuiltIn => "built_in",
                EdsSource::File(_) => "dir",
            },
            usable: true,
            vendor_id: Some(entry.vendor_id),
            product_code: Some(entry.product_code),
            revision: entry.revision,
            device_type: device_type(&entry.eds),
            profile: Some(entry.profile.name()),
            objects: Some(entry.eds.dictionary.len()),
            warnings: entry.eds.warnings.iter().map(warning).collect(),
            errors: Vec::new(),
        })
        .collect();
    files.extend(catalog.skipped().iter().map(skipped));
    ApiJson(EdsList { files })
}
