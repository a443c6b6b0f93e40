//! The motor shaft and its profile generator (JMC manual, "Position mode"
//! and "Velocity mode": target speed, acceleration, deceleration): one
//! millisecond at a time, trapezoidal ramps, positions in steps.
//!
//! Rates are in steps/s and steps/s²; a rate of [`INSTANT`] changes the
//! speed at once (an acceleration object left at 0: the drive cannot be
//! meant to never move).

/// A ramp rate that changes the speed within one tick.
pub const INSTANT: f64 = f64::INFINITY;

/// The simulation step in seconds.
pub const DT: f64 = 0.001;

/// Where the shaft is and how fast it turns, in the machine's frame (steps
/// since power-on of the simulation, not the drive's position counter).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Axis {
    /// Steps.
    pub position: f64,
    /// Steps per second, signed.
    pub velocity: f64,
}

/// `value` moved towards `goal` by at most `step`.
fn approach(value: f64, goal: f64, step: f64) -> f64 {
    if (goal - value).abs() <= step {
        goal
    } else if goal > value {
        value + step
    } else {
        value - step
    }
}

impl Axis {
    /// Stops dead (a stepper whose pulses stop, or a motor without current).
    pub fn stop(&mut self) {
        self.velocity = 0.0;
    }

    /// One tick of a speed ramp towards `target` (signed): `accel` while the
    /// speed grows in the direction of `target`, `decel` while it shrinks
    /// (reversing goes through 0 on `decel`). Returns where the shaft was
    /// before the tick.
    pub fn ramp_velocity(&mut self, target: f64, accel: f64, decel: f64) -> f64 {
        let v = self.velocity;
        let speeding_up =
            target != 0.0 && (v == 0.0 || v.signum() == target.signum()) && target.abs() > v.abs();
        let next = if speeding_up {
            approach(v, target, accel * DT)
        } else if v != 0.0 && target != 0.0 && v.signum() != target.signum() {
            approach(v, 0.0, decel * DT)
        } else {
            approach(v, target, decel * DT)
        };
        let before = self.position;
        self.velocity = next;
        self.position += next * DT;
        before
    }

    /// One tick of a point-to-point run to `target` at up to `speed`
    /// (> 0), arriving at `end_speed` (≥ 0, in the direction of travel: more
    /// than 0 to pass through without stopping). Returns true on arrival:
    /// the shaft is on `target` exactly. A target closer than the braking
    /// distance is overrun on the ramp and come back to, as a drive whose
    /// ramps are limits does.
    pub fn move_to(
        &mut self,
        target: f64,
        speed: f64,
        end_speed: f64,
        accel: f64,
        decel: f64,
    ) -> bool {
        let distance = target - self.position;
        if distance == 0.0 && (end_speed > 0.0 || self.velocity == 0.0) {
            return true;
        }
        let direction = if distance == 0.0 {
            -self.velocity.signum()
        } else {
            distance.signum()
        };
        let along = self.velocity * direction;
        if along < 0.0 {
            // Moving away (an overrun, or a new target behind): brake first.
            self.velocity = approach(self.velocity, 0.0, decel * DT);
            self.position += self.velocity * DT;
            return false;
        }
        let remaining = distance.abs();
        let end_speed = end_speed.min(speed);
        let braking_limit = if decel.is_infinite() {
            f64::INFINITY
        } else {
            (end_speed * end_speed + 2.0 * decel * remaining).sqrt()
        };
        let desired = speed.min(braking_limit);
        let next = if desired >= along {
            approach(along, desired, accel * DT)
        } else {
            approach(along, desired, decel * DT)
        };
        if next * DT >= remaining {
            // Within reach this tick: on the target, if the ramp allows
            // stopping (or passing) there. The discrete ramp may be one
            // tick's deceleration above the continuous one.
            let stoppable = decel.is_infinite() || next <= braking_limit + decel * DT;
            if end_speed > 0.0 || stoppable {
                self.position = target;
                self.velocity = direction * if end_speed > 0.0 { next } else { 0.0 };
                return true;
            }
        }
        self.velocity = direction * next;
        self.position += self.velocity * DT;
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_to(axis: &mut Axis, target: f64, speed: f64, accel: f64) -> u32 {
        let mut ticks = 0;
        while !axis.move_to(target, speed, 0.0, accel, accel) {
            ticks += 1;
            assert!(ticks < 1_000_000, "never arrives: {axis:?}");
        }
        ticks
    }

    #[test]
    fn a_trapezoid_lands_on_its_target_in_the_expected_time() {
        let mut axis = Axis::default();
        // 10 000 steps/s, 1e6 steps/s²: 10 ms ramps, 200 000 steps.
        let ticks = run_to(&mut axis, 200_000.0, 10_000.0, 1_000_000.0);
        assert_eq!(axis.position, 200_000.0);
        assert_eq!(axis.velocity, 0.0);
        // 20 s at speed plus one ramp's worth.
        assert!((20_005..=20_015).contains(&ticks), "{ticks}");
    }

    #[test]
    fn the_speed_never_exceeds_the_profile_and_ramps_are_kept() {
        let mut axis = Axis::default();
        let mut previous = 0.0;
        for _ in 0..2_000 {
            axis.move_to(-5_000.0, 8_000.0, 0.0, 100_000.0, 100_000.0);
            assert!(axis.velocity.abs() <= 8_000.0);
            // One tick's ramp, plus the last tick's landing.
            assert!((axis.velocity - previous).abs() <= 100.0 * 2.0 + 1e-9);
            previous = axis.velocity;
        }
        assert_eq!(axis.position, -5_000.0);
    }

    #[test]
    fn an_instant_ramp_jumps_to_speed() {
        let mut axis = Axis::default();
        axis.move_to(1_000.0, 10_000.0, 0.0, INSTANT, INSTANT);
        assert_eq!(axis.velocity, 10_000.0);
        assert_eq!(axis.position, 10.0);
        assert_eq!(run_to(&mut axis, 1_000.0, 10_000.0, INSTANT), 98);
    }

    #[test]
    fn a_target_behind_the_braking_distance_is_overrun_and_reached() {
        let mut axis = Axis {
            position: 0.0,
            velocity: 10_000.0,
        };
        // Braking from 10 000 steps/s at 1e5 steps/s² takes 500 steps.
        let mut furthest: f64 = 0.0;
        let mut ticks = 0;
        while !axis.move_to(100.0, 10_000.0, 0.0, 100_000.0, 100_000.0) {
            furthest = furthest.max(axis.position);
            ticks += 1;
            assert!(ticks < 100_000);
        }
        assert!(furthest > 400.0, "{furthest}");
        assert_eq!(axis.position, 100.0);
    }

    #[test]
    fn passing_through_keeps_the_speed() {
        let mut axis = Axis::default();
        while !axis.move_to(50_000.0, 20_000.0, 20_000.0, 1_000_000.0, 1_000_000.0) {}
        assert_eq!(axis.position, 50_000.0);
        assert_eq!(axis.velocity, 20_000.0);
    }

    #[test]
    fn velocity_ramps_accelerate_and_decelerate_at_their_rates() {
        let mut axis = Axis::default();
        axis.ramp_velocity(1_000.0, 100_000.0, 50_000.0);
        assert_eq!(axis.velocity, 100.0);
        for _ in 0..20 {
            axis.ramp_velocity(1_000.0, 100_000.0, 50_000.0);
        }
        assert_eq!(axis.velocity, 1_000.0);
        // Reversing brakes on the deceleration through 0.
        axis.ramp_velocity(-1_000.0, 100_000.0, 50_000.0);
        assert_eq!(axis.velocity, 950.0);
        for _ in 0..19 {
            axis.ramp_velocity(-1_000.0, 100_000.0, 50_000.0);
        }
        assert_eq!(axis.velocity, 0.0);
        axis.ramp_velocity(-1_000.0, 100_000.0, 50_000.0);
        assert_eq!(axis.velocity, -100.0);
    }
}
