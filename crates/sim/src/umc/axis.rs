//! One axis of a UMC (UMC manual chapter 2 §1 "Drives and motion
//! control"): its power drive system (Figure 2.1, Table 2.2, the option
//! codes of §1.4.8–§1.4.13), its modes of operation and their statusword
//! bits (§2–§7), the stops the PDS and halt ask for, the cascaded position,
//! velocity and current loops (chapter 1 §3.5) on the motor of
//! [`super::motor`], and the supervision that turns a condition into a
//! fault with its EMCY (§1.5).
//!
//! The loops ([`super::pid`], configured by 0x4021/0x4041/0x4061): the
//! position PID turns the position error (revolutions) into a velocity
//! (rpm) added to the trajectory's velocity; the velocity PID turns the
//! velocity error (rpm) into a current (A) added to the feed-forward of
//! the motor's known inertia and friction (not of an unknown load); the
//! torque PID turns the current error (A) into a voltage across the
//! winding added to the measured back-EMF, as a duty cycle of the supply.
//! All three run at the board's 1 ms cycle divided by their frequency
//! divider.

use crate::behaviour::DeviceIo;
use crate::canopen::emcy::ErrorBit;
use crate::profiles::cia402::{
    AbortConnectionOption, DisableOption, FaultReactionOption, HaltOption, QuickStopOption,
};
use crate::profiles::cia402::{
    Controlword, DriveStateMachine, Event, Mode, Options, Reaction, State, StopKind,
};
use crate::profiles::umc::drive as d;
use crate::profiles::umc::{self, MANUFACTURER_AXIS_STEP, PROFILE_AXIS_STEP, units};

use super::faults::{Condition, Conditions};
use super::ip::Interpolator;
use super::modes::{
    CW_BIT4, CW_BIT6, ContinuousPosition, Demand, DutyMode, FULL_DUTY, ProfilePosition, TorqueMode,
    VelocityMode,
};
use super::motor::{Bridge, Motor, MotorModel};
use super::params::Params;
use super::pid::Pid;
use super::publish::{Published, Slot};
use super::sensor::Sensor;
use super::trajectory::{Profile, Sample};

/// The board's control cycle, s.
const CYCLE_S: f64 = 1e-3;
/// Below this speed (increments/ms, about 0.05 rpm) an axis
/// counts as stopped for the end of a stop ramp and for "velocity of axis
/// is 0" (Table 2.23).
const STOPPED: f64 = 0.05;
/// The modes this firmware supports (0x6502 = 0x0011_044B, Figure 2.6).
pub const SUPPORTED_MODES: [Mode; 6] = [
    Mode::ProfilePosition,
    Mode::Velocity,
    Mode::Torque,
    Mode::InterpolatedPosition,
    Mode::DutyCycle,
    Mode::ContinuousPosition,
];
/// TQ target reached: the torque within this many per mille of the
/// target.
const TORQUE_REACHED: f64 = 10.0;

/// Why a stop runs and what its end does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StopPurpose {
    /// Transition 11; transition 12 follows unless the option stays.
    QuickStop { then_disable: bool },
    /// Transition 13; transition 14 follows.
    FaultReaction,
    /// Transitions 5 and 8 with their slow down ramp.
    Disable,
    /// Controlword bit 8.
    Halt,
    /// 0x6060 changed while moving (§5.1.5 "Inter mode transitions").
    ModeChange,
}

#[derive(Debug, Clone, PartialEq)]
struct Stop {
    purpose: StopPurpose,
    /// The ramp; `None` brakes on the short-circuited winding (stop at the
    /// voltage limit).
    profile: Option<Profile>,
    finished: bool,
}

/// What the loops last did, for the PID status objects.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Loops {
    /// Position loop: demand, error (increments), velocity command
    /// (increments/ms, feed-forward included).
    position: [f64; 3],
    /// Velocity loop: command, error (increments/ms), current command
    /// (A, feed-forward included).
    velocity: [f64; 3],
    /// Current loop: command, error (A), voltage (V, back-EMF included).
    current: [f64; 3],
    /// The PIDs themselves: their integrators.
    torque_pid: Pid,
    velocity_pid: Pid,
    position_pid: Pid,
}

/// What a controlword or a fault did that the board must hear of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AxisNews {
    /// A fault reset left fault: the error register is recomputed and the
    /// error reset EMCY sent.
    pub fault_reset: bool,
}

/// The board's view the axis needs each tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Supply {
    /// Bus voltage, V.
    pub voltage: f64,
    pub under_voltage: bool,
    pub over_voltage: bool,
}

/// One axis.
#[derive(Debug, Clone)]
pub struct Axis {
    /// 1-based.
    pub number: u8,
    offset: u16,
    m_offset: u16,
    pds: DriveStateMachine,
    pub params: Params,
    pub motor: Motor,
    mode: Mode,
    pending_mode: Option<Mode>,
    controlword: u16,
    /// The drive function is enabled: the loops drive the bridge.
    output: bool,
    stop: Option<Stop>,
    halted: bool,
    /// The demand of the last tick.
    demand: Sample,
    targets: Targets,
    pp: ProfilePosition,
    cp: ContinuousPosition,
    vl: VelocityMode,
    tq: TorqueMode,
    dty: DutyMode,
    pub ip: Interpolator,
    loops: Loops,
    /// Consecutive ms the position error exceeded 0x6065.
    following_ms: u32,
    /// Consecutive ms within 0x6067 of the target.
    window_ms: u32,
    /// Consecutive ms above the burst current.
    burst_ms: u32,
    /// The motor turned faster than 0x4007.7.
    over_speed: bool,
    /// A driver bridge of this axis is over temperature (set by the board).
    pub over_temperature: bool,
    /// Warning (statusword bit 7): a bridge is above the low trigger.
    pub warm: bool,
    /// The motor winding's temperature, °C (0x4006.7).
    pub motor_temperature: f64,
    /// Conditions injected by the simulation.
    pub injected: Conditions,
    /// Conditions present at the last check.
    present: Conditions,
    /// Conditions raised since the last fault reset.
    latched: Conditions,
    published: Published,
    /// The torque, velocity and position sensors, conditioned (§3.4.4).
    sensors: [Sensor; 3],
    /// The supply seen at the last tick.
    supply: Supply,
}

/// The targets the master writes, kept as written (SDO or RPDO).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Targets {
    /// 0x607A.
    position: f64,
    /// 0x6042.
    velocity: f64,
    /// 0x6071.
    torque: f64,
    /// 0x41FA.
    duty: f64,
}

impl Axis {
    /// Axis `number` (1-based) of a board, before [`Axis::reset`].
    pub fn new(number: u8, model: MotorModel) -> Self {
        let n = u16::from(number.max(1) - 1);
        let (offset, m_offset) = (PROFILE_AXIS_STEP * n, MANUFACTURER_AXIS_STEP * n);
        Axis {
            number,
            offset,
            m_offset,
            pds: DriveStateMachine::new(Options::default()),
            params: Params::default(),
            motor: Motor::new(model),
            mode: Mode::NoMode,
            pending_mode: None,
            controlword: 0,
            output: false,
            stop: None,
            halted: false,
            demand: Sample::default(),
            targets: Targets::default(),
            pp: ProfilePosition::new(0.0),
            cp: ContinuousPosition::new(0.0),
            vl: VelocityMode::default(),
            tq: TorqueMode::default(),
            dty: DutyMode::default(),
            ip: Interpolator::default(),
            loops: Loops::default(),
            following_ms: 0,
            window_ms: 0,
            burst_ms: 0,
            over_speed: false,
            over_temperature: false,
            warm: false,
            motor_temperature: crate::board::AMBIENT,
            injected: Conditions::default(),
            present: Conditions::default(),
            latched: Conditions::default(),
            published: Published::new(offset, m_offset),
            sensors: [Sensor::default(); 3],
            supply: Supply {
                voltage: 0.0,
                under_voltage: false,
                over_voltage: false,
            },
        }
    }

    /// The CiA 402 object `index` of this axis (axis 1's index given).
    pub fn profile_index(&self, index: u16) -> u16 {
        index + self.offset
    }

    pub fn state(&self) -> State {
        self.pds.state()
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Conditions raised since the last fault reset.
    pub fn latched(&self) -> Conditions {
        self.latched
    }

    /// Power-on: everything from the dictionary, the PDS through
    /// transitions 0 and 1 to switch on disabled.
    pub fn reset(&mut self, io: &mut DeviceIo<'_>, supply: Supply) {
        let model = self.motor.model;
        *self = Axis::new(self.number, model);
        self.supply = supply;
        self.params = Params::read(io, self.offset, self.m_offset);
        self.read_options(io);
        self.pds.event(Event::Initialised);
        self.pds.event(Event::MotorVoltage(!supply.under_voltage));
        let p = |io: &DeviceIo<'_>, index: u16, sub: u8| io.real(index, sub).unwrap_or(0.0);
        self.targets = Targets {
            position: p(io, d::TARGET_POSITION + self.offset, 0),
            velocity: p(io, d::VL_TARGET + self.offset, 0),
            torque: p(io, d::TQ_TARGET + self.offset, 0),
            duty: p(io, umc::axis::DTY_TARGET + self.m_offset, 0),
        };
        let mode = io.int(d::MODES_OF_OPERATION + self.offset, 0).unwrap_or(0) as i8;
        self.mode = match Mode::from_raw(mode) {
            mode if SUPPORTED_MODES.contains(&mode) => mode,
            _ => Mode::NoMode,
        };
        self.published.invalidate();
        self.publish(io, true);
    }

    fn read_options(&mut self, io: &DeviceIo<'_>) {
        let raw = |index: u16| io.int(index + self.offset, 0).unwrap_or(0) as i16;
        *self.pds.options_mut() = Options {
            abort_connection: AbortConnectionOption::from_raw(raw(d::ABORT_CONNECTION_OPTION)),
            quick_stop: QuickStopOption::from_raw(raw(d::QUICK_STOP_OPTION)),
            shutdown: DisableOption::from_raw(raw(d::SHUTDOWN_OPTION)),
            disable_operation: DisableOption::from_raw(raw(d::DISABLE_OPERATION_OPTION)),
            halt: HaltOption::from_raw(raw(d::HALT_OPTION)),
            fault_reaction: FaultReactionOption::from_raw(raw(d::FAULT_REACTION_OPTION)),
        };
    }

    /// A value the master wrote into one of this axis's objects (`base`
    /// is axis 1's index).
    pub fn written(&mut self, io: &mut DeviceIo<'_>, base: u16, sub: u8) -> AxisNews {
        let index = match base {
            0x4000..=0x41FF => base + self.m_offset,
            _ => base + self.offset,
        };
        let value = io.int(index, sub).unwrap_or(0);
        let mut news = AxisNews::default();
        match (base, sub) {
            (d::CONTROLWORD, 0) => news = self.controlword(io, value as u16),
            (d::MODES_OF_OPERATION, 0) => self.mode_written(io, value as i8),
            (d::TARGET_POSITION, 0) => self.targets.position = value as f64,
            (d::VL_TARGET, 0) => self.targets.velocity = value as f64,
            (d::TQ_TARGET, 0) => self.targets.torque = value as f64,
            (umc::axis::DTY_TARGET, 0) => self.targets.duty = value as f64,
            (umc::axis::CP_TARGET, 0) => {
                if self.mode == Mode::ContinuousPosition && self.moving_by_mode() {
                    let relative = self.controlword & CW_BIT6 != 0;
                    self.cp
                        .target(value as f64, relative, self.demand, &self.params);
                }
            }
            (d::IP_DATA_RECORD, 1) => {
                // A set-point into a full buffer is rejected (§6.1.5); an
                // SDO download was refused before it got here.
                let _ = self.ip.push(value as i32);
            }
            (d::IP_DATA_CONFIGURATION, 6) => {
                if value == 0 {
                    self.ip.clear();
                }
            }
            (d::IP_DATA_CONFIGURATION, 2) => self.published.invalidate_slot(Slot::IpBufferSize),
            (d::ABORT_CONNECTION_OPTION | d::QUICK_STOP_OPTION..=d::FAULT_REACTION_OPTION, 0) => {
                self.read_options(io)
            }
            _ => self.params = Params::read(io, self.offset, self.m_offset),
        }
        self.publish(io, true);
        news
    }

    /// Whether the mode's generator is in charge (a halt only pauses it).
    fn moving_by_mode(&self) -> bool {
        self.output && self.pds.state() == State::OperationEnabled
    }

    fn controlword(&mut self, io: &mut DeviceIo<'_>, raw: u16) -> AxisNews {
        self.controlword = raw;
        let before = self.pds.state();
        let reactions = self.pds.controlword(Controlword(raw));
        self.apply(io, &reactions);
        let mut news = AxisNews::default();
        if before == State::Fault && self.pds.state() != State::Fault {
            news.fault_reset = !self.latched.is_empty();
            self.latched = Conditions::default();
        }
        if self.pds.state() == State::OperationEnabled {
            match self.mode {
                Mode::ProfilePosition => {
                    self.pp
                        .controlword(raw, self.targets.position, self.demand, &self.params);
                }
                Mode::InterpolatedPosition => self.interpolation_bit(),
                _ => {}
            }
        }
        news
    }

    /// IP: bit 4 switches interpolation on and off (§6.1.3).
    fn interpolation_bit(&mut self) {
        let wanted = self.controlword & CW_BIT4 != 0 && self.output;
        if wanted && !self.ip.active() {
            self.ip
                .activate(self.demand.position, self.params.ip_period.unwrap_or(1.0));
        } else if !wanted && self.ip.active() {
            self.ip.deactivate();
        }
    }

    /// What the PDS asked of the motor.
    fn apply(&mut self, io: &mut DeviceIo<'_>, reactions: &[Reaction]) {
        for reaction in reactions {
            match *reaction {
                Reaction::EnableOutput => {
                    // Transition 4: the drive function on, every internal
                    // set-point cleared.
                    self.params = Params::read(io, self.offset, self.m_offset);
                    self.output = true;
                    self.stop = None;
                    self.halted = false;
                    self.demand = Sample {
                        position: self.motor.position,
                        velocity: 0.0,
                        acceleration: 0.0,
                    };
                    self.pp = ProfilePosition::new(self.motor.position);
                    self.cp = ContinuousPosition::new(self.motor.position);
                    self.vl = VelocityMode::default();
                    self.tq = TorqueMode::default();
                    self.dty = DutyMode::default();
                    self.following_ms = 0;
                    self.window_ms = 0;
                    self.loops = Loops::default();
                }
                Reaction::DisableOutput => {
                    self.output = false;
                    self.stop = None;
                    self.halted = false;
                    self.ip.deactivate();
                }
                Reaction::RampStop { kind, then_disable } => {
                    let purpose = match self.pds.state() {
                        State::QuickStopActive => StopPurpose::QuickStop { then_disable },
                        State::FaultReactionActive => StopPurpose::FaultReaction,
                        _ => StopPurpose::Disable,
                    };
                    self.ip.deactivate();
                    self.start_stop(kind, purpose);
                    if !self.output {
                        // Nothing turns: the stop is over before it began.
                        self.finish_stop(io);
                    }
                }
                Reaction::Halt { kind } => {
                    self.halted = true;
                    // VL's ramp brings its own halt (Table 2.28).
                    if self.mode != Mode::Velocity && self.stop.is_none() {
                        self.start_stop(kind, StopPurpose::Halt);
                    }
                }
                Reaction::Resume => {
                    self.halted = false;
                    if self
                        .stop
                        .as_ref()
                        .is_some_and(|stop| stop.purpose == StopPurpose::Halt)
                    {
                        self.stop = None;
                        self.resume_mode();
                    }
                }
            }
        }
    }

    /// After a halt: the mode carries on from where the axis stopped.
    fn resume_mode(&mut self) {
        match self.mode {
            Mode::ProfilePosition => self.pp.resume(self.demand, &self.params),
            Mode::ContinuousPosition => self.cp.resume(self.demand, &self.params),
            Mode::InterpolatedPosition => self.ip.resume(self.demand.position),
            _ => {}
        }
    }

    /// The deceleration of a stop kind in the present mode,
    /// increments/ms²; `None` to brake on the short-circuited winding.
    fn deceleration(&self, kind: StopKind) -> Option<f64> {
        let params = &self.params;
        // The ramp works after the set-point factor, which does not change it
        // (§4.2.12).
        let vl = |rate: f64| VelocityMode::internal(rate, params);
        Some(match kind {
            StopKind::SlowDownRamp if self.mode == Mode::Velocity => vl(params.vl_deceleration),
            StopKind::QuickStopRamp if self.mode == Mode::Velocity => vl(params.vl_quick_stop),
            StopKind::SlowDownRamp => params.profile_deceleration,
            StopKind::QuickStopRamp => params.quick_stop_deceleration,
            StopKind::CurrentLimit => {
                // As hard as the drive's current allows.
                let m = &self.motor.model;
                let alpha = params.current_limit * m.torque_constant / m.inertia;
                alpha / units::rad_per_s_from_increments_per_ms(1.0) / 1000.0
            }
            StopKind::VoltageLimit => return None,
        })
    }

    fn start_stop(&mut self, kind: StopKind, purpose: StopPurpose) {
        let profile = self.deceleration(kind).map(|deceleration| {
            Profile::stop(self.demand.position, self.demand.velocity, deceleration)
        });
        self.stop = Some(Stop {
            purpose,
            profile,
            finished: false,
        });
    }

    /// The stop has brought the axis to rest.
    fn finish_stop(&mut self, io: &mut DeviceIo<'_>) {
        let Some(stop) = self.stop.as_mut() else {
            return;
        };
        if stop.finished {
            return;
        }
        stop.finished = true;
        match stop.purpose {
            StopPurpose::QuickStop { then_disable } => {
                let reactions = self.pds.event(Event::QuickStopFinished);
                self.apply(io, &reactions);
                if then_disable {
                    self.output = false;
                    self.stop = None;
                }
            }
            StopPurpose::FaultReaction => {
                let reactions = self.pds.event(Event::FaultReactionFinished);
                self.apply(io, &reactions);
                self.output = false;
                self.stop = None;
            }
            StopPurpose::Disable => {
                self.output = false;
                self.stop = None;
            }
            // Holds where it stopped until bit 8 falls.
            StopPurpose::Halt => {}
            StopPurpose::ModeChange => {
                self.stop = None;
                if let Some(mode) = self.pending_mode.take() {
                    self.switch_mode(mode);
                }
            }
        }
    }

    fn mode_written(&mut self, io: &mut DeviceIo<'_>, raw: i8) {
        let mode = Mode::from_raw(raw);
        if mode == Mode::NoMode || !SUPPORTED_MODES.contains(&mode) {
            return;
        }
        if mode == self.mode {
            self.pending_mode = None;
            return;
        }
        let moving = self.output
            && (self.demand.velocity.abs() > STOPPED || self.motor.velocity.abs() > STOPPED);
        if moving {
            // Stop on the halt ramp first, then change (§5.1.5).
            self.pending_mode = Some(mode);
            if self.stop.is_none() {
                let kind = self.pds.options().halt.stop();
                self.start_stop(kind, StopPurpose::ModeChange);
            }
        } else {
            self.switch_mode(mode);
        }
        self.publish(io, true);
    }

    fn switch_mode(&mut self, mode: Mode) {
        if self.mode == Mode::InterpolatedPosition {
            self.ip.deactivate();
        }
        self.mode = mode;
        let at = self.demand.position;
        self.pp = ProfilePosition::new(at);
        self.cp = ContinuousPosition::new(at);
        self.vl = VelocityMode::default();
        self.tq = TorqueMode::default();
        self.dty = DutyMode::default();
        self.window_ms = 0;
        if mode == Mode::InterpolatedPosition && self.pds.state() == State::OperationEnabled {
            self.interpolation_bit();
        }
    }

    /// Whether the tick would change nothing: disabled, at rest, nothing
    /// counting.
    fn idle(&self) -> bool {
        !self.output
            && self.motor.at_rest()
            && self.burst_ms == 0
            && self.following_ms == 0
            && !self.over_speed
    }

    /// One millisecond. `slow` asks for the diagnostic objects too (every
    /// 10 ms).
    pub fn tick(&mut self, io: &mut DeviceIo<'_>, supply: Supply, slow: bool) {
        self.see_supply(supply);
        if self.idle() {
            self.supervise(io);
            if slow {
                self.publish(io, true);
            }
            return;
        }
        self.sense();
        let demand = self.demand_now();
        let bridge = match demand {
            None => Bridge::Off,
            Some(Demand::Position(sample)) => self.position_loop(sample),
            Some(Demand::Velocity {
                velocity,
                acceleration,
            }) => self.velocity_loop(velocity, acceleration),
            Some(Demand::Current(current)) => {
                let limit = self.params.current_limit;
                self.loops.velocity = [0.0; 3];
                self.loops.position = [0.0; 3];
                Bridge::Current(current.clamp(-limit, limit))
            }
            Some(Demand::Duty(duty)) => Bridge::Duty(duty),
        };
        let bridge = match bridge {
            Bridge::Current(current) => self.torque_loop(current, supply.voltage),
            other => {
                self.loops.current = [0.0, 0.0, self.motor.duty * supply.voltage];
                other
            }
        };
        self.motor
            .step(bridge, supply.voltage, self.params.peak_current);
        match demand {
            Some(Demand::Position(sample)) => self.demand = sample,
            Some(Demand::Velocity { velocity, .. }) => {
                self.demand = Sample {
                    position: self.motor.position,
                    velocity,
                    acceleration: 0.0,
                };
            }
            _ => {
                self.demand = Sample {
                    position: self.motor.position,
                    velocity: self.motor.velocity,
                    acceleration: 0.0,
                };
            }
        }
        self.count(matches!(demand, Some(Demand::Position(_))));
        self.supervise(io);
        if let Some(stop) = &self.stop
            && !stop.finished
        {
            let ramp_done = stop.profile.as_ref().is_none_or(Profile::done);
            if ramp_done && self.motor.velocity.abs() < STOPPED {
                self.finish_stop(io);
            }
        }
        self.publish(io, slow);
    }

    /// The demand of this millisecond; `None` with the drive function off.
    fn demand_now(&mut self) -> Option<Demand> {
        if !self.output {
            return None;
        }
        if let Some(stop) = self.stop.as_mut() {
            return Some(match stop.profile.as_mut() {
                Some(profile) => Demand::Position(profile.step()),
                None => Demand::Duty(0.0),
            });
        }
        let hold = Demand::Position(Sample {
            position: self.demand.position,
            velocity: 0.0,
            acceleration: 0.0,
        });
        if self.pds.state() != State::OperationEnabled {
            return Some(hold);
        }
        Some(match self.mode {
            Mode::ProfilePosition => Demand::Position(self.pp.step(&self.params)),
            Mode::ContinuousPosition => Demand::Position(self.cp.step()),
            Mode::InterpolatedPosition if self.ip.active() => Demand::Position(self.ip.step()),
            Mode::Velocity => {
                let halt = self.halted.then(|| {
                    let kind = self.pds.options().halt.stop();
                    match kind {
                        StopKind::SlowDownRamp => self.params.vl_deceleration,
                        _ => self.params.vl_quick_stop,
                    }
                });
                let before = self.vl.output;
                let output =
                    self.vl
                        .step(self.controlword, self.targets.velocity, halt, &self.params);
                Demand::Velocity {
                    velocity: VelocityMode::internal(output, &self.params),
                    acceleration: VelocityMode::internal(output - before, &self.params),
                }
            }
            Mode::Torque => Demand::Current(self.tq.step(self.targets.torque, &self.params)),
            Mode::DutyCycle => Demand::Duty(self.dty.step(
                self.controlword,
                self.targets.duty,
                &self.params,
            )),
            _ => return Some(hold),
        })
    }

    /// Reads the sensors through their conditioning: the torque sensor
    /// gives N·m (the current times 0x4007.6), the velocity sensor rpm, the
    /// position sensor revolutions.
    fn sense(&mut self) {
        let motor = &self.motor;
        let params = &self.params;
        self.sensors[0].read(
            &params.torque_sensor,
            motor.current * params.current_constant,
        );
        self.sensors[1].read(
            &params.velocity_sensor,
            units::rpm_from_increments_per_ms(motor.velocity),
        );
        self.sensors[2].read(
            &params.position_sensor,
            motor.position / units::INCREMENTS_PER_REV,
        );
    }

    fn position_loop(&mut self, sample: Sample) -> Bridge {
        let rev = units::INCREMENTS_PER_REV;
        let rpm = self.loops.position_pid.step(
            &self.params.position_pid,
            sample.position / rev,
            self.sensors[2].value,
            CYCLE_S,
        );
        let command = sample.velocity + units::increments_per_ms_from_rpm(rpm);
        let error = sample.position - self.motor.position;
        self.loops.position = [sample.position, error, command];
        self.velocity_loop(command, sample.acceleration)
    }

    fn velocity_loop(&mut self, command: f64, acceleration: f64) -> Bridge {
        let rpm = units::rpm_from_increments_per_ms;
        let amperes = self.loops.velocity_pid.step(
            &self.params.velocity_pid,
            rpm(command),
            self.sensors[1].value,
            CYCLE_S,
        );
        let error = command - self.motor.velocity;
        let limit = self.params.current_limit;
        let current =
            (self.motor.current_for(acceleration, command) + amperes).clamp(-limit, limit);
        self.loops.velocity = [command, error, current];
        Bridge::Current(current)
    }

    /// The torque loop: the bridge's duty cycle that drives `wanted`
    /// amperes through the winding.
    fn torque_loop(&mut self, wanted: f64, supply: f64) -> Bridge {
        let volts = self.loops.torque_pid.step(
            &self.params.torque_pid,
            wanted,
            self.motor.current,
            CYCLE_S,
        );
        let voltage = (self.motor.back_emf() + volts).clamp(-supply, supply);
        self.loops.current = [wanted, wanted - self.motor.current, voltage];
        Bridge::Duty(if supply > 0.0 { voltage / supply } else { 0.0 })
    }

    /// The windows and timers of the statusword and the supervision.
    fn count(&mut self, position_controlled: bool) {
        let params = &self.params;
        if self.motor.current.abs() > params.burst_current {
            self.burst_ms = self.burst_ms.saturating_add(1);
        } else {
            self.burst_ms = 0;
        }
        let rpm = units::rpm_from_increments_per_ms(self.motor.velocity).abs();
        self.over_speed = params.max_motor_rpm > 0.0 && rpm > params.max_motor_rpm;
        let error = (self.demand.position - self.motor.position).abs();
        match params.following_window {
            Some(window) if position_controlled && self.output && error > window => {
                self.following_ms = self.following_ms.saturating_add(1);
            }
            _ => self.following_ms = 0,
        }
        let end = match self.mode {
            Mode::ProfilePosition => self.pp.end(),
            Mode::ContinuousPosition => self.cp.end(),
            Mode::InterpolatedPosition => self.ip.last_point(),
            _ => self.demand.position,
        };
        if (end - self.motor.position).abs() <= params.position_window {
            self.window_ms = self.window_ms.saturating_add(1);
        } else {
            self.window_ms = 0;
        }
    }

    fn following_error(&self) -> bool {
        self.following_ms > self.params.following_timeout
    }

    /// The board's supply as it is now: statusword bit 4 follows it.
    pub fn see_supply(&mut self, supply: Supply) {
        if supply.under_voltage != self.supply.under_voltage {
            self.pds.event(Event::MotorVoltage(!supply.under_voltage));
        }
        self.supply = supply;
    }

    /// Turns the conditions present into faults: an EMCY and the register
    /// bit for each new one, the fault signal to the PDS (transition 13),
    /// and the fault's end when all are gone.
    pub fn supervise(&mut self, io: &mut DeviceIo<'_>) {
        let natural = Conditions::default()
            .set(Condition::OverTemperature, self.over_temperature)
            .set(Condition::UnderVoltage, self.supply.under_voltage)
            .set(Condition::OverVoltage, self.supply.over_voltage)
            .set(Condition::FollowingError, self.following_error())
            .set(
                Condition::OverCurrent,
                self.burst_ms > self.params.burst_duration,
            )
            .set(Condition::OverSpeed, self.over_speed);
        let now = natural.union(self.injected);
        if now == self.present && now.minus(self.latched).is_empty() {
            return;
        }
        let new = now.minus(self.latched);
        for condition in new.iter() {
            io.set_error_bit(condition.error_bit(), true);
            io.emcy(condition.emcy_code(), [self.number, 0, 0, 0, 0]);
        }
        self.latched = self.latched.union(new);
        if !now.is_empty() && (self.present.is_empty() || !new.is_empty()) {
            let reactions = self.pds.event(Event::FaultOccurred);
            self.apply(io, &reactions);
            if !self.output {
                self.stop = None;
            }
        } else if now.is_empty() {
            self.pds.event(Event::FaultCleared);
        }
        self.present = now;
        self.publish(io, true);
    }

    /// The master is gone (0x6007).
    pub fn connection_lost(&mut self, io: &mut DeviceIo<'_>) {
        let before = self.pds.state();
        let reactions = self.pds.event(Event::ConnectionLost);
        self.apply(io, &reactions);
        let faulted = matches!(self.pds.state(), State::FaultReactionActive | State::Fault);
        if faulted && !matches!(before, State::FaultReactionActive | State::Fault) {
            // A fault always says why (§1.5): EMCY and error register.
            let condition = Condition::ConnectionLost;
            io.set_error_bit(condition.error_bit(), true);
            io.emcy(condition.emcy_code(), [self.number, 0, 0, 0, 0]);
            self.latched = self.latched.with(condition);
        }
        self.publish(io, true);
    }

    /// Statusword bits 10–13 and 7 for the present mode (Tables 2.23,
    /// 2.29, 2.33, 2.38; Figure 2.42).
    fn refresh_flags(&mut self) {
        let stopped = self.motor.velocity.abs() < STOPPED
            && self
                .stop
                .as_ref()
                .is_none_or(|stop| stop.profile.as_ref().is_none_or(Profile::done));
        let in_window = self.window_ms >= self.params.position_window_time;
        let following = self.following_error();
        let operating = matches!(
            self.pds.state(),
            State::OperationEnabled | State::QuickStopActive
        );
        let (reached, limited, specific) = if !operating {
            (false, false, 0)
        } else if self.halted || self.pds.state() == State::QuickStopActive {
            let specific = match self.mode {
                Mode::ProfilePosition => u8::from(self.pp.acknowledge()),
                Mode::InterpolatedPosition => u8::from(self.ip.active()),
                _ => 0,
            };
            (stopped, false, specific)
        } else {
            match self.mode {
                Mode::ProfilePosition => (
                    self.pp.arrived() && in_window,
                    false,
                    u8::from(self.pp.acknowledge()) | u8::from(following) << 1,
                ),
                Mode::ContinuousPosition => {
                    let arrived = self.cp.arrived() && in_window;
                    (
                        arrived,
                        false,
                        u8::from(!arrived) | u8::from(following) << 1,
                    )
                }
                Mode::InterpolatedPosition => (
                    self.ip.finished() && in_window,
                    self.demand.velocity.abs() > self.params.max_velocity,
                    u8::from(self.ip.active()) | u8::from(following) << 1,
                ),
                Mode::Velocity => (self.vl.output == self.vl.reference, self.vl.limited, 0),
                Mode::Torque => (
                    (self.torque_per_mille() - self.targets.torque).abs() <= TORQUE_REACHED,
                    self.tq.limited,
                    0,
                ),
                Mode::DutyCycle => (self.dty.demand == self.targets.duty, false, 0),
                _ => (false, false, 0),
            }
        };
        let flags = self.pds.flags_mut();
        flags.target_reached = reached;
        flags.internal_limit_active = limited;
        flags.mode_specific = specific;
        flags.warning = self.warm;
    }

    /// 0x6077: the torque in per mille of the rated torque (the torque is
    /// the current times the current constant, so its ratio is the
    /// current's).
    fn torque_per_mille(&self) -> f64 {
        if self.params.rated_current > 0.0 {
            self.motor.current / self.params.rated_current * 1000.0
        } else {
            0.0
        }
    }

    /// Writes the status objects that changed; `all` adds the diagnostic
    /// ones.
    pub fn publish(&mut self, io: &mut DeviceIo<'_>, all: bool) {
        self.sense();
        self.refresh_flags();
        let statusword = self.pds.statusword().raw();
        let motor = &self.motor;
        let position = motor.position.round() as i64;
        let out = &mut self.published;
        out.set(io, Slot::Statusword, i64::from(statusword));
        out.set(io, Slot::ModeDisplay, i64::from(self.mode.raw()));
        out.set(io, Slot::PositionActual, position);
        out.set(io, Slot::PositionInternal, position);
        out.set(
            io,
            Slot::PositionDemand,
            self.demand.position.round() as i64,
        );
        out.set(io, Slot::VelocityActual, motor.velocity.round() as i64);
        out.set(
            io,
            Slot::VelocityDemand,
            self.demand.velocity.round() as i64,
        );
        out.set(
            io,
            Slot::FollowingErrorActual,
            (self.demand.position - motor.position).round() as i64,
        );
        let per_mille = if self.params.rated_current > 0.0 {
            (motor.current / self.params.rated_current * 1000.0).round() as i64
        } else {
            0
        };
        out.set(io, Slot::TorqueActual, per_mille);
        out.set(io, Slot::CurrentActual, per_mille);
        out.set(
            io,
            Slot::MotorCurrent,
            (motor.current * 100.0).round() as i64,
        );
        out.set(
            io,
            Slot::MotorCommand,
            (motor.duty * FULL_DUTY).round() as i64,
        );
        out.set(
            io,
            Slot::MotorTorque,
            i64::from(umc::to_q15_16(motor.current * self.params.current_constant)),
        );
        let rpm = units::rpm_from_increments_per_ms(motor.velocity);
        out.set(io, Slot::MotorVelocity, i64::from(umc::to_q15_16(rpm)));
        let revolutions = motor.position / units::INCREMENTS_PER_REV;
        out.set(
            io,
            Slot::MotorPosition,
            i64::from(umc::to_q15_16(revolutions)),
        );
        let params = &self.params;
        out.set(
            io,
            Slot::VlDemand,
            VelocityMode::user(self.demand.velocity, params).round() as i64,
        );
        out.set(
            io,
            Slot::VlActual,
            VelocityMode::user(motor.velocity, params).round() as i64,
        );
        let torque_demand = match self.mode {
            Mode::Torque => self.tq.demand,
            _ if params.rated_current > 0.0 => {
                self.loops.current[0] / params.rated_current * 1000.0
            }
            _ => 0.0,
        };
        out.set(io, Slot::TorqueDemand, torque_demand.round() as i64);
        out.set(io, Slot::DtyDemand, self.dty.demand.round() as i64);
        out.set(
            io,
            Slot::ControlEffort,
            self.loops.velocity[0].round() as i64,
        );
        out.set(io, Slot::IpBufferSize, self.ip.len() as i64);
        if !all {
            return;
        }
        out.set(
            io,
            Slot::MotionError,
            i64::from(self.latched.motion_error()),
        );
        out.set(io, Slot::MotorError, i64::from(self.latched.motor_error()));
        out.set(
            io,
            Slot::MotorTemperature,
            (self.motor_temperature * 10.0).round() as i64,
        );
        out.set(
            io,
            Slot::DcLinkVoltage,
            (self.supply.voltage * 1000.0).round() as i64,
        );
        let rev =
            |increments: f64| i64::from(umc::to_q15_16(increments / units::INCREMENTS_PER_REV));
        let rpm =
            |velocity: f64| i64::from(umc::to_q15_16(units::rpm_from_increments_per_ms(velocity)));
        let amps = |current: f64| i64::from(umc::to_q15_16(current));
        let q = |value: f64| i64::from(umc::to_q15_16(value));
        let loops = &self.loops;
        let [p_in, p_err, p_out] = loops.position;
        out.set(io, Slot::PositionPidInput, rev(p_in));
        out.set(io, Slot::PositionPidError, rev(p_err));
        out.set(
            io,
            Slot::PositionPidIntegrator,
            q(loops.position_pid.integrator),
        );
        out.set(io, Slot::PositionPidOutput, rpm(p_out));
        out.set(io, Slot::PositionPidTarget, rev(p_in));
        let [v_in, v_err, v_out] = loops.velocity;
        out.set(io, Slot::VelocityPidInput, rpm(v_in));
        out.set(io, Slot::VelocityPidError, rpm(v_err));
        out.set(
            io,
            Slot::VelocityPidIntegrator,
            q(loops.velocity_pid.integrator),
        );
        out.set(io, Slot::VelocityPidOutput, amps(v_out));
        out.set(io, Slot::VelocityPidTarget, rpm(v_in));
        let [c_in, c_err, c_out] = loops.current;
        out.set(io, Slot::TorquePidInput, amps(c_in));
        out.set(io, Slot::TorquePidError, amps(c_err));
        out.set(
            io,
            Slot::TorquePidIntegrator,
            q(loops.torque_pid.integrator),
        );
        out.set(io, Slot::TorquePidOutput, q(c_out));
        out.set(io, Slot::TorquePidTarget, amps(c_in));
        let [torque_sensor, velocity_sensor, position_sensor] = self.sensors;
        out.set(io, Slot::PositionSensorRaw, rev(motor.position));
        out.set(io, Slot::PositionSensorValue, q(position_sensor.value));
        out.set(io, Slot::PositionSensorFlags, position_sensor.flags);
        out.set(io, Slot::VelocitySensorRaw, rpm(motor.velocity));
        out.set(io, Slot::VelocitySensorValue, q(velocity_sensor.value));
        out.set(io, Slot::VelocitySensorFlags, velocity_sensor.flags);
        let torque = amps(motor.current * params.current_constant);
        out.set(io, Slot::TorqueSensorRaw, torque);
        out.set(io, Slot::TorqueSensorValue, q(torque_sensor.value));
        out.set(io, Slot::TorqueSensorFlags, torque_sensor.flags);
        // 0x4008: the rotor's electrical angle and the hall sensors that
        // see it (six 60° sectors, the usual 120° hall sequence).
        const HALL: [i64; 6] = [0b001, 0b011, 0b010, 0b110, 0b100, 0b101];
        let turns = motor.position / units::INCREMENTS_PER_REV * params.pole_pairs;
        let angle = (turns.rem_euclid(1.0) * 360.0).floor();
        let sector = ((angle / 60.0) as usize).min(5);
        out.set(io, Slot::ElectricalAngle, angle as i64);
        out.set(io, Slot::HallPhase, sector as i64);
        out.set(io, Slot::HallRaw, HALL[sector]);
    }

    /// Forgets what was published, so that the next publish rewrites all.
    pub fn republish(&mut self) {
        self.published.invalidate();
    }

    /// The error register bits this axis's raised conditions hold.
    pub fn holds_error_bit(&self, bit: ErrorBit) -> bool {
        self.latched
            .iter()
            .any(|condition| condition.error_bit() == bit)
    }
}
