//! Issue 8, fault tolerance, against the real binaries: the socketcand
//! server behind a bus killed and restarted (bus down, requests 503, the
//! gateway reconnects and the nodes come back), a node unplugged in the
//! middle of SDO transfers and of a move (clean errors, no queue left
//! stuck), and a transport that sends garbage (counted, never fatal).

mod common;

use std::time::Duration;

use common::{enable_and_move, json, poll, start, vbus};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpListener;

fn bus_state(buses: &serde_json::Value) -> &str {
    buses[0]["state"].as_str().unwrap_or("")
}

/// The value of a `/metrics` sample for bus `bus`.
async fn metric(address: &str, family: &str, bus: &str) -> f64 {
    let (status, page) = common::http(address, "GET", "/metrics", None).await;
    assert_eq!(status, 200);
    let prefix = format!("{family}{{bus=\"{bus}\"}} ");
    page.lines()
        .find_map(|line| line.strip_prefix(&prefix))
        .and_then(|value| value.trim().parse().ok())
        .unwrap_or_else(|| panic!("no {prefix} in /metrics"))
}

#[tokio::test]
async fn a_socketcand_server_killed_and_restarted_is_reconnected_and_its_nodes_refreshed() {
    let (vbus_process, channel) = vbus("127.0.0.1:0");
    let listen = channel.split('/').next().unwrap().to_string();
    let (gateway, _) = start(&["--bus", &format!("line=socketcand:{channel}")]);
    let address = gateway.address.clone();
    let nodes = "/api/v1/buses/line/nodes";
    // Found and identified (until then a node's profile is `generic`).
    let (_, listed) = poll(&address, nodes, |status, body| {
        status == 200
            && body.as_array().is_some_and(|n| {
                n.len() == 3 && n.iter().all(|n| n["identification"]["state"] == "done")
            })
    })
    .await;
    assert_eq!(listed.as_array().unwrap().len(), 3, "{listed}");
    let read = "/api/v1/buses/line/nodes/1/od/0x1018/1";
    assert_eq!(json(&address, "GET", read, None).await.0, 200);

    // The server goes away (a crash: SIGKILL).
    drop(vbus_process);
    let (_, buses) = poll(&address, "/api/v1/buses", |_, b| bus_state(b) == "down").await;
    assert_eq!(bus_state(&buses), "down", "{buses}");
    let (status, body) = json(&address, "GET", read, None).await;
    assert_eq!(status, 503, "{body}");
    assert_eq!(body["error"]["code"], "bus_down", "{body}");
    let (status, body) = json(
        &address,
        "POST",
        "/api/v1/buses/line/nodes/1/axes/1/state",
        Some(r#"{"target":"operation_enabled"}"#),
    )
    .await;
    assert!(
        status == 503 || body["error"]["code"] == "node_offline",
        "{status} {body}"
    );
    // The gateway itself is fine meanwhile.
    assert_eq!(json(&address, "GET", "/api/v1/health", None).await.0, 200);

    // Back on the same address: the gateway reconnects by itself, the
    // devices boot again and are online, and requests work.
    let (_vbus_again, _) = vbus(&listen);
    let (_, buses) = poll(&address, "/api/v1/buses", |_, b| bus_state(b) == "up").await;
    assert_eq!(bus_state(&buses), "up", "{buses}");
    let (status, body) = poll(&address, read, |status, _| status == 200).await;
    assert_eq!(status, 200, "{body}");
    let (_, listed) = poll(&address, nodes, |_, body| {
        body.as_array()
            .is_some_and(|n| n.len() == 3 && n.iter().all(|n| n["online"] == true))
    })
    .await;
    assert!(
        listed
            .as_array()
            .unwrap()
            .iter()
            .all(|n| n["online"] == true),
        "{listed}"
    );
    assert_eq!(
        metric(&address, "candeck_bus_reconnects_total", "line").await,
        1.0
    );
    // The restart is in the NMT history: the nodes booted again.
    let (_, events) = json(&address, "GET", "/api/v1/events?kind=nmt&limit=100", None).await;
    assert!(
        events.as_array().unwrap().iter().any(|e| e["node"] == 1),
        "{events}"
    );
}

#[tokio::test]
async fn a_node_unplugged_mid_transfer_and_mid_move_fails_cleanly_and_leaves_no_queue_stuck() {
    let (gateway, _) = start(&[]);
    let address = gateway.address.clone();
    let axis = "/api/v1/buses/demo/nodes/1/axes/1";
    poll(&address, axis, |status, _| status == 200).await;
    enable_and_move(&address, axis, r#"{"mode":"velocity","velocity":100}"#).await;

    // A DCF backup is a long run of SDO uploads: unplug the UMC under it.
    let backup = tokio::spawn({
        let address = address.clone();
        async move {
            common::http(
                &address,
                "GET",
                "/api/v1/buses/demo/nodes/1/config.dcf",
                None,
            )
            .await
        }
    });
    tokio::time::sleep(Duration::from_millis(30)).await;
    let (status, body) =
        common::http(&address, "DELETE", "/api/v1/buses/demo/sim/nodes/1", None).await;
    assert!(status < 300, "{status} {body}");
    let (status, body) = tokio::time::timeout(Duration::from_secs(30), backup)
        .await
        .expect("the backup ends")
        .unwrap();
    // Either it finished before the unplug took effect, or it failed in
    // the API's words: a timeout or the node gone, never a hang or a 500.
    if status != 200 {
        let body: serde_json::Value = serde_json::from_str(&body).unwrap();
        let code = body["error"]["code"].as_str().unwrap_or("");
        assert!(
            matches!(code, "sdo_timeout" | "node_offline"),
            "{status} {body}"
        );
    }
    // The moving axis is gone: drive requests fail in words.
    let (status, body) = json(&address, "GET", axis, None).await;
    assert!(matches!(status, 409 | 504), "{status} {body}");
    // The other nodes are not held up by the dead one's queue.
    let (status, body) = json(&address, "GET", "/api/v1/buses/demo/nodes/3/segments", None).await;
    assert_eq!(status, 200, "{body}");
    let (status, body) = json(&address, "GET", "/api/v1/buses/demo/nodes/2/axes/1", None).await;
    assert_eq!(status, 200, "{body}");

    // Plugged back: it boots, and its queue serves again.
    let (status, body) = json(
        &address,
        "POST",
        "/api/v1/buses/demo/sim/nodes",
        Some(r#"{"product":"umc1bds32","id":1}"#),
    )
    .await;
    assert!(status < 300, "{status} {body}");
    let (status, body) = poll(&address, axis, |status, _| status == 200).await;
    assert_eq!(status, 200, "{body}");
    // A fresh device: at rest, not enabled.
    assert_ne!(body["state"], "operation_enabled", "{body}");
}

/// A socketcand server that says hello properly, then sends `lines`, one
/// every 20 ms, each after a good frame of node 5's heartbeat, until the
/// client hangs up.
async fn garbage_server(lines: &'static [&'static str]) -> String {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap().to_string();
    tokio::spawn(async move {
        let (mut socket, _) = listener.accept().await.unwrap();
        socket.write_all(b"< hi >").await.unwrap();
        let mut buffer = [0u8; 256];
        let mut seen = String::new();
        // `< open can0 >` then `< rawmode >`, each answered `< ok >`.
        for expected in ["open", "rawmode"] {
            while !seen.contains(expected) {
                let n = socket.read(&mut buffer).await.unwrap();
                assert!(n > 0, "the client hung up during the handshake");
                seen.push_str(&String::from_utf8_lossy(&buffer[..n]));
            }
            socket.write_all(b"< ok >").await.unwrap();
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
        for garbage in lines.iter().cycle() {
            let heartbeat = socket.write_all(b"< frame 705 1.000000 05 >").await;
            if heartbeat.is_err() || socket.write_all(garbage.as_bytes()).await.is_err() {
                return;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    });
    address
}

#[tokio::test]
async fn malformed_frames_from_the_transport_are_counted_and_never_fatal() {
    let address = garbage_server(&[
        "< frame XYZ 1.0 00 >",
        "< frame 123 1.0 0G >",
        "< frame 7FF 1.0 001122334455667788 >",
        "< frame >",
    ])
    .await;
    let (gateway, _) = start(&["--bus", &format!("line=socketcand:{address}/can0")]);
    let http = gateway.address.clone();
    // Node 5 appears from its heartbeat between the garbage.
    let (status, body) = poll(&http, "/api/v1/buses/line/nodes/5", |status, _| {
        status == 200
    })
    .await;
    assert_eq!(status, 200, "{body}");
    // Every kind of garbage, several times over: each counted, none fatal.
    let mut malformed = 0.0;
    for _ in 0..200 {
        malformed = metric(&http, "candeck_bus_malformed_total", "line").await;
        if malformed >= 20.0 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(malformed >= 20.0, "{malformed} malformed lines counted");
    // The good frames between them kept coming in, and the bus is up.
    let (_, buses) = json(&http, "GET", "/api/v1/buses", None).await;
    assert_eq!(bus_state(&buses), "up", "{buses}");
    assert!(buses[0]["rx_frames"].as_u64().unwrap() >= 20, "{buses}");
    assert_eq!(json(&http, "GET", "/api/v1/health", None).await.0, 200);
}
