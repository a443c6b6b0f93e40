use super::*;
use crate::Bitrate;
use crate::bus::{BusError, RecvError};
use crate::frame::{CanId, Direction};

fn frame(id: u32, data: &[u8]) -> Frame {
    Frame::new(CanId::standard(id).unwrap(), data).unwrap()
}

#[tokio::test]
async fn frames_reach_every_other_attachment_in_order_never_the_sender() {
    let hub = VirtualHub::new("test");
    let a = hub.attach();
    let b = hub.attach();
    let c = hub.attach();
    let mut rx_a = a.subscribe();
    let mut rx_b = b.subscribe();
    let mut rx_c = c.subscribe();

    for i in 0..100u32 {
        a.send(frame(0x100 + i, &[i as u8])).await.unwrap();
    }
    b.send(frame(0x7FF, &[])).await.unwrap();

    for rx in [&mut rx_b, &mut rx_c] {
        for i in 0..100u32 {
            let got = rx.recv().await.unwrap();
            assert_eq!(got.frame, frame(0x100 + i, &[i as u8]));
            assert_eq!(got.direction, Direction::Rx);
        }
    }
    // b does not hear itself; c and a hear b.
    assert_eq!(rx_b.try_recv().unwrap(), None);
    assert_eq!(rx_c.recv().await.unwrap().frame, frame(0x7FF, &[]));
    assert_eq!(rx_a.recv().await.unwrap().frame, frame(0x7FF, &[]));
    assert_eq!(rx_a.try_recv().unwrap(), None);
    assert_eq!(hub.frames_total(), 101);
    assert_eq!(a.counters().tx_frames, 100);
    // Each attachment counts what it heard, the sender's own frames not.
    assert_eq!(
        [
            a.counters().rx_frames,
            b.counters().rx_frames,
            c.counters().rx_frames
        ],
        [1, 100, 101]
    );
    assert_eq!(c.counters().rx_bits, hub.bits_total());
}

#[tokio::test]
async fn a_monitor_sees_its_own_frames_as_tx() {
    let hub = VirtualHub::new("test");
    let a = hub.attach();
    let b = hub.attach();
    let mut monitor = a.monitor();
    a.send(frame(1, &[1])).await.unwrap();
    b.send(frame(2, &[2])).await.unwrap();
    let first = monitor.recv().await.unwrap();
    let second = monitor.recv().await.unwrap();
    assert_eq!(
        (first.frame, first.direction),
        (frame(1, &[1]), Direction::Tx)
    );
    assert_eq!(
        (second.frame, second.direction),
        (frame(2, &[2]), Direction::Rx)
    );
}

#[tokio::test]
async fn a_slow_reader_loses_oldest_frames_and_is_told_without_slowing_others() {
    let hub = VirtualHub::with_queue("test", 16);
    let sender = hub.attach();
    let slow = hub.attach();
    let fast = hub.attach();
    let mut slow_rx = slow.subscribe();
    let mut fast_rx = fast.subscribe();
    for i in 0..40u32 {
        sender.send(frame(i, &[])).await.unwrap();
        // The fast reader keeps up and sees every frame.
        assert_eq!(fast_rx.recv().await.unwrap().frame, frame(i, &[]));
    }
    assert_eq!(slow_rx.recv().await, Err(RecvError::Lagged(24)));
    assert_eq!(slow_rx.recv().await.unwrap().frame, frame(24, &[]));
    assert_eq!(slow.counters().rx_overruns, 24);
}

#[tokio::test]
async fn a_forced_down_bus_refuses_to_send_with_the_reason() {
    let hub = VirtualHub::new("line");
    let a = hub.attach();
    hub.set_status(BusStatus::new(BusState::BusOff, "injected"));
    let err = a.send(frame(1, &[])).await.unwrap_err();
    assert_eq!(
        err,
        BusError::NotUp {
            bus: "line".into(),
            state: BusState::BusOff,
            reason: Some("injected".into())
        }
    );
    assert_eq!(err.to_string(), "bus line is bus_off: injected");
    assert_eq!(a.counters().tx_errors, 1);
    hub.set_status(BusStatus::up());
    a.send(frame(1, &[])).await.unwrap();
}

#[tokio::test]
async fn receivers_see_closed_when_their_attachment_is_gone() {
    let hub = VirtualHub::new("gone");
    let mut rx = {
        let bus = hub.attach();
        bus.subscribe()
    };
    assert_eq!(hub.attachments(), 0);
    assert_eq!(rx.recv().await, Err(RecvError::Closed));
}

/// Receives `count` frames; each with the time it arrived since `t0`.
async fn arrivals(
    rx: &mut crate::FrameReceiver,
    count: usize,
    t0: tokio::time::Instant,
) -> Vec<(Frame, std::time::Duration)> {
    let mut out = Vec::new();
    while out.len() < count {
        let frame = rx.recv().await.unwrap().frame;
        out.push((frame, t0.elapsed()));
    }
    out
}

/// ISO 11898-1 arbitration at 125 kbit/s (8 µs a bit): a node that
/// keeps high-priority frames queued wins every round, so a heartbeat
/// queued with them goes only when the flood's queue is empty.
#[tokio::test(start_paused = true)]
async fn at_125_kbit_s_a_flood_holds_a_low_priority_heartbeat_back() {
    use crate::timing::frame_bits;
    use std::time::Duration;

    let hub = VirtualHub::with_bitrate("test", "125k".parse().unwrap());
    let flood = hub.attach();
    let device = hub.attach();
    let master = hub.attach();
    let mut rx = master.subscribe();
    let t0 = tokio::time::Instant::now();
    for i in 0..200u32 {
        flood.try_send(frame(0x081, &[i as u8; 8])).unwrap();
    }
    device.send(frame(0x705, &[0x05])).await.unwrap();
    let got = arrivals(&mut rx, 201, t0).await;
    let bit = Duration::from_micros(8);
    let full = frame_bits(&frame(0x081, &[0; 8]));
    assert_eq!(full, 135);
    // A frame arrives once its last bit has crossed the bus, at the tick
    // of the paused clock's timers (one millisecond) at or after it.
    let on_time =
        |at: Duration, crossed: Duration| at >= crossed && at < crossed + Duration::from_millis(1);
    for (n, (frame, at)) in got[..200].iter().enumerate() {
        assert_eq!(frame.id(), CanId::Standard(0x081));
        let crossed = bit * full * (n as u32 + 1);
        assert!(
            on_time(*at, crossed),
            "flood frame {n}: {at:?}, {crossed:?}"
        );
    }
    let (heartbeat, at) = got[200];
    assert_eq!(heartbeat.id(), CanId::Standard(0x705));
    let crossed = bit * (200 * full + 65);
    assert!(on_time(at, crossed), "heartbeat: {at:?}, {crossed:?}");
    // 216 ms late: a consumer watching it with 200 ms would have
    // declared the node lost, as on a real bus.
    assert!(at > Duration::from_millis(215));
    assert_eq!(hub.busy_bits(), u64::from(200 * full + 65));
}

/// At 100 % load (a sender that keeps its transmit queue full), the
/// frames a second are the bit rate over the frame's bits: 8-byte
/// standard frames are 135 bits with worst-case stuffing.
#[tokio::test(start_paused = true)]
async fn frames_a_second_at_full_load_are_the_bit_rate_over_the_frame_length() {
    for bitrate in [125_000u32, 250_000, 500_000, 1_000_000] {
        let hub = VirtualHub::with_bitrate("test", Bitrate::bits_per_second(bitrate));
        let sender = hub.attach();
        let receiver = hub.attach();
        let mut rx = receiver.subscribe();
        let frames = 3_000usize;
        let t0 = tokio::time::Instant::now();
        let task = tokio::spawn(async move {
            for i in 0..frames {
                sender.send(frame(0x181, &[i as u8; 8])).await.unwrap();
            }
            sender
        });
        let got = arrivals(&mut rx, frames, t0).await;
        let elapsed = got.last().unwrap().1.as_secs_f64();
        let measured = frames as f64 / elapsed;
        let arithmetic = f64::from(bitrate) / 135.0;
        assert!(
            (measured / arithmetic - 1.0).abs() < 0.02,
            "{bitrate} bit/s: {measured:.1} frames/s, arithmetic {arithmetic:.1}"
        );
        // The counters measure the occupancy: 100 % of the bit rate.
        let load = receiver.counters().rx_bits as f64 / elapsed / f64::from(bitrate);
        assert!((load - 1.0).abs() < 0.02, "{bitrate} bit/s: load {load}");
        let sender = task.await.unwrap();
        assert_eq!(sender.counters().tx_frames, frames as u64);
    }
}

/// A socketcand client that sends and hangs up at once (`candeck nmt`)
/// has handed its frames to the bus: they cross after it is gone.
#[tokio::test(start_paused = true)]
async fn frames_queued_by_a_sender_that_detaches_still_cross() {
    let hub = VirtualHub::with_bitrate("test", "125k".parse().unwrap());
    let listener = hub.attach();
    let mut rx = listener.subscribe();
    let sender = hub.attach();
    for i in 0..3u8 {
        sender.try_send(frame(0x000, &[1, i])).unwrap();
    }
    drop(sender);
    for i in 0..3u8 {
        assert_eq!(rx.recv().await.unwrap().frame, frame(0x000, &[1, i]));
    }
}

#[tokio::test(start_paused = true)]
async fn a_full_transmit_queue_refuses_try_send_and_makes_send_wait() {
    use crate::bus::DEFAULT_TX_QUEUE;

    let hub = VirtualHub::with_bitrate("test", "125k".parse().unwrap());
    let sender = hub.attach();
    for _ in 0..DEFAULT_TX_QUEUE {
        sender.try_send(frame(0x181, &[0; 8])).unwrap();
    }
    assert_eq!(
        sender.try_send(frame(0x181, &[0; 8])),
        Err(BusError::TxQueueFull("test".into()))
    );
    // Once the first frame has crossed (1080 µs; the paused clock's
    // timer tick at or after it) there is room again.
    let t0 = tokio::time::Instant::now();
    sender.send(frame(0x181, &[0; 8])).await.unwrap();
    let waited = t0.elapsed();
    assert!(
        waited >= std::time::Duration::from_micros(1080)
            && waited < std::time::Duration::from_micros(2080),
        "{waited:?}"
    );
}

#[tokio::test]
async fn a_busy_sender_keeps_its_whole_receive_window_for_others() {
    let hub = VirtualHub::with_queue("test", 16);
    let chatty = hub.attach();
    let other = hub.attach();
    let mut chatty_rx = chatty.subscribe();
    other.send(frame(0x581, &[1])).await.unwrap();
    // Far more of its own frames than its queue holds.
    for i in 0..100u32 {
        chatty.send(frame(0x601, &[i as u8])).await.unwrap();
    }
    assert_eq!(chatty_rx.recv().await.unwrap().frame, frame(0x581, &[1]));
    assert_eq!(chatty_rx.try_recv().unwrap(), None);
}

#[tokio::test]
async fn bit_errors_make_an_attachment_error_passive_then_bus_off_and_the_others_see_error_frames()
{
    let hub = VirtualHub::new("line");
    let node = hub.attach();
    let gateway = hub.attach();
    let mut rx = gateway.subscribe();
    node.controller_fault(ControllerFault::BitErrors).unwrap();
    for i in 0..18u8 {
        node.send(frame(0x181, &[i])).await.unwrap();
    }
    // 18 × (8 − 1) = 126: still error active.
    assert_eq!(node.state(), BusState::Up);
    assert_eq!(node.counters().tec, 126);
    node.send(frame(0x181, &[18])).await.unwrap();
    assert_eq!(node.state(), BusState::ErrorPassive);
    assert_eq!(node.counters().tec, 133);
    // An error-passive node keeps working: every frame crossed, each after
    // an error frame.
    for i in 0..19u8 {
        let error = rx.recv().await.unwrap().frame;
        assert_eq!(error.error_class(), Some(0x88));
        assert_eq!(error.data(), &[0, 0, 0x04, 0, 0, 0, 0, 0]);
        assert_eq!(rx.recv().await.unwrap().frame, frame(0x181, &[i]));
    }
    // The receiver's REC went up by one for each error and down for each
    // good frame.
    assert_eq!(gateway.counters().rec, 0);
    assert_eq!(gateway.counters().error_frames, 19);
    for i in 19..36u8 {
        node.send(frame(0x181, &[i])).await.unwrap();
    }
    assert_eq!(node.counters().tec, 252);
    // The 37th frame's error passes 255: bus-off, and the frame is lost.
    node.send(frame(0x181, &[36])).await.unwrap();
    assert_eq!(node.state(), BusState::BusOff);
    assert_eq!(node.counters().tec, 260);
    let err = node.send(frame(0x181, &[37])).await.unwrap_err();
    assert!(
        matches!(
            err,
            BusError::NotUp {
                state: BusState::BusOff,
                ..
            }
        ),
        "{err:?}"
    );
    let mut seen = Vec::new();
    while let Ok(Some(got)) = rx.try_recv() {
        seen.push(got.frame);
    }
    // 17 frames with their errors, then the last error alone.
    assert_eq!(seen.len(), 17 * 2 + 1);
    assert!(seen.last().unwrap().is_error());
    // The gateway's own controller is unharmed.
    assert_eq!(gateway.state(), BusState::Up);
}

#[tokio::test]
async fn a_bus_off_attachment_hears_nothing_and_recovers_on_request() {
    let hub = VirtualHub::new("line");
    let node = hub.attach();
    let other = hub.attach();
    let mut rx = node.subscribe();
    node.controller_fault(ControllerFault::BusOff).unwrap();
    assert_eq!(node.state(), BusState::BusOff);
    other.send(frame(0x80, &[])).await.unwrap();
    assert_eq!(rx.try_recv().unwrap(), None);
    // Unlimited: the 128 × 11 recessive bits take no time.
    node.controller_fault(ControllerFault::Recover).unwrap();
    assert_eq!(node.state(), BusState::Up);
    assert_eq!((node.counters().tec, node.counters().rec), (0, 0));
    other.send(frame(0x80, &[])).await.unwrap();
    assert_eq!(rx.recv().await.unwrap().frame, frame(0x80, &[]));
}

#[tokio::test(start_paused = true)]
async fn bus_off_recovery_takes_128_times_11_bit_times_at_the_bit_rate() {
    let hub = VirtualHub::with_bitrate("line", "125k".parse().unwrap());
    let node = hub.attach();
    node.controller_fault(ControllerFault::BusOff).unwrap();
    let start = tokio::time::Instant::now();
    node.controller_fault(ControllerFault::Recover).unwrap();
    let mut status = node.watch_status();
    status.wait_for(|s| s.state == BusState::Up).await.unwrap();
    // 1408 bits at 125 kbit/s: 11.264 ms, on tokio's millisecond timer.
    let elapsed = start.elapsed();
    let exact = std::time::Duration::from_micros(11_264);
    assert!(
        elapsed >= exact && elapsed < exact + std::time::Duration::from_millis(1),
        "{elapsed:?}"
    );
    // Forced down and back up, an attachment shows its controller again.
    node.controller_fault(ControllerFault::BusOff).unwrap();
    hub.set_status(BusStatus::new(BusState::Down, "cable pulled"));
    assert_eq!(node.state(), BusState::Down);
    hub.set_status(BusStatus::up());
    assert_eq!(node.state(), BusState::BusOff);
}

/// A lone frame on an idle bus takes its time too (ISO 11898-1: its bits
/// at the bit rate): an 8-byte standard frame at 500 kbit/s is 135 bits,
/// 270 µs, and reaches the others no sooner.
#[tokio::test(start_paused = true)]
async fn a_lone_frame_on_an_idle_bus_arrives_after_its_bits_have_crossed() {
    use std::time::Duration;

    let hub = VirtualHub::with_bitrate("test", "500k".parse().unwrap());
    let sender = hub.attach();
    let receiver = hub.attach();
    let mut rx = receiver.subscribe();
    for _ in 0..3 {
        tokio::time::sleep(Duration::from_millis(7)).await;
        let t0 = tokio::time::Instant::now();
        sender
            .send(frame(0x601, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]))
            .await
            .unwrap();
        let got = arrivals(&mut rx, 1, t0).await;
        let at = got[0].1;
        assert!(at >= Duration::from_micros(270), "{at:?}");
        assert!(at < Duration::from_micros(1270), "{at:?}");
    }
}

/// A request and its answer (an SDO exchange: two 8-byte frames) cost the
/// wire at least two frame times, 540 µs at 500 kbit/s; a frame queued
/// while another crosses goes after it.
#[tokio::test(start_paused = true)]
async fn a_request_and_its_answer_take_at_least_two_frame_times() {
    use std::time::Duration;

    let hub = VirtualHub::with_bitrate("test", "500k".parse().unwrap());
    let master = hub.attach();
    let device = hub.attach();
    let mut requests = device.subscribe();
    let answers = tokio::spawn(async move {
        while let Ok(envelope) = requests.recv().await {
            let mut data = envelope.frame.data().to_vec();
            data[0] = 0x43;
            device.send(frame(0x581, &data)).await.unwrap();
        }
    });
    let mut rx = master.subscribe();
    tokio::time::sleep(Duration::from_millis(3)).await;
    let t0 = tokio::time::Instant::now();
    master
        .send(frame(0x601, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]))
        .await
        .unwrap();
    let got = arrivals(&mut rx, 1, t0).await;
    assert_eq!(got[0].0.id(), CanId::Standard(0x581));
    assert!(got[0].1 >= Duration::from_micros(540), "{:?}", got[0].1);
    answers.abort();
}

/// On tokio's real clock too (finer than its millisecond timers): a lone
/// frame is never early.
#[tokio::test]
async fn on_the_real_clock_a_lone_frame_is_not_early_either() {
    use std::time::Duration;

    let hub = VirtualHub::with_bitrate("test", "125k".parse().unwrap());
    let sender = hub.attach();
    let receiver = hub.attach();
    let mut rx = receiver.subscribe();
    for _ in 0..5 {
        let t0 = tokio::time::Instant::now();
        sender.send(frame(0x181, &[0; 8])).await.unwrap();
        let got = arrivals(&mut rx, 1, t0).await;
        // 135 bits at 125 kbit/s.
        assert!(got[0].1 >= Duration::from_micros(1080), "{:?}", got[0].1);
    }
}

/// A frame a full transmit queue refuses is counted for the bus: every
/// attachment's counters show the bus's total.
#[tokio::test(start_paused = true)]
async fn frames_refused_by_a_full_transmit_queue_are_counted_for_the_bus() {
    use crate::bus::DEFAULT_TX_QUEUE;

    let hub = VirtualHub::with_bitrate("test", "125k".parse().unwrap());
    let sender = hub.attach();
    let gateway = hub.attach();
    let mut refused = 0;
    for _ in 0..DEFAULT_TX_QUEUE + 300 {
        if sender.try_send(frame(0x181, &[0; 8])).is_err() {
            refused += 1;
        }
    }
    assert_eq!(refused, 300);
    assert_eq!(gateway.counters().tx_queue_overflows, 300);
    assert_eq!(sender.counters().tx_queue_overflows, 300);
}

/// A frame that only its latest value is worth sending (a heartbeat)
/// takes the place of its predecessor still waiting for the bus, as a
/// CAN controller's transmit buffer rewritten before it went out.
#[tokio::test(start_paused = true)]
async fn a_latest_value_frame_replaces_the_one_still_waiting() {
    let hub = VirtualHub::with_bitrate("test", "125k".parse().unwrap());
    let flood = hub.attach();
    let device = hub.attach();
    let master = hub.attach();
    let mut rx = master.subscribe();
    for _ in 0..100 {
        flood.try_send(frame(0x081, &[0; 8])).unwrap();
    }
    for state in [0x05u8, 0x05, 0x7F, 0x05] {
        device.try_send_latest(frame(0x703, &[state])).unwrap();
    }
    let mut heartbeats = Vec::new();
    for _ in 0..101 {
        let frame = rx.recv().await.unwrap().frame;
        if frame.id() == CanId::Standard(0x703) {
            heartbeats.push(frame.data().to_vec());
        }
    }
    assert_eq!(heartbeats, vec![vec![0x05]]);
    assert!(
        tokio::time::timeout(std::time::Duration::from_millis(50), rx.recv())
            .await
            .is_err()
    );
}
