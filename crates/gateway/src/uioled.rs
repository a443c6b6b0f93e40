//! A UIO1LED's segments over SDO (UIOLed firmware manual §1.2–§1.3): the
//! parameters of segment n read from, and written to, the objects at
//! 0x6000 + 0x100 × (n − 1) that [`crate::profiles::uioled::objects`] names.
//!
//! What the strip shows is drawn by the one renderer of
//! [`crate::profiles::uioled`] from the parameters read here, as the
//! virtual UIO1LED draws it from its own: [`Preview`] is what
//! `GET .../segments/preview` answers and the `segments` topic publishes
//! ([`super::led_preview`]).

use serde::{Deserialize, Serialize};
use tokio::time::Instant;

use crate::canopen::od::{DataType, Value};
use crate::profiles::uioled::{Effect, Field, Rgbw, SEGMENTS, Segment, address};
use crate::sdo::{SdoChannel, SdoRequestError};

/// The type of each field's object: what its value is encoded as on the
/// wire (the profile's, [`Field::data_type`]).
pub(crate) fn data_type(field: Field) -> DataType {
    field.data_type()
}

/// The fields a segment's state is read from: every field but `Led_type`,
/// which firmware 1.0.x ignores and the API does not show.
fn shown_fields() -> impl Iterator<Item = Field> {
    Field::all().filter(|field| *field != Field::LedType)
}

/// Whether `value` fits `field`'s object.
pub fn fits(field: Field, value: i64) -> bool {
    Value::from_i128(data_type(field), i128::from(value)).is_ok()
}

/// The valid segments, 1 to [`SEGMENTS`].
pub fn is_segment(segment: u8) -> bool {
    (1..=SEGMENTS).contains(&segment)
}

/// Reads segment `segment`'s parameters (not `Led_type`, which stays 0).
/// The caller checks the segment number ([`is_segment`]).
pub async fn read_segment(channel: &SdoChannel, segment: u8) -> Result<Segment, SdoRequestError> {
    let mut state = Segment::default();
    for field in shown_fields() {
        read_field(channel, segment, field, &mut state).await?;
    }
    Ok(state)
}

/// Reads every segment, segment 1 first: the summary of a UIO1LED node.
pub(crate) async fn read_segments(channel: &SdoChannel) -> Result<Vec<Segment>, SdoRequestError> {
    let mut segments = Vec::with_capacity(usize::from(SEGMENTS));
    for segment in 1..=SEGMENTS {
        segments.push(read_segment(channel, segment).await?);
    }
    Ok(segments)
}

/// Writes `fields` of segment `segment` in the order given; values are
/// checked by the caller ([`fits`]). Stops at the first failure.
pub(crate) async fn write_fields(
    channel: &SdoChannel,
    segment: u8,
    fields: &[(Field, i64)],
) -> Result<(), SdoRequestError> {
    for &(field, value) in fields {
        let Some((index, sub)) = address(segment, field) else {
            continue;
        };
        let Ok(value) = Value::from_i128(data_type(field), i128::from(value)) else {
            continue;
        };
        channel.download(index, sub, &value.to_bytes()).await?;
    }
    Ok(())
}

/// One colour: red, green, blue and white, 0 to 255 each.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Color {
    pub r: u8,
    pub g: u8,
    pub b: u8,
    pub w: u8,
}

impl From<Rgbw> for Color {
    fn from(rgbw: Rgbw) -> Self {
        Color {
            r: rgbw.r,
            g: rgbw.g,
            b: rgbw.b,
            w: rgbw.w,
        }
    }
}

/// The API name of an effect.
pub fn effect_name(effect: Effect) -> String {
    match effect {
        Effect::Unknown(raw) => format!("0x{raw:04X}"),
        known => known.name().to_lowercase(),
    }
}

/// What the strip shows now.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Preview {
    /// LEDs on the strip: the sum of every segment's.
    pub led_count: usize,
    /// Where each segment's LEDs are in `pixels`.
    pub segments: Vec<PreviewSegment>,
    /// Every LED, the first of segment 1 first, dimmer applied.
    pub pixels: Vec<Color>,
}

/// One segment's place on the strip.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PreviewSegment {
    pub segment: u8,
    /// Its first LED in `pixels`.
    pub start: usize,
    pub led_count: u16,
    pub effect: String,
}

/// A segment's parameters as read for the preview, with when its Value
/// was read: Speed moves Value on from there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ReadSegment {
    pub segment: Segment,
    pub read_at: Instant,
}

/// Reads what the preview needs of every segment, segment 1 first: the
/// whole segment when it has LEDs, else only its LED count and effect (the
/// rest draws nothing), which spares most transfers on a strip that uses a
/// few segments.
pub(crate) async fn read_preview(
    channel: &SdoChannel,
) -> Result<Vec<ReadSegment>, SdoRequestError> {
    let mut segments = Vec::with_capacity(usize::from(SEGMENTS));
    for segment in 1..=SEGMENTS {
        let mut state = Segment::default();
        read_field(channel, segment, Field::LedCount, &mut state).await?;
        let mut read_at = Instant::now();
        if state.led_count == 0 {
            read_field(channel, segment, Field::Effect, &mut state).await?;
        } else {
            for field in shown_fields().filter(|field| *field != Field::LedCount) {
                read_field(channel, segment, field, &mut state).await?;
                if field == Field::Value {
                    read_at = Instant::now();
                }
            }
        }
        segments.push(ReadSegment {
            segment: state,
            read_at,
        });
    }
    Ok(segments)
}

/// Reads one field of a segment into `state`. A value the type cannot hold
/// (a short answer) keeps the default: the raw bytes of a broken answer are
/// no state of the strip.
async fn read_field(
    channel: &SdoChannel,
    segment: u8,
    field: Field,
    state: &mut Segment,
) -> Result<(), SdoRequestError> {
    let Some((index, sub)) = address(segment, field) else {
        return Ok(());
    };
    let raw = channel.upload(index, sub).await?;
    if let Some(value) = field.value_in(&raw) {
        state.set(field, value);
    }
    Ok(())
}

/// The strip at `now`: every LED, segment 1's first, each segment drawn by
/// the renderer of [`crate::profiles::uioled`] as far past its read as
/// `now` is (a segment read just now shows the Values read).
pub(crate) fn preview(segments: &[ReadSegment], now: Instant) -> Preview {
    let mut pixels = Vec::new();
    let mut places = Vec::with_capacity(segments.len());
    for (number, read) in (1..=SEGMENTS).zip(segments) {
        let t_ms = u64::try_from(now.saturating_duration_since(read.read_at).as_millis())
            .unwrap_or(u64::MAX);
        places.push(PreviewSegment {
            segment: number,
            start: pixels.len(),
            led_count: read.segment.led_count,
            effect: effect_name(read.segment.effect),
        });
        pixels.extend(read.segment.render_at(t_ms).into_iter().map(Color::from));
    }
    Preview {
        led_count: pixels.len(),
        segments: places,
        pixels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_field_has_the_type_of_its_object_in_our_eds() {
        let eds =
            crate::canopen::eds::Eds::parse(crate::profiles::builtin::UIO1LED, "uio1led").unwrap();
        for segment in [1, 10] {
            for field in Field::all() {
                let (index, sub) = address(segment, field).unwrap();
                let described = eds.dictionary.sub(index, sub).unwrap();
                assert_eq!(described.data_type, data_type(field), "{index:04X}sub{sub}");
            }
        }
        assert!(fits(Field::Dimmer, 255) && !fits(Field::Dimmer, 256));
        assert!(fits(Field::Speed, -5) && !fits(Field::LedCount, -1));
    }
}
