//! A gateway that is told to stop (SIGTERM) leaves no drive moving: the
//! demo devices run in a `candeck vbus` of their own, the gateway reaches
//! them over socketcand, enables UMC axis 1 and runs it in velocity mode,
//! and is terminated; a second gateway on the same bus then finds the axis
//! stopped.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};

use common::json;
use common::{poll, start, terminate};

struct Vbus(Child);

impl Drop for Vbus {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `candeck vbus --devices demo` on a free port, and its bus spec.
fn vbus() -> (Vbus, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(["vbus", "--listen", "127.0.0.1:0", "--devices", "demo"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("vbus starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    // "candeck vbus: socketcand on ADDR channel CHANNEL devices ..."
    let words: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(
        words.get(..3),
        Some(&["candeck", "vbus:", "socketcand"][..]),
        "{line}"
    );
    let spec = format!("demo=socketcand:{}/{}", words[4], words[6]);
    (Vbus(child), spec)
}

#[tokio::test]
async fn sigterm_during_a_move_leaves_the_axis_stopped() {
    let (_vbus, spec) = vbus();
    // A lease longer than the test, so that only the shutdown can have
    // stopped the axis, not its lease lapsing.
    let (mut gateway, _) = start(&["--bus", &spec, "--lease-ms", "60000"]);
    let address = gateway.address.clone();
    let axis = "/api/v1/buses/demo/nodes/1/axes/1";
    let (status, body) = poll(&address, axis, |status, _| status == 200).await;
    assert_eq!(status, 200, "{body}");
    let (status, body) = json(
        &address,
        "POST",
        &format!("{axis}/state"),
        Some(r#"{"target":"operation_enabled"}"#),
    )
    .await;
    assert_eq!(status, 200, "{body}");
    let (status, body) = json(
        &address,
        "POST",
        &format!("{axis}/move"),
        Some(r#"{"mode":"velocity","velocity":200}"#),
    )
    .await;
    assert_eq!(status, 200, "{body}");
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
