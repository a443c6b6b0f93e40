//! Where a segment's parameters live in the dictionary (UIOLed firmware
//! manual §1.2 "Multiple segments", Table 1.1, and §1.3): segment n's
//! objects are at 0x6000 + 0x100 × (n − 1) plus the offset of the object.

use super::segment::{Effect, Segment};
use crate::canopen::od::{DataType, Value};

/// How many segments the UIO1LED has.
pub const SEGMENTS: u8 = 10;

/// The index of segment 1's first object; each further segment is 0x100 on.
const FIRST_SEGMENT: u16 = 0x6000;
const SEGMENT_STRIDE: u16 = 0x100;

/// One parameter of a segment, as the manual names its objects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Field {
    LedType,
    LedCount,
    Value,
    MinValue,
    MaxValue,
    Speed,
    Effect,
    Smooth,
    Dimmer,
    /// One channel of a colour: `color` 1–3 (`Color_01`–`Color_03`),
    /// `channel` the sub-index 1–4 (R, G, B, W).
    Color {
        color: u8,
        channel: u8,
    },
}

impl Field {
    /// Every field of a segment, in dictionary order.
    pub fn all() -> impl Iterator<Item = Field> {
        let scalars = [
            Field::LedType,
            Field::LedCount,
            Field::Value,
            Field::MinValue,
            Field::MaxValue,
            Field::Speed,
            Field::Effect,
            Field::Smooth,
            Field::Dimmer,
        ];
        let colors =
            (1..=3).flat_map(|color| (1..=4).map(move |channel| Field::Color { color, channel }));
        scalars.into_iter().chain(colors)
    }

    /// The object's offset from the segment's base index, and its sub-index.
    pub fn offset(self) -> (u16, u8) {
        match self {
            Field::LedType => (0x00, 0),
            Field::LedCount => (0x01, 0),
            Field::Value => (0x10, 0),
            Field::MinValue => (0x11, 0),
            Field::MaxValue => (0x12, 0),
            Field::Speed => (0x13, 0),
            Field::Effect => (0x20, 0),
            Field::Smooth => (0x24, 0),
            Field::Dimmer => (0x25, 0),
            Field::Color { color, channel } => (0x2F + u16::from(color), channel),
        }
    }

    /// The field at an offset and sub-index, if the manual defines one there.
    /// Sub-index 0 of a colour (its entry count) is no field.
    pub fn at(offset: u16, sub: u8) -> Option<Field> {
        let field = match (offset, sub) {
            (0x00, 0) => Field::LedType,
            (0x01, 0) => Field::LedCount,
            (0x10, 0) => Field::Value,
            (0x11, 0) => Field::MinValue,
            (0x12, 0) => Field::MaxValue,
            (0x13, 0) => Field::Speed,
            (0x20, 0) => Field::Effect,
            (0x24, 0) => Field::Smooth,
            (0x25, 0) => Field::Dimmer,
            (0x30..=0x32, 1..=4) => Field::Color {
                color: (offset - 0x2F) as u8,
                channel: sub,
            },
            _ => return None,
        };
        Some(field)
    }

    /// The type of the field's object (manual §1.3, our EDS): what its
    /// value is encoded as on the wire.
    pub fn data_type(self) -> DataType {
        match self {
            Field::LedType | Field::Dimmer | Field::Color { .. } => DataType::Unsigned8,
            Field::LedCount | Field::Effect | Field::Smooth => DataType::Unsigned16,
            Field::Value | Field::MinValue | Field::MaxValue | Field::Speed => DataType::Integer16,
        }
    }

    /// The field's value in its object's bytes as the device sends them;
    /// `None` for bytes its type cannot hold (a short answer).
    pub fn value_in(self, data: &[u8]) -> Option<i64> {
        Value::from_bytes(self.data_type(), data)
            .ok()
            .and_then(|value| value.as_i128())
            .and_then(|value| i64::try_from(value).ok())
    }

    /// The manual's object name for segment `segment` (1–10), e.g.
    /// `s03_MinValue` or `s01_Color_02`.
    pub fn object_name(self, segment: u8) -> String {
        let name = match self {
            Field::LedType => "Led_type",
            Field::LedCount => "Led_count",
            Field::Value => "Value",
            Field::MinValue => "MinValue",
            Field::MaxValue => "MaxValue",
            Field::Speed => "Speed",
            Field::Effect => "Effect",
            Field::Smooth => "Smooth",
            Field::Dimmer => "Dimmer",
            Field::Color { color, .. } => return format!("s{segment:02}_Color_{color:02}"),
        };
        format!("s{segment:02}_{name}")
    }
}

/// The index and sub-index of `field` of segment `segment` (1–10), or
/// `None` for a segment the UIO1LED does not have.
pub fn address(segment: u8, field: Field) -> Option<(u16, u8)> {
    if !(1..=SEGMENTS).contains(&segment) {
        return None;
    }
    let (offset, sub) = field.offset();
    Some((segment_base(segment) + offset, sub))
}

/// The segment (1–10) and field an index and sub-index address, if any.
pub fn locate(index: u16, sub: u8) -> Option<(u8, Field)> {
    let relative = index.checked_sub(FIRST_SEGMENT)?;
    let segment = relative / SEGMENT_STRIDE + 1;
    if segment > u16::from(SEGMENTS) {
        return None;
    }
    let field = Field::at(relative % SEGMENT_STRIDE, sub)?;
    Some((segment as u8, field))
}

fn segment_base(segment: u8) -> u16 {
    FIRST_SEGMENT + SEGMENT_STRIDE * (u16::from(segment) - 1)
}

impl Segment {
    /// The value of `field`, widened to `i64` as an SDO or PDO carries it.
    pub fn get(&self, field: Field) -> i64 {
        match field {
            Field::LedType => self.led_type.into(),
            Field::LedCount => self.led_count.into(),
            Field::Value => self.value.into(),
            Field::MinValue => self.min_value.into(),
            Field::MaxValue => self.max_value.into(),
            Field::Speed => self.speed.into(),
            Field::Effect => self.effect.raw().into(),
            Field::Smooth => self.smooth.into(),
            Field::Dimmer => self.dimmer.into(),
            Field::Color { color, channel } => self
                .colors
                .get(usize::from(color).wrapping_sub(1))
                .and_then(|rgbw| rgbw.channel(channel))
                .map_or(0, i64::from),
        }
    }

    /// Sets `field` to `value`; false, and nothing changed, if the value
    /// does not fit the object's type (the dictionary's range check should
    /// have refused it first) or the field is no field of a segment.
    pub fn set(&mut self, field: Field, value: i64) -> bool {
        fn fit<T: TryFrom<i64>>(slot: &mut T, value: i64) -> bool {
            match T::try_from(value) {
                Ok(value) => {
                    *slot = value;
                    true
                }
                Err(_) => false,
            }
        }
        match field {
            Field::LedType => fit(&mut self.led_type, value),
            Field::LedCount => fit(&mut self.led_count, value),
            Field::Value => fit(&mut self.value, value),
            Field::MinValue => fit(&mut self.min_value, value),
            Field::MaxValue => fit(&mut self.max_value, value),
            Field::Speed => fit(&mut self.speed, value),
            Field::Effect => match u16::try_from(value) {
                Ok(raw) => {
                    self.effect = Effect::from_raw(raw);
                    true
                }
                Err(_) => false,
            },
            Field::Smooth => fit(&mut self.smooth, value),
            Field::Dimmer => fit(&mut self.dimmer, value),
            Field::Color { color, channel } => {
                let Ok(value) = u8::try_from(value) else {
                    return false;
                };
                match self.colors.get_mut(usize::from(color).wrapping_sub(1)) {
                    Some(rgbw) => rgbw.set_channel(channel, value),
                    None => false,
                }
            }
        }
    }
}
