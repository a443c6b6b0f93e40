//! Every stop reaches the drive (issue 19, point 1), on `virtual:demo`
//! through the router on a paused clock: STOP ALL, quick stop and halt of a
//! drive the gateway believes offline while it still answers and moves;
//! NMT stop of a node that does not answer SDO at all, from STOP ALL, a
//! halt and a lapsed lease.

use crate::emulator::RackOf;
use std::time::Duration;

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Value as Json, json};

use crate::api::AppState;
use crate::api::tests::support::{call, demo, post, put};
use crate::can::{CanId, FrameReceiver};
use crate::canopen::NodeId;

const UMC: u8 = 1;

fn axis_uri(axis: u8, what: &str) -> String {
    format!("/api/v1/buses/demo/nodes/{UMC}/axes/{axis}{what}")
}

/// An object of the UMC read over the OD route (which, unlike the axis
/// routes, does not refuse a node believed offline).
async fn read(app: &Router, index: u16) -> i64 {
    let uri = format!("/api/v1/buses/demo/nodes/{UMC}/od/0x{index:04X}/0");
    let (status, body) = call(app, Method::GET, &uri, None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    body["value"]
        .as_i64()
        .unwrap_or_else(|| panic!("value in {body}"))
}

/// The velocity of UMC axis `axis` (0x606C, 0x686C, ...), read every
/// 50 ms until `done` or for at most `limit`; the last value.
async fn velocity_until(
    app: &Router,
    axis: u8,
    limit: Duration,
    done: impl Fn(i64) -> bool,
) -> i64 {
    let index = crate::profiles::umc::axis_index(axis, 0x606C).unwrap();
    let deadline = tokio::time::Instant::now() + limit;
    loop {
        let velocity = read(app, index).await;
        if done(velocity) || tokio::time::Instant::now() >= deadline {
            return velocity;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

async fn enable(app: &Router, axis: u8) {
    let (status, body) = post(
        app,
        &axis_uri(axis, "/state"),
        json!({"target": "operation_enabled"}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
}

async fn start(app: &Router, axis: u8, body: Json) {
    let (status, answer) = post(app, &axis_uri(axis, "/move"), body).await;
    assert_eq!(status, StatusCode::OK, "{answer}");
}

/// The repro: the UMC, supervised by its heartbeat, stops it
/// (0x1017 = 0, a legal value) and the gateway marks it offline, while it
/// still answers SDO.
async fn silence_heartbeat(app: &Router, state: &AppState) {
    let heartbeat = |ms: u16| {
        let app = app.clone();
        async move {
            let (status, body) = put(
                &app,
                &format!("/api/v1/buses/demo/nodes/{UMC}/od/0x1017/0"),
                json!({ "value": ms }),
            )
            .await;
            assert_eq!(status, StatusCode::OK, "{body}");
        }
    };
    let registry = state.gateway.bus("demo").unwrap();
    let node = NodeId::new(UMC).unwrap();
    // The demo UMC sends no heartbeat: it starts one, and the gateway
    // learns its period.
    heartbeat(100).await;
    for _ in 0..100 {
        if registry.node(node).unwrap().heartbeat_ms.is_some() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(registry.node(node).unwrap().heartbeat_ms.is_some());
    // Stopped by another master on the bus, not through the gateway (a
    // write through the gateway is followed: the node would stay online,
    // unsupervised).
    let other_master = crate::gateway::SdoChannel::new(
        registry.hub().expect("a virtual bus").attach(),
        node,
        crate::canopen::sdo::ClientConfig::default(),
    );
    other_master
        .download(0x1017, 0, &0u16.to_le_bytes())
        .await
        .unwrap();
    for _ in 0..100 {
        if !registry.node(node).unwrap().online {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(
        !registry.node(node).unwrap().online,
        "the UMC is believed offline"
    );
    // What the gateway believes shows: a move is refused.
    let (status, body) = post(
        app,
        &axis_uri(2, "/move"),
        json!({"mode": "velocity", "velocity": 10}),
    )
    .await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    assert_eq!(body["error"]["code"], "node_offline", "{body}");
}

fn attempts(entry: &Json) -> Vec<(String, String)> {
    entry["attempts"]
        .as_array()
        .unwrap_or_else(|| panic!("attempts in {entry}"))
        .iter()
        .map(|a| {
            (
                a["method"].as_str().unwrap().to_string(),
                a["outcome"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

fn pair(method: &str, outcome: &str) -> (String, String) {
    (method.to_string(), outcome.to_string())
}

#[tokio::test(start_paused = true)]
async fn stop_all_reaches_a_drive_the_gateway_believes_offline() {
    let (app, state) = demo().await;
    enable(&app, 1).await;
    // A long profile-position move.
    start(
        &app,
        1,
        json!({"mode": "profile_position", "target": 100_000_000, "relative": true}),
    )
    .await;
    let moving = velocity_until(&app, 1, Duration::from_secs(3), |v| v > 0).await;
    assert!(moving > 0, "{moving}");
    silence_heartbeat(&app, &state).await;
    assert!(velocity_until(&app, 1, Duration::ZERO, |_| true).await > 0);

    let (status, body) = call(&app, Method::POST, "/api/v1/stop-all", None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["failed"], json!([]), "{body}");
    let stopped = body["stopped"].as_array().unwrap();
    assert_eq!(stopped.len(), 1, "{body}");
    assert_eq!(
        (&stopped[0]["node"], &stopped[0]["axis"]),
        (&json!(1), &json!(1))
    );
    assert_eq!(attempts(&stopped[0]), vec![pair("quick_stop", "confirmed")]);

    let velocity = velocity_until(&app, 1, Duration::from_secs(5), |v| v == 0).await;
    assert_eq!(velocity, 0, "the drive is at rest");
    let statusword = read(&app, 0x6041).await as u16;
    assert_ne!(
        statusword & 0x6F,
        0x27,
        "out of operation enabled: 0x{statusword:04X}"
    );
}

#[tokio::test(start_paused = true)]
async fn halt_and_quick_stop_reach_a_drive_the_gateway_believes_offline() {
    let (app, state) = demo().await;
    for axis in [1, 2] {
        enable(&app, axis).await;
        start(&app, axis, json!({"mode": "velocity", "velocity": 300})).await;
        let moving = velocity_until(&app, axis, Duration::from_secs(3), |v| v > 200).await;
        assert!(moving > 200, "axis {axis}: {moving}");
    }
    silence_heartbeat(&app, &state).await;

    let (status, body) = post(&app, &axis_uri(1, "/halt"), json!({"halt": true})).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(attempts(&body), vec![pair("halt", "confirmed")]);
    let (status, body) = post(
        &app,
        &axis_uri(2, "/state"),
        json!({"target": "quick_stop_active"}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(attempts(&body), vec![pair("quick_stop", "confirmed")]);
    assert_ne!(body["state"], "operation_enabled", "{body}");

    for axis in [1, 2] {
        let velocity = velocity_until(&app, axis, Duration::from_secs(5), |v| v == 0).await;
        assert_eq!(velocity, 0, "axis {axis} is at rest");
    }
}

/// Whether an NMT stop of `node` went over the bus since `frames` was made.
/// Whether the NMT stop of `node` crossed the bus: it takes its bits'
/// time on the wire after the answer that sent it.
async fn nmt_stop_seen(frames: &mut FrameReceiver, node: u8) -> bool {
    tokio::time::sleep(Duration::from_millis(5)).await;
    let mut seen = false;
    while let Ok(Some(frame)) = frames.try_recv() {
        seen |= frame.frame.id() == CanId::Standard(0) && frame.frame.data() == [0x02, node];
    }
    seen
}

#[tokio::test(start_paused = true)]
async fn stop_all_sends_nmt_stop_to_a_drive_that_does_not_answer_sdo() {
    let (app, state) = demo().await;
    enable(&app, 1).await;
    start(&app, 1, json!({"mode": "velocity", "velocity": 300})).await;
    velocity_until(&app, 1, Duration::from_secs(3), |v| v > 0).await;
    let served = &state.gateway.bus("demo").unwrap();
    let mut frames = served.monitor();
    // The node hears nothing and answers nothing from now on.
    served
        .rack()
        .unwrap()
        .unplug(NodeId::new(UMC).unwrap())
        .unwrap();

    let started = tokio::time::Instant::now();
    let (status, body) = call(&app, Method::POST, "/api/v1/stop-all", None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    // A short timeout per step, not the SDO timeout per transfer.
    assert!(
        started.elapsed() <= Duration::from_secs(2),
        "{:?}",
        started.elapsed()
    );
    assert_eq!(body["stopped"], json!([]), "{body}");
    let failed = body["failed"].as_array().unwrap();
    let axis_1 = failed
        .iter()
        .find(|f| f["node"] == 1 && f["axis"] == 1)
        .unwrap_or_else(|| panic!("{body}"));
    assert_eq!(axis_1["error"]["code"], "sdo_timeout", "{body}");
    assert_eq!(
        attempts(axis_1),
        vec![pair("quick_stop", "timeout"), pair("nmt_stop", "sent")]
    );
    // Its second axis is not asked once the node is not heard; the NMT
    // stop covers it.
    let axis_2 = failed
        .iter()
        .find(|f| f["node"] == 1 && f["axis"] == 2)
        .unwrap_or_else(|| panic!("{body}"));
    assert_eq!(
        attempts(axis_2),
        vec![pair("quick_stop", "skipped"), pair("nmt_stop", "sent")]
    );
    // The JMC answered: nothing of it failed.
    assert!(failed.iter().all(|f| f["node"] == 1), "{body}");
    assert!(
        nmt_stop_seen(&mut frames, UMC).await,
        "NMT stop of node 1 on the bus"
    );
}

#[tokio::test(start_paused = true)]
async fn a_halt_of_a_drive_that_does_not_answer_falls_back_to_nmt_stop() {
    let (app, state) = demo().await;
    enable(&app, 1).await;
    start(&app, 1, json!({"mode": "velocity", "velocity": 300})).await;
    let served = &state.gateway.bus("demo").unwrap();
    let mut frames = served.monitor();
    served
        .rack()
        .unwrap()
        .unplug(NodeId::new(UMC).unwrap())
        .unwrap();

    let (status, body) = post(&app, &axis_uri(1, "/halt"), json!({"halt": true})).await;
    assert_eq!(status, StatusCode::GATEWAY_TIMEOUT, "{body}");
    assert_eq!(body["error"]["code"], "sdo_timeout", "{body}");
    assert_eq!(
        attempts(&body["error"]),
        vec![
            pair("halt", "timeout"),
            pair("quick_stop", "timeout"),
            pair("nmt_stop", "sent")
        ]
    );
    assert!(
        nmt_stop_seen(&mut frames, UMC).await,
        "NMT stop of node 1 on the bus"
    );
}

#[tokio::test(start_paused = true)]
async fn a_lapsed_lease_on_a_drive_that_does_not_answer_sends_nmt_stop() {
    let (_, state) = demo().await;
    let state = state.with_lease_period(Duration::from_millis(500));
    let app = crate::api::app(state.clone());
    enable(&app, 1).await;
    start(&app, 1, json!({"mode": "velocity", "velocity": 300})).await;
    let served = &state.gateway.bus("demo").unwrap();
    let mut frames = served.monitor();
    served
        .rack()
        .unwrap()
        .unplug(NodeId::new(UMC).unwrap())
        .unwrap();
    // Not renewed: the lease lapses, halt and quick stop go unanswered.
    tokio::time::sleep(Duration::from_secs(5)).await;
    assert!(
        nmt_stop_seen(&mut frames, UMC).await,
        "NMT stop of node 1 on the bus"
    );
    let (status, body) = call(&app, Method::GET, "/api/v1/events?kind=audit", None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let text = body.to_string();
    assert!(
        text.contains("motion lease lapsed: axis not confirmed, node sent NMT stop"),
        "{body}"
    );
}
