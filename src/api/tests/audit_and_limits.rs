//! Issue 19, points 7 and 10, through the router: one write rate limit for
//! REST and CiA 309-5, refusals audited with the token that was refused,
//! unknown body fields refused, the batch read capped, and the docs UI
//! public.

use axum::Router;
use axum::body::Body;
use axum::http::{Method, Request, StatusCode};
use serde_json::{Value as Json, json};
use tower::ServiceExt;

use super::support::{self, assert_error, send_with_headers};
use crate::api::auth::{AuthConfig, RateLimit, Role, Token};
use crate::api::{AppState, app};

const VIEWER: &str = "v1ewer-0123456789abcdef";
const OPERATOR: &str = "0perator-0123456789abcdef";
const ADMIN: &str = "adm1n-0123456789abcdef";

fn config(rate_limit: Option<RateLimit>, body_limit: usize) -> AuthConfig {
    AuthConfig::new(
        vec![
            Token::new("hmi", Role::Viewer, VIEWER).unwrap(),
            Token::new("line-plc", Role::Operator, OPERATOR).unwrap(),
            Token::new("engineer", Role::Admin, ADMIN).unwrap(),
        ],
        Vec::new(),
        rate_limit,
        body_limit,
        body_limit,
    )
    .unwrap()
}

/// A gateway without buses, with the three tokens.
fn gateway(rate_limit: Option<RateLimit>, body_limit: usize) -> Router {
    app(AppState::new([]).with_auth(config(rate_limit, body_limit)))
}

/// One request with a bearer token (when given) and these headers; the
/// status and the body as JSON (`null` when it is none).
async fn send(
    app: &Router,
    method: Method,
    path: &str,
    token: Option<&str>,
    headers: &[(&str, &str)],
    body: Option<&str>,
) -> (StatusCode, Json) {
    let authorization = token.map(|token| format!("Bearer {token}"));
    let mut all: Vec<(&str, &str)> = authorization
        .iter()
        .map(|value| ("authorization", value.as_str()))
        .collect();
    all.extend_from_slice(headers);
    let (status, _, json) = send_with_headers(app, method, path, &all, body).await;
    (status, json)
}

/// The audit log, oldest first.
async fn audit(app: &Router) -> Vec<Json> {
    let (status, events) = send(
        app,
        Method::GET,
        "/api/v1/events?kind=audit",
        Some(ADMIN),
        &[],
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{events}");
    events.as_array().unwrap().clone()
}

/// CiA 309-5 writes and NMT commands draw on the token's write rate, the
/// same bucket as its REST writes, and are refused with REST's 429 (they
/// used to pass, however many: 100 of 100).
#[tokio::test(start_paused = true)]
async fn cia309_5_commands_share_the_rest_write_rate() {
    // The gateway's object operations take the writes (issue 29): on the
    // demo bus, so that they run.
    let served = support::open("demo", "virtual:demo").await;
    assert_eq!(served.scan().await.unwrap().len(), 3);
    let config = config(
        Some(RateLimit {
            per_second: 1.0,
            burst: 3,
        }),
        crate::api::auth::DEFAULT_BODY_LIMIT,
    );
    let app = app(AppState::new([served]).with_auth(config));
    let write = "/cia309-5/1.0/7/1/1/w/0x1017/0";
    let body = Some(r#"{"value":"1000","datatype":"u16"}"#);
    // Two through 309-5, one through REST: the bucket of 3 is empty.
    for _ in 0..2 {
        let (status, json) = send(&app, Method::PUT, write, Some(OPERATOR), &[], body).await;
        assert_eq!(status, StatusCode::OK, "{json}");
        assert_eq!(json["sequence"], "7", "{json}");
        assert_eq!(json["response"], "OK", "{json}");
    }
    let scan = "/api/v1/buses/nobus/scan";
    let (status, _) = send(&app, Method::POST, scan, Some(OPERATOR), &[], Some("{}")).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let refused = send(&app, Method::PUT, write, Some(OPERATOR), &[], body).await;
    assert_error(&refused, StatusCode::TOO_MANY_REQUESTS, "rate_limited");
    let nmt = "/cia309-5/1.0/8/1/0/start";
    let refused = send(&app, Method::POST, nmt, Some(OPERATOR), &[], None).await;
    assert_error(&refused, StatusCode::TOO_MANY_REQUESTS, "rate_limited");
    // Reads are not writes; another token has its own bucket.
    let read = "/cia309-5/1.0/9/1/1/r/0x1017/0";
    let (status, _) = send(&app, Method::GET, read, Some(OPERATOR), &[], None).await;
    assert_eq!(status, StatusCode::OK);
    let (status, _) = send(&app, Method::PUT, write, Some(ADMIN), &[], body).await;
    assert_eq!(status, StatusCode::OK);
    // One second gives one write back.
    tokio::time::advance(std::time::Duration::from_millis(1001)).await;
    let (status, _) = send(&app, Method::PUT, write, Some(OPERATOR), &[], body).await;
    assert_eq!(status, StatusCode::OK);
    // The refused ones are audited, with who was refused.
    let refused: Vec<_> = audit(&app)
        .await
        .into_iter()
        .filter(|entry| entry["outcome"] == "rate_limited")
        .collect();
    assert_eq!(refused.len(), 2, "{refused:?}");
    for entry in refused {
        assert_eq!(entry["who"], "line-plc", "{entry}");
        assert_eq!(entry["channel"], "cia309_5", "{entry}");
        assert_eq!(entry["error_code"], "rate_limited", "{entry}");
    }
}

/// A body too large, or a write from a foreign web page, sent with a valid
/// token: the audit log names the token, not `anonymous`.
#[tokio::test(start_paused = true)]
async fn refusals_before_the_role_check_are_audited_as_the_token() {
    let app = gateway(None, 100);
    let od = "/api/v1/buses/nobus/nodes/1/od/0x1017/0";
    let big = format!(r#"{{"value":"{}"}}"#, "x".repeat(200));
    let length = big.len().to_string();
    for headers in [&[][..], &[("content-length", length.as_str())][..]] {
        let refused = send(&app, Method::PUT, od, Some(OPERATOR), headers, Some(&big)).await;
        assert_error(&refused, StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large");
    }
    let nmt = "/api/v1/buses/nobus/nmt";
    let foreign = [
        ("host", "127.0.0.1:8080"),
        ("origin", "https://evil.example"),
    ];
    let refused = send(
        &app,
        Method::POST,
        nmt,
        Some(OPERATOR),
        &foreign,
        Some(r#"{"command":"stop"}"#),
    )
    .await;
    assert_error(&refused, StatusCode::FORBIDDEN, "forbidden");
    let seen: Vec<(String, String, u64)> = audit(&app)
        .await
        .iter()
        .map(|e| {
            (
                e["who"].as_str().unwrap().to_string(),
                e["role"].as_str().unwrap().to_string(),
                e["status"].as_u64().unwrap(),
            )
        })
        .collect();
    let plc = |status| ("line-plc".to_string(), "operator".to_string(), status);
    assert_eq!(seen, [plc(413), plc(413), plc(403)]);
}

/// Unknown fields of a request body are refused with 400 in the API's
/// shape, naming the field, on every body type (`{"inhibit_time":50}`
/// used to answer 200 and change nothing).
#[tokio::test(start_paused = true)]
async fn unknown_body_fields_are_refused_naming_the_field() {
    let (app, _) = support::demo().await;
    let node = "/api/v1/buses/demo/nodes/1";
    let cases: &[(Method, String, Json)] = &[
        (
            Method::PUT,
            format!("{node}/pdos/tpdo/1"),
            json!({"inhibit_time": 50}),
        ),
        (
            Method::PUT,
            format!("{node}/pdos/tpdo/1"),
            json!({"mapping": [{"index": "0x6041", "length": 16}]}),
        ),
        (
            Method::PUT,
            format!("{node}/od/0x1017/0"),
            json!({"value": 100, "datatype": "u16"}),
        ),
        (
            Method::POST,
            format!("{node}/od/read"),
            json!({"entries": [["0x1017", 0]], "limit": 1}),
        ),
        (
            Method::POST,
            format!("{node}/nmt"),
            json!({"command": "start", "node": 2}),
        ),
        (
            Method::POST,
            format!("{node}/pdos/rpdo/1/send"),
            json!({"values": {}, "sync": true}),
        ),
        (
            Method::POST,
            format!("{node}/axes/1/move"),
            json!({"mode": "velocity", "velocity": 10, "ramp": 5}),
        ),
        (
            Method::PUT,
            "/api/v1/buses/demo/sync".to_string(),
            json!({"period_ms": 0, "cob_id": 128}),
        ),
    ];
    for (method, path, body) in cases {
        let field = [
            "inhibit_time",
            "length",
            "datatype",
            "limit",
            "node",
            "sync",
            "ramp",
            "cob_id",
        ]
        .into_iter()
        .find(|field| body.to_string().contains(&format!("\"{field}\"")))
        .unwrap();
        let response = support::call(&app, method.clone(), path, Some(body.clone())).await;
        assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
        let message = response.1["error"]["message"].as_str().unwrap();
        assert!(message.contains(field), "{method} {path}: {message}");
    }
    // The same bodies without the stranger pass.
    let (status, json) =
        support::put(&app, &format!("{node}/od/0x1017/0"), json!({"value": 100})).await;
    assert_eq!(status, StatusCode::OK, "{json}");
}

/// Every JSON request body of the OpenAPI document is a closed object
/// (`additionalProperties: false`): the document says what the code does,
/// and a new body type that takes anything fails here.
#[test]
fn every_request_body_schema_refuses_unknown_fields() {
    let (_, doc) = crate::api::routers(AppState::new([]));
    let doc = serde_json::to_value(&doc).unwrap();
    let schemas = &doc["components"]["schemas"];
    let resolve = |schema: &Json| -> Json {
        match schema["$ref"].as_str() {
            Some(reference) => {
                let name = reference.rsplit('/').next().unwrap();
                schemas[name].clone()
            }
            None => schema.clone(),
        }
    };
    fn closed(schema: &Json, resolve: &dyn Fn(&Json) -> Json, at: &str) {
        let schema = resolve(schema);
        // A tagged enum (the move body): serde's `deny_unknown_fields` on
        // the enum closes every variant, which utoipa does not write; the
        // test above sends one an unknown field.
        if schema.get("oneOf").is_some() {
            return;
        }
        if schema["type"] == "object" && schema.get("properties").is_some() {
            assert_eq!(
                schema["additionalProperties"],
                json!(false),
                "{at}: {schema:#}"
            );
            for property in schema["properties"].as_object().unwrap().values() {
                let property = resolve(property);
                if property["type"] == "array" {
                    closed(&property["items"], resolve, at);
                }
            }
        }
    }
    let mut bodies = 0;
    for (path, item) in doc["paths"].as_object().unwrap() {
        for (method, operation) in item.as_object().unwrap() {
            let Some(schema) =
                operation["requestBody"]["content"]["application/json"].get("schema")
            else {
                continue;
            };
            closed(schema, &resolve, &format!("{method} {path}"));
            bodies += 1;
        }
    }
    assert!(bodies >= 15, "{bodies} JSON request bodies only");
}

/// A batch read takes at most 256 entries: each is an SDO transfer that
/// the node's other clients wait behind.
#[tokio::test(start_paused = true)]
async fn a_batch_read_of_more_than_256_entries_is_refused() {
    let (app, _) = support::demo().await;
    let read = "/api/v1/buses/demo/nodes/3/od/read";
    let entries = |n: usize| json!({ "entries": vec![json!(["0x1017", 0]); n] });
    let (status, json) = support::post(&app, read, entries(257)).await;
    // (Not the body in the message: 257 results when it is not refused.)
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert_eq!(
        json["error"]["code"], "too_many_entries",
        "{}",
        json["error"]
    );
    let (status, json) = support::post(&app, read, entries(3)).await;
    assert_eq!(status, StatusCode::OK, "{json}");
    assert_eq!(json.as_array().unwrap().len(), 3, "{json}");
}

/// The docs UI and the OpenAPI document are public, as the docs say: the
/// document holds no data and no secret.
#[tokio::test(start_paused = true)]
async fn the_docs_ui_and_the_openapi_document_need_no_token() {
    let app = gateway(None, crate::api::auth::DEFAULT_BODY_LIMIT);
    for path in ["/api/docs/", "/api/docs/index.html", "/api/openapi.json"] {
        let request = Request::builder().uri(path).body(Body::empty()).unwrap();
        let response = app.clone().oneshot(request).await.unwrap();
        assert_eq!(response.status(), StatusCode::OK, "{path}");
    }
    // `/api/docs` sends the browser to `/api/docs/`.
    let request = Request::builder()
        .uri("/api/docs")
        .body(Body::empty())
        .unwrap();
    let response = app.clone().oneshot(request).await.unwrap();
    assert!(response.status().is_redirection(), "{}", response.status());
    // The API itself still asks for one.
    let (status, _) = send(&app, Method::GET, "/api/v1/buses", None, &[], None).await;
    assert_eq!(status, StatusCode::UNAUTHORIZED);
}

/// LED segments and program downloads take their write in the gateway's
/// operation (issue 29), so the guard takes none: a bucket of 3 gives 3
/// segment writes, not 1 or 2, and a viewer is refused as before.
#[tokio::test(start_paused = true)]
async fn a_segment_write_or_program_download_is_one_write_of_the_rate() {
    let served = support::open("demo", "virtual:demo").await;
    assert_eq!(served.scan().await.unwrap().len(), 3);
    let config = config(
        Some(RateLimit {
            per_second: 0.001,
            burst: 3,
        }),
        crate::api::auth::DEFAULT_BODY_LIMIT,
    );
    let app = app(AppState::new([served]).with_auth(config));
    let segment = "/api/v1/buses/demo/nodes/3/segments/1";
    let scene = "/api/v1/buses/demo/nodes/3/segments";
    let dim = Some(r#"{"dimmer": 9}"#);
    let off = Some(r#"{"segments": [], "others": "off"}"#);
    let refused = send(&app, Method::PUT, segment, Some(VIEWER), &[], dim).await;
    assert_error(&refused, StatusCode::FORBIDDEN, "forbidden");
    for (path, body) in [(segment, dim), (scene, off), (segment, dim)] {
        let (status, json) = send(&app, Method::PUT, path, Some(OPERATOR), &[], body).await;
        assert_eq!(status, StatusCode::OK, "{path}: {json}");
    }
    let refused = send(&app, Method::PUT, scene, Some(OPERATOR), &[], off).await;
    assert_error(&refused, StatusCode::TOO_MANY_REQUESTS, "rate_limited");

    let program = "/api/v1/buses/demo/nodes/3/program?start=false";
    for _ in 0..3 {
        let (status, _, json) = send_with_headers(
            &app,
            Method::POST,
            program,
            &[
                ("authorization", &format!("Bearer {ADMIN}")),
                ("content-type", "application/octet-stream"),
            ],
            Some("CDKI\u{5}4.5.6 an image"),
        )
        .await;
        assert_eq!(status, StatusCode::OK, "{json}");
    }
    let refused = send(&app, Method::POST, program, Some(ADMIN), &[], Some("image")).await;
    assert_error(&refused, StatusCode::TOO_MANY_REQUESTS, "rate_limited");
}

/// The bus operations, LSS, the node-ID change and the I/O outputs take
/// their write in the gateway, one a request: REST's guard takes none of
/// its own (with two, a bucket of 2 would refuse the second request).
/// Asked of a bus not known, they still take it, as before.
#[tokio::test(start_paused = true)]
async fn each_bus_operation_takes_one_write_not_two() {
    let led = r#"{"vendor_id":1186,"product_code":16641,"revision":1,"serial":257,"node_id":10}"#;
    let requests = [
        (Method::POST, "/api/v1/buses/nobus/scan", None),
        (
            Method::PUT,
            "/api/v1/buses/nobus/sync",
            Some(r#"{"period_ms":10}"#),
        ),
        (
            Method::POST,
            "/api/v1/buses/nobus/frames",
            Some(r#"{"id":"0x123"}"#),
        ),
        (Method::POST, "/api/v1/buses/nobus/recording", None),
        (Method::DELETE, "/api/v1/buses/nobus/recording", None),
        (Method::POST, "/api/v1/buses/nobus/lss/scan", Some("{}")),
        (Method::POST, "/api/v1/buses/nobus/lss/configure", Some(led)),
        (
            Method::POST,
            "/api/v1/buses/nobus/nodes/1/node-id",
            Some(r#"{"node_id":9}"#),
        ),
        (
            Method::POST,
            "/api/v1/buses/nobus/machine/nodes/4/boot",
            None,
        ),
        (
            Method::PUT,
            "/api/v1/buses/nobus/nodes/4/io",
            Some(r#"{"outputs":{"do1":true}}"#),
        ),
    ];
    for (method, path, body) in requests {
        let limit = RateLimit {
            per_second: 0.0001,
            burst: 2,
        };
        let app = gateway(Some(limit), crate::api::auth::DEFAULT_BODY_LIMIT);
        let mut statuses = Vec::new();
        for _ in 0..3 {
            let (status, _) = send(&app, method.clone(), path, Some(ADMIN), &[], body).await;
            statuses.push(status.as_u16());
        }
        assert_eq!(statuses, [404, 404, 429], "{method} {path}");
    }
}
