//! Issue 29: exactly one audit row per request, whoever writes it: the gateway's
//! operation (a success, a refusal by the device, a refusal by the
//! gateway's policy) or the door, for what no operation audited (REST's
//! 401, 413, a body that is no JSON, a path no route has, a node not known
//! before the operation). Over REST, the row carries the status answered;
//! CiA 309-3 and Sparkplug commands get one row each too.

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Map, Value as Json};

use crate::api::auth::{AuthConfig, RateLimit, Role, Token};
use crate::api::tests::support::{open, send_with_headers};
use crate::api::{AppState, app};
use crate::ascii::Session;
use crate::cia309::reply::Reply;
use crate::cia309::{Cia309Gateway, Identity};
use crate::gateway::Gateway;
use crate::gateway::{Caller, Channel};
use crate::gateway::{EventKind, Query};
use crate::sparkplug::SparkplugConfig;
use crate::sparkplug::command::parse;
use crate::sparkplug::metric::MetricValue;
use crate::sparkplug::motion::HeldLeases;
use crate::sparkplug::node::run_command;
use crate::sparkplug::proto::Payload;
use crate::sparkplug::proto::payload::Metric;
use crate::sparkplug::topic::{MessageType, Topic};

const PLC: (&str, Role, &str) = ("plc", Role::Operator, "plc-0123456789abcdefgh");
const BUSY: (&str, Role, &str) = ("busy", Role::Operator, "busy-0123456789abcdefgh");
const OTHER: (&str, Role, &str) = ("other", Role::Operator, "other-0123456789abcdefg");
const ADMIN: (&str, Role, &str) = ("admin", Role::Admin, "admin-0123456789abcdefg");

async fn rig() -> (Router, Gateway) {
    let served = open("demo", "virtual:demo").await;
    assert_eq!(served.scan().await.unwrap().len(), 3);
    let tokens = [PLC, BUSY, OTHER, ADMIN]
        .into_iter()
        .map(|(name, role, secret)| Token::new(name, role, secret).unwrap())
        .collect();
    let config = AuthConfig::new(
        tokens,
        Vec::new(),
        // Never refills within a test: a spent bucket stays spent.
        Some(RateLimit {
            per_second: 0.0001,
            burst: 1000,
        }),
        crate::api::auth::DEFAULT_BODY_LIMIT,
        crate::api::auth::DEFAULT_BODY_LIMIT,
    )
    .unwrap();
    let state = AppState::new([served])
        .with_lease_period(crate::gateway::MAX_PERIOD)
        .with_auth(config);
    (app(state.clone()), state.gateway.clone())
}

/// Every audit row of `gateway`, in the order they were written (the
/// door tests' one reading of the log).
pub(crate) async fn rows(gateway: &Gateway) -> Vec<Map<String, Json>> {
    let mut events = gateway
        .history()
        .query(Query {
            kind: Some(EventKind::Audit),
            since_us: None,
            until_us: None,
            channel: None,
            limit: 10_000,
        })
        .await
        .unwrap();
    events.sort_by_key(|event| event.id);
    events.into_iter().map(|event| event.fields).collect()
}

/// One kind of REST request and the row it must leave.
struct Case {
    what: &'static str,
    method: Method,
    path: &'static str,
    token: Option<&'static str>,
    body: Option<String>,
    status: u16,
    outcome: &'static str,
}

fn case(
    what: &'static str,
    method: Method,
    path: &'static str,
    token: Option<&'static str>,
    body: Option<&str>,
    status: u16,
    outcome: &'static str,
) -> Case {
    Case {
        what,
        method,
        path,
        token,
        body: body.map(str::to_string),
        status,
        outcome,
    }
}

#[tokio::test(start_paused = true)]
async fn every_rest_request_leaves_exactly_one_row() {
    let (app, gateway) = rig().await;
    let od = "/api/v1/buses/demo/nodes/1/od/0x1017/0";
    let busy = Caller::new(Channel::Rest, BUSY.0, Some(Role::Operator));
    while gateway.take_write(&busy).is_ok() {}
    let too_large = format!(
        "{{\"value\":\"{}\"}}",
        "x".repeat(crate::api::auth::DEFAULT_BODY_LIMIT)
    );
    use Method as M;
    let velocity = r#"{"mode":"velocity","velocity":100}"#;
    let cases = [
        case(
            "an operation that succeeds",
            M::PUT,
            od,
            Some(PLC.2),
            Some(r#"{"value":1000}"#),
            200,
            "ok",
        ),
        case(
            "an operation the device refuses",
            M::PUT,
            "/api/v1/buses/demo/nodes/1/od/0x1a00/0",
            Some(PLC.2),
            Some(r#"{"value":0}"#),
            422,
            "sdo_abort",
        ),
        case(
            "an operation the gateway's write rate refuses",
            M::PUT,
            od,
            Some(BUSY.2),
            Some(r#"{"value":1000}"#),
            429,
            "rate_limited",
        ),
        case(
            "a state change",
            M::POST,
            "/api/v1/buses/demo/nodes/1/axes/1/state",
            Some(PLC.2),
            Some(r#"{"target":"operation_enabled"}"#),
            200,
            "ok",
        ),
        case(
            "a move that takes a lease",
            M::POST,
            "/api/v1/buses/demo/nodes/1/axes/1/move",
            Some(PLC.2),
            Some(velocity),
            200,
            "ok",
        ),
        case(
            "a move the gateway's lease refuses",
            M::POST,
            "/api/v1/buses/demo/nodes/1/axes/1/move",
            Some(OTHER.2),
            Some(velocity),
            409,
            "lease_conflict",
        ),
        case(
            "a halt",
            M::POST,
            "/api/v1/buses/demo/nodes/1/axes/1/halt",
            Some(PLC.2),
            Some(r#"{"halt":true}"#),
            200,
            "ok",
        ),
        case(
            "no token (the guard's 401)",
            M::PUT,
            od,
            None,
            Some(r#"{"value":1000}"#),
            401,
            "unauthenticated",
        ),
        case(
            "a body too large (413)",
            M::PUT,
            od,
            Some(PLC.2),
            Some(&too_large),
            413,
            "payload_too_large",
        ),
        case(
            "a body that is no JSON",
            M::PUT,
            od,
            Some(PLC.2),
            Some("{"),
            400,
            "invalid_request",
        ),
        case(
            "a role the guard refuses (403)",
            M::POST,
            "/api/v1/nowhere",
            Some(PLC.2),
            None,
            403,
            "forbidden",
        ),
        case(
            "a path no route has",
            M::POST,
            "/api/v1/nowhere",
            Some(ADMIN.2),
            None,
            404,
            "not_found",
        ),
        case(
            "a node not known, before the operation",
            M::PUT,
            "/api/v1/buses/demo/nodes/99/od/0x1017/0",
            Some(PLC.2),
            Some(r#"{"value":1000}"#),
            404,
            "unknown_node",
        ),
    ];
    let mut failures = Vec::new();
    for case in cases {
        let before = rows(&gateway).await.len();
        let bearer = case.token.map(|token| format!("Bearer {token}"));
        let headers: Vec<(&str, &str)> = bearer
            .as_deref()
            .map(|bearer| ("authorization", bearer))
            .into_iter()
            .collect();
        let (status, _, body) = send_with_headers(
            &app,
            case.method.clone(),
            case.path,
            &headers,
            case.body.as_deref(),
        )
        .await;
        let new = rows(&gateway).await.split_off(before);
        if status.as_u16() != case.status {
            failures.push(format!(
                "{}: answered {status}, not {}: {body}",
                case.what, case.status
            ));
        }
        if new.len() != 1 {
            failures.push(format!(
                "{}: {} rows, not 1: {new:#?}",
                case.what,
                new.len()
            ));
            continue;
        }
        let row = &new[0];
        if row["channel"] != "rest"
            || row["outcome"] != case.outcome
            || row["status"] != status.as_u16()
        {
            failures.push(format!(
                "{}: row {row:?}, not rest/{}/{status}",
                case.what, case.outcome
            ));
        }
        if row["method"] != case.method.as_str() || row["path"] != case.path {
            failures.push(format!("{}: row {row:?} lost REST's words", case.what));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A take-over names the lease it ended in the operation's row.
#[tokio::test(start_paused = true)]
async fn a_take_over_is_named_in_the_moves_row() {
    let (app, gateway) = rig().await;
    let send = |token: &'static str, path: &'static str, body: &'static str, takeover: bool| {
        let app = app.clone();
        async move {
            let bearer = format!("Bearer {token}");
            let mut headers = vec![("authorization", bearer.as_str())];
            if takeover {
                headers.push(("candeck-lease-takeover", "true"));
            }
            send_with_headers(&app, Method::POST, path, &headers, Some(body))
                .await
                .0
        }
    };
    let state = "/api/v1/buses/demo/nodes/1/axes/1/state";
    let moving = "/api/v1/buses/demo/nodes/1/axes/1/move";
    let velocity = r#"{"mode":"velocity","velocity":100}"#;
    assert_eq!(
        send(PLC.2, state, r#"{"target":"operation_enabled"}"#, false).await,
        StatusCode::OK
    );
    assert_eq!(send(PLC.2, moving, velocity, false).await, StatusCode::OK);
    let before = rows(&gateway).await.len();
    assert_eq!(send(OTHER.2, moving, velocity, true).await, StatusCode::OK);
    let new = rows(&gateway).await.split_off(before);
    assert_eq!(new.len(), 1, "{new:#?}");
    let operation = new[0]["operation"].as_str().unwrap();
    assert!(
        operation.starts_with("move; took over the velocity lease ")
            && operation.ends_with(" of plc"),
        "{operation}"
    );
    assert_eq!(new[0]["who"], "other");
    assert_eq!(new[0]["status"], 200);
}

#[tokio::test(start_paused = true)]
async fn every_cia_309_3_command_leaves_exactly_one_row() {
    let (_, gateway) = rig().await;
    let identity = Identity::anonymous("ascii", Some("127.0.0.1:50000".into()));
    let mut session = Session::new(Cia309Gateway::new(&gateway), identity);
    assert_eq!(
        session.handle(&format!("[1] auth {}", PLC.2)).await,
        Reply::Ok(1)
    );
    let lines = [
        ("[2] 1 w 0x1017 0 u16 1000", "write object", "ok"),
        ("[3] 1 w 0x1A00 0 u8 0", "write object", "sdo_abort"),
        ("[4] 99 w 0x1017 0 u16 1000", "write object", "unknown_node"),
        ("[5] 1 start", "nmt command", "ok"),
        ("[6] 0 preop", "nmt command to all nodes", "ok"),
        ("[7] 1 w 0x1017", "SDO write (refused)", "invalid_request"),
    ];
    for (line, operation, outcome) in lines {
        let before = rows(&gateway).await.len();
        session.handle(line).await;
        let new = rows(&gateway).await.split_off(before);
        assert_eq!(new.len(), 1, "{line}: {new:#?}");
        assert_eq!(new[0]["channel"], "cia309_3", "{line}");
        assert_eq!(new[0]["operation"], operation, "{line}");
        assert_eq!(new[0]["outcome"], outcome, "{line}");
        assert_eq!(new[0]["method"], "ASCII", "{line}");
    }
}

/// The rows a command must leave: (operation, outcome), in order.
type Rows = &'static [(&'static str, &'static str)];

fn metric(name: &str, value: MetricValue) -> Metric {
    let mut metric = Metric {
        name: Some(name.into()),
        ..Metric::default()
    };
    value.fill(&mut metric);
    metric
}

#[tokio::test(start_paused = true)]
async fn every_sparkplug_command_leaves_exactly_one_row() {
    let (_, gateway) = rig().await;
    let broker = "mqtt://127.0.0.1:1883".parse().unwrap();
    let mut config = SparkplugConfig::new(broker, "plant", "line1");
    config.username = Some("scada".into());
    config.role = Role::Operator;
    let held = HeldLeases::default();
    let topic = Topic::device("plant", MessageType::DCmd, "line1", "demo-1");
    let lease = "scada-host-axis1-0001";
    let commands: Vec<(Vec<Metric>, Rows)> = vec![
        (
            vec![metric("OD/0x1017:0", MetricValue::UInt16(1000))],
            &[("write object", "ok")],
        ),
        (
            vec![metric("OD/0x1A00:0", MetricValue::UInt8(0))],
            &[("write object", "sdo_abort")],
        ),
        (
            vec![metric("NMT", MetricValue::String("start".into()))],
            &[("nmt command", "ok")],
        ),
        (
            vec![metric(
                "Axis 1/State",
                MetricValue::String("operation_enabled".into()),
            )],
            &[("drive state change", "ok")],
        ),
        (
            vec![
                metric(
                    "Axis 1/Move",
                    MetricValue::String(r#"{"mode":"velocity","velocity":100}"#.into()),
                ),
                metric("Axis 1/Lease", MetricValue::Boolean(true)),
                metric("Axis 1/Lease Id", MetricValue::String(lease.into())),
            ],
            &[("move", "ok")],
        ),
        // The first renewal is audited; the next, within a minute, not.
        (
            vec![
                metric("Axis 1/Lease", MetricValue::Boolean(true)),
                metric("Axis 1/Lease Id", MetricValue::String(lease.into())),
            ],
            &[("renew motion lease", "ok")],
        ),
        (
            vec![
                metric("Axis 1/Lease", MetricValue::Boolean(true)),
                metric("Axis 1/Lease Id", MetricValue::String(lease.into())),
            ],
            &[],
        ),
        (
            vec![metric(
                "Axis 1/Move",
                MetricValue::String(r#"{"mode":"velocity","velocity":-300}"#.into()),
            )],
            &[("move", "lease_conflict")],
        ),
        (
            vec![metric("Axis 1/Halt", MetricValue::Boolean(true))],
            &[("halt", "ok")],
        ),
        (
            vec![metric("Nonsense", MetricValue::Boolean(true))],
            &[("unsupported command", "invalid_request")],
        ),
    ];
    for (metrics, want) in commands {
        let payload = Payload {
            metrics,
            ..Payload::default()
        };
        let before = rows(&gateway).await.len();
        for command in parse(&payload, true) {
            let _ = run_command(&gateway, &config, &held, &topic, &command).await;
        }
        let new = rows(&gateway).await.split_off(before);
        let got: Vec<(String, String)> = new
            .iter()
            .map(|row| {
                assert_eq!(row["channel"], "sparkplug");
                assert_eq!(row["method"], "DCMD");
                (
                    row["operation"].as_str().unwrap().to_string(),
                    row["outcome"].as_str().unwrap().to_string(),
                )
            })
            .collect();
        let want: Vec<(String, String)> = want
            .iter()
            .map(|(operation, outcome)| (operation.to_string(), outcome.to_string()))
            .collect();
        assert_eq!(got, want, "{payload:?}");
    }
}
