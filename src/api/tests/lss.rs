//! LSS (CiA 305) and the UniSwarm node-ID change through the router, on a
//! virtual bus with unconfigured devices, on a paused clock.

use axum::http::StatusCode;
use serde_json::{Value as Json, json};

use crate::api::tests::support::{assert_error, get, open, post};
use crate::api::{AppState, app};

fn ok(response: (StatusCode, Json)) -> Json {
    assert_eq!(response.0, StatusCode::OK, "{}", response.1);
    response.1
}

async fn line(spec: &str) -> axum::Router {
    let served = open("line", spec).await;
    served.scan().await.unwrap();
    app(AppState::new([served]))
}

fn node_ids(nodes: &Json) -> Vec<u64> {
    nodes
        .as_array()
        .unwrap()
        .iter()
        .map(|node| node["id"].as_u64().unwrap())
        .collect()
}

#[tokio::test(start_paused = true)]
async fn an_unconfigured_device_is_found_configured_and_listed() {
    let app = line("virtual:umc1bds32@1,uio1led@lss").await;
    assert_eq!(
        node_ids(&ok(get(&app, "/api/v1/buses/line/nodes").await)),
        vec![1]
    );
    let scan = ok(post(&app, "/api/v1/buses/line/lss/scan", json!({})).await);
    let led = json!({"vendor_id": 0x4A2, "product_code": 0x4101, "revision": 1, "serial": 0x101});
    assert_eq!(scan, json!({"found": [led]}));
    let mut request = led.clone();
    request["node_id"] = json!(10);
    request["store"] = json!(true);
    let node = ok(post(&app, "/api/v1/buses/line/lss/configure", request.clone()).await);
    assert_eq!(node["id"], 10);
    assert_eq!(
        node_ids(&ok(get(&app, "/api/v1/buses/line/nodes").await)),
        vec![1, 10]
    );
    assert_eq!(node["identity"]["serial"], 0x101, "{node}");
    // Nothing unconfigured is left.
    assert_eq!(
        ok(post(&app, "/api/v1/buses/line/lss/scan", json!({})).await),
        json!({"found": []})
    );
    // Node 10 is taken now; an identity nobody has is not found.
    assert_error(
        &post(&app, "/api/v1/buses/line/lss/configure", request.clone()).await,
        StatusCode::CONFLICT,
        "node_id_in_use",
    );
    request["node_id"] = json!(11);
    request["serial"] = json!(0x999);
    assert_error(
        &post(&app, "/api/v1/buses/line/lss/configure", request.clone()).await,
        StatusCode::NOT_FOUND,
        "lss_not_found",
    );
    request["node_id"] = json!(128);
    assert_error(
        &post(&app, "/api/v1/buses/line/lss/configure", request).await,
        StatusCode::BAD_REQUEST,
        "invalid_value",
    );
}

#[tokio::test(start_paused = true)]
async fn a_uniswarm_node_changes_its_node_id_by_0x2040() {
    let app = line("virtual:demo").await;
    // Operational, as the network manager leaves it: the device stores its
    // parameters in pre-operational only (0x08000021 otherwise), so the
    // change takes it there first.
    ok(post(
        &app,
        "/api/v1/buses/line/nodes/3/nmt",
        json!({"command": "start"}),
    )
    .await);
    let node = ok(post(
        &app,
        "/api/v1/buses/line/nodes/3/node-id",
        json!({"node_id": 9}),
    )
    .await);
    assert_eq!(node["id"], 9);
    assert_eq!(node["identity"]["product_code"], 0x4101, "{node}");
    let value = ok(get(&app, "/api/v1/buses/line/nodes/9/od/0x2040/1").await);
    assert_eq!(value["value"], 9);
    // The old ID is forgotten: not listed, and refused as unknown rather
    // than left to time out every request.
    assert_eq!(
        node_ids(&ok(get(&app, "/api/v1/buses/line/nodes").await)),
        vec![1, 2, 9]
    );
    assert_error(
        &get(&app, "/api/v1/buses/line/nodes/3/od/0x1000/0").await,
        StatusCode::NOT_FOUND,
        "unknown_node",
    );
    // Node 1 is taken; the JMC has no 0x2040.
    assert_error(
        &post(
            &app,
            "/api/v1/buses/line/nodes/9/node-id",
            json!({"node_id": 1}),
        )
        .await,
        StatusCode::CONFLICT,
        "node_id_in_use",
    );
    let refused = post(
        &app,
        "/api/v1/buses/line/nodes/2/node-id",
        json!({"node_id": 20}),
    )
    .await;
    assert_error(
        &refused,
        StatusCode::UNPROCESSABLE_ENTITY,
        "node_id_change_not_supported",
    );
    // The JMC manual ("Set the baud rate and station number"): its rotary
    // switches S1/S3 give the node-ID; it has no LSS to point to.
    let message = refused.1["error"]["message"].as_str().unwrap();
    assert!(message.contains("rotary switches S1"), "{message}");
    assert!(!message.contains("LSS"), "{message}");
}

#[tokio::test(start_paused = true)]
async fn sim_nodes_adds_an_unconfigured_device_which_lss_finds() {
    let app = line("virtual:empty").await;
    let added = crate::api::tests::support::call(
        &app,
        axum::http::Method::POST,
        "/api/v1/buses/line/sim/nodes",
        Some(json!({"product": "jmc", "lss": true, "serial": 42})),
    )
    .await;
    assert_eq!(added.0, StatusCode::CREATED, "{}", added.1);
    assert_eq!(
        added.1,
        json!({"id": null, "product": "jmc", "plugged": true, "serial": 42})
    );
    assert_eq!(
        ok(get(&app, "/api/v1/buses/line/sim/nodes").await),
        json!([added.1])
    );
    let scan = ok(post(&app, "/api/v1/buses/line/lss/scan", json!({})).await);
    assert_eq!(
        scan,
        json!({"found": [{"vendor_id": 0x2D9, "product_code": 0, "revision": 0, "serial": 42}]})
    );
    let bad = crate::api::tests::support::call(
        &app,
        axum::http::Method::POST,
        "/api/v1/buses/line/sim/nodes",
        Some(json!({"product": "jmc", "lss": true, "id": 4})),
    )
    .await;
    assert_error(&bad, StatusCode::BAD_REQUEST, "invalid_request");
}

#[tokio::test(start_paused = true)]
async fn one_lss_transaction_per_bus_at_a_time() {
    let served = open("line", "virtual:uio1led@lss").await;
    let state = AppState::new([served]);
    let app = app(state.clone());
    let served = state.bus("line").unwrap();
    let held = served.lss().begin().unwrap();
    assert_error(
        &post(&app, "/api/v1/buses/line/lss/scan", json!({})).await,
        StatusCode::CONFLICT,
        "lss_busy",
    );
    let request = json!({"vendor_id": 0x4A2, "product_code": 0x4101, "revision": 1,
        "serial": 0x101, "node_id": 5});
    assert_error(
        &post(&app, "/api/v1/buses/line/lss/configure", request.clone()).await,
        StatusCode::CONFLICT,
        "lss_busy",
    );
    drop(held);
    assert_eq!(
        ok(post(&app, "/api/v1/buses/line/lss/configure", request).await)["id"],
        5
    );
}
