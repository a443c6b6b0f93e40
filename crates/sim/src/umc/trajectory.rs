//! The trajectory generator of the position modes (UMC manual chapter 2
//! §5.1.3 "Trajectory generator", Figure 2.29, and §7.1.3, Figure 2.40):
//! a linear ramp, i.e. a trapezoidal velocity profile, planned in continuous
//! time and sampled once per millisecond.
//!
//! Planning in closed form (rather than stepping a rate limiter) means the
//! sampled demand never exceeds the profile velocity and never changes
//! velocity faster than the acceleration or deceleration, and lands on the
//! target exactly. A profile may start from any velocity (a set-point
//! changed immediately, a move resumed after halt): it first brakes what
//! must be braked, then runs the trapezoid.
//!
//! Units: positions in increments, velocities in increments/ms,
//! accelerations in increments/ms², time in ms.

/// The limits a profile honours, all positive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    pub velocity: f64,
    pub acceleration: f64,
    pub deceleration: f64,
}

/// One piece of constant acceleration.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Segment {
    /// When it starts, from the start of the profile.
    start: f64,
    duration: f64,
    position: f64,
    velocity: f64,
    acceleration: f64,
}

impl Segment {
    fn at(&self, t: f64) -> (f64, f64) {
        let t = t.clamp(0.0, self.duration);
        (
            self.position + self.velocity * t + 0.5 * self.acceleration * t * t,
            self.velocity + self.acceleration * t,
        )
    }
}

/// The most pieces a profile needs: brake (or slow to the profile
/// velocity), accelerate, cruise, decelerate.
const MAX_SEGMENTS: usize = 4;

/// A planned motion and how far along it the clock is.
#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    segments: [Segment; MAX_SEGMENTS],
    count: usize,
    /// Where the motion ends, at rest.
    end: f64,
    /// Time since the start, ms.
    t: f64,
}

/// One sample of a profile.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sample {
    pub position: f64,
    pub velocity: f64,
    pub acceleration: f64,
}

/// Below this, a velocity is zero (increments/ms).
const AT_REST: f64 = 1e-9;

impl Profile {
    /// At rest at `position`.
    pub fn rest(position: f64) -> Self {
        Profile {
            segments: [Segment::default(); MAX_SEGMENTS],
            count: 0,
            end: position,
            t: 0.0,
        }
    }

    /// From `position` moving at `velocity`, to rest at `target`, within
    /// `limits`.
    pub fn to_target(position: f64, velocity: f64, target: f64, limits: Limits) -> Self {
        let mut builder = Builder::new(position, velocity);
        let limits = Limits {
            velocity: limits.velocity.max(0.0),
            acceleration: positive(limits.acceleration),
            deceleration: positive(limits.deceleration),
        };
        builder.plan(target, limits);
        builder.finish(target)
    }

    /// From `position` moving at `velocity`, to rest braking at
    /// `deceleration`.
    pub fn stop(position: f64, velocity: f64, deceleration: f64) -> Self {
        let mut builder = Builder::new(position, velocity);
        builder.brake(positive(deceleration));
        let end = builder.position;
        builder.finish(end)
    }

    /// Where the motion ends.
    pub fn end(&self) -> f64 {
        self.end
    }

    /// Whether the clock has passed the last segment.
    pub fn done(&self) -> bool {
        self.t >= self.duration()
    }

    fn duration(&self) -> f64 {
        self.segments[..self.count]
            .last()
            .map_or(0.0, |last| last.start + last.duration)
    }

    /// Advances the clock by one millisecond and samples the profile there.
    pub fn step(&mut self) -> Sample {
        self.t += 1.0;
        self.sample()
    }

    /// The profile at the current time.
    pub fn sample(&self) -> Sample {
        for segment in &self.segments[..self.count] {
            if self.t < segment.start + segment.duration {
                let (position, velocity) = segment.at(self.t - segment.start);
                return Sample {
                    position,
                    velocity,
                    acceleration: segment.acceleration,
                };
            }
        }
        Sample {
            position: self.end,
            velocity: 0.0,
            acceleration: 0.0,
        }
    }
}

/// A zero limit would never get anywhere: a drive treats it as the
/// smallest step it can make.
fn positive(value: f64) -> f64 {
    if value > 0.0 { value } else { 1e-6 }
}

struct Builder {
    segments: [Segment; MAX_SEGMENTS],
    count: usize,
    position: f64,
    velocity: f64,
    time: f64,
}

impl Builder {
    fn new(position: f64, velocity: f64) -> Self {
        Builder {
            segments: [Segment::default(); MAX_SEGMENTS],
            count: 0,
            position,
            velocity,
            time: 0.0,
        }
    }

    fn push(&mut self, duration: f64, acceleration: f64) {
        if duration <= 0.0 || self.count == MAX_SEGMENTS {
            return;
        }
        let segment = Segment {
            start: self.time,
            duration,
            position: self.position,
            velocity: self.velocity,
            acceleration,
        };
        let (position, velocity) = segment.at(duration);
        self.segments[self.count] = segment;
        self.count += 1;
        self.position = position;
        self.velocity = velocity;
        self.time += duration;
    }

    /// To rest at `deceleration`.
    fn brake(&mut self, deceleration: f64) {
        let speed = self.velocity.abs();
        if speed > AT_REST {
            self.push(speed / deceleration, -self.velocity.signum() * deceleration);
        }
        self.velocity = 0.0;
    }

    fn plan(&mut self, target: f64, limits: Limits) {
        let distance = target - self.position;
        let direction = if distance.abs() > AT_REST {
            distance.signum()
        } else {
            -self.velocity.signum()
        };
        // Speed towards the target.
        let toward = self.velocity * direction;
        let stopping = toward.max(0.0).powi(2) / (2.0 * limits.deceleration);
        if toward < -AT_REST || stopping > distance.abs() + 1e-9 {
            // Moving away, or too fast to stop in time: brake to rest,
            // then come back from there.
            self.brake(limits.deceleration);
            self.towards(target, limits);
            return;
        }
        self.towards(target, limits);
    }

    /// Towards `target`, already moving towards it (or at rest) and able to
    /// stop before it.
    fn towards(&mut self, target: f64, limits: Limits) {
        let distance = target - self.position;
        if distance.abs() <= AT_REST {
            self.brake(limits.deceleration);
            return;
        }
        let direction = distance.signum();
        let distance = distance.abs();
        let u0 = (self.velocity * direction).max(0.0);
        let (a, d) = (limits.acceleration, limits.deceleration);
        if u0 > limits.velocity {
            // Faster than allowed: slow to the profile velocity first (at
            // the deceleration), then cruise and brake.
            let slow = (u0 - limits.velocity) / d;
            let slow_distance = (u0 + limits.velocity) / 2.0 * slow;
            let brake_distance = limits.velocity.powi(2) / (2.0 * d);
            if slow_distance + brake_distance <= distance {
                self.push(slow, -direction * d);
                let cruise =
                    (distance - slow_distance - brake_distance) / limits.velocity.max(AT_REST);
                self.push(cruise, 0.0);
                self.push(limits.velocity / d, -direction * d);
            } else {
                // Braking all the way at the deceleration arrives.
                self.push(u0 / d, -direction * d);
            }
            return;
        }
        // Peak speed of a triangle: accelerate from u0, decelerate to 0.
        let peak = ((distance + u0 * u0 / (2.0 * a)) * 2.0 * a * d / (a + d)).sqrt();
        let peak = peak.max(u0);
        if peak <= limits.velocity {
            self.push((peak - u0) / a, direction * a);
            self.push(peak / d, -direction * d);
        } else {
            let v = limits.velocity;
            let accelerate = (v - u0) / a;
            let accelerate_distance = (v * v - u0 * u0) / (2.0 * a);
            let brake_distance = v * v / (2.0 * d);
            let cruise = (distance - accelerate_distance - brake_distance) / v.max(AT_REST);
            self.push(accelerate, direction * a);
            self.push(cruise, 0.0);
            self.push(v / d, -direction * d);
        }
    }

    fn finish(self, end: f64) -> Profile {
        Profile {
            segments: self.segments,
            count: self.count,
            end,
            t: 0.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: Limits = Limits {
        velocity: 50.0,
        acceleration: 2.0,
        deceleration: 1.0,
    };

    /// Runs a profile to its end; checks every sample against the limits
    /// and returns the samples.
    fn run(mut profile: Profile, limits: Limits) -> Vec<Sample> {
        let mut samples = vec![profile.sample()];
        while !profile.done() {
            samples.push(profile.step());
            assert!(samples.len() < 1_000_000, "never ends");
        }
        samples.push(profile.step());
        for pair in samples.windows(2) {
            let dv = pair[1].velocity - pair[0].velocity;
            assert!(
                dv.abs() <= limits.acceleration.max(limits.deceleration) + 1e-9,
                "{pair:?}"
            );
            // The mean velocity over a millisecond is the position step.
            let mean = pair[1].position - pair[0].position;
            assert!(mean.abs() <= limits.velocity.max(pair[0].velocity.abs()) + 1e-9);
        }
        samples
    }

    #[test]
    fn a_long_move_is_a_trapezoid_that_lands_on_the_target() {
        let samples = run(Profile::to_target(0.0, 0.0, 10_000.0, LIMITS), LIMITS);
        let last = samples.last().unwrap();
        assert_eq!(last.position, 10_000.0);
        assert_eq!(last.velocity, 0.0);
        let top = samples.iter().map(|s| s.velocity).fold(0.0, f64::max);
        assert!(
            (top - 50.0).abs() < 1e-9,
            "cruises at the profile velocity: {top}"
        );
        // Accelerates at 2, decelerates at 1: 25 ms up, 50 ms down, and the
        // 10 000 increments minus 625 + 1250 cruised at 50.
        let expected = 25.0 + 50.0 + (10_000.0 - 625.0 - 1250.0) / 50.0;
        assert!((samples.len() as f64 - 2.0 - expected).abs() <= 1.0);
    }

    #[test]
    fn a_short_move_is_a_triangle_below_the_profile_velocity() {
        let samples = run(Profile::to_target(100.0, 0.0, 40.0, LIMITS), LIMITS);
        assert_eq!(samples.last().unwrap().position, 40.0);
        let top = samples.iter().map(|s| s.velocity.abs()).fold(0.0, f64::max);
        assert!(top < 50.0 && top > 5.0, "{top}");
        assert!(samples.iter().all(|s| s.position >= 40.0 - 1e-9));
    }

    #[test]
    fn a_new_target_behind_a_moving_axis_brakes_then_comes_back() {
        let samples = run(Profile::to_target(0.0, 30.0, 100.0, LIMITS), LIMITS);
        let furthest = samples.iter().map(|s| s.position).fold(0.0, f64::max);
        // Stopping from 30 at 1 takes 450 increments: past the target.
        assert!((furthest - 450.0).abs() < 1e-6, "{furthest}");
        assert_eq!(samples.last().unwrap().position, 100.0);
    }

    #[test]
    fn a_move_started_too_fast_slows_to_the_profile_velocity() {
        let samples = run(Profile::to_target(0.0, 80.0, 100_000.0, LIMITS), LIMITS);
        assert_eq!(samples.last().unwrap().position, 100_000.0);
        let cruise = samples[200].velocity;
        assert!((cruise - 50.0).abs() < 1e-9);
    }

    #[test]
    fn a_stop_brakes_at_the_deceleration() {
        let mut profile = Profile::stop(0.0, -20.0, 4.0);
        let mut n = 0;
        while !profile.done() {
            profile.step();
            n += 1;
        }
        assert_eq!(n, 5);
        assert_eq!(profile.end(), -50.0);
        assert_eq!(profile.sample().velocity, 0.0);
    }
}
