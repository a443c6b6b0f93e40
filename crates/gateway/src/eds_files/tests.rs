//! The EDS catalog's operations through the gateway alone, no door in
//! front: the policy (an admin uploads and deletes, an operator assigns),
//! one write of the caller's rate each, one audit row each, and the work
//! done for a caller that went away. The rig is shared with the loggers'
//! and the stream renewals' tests.

use std::time::Duration;

use crate::access::{RateLimit, Role, Token, Tokens};
use crate::caller::{Caller, Channel};
use crate::canopen::NodeId;
use crate::{Gateway, GatewayConfig, test_rig};

/// The demo rack with a viewer (`hmi`), an operator (`plc`) and an admin
/// (`admin`) token, each with `burst` writes (never refilled within a
/// test), its nodes identified.
pub(crate) async fn guarded_demo(burst: u32) -> Gateway {
    let tokens = Tokens::new(vec![
        Token::new("hmi", Role::Viewer, "hmi-0123456789abcdefgh").unwrap(),
        Token::new("plc", Role::Operator, "plc-0123456789abcdefgh").unwrap(),
        Token::new("admin", Role::Admin, "admin-0123456789abcdefg").unwrap(),
    ]);
    let config = GatewayConfig {
        tokens,
        write_limit: Some(RateLimit {
            per_second: 0.0001,
            burst,
        }),
        ..test_rig::config(&[("demo", "virtual:demo")])
    };
    let gateway = Gateway::start(config, &test_rig::rack).await.unwrap();
    tokio::time::sleep(Duration::from_secs(5)).await;
    gateway
}

/// The token `who` of [`guarded_demo`] with its role, through `channel`.
pub(crate) fn caller(channel: Channel, who: &str) -> Caller {
    let role = match who {
        "hmi" => Role::Viewer,
        "plc" => Role::Operator,
        _ => Role::Admin,
    };
    Caller::new(channel, who, Some(role))
}

/// (operation, bus, node, item, outcome) of every caller's audit row so
/// far (not the gateway's own: the network manager's), once `count` are
/// written (rows finished in a task of their own come a little later).
pub(crate) async fn rows_when(
    gateway: &Gateway,
    count: usize,
) -> Vec<(String, String, String, String, String)> {
    let text = |row: &serde_json::Map<String, serde_json::Value>, key: &str| match row.get(key) {
        None | Some(serde_json::Value::Null) => String::new(),
        Some(serde_json::Value::String(text)) => text.clone(),
        Some(other) => other.to_string(),
    };
    let rows =
        crate::audit::tests::rows_where(gateway, count, |row| row["channel"] != "system").await;
    rows.iter()
        .map(|row| {
            (
                text(row, "operation"),
                text(row, "bus"),
                text(row, "node"),
                text(row, "item"),
                text(row, "outcome"),
            )
        })
        .collect()
}

pub(crate) fn row(
    operation: &str,
    bus: &str,
    node: &str,
    item: &str,
    outcome: &str,
) -> (String, String, String, String, String) {
    (
        operation.into(),
        bus.into(),
        node.into(),
        item.into(),
        outcome.into(),
    )
}

const GOOD: &str = "[DeviceInfo]\nVendorNumber=0x77\nProductNumber=0x10\nRevisionNumber=1\n\
[MandatoryObjects]\nSupportedObjects=1\n1=0x1000\n\
[1000]\nParameterName=Device type\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x00020192\n";

fn uploaded(gateway: &Gateway, name: &str) -> bool {
    gateway.eds_catalog().unwrap().find(name).is_some()
}

#[tokio::test(start_paused = true)]
async fn the_catalog_is_an_admins_and_assignments_an_operators_each_one_row() {
    let gateway = guarded_demo(100).await;
    let node = NodeId::new(2).unwrap();
    let (hmi, plc, admin) = (
        caller(Channel::Cia309_3, "hmi"),
        caller(Channel::Sparkplug, "plc"),
        caller(Channel::Rest, "admin"),
    );
    for refused in [&hmi, &plc] {
        let error = gateway
            .upload_eds(refused, "good.eds", GOOD)
            .await
            .unwrap_err();
        assert_eq!(error.code(), "forbidden", "{error}");
        let error = gateway.delete_eds(refused, "good.eds").await.unwrap_err();
        assert_eq!(error.code(), "forbidden", "{error}");
    }
    let error = gateway
        .assign_eds(&hmi, "demo", node, Some("umc1bds32.eds"))
        .await
        .unwrap_err();
    assert_eq!(error.code(), "forbidden", "{error}");
    let error = gateway
        .assign_eds(&hmi, "demo", node, None)
        .await
        .unwrap_err();
    assert_eq!(error.code(), "forbidden", "{error}");
    assert!(!uploaded(&gateway, "good.eds"), "a refused upload was kept");

    gateway.upload_eds(&admin, "good.eds", GOOD).await.unwrap();
    assert!(uploaded(&gateway, "good.eds"));
    let info = gateway
        .assign_eds(&plc, "demo", node, Some("good.eds"))
        .await
        .unwrap()
        .unwrap();
    assert_eq!(info.eds.as_deref(), Some("good.eds"));
    let assigned = gateway.delete_eds(&admin, "good.eds").await.unwrap_err();
    assert_eq!(assigned.code(), "eds_conflict", "{assigned}");
    gateway.assign_eds(&plc, "demo", node, None).await.unwrap();
    gateway.delete_eds(&admin, "good.eds").await.unwrap();
    assert!(!uploaded(&gateway, "good.eds"));
    let not_eds = gateway
        .upload_eds(&admin, "notes.eds", "just notes\n")
        .await
        .unwrap_err();
    assert_eq!(not_eds.code(), "invalid_eds", "{not_eds}");

    let upload = |outcome| row("upload eds", "", "", "good.eds", outcome);
    let delete = |outcome| row("delete eds", "", "", "good.eds", outcome);
    let mut want = Vec::new();
    for _ in 0..2 {
        want.extend([upload("forbidden"), delete("forbidden")]);
    }
    want.extend([
        row("assign eds", "demo", "2", "", "forbidden"),
        row("unassign eds", "demo", "2", "", "forbidden"),
        upload("ok"),
        row("assign eds", "demo", "2", "", "ok"),
        delete("eds_conflict"),
        row("unassign eds", "demo", "2", "", "ok"),
        delete("ok"),
        row("upload eds", "", "", "notes.eds", "invalid_eds"),
    ]);
    assert_eq!(rows_when(&gateway, want.len()).await, want);
}

#[tokio::test(start_paused = true)]
async fn a_flood_of_catalog_requests_is_refused_for_the_rate() {
    let gateway = guarded_demo(2).await;
    let node = NodeId::new(2).unwrap();
    let admin = caller(Channel::Rest, "admin");
    gateway.upload_eds(&admin, "good.eds", GOOD).await.unwrap();
    gateway.delete_eds(&admin, "good.eds").await.unwrap();
    let flood = gateway
        .upload_eds(&admin, "good.eds", GOOD)
        .await
        .unwrap_err();
    assert_eq!(flood.code(), "rate_limited", "{flood}");
    assert!(!uploaded(&gateway, "good.eds"), "a refused upload was kept");

    let plc = caller(Channel::Rest, "plc");
    for file in [Some("umc1bds32.eds"), None] {
        gateway.assign_eds(&plc, "demo", node, file).await.unwrap();
    }
    let flood = gateway
        .assign_eds(&plc, "demo", node, Some("umc1bds32.eds"))
        .await
        .unwrap_err();
    assert_eq!(flood.code(), "rate_limited", "{flood}");
    let rows = rows_when(&gateway, 6).await;
    assert_eq!(
        rows[2],
        row("upload eds", "", "", "good.eds", "rate_limited")
    );
    assert_eq!(rows[5], row("assign eds", "demo", "2", "", "rate_limited"));
}

#[tokio::test(start_paused = true)]
async fn an_upload_is_kept_for_a_caller_that_went_away() {
    let gateway = guarded_demo(100).await;
    let admin = caller(Channel::Rest, "admin");
    // Polled once, then dropped: the caller is gone.
    let dropped =
        tokio::time::timeout(Duration::ZERO, gateway.upload_eds(&admin, "good.eds", GOOD)).await;
    assert!(dropped.is_err(), "it ended within its first poll");
    assert_eq!(
        rows_when(&gateway, 1).await,
        [row("upload eds", "", "", "good.eds", "ok")]
    );
    assert!(uploaded(&gateway, "good.eds"));
}
