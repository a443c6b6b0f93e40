//! The machine's events as OPC UA events (IEC 62541-3 §4.6, -5 §6.4.2):
//! NMT changes and EMCYs from the registries of the buses, and every step
//! of an alarm's life from the gateway's alarm book, each on the object of
//! its node (or bus), on `Machine` and on the standard `Server` object,
//! where a client subscribes to events (EventNotifier set).
//!
//! async-opcua 0.19 has the types of Alarms & Conditions but no condition
//! instances (no ConditionRefresh, no branches, no Acknowledge on the
//! condition): an alarm is an `AlarmEventType` event carrying the alarm's
//! id, state, step and severity, and `Machine/Acknowledge(AlarmId,
//! Comment)` is the gateway's alarm acknowledge operation (docs/opcua.md,
//! "Events").
//!
//! The events are built sans I/O ([`nmt_event`], [`emcy_event`],
//! [`alarm_event`]); [`run`] follows the gateway and hands them to the
//! server's subscriptions.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use opcua::nodes::{BaseEventType, Event};
use opcua::server::SubscriptionCache;
use opcua::server::address_space::{AccessLevel, AddressSpace, ObjectTypeBuilder, VariableBuilder};
use opcua::types::{
    ByteString, DataTypeId, DateTime, LocalizedText, NodeId, ObjectId, ObjectTypeId, QualifiedName,
    UAString, VariableTypeId, Variant,
};

use super::browse::{self, NodePath, ROOT};
use crate::gateway::{Alarm, AlarmChange, EmcyRecord, Gateway, NodeEvent};
use crate::profiles::alarm::Severity;

/// The event of an NMT state change of a node.
#[derive(Debug, opcua::Event)]
#[opcua(identifier = "s=NmtChangeEventType", namespace = "urn:candeck")]
pub struct NmtChangeEvent {
    pub base: BaseEventType,
    pub own_namespace_index: u16,
    pub bus: UAString,
    pub node: u8,
    /// The state before (`unknown` when the gateway knew none).
    pub previous_state: UAString,
    pub nmt_state: UAString,
}

/// The event of an EMCY a node sent.
#[derive(Debug, opcua::Event)]
#[opcua(identifier = "s=EmcyEventType", namespace = "urn:candeck")]
pub struct EmcyEvent {
    pub base: BaseEventType,
    pub own_namespace_index: u16,
    pub bus: UAString,
    pub node: u8,
    /// The axis (1-based) the profile assigns it to; 0: the whole node.
    pub axis: u8,
    pub error_code: u16,
    pub error_register: u8,
}

/// The event of one step of an alarm's life (raised, returned, cleared,
/// acknowledged, restored).
#[derive(Debug, opcua::Event)]
#[opcua(identifier = "s=AlarmEventType", namespace = "urn:candeck")]
pub struct AlarmEvent {
    pub base: BaseEventType,
    pub own_namespace_index: u16,
    /// The gateway's id of the alarm, as REST's `/alarms/{id}` and
    /// `Acknowledge` take it.
    pub alarm_id: UAString,
    /// `active_unacknowledged`, `active_acknowledged`,
    /// `cleared_unacknowledged` or `normal`.
    pub alarm_state: UAString,
    /// `raised`, `returned`, `cleared`, `acknowledged` or `restored`.
    pub alarm_step: UAString,
    /// `critical`, `high`, `medium` or `low` (Severity is its number).
    pub alarm_severity: UAString,
    pub kind: UAString,
    pub bus: UAString,
    /// 0: the bus itself.
    pub node: u8,
    /// 0: the whole node.
    pub axis: u8,
    pub acknowledged_by: UAString,
    pub comment: UAString,
}

/// The event types with their fields (each a property of the type, as a
/// client's event filter selects them).
pub const EVENT_TYPES: [(&str, &[(&str, DataTypeId)]); 3] = [
    (
        "NmtChangeEventType",
        &[
            ("Bus", DataTypeId::String),
            ("Node", DataTypeId::Byte),
            ("PreviousState", DataTypeId::String),
            ("NmtState", DataTypeId::String),
        ],
    ),
    (
        "EmcyEventType",
        &[
            ("Bus", DataTypeId::String),
            ("Node", DataTypeId::Byte),
            ("Axis", DataTypeId::Byte),
            ("ErrorCode", DataTypeId::UInt16),
            ("ErrorRegister", DataTypeId::Byte),
        ],
    ),
    (
        "AlarmEventType",
        &[
            ("AlarmId", DataTypeId::String),
            ("AlarmState", DataTypeId::String),
            ("AlarmStep", DataTypeId::String),
            ("AlarmSeverity", DataTypeId::String),
            ("Kind", DataTypeId::String),
            ("Bus", DataTypeId::String),
            ("Node", DataTypeId::Byte),
            ("Axis", DataTypeId::Byte),
            ("AcknowledgedBy", DataTypeId::String),
            ("Comment", DataTypeId::String),
        ],
    ),
];

/// The event types, subtypes of `BaseEventType` (the server's type tree
/// learns them from the address space when it starts).
pub fn build_types(space: &mut AddressSpace, ns: u16) {
    for (name, fields) in EVENT_TYPES {
        let type_id = NodeId::new(ns, name);
        if space.node_exists(&type_id) {
            continue;
        }
        ObjectTypeBuilder::new(&type_id, QualifiedName::new(ns, name), name)
            .is_abstract(false)
            .subtype_of(ObjectTypeId::BaseEventType)
            .insert(space);
        for (field, data_type) in fields {
            VariableBuilder::new(
                &NodeId::new(ns, format!("{name}/{field}")),
                QualifiedName::new(ns, *field),
                *field,
            )
            .data_type(*data_type)
            .value(Variant::Empty)
            .access_level(AccessLevel::CURRENT_READ)
            .user_access_level(AccessLevel::CURRENT_READ)
            .has_type_definition(VariableTypeId::PropertyType)
            .has_modelling_rule(ObjectId::ModellingRule_Mandatory)
            .property_of(type_id.clone())
            .insert(space);
        }
    }
}

/// Makes the event types' fields selectable as `BaseEventType`'s too.
/// Many clients (asyncua among them) select every field with
/// `TypeDefinitionId` = `BaseEventType` and the field's browse path, and
/// async-opcua validates a select clause against the properties of the type
/// it names: without this, `AlarmId` & co. would be refused as unknown.
/// The events answer such a clause by the field's name.
pub fn register_fields(types: &mut opcua::nodes::DefaultTypeTree, ns: u16) {
    let base: NodeId = ObjectTypeId::BaseEventType.into();
    for (name, fields) in EVENT_TYPES {
        for (field, _) in fields {
            let property = NodeId::new(ns, format!("{name}/{field}"));
            let path = QualifiedName::new(ns, *field);
            types.add_type_property(
                &property,
                &base,
                &[&path],
                opcua::types::NodeClass::Variable,
            );
        }
    }
}

/// A unique event id: the server's start and a counter.
fn event_id() -> ByteString {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    static START: std::sync::OnceLock<i64> = std::sync::OnceLock::new();
    let start = *START.get_or_init(|| DateTime::now().ticks());
    let mut bytes = start.to_be_bytes().to_vec();
    bytes.extend(NEXT.fetch_add(1, Ordering::Relaxed).to_be_bytes());
    ByteString::from(bytes)
}

/// A wall-clock time in µs since the Unix epoch as OPC UA's (100 ns ticks
/// since 1601).
fn date_time(unix_us: i64) -> DateTime {
    const EPOCH_1601_TO_1970_US: i64 = 11_644_473_600_000_000;
    DateTime::from(
        unix_us
            .saturating_add(EPOCH_1601_TO_1970_US)
            .saturating_mul(10),
    )
}

fn base(
    type_name: &str,
    ns: u16,
    source: (NodeId, String),
    time: DateTime,
    message: String,
    severity: u16,
) -> BaseEventType {
    BaseEventType {
        event_id: event_id(),
        event_type: NodeId::new(ns, type_name),
        source_node: source.0,
        source_name: source.1.into(),
        time,
        receive_time: DateTime::now(),
        message: LocalizedText::new("", &message),
        severity,
        ..Default::default()
    }
}

/// A node's object and its name (`demo/3`), the event's source.
fn node_source(ns: u16, node: &NodePath) -> (NodeId, String) {
    (
        NodeId::new(ns, node.id()),
        format!("{}/{}", node.bus, node.node),
    )
}

/// An NMT change as its event: severity 500 for a node that left
/// operational for stopped, 200 otherwise.
pub fn nmt_event(
    ns: u16,
    node: &NodePath,
    from: Option<crate::canopen::nmt::NmtState>,
    to: crate::canopen::nmt::NmtState,
) -> NmtChangeEvent {
    use crate::canopen::nmt::NmtState;
    let previous = from.map_or("unknown", NmtState::name);
    let severity = if to == NmtState::Stopped { 500 } else { 200 };
    NmtChangeEvent {
        base: base(
            "NmtChangeEventType",
            ns,
            node_source(ns, node),
            DateTime::now(),
            format!(
                "{}/{}: NMT {previous} -> {}",
                node.bus,
                node.node,
                to.name()
            ),
            severity,
        ),
        own_namespace_index: ns,
        bus: node.bus.as_str().into(),
        node: node.node,
        previous_state: previous.into(),
        nmt_state: to.name().into(),
    }
}

/// An EMCY as its event, at the time its frame came: severity 700, and
/// 100 for the "error reset or no error" code 0x0000.
pub fn emcy_event(ns: u16, node: &NodePath, emcy: &EmcyRecord) -> EmcyEvent {
    let severity = if emcy.code == 0 { 100 } else { 700 };
    let axis = emcy
        .axis
        .map(|axis| format!(" axis {axis}"))
        .unwrap_or_default();
    let (source, name) = node_source(ns, node);
    let source = match emcy.axis {
        Some(axis) => (NodeId::new(ns, node.axis(axis)), format!("{name}{axis}")),
        None => (source, name),
    };
    EmcyEvent {
        base: base(
            "EmcyEventType",
            ns,
            source,
            date_time(emcy.timestamp.as_micros() as i64),
            format!(
                "{}/{}{axis}: EMCY 0x{:04X} {}",
                node.bus, node.node, emcy.code, emcy.text
            ),
            severity,
        ),
        own_namespace_index: ns,
        bus: node.bus.as_str().into(),
        node: node.node,
        axis: emcy.axis.unwrap_or(0),
        error_code: emcy.code,
        error_register: emcy.register,
    }
}

/// An alarm's severity as OPC UA's 1–1000 (Part 9's bands: low 1–200 …
/// high 801–1000).
pub fn severity_number(severity: Severity) -> u16 {
    match severity {
        Severity::Critical => 900,
        Severity::High => 700,
        Severity::Medium => 500,
        Severity::Low => 300,
    }
}

/// The object an alarm is about: its axis, its node, or its bus.
fn alarm_source(ns: u16, alarm: &Alarm) -> (NodeId, String) {
    match alarm.node {
        Some(id) => {
            let node = NodePath {
                bus: alarm.bus.clone(),
                node: id,
            };
            match alarm.axis {
                Some(axis) => (
                    NodeId::new(ns, node.axis(axis)),
                    format!("{}/{id}/{axis}", alarm.bus),
                ),
                None => node_source(ns, &node),
            }
        }
        None => (
            NodeId::new(ns, browse::bus_id(&alarm.bus)),
            alarm.bus.clone(),
        ),
    }
}

/// One step of an alarm as its event, at the time of the step.
pub fn alarm_event(ns: u16, change: &AlarmChange) -> AlarmEvent {
    let alarm = &change.alarm;
    let step = change.step.name();
    let time = alarm
        .history
        .last()
        .map_or_else(DateTime::now, |event| date_time(event.time_us));
    AlarmEvent {
        base: base(
            "AlarmEventType",
            ns,
            alarm_source(ns, alarm),
            time,
            format!("alarm {} {step}: {}", alarm.id, alarm.reason()),
            severity_number(alarm.severity),
        ),
        own_namespace_index: ns,
        alarm_id: alarm.id.to_string().into(),
        alarm_state: alarm.state.name().into(),
        alarm_step: step.into(),
        alarm_severity: alarm.severity.name().into(),
        kind: alarm.kind.name().into(),
        bus: alarm.bus.as_str().into(),
        node: alarm.node.unwrap_or(0),
        axis: alarm.axis.unwrap_or(0),
        acknowledged_by: alarm.acknowledged_by.clone().unwrap_or_default().into(),
        comment: alarm.comment.clone().unwrap_or_default().into(),
    }
}

/// Where events go: the server's subscriptions.
#[derive(Clone)]
pub struct EventSink {
    ns: u16,
    subscriptions: Arc<SubscriptionCache>,
}

impl EventSink {
    pub fn new(ns: u16, subscriptions: Arc<SubscriptionCache>) -> Self {
        Self { ns, subscriptions }
    }

    /// The objects an event of `source` is notified on: its own (a node's,
    /// a bus's), `Machine` and the standard `Server` object.
    fn notifiers(&self, source: Option<NodeId>) -> Vec<NodeId> {
        let mut notifiers = vec![
            NodeId::new(self.ns, format!("{ROOT}/Machine")),
            NodeId::from(ObjectId::Server),
        ];
        notifiers.extend(source);
        notifiers
    }

    fn publish(&self, event: &dyn Event, source: Option<NodeId>) {
        let notifiers = self.notifiers(source);
        self.subscriptions
            .notify_events(notifiers.iter().map(|id| (event, id)));
    }
}

/// A registry event as its OPC UA event, where it is one (NMT changes and
/// EMCYs).
fn node_event(ns: u16, bus: &str, event: &NodeEvent) -> Option<(Box<dyn Event>, NodePath)> {
    let node = NodePath {
        bus: bus.to_string(),
        node: event.node().get(),
    };
    let event: Box<dyn Event> = match event {
        NodeEvent::NmtChanged { from, to, .. } => Box::new(nmt_event(ns, &node, *from, *to)),
        NodeEvent::Emcy { emcy, .. } => Box::new(emcy_event(ns, &node, emcy)),
        _ => return None,
    };
    Some((event, node))
}

/// Follows the buses' registries and the alarm book until aborted (the
/// followers are this task's: they end with it).
pub async fn run(gateway: Gateway, sink: EventSink) {
    use tokio::sync::broadcast::error::RecvError;
    let mut followers = tokio::task::JoinSet::new();
    for bus in gateway.buses() {
        let mut events = bus.node_events();
        let name = bus.name().to_string();
        let sink = sink.clone();
        followers.spawn(async move {
            loop {
                match events.recv().await {
                    Ok(event) => {
                        if let Some((event, node)) = node_event(sink.ns, &name, &event) {
                            let source = NodeId::new(sink.ns, node.id());
                            sink.publish(event.as_ref(), Some(source));
                        }
                    }
                    Err(RecvError::Lagged(lost)) => {
                        tracing::warn!("opcua: events of bus {name}: {lost} lost (too many)");
                    }
                    Err(RecvError::Closed) => return,
                }
            }
        });
    }
    let mut changes = gateway.alarm_book().subscribe();
    let alarms = async {
        loop {
            match changes.recv().await {
                Ok(change) => {
                    let event = alarm_event(sink.ns, &change);
                    let source = event.base.source_node.clone();
                    sink.publish(&event, Some(source));
                }
                Err(RecvError::Lagged(lost)) => {
                    tracing::warn!("opcua: alarm events: {lost} lost (too many)");
                }
                Err(RecvError::Closed) => return,
            }
        }
    };
    alarms.await;
    while followers.join_next().await.is_some() {}
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::nmt::NmtState;
    use opcua::types::{AttributeId, NumericRange};

    const NS: u16 = 2;

    fn node() -> NodePath {
        NodePath {
            bus: "demo".into(),
            node: 3,
        }
    }

    /// A field as a client's select clause asks it: by the type that
    /// declares it and its browse name.
    fn field(event: &dyn Event, declared_by: NodeId, name: QualifiedName) -> Variant {
        event.get_field(
            &declared_by,
            AttributeId::Value,
            &NumericRange::None,
            &[name],
        )
    }

    fn own(event: &dyn Event, type_name: &str, name: &str) -> Variant {
        field(
            event,
            NodeId::new(NS, type_name),
            QualifiedName::new(NS, name),
        )
    }

    fn base_field(event: &dyn Event, name: &str) -> Variant {
        field(
            event,
            ObjectTypeId::BaseEventType.into(),
            QualifiedName::new(0, name),
        )
    }

    #[test]
    fn an_nmt_change_is_an_event_of_its_node_with_both_states() {
        let event = nmt_event(NS, &node(), Some(NmtState::Operational), NmtState::Stopped);
        assert_eq!(
            event.event_type_id(),
            &NodeId::new(NS, "NmtChangeEventType")
        );
        assert_eq!(
            base_field(&event, "SourceNode"),
            Variant::from(NodeId::new(NS, "candeck/Nodes/demo/3"))
        );
        assert_eq!(base_field(&event, "Severity"), Variant::UInt16(500));
        let Variant::LocalizedText(message) = base_field(&event, "Message") else {
            panic!("no message");
        };
        assert!(
            message.text.as_ref().contains("operational -> stopped"),
            "{message:?}"
        );
        assert_eq!(
            own(&event, "NmtChangeEventType", "PreviousState"),
            Variant::from("operational")
        );
        assert_eq!(
            own(&event, "NmtChangeEventType", "NmtState"),
            Variant::from("stopped")
        );
        assert_eq!(own(&event, "NmtChangeEventType", "Node"), Variant::Byte(3));
        // Another type's field is not this event's.
        assert_eq!(own(&event, "EmcyEventType", "ErrorCode"), Variant::Empty);
    }

    #[test]
    fn an_emcy_is_an_event_of_its_axis_at_the_time_of_its_frame() {
        let emcy = EmcyRecord {
            code: 0x4310,
            text: "Excess temperature drive".into(),
            register: 0x09,
            manufacturer: [0; 5],
            timestamp: crate::can::Timestamp::from_micros(1_700_000_000_000_000),
            axis: Some(1),
        };
        let event = emcy_event(NS, &node(), &emcy);
        assert_eq!(
            own(&event, "EmcyEventType", "ErrorCode"),
            Variant::UInt16(0x4310)
        );
        assert_eq!(
            own(&event, "EmcyEventType", "ErrorRegister"),
            Variant::Byte(9)
        );
        assert_eq!(own(&event, "EmcyEventType", "Axis"), Variant::Byte(1));
        assert_eq!(
            base_field(&event, "SourceNode"),
            Variant::from(NodeId::new(NS, "candeck/Nodes/demo/3/Axes/1"))
        );
        assert_eq!(base_field(&event, "Severity"), Variant::UInt16(700));
        // 2023-11-14T22:13:20Z
        assert_eq!(
            event.time().as_chrono().timestamp(),
            1_700_000_000,
            "{:?}",
            event.time()
        );
    }

    #[test]
    fn an_alarm_step_carries_the_alarms_id_state_and_severity() {
        use crate::gateway::{AlarmState, AlarmStep};
        use crate::profiles::alarm::AlarmKind;
        let alarm = Alarm {
            id: 42,
            bus: "demo".into(),
            node: Some(3),
            axis: None,
            kind: AlarmKind::Emcy(0x4310),
            severity: Severity::High,
            state: AlarmState::ActiveAcknowledged,
            text: "Excess temperature drive".into(),
            help: String::new(),
            raised_us: 1_700_000_000_000_000,
            cleared_us: None,
            acknowledged_by: Some("line-hmi".into()),
            acknowledged_at_us: Some(1_700_000_001_000_000),
            comment: Some("seen".into()),
            count: 1,
            history: Vec::new(),
        };
        let event = alarm_event(
            NS,
            &AlarmChange {
                alarm,
                step: AlarmStep::Acknowledged,
            },
        );
        let at = |name| own(&event, "AlarmEventType", name);
        assert_eq!(at("AlarmId"), Variant::from("42"));
        assert_eq!(at("AlarmState"), Variant::from("active_acknowledged"));
        assert_eq!(at("AlarmStep"), Variant::from("acknowledged"));
        assert_eq!(at("AlarmSeverity"), Variant::from("high"));
        assert_eq!(at("AcknowledgedBy"), Variant::from("line-hmi"));
        assert_eq!(at("Comment"), Variant::from("seen"));
        assert_eq!(at("Node"), Variant::Byte(3));
        assert_eq!(base_field(&event, "Severity"), Variant::UInt16(700));
        assert_eq!(
            base_field(&event, "SourceNode"),
            Variant::from(NodeId::new(NS, "candeck/Nodes/demo/3"))
        );
    }

    #[test]
    fn the_event_types_are_subtypes_of_base_event_type_with_their_fields() {
        use opcua::nodes::{DefaultTypeTree, TypeTree};
        let mut space = AddressSpace::new();
        space.add_namespace(browse::NAMESPACE, NS);
        build_types(&mut space, NS);
        build_types(&mut space, NS);
        // The part of the core namespace's type tree the server has.
        use opcua::types::{NodeClass, ReferenceTypeId as R};
        let mut types = DefaultTypeTree::new();
        types.add_type_node(
            &ObjectTypeId::BaseEventType.into(),
            &ObjectTypeId::BaseObjectType.into(),
            NodeClass::ObjectType,
        );
        for (reference, parent) in [
            (R::HierarchicalReferences, R::References),
            (R::HasChild, R::HierarchicalReferences),
            (R::Aggregates, R::HasChild),
            (R::HasProperty, R::Aggregates),
            (R::HasSubtype, R::HasChild),
        ] {
            types.add_type_node(&reference.into(), &parent.into(), NodeClass::ReferenceType);
        }
        space.load_into_type_tree(&mut types);
        let base: NodeId = ObjectTypeId::BaseEventType.into();
        let alarm_id = [QualifiedName::new(NS, "AlarmId")];
        assert!(
            types
                .find_type_prop_by_browse_path(&base, &alarm_id)
                .is_none()
        );
        register_fields(&mut types, NS);
        assert!(
            types
                .find_type_prop_by_browse_path(&base, &alarm_id)
                .is_some()
        );
        for (name, fields) in EVENT_TYPES {
            let id = NodeId::new(NS, name);
            assert!(
                types.is_subtype_of(&id, &ObjectTypeId::BaseEventType.into()),
                "{name}"
            );
            for (field, _) in fields {
                let path = [QualifiedName::new(NS, *field)];
                assert!(
                    types.find_type_prop_by_browse_path(&id, &path).is_some(),
                    "{name}.{field}"
                );
            }
        }
    }
}
