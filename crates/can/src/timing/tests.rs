use std::time::{Duration, Instant};

use super::*;

fn data(id: u16, len: usize) -> Frame {
    Frame::new(CanId::Standard(id), &[0x55; 8][..len]).unwrap()
}

fn at_125k() -> Bitrate {
    "125k".parse().unwrap()
}

/// One bit time at 125 kbit/s: 8 µs.
fn bits(n: u64) -> Duration {
    Duration::from_micros(8 * n)
}

#[test]
fn frames_take_their_worst_case_stuffed_length() {
    // 44 bits + 8 stuff bits + 3 intermission for an empty standard frame;
    // 108 + 24 + 3 = 135 for a full one (the figure of bus-load tables).
    assert_eq!(frame_bits(&data(0x123, 0)), 55);
    assert_eq!(frame_bits(&data(0x123, 8)), 135);
    let extended = Frame::new(CanId::Extended(0x1234_5678), &[0; 8]).unwrap();
    assert_eq!(frame_bits(&extended), 128 + 29 + 3);
    let remote = Frame::remote(CanId::Standard(0x701), 1).unwrap();
    assert_eq!(frame_bits(&remote), 55);
    // The stuff bits never shorten a frame and grow with the data.
    for len in 0..8 {
        assert!(frame_bits(&data(1, len + 1)) > frame_bits(&data(1, len)));
        assert!(frame_bits(&data(1, len)) > data(1, len).wire_bits());
    }
}

#[test]
fn bit_rates_parse_as_numbers_with_units_or_unlimited() {
    assert_eq!("500000".parse(), Ok(Bitrate::bits_per_second(500_000)));
    assert_eq!("250k".parse(), Ok(Bitrate::bits_per_second(250_000)));
    assert_eq!("1M".parse(), Ok(Bitrate::bits_per_second(1_000_000)));
    assert_eq!("Unlimited".parse(), Ok(Bitrate::Unlimited));
    for wrong in ["", "0", "2M", "fast", "-5", "1.5k"] {
        assert!(wrong.parse::<Bitrate>().is_err(), "{wrong}");
    }
    assert_eq!(Bitrate::default().get(), Some(500_000));
    assert_eq!(Bitrate::Unlimited.to_string(), "unlimited");
    assert_eq!(at_125k().duration_of(135), Duration::from_micros(1080));
}

#[test]
fn arbitration_follows_the_bits_on_the_wire() {
    let key = |frame: Frame| arbitration_key(&frame);
    let remote = |id| Frame::remote(CanId::Standard(id), 0).unwrap();
    let ext = |id| Frame::new(CanId::Extended(id), &[]).unwrap();
    assert!(key(data(0x100, 8)) < key(data(0x101, 0)));
    // A data frame beats the remote frame with its identifier (RTR).
    assert!(key(data(0x701, 1)) < key(remote(0x701)));
    // A standard frame beats an extended one with the same base (SRR, IDE)...
    assert!(key(remote(0x100)) < key(ext(0x100 << 18)));
    // ...and loses to one whose base is lower.
    assert!(key(ext(0x0FF << 18 | 0x3_FFFF)) < key(data(0x100, 0)));
    assert!(key(ext(5)) < key(ext(6)));
}

#[test]
fn the_lowest_identifier_queued_when_the_bus_frees_goes_first() {
    let t0 = Instant::now();
    let mut wire = Wire::new(at_125k());
    wire.queue('a', data(0x300, 8), t0);
    // On the wire from t0: 135 bits.
    assert!(wire.poll(t0).is_empty());
    assert_eq!(wire.deadline(), Some(t0 + bits(135)));
    // While it crosses, b and c queue; c's lower identifier wins next.
    wire.queue('b', data(0x200, 0), t0 + bits(10));
    wire.queue('c', data(0x100, 0), t0 + bits(20));
    let crossed = wire.poll(t0 + bits(1000));
    let order: Vec<_> = crossed.iter().map(|c| (c.sender, c.end)).collect();
    assert_eq!(
        order,
        [
            ('a', t0 + bits(135)),
            ('c', t0 + bits(135 + 55)),
            ('b', t0 + bits(135 + 55 + 55)),
        ]
    );
    assert_eq!(crossed[1].start, t0 + bits(135));
    assert_eq!(wire.busy_bits(), 245);
    assert_eq!(wire.deadline(), None);
}

#[test]
fn a_frame_queued_after_the_bus_freed_waits_for_no_one() {
    let t0 = Instant::now();
    let mut wire = Wire::new(at_125k());
    wire.queue('a', data(0x7FF, 0), t0);
    assert_eq!(wire.poll(t0 + bits(55)).len(), 1);
    // The bus is idle; a frame queued later starts when it is queued.
    let later = t0 + bits(500);
    wire.queue('b', data(0x7FF, 0), later);
    assert_eq!(wire.deadline(), Some(later));
    let crossed = wire.poll(later + bits(55));
    assert_eq!(
        (crossed[0].start, crossed[0].end),
        (later, later + bits(55))
    );
}

#[test]
fn each_sender_keeps_its_own_order() {
    let t0 = Instant::now();
    let mut wire = Wire::new(at_125k());
    // An RPDO then a SYNC from the master: the SYNC does not overtake.
    wire.queue('m', data(0x201, 2), t0);
    wire.queue('m', data(0x080, 0), t0);
    let crossed = wire.poll(t0 + bits(1000));
    let ids: Vec<_> = crossed.iter().map(|c| c.frame.id()).collect();
    assert_eq!(ids, [CanId::Standard(0x201), CanId::Standard(0x080)]);
}

#[test]
fn a_flood_of_high_priority_frames_holds_a_heartbeat_back() {
    let t0 = Instant::now();
    let mut wire = Wire::new(at_125k());
    for _ in 0..50 {
        wire.queue('f', data(0x081, 8), t0);
    }
    wire.queue('d', data(0x705, 1), t0);
    // The flood keeps a frame at the head of its queue in every round, so
    // the heartbeat goes after the 50th: 50 × 135 + 65 bits (its 55 bits
    // with one data byte and the intermission, and 10 stuff bits).
    let crossed = wire.poll(t0 + Duration::from_secs(1));
    assert_eq!(crossed.len(), 51);
    let heartbeat = crossed.last().unwrap();
    assert_eq!(heartbeat.sender, 'd');
    assert_eq!(heartbeat.end, t0 + bits(50 * 135 + 65));
    // Gone from the bus, a sender's queue goes with it.
    wire.queue('f', data(0x081, 8), t0 + Duration::from_secs(1));
    assert_eq!(wire.queued('f'), 1);
    assert_eq!(wire.remove('f'), 1);
    assert_eq!(wire.deadline(), None);
}

#[test]
fn unlimited_takes_no_time() {
    let t0 = Instant::now();
    let mut wire = Wire::new(Bitrate::Unlimited);
    for id in [3, 1, 2] {
        wire.queue(id, data(id as u16, 8), t0);
    }
    let crossed = wire.poll(t0);
    assert!(crossed.iter().all(|c| c.end == t0));
    let ids: Vec<_> = crossed.iter().map(|c| c.sender).collect();
    assert_eq!(ids, [1, 2, 3]);
}
