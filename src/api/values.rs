//! `GET /buses/{bus}/nodes/{id}/values`: the newest value of every object a
//! node sends in its TPDOs (CiA 301 §7.2.2), decoded by the mapping the
//! gateway read from the node (`crate::gateway::values`). No SDO: this is
//! what the bus carried.

use axum::extract::State;
use serde::Serialize;
use tokio::time::Instant;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::doc::{ErrorBody, NodePath};
use super::nodes::known_node;
use super::od::AnyValue;
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::canopen::od::format_index;
use crate::gateway::TpdoValue;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(node_values))
}

/// The node's TPDO values.
#[derive(Debug, Serialize, ToSchema)]
pub struct NodeValues {
    /// The TPDOs the gateway decodes, as read from the node; null until
    /// they have been read (shortly after the node is identified).
    pub tpdos: Option<Vec<DecodedTpdo>>,
    /// The newest value of each mapped object, by index and sub-index.
    pub values: Vec<DecodedValueJson>,
}

/// A TPDO the gateway decodes.
#[derive(Debug, Serialize, ToSchema)]
pub struct DecodedTpdo {
    #[schema(example = 1)]
    pub number: u16,
    /// Its COB-ID's identifier.
    #[schema(example = 0x181)]
    pub cob_id: u32,
    /// The objects it maps, in order (`"0x6041:0"`).
    #[schema(example = json!(["0x6041:0", "0x6064:0"]))]
    pub mapping: Vec<String>,
}

/// The newest value of one mapped object.
#[derive(Debug, Serialize, ToSchema)]
pub struct DecodedValueJson {
    #[schema(example = "0x6064")]
    pub index: String,
    pub sub: u8,
    /// The EDS name; null without EDS.
    #[schema(example = "a1_pc_Position_actual_value")]
    pub name: Option<String>,
    /// Typed by the EDS; null for an object the EDS does not describe.
    #[schema(value_type = Option<AnyValue>, example = 12000)]
    pub value: serde_json::Value,
    /// The field's bytes as sent, hex, little-endian.
    #[schema(example = "e02e0000")]
    pub raw: String,
    #[schema(example = 32)]
    pub bits: u8,
    /// The TPDO it came in.
    #[schema(example = 1)]
    pub pdo: u16,
    /// Milliseconds since its last frame.
    #[schema(example = 4)]
    pub age_ms: u64,
    /// Frames it came in since the mapping was read.
    #[schema(example = 120)]
    pub count: u64,
}

fn value_json(value: &TpdoValue, now: Instant) -> DecodedValueJson {
    DecodedValueJson {
        index: format_index(value.index),
        sub: value.sub,
        name: value.name.clone(),
        value: value.value_json(),
        raw: value.raw_hex(),
        bits: value.bits,
        pdo: value.pdo,
        age_ms: u64::try_from(now.saturating_duration_since(value.at).as_millis())
            .unwrap_or(u64::MAX),
        count: value.count,
    }
}

/// The newest value of every object the node sends in its TPDOs.
///
/// Decoded by the TPDO mappings the gateway read from the node when it was
/// identified and after each `PUT .../pdos/tpdo/{n}`; no SDO transfer.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}/values", tag = "pdo", params(NodePath),
    responses(
        (status = 200, description = "The values", body = NodeValues),
        (status = 400, description = "`invalid_request`: no node id", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`", body = ErrorBody),
    ))]
async fn node_values(
    State(state): State<AppState>,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<ApiJson<NodeValues>, AppError> {
    let (served, info) = known_node(&state, &bus, &id)?;
    let now = Instant::now();
    let tpdos = served.values().tpdos(info.id).map(|tpdos| {
        tpdos
            .decoders
            .iter()
            .map(|(number, decoder)| DecodedTpdo {
                number: *number,
                cob_id: decoder.cob_id().raw(),
                mapping: decoder
                    .mapping()
                    .entries()
                    .iter()
                    .map(|entry| format!("{}:{}", format_index(entry.index), entry.sub))
                    .collect(),
            })
            .collect()
    });
    let values = served
        .values()
        .values(info.id)
        .iter()
        .map(|value| value_json(value, now))
        .collect();
    Ok(ApiJson(NodeValues { tpdos, values }))
}
