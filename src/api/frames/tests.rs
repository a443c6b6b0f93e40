//! `GET` and `POST /buses/{bus}/frames` through the router, on a paused
//! clock, against the demo devices.

use std::time::Duration;

use axum::Router;
use axum::http::StatusCode;
use serde_json::json;

use crate::api::tests::support::{assert_error, get, open, post_text as post};
use crate::api::{AppState, app};

use crate::can::{BusState, BusStatus};

async fn demo() -> (Router, AppState) {
    let state = AppState::new([open("demo", "virtual:demo").await]);
    (app(state.clone()), state)
}

#[tokio::test(start_paused = true)]
async fn recent_frames_show_both_directions_newest_last() {
    let (app, state) = demo().await;
    state.gateway.bus("demo").unwrap().scan().await.unwrap();
    let (status, frames) = get(&app, "/api/v1/buses/demo/frames").await;
    assert_eq!(status, StatusCode::OK);
    let frames = frames.as_array().unwrap();
    assert_eq!(
        frames.len(),
        super::DEFAULT_LIMIT,
        "the scan makes more than 100"
    );
    let (status, all) = get(&app, "/api/v1/buses/demo/frames?limit=1000").await;
    assert_eq!(status, StatusCode::OK);
    let all = all.as_array().unwrap();
    assert!(all.len() > 127 && all.len() <= 1000, "{}", all.len());
    // The newest 100 are the tail of the whole log.
    assert_eq!(frames[..], all[all.len() - 100..]);
    let timestamps: Vec<u64> = all
        .iter()
        .map(|frame| frame["timestamp_us"].as_u64().unwrap())
        .collect();
    assert!(timestamps.windows(2).all(|pair| pair[0] <= pair[1]));
    // The devices' boot-ups (rx) and the scan's SDO requests (tx) to node 1
    // with its answer.
    let boot = all
        .iter()
        .find(|frame| frame["id"] == "0x701")
        .expect("boot-up of node 1");
    assert_eq!(
        boot,
        &json!({"timestamp_us": boot["timestamp_us"], "id": "0x701", "extended": false,
                "rtr": false, "fd": false, "error": false, "dlc": 1, "data": "00", "dir": "rx"})
    );
    assert!(
        all.iter()
            .any(|frame| frame["id"] == "0x601" && frame["dir"] == "tx"),
        "no SDO request to node 1"
    );
    assert!(
        all.iter()
            .any(|frame| frame["id"] == "0x581" && frame["dir"] == "rx"),
        "no SDO answer of node 1"
    );
    let (_, none) = get(&app, "/api/v1/buses/demo/frames?limit=0").await;
    assert_eq!(none, json!([]));
}

#[tokio::test(start_paused = true)]
async fn a_posted_frame_reaches_the_devices() {
    let (app, _) = demo().await;
    // An SDO upload request of 0x1000 to node 1, by hand.
    let (status, sent) = post(
        &app,
        "/api/v1/buses/demo/frames",
        r#"{"id": "0x601", "data": "40 00 10 00 00 00 00 00"}"#,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{sent}");
    assert_eq!(sent["id"], "0x601");
    assert_eq!(sent["data"], "4000100000000000");
    assert_eq!(
        (sent["dir"].clone(), sent["dlc"].clone()),
        (json!("tx"), json!(8))
    );
    tokio::time::sleep(Duration::from_millis(5)).await;
    let (_, frames) = get(&app, "/api/v1/buses/demo/frames?limit=1000").await;
    let frames = frames.as_array().unwrap();
    let request = frames
        .iter()
        .position(|frame| frame["id"] == "0x601" && frame["data"] == "4000100000000000")
        .unwrap_or_else(|| panic!("the request is not in the log: {frames:?}"));
    let answer = frames[request..]
        .iter()
        .find(|frame| frame["id"] == "0x581")
        .expect("node 1 answered");
    // Expedited upload of 4 bytes: 0x1000 of a CiA 402 device.
    assert_eq!(answer["dir"], "rx");
    assert!(
        answer["data"].as_str().unwrap().starts_with("43001000"),
        "{answer}"
    );
    // Numbers and 29-bit ids.
    let (status, sent) = post(
        &app,
        "/api/v1/buses/demo/frames",
        r#"{"id": 448585456, "extended": true}"#,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{sent}");
    assert_eq!(
        (
            sent["id"].clone(),
            sent["extended"].clone(),
            sent["data"].clone()
        ),
        (json!("0x1ABCDEF0"), json!(true), json!(""))
    );
    let (status, sent) = post(&app, "/api/v1/buses/demo/frames", r#"{"id": "7FFh"}"#).await;
    assert_eq!(
        (status, sent["id"].clone()),
        (StatusCode::OK, json!("0x7FF"))
    );
}

#[tokio::test(start_paused = true)]
async fn frames_errors() {
    let (app, state) = demo().await;
    // The devices' identification done first: its SDO requests are the
    // gateway's own frames, which the requests below give time to run
    // (each audited one waits for its history write).
    state.gateway.bus("demo").unwrap().scan().await.unwrap();
    let uri = "/api/v1/buses/demo/frames";
    let tx_before = state.gateway.bus("demo").unwrap().counters().tx_frames;
    for (body, code) in [
        (r#"{"id": "0x800", "data": ""}"#, "value_out_of_range"),
        (r#"{"id": 2048}"#, "value_out_of_range"),
        (
            r#"{"id": "0x20000000", "extended": true}"#,
            "value_out_of_range",
        ),
        (
            r#"{"id": 1, "data": "010203040506070809"}"#,
            "value_out_of_range",
        ),
        (r#"{"id": 1, "data": "abc"}"#, "invalid_value"),
        (r#"{"id": 1, "data": "zz"}"#, "invalid_value"),
        (r#"{"id": "six"}"#, "invalid_value"),
        (r#"{"id": -1}"#, "invalid_request"),
        (r#"{"data": "00"}"#, "invalid_request"),
        (r#"{"id": 1, "dta": "00"}"#, "invalid_request"),
        ("not json", "invalid_request"),
    ] {
        let response = post(&app, uri, body).await;
        assert_error(&response, StatusCode::BAD_REQUEST, code);
    }
    assert_eq!(
        state.gateway.bus("demo").unwrap().counters().tx_frames,
        tx_before,
        "nothing invalid reached the bus"
    );
    for query in ["limit=1001", "limit=-1", "limit=many"] {
        let response = get(&app, &format!("{uri}?{query}")).await;
        assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
    }
    let response = get(&app, "/api/v1/buses/nope/frames").await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_bus");
    let response = post(&app, "/api/v1/buses/nope/frames", r#"{"id": 1}"#).await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_bus");
    state
        .gateway
        .bus("demo")
        .unwrap()
        .hub()
        .as_ref()
        .unwrap()
        .set_status(BusStatus::new(BusState::Down, "cable pulled"));
    let response = post(&app, uri, r#"{"id": 1}"#).await;
    assert_error(&response, StatusCode::SERVICE_UNAVAILABLE, "bus_down");
    // The log still reads.
    assert_eq!(get(&app, uri).await.0, StatusCode::OK);
}
