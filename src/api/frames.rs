//! Raw CAN frames of a bus (ISO 11898-1): the recent ones, from the
//! gateway's [`FrameLog`](crate::gateway::FrameLog), and one sent
//! as given.
//!
//! A frame in JSON:
//! `{"timestamp_us", "id": "0x181", "extended", "rtr", "fd", "error", "dlc",
//! "data": "0102AB", "dir": "rx|tx"}`. The id is a hex string, 3 digits for
//! an 11-bit id and 8 for a 29-bit one (as candump writes them); `dir` is
//! `tx` for what the gateway sent (SDO requests, NMT, frames posted here)
//! and `rx` for what others sent.
//!
//! A frame to send takes its id as a number or a string (`"0x181"`,
//! `"181h"`, decimal); an id above 0x7FF needs `"extended": true` (no
//! silent promotion to 29 bits: a CANopen device would not hear it).

use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::caller::RestCaller;
use super::doc::{BusPath, ErrorBody};
use super::{ApiJson, ApiPath, AppError, AppState};
use crate::can::{CanId, Direction as CanDirection, Frame, TimedFrame, Timestamp};
use crate::gateway::CAPACITY;
use crate::gateway::GatewayError;

/// How many frames `GET .../frames` returns without `limit`.
pub const DEFAULT_LIMIT: usize = 100;

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(recent_frames, send_frame))
}

/// Which way a frame went, seen from the gateway.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum FrameDirection {
    /// Sent by another node.
    Rx,
    /// Sent by the gateway.
    Tx,
}

/// One CAN frame.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct BusFrame {
    /// When the gateway saw it, microseconds since the Unix epoch.
    #[schema(example = 1_795_000_000_000_000u64)]
    pub timestamp_us: u64,
    /// The identifier, hex: 3 digits for 11 bits, 8 for 29 bits.
    #[schema(example = "0x181")]
    pub id: String,
    /// A 29-bit identifier.
    pub extended: bool,
    /// A remote transmission request (no data; `dlc` is the length asked).
    pub rtr: bool,
    /// A CAN FD frame (up to 64 bytes).
    pub fd: bool,
    /// An error frame reported by the controller.
    pub error: bool,
    /// The data length code.
    #[schema(example = 2)]
    pub dlc: u8,
    /// The data bytes, hex (upper case, no separators).
    #[schema(example = "3702")]
    pub data: String,
    pub dir: FrameDirection,
}

impl From<&TimedFrame> for BusFrame {
    fn from(timed: &TimedFrame) -> Self {
        let frame = &timed.frame;
        let id = match frame.id() {
            CanId::Standard(raw) => format!("0x{raw:03X}"),
            CanId::Extended(raw) => format!("0x{raw:08X}"),
        };
        Self {
            timestamp_us: timed.timestamp.as_micros(),
            id,
            extended: frame.id().is_extended(),
            rtr: frame.is_remote(),
            fd: frame.is_fd(),
            error: frame.is_error(),
            dlc: frame.dlc(),
            data: hex(frame.data()),
            dir: match timed.direction {
                CanDirection::Rx => FrameDirection::Rx,
                CanDirection::Tx => FrameDirection::Tx,
            },
        }
    }
}

fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write;
    bytes.iter().fold(String::new(), |mut out, byte| {
        let _ = write!(out, "{byte:02X}");
        out
    })
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct FramesQuery {
    /// How many of the newest frames: 0 to 1000, default 100.
    #[param(minimum = 0, maximum = 1000, example = 20)]
    limit: Option<usize>,
}

/// The bus's recent frames, oldest first.
///
/// The gateway keeps the last 1000 frames of each bus (what it sends and
/// what it receives); `limit` (default 100, at most 1000) takes the newest
/// of them.
#[utoipa::path(get, path = "/buses/{bus}/frames", tag = "frames", params(BusPath, FramesQuery),
    responses(
        (status = 200, description = "The newest frames, oldest first", body = [BusFrame]),
        (status = 400, description = "`invalid_request`: `limit` is no number from 0 to 1000", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
    ))]
async fn recent_frames(
    State(state): State<AppState>,
    ApiPath(bus): ApiPath<String>,
    query: Result<Query<FramesQuery>, QueryRejection>,
) -> Result<ApiJson<Vec<BusFrame>>, AppError> {
    let Query(query) = query.map_err(|err| AppError::InvalidRequest(err.body_text()))?;
    let served = state.bus(&bus)?;
    let limit = query.limit.unwrap_or(DEFAULT_LIMIT);
    if limit > CAPACITY {
        return Err(AppError::InvalidRequest(format!(
            "limit {limit}: at most {CAPACITY} frames are kept"
        )));
    }
    let frames = served.frames().recent(limit);
    Ok(ApiJson(frames.iter().map(BusFrame::from).collect()))
}

/// A CAN identifier as a request gives it.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(untagged)]
pub enum IdInput {
    Number(u64),
    /// `"0x181"`, `"181h"` or decimal.
    Text(String),
}

/// A frame to send.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"id": "0x601", "data": "4000100000000000"}))]
pub struct SendFrame {
    /// 0 to 0x7FF, or to 0x1FFFFFFF with `extended`.
    #[schema(example = "0x601")]
    pub id: IdInput,
    /// 0 to 8 bytes, hex (spaces allowed between bytes); default none.
    #[serde(default)]
    #[schema(example = "4000100000000000")]
    pub data: String,
    /// A 29-bit identifier; default false.
    #[serde(default)]
    pub extended: bool,
}

impl SendFrame {
    /// The frame, or 400 before the bus is touched.
    fn to_frame(&self) -> Result<Frame, GatewayError> {
        let raw = match &self.id {
            IdInput::Number(raw) => *raw,
            IdInput::Text(text) => parse_id(text)?,
        };
        let max = if self.extended { 0x1FFF_FFFF } else { 0x7FF };
        if raw > max {
            let hint = if self.extended {
                ""
            } else {
                " (a 29-bit id needs \"extended\": true)"
            };
            return Err(GatewayError::ValueOutOfRange(format!(
                "id 0x{raw:X} is above 0x{max:X}{hint}"
            )));
        }
        let raw = raw as u32;
        let id = if self.extended {
            CanId::extended(raw)
        } else {
            CanId::standard(raw)
        }
        .map_err(|err| GatewayError::ValueOutOfRange(err.to_string()))?;
        let data = parse_hex(&self.data)?;
        Frame::new(id, &data).map_err(|err| GatewayError::InvalidValue(err.to_string()))
    }
}

fn parse_id(text: &str) -> Result<u64, GatewayError> {
    let text = text.trim();
    let parsed = if let Some(hex) = text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        u64::from_str_radix(hex, 16)
    } else if let Some(hex) = text.strip_suffix(['h', 'H']) {
        u64::from_str_radix(hex, 16)
    } else {
        text.parse()
    };
    parsed.map_err(|_| {
        GatewayError::InvalidValue(format!(
            "id '{text}' is no CAN id (a number, \"0x181\" or \"181h\")"
        ))
    })
}

fn parse_hex(text: &str) -> Result<Vec<u8>, GatewayError> {
    let digits: Vec<u8> = text
        .bytes()
        .filter(|byte| !byte.is_ascii_whitespace())
        .collect();
    let invalid = || GatewayError::InvalidValue(format!("data '{text}' is no hex byte string"));
    if !digits.len().is_multiple_of(2) {
        return Err(invalid());
    }
    let bytes = digits
        .chunks(2)
        .map(|pair| {
            std::str::from_utf8(pair)
                .ok()
                .and_then(|pair| u8::from_str_radix(pair, 16).ok())
                .ok_or_else(invalid)
        })
        .collect::<Result<Vec<u8>, GatewayError>>()?;
    if bytes.len() > 8 {
        return Err(GatewayError::ValueOutOfRange(format!(
            "{} data bytes: a classic CAN frame has at most 8",
            bytes.len()
        )));
    }
    Ok(bytes)
}

/// Sends one classic data frame on the bus.
///
/// Checked before the bus is touched: the id (11 bits, or 29 with
/// `extended`), the data (hex, at most 8 bytes). Returns the frame as sent.
#[utoipa::path(post, path = "/buses/{bus}/frames", tag = "frames", params(BusPath),
    request_body = SendFrame,
    responses(
        (status = 200, description = "The frame, sent", body = BusFrame),
        (status = 400, description = "`invalid_request` (malformed body), `invalid_value` (id or data unreadable), `value_out_of_range` (id above 0x7FF or 0x1FFFFFFF, more than 8 bytes)", body = ErrorBody),
        (status = 404, description = "`unknown_bus`", body = ErrorBody),
        (status = 503, description = "`bus_down`: the bus cannot send now", body = ErrorBody),
    ))]
async fn send_frame(
    State(state): State<AppState>,
    RestCaller(caller): RestCaller,
    ApiPath(bus): ApiPath<String>,
    ApiJson(request): ApiJson<SendFrame>,
) -> Result<ApiJson<BusFrame>, AppError> {
    let frame = request.to_frame()?;
    state.gateway.send_frame(&caller, &bus, frame).await?;
    Ok(ApiJson(BusFrame::from(&TimedFrame {
        frame,
        timestamp: Timestamp::now(),
        direction: CanDirection::Tx,
    })))
}

#[cfg(test)]
mod tests;
