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
//! drive would fault on it.
//!
//! The actual value is sampled at the loop's rate from a TPDO the test
//! sets up for its duration ([`sampling`]: a free TPDO of the node, else
//! its last, carrying the actual value every millisecond, put back as it
//! was afterwards, whatever happens): one sample per frame, timed by its
//! arrival, and no SDO transfer. Where the node cannot have one (not
//! operational, no EDS, no event timer, a refused re-mapping), a TPDO that
//! already carries the actual value (sent within the last [`TPDO_FRESH`]
//! when the step is made) feeds the samples at its own rate, else the
//! actual value is read by SDO every millisecond (the board's control
//! cycle), or as fast as the node answers when that is slower; each read
//! queues on the node's channel with everyone else's. If the TPDO falls
//! silent during the hold, the rest is read by SDO. The answer says how
//! (`sampling`, `source`), why, and at what rate.
//!
//! Only a UMC-class drive (one with the PID objects) and only an axis in
//! operation enabled are tested. Whatever happens, the axis is stopped at
//! the end (halt, or quick stop if the halt cannot be written).

use std::sync::Arc;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::sync::Notify;
use tokio::sync::broadcast::{self, error::RecvError};

use crate::GatewayError;
use crate::audit::AuditRow;
use crate::authority::AxisTicket;
use crate::axis_telemetry::TPDO_FRESH;
use crate::drive::{Drive, DriveError, DriveKind, MoveRequest};
use crate::node::NodeHandle;
use crate::profiles::cia402::State;
use crate::profiles::cia402::objects as obj;
use crate::values::{TpdoFrame, TpdoValues};

mod sampling;
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

/// How a step test sampled the actual value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Sampling {
    /// From a TPDO's frames: the test's own, or one already running.
    Tpdo,
    /// By SDO reads: the node could have no sampling TPDO.
    Sdo,
}

/// What a step test measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
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
/// `node`: the drive's node, whose TPDO the test sets up for its samples
/// and whose bus's TPDO values feed them (see the module documentation).
/// `ticket`: the test's right to the axis, which `drive` holds too (its
/// writes go under the axis's gate, none after a stop); each hold waits on
/// it, so a stop of the axis (halt, quick stop, STOP ALL, a lapsed lease)
/// ends the test at once with `motion_stopped`, and no step is sent after
/// the stop (which has stopped the axis itself).
pub(crate) async fn run(
    drive: &Drive,
    node: &NodeHandle,
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
    let mut plan = None;
    let result = match lifted {
        Ok(()) => {
            let set_up = sampling::set_up(node, drive.object(request.actual())).await;
            let plan = plan.insert(set_up);
            steps(drive, &node.served.values, plan, request, ticket).await
        }
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
    let sampling_restored = match &plan {
        Some(sampling::Plan::Tpdo(tpdo)) => tpdo.restore().await,
        _ => Ok(()),
    };
    let mut result = result?;
    restored?;
    sampling_restored?;
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
    plan: &sampling::Plan,
    request: &StepTestRequest,
    ticket: &AxisTicket,
) -> Result<StepTestResult, GatewayError> {
    let hold = Duration::from_millis(u64::from(request.hold_ms));
    let actual = request.actual();
    let node = drive.node_id();
    let index = drive.object(actual);
    // Every decoded frame from here on: what came during the hold at
    // `from` says whether the sampling TPDO runs.
    let wake = Arc::new(Notify::new());
    let mut frames = values.follow(wake.clone());
    drive.run_move(&request.level(request.from)).await?;
    ticket.hold(hold).await?;
    let mut heard = Vec::new();
    loop {
        match frames.try_recv() {
            Ok(frame) if frame.node == node => heard.extend(
                frame
                    .values
                    .iter()
                    .filter(|value| (value.index, value.sub) == (index, 0))
                    .map(|value| value.pdo),
            ),
            Ok(_) | Err(broadcast::error::TryRecvError::Lagged(_)) => {}
            Err(_) => break,
        }
    }
    let running = Tpdo {
        values,
        node,
        index,
    }
    .running(tokio::time::Instant::now());
    // The TPDO that feeds the samples, how long it may fall silent, and
    // what the answer says of it.
    let (feed, mut note) = match plan {
        sampling::Plan::Tpdo(own) if heard.contains(&own.number) => (
            Some((
                own.number,
                Duration::from_millis(20 * u64::from(own.period_ms)).max(OWN_TPDO_SILENCE),
            )),
            format!(
                "TPDO {} set up for the test: 0x{index:04X} every {} ms, put back after it",
                own.number, own.period_ms
            ),
        ),
        sampling::Plan::Tpdo(own) => (
            None,
            format!(
                "read by SDO: TPDO {} set up for the test sent nothing during the hold at {} \
                 (a node sends PDOs only when operational, CiA 301 §7.3.2.2)",
                own.number, request.from
            ),
        ),
        sampling::Plan::Sdo(why) => match running {
            Some(value) => (
                Some((value.pdo, TPDO_FRESH)),
                format!(
                    "TPDO {} already carried 0x{index:04X}, at its own rate (no TPDO of the \
                     test's own: {why})",
                    value.pdo
                ),
            ),
            None => (None, format!("read by SDO: {why}")),
        },
    };
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
    let mut source = SampleSource::Sdo;
    if let Some((pdo, silence)) = feed {
        source = SampleSource::Tpdo;
        let feed = Feed {
            node,
            index,
            pdo,
            silence,
        };
        if !feed
            .record(&mut frames, start, hold, &mut samples, sample, ticket)
            .await
        {
            source = SampleSource::TpdoThenSdo;
            note.push_str("; it fell silent during the hold, the rest read by SDO");
        }
    }
    drop(frames);
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
    result.sampling = match source {
        SampleSource::Sdo => Sampling::Sdo,
        SampleSource::Tpdo | SampleSource::TpdoThenSdo => Sampling::Tpdo,
    };
    result.sampling_note = note;
    result.source = source;
    Ok(result)
}

/// How long the test's own TPDO may fall silent at least before the rest
/// of the hold is read by SDO (else 20 of its periods).
const OWN_TPDO_SILENCE: Duration = Duration::from_millis(50);

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
}

/// The frames of one TPDO that carry the loop's actual value.
struct Feed {
    node: crate::canopen::NodeId,
    index: u16,
    pdo: u16,
    /// How long it may fall silent.
    silence: Duration,
}

impl Feed {
    /// One sample per frame of the TPDO that carries the value, from
    /// `start` until the first frame at or after the hold's end (true: as
    /// the SDO path ends with its first read at or after it), or until the
    /// TPDO has been silent for its `silence` (false: the rest is for SDO).
    async fn record(
        &self,
        frames: &mut broadcast::Receiver<TpdoFrame>,
        start: tokio::time::Instant,
        hold: Duration,
        samples: &mut Vec<[f64; 3]>,
        sample: impl Fn(Duration, i64) -> [f64; 3],
        ticket: &AxisTicket,
    ) -> bool {
        let end = start + hold;
        let mut last = start;
        loop {
            if ticket.stopped() {
                return false;
            }
            let frame = match tokio::time::timeout_at(last + self.silence, frames.recv()).await {
                Ok(Ok(frame)) => frame,
                // Frames lost to a slow turn: the samples have a gap.
                Ok(Err(RecvError::Lagged(_))) => continue,
                Ok(Err(RecvError::Closed)) | Err(_) => return false,
            };
            if frame.node != self.node {
                continue;
            }
            let carried = frame
                .values
                .iter()
                .find(|value| (value.index, value.sub, value.pdo) == (self.index, 0, self.pdo));
            // Not one from before the step (the newest of those sent while
            // the step was being written counts).
            let Some(value) = carried.filter(|value| value.at >= start) else {
                continue;
            };
            last = value.at;
            samples.push(sample(value.at - start, value.as_i64(true)));
            if value.at >= end || samples.len() >= MAX_SAMPLES {
                return true;
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
    let sample_rate_hz = match (samples.first(), samples.last()) {
        (Some(first), Some(last)) if last[0] > first[0] => {
            (samples.len() - 1) as f64 * 1000.0 / (last[0] - first[0])
        }
        _ => 0.0,
    };
    StepTestResult {
        sampling: Sampling::Sdo,
        sample_rate_hz,
        sampling_note: String::new(),
        source: SampleSource::Sdo,
        rise_time_ms,
        overshoot_pct,
        settling_time_ms,
        steady_state_error,
        samples,
        gains: None,
    }
}
