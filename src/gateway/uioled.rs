//! A UIO1LED's segments over SDO (UIOLed firmware manual §1.2–§1.3): the
//! parameters of segment n read from, and written to, the objects at
//! 0x6000 + 0x100 × (n − 1) that [`crate::profiles::uioled::objects`] names.
//!
//! What the strip shows is drawn by the one renderer of
//! [`crate::profiles::uioled`] from the parameters read here, as the
//! virtual UIO1LED draws it from its own.

use crate::canopen::od::{DataType, Value};
use crate::gateway::sdo::{SdoChannel, SdoRequestError};
use crate::profiles::uioled::{Field, Rgbw, SEGMENTS, Segment, address};

/// The type of each field's object (manual §1.3, our EDS): what its value is
/// encoded as on the wire.
pub fn data_type(field: Field) -> DataType {
    match field {
        Field::LedType | Field::Dimmer | Field::Color { .. } => DataType::Unsigned8,
        Field::LedCount | Field::Effect | Field::Smooth => DataType::Unsigned16,
        Field::Value | Field::MinValue | Field::MaxValue | Field::Speed => DataType::Integer16,
    }
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
        let Some((index, sub)) = address(segment, field) else {
            continue;
        };
        let raw = channel.upload(index, sub).await?;
        // A value the type cannot hold (a short answer) keeps the default:
        // the raw bytes of a broken answer are no state of the strip.
        if let Some(value) = Value::from_bytes(data_type(field), &raw)
            .ok()
            .and_then(|value| value.as_i128())
            .and_then(|value| i64::try_from(value).ok())
        {
            state.set(field, value);
        }
    }
    Ok(state)
}

/// Reads every segment, segment 1 first: the summary of a UIO1LED node.
pub async fn read_segments(channel: &SdoChannel) -> Result<Vec<Segment>, SdoRequestError> {
    let mut segments = Vec::with_capacity(usize::from(SEGMENTS));
    for segment in 1..=SEGMENTS {
        segments.push(read_segment(channel, segment).await?);
    }
    Ok(segments)
}

/// Writes `fields` of segment `segment` in the order given; values are
/// checked by the caller ([`fits`]). Stops at the first failure.
pub async fn write_fields(
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

/// The strip as it shows now: every LED, segment 1's first, drawn from
/// `segments` as just read (time 0 of the renderer: the Values read are
/// the Values of now).
pub fn preview(segments: &[Segment]) -> Vec<Rgbw> {
    crate::profiles::uioled::render(segments, 0)
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
