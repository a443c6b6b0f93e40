//! JMC CANopen stepper drives (JMC CANopen manual Rev. 2.3: "Control word",
//! "Status word", 0x605A–0x609A, "Motion control mode" and "Homing mode"):
//! what the drive's numbers mean, for the gateway that drives a real one and
//! for the virtual one.
//!
//! The drive follows CiA 402 for its states (bits 0–3 and 7 of the
//! controlword, bits 0–6 of the statusword: see [`crate::cia402`])
//! and goes its own way elsewhere:
//!
//! - modes: 1 position, 3 velocity, 6 homing ([`JmcMode`]);
//! - units: velocities in 0.1 rps, accelerations UNSIGNED16 in 0.1 rps/s,
//!   positions in (micro)steps ([`units`]);
//! - controlword bits 4, 5, 6, 8, 9 ([`JmcControlword`]) and statusword bits
//!   8–15 ([`JmcStatusword`]);
//! - quick stop and halt codes ([`StopCode`]), homing methods 0–12
//!   ([`HomingMethod`]);
//! - the abort it gives for a value longer than its object
//!   ([`OVERSIZED_WRITE_ABORT`]).

use crate::canopen::sdo::AbortCode;

/// How the drive takes its node-ID ("Set the baud rate and station
/// number"): the rotary switches S1 (the low four bits) and S3 (the high
/// three), node-ID = S3 × 16 + S1, read at power-on or a network reset.
/// The manual names no other way: no node-ID object, no LSS (CiA 305).
pub const NODE_ID_SETTING: &str =
    "its rotary switches S1 (low four bits) and S3 (high three bits), read at power-on";

/// Whether the drive answers an LSS master: its manual has no LSS, its
/// node-ID is the switches' ([`NODE_ID_SETTING`]).
pub const ANSWERS_LSS: bool = false;
use crate::cia402::{HaltOption, Mode, QuickStopOption, StopKind, objects};

/// 0x6040, controlword (UNSIGNED16, write only on this drive).
pub const CONTROLWORD: u16 = objects::CONTROLWORD;
/// 0x6041, statusword (UNSIGNED16).
pub const STATUSWORD: u16 = objects::STATUSWORD;
/// 0x605A, quick stop code (INTEGER16), see [`StopCode`].
pub const QUICK_STOP_CODE: u16 = objects::QUICK_STOP_OPTION;
/// 0x605D, halt code (INTEGER16), see [`StopCode`].
pub const HALT_CODE: u16 = objects::HALT_OPTION;
/// 0x6060, modes of operation (INTEGER8, write only), see [`JmcMode`].
pub const MODES_OF_OPERATION: u16 = objects::MODES_OF_OPERATION;
/// 0x6061, mode code response (INTEGER8).
pub const MODE_DISPLAY: u16 = objects::MODES_OF_OPERATION_DISPLAY;
/// 0x6064, position actual value (INTEGER32, steps).
pub const POSITION_ACTUAL: u16 = objects::POSITION_ACTUAL;
/// 0x606C, velocity actual value (INTEGER32, 0.1 rps).
pub const VELOCITY_ACTUAL: u16 = objects::VELOCITY_ACTUAL;
/// 0x607A, target position (INTEGER32, steps).
pub const TARGET_POSITION: u16 = objects::TARGET_POSITION;
/// 0x607C, home offset (INTEGER32, steps).
pub const HOME_OFFSET: u16 = objects::HOME_OFFSET;
/// 0x6081, target velocity of both position and velocity mode (INTEGER32,
/// 0.1 rps; the drive has no 0x60FF).
pub const TARGET_VELOCITY: u16 = objects::PROFILE_VELOCITY;
/// 0x6083, acceleration (UNSIGNED16, 0.1 rps/s).
pub const ACCELERATION: u16 = objects::PROFILE_ACCELERATION;
/// 0x6084, deceleration (UNSIGNED16, 0.1 rps/s).
pub const DECELERATION: u16 = objects::PROFILE_DECELERATION;
/// 0x6085, quick stop deceleration (UNSIGNED16, 0.1 rps/s).
pub const QUICK_STOP_DECELERATION: u16 = objects::QUICK_STOP_DECELERATION;
/// 0x6098, homing method (INTEGER8, 0–12), see [`HomingMethod`].
pub const HOMING_METHOD: u16 = objects::HOMING_METHOD;
/// 0x6099, homing speeds (UNSIGNED32, 0.1 rps): sub 1 the search for the
/// mechanical origin, sub 2 the slow approach and the run to the zero.
pub const HOMING_SPEEDS: u16 = objects::HOMING_SPEEDS;
/// 0x609A, homing acceleration (UNSIGNED16, 0.1 rps/s), used for every
/// ramp of a homing run.
pub const HOMING_ACCELERATION: u16 = objects::HOMING_ACCELERATION;
/// 0x60C5, maximum acceleration (UNSIGNED32, 0.1 rps/s; 0: no limit).
pub const MAX_ACCELERATION: u16 = objects::MAX_ACCELERATION;
/// 0x60C6, maximum deceleration (UNSIGNED32, 0.1 rps/s; 0: no limit).
pub const MAX_DECELERATION: u16 = objects::MAX_DECELERATION;

/// The CiA 402 modes the drive has over CANopen, by their CiA 402 names
/// ([`JmcMode`] gives its numbers): position, velocity, homing. It has no
/// 0x6502 to say so, and no torque.
pub const CIA402_MODES: [Mode; 3] = [Mode::ProfilePosition, Mode::ProfileVelocity, Mode::Homing];

/// The object a velocity move's target goes to: the drive has no 0x60FF,
/// its 0x6081 is the target of both position and velocity mode.
pub const VELOCITY_MOVE_TARGET: u16 = TARGET_VELOCITY;

/// The drive's answer to a download longer than the 2-byte object it
/// writes (an acceleration sent with command 0x23 instead of 0x2B):
/// 0x06090030, "invalid value for parameter". The manual gives no
/// abort of its own for a wrong length; 0609 0030h is the one it gives for
/// every refused write it describes (0x1003, 0x1005, 0x1014, 0x1400–0x1803),
/// where the dictionary's generic answer would be 0x06070012.
pub const OVERSIZED_WRITE_ABORT: AbortCode = AbortCode::InvalidValue;

/// EMCY error codes of the drive's alarms. The manual names the error
/// register bits (0x1001: bit 1 current, 2 voltage, 3 temperature, 5 over
/// position) but no codes: these are CiA 402's for the same conditions.
pub mod emcy {
    /// 0x2310, continuous over-current (0x1001 bit 1).
    pub const OVER_CURRENT: u16 = 0x2310;
    /// 0x3210, DC link over-voltage (0x1001 bit 2).
    pub const OVER_VOLTAGE: u16 = 0x3210;
    /// 0x3220, DC link under-voltage (0x1001 bit 2).
    pub const UNDER_VOLTAGE: u16 = 0x3220;
    /// 0x4210, excess temperature of the drive (0x1001 bit 3).
    pub const OVER_TEMPERATURE: u16 = 0x4210;
    /// 0x8611, following error: the manual's "over position" of a stepping
    /// servo (0x1001 bit 5, statusword bit 13 in position mode).
    pub const FOLLOWING_ERROR: u16 = 0x8611;
}

/// A mode of operation as the JMC numbers them (0x6060, 0x6061).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum JmcMode {
    /// 0: no mode (the power-on value).
    NoMode,
    /// 1: position mode (CiA 402 profile position).
    Position,
    /// 2: pulse/direction mode; listed, not supported over CANopen.
    PulseDirection,
    /// 3: velocity mode (CiA 402 profile velocity).
    Velocity,
    /// 4: torque mode of the servo drives; not on a stepper.
    Torque,
    /// 6: homing mode.
    Homing,
    /// Any other value.
    Unknown(i8),
}

impl JmcMode {
    pub fn from_raw(raw: i8) -> Self {
        match raw {
            0 => Self::NoMode,
            1 => Self::Position,
            2 => Self::PulseDirection,
            3 => Self::Velocity,
            4 => Self::Torque,
            6 => Self::Homing,
            other => Self::Unknown(other),
        }
    }

    pub fn raw(self) -> i8 {
        match self {
            Self::NoMode => 0,
            Self::Position => 1,
            Self::PulseDirection => 2,
            Self::Velocity => 3,
            Self::Torque => 4,
            Self::Homing => 6,
            Self::Unknown(raw) => raw,
        }
    }

    /// "The device supports three modes: velocity mode, position mode and
    /// homing mode" (0x6060), and no mode at all.
    pub fn is_supported(self) -> bool {
        matches!(
            self,
            Self::NoMode | Self::Position | Self::Velocity | Self::Homing
        )
    }
}

/// Unit conversions. The drive counts positions in steps of its
/// subdivision (set with the handheld debugger, no object of the
/// dictionary), so everything that turns revolutions into steps takes the
/// steps per revolution.
pub mod units {
    /// What 0x6064, 0x607A, 0x607C count.
    pub const POSITION_UNIT: &str = "steps";
    /// What 0x606C, 0x6081, 0x6099 count.
    pub const VELOCITY_UNIT: &str = "0.1 rps";
    /// What 0x6083, 0x6084, 0x6085, 0x609A count.
    pub const ACCELERATION_UNIT: &str = "0.1 rps/s";

    /// 0x606C, 0x6081, 0x6099 count tenths of a revolution per second: 100
    /// is 10 rps.
    pub const VELOCITY_PER_RPS: f64 = 10.0;
    /// 0x6083, 0x6084, 0x6085, 0x609A count tenths of rps/s ("the drive
    /// internally divides this value by 10"): 1000 is 100 rps/s.
    pub const ACCELERATION_PER_RPS_PER_S: f64 = 10.0;

    /// A velocity object's value in rps.
    pub fn velocity_to_rps(raw: i64) -> f64 {
        raw as f64 / VELOCITY_PER_RPS
    }

    /// rps as a velocity object's value, rounded and saturated to INTEGER32.
    pub fn rps_to_velocity(rps: f64) -> i32 {
        (rps * VELOCITY_PER_RPS).round() as i32
    }

    /// A velocity object's value in steps per second.
    pub fn velocity_to_steps_per_s(raw: i64, steps_per_rev: u32) -> f64 {
        velocity_to_rps(raw) * f64::from(steps_per_rev)
    }

    /// Steps per second as a velocity object's value (0.1 rps), rounded.
    pub fn steps_per_s_to_velocity(steps_per_s: f64, steps_per_rev: u32) -> i32 {
        rps_to_velocity(steps_per_s / f64::from(steps_per_rev))
    }

    /// An acceleration object's value in rps/s.
    pub fn acceleration_to_rps_per_s(raw: u16) -> f64 {
        f64::from(raw) / ACCELERATION_PER_RPS_PER_S
    }

    /// rps/s as an acceleration object's value; `None` beyond what 16 bits
    /// hold (6553.5 rps/s) or below 0.
    pub fn rps_per_s_to_acceleration(rps_per_s: f64) -> Option<u16> {
        let raw = (rps_per_s * ACCELERATION_PER_RPS_PER_S).round();
        (0.0..=f64::from(u16::MAX))
            .contains(&raw)
            .then_some(raw as u16)
    }

    /// An acceleration value (0.1 rps/s, any width) in steps/s².
    pub fn acceleration_to_steps_per_s2(raw: u32, steps_per_rev: u32) -> f64 {
        f64::from(raw) / ACCELERATION_PER_RPS_PER_S * f64::from(steps_per_rev)
    }
}

/// Bit 4: position mode 0→1 takes the new set point ("position sampling"),
/// homing mode 0→1 starts homing.
pub const CW_NEW_SET_POINT: u16 = 1 << 4;
/// Bit 5 (position): 1 runs to the new set point at once, 0 finishes the
/// current one first.
pub const CW_CHANGE_IMMEDIATELY: u16 = 1 << 5;
/// Bit 6 (position): 0 absolute, 1 relative (to the previous target: "the
/// sum of two positions before and after").
pub const CW_RELATIVE: u16 = 1 << 6;
/// Bit 8: 0→1 halt, 1→0 carry on.
pub const CW_HALT: u16 = 1 << 8;
/// Bit 9 (position): 1 does not stop between two set points (the first is
/// passed at its own speed, then the second's speed is taken).
pub const CW_NO_STOP_BETWEEN: u16 = 1 << 9;

/// The controlword 0x6040 with the JMC's bits named.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct JmcControlword(pub u16);

impl JmcControlword {
    /// Enable operation (0x000F), the state every motion needs.
    pub const ENABLE_OPERATION: u16 = 0x000F;

    /// The controlword of the manual's position routines: enable operation
    /// with bit 4 as `sample`, and the set point's bits.
    pub fn position(sample: bool, immediately: bool, relative: bool, no_stop: bool) -> Self {
        let bit = |on: bool, mask: u16| if on { mask } else { 0 };
        JmcControlword(
            Self::ENABLE_OPERATION
                | bit(sample, CW_NEW_SET_POINT)
                | bit(immediately, CW_CHANGE_IMMEDIATELY)
                | bit(relative, CW_RELATIVE)
                | bit(no_stop, CW_NO_STOP_BETWEEN),
        )
    }

    pub fn raw(self) -> u16 {
        self.0
    }

    /// Bit 4 (new set point / start homing), as written.
    pub fn new_set_point(self) -> bool {
        self.0 & CW_NEW_SET_POINT != 0
    }

    /// Bit 5.
    pub fn change_immediately(self) -> bool {
        self.0 & CW_CHANGE_IMMEDIATELY != 0
    }

    /// Bit 6.
    pub fn relative(self) -> bool {
        self.0 & CW_RELATIVE != 0
    }

    /// Bit 8.
    pub fn halt(self) -> bool {
        self.0 & CW_HALT != 0
    }

    /// Bit 9.
    pub fn no_stop_between(self) -> bool {
        self.0 & CW_NO_STOP_BETWEEN != 0
    }
}

/// Bit 4: the power stage works (CiA 402: voltage enabled).
pub const SW_VOLTAGE_ENABLED: u16 = 1 << 4;
/// Bit 8: the motor is halted (controlword bit 8).
pub const SW_HALTED: u16 = 1 << 8;
/// Bit 9: the motor runs (not CiA 402's "remote").
pub const SW_RUNNING: u16 = 1 << 9;
/// Bit 10: position mode: target reached; velocity mode: target speed
/// reached; homing mode: home reached. While halted: the speed is 0.
pub const SW_TARGET_REACHED: u16 = 1 << 10;
/// Bit 11: the origin ("SW mechanical origin") switch is on.
pub const SW_ORIGIN_SWITCH: u16 = 1 << 11;
/// Bit 12: position mode: the set point was taken (no new one until bit 4
/// goes back to 0); velocity mode: the speed is 0; homing mode: homing done.
pub const SW_MODE_12: u16 = 1 << 12;
/// Bit 13: position mode: over position (following error); velocity mode:
/// the maximum acceleration limits the ramp; homing mode: homing error.
pub const SW_MODE_13: u16 = 1 << 13;
/// Bit 14: the CW limit switch is on.
pub const SW_CW_LIMIT: u16 = 1 << 14;
/// Bit 15: the CCW limit switch is on.
pub const SW_CCW_LIMIT: u16 = 1 << 15;

/// The statusword 0x6041 with the JMC's bits named. The state (bits 0–3, 5,
/// 6) reads as CiA 402's: [`JmcStatusword::state`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct JmcStatusword(pub u16);

impl JmcStatusword {
    pub fn raw(self) -> u16 {
        self.0
    }

    pub fn state(self) -> Option<crate::cia402::State> {
        crate::cia402::State::from_statusword(self.0)
    }

    fn bit(self, mask: u16) -> bool {
        self.0 & mask != 0
    }

    /// Bit 8.
    pub fn halted(self) -> bool {
        self.bit(SW_HALTED)
    }

    /// Bit 9.
    pub fn running(self) -> bool {
        self.bit(SW_RUNNING)
    }

    /// Bit 10.
    pub fn target_reached(self) -> bool {
        self.bit(SW_TARGET_REACHED)
    }

    /// Bit 11.
    pub fn origin_switch(self) -> bool {
        self.bit(SW_ORIGIN_SWITCH)
    }

    /// Bit 12 in position mode.
    pub fn set_point_acknowledged(self) -> bool {
        self.bit(SW_MODE_12)
    }

    /// Bit 12 in velocity mode.
    pub fn speed_zero(self) -> bool {
        self.bit(SW_MODE_12)
    }

    /// Bit 12 in homing mode.
    pub fn homing_attained(self) -> bool {
        self.bit(SW_MODE_12)
    }

    /// Bit 13 in position mode.
    pub fn over_position(self) -> bool {
        self.bit(SW_MODE_13)
    }

    /// Bit 13 in velocity mode.
    pub fn max_acceleration(self) -> bool {
        self.bit(SW_MODE_13)
    }

    /// Bit 13 in homing mode.
    pub fn homing_error(self) -> bool {
        self.bit(SW_MODE_13)
    }

    /// Bit 14.
    pub fn cw_limit(self) -> bool {
        self.bit(SW_CW_LIMIT)
    }

    /// Bit 15.
    pub fn ccw_limit(self) -> bool {
        self.bit(SW_CCW_LIMIT)
    }
}

/// The quick stop code 0x605A and the halt code 0x605D (INTEGER16; "now
/// only modes 1 and 2 are supported" for the quick stop).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum StopCode {
    /// 1, and the default 0 the table does not list: with the current
    /// deceleration (0x6084, 0x609A in homing).
    CurrentDeceleration,
    /// 2: with the quick stop deceleration 0x6085.
    QuickStopDeceleration,
    /// 3–32767: at once.
    Immediately,
}

impl StopCode {
    /// Values below 1 read as 1: the default 0 has to mean something, and
    /// the gentlest stop is the one the drive does for its supported code 1.
    pub fn from_raw(raw: i16) -> Self {
        match raw {
            ..=1 => Self::CurrentDeceleration,
            2 => Self::QuickStopDeceleration,
            _ => Self::Immediately,
        }
    }

    pub fn raw(self) -> i16 {
        match self {
            Self::CurrentDeceleration => 1,
            Self::QuickStopDeceleration => 2,
            Self::Immediately => 3,
        }
    }

    /// The stop in CiA 402 terms ("at once" as the current limit: the
    /// hardest stop there is).
    pub fn stop_kind(self) -> StopKind {
        match self {
            Self::CurrentDeceleration => StopKind::SlowDownRamp,
            Self::QuickStopDeceleration => StopKind::QuickStopRamp,
            Self::Immediately => StopKind::CurrentLimit,
        }
    }

    /// As a quick stop option: every JMC quick stop ends in switch on
    /// disabled.
    pub fn quick_stop_option(self) -> QuickStopOption {
        QuickStopOption::StopThenDisable(self.stop_kind())
    }

    pub fn halt_option(self) -> HaltOption {
        HaltOption::Stop(self.stop_kind())
    }
}

/// Which way the motor turns. The manual's homing diagrams run "left" to
/// the CW limit switch and "right" to the CCW one; left is taken as the
/// negative direction (CiA 402's homing method 1 also searches the
/// negative limit switch).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Decreasing positions, towards the CW limit switch.
    Left,
    /// Increasing positions, towards the CCW limit switch.
    Right,
}

impl Direction {
    /// −1 or +1.
    pub fn sign(self) -> f64 {
        match self {
            Self::Left => -1.0,
            Self::Right => 1.0,
        }
    }

    pub fn opposite(self) -> Self {
        match self {
            Self::Left => Self::Right,
            Self::Right => Self::Left,
        }
    }
}

/// What a homing method homes on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum HomeSwitch {
    /// The limit switch at the end the method runs to (CW for left, CCW
    /// for right).
    Limit,
    /// The origin switch.
    Origin,
}

/// A homing method, 0x6098 (manual, "Diagram of homing operation").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct HomingMethod(u8);

impl HomingMethod {
    /// The highest method.
    pub const MAX: u8 = 12;

    /// Methods 0–12; `None` for any other value.
    pub fn from_raw(raw: i8) -> Option<Self> {
        u8::try_from(raw)
            .ok()
            .filter(|&method| method <= Self::MAX)
            .map(HomingMethod)
    }

    pub fn raw(self) -> i8 {
        self.0 as i8
    }

    /// Method 0: no movement, where the motor stands is the origin.
    pub fn moves(self) -> bool {
        self.0 != 0
    }

    /// Where the search starts: odd methods left, even ones right.
    pub fn direction(self) -> Direction {
        if self.0 % 2 == 1 {
            Direction::Left
        } else {
            Direction::Right
        }
    }

    /// 1, 2, 5, 6, 9, 10 home on the limit switch, 3, 4, 7, 8, 11, 12 on the
    /// origin switch (0 on nothing).
    pub fn home_switch(self) -> HomeSwitch {
        match self.0 {
            1 | 2 | 5 | 6 | 9 | 10 => HomeSwitch::Limit,
            _ => HomeSwitch::Origin,
        }
    }

    /// 1–4 run at one speed and stop on the switch (hence their lower top
    /// speed); 5–12 search fast, brake, leave the switch slowly and come
    /// back to it slowly.
    pub fn two_speeds(self) -> bool {
        self.0 >= 5
    }

    /// 3, 4, 7, 8, 11, 12: the limit switch at the end of the search turns
    /// the motor back to look for the origin switch the other way.
    pub fn reverses_at_limit(self) -> bool {
        self.home_switch() == HomeSwitch::Origin && self.moves()
    }

    /// 9–12 "can set positive and negative homing offset": they run the
    /// home offset 0x607C from the mechanical origin before setting the
    /// zero. The others set the zero on the mechanical origin.
    pub fn uses_home_offset(self) -> bool {
        self.0 >= 9
    }

    /// The top homing speed in 0.1 rps: 300 r/min (50) for 1–4, 1200 r/min
    /// (200) for the others.
    pub fn max_speed(self) -> u32 {
        if self.two_speeds() || !self.moves() {
            200
        } else {
            50
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_are_the_manuals_numbers() {
        for (raw, mode, supported) in [
            (0, JmcMode::NoMode, true),
            (1, JmcMode::Position, true),
            (2, JmcMode::PulseDirection, false),
            (3, JmcMode::Velocity, true),
            (4, JmcMode::Torque, false),
            (6, JmcMode::Homing, true),
            (7, JmcMode::Unknown(7), false),
        ] {
            assert_eq!(JmcMode::from_raw(raw), mode);
            assert_eq!(mode.raw(), raw);
            assert_eq!(mode.is_supported(), supported, "{mode:?}");
        }
    }

    #[test]
    fn units_follow_the_manuals_examples() {
        // "If the value of index 606C is 100, it means the current speed is 10rps."
        assert_eq!(units::velocity_to_rps(100), 10.0);
        assert_eq!(units::rps_to_velocity(0.5), 5);
        // "Set this value to 10 rps/s, which the drive internally sees as 1 rps/s."
        assert_eq!(units::acceleration_to_rps_per_s(10), 1.0);
        assert_eq!(units::rps_per_s_to_acceleration(100.0), Some(1000));
        assert_eq!(units::rps_per_s_to_acceleration(6553.5), Some(u16::MAX));
        assert_eq!(units::rps_per_s_to_acceleration(6553.6), None);
        assert_eq!(units::rps_per_s_to_acceleration(-1.0), None);
        assert_eq!(units::velocity_to_steps_per_s(10, 10_000), 10_000.0);
        assert_eq!(units::steps_per_s_to_velocity(25_000.0, 10_000), 25);
        assert_eq!(
            units::acceleration_to_steps_per_s2(1000, 10_000),
            1_000_000.0
        );
    }

    #[test]
    fn controlwords_of_the_position_routines() {
        assert_eq!(
            JmcControlword::position(true, false, false, false).raw(),
            0x1F
        );
        assert_eq!(
            JmcControlword::position(true, false, true, false).raw(),
            0x5F
        );
        assert_eq!(
            JmcControlword::position(false, false, true, true).raw(),
            0x24F
        );
        assert_eq!(
            JmcControlword::position(true, true, true, true).raw(),
            0x27F
        );
        let word = JmcControlword(0x016F);
        assert!(word.halt() && word.relative() && word.change_immediately());
        assert!(!word.new_set_point() && !word.no_stop_between());
    }

    #[test]
    fn statusword_bits_9_to_15() {
        let word = JmcStatusword(0xD637);
        assert_eq!(word.state(), Some(crate::cia402::State::OperationEnabled));
        assert!(word.running() && word.target_reached() && word.cw_limit() && word.ccw_limit());
        assert!(word.homing_attained() && !word.homing_error() && !word.halted());
        assert!(!word.origin_switch());
    }

    #[test]
    fn stop_codes_default_to_the_current_deceleration() {
        assert_eq!(StopCode::from_raw(0), StopCode::CurrentDeceleration);
        assert_eq!(StopCode::from_raw(1), StopCode::CurrentDeceleration);
        assert_eq!(StopCode::from_raw(2), StopCode::QuickStopDeceleration);
        assert_eq!(StopCode::from_raw(3), StopCode::Immediately);
        assert_eq!(StopCode::from_raw(32767), StopCode::Immediately);
        assert_eq!(StopCode::QuickStopDeceleration.quick_stop_option().raw(), 2);
        assert_eq!(StopCode::CurrentDeceleration.halt_option().raw(), 1);
    }

    #[test]
    fn homing_methods_0_to_12() {
        assert_eq!(HomingMethod::from_raw(-1), None);
        assert_eq!(HomingMethod::from_raw(13), None);
        let method = |raw| HomingMethod::from_raw(raw).unwrap();
        assert!(!method(0).moves());
        for raw in 1..=12 {
            let m = method(raw);
            assert_eq!(m.raw(), raw);
            let left = raw % 2 == 1;
            assert_eq!(m.direction() == Direction::Left, left, "{raw}");
            assert_eq!(m.two_speeds(), raw >= 5, "{raw}");
            assert_eq!(m.uses_home_offset(), raw >= 9, "{raw}");
            assert_eq!(m.max_speed(), if raw <= 4 { 50 } else { 200 }, "{raw}");
        }
        assert_eq!(method(1).home_switch(), HomeSwitch::Limit);
        assert_eq!(method(4).home_switch(), HomeSwitch::Origin);
        assert_eq!(method(10).home_switch(), HomeSwitch::Limit);
        assert_eq!(method(11).home_switch(), HomeSwitch::Origin);
        assert!(method(7).reverses_at_limit() && !method(5).reverses_at_limit());
    }
}
