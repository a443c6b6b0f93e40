use std::time::Duration;

use candeck_sim::behaviour::Fault;
use candeck_sim::rack::Rack;

use super::*;
use crate::GatewayConfig;
use crate::access::Role;
use crate::caller::{Caller, Channel};
use crate::canopen::NodeId;
use crate::canopen::manager::{MachineStatus, NodeDescription};
use crate::error::GatewayError;
use crate::profiles::alarm::{AlarmKind, Product, describe};
use crate::service::Gateway;
use crate::test_rig::{self, config, enable_axis, operator, started};

// The book, sans I/O.

fn source(kind: AlarmKind) -> AlarmSource {
    AlarmSource::new("line", Some(1), Some(2), kind)
}

fn text(kind: AlarmKind) -> AlarmText {
    describe(Product::Umc, kind, Some(2), "Following error")
}

fn raise(book: &mut AlarmBook, kind: AlarmKind, at: i64) -> Option<Changed> {
    book.raise(source(kind), || text(kind), at)
}

#[test]
fn an_alarm_raised_cleared_and_back_while_unacknowledged_is_one_alarm_counted_twice() {
    let mut book = AlarmBook::default();
    let kind = AlarmKind::Emcy(0x8611);
    let raised = raise(&mut book, kind, 100).unwrap();
    assert_eq!(raised.alarm.state, AlarmState::ActiveUnacknowledged);
    assert_eq!(raised.alarm.severity, Severity::High);
    assert_eq!(raised.alarm.count, 1);
    // Raised again while active: nothing changes.
    assert_eq!(raise(&mut book, kind, 150), None);
    let cleared = book.clear(&source(kind), 200).unwrap();
    assert_eq!(cleared.alarm.state, AlarmState::ClearedUnacknowledged);
    assert_eq!(cleared.alarm.cleared_us, Some(200));
    // Back before anyone acknowledged it: the same alarm, counted.
    let back = raise(&mut book, kind, 300).unwrap();
    assert_eq!(back.alarm.id, raised.alarm.id);
    assert_eq!(back.alarm.state, AlarmState::ActiveUnacknowledged);
    assert_eq!(back.alarm.count, 2);
    assert_eq!(back.alarm.cleared_us, None);
    assert_eq!(back.event.step, AlarmStep::Returned);
    let steps: Vec<AlarmStep> = back.alarm.history.iter().map(|e| e.step).collect();
    assert_eq!(
        steps,
        [AlarmStep::Raised, AlarmStep::Cleared, AlarmStep::Returned]
    );
    assert_eq!(book.list(&AlarmFilter::default(), 1).1, 1, "no duplicate");
}

#[test]
fn acknowledged_before_clearing_it_goes_normal_when_its_cause_goes() {
    let mut book = AlarmBook::default();
    let kind = AlarmKind::AxisFault;
    let id = raise(&mut book, kind, 100).unwrap().alarm.id;
    let (alarm, changed) = book.acknowledge(id, "alice", Some("seen"), 150).unwrap();
    assert_eq!(alarm.state, AlarmState::ActiveAcknowledged);
    assert_eq!(alarm.acknowledged_by.as_deref(), Some("alice"));
    assert_eq!(alarm.acknowledged_at_us, Some(150));
    assert_eq!(alarm.comment.as_deref(), Some("seen"));
    assert_eq!(changed.unwrap().event.who.as_deref(), Some("alice"));
    // A second acknowledgement changes nothing.
    let (again, changed) = book.acknowledge(id, "bob", None, 160).unwrap();
    assert!(changed.is_none());
    assert_eq!(again.acknowledged_by.as_deref(), Some("alice"));
    let cleared = book.clear(&source(kind), 200).unwrap();
    assert_eq!(cleared.alarm.state, AlarmState::Normal);
    // Its cause again: a new alarm, the old one is history.
    let next = raise(&mut book, kind, 300).unwrap();
    assert_ne!(next.alarm.id, id);
    assert_eq!(next.alarm.count, 1);
    let (all, total) = book.list(&AlarmFilter::default(), 1);
    assert_eq!(total, 2);
    assert_eq!(all[0].id, next.alarm.id, "active first");
    assert_eq!(all[1].state, AlarmState::Normal);
}

#[test]
fn acknowledged_after_clearing_it_goes_normal_at_once() {
    let mut book = AlarmBook::default();
    let kind = AlarmKind::HeartbeatLost;
    let id = raise(&mut book, kind, 100).unwrap().alarm.id;
    book.clear(&source(kind), 200).unwrap();
    let (alarm, changed) = book.acknowledge(id, "alice", None, 300).unwrap();
    assert_eq!(alarm.state, AlarmState::Normal);
    assert!(changed.is_some());
    assert!(book.open_alarms(None).is_empty());
    assert!(book.acknowledge(id + 1, "alice", None, 300).is_none());
}

#[test]
fn acknowledging_by_filter_takes_only_the_unacknowledged_that_match() {
    let mut book = AlarmBook::default();
    let high = raise(&mut book, AlarmKind::AxisFault, 1).unwrap().alarm.id;
    let medium = raise(&mut book, AlarmKind::LeaseHalted, 2)
        .unwrap()
        .alarm
        .id;
    let other = book
        .raise(
            AlarmSource::new("line", Some(4), None, AlarmKind::NodeOffline),
            || describe(Product::Other, AlarmKind::NodeOffline, None, ""),
            3,
        )
        .unwrap()
        .alarm
        .id;
    let filter = AlarmFilter {
        node: Some(1),
        ..AlarmFilter::default()
    };
    let acked: Vec<u64> = book
        .acknowledge_matching(&filter, "alice", None, 10)
        .iter()
        .map(|c| c.alarm.id)
        .collect();
    assert_eq!(acked, [high, medium]);
    assert_eq!(
        book.get(other).unwrap().state,
        AlarmState::ActiveUnacknowledged
    );
    let filter = AlarmFilter {
        severity: Some(Severity::High),
        ..AlarmFilter::default()
    };
    let acked = book.acknowledge_matching(&filter, "bob", None, 11);
    assert_eq!(acked.len(), 1);
    assert_eq!(acked[0].alarm.id, other);
}

#[test]
fn a_list_is_paged_fifty_at_a_time_and_filtered() {
    let mut book = AlarmBook::default();
    for node in 1..=60u8 {
        let source = AlarmSource::new("line", Some(node), None, AlarmKind::NodeOffline);
        book.raise(source, || text(AlarmKind::NodeOffline), i64::from(node));
    }
    let (first, total) = book.list(&AlarmFilter::default(), 1);
    assert_eq!((first.len(), total), (50, 60));
    assert_eq!(first[0].node, Some(60), "newest first");
    let (second, _) = book.list(&AlarmFilter::default(), 2);
    assert_eq!(second.len(), 10);
    let filter = AlarmFilter {
        node: Some(7),
        ..AlarmFilter::default()
    };
    assert_eq!(book.list(&filter, 1).1, 1);
    book.clear(
        &AlarmSource::new("line", Some(3), None, AlarmKind::NodeOffline),
        100,
    );
    let since = AlarmFilter {
        since_us: Some(101),
        state: None,
        ..AlarmFilter::default()
    };
    assert_eq!(
        book.list(&since, 1).1,
        59,
        "cleared before `since`: left out"
    );
    let cleared = AlarmFilter {
        state: Some(AlarmState::ClearedUnacknowledged),
        ..AlarmFilter::default()
    };
    assert_eq!(book.list(&cleared, 1).1, 1);
}

#[test]
fn restored_alarms_stay_active_only_if_their_cause_is_reported_again() {
    let mut book = AlarmBook::default();
    let present = raise(&mut book, AlarmKind::AxisFault, 1).unwrap().alarm;
    let gone = raise(&mut book, AlarmKind::HeartbeatLost, 2).unwrap().alarm;
    let stored: Vec<Alarm> = book.open_alarms(None).into_iter().cloned().collect();
    let mut book = AlarmBook::restore(stored);
    let confirmed = raise(&mut book, AlarmKind::AxisFault, 10).unwrap();
    assert_eq!(confirmed.alarm.id, present.id);
    assert_eq!(confirmed.event.step, AlarmStep::Restored);
    assert_eq!(confirmed.alarm.count, 1, "not counted: it never went");
    let settled = book.settle_restored(20);
    assert_eq!(settled.len(), 1);
    assert_eq!(settled[0].alarm.id, gone.id);
    assert_eq!(settled[0].alarm.state, AlarmState::ClearedUnacknowledged);
    assert_eq!(
        book.get(present.id).unwrap().state,
        AlarmState::ActiveUnacknowledged
    );
    // New alarms go on from the restored ids.
    let next = raise(&mut book, AlarmKind::LeaseHalted, 30).unwrap();
    assert!(next.alarm.id > gone.id);
}

#[test]
fn the_machine_is_never_ready_while_a_critical_or_high_alarm_is_active() {
    let status = MachineStatus {
        state: crate::canopen::manager::MachineState::Ready,
        reasons: Vec::new(),
        nodes: Vec::new(),
    };
    let mut book = AlarmBook::default();
    raise(&mut book, AlarmKind::LeaseHalted, 1);
    let view = MachineView::new(status.clone(), &book.open_alarms(None));
    assert_eq!(view.state, MachineCondition::Ready, "a medium alarm only");
    let fault = raise(&mut book, AlarmKind::AxisFault, 2).unwrap().alarm;
    let view = MachineView::new(status.clone(), &book.open_alarms(None));
    assert_eq!(view.state, MachineCondition::Alarm);
    assert_eq!(
        view.reasons,
        [format!(
            "alarm {} (high): node 1 axis 2: Drive fault (axis 2)",
            fault.id
        )]
    );
    let json = serde_json::to_value(&view).unwrap();
    assert_eq!(json["state"], "alarm");
    // Acknowledged, it is still active: still no `ready`.
    book.acknowledge(fault.id, "alice", None, 3);
    let view = MachineView::new(status.clone(), &book.open_alarms(None));
    assert_eq!(view.state, MachineCondition::Alarm);
    book.clear(&source(AlarmKind::AxisFault), 4);
    let view = MachineView::new(status, &book.open_alarms(None));
    assert_eq!(view.state, MachineCondition::Ready);
}

// The gateway: sources, operations, persistence (paused clock, the demo
// rack).

fn rack(gateway: &Gateway, bus: &str) -> Rack {
    let served = gateway.bus(bus).unwrap();
    let devices = served.devices().unwrap().clone();
    devices.downcast_ref::<Rack>().unwrap().clone()
}

fn node(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

/// The axes `(node, axis)` of the bus `line` put in operation enabled by
/// `caller` (taking no lease), then the UMC (node 1) overheated for a
/// second: the rack, to clear the fault.
async fn enabled_then_overheated(
    gateway: &Gateway,
    caller: &Caller,
    axes: &[(&str, &str)],
) -> Rack {
    let free = crate::motion::LeaseClaim::presented(None, false);
    for &(node, axis) in axes {
        enable_axis(gateway, caller, ("line", node, axis), &free)
            .await
            .unwrap();
    }
    let rack = rack(gateway, "line");
    rack.inject_fault(node(1), Fault::OverTemperature).unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    rack
}

/// The open alarms of `kind` on the bus `line`.
fn open_of(gateway: &Gateway, kind: &str) -> Vec<Alarm> {
    gateway
        .alarms
        .open(Some("line"))
        .into_iter()
        .filter(|alarm| alarm.kind.name() == kind)
        .collect()
}

#[tokio::test(start_paused = true)]
async fn a_drive_fault_raises_its_emcy_alarm_on_its_axis_and_the_machine_leaves_ready() {
    // SYNC on: the drives' TPDOs carry their statuswords.
    let gateway = started(GatewayConfig {
        sync_period: Duration::from_millis(20),
        ..config(&[("line", "virtual:demo")])
    })
    .await;
    assert!(gateway.alarms.open(None).is_empty(), "a healthy rack");
    let rack = rack(&gateway, "line");
    rack.inject_fault(node(1), Fault::FollowingError).unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    // The virtual UMC faults both its axes: one alarm each, the axis from
    // its EMCY's manufacturer bytes.
    let emcy = open_of(&gateway, "emcy");
    let axes: Vec<Option<u8>> = emcy.iter().map(|alarm| alarm.axis).collect();
    assert_eq!(axes, [Some(1), Some(2)], "{emcy:?}");
    assert_eq!(emcy[0].kind, AlarmKind::Emcy(0x8611));
    // Axis 1's statusword is in the UMC's default TPDOs; axis 2's is not.
    let faults = open_of(&gateway, "axis_fault");
    let axes: Vec<Option<u8>> = faults.iter().map(|a| a.axis).collect();
    assert_eq!(axes, [Some(1)], "the statusword's fault bit, from a TPDO");
    assert!(
        emcy[1].help.contains("0x683F"),
        "axis 2's objects: {}",
        emcy[1].help
    );
    assert_eq!(emcy[0].severity, Severity::High);
    assert!(emcy[0].help.contains("0x603F"), "{}", emcy[0].help);
    let view = gateway.machine_view("line").unwrap();
    assert_eq!(view.state, MachineCondition::Alarm, "{view:?}");
    assert!(
        view.reasons.iter().any(|r| r.contains("EMCY 0x8611")),
        "{:?}",
        view.reasons
    );
    let watched = gateway.watch_machine("line").unwrap().borrow().clone();
    assert_eq!(
        watched.state,
        MachineCondition::Alarm,
        "the stream's view follows"
    );

    // The fault gone, the machine's reset brings the axis back and the
    // drive's error reset clears the alarm, which waits to be seen.
    rack.clear_fault(node(1), Fault::FollowingError).unwrap();
    let report = gateway
        .reset_machine_faults(&operator("alice"), "line")
        .await
        .unwrap();
    let umc: Vec<RecoveryOutcome> = report
        .axes
        .iter()
        .filter(|a| a.node == 1)
        .map(|a| a.outcome)
        .collect();
    assert_eq!(umc, [RecoveryOutcome::Done; 2], "{report:?}");
    let jmc = report.axes.iter().find(|a| a.node == 2).unwrap();
    assert_eq!(jmc.outcome, RecoveryOutcome::NotNeeded);
    tokio::time::sleep(Duration::from_secs(1)).await;
    for raised in &emcy {
        let alarm = gateway
            .alarm(&operator("alice"), &raised.id.to_string())
            .unwrap();
        assert_eq!(alarm.state, AlarmState::ClearedUnacknowledged, "{alarm:?}");
    }
    let fault = gateway.alarms.book().get(faults[0].id).cloned().unwrap();
    assert_eq!(fault.state, AlarmState::ClearedUnacknowledged, "{fault:?}");
    assert_eq!(
        gateway.machine_view("line").unwrap().state,
        MachineCondition::Ready
    );
}

#[tokio::test(start_paused = true)]
async fn a_lost_heartbeat_raises_an_alarm_cleared_when_the_node_is_heard_again() {
    let gateway = started(config(&[("line", "virtual:demo")])).await;
    let rack = rack(&gateway, "line");
    rack.inject_fault(node(2), Fault::HeartbeatLoss).unwrap();
    tokio::time::sleep(Duration::from_secs(3)).await;
    let lost = open_of(&gateway, "heartbeat_lost");
    assert_eq!(lost.len(), 1, "{:?}", gateway.alarms.open(None));
    assert_eq!(lost[0].node, Some(2));
    assert_eq!(lost[0].severity, Severity::Critical, "a drive's heartbeat");
    // Reset faults refuses the JMC's axis: its cause is still there.
    let report = gateway
        .reset_machine_faults(&operator("alice"), "line")
        .await
        .unwrap();
    let jmc = report.axes.iter().find(|a| a.node == 2).unwrap();
    assert_eq!(jmc.outcome, RecoveryOutcome::Refused);
    assert!(
        jmc.reason
            .as_deref()
            .unwrap()
            .contains("the cause is still present"),
        "{jmc:?}"
    );
    rack.clear_fault(node(2), Fault::HeartbeatLoss).unwrap();
    tokio::time::sleep(Duration::from_secs(3)).await;
    let alarm = gateway.alarms.book().get(lost[0].id).cloned().unwrap();
    assert_eq!(alarm.state, AlarmState::ClearedUnacknowledged);
}

#[tokio::test(start_paused = true)]
async fn the_network_manager_s_missing_and_wrong_nodes_raise_alarms() {
    let mut described = config(&[("line", "virtual:demo")]);
    let mut wrong = NodeDescription::new(node(2));
    wrong.identity.product_code = Some(0xDEAD);
    described.machine_nodes.insert(
        "line".to_string(),
        vec![NodeDescription::new(node(9)), wrong],
    );
    let gateway = started(described).await;
    tokio::time::sleep(Duration::from_secs(30)).await;
    let missing = open_of(&gateway, "node_missing");
    assert_eq!(missing.len(), 1, "{:?}", gateway.alarms.open(None));
    assert_eq!(missing[0].node, Some(9));
    let wrong = open_of(&gateway, "wrong_identity");
    assert_eq!(wrong.len(), 1, "{:?}", gateway.alarms.open(None));
    assert_eq!(wrong[0].node, Some(2));
    assert!(wrong[0].help.contains("0x1018"));
}

#[tokio::test(start_paused = true)]
async fn bus_off_and_error_passive_raise_alarms_of_the_bus() {
    let gateway = started(config(&[("line", "virtual:demo")])).await;
    let served = gateway.bus("line").unwrap();
    served
        .controller_fault(crate::can::ControllerFault::BusOff)
        .unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let off = open_of(&gateway, "bus_off");
    assert_eq!(off.len(), 1, "{:?}", gateway.alarms.open(None));
    assert_eq!((off[0].node, off[0].severity), (None, Severity::Critical));
    served
        .controller_fault(crate::can::ControllerFault::Recover)
        .unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let alarm = gateway.alarms.book().get(off[0].id).cloned().unwrap();
    assert_eq!(alarm.state, AlarmState::ClearedUnacknowledged);
}

/// The lease supervisor's stop and the program download tell the alarms
/// what they did, typed, as they end. The alarms used to read it back from
/// the audit rows' words, and took every outcome of `download program` but
/// a list of refusals for a failed download: a download refused before the
/// bus for another reason (here the node is NMT-stopped: 409
/// `wrong_nmt_state`) raised "program download failed".
#[tokio::test(start_paused = true)]
async fn a_halted_lease_and_a_failed_program_download_raise_alarms_as_they_end() {
    let gateway = started(config(&[("line", "virtual:demo")])).await;
    let admin = Caller::new(Channel::Rest, "ada", Some(Role::Admin));
    let image = || b"CDKI\x061.2.3x-a-program".to_vec();

    // Refused before the bus: no download failed.
    let led = gateway.node_handle("line", "3").unwrap();
    led.nmt(&admin, crate::canopen::nmt::NmtCommand::Stop)
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    let led = gateway.node_handle("line", "3").unwrap();
    let refused = led.download_program(&admin, image(), false).await;
    assert_eq!(refused.unwrap_err().code(), "wrong_nmt_state");
    tokio::time::sleep(Duration::from_millis(10)).await;
    assert!(open_of(&gateway, "program_failed").is_empty());

    // Failed on the device (the JMC has no 0x1F51): raised; a later
    // download that succeeds on that node clears it.
    let jmc = gateway.node_handle("line", "2").unwrap();
    let failed = jmc.download_program(&admin, image(), false).await;
    assert_eq!(failed.unwrap_err().code(), "sdo_abort");
    tokio::time::sleep(Duration::from_millis(10)).await;
    let program = open_of(&gateway, "program_failed");
    assert_eq!(program.len(), 1, "{program:?}");
    assert_eq!(
        (program[0].node, program[0].state),
        (Some(2), AlarmState::ActiveUnacknowledged)
    );

    // A leased move whose client stops renewing: the supervisor stops the
    // axis, and the alarm waits to be seen, its cause gone.
    let axis = ("line", "1", "2");
    let claim = crate::motion::LeaseClaim::default();
    enable_axis(&gateway, &admin, axis, &claim).await.unwrap();
    let velocity: crate::drive::MoveRequest =
        serde_json::from_str(r#"{"mode":"velocity","velocity":200}"#).unwrap();
    gateway
        .move_axis(&admin, axis, &velocity, &claim)
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_secs(3)).await;
    let lease = open_of(&gateway, "lease_halted");
    assert_eq!(lease.len(), 1, "{lease:?}");
    assert_eq!((lease[0].node, lease[0].axis), (Some(1), Some(2)));
    assert_eq!(
        lease[0].state,
        AlarmState::ClearedUnacknowledged,
        "the halt is over: it waits to be seen"
    );
}

#[tokio::test(start_paused = true)]
async fn acknowledging_is_an_operator_s_audited_with_who_and_when() {
    let gateway = started(config(&[("line", "virtual:demo")])).await;
    rack(&gateway, "line")
        .inject_fault(node(1), Fault::OverTemperature)
        .unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let alarm = gateway.alarms.open(None).remove(0);
    let viewer = Caller::new(Channel::Rest, "vera", Some(Role::Viewer));
    let refused = gateway
        .acknowledge_alarm(&viewer, &alarm.id.to_string(), None)
        .await;
    assert!(
        matches!(refused, Err(GatewayError::Forbidden(_))),
        "{refused:?}"
    );
    let unknown = gateway
        .acknowledge_alarm(&operator("alice"), "999", None)
        .await;
    assert!(matches!(unknown, Err(GatewayError::UnknownAlarm(_))));
    let too_long = gateway
        .acknowledge_alarm(&operator("alice"), "1", Some("x".repeat(501)))
        .await;
    assert!(matches!(too_long, Err(GatewayError::InvalidRequest(_))));
    let acked = gateway
        .acknowledge_alarm(
            &operator("alice"),
            &alarm.id.to_string(),
            Some("fan checked".to_string()),
        )
        .await
        .unwrap();
    assert_eq!(acked.state, AlarmState::ActiveAcknowledged);
    assert_eq!(acked.acknowledged_by.as_deref(), Some("alice"));
    assert_eq!(acked.comment.as_deref(), Some("fan checked"));
    let rows = gateway
        .history
        .query(crate::Query {
            kind: Some(crate::EventKind::Audit),
            since_us: None,
            until_us: None,
            channel: None,
            limit: 10,
        })
        .await
        .unwrap();
    let row = rows
        .iter()
        .rev()
        .find(|row| row.fields["operation"] == "acknowledge alarm")
        .unwrap();
    assert_eq!(row.fields["who"], "alice");
    assert_eq!(row.fields["outcome"], "ok");
    assert_eq!(row.fields["item"], format!("alarm {}", alarm.id));
    assert_eq!(row.fields["node"], 1);
    let refusal = rows.iter().find(|row| row.fields["who"] == "vera").unwrap();
    assert_eq!(refusal.fields["outcome"], "forbidden");
}

#[tokio::test(start_paused = true)]
async fn alarms_survive_a_restart_and_are_re_evaluated() {
    let dir = std::env::temp_dir().join(format!("candeck-alarms-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let with_dir = || GatewayConfig {
        data_dir: Some(dir.clone()),
        ..config(&[("line", "virtual:demo")])
    };
    let gateway = started(with_dir()).await;
    let rack_before = rack(&gateway, "line");
    rack_before
        .inject_fault(node(2), Fault::HeartbeatLoss)
        .unwrap();
    rack_before
        .inject_fault(node(1), Fault::OverTemperature)
        .unwrap();
    tokio::time::sleep(Duration::from_secs(3)).await;
    let before = gateway.alarms.open(None);
    let lost = before
        .iter()
        .find(|a| a.kind == AlarmKind::HeartbeatLost)
        .unwrap()
        .clone();
    let hot = before
        .iter()
        .find(|a| matches!(a.kind, AlarmKind::Emcy(_)))
        .unwrap()
        .clone();
    gateway.alarms.flush().await;
    gateway.shutdown().await;
    drop(gateway);

    // A new rack: the JMC's heartbeat is back, the UMC is hot again.
    let gateway = Gateway::start(with_dir(), &test_rig::rack).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let restored = gateway.alarms.open(None);
    assert_eq!(restored.len(), 3, "{restored:?}");
    assert!(restored.iter().all(|a| a.state.is_active()));
    // Its cause present again, the EMCY alarm stays the one it was.
    let rack_after = rack(&gateway, "line");
    rack_after
        .inject_fault(node(1), Fault::OverTemperature)
        .unwrap();
    tokio::time::sleep(service::RESTORE_SETTLE + Duration::from_secs(1)).await;
    let hot_now = gateway.alarms.book().get(hot.id).cloned().unwrap();
    assert_eq!(
        hot_now.state,
        AlarmState::ActiveUnacknowledged,
        "{hot_now:?}"
    );
    assert_eq!(hot_now.history.last().unwrap().step, AlarmStep::Restored);
    let lost_now = gateway.alarms.book().get(lost.id).cloned().unwrap();
    assert_eq!(lost_now.state, AlarmState::ClearedUnacknowledged);
    assert_eq!(open_of(&gateway, "heartbeat_lost").len(), 1);
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(start_paused = true)]
async fn enable_all_brings_back_the_axes_last_enabled_and_refuses_one_still_in_fault() {
    let gateway = started(config(&[("line", "virtual:demo")])).await;
    let alice = operator("alice");
    let rack = enabled_then_overheated(&gateway, &alice, &[("1", "1"), ("2", "1")]).await;
    let report = gateway.enable_machine(&alice, "line").await.unwrap();
    let outcomes: Vec<(u8, u8, RecoveryOutcome)> = report
        .axes
        .iter()
        .map(|a| (a.node, a.axis, a.outcome))
        .collect();
    assert_eq!(
        outcomes,
        [
            (1, 1, RecoveryOutcome::Refused),
            (2, 1, RecoveryOutcome::Done)
        ],
        "{report:?}"
    );
    assert_eq!(
        report.axes[0].reason.as_deref(),
        Some("the axis is in fault: reset the faults first")
    );
    // Its cause present, the reset is refused for that axis.
    let report = gateway.reset_machine_faults(&alice, "line").await.unwrap();
    let umc = report.axes.iter().find(|a| a.node == 1).unwrap();
    assert_eq!(umc.outcome, RecoveryOutcome::Refused, "{report:?}");
    assert!(
        umc.reason
            .as_deref()
            .unwrap()
            .starts_with("the cause is still present"),
        "{umc:?}"
    );
    // The cause gone: reset, then enable all, two operations.
    rack.clear_fault(node(1), Fault::OverTemperature).unwrap();
    gateway.reset_machine_faults(&alice, "line").await.unwrap();
    let report = gateway.enable_machine(&alice, "line").await.unwrap();
    assert!(
        report
            .axes
            .iter()
            .all(|a| a.outcome == RecoveryOutcome::Done
                && a.state.as_deref() == Some("operation_enabled")),
        "{report:?}"
    );
    let viewer = Caller::new(Channel::Rest, "vera", Some(Role::Viewer));
    assert!(matches!(
        gateway.enable_machine(&viewer, "line").await,
        Err(GatewayError::Forbidden(_))
    ));
    assert!(matches!(
        gateway.reset_machine_faults(&alice, "nope").await,
        Err(GatewayError::UnknownBus(_))
    ));
}

#[tokio::test(start_paused = true)]
async fn enable_all_takes_the_described_drive_s_axes_after_a_restart() {
    // The machine description expects node 1 (the UMC) started; node 2 is
    // described but left pre-operational, node 9 is not there.
    let mut described = config(&[("line", "virtual:demo")]);
    let mut idle = NodeDescription::new(node(2));
    idle.start = false;
    described.machine_nodes.insert(
        "line".to_string(),
        vec![
            NodeDescription::new(node(1)),
            idle,
            NodeDescription::new(node(9)),
        ],
    );
    let gateway = started(described).await;
    let alice = operator("alice");
    let rack = enabled_then_overheated(&gateway, &alice, &[("1", "1"), ("1", "2")]).await;
    rack.clear_fault(node(1), Fault::OverTemperature).unwrap();
    // As after a restart of the gateway: it enabled nothing in this run.
    gateway.enabled_axes.forget_node("line", 1);
    assert!(gateway.enabled_axes.axes_on("line").is_empty());
    let reset = gateway.reset_machine_faults(&alice, "line").await.unwrap();
    let umc: Vec<_> = reset.axes.iter().filter(|a| a.node == 1).collect();
    assert!(
        umc.len() == 2 && umc.iter().all(|a| a.outcome == RecoveryOutcome::Done),
        "{reset:?}"
    );
    let report = gateway.enable_machine(&alice, "line").await.unwrap();
    let enabled: Vec<(u8, u8, RecoveryOutcome, Option<&str>)> = report
        .axes
        .iter()
        .map(|a| (a.node, a.axis, a.outcome, a.state.as_deref()))
        .collect();
    assert_eq!(
        enabled,
        [
            (1, 1, RecoveryOutcome::Done, Some("operation_enabled")),
            (1, 2, RecoveryOutcome::Done, Some("operation_enabled")),
        ],
        "{report:?}"
    );
}
