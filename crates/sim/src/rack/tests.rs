use super::*;
use crate::behaviour::{Behaviour, DeviceIo};
use crate::can::CanId;
use crate::canopen::eds::Eds;
use crate::canopen::emcy::ErrorBit;
use crate::canopen::sdo::{AbortCode, ClientConfig};
use crate::profiles::builtin::UIO1LED;
use candeck_gateway::SdoChannel;

/// An application that counts its ticks and has an over-temperature
/// fault with EMCY 0x4210.
#[derive(Default)]
struct Probe {
    ticks: u64,
}

impl Behaviour for Probe {
    fn product(&self) -> &'static str {
        "probe"
    }

    fn reset(&mut self, _io: &mut DeviceIo<'_>) {
        self.ticks = 0;
    }

    fn written(&mut self, _io: &mut DeviceIo<'_>, _index: u16, _sub: u8) {}

    fn tick(&mut self, _io: &mut DeviceIo<'_>) {
        self.ticks += 1;
    }

    fn inject_fault(&mut self, io: &mut DeviceIo<'_>, fault: Fault) -> Result<(), FaultError> {
        if fault != Fault::OverTemperature {
            return Err(FaultError::NotApplicable {
                product: "probe",
                fault,
            });
        }
        io.set_error_bit(ErrorBit::Temperature, true);
        io.emcy(0x4210, [1, 2, 3, 4, 5]);
        Ok(())
    }

    fn clear_fault(&mut self, io: &mut DeviceIo<'_>, _fault: Fault) -> Result<(), FaultError> {
        io.set_error_bit(ErrorBit::Temperature, false);
        io.emcy(0x0000, [0; 5]);
        Ok(())
    }
}

fn node(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

fn probe(id: u8) -> DeviceCore {
    let mut dictionary = Eds::parse(UIO1LED, "uio1led.eds").unwrap().dictionary;
    // The UIO1LED's limits on 0x1014 (0x80–0x100) keep bit 31 out; the
    // probe is the core's, which may be told not to send EMCYs.
    dictionary.sub_mut(0x1014, 0).unwrap().high = None;
    DeviceCore::with_behaviour(dictionary, node(id), Box::new(Probe::default())).unwrap()
}

fn sdo(master: &Bus, id: u8) -> SdoChannel {
    let config = ClientConfig {
        timeout: Duration::from_millis(100),
        ..ClientConfig::default()
    };
    SdoChannel::new(master.clone(), node(id), config)
}

/// The frames on `id` in the next `ms` of (paused) time.
async fn frames_on(frames: &mut FrameReceiver, id: u16, ms: u64) -> Vec<Vec<u8>> {
    frames_on_any(frames, &[id], ms).await
}

/// The frames on any of `ids` in the next `ms` of (paused) time.
async fn frames_on_any(frames: &mut FrameReceiver, ids: &[u16], ms: u64) -> Vec<Vec<u8>> {
    let until = tokio::time::Instant::now() + Duration::from_millis(ms);
    let mut seen = Vec::new();
    loop {
        match tokio::time::timeout_at(until, frames.recv()).await {
            Ok(Ok(frame))
                if ids
                    .iter()
                    .any(|id| frame.frame.id() == CanId::Standard(*id)) =>
            {
                seen.push(frame.frame.data().to_vec())
            }
            Ok(Ok(_)) => {}
            Ok(Err(err)) => panic!("{err}"),
            Err(_) => return seen,
        }
    }
}

#[tokio::test(start_paused = true)]
async fn devices_boot_and_answer_through_one_runner() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let mut frames = master.subscribe();
    let rack = Rack::new(hub.clone());
    rack.add(Product::Uio1led, node(3)).unwrap();
    rack.add_device(probe(4)).unwrap();
    let boot_ups = [
        frames.recv().await.unwrap().frame,
        frames.recv().await.unwrap().frame,
    ];
    let ids: Vec<_> = boot_ups
        .iter()
        .map(|f| (f.id(), f.data().to_vec()))
        .collect();
    assert_eq!(
        ids,
        vec![
            (CanId::Standard(0x703), vec![0]),
            (CanId::Standard(0x704), vec![0])
        ]
    );
    assert_eq!(
        sdo(&master, 4).upload(0x1000, 0).await.unwrap(),
        sdo(&master, 3).upload(0x1000, 0).await.unwrap()
    );
    assert_eq!(
        rack.add(Product::Jmc, node(3)),
        Err(RackError::NodeTaken(node(3), "uio1led".into()))
    );
    assert_eq!(rack.remove(node(9)), Err(RackError::UnknownNode(node(9))));
}

#[tokio::test(start_paused = true)]
async fn the_simulation_clock_ticks_every_millisecond() {
    let hub = VirtualHub::new("test");
    let rack = Rack::new(hub.clone());
    rack.add_device(probe(4)).unwrap();
    tokio::time::sleep(Duration::from_millis(250)).await;
    let (ticks, sim_ms) = rack
        .with_device(node(4), |core| {
            let sim_ms = core.sim_ms();
            (core.behaviour_mut::<Probe>().unwrap().ticks, sim_ms)
        })
        .unwrap();
    // The first tick comes one period after the device was added.
    assert!((249..=250).contains(&ticks), "{ticks}");
    assert_eq!(ticks, sim_ms);
    assert_eq!(rack.stats().late_ticks.load(Ordering::Relaxed), 0);
}

#[test]
fn a_stalled_host_skips_simulated_time_rather_than_bursting() {
    let mut core = probe(4);
    let start = Instant::now();
    core.boot(start);
    core.tick_to(start);
    core.tick_to(start + Duration::from_micros(2_500));
    let ticks = |core: &mut DeviceCore| core.behaviour_mut::<Probe>().unwrap().ticks;
    assert_eq!((ticks(&mut core), core.sim_ms()), (2, 2));
    // 2.5 s late: 1000 ticks are run, the rest skipped and counted.
    core.tick_to(start + Duration::from_millis(2_502));
    assert_eq!(ticks(&mut core), 1_002);
    assert_eq!((core.sim_ms(), core.skipped_ticks()), (2_502, 1_500));
    // And the clock goes on from there, one tick per millisecond.
    core.tick_to(start + Duration::from_millis(2_503));
    assert_eq!((ticks(&mut core), core.sim_ms()), (1_003, 2_503));
}

#[tokio::test(start_paused = true)]
async fn a_fault_sends_its_emcy_and_fills_0x1001_and_0x1003() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let mut frames = master.subscribe();
    let rack = Rack::new(hub.clone());
    rack.add_device(probe(4)).unwrap();
    let sdo = sdo(&master, 4);
    assert_eq!(
        rack.inject_fault(node(4), Fault::UnderVoltage),
        Err(RackError::Fault(FaultError::NotApplicable {
            product: "probe",
            fault: Fault::UnderVoltage
        }))
    );
    rack.inject_fault(node(4), Fault::OverTemperature).unwrap();
    assert_eq!(
        frames_on(&mut frames, 0x084, 10).await,
        vec![vec![0x10, 0x42, 0x09, 1, 2, 3, 4, 5]]
    );
    assert_eq!(sdo.upload(0x1001, 0).await.unwrap(), vec![0x09]);
    assert_eq!(sdo.upload(0x1003, 0).await.unwrap(), vec![1]);
    assert_eq!(sdo.upload(0x1003, 1).await.unwrap(), vec![0x10, 0x42, 0, 0]);
    rack.clear_fault(node(4), Fault::OverTemperature).unwrap();
    assert_eq!(
        frames_on(&mut frames, 0x084, 10).await,
        vec![vec![0, 0, 0, 0, 0, 0, 0, 0]]
    );
    // An error reset is no error: the history keeps one entry.
    assert_eq!(sdo.upload(0x1003, 0).await.unwrap(), vec![1]);
    let refused = sdo.download(0x1003, 0, &[1]).await.unwrap_err();
    assert_eq!(refused.device_abort(), Some(AbortCode::InvalidValue));
    sdo.download(0x1003, 0, &[0]).await.unwrap();
    assert_eq!(sdo.upload(0x1003, 0).await.unwrap(), vec![0]);
    assert_eq!(sdo.upload(0x1003, 1).await.unwrap(), vec![0, 0, 0, 0]);
    // With 0x1014 bit 31 set, EMCYs are recorded but not sent.
    sdo.download(0x1014, 0, &0x8000_0084u32.to_le_bytes())
        .await
        .unwrap();
    rack.inject_fault(node(4), Fault::OverTemperature).unwrap();
    assert!(frames_on(&mut frames, 0x084, 10).await.is_empty());
    assert_eq!(sdo.upload(0x1003, 0).await.unwrap(), vec![1]);
}

#[tokio::test(start_paused = true)]
async fn an_unplugged_device_falls_silent_and_comes_back_without_booting() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add_device(probe(4)).unwrap();
    sdo(&master, 4)
        .download(0x1017, 0, &100u16.to_le_bytes())
        .await
        .unwrap();
    let mut frames = master.subscribe();
    assert_eq!(frames_on(&mut frames, 0x704, 550).await.len(), 5);
    rack.unplug(node(4)).unwrap();
    assert_eq!(rack.is_plugged(node(4)), Some(false));
    assert!(frames_on(&mut frames, 0x704, 500).await.is_empty());
    assert!(sdo(&master, 4).upload(0x1017, 0).await.is_err());
    rack.plug(node(4)).unwrap();
    let back = frames_on(&mut frames, 0x704, 500).await;
    // Heartbeats in pre-operational, no boot-up (0x00).
    assert!(
        back.len() >= 4 && back.iter().all(|data| data == &[0x7F]),
        "{back:?}"
    );
    // It went on running while unplugged.
    let ticks = rack
        .with_device(node(4), |core| core.behaviour_mut::<Probe>().unwrap().ticks)
        .unwrap();
    assert!(ticks >= 1500, "{ticks}");
}

#[tokio::test(start_paused = true)]
async fn heartbeat_loss_stops_the_heartbeat_but_not_the_device() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add_device(probe(4)).unwrap();
    let sdo = sdo(&master, 4);
    sdo.download(0x1017, 0, &100u16.to_le_bytes())
        .await
        .unwrap();
    let mut frames = master.subscribe();
    rack.inject_fault(node(4), Fault::HeartbeatLoss).unwrap();
    assert!(frames_on(&mut frames, 0x704, 350).await.is_empty());
    assert_eq!(sdo.upload(0x1017, 0).await.unwrap(), vec![100, 0]);
    rack.clear_fault(node(4), Fault::HeartbeatLoss).unwrap();
    assert_eq!(frames_on(&mut frames, 0x704, 350).await.len(), 3);
}

#[tokio::test(start_paused = true)]
async fn node_guarding_is_answered_and_a_lost_master_is_an_emcy() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add_device(probe(4)).unwrap();
    let sdo = sdo(&master, 4);
    sdo.download(0x100C, 0, &100u16.to_le_bytes())
        .await
        .unwrap();
    sdo.download(0x100D, 0, &[3]).await.unwrap();
    let mut frames = master.subscribe();
    let request = Frame::remote(CanId::Standard(0x704), 1).unwrap();
    master.send(request).await.unwrap();
    assert_eq!(frames_on(&mut frames, 0x704, 5).await, vec![vec![0x7F]]);
    master.send(request).await.unwrap();
    assert_eq!(frames_on(&mut frames, 0x704, 5).await, vec![vec![0xFF]]);
    // No request for the life time (300 ms): EMCY 0x8130, communication bit.
    assert_eq!(
        frames_on(&mut frames, 0x084, 400).await,
        vec![vec![0x30, 0x81, 0x11, 0, 0, 0, 0, 0]]
    );
    master.send(request).await.unwrap();
    assert_eq!(
        frames_on_any(&mut frames, &[0x704, 0x084], 10).await,
        vec![vec![0x7F], vec![0; 8]]
    );
    // With a heartbeat configured, guarding requests go unanswered.
    sdo.download(0x1017, 0, &1000u16.to_le_bytes())
        .await
        .unwrap();
    master.send(request).await.unwrap();
    assert!(frames_on(&mut frames, 0x704, 5).await.is_empty());
}

#[tokio::test(start_paused = true)]
async fn devices_hear_each_other_as_on_a_wire() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add(Product::Uio1led, node(3)).unwrap();
    rack.add(Product::Uio1led, node(4)).unwrap();
    let (three, four) = (sdo(&master, 3), sdo(&master, 4));
    // Node 3's TPDO1 carries s01_Value (0x6010, INTEGER16) on a change.
    for (index, sub, data) in [
        (0x1800, 1, 0x8000_0183u32.to_le_bytes().to_vec()),
        (0x1A00, 0, vec![0]),
        (0x1A00, 1, 0x6010_0010u32.to_le_bytes().to_vec()),
        (0x1A00, 0, vec![1]),
        (0x1800, 2, vec![255]),
        (0x1800, 1, 0x183u32.to_le_bytes().to_vec()),
    ] {
        three.download(index, sub, &data).await.unwrap();
    }
    // Node 4's RPDO1 takes it into its own s01_Value.
    for (index, sub, data) in [
        (0x1400, 1, 0x8000_0204u32.to_le_bytes().to_vec()),
        (0x1600, 0, vec![0]),
        (0x1600, 1, 0x6010_0010u32.to_le_bytes().to_vec()),
        (0x1600, 0, vec![1]),
        (0x1400, 2, vec![255]),
        (0x1400, 1, 0x183u32.to_le_bytes().to_vec()),
    ] {
        four.download(index, sub, &data).await.unwrap();
    }
    let start_all = crate::canopen::nmt::NmtMessage::new(
        crate::canopen::nmt::NmtCommand::Start,
        crate::canopen::nmt::NmtTarget::All,
    );
    master.send(start_all.encode()).await.unwrap();
    three
        .download(0x6010, 0, &1234i16.to_le_bytes())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(20)).await;
    assert_eq!(four.upload(0x6010, 0).await.unwrap(), 1234i16.to_le_bytes());
    // Unplugged, node 4 no longer hears it.
    rack.unplug(node(4)).unwrap();
    three
        .download(0x6010, 0, &77i16.to_le_bytes())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(20)).await;
    rack.plug(node(4)).unwrap();
    assert_eq!(four.upload(0x6010, 0).await.unwrap(), 1234i16.to_le_bytes());
}

#[tokio::test(start_paused = true)]
async fn a_drive_that_loses_its_masters_heartbeat_stops_as_0x6007_says() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add(Product::Umc1bds32, node(1)).unwrap();
    let sdo = sdo(&master, 1);
    // Watch node 127's heartbeat with a 300 ms timeout.
    sdo.download(0x1016, 1, &0x007F_012Cu32.to_le_bytes())
        .await
        .unwrap();
    let start = crate::canopen::nmt::NmtMessage::new(
        crate::canopen::nmt::NmtCommand::Start,
        crate::canopen::nmt::NmtTarget::Node(node(1)),
    );
    master.send(start.encode()).await.unwrap();
    for controlword in [6u16, 7, 15] {
        sdo.download(0x6040, 0, &controlword.to_le_bytes())
            .await
            .unwrap();
    }
    let statusword = |data: Vec<u8>| u16::from_le_bytes([data[0], data[1]]);
    assert_eq!(
        statusword(sdo.upload(0x6041, 0).await.unwrap()) & 0x6F,
        0x27
    );
    let mut frames = master.subscribe();
    let heartbeat = Frame::new(CanId::Standard(0x77F), &[0x05]).unwrap();
    for _ in 0..5 {
        master.send(heartbeat).await.unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(frames_on(&mut frames, 0x081, 1).await.is_empty());
    // The master goes silent: EMCY 0x8130, communication bit, and the
    // axis faults (0x6007 = 1, fault signal) with its own EMCY 0x8100
    // and the device profile bit.
    let emcys = frames_on(&mut frames, 0x081, 400).await;
    assert_eq!(emcys[0][..3], [0x30, 0x81, 0x31], "{emcys:02X?}");
    assert_eq!(emcys[1][..4], [0x00, 0x81, 0x31, 0x01], "{emcys:02X?}");
    let status = statusword(sdo.upload(0x6041, 0).await.unwrap());
    assert_eq!(status & 0x4F, 0x08, "{status:04X}: fault");
    // The master is back: the error reset of the communication error;
    // the axis's fault stays (register 0x21) until a fault reset, as
    // on the drive.
    master.send(heartbeat).await.unwrap();
    let reset = frames_on(&mut frames, 0x081, 10).await;
    assert_eq!(reset, vec![vec![0, 0, 0x21, 0, 0, 0, 0, 0]]);
}

#[tokio::test(start_paused = true)]
async fn each_injected_fault_of_a_umc_goes_out_as_its_emcy() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add(Product::Umc1bds32, node(1)).unwrap();
    let sdo = sdo(&master, 1);
    let mut frames = master.subscribe();
    for (fault, code, register) in [
        (Fault::OverTemperature, 0x4310u16, 0x09u8),
        (Fault::UnderVoltage, 0x3220, 0x05),
        (Fault::FollowingError, 0x8611, 0x21),
        (Fault::OverCurrent, 0x2310, 0x03),
    ] {
        rack.inject_fault(node(1), fault).unwrap();
        let emcys = frames_on(&mut frames, 0x081, 50).await;
        // One per axis, the axis in the first manufacturer byte.
        let [low, high] = code.to_le_bytes();
        assert_eq!(
            emcys,
            vec![
                vec![low, high, register, 1, 0, 0, 0, 0],
                vec![low, high, register, 2, 0, 0, 0, 0]
            ],
            "{fault}"
        );
        assert_eq!(sdo.upload(0x1001, 0).await.unwrap(), vec![register]);
        rack.clear_fault(node(1), fault).unwrap();
        // Fault reset (bit 7 rising) on both axes: error reset EMCYs.
        for offset in [0u16, 0x800] {
            for controlword in [0u16, 0x80] {
                sdo.download(0x6040 + offset, 0, &controlword.to_le_bytes())
                    .await
                    .unwrap();
            }
        }
        let resets = frames_on(&mut frames, 0x081, 50).await;
        assert_eq!(resets.last().map(|r| r[..3].to_vec()), Some(vec![0, 0, 0]));
        assert_eq!(sdo.upload(0x1001, 0).await.unwrap(), vec![0]);
    }
    // 0x1003 holds the errors, newest first.
    assert_eq!(sdo.upload(0x1003, 1).await.unwrap()[..2], [0x10, 0x23]);
}

#[tokio::test(start_paused = true)]
async fn saved_parameters_are_kept_under_the_data_dir() {
    let dir = std::env::temp_dir().join(format!("candeck-rack-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::with_data_dir(hub.clone(), Some(dir.clone()));
    rack.add(Product::Uio1led, node(3)).unwrap();
    let channel = sdo(&master, 3);
    channel
        .download(0x1017, 0, &250u16.to_le_bytes())
        .await
        .unwrap();
    channel.download(0x1010, 1, b"save").await.unwrap();
    tokio::time::sleep(Duration::from_millis(5)).await;
    drop(rack);
    // A new rack, as after a restart of candeck, starts with it.
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::with_data_dir(hub.clone(), Some(dir.clone()));
    rack.add(Product::Uio1led, node(3)).unwrap();
    assert_eq!(
        sdo(&master, 3).upload(0x1017, 0).await.unwrap(),
        250u16.to_le_bytes()
    );
    drop(rack);
    let _ = std::fs::remove_dir_all(dir);
}

/// CiA 302-3: a program image downloaded to 0x1F50 is kept under the data
/// dir (`devices/uio1led-3.program.bin`) and runs after a restart of
/// candeck: its CRC in 0x1F56, its header's version in 0x100A; a clear
/// removes it.
#[tokio::test(start_paused = true)]
async fn a_downloaded_program_is_kept_under_the_data_dir() {
    use crate::canopen::crc32::crc32;
    use crate::program::ImageHeader;

    let dir = std::env::temp_dir().join(format!("candeck-rack-program-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut image = ImageHeader::encode("9.9.9");
    image.extend((0..4000u32).map(|i| (i * 31) as u8));
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::with_data_dir(hub.clone(), Some(dir.clone()));
    rack.add(Product::Uio1led, node(3)).unwrap();
    let channel = sdo(&master, 3);
    channel.download(0x1F51, 1, &[0]).await.unwrap();
    channel.download(0x1F50, 1, &image).await.unwrap();
    tokio::time::sleep(Duration::from_millis(5)).await;
    let kept = dir.join("devices").join("uio1led-3.program.bin");
    assert_eq!(std::fs::read(&kept).unwrap(), image);
    drop(rack);
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::with_data_dir(hub.clone(), Some(dir.clone()));
    rack.add(Product::Uio1led, node(3)).unwrap();
    let channel = sdo(&master, 3);
    assert_eq!(
        channel.upload(0x1F56, 1).await.unwrap(),
        crc32(&image).to_le_bytes()
    );
    assert_eq!(channel.upload(0x100A, 0).await.unwrap(), b"9.9.9");
    channel.download(0x1F51, 1, &[0]).await.unwrap();
    channel.download(0x1F51, 1, &[3]).await.unwrap();
    tokio::time::sleep(Duration::from_millis(5)).await;
    assert!(!kept.exists());
    drop(rack);
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(start_paused = true)]
async fn bit_errors_make_a_device_error_passive_then_bus_off_and_it_recovers_on_request() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add_device(probe(4)).unwrap();
    let sdo = sdo(&master, 4);
    sdo.download(0x1017, 0, &10u16.to_le_bytes()).await.unwrap();
    let mut frames = master.subscribe();
    let errors_before = master.counters().error_frames;
    rack.inject_fault(node(4), Fault::BitErrors).unwrap();
    let seen = frames_on_any(&mut frames, &[0x704, 0x084], 600).await;
    // Every frame costs 8 − 1: the 19th heartbeat makes it error passive,
    // and EMCY 0x8120 (communication bit 4 in the error register) goes out
    // at once (with the generic bit 0, as every error sets it); an
    // error-passive device keeps working, until the 37th
    // frame's error passes 255: bus-off, that frame and all after it lost.
    let heartbeat = vec![0x7F];
    let passive = vec![0x20, 0x81, 0x11, 0, 0, 0, 0, 0];
    let mut expected = vec![heartbeat.clone(); 19];
    expected.push(passive);
    expected.extend(vec![heartbeat.clone(); 16]);
    assert_eq!(seen, expected);
    assert_eq!(master.counters().error_frames - errors_before, 37);
    let (state, tec, register) = rack
        .with_device(node(4), |core| {
            (
                core.controller().state(),
                core.controller().tec(),
                core.store().int(0x1001, 0),
            )
        })
        .unwrap();
    assert_eq!((state, tec), (crate::can::ErrorState::BusOff, 260));
    assert_eq!(register, Some(0x11));
    // Bus-off, it hears nothing either: an SDO request goes unanswered.
    let request = Frame::new(CanId::Standard(0x604), &[0x40, 0x17, 0x10, 0, 0, 0, 0, 0]).unwrap();
    master.send(request).await.unwrap();
    assert!(frames_on(&mut frames, 0x584, 50).await.is_empty());

    // Clearing the bit errors does not bring it back; the recovery request
    // does (no time at all on an unlimited bus): EMCY 0x8140, an error
    // reset, and the heartbeat again.
    rack.clear_fault(node(4), Fault::BitErrors).unwrap();
    assert!(frames_on(&mut frames, 0x704, 50).await.is_empty());
    rack.clear_fault(node(4), Fault::BusOff).unwrap();
    let seen = frames_on_any(&mut frames, &[0x704, 0x084], 25).await;
    assert_eq!(
        seen[..2],
        [vec![0x40, 0x81, 0x11, 0, 0, 0, 0, 0], vec![0; 8]]
    );
    assert_eq!(seen[2..], vec![heartbeat; 2]);
}

#[tokio::test(start_paused = true)]
async fn a_bus_off_recovery_takes_128_times_11_bit_times_of_the_bus() {
    let hub = VirtualHub::with_bitrate("test", "125k".parse().unwrap());
    let rack = Rack::new(hub.clone());
    rack.add_device(probe(4)).unwrap();
    rack.inject_fault(node(4), Fault::BusOff).unwrap();
    let start = tokio::time::Instant::now();
    rack.clear_fault(node(4), Fault::BusOff).unwrap();
    let state = || {
        rack.with_device(node(4), |core| core.controller().state())
            .unwrap()
    };
    // 1408 bits at 125 kbit/s: 11.264 ms; the runner looks every ms.
    tokio::time::sleep(Duration::from_millis(11)).await;
    assert_eq!(state(), crate::can::ErrorState::BusOff);
    tokio::time::sleep(Duration::from_millis(2)).await;
    assert_eq!(state(), crate::can::ErrorState::ErrorActive);
    assert!(start.elapsed() < Duration::from_millis(14));
}

#[tokio::test(start_paused = true)]
async fn bus_off_in_operational_is_a_communication_error_for_0x1029() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add_device(probe(4)).unwrap();
    let sdo = sdo(&master, 4);
    sdo.download(0x1017, 0, &10u16.to_le_bytes()).await.unwrap();
    // 0x1029.1 = 0: pre-operational on a communication error (CiA 301
    // §7.2.8.2.1.1; bus-off is one).
    sdo.download(0x1029, 1, &[0]).await.unwrap();
    master
        .send(Frame::new(CanId::Standard(0), &[0x01, 4]).unwrap())
        .await
        .unwrap();
    let mut frames = master.subscribe();
    assert_eq!(frames_on(&mut frames, 0x704, 25).await, vec![vec![0x05]; 2]);
    rack.inject_fault(node(4), Fault::BusOff).unwrap();
    assert!(frames_on(&mut frames, 0x704, 50).await.is_empty());
    rack.clear_fault(node(4), Fault::BusOff).unwrap();
    let seen = frames_on(&mut frames, 0x704, 25).await;
    assert_eq!(seen, vec![vec![0x7F]; 2]);
}

/// An LSS transaction of a master on `master`, run to its end.
async fn lss(
    master: &Bus,
    service: crate::canopen::lss::LssService,
) -> crate::canopen::lss::LssOutcome {
    let lss = candeck_gateway::BusLss::new(master.clone());
    lss.begin()
        .unwrap()
        .run(service)
        .await
        .unwrap()
        .unwrap_or_else(|err| panic!("{service:?}: {err}"))
}

fn lss_device(product: Product, serial: Option<u32>) -> DeviceSpec {
    DeviceSpec {
        product,
        node: None,
        serial,
        load: None,
    }
}

#[tokio::test(start_paused = true)]
async fn unconfigured_devices_are_silent_until_lss_gives_them_a_node_id() {
    use crate::canopen::lss::{LssAddress, LssOutcome, LssService, LssState};
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let mut frames = master.subscribe();
    let rack = Rack::new(hub.clone());
    rack.add_all(&[
        DeviceSpec::at(Product::Jmc, node(2)),
        lss_device(Product::Uio1led, None),
        lss_device(Product::Uio1led, None),
        lss_device(Product::Umc1bds32, Some(0xC0FFEE)),
    ])
    .unwrap();
    // Only the configured device boots up; nothing else is heard.
    let heard = frames_on_any(&mut frames, &(0x700..0x7FF).collect::<Vec<_>>(), 500).await;
    assert_eq!(heard, vec![vec![0]]);
    assert_eq!(rack.devices().len(), 1);
    assert_eq!(rack.loose_devices().len(), 3);
    let LssOutcome::FoundAll(mut found) = lss(&master, LssService::FastscanAll).await else {
        panic!("no Fastscan result");
    };
    found.sort();
    let uio = |serial| LssAddress {
        vendor_id: 0x4A2,
        product_code: 0x4101,
        revision: 1,
        serial,
    };
    let umc = LssAddress {
        vendor_id: 0x4A2,
        product_code: 0x1001,
        revision: 0x0100_0004,
        serial: 0xC0FFEE,
    };
    // Two of the same product told apart by their serial numbers.
    assert_eq!(found, vec![umc, uio(0x101), uio(0x102)]);
    // Configure one, stored: it boots up as node 10 and answers SDO there.
    let mut frames = master.subscribe();
    lss(&master, LssService::SwitchSelective(uio(0x102))).await;
    lss(&master, LssService::ConfigureNodeId(10)).await;
    lss(&master, LssService::StoreConfiguration).await;
    lss(&master, LssService::SwitchGlobal(LssState::Waiting)).await;
    assert_eq!(frames_on(&mut frames, 0x70A, 50).await, vec![vec![0]]);
    assert_eq!(
        sdo(&master, 10).upload(0x1018, 4).await.unwrap(),
        0x102u32.to_le_bytes()
    );
    assert_eq!(
        rack.devices()
            .iter()
            .map(|(node, product, _)| (node.get(), *product))
            .collect::<Vec<_>>(),
        vec![(2, Some(Product::Jmc)), (10, Some(Product::Uio1led))]
    );
    // The other, not stored: node 11 until its next reset.
    lss(&master, LssService::SwitchSelective(uio(0x101))).await;
    lss(&master, LssService::ConfigureNodeId(11)).await;
    lss(&master, LssService::SwitchGlobal(LssState::Waiting)).await;
    assert_eq!(frames_on(&mut frames, 0x70B, 50).await, vec![vec![0]]);
    // Reset node: the stored node-ID survives, the other is lost.
    let reset_all = crate::canopen::nmt::NmtMessage::new(
        crate::canopen::nmt::NmtCommand::ResetNode,
        crate::canopen::nmt::NmtTarget::All,
    );
    master.send(reset_all.encode()).await.unwrap();
    let boot_ups = frames_on_any(&mut frames, &[0x702, 0x70A, 0x70B], 100).await;
    assert_eq!(boot_ups.len(), 2, "{boot_ups:?}");
    assert_eq!(sdo(&master, 10).upload(0x1000, 0).await.unwrap().len(), 4);
    assert!(sdo(&master, 11).upload(0x1000, 0).await.is_err());
    let LssOutcome::FoundAll(found) = lss(&master, LssService::FastscanAll).await else {
        panic!("no Fastscan result");
    };
    assert_eq!(found.len(), 2, "{found:?}");
}

#[tokio::test(start_paused = true)]
async fn a_node_id_saved_in_0x2040_is_the_one_the_device_boots_with() {
    let dir = std::env::temp_dir().join(format!("candeck-rack-2040-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let mut frames = master.subscribe();
    let rack = Rack::with_data_dir(hub.clone(), Some(dir.clone()));
    rack.add(Product::Uio1led, node(3)).unwrap();
    let channel = sdo(&master, 3);
    channel.download(0x2040, 1, &[9]).await.unwrap();
    // Written but not saved: a reset keeps node 3.
    let reset = |target| {
        crate::canopen::nmt::NmtMessage::new(
            crate::canopen::nmt::NmtCommand::ResetNode,
            crate::canopen::nmt::NmtTarget::Node(node(target)),
        )
        .encode()
    };
    master.send(reset(3)).await.unwrap();
    assert_eq!(
        frames_on_any(&mut frames, &[0x703, 0x709], 50).await,
        vec![vec![0], vec![0]]
    );
    channel.download(0x2040, 1, &[9]).await.unwrap();
    channel.download(0x1010, 1, b"save").await.unwrap();
    master.send(reset(3)).await.unwrap();
    assert_eq!(frames_on(&mut frames, 0x709, 50).await, vec![vec![0]]);
    let moved = sdo(&master, 9);
    assert_eq!(moved.upload(0x2040, 1).await.unwrap(), vec![9]);
    // What followed the node-ID follows the new one: the TPDO COB-ID.
    let cob_id = moved.upload(0x1800, 1).await.unwrap();
    assert_eq!(
        u32::from_le_bytes(cob_id.try_into().unwrap()) & 0x7FF,
        0x189
    );
    assert_eq!(moved.upload(0x1018, 4).await.unwrap(), 3u32.to_le_bytes());
    assert!(channel.upload(0x1000, 0).await.is_err());
    assert_eq!(rack.is_plugged(node(9)), Some(true));
    assert_eq!(rack.is_plugged(node(3)), None);
    tokio::time::sleep(Duration::from_millis(5)).await;
    drop(rack);
    // A restart (vbus --data-dir) with the same device list boots it as 9.
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let mut frames = master.subscribe();
    let rack = Rack::with_data_dir(hub.clone(), Some(dir.clone()));
    rack.add(Product::Uio1led, node(3)).unwrap();
    assert_eq!(
        frames_on_any(&mut frames, &[0x703, 0x709], 50).await,
        vec![vec![0]]
    );
    assert_eq!(sdo(&master, 9).upload(0x2040, 1).await.unwrap(), vec![9]);
    drop(rack);
    let _ = std::fs::remove_dir_all(dir);
}

#[tokio::test(start_paused = true)]
async fn a_stored_lss_node_id_survives_a_restart_under_the_data_dir() {
    use crate::canopen::lss::{LssOutcome, LssService, LssState};
    let dir = std::env::temp_dir().join(format!("candeck-rack-lss-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let devices = [lss_device(Product::Jmc, Some(77))];
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let mut frames = master.subscribe();
    let rack = Rack::with_data_dir(hub.clone(), Some(dir.clone()));
    rack.add_all(&devices).unwrap();
    let LssOutcome::FoundAll(found) = lss(&master, LssService::FastscanAll).await else {
        panic!("no Fastscan result");
    };
    assert_eq!(found.len(), 1);
    lss(&master, LssService::SwitchSelective(found[0])).await;
    lss(&master, LssService::ConfigureNodeId(20)).await;
    lss(&master, LssService::StoreConfiguration).await;
    lss(&master, LssService::SwitchGlobal(LssState::Waiting)).await;
    assert_eq!(frames_on(&mut frames, 0x714, 50).await, vec![vec![0]]);
    tokio::time::sleep(Duration::from_millis(5)).await;
    drop(rack);
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let mut frames = master.subscribe();
    let rack = Rack::with_data_dir(hub.clone(), Some(dir.clone()));
    rack.add_all(&devices).unwrap();
    assert_eq!(frames_on(&mut frames, 0x714, 50).await, vec![vec![0]]);
    assert_eq!(
        sdo(&master, 20).upload(0x1018, 4).await.unwrap(),
        77u32.to_le_bytes()
    );
    drop(rack);
    let _ = std::fs::remove_dir_all(dir);
}

/// UMC manual chapter 2 §1.4.8 (0x6007, Table 2.10) and CiA 402-2: NMT
/// reset communication is an abort connection event as the stop and
/// pre-operational transitions are. A VL move in operational with the
/// factory 0x6007 (1, fault signal) ends in fault with EMCY 0x8100 for the
/// axis, after the boot-up of the reset.
#[tokio::test(start_paused = true)]
async fn reset_communication_aborts_the_connection_as_0x6007_says() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add(Product::Umc1bds32, node(1)).unwrap();
    let sdo = sdo(&master, 1);
    let nmt = |command| {
        crate::canopen::nmt::NmtMessage::new(command, crate::canopen::nmt::NmtTarget::Node(node(1)))
            .encode()
    };
    master
        .send(nmt(crate::canopen::nmt::NmtCommand::Start))
        .await
        .unwrap();
    sdo.download(0x6060, 0, &[2]).await.unwrap();
    sdo.download(0x6042, 0, &300i16.to_le_bytes())
        .await
        .unwrap();
    for controlword in [6u16, 7, 15] {
        sdo.download(0x6040, 0, &controlword.to_le_bytes())
            .await
            .unwrap();
    }
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let int16 = |data: Vec<u8>| i16::from_le_bytes([data[0], data[1]]);
    assert_eq!(int16(sdo.upload(0x6044, 0).await.unwrap()), 300);
    let mut frames = master.subscribe();
    // 000#8201
    master
        .send(nmt(crate::canopen::nmt::NmtCommand::ResetCommunication))
        .await
        .unwrap();
    let seen = frames_on_any(&mut frames, &[0x701, 0x081], 50).await;
    assert_eq!(seen[0], vec![0x00], "boot-up first: {seen:02X?}");
    assert_eq!(seen[1][..4], [0x00, 0x81, 0x21, 0x01], "{seen:02X?}");
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let status = int16(sdo.upload(0x6041, 0).await.unwrap()) as u16;
    assert_eq!(status & 0x4F, 0x08, "{status:04X}: fault");
    assert_eq!(int16(sdo.upload(0x6044, 0).await.unwrap()), 0);
}

/// The same with 0x6007 = 3 (quick stop command): the axis ramps down and
/// stays in quick stop active, no fault.
#[tokio::test(start_paused = true)]
async fn reset_communication_quick_stops_when_0x6007_says_so() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add(Product::Umc1bds32, node(1)).unwrap();
    let sdo = sdo(&master, 1);
    let nmt = |command| {
        crate::canopen::nmt::NmtMessage::new(command, crate::canopen::nmt::NmtTarget::Node(node(1)))
            .encode()
    };
    master
        .send(nmt(crate::canopen::nmt::NmtCommand::Start))
        .await
        .unwrap();
    sdo.download(0x6007, 0, &3i16.to_le_bytes()).await.unwrap();
    sdo.download(0x605A, 0, &6i16.to_le_bytes()).await.unwrap();
    sdo.download(0x6060, 0, &[2]).await.unwrap();
    sdo.download(0x6042, 0, &300i16.to_le_bytes())
        .await
        .unwrap();
    for controlword in [6u16, 7, 15] {
        sdo.download(0x6040, 0, &controlword.to_le_bytes())
            .await
            .unwrap();
    }
    tokio::time::sleep(Duration::from_millis(2500)).await;
    master
        .send(nmt(crate::canopen::nmt::NmtCommand::ResetCommunication))
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let int16 = |data: Vec<u8>| i16::from_le_bytes([data[0], data[1]]);
    let status = int16(sdo.upload(0x6041, 0).await.unwrap()) as u16;
    assert_eq!(status & 0x6F, 0x07, "{status:04X}: quick stop active");
    assert_eq!(int16(sdo.upload(0x6044, 0).await.unwrap()), 0);
}

/// The frames of a timed bus (ISO 11898-1: each frame's bits at the bit
/// rate, after the frame in progress) as a master sees a virtual device
/// answer at 500 kbit/s: an SDO exchange is two 8-byte frames (135 bits
/// each with worst-case stuffing, 540 µs), a TPDO answers SYNC (a 0-byte
/// frame, 57 bits) no sooner than both have crossed, and the boot-up of a
/// reset node (1 byte, 65 bits) comes after the NMT command (2 bytes, 75
/// bits) and its own frame.
#[tokio::test(start_paused = true)]
async fn a_device_answers_no_sooner_than_the_wire_allows() {
    use crate::can::Bitrate;
    use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtTarget};

    let hub = VirtualHub::with_bitrate("test", Bitrate::bits_per_second(500_000));
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add(Product::Uio1led, node(3)).unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let sdo = sdo(&master, 3);
    let bit = Duration::from_micros(2);
    for _ in 0..3 {
        let t0 = tokio::time::Instant::now();
        sdo.upload(0x1000, 0).await.unwrap();
        let took = t0.elapsed();
        assert!(took >= bit * 270, "SDO round trip {took:?}");
    }
    // TPDO1 on every SYNC, the error register mapped.
    sdo.download(0x1A00, 1, &0x1001_0008u32.to_le_bytes())
        .await
        .unwrap();
    sdo.download(0x1A00, 0, &[1]).await.unwrap();
    sdo.download(0x1800, 1, &0x183u32.to_le_bytes())
        .await
        .unwrap();
    master
        .send(NmtMessage::new(NmtCommand::Start, NmtTarget::Node(node(3))).encode())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(10)).await;
    let mut frames = master.subscribe();
    let sync = Frame::new(CanId::Standard(0x080), &[]).unwrap();
    let t0 = tokio::time::Instant::now();
    master.send(sync).await.unwrap();
    loop {
        let envelope = frames.recv().await.unwrap();
        if envelope.frame.id() == CanId::Standard(0x183) {
            let bits = crate::can::timing::frame_bits(&envelope.frame);
            let took = t0.elapsed();
            assert!(took >= bit * (57 + bits), "SYNC → TPDO {took:?}");
            break;
        }
    }
    let t0 = tokio::time::Instant::now();
    master
        .send(NmtMessage::new(NmtCommand::ResetNode, NmtTarget::Node(node(3))).encode())
        .await
        .unwrap();
    loop {
        let envelope = frames.recv().await.unwrap();
        if envelope.frame.id() == CanId::Standard(0x703) {
            let took = t0.elapsed();
            assert!(took >= bit * (75 + 65), "NMT → boot-up {took:?}");
            break;
        }
    }
}

/// CiA 301 table 21 (0x8110 "CAN overrun (objects lost)") as CANopenNode
/// reports a receive buffer overflow: a burst that overflows the devices'
/// receive queue gets EMCY 0x8110 with the communication bit (register
/// 0x11) from each device, and the error reset a cycle later.
#[tokio::test(start_paused = true)]
async fn a_receive_overrun_is_reported_with_emcy_0x8110() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add(Product::Uio1led, node(3)).unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut frames = master.subscribe();
    let flood = Frame::new(CanId::Standard(0x181), &[0; 8]).unwrap();
    // An unlimited bus hands every frame over at once: far more than the
    // devices' receive queue holds, before they run again.
    for _ in 0..crate::can::bus::DEFAULT_RX_QUEUE + 100 {
        master.try_send(flood).unwrap();
    }
    let emcys = frames_on(&mut frames, 0x083, 20).await;
    assert_eq!(
        emcys,
        vec![vec![0x10, 0x81, 0x11, 0, 0, 0, 0, 0], vec![0; 8]],
        "{emcys:02X?}"
    );
}

/// A device starved by a flood of higher-priority frames (ISO 11898-1
/// arbitration) sends its current heartbeat when the bus frees, not the
/// backlog of those it could not send meanwhile.
#[tokio::test(start_paused = true)]
async fn a_starved_device_sends_no_burst_of_stale_heartbeats() {
    use crate::can::Bitrate;

    let hub = VirtualHub::with_bitrate("test", Bitrate::bits_per_second(125_000));
    let master = hub.attach();
    let flood = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add(Product::Uio1led, node(3)).unwrap();
    let sdo = sdo(&master, 3);
    sdo.download(0x1017, 0, &100u16.to_le_bytes())
        .await
        .unwrap();
    let mut frames = master.subscribe();
    // 2 s of frames that win every arbitration (1.08 ms each).
    let flooding = tokio::spawn(async move {
        let frame = Frame::new(CanId::Standard(0x080), &[0; 8]).unwrap();
        for _ in 0..1900 {
            flood.send(frame).await.unwrap();
        }
    });
    let mut heartbeats = Vec::new();
    let until = tokio::time::Instant::now() + Duration::from_millis(2600);
    while let Ok(Ok(envelope)) = tokio::time::timeout_at(until, frames.recv()).await {
        if envelope.frame.id() == CanId::Standard(0x703) {
            heartbeats.push(tokio::time::Instant::now());
        }
    }
    flooding.await.unwrap();
    // After the flood, heartbeats 100 ms apart again: never two within
    // 10 ms of each other.
    for pair in heartbeats.windows(2) {
        let gap = pair[1] - pair[0];
        assert!(gap >= Duration::from_millis(10), "{gap:?}");
    }
    assert!(heartbeats.len() >= 3, "{}", heartbeats.len());
}

/// The JMC manual ("Set the baud rate and station number"): the drive's
/// node-ID is its rotary switches S1/S3, and the manual has no LSS: a JMC
/// at a node answers no LSS master (`jmc@lss` is the LSS-capable variant
/// the LSS demos use, `unconfigured_devices_are_silent_until_lss_gives_them_a_node_id`);
/// the UniSwarm devices answer as before.
#[tokio::test(start_paused = true)]
async fn a_jmc_at_its_switches_node_id_answers_no_lss_master() {
    let hub = VirtualHub::new("test");
    let master = hub.attach();
    let rack = Rack::new(hub.clone());
    rack.add(Product::Jmc, node(2)).unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut frames = master.subscribe();
    // Switch state global: configuration, then inquire node-ID (0x5E).
    let request = |head: &[u8]| {
        let mut data = [0u8; 8];
        data[..head.len()].copy_from_slice(head);
        Frame::new(CanId::Standard(0x7E5), &data).unwrap()
    };
    master.send(request(&[0x04, 1])).await.unwrap();
    master.send(request(&[0x5E])).await.unwrap();
    assert!(frames_on(&mut frames, 0x7E4, 50).await.is_empty());
    // A UMC answers as before.
    rack.add(Product::Umc1bds32, node(1)).unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    master.send(request(&[0x04, 1])).await.unwrap();
    master.send(request(&[0x5E])).await.unwrap();
    assert_eq!(
        frames_on(&mut frames, 0x7E4, 50).await,
        vec![vec![0x5E, 1, 0, 0, 0, 0, 0, 0]]
    );
}
