//! `GET /events`: the persisted history (`docs/rest-api.md`, "Audit
//! log and history"): the audit log of state-changing requests, the
//! EMCYs (CiA 301 §7.2.7) and the NMT/supervision events of every bus,
//! from [`History`](crate::gateway::History).
//!
//! Entries come oldest first. With `since` (RFC 3339 or Unix milliseconds)
//! they are the first `limit` entries at or after that time, so a client
//! pages by asking again from the last `time_us` it got (and drops the
//! entries it has, by `kind` and `id`); without `since`, the newest
//! `limit`. `until` (same forms) bounds them from above: without `since`
//! it gives the newest `limit` entries at or before it, which is how the
//! dashboard's events page loads older entries.

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use serde::{Deserialize, Serialize};
use serde_json::Value as Json;
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::doc::ErrorBody;
use super::{ApiJson, AppError, AppState};
use crate::gateway::Channel;
use crate::gateway::GatewayError;
use crate::gateway::civil_from_days;
use crate::gateway::{self, EventKind, StoredEvent};

/// Entries without `limit`.
pub const DEFAULT_LIMIT: usize = 100;
/// The most one answer holds.
pub const MAX_LIMIT: usize = 1000;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(events))
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct EventsQuery {
    /// `audit`, `emcy` or `nmt`; every kind when left out.
    #[param(example = "audit")]
    kind: Option<String>,
    /// Only audit entries of this channel: `rest`, `websocket`,
    /// `cia309_3`, `cia309_5`, `sparkplug`, `opcua` or `system` (the
    /// gateway's own). No EMCY or NMT entry has a channel.
    #[param(example = "rest")]
    channel: Option<String>,
    /// Entries at or after this time: RFC 3339 (`2026-11-23T18:00:00Z`,
    /// `2026-11-23T19:00:00.5+01:00`) or Unix milliseconds. Without it,
    /// the newest entries.
    #[param(example = "2026-11-23T18:00:00Z")]
    since: Option<String>,
    /// Entries at or before this time, in the same forms as `since`.
    /// Without `since`, the newest entries up to it: a client pages back
    /// by asking up to the oldest `time` it has (dropping the entries it
    /// has, by `kind` and `id`).
    #[param(example = "2026-11-23T19:00:00.123456Z")]
    until: Option<String>,
    /// How many entries: 1 to 1000, default 100.
    #[param(minimum = 1, maximum = 1000, example = 100)]
    limit: Option<usize>,
}

/// One entry of the history. `kind`, `id`, `time` and `time_us` are always
/// there; the other fields belong to one kind and are left out when empty.
#[derive(Debug, Clone, Default, PartialEq, Serialize, ToSchema)]
pub struct HistoryEvent {
    #[schema(value_type = String, example = "audit")]
    pub kind: String,
    /// Increasing within a kind.
    pub id: i64,
    /// UTC, RFC 3339 with microseconds.
    #[schema(example = "2026-11-23T18:00:00.123456Z")]
    pub time: String,
    /// Microseconds since the Unix epoch.
    pub time_us: i64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bus: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub node: Option<i64>,
    /// audit: the door the operation came through: `rest`, `websocket`,
    /// `cia309_3`, `cia309_5`, `sparkplug`, `opcua`, or `system` (the
    /// gateway's own: a lapsed lease's stop, the network manager, the
    /// recordings' pruning).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(example = "rest")]
    pub channel: Option<String>,
    /// audit: the token's name, `anonymous`, `mqtt:{user}`, `ascii:{peer}`,
    /// or `gateway`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub who: Option<String>,
    /// audit: the client's address.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub peer: Option<String>,
    /// audit: the caller's role (`viewer`, `operator`, `admin`), `none`
    /// without one, `system` for the gateway.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub role: Option<String>,
    /// audit: the door's own words for the request, where it has them:
    /// the HTTP method (REST, CiA 309-5), `ASCII` (CiA 309-3), the
    /// Sparkplug message type (`DCMD`). Left out for the gateway's own
    /// entries and the stream's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub method: Option<String>,
    /// audit: the HTTP path, the CiA 309-3 command line or the Sparkplug
    /// topic, with `method`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub path: Option<String>,
    /// audit: what the request does, in words (`write object`, `move`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub operation: Option<String>,
    /// audit: the axis acted on; emcy: the axis the EMCY belongs to,
    /// where the product says (the UMC: its first manufacturer byte).
    /// Left out for the whole node.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub axis: Option<i64>,
    /// audit: the object (`0x6040:0`, as the path gave it), PDO (`tpdo 1`)
    /// or segment (`segment 2`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub item: Option<String>,
    /// audit: the body, summarised (at most 1 KiB of JSON, secrets masked).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub request: Option<String>,
    /// audit: the HTTP status REST answered (REST entries only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub status: Option<i64>,
    /// audit: `ok`, or the error's `code` (as a REST error body names it:
    /// `sdo_abort`, `forbidden`, `rate_limited`; the network manager's
    /// `boot_failed`, `node_lost`).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(example = "ok")]
    pub outcome: Option<String>,
    /// audit: the error's `code` when the operation failed (the
    /// `outcome` of a failure).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error_code: Option<String>,
    /// audit: the SDO abort code when the device refused.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(example = "0x06090030")]
    pub abort_code: Option<String>,
    /// emcy: the error code, hex.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(example = "0x4310")]
    pub code: Option<String>,
    /// emcy: the code's text.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub text: Option<String>,
    /// emcy: the error register (0x1001).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub register: Option<i64>,
    /// emcy: the 5 manufacturer bytes, hex.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub manufacturer: Option<String>,
    /// nmt: `appeared`, `identified`, `identification_failed`,
    /// `nmt_changed`, `offline`, `online`, `heartbeat_written` (its 0x1017
    /// written through the gateway, the time in `reason`), `watchdog_off`
    /// (an admin's write switched off its protection against the
    /// gateway's death, the warning in `reason`), `motion_stopped` (the
    /// network manager stopped an enabled axis before writing the node's
    /// configuration, the axis and the lease it ended in `reason`), or
    /// `lost` (events the history missed, counted in `reason`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub event: Option<String>,
    /// nmt: the state before an `nmt_changed`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub from: Option<String>,
    /// nmt: the state after an `nmt_changed`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub to: Option<String>,
    /// nmt: why (`heartbeat_lost`, the profile identified, the error, the
    /// heartbeat time written).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

impl From<StoredEvent> for HistoryEvent {
    fn from(stored: StoredEvent) -> Self {
        let text = |name: &str| {
            stored
                .fields
                .get(name)
                .and_then(Json::as_str)
                .map(str::to_string)
        };
        let int = |name: &str| stored.fields.get(name).and_then(Json::as_i64);
        let outcome = text("outcome");
        let kind = match stored.kind {
            EventKind::Audit => "audit",
            EventKind::Emcy => "emcy",
            EventKind::Nmt => "nmt",
        };
        Self {
            kind: kind.to_string(),
            id: stored.id,
            time: rfc3339(stored.time_us),
            time_us: stored.time_us,
            bus: text("bus"),
            node: int("node"),
            channel: text("channel"),
            who: text("who"),
            peer: text("peer"),
            role: text("role"),
            method: text("method"),
            path: text("path"),
            operation: text("operation"),
            axis: int("axis"),
            item: text("item"),
            request: text("request"),
            status: int("status"),
            outcome: outcome.clone(),
            error_code: outcome.filter(|outcome| outcome != gateway::OK),
            abort_code: text("abort_code"),
            code: int("code").map(|code| format!("0x{code:04X}")),
            text: text("text"),
            register: int("register"),
            manufacturer: text("manufacturer"),
            event: text("event"),
            from: text("from_state"),
            to: text("to_state"),
            reason: text("reason"),
        }
    }
}

/// The persisted history: audit log, EMCYs, NMT and supervision events.
///
/// Oldest first. With `since`, the first `limit` entries at or after it
/// (page on by asking from the last `time_us` again, dropping entries
/// already seen by `kind` and `id`); without it, the newest `limit`. The
/// audit log has every operation that changed or tried to change a device
/// or the gateway, whichever door it came through (its `channel`; over
/// REST: `POST`, `PUT`, `PATCH`, `DELETE` under `/api/v1` except
/// `.../od/read`), refused ones included, and the gateway's own.
#[utoipa::path(get, path = "/events", tag = "events", params(EventsQuery),
    responses(
        (status = 200, description = "The entries, oldest first", body = [HistoryEvent]),
        (status = 400, description = "`invalid_request`: `kind`, `channel`, `since`, `until` or `limit` unreadable or out of range", body = ErrorBody),
        (status = 500, description = "`history_failed`: the history database failed", body = ErrorBody),
    ))]
async fn events(
    State(state): State<AppState>,
    query: Result<Query<EventsQuery>, QueryRejection>,
) -> Result<ApiJson<Vec<HistoryEvent>>, AppError> {
    let Query(query) = query.map_err(|err| AppError::InvalidRequest(err.body_text()))?;
    let found = state
        .gateway
        .history()
        .query(gateway::Query::try_from(query)?)
        .await
        .map_err(|err| {
            tracing::error!("events: {err}");
            GatewayError::HistoryFailed("the history database failed; see the gateway's log".into())
        })?;
    Ok(ApiJson(found.into_iter().map(HistoryEvent::from).collect()))
}

impl TryFrom<EventsQuery> for gateway::Query {
    type Error = AppError;

    fn try_from(query: EventsQuery) -> Result<Self, AppError> {
        let kind = match query.kind.as_deref() {
            None | Some("") => None,
            Some("audit") => Some(EventKind::Audit),
            Some("emcy") => Some(EventKind::Emcy),
            Some("nmt") => Some(EventKind::Nmt),
            Some(other) => {
                return Err(AppError::InvalidRequest(format!(
                    "kind '{other}': one of audit, emcy, nmt"
                )));
            }
        };
        let channel = match query.channel.as_deref() {
            None | Some("") => None,
            Some(name) => Some(Channel::from_name(name).ok_or_else(|| {
                let names: Vec<&str> = Channel::ALL.iter().map(|c| c.name()).collect();
                AppError::InvalidRequest(format!("channel '{name}': one of {}", names.join(", ")))
            })?),
        };
        let since_us = query.since.as_deref().map(parse_since).transpose()?;
        let until_us = query
            .until
            .as_deref()
            .map(|text| parse_time("until", text))
            .transpose()?;
        let limit = query.limit.unwrap_or(DEFAULT_LIMIT);
        if !(1..=MAX_LIMIT).contains(&limit) {
            return Err(AppError::InvalidRequest(format!(
                "limit {limit}: from 1 to {MAX_LIMIT}"
            )));
        }
        Ok(gateway::Query {
            kind,
            since_us,
            until_us,
            channel,
            limit,
        })
    }
}

/// `since` as µs since the Unix epoch: Unix milliseconds, or RFC 3339.
pub fn parse_since(text: &str) -> Result<i64, AppError> {
    parse_time("since", text)
}

/// The time parameter `name` as µs since the Unix epoch: Unix
/// milliseconds, or RFC 3339.
fn parse_time(name: &str, text: &str) -> Result<i64, AppError> {
    let text = text.trim();
    let invalid = || {
        AppError::InvalidRequest(format!(
            "{name} '{text}': an RFC 3339 time (2026-11-23T18:00:00Z) or Unix milliseconds"
        ))
    };
    if !text.is_empty() && text.bytes().all(|b| b.is_ascii_digit()) {
        let ms: i64 = text.parse().map_err(|_| invalid())?;
        return ms.checked_mul(1000).ok_or_else(invalid);
    }
    parse_rfc3339(text).ok_or_else(invalid)
}

/// `YYYY-MM-DDTHH:MM:SS[.fraction](Z|±HH:MM)` (`t`, `z` and a space for
/// `T` too, as RFC 3339 §5.6 allows) as µs since the Unix epoch.
fn parse_rfc3339(text: &str) -> Option<i64> {
    let bytes = text.as_bytes();
    let number = |from: usize, len: usize| -> Option<i64> {
        let digits = text.get(from..from + len)?;
        digits
            .bytes()
            .all(|b| b.is_ascii_digit())
            .then(|| digits.parse().ok())?
    };
    if bytes.len() < 20
        || bytes[4] != b'-'
        || bytes[7] != b'-'
        || !matches!(bytes[10], b'T' | b't' | b' ')
        || bytes[13] != b':'
        || bytes[16] != b':'
    {
        return None;
    }
    let (year, month, day) = (number(0, 4)?, number(5, 2)?, number(8, 2)?);
    let (hour, minute, second) = (number(11, 2)?, number(14, 2)?, number(17, 2)?);
    let days_in_month = match month {
        1 | 3 | 5 | 7 | 8 | 10 | 12 => 31,
        4 | 6 | 9 | 11 => 30,
        2 if year % 4 == 0 && (year % 100 != 0 || year % 400 == 0) => 29,
        2 => 28,
        _ => return None,
    };
    // 60: a leap second, counted as the next second's start.
    if day < 1 || day > days_in_month || hour > 23 || minute > 59 || second > 60 {
        return None;
    }
    let mut at = 19;
    let mut micros = 0i64;
    if bytes[at] == b'.' {
        at += 1;
        let start = at;
        while at < bytes.len() && bytes[at].is_ascii_digit() {
            if at - start < 6 {
                micros = micros * 10 + i64::from(bytes[at] - b'0');
            }
            at += 1;
        }
        if at == start {
            return None;
        }
        for _ in (at - start)..6 {
            micros *= 10;
        }
    }
    let offset_minutes = match &text[at..] {
        "Z" | "z" => 0,
        zone if zone.len() == 6 && zone.as_bytes()[3] == b':' => {
            let sign = match zone.as_bytes()[0] {
                b'+' => 1,
                b'-' => -1,
                _ => return None,
            };
            let (hours, minutes) = (number(at + 1, 2)?, number(at + 4, 2)?);
            if hours > 23 || minutes > 59 {
                return None;
            }
            sign * (hours * 60 + minutes)
        }
        _ => return None,
    };
    let days = days_from_civil(year, month, day);
    let seconds = days * 86_400 + hour * 3600 + minute * 60 + second - offset_minutes * 60;
    Some(seconds * 1_000_000 + micros)
}

/// Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant,
/// "chrono-Compatible Low-Level Date Algorithms"), the inverse of
/// [`civil_from_days`].
fn days_from_civil(year: i64, month: i64, day: i64) -> i64 {
    let year = if month <= 2 { year - 1 } else { year };
    let era = year.div_euclid(400);
    let yoe = year.rem_euclid(400);
    let mp = (month + 9) % 12;
    let doy = (153 * mp + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// µs since the Unix epoch as RFC 3339, UTC, with microseconds.
pub fn rfc3339(time_us: i64) -> String {
    let secs = time_us.div_euclid(1_000_000);
    let micros = time_us.rem_euclid(1_000_000);
    let (days, rest) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let (year, month, day) = civil_from_days(days);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}.{micros:06}Z",
        rest / 3600,
        rest % 3600 / 60,
        rest % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_read_and_write_both_ways() {
        assert_eq!(rfc3339(0), "1970-01-01T00:00:00.000000Z");
        let at = parse_since("2026-11-23T18:00:00.123456Z").unwrap();
        assert_eq!(rfc3339(at), "2026-11-23T18:00:00.123456Z");
        assert_eq!(
            parse_since("2026-11-23T19:00:00.5+01:00").unwrap(),
            at - 123_456 + 500_000
        );
        assert_eq!(
            parse_since("2024-02-29t00:00:00z").unwrap(),
            1_709_164_800_000_000
        );
        assert_eq!(parse_since("1709164800000").unwrap(), 1_709_164_800_000_000);
        for bad in [
            "",
            "yesterday",
            "2026-11-23",
            "2026-02-29T00:00:00Z",
            "2026-13-01T00:00:00Z",
            "2026-11-23T18:00:00",
            "2026-11-23T18:00:00.Z",
            "2026-11-23T18:00:00+1:00",
            "-5",
            "99999999999999999999",
        ] {
            let err = parse_since(bad).unwrap_err();
            assert_eq!(err.status(), axum::http::StatusCode::BAD_REQUEST, "{bad}");
        }
    }
}
