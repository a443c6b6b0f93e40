//! The OpenAPI document of the REST interface (utoipa), and the schemas the
//! routers share: the error body and the path parameters.
//!
//! Each router registers its handlers' `#[utoipa::path]`s itself
//! (`utoipa_axum::routes!`); [`ApiDoc`] adds what belongs to no router: the
//! title, the server base and the tags. `openapi/openapi.json` in the
//! repository is this document; a test fails when the two differ
//! (regenerate with `CANDECK_UPDATE_OPENAPI=1 cargo test --lib openapi`).
//!
//! Some handlers build their JSON with `serde_json::json!` (the values of an
//! object dictionary are typed at run time); their schemas here say what
//! that JSON is, and schemathesis (`tests/interop/test_openapi.py`) checks
//! every response against them.

use serde::Serialize;
use utoipa::{IntoParams, OpenApi, ToSchema};

/// The document's fixed parts.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "candeck",
        description = "REST interface of the candeck CANopen gateway: buses, nodes, NMT, the object \
dictionary over SDO, PDOs, CiA 402 drives, LED controllers and the emulated bus.\n\n\
Errors have one shape, `{\"error\": {\"code\", \"message\", ...}}`: 400 for a request or value \
that is invalid (found before the bus is touched), 404 for an unknown bus, node, object, axis or \
segment, 409 when the device's or gateway's state forbids the request, 422 when the device \
refused (SDO abort, with `abort_code` and `abort_text`), 502 when it broke the protocol, 503 when \
the bus is down and 504 when the device did not answer in time.\n\n\
When the gateway is configured with tokens, every request but `/health` needs \
`Authorization: Bearer TOKEN` of a role that may make it (docs/security.md): \
401 `unauthenticated` without a valid token, 403 `forbidden` for a role below the route's, \
429 `rate_limited` (with `Retry-After`) for writes faster than the token's rate.",
        license(name = "MIT OR Apache-2.0")
    ),
    tags(
        (name = "buses", description = "The gateway and its CAN buses"),
        (name = "nodes", description = "The nodes of a bus: discovery and NMT (CiA 301 §7.2.8)"),
        (name = "machine", description = "The network manager (CiA 302-2): the expected nodes, their boot-up, supervision and the machine state"),
        (name = "od", description = "A node's object dictionary over SDO (CiA 301 §7.2.4)"),
        (name = "leds", description = "LED controllers (UIO1LED): segments, scenes, preview"),
        (name = "config", description = "A node's configuration: store, restore (CiA 301 0x1010, 0x1011), DCF backup and restore (CiA 306)"),
        (name = "drives", description = "CiA 402 drives: axes, state machine, moves (profiles umc, jmc_stepper, cia402)"),
        (name = "pdo", description = "PDOs (CiA 301 §7.2.2): configuration, re-mapping, RPDO send; the SYNC producer (§7.2.5)"),
        (name = "frames", description = "Raw CAN frames of a bus (ISO 11898-1)"),
        (name = "lss", description = "Node-IDs: LSS (CiA 305) Fastscan and assignment, the UniSwarm node-ID change (0x2040)"),
        (name = "sim", description = "The virtual devices of an emulated bus: add, remove, inject faults"),
        (name = "events", description = "The persisted history: audit log of state-changing requests, EMCYs (CiA 301 §7.2.7), NMT and supervision events"),
        (name = "metrics", description = "The gateway's metrics for Prometheus (text format 0.0.4), at the root path"),
        (name = "auth", description = "Who the request's bearer token is (RFC 6750)"),
        (name = "eds", description = "The EDS catalog (CiA 306): built-in, --eds-dir and uploaded files, their warnings, the files left out, the nodes each describes; uploads, deletions, assignment to a node by hand"),
        (name = "io", description = "CiA 401 generic I/O modules: inputs live, outputs set and read back"),
        (name = "alarms", description = "Alarms (ISA-18.2): active, cleared and acknowledged, by severity, from every source of the machine"),
        (name = "loggers", description = "Data loggers: objects of any nodes sampled at a period (from TPDOs or by SDO), as CSV"),
    ),
    modifiers(&BearerAuth),
    security(("bearer" = []))
)]
pub struct ApiDoc;

/// The bearer token scheme (RFC 6750), so that the docs UI's "Authorize"
/// sends it.
struct BearerAuth;

impl utoipa::Modify for BearerAuth {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
    }
}

/// Every error: `{"error": {...}}`.
#[derive(Debug, Serialize, ToSchema)]
#[schema(example = json!({"error": {"code": "unknown_node", "message": "node 9 is not known on bus demo (try POST /api/v1/buses/demo/scan)"}}))]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

/// What went wrong.
#[derive(Debug, Serialize, ToSchema)]
pub struct ErrorDetail {
    /// A stable snake_case code (`invalid_value`, `unknown_node`,
    /// `sdo_abort`, `bus_down`, `sdo_timeout`, ...).
    #[schema(example = "sdo_abort")]
    pub code: String,
    /// Text for a human.
    #[schema(example = "node 1 refused: Attempt to write a read only object")]
    pub message: String,
    /// With `sdo_abort` and `sdo_protocol_error`: the CiA 301 abort code.
    #[schema(example = "0x06010002")]
    pub abort_code: Option<String>,
    /// With `sdo_abort` and `sdo_protocol_error`: its CiA 301 text.
    #[schema(example = "Attempt to write a read only object")]
    pub abort_text: Option<String>,
    /// With `wrong_nmt_state`: the node's NMT state.
    #[schema(example = "stopped")]
    pub nmt: Option<String>,
    /// With `invalid_dcf`: the line of the DCF that is wrong.
    #[schema(example = 12)]
    pub line: Option<usize>,
    /// With `drive_fault`, `drive_not_enabled` and `state_change_timeout`:
    /// the CiA 402 state the axis is in (`unknown` for a statusword that
    /// names none).
    #[schema(example = "fault")]
    pub state: Option<String>,
    /// When a sequence of transfers (a PDO re-mapping) stopped half way: the
    /// step that failed; the steps before it took effect.
    #[schema(example = "write_mapping_entry_2")]
    pub step: Option<String>,
    /// When a stop (halt, quick stop) was not confirmed by the drive: every
    /// step tried, the fallbacks included (quick stop, NMT stop of the
    /// node), with its outcome.
    #[schema(value_type = Option<Vec<super::schema::StopAttempt>>)]
    pub attempts: Option<Vec<crate::gateway::StopAttempt>>,
}

/// A bus named in a path.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Path)]
pub struct BusPath {
    /// The bus name (`demo` for the emulated demo bus).
    #[param(example = "demo")]
    pub bus: String,
}

/// A node of a bus named in a path.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Path)]
pub struct NodePath {
    /// The bus name.
    #[param(example = "demo")]
    pub bus: String,
    /// The node id, 1 to 127.
    #[param(minimum = 1, maximum = 127, example = 1)]
    pub id: u8,
}

/// The docs UI's page in place of Swagger UI's own `index.html` (which
/// has no viewport, so a phone draws it 980 px wide, and no way back):
/// the same scripts and styles, a viewport, and a bar back to the
/// dashboard (issue 21). Long blocks scroll inside their own box.
pub const DOCS_INDEX: &str = r##"<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>candeck API</title>
<link rel="stylesheet" href="./swagger-ui.css">
<link rel="stylesheet" href="./index.css">
<link rel="icon" type="image/png" href="./favicon-32x32.png" sizes="32x32">
<link rel="icon" type="image/png" href="./favicon-16x16.png" sizes="16x16">
<style>
  html, body { max-width: 100%; }
  .docs-bar { display: flex; align-items: center; gap: 1rem; padding: 0.4rem 1rem; background: #1b2430; font: 600 0.95rem system-ui, sans-serif; }
  .docs-bar a { color: #fff; text-decoration: none; display: inline-flex; align-items: center; min-height: 44px; }
  .docs-bar span { color: #c9d1db; font-weight: 400; }
  #swagger-ui { max-width: 100vw; overflow-x: auto; }
  #swagger-ui pre, #swagger-ui table { max-width: 100%; overflow-x: auto; }
</style>
</head>
<body>
<nav class="docs-bar" aria-label="candeck"><a id="back-to-dashboard" href="/">‹ Dashboard</a><span>REST API</span></nav>
<div id="swagger-ui"></div>
<script src="./swagger-ui-bundle.js" charset="UTF-8"></script>
<script src="./swagger-ui-standalone-preset.js" charset="UTF-8"></script>
<script src="./swagger-initializer.js" charset="UTF-8"></script>
</body>
</html>
"##;

/// Answers the docs UI's page with [`DOCS_INDEX`]; its other files are
/// Swagger UI's.
pub async fn docs_index(
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::http::header::{CACHE_CONTROL, CONTENT_TYPE};
    use axum::response::IntoResponse;
    let path = request.uri().path();
    if path == "/api/docs/" || path == "/api/docs/index.html" {
        return (
            [
                (CONTENT_TYPE, "text/html; charset=utf-8"),
                (CACHE_CONTROL, "no-cache"),
            ],
            DOCS_INDEX,
        )
            .into_response();
    }
    next.run(request).await
}

/// The document as served, with every router's paths.
pub fn openapi() -> utoipa::openapi::OpenApi {
    super::routers(super::AppState::new([])).1
}

#[cfg(test)]
mod tests {
    use super::*;

    const CHECKED_IN: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/openapi/openapi.json");

    /// `openapi/openapi.json` is what the binary serves; with
    /// `CANDECK_UPDATE_OPENAPI=1` the test writes it instead.
    #[test]
    fn openapi_json_in_the_repository_is_what_is_served() {
        let served = openapi().to_pretty_json().unwrap() + "\n";
        if std::env::var_os("CANDECK_UPDATE_OPENAPI").is_some() {
            std::fs::write(CHECKED_IN, &served).unwrap();
            return;
        }
        let checked_in = std::fs::read_to_string(CHECKED_IN).unwrap_or_default();
        assert!(
            checked_in == served,
            "openapi/openapi.json differs from the document the binary serves: \
             regenerate it with `CANDECK_UPDATE_OPENAPI=1 cargo test --lib openapi`"
        );
    }

    /// Every operation says what it answers, errors included.
    #[test]
    fn every_operation_has_a_summary_and_error_responses() {
        let doc = openapi();
        let mut operations = 0;
        for (path, item) in &doc.paths.paths {
            for (method, operation) in [
                ("get", &item.get),
                ("put", &item.put),
                ("post", &item.post),
                ("delete", &item.delete),
            ] {
                let Some(operation) = operation else { continue };
                operations += 1;
                assert!(
                    operation.summary.as_deref().is_some_and(|s| !s.is_empty()),
                    "{method} {path}: no summary"
                );
                let statuses: Vec<&String> = operation.responses.responses.keys().collect();
                assert!(
                    // 101: the stream's switch to WebSocket.
                    statuses
                        .iter()
                        .any(|status| status.starts_with('2') || *status == "101"),
                    "{method} {path}: no success response"
                );
                if path.contains("{bus}") {
                    assert!(
                        statuses.iter().any(|status| *status == "404"),
                        "{method} {path}: an unknown bus is 404, undocumented"
                    );
                }
            }
        }
        assert!(operations >= 10, "{operations} operations");
    }
}
