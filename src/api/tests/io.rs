//! `GET/PUT .../io` on the virtual io401 (CiA 401): inputs from its TPDOs
//! once it is operational (over SDO before), outputs set and read back,
//! and the refusals.

use crate::emulator::RackOf;
use std::time::Duration;

use axum::http::{Method, StatusCode};
use serde_json::{Value as Json, json};

use super::support::open;
use crate::api::{AppState, app};
use crate::canopen::NodeId;
use crate::sim::products::Product;

async fn bench() -> axum::Router {
    let served = open("bench", "virtual:empty").await;
    let rack = served.rack().unwrap();
    rack.add(Product::Io401, NodeId::new(4).unwrap()).unwrap();
    rack.add(Product::Uio1led, NodeId::new(3).unwrap()).unwrap();
    served.scan().await.unwrap();
    app(AppState::new([served]))
}

async fn call(
    app: &axum::Router,
    method: Method,
    uri: &str,
    body: Option<Json>,
) -> (StatusCode, Json) {
    super::support::call(app, method, uri, body).await
}

fn channel<'a>(io: &'a Json, kind: &str, name: &str) -> &'a Json {
    io[kind]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["channel"] == name)
        .unwrap_or_else(|| panic!("{name} not in {io}"))
}

#[tokio::test(start_paused = true)]
async fn the_io401_inputs_come_live_and_an_output_reads_back() {
    let app = bench().await;
    let (status, node) = call(&app, Method::GET, "/api/v1/buses/bench/nodes/4", None).await;
    assert_eq!(status, StatusCode::OK, "{node}");
    assert_eq!(
        (&node["profile"], &node["eds"]),
        (&"cia401".into(), &"io401.eds".into())
    );

    // Pre-operational: no TPDOs, every input read over SDO.
    let (status, io) = call(&app, Method::GET, "/api/v1/buses/bench/nodes/4/io", None).await;
    assert_eq!(status, StatusCode::OK, "{io}");
    let counts: Vec<usize> = [
        "digital_inputs",
        "digital_outputs",
        "analog_inputs",
        "analog_outputs",
    ]
    .iter()
    .map(|kind| io[kind].as_array().unwrap().len())
    .collect();
    assert_eq!(counts, [16, 16, 4, 2]);
    assert_eq!(channel(&io, "digital_inputs", "di1")["source"], "sdo");
    // Exactly one input of the running light is on.
    let lit = io["digital_inputs"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["value"] == true)
        .count();
    assert_eq!(lit, 1, "{io}");

    // Operational: the inputs come in TPDOs, and change on their own.
    let (status, body) = call(
        &app,
        Method::POST,
        "/api/v1/buses/bench/nodes/4/nmt",
        Some(json!({"command": "start"})),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let (_, first) = call(&app, Method::GET, "/api/v1/buses/bench/nodes/4/io", None).await;
    let ai2 = channel(&first, "analog_inputs", "ai2");
    assert_eq!(ai2["source"], "tpdo", "{first}");
    assert!(ai2["age_ms"].as_u64().unwrap() <= 1000, "{ai2}");
    assert_eq!(channel(&first, "digital_inputs", "di1")["source"], "tpdo");
    tokio::time::sleep(Duration::from_millis(600)).await;
    let (_, later) = call(&app, Method::GET, "/api/v1/buses/bench/nodes/4/io", None).await;
    assert_ne!(
        channel(&first, "analog_inputs", "ai2")["value"],
        channel(&later, "analog_inputs", "ai2")["value"]
    );
    assert_ne!(first["digital_inputs"], later["digital_inputs"]);

    // Outputs set, each read back; ai4 is wired to ao1.
    let (status, written) = call(
        &app,
        Method::PUT,
        "/api/v1/buses/bench/nodes/4/io",
        Some(json!({"outputs": {"do3": true, "do12": true, "ao1": -1234}})),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{written}");
    let outputs = written["outputs"].as_array().unwrap();
    assert_eq!(outputs.len(), 3);
    assert!(outputs.iter().all(|o| o["confirmed"] == true), "{written}");
    let (status, sdo) = call(
        &app,
        Method::GET,
        "/api/v1/buses/bench/nodes/4/od/0x6200/1",
        None,
    )
    .await;
    assert_eq!(
        (status, &sdo["value"]),
        (StatusCode::OK, &json!(0x04)),
        "{sdo}"
    );
    let (_, io) = call(&app, Method::GET, "/api/v1/buses/bench/nodes/4/io", None).await;
    assert_eq!(channel(&io, "digital_outputs", "do3")["value"], true);
    assert_eq!(channel(&io, "digital_outputs", "do12")["value"], true);
    assert_eq!(channel(&io, "digital_outputs", "do4")["value"], false);
    assert_eq!(channel(&io, "analog_outputs", "ao1")["value"], -1234);
    tokio::time::sleep(Duration::from_millis(200)).await;
    let (_, io) = call(&app, Method::GET, "/api/v1/buses/bench/nodes/4/io", None).await;
    assert_eq!(channel(&io, "analog_inputs", "ai4")["value"], -1234, "{io}");
    // Off again.
    let (_, written) = call(
        &app,
        Method::PUT,
        "/api/v1/buses/bench/nodes/4/io",
        Some(json!({"outputs": {"do3": false}})),
    )
    .await;
    assert_eq!(written["outputs"][0]["read_back"], false, "{written}");
}

#[tokio::test(start_paused = true)]
async fn bad_channels_and_values_are_refused_before_any_write() {
    let app = bench().await;
    let put = |body: Json| {
        let app = app.clone();
        async move {
            call(
                &app,
                Method::PUT,
                "/api/v1/buses/bench/nodes/4/io",
                Some(body),
            )
            .await
        }
    };
    for (body, status, code) in [
        (
            json!({"outputs": {"do17": true}}),
            StatusCode::NOT_FOUND,
            "unknown_channel",
        ),
        (
            json!({"outputs": {"di1": true}}),
            StatusCode::NOT_FOUND,
            "unknown_channel",
        ),
        (
            json!({"outputs": {"ao3": 1}}),
            StatusCode::NOT_FOUND,
            "unknown_channel",
        ),
        (
            json!({"outputs": {"relay": 1}}),
            StatusCode::NOT_FOUND,
            "unknown_channel",
        ),
        (
            json!({"outputs": {"do1": "on"}}),
            StatusCode::BAD_REQUEST,
            "invalid_value",
        ),
        (
            json!({"outputs": {"ao1": 1.5}}),
            StatusCode::BAD_REQUEST,
            "invalid_value",
        ),
        (
            json!({"outputs": {"ao1": 40000}}),
            StatusCode::BAD_REQUEST,
            "value_out_of_range",
        ),
        (
            json!({"outputs": {}}),
            StatusCode::BAD_REQUEST,
            "invalid_request",
        ),
        // One bad entry, nothing written (do1 stays off).
        (
            json!({"outputs": {"do1": true, "do99": true}}),
            StatusCode::NOT_FOUND,
            "unknown_channel",
        ),
        // Issue 30, finding 8: one spelling of a name; another is refused
        // (naming the accepted one), not taken for it, and nothing written.
        (
            json!({"outputs": {"DO1": true}}),
            StatusCode::BAD_REQUEST,
            "invalid_request",
        ),
        (
            json!({"outputs": {"do01": true}}),
            StatusCode::BAD_REQUEST,
            "invalid_request",
        ),
        (
            json!({"outputs": {"do1 ": true}}),
            StatusCode::BAD_REQUEST,
            "invalid_request",
        ),
    ] {
        let (got, answer) = put(body.clone()).await;
        assert_eq!(
            (got, answer["error"]["code"].as_str()),
            (status, Some(code)),
            "{body}: {answer}"
        );
        if code == "invalid_request" && body["outputs"].as_object().is_some_and(|o| !o.is_empty()) {
            let message = answer["error"]["message"].as_str().unwrap_or_default();
            assert!(message.contains("write 'do1'"), "{body}: {answer}");
        }
    }
    let (_, sdo) = call(
        &app,
        Method::GET,
        "/api/v1/buses/bench/nodes/4/od/0x6200/1",
        None,
    )
    .await;
    assert_eq!(sdo["value"], 0, "{sdo}");
    // A node that is no I/O module.
    let (status, answer) = call(&app, Method::GET, "/api/v1/buses/bench/nodes/3/io", None).await;
    assert_eq!(
        (status, answer["error"]["code"].as_str()),
        (StatusCode::NOT_FOUND, Some("not_an_io_module"))
    );
}
