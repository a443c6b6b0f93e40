//! The drives endpoints of `candeck serve` over real HTTP: the demo UMC
//! enabled, run in velocity mode, and stopped by `POST /api/v1/stop-all`.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use serde_json::Value as Json;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

struct Server {
    child: Child,
    address: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `candeck ARGS --listen 127.0.0.1:0` and reads the address from its
/// first stdout line.
fn start(args: &[&str]) -> (Server, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        .env_remove("CANDECK_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
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
    (Server { child, address }, line)
}

/// One request, `Connection: close`; returns the status code and body.
async fn http(address: &str, method: &str, path: &str, body: Option<&str>) -> (u16, String) {
    let mut stream = TcpStream::connect(address).await.unwrap();
    let body = body.unwrap_or("");
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    );
    stream.write_all(request.as_bytes()).await.unwrap();
    let mut response = String::new();
    tokio::time::timeout(
        Duration::from_secs(10),
        stream.read_to_string(&mut response),
    )
    .await
    .expect("answer in time")
    .unwrap();
    let status = response
        .strip_prefix("HTTP/1.1 ")
        .and_then(|rest| rest.get(..3))
        .and_then(|code| code.parse().ok())
        .unwrap_or_else(|| panic!("response: {response}"));
    let (_, body) = response.split_once("\r\n\r\n").unwrap();
    (status, body.to_string())
}

async fn json(address: &str, method: &str, path: &str, body: Option<&str>) -> (u16, Json) {
    let (status, body) = http(address, method, path, body).await;
    let json = serde_json::from_str(&body).unwrap_or_else(|err| panic!("{path}: {err}: {body}"));
    (status, json)
}

/// Polls `GET path` every 50 ms, for at most 10 s, until `done`.
async fn poll(address: &str, path: &str, done: impl Fn(u16, &Json) -> bool) -> (u16, Json) {
    for _ in 0..200 {
        let (status, body) = json(address, "GET", path, None).await;
        if done(status, &body) {
            return (status, body);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    json(address, "GET", path, None).await
}

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

    let (status, body) = json(
        &address,
        "POST",
        &format!("{axis}/state"),
        Some(r#"{"target":"operation_enabled"}"#),
    )
    .await;
    assert_eq!(status, 200, "{body}");
    assert_eq!(body["state"], "operation_enabled");
    let (status, body) = json(
        &address,
        "POST",
        &format!("{axis}/move"),
        Some(r#"{"mode":"velocity","velocity":100}"#),
    )
    .await;
    assert_eq!(status, 200, "{body}");
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
