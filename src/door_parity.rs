//! Issue 29: one table of operations run through the four doors — REST
//! (the router), CiA 309-3 (a session's command lines), CiA 309-5 (its
//! HTTP routes) and Sparkplug (the edge node's DCMD handling) — against
//! the demo rack on a paused clock. Every door that offers an operation
//! ends it the same way, and writes one audit entry that agrees with the
//! other doors' on everything but who asked through which door ([`Row`]).

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Map, Value as Json};

use crate::api::auth::{AuthConfig, RateLimit, Role, Token};
use crate::api::tests::support::{self, open, send_with_headers};
use crate::api::{AppState, app};
use crate::ascii::Session;
use crate::cia309::reply::Reply;
use crate::cia309::{Cia309Gateway, Identity};
use crate::gateway::Gateway;
use crate::gateway::{Caller, Channel};
use crate::sparkplug::SparkplugConfig;
use crate::sparkplug::command::parse;
use crate::sparkplug::command::summary;
use crate::sparkplug::metric::MetricValue;
use crate::sparkplug::motion::HeldLeases;
use crate::sparkplug::node::run_message;
use crate::sparkplug::proto::Payload;
use crate::sparkplug::proto::payload::Metric;
use crate::sparkplug::topic::{MessageType, Topic};

/// The tokens: who runs the operations, a viewer, an operator whose
/// bucket is spent, and another operator (a caller without the lease).
const PLC: (&str, Role, &str) = ("plc", Role::Operator, "plc-0123456789abcdefgh");
const HMI: (&str, Role, &str) = ("hmi", Role::Viewer, "hmi-0123456789abcdefgh");
const BUSY: (&str, Role, &str) = ("busy", Role::Operator, "busy-0123456789abcdefgh");
const OTHER: (&str, Role, &str) = ("other", Role::Operator, "other-0123456789abcdefg");

/// The lease id the Sparkplug host chooses.
const HOST_LEASE: &str = "scada-host-axis1-0001";

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Door {
    Rest,
    Cia309_3,
    Cia309_5,
    Sparkplug,
}

impl Door {
    fn channel(self) -> Channel {
        match self {
            Self::Rest => Channel::Rest,
            Self::Cia309_3 => Channel::Cia309_3,
            Self::Cia309_5 => Channel::Cia309_5,
            Self::Sparkplug => Channel::Sparkplug,
        }
    }
}

const DOORS: [Door; 4] = [Door::Rest, Door::Cia309_3, Door::Cia309_5, Door::Sparkplug];

/// One operation of the table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Op {
    /// Node 1's device type (0x1000:0).
    Read,
    /// Node 1's producer heartbeat time (0x1017:0) = 1000.
    Write,
    /// 0x1A00:0 = 0 while TPDO1 is valid: the device aborts (CiA 301
    /// §7.5.2.36, 0x06040043).
    WriteRefusedByDevice,
    /// NMT start of node 1.
    Nmt,
    /// A velocity move of axis 1, which takes a lease.
    MoveUnderLease,
    /// Another move of axis 1 by a caller without the lease.
    MoveWithoutLease,
    /// Halt of axis 1 (needs no lease; ends it).
    Halt,
    /// The write of [`Op::Write`] by a viewer.
    RoleRefused,
    /// The write of [`Op::Write`] by a caller over its write rate.
    WriteLimitRefused,
}

/// The table, in the order each door runs it.
const TABLE: [Op; 9] = [
    Op::Read,
    Op::Write,
    Op::WriteRefusedByDevice,
    Op::Nmt,
    Op::MoveUnderLease,
    Op::MoveWithoutLease,
    Op::Halt,
    Op::RoleRefused,
    Op::WriteLimitRefused,
];

impl Op {
    /// Whether `door` offers the operation: CiA 309 has no motion
    /// commands, Sparkplug no reads (it publishes values).
    fn offered_by(self, door: Door) -> bool {
        match self {
            Op::Read => door != Door::Sparkplug,
            Op::MoveUnderLease | Op::MoveWithoutLease | Op::Halt => {
                matches!(door, Door::Rest | Door::Sparkplug)
            }
            _ => true,
        }
    }

    /// The token it runs as.
    fn token(self) -> (&'static str, Role, &'static str) {
        match self {
            Op::RoleRefused => HMI,
            Op::WriteLimitRefused => BUSY,
            Op::MoveWithoutLease => OTHER,
            _ => PLC,
        }
    }
}

/// How an operation ended, as far as every door can say it (CiA 309-3
/// answers a refused caller with 102 whatever the reason: the audit entry
/// says which).
#[derive(Debug, Clone, PartialEq, Eq)]
enum Outcome {
    Done,
    Value(u64),
    Abort(u32),
    Refused,
}

/// An audit entry as the doors must agree on it: every field but the
/// channel (checked per door) and the door's own detail (REST's method,
/// path and status, CiA 309-3's command line, Sparkplug's topic). The
/// request summary is compared where every door hands the gateway the same
/// typed request (an NMT command, a move, a halt); a write's is each door's
/// own words for its value (REST's JSON body, CiA 309's `u16 1000`,
/// Sparkplug's metric value), as docs/rest-api.md has them.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Row {
    role: String,
    operation: String,
    bus: Option<String>,
    node: Option<i64>,
    axis: Option<i64>,
    item: Option<String>,
    outcome: String,
    abort_code: Option<String>,
    /// `None` where the doors' words for the request differ by design.
    request: Option<String>,
}

fn row(fields: &Map<String, Json>) -> Row {
    let text = |key: &str| fields.get(key).and_then(Json::as_str).map(str::to_string);
    let number = |key: &str| fields.get(key).and_then(Json::as_i64);
    Row {
        role: text("role").unwrap_or_default(),
        operation: text("operation").unwrap_or_default(),
        bus: text("bus"),
        node: number("node"),
        axis: number("axis"),
        item: text("item"),
        outcome: text("outcome").unwrap_or_default(),
        abort_code: text("abort_code"),
        request: text("request"),
    }
}

/// Who a door names for a token (MQTT carries no sender identity: the
/// edge node's own, `mqtt:{username}`).
fn who(door: Door, name: &str) -> String {
    match door {
        Door::Sparkplug => format!("mqtt:{name}"),
        _ => name.to_string(),
    }
}

struct Rig {
    app: Router,
    gateway: Gateway,
    held: HeldLeases,
    /// REST's lease of axis 1, while it holds one.
    rest_lease: Option<String>,
}

async fn rig() -> Rig {
    let served = open("demo", "virtual:demo").await;
    assert_eq!(served.scan().await.unwrap().len(), 3);
    let tokens = [PLC, HMI, BUSY, OTHER]
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
    Rig {
        app: app(state.clone()),
        gateway: state.gateway.clone(),
        held: HeldLeases::default(),
        rest_lease: None,
    }
}

fn sparkplug_config(name: &str, role: Role) -> SparkplugConfig {
    let broker = "mqtt://127.0.0.1:1883".parse().unwrap();
    let mut config = SparkplugConfig::new(broker, "plant", "line1");
    config.username = Some(name.to_string());
    config.role = role;
    config
}

fn metric(name: &str, value: MetricValue) -> Metric {
    let mut metric = Metric {
        name: Some(name.into()),
        ..Metric::default()
    };
    value.fill(&mut metric);
    metric
}

impl Rig {
    /// Spends the write bucket of `name` as `door` draws on it.
    fn spend(&self, door: Door, name: &str) {
        let channel = match door {
            Door::Sparkplug => Channel::Sparkplug,
            _ => Channel::Rest,
        };
        let caller = Caller::new(channel, who(door, name), Some(Role::Operator));
        while self.gateway.take_write(&caller).is_ok() {}
    }

    async fn rest(&self, method: Method, path: &str, token: &str, body: Option<&str>) -> Outcome {
        let bearer = format!("Bearer {token}");
        let headers = [("authorization", bearer.as_str())];
        let (status, _, json) =
            send_with_headers(&self.app, method.clone(), path, &headers, body).await;
        match status {
            // A read answers its value; a write, the value read back.
            StatusCode::OK if method == Method::GET => {
                Outcome::Value(json["value"].as_u64().unwrap())
            }
            StatusCode::OK => Outcome::Done,
            StatusCode::UNPROCESSABLE_ENTITY => {
                let code = json["error"]["abort_code"].as_str().unwrap();
                Outcome::Abort(u32::from_str_radix(&code[2..], 16).unwrap())
            }
            _ => Outcome::Refused,
        }
    }

    async fn ascii(&self, token: &str, line: &str) -> Outcome {
        let identity = Identity::anonymous("ascii", Some("127.0.0.1:50000".into()));
        let mut session = Session::new(Cia309Gateway::new(&self.gateway), identity);
        assert_eq!(
            session.handle(&format!("[1] auth {token}")).await,
            Reply::Ok(1)
        );
        match session.handle(line).await {
            Reply::Ok(_) => Outcome::Done,
            Reply::Value(_, text) => Outcome::Value(text.parse().unwrap()),
            Reply::Abort(_, code) => Outcome::Abort(code.raw()),
            Reply::Error(..) => Outcome::Refused,
            other => panic!("{line}: {other:?}"),
        }
    }

    async fn cia309_5(
        &self,
        method: Method,
        path: &str,
        token: &str,
        body: Option<&str>,
    ) -> Outcome {
        let bearer = format!("Bearer {token}");
        let headers = [("authorization", bearer.as_str())];
        let (status, _, json) = send_with_headers(&self.app, method, path, &headers, body).await;
        if status != StatusCode::OK {
            return Outcome::Refused;
        }
        match json["response"].as_str().unwrap() {
            "OK" => match json["data"].as_str() {
                Some(data) => Outcome::Value(u64::from_str_radix(&data[2..], 16).unwrap()),
                None => Outcome::Done,
            },
            error => match error.strip_prefix("ERROR:0x") {
                Some(code) => Outcome::Abort(u32::from_str_radix(code, 16).unwrap()),
                None => Outcome::Refused,
            },
        }
    }

    async fn dcmd(&self, name: &str, role: Role, metrics: Vec<Metric>) -> Outcome {
        let config = sparkplug_config(name, role);
        let topic = Topic::device("plant", MessageType::DCmd, "line1", "demo-1");
        let payload = Payload {
            metrics,
            ..Payload::default()
        };
        let mut outcome = Outcome::Done;
        let commands = parse(&payload, true);
        let results = run_message(
            &self.gateway,
            &config,
            &self.held,
            &topic,
            &commands,
            summary(&payload.metrics),
        )
        .await;
        for result in results {
            match result {
                Ok(()) => {}
                Err(crate::gateway::GatewayError::SdoAbort { code, .. }) => {
                    outcome = Outcome::Abort(code.raw());
                }
                Err(_) => outcome = Outcome::Refused,
            }
        }
        outcome
    }

    /// Axis 1 enabled, through `door` (not an operation of the table).
    async fn enable_axis(&self, door: Door) {
        let outcome = match door {
            Door::Rest => {
                self.rest(
                    Method::POST,
                    "/api/v1/buses/demo/nodes/1/axes/1/state",
                    PLC.2,
                    Some(r#"{"target":"operation_enabled"}"#),
                )
                .await
            }
            _ => {
                self.dcmd(
                    PLC.0,
                    PLC.1,
                    vec![metric(
                        "Axis 1/State",
                        MetricValue::String("operation_enabled".into()),
                    )],
                )
                .await
            }
        };
        assert_eq!(outcome, Outcome::Done, "{door:?}: axis 1 not enabled");
    }

    async fn run(&mut self, door: Door, op: Op) -> Outcome {
        let (name, role, token) = op.token();
        if op == Op::WriteLimitRefused {
            self.spend(door, name);
        }
        let node = "/api/v1/buses/demo/nodes/1";
        let cia = "/cia309-5/1.0/5/1/1";
        let heartbeat = |door: Door| match door {
            Door::Rest => (format!("{node}/od/0x1017/0"), r#"{"value":1000}"#),
            Door::Cia309_3 => ("[2] 1 w 0x1017 0 u16 1000".into(), ""),
            _ => (
                format!("{cia}/w/0x1017/0"),
                r#"{"value":"1000","datatype":"u16"}"#,
            ),
        };
        let velocity = |speed: i32| format!(r#"{{"mode":"velocity","velocity":{speed}}}"#);
        match (door, op) {
            (Door::Rest, Op::Read) => {
                self.rest(Method::GET, &format!("{node}/od/0x1000/0"), token, None)
                    .await
            }
            (Door::Cia309_3, Op::Read) => self.ascii(token, "[2] 1 r 0x1000 0 u32").await,
            (Door::Cia309_5, Op::Read) => {
                self.cia309_5(Method::GET, &format!("{cia}/r/0x1000/0"), token, None)
                    .await
            }
            (Door::Rest, Op::Write | Op::RoleRefused | Op::WriteLimitRefused) => {
                let (path, body) = heartbeat(door);
                self.rest(Method::PUT, &path, token, Some(body)).await
            }
            (Door::Cia309_3, Op::Write | Op::RoleRefused | Op::WriteLimitRefused) => {
                self.ascii(token, &heartbeat(door).0).await
            }
            (Door::Cia309_5, Op::Write | Op::RoleRefused | Op::WriteLimitRefused) => {
                let (path, body) = heartbeat(door);
                self.cia309_5(Method::PUT, &path, token, Some(body)).await
            }
            (Door::Sparkplug, Op::Write | Op::RoleRefused | Op::WriteLimitRefused) => {
                self.dcmd(
                    name,
                    role,
                    vec![metric("OD/0x1017:0", MetricValue::UInt16(1000))],
                )
                .await
            }
            (Door::Rest, Op::WriteRefusedByDevice) => {
                self.rest(
                    Method::PUT,
                    &format!("{node}/od/0x1a00/0"),
                    token,
                    Some(r#"{"value":0}"#),
                )
                .await
            }
            (Door::Cia309_3, Op::WriteRefusedByDevice) => {
                self.ascii(token, "[2] 1 w 0x1A00 0 u8 0").await
            }
            (Door::Cia309_5, Op::WriteRefusedByDevice) => {
                let body = r#"{"value":"0","datatype":"u8"}"#;
                self.cia309_5(Method::PUT, &format!("{cia}/w/0x1A00/0"), token, Some(body))
                    .await
            }
            (Door::Sparkplug, Op::WriteRefusedByDevice) => {
                self.dcmd(
                    name,
                    role,
                    vec![metric("OD/0x1A00:0", MetricValue::UInt8(0))],
                )
                .await
            }
            (Door::Rest, Op::Nmt) => {
                self.rest(
                    Method::POST,
                    &format!("{node}/nmt"),
                    token,
                    Some(r#"{"command":"start"}"#),
                )
                .await
            }
            (Door::Cia309_3, Op::Nmt) => self.ascii(token, "[2] 1 start").await,
            (Door::Cia309_5, Op::Nmt) => {
                self.cia309_5(Method::POST, &format!("{cia}/start"), token, None)
                    .await
            }
            (Door::Sparkplug, Op::Nmt) => {
                self.dcmd(
                    name,
                    role,
                    vec![metric("NMT", MetricValue::String("start".into()))],
                )
                .await
            }
            (Door::Rest, Op::MoveUnderLease | Op::MoveWithoutLease) => {
                let speed = if op == Op::MoveUnderLease { 100 } else { -300 };
                let path = format!("{node}/axes/1/move");
                let bearer = format!("Bearer {token}");
                let mut headers = vec![("authorization", bearer.as_str())];
                let presented = self.rest_lease.clone();
                if let Some(id) = presented.as_deref().filter(|_| op == Op::MoveUnderLease) {
                    headers.push(("candeck-lease", id));
                }
                let (status, _, json) = send_with_headers(
                    &self.app,
                    Method::POST,
                    &path,
                    &headers,
                    Some(&velocity(speed)),
                )
                .await;
                if status == StatusCode::OK {
                    self.rest_lease = json["lease"]["id"].as_str().map(str::to_string);
                    Outcome::Done
                } else {
                    Outcome::Refused
                }
            }
            (Door::Sparkplug, Op::MoveUnderLease) => {
                self.dcmd(
                    name,
                    role,
                    vec![
                        metric("Axis 1/Move", MetricValue::String(velocity(100))),
                        metric("Axis 1/Lease", MetricValue::Boolean(true)),
                        metric("Axis 1/Lease Id", MetricValue::String(HOST_LEASE.into())),
                    ],
                )
                .await
            }
            (Door::Sparkplug, Op::MoveWithoutLease) => {
                self.dcmd(
                    name,
                    role,
                    vec![metric("Axis 1/Move", MetricValue::String(velocity(-300)))],
                )
                .await
            }
            (Door::Rest, Op::Halt) => {
                self.rest_lease = None;
                let path = format!("{node}/axes/1/halt");
                self.rest(Method::POST, &path, token, Some(r#"{"halt":true}"#))
                    .await
            }
            (Door::Sparkplug, Op::Halt) => {
                self.dcmd(
                    name,
                    role,
                    vec![metric("Axis 1/Halt", MetricValue::Boolean(true))],
                )
                .await
            }
            (door, op) => panic!("{door:?} does not offer {op:?}"),
        }
    }
}

/// What every door must answer, and the audit entry it must write.
fn expected(op: Op) -> (Outcome, Option<Row>) {
    let (_, role, _) = op.token();
    let row = |operation: &str,
               axis: Option<i64>,
               item: Option<&str>,
               _status: i64,
               error: Option<&str>,
               abort: Option<&str>| Row {
        role: role.name().to_string(),
        operation: operation.to_string(),
        bus: Some("demo".into()),
        node: Some(1),
        axis,
        item: item.map(str::to_string),
        outcome: error.unwrap_or("ok").to_string(),
        abort_code: abort.map(str::to_string),
        request: None,
    };
    let asking = |row: Row, request: &str| Row {
        request: Some(request.to_string()),
        ..row
    };
    let heartbeat = Some("0x1017:0");
    match op {
        // The UMC's device type: CiA 402.
        Op::Read => (Outcome::Value(402), None),
        Op::Write => (
            Outcome::Done,
            Some(row("write object", None, heartbeat, 200, None, None)),
        ),
        Op::WriteRefusedByDevice => (
            Outcome::Abort(0x0604_0043),
            Some(row(
                "write object",
                None,
                Some("0x1A00:0"),
                422,
                Some("sdo_abort"),
                Some("0x06040043"),
            )),
        ),
        Op::Nmt => (
            Outcome::Done,
            Some(asking(
                row("nmt command", None, None, 200, None, None),
                r#"{"command":"start"}"#,
            )),
        ),
        Op::MoveUnderLease => (
            Outcome::Done,
            Some(asking(
                row("move", Some(1), None, 200, None, None),
                r#"{"mode":"velocity","velocity":100}"#,
            )),
        ),
        Op::MoveWithoutLease => (
            Outcome::Refused,
            Some(asking(
                row("move", Some(1), None, 409, Some("lease_conflict"), None),
                r#"{"mode":"velocity","velocity":-300}"#,
            )),
        ),
        Op::Halt => (
            Outcome::Done,
            Some(asking(
                row("halt", Some(1), None, 200, None, None),
                r#"{"halt":true}"#,
            )),
        ),
        Op::RoleRefused => (
            Outcome::Refused,
            Some(row(
                "write object",
                None,
                heartbeat,
                403,
                Some("forbidden"),
                None,
            )),
        ),
        Op::WriteLimitRefused => (
            Outcome::Refused,
            Some(row(
                "write object",
                None,
                heartbeat,
                429,
                Some("rate_limited"),
                None,
            )),
        ),
    }
}

#[tokio::test(start_paused = true)]
async fn every_door_ends_each_operation_alike_and_audits_it_alike() {
    let mut rig = rig().await;
    let mut failures = Vec::new();
    for door in DOORS {
        if TABLE
            .iter()
            .any(|op| op.offered_by(door) && op == &Op::MoveUnderLease)
        {
            rig.enable_axis(door).await;
        }
        for op in TABLE.into_iter().filter(|op| op.offered_by(door)) {
            let before = crate::door_audit::rows(&rig.gateway).await.len();
            let outcome = rig.run(door, op).await;
            let rows = crate::door_audit::rows(&rig.gateway)
                .await
                .split_off(before);
            let (want, want_row) = expected(op);
            if outcome != want {
                failures.push(format!(
                    "{door:?} {op:?}: answered {outcome:?}, not {want:?}"
                ));
            }
            let want_rows: Vec<Row> = want_row.into_iter().collect();
            let compared = want_rows.iter().any(|want| want.request.is_some());
            let got: Vec<Row> = rows
                .iter()
                .map(row)
                .map(|got| Row {
                    request: got.request.filter(|_| compared),
                    ..got
                })
                .collect();
            if got != want_rows {
                failures.push(format!(
                    "{door:?} {op:?}: audit {got:#?}, not {want_rows:#?}"
                ));
            }
            let channel = door.channel().name();
            if let Some(entry) = rows.iter().find(|entry| entry["channel"] != channel) {
                failures.push(format!(
                    "{door:?} {op:?}: audited on channel {}, not {channel}",
                    entry["channel"]
                ));
            }
            let name = who(door, op.token().0);
            if let Some(entry) = rows.iter().find(|entry| entry["who"] != name.as_str()) {
                failures.push(format!(
                    "{door:?} {op:?}: audited as {}, not {name}",
                    entry["who"]
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The gateway refuses a caller its role does not allow by itself, not
/// only behind REST's guard: a viewer reads, but neither writes nor sends
/// NMT.
#[tokio::test(start_paused = true)]
async fn the_gateway_refuses_a_viewer_by_itself() {
    let rig = rig().await;
    let node = rig.gateway.node_handle("demo", "1").unwrap();
    let viewer = Caller::new(Channel::Rest, HMI.0, Some(Role::Viewer)).with_peer("127.0.0.1:1");
    assert_eq!(
        node.read_object(&viewer, 0x1000, 0).await.unwrap(),
        402u32.to_le_bytes()
    );
    let refused = node
        .write_object(&viewer, 0x1017, 0, 1000u16.to_le_bytes().to_vec())
        .await
        .unwrap_err();
    assert_eq!(refused.code(), "forbidden", "{refused}");
    let refused = node
        .nmt(&viewer, crate::canopen::nmt::NmtCommand::Stop)
        .await
        .unwrap_err();
    assert_eq!(refused.code(), "forbidden", "{refused}");
    let refused = rig
        .gateway
        .bus_nmt(&viewer, "demo", crate::canopen::nmt::NmtCommand::Stop)
        .await
        .unwrap_err();
    assert_eq!(refused.code(), "forbidden", "{refused}");
    // No token at all, on a gateway with tokens: unauthenticated.
    let nobody = Caller::new(Channel::Cia309_5, "http:127.0.0.1:1", None);
    let refused = node.read_object(&nobody, 0x1000, 0).await.unwrap_err();
    assert_eq!(refused.code(), "unauthenticated", "{refused}");
    // The node still runs: the stop was never sent.
    tokio::time::sleep(std::time::Duration::from_secs(2)).await;
    let info = rig.gateway.node_handle("demo", "1").unwrap();
    assert_ne!(
        info.info().nmt,
        Some(crate::canopen::nmt::NmtState::Stopped)
    );
}

/// A CiA 309-3 write to 0x1A00 sub 0 reads the node's TPDOs again, as the
/// same write through REST does: the follow-up hangs on the node's SDO
/// channel, which the gateway's object write uses whatever the door.
#[tokio::test(start_paused = true)]
async fn a_cia_309_3_write_of_0x1a00_refreshes_the_pdo_decoder_as_rest_does() {
    use std::time::Duration;
    let (app, state) = support::demo().await;
    let served = state.gateway.bus("demo").unwrap().clone();
    let node1 = crate::canopen::NodeId::new(1).unwrap();
    let read_at = || served.values().tpdos(node1).map(|tpdos| tpdos.read_at);
    for _ in 0..100 {
        if read_at().is_some() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let identity = Identity::anonymous("ascii", Some("127.0.0.1:50000".into()));
    let mut session = Session::new(Cia309Gateway::new(&state.gateway), identity);
    // TPDO1 made not valid first (CiA 301 §7.5.2.36: its mapping changes
    // only then).
    assert_eq!(
        session.handle("[1] 1 w 0x1800 1 u32 0x80000181").await,
        Reply::Ok(1)
    );
    tokio::time::sleep(Duration::from_secs(1)).await;
    let disabled = read_at().unwrap();
    let tpdo_numbers = || -> Vec<u16> {
        let tpdos = served.values().tpdos(node1).unwrap();
        tpdos.decoders.iter().map(|(number, _)| *number).collect()
    };
    assert!(!tpdo_numbers().contains(&1));

    // Through CiA 309-3: the TPDOs are read again after the write.
    let written = tokio::time::Instant::now();
    assert_eq!(session.handle("[2] 1 w 0x1A00 0 u8 0").await, Reply::Ok(2));
    tokio::time::sleep(Duration::from_secs(1)).await;
    let after_cia = read_at().unwrap();
    assert!(
        after_cia > disabled && after_cia >= written,
        "the CiA 309-3 write of 0x1A00:0 was not followed"
    );

    // Through REST: the same.
    let written = tokio::time::Instant::now();
    let (status, json) = support::put(
        &app,
        "/api/v1/buses/demo/nodes/1/od/0x1A00/0",
        serde_json::json!({"value": 1}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{json}");
    tokio::time::sleep(Duration::from_secs(1)).await;
    let after_rest = read_at().unwrap();
    assert!(
        after_rest > after_cia && after_rest >= written,
        "the REST write of 0x1A00:0 was not followed"
    );

    // TPDO1 valid again, with the one object mapped: decoded again.
    assert_eq!(
        session.handle("[3] 1 w 0x1800 1 u32 0x181").await,
        Reply::Ok(3)
    );
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert!(tpdo_numbers().contains(&1), "{:?}", tpdo_numbers());
}

/// Issue 31: the machine state REST gives (`GET .../machine`, with its
/// alarms) is the one Sparkplug's `Machine State` gives.
#[tokio::test(start_paused = true)]
async fn rest_and_sparkplug_give_the_same_machine_state_with_its_alarms() {
    use crate::emulator::RackOf;
    let served = open("demo", "virtual:demo")
        .await
        .with_machine(crate::gateway::MachineSettings::default(), None);
    served.scan().await.unwrap();
    let machine = served.machine().unwrap().clone();
    machine.scan_done();
    machine
        .wait_for(
            crate::canopen::manager::MachineState::Ready,
            std::time::Duration::from_secs(10),
        )
        .await;
    let state = AppState::new([served]);
    let router = app(state.clone());
    let states = || async {
        let (_, rest) = support::get(&router, "/api/v1/buses/demo/machine").await;
        let sparkplug = crate::sparkplug::node::machine_state(&state.gateway);
        (
            rest["state"].as_str().unwrap().to_string(),
            sparkplug.unwrap(),
        )
    };
    assert_eq!(states().await, ("ready".to_string(), "ready".to_string()));
    state
        .bus("demo")
        .unwrap()
        .rack()
        .unwrap()
        .inject_fault(
            crate::canopen::NodeId::new(1).unwrap(),
            crate::sim::behaviour::Fault::OverTemperature,
        )
        .unwrap();
    tokio::time::sleep(std::time::Duration::from_secs(1)).await;
    assert_eq!(states().await, ("alarm".to_string(), "alarm".to_string()));
}
