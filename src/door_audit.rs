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
use crate::gateway::MachineSettings;
use crate::gateway::{Caller, Channel};
use crate::gateway::{DoorDetail, DoorRequest};
use crate::gateway::{EventKind, Query};
use crate::gateway::{Gateway, ServedBus};
use crate::sparkplug::SparkplugConfig;
use crate::sparkplug::command::parse;
use crate::sparkplug::command::summary;
use crate::sparkplug::metric::MetricValue;
use crate::sparkplug::motion::HeldLeases;
use crate::sparkplug::node::run_message;
use crate::sparkplug::proto::Payload;
use crate::sparkplug::proto::payload::Metric;
use crate::sparkplug::topic::{MessageType, Topic};

const PLC: (&str, Role, &str) = ("plc", Role::Operator, "plc-0123456789abcdefgh");
const BUSY: (&str, Role, &str) = ("busy", Role::Operator, "busy-0123456789abcdefgh");
const OTHER: (&str, Role, &str) = ("other", Role::Operator, "other-0123456789abcdefg");
const ADMIN: (&str, Role, &str) = ("admin", Role::Admin, "admin-0123456789abcdefg");
const BUSY_ADMIN: (&str, Role, &str) = ("busy-admin", Role::Admin, "busy-admin-0123456789ab");

async fn rig() -> (Router, Gateway) {
    rig_with_burst(1000).await
}

/// The demo bus behind REST, each token `burst` writes (never refilled
/// within a test: a spent bucket stays spent).
async fn rig_with_burst(burst: u32) -> (Router, Gateway) {
    let served = open("demo", "virtual:demo").await;
    assert_eq!(served.scan().await.unwrap().len(), 3);
    rig_on(served, burst)
}

/// The router over `served`, with the tokens above, each `burst` writes
/// (never refilled within a test: a spent bucket stays spent).
fn rig_on(served: ServedBus, burst: u32) -> (Router, Gateway) {
    let tokens = [PLC, BUSY, OTHER, ADMIN, BUSY_ADMIN]
        .into_iter()
        .map(|(name, role, secret)| Token::new(name, role, secret).unwrap())
        .collect();
    let config = AuthConfig::new(
        tokens,
        Vec::new(),
        Some(RateLimit {
            per_second: 0.0001,
            burst,
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
    /// The operation's words the row must have; `None`: not checked.
    operation: Option<&'static str>,
    /// The row's words, where the case checks them: operation, bus, node,
    /// item.
    words: Option<Words>,
}

type Words = (
    &'static str,
    Option<&'static str>,
    Option<u8>,
    Option<&'static str>,
);

impl Case {
    fn operation(mut self, words: &'static str) -> Self {
        self.operation = Some(words);
        self
    }

    fn words(
        mut self,
        operation: &'static str,
        bus: Option<&'static str>,
        node: Option<u8>,
        item: Option<&'static str>,
    ) -> Self {
        self.words = Some((operation, bus, node, item));
        self
    }
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
        operation: None,
        words: None,
    }
}

/// A file the catalog takes.
const GOOD_EDS: &str = "[DeviceInfo]\nVendorNumber=0x77\nProductNumber=0x10\nRevisionNumber=1\n\
[MandatoryObjects]\nSupportedObjects=1\n1=0x1000\n\
[1000]\nParameterName=Device type\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x00020192\n";

/// A logger of node 1's position.
const POSITION_LOGGER: &str =
    r#"{"channels":[{"bus":"demo","node":1,"index":"0x6064"}],"period_ms":100,"duration_s":60}"#;

/// The EDS catalog, data loggers and virtual devices: their successes,
/// the operations' refusals and the guard's, each with its row's words.
fn catalog_cases() -> Vec<Case> {
    use Method as M;
    let sim = Some("demo");
    let upload = "/api/v1/eds?name=good.eds";
    let assign = "/api/v1/buses/demo/nodes/2/eds";
    let good_file = Some(r#"{"file":"good.eds"}"#);
    let led = Some(r#"{"product":"uio1led","id":10}"#);
    let fault = "/api/v1/buses/demo/sim/nodes/1/faults";
    let hot = Some(r#"{"kind":"over_temperature"}"#);
    let controller = "/api/v1/buses/demo/sim/faults";
    let bit_errors = Some(r#"{"kind":"bit_errors"}"#);
    let good = Some("good.eds");
    vec![
        case(
            "an eds upload",
            M::POST,
            upload,
            Some(ADMIN.2),
            Some(GOOD_EDS),
            201,
            "ok",
        )
        .words("upload eds", None, None, good),
        case(
            "an eds upload by an operator (the guard's 403)",
            M::POST,
            upload,
            Some(PLC.2),
            Some(GOOD_EDS),
            403,
            "forbidden",
        )
        .words("upload eds", None, None, good),
        case(
            "an upload that is no eds",
            M::POST,
            "/api/v1/eds?name=notes.eds",
            Some(ADMIN.2),
            Some("just notes"),
            400,
            "invalid_eds",
        )
        .words("upload eds", None, None, Some("notes.eds")),
        case(
            "an eds upload over the rate",
            M::POST,
            upload,
            Some(BUSY_ADMIN.2),
            Some(GOOD_EDS),
            429,
            "rate_limited",
        )
        .words("upload eds", None, None, good),
        case(
            "an eds assigned",
            M::PUT,
            assign,
            Some(PLC.2),
            good_file,
            200,
            "ok",
        )
        .words("assign eds", sim, Some(2), None),
        case(
            "an assigned eds deleted",
            M::DELETE,
            "/api/v1/eds/good.eds",
            Some(ADMIN.2),
            None,
            409,
            "eds_conflict",
        )
        .words("delete eds", None, None, good),
        case(
            "an eds unassigned",
            M::DELETE,
            assign,
            Some(PLC.2),
            None,
            200,
            "ok",
        )
        .words("unassign eds", sim, Some(2), None),
        case(
            "an eds deleted",
            M::DELETE,
            "/api/v1/eds/good.eds",
            Some(ADMIN.2),
            None,
            204,
            "ok",
        )
        .words("delete eds", None, None, good),
        case(
            "an unknown eds assigned",
            M::PUT,
            assign,
            Some(PLC.2),
            good_file,
            404,
            "unknown_eds",
        )
        .words("assign eds", sim, Some(2), None),
        case(
            "an eds assigned over the rate",
            M::PUT,
            assign,
            Some(BUSY.2),
            good_file,
            429,
            "rate_limited",
        )
        .words("assign eds", sim, Some(2), None),
        case(
            "a logger started",
            M::POST,
            "/api/v1/loggers",
            Some(PLC.2),
            Some(POSITION_LOGGER),
            201,
            "ok",
        )
        .words("start data logger", None, None, None),
        case(
            "a logger of no period",
            M::POST,
            "/api/v1/loggers",
            Some(PLC.2),
            Some(&POSITION_LOGGER.replace("100", "0")),
            400,
            "value_out_of_range",
        )
        .words("start data logger", None, None, None),
        case(
            "a logger started over the rate",
            M::POST,
            "/api/v1/loggers",
            Some(BUSY.2),
            Some(POSITION_LOGGER),
            429,
            "rate_limited",
        )
        .words("start data logger", None, None, None),
        case(
            "a logger deleted",
            M::DELETE,
            "/api/v1/loggers/1",
            Some(PLC.2),
            None,
            200,
            "ok",
        )
        .words("delete data logger", None, None, Some("1")),
        case(
            "an unknown logger deleted",
            M::DELETE,
            "/api/v1/loggers/1",
            Some(PLC.2),
            None,
            404,
            "unknown_logger",
        )
        .words("delete data logger", None, None, Some("1")),
        case(
            "a virtual device added",
            M::POST,
            "/api/v1/buses/demo/sim/nodes",
            Some(ADMIN.2),
            led,
            201,
            "ok",
        )
        .words("add virtual device", sim, None, None),
        case(
            "a virtual device added at a taken id",
            M::POST,
            "/api/v1/buses/demo/sim/nodes",
            Some(ADMIN.2),
            led,
            409,
            "node_taken",
        )
        .words("add virtual device", sim, None, None),
        case(
            "a virtual device added by an operator (the guard's 403)",
            M::POST,
            "/api/v1/buses/demo/sim/nodes",
            Some(PLC.2),
            led,
            403,
            "forbidden",
        )
        .words("add virtual device", sim, None, None),
        case(
            "a virtual device added over the rate",
            M::POST,
            "/api/v1/buses/demo/sim/nodes",
            Some(BUSY_ADMIN.2),
            led,
            429,
            "rate_limited",
        )
        .words("add virtual device", sim, None, None),
        case(
            "a device's fault injected",
            M::POST,
            fault,
            Some(ADMIN.2),
            hot,
            204,
            "ok",
        )
        .words("inject fault", sim, Some(1), None),
        case(
            "a device's fault cleared",
            M::DELETE,
            fault,
            Some(ADMIN.2),
            hot,
            204,
            "ok",
        )
        .words("clear fault", sim, Some(1), None),
        case(
            "a virtual device removed",
            M::DELETE,
            "/api/v1/buses/demo/sim/nodes/10",
            Some(ADMIN.2),
            None,
            204,
            "ok",
        )
        .words("remove virtual device", sim, Some(10), None),
        case(
            "an unknown virtual device removed",
            M::DELETE,
            "/api/v1/buses/demo/sim/nodes/10",
            Some(ADMIN.2),
            None,
            404,
            "unknown_node",
        )
        .words("remove virtual device", sim, Some(10), None),
        // Rows only the operation writes these words in: REST's own table
        // has none for the gateway's controller.
        case(
            "the gateway's controller fault injected",
            M::POST,
            controller,
            Some(ADMIN.2),
            bit_errors,
            204,
            "ok",
        )
        .words("inject fault", sim, None, None),
        case(
            "the gateway's controller fault cleared",
            M::DELETE,
            controller,
            Some(ADMIN.2),
            bit_errors,
            204,
            "ok",
        )
        .words("clear fault", sim, None, None),
    ]
}

#[tokio::test(start_paused = true)]
async fn every_rest_request_leaves_exactly_one_row() {
    let (app, gateway) = rig().await;
    let od = "/api/v1/buses/demo/nodes/1/od/0x1017/0";
    for (name, role, _) in [BUSY, BUSY_ADMIN] {
        let busy = Caller::new(Channel::Rest, name, Some(role));
        while gateway.take_write(&busy).is_ok() {}
    }
    let too_large = format!(
        "{{\"value\":\"{}\"}}",
        "x".repeat(crate::api::auth::DEFAULT_BODY_LIMIT)
    );
    use Method as M;
    let velocity = r#"{"mode":"velocity","velocity":100}"#;
    let mut cases = vec![
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
    cases.extend(catalog_cases());
    assert_one_row_each(&app, &gateway, cases).await;
}

/// Sends each case and checks it left exactly one row, REST's words and
/// the status answered in it (and the case's operation, when it names
/// one).
async fn assert_one_row_each(
    app: &Router,
    gateway: &Gateway,
    cases: impl IntoIterator<Item = Case>,
) {
    let mut failures = Vec::new();
    for case in cases {
        let before = rows(gateway).await.len();
        let bearer = case.token.map(|token| format!("Bearer {token}"));
        let headers: Vec<(&str, &str)> = bearer
            .as_deref()
            .map(|bearer| ("authorization", bearer))
            .into_iter()
            .collect();
        let (status, _, body) = send_with_headers(
            app,
            case.method.clone(),
            case.path,
            &headers,
            case.body.as_deref(),
        )
        .await;
        let new = rows(gateway).await.split_off(before);
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
        let path = case.path.split('?').next().unwrap_or_default();
        if row["method"] != case.method.as_str() || row["path"] != path {
            failures.push(format!("{}: row {row:?} lost REST's words", case.what));
        }
        if let Some(words) = case.operation
            && row["operation"] != words
        {
            failures.push(format!("{}: row {row:?}, not {words}", case.what));
        }
        if let Some((operation, bus, node, item)) = case.words {
            let words = (
                row["operation"].as_str(),
                row.get("bus").and_then(Json::as_str),
                row.get("node").and_then(Json::as_u64),
                row.get("item").and_then(Json::as_str),
            );
            if words != (Some(operation), bus, node.map(u64::from), item) {
                failures.push(format!(
                    "{}: row {row:?}, not {operation}/{bus:?}/{node:?}/{item:?}",
                    case.what
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The bus operations, LSS, the node-ID change and the I/O outputs over
/// REST: each request leaves one row, written by the gateway's operation
/// (its words, whatever the outcome) or, for what the guard or the body
/// refused first, by the door.
#[tokio::test(start_paused = true)]
async fn every_bus_operation_over_rest_leaves_exactly_one_row() {
    // A UMC at 1 (0x2040), an I/O module at 4, a UIO1LED waiting for LSS;
    // the network manager boots them.
    let served = open("line", "virtual:umc1bds32@1,io401@4,uio1led@lss")
        .await
        .with_machine(MachineSettings::default(), None);
    assert_eq!(served.scan().await.unwrap().len(), 2);
    served.machine().unwrap().scan_done();
    tokio::time::sleep(std::time::Duration::from_secs(5)).await;
    let (app, gateway) = rig_on(served, 1000);
    let busy = Caller::new(Channel::Rest, BUSY.0, Some(Role::Operator));
    while gateway.take_write(&busy).is_ok() {}
    let led = r#"{"vendor_id":1186,"product_code":16641,"revision":1,"serial":257,"node_id":10}"#;
    use Method as M;
    let cases = [
        case(
            "a scan",
            M::POST,
            "/api/v1/buses/line/scan",
            Some(PLC.2),
            None,
            200,
            "ok",
        )
        .operation("scan"),
        case(
            "a SYNC period",
            M::PUT,
            "/api/v1/buses/line/sync",
            Some(PLC.2),
            Some(r#"{"period_ms":10}"#),
            200,
            "ok",
        )
        .operation("set sync period"),
        case(
            "a raw frame",
            M::POST,
            "/api/v1/buses/line/frames",
            Some(PLC.2),
            Some(r#"{"id":"0x123","data":"0102"}"#),
            200,
            "ok",
        )
        .operation("send frame"),
        case(
            "a recording started",
            M::POST,
            "/api/v1/buses/line/recording",
            Some(ADMIN.2),
            None,
            201,
            "ok",
        )
        .operation("start recording"),
        case(
            "a recording stopped",
            M::DELETE,
            "/api/v1/buses/line/recording",
            Some(ADMIN.2),
            None,
            200,
            "ok",
        )
        .operation("stop recording"),
        case(
            "an LSS scan",
            M::POST,
            "/api/v1/buses/line/lss/scan",
            Some(ADMIN.2),
            Some("{}"),
            200,
            "ok",
        )
        .operation("lss scan"),
        case(
            "an LSS configuration",
            M::POST,
            "/api/v1/buses/line/lss/configure",
            Some(ADMIN.2),
            Some(led),
            200,
            "ok",
        )
        .operation("lss configure"),
        case(
            "a node-ID change",
            M::POST,
            "/api/v1/buses/line/nodes/1/node-id",
            Some(PLC.2),
            Some(r#"{"node_id":9}"#),
            200,
            "ok",
        )
        .operation("change node-id"),
        case(
            "a boot-up again",
            M::POST,
            "/api/v1/buses/line/machine/nodes/4/boot",
            Some(PLC.2),
            None,
            200,
            "ok",
        )
        .operation("boot node again"),
        case(
            "outputs set",
            M::PUT,
            "/api/v1/buses/line/nodes/4/io",
            Some(PLC.2),
            Some(r#"{"outputs":{"do1":true}}"#),
            200,
            "ok",
        )
        .operation("set outputs"),
        // Refused by the operation: its own row, its own words.
        case(
            "a SYNC period beyond 0x1006",
            M::PUT,
            "/api/v1/buses/line/sync",
            Some(PLC.2),
            Some(r#"{"period_ms":4294968}"#),
            400,
            "value_out_of_range",
        )
        .operation("set sync period"),
        case(
            "a recording stopped twice",
            M::DELETE,
            "/api/v1/buses/line/recording",
            Some(ADMIN.2),
            None,
            409,
            "recording_not_running",
        )
        .operation("stop recording"),
        case(
            "a scan of a bus not known",
            M::POST,
            "/api/v1/buses/nowhere/scan",
            Some(PLC.2),
            None,
            404,
            "unknown_bus",
        )
        .operation("scan"),
        case(
            "a node-ID change of a node not known",
            M::POST,
            "/api/v1/buses/line/nodes/1/node-id",
            Some(PLC.2),
            Some(r#"{"node_id":9}"#),
            404,
            "unknown_node",
        )
        .operation("change node-id"),
        case(
            "outputs over the caller's write rate",
            M::PUT,
            "/api/v1/buses/line/nodes/4/io",
            Some(BUSY.2),
            Some(r#"{"outputs":{"do1":false}}"#),
            429,
            "rate_limited",
        )
        .operation("set outputs"),
        case(
            "a frame over the caller's write rate",
            M::POST,
            "/api/v1/buses/line/frames",
            Some(BUSY.2),
            Some(r#"{"id":"0x123"}"#),
            429,
            "rate_limited",
        )
        .operation("send frame"),
        // Refused by the door before any operation: the door's row.
        case(
            "LSS for an operator (the guard's 403)",
            M::POST,
            "/api/v1/buses/line/lss/scan",
            Some(PLC.2),
            Some("{}"),
            403,
            "forbidden",
        ),
        case(
            "a frame that is no JSON",
            M::POST,
            "/api/v1/buses/line/frames",
            Some(PLC.2),
            Some("{"),
            400,
            "invalid_request",
        )
        .operation("send frame"),
        case(
            "a boot-up without a token (the guard's 401)",
            M::POST,
            "/api/v1/buses/line/machine/nodes/4/boot",
            None,
            None,
            401,
            "unauthenticated",
        )
        .operation("boot node again"),
    ];
    assert_one_row_each(&app, &gateway, cases).await;
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
        let commands = parse(&payload, true);
        let summary = summary(&payload.metrics);
        let _ = run_message(&gateway, &config, &held, &topic, &commands, summary).await;
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

/// Issue 33, point 6: a command message is one row, however many metrics
/// it carries (each still its own operation, with its role, lease and
/// write): its operations named, its metrics summarised (bounded, with
/// their count), the first failure its outcome.
#[tokio::test(start_paused = true)]
async fn a_command_message_of_many_metrics_is_one_row() {
    let (_, gateway) = rig_with_burst(100).await;
    let broker = "mqtt://127.0.0.1:1883".parse().unwrap();
    let mut config = SparkplugConfig::new(broker, "plant", "line1");
    config.username = Some("scada".into());
    config.role = Role::Operator;
    let held = HeldLeases::default();
    let topic = Topic::device("plant", MessageType::DCmd, "line1", "demo-1");
    let run = |metrics: Vec<Metric>| {
        let (gateway, config, held, topic) = (&gateway, &config, &held, &topic);
        async move {
            let payload = Payload {
                metrics,
                ..Payload::default()
            };
            let commands = parse(&payload, true);
            let before = rows(gateway).await.len();
            let results = run_message(
                gateway,
                config,
                held,
                topic,
                &commands,
                summary(&payload.metrics),
            )
            .await;
            (results, rows(gateway).await.split_off(before))
        }
    };
    let (results, new) = run(vec![
        metric("OD/0x1017:0", MetricValue::UInt16(1000)),
        metric("NMT", MetricValue::String("start".into())),
        metric("Nonsense", MetricValue::Boolean(true)),
    ])
    .await;
    assert_eq!(results.len(), 3);
    assert!(results[0].is_ok() && results[1].is_ok(), "{results:?}");
    assert_eq!(new.len(), 1, "{new:#?}");
    let row = &new[0];
    assert_eq!(row["channel"], "sparkplug");
    assert_eq!(row["method"], "DCMD");
    assert_eq!(row["path"], "spBv1.0/plant/DCMD/line1/demo-1");
    assert_eq!(row["bus"], "demo");
    assert_eq!(row["node"], 1);
    assert_eq!(
        row["operation"],
        "write object, nmt command, unsupported command"
    );
    assert_eq!(row["outcome"], "invalid_request");
    assert_eq!(
        row["request"],
        "3 metrics: OD/0x1017:0=1000; NMT=\"start\"; Nonsense=true (1 of 3 failed)"
    );

    // 64 writes: one row, its summary bounded, every metric counted.
    let writes: Vec<Metric> = (0..64)
        .map(|_| metric("OD/0x1017:0", MetricValue::UInt16(1000)))
        .collect();
    let (results, new) = run(writes).await;
    assert!(results.iter().all(Result::is_ok), "{results:?}");
    assert_eq!(new.len(), 1, "{new:#?}");
    assert_eq!(new[0]["operation"], "write object");
    assert_eq!(new[0]["item"], "0x1017:0");
    assert_eq!(new[0]["outcome"], "ok");
    let request = new[0]["request"].as_str().unwrap();
    assert!(
        request.starts_with("64 metrics: OD/0x1017:0=1000; "),
        "{request}"
    );
    assert!(request.chars().count() <= 256, "{request}");
    assert!(request.ends_with(" more"), "{request}");
}

/// The catalog's routes take one write of the token's rate, the
/// operation's: the guard takes none of its own (a second would refuse the
/// second request of a bucket of two).
#[tokio::test(start_paused = true)]
async fn each_catalog_request_is_one_write_of_the_tokens_rate() {
    let (app, _) = rig_with_burst(2).await;
    use Method as M;
    let led = r#"{"product":"uio1led","id":10}"#;
    let file = r#"{"file":"umc1bds32.eds"}"#;
    // A token, and three requests it sends: (method, path, body).
    type Sent<'a> = (Method, &'a str, Option<&'a str>);
    let pairs: [(&str, [Sent; 3]); 4] = [
        (
            BUSY_ADMIN.2,
            [
                (M::POST, "/api/v1/eds?name=good.eds", Some(GOOD_EDS)),
                (M::DELETE, "/api/v1/eds/good.eds", None),
                (M::POST, "/api/v1/eds?name=good.eds", Some(GOOD_EDS)),
            ],
        ),
        (
            OTHER.2,
            [
                (M::PUT, "/api/v1/buses/demo/nodes/2/eds", Some(file)),
                (M::DELETE, "/api/v1/buses/demo/nodes/2/eds", None),
                (M::PUT, "/api/v1/buses/demo/nodes/2/eds", Some(file)),
            ],
        ),
        (
            PLC.2,
            [
                (M::POST, "/api/v1/loggers", Some(POSITION_LOGGER)),
                (M::DELETE, "/api/v1/loggers/1", None),
                (M::POST, "/api/v1/loggers", Some(POSITION_LOGGER)),
            ],
        ),
        (
            ADMIN.2,
            [
                (M::POST, "/api/v1/buses/demo/sim/nodes", Some(led)),
                (M::DELETE, "/api/v1/buses/demo/sim/nodes/10", None),
                (M::POST, "/api/v1/buses/demo/sim/nodes", Some(led)),
            ],
        ),
    ];
    for (token, requests) in pairs {
        let bearer = format!("Bearer {token}");
        let headers = [("authorization", bearer.as_str())];
        let mut statuses = Vec::new();
        for (method, path, body) in requests {
            let (status, _, answer) = send_with_headers(&app, method, path, &headers, body).await;
            statuses.push((path, status.as_u16(), answer["error"]["code"].clone()));
        }
        let [first, second, third] = &statuses[..] else {
            unreachable!()
        };
        assert!(first.1 < 300 && second.1 < 300, "{statuses:?}");
        assert_eq!((third.1, third.2.as_str()), (429, Some("rate_limited")));
    }
}

/// A request with REST's words, whose rows are handed to REST as the
/// audit layer asks; whether an operation audited it.
fn rest_request(method: &str, path: &str, who: (&str, Role, &str)) -> (Caller, DoorRequest) {
    let door = DoorRequest::handed_over(DoorDetail::new(method, path));
    let caller = Caller::new(Channel::Rest, who.0, Some(who.1)).with_door(door.clone());
    (caller, door)
}

/// Every catalog operation audits its request itself, refused or not: the
/// audit layer gets its one row back to add the status, and writes none of
/// its own.
#[tokio::test(start_paused = true)]
async fn the_catalog_operations_audit_their_requests_so_rest_writes_no_row_of_its_own() {
    use crate::canopen::NodeId;
    use crate::emulator::devices;
    use crate::sim::behaviour::Fault;
    use crate::sim::products::{DeviceSpec, Product};
    let (_, gateway) = rig().await;
    let node = NodeId::new(2).unwrap();
    let led = NodeId::new(10).unwrap();
    let drive = NodeId::new(1).unwrap();
    let logger = serde_json::from_str(POSITION_LOGGER).unwrap();
    let mut audited = Vec::new();
    macro_rules! check {
        ($what:expr, $who:expr, |$caller:ident| $call:expr) => {{
            let ($caller, door) = rest_request("POST", "/api/v1/...", $who);
            let outcome = $call.await.map(|_| ()).map_err(|error| error.code());
            let rows = door.take_rows();
            audited.push(($what, outcome, door.audited(), rows.len()));
        }};
    }
    check!("upload eds", ADMIN, |c| gateway
        .upload_eds(&c, "good.eds", GOOD_EDS));
    check!("upload eds, refused", PLC, |c| gateway
        .upload_eds(&c, "good.eds", GOOD_EDS));
    check!("assign eds", PLC, |c| gateway.assign_eds(
        &c,
        "demo",
        node,
        Some("good.eds")
    ));
    check!("unassign eds", PLC, |c| gateway
        .assign_eds(&c, "demo", node, None));
    check!("delete eds", ADMIN, |c| gateway.delete_eds(&c, "good.eds"));
    check!("start data logger", PLC, |c| gateway
        .start_logger(&c, logger));
    check!("delete data logger", PLC, |c| gateway
        .delete_logger(&c, "1"));
    check!("add virtual device", ADMIN, |c| devices::add_device(
        &gateway,
        &c,
        "demo",
        DeviceSpec::at(Product::Uio1led, led)
    ));
    check!("inject fault", ADMIN, |c| devices::inject_fault(
        &gateway,
        &c,
        "demo",
        drive,
        Fault::OverTemperature
    ));
    check!("clear fault", ADMIN, |c| devices::clear_fault(
        &gateway,
        &c,
        "demo",
        drive,
        Fault::OverTemperature
    ));
    check!("controller fault", ADMIN, |c| devices::controller_fault(
        &gateway,
        &c,
        "demo",
        crate::can::ControllerFault::Recover
    ));
    check!("remove virtual device", ADMIN, |c| devices::remove_device(
        &gateway, &c, "demo", led
    ));
    let want: Vec<_> = audited
        .iter()
        .map(|(what, ..)| {
            let outcome = if what.ends_with("refused") {
                Err("forbidden")
            } else {
                Ok(())
            };
            (*what, outcome, true, 1)
        })
        .collect();
    assert_eq!(audited, want);
}
