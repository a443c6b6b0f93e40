//! One PID of the UMC's cascaded control loops (UMC manual chapter 1
//! §3.5.2 status, §3.5.3 configuration), computed as the firmware's
//! description of its configuration reads:
//!
//! - the error is `input − measured`, and an error within ±Threshold
//!   counts as none (a dead band);
//! - the loop runs once every Frequency_divider board cycles and holds its
//!   output in between; its time step is the divider times the cycle;
//! - `output = P·e + Σ I·e·dt + D·Δe/dt`, clamped to Min..Max;
//! - the integrator stops growing while the output is clamped in the
//!   direction it would grow (no wind-up) and is itself kept in Min..Max;
//! - ANTI_REVERSE: an output whose sign differs from the input's (the
//!   loop's target) is cut to 0.
//!
//! The status shows Input, Error, the integrator (the I term, in output
//! units) and Output.

use crate::profiles::umc::pid::PidConfig;

#[cfg(test)]
mod tests;

/// The state of one loop.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pid {
    pub input: f64,
    pub error: f64,
    pub integrator: f64,
    pub output: f64,
    /// The error of the last run, for D; `None` before the first.
    last_error: Option<f64>,
    /// Board cycles since the last run.
    cycles: u16,
}

impl Pid {
    /// Forgets everything (operation enabled: every internal set-point
    /// cleared).
    pub fn reset(&mut self) {
        *self = Pid::default();
    }

    /// One board cycle of `cycle_s` seconds: `input` is the loop's target,
    /// `measured` what its sensor says. The output (held between runs).
    pub fn step(&mut self, config: &PidConfig, input: f64, measured: f64, cycle_s: f64) -> f64 {
        let divider = config.frequency_divider.max(1);
        self.cycles = self.cycles.saturating_add(1);
        if self.last_error.is_some() && self.cycles < divider {
            return self.output;
        }
        self.cycles = 0;
        let dt = cycle_s * f64::from(divider);
        let raw = input - measured;
        let error = if raw.abs() <= config.threshold.abs() {
            0.0
        } else {
            raw
        };
        let (low, high) = if config.min <= config.max {
            (config.min, config.max)
        } else {
            (config.max, config.min)
        };
        let derivative = match self.last_error {
            Some(last) if dt > 0.0 => config.d * (error - last) / dt,
            _ => 0.0,
        };
        let proportional = config.p * error;
        let growth = config.i * error * dt;
        let unclamped = proportional + self.integrator + growth + derivative;
        // Conditional integration: no wind-up against a limit.
        let winding = (unclamped > high && growth > 0.0) || (unclamped < low && growth < 0.0);
        if !winding {
            self.integrator = (self.integrator + growth).clamp(low, high);
        }
        let mut output = (proportional + self.integrator + derivative).clamp(low, high);
        if config.anti_reverse()
            && input != 0.0
            && output != 0.0
            && output.signum() != input.signum()
        {
            output = 0.0;
        }
        self.input = input;
        self.error = error;
        self.output = output;
        self.last_error = Some(error);
        output
    }

    /// Sets the integrator (a bumpless start from a known output).
    pub fn preset(&mut self, integrator: f64) {
        self.integrator = integrator;
    }
}
