//! The machine of a bus as its network manager (CiA 302-2,
//! `crate::gateway::machine`) sees it: `GET /buses/{bus}/machine`, and
//! `POST /buses/{bus}/machine/nodes/{id}/boot` to run a node's boot-up
//! again.

use axum::extract::State;
use serde::Serialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{BusPath, ErrorBody, NodePath};
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::gateway::MachineView;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(machine))
        .routes(routes!(boot))
}

/// The state of the machine.
#[derive(Debug, Serialize, ToSchema)]
#[serde(rename_all = "snake_case")]
#[allow(dead_code)] // The schema of what MachineState serializes to.
pub enum MachineStateName {
    /// Every mandatory node booted, supervised and in the NMT state it
    /// should have.
    Ready,
    /// A mandatory node is on its way there (or the first scan runs).
    Booting,
    /// A mandatory node is missing, lost, of the wrong identity, or failed
    /// its boot-up.
    Degraded,
    /// No mandatory node is ready, or the bus is down.
    Down,
    /// The network manager would say `ready`, but a `critical` or `high`
    /// alarm is active (`reasons` names each: `GET /alarms`).
    Alarm,
}

/// One node of the machine.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)]
pub struct MachineNode {
    #[schema(example = 1, minimum = 1, maximum = 127)]
    pub id: u8,
    /// The `name` of its description.
    #[schema(example = "lift axes")]
    pub name: Option<String>,
    /// The machine is not ready without it.
    pub mandatory: bool,
    /// Described in `[[nodes]]` (false: found and booted with the defaults,
    /// or present but not described).
    pub expected: bool,
    /// `ready`, `booting`, `missing`, `wrong_identity`, `config_failed`,
    /// `offline` or `unexpected`.
    #[schema(example = "ready")]
    pub state: String,
    /// The boot-up step it is at, or failed at: `waiting`, `identity`,
    /// `configuration`, `error_control`, `start`, `supervised`.
    #[schema(example = "supervised")]
    pub step: String,
    /// Why it is not ready (the step and the failure, the identity that
    /// did not match, the supervision that lost it).
    pub reason: Option<String>,
    /// `heartbeat`, `guarding` or `none` (`reason` says why).
    #[schema(example = "heartbeat")]
    pub supervision: String,
    /// Its producer heartbeat time, ms: its description's, or the one last
    /// written to its 0x1017 through the gateway (followed until the
    /// gateway restarts); a heartbeat supervision times out after
    /// `heartbeat_consumer_factor` (default 3) × this. 0: no heartbeat.
    #[schema(example = 500)]
    pub heartbeat_ms: u16,
    /// The NMT state it last reported (`unknown` before any).
    #[schema(example = "operational")]
    pub nmt: String,
    /// The EDS its description names.
    pub eds: Option<String>,
    /// The DCF its configuration comes from.
    pub dcf: Option<String>,
    /// Boot-ups begun.
    pub boots: u64,
    /// Boot-ups that ended well.
    pub boots_ok: u64,
}

/// The machine of a bus.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)]
pub struct Machine {
    pub state: MachineStateName,
    /// Why it is not ready: one line per node, then one per active
    /// `critical` or `high` alarm (`alarm 7 (high): node 1 axis 2: ...`).
    pub reasons: Vec<String>,
    pub nodes: Vec<MachineNode>,
}

/// The machine: the expected nodes and the ones found, each one's state,
/// boot-up step, supervision and reason; never `ready` while a `critical`
/// or `high` alarm is active (`alarm`, with the alarms among the reasons).
#[utoipa::path(get, path = "/buses/{bus}/machine", tag = "machine", params(BusPath),
    responses(
        (status = 200, description = "The machine", body = Machine),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn machine(
    State(state): State<AppState>,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<MachineView>, AppError> {
    Ok(ApiJson(state.gateway.machine_view(&bus)?))
}

/// What a boot request started.
#[derive(Debug, Serialize, ToSchema)]
pub struct BootStarted {
    #[schema(example = 3)]
    pub node: u8,
    pub started: bool,
}

/// Runs a node's boot-up again: identity check, configuration download,
/// error control, NMT start; its progress shows in the machine.
#[utoipa::path(post, path = "/buses/{bus}/machine/nodes/{id}/boot", tag = "machine", params(NodePath),
    responses(
        (status = 200, description = "Started", body = BootStarted),
        (status = 400, description = "`invalid_request`: no node id, or a node neither described nor present", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn boot(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<ApiJson<BootStarted>, AppError> {
    let node = state.gateway.boot_node(&caller, &bus, &id).await?;
    Ok(ApiJson(BootStarted {
        node: node.get(),
        started: true,
    }))
}
