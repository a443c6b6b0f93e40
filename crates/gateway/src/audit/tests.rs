use std::time::Duration;

use serde_json::Value as Json;

use super::*;
use crate::access::Role;
use crate::caller::Channel;
use crate::canopen::sdo::AbortCode;
use crate::history::{EventKind, Query};

fn operator() -> Caller {
    Caller::new(Channel::Cia309_3, "plc", Some(Role::Operator)).with_peer("127.0.0.1:4000")
}

fn target() -> AuditTarget {
    AuditTarget::new("write object")
        .bus("demo")
        .node(1)
        .item("0x1017:0".to_string())
}

/// Every audit row written so far, oldest first (the node operations'
/// tests read them too).
pub(crate) async fn rows(gateway: &Gateway) -> Vec<serde_json::Map<String, Json>> {
    let mut events = gateway
        .history
        .query(Query {
            kind: Some(EventKind::Audit),
            since_us: None,
            until_us: None,
            channel: None,
            limit: 1000,
        })
        .await
        .unwrap();
    events.sort_by_key(|event| event.id);
    events.into_iter().map(|event| event.fields).collect()
}

/// The rows `keep` accepts, once `count` of them are written (or what there
/// is after a second of the paused clock: the test's assertion says what
/// is missing).
pub(crate) async fn rows_where(
    gateway: &Gateway,
    count: usize,
    keep: impl Fn(&serde_json::Map<String, Json>) -> bool,
) -> Vec<serde_json::Map<String, Json>> {
    let mut kept = Vec::new();
    for _ in 0..100 {
        kept = rows(gateway).await;
        kept.retain(|row| keep(row));
        if kept.len() >= count {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    kept
}

/// The rows once `count` are written (rows written from a `Drop` are
/// written by a task of their own).
async fn rows_when(gateway: &Gateway, count: usize) -> Vec<serde_json::Map<String, Json>> {
    for _ in 0..500 {
        let rows = rows(gateway).await;
        if rows.len() >= count {
            return rows;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    rows(gateway).await
}

#[tokio::test(start_paused = true)]
async fn an_operation_writes_one_row_with_its_outcome() {
    let gateway = Gateway::new([]);
    let done = gateway
        .audited(
            &operator(),
            target(),
            Some("{\"raw\":\"e803\"}".into()),
            async { Ok::<_, GatewayError>(7) },
        )
        .await;
    assert_eq!(done.unwrap(), 7);
    let refused = gateway
        .audited(&operator(), target(), None, async {
            Err::<(), _>(GatewayError::SdoAbort {
                node: 1,
                code: AbortCode::from_raw(0x0609_0030),
            })
        })
        .await;
    assert_eq!(refused.unwrap_err().code(), "sdo_abort");
    let rows = rows(&gateway).await;
    assert_eq!(rows.len(), 2, "{rows:?}");
    assert_eq!(rows[0]["channel"], "cia309_3");
    assert_eq!(rows[0]["who"], "plc");
    assert_eq!(rows[0]["role"], "operator");
    assert_eq!(rows[0]["peer"], "127.0.0.1:4000");
    assert_eq!(rows[0]["operation"], "write object");
    assert_eq!(rows[0]["bus"], "demo");
    assert_eq!(rows[0]["node"], 1);
    assert_eq!(rows[0]["item"], "0x1017:0");
    assert_eq!(rows[0]["request"], "{\"raw\":\"e803\"}");
    assert_eq!(rows[0]["outcome"], "ok");
    assert_eq!(rows[1]["outcome"], "sdo_abort");
    assert_eq!(rows[1]["abort_code"], "0x06090030");
}

#[tokio::test(start_paused = true)]
async fn the_doors_words_and_summary_go_into_the_row() {
    let gateway = Gateway::new([]);
    let detail =
        DoorDetail::new("ASCII", "[1] 1 w 0x1017 0 u16 1000").summary(Some("u16 1000".into()));
    let caller = operator().with_detail(detail);
    gateway
        .audited(
            &caller,
            target(),
            Some("{\"raw\":\"e803\"}".into()),
            async { Ok::<_, GatewayError>(()) },
        )
        .await
        .unwrap();
    let rows = rows(&gateway).await;
    assert_eq!(rows[0]["method"], "ASCII");
    assert_eq!(rows[0]["path"], "[1] 1 w 0x1017 0 u16 1000");
    // The door's summary, not the operation's.
    assert_eq!(rows[0]["request"], "u16 1000");
    assert!(caller.door.as_ref().unwrap().audited());
}

/// The caller's future dropped while the transfer runs in its task: the
/// transfer ends, and its row says how.
#[tokio::test(start_paused = true)]
async fn a_row_finished_in_the_transfers_task_survives_its_caller() {
    let gateway = Gateway::new([]);
    let row = gateway.audit_row(&operator(), target(), None);
    let operation = spawn_audited(row, async {
        tokio::time::sleep(Duration::from_secs(1)).await;
        Ok::<_, GatewayError>(())
    });
    // The caller goes away half way.
    assert!(
        tokio::time::timeout(Duration::from_millis(100), operation)
            .await
            .is_err()
    );
    tokio::time::sleep(Duration::from_secs(2)).await;
    let rows = rows_when(&gateway, 1).await;
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_eq!(rows[0]["outcome"], "ok");
}

/// An operation that runs in its caller's future (a move holding its lease
/// in flight): dropped half way, its row is written all the same.
#[tokio::test(start_paused = true)]
async fn a_row_dropped_unfinished_is_written_as_interrupted() {
    let gateway = Gateway::new([]);
    let caller = operator();
    let operation = gateway.audited(&caller, target(), None, async {
        tokio::time::sleep(Duration::from_secs(1)).await;
        Ok::<_, GatewayError>(())
    });
    assert!(
        tokio::time::timeout(Duration::from_millis(100), operation)
            .await
            .is_err()
    );
    let rows = rows_when(&gateway, 1).await;
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_eq!(rows[0]["outcome"], INTERRUPTED);
}

#[tokio::test(start_paused = true)]
async fn a_door_writes_a_row_only_for_what_no_operation_audited() {
    let gateway = Gateway::new([]);
    let door_target = || AuditTarget::new("write object").bus("demo");
    // Refused by the door before any operation: the door's row.
    let caller = operator().with_detail(DoorDetail::new("ASCII", "[1] 9 w 0x1017 0 u16 1"));
    let refused = gateway
        .audited_by_door(&caller, door_target(), None, async {
            Err::<(), _>(GatewayError::UnknownNode {
                bus: "demo".into(),
                node: "9".into(),
            })
        })
        .await;
    assert_eq!(refused.unwrap_err().code(), "unknown_node");
    // An operation audited it: its row only.
    let caller = operator().with_detail(DoorDetail::new("ASCII", "[2] 1 w 0x1017 0 u16 1"));
    let work = gateway.audited(&caller, target(), None, async { Ok::<_, GatewayError>(()) });
    gateway
        .audited_by_door(&caller, door_target(), None, work)
        .await
        .unwrap();
    let rows = rows(&gateway).await;
    assert_eq!(rows.len(), 2, "{rows:?}");
    assert_eq!(rows[0]["outcome"], "unknown_node");
    assert_eq!(rows[0]["path"], "[1] 9 w 0x1017 0 u16 1");
    assert_eq!(rows[1]["outcome"], "ok");
    assert_eq!(rows[1]["item"], "0x1017:0", "the operation's row");
}

/// A door's future dropped while the operation it called finishes in its
/// own task: one row, the operation's, not the door's too.
#[tokio::test(start_paused = true)]
async fn a_door_dropped_while_its_operation_runs_leaves_one_row() {
    let gateway = Gateway::new([]);
    let caller = operator().with_detail(DoorDetail::new("DCMD", "spBv1.0/plant/DCMD/line1/demo-1"));
    let row = gateway.audit_row(&caller, target(), None);
    let work = spawn_audited(row, async {
        tokio::time::sleep(Duration::from_secs(1)).await;
        Ok::<_, GatewayError>(())
    });
    let door = gateway.audited_by_door(&caller, AuditTarget::new("write object"), None, work);
    assert!(
        tokio::time::timeout(Duration::from_millis(100), door)
            .await
            .is_err()
    );
    drop(caller);
    tokio::time::sleep(Duration::from_secs(2)).await;
    let first = rows_when(&gateway, 1).await;
    // Give a second row, if any, the time to show.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let later = rows(&gateway).await;
    assert_eq!(later.len(), 1, "{later:?}");
    assert_eq!(first[0]["outcome"], "ok");
    assert_eq!(first[0]["item"], "0x1017:0");
}

/// A door that adds words once the operation has answered (REST's status)
/// takes the rows; the ones it never takes are written when it lets go.
#[tokio::test(start_paused = true)]
async fn rows_handed_over_are_the_doors_to_write() {
    let gateway = Gateway::new([]);
    let door = DoorRequest::handed_over(DoorDetail::new(
        "PUT",
        "/api/v1/buses/demo/nodes/1/od/0x1017/0",
    ));
    let caller = Caller::new(Channel::Rest, "plc", Some(Role::Operator)).with_door(door.clone());
    gateway
        .audited(&caller, target(), None, async { Ok::<_, GatewayError>(()) })
        .await
        .unwrap();
    assert!(door.audited());
    assert!(rows(&gateway).await.is_empty(), "held for the door");
    let taken = door.take_rows();
    assert_eq!(taken.len(), 1);
    gateway.write_audit(taken[0].clone().http_status(200)).await;
    assert_eq!(rows(&gateway).await[0]["status"], 200);

    // Never taken: written when the request ends.
    let door = DoorRequest::handed_over(DoorDetail::new("POST", "/api/v1/buses/demo/nodes/1/nmt"));
    let caller = Caller::new(Channel::Rest, "plc", Some(Role::Operator)).with_door(door.clone());
    gateway
        .audited(&caller, AuditTarget::new("nmt command"), None, async {
            Ok::<_, GatewayError>(())
        })
        .await
        .unwrap();
    drop((door, caller));
    let rows = rows_when(&gateway, 2).await;
    assert_eq!(rows.len(), 2, "{rows:?}");
    assert_eq!(rows[1]["operation"], "nmt command");
    assert!(rows[1].get("status").is_none());
}

#[tokio::test(start_paused = true)]
async fn a_skipped_row_counts_as_audited_and_writes_nothing() {
    let gateway = Gateway::new([]);
    let caller = operator().with_detail(DoorDetail::new("DCMD", "spBv1.0/plant/DCMD/line1/demo-1"));
    let row = gateway.audit_row(&caller, AuditTarget::new("renew motion lease"), None);
    row.skip();
    gateway
        .audited_by_door(
            &caller,
            AuditTarget::new("renew motion lease"),
            None,
            async { Ok::<_, GatewayError>(()) },
        )
        .await
        .unwrap();
    assert!(rows(&gateway).await.is_empty());
}

fn dcmd_caller() -> (Caller, DoorRequest) {
    let door = DoorRequest::gathered(
        DoorDetail::new("DCMD", "spBv1.0/plant/DCMD/line1/demo-1").summary(Some(
            "3 metrics: OD/0x1017:0=1000; NMT=\"start\"; Nonsense=true".into(),
        )),
    );
    let caller = Caller::new(Channel::Sparkplug, "mqtt:candeck", Some(Role::Operator))
        .with_door(door.clone());
    (caller, door)
}

/// A request of several commands, each its own operation (or the door's
/// own refusal), is one row: its operations named, the first failure its
/// outcome.
#[tokio::test(start_paused = true)]
async fn the_operations_of_a_gathered_request_are_one_row() {
    let gateway = Gateway::new([]);
    let (caller, _door) = dcmd_caller();
    let whole = AuditTarget::new("command").bus("demo").node(1);
    let result = gateway
        .audited_together(&caller, whole, None, async {
            gateway
                .audited(&caller, target(), None, async { Ok::<_, GatewayError>(()) })
                .await?;
            let nmt = AuditTarget::new("nmt command").bus("demo").node(1);
            let _ = gateway
                .audited_by_door(&caller, nmt, None, async {
                    Err::<(), _>(GatewayError::SdoTimeout { node: 1 })
                })
                .await;
            // The door's own refusal, after an operation audited another
            // command of the request: a part too.
            let _ = gateway
                .audited_by_door(
                    &caller,
                    AuditTarget::new("unsupported command"),
                    None,
                    async { Err::<(), _>(GatewayError::InvalidRequest("Nonsense".into())) },
                )
                .await;
            Ok::<_, GatewayError>(())
        })
        .await;
    assert!(result.is_ok());
    let rows = rows(&gateway).await;
    assert_eq!(rows.len(), 1, "{rows:?}");
    let row = &rows[0];
    assert_eq!(
        row["operation"],
        "write object, nmt command, unsupported command"
    );
    assert_eq!(row["outcome"], "sdo_timeout");
    assert_eq!(row["bus"], "demo");
    assert_eq!(row["node"], 1);
    assert!(row.get("item").is_none(), "{row:?}");
    assert_eq!(row["method"], "DCMD");
    assert_eq!(
        row["request"],
        "3 metrics: OD/0x1017:0=1000; NMT=\"start\"; Nonsense=true (2 of 3 failed)"
    );

    // One operation: the row is its own (its words and item).
    let (caller, _door) = dcmd_caller();
    gateway
        .audited_together(&caller, AuditTarget::new("command"), None, async {
            gateway
                .audited(&caller, target(), None, async { Ok::<_, GatewayError>(()) })
                .await
        })
        .await
        .unwrap();
    let rows = rows_when(&gateway, 2).await;
    assert_eq!(rows.len(), 2, "{rows:?}");
    assert_eq!(rows[1]["operation"], "write object");
    assert_eq!(rows[1]["item"], "0x1017:0");
    assert_eq!(rows[1]["outcome"], "ok");
}

/// A request whose operations all decided no row was due (lease renewals)
/// writes none; one with no operation at all writes its own.
#[tokio::test(start_paused = true)]
async fn a_gathered_request_of_skipped_rows_writes_none() {
    let gateway = Gateway::new([]);
    let (caller, _door) = dcmd_caller();
    gateway
        .audited_together(&caller, AuditTarget::new("command"), None, async {
            gateway
                .audit_row(&caller, AuditTarget::new("renew motion lease"), None)
                .skip();
            Ok::<_, GatewayError>(())
        })
        .await
        .unwrap();
    assert!(rows(&gateway).await.is_empty());
    let (caller, _door) = dcmd_caller();
    let _ = gateway
        .audited_together(&caller, AuditTarget::new("command"), None, async {
            Err::<(), _>(GatewayError::InvalidRequest("nothing to run".into()))
        })
        .await;
    let rows = rows(&gateway).await;
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_eq!(rows[0]["operation"], "command");
    assert_eq!(rows[0]["outcome"], "invalid_request");
}
