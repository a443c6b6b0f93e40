use super::*;
use crate::behaviour::RaisedEmcy;
use crate::canopen::NodeId;
use crate::canopen::eds::Eds;
use crate::canopen::nmt::NmtState;
use crate::canopen::od::Value;
use crate::canopen::sdo::ObjectAccess;
use crate::objects::ObjectStore;
use crate::profiles::builtin;
use crate::profiles::uioled::{Effect, layout};

const RED: Rgbw = Rgbw::new(255, 0, 0, 0);
const GREEN: Rgbw = Rgbw::new(0, 255, 0, 0);

fn color(color: u8, channel: u8) -> Field {
    Field::Color { color, channel }
}

/// A UIO1LED at node 3 with its store, on a simulation clock of its
/// own, in NMT operational.
struct Bench {
    store: ObjectStore,
    uioled: Uioled,
    sim_ms: u64,
    raised: Vec<RaisedEmcy>,
}

impl Bench {
    fn new() -> Self {
        let dictionary = Eds::parse(builtin::UIO1LED, "x").unwrap().dictionary;
        let store = ObjectStore::new(dictionary, NodeId::new(3).unwrap()).unwrap();
        let mut bench = Bench {
            store,
            uioled: Uioled::new(),
            sim_ms: 0,
            raised: Vec::new(),
        };
        bench.reset();
        bench
    }

    fn io(&mut self) -> DeviceIo<'_> {
        DeviceIo::new(
            &mut self.store,
            NmtState::Operational,
            self.sim_ms,
            &mut self.raised,
        )
    }

    fn reset(&mut self) {
        let mut uioled = std::mem::take(&mut self.uioled);
        uioled.reset(&mut self.io());
        self.uioled = uioled;
    }

    /// Writes `value` into the store as the bus does (with the
    /// dictionary's checks), without telling the behaviour.
    fn store_write(&mut self, segment: u8, field: Field, value: i64) {
        let (index, sub) = address(segment, field).unwrap();
        let data_type = self
            .store
            .dictionary()
            .get(index)
            .unwrap()
            .sub(sub)
            .unwrap()
            .data_type;
        let bytes = Value::from_i128(data_type, i128::from(value))
            .unwrap()
            .to_bytes();
        self.store.write(index, sub, &bytes).unwrap();
    }

    /// A write from the bus: the store, then the behaviour.
    fn write(&mut self, segment: u8, field: Field, value: i64) {
        self.store_write(segment, field, value);
        let (index, sub) = address(segment, field).unwrap();
        let mut uioled = std::mem::take(&mut self.uioled);
        uioled.written(&mut self.io(), index, sub);
        self.uioled = uioled;
    }

    /// `ms` ticks, one millisecond each, as the device core runs them.
    fn tick(&mut self, ms: u64) {
        let mut uioled = std::mem::take(&mut self.uioled);
        for _ in 0..ms {
            self.sim_ms += 1;
            uioled.tick(&mut self.io());
        }
        self.uioled = uioled;
    }

    /// Value as an SDO upload reads it.
    fn value(&mut self, segment: u8) -> i16 {
        let (index, sub) = address(segment, Field::Value).unwrap();
        let bytes = self.store.read(index, sub).unwrap();
        i16::from_le_bytes(bytes.try_into().unwrap())
    }

    fn segment(&self, segment: u8) -> Segment {
        self.uioled.segments()[usize::from(segment) - 1]
    }

    fn pixels(&self) -> Vec<Rgbw> {
        self.uioled.pixels(self.sim_ms)
    }

    /// The LEDs of segment `segment` alone.
    fn pixels_of(&self, segment: u8) -> Vec<Rgbw> {
        let range = layout(self.uioled.segments())[usize::from(segment) - 1].clone();
        self.pixels()[range].to_vec()
    }

    /// Segment `segment` with `led_count` LEDs, `effect`, colour 1 red
    /// and colour 2 green.
    fn light(&mut self, segment: u8, led_count: i64, effect: Effect) {
        self.write(segment, Field::LedCount, led_count);
        self.write(segment, Field::Effect, i64::from(effect.raw()));
        self.write(segment, color(1, 1), 255);
        self.write(segment, color(2, 2), 255);
    }

    /// Value moving from `value` by `speed` within `min..=max`.
    fn animate(&mut self, segment: u8, value: i64, min: i64, max: i64, speed: i64) {
        self.write(segment, Field::MinValue, min);
        self.write(segment, Field::MaxValue, max);
        self.write(segment, Field::Value, value);
        self.write(segment, Field::Speed, speed);
    }
}

#[test]
fn reset_reads_every_segment_from_the_store() {
    let mut bench = Bench::new();
    // The EDS defaults are the segment defaults.
    assert_eq!(bench.uioled.segments(), [Segment::default(); 10]);
    // Values saved before a reset (as 0x1010 keeps them) come back.
    bench.store_write(7, Field::LedCount, 12);
    bench.store_write(7, Field::Effect, 0x0300);
    bench.store_write(7, Field::Value, -40);
    bench.store_write(7, Field::MinValue, -50);
    bench.store_write(7, Field::MaxValue, 50);
    bench.store_write(7, Field::Speed, -2);
    bench.store_write(7, Field::Smooth, 3);
    bench.store_write(7, Field::Dimmer, 90);
    bench.store_write(7, color(3, 4), 77);
    bench.store_write(10, Field::LedType, 2);
    bench.reset();
    let expected = Segment {
        led_count: 12,
        effect: Effect::Flow,
        value: -40,
        min_value: -50,
        max_value: 50,
        speed: -2,
        smooth: 3,
        dimmer: 90,
        colors: [Rgbw::BLACK, Rgbw::BLACK, Rgbw::new(0, 0, 0, 77)],
        ..Segment::default()
    };
    assert_eq!(bench.segment(7), expected);
    assert_eq!(bench.segment(10).led_type, 2);
    assert_eq!(bench.segment(6), Segment::default());
    // And the speed controller runs from them.
    bench.tick(3);
    assert_eq!(bench.value(7), -46);
}

#[test]
fn speed_is_added_to_value_every_millisecond() {
    let mut bench = Bench::new();
    bench.animate(1, 10, 0, 1_000, 3);
    assert_eq!(bench.value(1), 10);
    bench.tick(1);
    assert_eq!(bench.value(1), 13);
    bench.tick(9);
    assert_eq!(bench.value(1), 40);
    assert_eq!(bench.segment(1).value, 40);
    // Other segments stay as they were.
    assert_eq!(bench.value(2), 0);
}

#[test]
fn past_max_value_goes_on_from_min_value_and_back_for_a_negative_speed() {
    let mut bench = Bench::new();
    bench.animate(1, 0, -10, 10, 3);
    bench.animate(10, 0, -10, 10, -3);
    bench.tick(3);
    assert_eq!((bench.value(1), bench.value(10)), (9, -9));
    bench.tick(1);
    // 12 is 2 past 10: -10, then -9 (and the mirror image).
    assert_eq!((bench.value(1), bench.value(10)), (-9, 9));
    // Never outside the bounds, and where the renderer puts it.
    let rising_as_written = Segment {
        value: 0,
        min_value: -10,
        max_value: 10,
        speed: 3,
        ..Segment::default()
    };
    for t in 5..=500 {
        bench.tick(1);
        let value = bench.value(1);
        assert!((-10..=10).contains(&value), "{value} at {t}");
        assert_eq!(value, rising_as_written.value_at(t));
        assert!((-10..=10).contains(&bench.value(10)));
    }
}

#[test]
fn the_speed_controller_runs_under_every_effect() {
    let effects = [
        Effect::Off,
        Effect::Fix,
        Effect::Flash,
        Effect::Breathing,
        Effect::Flow,
        Effect::FlowReversed,
    ];
    let mut bench = Bench::new();
    for (number, effect) in (1..).zip(effects) {
        bench.light(number, 4, effect);
        bench.animate(number, 0, 0, 99, 7);
    }
    bench.tick(20);
    for number in 1..=6 {
        // 7 × 20 is 140, which wraps to 40 in 0..=99.
        assert_eq!(bench.value(number), 40);
    }
}

#[test]
fn each_effect_draws_value_within_min_and_max() {
    let mut bench = Bench::new();
    // FLASH: first half of the range colour 1, second half colour 2.
    bench.light(1, 2, Effect::Flash);
    bench.animate(1, 0, 0, 99, 1);
    // BREATHING: colour 1 from dark at MinValue to full at MaxValue.
    bench.light(2, 1, Effect::Breathing);
    bench.animate(2, 0, 0, 100, 10);
    // FLOW: one LED of colour 1 at Value's place along the segment.
    bench.light(3, 5, Effect::Flow);
    bench.light(4, 5, Effect::FlowReversed);
    bench.animate(3, 0, 0, 4, 1);
    bench.animate(4, 0, 0, 4, 1);
    for t in 0..=100 {
        let flash = if t % 100 < 50 { RED } else { GREEN };
        assert_eq!(bench.pixels_of(1), [flash; 2], "FLASH at {t}");
        let head = t % 5;
        for led in 0..5 {
            let forward = if led == head { RED } else { GREEN };
            let reversed = if led == 4 - head { RED } else { GREEN };
            assert_eq!(bench.pixels_of(3)[led], forward, "FLOW at {t}, LED {led}");
            assert_eq!(
                bench.pixels_of(4)[led],
                reversed,
                "FLOW_REVERSED at {t}, LED {led}"
            );
        }
        let breathing = match t {
            0 => Some(Rgbw::BLACK),
            5 => Some(Rgbw::new(128, 0, 0, 0)),
            10 => Some(RED),
            // 110 is 9 in 0..=100: 9 × 255 / 100, rounded.
            11 => Some(Rgbw::new(23, 0, 0, 0)),
            _ => None,
        };
        if let Some(breathing) = breathing {
            assert_eq!(bench.pixels_of(2), [breathing], "BREATHING at {t}");
        }
        bench.tick(1);
    }
}

#[test]
fn writing_value_restarts_the_animation_from_it() {
    let mut bench = Bench::new();
    bench.animate(2, 0, 0, 1_000, 5);
    bench.tick(10);
    assert_eq!(bench.value(2), 50);
    bench.write(2, Field::Value, 7);
    assert_eq!(bench.value(2), 7);
    bench.tick(1);
    assert_eq!(bench.value(2), 12);
    // Written outside the range, it is read back as written until the
    // first step wraps it in: 2_005 is 3 in 0..=1_000 (2_005 − 2 × 1_001).
    bench.write(2, Field::Value, 2_000);
    assert_eq!(bench.value(2), 2_000);
    bench.tick(1);
    assert_eq!(bench.value(2), 3);
    bench.tick(1);
    assert_eq!(bench.value(2), 8);
}

#[test]
fn new_speed_and_bounds_apply_from_the_write_on() {
    let mut bench = Bench::new();
    bench.animate(5, 0, 0, 1_000, 1);
    bench.tick(10);
    bench.write(5, Field::Speed, 2);
    bench.tick(5);
    assert_eq!(bench.value(5), 20);
    bench.write(5, Field::Speed, -4);
    bench.tick(1);
    assert_eq!(bench.value(5), 16);
    // A MaxValue below Value: the next step wraps it into the new range
    // (16 − 4 is 12, 5 past 7: 0, 1, 2, 3, then 4).
    bench.write(5, Field::MaxValue, 7);
    bench.tick(1);
    assert_eq!(bench.value(5), 4);
    // MinValue and MaxValue written the wrong way round still bound it.
    bench.write(5, Field::MinValue, 20);
    bench.write(5, Field::MaxValue, 10);
    for _ in 0..50 {
        bench.tick(1);
        assert!((10..=20).contains(&bench.value(5)));
    }
}

#[test]
fn a_write_after_skipped_milliseconds_lands_after_them() {
    let mut bench = Bench::new();
    bench.animate(6, 0, 0, 1_000, 3);
    bench.animate(8, 0, 0, 1_000, 1);
    bench.tick(10);
    // The host skipped 5 ms and a frame arrives before the next tick:
    // those 5 ms ran under the old parameters.
    bench.sim_ms += 5;
    bench.write(6, Field::Value, 7);
    bench.write(8, Field::Speed, 10);
    assert_eq!((bench.value(6), bench.value(8)), (7, 15));
    bench.tick(1);
    assert_eq!((bench.value(6), bench.value(8)), (10, 25));
}

#[test]
fn the_board_reports_its_supply_cpu_and_life_cycle() {
    let mut bench = Bench::new();
    let int = |bench: &Bench, (index, sub): (u16, u8)| {
        bench.store.get(index, sub).unwrap().as_i128().unwrap()
    };
    // Nothing lit: the supply less what the board draws (2.5 mV).
    assert_eq!(int(&bench, BOARD_VOLTAGE), 2_400);
    let cpu = int(&bench, CPU_TEMPERATURE);
    assert!((300..=320).contains(&cpu), "{cpu}");
    bench.tick(1_000);
    // 20 cycles a millisecond, counted every 10 ms.
    assert_eq!(int(&bench, CPU_LIFE_CYCLE), 20_000);
    bench.tick(3_000);
    assert_eq!(int(&bench, CPU_LIFE_CYCLE), (80_000 % 65_536) as i128);
    // 100 LEDs lit white (RGB) at full dimmer draw 6 A: 0.3 V less.
    // (Led_count 100 is the manual's default; the device starts at 0.)
    bench.write(1, Field::LedCount, 100);
    for channel in 1..=3 {
        bench.write(1, color(1, channel), 255);
    }
    bench.write(1, Field::Effect, i64::from(Effect::Fix.raw()));
    bench.tick(10);
    assert_eq!(int(&bench, BOARD_VOLTAGE), 2_370);
    // Dimmed to half, half the current; dimmed to 0, dark.
    bench.write(1, Field::Dimmer, 128);
    bench.tick(10);
    assert_eq!(int(&bench, BOARD_VOLTAGE), 2_385);
    bench.write(1, Field::Dimmer, 0);
    bench.tick(10);
    assert_eq!(int(&bench, BOARD_VOLTAGE), 2_400);
}

#[test]
fn speed_0_leaves_value_still() {
    let mut bench = Bench::new();
    bench.write(3, Field::Value, 30_000);
    bench.tick(100);
    assert_eq!(bench.value(3), 30_000);
    bench.animate(3, 0, 0, 100, 1);
    bench.tick(30);
    bench.write(3, Field::Speed, 0);
    // Held where it stopped, even when the range changes under it.
    bench.write(3, Field::MaxValue, 10);
    bench.tick(100);
    assert_eq!(bench.value(3), 30);
    // The clock ran on without ticks: a new Speed starts from now.
    bench.sim_ms += 1_000;
    bench.write(3, Field::MaxValue, 100);
    bench.write(3, Field::Speed, 1);
    bench.tick(1);
    assert_eq!(bench.value(3), 31);
}

#[test]
fn skipped_ticks_are_caught_up_at_the_next() {
    let mut bench = Bench::new();
    bench.animate(4, 0, -300, 300, 7);
    let mut one_by_one = Bench::new();
    one_by_one.animate(4, 0, -300, 300, 7);
    // The host fell 500 ms behind: the device core moves the clock on
    // and ticks once.
    bench.sim_ms += 499;
    bench.tick(1);
    one_by_one.tick(500);
    assert_eq!(bench.value(4), one_by_one.value(4));
    assert_eq!(bench.segment(4), one_by_one.segment(4));
}

#[test]
fn pixels_ahead_of_time_are_the_pixels_once_there() {
    let mut bench = Bench::new();
    bench.light(1, 9, Effect::Flow);
    bench.write(1, Field::Smooth, 3);
    bench.animate(1, 2, -5, 40, 3);
    bench.light(2, 4, Effect::Breathing);
    bench.animate(2, 100, 0, 1_000, -11);
    let ahead: Vec<_> = (0..200)
        .map(|t| bench.uioled.pixels(bench.sim_ms + t))
        .collect();
    for (t, expected) in ahead.iter().enumerate() {
        assert_eq!(&bench.pixels(), expected, "at {t}");
        bench.tick(1);
    }
}

#[test]
fn dimmer_and_colours_show_in_the_pixels() {
    let mut bench = Bench::new();
    bench.light(1, 3, Effect::Fix);
    bench.light(2, 1, Effect::Fix);
    assert_eq!(bench.pixels(), [RED; 4]);
    bench.write(1, Field::Dimmer, 128);
    assert_eq!(
        bench.pixels(),
        [
            Rgbw::new(128, 0, 0, 0),
            Rgbw::new(128, 0, 0, 0),
            Rgbw::new(128, 0, 0, 0),
            RED
        ]
    );
    bench.write(1, color(1, 3), 200);
    bench.write(1, color(1, 4), 255);
    bench.write(1, Field::Dimmer, 255);
    assert_eq!(bench.pixels()[..3], [Rgbw::new(255, 0, 200, 255); 3]);
    bench.write(2, Field::Dimmer, 0);
    assert_eq!(bench.pixels()[3], Rgbw::BLACK);
    bench.write(1, Field::Effect, 0);
    assert_eq!(bench.pixels()[..3], [Rgbw::BLACK; 3]);
}

#[test]
fn led_counts_set_the_strip_length_and_where_segments_start() {
    let mut bench = Bench::new();
    assert!(bench.pixels().is_empty());
    // The manual's getting started (§1.1): 10 red, then 5 green.
    bench.write(1, Field::LedCount, 10);
    bench.write(1, Field::Effect, 1);
    bench.write(1, color(1, 1), 255);
    bench.write(2, Field::LedCount, 5);
    bench.write(2, Field::Effect, 1);
    bench.write(2, color(1, 2), 255);
    let pixels = bench.pixels();
    assert_eq!(pixels.len(), 15);
    assert_eq!(pixels[..10], [RED; 10]);
    assert_eq!(pixels[10..], [GREEN; 5]);
    bench.write(1, Field::LedCount, 3);
    bench.write(10, Field::LedCount, 2);
    let pixels = bench.pixels();
    assert_eq!(pixels.len(), 10);
    assert_eq!(pixels[..3], [RED; 3]);
    assert_eq!(pixels[3..8], [GREEN; 5]);
    assert_eq!(pixels[8..], [Rgbw::BLACK; 2]);
    assert_eq!(layout(bench.uioled.segments())[9], 8..10);
}

#[test]
fn objects_that_are_no_segment_parameter_are_left_alone() {
    let mut bench = Bench::new();
    bench.animate(1, 0, 0, 100, 1);
    let before = bench.uioled.segments().to_vec();
    let mut uioled = std::mem::take(&mut bench.uioled);
    // Board_led, a colour's entry count, and a segment object the
    // manual does not describe (our EDS's s01_Profile).
    for (index, sub) in [(0x2004, 0), (0x6030, 0), (0x6014, 0)] {
        uioled.written(&mut bench.io(), index, sub);
    }
    bench.uioled = uioled;
    assert_eq!(bench.uioled.segments(), before);
}
