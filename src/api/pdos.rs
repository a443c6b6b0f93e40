//! A node's PDOs (CiA 301 §7.2.2) and the bus's SYNC producer (§7.2.5):
//! the configuration read over SDO, the re-mapping procedure, sending an
//! RPDO by its mapping, and `PUT`/`GET /buses/{bus}/sync`.
//!
//! A re-mapping request is checked against the node's EDS before the bus is
//! touched (400 `invalid_mapping`: an object the EDS does not describe or
//! does not let map in that direction, more than 64 bits, more entries than
//! the mapping record has; 400 `value_out_of_range`: a reserved transmission
//! type; 404 `unknown_pdo`: a PDO number the node does not have). When the
//! device refuses a step half way, the error names the step (`"step"`) next
//! to the device's abort; the PDO then stays invalid, as the procedure left
//! it.
//!
//! The protocol work is `crate::gateway::pdo`'s; every sequence of SDO
//! transfers runs in a task of its own, so that a client hanging up never
//! cuts the procedure between invalidation and validation.

use std::time::Duration;

use axum::extract::State;
use serde::{Deserialize, Serialize};
use serde_json::Value as Json;
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{BusPath, ErrorBody, NodePath};
use super::od::{AnyValue, dictionary, hex};
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::canopen::od::{ObjectDictionary, format_index};
use crate::canopen::pdo::{MappingEntry, PdoKind};
use crate::gateway::GatewayError;
use crate::gateway::PdoError;
use crate::gateway::SyncStatus;
use crate::gateway::{self, DecodedValue, EntryRequest, PdoConfig, PdoRequest};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_pdos))
        .routes(routes!(put_pdo))
        .routes(routes!(send_rpdo))
        .routes(routes!(get_sync, put_sync))
}

/// One mapped object of a PDO.
#[derive(Debug, Serialize, ToSchema)]
pub struct PdoMappingEntry {
    #[schema(example = "0x6041")]
    pub index: String,
    pub sub: u8,
    /// The length in bits.
    #[schema(example = 16)]
    pub bits: u8,
    /// The EDS name; null for a dummy entry or an object the EDS does not
    /// describe.
    #[schema(example = "a1_Statusword")]
    pub name: Option<String>,
}

/// One PDO's configuration, as read from the node. Parameters the node's
/// EDS does not describe are null.
#[derive(Debug, Serialize, ToSchema)]
pub struct Pdo {
    #[schema(example = 1)]
    pub number: u16,
    /// The identifier (COB-ID bits 0–28; bit 29 is set in the entry for a
    /// 29-bit identifier).
    #[schema(example = 0x181)]
    pub cob_id: u32,
    /// Valid (COB-ID bit 31 clear).
    pub enabled: bool,
    /// 0: synchronous acyclic, 1–240: every nth SYNC, 252/253: on remote
    /// request, 254/255: event-driven.
    #[schema(example = 1)]
    pub transmission_type: Option<u8>,
    #[schema(example = 0)]
    pub inhibit_time_100us: Option<u16>,
    #[schema(example = 0)]
    pub event_timer_ms: Option<u16>,
    /// TPDOs only.
    #[schema(example = 0)]
    pub sync_start: Option<u8>,
    pub mapping: Vec<PdoMappingEntry>,
}

/// The PDOs of a node.
#[derive(Debug, Serialize, ToSchema)]
pub struct PdoList {
    pub rpdo: Vec<Pdo>,
    pub tpdo: Vec<Pdo>,
}

fn mapping_json(entries: &[MappingEntry], dict: Option<&ObjectDictionary>) -> Vec<PdoMappingEntry> {
    entries
        .iter()
        .map(|entry| PdoMappingEntry {
            index: format_index(entry.index),
            sub: entry.sub,
            bits: entry.bits,
            name: dict.and_then(|dict| gateway::entry_name(dict, entry.index, entry.sub)),
        })
        .collect()
}

fn pdo_json(config: &PdoConfig, dict: Option<&ObjectDictionary>) -> Pdo {
    Pdo {
        number: config.number,
        cob_id: config.can_id(),
        enabled: config.enabled(),
        transmission_type: config.transmission_type,
        inhibit_time_100us: config.inhibit_time_100us,
        event_timer_ms: config.event_timer_ms,
        sync_start: config.sync_start,
        mapping: mapping_json(&config.mapping, dict),
    }
}

/// Which way a PDO goes, seen from the node: `tpdo` (it sends) or `rpdo`
/// (it receives).
#[derive(Debug, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
#[allow(dead_code)] // The schema of the path segment.
pub enum PdoKindParam {
    Tpdo,
    Rpdo,
}

/// A PDO named in a path.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Path)]
#[allow(dead_code)]
pub struct PdoPath {
    /// The bus name.
    #[param(example = "demo")]
    pub bus: String,
    /// The node id, 1 to 127.
    #[param(minimum = 1, maximum = 127, example = 1)]
    pub id: u8,
    #[param(inline)]
    pub kind: PdoKindParam,
    /// The PDO number, from 1.
    #[param(minimum = 1, maximum = 512, example = 1)]
    pub n: u16,
}

/// An RPDO named in a path.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Path)]
#[allow(dead_code)]
pub struct RpdoPath {
    /// The bus name.
    #[param(example = "demo")]
    pub bus: String,
    /// The node id, 1 to 127.
    #[param(minimum = 1, maximum = 127, example = 1)]
    pub id: u8,
    /// The RPDO number, from 1.
    #[param(minimum = 1, maximum = 512, example = 1)]
    pub n: u16,
}

fn pdo_kind(kind: &str) -> Result<PdoKind, GatewayError> {
    PdoKind::from_name(kind).ok_or_else(|| {
        GatewayError::Pdo(PdoError::UnknownPdo(format!(
            "'{kind}' is no kind of PDO: give tpdo or rpdo"
        )))
    })
}

fn pdo_number(kind: PdoKind, n: &str) -> Result<u16, GatewayError> {
    n.parse::<u16>()
        .ok()
        .filter(|n| (1..=PdoKind::MAX_NUMBER).contains(n))
        .ok_or_else(|| {
            GatewayError::Pdo(PdoError::UnknownPdo(format!(
                "{} '{n}': PDOs are numbered 1 to 512",
                kind.name().to_uppercase()
            )))
        })
}

/// Reads every PDO of the node over SDO.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}/pdos", tag = "pdo", params(NodePath),
    responses(
        (status = 200, description = "The RPDOs and TPDOs the node's EDS describes (1–4 of each without EDS), as configured now", body = PdoList),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: the device refused", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn list_pdos(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<ApiJson<PdoList>, AppError> {
    let node = state.gateway.node_handle(&bus, &id)?;
    let configs = node.read_pdos(&caller).await?;
    let dict = dictionary(node.info());
    let of = |kind| {
        configs
            .iter()
            .filter(|config| config.kind == kind)
            .map(|config| pdo_json(config, dict))
            .collect()
    };
    Ok(ApiJson(PdoList {
        rpdo: of(PdoKind::Rpdo),
        tpdo: of(PdoKind::Tpdo),
    }))
}

/// A mapping entry of a request: `index` (`"0x6041"`, `"6041h"`, a number
/// or the EDS name) or, instead, `name`; `sub` (number or EDS name, 0 when
/// absent); `bits` (the data type's length when absent).
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"index": "a1_Statusword"}))]
pub struct MappingEntryRequest {
    #[schema(value_type = Option<AnyValue>, example = "0x6041")]
    pub index: Option<Json>,
    #[schema(value_type = Option<AnyValue>, example = 0)]
    pub sub: Option<Json>,
    #[schema(example = 16)]
    pub bits: Option<u32>,
    /// The EDS name, used when `index` is absent (a PDO as `GET` returns it
    /// can be sent back).
    #[schema(example = "a1_Statusword")]
    pub name: Option<String>,
}

/// A PDO to configure; absent fields keep the node's value.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"transmission_type": 1, "mapping": [{"index": "a1_Statusword"}, {"index": "0x6064", "sub": 0}]}))]
pub struct PdoUpdate {
    /// If given, must be the number in the path.
    pub number: Option<u16>,
    /// The identifier (11 bits, or 29 bits with bit 29 set); without flags.
    #[schema(example = 0x181)]
    pub cob_id: Option<u32>,
    /// Valid after the procedure; `true` when absent.
    pub enabled: Option<bool>,
    pub transmission_type: Option<u8>,
    pub inhibit_time_100us: Option<u16>,
    pub event_timer_ms: Option<u16>,
    pub sync_start: Option<u8>,
    /// The new mapping; absent keeps the current one.
    pub mapping: Option<Vec<MappingEntryRequest>>,
}

fn entry_request(
    position: usize,
    entry: MappingEntryRequest,
) -> Result<EntryRequest, GatewayError> {
    let index = entry
        .index
        .or(entry.name.map(Json::String))
        .ok_or_else(|| {
            GatewayError::Pdo(PdoError::InvalidMapping(format!(
                "mapping entry {position}: give its \"index\" (or \"name\")"
            )))
        })?;
    Ok(EntryRequest {
        index,
        sub: entry.sub,
        bits: entry.bits,
    })
}

/// Configures a PDO by the CiA 301 re-mapping procedure.
///
/// Invalidates the PDO (COB-ID bit 31), clears the mapping count, writes the
/// entries, sets the count, writes the communication parameters, validates,
/// and returns the configuration read back. The request is checked against
/// the node's EDS before the bus is touched. When the device refuses a step,
/// the error names it in `step`.
#[utoipa::path(put, path = "/buses/{bus}/nodes/{id}/pdos/{kind}/{n}", tag = "pdo", params(PdoPath),
    request_body = PdoUpdate,
    responses(
        (status = 200, description = "The configuration read back", body = Pdo),
        (status = 400, description = "`invalid_mapping` (object not in the EDS or not mappable, more than 64 bits, too many entries), `value_out_of_range` (transmission type), `invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `unknown_pdo`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: the device refused a step (named in `step`)", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn put_pdo(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id, kind, n)): ApiPath<(String, String, String, String)>,
    ApiJson(update): ApiJson<PdoUpdate>,
) -> Result<ApiJson<Pdo>, AppError> {
    let node = state.gateway.node_handle(&bus, &id)?;
    let kind = pdo_kind(&kind)?;
    let number = pdo_number(kind, &n)?;
    let request = update.into_request(number)?;
    let config = node.configure_pdo(&caller, kind, number, &request).await?;
    Ok(ApiJson(pdo_json(&config, dictionary(node.info()))))
}

impl PdoUpdate {
    /// The request for PDO `number`, whose body names no other PDO.
    fn into_request(self, number: u16) -> Result<PdoRequest, AppError> {
        if let Some(given) = self.number.filter(|given| *given != number) {
            return Err(AppError::InvalidRequest(format!(
                "the body is for PDO {given}, the path for PDO {number}"
            )));
        }
        let mapping = self
            .mapping
            .map(|entries| {
                entries
                    .into_iter()
                    .enumerate()
                    .map(|(i, entry)| entry_request(i + 1, entry))
                    .collect::<Result<Vec<_>, _>>()
            })
            .transpose()?;
        Ok(PdoRequest {
            cob_id: self.cob_id,
            enabled: self.enabled,
            transmission_type: self.transmission_type,
            inhibit_time_100us: self.inhibit_time_100us,
            event_timer_ms: self.event_timer_ms,
            sync_start: self.sync_start,
            mapping,
        })
    }
}

/// Values to send, by the EDS name of each mapped object (or `"0x6040"`,
/// `"0x6040:0"`).
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"values": {"a1_Controlword": 15}}))]
pub struct RpdoSend {
    #[schema(value_type = Object)]
    pub values: serde_json::Map<String, Json>,
}

/// One value an RPDO carried.
#[derive(Debug, Serialize, ToSchema)]
pub struct PdoValue {
    #[schema(example = "0x6040")]
    pub index: String,
    pub sub: u8,
    #[schema(example = 16)]
    pub bits: u8,
    #[schema(example = "a1_Controlword")]
    pub name: Option<String>,
    #[schema(value_type = Option<AnyValue>, example = 15)]
    pub value: Json,
}

/// The RPDO frame sent.
#[derive(Debug, Serialize, ToSchema)]
pub struct RpdoSent {
    #[schema(example = 0x201)]
    pub cob_id: u32,
    /// The frame's data, hex.
    #[schema(example = "0f00")]
    pub data: String,
    pub values: Vec<PdoValue>,
}

fn value_json(value: DecodedValue) -> PdoValue {
    PdoValue {
        index: format_index(value.entry.index),
        sub: value.entry.sub,
        bits: value.entry.bits,
        name: value.name,
        value: value.value.map_or(Json::Null, |value| value.to_json()),
    }
}

/// Sends an RPDO with the given values.
///
/// The RPDO's current mapping and COB-ID are read from the node; every
/// mapped object must be given a value, typed and checked by the EDS. A
/// synchronous RPDO (transmission type 0–240) takes effect at the next SYNC.
/// A node whose heartbeat says it is not operational would ignore the frame:
/// 409.
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/pdos/rpdo/{n}/send", tag = "pdo", params(RpdoPath),
    request_body = RpdoSend,
    responses(
        (status = 200, description = "The frame sent", body = RpdoSent),
        (status = 400, description = "`invalid_value`, `value_out_of_range`, `invalid_mapping`, `invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `unknown_pdo`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state` (the node is not operational), `pdo_disabled`", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: reading the mapping was refused", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn send_rpdo(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id, n)): ApiPath<(String, String, String)>,
    ApiJson(request): ApiJson<RpdoSend>,
) -> Result<ApiJson<RpdoSent>, AppError> {
    let node = state.gateway.node_handle(&bus, &id)?;
    let number = pdo_number(PdoKind::Rpdo, &n)?;
    let sent = node.send_rpdo(&caller, number, &request.values).await?;
    Ok(ApiJson(RpdoSent {
        cob_id: sent.cob_id,
        data: hex(&sent.data),
        values: sent.values.into_iter().map(value_json).collect(),
    }))
}

/// The SYNC producer of a bus.
#[derive(Debug, Serialize, ToSchema)]
pub struct SyncState {
    /// The period; 0 = off.
    #[schema(example = 10)]
    pub period_ms: u32,
    /// The COB-ID SYNC goes on.
    #[schema(example = 0x80)]
    pub cob_id: u32,
    /// SYNC frames sent since the gateway started.
    #[schema(example = 1200)]
    pub sent: u64,
}

/// A SYNC period to set.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"period_ms": 10}))]
pub struct SyncSetting {
    /// The period in ms; 0 turns SYNC off.
    #[schema(maximum = 4294967)]
    pub period_ms: u32,
}

impl From<SyncStatus> for SyncState {
    fn from(status: SyncStatus) -> Self {
        Self {
            period_ms: status.period.as_millis() as u32,
            cob_id: status.cob_id.raw(),
            sent: status.sent,
        }
    }
}

/// The bus's SYNC producer.
#[utoipa::path(get, path = "/buses/{bus}/sync", tag = "pdo", params(BusPath),
    responses(
        (status = 200, description = "The SYNC period and count", body = SyncState),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn get_sync(
    State(state): State<AppState>,
    ApiPath(bus): ApiPath<String>,
) -> Result<ApiJson<SyncState>, AppError> {
    let served = state.bus(&bus)?;
    Ok(ApiJson(served.sync().status().into()))
}

/// Sets the period of the bus's SYNC producer (0 = off).
///
/// SYNC goes on COB-ID 0x080 without counter; the first one a period after
/// the request.
#[utoipa::path(put, path = "/buses/{bus}/sync", tag = "pdo", params(BusPath),
    request_body = SyncSetting,
    responses(
        (status = 200, description = "The SYNC producer's new setting", body = SyncState),
        (status = 400, description = "`invalid_request`, `value_out_of_range`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn put_sync(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
    ApiJson(setting): ApiJson<SyncSetting>,
) -> Result<ApiJson<SyncState>, AppError> {
    let period = Duration::from_millis(u64::from(setting.period_ms));
    let status = state.gateway.set_sync_period(&caller, &bus, period).await?;
    Ok(ApiJson(status.into()))
}
