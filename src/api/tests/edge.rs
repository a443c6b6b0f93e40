//! The edge of the HTTP interface (issue 19): the `Host` check against DNS
//! rebinding on every route, and the anti-framing and content headers of
//! every answer.

use axum::http::{Method, StatusCode};

use super::support::{demo, send_with_headers as send};
use crate::api::headers::{CONTENT_SECURITY_POLICY, DOCS_CONTENT_SECURITY_POLICY};
use crate::api::host::AllowedHosts;

const EVIL: &[(&str, &str)] = &[
    ("host", "evil.example:8080"),
    ("origin", "http://evil.example:8080"),
];

fn upgrade<'a>(headers: &[(&'a str, &'a str)]) -> Vec<(&'a str, &'a str)> {
    let mut all = headers.to_vec();
    all.extend([
        ("connection", "upgrade"),
        ("upgrade", "websocket"),
        ("sec-websocket-version", "13"),
        ("sec-websocket-key", "dGhlIHNhbXBsZSBub25jZQ=="),
        ("sec-websocket-protocol", "candeck.v1"),
    ]);
    all
}

#[tokio::test(start_paused = true)]
async fn a_rebinding_page_is_refused_on_every_route_and_the_stream() {
    let (app, state) = demo().await;
    // A page under a foreign name that resolves to the gateway: Origin and
    // Host agree, so only the Host gives it away.
    let enable = "/api/v1/buses/demo/nodes/1/axes/1/state";
    let (status, _, json) = send(
        &app,
        Method::POST,
        enable,
        EVIL,
        Some(r#"{"target":"operation_enabled"}"#),
    )
    .await;
    assert_eq!(status, StatusCode::MISDIRECTED_REQUEST, "{json}");
    assert_eq!(json["error"]["code"], "host_not_allowed", "{json}");
    assert!(
        json["error"]["message"]
            .as_str()
            .unwrap()
            .contains("allowed_hosts")
    );
    for uri in [
        "/api/v1/buses",
        "/api/v1/buses/demo/nodes/1/axes/1",
        "/api/v1/health",
        "/metrics",
        "/",
        "/api/docs/",
        "/api/openapi.json",
        "/cia309-5/1.0/1/1/1/r/0x1008/0",
    ] {
        let (status, headers, json) = send(&app, Method::GET, uri, EVIL, None).await;
        assert_eq!(status, StatusCode::MISDIRECTED_REQUEST, "{uri}: {json}");
        assert_eq!(json["error"]["code"], "host_not_allowed", "{uri}");
        assert!(headers.contains_key("content-security-policy"), "{uri}");
    }
    let (status, _, json) = send(&app, Method::GET, "/api/v1/stream", &upgrade(EVIL), None).await;
    assert_eq!(status, StatusCode::MISDIRECTED_REQUEST, "{json}");
    // Nothing moved: the axis was never enabled.
    let (_, _, axis) = send(
        &app,
        Method::GET,
        "/api/v1/buses/demo/nodes/1/axes/1",
        &[("host", "localhost:8080")],
        None,
    )
    .await;
    assert_ne!(axis["state"], "operation_enabled", "{axis}");

    // The gateway's own names pass, on the same routes.
    for own in [
        &[
            ("host", "localhost:8080"),
            ("origin", "http://localhost:8080"),
        ][..],
        &[
            ("host", "127.0.0.1:39127"),
            ("origin", "http://127.0.0.1:39127"),
        ][..],
        &[("host", "[::1]:8080")][..],
    ] {
        let (status, _, json) = send(&app, Method::GET, "/api/v1/buses", own, None).await;
        assert_eq!(status, StatusCode::OK, "{own:?}: {json}");
        let (status, _, json) =
            send(&app, Method::GET, "/api/v1/stream", &upgrade(own), None).await;
        assert_ne!(status, StatusCode::MISDIRECTED_REQUEST, "{own:?}: {json}");
        assert_ne!(status, StatusCode::FORBIDDEN, "{own:?}: {json}");
        let (status, _, json) = send(&app, Method::POST, "/api/v1/stop-all", own, Some("{}")).await;
        assert_eq!(status, StatusCode::OK, "{own:?}: {json}");
    }

    // A name listed in allowed_hosts passes; "*" lets every name through.
    let listed =
        crate::api::app(state.clone().with_allowed_hosts(
            AllowedHosts::new(&["gateway.plant.example".to_string()]).unwrap(),
        ));
    let host = &[("host", "gateway.plant.example:8080")][..];
    let (status, _, _) = send(&listed, Method::GET, "/api/v1/buses", host, None).await;
    assert_eq!(status, StatusCode::OK);
    let (status, _, _) = send(&listed, Method::GET, "/api/v1/buses", EVIL, None).await;
    assert_eq!(status, StatusCode::MISDIRECTED_REQUEST);
    let any =
        crate::api::app(state.with_allowed_hosts(AllowedHosts::new(&["*".to_string()]).unwrap()));
    let (status, _, _) = send(&any, Method::GET, "/api/v1/buses", EVIL, None).await;
    assert_eq!(status, StatusCode::OK);
}

#[tokio::test(start_paused = true)]
async fn every_answer_forbids_framing_and_sniffing() {
    let (app, _) = demo().await;
    for (method, uri, body) in [
        (Method::GET, "/", None),
        (Method::GET, "/api/v1/buses", None),
        (Method::GET, "/api/v1/nowhere", None),
        (Method::GET, "/metrics", None),
        (Method::POST, "/api/v1/buses/demo/nmt", Some("{not json")),
        (Method::GET, "/api/docs/", None),
    ] {
        let (status, headers, _) = send(&app, method, uri, &[], body).await;
        let header = |name: &str| {
            headers
                .get(name)
                .unwrap_or_else(|| panic!("{uri} ({status}): no {name}"))
                .to_str()
                .unwrap()
                .to_string()
        };
        assert_eq!(header("x-frame-options"), "DENY", "{uri}");
        assert_eq!(header("x-content-type-options"), "nosniff", "{uri}");
        assert_eq!(header("referrer-policy"), "no-referrer", "{uri}");
        let policy = header("content-security-policy");
        assert!(policy.contains("frame-ancestors 'none'"), "{uri}: {policy}");
        assert!(policy.contains("script-src 'self';"), "{uri}: {policy}");
        if uri.starts_with("/api/docs") {
            assert_eq!(policy, DOCS_CONTENT_SECURITY_POLICY);
        } else {
            assert_eq!(policy, CONTENT_SECURITY_POLICY, "{uri}");
            assert!(!policy.contains("unsafe-inline"), "{uri}");
        }
    }
}
