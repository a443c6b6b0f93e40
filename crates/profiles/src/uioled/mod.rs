//! UniSwarm UIO1LED LED strip controllers (UIOLed firmware manual, chapter 1
//! "Led profile"): up to 10 segments of one addressable strip, each with its
//! own effect, and the renderer that turns their parameters into the colour
//! of every LED at a given time.
//!
//! The renderer is pure: time comes in as milliseconds since the segments
//! held the parameters given (Value included: the virtual UIO1LED passes
//! its live ones, the preview those last read from a real one), so both
//! draw the same pixels, and tests need no clock.
//!
//! # Layout
//!
//! - [`segment`]: [`Segment`], [`Effect`] (Table 1.2), [`Rgbw`], and one
//!   segment's effect at a time.
//! - [`objects`]: segment n's objects at 0x6000 + 0x100 × (n − 1) (Table 1.1)
//!   and the [`Field`] at each.
//! - [`render()`]: the whole strip, segments end to end (§1.1).

pub mod objects;
pub mod segment;

#[cfg(test)]
mod tests;

pub use objects::{Field, SEGMENTS, address, locate};
pub use segment::{Effect, Rgbw, Segment};

/// Every LED of the strip at `t_ms`: segment 1's `led_count` LEDs first, then
/// segment 2's, and so on (manual §1.1: segment 2 starts at
/// `s01_Led_count + 1`). A segment with no LEDs takes no place.
pub fn render(segments: &[Segment], t_ms: u64) -> Vec<Rgbw> {
    let total = led_count(segments);
    let mut pixels = Vec::with_capacity(total);
    for segment in segments {
        pixels.extend(segment.render_at(t_ms));
    }
    pixels
}

/// The number of LEDs on the strip: the sum of every segment's.
pub fn led_count(segments: &[Segment]) -> usize {
    segments
        .iter()
        .map(|segment| usize::from(segment.led_count))
        .sum()
}

/// The LEDs of each segment: where in the strip segment `i` starts, and how
/// many it has.
pub fn layout(segments: &[Segment]) -> Vec<std::ops::Range<usize>> {
    let mut start = 0;
    segments
        .iter()
        .map(|segment| {
            let end = start + usize::from(segment.led_count);
            let range = start..end;
            start = end;
            range
        })
        .collect()
}
