//! The bus operations (and LSS, the node-ID change, the I/O outputs)
//! through the gateway alone, no door in front, on a paused clock: each
//! holds its caller to the role and the write rate itself, writes exactly
//! one audit row with the words the audit log has for it, and cannot be
//! cut by a caller that goes away.

use std::time::Duration;

use serde_json::{Map, Value as Json};

use crate::access::{RateLimit, Role, Token, Tokens};
use crate::audit::{DoorDetail, DoorRequest};
use crate::caller::{Caller, Channel};
use crate::can::{CanId, Frame};
use crate::canopen::lss::LssAddress;
use crate::recording::Limits;
use crate::{Gateway, GatewayConfig, GatewayError, test_rig};

/// A UMC at 1 (0x2040), an I/O module at 4, a UIO1LED waiting for LSS.
const LINE: &str = "virtual:umc1bds32@1,io401@4,uio1led@lss";

/// The gateway on [`LINE`], its network manager done with the first
/// boot-ups; with `tokens`, writes are counted by token name, 2 a caller.
async fn line(tokens: Tokens) -> Gateway {
    let config = GatewayConfig {
        tokens,
        write_limit: Some(RateLimit {
            per_second: 0.0001,
            burst: 2,
        }),
        ..test_rig::config(&[("line", LINE)])
    };
    let gateway = Gateway::start(config, &test_rig::rack).await.unwrap();
    tokio::time::sleep(Duration::from_secs(5)).await;
    gateway
}

/// The UIO1LED of [`LINE`], as Fastscan finds it.
const LED: LssAddress = LssAddress {
    vendor_id: 0x4A2,
    product_code: 0x4101,
    revision: 1,
    serial: 0x101,
};

/// One call of an operation.
#[derive(Debug, Clone, Copy)]
enum Op {
    Scan,
    Sync(u64),
    SendFrame,
    StartRecording,
    StopRecording,
    LssScan,
    LssConfigure(i64),
    ChangeNodeId(&'static str, i64),
    Boot(&'static str),
    SetOutputs(&'static str),
}

impl Op {
    /// The operation's words and node, as its audit row has them.
    fn words(self) -> (&'static str, Option<u8>) {
        let node = |id: &str| id.parse().ok();
        match self {
            Self::Scan => ("scan", None),
            Self::Sync(_) => ("set sync period", None),
            Self::SendFrame => ("send frame", None),
            Self::StartRecording => ("start recording", None),
            Self::StopRecording => ("stop recording", None),
            Self::LssScan => ("lss scan", None),
            Self::LssConfigure(_) => ("lss configure", None),
            Self::ChangeNodeId(id, _) => ("change node-id", node(id)),
            Self::Boot(id) => ("boot node again", node(id)),
            Self::SetOutputs(id) => ("set outputs", node(id)),
        }
    }

    async fn call(self, gateway: &Gateway, caller: &Caller) -> Result<(), GatewayError> {
        let bus = "line";
        match self {
            Self::Scan => gateway.scan(caller, bus).await.map(drop),
            Self::Sync(ms) => gateway
                .set_sync_period(caller, bus, Duration::from_millis(ms))
                .await
                .map(drop),
            Self::SendFrame => {
                let frame = Frame::new(CanId::Standard(0x123), &[1, 2]).unwrap();
                gateway.send_frame(caller, bus, frame).await
            }
            Self::StartRecording => gateway
                .start_recording(caller, bus, Limits::default())
                .await
                .map(drop),
            Self::StopRecording => gateway.stop_recording(caller, bus).await.map(drop),
            Self::LssScan => gateway.lss_scan(caller, bus).await.map(drop),
            Self::LssConfigure(node_id) => gateway
                .lss_configure(caller, bus, LED, node_id, false)
                .await
                .map(drop),
            Self::ChangeNodeId(id, node_id) => gateway
                .change_node_id(caller, bus, id, node_id)
                .await
                .map(drop),
            Self::Boot(id) => gateway.boot_node(caller, bus, id).await.map(drop),
            Self::SetOutputs(id) => {
                let outputs = [("do1".to_string(), Json::Bool(true))].into();
                gateway.write_io(caller, bus, id, outputs).await.map(drop)
            }
        }
    }
}

/// The callers' audit rows so far (not the network manager's own).
async fn rows(gateway: &Gateway) -> Vec<Map<String, Json>> {
    crate::audit::tests::rows(gateway)
        .await
        .into_iter()
        .filter(|row| row["who"] != "gateway")
        .collect()
}

/// Calls `op` and checks it left exactly one row, its own, with its
/// outcome: `ok` or the error's code.
async fn call_once(gateway: &Gateway, caller: &Caller, op: Op) -> String {
    let before = rows(gateway).await.len();
    let outcome = match op.call(gateway, caller).await {
        Ok(()) => "ok".to_string(),
        Err(error) => error.code().to_string(),
    };
    let new = rows(gateway).await.split_off(before);
    assert_eq!(new.len(), 1, "{op:?}: {new:#?}");
    let (operation, node) = op.words();
    let row = &new[0];
    assert_eq!(row["operation"], operation, "{op:?}: {row:?}");
    assert_eq!(row["bus"], "line", "{op:?}: {row:?}");
    let logged_node = row.get("node").cloned().unwrap_or(Json::Null);
    assert_eq!(logged_node, node.map_or(Json::Null, Json::from), "{op:?}");
    assert_eq!(row["outcome"], outcome, "{op:?}: {row:?}");
    assert_eq!(row["who"], caller.who.as_str(), "{op:?}: {row:?}");
    outcome
}

const EVERY_OPERATION: [Op; 10] = [
    Op::Scan,
    Op::Sync(10),
    Op::SendFrame,
    Op::StartRecording,
    Op::StopRecording,
    Op::LssScan,
    Op::LssConfigure(10),
    Op::ChangeNodeId("1", 9),
    Op::Boot("4"),
    Op::SetOutputs("4"),
];

#[tokio::test(start_paused = true)]
async fn a_viewer_is_refused_every_bus_operation_by_the_operation_itself() {
    let gateway = line(Tokens::default()).await;
    let mut frames = gateway.buses["line"].bus.monitor();
    for channel in [Channel::Rest, Channel::Cia309_3, Channel::Sparkplug] {
        let viewer = Caller::new(channel, "watcher", Some(Role::Viewer));
        for op in EVERY_OPERATION {
            assert_eq!(
                call_once(&gateway, &viewer, op).await,
                "forbidden",
                "{op:?}"
            );
        }
    }
    // Refused before the bus: no raw frame, no LSS request, no SYNC.
    while let Ok(Some(frame)) = frames.try_recv() {
        let id = frame.frame.id().raw();
        assert!(![0x123, 0x7E5, 0x080].contains(&id), "{frame:?}");
    }
    assert_eq!(gateway.buses["line"].sync.period(), Duration::ZERO);
    assert!(gateway.buses["line"].recorder.current_path().is_none());
}

/// Each operation takes one write of its caller's rate (2 here): the
/// third call in a row is refused `rate_limited`, the first two do their
/// work (or are refused for what they find).
#[tokio::test(start_paused = true)]
async fn each_bus_operation_takes_one_write_and_a_flood_is_refused() {
    let token = Token::new("hmi", Role::Viewer, "v1ewer-0123456789abcdef").unwrap();
    let gateway = line(Tokens::new(vec![token])).await;
    let expected: [(Op, [&str; 3]); 10] = [
        (Op::Scan, ["ok", "ok", "rate_limited"]),
        (Op::Sync(10), ["ok", "ok", "rate_limited"]),
        (Op::SendFrame, ["ok", "ok", "rate_limited"]),
        (
            Op::StartRecording,
            ["ok", "recording_running", "rate_limited"],
        ),
        (
            Op::StopRecording,
            ["ok", "recording_not_running", "rate_limited"],
        ),
        (Op::LssScan, ["ok", "ok", "rate_limited"]),
        (
            Op::LssConfigure(10),
            ["ok", "node_id_in_use", "rate_limited"],
        ),
        (
            Op::ChangeNodeId("1", 9),
            ["ok", "unknown_node", "rate_limited"],
        ),
        (Op::Boot("4"), ["ok", "ok", "rate_limited"]),
        (Op::SetOutputs("4"), ["ok", "ok", "rate_limited"]),
    ];
    for (op, outcomes) in expected {
        // A caller of its own per operation: a bucket of its own.
        let who = format!("{op:?}");
        let caller = Caller::new(Channel::Cia309_5, who, Some(Role::Admin));
        let mut got = Vec::new();
        for _ in outcomes {
            got.push(call_once(&gateway, &caller, op).await);
        }
        assert_eq!(got, outcomes, "{op:?}");
    }
    // What they did is done: the SYNC runs, the LED and the UMC moved.
    let served = &gateway.buses["line"];
    assert_eq!(served.sync.period(), Duration::from_millis(10));
    let ids: Vec<u8> = served.nodes().iter().map(|node| node.id.get()).collect();
    assert!(ids.contains(&9) && ids.contains(&10), "{ids:?}");
    assert!(!ids.contains(&1), "{ids:?}");
}

/// A door's request is audited by the operation: the row is handed to the
/// door with its words, and the door writes none of its own.
#[tokio::test(start_paused = true)]
async fn the_operation_audits_a_doors_request() {
    let gateway = line(Tokens::default()).await;
    for op in EVERY_OPERATION {
        let door = DoorRequest::handed_over(DoorDetail::new("POST", "/somewhere"));
        let caller = Caller::new(Channel::Rest, "plc", Some(Role::Admin)).with_door(door.clone());
        let _ = op.call(&gateway, &caller).await;
        assert!(door.audited(), "{op:?}");
        let handed = door.take_rows();
        assert_eq!(handed.len(), 1, "{op:?}: {handed:?}");
        assert_eq!(handed[0].operation, op.words().0, "{op:?}");
        assert_eq!(handed[0].path.as_deref(), Some("/somewhere"), "{op:?}");
    }
}

/// An LSS scan whose caller goes away runs to its end, and its row says
/// how it ended; the bus's LSS is free again after it.
#[tokio::test(start_paused = true)]
async fn an_lss_scan_whose_caller_goes_away_runs_to_its_end() {
    let gateway = line(Tokens::default()).await;
    let admin = Caller::new(Channel::Rest, "admin", Some(Role::Admin));
    let cut = tokio::time::timeout(Duration::from_millis(30), gateway.lss_scan(&admin, "line"));
    assert!(cut.await.is_err(), "the scan ended within 30 ms");
    // Still under way: a second transaction is refused.
    let busy = gateway.lss_scan(&admin, "line").await.unwrap_err();
    assert_eq!(busy.code(), "lss_busy", "{busy}");
    tokio::time::sleep(Duration::from_secs(10)).await;
    let outcomes: Vec<(Json, Json)> = rows(&gateway)
        .await
        .iter()
        .map(|row| (row["operation"].clone(), row["outcome"].clone()))
        .collect();
    assert_eq!(
        outcomes,
        [
            ("lss scan".into(), "lss_busy".into()),
            ("lss scan".into(), "ok".into()),
        ]
    );
    let found = gateway.lss_scan(&admin, "line").await.unwrap();
    assert_eq!(found, [LED]);
}
