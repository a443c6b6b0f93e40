//! Authentication and roles through the router: the role table against
//! every route, the auth matrix (every route × no token, viewer, operator,
//! admin), refused requests in the audit log, the WebSocket's token, CORS,
//! body limits and the write rate limit on a paused clock.

use std::time::Duration;

use axum::Router;
use axum::http::{Method, StatusCode, header};
use serde_json::Value as Json;

use crate::api::auth::{
    AuthConfig, DEFAULT_BODY_LIMIT, FALLBACK, ROUTES, RateLimit, Role, Token, route_entry,
};
use crate::api::tests::support::send_with_headers as send;
use crate::api::{AppState, app, routers};

const VIEWER: &str = "v1ewer-0123456789abcdef";
const OPERATOR: &str = "0perator-0123456789abcdef";
const ADMIN: &str = "adm1n-0123456789abcdef";

fn config(rate_limit: Option<RateLimit>) -> AuthConfig {
    AuthConfig::new(
        vec![
            Token::new("hmi", Role::Viewer, VIEWER).unwrap(),
            Token::new("line-plc", Role::Operator, OPERATOR).unwrap(),
            Token::new("engineer", Role::Admin, ADMIN).unwrap(),
        ],
        vec!["https://scada.example".to_string()],
        rate_limit,
        DEFAULT_BODY_LIMIT,
        2 * DEFAULT_BODY_LIMIT,
    )
    .unwrap()
}

/// A gateway with no bus (every bus route answers 404 after the guard,
/// and nothing moves), with the three tokens.
fn gateway(rate_limit: Option<RateLimit>) -> Router {
    app(AppState::new([]).with_auth(config(rate_limit)))
}

fn bearer(token: &str) -> String {
    format!("Bearer {token}")
}

/// A path of `pattern` with every parameter filled in.
fn concrete(pattern: &str) -> String {
    pattern
        .split('/')
        .map(|segment| match segment {
            "{bus}" => "nobus".to_string(),
            "{index}" => "0x1008".to_string(),
            "{sub}" => "0".to_string(),
            "{kind}" => "tpdo".to_string(),
            "{version}" => crate::web::static_version().to_string(),
            "{*path}" => "js/api.js".to_string(),
            s if s.starts_with("{*") => "x".to_string(),
            s if s.starts_with('{') => "1".to_string(),
            s => s.to_string(),
        })
        .collect::<Vec<_>>()
        .join("/")
}

#[test]
fn every_route_of_the_router_has_an_entry_in_the_role_table() {
    let (_, doc) = routers(AppState::new([]));
    let mut checked = 0;
    for (path, item) in &doc.paths.paths {
        let methods = [
            ("GET", item.get.is_some()),
            ("PUT", item.put.is_some()),
            ("POST", item.post.is_some()),
            ("DELETE", item.delete.is_some()),
            ("PATCH", item.patch.is_some()),
        ];
        for (method, present) in methods {
            if !present {
                continue;
            }
            let method: Method = method.parse().unwrap();
            assert!(
                route_entry(&method, path).is_some(),
                "{method} {path} has no entry in auth::ROUTES: add one line there"
            );
            checked += 1;
        }
    }
    assert!(checked > 40, "{checked} routes only");
    // The routes outside the OpenAPI document.
    for path in [
        "/",
        "/api/openapi.json",
        "/api/docs",
        "/api/docs/index.html",
    ] {
        assert!(route_entry(&Method::GET, path).is_some(), "{path}");
    }
}

/// What each entry of the role table answers to no token, a viewer, an
/// operator and an admin: 401, 403, or anything else (the handler's 404,
/// 400, 426...: the guard let it through).
#[tokio::test(start_paused = true)]
async fn the_auth_matrix_follows_the_role_table() {
    let app = gateway(None);
    let tokens = [
        (None, None),
        (Some(VIEWER), Some(Role::Viewer)),
        (Some(OPERATOR), Some(Role::Operator)),
        (Some(ADMIN), Some(Role::Admin)),
    ];
    for (method, pattern, access) in ROUTES.iter().chain(FALLBACK) {
        let method: Method = if *method == "*" { "POST" } else { method }
            .parse()
            .unwrap();
        let path = concrete(pattern);
        let body = (method != Method::GET && method != Method::DELETE).then_some("{}");
        for (token, role) in tokens {
            let auth = token.map(bearer);
            let headers: Vec<(&str, &str)> = auth
                .as_deref()
                .map(|value| ("authorization", value))
                .into_iter()
                .collect();
            let (status, response_headers, json) =
                send(&app, method.clone(), &path, &headers, body).await;
            let who = role.map_or("no token", Role::name);
            match (access.role(), role) {
                (None, _) => assert!(
                    status != StatusCode::UNAUTHORIZED && status != StatusCode::FORBIDDEN,
                    "{method} {path}, {who}: {status} {json}"
                ),
                (Some(_), None) => {
                    assert_eq!(status, StatusCode::UNAUTHORIZED, "{method} {path}: {json}");
                    assert_eq!(json["error"]["code"], "unauthenticated");
                    assert!(
                        response_headers[header::WWW_AUTHENTICATE]
                            .to_str()
                            .unwrap()
                            .starts_with("Bearer"),
                        "{response_headers:?}"
                    );
                }
                (Some(needed), Some(role)) if role < needed => {
                    assert_eq!(
                        status,
                        StatusCode::FORBIDDEN,
                        "{method} {path}, {who}: {json}"
                    );
                    assert_eq!(json["error"]["code"], "forbidden");
                }
                (Some(_), Some(_)) => assert!(
                    status != StatusCode::UNAUTHORIZED && status != StatusCode::FORBIDDEN,
                    "{method} {path}, {who}: {status} {json}"
                ),
            }
        }
    }
    // A token nobody configured is no token.
    let (status, _, json) = send(
        &app,
        Method::GET,
        "/api/v1/buses",
        &[("authorization", "Bearer not-a-token-of-this-gateway")],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::UNAUTHORIZED, "{json}");
}

#[tokio::test(start_paused = true)]
async fn whoami_names_the_token_and_says_whether_tokens_are_required() {
    let app = gateway(None);
    let auth = bearer(OPERATOR);
    let (status, _, json) = send(
        &app,
        Method::GET,
        "/api/v1/auth/whoami",
        &[("authorization", &auth)],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(
        json,
        serde_json::json!({"name": "line-plc", "role": "operator", "auth_required": true})
    );
    let open = app_open();
    let (status, _, json) = send(&open, Method::GET, "/api/v1/auth/whoami", &[], None).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(
        json,
        serde_json::json!({"name": "anonymous", "role": "admin", "auth_required": false})
    );
}

fn app_open() -> Router {
    app(AppState::new([]))
}

#[tokio::test(start_paused = true)]
async fn refused_requests_are_audited_with_who_tried() {
    let app = gateway(None);
    let scan = "/api/v1/buses/nobus/scan";
    let viewer = bearer(VIEWER);
    let operator = bearer(OPERATOR);
    send(&app, Method::POST, scan, &[], Some("{}")).await;
    send(
        &app,
        Method::POST,
        scan,
        &[("authorization", "Bearer forged-0123456789abcdef")],
        Some("{}"),
    )
    .await;
    send(
        &app,
        Method::POST,
        scan,
        &[("authorization", &viewer)],
        Some("{}"),
    )
    .await;
    send(
        &app,
        Method::POST,
        scan,
        &[("authorization", &operator)],
        Some("{}"),
    )
    .await;
    let admin = bearer(ADMIN);
    let (status, _, events) = send(
        &app,
        Method::GET,
        "/api/v1/events?kind=audit",
        &[("authorization", &admin)],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{events}");
    // Oldest first.
    let seen: Vec<(String, String, u64, String)> = events
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["who"].as_str().unwrap().to_string(),
                e["role"].as_str().unwrap().to_string(),
                e["status"].as_u64().unwrap(),
                e["error_code"].as_str().unwrap_or("").to_string(),
            )
        })
        .collect();
    let expected = [
        ("anonymous", "none", 401, "unauthenticated"),
        ("invalid-token", "none", 401, "unauthenticated"),
        ("hmi", "viewer", 403, "forbidden"),
        ("line-plc", "operator", 404, "unknown_bus"),
    ];
    let expected: Vec<(String, String, u64, String)> = expected
        .iter()
        .map(|(w, r, s, c)| (w.to_string(), r.to_string(), *s, c.to_string()))
        .collect();
    assert_eq!(seen, expected, "{events:#}");
    // The secret itself is never written anywhere in the log.
    assert!(!events.to_string().contains("forged-0123456789abcdef"));
    assert!(!events.to_string().contains(OPERATOR));
}

/// Issue 21: the bus tools (SYNC, a raw frame, an RPDO sent) are the
/// operator's and the admin's, not a viewer's, and audited with who sent.
#[tokio::test(start_paused = true)]
async fn the_bus_tools_are_an_operators_and_audited() {
    let app = gateway(None);
    let tools = [
        (
            Method::PUT,
            "/api/v1/buses/nobus/sync",
            r#"{"period_ms":0}"#,
        ),
        (
            Method::POST,
            "/api/v1/buses/nobus/frames",
            r#"{"id":"0x7FF","data":""}"#,
        ),
        (
            Method::POST,
            "/api/v1/buses/nobus/nodes/1/pdos/rpdo/1/send",
            r#"{"values":{}}"#,
        ),
    ];
    for (method, path, body) in &tools {
        for (token, allowed) in [(VIEWER, false), (OPERATOR, true), (ADMIN, true)] {
            let auth = bearer(token);
            let (status, _, json) = send(
                &app,
                method.clone(),
                path,
                &[("authorization", &auth)],
                Some(body),
            )
            .await;
            if allowed {
                // Through the guard: the handler's answer (no such bus).
                assert_eq!(status, StatusCode::NOT_FOUND, "{method} {path}: {json}");
                assert_eq!(json["error"]["code"], "unknown_bus", "{json}");
            } else {
                assert_eq!(status, StatusCode::FORBIDDEN, "{method} {path}: {json}");
            }
        }
    }
    let admin = bearer(ADMIN);
    let (_, _, events) = send(
        &app,
        Method::GET,
        "/api/v1/events?kind=audit&limit=100",
        &[("authorization", &admin)],
        None,
    )
    .await;
    for (method, path, _) in &tools {
        let by_operator = events.as_array().unwrap().iter().any(|e| {
            e["who"] == "line-plc"
                && e["role"] == "operator"
                && e["method"] == method.as_str()
                && e["path"] == *path
        });
        assert!(by_operator, "{method} {path} not audited: {events:#}");
    }
}

#[tokio::test(start_paused = true)]
async fn cors_preflights_are_answered_for_listed_origins_only() {
    let app = gateway(None);
    let preflight = |origin: &'static str| {
        [
            ("origin", origin),
            ("access-control-request-method", "PUT"),
            (
                "access-control-request-headers",
                "authorization, content-type",
            ),
        ]
    };
    let path = "/api/v1/buses/demo/nodes/1/od/0x6040/0";
    let (status, headers, _) = send(
        &app,
        Method::OPTIONS,
        path,
        &preflight("https://scada.example"),
        None,
    )
    .await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    assert_eq!(
        headers[header::ACCESS_CONTROL_ALLOW_ORIGIN],
        "https://scada.example"
    );
    assert!(
        headers[header::ACCESS_CONTROL_ALLOW_HEADERS]
            .to_str()
            .unwrap()
            .contains("authorization")
    );
    let (status, headers, json) = send(
        &app,
        Method::OPTIONS,
        path,
        &preflight("https://evil.example"),
        None,
    )
    .await;
    assert_eq!(status, StatusCode::FORBIDDEN, "{json}");
    assert_eq!(json["error"]["code"], "forbidden");
    assert!(!headers.contains_key(header::ACCESS_CONTROL_ALLOW_ORIGIN));
    // A listed origin's real request gets its CORS header.
    let viewer = bearer(VIEWER);
    let (status, headers, _) = send(
        &app,
        Method::GET,
        "/api/v1/buses",
        &[
            ("authorization", &viewer),
            ("origin", "https://scada.example"),
        ],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(
        headers[header::ACCESS_CONTROL_ALLOW_ORIGIN],
        "https://scada.example"
    );
    // An open gateway without an allow-list answers no CORS at all.
    let open = app_open();
    let (status, _, _) = send(
        &open,
        Method::OPTIONS,
        path,
        &preflight("https://scada.example"),
        None,
    )
    .await;
    assert_eq!(status, StatusCode::FORBIDDEN);
    let (status, headers, _) = send(
        &open,
        Method::GET,
        "/api/v1/buses",
        &[("origin", "https://scada.example")],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    assert!(!headers.contains_key(header::ACCESS_CONTROL_ALLOW_ORIGIN));
}

#[tokio::test(start_paused = true)]
async fn an_open_gateway_refuses_writes_from_other_web_pages_and_audits_them() {
    let app = app_open();
    let nmt = "/api/v1/buses/nobus/nmt";
    let body = Some(r#"{"command":"start"}"#);
    let (status, _, json) = send(
        &app,
        Method::POST,
        nmt,
        &[
            ("host", "127.0.0.1:8080"),
            ("origin", "https://evil.example"),
        ],
        body,
    )
    .await;
    assert_eq!(status, StatusCode::FORBIDDEN, "{json}");
    assert_eq!(json["error"]["code"], "forbidden");
    // A WebSocket from another page is refused too: browsers apply no CORS
    // to WebSockets.
    let (status, _, _) = send(
        &app,
        Method::GET,
        "/api/v1/stream",
        &[
            ("host", "127.0.0.1:8080"),
            ("origin", "https://evil.example"),
            ("upgrade", "websocket"),
        ],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::FORBIDDEN);
    // The gateway's own pages, and programs that send no Origin, pass.
    for headers in [
        &[
            ("host", "127.0.0.1:8080"),
            ("origin", "http://127.0.0.1:8080"),
        ][..],
        &[("host", "127.0.0.1:8080")][..],
    ] {
        let (status, _, json) = send(&app, Method::POST, nmt, headers, body).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{json}");
    }
    let (_, _, events) = send(&app, Method::GET, "/api/v1/events?kind=audit", &[], None).await;
    let statuses: Vec<u64> = events
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["status"].as_u64().unwrap())
        .collect();
    assert_eq!(statuses, [403, 404, 404], "{events:#}");
}

#[tokio::test(start_paused = true)]
async fn bodies_over_the_limit_are_413_in_the_apis_shape() {
    let config = AuthConfig::new(Vec::new(), Vec::new(), None, 100, 1000).unwrap();
    let app = app(AppState::new([]).with_auth(config));
    let big = format!("{{\"value\":\"{}\"}}", "x".repeat(200));
    let length = big.len().to_string();
    let od = "/api/v1/buses/nobus/nodes/1/od/0x1008/0";
    // Without Content-Length (read and cut) and with it (refused unread).
    for headers in [&[][..], &[("content-length", length.as_str())][..]] {
        let (status, _, json) = send(&app, Method::PUT, od, headers, Some(&big)).await;
        assert_eq!(status, StatusCode::PAYLOAD_TOO_LARGE, "{json}");
        assert_eq!(json["error"]["code"], "payload_too_large");
        // The batch read is no write, and has the same limit.
        let read = "/api/v1/buses/nobus/nodes/1/od/read";
        let (status, _, json) = send(&app, Method::POST, read, headers, Some(&big)).await;
        assert_eq!(status, StatusCode::PAYLOAD_TOO_LARGE, "{json}");
        assert_eq!(json["error"]["code"], "payload_too_large");
    }
    // A DCF may be larger.
    let dcf = "/api/v1/buses/nobus/nodes/1/config.dcf";
    let (status, _, json) = send(&app, Method::PUT, dcf, &[], Some(&big)).await;
    assert_eq!(status, StatusCode::NOT_FOUND, "{json}");
}

#[tokio::test(start_paused = true)]
async fn writes_beyond_the_token_rate_are_429_until_the_bucket_refills() {
    let app = gateway(Some(RateLimit {
        per_second: 2.0,
        burst: 3,
    }));
    let plc = bearer(OPERATOR);
    let viewer = bearer(VIEWER);
    let scan = "/api/v1/buses/nobus/scan";
    let auth = [("authorization", plc.as_str())];
    for _ in 0..3 {
        let (status, _, json) = send(&app, Method::POST, scan, &auth, Some("{}")).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{json}");
    }
    let (status, headers, json) = send(&app, Method::POST, scan, &auth, Some("{}")).await;
    assert_eq!(status, StatusCode::TOO_MANY_REQUESTS, "{json}");
    assert_eq!(json["error"]["code"], "rate_limited");
    assert_eq!(headers[header::RETRY_AFTER], "1");
    // Reads are not limited, other tokens have buckets of their own, and a
    // stop is never refused for the rate.
    let (status, _, _) = send(&app, Method::GET, "/api/v1/buses", &auth, None).await;
    assert_eq!(status, StatusCode::OK);
    let other = [("authorization", viewer.as_str())];
    let (status, _, _) = send(&app, Method::POST, "/api/v1/stop-all", &other, Some("{}")).await;
    assert_eq!(status, StatusCode::OK);
    for _ in 0..3 {
        let (status, _, _) = send(&app, Method::POST, "/api/v1/stop-all", &auth, Some("{}")).await;
        assert_eq!(status, StatusCode::OK);
    }
    // Nor a halt or a walk out of operation enabled (found by the
    // re-probe of issue 19: an operator whose bucket was spent could not
    // halt its axis). No bus here: past the guard, 404.
    let axis = "/api/v1/buses/nobus/nodes/1/axes/1";
    for (what, body) in [
        ("/halt", r#"{"halt":true}"#),
        ("/state", r#"{"target":"quick_stop_active"}"#),
        ("/state", r#"{"target":"switch_on_disabled"}"#),
    ] {
        let path = format!("{axis}{what}");
        let (status, _, json) = send(&app, Method::POST, &path, &auth, Some(body)).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{path} {body}: {json}");
    }
    // What starts motion still draws on the bucket.
    for (what, body) in [
        ("/halt", r#"{"halt":false}"#),
        ("/state", r#"{"target":"operation_enabled"}"#),
    ] {
        let path = format!("{axis}{what}");
        let (status, _, json) = send(&app, Method::POST, &path, &auth, Some(body)).await;
        assert_eq!(
            status,
            StatusCode::TOO_MANY_REQUESTS,
            "{path} {body}: {json}"
        );
    }
    // Half a second gives one write back (2 per second).
    tokio::time::advance(Duration::from_millis(499)).await;
    let (status, _, _) = send(&app, Method::POST, scan, &auth, Some("{}")).await;
    assert_eq!(status, StatusCode::TOO_MANY_REQUESTS);
    tokio::time::advance(Duration::from_millis(2)).await;
    let (status, _, _) = send(&app, Method::POST, scan, &auth, Some("{}")).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let (status, _, _) = send(&app, Method::POST, scan, &auth, Some("{}")).await;
    assert_eq!(status, StatusCode::TOO_MANY_REQUESTS);
}

/// The stream over a real socket: a token as `Authorization` (programs)
/// or as a subprotocol (browsers), and none.
#[tokio::test]
async fn the_stream_needs_a_token_as_a_header_or_a_subprotocol() {
    use tokio_tungstenite::tungstenite::client::IntoClientRequest;
    use tokio_tungstenite::tungstenite::{Error as WsError, Message};

    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap();
    let server = tokio::spawn(axum::serve(listener, gateway(None)).into_future());
    let url = format!("ws://{address}/api/v1/stream");

    let refused = tokio_tungstenite::connect_async(&url).await.unwrap_err();
    match refused {
        WsError::Http(response) => assert_eq!(response.status(), 401),
        other => panic!("{other:?}"),
    }

    let mut request = url.as_str().into_client_request().unwrap();
    let protocols = format!("candeck.v1, bearer.{VIEWER}");
    request
        .headers_mut()
        .insert("sec-websocket-protocol", protocols.parse().unwrap());
    let (mut socket, response) = tokio_tungstenite::connect_async(request).await.unwrap();
    // Only our protocol comes back, never the token.
    assert_eq!(response.headers()["sec-websocket-protocol"], "candeck.v1");
    use futures_util::{SinkExt, StreamExt};
    socket
        .send(Message::text(r#"{"op":"subscribe","topics":["nodes"]}"#))
        .await
        .unwrap();
    let answer = socket.next().await.unwrap().unwrap();
    let answer: Json = serde_json::from_str(answer.to_text().unwrap()).unwrap();
    assert_eq!(answer["op"], "subscribed", "{answer}");

    let mut request = url.as_str().into_client_request().unwrap();
    request
        .headers_mut()
        .insert("authorization", bearer(VIEWER).parse().unwrap());
    assert!(tokio_tungstenite::connect_async(request).await.is_ok());

    let mut request = url.as_str().into_client_request().unwrap();
    request.headers_mut().insert(
        "sec-websocket-protocol",
        "candeck.v1, bearer.wrong-0123456789abcdef".parse().unwrap(),
    );
    match tokio_tungstenite::connect_async(request).await.unwrap_err() {
        WsError::Http(response) => assert_eq!(response.status(), 401),
        other => panic!("{other:?}"),
    }
    server.abort();
}

/// Issue 30, finding 8: the `bearer.` subprotocol is a token for a
/// WebSocket upgrade only: a plain request naming it is unauthenticated.
#[tokio::test(start_paused = true)]
async fn the_bearer_subprotocol_authenticates_websocket_upgrades_only() {
    let app = gateway(None);
    let protocols = format!("candeck.v1, bearer.{ADMIN}");
    for (method, path) in [
        (Method::POST, "/api/v1/stop-all"),
        (Method::GET, "/api/v1/auth/whoami"),
        (Method::GET, "/api/v1/buses"),
    ] {
        let (status, _, json) = send(
            &app,
            method.clone(),
            path,
            &[("sec-websocket-protocol", &protocols)],
            None,
        )
        .await;
        assert_eq!(status, StatusCode::UNAUTHORIZED, "{method} {path}: {json}");
    }
    // Nor a POST that says it upgrades: a WebSocket opens with a GET.
    let (status, _, json) = send(
        &app,
        Method::POST,
        "/api/v1/stop-all",
        &[
            ("sec-websocket-protocol", &protocols),
            ("upgrade", "websocket"),
            ("connection", "upgrade"),
        ],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::UNAUTHORIZED, "{json}");
}

/// Issue 30, finding 7: a token, and a peer address, hold at most their
/// number of streams; one more is answered 429 `too_many_streams` before
/// the upgrade, a closed stream gives its place back, and REST answers
/// throughout.
#[tokio::test]
async fn streams_are_limited_per_token_and_per_peer() {
    use crate::api::stream::StreamLimits;
    use tokio_tungstenite::tungstenite::Error as WsError;
    use tokio_tungstenite::tungstenite::client::IntoClientRequest;

    let state = AppState::new([])
        .with_auth(config(None))
        .with_stream_limits(StreamLimits::new(2, 3).unwrap());
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap();
    let server = tokio::spawn(
        axum::serve(
            listener,
            app(state).into_make_service_with_connect_info::<std::net::SocketAddr>(),
        )
        .into_future(),
    );
    let url = format!("ws://{address}/api/v1/stream");
    let open = |token: &'static str| {
        let mut request = url.as_str().into_client_request().unwrap();
        request
            .headers_mut()
            .insert("authorization", bearer(token).parse().unwrap());
        tokio_tungstenite::connect_async(request)
    };
    let refused = |result: Result<_, WsError>| match result {
        Ok(_) => panic!("a stream beyond the limit was opened"),
        Err(WsError::Http(response)) => {
            assert_eq!(response.status(), 429);
            let body = response.body().as_deref().unwrap_or_default();
            let body: Json = serde_json::from_slice(body).unwrap();
            assert_eq!(body["error"]["code"], "too_many_streams", "{body}");
            body["error"]["message"].as_str().unwrap().to_string()
        }
        Err(other) => panic!("{other:?}"),
    };
    let (first, _) = open(VIEWER).await.unwrap();
    let (_second, _) = open(VIEWER).await.unwrap();
    let message = refused(open(VIEWER).await);
    assert!(message.contains("stream_max_per_token"), "{message}");
    // Another token from the same address: the address's limit (3).
    let (_third, _) = open(OPERATOR).await.unwrap();
    let message = refused(open(OPERATOR).await);
    assert!(message.contains("stream_max_per_peer"), "{message}");
    // REST still answers.
    {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut rest = tokio::net::TcpStream::connect(address).await.unwrap();
        let request = format!(
            "GET /api/v1/buses HTTP/1.1\r\nHost: {address}\r\nAuthorization: {}\r\nConnection: close\r\n\r\n",
            bearer(VIEWER)
        );
        rest.write_all(request.as_bytes()).await.unwrap();
        let mut answer = String::new();
        tokio::time::timeout(Duration::from_secs(10), rest.read_to_string(&mut answer))
            .await
            .expect("REST answers within 10 s")
            .unwrap();
        assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    }
    // A closed stream gives its place back.
    drop(first);
    let mut reopened = None;
    for _ in 0..100 {
        if let Ok(stream) = open(VIEWER).await {
            reopened = Some(stream);
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(reopened.is_some(), "no place after a stream closed");
    server.abort();
}
