//! Position mode (JMC manual, "Position mode" and "The bit of control
//! word"): set points taken on the 0→1 edge of controlword bit 4, one
//! running and one waiting, with the JMC's bits 5 (at once), 6 (relative)
//! and 9 (no stop between two points).
//!
//! Statusword bit 12 follows CiA 402's set-point handshake, which is how
//! the manual's own routines use it (bit 4 set: "sampling new position",
//! bit 4 cleared: "clear the flag"): 1 once a set point is taken; back to 0
//! when bit 4 is 0 and there is room for the next one. While it is 1 no
//! new set point is taken.

use super::axis::Axis;

/// A set point as it was taken: everything in steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SetPoint {
    /// Target in the drive's position counter.
    pub target: i64,
    /// Steps/s, > 0 to move at all.
    pub speed: f64,
    /// Steps/s².
    pub accel: f64,
    pub decel: f64,
    /// Controlword bit 9 when it was taken: the running point is passed
    /// through at its own speed instead of stopped at.
    pub no_stop_before: bool,
}

/// The set points of position mode.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SetPoints {
    running: Option<SetPoint>,
    waiting: Option<SetPoint>,
    /// Statusword bit 12.
    acknowledged: bool,
    /// The last target taken, the base of a relative one.
    last_target: i64,
    /// The running set point ended on its target (statusword bit 10 once
    /// the shaft stands).
    reached: bool,
}

/// The JMC bits of the controlword that shape a set point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SetPointBits {
    /// Bit 5.
    pub immediately: bool,
    /// Bit 6.
    pub relative: bool,
    /// Bit 9.
    pub no_stop: bool,
}

impl SetPoints {
    /// None running, the shaft counted at `position`: operation enabled,
    /// a new mode, a homing run ended.
    pub fn reset(&mut self, position: i64) {
        *self = SetPoints {
            last_target: position,
            reached: true,
            ..SetPoints::default()
        };
    }

    /// Forgets the motion (a stop, a limit switch), keeping the base of
    /// relative set points; the target is not reached.
    pub fn abandon(&mut self) {
        if self.running.is_some() {
            self.reached = false;
        }
        self.running = None;
        self.waiting = None;
        self.acknowledged = false;
    }

    pub fn acknowledged(&self) -> bool {
        self.acknowledged
    }

    pub fn reached(&self) -> bool {
        self.reached
    }

    /// Something to run.
    pub fn is_running(&self) -> bool {
        self.running.is_some()
    }

    /// The 0→1 edge of bit 4: takes 0x607A as `value` (with the speed and
    /// ramps already in steps) unless bit 12 is still set or both places
    /// are taken. Returns whether it was taken.
    pub fn sample(&mut self, value: i32, bits: SetPointBits, mut set_point: SetPoint) -> bool {
        if self.acknowledged || self.waiting.is_some() && !bits.immediately {
            return false;
        }
        let base = if bits.relative { self.last_target } else { 0 };
        set_point.target =
            (base + i64::from(value)).clamp(i64::from(i32::MIN), i64::from(i32::MAX));
        set_point.no_stop_before = bits.no_stop;
        self.last_target = set_point.target;
        self.acknowledged = true;
        self.reached = false;
        if bits.immediately || self.running.is_none() {
            self.running = Some(set_point);
            self.waiting = None;
        } else {
            self.waiting = Some(set_point);
        }
        true
    }

    /// The 1→0 edge of bit 4 (and bit 4 low when a waiting point starts).
    pub fn bit4_cleared(&mut self) {
        if self.waiting.is_none() {
            self.acknowledged = false;
        }
    }

    /// One tick towards the running set point; `zero` is the machine
    /// position of the counter's 0 and `bit4` the controlword's bit 4 now.
    /// Returns false when there is nothing to run.
    pub fn tick(&mut self, axis: &mut Axis, zero: f64, bit4: bool) -> bool {
        let Some(running) = self.running else {
            return false;
        };
        let target = running.target as f64 + zero;
        let end_speed = match self.waiting {
            Some(next) if next.no_stop_before => {
                let heading = (target - axis.position).signum();
                let onwards = (next.target - running.target).signum() as f64;
                if heading == onwards {
                    running.speed
                } else {
                    0.0
                }
            }
            _ => 0.0,
        };
        if axis.move_to(
            target,
            running.speed,
            end_speed,
            running.accel,
            running.decel,
        ) {
            self.running = self.waiting.take();
            match self.running {
                Some(_) if !bit4 => self.acknowledged = false,
                Some(_) => {}
                None => self.reached = true,
            }
        }
        true
    }
}
