//! The states of the PDS (UMC manual §1.2.1, Figure 2.1) and the statusword
//! 0x6041 that reports them (§1.4.4, Tables 2.7 and 2.8).

/// A state of the power drive system. [`State::name`] gives the snake_case
/// name the HTTP API uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum State {
    /// `x0xx 0000` (mask 0x004F): initialising; the drive leaves it alone.
    NotReadyToSwitchOn,
    /// `x1xx 0000` (mask 0x004F).
    SwitchOnDisabled,
    /// `x01x 0001` (mask 0x006F).
    ReadyToSwitchOn,
    /// `x01x 0011` (mask 0x006F): high-level power on, drive function off.
    SwitchedOn,
    /// `x01x 0111` (mask 0x006F): the drive function is enabled.
    OperationEnabled,
    /// `x00x 0111` (mask 0x006F).
    QuickStopActive,
    /// `x0xx 1111` (mask 0x004F).
    FaultReactionActive,
    /// `x0xx 1000` (mask 0x004F).
    Fault,
}

/// Bits 0–3 and 6: enough to tell every state but the three that differ
/// only in bit 5.
const MASK_SHORT: u16 = 0x004F;
/// Bits 0–3, 5 and 6.
const MASK_LONG: u16 = 0x006F;

impl State {
    /// Every state, in the order of Table 2.8.
    pub const ALL: [State; 8] = [
        State::NotReadyToSwitchOn,
        State::SwitchOnDisabled,
        State::ReadyToSwitchOn,
        State::SwitchedOn,
        State::OperationEnabled,
        State::QuickStopActive,
        State::FaultReactionActive,
        State::Fault,
    ];

    /// The state a statusword reports, or `None` for a bit pattern Table 2.8
    /// does not list (e.g. `x00x 0001`).
    pub fn from_statusword(statusword: u16) -> Option<State> {
        match statusword & MASK_SHORT {
            0x0000 => return Some(State::NotReadyToSwitchOn),
            0x0040 => return Some(State::SwitchOnDisabled),
            0x000F => return Some(State::FaultReactionActive),
            0x0008 => return Some(State::Fault),
            _ => {}
        }
        match statusword & MASK_LONG {
            0x0021 => Some(State::ReadyToSwitchOn),
            0x0023 => Some(State::SwitchedOn),
            0x0027 => Some(State::OperationEnabled),
            0x0007 => Some(State::QuickStopActive),
            _ => None,
        }
    }

    /// The bits of the statusword this state fixes. Bit 5 where Table 2.8
    /// leaves it free is written 0, so each state has one canonical
    /// encoding.
    pub fn statusword_bits(self) -> u16 {
        match self {
            State::NotReadyToSwitchOn => 0x0000,
            State::SwitchOnDisabled => 0x0040,
            State::ReadyToSwitchOn => 0x0021,
            State::SwitchedOn => 0x0023,
            State::OperationEnabled => 0x0027,
            State::QuickStopActive => 0x0007,
            State::FaultReactionActive => 0x000F,
            State::Fault => 0x0008,
        }
    }

    /// The name in the HTTP API (`switch_on_disabled`).
    pub fn name(self) -> &'static str {
        match self {
            State::NotReadyToSwitchOn => "not_ready_to_switch_on",
            State::SwitchOnDisabled => "switch_on_disabled",
            State::ReadyToSwitchOn => "ready_to_switch_on",
            State::SwitchedOn => "switched_on",
            State::OperationEnabled => "operation_enabled",
            State::QuickStopActive => "quick_stop_active",
            State::FaultReactionActive => "fault_reaction_active",
            State::Fault => "fault",
        }
    }

    /// The state named `name` in the HTTP API.
    pub fn from_name(name: &str) -> Option<State> {
        State::ALL.into_iter().find(|state| state.name() == name)
    }

    /// Whether the drive function is enabled (Table 2.3): the motor is
    /// controlled, so leaving the state may need a stop.
    pub fn drive_function_enabled(self) -> bool {
        matches!(
            self,
            State::OperationEnabled | State::QuickStopActive | State::FaultReactionActive
        )
    }
}

impl std::fmt::Display for State {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Bit 4, VE: high-level (motor) voltage is applied.
const VOLTAGE_ENABLED: u16 = 1 << 4;
/// Bit 7, W.
const WARNING: u16 = 1 << 7;
/// Bit 9, RM: the controlword is being processed.
const REMOTE: u16 = 1 << 9;
/// Bit 10, TR.
const TARGET_REACHED: u16 = 1 << 10;
/// Bit 11, ILA.
const INTERNAL_LIMIT_ACTIVE: u16 = 1 << 11;
/// Bits 12–13, OMS.
const MODE_SPECIFIC_SHIFT: u16 = 12;
/// Bits 8, 14 and 15, MS: the manufacturer's (the JMC drive puts "motor
/// halted", "CW limit" and "CCW limit" there).
pub const MANUFACTURER_BITS: u16 = 0xC100;

/// The statusword bits beside the state: what the drive sets from its own
/// knowledge of the motor and the mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct StatusFlags {
    /// Bit 4.
    pub voltage_enabled: bool,
    /// Bit 7.
    pub warning: bool,
    /// Bit 9.
    pub remote: bool,
    /// Bit 10.
    pub target_reached: bool,
    /// Bit 11, mode-dependent.
    pub internal_limit_active: bool,
    /// Bits 12 (bit 0 here) and 13 (bit 1 here), mode-dependent.
    pub mode_specific: u8,
    /// Bits 8, 14 and 15 in place (other bits ignored); opaque.
    pub manufacturer: u16,
}

/// Object 0x6041 as read from the drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Statusword(pub u16);

impl Statusword {
    /// What a drive in `state` with `flags` reports.
    pub fn encode(state: State, flags: StatusFlags) -> Statusword {
        let bit = |on: bool, mask: u16| if on { mask } else { 0 };
        Statusword(
            state.statusword_bits()
                | bit(flags.voltage_enabled, VOLTAGE_ENABLED)
                | bit(flags.warning, WARNING)
                | bit(flags.remote, REMOTE)
                | bit(flags.target_reached, TARGET_REACHED)
                | bit(flags.internal_limit_active, INTERNAL_LIMIT_ACTIVE)
                | (u16::from(flags.mode_specific & 0b11) << MODE_SPECIFIC_SHIFT)
                | (flags.manufacturer & MANUFACTURER_BITS),
        )
    }

    pub fn raw(self) -> u16 {
        self.0
    }

    /// See [`State::from_statusword`].
    pub fn state(self) -> Option<State> {
        State::from_statusword(self.0)
    }

    /// Bit 5, QS. Active low: `false` while a quick stop is under way.
    pub fn quick_stop(self) -> bool {
        self.0 & (1 << 5) != 0
    }

    /// Bit 3, F.
    pub fn fault(self) -> bool {
        self.0 & (1 << 3) != 0
    }

    pub fn voltage_enabled(self) -> bool {
        self.0 & VOLTAGE_ENABLED != 0
    }

    pub fn warning(self) -> bool {
        self.0 & WARNING != 0
    }

    pub fn remote(self) -> bool {
        self.0 & REMOTE != 0
    }

    pub fn target_reached(self) -> bool {
        self.0 & TARGET_REACHED != 0
    }

    pub fn internal_limit_active(self) -> bool {
        self.0 & INTERNAL_LIMIT_ACTIVE != 0
    }

    /// Bits 12–13 as 0–3.
    pub fn mode_specific(self) -> u8 {
        ((self.0 >> MODE_SPECIFIC_SHIFT) & 0b11) as u8
    }

    /// Bits 8, 14 and 15 in place.
    pub fn manufacturer(self) -> u16 {
        self.0 & MANUFACTURER_BITS
    }

    /// Everything but the state.
    pub fn flags(self) -> StatusFlags {
        StatusFlags {
            voltage_enabled: self.voltage_enabled(),
            warning: self.warning(),
            remote: self.remote(),
            target_reached: self.target_reached(),
            internal_limit_active: self.internal_limit_active(),
            mode_specific: self.mode_specific(),
            manufacturer: self.manufacturer(),
        }
    }
}
