//! A move in each mode: the CiA 402 mode it uses on the product, the
//! objects it writes, the controlwords that start it, the interpolated
//! points fed as the buffer drains.

use std::time::Duration;

use tokio::sync::OwnedMutexGuard;

use crate::canopen::od::DataType;
use crate::profiles::cia402::objects as obj;
use crate::profiles::cia402::{Command, Mode, State};
use crate::profiles::{jmc, umc};

use super::*;

impl Drive {
    /// The CiA 402 mode number a move uses on this drive, or 422.
    pub(super) async fn mode_for(&self, mode: MoveMode) -> Result<Mode, DriveError> {
        let refuse = |supported: Vec<MoveMode>| DriveError::ModeNotSupported {
            axis: self.axis,
            mode,
            supported,
        };
        if !self.kind.may_support(mode) {
            return Err(refuse(self.move_modes(&self.supported().await?)));
        }
        let supported = self.supported().await?;
        mode.modes()
            .iter()
            .copied()
            .find(|m| supported.contains(m))
            .ok_or_else(|| refuse(self.move_modes(&supported)))
    }

    /// Checks a move before the bus: values against their objects. (A
    /// generic drive's velocity mode is known only once 0x6502 is read:
    /// [`Drive::run_move`] checks VL's 16-bit target again before writing.)
    pub fn validate(&self, request: &MoveRequest) -> Result<(), DriveError> {
        let mode = match (request, self.kind) {
            (MoveRequest::Velocity { .. }, DriveKind::Umc) => Mode::Velocity,
            (MoveRequest::Velocity { .. }, _) => Mode::ProfileVelocity,
            _ => Mode::ProfilePosition,
        };
        self.writes(request, mode).map(|_| ())
    }

    /// The parameter writes of a move (before its controlwords), for the
    /// CiA 402 `mode` it runs in.
    pub(super) fn writes(
        &self,
        request: &MoveRequest,
        mode: Mode,
    ) -> Result<Vec<Write>, DriveError> {
        use DataType as T;
        let mut writes = Vec::new();
        let mut put = |index: u16, sub: u8, default: DataType, value: i64, what: &str| {
            writes.push(self.encode(index, sub, default, value, what)?);
            Ok::<(), DriveError>(())
        };
        match request {
            MoveRequest::ProfilePosition {
                target,
                velocity,
                acceleration,
                deceleration,
                ..
            } => {
                put(
                    obj::TARGET_POSITION,
                    0,
                    T::Integer32,
                    (*target).into(),
                    "target",
                )?;
                if let Some(v) = velocity {
                    put(obj::PROFILE_VELOCITY, 0, T::Unsigned32, *v, "velocity")?;
                }
                if let Some(a) = acceleration {
                    put(
                        obj::PROFILE_ACCELERATION,
                        0,
                        T::Unsigned32,
                        *a,
                        "acceleration",
                    )?;
                }
                if let Some(d) = deceleration {
                    put(
                        obj::PROFILE_DECELERATION,
                        0,
                        T::Unsigned32,
                        *d,
                        "deceleration",
                    )?;
                }
            }
            MoveRequest::Velocity {
                velocity,
                acceleration,
                deceleration,
            } => {
                let velocity = i64::from(*velocity);
                if mode == Mode::Velocity {
                    put(obj::VL_TARGET, 0, T::Integer16, velocity, "velocity")?;
                    if let Some(a) = acceleration {
                        put(obj::VL_ACCELERATION, 1, T::Unsigned32, *a, "acceleration")?;
                        put(obj::VL_ACCELERATION, 2, T::Unsigned16, 1, "delta time")?;
                    }
                    if let Some(d) = deceleration {
                        put(obj::VL_DECELERATION, 1, T::Unsigned32, *d, "deceleration")?;
                        put(obj::VL_DECELERATION, 2, T::Unsigned16, 1, "delta time")?;
                    }
                } else {
                    let target = match self.kind {
                        DriveKind::Jmc => jmc::VELOCITY_MOVE_TARGET,
                        _ => obj::TARGET_VELOCITY,
                    };
                    put(target, 0, T::Integer32, velocity, "velocity")?;
                    if let Some(a) = acceleration {
                        put(
                            obj::PROFILE_ACCELERATION,
                            0,
                            T::Unsigned32,
                            *a,
                            "acceleration",
                        )?;
                    }
                    if let Some(d) = deceleration {
                        put(
                            obj::PROFILE_DECELERATION,
                            0,
                            T::Unsigned32,
                            *d,
                            "deceleration",
                        )?;
                    }
                }
            }
            MoveRequest::Torque { torque, slope } => {
                put(obj::TQ_TARGET, 0, T::Integer16, (*torque).into(), "torque")?;
                if let Some(s) = slope {
                    put(obj::TQ_SLOPE, 0, T::Unsigned32, *s, "slope")?;
                }
            }
            MoveRequest::DutyCycle { duty, slope } => {
                if let Some(s) = slope {
                    put(umc::axis::DTY_SLOPE, 0, T::Unsigned16, *s, "slope")?;
                }
                put(
                    umc::axis::DTY_TARGET,
                    0,
                    T::Integer16,
                    (*duty).into(),
                    "duty",
                )?;
            }
            MoveRequest::ContinuousPosition { target, .. } => {
                // Validated only: 0x41F0 is written after the controlword.
                self.encode(
                    umc::axis::CP_TARGET,
                    0,
                    T::Integer32,
                    (*target).into(),
                    "target",
                )?;
            }
            MoveRequest::InterpolatedPosition { period_ms, points } => {
                if *period_ms == 0 {
                    return Err(DriveError::Invalid("period_ms must be 1 to 255".into()));
                }
                if points.is_empty() || points.len() > MAX_IP_POINTS {
                    return Err(DriveError::Invalid(format!(
                        "points: 1 to {MAX_IP_POINTS} positions"
                    )));
                }
                let total_ms = points.len() as u64 * u64::from(*period_ms);
                if total_ms > MAX_IP_DURATION_MS {
                    return Err(DriveError::Invalid(format!(
                        "{} points every {period_ms} ms take {total_ms} ms; at most {MAX_IP_DURATION_MS} ms in one request",
                        points.len()
                    )));
                }
                put(
                    obj::IP_TIME_PERIOD,
                    1,
                    T::Unsigned8,
                    (*period_ms).into(),
                    "period",
                )?;
                put(obj::IP_TIME_PERIOD, 2, T::Integer8, -3, "period index")?;
                put(
                    obj::IP_DATA_CONFIGURATION,
                    6,
                    T::Unsigned8,
                    0,
                    "buffer clear",
                )?;
            }
            MoveRequest::Homing {
                method,
                speeds,
                acceleration,
                offset,
            } => {
                if self.kind == DriveKind::Jmc && jmc::HomingMethod::from_raw(*method).is_none() {
                    return Err(DriveError::OutOfRange(format!(
                        "homing method {method}: the JMC has methods 0 to 12"
                    )));
                }
                put(
                    obj::HOMING_METHOD,
                    0,
                    T::Integer8,
                    (*method).into(),
                    "method",
                )?;
                if let Some([fast, slow]) = speeds {
                    put(obj::HOMING_SPEEDS, 1, T::Unsigned32, *fast, "search speed")?;
                    put(obj::HOMING_SPEEDS, 2, T::Unsigned32, *slow, "slow speed")?;
                }
                if let Some(a) = acceleration {
                    put(
                        obj::HOMING_ACCELERATION,
                        0,
                        T::Unsigned32,
                        *a,
                        "acceleration",
                    )?;
                }
                if let Some(o) = offset {
                    put(obj::HOME_OFFSET, 0, T::Integer32, (*o).into(), "offset")?;
                }
            }
        }
        Ok(writes)
    }

    /// Runs a move: checks the mode and the state, switches the mode
    /// (waiting for 0x6061 to show it), writes the parameters and gives the
    /// controlwords the mode needs. If anything fails after the first
    /// write, the axis is halted (or quick-stopped) before the error is
    /// returned.
    pub async fn run_move(&self, request: &MoveRequest) -> Result<AxisStatus, DriveError> {
        let mode = self.mode_for(request.mode()).await?;
        let writes = self.writes(request, mode)?;
        let procedure = self.channel.procedure().await;
        let statusword = self.statusword().await?;
        match statusword.state() {
            Some(State::OperationEnabled) => {}
            Some(State::Fault | State::FaultReactionActive) => {
                return Err(self.fault(statusword, ": reset the fault first"));
            }
            state => {
                return Err(DriveError::NotEnabled {
                    axis: self.axis,
                    state,
                });
            }
        }
        match self.run_steps(request, mode, &writes, procedure).await {
            Ok(()) => self.status().await,
            Err(error) => {
                self.stop_after_failure().await;
                Err(error)
            }
        }
    }

    pub(super) async fn run_steps(
        &self,
        request: &MoveRequest,
        mode: Mode,
        writes: &[Write],
        procedure: OwnedMutexGuard<()>,
    ) -> Result<(), DriveError> {
        let enable = Command::EnableOperation.bits();
        self.set_mode(mode).await?;
        for write in writes {
            self.write(write).await?;
        }
        match request {
            MoveRequest::ProfilePosition {
                relative,
                immediate,
                ..
            } => {
                let word = enable
                    | if *immediate { CW_BIT5 } else { 0 }
                    | if *relative { CW_BIT6 } else { 0 };
                // Bit 4 low first, so that the next write is an edge.
                self.controlword(word).await?;
                self.controlword(word | CW_BIT4).await?;
                // Or someone else stopped the drive meanwhile (STOP ALL, a
                // quick stop, a lapsed lease): no set-point is acknowledged
                // out of operation enabled, so waiting longer is no use.
                let seen = self
                    .wait("set-point acknowledge", ACK_TIMEOUT, false, |sw| {
                        sw.raw() & SW_BIT12 != 0 || sw.state() != Some(State::OperationEnabled)
                    })
                    .await?;
                if seen.raw() & SW_BIT12 == 0 {
                    return Err(DriveError::Interrupted {
                        axis: self.axis,
                        what: "set-point acknowledge".to_string(),
                        state: seen.state(),
                    });
                }
                self.controlword(word).await?;
            }
            MoveRequest::Velocity { .. } => {
                let word = if mode == Mode::Velocity {
                    // Ramp enabled, unlocked, on the reference (Table 2.28).
                    enable | CW_BIT4 | CW_BIT5 | CW_BIT6
                } else {
                    enable
                };
                self.controlword(word).await?;
            }
            MoveRequest::Torque { .. } => self.controlword(enable).await?,
            MoveRequest::DutyCycle { slope, .. } => {
                let word = enable | if slope.is_some() { CW_BIT4 } else { 0 };
                self.controlword(word).await?;
            }
            MoveRequest::ContinuousPosition { target, relative } => {
                self.controlword(enable | if *relative { CW_BIT6 } else { 0 })
                    .await?;
                let write = self.encode(
                    umc::axis::CP_TARGET,
                    0,
                    DataType::Integer32,
                    (*target).into(),
                    "target",
                )?;
                self.write(&write).await?;
            }
            MoveRequest::InterpolatedPosition { period_ms, points } => {
                self.interpolate(*period_ms, points, procedure).await?;
            }
            MoveRequest::Homing { .. } => {
                self.controlword(enable).await?;
                self.controlword(enable | CW_BIT4).await?;
            }
        }
        Ok(())
    }

    /// Writes 0x6060 unless the drive runs `mode` already, and waits for
    /// 0x6061 to show it.
    pub(super) async fn set_mode(&self, mode: Mode) -> Result<(), DriveError> {
        let display = || async {
            self.read_int(obj::MODES_OF_OPERATION_DISPLAY, 0, true)
                .await
                .map(|raw| raw as i8)
        };
        if display().await? == mode.raw() {
            return Ok(());
        }
        self.download(
            self.index(obj::MODES_OF_OPERATION),
            0,
            &mode.raw().to_le_bytes(),
        )
        .await?;
        let deadline = tokio::time::Instant::now() + MODE_TIMEOUT;
        while display().await? != mode.raw() {
            // A drive changing mode while it moves stops first (CiA 402
            // §5.1.5); a fault or a quick stop (STOP ALL) during that stop
            // leaves the change pending for good, and the move ends with
            // what happened, not with a timeout seconds later.
            let statusword = self.statusword().await?;
            match statusword.state() {
                Some(State::OperationEnabled) => {}
                Some(State::Fault | State::FaultReactionActive) => {
                    return Err(self.fault(statusword, " during the change of mode"));
                }
                state => {
                    return Err(DriveError::NotEnabled {
                        axis: self.axis,
                        state,
                    });
                }
            }
            if tokio::time::Instant::now() >= deadline {
                return Err(DriveError::Timeout {
                    axis: self.axis,
                    what: format!("the change to mode {mode}"),
                    state: self.statusword().await?.state(),
                });
            }
            tokio::time::sleep(POLL).await;
        }
        Ok(())
    }

    /// Interpolated position: fills the buffer, enables interpolation
    /// (bit 4), and tops the buffer up as the drive drains it, one period
    /// at a time, until every point is in.
    pub(super) async fn interpolate(
        &self,
        period_ms: u8,
        points: &[i32],
        procedure: OwnedMutexGuard<()>,
    ) -> Result<(), DriveError> {
        let mut procedure = Some(procedure);
        let enable = Command::EnableOperation.bits();
        self.controlword(enable).await?;
        let capacity = self
            .read_optional(obj::IP_DATA_CONFIGURATION, 1, false)
            .await?
            .filter(|&n| n > 0)
            .unwrap_or(32)
            .min(1024) as usize;
        let mut queued = 0usize;
        let mut enabled = false;
        let period = Duration::from_millis(u64::from(period_ms));
        // Every point drains in a period; a drive that stops draining for
        // longer than the whole buffer's time is stuck.
        let stall = period * (capacity as u32 + 10) + STEP_TIMEOUT;
        let mut last_progress = tokio::time::Instant::now();
        while queued < points.len() {
            let in_buffer = self
                .read_optional(obj::IP_DATA_CONFIGURATION, 2, false)
                .await?
                .unwrap_or(0) as usize;
            let free = capacity.saturating_sub(in_buffer);
            let batch = free.min(points.len() - queued);
            for point in &points[queued..queued + batch] {
                self.download(self.index(obj::IP_DATA_RECORD), 1, &point.to_le_bytes())
                    .await?;
            }
            queued += batch;
            if batch > 0 {
                last_progress = tokio::time::Instant::now();
            }
            if !enabled {
                self.controlword(enable | CW_BIT4).await?;
                enabled = true;
                // The set-up is done; feeding the buffer is single
                // transfers, which must not hold off the node's other axes
                // for the whole move.
                procedure.take();
            }
            if queued < points.len() {
                let statusword = self.statusword().await?;
                if statusword.state() != Some(State::OperationEnabled) {
                    return Err(match statusword.state() {
                        Some(State::Fault | State::FaultReactionActive) => {
                            self.fault(statusword, "")
                        }
                        state => DriveError::NotEnabled {
                            axis: self.axis,
                            state,
                        },
                    });
                }
                if tokio::time::Instant::now() - last_progress > stall {
                    return Err(DriveError::Timeout {
                        axis: self.axis,
                        what: "the interpolation buffer to drain".into(),
                        state: statusword.state(),
                    });
                }
                tokio::time::sleep(period).await;
            }
        }
        Ok(())
    }
}
