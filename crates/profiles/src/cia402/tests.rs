//! The codings byte for byte, every transition of Table 2.2 through the
//! drive's machine, every walk [`plan()`] makes obeyed by that machine, and
//! the mode numbers.

use proptest::prelude::*;

use super::*;

const ALL_STOPS: [StopKind; 4] = [
    StopKind::SlowDownRamp,
    StopKind::QuickStopRamp,
    StopKind::CurrentLimit,
    StopKind::VoltageLimit,
];

// ---- statusword ----

#[test]
fn every_state_encodes_to_its_table_2_8_pattern_and_back() {
    let expected: [(State, u16); 8] = [
        (State::NotReadyToSwitchOn, 0x0000),
        (State::SwitchOnDisabled, 0x0040),
        (State::ReadyToSwitchOn, 0x0021),
        (State::SwitchedOn, 0x0023),
        (State::OperationEnabled, 0x0027),
        (State::QuickStopActive, 0x0007),
        (State::FaultReactionActive, 0x000F),
        (State::Fault, 0x0008),
    ];
    for (state, raw) in expected {
        let word = Statusword::encode(state, StatusFlags::default());
        assert_eq!(word.raw(), raw, "{state}");
        assert_eq!(word.state(), Some(state));
    }
}

#[test]
fn states_decode_from_real_statuswords_with_other_bits_set() {
    // Values seen from drives: voltage, remote, target reached set.
    assert_eq!(
        State::from_statusword(0x0250),
        Some(State::SwitchOnDisabled)
    );
    assert_eq!(
        State::from_statusword(0x0660),
        Some(State::SwitchOnDisabled)
    );
    assert_eq!(State::from_statusword(0x0231), Some(State::ReadyToSwitchOn));
    assert_eq!(State::from_statusword(0x0233), Some(State::SwitchedOn));
    assert_eq!(
        State::from_statusword(0x0637),
        Some(State::OperationEnabled)
    );
    assert_eq!(State::from_statusword(0x0617), Some(State::QuickStopActive));
    assert_eq!(
        State::from_statusword(0x021F),
        Some(State::FaultReactionActive)
    );
    assert_eq!(State::from_statusword(0x0238), Some(State::Fault));
    assert_eq!(
        State::from_statusword(0xFF90),
        Some(State::NotReadyToSwitchOn)
    );
    // Bit 5 is free in the four states of the short mask.
    assert_eq!(State::from_statusword(0x0028), Some(State::Fault));
    assert_eq!(
        State::from_statusword(0x0060),
        Some(State::SwitchOnDisabled)
    );
}

#[test]
fn statuswords_outside_table_2_8_decode_to_no_state() {
    for raw in [
        0x0001, 0x0003, 0x0002, 0x0004, 0x0041, 0x0067, 0x0047, 0x0009,
    ] {
        assert_eq!(State::from_statusword(raw), None, "{raw:#06x}");
    }
}

#[test]
fn statusword_flags_encode_to_their_bits() {
    let base = Statusword::encode(State::OperationEnabled, StatusFlags::default()).raw();
    let cases: [(StatusFlags, u16); 7] = [
        (
            StatusFlags {
                voltage_enabled: true,
                ..Default::default()
            },
            0x0010,
        ),
        (
            StatusFlags {
                warning: true,
                ..Default::default()
            },
            0x0080,
        ),
        (
            StatusFlags {
                remote: true,
                ..Default::default()
            },
            0x0200,
        ),
        (
            StatusFlags {
                target_reached: true,
                ..Default::default()
            },
            0x0400,
        ),
        (
            StatusFlags {
                internal_limit_active: true,
                ..Default::default()
            },
            0x0800,
        ),
        (
            StatusFlags {
                mode_specific: 0b11,
                ..Default::default()
            },
            0x3000,
        ),
        (
            StatusFlags {
                manufacturer: 0xFFFF,
                ..Default::default()
            },
            0xC100,
        ),
    ];
    for (flags, bits) in cases {
        let word = Statusword::encode(State::OperationEnabled, flags);
        assert_eq!(word.raw(), base | bits, "{flags:?}");
        assert_eq!(word.state(), Some(State::OperationEnabled));
    }
}

#[test]
fn statusword_accessors_read_each_bit() {
    let word = Statusword(0xD6B7);
    assert_eq!(word.state(), Some(State::OperationEnabled));
    assert!(word.voltage_enabled());
    assert!(word.quick_stop());
    assert!(word.warning());
    assert!(word.remote());
    assert!(word.target_reached());
    assert!(!word.internal_limit_active());
    assert_eq!(word.mode_specific(), 0b01);
    assert_eq!(word.manufacturer(), 0xC000);
    assert!(!word.fault());
    assert!(!Statusword(0x0617).quick_stop());
    assert!(Statusword(0x0008).fault());
}

proptest! {
    #[test]
    fn statusword_flags_round_trip(raw in any::<u16>()) {
        let word = Statusword(raw);
        if let Some(state) = word.state() {
            let again = Statusword::encode(state, word.flags());
            prop_assert_eq!(again.state(), Some(state));
            prop_assert_eq!(again.flags(), word.flags());
            // Only the free bit 5 of the short-mask states may differ.
            prop_assert_eq!(again.raw() | 0x0020, raw | 0x0020);
        }
    }

    #[test]
    fn every_controlword_without_bit_7_is_a_command(raw in any::<u16>()) {
        let word = Controlword(raw & !0x0080);
        prop_assert!(word.command(Controlword(0)).is_some());
        prop_assert!(word.command(Controlword(0x0080)).is_some());
    }
}

#[test]
fn state_names_are_the_api_s() {
    let names = [
        "not_ready_to_switch_on",
        "switch_on_disabled",
        "ready_to_switch_on",
        "switched_on",
        "operation_enabled",
        "quick_stop_active",
        "fault_reaction_active",
        "fault",
    ];
    for (state, name) in State::ALL.into_iter().zip(names) {
        assert_eq!(state.name(), name);
        assert_eq!(State::from_name(name), Some(state));
    }
    assert_eq!(State::from_name("enabled"), None);
}

// ---- controlword ----

#[test]
fn every_command_has_figure_2_4_s_bits() {
    let expected: [(Command, u16); 8] = [
        (Command::Shutdown, 0x0006),
        (Command::SwitchOn, 0x0007),
        (Command::SwitchOnEnableOperation, 0x000F),
        (Command::DisableVoltage, 0x0000),
        (Command::QuickStop, 0x0002),
        (Command::DisableOperation, 0x0007),
        (Command::EnableOperation, 0x000F),
        (Command::FaultReset, 0x0080),
    ];
    for (command, raw) in expected {
        assert_eq!(command.controlword(), Controlword(raw), "{command}");
    }
}

#[test]
fn controlwords_decode_to_their_commands() {
    let none = Controlword(0);
    let cases: [(u16, Command); 11] = [
        (0x0006, Command::Shutdown),
        (0x000E, Command::Shutdown),
        (0x0007, Command::SwitchOn),
        (0x000F, Command::EnableOperation),
        (0x0000, Command::DisableVoltage),
        (0x000D, Command::DisableVoltage),
        (0x0001, Command::DisableVoltage),
        (0x0002, Command::QuickStop),
        (0x000B, Command::QuickStop),
        (0x0080, Command::FaultReset),
        (0x008F, Command::FaultReset),
    ];
    for (raw, command) in cases {
        assert_eq!(Controlword(raw).command(none), Some(command), "{raw:#06x}");
    }
}

#[test]
fn shared_codings_are_told_apart_by_the_state() {
    let none = Controlword(0);
    assert_eq!(
        Controlword(0x0007).command_in(none, State::OperationEnabled),
        Some(Command::DisableOperation)
    );
    assert_eq!(
        Controlword(0x0007).command_in(none, State::ReadyToSwitchOn),
        Some(Command::SwitchOn)
    );
    assert_eq!(
        Controlword(0x000F).command_in(none, State::ReadyToSwitchOn),
        Some(Command::SwitchOnEnableOperation)
    );
    assert_eq!(
        Controlword(0x000F).command_in(none, State::SwitchedOn),
        Some(Command::EnableOperation)
    );
}

#[test]
fn fault_reset_is_the_rising_edge_of_bit_7() {
    assert_eq!(
        Controlword(0x0080).command(Controlword(0x000F)),
        Some(Command::FaultReset)
    );
    assert_eq!(Controlword(0x0080).command(Controlword(0x0080)), None);
    assert_eq!(Controlword(0x0086).command(Controlword(0x0080)), None);
    assert_eq!(
        Controlword(0x0006).command(Controlword(0x0080)),
        Some(Command::Shutdown)
    );
}

#[test]
fn halt_and_mode_bits_are_raw_and_kept_across_commands() {
    let word = Controlword(0xFB7F);
    assert!(word.halt());
    assert!(!word.fault_reset_bit());
    assert_eq!(word.mode_specific(), 0x0270);
    assert_eq!(word.manufacturer(), 0xF800);
    let word = Controlword(0x0170).with_command(Command::EnableOperation);
    assert_eq!(word, Controlword(0x017F));
    assert_eq!(word.with_command(Command::Shutdown), Controlword(0x0176));
    assert_eq!(word.with_halt(false), Controlword(0x007F));
    assert_eq!(Controlword(0x000F).with_halt(true), Controlword(0x010F));
}

// ---- the drive's machine ----

fn machine(options: Options) -> DriveStateMachine {
    let mut drive = DriveStateMachine::new(options);
    drive.event(Event::Initialised);
    drive
}

/// Writes each controlword in turn; the reactions of the last.
fn write(drive: &mut DriveStateMachine, words: &[u16]) -> Vec<Reaction> {
    let mut last = Vec::new();
    for &word in words {
        last = drive.controlword(Controlword(word));
    }
    last
}

fn enabled(options: Options) -> DriveStateMachine {
    let mut drive = machine(options);
    write(&mut drive, &[0x0006, 0x0007, 0x000F]);
    assert_eq!(drive.state(), State::OperationEnabled);
    drive
}

fn faulted(options: Options) -> DriveStateMachine {
    let mut drive = enabled(options);
    drive.event(Event::FaultOccurred);
    drive.event(Event::FaultReactionFinished);
    assert_eq!(drive.state(), State::Fault);
    drive
}

#[test]
fn transitions_0_and_1_start_and_initialise() {
    let mut drive = DriveStateMachine::new(Options::default());
    assert_eq!(drive.state(), State::NotReadyToSwitchOn);
    // Commands wait for the drive to be ready.
    assert_eq!(write(&mut drive, &[0x0006]), vec![]);
    assert_eq!(drive.state(), State::NotReadyToSwitchOn);
    drive.event(Event::Initialised);
    assert_eq!(drive.state(), State::SwitchOnDisabled);
    assert_eq!(drive.statusword(), Statusword(0x0240));
}

#[test]
fn transitions_2_3_4_climb_to_operation_enabled() {
    let mut drive = machine(Options::default());
    assert_eq!(write(&mut drive, &[0x0006]), vec![]);
    assert_eq!(drive.state(), State::ReadyToSwitchOn);
    assert_eq!(write(&mut drive, &[0x0007]), vec![]);
    assert_eq!(drive.state(), State::SwitchedOn);
    assert_eq!(write(&mut drive, &[0x000F]), vec![Reaction::EnableOutput]);
    assert_eq!(drive.state(), State::OperationEnabled);
    assert_eq!(drive.statusword(), Statusword(0x0227));
}

#[test]
fn transition_3_and_4_at_once_from_ready_to_switch_on() {
    let mut drive = machine(Options::default());
    write(&mut drive, &[0x0006]);
    assert_eq!(write(&mut drive, &[0x000F]), vec![Reaction::EnableOutput]);
    assert_eq!(drive.state(), State::OperationEnabled);
}

#[test]
fn transition_5_honours_the_disable_operation_option() {
    for (raw, reaction) in [
        (0, Reaction::DisableOutput),
        (
            1,
            Reaction::RampStop {
                kind: StopKind::SlowDownRamp,
                then_disable: true,
            },
        ),
    ] {
        let mut drive = enabled(Options {
            disable_operation: DisableOption::from_raw(raw),
            ..Options::default()
        });
        assert_eq!(write(&mut drive, &[0x0007]), vec![reaction]);
        assert_eq!(drive.state(), State::SwitchedOn);
    }
}

#[test]
fn transition_6_shuts_down_from_switched_on() {
    let mut drive = machine(Options::default());
    write(&mut drive, &[0x0006, 0x0007]);
    assert_eq!(write(&mut drive, &[0x0006]), vec![]);
    assert_eq!(drive.state(), State::ReadyToSwitchOn);
}

#[test]
fn transition_7_by_quick_stop_or_disable_voltage() {
    for word in [0x0002, 0x0000] {
        let mut drive = machine(Options::default());
        write(&mut drive, &[0x0006]);
        assert_eq!(write(&mut drive, &[word]), vec![]);
        assert_eq!(drive.state(), State::SwitchOnDisabled);
    }
}

#[test]
fn transition_8_honours_the_shutdown_option() {
    for (raw, reaction) in [
        (0, Reaction::DisableOutput),
        (
            1,
            Reaction::RampStop {
                kind: StopKind::SlowDownRamp,
                then_disable: true,
            },
        ),
        (-3, Reaction::DisableOutput),
    ] {
        let mut drive = enabled(Options {
            shutdown: DisableOption::from_raw(raw),
            ..Options::default()
        });
        assert_eq!(write(&mut drive, &[0x0006]), vec![reaction]);
        assert_eq!(drive.state(), State::ReadyToSwitchOn);
    }
}

#[test]
fn transition_9_disables_voltage_from_operation_enabled() {
    let mut drive = enabled(Options::default());
    assert_eq!(write(&mut drive, &[0x0000]), vec![Reaction::DisableOutput]);
    assert_eq!(drive.state(), State::SwitchOnDisabled);
}

#[test]
fn transition_10_by_disable_voltage_or_quick_stop() {
    for word in [0x0000, 0x0002] {
        let mut drive = machine(Options::default());
        write(&mut drive, &[0x0006, 0x0007]);
        assert_eq!(write(&mut drive, &[word]), vec![]);
        assert_eq!(drive.state(), State::SwitchOnDisabled);
    }
}

#[test]
fn transitions_11_and_12_for_options_1_to_4() {
    for (raw, kind) in (1..=4).zip(ALL_STOPS) {
        let mut drive = enabled(Options {
            quick_stop: QuickStopOption::from_raw(raw),
            ..Options::default()
        });
        assert_eq!(
            write(&mut drive, &[0x0002]),
            vec![Reaction::RampStop {
                kind,
                then_disable: true
            }]
        );
        assert_eq!(drive.state(), State::QuickStopActive);
        assert_eq!(drive.statusword(), Statusword(0x0207));
        // 16 is not allowed with these options.
        assert_eq!(write(&mut drive, &[0x000F]), vec![]);
        assert_eq!(drive.state(), State::QuickStopActive);
        assert_eq!(drive.event(Event::QuickStopFinished), vec![]);
        assert_eq!(drive.state(), State::SwitchOnDisabled);
    }
}

#[test]
fn transitions_11_16_and_12_for_options_5_to_8() {
    for (raw, kind) in (5..=8).zip(ALL_STOPS) {
        let mut drive = enabled(Options {
            quick_stop: QuickStopOption::from_raw(raw),
            ..Options::default()
        });
        assert_eq!(
            write(&mut drive, &[0x0002]),
            vec![Reaction::RampStop {
                kind,
                then_disable: false
            }]
        );
        assert_eq!(drive.event(Event::QuickStopFinished), vec![]);
        assert_eq!(drive.state(), State::QuickStopActive);
        // Other commands do not leave it.
        for word in [0x0006, 0x0007, 0x0002] {
            assert_eq!(write(&mut drive, &[word]), vec![]);
            assert_eq!(drive.state(), State::QuickStopActive);
        }
        assert_eq!(write(&mut drive, &[0x000F]), vec![Reaction::EnableOutput]); // 16
        assert_eq!(drive.state(), State::OperationEnabled);
        write(&mut drive, &[0x0002]);
        assert_eq!(write(&mut drive, &[0x0000]), vec![Reaction::DisableOutput]); // 12
        assert_eq!(drive.state(), State::SwitchOnDisabled);
    }
}

#[test]
fn quick_stop_option_0_and_unknown_disable_at_once() {
    for raw in [0, -1, 9] {
        let mut drive = enabled(Options {
            quick_stop: QuickStopOption::from_raw(raw),
            ..Options::default()
        });
        assert_eq!(write(&mut drive, &[0x000B]), vec![Reaction::DisableOutput]);
        assert_eq!(drive.state(), State::SwitchOnDisabled);
    }
}

#[test]
fn transitions_13_and_14_with_a_ramping_fault_reaction() {
    for (raw, kind) in (1..=4).zip(ALL_STOPS) {
        let mut drive = enabled(Options {
            fault_reaction: FaultReactionOption::from_raw(raw),
            ..Options::default()
        });
        assert_eq!(
            drive.event(Event::FaultOccurred),
            vec![Reaction::RampStop {
                kind,
                then_disable: true
            }]
        );
        assert_eq!(drive.state(), State::FaultReactionActive);
        assert_eq!(drive.statusword(), Statusword(0x020F));
        // Commands do not interrupt the fault reaction.
        assert_eq!(write(&mut drive, &[0x0000, 0x0080]), vec![]);
        assert_eq!(drive.state(), State::FaultReactionActive);
        drive.event(Event::FaultReactionFinished);
        assert_eq!(drive.state(), State::Fault);
        assert_eq!(drive.statusword(), Statusword(0x0208));
    }
}

#[test]
fn transition_13_without_a_ramp_lands_in_fault() {
    let mut drive = enabled(Options {
        fault_reaction: FaultReactionOption::from_raw(0),
        ..Options::default()
    });
    assert_eq!(
        drive.event(Event::FaultOccurred),
        vec![Reaction::DisableOutput]
    );
    assert_eq!(drive.state(), State::Fault);
    // From a state with the drive function off there is nothing to stop.
    for setup in [&[][..], &[0x0006], &[0x0006, 0x0007]] {
        let mut drive = machine(Options::default());
        write(&mut drive, setup);
        assert_eq!(drive.event(Event::FaultOccurred), vec![]);
        assert_eq!(drive.state(), State::Fault);
    }
}

#[test]
fn transition_13_from_quick_stop_active() {
    let mut drive = enabled(Options::default());
    write(&mut drive, &[0x0002]);
    drive.event(Event::FaultOccurred);
    assert_eq!(drive.state(), State::FaultReactionActive);
}

#[test]
fn transition_15_needs_the_edge_and_no_fault_present() {
    let mut drive = faulted(Options::default());
    // The condition persists: reset refused.
    write(&mut drive, &[0x0000, 0x0080]);
    assert_eq!(drive.state(), State::Fault);
    drive.event(Event::FaultCleared);
    // Bit 7 still high: no edge, no reset.
    write(&mut drive, &[0x0080]);
    assert_eq!(drive.state(), State::Fault);
    write(&mut drive, &[0x0000]);
    assert_eq!(drive.state(), State::Fault);
    write(&mut drive, &[0x0080]);
    assert_eq!(drive.state(), State::SwitchOnDisabled);
}

#[test]
fn fault_reset_edge_straight_after_a_command() {
    let mut drive = faulted(Options::default());
    drive.event(Event::FaultCleared);
    // The last controlword was 0x000F, bit 7 clear: 0x0080 is an edge.
    assert_eq!(drive.last_controlword(), Controlword(0x000F));
    write(&mut drive, &[0x008F]);
    assert_eq!(drive.state(), State::SwitchOnDisabled);
}

#[test]
fn fault_reset_elsewhere_changes_nothing() {
    let mut drive = enabled(Options::default());
    assert_eq!(write(&mut drive, &[0x0080]), vec![]);
    assert_eq!(drive.state(), State::OperationEnabled);
}

#[test]
fn halt_follows_bit_8_in_operation_enabled_only() {
    for (raw, kind) in (1..=4).zip(ALL_STOPS) {
        let mut drive = enabled(Options {
            halt: HaltOption::from_raw(raw),
            ..Options::default()
        });
        assert_eq!(write(&mut drive, &[0x010F]), vec![Reaction::Halt { kind }]);
        assert_eq!(drive.state(), State::OperationEnabled);
        assert_eq!(write(&mut drive, &[0x010F]), vec![]);
        assert_eq!(write(&mut drive, &[0x000F]), vec![Reaction::Resume]);
    }
    let mut drive = machine(Options::default());
    assert_eq!(write(&mut drive, &[0x0106, 0x0107]), vec![]);
    // Enabling with bit 8 high enables, then halts.
    assert_eq!(
        write(&mut drive, &[0x010F]),
        vec![
            Reaction::EnableOutput,
            Reaction::Halt {
                kind: StopKind::SlowDownRamp
            }
        ]
    );
    // Leaving while halted resumes nothing.
    assert_eq!(write(&mut drive, &[0x0100]), vec![Reaction::DisableOutput]);
}

#[test]
fn motor_voltage_shows_in_bit_4() {
    let mut drive = machine(Options::default());
    drive.event(Event::MotorVoltage(true));
    assert_eq!(drive.statusword(), Statusword(0x0250));
    drive.event(Event::MotorVoltage(false));
    assert_eq!(drive.statusword(), Statusword(0x0240));
    drive.flags_mut().target_reached = true;
    assert_eq!(drive.statusword(), Statusword(0x0640));
}

#[test]
fn connection_loss_follows_option_6007() {
    let cases = [
        (0, State::OperationEnabled),
        (1, State::FaultReactionActive),
        (2, State::SwitchOnDisabled),
        (3, State::QuickStopActive),
    ];
    for (raw, state) in cases {
        let mut drive = enabled(Options {
            abort_connection: AbortConnectionOption::from_raw(raw),
            ..Options::default()
        });
        drive.event(Event::ConnectionLost);
        assert_eq!(drive.state(), state, "0x6007 = {raw}");
    }
    // A lost connection leaves no fault behind: reset works.
    let mut drive = enabled(Options::default());
    drive.event(Event::ConnectionLost);
    drive.event(Event::FaultReactionFinished);
    write(&mut drive, &[0x0080]);
    assert_eq!(drive.state(), State::SwitchOnDisabled);
}

#[test]
fn option_codes_round_trip() {
    for raw in -5..=12 {
        assert_eq!(QuickStopOption::from_raw(raw).raw(), raw);
        assert_eq!(DisableOption::from_raw(raw).raw(), raw);
        assert_eq!(HaltOption::from_raw(raw).raw(), raw);
        assert_eq!(FaultReactionOption::from_raw(raw).raw(), raw);
        assert_eq!(AbortConnectionOption::from_raw(raw).raw(), raw);
    }
    assert_eq!(QuickStopOption::from_raw(9), QuickStopOption::Unknown(9));
    assert_eq!(QuickStopOption::default().raw(), 2);
    assert_eq!(HaltOption::default().raw(), 1);
    assert_eq!(FaultReactionOption::default().raw(), 2);
    assert_eq!(DisableOption::default().raw(), 1);
    assert_eq!(AbortConnectionOption::default().raw(), 1);
}

// ---- the master's walk ----

/// A drive resting in `state`, its quick stop option 6 so quick stop
/// active is a state it rests in.
fn drive_in(state: State) -> DriveStateMachine {
    let options = Options {
        quick_stop: QuickStopOption::from_raw(6),
        ..Options::default()
    };
    let mut drive = machine(options);
    let setup: &[u16] = match state {
        State::SwitchOnDisabled => &[],
        State::ReadyToSwitchOn => &[0x0006],
        State::SwitchedOn => &[0x0006, 0x0007],
        State::OperationEnabled => &[0x0006, 0x0007, 0x000F],
        State::QuickStopActive => &[0x0006, 0x0007, 0x000F, 0x0002],
        State::Fault => {
            let mut drive = faulted(options);
            drive.event(Event::FaultCleared);
            return drive;
        }
        other => panic!("{other} is not a resting state"),
    };
    write(&mut drive, setup);
    drive.event(Event::QuickStopFinished);
    assert_eq!(drive.state(), state);
    drive
}

#[test]
fn every_plan_walks_the_drive_to_its_target() {
    let mut walks = 0;
    for current in State::ALL {
        for target in State::ALL {
            let result = plan(current, target);
            match (current, target) {
                (_, State::NotReadyToSwitchOn | State::FaultReactionActive | State::Fault) => {
                    assert_eq!(result, Err(PlanError::TargetNotCommandable(target)));
                }
                (State::NotReadyToSwitchOn | State::FaultReactionActive, _) => {
                    assert_eq!(result, Err(PlanError::Transient(current)));
                }
                _ => {
                    let commands = result.expect("a walk");
                    let mut drive = drive_in(current);
                    for command in &commands {
                        let word = drive.last_controlword().with_command(*command);
                        drive.controlword(word);
                        assert_eq!(
                            drive.state(),
                            expected_state(*command),
                            "{current} → {target}: {commands:?}"
                        );
                    }
                    assert_eq!(drive.state(), target, "{current} → {target}: {commands:?}");
                    walks += 1;
                }
            }
        }
    }
    assert_eq!(walks, 6 * 5);
}

#[test]
fn plans_are_the_expected_walks() {
    use Command as C;
    use State as S;
    let cases: [(S, S, &[C]); 8] = [
        (
            S::SwitchOnDisabled,
            S::OperationEnabled,
            &[C::Shutdown, C::SwitchOn, C::EnableOperation],
        ),
        (
            S::OperationEnabled,
            S::SwitchOnDisabled,
            &[C::DisableVoltage],
        ),
        (S::OperationEnabled, S::SwitchedOn, &[C::DisableOperation]),
        (S::OperationEnabled, S::ReadyToSwitchOn, &[C::Shutdown]),
        (
            S::SwitchedOn,
            S::QuickStopActive,
            &[C::EnableOperation, C::QuickStop],
        ),
        (
            S::QuickStopActive,
            S::OperationEnabled,
            &[C::EnableOperation],
        ),
        (
            S::QuickStopActive,
            S::SwitchedOn,
            &[C::DisableVoltage, C::Shutdown, C::SwitchOn],
        ),
        (
            S::Fault,
            S::OperationEnabled,
            &[C::FaultReset, C::Shutdown, C::SwitchOn, C::EnableOperation],
        ),
    ];
    for (current, target, commands) in cases {
        assert_eq!(
            plan(current, target).as_deref(),
            Ok(commands),
            "{current} → {target}"
        );
    }
    assert_eq!(plan(S::SwitchedOn, S::SwitchedOn), Ok(vec![]));
    assert_eq!(plan(S::Fault, S::SwitchOnDisabled), Ok(vec![C::FaultReset]));
}

// ---- modes ----

#[test]
fn modes_round_trip_with_their_numbers_and_names() {
    let expected: [(Mode, i8, &str); 12] = [
        (Mode::NoMode, 0, "none"),
        (Mode::ProfilePosition, 1, "profile_position"),
        (Mode::Velocity, 2, "velocity"),
        (Mode::ProfileVelocity, 3, "profile_velocity"),
        (Mode::Torque, 4, "torque"),
        (Mode::Homing, 6, "homing"),
        (Mode::InterpolatedPosition, 7, "interpolated_position"),
        (Mode::CyclicSyncPosition, 8, "cyclic_sync_position"),
        (Mode::CyclicSyncVelocity, 9, "cyclic_sync_velocity"),
        (Mode::CyclicSyncTorque, 10, "cyclic_sync_torque"),
        (Mode::DutyCycle, -1, "duty_cycle"),
        (Mode::ContinuousPosition, -16, "continuous_position"),
    ];
    for (mode, raw, name) in expected {
        assert_eq!(mode.raw(), raw);
        assert_eq!(Mode::from_raw(raw), mode);
        assert_eq!(mode.name(), Some(name));
        assert_eq!(Mode::from_name(name), Some(mode));
    }
    for raw in i8::MIN..=i8::MAX {
        assert_eq!(Mode::from_raw(raw).raw(), raw);
    }
    assert_eq!(Mode::from_raw(5), Mode::Unknown(5));
    assert_eq!(Mode::Unknown(-2).name(), None);
}

#[test]
fn umc_supported_drive_modes_default_decodes() {
    // 0x6502 default, 1115211 = 0x0011_044B (UMC manual §1.4.7).
    assert_eq!(
        Mode::supported(1_115_211),
        vec![
            Mode::ProfilePosition,
            Mode::Velocity,
            Mode::Torque,
            Mode::InterpolatedPosition,
            Mode::DutyCycle,
            Mode::ContinuousPosition,
        ]
    );
}
