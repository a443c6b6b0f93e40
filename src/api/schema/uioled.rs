//! The schemas of `crate::gateway::uioled`'s colours and strip preview.

use utoipa::ToSchema;

/// One colour: red, green, blue and white, 0 to 255 each.
#[derive(Debug, ToSchema)]
#[schema(example = json!({"r": 255, "g": 80, "b": 0, "w": 0}))]
pub struct Color {
    pub r: u8,
    pub g: u8,
    pub b: u8,
    pub w: u8,
}

/// What the strip shows now.
#[derive(Debug, ToSchema)]
#[schema(example = json!({"led_count": 3, "segments": [{"segment": 1, "start": 0, "led_count": 3, "effect": "fix"}],
    "pixels": [{"r": 255, "g": 0, "b": 0, "w": 0}, {"r": 255, "g": 0, "b": 0, "w": 0}, {"r": 255, "g": 0, "b": 0, "w": 0}]}))]
pub struct Preview {
    /// LEDs on the strip: the sum of every segment's.
    pub led_count: usize,
    /// Where each segment's LEDs are in `pixels`.
    pub segments: Vec<PreviewSegment>,
    /// Every LED, the first of segment 1 first, dimmer applied.
    pub pixels: Vec<Color>,
}

/// One segment's place on the strip.
#[derive(Debug, ToSchema)]
pub struct PreviewSegment {
    pub segment: u8,
    /// Its first LED in `pixels`.
    pub start: usize,
    pub led_count: u16,
    pub effect: String,
}
