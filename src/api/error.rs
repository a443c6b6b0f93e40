//! The HTTP layer's one error type — the gateway's [`GatewayError`], or
//! one of HTTP's own (a body that cannot be read, no route, ...) — and its
//! mapping to status codes, once (`docs/rest-api.md`, "Errors"): every
//! failure leaves as
//! `{"error": {"code": "snake_case", "message": "human text", ...}}`.
//!
//! What the device said (SDO abort, 422), what the clock said (timeout, 504)
//! and what the bus did (down, 503) stay apart, as they do in
//! [`SdoRequestError`]. Internal detail is logged, never returned.

use axum::extract::rejection::{JsonRejection, PathRejection};
use axum::extract::{FromRequest, FromRequestParts, Request};
use axum::http::StatusCode;
use axum::http::request::Parts;
use axum::response::{IntoResponse, Response};
use serde_json::{Value as Json, json};

use crate::can::BusError;
use crate::canopen::od::{DictionaryError, ValueError};
use crate::gateway::GatewayError;
use crate::gateway::LoggerError;
use crate::gateway::RecordingError;
use crate::gateway::RegistryError;
use crate::gateway::SdoRequestError;
use crate::gateway::{LedError, PdoError, SimError};

/// Why a request failed: the gateway's error, or one of HTTP's own.
#[derive(Debug)]
pub enum AppError {
    /// What the gateway said (its one error type, whichever door asked).
    Gateway(GatewayError),
    /// The body, path or query cannot be read (malformed JSON, a missing
    /// field, a segment that is not UTF-8).
    InvalidRequest(String),
    /// A request body larger than the gateway reads.
    PayloadTooLarge(String),
    /// No route has this path.
    NoRoute(String),
    MethodNotAllowed {
        method: String,
        path: String,
    },
    /// A plain HTTP request to an endpoint that speaks WebSocket only.
    UpgradeRequired(String),
    /// The `Host` the request was sent to is none of the gateway's names
    /// (DNS rebinding): answered 421 Misdirected Request.
    HostNotAllowed(String),
    /// Every connection the HTTP server takes is in use; the reserve
    /// answers `/health` and `stop-all` only.
    TooManyConnections(String),
    /// The token or the peer holds as many WebSocket streams as it may
    /// (`stream_max_per_token`, `stream_max_per_peer`): answered 429.
    TooManyStreams(String),
}

/// The HTTP status of each of the gateway's errors, in one place (a failed
/// step and an unconfirmed stop answer as their cause).
pub fn status_of(error: &GatewayError) -> StatusCode {
    match error {
        GatewayError::InvalidRequest(_)
        | GatewayError::InvalidValue(_)
        | GatewayError::ValueOutOfRange(_)
        | GatewayError::InvalidEds { .. }
        | GatewayError::InvalidIndex(_)
        | GatewayError::TooManyEntries(_)
        | GatewayError::Pdo(PdoError::InvalidMapping(_))
        | GatewayError::InvalidDcf { .. } => StatusCode::BAD_REQUEST,
        GatewayError::CommandTooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
        GatewayError::Unauthenticated(_) => StatusCode::UNAUTHORIZED,
        GatewayError::Forbidden(_) | GatewayError::WatchdogProtected(_) => StatusCode::FORBIDDEN,
        GatewayError::UnknownBus(_)
        | GatewayError::UnknownNode { .. }
        | GatewayError::NotADrive(_)
        | GatewayError::UnknownAxis(_)
        | GatewayError::UnknownLease(_)
        | GatewayError::LssNotFound(_)
        | GatewayError::UnknownEds(_)
        | GatewayError::NotAnIoModule(_)
        | GatewayError::UnknownChannel(_)
        | GatewayError::UnknownObject(_)
        | GatewayError::UnknownSubObject(_)
        | GatewayError::Pdo(PdoError::UnknownPdo(_))
        | GatewayError::Led(LedError::NotAnLedController(_) | LedError::UnknownSegment(_))
        | GatewayError::Sim(SimError::UnknownDevice { .. })
        | GatewayError::NoRecording(_)
        | GatewayError::UnknownLogger(_)
        | GatewayError::UnknownAlarm(_) => StatusCode::NOT_FOUND,
        GatewayError::WrongNmtState { .. }
        | GatewayError::NodeOffline(_)
        | GatewayError::DriveFault { .. }
        | GatewayError::DriveNotEnabled { .. }
        | GatewayError::LeaseConflict(_)
        | GatewayError::MotionStopped(_)
        | GatewayError::NodeBusy(_)
        | GatewayError::AxisEnabled(_)
        | GatewayError::ClientGone(_)
        | GatewayError::LssBusy(_)
        | GatewayError::NodeIdInUse(_)
        | GatewayError::EdsConflict(_)
        | GatewayError::EdsQuota(_)
        | GatewayError::Pdo(PdoError::PdoDisabled(_))
        | GatewayError::Sim(SimError::NotVirtual(_) | SimError::NodeTaken(_))
        | GatewayError::RecordingRunning(_)
        | GatewayError::RecordingNotRunning(_)
        | GatewayError::TooManyLoggers(_) => StatusCode::CONFLICT,
        GatewayError::SdoAbort { .. }
        | GatewayError::ModeNotSupported(_)
        | GatewayError::StepBeyondFollowingWindow(_)
        | GatewayError::LssRefused(_)
        | GatewayError::NodeIdNotSupported(_)
        | GatewayError::Sim(SimError::FaultNotApplicable(_))
        | GatewayError::NotLoggable(_) => StatusCode::UNPROCESSABLE_ENTITY,
        GatewayError::RateLimited { .. } => StatusCode::TOO_MANY_REQUESTS,
        GatewayError::Internal(_)
        | GatewayError::RecordingFailed(_)
        | GatewayError::HistoryFailed(_) => StatusCode::INTERNAL_SERVER_ERROR,
        GatewayError::SdoProtocol { .. } | GatewayError::ProgramNotVerified(_) => {
            StatusCode::BAD_GATEWAY
        }
        GatewayError::BusDown(_) => StatusCode::SERVICE_UNAVAILABLE,
        GatewayError::SdoTimeout { .. }
        | GatewayError::StateChangeTimeout { .. }
        | GatewayError::LssTimeout(_) => StatusCode::GATEWAY_TIMEOUT,
        GatewayError::FailedAt { source, .. } | GatewayError::StopNotConfirmed { source, .. } => {
            status_of(source)
        }
    }
}

/// The message REST gives for a gateway error: the gateway's, but for the
/// hint of where to look for a node the registry does not know, and an
/// internal fault's detail, which is for the log.
fn message_of(error: &GatewayError) -> String {
    match error {
        GatewayError::UnknownNode { bus, node } => {
            format!("node {node} is not known on bus {bus} (try POST /api/v1/buses/{bus}/scan)")
        }
        GatewayError::Internal(_) => "internal error".to_string(),
        GatewayError::FailedAt { step, source } => {
            format!("step {step} failed: {}", message_of(source))
        }
        GatewayError::StopNotConfirmed { source, .. } => message_of(source),
        other => other.to_string(),
    }
}

/// The `{"code", "message", ...}` object of a gateway error.
pub fn body_of(error: &GatewayError) -> Json {
    match error {
        GatewayError::FailedAt { step, source } => {
            let mut body = body_of(source);
            body["message"] = json!(message_of(error));
            body["step"] = json!(step);
            return body;
        }
        GatewayError::StopNotConfirmed { source, attempts } => {
            let mut body = body_of(source);
            body["attempts"] = json!(attempts);
            return body;
        }
        _ => {}
    }
    let mut body = json!({ "code": error.code(), "message": message_of(error) });
    match error {
        GatewayError::SdoAbort { code, .. } | GatewayError::SdoProtocol { code, .. } => {
            body["abort_code"] = json!(format!("0x{:08X}", code.raw()));
            body["abort_text"] = json!(code.text());
        }
        GatewayError::WrongNmtState { state, .. } => body["nmt"] = json!(state.name()),
        GatewayError::InvalidDcf {
            line: Some(line), ..
        }
        | GatewayError::InvalidEds {
            line: Some(line), ..
        } => body["line"] = json!(line),
        GatewayError::DriveFault { state, .. }
        | GatewayError::DriveNotEnabled { state, .. }
        | GatewayError::StateChangeTimeout { state, .. } => body["state"] = json!(state),
        GatewayError::RateLimited { retry_after_s, .. } => {
            body["retry_after_s"] = json!(retry_after_s)
        }
        // Every error is rendered once, here: the one place to log what
        // the client is not told.
        GatewayError::Internal(detail) => tracing::error!("api: {detail}"),
        _ => {}
    }
    body
}

impl std::fmt::Display for AppError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Gateway(error) => f.write_str(&message_of(error)),
            Self::InvalidRequest(message)
            | Self::PayloadTooLarge(message)
            | Self::HostNotAllowed(message)
            | Self::TooManyConnections(message)
            | Self::TooManyStreams(message) => f.write_str(message),
            Self::NoRoute(path) => write!(f, "no such endpoint: {path}"),
            Self::MethodNotAllowed { method, path } => {
                write!(f, "method {method} is not allowed on {path}")
            }
            Self::UpgradeRequired(message) => {
                write!(f, "this endpoint speaks WebSocket only: {message}")
            }
        }
    }
}

impl std::error::Error for AppError {}

impl AppError {
    pub fn status(&self) -> StatusCode {
        match self {
            Self::Gateway(error) => status_of(error),
            Self::InvalidRequest(_) => StatusCode::BAD_REQUEST,
            Self::PayloadTooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            Self::NoRoute(_) => StatusCode::NOT_FOUND,
            Self::MethodNotAllowed { .. } => StatusCode::METHOD_NOT_ALLOWED,
            Self::UpgradeRequired(_) => StatusCode::UPGRADE_REQUIRED,
            Self::HostNotAllowed(_) => StatusCode::MISDIRECTED_REQUEST,
            Self::TooManyConnections(_) => StatusCode::SERVICE_UNAVAILABLE,
            Self::TooManyStreams(_) => StatusCode::TOO_MANY_REQUESTS,
        }
    }

    /// The `{"code", "message", ...}` object, also used for one failed
    /// entry of a batch.
    pub fn to_json(&self) -> Json {
        let code = match self {
            Self::Gateway(error) => return body_of(error),
            Self::InvalidRequest(_) => "invalid_request",
            Self::PayloadTooLarge(_) => "payload_too_large",
            Self::NoRoute(_) => "not_found",
            Self::MethodNotAllowed { .. } => "method_not_allowed",
            Self::UpgradeRequired(_) => "upgrade_required",
            Self::HostNotAllowed(_) => "host_not_allowed",
            Self::TooManyConnections(_) => "too_many_connections",
            Self::TooManyStreams(_) => "too_many_streams",
        };
        json!({ "code": code, "message": self.to_string() })
    }

    /// A failed SDO transfer of `node`.
    pub fn from_sdo(error: SdoRequestError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<GatewayError> for AppError {
    fn from(error: GatewayError) -> Self {
        Self::Gateway(error)
    }
}

impl From<PdoError> for AppError {
    fn from(error: PdoError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<LedError> for AppError {
    fn from(error: LedError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<SimError> for AppError {
    fn from(error: SimError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<BusError> for AppError {
    fn from(error: BusError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<RegistryError> for AppError {
    fn from(error: RegistryError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<RecordingError> for AppError {
    fn from(error: RecordingError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<DictionaryError> for AppError {
    fn from(error: DictionaryError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<ValueError> for AppError {
    fn from(error: ValueError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<LoggerError> for AppError {
    fn from(error: LoggerError) -> Self {
        GatewayError::from(error).into()
    }
}

impl From<JsonRejection> for AppError {
    fn from(rejection: JsonRejection) -> Self {
        if rejection.status() == StatusCode::PAYLOAD_TOO_LARGE {
            return Self::PayloadTooLarge(rejection.body_text());
        }
        Self::InvalidRequest(rejection.body_text())
    }
}

impl From<PathRejection> for AppError {
    fn from(rejection: PathRejection) -> Self {
        Self::InvalidRequest(rejection.body_text())
    }
}

/// What an error response was, for the audit log (a response extension,
/// so the audit layer need not parse the body).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ErrorSummary {
    pub code: String,
    /// `0x06090030` for an SDO abort (also inside a failed step).
    pub abort_code: Option<String>,
}

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        let status = self.status();
        let body = self.to_json();
        let extra_header = match &self {
            Self::Gateway(GatewayError::Unauthenticated(_)) => Some((
                axum::http::header::WWW_AUTHENTICATE,
                axum::http::HeaderValue::from_static("Bearer realm=\"candeck\""),
            )),
            Self::Gateway(GatewayError::RateLimited { retry_after_s, .. }) => Some((
                axum::http::header::RETRY_AFTER,
                axum::http::HeaderValue::from(*retry_after_s),
            )),
            _ => None,
        };
        let summary = ErrorSummary {
            code: body["code"].as_str().unwrap_or_default().to_string(),
            abort_code: body["abort_code"].as_str().map(str::to_string),
        };
        let mut response = (status, axum::Json(json!({ "error": body }))).into_response();
        response.extensions_mut().insert(summary);
        if let Some((name, value)) = extra_header {
            response.headers_mut().insert(name, value);
        }
        response
    }
}

/// `axum::Json` whose rejection (malformed JSON, wrong content type, a
/// missing field) is an [`AppError`], so it has the API's error shape.
#[derive(Debug, Clone, Copy, Default)]
pub struct ApiJson<T>(pub T);

impl<T, S> FromRequest<S> for ApiJson<T>
where
    axum::Json<T>: FromRequest<S, Rejection = JsonRejection>,
    S: Send + Sync,
{
    type Rejection = AppError;

    async fn from_request(request: Request, state: &S) -> Result<Self, Self::Rejection> {
        let axum::Json(value) = axum::Json::<T>::from_request(request, state).await?;
        Ok(Self(value))
    }
}

impl<T: serde::Serialize> IntoResponse for ApiJson<T> {
    fn into_response(self) -> Response {
        axum::Json(self.0).into_response()
    }
}

/// `axum::extract::Path` whose rejection (a segment that is not UTF-8 once
/// percent-decoded) is an [`AppError`].
#[derive(Debug, Clone, Copy, Default)]
pub struct ApiPath<T>(pub T);

impl<T, S> FromRequestParts<S> for ApiPath<T>
where
    axum::extract::Path<T>: FromRequestParts<S, Rejection = PathRejection>,
    S: Send + Sync,
{
    type Rejection = AppError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, Self::Rejection> {
        let axum::extract::Path(value) =
            axum::extract::Path::<T>::from_request_parts(parts, state).await?;
        Ok(Self(value))
    }
}

/// Answers for paths no router has.
pub async fn no_route(axum::extract::OriginalUri(uri): axum::extract::OriginalUri) -> AppError {
    AppError::NoRoute(uri.path().to_string())
}

/// Answers for a known path with a method it does not take.
pub async fn method_not_allowed(
    method: axum::http::Method,
    axum::extract::OriginalUri(uri): axum::extract::OriginalUri,
) -> AppError {
    AppError::MethodNotAllowed {
        method: method.to_string(),
        path: uri.path().to_string(),
    }
}

#[cfg(test)]
mod tests;
// One sample of every error, for the other doors' mappings (OPC UA's).
#[cfg(test)]
pub(crate) use tests::{VARIANTS, samples};
