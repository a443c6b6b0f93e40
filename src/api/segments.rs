//! LED controllers (profile `uioled`, UIOLed firmware manual chapter 1): a
//! UIO1LED's segments read and written over SDO, and the pixels the strip
//! shows, drawn by the one renderer of [`crate::profiles::uioled`] from the
//! parameters read from the device.
//!
//! Every value of a request is checked (names, types, ranges) before the
//! first write; the writes of one segment go out in an order that shows
//! the new look at once: layout and colours first, the Value range before
//! Value and Speed, the effect last.

use axum::extract::State;
use serde::{Deserialize, Serialize};
use serde_json::Value as Json;
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{ErrorBody, NodePath};
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::gateway::Caller;
use crate::gateway::GatewayError;
use crate::gateway::LedError;
use crate::gateway::PreviewError;
use crate::gateway::{self, ColorChannels, LedController, Others, Scene};
pub use crate::gateway::{Color, Preview, PreviewSegment, effect_name};
use crate::gateway::{fits, is_segment};
use crate::profiles::uioled::{Field, SEGMENTS, Segment};

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_segments, put_scene))
        .routes(routes!(put_segment))
        .routes(routes!(preview))
}

/// A segment's parameters as read from the device.
#[derive(Debug, Clone, Serialize, ToSchema)]
#[schema(example = json!({"segment": 1, "led_count": 30, "effect": "flow", "colors": [
    {"r": 255, "g": 0, "b": 0, "w": 0}, {"r": 0, "g": 0, "b": 40, "w": 0}, {"r": 0, "g": 0, "b": 0, "w": 0}],
    "dimmer": 255, "value": 120, "min_value": 0, "max_value": 999, "speed": 1, "smooth": 4}))]
pub struct SegmentState {
    /// 1 to 10.
    pub segment: u8,
    /// LEDs in this segment; it starts right after the previous segment's.
    pub led_count: u16,
    /// `off`, `fix`, `flash`, `breathing`, `flow`, `flow_reversed`, or
    /// `0xNNNN` for a value the manual does not define (drawn dark).
    pub effect: String,
    /// `Color_01` to `Color_03`.
    #[schema(value_type = Vec<super::schema::Color>)]
    pub colors: Vec<Color>,
    /// 0 (0 %) to 255 (100 %).
    pub dimmer: u8,
    /// Drives the effect: the place of FLOW, the level of BREATHING.
    pub value: i16,
    pub min_value: i16,
    pub max_value: i16,
    /// Added to `value` every millisecond, wrapping within the range.
    pub speed: i16,
    /// LEDs a moving edge fades over.
    pub smooth: u16,
}

impl SegmentState {
    pub fn new(segment: u8, state: &Segment) -> Self {
        SegmentState {
            segment,
            led_count: state.led_count,
            effect: effect_name(state.effect),
            colors: state.colors.iter().copied().map(Color::from).collect(),
            dimmer: state.dimmer,
            value: state.value,
            min_value: state.min_value,
            max_value: state.max_value,
            speed: state.speed,
            smooth: state.smooth,
        }
    }
}

/// Colour channels to write; those not given stay as they are.
#[derive(Debug, Serialize, ToSchema)]
#[allow(dead_code)] // The schema of a colour in a request.
pub struct ColorUpdate {
    #[schema(minimum = 0, maximum = 255)]
    pub r: Option<u8>,
    #[schema(minimum = 0, maximum = 255)]
    pub g: Option<u8>,
    #[schema(minimum = 0, maximum = 255)]
    pub b: Option<u8>,
    #[schema(minimum = 0, maximum = 255)]
    pub w: Option<u8>,
}

/// A colour in a request: channels (only those given are written), or
/// `"#rrggbb"` / `"#rrggbbww"` (every channel; white 0 when not given).
#[derive(Debug, Serialize, ToSchema)]
#[serde(untagged)]
#[allow(dead_code)]
pub enum ColorInput {
    Channels(ColorUpdate),
    #[schema(example = "#ff5000")]
    Hex(String),
}

/// An effect in a request: its name, or its wire value.
#[derive(Debug, Serialize, ToSchema)]
#[serde(untagged)]
#[allow(dead_code)]
pub enum EffectInput {
    /// `off`, `fix`, `flash`, `breathing`, `flow`, `flow_reversed` (any
    /// case).
    #[schema(example = "flow")]
    Name(String),
    /// The value of `sNN_Effect` (manual Table 1.2), e.g. 0x0300 = 768.
    #[schema(example = 768)]
    Raw(u16),
}

/// The fields of a segment to write; only those given are written.
#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"effect": "flow", "colors": ["#ff0000", {"b": 40}], "speed": 1, "max_value": 999}))]
pub struct SegmentUpdate {
    /// In a scene: which segment (1 to 10). In `PUT .../segments/{n}`:
    /// absent, or `n`.
    #[schema(minimum = 1, maximum = 10)]
    pub segment: Option<u32>,
    #[schema(minimum = 0, maximum = 65535)]
    pub led_count: Option<i64>,
    /// An effect name (`off`, `fix`, `flash`, `breathing`, `flow`,
    /// `flow_reversed`, any case) or its wire value (0 to 65535).
    #[schema(value_type = Option<EffectInput>, example = "breathing")]
    pub effect: Option<Json>,
    /// Up to three colours (`Color_01`..`Color_03`); `null` leaves one as
    /// it is.
    #[schema(value_type = Option<Vec<Option<ColorInput>>>)]
    pub colors: Option<Vec<Json>>,
    #[schema(minimum = 0, maximum = 255)]
    pub dimmer: Option<i64>,
    #[schema(minimum = -32768, maximum = 32767)]
    pub value: Option<i64>,
    #[schema(minimum = -32768, maximum = 32767)]
    pub min_value: Option<i64>,
    #[schema(minimum = -32768, maximum = 32767)]
    pub max_value: Option<i64>,
    #[schema(minimum = -32768, maximum = 32767)]
    pub speed: Option<i64>,
    #[schema(minimum = 0, maximum = 65535)]
    pub smooth: Option<i64>,
}

/// A whole scene: the segments listed are written as [`SegmentUpdate`]s.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"segments": [
    {"segment": 1, "led_count": 30, "effect": "flow", "colors": ["#ff0000", "#000028"], "min_value": 0, "max_value": 999, "speed": 1, "smooth": 4},
    {"segment": 2, "led_count": 10, "effect": "fix", "colors": ["#00ff00"]}], "others": "off"}))]
pub struct SceneRequest {
    pub segments: Vec<SegmentUpdate>,
    /// What becomes of the segments not listed: `keep` (the default) or
    /// `off` (their effect set to off).
    #[schema(example = "off")]
    pub others: Option<String>,
}

/// A segment named in a path.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Path)]
#[allow(dead_code)]
pub struct SegmentPath {
    /// The bus name.
    #[param(example = "demo")]
    pub bus: String,
    /// The node id, 1 to 127.
    #[param(minimum = 1, maximum = 127, example = 3)]
    pub id: u8,
    /// The segment, 1 to 10.
    #[param(minimum = 1, maximum = 10, example = 1)]
    pub n: u8,
}

/// The bus and node of a path, which must be an LED controller.
fn led_controller(state: &AppState, bus: &str, id: &str) -> Result<LedController, GatewayError> {
    state.gateway.node_handle(bus, id)?.led_controller()
}

impl From<PreviewError> for AppError {
    /// A subscription to a preview fails as `GET .../segments/preview`
    /// would: `unknown_node`, `not_an_led_controller`.
    fn from(error: PreviewError) -> Self {
        match error {
            PreviewError::Registry(error) => Self::from(error),
            PreviewError::NotAnLedController { .. } => {
                GatewayError::Led(LedError::NotAnLedController(error.to_string())).into()
            }
        }
    }
}

/// The segment number of a path or a scene entry: 1 to 10, else 404
/// `unknown_segment`.
fn segment_number(text: &str) -> Result<u8, GatewayError> {
    let unknown = || {
        GatewayError::Led(LedError::UnknownSegment(format!(
            "segment '{text}' does not exist: a UIO1LED has segments 1 to {SEGMENTS}"
        )))
    };
    let number: i64 = text.trim().parse().map_err(|_| {
        GatewayError::InvalidRequest(format!("segment '{text}' is no number (1 to {SEGMENTS})"))
    })?;
    u8::try_from(number)
        .ok()
        .filter(|n| is_segment(*n))
        .ok_or_else(unknown)
}

fn parse_effect(effect: &Json) -> Result<i64, GatewayError> {
    let names = "off, fix, flash, breathing, flow, flow_reversed";
    match effect {
        Json::String(name) => gateway::effect_by_name(name)
            .map(|effect| i64::from(effect.raw()))
            .ok_or_else(|| {
                GatewayError::InvalidValue(format!("effect '{name}' is not one of {names}"))
            }),
        Json::Number(number) => match number.as_i64() {
            Some(raw) if fits(Field::Effect, raw) => Ok(raw),
            _ if number.is_i64() || number.is_u64() => Err(GatewayError::ValueOutOfRange(format!(
                "effect {number} is no wire value (0 to 65535)"
            ))),
            _ => Err(GatewayError::InvalidValue(format!(
                "effect {number} is no whole number"
            ))),
        },
        other => Err(GatewayError::InvalidValue(format!(
            "effect {other} is neither a name ({names}) nor a number"
        ))),
    }
}

/// The channels a colour of a request writes (red, green, blue, white).
fn parse_color(position: usize, color: &Json) -> Result<ColorChannels, GatewayError> {
    let invalid = |why: String| GatewayError::InvalidValue(format!("colors[{position}]: {why}"));
    let mut channels: ColorChannels = [None; 4];
    match color {
        Json::Null => {}
        Json::String(text) => {
            let digits = text.trim().trim_start_matches('#');
            if !(digits.len() == 6 || digits.len() == 8)
                || !digits.bytes().all(|b| b.is_ascii_hexdigit())
            {
                return Err(invalid(format!(
                    "'{text}' is not #rrggbb or #rrggbbww (hex digits)"
                )));
            }
            for (n, channel) in channels.iter_mut().enumerate() {
                *channel = Some(
                    digits
                        .get(2 * n..2 * n + 2)
                        .and_then(|pair| u8::from_str_radix(pair, 16).ok())
                        .unwrap_or(0),
                );
            }
        }
        Json::Object(given) => {
            for (key, value) in given {
                let channel = match key.as_str() {
                    "r" => 0,
                    "g" => 1,
                    "b" => 2,
                    "w" => 3,
                    other => {
                        return Err(invalid(format!("'{other}' is no channel (r, g, b, w)")));
                    }
                };
                let level = value
                    .as_u64()
                    .and_then(|level| u8::try_from(level).ok())
                    .ok_or_else(|| {
                        GatewayError::ValueOutOfRange(format!(
                            "colors[{position}].{key}: {value} is not 0 to 255"
                        ))
                    })?;
                channels[channel] = Some(level);
            }
        }
        other => {
            return Err(invalid(format!(
                "{other} is neither {{\"r\",\"g\",\"b\",\"w\"}} nor \"#rrggbb\""
            )));
        }
    }
    Ok(channels)
}

impl SegmentUpdate {
    /// The update as the gateway takes it: colours and effect read, at
    /// most three colours.
    fn parse(&self) -> Result<gateway::SegmentUpdate, GatewayError> {
        let mut colors = [[None; 4]; 3];
        if let Some(given) = &self.colors {
            if given.len() > 3 {
                return Err(GatewayError::InvalidValue(format!(
                    "{} colours given: a segment has 3",
                    given.len()
                )));
            }
            for (position, color) in given.iter().enumerate() {
                colors[position] = parse_color(position, color)?;
            }
        }
        Ok(gateway::SegmentUpdate {
            led_count: self.led_count,
            colors,
            dimmer: self.dimmer,
            smooth: self.smooth,
            min_value: self.min_value,
            max_value: self.max_value,
            value: self.value,
            speed: self.speed,
            effect: self.effect.as_ref().map(parse_effect).transpose()?,
        })
    }

    /// The update of `PUT .../segments/{segment}`, whose body names no
    /// other segment.
    fn for_segment(&self, segment: u8) -> Result<gateway::SegmentUpdate, GatewayError> {
        if let Some(given) = self.segment
            && given != u32::from(segment)
        {
            return Err(GatewayError::InvalidValue(format!(
                "the body names segment {given}, the path segment {segment}"
            )));
        }
        self.parse()
    }
}

impl TryFrom<SceneRequest> for Scene {
    type Error = GatewayError;

    fn try_from(scene: SceneRequest) -> Result<Self, GatewayError> {
        let others = scene
            .others
            .as_deref()
            .map_or(Ok(Others::Keep), Others::from_name)?;
        let segments = scene
            .segments
            .iter()
            .enumerate()
            .map(|(position, update)| {
                let segment = update.segment.ok_or_else(|| {
                    GatewayError::InvalidValue(format!("segments[{position}] names no segment"))
                })?;
                Ok((segment_number(&segment.to_string())?, update.parse()?))
            })
            .collect::<Result<_, GatewayError>>()?;
        Ok(Scene { segments, others })
    }
}

/// Reads every segment of an LED controller: the summary of `GET
/// /nodes/{id}` for a `uioled` node.
pub async fn summary(
    state: &AppState,
    caller: &Caller,
    bus: &str,
    id: &str,
) -> Result<Vec<SegmentState>, AppError> {
    let segments = led_controller(state, bus, id)?
        .read_segments(caller)
        .await?;
    Ok(states(&segments))
}

fn states(segments: &[Segment]) -> Vec<SegmentState> {
    (1..=SEGMENTS)
        .zip(segments)
        .map(|(n, segment)| SegmentState::new(n, segment))
        .collect()
}

/// Every segment of an LED controller, read over SDO.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}/segments", tag = "leds", params(NodePath),
    responses(
        (status = 200, description = "Segments 1 to 10", body = [SegmentState]),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_an_led_controller`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: the device refused", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn list_segments(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<ApiJson<Vec<SegmentState>>, AppError> {
    let segments = led_controller(&state, &bus, &id)?
        .read_segments(&caller)
        .await?;
    Ok(ApiJson(states(&segments)))
}

/// Writes the fields given of one segment and returns it read back.
#[utoipa::path(put, path = "/buses/{bus}/nodes/{id}/segments/{n}", tag = "leds", params(SegmentPath),
    request_body = SegmentUpdate,
    responses(
        (status = 200, description = "The segment read back", body = SegmentState),
        (status = 400, description = "`invalid_value`, `value_out_of_range`, `invalid_request` (checked before the first write)", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_an_led_controller`, `unknown_segment`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: the device refused", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn put_segment(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id, n)): ApiPath<(String, String, String)>,
    ApiJson(update): ApiJson<SegmentUpdate>,
) -> Result<ApiJson<SegmentState>, AppError> {
    let leds = led_controller(&state, &bus, &id)?;
    let segment = segment_number(&n)?;
    let update = update.for_segment(segment)?;
    let read_back = leds
        .write_segment_read_back(&caller, segment, &update)
        .await?;
    Ok(ApiJson(SegmentState::new(segment, &read_back)))
}

/// Applies a scene: the segments listed, each as a partial update, and
/// optionally every other segment off; returns every segment read back.
#[utoipa::path(put, path = "/buses/{bus}/nodes/{id}/segments", tag = "leds", params(NodePath),
    request_body = SceneRequest,
    responses(
        (status = 200, description = "Segments 1 to 10 read back", body = [SegmentState]),
        (status = 400, description = "`invalid_value`, `value_out_of_range`, `invalid_request` (checked before the first write)", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_an_led_controller`, `unknown_segment`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: the device refused", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn put_scene(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
    ApiJson(scene): ApiJson<SceneRequest>,
) -> Result<ApiJson<Vec<SegmentState>>, AppError> {
    let leds = led_controller(&state, &bus, &id)?;
    let scene = Scene::try_from(scene)?;
    let segments = leds.apply_scene(&caller, &scene).await?;
    Ok(ApiJson(states(&segments)))
}

/// The pixels the strip shows now, drawn from the parameters read from the
/// device by the renderer the virtual UIO1LED uses.
#[utoipa::path(get, path = "/buses/{bus}/nodes/{id}/segments/preview", tag = "leds", params(NodePath),
    responses(
        (status = 200, description = "Every LED of the strip", body = super::schema::Preview),
        (status = 400, description = "`invalid_request`", body = ErrorBody),
        (status = 404, description = "`unknown_bus`, `unknown_node`, `not_an_led_controller`", body = ErrorBody),
        (status = 409, description = "`wrong_nmt_state`: the node is stopped", body = ErrorBody),
        (status = 422, description = "`sdo_abort`: the device refused", body = ErrorBody),
        (status = 502, description = "`sdo_protocol_error`", body = ErrorBody),
        (status = 503, description = "`bus_down`", body = ErrorBody),
        (status = 504, description = "`sdo_timeout`", body = ErrorBody),
    ))]
async fn preview(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath((bus, id)): ApiPath<(String, String)>,
) -> Result<ApiJson<Preview>, AppError> {
    let preview = led_controller(&state, &bus, &id)?.preview(&caller).await?;
    Ok(ApiJson(preview))
}
