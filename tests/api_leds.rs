//! LED segments, store/restore and DCF backup/restore against the real
//! `candeck serve` on the demo bus, in plain HTTP/1.1 over TCP: each
//! endpoint's normal case and its error cases, as integrators meet them.

use std::time::Duration;

use serde_json::{Value as Json, json};

mod common;

use common::{Response, start};

/// The API's error shape with `status` and `code`.
trait ApiError {
    fn assert_error(&self, status: u16, code: &str);
}

impl ApiError for Response {
    fn assert_error(&self, status: u16, code: &str) {
        assert_eq!(self.status, status, "{}", self.body);
        let body = self.json();
        assert_eq!(body["error"]["code"], code, "{body}");
        assert!(
            body["error"]["message"]
                .as_str()
                .is_some_and(|m| !m.is_empty())
        );
    }
}

/// One request, `Connection: close`, answered within 20 s (a DCF restore
/// writes every parameter).
async fn http(
    address: &str,
    method: &str,
    path: &str,
    content_type: &str,
    body: Option<&str>,
) -> Response {
    common::request(
        address,
        method,
        path,
        content_type,
        body,
        Duration::from_secs(20),
    )
    .await
}

async fn json_call(address: &str, method: &str, path: &str, body: Option<Json>) -> Response {
    let body = body.map(|body| body.to_string());
    http(address, method, path, "application/json", body.as_deref()).await
}

/// Waits for the first scan to have identified the three demo nodes.
async fn demo_ready(address: &str) {
    for _ in 0..100 {
        let response = json_call(address, "GET", "/api/v1/buses/demo/nodes", None).await;
        let nodes = response.json();
        let done = nodes
            .as_array()
            .unwrap()
            .iter()
            .filter(|n| n["identification"]["state"] == "done")
            .count();
        if done == 3 {
            return;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("the demo nodes were not identified");
}

const NODES: &str = "/api/v1/buses/demo/nodes";

#[tokio::test]
async fn segments_over_http() {
    let (server, _) = start(&["serve"]);
    let address = server.address.as_str();
    demo_ready(address).await;
    let segments = format!("{NODES}/3/segments");

    let scene = json!({"segments": [
        {"segment": 1, "led_count": 8, "effect": "fix", "colors": ["#ff8000"]},
        {"segment": 2, "led_count": 4, "effect": "flash", "colors": ["#0000ff", "#00ff00"], "dimmer": 255},
    ], "others": "off"});
    let response = json_call(address, "PUT", &segments, Some(scene)).await;
    assert_eq!(response.status, 200, "{}", response.body);
    let applied = response.json();
    assert_eq!(applied[0]["effect"], "fix");
    assert_eq!(
        applied[0]["colors"][0],
        json!({"r": 255, "g": 128, "b": 0, "w": 0})
    );
    assert_eq!(applied[1]["effect"], "flash");

    let response = json_call(
        address,
        "PUT",
        &format!("{segments}/1"),
        Some(json!({"dimmer": 0})),
    )
    .await;
    assert_eq!(response.status, 200, "{}", response.body);
    assert_eq!(response.json()["effect"], "fix");

    let listed = json_call(address, "GET", &segments, None).await;
    assert_eq!(listed.status, 200);
    assert_eq!(listed.json()[0]["dimmer"], 0);

    let preview = json_call(address, "GET", &format!("{segments}/preview"), None).await;
    assert_eq!(preview.status, 200, "{}", preview.body);
    let preview = preview.json();
    assert_eq!(preview["led_count"], 12);
    // Segment 1 dimmed to nothing.
    assert_eq!(
        preview["pixels"][0],
        json!({"r": 0, "g": 0, "b": 0, "w": 0})
    );

    json_call(
        address,
        "PUT",
        &format!("{segments}/11"),
        Some(json!({"dimmer": 1})),
    )
    .await
    .assert_error(404, "unknown_segment");
    json_call(
        address,
        "PUT",
        &format!("{segments}/1"),
        Some(json!({"colors": ["red"]})),
    )
    .await
    .assert_error(400, "invalid_value");
    json_call(
        address,
        "PUT",
        &format!("{segments}/1"),
        Some(json!({"effect": 2.5})),
    )
    .await
    .assert_error(400, "invalid_value");
    json_call(address, "GET", &format!("{NODES}/1/segments"), None)
        .await
        .assert_error(404, "not_an_led_controller");
    json_call(
        address,
        "GET",
        &format!("{NODES}/42/segments/preview"),
        None,
    )
    .await
    .assert_error(404, "unknown_node");
    json_call(address, "GET", "/api/v1/buses/nope/nodes/3/segments", None)
        .await
        .assert_error(404, "unknown_bus");
    http(
        address,
        "PUT",
        &segments,
        "application/json",
        Some("{\"segments\": ["),
    )
    .await
    .assert_error(400, "invalid_request");
}

#[tokio::test]
async fn store_restore_and_dcf_over_http() {
    // The demo nodes left pre-operational, where UniSwarm devices store.
    let dir = std::env::temp_dir().join(format!("candeck-leds-store-{}", std::process::id()));
    let config = common::demo_left_alone(&dir);
    let (server, _) = start(&["serve", "--config", config.to_str().unwrap()]);
    let address = server.address.as_str();
    demo_ready(address).await;

    // The demo nodes stay pre-operational, where UniSwarm devices store.
    let response = json_call(
        address,
        "POST",
        &format!("{NODES}/1/store"),
        Some(json!({"what": "communication"})),
    )
    .await;
    assert_eq!(response.status, 200, "{}", response.body);
    assert_eq!(response.json()["sub"], 2);
    let response = json_call(
        address,
        "POST",
        &format!("{NODES}/1/restore"),
        Some(json!({"what": "manufacturer", "source": "saved"})),
    )
    .await;
    assert_eq!(response.status, 200, "{}", response.body);
    assert_eq!(response.json()["sub"], 8);
    json_call(
        address,
        "POST",
        &format!("{NODES}/1/store"),
        Some(json!({"what": "some"})),
    )
    .await
    .assert_error(400, "invalid_request");
    json_call(
        address,
        "POST",
        &format!("{NODES}/2/restore"),
        Some(json!({"what": "all", "source": "saved"})),
    )
    .await
    .assert_error(400, "invalid_value");
    json_call(
        address,
        "POST",
        &format!("{NODES}/77/store"),
        Some(json!({"what": "all"})),
    )
    .await
    .assert_error(404, "unknown_node");

    // Backup of the JMC, restored onto itself.
    let dcf = http(address, "GET", &format!("{NODES}/2/config.dcf"), "", None).await;
    assert_eq!(dcf.status, 200, "{}", dcf.body);
    assert!(
        dcf.content_type.starts_with("text/plain"),
        "{}",
        dcf.content_type
    );
    assert!(dcf.body.contains("[DeviceComissioning]\r\nNodeID=2\r\n"));
    let report = http(
        address,
        "PUT",
        &format!("{NODES}/2/config.dcf"),
        "text/plain",
        Some(&dcf.body),
    )
    .await;
    assert_eq!(report.status, 200, "{}", report.body);
    let report = report.json();
    assert_eq!(report["failed"], 0, "{report}");
    assert!(report["written"].as_u64().unwrap() > 50, "{report}");
    assert!(report["entries"][0]["ok"].as_bool().unwrap());

    let broken = http(
        address,
        "PUT",
        &format!("{NODES}/2/config.dcf"),
        "text/plain",
        Some("[DeviceInfo]\r\nVendorName=x\r\nthis is no DCF\r\n"),
    )
    .await;
    broken.assert_error(400, "invalid_dcf");
    assert_eq!(broken.json()["error"]["line"], 3);
    http(address, "GET", &format!("{NODES}/99/config.dcf"), "", None)
        .await
        .assert_error(404, "unknown_node");
}
