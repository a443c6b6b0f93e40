//! A homing run (JMC manual, "Homing mode" and "Diagram of homing
//! operation", methods 0–12; 0x6098, 0x6099, 0x609A, 0x607C).
//!
//! How the manual's sentences are read (left is towards the CW limit
//! switch, see [`crate::profiles::jmc::Direction`]):
//!
//! - 0: no movement; where the shaft stands is the origin.
//! - 1, 2: run left (right) at the search speed 0x6099:1 and stop on the
//!   CW (CCW) limit switch.
//! - 3, 4: run left (right) at the search speed; stop on the origin switch;
//!   if the limit switch comes first, brake and run back the other way,
//!   stopping on the origin switch (a second limit switch: homing error).
//! - 5, 6 (9, 10): fast left (right) at 0x6099:1 to the limit switch, brake,
//!   leave the switch the other way at the slow speed 0x6099:2, come back to
//!   it at the slow speed and stop on its edge.
//! - 7, 8 (11, 12): fast left (right) to the origin switch, turning back
//!   fast at the limit switch if need be; brake, leave the origin switch
//!   rightwards (leftwards) at the slow speed, come back and stop on its
//!   edge.
//! - 9–12 then run the home offset 0x607C (signed, positive to the right)
//!   from that edge at the slow speed; the others ignore it ("This mode can
//!   set positive and negative homing offset" is said of 9–12 only).
//!
//! Where the run ends, the position counter is set to 0 ("after finding
//! the mechanical origin, all the parameters will be cleared after a short
//! distance": 0x607C). Speeds are capped at 300 r/min for 1–4 and 1200
//! r/min for the others; every ramp uses the homing acceleration 0x609A.
//! The single-speed methods and the slow approaches stop dead on the
//! switch edge, as a stepper does at those speeds.

use crate::profiles::jmc::{Direction, HomeSwitch, HomingMethod, units};

use super::axis::{Axis, INSTANT};
use super::switches::{LimitSwitches, Switch};

/// What a tick of the run came to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HomingOutcome {
    Running,
    /// Done: the shaft stands at `zero` (machine steps), the new position 0.
    Homed {
        zero: f64,
    },
    /// Statusword bit 13: a limit switch where the method allows none.
    Failed,
}

/// What follows a brake.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum AfterBrake {
    SearchBack,
    Leave,
    Fail,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    /// At the search speed, towards `direction`; `back` once turned back
    /// by the limit switch.
    Search { direction: Direction, back: bool },
    /// Down to standstill on the homing acceleration.
    Brake { then: AfterBrake },
    /// Slowly off the home switch, against the method's direction, until
    /// past it (the brake may have carried the shaft past it already).
    Leave,
    /// Slowly back onto the home switch, in the method's direction.
    Return,
    /// Methods 9–12: the home offset.
    Offset { target: f64 },
}

/// The parameters of one run, in steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HomingParameters {
    pub method: HomingMethod,
    /// 0x6099:1, 0.1 rps.
    pub search_speed: u32,
    /// 0x6099:2, 0.1 rps.
    pub slow_speed: u32,
    /// 0x609A, 0.1 rps/s (0: no ramp).
    pub acceleration: u16,
    /// 0x607C, steps.
    pub home_offset: i32,
    pub steps_per_rev: u32,
}

/// One homing run, from bit 4's 0→1 edge to its outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct HomingRun {
    method: HomingMethod,
    home: Switch,
    /// Steps/s.
    fast: f64,
    slow: f64,
    /// Steps/s².
    accel: f64,
    /// Steps; 0 for the methods that do not run it.
    offset: f64,
    phase: Phase,
}

impl HomingRun {
    pub fn new(parameters: HomingParameters) -> Self {
        let method = parameters.method;
        let speed = |raw: u32| {
            units::velocity_to_steps_per_s(
                i64::from(raw.min(method.max_speed())),
                parameters.steps_per_rev,
            )
        };
        let accel = match parameters.acceleration {
            0 => INSTANT,
            raw => units::acceleration_to_steps_per_s2(u32::from(raw), parameters.steps_per_rev),
        };
        let home = match method.home_switch() {
            HomeSwitch::Limit => Switch::limit_towards(method.direction()),
            HomeSwitch::Origin => Switch::Origin,
        };
        HomingRun {
            method,
            home,
            fast: speed(parameters.search_speed),
            slow: speed(parameters.slow_speed),
            accel,
            offset: if method.uses_home_offset() {
                f64::from(parameters.home_offset)
            } else {
                0.0
            },
            phase: Phase::Search {
                direction: method.direction(),
                back: false,
            },
        }
    }

    pub fn method(&self) -> HomingMethod {
        self.method
    }

    /// The homing acceleration in steps/s², for a stop that ends the run.
    pub fn acceleration(&self) -> f64 {
        self.accel
    }

    /// One millisecond of the run.
    pub fn tick(&mut self, axis: &mut Axis, switches: &LimitSwitches) -> HomingOutcome {
        if !self.method.moves() {
            axis.stop();
            return HomingOutcome::Homed {
                zero: axis.position,
            };
        }
        match self.phase {
            Phase::Search { direction, back } => self.search(axis, switches, direction, back),
            Phase::Brake { then } => {
                axis.ramp_velocity(0.0, self.accel, self.accel);
                if axis.velocity == 0.0 {
                    self.phase = match then {
                        AfterBrake::SearchBack => Phase::Search {
                            direction: self.method.direction().opposite(),
                            back: true,
                        },
                        AfterBrake::Leave => Phase::Leave,
                        AfterBrake::Fail => return HomingOutcome::Failed,
                    };
                }
                HomingOutcome::Running
            }
            Phase::Leave => {
                let direction = self.method.direction().opposite();
                axis.ramp_velocity(direction.sign() * self.slow, self.accel, self.accel);
                if switches.is_past(self.home, direction, axis.position) {
                    // Off the switch: turn back at once at the slow speed.
                    axis.stop();
                    self.phase = Phase::Return;
                } else if self.limit_in_the_way(axis, switches, direction) {
                    self.phase = Phase::Brake {
                        then: AfterBrake::Fail,
                    };
                }
                HomingOutcome::Running
            }
            Phase::Return => {
                let direction = self.method.direction();
                let before =
                    axis.ramp_velocity(direction.sign() * self.slow, self.accel, self.accel);
                if let Some(origin) = self.stop_on_home(axis, switches, before) {
                    return self.found(axis, origin);
                }
                if self.limit_in_the_way(axis, switches, direction) {
                    self.phase = Phase::Brake {
                        then: AfterBrake::Fail,
                    };
                }
                HomingOutcome::Running
            }
            Phase::Offset { target } => {
                if axis.move_to(target, self.slow, 0.0, self.accel, self.accel) {
                    HomingOutcome::Homed { zero: target }
                } else {
                    HomingOutcome::Running
                }
            }
        }
    }

    fn search(
        &mut self,
        axis: &mut Axis,
        switches: &LimitSwitches,
        direction: Direction,
        back: bool,
    ) -> HomingOutcome {
        let before = axis.ramp_velocity(direction.sign() * self.fast, self.accel, self.accel);
        if self.method.two_speeds() {
            let reached = switches.is_on(self.home, axis.position)
                || switches.reached(self.home, before, axis.position).is_some();
            if reached {
                self.phase = Phase::Brake {
                    then: AfterBrake::Leave,
                };
                return HomingOutcome::Running;
            }
        } else if let Some(origin) = self.stop_on_home(axis, switches, before) {
            return self.found(axis, origin);
        }
        if self.limit_in_the_way(axis, switches, direction) {
            self.phase = Phase::Brake {
                then: if self.method.reverses_at_limit() && !back {
                    AfterBrake::SearchBack
                } else {
                    AfterBrake::Fail
                },
            };
        }
        HomingOutcome::Running
    }

    /// The home switch on at `before` (stay there) or reached on the way
    /// (back to its edge): the shaft stops dead there.
    fn stop_on_home(&self, axis: &mut Axis, switches: &LimitSwitches, before: f64) -> Option<f64> {
        let at = if switches.is_on(self.home, before) {
            before
        } else {
            switches.reached(self.home, before, axis.position)?
        };
        axis.position = at;
        axis.stop();
        Some(at)
    }

    /// A limit switch other than the home switch is on ahead.
    fn limit_in_the_way(
        &self,
        axis: &Axis,
        switches: &LimitSwitches,
        direction: Direction,
    ) -> bool {
        let limit = Switch::limit_towards(direction);
        limit != self.home && switches.is_on(limit, axis.position)
    }

    fn found(&mut self, axis: &Axis, origin: f64) -> HomingOutcome {
        if self.offset == 0.0 {
            return HomingOutcome::Homed {
                zero: axis.position,
            };
        }
        self.phase = Phase::Offset {
            target: origin + self.offset,
        };
        HomingOutcome::Running
    }
}
