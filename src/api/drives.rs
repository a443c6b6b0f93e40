//! CiA 402 drives (`docs/rest-api.md`, "Routes"): the axes of nodes whose
//! profile is `umc`, `jmc_stepper` or `cia402`, their state machine, fault
//! reset, halt and moves, and `POST /stop-all`. The CiA 402 master itself is
//! `crate::gateway::drive`.
//!
//! Errors beside the SDO ones (see [`super::od`]):
//! - 404 `not_a_drive`: the node's profile has no axes (`uioled`,
//!   `generic`); 404 `unknown_axis`: no such axis on the node (axes count
//!   from 1; a UMC1BDS32 has 2).
//! - 409 `drive_fault`: the axis is in fault, went there during a walk or
//!   a move's change of mode, or its fault is still present after a fault
//!   reset; 409 `drive_not_enabled`: a move, or the target
//!   quick_stop_active, needs operation enabled (and a move whose change of
//!   mode a quick stop interrupts gets it too, as does a state walk that
//!   sees the drive stopped by someone else meanwhile). Both carry `state`.
//! - 422 `mode_not_supported`: the drive lacks the mode (0x6502, or the
//!   product's fixed list).
//! - 504 `state_change_timeout`: the statusword (or 0x6061, or the
//!   set-point acknowledge) did not show the step in time; `state` is where
//!   the drive stopped.
//!
//! Motion leases ([`super::leases`]): a velocity, torque or duty-cycle move,
//! and releasing halt in one of those modes, answers with a `lease` that the
//! client renews; an interpolated move holds one while its request feeds
//! points. While a lease is held, a move, `halt: false` or the target
//! `operation_enabled` from anyone who does not present it in the
//! `Candeck-Lease` header, or presents it but is not its holder, is refused
//! with 409 `lease_conflict`, unless it asks for an explicit take-over
//! (`Candeck-Lease-Takeover: true`: the lease ends, and the audit entry
//! names both holders); halting, quick stop, a walk out of operation
//! enabled and STOP ALL are never refused, and end the lease.
//!
//! The policy is the gateway's (`crate::gateway::motion`, which the
//! Sparkplug edge node calls too): the handlers read the request and its
//! headers, call one operation and map its outcome. Every sequence runs in
//! a task of its own and the handler awaits it: a client that hangs up
//! never cuts a walk or a move half way. A move that
//! fails after its first write halts the axis (quick stop if halting fails)
//! before the error is answered.

use axum::extract::State;
use axum::http::HeaderMap;
use serde::{Deserialize, Serialize};
use serde_json::Value as Json;
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{ErrorBody, ErrorDetail, NodePath};
use super::leases::{LeaseInfo, presented, takeover_asked};
use super::schema;
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::gateway::GatewayError;
use crate::gateway::{AxisLimits, AxisStatus, AxisUnits, DriveError, MoveRequest, TargetState};
use crate::gateway::{LeaseClaim, MotionFailed, MotionOutcome, spawned};
use crate::gateway::{StepTestRequest, StepTestResult};
use crate::gateway::{StopAttempt, StopReport};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_axes))
        .routes(routes!(one_axis))
        .routes(routes!(set_state))
        .routes(routes!(fault_reset))
        .routes(routes!(halt))
        .routes(routes!(run_move))
        .routes(routes!(step_test))
        .routes(routes!(stop_all))
}

impl From<DriveError> for AppError {
    fn from(error: DriveError) -> Self {
        GatewayError::from(error).into()
    }
}

/// An axis of a node named in a path.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Path)]
#[allow(dead_code)]
pub struct AxisPath {
    /// The bus name.
    #[param(example = "demo")]
    pub bus: String,
    /// The node id, 1 to 127.
    #[param(minimum = 1, maximum = 127, example = 1)]
    pub id: u8,
    /// The axis, from 1.
    #[param(minimum = 1, example = 1)]
    pub axis: u8,
}

/// `POST .../state`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StateRequest {
    #[schema(value_type = schema::TargetState)]
    pub target: TargetState,
}

/// `POST .../halt`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct HaltRequest {
    /// Controlword bit 8: true stops the motion and holds, false carries on.
    pub halt: bool,
}

/// An axis `POST /stop-all` quick-stopped.
#[derive(Debug, Serialize, ToSchema)]
pub struct StoppedAxis {
    #[schema(example = "demo")]
    pub bus: String,
    #[schema(example = 1)]
    pub node: u8,
    #[schema(example = 1)]
    pub axis: u8,
    /// What was tried and what the drive confirmed.
    #[schema(value_type = Vec<schema::StopAttempt>)]
    pub attempts: Vec<StopAttempt>,
}

/// A node or axis `POST /stop-all` could not stop (or not ask).
#[derive(Debug, Serialize, ToSchema)]
pub struct StopFailure {
    #[schema(example = "demo")]
    pub bus: String,
    #[schema(example = 2)]
    pub node: u8,
    /// Null when the node as a whole failed (its axes could not be named).
    #[schema(example = 1)]
    pub axis: Option<u8>,
    /// The first failure (`sdo_timeout`: the node did not answer;
    /// `state_change_timeout`: the statusword did not show the quick stop).
    #[schema(value_type = ErrorDetail)]
    pub error: Json,
    /// What was tried, in order, with its outcome: the quick stop, then NMT
    /// stop of the node.
    #[schema(value_type = Vec<schema::StopAttempt>)]
    pub attempts: Vec<StopAttempt>,
}

/// What `POST /stop-all` did.
#[derive(Debug, Serialize, ToSchema)]
pub struct StopAllReport {
    /// The axes that were in operation enabled and confirmed the quick stop
    /// (the statusword read back out of operation enabled).
    pub stopped: Vec<StoppedAxis>,
    /// The axes that did not confirm it (or could not be read), whatever
    /// was sent instead.
    pub failed: Vec<StopFailure>,
}

/// One axis with what a page needs to label and bound its values: the
/// units its product's manual gives them and the limits the drive applies.
#[derive(Debug, Serialize, ToSchema)]
pub struct AxisDetail {
    #[serde(flatten)]
    #[schema(value_type = schema::AxisStatus)]
    pub status: AxisStatus,
    #[schema(value_type = schema::AxisUnits)]
    pub units: AxisUnits,
    #[schema(value_type = schema::AxisLimits)]
    pub limits: AxisLimits,
}

/// An axis after a state walk; after a quick stop, what was tried.
#[derive(Debug, Serialize, ToSchema)]
pub struct StateResponse {
    #[serde(flatten)]
    #[schema(value_type = schema::AxisStatus)]
    pub status: AxisStatus,
    /// With the target `quick_stop_active`: the steps of the stop and their
    /// outcome (`[{"method":"quick_stop","outcome":"confirmed",...}]`;
    /// empty when the axis was in quick stop active already).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Vec<schema::StopAttempt>>)]
    pub attempts: Option<Vec<StopAttempt>>,
}

/// An axis after a command that may start motion: its status, and the
/// motion lease its client must renew when the motion has no end of its
/// own (velocity, torque, duty cycle), else null.
#[derive(Debug, Serialize, ToSchema)]
pub struct MotionResponse {
    #[serde(flatten)]
    #[schema(value_type = schema::AxisStatus)]
    pub status: AxisStatus,
    pub lease: Option<LeaseInfo>,
    /// With a halt: the steps of the stop and their outcome.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = Option<Vec<schema::StopAttempt>>)]
    pub attempts: Option<Vec<StopAttempt>>,
}

/// The axes of a drive node, read now.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}/axes", tag = "drives", params(NodePath),
    responses(
        (status = 200, description = "Every axis of the node", body = [schema::AxisStatus]),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_a_drive`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`", body = ErrorBody),
        (status = 422, description = "`sdo_abort`", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn list_axes(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<ApiJson<Vec<AxisStatus>>, AppError> {
    let node = state.gateway.node_handle(&bus, &id)?;
    Ok(ApiJson(node.read_axes(&caller).await?))
}

/// One axis, read now.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}/axes/{axis}", tag = "drives", params(AxisPath),
    responses(
        (status = 200, description = "The axis, with its units and the limits the drive applies to requests (0x607F, 0x6080, 0x6046, 0x607D) and its factor group (0x604C, 0x608F, 0x6091)", body = AxisDetail),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_a_drive`, `unknown_axis`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`; `node_offline`: its heartbeat is lost", body = ErrorBody),
        (status = 422, description = "`sdo_abort`", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn one_axis(
    State(state): State<AppState>,
    ApiPath((bus, id, axis)): ApiPath<(String, String, String)>,
) -> Result<ApiJson<AxisDetail>, AppError> {
    let drive = state.gateway.drive(&bus, &id, &axis)?;
    let detail = spawned(drive, |drive| async move {
        Ok(AxisDetail {
            status: drive.status().await?,
            units: drive.units(),
            limits: drive.limits().await?,
        })
    })
    .await?;
    Ok(ApiJson(detail))
}

/// Walks the CiA 402 state machine to a state.
///
/// One transition at a time, the statusword checked after each. A drive in
/// fault is not reset by this (`fault-reset` does that): 409 `drive_fault`.
///
/// Quick stop active is reached from operation enabled only (409
/// `drive_not_enabled` otherwise: the motor is not powered to be stopped).
/// It is sent whatever the gateway believes of the node (offline, NMT state,
/// not identified yet), each step bounded by 500 ms: the quick stop
/// controlword, confirmed in the statusword; if the drive does not confirm
/// or answer, NMT stop of the node. The answer's `attempts` say what was
/// tried; a stop not confirmed answers with the error of the quick stop and
/// the `attempts` in the error.
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/axes/{axis}/state", tag = "drives",
    params(AxisPath, ("Candeck-Lease" = Option<String>, Header, description = "The motion lease held on the axis, to command it while the lease is held (its holder only)"), ("Candeck-Lease-Takeover" = Option<bool>, Header, description = "`true`: take the axis over from the lease held on it (operator or admin; audited, naming both holders)")),
    request_body = StateRequest,
    responses(
        (status = 200, description = "The axis in the state asked for; after a quick stop, the steps tried in `attempts`", body = StateResponse),
        (status = 400, description = "`invalid_request`: no such target", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_a_drive`, `unknown_axis`", body = ErrorBody),
        (status = 409, description = "`drive_fault` (with `state`); `drive_not_enabled`: quick_stop_active asked of an axis not in operation_enabled, or a walk interrupted by a stop (STOP ALL, a quick stop, a lapsed lease) meanwhile; `wrong_nmt_state`, `node_offline` (its heartbeat is lost): any target but quick_stop_active; `lease_conflict`: operation_enabled asked of an axis another client's lease holds, or with a lease of another token; `motion_stopped`: a stop of the axis came after the command was taken, which was not sent; `node_busy`: a program download or a renumbering runs on the node", body = ErrorBody),
        (status = 422, description = "`sdo_abort`", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`state_change_timeout` (with the `state` it stopped in), `sdo_timeout`; a quick stop not confirmed carries `attempts` (NMT stop `sent`)", body = ErrorBody),
    ))]
async fn set_state(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    headers: HeaderMap,
    ApiPath((bus, id, axis)): ApiPath<(String, String, String)>,
    ApiJson(request): ApiJson<StateRequest>,
) -> Result<ApiJson<StateResponse>, AppError> {
    // The take-over header is read only where it can count: a stop is
    // never refused, not even for a malformed header.
    let takeover = request.target == TargetState::OperationEnabled && takeover_asked(&headers)?;
    let claim = LeaseClaim::presented(presented(&headers), takeover);
    let outcome = state
        .gateway
        .set_axis_state(&caller, (&bus, &id, &axis), request.target, &claim)
        .await
        .map_err(failure)?;
    Ok(ApiJson(StateResponse {
        status: outcome.status,
        attempts: outcome.attempts,
    }))
}

/// A motion operation that failed; a stop the drive did not confirm, with
/// what was tried.
fn failure(failed: MotionFailed) -> AppError {
    if failed.attempts.is_empty() {
        return failed.error.into();
    }
    GatewayError::StopNotConfirmed {
        source: Box::new(failed.error),
        attempts: failed.attempts,
    }
    .into()
}

/// Resets a fault (controlword bit 7, 0→1).
///
/// An axis not in fault is left as it is. A fault still present keeps the
/// drive in fault: 409 `drive_fault`.
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/axes/{axis}/fault-reset", tag = "drives", params(AxisPath),
    responses(
        (status = 200, description = "The axis, out of fault (switch_on_disabled)", body = schema::AxisStatus),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_a_drive`, `unknown_axis`", body = ErrorBody),
        (status = 409, description = "`drive_fault`: the fault is still present; `wrong_nmt_state`; `node_offline`: its heartbeat is lost; `motion_stopped`: a stop of the axis came after the command was taken, which was not sent; `node_busy`: a program download or a renumbering runs on the node", body = ErrorBody),
        (status = 422, description = "`sdo_abort`", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn fault_reset(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id, axis)): ApiPath<(String, String, String)>,
) -> Result<ApiJson<AxisStatus>, AppError> {
    let status = state
        .gateway
        .reset_axis_fault(&caller, (&bus, &id, &axis))
        .await?;
    Ok(ApiJson(status))
}

/// Sets or clears halt (controlword bit 8).
///
/// The rest of the controlword is kept (read back on a UMC; implied by the
/// state on a JMC, whose controlword is write only).
///
/// `halt: true` is sent whatever the gateway believes of the node (offline,
/// NMT state, not identified yet), bounded by 1 s; if it cannot be given,
/// quick stop by controlword, then NMT stop of the node if the drive does
/// not confirm. The answer's `attempts` say what was tried; a halt that
/// could not be given answers with its error and the `attempts` in it.
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/axes/{axis}/halt", tag = "drives",
    params(AxisPath, ("Candeck-Lease" = Option<String>, Header, description = "The motion lease held on the axis, to command it while the lease is held (its holder only)"), ("Candeck-Lease-Takeover" = Option<bool>, Header, description = "`true`: take the axis over from the lease held on it (operator or admin; audited, naming both holders)")),
    request_body = HaltRequest,
    responses(
        (status = 200, description = "The axis after the controlword; releasing halt in velocity, torque or duty-cycle mode answers with a motion lease", body = MotionResponse),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_a_drive`, `unknown_axis`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`, `node_offline` (its heartbeat is lost): halt released only; `lease_conflict`: halt released on an axis another client's lease holds, or with a lease of another token; `motion_stopped`: a stop of the axis came after the command was taken, which was not sent; `node_busy`: a program download or a renumbering runs on the node", body = ErrorBody),
        (status = 422, description = "`sdo_abort`", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`; a halt that could not be given carries `attempts` (quick stop, NMT stop)", body = ErrorBody),
    ))]
async fn halt(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    headers: HeaderMap,
    ApiPath((bus, id, axis)): ApiPath<(String, String, String)>,
    ApiJson(request): ApiJson<HaltRequest>,
) -> Result<ApiJson<MotionResponse>, AppError> {
    let claim = if request.halt {
        // A stop: no lease to present, nothing to take over.
        LeaseClaim::default()
    } else {
        LeaseClaim::presented(presented(&headers), takeover_asked(&headers)?)
    };
    let outcome = state
        .gateway
        .set_axis_halt(&caller, (&bus, &id, &axis), request.halt, &claim)
        .await
        .map_err(failure)?;
    Ok(ApiJson(motion_response(outcome)))
}

fn motion_response(outcome: MotionOutcome) -> MotionResponse {
    let now = tokio::time::Instant::now();
    MotionResponse {
        status: outcome.status,
        lease: outcome.lease.map(|lease| LeaseInfo::of(&lease, now)),
        attempts: outcome.attempts,
    }
}

/// Starts a motion in one of the drive's modes.
///
/// The axis must be in operation enabled. The gateway switches the mode
/// (0x6060, waiting for 0x6061), writes the mode's objects for the product
/// (UMC axis offsets; JMC velocity in 0.1 rps on 0x6081, 16-bit
/// accelerations) and gives the controlwords: profile position waits for the
/// set-point acknowledge, interpolated position for the last point to be in
/// the buffer; the others answer once started. Values are device units. A
/// move clears halt. If it fails half way, the axis is halted (or
/// quick-stopped) before the error is answered.
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/axes/{axis}/move", tag = "drives",
    params(AxisPath, ("Candeck-Lease" = Option<String>, Header, description = "The motion lease held on the axis, to command it while the lease is held (its holder only)"), ("Candeck-Lease-Takeover" = Option<bool>, Header, description = "`true`: take the axis over from the lease held on it (operator or admin; audited, naming both holders)")),
    request_body = schema::MoveRequest,
    responses(
        (status = 200, description = "The motion is under way; the axis as it is now, and for velocity, torque and duty cycle the lease to renew", body = MotionResponse),
        (status = 400, description = "`invalid_request`, `invalid_value`, `value_out_of_range`: before the bus", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_a_drive`, `unknown_axis`", body = ErrorBody),
        (status = 409, description = "`drive_fault`, `drive_not_enabled` (with `state`), `wrong_nmt_state`, `node_offline`: its heartbeat is lost; `lease_conflict`: another client's lease holds the axis, or the lease presented is another token's; `motion_stopped`: a stop of the axis came after the command was taken, which was not sent; `node_busy`: a program download or a renumbering runs on the node", body = ErrorBody),
        (status = 422, description = "`mode_not_supported`, `sdo_abort`", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`state_change_timeout` (mode change, set-point acknowledge), `sdo_timeout`", body = ErrorBody),
    ))]
async fn run_move(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    headers: HeaderMap,
    ApiPath((bus, id, axis)): ApiPath<(String, String, String)>,
    ApiJson(request): ApiJson<MoveRequest>,
) -> Result<ApiJson<MotionResponse>, AppError> {
    let claim = LeaseClaim::presented(presented(&headers), takeover_asked(&headers)?);
    let outcome = state
        .gateway
        .move_axis(&caller, (&bus, &id, &axis), &request, &claim)
        .await
        .map_err(failure)?;
    Ok(ApiJson(motion_response(outcome)))
}

/// Step test of a UMC axis's control loop.
///
/// Holds the loop's target at `from` for `hold_ms`, steps it to `to` and
/// holds it for `hold_ms` again while the actual value is recorded: from
/// each frame of a running TPDO that carries it (`source` `tpdo`), else read
/// by SDO every millisecond or as fast as the node answers (`sdo`); answers
/// the response and its metrics. The torque loop
/// runs in TQ (0x6071/0x6077), the velocity loop in VL (0x6042/0x6044), the
/// position loop in PP with change immediately (0x607A/0x6064), each
/// through its mode's ramp. The axis holds a motion lease while the test
/// runs and is halted at the end, and on any failure.
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/axes/{axis}/step-test", tag = "drives",
    params(AxisPath, ("Candeck-Lease" = Option<String>, Header, description = "The motion lease held on the axis, to command it while the lease is held (its holder only)"), ("Candeck-Lease-Takeover" = Option<bool>, Header, description = "`true`: take the axis over from the lease held on it (operator or admin; audited, naming both holders)")),
    request_body = schema::StepTestRequest,
    responses(
        (status = 200, description = "The response and its metrics; the axis is halted", body = schema::StepTestResult),
        (status = 400, description = "`invalid_request`, `invalid_value` (from = to, hold_ms outside 20 to 10,000, settle_band_pct outside 0 to 50), `value_out_of_range`: before the bus", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_a_drive`, `unknown_axis`", body = ErrorBody),
        (status = 409, description = "`drive_not_enabled`: the axis is not in operation_enabled (or left it during the test); `drive_fault`; `wrong_nmt_state`, `node_offline`; `lease_conflict`; `motion_stopped`: the axis was stopped (halt, quick stop, STOP ALL, the lease lapsed when its client went away) during the test, which sent no later step; `node_busy`: a program download or a renumbering runs on the node", body = ErrorBody),
        (status = 422, description = "`mode_not_supported`: the drive is not UMC-class (no control loop objects), or lacks the loop's mode; `sdo_abort`", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`state_change_timeout`, `sdo_timeout`", body = ErrorBody),
    ))]
async fn step_test(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    headers: HeaderMap,
    ApiPath((bus, id, axis)): ApiPath<(String, String, String)>,
    ApiJson(request): ApiJson<StepTestRequest>,
) -> Result<ApiJson<StepTestResult>, AppError> {
    let claim = LeaseClaim::presented(presented(&headers), takeover_asked(&headers)?);
    let outcome = state
        .gateway
        .step_test_axis(&caller, (&bus, &id, &axis), &request, &claim)
        .await
        .map_err(failure)?;
    Ok(ApiJson(outcome.status))
}

/// Quick stop of every enabled axis on every bus.
///
/// Every axis of every node known as a drive, online or not and whatever
/// its NMT state, and every axis the gateway enabled, all nodes at once; an
/// axis in operation enabled gets the quick stop command, confirmed in its
/// statusword. Each step is bounded by 500 ms; a drive that does not confirm
/// or answer gets NMT stop of its node. The answer lists the axes that
/// confirmed and those that did not, each with the steps tried
/// (`attempts`).
#[utoipa::path(post, path = "/stop-all", tag = "drives",
    responses(
        (status = 200, description = "What was stopped, and what failed", body = StopAllReport),
    ))]
async fn stop_all(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
) -> Result<ApiJson<StopAllReport>, AppError> {
    let report = state.gateway.stop_all(&caller).await?;
    Ok(ApiJson(StopAllReport::from(report)))
}

impl From<StopReport> for StopAllReport {
    fn from(report: StopReport) -> Self {
        Self {
            stopped: report
                .stopped
                .into_iter()
                .map(|stopped| StoppedAxis {
                    bus: stopped.axis.bus,
                    node: stopped.axis.node,
                    axis: stopped.axis.axis,
                    attempts: stopped.attempts,
                })
                .collect(),
            failed: report
                .failed
                .into_iter()
                .map(|failure| StopFailure {
                    bus: failure.bus,
                    node: failure.node,
                    axis: failure.axis,
                    error: AppError::from(failure.error).to_json(),
                    attempts: failure.attempts,
                })
                .collect(),
        }
    }
}
