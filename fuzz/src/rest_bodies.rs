//! REST API (`docs/rest-api.md`): an arbitrary request to a route that changes something
//! (every POST, PUT and DELETE of `openapi/openapi.json`), with path
//! parameters from small sets of valid and invalid values and an arbitrary
//! body, through the axum router on the demo virtual bus, in-process.
//!
//! Each input gets a fresh demo bus on its own current-thread tokio runtime
//! with a paused clock, so that inputs do not see each other and SDO timeouts
//! cost no wall time. What must hold: never a panic (libFuzzer aborts on any,
//! in a spawned task too), no 5xx but the bus's 502/503/504, and every 4xx
//! in the API's error shape (`{"error": {"code", "message"}}`, JSON).

use std::sync::{Arc, OnceLock};
use std::time::Duration;

use axum::body::Body;
use axum::http::{Method, Request};
use candeck::api::{AppState, app};
use candeck::gateway::EdsCatalog;
use candeck::gateway::RegistryConfig;
use serde_json::Value as Json;
use tower::ServiceExt;

const OPENAPI: &str = include_str!("../../openapi/openapi.json");

/// Every (method, path template) of the OpenAPI document that is not a GET.
fn routes() -> &'static [(Method, String)] {
    static ROUTES: OnceLock<Vec<(Method, String)>> = OnceLock::new();
    ROUTES.get_or_init(|| {
        let doc: Json = serde_json::from_str(OPENAPI).expect("openapi.json is JSON");
        let mut routes = Vec::new();
        for (path, item) in doc["paths"].as_object().expect("paths") {
            for (method, _) in item.as_object().expect("path item") {
                let method = match method.as_str() {
                    "post" => Method::POST,
                    "put" => Method::PUT,
                    "delete" => Method::DELETE,
                    "patch" => Method::PATCH,
                    _ => continue,
                };
                routes.push((method, path.clone()));
            }
        }
        assert!(routes.len() > 20, "{routes:?}");
        routes
    })
}

/// Values for each path parameter: the valid ones of the demo bus first,
/// then wrong ones of every kind.
fn values(name: &str) -> &'static [&'static str] {
    match name {
        "bus" => &["demo", "nope", "DEMO", "demo%00", "%FF", "a%2Fb"],
        "id" => &[
            "1",
            "2",
            "3",
            "4",
            "0",
            "127",
            "128",
            "x",
            "-1",
            "0x01",
            "99999999999",
        ],
        "index" => &[
            "0x6040", "0x1017", "0x2000", "6060", "0x1000", "zz", "0x10000", "0x",
        ],
        "sub" => &["0", "1", "255", "256", "-1", "x"],
        "n" => &["1", "0", "4", "5", "512", "x"],
        "axis" => &["1", "0", "2", "3", "x"],
        "kind" => &["rpdo", "tpdo", "pdo", ""],
        _ => &["1", "x"],
    }
}

/// The shared, read-only catalog (building it per input would only cost).
fn catalog() -> Arc<EdsCatalog> {
    static CATALOG: OnceLock<Arc<EdsCatalog>> = OnceLock::new();
    CATALOG
        .get_or_init(|| Arc::new(EdsCatalog::builtin().expect("built-in EDS")))
        .clone()
}

/// One input: what the fuzz target and the seed replay run.
pub fn run(data: &[u8]) {
    let [route, params, kind, body @ ..] = data else {
        return;
    };
    let routes = routes();
    let (method, template) = &routes[usize::from(*route) % routes.len()];
    // Fill each parameter from the next bits of `params`.
    let mut bits = *params;
    let mut uri = String::new();
    for (i, piece) in template.split('{').enumerate() {
        if i == 0 {
            uri.push_str(piece);
            continue;
        }
        let (name, rest) = piece.split_once('}').expect("a closed parameter");
        let choices = values(name);
        // The valid value most of the time, so that bodies reach handlers.
        let pick = if bits & 1 == 0 {
            0
        } else {
            usize::from(bits >> 1) % choices.len()
        };
        bits = bits.rotate_right(3);
        uri.push_str(choices[pick]);
        uri.push_str(rest);
    }
    let content_type = match kind % 4 {
        0 | 1 => Some("application/json"),
        2 => Some("text/plain"),
        _ => None,
    };
    let method = if kind & 0x80 != 0 {
        Method::GET
    } else {
        method.clone()
    };
    let mut request = Request::builder().method(method.clone()).uri(&uri);
    if let Some(content_type) = content_type {
        request = request.header("content-type", content_type);
    }
    let Ok(request) = request.body(Body::from(body.to_vec())) else {
        return;
    };

    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .expect("a runtime");
    runtime.block_on(async {
        let served = candeck::emulator::open_bus(
            "demo",
            &"virtual:demo".parse().unwrap(),
            catalog(),
            RegistryConfig::default(),
            500_000,
        )
        .await
        .expect("the demo bus opens");
        served.scan().await.expect("the demo bus scans");
        let router = app(AppState::new([served]));
        let response = tokio::time::timeout(Duration::from_secs(600), router.oneshot(request))
            .await
            .unwrap_or_else(|_| panic!("{method} {uri}: no answer in 600 s"))
            .expect("the router is infallible");
        let status = response.status();
        let content_type = response
            .headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok())
            .map(str::to_string);
        let bytes = axum::body::to_bytes(response.into_body(), 1 << 24)
            .await
            .expect("the body reads");
        let text = String::from_utf8_lossy(&bytes);
        assert!(
            !status.is_server_error() || matches!(status.as_u16(), 502..=504),
            "{method} {uri} {content_type:?} {:?}: {status} {text}",
            String::from_utf8_lossy(body)
        );
        if status.is_client_error() {
            assert_eq!(
                content_type.as_deref(),
                Some("application/json"),
                "{method} {uri}: {status} {text}"
            );
            let json: Json = serde_json::from_slice(&bytes)
                .unwrap_or_else(|e| panic!("{method} {uri}: {status} not JSON ({e}): {text}"));
            assert!(
                json["error"]["code"].is_string() && json["error"]["message"].is_string(),
                "{method} {uri}: {status} not the error shape: {text}"
            );
        }
    });
}
