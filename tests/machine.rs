//! The network manager (CiA 302-2) of the real `candeck serve`, over the
//! demo bus: a machine description in the config file (nodes checked,
//! configured, supervised and started; a missing mandatory node; a wrong
//! identity), a node unplugged and plugged back without any client request,
//! and the default demo without a description. Real processes: the waits
//! poll with deadlines (the bounds of issue 17), never sleep for a result.

mod common;

use std::path::PathBuf;
use std::time::Duration;

use common::{http, json, poll, start};
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value as Json, json};
use tokio::net::TcpStream;
use tokio::time::Instant;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

type Socket = WebSocketStream<MaybeTlsStream<TcpStream>>;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("candeck-machine-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

async fn connect(address: &str) -> Socket {
    let (socket, _) = tokio_tungstenite::connect_async(format!("ws://{address}/api/v1/stream"))
        .await
        .expect("the stream accepts WebSockets");
    socket
}

async fn subscribe(socket: &mut Socket, topic: &str) {
    let request = json!({"op": "subscribe", "topics": [topic]});
    socket
        .send(Message::text(request.to_string()))
        .await
        .unwrap();
}

/// The first `nodes` event of `node` that is `event`, waited for until
/// `deadline`; `None` when none came.
async fn wait_event(
    socket: &mut Socket,
    node: u64,
    event: &str,
    deadline: Instant,
) -> Option<Json> {
    loop {
        let message = tokio::time::timeout_at(deadline, socket.next())
            .await
            .ok()??
            .ok()?;
        let Message::Text(text) = message else {
            continue;
        };
        let message: Json = serde_json::from_str(&text).unwrap();
        if message["topic"] == "nodes"
            && message["data"]["node"] == node
            && message["data"]["event"] == event
        {
            return Some(message["data"].clone());
        }
    }
}

fn node(machine: &Json, id: u64) -> &Json {
    machine["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|node| node["id"] == id)
        .unwrap_or_else(|| panic!("node {id} not in {machine}"))
}

async fn heartbeat_time(address: &str, id: u8) -> Json {
    let (status, value) = json(
        address,
        "GET",
        &format!("/api/v1/buses/demo/nodes/{id}/od/0x1017/0"),
        None,
    )
    .await;
    assert_eq!(status, 200, "{value}");
    value["value"].clone()
}

const MACHINE: &str = "/api/v1/buses/demo/machine";

#[tokio::test]
async fn a_described_machine_boots_supervises_and_brings_a_node_back_by_itself() {
    let dir = temp_dir("described");
    // A configuration value for node 3, downloaded at every boot-up.
    std::fs::write(
        dir.join("leds.dcf"),
        "[DeviceComissioning]\nNodeID=3\n\n\
         [1800]\nParameterName=TPDO communication parameter 1\nObjectType=0x9\nSubNumber=2\n\n\
         [1800sub0]\nParameterName=Highest sub-index\nObjectType=0x7\nDataType=0x0005\nAccessType=ro\nDefaultValue=6\n\n\
         [1800sub5]\nParameterName=Event timer\nObjectType=0x7\nDataType=0x0006\nAccessType=rw\nDefaultValue=0\nParameterValue=250\n",
    )
    .unwrap();
    let config = dir.join("machine.toml");
    std::fs::write(
        &config,
        r#"
manager_node_id = 127
manager_heartbeat_ms = 100

[[nodes]]
id = 1
name = "lift axes"
heartbeat_ms = 200

[[nodes]]
id = 2
name = "not the stepper we expect"
product_code = 0xDEAD

[[nodes]]
id = 3
name = "signal lights"
vendor_id = 0x4A2
product_code = 0x4101
heartbeat_ms = 300
dcf = "leds.dcf"

[[nodes]]
id = 5
name = "the missing one"
"#,
    )
    .unwrap();
    let (server, _) = start(&["serve", "--config", config.to_str().unwrap()]);
    let address = server.address.clone();

    let (status, machine) = poll(&address, MACHINE, |_, machine| {
        machine["state"] == "degraded"
            && node(machine, 1)["state"] == "ready"
            && node(machine, 1)["nmt"] == "operational"
            && node(machine, 3)["state"] == "ready"
            && node(machine, 3)["nmt"] == "operational"
            && node(machine, 2)["state"] == "wrong_identity"
            && machine["reasons"].to_string().contains("node 5 missing")
    })
    .await;
    assert_eq!(status, 200);
    assert_eq!(machine["state"], "degraded", "{machine}");
    let reasons = machine["reasons"].to_string();
    assert!(reasons.contains("node 5 missing"), "{machine}");
    assert_eq!(node(&machine, 5)["state"], "missing", "{machine}");
    for id in [1, 3] {
        assert_eq!(node(&machine, id)["state"], "ready", "{machine}");
        assert_eq!(node(&machine, id)["supervision"], "heartbeat", "{machine}");
        assert_eq!(node(&machine, id)["nmt"], "operational", "{machine}");
    }
    let wrong = node(&machine, 2);
    assert_eq!(wrong["state"], "wrong_identity", "{machine}");
    assert!(
        wrong["reason"].as_str().unwrap().contains("product_code"),
        "{machine}"
    );
    assert_eq!(heartbeat_time(&address, 3).await, 300);
    assert_eq!(heartbeat_time(&address, 1).await, 200);
    // The DCF's value is in node 3.
    let (_, timer) = json(
        &address,
        "GET",
        "/api/v1/buses/demo/nodes/3/od/0x1800/5",
        None,
    )
    .await;
    assert_eq!(timer["value"], 250, "{timer}");
    // Node 2 was neither configured nor started: still pre-operational.
    let (_, two) = json(&address, "GET", "/api/v1/buses/demo/nodes/2", None).await;
    assert_eq!(two["nmt"], "pre_operational", "{two}");

    // Unplugged: offline on the nodes topic within 1.5 s (lost after 3 ×
    // its 300 ms heartbeat, heartbeat_consumer_factor).
    let mut socket = connect(&address).await;
    subscribe(&mut socket, "nodes").await;
    let (status, body) = http(&address, "DELETE", "/api/v1/buses/demo/sim/nodes/3", None).await;
    assert_eq!(status, 204, "{body}");
    let unplugged = Instant::now();
    let offline = wait_event(
        &mut socket,
        3,
        "offline",
        unplugged + Duration::from_millis(1500),
    )
    .await;
    assert!(
        offline.is_some(),
        "no offline event for node 3 within 1.5 s"
    );

    // Plugged back: ready, operational, 0x1017 = 300 again within 2 s, no
    // client request but the plug.
    let (status, body) = http(
        &address,
        "POST",
        "/api/v1/buses/demo/sim/nodes",
        Some(r#"{"product":"uio1led","id":3}"#),
    )
    .await;
    assert!(status == 200 || status == 201, "{status} {body}");
    let plugged = Instant::now();
    let mut back = false;
    while Instant::now() < plugged + Duration::from_secs(2) {
        let (_, machine) = json(&address, "GET", MACHINE, None).await;
        let three = node(&machine, 3);
        if three["state"] == "ready" && three["nmt"] == "operational" && three["boots_ok"] == 2 {
            back = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(
        back,
        "node 3 not ready and operational within 2 s of being plugged back"
    );
    assert_eq!(heartbeat_time(&address, 3).await, 300);
    let (_, timer) = json(
        &address,
        "GET",
        "/api/v1/buses/demo/nodes/3/od/0x1800/5",
        None,
    )
    .await;
    assert_eq!(timer["value"], 250, "{timer}");

    // The operator's "boot again", and its refusal for a node id unknown.
    let (status, body) = http(
        &address,
        "POST",
        "/api/v1/buses/demo/machine/nodes/3/boot",
        None,
    )
    .await;
    assert_eq!(status, 200, "{body}");
    let (status, body) = http(
        &address,
        "POST",
        "/api/v1/buses/demo/machine/nodes/9/boot",
        None,
    )
    .await;
    assert_eq!(status, 400, "{body}");
    // The machine state on /metrics: 1, degraded.
    let (status, metrics) = http(&address, "GET", "/metrics", None).await;
    assert_eq!(status, 200);
    assert!(
        metrics.contains("candeck_machine_state{bus=\"demo\"} 1"),
        "{metrics}"
    );
    drop(server);
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test]
async fn the_default_demo_is_supervised_and_notices_an_unplugged_node_within_2_s() {
    let (server, _) = start(&["serve"]);
    let address = server.address.clone();
    let (_, machine) = poll(&address, MACHINE, |_, machine| {
        machine["state"] == "ready"
            && machine["nodes"].as_array().is_some_and(|nodes| {
                nodes.len() == 3 && nodes.iter().all(|node| node["nmt"] == "operational")
            })
    })
    .await;
    assert_eq!(machine["state"], "ready", "{machine}");
    for id in 1..=3 {
        assert_eq!(node(&machine, id)["expected"], false, "{machine}");
        assert_eq!(node(&machine, id)["supervision"], "heartbeat", "{machine}");
    }
    let mut socket = connect(&address).await;
    subscribe(&mut socket, "nodes").await;
    let (status, body) = http(&address, "DELETE", "/api/v1/buses/demo/sim/nodes/3", None).await;
    assert_eq!(status, 204, "{body}");
    let unplugged = Instant::now();
    // Lost after 3 heartbeat periods of 500 ms (heartbeat_consumer_factor).
    let offline = wait_event(
        &mut socket,
        3,
        "offline",
        unplugged + Duration::from_secs(2),
    )
    .await;
    assert!(offline.is_some(), "no offline event for node 3 within 2 s");
    drop(server);
}

/// A description's `eds` key describes its node by that file from the
/// start (here a file that names no identity numbers, which matching by
/// identity never picks), and a name no catalog holds stops the start
/// with the name in the error.
#[tokio::test]
async fn a_described_eds_describes_its_node_and_an_unknown_one_is_refused_at_start() {
    let dir = temp_dir("eds");
    let eds_dir = dir.join("eds");
    std::fs::create_dir_all(&eds_dir).unwrap();
    let corpus = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/eds-corpus/synthetic/technosoft-ipos-like.eds");
    std::fs::copy(&corpus, eds_dir.join("ipos.eds")).unwrap();
    let config = dir.join("machine.toml");
    std::fs::write(&config, "[[nodes]]\nid = 1\neds = \"ipos.eds\"\n").unwrap();
    let (server, _) = start(&[
        "serve",
        "--config",
        config.to_str().unwrap(),
        "--eds-dir",
        eds_dir.to_str().unwrap(),
    ]);
    let (status, node) = poll(&server.address, "/api/v1/buses/demo/nodes/1", |_, node| {
        node["eds"] == "ipos.eds"
    })
    .await;
    assert_eq!(status, 200, "{node}");
    assert_eq!(node["eds"], "ipos.eds", "{node}");
    assert_eq!(node["profile"], "cia402", "{node}");
    drop(server);

    std::fs::write(&config, "[[nodes]]\nid = 1\neds = \"nowhere.eds\"\n").unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(["serve", "--listen", "127.0.0.1:0", "--config"])
        .arg(&config)
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("nowhere.eds"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A device without a node ID, found by LSS Fastscan and given node ID 10,
/// boots up under it and the network manager boots it like any other node:
/// it reaches `ready`, supervised by heartbeat and operational, with no
/// other request.
#[tokio::test]
async fn a_device_configured_by_lss_is_booted_by_the_manager_and_reaches_ready() {
    let (server, _) = start(&["serve", "--bus", "line=virtual:umc1bds32@1,uio1led@lss"]);
    let address = server.address.clone();
    let (status, scan) = json(&address, "POST", "/api/v1/buses/line/lss/scan", Some("{}")).await;
    assert_eq!(status, 200, "{scan}");
    let found = scan["found"].as_array().unwrap();
    assert_eq!(found.len(), 1, "{scan}");
    let mut request = found[0].clone();
    request["node_id"] = json!(10);
    request["store"] = json!(false);
    let (status, configured) = json(
        &address,
        "POST",
        "/api/v1/buses/line/lss/configure",
        Some(&request.to_string()),
    )
    .await;
    assert_eq!(status, 200, "{configured}");
    assert_eq!(configured["id"], 10, "{configured}");
    let (_, machine) = poll(&address, "/api/v1/buses/line/machine", |_, machine| {
        machine["state"] == "ready"
            && machine["nodes"].as_array().is_some_and(|nodes| {
                nodes
                    .iter()
                    .any(|node| node["id"] == 10 && node["nmt"] == "operational")
            })
    })
    .await;
    assert_eq!(machine["state"], "ready", "{machine}");
    let ten = node(&machine, 10);
    assert_eq!(ten["state"], "ready", "{machine}");
    assert_eq!(ten["nmt"], "operational", "{machine}");
    assert_eq!(ten["supervision"], "heartbeat", "{machine}");
    drop(server);
}

/// A UniSwarm node moved to another ID (0x2040) is booted by the manager
/// under the new one, and its old ID is neither listed nor supervised (it
/// would be "lost" for ever otherwise).
#[tokio::test]
async fn a_node_moved_by_0x2040_leaves_its_old_id_behind() {
    let (server, _) = start(&["serve"]);
    let address = server.address.clone();
    poll(&address, MACHINE, |_, machine| machine["state"] == "ready").await;
    let (status, moved) = json(
        &address,
        "POST",
        "/api/v1/buses/demo/nodes/3/node-id",
        Some(r#"{"node_id":9}"#),
    )
    .await;
    assert_eq!(status, 200, "{moved}");
    let ids = |machine: &Json| -> Vec<u64> {
        machine["nodes"]
            .as_array()
            .map(|nodes| nodes.iter().filter_map(|n| n["id"].as_u64()).collect())
            .unwrap_or_default()
    };
    let (_, machine) = poll(&address, MACHINE, |_, machine| {
        machine["state"] == "ready"
            && ids(machine) == [1, 2, 9]
            && node(machine, 9)["nmt"] == "operational"
    })
    .await;
    assert_eq!(ids(&machine), [1, 2, 9], "{machine}");
    assert_eq!(machine["state"], "ready", "{machine}");
    let (status, nodes) = json(&address, "GET", "/api/v1/buses/demo/nodes", None).await;
    assert_eq!(status, 200);
    let listed: Vec<u64> = nodes
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|n| n["id"].as_u64())
        .collect();
    assert_eq!(listed, [1, 2, 9], "{nodes}");
    drop(server);
}
