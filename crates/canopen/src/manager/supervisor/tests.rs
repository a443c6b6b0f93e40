use std::time::{Duration, Instant};

use super::*;
use crate::heartbeat::{GuardReply, guard_request};

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn id(n: u8) -> NodeId {
    NodeId::new(n).unwrap()
}

fn heartbeat(node: u8, state: NmtState) -> Frame {
    Heartbeat::new(id(node), state).encode()
}

#[test]
fn a_producer_slowed_past_the_timeout_is_followed_after_three_heartbeats() {
    let t0 = Instant::now();
    let mut learner = HeartbeatLearner::default();
    let mut t = t0;
    learner.on_heartbeat(t, ConsumerFactor::MIN);
    for _ in 0..HEARTBEAT_WINDOW {
        t += ms(250);
        learner.on_heartbeat(t, ConsumerFactor::MIN);
    }
    assert_eq!(learner.period, Some(ms(250)));
    // 0x1017 written to 1000 ms: each heartbeat now comes after the
    // consumer's timeout (375 ms). Two are not yet a new period (a node may
    // miss a frame or two)...
    t += ms(1000);
    assert_eq!(learner.on_heartbeat(t, ConsumerFactor::MIN), None);
    t += ms(1000);
    assert_eq!(learner.on_heartbeat(t, ConsumerFactor::MIN), None);
    // ...three in a row are.
    t += ms(1000);
    assert_eq!(learner.on_heartbeat(t, ConsumerFactor::MIN), Some(ms(1000)));
    t += ms(1000);
    assert_eq!(learner.on_heartbeat(t, ConsumerFactor::MIN), None);
    assert_eq!(learner.period, Some(ms(1000)));
}

#[test]
fn the_period_is_the_shortest_recent_interval() {
    let t0 = Instant::now();
    let mut learner = HeartbeatLearner::default();
    assert_eq!(learner.on_heartbeat(t0, ConsumerFactor::MIN), None);
    assert_eq!(
        learner.on_heartbeat(t0 + ms(100), ConsumerFactor::MIN),
        Some(ms(100))
    );
    // One heartbeat lost on the bus: the interval doubles, not the period.
    assert_eq!(
        learner.on_heartbeat(t0 + ms(300), ConsumerFactor::MIN),
        None
    );
    assert_eq!(learner.period, Some(ms(100)));
    // The producer got faster: followed after three intervals in a row
    // (one short one is a burst).
    assert_eq!(
        learner.on_heartbeat(t0 + ms(350), ConsumerFactor::MIN),
        None
    );
    assert_eq!(
        learner.on_heartbeat(t0 + ms(400), ConsumerFactor::MIN),
        None
    );
    assert_eq!(
        learner.on_heartbeat(t0 + ms(450), ConsumerFactor::MIN),
        Some(ms(50))
    );
    // Slower again: followed once the short intervals left the window.
    let mut t = t0 + ms(450);
    let mut changed = None;
    for _ in 0..HEARTBEAT_WINDOW {
        t += ms(120);
        changed = changed.or(learner.on_heartbeat(t, ConsumerFactor::MIN));
    }
    assert_eq!(changed, Some(ms(120)));
    assert_eq!(learner.period, Some(ms(120)));
    // Two frames of one burst are no period.
    assert_eq!(learner.on_heartbeat(t, ConsumerFactor::MIN), None);
    assert_eq!(learner.period, Some(ms(120)));
    // After a loss the gap does not count, the period stays.
    learner.restart();
    assert_eq!(
        learner.on_heartbeat(t + ms(5000), ConsumerFactor::MIN),
        None
    );
    assert_eq!(learner.period, Some(ms(120)));
    learner.set_period(ms(1000));
    assert_eq!(learner.period, Some(ms(1000)));
    learner = HeartbeatLearner::default();
    assert_eq!(learner.period, None);
}

fn events(supervisor: &mut Supervisor) -> Vec<SupervisorEvent> {
    supervisor.take_events()
}

#[test]
fn a_node_is_lost_at_one_and_a_half_learnt_periods_and_heard_again() {
    let t0 = Instant::now();
    let mut supervisor = Supervisor::new(true).with_consumer_factor(ConsumerFactor::MIN);
    let n = id(4);
    supervisor
        .on_frame(&heartbeat(4, NmtState::Operational), t0)
        .unwrap();
    assert_eq!(
        events(&mut supervisor),
        vec![
            SupervisorEvent::Nmt {
                node: n,
                from: None,
                to: NmtState::Operational
            },
            SupervisorEvent::Heard {
                node: n,
                nmt: NmtState::Operational
            },
        ]
    );
    // One interval is no period yet: not timed.
    assert_eq!(supervisor.deadline(), None);
    supervisor
        .on_frame(&heartbeat(4, NmtState::Operational), t0 + ms(200))
        .unwrap();
    let node = supervisor.node(n).unwrap();
    assert_eq!(
        (node.heartbeat, node.deadline),
        (Some(ms(200)), Some(t0 + ms(500)))
    );
    events(&mut supervisor);
    assert!(supervisor.poll(t0 + ms(499)).is_empty());
    assert!(events(&mut supervisor).is_empty());
    assert!(supervisor.poll(t0 + ms(500)).is_empty());
    let by = LostBy::Heartbeat { period: ms(200) };
    assert_eq!(
        events(&mut supervisor),
        vec![
            SupervisorEvent::Lost { node: n, by },
            SupervisorEvent::Offline {
                node: n,
                cause: OfflineCause::Lost(by)
            },
        ]
    );
    // Once, until heard again.
    assert!(supervisor.poll(t0 + ms(5000)).is_empty());
    assert!(events(&mut supervisor).is_empty());
    supervisor
        .on_frame(&heartbeat(4, NmtState::Operational), t0 + ms(5000))
        .unwrap();
    assert_eq!(
        events(&mut supervisor),
        vec![
            SupervisorEvent::Recovered { node: n },
            SupervisorEvent::Heard {
                node: n,
                nmt: NmtState::Operational
            },
            SupervisorEvent::Online { node: n },
        ]
    );
    assert!(supervisor.node(n).unwrap().online);
}

#[test]
fn a_boot_up_forgets_the_period_until_it_is_learnt_or_written_again() {
    let t0 = Instant::now();
    let mut supervisor = Supervisor::new(true).with_consumer_factor(ConsumerFactor::MIN);
    let n = id(2);
    supervisor.watch(n, t0);
    supervisor.heartbeat_read(n, 100, t0);
    assert_eq!(supervisor.deadline(), Some(t0 + ms(150)));
    supervisor
        .on_frame(&heartbeat(2, NmtState::BootUp), t0 + ms(10))
        .unwrap();
    assert_eq!(
        events(&mut supervisor),
        vec![
            SupervisorEvent::Nmt {
                node: n,
                from: None,
                to: NmtState::BootUp
            },
            SupervisorEvent::BootUp { node: n },
        ]
    );
    let node = supervisor.node(n).unwrap();
    assert_eq!((node.heartbeat, node.deadline), (None, None));
    // An SDO answer after the boot-up: pre-operational.
    supervisor.answered(n);
    assert_eq!(
        supervisor.node(n).unwrap().nmt,
        Some(NmtState::PreOperational)
    );
    // A write sets the period at once, timed from the write.
    supervisor.heartbeat_written(n, 300, t0 + ms(20));
    assert_eq!(supervisor.deadline(), Some(t0 + ms(470)));
    // Written 0: not timed, online by any frame.
    supervisor.heartbeat_written(n, 0, t0 + ms(30));
    assert_eq!(supervisor.deadline(), None);
    assert!(!supervisor.node(n).unwrap().lost);
}

#[test]
fn a_write_rearms_a_lost_node_which_stays_offline_until_heard() {
    let t0 = Instant::now();
    let mut supervisor = Supervisor::new(true).with_consumer_factor(ConsumerFactor::MIN);
    let n = id(3);
    supervisor.watch(n, t0);
    supervisor.heartbeat_read(n, 100, t0);
    assert!(supervisor.poll(t0 + ms(150)).is_empty());
    assert!(!supervisor.node(n).unwrap().online);
    events(&mut supervisor);
    supervisor.heartbeat_written(n, 1000, t0 + ms(200));
    let node = supervisor.node(n).unwrap();
    assert_eq!(
        (node.online, node.lost, node.deadline),
        (false, false, Some(t0 + ms(1700)))
    );
    assert!(supervisor.poll(t0 + ms(1700)).is_empty());
    assert_eq!(
        events(&mut supervisor),
        vec![
            SupervisorEvent::HeartbeatWritten {
                node: n,
                heartbeat_ms: 1000
            },
            SupervisorEvent::Lost {
                node: n,
                by: LostBy::Heartbeat { period: ms(1000) }
            }
        ]
    );
}

#[test]
fn a_guarded_node_is_lost_by_its_life_time_not_by_its_replies_intervals() {
    let t0 = Instant::now();
    let mut supervisor = Supervisor::new(true).with_consumer_factor(ConsumerFactor::MIN);
    let n = id(5);
    supervisor.watch(n, t0);
    supervisor.guard(n, 100, 3, t0);
    assert_eq!(supervisor.poll(t0), vec![guard_request(n)]);
    let reply = |toggle| {
        GuardReply {
            node: n,
            toggle,
            state: NmtState::PreOperational,
        }
        .encode()
    };
    supervisor.on_frame(&reply(false), t0 + ms(5)).unwrap();
    assert_eq!(supervisor.poll(t0 + ms(100)), vec![guard_request(n)]);
    supervisor.on_frame(&reply(true), t0 + ms(105)).unwrap();
    // The replies are 100 ms apart (the learnt period), but a reply late by
    // more than 1.5 of them is no loss: the life time (300 ms) decides.
    assert_eq!(supervisor.node(n).unwrap().heartbeat, Some(ms(100)));
    let _ = supervisor.poll(t0 + ms(200));
    let _ = supervisor.poll(t0 + ms(300));
    events(&mut supervisor);
    let _ = supervisor.poll(t0 + ms(404));
    assert!(events(&mut supervisor).is_empty());
    assert!(supervisor.node(n).unwrap().online);
    let _ = supervisor.poll(t0 + ms(405));
    let by = LostBy::Guarding { life_time: ms(300) };
    assert_eq!(
        events(&mut supervisor),
        vec![
            SupervisorEvent::Lost { node: n, by },
            SupervisorEvent::Offline {
                node: n,
                cause: OfflineCause::Lost(by)
            },
        ]
    );
    // A reply with the wrong toggle does not bring it back.
    supervisor.on_frame(&reply(true), t0 + ms(410)).unwrap();
    assert!(!supervisor.node(n).unwrap().online);
    supervisor.on_frame(&reply(false), t0 + ms(420)).unwrap();
    let heard = events(&mut supervisor);
    assert!(
        heard.contains(&SupervisorEvent::Recovered { node: n }),
        "{heard:?}"
    );
    assert!(
        heard.contains(&SupervisorEvent::Online { node: n }),
        "{heard:?}"
    );
}

#[test]
fn the_bus_down_takes_every_node_offline_and_nothing_else_online() {
    let t0 = Instant::now();
    let mut supervisor = Supervisor::new(true).with_consumer_factor(ConsumerFactor::MIN);
    let n = id(6);
    supervisor.heard(n, t0);
    supervisor.bus_up(false);
    assert_eq!(
        events(&mut supervisor),
        vec![SupervisorEvent::Offline {
            node: n,
            cause: OfflineCause::BusDown
        }]
    );
    supervisor.heard(n, t0 + ms(1));
    assert!(!supervisor.node(n).unwrap().online);
    supervisor.bus_up(true);
    supervisor.heard(n, t0 + ms(2));
    assert_eq!(
        events(&mut supervisor),
        vec![SupervisorEvent::Online { node: n }]
    );
    // Unsupervised: a probe without answer takes it offline.
    supervisor.no_answer(n);
    assert!(!supervisor.node(n).unwrap().online);
}

#[test]
fn by_default_a_node_is_lost_after_three_silent_periods() {
    let t0 = Instant::now();
    let mut supervisor = Supervisor::new(true);
    assert_eq!(supervisor.consumer_factor(), ConsumerFactor::DEFAULT);
    let node = id(4);
    supervisor.watch(node, t0);
    supervisor.heartbeat_read(node, 500, t0);
    // 1.4 s of silence (the old 1.5-period margin lost it at 750 ms): heard.
    let _ = supervisor.poll(t0 + ms(1400));
    assert!(!supervisor.node(node).unwrap().lost);
    let _ = supervisor.poll(t0 + ms(1500));
    assert!(supervisor.node(node).unwrap().lost);
    assert_eq!(ConsumerFactor::new(2.04).unwrap().to_string(), "2.0");
    assert!(ConsumerFactor::new(f64::NAN).is_err());
}

#[test]
fn a_jittered_heartbeat_keeps_its_period() {
    let t0 = Instant::now();
    let mut learner = HeartbeatLearner::default();
    learner.written(Some(ms(500)));
    let mut t = t0;
    // A loaded sender: 40 to 60 ms early or late, for a while.
    for (i, jitter) in [-60i64, 40, -45, 60, -50, 30, -60, 55, -40, 20]
        .into_iter()
        .cycle()
        .take(40)
        .enumerate()
    {
        t = t0 + ms((500 * (i as i64 + 1) + jitter) as u64);
        assert_eq!(learner.on_heartbeat(t, ConsumerFactor::DEFAULT), None);
    }
    assert_eq!(learner.period, Some(ms(500)));
    // A stall: one heartbeat 400 ms late, the next on time 100 ms after
    // it. A burst, not a faster producer.
    t += ms(900);
    assert_eq!(learner.on_heartbeat(t, ConsumerFactor::DEFAULT), None);
    t += ms(100);
    assert_eq!(learner.on_heartbeat(t, ConsumerFactor::DEFAULT), None);
    for _ in 0..5 {
        t += ms(500);
        assert_eq!(learner.on_heartbeat(t, ConsumerFactor::DEFAULT), None);
    }
    assert_eq!(learner.period, Some(ms(500)));
    // A real change (0x1017 written 200 by someone else) is followed, at
    // its third interval.
    for _ in 0..2 {
        t += ms(200);
        assert_eq!(learner.on_heartbeat(t, ConsumerFactor::DEFAULT), None);
    }
    assert_eq!(
        learner.on_heartbeat(t + ms(200), ConsumerFactor::DEFAULT),
        Some(ms(200))
    );
}
