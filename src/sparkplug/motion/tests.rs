//! DCMD motion commands against the demo UMC on `virtual:demo`, on a
//! paused clock: the lease promise and its id, a lapse that halts the
//! axis, renewals through `Axis 1/Lease`, a second sender without the
//! lease id refused, REST and MQTT leases side by side, the edge node's
//! leases lapsing when its broker connection is gone, the role, and an LED
//! segment write.

use std::time::Duration;

use super::*;
use crate::gateway::{EventKind, Query};
use crate::sparkplug::SparkplugConfig;
use crate::sparkplug::command::parse;
use crate::sparkplug::command::summary;
use crate::sparkplug::config::BrokerUrl;
use crate::sparkplug::metric::MetricValue;
use crate::sparkplug::node::run_message;
use crate::sparkplug::proto::Payload;
use crate::sparkplug::proto::payload::Metric;
use crate::sparkplug::topic::{MessageType, Topic};

const PERIOD: Duration = Duration::from_millis(1000);

async fn demo() -> Gateway {
    let served = crate::sparkplug::tests::demo_bus().await;
    Gateway::new([served]).with_lease_period(PERIOD)
}

fn config(role: crate::gateway::Role) -> SparkplugConfig {
    let broker: BrokerUrl = "mqtt://127.0.0.1:1883".parse().unwrap();
    let mut config = SparkplugConfig::new(broker, "plant", "line1");
    config.username = Some("scada".into());
    config.role = role;
    config
}

fn metric(name: &str, value: MetricValue) -> Metric {
    let mut metric = Metric {
        name: Some(name.into()),
        ..Metric::default()
    };
    value.fill(&mut metric);
    metric
}

/// A DCMD to `demo-{node}`, its commands run in order as the edge node
/// runs them; the result of each.
async fn dcmd(
    gateway: &Gateway,
    config: &SparkplugConfig,
    held: &HeldLeases,
    node: u8,
    metrics: Vec<Metric>,
) -> Vec<Result<(), GatewayError>> {
    let topic = Topic::device("plant", MessageType::DCmd, "line1", &format!("demo-{node}"));
    let payload = Payload {
        metrics,
        ..Payload::default()
    };
    let commands = parse(&payload, true);
    run_message(
        gateway,
        config,
        held,
        &topic,
        &commands,
        summary(&payload.metrics),
    )
    .await
}

async fn velocity(gateway: &Gateway) -> i64 {
    let drive = gateway.drive("demo", "1", "1").unwrap();
    i64::from(drive.status().await.unwrap().velocity.unwrap())
}

fn enable() -> Metric {
    metric(
        "Axis 1/State",
        MetricValue::String("operation_enabled".into()),
    )
}

fn run_at(speed: i32) -> Metric {
    metric(
        "Axis 1/Move",
        MetricValue::String(format!(r#"{{"mode":"velocity","velocity":{speed}}}"#)),
    )
}

fn renew() -> Metric {
    metric("Axis 1/Lease", MetricValue::Boolean(true))
}

/// The lease id the SCADA host chose for axis 1.
const HOST_ID: &str = "scada-host-axis1-0001";
/// Another MQTT client's, of its own choosing.
const OTHER_ID: &str = "other-client-axis1-02";

fn lease_id(id: &str) -> Metric {
    metric("Axis 1/Lease Id", MetricValue::String(id.into()))
}

async fn audit(gateway: &Gateway) -> Vec<serde_json::Map<String, serde_json::Value>> {
    gateway
        .history()
        .query(Query {
            kind: Some(EventKind::Audit),
            since_us: None,
            until_us: None,
            channel: None,
            limit: 100,
        })
        .await
        .unwrap()
        .into_iter()
        .map(|event| event.fields)
        .collect()
}

/// Axis 1 enabled and turning at 100 under the edge node's lease.
async fn turning() -> (Gateway, SparkplugConfig, HeldLeases) {
    let gateway = demo().await;
    let config = config(crate::gateway::Role::Operator);
    let held = HeldLeases::default();
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![enable(), run_at(100), renew(), lease_id(HOST_ID)],
    )
    .await;
    assert!(results.iter().all(Result::is_ok), "{results:?}");
    assert_eq!(held.len(), 1);
    tokio::time::sleep(PERIOD / 4).await;
    assert!(velocity(&gateway).await > 0, "not turning");
    (gateway, config, held)
}

#[tokio::test(start_paused = true)]
async fn a_move_without_an_end_is_refused_without_the_lease_promise() {
    let gateway = demo().await;
    let config = config(crate::gateway::Role::Operator);
    let held = HeldLeases::default();
    let results = dcmd(&gateway, &config, &held, 1, vec![enable(), run_at(100)]).await;
    assert!(results[0].is_ok(), "{results:?}");
    let refused = results[1].as_ref().unwrap_err();
    assert_eq!(refused.code(), "invalid_request", "{refused}");
    assert!(refused.to_string().contains("Axis 1/Lease"), "{refused}");
    assert!(held.is_empty());
    tokio::time::sleep(PERIOD / 2).await;
    assert_eq!(velocity(&gateway).await, 0, "moving without a lease");
    // A move with an end of its own needs none.
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![metric(
            "Axis 1/Move",
            MetricValue::String(r#"{"mode":"profile_position","target":1000}"#.into()),
        )],
    )
    .await;
    assert!(results[0].is_ok(), "{results:?}");
    assert!(held.is_empty());
    let entry = audit(&gateway)
        .await
        .into_iter()
        .find(|e| {
            e["operation"] == "drive state change, move"
                && e["request"]
                    .as_str()
                    .is_some_and(|r| r.ends_with("(1 of 2 failed)"))
        })
        .expect("the refused move is audited, in its message's row");
    assert_eq!(entry["outcome"], "invalid_request");
    assert_eq!(entry["channel"], "sparkplug");
    assert_eq!(entry["who"], "mqtt:scada");
    assert_eq!(entry["axis"], 1);
    assert_eq!(entry["method"], "DCMD");
}

#[tokio::test(start_paused = true)]
async fn a_lease_not_renewed_halts_the_axis() {
    let (gateway, _config, held) = turning().await;
    tokio::time::sleep(PERIOD / 2).await;
    assert!(velocity(&gateway).await > 0, "stopped before the lapse");
    tokio::time::sleep(PERIOD / 2 + PERIOD).await;
    assert_eq!(velocity(&gateway).await, 0, "still moving after the lapse");
    let lapse = audit(&gateway)
        .await
        .into_iter()
        .find(|e| e["who"] == "gateway")
        .expect("the lapse is audited");
    assert_eq!(lapse["operation"], "motion lease lapsed: axis halted");
    assert_eq!(lapse["item"], "velocity lease of mqtt:scada (1000 ms)");
    drop(held);
}

#[tokio::test(start_paused = true)]
async fn lease_renewals_keep_the_axis_moving_and_a_lapsed_one_is_refused() {
    let (gateway, config, held) = turning().await;
    for _ in 0..6 {
        tokio::time::sleep(PERIOD / 2).await;
        let results = dcmd(
            &gateway,
            &config,
            &held,
            1,
            vec![renew(), lease_id(HOST_ID)],
        )
        .await;
        assert!(results[0].is_ok(), "{results:?}");
    }
    assert!(velocity(&gateway).await > 0, "halted while renewed");
    // Renewals are audited once, not each.
    let renewals = audit(&gateway)
        .await
        .into_iter()
        .filter(|e| e["operation"] == "renew motion lease")
        .count();
    assert_eq!(renewals, 1);
    // Not renewed: it lapses, and a late renewal is refused in words.
    tokio::time::sleep(PERIOD * 3).await;
    assert_eq!(velocity(&gateway).await, 0);
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![renew(), lease_id(HOST_ID)],
    )
    .await;
    assert_eq!(results[0].as_ref().unwrap_err().code(), "unknown_lease");
    assert!(held.is_empty());
}

#[tokio::test(start_paused = true)]
async fn losing_the_broker_lapses_the_edge_nodes_leases_at_once() {
    let (gateway, _config, held) = turning().await;
    // What the runner does when its connection is lost.
    assert_eq!(held.lapse_all(&gateway, "test"), 1);
    assert!(held.is_empty());
    // Stopped well before the lease would have run out.
    tokio::time::sleep(PERIOD / 2).await;
    assert_eq!(velocity(&gateway).await, 0, "still moving without a host");
}

#[tokio::test(start_paused = true)]
async fn giving_the_lease_up_halts_and_another_client_is_refused_meanwhile() {
    let (gateway, config, held) = turning().await;
    // REST's anonymous client may not take the axis held by MQTT.
    let anonymous = crate::gateway::Caller::new(crate::gateway::Channel::Rest, "anonymous", None);
    let refused = gateway
        .set_axis_state(
            &anonymous,
            ("demo", "1", "1"),
            crate::gateway::TargetState::OperationEnabled,
            &crate::gateway::LeaseClaim::presented(None, false),
        )
        .await
        .unwrap_err();
    assert_eq!(refused.error.code(), "lease_conflict");
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![
            metric("Axis 1/Lease", MetricValue::Boolean(false)),
            lease_id(HOST_ID),
        ],
    )
    .await;
    assert!(results[0].is_ok(), "{results:?}");
    assert!(held.is_empty());
    tokio::time::sleep(PERIOD / 2).await;
    assert_eq!(velocity(&gateway).await, 0);
}

/// The refused commands' audit entries: (operation, outcome).
async fn refusals(gateway: &Gateway) -> Vec<(String, String)> {
    audit(gateway)
        .await
        .into_iter()
        .filter(|e| e["outcome"] != "ok" && e["who"] == "mqtt:scada")
        .map(|e| {
            assert_eq!(e["channel"], "sparkplug", "{e:?}");
            (
                e["operation"].as_str().unwrap_or_default().to_string(),
                e["outcome"].as_str().unwrap_or_default().to_string(),
            )
        })
        .collect()
}

#[tokio::test(start_paused = true)]
async fn a_second_sender_without_the_lease_id_cannot_move_reverse_or_release_halt() {
    // The host turns axis 1 under its lease; another MQTT client (the same
    // MQTT identity: MQTT carries none of the sender) sends DCMDs to it.
    let (gateway, config, held) = turning().await;
    let attempts = [
        vec![run_at(-300)],
        vec![run_at(-300), renew()],
        vec![run_at(-300), renew(), lease_id(OTHER_ID)],
        vec![metric("Axis 1/Halt", MetricValue::Boolean(false))],
        vec![
            metric("Axis 1/Halt", MetricValue::Boolean(false)),
            renew(),
            lease_id(OTHER_ID),
        ],
        vec![enable(), lease_id(OTHER_ID)],
        vec![metric(
            "Axis 1/Move",
            MetricValue::String(r#"{"mode":"profile_position","target":0}"#.into()),
        )],
        vec![renew(), lease_id(OTHER_ID)],
        vec![
            metric("Axis 1/Lease", MetricValue::Boolean(false)),
            lease_id(OTHER_ID),
        ],
    ];
    for metrics in attempts {
        let results = dcmd(&gateway, &config, &held, 1, metrics.clone()).await;
        let refused = results[0]
            .as_ref()
            .expect_err("the other sender was obeyed");
        assert!(
            ["lease_conflict", "unknown_lease"].contains(&refused.code()),
            "{metrics:?}: {refused}"
        );
        tokio::time::sleep(PERIOD / 4).await;
        assert!(
            velocity(&gateway).await > 0,
            "{metrics:?} disturbed the axis"
        );
        // The host's renewals go on.
        let renewed = dcmd(
            &gateway,
            &config,
            &held,
            1,
            vec![renew(), lease_id(HOST_ID)],
        )
        .await;
        assert!(renewed[0].is_ok(), "{renewed:?}");
    }
    // Never reversed: the other sender's -300 did not reach the drive.
    assert!(velocity(&gateway).await > 0);
    assert_eq!(held.len(), 1);
    // Each refusal is audited, as any refused DCMD is.
    let refused = refusals(&gateway).await;
    let count = |operation: &str| refused.iter().filter(|r| r.0 == operation).count();
    assert_eq!(count("move"), 4, "{refused:?}");
    assert_eq!(count("halt"), 2, "{refused:?}");
    assert_eq!(count("drive state change"), 1, "{refused:?}");
    assert_eq!(count("renew motion lease"), 1, "{refused:?}");
    assert_eq!(count("end motion lease"), 1, "{refused:?}");
    assert!(refused.iter().any(|r| r.1 == "lease_conflict"));
    // The host itself, presenting its id, changes its set-point.
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![run_at(-300), renew(), lease_id(HOST_ID)],
    )
    .await;
    assert!(results[0].is_ok(), "{results:?}");
    tokio::time::sleep(PERIOD / 4).await;
    assert!(
        velocity(&gateway).await < 0,
        "the holder's reverse not obeyed"
    );
    // A stop needs no lease: whoever sends it, it reaches the drive.
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![metric("Axis 1/Halt", MetricValue::Boolean(true))],
    )
    .await;
    assert!(results[0].is_ok(), "{results:?}");
    assert_eq!(gateway.leases_held(), 0);
}

#[tokio::test(start_paused = true)]
async fn a_lease_id_is_needed_to_take_a_lease_and_a_short_one_is_refused() {
    let gateway = demo().await;
    let config = config(crate::gateway::Role::Operator);
    let held = HeldLeases::default();
    // The promise without an id: the host could never present the lease.
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![enable(), run_at(100), renew()],
    )
    .await;
    assert!(results[0].is_ok(), "{results:?}");
    let refused = results[1].as_ref().unwrap_err();
    assert_eq!(refused.code(), "invalid_request", "{refused}");
    assert!(refused.to_string().contains("Axis 1/Lease Id"), "{refused}");
    for bad in ["too-short-id", "sixteen+chars/!!"] {
        let results = dcmd(
            &gateway,
            &config,
            &held,
            1,
            vec![run_at(100), renew(), lease_id(bad)],
        )
        .await;
        let refused = results[0].as_ref().unwrap_err();
        assert_eq!(refused.code(), "invalid_request", "{refused}");
        assert!(refused.to_string().contains("16 to 128"), "{refused}");
    }
    tokio::time::sleep(PERIOD / 2).await;
    assert_eq!(velocity(&gateway).await, 0, "moving without a lease");
    assert!(held.is_empty());
    assert_eq!(gateway.leases_held(), 0);
}

#[tokio::test(start_paused = true)]
async fn a_rest_client_and_a_sparkplug_host_lease_different_axes_undisturbed() {
    use crate::gateway::LeaseClaim;
    use crate::gateway::{Caller, Channel};
    use crate::gateway::{MoveRequest, TargetState};
    let (gateway, config, held) = turning().await;
    // A REST client (its operations are the ones REST's routes call) on
    // axis 2 of the same drive.
    let rest = Caller::new(Channel::Rest, "anonymous", None);
    let axis2 = ("demo", "1", "2");
    gateway
        .set_axis_state(
            &rest,
            axis2,
            TargetState::OperationEnabled,
            &LeaseClaim::default(),
        )
        .await
        .unwrap();
    let request: MoveRequest =
        serde_json::from_str(r#"{"mode":"velocity","velocity":200}"#).unwrap();
    let moved = gateway
        .move_axis(&rest, axis2, &request, &LeaseClaim::default())
        .await
        .unwrap();
    let rest_lease = moved.lease.expect("a velocity move is leased");
    let axis2_key = AxisKey {
        bus: "demo".into(),
        node: 1,
        axis: 2,
    };
    let speed2 = || async {
        let drive = gateway.drive("demo", "1", "2").unwrap();
        i64::from(drive.status().await.unwrap().velocity.unwrap())
    };
    for _ in 0..4 {
        tokio::time::sleep(PERIOD / 2).await;
        // Each renews its own, through its own door.
        gateway
            .renew_axis_lease(&rest, &axis2_key, &rest_lease.id)
            .await
            .unwrap();
        let results = dcmd(
            &gateway,
            &config,
            &held,
            1,
            vec![renew(), lease_id(HOST_ID)],
        )
        .await;
        assert!(results[0].is_ok(), "{results:?}");
    }
    assert!(velocity(&gateway).await > 0);
    assert!(speed2().await > 0);
    // Neither commands the other's axis without its lease.
    let refused = gateway
        .move_axis(&rest, ("demo", "1", "1"), &request, &LeaseClaim::default())
        .await
        .unwrap_err();
    assert_eq!(refused.error.code(), "lease_conflict");
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![
            metric(
                "Axis 2/Move",
                MetricValue::String(r#"{"mode":"velocity","velocity":-300}"#.into()),
            ),
            metric("Axis 2/Lease", MetricValue::Boolean(true)),
            metric("Axis 2/Lease Id", MetricValue::String(HOST_ID.into())),
        ],
    )
    .await;
    assert_eq!(results[0].as_ref().unwrap_err().code(), "lease_conflict");
    // The edge node losing its broker lapses the host's lease only.
    assert_eq!(held.lapse_all(&gateway, "test"), 1);
    tokio::time::sleep(PERIOD / 2).await;
    gateway
        .renew_axis_lease(&rest, &axis2_key, &rest_lease.id)
        .await
        .unwrap();
    assert_eq!(velocity(&gateway).await, 0, "axis 1 still moving");
    assert!(speed2().await > 0, "the REST client's axis was stopped");
}

#[tokio::test(start_paused = true)]
async fn a_viewer_role_refuses_every_motion_command() {
    let gateway = demo().await;
    let config = config(crate::gateway::Role::Viewer);
    let held = HeldLeases::default();
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![enable(), run_at(100), renew()],
    )
    .await;
    assert_eq!(results.len(), 2);
    for result in &results {
        assert_eq!(result.as_ref().unwrap_err().code(), "forbidden");
    }
    let drive = gateway.drive("demo", "1", "1").unwrap();
    assert_ne!(drive.status().await.unwrap().state, "operation_enabled");
}

/// The edge node's door checks no role: each operation checks the role it
/// needs (`crate::gateway::Operation`), as for REST's callers, and
/// its refusal is audited once, by the operation.
#[tokio::test(start_paused = true)]
async fn a_viewer_role_is_refused_by_the_operations_themselves() {
    let gateway = demo().await;
    let config = config(crate::gateway::Role::Viewer);
    let held = HeldLeases::default();
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![
            metric("OD/0x1017:0", MetricValue::UInt16(1000)),
            metric("NMT", MetricValue::String("stop".into())),
        ],
    )
    .await;
    assert_eq!(results.len(), 2);
    for result in &results {
        assert_eq!(result.as_ref().unwrap_err().code(), "forbidden");
    }
    let rows = crate::door_audit::rows(&gateway).await;
    let mut refused: Vec<_> = rows
        .iter()
        .map(|row| {
            (
                row["operation"].as_str().unwrap().to_string(),
                row["outcome"].as_str().unwrap().to_string(),
                row["role"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    refused.sort();
    assert_eq!(
        refused,
        // One row for the DCMD, both refusals in it.
        [(
            "write object, nmt command".into(),
            "forbidden".into(),
            "viewer".into()
        )]
    );
}

/// Issue 33, point 1: an operator edge node that logs in to no broker
/// account takes no command (anyone on the broker could send it), audited
/// as refused under the door `sparkplug`.
#[tokio::test(start_paused = true)]
async fn an_edge_node_without_broker_credentials_takes_no_command() {
    let gateway = demo().await;
    let mut config = config(crate::gateway::Role::Operator);
    config.username = None;
    let held = HeldLeases::default();
    let results = dcmd(&gateway, &config, &held, 1, vec![enable()]).await;
    assert_eq!(results.len(), 1);
    assert_eq!(results[0].as_ref().unwrap_err().code(), "forbidden");
    let drive = gateway.drive("demo", "1", "1").unwrap();
    assert_ne!(drive.status().await.unwrap().state, "operation_enabled");
    let rows = crate::door_audit::rows(&gateway).await;
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_eq!(rows[0]["channel"], "sparkplug");
    assert_eq!(rows[0]["outcome"], "forbidden");
    // The insecure override takes it.
    config.insecure = true;
    let results = dcmd(&gateway, &config, &held, 1, vec![enable()]).await;
    assert!(results[0].is_ok(), "{results:?}");
}

/// Issue 33, point 3: what a host may write to a drive is in its birth,
/// typed and writable: the command metrics and the EDS's writable objects.
#[tokio::test(start_paused = true)]
async fn a_drive_s_birth_names_every_command_metric_typed_and_writable() {
    use crate::sparkplug::proto::DataType;
    let gateway = demo().await;
    let served = gateway.bus("demo").unwrap();
    let info = served
        .node(crate::canopen::NodeId::new(1).unwrap())
        .unwrap();
    let samples = crate::sparkplug::node::command_samples(&info, 0);
    let find = |name: &str| {
        samples
            .iter()
            .find(|sample| sample.name == name)
            .unwrap_or_else(|| panic!("{name} not born"))
    };
    for (name, datatype) in [
        ("NMT", DataType::String),
        ("Axis 1/State", DataType::String),
        ("Axis 1/Move", DataType::String),
        ("Axis 1/Halt", DataType::Boolean),
        ("Axis 1/Fault Reset", DataType::Boolean),
        ("Axis 1/Lease", DataType::Boolean),
        ("Axis 1/Lease Id", DataType::String),
        ("OD/0x1017:0", DataType::UInt16),
    ] {
        let sample = find(name);
        assert!(sample.writable, "{name}");
        assert_eq!(sample.value.datatype(), datatype, "{name}");
    }
    assert!(!find("Axis 1/Position").writable);
    // A read-only object of the EDS is no command.
    assert!(samples.iter().all(|sample| sample.name != "OD/0x1000:0"));
}

/// Issue 33, point 4 (the audit half): a command's row keeps a bounded
/// summary, never the whole payload.
#[tokio::test(start_paused = true)]
async fn a_huge_command_value_leaves_a_bounded_audit_row() {
    let gateway = demo().await;
    let config = config(crate::gateway::Role::Operator);
    let held = HeldLeases::default();
    let huge = "x".repeat(2 * 1024 * 1024);
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![metric("OD/0x1008:0", MetricValue::String(huge))],
    )
    .await;
    assert_eq!(results.len(), 1);
    let rows = crate::door_audit::rows(&gateway).await;
    assert_eq!(rows.len(), 1, "{rows:?}");
    let request = rows[0]["request"].as_str().unwrap();
    assert!(request.len() < 1024, "{} bytes", request.len());
    assert!(request.contains("bytes)"), "{request}");
}

#[tokio::test(start_paused = true)]
async fn a_segment_write_reaches_the_led_controller() {
    let gateway = demo().await;
    let config = config(crate::gateway::Role::Operator);
    let held = HeldLeases::default();
    let led = gateway
        .bus("demo")
        .unwrap()
        .nodes()
        .into_iter()
        .find(|info| info.profile == crate::gateway::Profile::Uioled)
        .expect("the demo has a UIO1LED");
    let node = led.id.get();
    let results = dcmd(
        &gateway,
        &config,
        &held,
        node,
        vec![
            metric("Segment 2/Color 1", MetricValue::String("#ff5000".into())),
            metric("Segment 2/Effect", MetricValue::String("breathing".into())),
            metric("Segment 2/Dimmer", MetricValue::UInt8(99)),
            metric("Segment 2/Dimmer", MetricValue::Int32(999)),
        ],
    )
    .await;
    assert!(results[..3].iter().all(Result::is_ok), "{results:?}");
    assert_eq!(
        results[3].as_ref().unwrap_err().code(),
        "value_out_of_range"
    );
    // Read back by another master on the bus.
    let (served, info) = gateway.node("demo", &node.to_string()).unwrap();
    let channel = crate::gateway::SdoChannel::new(
        served.hub().expect("a virtual bus").attach(),
        info.id,
        crate::canopen::sdo::ClientConfig::default(),
    );
    let segment = crate::gateway::read_segment(&channel, 2).await.unwrap();
    assert_eq!(segment.get(crate::profiles::uioled::Field::Dimmer), 99);
    assert_eq!(
        segment.get(crate::profiles::uioled::Field::Effect),
        i64::from(crate::profiles::uioled::Effect::Breathing.raw())
    );
    assert_eq!(segment.color_1().r, 0xff);
    assert_eq!(segment.color_1().g, 0x50);
}

/// Issue 29: every MQTT client shares the edge node's identity, so an
/// unleased flood from one client used to spend the bucket the lease's
/// holder draws on (7 of 8 of the host's writes refused with 429). A
/// command presenting the lease held on its axis draws on that lease's
/// bucket; the flood is refused, and audited, on its own.
#[tokio::test(start_paused = true)]
async fn a_flood_without_the_lease_does_not_starve_the_lease_holder() {
    use crate::gateway::RateLimit;
    let gateway = demo().await.with_write_limit(Some(RateLimit::default()));
    let config = config(crate::gateway::Role::Operator);
    let held = HeldLeases::default();
    let results = dcmd(
        &gateway,
        &config,
        &held,
        1,
        vec![enable(), run_at(100), renew(), lease_id(HOST_ID)],
    )
    .await;
    assert!(results.iter().all(Result::is_ok), "{results:?}");
    // Another client floods at 120 writes a second (object writes and
    // moves that present no lease) while the host changes its set-point
    // 8 times, presenting its lease.
    let mut host_refused = 0;
    let mut flood_refused = 0;
    for round in 0..8 {
        for _ in 0..30 {
            let flood = dcmd(
                &gateway,
                &config,
                &held,
                1,
                vec![metric("OD/0x1017:0", MetricValue::UInt16(1000))],
            )
            .await;
            if flood[0].as_ref().is_err_and(|e| e.code() == "rate_limited") {
                flood_refused += 1;
            }
        }
        let host = dcmd(
            &gateway,
            &config,
            &held,
            1,
            vec![run_at(100 + round), renew(), lease_id(HOST_ID)],
        )
        .await;
        if host[0].is_err() {
            host_refused += 1;
        }
        // Within the lease period (the move renews the lease).
        tokio::time::sleep(PERIOD / 4).await;
    }
    assert_eq!(host_refused, 0, "the host was starved");
    assert!(
        flood_refused > 100,
        "the flood was not limited: {flood_refused}"
    );
    assert!(
        velocity(&gateway).await > 100,
        "the last set-point not obeyed"
    );
    // Each refusal of the flood is audited.
    let audited = gateway
        .history()
        .query(Query {
            kind: Some(EventKind::Audit),
            since_us: None,
            until_us: None,
            channel: None,
            limit: 10_000,
        })
        .await
        .unwrap()
        .into_iter()
        .filter(|event| {
            event.fields.get("operation") == Some(&"write object".into())
                && event.fields.get("outcome") == Some(&"rate_limited".into())
                && event.fields.get("channel") == Some(&"sparkplug".into())
        })
        .count();
    assert_eq!(audited, flood_refused);
}

/// A segment command runs REST's LED operation: one write of the edge
/// node's rate each (not one by the edge node and another by the
/// operation), and a node that is no LED controller is refused as REST
/// refuses it.
#[tokio::test(start_paused = true)]
async fn a_segment_command_is_one_write_and_refused_as_rest_refuses_it() {
    use crate::gateway::RateLimit;
    let gateway = demo().await.with_write_limit(Some(RateLimit {
        per_second: 0.001,
        burst: 3,
    }));
    let config = config(crate::gateway::Role::Operator);
    let held = HeldLeases::default();
    let dim = |level: u8| metric("Segment 1/Dimmer", MetricValue::UInt8(level));
    let results = dcmd(
        &gateway,
        &config,
        &held,
        3,
        vec![dim(1), dim(2), dim(3), dim(4)],
    )
    .await;
    assert!(results[..3].iter().all(Result::is_ok), "{results:?}");
    assert_eq!(results[3].as_ref().unwrap_err().code(), "rate_limited");

    let gateway = demo().await;
    let results = dcmd(&gateway, &config, &held, 1, vec![dim(1)]).await;
    assert_eq!(
        results[0].as_ref().unwrap_err().code(),
        "not_an_led_controller"
    );
}
