//! Motion leases bound to their holder (issue 19, point 5), on a gateway
//! with tokens and the demo UMC, on a paused clock: another token may
//! neither renew a lease nor present it, only take the axis over
//! explicitly (audited, naming both); a viewer never renews one over the
//! stream; lease ids are masked in the audit log that viewers read; stream
//! renewals are audited, once per lease per interval.

use std::time::Duration;

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Value as Json, json};
use tokio::sync::mpsc;

use crate::api::auth::{AuthConfig, DEFAULT_BODY_LIMIT, Identity, Role, Token};
use crate::api::stream::{Client, Inbound, run_session_as};
use crate::api::tests::support::{demo, send_with_headers};
use crate::api::{AppState, app};

const VIEWER: &str = "v1ewer-0123456789abcdef";
const OPERATOR: &str = "0perator-0123456789abcdef";
const OTHER_OPERATOR: &str = "0ther-0perator-0123456789";
const ADMIN: &str = "adm1n-0123456789abcdef";
const PERIOD: Duration = Duration::from_millis(1000);

fn config() -> AuthConfig {
    AuthConfig::new(
        vec![
            Token::new("hmi", Role::Viewer, VIEWER).unwrap(),
            Token::new("line-plc", Role::Operator, OPERATOR).unwrap(),
            Token::new("cell-plc", Role::Operator, OTHER_OPERATOR).unwrap(),
            Token::new("engineer", Role::Admin, ADMIN).unwrap(),
        ],
        vec![],
        None,
        DEFAULT_BODY_LIMIT,
        2 * DEFAULT_BODY_LIMIT,
    )
    .unwrap()
}

fn uri(what: &str) -> String {
    format!("/api/v1/buses/demo/nodes/1/axes/1{what}")
}

/// A request with `token` and more headers; status and body.
async fn send(
    app: &Router,
    method: Method,
    path: &str,
    token: &str,
    headers: &[(&str, &str)],
    body: Option<Json>,
) -> (StatusCode, Json) {
    let bearer = format!("Bearer {token}");
    let mut all = vec![("authorization", bearer.as_str())];
    all.extend_from_slice(headers);
    let body = body.map(|b| b.to_string());
    let (status, _, json) = send_with_headers(app, method, path, &all, body.as_deref()).await;
    (status, json)
}

async fn velocity(app: &Router) -> i64 {
    let (status, body) = send(app, Method::GET, &uri(""), VIEWER, &[], None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    body["velocity"].as_i64().unwrap()
}

/// Axis 1 turning under a lease of the operator `line-plc`; the router,
/// the state and the lease id.
async fn turning() -> (Router, AppState, String) {
    let (_, state) = demo().await;
    let state = state.with_auth(config()).with_lease_period(PERIOD);
    let app = app(state.clone());
    let (status, body) = send(
        &app,
        Method::POST,
        &uri("/state"),
        OPERATOR,
        &[],
        Some(json!({"target": "operation_enabled"})),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, body) = send(
        &app,
        Method::POST,
        &uri("/move"),
        OPERATOR,
        &[],
        Some(json!({"mode": "velocity", "velocity": 500})),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["lease"]["holder"], "line-plc", "{body}");
    tokio::time::sleep(PERIOD / 4).await;
    assert!(velocity(&app).await > 0);
    (
        app,
        state,
        body["lease"]["id"].as_str().unwrap().to_string(),
    )
}

async fn audit(app: &Router) -> Vec<Json> {
    // Stream renewals are written by a task of their own.
    tokio::time::sleep(Duration::from_millis(10)).await;
    let (status, body) = send(
        app,
        Method::GET,
        "/api/v1/events?kind=audit&limit=1000",
        VIEWER,
        &[],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    body.as_array().unwrap().clone()
}

fn assert_conflict(response: &(StatusCode, Json)) {
    assert_eq!(response.0, StatusCode::CONFLICT, "{}", response.1);
    assert_eq!(
        response.1["error"]["code"], "lease_conflict",
        "{}",
        response.1
    );
}

#[tokio::test(start_paused = true)]
async fn another_token_can_neither_renew_nor_present_a_lease() {
    let (app, _state, id) = turning().await;
    let renew = json!({"lease": id});
    for token in [ADMIN, OTHER_OPERATOR] {
        let refused = send(
            &app,
            Method::POST,
            &uri("/lease"),
            token,
            &[],
            Some(renew.clone()),
        )
        .await;
        assert_conflict(&refused);
        let message = refused.1["error"]["message"].as_str().unwrap();
        assert!(message.contains("held by line-plc"), "{message}");
        assert!(!message.contains(&id), "the id in clear: {message}");
        let refused = send(
            &app,
            Method::POST,
            &uri("/move"),
            token,
            &[("candeck-lease", &id)],
            Some(json!({"mode": "velocity", "velocity": 900})),
        )
        .await;
        assert_conflict(&refused);
        let refused = send(
            &app,
            Method::POST,
            &uri("/halt"),
            token,
            &[("candeck-lease", &id)],
            Some(json!({"halt": false})),
        )
        .await;
        assert_conflict(&refused);
    }
    // The refusals renewed nothing: unrenewed, the lease lapses and the
    // axis is halted.
    tokio::time::sleep(2 * PERIOD + PERIOD / 2).await;
    assert_eq!(velocity(&app).await, 0, "still moving after the lapse");
}

#[tokio::test(start_paused = true)]
async fn the_holder_renews_and_uses_its_lease() {
    let (app, _state, id) = turning().await;
    for _ in 0..4 {
        tokio::time::sleep(PERIOD / 2).await;
        let (status, body) = send(
            &app,
            Method::POST,
            &uri("/lease"),
            OPERATOR,
            &[],
            Some(json!({"lease": id})),
        )
        .await;
        assert_eq!(status, StatusCode::OK, "{body}");
    }
    let (status, body) = send(
        &app,
        Method::POST,
        &uri("/move"),
        OPERATOR,
        &[("candeck-lease", &id)],
        Some(json!({"mode": "velocity", "velocity": 300})),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["lease"]["id"], id.as_str(), "{body}");
    assert!(velocity(&app).await > 0);
}

#[tokio::test(start_paused = true)]
async fn an_explicit_take_over_ends_the_old_lease_and_is_audited_naming_both() {
    let (app, _state, id) = turning().await;
    let (status, body) = send(
        &app,
        Method::POST,
        &uri("/move"),
        ADMIN,
        &[("candeck-lease-takeover", "true")],
        Some(json!({"mode": "velocity", "velocity": 200})),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let new_id = body["lease"]["id"].as_str().unwrap().to_string();
    assert_ne!(new_id, id);
    assert_eq!(body["lease"]["holder"], "engineer", "{body}");
    // The previous holder's moves and renewals are refused from now on.
    let refused = send(
        &app,
        Method::POST,
        &uri("/move"),
        OPERATOR,
        &[("candeck-lease", &id)],
        Some(json!({"mode": "velocity", "velocity": 900})),
    )
    .await;
    assert_conflict(&refused);
    let refused = send(
        &app,
        Method::POST,
        &uri("/lease"),
        OPERATOR,
        &[],
        Some(json!({"lease": id})),
    )
    .await;
    assert_eq!(refused.0, StatusCode::NOT_FOUND, "{}", refused.1);
    // The new holder's lease holds the axis against the old one.
    let refused = send(
        &app,
        Method::POST,
        &uri("/move"),
        OPERATOR,
        &[("candeck-lease", &new_id)],
        Some(json!({"mode": "velocity", "velocity": 900})),
    )
    .await;
    assert_conflict(&refused);
    // A bad header value is a mistake, said as such.
    let (status, body) = send(
        &app,
        Method::POST,
        &uri("/move"),
        ADMIN,
        &[("candeck-lease-takeover", "yes please")],
        Some(json!({"mode": "velocity", "velocity": 200})),
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");

    let entries = audit(&app).await;
    let takeover = entries
        .iter()
        .find(|e| e["who"] == "engineer" && e["status"] == 200)
        .unwrap_or_else(|| panic!("no take-over entry in {entries:#?}"));
    let operation = takeover["operation"].as_str().unwrap();
    assert_eq!(
        operation,
        format!(
            "move; took over the velocity lease {}… of line-plc",
            &id[..4]
        ),
        "{takeover}"
    );
}

#[tokio::test(start_paused = true)]
async fn lease_ids_are_masked_in_the_audit_log_viewers_read() {
    let (app, _state, id) = turning().await;
    let (status, body) = send(
        &app,
        Method::POST,
        &uri("/lease"),
        OPERATOR,
        &[],
        Some(json!({"lease": id})),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let refused = send(
        &app,
        Method::POST,
        &uri("/lease"),
        ADMIN,
        &[],
        Some(json!({"lease": id})),
    )
    .await;
    assert_conflict(&refused);
    let entries = audit(&app).await;
    let renewals: Vec<&Json> = entries
        .iter()
        .filter(|e| e["operation"] == "renew motion lease")
        .collect();
    assert_eq!(renewals.len(), 2, "{entries:#?}");
    for entry in renewals {
        assert_eq!(
            entry["request"],
            format!("{{\"lease\":\"{}…\"}}", &id[..4]),
            "{entry}"
        );
    }
    let all = Json::Array(entries).to_string();
    assert!(!all.contains(&id), "the lease id in clear in {all}");
}

/// A stream session of `identity`: its request sender and its messages.
fn session(
    state: &AppState,
    name: &str,
    role: Role,
) -> (mpsc::Sender<Inbound>, mpsc::Receiver<String>) {
    let (requests, inbound) = mpsc::channel::<Inbound>(4);
    let (outbound, messages) = mpsc::channel::<String>(64);
    let inbound = futures_util::stream::unfold(inbound, |mut rx| async move {
        rx.recv().await.map(|request| (request, rx))
    });
    let sink = futures_util::sink::unfold(outbound, |tx, message: String| async move {
        tx.send(message).await.map(|()| tx)
    });
    let client = Client {
        identity: Identity {
            name: name.to_string(),
            role: Some(role),
        },
        peer: Some("192.0.2.7:40000".to_string()),
    };
    tokio::spawn(run_session_as(
        state.clone(),
        client,
        Box::pin(inbound),
        Box::pin(sink),
    ));
    (requests, messages)
}

async fn renew_on_stream(
    requests: &mpsc::Sender<Inbound>,
    messages: &mut mpsc::Receiver<String>,
    id: &str,
) -> Vec<Json> {
    let renew = json!({"op": "renew", "leases": [id]});
    requests
        .send(Inbound::Text(renew.to_string()))
        .await
        .unwrap();
    let mut replies = vec![serde_json::from_str(&messages.recv().await.unwrap()).unwrap()];
    while let Ok(more) = messages.try_recv() {
        replies.push(serde_json::from_str(&more).unwrap());
    }
    replies
}

#[tokio::test(start_paused = true)]
async fn a_viewer_never_renews_a_lease_over_the_stream() {
    let (app, state, id) = turning().await;
    let (requests, mut messages) = session(&state, "hmi", Role::Viewer);
    // Every half period for four periods: the lease must lapse anyway.
    for _ in 0..8 {
        let replies = renew_on_stream(&requests, &mut messages, &id).await;
        assert_eq!(replies[0], json!({"op": "renewed", "leases": []}));
        assert_eq!(replies[1]["op"], "error", "{replies:?}");
        assert_eq!(replies[1]["error"]["code"], "forbidden", "{replies:?}");
        tokio::time::sleep(PERIOD / 2).await;
    }
    assert_eq!(velocity(&app).await, 0, "a viewer kept the axis moving");
    // Another operator is refused too.
    let (_app, state, id) = turning().await;
    let (requests, mut messages) = session(&state, "cell-plc", Role::Operator);
    let replies = renew_on_stream(&requests, &mut messages, &id).await;
    assert_eq!(replies[1]["error"]["code"], "lease_conflict", "{replies:?}");
}

#[tokio::test(start_paused = true)]
async fn stream_renewals_are_audited_once_per_interval_masked() {
    let (app, state, id) = turning().await;
    let (requests, mut messages) = session(&state, "line-plc", Role::Operator);
    // Every half period for 70 s: 140 renewals.
    for _ in 0..140 {
        let replies = renew_on_stream(&requests, &mut messages, &id).await;
        assert_eq!(replies[0]["leases"][0]["id"], id.as_str(), "{replies:?}");
        tokio::time::sleep(PERIOD / 2).await;
    }
    assert!(velocity(&app).await > 0, "halted while renewed");
    // A viewer's refused attempts, 50 of them: one entry that counts the
    // rest.
    let (viewer, mut viewer_messages) = session(&state, "hmi", Role::Viewer);
    for _ in 0..50 {
        renew_on_stream(&viewer, &mut viewer_messages, &id).await;
    }
    let entries = audit(&app).await;
    let stream: Vec<&Json> = entries
        .iter()
        .filter(|e| e["operation"] == "renew motion lease (stream)")
        .collect();
    let (granted, refused): (Vec<&Json>, Vec<&Json>) =
        stream.iter().partition(|e| e["outcome"] == "ok");
    // The first renewal, then one a minute: at 0 s and 60 s.
    assert_eq!(granted.len(), 2, "{stream:#?}");
    for entry in &granted {
        assert_eq!(entry["who"], "line-plc", "{entry}");
        assert_eq!(entry["channel"], "websocket", "{entry}");
        assert!(entry.get("method").is_none(), "{entry}");
        assert_eq!(entry["axis"], 1, "{entry}");
        assert_eq!(entry["peer"], "192.0.2.7:40000", "{entry}");
        assert_eq!(
            entry["request"],
            format!("{{\"leases\":[\"{}…\"],\"op\":\"renew\"}}", &id[..4]),
            "{entry}"
        );
    }
    assert_eq!(refused.len(), 1, "{stream:#?}");
    assert_eq!(refused[0]["who"], "hmi", "{}", refused[0]);
    assert_eq!(refused[0]["channel"], "websocket", "{}", refused[0]);
    assert_eq!(refused[0]["outcome"], "forbidden", "{}", refused[0]);
    assert_eq!(refused[0]["error_code"], "forbidden", "{}", refused[0]);
    let all = Json::Array(entries).to_string();
    assert!(!all.contains(&id), "the lease id in clear in {all}");
}
