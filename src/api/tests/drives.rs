//! The drives endpoints against the demo devices on `virtual:demo` (node 1
//! the UMC1BDS32, node 2 the JMC stepper, node 3 the UIO1LED), through the
//! router without a socket, on a paused clock: every motion asked for is
//! checked in the positions and velocities the drives report.

use crate::emulator::RackOf;
use std::time::Duration;

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Value as Json, json};

use crate::api::tests::support::{assert_error, call, demo, post, post_with_lease};
use crate::canopen::NodeId;
use crate::sim::behaviour::Fault;

const UMC: u8 = 1;
const JMC: u8 = 2;
const LED: u8 = 3;

fn axis_uri(node: u8, axis: u8, what: &str) -> String {
    format!("/api/v1/buses/demo/nodes/{node}/axes/{axis}{what}")
}

async fn axis(app: &Router, node: u8, axis: u8) -> Json {
    let (status, body) = call(app, Method::GET, &axis_uri(node, axis, ""), None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    body
}

async fn enable(app: &Router, node: u8, number: u8) -> Json {
    let response = post(
        app,
        &axis_uri(node, number, "/state"),
        json!({"target": "operation_enabled"}),
    )
    .await;
    assert_eq!(response.0, StatusCode::OK, "{}", response.1);
    assert_eq!(response.1["state"], "operation_enabled", "{}", response.1);
    response.1
}

async fn run(app: &Router, node: u8, number: u8, body: Json) -> Json {
    let response = post(app, &axis_uri(node, number, "/move"), body).await;
    assert_eq!(response.0, StatusCode::OK, "{}", response.1);
    response.1
}

/// A further move by the client that holds the axis's motion lease (the
/// one `earlier` answered with).
async fn run_holding(app: &Router, node: u8, number: u8, earlier: &Json, body: Json) -> Json {
    let lease = earlier["lease"]["id"].as_str().expect("a leased move");
    let response = post_with_lease(app, &axis_uri(node, number, "/move"), lease, body).await;
    assert_eq!(response.0, StatusCode::OK, "{}", response.1);
    response.1
}

/// Polls the axis every 20 ms (virtual) until `done`, for at most
/// `limit_ms`; the last status either way.
async fn wait_for(
    app: &Router,
    node: u8,
    number: u8,
    limit_ms: u64,
    done: impl Fn(&Json) -> bool,
) -> Json {
    let mut waited = 0;
    loop {
        let status = axis(app, node, number).await;
        if done(&status) || waited >= limit_ms {
            return status;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
        waited += 20;
    }
}

fn int(status: &Json, field: &str) -> i64 {
    status[field]
        .as_i64()
        .unwrap_or_else(|| panic!("{field} in {status}"))
}

#[tokio::test(start_paused = true)]
async fn axes_of_each_drive_and_none_of_the_led_controller() {
    let (app, _) = demo().await;
    let (status, body) = call(&app, Method::GET, "/api/v1/buses/demo/nodes/1/axes", None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let axes = body.as_array().unwrap();
    assert_eq!(axes.len(), 2, "{body}");
    assert_eq!(axes[0]["axis"], 1);
    assert_eq!(axes[1]["axis"], 2);
    assert_eq!(axes[0]["state"], "switch_on_disabled", "{body}");
    assert_eq!(axes[0]["fault"], false);
    assert!(axes[0]["torque"].is_i64(), "{body}");
    let modes: Vec<&str> = axes[0]["supported_modes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m.as_str().unwrap())
        .collect();
    for mode in [
        "profile_position",
        "velocity",
        "torque",
        "duty_cycle",
        "continuous_position",
        "interpolated_position",
    ] {
        assert!(modes.contains(&mode), "{mode} missing from {modes:?}");
    }
    assert!(!modes.contains(&"homing"), "{modes:?}");

    let (status, body) = call(&app, Method::GET, "/api/v1/buses/demo/nodes/2/axes", None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body.as_array().unwrap().len(), 1, "{body}");
    assert_eq!(
        body[0]["supported_modes"],
        json!(["profile_position", "velocity", "homing"])
    );
    assert_eq!(body[0]["torque"], Json::Null, "the JMC has no 0x6077");

    let response = call(&app, Method::GET, "/api/v1/buses/demo/nodes/3/axes", None).await;
    assert_error(&response, StatusCode::NOT_FOUND, "not_a_drive");
    let response = post(
        &app,
        &axis_uri(LED, 1, "/state"),
        json!({"target": "operation_enabled"}),
    )
    .await;
    assert_error(&response, StatusCode::NOT_FOUND, "not_a_drive");
}

#[tokio::test(start_paused = true)]
async fn the_state_walk_climbs_and_descends_the_ladder() {
    let (app, _) = demo().await;
    enable(&app, UMC, 1).await;
    for (target, expected) in [
        ("switched_on", "switched_on"),
        ("ready_to_switch_on", "ready_to_switch_on"),
        ("operation_enabled", "operation_enabled"),
        ("quick_stop_active", "quick_stop_active"),
        ("switch_on_disabled", "switch_on_disabled"),
    ] {
        let (status, body) =
            post(&app, &axis_uri(UMC, 1, "/state"), json!({"target": target})).await;
        assert_eq!(status, StatusCode::OK, "{target}: {body}");
        // A quick stop option 1–4 ends in switch on disabled by itself.
        if target == "quick_stop_active" {
            assert!(
                body["state"] == expected || body["state"] == "switch_on_disabled",
                "{body}"
            );
        } else {
            assert_eq!(body["state"], expected, "{target}: {body}");
        }
    }
    // Quick stop only from operation enabled: not by powering the motor.
    let response = post(
        &app,
        &axis_uri(UMC, 1, "/state"),
        json!({"target": "quick_stop_active"}),
    )
    .await;
    assert_error(&response, StatusCode::CONFLICT, "drive_not_enabled");
    assert_eq!(response.1["error"]["state"], "switch_on_disabled");
    // Axis 2 was never touched: its own objects (0x6841) say so.
    assert_eq!(axis(&app, UMC, 2).await["state"], "switch_on_disabled");
}

#[tokio::test(start_paused = true)]
async fn umc_duty_cycle_turns_the_motor() {
    let (app, _) = demo().await;
    enable(&app, UMC, 1).await;
    let body = run(&app, UMC, 1, json!({"mode": "duty_cycle", "duty": 8192})).await;
    assert_eq!(body["mode"], "duty_cycle", "{body}");
    let status = wait_for(&app, UMC, 1, 2000, |s| int(s, "velocity") > 0).await;
    assert!(int(&status, "velocity") > 0, "{status}");
    let before = int(&status, "position");
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert!(int(&axis(&app, UMC, 1).await, "position") > before);
    // Backwards with a negative duty.
    run_holding(
        &app,
        UMC,
        1,
        &body,
        json!({"mode": "duty_cycle", "duty": -8192, "slope": 60000}),
    )
    .await;
    let status = wait_for(&app, UMC, 1, 3000, |s| int(s, "velocity") < 0).await;
    assert!(int(&status, "velocity") < 0, "{status}");
}

#[tokio::test(start_paused = true)]
async fn umc_torque_accelerates_the_motor() {
    let (app, _) = demo().await;
    enable(&app, UMC, 1).await;
    let body = run(&app, UMC, 1, json!({"mode": "torque", "torque": 200})).await;
    assert_eq!(body["mode"], "torque", "{body}");
    let status = wait_for(&app, UMC, 1, 2000, |s| {
        int(s, "velocity") > 0 && int(s, "torque") > 0
    })
    .await;
    assert!(int(&status, "velocity") > 0, "{status}");
    assert!(int(&status, "torque") > 0, "{status}");
}

#[tokio::test(start_paused = true)]
async fn umc_velocity_mode_runs_at_the_target() {
    let (app, _) = demo().await;
    enable(&app, UMC, 1).await;
    let body = run(&app, UMC, 1, json!({"mode": "velocity", "velocity": 100})).await;
    assert_eq!(body["mode"], "velocity", "{body}");
    let status = wait_for(&app, UMC, 1, 3000, |s| {
        s["target_reached"] == true && int(s, "velocity") > 0
    })
    .await;
    assert!(int(&status, "velocity") > 0, "{status}");
    assert_eq!(status["target_reached"], true, "{status}");
    // Halt stops it and keeps the drive enabled.
    let (code, body) = post(&app, &axis_uri(UMC, 1, "/halt"), json!({"halt": true})).await;
    assert_eq!(code, StatusCode::OK, "{body}");
    let status = wait_for(&app, UMC, 1, 3000, |s| int(s, "velocity") == 0).await;
    assert_eq!(int(&status, "velocity"), 0, "{status}");
    assert_eq!(status["state"], "operation_enabled");
    // And carries on when released.
    post(&app, &axis_uri(UMC, 1, "/halt"), json!({"halt": false})).await;
    let status = wait_for(&app, UMC, 1, 3000, |s| int(s, "velocity") > 0).await;
    assert!(int(&status, "velocity") > 0, "{status}");
}

#[tokio::test(start_paused = true)]
async fn umc_profile_position_reaches_the_target() {
    let (app, _) = demo().await;
    enable(&app, UMC, 1).await;
    let start = int(&axis(&app, UMC, 1).await, "position");
    let body = run(
        &app,
        UMC,
        1,
        json!({"mode": "profile_position", "target": 65536, "relative": true}),
    )
    .await;
    assert_eq!(body["mode"], "profile_position", "{body}");
    let status = wait_for(&app, UMC, 1, 5000, |s| s["target_reached"] == true).await;
    assert_eq!(status["target_reached"], true, "{status}");
    let moved = int(&status, "position") - start;
    assert!((moved - 65536).abs() < 2000, "moved {moved}: {status}");
    // Absolute, back to where it started.
    run(
        &app,
        UMC,
        1,
        json!({"mode": "profile_position", "target": start, "velocity": 200, "acceleration": 2}),
    )
    .await;
    let status = wait_for(&app, UMC, 1, 5000, |s| {
        s["target_reached"] == true && (int(s, "position") - start).abs() < 2000
    })
    .await;
    assert!((int(&status, "position") - start).abs() < 2000, "{status}");
}

#[tokio::test(start_paused = true)]
async fn umc_continuous_position_reaches_the_target() {
    let (app, _) = demo().await;
    enable(&app, UMC, 1).await;
    let start = int(&axis(&app, UMC, 1).await, "position");
    let body = run(
        &app,
        UMC,
        1,
        json!({"mode": "continuous_position", "target": start + 30000}),
    )
    .await;
    assert_eq!(body["mode"], "continuous_position", "{body}");
    let status = wait_for(&app, UMC, 1, 5000, |s| {
        s["target_reached"] == true && int(s, "position") > start + 25000
    })
    .await;
    assert_eq!(status["target_reached"], true, "{status}");
    assert!(
        (int(&status, "position") - (start + 30000)).abs() < 2000,
        "{status}"
    );
}

#[tokio::test(start_paused = true)]
async fn umc_interpolated_position_follows_more_points_than_the_buffer_holds() {
    let (app, _) = demo().await;
    enable(&app, UMC, 1).await;
    let start = int(&axis(&app, UMC, 1).await, "position");
    // 80 points, 10 ms apart, 300 increments each: more than the 32 the
    // buffer takes, so the gateway has to feed it as it drains.
    let points: Vec<i64> = (1..=80).map(|i| start + i * 300).collect();
    let body = run(
        &app,
        UMC,
        1,
        json!({"mode": "interpolated_position", "period_ms": 10, "points": points}),
    )
    .await;
    assert_eq!(body["mode"], "interpolated_position", "{body}");
    let end = start + 80 * 300;
    let status = wait_for(&app, UMC, 1, 5000, |s| {
        (int(s, "position") - end).abs() < 500
    })
    .await;
    assert!((int(&status, "position") - end).abs() < 500, "{status}");
}

#[tokio::test(start_paused = true)]
async fn umc_axis_2_is_addressed_at_its_own_objects() {
    let (app, _) = demo().await;
    enable(&app, UMC, 2).await;
    assert_eq!(axis(&app, UMC, 1).await["state"], "switch_on_disabled");
    run(&app, UMC, 2, json!({"mode": "velocity", "velocity": 100})).await;
    let status = wait_for(&app, UMC, 2, 3000, |s| int(s, "velocity") > 0).await;
    assert!(int(&status, "velocity") > 0, "{status}");
    assert_eq!(status["mode"], "velocity");
    let one = axis(&app, UMC, 1).await;
    assert_eq!(int(&one, "velocity"), 0, "{one}");
    assert_ne!(one["mode"], "velocity", "{one}");
}

#[tokio::test(start_paused = true)]
async fn jmc_profile_position_velocity_and_homing() {
    let (app, _) = demo().await;
    enable(&app, JMC, 1).await;
    let start = int(&axis(&app, JMC, 1).await, "position");
    let body = run(
        &app,
        JMC,
        1,
        json!({"mode": "profile_position", "target": start + 4000, "velocity": 50, "acceleration": 1000, "deceleration": 1000}),
    )
    .await;
    assert_eq!(body["mode"], "profile_position", "{body}");
    let status = wait_for(&app, JMC, 1, 5000, |s| {
        s["target_reached"] == true && int(s, "position") == start + 4000
    })
    .await;
    assert_eq!(int(&status, "position"), start + 4000, "{status}");

    // Profile velocity (mode 3), 0x6081 in 0.1 rps.
    let body = run(
        &app,
        JMC,
        1,
        json!({"mode": "velocity", "velocity": -20, "acceleration": 500}),
    )
    .await;
    assert_eq!(body["mode"], "profile_velocity", "{body}");
    let status = wait_for(&app, JMC, 1, 3000, |s| int(s, "velocity") == -20).await;
    assert_eq!(int(&status, "velocity"), -20, "{status}");
    let position = int(&status, "position");
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert!(int(&axis(&app, JMC, 1).await, "position") < position);

    // Homing on the origin switch (method 3), the mode changed from a
    // running velocity mode (by the client that started it).
    let body = run_holding(
        &app,
        JMC,
        1,
        &body,
        json!({"mode": "homing", "method": 3, "speeds": [50, 10], "acceleration": 1000}),
    )
    .await;
    assert_eq!(body["mode"], "homing", "{body}");
    let status = wait_for(&app, JMC, 1, 60_000, |s| {
        s["target_reached"] == true && s["statusword"].as_u64().unwrap() & 0x1000 != 0
    })
    .await;
    assert_eq!(status["target_reached"], true, "{status}");
    assert_eq!(int(&status, "position"), 0, "homed: {status}");
}

#[tokio::test(start_paused = true)]
async fn errors_unknown_axis_unsupported_mode_invalid_body_not_enabled() {
    let (app, _) = demo().await;
    for uri in [
        axis_uri(UMC, 3, ""),
        axis_uri(UMC, 0, ""),
        axis_uri(JMC, 2, ""),
    ] {
        let response = call(&app, Method::GET, &uri, None).await;
        assert_error(&response, StatusCode::NOT_FOUND, "unknown_axis");
    }
    let response = post(
        &app,
        &axis_uri(UMC, 3, "/move"),
        json!({"mode": "velocity", "velocity": 1}),
    )
    .await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_axis");

    enable(&app, JMC, 1).await;
    let response = post(
        &app,
        &axis_uri(JMC, 1, "/move"),
        json!({"mode": "torque", "torque": 100}),
    )
    .await;
    assert_error(
        &response,
        StatusCode::UNPROCESSABLE_ENTITY,
        "mode_not_supported",
    );
    enable(&app, UMC, 1).await;
    let response = post(
        &app,
        &axis_uri(UMC, 1, "/move"),
        json!({"mode": "homing", "method": 1}),
    )
    .await;
    assert_error(
        &response,
        StatusCode::UNPROCESSABLE_ENTITY,
        "mode_not_supported",
    );

    for body in [
        json!({"mode": "warp", "target": 1}),
        json!({"mode": "profile_position"}),
        json!({"mode": "torque", "torque": 40000}),
        json!({"mode": "velocity", "velocity": 1, "extra": 1}),
    ] {
        let response = post(&app, &axis_uri(UMC, 1, "/move"), body.clone()).await;
        assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
    }
    // Values that do not fit the product's objects, before the bus.
    let response = post(
        &app,
        &axis_uri(JMC, 1, "/move"),
        json!({"mode": "velocity", "velocity": 10, "acceleration": 70000}),
    )
    .await;
    assert_error(&response, StatusCode::BAD_REQUEST, "value_out_of_range");
    let response = post(
        &app,
        &axis_uri(UMC, 1, "/move"),
        json!({"mode": "velocity", "velocity": 40000}),
    )
    .await;
    assert_error(&response, StatusCode::BAD_REQUEST, "value_out_of_range");
    let response = post(
        &app,
        &axis_uri(JMC, 1, "/move"),
        json!({"mode": "homing", "method": 13}),
    )
    .await;
    assert_error(&response, StatusCode::BAD_REQUEST, "value_out_of_range");
    let response = post(
        &app,
        &axis_uri(UMC, 1, "/move"),
        json!({"mode": "interpolated_position", "period_ms": 10, "points": []}),
    )
    .await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_value");
    let response = post(
        &app,
        &axis_uri(UMC, 1, "/move"),
        json!({"mode": "interpolated_position", "period_ms": 255, "points": vec![0; 3000]}),
    )
    .await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_value");
    let response = post(
        &app,
        &axis_uri(UMC, 1, "/state"),
        json!({"target": "fault"}),
    )
    .await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");
    let response = post(&app, &axis_uri(UMC, 1, "/halt"), json!({})).await;
    assert_error(&response, StatusCode::BAD_REQUEST, "invalid_request");

    // A move needs operation enabled.
    let response = post(
        &app,
        &axis_uri(UMC, 2, "/move"),
        json!({"mode": "velocity", "velocity": 1}),
    )
    .await;
    assert_error(&response, StatusCode::CONFLICT, "drive_not_enabled");
    assert_eq!(response.1["error"]["state"], "switch_on_disabled");
}

#[tokio::test(start_paused = true)]
async fn a_drive_in_fault_is_409_until_reset() {
    let (app, state) = demo().await;
    enable(&app, UMC, 1).await;
    let rack = state.gateway.bus("demo").unwrap().rack().cloned().unwrap();
    let umc = NodeId::new(UMC).unwrap();
    rack.inject_fault(umc, Fault::OverTemperature).unwrap();
    let status = wait_for(&app, UMC, 1, 2000, |s| s["state"] == "fault").await;
    assert_eq!(status["state"], "fault", "{status}");
    assert_eq!(status["fault"], true);

    let response = post(
        &app,
        &axis_uri(UMC, 1, "/state"),
        json!({"target": "operation_enabled"}),
    )
    .await;
    assert_error(&response, StatusCode::CONFLICT, "drive_fault");
    assert_eq!(response.1["error"]["state"], "fault");
    let response = post(
        &app,
        &axis_uri(UMC, 1, "/move"),
        json!({"mode": "velocity", "velocity": 1}),
    )
    .await;
    assert_error(&response, StatusCode::CONFLICT, "drive_fault");
    // The condition is still there: the reset cannot leave fault.
    let response = post(&app, &axis_uri(UMC, 1, "/fault-reset"), json!({})).await;
    assert_error(&response, StatusCode::CONFLICT, "drive_fault");

    rack.clear_fault(umc, Fault::OverTemperature).unwrap();
    let mut reset = (StatusCode::OK, Json::Null);
    for _ in 0..100 {
        reset = call(&app, Method::POST, &axis_uri(UMC, 1, "/fault-reset"), None).await;
        if reset.0 == StatusCode::OK {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(reset.0, StatusCode::OK, "{}", reset.1);
    assert_eq!(reset.1["state"], "switch_on_disabled", "{}", reset.1);
    enable(&app, UMC, 1).await;
}

#[tokio::test(start_paused = true)]
async fn stop_all_quick_stops_every_moving_axis() {
    let (app, _) = demo().await;
    enable(&app, UMC, 1).await;
    enable(&app, UMC, 2).await;
    enable(&app, JMC, 1).await;
    run(&app, UMC, 1, json!({"mode": "velocity", "velocity": 100})).await;
    run(&app, UMC, 2, json!({"mode": "velocity", "velocity": -100})).await;
    run(&app, JMC, 1, json!({"mode": "velocity", "velocity": 20})).await;
    wait_for(&app, UMC, 1, 3000, |s| int(s, "velocity") > 0).await;
    wait_for(&app, UMC, 2, 3000, |s| int(s, "velocity") < 0).await;
    wait_for(&app, JMC, 1, 3000, |s| int(s, "velocity") > 0).await;

    let (status, body) = call(&app, Method::POST, "/api/v1/stop-all", None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let mut stopped: Vec<(u64, u64)> = body["stopped"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| (s["node"].as_u64().unwrap(), s["axis"].as_u64().unwrap()))
        .collect();
    stopped.sort();
    assert_eq!(stopped, vec![(1, 1), (1, 2), (2, 1)], "{body}");
    assert_eq!(body["failed"], json!([]), "{body}");
    for (node, number) in [(UMC, 1), (UMC, 2), (JMC, 1)] {
        let status = wait_for(&app, node, number, 5000, |s| int(s, "velocity") == 0).await;
        assert_eq!(int(&status, "velocity"), 0, "{status}");
        assert_ne!(status["state"], "operation_enabled", "{status}");
    }
    // Nothing enabled any more: nothing to stop.
    let (_, body) = call(&app, Method::POST, "/api/v1/stop-all", None).await;
    assert_eq!(body["stopped"], json!([]), "{body}");
}

#[tokio::test(start_paused = true)]
async fn a_fault_during_a_move_ends_it_with_the_error() {
    let (app, state) = demo().await;
    enable(&app, UMC, 1).await;
    // 300 points, 10 ms apart: the gateway feeds the buffer for about 3 s.
    let points: Vec<i64> = (1..=300).map(|i| i * 100).collect();
    let request = {
        let app = app.clone();
        tokio::spawn(async move {
            post(
                &app,
                &axis_uri(UMC, 1, "/move"),
                json!({"mode": "interpolated_position", "period_ms": 10, "points": points}),
            )
            .await
        })
    };
    tokio::time::sleep(Duration::from_millis(500)).await;
    let rack = state.gateway.bus("demo").unwrap().rack().cloned().unwrap();
    rack.inject_fault(NodeId::new(UMC).unwrap(), Fault::OverTemperature)
        .unwrap();
    let response = request.await.unwrap();
    assert!(
        response.0 == StatusCode::CONFLICT || response.0 == StatusCode::UNPROCESSABLE_ENTITY,
        "{}",
        response.1
    );
    let status = wait_for(&app, UMC, 1, 3000, |s| int(s, "velocity") == 0).await;
    assert_eq!(int(&status, "velocity"), 0, "{status}");
}

/// UMC axis 1 turning fast with a slow deceleration, and a profile
/// position move by its lease holder waiting (in a task) for the axis to
/// stop before the mode changes: the stop takes seconds.
async fn pending_mode_change(app: &Router) -> tokio::task::JoinHandle<(StatusCode, Json)> {
    enable(app, UMC, 1).await;
    let running = run(
        app,
        UMC,
        1,
        json!({"mode": "velocity", "velocity": 1000, "deceleration": 1}),
    )
    .await;
    let status = wait_for(app, UMC, 1, 3000, |s| int(s, "velocity") > 500).await;
    assert!(int(&status, "velocity") > 500, "{status}");
    let lease = running["lease"]["id"].as_str().unwrap().to_string();
    let request = {
        let app = app.clone();
        tokio::spawn(async move {
            post_with_lease(
                &app,
                &axis_uri(UMC, 1, "/move"),
                &lease,
                json!({"mode": "profile_position", "target": 0}),
            )
            .await
        })
    };
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert!(!request.is_finished(), "the mode change waits for the stop");
    request
}

/// Found by the soak test: a move that changes the mode of a moving axis
/// waits for the drive to stop first; a fault during that stop left the
/// change pending for good, and the move answered 504 after 5 s.
#[tokio::test(start_paused = true)]
async fn a_fault_during_a_pending_mode_change_is_409_not_a_timeout() {
    let (app, state) = demo().await;
    let request = pending_mode_change(&app).await;
    let rack = state.gateway.bus("demo").unwrap().rack().cloned().unwrap();
    rack.inject_fault(NodeId::new(UMC).unwrap(), Fault::OverTemperature)
        .unwrap();
    let response = request.await.unwrap();
    assert_error(&response, StatusCode::CONFLICT, "drive_fault");
}

/// The same with STOP ALL during the stop (seen in the soak test too): the
/// axis leaves operation enabled, and the move says so at once.
#[tokio::test(start_paused = true)]
async fn stop_all_during_a_pending_mode_change_is_409_not_a_timeout() {
    let (app, _) = demo().await;
    let request = pending_mode_change(&app).await;
    let (status, body) = call(&app, Method::POST, "/api/v1/stop-all", None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let response = request.await.unwrap();
    assert_error(&response, StatusCode::CONFLICT, "drive_not_enabled");
}

#[tokio::test(start_paused = true)]
async fn jmc_halt_keeps_the_rest_of_its_write_only_controlword() {
    let (app, _) = demo().await;
    enable(&app, JMC, 1).await;
    run(
        &app,
        JMC,
        1,
        json!({"mode": "velocity", "velocity": 30, "acceleration": 1000}),
    )
    .await;
    wait_for(&app, JMC, 1, 3000, |s| int(s, "velocity") == 30).await;
    let (code, body) = post(&app, &axis_uri(JMC, 1, "/halt"), json!({"halt": true})).await;
    assert_eq!(code, StatusCode::OK, "{body}");
    let status = wait_for(&app, JMC, 1, 3000, |s| int(s, "velocity") == 0).await;
    assert_eq!(int(&status, "velocity"), 0, "{status}");
    assert_eq!(status["state"], "operation_enabled", "{status}");
    // JMC statusword bit 8: halted.
    assert_ne!(
        status["statusword"].as_u64().unwrap() & 0x0100,
        0,
        "{status}"
    );
    post(&app, &axis_uri(JMC, 1, "/halt"), json!({"halt": false})).await;
    let status = wait_for(&app, JMC, 1, 3000, |s| int(s, "velocity") == 30).await;
    assert_eq!(int(&status, "velocity"), 30, "{status}");
}

#[tokio::test(start_paused = true)]
async fn the_node_summary_lists_a_drives_axes() {
    let (_, state) = demo().await;
    for (node, axes) in [(UMC, 2), (JMC, 1)] {
        let summary = state
            .gateway
            .node_handle("demo", &node.to_string())
            .unwrap()
            .read_axes(&crate::gateway::Caller::system())
            .await
            .unwrap();
        assert_eq!(summary.len(), axes, "node {node}: {summary:?}");
        for (i, axis) in summary.iter().enumerate() {
            assert_eq!(usize::from(axis.axis), i + 1);
            assert_eq!(axis.state, "switch_on_disabled");
        }
    }
    let led = state
        .gateway
        .node_handle("demo", &LED.to_string())
        .unwrap()
        .read_axes(&crate::gateway::Caller::system())
        .await
        .unwrap_err();
    assert_eq!(led.code(), "not_a_drive");
}

/// A CiA 402 device of no known product whose PDS never moves: its
/// statusword stays switch on disabled whatever is written to 0x6040; 0x6502
/// lists profile position and profile velocity.
fn stuck_cia402_drive(node: u8, statusword: &str, mode: &str) -> crate::sim::device::DeviceCore {
    use crate::canopen::od::{
        AccessType, DataType, Object, ObjectDictionary, ObjectType, SubObject,
    };
    let var = |index: u16, name: &str, data_type: DataType, access: AccessType, default: &str| {
        let mut sub = SubObject::new(0, name, data_type, access);
        sub.default = Some(default.to_string());
        Object::var(index, sub)
    };
    let mut dictionary = ObjectDictionary::new();
    dictionary.insert(var(
        0x1000,
        "Device type",
        DataType::Unsigned32,
        AccessType::Ro,
        "0x00020192",
    ));
    let mut identity = Object::new(0x1018, "Identity", ObjectType::Record);
    let mut count = SubObject::new(0, "Count", DataType::Unsigned8, AccessType::Const);
    count.default = Some("1".into());
    identity.insert_sub(count);
    let mut vendor = SubObject::new(1, "Vendor", DataType::Unsigned32, AccessType::Ro);
    vendor.default = Some("0x12345678".into());
    identity.insert_sub(vendor);
    dictionary.insert(identity);
    dictionary.insert(var(
        0x6040,
        "Controlword",
        DataType::Unsigned16,
        AccessType::Rw,
        "0",
    ));
    dictionary.insert(var(
        0x6041,
        "Statusword",
        DataType::Unsigned16,
        AccessType::Ro,
        statusword,
    ));
    dictionary.insert(var(
        0x6060,
        "Modes",
        DataType::Integer8,
        AccessType::Rw,
        "0",
    ));
    dictionary.insert(var(
        0x6061,
        "Modes display",
        DataType::Integer8,
        AccessType::Ro,
        mode,
    ));
    dictionary.insert(var(
        0x6064,
        "Position",
        DataType::Integer32,
        AccessType::Ro,
        "1234",
    ));
    dictionary.insert(var(
        0x607A,
        "Target position",
        DataType::Integer32,
        AccessType::Rw,
        "0",
    ));
    dictionary.insert(var(
        0x6502,
        "Supported modes",
        DataType::Unsigned32,
        AccessType::Ro,
        "0x05",
    ));
    crate::sim::device::DeviceCore::new(dictionary, NodeId::new(node).unwrap()).unwrap()
}

#[tokio::test(start_paused = true)]
async fn a_generic_cia402_drive_that_does_not_follow_times_out_with_its_state() {
    let (app, state) = demo().await;
    let served = &state.gateway.bus("demo").unwrap();
    served
        .rack()
        .unwrap()
        .add_device(stuck_cia402_drive(9, "0x0040", "0"))
        .unwrap();
    served.scan().await.unwrap();
    let info = served.node(NodeId::new(9).unwrap()).unwrap();
    assert_eq!(info.profile.name(), "cia402", "{info:?}");

    let (status, body) = call(&app, Method::GET, "/api/v1/buses/demo/nodes/9/axes", None).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body.as_array().unwrap().len(), 1, "{body}");
    assert_eq!(
        body[0]["supported_modes"],
        json!(["profile_position", "velocity"])
    );
    assert_eq!(body[0]["position"], 1234);
    assert_eq!(body[0]["velocity"], Json::Null, "no 0x606C: {body}");
    assert_eq!(body[0]["torque"], Json::Null, "no 0x6077: {body}");

    let response = post(
        &app,
        "/api/v1/buses/demo/nodes/9/axes/1/state",
        json!({"target": "operation_enabled"}),
    )
    .await;
    assert_error(
        &response,
        StatusCode::GATEWAY_TIMEOUT,
        "state_change_timeout",
    );
    assert_eq!(
        response.1["error"]["state"], "switch_on_disabled",
        "{}",
        response.1
    );

    for mode in [
        json!({"mode": "torque", "torque": 1}),
        json!({"mode": "duty_cycle", "duty": 1}),
    ] {
        let response = post(&app, "/api/v1/buses/demo/nodes/9/axes/1/move", mode).await;
        assert_error(
            &response,
            StatusCode::UNPROCESSABLE_ENTITY,
            "mode_not_supported",
        );
    }
    let response = post(
        &app,
        "/api/v1/buses/demo/nodes/9/axes/1/move",
        json!({"mode": "velocity", "velocity": 5}),
    )
    .await;
    assert_error(&response, StatusCode::CONFLICT, "drive_not_enabled");
}

#[tokio::test(start_paused = true)]
async fn a_client_that_hangs_up_mid_interpolated_move_gets_its_axis_halted() {
    let (app, _) = demo().await;
    enable(&app, UMC, 1).await;
    let start = int(&axis(&app, UMC, 1).await, "position");
    let points: Vec<i64> = (1..=400).map(|i| start + i * 300).collect();
    // The client gives up after 100 ms, long before the 4 s of points are
    // all in the buffer: axum drops the handler's future. The request held
    // the move's lease, which lapses with it: the axis is halted rather
    // than left to run on points nobody watches.
    let gave_up = tokio::time::timeout(
        Duration::from_millis(100),
        post(
            &app,
            &axis_uri(UMC, 1, "/move"),
            json!({"mode": "interpolated_position", "period_ms": 10, "points": points}),
        ),
    )
    .await;
    assert!(gave_up.is_err(), "the move answered within 100 ms");
    tokio::time::sleep(Duration::from_millis(1000)).await;
    let halted = int(&axis(&app, UMC, 1).await, "position");
    tokio::time::sleep(Duration::from_millis(1000)).await;
    let status = axis(&app, UMC, 1).await;
    assert_eq!(int(&status, "position"), halted, "still moving: {status}");
    assert_eq!(int(&status, "velocity"), 0, "{status}");
    // Far short of the last point (400 × 300 after the start).
    assert!(halted - start < 200 * 300, "{start} → {halted}");
    // Stopped, not failed: halted, or quick-stopped by the feeding that
    // ended on a buffer no longer drained.
    assert_eq!(status["fault"], false, "{status}");
}

#[tokio::test(start_paused = true)]
async fn a_move_that_fails_half_way_halts_the_axis_before_answering() {
    let (app, state) = demo().await;
    let served = &state.gateway.bus("demo").unwrap();
    // Operation enabled in profile position, but it never acknowledges a
    // set-point: the target is written, then the wait for bit 12 fails.
    served
        .rack()
        .unwrap()
        .add_device(stuck_cia402_drive(9, "0x0027", "1"))
        .unwrap();
    served.scan().await.unwrap();
    let response = post(
        &app,
        "/api/v1/buses/demo/nodes/9/axes/1/move",
        json!({"mode": "profile_position", "target": 5000}),
    )
    .await;
    assert_error(
        &response,
        StatusCode::GATEWAY_TIMEOUT,
        "state_change_timeout",
    );
    assert_eq!(response.1["error"]["state"], "operation_enabled");
    let read = |index: &str| {
        let app = app.clone();
        let uri = format!("/api/v1/buses/demo/nodes/9/od/{index}/0");
        async move { call(&app, Method::GET, &uri, None).await.1 }
    };
    assert_eq!(
        read("0x607A").await["raw"],
        "88130000",
        "the target went out"
    );
    // The last controlword is enable operation with halt (bit 8), written
    // after the failure and before the answer.
    let controlword = read("0x6040").await;
    assert_eq!(controlword["raw"], "0f01", "{controlword}");
}

#[tokio::test(start_paused = true)]
async fn a_drive_whose_heartbeat_is_lost_is_refused_at_once_until_heard_again() {
    let (app, state) = demo().await;
    let jmc = NodeId::new(2).unwrap();
    let served = &state.gateway.bus("demo").unwrap();
    let period = served.node(jmc).unwrap().heartbeat_ms.unwrap();
    served.rack().unwrap().unplug(jmc).unwrap();
    // Lost after heartbeat_consumer_factor (3) periods of silence.
    tokio::time::sleep(Duration::from_millis(4 * period)).await;
    assert!(!served.node(jmc).unwrap().online);

    let started = tokio::time::Instant::now();
    let refused = post(
        &app,
        &axis_uri(2, 1, "/state"),
        json!({"target": "operation_enabled"}),
    )
    .await;
    assert_error(&refused, StatusCode::CONFLICT, "node_offline");
    // Refused before any SDO timeout could run out.
    assert_eq!(started.elapsed(), Duration::ZERO);
    // A stop is never refused: the halt is sent, and with no answer the
    // gateway falls back to the quick stop, then NMT stop of the node.
    let (status, body) = post(&app, &axis_uri(2, 1, "/halt"), json!({"halt": true})).await;
    assert_eq!(status, StatusCode::GATEWAY_TIMEOUT, "{body}");
    let methods: Vec<&str> = body["error"]["attempts"]
        .as_array()
        .unwrap_or_else(|| panic!("{body}"))
        .iter()
        .map(|a| a["method"].as_str().unwrap())
        .collect();
    assert_eq!(methods, ["halt", "quick_stop", "nmt_stop"], "{body}");

    // The NMT stop crosses the wire after the answer: the cable goes back
    // in once it has (a drive plugged in meanwhile would hear it).
    tokio::time::sleep(Duration::from_millis(5)).await;
    served.rack().unwrap().plug(jmc).unwrap();
    tokio::time::sleep(Duration::from_millis(2 * period)).await;
    assert!(served.node(jmc).unwrap().online);
    enable(&app, 2, 1).await;
}

/// The soak's `state_change_timeout` on an axis being enabled (issue 19,
/// point 11): a stop by someone else (STOP ALL, a quick stop, a lapsed
/// lease) takes the drive to switch on disabled while the walk waits for
/// operation enabled, which no command of the walk leads to any more. It
/// waited out its 5 s and answered 504 "did not happen in time; the drive
/// stopped in switch_on_disabled"; it now answers 409 at once. The drive
/// here follows no controlword: the test moves its statusword as the stop
/// would.
#[tokio::test(start_paused = true)]
async fn a_stop_during_an_enable_walk_is_409_not_a_timeout() {
    let (app, state) = demo().await;
    let served = &state.gateway.bus("demo").unwrap();
    let rack = served.rack().unwrap();
    // Switched on: the walk to operation enabled is one step.
    rack.add_device(stuck_cia402_drive(9, "0x0023", "1"))
        .unwrap();
    served.scan().await.unwrap();
    let request = {
        let app = app.clone();
        tokio::spawn(async move {
            post(
                &app,
                "/api/v1/buses/demo/nodes/9/axes/1/state",
                json!({"target": "operation_enabled"}),
            )
            .await
        })
    };
    // The walk is waiting for its step; the stop comes.
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert!(!request.is_finished());
    rack.with_device(NodeId::new(9).unwrap(), |core| {
        core.store_mut()
            .set(0x6041, 0, crate::canopen::od::Value::Unsigned16(0x0040))
            .unwrap();
    })
    .unwrap();
    let response = request.await.unwrap();
    assert_error(&response, StatusCode::CONFLICT, "drive_not_enabled");
    assert_eq!(response.1["error"]["state"], "switch_on_disabled");
    let message = response.1["error"]["message"].as_str().unwrap();
    assert!(message.contains("interrupted"), "{message}");
}

/// The same race in a profile position move (issue 19, point 11: the third
/// 30-minute soak): STOP ALL took the drive out of operation enabled while
/// the move waited for its set-point acknowledge, which then waited out its
/// time and answered 504 "set-point acknowledge did not happen in time; the
/// drive stopped in switch_on_disabled". It is 409 at once now.
#[tokio::test(start_paused = true)]
async fn a_stop_during_a_set_point_wait_is_409_not_a_timeout() {
    let (app, state) = demo().await;
    let served = &state.gateway.bus("demo").unwrap();
    let rack = served.rack().unwrap();
    // Operation enabled in profile position; it never acknowledges.
    rack.add_device(stuck_cia402_drive(9, "0x0027", "1"))
        .unwrap();
    served.scan().await.unwrap();
    let request = {
        let app = app.clone();
        tokio::spawn(async move {
            post(
                &app,
                "/api/v1/buses/demo/nodes/9/axes/1/move",
                json!({"mode": "profile_position", "target": 5000}),
            )
            .await
        })
    };
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert!(!request.is_finished());
    rack.with_device(NodeId::new(9).unwrap(), |core| {
        core.store_mut()
            .set(0x6041, 0, crate::canopen::od::Value::Unsigned16(0x0040))
            .unwrap();
    })
    .unwrap();
    let response = request.await.unwrap();
    assert_error(&response, StatusCode::CONFLICT, "drive_not_enabled");
    assert_eq!(response.1["error"]["state"], "switch_on_disabled");
    let message = response.1["error"]["message"].as_str().unwrap();
    assert!(message.contains("interrupted"), "{message}");
}

/// Issue 21 point 4: one axis answers with its product's units and the
/// limits the drive applies, read from that axis's own objects (a UMC's
/// axis 2 at +0x800); software limits of 0 and 0 are none.
#[tokio::test(start_paused = true)]
async fn one_axis_answers_with_its_units_and_limits() {
    let (app, _) = demo().await;
    for (index, sub, value) in [
        ("0x687F", 0, 1200),
        ("0x6846", 2, 700),
        ("0x687D", 1, -5000),
        ("0x687D", 2, 9000),
    ] {
        let uri = format!("/api/v1/buses/demo/nodes/{UMC}/od/{index}/{sub}");
        let (status, body) = call(&app, Method::PUT, &uri, Some(json!({"value": value}))).await;
        assert_eq!(status, StatusCode::OK, "{uri}: {body}");
    }
    let second = axis(&app, UMC, 2).await;
    assert_eq!(second["units"]["position"], "increments", "{second}");
    assert_eq!(second["units"]["velocity"], "increments/ms", "{second}");
    assert_eq!(second["units"]["vl_velocity"], "vl units", "{second}");
    assert_eq!(
        second["units"]["position_per_revolution"], 65536.0,
        "{second}"
    );
    let limits = &second["limits"];
    assert_eq!(limits["max_profile_velocity"], 1200, "{second}");
    assert_eq!(limits["vl_max"], 700, "{second}");
    assert_eq!(
        limits["software_position_limit"],
        json!([-5000, 9000]),
        "{second}"
    );
    assert_eq!(limits["vl_dimension_factor"], json!([1, 1]), "{second}");
    // Axis 1 kept its own.
    let first = axis(&app, UMC, 1).await;
    assert_eq!(first["limits"]["max_profile_velocity"], 16384, "{first}");
    assert_eq!(first["limits"]["vl_max"], 1000, "{first}");
    for sub in [1, 2] {
        let uri = format!("/api/v1/buses/demo/nodes/{UMC}/od/0x607D/{sub}");
        let (status, body) = call(&app, Method::PUT, &uri, Some(json!({"value": 0}))).await;
        assert_eq!(status, StatusCode::OK, "{body}");
    }
    let first = axis(&app, UMC, 1).await;
    assert_eq!(
        first["limits"]["software_position_limit"],
        Json::Null,
        "{first}"
    );

    // The JMC: steps and 0.1 rps, and none of the UMC's limit objects.
    let jmc = axis(&app, JMC, 1).await;
    assert_eq!(jmc["units"]["position"], "steps", "{jmc}");
    assert_eq!(jmc["units"]["velocity"], "0.1 rps", "{jmc}");
    assert_eq!(jmc["units"]["rps_per_velocity_unit"], 0.1, "{jmc}");
    assert_eq!(jmc["units"]["vl_velocity"], Json::Null, "{jmc}");
    assert_eq!(jmc["limits"]["max_profile_velocity"], Json::Null, "{jmc}");
    assert_eq!(jmc["limits"]["vl_max"], Json::Null, "{jmc}");
    assert!(jmc["limits"]["profile_velocity"].is_u64(), "{jmc}");
}
