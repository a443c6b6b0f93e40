//! `GET/PUT /buses/{bus}/nodes/{id}/io`: the channels of a CiA 401 generic
//! I/O module (profile `cia401`): inputs live (TPDO-fed where mapped,
//! read over SDO otherwise, each with its age), outputs set and read back
//! for confirmation. The operations are the gateway's
//! (`crate::gateway::io`); what the objects mean is
//! [`crate::profiles::cia401`].

use std::collections::BTreeMap;

use axum::extract::State;
use serde::Deserialize;
use serde_json::Value as Json;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{ErrorBody, NodePath};
use super::od::AnyValue;
use super::{ApiJson, ApiPath, AppError, AppState};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(read_io, write_io))
}

/// One channel's value.
#[derive(Debug, serde::Serialize, ToSchema)]
#[allow(dead_code)] // The schema of what ChannelValue serializes to.
pub struct IoChannel {
    #[schema(example = "di3")]
    pub channel: String,
    /// A boolean (digital) or an integer (analogue, INTEGER16).
    #[schema(value_type = AnyValue, example = true)]
    pub value: Json,
    /// ms since its TPDO came; 0 when read now over SDO.
    #[schema(example = 12)]
    pub age_ms: u64,
    /// `tpdo` or `sdo`.
    #[schema(example = "tpdo")]
    pub source: String,
}

/// Every channel of the module, by kind, from 1.
#[derive(Debug, serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct IoView {
    /// 0x6000, bit by bit.
    pub digital_inputs: Vec<IoChannel>,
    /// 0x6200, bit by bit.
    pub digital_outputs: Vec<IoChannel>,
    /// 0x6401.
    pub analog_inputs: Vec<IoChannel>,
    /// 0x6411.
    pub analog_outputs: Vec<IoChannel>,
}

/// Outputs to set.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct IoWrite {
    /// Channel name to value: `do1`–`doN` a boolean, `ao1`–`aoN` an
    /// INTEGER16.
    #[schema(value_type = Object, example = json!({"do3": true, "ao1": 1000}))]
    pub outputs: BTreeMap<String, Json>,
}

/// An output set.
#[derive(Debug, serde::Serialize, ToSchema)]
#[allow(dead_code)]
pub struct IoSet {
    #[schema(example = "do3")]
    pub channel: String,
    #[schema(value_type = AnyValue, example = true)]
    pub written: Json,
    /// Read from the device after the write.
    #[schema(value_type = AnyValue, example = true)]
    pub read_back: Json,
    /// Whether the device holds what was written.
    pub confirmed: bool,
}

/// The outputs set.
#[derive(Debug, serde::Serialize, ToSchema)]
pub struct IoWritten {
    #[schema(value_type = Vec<IoSet>)]
    pub outputs: Vec<crate::gateway::OutputSet>,
}

/// Every input and output of a CiA 401 module, with its value and age.
///
/// Inputs mapped in a TPDO are the newest the gateway decoded (`source`
/// `tpdo`, `age_ms` since it came); the others, and every output, are read
/// over SDO now (`sdo`, age 0). The channels are those of the node's EDS
/// (8 digital channels per sub-index of 0x6000/0x6200), else of the
/// highest sub-indices the device reports.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}/io", tag = "io", params(NodePath),
    responses(
        (status = 200, description = "Every channel", body = IoView),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_an_io_module` (the node's profile is not cia401)", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn read_io(
    State(state): State<AppState>,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<ApiJson<crate::gateway::IoState>, AppError> {
    Ok(ApiJson(state.gateway.read_io(&bus, &id).await?))
}

/// Sets outputs and reads each back for confirmation.
///
/// Every channel and value is checked before the first write (nothing is
/// written when one is wrong). A digital output is one bit of its 8-bit
/// group (0x6200): the group is read, the bit changed, the group written
/// and read again. `confirmed` says whether the device holds what was
/// written.
#[utoipa::path(put, path = "/buses/{bus}/nodes/{id}/io", tag = "io", params(NodePath),
    request_body = IoWrite,
    responses(
        (status = 200, description = "Each output written and read back", body = IoWritten),
        (status = 400, description = "`invalid_request` (no outputs), `invalid_value` (not a boolean or integer), `value_out_of_range` (beyond INTEGER16)", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_an_io_module`, `unknown_channel` (no such output: an input, or beyond the module's count)", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn write_io(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<IoWrite>,
) -> Result<ApiJson<IoWritten>, AppError> {
    let outputs = state
        .gateway
        .write_io(&caller, &bus, &id, request.outputs)
        .await?;
    Ok(ApiJson(IoWritten { outputs }))
}
