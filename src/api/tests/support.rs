//! What the router-level tests of every resource share: the demo bus, and
//! requests through the router without a socket.

use std::sync::Arc;

use axum::Router;
use axum::body::Body;
use axum::http::{HeaderMap, Method, Request, StatusCode};
use serde_json::Value as Json;
use tower::ServiceExt;

use super::{AppState, ServedBus, app};
use crate::gateway::EdsCatalog;
use crate::gateway::RegistryConfig;

/// `spec` opened as bus `name` with the built-in EDS catalog.
pub(crate) async fn open(name: &str, spec: &str) -> ServedBus {
    crate::emulator::open_bus(
        name,
        &spec.parse().unwrap(),
        Arc::new(EdsCatalog::builtin().unwrap()),
        RegistryConfig::default(),
        500_000,
    )
    .await
    .unwrap()
}

/// The demo bus with its three devices found by a scan, and its router.
/// Motion leases last the longest period the gateway grants, so that
/// tests of other things may watch a velocity move for a while unrenewed
/// (`tests_leases` sets its own).
pub(crate) async fn demo() -> (Router, AppState) {
    demo_at("virtual:demo").await
}

/// [`demo`] on the bus `spec` (`virtual:demo?bitrate=unlimited` for tests
/// of the software that send more than a wire carries).
pub(crate) async fn demo_at(spec: &str) -> (Router, AppState) {
    serve_scanned(open("demo", spec).await, 3).await
}

/// [`demo`] of a bus opened by the test (with devices of its own added):
/// a scan finds `devices` nodes, and the router serves it.
pub(crate) async fn serve_scanned(served: ServedBus, devices: usize) -> (Router, AppState) {
    let nodes = served.scan().await.unwrap();
    assert_eq!(nodes.len(), devices, "{nodes:?}");
    let state = AppState::new([served]).with_lease_period(crate::gateway::MAX_PERIOD);
    (app(state.clone()), state)
}

/// One request; the status, the body as text and its content type.
pub(crate) async fn raw_call(
    app: &Router,
    method: Method,
    uri: &str,
    content_type: &str,
    body: Option<String>,
) -> (StatusCode, String, Option<String>) {
    let mut request = Request::builder().method(method).uri(uri);
    if body.is_some() {
        request = request.header("content-type", content_type);
    }
    let request = request
        .body(body.map_or_else(Body::empty, Body::from))
        .unwrap();
    let response = app.clone().oneshot(request).await.unwrap();
    let status = response.status();
    let content_type = response
        .headers()
        .get("content-type")
        .map(|value| value.to_str().unwrap().to_string());
    let bytes = axum::body::to_bytes(response.into_body(), usize::MAX)
        .await
        .unwrap();
    (
        status,
        String::from_utf8(bytes.to_vec()).unwrap(),
        content_type,
    )
}

/// One request with a JSON body given as text; the answer's JSON (`null`
/// for an empty body, as a 204 has).
pub(crate) async fn call_text(
    app: &Router,
    method: Method,
    uri: &str,
    body: Option<&str>,
) -> (StatusCode, Json) {
    let (status, text, _) = raw_call(
        app,
        method,
        uri,
        "application/json",
        body.map(str::to_string),
    )
    .await;
    if text.is_empty() {
        return (status, Json::Null);
    }
    let json = serde_json::from_str(&text)
        .unwrap_or_else(|err| panic!("{uri}: body is no JSON ({err}): {text}"));
    (status, json)
}

/// [`call_text`] with a JSON value.
pub(crate) async fn call(
    app: &Router,
    method: Method,
    uri: &str,
    body: Option<Json>,
) -> (StatusCode, Json) {
    call_text(
        app,
        method,
        uri,
        body.map(|body| body.to_string()).as_deref(),
    )
    .await
}

pub(crate) async fn get(app: &Router, uri: &str) -> (StatusCode, Json) {
    call(app, Method::GET, uri, None).await
}

pub(crate) async fn put(app: &Router, uri: &str, body: Json) -> (StatusCode, Json) {
    call(app, Method::PUT, uri, Some(body)).await
}

pub(crate) async fn post(app: &Router, uri: &str, body: Json) -> (StatusCode, Json) {
    call(app, Method::POST, uri, Some(body)).await
}

/// POST a JSON body presenting a motion lease (`Candeck-Lease`).
pub(crate) async fn post_with_lease(
    app: &Router,
    uri: &str,
    lease: &str,
    body: Json,
) -> (StatusCode, Json) {
    let request = Request::builder()
        .method(Method::POST)
        .uri(uri)
        .header("content-type", "application/json")
        .header("candeck-lease", lease)
        .body(Body::from(body.to_string()))
        .unwrap();
    let response = app.clone().oneshot(request).await.unwrap();
    let status = response.status();
    let bytes = axum::body::to_bytes(response.into_body(), usize::MAX)
        .await
        .unwrap();
    (status, serde_json::from_slice(&bytes).unwrap())
}

pub(crate) async fn post_text(app: &Router, uri: &str, body: &str) -> (StatusCode, Json) {
    call_text(app, Method::POST, uri, Some(body)).await
}

pub(crate) async fn delete_text(app: &Router, uri: &str, body: Option<&str>) -> (StatusCode, Json) {
    call_text(app, Method::DELETE, uri, body).await
}

/// Asserts the API's error shape and code.
pub(crate) fn assert_error(response: &(StatusCode, Json), status: StatusCode, code: &str) {
    assert_eq!(response.0, status, "{}", response.1);
    assert_eq!(response.1["error"]["code"], code, "{}", response.1);
    assert!(
        response.1["error"]["message"]
            .as_str()
            .is_some_and(|m| !m.is_empty()),
        "{}",
        response.1
    );
}

/// One request through `app` with these headers (and a JSON content type
/// when there is a body); its status, headers and body as JSON (`null` when
/// empty or not JSON).
pub(crate) async fn send_with_headers(
    app: &Router,
    method: Method,
    path: &str,
    headers: &[(&str, &str)],
    body: Option<&str>,
) -> (StatusCode, HeaderMap, Json) {
    let mut request = Request::builder().method(method).uri(path);
    for (name, value) in headers {
        request = request.header(*name, *value);
    }
    if body.is_some() {
        request = request.header("content-type", "application/json");
    }
    let request = request
        .body(body.map_or_else(Body::empty, |b| Body::from(b.to_string())))
        .unwrap();
    let response = app.clone().oneshot(request).await.unwrap();
    let status = response.status();
    let headers = response.headers().clone();
    let bytes = axum::body::to_bytes(response.into_body(), usize::MAX)
        .await
        .unwrap();
    (
        status,
        headers,
        serde_json::from_slice(&bytes).unwrap_or(Json::Null),
    )
}
