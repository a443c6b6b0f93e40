//! The PDS walked: the state walk, fault reset, halt, quick stop, and the
//! stop after a failed move.

use crate::profiles::cia402::objects as obj;
use crate::profiles::cia402::{Command, PlanError, State, Statusword, expected_state, plan};

use super::*;

/// Whether a walk's step from `from` towards `expected` sees `seen`, a
/// state a stop leaves (quick stop active, switch on disabled) that is
/// neither: another command stopped the drive meanwhile. Without this the
/// walk would wait for its step until the timeout and answer 504, though
/// nothing is late (found by the soak test: STOP ALL while an axis was
/// being enabled).
fn stopped_meanwhile(from: State, expected: State, seen: Option<State>) -> bool {
    matches!(
        seen,
        Some(state @ (State::QuickStopActive | State::SwitchOnDisabled))
            if state != from && state != expected
    )
}

impl Drive {
    /// Walks the PDS to `target`, one transition at a time, each checked
    /// in the statusword. A drive in fault is not reset here (that is
    /// [`Drive::fault_reset`]'s, asked for on purpose).
    pub async fn set_state(&self, target: State) -> Result<AxisStatus, DriveError> {
        let _procedure = self.channel.procedure().await;
        let mut statusword = self.statusword().await?;
        // A drive initialising leaves that state by itself.
        if statusword.state() == Some(State::NotReadyToSwitchOn) {
            statusword = self
                .wait("initialisation", STEP_TIMEOUT, false, |sw| {
                    sw.state() != Some(State::NotReadyToSwitchOn)
                })
                .await?;
        }
        let Some(current) = statusword.state() else {
            return Err(DriveError::Timeout {
                axis: self.axis,
                what: format!("statusword 0x{:04X} names a state", statusword.raw()),
                state: None,
            });
        };
        if matches!(current, State::Fault | State::FaultReactionActive) {
            return Err(self.fault(statusword, ": reset the fault first (POST .../fault-reset)"));
        }
        // Transition 11 starts only from operation enabled: climbing there
        // first would power a motor only to stop it.
        if target == State::QuickStopActive
            && !matches!(current, State::OperationEnabled | State::QuickStopActive)
        {
            return Err(DriveError::NotEnabled {
                axis: self.axis,
                state: Some(current),
            });
        }
        let commands = plan(current, target).map_err(|error| match error {
            PlanError::TargetNotCommandable(_) | PlanError::Transient(_) => {
                DriveError::Invalid(error.to_string())
            }
        })?;
        let mut from = current;
        for command in commands {
            self.controlword(command.bits()).await?;
            let expected = expected_state(command);
            let step_done = |state: Option<State>| {
                state == Some(expected)
                    // Quick stop options 1–4 end in switch on disabled.
                    || (command == Command::QuickStop && state == Some(State::SwitchOnDisabled))
            };
            let reached = self
                .wait(
                    &format!("{command} (expecting {expected})"),
                    STEP_TIMEOUT,
                    false,
                    // Or someone else stopped the drive during the walk
                    // (STOP ALL, a quick stop, a lapsed lease): no command
                    // of this walk leads on from there.
                    |sw| step_done(sw.state()) || stopped_meanwhile(from, expected, sw.state()),
                )
                .await?;
            let state = reached.state();
            if !step_done(state) && stopped_meanwhile(from, expected, state) {
                return Err(DriveError::Interrupted {
                    axis: self.axis,
                    what: format!("{command} (expecting {expected})"),
                    state,
                });
            }
            from = expected;
        }
        self.status().await
    }

    /// Fault reset (transition 15): a 0→1 edge of controlword bit 7, then
    /// switch on disabled must show. A drive whose fault is still present
    /// stays in fault: 409.
    pub async fn fault_reset(&self) -> Result<AxisStatus, DriveError> {
        let _procedure = self.channel.procedure().await;
        let statusword = self.statusword().await?;
        if statusword.state() == Some(State::Fault) {
            self.controlword(Command::DisableVoltage.bits()).await?;
            self.controlword(Command::FaultReset.bits()).await?;
            let deadline = tokio::time::Instant::now() + ACK_TIMEOUT;
            loop {
                let statusword = self.statusword().await?;
                if statusword.state() != Some(State::Fault) {
                    break;
                }
                if tokio::time::Instant::now() >= deadline {
                    return Err(self.fault(statusword, ": the fault is still present"));
                }
                tokio::time::sleep(POLL).await;
            }
        } else if statusword.state() == Some(State::FaultReactionActive) {
            return Err(self.fault(statusword, ": the fault reaction is still running"));
        }
        self.status().await
    }

    /// The controlword the drive runs with now: read back where it can be
    /// read (UMC), else the one its state implies (the JMC's is write only).
    pub(super) async fn current_controlword(
        &self,
        statusword: Statusword,
    ) -> Result<u16, DriveError> {
        let readable = self.eds.as_ref().is_none_or(|entry| {
            entry
                .eds
                .dictionary
                .sub(self.index(obj::CONTROLWORD), 0)
                .is_some_and(|sub| sub.access.is_readable())
        });
        if readable && let Some(value) = self.read_optional(obj::CONTROLWORD, 0, false).await? {
            return Ok(value as u16);
        }
        Ok(match statusword.state() {
            Some(State::OperationEnabled) => Command::EnableOperation.bits(),
            Some(State::SwitchedOn) => Command::SwitchOn.bits(),
            Some(State::ReadyToSwitchOn) => Command::Shutdown.bits(),
            _ => Command::DisableVoltage.bits(),
        })
    }

    /// Sets or clears the halt bit (controlword bit 8), the rest of the
    /// controlword kept.
    pub async fn halt(&self, halt: bool) -> Result<AxisStatus, DriveError> {
        let _procedure = self.channel.procedure().await;
        let statusword = self.statusword().await?;
        let word = self.current_controlword(statusword).await? & !0x0080;
        let word = if halt {
            word | CW_HALT
        } else {
            word & !CW_HALT
        };
        self.controlword(word).await?;
        self.status().await
    }

    /// Quick stop of an axis in operation enabled; `Ok(None)` for an axis
    /// that was not enabled (nothing to stop), else the state it was in.
    pub async fn quick_stop_if_enabled(&self) -> Result<Option<State>, DriveError> {
        let statusword = self.statusword().await?;
        if statusword.state() != Some(State::OperationEnabled) {
            return Ok(None);
        }
        self.controlword(Command::QuickStop.bits()).await?;
        Ok(Some(State::OperationEnabled))
    }

    /// What a failed move leaves: an axis still in operation enabled is
    /// halted, and quick-stopped if the halt cannot be written; an axis in
    /// any other state is not driving (a quick stop or fault got there
    /// first) and is left alone, as a halt's enable-operation bits could
    /// take it out of quick stop active again (transition 16). Best effort:
    /// the move's own error is what the caller reports.
    pub(crate) async fn stop_after_failure(&self) {
        let state = match self.statusword().await {
            Ok(statusword) => statusword.state(),
            // Unknown: assume the worst.
            Err(_) => Some(State::OperationEnabled),
        };
        if state != Some(State::OperationEnabled) {
            return;
        }
        let halt = Command::EnableOperation.bits() | CW_HALT;
        if let Err(error) = self.controlword(halt).await {
            tracing::warn!("axis {}: halt after a failed move: {error}", self.axis);
            if let Err(error) = self.controlword(Command::QuickStop.bits()).await {
                tracing::error!(
                    "axis {}: quick stop after a failed move: {error}",
                    self.axis
                );
            }
        }
    }
}
