//! The network manager of the demo bus (every node booted with the
//! defaults) and what a client writes: a producer heartbeat time written
//! through the API is followed, by the registry and by the manager, at
//! once, never undone by a boot-up it caused.

use crate::emulator::RackOf;
use std::time::Duration;

use axum::Router;
use axum::http::StatusCode;
use serde_json::{Value as Json, json};
use tokio::sync::broadcast;

use super::support::{get, open, put};
use crate::api::{AppState, app};
use crate::canopen::NodeId;
use crate::canopen::manager::MachineState;
use crate::gateway::MachineSettings;
use crate::gateway::{NodeEvent, OfflineReason};

const HEARTBEAT: &str = "/api/v1/buses/demo/nodes/1/od/0x1017/0";

/// The demo bus scanned, its manager run with the defaults, every node
/// booted and supervised.
async fn demo_with_machine() -> (Router, AppState) {
    let served = open("demo", "virtual:demo")
        .await
        .with_machine(MachineSettings::default(), None);
    let nodes = served.scan().await.unwrap();
    assert_eq!(nodes.len(), 3, "{nodes:?}");
    let machine = served.machine().unwrap().clone();
    machine.scan_done();
    let status = machine
        .wait_for(MachineState::Ready, Duration::from_secs(10))
        .await;
    assert_eq!(status.state, MachineState::Ready, "{status:?}");
    let state = AppState::new([served]);
    (app(state.clone()), state)
}

async fn machine_node(app: &Router, id: u64) -> Json {
    let (status, machine) = get(app, "/api/v1/buses/demo/machine").await;
    assert_eq!(status, StatusCode::OK, "{machine}");
    machine["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|node| node["id"] == id)
        .unwrap_or_else(|| panic!("node {id} not in {machine}"))
        .clone()
}

/// Writes node 1's producer heartbeat time (0x1017) over REST.
async fn write_heartbeat(app: &Router, ms: u16) {
    let (status, body) = put(app, HEARTBEAT, json!({ "value": ms })).await;
    assert!(status.is_success(), "{status} {body}");
}

/// Node 1 was not reported offline since the last look at `events`.
fn assert_node_1_never_offline(events: &mut broadcast::Receiver<NodeEvent>) {
    let seen = node_1_events(events);
    assert!(
        !seen
            .iter()
            .any(|event| matches!(event, NodeEvent::Offline { .. })),
        "{seen:?}"
    );
}

/// The events of node 1 since the last call.
fn node_1_events(events: &mut broadcast::Receiver<NodeEvent>) -> Vec<NodeEvent> {
    let mut seen = Vec::new();
    while let Ok(event) = events.try_recv() {
        if event.node().get() == 1 {
            seen.push(event);
        }
    }
    seen
}

#[tokio::test(start_paused = true)]
async fn a_written_producer_heartbeat_time_stays_and_is_supervised_with_at_once() {
    let (app, state) = demo_with_machine().await;
    let served = state.bus("demo").unwrap();
    let node_1 = NodeId::new(1).unwrap();
    let before = machine_node(&app, 1).await;
    assert_eq!(
        (
            &before["state"],
            &before["supervision"],
            &before["heartbeat_ms"]
        ),
        (&json!("ready"), &json!("heartbeat"), &json!(500)),
        "{before}"
    );
    let mut events = served.node_events();

    // Twice the period the manager set, and more than its 750 ms timeout.
    write_heartbeat(&app, 1000).await;
    tokio::time::sleep(Duration::from_secs(5)).await;

    let (status, value) = get(&app, HEARTBEAT).await;
    assert_eq!(status, StatusCode::OK, "{value}");
    assert_eq!(value["value"], 1000, "the write was undone: {value}");
    let after = machine_node(&app, 1).await;
    assert_eq!(after["boots"], before["boots"], "booted again: {after}");
    let seen = node_1_events(&mut events);
    assert!(
        !seen.iter().any(|event| matches!(
            event,
            NodeEvent::Offline { .. } | NodeEvent::NmtChanged { .. }
        )),
        "node 1 went offline or booted again: {seen:?}"
    );
    assert!(
        seen.contains(&NodeEvent::HeartbeatWritten {
            node: node_1,
            heartbeat_ms: 1000
        }),
        "{seen:?}"
    );
    assert_eq!(
        (
            &after["state"],
            &after["supervision"],
            &after["heartbeat_ms"]
        ),
        (&json!("ready"), &json!("heartbeat"), &json!(1000)),
        "{after}"
    );
    let info = served.node(node_1).unwrap();
    assert!(info.online);
    assert_eq!(info.heartbeat_ms, Some(1000));

    // Faster: its silence of 600 ms (3 × 200) is a loss, for both.
    write_heartbeat(&app, 200).await;
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert_eq!(machine_node(&app, 1).await["heartbeat_ms"], 200);
    assert!(served.node(node_1).unwrap().online);
    node_1_events(&mut events);
    served.rack().unwrap().unplug(node_1).unwrap();
    tokio::time::sleep(Duration::from_millis(610)).await;
    let lost = machine_node(&app, 1).await;
    assert_eq!(lost["state"], "offline", "{lost}");
    assert_eq!(
        lost["reason"], "no heartbeat within 600 ms (3.0 × 200 ms)",
        "{lost}"
    );
    assert!(node_1_events(&mut events).contains(&NodeEvent::Offline {
        node: node_1,
        reason: OfflineReason::HeartbeatLost
    }));
}

#[tokio::test(start_paused = true)]
async fn a_producer_heartbeat_time_written_0_is_no_loss_and_said() {
    let (app, state) = demo_with_machine().await;
    let served = state.bus("demo").unwrap();
    let node_1 = NodeId::new(1).unwrap();
    let mut events = served.node_events();
    write_heartbeat(&app, 0).await;
    tokio::time::sleep(Duration::from_secs(5)).await;
    assert_node_1_never_offline(&mut events);
    let node = machine_node(&app, 1).await;
    assert_eq!(
        (&node["state"], &node["supervision"], &node["heartbeat_ms"]),
        (&json!("ready"), &json!("none"), &json!(0)),
        "{node}"
    );
    assert!(
        node["reason"]
            .as_str()
            .is_some_and(|reason| reason.contains("0x1017 was written 0")),
        "{node}"
    );
    let info = served.node(node_1).unwrap();
    assert!(info.online);
    assert_eq!(info.heartbeat_ms, None);
    assert_eq!(get(&app, HEARTBEAT).await.1["value"], 0);
}

#[tokio::test(start_paused = true)]
async fn without_a_manager_the_registry_follows_a_written_heartbeat_time_at_once() {
    let (app, state) = super::support::demo().await;
    let served = state.bus("demo").unwrap();
    let node_1 = NodeId::new(1).unwrap();
    // Its heartbeat on (the demo's devices start without) and learnt.
    write_heartbeat(&app, 500).await;
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert_eq!(served.node(node_1).unwrap().heartbeat_ms, Some(500));
    let mut events = served.node_events();
    write_heartbeat(&app, 1000).await;
    tokio::time::sleep(Duration::from_secs(5)).await;
    // Not offline for a moment at every slower heartbeat until it is learnt.
    assert_node_1_never_offline(&mut events);
    let info = served.node(node_1).unwrap();
    assert!(info.online);
    assert_eq!(info.heartbeat_ms, Some(1000));
}

#[tokio::test(start_paused = true)]
async fn a_cia_309_write_of_0x1017_is_followed_as_well() {
    // The CiA 309 gateway (what a 309-3 session and a 309-5 request call)
    // writes through the node's channel too.
    use crate::cia309::gateway::{Cia309Gateway, Identity, Origin, TransferOptions};

    let (app, state) = demo_with_machine().await;
    let before = machine_node(&app, 1).await;
    let gateway = Cia309Gateway::new(&state.gateway);
    let identity = Identity::anonymous("ascii", None);
    let origin = Origin {
        identity: &identity,
        method: "ASCII",
        path: "[1] 1 w 0x1017 0 u16 1000",
    };
    let options = TransferOptions::default();
    gateway
        .write(
            origin,
            1,
            1,
            0x1017,
            0,
            1000u16.to_le_bytes().to_vec(),
            "1000".into(),
            options,
        )
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_secs(5)).await;
    let origin = Origin {
        identity: &identity,
        method: "ASCII",
        path: "[2] 1 r 0x1017 0 u16",
    };
    let read = gateway
        .read(origin, 1, 1, 0x1017, 0, options)
        .await
        .unwrap();
    assert_eq!(read, 1000u16.to_le_bytes().to_vec());
    let after = machine_node(&app, 1).await;
    assert_eq!(after["boots"], before["boots"], "{after}");
    assert_eq!(
        (&after["state"], &after["heartbeat_ms"]),
        (&json!("ready"), &json!(1000)),
        "{after}"
    );
}

#[tokio::test(start_paused = true)]
async fn the_node_list_and_the_machine_view_lose_a_node_together() {
    // Before one supervisor, the registry learnt a faster heartbeat (set
    // past the gateway) and lost the node at 1.5 × 100 ms, while the
    // manager still waited 1.5 × 500 ms: offline in the node list, ready
    // in the machine view, for 600 ms.
    use crate::can::{CanId, Frame};
    let (app, state) = demo_with_machine().await;
    let served = state.bus("demo").unwrap();
    let node_1 = NodeId::new(1).unwrap();
    // Another master writes 100 ms into node 1's 0x1017 (an expedited SDO
    // download, not through the gateway's channel).
    let download = [0x2B, 0x17, 0x10, 0x00, 100, 0, 0, 0];
    let other_master = served.hub().expect("a virtual bus").attach();
    other_master
        .send(Frame::new(CanId::Standard(0x601), &download).unwrap())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(served.node(node_1).unwrap().heartbeat_ms, Some(100));
    assert_eq!(machine_node(&app, 1).await["state"], "ready");
    served.rack().unwrap().unplug(node_1).unwrap();
    tokio::time::sleep(Duration::from_millis(400)).await;
    let info = served.node(node_1).unwrap();
    let machine = machine_node(&app, 1).await;
    assert!(!info.online, "{info:?}");
    assert_eq!(machine["state"], "offline", "{machine}");
    assert_eq!(
        machine["reason"], "no heartbeat within 300 ms (3.0 × 100 ms)",
        "{machine}"
    );
}
