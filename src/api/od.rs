//! A node's object dictionary over SDO (CiA 301 §7.2.4): the dictionary of
//! its EDS, reads, writes and batch reads.
//!
//! How a request names an entry (`docs/rest-api.md`, "Conventions"):
//! - an index as `0x6041`, `6041h`, a decimal number or the EDS name; a sub
//!   as a number or the EDS name;
//! - a name the EDS does not have is 404 (`unknown_object`,
//!   `unknown_sub_object`); so is a sub-index the EDS lacks in an object it
//!   describes (the EDS lists an object's sub-objects);
//! - a numeric index the EDS does not describe at all goes to the device as
//!   is (vendor objects an EDS forgot exist): a read returns `raw` only, a
//!   write needs `data_type`, and the device has the last word (an abort
//!   0x06020000 is 422 `sdo_abort`).
//!
//! A node matched to no EDS has no dictionary to list (404
//! `unknown_object`), and its objects are reached by number only.
//!
//! Values are checked against the EDS type and limits before the bus is
//! touched (400). SDO in the stopped state is refused with 409
//! `wrong_nmt_state` from the state the node last reported (CiA 301 §7.3.2.2:
//! a stopped node does not answer SDO, so asking would only end in a
//! timeout). A write to an object the EDS describes as read-only (`ro`,
//! `const`) is refused before the bus with the abort the device would give
//! (0x06010002, 422); the access of an object the EDS does not describe is
//! the device's to enforce.

use std::str::FromStr;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use serde::{Deserialize, Serialize};
use serde_json::{Value as Json, json};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::{AuditItem, RestCaller};
use super::doc::{ErrorBody, ErrorDetail, NodePath};
use super::nodes::known_node;
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::canopen::od::{DataType, ObjectDictionary, SubObject, Value, format_index, parse_index};
use crate::gateway::Caller;
use crate::gateway::GatewayError;
use crate::gateway::NodeHandle;
use crate::gateway::NodeInfo;
use crate::gateway::object_item;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_dictionary))
        .routes(routes!(read_one, write_one))
        .routes(routes!(read_batch))
}

/// An object of a node's dictionary, from its EDS.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)] // The schema of `Object::to_json`.
pub struct DictionaryObject {
    #[schema(example = "0x6041")]
    pub index: String,
    #[schema(example = "a1_Statusword")]
    pub name: String,
    /// `VAR`, `ARRAY`, `RECORD`, ...
    #[schema(example = "VAR")]
    pub object_type: String,
    pub subs: Vec<DictionarySub>,
}

/// A sub-object of a node's dictionary.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)]
pub struct DictionarySub {
    pub sub: u8,
    #[schema(example = "a1_Statusword")]
    pub name: String,
    /// `bool`, `i8`..`i64`, `u8`..`u64`, `r32`, `r64`, `vs`, `os`, `us`,
    /// `domain`, or `0xNNNN` for a type without a short name.
    #[schema(example = "u16")]
    pub data_type: String,
    /// `ro`, `wo`, `rw`, `rwr`, `rww` or `const`.
    #[schema(example = "ro")]
    pub access: String,
    pub pdo_mappable: bool,
    /// The EDS default, typed; null when the EDS gives none.
    #[schema(value_type = Option<AnyValue>)]
    pub default: Json,
    /// The EDS low limit.
    #[schema(value_type = Option<AnyValue>)]
    pub low: Json,
    /// The EDS high limit.
    #[schema(value_type = Option<AnyValue>)]
    pub high: Json,
}

/// A value of an object: a number, a string (64-bit integers, strings,
/// base64 octet strings), a boolean.
#[derive(Debug, Serialize, ToSchema)]
#[serde(untagged)]
#[schema(example = 567)]
#[allow(dead_code)]
pub enum AnyValue {
    Number(f64),
    Text(String),
    Flag(bool),
}

/// A value read from (or written to) a device.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)]
pub struct ObjectValue {
    #[schema(example = "0x6041")]
    pub index: String,
    pub sub: u8,
    /// The EDS name; null for an object the EDS does not describe.
    #[schema(example = "a1_Statusword")]
    pub name: Option<String>,
    /// The type the value is decoded with; null when unknown.
    #[schema(example = "u16")]
    pub data_type: Option<String>,
    /// The decoded value; null when the type is unknown.
    #[schema(value_type = Option<AnyValue>, example = 567)]
    pub value: Json,
    /// The bytes on the wire, hex.
    #[schema(example = "3702")]
    pub raw: String,
    /// When the bytes are no value of the EDS type: why.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub decode_error: Option<String>,
}

/// An object named in a path.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Path)]
#[allow(dead_code)]
pub struct ObjectPath {
    /// The bus name.
    #[param(example = "demo")]
    pub bus: String,
    /// The node id, 1 to 127.
    #[param(minimum = 1, maximum = 127, example = 1)]
    pub id: u8,
    /// `0x6041`, `6041h`, a decimal number, or the EDS name.
    #[param(example = "0x6041")]
    pub index: String,
    /// A number, or the sub-object's EDS name.
    #[param(example = "0")]
    pub sub: String,
}

/// One entry a request names.
struct Entry {
    index: u16,
    sub: u8,
    /// What the EDS says of it; `None` for an object the EDS does not know.
    described: Option<(String, SubObject)>,
    /// The type a write request gave for an object the EDS does not know.
    requested_type: Option<DataType>,
}

impl Entry {
    fn data_type(&self) -> Option<DataType> {
        self.described
            .as_ref()
            .map(|(_, sub)| sub.data_type)
            .or(self.requested_type)
    }

    /// The answer for a value read (or written) as `raw`.
    fn to_json(&self, raw: &[u8]) -> Json {
        let mut body = json!({
            "index": format_index(self.index),
            "sub": self.sub,
            "name": self.described.as_ref().map(|(name, _)| name),
            "data_type": self.data_type(),
            "value": Json::Null,
            "raw": hex(raw),
        });
        if let Some(data_type) = self.data_type() {
            match Value::from_bytes(data_type, raw) {
                Ok(value) => body["value"] = value.to_json(),
                // The device sent bytes that are no value of the EDS type:
                // the raw bytes say what it sent.
                Err(err) => body["decode_error"] = json!(err.to_string()),
            }
        }
        body
    }
}

pub(super) fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|byte| format!("{byte:02x}")).collect()
}

pub(super) fn dictionary(info: &NodeInfo) -> Option<&ObjectDictionary> {
    info.eds_entry.as_ref().map(|entry| &entry.eds.dictionary)
}

/// The object name of an entry, `"Identity object/Vendor-ID"` style for
/// sub-objects of records and arrays.
fn entry_name(object_name: &str, sub: &SubObject, has_subs: bool) -> String {
    if has_subs {
        format!("{object_name}/{}", sub.name)
    } else {
        object_name.to_string()
    }
}

/// Resolves a request's `index` and `sub` (strings from a path, or JSON
/// from a batch) against the node's dictionary.
fn resolve(dict: Option<&ObjectDictionary>, index: &Json, sub: &Json) -> Result<Entry, AppError> {
    let numeric_index = match index {
        Json::String(text) => parse_index(text),
        Json::Number(n) => Some(
            n.as_u64()
                .and_then(|n| u16::try_from(n).ok())
                .ok_or_else(|| GatewayError::InvalidIndex(format!("{n} is no object index")))?,
        ),
        other => {
            return Err(GatewayError::InvalidIndex(format!(
                "{other} is no object index: give 0x6041, 6041h, a decimal number or an EDS name"
            ))
            .into());
        }
    };
    let object = match (dict, numeric_index) {
        (Some(dict), Some(index)) => dict.get(index),
        (Some(dict), None) => Some(dict.resolve_index_json(index)?),
        (None, Some(_)) => None,
        (None, None) => {
            return Err(GatewayError::UnknownObject(format!(
                "the node has no EDS, so no object has a name: give {index} as a number"
            ))
            .into());
        }
    };
    match object {
        Some(object) => {
            let described = object.resolve_sub_json(sub)?;
            Ok(Entry {
                index: object.index,
                sub: described.sub_index,
                described: Some((
                    entry_name(
                        &object.name,
                        described,
                        object.object_type.has_sub_objects(),
                    ),
                    described.clone(),
                )),
                requested_type: None,
            })
        }
        None => Ok(Entry {
            index: numeric_index.unwrap_or_default(),
            sub: numeric_sub(sub)?,
            described: None,
            requested_type: None,
        }),
    }
}

/// A sub-index given as a number, for an object without EDS description.
fn numeric_sub(sub: &Json) -> Result<u8, GatewayError> {
    let number = match sub {
        Json::Number(n) => n.as_u64().and_then(|n| u8::try_from(n).ok()),
        Json::String(text) => {
            let text = text.trim();
            match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
                Some(hex) => u8::from_str_radix(hex, 16).ok(),
                None => text.parse().ok(),
            }
        }
        _ => None,
    };
    number.ok_or_else(|| {
        GatewayError::InvalidIndex(format!(
            "{sub} is no sub-index: give 0 to 255 (the EDS does not describe the object, so names are unknown)"
        ))
    })
}

/// Reads an entry, as the gateway's object read does it for `caller`.
async fn read_entry(node: &NodeHandle, caller: &Caller, entry: &Entry) -> Result<Json, AppError> {
    let raw = node.read_object(caller, entry.index, entry.sub).await?;
    Ok(entry.to_json(&raw))
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct DictionaryQuery {
    /// Words that an object's index, name or one of its sub-objects' names
    /// all contain, in any order and any case; spaces and underscores both
    /// separate words (`profile velocity` finds `a1_pc_Profile_velocity`),
    /// and an index is found with or without `0x` (`6081`, `0x6081`).
    q: Option<String>,
}

/// The words of a dictionary search: lowercase, split at spaces and
/// underscores.
fn search_words(q: &str) -> Vec<String> {
    q.split(|c: char| c.is_whitespace() || c == '_')
        .filter(|word| !word.is_empty())
        .map(str::to_lowercase)
        .collect()
}

/// Whether `text` contains every word (none: everything matches).
fn matches_words(words: &[String], text: &str) -> bool {
    let text = text.to_lowercase();
    words.iter().all(|word| text.contains(word.as_str()))
}

/// The node's dictionary, from its EDS.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}/od", tag = "od", params(NodePath, DictionaryQuery),
    responses(
        (status = 200, description = "The objects whose index or names contain `q`", body = [DictionaryObject]),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`; `unknown_object` when the node has no EDS", body = ErrorBody),
    ))]
async fn list_dictionary(
    State(state): State<AppState>,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    query: Result<Query<DictionaryQuery>, QueryRejection>,
) -> Result<ApiJson<Json>, AppError> {
    let Query(query) = query.map_err(|err| AppError::InvalidRequest(err.body_text()))?;
    let (_, info) = known_node(&state, &bus, &id)?;
    let dict = dictionary(&info).ok_or_else(|| {
        GatewayError::UnknownObject(format!(
            "node {} has no EDS: its dictionary is not known",
            info.id
        ))
    })?;
    let words = query.q.as_deref().map(search_words).unwrap_or_default();
    let matches = |text: &str| matches_words(&words, text);
    let objects = dict
        .iter()
        .filter(|object| {
            matches(&format_index(object.index))
                || matches(&object.name)
                || object.subs.values().any(|sub| matches(&sub.name))
        })
        .map(|object| object.to_json(Some(info.id)))
        .collect();
    Ok(ApiJson(Json::Array(objects)))
}

/// Reads one value over SDO.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}/od/{index}/{sub}", tag = "od", params(ObjectPath),
    responses(
        (status = 200, description = "The value read", body = ObjectValue),
        (status = 400, description = "`invalid_index`, `invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `unknown_object`, `unknown_sub_object`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: the device refused", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`: the device broke the SDO protocol", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn read_one(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id, index, sub)): ApiPath<(String, String, String, String)>,
) -> Result<ApiJson<Json>, AppError> {
    let node = state.gateway.node_handle(&bus, &id)?;
    let entry = resolve(
        dictionary(node.info()),
        &Json::String(index),
        &Json::String(sub),
    )?;
    Ok(ApiJson(read_entry(&node, &caller, &entry).await?))
}

/// A value to write.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct WriteRequest {
    /// Typed by the EDS: a number, a string (64-bit integers may be
    /// strings; `os` is base64), a boolean.
    #[schema(value_type = AnyValue, example = 1000)]
    pub value: Json,
    /// Needed for an object the EDS does not describe: `u8`, `i16`, `u32`,
    /// `r32`, `vs`, `os`, ...
    #[schema(example = "u32")]
    pub data_type: Option<String>,
}

/// The value of a write, checked against the EDS (type and limits), or
/// typed by the request for an object the EDS does not know.
fn value_to_write(
    entry: &Entry,
    info: &NodeInfo,
    request: &WriteRequest,
) -> Result<Value, GatewayError> {
    let given_type = request
        .data_type
        .as_deref()
        .map(|text| {
            DataType::from_str(text).map_err(|err| GatewayError::InvalidValue(err.to_string()))
        })
        .transpose()?;
    match (&entry.described, given_type) {
        (Some((name, sub)), given) => {
            if let Some(given) = given.filter(|given| *given != sub.data_type) {
                return Err(GatewayError::InvalidValue(format!(
                    "{name} is a {} in the EDS, not a {given}",
                    sub.data_type
                )));
            }
            Ok(sub.value_from_json(&request.value, Some(info.id))?)
        }
        (None, Some(data_type)) => Ok(Value::from_json(data_type, &request.value)?),
        (None, None) => Err(GatewayError::InvalidValue(format!(
            "the EDS does not describe {} sub {}: give its \"data_type\" (u8, i16, u32, r32, vs, os, ...)",
            format_index(entry.index),
            entry.sub
        ))),
    }
}

/// Writes one value over SDO and returns it read back.
#[utoipa::path(put, path = "/buses/{bus}/nodes/{id}/od/{index}/{sub}", tag = "od", params(ObjectPath),
    request_body = WriteRequest,
    responses(
        (status = 200, description = "The value read back (what was written, for a write-only object)", body = ObjectValue),
        (status = 400, description = "`invalid_value`, `value_out_of_range` (checked against the EDS before the bus), `invalid_index`, `invalid_request`", body = ErrorBody),
        (status = 403, description = "`forbidden`: not an operator; `watchdog_protected`: an operator's write that would switch the device's watchdog off (the 0x1016 entry watching the gateway, a drive's 0x6007 = 0, 0x1029 sub 1 = 1): only an admin may (docs/security.md, \"Watchdog policy\")", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `unknown_object`, `unknown_sub_object`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped; `lease_conflict`: the controlword (no stop), mode or target of an axis a lease holds (an OD write presents none: use the drive routes); `node_busy`: an axis's controlword, mode or target while a program download or a renumbering runs on the node; `motion_stopped`", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: the device refused", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`: the device broke the SDO protocol", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn write_one(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    item: Option<axum::Extension<AuditItem>>,
    ApiPath((bus, id, index, sub)): ApiPath<(String, String, String, String)>,
    ApiJson(request): ApiJson<WriteRequest>,
) -> Result<ApiJson<Json>, AppError> {
    let node = state.gateway.node_handle(&bus, &id)?;
    let mut entry = resolve(
        dictionary(node.info()),
        &Json::String(index),
        &Json::String(sub),
    )?;
    // The audit entry names the object as the other doors do.
    if let Some(axum::Extension(item)) = item {
        item.set(object_item(entry.index, entry.sub));
    }
    let value = value_to_write(&entry, node.info(), &request)?;
    let read_back = node
        .write_object_read_back(&caller, entry.index, entry.sub, value.to_bytes())
        .await?;
    // The request typed the value of an object the EDS does not know:
    // answer in its type. A write-only object cannot be read back: the
    // answer is what was written.
    entry.requested_type = Some(value.data_type());
    Ok(ApiJson(entry.to_json(&read_back)))
}

/// The most entries one batch read may carry: each is an SDO transfer on
/// the node's one channel, which other clients wait behind.
pub const MAX_BATCH_ENTRIES: usize = 256;

/// Entries to read, each `[index, sub]` (numbers or EDS names); at most
/// 256.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"entries": [["0x6041", 0], ["a1_Motor_status", "Current"]]}))]
pub struct BatchRequest {
    #[schema(value_type = Vec<Vec<AnyValue>>, max_items = 256)]
    pub entries: Vec<Json>,
}

/// One entry of a batch read: the value, or the error of that entry.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)]
pub struct BatchValue {
    /// The index as read (`"0x6041"`), or as given when it failed.
    #[schema(value_type = Option<AnyValue>)]
    pub index: Json,
    /// The sub-index, or as given when it failed.
    #[schema(value_type = Option<AnyValue>)]
    pub sub: Json,
    pub name: Option<String>,
    pub data_type: Option<String>,
    #[schema(value_type = Option<AnyValue>)]
    pub value: Option<Json>,
    pub raw: Option<String>,
    pub decode_error: Option<String>,
    /// Why this entry failed.
    pub error: Option<ErrorDetail>,
}

/// Reads several values, each with its own result.
///
/// The entries are read one after another (the node's SDO channel would
/// queue them anyway); each failure stays with its entry.
#[utoipa::path(post, path = "/buses/{bus}/nodes/{id}/od/read", tag = "od", params(NodePath),
    request_body = BatchRequest,
    responses(
        (status = 200, description = "One result per entry, in order; a failed entry carries `error`", body = [BatchValue]),
        (status = 400, description = "`invalid_request`; `too_many_entries` for more than 256 entries", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`", body = ErrorBody),
    ))]
async fn read_batch(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(request): ApiJson<BatchRequest>,
) -> Result<ApiJson<Json>, AppError> {
    if request.entries.len() > MAX_BATCH_ENTRIES {
        return Err(GatewayError::TooManyEntries(format!(
            "{} entries: a batch read takes at most {MAX_BATCH_ENTRIES} (send several)",
            request.entries.len()
        ))
        .into());
    }
    let node = state.gateway.node_handle(&bus, &id)?;
    let mut results = Vec::with_capacity(request.entries.len());
    for requested in &request.entries {
        results.push(read_batch_entry(&node, &caller, requested).await);
    }
    Ok(ApiJson(Json::Array(results)))
}

/// One entry of a batch read: its value, or its error with the index and
/// sub asked for.
async fn read_batch_entry(node: &NodeHandle, caller: &Caller, requested: &Json) -> Json {
    let pair = match requested {
        Json::Array(pair) if pair.len() == 2 => Some((&pair[0], &pair[1])),
        _ => None,
    };
    let result = match pair {
        None => Err(AppError::InvalidRequest(format!(
            "{requested} is not an [index, sub] pair"
        ))),
        Some((index, sub)) => match resolve(dictionary(node.info()), index, sub) {
            Ok(entry) => read_entry(node, caller, &entry).await,
            Err(err) => Err(err),
        },
    };
    result.unwrap_or_else(|err| {
        let (index, sub) = pair.map_or((Json::Null, Json::Null), |(i, s)| (i.clone(), s.clone()));
        json!({ "index": index, "sub": sub, "error": err.to_json() })
    })
}
