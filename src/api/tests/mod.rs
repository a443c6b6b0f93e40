//! The REST interface against the demo devices on `virtual:demo` (and one
//! test device from `tests/data/testnode.eds` for 64-bit values), called
//! through the router without a socket, on a paused clock.

mod alarms;
mod audit;
mod audit_and_limits;
mod auth;
mod drives;
mod edge;
mod eds;
mod io;
mod lease_holders;
mod leases;
mod leds;
mod loggers;
mod lss;
mod machine;
mod pdos;
mod program;
mod recording;
mod step_test;
mod stops;
mod stream;
pub(crate) mod support;
mod telemetry;

use crate::emulator::RackOf;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::http::{Method, Request, StatusCode};
use serde_json::{Value as Json, json};
use tower::ServiceExt;

use super::{AppState, ServedBus, app};
use crate::can::{BusState, BusStatus};
use crate::canopen::NodeId;
use crate::canopen::eds::Eds;
use crate::gateway::EdsCatalog;
use crate::gateway::RegistryConfig;
use crate::sim::device::DeviceCore;

const TESTNODE: u8 = 5;

/// The demo bus with its registry and every node identified; with
/// `testnode`, also the test device at node 5 and its EDS in the catalog.
async fn served(testnode: bool) -> ServedBus {
    let mut catalog = EdsCatalog::builtin().unwrap();
    if testnode {
        catalog
            .add_file(std::path::Path::new(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/tests/data/testnode.eds"
            )))
            .unwrap();
    }
    let served = crate::emulator::open_bus(
        "demo",
        &"virtual:demo".parse().unwrap(),
        Arc::new(catalog),
        RegistryConfig::default(),
        500_000,
    )
    .await
    .unwrap();
    if testnode {
        let text = include_str!("../../../tests/data/testnode.eds");
        let dictionary = Eds::parse(text, "testnode.eds").unwrap().dictionary;
        let device = DeviceCore::new(dictionary, NodeId::new(TESTNODE).unwrap()).unwrap();
        served.rack().unwrap().add_device(device).unwrap();
    }
    let nodes = served.scan().await.unwrap();
    assert_eq!(nodes.len(), if testnode { 4 } else { 3 }, "{nodes:?}");
    served
}

async fn demo() -> (Router, AppState) {
    let state = AppState::new([served(false).await]);
    (app(state.clone()), state)
}

async fn call(app: &Router, method: Method, uri: &str, body: Option<&str>) -> (StatusCode, Json) {
    let mut request = Request::builder().method(method).uri(uri);
    if body.is_some() {
        request = request.header("content-type", "application/json");
    }
    let request = request
        .body(body.map_or_else(Body::empty, |body| Body::from(body.to_string())))
        .unwrap();
    let response = app.clone().oneshot(request).await.unwrap();
    let status = response.status();
    let bytes = axum::body::to_bytes(response.into_body(), usize::MAX)
        .await
        .unwrap();
    let json = serde_json::from_slice(&bytes)
        .unwrap_or_else(|err| panic!("{uri}: body is no JSON ({err}): {bytes:?}"));
    (status, json)
}

async fn get(app: &Router, uri: &str) -> (StatusCode, Json) {
    call(app, Method::GET, uri, None).await
}

/// Asserts the API's error shape and code.
fn assert_error(response: &(StatusCode, Json), status: StatusCode, code: &str) {
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

fn tx_frames(state: &AppState) -> u64 {
    state.gateway.bus("demo").unwrap().counters().tx_frames
}

#[tokio::test(start_paused = true)]
async fn health_gives_status_and_version() {
    let (app, _) = demo().await;
    let (status, body) = get(&app, "/api/v1/health").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(
        body,
        json!({"status": "ok", "version": env!("CARGO_PKG_VERSION")})
    );
}

#[tokio::test(start_paused = true)]
async fn buses_list_counts_frames_and_measures_the_load() {
    let (app, _) = demo().await;
    // One full sampling window of heartbeats.
    tokio::time::sleep(Duration::from_millis(2100)).await;
    let (status, body) = get(&app, "/api/v1/buses").await;
    assert_eq!(status, StatusCode::OK);
    let bus = &body[0];
    assert_eq!(bus["name"], "demo");
    assert_eq!(bus["spec"], "virtual:demo");
    assert_eq!(bus["kind"], "virtual");
    assert_eq!(bus["state"], "up");
    assert_eq!(bus["reason"], Json::Null);
    assert_eq!(bus["reconnects"], 0);
    // The scan sent at least one probe per node id, and the nodes answered.
    assert!(bus["tx_frames"].as_u64().unwrap() >= 127, "{bus}");
    assert!(bus["rx_frames"].as_u64().unwrap() >= 3, "{bus}");
    let load = bus["load"].as_f64().unwrap();
    assert!(load > 0.0 && load < 1.0, "{bus}");
    let bits = bus["bits_per_second"].as_f64().unwrap();
    assert!((load - bits / 500_000.0).abs() < 1e-9, "{bus}");
}

#[tokio::test(start_paused = true)]
async fn nodes_list_and_one_node() {
    let (app, _) = demo().await;
    let (status, body) = get(&app, "/api/v1/buses/demo/nodes").await;
    assert_eq!(status, StatusCode::OK);
    let ids: Vec<_> = body
        .as_array()
        .unwrap()
        .iter()
        .map(|n| (n["id"].as_u64().unwrap(), n["profile"].as_str().unwrap()))
        .collect();
    assert_eq!(ids, [(1, "umc"), (2, "jmc_stepper"), (3, "uioled")]);
    assert_eq!(body[0]["identity"]["vendor_id"], 1186);
    assert_eq!(body[0]["eds"], "umc1bds32.eds");

    let (status, node) = get(&app, "/api/v1/buses/demo/nodes/2").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(node["id"], 2);
    assert!(node["emcy"].is_array(), "{node}");
    assert!(node["nmt"].is_string(), "{node}");
}

#[tokio::test(start_paused = true)]
async fn unknown_bus_and_node_are_404_and_bad_ids_400() {
    let (app, _) = demo().await;
    let response = get(&app, "/api/v1/buses/nope/nodes").await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_bus");
    let response = get(&app, "/api/v1/buses/nope/nodes/1/od/0x1000/0").await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_bus");
    let response = get(&app, "/api/v1/buses/demo/nodes/99").await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_node");
    let response = get(&app, "/api/v1/buses/demo/nodes/99/od/0x1000/0").await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_node");
    // A path segment that is no UTF-8 once decoded.
    let response = get(&app, "/api/v1/buses/%FF/nodes").await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
    for bad in ["0", "128", "abc"] {
        let response = get(&app, &format!("/api/v1/buses/demo/nodes/{bad}")).await;
        assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
    }
}

#[tokio::test(start_paused = true)]
async fn paths_outside_the_api_and_wrong_methods_have_the_error_shape() {
    let (app, _) = demo().await;
    let response = get(&app, "/api/v1/buses/demo/pdos").await;
    assert_error(&response, StatusCode::NOT_FOUND, "not_found");
    let response = get(&app, "/nodes").await;
    assert_error(&response, StatusCode::NOT_FOUND, "not_found");
    let response = call(&app, Method::DELETE, "/api/v1/health", None).await;
    assert_error(
        &response,
        StatusCode::METHOD_NOT_ALLOWED,
        "method_not_allowed",
    );
}

#[tokio::test(start_paused = true)]
async fn scan_returns_the_node_list() {
    let (app, _) = demo().await;
    let (status, body) = call(&app, Method::POST, "/api/v1/buses/demo/scan", None).await;
    assert_eq!(status, StatusCode::OK);
    let ids: Vec<_> = body
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n["id"].as_u64().unwrap())
        .collect();
    assert_eq!(ids, [1, 2, 3]);
    let response = call(&app, Method::POST, "/api/v1/buses/nope/scan", None).await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_bus");
}

async fn nmt_of(app: &Router, node: u8) -> String {
    let (_, body) = get(app, &format!("/api/v1/buses/demo/nodes/{node}")).await;
    body["nmt"].as_str().unwrap().to_string()
}

/// Node 2 (JMC) sends a heartbeat every second: its state shows in the
/// node list after the next one.
#[tokio::test(start_paused = true)]
async fn nmt_start_stop_and_sdo_to_a_stopped_node() {
    let (app, _) = demo().await;
    let nmt = "/api/v1/buses/demo/nodes/2/nmt";
    let (status, body) = call(&app, Method::POST, nmt, Some(r#"{"command":"start"}"#)).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["command"], "start");
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(nmt_of(&app, 2).await, "operational");

    // All nodes: stop. A stopped node does not serve SDO (CiA 301): 409.
    let (status, body) = call(
        &app,
        Method::POST,
        "/api/v1/buses/demo/nmt",
        Some(r#"{"command":"stop"}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(nmt_of(&app, 2).await, "stopped");
    let response = get(&app, "/api/v1/buses/demo/nodes/2/od/0x1000/0").await;
    assert_error(&response, StatusCode::CONFLICT, "wrong_nmt_state");
    assert_eq!(response.1["error"]["nmt"], "stopped");
    let response = call(
        &app,
        Method::PUT,
        "/api/v1/buses/demo/nodes/2/od/0x1017/0",
        Some(r#"{"value":500}"#),
    )
    .await;
    assert_error(&response, StatusCode::CONFLICT, "wrong_nmt_state");

    let (status, _) = call(
        &app,
        Method::POST,
        nmt,
        Some(r#"{"command":"pre_operational"}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(nmt_of(&app, 2).await, "pre_operational");
    let (status, _) = get(&app, "/api/v1/buses/demo/nodes/2/od/0x1000/0").await;
    assert_eq!(status, StatusCode::OK);
}

#[tokio::test(start_paused = true)]
async fn nmt_refuses_unknown_commands_and_nodes() {
    let (app, state) = demo().await;
    let before = tx_frames(&state);
    let nmt = "/api/v1/buses/demo/nodes/2/nmt";
    let response = call(&app, Method::POST, nmt, Some(r#"{"command":"jump"}"#)).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_value");
    let response = call(&app, Method::POST, nmt, Some(r#"{"cmd":"start"}"#)).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
    let response = call(
        &app,
        Method::POST,
        "/api/v1/buses/demo/nodes/42/nmt",
        Some(r#"{"command":"start"}"#),
    )
    .await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_node");
    assert_eq!(tx_frames(&state), before, "nothing was sent");
}

#[tokio::test(start_paused = true)]
async fn od_reads_by_every_spelling_of_an_index() {
    let (app, _) = demo().await;
    for index in ["0x6041", "6041h", "24641", "a1_Statusword"] {
        let (status, body) = get(&app, &format!("/api/v1/buses/demo/nodes/1/od/{index}/0")).await;
        assert_eq!(status, StatusCode::OK, "{index}: {body}");
        assert_eq!(body["index"], "0x6041");
        assert_eq!(body["sub"], 0);
        assert_eq!(body["name"], "a1_Statusword");
        assert_eq!(body["data_type"], "u16");
        let value = body["value"].as_u64().unwrap();
        let raw = body["raw"].as_str().unwrap();
        assert_eq!(raw, hex_le(value, 2), "{body}");
    }
    let (status, body) = get(&app, "/api/v1/buses/demo/nodes/1/od/0x1018/Vendor_ID").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["sub"], 1);
    assert_eq!(body["value"], 1186);
    assert_eq!(body["raw"], "a2040000");
}

fn hex_le(value: u64, len: usize) -> String {
    value.to_le_bytes()[..len]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

#[tokio::test(start_paused = true)]
async fn od_names_nothing_is_404_and_bad_references_400() {
    let (app, state) = demo().await;
    let before = tx_frames(&state);
    let base = "/api/v1/buses/demo/nodes/1/od";
    let response = get(&app, &format!("{base}/No_such_object/0")).await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_object");
    let response = get(&app, &format!("{base}/0x1018/No_such_sub")).await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_sub_object");
    let response = get(&app, &format!("{base}/0x1018/99")).await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_sub_object");
    let response = get(&app, &format!("{base}/0xZZZZ/0")).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_index");
    let response = get(&app, &format!("{base}/0x1018/300")).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_index");
    let response = get(&app, &format!("{base}/0x12345/0")).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_index");
    assert_eq!(tx_frames(&state), before, "nothing was sent");
}

#[tokio::test(start_paused = true)]
async fn od_objects_the_eds_does_not_know_go_to_the_device() {
    let (app, state) = demo().await;
    let base = "/api/v1/buses/demo/nodes/1/od";
    // The device has no 0x5FFF: its abort comes back.
    let response = get(&app, &format!("{base}/0x5FFF/0")).await;
    assert_error(&response, StatusCode::UNPROCESSABLE_ENTITY, "sdo_abort");
    assert_eq!(response.1["error"]["abort_code"], "0x06020000");
    // A write needs its type, before the bus.
    let before = tx_frames(&state);
    let response = call(
        &app,
        Method::PUT,
        &format!("{base}/0x5FFF/0"),
        Some(r#"{"value":1}"#),
    )
    .await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_value");
    assert_eq!(tx_frames(&state), before, "nothing was sent");
}

#[tokio::test(start_paused = true)]
async fn od_write_reads_the_value_back() {
    let (app, state) = demo().await;
    let before = tx_frames(&state);
    let uri = "/api/v1/buses/demo/nodes/2/od/Producer_heartbeat_time/0";
    let (status, body) = call(&app, Method::PUT, uri, Some(r#"{"value":500}"#)).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    // The write and the read back: the counter the other tests rely on
    // to prove that nothing was sent does count SDO requests.
    assert_eq!(tx_frames(&state), before + 2);
    assert_eq!(body["index"], "0x1017");
    assert_eq!(body["value"], 500);
    assert_eq!(body["raw"], "f401");
    let (_, body) = get(&app, uri).await;
    assert_eq!(body["value"], 500);
    // The type may be given, and must then be the EDS's.
    let (status, body) = call(
        &app,
        Method::PUT,
        uri,
        Some(r#"{"value":"1000","data_type":"u16"}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["value"], 1000);
    let response = call(
        &app,
        Method::PUT,
        uri,
        Some(r#"{"value":1000,"data_type":"u32"}"#),
    )
    .await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_value");
}

#[tokio::test(start_paused = true)]
async fn od_write_values_are_checked_before_the_bus() {
    let (app, state) = demo().await;
    let before = tx_frames(&state);
    let uri = "/api/v1/buses/demo/nodes/2/od/0x1017/0";
    let response = call(&app, Method::PUT, uri, Some(r#"{"value":70000}"#)).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "value_out_of_range");
    let response = call(&app, Method::PUT, uri, Some(r#"{"value":-1}"#)).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "value_out_of_range");
    let response = call(&app, Method::PUT, uri, Some(r#"{"value":"fast"}"#)).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_value");
    let response = call(&app, Method::PUT, uri, Some(r#"{"value":[1]}"#)).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_value");
    // Malformed JSON, a missing field, no JSON content type: same shape.
    let response = call(&app, Method::PUT, uri, Some(r#"{"value":"#)).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
    let response = call(&app, Method::PUT, uri, Some(r#"{"val":1}"#)).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
    let request = Request::put(uri)
        .body(Body::from(r#"{"value":1}"#))
        .unwrap();
    let response = app.clone().oneshot(request).await.unwrap();
    assert_eq!(response.status(), StatusCode::BAD_REQUEST);
    assert_eq!(tx_frames(&state), before, "nothing was sent");
}

#[tokio::test(start_paused = true)]
async fn od_write_to_a_read_only_object_is_refused_before_the_bus_as_the_device_would() {
    let (app, state) = demo().await;
    let mut monitor = state.bus("demo").unwrap().monitor();
    let response = call(
        &app,
        Method::PUT,
        "/api/v1/buses/demo/nodes/1/od/0x1000/0",
        Some(r#"{"value":1}"#),
    )
    .await;
    assert_error(&response, StatusCode::UNPROCESSABLE_ENTITY, "sdo_abort");
    assert_eq!(response.1["error"]["abort_code"], "0x06010002");
    assert_eq!(
        response.1["error"]["abort_text"],
        "Attempt to write a read only object"
    );
    // The EDS says 0x1000 is ro: no transfer was started.
    while let Ok(Some(frame)) = monitor.try_recv() {
        assert_ne!(
            frame.frame.id(),
            crate::can::CanId::Standard(0x601),
            "an SDO request reached node 1: {:?}",
            frame.frame
        );
    }
}

#[tokio::test(start_paused = true)]
async fn od_batch_read_keeps_each_entrys_error() {
    let (app, _) = demo().await;
    let (status, body) = call(
        &app,
        Method::POST,
        "/api/v1/buses/demo/nodes/1/od/read",
        Some(r#"{"entries":[["0x6041",0],["a1_Motor_status","Current"],["No_such",0],[4120,"Vendor_ID"],"0x1000"]}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let entries = body.as_array().unwrap();
    assert_eq!(entries.len(), 5);
    assert_eq!(entries[0]["index"], "0x6041");
    assert!(entries[0]["value"].is_u64(), "{body}");
    assert_eq!(entries[1]["index"], "0x4006");
    assert_eq!(entries[1]["data_type"], "i16");
    assert!(entries[1]["raw"].is_string(), "{body}");
    assert_eq!(entries[2]["error"]["code"], "unknown_object");
    assert_eq!(entries[2]["index"], "No_such");
    assert_eq!(entries[3]["value"], 1186);
    assert_eq!(entries[4]["error"]["code"], "invalid_request");
    let response = call(
        &app,
        Method::POST,
        "/api/v1/buses/demo/nodes/1/od/read",
        Some(r#"{"entries":"all"}"#),
    )
    .await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
}

#[tokio::test(start_paused = true)]
async fn od_listing_comes_from_the_eds_and_filters() {
    let (app, _) = demo().await;
    let (status, all) = get(&app, "/api/v1/buses/demo/nodes/1/od").await;
    assert_eq!(status, StatusCode::OK);
    let all = all.as_array().unwrap();
    assert!(all.len() > 20, "{}", all.len());
    let identity = all.iter().find(|o| o["index"] == "0x1018").unwrap();
    assert_eq!(identity["subs"][1]["name"], "Vendor_ID");
    assert_eq!(identity["subs"][1]["data_type"], "u32");
    assert_eq!(identity["subs"][1]["access"], "ro");

    let (status, found) = get(&app, "/api/v1/buses/demo/nodes/1/od?q=vendor").await;
    assert_eq!(status, StatusCode::OK);
    let found = found.as_array().unwrap();
    assert!(!found.is_empty() && found.len() < all.len());
    assert!(found.iter().any(|o| o["index"] == "0x1018"));
    let (_, none) = get(&app, "/api/v1/buses/demo/nodes/1/od?q=zzzz-nothing").await;
    assert_eq!(none, json!([]));

    // Words in any case and order, spaces or underscores (issue 21 point 9):
    // "Profile velocity" is a1_pc_Profile_velocity, 0x6081.
    for q in [
        "Profile%20velocity",
        "velocity%20PROFILE",
        "profile_velocity",
        "6081",
        "0x6081",
    ] {
        let (status, found) = get(&app, &format!("/api/v1/buses/demo/nodes/1/od?q={q}")).await;
        assert_eq!(status, StatusCode::OK);
        let found = found.as_array().unwrap();
        assert!(
            found.iter().any(|o| o["index"] == "0x6081"),
            "{q}: {found:?}"
        );
        assert!(found.len() < all.len(), "{q}");
    }
}

#[tokio::test(start_paused = true)]
async fn silent_device_is_504_and_bus_down_503() {
    let (app, state) = demo().await;
    let served = &state.gateway.bus("demo").unwrap();
    served
        .rack()
        .unwrap()
        .unplug(NodeId::new(3).unwrap())
        .unwrap();
    let response = get(&app, "/api/v1/buses/demo/nodes/3/od/0x1000/0").await;
    assert_error(&response, StatusCode::GATEWAY_TIMEOUT, "sdo_timeout");

    served
        .hub()
        .as_ref()
        .unwrap()
        .set_status(BusStatus::new(BusState::Down, "cable pulled"));
    let response = get(&app, "/api/v1/buses/demo/nodes/1/od/0x1000/0").await;
    assert_error(&response, StatusCode::SERVICE_UNAVAILABLE, "bus_down");
    let response = call(&app, Method::POST, "/api/v1/buses/demo/scan", None).await;
    assert_error(&response, StatusCode::SERVICE_UNAVAILABLE, "bus_down");
    let (_, buses) = get(&app, "/api/v1/buses").await;
    assert_eq!(buses[0]["state"], "down");
}

#[tokio::test(start_paused = true)]
async fn sixty_four_bit_values_are_strings_both_ways() {
    let state = AppState::new([served(true).await]);
    let app = app(state);
    let uri = format!("/api/v1/buses/demo/nodes/{TESTNODE}/od/0x2004/0");
    let (status, body) = get(&app, &uri).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["data_type"], "i64");
    assert_eq!(body["value"], "-5000000000");
    for (written, expected) in [
        (r#"{"value":"-9007199254740993"}"#, "-9007199254740993"),
        (r#"{"value":1234}"#, "1234"),
    ] {
        let (status, body) = call(&app, Method::PUT, &uri, Some(written)).await;
        assert_eq!(status, StatusCode::OK, "{body}");
        assert_eq!(body["value"], expected);
    }
}

#[tokio::test(start_paused = true)]
async fn openapi_document_is_served_as_generated() {
    let (app, _) = demo().await;
    let (status, body) = get(&app, "/api/openapi.json").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body, serde_json::to_value(super::doc::openapi()).unwrap());
    assert!(body["paths"]["/api/v1/buses/{bus}/nodes/{id}/od/{index}/{sub}"]["put"].is_object());
}

/// The docs UI and every file it loads come from the binary: no address
/// outside the gateway appears in what it serves.
#[tokio::test(start_paused = true)]
async fn docs_ui_is_served_from_the_binary() {
    let (app, _) = demo().await;
    let fetch = |uri: &'static str| {
        let app = app.clone();
        async move {
            let request = Request::builder().uri(uri).body(Body::empty()).unwrap();
            let response = app.oneshot(request).await.unwrap();
            let status = response.status();
            let bytes = axum::body::to_bytes(response.into_body(), usize::MAX)
                .await
                .unwrap();
            (status, String::from_utf8_lossy(&bytes).into_owned())
        }
    };
    let (status, index) = fetch("/api/docs/").await;
    assert_eq!(status, StatusCode::OK);
    assert!(index.contains("swagger-ui"), "{index}");
    let (status, initializer) = fetch("/api/docs/swagger-initializer.js").await;
    assert_eq!(status, StatusCode::OK);
    assert!(initializer.contains("/api/openapi.json"), "{initializer}");
    let compact: String = initializer.split_whitespace().collect();
    assert!(
        compact.contains("\"validatorUrl\":\"none\""),
        "{initializer}"
    );
    for (name, text) in [("index", &index), ("initializer", &initializer)] {
        assert!(
            !text.contains("http://") && !text.contains("https://"),
            "{name}: {text}"
        );
    }
    let (status, bundle) = fetch("/api/docs/swagger-ui-bundle.js").await;
    assert_eq!(status, StatusCode::OK);
    assert!(bundle.len() > 100_000);
}

/// A node's answer carries its profile's summary: axes for drives,
/// segments for LED controllers; a stopped node says why it has none.
#[tokio::test(start_paused = true)]
async fn one_node_has_its_profile_summary() {
    let (app, _) = demo().await;
    let (status, umc) = get(&app, "/api/v1/buses/demo/nodes/1").await;
    assert_eq!(status, StatusCode::OK, "{umc}");
    let axes = umc["axes"].as_array().unwrap();
    assert_eq!(axes.len(), 2, "{umc}");
    assert_eq!(axes[1]["axis"], 2);
    assert_eq!(axes[0]["state"], "switch_on_disabled");
    assert!(umc.get("segments").is_none(), "{umc}");
    let (_, jmc) = get(&app, "/api/v1/buses/demo/nodes/2").await;
    assert_eq!(jmc["axes"].as_array().unwrap().len(), 1, "{jmc}");
    let (_, leds) = get(&app, "/api/v1/buses/demo/nodes/3").await;
    let segments = leds["segments"].as_array().unwrap();
    assert_eq!(segments.len(), 10, "{leds}");
    assert_eq!(segments[9]["segment"], 10);
    assert!(leds.get("axes").is_none(), "{leds}");

    // With a heartbeat, the gateway knows when the node is stopped.
    let (status, _) = call(
        &app,
        Method::PUT,
        "/api/v1/buses/demo/nodes/3/od/0x1017/0",
        Some(r#"{"value":100}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    let (status, _) = call(
        &app,
        Method::POST,
        "/api/v1/buses/demo/nodes/3/nmt",
        Some(r#"{"command":"stop"}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (status, stopped) = get(&app, "/api/v1/buses/demo/nodes/3").await;
    assert_eq!(status, StatusCode::OK, "{stopped}");
    assert_eq!(stopped["nmt"], "stopped", "{stopped}");
    assert!(stopped.get("segments").is_none(), "{stopped}");
    assert_eq!(stopped["summary_error"]["code"], "wrong_nmt_state");
}

/// A node known only from its boot-up message is pre-operational (CiA 301
/// §7.3.2.2.1): SDO goes to it, it is not refused as "boot_up".
#[tokio::test(start_paused = true)]
async fn a_node_heard_only_booting_takes_sdo() {
    let (app, state) = demo().await;
    let rack = state.gateway.bus("demo").unwrap().rack().cloned().unwrap();
    rack.add(
        crate::sim::products::Product::Uio1led,
        NodeId::new(9).unwrap(),
    )
    .unwrap();
    // Long enough for the boot-up to be heard and the node identified (on
    // the 500 kbit/s wire the frames wait behind lower identifiers), too
    // short for any scan.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let (status, body) = get(&app, "/api/v1/buses/demo/nodes/9/od/0x1000/0").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["value"], 428, "{body}");
}
