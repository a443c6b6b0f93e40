//! A gateway that is told to stop (SIGTERM) leaves no drive moving: the
//! demo devices run in a `candeck vbus` of their own, the gateway reaches
//! them over socketcand, enables UMC axis 1 and runs it in velocity mode,
//! and is terminated; a second gateway on the same bus then finds the axis
//! stopped.

mod common;

use std::time::Duration;

use common::{enable_and_move, poll, start, terminate, vbus};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;

/// One test at a time: each starts gateways (and a `candeck vbus`) whose
/// first scan must find the UMC, which has no heartbeat to be found by.
static SERIAL: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

#[tokio::test]
async fn sigterm_during_a_move_leaves_the_axis_stopped() {
    let _serial = SERIAL.lock().await;
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

/// `candeck serve ARGS --listen 127.0.0.1:0`, its log (stderr) read line by
/// line into a channel: the process, its address and the log.
fn start_logged(args: &[&str]) -> (common::Server, std::sync::mpsc::Receiver<String>) {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        .env("CANDECK_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("candeck starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let address = line
        .strip_prefix("candeck: serving http://")
        .and_then(|rest| rest.split_once('/'))
        .map(|(address, _)| address.to_string())
        .unwrap_or_else(|| panic!("first line: {line}"));
    let (lines, log) = std::sync::mpsc::channel();
    let stderr = child.stderr.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if lines.send(line).is_err() {
                return;
            }
        }
    });
    (common::Server { child, address }, log)
}

/// Waits (at most `limit`) for a log line that contains `text`.
fn wait_for_line(log: &std::sync::mpsc::Receiver<String>, text: &str, limit: Duration) -> bool {
    let deadline = std::time::Instant::now() + limit;
    while let Some(left) = deadline.checked_duration_since(std::time::Instant::now()) {
        match log.recv_timeout(left) {
            Ok(line) if line.contains(text) => return true,
            Ok(_) => {}
            Err(_) => return false,
        }
    }
    false
}

/// A client that opened a connection and sent half a request header.
async fn half_sent_request(address: &str) -> TcpStream {
    let mut stream = TcpStream::connect(address).await.unwrap();
    stream
        .write_all(b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Partial: ")
        .await
        .unwrap();
    stream
}

fn send_sigterm(server: &common::Server) {
    let pid = server.child.id().to_string();
    let killed = std::process::Command::new("kill")
        .args(["-TERM", &pid])
        .status()
        .unwrap();
    assert!(killed.success());
}

/// Issue 19, point 2: a client holding a half-sent request kept the
/// process alive, the axes moving, until SIGKILL: the quick stop ran only
/// once every connection had ended. The axes are stopped first now; the
/// connection is drained afterwards.
#[tokio::test]
async fn sigterm_stops_the_axes_before_draining_a_half_sent_request() {
    let _serial = SERIAL.lock().await;
    let (_vbus, channel) = vbus("127.0.0.1:0");
    let spec = format!("demo=socketcand:{channel}");
    // A grace period longer than the test: only the stop can come first.
    let (mut gateway, log) = start_logged(&[
        "--bus",
        &spec,
        "--lease-ms",
        "60000",
        "--shutdown-grace-ms",
        "600000",
    ]);
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

    let held = half_sent_request(&address).await;
    send_sigterm(&gateway);
    // The drive confirmed the quick stop (the gateway logs only what the
    // statusword showed) while the connection is still held.
    let log = tokio::task::spawn_blocking(move || {
        let seen = wait_for_line(
            &log,
            "shutdown: quick stop of bus demo node 1 axis 1",
            Duration::from_secs(20),
        );
        (seen, log)
    });
    let (seen, _log) = log.await.unwrap();
    assert!(seen, "the axis was quick-stopped while a request was held");
    assert!(
        gateway.child.try_wait().unwrap().is_none(),
        "still draining the held connection"
    );
    // The client gives up: the drain ends, and so does the process.
    drop(held);
    assert_eq!(terminate(&mut gateway).await, Some(0));
}

/// The drain is bounded: a connection that never finishes its request is
/// closed after the grace period, and the process exits.
#[tokio::test]
async fn a_half_sent_request_does_not_outlast_the_grace_period() {
    let _serial = SERIAL.lock().await;
    let (mut gateway, _) = start(&["--shutdown-grace-ms", "500"]);
    let address = gateway.address.clone();
    let (status, _) = poll(&address, "/api/v1/health", |status, _| status == 200).await;
    assert_eq!(status, 200);
    let _held = half_sent_request(&address).await;
    // Within the 5 s terminate() waits, with the connection still open.
    assert_eq!(terminate(&mut gateway).await, Some(0));
}

/// `candeck od read` of node 1's `index` sub 0 as `data_type`, over the
/// socketcand bus `channel` (a client of its own, not the gateway): the
/// value, or `None` when the read failed.
fn od_read(channel: &str, index: &str, data_type: &str) -> Option<i64> {
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args([
            "od",
            "read",
            "--bus",
            &format!("socketcand:{channel}"),
            "--node",
            "1",
        ])
        .args([
            index,
            "0",
            "--type",
            data_type,
            "--json",
            "--timeout",
            "200",
        ])
        .env_remove("CANDECK_LOG")
        .output()
        .expect("candeck od read runs");
    let text = String::from_utf8_lossy(&output.stdout);
    let value: serde_json::Value = serde_json::from_str(text.trim()).ok()?;
    value["value"].as_i64()
}

/// Issue 17, point 4: the gateway is its bus's heartbeat producer, and its
/// network manager writes that heartbeat into the UMC's 0x1016; when the
/// gateway is killed (SIGKILL: no shutdown stop, no lease supervisor) the
/// drive notices by itself (heartbeat consumer timeout, 0x6007 abort
/// connection option) and the axis is at rest, or out of operation
/// enabled, within 3 s.
#[tokio::test]
async fn sigkill_of_the_gateway_stops_the_drive_by_its_own_heartbeat_consumer() {
    let _serial = SERIAL.lock().await;
    let (_vbus, channel) = vbus("127.0.0.1:0");
    let spec = format!("demo=socketcand:{channel}");
    // A lease longer than the test: only the drive itself can stop the axis.
    let (mut gateway, _) = start(&["--bus", &spec, "--lease-ms", "60000"]);
    let address = gateway.address.clone();
    // Node 1 booted by the manager: started, and consuming its heartbeat.
    let (_, machine) = poll(&address, "/api/v1/buses/demo/machine", |_, machine| {
        machine["nodes"].as_array().is_some_and(|nodes| {
            nodes.iter().any(|node| {
                node["id"] == 1 && node["state"] == "ready" && node["nmt"] == "operational"
            })
        })
    })
    .await;
    assert!(machine.to_string().contains("\"operational\""), "{machine}");
    let (status, consumer) = common::json(
        &address,
        "GET",
        "/api/v1/buses/demo/nodes/1/od/0x1016/1",
        None,
    )
    .await;
    assert_eq!(status, 200, "{consumer}");
    // Node 127, 3 × 100 ms.
    assert_eq!(consumer["value"], 0x007F_012C, "{consumer}");
    let axis = "/api/v1/buses/demo/nodes/1/axes/1";
    let (status, body) = poll(&address, axis, |status, _| status == 200).await;
    assert_eq!(status, 200, "{body}");
    enable_and_move(&address, axis, r#"{"mode":"velocity","velocity":300}"#).await;
    let (_, moving) = poll(&address, axis, |_, s| {
        s["velocity"].as_i64().is_some_and(|v| v > 0)
    })
    .await;
    assert!(moving["velocity"].as_i64().unwrap() > 0, "{moving}");

    gateway.child.kill().unwrap();
    gateway.child.wait().unwrap();
    let killed = std::time::Instant::now();
    let deadline = killed + Duration::from_secs(3);
    let channel_read = channel.clone();
    let at_rest = tokio::task::spawn_blocking(move || {
        let mut last = (None, None);
        while std::time::Instant::now() < deadline {
            let velocity = od_read(&channel_read, "0x606C", "i32");
            let statusword = od_read(&channel_read, "0x6041", "u16");
            last = (velocity, statusword);
            // Operation enabled: statusword & 0x6F == 0x27.
            let enabled = statusword.is_some_and(|word| word & 0x6F == 0x27);
            if velocity == Some(0) || (statusword.is_some() && !enabled) {
                return Ok(std::time::Instant::now() - killed);
            }
        }
        Err(last)
    })
    .await
    .unwrap();
    match at_rest {
        Ok(after) => assert!(after <= Duration::from_secs(3)),
        Err((velocity, statusword)) => panic!(
            "3 s after SIGKILL of the gateway the axis still turns: 0x606C = {velocity:?}, 0x6041 = {statusword:?}"
        ),
    }
}
