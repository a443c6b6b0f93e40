//! Recording a bus as a candump `-L` log (linux-can/can-utils `candump -L`)
//! through REST, and downloading it; the gateway side is
//! `crate::gateway::recording`. `--bus replay:FILE` plays a downloaded
//! log back.
//!
//! - `POST /buses/{bus}/recording` `{"max_frames"?, "max_seconds"?}` starts
//!   one (201), 409 `recording_running` while one runs;
//! - `GET /buses/{bus}/recording` its status (`state`: `recording`,
//!   `stopped` or `none`);
//! - `DELETE /buses/{bus}/recording` stops it and returns the final status;
//! - `GET /buses/{bus}/recording.log` the log (as far as written, flushed
//!   first), streamed from its file.

use axum::body::{Body, Bytes};
use axum::extract::State;
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncRead, AsyncReadExt};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{BusPath, ErrorBody};
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::gateway::GatewayError;
use crate::gateway::{Limits, RecordingState, RecordingStatus, StopReason};

/// The chunks a download is streamed in.
const CHUNK: usize = 64 * 1024;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(start_recording, recording_status, stop_recording))
        .routes(routes!(download_recording))
}

/// What to record: both limits are optional; the recording stops at the
/// first one reached (or when stopped).
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"max_frames": 100000, "max_seconds": 60}))]
pub struct StartRecording {
    /// Stop after this many frames: 1 to 1000000, default 1000000.
    #[schema(minimum = 1, maximum = 1_000_000, example = 100_000)]
    pub max_frames: Option<u64>,
    /// Stop after this many seconds: 1 to 3600, default 3600.
    #[schema(minimum = 1, maximum = 3600, example = 60)]
    pub max_seconds: Option<u64>,
}

/// Whether the bus is being recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum RecordingStateName {
    Recording,
    Stopped,
    /// Not recorded since the gateway started.
    None,
}

/// Why a recording stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum StopReasonName {
    /// `DELETE .../recording` (or the gateway stopping).
    Asked,
    MaxFrames,
    MaxSeconds,
    /// The bus closed: no frame could come any more.
    BusClosed,
    /// Writing the file failed; `error` says why.
    DiskError,
}

/// A bus's recording: the one running, or the last one.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, ToSchema)]
#[schema(example = json!({"state": "stopped", "stop_reason": "asked", "error": null,
    "file": "demo-20261123T180000Z.log", "download": "/api/v1/buses/demo/recording.log",
    "frames": 1532, "lost": 0, "bytes": 52301, "started_us": 1_795_000_000_000_000u64,
    "stopped_us": 1_795_000_030_000_000u64, "max_frames": 1_000_000, "max_seconds": 3600}))]
pub struct RecordingInfo {
    pub state: RecordingStateName,
    /// Why it stopped; null while it runs.
    pub stop_reason: Option<StopReasonName>,
    /// With `disk_error`: what the system said.
    pub error: Option<String>,
    /// The log's file name (the download's name).
    pub file: Option<String>,
    /// Where to download the log; null without a recording.
    pub download: Option<String>,
    /// Frames written to the log.
    pub frames: u64,
    /// Frames the recorder missed because it fell behind the bus.
    pub lost: u64,
    /// Bytes of log written.
    pub bytes: u64,
    /// When it started, microseconds since the Unix epoch.
    pub started_us: Option<u64>,
    /// When it stopped; null while it runs.
    pub stopped_us: Option<u64>,
    pub max_frames: Option<u64>,
    pub max_seconds: Option<u64>,
}

impl RecordingInfo {
    fn new(bus: &str, status: RecordingStatus) -> Self {
        Self {
            state: match status.state {
                RecordingState::Recording => RecordingStateName::Recording,
                RecordingState::Stopped => RecordingStateName::Stopped,
                RecordingState::None => RecordingStateName::None,
            },
            stop_reason: status.stop_reason.map(|reason| match reason {
                StopReason::Asked => StopReasonName::Asked,
                StopReason::MaxFrames => StopReasonName::MaxFrames,
                StopReason::MaxSeconds => StopReasonName::MaxSeconds,
                StopReason::BusClosed => StopReasonName::BusClosed,
                StopReason::DiskError => StopReasonName::DiskError,
            }),
            error: status.error,
            download: status
                .file
                .as_ref()
                .map(|_| format!("/api/v1/buses/{bus}/recording.log")),
            file: status.file,
            frames: status.frames,
            lost: status.lost,
            bytes: status.bytes,
            started_us: status.started.map(|at| at.as_micros()),
            stopped_us: status.stopped.map(|at| at.as_micros()),
            max_frames: status.limits.map(|limits| limits.max_frames),
            max_seconds: status.limits.map(|limits| limits.max_seconds),
        }
    }
}

/// Starts recording the bus to a candump `-L` log.
///
/// Every frame the gateway sees from now on (what the nodes send and what
/// the gateway sends) goes to a file, until `DELETE .../recording`,
/// `max_frames` (1 to 1000000, default 1000000) or `max_seconds` (1 to
/// 3600, default 3600). The body is optional. With `--data-dir DIR` the
/// files are kept in `DIR/recordings/`; otherwise they live in a temporary
/// directory, and a new recording replaces the last one.
#[utoipa::path(post, path = "/buses/{bus}/recording", tag = "frames", params(BusPath),
    request_body(content = Option<StartRecording>, description = "Limits (optional: no body, `null` or `{}` for the defaults)"),
    responses(
        (status = 201, description = "Recording", body = RecordingInfo),
        (status = 400, description = "`invalid_request` (malformed body, unknown field), `value_out_of_range` (a limit of 0 or above its maximum)", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
        (status = 409, description = "`recording_running`: the bus is being recorded already", body = ErrorBody),
        (status = 500, description = "`recording_failed`: the file cannot be made (disk full, no permission)", body = ErrorBody),
    ))]
async fn start_recording(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
    body: Bytes,
) -> Result<(StatusCode, ApiJson<RecordingInfo>), AppError> {
    // No body, or `null`, asks for the defaults.
    let request: StartRecording = if body.iter().all(u8::is_ascii_whitespace) {
        StartRecording::default()
    } else {
        serde_json::from_slice::<Option<StartRecording>>(&body)
            .map_err(|err| {
                AppError::InvalidRequest(format!("the body is no recording request: {err}"))
            })?
            .unwrap_or_default()
    };
    let limits =
        Limits::new(request.max_frames, request.max_seconds).map_err(GatewayError::from)?;
    let status = state.gateway.start_recording(&caller, &bus, limits).await?;
    Ok((
        StatusCode::CREATED,
        ApiJson(RecordingInfo::new(&bus, status)),
    ))
}

/// The bus's recording: the one running, or the last one.
///
/// `state` is `none` when the bus has not been recorded since the gateway
/// started.
#[utoipa::path(get, path = "/buses/{bus}/recording", tag = "frames", params(BusPath),
    responses(
        (status = 200, description = "The recording's status", body = RecordingInfo),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn recording_status(
    State(state): State<AppState>,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<RecordingInfo>, AppError> {
    let served = state.bus(&bus)?;
    Ok(ApiJson(RecordingInfo::new(
        &bus,
        served.recorder().status(),
    )))
}

/// Stops the bus's recording.
///
/// Every frame received until now is written and flushed; returns the final
/// status. The log stays downloadable.
#[utoipa::path(delete, path = "/buses/{bus}/recording", tag = "frames", params(BusPath),
    responses(
        (status = 200, description = "Stopped: the final status", body = RecordingInfo),
        (status = 404, description = "`unknown_bus`, `no_recording` (the bus has not been recorded)", body = ErrorBody),
        (status = 409, description = "`recording_not_running`: the recording has stopped already", body = ErrorBody),
    ))]
async fn stop_recording(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<RecordingInfo>, AppError> {
    let status = state.gateway.stop_recording(&caller, &bus).await?;
    Ok(ApiJson(RecordingInfo::new(&bus, status)))
}

/// The recording's log, a candump `-L` file.
///
/// One frame per line, `(SECONDS.MICROSECONDS) INTERFACE FRAME`, the
/// interface being the bus name (or `can0` when that is no Linux interface
/// name). While the recording runs, what it has written so far. Play it
/// back with `candeck serve --bus replay:FILE` or can-utils' `canplayer`.
#[utoipa::path(get, path = "/buses/{bus}/recording.log", tag = "frames", params(BusPath),
    responses(
        (status = 200, description = "The log", content_type = "text/plain", body = String,
            example = "(1795000000.000125) demo 701#7F\n(1795000000.103417) demo 601#4000100000000000\n"),
        (status = 404, description = "`unknown_bus`, `no_recording` (the bus has not been recorded, or its file is gone)", body = ErrorBody),
        (status = 500, description = "`recording_failed`: the file cannot be read", body = ErrorBody),
    ))]
async fn download_recording(
    State(state): State<AppState>,
    ApiPath(bus): ApiPath<String>,
) -> Result<Response, AppError> {
    let log = state
        .bus(&bus)?
        .recorder()
        .open_log()
        .await
        .map_err(GatewayError::from)?;
    let headers = [
        (
            header::CONTENT_TYPE,
            "text/plain; charset=utf-8".to_string(),
        ),
        (
            header::CONTENT_DISPOSITION,
            format!("attachment; filename=\"{}\"", log.file_name),
        ),
        (header::CONTENT_LENGTH, log.len.to_string()),
    ];
    Ok((headers, Body::from_stream(chunks(log.reader))).into_response())
}

/// A reader as the chunks of a response body.
fn chunks(
    reader: impl AsyncRead + Unpin + Send + 'static,
) -> impl futures_util::Stream<Item = std::io::Result<Bytes>> + Send + 'static {
    futures_util::stream::unfold(Some(reader), |reader| async move {
        let mut reader = reader?;
        let mut buf = vec![0; CHUNK];
        match reader.read(&mut buf).await {
            Ok(0) => None,
            Ok(n) => {
                buf.truncate(n);
                Some((Ok(Bytes::from(buf)), Some(reader)))
            }
            Err(err) => Some((Err(err), None)),
        }
    })
}
