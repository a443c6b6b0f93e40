//! The segments' and channels' variables: the tree (what exists, typed,
//! with which access level), the values as updates, and reads and writes
//! through the gateway on a virtual UIO1LED and io401: a viewer refused and
//! audited as REST's, an operator's write reaching the device.

use opcua::server::address_space::NodeType;
use opcua::types::{NodeId, StatusCode};

use super::*;
use crate::gateway::{Channel as Door, DoorDetail, EdsCatalog, Role};
use crate::opcua::browse::{self, NAMESPACE};
use crate::opcua::tree::{build_fixed, build_node};

const NS: u16 = 2;

fn node(id: u8) -> NodePath {
    NodePath {
        bus: "bench".into(),
        node: id,
    }
}

fn found<'a>(space: &'a AddressSpace, path: &str) -> &'a opcua::server::address_space::Variable {
    match space.find(&id(NS, path)) {
        Some(NodeType::Variable(variable)) => variable,
        other => panic!("{path}: {other:?}"),
    }
}

#[test]
fn segments_and_channels_are_typed_variables_outputs_and_fields_writable() {
    let mut space = AddressSpace::new();
    space.add_namespace(NAMESPACE, NS);
    build_fixed(&mut space, NS, &["bench".to_string()]);
    let catalog = EdsCatalog::builtin().unwrap();
    let io401 = catalog.find("io401.eds").unwrap();
    let (leds, module, drive) = (node(3), node(4), node(1));
    for (path, profile, dictionary) in [
        (&leds, Profile::Uioled, None),
        (&module, Profile::Cia401, Some(&io401.eds.dictionary)),
        (&drive, Profile::Umc, None),
    ] {
        // Twice, as the feed builds a node it sees again: nothing twice.
        for _ in 0..2 {
            build_node(&mut space, NS, path, dictionary);
            build(&mut space, NS, path, profile, dictionary);
        }
    }

    for segment in [1, SEGMENTS] {
        for field in LedField::ALL {
            let path = segment_path(&leds, segment, field);
            let variable = found(&space, &path);
            assert!(variable.is_readable() && variable.is_writable(), "{path}");
            assert_eq!(
                variable.data_type(),
                NodeId::from(field.data_type()),
                "{path}"
            );
            assert_eq!(
                IoVariable::parse(&path),
                Some(IoVariable::Segment {
                    node: leds.clone(),
                    segment,
                    field
                })
            );
        }
    }
    assert_eq!(
        segment_path(&leds, 2, LedField::Color(3)),
        "candeck/Nodes/bench/3/Leds/2/Color3"
    );
    assert!(
        space
            .find(&id(NS, format!("{}/Leds/11", leds.id())))
            .is_none()
    );

    // The io401's EDS: 16 digital inputs and outputs, 4 analogue inputs, 2
    // analogue outputs; inputs read-only.
    for (name, writable, data_type) in [
        ("di1", false, DataTypeId::Boolean),
        ("di16", false, DataTypeId::Boolean),
        ("do1", true, DataTypeId::Boolean),
        ("do16", true, DataTypeId::Boolean),
        ("ai4", false, DataTypeId::Int16),
        ("ao2", true, DataTypeId::Int16),
    ] {
        let channel = Channel::parse(name).unwrap();
        let path = channel_path(&module, channel);
        assert_eq!(path, format!("candeck/Nodes/bench/4/Io/{name}"));
        let variable = found(&space, &path);
        assert!(variable.is_readable(), "{path}");
        assert_eq!(variable.is_writable(), writable, "{path}");
        assert_eq!(variable.data_type(), NodeId::from(data_type), "{path}");
        assert_eq!(
            IoVariable::parse(&path),
            Some(IoVariable::Channel {
                node: module.clone(),
                channel
            })
        );
    }
    for beyond in ["di17", "ai5", "ao3"] {
        assert!(
            space
                .find(&id(NS, format!("{}/Io/{beyond}", module.id())))
                .is_none(),
            "{beyond}"
        );
    }
    // A drive has neither; LED and I/O ids are no method targets.
    assert!(space.find(&id(NS, drive.child("Leds"))).is_none());
    assert!(space.find(&id(NS, drive.child("Io"))).is_none());
    assert_eq!(
        browse::Target::parse(&segment_path(&leds, 1, LedField::Effect)),
        None
    );
    assert_eq!(IoVariable::parse("candeck/Nodes/bench/4/Io/DO1"), None);
    assert_eq!(
        IoVariable::parse("candeck/Nodes/bench/3/Leds/0/Effect"),
        None
    );
    assert_eq!(
        IoVariable::parse("candeck/Nodes/bench/3/Leds/1/Colour"),
        None
    );
}

#[test]
fn written_values_become_the_segment_updates_rest_would_send() {
    let effect = LedField::Effect
        .update(&Variant::String("Breathing".into()))
        .unwrap();
    assert_eq!(effect.effect, Some(0x0102));
    let raw = LedField::Effect
        .update(&Variant::String("0x0300".into()))
        .unwrap();
    assert_eq!(raw.effect, Some(0x0300));
    let unknown = LedField::Effect
        .update(&Variant::String("sparkle".into()))
        .unwrap_err();
    assert_eq!(status_of(&unknown), StatusCode::BadOutOfRange, "{unknown}");

    let color = LedField::Color(2)
        .update(&Variant::String("#ff800040".into()))
        .unwrap();
    assert_eq!(
        color.colors[1],
        [Some(0xff), Some(0x80), Some(0), Some(0x40)]
    );
    assert_eq!(color.colors[0], [None; 4]);
    let rgb = LedField::Color(1)
        .update(&Variant::String("#00ff00".into()))
        .unwrap();
    assert_eq!(rgb.colors[0], [Some(0), Some(0xff), Some(0), Some(0)]);
    let bad = LedField::Color(1)
        .update(&Variant::String("green".into()))
        .unwrap_err();
    assert_eq!(status_of(&bad), StatusCode::BadTypeMismatch, "{bad}");

    let speed = LedField::Speed.update(&Variant::Int16(-3)).unwrap();
    assert_eq!(speed.speed, Some(-3));
    let wrong = LedField::Dimmer.update(&Variant::Double(0.5)).unwrap_err();
    assert_eq!(status_of(&wrong), StatusCode::BadTypeMismatch, "{wrong}");
}

fn caller(role: Role, path: &str) -> Caller {
    Caller::new(Door::Opcua, role.to_string(), Some(role))
        .with_detail(DoorDetail::new("Write", path))
}

/// A virtual UIO1LED (3) and CiA 401 module (4), scanned, under a gateway
/// of their own (no door's test support: doors do not lean on each other).
async fn bench() -> Gateway {
    let served = crate::emulator::open_bus(
        "bench",
        &"virtual:uio1led@3,io401@4".parse().unwrap(),
        std::sync::Arc::new(EdsCatalog::builtin().unwrap()),
        crate::gateway::RegistryConfig::default(),
        500_000,
    )
    .await
    .unwrap();
    assert_eq!(served.scan().await.unwrap().len(), 2);
    Gateway::new([served])
}

#[tokio::test(start_paused = true)]
async fn a_viewers_writes_are_refused_and_audited_an_operators_reach_the_devices() {
    let gateway = bench().await;
    let effect = IoVariable::parse(&segment_path(&node(3), 2, LedField::Effect)).unwrap();
    let output = IoVariable::parse("candeck/Nodes/bench/4/Io/do3").unwrap();
    let breathing = Variant::String("breathing".into());

    let viewer = caller(Role::Viewer, &effect.path());
    let refused = write(&gateway, &viewer, &effect, &breathing)
        .await
        .unwrap_err();
    assert_eq!(
        status_of(&refused),
        StatusCode::BadUserAccessDenied,
        "{refused}"
    );
    let refused = write(&gateway, &viewer, &output, &Variant::Boolean(true))
        .await
        .unwrap_err();
    assert_eq!(
        status_of(&refused),
        StatusCode::BadUserAccessDenied,
        "{refused}"
    );
    let rows = crate::door_audit::rows(&gateway).await;
    let words: Vec<_> = rows
        .iter()
        .map(|row| {
            (
                row["channel"].as_str().unwrap(),
                row["who"].as_str().unwrap(),
                row["operation"].as_str().unwrap(),
                row["outcome"].as_str().unwrap(),
                row.get("item").and_then(serde_json::Value::as_str),
            )
        })
        .collect();
    assert_eq!(
        words,
        [
            (
                "opcua",
                "viewer",
                "set segment",
                "forbidden",
                Some("segment 2")
            ),
            ("opcua", "viewer", "set outputs", "forbidden", None),
        ],
        "{rows:?}"
    );

    // Nothing was written.
    let mut reads = Reads::default();
    let operator = caller(Role::Operator, &effect.path());
    assert_eq!(
        reads.value(&gateway, &operator, &output).await.unwrap(),
        Variant::Boolean(false)
    );

    write(&gateway, &operator, &effect, &breathing)
        .await
        .unwrap();
    let color = IoVariable::parse(&segment_path(&node(3), 2, LedField::Color(1))).unwrap();
    write(
        &gateway,
        &operator,
        &color,
        &Variant::String("#102030".into()),
    )
    .await
    .unwrap();
    write(&gateway, &operator, &output, &Variant::Boolean(true))
        .await
        .unwrap();
    let analog = IoVariable::parse("candeck/Nodes/bench/4/Io/ao1").unwrap();
    write(&gateway, &operator, &analog, &Variant::Int16(-1234))
        .await
        .unwrap();

    // Read back over SDO, as REST reads them.
    let mut reads = Reads::default();
    assert_eq!(
        reads.value(&gateway, &operator, &effect).await.unwrap(),
        breathing
    );
    assert_eq!(
        reads.value(&gateway, &operator, &color).await.unwrap(),
        Variant::String("#10203000".into())
    );
    let io = gateway.read_io("bench", "4").await.unwrap();
    let held = |name: &str| {
        io.digital_outputs
            .iter()
            .chain(&io.analog_outputs)
            .find(|channel| channel.channel == name)
            .unwrap()
            .value
            .clone()
    };
    assert_eq!(held("do3"), Json::Bool(true));
    assert_eq!(held("do2"), Json::Bool(false));
    assert_eq!(held("ao1"), Json::from(-1234));
    assert_eq!(
        reads.value(&gateway, &operator, &output).await.unwrap(),
        Variant::Boolean(true)
    );
    let rows = crate::door_audit::rows(&gateway).await;
    let done: Vec<_> = rows[2..]
        .iter()
        .map(|row| {
            (
                row["operation"].as_str().unwrap(),
                row["outcome"].as_str().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        done,
        [
            ("set segment", "ok"),
            ("set segment", "ok"),
            ("set outputs", "ok"),
            ("set outputs", "ok")
        ]
    );

    // Values the objects cannot hold, and the wrong type: refused before
    // anything is sent, as the statuses a client branches on.
    let dimmer = IoVariable::parse(&segment_path(&node(3), 1, LedField::LedCount)).unwrap();
    let error = write(&gateway, &operator, &dimmer, &Variant::Int32(70_000))
        .await
        .unwrap_err();
    assert_eq!(status_of(&error), StatusCode::BadOutOfRange, "{error}");
    let error = write(&gateway, &operator, &output, &Variant::Int16(1))
        .await
        .unwrap_err();
    assert_eq!(status_of(&error), StatusCode::BadTypeMismatch, "{error}");
    let error = write(&gateway, &operator, &analog, &Variant::Empty)
        .await
        .unwrap_err();
    assert_eq!(status_of(&error), StatusCode::BadTypeMismatch, "{error}");
}

#[tokio::test(start_paused = true)]
async fn a_read_of_a_node_without_segments_or_channels_says_so() {
    let gateway = bench().await;
    let viewer = caller(Role::Viewer, "read");
    let mut reads = Reads::default();
    // The LED controller has no channels, the module no segments.
    let not_io = IoVariable::parse("candeck/Nodes/bench/3/Io/di1").unwrap();
    let value = reads.read(&gateway, &viewer, &not_io).await;
    assert_eq!(value.status, Some(StatusCode::BadNotSupported));
    let not_leds = IoVariable::parse(&segment_path(&node(4), 1, LedField::Value)).unwrap();
    let value = reads.read(&gateway, &viewer, &not_leds).await;
    assert_eq!(value.status, Some(StatusCode::BadNotSupported));
    // A viewer reads.
    let input = IoVariable::parse("candeck/Nodes/bench/4/Io/di1").unwrap();
    let value = reads.read(&gateway, &viewer, &input).await;
    assert!(
        matches!(value.value, Some(Variant::Boolean(_))),
        "{value:?}"
    );
}
