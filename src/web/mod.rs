//! The browser dashboard (`docs/dashboard.md`): its
//! pages and the static files they load, all compiled into the binary so
//! that the gateway serves them with no file next to it, no CDN and no
//! front-end build.
//!
//! The pages are askama templates from `web/templates/`; they hold the
//! layout only and fill themselves in from the REST API and the WebSocket
//! stream with the ES modules of `web/static/js/`. Static files are served
//! under a versioned prefix, `/static/{version}/css/app.css`, where the
//! version is a hash of every file's content: a page always loads the files
//! of the build that rendered it, and the browser may keep them forever
//! (`immutable`), since a changed file gets a new URL. The modules import
//! each other by relative path, so they carry the prefix along without
//! knowing it. Each file also has an `ETag` of its own content for the
//! revalidation a reload forces.
//!
//! # Layout
//!
//! - [`router`]: the pages, `/` (the overview), `/nodes/{bus}/{node}` (one
//!   node: identity, NMT, dictionary, store/restore, DCF backup),
//!   `/nodes/{bus}/{node}/axes/{axis}` (the drive page of an axis),
//!   `/nodes/{bus}/{node}/pdos` (a node's PDO editor),
//!   `/nodes/{bus}/{node}/leds` (an LED controller's segments and live
//!   strip), `/buses/{bus}/trace` (a bus's live frames, decoded, and its
//!   recording), `/alarms` (the alarms, acknowledging, machine-level
//!   recovery), `/events` (the persisted history), `/loggers` (the data
//!   logger: channels, live chart, CSV), `/eds` (the device
//!   descriptions: the EDS catalog, uploads) and `/nodes/{bus}/{node}/io`
//!   (a CiA 401 module's inputs and outputs),
//!   `/nodes/{bus}/{node}/axes/{axis}/tune` (a UMC axis's control loops and
//!   step test), `/nodes/{bus}/{node}/axes/{axis}/commissioning/{page}`
//!   (a UMC's board, motor, brake and sensor objects, listed in
//!   [`crate::profiles::umc::commissioning`]), and
//!   `/static/{version}/{*path}`; none is under
//!   `/api/v1` nor in the OpenAPI document. A page is rendered for any bus
//!   and node in its path: it asks the API, and shows its 404 in words
//!   when the bus or node is unknown.
//! - [`ASSETS`]: the static files, embedded with `include_bytes!`, and
//!   [`asset`] to look one up; [`static_version`] is the prefix's version.
//! - `OverviewPage`: the overview's template (`web/templates/overview.html`,
//!   which extends `base.html`: navigation and the connection indicator).
//! - `DrivePage`: one axis of a drive (`web/templates/drive.html`).
//! - `PdosPage`: the PDO editor (`web/templates/pdos.html`).
//! - `NodePage`, `EventsPage`: a node and the history
//!   (`web/templates/node.html`, `events.html`).
//! - `EdsPage`, `IoPage`: the device descriptions and the I/O page
//!   (`web/templates/eds.html`, `io.html`).
//! - `LedsPage`, `TracePage`: the LED and trace pages, which carry the bus
//!   and node of their path in data attributes for their modules.

use std::sync::LazyLock;

use askama::Template;
use axum::Router;
use axum::extract::Path;
use axum::http::header::{CACHE_CONTROL, CONTENT_TYPE, ETAG, IF_NONE_MATCH};
use axum::http::{HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;

use crate::api::AppError;
use crate::gateway::GatewayError;
use crate::profiles::umc;

/// One embedded static file.
#[derive(Debug)]
pub struct Asset {
    /// Its path under `web/static/` (`js/api.js`).
    pub path: &'static str,
    pub content_type: &'static str,
    pub bytes: &'static [u8],
}

/// A file of `web/static/`, embedded, with its content type.
macro_rules! asset {
    ($path:literal, $content_type:expr) => {
        Asset {
            path: $path,
            content_type: $content_type,
            bytes: include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/web/static/", $path)),
        }
    };
}

const CSS: &str = "text/css; charset=utf-8";
const JS: &str = "text/javascript; charset=utf-8";
const SVG: &str = "image/svg+xml";

/// Every file of `web/static/` (a unit test checks that none is missing).
pub static ASSETS: &[Asset] = &[
    asset!("css/alarms.css", CSS),
    asset!("css/app.css", CSS),
    asset!("css/auth.css", CSS),
    asset!("css/drive.css", CSS),
    asset!("css/eds.css", CSS),
    asset!("css/events.css", CSS),
    asset!("css/io.css", CSS),
    asset!("css/leds.css", CSS),
    asset!("css/logger.css", CSS),
    asset!("css/node.css", CSS),
    asset!("css/pdos.css", CSS),
    asset!("css/trace.css", CSS),
    asset!("css/tune.css", CSS),
    asset!("js/alarmbar.js", JS),
    asset!("js/alarms.js", JS),
    asset!("js/api.js", JS),
    asset!("js/auth.js", JS),
    asset!("js/axes.js", JS),
    asset!("js/bustools.js", JS),
    asset!("js/canopen.js", JS),
    asset!("js/chart.js", JS),
    asset!("js/cia402.js", JS),
    asset!("js/dom.js", JS),
    asset!("js/drive.js", JS),
    asset!("js/eds.js", JS),
    asset!("js/events.js", JS),
    asset!("js/io.js", JS),
    asset!("js/layout.js", JS),
    asset!("js/leds.js", JS),
    asset!("js/logchart.js", JS),
    asset!("js/logger.js", JS),
    asset!("js/lss.js", JS),
    asset!("js/motion.js", JS),
    asset!("js/node.js", JS),
    asset!("js/overview.js", JS),
    asset!("js/pdos.js", JS),
    asset!("js/recovery.js", JS),
    asset!("js/stepchart.js", JS),
    asset!("js/stopall.js", JS),
    asset!("js/stream.js", JS),
    asset!("js/trace.js", JS),
    asset!("js/commission.js", JS),
    asset!("js/tune.js", JS),
    asset!("icon.svg", SVG),
];

/// The embedded file at `path` (relative to `web/static/`).
pub fn asset(path: &str) -> Option<&'static Asset> {
    ASSETS.iter().find(|asset| asset.path == path)
}

/// 64-bit FNV-1a: a content hash for URLs and ETags, not for security
/// (nobody chooses these bytes but us).
fn fnv1a(hash: u64, bytes: &[u8]) -> u64 {
    bytes.iter().fold(hash, |hash, &byte| {
        (hash ^ u64::from(byte)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

static VERSION: LazyLock<String> = LazyLock::new(|| {
    let hash = ASSETS.iter().fold(FNV_OFFSET, |hash, asset| {
        // The path goes in too, so that renaming a file changes the version.
        fnv1a(fnv1a(fnv1a(hash, asset.path.as_bytes()), &[0]), asset.bytes)
    });
    format!("{:012x}", hash >> 16)
});

/// The version in the static files' URLs: a hash of all of them.
pub fn static_version() -> &'static str {
    &VERSION
}

/// The quoted `ETag` of one file: a hash of its content.
fn etag(asset: &Asset) -> String {
    format!("\"{:016x}\"", fnv1a(FNV_OFFSET, asset.bytes))
}

/// The dashboard's routes; merged into [`crate::api::app`].
pub fn router() -> Router {
    Router::new()
        .route("/", get(overview))
        .route("/nodes/{bus}/{node}", get(node))
        .route("/events", get(events))
        .route("/alarms", get(alarms))
        .route("/loggers", get(loggers))
        .route("/eds", get(eds))
        .route("/nodes/{bus}/{node}/io", get(io))
        .route("/nodes/{bus}/{node}/leds", get(leds))
        .route("/buses/{bus}/trace", get(trace))
        .route("/nodes/{bus}/{node}/axes/{axis}", get(drive))
        .route("/nodes/{bus}/{node}/pdos", get(pdos))
        .route("/nodes/{bus}/{node}/axes/{axis}/tune", get(tune))
        .route(
            "/nodes/{bus}/{node}/axes/{axis}/commissioning/{page}",
            get(commission),
        )
        .route("/static/{version}/{*path}", get(static_file))
}

/// What every page's layout needs.
struct Layout {
    /// `/static/{version}`, the prefix of every static URL.
    static_root: String,
    /// The navigation entry to mark as the current page.
    current: &'static str,
    /// candeck's version, in the footer.
    version: &'static str,
    /// The breadcrumbs over the page, the last one the page itself: the
    /// same trail on every page (overview › bus › node › axis › page).
    crumbs: Vec<Crumb>,
}

/// One breadcrumb: a link, or the current page (`href` empty).
struct Crumb {
    label: String,
    href: String,
    /// The element's id, empty for none (`node-link`: pages rename it).
    id: &'static str,
}

/// Where a page is: its bus, node and axis as its path gives them (any
/// may be absent), and its own name; `None` for the node's or the axis's
/// own page, whose crumb is then the current one.
fn trail(
    bus: Option<&str>,
    node: Option<&str>,
    axis: Option<&str>,
    here: Option<&str>,
) -> Vec<Crumb> {
    let link = |label: String, href: String, id: &'static str| Crumb { label, href, id };
    let mut crumbs = vec![link("Overview".into(), "/".into(), "")];
    if let Some(bus) = bus {
        crumbs.push(link(
            format!("Bus {bus}"),
            format!("/buses/{}/trace", path_segment(bus)),
            "bus-link",
        ));
        if let Some(node) = node {
            let node_href = format!("/nodes/{}/{}", path_segment(bus), path_segment(node));
            crumbs.push(link(format!("Node {node}"), node_href.clone(), "node-link"));
            if let Some(axis) = axis {
                crumbs.push(link(
                    format!("Axis {axis}"),
                    format!("{node_href}/axes/{}", path_segment(axis)),
                    "axis-link",
                ));
            }
        }
    }
    match here {
        Some(here) => crumbs.push(link(here.into(), String::new(), "")),
        // The last one is the page itself.
        None => {
            if let Some(last) = crumbs.last_mut() {
                last.href.clear();
            }
        }
    }
    crumbs
}

impl Layout {
    fn new(current: &'static str) -> Self {
        Self {
            static_root: format!("/static/{}", static_version()),
            current,
            version: env!("CARGO_PKG_VERSION"),
            crumbs: Vec::new(),
        }
    }

    fn with_crumbs(mut self, crumbs: Vec<Crumb>) -> Self {
        self.crumbs = crumbs;
        self
    }
}

/// The overview: buses, nodes, STOP ALL and recent events.
#[derive(Template)]
#[template(path = "overview.html")]
struct OverviewPage {
    layout: Layout,
}

/// The drive page of one axis: its state machine, motion, statusword and
/// charts (`web/templates/drive.html`). The path's parts are rendered as
/// given (escaped) into data attributes; the page asks the API for them,
/// so an unknown bus, node or axis is the API's 404, said on the page.
#[derive(Template)]
#[template(path = "drive.html")]
struct DrivePage {
    layout: Layout,
    bus: String,
    node: String,
    axis: String,
}

/// The PDO editor of one node. The bus and node come from the path as
/// given: the page asks the API for them, which answers 404 for one that
/// does not exist, and askama escapes them in the data attributes.
#[derive(Template)]
#[template(path = "pdos.html")]
struct PdosPage {
    layout: Layout,
    bus: String,
    node: String,
}

/// One node's page. `bus` and `node` are the path's, unchecked: askama
/// escapes them into data attributes, and the page asks the API about them.
#[derive(Template)]
#[template(path = "node.html")]
struct NodePage {
    layout: Layout,
    bus: String,
    node: String,
}

/// The persisted history: EMCYs, NMT events and the audit log.
#[derive(Template)]
#[template(path = "eds.html")]
struct EdsPage {
    layout: Layout,
}

#[derive(Template)]
#[template(path = "io.html")]
struct IoPage {
    layout: Layout,
    bus: String,
    node: String,
}

/// The alarms: active, cleared and waiting, the history; acknowledging,
/// machine-level recovery.
#[derive(Template)]
#[template(path = "alarms.html")]
struct AlarmsPage {
    layout: Layout,
}

#[derive(Template)]
#[template(path = "events.html")]
struct EventsPage {
    layout: Layout,
}

/// The data logger: channels picked by name, the loggers, a live chart.
#[derive(Template)]
#[template(path = "logger.html")]
struct LoggerPage {
    layout: Layout,
}

/// An LED controller's page: its segments' editors and the live strip.
#[derive(Template)]
#[template(path = "leds.html")]
struct LedsPage {
    layout: Layout,
    bus: String,
    node: u8,
}

/// A bus's trace: its live frames decoded, filters, and its recording.
#[derive(Template)]
#[template(path = "trace.html")]
struct TracePage {
    layout: Layout,
    bus: String,
}

/// The links between a UMC axis's tuning and commissioning pages.
struct UmcNav {
    /// `/nodes/{bus}/{node}/axes/{axis}`, path-encoded.
    axis_href: String,
    /// `(slug, title)` of each commissioning page.
    pages: Vec<(&'static str, &'static str)>,
}

impl UmcNav {
    fn new(bus: &str, node: u8, axis: u8) -> Self {
        Self {
            axis_href: format!("/nodes/{}/{node}/axes/{axis}", path_segment(bus)),
            pages: umc::commissioning::PAGES
                .iter()
                .map(|page| (page.slug, page.title))
                .collect(),
        }
    }
}

/// One loop of the tuning page: its objects (the axis's) and units.
struct LoopView {
    name: &'static str,
    config: String,
    status: String,
    input_unit: &'static str,
    output_unit: &'static str,
}

/// The tuning page of a UMC axis: the PID configuration of each loop
/// (`crates/profiles/src/umc.rs`, `pid`), its live status, the step test.
#[derive(Template)]
#[template(path = "tune.html")]
struct TunePage {
    layout: Layout,
    nav: UmcNav,
    bus: String,
    node: u8,
    axis: u8,
    loops: Vec<LoopView>,
}

/// One object of a commissioning page, for the template.
struct ObjectView {
    index: String,
    sub: u8,
    name: &'static str,
    /// `q15`, `code`, or the scale of an integer.
    kind: String,
    unit: &'static str,
    writable: bool,
    meaning: &'static str,
}

/// A commissioning page of a UMC (board, motor, brake, sensors): the
/// objects the profile lists, the axis's.
#[derive(Template)]
#[template(path = "commission.html")]
struct CommissionPage {
    layout: Layout,
    nav: UmcNav,
    bus: String,
    node: u8,
    axis: u8,
    slug: &'static str,
    title: &'static str,
    sections: &'static str,
    objects: Vec<ObjectView>,
}

/// A rendered page. It names this build's static URLs, so a browser must
/// ask again each time (`no-cache`), or it would keep a page that loads
/// the files of a build no longer running.
fn page(template: &impl Template) -> Response {
    match template.render() {
        Ok(html) => (
            [
                (CONTENT_TYPE, "text/html; charset=utf-8"),
                (CACHE_CONTROL, "no-cache"),
            ],
            html,
        )
            .into_response(),
        Err(err) => AppError::from(GatewayError::Internal(format!(
            "rendering a dashboard page: {err}"
        )))
        .into_response(),
    }
}

async fn overview() -> Response {
    page(&OverviewPage {
        layout: Layout::new("overview"),
    })
}

async fn drive(Path((bus, node, axis)): Path<(String, String, String)>) -> Response {
    page(&DrivePage {
        layout: Layout::new("drive").with_crumbs(trail(Some(&bus), Some(&node), Some(&axis), None)),
        bus,
        node,
        axis,
    })
}

/// The node and axis of a UMC page's path, else no page.
fn umc_axis(node: &str, axis: &str) -> Option<(u8, u8)> {
    let axis = axis
        .parse::<u8>()
        .ok()
        .filter(|axis| (1..=umc::MAX_AXES).contains(axis))?;
    Some((node_id(node)?, axis))
}

async fn tune(Path((bus, node, axis)): Path<(String, String, String)>) -> Response {
    let Some((node, axis)) = umc_axis(&node, &axis) else {
        return AppError::NoRoute(format!("/nodes/{bus}/{node}/axes/{axis}/tune")).into_response();
    };
    let at = |index: u16| format!("0x{:04X}", umc::axis_index(axis, index).unwrap_or(index));
    let loops = umc::pid::Loop::ALL
        .into_iter()
        .map(|which| LoopView {
            name: which.name(),
            config: at(which.config_index()),
            status: at(which.status_index()),
            input_unit: which.input_unit(),
            output_unit: which.output_unit(),
        })
        .collect();
    page(&TunePage {
        layout: Layout::new("drive").with_crumbs(trail(
            Some(&bus),
            Some(&node.to_string()),
            Some(&axis.to_string()),
            Some("Tuning"),
        )),
        nav: UmcNav::new(&bus, node, axis),
        bus,
        node,
        axis,
        loops,
    })
}

async fn commission(
    Path((bus, node, axis, slug)): Path<(String, String, String, String)>,
) -> Response {
    let found = umc_axis(&node, &axis).zip(umc::commissioning::page(&slug));
    let Some(((node, axis), found)) = found else {
        return AppError::NoRoute(format!(
            "/nodes/{bus}/{node}/axes/{axis}/commissioning/{slug}"
        ))
        .into_response();
    };
    use umc::commissioning::Kind;
    let objects = found
        .objects
        .iter()
        .map(|object| ObjectView {
            index: format!(
                "0x{:04X}",
                umc::axis_index(axis, object.index).unwrap_or(object.index)
            ),
            sub: object.sub,
            name: object.name,
            kind: match object.kind {
                Kind::Q15_16 => "q15".into(),
                Kind::Code => "code".into(),
                Kind::Scaled(scale) => scale.to_string(),
            },
            unit: object.unit,
            writable: object.writable,
            meaning: object.meaning,
        })
        .collect();
    page(&CommissionPage {
        layout: Layout::new("drive").with_crumbs(trail(
            Some(&bus),
            Some(&node.to_string()),
            Some(&axis.to_string()),
            Some(found.title),
        )),
        nav: UmcNav::new(&bus, node, axis),
        bus,
        node,
        axis,
        slug: found.slug,
        title: found.title,
        sections: found.sections,
        objects,
    })
}

async fn pdos(Path((bus, node)): Path<(String, String)>) -> Response {
    page(&PdosPage {
        layout: Layout::new("pdos").with_crumbs(trail(Some(&bus), Some(&node), None, Some("PDOs"))),
        bus,
        node,
    })
}

async fn node(Path((bus, node)): Path<(String, String)>) -> Response {
    page(&NodePage {
        layout: Layout::new("node").with_crumbs(trail(Some(&bus), Some(&node), None, None)),
        bus,
        node,
    })
}

async fn eds() -> Response {
    page(&EdsPage {
        layout: Layout::new("eds").with_crumbs(trail(
            None,
            None,
            None,
            Some("Device descriptions"),
        )),
    })
}

async fn io(Path((bus, node)): Path<(String, String)>) -> Response {
    page(&IoPage {
        layout: Layout::new("io").with_crumbs(trail(Some(&bus), Some(&node), None, Some("I/O"))),
        bus,
        node,
    })
}

async fn events() -> Response {
    page(&EventsPage {
        layout: Layout::new("events").with_crumbs(trail(None, None, None, Some("Events"))),
    })
}

async fn alarms() -> Response {
    page(&AlarmsPage {
        layout: Layout::new("alarms").with_crumbs(trail(None, None, None, Some("Alarms"))),
    })
}

async fn loggers() -> Response {
    page(&LoggerPage {
        layout: Layout::new("loggers").with_crumbs(trail(None, None, None, Some("Logger"))),
    })
}

/// `text` as one segment of a URL path: every byte but the unreserved
/// ones (RFC 3986 section 2.3) percent-encoded, so that a bus named
/// `a/b` or `a?b` links back to itself.
fn path_segment(text: &str) -> String {
    use std::fmt::Write;
    text.bytes().fold(String::new(), |mut out, byte| {
        if byte.is_ascii_alphanumeric() || b"-._~".contains(&byte) {
            out.push(char::from(byte));
        } else {
            let _ = write!(out, "%{byte:02X}");
        }
        out
    })
}

/// The node id of a page's path: 1 to 127 (CiA 301), else the page does
/// not exist. Whether the bus and node are known is the API's to say: the
/// page asks it and shows its answer.
fn node_id(text: &str) -> Option<u8> {
    text.parse::<u8>().ok().filter(|id| (1..=127).contains(id))
}

async fn leds(Path((bus, node)): Path<(String, String)>) -> Response {
    match node_id(&node) {
        Some(node) => page(&LedsPage {
            layout: Layout::new("leds").with_crumbs(trail(
                Some(&bus),
                Some(&node.to_string()),
                None,
                Some("LEDs"),
            )),
            bus,
            node,
        }),
        None => AppError::NoRoute(format!("/nodes/{bus}/{node}/leds")).into_response(),
    }
}

async fn trace(Path(bus): Path<String>) -> Response {
    page(&TracePage {
        layout: Layout::new("trace").with_crumbs(trail(Some(&bus), None, None, Some("Trace"))),
        bus,
    })
}

/// A static file of this build: 404 for a path not embedded or another
/// build's version (its files are not here), 304 when the browser has it.
async fn static_file(
    Path((version, path)): Path<(String, String)>,
    headers: HeaderMap,
) -> Response {
    let Some(asset) = asset(&path).filter(|_| version == static_version()) else {
        return AppError::NoRoute(format!("/static/{version}/{path}")).into_response();
    };
    let etag = etag(asset);
    let cached = headers
        .get(IF_NONE_MATCH)
        .and_then(|value| value.to_str().ok())
        .is_some_and(|value| {
            value
                .split(',')
                .any(|tag| tag.trim() == etag || tag.trim() == "*")
        });
    let etag = HeaderValue::from_str(&etag).expect("a hex ETag is a valid header value");
    // The URL changes with the content, so the file never goes stale.
    let cache = HeaderValue::from_static("public, max-age=31536000, immutable");
    if cached {
        return (
            StatusCode::NOT_MODIFIED,
            [(ETAG, etag), (CACHE_CONTROL, cache)],
        )
            .into_response();
    }
    (
        [
            (CONTENT_TYPE, HeaderValue::from_static(asset.content_type)),
            (ETAG, etag),
            (CACHE_CONTROL, cache),
            (
                axum::http::header::X_CONTENT_TYPE_OPTIONS,
                HeaderValue::from_static("nosniff"),
            ),
        ],
        asset.bytes,
    )
        .into_response()
}

#[cfg(test)]
mod tests;
