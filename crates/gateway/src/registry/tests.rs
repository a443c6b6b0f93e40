use std::collections::BTreeSet;

use super::*;
use crate::can::{CanId, Frame, VirtualHub};

fn node(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn registry(hub: &VirtualHub, config: RegistryConfig) -> NodeRegistry {
    NodeRegistry::spawn(
        hub.attach(),
        Arc::new(EdsCatalog::builtin().unwrap()),
        config,
    )
}

/// The registry's defaults, a node lost after 1.5 silent periods.
fn one_and_a_half_periods() -> RegistryConfig {
    RegistryConfig {
        consumer_factor: crate::canopen::manager::ConsumerFactor::MIN,
        ..RegistryConfig::default()
    }
}

fn frame(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).unwrap()
}

fn drain(events: &mut broadcast::Receiver<NodeEvent>) -> Vec<NodeEvent> {
    let mut out = Vec::new();
    while let Ok(event) = events.try_recv() {
        out.push(event);
    }
    out
}

#[test]
fn identification_values_are_read_as_devices_send_them() {
    assert_eq!(unsigned(&[0x92, 0x01, 0x00, 0x00]), Some(402));
    assert_eq!(unsigned(&[0xE8, 0x03]), Some(1000));
    assert_eq!(unsigned(&[]), None);
    assert_eq!(unsigned(&[1, 2, 3, 4, 5]), None);
    assert_eq!(
        visible_string(b"UMC1BDS32 motion controller"),
        "UMC1BDS32 motion controller"
    );
    assert_eq!(visible_string(b"JMC  \0\0\0"), "JMC");
    assert_eq!(visible_string(&[0x41, 0xFF, 0x42]), "A\u{FFFD}B");
    assert_eq!(visible_string(&[b'x'; 1000]).len(), MAX_NAME_LEN);
}

#[test]
fn an_emcy_record_is_written_as_the_api_shows_it() {
    let emcy = Emcy {
        code: 0x8130,
        register: crate::canopen::emcy::ErrorRegister::from_raw(0x11),
        manufacturer: [0xDE, 0xAD, 0, 1, 0xFF],
    };
    let record = EmcyRecord::new(&emcy, Timestamp::from_micros(1_500_000));
    assert_eq!(record.text, emcy_text(0x8130));
    assert!(!record.is_reset());
    assert_eq!(
        serde_json::to_value(&record).unwrap(),
        serde_json::json!({
            "code": "0x8130",
            "text": emcy_text(0x8130),
            "register": 0x11,
            "manufacturer": "dead0001ff",
            "timestamp_us": 1_500_000,
            "axis": null,
        })
    );
    let reset = EmcyRecord::new(
        &Emcy::error_reset(crate::canopen::emcy::ErrorRegister::NONE),
        Timestamp::default(),
    );
    assert!(reset.is_reset());
}

#[tokio::test(start_paused = true)]
async fn a_heartbeat_timeout_comes_on_time_on_a_bus_busy_with_pdos() {
    // The registry skips PDOs without moving its timer: the timeout must
    // still fire while other frames come every millisecond.
    let hub = VirtualHub::new("test");
    // Timed at one and a half periods (heartbeat_consumer_factor 1.5).
    let registry = registry(&hub, one_and_a_half_periods());
    let device = hub.attach();
    for _ in 0..5 {
        device.send(frame(0x705, &[0x05])).await.unwrap();
        tokio::time::sleep(ms(50)).await;
    }
    for _ in 0..24 {
        device.send(frame(0x185, &[1, 2])).await.unwrap();
        device.send(frame(0x286, &[3, 4])).await.unwrap();
        tokio::time::sleep(ms(1)).await;
    }
    assert!(registry.node(node(5)).unwrap().online);
    for _ in 0..2 {
        device.send(frame(0x185, &[1, 2])).await.unwrap();
        tokio::time::sleep(ms(1)).await;
    }
    assert!(!registry.node(node(5)).unwrap().online);
}

#[tokio::test(start_paused = true)]
async fn a_heartbeat_adds_a_node_and_its_silence_takes_it_offline_at_one_and_a_half_periods() {
    let hub = VirtualHub::new("test");
    // Timed at one and a half periods (heartbeat_consumer_factor 1.5).
    let registry = registry(&hub, one_and_a_half_periods());
    let mut events = registry.subscribe();
    let device = hub.attach();
    for _ in 0..5 {
        device.send(frame(0x705, &[0x05])).await.unwrap();
        tokio::time::sleep(ms(50)).await;
    }
    let info = registry.node(node(5)).unwrap();
    assert_eq!(
        (info.nmt, info.online, info.heartbeat_ms),
        (Some(NmtState::Operational), true, Some(50))
    );
    let seen = drain(&mut events);
    assert_eq!(
        seen[..2],
        [
            NodeEvent::Appeared { node: node(5) },
            NodeEvent::NmtChanged {
                node: node(5),
                from: None,
                to: NmtState::Operational
            }
        ]
    );
    // The last heartbeat was 50 ms ago: lost at 75 ms, not a moment before.
    tokio::time::sleep(ms(24)).await;
    assert!(registry.node(node(5)).unwrap().online);
    tokio::time::sleep(ms(2)).await;
    assert!(!registry.node(node(5)).unwrap().online);
    assert!(drain(&mut events).contains(&NodeEvent::Offline {
        node: node(5),
        reason: OfflineReason::HeartbeatLost
    }));
    // Something else from it does not make it well again; a heartbeat does.
    device.send(frame(0x185, &[1, 2])).await.unwrap();
    tokio::time::sleep(ms(1)).await;
    assert!(!registry.node(node(5)).unwrap().online);
    device.send(frame(0x705, &[0x05])).await.unwrap();
    tokio::time::sleep(ms(1)).await;
    let info = registry.node(node(5)).unwrap();
    assert!(info.online);
    assert_eq!(info.last_seen_ms, 1);
    assert!(drain(&mut events).contains(&NodeEvent::Online { node: node(5) }));
}

#[tokio::test(start_paused = true)]
async fn frames_that_are_not_a_node_speaking_add_no_node() {
    let hub = VirtualHub::new("test");
    let registry = registry(&hub, RegistryConfig::default());
    let other = hub.attach();
    for frame in [
        // A TPDO and an SDO answer of a node nobody heard of.
        frame(0x185, &[1, 2, 3]),
        frame(0x586, &[0x43, 0, 0x10, 0, 0x92, 1, 0, 0]),
        // A malformed heartbeat, a node-guarding request, an SDO request.
        frame(0x707, &[0x05, 0x05]),
        Frame::remote(CanId::Standard(0x708), 1).unwrap(),
        frame(0x609, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]),
        // SYNC, NMT, and a malformed EMCY.
        frame(0x080, &[]),
        frame(0x000, &[0x01, 0]),
        frame(0x08A, &[0x10, 0x43]),
    ] {
        other.send(frame).await.unwrap();
    }
    tokio::time::sleep(ms(10)).await;
    assert!(registry.nodes().is_empty());
}

#[tokio::test(start_paused = true)]
async fn the_emcy_history_keeps_the_most_recent_ones() {
    let hub = VirtualHub::new("test");
    let config = RegistryConfig {
        emcy_history: 4,
        ..RegistryConfig::default()
    };
    let registry = registry(&hub, config);
    let mut events = registry.subscribe();
    let device = hub.attach();
    for code in 0x1000u16..0x1006 {
        let emcy = Emcy::new(code, crate::canopen::emcy::ErrorRegister::from_raw(1));
        device.send(emcy.encode(node(7))).await.unwrap();
    }
    tokio::time::sleep(ms(1)).await;
    let codes: Vec<u16> = registry
        .emcy(node(7))
        .unwrap()
        .iter()
        .map(|e| e.code)
        .collect();
    assert_eq!(codes, [0x1002, 0x1003, 0x1004, 0x1005]);
    // Every one was published, the node appeared from the first.
    let seen = drain(&mut events);
    assert_eq!(seen[0], NodeEvent::Appeared { node: node(7) });
    let published = seen
        .iter()
        .filter(|event| matches!(event, NodeEvent::Emcy { .. }))
        .count();
    assert_eq!(published, 6);
    assert_eq!(registry.emcy(node(8)), None);
}

#[tokio::test(start_paused = true)]
async fn a_scan_probes_every_id_once_eight_at_a_time() {
    let hub = VirtualHub::new("test");
    let registry = registry(&hub, RegistryConfig::default());
    let observer = hub.attach();
    let mut frames = observer.subscribe();
    let start = Instant::now();
    let scan = tokio::spawn({
        let registry = registry.clone();
        async move { registry.scan().await }
    });
    let mut requested = Vec::new();
    let mut in_first_window = 0;
    loop {
        tokio::select! {
            received = frames.recv() => {
                let frame = received.unwrap().frame;
                let CanId::Standard(id) = frame.id() else { continue };
                // Requests, not the aborts that follow a timeout.
                if (0x601..=0x67F).contains(&id) && frame.data()[0] == 0x40 {
                    requested.push(id - 0x600);
                    if start.elapsed() < ms(50) {
                        in_first_window += 1;
                    }
                }
            }
            _ = tokio::time::sleep(ms(200)) => {
                if scan.is_finished() {
                    break;
                }
            }
        }
    }
    assert_eq!(scan.await.unwrap().unwrap().len(), 0);
    assert_eq!(in_first_window, 8);
    assert_eq!(requested.len(), 127);
    let distinct: BTreeSet<u16> = requested.iter().copied().collect();
    assert_eq!(distinct, (1..=127).collect());
    // 16 rounds of 100 ms, and the listening after.
    let took = start.elapsed();
    assert!(took >= ms(1600) && took < ms(2000), "{took:?}");
}

#[tokio::test(start_paused = true)]
async fn an_unknown_node_has_no_channel() {
    let hub = VirtualHub::new("test");
    let registry = registry(&hub, RegistryConfig::default());
    assert_eq!(
        registry.sdo(node(9)).err(),
        Some(RegistryError::UnknownNode {
            bus: "test".into(),
            node: node(9)
        })
    );
    assert_eq!(registry.bus_name(), "test");
}

/// A node that speaks while the scan probes it takes the probe's channel:
/// a read of it waits for the probe, so the server never has two requests
/// of two clients open at once (on a bus with a bit rate the probe and a
/// client's read overlapped, and the read got the probe's answer:
/// "it answered for object 0x1000 instead of 0x1008").
#[tokio::test(start_paused = true)]
async fn a_node_heard_during_its_probe_is_read_only_after_the_probe() {
    let hub = VirtualHub::new("test");
    let registry = registry(&hub, RegistryConfig::default());
    let device = hub.attach();
    let mut frames = device.subscribe();
    let scan = tokio::spawn({
        let registry = registry.clone();
        async move { registry.scan().await }
    });
    // The probe of node 5: an upload of 0x1000:0, left unanswered for now.
    let request = |frame: &Frame| frame.id() == CanId::Standard(0x605) && frame.data()[0] == 0x40;
    let probe = loop {
        let frame = frames.recv().await.unwrap().frame;
        if request(&frame) {
            break frame;
        }
    };
    assert_eq!(&probe.data()[1..4], &[0x00, 0x10, 0x00]);
    // Node 5 speaks meanwhile (a heartbeat, pre-operational), and a client
    // reads its 0x1008 through the node's channel at once.
    device.send(frame(0x705, &[0x7F])).await.unwrap();
    tokio::time::sleep(ms(1)).await;
    let channel = registry.sdo(node(5)).expect("the node is known");
    let read = tokio::spawn(async move { channel.upload(0x1008, 0).await });
    // No second request while the probe's is open.
    let deadline = tokio::time::Instant::now() + ms(20);
    while let Ok(received) = tokio::time::timeout_at(deadline, frames.recv()).await {
        let frame = received.unwrap().frame;
        assert!(
            !request(&frame),
            "a second request to node 5 while its probe is open: {frame:?}"
        );
    }
    // The probe's answer (device type 0x00020192), then the read's turn.
    device
        .send(frame(
            0x585,
            &[0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00],
        ))
        .await
        .unwrap();
    let second = loop {
        let frame = frames.recv().await.unwrap().frame;
        if request(&frame) && frame.data()[1..4] == [0x08, 0x10, 0x00] {
            break frame;
        }
    };
    assert_eq!(second.data()[0], 0x40);
    device
        .send(frame(0x585, &[0x4F, 0x08, 0x10, 0x00, b'X', 0, 0, 0]))
        .await
        .unwrap();
    assert_eq!(read.await.unwrap().unwrap(), b"X".to_vec());
    scan.abort();
}
