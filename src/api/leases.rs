//! Motion leases over HTTP and the stream (the policy and its table are
//! `crate::gateway::motion_lease`): a velocity, torque or duty-cycle move
//! answers with a lease that its client renews with
//! `POST .../axes/{axis}/lease` `{"lease": id}` or the stream's
//! `{"op":"renew","leases":[id]}`; an interpolated move holds one while its
//! request feeds points. The leases and the supervisor that stops the
//! axis of every lease that lapses are `crate::gateway::leases`.
//!
//! A stream session that renewed a lease is its client's heartbeat: when
//! the socket closes the lease lapses at once.
//!
//! A lease is bound to its holder, the identity that took it (the token's
//! name; `anonymous` on a gateway without tokens, where the lease id alone
//! is the credential): renewing it, or presenting it in `Candeck-Lease`, as
//! anyone else is 409 `lease_conflict`. An operator or admin takes a held
//! axis over explicitly with `Candeck-Lease-Takeover: true` on a move,
//! `halt: false` or the target `operation_enabled`: the lease held ends
//! (its id is refused from then on) and the request's audit entry names
//! both holders. Lease ids are masked (`3f2a…`) in the audit log, events
//! and the gateway's log.

use std::time::Duration;

use axum::Extension;
use axum::extract::State;
use axum::http::HeaderMap;
use serde::{Deserialize, Serialize};
use tokio::time::Instant;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::auth::Identity;
use super::caller::RestCaller;
use super::doc::ErrorBody;
use super::drives::AxisPath;
use super::nodes::known_node;
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::gateway::GatewayError;
use crate::gateway::{AxisKey, LeaseError, MotionLease};

/// The request header that presents a lease to a command on a held axis.
pub const LEASE_HEADER: &str = "candeck-lease";
/// The request header (`true`) that takes a held axis over explicitly.
pub const TAKEOVER_HEADER: &str = "candeck-lease-takeover";

/// Whether the request asks for a take-over (`Candeck-Lease-Takeover`:
/// `true` or `false`; anything else is a mistake worth saying).
pub fn takeover_asked(headers: &HeaderMap) -> Result<bool, AppError> {
    let Some(value) = headers.get(TAKEOVER_HEADER) else {
        return Ok(false);
    };
    match value.to_str().map(str::trim) {
        Ok(text) if text.eq_ignore_ascii_case("true") => Ok(true),
        Ok(text) if text.eq_ignore_ascii_case("false") => Ok(false),
        _ => Err(AppError::InvalidRequest(
            "Candeck-Lease-Takeover is true or false".to_string(),
        )),
    }
}

/// Who a request acts for, as a lease records it: its token's name
/// (`anonymous` on a gateway without tokens).
pub fn holder(identity: Option<&Extension<Identity>>) -> String {
    identity.map_or_else(|| "anonymous".to_string(), |Extension(id)| id.name.clone())
}

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(renew))
}

/// A lease as a client sees it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, ToSchema)]
pub struct LeaseInfo {
    /// Present it to renew the lease, or in the `Candeck-Lease` header of a
    /// further command on the axis.
    #[schema(example = "3f2a9c0e5b7d41e8a6c2f0d9b8e7a615")]
    pub id: String,
    pub bus: String,
    pub node: u8,
    pub axis: u8,
    /// Who holds it (the token's name, or `anonymous`).
    pub holder: String,
    /// The move's mode.
    #[schema(example = "velocity")]
    pub mode: String,
    /// How long one renewal lasts (`--lease-ms`).
    #[schema(example = 3000)]
    pub period_ms: u64,
    /// Time left before the gateway halts the axis.
    #[schema(example = 3000)]
    pub expires_in_ms: u64,
}

impl LeaseInfo {
    pub fn of(lease: &MotionLease, now: Instant) -> Self {
        Self {
            id: lease.id.clone(),
            bus: lease.axis.bus.clone(),
            node: lease.axis.node,
            axis: lease.axis.axis,
            holder: lease.holder.clone(),
            mode: lease.mode.clone(),
            period_ms: millis(lease.period),
            expires_in_ms: millis(lease.remaining(now)),
        }
    }
}

fn millis(duration: Duration) -> u64 {
    u64::try_from(duration.as_millis()).unwrap_or(u64::MAX)
}

/// `{"lease": id}`.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct RenewRequest {
    pub lease: String,
}

impl From<LeaseError> for AppError {
    fn from(error: LeaseError) -> Self {
        GatewayError::from(error).into()
    }
}

/// The lease presented in a request's `Candeck-Lease` header.
pub fn presented(headers: &HeaderMap) -> Option<&str> {
    headers
        .get(LEASE_HEADER)
        .and_then(|value| value.to_str().ok())
        .map(str::trim)
}

/// Renews a motion lease for another period.
///
/// The holder of a velocity, torque or duty-cycle move calls this (or sends
/// `{"op":"renew","leases":[id]}` on the stream) more often than the
/// lease's `period_ms`; if the lease lapses, the gateway halts the axis,
/// and quick-stops it if it has not stopped one period later. Halting or
/// stopping the axis ends the lease. Only the lease's holder (the token
/// that took it) renews it: anyone else is refused with `lease_conflict`.
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/axes/{axis}/lease", tag = "drives", params(AxisPath),
    request_body = RenewRequest,
    responses(
        (status = 200, description = "The lease, renewed", body = LeaseInfo),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `unknown_lease`: it lapsed, was ended by a stop or a take-over, or is not this axis's", body = ErrorBody),
        (status = 409, description = "`lease_conflict`: the lease is held by another token", body = ErrorBody),
    ))]
async fn renew(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id, axis)): ApiPath<(String, String, String)>,
    ApiJson(request): ApiJson<RenewRequest>,
) -> Result<ApiJson<LeaseInfo>, AppError> {
    let (_, info) = known_node(&state, &bus, &id)?;
    let key = AxisKey {
        bus,
        node: info.id.get(),
        axis: axis
            .parse()
            .map_err(|_| AppError::InvalidRequest(format!("axis '{axis}' is not a number")))?,
    };
    let lease = state
        .gateway
        .renew_axis_lease(&caller, &key, &request.lease)
        .await?;
    Ok(ApiJson(LeaseInfo::of(&lease, Instant::now())))
}
