//! The data logger through REST (`docs/data-logger.md`); the gateway side
//! is `crate::gateway::logger`.
//!
//! - `POST /loggers` `{"channels":[{"bus","node","index","sub"}],"period_ms","duration_s"}`
//!   starts one (201 with its status, `id` among it);
//! - `GET /loggers` every logger kept, `GET /loggers/{id}` one: state and
//!   statistics (samples, missed, dropped, per channel its source `sdo` or
//!   `tpdo` and its errors);
//! - `GET /loggers/{id}/data.csv` the rows: `time_ms,<channel names>`;
//! - `DELETE /loggers/{id}` stops it and forgets it (its kept files too).
//!
//! The live rows are the `loggers/{id}` topic of `/stream`.

use axum::extract::State;
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use utoipa::IntoParams;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::ErrorBody;
use super::schema;
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::gateway::{LoggerRequest, LoggerStatus};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(create_logger, list_loggers))
        .routes(routes!(logger_status, delete_logger))
        .routes(routes!(logger_csv))
}

/// A logger named in a path.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Path)]
#[allow(dead_code)]
pub struct LoggerPath {
    /// The logger's id, as `POST /loggers` gave it.
    #[param(example = 1)]
    pub id: u64,
}

/// Starts a data logger.
///
/// Each channel is an object of a node, by number or EDS name. Every
/// `period_ms` (1 to 60000) for `duration_s` (1 to 86400) each channel is
/// sampled: from the node's TPDO when one carries the object and came
/// within a second (`source: "tpdo"`), else by an SDO upload queued with
/// every other transfer to the node (`source: "sdo"`). At most 16 channels
/// and 16 loggers (a new one replaces the oldest finished one).
#[utoipa::path(post, path = "/loggers", tag = "loggers",
    request_body = schema::LoggerRequest,
    responses(
        (status = 201, description = "Started: its status", body = schema::LoggerStatus),
        (status = 400, description = "`invalid_request` (malformed body, unknown field), `too_many_entries` (no channel, or more than 16), `value_out_of_range` (period_ms or duration_s), `invalid_index`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `unknown_object`, `unknown_sub_object`", body = ErrorBody),
        (status = 409, description = "`too_many_loggers`: 16 loggers run; `wrong_nmt_state`", body = ErrorBody),
        (status = 422, description = "`not_loggable`: the object is write-only or no number; `sdo_abort` (the trial read of an object the EDS does not describe)", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn create_logger(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiJson(request): ApiJson<LoggerRequest>,
) -> Result<(StatusCode, ApiJson<LoggerStatus>), AppError> {
    let status = state.gateway.start_logger(&caller, request).await?;
    Ok((StatusCode::CREATED, ApiJson(status)))
}

/// The loggers kept: running, done, and those of an earlier run kept in
/// the data directory.
#[utoipa::path(get, path = "/loggers", tag = "loggers",
    responses(
        (status = 200, description = "Oldest first", body = [schema::LoggerStatus]),
    ))]
async fn list_loggers(State(state): State<AppState>) -> ApiJson<Vec<LoggerStatus>> {
    ApiJson(state.gateway.loggers().list())
}

/// A logger's status and statistics.
#[utoipa::path(get, path = "/loggers/{id}", tag = "loggers", params(LoggerPath),
    responses(
        (status = 200, description = "Its status", body = schema::LoggerStatus),
        (status = 404, description = "`unknown_logger`", body = ErrorBody),
    ))]
async fn logger_status(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<ApiJson<LoggerStatus>, AppError> {
    Ok(ApiJson(state.gateway.loggers().status(&id)?))
}

/// Stops a logger and forgets it.
///
/// Its rows go, and its files in the data directory; the answer is its
/// last status.
#[utoipa::path(delete, path = "/loggers/{id}", tag = "loggers", params(LoggerPath),
    responses(
        (status = 200, description = "Its last status", body = schema::LoggerStatus),
        (status = 404, description = "`unknown_logger`", body = ErrorBody),
    ))]
async fn delete_logger(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(id): ApiPath<String>,
) -> Result<ApiJson<LoggerStatus>, AppError> {
    Ok(ApiJson(state.gateway.delete_logger(&caller, &id).await?))
}

/// A logger's rows as CSV.
///
/// A header `time_ms,<channel names>` (each `bus/node/EDS name`), then a
/// row per sample time: milliseconds from the start, and each channel's
/// value (empty where its read failed). While it runs, the rows so far.
#[utoipa::path(get, path = "/loggers/{id}/data.csv", tag = "loggers", params(LoggerPath),
    responses(
        (status = 200, description = "The rows", content_type = "text/csv", body = String,
            example = "time_ms,demo/1/a1_pc_Position_actual_value,demo/1/a1_pv_Velocity_actual_value\n0,0,0\n10,12,1200\n"),
        (status = 404, description = "`unknown_logger`", body = ErrorBody),
    ))]
async fn logger_csv(
    State(state): State<AppState>,
    ApiPath(id): ApiPath<String>,
) -> Result<Response, AppError> {
    let csv = state.gateway.loggers().csv(&id)?;
    Ok((
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"logger-{id}.csv\""),
            ),
        ],
        csv,
    )
        .into_response())
}
