//! The set-point generators of the modes of operation (UMC manual chapter
//! 2): duty cycle (§2, DTY), torque (§3, TQ), velocity (§4, VL), profile
//! position (§5, PP) and continuous position (§7, CP). Interpolated
//! position (§6) is in [`super::ip`].
//!
//! Each generator turns its targets and the controlword's mode bits into a
//! demand for the control loops; stops asked by the PDS or by halt are the
//! axis's, not the mode's (except in VL, whose ramp brings the halt).

use super::params::Params;
use super::trajectory::{Limits, Profile, Sample};

/// Controlword bit 4: PP new set-point, VL enable ramp, IP enable
/// interpolation, DTY slope.
pub const CW_BIT4: u16 = 1 << 4;
/// Controlword bit 5: PP change set immediately, VL unlock ramp.
pub const CW_BIT5: u16 = 1 << 5;
/// Controlword bit 6: PP and CP relative, VL use reference.
pub const CW_BIT6: u16 = 1 << 6;

/// What the control loops are asked to do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Demand {
    /// Follow a position, with its velocity and acceleration as
    /// feed-forward (increments, /ms, /ms²).
    Position(Sample),
    /// Follow a velocity (increments/ms) and its acceleration.
    Velocity { velocity: f64, acceleration: f64 },
    /// Hold a current, A.
    Current(f64),
    /// Apply a duty cycle, −1 to 1.
    Duty(f64),
}

/// Profile position (§5): the set-point handshake of §5.1.2 and the
/// trapezoid of §5.1.3.
#[derive(Debug, Clone, PartialEq)]
pub struct ProfilePosition {
    profile: Profile,
    /// The set-point being processed.
    target: Option<f64>,
    /// Set of set-points: the one that follows.
    pending: Option<f64>,
    /// The new set-point bit that was accepted is still high.
    accepted_bit: bool,
    /// Bit 4 as last written, for its edge.
    new_set_point: bool,
}

impl ProfilePosition {
    /// At rest at `position`, nothing to do.
    pub fn new(position: f64) -> Self {
        ProfilePosition {
            profile: Profile::rest(position),
            target: None,
            pending: None,
            accepted_bit: false,
            new_set_point: false,
        }
    }

    /// A controlword in operation enabled; `target` is 0x607A, `from` the
    /// demand now (position, velocity).
    pub fn controlword(&mut self, controlword: u16, target: f64, from: Sample, params: &Params) {
        let bit = controlword & CW_BIT4 != 0;
        let rising = bit && !self.new_set_point;
        self.new_set_point = bit;
        if !bit {
            self.accepted_bit = false;
        }
        if !rising {
            return;
        }
        let immediately = controlword & CW_BIT5 != 0;
        let relative = controlword & CW_BIT6 != 0;
        let busy = self.target.is_some() && !self.profile.done();
        if immediately || !busy {
            // 6062 is where a relative set-point counts from.
            let base = if relative { from.position } else { 0.0 };
            let target = params.limit_position(base + target);
            self.start(target, from, params);
            self.pending = None;
            self.accepted_bit = true;
        } else if self.pending.is_none() {
            // Counted from where the set-point before it ends.
            let base = if relative { self.profile.end() } else { 0.0 };
            self.pending = Some(params.limit_position(base + target));
            self.accepted_bit = true;
        }
        // A third set-point while one waits is not taken: the
        // acknowledge bit is still high.
    }

    fn start(&mut self, target: f64, from: Sample, params: &Params) {
        self.target = Some(target);
        self.profile = Profile::to_target(from.position, from.velocity, target, limits(params));
    }

    /// After a halt or a stop: carry on towards the set-point from `from`.
    pub fn resume(&mut self, from: Sample, params: &Params) {
        match self.target {
            Some(target) => self.start(target, from, params),
            None => self.profile = Profile::rest(from.position),
        }
    }

    /// One millisecond of the trajectory.
    pub fn step(&mut self, params: &Params) -> Sample {
        let sample = self.profile.step();
        if self.profile.done()
            && let Some(next) = self.pending.take()
        {
            self.start(next, sample, params);
        }
        sample
    }

    /// Statusword bit 12, set-point acknowledge.
    pub fn acknowledge(&self) -> bool {
        self.accepted_bit || self.pending.is_some()
    }

    /// The trajectory has arrived and no set-point waits.
    pub fn arrived(&self) -> bool {
        self.profile.done() && self.pending.is_none()
    }

    /// Where the present set-point leads.
    pub fn end(&self) -> f64 {
        self.profile.end()
    }
}

/// Continuous position (§7): every new 0x41F0 is processed at once.
#[derive(Debug, Clone, PartialEq)]
pub struct ContinuousPosition {
    profile: Profile,
}

impl ContinuousPosition {
    pub fn new(position: f64) -> Self {
        ContinuousPosition {
            profile: Profile::rest(position),
        }
    }

    /// 0x41F0 was written: `relative` is controlword bit 6.
    pub fn target(&mut self, target: f64, relative: bool, from: Sample, params: &Params) {
        let base = if relative { from.position } else { 0.0 };
        let target = params.limit_position(base + target);
        self.profile = Profile::to_target(from.position, from.velocity, target, limits(params));
    }

    pub fn resume(&mut self, from: Sample, params: &Params) {
        let target = self.profile.end();
        self.profile = Profile::to_target(from.position, from.velocity, target, limits(params));
    }

    pub fn step(&mut self) -> Sample {
        self.profile.step()
    }

    pub fn arrived(&self) -> bool {
        self.profile.done()
    }

    pub fn end(&self) -> f64 {
        self.profile.end()
    }
}

fn limits(params: &Params) -> Limits {
    Limits {
        velocity: params.profile_velocity,
        acceleration: params.profile_acceleration,
        deceleration: params.profile_deceleration,
    }
}

/// Velocity (§4): factor, limit and ramp functions of Figures 2.15–2.19,
/// with the controlword priorities of Table 2.28.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VelocityMode {
    /// The ramp's output, in set-point units (after 0x604B).
    pub output: f64,
    /// The reference after the limit function.
    pub reference: f64,
    /// The limit function changed the target (statusword bit 11).
    pub limited: bool,
}

impl VelocityMode {
    /// One millisecond: `target` is 0x6042, `halt` the deceleration of the
    /// halt option (set-point units per ms) while bit 8 is high.
    pub fn step(
        &mut self,
        controlword: u16,
        target: f64,
        halt: Option<f64>,
        params: &Params,
    ) -> f64 {
        let scaled = target * params.vl_set_point_factor;
        let magnitude = scaled.abs();
        let limited_magnitude = if magnitude == 0.0 {
            0.0
        } else {
            magnitude.clamp(params.vl_min.min(params.vl_max), params.vl_max)
        };
        self.limited = limited_magnitude != magnitude;
        self.reference = limited_magnitude.copysign(scaled);
        let enable = controlword & CW_BIT4 != 0;
        let unlock = controlword & CW_BIT5 != 0;
        let use_reference = controlword & CW_BIT6 != 0;
        if let Some(deceleration) = halt {
            self.output = ramp(self.output, 0.0, deceleration, deceleration);
        } else if !enable {
            // The ramp is disabled: its output is its input.
            self.output = self.reference;
        } else if !unlock {
            // Locked: the output holds.
        } else if !use_reference {
            self.output = ramp(
                self.output,
                0.0,
                params.vl_acceleration,
                params.vl_deceleration,
            );
        } else {
            self.output = ramp(
                self.output,
                self.reference,
                params.vl_acceleration,
                params.vl_deceleration,
            );
        }
        self.output
    }

    /// The internal velocity (increments/ms) of a set-point-unit value.
    pub fn internal(value: f64, params: &Params) -> f64 {
        value * params.vl_dimension_factor
    }

    /// A velocity in increments/ms in the user's units (the reverse factor
    /// functions, Figure 2.18).
    pub fn user(internal: f64, params: &Params) -> f64 {
        let factor = params.vl_dimension_factor * params.vl_set_point_factor;
        if factor != 0.0 {
            internal / factor
        } else {
            0.0
        }
    }
}

/// Moves `from` towards `to` by at most `acceleration` when the magnitude
/// grows and `deceleration` when it shrinks.
pub fn ramp(from: f64, to: f64, acceleration: f64, deceleration: f64) -> f64 {
    let speeding_up = to.abs() > from.abs() && (from == 0.0 || to.signum() == from.signum());
    let rate = if speeding_up {
        acceleration
    } else {
        deceleration
    };
    from + (to - from).clamp(-rate, rate)
}

/// Torque (§3): the target, limited by 0x6072, ramped by 0x6087.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TorqueMode {
    /// 0x6074, per mille of rated torque.
    pub demand: f64,
    /// The target was above 0x6072 (statusword bit 11).
    pub limited: bool,
}

impl TorqueMode {
    /// One millisecond towards `target` (0x6071); the current to hold.
    pub fn step(&mut self, target: f64, params: &Params) -> f64 {
        let limited = target.clamp(-params.max_torque, params.max_torque);
        self.limited = limited != target;
        let slope = params.torque_slope;
        self.demand += (limited - self.demand).clamp(-slope, slope);
        self.demand / 1000.0 * params.rated_current
    }
}

/// Duty cycle (§2): 0x41FA limited by 0x41FC, ramped by 0x41FD when
/// controlword bit 4 asks.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DutyMode {
    /// 0x41FB, ±32768 for ±100 %.
    pub demand: f64,
}

/// Full duty in 0x41FA, 0x41FB and 0x4006.1.
pub const FULL_DUTY: f64 = 32768.0;

impl DutyMode {
    /// One millisecond; the duty cycle, −1 to 1.
    pub fn step(&mut self, controlword: u16, target: f64, params: &Params) -> f64 {
        let limited = target.clamp(-params.dty_max, params.dty_max);
        if controlword & CW_BIT4 != 0 {
            let slope = params.dty_slope;
            self.demand += (limited - self.demand).clamp(-slope, slope);
        } else {
            self.demand = limited;
        }
        (self.demand / FULL_DUTY).clamp(-1.0, 1.0)
    }
}
