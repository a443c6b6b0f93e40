//! `candeck serve` options over the real binary: `--share` (a virtual bus
//! joined over socketcand), `--config` (a TOML file, the command line over
//! it, its errors) and `--data-dir` (saved parameters survive a restart).

use std::io::{BufRead, BufReader, Lines};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::Duration;

use candeck::can::spec::BusSpec;
use candeck::can::{Bus, CanId, Frame};
use serde_json::{Value as Json, json};

struct Server {
    child: Child,
    address: String,
    stdout: Lines<BufReader<ChildStdout>>,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `candeck ARGS` and reads the HTTP address from its first stdout
/// line.
fn start(args: &[&str]) -> Server {
    let mut child = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(args)
        .env_remove("CANDECK_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("candeck starts");
    let mut stdout = BufReader::new(child.stdout.take().unwrap()).lines();
    let line = stdout.next().expect("a first line").unwrap();
    let address = line
        .strip_prefix("candeck: serving http://")
        .and_then(|rest| rest.split_once('/'))
        .map(|(address, _)| address.to_string())
        .unwrap_or_else(|| panic!("first line: {line}"));
    Server {
        child,
        address,
        stdout,
    }
}

mod common;

/// One request, `Connection: close`; returns the status code and the body
/// as JSON (null when empty).
async fn http(address: &str, method: &str, path: &str, body: Option<&str>) -> (u16, Json) {
    let (status, body) = common::http(address, method, path, body).await;
    let json = if body.is_empty() {
        Json::Null
    } else {
        serde_json::from_str(&body).unwrap_or_else(|err| panic!("{err}: {body}"))
    };
    (status, json)
}

/// Waits until the gateway has identified `count` nodes of `bus`.
async fn wait_for_nodes(address: &str, bus: &str, count: usize) {
    for _ in 0..100 {
        let (_, nodes) = http(address, "GET", &format!("/api/v1/buses/{bus}/nodes"), None).await;
        let done = nodes.as_array().map_or(0, |nodes| {
            nodes
                .iter()
                .filter(|node| node["identification"]["state"] == "done")
                .count()
        });
        if done >= count {
            return;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("{count} nodes of {bus} not identified");
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("candeck-ops-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The next frame of `id` on `bus` within 5 s.
async fn frame_of(frames: &mut candeck::can::FrameReceiver, id: u32) -> Frame {
    tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            let timed = frames.recv().await.unwrap();
            if timed.frame.id().raw() == id {
                return timed.frame;
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("no frame 0x{id:X}"))
}

#[tokio::test]
async fn share_lets_another_program_join_the_virtual_bus() {
    let mut server = start(&["--listen", "127.0.0.1:0", "--share", "127.0.0.1:0"]);
    let line = server.stdout.next().expect("a second line").unwrap();
    let share = line
        .strip_prefix("candeck: sharing bus demo over socketcand on ")
        .and_then(|rest| rest.split_once(' '))
        .map(|(address, _)| address.to_string())
        .unwrap_or_else(|| panic!("second line: {line}"));
    // Our socketcand client, as another program would join.
    let spec: BusSpec = format!("socketcand:{share}/demo").parse().unwrap();
    let peer: Bus = spec.open("peer").await.unwrap().bus;
    peer.wait_up(Duration::from_secs(5)).await.unwrap();
    let mut frames = peer.subscribe();
    // The peer asks node 1 for 0x1000 and the demo device answers.
    let request = Frame::new(
        CanId::standard(0x601).unwrap(),
        &[0x40, 0x00, 0x10, 0, 0, 0, 0, 0],
    )
    .unwrap();
    peer.send(request).await.unwrap();
    // The gateway reads node 1 too (identification, TPDO mappings) with the
    // same default SDO channel: its answers are on 0x581 as well, so wait
    // for the one to this request, by its multiplexer.
    let answer = tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            let answer = frame_of(&mut frames, 0x581).await;
            if answer.data()[1..4] == [0x00, 0x10, 0x00] {
                return answer;
            }
        }
    })
    .await
    .expect("the answer to 0x1000");
    assert_eq!(answer.data()[..4], [0x43, 0x00, 0x10, 0x00]);
    // A frame posted through REST reaches the peer...
    let (status, body) = http(
        &server.address,
        "POST",
        "/api/v1/buses/demo/frames",
        Some(r#"{"id": "0x123", "data": "CAFE"}"#),
    )
    .await;
    assert_eq!(status, 200, "{body}");
    assert_eq!(frame_of(&mut frames, 0x123).await.data(), [0xCA, 0xFE]);
    // ... and the peer's frames are in the gateway's log.
    peer.send(Frame::new(CanId::standard(0x124).unwrap(), &[7]).unwrap())
        .await
        .unwrap();
    let mut seen = false;
    for _ in 0..50 {
        let (_, log) = http(
            &server.address,
            "GET",
            "/api/v1/buses/demo/frames?limit=1000",
            None,
        )
        .await;
        seen =
            log.as_array().unwrap().iter().any(|frame| {
                frame["id"] == "0x124" && frame["data"] == "07" && frame["dir"] == "rx"
            });
        if seen {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(seen, "the peer's frame is not in the log");
    drop(server);
}

#[tokio::test]
async fn config_file_gives_the_settings_and_the_command_line_overrides_it() {
    let dir = temp_dir("config");
    let config = dir.join("candeck.toml");
    std::fs::write(
        &config,
        "# a test bench\nlisten = \"127.0.0.1:0\"\nbuses = [\"bench=virtual:empty\", \"virtual:demo\"]\nbitrate = 125000\ndata_dir = \"data\"\n",
    )
    .unwrap();
    let config = config.to_str().unwrap();
    let server = start(&["--config", config, "--bitrate", "250000"]);
    let (status, buses) = http(&server.address, "GET", "/api/v1/buses", None).await;
    assert_eq!(status, 200, "{buses}");
    let names: Vec<&str> = buses
        .as_array()
        .unwrap()
        .iter()
        .map(|bus| bus["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["bench", "demo"]);
    // --bitrate beat the file's.
    assert_eq!(buses[0]["bitrate"], 250_000);
    // data_dir, relative to the file, was created.
    assert!(dir.join("data").is_dir());
    // The empty bench takes a device.
    let (status, body) = http(
        &server.address,
        "POST",
        "/api/v1/buses/bench/sim/nodes",
        Some(r#"{"product": "jmc", "id": 2}"#),
    )
    .await;
    assert_eq!(status, 201, "{body}");
    wait_for_nodes(&server.address, "bench", 1).await;
    drop(server);

    // A JSON file works as well; --bus replaces the file's buses.
    let json_config = dir.join("candeck.json");
    std::fs::write(
        &json_config,
        r#"{"listen": "127.0.0.1:0", "buses": ["virtual:demo"]}"#,
    )
    .unwrap();
    let server = start(&[
        "--config",
        json_config.to_str().unwrap(),
        "--bus",
        "only=virtual:empty",
    ]);
    let (_, buses) = http(&server.address, "GET", "/api/v1/buses", None).await;
    assert_eq!(buses.as_array().unwrap().len(), 1);
    assert_eq!(buses[0]["name"], "only");
    assert_eq!(buses[0]["bitrate"], 500_000);
    drop(server);
    let _ = std::fs::remove_dir_all(dir);
}

/// `candeck ARGS` that must fail: its exit status and stderr.
fn fails(args: &[&str]) -> (i32, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(args)
        .env_remove("CANDECK_LOG")
        .output()
        .unwrap();
    assert!(!output.status.success());
    (
        output.status.code().unwrap(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

#[test]
fn a_bad_config_file_or_share_is_one_clear_line() {
    let dir = temp_dir("bad-config");
    let write = |name: &str, text: &str| -> String {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path.to_str().unwrap().to_string()
    };
    let cases = [
        (
            write(
                "syntax.toml",
                "listen = \"127.0.0.1:0\"\nbuses = [\"virtual:demo\"\n",
            ),
            "line 2",
        ),
        (
            write("unknown.toml", "listen = \"127.0.0.1:0\"\n\nbitrat = 5\n"),
            "line 3, column 1: unknown field `bitrat`",
        ),
        (write("spec.toml", "buses = [\"x=bogus:1\"]\n"), "line 1"),
        (
            write(
                "type.json",
                "{\"listen\": \"127.0.0.1:0\",\n \"bitrate\": \"fast\"}",
            ),
            "line 2 column",
        ),
        (
            dir.join("missing.toml").to_str().unwrap().to_string(),
            "missing.toml",
        ),
    ];
    for (path, expected) in &cases {
        let (code, stderr) = fails(&["--config", path]);
        assert_eq!(code, 1, "{stderr}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert!(stderr.starts_with("candeck: error: config "), "{stderr}");
        assert!(stderr.contains(expected), "{expected}: {stderr}");
    }
    let (code, stderr) = fails(&["--listen", "127.0.0.1:0", "--share", "other=127.0.0.1:0"]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("no bus is named 'other'"), "{stderr}");
    let (code, stderr) = fails(&[
        "--listen",
        "127.0.0.1:0",
        "--bus",
        "socketcand:127.0.0.1:1/can0",
        "--share",
        "127.0.0.1:0",
    ]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("no virtual bus to share"), "{stderr}");
    let (code, stderr) = fails(&["--share", "nowhere"]);
    assert_eq!(code, 2, "{stderr}");
    let _ = std::fs::remove_dir_all(dir);
}

/// Reads 0x1017 of node 3 (the UIO1LED) through REST.
async fn heartbeat_time(address: &str) -> Json {
    let (status, value) = http(
        address,
        "GET",
        "/api/v1/buses/demo/nodes/3/od/0x1017/0",
        None,
    )
    .await;
    assert_eq!(status, 200, "{value}");
    value["value"].clone()
}

fn saved_file(dir: &Path) -> PathBuf {
    dir.join("sim")
        .join("demo")
        .join("devices")
        .join("uio1led-3.json")
}

#[tokio::test]
async fn saved_parameters_survive_a_restart_with_the_same_data_dir() {
    let dir = temp_dir("data");
    let data = dir.join("state");
    // The network manager would write 0x1017 at every boot-up, over the
    // saved value: the demo's nodes are left as they boot.
    let config = common::demo_left_alone(&dir);
    let args = [
        "--listen",
        "127.0.0.1:0",
        "--data-dir",
        data.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ];
    let server = start(&args);
    assert!(data.is_dir(), "--data-dir is created");
    wait_for_nodes(&server.address, "demo", 3).await;
    let before = heartbeat_time(&server.address).await;
    assert_ne!(before, json!(1234));
    let (status, body) = http(
        &server.address,
        "PUT",
        "/api/v1/buses/demo/nodes/3/od/0x1017/0",
        Some(r#"{"value": 1234}"#),
    )
    .await;
    assert_eq!(status, 200, "{body}");
    // 'save' (0x65766173) to 0x1010 sub 1: store all parameters.
    let (status, body) = http(
        &server.address,
        "PUT",
        "/api/v1/buses/demo/nodes/3/od/0x1010/1",
        Some(r#"{"value": 1702257011}"#),
    )
    .await;
    assert_eq!(status, 200, "{body}");
    // The device writes its flash right after answering.
    for _ in 0..50 {
        if saved_file(&data).exists() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(
        saved_file(&data).exists(),
        "nothing saved under {}",
        data.display()
    );
    drop(server);

    let server = start(&args);
    wait_for_nodes(&server.address, "demo", 3).await;
    assert_eq!(heartbeat_time(&server.address).await, json!(1234));
    drop(server);
    // Without the data dir, the device starts from its defaults.
    let server = start(&[
        "--listen",
        "127.0.0.1:0",
        "--config",
        config.to_str().unwrap(),
    ]);
    wait_for_nodes(&server.address, "demo", 3).await;
    assert_eq!(heartbeat_time(&server.address).await, before);
    drop(server);
    let _ = std::fs::remove_dir_all(dir);
}
