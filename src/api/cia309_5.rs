//! CiA 309-5 (CANopen access over HTTP): the routes and JSON shape of the
//! open implementations (gocanopen's `pkg/gateway/http`), through the same
//! gateway as REST and CiA 309-3 ([`crate::cia309`]):
//!
//! ```text
//! GET  /cia309-5/1.0/{sequence}/{net}/{node}/r[ead]/{index}/{sub}
//! PUT  /cia309-5/1.0/{sequence}/{net}/{node}/w[rite]/{index}/{sub}   {"value": "1000", "datatype": "u16"}
//! POST /cia309-5/1.0/{sequence}/{net}/{node}/start | stop | preop[erational]
//! POST /cia309-5/1.0/{sequence}/{net}/{node}/reset/node | reset/comm[unication]
//! ```
//!
//! Every answer is HTTP 200 with `{"sequence": "<n>", "response": "OK"}`,
//! a read adding `"data": "0x<value, most significant byte first>"` and
//! `"length": <bytes>`, and a failure answering `"response":
//! "ERROR:<number>"` or `"ERROR:0x<abort code>"` (CiA 309-5 puts the
//! outcome in the body, as 309-3 does in its reply line). `net` is a number
//! (1 = the first bus) or `default`/`none` (net 1); `node` is 1–127, or
//! `all` (0) for NMT. These routes are outside `/api/v1` and its OpenAPI
//! document: their contract is CiA 309-5's.

use std::net::SocketAddr;

use axum::Router;
use axum::extract::{ConnectInfo, Path, State};
use axum::http::{Extensions, Uri};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use serde_json::{Value as Json, json};

use super::caller::AuditedByHandler;
use super::{AppError, AppState};
use crate::cia309::command::Nmt;
use crate::cia309::datatype::{Datatype, unsigned};
use crate::cia309::reply::ErrorCode;
use crate::cia309::{Cia309Gateway, Failure, Identity, Origin, TransferOptions};
use crate::gateway::GatewayError;
use crate::gateway::object_item;

/// The routes, at the root (not under `/api/v1`).
pub fn router() -> Router<AppState> {
    let base = "/cia309-5/1.0/{sequence}/{net}/{node}";
    let mut router = Router::new();
    for read in ["r", "read"] {
        router = router.route(
            &format!("{base}/{read}/{{index}}/{{sub}}"),
            get(read_object),
        );
    }
    for write in ["w", "write"] {
        router = router.route(
            &format!("{base}/{write}/{{index}}/{{sub}}"),
            axum::routing::put(write_object),
        );
    }
    for command in ["start", "stop", "preop", "preoperational"] {
        router = router.route(&format!("{base}/{command}"), post(nmt).put(nmt));
    }
    router.route(
        &format!("{base}/reset/{{what}}"),
        post(nmt_reset).put(nmt_reset),
    )
}

/// The body of an answer.
fn answer(sequence: &str, response: String) -> axum::Json<Json> {
    axum::Json(json!({ "sequence": sequence, "response": response }))
}

fn error(sequence: &str, failure: Failure) -> Response {
    let response = match failure {
        Failure::Abort(code) => format!("ERROR:0x{:08X}", code.raw()),
        Failure::Error(code) => format!("ERROR:{}", code.number()),
    };
    answer(sequence, response).into_response()
}

/// The answer to a request the gateway refused: in the body, as CiA 309-5
/// answers, except a refusal of the caller (no token, a role too low, over
/// its write rate), answered as REST answers it (401, 403, 429 with
/// `Retry-After`), as the guard does; the command's own audit entry
/// stands for it.
fn failed(sequence: &str, refused: GatewayError) -> Response {
    match refused {
        GatewayError::Unauthenticated(_)
        | GatewayError::Forbidden(_)
        | GatewayError::RateLimited { .. } => {
            let mut response = AppError::from(refused).into_response();
            response.extensions_mut().insert(AuditedByHandler);
            response
        }
        other => error(sequence, Failure::of(&other)),
    }
}

/// The request's sequence, net and node, or the error to answer with.
struct Target {
    sequence: String,
    net: u16,
    node: u8,
}

fn target(
    gateway: &Cia309Gateway,
    sequence: &str,
    net: &str,
    node: &str,
    min_node: u8,
) -> Result<Target, (String, Failure)> {
    // A sequence that is no number is answered as 0, as gocanopen does.
    let Ok(number) = unsigned(sequence, u32::MAX.into()) else {
        return Err(("0".into(), Failure::Error(ErrorCode::Syntax)));
    };
    let sequence = number.to_string();
    let fail = |code| Err((sequence.clone(), Failure::Error(code)));
    let net = match net.to_ascii_lowercase().as_str() {
        "default" | "none" => 1,
        "all" => return fail(ErrorCode::UnsupportedNet),
        text => match unsigned(text, 0xFFFF) {
            Ok(net) => net as u16,
            Err(_) => return fail(ErrorCode::Syntax),
        },
    };
    if net == 0 || net > gateway.networks() {
        return fail(ErrorCode::UnsupportedNet);
    }
    let node = match node.to_ascii_lowercase().as_str() {
        // Over HTTP there is no connection to keep a default node in.
        "default" | "none" => return fail(ErrorCode::NoDefaultNode),
        "all" if min_node == 0 => 0,
        "all" => return fail(ErrorCode::UnsupportedNode),
        text => match unsigned(text, 0xFFFF_FFFF) {
            Ok(node) if node >= u64::from(min_node) && node <= 127 => node as u8,
            Ok(_) => return fail(ErrorCode::UnsupportedNode),
            Err(_) => return fail(ErrorCode::Syntax),
        },
    };
    Ok(Target {
        sequence,
        net,
        node,
    })
}

/// Who sent the request, for the audit log: the token's name and role
/// when the gateway has tokens (the guard put them on the request), else
/// the client's address.
fn identity(extensions: &Extensions) -> Identity {
    let peer = extensions
        .get::<ConnectInfo<SocketAddr>>()
        .map(|ConnectInfo(addr)| addr.to_string());
    let mut identity = Identity::anonymous("http", peer);
    if let Some(token) = extensions.get::<crate::api::auth::Identity>()
        && let Some(role) = token.role
    {
        identity.who = token.name.clone();
        identity.role = role.name().to_string();
        identity.access = Some(role);
    }
    identity
}

fn object(index: &str, sub: &str) -> Option<(u16, u8)> {
    let index = unsigned(index, 0xFFFF).ok()? as u16;
    let sub = unsigned(sub, 0xFF).ok()? as u8;
    Some((index, sub))
}

/// The path of a read or write: sequence, net, node, index, sub.
type ObjectPath = (String, String, String, String, String);

/// The target and object of a read or write, or the sequence and error to
/// answer a path that names none with.
fn object_target(
    gateway: &Cia309Gateway,
    (sequence, net, node, index, sub): &ObjectPath,
) -> Result<(Target, u16, u8), (String, Failure)> {
    let target = target(gateway, sequence, net, node, 1)?;
    match object(index, sub) {
        Some((index, sub)) => Ok((target, index, sub)),
        None => Err((target.sequence, Failure::Error(ErrorCode::Syntax))),
    }
}

/// A write, parsed: its target and object, the request as the audit log
/// names it (`u16 1000`), and the bytes to write.
struct WriteRequest {
    target: Target,
    index: u16,
    sub: u8,
    summary: String,
    data: Vec<u8>,
}

impl WriteRequest {
    /// Writes through the gateway and answers as CiA 309-5 does.
    async fn run(self, gateway: &Cia309Gateway, origin: Origin<'_>) -> Response {
        let Self {
            target,
            index,
            sub,
            summary,
            data,
        } = self;
        let options = TransferOptions::default();
        let (net, node) = (target.net, target.node);
        match gateway
            .write(origin, net, node, index, sub, data, summary, options)
            .await
        {
            Ok(()) => answer(&target.sequence, "OK".into()).into_response(),
            Err(refused) => failed(&target.sequence, refused),
        }
    }
}

fn write_request(
    gateway: &Cia309Gateway,
    path: &ObjectPath,
    body: &[u8],
) -> Result<WriteRequest, (String, Failure)> {
    let (target, index, sub) = object_target(gateway, path)?;
    let (value, datatype, data) =
        write_value(body).map_err(|failure| (target.sequence.clone(), failure))?;
    Ok(WriteRequest {
        summary: format!("{} {value}", datatype.mnemonic()),
        target,
        index,
        sub,
        data,
    })
}

/// The answer to a read: the value most significant byte first.
fn data_answer(sequence: &str, bytes: &[u8]) -> Response {
    let data: String = bytes.iter().rev().map(|b| format!("{b:02x}")).collect();
    axum::Json(json!({
        "sequence": sequence,
        "response": "OK",
        "data": format!("0x{data}"),
        "length": bytes.len(),
    }))
    .into_response()
}

/// The value of a write's body (`{"value": "1000", "datatype": "u16"}`):
/// its text, its datatype and its bytes.
fn write_value(body: &[u8]) -> Result<(String, Datatype, Vec<u8>), Failure> {
    let syntax = Failure::Error(ErrorCode::Syntax);
    let Ok(Json::Object(request)) = serde_json::from_slice::<Json>(body) else {
        return Err(syntax);
    };
    // The value is a string in CiA 309-5; a JSON number is taken as well.
    let value = match request.get("value") {
        Some(Json::String(text)) => text.clone(),
        Some(Json::Number(number)) => number.to_string(),
        _ => return Err(syntax),
    };
    let datatype = request
        .get("datatype")
        .and_then(Json::as_str)
        .and_then(Datatype::from_mnemonic)
        .ok_or(Failure::Error(ErrorCode::RequestNotSupported))?;
    match datatype.encode(&value) {
        Ok(data) if !data.is_empty() => Ok((value, datatype, data)),
        _ => Err(syntax),
    }
}

async fn read_object(
    State(state): State<AppState>,
    Path(path): Path<ObjectPath>,
    uri: Uri,
    extensions: Extensions,
) -> Response {
    let gateway = Cia309Gateway::new(&state.gateway);
    let (target, index, sub) = match object_target(&gateway, &path) {
        Ok(found) => found,
        Err((sequence, failure)) => return error(&sequence, failure),
    };
    let identity = identity(&extensions);
    let origin = Origin {
        identity: &identity,
        method: "GET",
        path: uri.path(),
    };
    let options = TransferOptions::default();
    match gateway
        .read(origin, target.net, target.node, index, sub, options)
        .await
    {
        Ok(bytes) => data_answer(&target.sequence, &bytes),
        Err(refused) => failed(&target.sequence, refused),
    }
}

async fn write_object(
    State(state): State<AppState>,
    Path(path): Path<ObjectPath>,
    uri: Uri,
    extensions: Extensions,
    body: axum::body::Bytes,
) -> Response {
    let gateway = Cia309Gateway::new(&state.gateway);
    let request = match write_request(&gateway, &path, &body) {
        Ok(request) => request,
        Err((sequence, failure)) => return error(&sequence, failure),
    };
    let identity = identity(&extensions);
    let origin = Origin {
        identity: &identity,
        method: "PUT",
        path: uri.path(),
    };
    request.run(&gateway, origin).await
}

async fn nmt(
    State(state): State<AppState>,
    Path((sequence, net, node)): Path<(String, String, String)>,
    method: axum::http::Method,
    uri: Uri,
    extensions: Extensions,
) -> Response {
    let command = match uri.path().rsplit('/').next().unwrap_or_default() {
        "start" => Nmt::Start,
        "stop" => Nmt::Stop,
        _ => Nmt::PreOperational,
    };
    run_nmt(
        &state,
        &sequence,
        &net,
        &node,
        command,
        &method,
        &uri,
        &extensions,
    )
    .await
}

async fn nmt_reset(
    State(state): State<AppState>,
    Path((sequence, net, node, what)): Path<(String, String, String, String)>,
    method: axum::http::Method,
    uri: Uri,
    extensions: Extensions,
) -> Response {
    let command = match what.to_ascii_lowercase().as_str() {
        "node" => Nmt::ResetNode,
        "comm" | "communication" => Nmt::ResetCommunication,
        _ => {
            let sequence = unsigned(&sequence, u32::MAX.into())
                .unwrap_or(0)
                .to_string();
            return error(&sequence, Failure::Error(ErrorCode::RequestNotSupported));
        }
    };
    run_nmt(
        &state,
        &sequence,
        &net,
        &node,
        command,
        &method,
        &uri,
        &extensions,
    )
    .await
}

#[allow(clippy::too_many_arguments)]
async fn run_nmt(
    state: &AppState,
    sequence: &str,
    net: &str,
    node: &str,
    command: Nmt,
    method: &axum::http::Method,
    uri: &Uri,
    extensions: &Extensions,
) -> Response {
    let gateway = Cia309Gateway::new(&state.gateway);
    let target = match target(&gateway, sequence, net, node, 0) {
        Ok(target) => target,
        Err((sequence, failure)) => return error(&sequence, failure),
    };
    let identity = identity(extensions);
    let origin = Origin {
        identity: &identity,
        method: method.as_str(),
        path: uri.path(),
    };
    match gateway.nmt(origin, target.net, target.node, command).await {
        Ok(()) => answer(&target.sequence, "OK".into()).into_response(),
        Err(refused) => failed(&target.sequence, refused),
    }
}

/// What a CiA 309-5 command acts on, for the audit entry of one refused
/// before its handler (no token, a role too low): named as the handler's
/// own entries, and as the other doors name the same operation (`write
/// object` with its `0x1017:0`, `nmt command`), the bus found by its net.
pub fn audit_target(gateway: &crate::gateway::Gateway, path: &str) -> super::audit::Target {
    let mut target = super::audit::Target {
        operation: "unknown request".to_string(),
        ..Default::default()
    };
    let Some(rest) = path.strip_prefix("/cia309-5/1.0/") else {
        return target;
    };
    let segments: Vec<&str> = rest.split('/').collect();
    let [_sequence, net, node, command @ ..] = segments.as_slice() else {
        return target;
    };
    let net = match net.to_ascii_lowercase().as_str() {
        "default" | "none" => Some(1),
        text => unsigned(text, 0xFFFF).ok().map(|net| net as usize),
    };
    target.bus = net.and_then(|net| net.checked_sub(1)).and_then(|at| {
        gateway
            .buses_in_order()
            .get(at)
            .map(|bus| bus.name().to_string())
    });
    let all = node.eq_ignore_ascii_case("all") || *node == "0";
    if !all {
        target.node = unsigned(node, 127).ok().map(|node| node as u8);
    }
    let operation = match command {
        ["w" | "write", index, sub] => {
            target.item = object(index, sub).map(|(index, sub)| object_item(index, sub));
            "write object"
        }
        ["start" | "stop" | "preop" | "preoperational"] | ["reset", _] if all => {
            "nmt command to all nodes"
        }
        ["start" | "stop" | "preop" | "preoperational"] | ["reset", _] => "nmt command",
        _ => "unknown request",
    };
    target.operation = operation.to_string();
    target
}
