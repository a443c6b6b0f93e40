//! The node registry against the virtual demo devices (node 1 a UMC1BDS32,
//! node 2 a JMC stepper, node 3 a UIO1LED) on a paused clock: nodes found
//! by boot-up and by scan, identified and matched to an EDS, supervised by
//! heartbeat, with their EMCY history; and user EDS files preferred over the
//! built-in ones.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::broadcast;
use tokio::time::Instant;

use candeck::can::{BusState, BusStatus, CanId, Frame, VirtualHub};
use candeck::canopen::NodeId;
use candeck::canopen::emcy::emcy_text;
use candeck::canopen::nmt::{NmtCommand, NmtMessage, NmtState, NmtTarget};
use candeck::gateway::{EdsCatalog, EdsSource, Identity, Profile};
use candeck::gateway::{
    Identification, NodeEvent, NodeInfo, NodeRegistry, OfflineReason, RegistryConfig, RegistryError,
};
use candeck::sim::behaviour::Fault;
use candeck::sim::products::{Product, demo};
use candeck::sim::rack::Rack;

fn node(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

fn builtin() -> Arc<EdsCatalog> {
    Arc::new(EdsCatalog::builtin().unwrap())
}

/// The registry first, then the demo devices, which boot as they are added.
async fn demo_bus(catalog: Arc<EdsCatalog>) -> (VirtualHub, Rack, NodeRegistry) {
    let hub = VirtualHub::new("demo");
    let registry = NodeRegistry::spawn(hub.attach(), catalog, RegistryConfig::default());
    let rack = Rack::new(hub.clone());
    rack.add_all(&demo()).unwrap();
    // Let the boot-ups arrive and the identifications start.
    tokio::time::sleep(Duration::from_millis(20)).await;
    registry.settle().await;
    (hub, rack, registry)
}

/// The first event that `pick` accepts, within `limit` of (paused) time.
async fn event_within<T>(
    events: &mut broadcast::Receiver<NodeEvent>,
    limit: Duration,
    mut pick: impl FnMut(&NodeEvent) -> Option<T>,
) -> Option<T> {
    tokio::time::timeout(limit, async {
        loop {
            match events.recv().await {
                Ok(event) => {
                    if let Some(found) = pick(&event) {
                        return Some(found);
                    }
                }
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => return None,
            }
        }
    })
    .await
    .ok()
    .flatten()
}

/// A virtual device's identity: its serial number is its node-ID.
fn identity(vendor: u32, product: u32, revision: u32, serial: u32) -> Option<Identity> {
    Some(Identity {
        vendor_id: vendor,
        product_code: Some(product),
        revision: Some(revision),
        serial: Some(serial),
    })
}

fn check_demo_identities(nodes: &[NodeInfo]) {
    let summary: Vec<_> = nodes
        .iter()
        .map(|n| {
            (
                n.id.get(),
                n.profile,
                n.eds.as_deref(),
                n.identification.clone(),
            )
        })
        .collect();
    assert_eq!(
        summary,
        [
            (1, Profile::Umc, Some("umc1bds32.eds"), Identification::Done),
            (
                2,
                Profile::JmcStepper,
                Some("jmc_stepper.eds"),
                Identification::Done
            ),
            (
                3,
                Profile::Uioled,
                Some("uio1led.eds"),
                Identification::Done
            ),
        ]
    );
    let [umc, jmc, led] = nodes else {
        panic!("three nodes: {nodes:?}");
    };
    assert_eq!(umc.identity, identity(0x4A2, 0x1001, 0x0100_0004, 1));
    assert_eq!(umc.device_type, Some(402));
    assert_eq!(umc.name.as_deref(), Some("UMC1BDS32 motion controller"));
    // The JMC drive reports vendor 0x2D9, product 0, revision 0.
    assert_eq!(jmc.identity, identity(0x2D9, 0, 0, 2));
    assert_eq!(jmc.device_type, Some(0x0006_0912));
    assert_eq!(jmc.name.as_deref(), Some("AMA CANopen Motor Driver"));
    assert_eq!(led.identity, identity(0x4A2, 0x4101, 1, 3));
    assert_eq!(led.device_type, Some(428));
    assert_eq!(led.name.as_deref(), Some("UIO1LED LEDs controller"));
    for n in nodes {
        assert!(n.online, "{n:?}");
        let entry = n.eds_entry.as_ref().expect("an EDS");
        assert!(entry.eds.dictionary.get(0x1018).is_some());
    }
}

#[tokio::test(start_paused = true)]
async fn the_demo_nodes_appear_from_their_boot_up_identified_and_matched() {
    let hub = VirtualHub::new("demo");
    let registry = NodeRegistry::spawn(hub.attach(), builtin(), RegistryConfig::default());
    let mut events = registry.subscribe();
    assert!(registry.nodes().is_empty());
    let rack = Rack::new(hub.clone());
    rack.add_all(&demo()).unwrap();

    let mut identified = Vec::new();
    while identified.len() < 3 {
        let found = event_within(&mut events, Duration::from_secs(2), |event| match event {
            NodeEvent::Identified { node, profile, .. } => Some((node.get(), *profile)),
            _ => None,
        })
        .await
        .expect("every demo node is identified");
        identified.push(found);
    }
    identified.sort_by_key(|(id, _)| *id);
    assert_eq!(
        identified,
        [
            (1, Profile::Umc),
            (2, Profile::JmcStepper),
            (3, Profile::Uioled)
        ]
    );
    let nodes = registry.nodes();
    check_demo_identities(&nodes);
    // Booted, then answering SDO: pre-operational, as CiA 301 has it.
    assert!(
        nodes
            .iter()
            .all(|n| n.nmt == Some(NmtState::PreOperational))
    );
    // Only the JMC produces a heartbeat out of the box (its 0x1017 is 1000).
    let periods: Vec<_> = nodes.iter().map(|n| n.heartbeat_ms).collect();
    assert_eq!(periods, [None, Some(1000), None]);
    assert_eq!(
        registry.node(node(2)).map(|n| n.profile),
        Some(Profile::JmcStepper)
    );
    assert!(registry.node(node(4)).is_none());

    // The shape of GET /buses/{bus}/nodes.
    let json = serde_json::to_value(&nodes[0]).unwrap();
    assert_eq!(json["id"], 1);
    assert_eq!(json["nmt"], "pre_operational");
    assert_eq!(json["online"], true);
    assert_eq!(json["profile"], "umc");
    assert_eq!(json["eds"], "umc1bds32.eds");
    assert_eq!(json["device_type"], 402);
    assert_eq!(json["name"], "UMC1BDS32 motion controller");
    assert_eq!(
        json["identity"],
        serde_json::json!({"vendor_id": 0x4A2, "product_code": 0x1001, "revision": 0x0100_0004, "serial": 1})
    );
    assert!(json["last_seen_ms"].is_u64());
    assert!(json.get("eds_entry").is_none());
}

#[tokio::test(start_paused = true)]
async fn a_scan_finds_the_nodes_whose_boot_up_was_missed() {
    let hub = VirtualHub::new("demo");
    let rack = Rack::new(hub.clone());
    rack.add_all(&demo()).unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    // The registry starts after the devices booted: it has heard nothing.
    let registry = NodeRegistry::spawn(hub.attach(), builtin(), RegistryConfig::default());
    tokio::time::sleep(Duration::from_millis(10)).await;
    assert!(registry.nodes().is_empty());

    let start = Instant::now();
    let nodes = registry.scan().await.unwrap();
    let took = start.elapsed();
    check_demo_identities(&nodes);
    // 124 silent ids at 100 ms, 8 at a time: about 1.6 s, not 12.7 s.
    assert!(took < Duration::from_millis(2500), "{took:?}");
    assert!(took >= Duration::from_millis(1500), "{took:?}");
    // Nothing said which state the UMC is in (it sends no heartbeat).
    assert_eq!(nodes[0].nmt, None);
    assert_eq!(serde_json::to_value(&nodes[0]).unwrap()["nmt"], "unknown");

    // A node without heartbeat that no longer answers goes offline, and
    // is back with the next scan that it answers.
    let mut events = registry.subscribe();
    rack.unplug(node(3)).unwrap();
    let nodes = registry.scan().await.unwrap();
    assert_eq!(nodes.len(), 3);
    assert!(!nodes[2].online && nodes[0].online);
    assert_eq!(
        event_within(&mut events, Duration::ZERO, |event| match event {
            NodeEvent::Offline { node, reason } => Some((node.get(), *reason)),
            _ => None,
        })
        .await,
        Some((3, OfflineReason::NoAnswer))
    );
    rack.plug(node(3)).unwrap();
    let nodes = registry.scan().await.unwrap();
    assert!(nodes.iter().all(|n| n.online), "{nodes:?}");
}

#[tokio::test(start_paused = true)]
async fn a_node_whose_heartbeat_stops_goes_offline_within_three_periods() {
    let (hub, rack, registry) = demo_bus(builtin()).await;
    // Written by another master: the gateway learns the period from the
    // heartbeats alone.
    let umc = candeck::gateway::SdoChannel::new(
        hub.attach(),
        node(1),
        candeck::canopen::sdo::ClientConfig::default(),
    );
    umc.download(0x1017, 0, &100u16.to_le_bytes())
        .await
        .unwrap();
    // The period is learnt from the heartbeats.
    tokio::time::sleep(Duration::from_millis(350)).await;
    let info = registry.node(node(1)).unwrap();
    assert_eq!((info.heartbeat_ms, info.online), (Some(100), true));
    assert!(info.last_seen_ms <= 100, "{info:?}");

    let mut events = registry.subscribe();
    rack.unplug(node(1)).unwrap();
    let unplugged = Instant::now();
    let offline = event_within(&mut events, Duration::from_secs(1), |event| match event {
        NodeEvent::Offline { node, reason } => Some((node.get(), *reason)),
        _ => None,
    })
    .await;
    assert_eq!(offline, Some((1, OfflineReason::HeartbeatLost)));
    let after = unplugged.elapsed();
    // heartbeat_consumer_factor: 3 periods after its last heartbeat.
    assert!(after <= Duration::from_millis(300), "{after:?}");
    let info = registry.node(node(1)).unwrap();
    assert!(!info.online);
    assert!(info.last_seen_ms >= 100, "{info:?}");
    // Still listed, still identified.
    assert_eq!(info.profile, Profile::Umc);

    rack.plug(node(1)).unwrap();
    let online = event_within(
        &mut events,
        Duration::from_millis(200),
        |event| match event {
            NodeEvent::Online { node } => Some(node.get()),
            _ => None,
        },
    )
    .await;
    assert_eq!(online, Some(1));
    assert!(registry.node(node(1)).unwrap().online);
    // The others were never in doubt; the JMC's 1 s heartbeat kept it online.
    tokio::time::sleep(Duration::from_millis(1600)).await;
    assert!(registry.nodes().iter().all(|n| n.online));
}

#[tokio::test(start_paused = true)]
async fn an_injected_fault_is_in_the_nodes_emcy_history_with_its_text() {
    let (_hub, rack, registry) = demo_bus(builtin()).await;
    assert_eq!(registry.emcy(node(1)), Some(vec![]));
    let mut events = registry.subscribe();
    rack.inject_fault(node(1), Fault::OverTemperature).unwrap();
    let emcy = event_within(
        &mut events,
        Duration::from_millis(100),
        |event| match event {
            NodeEvent::Emcy { node, emcy } if node.get() == 1 => Some(emcy.clone()),
            _ => None,
        },
    )
    .await
    .expect("an EMCY from node 1");
    assert_eq!((emcy.code, emcy.register), (0x4310, 0x09));
    assert_eq!(emcy.text, emcy_text(0x4310));
    assert!(emcy.text.to_lowercase().contains("temperature"), "{emcy:?}");
    let history = registry.emcy(node(1)).unwrap();
    assert!(history.contains(&emcy), "{history:?}");
    let json = serde_json::to_value(&emcy).unwrap();
    assert_eq!(json["code"], "0x4310");
    assert_eq!(json["register"], 9);
    assert_eq!(json["manufacturer"].as_str().map(str::len), Some(10));

    // One per axis of the UMC1BDS32 (the axis in the first manufacturer
    // byte), both kept, in the order received.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let history = registry.emcy(node(1)).unwrap();
    let seen: Vec<_> = history
        .iter()
        .map(|e| (e.code, e.manufacturer[0]))
        .collect();
    assert_eq!(seen, [(0x4310, 1), (0x4310, 2)], "{history:?}");
    // Nobody else raised anything.
    assert_eq!(registry.emcy(node(3)), Some(vec![]));
}

#[tokio::test(start_paused = true)]
async fn a_boot_up_identifies_the_node_again_and_keeps_its_emcy_history() {
    let (hub, rack, registry) = demo_bus(builtin()).await;
    rack.inject_fault(node(1), Fault::OverTemperature).unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut events = registry.subscribe();
    let master = hub.attach();
    master
        .send(NmtMessage::new(NmtCommand::ResetNode, NmtTarget::Node(node(1))).encode())
        .await
        .unwrap();
    let rebooted = event_within(
        &mut events,
        Duration::from_millis(500),
        |event| match event {
            NodeEvent::NmtChanged { node, to, .. } if node.get() == 1 => Some(*to),
            _ => None,
        },
    )
    .await;
    assert_eq!(rebooted, Some(NmtState::BootUp));
    let again = event_within(&mut events, Duration::from_secs(2), |event| match event {
        NodeEvent::Identified { node, profile, .. } if node.get() == 1 => Some(*profile),
        _ => None,
    })
    .await;
    assert_eq!(again, Some(Profile::Umc));
    let info = registry.node(node(1)).unwrap();
    assert_eq!(info.identification, Identification::Done);
    assert_eq!(info.nmt, Some(NmtState::PreOperational));
    assert!(
        registry
            .emcy(node(1))
            .unwrap()
            .iter()
            .any(|e| e.code == 0x4310)
    );
}

#[tokio::test(start_paused = true)]
async fn a_node_that_does_not_answer_stays_generic_until_its_next_boot_up() {
    let (hub, rack, registry) = demo_bus(builtin()).await;
    // A boot-up from node 50, where no device answers SDO.
    let master = hub.attach();
    master
        .send(Frame::new(CanId::Standard(0x732), &[0x00]).unwrap())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(10)).await;
    assert_eq!(
        registry.node(node(50)).map(|n| n.identification),
        Some(Identification::Pending)
    );
    registry.settle().await;
    let info = registry.node(node(50)).unwrap();
    assert_eq!(info.profile, Profile::Generic);
    assert_eq!(
        (info.identity, info.device_type, info.eds.as_deref()),
        (None, None, None)
    );
    let Identification::Failed { error } = &info.identification else {
        panic!("{info:?}");
    };
    assert!(error.contains("did not answer"), "{error}");
    assert_eq!(info.nmt, Some(NmtState::BootUp));

    // A device at 50 boots: identified this time.
    rack.add(Product::Uio1led, node(50)).unwrap();
    tokio::time::sleep(Duration::from_millis(20)).await;
    registry.settle().await;
    let info = registry.node(node(50)).unwrap();
    assert_eq!(
        (info.profile, info.identification),
        (Profile::Uioled, Identification::Done)
    );
}

#[tokio::test(start_paused = true)]
async fn a_bus_that_goes_down_keeps_its_nodes_offline_and_brings_them_back() {
    let (hub, _rack, registry) = demo_bus(builtin()).await;
    let mut events = registry.subscribe();
    hub.set_status(BusStatus::new(BusState::Down, "cable pulled"));
    let mut offline = Vec::new();
    while offline.len() < 3 {
        let event = event_within(
            &mut events,
            Duration::from_millis(100),
            |event| match event {
                NodeEvent::Offline { node, reason } => Some((node.get(), *reason)),
                _ => None,
            },
        )
        .await
        .expect("every node goes offline");
        offline.push(event);
    }
    offline.sort_by_key(|(id, _)| *id);
    assert_eq!(
        offline,
        [1, 2, 3].map(|id| (id, OfflineReason::BusDown)).to_vec()
    );
    let nodes = registry.nodes();
    assert_eq!(nodes.len(), 3);
    assert!(nodes.iter().all(|n| !n.online));
    assert!(matches!(
        registry.scan().await,
        Err(RegistryError::Bus(candeck::can::BusError::NotUp { .. }))
    ));

    hub.set_status(BusStatus::up());
    // The UMC and the UIO1LED (no heartbeat) are asked; the JMC is heard.
    let mut online = Vec::new();
    while online.len() < 3 {
        let event = event_within(
            &mut events,
            Duration::from_millis(1600),
            |event| match event {
                NodeEvent::Online { node } => Some(node.get()),
                _ => None,
            },
        )
        .await
        .expect("every node comes back");
        online.push(event);
    }
    online.sort();
    assert_eq!(online, [1, 2, 3]);
    assert!(registry.nodes().iter().all(|n| n.online));
}

#[tokio::test(start_paused = true)]
async fn a_users_eds_file_is_preferred_for_the_identity_it_describes() {
    // A user's file for the UMC1BDS32 (here a copy of the project's own, as
    // a user would start from it) names the identity the virtual one reports:
    // 0x4A2, 0x1001, revision 0x01000004.
    let users = concat!(env!("CARGO_MANIFEST_DIR"), "/eds/umc1bds32.eds");
    let dir = std::env::temp_dir().join(format!("candeck-registry-eds-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(users, dir.join("my_umc1bds32.eds")).unwrap();
    let catalog = Arc::new(EdsCatalog::with_dir(&dir).unwrap());

    let (_hub, _rack, registry) = demo_bus(catalog).await;
    let umc = registry.node(node(1)).unwrap();
    assert_eq!(umc.eds.as_deref(), Some("my_umc1bds32.eds"));
    assert_eq!(umc.profile, Profile::Umc);
    let entry = umc.eds_entry.unwrap();
    assert_eq!(entry.source, EdsSource::File(dir.join("my_umc1bds32.eds")));
    // The others keep the built-in files.
    let led = registry.node(node(3)).unwrap();
    assert_eq!(led.eds.as_deref(), Some("uio1led.eds"));

    // A file in the directory that is no EDS is left out and named; the
    // others still load (a bad file never stops the gateway).
    std::fs::write(dir.join("zz_broken.eds"), "\0\u{1}binary, not text\n").unwrap();
    let catalog = EdsCatalog::with_dir(&dir).unwrap();
    let skipped = catalog.skipped();
    assert_eq!(skipped.len(), 1, "{skipped:?}");
    assert_eq!(skipped[0].path, dir.join("zz_broken.eds"));
    assert!(
        catalog
            .entries()
            .iter()
            .any(|entry| entry.name == "my_umc1bds32.eds"),
        "the good file is still in the catalog"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test(start_paused = true)]
async fn a_node_that_boots_while_a_scan_probes_it_is_asked_by_one_client_at_a_time() {
    let hub = VirtualHub::new("demo");
    let rack = Rack::new(hub.clone());
    let registry = NodeRegistry::spawn(hub.attach(), builtin(), RegistryConfig::default());
    let observer = hub.attach();
    let mut frames = observer.subscribe();
    let start = Instant::now();
    let scan = tokio::spawn({
        let registry = registry.clone();
        async move { registry.scan().await }
    });
    // Ids go 8 at a time, 100 ms each: 97–104 are probed from 1.2 s on.
    tokio::time::sleep(Duration::from_millis(1250)).await;
    rack.add(Product::Uio1led, node(100)).unwrap();
    let nodes = scan.await.unwrap().unwrap();
    assert_eq!(nodes.len(), 1);
    assert_eq!(
        (
            nodes[0].id,
            nodes[0].profile,
            nodes[0].identification.clone()
        ),
        (node(100), Profile::Uioled, Identification::Done)
    );
    // What was sent to node 100: the scan's request, its abort at the
    // timeout, and only then the identification's requests.
    let mut to_node = Vec::new();
    while let Ok(Some(timed)) = frames.try_recv() {
        if timed.frame.id() == CanId::Standard(0x664) {
            to_node.push(timed.frame.data()[0]);
        }
    }
    assert_eq!(to_node[..2], [0x40, 0x80], "{to_node:02X?}");
    // 0x1000, 0x1018 sub 1–4, 0x1008 (segmented), 0x1017: no abort.
    let initiated = to_node[2..].iter().filter(|&&c| c == 0x40).count();
    assert_eq!(initiated, 7, "{to_node:02X?}");
    assert!(!to_node[2..].contains(&0x80), "{to_node:02X?}");
    assert!(start.elapsed() < Duration::from_millis(2500));
}
