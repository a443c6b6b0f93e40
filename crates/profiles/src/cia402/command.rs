//! The controlword 0x6040 (UMC manual §1.4.3, Figure 2.4 "Frame of
//! Controlword"): the commands to the PDS in bits 0–3 and 7, halt in bit 8,
//! and the bits each mode of operation reads for itself.

use super::state::State;

/// Bit 0, SO.
const SWITCH_ON: u16 = 1 << 0;
/// Bit 1, EV.
const ENABLE_VOLTAGE: u16 = 1 << 1;
/// Bit 2, QS. Active low: 0 asks for a quick stop.
const QUICK_STOP: u16 = 1 << 2;
/// Bit 3, EO.
const ENABLE_OPERATION: u16 = 1 << 3;
/// Bit 7, FR. Acts on its 0→1 edge.
const FAULT_RESET: u16 = 1 << 7;
/// Bit 8, H.
const HALT: u16 = 1 << 8;
/// The bits a command sets or clears.
pub const COMMAND_BITS: u16 =
    SWITCH_ON | ENABLE_VOLTAGE | QUICK_STOP | ENABLE_OPERATION | FAULT_RESET;
/// Bits 4, 5, 6 and 9, OMS: their meaning is the mode's (JMC profile
/// position: 4 new set-point, 5 change immediately, 6 relative, 9 change
/// on set-point; JMC homing: 4 start).
pub const MODE_SPECIFIC_BITS: u16 = 0x0270;
/// Bits 11–15, the manufacturer's.
pub const MANUFACTURER_BITS: u16 = 0xF800;

/// A command to the PDS (Figure 2.4). Two pairs share a coding: the drive
/// tells [`Command::SwitchOn`] from [`Command::DisableOperation`], and
/// [`Command::SwitchOnEnableOperation`] from [`Command::EnableOperation`], by
/// the state it is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// `0xxx x110` (0x0006): transitions 2, 6, 8.
    Shutdown,
    /// `0xxx 0111` (0x0007): transition 3.
    SwitchOn,
    /// `0xxx 1111` (0x000F): transitions 3 + 4 at once.
    SwitchOnEnableOperation,
    /// `0xxx xx0x` (0x0000): transitions 7, 9, 10, 12.
    DisableVoltage,
    /// `0xxx x01x` (0x0002): transitions 7, 10, 11.
    QuickStop,
    /// `0xxx 0111` (0x0007): transition 5.
    DisableOperation,
    /// `0xxx 1111` (0x000F): transitions 4, 16.
    EnableOperation,
    /// `1xxx xxxx` (0x0080), on the 0→1 edge of bit 7: transition 15. The
    /// controlword written before it must have bit 7 clear.
    FaultReset,
}

impl Command {
    /// Every command, in the order of Figure 2.4.
    pub const ALL: [Command; 8] = [
        Command::Shutdown,
        Command::SwitchOn,
        Command::SwitchOnEnableOperation,
        Command::DisableVoltage,
        Command::QuickStop,
        Command::DisableOperation,
        Command::EnableOperation,
        Command::FaultReset,
    ];

    /// The command bits (0–3, 7), the bits marked X written 0.
    pub fn bits(self) -> u16 {
        match self {
            Command::Shutdown => 0x0006,
            Command::SwitchOn | Command::DisableOperation => 0x0007,
            Command::SwitchOnEnableOperation | Command::EnableOperation => 0x000F,
            Command::DisableVoltage => 0x0000,
            Command::QuickStop => 0x0002,
            Command::FaultReset => 0x0080,
        }
    }

    /// The controlword that carries this command and nothing else.
    pub fn controlword(self) -> Controlword {
        Controlword(self.bits())
    }

    /// The name in the HTTP API and logs (`switch_on`).
    pub fn name(self) -> &'static str {
        match self {
            Command::Shutdown => "shutdown",
            Command::SwitchOn => "switch_on",
            Command::SwitchOnEnableOperation => "switch_on_enable_operation",
            Command::DisableVoltage => "disable_voltage",
            Command::QuickStop => "quick_stop",
            Command::DisableOperation => "disable_operation",
            Command::EnableOperation => "enable_operation",
            Command::FaultReset => "fault_reset",
        }
    }
}

impl std::fmt::Display for Command {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Object 0x6040.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Controlword(pub u16);

impl Controlword {
    pub fn raw(self) -> u16 {
        self.0
    }

    /// This controlword with its command bits replaced by `command`'s:
    /// halt and the mode's bits are kept, so a state change does not
    /// disturb a motion set-up.
    pub fn with_command(self, command: Command) -> Controlword {
        Controlword((self.0 & !COMMAND_BITS) | command.bits())
    }

    /// Bit 8.
    pub fn halt(self) -> bool {
        self.0 & HALT != 0
    }

    /// This controlword with bit 8 set or cleared.
    pub fn with_halt(self, halt: bool) -> Controlword {
        Controlword(if halt { self.0 | HALT } else { self.0 & !HALT })
    }

    /// Bit 7, as written (not the edge).
    pub fn fault_reset_bit(self) -> bool {
        self.0 & FAULT_RESET != 0
    }

    /// Bits 4, 5, 6 and 9 in place.
    pub fn mode_specific(self) -> u16 {
        self.0 & MODE_SPECIFIC_BITS
    }

    /// Bits 11–15 in place.
    pub fn manufacturer(self) -> u16 {
        self.0 & MANUFACTURER_BITS
    }

    /// The command this controlword gives after `previous`, without knowing
    /// the drive's state: the shared codings read as [`Command::SwitchOn`]
    /// and [`Command::EnableOperation`]. `None` while bit 7 stays high: the
    /// fault reset has been given and no other command is coded with bit 7
    /// set.
    pub fn command(self, previous: Controlword) -> Option<Command> {
        if self.fault_reset_bit() {
            return (!previous.fault_reset_bit()).then_some(Command::FaultReset);
        }
        let bits = self.0;
        Some(if bits & ENABLE_VOLTAGE == 0 {
            Command::DisableVoltage
        } else if bits & QUICK_STOP == 0 {
            Command::QuickStop
        } else if bits & SWITCH_ON == 0 {
            Command::Shutdown
        } else if bits & ENABLE_OPERATION == 0 {
            Command::SwitchOn
        } else {
            Command::EnableOperation
        })
    }

    /// The command this controlword gives after `previous` to a drive in
    /// `state`, the shared codings told apart: 0x0007 disables operation
    /// from operation enabled, 0x000F switches on and enables from ready to
    /// switch on.
    pub fn command_in(self, previous: Controlword, state: State) -> Option<Command> {
        let command = self.command(previous)?;
        Some(match (command, state) {
            (Command::SwitchOn, State::OperationEnabled) => Command::DisableOperation,
            (Command::EnableOperation, State::ReadyToSwitchOn) => Command::SwitchOnEnableOperation,
            (command, _) => command,
        })
    }
}
