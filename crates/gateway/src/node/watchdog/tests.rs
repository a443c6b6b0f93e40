//! Finding 4 of issue 30: one operator write of 0x1016:1 = 0 or 0x6007 = 0
//! used to switch a drive's watchdog off silently.

use std::time::Duration;

use crate::access::Role;
use crate::caller::{Caller, Channel};
use crate::registry::NodeEvent;
use crate::{Gateway, test_rig};

/// The demo's UMC.
const UMC: &str = "1";

async fn demo() -> Gateway {
    let config = test_rig::config(&[("demo", "virtual:demo")]);
    let gateway = Gateway::start(config, &test_rig::rack).await.unwrap();
    tokio::time::sleep(Duration::from_secs(5)).await;
    gateway
}

fn caller(role: Role) -> Caller {
    let who = match role {
        Role::Admin => "admin",
        _ => "plc",
    };
    Caller::new(Channel::Rest, who, Some(role))
}

async fn read(gateway: &Gateway, index: u16, sub: u8) -> Vec<u8> {
    gateway
        .node_handle("demo", UMC)
        .unwrap()
        .read_object(&caller(Role::Operator), index, sub)
        .await
        .unwrap()
}

async fn write(
    gateway: &Gateway,
    role: Role,
    index: u16,
    sub: u8,
    bytes: &[u8],
) -> Result<(), crate::GatewayError> {
    gateway
        .node_handle("demo", UMC)
        .unwrap()
        .write_object(&caller(role), index, sub, bytes.to_vec())
        .await
}

/// The 0x1016 entry the network manager's boot-up set to watch it (node
/// 127).
async fn manager_entry(gateway: &Gateway) -> (u8, u32) {
    let count = read(gateway, 0x1016, 0).await[0];
    for sub in 1..=count {
        let data = read(gateway, 0x1016, sub).await;
        let value = u32::from_le_bytes(data[..4].try_into().unwrap());
        if value >> 16 & 0xFF == 127 {
            return (sub, value);
        }
    }
    panic!("no 0x1016 entry watches the manager");
}

#[tokio::test(start_paused = true)]
async fn an_operator_cannot_switch_the_watchdog_off() {
    let gateway = demo().await;
    let before = read(&gateway, 0x6007, 0).await;
    assert_ne!(before, [0, 0], "the UMC reacts to a lost connection");
    let refused = write(&gateway, Role::Operator, 0x6007, 0, &[0, 0])
        .await
        .unwrap_err();
    assert_eq!(refused.code(), "watchdog_protected", "{refused}");
    assert!(refused.to_string().contains("only an admin"), "{refused}");
    assert_eq!(read(&gateway, 0x6007, 0).await, before);
    // Another reaction is the operator's to choose.
    write(&gateway, Role::Operator, 0x6007, 0, &[3, 0])
        .await
        .unwrap();

    let (sub, entry) = manager_entry(&gateway).await;
    let refused = write(&gateway, Role::Operator, 0x1016, sub, &[0, 0, 0, 0])
        .await
        .unwrap_err();
    assert_eq!(refused.code(), "watchdog_protected", "{refused}");
    // Nor handed to another producer.
    let other = (entry & 0xFFFF) | 5 << 16;
    let refused = write(&gateway, Role::Operator, 0x1016, sub, &other.to_le_bytes())
        .await
        .unwrap_err();
    assert_eq!(refused.code(), "watchdog_protected", "{refused}");
    assert_eq!(manager_entry(&gateway).await, (sub, entry));

    let rows = crate::audit::tests::rows(&gateway).await;
    let refusals = rows
        .iter()
        .filter(|row| row["operation"] == "write object" && row["outcome"] == "watchdog_protected")
        .count();
    assert_eq!(refusals, 3, "{rows:#?}");
}

#[tokio::test(start_paused = true)]
async fn an_admin_may_with_a_warning_on_the_stream_and_in_the_audit_log() {
    let gateway = demo().await;
    let mut events = gateway.buses["demo"].registry.subscribe();
    write(&gateway, Role::Admin, 0x6007, 0, &[0, 0])
        .await
        .unwrap();
    assert_eq!(read(&gateway, 0x6007, 0).await, [0, 0]);
    let warning = loop {
        match events.recv().await.unwrap() {
            NodeEvent::WatchdogOff { node, warning } => {
                assert_eq!(node.get(), 1);
                break warning;
            }
            _ => continue,
        }
    };
    assert!(
        warning.contains("0x6007") && warning.contains("admin"),
        "{warning}"
    );
    let rows = crate::audit::tests::rows_where(&gateway, 1, |row| row["who"] == "admin").await;
    let row = rows.first().expect("the admin's row");
    assert_eq!(row["outcome"], "ok", "{row:?}");
    assert!(
        row["operation"]
            .as_str()
            .unwrap()
            .starts_with("write object; WATCHDOG SWITCHED OFF: 0x6007"),
        "{row:?}"
    );
}

/// The network manager sets the entry up again at the node's next
/// boot-up, whoever cleared it.
#[tokio::test(start_paused = true)]
async fn the_manager_watches_again_after_the_nodes_boot_up() {
    use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};
    let gateway = demo().await;
    let (sub, entry) = manager_entry(&gateway).await;
    write(&gateway, Role::Admin, 0x1016, sub, &[0, 0, 0, 0])
        .await
        .unwrap();
    assert_eq!(read(&gateway, 0x1016, sub).await, [0, 0, 0, 0]);
    let node = crate::canopen::NodeId::new(1).unwrap();
    let reset = NmtMessage::new(NmtCommand::ResetCommunication, NmtTarget::Node(node)).encode();
    gateway.buses["demo"].bus.send(reset).await.unwrap();
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert_eq!(manager_entry(&gateway).await.1, entry);
}

/// An admin's DCF restore is checked as an admin's object write is: a DCF
/// whose 0x6007 = 0 and whose manager's 0x1016 entry is 0 is written,
/// with the warning on the stream and in the restore's audit row.
#[tokio::test(start_paused = true)]
async fn a_dcf_restore_that_switches_the_watchdog_off_warns_like_a_write() {
    let gateway = demo().await;
    let (sub, _) = manager_entry(&gateway).await;
    let umc = gateway.node_handle("demo", UMC).unwrap();
    let admin = caller(Role::Admin);
    let mut dcf = umc.backup_dcf(&admin).await.unwrap();
    // Only the two watchdog entries, switched off.
    for object in dcf.dictionary.objects.values_mut() {
        for entry in object.subs.values_mut() {
            entry.parameter_value = None;
        }
    }
    dcf.dictionary.sub_mut(0x6007, 0).unwrap().parameter_value = Some("0".into());
    dcf.dictionary.sub_mut(0x1016, sub).unwrap().parameter_value = Some("0".into());
    let mut events = gateway.buses["demo"].registry.subscribe();

    let restored = umc
        .restore_dcf(&admin, dcf.write().as_bytes())
        .await
        .unwrap();
    assert_eq!(restored.len(), 2, "{restored:?}");
    assert!(
        restored
            .iter()
            .all(|entry| matches!(entry.result, Some(Ok(())))),
        "{restored:?}"
    );
    assert_eq!(read(&gateway, 0x6007, 0).await, [0, 0]);
    assert_eq!(read(&gateway, 0x1016, sub).await, [0, 0, 0, 0]);

    let mut warnings = Vec::new();
    while warnings.len() < 2 {
        match tokio::time::timeout(Duration::from_secs(1), events.recv()).await {
            Ok(Ok(NodeEvent::WatchdogOff { node, warning })) => {
                assert_eq!(node.get(), 1);
                warnings.push(warning);
            }
            Ok(Ok(_)) => continue,
            other => panic!("two watchdog_off events, got {warnings:?} then {other:?}"),
        }
    }
    assert!(
        warnings.iter().any(|w| w.contains("0x6007")),
        "{warnings:?}"
    );
    assert!(
        warnings.iter().any(|w| w.contains("0x1016")),
        "{warnings:?}"
    );

    let rows = crate::audit::tests::rows_where(&gateway, 1, |row| row["who"] == "admin").await;
    let row = rows.first().expect("the admin's row");
    assert_eq!(row["outcome"], "ok", "{row:?}");
    let operation = row["operation"].as_str().unwrap();
    assert!(
        operation.starts_with("restore configuration (DCF); WATCHDOG SWITCHED OFF: ")
            && operation.contains("0x6007")
            && operation.contains("0x1016"),
        "{row:?}"
    );
}
