//! The persisted history over the real binary: audit entries written with
//! `--data-dir` are there after a restart, whether candeck stopped on
//! SIGTERM or was killed (SIGKILL) right after its answers; the EMCY and NMT
//! history too; retention options are read.

mod common;

use std::path::PathBuf;
use std::time::Duration;

use common::{http, start, terminate};
use serde_json::Value as Json;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("candeck-history-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// The requests: one that succeeds, one refused before the bus, one the
/// device refuses (an SDO abort); the three answers' statuses.
async fn write_some(address: &str) -> [u16; 3] {
    // The first scan runs in the background: wait for node 1's EDS.
    let mut identified = false;
    for _ in 0..200 {
        let (status, body) = http(address, "GET", "/api/v1/buses/demo/nodes/1", None).await;
        if status == 200 && serde_json::from_str::<Json>(&body).unwrap()["eds"].is_string() {
            identified = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(identified, "node 1 not identified");
    let path = "/api/v1/buses/demo/nodes/1/od/0x1017/0";
    let (ok, body) = http(address, "PUT", path, Some(r#"{"value":250}"#)).await;
    assert_eq!(ok, 200, "{body}");
    let (refused, body) = http(address, "PUT", path, Some(r#"{"value":-1}"#)).await;
    assert_eq!(refused, 400, "{body}");
    let (aborted, body) = http(
        address,
        "PUT",
        "/api/v1/buses/demo/nodes/1/od/0x2FFF/0",
        Some(r#"{"value":1,"data_type":"u8"}"#),
    )
    .await;
    assert_eq!(aborted, 422, "{body}");
    [ok, refused, aborted]
}

async fn audit(address: &str) -> Vec<Json> {
    let (status, body) = http(address, "GET", "/api/v1/events?kind=audit&limit=1000", None).await;
    assert_eq!(status, 200, "{body}");
    serde_json::from_str::<Json>(&body)
        .unwrap()
        .as_array()
        .unwrap()
        .clone()
}

fn check_entries(entries: &[Json], statuses: [u16; 3]) {
    let writes: Vec<&Json> = entries
        .iter()
        .filter(|entry| entry["operation"] == "write object")
        .collect();
    assert_eq!(writes.len(), 3, "{entries:#?}");
    for (entry, status) in writes.iter().zip(statuses) {
        assert_eq!(entry["status"], status, "{entry}");
        assert_eq!(entry["bus"], "demo");
        assert_eq!(entry["node"], 1);
        assert!(
            entry["peer"].as_str().unwrap().starts_with("127.0.0.1:"),
            "{entry}"
        );
    }
    assert_eq!(writes[0]["item"], "0x1017:0");
    let outcomes: Vec<(&Json, &Json)> = writes
        .iter()
        .map(|entry| (&entry["channel"], &entry["outcome"]))
        .collect();
    assert_eq!(
        outcomes,
        [
            (&Json::from("rest"), &Json::from("ok")),
            (&Json::from("rest"), &Json::from("value_out_of_range")),
            (&Json::from("rest"), &Json::from("sdo_abort")),
        ]
    );
    assert_eq!(writes[1]["error_code"], "value_out_of_range");
    assert_eq!(writes[2]["abort_code"], "0x06020000");
}

#[tokio::test]
async fn audit_entries_survive_a_restart() {
    let dir = temp_dir("restart");
    let data = dir.to_str().unwrap();
    let (mut server, _) = start(&["serve", "--data-dir", data]);
    let statuses = write_some(&server.address).await;
    // A fault, for the EMCY history.
    let (status, body) = http(
        &server.address,
        "POST",
        "/api/v1/buses/demo/sim/nodes/1/faults",
        Some(r#"{"kind":"over_temperature"}"#),
    )
    .await;
    assert_eq!(status, 204, "{body}");
    let mut emcy_seen = false;
    for _ in 0..100 {
        let (_, body) = http(&server.address, "GET", "/api/v1/events?kind=emcy", None).await;
        if body.contains("\"node\":1") {
            emcy_seen = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(emcy_seen, "no EMCY in the history");
    assert_eq!(terminate(&mut server).await, Some(0));
    assert!(dir.join("history.sqlite3").is_file());

    let (server, _) = start(&["serve", "--data-dir", data]);
    let entries = audit(&server.address).await;
    check_entries(&entries, statuses);
    // The fault injection is audited too, and the EMCY and the nodes'
    // appearance of the first run are kept.
    assert!(
        entries
            .iter()
            .any(|entry| entry["operation"] == "inject fault")
    );
    let (_, body) = http(&server.address, "GET", "/api/v1/events?kind=emcy", None).await;
    assert!(body.contains("\"node\":1"), "{body}");
    let (_, body) = http(
        &server.address,
        "GET",
        "/api/v1/events?kind=nmt&limit=1000",
        None,
    )
    .await;
    let nmt: Json = serde_json::from_str(&body).unwrap();
    let appeared = nmt
        .as_array()
        .unwrap()
        .iter()
        .filter(|event| event["event"] == "appeared" && event["node"] == 1)
        .count();
    assert!(appeared >= 2, "node 1 appeared in each run: {body}");
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test]
async fn audit_entries_answered_before_a_crash_are_kept() {
    let dir = temp_dir("crash");
    let data = dir.to_str().unwrap();
    let (mut server, _) = start(&["serve", "--data-dir", data, "--retention-days", "0"]);
    let statuses = write_some(&server.address).await;
    // SIGKILL right after the last answer: no shutdown, no checkpoint.
    server.child.kill().unwrap();
    server.child.wait().unwrap();

    let (server, _) = start(&["serve", "--data-dir", data]);
    check_entries(&audit(&server.address).await, statuses);
    drop(server);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test]
async fn without_a_data_dir_the_history_is_in_memory() {
    let (mut server, _) = start(&["serve", "--retention-rows", "2"]);
    let statuses = write_some(&server.address).await;
    check_entries(&audit(&server.address).await, statuses);
    assert_eq!(terminate(&mut server).await, Some(0));
    let (server, _) = start(&["serve"]);
    // Nothing of the first run; only what the new gateway's network manager
    // did at start (as `gateway`).
    let entries = audit(&server.address).await;
    assert!(
        entries.iter().all(|entry| entry["who"] == "gateway"),
        "{entries:?}"
    );
}

#[test]
fn retention_options_are_checked() {
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(["serve", "--retention-days", "soon"])
        .output()
        .unwrap();
    assert_eq!(output.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("--retention-days"), "{stderr}");
}
