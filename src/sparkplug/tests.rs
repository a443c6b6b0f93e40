use prost::Message;

use super::command::{self, Command, parse_device};
use super::config::BrokerUrl;
use super::edge::{EdgeSession, MetricRule, Policy, REBIRTH, RebirthGate, Reporting};
use super::metric::{MetricValue, Sample};
use super::proto::payload::{Metric, metric};
use super::proto::{DataType, Payload};
use super::spool::{Spool, read_records};
use super::topic::{
    HostState, HostVerdict, MessageType, PrimaryHost, Topic, parse_host_state, state_topic,
};
use crate::canopen::nmt::NmtCommand;
use crate::canopen::od::Value;
use crate::gateway::SegmentUpdate;

fn session() -> EdgeSession {
    EdgeSession::new("plant", "line1", 0, Policy::default())
}

/// A data message's value: typed by the birth (Sparkplug 3.0: the data
/// messages carry no datatype).
fn data_value(metric: &Metric, datatype: DataType) -> Option<MetricValue> {
    assert_eq!(
        metric.datatype, None,
        "a datatype repeated in data: {metric:?}"
    );
    let mut typed = metric.clone();
    typed.datatype = Some(datatype as u32);
    MetricValue::from_metric(&typed)
}

fn sample(name: &str, value: MetricValue) -> Sample {
    Sample::new(name, value, 1_000)
}

fn device_born(session: &mut EdgeSession, metrics: Vec<Sample>) {
    session.birth(Vec::new(), 1_000);
    session.device_birth("demo-1", metrics, 1_000);
}

#[test]
fn topics_are_written_and_read_as_the_namespace_says() {
    let topic = Topic::device("plant", MessageType::DData, "line1", "demo-1");
    assert_eq!(topic.to_string(), "spBv1.0/plant/DDATA/line1/demo-1");
    assert_eq!(
        Topic::parse("spBv1.0/plant/DDATA/line1/demo-1"),
        Some(topic)
    );
    let node = Topic::node("plant", MessageType::NBirth, "line1");
    assert_eq!(node.to_string(), "spBv1.0/plant/NBIRTH/line1");
    assert_eq!(Topic::parse(&node.to_string()), Some(node));
    for bad in [
        "spBv1.0/plant/DDATA/line1",
        "spBv1.0/plant/NDATA/line1/demo-1",
        "spBv2.0/plant/NDATA/line1",
        "spBv1.0/plant/XDATA/line1",
        "spBv1.0//NDATA/line1",
        "spBv1.0/plant/DCMD/line1/demo-1/x",
    ] {
        assert_eq!(Topic::parse(bad), None, "{bad}");
    }
    assert_eq!(state_topic("scada"), "spBv1.0/STATE/scada");
}

#[test]
fn a_host_state_is_json_with_online() {
    let state = parse_host_state(br#"{"online":true,"timestamp":5}"#).unwrap();
    assert!(state.online);
    assert_eq!(state.timestamp, Some(5));
    assert!(!parse_host_state(br#"{"online":false}"#).unwrap().online);
    assert_eq!(parse_host_state(b"ONLINE"), None);
    assert_eq!(parse_host_state(br#"{"timestamp":5}"#), None);
}

#[test]
fn signed_integers_go_as_sign_extended_u32_and_come_back() {
    let mut m = Metric::default();
    MetricValue::Int8(-1).fill(&mut m);
    assert_eq!(m.value, Some(metric::Value::IntValue(0xFFFF_FFFF)));
    assert_eq!(m.datatype, Some(DataType::Int8 as u32));
    assert_eq!(MetricValue::from_metric(&m), Some(MetricValue::Int8(-1)));
    for value in [
        MetricValue::Int16(-300),
        MetricValue::Int32(i32::MIN),
        MetricValue::Int64(-5),
        MetricValue::UInt8(200),
        MetricValue::UInt16(65_535),
        MetricValue::UInt32(u32::MAX),
        MetricValue::UInt64(u64::MAX),
        MetricValue::Float(1.5),
        MetricValue::Double(-2.25),
        MetricValue::Boolean(true),
        MetricValue::String("operational".into()),
        MetricValue::Bytes(vec![1, 2]),
        MetricValue::Null(DataType::UInt16),
    ] {
        let mut m = Metric::default();
        value.fill(&mut m);
        assert_eq!(
            MetricValue::from_metric(&m),
            Some(value.clone()),
            "{value:?}"
        );
    }
    // A UInt8 whose value does not fit is no UInt8.
    let m = Metric {
        datatype: Some(DataType::UInt8 as u32),
        value: Some(metric::Value::IntValue(256)),
        ..Metric::default()
    };
    assert_eq!(MetricValue::from_metric(&m), None);
}

#[test]
fn canopen_values_take_their_nearest_sparkplug_type() {
    assert_eq!(
        MetricValue::from_canopen(&Value::Unsigned16(0x637)),
        MetricValue::UInt16(0x637)
    );
    assert_eq!(
        MetricValue::from_canopen(&Value::Integer24(-7)),
        MetricValue::Int32(-7)
    );
    assert_eq!(
        MetricValue::from_canopen(&Value::Unsigned40(1 << 33)),
        MetricValue::UInt64(1 << 33)
    );
    assert_eq!(
        MetricValue::from_canopen(&Value::VisibleString("x".into())),
        MetricValue::String("x".into())
    );
    assert_eq!(
        MetricValue::from_canopen(&Value::Real32(0.5)),
        MetricValue::Float(0.5)
    );
}

#[test]
fn nbirth_has_seq_0_the_bdseq_and_rebirth_and_ndeath_has_no_seq() {
    let mut s = EdgeSession::new("plant", "line1", 254, Policy::default());
    assert_eq!(s.next_connection(), 255);
    let birth = s.birth(
        vec![sample(
            "Properties/Version",
            MetricValue::String("1".into()),
        )],
        9,
    );
    assert_eq!(birth.topic.to_string(), "spBv1.0/plant/NBIRTH/line1");
    assert_eq!(birth.payload.seq, Some(0));
    let names: Vec<_> = birth
        .payload
        .metrics
        .iter()
        .map(|m| m.name.clone().unwrap())
        .collect();
    assert_eq!(names, ["bdSeq", REBIRTH, "Properties/Version"]);
    assert_eq!(
        MetricValue::from_metric(&birth.payload.metrics[0]),
        Some(MetricValue::Int64(255))
    );
    // Sparkplug 3.0: bdSeq is an Int64.
    assert_eq!(
        birth.payload.metrics[0].datatype,
        Some(DataType::Int64 as u32)
    );
    let death = s.death(10);
    assert_eq!(death.topic.to_string(), "spBv1.0/plant/NDEATH/line1");
    assert_eq!(
        death.payload.metrics[0].datatype,
        Some(DataType::Int64 as u32)
    );
    assert_eq!(death.payload.seq, None);
    assert_eq!(
        MetricValue::from_metric(&death.payload.metrics[0]),
        Some(MetricValue::Int64(255))
    );
    // The next connection's bdSeq wraps.
    assert_eq!(s.next_connection(), 0);
}

#[test]
fn seq_counts_every_message_after_the_birth_and_wraps_after_255() {
    let mut s = session();
    device_born(&mut s, vec![sample("v", MetricValue::UInt32(0))]);
    let mut last = 1;
    for i in 1..=300u32 {
        let mut message = s
            .data(
                Some("demo-1"),
                vec![sample("v", MetricValue::UInt32(i))],
                0,
                false,
            )
            .unwrap();
        s.sequence(&mut message.payload);
        let seq = message.payload.seq.unwrap();
        assert_eq!(seq, (last + 1) % 256);
        last = seq;
    }
    // A new birth starts at 0 again.
    assert_eq!(s.birth(Vec::new(), 0).payload.seq, Some(0));
}

#[test]
fn data_carries_aliases_alone_and_only_what_changed() {
    let mut s = session();
    device_born(
        &mut s,
        vec![
            sample("a", MetricValue::UInt16(1)),
            sample("b", MetricValue::String("x".into())),
        ],
    );
    let birth_alias = |s: &mut EdgeSession| {
        s.device_birth(
            "demo-1",
            vec![
                sample("a", MetricValue::UInt16(1)),
                sample("b", MetricValue::String("x".into())),
            ],
            0,
        )
        .payload
        .metrics[0]
            .alias
    };
    let alias_a = birth_alias(&mut s);
    let message = s
        .data(
            Some("demo-1"),
            vec![
                sample("a", MetricValue::UInt16(2)),
                sample("b", MetricValue::String("x".into())),
                sample("never born", MetricValue::UInt16(2)),
            ],
            0,
            false,
        )
        .unwrap();
    assert_eq!(
        message.topic.to_string(),
        "spBv1.0/plant/DDATA/line1/demo-1"
    );
    assert_eq!(message.payload.metrics.len(), 1);
    let m = &message.payload.metrics[0];
    assert_eq!((m.name.as_deref(), m.alias), (None, alias_a));
    assert_eq!(
        data_value(m, DataType::UInt16),
        Some(MetricValue::UInt16(2))
    );
    // The same value again is no change.
    assert_eq!(
        s.data(
            Some("demo-1"),
            vec![sample("a", MetricValue::UInt16(2))],
            0,
            false
        ),
        None
    );
    // Offline, the names go along (a later session's aliases may differ).
    let named = s
        .data(
            Some("demo-1"),
            vec![sample("a", MetricValue::UInt16(3))],
            0,
            true,
        )
        .unwrap();
    assert_eq!(named.payload.metrics[0].name.as_deref(), Some("a"));
    // A device that was not born reports nothing.
    assert_eq!(
        s.data(
            Some("demo-9"),
            vec![sample("a", MetricValue::UInt16(3))],
            0,
            false
        ),
        None
    );
}

#[test]
fn a_deadband_holds_small_moves_back() {
    let policy = Policy {
        default: Reporting::default(),
        rules: vec![MetricRule {
            metric: "Position".into(),
            reporting: Reporting {
                deadband: 10.0,
                min_interval_ms: 0,
            },
        }],
    };
    let mut s = EdgeSession::new("plant", "line1", 0, policy);
    device_born(
        &mut s,
        vec![sample("Axis 1/Position", MetricValue::Int32(100))],
    );
    let report = |s: &mut EdgeSession, v| {
        s.data(
            Some("demo-1"),
            vec![sample("Axis 1/Position", MetricValue::Int32(v))],
            0,
            false,
        )
        .map(|m| data_value(&m.payload.metrics[0], DataType::Int32).unwrap())
    };
    assert_eq!(report(&mut s, 105), None);
    assert_eq!(report(&mut s, 110), None);
    assert_eq!(report(&mut s, 111), Some(MetricValue::Int32(111)));
    // Measured from what was reported last.
    assert_eq!(report(&mut s, 120), None);
    assert_eq!(report(&mut s, 100), Some(MetricValue::Int32(100)));
}

/// A session whose metrics are reported at most every 100 ms.
fn rate_limited_session() -> EdgeSession {
    let policy = Policy {
        default: Reporting {
            deadband: 0.0,
            min_interval_ms: 100,
        },
        rules: Vec::new(),
    };
    EdgeSession::new("plant", "line1", 0, policy)
}

#[test]
fn a_maximum_rate_reports_the_newest_value_when_its_interval_is_up() {
    let mut s = rate_limited_session();
    device_born(&mut s, vec![sample("v", MetricValue::UInt32(0))]);
    let at = |s: &mut EdgeSession, v, now| {
        s.data(
            Some("demo-1"),
            vec![sample("v", MetricValue::UInt32(v))],
            now,
            false,
        )
    };
    assert!(at(&mut s, 1, 1_000).is_some());
    assert!(at(&mut s, 2, 1_010).is_none());
    assert!(at(&mut s, 3, 1_050).is_none());
    assert_eq!(s.next_due(), Some(1_100));
    assert!(s.due(1_099, false).is_empty());
    let due = s.due(1_100, false);
    assert_eq!(due.len(), 1);
    assert_eq!(
        data_value(&due[0].payload.metrics[0], DataType::UInt32),
        Some(MetricValue::UInt32(3))
    );
    assert_eq!(s.next_due(), None);
    // A held change that goes back to what was reported is void.
    assert!(at(&mut s, 4, 1_150).is_none());
    assert!(at(&mut s, 3, 1_160).is_none());
    assert_eq!(s.next_due(), None);
    assert!(s.due(5_000, false).is_empty());
}

#[test]
fn held_changes_end_with_their_device_birth_or_death_and_others_stay_due() {
    let mut s = rate_limited_session();
    s.birth(Vec::new(), 1_000);
    for device in ["demo-1", "demo-2", "demo-3"] {
        s.device_birth(device, vec![sample("v", MetricValue::UInt32(0))], 1_000);
    }
    let at = |s: &mut EdgeSession, device, v, now| {
        s.data(
            Some(device),
            vec![sample("v", MetricValue::UInt32(v))],
            now,
            false,
        )
    };
    for (device, now) in [("demo-1", 1_000), ("demo-2", 1_020), ("demo-3", 1_040)] {
        assert!(at(&mut s, device, 1, now).is_some());
        assert!(at(&mut s, device, 2, now + 1).is_none());
    }
    assert_eq!(s.next_due(), Some(1_100));
    // A new birth says the newest value: nothing is held for it any more.
    s.device_birth("demo-1", vec![sample("v", MetricValue::UInt32(2))], 1_050);
    assert_eq!(s.next_due(), Some(1_120));
    // Nor for a device that died.
    assert!(s.device_death("demo-2", 1_060).is_some());
    assert_eq!(s.next_due(), Some(1_140));
    let due = s.due(1_140, false);
    assert_eq!(due.len(), 1);
    assert_eq!(due[0].topic.to_string(), "spBv1.0/plant/DDATA/line1/demo-3");
    assert_eq!(s.next_due(), None);
    assert!(s.due(9_000, false).is_empty());
}

#[test]
fn ddeath_only_for_a_born_device_and_a_new_nbirth_unbirths_all() {
    let mut s = session();
    assert!(s.device_death("demo-1", 0).is_none());
    device_born(&mut s, vec![sample("v", MetricValue::UInt8(1))]);
    assert!(s.is_born("demo-1"));
    assert!(s.knows("demo-1", "v"));
    let death = s.device_death("demo-1", 0).unwrap();
    assert_eq!(death.topic.to_string(), "spBv1.0/plant/DDEATH/line1/demo-1");
    assert_eq!(death.payload.seq, Some(2));
    assert!(!s.is_born("demo-1"));
    device_born(&mut s, vec![sample("v", MetricValue::UInt8(1))]);
    s.birth(Vec::new(), 0);
    assert_eq!(s.born().count(), 0);
}

#[test]
fn aliases_are_unique_within_a_session() {
    let mut s = session();
    let nbirth = s.birth(vec![sample("n", MetricValue::UInt8(0))], 0);
    let d1 = s.device_birth("demo-1", vec![sample("v", MetricValue::UInt8(0))], 0);
    let d2 = s.device_birth("demo-2", vec![sample("v", MetricValue::UInt8(0))], 0);
    let mut aliases: Vec<u64> = [nbirth, d1, d2]
        .iter()
        .flat_map(|m| m.payload.metrics.iter().filter_map(|m| m.alias))
        .collect();
    let count = aliases.len();
    aliases.sort_unstable();
    aliases.dedup();
    assert_eq!(aliases.len(), count);
}

fn message(s: &mut EdgeSession, v: u32) -> super::edge::Outgoing {
    s.data(
        Some("demo-1"),
        vec![sample("v", MetricValue::UInt32(v))],
        0,
        true,
    )
    .unwrap()
}

#[test]
fn the_spool_is_bounded_counts_its_drops_and_drains_in_order_as_historical() {
    let mut s = session();
    device_born(&mut s, vec![sample("v", MetricValue::UInt32(0))]);
    let mut spool = Spool::new(3);
    for v in 1..=5 {
        spool.push(message(&mut s, v));
    }
    assert_eq!((spool.len(), spool.dropped()), (3, 2));
    let drained = spool.drain();
    assert!(spool.is_empty());
    let values: Vec<_> = drained
        .iter()
        .map(|m| data_value(&m.payload.metrics[0], DataType::UInt32).unwrap())
        .collect();
    assert_eq!(
        values,
        [3, 4, 5].map(MetricValue::UInt32).to_vec(),
        "the oldest dropped, the rest in order"
    );
    for m in &drained {
        let metric = &m.payload.metrics[0];
        assert_eq!(metric.is_historical, Some(true));
        assert_eq!(metric.name.as_deref(), Some("v"));
        assert_eq!(metric.alias, None);
        assert_eq!(m.payload.seq, None, "sequenced when sent");
    }
}

#[test]
fn the_spool_file_keeps_the_queue_across_a_restart() {
    let dir = std::env::temp_dir().join(format!("candeck-spool-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("sparkplug-spool.bin");
    let mut s = session();
    device_born(&mut s, vec![sample("v", MetricValue::UInt32(0))]);
    {
        let mut spool = Spool::with_file(2, file.clone()).unwrap();
        for v in 1..=3 {
            spool.push(message(&mut s, v));
        }
    }
    let mut again = Spool::with_file(10, file.clone()).unwrap();
    let values: Vec<_> = again
        .drain()
        .iter()
        .map(|m| data_value(&m.payload.metrics[0], DataType::UInt32).unwrap())
        .collect();
    assert_eq!(values, [2, 3].map(MetricValue::UInt32).to_vec());
    // Drained: the file is empty too.
    assert!(Spool::with_file(10, file.clone()).unwrap().is_empty());
    // A record cut short (a crash mid-write) ends the reading.
    {
        let mut spool = Spool::with_file(10, file.clone()).unwrap();
        spool.push(message(&mut s, 7));
        spool.push(message(&mut s, 8));
    }
    let bytes = std::fs::read(&file).unwrap();
    assert_eq!(read_records(&bytes).len(), 2);
    assert_eq!(read_records(&bytes[..bytes.len() - 1]).len(), 1);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn commands_are_read_from_ncmd_and_dcmd_metrics() {
    let m = |name: &str, value: MetricValue| {
        let mut metric = Metric {
            name: Some(name.into()),
            ..Metric::default()
        };
        value.fill(&mut metric);
        metric
    };
    let ncmd = Payload {
        metrics: vec![m(REBIRTH, MetricValue::Boolean(true))],
        ..Payload::default()
    };
    assert_eq!(command::parse(&ncmd, false), [Command::Rebirth]);
    // Rebirth is no device command.
    assert!(matches!(
        command::parse(&ncmd, true)[0],
        Command::Unsupported(_)
    ));
    let dcmd = Payload {
        metrics: vec![
            m("OD/0x1017:0", MetricValue::UInt16(500)),
            m("NMT", MetricValue::String("reset_node".into())),
            m("NMT", MetricValue::String("dance".into())),
            m("OD/zz:0", MetricValue::UInt16(1)),
        ],
        ..Payload::default()
    };
    let commands = command::parse(&dcmd, true);
    assert_eq!(
        commands[..2],
        [
            Command::Write {
                index: 0x1017,
                sub: 0,
                value: MetricValue::UInt16(500)
            },
            Command::Nmt(NmtCommand::ResetNode),
        ]
    );
    assert!(matches!(commands[2], Command::Unsupported(_)));
    assert!(matches!(commands[3], Command::Unsupported(_)));
}

#[test]
fn axis_and_segment_commands_are_read_and_a_lease_promise_goes_with_its_move() {
    let m = |name: &str, value: MetricValue| {
        let mut metric = Metric {
            name: Some(name.into()),
            ..Metric::default()
        };
        value.fill(&mut metric);
        metric
    };
    let velocity = r#"{"mode":"velocity","velocity":100}"#;
    let dcmd = Payload {
        metrics: vec![
            m(
                "Axis 1/State",
                MetricValue::String("operation_enabled".into()),
            ),
            m("Axis 1/Move", MetricValue::String(velocity.into())),
            m("Axis 1/Lease", MetricValue::Boolean(true)),
            m("Axis 2/Lease", MetricValue::Boolean(true)),
            m("Axis 2/Halt", MetricValue::Boolean(true)),
            m("Axis 1/State", MetricValue::String("flying".into())),
            m("Axis 9/Halt", MetricValue::Boolean(true)),
            m(
                "Axis 1/Move",
                MetricValue::String("{\"mode\":\"warp\"}".into()),
            ),
            m("Segment 3/Color 2", MetricValue::String("#0a0b0c".into())),
            m("Segment 3/Effect", MetricValue::String("Flow".into())),
            m("Segment 11/Dimmer", MetricValue::UInt8(1)),
            m("Segment 3/Color 2", MetricValue::String("red".into())),
        ],
        ..Payload::default()
    };
    let commands = command::parse(&dcmd, true);
    assert_eq!(commands.len(), 11, "{commands:#?}");
    assert_eq!(
        commands[0],
        Command::AxisState {
            axis: 1,
            target: crate::gateway::TargetState::OperationEnabled,
            lease_id: None,
        }
    );
    // The promise is folded into the move of its axis; axis 2's, beside
    // a halt that stops, stays a renewal of its own.
    assert!(
        matches!(&commands[1], Command::Move { axis: 1, lease: true, body, .. } if body == velocity),
        "{:?}",
        commands[1]
    );
    assert_eq!(
        commands[2],
        Command::Lease {
            axis: 2,
            keep: true,
            lease_id: None,
        }
    );
    assert_eq!(
        commands[3],
        Command::Halt {
            axis: 2,
            halt: true,
            lease: false,
            lease_id: None,
        }
    );
    assert!(commands[3].is_stop());
    for bad in &commands[4..7] {
        assert!(matches!(bad, Command::Unsupported(_)), "{bad:?}");
    }
    // Segment 3's Color_02 is 0x6231, sub-indexes 1-4 R, G, B, W.
    let color_2 = SegmentUpdate {
        colors: [
            [None; 4],
            [Some(10), Some(11), Some(12), Some(0)],
            [None; 4],
        ],
        ..SegmentUpdate::default()
    };
    assert_eq!(
        commands[7],
        Command::Segment {
            segment: 3,
            update: color_2.clone()
        }
    );
    assert_eq!(
        command::segment_request(3, &color_2),
        "0x6231:1=10 0x6231:2=11 0x6231:3=12 0x6231:4=0"
    );
    let flow = SegmentUpdate {
        effect: Some(0x0300),
        ..SegmentUpdate::default()
    };
    assert_eq!(
        commands[8],
        Command::Segment {
            segment: 3,
            update: flow.clone()
        }
    );
    assert_eq!(command::segment_request(3, &flow), "0x6220:0=768");
    assert!(matches!(commands[9], Command::Unsupported(_)));
    assert!(matches!(commands[10], Command::Unsupported(_)));
}

#[test]
fn a_lease_id_goes_with_every_command_of_its_axis_in_the_dcmd() {
    let m = |name: &str, value: MetricValue| {
        let mut metric = Metric {
            name: Some(name.into()),
            ..Metric::default()
        };
        value.fill(&mut metric);
        metric
    };
    let id = "host-a-lease-0001";
    let dcmd = Payload {
        metrics: vec![
            m(
                "Axis 1/Move",
                MetricValue::String(r#"{"mode":"velocity","velocity":5}"#.into()),
            ),
            m("Axis 1/Lease", MetricValue::Boolean(true)),
            m("Axis 1/Lease Id", MetricValue::String(id.into())),
            m("Axis 1/Halt", MetricValue::Boolean(false)),
            m("Axis 2/Fault Reset", MetricValue::Boolean(true)),
            m("Axis 2/Lease Id", MetricValue::String(id.into())),
        ],
        ..Payload::default()
    };
    let commands = command::parse(&dcmd, true);
    assert_eq!(commands.len(), 4, "{commands:#?}");
    assert!(
        matches!(&commands[0], Command::Move { axis: 1, lease: true, lease_id: Some(given), .. } if given == id),
        "{:?}",
        commands[0]
    );
    assert!(
        matches!(&commands[1], Command::Halt { axis: 1, halt: false, lease: true, lease_id: Some(given) } if given == id),
        "{:?}",
        commands[1]
    );
    assert_eq!(commands[2], Command::FaultReset { axis: 2 });
    // An id no command of its axis presents is said, not dropped silently.
    assert!(
        matches!(&commands[3], Command::Unsupported(what) if what.starts_with("Axis 2/Lease Id")),
        "{:?}",
        commands[3]
    );
}

#[test]
fn device_ids_are_bus_dash_node() {
    assert_eq!(command::device_id("demo", 1), "demo-1");
    assert_eq!(parse_device("demo-1"), Some(("demo", 1)));
    assert_eq!(parse_device("line-a-127"), Some(("line-a", 127)));
    assert_eq!(parse_device("demo-0"), None);
    assert_eq!(parse_device("demo-128"), None);
    assert_eq!(parse_device("-5"), None);
    // Issue 33, point 6: only the canonical decimal form (`demo-01` reached
    // node 1).
    for other in ["demo-01", "demo-+1", "demo-001", "demo- 1", "demo-1 "] {
        assert_eq!(parse_device(other), None, "{other}");
    }
}

#[test]
fn broker_urls_are_mqtt_or_mqtts_with_default_ports() {
    let url: BrokerUrl = "mqtt://127.0.0.1:1884".parse().unwrap();
    assert_eq!(
        (url.host.as_str(), url.port, url.tls),
        ("127.0.0.1", 1884, false)
    );
    let url: BrokerUrl = "mqtts://broker.plant".parse().unwrap();
    assert_eq!(
        (url.host.as_str(), url.port, url.tls),
        ("broker.plant", 8883, true)
    );
    assert_eq!("mqtt://b".parse::<BrokerUrl>().unwrap().port, 1883);
    assert_eq!(
        "mqtt://[::1]:1900".parse::<BrokerUrl>().unwrap().host,
        "::1"
    );
    for bad in ["tcp://b:1", "mqtt://", "mqtt://u:p@b:1", "mqtt://b:x"] {
        assert!(bad.parse::<BrokerUrl>().is_err(), "{bad}");
    }
}

#[test]
fn a_payload_survives_protobuf_both_ways() {
    let mut s = session();
    let birth = s.birth(vec![sample("x", MetricValue::Double(1.25))], 7);
    let bytes = birth.payload.encode_to_vec();
    assert_eq!(Payload::decode(bytes.as_slice()).unwrap(), birth.payload);
}

#[test]
fn a_missing_or_bad_ca_file_is_refused_in_words() {
    let dir = std::env::temp_dir().join(format!("candeck-tls-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let missing = dir.join("missing.pem");
    let files = super::config::TlsFiles {
        ca_file: Some(missing.clone()),
        ..Default::default()
    };
    let err = super::tls::client_config(&files).unwrap_err();
    assert!(
        err.starts_with(&format!("mqtt_ca_file {}: ", missing.display())),
        "{err}"
    );
    let bad = dir.join("bad.pem");
    std::fs::write(&bad, "this is not PEM\n").unwrap();
    let files = super::config::TlsFiles {
        ca_file: Some(bad.clone()),
        ..Default::default()
    };
    let err = super::tls::client_config(&files).unwrap_err();
    assert_eq!(
        err,
        format!("mqtt_ca_file {}: no certificate in it", bad.display())
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A device's alarm metrics: the counts and the highest severity of its
/// alarms, `none` without one; born in its DBIRTH and sent again on each
/// change.
#[test]
fn a_device_s_alarm_metrics_count_its_alarms_and_name_the_highest_severity() {
    use crate::gateway::{AlarmSummary, Severity};
    let value = |samples: &[Sample], name: &str| {
        samples
            .iter()
            .find(|sample| sample.name == name)
            .map(|sample| sample.value.clone())
            .unwrap_or_else(|| panic!("no {name}"))
    };
    let none = super::node::alarm_samples(&AlarmSummary::default(), 5);
    assert_eq!(value(&none, "Alarms/Active"), MetricValue::UInt32(0));
    assert_eq!(
        value(&none, "Alarms/Unacknowledged"),
        MetricValue::UInt32(0)
    );
    assert_eq!(
        value(&none, "Alarms/Highest Severity"),
        MetricValue::String("none".to_string())
    );
    let summary = AlarmSummary {
        active: [1, 2, 0, 0],
        unacknowledged: [1, 0, 0, 3],
        highest: Some(Severity::Critical),
    };
    let some = super::node::alarm_samples(&summary, 5);
    assert_eq!(value(&some, "Alarms/Active"), MetricValue::UInt32(3));
    assert_eq!(
        value(&some, "Alarms/Unacknowledged"),
        MetricValue::UInt32(4)
    );
    assert_eq!(
        value(&some, "Alarms/Highest Severity"),
        MetricValue::String("critical".to_string())
    );
}

/// Issue 33, point 2: the newest STATE timestamp wins. A stale or replayed
/// offline changes nothing, a valid one ends the session, a duplicate
/// online brings no rebirth, and a retained old offline cannot silence the
/// next connection once the host is back.
#[test]
fn the_newest_host_state_wins_and_a_duplicate_online_is_nothing() {
    let state = |online, timestamp| HostState {
        online,
        timestamp: Some(timestamp),
    };
    let mut host = PrimaryHost::default();
    assert!(!host.online());
    assert_eq!(host.on_state(state(true, 1000)), HostVerdict::CameOnline);
    assert!(host.online());
    assert_eq!(host.on_state(state(true, 1000)), HostVerdict::StillOnline);
    assert_eq!(host.on_state(state(true, 1500)), HostVerdict::StillOnline);
    // A replayed offline, or the late will of the host's older session.
    assert_eq!(host.on_state(state(false, 1)), HostVerdict::Stale);
    assert_eq!(host.on_state(state(false, 1499)), HostVerdict::Stale);
    assert!(host.online());
    // Its will carries its online's timestamp: valid.
    assert_eq!(host.on_state(state(false, 1500)), HostVerdict::WentOffline);
    assert!(!host.online());
    // The next connection: the retained offline again, then the host back.
    host.connection_lost();
    assert_eq!(host.on_state(state(false, 1500)), HostVerdict::StillOffline);
    assert_eq!(host.on_state(state(true, 900)), HostVerdict::Stale);
    assert_eq!(host.on_state(state(true, 2000)), HostVerdict::CameOnline);
    // The first STATE ever is taken as it is.
    let mut fresh = PrimaryHost::default();
    assert_eq!(fresh.on_state(state(false, 7)), HostVerdict::StillOffline);
    assert_eq!(fresh.on_state(state(true, 7)), HostVerdict::CameOnline);
}

fn read_only(metric: &Metric) -> Option<bool> {
    let properties = metric.properties.as_ref()?;
    let at = properties.keys.iter().position(|key| key == "readOnly")?;
    match properties.values.get(at)?.value {
        Some(super::proto::payload::property_value::Value::BooleanValue(read_only)) => {
            Some(read_only)
        }
        _ => None,
    }
}

/// Issue 33, points 3 and 7: every born metric says whether a host may
/// write it (Ignition's tag property `readOnly`), `Node Control/Rebirth`
/// (writable) is born without an alias, and the data messages carry no
/// datatype.
#[test]
fn births_say_what_is_writable_and_rebirth_has_no_alias() {
    let mut s = session();
    let nbirth = s.birth(vec![sample("n", MetricValue::UInt8(0))], 0);
    let rebirth = nbirth
        .payload
        .metrics
        .iter()
        .find(|m| m.name.as_deref() == Some(REBIRTH))
        .unwrap();
    assert_eq!(rebirth.alias, None);
    assert_eq!(rebirth.datatype, Some(DataType::Boolean as u32));
    assert_eq!(read_only(rebirth), Some(false));
    for metric in &nbirth.payload.metrics {
        assert!(read_only(metric).is_some(), "{metric:?}");
    }
    let dbirth = s.device_birth(
        "demo-1",
        vec![
            sample("Axis 1/Position", MetricValue::Int32(0)),
            sample("Axis 1/Move", MetricValue::Null(DataType::String)).writable(),
        ],
        0,
    );
    let flags: Vec<_> = dbirth.payload.metrics.iter().map(read_only).collect();
    assert_eq!(flags, [Some(true), Some(false)]);
    assert!(
        dbirth
            .payload
            .metrics
            .iter()
            .all(|m| m.datatype.is_some() && m.alias.is_some())
    );
    let data = s
        .data(
            Some("demo-1"),
            vec![sample("Axis 1/Position", MetricValue::Int32(5))],
            0,
            false,
        )
        .unwrap();
    assert_eq!(
        data_value(&data.payload.metrics[0], DataType::Int32),
        Some(MetricValue::Int32(5))
    );
}

/// Issue 33, point 3: a DCMD in the spec's form (the alias alone, no
/// datatype) is the command its birth named.
#[test]
fn an_alias_only_command_without_datatype_is_named_and_typed_by_its_birth() {
    let mut s = session();
    let dbirth = s.device_birth(
        "demo-1",
        vec![
            sample("Axis 1/Move", MetricValue::Null(DataType::String)).writable(),
            sample("Axis 1/Lease", MetricValue::Null(DataType::Boolean)).writable(),
            sample("OD/0x1017:0", MetricValue::Null(DataType::UInt16)).writable(),
        ],
        0,
    );
    let alias = |name: &str| {
        dbirth
            .payload
            .metrics
            .iter()
            .find(|m| m.name.as_deref() == Some(name))
            .unwrap()
            .alias
    };
    let bare = |alias: Option<u64>, value: metric::Value| Metric {
        alias,
        value: Some(value),
        ..Metric::default()
    };
    let mut payload = Payload {
        metrics: vec![
            bare(
                alias("Axis 1/Move"),
                metric::Value::StringValue(r#"{"mode":"velocity","velocity":100}"#.into()),
            ),
            bare(alias("Axis 1/Lease"), metric::Value::BooleanValue(true)),
            bare(alias("OD/0x1017:0"), metric::Value::IntValue(1000)),
            bare(Some(9999), metric::Value::BooleanValue(true)),
        ],
        ..Payload::default()
    };
    for metric in &mut payload.metrics {
        s.complete_command(Some("demo-1"), metric);
    }
    let commands = command::parse(&payload, true);
    assert!(
        matches!(
            &commands[0],
            Command::Move {
                axis: 1,
                lease: true,
                ..
            }
        ),
        "{commands:?}"
    );
    assert_eq!(
        commands[1],
        Command::Write {
            index: 0x1017,
            sub: 0,
            value: MetricValue::UInt16(1000)
        }
    );
    // An alias no birth gave is refused, not guessed.
    assert!(
        matches!(&commands[2], Command::Unsupported(_)),
        "{commands:?}"
    );
}

/// Issue 33, point 7: `bdSeq` goes up by one per CONNECT the broker
/// accepted, not per attempt (it jumped 0 to 7 across refused ones).
#[test]
fn bdseq_goes_up_once_per_accepted_connect() {
    let mut s = EdgeSession::new("plant", "line1", u8::MAX, Policy::default());
    assert_eq!(s.connect_attempt(), 0);
    // Refused, or lost before the CONNACK: the same number again.
    assert_eq!(s.connect_attempt(), 0);
    assert_eq!(s.connect_attempt(), 0);
    s.connection_accepted();
    assert_eq!(s.bd_seq(), 0);
    assert_eq!(s.connect_attempt(), 1);
    s.connection_accepted();
    assert_eq!(s.connect_attempt(), 2);
}

/// Issue 33, point 6: rebirth requests are coalesced: one run at once,
/// those within the interval one more run when it is up.
#[test]
fn rebirth_requests_within_the_interval_are_one_more_run() {
    let mut gate = RebirthGate::new(1000);
    assert!(gate.request(0));
    gate.born(0);
    assert_eq!(gate.due(), None);
    for at in 1..2000 {
        assert!(!gate.request(at % 1000));
    }
    assert_eq!(gate.due(), Some(1000));
    gate.born(1000);
    assert_eq!(gate.due(), None);
    assert!(gate.request(2000));
}

/// Issue 33, point 5: after a restart the spooled history of a device goes
/// only once its DBIRTH is out; the rest stays queued, in order, also in
/// the file.
#[test]
fn history_waits_for_the_birth_of_its_device() {
    let mut s = session();
    for device in ["demo-1", "demo-2"] {
        s.device_birth(device, vec![sample("v", MetricValue::UInt32(0))], 0);
    }
    let data = |s: &mut EdgeSession, device: &str, v: u32| {
        s.data(
            Some(device),
            vec![sample("v", MetricValue::UInt32(v))],
            0,
            true,
        )
        .unwrap()
    };
    let file = std::env::temp_dir().join(format!("candeck-spool-births-{}", std::process::id()));
    let _ = std::fs::remove_file(&file);
    let mut spool = Spool::with_file(10, file.clone()).unwrap();
    spool.push(data(&mut s, "demo-1", 1));
    spool.push(data(&mut s, "demo-2", 2));
    spool.push(data(&mut s, "demo-1", 3));
    let first = spool.drain_where(|topic| topic.device.as_deref() == Some("demo-1"));
    let values: Vec<_> = first
        .iter()
        .map(|m| data_value(&m.payload.metrics[0], DataType::UInt32).unwrap())
        .collect();
    assert_eq!(values, [1, 3].map(MetricValue::UInt32).to_vec());
    assert!(
        first
            .iter()
            .all(|m| m.payload.metrics[0].is_historical == Some(true))
    );
    assert_eq!(spool.len(), 1);
    // What waits is in the file too (a restart meanwhile keeps it).
    let again = Spool::with_file(10, file.clone()).unwrap();
    assert_eq!(again.len(), 1);
    drop(again);
    let rest = Spool::with_file(10, file.clone()).unwrap().drain();
    assert_eq!(rest[0].topic.device.as_deref(), Some("demo-2"));
    let _ = std::fs::remove_file(&file);
}

/// The demo's virtual bus, its three nodes found by a scan: the fixture of
/// the edge node's and the motion commands' tests.
pub(crate) async fn demo_bus() -> crate::gateway::ServedBus {
    let served = crate::emulator::open_bus(
        "demo",
        &"virtual:demo".parse().unwrap(),
        std::sync::Arc::new(crate::gateway::EdsCatalog::builtin().unwrap()),
        crate::gateway::RegistryConfig::default(),
        500_000,
    )
    .await
    .unwrap();
    assert_eq!(served.scan().await.unwrap().len(), 3);
    served
}
