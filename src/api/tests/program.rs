//! `POST /buses/{bus}/nodes/{id}/program` (CiA 302-3) against the demo's
//! UIO1LED (node 3), the UMC (node 1) and the JMC (node 2, which has no
//! program objects), and the progress on the `.../program` stream topic.

use axum::body::Body;
use axum::http::{Method, Request, StatusCode};
use serde_json::Value as Json;
use tower::ServiceExt;

use super::stream::Client;
use super::support::{demo, get};
use crate::canopen::crc32::crc32;

async fn post_image(app: &axum::Router, uri: &str, image: Vec<u8>) -> (StatusCode, Json) {
    let request = Request::builder()
        .method(Method::POST)
        .uri(uri)
        .header("content-type", "application/octet-stream")
        .body(Body::from(image))
        .unwrap();
    let response = app.clone().oneshot(request).await.unwrap();
    let status = response.status();
    let bytes = axum::body::to_bytes(response.into_body(), usize::MAX)
        .await
        .unwrap();
    (status, serde_json::from_slice(&bytes).unwrap())
}

fn image(len: usize) -> Vec<u8> {
    let mut image = b"CDKI\x054.5.6".to_vec();
    image.extend((0..len as u32 - 10).map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8));
    image
}

/// A 64 KiB image: downloaded, verified against 0x1F56, started (0x100A
/// then the header's version); with `start=false` the program stays
/// stopped.
#[tokio::test(start_paused = true)]
async fn a_program_is_downloaded_verified_and_started() {
    let (app, _) = demo().await;
    let big = image(64 * 1024);
    let (status, body) = post_image(&app, "/api/v1/buses/demo/nodes/3/program", big.clone()).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["bytes"], 65536);
    assert_eq!(body["crc32"], crc32(&big));
    assert_eq!(body["crc32_hex"], format!("0x{:08X}", crc32(&big)));
    assert_eq!(body["verified"], true);
    assert_eq!(body["started"], true);
    let (_, value) = get(&app, "/api/v1/buses/demo/nodes/3/od/0x1F56/1").await;
    assert_eq!(value["value"], crc32(&big), "{value}");
    let (_, value) = get(&app, "/api/v1/buses/demo/nodes/3/od/0x100A/0").await;
    assert_eq!(value["value"], "4.5.6", "{value}");

    let (status, body) = post_image(
        &app,
        "/api/v1/buses/demo/nodes/1/program?start=false",
        image(1000),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["started"], false);
    let (_, value) = get(&app, "/api/v1/buses/demo/nodes/1/od/0x1F51/1").await;
    assert_eq!(value["value"], 0, "{value}");
}

/// A failed step is named, with the device's abort code: the JMC has no
/// 0x1F51 (the first step), an image larger than the UIO1LED's program
/// memory is refused at the download; an empty body is 400.
#[tokio::test(start_paused = true)]
async fn a_failed_step_is_named_with_its_abort_code() {
    let (app, _) = demo().await;
    let (status, body) = post_image(&app, "/api/v1/buses/demo/nodes/2/program", image(100)).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["error"]["code"], "sdo_abort");
    assert_eq!(body["error"]["step"], "stop program (0x1F51 = 0)");
    assert_eq!(body["error"]["abort_code"], "0x06020000");

    let too_large = image(crate::sim::program::MAX_PROGRAM_SIZE + 1);
    let (status, body) = post_image(&app, "/api/v1/buses/demo/nodes/3/program", too_large).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["error"]["step"], "download image (0x1F50)");
    assert_eq!(body["error"]["abort_code"], "0x05040005");

    let (status, body) = post_image(&app, "/api/v1/buses/demo/nodes/3/program", Vec::new()).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert_eq!(body["error"]["code"], "invalid_request");
}

/// The `program` topic follows a download: running through the download
/// step with the bytes the device confirmed, then done at 100 %, with the
/// run the answer gives; a late reader gets how it ended.
#[tokio::test(start_paused = true)]
async fn the_stream_carries_the_progress_to_100_percent() {
    let (app, state) = demo().await;
    let topic = "buses/demo/nodes/3/program";
    let mut client = Client::start(&state, 1024);
    let reply = client.subscribe(&[topic], Some(50.0)).await;
    assert_eq!(reply["op"], "subscribed", "{reply}");
    let big = image(64 * 1024);
    let posted = tokio::spawn({
        let app = app.clone();
        let big = big.clone();
        async move { post_image(&app, "/api/v1/buses/demo/nodes/3/program", big).await }
    });
    let mut seen = Vec::new();
    loop {
        let message = client.until(|m| m["topic"] == topic).await;
        let data = message["data"].clone();
        assert_eq!(data["bytes_total"], 65536, "{data}");
        seen.push(data.clone());
        if data["state"] != "running" {
            break;
        }
    }
    let (status, answer) = posted.await.unwrap();
    assert_eq!(status, StatusCode::OK, "{answer}");
    let last = seen.last().unwrap();
    assert_eq!(
        (
            &last["state"],
            &last["step"],
            &last["percent"],
            &last["bytes_sent"]
        ),
        (
            &Json::from("done"),
            &Json::from("start"),
            &Json::from(100),
            &Json::from(65536)
        ),
        "{last}"
    );
    assert!(
        seen.iter().all(|data| data["run"] == answer["run"]),
        "{seen:?}"
    );
    let percents: Vec<u64> = seen
        .iter()
        .filter(|data| data["step"] == "download")
        .map(|data| data["percent"].as_u64().unwrap())
        .collect();
    assert!(percents.windows(2).all(|w| w[0] <= w[1]), "{percents:?}");
    assert!(
        percents.iter().filter(|&&p| p > 0 && p < 100).count() >= 5,
        "the download's progress in between: {percents:?}"
    );

    let mut late = Client::start(&state, 64);
    late.subscribe(&[topic], None).await;
    let message = late.until(|m| m["topic"] == topic).await;
    assert_eq!(message["data"], *last);
}

/// A refused step ends the topic's run as failed, naming the step and the
/// abort code; an unknown node has no topic.
#[tokio::test(start_paused = true)]
async fn the_stream_says_at_which_step_a_download_failed() {
    let (app, state) = demo().await;
    let topic = "buses/demo/nodes/2/program";
    let mut client = Client::start(&state, 1024);
    client.subscribe(&[topic], Some(50.0)).await;
    let (status, body) = post_image(&app, "/api/v1/buses/demo/nodes/2/program", image(100)).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    let failed = client
        .until(|m| m["topic"] == topic && m["data"]["state"] != "running")
        .await;
    let data = &failed["data"];
    assert_eq!(
        (
            &data["state"],
            &data["step"],
            &data["abort_code"],
            &data["run"]
        ),
        (
            &Json::from("failed"),
            &Json::from("stop"),
            &Json::from("0x06020000"),
            &Json::from(1)
        ),
        "{data}"
    );
    assert_eq!(data["step_name"], body["error"]["step"], "{data}");

    let reply = client
        .subscribe(&["buses/demo/nodes/99/program"], None)
        .await;
    assert_eq!(reply["error"]["code"], "unknown_node", "{reply}");
}
