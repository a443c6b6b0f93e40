//! Who may do what (issue 8, point 1): bearer tokens with a name and a role,
//! the one table of the least role of every route ([`ROUTES`]), and the one
//! middleware ([`guard`]) that applies it, together with what keeps other
//! web pages and greedy clients out: the origin check and CORS preflights,
//! request body limits, and a per-token rate limit on writes.
//!
//! Bearer tokens as RFC 6750 sends them (`Authorization: Bearer TOKEN`);
//! a browser cannot set that header on a WebSocket, so the stream also
//! takes the token as a subprotocol (RFC 6455, 4.1: `Sec-WebSocket-Protocol:
//! candeck.v1, bearer.TOKEN`; the answer names `candeck.v1` only). Never in
//! the URL: a query ends in proxy and access logs.
//!
//! Without tokens the gateway is open (`candeck serve` allows that on a
//! loopback address only, or with `--insecure`); the origin check applies
//! either way, so that a web page a floor PC visits cannot send writes to
//! an open gateway on `127.0.0.1`.

use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::doc::ErrorBody;
use super::{AppError, AppState};
use crate::gateway::GatewayError;
use crate::gateway::Operation;
use crate::gateway::Tokens;
pub use crate::gateway::{RateLimit, Role, Token};

/// What a route asks of a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Anyone: it carries no data from the devices.
    Public,
    /// What the gateway's operation of that kind needs of its caller
    /// ([`Operation::required_role`]): REST asks before it reads a body,
    /// the operation asks again whichever door called it.
    Operation(Operation),
    /// A path no route has (404 after authentication): a token of this
    /// role or above, so that only who could have asked learns it.
    Unrouted(Role),
}

impl Access {
    /// The least role it needs; none for a public route.
    pub fn role(self) -> Option<Role> {
        match self {
            Self::Public => None,
            Self::Operation(kind) => Some(kind.required_role()),
            Self::Unrouted(role) => Some(role),
        }
    }
}

const PUBLIC: Access = Access::Public;
const VIEW: Access = Access::Operation(Operation::View);
const fn op(kind: Operation) -> Access {
    Access::Operation(kind)
}

/// The operation of every route: method (`*` any), path pattern
/// (`{name}` one segment, `{*name}` the rest), access (the roles are the
/// gateway's, one per kind of operation). The first entry
/// that matches decides; a test fails when a route of the router has no
/// entry here, so a new route is one line here.
#[rustfmt::skip]
pub static ROUTES: &[(&str, &str, Access)] = &[
    // Container health checks ask without a token.
    ("GET",    "/api/v1/health", PUBLIC),
    ("GET",    "/api/v1/auth/whoami", VIEW),
    ("GET",    "/api/v1/buses", VIEW),
    ("GET",    "/api/v1/buses/{bus}/nodes", VIEW),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}", VIEW),
    // A scan reads identities only, but adds nodes and marks silent ones
    // offline: it changes the gateway.
    ("POST",   "/api/v1/buses/{bus}/scan", op(Operation::Scan)),
    ("POST",   "/api/v1/buses/{bus}/nmt", op(Operation::Nmt)),
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/nmt", op(Operation::Nmt)),
    ("GET",    "/api/v1/buses/{bus}/machine", VIEW),
    // Runs a node's boot-up again: configuration download and NMT start.
    ("POST",   "/api/v1/buses/{bus}/machine/nodes/{id}/boot", op(Operation::BootNode)),
    // The machine's recovery: each axis's own operation takes its write.
    ("POST",   "/api/v1/buses/{bus}/machine/reset-faults", op(Operation::RecoverMachine)),
    ("POST",   "/api/v1/buses/{bus}/machine/enable", op(Operation::RecoverMachine)),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}/od", VIEW),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}/od/{index}/{sub}", VIEW),
    ("PUT",    "/api/v1/buses/{bus}/nodes/{id}/od/{index}/{sub}", op(Operation::WriteObject)),
    // A batch of reads, a POST only because it has a body.
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/od/read", VIEW),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}/segments", VIEW),
    ("PUT",    "/api/v1/buses/{bus}/nodes/{id}/segments", op(Operation::SetLeds)),
    ("PUT",    "/api/v1/buses/{bus}/nodes/{id}/segments/{n}", op(Operation::SetLeds)),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}/segments/preview", VIEW),
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/store", op(Operation::StoreRestore)),
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/restore", op(Operation::StoreRestore)),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}/config.dcf", VIEW),
    ("PUT",    "/api/v1/buses/{bus}/nodes/{id}/config.dcf", op(Operation::RestoreConfiguration)),
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/program", op(Operation::DownloadProgram)),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}/axes", VIEW),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}/axes/{axis}", VIEW),
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/axes/{axis}/state", op(Operation::Motion)),
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/axes/{axis}/fault-reset", op(Operation::Motion)),
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/axes/{axis}/halt", op(Operation::Motion)),
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/axes/{axis}/move", op(Operation::Motion)),
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/axes/{axis}/step-test", op(Operation::Motion)),
    // Renewing the motion lease of a move the operator started.
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/axes/{axis}/lease", op(Operation::RenewLease)),
    // A safety function: whoever watches a machine may stop it, as anyone
    // may press an emergency stop; it can only stop motion, and the log
    // names the token. Never rate limited.
    ("POST",   "/api/v1/stop-all", op(Operation::StopAll)),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}/values", VIEW),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}/io", VIEW),
    ("PUT",    "/api/v1/buses/{bus}/nodes/{id}/io", op(Operation::SetOutputs)),
    ("GET",    "/api/v1/buses/{bus}/nodes/{id}/pdos", VIEW),
    ("PUT",    "/api/v1/buses/{bus}/nodes/{id}/pdos/{kind}/{n}", op(Operation::ConfigurePdo)),
    // The bus tools of commissioning (issue 21): process data straight to a
    // device's mapped objects, the bus's SYNC and raw frames are the
    // operator's, as motion and NMT are, and audited as every write.
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/pdos/rpdo/{n}/send", op(Operation::SendRpdo)),
    ("GET",    "/api/v1/buses/{bus}/sync", VIEW),
    ("PUT",    "/api/v1/buses/{bus}/sync", op(Operation::SetSync)),
    ("GET",    "/api/v1/buses/{bus}/frames", VIEW),
    ("POST",   "/api/v1/buses/{bus}/frames", op(Operation::SendFrame)),
    ("GET",    "/api/v1/buses/{bus}/recording", VIEW),
    ("POST",   "/api/v1/buses/{bus}/recording", op(Operation::Record)),
    ("DELETE", "/api/v1/buses/{bus}/recording", op(Operation::Record)),
    ("GET",    "/api/v1/buses/{bus}/recording.log", VIEW),
    // LSS reconfigures the bus's node-IDs: the administrator's.
    ("POST",   "/api/v1/buses/{bus}/lss/scan", op(Operation::Lss)),
    ("POST",   "/api/v1/buses/{bus}/lss/configure", op(Operation::Lss)),
    // A node-ID change of one node, as its operator's NMT reset is.
    ("POST",   "/api/v1/buses/{bus}/nodes/{id}/node-id", op(Operation::ChangeNodeId)),
    ("GET",    "/api/v1/buses/{bus}/sim/nodes", VIEW),
    ("POST",   "/api/v1/buses/{bus}/sim/nodes", op(Operation::VirtualDevices)),
    ("DELETE", "/api/v1/buses/{bus}/sim/nodes/{id}", op(Operation::VirtualDevices)),
    ("POST",   "/api/v1/buses/{bus}/sim/nodes/{id}/faults", op(Operation::VirtualDevices)),
    ("DELETE", "/api/v1/buses/{bus}/sim/nodes/{id}/faults", op(Operation::VirtualDevices)),
    ("POST",   "/api/v1/buses/{bus}/sim/faults", op(Operation::VirtualDevices)),
    ("DELETE", "/api/v1/buses/{bus}/sim/faults", op(Operation::VirtualDevices)),
    // Data loggers: sampling takes the nodes' SDO queues, as an operator's
    // reads would; reading what they sampled is a viewer's.
    ("GET",    "/api/v1/loggers", VIEW),
    ("POST",   "/api/v1/loggers", op(Operation::Logger)),
    ("GET",    "/api/v1/loggers/{id}", VIEW),
    ("DELETE", "/api/v1/loggers/{id}", op(Operation::Logger)),
    ("GET",    "/api/v1/loggers/{id}/data.csv", VIEW),
    // Alarms: acknowledging is an operator's word that they saw them; it
    // changes no device.
    ("GET",    "/api/v1/alarms", VIEW),
    ("POST",   "/api/v1/alarms/ack", op(Operation::AcknowledgeAlarm)),
    ("GET",    "/api/v1/alarms/{id}", VIEW),
    ("POST",   "/api/v1/alarms/{id}/ack", op(Operation::AcknowledgeAlarm)),
    ("GET",    "/api/v1/stream", VIEW),
    ("GET",    "/api/v1/events", VIEW),
    ("GET",    "/api/v1/eds", VIEW),
    ("POST",   "/api/v1/eds", op(Operation::ManageEds)),
    ("DELETE", "/api/v1/eds/{name}", op(Operation::ManageEds)),
    ("PUT",    "/api/v1/buses/{bus}/nodes/{id}/eds", op(Operation::AssignEds)),
    ("DELETE", "/api/v1/buses/{bus}/nodes/{id}/eds", op(Operation::AssignEds)),
    ("GET",    "/metrics", VIEW),
    // The interface's description: no data, and the docs UI is where one
    // enters a token to try the API ("Authorize"). `/api/docs` redirects
    // to `/api/docs/`, the UI's page.
    ("GET",    "/api/openapi.json", PUBLIC),
    ("GET",    "/api/docs", PUBLIC),
    ("GET",    "/api/docs/", PUBLIC),
    ("GET",    "/api/docs/{*file}", PUBLIC),
    // CiA 309-5 (the gateway protocol): its SDO reads for viewers, its SDO
    // writes and NMT commands for operators, as the same requests through
    // /api/v1 (od PUT, nmt POST).
    ("GET",    "/cia309-5/{*rest}", VIEW),
    ("*",      "/cia309-5/{*rest}", op(Operation::WriteObject)),
    // The dashboard's pages and static files: layout only, the data comes
    // from the API (each page asks for a token when the API wants one).
    ("GET",    "/", PUBLIC),
    ("GET",    "/static/{version}/{*path}", PUBLIC),
];

/// A write to a path no route has: as if it were the admin's (the safe
/// side).
const UNROUTED_WRITE: Access = Access::Unrouted(Role::Admin);

/// What applies to requests no entry of [`ROUTES`] matches: unknown API
/// paths (404 after authentication; writes to them as if they were
/// admin's, the safe side), and every other `GET` outside the API — the
/// dashboard's pages, which hold no data.
#[rustfmt::skip]
pub static FALLBACK: &[(&str, &str, Access)] = &[
    ("GET", "/api/{*rest}", VIEW),
    ("*",   "/api/{*rest}", UNROUTED_WRITE),
    ("GET", "/metrics/{*rest}", VIEW),
    ("GET", "/{*page}", PUBLIC),
    ("*",   "/{*rest}", UNROUTED_WRITE),
];

/// Whether `path` fits `pattern` (see [`ROUTES`]).
pub fn matches(pattern: &str, path: &str) -> bool {
    let mut path_segments = path.split('/');
    for expected in pattern.split('/') {
        if expected.starts_with("{*") {
            // A wildcard takes at least one segment, as axum's does.
            return path_segments.next().is_some_and(|s| !s.is_empty());
        }
        let Some(segment) = path_segments.next() else {
            return false;
        };
        let is_param = expected.starts_with('{') && expected.ends_with('}');
        if !(is_param && !segment.is_empty() || segment == expected) {
            return false;
        }
    }
    path_segments.next().is_none()
}

fn method_fits(entry: &str, method: &Method) -> bool {
    // HEAD is answered by GET routes.
    let method = if *method == Method::HEAD {
        "GET"
    } else {
        method.as_str()
    };
    entry == "*" || entry == method
}

/// The entry of [`ROUTES`] for a request, if any.
pub fn route_entry(
    method: &Method,
    path: &str,
) -> Option<&'static (&'static str, &'static str, Access)> {
    ROUTES
        .iter()
        .find(|(m, pattern, _)| method_fits(m, method) && matches(pattern, path))
}

/// What a request needs: its entry of [`ROUTES`], else of [`FALLBACK`].
pub fn required(method: &Method, path: &str) -> Access {
    route_entry(method, path)
        .or_else(|| {
            FALLBACK
                .iter()
                .find(|(m, pattern, _)| method_fits(m, method) && matches(pattern, path))
        })
        .map_or(UNROUTED_WRITE, |(_, _, access)| *access)
}

/// The largest request body by default (JSON bodies are small).
pub const DEFAULT_BODY_LIMIT: usize = 1024 * 1024;
/// The largest DCF upload by default (`PUT .../config.dcf`).
pub const DEFAULT_DCF_BODY_LIMIT: usize = 4 * 1024 * 1024;

/// The gateway's access settings.
#[derive(Debug, Clone)]
pub struct AuthConfig {
    /// No token: the gateway is open.
    pub tokens: Tokens,
    /// Origins (`https://scada.example`) allowed to call from other pages.
    pub cors_origins: Vec<String>,
    /// `None`: writes are not rate limited.
    pub rate_limit: Option<RateLimit>,
    pub body_limit: usize,
    pub dcf_body_limit: usize,
}

impl Default for AuthConfig {
    fn default() -> Self {
        Self {
            tokens: Tokens::default(),
            cors_origins: Vec::new(),
            rate_limit: Some(RateLimit::default()),
            body_limit: DEFAULT_BODY_LIMIT,
            dcf_body_limit: DEFAULT_DCF_BODY_LIMIT,
        }
    }
}

impl AuthConfig {
    /// The settings, checked: no two tokens of one name or one secret, no
    /// origin that is not `scheme://host[:port]`.
    pub fn new(
        tokens: Vec<Token>,
        cors_origins: Vec<String>,
        rate_limit: Option<RateLimit>,
        body_limit: usize,
        dcf_body_limit: usize,
    ) -> Result<Self, String> {
        Tokens::check(&tokens)?;
        for origin in &cors_origins {
            let valid = origin.split_once("://").is_some_and(|(scheme, host)| {
                matches!(scheme, "http" | "https") && !host.is_empty() && !host.contains('/')
            });
            if !valid {
                return Err(format!(
                    "cors_origins: '{origin}' is no origin like https://scada.example:8443 (no path, no trailing slash)"
                ));
            }
        }
        if let Some(rate) = rate_limit
            && !(rate.per_second.is_finite() && rate.per_second > 0.0 && rate.burst >= 1)
        {
            return Err(format!(
                "write rate limit: {} per second, burst {}: both must be above 0 (0 per second turns it off)",
                rate.per_second, rate.burst
            ));
        }
        if body_limit == 0 || dcf_body_limit == 0 {
            return Err("a body limit is at least 1 byte".to_string());
        }
        Ok(Self {
            tokens: Tokens::new(tokens),
            cors_origins,
            rate_limit,
            body_limit,
            dcf_body_limit,
        })
    }

    /// Whether requests need a token.
    pub fn required(&self) -> bool {
        self.tokens.required()
    }

    /// The token whose secret is `given` (see [`Tokens::find`]).
    pub fn token(&self, given: &str) -> Option<&Token> {
        self.tokens.find(given)
    }

    /// The largest body a request to `path` may carry.
    pub fn body_limit(&self, method: &Method, path: &str) -> usize {
        let eds_upload = *method == Method::POST && path == "/api/v1/eds";
        let program = *method == Method::POST && path.ends_with("/program");
        if eds_upload || program || *method == Method::PUT && path.ends_with("/config.dcf") {
            self.dcf_body_limit
        } else {
            self.body_limit
        }
    }

    /// The largest body of any request.
    pub fn largest_body(&self) -> usize {
        self.body_limit.max(self.dcf_body_limit)
    }
}

/// Who made a request: in the request's extensions (handlers) and the
/// response's (the audit log).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// The token's name; `anonymous` without one, `invalid-token` for a
    /// token nobody configured.
    pub name: String,
    /// `None` without a valid token.
    pub role: Option<Role>,
}

impl Identity {
    pub fn anonymous() -> Self {
        Self {
            name: "anonymous".to_string(),
            role: None,
        }
    }
}

/// The middleware's state: the settings. The write buckets are the
/// gateway service's ([`crate::gateway::Gateway::take_write`]), shared
/// with CiA 309-3.
pub struct Guard {
    pub config: AuthConfig,
}

impl Default for Guard {
    fn default() -> Self {
        Self::new(AuthConfig::default())
    }
}

impl std::fmt::Debug for Guard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Guard")
            .field("config", &self.config)
            .finish()
    }
}

impl Guard {
    pub fn new(config: AuthConfig) -> Self {
        Self { config }
    }

    /// Whether requests need a token (some are configured).
    pub fn required(&self) -> bool {
        self.config.required()
    }
}

/// The subprotocol the stream speaks; a browser sends its token as a
/// second one, `bearer.TOKEN`.
pub const STREAM_PROTOCOL: &str = "candeck.v1";
const BEARER_PROTOCOL: &str = "bearer.";

/// The token a request carries: `Authorization: Bearer`, else, on a
/// WebSocket upgrade only (a `GET` with `Upgrade: websocket`), a `bearer.`
/// subprotocol: a plain request naming one has no token (issue 30,
/// finding 8).
fn credentials(method: &Method, headers: &HeaderMap) -> Option<String> {
    if let Some(value) = headers.get(header::AUTHORIZATION) {
        let value = value.to_str().ok()?;
        let (scheme, token) = value.trim().split_once(' ')?;
        return scheme
            .eq_ignore_ascii_case("bearer")
            .then(|| token.trim().to_string());
    }
    if !is_websocket_upgrade(method, headers) {
        return None;
    }
    headers
        .get_all(header::SEC_WEBSOCKET_PROTOCOL)
        .iter()
        .filter_map(|value| value.to_str().ok())
        .flat_map(|value| value.split(','))
        .find_map(|protocol| protocol.trim().strip_prefix(BEARER_PROTOCOL))
        .map(str::to_string)
}

/// Whether a request asks for a WebSocket (RFC 6455, 4.1: a `GET` with
/// `Upgrade: websocket`).
fn is_websocket_upgrade(method: &Method, headers: &HeaderMap) -> bool {
    *method == Method::GET
        && headers
            .get_all(header::UPGRADE)
            .iter()
            .filter_map(|value| value.to_str().ok())
            .flat_map(|value| value.split(','))
            .any(|protocol| protocol.trim().eq_ignore_ascii_case("websocket"))
}

/// Whether `origin` is the page's own: the origin of the address the
/// request was sent to.
fn same_origin(origin: &str, headers: &HeaderMap) -> bool {
    let Some(host) = headers.get(header::HOST).and_then(|h| h.to_str().ok()) else {
        return false;
    };
    origin
        .split_once("://")
        .is_some_and(|(scheme, rest)| matches!(scheme, "http" | "https") && rest == host)
}

fn is_write(method: &Method) -> bool {
    matches!(
        *method,
        Method::POST | Method::PUT | Method::PATCH | Method::DELETE
    )
}

/// Who a request says it is: the token's name and role when the gateway
/// has tokens and the request carries one it knows, `invalid-token` for
/// one it does not, `anonymous` without one (or on an open gateway); and
/// whether it carried a token at all.
pub fn identify(config: &AuthConfig, method: &Method, headers: &HeaderMap) -> (Identity, bool) {
    if !config.required() {
        return (Identity::anonymous(), false);
    }
    let given = credentials(method, headers);
    let found = given.as_deref().and_then(|given| config.token(given));
    let identity = match (found, &given) {
        (Some(token), _) => Identity {
            name: token.name.clone(),
            role: Some(token.role),
        },
        (None, Some(_)) => Identity {
            name: "invalid-token".to_string(),
            role: None,
        },
        (None, None) => Identity::anonymous(),
    };
    (identity, given.is_some())
}

/// Whether the guard refuses a request for its credentials (401 without a
/// valid token, 403 for a role too low): such a request's body is never
/// read (issue 30, finding 6), so that clients without a token cannot hold
/// connections by sending a body slowly, or never.
pub fn refused_for_credentials(
    config: &AuthConfig,
    method: &Method,
    path: &str,
    headers: &HeaderMap,
) -> bool {
    if !config.required() {
        return false;
    }
    let Some(needed) = required(method, path).role() else {
        return false;
    };
    identify(config, method, headers)
        .0
        .role
        .is_none_or(|role| role < needed)
}

/// Whether the guard takes a write of the token's rate for a request:
/// only for a write to a path no route has under `/api/v1` (refused here,
/// with no operation behind it, and audited). Every route's operation
/// takes its own write in the gateway ([`Operation::draws_on_write_rate`]:
/// never for a stop or a lease renewal), whichever door calls it, so the
/// guard never takes a second one.
pub fn takes_a_write_itself(method: &Method, path: &str) -> bool {
    matches!(required(method, path), Access::Unrouted(_))
        && super::audit::is_state_changing(method, path)
}

/// The middleware (`axum::middleware::from_fn_with_state`): who the token
/// is, the origin check and CORS preflights, then the role of the route's
/// operation ([`ROUTES`], [`Operation::required_role`]), then the body
/// limit and, for a write no route has, the write rate. Who it found (or
/// did not) goes into the response's extensions for the audit log, also
/// when it refuses the request for its origin or its size.
pub async fn guard(State(state): State<AppState>, mut request: Request, next: Next) -> Response {
    // Before anyone looks at the request: a foreign Host is a DNS
    // rebinding page (refused before it is known who sent it). One layer
    // with the guard: every layer costs each request a boxed future and a
    // clone of the routes' service.
    if let Some(refusal) = super::host::refusal(&state.allowed_hosts, &request) {
        return refusal;
    }
    let guard = state.guard.clone();
    let config = &guard.config;
    let method = request.method().clone();
    let path = request.uri().path().to_string();
    let headers = request.headers();
    // First, so that every refusal below is logged with who was refused.
    let (identity, given) = identify(config, &method, headers);

    // Other web pages: a browser sends Origin with every cross-origin
    // request, and with every same-origin one that is not a GET.
    let origin = headers
        .get(header::ORIGIN)
        .and_then(|value| value.to_str().ok())
        .map(str::to_string);
    let listed = origin
        .as_ref()
        .filter(|origin| config.cors_origins.iter().any(|allowed| allowed == *origin));
    if method == Method::OPTIONS && headers.contains_key(header::ACCESS_CONTROL_REQUEST_METHOD) {
        return match (&origin, listed) {
            (_, Some(origin)) => preflight(origin),
            (origin, None) => with_identity(
                AppError::from(GatewayError::Forbidden(format!(
                    "cross-origin requests from {} are not allowed (cors_origins lists the origins that are)",
                    origin.as_deref().unwrap_or("an unnamed origin")
                )))
                .into_response(),
                identity,
            ),
        };
    }
    if let Some(origin) = &origin
        && listed.is_none()
        && !same_origin(origin, headers)
    {
        // A page elsewhere may send writes to an open gateway, and open
        // a WebSocket to one (browsers do not apply CORS to WebSockets).
        let upgrade = headers.contains_key(header::UPGRADE);
        if is_write(&method) || upgrade {
            return with_identity(
                AppError::from(GatewayError::Forbidden(format!(
                    "{method} {path} from the web page of {origin}: cross-origin writes and streams are not allowed (cors_origins lists the origins that are)"
                )))
                .into_response(),
                identity,
            );
        }
    }

    let access = required(&method, &path);
    if config.required()
        && let Some(needed) = access.role()
    {
        match identity.role {
            None => {
                let message = if given {
                    "the token is not valid: sign in again"
                } else {
                    "this gateway asks for a token: send Authorization: Bearer TOKEN"
                };
                return with_identity(
                    AppError::from(GatewayError::Unauthenticated(message.to_string()))
                        .into_response(),
                    identity,
                );
            }
            Some(role) if role < needed => {
                return with_identity(
                    AppError::from(GatewayError::Forbidden(format!(
                        "token {} has the role {role}; {method} {path} needs {needed}",
                        identity.name
                    )))
                    .into_response(),
                    identity,
                );
            }
            Some(_) => {}
        }
    }

    let limit = config.body_limit(&method, &path);
    let length = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|value| value.to_str().ok())
        .and_then(|value| value.parse::<u64>().ok());
    if length.is_some_and(|length| length > limit as u64) {
        return with_identity(too_large(limit).into_response(), identity);
    }
    // A write to no route has no operation to take it (see
    // `takes_a_write_itself`): from the token's bucket, as every door's.
    let caller = crate::gateway::Caller::new(
        crate::gateway::Channel::Rest,
        identity.name.clone(),
        identity.role,
    );
    if takes_a_write_itself(&method, &path)
        && let Err(refused) = state.gateway.take_write(&caller)
    {
        return with_identity(AppError::from(refused).into_response(), identity);
    }

    // A body without Content-Length is read here, up to the route's limit
    // (the handlers read it whole anyway).
    if is_write(&method) && length.is_none() {
        let (parts, body) = request.into_parts();
        match axum::body::to_bytes(body, limit).await {
            Ok(bytes) => request = Request::from_parts(parts, axum::body::Body::from(bytes)),
            Err(_) => return with_identity(too_large(limit).into_response(), identity),
        }
    }
    request.extensions_mut().insert(identity.clone());
    let mut response = next.run(request).await;
    if let Some(origin) = listed
        && let Ok(value) = HeaderValue::from_str(origin)
    {
        let headers = response.headers_mut();
        headers.insert(header::ACCESS_CONTROL_ALLOW_ORIGIN, value);
        headers.append(header::VARY, HeaderValue::from_static("Origin"));
    }
    with_identity(response, identity)
}

/// The 413 for a body over `limit` bytes.
pub fn too_large(limit: usize) -> AppError {
    AppError::PayloadTooLarge(format!(
        "the request body is larger than {limit} bytes (body_limit, dcf_body_limit)"
    ))
}

fn with_identity(mut response: Response, identity: Identity) -> Response {
    response.extensions_mut().insert(identity);
    response
}

/// The answer to an allowed CORS preflight.
fn preflight(origin: &str) -> Response {
    let mut response = StatusCode::NO_CONTENT.into_response();
    let headers = response.headers_mut();
    if let Ok(value) = HeaderValue::from_str(origin) {
        headers.insert(header::ACCESS_CONTROL_ALLOW_ORIGIN, value);
    }
    headers.insert(
        header::ACCESS_CONTROL_ALLOW_METHODS,
        HeaderValue::from_static("GET, POST, PUT, DELETE"),
    );
    headers.insert(
        header::ACCESS_CONTROL_ALLOW_HEADERS,
        HeaderValue::from_static("authorization, content-type"),
    );
    headers.insert(
        header::ACCESS_CONTROL_MAX_AGE,
        HeaderValue::from_static("600"),
    );
    headers.insert(header::VARY, HeaderValue::from_static("Origin"));
    response
}

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(whoami))
}

/// Who the request's token is.
#[derive(Debug, Serialize, ToSchema)]
pub struct WhoAmI {
    /// The token's name; `anonymous` when the gateway asks for none.
    pub name: String,
    /// What the token may do; `admin` when the gateway asks for no token
    /// (anyone may do anything).
    #[schema(value_type = super::schema::Role)]
    pub role: Role,
    /// Whether the gateway asks for tokens.
    pub auth_required: bool,
}

/// The signed-in token: its name and role (the dashboard's top bar).
#[utoipa::path(get, path = "/auth/whoami", tag = "auth",
    responses(
        (status = 200, description = "The token's name and role", body = WhoAmI),
        (status = 401, description = "`unauthenticated`: no token, or one the gateway does not know", body = ErrorBody),
    ))]
async fn whoami(
    State(state): State<AppState>,
    identity: Option<axum::Extension<Identity>>,
) -> axum::Json<WhoAmI> {
    let required = state.guard.config.required();
    let (name, role) = match identity.map(|axum::Extension(identity)| identity) {
        Some(Identity {
            name,
            role: Some(role),
        }) if required => (name, role),
        _ => ("anonymous".to_string(), Role::Admin),
    };
    axum::Json(WhoAmI {
        name,
        role,
        auth_required: required,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gateway::constant_time_eq;

    #[test]
    fn patterns_match_segments_and_the_rest() {
        let od = "/api/v1/buses/{bus}/nodes/{id}/od/{index}/{sub}";
        assert!(matches(od, "/api/v1/buses/demo/nodes/1/od/0x1008/0"));
        assert!(!matches(od, "/api/v1/buses/demo/nodes/1/od/0x1008"));
        assert!(!matches(od, "/api/v1/buses/demo/nodes/1/od/0x1008/0/x"));
        assert!(!matches(od, "/api/v1/buses//nodes/1/od/0x1008/0"));
        assert!(matches("/static/{v}/{*path}", "/static/abc/js/api.js"));
        assert!(!matches("/static/{v}/{*path}", "/static/abc"));
        assert!(matches("/", "/"));
        assert!(!matches("/", "/nodes"));
        assert!(matches("/{*page}", "/nodes/demo/1"));
    }

    #[test]
    fn unlisted_paths_fall_back_to_the_safe_side() {
        assert_eq!(required(&Method::GET, "/api/v1/nowhere"), VIEW);
        assert_eq!(required(&Method::POST, "/api/v1/nowhere"), UNROUTED_WRITE);
        assert_eq!(required(&Method::GET, "/nodes/demo/1"), PUBLIC);
        assert_eq!(required(&Method::HEAD, "/"), PUBLIC);
        assert_eq!(required(&Method::POST, "/"), UNROUTED_WRITE);
        assert_eq!(required(&Method::GET, "/metrics"), VIEW);
        assert_eq!(
            required(&Method::GET, "/cia309-5/1.0/1/1/1/r/0x1008/0"),
            VIEW
        );
        assert_eq!(
            required(&Method::PUT, "/cia309-5/1.0/1/1/1/w/0x1008/0"),
            op(Operation::WriteObject)
        );
        // Every route is public or one of the gateway's operations: REST
        // has no role of its own for a route.
        for (method, pattern, access) in ROUTES {
            assert!(
                matches!(access, Access::Public | Access::Operation(_)),
                "{method} {pattern}: {access:?}"
            );
        }
    }

    #[test]
    fn comparison_is_by_every_byte_and_the_length() {
        assert!(constant_time_eq(b"abcdef", b"abcdef"));
        assert!(!constant_time_eq(b"abcdeg", b"abcdef"));
        assert!(!constant_time_eq(b"abcde", b"abcdef"));
        assert!(!constant_time_eq(b"abcdefg", b"abcdef"));
        assert!(!constant_time_eq(b"", b"abcdef"));
        // A byte that is the complement of the secret's pads a short guess:
        // no zero byte can make a prefix match.
        assert!(!constant_time_eq(b"abc\0\0\0", b"abc"));
    }

    #[test]
    fn weak_duplicate_and_unknown_tokens_are_refused() {
        let good = "3f9c2a7be81d4c06a5e9";
        assert!(Token::new("plc", Role::Operator, good).is_ok());
        let err = Token::new("plc", Role::Operator, "short").unwrap_err();
        assert!(err.contains("too weak"), "{err}");
        let err = Token::new("plc", Role::Operator, &"ab".repeat(20)).unwrap_err();
        assert!(err.contains("too weak"), "{err}");
        let err = Token::new("plc", Role::Operator, "3f9c2a7be81d4c06a5e9/+").unwrap_err();
        assert!(err.contains("not allowed"), "{err}");
        let err = Token::new("p l c", Role::Operator, good).unwrap_err();
        assert!(err.contains("not a name"), "{err}");
        let err = Token::parse_entry(&format!("plc:superuser:{good}")).unwrap_err();
        assert!(err.contains("not a role"), "{err}");
        assert!(!err.contains("superuser"), "{err}");
        let err = Token::parse_entry("plc").unwrap_err();
        assert!(err.contains("NAME:ROLE:TOKEN"), "{err}");
        let token = Token::parse_entry(&format!("plc:admin:{good}")).unwrap();
        assert_eq!((token.name.as_str(), token.role), ("plc", Role::Admin));
        assert!(!format!("{token:?}").contains(good));

        let a = Token::new("a", Role::Viewer, good).unwrap();
        let b = Token::new("a", Role::Admin, "0123456789abcdefghij").unwrap();
        let err = AuthConfig::new(vec![a.clone(), b], vec![], None, 1, 1).unwrap_err();
        assert!(err.contains("two tokens are named 'a'"), "{err}");
        let c = Token::new("c", Role::Admin, good).unwrap();
        let err = AuthConfig::new(vec![a, c], vec![], None, 1, 1).unwrap_err();
        assert!(err.contains("the same token"), "{err}");
        let err =
            AuthConfig::new(vec![], vec!["https://x.example/".into()], None, 1, 1).unwrap_err();
        assert!(err.contains("no origin"), "{err}");
    }
}
