//! The motion facade on the demo rack, no door in front: the chosen lease
//! ids, and the one motion authority per axis (a stop always wins over a
//! sequence running on the axis).

use std::time::Duration;

use super::*;
use crate::caller::Channel;
use crate::can::FrameReceiver;
use crate::canopen::nmt::NmtCommand;
use crate::registry::NodeEvent;
use crate::safe_stop::StopOutcome;
use crate::test_rig;

#[test]
fn a_chosen_lease_id_is_long_and_of_the_safe_set() {
    assert!(check_chosen_id("host-7f3a9c0e.axis_1~").is_ok());
    for bad in ["short-id", "sixteen chars!!!", "ÿ".repeat(16).as_str()] {
        let refused = check_chosen_id(bad).unwrap_err();
        assert_eq!(refused.code(), "invalid_request");
        assert!(refused.to_string().contains("16 to 128"), "{refused}");
    }
    assert!(check_chosen_id(&"a".repeat(129)).is_err());
}

const AXIS: (&str, &str, &str) = ("demo", "1", "1");

/// The gateway on the demo rack (no tokens, leases of 1 s), its nodes
/// identified, and axis 1 of the UMC (node 1) in operation enabled.
async fn enabled_demo() -> (Gateway, Caller) {
    let gateway = test_rig::started(test_rig::config(&[("demo", "virtual:demo")])).await;
    let caller = Caller::new(Channel::Rest, "anonymous", None);
    enable(&gateway, &caller, AXIS).await.unwrap();
    (gateway, caller)
}

/// `axis` put in operation enabled by `caller`, with the default claim.
async fn enable(
    gateway: &Gateway,
    caller: &Caller,
    axis: (&str, &str, &str),
) -> Result<MotionOutcome, MotionFailed> {
    test_rig::enable_axis(gateway, caller, axis, &LeaseClaim::default()).await
}

/// A velocity move at `velocity`.
fn velocity_move(velocity: i32) -> MoveRequest {
    serde_json::from_str(&format!(r#"{{"mode":"velocity","velocity":{velocity}}}"#)).unwrap()
}

/// [`AXIS`] in a velocity move of `caller`'s, under a lease, turning
/// 300 ms later; the lease.
async fn turning_under_lease(gateway: &Gateway, caller: &Caller) -> MotionLease {
    let moved = gateway
        .move_axis(caller, AXIS, &velocity_move(300), &LeaseClaim::default())
        .await
        .unwrap();
    let lease = moved.lease.expect("a velocity move is leased");
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert!(velocity(gateway).await > 0, "not turning");
    lease
}

/// The last `motion_ended` of `events` so far: node, axis, reason.
fn motion_ended(
    events: &mut tokio::sync::broadcast::Receiver<NodeEvent>,
) -> Option<(u8, u8, &'static str)> {
    let mut told = None;
    while let Ok(event) = events.try_recv() {
        if let NodeEvent::MotionEnded { axis, reason, .. } = event {
            told = Some((event.node().get(), axis, reason));
        }
    }
    told
}

/// Node 1's (the UMC's) SDO channel.
fn umc_sdo(gateway: &Gateway) -> crate::SdoChannel {
    gateway
        .bus("demo")
        .unwrap()
        .registry
        .sdo(crate::canopen::NodeId::new(1).unwrap())
        .unwrap()
}

/// The text fields `names` of each audit row (an absent one as "", which
/// no expected word is).
fn words<'a, const N: usize>(
    rows: &'a [serde_json::Map<String, serde_json::Value>],
    names: [&str; N],
) -> Vec<[&'a str; N]> {
    rows.iter()
        .map(|row| names.map(|name| row.get(name).and_then(|v| v.as_str()).unwrap_or("")))
        .collect()
}

/// A halt of [`AXIS`] by `caller`, and the step test `test` it ends:
/// failed.
async fn halt_ends(
    gateway: &Gateway,
    caller: &Caller,
    test: tokio::task::JoinHandle<Result<MotionOutcome<StepTestResult>, MotionFailed>>,
) {
    gateway
        .set_axis_halt(caller, AXIS, true, &LeaseClaim::default())
        .await
        .unwrap();
    let ended = test.await.unwrap();
    assert!(ended.is_err(), "the halt ended the test");
}

fn step_request() -> StepTestRequest {
    serde_json::from_str(r#"{"loop":"velocity","from":0,"to":3000,"hold_ms":3000}"#).unwrap()
}

/// The axis's velocity as the drive reports it.
async fn velocity(gateway: &Gateway) -> i64 {
    let drive = gateway.drive("demo", "1", "1").unwrap();
    i64::from(drive.status().await.unwrap().velocity.unwrap())
}

/// The SDO downloads to node 1's axis-1 controlword (0x6040) or VL target
/// (0x6042) seen since the last call: what sets the axis moving.
fn motion_writes(frames: &mut FrameReceiver) -> Vec<String> {
    let mut writes = Vec::new();
    while let Ok(Some(frame)) = frames.try_recv() {
        let data = frame.frame.data();
        if frame.frame.id().raw() != 0x601 || data.len() < 4 {
            continue;
        }
        let download = data[0] & 0xE0 == 0x20;
        let index = u16::from_le_bytes([data[1], data[2]]);
        if download && matches!(index, 0x6040 | 0x6042) {
            writes.push(format!("0x{index:04X} {data:02X?}"));
        }
    }
    writes
}

/// The step test of [`step_request`] on [`AXIS`], run as a client's
/// request would be: in a task of its own, which the test can abort.
fn spawn_step_test(
    gateway: &Gateway,
    caller: &Caller,
) -> tokio::task::JoinHandle<Result<MotionOutcome<StepTestResult>, MotionFailed>> {
    let (gateway, caller) = (gateway.clone(), caller.clone());
    tokio::spawn(async move {
        gateway
            .step_test_axis(&caller, AXIS, &step_request(), &LeaseClaim::default())
            .await
    })
}

/// Issue 30, finding 1: a halt answered "confirmed" while a step test held
/// its first level was undone when the test sent its step 2 s later (the
/// axis ran for the rest of the hold). The halt ends the test now, and no
/// step is sent after it.
#[tokio::test(start_paused = true)]
async fn a_confirmed_halt_ends_a_running_step_test_and_no_later_step_is_sent() {
    let (gateway, caller) = enabled_demo().await;
    let test = spawn_step_test(&gateway, &caller);
    tokio::time::sleep(Duration::from_secs(1)).await;
    let halted = gateway
        .set_axis_halt(&caller, AXIS, true, &LeaseClaim::default())
        .await
        .unwrap();
    let attempts = halted.attempts.unwrap();
    assert_eq!(attempts[0].outcome, StopOutcome::Confirmed, "{attempts:?}");
    let mut frames = gateway.bus("demo").unwrap().monitor();

    // Where the step would have come (t = 3 s) and after it, the axis
    // stays halted, and nothing set it moving again.
    for _ in 0..6 {
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert_eq!(velocity(&gateway).await, 0, "moving after a confirmed halt");
    }
    assert_eq!(motion_writes(&mut frames), Vec::<String>::new());
    // The test ended with the stop (not at the end of its hold).
    assert!(test.is_finished(), "the step test still runs");
    let failed = test.await.unwrap().unwrap_err();
    assert_eq!(failed.error.code(), "motion_stopped", "{}", failed.error);
    assert_eq!(gateway.leases_held(), 0);
}

/// Issue 30, finding 5 (the step test part): a step test whose client goes
/// away (its request dropped) went on to send its step and ran the axis
/// for the rest of the hold. Its lease lapses at once, which stops the
/// axis and ends the test: no later step is sent.
#[tokio::test(start_paused = true)]
async fn a_step_test_whose_client_goes_away_stops_and_sends_no_later_step() {
    let (gateway, caller) = enabled_demo().await;
    let test = spawn_step_test(&gateway, &caller);
    tokio::time::sleep(Duration::from_secs(1)).await;
    // The client hangs up: its request future is dropped.
    test.abort();
    let _ = test.await;
    // The lapse's halt goes out at once.
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut frames = gateway.bus("demo").unwrap().monitor();
    for _ in 0..8 {
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert_eq!(velocity(&gateway).await, 0, "moving without its client");
    }
    assert_eq!(motion_writes(&mut frames), Vec::<String>::new());
    let rows = crate::audit::tests::rows(&gateway).await;
    assert!(
        rows.iter()
            .any(|row| row["operation"] == "motion lease lapsed: axis halted"),
        "{rows:?}"
    );
}

/// A move admitted before a stop of its axis, whose transfers had not
/// begun when the stop came, is not sent after it: `motion_stopped`.
#[tokio::test(start_paused = true)]
async fn a_command_admitted_before_a_stop_is_not_sent_after_it() {
    let (gateway, _caller) = enabled_demo().await;
    let axis = AxisKey {
        bus: "demo".into(),
        node: 1,
        axis: 1,
    };
    let ticket = gateway.authority.ticket(&axis).unwrap();
    gateway.halt_axis("demo", "1", "1").await.unwrap();
    let mut frames = gateway.bus("demo").unwrap().monitor();
    let drive = gateway.drive("demo", "1", "1").unwrap();
    let refused = ticket
        .send(drive.run_move(&velocity_move(500)))
        .await
        .unwrap_err();
    assert_eq!(refused.code(), "motion_stopped", "{refused}");
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(motion_writes(&mut frames), Vec::<String>::new());
}

/// The LSS address of node `id` of the demo bus, from its identity.
fn lss_address(gateway: &Gateway, id: &str) -> crate::canopen::lss::LssAddress {
    let (_, info) = gateway.node("demo", id).unwrap();
    let identity = info.identity.unwrap();
    crate::canopen::lss::LssAddress {
        vendor_id: identity.vendor_id,
        product_code: identity.product_code.unwrap(),
        revision: identity.revision.unwrap(),
        serial: identity.serial.unwrap(),
    }
}

/// Issue 30, finding 2: an admin renumbered by LSS a drive in a leased
/// velocity move; when the lease lapsed, the supervisor halted the old
/// node-ID, where nothing answered, and the drive kept turning. Now the
/// axis is stopped and its lease ended before the device takes its new
/// number (an audit row and a `motion_ended` event say so), and nothing
/// is left to address the old one.
#[tokio::test(start_paused = true)]
async fn a_drive_renumbered_by_lss_in_a_leased_move_is_stopped_at_its_new_id() {
    let (gateway, caller) = enabled_demo().await;
    turning_under_lease(&gateway, &caller).await;
    let mut events = gateway.bus("demo").unwrap().registry.subscribe();

    let admin = Caller::new(Channel::Rest, "admin", Some(crate::access::Role::Admin));
    let address = lss_address(&gateway, "1");
    let moved = gateway
        .lss_configure(&admin, "demo", address, 9, false)
        .await
        .unwrap();
    assert_eq!(moved.id.get(), 9);

    // Well past the lease's lapse (1 s), the drive, at its new ID, is at
    // rest.
    tokio::time::sleep(Duration::from_secs(4)).await;
    let drive = gateway.drive("demo", "9", "1").unwrap();
    let status = drive.status().await.unwrap();
    assert_eq!(status.velocity, Some(0), "{status:?}");
    assert_ne!(status.state, "operation_enabled", "{status:?}");
    assert_eq!(gateway.leases_held(), 0);
    // The old number is forgotten: no stop is addressed there.
    assert!(gateway.node("demo", "1").is_err());
    assert!(gateway.enabled_axes.on_node("demo", 1).is_empty());

    assert_eq!(motion_ended(&mut events), Some((1, 1, "node_id_changed")));
    let rows = crate::audit::tests::rows(&gateway).await;
    let row = rows
        .iter()
        .find(|row| row["operation"] == "motion ended: node renumbered")
        .unwrap_or_else(|| panic!("{rows:#?}"));
    assert_eq!(row["node"], 1);
    assert_eq!(row["axis"], 1);
    assert!(
        row["item"].as_str().unwrap().contains("velocity lease"),
        "{row:?}"
    );
}

/// Issue 30: a raw OD write of the UMC's node-ID (0x2040 sub 1) followed by
/// an NMT reset went past the renumbering rule: the leased move went on
/// through the write, and the old node-ID stayed listed and supervised
/// where nothing answered. Now the write is a renumbering as the node-ID
/// route's: the gateway's own node-ID is refused, the axis is stopped and
/// its lease ended before the write goes out, the node takes no motion
/// command until its reset (`node_busy`), and after the reset the old
/// node-ID is forgotten.
#[tokio::test(start_paused = true)]
async fn an_od_write_of_the_node_id_then_a_reset_is_a_renumbering() {
    let (gateway, caller) = enabled_demo().await;
    turning_under_lease(&gateway, &caller).await;
    let mut events = gateway.bus("demo").unwrap().registry.subscribe();

    let operator = test_rig::operator("op");
    let node = gateway.node_handle("demo", "1").unwrap();
    let manager = gateway
        .bus("demo")
        .unwrap()
        .machine
        .as_ref()
        .unwrap()
        .manager()
        .node_id;
    let refused = node
        .write_object(&operator, 0x2040, 1, vec![manager.get()])
        .await
        .unwrap_err();
    assert_eq!(refused.code(), "node_id_in_use", "{refused}");
    node.write_object(&operator, 0x2040, 1, vec![9])
        .await
        .unwrap();

    // Stopped before the write went out: no lease left, the axis at rest.
    assert_eq!(gateway.leases_held(), 0);
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(velocity(&gateway).await, 0);
    assert_eq!(motion_ended(&mut events), Some((1, 1, "node_id_changed")));
    // Until its reset, the node takes no motion command.
    let busy = enable(&gateway, &caller, AXIS).await.unwrap_err().error;
    assert_eq!(busy.code(), "node_busy", "{busy}");

    // Stored (in pre-operational, as UniSwarm wants), then reset: the
    // device is at 9, and 1 is forgotten.
    node.nmt(&operator, NmtCommand::EnterPreOperational)
        .await
        .unwrap();
    node.write_object(&operator, 0x1010, 4, b"save".to_vec())
        .await
        .unwrap();
    node.nmt(&operator, NmtCommand::ResetNode).await.unwrap();
    assert!(gateway.node("demo", "9").is_ok());
    assert!(
        gateway.node("demo", "1").is_err(),
        "the old node-ID is listed still"
    );
    assert!(gateway.enabled_axes.on_node("demo", 1).is_empty());
    // The device at its new number takes motion commands again.
    enable(&gateway, &caller, ("demo", "9", "1")).await.unwrap();
}

/// Writing a node's own node-ID to 0x2040 is no renumbering, and ends one
/// pending: the node takes motion commands again.
#[tokio::test(start_paused = true)]
async fn writing_its_own_node_id_back_ends_a_pending_renumbering() {
    let (gateway, caller) = enabled_demo().await;
    let operator = test_rig::operator("op");
    let node = gateway.node_handle("demo", "1").unwrap();
    node.write_object(&operator, 0x2040, 1, vec![9])
        .await
        .unwrap();
    let busy = enable(&gateway, &caller, AXIS).await.unwrap_err().error;
    assert_eq!(busy.code(), "node_busy", "{busy}");
    node.write_object(&operator, 0x2040, 1, vec![1])
        .await
        .unwrap();
    enable(&gateway, &caller, AXIS).await.unwrap();
    let refused = node
        .write_object(&operator, 0x2040, 1, vec![9, 0])
        .await
        .unwrap_err();
    assert_eq!(refused.code(), "invalid_value", "{refused}");
}

/// An OD write (CiA 309-3 and -5, REST's object route: one operation)
/// to a leased axis's controlword or target went past the lease. Now a
/// command from a caller who does not hold the lease is refused, and a
/// stop in the controlword (halt) is taken from anyone and ends the lease,
/// as a halt does.
#[tokio::test(start_paused = true)]
async fn an_od_write_to_a_leased_axis_is_held_to_the_lease_but_a_stop_always_goes() {
    let (gateway, _) = enabled_demo().await;
    let plc = test_rig::operator("plc");
    let lease = turning_under_lease(&gateway, &plc).await;
    gateway
        .renew_axis_lease(&plc, &lease.axis, &lease.id)
        .await
        .unwrap();

    let other = Caller::new(
        Channel::Cia309_3,
        "other",
        Some(crate::access::Role::Operator),
    );
    let umc = gateway.node_handle("demo", "1").unwrap();
    let mut frames = gateway.bus("demo").unwrap().monitor();
    for (index, bytes) in [
        // Enable operation with a new set-point, a faster target, another
        // mode.
        (0x6040, 0x001Fu16.to_le_bytes().to_vec()),
        (0x6042, 3000i16.to_le_bytes().to_vec()),
        (0x6060, vec![1]),
    ] {
        let refused = umc.write_object(&other, index, 0, bytes).await.unwrap_err();
        assert_eq!(refused.code(), "lease_conflict", "0x{index:04X}: {refused}");
    }
    assert_eq!(motion_writes(&mut frames), Vec::<String>::new());
    assert!(velocity(&gateway).await > 0);

    // A halt in the controlword is a stop: anyone's, and the lease ends.
    umc.write_object(&other, 0x6040, 0, 0x010Fu16.to_le_bytes().to_vec())
        .await
        .unwrap();
    assert_eq!(gateway.leases_held(), 0);
    let refused = gateway
        .renew_axis_lease(&plc, &lease.axis, &lease.id)
        .await
        .unwrap_err();
    assert_eq!(refused.code(), "unknown_lease");
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(velocity(&gateway).await, 0);
    // On a free axis the controlword is anyone's (with the operator's
    // role): halt released.
    umc.write_object(&other, 0x6040, 0, 0x000Fu16.to_le_bytes().to_vec())
        .await
        .unwrap();
}

/// Issue 32, "Tuning does not show the loop": the ramps a step test lifts
/// (VL's 0x6048 and 0x6049 here) are put back when a halt ends the test
/// half-way, and both the lift and the restore are rows of the audit log
/// (the gateway's, on the axis, naming each value), besides the caller's
/// own `step test` row.
#[tokio::test(start_paused = true)]
async fn a_halted_step_test_puts_its_ramps_back_and_says_so() {
    let (gateway, caller) = enabled_demo().await;
    let sdo = umc_sdo(&gateway);
    let ramp = || async {
        let mut values = Vec::new();
        for (index, sub) in [(0x6048, 1), (0x6048, 2), (0x6049, 1), (0x6049, 2)] {
            values.push(sdo.upload(index, sub).await.unwrap());
        }
        values
    };
    let before = ramp().await;
    let test = spawn_step_test(&gateway, &caller);
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert_ne!(ramp().await, before, "lifted during the test");
    halt_ends(&gateway, &caller, test).await;
    assert_eq!(ramp().await, before, "put back");
    let rows = crate::audit::tests::rows_where(&gateway, 2, |row| {
        row["operation"]
            .as_str()
            .is_some_and(|operation| operation.starts_with("step test: set-point shaping"))
    })
    .await;
    assert_eq!(
        words(&rows, ["operation", "who", "request"]),
        [
            [
                "step test: set-point shaping lifted",
                "gateway",
                "0x6048.1 = 3000, 0x6048.2 = 1, 0x6049.1 = 3000, 0x6049.2 = 1"
            ],
            [
                "step test: set-point shaping restored",
                "gateway",
                "0x6048.1 = 1, 0x6048.2 = 1, 0x6049.1 = 1, 0x6049.2 = 1"
            ],
        ],
        "{rows:#?}"
    );
    assert!(
        rows.iter().all(|row| row["node"] == 1 && row["axis"] == 1),
        "{rows:#?}"
    );
}

/// Node 1's TPDO parameters as they read: 0x1800-0x1803 subs 1, 2, 3, 5,
/// 6 and 0x1A00-0x1A03 subs 0 to 8.
async fn tpdo_parameters(gateway: &Gateway) -> Vec<(u16, u8, Vec<u8>)> {
    let sdo = umc_sdo(gateway);
    let mut values = Vec::new();
    for number in 0..4u16 {
        for (index, subs) in [
            (0x1800 + number, &[1u8, 2, 3, 5, 6][..]),
            (0x1A00 + number, &[0, 1, 2, 3, 4, 5, 6, 7, 8]),
        ] {
            for &sub in subs {
                values.push((index, sub, sdo.upload(index, sub).await.unwrap()));
            }
        }
    }
    values
}

/// Issue 32, "samples come at the loop's rate from a TPDO": the step test
/// sets up a TPDO of its own on an operational node (the UMC has no free
/// one: its last, TPDO 4, borrowed: 0x6044 every millisecond), and puts
/// its mapping and communication parameters back when a halt ends the
/// test half-way; both are the gateway's `configure pdo` rows.
#[tokio::test(start_paused = true)]
async fn a_halted_step_test_puts_its_sampling_tpdo_back_and_says_so() {
    let (gateway, caller) = enabled_demo().await;
    let node = gateway.node_handle("demo", "1").unwrap();
    node.nmt(&caller, NmtCommand::Start).await.unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let before = tpdo_parameters(&gateway).await;
    let values = gateway.bus("demo").unwrap().values.clone();
    let test = spawn_step_test(&gateway, &caller);
    tokio::time::sleep(Duration::from_secs(1)).await;
    let during = values
        .value(crate::canopen::NodeId::new(1).unwrap(), 0x6044, 0)
        .expect("0x6044 in a TPDO during the test");
    assert_eq!(during.pdo, 4, "{during:?}");
    assert_ne!(tpdo_parameters(&gateway).await, before, "TPDO 4 set up");
    halt_ends(&gateway, &caller, test).await;
    assert_eq!(tpdo_parameters(&gateway).await, before, "put back");
    let rows = crate::audit::tests::rows_where(&gateway, 2, |row| {
        row["operation"] == "configure pdo" && row["who"] == "gateway"
    })
    .await;
    assert_eq!(
        words(&rows, ["item", "request"]),
        [
            [
                "tpdo 4",
                "step test sampling: 0x6044 every 1 ms (borrowed, put back after the test)"
            ],
            [
                "tpdo 4",
                "step test sampling over: TPDO 4 put back as before the test"
            ],
        ],
        "{rows:#?}"
    );
    assert!(rows.iter().all(|row| row["outcome"] == "ok"), "{rows:#?}");
}
