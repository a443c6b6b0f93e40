//! The alarms through REST (`docs/alarms.md`); the model is the gateway's
//! (`crate::gateway::Alarms`).
//!
//! - `GET /alarms?state=&severity=&bus=&node=&since=&page=`: a page of at
//!   most 50, active first, and how many match;
//! - `GET /alarms/{id}`: one, with its history;
//! - `POST /alarms/{id}/ack` `{"comment"}` (optional): an operator
//!   acknowledges it;
//! - `POST /alarms/ack` `{"bus","node","severity","comment"}` (all
//!   optional): every unacknowledged alarm that matches;
//! - `POST /buses/{bus}/machine/reset-faults` and `/enable`: the machine's
//!   recovery, axis by axis.
//!
//! Each change goes out on the stream topic `alarms` as well.

use axum::body::Bytes;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{BusPath, ErrorBody};
use super::events::{parse_since, rfc3339};
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::gateway::{
    AckFilter, Alarm, AlarmChange, AlarmEvent, AlarmFilter, AlarmState, Alarms, AxisRecovery,
    RecoveryReport, Severity,
};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_alarms))
        .routes(routes!(one_alarm))
        .routes(routes!(acknowledge_one))
        .routes(routes!(acknowledge_matching))
        .routes(routes!(reset_faults))
        .routes(routes!(enable_all))
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct AlarmsQuery {
    /// `active_unacknowledged`, `active_acknowledged`,
    /// `cleared_unacknowledged` or `normal`.
    #[param(example = "active_unacknowledged")]
    state: Option<String>,
    /// `critical`, `high`, `medium` or `low`.
    #[param(example = "high")]
    severity: Option<String>,
    #[param(example = "demo")]
    bus: Option<String>,
    #[param(minimum = 1, maximum = 127, example = 1)]
    node: Option<u8>,
    /// Alarms whose cause was present at or after this time (active ones,
    /// and those cleared since): RFC 3339 or Unix milliseconds.
    #[param(example = "2026-11-23T18:00:00Z")]
    since: Option<String>,
    /// The page, from 1 (50 alarms a page).
    #[param(minimum = 1, example = 1)]
    page: Option<usize>,
}

/// One step of an alarm's life.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
pub struct AlarmStepBody {
    /// `raised`, `returned` (its cause back before it was acknowledged),
    /// `cleared`, `acknowledged`, `restored` (active before a restart, its
    /// cause still there after it).
    #[schema(example = "raised")]
    pub step: String,
    /// UTC, RFC 3339.
    #[schema(example = "2026-11-23T18:00:00.123456Z")]
    pub time: String,
    /// The state it left the alarm in.
    #[schema(example = "active_unacknowledged")]
    pub state: String,
    pub who: Option<String>,
    pub comment: Option<String>,
}

/// One alarm.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
pub struct AlarmBody {
    #[schema(example = 7)]
    pub id: u64,
    #[schema(example = "demo")]
    pub bus: String,
    /// Null for an alarm of the bus (bus off, error passive).
    #[schema(example = 1)]
    pub node: Option<u8>,
    /// Where the source says (the UMC's EMCYs, a statusword).
    #[schema(example = 2)]
    pub axis: Option<u8>,
    /// `axis_fault`, `emcy`, `node_offline`, `node_missing`,
    /// `wrong_identity`, `config_failed`, `heartbeat_lost`,
    /// `guarding_lost`, `bus_off`, `error_passive`, `lease_halted`,
    /// `program_failed`.
    #[schema(example = "emcy")]
    pub kind: String,
    /// An EMCY's error code.
    #[schema(example = "0x8611")]
    #[serde(skip_serializing_if = "Option::is_none")]
    pub code: Option<String>,
    /// `critical`, `high`, `medium` or `low`.
    #[schema(example = "high")]
    pub severity: String,
    /// `active_unacknowledged`, `active_acknowledged`,
    /// `cleared_unacknowledged` or `normal`.
    #[schema(example = "active_unacknowledged")]
    pub state: String,
    #[schema(example = "EMCY 0x8611: Following error (axis 2)")]
    pub text: String,
    /// What to look at, naming objects (`0x683F`) and values.
    pub help: String,
    /// UTC, RFC 3339.
    pub raised: String,
    /// When its cause last went; null while active.
    pub cleared: Option<String>,
    pub acknowledged_by: Option<String>,
    pub acknowledged_at: Option<String>,
    pub comment: Option<String>,
    /// How many times its cause came before it was back to normal.
    #[schema(example = 1)]
    pub count: u32,
    /// Its life, oldest first (`GET /alarms/{id}` only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub history: Option<Vec<AlarmStepBody>>,
}

impl AlarmBody {
    /// The alarm without its history (lists, the stream).
    pub fn of(alarm: &Alarm) -> Self {
        Self {
            id: alarm.id,
            bus: alarm.bus.clone(),
            node: alarm.node,
            axis: alarm.axis,
            kind: alarm.kind.name().to_string(),
            code: match alarm.kind {
                crate::gateway::AlarmKind::Emcy(code) => Some(format!("0x{code:04X}")),
                _ => None,
            },
            severity: alarm.severity.name().to_string(),
            state: alarm.state.name().to_string(),
            text: alarm.text.clone(),
            help: alarm.help.clone(),
            raised: rfc3339(alarm.raised_us),
            cleared: alarm.cleared_us.map(rfc3339),
            acknowledged_by: alarm.acknowledged_by.clone(),
            acknowledged_at: alarm.acknowledged_at_us.map(rfc3339),
            comment: alarm.comment.clone(),
            count: alarm.count,
            history: None,
        }
    }

    fn with_history(alarm: &Alarm) -> Self {
        let step = |event: &AlarmEvent| AlarmStepBody {
            step: event.step.name().to_string(),
            time: rfc3339(event.time_us),
            state: event.state.name().to_string(),
            who: event.who.clone(),
            comment: event.comment.clone(),
        };
        Self {
            history: Some(alarm.history.iter().map(step).collect()),
            ..Self::of(alarm)
        }
    }
}

/// A page of alarms.
#[derive(Debug, Serialize, ToSchema)]
pub struct AlarmList {
    pub alarms: Vec<AlarmBody>,
    /// How many match (every page).
    #[schema(example = 3)]
    pub total: usize,
}

/// The alarms: active first, then the cleared ones waiting for an
/// acknowledgement, then the history; the most severe and newest first
/// within each. At most 50 a page.
#[utoipa::path(get, path = "/alarms", tag = "alarms", params(AlarmsQuery),
    responses(
        (status = 200, description = "A page of alarms", body = AlarmList),
        (status = 400, description = "`invalid_request`: a filter or the page unreadable", body = ErrorBody),
    ))]
async fn list_alarms(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    query: Result<Query<AlarmsQuery>, QueryRejection>,
) -> Result<ApiJson<AlarmList>, AppError> {
    let Query(query) = query.map_err(|err| AppError::InvalidRequest(err.body_text()))?;
    let page = query.page.unwrap_or(1);
    let filter = AlarmFilter::try_from(query)?;
    let found = state.gateway.list_alarms(&caller, &filter, page)?;
    Ok(ApiJson(AlarmList {
        alarms: found.alarms.iter().map(AlarmBody::of).collect(),
        total: found.total,
    }))
}

impl TryFrom<AlarmsQuery> for AlarmFilter {
    type Error = AppError;

    fn try_from(query: AlarmsQuery) -> Result<Self, AppError> {
        let state = match query.state.as_deref() {
            None | Some("") => None,
            Some(name) => Some(AlarmState::from_name(name).ok_or_else(|| {
                AppError::InvalidRequest(format!(
                    "state '{name}': one of active_unacknowledged, active_acknowledged, \
                     cleared_unacknowledged, normal"
                ))
            })?),
        };
        Ok(Self {
            state,
            severity: severity(query.severity.as_deref())?,
            bus: query.bus.filter(|bus| !bus.is_empty()),
            node: query.node,
            since_us: query.since.as_deref().map(parse_since).transpose()?,
        })
    }
}

fn severity(name: Option<&str>) -> Result<Option<Severity>, AppError> {
    match name {
        None | Some("") => Ok(None),
        Some(name) => Severity::from_name(name).map(Some).ok_or_else(|| {
            AppError::InvalidRequest(format!(
                "severity '{name}': one of critical, high, medium, low"
            ))
        }),
    }
}

/// An alarm named in a path.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Path)]
#[allow(dead_code)]
pub struct AlarmPath {
    #[param(example = 7)]
    pub id: u64,
}

/// One alarm, with its history.
#[utoipa::path(get, path = "/alarms/{id}", tag = "alarms", params(AlarmPath),
    responses(
        (status = 200, description = "The alarm", body = AlarmBody),
        (status = 400, description = "`invalid_request`: no alarm id", body = ErrorBody),
        (status = 404, description = "`unknown_alarm`", body = ErrorBody),
    ))]
async fn one_alarm(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(id): ApiPath<String>,
) -> Result<ApiJson<AlarmBody>, AppError> {
    let alarm = state.gateway.alarm(&caller, &id)?;
    Ok(ApiJson(AlarmBody::with_history(&alarm)))
}

/// An acknowledgement's comment.
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct AckRequest {
    /// At most 500 characters.
    #[schema(example = "fan replaced")]
    pub comment: Option<String>,
}

/// Acknowledges an alarm: who (the token's name) and when are kept with
/// it. An active alarm stays active (`active_acknowledged`) until its
/// cause goes; a cleared one goes back to `normal`. An alarm that waits
/// for no acknowledgement is answered as it is. The body is optional.
#[utoipa::path(post, path = "/alarms/{id}/ack", tag = "alarms", params(AlarmPath),
    request_body(content = Option<AckRequest>, description = "An optional comment"),
    responses(
        (status = 200, description = "The alarm as it is now", body = AlarmBody),
        (status = 400, description = "`invalid_request`: no alarm id, a malformed body, a comment over 500 characters", body = ErrorBody),
        (status = 403, description = "`forbidden`: not an operator", body = ErrorBody),
        (status = 404, description = "`unknown_alarm`", body = ErrorBody),
    ))]
async fn acknowledge_one(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(id): ApiPath<String>,
    body: Bytes,
) -> Result<ApiJson<AlarmBody>, AppError> {
    let request: AckRequest = optional_body(&body)?;
    let alarm = state
        .gateway
        .acknowledge_alarm(&caller, &id, request.comment)
        .await?;
    Ok(ApiJson(AlarmBody::of(&alarm)))
}

/// Which alarms to acknowledge (every field optional: none, all).
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct AckAllRequest {
    #[schema(example = "demo")]
    pub bus: Option<String>,
    #[schema(example = 1)]
    pub node: Option<u8>,
    /// `critical`, `high`, `medium` or `low`.
    #[schema(example = "high")]
    pub severity: Option<String>,
    /// At most 500 characters.
    pub comment: Option<String>,
}

/// What an acknowledgement of many did.
#[derive(Debug, Serialize, ToSchema)]
pub struct AckAllResult {
    /// The alarms acknowledged, as they are now.
    pub acknowledged: Vec<AlarmBody>,
}

/// Acknowledges every alarm that waits for an acknowledgement and matches
/// the filter (bus, node, severity; no filter: all). The body is optional.
#[utoipa::path(post, path = "/alarms/ack", tag = "alarms",
    request_body(content = Option<AckAllRequest>, description = "The filter and an optional comment"),
    responses(
        (status = 200, description = "The alarms acknowledged", body = AckAllResult),
        (status = 400, description = "`invalid_request`: a malformed body, an unknown severity, a comment over 500 characters", body = ErrorBody),
        (status = 403, description = "`forbidden`: not an operator", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn acknowledge_matching(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    body: Bytes,
) -> Result<ApiJson<AckAllResult>, AppError> {
    let request: AckAllRequest = optional_body(&body)?;
    let filter = AckFilter {
        bus: request.bus,
        node: request.node,
        severity: severity(request.severity.as_deref())?,
    };
    let acknowledged = state
        .gateway
        .acknowledge_alarms(&caller, filter, request.comment)
        .await?;
    Ok(ApiJson(AckAllResult {
        acknowledged: acknowledged.iter().map(AlarmBody::of).collect(),
    }))
}

/// A JSON body that may be left out (empty: the defaults).
fn optional_body<T: Default + serde::de::DeserializeOwned>(body: &[u8]) -> Result<T, AppError> {
    if body.iter().all(u8::is_ascii_whitespace) {
        return Ok(T::default());
    }
    serde_json::from_slice(body).map_err(|err| AppError::InvalidRequest(format!("body: {err}")))
}

/// One axis of a machine's recovery.
#[derive(Debug, Serialize, ToSchema)]
pub struct AxisRecoveryBody {
    #[schema(example = 1)]
    pub node: u8,
    #[schema(example = 2)]
    pub axis: u8,
    /// `done`, `not_needed` (not in fault), or `refused`.
    #[schema(example = "refused")]
    pub outcome: String,
    /// Why it was refused: the cause still present, in words.
    #[schema(example = "the cause is still present: alarm 3 (critical): node 2: Heartbeat lost")]
    pub reason: Option<String>,
    /// The error's code where an operation refused it (`drive_fault`,
    /// `node_offline`, `lease_conflict`).
    pub code: Option<String>,
    /// Its PDS state after it, where read.
    #[schema(example = "switch_on_disabled")]
    pub state: Option<String>,
}

/// What a machine's recovery did, axis by axis.
#[derive(Debug, Serialize, ToSchema)]
pub struct RecoveryBody {
    #[schema(example = "demo")]
    pub bus: String,
    pub axes: Vec<AxisRecoveryBody>,
}

impl From<RecoveryReport> for RecoveryBody {
    fn from(report: RecoveryReport) -> Self {
        let axis = |axis: AxisRecovery| AxisRecoveryBody {
            node: axis.node,
            axis: axis.axis,
            outcome: axis.outcome.name().to_string(),
            reason: axis.reason,
            code: axis.code,
            state: axis.state,
        };
        Self {
            bus: report.bus,
            axes: report.axes.into_iter().map(axis).collect(),
        }
    }
}

/// Resets the fault of every axis of the bus's drives that is in fault.
/// An axis whose cause is still present (its node offline, missing,
/// unconfigured or its heartbeat lost, the bus off, a fault that does not
/// reset) is refused with its reason; the others are reset. Each reset is
/// the axis's own `fault reset` (audited, one write each).
#[utoipa::path(post, path = "/buses/{bus}/machine/reset-faults", tag = "machine", params(BusPath),
    responses(
        (status = 200, description = "Axis by axis", body = RecoveryBody),
        (status = 403, description = "`forbidden`: not an operator", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn reset_faults(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<RecoveryBody>, AppError> {
    let report = state.gateway.reset_machine_faults(&caller, &bus).await?;
    Ok(ApiJson(report.into()))
}

/// Puts every axis the gateway last put in operation enabled back in
/// operation enabled. An axis whose cause is still present, or still in
/// fault, is refused with its reason. Each is the axis's own `drive state
/// change` (its lease rules, audited, one write each).
#[utoipa::path(post, path = "/buses/{bus}/machine/enable", tag = "machine", params(BusPath),
    responses(
        (status = 200, description = "Axis by axis", body = RecoveryBody),
        (status = 403, description = "`forbidden`: not an operator", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn enable_all(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<RecoveryBody>, AppError> {
    let report = state.gateway.enable_machine(&caller, &bus).await?;
    Ok(ApiJson(report.into()))
}

/// The counts of a summary, by severity name.
fn counts(by_severity: [u32; 4]) -> serde_json::Value {
    let mut counts = serde_json::Map::new();
    for (severity, count) in Severity::ALL.iter().zip(by_severity) {
        counts.insert(severity.name().to_string(), count.into());
    }
    serde_json::Value::Object(counts)
}

/// The summary the stream's `alarms` topic sends with each message.
fn stream_summary(alarms: &Alarms) -> serde_json::Value {
    let summary = alarms.summary(None, None);
    serde_json::json!({
        "active": counts(summary.active),
        "unacknowledged": counts(summary.unacknowledged),
        "highest": summary.highest.map(Severity::name),
    })
}

/// The stream's `alarms` topic when subscribed: every alarm that is not
/// `normal`, and the counts.
pub fn stream_open(alarms: &Alarms) -> serde_json::Value {
    let open: Vec<AlarmBody> = alarms.open(None).iter().map(AlarmBody::of).collect();
    serde_json::json!({
        "event": "open",
        "alarms": open,
        "summary": stream_summary(alarms),
    })
}

/// One change on the stream's `alarms` topic: the step, the alarm as it
/// is now, and the counts.
pub fn stream_change(alarms: &Alarms, change: &AlarmChange) -> serde_json::Value {
    serde_json::json!({
        "event": change.step.name(),
        "alarm": AlarmBody::of(&change.alarm),
        "summary": stream_summary(alarms),
    })
}
