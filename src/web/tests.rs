use std::collections::BTreeSet;
use std::path::Path;

use axum::Router;
use axum::body::Body;
use axum::http::{HeaderMap, Request, StatusCode};
use tower::ServiceExt;

use super::{ASSETS, asset, router, static_version};

async fn fetch(
    app: &Router,
    uri: &str,
    headers: &[(&str, &str)],
) -> (StatusCode, HeaderMap, Vec<u8>) {
    let mut request = Request::builder().uri(uri);
    for (name, value) in headers {
        request = request.header(*name, *value);
    }
    let response = app
        .clone()
        .oneshot(request.body(Body::empty()).unwrap())
        .await
        .unwrap();
    let status = response.status();
    let headers = response.headers().clone();
    let body = axum::body::to_bytes(response.into_body(), usize::MAX)
        .await
        .unwrap();
    (status, headers, body.to_vec())
}

fn header<'a>(headers: &'a HeaderMap, name: &str) -> &'a str {
    headers
        .get(name)
        .unwrap_or_else(|| panic!("no {name} header"))
        .to_str()
        .unwrap()
}

/// Every `/static/...` URL a page names.
fn static_urls(html: &str) -> Vec<String> {
    html.split('"')
        .filter(|part| part.starts_with("/static/"))
        .map(str::to_string)
        .collect()
}

fn files_under(dir: &Path, prefix: &str, out: &mut BTreeSet<String>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let entry = entry.unwrap();
        let name = format!("{prefix}{}", entry.file_name().to_str().unwrap());
        if entry.file_type().unwrap().is_dir() {
            files_under(&entry.path(), &format!("{name}/"), out);
        } else {
            out.insert(name);
        }
    }
}

#[test]
fn every_file_of_web_static_is_embedded_and_nothing_else() {
    let mut on_disk = BTreeSet::new();
    files_under(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("web/static"),
        "",
        &mut on_disk,
    );
    let embedded: BTreeSet<String> = ASSETS.iter().map(|a| a.path.to_string()).collect();
    assert_eq!(on_disk, embedded, "web/static and web::ASSETS differ");
}

#[test]
fn every_module_import_names_an_embedded_file() {
    for js in ASSETS.iter().filter(|a| a.path.ends_with(".js")) {
        let text = std::str::from_utf8(js.bytes).unwrap();
        let dir = Path::new(js.path).parent().unwrap();
        for line in text.lines().filter(|l| l.starts_with("import ")) {
            let target = line
                .split(['\'', '"'])
                .nth(1)
                .unwrap_or_else(|| panic!("{}: cannot read {line}", js.path));
            assert!(
                target.starts_with("./"),
                "{}: import {target} is not relative",
                js.path
            );
            let path = dir.join(&target[2..]);
            let path = path.to_str().unwrap();
            assert!(
                asset(path).is_some(),
                "{}: imports {path}, which is not embedded",
                js.path
            );
        }
    }
}

/// The page at `uri`, checked as every page must be: 200, HTML, never
/// cached, naming each of `wanted` (paths under `web/static/`) under this
/// build's prefix, and loading only files that are embedded.
async fn page_html(app: &Router, uri: &str, wanted: &[&str]) -> String {
    let (status, headers, body) = fetch(app, uri, &[]).await;
    assert_eq!(status, StatusCode::OK, "{uri}");
    assert_eq!(header(&headers, "content-type"), "text/html; charset=utf-8");
    assert_eq!(header(&headers, "cache-control"), "no-cache");
    let html = String::from_utf8(body).unwrap();
    let urls = static_urls(&html);
    let prefix = format!("/static/{}/", static_version());
    for wanted in wanted {
        assert!(
            urls.contains(&format!("{prefix}{wanted}")),
            "{uri}: {wanted} not in {urls:?}"
        );
    }
    for url in urls {
        let (status, headers, body) = fetch(app, &url, &[]).await;
        assert_eq!(status, StatusCode::OK, "{url}");
        assert!(!body.is_empty(), "{url}");
        assert!(!header(&headers, "content-type").is_empty(), "{url}");
    }
    html
}

#[tokio::test]
async fn the_overview_is_at_the_root_and_loads_only_embedded_files() {
    let html = page_html(
        &router(),
        "/",
        &["css/app.css", "js/overview.js", "icon.svg"],
    )
    .await;
    assert!(html.contains("id=\"stop-all\""), "{html}");
    assert!(html.contains("id=\"connection\""), "{html}");
}

#[tokio::test]
async fn static_files_have_their_type_a_long_cache_life_and_an_etag() {
    let app = router();
    let version = static_version();
    for (path, content_type) in [
        ("css/app.css", "text/css; charset=utf-8"),
        ("js/stream.js", "text/javascript; charset=utf-8"),
        ("icon.svg", "image/svg+xml"),
    ] {
        let (status, headers, body) = fetch(&app, &format!("/static/{version}/{path}"), &[]).await;
        assert_eq!(status, StatusCode::OK, "{path}");
        assert_eq!(header(&headers, "content-type"), content_type);
        assert_eq!(
            header(&headers, "cache-control"),
            "public, max-age=31536000, immutable"
        );
        assert_eq!(body, asset(path).unwrap().bytes);
        let etag = header(&headers, "etag").to_string();
        assert!(etag.starts_with('"') && etag.ends_with('"') && etag.len() > 2);

        let uri = format!("/static/{version}/{path}");
        let (status, headers, body) = fetch(&app, &uri, &[("if-none-match", &etag)]).await;
        assert_eq!(status, StatusCode::NOT_MODIFIED, "{path}");
        assert_eq!(header(&headers, "etag"), etag);
        assert!(body.is_empty());
        // Another ETag (the file changed) gets the file.
        let (status, _, body) = fetch(&app, &uri, &[("if-none-match", "\"0\"")]).await;
        assert_eq!(status, StatusCode::OK);
        assert_eq!(body, asset(path).unwrap().bytes);
    }
}

#[tokio::test]
async fn unknown_static_paths_and_other_versions_are_404() {
    let app = router();
    let version = static_version();
    for uri in [
        format!("/static/{version}/js/nothing.js"),
        format!("/static/{version}/css"),
        format!("/static/{version}/../Cargo.toml"),
        "/static/0123456789ab/css/app.css".to_string(),
        "/static/css/app.css".to_string(),
    ] {
        let (status, headers, body) = fetch(&app, &uri, &[]).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}");
        assert_eq!(header(&headers, "content-type"), "application/json");
        let body: serde_json::Value = serde_json::from_slice(&body).unwrap();
        assert_eq!(body["error"]["code"], "not_found", "{uri}: {body}");
    }
}

#[test]
fn the_version_is_a_hash_of_the_files() {
    let version = static_version();
    assert_eq!(version.len(), 12);
    assert!(version.bytes().all(|b| b.is_ascii_hexdigit()));
    assert_ne!(
        super::fnv1a(super::FNV_OFFSET, b"a"),
        super::fnv1a(super::FNV_OFFSET, b"b")
    );
}

#[tokio::test]
async fn the_api_app_serves_the_dashboard_outside_the_api_and_its_document() {
    let (router, doc) = crate::api::routers(crate::api::AppState::new([]));
    let app = router.merge(super::router());
    let (status, headers, _) = fetch(&app, "/", &[]).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(header(&headers, "content-type"), "text/html; charset=utf-8");
    let (status, _, _) = fetch(&app, "/api/v1/health", &[]).await;
    assert_eq!(status, StatusCode::OK);
    for path in doc.paths.paths.keys() {
        assert!(
            path.starts_with("/api/v1/") || path == "/metrics",
            "{path} in the OpenAPI document"
        );
    }
}

#[tokio::test]
async fn the_drive_page_names_its_axis_and_loads_only_embedded_files() {
    let wanted = ["css/app.css", "css/drive.css", "js/drive.js", "icon.svg"];
    let html = page_html(&router(), "/nodes/demo/1/axes/2", &wanted).await;
    assert!(
        html.contains(r#"data-bus="demo" data-node="1" data-axis="2""#),
        "{html}"
    );
    assert!(html.contains(r#"href="/nodes/demo/1""#), "{html}");
    assert!(html.contains("<title>Axis 2 · node 1 · demo · candeck</title>"));
    for id in [
        "diagram",
        "transitions",
        "fault-reset",
        "chart-position",
        "status-bits",
    ] {
        assert!(html.contains(&format!("id=\"{id}\"")), "no #{id}");
    }
}

/// The path is the page's input: whatever it holds is text in the page,
/// never markup, and a path segment again in the node link.
#[tokio::test]
async fn the_drive_page_escapes_what_the_path_holds() {
    let uri = "/nodes/%3Cb%3Ex%22y%2Fz/%3Cscript%3E/axes/1%22%20onload%3D%22x";
    let (status, _, body) = fetch(&router(), uri, &[]).await;
    assert_eq!(status, StatusCode::OK);
    let html = String::from_utf8(body).unwrap();
    assert!(
        !html.contains("<b>") && !html.contains("<script>"),
        "{html}"
    );
    assert!(!html.contains(r#"" onload=""#), "{html}");
    assert!(html.contains("data-bus=\"&#60;b&#62;x&#34;y/z\""), "{html}");
    assert!(
        html.contains(r#"href="/nodes/%3Cb%3Ex%22y%2Fz/%3Cscript%3E""#),
        "{html}"
    );
}

#[tokio::test]
async fn a_drive_path_with_parts_missing_or_added_is_no_page() {
    let app = router();
    for uri in [
        "/nodes/demo/1/axes",
        "/nodes/demo/1/axes/1/move",
        "/nodes/demo/axes/1",
    ] {
        let (status, _, _) = fetch(&app, uri, &[]).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}");
    }
}

#[tokio::test]
async fn the_pdo_editor_names_its_node_and_loads_only_embedded_files() {
    let wanted = ["css/app.css", "css/pdos.css", "js/pdos.js"];
    let html = page_html(&router(), "/nodes/demo/1/pdos", &wanted).await;
    assert!(
        html.contains(r#"id="pdo-page" data-bus="demo" data-node="1""#),
        "{html}"
    );
    assert!(html.contains(r#"href="/nodes/demo/1""#), "{html}");
    assert!(html.contains("<title>PDOs of node 1 on demo · candeck</title>"));
}

/// The bus and node come from the path as typed: text, never markup.
#[tokio::test]
async fn the_pdo_editor_escapes_what_the_path_says() {
    let (status, _, body) = fetch(
        &router(),
        "/nodes/%3Cscript%3Ex%22%3C%2Fscript%3E/1%22%20onload%3D%22x/pdos",
        &[],
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    let html = String::from_utf8(body).unwrap();
    assert!(!html.contains("<script>x"), "{html}");
    assert!(!html.contains("1\" onload"), "{html}");
    assert!(
        html.contains(
            r#"data-bus="&#60;script&#62;x&#34;&#60;/script&#62;" data-node="1&#34; onload=&#34;x""#
        ),
        "{html}"
    );
    // The link back to the node page: one path segment each.
    assert!(
        html.contains(r#"href="/nodes/%3Cscript%3Ex%22%3C%2Fscript%3E/1%22%20onload%3D%22x""#),
        "{html}"
    );
}

#[tokio::test]
async fn the_node_page_carries_its_bus_and_node_escaped_and_loads_only_embedded_files() {
    let app = router();
    let html = page_html(
        &app,
        "/nodes/demo/1",
        &["css/app.css", "css/node.css", "js/node.js"],
    )
    .await;
    assert!(
        html.contains(r#"id="node-page" data-bus="demo" data-node="1""#),
        "{html}"
    );
    assert!(html.contains("id=\"od-search\""), "{html}");
    assert!(
        html.contains("<title>Node 1 · demo · candeck</title>"),
        "{html}"
    );

    // Whatever the path holds is text in an attribute, never markup: the
    // page itself asks the API whether the bus and node exist.
    let (status, _, body) = fetch(&app, "/nodes/%3Cb%3Ex%22/%27%3E", &[]).await;
    assert_eq!(status, StatusCode::OK);
    let html = String::from_utf8(body).unwrap();
    assert!(!html.contains("<b>x"), "{html}");
    let bus = html
        .split("data-bus=\"")
        .nth(1)
        .and_then(|rest| rest.split('"').next())
        .unwrap();
    assert!(
        bus.contains('x') && !bus.contains('<') && !bus.contains('>'),
        "{bus}"
    );
    let node = html.split("data-node=\"").nth(1).unwrap();
    assert!(
        node.starts_with("&#") || node.starts_with("&apos;"),
        "{node}"
    );
}

#[tokio::test]
async fn the_events_page_is_in_the_navigation_and_marked_current() {
    let app = router();
    let (status, headers, body) = fetch(&app, "/events", &[]).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(header(&headers, "content-type"), "text/html; charset=utf-8");
    let html = String::from_utf8(body).unwrap();
    assert!(
        html.contains(r#"<a href="/events" aria-current="page">Events</a>"#),
        "{html}"
    );
    assert!(html.contains("id=\"history\""), "{html}");
    let prefix = format!("/static/{}/", static_version());
    let urls = static_urls(&html);
    for wanted in ["css/events.css", "js/events.js"] {
        assert!(
            urls.contains(&format!("{prefix}{wanted}")),
            "{wanted} not in {urls:?}"
        );
    }
    // The overview links the events page without marking it.
    let (_, _, body) = fetch(&app, "/", &[]).await;
    let html = String::from_utf8(body).unwrap();
    assert!(html.contains(r#"<a href="/events">Events</a>"#), "{html}");
}

#[tokio::test]
async fn a_node_path_with_a_part_missing_is_no_page() {
    let app = router();
    for uri in ["/nodes/demo", "/nodes/demo/1/od/extra/more"] {
        let (status, _, _) = fetch(&app, uri, &[]).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}");
    }
}

#[tokio::test]
async fn the_led_page_carries_its_bus_and_node_and_loads_its_module() {
    let wanted = ["css/app.css", "css/leds.css", "js/leds.js"];
    let html = page_html(&router(), "/nodes/demo/3/leds", &wanted).await;
    assert!(
        html.contains(r#"id="leds-page" data-bus="demo" data-node="3""#),
        "{html}"
    );
    assert!(html.contains(r#"href="/nodes/demo/3""#), "{html}");
    assert!(html.contains("<title>LEDs · node 3 · demo · candeck</title>"));
}

#[tokio::test]
async fn the_trace_page_carries_its_bus_and_loads_its_module() {
    let html = page_html(
        &router(),
        "/buses/demo/trace",
        &["css/trace.css", "js/trace.js"],
    )
    .await;
    assert!(
        html.contains(r#"id="trace-page" data-bus="demo""#),
        "{html}"
    );
}

/// A bus name from the URL is text in the page, never markup, and the
/// link back to the node page names the same bus.
#[tokio::test]
async fn a_bus_name_in_the_path_is_escaped_in_the_page_and_encoded_in_links() {
    let app = router();
    let (status, _, body) = fetch(&app, "/nodes/a%22%3E%3Cb%3E%20x/5/leds", &[]).await;
    assert_eq!(status, StatusCode::OK);
    let html = String::from_utf8(body).unwrap();
    assert!(!html.contains("\"><b>"), "{html}");
    assert!(
        html.contains(r#"data-bus="a&#34;&#62;&#60;b&#62; x""#),
        "{html}"
    );
    assert!(
        html.contains(r#"href="/nodes/a%22%3E%3Cb%3E%20x/5""#),
        "{html}"
    );

    let (status, _, body) = fetch(&app, "/buses/%3Cscript%3E/trace", &[]).await;
    assert_eq!(status, StatusCode::OK);
    let html = String::from_utf8(body).unwrap();
    assert!(!html.contains("<script>"), "{html}");
    assert!(html.contains(r#"data-bus="&#60;script&#62;""#), "{html}");
}

#[tokio::test]
async fn an_led_page_of_a_node_id_beyond_1_to_127_is_404() {
    let app = router();
    for uri in [
        "/nodes/demo/0/leds",
        "/nodes/demo/128/leds",
        "/nodes/demo/-1/leds",
        "/nodes/demo/x/leds",
        "/nodes/demo/3/leds/more",
    ] {
        let (status, headers, body) = fetch(&app, uri, &[]).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}");
        if !body.is_empty() {
            assert_eq!(header(&headers, "content-type"), "application/json");
            let body: serde_json::Value = serde_json::from_slice(&body).unwrap();
            assert_eq!(body["error"]["code"], "not_found", "{uri}: {body}");
        }
    }
}

#[test]
fn path_segments_are_percent_encoded_but_unreserved_characters() {
    assert_eq!(super::path_segment("demo-1_a.b~"), "demo-1_a.b~");
    assert_eq!(super::path_segment("a/b?c d"), "a%2Fb%3Fc%20d");
    assert_eq!(super::path_segment("é"), "%C3%A9");
}

/// The bytes a page loads before API data: its HTML, the static files it
/// names, and the modules those import (`from './x.js'`), transitively.
async fn page_weight(app: &Router, page: &str) -> usize {
    let (status, _, html) = fetch(app, page, &[]).await;
    assert_eq!(status, StatusCode::OK, "{page}");
    let html = String::from_utf8(html).unwrap();
    let prefix = format!("/static/{}/", static_version());
    let mut pending: Vec<String> = static_urls(&html)
        .into_iter()
        .filter_map(|url| url.strip_prefix(&prefix).map(str::to_string))
        .collect();
    let mut seen = std::collections::BTreeSet::new();
    let mut total = html.len();
    while let Some(path) = pending.pop() {
        if !seen.insert(path.clone()) {
            continue;
        }
        let asset = asset(&path).unwrap_or_else(|| panic!("{page} loads {path}, not embedded"));
        total += asset.bytes.len();
        if path.ends_with(".js") {
            let text = std::str::from_utf8(asset.bytes).unwrap();
            for part in text.split("'./").skip(1) {
                if let Some((name, _)) = part.split_once('\'')
                    && name.ends_with(".js")
                {
                    pending.push(format!("js/{name}"));
                }
            }
        }
    }
    total
}

/// Issue 7's budget: each page's HTML, CSS and JS under 300 KB before API
/// data. The end-to-end tests measure what the browser loads; this keeps a
/// change that breaks the budget from getting that far.
#[tokio::test]
async fn every_page_weighs_under_300_kb() {
    let app = router();
    for page in [
        "/",
        "/events",
        "/loggers",
        "/nodes/demo/1",
        "/nodes/demo/1/axes/1",
        "/nodes/demo/1/pdos",
        "/nodes/demo/3/leds",
        "/buses/demo/trace",
        "/alarms",
    ] {
        let total = page_weight(&app, page).await;
        assert!(total < 300 * 1024, "{page}: {total} bytes");
        // Counted, not zero: the page's module and styles are in it.
        assert!(total > 10 * 1024, "{page}: {total} bytes");
    }
}

#[tokio::test]
async fn the_tuning_page_lists_the_axis_loops_from_the_profile() {
    let wanted = ["css/tune.css", "js/tune.js"];
    let html = page_html(&router(), "/nodes/demo/1/axes/2/tune", &wanted).await;
    // Axis 2's records, at +0x200 (UMC manual Table 1.5).
    for (name, config, status) in [
        ("torque", "0x4221", "0x4220"),
        ("velocity", "0x4241", "0x4240"),
        ("position", "0x4261", "0x4260"),
    ] {
        assert!(
            html.contains(&format!(
                r#"data-loop="{name}" data-config="{config}" data-status="{status}""#
            )),
            "{name}: {html}"
        );
    }
    assert!(html.contains(r#"data-input-unit="rpm" data-output-unit="A""#));
    for id in [
        "gains",
        "pid-status",
        "step-form",
        "step-chart",
        "step-unit",
        "step-runs",
        "runs-clear",
        "gains-store",
    ] {
        assert!(html.contains(&format!("id=\"{id}\"")), "no #{id}");
    }
    assert!(html.contains(r#"href="/nodes/demo/1/axes/2/commissioning/motor""#));
}

#[tokio::test]
async fn each_commissioning_page_lists_its_objects_with_units() {
    let app = router();
    let html = page_html(
        &app,
        "/nodes/demo/1/axes/2/commissioning/motor",
        &["css/tune.css", "js/commission.js"],
    )
    .await;
    // Axis 2's Peak_current, in 0.01 A, writable.
    assert!(
        html.contains(r#"data-index="0x4207" data-sub="2" data-kind="0.01" data-writable="true""#),
        "{html}"
    );
    assert!(
        html.contains(r#"data-index="0x4206" data-sub="3" data-kind="q15" data-writable="false""#)
    );
    for (slug, object) in [
        ("board", r#"data-index="0x2041" data-sub="1""#),
        ("brake", r#"data-index="0x4082" data-sub="1""#),
        ("sensors", r#"data-index="0x4063" data-sub="1""#),
    ] {
        let uri = format!("/nodes/demo/1/axes/1/commissioning/{slug}");
        let html = page_html(&app, &uri, &["js/commission.js"]).await;
        assert!(html.contains(object), "{slug}: {html}");
    }
    for uri in [
        "/nodes/demo/1/axes/1/commissioning/gearbox",
        "/nodes/demo/1/axes/9/commissioning/motor",
        "/nodes/demo/0/axes/1/tune",
    ] {
        let (status, _, _) = fetch(&app, uri, &[]).await;
        assert_eq!(status, StatusCode::NOT_FOUND, "{uri}");
    }
}

/// Issue 31: the alarm bar on every page (its element and its module, in
/// the layout), and the alarm page in the navigation.
#[tokio::test]
async fn every_page_has_the_alarm_bar_and_the_alarm_page_is_in_the_navigation() {
    let app = router();
    for uri in [
        "/",
        "/alarms",
        "/events",
        "/loggers",
        "/eds",
        "/nodes/demo/1",
        "/nodes/demo/1/axes/1",
        "/nodes/demo/1/pdos",
        "/nodes/demo/2/io",
        "/nodes/demo/3/leds",
        "/buses/demo/trace",
        "/nodes/demo/1/axes/1/tune",
        "/nodes/demo/1/axes/1/commissioning/board",
    ] {
        let html = page_html(&app, uri, &["js/alarmbar.js"]).await;
        assert!(
            html.contains(r#"<a id="alarm-bar" class="alarm-bar" href="/alarms""#),
            "{uri}: {html}"
        );
    }
    let html = page_html(&app, "/alarms", &["css/alarms.css", "js/alarms.js"]).await;
    assert!(
        html.contains(r#"<a href="/alarms" aria-current="page">Alarms</a>"#),
        "{html}"
    );
    assert!(html.contains(r#"id="alarm-list""#), "{html}");
}
