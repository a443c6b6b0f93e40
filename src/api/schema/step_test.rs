//! The schemas of `crate::gateway::step_test`'s request and answer.

use utoipa::ToSchema;

/// Which loop a step test exercises.
#[derive(Debug, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum StepLoop {
    Torque,
    Velocity,
    Position,
}

/// `POST .../axes/{axis}/step-test`.
#[derive(Debug, ToSchema)]
#[serde(deny_unknown_fields)]
#[schema(example = json!({"loop": "velocity", "from": 0, "to": 500, "hold_ms": 300, "settle_band_pct": 2}))]
pub struct StepTestRequest {
    /// The loop: `torque` (TQ, per mille of rated torque), `velocity` (VL,
    /// velocity units) or `position` (PP, increments).
    #[serde(rename = "loop")]
    pub loop_: StepLoop,
    /// The level held first, in the mode's target units.
    pub from: i32,
    /// The level stepped to.
    pub to: i32,
    /// How long each level is held, ms (20 to 10,000).
    pub hold_ms: u32,
    /// The settling band, per cent of the step (default 2).
    // 2 when not given (the gateway's default): utoipa reads only that it
    // may be left out.
    #[serde(default)]
    pub settle_band_pct: f64,
}

/// Where a step test's actual values came from.
#[derive(Debug, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum SampleSource {
    /// Every sample from a TPDO frame that carried the actual value.
    Tpdo,
    /// Every sample read by SDO.
    Sdo,
    /// From the TPDO until it fell silent, then by SDO.
    TpdoThenSdo,
}

/// How a step test sampled the actual value.
#[derive(Debug, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Sampling {
    /// From a TPDO's frames: the test's own, or one already running.
    Tpdo,
    /// By SDO reads: the node could have no sampling TPDO.
    Sdo,
}

/// What a step test measured.
#[derive(Debug, ToSchema)]
pub struct StepTestResult {
    /// How the actual value was sampled: `tpdo` (a TPDO's frames, the
    /// test's own at up to 1 kHz or one already running) or `sdo`.
    pub sampling: Sampling,
    /// Samples per second over the hold after the step, as achieved.
    pub sample_rate_hz: f64,
    /// Which TPDO at which period, or why by SDO.
    pub sampling_note: String,
    /// Where the actual values came from: `tpdo` (a TPDO's frames), `sdo`
    /// (read every millisecond, or as fast as the node answers), or
    /// `tpdo_then_sdo` (the TPDO fell silent during the hold).
    pub source: SampleSource,
    /// 10 % to 90 % of the step, ms; null if the actual never got to 90 %.
    pub rise_time_ms: Option<f64>,
    /// How far past the target the actual went, per cent of the step.
    pub overshoot_pct: f64,
    /// From the step until the actual stayed within the band, ms; null if
    /// it was outside at the end.
    pub settling_time_ms: Option<f64>,
    /// Target minus the mean actual over the last tenth of the hold, in
    /// the target's units.
    pub steady_state_error: f64,
    /// `[t_ms, target, actual]` from the step on.
    #[schema(value_type = Vec<Vec<f64>>)]
    pub samples: Vec<[f64; 3]>,
    /// The gains of the loop tested, as the drive had them (its
    /// configuration record's P, I and D); null where they could not be
    /// read.
    pub gains: Option<LoopGains>,
}

/// The gains of one control loop (UMC manual chapter 1 §3.5.3).
#[derive(Debug, ToSchema)]
pub struct LoopGains {
    pub p: f64,
    pub i: f64,
    pub d: f64,
}
