use std::sync::{Arc, Mutex};

use super::*;
use crate::can::{Bus, VirtualHub};
use crate::canopen::NodeId;
use crate::canopen::eds::Eds;
use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtState, NmtTarget};
use crate::canopen::od::{AccessType, DataType, ObjectDictionary, SubObject};
use crate::canopen::sdo::ClientConfig;
use crate::device::{DeviceCore, run_device};
use crate::profiles::builtin::JMC_STEPPER;
use candeck_gateway::SdoChannel;

const SYNC: CanId = CanId::Standard(0x080);
const TPDO1: CanId = CanId::Standard(0x185);
const TPDO2: CanId = CanId::Standard(0x285);
const RPDO1: CanId = CanId::Standard(0x205);

fn node() -> NodeId {
    NodeId::new(5).unwrap()
}

fn ms(ms: u64) -> Duration {
    Duration::from_millis(ms)
}

/// The JMC dictionary, with inhibit time and event timer on TPDO2.
fn jmc() -> ObjectDictionary {
    let mut dictionary = Eds::parse(JMC_STEPPER, "jmc.eds").unwrap().dictionary;
    let tpdo2 = dictionary.get_mut(0x1801).unwrap();
    tpdo2.insert_sub(SubObject::new(
        3,
        "Inhibit time",
        DataType::Unsigned16,
        AccessType::Rw,
    ));
    tpdo2.insert_sub(SubObject::new(
        5,
        "Event timer",
        DataType::Unsigned16,
        AccessType::Rw,
    ));
    dictionary
}

fn sync() -> Frame {
    Frame::new(SYNC, &[]).unwrap()
}

fn nmt(command: NmtCommand) -> Frame {
    NmtMessage::new(command, NmtTarget::Node(node())).encode()
}

/// A booted device, and the clock it runs on.
fn device() -> (DeviceCore, Instant) {
    let mut device = DeviceCore::new(jmc(), node()).unwrap();
    let start = Instant::now();
    device.boot(start);
    (device, start)
}

fn on(frames: &[Frame], id: CanId) -> Vec<Vec<u8>> {
    frames
        .iter()
        .filter(|frame| frame.id() == id)
        .map(|frame| frame.data().to_vec())
        .collect()
}

/// Runs the device's timers from `from` to `to` in 1 ms steps; the frames
/// on `id` with the ms they went at.
fn run(device: &mut DeviceCore, from: Instant, to: Instant, id: CanId) -> Vec<u128> {
    let mut sent = Vec::new();
    let mut now = from;
    while now <= to {
        if device.deadline().is_some_and(|deadline| deadline <= now) {
            for frame in device.poll(now) {
                if frame.id() == id {
                    sent.push(now.duration_since(from).as_millis());
                }
            }
        }
        now += ms(1);
    }
    sent
}

/// Configures TPDO2 as event-driven with `inhibit` (100 µs) and `timer`
/// (ms), through the dictionary as a configuration tool would.
fn event_driven(device: &mut DeviceCore, inhibit: u16, timer: u16, now: Instant) {
    let store = device.store_mut();
    store.set(0x1801, 2, Value::Unsigned8(255)).unwrap();
    store.set(0x1801, 3, Value::Unsigned16(inhibit)).unwrap();
    store.set(0x1801, 5, Value::Unsigned16(timer)).unwrap();
    device.pdo_parameters_changed(now);
}

#[test]
fn tpdo1_goes_on_every_sync_once_operational_and_not_before() {
    let (mut device, now) = device();
    assert!(on(&device.handle_frame(&sync(), now), TPDO1).is_empty());
    device.handle_frame(&nmt(NmtCommand::Start), now);
    assert_eq!(device.nmt_state(), NmtState::Operational);
    device
        .store_mut()
        .set(0x6041, 0, Value::Unsigned16(0x0237))
        .unwrap();
    device
        .store_mut()
        .set(0x6064, 0, Value::Integer32(-2))
        .unwrap();
    for _ in 0..3 {
        let out = device.handle_frame(&sync(), now);
        assert_eq!(
            on(&out, TPDO1),
            vec![vec![0x37, 0x02, 0xFE, 0xFF, 0xFF, 0xFF]]
        );
    }
    device.handle_frame(&nmt(NmtCommand::Stop), now);
    assert!(on(&device.handle_frame(&sync(), now), TPDO1).is_empty());
}

#[test]
fn an_event_timer_tpdo_repeats_at_its_period() {
    let (mut device, start) = device();
    event_driven(&mut device, 0, 100, start);
    device.handle_frame(&nmt(NmtCommand::Start), start);
    let sent = run(&mut device, start, start + ms(350), TPDO2);
    // Once on entering operational, then every 100 ms.
    assert_eq!(sent, vec![0, 100, 200, 300]);
}

#[test]
fn a_change_of_state_sends_within_the_inhibit_time() {
    let (mut device, start) = device();
    // 50 ms inhibit time, no event timer.
    event_driven(&mut device, 500, 0, start);
    device.handle_frame(&nmt(NmtCommand::Start), start);
    assert_eq!(run(&mut device, start, start + ms(20), TPDO2), vec![0]);
    // Nothing changes, nothing goes.
    assert!(run(&mut device, start + ms(21), start + ms(200), TPDO2).is_empty());
    // TPDO2 maps 0x606C, velocity actual value (JMC default 0x1A01).
    let from = start + ms(201);
    device
        .store_mut()
        .set(0x606C, 0, Value::Integer32(1))
        .unwrap();
    // Changes are looked for every CHANGE_SCAN, the device's cycle.
    let sent = run(&mut device, from, from + CHANGE_SCAN, TPDO2);
    assert_eq!(sent.len(), 1, "{sent:?}");
    // A second change at once waits for the inhibit time.
    let sent_at = from + ms(sent[0] as u64);
    device
        .store_mut()
        .set(0x606C, 0, Value::Integer32(2))
        .unwrap();
    let again = run(&mut device, sent_at + ms(1), sent_at + ms(100), TPDO2);
    assert_eq!(again.len(), 1, "{again:?}");
    assert!(again[0] + 1 >= 50, "{again:?}");
}

#[test]
fn an_rpdo_writes_its_objects_and_a_short_one_does_not() {
    let (mut device, now) = device();
    // Not before operational.
    let frame = Frame::new(RPDO1, &[0x10, 0, 0, 0, 0x20, 0, 0x30, 0]).unwrap();
    device.handle_frame(&frame, now);
    assert_eq!(device.store().get(0x6081, 0), Some(&Value::Integer32(0)));
    device.handle_frame(&nmt(NmtCommand::Start), now);
    device.handle_frame(&frame, now);
    // 0x1600: 0x6081 (32), 0x6083 (16), 0x6084 (16).
    assert_eq!(device.store().get(0x6081, 0), Some(&Value::Integer32(0x10)));
    assert_eq!(
        device.store().get(0x6083, 0),
        Some(&Value::Unsigned16(0x20))
    );
    let short = Frame::new(RPDO1, &[0x99, 0, 0, 0, 0x20]).unwrap();
    device.handle_frame(&short, now);
    assert_eq!(device.store().get(0x6081, 0), Some(&Value::Integer32(0x10)));
}

#[test]
fn a_sync_rpdo_is_applied_at_the_next_sync() {
    let (mut device, now) = device();
    device
        .store_mut()
        .set(0x1400, 2, Value::Unsigned8(1))
        .unwrap();
    device.pdo_parameters_changed(now);
    device.handle_frame(&nmt(NmtCommand::Start), now);
    let frame = Frame::new(RPDO1, &[7, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    device.handle_frame(&frame, now);
    assert_eq!(device.store().get(0x6081, 0), Some(&Value::Integer32(0)));
    device.handle_frame(&sync(), now);
    assert_eq!(device.store().get(0x6081, 0), Some(&Value::Integer32(7)));
}

#[test]
fn a_remote_frame_asks_for_an_rtr_tpdo() {
    let (mut device, now) = device();
    device
        .store_mut()
        .set(0x1800, 2, Value::Unsigned8(253))
        .unwrap();
    device.pdo_parameters_changed(now);
    device.handle_frame(&nmt(NmtCommand::Start), now);
    assert!(on(&device.handle_frame(&sync(), now), TPDO1).is_empty());
    let rtr = Frame::remote(TPDO1, 6).unwrap();
    assert_eq!(on(&device.handle_frame(&rtr, now), TPDO1).len(), 1);
}

async fn send_nmt(master: &Bus, command: NmtCommand) {
    master.send(nmt(command)).await.unwrap();
    tokio::time::sleep(ms(1)).await;
}

#[tokio::test(start_paused = true)]
async fn remapping_through_sdo_follows_cia_301() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let device = Arc::new(Mutex::new(DeviceCore::new(jmc(), node()).unwrap()));
    let task = tokio::spawn(run_device(hub.attach(), device.clone()));
    let config = ClientConfig {
        timeout: ms(200),
        ..ClientConfig::default()
    };
    let sdo = SdoChannel::new(master.clone(), node(), config);
    let abort = |code: u32| Some(AbortCode::from_raw(code));
    // While TPDO1 is valid, neither entries nor sub 0 may change.
    let refused = sdo.download(0x1A00, 1, &0x6064_0020u32.to_le_bytes()).await;
    assert_eq!(refused.unwrap_err().device_abort(), abort(0x0604_0043));
    let refused = sdo.download(0x1A00, 0, &[0]).await;
    assert_eq!(refused.unwrap_err().device_abort(), abort(0x0604_0043));
    // 1. Invalidate; 2. sub 0 = 0.
    sdo.download(0x1800, 1, &0x8000_0185u32.to_le_bytes())
        .await
        .unwrap();
    sdo.download(0x1A00, 0, &[0]).await.unwrap();
    // 3. Entries: not one that does not exist, nor one not mappable.
    let refused = sdo.download(0x1A00, 1, &0x3FFF_0010u32.to_le_bytes()).await;
    assert_eq!(refused.unwrap_err().device_abort(), abort(0x0602_0000));
    let refused = sdo.download(0x1A00, 1, &0x1017_0010u32.to_le_bytes()).await;
    assert_eq!(refused.unwrap_err().device_abort(), abort(0x0604_0041));
    sdo.download(0x1A00, 1, &0x6064_0020u32.to_le_bytes())
        .await
        .unwrap();
    sdo.download(0x1A00, 2, &0x6041_0010u32.to_le_bytes())
        .await
        .unwrap();
    sdo.download(0x1A00, 3, &0x6064_0020u32.to_le_bytes())
        .await
        .unwrap();
    // 4. Sub 0: three entries are 80 bits, too many; two are fine.
    let refused = sdo.download(0x1A00, 0, &[3]).await;
    assert_eq!(refused.unwrap_err().device_abort(), abort(0x0604_0042));
    sdo.download(0x1A00, 0, &[2]).await.unwrap();
    // With sub 0 set, entries are fixed again.
    let refused = sdo.download(0x1A00, 3, &0u32.to_le_bytes()).await;
    assert_eq!(refused.unwrap_err().device_abort(), abort(0x0604_0043));
    // 5. Validate.
    sdo.download(0x1800, 1, &0x0000_0185u32.to_le_bytes())
        .await
        .unwrap();
    {
        let mut device = device.lock().unwrap();
        let store = device.store_mut();
        store.set(0x6064, 0, Value::Integer32(0x0102_0304)).unwrap();
        store.set(0x6041, 0, Value::Unsigned16(0x0506)).unwrap();
    }
    let mut frames = master.subscribe();
    send_nmt(&master, NmtCommand::Start).await;
    master.send(sync()).await.unwrap();
    let tpdo = loop {
        let frame = frames.recv().await.unwrap().frame;
        if frame.id() == TPDO1 {
            break frame;
        }
    };
    assert_eq!(tpdo.data(), &[4, 3, 2, 1, 6, 5]);
    task.abort();
}

#[test]
fn a_cob_id_is_not_made_valid_over_an_invalid_mapping() {
    let (mut device, _) = device();
    let store = device.store_mut();
    store
        .set(0x1800, 1, Value::Unsigned32(0x8000_0185))
        .unwrap();
    // 0x1017 is not mappable; as if the factory mapping were wrong.
    store
        .set(0x1A00, 1, Value::Unsigned32(0x1017_0010))
        .unwrap();
    assert_eq!(
        check_write(
            store,
            0x1800,
            1,
            Some(&0x185u32.to_le_bytes()),
            PdoRules::Cia301
        ),
        Err(AbortCode::ParameterIncompatible)
    );
    store.set(0x1A00, 0, Value::Unsigned8(9)).unwrap();
    assert_eq!(
        check_write(
            store,
            0x1800,
            1,
            Some(&0x185u32.to_le_bytes()),
            PdoRules::Cia301
        ),
        Err(AbortCode::ParameterIncompatible)
    );
}

/// The step test's sampling TPDO on a virtual UMC (issue 32): TPDO 4
/// re-mapped over SDO while the node is operational (CiA 301 §7.2.2.3:
/// invalidate, map, set the event-driven type 255 and a 1 ms event timer,
/// validate) goes every millisecond on a 500 kbit/s bus, carrying 0x6044.
#[tokio::test(start_paused = true)]
async fn the_virtual_umc_honours_a_one_millisecond_event_timer() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let node = NodeId::new(1).unwrap();
    let core = crate::products::Product::Umc1bds32.device(node).unwrap();
    let device = Arc::new(Mutex::new(core));
    let task = tokio::spawn(run_device(hub.attach(), device.clone()));
    tokio::time::sleep(ms(10)).await;
    send_nmt_to(&master, node, NmtCommand::Start).await;
    let sdo = SdoChannel::new(master.clone(), node, ClientConfig::default());
    let tpdo4 = CanId::Standard(0x481);
    let write = async |index: u16, sub: u8, bytes: &[u8]| {
        sdo.download(index, sub, bytes).await.unwrap();
    };
    write(0x1803, 1, &0x8000_0481u32.to_le_bytes()).await;
    write(0x1A03, 0, &[0]).await;
    write(0x1A03, 1, &0x6044_0010u32.to_le_bytes()).await;
    write(0x1A03, 0, &[1]).await;
    write(0x1803, 2, &[255]).await;
    write(0x1803, 3, &0u16.to_le_bytes()).await;
    write(0x1803, 5, &1u16.to_le_bytes()).await;
    let mut frames = master.subscribe();
    write(0x1803, 1, &0x0000_0481u32.to_le_bytes()).await;
    let from = tokio::time::Instant::now();
    let mut times = Vec::new();
    while from.elapsed() < ms(100) {
        let frame = frames.recv().await.unwrap().frame;
        if frame.id() == tpdo4 {
            assert_eq!(frame.data().len(), 2, "0x6044 alone: 16 bits");
            times.push(from.elapsed());
        }
    }
    assert!((98..=101).contains(&times.len()), "{} frames", times.len());
    for pair in times.windows(2) {
        let gap = pair[1] - pair[0];
        assert!(
            gap >= Duration::from_micros(900) && gap <= Duration::from_micros(1100),
            "{gap:?}"
        );
    }
    task.abort();
}

async fn send_nmt_to(master: &Bus, node: NodeId, command: NmtCommand) {
    let frame = NmtMessage::new(command, NmtTarget::Node(node)).encode();
    master.send(frame).await.unwrap();
    tokio::time::sleep(ms(1)).await;
}
