//! The master's walk through the PDS (UMC manual Figure 2.1): the commands
//! that take a drive from the state its statusword shows to the state asked
//! for, one transition at a time so each can be checked.

use super::command::Command;
use super::state::State;

/// Why no walk leads from one state to another.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, thiserror::Error)]
pub enum PlanError {
    /// Not ready to switch on, fault reaction active and fault are entered
    /// by the drive itself, never commanded.
    #[error("{0} cannot be commanded; only the drive enters it")]
    TargetNotCommandable(State),
    /// The drive is in a state that ends by itself (initialising, or running
    /// its fault reaction): wait, read the statusword again, and re-plan.
    #[error("the drive is in {0}, which it leaves by itself")]
    Transient(State),
}

/// The commands that walk a drive from `current` to `target`, each one
/// transition checkable with [`expected_state`].
///
/// The walk never uses the shortcut "switch on + enable operation" (3 + 4):
/// it goes through switched on, so every step shows in the statusword.
/// Down the ladder it takes the single transition (9, 8, 5, 12). From
/// fault it resets first; from quick stop active it enables operation
/// again by transition 16 (a drive only rests in quick stop active with
/// quick stop option 5–8, the ones that allow it) and otherwise goes
/// through switch on disabled.
pub fn plan(current: State, target: State) -> Result<Vec<Command>, PlanError> {
    use Command as C;
    use State as S;
    let rung = |state: State| match state {
        S::SwitchOnDisabled => Some(0),
        S::ReadyToSwitchOn => Some(1),
        S::SwitchedOn => Some(2),
        S::OperationEnabled => Some(3),
        _ => None,
    };
    // Each command climbs one rung from the rung before it.
    const UP: [Command; 3] = [C::Shutdown, C::SwitchOn, C::EnableOperation];
    let climb = |from: usize, to: usize| UP[from..to].to_vec();

    match target {
        S::NotReadyToSwitchOn | S::FaultReactionActive | S::Fault => {
            return Err(PlanError::TargetNotCommandable(target));
        }
        _ => {}
    }
    let mut commands = Vec::new();
    let from = match current {
        S::NotReadyToSwitchOn | S::FaultReactionActive => {
            return Err(PlanError::Transient(current));
        }
        S::Fault => {
            commands.push(C::FaultReset);
            0
        }
        S::QuickStopActive => match target {
            S::QuickStopActive => return Ok(commands),
            S::OperationEnabled => return Ok(vec![C::EnableOperation]), // 16
            _ => {
                commands.push(C::DisableVoltage); // 12
                0
            }
        },
        other => rung(other).expect("every other state is on the ladder"),
    };
    match target {
        S::QuickStopActive => {
            commands.extend(climb(from, 3));
            commands.push(C::QuickStop); // 11
        }
        _ => {
            let to = rung(target).expect("every other target is on the ladder");
            if to >= from {
                commands.extend(climb(from, to));
            } else {
                commands.push(match to {
                    0 => C::DisableVoltage,   // 7, 9, 10
                    1 => C::Shutdown,         // 6, 8
                    _ => C::DisableOperation, // 5
                });
            }
        }
    }
    Ok(commands)
}

/// The state the statusword should show once `after` has been obeyed, in a
/// walk [`plan`] made. Quick stop is only planned from operation enabled,
/// so it expects quick stop active; a drive whose quick stop option is 1–4
/// goes on to switch on disabled when the ramp ends, which a master should
/// accept too.
pub fn expected_state(after: Command) -> State {
    match after {
        Command::Shutdown => State::ReadyToSwitchOn,
        Command::SwitchOn | Command::DisableOperation => State::SwitchedOn,
        Command::SwitchOnEnableOperation | Command::EnableOperation => State::OperationEnabled,
        Command::DisableVoltage | Command::FaultReset => State::SwitchOnDisabled,
        Command::QuickStop => State::QuickStopActive,
    }
}
