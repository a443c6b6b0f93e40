use super::*;

fn samples(values: &[f64], to: f64) -> Vec<[f64; 3]> {
    values
        .iter()
        .enumerate()
        .map(|(t, v)| [t as f64, to, *v])
        .collect()
}

#[test]
fn a_clean_step_has_its_rise_time_overshoot_and_settling() {
    // 0 → 100: 10 at 1 ms, 90 at 3 ms, a peak of 120, in the 2 % band
    // from 7 ms on.
    let values = [
        0.0, 10.0, 50.0, 90.0, 120.0, 110.0, 97.0, 101.0, 100.0, 99.0,
    ];
    let result = metrics(0.0, 100.0, 2.0, samples(&values, 100.0));
    assert_eq!(result.rise_time_ms, Some(2.0));
    assert!((result.overshoot_pct - 20.0).abs() < 1e-9);
    assert_eq!(result.settling_time_ms, Some(7.0));
    // The last tenth (one sample): 99.
    assert_eq!(result.steady_state_error, 1.0);
    assert_eq!(result.samples.len(), 10);
}

#[test]
fn a_downward_step_counts_the_same_way() {
    let values = [100.0, 80.0, 20.0, -5.0, 0.0, 0.0];
    let result = metrics(100.0, 0.0, 2.0, samples(&values, 0.0));
    // 90 (10 %) at 1 ms... 80 is 20 %: first ≥ 10 % at 1 ms; ≥ 90 % (10)
    // at 3 ms.
    assert_eq!(result.rise_time_ms, Some(2.0));
    assert!((result.overshoot_pct - 5.0).abs() < 1e-9);
    assert_eq!(result.settling_time_ms, Some(4.0));
    assert_eq!(result.steady_state_error, 0.0);
}

#[test]
fn a_response_that_never_arrives_has_no_rise_or_settling_time() {
    let values = [0.0, 20.0, 40.0, 50.0, 50.0];
    let result = metrics(0.0, 100.0, 2.0, samples(&values, 100.0));
    assert_eq!(result.rise_time_ms, None);
    assert_eq!(result.settling_time_ms, None);
    assert_eq!(result.overshoot_pct, 0.0);
    assert_eq!(result.steady_state_error, 50.0);
    let empty = metrics(0.0, 100.0, 2.0, Vec::new());
    assert_eq!(empty.rise_time_ms, None);
    assert_eq!(empty.steady_state_error, 100.0);
}

#[test]
fn requests_are_checked_before_the_bus() {
    let request = |json: &str| serde_json::from_str::<StepTestRequest>(json).unwrap();
    let ok = request(r#"{"loop":"velocity","from":0,"to":500,"hold_ms":200}"#);
    assert_eq!(ok.settle_band_pct, 2.0);
    assert!(ok.validate().is_ok());
    for bad in [
        r#"{"loop":"velocity","from":5,"to":5,"hold_ms":200}"#,
        r#"{"loop":"velocity","from":0,"to":5,"hold_ms":5}"#,
        r#"{"loop":"velocity","from":0,"to":5,"hold_ms":200,"settle_band_pct":0}"#,
        r#"{"loop":"torque","from":0,"to":40000,"hold_ms":200}"#,
    ] {
        assert!(request(bad).validate().is_err(), "{bad}");
    }
    assert!(
        serde_json::from_str::<StepTestRequest>(
            r#"{"loop":"current","from":0,"to":1,"hold_ms":50}"#
        )
        .is_err()
    );
}
