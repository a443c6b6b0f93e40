//! The virtual JMC CANopen stepper drive (JMC CANopen manual Rev. 2.3:
//! "Control word", "Status word", "Device protocol" 0x6040–0x609A, "Motion
//! control mode"; CiA 402 for the states).
//!
//! The drive runs the CiA 402 state machine of [`crate::profiles::cia402`]
//! for bits 0–3 and 7 of the controlword and bits 0–3, 5 and 6 of the
//! statusword, and the JMC's own meaning of the other bits
//! ([`crate::profiles::jmc`]). Its modes are position (1, [`position`]),
//! velocity (3) and homing (6, [`homing`]) against the switches of
//! [`switches`]; the shaft is [`axis::Axis`], moved one millisecond per
//! tick. Every value a master can read (statusword, position and velocity
//! actual, mode display) is kept in the store, written only when it
//! changes; a drive at rest with nothing to do returns from its tick at
//! once.
//!
//! # Layout
//!
//! - [`axis`]: the shaft and its ramps.
//! - [`position`]: the set points of position mode.
//! - [`homing`]: a homing run, methods 0–12.
//! - [`switches`]: the CW, CCW and origin switches.

pub mod axis;
pub mod homing;
pub mod position;
pub mod switches;

#[cfg(test)]
mod tests;

use crate::behaviour::{Behaviour, DeviceIo, Fault, FaultError};
use crate::canopen::emcy::ErrorBit;
use crate::canopen::sdo::AbortCode;
use crate::objects::ObjectStore;
use crate::pdo::PdoRules;
use crate::profiles::cia402::{
    AbortConnectionOption, Controlword, DisableOption, DriveStateMachine, Event,
    FaultReactionOption, Options, Reaction, State, StopKind,
};
use crate::profiles::jmc::{
    self, CW_NEW_SET_POINT, HomingMethod, JmcControlword, JmcMode, SW_HALTED, SW_MODE_12,
    SW_MODE_13, SW_RUNNING, SW_TARGET_REACHED, SW_VOLTAGE_ENABLED, StopCode, emcy, units,
};

use axis::{Axis, INSTANT};
use homing::{HomingOutcome, HomingParameters, HomingRun};
use position::{SetPoint, SetPointBits, SetPoints};
pub use switches::{LimitSwitches, Switch};

/// Steps per revolution of the virtual drive. The real one takes its
/// subdivision from the handheld debugger (no dictionary object); 10 000
/// makes the manual's routines (200 000 steps at 1 rps) last seconds.
pub const DEFAULT_STEPS_PER_REVOLUTION: u32 = 10_000;

/// Statusword bits 0–3, 5, 6: the CiA 402 state.
const STATE_BITS: u16 = 0x006F;

/// The parameters the drive runs on, copied from the store when written.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Parameters {
    /// 0x6081, 0.1 rps.
    target_velocity: i32,
    /// 0x6083, 0x6084, 0x6085, 0.1 rps/s.
    acceleration: u16,
    deceleration: u16,
    quick_stop_deceleration: u16,
    /// 0x60C5, 0x60C6, 0.1 rps/s; 0 no limit.
    max_acceleration: u32,
    max_deceleration: u32,
    /// 0x609A, 0.1 rps/s.
    homing_acceleration: u16,
}

/// The faults a JMC drive reports, as a bit set of [`Fault`]s.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Faults(u8);

impl Faults {
    fn mask(fault: Fault) -> u8 {
        1 << (fault as u8)
    }

    fn contains(self, fault: Fault) -> bool {
        self.0 & Self::mask(fault) != 0
    }

    fn with(self, fault: Fault) -> Self {
        Faults(self.0 | Self::mask(fault))
    }

    fn without(self, fault: Fault) -> Self {
        Faults(self.0 & !Self::mask(fault))
    }

    fn is_empty(self) -> bool {
        self.0 == 0
    }
}

/// The error register bit and EMCY code of each alarm of the drive;
/// `None` for the faults it does not have.
fn alarm(fault: Fault) -> Option<(ErrorBit, u16)> {
    Some(match fault {
        Fault::OverCurrent => (ErrorBit::Current, emcy::OVER_CURRENT),
        Fault::UnderVoltage => (ErrorBit::Voltage, emcy::UNDER_VOLTAGE),
        Fault::OverTemperature => (ErrorBit::Temperature, emcy::OVER_TEMPERATURE),
        // 0x1001 bit 5, "over position (stepping servo drive)".
        Fault::FollowingError => (ErrorBit::DeviceProfile, emcy::FOLLOWING_ERROR),
        Fault::HeartbeatLoss | Fault::BitErrors | Fault::BusOff => return None,
    })
}

/// Where homing mode stands (statusword bits 10, 12, 13 in mode 6).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
enum HomingStatus {
    #[default]
    NotDone,
    Attained,
    Failed,
}

/// A JMC stepper drive and the machine it turns.
pub struct Jmc {
    steps_per_rev: u32,
    switches: LimitSwitches,
    axis: Axis,
    /// The machine position of the position counter's 0.
    zero: f64,
    pds: DriveStateMachine,
    mode: JmcMode,
    controlword: u16,
    parameters: Parameters,
    /// Controlword bit 8 in force, and how to stop for it.
    halted: bool,
    halt_stop: StopKind,
    /// The stop a state change asked for (quick stop, disable operation,
    /// fault reaction), until the shaft stands.
    stopping: Option<StopKind>,
    /// The power stage drives the motor.
    output: bool,
    set_points: SetPoints,
    homing: Option<HomingRun>,
    homing_status: HomingStatus,
    /// Velocity mode: the ramp is cut down to 0x60C5 (statusword bit 13).
    acceleration_limited: bool,
    /// Alarms present now, and those not reset yet (the error register).
    faults: Faults,
    latched: Faults,
    /// What the store holds, to write only changes.
    published: Option<(u16, i64, i64)>,
}

impl Default for Jmc {
    fn default() -> Self {
        Self::new()
    }
}

impl Jmc {
    pub fn new() -> Self {
        Jmc {
            steps_per_rev: DEFAULT_STEPS_PER_REVOLUTION,
            switches: LimitSwitches::default(),
            axis: Axis::default(),
            zero: 0.0,
            pds: DriveStateMachine::new(Self::options(0, 0)),
            mode: JmcMode::NoMode,
            controlword: 0,
            parameters: Parameters::default(),
            halted: false,
            halt_stop: StopKind::SlowDownRamp,
            stopping: None,
            output: false,
            set_points: SetPoints::default(),
            homing: None,
            homing_status: HomingStatus::NotDone,
            acceleration_limited: false,
            faults: Faults::default(),
            latched: Faults::default(),
            published: None,
        }
    }

    /// Where the switches are (machine steps).
    pub fn switches(&self) -> LimitSwitches {
        self.switches
    }

    /// Moves the switches (the `/sim` API, tests); the statusword follows
    /// at the next tick.
    pub fn set_switches(&mut self, switches: LimitSwitches) {
        self.switches = switches;
        self.published = None;
    }

    pub fn steps_per_revolution(&self) -> u32 {
        self.steps_per_rev
    }

    /// The subdivision set on the drive (ignored if 0).
    pub fn set_steps_per_revolution(&mut self, steps: u32) {
        if steps > 0 {
            self.steps_per_rev = steps;
        }
    }

    /// Where the shaft is on the machine, in steps since the simulation
    /// started (not the drive's counter, which homing and resets re-zero).
    pub fn machine_position(&self) -> f64 {
        self.axis.position
    }

    /// The machine position of the drive's position 0 (0x6064): a switch
    /// at counter position `p` is at machine position `p + counter_zero()`.
    /// Power-on, reset node and homing move it.
    pub fn counter_zero(&self) -> f64 {
        self.zero
    }

    /// The shaft's speed in steps/s.
    pub fn machine_velocity(&self) -> f64 {
        self.axis.velocity
    }

    fn options(quick_stop: i16, halt: i16) -> Options {
        Options {
            quick_stop: StopCode::from_raw(quick_stop).quick_stop_option(),
            halt: StopCode::from_raw(halt).halt_option(),
            shutdown: DisableOption::SlowDownRamp,
            disable_operation: DisableOption::SlowDownRamp,
            // An alarm cuts the motor current: a stepper has no ramp left.
            fault_reaction: FaultReactionOption::DisableDriveFunction,
            // The drive has no 0x6007: losing the master changes nothing.
            abort_connection: AbortConnectionOption::NoAction,
        }
    }

    fn read_options(io: &DeviceIo<'_>) -> Options {
        let code = |index| io.int(index, 0).unwrap_or(0) as i16;
        Self::options(code(jmc::QUICK_STOP_CODE), code(jmc::HALT_CODE))
    }

    fn read_parameters(io: &DeviceIo<'_>) -> Parameters {
        let int = |index| io.int(index, 0).unwrap_or(0);
        Parameters {
            target_velocity: int(jmc::TARGET_VELOCITY) as i32,
            acceleration: int(jmc::ACCELERATION) as u16,
            deceleration: int(jmc::DECELERATION) as u16,
            quick_stop_deceleration: int(jmc::QUICK_STOP_DECELERATION) as u16,
            max_acceleration: int(jmc::MAX_ACCELERATION) as u32,
            max_deceleration: int(jmc::MAX_DECELERATION) as u32,
            homing_acceleration: int(jmc::HOMING_ACCELERATION) as u16,
        }
    }

    /// An acceleration value (0.1 rps/s) in steps/s², cut to `max` (0: no
    /// limit); 0 is no ramp. Says whether `max` cut it.
    fn rate(&self, raw: u32, max: u32) -> (f64, bool) {
        let limited = max != 0 && (raw == 0 || raw > max);
        let raw = if limited { max } else { raw };
        if raw == 0 {
            (INSTANT, false)
        } else {
            (
                units::acceleration_to_steps_per_s2(raw, self.steps_per_rev),
                limited,
            )
        }
    }

    fn acceleration(&self) -> (f64, bool) {
        self.rate(
            u32::from(self.parameters.acceleration),
            self.parameters.max_acceleration,
        )
    }

    fn deceleration(&self) -> f64 {
        self.rate(
            u32::from(self.parameters.deceleration),
            self.parameters.max_deceleration,
        )
        .0
    }

    /// The deceleration of a stop of `kind` in the present mode.
    fn stop_rate(&self, kind: StopKind) -> f64 {
        match kind {
            StopKind::SlowDownRamp => match &self.homing {
                Some(run) => run.acceleration(),
                None if self.mode == JmcMode::Homing => {
                    self.rate(u32::from(self.parameters.homing_acceleration), 0)
                        .0
                }
                None => self.deceleration(),
            },
            StopKind::QuickStopRamp => {
                self.rate(u32::from(self.parameters.quick_stop_deceleration), 0)
                    .0
            }
            StopKind::CurrentLimit | StopKind::VoltageLimit => INSTANT,
        }
    }

    fn position_actual(&self) -> i64 {
        (self.axis.position - self.zero).round() as i64
    }

    fn controlword_bit4(&self) -> bool {
        self.controlword & CW_NEW_SET_POINT != 0
    }

    /// What the reactions of the state machine ask of the motor.
    fn react(&mut self, reactions: Vec<Reaction>) {
        for reaction in reactions {
            match reaction {
                Reaction::EnableOutput => {
                    self.output = true;
                    self.stopping = None;
                    // Transition 4 starts unhalted; a bit 8 still high
                    // halts afresh (the next reaction).
                    self.halted = false;
                    self.set_points.reset(self.position_actual());
                }
                Reaction::DisableOutput => {
                    self.output = false;
                    self.stopping = None;
                    self.axis.stop();
                    self.end_motion();
                }
                Reaction::RampStop { kind, .. } => {
                    self.stopping = Some(kind);
                    self.end_motion();
                }
                Reaction::Halt { kind } => {
                    self.halted = true;
                    self.halt_stop = kind;
                    // "Stop homing": the run is over, not attained.
                    self.homing = None;
                }
                Reaction::Resume => self.halted = false,
            }
        }
    }

    /// The motion of the mode ends (the shaft may still be braking).
    fn end_motion(&mut self) {
        self.set_points.abandon();
        self.homing = None;
    }

    fn controlword_written(&mut self, io: &mut DeviceIo<'_>) {
        let word = io.int(jmc::CONTROLWORD, 0).unwrap_or(0) as u16;
        let previous = JmcControlword(self.controlword);
        self.controlword = word;
        let before = self.pds.state();
        let reactions = self.pds.controlword(Controlword(word));
        self.react(reactions);
        if self.pds.state() != State::OperationEnabled {
            // The halt is a function of operation enabled: leaving it (a
            // shutdown after routine 4's 0x010F) drops it, as the state
            // machine does, so that statusword bit 8 does not stay latched.
            self.halted = false;
        }
        if before == State::Fault && self.pds.state() != State::Fault {
            self.alarms_reset(io);
        }
        let word = JmcControlword(word);
        let rising = word.new_set_point() && !previous.new_set_point();
        if previous.new_set_point() && !word.new_set_point() {
            self.set_points.bit4_cleared();
        }
        if !rising || self.pds.state() != State::OperationEnabled {
            return;
        }
        match self.mode {
            JmcMode::Position => self.sample_set_point(io, word),
            JmcMode::Homing if !self.halted => self.start_homing(io),
            _ => {}
        }
    }

    fn sample_set_point(&mut self, io: &DeviceIo<'_>, word: JmcControlword) {
        let value = io.int(jmc::TARGET_POSITION, 0).unwrap_or(0) as i32;
        let speed = units::velocity_to_steps_per_s(
            i64::from(self.parameters.target_velocity).abs(),
            self.steps_per_rev,
        );
        let set_point = SetPoint {
            target: 0,
            speed,
            accel: self.acceleration().0,
            decel: self.deceleration(),
            no_stop_before: false,
        };
        let bits = SetPointBits {
            immediately: word.change_immediately(),
            relative: word.relative(),
            no_stop: word.no_stop_between(),
        };
        self.set_points.sample(value, bits, set_point);
    }

    fn start_homing(&mut self, io: &DeviceIo<'_>) {
        let int = |index, sub| io.int(index, sub).unwrap_or(0);
        // The dictionary keeps 0x6098 within 0–12.
        let Some(method) = HomingMethod::from_raw(int(jmc::HOMING_METHOD, 0) as i8) else {
            self.homing_status = HomingStatus::Failed;
            return;
        };
        self.homing = Some(HomingRun::new(HomingParameters {
            method,
            search_speed: int(jmc::HOMING_SPEEDS, 1) as u32,
            slow_speed: int(jmc::HOMING_SPEEDS, 2) as u32,
            acceleration: self.parameters.homing_acceleration,
            home_offset: int(jmc::HOME_OFFSET, 0) as i32,
            steps_per_rev: self.steps_per_rev,
        }));
        self.homing_status = HomingStatus::NotDone;
    }

    fn mode_written(&mut self, io: &mut DeviceIo<'_>) {
        let mode = JmcMode::from_raw(io.int(jmc::MODES_OF_OPERATION, 0).unwrap_or(0) as i8);
        // An RPDO bypasses the SDO check: an unsupported mode is ignored.
        if !mode.is_supported() || mode == self.mode {
            return;
        }
        self.end_motion();
        self.mode = mode;
        self.set_points.reset(self.position_actual());
        io.set_int(jmc::MODE_DISPLAY, 0, i64::from(mode.raw()));
    }

    /// A fault reset took the drive out of fault: the alarms that are
    /// gone leave the error register, and an EMCY 0000 says so.
    fn alarms_reset(&mut self, io: &mut DeviceIo<'_>) {
        for fault in Fault::ALL {
            if self.latched.contains(fault)
                && !self.faults.contains(fault)
                && let Some((bit, _)) = alarm(fault)
            {
                io.set_error_bit(bit, false);
            }
        }
        let had = !self.latched.is_empty();
        self.latched = self.faults;
        if had && self.latched.is_empty() {
            io.emcy(0x0000, [0; 5]);
        }
    }

    /// Whether a tick has anything to do.
    fn busy(&self) -> bool {
        if self.axis.velocity != 0.0 || self.stopping.is_some() {
            return true;
        }
        if !self.output || self.halted {
            return false;
        }
        match self.mode {
            JmcMode::Position => self.set_points.is_running(),
            JmcMode::Velocity => self.parameters.target_velocity != 0,
            JmcMode::Homing => self.homing.is_some(),
            _ => false,
        }
    }

    /// One millisecond of the motor.
    fn step(&mut self) {
        let before = self.axis.position;
        if let Some(kind) = self.stopping {
            let rate = self.stop_rate(kind);
            self.axis.ramp_velocity(0.0, rate, rate);
            if self.axis.velocity == 0.0 {
                self.stopping = None;
                let event = match self.pds.state() {
                    State::QuickStopActive => Some(Event::QuickStopFinished),
                    State::FaultReactionActive => Some(Event::FaultReactionFinished),
                    _ => None,
                };
                if let Some(event) = event {
                    let reactions = self.pds.event(event);
                    self.react(reactions);
                }
                self.output = self.pds.state() == State::OperationEnabled;
            }
        } else if !self.output {
            self.axis.stop();
        } else if self.halted {
            let rate = self.stop_rate(self.halt_stop);
            self.axis.ramp_velocity(0.0, rate, rate);
        } else {
            match self.mode {
                JmcMode::Position => {
                    let bit4 = self.controlword_bit4();
                    if !self.set_points.tick(&mut self.axis, self.zero, bit4) {
                        let rate = self.deceleration();
                        self.axis.ramp_velocity(0.0, rate, rate);
                    }
                }
                JmcMode::Velocity => {
                    let target = units::velocity_to_steps_per_s(
                        i64::from(self.parameters.target_velocity),
                        self.steps_per_rev,
                    );
                    let (accel, limited) = self.acceleration();
                    let speeding_up = target.abs() > self.axis.velocity.abs();
                    self.acceleration_limited = limited && speeding_up;
                    self.axis.ramp_velocity(target, accel, self.deceleration());
                }
                JmcMode::Homing => {
                    if let Some(run) = &mut self.homing {
                        match run.tick(&mut self.axis, &self.switches) {
                            HomingOutcome::Running => {}
                            HomingOutcome::Homed { zero } => {
                                self.zero = zero;
                                self.homing = None;
                                self.homing_status = HomingStatus::Attained;
                                self.set_points.reset(0);
                            }
                            HomingOutcome::Failed => {
                                self.homing = None;
                                self.homing_status = HomingStatus::Failed;
                            }
                        }
                        // The run deals with the switches itself.
                        return;
                    }
                    let rate = self.stop_rate(StopKind::SlowDownRamp);
                    self.axis.ramp_velocity(0.0, rate, rate);
                }
                _ => {
                    let rate = self.deceleration();
                    self.axis.ramp_velocity(0.0, rate, rate);
                }
            }
        }
        self.keep_off_the_limits(before);
    }

    /// A limit switch stops the motor running into it (statusword bits 14
    /// and 15 say why): the shaft stops on the switch's edge, and a set
    /// point beyond it is abandoned. Running away from it is allowed.
    fn keep_off_the_limits(&mut self, before: f64) {
        let velocity = self.axis.velocity;
        let switch = if velocity < 0.0 {
            Switch::Cw
        } else if velocity > 0.0 {
            Switch::Ccw
        } else {
            return;
        };
        if !self.switches.is_on(switch, self.axis.position) {
            return;
        }
        self.axis.position = if self.switches.is_on(switch, before) {
            before
        } else {
            self.switches
                .reached(switch, before, self.axis.position)
                .unwrap_or(before)
        };
        self.axis.stop();
        self.set_points.abandon();
    }

    fn statusword(&self) -> u16 {
        let mut word = self.pds.statusword().raw() & STATE_BITS;
        let bit = |on: bool, mask: u16| if on { mask } else { 0 };
        let standing = self.axis.velocity == 0.0;
        word |= bit(
            !self.faults.contains(Fault::UnderVoltage),
            SW_VOLTAGE_ENABLED,
        );
        word |= bit(self.halted, SW_HALTED);
        word |= bit(!standing, SW_RUNNING);
        word |= self.switches.status_bits(self.axis.position);
        let halted_and_standing = self.halted && standing;
        word |= match self.mode {
            JmcMode::Position => {
                bit(
                    halted_and_standing || self.set_points.reached() && standing,
                    SW_TARGET_REACHED,
                ) | bit(self.set_points.acknowledged(), SW_MODE_12)
                    | bit(self.latched.contains(Fault::FollowingError), SW_MODE_13)
            }
            JmcMode::Velocity => {
                let target = if self.output && !self.halted {
                    units::velocity_to_steps_per_s(
                        i64::from(self.parameters.target_velocity),
                        self.steps_per_rev,
                    )
                } else {
                    0.0
                };
                bit(self.axis.velocity == target, SW_TARGET_REACHED)
                    | bit(standing, SW_MODE_12)
                    | bit(self.acceleration_limited, SW_MODE_13)
            }
            JmcMode::Homing => {
                let attained = self.homing_status == HomingStatus::Attained;
                bit(
                    halted_and_standing || attained && standing,
                    SW_TARGET_REACHED,
                ) | bit(attained, SW_MODE_12)
                    | bit(self.homing_status == HomingStatus::Failed, SW_MODE_13)
            }
            _ => 0,
        };
        word
    }

    /// Writes the statusword and the actual values where they changed.
    fn publish(&mut self, io: &mut DeviceIo<'_>) {
        let now = (
            self.statusword(),
            self.position_actual(),
            i64::from(units::steps_per_s_to_velocity(
                self.axis.velocity,
                self.steps_per_rev,
            )),
        );
        let last = self.published;
        if last.map(|last| last.0) != Some(now.0) {
            io.set_int(jmc::STATUSWORD, 0, i64::from(now.0));
        }
        if last.map(|last| last.1) != Some(now.1) {
            io.set_int(jmc::POSITION_ACTUAL, 0, now.1);
        }
        if last.map(|last| last.2) != Some(now.2) {
            io.set_int(jmc::VELOCITY_ACTUAL, 0, now.2);
        }
        self.published = Some(now);
    }
}

impl Behaviour for Jmc {
    fn product(&self) -> &'static str {
        "jmc"
    }

    /// The manual's programming routines (appendix 1 and 2) re-map PDOs
    /// that are in use, without setting bit 31 first.
    fn pdo_rules(&self) -> PdoRules {
        PdoRules::RemapWhileValid
    }

    /// Power-on and reset node: the drive starts afresh in switch on
    /// disabled with its counter at 0; the shaft and the switches stay
    /// where they are, and an alarm still present is still there.
    fn reset(&mut self, io: &mut DeviceIo<'_>) {
        self.pds = DriveStateMachine::new(Self::read_options(io));
        self.pds.event(Event::Initialised);
        self.parameters = Self::read_parameters(io);
        self.controlword = io.int(jmc::CONTROLWORD, 0).unwrap_or(0) as u16;
        self.mode = JmcMode::from_raw(io.int(jmc::MODES_OF_OPERATION, 0).unwrap_or(0) as i8);
        if !self.mode.is_supported() {
            self.mode = JmcMode::NoMode;
        }
        io.set_int(jmc::MODE_DISPLAY, 0, i64::from(self.mode.raw()));
        self.axis.stop();
        self.zero = self.axis.position;
        self.halted = false;
        self.stopping = None;
        self.output = false;
        self.set_points.reset(0);
        self.homing = None;
        self.homing_status = HomingStatus::NotDone;
        self.acceleration_limited = false;
        self.latched = self.faults;
        if !self.faults.is_empty() {
            for fault in Fault::ALL {
                if let (true, Some((bit, _))) = (self.faults.contains(fault), alarm(fault)) {
                    io.set_error_bit(bit, true);
                }
            }
            self.pds.event(Event::FaultOccurred);
        }
        self.published = None;
        self.publish(io);
    }

    /// A value longer than the 2-byte object it is written to gets the
    /// drive's own abort ([`jmc::OVERSIZED_WRITE_ABORT`]).
    fn check_write(
        &self,
        store: &ObjectStore,
        index: u16,
        sub: u8,
        size: Option<usize>,
    ) -> Result<(), AbortCode> {
        let (Some(size), Some(entry)) = (size, store.dictionary().sub(index, sub)) else {
            return Ok(());
        };
        if entry.access.is_writable() && entry.data_type.byte_len() == Some(2) && size > 2 {
            return Err(jmc::OVERSIZED_WRITE_ABORT);
        }
        Ok(())
    }

    /// 0x6060 takes the three modes the drive has (and 0).
    fn check_value(
        &self,
        _store: &ObjectStore,
        index: u16,
        sub: u8,
        data: &[u8],
    ) -> Result<(), AbortCode> {
        if index == jmc::MODES_OF_OPERATION
            && let [raw] = data
            && !JmcMode::from_raw(*raw as i8).is_supported()
        {
            return Err(AbortCode::InvalidValue);
        }
        // The manual's 0x1005 and PDO COB-ID descriptions: standard frames
        // only, and no SYNC producer; bit 29 (and 30 of 0x1005) is 0609 0030h.
        let refused_bits = match (index, sub) {
            (0x1005, 0) => 0x6000_0000,
            (0x1400..=0x1403 | 0x1800..=0x1803, 1) => 0x2000_0000,
            _ => 0,
        };
        if let Ok(raw) = <[u8; 4]>::try_from(data)
            && u32::from_le_bytes(raw) & refused_bits != 0
        {
            return Err(AbortCode::InvalidValue);
        }
        Ok(())
    }

    fn written(&mut self, io: &mut DeviceIo<'_>, index: u16, _sub: u8) {
        match index {
            jmc::CONTROLWORD => self.controlword_written(io),
            jmc::MODES_OF_OPERATION => self.mode_written(io),
            jmc::QUICK_STOP_CODE | jmc::HALT_CODE => {
                *self.pds.options_mut() = Self::read_options(io);
            }
            jmc::TARGET_VELOCITY
            | jmc::ACCELERATION
            | jmc::DECELERATION
            | jmc::QUICK_STOP_DECELERATION
            | jmc::MAX_ACCELERATION
            | jmc::MAX_DECELERATION
            | jmc::HOMING_ACCELERATION => self.parameters = Self::read_parameters(io),
            _ => return,
        }
        self.publish(io);
    }

    fn tick(&mut self, io: &mut DeviceIo<'_>) {
        if self.busy() {
            self.step();
        } else if self.published.is_some() {
            return;
        }
        self.publish(io);
    }

    fn inject_fault(&mut self, io: &mut DeviceIo<'_>, fault: Fault) -> Result<(), FaultError> {
        let Some((bit, code)) = alarm(fault) else {
            return Err(FaultError::NotApplicable {
                product: self.product(),
                fault,
            });
        };
        if self.faults.contains(fault) {
            return Ok(());
        }
        self.faults = self.faults.with(fault);
        self.latched = self.latched.with(fault);
        io.set_error_bit(bit, true);
        io.emcy(code, [0; 5]);
        let reactions = self.pds.event(Event::FaultOccurred);
        self.react(reactions);
        self.publish(io);
        Ok(())
    }

    fn clear_fault(&mut self, io: &mut DeviceIo<'_>, fault: Fault) -> Result<(), FaultError> {
        if alarm(fault).is_none() {
            return Err(FaultError::NotApplicable {
                product: self.product(),
                fault,
            });
        }
        self.faults = self.faults.without(fault);
        if self.faults.is_empty() {
            self.pds.event(Event::FaultCleared);
        }
        self.publish(io);
        Ok(())
    }
}
