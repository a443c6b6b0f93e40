use super::*;

fn passive() -> Transition {
    Transition {
        from: ErrorState::ErrorActive,
        to: ErrorState::ErrorPassive,
    }
}

#[test]
fn sixteen_transmit_errors_make_a_node_error_passive() {
    let mut node = FaultConfinement::new();
    for n in 1..16 {
        assert_eq!(node.transmit_error(), None, "after {n} errors");
        assert_eq!(node.tec(), 8 * n);
    }
    // TEC 128: error passive (ISO 11898-1: "equal to or greater than 128").
    assert_eq!(node.transmit_error(), Some(passive()));
    assert_eq!(node.tec(), 128);
    assert!(node.can_transmit());
}

#[test]
fn thirty_two_transmit_errors_make_it_bus_off_and_it_sends_nothing() {
    let mut node = FaultConfinement::new();
    for _ in 0..31 {
        node.transmit_error();
    }
    assert_eq!(node.tec(), 248);
    assert_eq!(node.state(), ErrorState::ErrorPassive);
    assert_eq!(
        node.transmit_error(),
        Some(Transition {
            from: ErrorState::ErrorPassive,
            to: ErrorState::BusOff,
        })
    );
    assert_eq!(node.tec(), 256);
    assert!(!node.can_transmit());
    // Nothing moves the counters of a node that is off the bus.
    assert_eq!(node.transmit_ok(), None);
    assert_eq!(node.receive_ok(), None);
    assert_eq!(node.tec(), 256);
}

#[test]
fn an_error_then_a_good_retransmission_costs_seven() {
    // The bit-error fault of the virtual devices: every frame fails once and
    // goes through on its retransmission.
    let mut node = FaultConfinement::new();
    let mut frames = 0;
    while node.state() == ErrorState::ErrorActive {
        node.transmit_error();
        node.transmit_ok();
        frames += 1;
    }
    // 7 × 18 = 126, the 19th frame's error takes it to 134.
    assert_eq!(frames, 19);
    assert_eq!(node.tec(), 133);
    while node.can_transmit() {
        node.transmit_error();
        if node.can_transmit() {
            node.transmit_ok();
        }
        frames += 1;
    }
    // 7 × 36 = 252, the 37th error: 260.
    assert_eq!(frames, 37);
    assert_eq!(node.state(), ErrorState::BusOff);
}

#[test]
fn good_transmissions_bring_an_error_passive_node_back() {
    let mut node = FaultConfinement::new();
    for _ in 0..16 {
        node.transmit_error();
    }
    assert_eq!(node.state(), ErrorState::ErrorPassive);
    assert_eq!(
        node.transmit_ok(),
        Some(Transition {
            from: ErrorState::ErrorPassive,
            to: ErrorState::ErrorActive,
        })
    );
    assert_eq!(node.tec(), 127);
}

#[test]
fn receive_errors_make_a_node_passive_but_never_bus_off() {
    let mut node = FaultConfinement::new();
    for _ in 0..127 {
        assert_eq!(node.receive_error(), None);
    }
    assert_eq!(node.receive_error(), Some(passive()));
    for _ in 0..1000 {
        node.receive_error();
    }
    assert_eq!(node.rec(), 255);
    assert_eq!(node.state(), ErrorState::ErrorPassive);
    assert!(node.can_transmit());
    // One good frame brings a REC above 127 back between 119 and 127.
    let back = node.receive_ok();
    assert_eq!(back.map(|t| t.to), Some(ErrorState::ErrorActive));
    assert!((119..=127).contains(&node.rec()), "{}", node.rec());
    node.receive_ok();
    assert_eq!(node.rec(), 126);
}

#[test]
fn bus_off_recovery_waits_for_the_request_then_128_runs_of_11_recessive_bits() {
    let mut node = FaultConfinement::new();
    assert_eq!(node.force_bus_off().map(|t| t.to), Some(ErrorState::BusOff));
    // Not requested: recessive bits alone do nothing.
    assert_eq!(node.recessive_bits(100_000), None);
    assert_eq!(node.state(), ErrorState::BusOff);
    assert!(!node.recovering());
    node.request_recovery();
    assert_eq!(node.recovery_bits_left(), Some(1408));
    assert_eq!(node.recessive_bits(1407), None);
    assert_eq!(node.recovery_bits_left(), Some(1));
    assert_eq!(
        node.recessive_bits(1),
        Some(Transition {
            from: ErrorState::BusOff,
            to: ErrorState::ErrorActive,
        })
    );
    assert_eq!((node.tec(), node.rec()), (0, 0));
    assert!(node.can_transmit());
    assert!(!node.recovering());
}

#[test]
fn automatic_recovery_starts_counting_at_bus_off() {
    let mut node = FaultConfinement::with_recovery(BusOffRecovery::Automatic);
    for _ in 0..32 {
        node.transmit_error();
    }
    assert_eq!(node.state(), ErrorState::BusOff);
    assert!(node.recovering());
    assert_eq!(
        node.recessive_bits(RECOVERY_BITS).map(|t| t.to),
        Some(ErrorState::ErrorActive)
    );
}

#[test]
fn a_recovery_request_outside_bus_off_does_nothing() {
    let mut node = FaultConfinement::new();
    node.request_recovery();
    assert!(!node.recovering());
    assert_eq!(node.recessive_bits(RECOVERY_BITS), None);
    assert_eq!(node.status(), ControllerStatus::default());
}

#[test]
fn states_have_the_names_of_the_api() {
    assert_eq!(ErrorState::ErrorActive.as_str(), "error_active");
    assert_eq!(ErrorState::ErrorPassive.as_str(), "error_passive");
    assert_eq!(ErrorState::BusOff.as_str(), "bus_off");
    assert_eq!(ErrorState::of_counters(127, 127), ErrorState::ErrorActive);
    assert_eq!(ErrorState::of_counters(0, 128), ErrorState::ErrorPassive);
    assert_eq!(ErrorState::of_counters(255, 0), ErrorState::ErrorPassive);
    assert_eq!(ErrorState::of_counters(256, 0), ErrorState::BusOff);
}
