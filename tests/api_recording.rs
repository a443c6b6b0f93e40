//! Recording through REST against the real `candeck serve`: the log lands
//! in `--data-dir DIR/recordings`, a running recording is flushed when the
//! gateway stops, temporary recordings go with the gateway, and
//! `candeck serve --bus replay:FILE` of a downloaded log finds the nodes
//! that were recorded.

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use common::{http, start, start_with_env, terminate};
use serde_json::Value as Json;

/// A directory of its own under the temporary directory, removed when
/// dropped.
struct Scratch(PathBuf);

impl Scratch {
    fn new(name: &str) -> Self {
        let path = std::env::temp_dir().join(format!(
            "candeck-api-recording-{}-{name}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&path);
        std::fs::create_dir_all(&path).unwrap();
        Self(path)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn json(body: &str) -> Json {
    serde_json::from_str(body).unwrap_or_else(|err| panic!("{err}: {body}"))
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .map(|entry| entry.unwrap().file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
}

#[tokio::test]
async fn a_downloaded_recording_replayed_by_serve_lists_the_recorded_nodes() {
    let scratch = Scratch::new("replay");
    let data_dir = scratch.0.join("data");
    let (mut server, _) = start(&["serve", "--data-dir", data_dir.to_str().unwrap()]);
    let address = server.address.clone();
    let (status, body) = http(&address, "POST", "/api/v1/buses/demo/recording", Some("{}")).await;
    assert_eq!(status, 201, "{body}");
    let file = json(&body)["file"].as_str().unwrap().to_string();
    let (status, body) = http(
        &address,
        "POST",
        "/api/v1/buses/demo/nmt",
        Some(r#"{"command":"reset_communication"}"#),
    )
    .await;
    assert_eq!(status, 200, "{body}");
    // Every node boots again: three boot-ups in the log, and the gateway's
    // own heartbeat (its network manager's, node 127, every 100 ms) after
    // them, which the replay below lists as a node too.
    let boot_ups = ["demo 701#00", "demo 702#00", "demo 703#00", "demo 77F#05"];
    let mut log = String::new();
    for _ in 0..100 {
        let (status, body) = http(&address, "GET", "/api/v1/buses/demo/recording.log", None).await;
        assert_eq!(status, 200, "{body}");
        log = body;
        if boot_ups.iter().all(|line| log.contains(line)) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(boot_ups.iter().all(|line| log.contains(line)), "{log}");
    let (status, body) = http(&address, "DELETE", "/api/v1/buses/demo/recording", None).await;
    assert_eq!(status, 200, "{body}");
    let stopped = json(&body);
    assert_eq!(stopped["stop_reason"], "asked");
    let (status, log) = http(&address, "GET", "/api/v1/buses/demo/recording.log", None).await;
    assert_eq!(status, 200, "{log}");
    assert_eq!(
        log.lines().count() as u64,
        stopped["frames"].as_u64().unwrap()
    );
    // The download is the file kept in the data directory.
    let recordings = data_dir.join("recordings");
    assert_eq!(
        std::fs::read_to_string(recordings.join(&file)).unwrap(),
        log
    );

    // A recording still running when the gateway stops is written out.
    let (status, body) = http(&address, "POST", "/api/v1/buses/demo/recording", Some("{}")).await;
    assert_eq!(status, 201, "{body}");
    let second = json(&body)["file"].as_str().unwrap().to_string();
    http(
        &address,
        "GET",
        "/api/v1/buses/demo/nodes/1/od/0x1000/0",
        None,
    )
    .await;
    assert_eq!(terminate(&mut server).await, Some(0));
    let kept = std::fs::read_to_string(recordings.join(&second)).unwrap();
    assert!(kept.contains(" demo 601#40001000"), "{kept}");
    assert!(kept.ends_with('\n'), "{kept}");

    // The first log, replayed: the gateway hears the boot-ups and lists the nodes.
    let replayed = scratch.0.join("bench.log");
    std::fs::write(&replayed, &log).unwrap();
    let spec = format!("replay:{}", replayed.display());
    let (server, line) = start(&["serve", "--bus", &spec]);
    assert!(line.contains(&format!("(bus bench: {spec})")), "{line}");
    let mut ids = Vec::new();
    for _ in 0..100 {
        let (status, body) = http(&server.address, "GET", "/api/v1/buses/bench/nodes", None).await;
        assert_eq!(status, 200, "{body}");
        ids = json(&body)
            .as_array()
            .unwrap()
            .iter()
            .map(|node| node["id"].as_u64().unwrap())
            .collect();
        if ids.len() == 4 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // The demo's nodes, and the gateway that recorded them: its heartbeat
    // (node 127, the network manager's) is on the recorded bus too.
    assert_eq!(ids, [1, 2, 3, 127]);
}

#[tokio::test]
async fn temporary_recordings_go_with_the_gateway() {
    let scratch = Scratch::new("tmp");
    let (mut server, _) = start_with_env(&["serve"], &[("TMPDIR", &scratch.0)]);
    let address = server.address.clone();
    let (status, body) = http(&address, "POST", "/api/v1/buses/demo/recording", Some("{}")).await;
    assert_eq!(status, 201, "{body}");
    let file = json(&body)["file"].as_str().unwrap().to_string();
    let dirs = files_in(&scratch.0);
    assert_eq!(dirs.len(), 1, "{dirs:?}");
    assert!(dirs[0].starts_with("candeck-recordings-"), "{dirs:?}");
    assert_eq!(files_in(&scratch.0.join(&dirs[0])), [file]);
    assert_eq!(terminate(&mut server).await, Some(0));
    assert_eq!(files_in(&scratch.0), Vec::<String>::new());
}
