//! The virtual-device operations through the gateway alone, no door in
//! front: the policy (an admin's, one write of the rate), one row each,
//! and the work done for a caller that went away.

use std::time::Duration;

use serde_json::{Map, Value as Json};

use super::*;
use crate::api::tests::support::open;
use crate::gateway::Channel;
use crate::gateway::{RateLimit, Role, Token, Tokens};

/// The demo bus, with a viewer, an operator and an admin token, each
/// `burst` writes in its bucket (never refilled within a test).
async fn demo(burst: u32) -> Gateway {
    let served = open("demo", "virtual:demo").await;
    served.scan().await.unwrap();
    let tokens = Tokens::new(vec![
        Token::new("hmi", Role::Viewer, "hmi-0123456789abcdefgh").unwrap(),
        Token::new("plc", Role::Operator, "plc-0123456789abcdefgh").unwrap(),
        Token::new("admin", Role::Admin, "admin-0123456789abcdefg").unwrap(),
    ]);
    Gateway::new([served])
        .with_tokens(tokens)
        .with_write_limit(Some(RateLimit {
            per_second: 0.0001,
            burst,
        }))
}

fn caller(who: &str, role: Role) -> Caller {
    Caller::new(Channel::Rest, who, Some(role))
}

/// (operation, node, outcome) of every audit row so far, oldest first.
async fn rows(gateway: &Gateway) -> Vec<(String, Option<u64>, String)> {
    crate::door_audit::rows(gateway)
        .await
        .into_iter()
        .map(|fields: Map<String, Json>| {
            assert_eq!(fields["bus"], "demo", "{fields:?}");
            (
                fields["operation"].as_str().unwrap().to_string(),
                fields.get("node").and_then(Json::as_u64),
                fields["outcome"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

fn row(operation: &str, node: Option<u64>, outcome: &str) -> (String, Option<u64>, String) {
    (operation.to_string(), node, outcome.to_string())
}

fn led_at(node: u8) -> DeviceSpec {
    DeviceSpec::at(Product::Uio1led, NodeId::new(node).unwrap())
}

#[tokio::test(start_paused = true)]
async fn only_an_admin_changes_the_virtual_devices_and_each_request_is_one_row() {
    let gateway = demo(100).await;
    let node = NodeId::new(1).unwrap();
    for refused in [caller("hmi", Role::Viewer), caller("plc", Role::Operator)] {
        let refusals = [
            add_device(&gateway, &refused, "demo", led_at(10))
                .await
                .map(|_| ()),
            remove_device(&gateway, &refused, "demo", node).await,
            inject_fault(&gateway, &refused, "demo", node, Fault::OverTemperature).await,
            clear_fault(&gateway, &refused, "demo", node, Fault::OverTemperature).await,
            controller_fault(&gateway, &refused, "demo", ControllerFault::BitErrors).await,
            controller_fault(&gateway, &refused, "demo", ControllerFault::NoBitErrors).await,
        ];
        for refusal in refusals {
            let error = refusal.unwrap_err();
            assert_eq!(error.code(), "forbidden", "{}: {error}", refused.who);
        }
    }
    let rack = rack_of(&gateway, "demo").unwrap();
    assert_eq!(
        rack.devices().len(),
        3,
        "a refused request changed the rack"
    );
    let refused = [
        row("add virtual device", None, "forbidden"),
        row("remove virtual device", Some(1), "forbidden"),
        row("inject fault", Some(1), "forbidden"),
        row("clear fault", Some(1), "forbidden"),
        row("inject fault", None, "forbidden"),
        row("clear fault", None, "forbidden"),
    ];
    let mut want: Vec<_> = refused.iter().chain(&refused).cloned().collect();
    assert_eq!(rows(&gateway).await, want);

    let admin = caller("admin", Role::Admin);
    let added = add_device(&gateway, &admin, "demo", led_at(10))
        .await
        .unwrap();
    assert_eq!(
        added,
        VirtualDevice {
            id: NodeId::new(10).ok(),
            product: Some(Product::Uio1led),
            plugged: true,
            serial: None,
        }
    );
    let taken = add_device(&gateway, &admin, "demo", led_at(10))
        .await
        .unwrap_err();
    assert_eq!(taken.code(), "node_taken", "{taken}");
    inject_fault(&gateway, &admin, "demo", node, Fault::OverTemperature)
        .await
        .unwrap();
    clear_fault(&gateway, &admin, "demo", node, Fault::OverTemperature)
        .await
        .unwrap();
    // An LED controller has no following error.
    let led = NodeId::new(10).unwrap();
    let not_applicable = inject_fault(&gateway, &admin, "demo", led, Fault::FollowingError)
        .await
        .unwrap_err();
    assert_eq!(not_applicable.code(), "fault_not_applicable");
    controller_fault(&gateway, &admin, "demo", ControllerFault::BitErrors)
        .await
        .unwrap();
    controller_fault(&gateway, &admin, "demo", ControllerFault::NoBitErrors)
        .await
        .unwrap();
    remove_device(&gateway, &admin, "demo", led).await.unwrap();
    let gone = remove_device(&gateway, &admin, "demo", led)
        .await
        .unwrap_err();
    assert_eq!(gone.code(), "unknown_node", "{gone}");
    want.extend([
        row("add virtual device", None, "ok"),
        row("add virtual device", None, "node_taken"),
        row("inject fault", Some(1), "ok"),
        row("clear fault", Some(1), "ok"),
        row("inject fault", Some(10), "fault_not_applicable"),
        row("inject fault", None, "ok"),
        row("clear fault", None, "ok"),
        row("remove virtual device", Some(10), "ok"),
        row("remove virtual device", Some(10), "unknown_node"),
    ]);
    assert_eq!(rows(&gateway).await, want);
}

#[tokio::test(start_paused = true)]
async fn a_flood_of_virtual_device_requests_is_refused_for_the_rate() {
    let gateway = demo(2).await;
    let admin = caller("admin", Role::Admin);
    let node = NodeId::new(1).unwrap();
    inject_fault(&gateway, &admin, "demo", node, Fault::OverTemperature)
        .await
        .unwrap();
    clear_fault(&gateway, &admin, "demo", node, Fault::OverTemperature)
        .await
        .unwrap();
    let flood = add_device(&gateway, &admin, "demo", led_at(10))
        .await
        .unwrap_err();
    assert_eq!(flood.code(), "rate_limited", "{flood}");
    assert!(
        rack_of(&gateway, "demo")
            .unwrap()
            .devices()
            .iter()
            .all(|(id, _, _)| id.get() != 10),
        "a refused device was added"
    );
    assert_eq!(
        rows(&gateway).await.last(),
        Some(&row("add virtual device", None, "rate_limited"))
    );
}

#[tokio::test(start_paused = true)]
async fn a_device_is_added_for_a_caller_that_went_away() {
    let gateway = demo(100).await;
    let admin = caller("admin", Role::Admin);
    // Polled once, then dropped: the caller is gone.
    let dropped = tokio::time::timeout(
        Duration::ZERO,
        add_device(&gateway, &admin, "demo", led_at(10)),
    )
    .await;
    assert!(dropped.is_err(), "it ended within its first poll");
    tokio::time::sleep(Duration::from_millis(10)).await;
    let rack = rack_of(&gateway, "demo").unwrap();
    assert!(
        rack.devices().iter().any(|(id, _, _)| id.get() == 10),
        "the device was not added"
    );
    assert_eq!(
        rows(&gateway).await,
        [row("add virtual device", None, "ok")]
    );
}
