//! The step test of a UMC axis's control loop (UMC manual chapter 1 §3.5;
//! what UniSwarm's UDTStudio PID widget does): the loop's target is held at
//! `from`, then stepped to `to` and held, while its actual value is
//! recorded; the answer is the response with its rise time, overshoot,
//! settling time and steady-state error.
//!
//! Each loop is exercised through the CiA 402 mode whose target is its
//! input (UMC manual chapter 2): the torque loop in TQ (0x6071 → 0x6077,
//! per mille of the rated torque), the velocity loop in VL (0x6042 →
//! 0x6044, velocity units), the position loop in PP with change
//! immediately (0x607A → 0x6064, increments). For the test's duration the
//! gateway lifts what shapes the set-point in that mode, so that the step
//! reaches the loop as a step, not as the mode's ramp ([`Shaping`]): TQ's
//! slope 0x6087, VL's ramps 0x6048 and 0x6049, PP's profile velocity,
//! acceleration and deceleration (0x6081, 0x6083, 0x6084, up to the
//! drive's own limits 0x607F, 0x60C5, 0x60C6); every value it changed is
//! written back afterwards, also when the test fails or its caller goes
//! (the test runs in a task of its own), each as a row of the audit log.
//! A position step larger than the following-error window (0x6065), or a
//! move to `from` that is, is refused before anything is written: the
//! drive would fault on it. The actual value is taken from the TPDO that carries
//! it when one runs (the node sent the axis's actual value in a TPDO within
//! the last [`TPDO_FRESH`] when the step is made: node operational, the
//! TPDO on an event timer or on SYNC): one sample per frame, timed by its
//! arrival, at whatever rate the TPDO comes, and no SDO transfer. If that
//! TPDO then falls silent for [`TPDO_FRESH`], the rest of the hold is read
//! by SDO. Without such a TPDO the actual value is read by SDO every
//! millisecond (the board's control cycle), or as fast as the node answers
//! when that is slower; each read queues on the node's channel with
//! everyone else's. The answer's `source` says which.
//!
//! Only a UMC-class drive (one with the PID objects) and only an axis in
//! operation enabled are tested. Whatever happens, the axis is stopped at
//! the end (halt, or quick stop if the halt cannot be written).

use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::GatewayError;
use crate::audit::AuditRow;
use crate::authority::AxisTicket;
use crate::axis_telemetry::TPDO_FRESH;
use crate::drive::{Drive, DriveError, DriveKind, MoveRequest};
use crate::profiles::cia402::State;
use crate::profiles::cia402::objects as obj;
use crate::values::TpdoValues;

#[cfg(test)]
mod tests;

/// Opens the audit row of what the test does to the axis besides its
/// steps (the operation's words, the summary).
pub(crate) type Audit<'a> = &'a (dyn Fn(&str, String) -> AuditRow + Send + Sync);

/// The shortest and longest hold of each level, ms.
pub(crate) const HOLD_MS: (u32, u32) = (20, 10_000);
/// The sampling period: the board's control cycle (UMC: 1 ms).
pub(crate) const SAMPLE_PERIOD: Duration = Duration::from_millis(1);
/// At most this many samples are kept per test.
pub(crate) const MAX_SAMPLES: usize = 20_000;

/// Which loop a step test exercises.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StepLoop {
    Torque,
    Velocity,
    Position,
}

/// `POST .../axes/{axis}/step-test`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
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
    #[serde(default = "default_band")]
    pub settle_band_pct: f64,
}

fn default_band() -> f64 {
    2.0
}

/// Where a step test's actual values came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SampleSource {
    /// Every sample from a TPDO frame that carried the actual value.
    Tpdo,
    /// Every sample read by SDO.
    Sdo,
    /// From the TPDO until it fell silent, then by SDO.
    TpdoThenSdo,
}

/// What a step test measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StepTestResult {
    /// Where the actual values came from: `tpdo` (the frames of a running
    /// TPDO that carries the loop's actual value, at its rate), `sdo`
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
    pub samples: Vec<[f64; 3]>,
    /// The gains of the loop tested, as the drive had them (its
    /// configuration record's P, I and D): the run's own, for its history.
    pub gains: Option<LoopGains>,
}

/// The gains of one control loop (UMC manual chapter 1 §3.5.3, Q15.16).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LoopGains {
    pub p: f64,
    pub i: f64,
    pub d: f64,
}

impl StepTestRequest {
    /// Checks the request before the bus.
    pub fn validate(&self) -> Result<(), DriveError> {
        if self.from == self.to {
            return Err(DriveError::Invalid("from and to must differ".into()));
        }
        if !(HOLD_MS.0..=HOLD_MS.1).contains(&self.hold_ms) {
            return Err(DriveError::Invalid(format!(
                "hold_ms must be {} to {}",
                HOLD_MS.0, HOLD_MS.1
            )));
        }
        if !(self.settle_band_pct > 0.0 && self.settle_band_pct <= 50.0) {
            return Err(DriveError::Invalid(
                "settle_band_pct must be above 0 and at most 50".into(),
            ));
        }
        match self.loop_ {
            StepLoop::Torque => {
                for value in [self.from, self.to] {
                    if i16::try_from(value).is_err() {
                        return Err(DriveError::OutOfRange(format!(
                            "torque {value} does not fit 0x6071 (-32768 to 32767)"
                        )));
                    }
                }
            }
            StepLoop::Velocity => {
                for value in [self.from, self.to] {
                    if i16::try_from(value).is_err() {
                        return Err(DriveError::OutOfRange(format!(
                            "velocity {value} does not fit 0x6042 (-32768 to 32767)"
                        )));
                    }
                }
            }
            StepLoop::Position => {}
        }
        Ok(())
    }

    /// The move that sets the loop's target to `level`.
    fn level(&self, level: i32) -> MoveRequest {
        match self.loop_ {
            StepLoop::Torque => MoveRequest::Torque {
                torque: level as i16,
                slope: None,
            },
            StepLoop::Velocity => MoveRequest::Velocity {
                velocity: level,
                acceleration: None,
                deceleration: None,
            },
            StepLoop::Position => MoveRequest::ProfilePosition {
                target: level,
                relative: false,
                immediate: true,
                velocity: None,
                acceleration: None,
                deceleration: None,
            },
        }
    }

    /// The axis-1 configuration record of the loop (0x4021, 0x4041,
    /// 0x4061: P, I, D in subs 1 to 3).
    fn loop_config(&self) -> u16 {
        match self.loop_ {
            StepLoop::Torque => crate::profiles::umc::axis::TORQUE_PID_CONFIG,
            StepLoop::Velocity => crate::profiles::umc::axis::VELOCITY_PID_CONFIG,
            StepLoop::Position => crate::profiles::umc::axis::POSITION_PID_CONFIG,
        }
    }

    /// The axis-1 object that reads the loop's actual value.
    fn actual(&self) -> u16 {
        match self.loop_ {
            StepLoop::Torque => obj::TQ_ACTUAL,
            StepLoop::Velocity => obj::VL_ACTUAL,
            StepLoop::Position => obj::POSITION_ACTUAL,
        }
    }
}

/// Runs a step test on `drive`; the axis is stopped at the end whatever
/// happened.
/// `values`: the TPDO values of the drive's bus, which feed the samples
/// when they carry the loop's actual value (see the module documentation).
/// `ticket`: the test's right to the axis, which `drive` holds too (its
/// writes go under the axis's gate, none after a stop); each hold waits on
/// it, so a stop of the axis (halt, quick stop, STOP ALL, a lapsed lease)
/// ends the test at once with `motion_stopped`, and no step is sent after
/// the stop (which has stopped the axis itself).
pub(crate) async fn run(
    drive: &Drive,
    values: &TpdoValues,
    request: &StepTestRequest,
    ticket: &AxisTicket,
    audit: Audit<'_>,
) -> Result<StepTestResult, GatewayError> {
    request.validate()?;
    if drive.kind() != DriveKind::Umc {
        return Err(DriveError::NotTunable(format!(
            "node {} is a {:?} drive: the step test needs a UMC-class drive, whose control loops \
             are 0x4020-0x4061 (UMC manual §3.5)",
            drive.node(),
            drive.kind()
        ))
        .into());
    }
    let statusword = drive.statusword().await?;
    match statusword.state() {
        Some(State::OperationEnabled) => {}
        state => {
            return Err(DriveError::NotEnabled {
                axis: drive.axis(),
                state,
            }
            .into());
        }
    }
    if request.loop_ == StepLoop::Position {
        within_following_window(drive, request).await?;
    }
    let gains = loop_gains(drive, request).await;
    let mut shaping = Shaping::of(drive, request).await?;
    let lifted = shaping.lift(drive, audit).await;
    let result = match lifted {
        Ok(()) => steps(drive, values, request, ticket).await,
        Err(error) => Err(error),
    };
    // The stop always goes out: after a result, and after a failure; but
    // not after a stop of the axis, which stopped it already (and a halt's
    // enable-operation bits would take a quick-stopped axis out of quick
    // stop active again).
    if !ticket.stopped() {
        drive.stop_after_failure().await;
    }
    // Put back whatever was lifted, whatever happened: not through the
    // ticket, which a stop voids.
    let restored = shaping.restore(&drive.untethered(), audit).await;
    let mut result = result?;
    restored?;
    result.gains = gains;
    Ok(result)
}

/// The gains of the loop under test, read from its configuration record;
/// `None` where the drive does not answer them (the test goes on).
async fn loop_gains(drive: &Drive, request: &StepTestRequest) -> Option<LoopGains> {
    let config = request.loop_config();
    let mut gains = [0.0; 3];
    for (sub, gain) in (1u8..).zip(gains.iter_mut()) {
        let raw = drive.read_int(config, sub, true).await.ok()?;
        *gain = f64::from(raw as i32) / 65536.0;
    }
    Some(LoopGains {
        p: gains[0],
        i: gains[1],
        d: gains[2],
    })
}

/// A position step the drive would fault on is refused before anything is
/// written: the step (and the move to `from` before it), with the profile
/// lifted, is a following error of its whole size at once, and a drive
/// faults on one beyond 0x6065 for longer than 0x6066 (CiA 402 §6.2.3;
/// 0xFFFFFFFF switches the detection off).
async fn within_following_window(
    drive: &Drive,
    request: &StepTestRequest,
) -> Result<(), GatewayError> {
    let window = drive
        .read_int(obj::FOLLOWING_ERROR_WINDOW, 0, false)
        .await?;
    if window == i64::from(u32::MAX) {
        return Ok(());
    }
    let position = drive.read_int(obj::POSITION_ACTUAL, 0, true).await?;
    let moves = [
        ("the move to from", position, i64::from(request.from)),
        ("the step", i64::from(request.from), i64::from(request.to)),
    ];
    for (what, start, end) in moves {
        let size = (end - start).abs();
        if size >= window {
            return Err(DriveError::StepBeyondFollowingWindow(format!(
                "{what} ({start} to {end}: {size} increments) is not inside the following error \
                 window 0x{:04X} = {window} increments: the drive would fault on it; step by \
                 less, or widen the window",
                drive.object(obj::FOLLOWING_ERROR_WINDOW)
            ))
            .into());
        }
    }
    Ok(())
}

/// What shapes the set-point in the mode of the loop under test, and the
/// values the test gives it: one object each (axis-1 index, sub), with the
/// bytes it had before and the value it is lifted to.
struct Shaping {
    objects: Vec<Lifted>,
}

struct Lifted {
    index: u16,
    sub: u8,
    default: crate::canopen::od::DataType,
    value: i64,
    /// As read before the test: written back byte for byte.
    before: Option<Vec<u8>>,
}

impl Shaping {
    /// The objects the loop's mode shapes its set-point with and the value
    /// each is lifted to: the whole step (and the move to `from`) within
    /// one millisecond, as far as the drive's own limits allow.
    async fn of(drive: &Drive, request: &StepTestRequest) -> Result<Self, GatewayError> {
        use crate::canopen::od::DataType as T;
        let span = [
            i64::from(request.from).abs(),
            i64::from(request.to).abs(),
            (i64::from(request.to) - i64::from(request.from)).abs(),
        ]
        .into_iter()
        .max()
        .unwrap_or(1)
        .max(1);
        let lift = |index, sub, default, value| Lifted {
            index,
            sub,
            default,
            value,
            before: None,
        };
        let objects = match request.loop_ {
            // 0x6087 is per mille of the rated torque per second.
            StepLoop::Torque => vec![lift(
                obj::TQ_SLOPE,
                0,
                T::Unsigned32,
                (span * 1000).min(i64::from(u32::MAX)),
            )],
            // Delta speed per delta time of one: the whole span at once.
            StepLoop::Velocity => vec![
                lift(obj::VL_ACCELERATION, 1, T::Unsigned32, span),
                lift(obj::VL_ACCELERATION, 2, T::Unsigned16, 1),
                lift(obj::VL_DECELERATION, 1, T::Unsigned32, span),
                lift(obj::VL_DECELERATION, 2, T::Unsigned16, 1),
            ],
            // Up to the drive's limits, which the test does not touch.
            StepLoop::Position => {
                let mut objects = Vec::new();
                for (object, limit) in [
                    (obj::PROFILE_VELOCITY, obj::MAX_PROFILE_VELOCITY),
                    (obj::PROFILE_ACCELERATION, obj::MAX_ACCELERATION),
                    (obj::PROFILE_DECELERATION, obj::MAX_DECELERATION),
                ] {
                    if let Some(limit) = drive.read_optional(limit, 0, false).await? {
                        objects.push(lift(object, 0, T::Unsigned32, limit));
                    }
                }
                objects
            }
        };
        Ok(Self { objects })
    }

    /// Reads each object's value, then writes the lifted one; one audit
    /// row says what was lifted from what. On a failure what was written
    /// so far is restored by [`Shaping::restore`].
    async fn lift(&mut self, drive: &Drive, audit: Audit<'_>) -> Result<(), GatewayError> {
        for object in &mut self.objects {
            let index = drive.object(object.index);
            let before = drive.channel().upload(index, object.sub).await;
            object.before = Some(before.map_err(DriveError::from)?);
        }
        let row = audit(
            "step test: set-point shaping lifted",
            self.describe(|object| object.value),
        );
        let mut result = Ok(());
        for object in &self.objects {
            let write = drive.encode(
                object.index,
                object.sub,
                object.default,
                object.value,
                "lifted value",
            );
            let written = match write {
                Ok(write) => drive.write(&write).await,
                Err(error) => Err(error),
            };
            if let Err(error) = written {
                result = Err(GatewayError::from(error));
                break;
            }
        }
        row.finish(&result).await;
        result
    }

    /// Writes back every value read before the test; one audit row.
    async fn restore(&self, drive: &Drive, audit: Audit<'_>) -> Result<(), GatewayError> {
        let read: Vec<&Lifted> = self
            .objects
            .iter()
            .filter(|object| object.before.is_some())
            .collect();
        if read.is_empty() {
            return Ok(());
        }
        let row = audit(
            "step test: set-point shaping restored",
            self.describe(|object| object.before.as_deref().map_or(0, little_endian)),
        );
        let mut result = Ok(());
        for object in read {
            let bytes = object.before.as_deref().unwrap_or_default();
            let index = drive.object(object.index);
            // Every one is tried, even after one failed.
            if let Err(error) = drive.download(index, object.sub, bytes).await
                && result.is_ok()
            {
                result = Err(GatewayError::from(error));
            }
        }
        row.finish(&result).await;
        result
    }

    /// `0x6048.1 = 1000, 0x6048.2 = 1, ...` with each object's `value`.
    fn describe(&self, value: impl Fn(&Lifted) -> i64) -> String {
        self.objects
            .iter()
            .map(|object| format!("0x{:04X}.{} = {}", object.index, object.sub, value(object)))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// An unsigned little-endian integer of up to 8 bytes.
fn little_endian(bytes: &[u8]) -> i64 {
    let mut buffer = [0u8; 8];
    let len = bytes.len().min(8);
    buffer[..len].copy_from_slice(&bytes[..len]);
    i64::from_le_bytes(buffer)
}

async fn steps(
    drive: &Drive,
    values: &TpdoValues,
    request: &StepTestRequest,
    ticket: &AxisTicket,
) -> Result<StepTestResult, GatewayError> {
    let hold = Duration::from_millis(u64::from(request.hold_ms));
    drive.run_move(&request.level(request.from)).await?;
    ticket.hold(hold).await?;
    let actual = request.actual();
    let start = tokio::time::Instant::now();
    drive.run_move(&request.level(request.to)).await?;
    let mut samples = Vec::new();
    let sample = |t: Duration, value: i64| {
        [
            t.as_secs_f64() * 1000.0,
            f64::from(request.to),
            value as f64,
        ]
    };
    let tpdo = Tpdo {
        values,
        node: drive.node_id(),
        index: drive.object(actual),
    };
    let mut source = SampleSource::Sdo;
    if tpdo.running(tokio::time::Instant::now()).is_some() {
        source = SampleSource::Tpdo;
        if !tpdo.record(start, hold, &mut samples, sample, ticket).await {
            source = SampleSource::TpdoThenSdo;
        }
    }
    ticket.check()?;
    let done = |samples: &Vec<[f64; 3]>| {
        samples.len() >= MAX_SAMPLES
            || samples
                .last()
                .is_some_and(|s| s[0] >= hold.as_secs_f64() * 1000.0)
    };
    if source != SampleSource::Tpdo && !done(&samples) {
        // At the loop's 1 ms rate, or as fast as the node answers if slower.
        let mut tick = tokio::time::interval(SAMPLE_PERIOD);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        loop {
            tick.tick().await;
            ticket.check()?;
            let value = drive.read_int(actual, 0, true).await?;
            samples.push(sample(start.elapsed(), value));
            if done(&samples) {
                break;
            }
        }
    }
    let statusword = drive.statusword().await?;
    if statusword.state() != Some(State::OperationEnabled) {
        return Err(DriveError::NotEnabled {
            axis: drive.axis(),
            state: statusword.state(),
        }
        .into());
    }
    let mut result = metrics(
        f64::from(request.from),
        f64::from(request.to),
        request.settle_band_pct,
        samples,
    );
    result.source = source;
    Ok(result)
}

/// The TPDO value of the loop's actual value.
struct Tpdo<'a> {
    values: &'a TpdoValues,
    node: crate::canopen::NodeId,
    index: u16,
}

impl Tpdo<'_> {
    /// The newest value if a TPDO carries it and sent it within
    /// [`TPDO_FRESH`] of `now`.
    fn running(&self, now: tokio::time::Instant) -> Option<super::values::TpdoValue> {
        self.values
            .value(self.node, self.index, 0)
            .filter(|value| now.saturating_duration_since(value.at) <= TPDO_FRESH)
    }

    /// One sample per frame that carries the value, from `start` until the
    /// first frame at or after the hold's end (true: as the SDO path ends
    /// with its first read at or after it), or until the TPDO has been
    /// silent for [`TPDO_FRESH`] (false: the rest is for SDO).
    async fn record(
        &self,
        start: tokio::time::Instant,
        hold: Duration,
        samples: &mut Vec<[f64; 3]>,
        sample: impl Fn(Duration, i64) -> [f64; 3],
        ticket: &AxisTicket,
    ) -> bool {
        let mut frames = self.values.watch_frames(self.node);
        let mut counted = None;
        let end = start + hold;
        loop {
            // Seen before reading: a frame from here on wakes the wait.
            frames.borrow_and_update();
            let Some(value) = self.values.value(self.node, self.index, 0) else {
                // No longer mapped (the TPDOs were read again).
                return false;
            };
            // A new frame, and not one from before the step (the newest
            // of those sent while the step was being written counts).
            if counted != Some(value.count) {
                counted = Some(value.count);
                if value.at >= start {
                    samples.push(sample(value.at - start, value.as_i64(true)));
                    if value.at >= end || samples.len() >= MAX_SAMPLES {
                        return true;
                    }
                }
            }
            if ticket.stopped() {
                return false;
            }
            tokio::select! {
                changed = frames.changed() => {
                    if changed.is_err() {
                        return false;
                    }
                }
                () = tokio::time::sleep(TPDO_FRESH) => return false,
            }
        }
    }
}

/// The metrics of a step from `from` to `to` recorded as `samples`
/// (`[t_ms, target, actual]`, time from the step).
pub(crate) fn metrics(from: f64, to: f64, band_pct: f64, samples: Vec<[f64; 3]>) -> StepTestResult {
    let step = to - from;
    // The response as a fraction of the step: 0 at `from`, 1 at `to`.
    let fraction = |actual: f64| (actual - from) / step;
    let first = |level: f64| {
        samples
            .iter()
            .find(|s| fraction(s[2]) >= level)
            .map(|s| s[0])
    };
    let rise_time_ms = match (first(0.1), first(0.9)) {
        (Some(low), Some(high)) => Some(high - low),
        _ => None,
    };
    let peak = samples
        .iter()
        .map(|s| fraction(s[2]))
        .fold(f64::NEG_INFINITY, f64::max);
    let overshoot_pct = if peak.is_finite() {
        ((peak - 1.0) * 100.0).max(0.0)
    } else {
        0.0
    };
    let band = band_pct / 100.0;
    let outside = samples
        .iter()
        .rposition(|s| (fraction(s[2]) - 1.0).abs() > band);
    let settling_time_ms = match outside {
        None => samples.first().map(|s| s[0]),
        Some(last) => samples.get(last + 1).map(|s| s[0]),
    };
    let tail = (samples.len() / 10).max(1).min(samples.len());
    let steady_state_error = if samples.is_empty() {
        step
    } else {
        let mean = samples[samples.len() - tail..]
            .iter()
            .map(|s| s[2])
            .sum::<f64>()
            / tail as f64;
        to - mean
    };
    StepTestResult {
        source: SampleSource::Sdo,
        rise_time_ms,
        overshoot_pct,
        settling_time_ms,
        steady_state_error,
        samples,
        gains: None,
    }
}
