//! The motor, its load and the power bridge behind one axis (UMC manual
//! chapter 1 §3.2 "Motor", §2.4 "Power bridges status", §2.5
//! "Temperatures"): what the firmware's control loops act on and what its
//! sensors measure.
//!
//! A brushed DC motor driving an inertia with viscous and Coulomb friction,
//! fed by an H-bridge from the board supply:
//!
//! - electrical (the winding's inductance is fast next to a 1 ms step):
//!   `i = (d·V_bus − Ke·ω) / R`, limited to the peak current by the
//!   bridge's comparator (0x4007.2: "every power bridge is open" above it,
//!   i.e. the current is chopped there);
//! - mechanical: `J·dω/dt = Kt·i − B·ω − Tc·sign(ω)`, the Coulomb friction
//!   holding the shaft at rest while the motor torque stays below it;
//! - thermal, first order per body: `τ·dT/dt = P·Rth − (T − T_ambient)`,
//!   with `P = i²·R_on` in each bridge and `P = i²·R` in the winding.
//!
//! SI units inside; [`Motor::position`] and [`Motor::velocity`] are in the
//! axis units of [`crate::profiles::umc::units`] (increments, increments/ms).

use std::f64::consts::TAU;

use crate::profiles::umc::units::INCREMENTS_PER_REV;

/// The motor the virtual UMC drives: a 24 V brushed DC motor, about
/// 7600 rpm unloaded at 24 V, driving a load ([`Load::DEFAULT`] unless the
/// device was given another).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorModel {
    /// Winding resistance, Ω.
    pub resistance: f64,
    /// Torque constant, N·m/A; also the back-EMF constant in V·s/rad.
    pub torque_constant: f64,
    /// Rotor and load inertia, kg·m².
    pub inertia: f64,
    /// Viscous friction, N·m per rad/s.
    pub viscous: f64,
    /// Coulomb friction, N·m.
    pub coulomb: f64,
}

impl MotorModel {
    /// The motor driving `load`.
    pub fn with_load(load: Load) -> Self {
        MotorModel {
            resistance: 0.1,
            torque_constant: 0.03,
            inertia: load.inertia,
            viscous: load.friction,
            coulomb: 2e-3,
        }
    }

    /// The mechanical time constant `J·R/(Kt·Ke)`, s: how long the shaft
    /// takes to reach 63 % of a speed step at a fixed voltage; what a
    /// velocity loop can shorten, and what it must be tuned against.
    pub fn mechanical_time_constant(&self) -> f64 {
        self.inertia * self.resistance / (self.torque_constant * self.torque_constant)
    }
}

impl Default for MotorModel {
    fn default() -> Self {
        Self::with_load(Load::DEFAULT)
    }
}

/// What the motor of a virtual UMC axis drives: the inertia at its shaft
/// (rotor included) and the viscous friction. Set per device by
/// `--devices umc1bds32@1?inertia=KGM2&friction=NMS` or the keys
/// `inertia` and `friction` of `POST /buses/{bus}/sim/nodes`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Load {
    /// kg·m², rotor included.
    pub inertia: f64,
    /// Viscous friction, N·m·s (N·m per rad/s).
    pub friction: f64,
}

impl Eq for Load {} // Finite by construction (Load::new).

impl Load {
    /// An axis with a load, not a bare rotor: 3·10⁻⁴ kg·m² (a mechanical
    /// time constant of 33 ms with the motor's 0.1 Ω and 0.03 N·m/A) and
    /// 10⁻⁴ N·m·s of viscous friction.
    pub const DEFAULT: Load = Load {
        inertia: 3e-4,
        friction: 1e-4,
    };
    /// The motor's bare rotor with a trace of friction: what the firmware's
    /// own tests (trajectories, statuswords) run on, where the load's
    /// dynamics would only blur the figures they check.
    pub const BARE_ROTOR: Load = Load {
        inertia: 2e-5,
        friction: 2e-6,
    };
    /// The inertias a device takes, kg·m²: the bare rotor (2·10⁻⁵) up to
    /// a flywheel that takes minutes to spin up.
    pub const INERTIA: (f64, f64) = (2e-5, 1.0);
    /// The viscous frictions a device takes, N·m·s.
    pub const FRICTION: (f64, f64) = (0.0, 0.1);

    /// A load of `inertia` kg·m² and `friction` N·m·s (the defaults where
    /// `None`); an error names the value out of range.
    pub fn new(inertia: Option<f64>, friction: Option<f64>) -> Result<Load, String> {
        let inertia = inertia.unwrap_or(Self::DEFAULT.inertia);
        let friction = friction.unwrap_or(Self::DEFAULT.friction);
        let (low, high) = Self::INERTIA;
        if !(inertia.is_finite() && (low..=high).contains(&inertia)) {
            return Err(format!(
                "inertia {inertia} kg·m² is out of range: {low} to {high} (default {})",
                Self::DEFAULT.inertia
            ));
        }
        let (low, high) = Self::FRICTION;
        if !(friction.is_finite() && (low..=high).contains(&friction)) {
            return Err(format!(
                "friction {friction} N·m·s is out of range: {low} to {high} (default {})",
                Self::DEFAULT.friction
            ));
        }
        Ok(Load { inertia, friction })
    }
}

/// What the bridge does to the motor during one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Bridge {
    /// Floating: no current flows; the motor coasts.
    Off,
    /// A duty cycle, −1 to 1, of the supply.
    Duty(f64),
    /// The current loop holds this current (A) as far as the supply
    /// voltage allows.
    Current(f64),
}

/// Seconds per simulation step.
const DT: f64 = 1e-3;
/// rad/s per increment/ms.
const RAD_PER_S: f64 = 1000.0 * TAU / INCREMENTS_PER_REV;
/// Commanded speeds (increments/ms) below this get part of the friction
/// feed-forward, so that holding still does not chatter between senses.
const FRICTION_BLEND: f64 = 0.01;
/// Below this speed (rad/s) the shaft counts as at rest for friction.
const STICTION_SPEED: f64 = 1e-4;

/// One axis's motor and load.
#[derive(Debug, Clone, PartialEq)]
pub struct Motor {
    pub model: MotorModel,
    /// Increments.
    pub position: f64,
    /// Increments/ms.
    pub velocity: f64,
    /// Winding current, A.
    pub current: f64,
    /// Duty cycle applied, −1 to 1 (0 when floating).
    pub duty: f64,
    /// Whether the bridge drives the motor (not floating).
    pub driven: bool,
    /// The load is seized: the shaft cannot turn (a jammed mechanism).
    pub jammed: bool,
    /// A constant torque the load puts on the shaft against positive
    /// rotation (a weight on a winch), N·m; the loops do not know it.
    pub load_torque: f64,
}

impl Motor {
    pub fn new(model: MotorModel) -> Self {
        Motor {
            model,
            position: 0.0,
            velocity: 0.0,
            current: 0.0,
            duty: 0.0,
            driven: false,
            jammed: false,
            load_torque: 0.0,
        }
    }

    /// Angular velocity, rad/s.
    pub fn omega(&self) -> f64 {
        self.velocity * RAD_PER_S
    }

    /// Back-EMF, V.
    pub fn back_emf(&self) -> f64 {
        self.model.torque_constant * self.omega()
    }

    /// Torque of the motor, N·m.
    pub fn torque(&self) -> f64 {
        self.model.torque_constant * self.current
    }

    /// Whether nothing moves and no current flows: a step would change
    /// nothing.
    pub fn at_rest(&self) -> bool {
        self.velocity == 0.0 && self.current == 0.0 && !self.driven && self.load_torque == 0.0
    }

    /// The current (A) that gives the shaft the angular acceleration
    /// `acceleration` (increments/ms²) at the present speed, friction
    /// compensated: the feed-forward of the control loops. `direction`
    /// (increments/ms) tells which way friction acts when at rest.
    pub fn current_for(&self, acceleration: f64, direction: f64) -> f64 {
        let m = &self.model;
        let omega = self.omega();
        let alpha = acceleration * RAD_PER_S * 1000.0;
        // Friction opposes the motion; at rest, the motion about to start.
        let sense = if omega.abs() > STICTION_SPEED {
            omega.signum()
        } else {
            (direction / FRICTION_BLEND).clamp(-1.0, 1.0)
        };
        (m.inertia * alpha + m.viscous * omega + m.coulomb * sense) / m.torque_constant
    }

    /// One millisecond with the bridge doing `bridge` from a supply of
    /// `supply` volts, the current limited to `peak` amperes.
    pub fn step(&mut self, bridge: Bridge, supply: f64, peak: f64) {
        let m = self.model;
        let emf = self.back_emf();
        let (duty, current) = match bridge {
            Bridge::Off => (0.0, 0.0),
            Bridge::Duty(duty) => {
                let duty = duty.clamp(-1.0, 1.0);
                (
                    duty,
                    ((duty * supply - emf) / m.resistance).clamp(-peak, peak),
                )
            }
            Bridge::Current(wanted) => {
                let wanted = wanted.clamp(-peak, peak);
                let voltage = (m.resistance * wanted + emf).clamp(-supply, supply);
                let duty = if supply > 0.0 { voltage / supply } else { 0.0 };
                (duty, (voltage - emf) / m.resistance)
            }
        };
        self.duty = duty;
        self.current = current;
        self.driven = !matches!(bridge, Bridge::Off);
        if self.jammed {
            self.velocity = 0.0;
            return;
        }
        let omega = self.omega();
        let drive = m.torque_constant * current - m.viscous * omega - self.load_torque;
        let next = if omega.abs() <= STICTION_SPEED && drive.abs() <= m.coulomb {
            0.0
        } else {
            let friction = if omega.abs() > STICTION_SPEED {
                m.coulomb * omega.signum()
            } else {
                m.coulomb * drive.signum()
            };
            let next = omega + (drive - friction) / m.inertia * DT;
            // Crossing zero, the shaft stops; whether the motor turns it
            // the other way is the next step's question, from rest.
            if omega != 0.0 && next.signum() != omega.signum() {
                0.0
            } else {
                next
            }
        };
        let next = if next.abs() < STICTION_SPEED && drive.abs() <= m.coulomb {
            0.0
        } else {
            next
        };
        self.position += (omega + next) / 2.0 * DT / TAU * INCREMENTS_PER_REV;
        self.velocity = next / RAD_PER_S;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_load_has_a_time_constant_of_tens_of_ms_and_others_are_checked() {
        let tau = MotorModel::default().mechanical_time_constant();
        assert!((0.02..0.1).contains(&tau), "{tau}");
        // Spun up at full duty, the shaft is at 63 % of its final speed
        // after about one time constant.
        let mut motor = Motor::new(MotorModel::default());
        let mut samples = Vec::new();
        for _ in 0..1000 {
            motor.step(Bridge::Duty(1.0), 24.0, 1000.0);
            samples.push(motor.omega());
        }
        let last = samples[999];
        let at = samples.iter().position(|w| *w >= 0.632 * last).unwrap() + 1;
        assert!((25..45).contains(&at), "{at} ms");
        let heavy = Load::new(Some(3e-3), None).unwrap();
        assert_eq!(heavy.friction, Load::DEFAULT.friction);
        assert!(MotorModel::with_load(heavy).mechanical_time_constant() > 0.3);
        for (inertia, friction, error) in [
            (
                Some(0.0),
                None,
                "inertia 0 kg·m² is out of range: 0.00002 to 1",
            ),
            (Some(f64::NAN), None, "inertia NaN"),
            (
                None,
                Some(-1.0),
                "friction -1 N·m·s is out of range: 0 to 0.1",
            ),
            (None, Some(2.0), "friction 2 N·m·s is out of range"),
        ] {
            let refused = Load::new(inertia, friction).unwrap_err();
            assert!(refused.contains(error), "{refused}");
        }
    }

    fn bare() -> MotorModel {
        MotorModel::with_load(Load::BARE_ROTOR)
    }

    #[test]
    fn full_duty_runs_up_to_the_no_load_speed() {
        let mut motor = Motor::new(bare());
        for _ in 0..3000 {
            motor.step(Bridge::Duty(1.0), 24.0, 32.0);
        }
        // 24 V / 0.03 V·s/rad = 800 rad/s, less what friction takes.
        let omega = motor.omega();
        assert!(omega > 700.0 && omega < 800.0, "{omega}");
        assert!(
            motor.current > 0.0 && motor.current < 2.0,
            "{}",
            motor.current
        );
        assert!(motor.position > 0.0);
    }

    #[test]
    fn the_current_is_chopped_at_the_peak() {
        let mut motor = Motor::new(bare());
        motor.step(Bridge::Duty(1.0), 24.0, 32.0);
        assert_eq!(motor.current, 32.0);
    }

    #[test]
    fn friction_holds_a_shaft_the_motor_does_not_push_hard_enough() {
        let mut motor = Motor::new(bare());
        motor.step(Bridge::Current(0.05), 24.0, 32.0);
        assert_eq!(motor.velocity, 0.0);
        motor.step(Bridge::Current(1.0), 24.0, 32.0);
        assert!(motor.velocity > 0.0);
    }

    #[test]
    fn a_coasting_motor_comes_to_rest() {
        let mut motor = Motor::new(bare());
        for _ in 0..500 {
            motor.step(Bridge::Current(5.0), 24.0, 32.0);
        }
        assert!(motor.velocity > 0.0);
        for _ in 0..100_000 {
            motor.step(Bridge::Off, 24.0, 32.0);
        }
        assert_eq!(motor.velocity, 0.0);
        assert_eq!(motor.current, 0.0);
    }
}
