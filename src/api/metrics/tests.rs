//! `GET /metrics` through the router, on a paused clock, against the demo
//! devices; every page is read by a strict checker of the text exposition
//! format 0.0.4, written here from the format's rules.

use std::collections::{BTreeMap, BTreeSet};

use axum::Router;
use axum::http::{Method, StatusCode};

use super::{CONTENT_TYPE_TEXT, Exposition, Kind, ProcessStats, Value};
use super::{parse_boot_time, parse_stat, status_kb};
use crate::api::tests::support::{assert_error, demo, get, raw_call};
use crate::can::{BusState, BusStatus};
use crate::gateway::LATENCY_BUCKETS;

/// A page read by [`parse`]: each family's type, and each sample's value by
/// its series (`name{a="1",b="2"}`, labels sorted, values unescaped).
#[derive(Debug)]
struct Page {
    types: BTreeMap<String, String>,
    samples: BTreeMap<String, f64>,
}

impl Page {
    fn value(&self, name: &str, labels: &[(&str, &str)]) -> Option<f64> {
        let labels: BTreeMap<String, String> = labels
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        self.samples.get(&series(name, &labels)).copied()
    }

    fn node(&self, name: &str, node: &str) -> f64 {
        self.value(name, &[("bus", "demo"), ("node", node)])
            .unwrap_or_else(|| panic!("no {name} for node {node}"))
    }
}

fn series(name: &str, labels: &BTreeMap<String, String>) -> String {
    let labels: Vec<String> = labels.iter().map(|(k, v)| format!("{k}={v:?}")).collect();
    format!("{name}{{{}}}", labels.join(","))
}

fn is_metric_name(name: &str) -> bool {
    let mut chars = name.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_' || c == ':')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':')
}

fn is_label_name(name: &str) -> bool {
    let mut chars = name.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// A float as the format writes it (Go's syntax: `+Inf`, `-Inf`, `NaN`).
fn parse_float(text: &str) -> Result<f64, String> {
    match text {
        "+Inf" => Ok(f64::INFINITY),
        "-Inf" => Ok(f64::NEG_INFINITY),
        "NaN" => Ok(f64::NAN),
        _ if text
            .chars()
            .all(|c| c.is_ascii_digit() || matches!(c, '.' | '-' | '+' | 'e' | 'E')) =>
        {
            text.parse().map_err(|_| format!("bad value {text:?}"))
        }
        _ => Err(format!("bad value {text:?}")),
    }
}

/// `{a="x",b="y\"z"}` after a metric name: the labels (unescaped) and the
/// rest of the line.
fn parse_labels(text: &str) -> Result<(BTreeMap<String, String>, &str), String> {
    let mut labels = BTreeMap::new();
    let Some(mut rest) = text.strip_prefix('{') else {
        return Ok((labels, text));
    };
    loop {
        if let Some(after) = rest.strip_prefix('}') {
            return Ok((labels, after));
        }
        let (name, after) = rest
            .split_once("=\"")
            .ok_or_else(|| format!("no label value in {rest:?}"))?;
        if !is_label_name(name) || name.starts_with("__") {
            return Err(format!("bad label name {name:?}"));
        }
        let mut value = String::new();
        let mut chars = after.char_indices();
        let end = loop {
            match chars.next() {
                None => return Err(format!("unterminated label value in {text:?}")),
                Some((i, '"')) => break i,
                Some((_, '\\')) => match chars.next() {
                    Some((_, '\\')) => value.push('\\'),
                    Some((_, '"')) => value.push('"'),
                    Some((_, 'n')) => value.push('\n'),
                    other => return Err(format!("bad escape {other:?} in {text:?}")),
                },
                Some((_, c)) => value.push(c),
            }
        };
        if labels.insert(name.to_string(), value).is_some() {
            return Err(format!("label {name} twice in {text:?}"));
        }
        rest = &after[end + 1..];
        if let Some(after) = rest.strip_prefix(',') {
            rest = after;
        } else if !rest.starts_with('}') {
            return Err(format!("expected , or }} in {text:?}"));
        }
    }
}

/// One histogram series (its labels but `le`), as read so far.
#[derive(Default)]
struct Buckets {
    /// `(le, cumulative count)` in the order of the page.
    buckets: Vec<(f64, f64)>,
    sum: Option<f64>,
    count: Option<f64>,
}

/// Reads a page under the text format's rules, strictly: every sample
/// belongs to a family announced by `# TYPE` before it (one TYPE and at
/// most one HELP per family), a family's samples come together, names and
/// label names are well formed, label values are escaped, no series twice,
/// counters are not negative, and each histogram's buckets rise with `le`,
/// are cumulative, end in `le="+Inf"` equal to `_count`, with a `_sum`.
fn parse(text: &str) -> Result<Page, String> {
    if !text.ends_with('\n') {
        return Err("the last line has no line feed".into());
    }
    let mut types: BTreeMap<String, String> = BTreeMap::new();
    let mut helps = BTreeSet::new();
    let mut done: BTreeSet<String> = BTreeSet::new();
    let mut current: Option<String> = None;
    let mut samples = BTreeMap::new();
    let mut histograms: BTreeMap<(String, String), Buckets> = BTreeMap::new();
    for (n, line) in text.lines().enumerate() {
        let at = |message: String| format!("line {}: {message}: {line:?}", n + 1);
        if line.is_empty() {
            continue;
        }
        if let Some(comment) = line.strip_prefix('#') {
            let words: Vec<&str> = comment.trim_start().splitn(3, ' ').collect();
            match words.as_slice() {
                ["TYPE", name, kind] => {
                    if !is_metric_name(name) {
                        return Err(at(format!("bad name {name:?}")));
                    }
                    if !["counter", "gauge", "histogram", "summary", "untyped"].contains(kind) {
                        return Err(at(format!("bad type {kind:?}")));
                    }
                    if types.insert(name.to_string(), kind.to_string()).is_some() {
                        return Err(at("second TYPE".into()));
                    }
                    if done.contains(*name) || current.as_deref() == Some(*name) {
                        return Err(at("TYPE after its samples".into()));
                    }
                }
                ["HELP", name, ..] => {
                    if !is_metric_name(name) || !helps.insert(name.to_string()) {
                        return Err(at("bad or second HELP".into()));
                    }
                    let help = words.get(2).copied().unwrap_or("");
                    let mut chars = help.chars();
                    while let Some(c) = chars.next() {
                        if c == '\\' && !matches!(chars.next(), Some('\\' | 'n')) {
                            return Err(at("bad escape in HELP".into()));
                        }
                    }
                }
                _ => {} // Any other comment.
            }
            continue;
        }
        let name_end = line.find(['{', ' ']).ok_or_else(|| at("no value".into()))?;
        let name = &line[..name_end];
        if !is_metric_name(name) {
            return Err(at(format!("bad name {name:?}")));
        }
        let (mut labels, rest) = parse_labels(&line[name_end..]).map_err(at)?;
        let mut words = rest.split(' ');
        if words.next() != Some("") {
            return Err(at("no space before the value".into()));
        }
        let value = parse_float(words.next().unwrap_or("")).map_err(at)?;
        if let Some(timestamp) = words.next() {
            timestamp
                .parse::<i64>()
                .map_err(|_| at("bad timestamp".into()))?;
        }
        if words.next().is_some() {
            return Err(at("trailing text".into()));
        }
        // The family it belongs to, and its part of a histogram.
        let (family, part) = if types.contains_key(name) {
            (name.to_string(), "")
        } else {
            ["_bucket", "_sum", "_count"]
                .iter()
                .find_map(|suffix| {
                    let family = name.strip_suffix(suffix)?;
                    (types.get(family).map(String::as_str) == Some("histogram"))
                        .then(|| (family.to_string(), *suffix))
                })
                .ok_or_else(|| at("no TYPE announced it".into()))?
        };
        if current.as_deref() != Some(&family) {
            if done.contains(&family) {
                return Err(at("family's samples are not together".into()));
            }
            if let Some(previous) = current.replace(family.clone()) {
                done.insert(previous);
            }
        }
        let kind = types[&family].as_str();
        if kind == "counter" && (value.is_nan() || value < 0.0) {
            return Err(at("negative or NaN counter".into()));
        }
        if samples.insert(series(name, &labels), value).is_some() {
            return Err(at("series twice".into()));
        }
        if kind == "histogram" {
            if part.is_empty() {
                return Err(at("histogram sample without _bucket, _sum or _count".into()));
            }
            let le = labels.remove("le");
            let entry = histograms
                .entry((family.clone(), series("", &labels)))
                .or_default();
            match (part, le) {
                ("_bucket", Some(le)) => {
                    let le = parse_float(&le).map_err(at)?;
                    if let Some(&(last_le, last_count)) = entry.buckets.last()
                        && (le.is_nan() || le <= last_le || value < last_count)
                    {
                        return Err(at("buckets not rising or not cumulative".into()));
                    }
                    entry.buckets.push((le, value));
                }
                ("_bucket", None) => return Err(at("bucket without le".into())),
                (_, Some(_)) => return Err(at("le outside a bucket".into())),
                ("_sum", None) => entry.sum = Some(value),
                (_, None) => entry.count = Some(value),
            }
        }
    }
    for ((family, labels), entry) in &histograms {
        let last = entry.buckets.last();
        if last.map(|b| b.0) != Some(f64::INFINITY) {
            return Err(format!("{family}{labels}: no le=\"+Inf\" bucket last"));
        }
        if last.map(|b| b.1) != entry.count {
            return Err(format!("{family}{labels}: +Inf bucket is not _count"));
        }
        if entry.sum.is_none() {
            return Err(format!("{family}{labels}: no _sum"));
        }
    }
    Ok(Page { types, samples })
}

async fn scrape(app: &Router) -> Page {
    let (status, text, content_type) = raw_call(app, Method::GET, "/metrics", "", None).await;
    assert_eq!(status, StatusCode::OK, "{text}");
    assert_eq!(content_type.as_deref(), Some(CONTENT_TYPE_TEXT));
    parse(&text).unwrap_or_else(|error| panic!("{error}\n{text}"))
}

#[test]
fn the_checker_refuses_what_the_format_does_not_allow() {
    let good = "# HELP a_total A.\n# TYPE a_total counter\na_total{x=\"1\"} 3\n";
    assert!(parse(good).is_ok());
    let histogram = "# TYPE h histogram\nh_bucket{le=\"0.1\"} 1\nh_bucket{le=\"+Inf\"} 2\nh_sum 0.3\nh_count 2\n";
    assert!(parse(histogram).is_ok());
    for (bad, why) in [
        ("a_total 3\n", "no TYPE"),
        ("# TYPE a_total counter\na_total 3", "no final line feed"),
        ("# TYPE a_total counter\na_total -1\n", "negative counter"),
        ("# TYPE 1a gauge\n1a 3\n", "bad name"),
        ("# TYPE a gauge\na{x=\"1\\t\"} 3\n", "bad escape"),
        ("# TYPE a gauge\na{x=\"1\",x=\"2\"} 3\n", "label twice"),
        ("# TYPE a gauge\na{x=\"1} 3\n", "unterminated value"),
        ("# TYPE a gauge\na 3\na 4\n", "series twice"),
        ("# TYPE a gauge\na three\n", "bad value"),
        (
            "# TYPE a gauge\n# TYPE b gauge\na{x=\"1\"} 1\nb 1\na{x=\"2\"} 1\n",
            "family split",
        ),
        (
            "# TYPE h histogram\nh_bucket{le=\"1\"} 2\nh_bucket{le=\"+Inf\"} 1\nh_sum 0\nh_count 1\n",
            "not cumulative",
        ),
        (
            "# TYPE h histogram\nh_bucket{le=\"1\"} 2\nh_sum 0\nh_count 2\n",
            "no +Inf",
        ),
        (
            "# TYPE h histogram\nh_bucket{le=\"+Inf\"} 2\nh_sum 0\nh_count 3\n",
            "+Inf is not _count",
        ),
    ] {
        assert!(parse(bad).is_err(), "accepted ({why}): {bad:?}");
    }
}

#[test]
fn label_values_and_help_are_escaped() {
    let mut out = Exposition::default();
    out.family("odd", Kind::Gauge, "Back\\slash and\nnew line.");
    out.sample("odd", &[("bus", "a\"b\\c\nd")], Value::Float(f64::INFINITY));
    out.sample("odd", &[("bus", "plain")], Value::Float(0.5));
    assert_eq!(
        out.text,
        "# HELP odd Back\\\\slash and\\nnew line.\n# TYPE odd gauge\n\
         odd{bus=\"a\\\"b\\\\c\\nd\"} +Inf\nodd{bus=\"plain\"} 0.5\n"
    );
    let page = parse(&out.text).unwrap();
    assert_eq!(
        page.value("odd", &[("bus", "a\"b\\c\nd")]),
        Some(f64::INFINITY)
    );
}

#[tokio::test(start_paused = true)]
async fn the_page_is_valid_exposition_text_with_every_family() {
    let (app, _) = demo().await;
    let read = get(&app, "/api/v1/buses/demo/nodes/1/od/0x1000/0").await;
    assert_eq!(read.0, StatusCode::OK, "{}", read.1);
    let page = scrape(&app).await;
    for (family, kind) in [
        ("candeck_build_info", "gauge"),
        ("candeck_bus_info", "gauge"),
        ("candeck_bus_up", "gauge"),
        ("candeck_bus_frames_total", "counter"),
        ("candeck_bus_bits_total", "counter"),
        ("candeck_bus_load_ratio", "gauge"),
        ("candeck_bus_bitrate_bits_per_second", "gauge"),
        ("candeck_bus_reconnects_total", "counter"),
        ("candeck_bus_malformed_total", "counter"),
        ("candeck_bus_error_frames_total", "counter"),
        ("candeck_bus_send_errors_total", "counter"),
        ("candeck_bus_receive_overruns_total", "counter"),
        ("candeck_frame_log_lost_frames_total", "counter"),
        ("candeck_tpdo_malformed_frames_total", "counter"),
        ("candeck_nodes_known", "gauge"),
        ("candeck_nodes_online", "gauge"),
        ("candeck_node_online", "gauge"),
        ("candeck_sdo_transactions_total", "counter"),
        ("candeck_sdo_aborts_total", "counter"),
        ("candeck_sdo_timeouts_total", "counter"),
        ("candeck_sdo_protocol_errors_total", "counter"),
        ("candeck_sdo_bus_errors_total", "counter"),
        ("candeck_sdo_abandoned_total", "counter"),
        ("candeck_sdo_duration_seconds", "histogram"),
        ("candeck_stream_clients", "gauge"),
        ("candeck_stream_messages_total", "counter"),
        ("candeck_stream_coalesced_total", "counter"),
        ("candeck_stream_lagged_total", "counter"),
    ] {
        assert_eq!(
            page.types.get(family).map(String::as_str),
            Some(kind),
            "{family}"
        );
    }
    let bus = [("bus", "demo")];
    assert_eq!(page.value("candeck_bus_up", &bus), Some(1.0));
    assert_eq!(page.value("candeck_nodes_known", &bus), Some(3.0));
    assert_eq!(page.value("candeck_nodes_online", &bus), Some(3.0));
    assert_eq!(
        page.value("candeck_bus_bitrate_bits_per_second", &bus),
        Some(500_000.0)
    );
    // The scan and the read went both ways.
    for direction in ["rx", "tx"] {
        let frames = page.value(
            "candeck_bus_frames_total",
            &[("bus", "demo"), ("direction", direction)],
        );
        assert!(frames.is_some_and(|n| n > 0.0), "{direction}: {frames:?}");
    }
    for node in ["1", "2", "3"] {
        assert_eq!(page.node("candeck_node_online", node), 1.0);
        // Identified by the scan through their channels.
        assert!(page.node("candeck_sdo_transactions_total", node) > 0.0);
        let buckets = LATENCY_BUCKETS.len() + 1;
        let count = page.node("candeck_sdo_duration_seconds_count", node);
        assert!(count > 0.0, "node {node}");
        assert_eq!(
            page.samples
                .keys()
                .filter(
                    |key| key.starts_with("candeck_sdo_duration_seconds_bucket{")
                        && key.contains(&format!("node=\"{node}\""))
                )
                .count(),
            buckets
        );
    }
    assert_eq!(page.value("candeck_stream_clients", &[]), Some(0.0));
    if cfg!(target_os = "linux") {
        let rss = page.value("process_resident_memory_bytes", &[]).unwrap();
        let peak = page
            .value("candeck_process_resident_memory_peak_bytes", &[])
            .unwrap();
        assert!(rss > 1e6 && peak >= rss, "{rss} {peak}");
        assert!(page.value("process_open_fds", &[]).unwrap() > 0.0);
        assert!(page.value("process_start_time_seconds", &[]).unwrap() > 1.7e9);
    }
}

#[tokio::test(start_paused = true)]
async fn reads_count_as_transactions_in_the_histogram_too() {
    const N: usize = 25;
    let (app, _) = demo().await;
    let before = scrape(&app).await;
    for _ in 0..N {
        let read = get(&app, "/api/v1/buses/demo/nodes/1/od/a1_Statusword/0").await;
        assert_eq!(read.0, StatusCode::OK, "{}", read.1);
    }
    let after = scrape(&app).await;
    let delta = |name| after.node(name, "1") - before.node(name, "1");
    assert!(delta("candeck_sdo_transactions_total") >= N as f64);
    assert!(delta("candeck_sdo_duration_seconds_count") >= N as f64);
    assert_eq!(delta("candeck_sdo_aborts_total"), 0.0);
    assert_eq!(delta("candeck_sdo_timeouts_total"), 0.0);
    // The other nodes were not asked.
    assert_eq!(
        after.node("candeck_sdo_transactions_total", "3"),
        before.node("candeck_sdo_transactions_total", "3")
    );
}

#[tokio::test(start_paused = true)]
async fn an_object_the_node_lacks_counts_an_abort() {
    let (app, _) = demo().await;
    let before = scrape(&app).await;
    let response = get(&app, "/api/v1/buses/demo/nodes/1/od/0x5FFF/0").await;
    assert_error(&response, StatusCode::UNPROCESSABLE_ENTITY, "sdo_abort");
    let after = scrape(&app).await;
    let delta = |name| after.node(name, "1") - before.node(name, "1");
    assert_eq!(delta("candeck_sdo_aborts_total"), 1.0);
    assert!(delta("candeck_sdo_transactions_total") >= 1.0);
    assert_eq!(delta("candeck_sdo_timeouts_total"), 0.0);
}

#[tokio::test(start_paused = true)]
async fn a_bus_that_goes_down_shows_as_down() {
    let (app, state) = demo().await;
    let served = &state.gateway.bus("demo").unwrap();
    served
        .hub()
        .as_ref()
        .unwrap()
        .set_status(BusStatus::new(BusState::Down, "cable pulled"));
    let page = scrape(&app).await;
    assert_eq!(page.value("candeck_bus_up", &[("bus", "demo")]), Some(0.0));
    assert_eq!(
        page.value("candeck_nodes_known", &[("bus", "demo")]),
        Some(3.0)
    );
}

#[tokio::test(start_paused = true)]
async fn the_stream_counters_are_shown() {
    let (app, state) = demo().await;
    let counters = &state.stream_counters;
    counters
        .clients
        .store(2, std::sync::atomic::Ordering::Relaxed);
    crate::gateway::StreamCounters::add(&counters.coalesced, 7);
    crate::gateway::StreamCounters::add(&counters.lagged, 3);
    let page = scrape(&app).await;
    assert_eq!(page.value("candeck_stream_clients", &[]), Some(2.0));
    assert_eq!(page.value("candeck_stream_coalesced_total", &[]), Some(7.0));
    assert_eq!(page.value("candeck_stream_lagged_total", &[]), Some(3.0));
    assert_eq!(page.value("candeck_stream_messages_total", &[]), Some(0.0));
}

#[tokio::test(start_paused = true)]
async fn metrics_answers_get_only() {
    let (app, _) = demo().await;
    let (status, _, _) = raw_call(&app, Method::POST, "/metrics", "", None).await;
    assert_eq!(status, StatusCode::METHOD_NOT_ALLOWED);
}

#[test]
fn proc_files_are_read_field_by_field() {
    let status = "Name:\tcandeck\nVmHWM:\t   51200 kB\nVmRSS:\t   40960 kB\nThreads:\t3\n";
    assert_eq!(status_kb(status, "VmRSS"), Some(40960 * 1024));
    assert_eq!(status_kb(status, "VmHWM"), Some(51200 * 1024));
    assert_eq!(status_kb(status, "VmSwap"), None);
    assert_eq!(status_kb("VmRSS:\tlots\n", "VmRSS"), None);
    // A command name with spaces and parentheses does not shift the fields.
    let stat = "4242 (my (odd) name) S 1 4242 4242 0 -1 4194560 500 0 0 0 \
                250 150 0 0 20 0 3 0 123456 100000000 2500 18446744073709551615";
    let times = parse_stat(stat).unwrap();
    assert_eq!(times.cpu_seconds, 4.0);
    assert_eq!(times.start_after_boot_seconds, 1234.56);
    assert_eq!(parse_stat("4242 (cut short) S 1 2"), None);
    assert_eq!(
        parse_boot_time("cpu  1 2 3\nbtime 1795400000\nprocesses 9\n"),
        Some(1_795_400_000)
    );
    assert_eq!(parse_boot_time("cpu  1 2 3\n"), None);
}

#[cfg(target_os = "linux")]
#[test]
fn this_process_is_read_from_proc() {
    let process = ProcessStats::read();
    let rss = process.resident_bytes.unwrap();
    assert!(rss > 0 && process.peak_resident_bytes.unwrap() >= rss);
    assert!(process.open_fds.unwrap() >= 3);
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    let started = process.start_time_seconds.unwrap();
    // Started before now, and not long ago: /proc/stat's boot time is whole
    // seconds, and follows the wall clock's adjustments only roughly.
    assert!(
        started <= now + 60.0 && now - started < 86_400.0,
        "{started} {now}"
    );
}
