//! Interpolated position (UMC manual chapter 2 §6): the FIFO of §6.1.5 fed
//! through 0x60C1, reported and cleared through 0x60C4, and the linear
//! interpolation of §6.1.4 at the period of 0x60C2.
//!
//! §6.1.5: "The buffer size is 32 items. When the buffer is empty, the
//! device keeps the last set point. [...] When the buffer is full, the new
//! positions are rejected." An SDO download into a full buffer is refused
//! (abort 0x08000022, the buffer's state forbids it); a set-point an RPDO
//! brings is dropped, as a PDO has no answer.

use super::trajectory::Sample;

/// 0x60C4.1 Maximum_buffer_size.
pub const BUFFER_SIZE: usize = 32;

/// The FIFO and the interpolator of one axis.
#[derive(Debug, Clone, PartialEq)]
pub struct Interpolator {
    buffer: [i32; BUFFER_SIZE],
    head: usize,
    len: usize,
    /// Interpolation active (statusword bit 12).
    active: bool,
    /// ms per set-point, fixed at activation (§6.2.7 note).
    period: f64,
    /// Time into the present segment, ms.
    phase: f64,
    from: f64,
    to: f64,
}

impl Default for Interpolator {
    fn default() -> Self {
        Interpolator {
            buffer: [0; BUFFER_SIZE],
            head: 0,
            len: 0,
            active: false,
            period: 1.0,
            phase: 0.0,
            from: 0.0,
            to: 0.0,
        }
    }
}

impl Interpolator {
    /// 0x60C4.2 Actual_buffer_size.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn is_full(&self) -> bool {
        self.len == BUFFER_SIZE
    }

    pub fn active(&self) -> bool {
        self.active
    }

    /// A set-point from 0x60C1.1; false if the buffer is full and it was
    /// rejected.
    pub fn push(&mut self, set_point: i32) -> bool {
        if self.is_full() {
            return false;
        }
        self.buffer[(self.head + self.len) % BUFFER_SIZE] = set_point;
        self.len += 1;
        true
    }

    fn pop(&mut self) -> Option<i32> {
        if self.len == 0 {
            return None;
        }
        let value = self.buffer[self.head];
        self.head = (self.head + 1) % BUFFER_SIZE;
        self.len -= 1;
        Some(value)
    }

    /// 0x60C4.6 written 0, or the transition to interpolation inactive.
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }

    /// Interpolation active from `position`, a set-point taken each
    /// `period` ms; the first at once.
    pub fn activate(&mut self, position: f64, period: f64) {
        self.active = true;
        self.period = period.max(1.0);
        self.from = position;
        self.to = position;
        // The first step takes the first set-point.
        self.phase = self.period - 1.0;
    }

    /// Interpolation inactive: the buffer is cleared (Figure 2.34).
    pub fn deactivate(&mut self) {
        self.active = false;
        self.clear();
    }

    /// After a halt: the segment under way starts again from `position`.
    pub fn resume(&mut self, position: f64) {
        self.from = position;
        self.phase = 0.0;
    }

    /// One millisecond of interpolation.
    pub fn step(&mut self) -> Sample {
        self.phase += 1.0;
        if self.phase >= self.period {
            self.phase -= self.period;
            self.from = self.to;
            if let Some(next) = self.pop() {
                self.to = f64::from(next);
            }
        }
        let velocity = (self.to - self.from) / self.period;
        Sample {
            position: self.from + velocity * self.phase,
            velocity,
            acceleration: 0.0,
        }
    }

    /// The last set-point taken: where the axis stays once the buffer is
    /// empty.
    pub fn last_point(&self) -> f64 {
        self.to
    }

    /// Nothing left: the buffer is empty and the last segment is run.
    pub fn finished(&self) -> bool {
        self.len == 0 && self.from == self.to
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_buffer_holds_32_set_points_and_rejects_the_33rd() {
        let mut ip = Interpolator::default();
        for n in 0..32 {
            assert!(ip.push(n));
        }
        assert!(ip.is_full());
        assert!(!ip.push(99));
        assert_eq!(ip.len(), 32);
        ip.clear();
        assert!(ip.is_empty());
    }

    #[test]
    fn set_points_are_interpolated_linearly_over_the_period() {
        let mut ip = Interpolator::default();
        ip.push(400);
        ip.push(800);
        ip.activate(0.0, 4.0);
        // The first set-point is taken at once: 0 → 400 over 4 ms.
        let samples: Vec<f64> = (0..8).map(|_| ip.step().position).collect();
        assert_eq!(
            samples,
            [0.0, 100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0]
        );
        assert_eq!(ip.step().position, 800.0);
        // Empty: the last set-point is kept.
        for _ in 0..10 {
            let sample = ip.step();
            assert_eq!(sample.position, 800.0);
            assert_eq!(sample.velocity, 0.0);
        }
        assert!(ip.finished());
    }
}
