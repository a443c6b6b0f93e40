//! `/buses/{bus}/recording` and `/buses/{bus}/recording.log` through the
//! router, on a paused clock, against the demo devices; and the round trip:
//! a recording replayed gives the same frames.

use std::path::{Path, PathBuf};
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::http::{HeaderMap, Method, Request, StatusCode};
use serde_json::{Value as Json, json};
use tower::ServiceExt;

use crate::api::frames::BusFrame;
use crate::api::tests::support::{
    assert_error, call_text, delete_text, demo, get, post, post_text, put,
};
use crate::can::candump::{LoggedFrame, read_log_from};
use crate::can::spec::BusSpec;
use crate::can::{BusState, Direction, Frame, TimedFrame};

const URI: &str = "/api/v1/buses/demo/recording";
const LOG: &str = "/api/v1/buses/demo/recording.log";

/// `GET` of a log: status, headers, body.
async fn download(app: &Router, uri: &str) -> (StatusCode, HeaderMap, String) {
    let request = Request::builder().uri(uri).body(Body::empty()).unwrap();
    let response = app.clone().oneshot(request).await.unwrap();
    let (parts, body) = response.into_parts();
    let bytes = axum::body::to_bytes(body, usize::MAX).await.unwrap();
    (
        parts.status,
        parts.headers,
        String::from_utf8(bytes.to_vec()).unwrap(),
    )
}

fn parse(text: &str) -> Vec<LoggedFrame> {
    read_log_from(text.as_bytes(), Path::new("recording.log")).unwrap()
}

fn stop_reason(status: &Json) -> &Json {
    &status["stop_reason"]
}

#[tokio::test(start_paused = true)]
async fn record_download_and_stop() {
    let (app, _) = demo().await;
    let (status, none) = get(&app, URI).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(
        none,
        json!({"state": "none", "stop_reason": null, "error": null, "file": null,
               "download": null, "frames": 0, "lost": 0, "bytes": 0, "started_us": null,
               "stopped_us": null, "max_frames": null, "max_seconds": null})
    );

    let (status, started) = post(&app, URI, json!({"max_frames": 5000, "max_seconds": 60})).await;
    assert_eq!(status, StatusCode::CREATED, "{started}");
    assert_eq!(started["state"], "recording");
    assert_eq!(stop_reason(&started), &Json::Null);
    assert_eq!(
        (
            started["max_frames"].clone(),
            started["max_seconds"].clone()
        ),
        (json!(5000), json!(60))
    );
    assert_eq!(started["download"], LOG);
    let file = started["file"].as_str().unwrap().to_string();
    assert!(
        file.starts_with("demo-") && file.ends_with(".log"),
        "{file}"
    );

    // An SDO read by REST: request and answer are in the log.
    let (status, read) = get(&app, "/api/v1/buses/demo/nodes/1/od/0x1000/0").await;
    assert_eq!(status, StatusCode::OK, "{read}");
    let (status, running) = get(&app, URI).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(running["state"], "recording");
    assert!(running["frames"].as_u64().unwrap() >= 2, "{running}");

    // While it runs, the download has everything so far.
    let (status, headers, text) = download(&app, LOG).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(headers["content-type"], "text/plain; charset=utf-8");
    assert_eq!(
        headers["content-disposition"],
        format!("attachment; filename=\"{file}\"").as_str()
    );
    let so_far = parse(&text);
    assert!(so_far.iter().all(|line| line.iface == "demo"));
    let request = so_far
        .iter()
        .position(|line| {
            line.frame.id().raw() == 0x601 && line.frame.data()[..4] == [0x40, 0x00, 0x10, 0x00]
        })
        .expect("the SDO request");
    assert!(
        so_far[request..]
            .iter()
            .any(|line| line.frame.id().raw() == 0x581),
        "the SDO answer"
    );

    let (status, stopped) = delete_text(&app, URI, None).await;
    assert_eq!(status, StatusCode::OK, "{stopped}");
    assert_eq!(stopped["state"], "stopped");
    assert_eq!(stop_reason(&stopped), "asked");
    assert_eq!(stopped["lost"], 0);
    assert!(stopped["stopped_us"].as_u64().unwrap() >= stopped["started_us"].as_u64().unwrap());
    let (_, headers, text) = download(&app, LOG).await;
    assert_eq!(
        parse(&text).len() as u64,
        stopped["frames"].as_u64().unwrap()
    );
    assert_eq!(text.len() as u64, stopped["bytes"].as_u64().unwrap());
    assert_eq!(headers["content-length"], text.len().to_string().as_str());
    assert_eq!(get(&app, URI).await.1, stopped);

    // Another one may start now, without a body.
    let (status, again) = post_text(&app, URI, "").await;
    assert_eq!(status, StatusCode::CREATED, "{again}");
    assert_eq!(
        (again["max_frames"].clone(), again["max_seconds"].clone()),
        (json!(1_000_000), json!(3600))
    );
    assert_eq!(again["frames"], 0);
    delete_text(&app, URI, None).await;
    let (status, again) = post_text(&app, URI, "null").await;
    assert_eq!(status, StatusCode::CREATED, "{again}");
}

#[tokio::test(start_paused = true)]
async fn a_recording_stops_at_its_limits() {
    let (app, _) = demo().await;
    let (status, _) = post(&app, URI, json!({"max_frames": 3})).await;
    assert_eq!(status, StatusCode::CREATED);
    // An SDO read makes two frames, a second one two more.
    for _ in 0..2 {
        get(&app, "/api/v1/buses/demo/nodes/1/od/0x1000/0").await;
    }
    tokio::time::sleep(Duration::from_millis(1)).await;
    let (_, status) = get(&app, URI).await;
    assert_eq!(
        (status["state"].clone(), stop_reason(&status).clone()),
        (json!("stopped"), json!("max_frames"))
    );
    assert_eq!(status["frames"], 3);
    let (_, _, text) = download(&app, LOG).await;
    assert_eq!(parse(&text).len(), 3);

    let (status, _) = post(&app, URI, json!({"max_seconds": 1})).await;
    assert_eq!(status, StatusCode::CREATED);
    tokio::time::sleep(Duration::from_millis(1001)).await;
    let (_, status) = get(&app, URI).await;
    assert_eq!(stop_reason(&status), "max_seconds");
}

#[tokio::test(start_paused = true)]
async fn recording_errors() {
    let (app, _) = demo().await;
    // Nothing recorded yet.
    assert_error(
        &delete_text(&app, URI, None).await,
        StatusCode::NOT_FOUND,
        "no_recording",
    );
    let (status, _, text) = download(&app, LOG).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let body: Json = serde_json::from_str(&text).unwrap();
    assert_error(&(status, body), StatusCode::NOT_FOUND, "no_recording");
    // Bodies refused before anything starts.
    for (body, code) in [
        (r#"{"max_frames": 0}"#, "value_out_of_range"),
        (r#"{"max_frames": 1000001}"#, "value_out_of_range"),
        (r#"{"max_seconds": 0}"#, "value_out_of_range"),
        (r#"{"max_seconds": 3601}"#, "value_out_of_range"),
        (r#"{"max_frames": -1}"#, "invalid_request"),
        (r#"{"max_seconds": 1.5}"#, "invalid_request"),
        (r#"{"max_seconds": "10"}"#, "invalid_request"),
        (r#"{"max_frame": 10}"#, "invalid_request"),
        ("[]", "invalid_request"),
        ("not json", "invalid_request"),
    ] {
        assert_error(
            &post_text(&app, URI, body).await,
            StatusCode::BAD_REQUEST,
            code,
        );
    }
    assert_eq!(get(&app, URI).await.1["state"], "none");
    // Unknown bus, every method.
    let other = "/api/v1/buses/nope/recording";
    assert_error(
        &get(&app, other).await,
        StatusCode::NOT_FOUND,
        "unknown_bus",
    );
    assert_error(
        &post_text(&app, other, "{}").await,
        StatusCode::NOT_FOUND,
        "unknown_bus",
    );
    assert_error(
        &delete_text(&app, other, None).await,
        StatusCode::NOT_FOUND,
        "unknown_bus",
    );
    let (status, _, text) = download(&app, "/api/v1/buses/nope/recording.log").await;
    let body: Json = serde_json::from_str(&text).unwrap();
    assert_error(&(status, body), StatusCode::NOT_FOUND, "unknown_bus");
    // One at a time.
    assert_eq!(post_text(&app, URI, "{}").await.0, StatusCode::CREATED);
    let running = post_text(&app, URI, "{}").await;
    assert_error(&running, StatusCode::CONFLICT, "recording_running");
    assert_eq!(delete_text(&app, URI, None).await.0, StatusCode::OK);
    assert_error(
        &delete_text(&app, URI, None).await,
        StatusCode::CONFLICT,
        "recording_not_running",
    );
    // Other methods on the log.
    let (status, body) = call_text(&app, Method::PUT, LOG, Some("{}")).await;
    assert_error(
        &(status, body),
        StatusCode::METHOD_NOT_ALLOWED,
        "method_not_allowed",
    );
}

/// A file in the temporary directory, removed when dropped.
struct TempFile(PathBuf);

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The round trip of issue 6: record the demo bus while the gateway
/// works it (SDO reads and writes, an NMT command, the devices'
/// heartbeats), download the log, replay it: the replay plays exactly the
/// recorded frames, which are exactly what the frame log saw meanwhile.
#[tokio::test(start_paused = true)]
async fn a_recording_replayed_gives_the_same_frames() {
    let (app, _) = demo().await;
    let (status, started) = post(&app, URI, json!({})).await;
    assert_eq!(status, StatusCode::CREATED, "{started}");

    let (status, body) = get(&app, "/api/v1/buses/demo/nodes/1/od/0x1018/1").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, body) = put(
        &app,
        "/api/v1/buses/demo/nodes/1/od/0x1017/0",
        json!({"value": 100}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, body) = get(&app, "/api/v1/buses/demo/nodes/3/od/0x1008/0").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, body) = post(
        &app,
        "/api/v1/buses/demo/nodes/2/nmt",
        json!({"command": "reset_communication"}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    // Heartbeats: node 1 every 100 ms now, the JMC every second.
    tokio::time::sleep(Duration::from_millis(1500)).await;

    let (status, stopped) = delete_text(&app, URI, None).await;
    assert_eq!(status, StatusCode::OK, "{stopped}");
    assert_eq!(stopped["lost"], 0);
    let (status, _, text) = download(&app, LOG).await;
    assert_eq!(status, StatusCode::OK);
    let recorded = parse(&text);
    assert_eq!(recorded.len() as u64, stopped["frames"].as_u64().unwrap());
    let has = |id: u32, data: &[u8]| {
        recorded
            .iter()
            .any(|line| line.frame.id().raw() == id && line.frame.data().starts_with(data))
    };
    assert!(has(0x601, &[0x40, 0x18, 0x10, 0x01]), "SDO read request");
    assert!(
        has(0x601, &[0x2B, 0x17, 0x10, 0x00, 100, 0]),
        "SDO write request"
    );
    assert!(has(0x583, &[]), "SDO answer of node 3");
    assert!(has(0x000, &[0x82, 2]), "NMT reset communication of node 2");
    assert!(has(0x702, &[0x00]), "boot-up of node 2");
    let heartbeats = recorded
        .iter()
        .filter(|line| line.frame.id().raw() == 0x701)
        .count();
    assert!(heartbeats >= 10, "{heartbeats} heartbeats of node 1");

    // The frame log saw the same frames, with the same times, in one run.
    let (_, seen) = get(&app, "/api/v1/buses/demo/frames?limit=1000").await;
    let seen: Vec<Json> = seen.as_array().unwrap().iter().map(without_dir).collect();
    let recorded_json: Vec<Json> = recorded
        .iter()
        .map(|line| {
            without_dir(
                &serde_json::to_value(BusFrame::from(&TimedFrame {
                    frame: line.frame,
                    timestamp: line.timestamp,
                    direction: Direction::Rx,
                }))
                .unwrap(),
            )
        })
        .collect();
    let first = seen
        .iter()
        .position(|frame| frame == &recorded_json[0])
        .expect("the first recorded frame is in the frame log");
    assert!(
        seen.len() >= first + recorded_json.len(),
        "the frame log holds the whole recording"
    );
    assert_eq!(seen[first..first + recorded_json.len()], recorded_json[..]);
    // Nothing the frame log has from before the recording is in it.
    if first > 0 {
        assert!(seen[first - 1]["timestamp_us"].as_u64() <= started["started_us"].as_u64());
    }

    // Replayed as fast as it can go: the same frames, in the same order.
    let path = std::env::temp_dir().join(format!("candeck-roundtrip-{}.log", std::process::id()));
    let _cleanup = TempFile(path.clone());
    std::fs::write(&path, &text).unwrap();
    let spec: BusSpec = format!("replay:{}?speed=max", path.display())
        .parse()
        .unwrap();
    let replay = spec.open(&spec.default_name()).await.unwrap().bus;
    let mut frames = replay.subscribe();
    let mut status = replay.watch_status();
    let mut played: Vec<Frame> = Vec::new();
    for _ in 0..recorded.len() {
        played.push(frames.recv().await.unwrap().frame);
    }
    status
        .wait_for(|s| s.state == BusState::Down)
        .await
        .unwrap();
    assert_eq!(frames.try_recv(), Ok(None), "nothing more is played");
    let expected: Vec<Frame> = recorded.iter().map(|line| line.frame).collect();
    assert_eq!(played, expected);
}

fn without_dir(frame: &Json) -> Json {
    let mut frame = frame.clone();
    frame.as_object_mut().unwrap().remove("dir");
    frame
}
