//! A monitored variable's values from the gateway's samples of its
//! objects, sans I/O.

use std::time::SystemTime;

use super::*;

/// A sample of `object`: `data`, read over SDO unless `carried`.
fn sample(object: Entry, data: Result<&[u8], GatewayError>, carried: bool) -> ObjectSample {
    ObjectSample {
        object,
        data: data.map(<[u8]>::to_vec),
        slowed: false,
        carried,
        at: SystemTime::now(),
    }
}

/// By its length, as an EDS would type it.
fn decode(entry: Entry, data: &[u8]) -> Result<Variant, GatewayError> {
    match *data {
        [byte] => Ok(Variant::Byte(byte)),
        [low, high] => Ok(Variant::UInt16(u16::from_le_bytes([low, high]))),
        [a, b, c, d] => Ok(Variant::Int32(i32::from_le_bytes([a, b, c, d]))),
        _ => Err(GatewayError::InvalidValue(format!("{entry:?}: {data:?}"))),
    }
}

/// The values `samples` send for `watched`, in order.
fn sent(variable: &mut Variable, watched: Watched, samples: &[ObjectSample]) -> Vec<DataValue> {
    samples
        .iter()
        .filter_map(|sample| variable.take(watched, sample, &decode))
        .collect()
}

fn values(sent: &[DataValue]) -> Vec<Variant> {
    sent.iter()
        .filter_map(|value| value.value.clone())
        .collect()
}

fn channel(name: &str) -> Watched {
    Watched::Channel(Channel::parse(name).unwrap())
}

fn led(segment: u8, field: LedField) -> Watched {
    Watched::Led { segment, field }
}

#[test]
fn a_variable_is_sent_when_its_value_changes_and_a_slowed_one_says_overload() {
    let entry = (0x1017, 0);
    let watched = Watched::Entry(entry);
    let mut variable = Variable::default();
    let mut slowed = sample(entry, Ok(&500u16.to_le_bytes()), false);
    slowed.slowed = true;
    let out = sent(
        &mut variable,
        watched,
        &[
            sample(entry, Ok(&500u16.to_le_bytes()), false),
            sample(entry, Ok(&500u16.to_le_bytes()), false),
            slowed,
            sample(entry, Ok(&1000u16.to_le_bytes()), false),
            // Another object's sample is not this variable's.
            sample((0x1018, 1), Ok(&[1, 2, 3, 4]), false),
        ],
    );
    assert_eq!(
        values(&out),
        vec![
            Variant::UInt16(500),
            Variant::UInt16(500),
            Variant::UInt16(1000)
        ]
    );
    let statuses: Vec<StatusCode> = out.iter().map(DataValue::status).collect();
    assert_eq!(
        statuses,
        vec![StatusCode::Good, StatusCode::GoodOverload, StatusCode::Good]
    );
}

#[test]
fn a_failed_read_is_a_value_with_its_status_then_the_next_good_one() {
    let dimmer = led(3, LedField::Dimmer);
    let object = dimmer.objects()[0];
    let mut variable = Variable::default();
    let out = sent(
        &mut variable,
        dimmer,
        &[
            sample(object, Err(GatewayError::SdoTimeout { node: 3 }), false),
            sample(object, Err(GatewayError::SdoTimeout { node: 3 }), false),
            sample(object, Ok(&[42]), false),
        ],
    );
    assert_eq!(out.len(), 2, "{out:?}");
    assert_eq!(out[0].status(), StatusCode::BadTimeout);
    assert_eq!(out[1].value, Some(Variant::Byte(42)));
    assert_eq!(out[1].status(), StatusCode::Good);
}

#[test]
fn a_tpdo_carried_digital_input_sends_each_change_of_its_bit_and_nothing_for_the_others() {
    // di1 and di2: bits 0 and 1 of 0x6000 sub 1.
    let group = (0x6000, 1);
    assert_eq!(channel("di2").objects(), vec![group]);
    let frames: Vec<ObjectSample> = [
        0b0000_0000u8,
        0b0000_0001,
        0b0000_0011,
        0b0000_0011,
        0b1000_0001,
    ]
    .iter()
    .map(|byte| sample(group, Ok(&[*byte]), true))
    .collect();
    let (mut di1, mut di2) = (Variable::default(), Variable::default());
    // di2 changes at the third frame and the fifth: di1's change at the
    // second, the same byte again and bit 7 send nothing for it.
    assert_eq!(
        values(&sent(&mut di2, channel("di2"), &frames)),
        vec![
            Variant::Boolean(false),
            Variant::Boolean(true),
            Variant::Boolean(false)
        ]
    );
    assert_eq!(
        values(&sent(&mut di1, channel("di1"), &frames)),
        vec![Variant::Boolean(false), Variant::Boolean(true)]
    );
}

#[test]
fn an_analog_output_is_read_as_its_profile_says() {
    let ao1 = channel("ao1");
    assert_eq!(ao1.objects(), vec![(0x6411, 1)]);
    let mut variable = Variable::default();
    let out = sent(
        &mut variable,
        ao1,
        &[sample((0x6411, 1), Ok(&(-1000i16).to_le_bytes()), false)],
    );
    assert_eq!(values(&out), vec![Variant::Int16(-1000)]);
    // Bytes a channel cannot be read from: a bad status, not a value.
    let mut variable = Variable::default();
    let out = sent(&mut variable, ao1, &[sample((0x6411, 1), Ok(&[]), false)]);
    assert_eq!(out.len(), 1);
    assert!(out[0].status().is_bad(), "{out:?}");
    assert_eq!(out[0].value, None);
}

#[test]
fn a_colour_goes_out_whole_once_its_four_objects_were_read() {
    // Segment 1's Color_01 is 0x6030 sub 1 to 4 (red, green, blue, white).
    let colour = led(1, LedField::Color(1));
    assert_eq!(
        colour.objects(),
        vec![(0x6030, 1), (0x6030, 2), (0x6030, 3), (0x6030, 4)]
    );
    let round = |levels: [u8; 4]| -> Vec<ObjectSample> {
        (1..=4)
            .zip(levels)
            .map(|(sub, level)| sample((0x6030, sub), Ok(&[level]), false))
            .collect()
    };
    let mut variable = Variable::default();
    // Three of four read: nothing yet.
    assert!(sent(&mut variable, colour, &round([0x12, 0x34, 0x56, 0x78])[..3]).is_empty());
    let first = round([0x12, 0x34, 0x56, 0x78]);
    assert_eq!(
        values(&sent(&mut variable, colour, &first)),
        vec![Variant::String("#12345678".into())]
    );
    // A new green goes out with the round's last object, the same round
    // again sends nothing.
    let second = round([0x12, 0xFF, 0x56, 0x78]);
    assert_eq!(
        values(&sent(&mut variable, colour, &second)),
        vec![Variant::String("#12ff5678".into())]
    );
    assert!(sent(&mut variable, colour, &second).is_empty());
}

#[test]
fn an_item_that_joins_starts_with_the_value_last_sent_else_the_newest_samples() {
    let position = (0x6064, 0);
    let watched = Watched::Entry(position);
    // A new variable: the gateway's newest (a carrying TPDO's).
    let mut variable = Variable::default();
    let newest = [sample(position, Ok(&(-1100i32).to_le_bytes()), true)];
    let initial = variable.initial(watched, &newest, &decode);
    assert_eq!(
        initial.and_then(|value| value.value),
        Some(Variant::Int32(-1100))
    );
    // Which counts as sent: the same again sends nothing.
    assert!(sent(&mut variable, watched, &newest).is_empty());
    // Nothing sampled yet: no value.
    assert_eq!(Variable::default().initial(watched, &[], &decode), None);
    // A variable sent before: its value, whatever the newest says.
    let later = [sample(position, Ok(&7i32.to_le_bytes()), true)];
    let initial = variable.initial(watched, &later, &decode);
    assert_eq!(
        initial.and_then(|value| value.value),
        Some(Variant::Int32(-1100))
    );
}

#[test]
fn an_items_interval_is_its_own_or_the_subscriptions() {
    assert_eq!(interval_of(250.0), Duration::from_millis(250));
    assert_eq!(interval_of(0.0), Duration::ZERO);
    assert_eq!(interval_of(-1.0), SUBSCRIPTION_INTERVAL);
    assert_eq!(interval_of(f64::NAN), SUBSCRIPTION_INTERVAL);
}
