//! Program download (CiA 302-3): `POST /buses/{bus}/nodes/{id}/program`
//! with the image as the body. The sequence is the gateway's
//! (`crate::gateway::program`).

use axum::body::Bytes;
use axum::extract::{Query, State};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{ErrorBody, NodePath};
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::gateway::ProgramDownload;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(post_program))
}

/// Whether to start the program once verified.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ProgramQuery {
    /// Start the program (0x1F51 = 1) once verified; `false` leaves it
    /// stopped. Default true.
    #[param(example = true)]
    pub start: Option<bool>,
}

/// What a program download did.
#[derive(Debug, Serialize, ToSchema)]
pub struct ProgramAnswer {
    /// This download's number on the node (1, 2, ...), as the reports of
    /// the `buses/{bus}/nodes/{id}/program` stream topic carry it.
    #[schema(example = 1)]
    pub run: u64,
    /// The image's size in bytes.
    #[schema(example = 65536)]
    pub bytes: usize,
    /// The image's CRC-32 (IEEE), which 0x1F56 sub 1 gave back.
    #[schema(example = 3_735_928_559u32)]
    pub crc32: u32,
    /// The same, as hex.
    #[schema(example = "0xDEADBEEF")]
    pub crc32_hex: String,
    /// 0x1F56 sub 1 matched the image's CRC-32 (always true in an answer
    /// of 200: a mismatch is a 502 `program_not_verified`).
    pub verified: bool,
    /// The program was started at the end.
    pub started: bool,
    /// The whole sequence, in ms.
    #[schema(example = 850)]
    pub elapsed_ms: u64,
    /// The block download of 0x1F50 alone, in ms.
    #[schema(example = 800)]
    pub download_ms: u64,
    /// The image's size over the download's time.
    #[schema(example = 81920)]
    pub bytes_per_s: u64,
}

/// Downloads a program image (the body, as sent) to the node and verifies
/// it (CiA 302-3).
///
/// The steps: stop the program (0x1F51 sub 1 = 0), clear it (3), download
/// the image to 0x1F50 sub 1 by SDO block transfer with the CRC, read
/// 0x1F56 sub 1 and compare it with the image's CRC-32 (IEEE), then start
/// the program (1) unless `start=false`. The progress (each step, the
/// bytes the device has confirmed, the end) is published as it goes on the
/// stream topic `buses/{bus}/nodes/{id}/program`. A failed step answers the error of
/// its cause with `step` naming it (and `abort_code` when the device
/// refused); the steps before it took effect. At most `dcf_body_limit`
/// bytes (4 MiB by default); the device may take less (a virtual UniSwarm
/// device 512 KiB: 0x05040005).
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/program", tag = "config",
    params(NodePath, ProgramQuery),
    request_body(content = Vec<u8>, content_type = "application/octet-stream", description = "The program image"),
    responses(
        (status = 200, description = "Downloaded and verified", body = ProgramAnswer),
        (status = 400, description = "`invalid_request`: an empty image", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped; `axis_enabled`: an axis of the node is in operation_enabled (or quick_stop_active) or leased; `node_busy`: another program download (or a renumbering) runs on the node (one at a time, never queued)", body = ErrorBody),
        (status = 413, description = "`payload_too_large`", body = ErrorBody),
        (status = 422, description = "`sdo_abort` with `step` and `abort_code`: the device refused a step", body = ErrorBody),
        (status = 502, description = "`program_not_verified` (step `verify (0x1F56)`): 0x1F56 is not the image's CRC-32; `sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout` with `step`", body = ErrorBody),
    ))]
async fn post_program(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    query: Result<Query<ProgramQuery>, axum::extract::rejection::QueryRejection>,
    body: Bytes,
) -> Result<ApiJson<ProgramAnswer>, AppError> {
    let start = match query {
        Ok(Query(query)) => query.start.unwrap_or(true),
        Err(rejection) => return Err(AppError::InvalidRequest(rejection.body_text())),
    };
    let download = state
        .gateway
        .node_handle(&bus, &id)?
        .download_program(&caller, body.into(), start)
        .await?;
    Ok(ApiJson(ProgramAnswer::from(download)))
}

impl From<ProgramDownload> for ProgramAnswer {
    fn from(download: ProgramDownload) -> Self {
        let bytes_per_s = download.bytes_per_s();
        let ProgramDownload { run, report } = download;
        ProgramAnswer {
            run,
            bytes: report.bytes,
            crc32: report.crc32,
            crc32_hex: format!("0x{:08X}", report.crc32),
            verified: true,
            started: report.started,
            elapsed_ms: report.elapsed_ms,
            download_ms: report.download_ms,
            bytes_per_s,
        }
    }
}
