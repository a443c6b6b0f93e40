use super::*;
use crate::profiles::umc::pid::{ANTI_REVERSE, PidConfig};

fn config(p: f64, i: f64, d: f64) -> PidConfig {
    PidConfig {
        p,
        i,
        d,
        min: -100.0,
        max: 100.0,
        threshold: 0.0,
        frequency_divider: 1,
        flags: 0,
    }
}

#[test]
fn proportional_integral_and_derivative_terms_add_up() {
    let mut pid = Pid::default();
    // e = 2: P 2·0.5 = 1, I 10·2·0.001 = 0.02, no D on the first run.
    let out = pid.step(&config(0.5, 10.0, 0.1), 2.0, 0.0, 0.001);
    assert!((out - 1.02).abs() < 1e-12, "{out}");
    assert_eq!(pid.error, 2.0);
    assert!((pid.integrator - 0.02).abs() < 1e-12);
    // e = 1: P 0.5, I 0.02 + 0.01, D 0.1·(1 − 2)/0.001 = −100.
    let out = pid.step(&config(0.5, 10.0, 0.1), 2.0, 1.0, 0.001);
    assert!((out + 99.47).abs() < 1e-9, "{out}");
    // D alone past Min: clamped.
    let out = pid.step(&config(0.0, 0.0, 1.0), 2.0, 2.0, 0.001);
    assert_eq!(out, -100.0);
    assert_eq!(pid.input, 2.0);
}

#[test]
fn the_output_stays_within_min_and_max_and_the_integrator_does_not_wind_up() {
    let mut cfg = config(1.0, 100.0, 0.0);
    cfg.min = -5.0;
    cfg.max = 5.0;
    let mut pid = Pid::default();
    for _ in 0..1000 {
        assert_eq!(pid.step(&cfg, 50.0, 0.0, 0.001), 5.0);
    }
    // P alone saturates: the integrator never started.
    assert_eq!(pid.integrator, 0.0);
    // Back inside the band the output follows at once.
    let out = pid.step(&cfg, 1.0, 0.0, 0.001);
    assert!((out - 1.1).abs() < 1e-12, "{out}");
}

#[test]
fn the_threshold_is_a_dead_band() {
    let mut cfg = config(1.0, 0.0, 0.0);
    cfg.threshold = 0.5;
    let mut pid = Pid::default();
    assert_eq!(pid.step(&cfg, 0.4, 0.0, 0.001), 0.0);
    assert_eq!(pid.step(&cfg, -0.5, 0.0, 0.001), 0.0);
    assert_eq!(pid.step(&cfg, 0.6, 0.0, 0.001), 0.6);
}

#[test]
fn the_frequency_divider_runs_the_loop_every_nth_cycle() {
    let mut cfg = config(1.0, 1000.0, 0.0);
    cfg.frequency_divider = 4;
    let mut pid = Pid::default();
    // The first cycle runs (dt = 4 ms: I adds 1000·1·0.004 = 4).
    assert_eq!(pid.step(&cfg, 1.0, 0.0, 0.001), 5.0);
    // Held for three cycles whatever the error.
    for _ in 0..3 {
        assert_eq!(pid.step(&cfg, 3.0, 0.0, 0.001), 5.0);
    }
    // Then it runs again: P 3 + I 4 + 12.
    assert_eq!(pid.step(&cfg, 3.0, 0.0, 0.001), 19.0);
}

#[test]
fn anti_reverse_cuts_an_output_against_the_target() {
    let mut cfg = config(1.0, 0.0, 0.0);
    let mut pid = Pid::default();
    // Overshoot: target 1, measured 3, P says −2.
    assert_eq!(pid.step(&cfg, 1.0, 3.0, 0.001), -2.0);
    cfg.flags = ANTI_REVERSE;
    assert_eq!(pid.step(&cfg, 1.0, 3.0, 0.001), 0.0);
    assert_eq!(pid.step(&cfg, -1.0, -3.0, 0.001), 0.0);
    // With the target's sign it passes.
    assert_eq!(pid.step(&cfg, 3.0, 1.0, 0.001), 2.0);
}
