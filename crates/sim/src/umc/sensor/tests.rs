use super::*;

#[test]
fn the_defaults_pass_the_raw_value_through() {
    let mut sensor = Sensor::default();
    assert_eq!(sensor.read(&Conditioning::default(), 12.5), 12.5);
    assert_eq!(sensor.flags, VALID);
    // The manual's raw defaults are the same thing.
    let raw = [
        0,
        65536,
        0,
        i64::from(i32::MIN),
        i64::from(i32::MAX),
        i64::from(i32::MIN),
        i64::from(i32::MAX),
        0,
    ];
    assert_eq!(Conditioning::from_raw(raw), Conditioning::default());
}

#[test]
fn offsets_and_scale_then_errors_and_thresholds() {
    let config = Conditioning {
        pre_offset: 1.0,
        scale: 2.0,
        post_offset: -0.5,
        error_min: -10.0,
        error_max: 10.0,
        threshold_min: 0.0,
        threshold_max: 4.0,
        threshold_mode: 0,
    };
    let mut sensor = Sensor::default();
    // (2 + 1) · 2 − 0.5 = 5.5.
    assert_eq!(sensor.read(&config, 2.0), 5.5);
    assert_eq!(sensor.read(&config, 10.0), 21.5);
    assert_eq!(sensor.flags, MAX_ERROR);
    sensor.read(&config, -10.0);
    assert_eq!(sensor.flags, MIN_ERROR);
    let clamp = Conditioning {
        threshold_mode: 1,
        ..config
    };
    assert_eq!(sensor.read(&clamp, 2.0), 4.0);
    let modulo = Conditioning {
        threshold_mode: 2,
        ..config
    };
    assert_eq!(sensor.read(&modulo, 2.0), 1.5);
    let last = Conditioning {
        threshold_mode: 3,
        ..config
    };
    assert_eq!(sensor.read(&last, 1.0), 3.5);
    assert_eq!(sensor.read(&last, 50.0), 3.5, "kept while in error");
    assert_eq!(sensor.flags, MAX_ERROR);
}
