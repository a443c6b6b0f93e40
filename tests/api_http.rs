//! `candeck serve` as integrators meet it: the real binary on a free port,
//! spoken to in plain HTTP/1.1 over TCP; and its command-line errors.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

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

#[tokio::test]
async fn serve_answers_http_and_stops_on_sigterm() {
    let (mut server, line) = start(&[]);
    assert!(
        line.trim_end().ends_with("/ (bus demo: virtual:demo)"),
        "{line}"
    );
    let address = server.address.clone();

    let (status, body) = http(&address, "GET", "/api/v1/health", None).await;
    assert_eq!(status, 200, "{body}");
    let health: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert_eq!(health["status"], "ok");
    assert_eq!(health["version"], env!("CARGO_PKG_VERSION"));

    // The demo devices are found by the first scan.
    let mut ids = Vec::new();
    for _ in 0..50 {
        let (status, body) = http(&address, "GET", "/api/v1/buses/demo/nodes", None).await;
        assert_eq!(status, 200, "{body}");
        let nodes: serde_json::Value = serde_json::from_str(&body).unwrap();
        ids = nodes
            .as_array()
            .unwrap()
            .iter()
            .filter(|n| n["identification"]["state"] == "done")
            .map(|n| n["id"].as_u64().unwrap())
            .collect();
        if ids.len() == 3 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(ids, [1, 2, 3]);

    let (status, body) = http(
        &address,
        "GET",
        "/api/v1/buses/demo/nodes/1/od/a1_Statusword/0",
        None,
    )
    .await;
    assert_eq!(status, 200, "{body}");
    assert!(body.contains(r#""index":"0x6041""#), "{body}");

    let (status, body) = http(
        &address,
        "PUT",
        "/api/v1/buses/demo/nodes/1/od/0x1000/0",
        Some(r#"{"value":1}"#),
    )
    .await;
    assert_eq!(status, 422, "{body}");
    assert!(body.contains(r#""abort_code":"0x06010002""#), "{body}");

    let (status, body) = http(
        &address,
        "PUT",
        "/api/v1/buses/demo/nodes/1/od/0x1017/0",
        Some("{"),
    )
    .await;
    assert_eq!(status, 400, "{body}");
    assert!(body.starts_with(r#"{"error":{"#), "{body}");

    // Graceful shutdown: SIGTERM ends the process with status 0.
    let pid = server.child.id().to_string();
    let killed = Command::new("kill").args(["-TERM", &pid]).status().unwrap();
    assert!(killed.success());
    let mut status = None;
    for _ in 0..100 {
        if let Some(exit) = server.child.try_wait().unwrap() {
            status = Some(exit);
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(status.expect("stopped within 5 s").code(), Some(0));
}

#[tokio::test]
async fn serve_takes_named_buses() {
    let (server, line) = start(&[
        "serve",
        "--bus",
        "left=virtual:demo",
        "--bus",
        "virtual:empty",
    ]);
    assert!(
        line.contains("(buses left: virtual:demo, empty: virtual:empty)"),
        "{line}"
    );
    let (status, body) = http(&server.address, "GET", "/api/v1/buses", None).await;
    assert_eq!(status, 200, "{body}");
    let buses: serde_json::Value = serde_json::from_str(&body).unwrap();
    let names: Vec<_> = buses
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b["name"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(names, ["empty", "left"]);
    let (status, _) = http(&server.address, "GET", "/api/v1/buses/demo/nodes", None).await;
    assert_eq!(status, 404);
}

#[test]
fn bad_bus_arguments_give_one_line_and_status_2() {
    let cases: &[(&[&str], &str)] = &[
        (&["--bus", "can0"], "bus spec 'can0' is not one of"),
        (
            &["serve", "--bus", "x y=virtual:demo"],
            "bus name 'x y' is not a name",
        ),
        (
            &["--bus", "a=virtual:demo", "--bus", "a=virtual:empty"],
            "two buses are named 'a'",
        ),
        (&["--listen", "localhost"], "invalid value 'localhost'"),
        (&["--bitrate", "0"], "invalid value '0'"),
    ];
    for (args, expected) in cases {
        let output = Command::new(env!("CARGO_BIN_EXE_candeck"))
            .args(*args)
            .env_remove("CANDECK_LOG")
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
        let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
        assert_eq!(lines.len(), 1, "{args:?}: {stderr}");
        assert!(lines[0].starts_with("candeck: error: "), "{stderr}");
        assert!(lines[0].contains(expected), "'{expected}' not in: {stderr}");
    }
}

#[test]
fn a_port_in_use_is_one_line_and_status_1() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let address = taken.local_addr().unwrap().to_string();
    let output = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(["--listen", &address])
        .env_remove("CANDECK_LOG")
        .stdout(Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    let errors: Vec<&str> = stderr.lines().filter(|l| l.contains("error")).collect();
    assert_eq!(errors.len(), 1, "{stderr}");
    assert!(
        errors[0].starts_with(&format!("candeck: error: cannot listen on {address}")),
        "{stderr}"
    );
}
