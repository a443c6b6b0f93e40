//! The audit log and `/events` through the router, against the demo
//! devices on a paused clock.

use std::time::Duration;

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Value as Json, json};

use crate::api::tests::support::{assert_error, call_text, demo, get, raw_call};

/// Polls `/events?{query}` until `found` holds (the EMCY/NMT recorder
/// writes after the registry publishes); the entries.
async fn wait_events(app: &Router, query: &str, found: impl Fn(&[Json]) -> bool) -> Vec<Json> {
    for _ in 0..500 {
        let (status, events) = get(app, &format!("/api/v1/events?{query}")).await;
        assert_eq!(status, StatusCode::OK, "{events}");
        let events = events.as_array().unwrap().clone();
        if found(&events) {
            return events;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let (_, events) = get(app, &format!("/api/v1/events?{query}")).await;
    panic!("/events?{query}: never found what was expected in {events:#}");
}

/// One request: method, path, body, and the target the audit entry must
/// name: (operation, bus, node, axis, item).
struct Case {
    method: Method,
    path: &'static str,
    body: Option<&'static str>,
    operation: &'static str,
    node: Option<u8>,
    axis: Option<u8>,
    item: Option<&'static str>,
}

fn case(
    method: Method,
    path: &'static str,
    body: Option<&'static str>,
    operation: &'static str,
    node: Option<u8>,
    axis: Option<u8>,
    item: Option<&'static str>,
) -> Case {
    Case {
        method,
        path,
        body,
        operation,
        node,
        axis,
        item,
    }
}

#[tokio::test(start_paused = true)]
async fn every_state_changing_request_is_audited_with_its_target_and_result() {
    let (app, _) = demo().await;
    use Method as M;
    let cases = [
        case(
            M::PUT,
            "/api/v1/buses/demo/nodes/1/od/0x1017/0",
            Some(r#"{"value":100}"#),
            "write object",
            Some(1),
            None,
            Some("0x1017:0"),
        ),
        // Refused before the bus: out of range for UNSIGNED16.
        case(
            M::PUT,
            "/api/v1/buses/demo/nodes/1/od/0x1017/0",
            Some(r#"{"value":70000}"#),
            "write object",
            Some(1),
            None,
            Some("0x1017:0"),
        ),
        // Refused by the device: an object it does not have.
        case(
            M::PUT,
            "/api/v1/buses/demo/nodes/1/od/0x2FFF/0",
            Some(r#"{"value":1,"data_type":"u8"}"#),
            "write object",
            Some(1),
            None,
            Some("0x2FFF:0"),
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/nodes/1/nmt",
            Some(r#"{"command":"pre_operational"}"#),
            "nmt command",
            Some(1),
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/nmt",
            Some(r#"{"command":"bogus"}"#),
            "nmt command to all nodes",
            None,
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/nodes/1/store",
            Some(r#"{"what":"all"}"#),
            "store parameters",
            Some(1),
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/nodes/1/restore",
            Some(r#"{"what":"nothing"}"#),
            "restore parameters",
            Some(1),
            None,
            None,
        ),
        case(
            M::PUT,
            "/api/v1/buses/demo/nodes/1/config.dcf",
            Some("[not a dcf"),
            "restore configuration (DCF)",
            Some(1),
            None,
            None,
        ),
        case(
            M::PUT,
            "/api/v1/buses/demo/nodes/1/pdos/tpdo/1",
            Some(r#"{"transmission_type":255,"mapping":[{"index":"a1_Statusword"}]}"#),
            "configure pdo",
            Some(1),
            None,
            Some("tpdo 1"),
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/nodes/1/pdos/rpdo/1/send",
            Some(r#"{"values":{}}"#),
            "send rpdo",
            Some(1),
            None,
            Some("rpdo 1"),
        ),
        case(
            M::PUT,
            "/api/v1/buses/demo/sync",
            Some(r#"{"period_ms":0}"#),
            "set sync period",
            None,
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/nodes/1/axes/1/state",
            Some(r#"{"target":"switch_on_disabled"}"#),
            "drive state change",
            Some(1),
            Some(1),
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/nodes/1/axes/2/fault-reset",
            None,
            "fault reset",
            Some(1),
            Some(2),
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/nodes/1/axes/1/halt",
            Some(r#"{"halt":true}"#),
            "halt",
            Some(1),
            Some(1),
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/nodes/2/axes/1/move",
            Some(r#"{"mode":"velocity","velocity":10}"#),
            "move",
            Some(2),
            Some(1),
            None,
        ),
        case(
            M::PUT,
            "/api/v1/buses/demo/nodes/3/segments/1",
            Some(r#"{"effect":"fix"}"#),
            "set segment",
            Some(3),
            None,
            Some("segment 1"),
        ),
        case(
            M::PUT,
            "/api/v1/buses/demo/nodes/3/segments",
            Some(r#"{"segments":[],"others":"off"}"#),
            "set scene",
            Some(3),
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/frames",
            Some(r#"{"id":"0x7FF","data":""}"#),
            "send frame",
            None,
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/recording",
            None,
            "start recording",
            None,
            None,
            None,
        ),
        case(
            M::DELETE,
            "/api/v1/buses/demo/recording",
            None,
            "stop recording",
            None,
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/sim/nodes",
            Some(r#"{"product":"jmc","id":4}"#),
            "add virtual device",
            None,
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/sim/nodes/4/faults",
            Some(r#"{"kind":"over_temperature"}"#),
            "inject fault",
            Some(4),
            None,
            None,
        ),
        case(
            M::DELETE,
            "/api/v1/buses/demo/sim/nodes/4/faults",
            Some(r#"{"kind":"over_temperature"}"#),
            "clear fault",
            Some(4),
            None,
            None,
        ),
        case(
            M::DELETE,
            "/api/v1/buses/demo/sim/nodes/4",
            None,
            "remove virtual device",
            Some(4),
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/scan",
            None,
            "scan",
            None,
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/stop-all",
            None,
            "stop all axes",
            None,
            None,
            None,
        ),
        case(
            M::PUT,
            "/api/v1/buses/nope/nodes/1/od/0x1017/0",
            Some(r#"{"value":1}"#),
            "write object",
            Some(1),
            None,
            Some("0x1017:0"),
        ),
        case(
            M::DELETE,
            "/api/v1/eds/umc1bds32.eds",
            None,
            "delete eds",
            None,
            None,
            Some("umc1bds32.eds"),
        ),
        case(
            M::PUT,
            "/api/v1/buses/demo/nodes/1/eds",
            Some(r#"{"file":"nothing.eds"}"#),
            "assign eds",
            Some(1),
            None,
            None,
        ),
        case(
            M::DELETE,
            "/api/v1/buses/demo/nodes/1/eds",
            None,
            "unassign eds",
            Some(1),
            None,
            None,
        ),
        case(
            M::PUT,
            "/api/v1/buses/demo/nodes/1/io",
            Some(r#"{"outputs":{"do1":true}}"#),
            "set outputs",
            Some(1),
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/lss/configure",
            Some(r#"{"address":"bad","node_id":5}"#),
            "lss configure",
            None,
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/buses/demo/nodes/1/node-id",
            Some(r#"{"node_id":0}"#),
            "change node-id",
            Some(1),
            None,
            None,
        ),
        case(
            M::POST,
            "/api/v1/nowhere",
            Some("{}"),
            "unknown request",
            None,
            None,
            None,
        ),
        case(
            M::DELETE,
            "/api/v1/buses",
            None,
            "unknown request",
            None,
            None,
            None,
        ),
    ];
    let mut answers = Vec::new();
    for case in &cases {
        let answer = call_text(&app, case.method.clone(), case.path, case.body).await;
        // Reads in between are not audited.
        let _ = get(&app, "/api/v1/buses/demo/nodes/1/od/0x1017/0").await;
        let (status, _) = call_text(
            &app,
            Method::POST,
            "/api/v1/buses/demo/nodes/1/od/read",
            Some(r#"{"entries":[["0x1017",0]]}"#),
        )
        .await;
        assert_eq!(status, StatusCode::OK);
        answers.push(answer);
    }
    // The three refusals the issue names, as answered.
    assert_error(&answers[1], StatusCode::BAD_REQUEST, "value_out_of_range");
    assert_error(&answers[2], StatusCode::UNPROCESSABLE_ENTITY, "sdo_abort");
    assert_eq!(answers[2].1["error"]["abort_code"], "0x06020000");
    assert_eq!(answers[0].0, StatusCode::OK, "{}", answers[0].1);

    let (status, audit) = get(&app, "/api/v1/events?kind=audit&limit=1000").await;
    assert_eq!(status, StatusCode::OK, "{audit}");
    let audit = audit.as_array().unwrap();
    assert_eq!(audit.len(), cases.len(), "{audit:#?}");
    for ((case, (status, body)), entry) in cases.iter().zip(&answers).zip(audit) {
        let what = format!("{} {}: {entry}", case.method, case.path);
        assert_eq!(entry["kind"], "audit", "{what}");
        assert_eq!(entry["method"], case.method.as_str(), "{what}");
        assert_eq!(entry["path"], case.path, "{what}");
        assert_eq!(entry["operation"], case.operation, "{what}");
        assert_eq!(entry["who"], "anonymous", "{what}");
        assert_eq!(entry["role"], "none", "{what}");
        let bus = case
            .path
            .split('/')
            .nth(4)
            .filter(|_| case.path.contains("/buses/"));
        assert_eq!(entry["bus"].as_str(), bus, "{what}");
        assert_eq!(entry["node"].as_u64(), case.node.map(u64::from), "{what}");
        assert_eq!(entry["axis"].as_u64(), case.axis.map(u64::from), "{what}");
        assert_eq!(entry["item"].as_str(), case.item, "{what}");
        assert_eq!(entry["status"], status.as_u16(), "{what}");
        assert_eq!(entry["channel"], "rest", "{what}");
        let outcome = if status.is_success() {
            json!("ok")
        } else {
            body["error"]["code"].clone()
        };
        assert_eq!(entry["outcome"], outcome, "{what}");
        assert_eq!(entry["error_code"], body["error"]["code"], "{what}");
        assert_eq!(entry["abort_code"], body["error"]["abort_code"], "{what}");
        match case.body {
            Some(text) if text.starts_with('{') => {
                let sent: Json = serde_json::from_str(text).unwrap();
                let kept: Json = serde_json::from_str(entry["request"].as_str().unwrap()).unwrap();
                assert_eq!(kept, sent, "{what}");
            }
            Some(text) => assert_eq!(
                entry["request"],
                format!("{} bytes, not JSON (application/json)", text.len()),
                "{what}"
            ),
            None => assert!(entry.get("request").is_none(), "{what}"),
        }
    }
    assert_eq!(audit[2]["abort_code"], "0x06020000");
    assert_eq!(audit[2]["status"], 422);
    assert_eq!(audit[1]["error_code"], "value_out_of_range");
    assert_eq!(audit[0]["error_code"], Json::Null);
}

#[tokio::test(start_paused = true)]
async fn a_body_too_large_is_refused_and_audited() {
    let (app, _) = demo().await;
    let body = format!(
        "{{\"value\":\"{}\"}}",
        "x".repeat(crate::api::auth::DEFAULT_BODY_LIMIT)
    );
    let (status, text, _) = raw_call(
        &app,
        Method::PUT,
        "/api/v1/buses/demo/nodes/1/od/0x1008/0",
        "application/json",
        Some(body),
    )
    .await;
    assert_eq!(status, StatusCode::PAYLOAD_TOO_LARGE, "{text}");
    let (_, audit) = get(&app, "/api/v1/events?kind=audit").await;
    assert_eq!(audit[0]["status"], 413);
    assert_eq!(audit[0]["error_code"], "payload_too_large");
}

#[tokio::test(start_paused = true)]
async fn emcy_and_nmt_events_land_in_the_history() {
    let (app, _) = demo().await;
    // The devices' appearance, from before the API existed.
    let nmt = wait_events(&app, "kind=nmt&limit=1000", |events| {
        (1..=3).all(|node| {
            events
                .iter()
                .any(|event| event["event"] == "appeared" && event["node"] == node)
        })
    })
    .await;
    assert!(
        nmt.iter()
            .all(|event| event["kind"] == "nmt" && event["bus"] == "demo")
    );

    let (status, _) = call_text(
        &app,
        Method::POST,
        // The JMC: it sends heartbeats (1000 ms), so its state is heard.
        "/api/v1/buses/demo/nodes/2/nmt",
        Some(r#"{"command":"start"}"#),
    )
    .await;
    assert!(status.is_success(), "{status}");
    wait_events(&app, "kind=nmt&limit=1000", |events| {
        events.iter().any(|event| {
            event["event"] == "nmt_changed" && event["node"] == 2 && event["to"] == "operational"
        })
    })
    .await;

    let (status, body) = call_text(
        &app,
        Method::POST,
        "/api/v1/buses/demo/sim/nodes/1/faults",
        Some(r#"{"kind":"over_temperature"}"#),
    )
    .await;
    assert!(status.is_success(), "{status} {body}");
    let emcy = wait_events(&app, "kind=emcy", |events| {
        events.iter().any(|event| event["node"] == 1)
    })
    .await;
    let first = &emcy[0];
    assert_eq!(first["bus"], "demo");
    assert!(first["code"].as_str().unwrap().starts_with("0x"), "{first}");
    assert!(!first["text"].as_str().unwrap().is_empty(), "{first}");
    assert!(first["register"].as_u64().unwrap() > 0, "{first}");
    assert_eq!(first["manufacturer"].as_str().unwrap().len(), 10, "{first}");
    // Issue 31: the UMC's EMCY of each axis says which (two rows used to
    // read the same "demo · node 1").
    let emcy = wait_events(&app, "kind=emcy", |events| {
        events.iter().filter(|event| event["node"] == 1).count() >= 2
    })
    .await;
    let axes: std::collections::BTreeSet<u64> = emcy
        .iter()
        .filter(|event| event["node"] == 1)
        .filter_map(|event| event["axis"].as_u64())
        .collect();
    assert_eq!(axes, [1, 2].into(), "{emcy:#?}");

    // Every kind together, oldest first; `since` cuts.
    let (_, all) = get(&app, "/api/v1/events?limit=1000").await;
    let all = all.as_array().unwrap();
    let kinds: std::collections::BTreeSet<&str> = all
        .iter()
        .map(|event| event["kind"].as_str().unwrap())
        .collect();
    assert_eq!(kinds, ["audit", "emcy", "nmt"].into());
    let times: Vec<i64> = all
        .iter()
        .map(|event| event["time_us"].as_i64().unwrap())
        .collect();
    assert!(times.windows(2).all(|pair| pair[0] <= pair[1]), "{times:?}");
    let since = first["time"].as_str().unwrap();
    let (status, later) = get(&app, &format!("/api/v1/events?since={since}&limit=1000")).await;
    assert_eq!(status, StatusCode::OK, "{later}");
    let later = later.as_array().unwrap();
    assert!(
        later
            .iter()
            .all(|event| event["time_us"].as_i64() >= first["time_us"].as_i64())
    );
    assert!(later.contains(first));
    let ms = first["time_us"].as_i64().unwrap() / 1000;
    let (_, by_ms) = get(
        &app,
        &format!("/api/v1/events?kind=emcy&since={ms}&limit=1"),
    )
    .await;
    assert_eq!(by_ms.as_array().unwrap().len(), 1);

    // Paging back: the newest entries up to a time, that time included.
    let last = all.last().unwrap();
    let until = last["time"].as_str().unwrap();
    let (status, older) = get(&app, &format!("/api/v1/events?until={until}&limit=2")).await;
    assert_eq!(status, StatusCode::OK, "{older}");
    let older = older.as_array().unwrap();
    assert_eq!(older.len(), 2);
    assert!(older.contains(last), "{older:?}");
    assert!(
        older
            .iter()
            .all(|event| event["time_us"].as_i64() <= last["time_us"].as_i64())
    );
    let before_first = first["time_us"].as_i64().unwrap() / 1000 - 1;
    let (_, none) = get(
        &app,
        &format!("/api/v1/events?kind=emcy&until={before_first}"),
    )
    .await;
    assert_eq!(none, json!([]));
}

#[tokio::test(start_paused = true)]
async fn bad_queries_are_400() {
    let (app, _) = demo().await;
    for query in [
        "kind=everything",
        "channel=http",
        "channel=REST",
        "since=yesterday",
        "since=2026-11-23",
        "until=tomorrow",
        "limit=0",
        "limit=1001",
        "limit=many",
    ] {
        let answer = get(&app, &format!("/api/v1/events?{query}")).await;
        assert_error(&answer, StatusCode::BAD_REQUEST, "invalid_request");
    }
    let (status, none) = get(&app, "/api/v1/events?kind=audit&since=2999-01-01T00:00:00Z").await;
    assert_eq!((status, none), (StatusCode::OK, json!([])));
}

/// Every audit entry names its channel and outcome; `channel=` keeps to
/// one door's, and an entry without REST's words leaves them out.
#[tokio::test(start_paused = true)]
async fn entries_name_their_channel_and_can_be_filtered_by_it() {
    use crate::gateway::AuditEntry;
    use crate::gateway::Caller;
    let (app, state) = demo().await;
    let (status, _) = call_text(
        &app,
        Method::PUT,
        "/api/v1/buses/demo/sync",
        Some(r#"{"period_ms":0}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    state
        .gateway
        .history()
        .audit(
            AuditEntry::new(&Caller::system(), "prune recording (over quota)").target(
                None,
                None,
                None,
                Some("old.log".into()),
            ),
        )
        .await
        .unwrap();
    let (_, all) = get(&app, "/api/v1/events?kind=audit&limit=1000").await;
    let all = all.as_array().unwrap();
    assert!(
        all.iter()
            .all(|e| e["channel"].is_string() && e["outcome"].is_string()),
        "{all:#?}"
    );
    let (status, system) = get(&app, "/api/v1/events?channel=system&limit=1000").await;
    assert_eq!(status, StatusCode::OK, "{system}");
    let pruned: Vec<&Json> = system
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["item"] == "old.log")
        .collect();
    assert_eq!(pruned.len(), 1, "{system:#}");
    let pruned = pruned[0];
    assert_eq!(pruned["who"], "gateway", "{pruned}");
    assert_eq!(pruned["role"], "system", "{pruned}");
    assert_eq!(pruned["outcome"], "ok", "{pruned}");
    for detail in ["method", "path", "status", "error_code"] {
        assert!(pruned.get(detail).is_none(), "{detail} in {pruned}");
    }
    // Only audit entries of that channel: no EMCY, NMT or REST entry.
    assert!(
        system
            .as_array()
            .unwrap()
            .iter()
            .all(|e| e["kind"] == "audit" && e["channel"] == "system"),
        "{system:#}"
    );
    let (_, rest) = get(&app, "/api/v1/events?channel=rest&limit=1000").await;
    let rest = rest.as_array().unwrap();
    assert!(
        rest.iter().any(|e| e["path"] == "/api/v1/buses/demo/sync"),
        "{rest:#?}"
    );
    assert!(rest.iter().all(|e| e["channel"] == "rest"), "{rest:#?}");
    let (status, none) = get(&app, "/api/v1/events?channel=system&kind=emcy").await;
    assert_eq!((status, none), (StatusCode::OK, json!([])));
}
