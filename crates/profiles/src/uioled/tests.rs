//! Each effect at chosen times, the strip layout, the dimmer, Value's
//! bounds, the segment objects against our EDS, and a renderer that never
//! panics.

use proptest::prelude::*;

use super::*;
use crate::builtin;
use crate::canopen::eds::Eds;

const RED: Rgbw = Rgbw::new(255, 0, 0, 0);
const GREEN: Rgbw = Rgbw::new(0, 255, 0, 0);
const BLUE: Rgbw = Rgbw::new(0, 0, 255, 0);

fn segment(led_count: u16, effect: Effect) -> Segment {
    Segment {
        led_count,
        effect,
        colors: [RED, GREEN, BLUE],
        ..Segment::default()
    }
}

#[test]
fn effects_have_the_wire_values_of_table_1_2() {
    let effects = [
        (Effect::Off, 0x0000, "OFF"),
        (Effect::Fix, 0x0001, "FIX"),
        (Effect::Flash, 0x0101, "FLASH"),
        (Effect::Breathing, 0x0102, "BREATHING"),
        (Effect::Flow, 0x0300, "FLOW"),
        (Effect::FlowReversed, 0x0301, "FLOW_REVERSED"),
    ];
    for (effect, raw, name) in effects {
        assert_eq!(effect.raw(), raw);
        assert_eq!(Effect::from_raw(raw), effect);
        assert_eq!(effect.name(), name);
    }
    assert_eq!(Effect::from_raw(0x0200), Effect::Unknown(0x0200));
    assert_eq!(Effect::Unknown(0x0200).raw(), 0x0200);
}

#[test]
fn off_and_unknown_effects_are_dark() {
    for effect in [Effect::Off, Effect::Unknown(0x1234)] {
        let segment = segment(4, effect);
        assert_eq!(segment.render_at(0), vec![Rgbw::BLACK; 4]);
        assert_eq!(segment.render_at(12_345), vec![Rgbw::BLACK; 4]);
    }
}

#[test]
fn fix_shows_colour_1_at_any_time() {
    let segment = Segment {
        speed: 7,
        ..segment(3, Effect::Fix)
    };
    for t in [0, 1, 999, u64::MAX] {
        assert_eq!(segment.render_at(t), vec![RED; 3]);
    }
}

#[test]
fn flash_alternates_colours_1_and_2_as_value_passes_its_range() {
    // Value 0..=99 at 1 per ms: colour 1 for 50 ms, colour 2 for 50 ms.
    let flash = Segment {
        max_value: 99,
        speed: 1,
        ..segment(2, Effect::Flash)
    };
    assert_eq!(flash.render_at(0), vec![RED; 2]);
    assert_eq!(flash.render_at(49), vec![RED; 2]);
    assert_eq!(flash.render_at(50), vec![GREEN; 2]);
    assert_eq!(flash.render_at(99), vec![GREEN; 2]);
    assert_eq!(flash.render_at(100), vec![RED; 2]);
    // Written directly, Value picks the colour.
    let written = Segment {
        value: 20_000,
        ..segment(1, Effect::Flash)
    };
    assert_eq!(written.render_at(0), vec![GREEN]);
}

#[test]
fn breathing_follows_value_from_min_to_max() {
    let breathing = Segment {
        max_value: 100,
        speed: 10,
        ..segment(2, Effect::Breathing)
    };
    assert_eq!(breathing.render_at(0), vec![Rgbw::BLACK; 2]);
    assert_eq!(breathing.render_at(5), vec![Rgbw::new(128, 0, 0, 0); 2]);
    assert_eq!(breathing.render_at(10), vec![RED; 2]);
    // 110 is past MaxValue 100: Value starts over from MinValue (9).
    assert_eq!(breathing.value_at(11), 9);
    assert_eq!(breathing.render_at(11), vec![Rgbw::new(23, 0, 0, 0); 2]);
}

#[test]
fn flow_moves_one_led_of_colour_1_along_the_segment() {
    let flow = Segment {
        max_value: 4,
        speed: 1,
        ..segment(5, Effect::Flow)
    };
    for t in 0..10u64 {
        let pixels = flow.render_at(t);
        let head = (t % 5) as usize;
        for (led, pixel) in pixels.iter().enumerate() {
            let expected = if led == head { RED } else { GREEN };
            assert_eq!(*pixel, expected, "t {t} led {led}");
        }
    }
}

#[test]
fn flow_reversed_moves_the_other_way() {
    let forward = Segment {
        max_value: 4,
        speed: 1,
        ..segment(5, Effect::Flow)
    };
    let reversed = Segment {
        effect: Effect::FlowReversed,
        ..forward
    };
    for t in 0..10 {
        let mut mirrored = forward.render_at(t);
        mirrored.reverse();
        assert_eq!(reversed.render_at(t), mirrored);
    }
    assert_eq!(reversed.render_at(1)[3], RED);
}

#[test]
fn smooth_fades_the_leds_behind_the_flow_head() {
    let flow = Segment {
        value: 2,
        max_value: 4,
        smooth: 2,
        colors: [Rgbw::new(255, 0, 0, 0), Rgbw::BLACK, Rgbw::BLACK],
        ..segment(5, Effect::Flow)
    };
    let reds: Vec<u8> = flow.render_at(0).iter().map(|pixel| pixel.r).collect();
    // Head at 2, then 2/3 and 1/3 of colour 1 behind it, the rest colour 2.
    assert_eq!(reds, [85, 170, 255, 0, 0]);
    // The tail wraps round the segment's start.
    let at_start = Segment { value: 0, ..flow };
    let reds: Vec<u8> = at_start.render_at(0).iter().map(|pixel| pixel.r).collect();
    assert_eq!(reds, [255, 0, 0, 85, 170]);
}

#[test]
fn segments_lie_end_to_end_as_in_the_manuals_example() {
    // §1.1: the first 10 LEDs red, the next 5 green.
    let segments = [
        segment(10, Effect::Fix),
        Segment {
            colors: [GREEN, Rgbw::BLACK, Rgbw::BLACK],
            ..segment(5, Effect::Fix)
        },
    ];
    let pixels = render(&segments, 0);
    assert_eq!(pixels.len(), 15);
    assert_eq!(pixels[..10], [RED; 10]);
    assert_eq!(pixels[10..], [GREEN; 5]);
    assert_eq!(layout(&segments), vec![0..10, 10..15]);
}

#[test]
fn an_empty_segment_takes_no_place() {
    let segments = [
        segment(2, Effect::Fix),
        segment(0, Effect::Flow),
        Segment::default(),
        Segment {
            colors: [BLUE; 3],
            ..segment(1, Effect::Fix)
        },
    ];
    assert_eq!(render(&segments, 3), vec![RED, RED, BLUE]);
    assert_eq!(layout(&segments), vec![0..2, 2..2, 2..2, 2..3]);
    assert_eq!(led_count(&segments), 3);
    assert!(render(&[], 0).is_empty());
}

#[test]
fn dimmer_scales_every_channel_of_the_segment() {
    let colour = Rgbw::new(255, 128, 10, 200);
    let dimmed = |dimmer| {
        Segment {
            dimmer,
            colors: [colour; 3],
            ..segment(2, Effect::Fix)
        }
        .render_at(0)
    };
    assert_eq!(dimmed(255), vec![colour; 2]);
    assert_eq!(dimmed(128), vec![Rgbw::new(128, 64, 5, 100); 2]);
    assert_eq!(dimmed(0), vec![Rgbw::BLACK; 2]);
    // Only its own segment.
    let segments = [
        Segment {
            dimmer: 0,
            ..segment(1, Effect::Fix)
        },
        segment(1, Effect::Fix),
    ];
    assert_eq!(render(&segments, 0), vec![Rgbw::BLACK, RED]);
}

#[test]
fn value_stays_within_min_and_max_while_speed_is_set() {
    let rising = Segment {
        value: 0,
        min_value: -10,
        max_value: 10,
        speed: 3,
        ..Segment::default()
    };
    assert_eq!(rising.value_at(0), 0);
    assert_eq!(rising.value_at(3), 9);
    assert_eq!(rising.value_at(4), -9); // 12 is 2 past 10: -10, then -9.
    let falling = Segment {
        speed: -3,
        ..rising
    };
    assert_eq!(falling.value_at(3), -9);
    assert_eq!(falling.value_at(4), 9);
    // Far in the future, and with the bounds written the wrong way round.
    let swapped = Segment {
        min_value: 10,
        max_value: -10,
        speed: i16::MIN,
        ..rising
    };
    for t in [u64::MAX, u64::MAX / 3, 1 << 40] {
        assert!((-10..=10).contains(&swapped.value_at(t)));
    }
    // With speed 0 Value is as written, even outside the bounds.
    let still = Segment {
        value: 500,
        speed: 0,
        ..rising
    };
    assert_eq!(still.value_at(1_000), 500);
    assert_eq!(still.level_at(1_000), 255);
}

#[test]
fn defaults_are_those_of_our_eds() {
    let eds = Eds::parse(builtin::UIO1LED, "uio1led.eds").unwrap();
    let defaults = Segment::default();
    for number in 1..=SEGMENTS {
        for field in Field::all() {
            let (index, sub) = address(number, field).unwrap();
            let object = eds.dictionary.get(index).unwrap();
            assert_eq!(object.name, field.object_name(number));
            let entry = object.sub(sub).unwrap();
            let default = entry.default_value(None).unwrap().unwrap();
            assert_eq!(
                default.as_i128(),
                Some(i128::from(defaults.get(field))),
                "{}",
                field.object_name(number)
            );
            assert_eq!(locate(index, sub), Some((number, field)));
        }
    }
}

#[test]
fn segment_n_is_at_0x6000_plus_0x100_per_segment() {
    assert_eq!(address(1, Field::LedCount), Some((0x6001, 0)));
    assert_eq!(address(2, Field::Effect), Some((0x6120, 0)));
    let blue_of_colour_3 = Field::Color {
        color: 3,
        channel: 3,
    };
    assert_eq!(address(10, blue_of_colour_3), Some((0x6932, 3)));
    assert_eq!(address(0, Field::Value), None);
    assert_eq!(address(11, Field::Value), None);
    assert_eq!(locate(0x6030, 0), None);
    assert_eq!(locate(0x6014, 0), None);
    assert_eq!(locate(0x6A01, 0), None);
    assert_eq!(locate(0x5FFF, 0), None);
    assert_eq!(locate(0x6325, 0), Some((4, Field::Dimmer)));
    assert_eq!(Field::all().count(), 9 + 3 * 4);
    assert_eq!(Field::Speed.object_name(7), "s07_Speed");
    assert_eq!(blue_of_colour_3.object_name(10), "s10_Color_03");
}

#[test]
fn fields_are_set_and_read_as_the_wire_carries_them() {
    let mut segment = Segment::default();
    for (field, value) in [
        (Field::LedCount, 300),
        (Field::Value, -5),
        (Field::Effect, 0x0301),
        (Field::Dimmer, 17),
        (
            Field::Color {
                color: 2,
                channel: 4,
            },
            99,
        ),
    ] {
        assert!(segment.set(field, value));
        assert_eq!(segment.get(field), value);
    }
    assert_eq!(segment.effect, Effect::FlowReversed);
    assert_eq!(segment.colors[1].w, 99);
    assert!(!segment.set(Field::Dimmer, 256));
    assert!(!segment.set(Field::LedCount, -1));
    assert!(!segment.set(
        Field::Color {
            color: 4,
            channel: 1
        },
        1
    ));
    assert_eq!(segment.dimmer, 17);
}

#[test]
fn value_at_is_the_one_millisecond_steps() {
    // Bounds that Speed does not divide, a negative speed, and a Value
    // written outside the bounds (wrapped in by the first step).
    let moving = [
        Segment {
            value: 3,
            min_value: -7,
            max_value: 12,
            speed: 6,
            ..Segment::default()
        },
        Segment {
            value: 100,
            min_value: -7,
            max_value: 12,
            speed: -5,
            ..Segment::default()
        },
        Segment {
            value: i16::MIN,
            min_value: i16::MIN,
            max_value: i16::MAX,
            speed: i16::MAX,
            ..Segment::default()
        },
    ];
    for segment in moving {
        let mut stepped = segment;
        for t in 1..=1_000u64 {
            let (low, high) = segment.bounds();
            // What a firmware loop does each millisecond: add, then wrap.
            let sum = i64::from(stepped.value) + i64::from(stepped.speed);
            let span = i64::from(high) - i64::from(low) + 1;
            let next = i64::from(low) + (sum - i64::from(low)).rem_euclid(span);
            stepped.value = next as i16;
            assert_eq!(segment.value_at(t), stepped.value, "{segment:?} at {t}");
        }
    }
    // At 0 nothing has moved yet, even outside the bounds.
    assert_eq!(moving[1].value_at(0), 100);
    // 95 is 83 past 12: four spans of 20, then 3 past MaxValue: -7, -6, -5.
    assert_eq!(moving[1].value_at(1), -5);
}

#[test]
fn value_at_far_in_the_future_matches_exact_arithmetic() {
    let segment = Segment {
        value: 1_234,
        min_value: -30_000,
        max_value: 29_999,
        speed: -32_768,
        ..Segment::default()
    };
    for t in [u64::MAX, u64::MAX - 1, 1 << 63, 987_654_321_987] {
        let exact = -30_000 + (31_234 + -32_768 * i128::from(t)).rem_euclid(60_000);
        assert_eq!(i128::from(segment.value_at(t)), exact, "t {t}");
    }
}

fn any_rgbw() -> impl Strategy<Value = Rgbw> {
    any::<[u8; 4]>().prop_map(|[r, g, b, w]| Rgbw::new(r, g, b, w))
}

fn any_segment() -> impl Strategy<Value = Segment> {
    (
        (
            any::<u8>(),
            0..300u16,
            any::<i16>(),
            any::<i16>(),
            any::<i16>(),
        ),
        (any::<i16>(), any::<u16>(), any::<u16>(), any::<u8>()),
        [any_rgbw(), any_rgbw(), any_rgbw()],
    )
        .prop_map(
            |(
                (led_type, led_count, value, min_value, max_value),
                (speed, effect, smooth, dimmer),
                colors,
            )| Segment {
                led_type,
                led_count,
                value,
                min_value,
                max_value,
                speed,
                // Mostly the effects the manual defines.
                effect: Effect::from_raw(match effect % 8 {
                    0 => 0x0000,
                    1 => 0x0001,
                    2 => 0x0101,
                    3 => 0x0102,
                    4 => 0x0300,
                    5 => 0x0301,
                    _ => effect,
                }),
                smooth,
                dimmer,
                colors,
            },
        )
}

proptest! {
    #[test]
    fn value_steps_compose(
        segment in any_segment(),
        first in 0..u64::MAX / 2,
        then in 0..u64::MAX / 2,
    ) {
        let later = Segment { value: segment.value_at(first), ..segment };
        prop_assert_eq!(later.value_at(then), segment.value_at(first + then));
    }

    #[test]
    fn rendering_never_panics_and_gives_every_led(
        segments in prop::collection::vec(any_segment(), 0..12),
        t_ms in any::<u64>(),
    ) {
        let pixels = render(&segments, t_ms);
        prop_assert_eq!(pixels.len(), led_count(&segments));
        for (segment, range) in segments.iter().zip(layout(&segments)) {
            let (low, high) = segment.bounds();
            if segment.speed != 0 && t_ms > 0 {
                prop_assert!((low..=high).contains(&segment.value_at(t_ms)));
            }
            if segment.dimmer == 0 {
                prop_assert!(pixels[range].iter().all(|pixel| *pixel == Rgbw::BLACK));
            }
        }
    }
}

#[test]
fn a_fields_value_is_read_from_its_objects_bytes_by_its_type() {
    assert_eq!(Field::Value.value_in(&[0x18, 0xFC]), Some(-1000));
    assert_eq!(Field::Effect.value_in(&[0x04, 0x00]), Some(4));
    assert_eq!(Field::Dimmer.value_in(&[200]), Some(200));
    let red = Field::Color {
        color: 1,
        channel: 1,
    };
    assert_eq!(red.value_in(&[0xFF]), Some(255));
    // A short answer, or one too long for the type: no value.
    assert_eq!(Field::Speed.value_in(&[0x01]), None);
    assert_eq!(Field::Dimmer.value_in(&[1, 2]), None);
}
