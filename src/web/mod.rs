//! The browser dashboard (`../shared/API.md`: `GET /` the dashboard): its
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
//! - [`router`]: `/` (the overview) and `/static/{version}/{*path}`;
//!   neither is under `/api/v1` nor in the OpenAPI document.
//! - [`ASSETS`]: the static files, embedded with `include_bytes!`, and
//!   [`asset`] to look one up; [`static_version`] is the prefix's version.
//! - `OverviewPage`: the overview's template (`web/templates/overview.html`,
//!   which extends `base.html`: navigation and the connection indicator).

use std::sync::LazyLock;

use askama::Template;
use axum::Router;
use axum::extract::Path;
use axum::http::header::{CACHE_CONTROL, CONTENT_TYPE, ETAG, IF_NONE_MATCH};
use axum::http::{HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;

use crate::api::AppError;

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
    asset!("css/app.css", CSS),
    asset!("css/auth.css", CSS),
    asset!("js/api.js", JS),
    asset!("js/auth.js", JS),
    asset!("js/dom.js", JS),
    asset!("js/layout.js", JS),
    asset!("js/overview.js", JS),
    asset!("js/stream.js", JS),
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
}

impl Layout {
    fn new(current: &'static str) -> Self {
        Self {
            static_root: format!("/static/{}", static_version()),
            current,
            version: env!("CARGO_PKG_VERSION"),
        }
    }
}

/// The overview: buses, nodes, STOP ALL and recent events.
#[derive(Template)]
#[template(path = "overview.html")]
struct OverviewPage {
    layout: Layout,
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
        Err(err) => {
            AppError::Internal(format!("rendering a dashboard page: {err}")).into_response()
        }
    }
}

async fn overview() -> Response {
    page(&OverviewPage {
        layout: Layout::new("overview"),
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
