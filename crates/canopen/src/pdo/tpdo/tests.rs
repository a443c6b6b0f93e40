use std::time::Duration;

use super::*;
use crate::can::CanId;
use crate::pdo::PdoCobId;

fn ms(ms: u64) -> Duration {
    Duration::from_millis(ms)
}

fn params(transmission_type: u8) -> PdoCommParams {
    let mut params = PdoCommParams::new(PdoCobId::new(CanId::Standard(0x181)));
    params.transmission_type = TransmissionType::from_raw(transmission_type);
    params
}

/// Which of SYNCs 1..=count (at 10 ms each, counters as given) send.
fn syncs_sending(trigger: &mut TpdoTrigger, t0: Instant, counters: &[Option<u8>]) -> Vec<usize> {
    counters
        .iter()
        .enumerate()
        .filter_map(|(i, &counter)| {
            let now = t0 + ms(10 * (i as u64 + 1));
            trigger.on_sync(counter, now).then_some(i + 1)
        })
        .collect()
}

#[test]
fn cyclic_sends_at_every_third_sync() {
    let t0 = Instant::now();
    let mut trigger = TpdoTrigger::new(params(3), t0);
    assert_eq!(syncs_sending(&mut trigger, t0, &[None; 10]), [3, 6, 9]);
    // Events, remote requests and time do not send a cyclic TPDO.
    assert!(!trigger.on_event(t0 + ms(200)));
    assert!(!trigger.on_rtr(t0 + ms(200)));
    assert!(!trigger.poll(t0 + ms(10_000)));
    assert_eq!(trigger.deadline(), None);
}

#[test]
fn cyclic_every_sync() {
    let t0 = Instant::now();
    let mut trigger = TpdoTrigger::new(params(1), t0);
    assert_eq!(syncs_sending(&mut trigger, t0, &[None; 4]), [1, 2, 3, 4]);
}

#[test]
fn the_sync_start_value_picks_the_first_sync() {
    let t0 = Instant::now();
    let mut p = params(3);
    p.sync_start = 4;
    let mut trigger = TpdoTrigger::new(p, t0);
    let counters: Vec<Option<u8>> = (1..=12).map(|c| Some((c - 1) % 10 + 1)).collect();
    // Counters 1, 2, 3 are ignored; the SYNC with counter 4 sends, then
    // every third one: counters 7 and 10.
    assert_eq!(syncs_sending(&mut trigger, t0, &counters), [4, 7, 10]);
    // After a restart it waits for counter 4 again.
    trigger.restart(t0 + ms(500));
    assert!(!trigger.on_sync(Some(1), t0 + ms(510)));
    assert!(trigger.on_sync(Some(4), t0 + ms(520)));
}

#[test]
fn the_sync_start_value_needs_a_sync_counter() {
    let t0 = Instant::now();
    let mut p = params(2);
    p.sync_start = 4;
    let mut trigger = TpdoTrigger::new(p, t0);
    // SYNC without counter: the start value does not apply.
    assert_eq!(syncs_sending(&mut trigger, t0, &[None; 5]), [2, 4]);
}

#[test]
fn acyclic_sync_sends_only_after_an_event() {
    let t0 = Instant::now();
    let mut trigger = TpdoTrigger::new(params(0), t0);
    assert!(!trigger.on_sync(None, t0 + ms(10)));
    assert!(!trigger.on_event(t0 + ms(11)));
    // Several events before a SYNC make one transmission.
    assert!(!trigger.on_event(t0 + ms(12)));
    assert!(trigger.on_sync(None, t0 + ms(20)));
    assert!(!trigger.on_sync(None, t0 + ms(30)));
    // A remote request is served at the next SYNC too.
    assert!(!trigger.on_rtr(t0 + ms(31)));
    assert!(trigger.on_sync(Some(7), t0 + ms(40)));
    assert_eq!(trigger.deadline(), None);
}

#[test]
fn the_event_timer_fires_repeatedly() {
    let t0 = Instant::now();
    let mut p = params(254);
    p.event_timer_ms = 100;
    let mut trigger = TpdoTrigger::new(p, t0);
    assert_eq!(trigger.deadline(), Some(t0 + ms(100)));
    assert!(!trigger.poll(t0 + ms(99)));
    assert!(trigger.poll(t0 + ms(100)));
    assert_eq!(trigger.deadline(), Some(t0 + ms(200)));
    assert!(!trigger.poll(t0 + ms(100)));
    assert!(trigger.poll(t0 + ms(200)));
    // An event sends at once and restarts the timer.
    assert!(trigger.on_event(t0 + ms(250)));
    assert_eq!(trigger.deadline(), Some(t0 + ms(350)));
    assert!(!trigger.poll(t0 + ms(300)));
    assert!(trigger.poll(t0 + ms(350)));
    // SYNC means nothing to an event-driven TPDO.
    assert!(!trigger.on_sync(Some(1), t0 + ms(360)));
}

#[test]
fn the_inhibit_time_turns_a_burst_into_one_frame_per_period() {
    let t0 = Instant::now();
    let mut p = params(255);
    p.inhibit_time_100us = 100; // 10 ms
    let mut trigger = TpdoTrigger::new(p, t0);
    assert_eq!(trigger.deadline(), None);
    // An event every millisecond for 35 ms, polled every millisecond.
    let mut sent = Vec::new();
    for t in 0..=35 {
        let now = t0 + ms(t);
        if trigger.on_event(now) || trigger.poll(now) {
            sent.push(t);
        }
    }
    assert_eq!(sent, [0, 10, 20, 30]);
    // The events after the last frame still go out when the inhibit
    // time ends, and then nothing more.
    assert_eq!(trigger.deadline(), Some(t0 + ms(40)));
    assert!(!trigger.poll(t0 + ms(39)));
    assert!(trigger.poll(t0 + ms(40)));
    assert_eq!(trigger.deadline(), None);
    assert!(!trigger.poll(t0 + ms(1000)));
}

#[test]
fn the_event_timer_waits_for_the_inhibit_time() {
    let t0 = Instant::now();
    let mut p = params(254);
    p.inhibit_time_100us = 300; // 30 ms
    p.event_timer_ms = 20;
    let mut trigger = TpdoTrigger::new(p, t0);
    assert!(trigger.poll(t0 + ms(20)));
    // The timer is due at 40, the inhibit time ends at 50.
    assert!(!trigger.poll(t0 + ms(40)));
    assert_eq!(trigger.deadline(), Some(t0 + ms(50)));
    assert!(trigger.poll(t0 + ms(50)));
    assert_eq!(trigger.deadline(), Some(t0 + ms(70)));
}

#[test]
fn rtr_only_types_never_send_on_their_own() {
    let t0 = Instant::now();
    for transmission_type in [252, 253] {
        let mut p = params(transmission_type);
        p.event_timer_ms = 10;
        p.inhibit_time_100us = 10;
        let mut trigger = TpdoTrigger::new(p, t0);
        for t in 1..=100 {
            let now = t0 + ms(t);
            assert!(!trigger.on_event(now));
            assert!(!trigger.on_sync(Some(1), now));
            assert!(!trigger.poll(now));
        }
        assert_eq!(trigger.deadline(), None);
    }
}

#[test]
fn rtr_only_types_send_when_asked() {
    let t0 = Instant::now();
    // 253: at once.
    let mut trigger = TpdoTrigger::new(params(253), t0);
    assert!(trigger.on_rtr(t0 + ms(1)));
    assert!(trigger.on_rtr(t0 + ms(2)));
    // 252: at the next SYNC.
    let mut trigger = TpdoTrigger::new(params(252), t0);
    assert!(!trigger.on_rtr(t0 + ms(1)));
    assert!(trigger.on_sync(None, t0 + ms(10)));
    assert!(!trigger.on_sync(None, t0 + ms(20)));
    // Bit 30 of the COB-ID forbids remote requests.
    let mut p = params(253);
    p.cob_id.rtr_allowed = false;
    let mut trigger = TpdoTrigger::new(p, t0);
    assert!(!trigger.on_rtr(t0 + ms(1)));
}

#[test]
fn remote_requests_of_event_driven_types_respect_the_inhibit_time() {
    let t0 = Instant::now();
    let mut p = params(255);
    p.inhibit_time_100us = 50;
    let mut trigger = TpdoTrigger::new(p, t0);
    assert!(trigger.on_rtr(t0));
    assert!(!trigger.on_rtr(t0 + ms(1)));
    assert_eq!(trigger.deadline(), Some(t0 + ms(5)));
    assert!(trigger.poll(t0 + ms(5)));
}

#[test]
fn an_invalid_pdo_never_sends() {
    let t0 = Instant::now();
    for transmission_type in [0, 1, 252, 253, 254, 255] {
        let mut p = params(transmission_type);
        p.cob_id.valid = false;
        p.event_timer_ms = 1;
        let mut trigger = TpdoTrigger::new(p, t0);
        assert!(!trigger.on_event(t0));
        assert!(!trigger.on_rtr(t0));
        assert!(!trigger.on_sync(None, t0));
        assert!(!trigger.poll(t0 + ms(100)));
        assert_eq!(trigger.deadline(), None);
    }
}

#[test]
fn new_params_start_over() {
    let t0 = Instant::now();
    let mut trigger = TpdoTrigger::new(params(2), t0);
    assert!(!trigger.on_sync(None, t0 + ms(10)));
    let mut p = params(254);
    p.event_timer_ms = 50;
    trigger.set_params(p, t0 + ms(15));
    assert_eq!(trigger.params().event_timer_ms, 50);
    assert_eq!(trigger.deadline(), Some(t0 + ms(65)));
}
