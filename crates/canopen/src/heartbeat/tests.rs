use super::*;

fn node(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

fn ms(ms: u64) -> Duration {
    Duration::from_millis(ms)
}

fn hb(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).unwrap()
}

#[test]
fn heartbeats_encode_byte_exact() {
    let cases = [
        (NmtState::BootUp, "705#00"),
        (NmtState::Stopped, "705#04"),
        (NmtState::Operational, "705#05"),
        (NmtState::PreOperational, "705#7F"),
    ];
    for (state, text) in cases {
        let frame = Heartbeat::new(node(5), state).encode();
        assert_eq!(frame.to_string(), text);
        assert_eq!(
            Heartbeat::decode(&frame),
            Ok(Heartbeat::new(node(5), state))
        );
    }
    assert_eq!(
        Heartbeat::new(node(127), NmtState::Operational)
            .encode()
            .to_string(),
        "77F#05"
    );
}

#[test]
fn heartbeats_decode_and_reject_malformed_ones() {
    // Bit 7 is reserved (or a toggle bit): the state is bits 0-6.
    assert_eq!(
        Heartbeat::decode(&hb(0x701, &[0x85])),
        Ok(Heartbeat::new(node(1), NmtState::Operational))
    );
    assert_eq!(
        Heartbeat::decode(&hb(0x701, &[0x03])),
        Ok(Heartbeat::new(node(1), NmtState::Unknown(3)))
    );
    assert_eq!(
        Heartbeat::decode(&hb(0x701, &[])),
        Err(HeartbeatError::Length(0))
    );
    assert_eq!(
        Heartbeat::decode(&hb(0x701, &[0x05, 0x00])),
        Err(HeartbeatError::Length(2))
    );
    assert_eq!(
        Heartbeat::decode(&hb(0x700, &[0x05])),
        Err(HeartbeatError::NotHeartbeat(CanId::Standard(0x700)))
    );
    assert_eq!(
        Heartbeat::decode(&hb(0x181, &[0x05])),
        Err(HeartbeatError::NotHeartbeat(CanId::Standard(0x181)))
    );
    assert_eq!(
        Heartbeat::decode(&Frame::new(CanId::Extended(0x701), &[5]).unwrap()),
        Err(HeartbeatError::NotHeartbeat(CanId::Extended(0x701)))
    );
    assert_eq!(
        Heartbeat::decode(&guard_request(node(1))),
        Err(HeartbeatError::Remote(CanId::Standard(0x701)))
    );
}

#[test]
fn guarding_frames_encode_byte_exact() {
    assert_eq!(guard_request(node(0x10)).to_string(), "710#R1");
    let reply = |toggle, state| GuardReply {
        node: node(0x10),
        toggle,
        state,
    };
    assert_eq!(
        reply(false, NmtState::PreOperational).encode().to_string(),
        "710#7F"
    );
    assert_eq!(
        reply(true, NmtState::PreOperational).encode().to_string(),
        "710#FF"
    );
    assert_eq!(
        reply(true, NmtState::Operational).encode().to_string(),
        "710#85"
    );
    assert_eq!(
        reply(false, NmtState::Stopped).encode().to_string(),
        "710#04"
    );
    assert_eq!(
        GuardReply::decode(&hb(0x710, &[0x84])),
        Ok(reply(true, NmtState::Stopped))
    );
    assert_eq!(
        GuardReply::decode(&hb(0x710, &[0x84, 0])),
        Err(HeartbeatError::Length(2))
    );
}

#[test]
fn consumer_time_entries_of_0x1016() {
    let entry = ConsumerTime::from_raw(0x0005_01F4);
    assert_eq!(
        entry,
        ConsumerTime {
            node: 5,
            time_ms: 500
        }
    );
    assert_eq!(entry.raw(), 0x0005_01F4);
    assert_eq!(entry.monitored(), Some((node(5), ms(500))));
    // Reserved bits 24-31 are dropped.
    assert_eq!(ConsumerTime::from_raw(0xFF05_01F4), entry);
    assert_eq!(ConsumerTime::from_raw(0x0000_01F4).monitored(), None);
    assert_eq!(ConsumerTime::from_raw(0x0005_0000).monitored(), None);
    assert_eq!(ConsumerTime::from_raw(0x0080_0064).monitored(), None);
}

#[test]
fn the_producer_sends_the_state_every_period() {
    let t0 = Instant::now();
    let mut producer = HeartbeatProducer::new(node(3));
    assert_eq!(producer.deadline(), None);
    assert_eq!(producer.poll(t0 + ms(5000), NmtState::Operational), None);

    producer.set_period_ms(100, t0);
    assert_eq!(producer.period(), Some(ms(100)));
    assert_eq!(producer.deadline(), Some(t0 + ms(100)));
    assert_eq!(producer.poll(t0 + ms(99), NmtState::PreOperational), None);
    let frame = producer
        .poll(t0 + ms(100), NmtState::PreOperational)
        .unwrap();
    assert_eq!(frame.to_string(), "703#7F");
    assert_eq!(producer.deadline(), Some(t0 + ms(200)));
    // Polled a little late: the period does not drift.
    let frame = producer.poll(t0 + ms(230), NmtState::Operational).unwrap();
    assert_eq!(frame.to_string(), "703#05");
    assert_eq!(producer.deadline(), Some(t0 + ms(300)));
    // Polled very late: one heartbeat, not a burst.
    assert!(producer.poll(t0 + ms(1000), NmtState::Stopped).is_some());
    assert_eq!(producer.poll(t0 + ms(1000), NmtState::Stopped), None);
    assert_eq!(producer.deadline(), Some(t0 + ms(1100)));

    producer.set_period_ms(0, t0 + ms(1050));
    assert_eq!(producer.deadline(), None);
    assert_eq!(producer.poll(t0 + ms(5000), NmtState::Operational), None);
}

#[test]
fn the_consumer_reports_state_changes_and_boot_up() {
    let t0 = Instant::now();
    let mut consumer = HeartbeatConsumer::new();
    consumer.monitor(node(5), ms(150));
    // Not timed until the first heartbeat.
    assert_eq!(consumer.deadline(), None);
    assert_eq!(consumer.poll(t0 + ms(10_000)), []);

    assert_eq!(
        consumer.on_frame(&hb(0x705, &[0x00]), t0),
        Ok(vec![HeartbeatEvent::BootUp { node: node(5) }])
    );
    assert_eq!(consumer.state(node(5)), Some(NmtState::BootUp));
    // Boot-up does not start the timeout.
    assert_eq!(consumer.deadline(), None);
    assert_eq!(
        consumer.on_frame(&hb(0x705, &[0x7F]), t0 + ms(10)),
        Ok(vec![HeartbeatEvent::StateChanged {
            node: node(5),
            from: Some(NmtState::BootUp),
            to: NmtState::PreOperational
        }])
    );
    assert_eq!(consumer.deadline(), Some(t0 + ms(160)));
    // The same state again: nothing to report, the timeout restarts.
    assert_eq!(
        consumer.on_frame(&hb(0x705, &[0x7F]), t0 + ms(110)),
        Ok(vec![])
    );
    assert_eq!(consumer.deadline(), Some(t0 + ms(260)));
    assert_eq!(consumer.last_seen(node(5)), Some(t0 + ms(110)));
    assert_eq!(
        consumer.on_frame(&hb(0x705, &[0x05]), t0 + ms(210)),
        Ok(vec![HeartbeatEvent::StateChanged {
            node: node(5),
            from: Some(NmtState::PreOperational),
            to: NmtState::Operational
        }])
    );
}

#[test]
fn the_consumer_reports_a_lost_node_once_and_its_recovery() {
    let t0 = Instant::now();
    let mut consumer = HeartbeatConsumer::new();
    consumer.monitor_producer(node(2), ms(100));
    let _ = consumer.on_frame(&hb(0x702, &[0x05]), t0);
    assert_eq!(consumer.deadline(), Some(t0 + ms(150)));
    assert_eq!(consumer.poll(t0 + ms(149)), []);
    assert_eq!(
        consumer.poll(t0 + ms(150)),
        [HeartbeatEvent::Lost { node: node(2) }]
    );
    assert!(consumer.is_lost(node(2)));
    assert_eq!(consumer.deadline(), None);
    assert_eq!(consumer.poll(t0 + ms(1000)), []);
    // It comes back in another state.
    assert_eq!(
        consumer.on_frame(&hb(0x702, &[0x04]), t0 + ms(2000)),
        Ok(vec![
            HeartbeatEvent::Recovered {
                node: node(2),
                state: NmtState::Stopped
            },
            HeartbeatEvent::StateChanged {
                node: node(2),
                from: Some(NmtState::Operational),
                to: NmtState::Stopped
            }
        ])
    );
    assert!(!consumer.is_lost(node(2)));
    assert_eq!(consumer.deadline(), Some(t0 + ms(2150)));
    // A lost node that reboots recovers in boot-up.
    assert_eq!(consumer.poll(t0 + ms(2150)).len(), 1);
    assert_eq!(
        consumer.on_frame(&hb(0x702, &[0x00]), t0 + ms(3000)),
        Ok(vec![
            HeartbeatEvent::Recovered {
                node: node(2),
                state: NmtState::BootUp
            },
            HeartbeatEvent::BootUp { node: node(2) }
        ])
    );
}

#[test]
fn the_consumer_can_be_armed_before_the_first_heartbeat() {
    let t0 = Instant::now();
    let mut consumer = HeartbeatConsumer::new();
    consumer.monitor(node(9), ms(500));
    consumer.arm(node(9), t0);
    // Arming a node that is not monitored does nothing.
    consumer.arm(node(10), t0);
    assert_eq!(consumer.deadline(), Some(t0 + ms(500)));
    assert_eq!(
        consumer.poll(t0 + ms(500)),
        [HeartbeatEvent::Lost { node: node(9) }]
    );
    assert_eq!(consumer.state(node(9)), None);
}

#[test]
fn the_consumer_tracks_unmonitored_nodes_without_a_timeout() {
    let t0 = Instant::now();
    let mut consumer = HeartbeatConsumer::new();
    assert_eq!(
        consumer.on_frame(&hb(0x77F, &[0x7F]), t0),
        Ok(vec![HeartbeatEvent::StateChanged {
            node: node(127),
            from: None,
            to: NmtState::PreOperational
        }])
    );
    assert_eq!(consumer.deadline(), None);
    assert_eq!(consumer.poll(t0 + ms(100_000)), []);
    assert_eq!(consumer.nodes().collect::<Vec<_>>(), [node(127)]);
    // Monitoring it now times it from its last heartbeat.
    consumer.monitor(node(127), ms(200));
    assert_eq!(consumer.deadline(), Some(t0 + ms(200)));
    consumer.monitor(node(127), Duration::ZERO);
    assert_eq!(consumer.deadline(), None);
    consumer.unmonitor(node(127));
    assert_eq!(consumer.state(node(127)), None);
}

#[test]
fn the_consumer_ignores_other_frames_and_reports_malformed_heartbeats() {
    let t0 = Instant::now();
    let mut consumer = HeartbeatConsumer::new();
    assert_eq!(consumer.on_frame(&hb(0x185, &[1, 2]), t0), Ok(vec![]));
    assert_eq!(consumer.on_frame(&guard_request(node(5)), t0), Ok(vec![]));
    assert_eq!(
        consumer.on_frame(&hb(0x705, &[0x05, 0x05]), t0),
        Err(HeartbeatError::Length(2))
    );
    assert_eq!(consumer.nodes().count(), 0);
}

#[test]
fn several_nodes_time_out_independently() {
    let t0 = Instant::now();
    let mut consumer = HeartbeatConsumer::new();
    consumer.monitor(node(1), ms(100));
    consumer.monitor(node(2), ms(300));
    let _ = consumer.on_frame(&hb(0x701, &[0x05]), t0);
    let _ = consumer.on_frame(&hb(0x702, &[0x05]), t0);
    assert_eq!(consumer.deadline(), Some(t0 + ms(100)));
    assert_eq!(
        consumer.poll(t0 + ms(100)),
        [HeartbeatEvent::Lost { node: node(1) }]
    );
    assert_eq!(consumer.deadline(), Some(t0 + ms(300)));
    assert_eq!(
        consumer.poll(t0 + ms(300)),
        [HeartbeatEvent::Lost { node: node(2) }]
    );
    assert_eq!(consumer.deadline(), None);
}

#[test]
fn the_guarding_master_polls_checks_the_toggle_and_loses_a_silent_node() {
    let t0 = Instant::now();
    let mut guard = NodeGuardMaster::new(node(4), 100, 3);
    assert_eq!(guard.life_time(), Some(ms(300)));
    assert_eq!(guard.deadline(), None);
    guard.start(t0);
    let poll = guard.poll(t0);
    assert_eq!(poll.request.unwrap().to_string(), "704#R1");
    assert_eq!(poll.event, None);
    assert_eq!(guard.deadline(), Some(t0 + ms(100)));
    // First reply: toggle taken as it comes.
    assert_eq!(
        guard.on_frame(&hb(0x704, &[0x7F]), t0 + ms(1)),
        Ok(vec![HeartbeatEvent::StateChanged {
            node: node(4),
            from: None,
            to: NmtState::PreOperational
        }])
    );
    let _ = guard.poll(t0 + ms(100));
    assert_eq!(
        guard.on_frame(&hb(0x704, &[0xFF]), t0 + ms(101)),
        Ok(vec![])
    );
    let _ = guard.poll(t0 + ms(200));
    assert_eq!(
        guard.on_frame(&hb(0x704, &[0x05]), t0 + ms(201)),
        Ok(vec![HeartbeatEvent::StateChanged {
            node: node(4),
            from: Some(NmtState::PreOperational),
            to: NmtState::Operational
        }])
    );
    assert_eq!(guard.state(), Some(NmtState::Operational));
    assert_eq!(guard.last_seen(), Some(t0 + ms(201)));
    // Silence: requests at 300, 400 and 500 unanswered. The node life time
    // (300 ms) runs from the last valid reply at 201: lost at 501, within
    // guard time × life time factor of its last word (counting three missed
    // requests would report it at 600, 399 ms after it).
    for t in [300, 400, 500] {
        assert_eq!(guard.deadline(), Some(t0 + ms(t)));
        let poll = guard.poll(t0 + ms(t));
        assert!(poll.request.is_some());
        assert_eq!(poll.event, None, "at {t} ms");
    }
    assert_eq!(guard.deadline(), Some(t0 + ms(501)));
    let poll = guard.poll(t0 + ms(501));
    assert_eq!(poll.request, None);
    assert_eq!(poll.event, Some(HeartbeatEvent::Lost { node: node(4) }));
    assert!(guard.is_lost());
    assert_eq!(guard.deadline(), Some(t0 + ms(600)));
    let poll = guard.poll(t0 + ms(600));
    assert!(poll.request.is_some(), "a lost node is still asked");
    assert_eq!(poll.event, None);
    assert_eq!(guard.poll(t0 + ms(700)).event, None);
    // It answers again, toggle continuing from the last valid reply (1).
    assert_eq!(
        guard.on_frame(&hb(0x704, &[0x85]), t0 + ms(701)),
        Ok(vec![HeartbeatEvent::Recovered {
            node: node(4),
            state: NmtState::Operational
        }])
    );
    assert!(!guard.is_lost());
}

#[test]
fn a_wrong_toggle_costs_one_request() {
    let t0 = Instant::now();
    let mut guard = NodeGuardMaster::new(node(4), 100, 3);
    guard.start(t0);
    let _ = guard.poll(t0);
    let _ = guard.on_frame(&hb(0x704, &[0x05]), t0);
    let _ = guard.poll(t0 + ms(100));
    // Expected toggle 1, got 0: not a valid reply.
    assert_eq!(
        guard.on_frame(&hb(0x704, &[0x05]), t0 + ms(101)),
        Ok(vec![])
    );
    assert_eq!(guard.poll(t0 + ms(200)).event, None);
    // The node toggles on: 1 is what was expected, the node is back in step.
    assert_eq!(
        guard.on_frame(&hb(0x704, &[0x85]), t0 + ms(201)),
        Ok(vec![])
    );
    assert_eq!(guard.last_seen(), Some(t0 + ms(201)));
    assert_eq!(guard.poll(t0 + ms(300)).event, None);
    assert_eq!(guard.poll(t0 + ms(400)).event, None);
    assert_eq!(guard.poll(t0 + ms(500)).event, None);
    assert_eq!(
        guard.poll(t0 + ms(501)).event,
        Some(HeartbeatEvent::Lost { node: node(4) })
    );
}

#[test]
fn the_guarding_master_sees_boot_up_and_ignores_unsolicited_bytes() {
    let t0 = Instant::now();
    let mut guard = NodeGuardMaster::new(node(4), 100, 1);
    guard.start(t0);
    // No request outstanding: a heartbeat-like byte is not a reply.
    assert_eq!(guard.on_frame(&hb(0x704, &[0x05]), t0), Ok(vec![]));
    let _ = guard.poll(t0);
    let _ = guard.on_frame(&hb(0x704, &[0x85]), t0);
    assert_eq!(
        guard.on_frame(&hb(0x704, &[0x00]), t0 + ms(50)),
        Ok(vec![HeartbeatEvent::BootUp { node: node(4) }])
    );
    let _ = guard.poll(t0 + ms(100));
    // After boot-up the toggle restarts at 0: 0x80 is wrong.
    assert_eq!(
        guard.on_frame(&hb(0x704, &[0xFF]), t0 + ms(101)),
        Ok(vec![])
    );
    assert_eq!(
        guard.poll(t0 + ms(200)).event,
        Some(HeartbeatEvent::Lost { node: node(4) })
    );
    // Other nodes' frames are not ours.
    assert_eq!(guard.on_frame(&hb(0x705, &[0x00]), t0), Ok(vec![]));
    assert_eq!(
        guard.on_frame(&hb(0x704, &[]), t0),
        Err(HeartbeatError::Length(0))
    );
    guard.stop();
    assert_eq!(guard.deadline(), None);
    assert_eq!(guard.poll(t0 + ms(1000)), GuardPoll::default());
}

#[test]
fn guarding_is_off_when_guard_time_or_factor_is_zero() {
    let t0 = Instant::now();
    for (time, factor) in [(0, 3), (100, 0)] {
        let mut guard = NodeGuardMaster::new(node(4), time, factor);
        guard.start(t0);
        assert_eq!(guard.life_time(), None);
        assert_eq!(guard.deadline(), None);
        assert_eq!(guard.poll(t0 + ms(1000)), GuardPoll::default());
    }
}

#[test]
fn the_slave_answers_with_a_toggling_state_byte() {
    let t0 = Instant::now();
    let mut guard = LifeGuard::new(node(6));
    let request = guard_request(node(6));
    let reply = |guard: &mut LifeGuard, state| {
        guard
            .on_frame(&request, t0, state)
            .reply
            .map(|f| f.to_string())
    };
    assert_eq!(
        reply(&mut guard, NmtState::PreOperational).as_deref(),
        Some("706#7F")
    );
    assert_eq!(
        reply(&mut guard, NmtState::PreOperational).as_deref(),
        Some("706#FF")
    );
    assert_eq!(
        reply(&mut guard, NmtState::Operational).as_deref(),
        Some("706#05")
    );
    assert_eq!(
        reply(&mut guard, NmtState::Stopped).as_deref(),
        Some("706#84")
    );
    // Not while initialising; no toggle is used up.
    assert_eq!(reply(&mut guard, NmtState::BootUp), None);
    assert_eq!(
        reply(&mut guard, NmtState::Stopped).as_deref(),
        Some("706#04")
    );
    guard.reset();
    assert_eq!(
        reply(&mut guard, NmtState::PreOperational).as_deref(),
        Some("706#7F")
    );
    // Another node's request, or a data frame, is not ours.
    assert_eq!(
        guard.on_frame(&guard_request(node(7)), t0, NmtState::Operational),
        LifeGuardOutput::default()
    );
    assert_eq!(
        guard.on_frame(&hb(0x706, &[0x05]), t0, NmtState::Operational),
        LifeGuardOutput::default()
    );
    // Life guarding is off: no deadline.
    assert_eq!(guard.deadline(), None);
}

#[test]
fn the_slave_signals_life_guarding_when_the_master_stops() {
    let t0 = Instant::now();
    let mut guard = LifeGuard::new(node(6));
    guard.configure(100, 3, t0);
    assert_eq!(guard.life_time(), Some(ms(300)));
    // Watching starts with the first request.
    assert_eq!(guard.deadline(), None);
    assert_eq!(guard.poll(t0 + ms(10_000)), None);
    let request = guard_request(node(6));
    let out = guard.on_frame(&request, t0, NmtState::Operational);
    assert!(out.reply.is_some());
    assert_eq!(out.event, None);
    assert_eq!(guard.deadline(), Some(t0 + ms(300)));
    let _ = guard.on_frame(&request, t0 + ms(100), NmtState::Operational);
    assert_eq!(guard.poll(t0 + ms(399)), None);
    assert_eq!(guard.poll(t0 + ms(400)), Some(LifeGuardEvent::Lost));
    assert!(guard.is_lost());
    assert_eq!(guard.poll(t0 + ms(800)), None);
    let out = guard.on_frame(&request, t0 + ms(900), NmtState::Operational);
    assert_eq!(out.event, Some(LifeGuardEvent::Recovered));
    assert!(!guard.is_lost());
    // A new life time while watching runs from now.
    guard.configure(50, 2, t0 + ms(950));
    assert_eq!(guard.deadline(), Some(t0 + ms(1050)));
    guard.configure(0, 2, t0 + ms(960));
    assert_eq!(guard.deadline(), None);
}
