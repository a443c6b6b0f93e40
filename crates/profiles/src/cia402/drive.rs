//! The PDS as a drive runs it (UMC manual §1.2.1, Figure 2.1 and Table 2.2,
//! transitions 0–16): controlwords and the drive's own events in, the state
//! and what the drive must do to its motor out.
//!
//! The machine keeps no clock and moves no motor: when it asks for a ramp,
//! the drive runs it and says when it ended ([`Event::QuickStopFinished`],
//! [`Event::FaultReactionFinished`]).

use super::command::{Command, Controlword};
use super::options::{
    AbortConnectionOption, DisableOption, FaultReactionOption, HaltOption, QuickStopOption,
    StopKind,
};
use super::state::{State, StatusFlags, Statusword};

/// The option codes the machine honours (Table 2.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Options {
    /// 0x605A, transition 11 (and 12).
    pub quick_stop: QuickStopOption,
    /// 0x605B, transition 8.
    pub shutdown: DisableOption,
    /// 0x605C, transition 5.
    pub disable_operation: DisableOption,
    /// 0x605D, controlword bit 8.
    pub halt: HaltOption,
    /// 0x605E, transition 13.
    pub fault_reaction: FaultReactionOption,
    /// 0x6007, [`Event::ConnectionLost`].
    pub abort_connection: AbortConnectionOption,
}

/// Something that happened inside the drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Event {
    /// Self-test and initialisation are done: transition 1.
    Initialised,
    /// A fault appeared: transition 13. It stays present, and blocks fault
    /// reset, until [`Event::FaultCleared`].
    FaultOccurred,
    /// The fault condition is gone; a fault reset may now succeed.
    FaultCleared,
    /// The fault reaction's ramp ended: transition 14.
    FaultReactionFinished,
    /// The quick stop's ramp ended: transition 12 for quick stop options
    /// 1–4, nothing for 5–8 (the drive holds in quick stop active).
    QuickStopFinished,
    /// The high-level (motor) voltage came or went: statusword bit 4.
    MotorVoltage(bool),
    /// The master is gone (bus-off, heartbeat lost, NMT change): 0x6007
    /// decides.
    ConnectionLost,
}

/// What the drive must do to its motor after a step of the machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Reaction {
    /// Enable the drive function, internal set-points cleared
    /// (transitions 4, 3 + 4, 16).
    EnableOutput,
    /// Disable the drive function now; the motor is free to rotate.
    DisableOutput,
    /// Bring the motor to rest; then disable the drive function if
    /// `then_disable`, else hold it (quick stop options 5–8).
    RampStop { kind: StopKind, then_disable: bool },
    /// Controlword bit 8 went high in operation enabled: stop and hold,
    /// the state stays operation enabled (0x605D).
    Halt { kind: StopKind },
    /// Bit 8 went low again: carry on with the mode's motion.
    Resume,
}

/// The drive side of the PDS.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DriveStateMachine {
    state: State,
    options: Options,
    /// The last controlword written, for the edge of fault reset (bit 7).
    previous: Controlword,
    /// A fault condition exists now: fault reset cannot leave fault.
    fault_present: bool,
    /// Bit 8 was high while in operation enabled.
    halted: bool,
    flags: StatusFlags,
}

impl DriveStateMachine {
    /// A drive just powered on: transition 0 done, in not ready to switch
    /// on until [`Event::Initialised`]. Remote (statusword bit 9) is set: the
    /// drive takes its commands from the controlword.
    pub fn new(options: Options) -> Self {
        DriveStateMachine {
            state: State::NotReadyToSwitchOn,
            options,
            previous: Controlword(0),
            fault_present: false,
            halted: false,
            flags: StatusFlags {
                remote: true,
                ..StatusFlags::default()
            },
        }
    }

    pub fn state(&self) -> State {
        self.state
    }

    pub fn options(&self) -> Options {
        self.options
    }

    /// Option codes may be written at any time; they take effect at the
    /// next transition they govern.
    pub fn options_mut(&mut self) -> &mut Options {
        &mut self.options
    }

    /// The last controlword written.
    pub fn last_controlword(&self) -> Controlword {
        self.previous
    }

    pub fn fault_present(&self) -> bool {
        self.fault_present
    }

    /// The statusword bits beside the state, for the drive to set (target
    /// reached, the mode's bits, warning, ...).
    pub fn flags_mut(&mut self) -> &mut StatusFlags {
        &mut self.flags
    }

    /// What 0x6041 reads now.
    pub fn statusword(&self) -> Statusword {
        Statusword::encode(self.state, self.flags)
    }

    /// A controlword written to 0x6040. Commands a state does not accept
    /// are ignored, as Figure 2.1 has no arrow for them.
    pub fn controlword(&mut self, controlword: Controlword) -> Vec<Reaction> {
        let command = controlword.command_in(self.previous, self.state);
        self.previous = controlword;
        let mut reactions = command.map(|c| self.command(c)).unwrap_or_default();
        if self.state != State::OperationEnabled {
            // Halt only means something while operating; leaving the state
            // drops it, so re-entering with bit 8 high halts afresh.
            self.halted = false;
        } else if controlword.halt() != self.halted {
            self.halted = controlword.halt();
            reactions.push(if self.halted {
                Reaction::Halt {
                    kind: self.options.halt.stop(),
                }
            } else {
                Reaction::Resume
            });
        }
        reactions
    }

    /// Something the drive noticed.
    pub fn event(&mut self, event: Event) -> Vec<Reaction> {
        match event {
            Event::Initialised => {
                if self.state == State::NotReadyToSwitchOn {
                    self.state = State::SwitchOnDisabled; // 1
                }
                Vec::new()
            }
            Event::FaultOccurred => {
                self.fault_present = true;
                self.fault_signal()
            }
            Event::FaultCleared => {
                self.fault_present = false;
                Vec::new()
            }
            Event::FaultReactionFinished => {
                if self.state == State::FaultReactionActive {
                    self.state = State::Fault; // 14
                }
                Vec::new()
            }
            Event::QuickStopFinished => {
                if self.state == State::QuickStopActive && !self.options.quick_stop.stays() {
                    // 12: the ramp asked for the drive function to go off
                    // at rest, so nothing more to do.
                    self.state = State::SwitchOnDisabled;
                }
                Vec::new()
            }
            Event::MotorVoltage(present) => {
                self.flags.voltage_enabled = present;
                Vec::new()
            }
            // CiA 402-2 0x6007: the option is what an enabled drive does;
            // a drive whose function is off has no connection to abort.
            Event::ConnectionLost if !self.state.drive_function_enabled() => Vec::new(),
            Event::ConnectionLost => match self.options.abort_connection {
                AbortConnectionOption::NoAction => Vec::new(),
                // A lost master is no lasting condition: the fault can be
                // reset once the master is back.
                AbortConnectionOption::FaultSignal | AbortConnectionOption::Unknown(_) => {
                    self.fault_signal()
                }
                AbortConnectionOption::DisableVoltage => self.command(Command::DisableVoltage),
                AbortConnectionOption::QuickStop => self.command(Command::QuickStop),
            },
        }
    }

    /// Transition 13, then 14 at once when there is no ramp to wait for.
    fn fault_signal(&mut self) -> Vec<Reaction> {
        if matches!(self.state, State::FaultReactionActive | State::Fault) {
            return Vec::new();
        }
        let enabled = self.state.drive_function_enabled();
        match self.options.fault_reaction.stop() {
            Some(kind) if enabled => {
                self.state = State::FaultReactionActive;
                vec![Reaction::RampStop {
                    kind,
                    then_disable: true,
                }]
            }
            _ => {
                self.state = State::Fault;
                if enabled {
                    vec![Reaction::DisableOutput]
                } else {
                    Vec::new()
                }
            }
        }
    }

    /// The transitions a command causes (Table 2.2).
    fn command(&mut self, command: Command) -> Vec<Reaction> {
        use Command as C;
        use State as S;
        let (next, reactions) = match (self.state, command) {
            (S::SwitchOnDisabled, C::Shutdown) => (S::ReadyToSwitchOn, Vec::new()), // 2
            (S::ReadyToSwitchOn, C::SwitchOn) => (S::SwitchedOn, Vec::new()),       // 3
            (S::ReadyToSwitchOn, C::SwitchOnEnableOperation) => {
                (S::OperationEnabled, vec![Reaction::EnableOutput]) // 3 + 4
            }
            (S::SwitchedOn, C::EnableOperation) => {
                (S::OperationEnabled, vec![Reaction::EnableOutput]) // 4
            }
            (S::OperationEnabled, C::DisableOperation) => {
                (S::SwitchedOn, disable(self.options.disable_operation)) // 5
            }
            (S::SwitchedOn, C::Shutdown) => (S::ReadyToSwitchOn, Vec::new()), // 6
            (S::ReadyToSwitchOn, C::QuickStop | C::DisableVoltage) => {
                (S::SwitchOnDisabled, Vec::new()) // 7
            }
            (S::OperationEnabled, C::Shutdown) => {
                (S::ReadyToSwitchOn, disable(self.options.shutdown)) // 8
            }
            (S::OperationEnabled, C::DisableVoltage) => {
                (S::SwitchOnDisabled, vec![Reaction::DisableOutput]) // 9
            }
            (S::SwitchedOn, C::DisableVoltage | C::QuickStop) => {
                (S::SwitchOnDisabled, Vec::new()) // 10
            }
            (S::OperationEnabled, C::QuickStop) => match self.options.quick_stop.stop() {
                Some(kind) => (
                    S::QuickStopActive, // 11
                    vec![Reaction::RampStop {
                        kind,
                        then_disable: !self.options.quick_stop.stays(),
                    }],
                ),
                // 11 and 12 at once: nothing to wait for.
                None => (S::SwitchOnDisabled, vec![Reaction::DisableOutput]),
            },
            (S::QuickStopActive, C::DisableVoltage) => {
                (S::SwitchOnDisabled, vec![Reaction::DisableOutput]) // 12
            }
            (S::Fault, C::FaultReset) if !self.fault_present => {
                self.flags.warning = false;
                (S::SwitchOnDisabled, Vec::new()) // 15
            }
            (S::QuickStopActive, C::EnableOperation) if self.options.quick_stop.stays() => {
                (S::OperationEnabled, vec![Reaction::EnableOutput]) // 16
            }
            (state, _) => (state, Vec::new()),
        };
        self.state = next;
        reactions
    }
}

/// Transitions 5 and 8 as 0x605C and 0x605B have them.
fn disable(option: DisableOption) -> Vec<Reaction> {
    vec![match option.stop() {
        Some(kind) => Reaction::RampStop {
            kind,
            then_disable: true,
        },
        None => Reaction::DisableOutput,
    }]
}
