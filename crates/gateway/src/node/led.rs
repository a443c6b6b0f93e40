//! A UIO1LED's segments (UIOLed firmware manual chapter 1) as operations of
//! its node: [`NodeHandle::led_controller`] checks the node is one, and
//! [`LedController`]'s operations read the segments, write one segment's
//! fields ([`SegmentUpdate`]), apply a [`Scene`] and draw the strip's
//! [`Preview`]. Each does the whole job for its [`Caller`], whichever door
//! asks (REST's segment routes, a Sparkplug `Segment {n}/{field}`
//! command): the role (a viewer's to read, an operator's to write), a write
//! from the caller's write rate, every value checked before the first
//! write, the node's state checked, and the transfers in a task a vanished
//! client cannot cut, not interleaved with another request's. The LED
//! preview follows every write the node confirms, even of a sequence that
//! stops half way ([`crate::registry::NodeRegistry::subscribe_writes`]).
//!
//! The SDO work is [`crate::uioled`]'s; parsing a request (names of
//! effects, colours as text) is the door's.

use crate::policy::Operation;
use tokio::time::Instant;

use super::NodeHandle;
use super::transfer::{audited, spawned};
use crate::GatewayError;
use crate::caller::Caller;
use crate::check_sdo_allowed;
use crate::error::LedError;
use crate::profile::Profile;
use crate::profiles::uioled::{Effect, Field, SEGMENTS, Segment};
use crate::uioled::{self, Preview, ReadSegment, fits, is_segment};

/// Channels of one colour to write: red, green, blue, white; `None` stays
/// as it is.
pub type ColorChannels = [Option<u8>; 4];

/// The fields of one segment to write; only those given are written, in
/// the order that shows the new look at once: layout and colours first,
/// the Value range before Value and Speed, the effect last.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SegmentUpdate {
    pub led_count: Option<i64>,
    /// `Color_01` to `Color_03`.
    pub colors: [ColorChannels; 3],
    pub dimmer: Option<i64>,
    pub smooth: Option<i64>,
    pub min_value: Option<i64>,
    pub max_value: Option<i64>,
    pub value: Option<i64>,
    pub speed: Option<i64>,
    /// The wire value of `sNN_Effect` (manual Table 1.2).
    pub effect: Option<i64>,
}

impl SegmentUpdate {
    /// The fields given and their values, in the order they go out,
    /// unchecked.
    pub fn fields(&self) -> Vec<(Field, i64)> {
        let mut fields: Vec<(Field, i64)> = Vec::new();
        fields.extend(self.led_count.map(|count| (Field::LedCount, count)));
        for (color, channels) in (1..).zip(&self.colors) {
            for (channel, level) in (1..).zip(channels) {
                fields
                    .extend(level.map(|level| (Field::Color { color, channel }, i64::from(level))));
            }
        }
        for (field, value) in [
            (Field::Dimmer, self.dimmer),
            (Field::Smooth, self.smooth),
            (Field::MinValue, self.min_value),
            (Field::MaxValue, self.max_value),
            (Field::Value, self.value),
            (Field::Speed, self.speed),
            (Field::Effect, self.effect),
        ] {
            fields.extend(value.map(|value| (field, value)));
        }
        fields
    }

    /// [`SegmentUpdate::fields`], each checked against its object's type.
    fn writes(&self) -> Result<Vec<(Field, i64)>, GatewayError> {
        let fields = self.fields();
        if let Some((field, value)) = fields.iter().find(|(field, value)| !fits(*field, *value)) {
            return Err(GatewayError::ValueOutOfRange(format!(
                "{} {value} does not fit its object ({})",
                field_name(*field),
                uioled::data_type(*field)
            )));
        }
        Ok(fields)
    }
}

/// A field as a request names it.
fn field_name(field: Field) -> &'static str {
    match field {
        Field::LedType => "led_type",
        Field::LedCount => "led_count",
        Field::Value => "value",
        Field::MinValue => "min_value",
        Field::MaxValue => "max_value",
        Field::Speed => "speed",
        Field::Effect => "effect",
        Field::Smooth => "smooth",
        Field::Dimmer => "dimmer",
        Field::Color { .. } => "colors",
    }
}

/// The effects by name, as the manual names them.
const EFFECTS: [Effect; 6] = [
    Effect::Off,
    Effect::Fix,
    Effect::Flash,
    Effect::Breathing,
    Effect::Flow,
    Effect::FlowReversed,
];

/// The effect of a name, in any case, with ` ` or `-` for `_`
/// (`flow_reversed`, `Flow Reversed`); `None` for a name the manual does
/// not give.
pub fn effect_by_name(name: &str) -> Option<Effect> {
    let folded = name.trim().to_ascii_uppercase().replace([' ', '-'], "_");
    EFFECTS.into_iter().find(|effect| effect.name() == folded)
}

/// One segment's checked writes, in the order they go out.
type SegmentWrites = (u8, Vec<(Field, i64)>);

/// What becomes of the segments a scene does not list.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Others {
    /// They stay as they are.
    #[default]
    Keep,
    /// Their effect is set to off.
    Off,
}

impl Others {
    /// `keep` or `off`.
    pub fn from_name(name: &str) -> Result<Self, GatewayError> {
        match name {
            "keep" => Ok(Self::Keep),
            "off" => Ok(Self::Off),
            other => Err(GatewayError::InvalidValue(format!(
                "others '{other}' is not keep or off"
            ))),
        }
    }
}

/// A whole scene: the segments listed, each with its update, and what
/// becomes of the others.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Scene {
    pub segments: Vec<(u8, SegmentUpdate)>,
    pub others: Others,
}

impl Scene {
    /// Every segment's writes, in the order they go out, all checked: a
    /// segment listed twice is refused.
    fn writes(&self) -> Result<Vec<SegmentWrites>, GatewayError> {
        let mut writes: Vec<SegmentWrites> = Vec::new();
        for (segment, update) in &self.segments {
            check_segment(*segment)?;
            if writes.iter().any(|(n, _)| n == segment) {
                return Err(GatewayError::InvalidValue(format!(
                    "segment {segment} is listed twice"
                )));
            }
            writes.push((*segment, update.writes()?));
        }
        if self.others == Others::Off {
            for segment in 1..=SEGMENTS {
                if !writes.iter().any(|(n, _)| *n == segment) {
                    writes.push((segment, vec![(Field::Effect, i64::from(Effect::Off.raw()))]));
                }
            }
        }
        Ok(writes)
    }
}

/// A segment that is none of the UIO1LED's: `unknown_segment`.
fn check_segment(segment: u8) -> Result<(), GatewayError> {
    if is_segment(segment) {
        return Ok(());
    }
    Err(LedError::UnknownSegment(format!(
        "segment '{segment}' does not exist: a UIO1LED has segments 1 to {SEGMENTS}"
    ))
    .into())
}

/// A node that is an LED controller (profile uioled): what the segment
/// operations act on.
#[derive(Clone)]
pub struct LedController {
    node: NodeHandle,
}

impl NodeHandle {
    /// The node as an LED controller; `not_an_led_controller` when its
    /// profile is not uioled.
    pub fn led_controller(self) -> Result<LedController, GatewayError> {
        if self.info.profile != Profile::Uioled {
            return Err(LedError::NotAnLedController(format!(
                "node {} is a {} node, not an LED controller (profile uioled): it has no segments",
                self.info.id,
                self.info.profile.name()
            ))
            .into());
        }
        Ok(LedController { node: self })
    }
}

impl LedController {
    /// The node.
    pub fn node(&self) -> &NodeHandle {
        &self.node
    }

    /// Every segment, segment 1 first (the viewer's).
    pub async fn read_segments(&self, caller: &Caller) -> Result<Vec<Segment>, GatewayError> {
        let node = &self.node;
        node.gateway.require(caller, Operation::View)?;
        check_sdo_allowed(&node.served, &node.info)?;
        let channel = node.served.registry.sdo(node.info.id)?;
        spawned(async move { Ok(uioled::read_segments(&channel).await?) }).await
    }

    /// One segment (the viewer's): what a door that shows a segment's
    /// fields one by one reads, without the other nine segments' transfers.
    pub async fn read_segment(
        &self,
        caller: &Caller,
        segment: u8,
    ) -> Result<Segment, GatewayError> {
        let node = &self.node;
        node.gateway.require(caller, Operation::View)?;
        check_segment(segment)?;
        check_sdo_allowed(&node.served, &node.info)?;
        let channel = node.served.registry.sdo(node.info.id)?;
        spawned(async move { Ok(uioled::read_segment(&channel, segment).await?) }).await
    }

    /// Writes `update` to `segment` (the operator's; one write of the
    /// caller's rate).
    pub async fn write_segment(
        &self,
        caller: &Caller,
        segment: u8,
        update: &SegmentUpdate,
    ) -> Result<(), GatewayError> {
        self.write(caller, segment, update, None).await.map(|_| ())
    }

    /// [`LedController::write_segment`], then the segment read back in the
    /// same sequence.
    pub async fn write_segment_read_back(
        &self,
        caller: &Caller,
        segment: u8,
        update: &SegmentUpdate,
    ) -> Result<Segment, GatewayError> {
        let read = self
            .write(caller, segment, update, Some(ReadBack::One(segment)))
            .await?;
        read.into_iter()
            .next()
            .ok_or_else(|| GatewayError::Internal(format!("segment {segment} was not read back")))
    }

    /// Applies `scene` (the operator's; one write of the caller's rate) and
    /// reads every segment back in the same sequence.
    ///
    /// Audited as `set scene`, in a task of its own with its row.
    pub async fn apply_scene(
        &self,
        caller: &Caller,
        scene: &Scene,
    ) -> Result<Vec<Segment>, GatewayError> {
        let row = self.node.audit_row(caller, "set scene", None, None);
        let (this, caller, scene) = (self.clone(), caller.clone(), scene.clone());
        audited(row, async move {
            let node = &this.node;
            node.gateway.admit(&caller, Operation::SetLeds)?;
            let writes = scene.writes()?;
            this.transfer(writes, Some(ReadBack::All)).await
        })
        .await
    }

    /// Audited as `set segment`, in a task of its own with its row.
    async fn write(
        &self,
        caller: &Caller,
        segment: u8,
        update: &SegmentUpdate,
        read_back: Option<ReadBack>,
    ) -> Result<Vec<Segment>, GatewayError> {
        let item = Some(format!("segment {segment}"));
        let row = self.node.audit_row(caller, "set segment", item, None);
        let (this, caller, update) = (self.clone(), caller.clone(), update.clone());
        audited(row, async move {
            let node = &this.node;
            node.gateway.admit(&caller, Operation::SetLeds)?;
            check_segment(segment)?;
            let writes = vec![(segment, update.writes()?)];
            this.transfer(writes, read_back).await
        })
        .await
    }

    /// The checked writes and the read-back, in one task, not interleaved
    /// with another request's transfers to the node.
    async fn transfer(
        &self,
        writes: Vec<SegmentWrites>,
        read_back: Option<ReadBack>,
    ) -> Result<Vec<Segment>, GatewayError> {
        let node = &self.node;
        check_sdo_allowed(&node.served, &node.info)?;
        let channel = node.served.registry.sdo(node.info.id)?;
        spawned(async move {
            let _procedure = channel.procedure().await;
            for (segment, fields) in &writes {
                uioled::write_fields(&channel, *segment, fields).await?;
            }
            Ok(match read_back {
                None => Vec::new(),
                Some(ReadBack::One(segment)) => {
                    vec![uioled::read_segment(&channel, segment).await?]
                }
                Some(ReadBack::All) => uioled::read_segments(&channel).await?,
            })
        })
        .await
    }

    /// What the strip shows now (the viewer's), drawn from the parameters
    /// read from the device by the renderer the virtual UIO1LED uses.
    pub async fn preview(&self, caller: &Caller) -> Result<Preview, GatewayError> {
        let node = &self.node;
        node.gateway.require(caller, Operation::View)?;
        check_sdo_allowed(&node.served, &node.info)?;
        let channel = node.served.registry.sdo(node.info.id)?;
        let segments = spawned(async move { Ok(uioled::read_preview(&channel).await?) }).await?;
        // The Values read are taken for those of now (time 0 of the
        // renderer).
        let now = Instant::now();
        let segments: Vec<ReadSegment> = segments
            .into_iter()
            .map(|read| ReadSegment {
                read_at: now,
                ..read
            })
            .collect();
        Ok(uioled::preview(&segments, now))
    }
}

/// What a write reads back.
#[derive(Debug, Clone, Copy)]
enum ReadBack {
    One(u8),
    All,
}
