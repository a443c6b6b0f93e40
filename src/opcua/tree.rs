//! The nodes of the browse tree, built into an address space: folders,
//! objects, variables (typed, with their access level and engineering
//! units) and methods with their arguments. What each stands for is
//! [`super::browse`]'s; the values come from the feed
//! ([`super::feed`]).

use opcua::server::address_space::{
    AccessLevel, AddressSpace, EventNotifier, MethodBuilder, ObjectBuilder, VariableBuilder,
};
use opcua::types::{
    Argument, DataTypeId, EUInformation, ExtensionObject, LocalizedText, NodeId, ObjectId,
    ObjectTypeId, QualifiedName, UAString, VariableTypeId, Variant,
};

use super::browse::{self, AxisMethod, NodePath, ROOT};
use crate::canopen::od::ObjectDictionary;
use crate::gateway::AxisUnits;

/// The variables of the machine, each with its type.
pub const MACHINE: [(&str, DataTypeId); 5] = [
    ("State", DataTypeId::String),
    ("Reasons", DataTypeId::String),
    ("ActiveAlarms", DataTypeId::UInt32),
    ("UnacknowledgedAlarms", DataTypeId::UInt32),
    ("HighestSeverity", DataTypeId::String),
];

/// The variables of a bus.
pub const BUS: [(&str, DataTypeId); 7] = [
    ("State", DataTypeId::String),
    ("Load", DataTypeId::Double),
    ("RxFrames", DataTypeId::UInt64),
    ("TxFrames", DataTypeId::UInt64),
    ("ErrorFrames", DataTypeId::UInt64),
    ("RxOverruns", DataTypeId::UInt64),
    ("TxErrors", DataTypeId::UInt64),
];

/// The variables of a node.
pub const NODE: [(&str, DataTypeId); 3] = [
    ("NmtState", DataTypeId::String),
    ("Online", DataTypeId::Boolean),
    ("Profile", DataTypeId::String),
];

/// The variables of `Identification` (OPC UA for Devices' names).
pub const IDENTIFICATION: [(&str, DataTypeId); 8] = [
    ("Manufacturer", DataTypeId::String),
    ("Model", DataTypeId::String),
    ("SerialNumber", DataTypeId::String),
    ("HardwareRevision", DataTypeId::String),
    ("SoftwareRevision", DataTypeId::String),
    ("DeviceRevision", DataTypeId::String),
    ("VendorId", DataTypeId::UInt32),
    ("ProductCode", DataTypeId::UInt32),
];

/// The variables of an axis.
pub const AXIS: [(&str, DataTypeId); 9] = [
    ("State", DataTypeId::String),
    ("Mode", DataTypeId::String),
    ("Statusword", DataTypeId::UInt16),
    ("Position", DataTypeId::Int32),
    ("Velocity", DataTypeId::Int32),
    ("Torque", DataTypeId::Int16),
    ("FaultCode", DataTypeId::UInt16),
    ("FaultText", DataTypeId::String),
    ("TargetReached", DataTypeId::Boolean),
];

/// A method's arguments: each name with its type.
type Arguments = &'static [(&'static str, DataTypeId)];

/// One node of the tree as a node id of namespace `ns`.
pub fn id(ns: u16, path: impl Into<String>) -> NodeId {
    NodeId::new(ns, path.into())
}

pub(super) fn folder(
    space: &mut AddressSpace,
    ns: u16,
    path: &str,
    name: &str,
    parent: &NodeId,
) -> NodeId {
    let node = id(ns, path);
    if !space.node_exists(&node) {
        ObjectBuilder::new(&node, QualifiedName::new(ns, name), name)
            .has_type_definition(ObjectTypeId::FolderType)
            .organized_by(parent.clone())
            .insert(space);
    }
    node
}

pub(super) fn object(
    space: &mut AddressSpace,
    ns: u16,
    path: &str,
    name: &str,
    parent: &NodeId,
) -> NodeId {
    let node = id(ns, path);
    if !space.node_exists(&node) {
        ObjectBuilder::new(&node, QualifiedName::new(ns, name), name)
            .has_type_definition(ObjectTypeId::BaseObjectType)
            .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
            .component_of(parent.clone())
            .insert(space);
    }
    node
}

/// A read-only value the feed keeps.
fn value(space: &mut AddressSpace, ns: u16, parent: &str, (name, data_type): (&str, DataTypeId)) {
    let node = id(ns, format!("{parent}/{name}"));
    if space.node_exists(&node) {
        return;
    }
    VariableBuilder::new(&node, QualifiedName::new(ns, name), name)
        .data_type(data_type)
        .value(Variant::Empty)
        .access_level(AccessLevel::CURRENT_READ)
        .user_access_level(AccessLevel::CURRENT_READ)
        .has_type_definition(VariableTypeId::BaseDataVariableType)
        .component_of(id(ns, parent))
        .insert(space);
}

/// `EngineeringUnits` of a variable: the unit as its product's manual
/// names it (no UNECE code is claimed for `0.1 rps`).
fn units(space: &mut AddressSpace, ns: u16, variable: &str, unit: &str) {
    let node = id(ns, format!("{variable}/EngineeringUnits"));
    if space.node_exists(&node) {
        return;
    }
    let information = EUInformation {
        namespace_uri: UAString::null(),
        unit_id: -1,
        display_name: LocalizedText::new("", unit),
        description: LocalizedText::new("", unit),
    };
    VariableBuilder::new(&node, "EngineeringUnits", "EngineeringUnits")
        .data_type(DataTypeId::EUInformation)
        .value(Variant::from(ExtensionObject::from_message(information)))
        .access_level(AccessLevel::CURRENT_READ)
        .user_access_level(AccessLevel::CURRENT_READ)
        .has_type_definition(VariableTypeId::PropertyType)
        .property_of(id(ns, variable))
        .insert(space);
}

fn method(
    space: &mut AddressSpace,
    ns: u16,
    parent: &str,
    name: &str,
    inputs: &[(&str, DataTypeId)],
    outputs: &[(&str, DataTypeId)],
) {
    let path = format!("{parent}/{name}");
    let node = id(ns, &path);
    if space.node_exists(&node) {
        return;
    }
    let arguments = |list: &[(&str, DataTypeId)]| -> Vec<Argument> {
        list.iter()
            .map(|(name, data_type)| (*name, *data_type).into())
            .collect()
    };
    let mut builder = MethodBuilder::new(&node, QualifiedName::new(ns, name), name)
        .executable(true)
        .user_executable(true)
        .component_of(id(ns, parent));
    if !inputs.is_empty() {
        builder = builder.input_args(
            space,
            &id(ns, format!("{path}/InputArguments")),
            &arguments(inputs),
        );
    }
    if !outputs.is_empty() {
        builder = builder.output_args(
            space,
            &id(ns, format!("{path}/OutputArguments")),
            &arguments(outputs),
        );
    }
    builder.insert(space);
}

/// The fixed part: `candeck` under `Objects` with `StopAll`, `Machine`,
/// `Buses/{bus}` for each bus (with `Scan` and `Sync`) and the `Nodes`
/// folders the feed fills.
pub fn build_fixed(space: &mut AddressSpace, ns: u16, buses: &[String]) {
    let objects = NodeId::from(ObjectId::ObjectsFolder);
    let root = id(ns, ROOT);
    if !space.node_exists(&root) {
        ObjectBuilder::new(&root, QualifiedName::new(ns, ROOT), ROOT)
            .has_type_definition(ObjectTypeId::BaseObjectType)
            .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
            .organized_by(objects)
            .insert(space);
    }
    method(
        space,
        ns,
        ROOT,
        "StopAll",
        &[],
        &[("Stopped", DataTypeId::UInt32)],
    );
    let machine = format!("{ROOT}/Machine");
    object(space, ns, &machine, "Machine", &root);
    for variable in MACHINE {
        value(space, ns, &machine, variable);
    }
    method(
        space,
        ns,
        &machine,
        "Acknowledge",
        &[
            ("AlarmId", DataTypeId::String),
            ("Comment", DataTypeId::String),
        ],
        &[("AlarmState", DataTypeId::String)],
    );
    super::events::build_types(space, ns);
    let buses_folder = folder(space, ns, &format!("{ROOT}/Buses"), "Buses", &root);
    let nodes_folder = folder(space, ns, &format!("{ROOT}/Nodes"), "Nodes", &root);
    for bus in buses {
        let path = browse::bus_id(bus);
        object(space, ns, &path, bus, &buses_folder);
        for variable in BUS {
            value(space, ns, &path, variable);
        }
        units(
            space,
            ns,
            &format!("{path}/Load"),
            "fraction of the bit rate",
        );
        method(
            space,
            ns,
            &path,
            "Scan",
            &[],
            &[("NodesFound", DataTypeId::UInt32)],
        );
        method(
            space,
            ns,
            &path,
            "Sync",
            &[("PeriodMs", DataTypeId::UInt32)],
            &[],
        );
        folder(
            space,
            ns,
            &format!("{ROOT}/Nodes/{bus}"),
            bus,
            &nodes_folder,
        );
    }
}

/// A node's object, its identification, its methods and its dictionary
/// (each entry the EDS describes, typed, with its access level).
pub fn build_node(
    space: &mut AddressSpace,
    ns: u16,
    node: &NodePath,
    dictionary: Option<&ObjectDictionary>,
) {
    let path = node.id();
    let parent = id(ns, format!("{ROOT}/Nodes/{}", node.bus));
    object(space, ns, &path, &node.node.to_string(), &parent);
    for variable in NODE {
        value(space, ns, &path, variable);
    }
    let identification = node.child("Identification");
    object(space, ns, &identification, "Identification", &id(ns, &path));
    for variable in IDENTIFICATION {
        value(space, ns, &identification, variable);
    }
    method(
        space,
        ns,
        &path,
        "Nmt",
        &[("Command", DataTypeId::String)],
        &[],
    );
    method(
        space,
        ns,
        &path,
        "Store",
        &[("Area", DataTypeId::String)],
        &[],
    );
    method(
        space,
        ns,
        &path,
        "Restore",
        &[("Area", DataTypeId::String), ("Source", DataTypeId::String)],
        &[],
    );
    let Some(dictionary) = dictionary else {
        return;
    };
    let folder_path = node.child("Dictionary");
    folder(space, ns, &folder_path, "Dictionary", &id(ns, &path));
    for entry in dictionary.iter() {
        for sub in entry.subs.values() {
            let variable = id(ns, node.object(entry.index, sub.sub_index));
            if space.node_exists(&variable) {
                continue;
            }
            let name = browse::object_name(entry.index, sub.sub_index);
            let shown = if entry.subs.len() > 1 {
                format!("{} / {}", entry.name, sub.name)
            } else {
                entry.name.clone()
            };
            let level = super::values::access_level(sub.access);
            VariableBuilder::new(&variable, QualifiedName::new(ns, name), shown.as_str())
                .data_type(super::values::data_type_id(sub.data_type))
                .value(Variant::Empty)
                .access_level(level)
                .user_access_level(level)
                .has_type_definition(VariableTypeId::BaseDataVariableType)
                .organized_by(id(ns, &folder_path))
                .insert(space);
        }
    }
}

/// The axes of a drive, each with its values in `units` and its methods.
pub fn build_axes(
    space: &mut AddressSpace,
    ns: u16,
    node: &NodePath,
    axes: u8,
    axis_units: &AxisUnits,
) {
    let node_path = node.id();
    let axes_path = node.child("Axes");
    folder(space, ns, &axes_path, "Axes", &id(ns, &node_path));
    for axis in 1..=axes {
        let path = node.axis(axis);
        object(space, ns, &path, &axis.to_string(), &id(ns, &axes_path));
        for variable in AXIS {
            value(space, ns, &path, variable);
        }
        units(space, ns, &format!("{path}/Position"), &axis_units.position);
        units(space, ns, &format!("{path}/Velocity"), &axis_units.velocity);
        units(space, ns, &format!("{path}/Torque"), &axis_units.torque);
        for axis_method in AxisMethod::ALL {
            let (inputs, outputs): (Arguments, Arguments) = match axis_method {
                AxisMethod::SetState => (&[("Target", DataTypeId::String)], &[]),
                AxisMethod::Move => (
                    &[
                        ("Mode", DataTypeId::String),
                        ("Target", DataTypeId::Double),
                        ("Velocity", DataTypeId::Double),
                        ("Acceleration", DataTypeId::Double),
                        ("Deceleration", DataTypeId::Double),
                        ("Relative", DataTypeId::Boolean),
                    ],
                    &[("LeaseHeld", DataTypeId::Boolean)],
                ),
                AxisMethod::StepTest => (
                    &[("Request", DataTypeId::String)],
                    &[("Result", DataTypeId::String)],
                ),
                AxisMethod::TakeLease => (
                    &[],
                    &[
                        ("LeaseId", DataTypeId::String),
                        ("PeriodMs", DataTypeId::UInt32),
                    ],
                ),
                AxisMethod::RenewLease => (
                    &[("LeaseId", DataTypeId::String)],
                    &[("PeriodMs", DataTypeId::UInt32)],
                ),
                AxisMethod::ReleaseLease => (&[("LeaseId", DataTypeId::String)], &[]),
                AxisMethod::Halt | AxisMethod::QuickStop | AxisMethod::FaultReset => (&[], &[]),
            };
            method(space, ns, &path, axis_method.name(), inputs, outputs);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::od::{AccessType, DataType, Object, ObjectType, SubObject};
    use opcua::server::address_space::{NodeBase, NodeType};

    fn dictionary() -> ObjectDictionary {
        let mut dictionary = ObjectDictionary::default();
        let sub =
            |access| SubObject::new(0, "Producer heartbeat time", DataType::Unsigned16, access);
        for (index, access) in [(0x1017, AccessType::Rw), (0x1001, AccessType::Ro)] {
            dictionary.objects.insert(
                index,
                Object {
                    index,
                    name: "Producer heartbeat time".into(),
                    object_type: ObjectType::Var,
                    subs: [(0, sub(access))].into(),
                    obj_flags: None,
                },
            );
        }
        dictionary
    }

    fn variable<'a>(
        space: &'a AddressSpace,
        ns: u16,
        path: &str,
    ) -> &'a opcua::server::address_space::Variable {
        match space.find(&id(ns, path)) {
            Some(NodeType::Variable(variable)) => variable,
            other => panic!("{path}: {other:?}"),
        }
    }

    #[test]
    fn a_drive_is_browsable_by_its_path_with_typed_values_methods_and_units() {
        let mut space = AddressSpace::new();
        let ns = 2;
        space.add_namespace(browse::NAMESPACE, ns);
        build_fixed(&mut space, ns, &["demo".to_string()]);
        let node = NodePath {
            bus: "demo".into(),
            node: 3,
        };
        build_node(&mut space, ns, &node, Some(&dictionary()));
        let units = crate::gateway::DriveKind::Umc.units();
        build_axes(&mut space, ns, &node, 2, &units);
        // Built twice (the feed sees the node again): nothing is added twice.
        build_node(&mut space, ns, &node, Some(&dictionary()));
        build_axes(&mut space, ns, &node, 2, &units);

        for path in [
            "candeck/Machine/State",
            "candeck/Buses/demo/Load",
            "candeck/Nodes/demo/3/NmtState",
            "candeck/Nodes/demo/3/Identification/SerialNumber",
            "candeck/Nodes/demo/3/Axes/2/Position",
        ] {
            assert!(variable(&space, ns, path).is_readable(), "{path}");
        }
        for path in [
            "candeck/StopAll",
            "candeck/Buses/demo/Scan",
            "candeck/Nodes/demo/3/Nmt",
            "candeck/Nodes/demo/3/Axes/1/Move",
            "candeck/Nodes/demo/3/Axes/2/QuickStop",
        ] {
            assert!(
                matches!(space.find(&id(ns, path)), Some(NodeType::Method(_))),
                "{path}"
            );
            assert!(browse::Target::parse(path).is_some(), "{path}");
        }
        let position = variable(
            &space,
            ns,
            "candeck/Nodes/demo/3/Axes/1/Position/EngineeringUnits",
        );
        assert!(position.is_readable());

        // Browse names are the namespace's, so that a browse path
        // `2:candeck/2:Nodes/...` finds them.
        let position = variable(&space, ns, "candeck/Nodes/demo/3/Axes/1/Position");
        assert_eq!(position.browse_name(), &QualifiedName::new(ns, "Position"));

        // The dictionary: the EDS's type and access type.
        let heartbeat = variable(&space, ns, &node.object(0x1017, 0));
        assert!(heartbeat.is_writable());
        assert_eq!(heartbeat.data_type(), NodeId::from(DataTypeId::UInt16));
        let error_register = variable(&space, ns, &node.object(0x1001, 0));
        assert!(!error_register.is_writable());
        assert!(error_register.is_readable());
        // The fixed values are never writable.
        assert!(!variable(&space, ns, "candeck/Nodes/demo/3/Axes/1/Position").is_writable());
    }
}
