//! `POST .../axes/{axis}/step-test` of `candeck serve` over real HTTP: the
//! demo UMC's velocity loop (its motor driving the default load) stepped
//! with P and 4 × P (0x4041.1, Q15.16) gives rise times more than 20 %
//! apart, as UMC manual §3.5 says gains do, with the demo's ramps as they
//! are: the test lifts them and puts them back.

mod common;

use common::{json, poll, start};

const AXIS: &str = "/api/v1/buses/demo/nodes/1/axes/1";

async fn put(address: &str, object: &str, value: i64) {
    let body = format!(r#"{{"value":{value}}}"#);
    let path = format!("/api/v1/buses/demo/nodes/1/od/{object}");
    let (status, answer) = json(address, "PUT", &path, Some(&body)).await;
    assert_eq!(status, 200, "{object}: {answer}");
}

async fn get(address: &str, object: &str) -> i64 {
    let path = format!("/api/v1/buses/demo/nodes/1/od/{object}");
    let (status, answer) = json(address, "GET", &path, None).await;
    assert_eq!(status, 200, "{object}: {answer}");
    answer["value"].as_i64().unwrap()
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
        Some(r#"{"loop":"velocity","from":0,"to":800,"hold_ms":600,"settle_band_pct":2}"#),
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
async fn p_and_four_times_p_give_rise_times_more_than_20_pct_apart_and_the_ramps_are_put_back() {
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
    let ramps = ["0x6048/1", "0x6048/2", "0x6049/1", "0x6049/2", "0x6083/0"];
    let mut before = Vec::new();
    for object in ramps {
        before.push(get(&address, object).await);
    }
    // The demo's VL ramp as it is (1 per ms): the test lifts it.
    let (soft_rise, _) = step(&address, 0.015, 0.0).await;
    let (stiff_rise, _) = step(&address, 0.06, 0.0).await;
    assert!(
        soft_rise > 1.2 * stiff_rise,
        "rise {soft_rise} ms vs {stiff_rise} ms"
    );
    for (object, value) in ramps.iter().zip(before) {
        assert_eq!(get(&address, object).await, value, "{object} put back");
    }
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
