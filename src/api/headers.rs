//! The headers every answer carries against framing and content sniffing
//! (issue 19, point 9): a foreign page must not frame the buttons that move
//! axes (clickjacking), nor a browser run an answer as something else.
//!
//! The dashboard's pages load their scripts and styles from `/static/` and
//! have no inline script or style, so their policy allows `'self'` only.
//! The docs UI (`/api/docs`, Swagger UI) sets styles inline and draws its
//! icons from `data:` URLs: it has a policy of its own that allows those,
//! still with no inline script.

use axum::http::{HeaderValue, header};
use axum::response::Response;

/// The dashboard's, the API's and every other answer's policy.
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self'; connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'";

/// The docs UI's policy (`/api/docs`).
pub const DOCS_CONTENT_SECURITY_POLICY: &str = "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'";

/// Adds the headers to an answer to a request for `path` (those the
/// handler set itself stay).
pub fn add(path: &str, response: &mut Response) {
    let policy = if path == "/api/docs" || path.starts_with("/api/docs/") {
        DOCS_CONTENT_SECURITY_POLICY
    } else {
        CONTENT_SECURITY_POLICY
    };
    let headers = response.headers_mut();
    for (name, value) in [
        (header::CONTENT_SECURITY_POLICY, policy),
        (header::X_FRAME_OPTIONS, "DENY"),
        (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        (header::REFERRER_POLICY, "no-referrer"),
    ] {
        headers
            .entry(name)
            .or_insert(HeaderValue::from_static(value));
    }
}

/// The middleware (`axum::middleware::from_fn`), around everything.
pub async fn layer(request: axum::extract::Request, next: axum::middleware::Next) -> Response {
    let path = request.uri().path().to_string();
    let mut response = next.run(request).await;
    add(&path, &mut response);
    response
}
