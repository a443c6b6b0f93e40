//! The audit layer: every request under `/api/v1` that changes, or tries to
//! change, a device or the gateway is written to the history before its
//! response leaves, once, with the method, path and status as REST's
//! detail and the JSON body summarised as its request.
//!
//! The gateway's operations write their own rows (`crate::gateway::audit`):
//! this layer hands each request a [`DoorRequest`] (its method, path and
//! summary), which the [`super::caller::RestCaller`] carries to the
//! operations; they hand their rows back, and this layer writes them with
//! the status answered. Only a request no operation audited gets a row of
//! this layer's own ([`AuditEntry::new`], outcome the error body's `code`,
//! `ok` for a 2xx): a refusal of REST's own (the guard's 401, 403, 413,
//! 429, a body that is no JSON, a path no route has) or a route not yet
//! backed by an audited operation.
//!
//! State-changing means a `POST`, `PUT`, `PATCH` or `DELETE` under
//! `/api/v1`, whatever its outcome: refused ones (400, 404, 405, 409, 413,
//! 422 with the abort code, 503, 504) are written as well as the ones that
//! succeed, and so are requests to paths no router has (someone tried). The
//! one exception is `POST .../od/read`, a batch of reads sent as a POST
//! because it has a body: it changes nothing. `POST .../scan` is recorded:
//! it adds nodes to the gateway and marks silent ones offline. `GET`,
//! `HEAD` and `OPTIONS` never are (the stream is a `GET`).
//!
//! Who made the request is what the access layer ([`super::auth`]) found:
//! the token's name and role, `anonymous`/`none` without one (or when the
//! gateway asks for none), `invalid-token`/`none` for a token it does not
//! know; requests it refused (401, 403, 413, 429) are written too, with the
//! token's name when the token was valid (a foreign origin or a body too
//! large is refused with the identity known).
//!
//! Lease ids (`lease`, `leases` in a body) are masked to their first 4
//! characters: the log is shown to viewers (`GET /events`), and a lease is
//! the right to move an axis.
//!
//! If the entry cannot be written (disk full), the request has happened
//! already: its response is sent unchanged, and the failure is logged as
//! an error.

use std::net::SocketAddr;

use axum::body::Body;
use axum::extract::{ConnectInfo, Request, State};
use axum::http::{Method, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use serde_json::Value as Json;

use super::AppState;
use super::auth::Identity;
use super::caller::{AuditItem, AuditedByHandler};
use super::error::ErrorSummary;
use crate::can::Timestamp;
use crate::gateway::{AuditEntry, OK};
use crate::gateway::{Caller, Channel};
use crate::gateway::{DoorDetail, DoorRequest};

/// The request body as the audit log keeps it, at most (bytes of JSON).
pub const MAX_SUMMARY: usize = 1024;
/// Keys whose values are never written to the log.
const SECRET_KEYS: &[&str] = &["token", "password", "secret", "authorization", "api_key"];
/// Keys whose values are lease ids: written masked (`3f2a…`).
const LEASE_KEYS: &[&str] = &["lease", "leases"];

/// Whether a request is one the audit log records.
pub fn is_state_changing(method: &Method, path: &str) -> bool {
    let changing = matches!(
        *method,
        Method::POST | Method::PUT | Method::PATCH | Method::DELETE
    );
    let api = path == "/api/v1" || path.starts_with("/api/v1/");
    let batch_read = *method == Method::POST && path.ends_with("/od/read");
    changing && api && !batch_read
}

/// A CiA 309-5 command (`/cia309-5/...`, not a GET): its handler writes
/// its own audit entry, as the CiA 309-3 gateway does, so the middleware
/// records only those refused before it (401, 403, 413, 429).
fn is_cia309_command(method: &Method, path: &str) -> bool {
    *method != Method::GET && *method != Method::HEAD && path.starts_with("/cia309-5/")
}

/// The middleware (`axum::middleware::from_fn_with_state`).
pub async fn record(State(state): State<AppState>, request: Request, next: Next) -> Response {
    let method = request.method().clone();
    let path = request.uri().path().to_string();
    let uri = request.uri().clone();
    let cia309 = is_cia309_command(&method, &path);
    if !is_state_changing(&method, &path) && !cia309 {
        return next.run(request).await;
    }
    let time = Timestamp::now();
    let peer = request
        .extensions()
        .get::<ConnectInfo<SocketAddr>>()
        .map(|ConnectInfo(addr)| addr.to_string());
    let (mut parts, body) = request.into_parts();
    let resolved = AuditItem::default();
    parts.extensions.insert(resolved.clone());
    let content_type = parts
        .headers
        .get(header::CONTENT_TYPE)
        .and_then(|value| value.to_str().ok())
        .unwrap_or("")
        .to_string();
    // The body is read here, once, so that the log can summarise it; the
    // handler gets the same bytes.
    // The route's limit (`body_limit`, `dcf_body_limit`): a larger body is
    // refused with 413, and audited.
    let limit = state.guard.config.body_limit(&method, &path);
    // A request the guard refuses for its credentials: its body is not
    // read (it may never come); the guard answers at once.
    let refused =
        super::auth::refused_for_credentials(&state.guard.config, &method, &path, &parts.headers);
    let read = if refused {
        Err(body)
    } else {
        Ok(axum::body::to_bytes(body, limit).await)
    };
    let (response, summary, door) = match read {
        Err(body) => (next.run(Request::from_parts(parts, body)).await, None, None),
        Ok(Ok(bytes)) => {
            let summary = summarise(&bytes, &content_type);
            // The request as REST knows it, for the rows of the operations
            // its handler calls: handed back here to add the status.
            let detail = DoorDetail::new(method.as_str(), path.clone()).summary(summary.clone());
            let door = DoorRequest::handed_over(detail);
            parts.extensions.insert(door.clone());
            let request = Request::from_parts(parts, Body::from(bytes));
            (next.run(request).await, summary, Some(door))
        }
        Ok(Err(_)) => {
            // Refused before the guard saw it: who sent it is found here,
            // so that a token's oversized request is logged as the token's.
            let (identity, _) = super::auth::identify(&state.guard.config, &method, &parts.headers);
            let mut response = super::auth::too_large(limit).into_response();
            response.extensions_mut().insert(identity);
            (response, Some(format!("more than {limit} bytes")), None)
        }
    };
    let status = response.status().as_u16();
    if let Some(door) = door.filter(DoorRequest::audited) {
        // The operations wrote their rows: REST adds the status answered.
        for entry in door.take_rows() {
            state.gateway.write_audit(entry.http_status(status)).await;
        }
        return response;
    }
    let refused_before_handler = matches!(status, 401 | 403 | 413 | 429)
        && response.extensions().get::<AuditedByHandler>().is_none();
    if cia309 && !refused_before_handler {
        return response;
    }
    let mut target = if cia309 {
        super::cia309_5::audit_target(&state.gateway, &path)
    } else {
        Target::of(&method, &path)
    };
    if target.operation == "upload eds" {
        target.item = upload_name(&uri);
    }
    if let Some(item) = resolved.take() {
        target.item = Some(item);
    }
    let error = response.extensions().get::<ErrorSummary>();
    // The guard names who it let in or turned away (a body refused for its
    // size here is named above).
    let identity = response.extensions().get::<Identity>();
    // A CiA 309-5 command refused here is 309-5's, not REST's.
    let channel = if cia309 {
        Channel::Cia309_5
    } else {
        Channel::Rest
    };
    let mut caller = Caller::new(
        channel,
        identity.map_or("anonymous", |id| id.name.as_str()),
        identity.and_then(|id| id.role),
    );
    caller.peer = peer;
    let (outcome, abort_code) = match error {
        _ if response.status().is_success() => (OK.to_string(), None),
        Some(error) => (error.code.clone(), error.abort_code.clone()),
        // Every error of the API carries its summary; anything else is
        // named by its status, as migrated rows without a code are.
        None => (format!("http_{status}"), None),
    };
    // What no operation audited: a refusal of the door's own (the guard's,
    // a body that is no JSON, a path no route has) or a route not yet
    // backed by an audited operation.
    let entry = AuditEntry::new(&caller, target.operation)
        .at(time)
        .target(target.bus, target.node, target.axis, target.item)
        .request(summary)
        .failed(outcome, abort_code)
        .detail(method.as_str(), path)
        .http_status(status);
    state.gateway.write_audit(entry).await;
    response
}

/// The body as the log keeps it: JSON compacted with secrets masked and
/// cut at [`MAX_SUMMARY`] bytes; anything else by its size and type.
pub fn summarise(bytes: &[u8], content_type: &str) -> Option<String> {
    if bytes.is_empty() {
        return None;
    }
    let Ok(mut json) = serde_json::from_slice::<Json>(bytes) else {
        let kind = if content_type.is_empty() {
            "no content type"
        } else {
            content_type
        };
        return Some(format!("{} bytes, not JSON ({kind})", bytes.len()));
    };
    mask(&mut json);
    let mut text = json.to_string();
    if text.len() > MAX_SUMMARY {
        let mut cut = MAX_SUMMARY;
        while !text.is_char_boundary(cut) {
            cut -= 1;
        }
        text.truncate(cut);
        text.push('…');
    }
    Some(text)
}

fn mask(json: &mut Json) {
    match json {
        Json::Object(map) => {
            for (key, value) in map.iter_mut() {
                let key = key.to_ascii_lowercase();
                if SECRET_KEYS.iter().any(|secret| key.contains(secret)) {
                    *value = Json::from("***");
                } else if LEASE_KEYS.contains(&key.as_str()) {
                    mask_leases(value);
                } else {
                    mask(value);
                }
            }
        }
        Json::Array(items) => items.iter_mut().for_each(mask),
        _ => {}
    }
}

/// The `name` of an EDS upload's query (`?name=my_file.eds`), decoded.
fn upload_name(uri: &axum::http::Uri) -> Option<String> {
    #[derive(serde::Deserialize)]
    struct Upload {
        name: Option<String>,
    }
    axum::extract::Query::<Upload>::try_from_uri(uri)
        .ok()?
        .0
        .name
}

/// Lease ids, wherever they are in `json`, masked.
fn mask_leases(json: &mut Json) {
    match json {
        Json::String(id) => *id = crate::gateway::mask(id),
        Json::Array(items) => items.iter_mut().for_each(mask_leases),
        Json::Object(map) => map.values_mut().for_each(mask_leases),
        _ => {}
    }
}

/// What a request acts on, from its path.
#[derive(Debug, Default, PartialEq, Eq)]
pub struct Target {
    pub operation: String,
    pub bus: Option<String>,
    pub node: Option<u8>,
    pub axis: Option<u8>,
    pub item: Option<String>,
}

impl Target {
    pub fn of(method: &Method, path: &str) -> Self {
        let tail = path.strip_prefix("/api/v1").unwrap_or(path);
        let segments: Vec<&str> = tail.split('/').filter(|s| !s.is_empty()).collect();
        let mut target = Self::default();
        let word = |text: &str| Some(text.to_string());
        let (operation, item): (&str, Option<String>) = match (method, segments.as_slice()) {
            (&Method::POST, ["stop-all"]) => ("stop all axes", None),
            // The file's name is in the query (`?name=`): see `record`.
            (&Method::POST, ["eds"]) => ("upload eds", None),
            (&Method::DELETE, ["eds", name]) => ("delete eds", word(name)),
            (&Method::POST, ["loggers"]) => ("start data logger", None),
            (&Method::DELETE, ["loggers", id]) => ("delete data logger", word(id)),
            (&Method::POST, ["alarms", "ack"]) => ("acknowledge alarms", None),
            (&Method::POST, ["alarms", id, "ack"]) => {
                ("acknowledge alarm", Some(format!("alarm {id}")))
            }
            (_, ["buses", bus, rest @ ..]) => {
                target.bus = word(bus);
                match (method, rest) {
                    (&Method::POST, ["scan"]) => ("scan", None),
                    (&Method::POST, ["nmt"]) => ("nmt command to all nodes", None),
                    (&Method::PUT, ["sync"]) => ("set sync period", None),
                    (&Method::POST, ["frames"]) => ("send frame", None),
                    (&Method::POST, ["machine", "reset-faults"]) => ("machine reset faults", None),
                    (&Method::POST, ["machine", "enable"]) => ("machine enable", None),
                    (&Method::POST, ["machine", "nodes", node, "boot"]) => {
                        target.node = node.parse().ok();
                        ("boot node again", None)
                    }
                    (&Method::POST, ["recording"]) => ("start recording", None),
                    (&Method::DELETE, ["recording"]) => ("stop recording", None),
                    (&Method::POST, ["lss", "scan"]) => ("lss scan", None),
                    (&Method::POST, ["lss", "configure"]) => ("lss configure", None),
                    (&Method::POST, ["sim", "nodes"]) => ("add virtual device", None),
                    (&Method::DELETE, ["sim", "nodes", node]) => {
                        target.node = node.parse().ok();
                        ("remove virtual device", None)
                    }
                    (_, ["sim", "faults"]) => match *method {
                        Method::POST => ("inject fault", None),
                        Method::DELETE => ("clear fault", None),
                        _ => ("unknown request", None),
                    },
                    (_, ["sim", "nodes", node, "faults"]) => {
                        target.node = node.parse().ok();
                        match *method {
                            Method::POST => ("inject fault", None),
                            Method::DELETE => ("clear fault", None),
                            _ => ("unknown request", None),
                        }
                    }
                    (_, ["nodes", node, rest @ ..]) => {
                        target.node = node.parse().ok();
                        node_operation(method, rest, &mut target)
                    }
                    _ => ("unknown request", None),
                }
            }
            _ => ("unknown request", None),
        };
        target.operation = operation.to_string();
        target.item = item;
        target
    }
}

fn node_operation(
    method: &Method,
    rest: &[&str],
    target: &mut Target,
) -> (&'static str, Option<String>) {
    match (method, rest) {
        (&Method::POST, ["nmt"]) => ("nmt command", None),
        (&Method::PUT, ["od", index, sub]) => ("write object", Some(format!("{index}:{sub}"))),
        (&Method::POST, ["store"]) => ("store parameters", None),
        (&Method::POST, ["restore"]) => ("restore parameters", None),
        (&Method::PUT, ["config.dcf"]) => ("restore configuration (DCF)", None),
        (&Method::POST, ["program"]) => ("download program", None),
        (&Method::PUT, ["pdos", kind, n]) => ("configure pdo", Some(format!("{kind} {n}"))),
        (&Method::POST, ["pdos", kind, n, "send"]) => ("send rpdo", Some(format!("{kind} {n}"))),
        (&Method::PUT, ["segments"]) => ("set scene", None),
        (&Method::PUT, ["segments", n]) => ("set segment", Some(format!("segment {n}"))),
        (&Method::PUT, ["eds"]) => ("assign eds", None),
        (&Method::DELETE, ["eds"]) => ("unassign eds", None),
        (&Method::PUT, ["io"]) => ("set outputs", None),
        (&Method::POST, ["node-id"]) => ("change node-id", None),
        (&Method::POST, ["axes", axis, action]) => {
            target.axis = axis.parse().ok();
            let operation = match *action {
                "state" => "drive state change",
                "fault-reset" => "fault reset",
                "halt" => "halt",
                "move" => "move",
                "step-test" => "step test",
                "lease" => "renew motion lease",
                _ => "unknown request",
            };
            (operation, None)
        }
        _ => ("unknown request", None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_are_not_state_changing_and_changes_are() {
        let path = "/api/v1/buses/demo/nodes/1/od/read";
        assert!(!is_state_changing(&Method::POST, path));
        assert!(!is_state_changing(&Method::GET, "/api/v1/buses"));
        assert!(!is_state_changing(&Method::POST, "/metrics"));
        assert!(is_state_changing(&Method::POST, "/api/v1/buses/demo/scan"));
        assert!(is_state_changing(&Method::DELETE, "/api/v1/nowhere"));
        // Only the batch read is a read.
        assert!(is_state_changing(&Method::PUT, path));
    }

    #[test]
    fn targets_come_from_the_path() {
        let target = Target::of(&Method::PUT, "/api/v1/buses/demo/nodes/1/od/0x6040/0");
        assert_eq!(
            target,
            Target {
                operation: "write object".into(),
                bus: Some("demo".into()),
                node: Some(1),
                axis: None,
                item: Some("0x6040:0".into()),
            }
        );
        let target = Target::of(&Method::POST, "/api/v1/buses/demo/nodes/2/axes/1/move");
        assert_eq!((target.operation.as_str(), target.axis), ("move", Some(1)));
        let target = Target::of(&Method::POST, "/api/v1/stop-all");
        assert_eq!(
            (target.operation.as_str(), target.bus),
            ("stop all axes", None)
        );
    }

    #[test]
    fn summaries_are_bounded_and_mask_secrets() {
        let body = br#"{"value":1,"auth":{"Token":"abc"},"password":"x"}"#;
        assert_eq!(
            summarise(body, "application/json").unwrap(),
            r#"{"auth":{"Token":"***"},"password":"***","value":1}"#
        );
        let long = format!("{{\"points\":[{}1]}}", "1234,".repeat(1000));
        let summary = summarise(long.as_bytes(), "application/json").unwrap();
        assert!(
            summary.len() <= MAX_SUMMARY + '…'.len_utf8(),
            "{}",
            summary.len()
        );
        assert!(summary.ends_with('…'));
        assert_eq!(
            summarise(b"[DeviceInfo]\n", "text/plain").unwrap(),
            "13 bytes, not JSON (text/plain)"
        );
        assert_eq!(summarise(b"", ""), None);
    }

    #[test]
    fn lease_ids_are_masked() {
        let body = br#"{"lease":"3f2a9c0e5b7d41e8a6c2f0d9b8e7a615"}"#;
        assert_eq!(
            summarise(body, "application/json").unwrap(),
            r#"{"lease":"3f2a…"}"#
        );
        let body = br#"{"op":"renew","leases":["3f2a9c0e5b7d41e8","feedfeedfeed"]}"#;
        assert_eq!(
            summarise(body, "application/json").unwrap(),
            r#"{"leases":["3f2a…","feed…"],"op":"renew"}"#
        );
    }
}
