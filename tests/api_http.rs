//! `candeck serve` as integrators meet it: the real binary on a free port,
//! spoken to in plain HTTP/1.1 over TCP; and its command-line errors.

mod common;

use common::{http, start};
use std::process::{Command, Stdio};
use std::time::Duration;

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
    // That one the gateway refused before the bus (the EDS says ro); an
    // object the EDS does not describe is the device's to refuse.
    let (status, body) = http(
        &address,
        "PUT",
        "/api/v1/buses/demo/nodes/1/od/0x5FF0/0",
        Some(r#"{"value":1,"data_type":"u8"}"#),
    )
    .await;
    assert_eq!(status, 422, "{body}");
    assert!(body.contains(r#""abort_code":"0x06020000""#), "{body}");

    let (status, body) = http(
        &address,
        "PUT",
        "/api/v1/buses/demo/nodes/1/od/0x1017/0",
        Some("{"),
    )
    .await;
    assert_eq!(status, 400, "{body}");
    assert!(body.starts_with(r#"{"error":{"#), "{body}");

    // Prometheus finds the metrics at the root; the device refused a write.
    let (status, body) = http(&address, "GET", "/metrics", None).await;
    assert_eq!(status, 200, "{body}");
    let abort_line = body
        .lines()
        .find(|line| line.starts_with(r#"candeck_sdo_aborts_total{bus="demo",node="1"} "#))
        .unwrap_or_else(|| panic!("{body}"));
    assert!(!abort_line.ends_with(" 0"), "{abort_line}");
    assert!(body.contains("\nprocess_resident_memory_bytes "), "{body}");

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
