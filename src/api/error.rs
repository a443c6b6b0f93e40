//! The HTTP layer's one error type and its mapping to status codes
//! (`docs/rest-api.md`, "Errors"): every failure leaves as
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
use crate::canopen::nmt::NmtState;
use crate::canopen::od::{DictionaryError, ValueError};
use crate::canopen::sdo::AbortCode;
use crate::gateway::GatewayError;
use crate::gateway::logger::LoggerError;
use crate::gateway::recording::RecordingError;
use crate::gateway::registry::RegistryError;
use crate::gateway::sdo::SdoRequestError;

/// Why a request failed.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// The body or a parameter cannot be read (malformed JSON, a missing
    /// field, a node id that is no number).
    #[error("{0}")]
    InvalidRequest(String),
    #[error("{0}")]
    InvalidIndex(String),
    #[error("{0}")]
    InvalidValue(String),
    #[error("{0}")]
    ValueOutOfRange(String),
    #[error("no bus is named '{0}'")]
    UnknownBus(String),
    #[error("node {node} is not known on bus {bus} (try POST /api/v1/buses/{bus}/scan)")]
    UnknownNode { bus: String, node: String },
    #[error("{0}")]
    UnknownObject(String),
    #[error("{0}")]
    UnknownSubObject(String),
    /// No route has this path.
    #[error("no such endpoint: {0}")]
    NoRoute(String),
    #[error("method {method} is not allowed on {path}")]
    MethodNotAllowed { method: String, path: String },
    /// CiA 301 allows no SDO in this NMT state; refused before the bus.
    #[error("node {node} is {state}: SDO is not allowed in this NMT state", state = .state.name())]
    WrongNmtState { node: u8, state: NmtState },
    #[error("node {node} refused: {}", .code.text())]
    SdoAbort { node: u8, code: AbortCode },
    /// The device answered, but not by the protocol; the gateway aborted.
    #[error("node {node} broke the SDO protocol ({detail}); the gateway aborted with {code}")]
    SdoProtocol {
        node: u8,
        code: AbortCode,
        detail: String,
    },
    #[error("{0}")]
    BusDown(String),
    #[error("node {node} did not answer in time")]
    SdoTimeout { node: u8 },
    /// The node has no segments (its profile is not uioled).
    #[error("{0}")]
    NotAnLedController(String),
    #[error("{0}")]
    UnknownSegment(String),
    /// A DCF that cannot be read; nothing was written.
    #[error("{message}")]
    InvalidDcf {
        message: String,
        line: Option<usize>,
    },
    /// The node has no axes (its profile is not umc, jmc_stepper or
    /// cia402).
    #[error("{0}")]
    NotADrive(String),
    #[error("{0}")]
    UnknownAxis(String),
    /// The drive is in fault (or went there during a state walk).
    #[error("{message}")]
    DriveFault { message: String, state: String },
    /// A move asks for operation enabled.
    #[error("{message}")]
    DriveNotEnabled { message: String, state: String },
    #[error("{0}")]
    ModeNotSupported(String),
    /// The drive did not reach a state (mode, acknowledge) in time.
    #[error("{message}")]
    StateChangeTimeout { message: String, state: String },
    /// A PDO number (or kind) the node does not have.
    #[error("{0}")]
    UnknownPdo(String),
    /// A PDO mapping or communication parameter the node's EDS rules out.
    #[error("{0}")]
    InvalidMapping(String),
    /// The PDO is not valid (COB-ID bit 31 set): the node ignores its frames.
    #[error("{0}")]
    PdoDisabled(String),
    /// A sequence of transfers stopped at `step`: the error of that step,
    /// with the step named (the steps before it took effect).
    #[error("step {step} failed: {source}")]
    FailedAt { step: String, source: Box<AppError> },
    /// A stop the drive did not confirm: the error of the stop asked for,
    /// with every step tried (the fallbacks included) and its outcome.
    #[error("{source}")]
    StopNotConfirmed {
        source: Box<AppError>,
        attempts: Vec<crate::gateway::safe_stop::StopAttempt>,
    },
    /// A `/sim` request on a bus that has no virtual devices.
    #[error("bus {0} is no virtual bus: it has no virtual devices to control")]
    NotVirtual(String),
    /// No virtual device at this node id of a virtual bus.
    #[error("no virtual device is at node {node} of bus {bus}")]
    UnknownDevice { bus: String, node: u8 },
    /// A virtual device is added at a node id another one has.
    #[error("{0}")]
    NodeTaken(String),
    /// The virtual device's product cannot have this fault.
    #[error("{0}")]
    FaultNotApplicable(String),
    /// A recording of the bus runs already.
    #[error("{0}")]
    RecordingRunning(String),
    /// The bus's recording has stopped already.
    #[error("{0}")]
    RecordingNotRunning(String),
    /// The bus has no recording (none since the gateway started, or its
    /// file is gone).
    #[error("{0}")]
    NoRecording(String),
    /// The recording's file could not be made or read (disk full, no
    /// permission): the gateway's machine, not the request.
    #[error("{0}")]
    RecordingFailed(String),
    /// A drive node whose heartbeat is lost: refused at once rather than
    /// after an SDO timeout per transfer.
    #[error("{0}")]
    NodeOffline(String),
    /// The axis is held by another client's motion lease.
    #[error("{0}")]
    LeaseConflict(String),
    /// A lease that is not held (lapsed, ended, or never granted).
    #[error("{0}")]
    UnknownLease(String),
    /// A plain HTTP request to an endpoint that speaks WebSocket only.
    #[error("this endpoint speaks WebSocket only: {0}")]
    UpgradeRequired(String),
    /// A request body larger than the gateway reads.
    #[error("{0}")]
    PayloadTooLarge(String),
    /// A batch with more entries than one request may carry.
    #[error("{0}")]
    TooManyEntries(String),
    /// No token, or one the gateway does not know (the gateway asks for
    /// tokens); answered with `WWW-Authenticate: Bearer`.
    #[error("{0}")]
    Unauthenticated(String),
    /// The token's role is below the route's, or a cross-origin request
    /// the gateway does not allow.
    #[error("{0}")]
    Forbidden(String),
    /// The token sent more writes than its rate allows; answered with
    /// `Retry-After`.
    #[error("{message}")]
    RateLimited { message: String, retry_after_s: u64 },
    /// The `Host` the request was sent to is none of the gateway's names
    /// (DNS rebinding): answered 421 Misdirected Request.
    #[error("{0}")]
    HostNotAllowed(String),
    /// Every connection the HTTP server takes is in use; the reserve
    /// answers `/health` and `stop-all` only.
    #[error("{0}")]
    TooManyConnections(String),
    /// The history database failed (disk full, file damaged): the
    /// gateway's machine, not the request.
    #[error("{0}")]
    HistoryFailed(String),
    /// Another LSS transaction runs on the bus.
    #[error("{0}")]
    LssBusy(String),
    /// No device with the LSS address asked for answered.
    #[error("{0}")]
    LssNotFound(String),
    /// An LSS answer (or the boot-up after one) did not come in time.
    #[error("{0}")]
    LssTimeout(String),
    /// The LSS slave refused a configuration service.
    #[error("{0}")]
    LssRefused(String),
    /// The node-ID asked for is in use on the bus.
    #[error("{0}")]
    NodeIdInUse(String),
    /// The node's product cannot change its node-ID over SDO (no 0x2040).
    #[error("{0}")]
    NodeIdNotSupported(String),
    /// No EDS file of the catalog has this name.
    #[error("no EDS file is named '{0}'")]
    UnknownEds(String),
    /// An uploaded file that is no EDS; nothing was kept.
    #[error("{message}")]
    InvalidEds {
        message: String,
        line: Option<usize>,
    },
    /// An EDS file's name is taken, it is not an uploaded one, or a node is
    /// assigned to it.
    #[error("{0}")]
    EdsConflict(String),
    /// The node is no CiA 401 I/O module (its profile is not cia401).
    #[error("{0}")]
    NotAnIoModule(String),
    /// The I/O module has no such channel.
    #[error("{0}")]
    UnknownChannel(String),
    /// No data logger has this id.
    #[error("{0}")]
    UnknownLogger(String),
    /// Every data logger kept still runs.
    #[error("{0}")]
    TooManyLoggers(String),
    /// An object a data logger cannot sample (write-only, no number).
    #[error("{0}")]
    NotLoggable(String),
    /// The device does not identify a downloaded program as the one sent.
    #[error("{0}")]
    ProgramNotVerified(String),
    /// A fault of the gateway itself: logged in full, reported in short.
    #[error("internal error")]
    Internal(String),
}

impl AppError {
    /// Status and code, in one place.
    fn status_and_code(&self) -> (StatusCode, &'static str) {
        match self {
            Self::InvalidRequest(_) => (StatusCode::BAD_REQUEST, "invalid_request"),
            Self::InvalidIndex(_) => (StatusCode::BAD_REQUEST, "invalid_index"),
            Self::InvalidValue(_) => (StatusCode::BAD_REQUEST, "invalid_value"),
            Self::ValueOutOfRange(_) => (StatusCode::BAD_REQUEST, "value_out_of_range"),
            Self::UnknownBus(_) => (StatusCode::NOT_FOUND, "unknown_bus"),
            Self::UnknownNode { .. } => (StatusCode::NOT_FOUND, "unknown_node"),
            Self::UnknownObject(_) => (StatusCode::NOT_FOUND, "unknown_object"),
            Self::UnknownSubObject(_) => (StatusCode::NOT_FOUND, "unknown_sub_object"),
            Self::NoRoute(_) => (StatusCode::NOT_FOUND, "not_found"),
            Self::MethodNotAllowed { .. } => (StatusCode::METHOD_NOT_ALLOWED, "method_not_allowed"),
            Self::WrongNmtState { .. } => (StatusCode::CONFLICT, "wrong_nmt_state"),
            Self::SdoAbort { .. } => (StatusCode::UNPROCESSABLE_ENTITY, "sdo_abort"),
            Self::SdoProtocol { .. } => (StatusCode::BAD_GATEWAY, "sdo_protocol_error"),
            Self::BusDown(_) => (StatusCode::SERVICE_UNAVAILABLE, "bus_down"),
            Self::SdoTimeout { .. } => (StatusCode::GATEWAY_TIMEOUT, "sdo_timeout"),
            Self::NotAnLedController(_) => (StatusCode::NOT_FOUND, "not_an_led_controller"),
            Self::UnknownSegment(_) => (StatusCode::NOT_FOUND, "unknown_segment"),
            Self::InvalidDcf { .. } => (StatusCode::BAD_REQUEST, "invalid_dcf"),
            Self::NotADrive(_) => (StatusCode::NOT_FOUND, "not_a_drive"),
            Self::UnknownAxis(_) => (StatusCode::NOT_FOUND, "unknown_axis"),
            Self::DriveFault { .. } => (StatusCode::CONFLICT, "drive_fault"),
            Self::DriveNotEnabled { .. } => (StatusCode::CONFLICT, "drive_not_enabled"),
            Self::ModeNotSupported(_) => (StatusCode::UNPROCESSABLE_ENTITY, "mode_not_supported"),
            Self::StateChangeTimeout { .. } => {
                (StatusCode::GATEWAY_TIMEOUT, "state_change_timeout")
            }
            Self::UnknownPdo(_) => (StatusCode::NOT_FOUND, "unknown_pdo"),
            Self::InvalidMapping(_) => (StatusCode::BAD_REQUEST, "invalid_mapping"),
            Self::PdoDisabled(_) => (StatusCode::CONFLICT, "pdo_disabled"),
            Self::FailedAt { source, .. } | Self::StopNotConfirmed { source, .. } => {
                source.status_and_code()
            }
            Self::NotVirtual(_) => (StatusCode::CONFLICT, "not_virtual"),
            Self::UnknownDevice { .. } => (StatusCode::NOT_FOUND, "unknown_node"),
            Self::NodeTaken(_) => (StatusCode::CONFLICT, "node_taken"),
            Self::FaultNotApplicable(_) => {
                (StatusCode::UNPROCESSABLE_ENTITY, "fault_not_applicable")
            }
            Self::RecordingRunning(_) => (StatusCode::CONFLICT, "recording_running"),
            Self::RecordingNotRunning(_) => (StatusCode::CONFLICT, "recording_not_running"),
            Self::NoRecording(_) => (StatusCode::NOT_FOUND, "no_recording"),
            Self::RecordingFailed(_) => (StatusCode::INTERNAL_SERVER_ERROR, "recording_failed"),
            Self::NodeOffline(_) => (StatusCode::CONFLICT, "node_offline"),
            Self::LeaseConflict(_) => (StatusCode::CONFLICT, "lease_conflict"),
            Self::UnknownLease(_) => (StatusCode::NOT_FOUND, "unknown_lease"),
            Self::UpgradeRequired(_) => (StatusCode::UPGRADE_REQUIRED, "upgrade_required"),
            Self::PayloadTooLarge(_) => (StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large"),
            Self::TooManyEntries(_) => (StatusCode::BAD_REQUEST, "too_many_entries"),
            Self::Unauthenticated(_) => (StatusCode::UNAUTHORIZED, "unauthenticated"),
            Self::Forbidden(_) => (StatusCode::FORBIDDEN, "forbidden"),
            Self::RateLimited { .. } => (StatusCode::TOO_MANY_REQUESTS, "rate_limited"),
            Self::HostNotAllowed(_) => (StatusCode::MISDIRECTED_REQUEST, "host_not_allowed"),
            Self::TooManyConnections(_) => {
                (StatusCode::SERVICE_UNAVAILABLE, "too_many_connections")
            }
            Self::HistoryFailed(_) => (StatusCode::INTERNAL_SERVER_ERROR, "history_failed"),
            Self::LssBusy(_) => (StatusCode::CONFLICT, "lss_busy"),
            Self::LssNotFound(_) => (StatusCode::NOT_FOUND, "lss_not_found"),
            Self::LssTimeout(_) => (StatusCode::GATEWAY_TIMEOUT, "lss_timeout"),
            Self::LssRefused(_) => (StatusCode::UNPROCESSABLE_ENTITY, "lss_refused"),
            Self::NodeIdInUse(_) => (StatusCode::CONFLICT, "node_id_in_use"),
            Self::NodeIdNotSupported(_) => (
                StatusCode::UNPROCESSABLE_ENTITY,
                "node_id_change_not_supported",
            ),
            Self::UnknownEds(_) => (StatusCode::NOT_FOUND, "unknown_eds"),
            Self::InvalidEds { .. } => (StatusCode::BAD_REQUEST, "invalid_eds"),
            Self::EdsConflict(_) => (StatusCode::CONFLICT, "eds_conflict"),
            Self::NotAnIoModule(_) => (StatusCode::NOT_FOUND, "not_an_io_module"),
            Self::UnknownChannel(_) => (StatusCode::NOT_FOUND, "unknown_channel"),
            Self::UnknownLogger(_) => (StatusCode::NOT_FOUND, "unknown_logger"),
            Self::TooManyLoggers(_) => (StatusCode::CONFLICT, "too_many_loggers"),
            Self::NotLoggable(_) => (StatusCode::UNPROCESSABLE_ENTITY, "not_loggable"),
            Self::ProgramNotVerified(_) => (StatusCode::BAD_GATEWAY, "program_not_verified"),
            Self::Internal(_) => (StatusCode::INTERNAL_SERVER_ERROR, "internal_error"),
        }
    }

    pub fn status(&self) -> StatusCode {
        self.status_and_code().0
    }

    /// The `{"code", "message", ...}` object, also used for one failed
    /// entry of a batch.
    pub fn to_json(&self) -> Json {
        let (_, code) = self.status_and_code();
        if let Self::FailedAt { step, source } = self {
            let mut body = source.to_json();
            body["message"] = json!(self.to_string());
            body["step"] = json!(step);
            return body;
        }
        if let Self::StopNotConfirmed { source, attempts } = self {
            let mut body = source.to_json();
            body["attempts"] = json!(attempts);
            return body;
        }
        let mut body = json!({ "code": code, "message": self.to_string() });
        match self {
            Self::SdoAbort { code, .. } | Self::SdoProtocol { code, .. } => {
                body["abort_code"] = json!(format!("0x{:08X}", code.raw()));
                body["abort_text"] = json!(code.text());
            }
            Self::WrongNmtState { state, .. } => body["nmt"] = json!(state.name()),
            Self::InvalidDcf {
                line: Some(line), ..
            }
            | Self::InvalidEds {
                line: Some(line), ..
            } => body["line"] = json!(line),
            Self::DriveFault { state, .. }
            | Self::DriveNotEnabled { state, .. }
            | Self::StateChangeTimeout { state, .. } => body["state"] = json!(state),
            Self::RateLimited { retry_after_s, .. } => body["retry_after_s"] = json!(retry_after_s),
            // Every error is rendered once, here: the one place to log
            // what the client is not told.
            Self::Internal(detail) => tracing::error!("api: {detail}"),
            _ => {}
        }
        body
    }

    /// A failed SDO transfer of `node`.
    pub fn from_sdo(error: SdoRequestError) -> Self {
        GatewayError::from(error).into()
    }
}

/// The gateway's errors, variant by variant (their statuses are those of
/// `AppError::status_and_code`).
impl From<GatewayError> for AppError {
    fn from(error: GatewayError) -> Self {
        match error {
            GatewayError::InvalidRequest(message) => Self::InvalidRequest(message),
            GatewayError::InvalidValue(message) => Self::InvalidValue(message),
            GatewayError::ValueOutOfRange(message) => Self::ValueOutOfRange(message),
            GatewayError::UnknownBus(bus) => Self::UnknownBus(bus),
            GatewayError::UnknownNode { bus, node } => Self::UnknownNode { bus, node },
            GatewayError::WrongNmtState { node, state } => Self::WrongNmtState { node, state },
            GatewayError::SdoAbort { node, code } => Self::SdoAbort { node, code },
            GatewayError::SdoProtocol { node, code, detail } => {
                Self::SdoProtocol { node, code, detail }
            }
            GatewayError::SdoTimeout { node } => Self::SdoTimeout { node },
            GatewayError::BusDown(message) => Self::BusDown(message),
            GatewayError::NodeOffline(message) => Self::NodeOffline(message),
            GatewayError::NotADrive(message) => Self::NotADrive(message),
            GatewayError::UnknownAxis(message) => Self::UnknownAxis(message),
            GatewayError::DriveFault { message, state } => Self::DriveFault { message, state },
            GatewayError::DriveNotEnabled { message, state } => {
                Self::DriveNotEnabled { message, state }
            }
            GatewayError::ModeNotSupported(message) => Self::ModeNotSupported(message),
            GatewayError::StateChangeTimeout { message, state } => {
                Self::StateChangeTimeout { message, state }
            }
            GatewayError::LeaseConflict(message) => Self::LeaseConflict(message),
            GatewayError::UnknownLease(message) => Self::UnknownLease(message),
            GatewayError::Unauthenticated(message) => Self::Unauthenticated(message),
            GatewayError::Forbidden(message) => Self::Forbidden(message),
            GatewayError::RateLimited {
                message,
                retry_after_s,
            } => Self::RateLimited {
                message,
                retry_after_s,
            },
            GatewayError::LssBusy(message) => Self::LssBusy(message),
            GatewayError::LssNotFound(message) => Self::LssNotFound(message),
            GatewayError::LssTimeout(message) => Self::LssTimeout(message),
            GatewayError::LssRefused(message) => Self::LssRefused(message),
            GatewayError::NodeIdInUse(message) => Self::NodeIdInUse(message),
            GatewayError::NodeIdNotSupported(message) => Self::NodeIdNotSupported(message),
            GatewayError::UnknownEds(name) => Self::UnknownEds(name),
            GatewayError::InvalidEds { message, line } => Self::InvalidEds { message, line },
            GatewayError::EdsConflict(message) => Self::EdsConflict(message),
            GatewayError::NotAnIoModule(message) => Self::NotAnIoModule(message),
            GatewayError::UnknownChannel(message) => Self::UnknownChannel(message),
            GatewayError::ProgramNotVerified(message) => Self::ProgramNotVerified(message),
            GatewayError::Internal(detail) => Self::Internal(detail),
        }
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
        let message = error.to_string();
        match error {
            RecordingError::LimitOutOfRange { .. } => Self::ValueOutOfRange(message),
            RecordingError::Running { .. } => Self::RecordingRunning(message),
            RecordingError::NotRunning { .. } => Self::RecordingNotRunning(message),
            RecordingError::NoRecording(_) => Self::NoRecording(message),
            RecordingError::Io { .. } => {
                tracing::error!("api: {message}");
                Self::RecordingFailed(message)
            }
        }
    }
}

impl From<DictionaryError> for AppError {
    fn from(error: DictionaryError) -> Self {
        match error {
            DictionaryError::UnknownObject(_) | DictionaryError::UnknownName(_) => {
                Self::UnknownObject(error.to_string())
            }
            DictionaryError::UnknownSubObject { .. } | DictionaryError::UnknownSubName { .. } => {
                Self::UnknownSubObject(error.to_string())
            }
            DictionaryError::InvalidIndex(_) | DictionaryError::InvalidSubIndex(_) => {
                Self::InvalidIndex(error.to_string())
            }
            DictionaryError::WrongType { .. } => Self::InvalidValue(error.to_string()),
        }
    }
}

impl From<ValueError> for AppError {
    fn from(error: ValueError) -> Self {
        if error.is_out_of_range() {
            Self::ValueOutOfRange(error.to_string())
        } else {
            Self::InvalidValue(error.to_string())
        }
    }
}

/// A logger's errors; a channel's say which channel (0-based).
impl From<LoggerError> for AppError {
    fn from(error: LoggerError) -> Self {
        let message = error.to_string();
        match error {
            LoggerError::ChannelCount(_) => Self::TooManyEntries(message),
            LoggerError::Period(_) | LoggerError::Duration(_) => Self::ValueOutOfRange(message),
            LoggerError::Channel { .. } => Self::InvalidIndex(message),
            LoggerError::NotLoggable { .. } => Self::NotLoggable(message),
            LoggerError::Dictionary { source, .. } => match Self::from(source) {
                Self::UnknownObject(_) => Self::UnknownObject(message),
                Self::UnknownSubObject(_) => Self::UnknownSubObject(message),
                Self::InvalidIndex(_) => Self::InvalidIndex(message),
                other => other,
            },
            // The gateway's own words (unknown_bus, unknown_node, an SDO
            // error of a trial read), with the channel's number.
            LoggerError::Gateway { channel, source } => match Self::from(source) {
                Self::FailedAt { .. } => Self::Internal(message),
                other => Self::FailedAt {
                    step: format!("channel {channel}"),
                    source: Box::new(other),
                },
            },
            LoggerError::TooMany => Self::TooManyLoggers(message),
            LoggerError::Unknown(_) => Self::UnknownLogger(message),
        }
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
            Self::Unauthenticated(_) => Some((
                axum::http::header::WWW_AUTHENTICATE,
                axum::http::HeaderValue::from_static("Bearer realm=\"candeck\""),
            )),
            Self::RateLimited { retry_after_s, .. } => Some((
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
