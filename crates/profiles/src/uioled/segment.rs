//! One strip segment's parameters (UIOLed firmware manual §1.3 "Leds
//! configuration and control"): what the objects 0x6n00–0x6n32 hold.

use serde::{Deserialize, Serialize};

/// The effect of a segment, object `sNN_Effect` (manual Table 1.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Effect {
    /// 0x0000: every LED dark.
    #[default]
    Off,
    /// 0x0001: every LED in colour 1.
    Fix,
    /// 0x0101: the segment alternates between colour 1 and colour 2.
    Flash,
    /// 0x0102: colour 1, its brightness following Value.
    Breathing,
    /// 0x0300: a pattern moving from the segment's first LED to its last.
    Flow,
    /// 0x0301: [`Effect::Flow`] moving from the last LED to the first.
    FlowReversed,
    /// A value the manual does not define; rendered dark.
    Unknown(u16),
}

impl Effect {
    pub fn from_raw(raw: u16) -> Self {
        match raw {
            0x0000 => Effect::Off,
            0x0001 => Effect::Fix,
            0x0101 => Effect::Flash,
            0x0102 => Effect::Breathing,
            0x0300 => Effect::Flow,
            0x0301 => Effect::FlowReversed,
            other => Effect::Unknown(other),
        }
    }

    pub fn raw(self) -> u16 {
        match self {
            Effect::Off => 0x0000,
            Effect::Fix => 0x0001,
            Effect::Flash => 0x0101,
            Effect::Breathing => 0x0102,
            Effect::Flow => 0x0300,
            Effect::FlowReversed => 0x0301,
            Effect::Unknown(raw) => raw,
        }
    }

    /// The manual's name (`FLOW_REVERSED`), or the wire value in hex.
    pub fn name(self) -> String {
        match self {
            Effect::Off => "OFF".into(),
            Effect::Fix => "FIX".into(),
            Effect::Flash => "FLASH".into(),
            Effect::Breathing => "BREATHING".into(),
            Effect::Flow => "FLOW".into(),
            Effect::FlowReversed => "FLOW_REVERSED".into(),
            Effect::Unknown(raw) => format!("0x{raw:04X}"),
        }
    }
}

/// One LED's colour: the four channels of the `sNN_Color_0x` arrays
/// (sub-indexes 1–4 are R, G, B, W).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
pub struct Rgbw {
    pub r: u8,
    pub g: u8,
    pub b: u8,
    pub w: u8,
}

impl Rgbw {
    pub const BLACK: Rgbw = Rgbw::new(0, 0, 0, 0);

    pub const fn new(r: u8, g: u8, b: u8, w: u8) -> Self {
        Rgbw { r, g, b, w }
    }

    /// Every channel scaled by `level` / 255, rounded to nearest: the
    /// dimmer's 255 is 100 %, so full level must give the colour back exactly.
    pub fn scaled(self, level: u8) -> Self {
        let scale = |channel: u8| ((u32::from(channel) * u32::from(level) + 127) / 255) as u8;
        Rgbw::new(scale(self.r), scale(self.g), scale(self.b), scale(self.w))
    }

    /// `self` weighted `weight` / 255 against `other`: 255 gives `self`, 0
    /// gives `other`.
    pub fn mixed(self, other: Rgbw, weight: u8) -> Self {
        let mix = |a: u8, b: u8| {
            let (a, b, w) = (i32::from(a), i32::from(b), i32::from(weight));
            (b + ((a - b) * w + if a >= b { 127 } else { -127 }) / 255) as u8
        };
        Rgbw::new(
            mix(self.r, other.r),
            mix(self.g, other.g),
            mix(self.b, other.b),
            mix(self.w, other.w),
        )
    }

    /// The channel of sub-index 1–4 (R, G, B, W).
    pub fn channel(&self, sub: u8) -> Option<u8> {
        match sub {
            1 => Some(self.r),
            2 => Some(self.g),
            3 => Some(self.b),
            4 => Some(self.w),
            _ => None,
        }
    }

    /// Sets the channel of sub-index 1–4; false for any other sub-index.
    pub fn set_channel(&mut self, sub: u8, value: u8) -> bool {
        let channel = match sub {
            1 => &mut self.r,
            2 => &mut self.g,
            3 => &mut self.b,
            4 => &mut self.w,
            _ => return false,
        };
        *channel = value;
        true
    }
}

/// A segment's parameters, one field per object of manual §1.3, named as
/// the manual names them without the `sNN_` prefix.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Segment {
    /// `Led_type` (0x6n00): unused by firmware 1.0.x.
    pub led_type: u8,
    /// `Led_count` (0x6n01): the number of LEDs in this segment; the segment
    /// starts right after the previous one's last LED.
    pub led_count: u16,
    /// `Value` (0x6n10): drives the effect; written directly, or advanced by
    /// `speed` every millisecond.
    pub value: i16,
    /// `MinValue` (0x6n11): the lowest `value` reaches while `speed` ≠ 0.
    pub min_value: i16,
    /// `MaxValue` (0x6n12): the highest `value` reaches while `speed` ≠ 0.
    pub max_value: i16,
    /// `Speed` (0x6n13): added to `value` every millisecond; 0 leaves
    /// `value` as written.
    pub speed: i16,
    /// `Effect` (0x6n20).
    pub effect: Effect,
    /// `Smooth` (0x6n24): how many LEDs a moving edge fades over, rather
    /// than lighting LEDs up at once.
    pub smooth: u16,
    /// `Dimmer` (0x6n25): the whole segment, 0 (0 %) to 255 (100 %).
    pub dimmer: u8,
    /// `Color_01`–`Color_03` (0x6n30–0x6n32).
    pub colors: [Rgbw; 3],
}

impl Default for Segment {
    /// The defaults of our EDS, which are the device's. The manual gives
    /// `Led_count` a default of 100, but the device starts at 0.
    fn default() -> Self {
        Segment {
            led_type: 0,
            led_count: 0,
            value: 0,
            min_value: 0,
            max_value: i16::MAX,
            speed: 0,
            effect: Effect::Off,
            smooth: 0,
            dimmer: 255,
            colors: [Rgbw::BLACK; 3],
        }
    }
}

impl Segment {
    /// Colour 1, the colour of every effect that has one.
    pub fn color_1(&self) -> Rgbw {
        self.colors[0]
    }

    /// Colour 2: the other colour of FLASH and the background of FLOW.
    pub fn color_2(&self) -> Rgbw {
        self.colors[1]
    }

    /// `MinValue` and `MaxValue` as a range, whichever way round they were
    /// written, so that no pair of writes leaves Value without a range.
    pub fn bounds(&self) -> (i16, i16) {
        if self.min_value <= self.max_value {
            (self.min_value, self.max_value)
        } else {
            (self.max_value, self.min_value)
        }
    }

    /// Value `t_ms` milliseconds after the segment held `value`.
    ///
    /// With `speed` 0, Value is as written. Otherwise Speed is added every
    /// millisecond and Value stays within MinValue..=MaxValue by wrapping
    /// around: past MaxValue it continues from MinValue (and below MinValue,
    /// for a negative speed, from MaxValue). Wrapping rather than bouncing
    /// keeps FLOW moving one way, which is what FLOW_REVERSED is for. The
    /// manual does not say which; this is a closed form of the 1 ms steps,
    /// so any `t_ms` costs the same, and steps compose: `value_at(a + b)` is
    /// `value_at(b)` of the segment holding `value_at(a)`. The virtual
    /// UIO1LED's speed controller is this function, so the Value it shows
    /// over the bus is the Value drawn.
    pub fn value_at(&self, t_ms: u64) -> i16 {
        // At 0 no step has been taken: a Value written outside the bounds
        // is shown as written until the first millisecond wraps it in.
        if self.speed == 0 || t_ms == 0 {
            return self.value;
        }
        let (low, high) = self.bounds();
        // 1..=65536.
        let span = i64::from(high) - i64::from(low) + 1;
        // Speed × t counts only modulo the span: reducing t first keeps the
        // product within i64 for any t (|speed| ≤ 2^15, steps < 2^16), and
        // avoids 128-bit division on a path run every millisecond.
        let steps = (t_ms % span as u64) as i64;
        let moved = i64::from(self.value) - i64::from(low) + i64::from(self.speed) * steps;
        (i64::from(low) + moved.rem_euclid(span)) as i16
    }

    /// Where Value is within MinValue..=MaxValue, as 0..=`steps` − 1: the
    /// common position of every effect. A value outside the bounds (written
    /// with speed 0) counts as the nearest bound.
    fn position(&self, t_ms: u64, steps: u64) -> u64 {
        let (low, high) = self.bounds();
        let value = self.value_at(t_ms).clamp(low, high);
        let span = (i64::from(high) - i64::from(low) + 1) as u64;
        let offset = (i64::from(value) - i64::from(low)) as u64;
        offset * steps / span
    }

    /// The brightness of BREATHING, 0 at MinValue to 255 at MaxValue.
    pub fn level_at(&self, t_ms: u64) -> u8 {
        let (low, high) = self.bounds();
        if low == high {
            return 255;
        }
        let value = self.value_at(t_ms).clamp(low, high);
        let offset = i64::from(value) - i64::from(low);
        let span = i64::from(high) - i64::from(low);
        ((offset * 255 + span / 2) / span) as u8
    }

    /// The segment's LEDs at `t_ms`, dimmer applied, first LED first.
    pub fn render_at(&self, t_ms: u64) -> Vec<Rgbw> {
        let count = usize::from(self.led_count);
        let mut pixels = match self.effect {
            Effect::Off | Effect::Unknown(_) => vec![Rgbw::BLACK; count],
            Effect::Fix => vec![self.color_1(); count],
            // The first half of the range shows colour 1, the second colour
            // 2: with Speed set the segment flashes once per pass through
            // the range.
            Effect::Flash => {
                let color = match self.position(t_ms, 2) {
                    0 => self.color_1(),
                    _ => self.color_2(),
                };
                vec![color; count]
            }
            Effect::Breathing => vec![self.color_1().scaled(self.level_at(t_ms)); count],
            Effect::Flow => self.flow(t_ms),
            Effect::FlowReversed => {
                let mut pixels = self.flow(t_ms);
                pixels.reverse();
                pixels
            }
        };
        for pixel in &mut pixels {
            *pixel = pixel.scaled(self.dimmer);
        }
        pixels
    }

    /// FLOW: one LED in colour 1 on colour 2, at the place along the segment
    /// that Value holds within its range. `smooth` LEDs behind it fade from
    /// colour 1 to colour 2 (a tail), wrapping round the segment's start so
    /// the pattern does not jump when the head does.
    fn flow(&self, t_ms: u64) -> Vec<Rgbw> {
        let count = u64::from(self.led_count);
        if count == 0 {
            return Vec::new();
        }
        let head = self.position(t_ms, count);
        let smooth = u64::from(self.smooth);
        (0..count)
            .map(|led| {
                let behind = (head + count - led) % count;
                if behind > smooth {
                    self.color_2()
                } else {
                    let weight = 255 - behind * 255 / (smooth + 1);
                    self.color_1().mixed(self.color_2(), weight as u8)
                }
            })
            .collect()
    }
}
