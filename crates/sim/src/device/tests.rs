use std::time::Duration;

use super::*;
use crate::can::VirtualHub;
use crate::canopen::eds::Eds;
use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};
use crate::canopen::sdo::{ClientConfig, SdoError};
use candeck_gateway::{SdoChannel, SdoRequestError};

fn node() -> NodeId {
    NodeId::new(5).unwrap()
}

fn testnode() -> ObjectDictionary {
    let text = include_str!("../../../../tests/data/testnode.eds");
    Eds::parse(text, "testnode.eds").unwrap().dictionary
}

struct Rig {
    hub: VirtualHub,
    master: Bus,
    device: Arc<Mutex<DeviceCore>>,
    sdo: SdoChannel,
    task: tokio::task::JoinHandle<()>,
}

fn rig() -> Rig {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let device = Arc::new(Mutex::new(DeviceCore::new(testnode(), node()).unwrap()));
    let task = tokio::spawn(run_device(hub.attach(), device.clone()));
    let config = ClientConfig {
        timeout: Duration::from_millis(200),
        ..ClientConfig::default()
    };
    let sdo = SdoChannel::new(master.clone(), node(), config);
    Rig {
        hub,
        master,
        device,
        sdo,
        task,
    }
}

async fn nmt(master: &Bus, command: NmtCommand) {
    let frame = NmtMessage::new(command, NmtTarget::Node(node())).encode();
    master.send(frame).await.unwrap();
    tokio::time::sleep(Duration::from_millis(1)).await;
}

#[tokio::test(start_paused = true)]
async fn a_device_boots_then_answers_sdo_in_pre_operational() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let mut frames = master.subscribe();
    let device = Arc::new(Mutex::new(DeviceCore::new(testnode(), node()).unwrap()));
    let task = tokio::spawn(run_device(hub.attach(), device.clone()));
    let boot_up = frames.recv().await.unwrap().frame;
    assert_eq!(
        (boot_up.id(), boot_up.data()),
        (CanId::Standard(0x705), &[0u8][..])
    );
    assert_eq!(lock(&device).nmt_state(), NmtState::PreOperational);
    let sdo = SdoChannel::new(master.clone(), node(), ClientConfig::default());
    assert_eq!(
        sdo.upload(0x1018, 1).await.unwrap(),
        0x00C4_DEC0u32.to_le_bytes()
    );
    task.abort();
}

#[tokio::test(start_paused = true)]
async fn a_stopped_device_does_not_answer_sdo_until_started() {
    let rig = rig();
    nmt(&rig.master, NmtCommand::Stop).await;
    assert_eq!(lock(&rig.device).nmt_state(), NmtState::Stopped);
    let error = rig.sdo.upload(0x2001, 0).await.unwrap_err();
    assert!(
        matches!(
            error,
            SdoRequestError::Sdo {
                error: SdoError::Timeout,
                ..
            }
        ),
        "{error:?}"
    );
    nmt(&rig.master, NmtCommand::Start).await;
    assert_eq!(lock(&rig.device).nmt_state(), NmtState::Operational);
    assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![7]);
    rig.task.abort();
}

#[tokio::test(start_paused = true)]
async fn the_heartbeat_follows_0x1017_with_the_nmt_state() {
    let rig = rig();
    let mut frames = rig.master.subscribe();
    rig.sdo
        .download(0x1017, 0, &100u16.to_le_bytes())
        .await
        .unwrap();
    let start = tokio::time::Instant::now();
    let mut seen = Vec::new();
    while seen.len() < 3 {
        let frame = frames.recv().await.unwrap().frame;
        // The boot-up message (0x00) shares the COB-ID; it is no heartbeat.
        if frame.id() == CanId::Standard(0x705) && frame.data() != [0x00] {
            seen.push((start.elapsed(), frame.data().to_vec()));
        }
    }
    // SDO answers came first; heartbeats then every 100 ms, pre-operational.
    let times: Vec<_> = seen.iter().map(|(t, _)| t.as_millis()).collect();
    assert_eq!(times[1] - times[0], 100);
    assert_eq!(times[2] - times[1], 100);
    assert!(seen.iter().all(|(_, data)| data == &[0x7F]));
    nmt(&rig.master, NmtCommand::Start).await;
    loop {
        let frame = frames.recv().await.unwrap().frame;
        if frame.id() == CanId::Standard(0x705) {
            assert_eq!(frame.data(), &[0x05]);
            break;
        }
    }
    rig.task.abort();
}

#[tokio::test(start_paused = true)]
async fn reset_node_reloads_defaults_and_boots_again() {
    let rig = rig();
    rig.sdo.download(0x2001, 0, &[99]).await.unwrap();
    rig.sdo
        .download(0x1017, 0, &50u16.to_le_bytes())
        .await
        .unwrap();
    let mut frames = rig.master.subscribe();
    nmt(&rig.master, NmtCommand::ResetNode).await;
    loop {
        let frame = frames.recv().await.unwrap().frame;
        if frame.id() == CanId::Standard(0x705) && frame.data() == [0x00] {
            break;
        }
    }
    assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![7]);
    assert_eq!(rig.sdo.upload(0x1017, 0).await.unwrap(), vec![0, 0]);
    rig.task.abort();
}

#[tokio::test(start_paused = true)]
async fn reset_communication_keeps_application_values() {
    let rig = rig();
    rig.sdo.download(0x2001, 0, &[99]).await.unwrap();
    rig.sdo
        .download(0x1017, 0, &50u16.to_le_bytes())
        .await
        .unwrap();
    nmt(&rig.master, NmtCommand::ResetCommunication).await;
    assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![99]);
    assert_eq!(rig.sdo.upload(0x1017, 0).await.unwrap(), vec![0, 0]);
    let refused = rig
        .sdo
        .download(0x1018, 1, &[1, 0, 0, 0])
        .await
        .unwrap_err();
    assert_eq!(refused.device_abort(), Some(AbortCode::ReadOnlyObject));
    drop(rig.hub);
    rig.task.abort();
}

const SAVE: [u8; 4] = *b"save";
const LOAD: [u8; 4] = *b"load";

#[tokio::test(start_paused = true)]
async fn saved_parameters_survive_a_reset_node() {
    let rig = rig();
    rig.sdo.download(0x2001, 0, &[42]).await.unwrap();
    rig.sdo.download(0x1010, 1, &SAVE).await.unwrap();
    rig.sdo.download(0x2001, 0, &[43]).await.unwrap();
    nmt(&rig.master, NmtCommand::ResetNode).await;
    assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![42]);
    // Reading 0x1010 still tells what the device can do, not the signature.
    assert_eq!(rig.sdo.upload(0x1010, 1).await.unwrap(), 1u32.to_le_bytes());
    // And the values are there for a restart.
    assert_eq!(
        lock(&rig.device).saved().get(&(0x2001, 0)),
        Some(&Value::Unsigned8(42))
    );
    rig.task.abort();
}

#[tokio::test(start_paused = true)]
async fn store_and_restore_only_in_pre_operational_with_the_right_signature() {
    let rig = rig();
    let wrong = rig.sdo.download(0x1010, 1, b"evas").await.unwrap_err();
    assert_eq!(wrong.device_abort(), Some(AbortCode::CannotStore));
    let wrong = rig.sdo.download(0x1011, 1, b"save").await.unwrap_err();
    assert_eq!(wrong.device_abort(), Some(AbortCode::CannotStore));
    nmt(&rig.master, NmtCommand::Start).await;
    let refused = rig.sdo.download(0x1010, 1, &SAVE).await.unwrap_err();
    assert_eq!(
        refused.device_abort(),
        Some(AbortCode::CannotStoreLocalControl)
    );
    let refused = rig.sdo.download(0x1011, 1, &LOAD).await.unwrap_err();
    assert_eq!(
        refused.device_abort(),
        Some(AbortCode::CannotStoreLocalControl)
    );
    rig.task.abort();
}

#[tokio::test(start_paused = true)]
async fn areas_are_saved_and_restored_apart() {
    let rig = rig();
    // A communication parameter and a manufacturer parameter.
    rig.sdo
        .download(0x1017, 0, &200u16.to_le_bytes())
        .await
        .unwrap();
    rig.sdo.download(0x2001, 0, &[42]).await.unwrap();
    // Save only the manufacturer area.
    rig.sdo.download(0x1010, 4, &SAVE).await.unwrap();
    nmt(&rig.master, NmtCommand::ResetNode).await;
    assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![42]);
    assert_eq!(rig.sdo.upload(0x1017, 0).await.unwrap(), vec![0, 0]);
    // Factory values of the manufacturer area, now and after a reset.
    rig.sdo.download(0x1011, 4, &LOAD).await.unwrap();
    assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![7]);
    nmt(&rig.master, NmtCommand::ResetNode).await;
    assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![7]);
    // Restore saved: back to what was saved, without a reset.
    rig.sdo.download(0x2001, 0, &[9]).await.unwrap();
    rig.sdo.download(0x1010, 1, &SAVE).await.unwrap();
    rig.sdo.download(0x2001, 0, &[10]).await.unwrap();
    rig.sdo.download(0x1011, 5, &LOAD).await.unwrap();
    assert_eq!(rig.sdo.upload(0x2001, 0).await.unwrap(), vec![9]);
    rig.task.abort();
}

/// UMC manual chapter 3 §4.2.2 and §9.1.7 (the UIO1LED manual's are the
/// same words): the heartbeat is on while 0x1017 is not zero, at its
/// period. After reset communication or reset node 0x1017 is back to
/// its default 0, so no heartbeat; writing a period starts it again and
/// writing 0 stops it.
#[test]
fn after_a_reset_the_heartbeat_follows_0x1017_again() {
    use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};
    use crate::products::Product;

    let id = NodeId::new(9).unwrap();
    let heartbeat = CanId::standard(0x709).unwrap();
    let write_1017 = |ms: u16| {
        let [lo, hi] = ms.to_le_bytes();
        Frame::new(
            CanId::standard(0x609).unwrap(),
            &[0x2B, 0x17, 0x10, 0, lo, hi, 0, 0],
        )
        .unwrap()
    };
    // Heartbeats (not the boot-up) sent from `from` for `ms` simulated ms.
    let run = |device: &mut DeviceCore, from: Instant, ms: u64| {
        let mut beats = 0;
        for step in 1..=ms {
            let now = from + Duration::from_millis(step);
            device.tick_to(now);
            beats += device
                .poll(now)
                .iter()
                .filter(|f| f.id() == heartbeat && f.data() != [0x00])
                .count();
        }
        beats
    };
    for product in [Product::Umc1bds32, Product::Uio1led] {
        for reset in [NmtCommand::ResetCommunication, NmtCommand::ResetNode] {
            let mut device = product.device(id).unwrap();
            let start = Instant::now();
            device.boot(start);
            device.handle_frame(&write_1017(200), start);
            assert_eq!(run(&mut device, start, 1000), 5, "{product:?}");
            let now = start + Duration::from_millis(1000);
            let frame = NmtMessage::new(reset, NmtTarget::Node(id)).encode();
            device.handle_frame(&frame, now);
            assert_eq!(device.store().int(0x1017, 0), Some(0));
            assert_eq!(run(&mut device, now, 1000), 0, "{product:?} {reset:?}");
            let now = now + Duration::from_millis(1000);
            device.handle_frame(&write_1017(100), now);
            assert_eq!(run(&mut device, now, 1000), 10, "{product:?} {reset:?}");
            let now = now + Duration::from_millis(1000);
            device.handle_frame(&write_1017(0), now);
            assert_eq!(run(&mut device, now, 1000), 0, "{product:?} {reset:?}");
        }
    }
}

/// UMC manual chapter 3 §6.1.2 (0x1029, Table 3.11; the UIO1LED
/// manual's §6.1.2, Table 2.11), CiA 301 §7.2.8.2.1.1: a heartbeat
/// time-out in operational is a communication error, and 0x1029.1 says
/// what follows: 0 pre-operational (the default), 1 no change of the NMT
/// state, 2 stopped. The EMCY 0x8130 goes out in every case.
#[test]
fn a_heartbeat_time_out_in_operational_follows_0x1029() {
    use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};
    use crate::products::Product;

    let id = NodeId::new(9).unwrap();
    let sdo = |data: [u8; 8]| Frame::new(CanId::standard(0x609).unwrap(), &data).unwrap();
    for product in [Product::Umc1bds32, Product::Uio1led] {
        for (behaviour, expected) in [
            (0u8, NmtState::PreOperational),
            (1, NmtState::Operational),
            (2, NmtState::Stopped),
        ] {
            let mut device = product.device(id).unwrap();
            let start = Instant::now();
            device.boot(start);
            device.handle_frame(&sdo([0x2F, 0x29, 0x10, 1, behaviour, 0, 0, 0]), start);
            assert_eq!(device.store().int(0x1029, 1), Some(behaviour.into()));
            // Watch node 0x7F's heartbeat, 100 ms.
            device.handle_frame(&sdo([0x23, 0x16, 0x10, 1, 100, 0, 0x7F, 0]), start);
            let go = NmtMessage::new(NmtCommand::Start, NmtTarget::Node(id)).encode();
            device.handle_frame(&go, start);
            let beat = Frame::new(CanId::standard(0x77F).unwrap(), &[0x05]).unwrap();
            device.handle_frame(&beat, start);
            assert_eq!(device.nmt_state(), NmtState::Operational);
            let mut emcys = Vec::new();
            for ms in 1..=200 {
                let now = start + Duration::from_millis(ms);
                device.tick_to(now);
                let out = device.poll(now);
                emcys.extend(
                    out.iter()
                        .filter(|f| f.id() == CanId::standard(0x89).unwrap())
                        .map(|f| u16::from_le_bytes([f.data()[0], f.data()[1]])),
                );
            }
            assert!(emcys.contains(&0x8130), "{product:?} {emcys:04X?}");
            assert_eq!(
                device.nmt_state(),
                expected,
                "{product:?}, 0x1029.1 = {behaviour}"
            );
        }
    }
}

/// CiA 301 §7.2.2.2 and the EMCY tables of the UMC manual (chapter 3
/// §6.1, "0x8210 PDO not processed due to length error", "0x8220 PDO
/// length exceeded") and the UIO1LED manual (the same table): an RPDO
/// shorter than its mapping is not processed and says so with 0x8210;
/// a longer one is processed and the UniSwarm devices report 0x8220. The
/// JMC's manual lists no 0x8220, so it only reports the short one.
#[test]
fn an_rpdo_of_the_wrong_length_raises_its_emcy() {
    use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};
    use crate::products::Product;

    let id = NodeId::new(9).unwrap();
    let rpdo1 = |len: usize| Frame::new(CanId::standard(0x209).unwrap(), &[0; 8][..len]).unwrap();
    for (product, reports_longer) in [
        (Product::Umc1bds32, true),
        (Product::Uio1led, true),
        (Product::Jmc, false),
    ] {
        let mut device = product.device(id).unwrap();
        let start = Instant::now();
        device.boot(start);
        // RPDO1: two dummies, 16 and 32 bits (6 bytes), on 0x209.
        let store = device.store_mut();
        store.set(0x1600, 0, Value::Unsigned8(0)).unwrap();
        store
            .set(0x1600, 1, Value::Unsigned32(0x0006_0010))
            .unwrap();
        store
            .set(0x1600, 2, Value::Unsigned32(0x0007_0020))
            .unwrap();
        store.set(0x1600, 0, Value::Unsigned8(2)).unwrap();
        store.set(0x1400, 1, Value::Unsigned32(0x209)).unwrap();
        store.set(0x1400, 2, Value::Unsigned8(255)).unwrap();
        device.pdo_parameters_changed(start);
        let go = NmtMessage::new(NmtCommand::Start, NmtTarget::Node(id)).encode();
        device.handle_frame(&go, start);
        let mut emcys = |len: usize, at: u64| {
            let now = start + Duration::from_millis(at);
            device.handle_frame(&rpdo1(len), now);
            let mut codes = Vec::new();
            for ms in at..at + 10 {
                let now = start + Duration::from_millis(ms);
                device.tick_to(now);
                codes.extend(
                    device
                        .poll(now)
                        .iter()
                        .filter(|f| f.id() == CanId::standard(0x89).unwrap())
                        .map(|f| u16::from_le_bytes([f.data()[0], f.data()[1]])),
                );
            }
            codes
        };
        assert_eq!(emcys(6, 100), Vec::<u16>::new(), "{product:?}");
        assert_eq!(emcys(5, 200), [0x8210], "{product:?}");
        // The JMC processes the longer one and reports nothing: an RPDO
        // processed right, so the 0x8210 before is reset.
        let longer = if reports_longer {
            vec![0x8220]
        } else {
            vec![0x0000]
        };
        assert_eq!(emcys(8, 300), longer, "{product:?}");
    }
}

/// One expedited SDO request to node 9 and its answer.
fn sdo_exchange(device: &mut DeviceCore, request: [u8; 8]) -> [u8; 8] {
    let frame = Frame::new(CanId::standard(0x609).unwrap(), &request).unwrap();
    let replies = device.handle_frame(&frame, Instant::now());
    let reply = replies
        .iter()
        .find(|f| f.id() == CanId::standard(0x589).unwrap())
        .expect("an SDO answer");
    reply.data().try_into().unwrap()
}

/// The abort code of an answer, `None` for a confirmation.
fn abort_of(reply: [u8; 8]) -> Option<u32> {
    (reply[0] == 0x80).then(|| u32::from_le_bytes(reply[4..8].try_into().unwrap()))
}

/// CiA 306 §4.5.4 `[DummyUsage]` and CiA 301 §7.4.7.1: the UIO1LED's EDS
/// declares Dummy0002–Dummy0007, the dummy objects an RPDO may map; a
/// device reading them answers the length of their type in bits as
/// UNSIGNED32 (const), as python-canopen's reading of such an EDS
/// expects. The EDS's 0x1014 (COB_ID_EMCY) has limits 0x80–0x100: a value
/// outside them is refused with 0x06090032 / 0x06090031.
#[test]
fn the_uio1led_answers_its_dummy_objects_and_keeps_0x1014_in_its_limits() {
    use crate::products::Product;

    let mut device = Product::Uio1led.device(NodeId::new(9).unwrap()).unwrap();
    device.boot(Instant::now());
    for (index, bits) in [(2u8, 8u8), (3, 16), (4, 32), (5, 8), (6, 16), (7, 32)] {
        let reply = sdo_exchange(&mut device, [0x40, index, 0, 0, 0, 0, 0, 0]);
        assert_eq!(reply, [0x43, index, 0, 0, bits, 0, 0, 0], "0x{index:04X}");
        let write = sdo_exchange(&mut device, [0x23, index, 0, 0, bits, 0, 0, 0]);
        assert_eq!(abort_of(write), Some(0x0601_0002), "0x{index:04X} is const");
    }
    // Dummy0001 is not declared.
    let reply = sdo_exchange(&mut device, [0x40, 1, 0, 0, 0, 0, 0, 0]);
    assert_eq!(abort_of(reply), Some(0x0602_0000));
    for (value, abort) in [(0x7Fu32, 0x0609_0032u32), (0x101, 0x0609_0031)] {
        let [a, b, c, d] = value.to_le_bytes();
        let reply = sdo_exchange(&mut device, [0x23, 0x14, 0x10, 0, a, b, c, d]);
        assert_eq!(abort_of(reply), Some(abort), "0x1014 = {value:#X}");
    }
    assert_eq!(device.store().int(0x1014, 0), Some(0x89));
}

/// An expedited download of a 32-bit `value`; the abort code, if any.
fn download_u32(device: &mut DeviceCore, index: u16, sub: u8, value: u32) -> Option<u32> {
    let [i0, i1] = index.to_le_bytes();
    let [a, b, c, d] = value.to_le_bytes();
    abort_of(sdo_exchange(device, [0x23, i0, i1, sub, a, b, c, d]))
}

/// CiA 301 §7.5.2.16 (0x1014 COB-ID EMCY): bits 0–29 shall not be
/// changed while the EMCY exists (bit 31 = 0); the UMC and the UIO1LED
/// refuse such a write with 0x06090030 (invalid value). Setting bit 31
/// first, the COB-ID can be changed (the UMC; the UIO1LED's EDS limits
/// keep bit 31 out).
#[test]
fn the_emcy_cob_id_does_not_change_while_the_emcy_is_valid() {
    use crate::products::Product;

    for product in [Product::Umc1bds32, Product::Uio1led] {
        let mut device = product.device(NodeId::new(9).unwrap()).unwrap();
        device.boot(Instant::now());
        assert_eq!(
            download_u32(&mut device, 0x1014, 0, 0x8A),
            Some(0x0609_0030),
            "{product:?}"
        );
        // The same value again changes nothing and is taken.
        assert_eq!(download_u32(&mut device, 0x1014, 0, 0x89), None);
        assert_eq!(device.store().int(0x1014, 0), Some(0x89));
    }
    let mut device = Product::Umc1bds32.device(NodeId::new(9).unwrap()).unwrap();
    device.boot(Instant::now());
    assert_eq!(download_u32(&mut device, 0x1014, 0, 0x8000_0089), None);
    assert_eq!(download_u32(&mut device, 0x1014, 0, 0x8000_008A), None);
    assert_eq!(download_u32(&mut device, 0x1014, 0, 0x8A), None);
    assert_eq!(device.store().int(0x1014, 0), Some(0x8A));
}

/// The JMC manual, 0x1005: "The device supports standard CAN data
/// frames. When attempting to modify bit 29, Will be invalid and an
/// error code of 0609 0030h will be returned", and bit 30 (the device
/// generates SYNC) the same for a device that does not; 0x1400–0x1803
/// ("PDO COB-ID description"): "modify the 29th bit is 1 ... will cause
/// the error code: 0609 0030h".
#[test]
fn the_jmc_refuses_29_bit_and_sync_producer_cob_ids() {
    use crate::products::Product;

    let mut device = Product::Jmc.device(NodeId::new(9).unwrap()).unwrap();
    device.boot(Instant::now());
    for value in [0x2000_0080u32, 0x4000_0080] {
        assert_eq!(
            download_u32(&mut device, 0x1005, 0, value),
            Some(0x0609_0030),
            "0x1005 = {value:#X}"
        );
    }
    assert_eq!(device.store().int(0x1005, 0), Some(0x80));
    for (index, cob_id) in [(0x1801u16, 0x283u32), (0x1401, 0x303)] {
        assert_eq!(
            download_u32(&mut device, index, 1, cob_id | 0x2000_0000),
            Some(0x0609_0030),
            "0x{index:04X}.1"
        );
        // The 11-bit one is taken (the JMC re-maps a valid PDO).
        assert_eq!(download_u32(&mut device, index, 1, cob_id), None);
    }
}

#[test]
fn values_saved_before_a_restart_are_in_force() {
    let mut device = DeviceCore::new(testnode(), node()).unwrap();
    let mut saved = SavedValues::new();
    saved.insert((0x2001, 0), Value::Unsigned8(55));
    device.load_saved(saved);
    assert_eq!(device.store().get(0x2001, 0), Some(&Value::Unsigned8(55)));
}

/// A UniSwarm device at node 5 on a virtual bus, and an SDO channel that
/// downloads by block transfer (with the CRC) from `block_from` bytes.
fn uniswarm_rig(
    product: crate::products::Product,
    block_from: Option<usize>,
) -> (
    Arc<Mutex<DeviceCore>>,
    SdoChannel,
    tokio::task::JoinHandle<()>,
) {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let device = Arc::new(Mutex::new(product.device(node()).unwrap()));
    let task = tokio::spawn(run_device(hub.attach(), device.clone()));
    let config = ClientConfig {
        timeout: Duration::from_millis(200),
        use_block_download_from: block_from,
        crc: true,
        ..ClientConfig::default()
    };
    (device, SdoChannel::new(master, node(), config), task)
}

/// A 64 KiB image: the header naming version `version` (if any), then a
/// pattern.
fn image(version: Option<&str>) -> Vec<u8> {
    let mut image = version
        .map(crate::program::ImageHeader::encode)
        .unwrap_or_default();
    image.extend(
        (0..64 * 1024u32 - image.len() as u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8),
    );
    image
}

async fn abort_code(sdo: &SdoChannel, index: u16, sub: u8, data: &[u8]) -> Option<u32> {
    sdo.download(index, sub, data)
        .await
        .err()
        .map(|err| err.device_abort().expect("a device abort").raw())
}

/// CiA 302-3 on the UIO1LED and the UMC: the running factory program
/// refuses a download; stopped and cleared (0x1F51 = 0, 3), the device
/// takes a 64 KiB image by block download, 0x1F56 sub 1 is its CRC-32 and
/// 0x1F57 sub 1 no error; the software version (0x100A) changes only when
/// the program is reset (0x1F51 = 2), to the header's, and stays so after
/// an NMT reset node.
#[tokio::test(start_paused = true)]
async fn a_downloaded_program_gives_its_crc_and_after_a_reset_its_version() {
    use crate::canopen::crc32::crc32;
    use crate::products::Product;

    for product in [Product::Uio1led, Product::Umc1bds32] {
        let (device, sdo, task) = uniswarm_rig(product, Some(1));
        let image = image(Some("2.1.0-test"));
        let factory_version = sdo.upload(0x100A, 0).await.unwrap();
        assert_eq!(sdo.upload(0x1F51, 1).await.unwrap(), [1], "{product:?}");
        assert_eq!(
            abort_code(&sdo, 0x1F50, 1, &image).await,
            Some(0x0800_0022),
            "{product:?}: a running program is not overwritten"
        );
        assert_eq!(abort_code(&sdo, 0x1F51, 1, &[3]).await, Some(0x0800_0022));
        sdo.download(0x1F51, 1, &[0]).await.unwrap();
        sdo.download(0x1F51, 1, &[3]).await.unwrap();
        assert_eq!(sdo.upload(0x1F51, 1).await.unwrap(), [3]);
        assert_eq!(sdo.upload(0x1F57, 1).await.unwrap(), 2u32.to_le_bytes());
        assert_eq!(abort_code(&sdo, 0x1F51, 1, &[1]).await, Some(0x0800_0022));
        sdo.download(0x1F50, 1, &image).await.unwrap();
        assert_eq!(
            sdo.upload(0x1F56, 1).await.unwrap(),
            crc32(&image).to_le_bytes(),
            "{product:?}"
        );
        assert_eq!(sdo.upload(0x1F57, 1).await.unwrap(), 0u32.to_le_bytes());
        assert_eq!(sdo.upload(0x1F51, 1).await.unwrap(), [0]);
        assert_eq!(sdo.upload(0x100A, 0).await.unwrap(), factory_version);
        assert_eq!(lock(&device).program().image(), Some(&image[..]));
        sdo.download(0x1F51, 1, &[2]).await.unwrap();
        assert_eq!(sdo.upload(0x1F51, 1).await.unwrap(), [1]);
        assert_eq!(sdo.upload(0x100A, 0).await.unwrap(), b"2.1.0-test");
        let reset = NmtMessage::new(NmtCommand::ResetNode, NmtTarget::Node(node())).encode();
        sdo.download(0x1017, 0, &0u16.to_le_bytes()).await.unwrap();
        lock(&device).handle_frame(&reset, Instant::now());
        assert_eq!(sdo.upload(0x100A, 0).await.unwrap(), b"2.1.0-test");
        assert_eq!(
            sdo.upload(0x1F56, 1).await.unwrap(),
            crc32(&image).to_le_bytes()
        );
        task.abort();
    }
}

/// A segmented download works as well; an image without the header
/// leaves 0x100A as it was; one larger than the program memory is refused
/// with 0x05040005 at the initiate and leaves the stored one.
#[tokio::test(start_paused = true)]
async fn a_program_too_large_is_refused_and_one_without_header_keeps_the_version() {
    use crate::canopen::crc32::crc32;
    use crate::products::Product;
    use crate::program::MAX_PROGRAM_SIZE;

    let (_device, sdo, task) = uniswarm_rig(Product::Uio1led, None);
    let factory_version = sdo.upload(0x100A, 0).await.unwrap();
    sdo.download(0x1F51, 1, &[0]).await.unwrap();
    let plain = image(None);
    sdo.download(0x1F50, 1, &plain).await.unwrap();
    assert_eq!(
        sdo.upload(0x1F56, 1).await.unwrap(),
        crc32(&plain).to_le_bytes()
    );
    let too_large = vec![0x55; MAX_PROGRAM_SIZE + 1];
    assert_eq!(
        abort_code(&sdo, 0x1F50, 1, &too_large).await,
        Some(0x0504_0005)
    );
    assert_eq!(
        sdo.upload(0x1F56, 1).await.unwrap(),
        crc32(&plain).to_le_bytes()
    );
    assert_eq!(abort_code(&sdo, 0x1F51, 1, &[4]).await, Some(0x0609_0030));
    sdo.download(0x1F51, 1, &[1]).await.unwrap();
    assert_eq!(sdo.upload(0x100A, 0).await.unwrap(), factory_version);
    task.abort();
}

/// An image kept before a restart ([`DeviceCore::load_program`]) runs from
/// the boot: its CRC in 0x1F56, its header's version in 0x100A.
#[test]
fn a_kept_program_runs_from_the_boot() {
    use crate::canopen::crc32::crc32;
    use crate::products::Product;

    let image = image(Some("3.0"));
    let mut device = Product::Uio1led.device(NodeId::new(9).unwrap()).unwrap();
    device.load_program(Some(image.clone()));
    device.boot(Instant::now());
    assert_eq!(
        device.store().get(0x1F56, 1),
        Some(&Value::Unsigned32(crc32(&image)))
    );
    assert_eq!(
        device.store().get(0x100A, 0),
        Some(&Value::VisibleString("3.0".into()))
    );
    assert_eq!(device.store().int(0x1F51, 1), Some(1));
}

/// CiA 301 §7.5.2.6 (0x1005): bit 30 "generate SYNC" on a device that has
/// no SYNC producer (the UMC's EDS and manual list no 0x1006) is refused
/// with 0x06090030; bits 0–29 may change while bit 30 is 0. On a device
/// with 0x1006, bit 30 is taken, and bits 0–29 may not change while it is
/// set (0x06090030): bit 30 is cleared first.
#[test]
fn cob_id_sync_refuses_generate_without_a_sync_producer_and_changes_while_generating() {
    use crate::products::Product;

    let id = NodeId::new(9).unwrap();
    let mut umc = Product::Umc1bds32.device(id).unwrap();
    umc.boot(Instant::now());
    let write = |device: &mut DeviceCore, value: u32| {
        let [a, b, c, d] = value.to_le_bytes();
        abort_of(sdo_exchange(device, [0x23, 0x05, 0x10, 0, a, b, c, d]))
    };
    assert_eq!(write(&mut umc, 0x4000_0080), Some(0x0609_0030));
    assert_eq!(umc.store().int(0x1005, 0), Some(0x80));
    assert_eq!(write(&mut umc, 0x0000_0081), None);
    // A device that has 0x1006: a SYNC producer.
    let mut dictionary = Eds::parse(crate::profiles::builtin::UIO1LED, "uio1led.eds")
        .unwrap()
        .dictionary;
    let mut period = crate::canopen::od::SubObject::new(
        0,
        "Communication_cycle_period",
        crate::canopen::od::DataType::Unsigned32,
        crate::canopen::od::AccessType::Rw,
    );
    period.default = Some("0".into());
    dictionary.insert(crate::canopen::od::Object::var(0x1006, period));
    let mut producer = DeviceCore::new(dictionary, id).unwrap();
    producer.boot(Instant::now());
    assert_eq!(write(&mut producer, 0x4000_0080), None);
    assert_eq!(write(&mut producer, 0x4000_0081), Some(0x0609_0030));
    assert_eq!(write(&mut producer, 0x0000_0080), None);
    assert_eq!(write(&mut producer, 0x0000_0081), None);
}

/// CiA 301 §7.5.2.16 (0x1014 bit 31, EMCY does not exist) on the UIO1LED,
/// whose EDS bounds 0x1014 to 0x80–0x100: the bounds are the CAN-ID's, so
/// 0x80000083 (EMCY disabled, a new COB-ID) is taken, and a CAN-ID above
/// them is still refused (0x06090031).
#[test]
fn the_uio1led_takes_an_emcy_cob_id_with_bit_31_within_its_limits() {
    use crate::products::Product;

    let mut device = Product::Uio1led.device(NodeId::new(9).unwrap()).unwrap();
    device.boot(Instant::now());
    let write = |device: &mut DeviceCore, value: u32| {
        let [a, b, c, d] = value.to_le_bytes();
        abort_of(sdo_exchange(device, [0x23, 0x14, 0x10, 0, a, b, c, d]))
    };
    assert_eq!(write(&mut device, 0x8000_0089), None);
    assert_eq!(write(&mut device, 0x8000_0083), None);
    assert_eq!(device.store().int(0x1014, 0), Some(0x8000_0083));
    assert_eq!(write(&mut device, 0x8000_0101), Some(0x0609_0031));
    assert_eq!(write(&mut device, 0x0000_0083), None);
}

/// UMC manual §2.3.1 and UIO1LED manual §4.2 (0x2040 sub 1 Node_ID, the
/// ID the device boots with after a save and reset) and CiA 301 (node-IDs
/// 1–127): 0, 128 and 255 are refused with 0x06090030 rather than saved
/// and ignored at the reset.
#[test]
fn node_id_0x2040_refuses_what_the_device_cannot_boot_with() {
    use crate::products::Product;

    for product in [Product::Umc1bds32, Product::Uio1led] {
        let mut device = product.device(NodeId::new(9).unwrap()).unwrap();
        device.boot(Instant::now());
        for value in [0u8, 128, 255] {
            let reply = sdo_exchange(&mut device, [0x2F, 0x40, 0x20, 1, value, 0, 0, 0]);
            assert_eq!(abort_of(reply), Some(0x0609_0030), "{product:?} {value}");
        }
        assert_eq!(device.store().int(0x2040, 1), Some(9));
        for value in [1u8, 127] {
            let reply = sdo_exchange(&mut device, [0x2F, 0x40, 0x20, 1, value, 0, 0, 0]);
            assert_eq!(abort_of(reply), None, "{product:?} {value}");
        }
    }
}

/// CiA 301 table 21 and CANopenNode (the UniSwarm firmware's stack): the
/// EMCY of an RPDO of the wrong length (0x8210 too short, 0x8220 too long)
/// is a communication error, error register 0x11 (generic and
/// communication bits), and once an RPDO is processed right again an error
/// reset (0x0000) follows and the register is clear.
#[test]
fn an_rpdo_length_error_carries_its_register_and_is_reset_by_a_right_rpdo() {
    use crate::products::Product;

    let id = NodeId::new(9).unwrap();
    let rpdo1 = |len: usize| Frame::new(CanId::standard(0x209).unwrap(), &[0; 8][..len]).unwrap();
    for (product, longer) in [(Product::Umc1bds32, true), (Product::Jmc, false)] {
        let mut device = product.device(id).unwrap();
        let start = Instant::now();
        device.boot(start);
        let store = device.store_mut();
        store.set(0x1600, 0, Value::Unsigned8(0)).unwrap();
        store
            .set(0x1600, 1, Value::Unsigned32(0x0006_0010))
            .unwrap();
        store
            .set(0x1600, 2, Value::Unsigned32(0x0007_0020))
            .unwrap();
        store.set(0x1600, 0, Value::Unsigned8(2)).unwrap();
        store.set(0x1400, 1, Value::Unsigned32(0x209)).unwrap();
        store.set(0x1400, 2, Value::Unsigned8(255)).unwrap();
        device.pdo_parameters_changed(start);
        let go = NmtMessage::new(NmtCommand::Start, NmtTarget::Node(id)).encode();
        device.handle_frame(&go, start);
        let mut emcys = |len: usize, at: u64| {
            let now = start + Duration::from_millis(at);
            device.handle_frame(&rpdo1(len), now);
            let mut seen = Vec::new();
            for ms in at..at + 10 {
                let now = start + Duration::from_millis(ms);
                device.tick_to(now);
                seen.extend(
                    device
                        .poll(now)
                        .iter()
                        .filter(|f| f.id() == CanId::standard(0x89).unwrap())
                        .map(|f| (u16::from_le_bytes([f.data()[0], f.data()[1]]), f.data()[2])),
                );
            }
            seen
        };
        assert_eq!(emcys(5, 100), [(0x8210, 0x11)], "{product:?}");
        assert_eq!(emcys(5, 200), [(0x8210, 0x11)], "{product:?}");
        assert_eq!(emcys(6, 300), [(0x0000, 0x00)], "{product:?}");
        assert_eq!(emcys(6, 400), [], "{product:?}");
        if longer {
            assert_eq!(emcys(8, 500), [(0x8220, 0x11)], "{product:?}");
            assert_eq!(emcys(6, 600), [(0x0000, 0x00)], "{product:?}");
        } else {
            assert_eq!(emcys(8, 500), [], "{product:?}");
        }
    }
}
