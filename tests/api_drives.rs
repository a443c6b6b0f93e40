//! The drives endpoints of `candeck serve` over real HTTP: the demo UMC
//! enabled, run in velocity mode, and stopped by `POST /api/v1/stop-all`.

mod common;

use common::{enable_and_move, json, poll, start};

#[tokio::test]
async fn a_umc_axis_runs_and_stop_all_stops_it() {
    let (server, _) = start(&[]);
    let address = server.address.clone();
    let axis = "/api/v1/buses/demo/nodes/1/axes/1";
    // The registry hears the demo devices boot; the UMC is identified soon.
    let (status, body) = poll(&address, "/api/v1/buses/demo/nodes/1/axes", |status, _| {
        status == 200
    })
    .await;
    assert_eq!(status, 200, "{body}");
    assert_eq!(body.as_array().unwrap().len(), 2, "{body}");

    enable_and_move(&address, axis, r#"{"mode":"velocity","velocity":100}"#).await;
    let (_, body) = poll(&address, axis, |_, s| {
        s["velocity"].as_i64().is_some_and(|v| v > 0)
    })
    .await;
    assert!(body["velocity"].as_i64().unwrap() > 0, "{body}");

    let (status, body) = json(&address, "POST", "/api/v1/stop-all", None).await;
    assert_eq!(status, 200, "{body}");
    assert_eq!(body["stopped"][0]["node"], 1, "{body}");
    assert_eq!(body["stopped"][0]["axis"], 1, "{body}");
    let (_, body) = poll(&address, axis, |_, s| s["velocity"] == 0).await;
    assert_eq!(body["velocity"], 0, "{body}");
    assert_ne!(body["state"], "operation_enabled", "{body}");

    let (status, body) = json(
        &address,
        "POST",
        "/api/v1/buses/demo/nodes/2/axes/1/move",
        Some(r#"{"mode":"torque","torque":10}"#),
    )
    .await;
    assert_eq!(status, 422, "{body}");
    assert_eq!(body["error"]["code"], "mode_not_supported");
}
