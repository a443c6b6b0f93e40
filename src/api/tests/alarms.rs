//! The alarms through the router: a fault on the demo rack raises its
//! alarms, the machine leaves `ready`, the list filters and pages, one
//! alarm has its history, acknowledgements say who and are audited, and
//! the machine recovers in two requests.

use std::time::Duration;

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Value as Json, json};

use super::support::{assert_error, call, call_text, get, open, post, raw_call};
use crate::api::{AppState, app};
use crate::canopen::manager::MachineState;
use crate::gateway::MachineSettings;

/// The demo bus scanned, its manager run, every node booted.
async fn demo_with_machine() -> Router {
    demo_with_state().await.0
}

async fn demo_with_state() -> (Router, AppState) {
    let served = open("demo", "virtual:demo")
        .await
        .with_machine(MachineSettings::default(), None);
    served.scan().await.unwrap();
    let machine = served.machine().unwrap().clone();
    machine.scan_done();
    let status = machine
        .wait_for(MachineState::Ready, Duration::from_secs(10))
        .await;
    assert_eq!(status.state, MachineState::Ready, "{status:?}");
    let state = AppState::new([served]);
    (app(state.clone()), state)
}

async fn inject(app: &Router, node: u8, fault: &str) {
    let uri = format!("/api/v1/buses/demo/sim/nodes/{node}/faults");
    let (status, body) = post(app, &uri, json!({ "kind": fault })).await;
    assert!(status.is_success(), "{status} {body}");
}

async fn clear(app: &Router, node: u8, fault: &str) {
    let uri = format!("/api/v1/buses/demo/sim/nodes/{node}/faults");
    let body = json!({ "kind": fault }).to_string();
    let (status, body) = call_text(app, Method::DELETE, &uri, Some(&body)).await;
    assert!(status.is_success(), "{status} {body}");
}

async fn alarms(app: &Router, query: &str) -> Json {
    let (status, body) = get(app, &format!("/api/v1/alarms{query}")).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    body
}

#[tokio::test(start_paused = true)]
async fn a_fault_shows_as_alarms_the_machine_leaves_ready_and_an_operator_acknowledges_them() {
    let app = demo_with_machine().await;
    assert_eq!(alarms(&app, "").await, json!({"alarms": [], "total": 0}));
    inject(&app, 1, "over_temperature").await;
    tokio::time::sleep(Duration::from_secs(1)).await;

    let list = alarms(&app, "?node=1&severity=high").await;
    assert_eq!(list["total"], 2, "one per axis: {list}");
    let first = &list["alarms"][0];
    assert_eq!(first["bus"], "demo");
    assert_eq!(first["kind"], "emcy");
    assert_eq!(first["state"], "active_unacknowledged");
    assert_eq!(first["count"], 1);
    assert!(
        first["code"].as_str().unwrap().starts_with("0x4"),
        "{first}"
    );
    assert!(first["raised"].as_str().unwrap().ends_with('Z'));
    assert_eq!(first["cleared"], Json::Null);
    assert!(
        first.get("history").is_none(),
        "lists leave the history out"
    );
    let axes: Vec<&Json> = list["alarms"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| &a["axis"])
        .collect();
    assert!(
        axes.contains(&&json!(1)) && axes.contains(&&json!(2)),
        "{list}"
    );
    assert_eq!(alarms(&app, "?severity=low").await["total"], 0);
    assert_eq!(alarms(&app, "?node=3").await["total"], 0);

    let (_, machine) = get(&app, "/api/v1/buses/demo/machine").await;
    assert_eq!(machine["state"], "alarm", "{machine}");
    assert!(
        machine["reasons"]
            .as_array()
            .unwrap()
            .iter()
            .any(|reason| reason.as_str().unwrap().contains("(high): node 1 axis")),
        "{machine}"
    );

    let id = first["id"].as_u64().unwrap();
    let uri = format!("/api/v1/alarms/{id}/ack");
    let (status, acked) = post(&app, &uri, json!({"comment": "fan checked"})).await;
    assert_eq!(status, StatusCode::OK, "{acked}");
    assert_eq!(acked["state"], "active_acknowledged");
    assert_eq!(acked["acknowledged_by"], "anonymous");
    assert_eq!(acked["comment"], "fan checked");
    assert!(acked["acknowledged_at"].as_str().unwrap().ends_with('Z'));
    let (status, one) = get(&app, &format!("/api/v1/alarms/{id}")).await;
    assert_eq!(status, StatusCode::OK);
    let steps: Vec<&str> = one["history"]
        .as_array()
        .unwrap()
        .iter()
        .map(|step| step["step"].as_str().unwrap())
        .collect();
    assert_eq!(steps, ["raised", "acknowledged"]);
    assert_eq!(one["history"][1]["who"], "anonymous");

    // The rest of node 1's, without a body.
    let (status, all) = call_text(&app, Method::POST, "/api/v1/alarms/ack", None).await;
    assert_eq!(status, StatusCode::OK, "{all}");
    let acked = all["acknowledged"].as_array().unwrap();
    assert_eq!(acked.len(), 1, "{all}");
    assert_eq!(
        alarms(&app, "?state=active_unacknowledged").await["total"],
        0
    );

    // The cause gone, reset faults: the alarms go back to normal (they
    // were acknowledged) and the machine is ready again.
    clear(&app, 1, "over_temperature").await;
    let (status, report) = post(&app, "/api/v1/buses/demo/machine/reset-faults", json!({})).await;
    assert_eq!(status, StatusCode::OK, "{report}");
    let umc: Vec<&Json> = report["axes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|axis| axis["node"] == 1)
        .collect();
    assert!(umc.iter().all(|axis| axis["outcome"] == "done"), "{report}");
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert_eq!(alarms(&app, "?state=normal").await["total"], 2);
    let (_, machine) = get(&app, "/api/v1/buses/demo/machine").await;
    assert_eq!(machine["state"], "ready", "{machine}");

    let (_, events) = get(&app, "/api/v1/events?kind=audit").await;
    let operations: Vec<&str> = events
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|event| event["operation"].as_str())
        .collect();
    assert_eq!(
        operations
            .iter()
            .filter(|op| **op == "acknowledge alarm")
            .count(),
        1,
        "{operations:?}"
    );
    assert!(operations.contains(&"acknowledge alarms"));
    assert!(operations.contains(&"machine reset faults"));
    assert!(operations.contains(&"fault reset"), "each axis its own row");
}

#[tokio::test(start_paused = true)]
async fn bad_alarm_requests_are_refused_with_a_clear_error() {
    let app = demo_with_machine().await;
    assert_error(
        &get(&app, "/api/v1/alarms?state=burning").await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    assert_error(
        &get(&app, "/api/v1/alarms?severity=urgent").await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    assert_error(
        &get(&app, "/api/v1/alarms?since=yesterday").await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    assert_error(
        &get(&app, "/api/v1/alarms?page=0").await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    assert_error(
        &get(&app, "/api/v1/alarms/999").await,
        StatusCode::NOT_FOUND,
        "unknown_alarm",
    );
    assert_error(
        &get(&app, "/api/v1/alarms/first").await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    assert_error(
        &post(&app, "/api/v1/alarms/999/ack", json!({})).await,
        StatusCode::NOT_FOUND,
        "unknown_alarm",
    );
    assert_error(
        &post(&app, "/api/v1/alarms/ack", json!({"colour": "red"})).await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    assert_error(
        &post(&app, "/api/v1/alarms/ack", json!({"bus": "nope"})).await,
        StatusCode::NOT_FOUND,
        "unknown_bus",
    );
    let long = "x".repeat(501);
    assert_error(
        &post(&app, "/api/v1/alarms/ack", json!({"comment": long})).await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    assert_error(
        &call(
            &app,
            Method::POST,
            "/api/v1/buses/nope/machine/enable",
            None,
        )
        .await,
        StatusCode::NOT_FOUND,
        "unknown_bus",
    );
}

#[tokio::test(start_paused = true)]
async fn a_lost_heartbeat_refuses_reset_faults_on_that_node_with_its_reason() {
    let app = demo_with_machine().await;
    inject(&app, 2, "heartbeat_loss").await;
    tokio::time::sleep(Duration::from_secs(3)).await;
    let list = alarms(&app, "?node=2").await;
    assert_eq!(list["alarms"][0]["kind"], "heartbeat_lost", "{list}");
    assert_eq!(list["alarms"][0]["severity"], "critical");
    let (status, report) = post(&app, "/api/v1/buses/demo/machine/reset-faults", json!({})).await;
    assert_eq!(status, StatusCode::OK, "{report}");
    let jmc = report["axes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|axis| axis["node"] == 2)
        .unwrap();
    assert_eq!(jmc["outcome"], "refused");
    assert!(
        jmc["reason"]
            .as_str()
            .unwrap()
            .contains("the cause is still present: alarm"),
        "{jmc}"
    );
}

#[tokio::test(start_paused = true)]
async fn the_stream_sends_the_open_alarms_then_each_change_and_the_machine_follows() {
    let (app, state) = demo_with_state().await;
    let mut client = super::stream::Client::start(&state, 256);
    client.subscribe(&["alarms", "machine"], None).await;
    let open = client.until(|m| m["topic"] == "alarms").await;
    assert_eq!(open["data"]["event"], "open", "{open}");
    assert_eq!(open["data"]["alarms"], json!([]));
    assert_eq!(open["data"]["summary"]["active"]["high"], 0);
    let ready = client.until(|m| m["topic"] == "machine").await;
    assert_eq!(ready["data"]["state"], "ready", "{ready}");

    inject(&app, 1, "following_error").await;
    let raised = client
        .until(|m| m["topic"] == "alarms" && m["data"]["event"] == "raised")
        .await;
    assert_eq!(raised["data"]["alarm"]["kind"], "emcy", "{raised}");
    assert_eq!(raised["data"]["alarm"]["code"], "0x8611");
    assert_eq!(raised["data"]["alarm"]["node"], 1);
    assert!(
        raised["data"]["summary"]["active"]["high"]
            .as_u64()
            .unwrap()
            >= 1
    );
    assert_eq!(raised["data"]["summary"]["highest"], "high");
    let alarm = client
        .until(|m| m["topic"] == "machine" && m["data"]["state"] == "alarm")
        .await;
    assert_eq!(alarm["data"]["bus"], "demo");

    // Prometheus counts them by severity.
    let (status, page, _) = raw_call(&app, Method::GET, "/metrics", "text/plain", None).await;
    assert_eq!(status, StatusCode::OK);
    assert!(
        page.contains("candeck_alarms_active{bus=\"demo\",severity=\"high\"} 2"),
        "{page}"
    );
    assert!(page.contains("candeck_alarms_unacknowledged{bus=\"demo\",severity=\"critical\"} 0"));
}

#[tokio::test(start_paused = true)]
async fn only_an_operator_acknowledges_and_each_request_is_audited_once_by_its_token() {
    use crate::api::auth::{AuthConfig, DEFAULT_BODY_LIMIT, Role, Token};
    use crate::api::tests::support::send_with_headers;
    const VIEWER: &str = "v1ewer-0123456789abcdef";
    const OPERATOR: &str = "0perator-0123456789abcdef";
    let (_, state) = demo_with_state().await;
    let config = AuthConfig::new(
        vec![
            Token::new("hmi", Role::Viewer, VIEWER).unwrap(),
            Token::new("line-plc", Role::Operator, OPERATOR).unwrap(),
        ],
        Vec::new(),
        None,
        DEFAULT_BODY_LIMIT,
        2 * DEFAULT_BODY_LIMIT,
    )
    .unwrap();
    let app = app(state.clone().with_auth(config));
    let as_token = |token: &'static str| format!("Bearer {token}");
    let viewer = as_token(VIEWER);
    let operator = as_token(OPERATOR);
    // The fault straight on the rack: no admin token here.
    state_rack_fault(&state);
    tokio::time::sleep(Duration::from_secs(1)).await;
    let (status, _, list) = send_with_headers(
        &app,
        Method::GET,
        "/api/v1/alarms",
        &[("authorization", &viewer)],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "a viewer reads them");
    let id = list["alarms"][0]["id"].as_u64().unwrap();
    let ack = format!("/api/v1/alarms/{id}/ack");
    let (status, _, body) = send_with_headers(
        &app,
        Method::POST,
        &ack,
        &[("authorization", &viewer)],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::FORBIDDEN, "{body}");
    let (status, _, body) = send_with_headers(
        &app,
        Method::POST,
        &ack,
        &[("authorization", &operator)],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["acknowledged_by"], "line-plc");

    let (_, _, events) = send_with_headers(
        &app,
        Method::GET,
        "/api/v1/events?kind=audit",
        &[("authorization", &viewer)],
        None,
    )
    .await;
    let rows: Vec<(&str, &str)> = events
        .as_array()
        .unwrap()
        .iter()
        .filter(|row| row["operation"] == "acknowledge alarm")
        .map(|row| {
            (
                row["who"].as_str().unwrap(),
                row["outcome"].as_str().unwrap(),
            )
        })
        .collect();
    assert_eq!(rows, [("hmi", "forbidden"), ("line-plc", "ok")]);
}

/// Over-temperature on node 1 of the demo rack, straight on the rack.
fn state_rack_fault(state: &AppState) {
    use crate::emulator::RackOf;
    let served = state.bus("demo").unwrap();
    let rack = served.rack().unwrap();
    rack.inject_fault(
        crate::canopen::NodeId::new(1).unwrap(),
        crate::sim::behaviour::Fault::OverTemperature,
    )
    .unwrap();
}
