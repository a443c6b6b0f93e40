//! A UIO1LED's segments and a CiA 401 module's channels as variables:
//! `Nodes/{bus}/{id}/Leds/{n}/{field}` (REST's segment fields) and
//! `Nodes/{bus}/{id}/Io/{channel}` (the gateway's channel names, `di1`,
//! `do1`, `ai1`, `ao1`). A read is the gateway's read of the segment or of
//! the module when the client reads (one per segment or module in a Read
//! request, however many of its variables it names); a monitored one is
//! sampled object by object with the node's dictionary variables, or fed
//! from its TPDOs ([`super::sampling`]); a write is the gateway's segment
//! write or output write with the session's caller, so the role, the write
//! limiter and the audit row are REST's (`set segment`, `set outputs`).
//! What a value means is [`crate::profiles::uioled`]'s and
//! [`crate::profiles::cia401`]'s.

use std::collections::{BTreeMap, HashMap};

use opcua::server::address_space::{AccessLevel, AddressSpace, VariableBuilder};
use opcua::types::{DataTypeId, DataValue, QualifiedName, VariableTypeId, Variant};
use serde_json::Value as Json;

use super::browse::{NodePath, ROOT};
use super::status::status_of;
use super::tree::{folder, id, object};
use crate::canopen::od::ObjectDictionary;
use crate::gateway::{
    Caller, Gateway, GatewayError, IoState, Profile, SegmentUpdate, effect_by_name, effect_name,
};
use crate::profiles::cia401::{Channel, ChannelKind, Layout};
use crate::profiles::uioled::{Field, SEGMENTS, Segment};

/// One field of a segment, as a variable of `Leds/{n}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum LedField {
    LedCount,
    /// The effect's name (`flow`), or `0xNNNN` for a value the manual does
    /// not name.
    Effect,
    /// `Color_01` to `Color_03` as `#rrggbbww`.
    Color(u8),
    Dimmer,
    Value,
    MinValue,
    MaxValue,
    Speed,
    Smooth,
}

impl LedField {
    pub const ALL: [Self; 11] = [
        Self::LedCount,
        Self::Effect,
        Self::Color(1),
        Self::Color(2),
        Self::Color(3),
        Self::Dimmer,
        Self::Value,
        Self::MinValue,
        Self::MaxValue,
        Self::Speed,
        Self::Smooth,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::LedCount => "LedCount",
            Self::Effect => "Effect",
            Self::Color(1) => "Color1",
            Self::Color(2) => "Color2",
            Self::Color(_) => "Color3",
            Self::Dimmer => "Dimmer",
            Self::Value => "Value",
            Self::MinValue => "MinValue",
            Self::MaxValue => "MaxValue",
            Self::Speed => "Speed",
            Self::Smooth => "Smooth",
        }
    }

    /// The type of its object (UNSIGNED8 `Dimmer`, INTEGER16 `Value`, ...);
    /// the effect and the colours as text.
    pub fn data_type(self) -> DataTypeId {
        match self {
            Self::Effect | Self::Color(_) => DataTypeId::String,
            Self::LedCount | Self::Smooth => DataTypeId::UInt16,
            Self::Dimmer => DataTypeId::Byte,
            Self::Value | Self::MinValue | Self::MaxValue | Self::Speed => DataTypeId::Int16,
        }
    }

    /// The segment's objects it shows (the profile's fields): one, or a
    /// colour's four (red, green, blue, white), in the order they are read.
    pub fn fields(self) -> Vec<Field> {
        let one = match self {
            Self::Color(color) => {
                return (1..=4)
                    .map(|channel| Field::Color { color, channel })
                    .collect();
            }
            Self::LedCount => Field::LedCount,
            Self::Effect => Field::Effect,
            Self::Dimmer => Field::Dimmer,
            Self::Value => Field::Value,
            Self::MinValue => Field::MinValue,
            Self::MaxValue => Field::MaxValue,
            Self::Speed => Field::Speed,
            Self::Smooth => Field::Smooth,
        };
        vec![one]
    }

    /// Its value from the bytes of its objects ([`LedField::fields`], in
    /// that order) as the device sent them, decoded as the gateway's
    /// segment read decodes them: a value its object's type cannot hold
    /// keeps the segment's default.
    pub fn value_from(self, data: &[&[u8]]) -> Variant {
        let mut segment = Segment::default();
        for (field, bytes) in self.fields().into_iter().zip(data) {
            if let Some(value) = field.value_in(bytes) {
                segment.set(field, value);
            }
        }
        self.value_of(&segment)
    }

    /// Its value in a segment read from the device.
    pub fn value_of(self, segment: &Segment) -> Variant {
        match self {
            Self::LedCount => Variant::UInt16(segment.led_count),
            Self::Effect => Variant::String(effect_name(segment.effect).into()),
            Self::Color(color) => {
                let rgbw = segment.colors[usize::from(color - 1)];
                Variant::String(
                    format!("#{:02x}{:02x}{:02x}{:02x}", rgbw.r, rgbw.g, rgbw.b, rgbw.w).into(),
                )
            }
            Self::Dimmer => Variant::Byte(segment.dimmer),
            Self::Value => Variant::Int16(segment.value),
            Self::MinValue => Variant::Int16(segment.min_value),
            Self::MaxValue => Variant::Int16(segment.max_value),
            Self::Speed => Variant::Int16(segment.speed),
            Self::Smooth => Variant::UInt16(segment.smooth),
        }
    }

    /// A written value as the segment update that writes it; its range is
    /// checked by the gateway's segment write, against the object's type.
    pub fn update(self, value: &Variant) -> Result<SegmentUpdate, GatewayError> {
        let mut update = SegmentUpdate::default();
        match self {
            Self::Effect => {
                let name = text(self, value)?;
                let raw = match name.strip_prefix("0x") {
                    Some(hex) => i64::from_str_radix(hex, 16).ok(),
                    None => effect_by_name(&name).map(|effect| i64::from(effect.raw())),
                };
                update.effect = Some(raw.ok_or_else(|| {
                    GatewayError::ValueOutOfRange(format!(
                        "Effect '{name}' is not one of off, fix, flash, breathing, flow, \
                         flow_reversed (or 0xNNNN)"
                    ))
                })?);
            }
            Self::Color(color) => {
                let given = text(self, value)?;
                let channels = hex_color(&given).ok_or_else(|| {
                    GatewayError::InvalidValue(format!(
                        "{}: '{given}' is not #rrggbb or #rrggbbww",
                        self.name()
                    ))
                })?;
                update.colors[usize::from(color - 1)] = channels.map(Some);
            }
            Self::LedCount => update.led_count = Some(integer(self, value)?),
            Self::Dimmer => update.dimmer = Some(integer(self, value)?),
            Self::Value => update.value = Some(integer(self, value)?),
            Self::MinValue => update.min_value = Some(integer(self, value)?),
            Self::MaxValue => update.max_value = Some(integer(self, value)?),
            Self::Speed => update.speed = Some(integer(self, value)?),
            Self::Smooth => update.smooth = Some(integer(self, value)?),
        }
        Ok(update)
    }
}

fn text(field: LedField, value: &Variant) -> Result<String, GatewayError> {
    match value {
        Variant::String(text) => Ok(text.as_ref().to_string()),
        other => Err(GatewayError::InvalidValue(format!(
            "{} is a String, not {:?}",
            field.name(),
            other.type_id()
        ))),
    }
}

fn integer(field: LedField, value: &Variant) -> Result<i64, GatewayError> {
    Ok(match value {
        Variant::SByte(v) => i64::from(*v),
        Variant::Byte(v) => i64::from(*v),
        Variant::Int16(v) => i64::from(*v),
        Variant::UInt16(v) => i64::from(*v),
        Variant::Int32(v) => i64::from(*v),
        Variant::UInt32(v) => i64::from(*v),
        Variant::Int64(v) => *v,
        Variant::UInt64(v) => i64::try_from(*v).unwrap_or(i64::MAX),
        other => {
            return Err(GatewayError::InvalidValue(format!(
                "{} is a whole number, not {:?}",
                field.name(),
                other.type_id()
            )));
        }
    })
}

/// `#rrggbb` (white 0, as REST's) or `#rrggbbww` as its four channels.
fn hex_color(text: &str) -> Option<[u8; 4]> {
    let hex = text.trim().strip_prefix('#')?;
    if !(hex.len() == 6 || hex.len() == 8) || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let mut channels = [0u8; 4];
    for (slot, at) in channels.iter_mut().zip((0..hex.len()).step_by(2)) {
        *slot = u8::from_str_radix(&hex[at..at + 2], 16).ok()?;
    }
    Some(channels)
}

/// A variable of this module: a segment's field or a module's channel.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum IoVariable {
    Segment {
        node: NodePath,
        segment: u8,
        field: LedField,
    },
    Channel {
        node: NodePath,
        channel: Channel,
    },
}

/// `Nodes/{bus}/{id}/Leds/{n}/{field}`.
pub fn segment_path(node: &NodePath, segment: u8, field: LedField) -> String {
    format!("{}/Leds/{segment}/{}", node.id(), field.name())
}

/// `Nodes/{bus}/{id}/Io/{channel}`.
pub fn channel_path(node: &NodePath, channel: Channel) -> String {
    format!("{}/Io/{channel}", node.id())
}

impl IoVariable {
    /// The variable node id `id` (its string) is, if it is one.
    pub fn parse(id: &str) -> Option<Self> {
        let rest = id.strip_prefix(ROOT)?.strip_prefix("/Nodes/")?;
        let parts: Vec<&str> = rest.split('/').collect();
        let node = |bus: &str, node: &str| {
            Some(NodePath {
                bus: bus.to_string(),
                node: node.parse().ok().filter(|id| (1..=127).contains(id))?,
            })
        };
        match parts.as_slice() {
            [bus, id, "Leds", segment, field] => Some(Self::Segment {
                node: node(bus, id)?,
                segment: segment
                    .parse()
                    .ok()
                    .filter(|n| (1..=SEGMENTS).contains(n))?,
                field: LedField::ALL
                    .into_iter()
                    .find(|known| known.name() == *field)?,
            }),
            [bus, id, "Io", channel] => Some(Self::Channel {
                node: node(bus, id)?,
                channel: Channel::parse(channel)?,
            }),
            _ => None,
        }
    }

    pub fn path(&self) -> String {
        match self {
            Self::Segment {
                node,
                segment,
                field,
            } => segment_path(node, *segment, *field),
            Self::Channel { node, channel } => channel_path(node, *channel),
        }
    }
}

fn variable(
    space: &mut AddressSpace,
    ns: u16,
    path: &str,
    parent: &str,
    data_type: DataTypeId,
    writable: bool,
) {
    let node = id(ns, path);
    if space.node_exists(&node) {
        return;
    }
    let name = path.rsplit('/').next().unwrap_or(path);
    let level = if writable {
        AccessLevel::CURRENT_READ | AccessLevel::CURRENT_WRITE
    } else {
        AccessLevel::CURRENT_READ
    };
    VariableBuilder::new(&node, QualifiedName::new(ns, name), name)
        .data_type(data_type)
        .value(Variant::Empty)
        .access_level(level)
        .user_access_level(level)
        .has_type_definition(VariableTypeId::BaseDataVariableType)
        .component_of(id(ns, parent))
        .insert(space);
}

/// The segments of a UIO1LED (`Leds/1` to `Leds/10`, every field
/// writable), or the channels of a CiA 401 module whose EDS says how many
/// it has (inputs read-only, outputs writable); nothing for other nodes.
/// The channels count of a module without an EDS takes SDO reads: it gets
/// no `Io` (REST's `GET .../io` has them).
pub fn build(
    space: &mut AddressSpace,
    ns: u16,
    node: &NodePath,
    profile: Profile,
    dictionary: Option<&ObjectDictionary>,
) {
    let node_id = id(ns, node.id());
    match profile {
        Profile::Uioled => {
            let leds = node.child("Leds");
            folder(space, ns, &leds, "Leds", &node_id);
            for segment in 1..=SEGMENTS {
                let path = format!("{leds}/{segment}");
                object(space, ns, &path, &segment.to_string(), &id(ns, &leds));
                for field in LedField::ALL {
                    let variable_path = segment_path(node, segment, field);
                    variable(space, ns, &variable_path, &path, field.data_type(), true);
                }
            }
        }
        Profile::Cia401 => {
            let Some(dictionary) = dictionary else {
                return;
            };
            let layout = Layout::from_dictionary(dictionary);
            if layout.is_empty() {
                return;
            }
            let io = node.child("Io");
            object(space, ns, &io, "Io", &node_id);
            for kind in ChannelKind::ALL {
                let data_type = if kind.is_digital() {
                    DataTypeId::Boolean
                } else {
                    DataTypeId::Int16
                };
                for channel in layout.channels(kind) {
                    let path = channel_path(node, channel);
                    variable(space, ns, &path, &io, data_type, kind.is_output());
                }
            }
        }
        _ => {}
    }
}

/// What one Read request read: each segment and module once, however many
/// of its variables the request names.
#[derive(Default)]
pub struct Reads {
    segments: HashMap<(NodePath, u8), Result<Segment, GatewayError>>,
    modules: HashMap<NodePath, Result<IoState, GatewayError>>,
}

impl Reads {
    /// The variable's value now, read through the gateway; an error as its
    /// status.
    pub async fn read(
        &mut self,
        gateway: &Gateway,
        caller: &Caller,
        variable: &IoVariable,
    ) -> DataValue {
        match self.value(gateway, caller, variable).await {
            Ok(value) => DataValue::new_now(value),
            Err(error) => {
                tracing::debug!("opcua: read of {}: {error}", variable.path());
                super::sampling::failed(status_of(&error))
            }
        }
    }

    async fn value(
        &mut self,
        gateway: &Gateway,
        caller: &Caller,
        variable: &IoVariable,
    ) -> Result<Variant, GatewayError> {
        match variable {
            IoVariable::Segment {
                node,
                segment,
                field,
            } => {
                let key = (node.clone(), *segment);
                if !self.segments.contains_key(&key) {
                    let read = async {
                        handle(gateway, node)?
                            .led_controller()?
                            .read_segment(caller, *segment)
                            .await
                    }
                    .await;
                    self.segments.insert(key.clone(), read);
                }
                let read = self.segments[&key].as_ref().map_err(Clone::clone)?;
                Ok(field.value_of(read))
            }
            IoVariable::Channel { node, channel } => {
                if !self.modules.contains_key(node) {
                    let read = gateway.read_io(&node.bus, &node.node.to_string()).await;
                    self.modules.insert(node.clone(), read);
                }
                let state = self.modules[node].as_ref().map_err(Clone::clone)?;
                let name = channel.to_string();
                let value = [
                    &state.digital_inputs,
                    &state.digital_outputs,
                    &state.analog_inputs,
                    &state.analog_outputs,
                ]
                .into_iter()
                .flatten()
                .find(|read| read.channel == name)
                .map(|read| read.value.clone())
                .ok_or_else(|| {
                    GatewayError::UnknownChannel(format!("node {} has no {name}", node.node))
                })?;
                Ok(match value {
                    Json::Bool(on) => Variant::Boolean(on),
                    number => Variant::Int16(
                        number
                            .as_i64()
                            .and_then(|n| i16::try_from(n).ok())
                            .ok_or_else(|| {
                                GatewayError::Internal(format!("{name}: {number} is no INTEGER16"))
                            })?,
                    ),
                })
            }
        }
    }
}

fn handle(gateway: &Gateway, node: &NodePath) -> Result<crate::gateway::NodeHandle, GatewayError> {
    gateway.node_handle(&node.bus, &node.node.to_string())
}

/// A written value as the JSON of the audit row's summary.
pub fn summary(value: &Variant) -> Option<String> {
    super::values::json_of(value).map(|json| json.to_string())
}

/// Writes `value` to `variable` as `caller`: a segment's field by the
/// gateway's segment write, an output by its output write (each audited
/// and held to the caller's role and write rate there).
pub async fn write(
    gateway: &Gateway,
    caller: &Caller,
    variable: &IoVariable,
    value: &Variant,
) -> Result<(), GatewayError> {
    match variable {
        IoVariable::Segment {
            node,
            segment,
            field,
        } => {
            let update = field.update(value)?;
            handle(gateway, node)?
                .led_controller()?
                .write_segment(caller, *segment, &update)
                .await
        }
        IoVariable::Channel { node, channel } => {
            let name = channel.to_string();
            let json = match (channel.kind.is_digital(), value) {
                (true, Variant::Boolean(on)) => Json::Bool(*on),
                (false, Variant::Int16(level)) => Json::from(*level),
                (digital, other) => {
                    return Err(GatewayError::InvalidValue(format!(
                        "{name} is {}, not {:?}",
                        if digital { "a Boolean" } else { "an Int16" },
                        other.type_id()
                    )));
                }
            };
            gateway
                .write_io(
                    caller,
                    &node.bus,
                    &node.node.to_string(),
                    BTreeMap::from([(name, json)]),
                )
                .await
                .map(|_| ())
        }
    }
}

#[cfg(test)]
mod tests;
