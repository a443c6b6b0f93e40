//! The `/sim` endpoints through the router, on a paused clock: devices
//! added to an empty virtual bus and found by the gateway, removed, faults
//! injected and seen as EMCYs; every error case.

use std::time::Duration;

use axum::Router;
use axum::http::StatusCode;
use serde_json::{Value as Json, json};

use crate::api::tests::support::{
    assert_error, delete_text as delete, get, open, post_text as post,
};
use crate::api::{AppState, app};

/// `demo` (virtual:demo), `bench` (virtual:empty) and `remote`, a bus
/// without virtual devices.
async fn buses() -> (Router, AppState) {
    let remote = open("remote", "virtual:empty").await.with_devices(None);
    let state = AppState::new([
        open("demo", "virtual:demo").await,
        open("bench", "virtual:empty").await,
        remote,
    ]);
    (app(state.clone()), state)
}

#[tokio::test(start_paused = true)]
async fn a_device_added_to_an_empty_bus_boots_and_is_found() {
    let (app, _) = buses().await;
    assert_eq!(
        get(&app, "/api/v1/buses/bench/sim/nodes").await.1,
        json!([])
    );
    let (status, added) = post(
        &app,
        "/api/v1/buses/bench/sim/nodes",
        r#"{"product": "uio1led", "id": 4}"#,
    )
    .await;
    assert_eq!(status, StatusCode::CREATED, "{added}");
    assert_eq!(
        added,
        json!({"id": 4, "product": "uio1led", "plugged": true})
    );
    // Its boot-up puts it in the gateway's node list, identified.
    tokio::time::sleep(Duration::from_millis(200)).await;
    let (status, node) = get(&app, "/api/v1/buses/bench/nodes/4").await;
    assert_eq!(status, StatusCode::OK, "{node}");
    assert_eq!(node["profile"], "uioled", "{node}");
    // And it answers SDO.
    let (status, value) = get(&app, "/api/v1/buses/bench/nodes/4/od/0x1018/1").await;
    assert_eq!(
        (status, value["value"].clone()),
        (StatusCode::OK, json!(0x4A2)),
        "{value}"
    );
    let (_, list) = get(&app, "/api/v1/buses/bench/sim/nodes").await;
    assert_eq!(
        list,
        json!([{"id": 4, "product": "uio1led", "plugged": true}])
    );

    let taken = post(
        &app,
        "/api/v1/buses/bench/sim/nodes",
        r#"{"product": "jmc", "id": 4}"#,
    )
    .await;
    assert_error(&taken, StatusCode::CONFLICT, "node_taken");
}

#[tokio::test(start_paused = true)]
async fn a_removed_device_falls_silent_and_its_id_is_free_again() {
    let (app, state) = buses().await;
    state.gateway.bus("demo").unwrap().scan().await.unwrap();
    let (status, body) = delete(&app, "/api/v1/buses/demo/sim/nodes/3", None).await;
    assert_eq!((status, body), (StatusCode::NO_CONTENT, Json::Null));
    let (_, list) = get(&app, "/api/v1/buses/demo/sim/nodes").await;
    let ids: Vec<u64> = list
        .as_array()
        .unwrap()
        .iter()
        .map(|device| device["id"].as_u64().unwrap())
        .collect();
    assert_eq!(ids, vec![1, 2]);
    tokio::time::sleep(Duration::from_millis(50)).await;
    let gone = get(&app, "/api/v1/buses/demo/nodes/3/od/0x1000/0").await;
    assert_error(&gone, StatusCode::GATEWAY_TIMEOUT, "sdo_timeout");
    let again = delete(&app, "/api/v1/buses/demo/sim/nodes/3", None).await;
    assert_error(&again, StatusCode::NOT_FOUND, "unknown_node");
    let (status, _) = post(
        &app,
        "/api/v1/buses/demo/sim/nodes",
        r#"{"product": "uio1led", "id": 3}"#,
    )
    .await;
    assert_eq!(status, StatusCode::CREATED);
    tokio::time::sleep(Duration::from_millis(50)).await;
    let (status, _) = get(&app, "/api/v1/buses/demo/nodes/3/od/0x1000/0").await;
    assert_eq!(status, StatusCode::OK);
}

#[tokio::test(start_paused = true)]
async fn an_injected_fault_is_an_emcy_and_clears() {
    let (app, state) = buses().await;
    state.gateway.bus("demo").unwrap().scan().await.unwrap();
    let uri = "/api/v1/buses/demo/sim/nodes/1/faults";
    let (status, _) = post(&app, uri, r#"{"kind": "over_temperature"}"#).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    tokio::time::sleep(Duration::from_millis(20)).await;
    let (_, node) = get(&app, "/api/v1/buses/demo/nodes/1").await;
    let codes: Vec<&str> = node["emcy"]
        .as_array()
        .unwrap()
        .iter()
        .map(|emcy| emcy["code"].as_str().unwrap())
        .collect();
    assert!(codes.contains(&"0x4310"), "{codes:?}");
    let (_, register) = get(&app, "/api/v1/buses/demo/nodes/1/od/0x1001/0").await;
    assert_eq!(register["value"], 9, "{register}");
    let (status, _) = delete(&app, uri, Some(r#"{"kind": "over_temperature"}"#)).await;
    assert_eq!(status, StatusCode::NO_CONTENT);

    // The LED controller has no following error.
    let refused = post(
        &app,
        "/api/v1/buses/demo/sim/nodes/3/faults",
        r#"{"kind": "following_error"}"#,
    )
    .await;
    assert_error(
        &refused,
        StatusCode::UNPROCESSABLE_ENTITY,
        "fault_not_applicable",
    );
    let refused = delete(
        &app,
        "/api/v1/buses/demo/sim/nodes/3/faults",
        Some(r#"{"kind": "following_error"}"#),
    )
    .await;
    assert_error(
        &refused,
        StatusCode::UNPROCESSABLE_ENTITY,
        "fault_not_applicable",
    );
}

#[tokio::test(start_paused = true)]
async fn sim_errors() {
    let (app, _) = buses().await;
    let nodes = "/api/v1/buses/bench/sim/nodes";
    for (body, code) in [
        (r#"{"product": "umc2", "id": 4}"#, "invalid_value"),
        (r#"{"product": "jmc", "id": 0}"#, "value_out_of_range"),
        (r#"{"product": "jmc", "id": 128}"#, "value_out_of_range"),
        (r#"{"product": "jmc", "id": -5}"#, "value_out_of_range"),
        (r#"{"product": "jmc"}"#, "invalid_request"),
        (r#"{"product": "jmc", "id": "four"}"#, "invalid_request"),
        ("{", "invalid_request"),
    ] {
        assert_error(
            &post(&app, nodes, body).await,
            StatusCode::BAD_REQUEST,
            code,
        );
    }
    assert_eq!(get(&app, nodes).await.1, json!([]), "nothing was added");
    let faults = "/api/v1/buses/demo/sim/nodes/1/faults";
    assert_error(
        &post(&app, faults, r#"{"kind": "meltdown"}"#).await,
        StatusCode::BAD_REQUEST,
        "invalid_value",
    );
    assert_error(
        &delete(&app, faults, Some(r#"{"kind": "meltdown"}"#)).await,
        StatusCode::BAD_REQUEST,
        "invalid_value",
    );
    assert_error(
        &delete(&app, faults, None).await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    for uri in [
        "/api/v1/buses/demo/sim/nodes/0/faults",
        "/api/v1/buses/demo/sim/nodes/x/faults",
    ] {
        let response = post(&app, uri, r#"{"kind": "over_current"}"#).await;
        assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
    }
    assert_error(
        &delete(&app, "/api/v1/buses/demo/sim/nodes/200", None).await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    // No device at 9.
    let fault = r#"{"kind": "over_current"}"#;
    assert_error(
        &post(&app, "/api/v1/buses/demo/sim/nodes/9/faults", fault).await,
        StatusCode::NOT_FOUND,
        "unknown_node",
    );
    assert_error(
        &delete(&app, "/api/v1/buses/demo/sim/nodes/9/faults", Some(fault)).await,
        StatusCode::NOT_FOUND,
        "unknown_node",
    );
    // Unknown bus; a bus without virtual devices.
    for (bus, status, code) in [
        ("nope", StatusCode::NOT_FOUND, "unknown_bus"),
        ("remote", StatusCode::CONFLICT, "not_virtual"),
    ] {
        let base = format!("/api/v1/buses/{bus}/sim/nodes");
        assert_error(&get(&app, &base).await, status, code);
        let add = post(&app, &base, r#"{"product": "jmc", "id": 4}"#).await;
        assert_error(&add, status, code);
        assert_error(
            &delete(&app, &format!("{base}/4"), None).await,
            status,
            code,
        );
        let faults = format!("{base}/4/faults");
        assert_error(&post(&app, &faults, fault).await, status, code);
        assert_error(&delete(&app, &faults, Some(fault)).await, status, code);
    }
}

#[tokio::test(start_paused = true)]
async fn bit_errors_make_a_node_error_passive_then_bus_off_and_recovered_it_is_back() {
    let (app, state) = buses().await;
    state.gateway.bus("demo").unwrap().scan().await.unwrap();
    // The JMC (node 2) sends heartbeats: the gateway supervises it.
    let uri = "/api/v1/buses/demo/sim/nodes/2/faults";
    let (status, _) = post(&app, uri, r#"{"kind": "bit_errors"}"#).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let codes = |node: &Json| -> Vec<String> {
        node["emcy"]
            .as_array()
            .unwrap()
            .iter()
            .map(|emcy| emcy["code"].as_str().unwrap().to_string())
            .collect()
    };
    // 37 frames take it bus-off; by then it sent EMCY 0x8120 and fell
    // silent, so the gateway's heartbeat supervision took it offline.
    tokio::time::sleep(Duration::from_secs(60)).await;
    let (_, node) = get(&app, "/api/v1/buses/demo/nodes/2").await;
    assert!(codes(&node).contains(&"0x8120".to_string()), "{node}");
    assert_eq!(node["online"], false, "{node}");
    let (_, devices) = get(&app, "/api/v1/buses/demo/sim/nodes").await;
    assert_eq!(devices[1]["id"], 2);
    // The others saw an error frame for each of its 37 errors.
    let (_, buses) = get(&app, "/api/v1/buses").await;
    assert_eq!(buses[0]["error_state"], "error_active", "{buses}");
    let error_frames = state.gateway.bus("demo").unwrap().counters().error_frames;
    assert_eq!(error_frames, 37);

    // Stop the errors, ask for the recovery: EMCY 0x8140 and online again.
    let (status, _) = delete(&app, uri, Some(r#"{"kind": "bit_errors"}"#)).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let (status, _) = delete(&app, uri, Some(r#"{"kind": "bus_off"}"#)).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    tokio::time::sleep(Duration::from_secs(3)).await;
    let (_, node) = get(&app, "/api/v1/buses/demo/nodes/2").await;
    assert!(codes(&node).contains(&"0x8140".to_string()), "{node}");
    assert_eq!(node["online"], true, "{node}");
}

#[tokio::test(start_paused = true)]
async fn the_gateways_own_controller_is_reported_as_an_interface_reports_it() {
    let (app, state) = buses().await;
    let bench = |buses: &Json| -> Json {
        buses
            .as_array()
            .unwrap()
            .iter()
            .find(|bus| bus["name"] == "bench")
            .unwrap()
            .clone()
    };
    let (_, buses) = get(&app, "/api/v1/buses").await;
    let info = bench(&buses);
    assert_eq!(
        (
            &info["state"],
            &info["error_state"],
            &info["tx_error_counter"],
            &info["rx_error_counter"]
        ),
        (&json!("up"), &json!("error_active"), &json!(0), &json!(0))
    );
    let uri = "/api/v1/buses/bench/sim/faults";
    let (status, _) = post(&app, uri, r#"{"kind": "bus_off"}"#).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let (_, buses) = get(&app, "/api/v1/buses").await;
    let info = bench(&buses);
    assert_eq!(info["state"], "down", "{info}");
    assert_eq!(info["error_state"], "bus_off", "{info}");
    assert_eq!(info["tx_error_counter"], 256, "{info}");
    let metrics = crate::api::metrics::render(&state);
    assert!(
        metrics.contains("candeck_bus_error_state{bus=\"bench\",state=\"bus_off\"} 1"),
        "{metrics}"
    );
    assert!(metrics.contains("candeck_bus_tx_error_counter{bus=\"bench\"} 256"));
    // Recovery: 128 × 11 bit times at 500 kbit/s, 2.816 ms.
    let (status, _) = delete(&app, uri, Some(r#"{"kind": "bus_off"}"#)).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    tokio::time::sleep(Duration::from_millis(5)).await;
    let (_, buses) = get(&app, "/api/v1/buses").await;
    let info = bench(&buses);
    assert_eq!(
        (
            &info["state"],
            &info["error_state"],
            &info["tx_error_counter"]
        ),
        (&json!("up"), &json!("error_active"), &json!(0))
    );
    // Bit errors on the gateway's frames: error passive after 19, and it
    // still sends.
    let (status, _) = post(&app, uri, r#"{"kind": "bit_errors"}"#).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let bus = state.gateway.bus("bench").unwrap();
    let frame = crate::can::Frame::new(crate::can::CanId::Standard(0x80), &[]).unwrap();
    for _ in 0..19 {
        bus.send_frame(frame).await.unwrap();
    }
    let (_, buses) = get(&app, "/api/v1/buses").await;
    let info = bench(&buses);
    assert_eq!(
        (
            &info["state"],
            &info["error_state"],
            &info["tx_error_counter"]
        ),
        (&json!("up"), &json!("error_passive"), &json!(133))
    );
    let metrics = crate::api::metrics::render(&state);
    assert!(metrics.contains("candeck_bus_error_state{bus=\"bench\",state=\"error_passive\"} 1"));
    assert!(metrics.contains("candeck_bus_error_state{bus=\"bench\",state=\"error_active\"} 0"));

    let refused = post(&app, uri, r#"{"kind": "over_current"}"#).await;
    assert_error(&refused, StatusCode::BAD_REQUEST, "invalid_value");
    let refused = post(
        &app,
        "/api/v1/buses/remote/sim/faults",
        r#"{"kind": "bus_off"}"#,
    )
    .await;
    assert_error(&refused, StatusCode::CONFLICT, "not_virtual");
    let refused = post(
        &app,
        "/api/v1/buses/nope/sim/faults",
        r#"{"kind": "bus_off"}"#,
    )
    .await;
    assert_error(&refused, StatusCode::NOT_FOUND, "unknown_bus");
}

/// A UMC takes its load (`inertia`, `friction`); values out of range and
/// a load for a product without motors are refused, saying why.
#[tokio::test(start_paused = true)]
async fn a_umc_is_added_with_its_load_and_bad_loads_are_refused() {
    let (app, _) = buses().await;
    let nodes = "/api/v1/buses/bench/sim/nodes";
    let heavy = post(
        &app,
        nodes,
        r#"{"product": "umc1bds32", "id": 5, "inertia": 0.003, "friction": 0.0002}"#,
    )
    .await;
    assert_eq!(heavy.0, StatusCode::CREATED, "{}", heavy.1);
    for (body, code, says) in [
        (
            r#"{"product": "umc1bd90", "id": 6, "inertia": 2}"#,
            "value_out_of_range",
            "inertia 2 kg·m² is out of range: 0.00002 to 1 (default 0.0003)",
        ),
        (
            r#"{"product": "umc1bd90", "id": 6, "friction": -0.5}"#,
            "value_out_of_range",
            "friction -0.5 N·m·s is out of range: 0 to 0.1 (default 0.0001)",
        ),
        (
            r#"{"product": "uio1led", "id": 6, "inertia": 0.001}"#,
            "invalid_request",
            "uio1led drives no motor",
        ),
    ] {
        let refused = post(&app, nodes, body).await;
        assert_error(&refused, StatusCode::BAD_REQUEST, code);
        assert!(
            refused.1["error"]["message"]
                .as_str()
                .is_some_and(|message| message.contains(says)),
            "{body}: {}",
            refused.1
        );
    }
}
