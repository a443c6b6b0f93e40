//! A gateway that is told to stop (SIGTERM) leaves no drive moving: the
//! demo devices run in a `candeck vbus` of their own, the gateway reaches
//! them over socketcand, enables UMC axis 1 and runs it in velocity mode,
//! and is terminated; a second gateway on the same bus then finds the axis
//! stopped.

mod common;

use common::{enable_and_move, poll, start, terminate, vbus};

#[tokio::test]
async fn sigterm_during_a_move_leaves_the_axis_stopped() {
    let (_vbus, channel) = vbus("127.0.0.1:0");
    let spec = format!("demo=socketcand:{channel}");
    // A lease longer than the test, so that only the shutdown can have
    // stopped the axis, not its lease lapsing.
    let (mut gateway, _) = start(&["--bus", &spec, "--lease-ms", "60000"]);
    let address = gateway.address.clone();
    let axis = "/api/v1/buses/demo/nodes/1/axes/1";
    let (status, body) = poll(&address, axis, |status, _| status == 200).await;
    assert_eq!(status, 200, "{body}");
    enable_and_move(&address, axis, r#"{"mode":"velocity","velocity":200}"#).await;
    let (_, moving) = poll(&address, axis, |_, s| {
        s["velocity"].as_i64().is_some_and(|v| v > 0)
    })
    .await;
    assert!(moving["velocity"].as_i64().unwrap() > 0, "{moving}");

    assert_eq!(
        terminate(&mut gateway).await,
        Some(0),
        "the gateway exits cleanly"
    );

    // Another gateway on the same bus sees the axis out of operation
    // enabled, and at rest.
    let (second, _) = start(&["--bus", &spec]);
    let (status, body) = poll(&second.address, axis, |status, s| {
        status == 200 && s["velocity"] == 0
    })
    .await;
    assert_eq!(status, 200, "{body}");
    assert_ne!(body["state"], "operation_enabled", "{body}");
    assert_eq!(body["velocity"], 0, "{body}");
}
