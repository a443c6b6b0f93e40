//! `POST .../axes/{axis}/step-test` against the demo devices on a paused
//! clock: the virtual UMC's velocity loop stepped and measured, and the
//! refusals (not a UMC, not enabled, not a drive, bad requests).

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Value as Json, json};

use crate::api::tests::support::{assert_error, call, demo_at, post, put};

/// The demo on a bus without wire timing: the step test samples the axis
/// by SDO (or its TPDO) after several SDO writes; on a timed bus under the
/// paused clock each exchange costs a timer tick, and the demo's loop has
/// risen before the first sample. The loop is the subject here, not the
/// wire.
async fn demo() -> (axum::Router, crate::api::AppState) {
    demo_at("virtual:demo?bitrate=unlimited").await
}

fn uri(node: u8, axis: u8, what: &str) -> String {
    format!("/api/v1/buses/demo/nodes/{node}/axes/{axis}{what}")
}

async fn enable(app: &Router, node: u8) {
    let response = post(
        app,
        &uri(node, 1, "/state"),
        json!({"target": "operation_enabled"}),
    )
    .await;
    assert_eq!(response.0, StatusCode::OK, "{}", response.1);
}

async fn velocity_gain(app: &Router, p: f64) {
    let raw = (p * 65536.0).round() as i64;
    let (status, body) = call(
        app,
        Method::PUT,
        "/api/v1/buses/demo/nodes/1/od/0x4041/1",
        Some(json!({"value": raw})),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
}

async fn step(app: &Router) -> Json {
    // Steep VL ramps up and down, so that the loop, not the ramp, shapes
    // the step, and the axis is back at `from` before it.
    for (index, sub, value) in [
        ("0x6048", 1, 10_000),
        ("0x6048", 2, 1),
        ("0x6049", 1, 10_000),
        ("0x6049", 2, 1),
    ] {
        let (status, body) = call(
            app,
            Method::PUT,
            &format!("/api/v1/buses/demo/nodes/1/od/{index}/{sub}"),
            Some(json!({"value": value})),
        )
        .await;
        assert_eq!(status, StatusCode::OK, "{body}");
    }
    let response = post(
        app,
        &uri(1, 1, "/step-test"),
        json!({"loop": "velocity", "from": 0, "to": 800, "hold_ms": 300, "settle_band_pct": 2}),
    )
    .await;
    assert_eq!(response.0, StatusCode::OK, "{}", response.1);
    response.1
}

#[tokio::test(start_paused = true)]
async fn a_velocity_step_is_measured_and_the_axis_halted_after() {
    let (app, _) = demo().await;
    enable(&app, 1).await;
    let body = step(&app).await;
    // The demo UMC sends no TPDO before it is started: read by SDO.
    assert_eq!(body["source"], "sdo", "{}", body["source"]);
    let samples = body["samples"].as_array().unwrap();
    assert!(samples.len() >= 100, "{} samples", samples.len());
    let last = samples.last().unwrap();
    assert!(last[0].as_f64().unwrap() >= 300.0, "{last}");
    assert_eq!(last[1], 800.0);
    let actual = last[2].as_f64().unwrap();
    assert!((actual - 800.0).abs() <= 20.0, "{actual}");
    let rise = body["rise_time_ms"].as_f64().unwrap();
    assert!(rise > 0.0 && rise < 100.0, "{rise}");
    assert!(body["settling_time_ms"].as_f64().is_some(), "{body}");
    assert!(body["overshoot_pct"].as_f64().unwrap() >= 0.0);
    assert!(body["steady_state_error"].as_f64().unwrap().abs() <= 20.0);
    // Halted at the end: controlword bit 8, and the axis comes to rest.
    let (_, axis) = call(&app, Method::GET, &uri(1, 1, ""), None).await;
    assert_eq!(axis["state"], "operation_enabled", "{axis}");
    let (_, word) = call(
        &app,
        Method::GET,
        "/api/v1/buses/demo/nodes/1/od/0x6040/0",
        None,
    )
    .await;
    assert_ne!(word["value"].as_i64().unwrap() & 0x100, 0, "{word}");
    // The lease of the test is over: a move needs none.
    let response = post(
        &app,
        &uri(1, 1, "/move"),
        json!({"mode": "profile_position", "target": 0}),
    )
    .await;
    assert_eq!(response.0, StatusCode::OK, "{}", response.1);
}

#[tokio::test(start_paused = true)]
async fn the_velocity_gain_shows_in_the_rise_time() {
    let (app, _) = demo().await;
    enable(&app, 1).await;
    // The stiff gain first: whatever the first test leaves behind favours
    // the second, the soft one.
    velocity_gain(&app, 0.03).await;
    let stiff = step(&app).await;
    velocity_gain(&app, 0.004).await;
    let soft = step(&app).await;
    let rise = |body: &Json| body["rise_time_ms"].as_f64().unwrap();
    assert!(
        rise(&soft) > 2.0 * rise(&stiff),
        "{} vs {}",
        rise(&soft),
        rise(&stiff)
    );
}

#[tokio::test(start_paused = true)]
async fn refused_on_what_cannot_be_tested() {
    let (app, _) = demo().await;
    let request = json!({"loop": "velocity", "from": 0, "to": 100, "hold_ms": 100});
    // Not enabled.
    let response = post(&app, &uri(1, 1, "/step-test"), request.clone()).await;
    assert_error(&response, StatusCode::CONFLICT, "drive_not_enabled");
    // The JMC has no control loop objects.
    enable(&app, 2).await;
    let response = post(&app, &uri(2, 1, "/step-test"), request.clone()).await;
    assert_error(
        &response,
        StatusCode::UNPROCESSABLE_ENTITY,
        "mode_not_supported",
    );
    assert!(
        response.1["error"]["message"]
            .as_str()
            .unwrap()
            .contains("UMC"),
        "{}",
        response.1
    );
    // The LED controller is no drive.
    let response = post(&app, &uri(3, 1, "/step-test"), request.clone()).await;
    assert_error(&response, StatusCode::NOT_FOUND, "not_a_drive");
    // Bad requests, before the bus.
    enable(&app, 1).await;
    for bad in [
        json!({"loop": "velocity", "from": 5, "to": 5, "hold_ms": 100}),
        json!({"loop": "velocity", "from": 0, "to": 5, "hold_ms": 1}),
        json!({"loop": "speed", "from": 0, "to": 5, "hold_ms": 100}),
    ] {
        let response = post(&app, &uri(1, 1, "/step-test"), bad.clone()).await;
        assert_eq!(response.0, StatusCode::BAD_REQUEST, "{bad}: {}", response.1);
    }
}

/// SDO uploads of `index` sub 0 from node 1's client among `frames`.
fn uploads_of(frames: &mut crate::can::FrameReceiver, index: u16) -> usize {
    let mut count = 0;
    loop {
        let frame = match frames.try_recv() {
            Ok(Some(frame)) => frame,
            Ok(None) => break,
            // A lost frame could have been one of them.
            Err(error) => panic!("the monitor lost frames: {error:?}"),
        };
        let data = frame.frame.data();
        if frame.frame.id() == crate::can::CanId::standard(0x601).unwrap()
            && data.len() == 8
            && data[0] == 0x40
            && u16::from_le_bytes([data[1], data[2]]) == index
        {
            count += 1;
        }
    }
    count
}

/// With the velocity loop's actual value (VL's 0x6044) in a TPDO sent
/// every 2 ms by an operational node, the step is recorded from its
/// frames, one sample each, and 0x6044 is not read by SDO at all; once the TPDO stops (the
/// node pre-operational), the next step is read by SDO again.
#[tokio::test(start_paused = true)]
async fn a_step_on_an_axis_whose_tpdo_carries_the_actual_is_fed_by_it() {
    let (app, state) = demo().await;
    let (status, pdo) = put(
        &app,
        "/api/v1/buses/demo/nodes/1/pdos/tpdo/1",
        json!({"transmission_type": 255, "event_timer_ms": 2, "mapping": [
            {"index": "0x6044", "sub": 0},
        ]}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{pdo}");
    let nmt = |command: &'static str| {
        let app = app.clone();
        async move {
            let (status, body) = post(
                &app,
                "/api/v1/buses/demo/nodes/1/nmt",
                json!({ "command": command }),
            )
            .await;
            assert_eq!(status, StatusCode::OK, "{body}");
        }
    };
    nmt("start").await;
    enable(&app, 1).await;
    tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    let served = state.bus("demo").unwrap();
    let mut monitor = served.monitor();
    let body = step(&app).await;
    assert_eq!(body["source"], "tpdo", "{}", body["source"]);
    assert_eq!(uploads_of(&mut monitor, 0x6044), 0, "0x6044 read by SDO");
    let samples = body["samples"].as_array().unwrap();
    let times: Vec<f64> = samples.iter().map(|s| s[0].as_f64().unwrap()).collect();
    // One sample per TPDO: 2 ms apart over the 300 ms hold.
    assert!(
        (140..=160).contains(&times.len()),
        "{} samples",
        times.len()
    );
    assert!(
        times.windows(2).all(|w| (w[1] - w[0] - 2.0).abs() < 0.5),
        "{times:?}"
    );
    assert!(*times.last().unwrap() >= 300.0, "{times:?}");
    let actual = samples.last().unwrap()[2].as_f64().unwrap();
    assert!((actual - 800.0).abs() <= 20.0, "{actual}");
    assert!(body["rise_time_ms"].as_f64().unwrap() > 0.0, "{body}");

    nmt("pre_operational").await;
    tokio::time::sleep(std::time::Duration::from_secs(2)).await;
    // Leaving operational faults the UMC's axis: reset and enabled again.
    let (status, body) = post(&app, &uri(1, 1, "/fault-reset"), json!({})).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    enable(&app, 1).await;
    let body = step(&app).await;
    assert_eq!(body["source"], "sdo", "{}", body["source"]);
    assert!(uploads_of(&mut monitor, 0x6044) > 100);
}
