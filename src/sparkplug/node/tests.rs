//! The edge node's loop on a paused clock, against the demo's virtual bus,
//! with a connection whose broker is the test: it says CONNACK and reads
//! what the runner published (rumqttc's request queue, never sent).

use std::collections::BTreeMap;
use std::time::Duration;

use prost::Message;
use rumqttc::{ConnAck, ConnectReturnCode, Request};

use super::*;
use crate::can::{CanId, Frame};
use crate::sparkplug::proto::Payload;

/// The demo's bus, every node identified.
async fn demo() -> Gateway {
    let served = crate::sparkplug::tests::demo_bus().await;
    for _ in 0..600 {
        if served.nodes().iter().all(born_device) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(
        served.nodes().iter().all(born_device),
        "{:?}",
        served.nodes()
    );
    Gateway::new([served])
}

/// What the runner published so far: (when, topic, payload).
type Published = Vec<(Instant, String, Payload)>;

fn take_published(events: &mut EventLoop, into: &mut Published) {
    events.clean();
    for request in events.pending.drain(..) {
        if let Request::Publish(publish) = request {
            let payload = Payload::decode(publish.payload.as_ref()).unwrap();
            into.push((Instant::now(), publish.topic, payload));
        }
    }
}

/// Issue 33, point 7: one DDATA per device per publish tick (the TCK saw
/// DDATA pairs for one device 3 ms apart despite the 10 ms tick): what
/// changes within a tick (two NMT states, a TPDO frame twice) is one DDATA
/// of its device, every change in it, in order.
#[tokio::test(start_paused = true)]
async fn one_ddata_per_device_per_publish_tick() {
    let gateway = demo().await;
    let broker = "mqtt://127.0.0.1:1883".parse().unwrap();
    let mut config = SparkplugConfig::new(broker, "plant", "line1");
    config.publish_tick = Duration::from_millis(10);
    let tick = config.publish_tick;
    let runner = Runner::new(gateway.clone(), config.clone(), Spool::new(1000));
    let options = MqttOptions::new(config.client_id(), "127.0.0.1", 1883);
    let (client, mut requests) = AsyncClient::new(options, CLIENT_QUEUE);
    let (broker, events) = mpsc::channel(16);
    let connection = Connection {
        client,
        events,
        task: tokio::spawn(std::future::pending()),
        connected: false,
    };
    let (_stop, stopped) = oneshot::channel();
    let task = tokio::spawn(runner.run(stopped, Some(connection)));
    broker
        .send(Ok(Event::Incoming(Packet::ConnAck(ConnAck {
            session_present: false,
            code: ConnectReturnCode::Success,
        }))))
        .await
        .unwrap();
    let mut published = Published::new();
    for _ in 0..50 {
        tokio::time::sleep(Duration::from_millis(1)).await;
        take_published(&mut requests, &mut published);
    }
    assert!(
        published
            .iter()
            .any(|(_, topic, _)| topic.contains("/DBIRTH/")),
        "{:?}",
        published
            .iter()
            .map(|(_, topic, _)| topic)
            .collect::<Vec<_>>()
    );

    // Node 1 as another master sees it: stopped, then operational, within
    // a millisecond; and a burst of its heartbeats, each a frame.
    let wire = gateway
        .bus("demo")
        .unwrap()
        .hub()
        .expect("a virtual bus")
        .attach();
    let mut events = gateway.bus("demo").unwrap().node_events();
    let heartbeat = |state: u8| Frame::new(CanId::standard(0x701).unwrap(), &[state]).unwrap();
    for round in 0..5 {
        wire.send(heartbeat(0x04)).await.unwrap();
        tokio::time::sleep(Duration::from_micros(300)).await;
        wire.send(heartbeat(0x05)).await.unwrap();
        for _ in 0..(3 + round) {
            tokio::time::sleep(Duration::from_millis(1)).await;
            take_published(&mut requests, &mut published);
        }
    }
    for _ in 0..100 {
        tokio::time::sleep(Duration::from_millis(1)).await;
        take_published(&mut requests, &mut published);
    }
    task.abort();
    let mut emitted = 0;
    while let Ok(event) = events.try_recv() {
        if matches!(event, NodeEvent::NmtChanged { node, .. } if node.get() == 1) {
            emitted += 1;
        }
    }
    assert!(
        emitted >= 2,
        "the registry saw {emitted} NMT changes of node 1"
    );

    // Every change reported, in order: the NMT State metrics of demo-1's
    // DDATA, by the alias of its birth before them (a node that stops and
    // starts is born again).
    let mut nmt_alias = None;
    let mut nmt_changes = 0;
    let mut ddata: BTreeMap<String, Vec<(Instant, Payload)>> = BTreeMap::new();
    for (at, topic, payload) in published {
        if topic == "spBv1.0/plant/DBIRTH/line1/demo-1" {
            nmt_alias = payload
                .metrics
                .iter()
                .find(|metric| metric.name.as_deref() == Some("NMT State"))
                .and_then(|metric| metric.alias);
        }
        if let Some(device) = topic.strip_prefix("spBv1.0/plant/DDATA/line1/") {
            if device == "demo-1" {
                nmt_changes += payload
                    .metrics
                    .iter()
                    .filter(|metric| metric.alias.is_some() && metric.alias == nmt_alias)
                    .count();
            }
            ddata
                .entry(device.to_string())
                .or_default()
                .push((at, payload));
        }
    }
    assert!(ddata.contains_key("demo-1"), "no DDATA of demo-1");
    assert!(
        nmt_changes >= 2,
        "{nmt_changes} NMT changes in DDATA of {emitted}"
    );
    for (device, messages) in &ddata {
        for pair in messages.windows(2) {
            let apart = pair[1].0 - pair[0].0;
            assert!(
                apart >= tick,
                "{device}: two DDATA {apart:?} apart (the tick is {tick:?}): {:#?}",
                pair
            );
        }
    }
}

/// Issue 33, point 4: a command over `sparkplug_max_command_bytes` is
/// refused whole with its own code (413-like: `command_too_large`, the
/// size and the limit in its words), in one audit row, and nothing of it
/// runs.
#[tokio::test(start_paused = true)]
async fn a_command_over_the_byte_limit_is_refused_as_too_large() {
    let gateway = demo().await;
    let broker = "mqtt://127.0.0.1:1883".parse().unwrap();
    let mut config = SparkplugConfig::new(broker, "plant", "line1");
    config.username = Some("scada".into());
    config.role = crate::gateway::Role::Operator;
    config.max_command_bytes = 65_536;
    let mut runner = Runner::new(gateway.clone(), config, Spool::new(10));
    let topic = "spBv1.0/plant/DCMD/line1/demo-1";
    assert_eq!(runner.on_publish(&mut None, topic, &vec![0; 70_000]), None);
    let mut rows = Vec::new();
    for _ in 0..100 {
        rows = crate::door_audit::rows(&gateway).await;
        if !rows.is_empty() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert_eq!(rows.len(), 1, "{rows:#?}");
    let row = &rows[0];
    assert_eq!(row["operation"], "command");
    assert_eq!(row["outcome"], "command_too_large");
    assert_eq!(row["method"], "DCMD");
    assert_eq!(row["bus"], "demo");
    assert_eq!(row["node"], 1);
    assert_eq!(
        row["request"],
        "70000 bytes: over the limit of 65536 bytes for one command"
    );
    assert_eq!(
        runner
            .stats
            .commands_failed
            .load(std::sync::atomic::Ordering::Relaxed),
        1
    );
}
