//! The stream's renewals as the gateway's operation: the role, the holder,
//! the session the lease lapses with, and the audit rows with their
//! throttles, no door in front.

use std::time::Duration;

use serde_json::Value as Json;

use super::*;
use crate::caller::Channel;
use crate::eds_files::tests::{caller, guarded_demo};

fn axis() -> AxisKey {
    AxisKey {
        bus: "demo".into(),
        node: 1,
        axis: 1,
    }
}

/// A velocity lease of `plc` on the demo's axis 1.
async fn leased() -> (Gateway, String) {
    let gateway = guarded_demo(100).await;
    let lease = gateway
        .leases
        .grant(&gateway, axis(), None, None, "plc", "velocity")
        .unwrap();
    (gateway, lease.id)
}

/// The stream renewal rows so far, once `count` are written.
async fn renewal_rows(gateway: &Gateway, count: usize) -> Vec<serde_json::Map<String, Json>> {
    crate::audit::tests::rows_where(gateway, count, |row| {
        row["operation"] == "renew motion lease (stream)"
    })
    .await
}

#[tokio::test(start_paused = true)]
async fn only_the_holder_renews_and_the_lease_lapses_with_its_session() {
    let (gateway, id) = leased().await;
    let mut session = gateway.lease_session();
    let viewer = caller(Channel::Websocket, "hmi");
    let refused = gateway
        .renew_in_session(&viewer, &mut session, &id)
        .unwrap_err();
    assert_eq!(refused.code(), "forbidden", "{refused}");
    // An admin may renew leases, but only its own.
    let admin = caller(Channel::Websocket, "admin");
    let refused = gateway
        .renew_in_session(&admin, &mut session, &id)
        .unwrap_err();
    assert_eq!(refused.code(), "lease_conflict", "{refused}");
    let unknown = gateway
        .renew_in_session(&admin, &mut session, "made-up-lease-id-0000")
        .unwrap_err();
    assert_eq!(unknown.code(), "unknown_lease", "{unknown}");

    let holder = caller(Channel::Websocket, "plc");
    // Renewed past three periods: held.
    for _ in 0..6 {
        let lease = gateway
            .renew_in_session(&holder, &mut session, &id)
            .unwrap();
        assert_eq!(lease.holder, "plc");
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    assert!(gateway.leases.holds(&axis(), &id));
    // The session ends (its client went away): the lease lapses now.
    drop(session);
    assert!(!gateway.leases.holds(&axis(), &id));
}

#[tokio::test(start_paused = true)]
async fn renewals_are_audited_once_a_minute_and_refusals_once_a_minute_per_session() {
    let (gateway, id) = leased().await;
    let masked = mask(&id);
    let holder = caller(Channel::Websocket, "plc").with_peer("192.0.2.7:40000");
    let mut session = gateway.lease_session();
    // Every half period for 70 s: 140 renewals, rows at 0 s and 60 s.
    for _ in 0..140 {
        gateway
            .renew_in_session(&holder, &mut session, &id)
            .unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    let rows = renewal_rows(&gateway, 2).await;
    assert_eq!(rows.len(), 2, "{rows:#?}");
    for row in &rows {
        assert_eq!(row["outcome"], "ok", "{row:?}");
        assert_eq!(row["channel"], "websocket", "{row:?}");
        assert_eq!(row["who"], "plc", "{row:?}");
        assert_eq!(row["peer"], "192.0.2.7:40000", "{row:?}");
        assert_eq!(
            (&row["bus"], &row["node"], &row["axis"]),
            (&"demo".into(), &1.into(), &1.into())
        );
        assert_eq!(
            row["item"],
            format!("lease {masked} (velocity lease of plc)"),
            "{row:?}"
        );
        assert_eq!(
            row["request"],
            format!("{{\"leases\":[\"{masked}\"],\"op\":\"renew\"}}"),
            "{row:?}"
        );
    }

    // A viewer's session: 50 refusals, one row; a minute later the next
    // row counts the 49 left out.
    let viewer = caller(Channel::Websocket, "hmi");
    let mut watching = gateway.lease_session();
    for _ in 0..50 {
        let refused = gateway.renew_in_session(&viewer, &mut watching, &id);
        assert_eq!(refused.unwrap_err().code(), "forbidden");
    }
    // Another session's refusals are throttled on their own.
    let mut other = gateway.lease_session();
    let _ = gateway.renew_in_session(&viewer, &mut other, &id);
    tokio::time::sleep(RENEWAL_AUDIT_EVERY).await;
    let _ = gateway.renew_in_session(&viewer, &mut watching, &id);
    let rows = renewal_rows(&gateway, 5).await;
    let refused: Vec<(&Json, &Json)> = rows[2..]
        .iter()
        .map(|row| (&row["outcome"], &row["item"]))
        .collect();
    let forbidden = Json::from("forbidden");
    assert_eq!(
        refused,
        [
            (&forbidden, &Json::from(format!("lease {masked}"))),
            (&forbidden, &Json::from(format!("lease {masked}"))),
            (
                &forbidden,
                &Json::from(format!(
                    "lease {masked}; 49 more refused renewals not logged"
                ))
            ),
        ]
    );
    assert!(
        !Json::Array(rows.into_iter().map(Json::Object).collect())
            .to_string()
            .contains(&id),
        "the lease id in clear"
    );
}
