//! `POST .../axes/{axis}/step-test` of `candeck serve` over real HTTP: the
//! demo UMC's velocity loop stepped with two proportional gains
//! (0x4041.1, Q15.16) gives measurably different rise times and
//! overshoots, as UMC manual §3.5 says gains do.

mod common;

use common::{json, poll, start};

const AXIS: &str = "/api/v1/buses/demo/nodes/1/axes/1";

async fn put(address: &str, object: &str, value: i64) {
    let body = format!(r#"{{"value":{value}}}"#);
    let path = format!("/api/v1/buses/demo/nodes/1/od/{object}");
    let (status, answer) = json(address, "PUT", &path, Some(&body)).await;
    assert_eq!(status, 200, "{object}: {answer}");
}

/// A velocity step 0 → 800 with the velocity loop's P and I (A/rpm,
/// A/(rpm·s)): rise time (ms) and overshoot (%).
async fn step(address: &str, p: f64, i: f64) -> (f64, f64) {
    put(address, "0x4041/1", (p * 65536.0).round() as i64).await;
    put(address, "0x4041/2", (i * 65536.0).round() as i64).await;
    let (status, answer) = json(
        address,
        "POST",
        &format!("{AXIS}/step-test"),
        Some(r#"{"loop":"velocity","from":0,"to":800,"hold_ms":400,"settle_band_pct":2}"#),
    )
    .await;
    assert_eq!(status, 200, "{answer}");
    assert!(answer["samples"].as_array().unwrap().len() > 50, "{answer}");
    (
        answer["rise_time_ms"]
            .as_f64()
            .expect("the step reached 90 %"),
        answer["overshoot_pct"].as_f64().unwrap(),
    )
}

#[tokio::test]
async fn two_velocity_gains_give_different_rise_times_and_overshoots() {
    let (server, _) = start(&[]);
    let address = server.address.clone();
    let (status, body) = poll(&address, "/api/v1/buses/demo/nodes/1/axes", |status, _| {
        status == 200
    })
    .await;
    assert_eq!(status, 200, "{body}");
    let (status, body) = json(
        &address,
        "POST",
        &format!("{AXIS}/state"),
        Some(r#"{"target":"operation_enabled"}"#),
    )
    .await;
    assert_eq!(status, 200, "{body}");
    // A steep VL ramp: the loop, not the ramp, shapes the step.
    put(&address, "0x6046/2", 10_000).await;
    put(&address, "0x6048/1", 10_000).await;
    put(&address, "0x6048/2", 1).await;
    // And down: the axis is back at rest before the next step.
    put(&address, "0x6049/1", 10_000).await;
    put(&address, "0x6049/2", 1).await;
    // The stiff gain first: whatever the first test leaves behind favours
    // the second, the soft one.
    let (stiff_rise, stiff_overshoot) = step(&address, 0.02, 0.4).await;
    let (soft_rise, soft_overshoot) = step(&address, 0.004, 0.4).await;
    assert!(
        soft_rise >= 2.0 * stiff_rise,
        "rise {soft_rise} ms vs {stiff_rise} ms"
    );
    assert!(
        soft_overshoot > stiff_overshoot + 5.0,
        "overshoot {soft_overshoot} % vs {stiff_overshoot} %"
    );
    // Halted at the end.
    let (_, word) = json(
        &address,
        "GET",
        "/api/v1/buses/demo/nodes/1/od/0x6040/0",
        None,
    )
    .await;
    assert_ne!(word["value"].as_i64().unwrap() & 0x100, 0, "{word}");
}
