//! Motion leases against the demo UMC on `virtual:demo`, through the router
//! on a paused clock: a velocity move that is not renewed is halted within
//! one lease period of its lapse, one that is renewed keeps running, another
//! client is refused while it runs, stops end the lease, and a stream
//! session that renewed it takes it along when it closes.

use std::time::Duration;

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Value as Json, json};
use tokio::sync::mpsc;

use crate::api::AppState;
use crate::api::stream::{Inbound, run_session};
use crate::api::tests::support::{assert_error, call, demo, get, post, post_with_lease};

const UMC: u8 = 1;

fn uri(axis: u8, what: &str) -> String {
    format!("/api/v1/buses/demo/nodes/{UMC}/axes/{axis}{what}")
}

async fn velocity(app: &Router, axis: u8) -> i64 {
    let (status, body) = call(app, Method::GET, &uri(axis, ""), None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    body["velocity"].as_i64().unwrap()
}

/// Enables axis 1 and runs it at `velocity`; the move's answer.
async fn enable_and_run(app: &Router, velocity: i32) -> Json {
    let (status, body) = post(
        app,
        &uri(1, "/state"),
        json!({"target": "operation_enabled"}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, body) = post(
        app,
        &uri(1, "/move"),
        json!({"mode": "velocity", "velocity": velocity}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    body
}

/// Axis 1 enabled and turning at velocity 100 under a fresh lease of
/// `period`; the lease as the move answered it.
async fn turning(period: Duration) -> (Router, AppState, Json) {
    let (_, state) = demo().await;
    let state = state.with_lease_period(period);
    let app = crate::api::app(state.clone());
    let body = enable_and_run(&app, 100).await;
    let lease = body["lease"].clone();
    assert_eq!(lease["mode"], "velocity", "{body}");
    assert_eq!(lease["holder"], "anonymous", "{body}");
    assert_eq!(lease["period_ms"], period.as_millis() as u64, "{body}");
    assert_eq!(lease["id"].as_str().unwrap().len(), 32, "{body}");
    // Up to speed well within the period.
    tokio::time::sleep(period / 4).await;
    assert!(velocity(&app, 1).await > 0);
    (app, state, lease)
}

const PERIOD: Duration = Duration::from_millis(1000);

#[tokio::test(start_paused = true)]
async fn a_lapsed_lease_halts_the_moving_axis_within_one_period_and_is_audited() {
    let (app, _state, lease) = turning(PERIOD).await;
    // Still running just before the lease runs out (the move took a
    // quarter period, its lease was renewed when it answered).
    tokio::time::sleep(PERIOD / 2).await;
    assert!(
        velocity(&app, 1).await > 0,
        "stopped before the lease lapsed"
    );
    // One period after the lapse, at the latest, it stands still.
    tokio::time::sleep(PERIOD / 2 + PERIOD).await;
    assert_eq!(
        velocity(&app, 1).await,
        0,
        "still moving a period after the lapse"
    );
    let (_, axis) = get(&app, &uri(1, "")).await;
    // Halted, not disabled: the lapse took the gentle way.
    assert_eq!(axis["state"], "operation_enabled", "{axis}");
    // The lease is gone: renewing it is refused in words.
    let id = lease["id"].as_str().unwrap();
    let answer = post(&app, &uri(1, "/lease"), json!({"lease": id})).await;
    assert_error(&answer, StatusCode::NOT_FOUND, "unknown_lease");
    // The gateway's stop is in the audit log, with whose lease it was.
    let (_, audit) = get(&app, "/api/v1/events?kind=audit&limit=100").await;
    let lapse = audit
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["who"] == "gateway")
        .unwrap_or_else(|| panic!("no entry of the gateway in {audit:#}"));
    assert_eq!(
        lapse["operation"], "motion lease lapsed: axis halted",
        "{lapse}"
    );
    assert_eq!(lapse["axis"], 1, "{lapse}");
    assert_eq!(
        lapse["item"], "velocity lease of anonymous (1000 ms)",
        "{lapse}"
    );
    // The gateway's own row: no HTTP request made it.
    assert_eq!(lapse["channel"], "system", "{lapse}");
    assert_eq!(lapse["outcome"], "ok", "{lapse}");
    assert!(
        lapse.get("method").is_none()
            && lapse.get("path").is_none()
            && lapse.get("status").is_none(),
        "{lapse}"
    );
}

#[tokio::test(start_paused = true)]
async fn a_renewed_lease_keeps_the_axis_moving() {
    let (app, _state, lease) = turning(PERIOD).await;
    let id = lease["id"].as_str().unwrap();
    for _ in 0..8 {
        tokio::time::sleep(PERIOD / 2).await;
        let (status, renewed) = post(&app, &uri(1, "/lease"), json!({"lease": id})).await;
        assert_eq!(status, StatusCode::OK, "{renewed}");
        assert_eq!(renewed["expires_in_ms"], 1000, "{renewed}");
    }
    assert!(velocity(&app, 1).await > 0, "halted while renewed");
    // Not through another axis's path.
    let answer = post(&app, &uri(2, "/lease"), json!({"lease": id})).await;
    assert_error(&answer, StatusCode::NOT_FOUND, "unknown_lease");
}

#[tokio::test(start_paused = true)]
async fn another_client_is_refused_while_the_holder_may_change_its_set_point() {
    let (app, _state, lease) = turning(PERIOD).await;
    let id = lease["id"].as_str().unwrap();
    let refused = post(
        &app,
        &uri(1, "/move"),
        json!({"mode": "velocity", "velocity": -50}),
    )
    .await;
    assert_error(&refused, StatusCode::CONFLICT, "lease_conflict");
    let message = refused.1["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("velocity motion of anonymous"),
        "{message}"
    );
    let refused = post(
        &app,
        &uri(1, "/move"),
        json!({"mode": "profile_position", "target": 0}),
    )
    .await;
    assert_error(&refused, StatusCode::CONFLICT, "lease_conflict");
    let wrong = post_with_lease(
        &app,
        &uri(1, "/move"),
        "0123456789abcdef0123456789abcdef",
        json!({"mode": "velocity", "velocity": -50}),
    )
    .await;
    assert_error(&wrong, StatusCode::CONFLICT, "lease_conflict");
    // The holder changes its set-point and keeps its lease.
    let (status, body) = post_with_lease(
        &app,
        &uri(1, "/move"),
        id,
        json!({"mode": "velocity", "velocity": -50}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["lease"]["id"], id, "{body}");
    // Anyone may halt; that ends the lease.
    let (status, body) = post(&app, &uri(1, "/halt"), json!({"halt": true})).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["lease"], Json::Null, "{body}");
    let answer = post(&app, &uri(1, "/lease"), json!({"lease": id})).await;
    assert_error(&answer, StatusCode::NOT_FOUND, "unknown_lease");
    // Releasing halt resumes the velocity: a motion of its own, leased to
    // whoever released it.
    let (status, body) = post(&app, &uri(1, "/halt"), json!({"halt": false})).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["lease"]["mode"], "velocity", "{body}");
    assert_ne!(body["lease"]["id"], id, "{body}");
}

#[tokio::test(start_paused = true)]
async fn stop_all_and_leaving_operation_enabled_end_leases() {
    let (app, state, lease) = turning(PERIOD).await;
    assert_eq!(state.gateway.leases_held(), 1);
    let (status, body) = post(&app, "/api/v1/stop-all", json!({})).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(state.gateway.leases_held(), 0);
    let answer = post(
        &app,
        &uri(1, "/lease"),
        json!({"lease": lease["id"].as_str().unwrap()}),
    )
    .await;
    assert_error(&answer, StatusCode::NOT_FOUND, "unknown_lease");

    // A walk to switch_on_disabled is never refused, and ends the lease.
    // (Quick stop ends in switch_on_disabled once the axis stands.)
    tokio::time::sleep(PERIOD).await;
    enable_and_run(&app, 80).await;
    assert_eq!(state.gateway.leases_held(), 1);
    let (status, body) = post(
        &app,
        &uri(1, "/state"),
        json!({"target": "switch_on_disabled"}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(state.gateway.leases_held(), 0);
}

#[tokio::test(start_paused = true)]
async fn a_bounded_move_gets_no_lease() {
    let (app, _) = demo().await;
    post(
        &app,
        &uri(1, "/state"),
        json!({"target": "operation_enabled"}),
    )
    .await;
    let (status, body) = post(
        &app,
        &uri(1, "/move"),
        json!({"mode": "profile_position", "target": 1000}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["lease"], Json::Null, "{body}");
    assert_eq!(body["state"], "operation_enabled", "{body}");
}

#[tokio::test(start_paused = true)]
async fn a_lease_renewed_on_the_stream_lapses_when_the_session_closes() {
    // A long period: only the session's end can stop the axis this soon.
    let period = Duration::from_secs(30);
    let (app, state, lease) = turning(period).await;
    let id = lease["id"].as_str().unwrap().to_string();
    let (requests, inbound) = mpsc::channel::<Inbound>(4);
    let (outbound, mut messages) = mpsc::channel::<String>(16);
    let inbound = futures_util::stream::unfold(inbound, |mut rx| async move {
        rx.recv().await.map(|request| (request, rx))
    });
    let sink = futures_util::sink::unfold(outbound, |tx, message: String| async move {
        tx.send(message).await.map(|()| tx)
    });
    let session = tokio::spawn(run_session(
        state.clone(),
        Box::pin(inbound),
        Box::pin(sink),
    ));
    let renew = json!({"op": "renew", "leases": [id, "feedfeedfeedfeedfeedfeedfeedfeed"]});
    requests
        .send(Inbound::Text(renew.to_string()))
        .await
        .unwrap();
    let renewed: Json = serde_json::from_str(&messages.recv().await.unwrap()).unwrap();
    assert_eq!(
        renewed,
        json!({"op": "renewed", "leases": [{"id": id, "expires_in_ms": 30000}]})
    );
    let refused: Json = serde_json::from_str(&messages.recv().await.unwrap()).unwrap();
    assert_eq!(refused["op"], "error", "{refused}");
    assert_eq!(
        refused["lease"], "feedfeedfeedfeedfeedfeedfeedfeed",
        "{refused}"
    );
    assert_eq!(refused["error"]["code"], "unknown_lease", "{refused}");

    tokio::time::sleep(Duration::from_secs(2)).await;
    assert!(velocity(&app, 1).await > 0);
    // The client goes away.
    drop(requests);
    session.await.unwrap();
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(
        velocity(&app, 1).await,
        0,
        "still moving after its client left"
    );
    assert_eq!(state.gateway.leases_held(), 0);
}
