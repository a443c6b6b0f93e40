//! The board of a UniSwarm device as its status objects report it (UMC
//! manual chapter 1 §2, UIOLed manual §4): the supply's voltage (0x2000),
//! the CPUs' temperatures (0x2020) and life-cycle counters (0x2021), and the
//! first-order thermal model behind every temperature the simulation shows.

/// The air around the board, °C.
pub const AMBIENT: f64 = 25.0;

/// The supply the boards are powered from, V.
pub const NOMINAL_SUPPLY: f64 = 24.0;

/// CPU cycles per millisecond (a 50 µs main cycle): 0x2021 counts them.
pub const CPU_CYCLES_PER_MS: u16 = 20;

/// A body warming with the power it dissipates and cooling to ambient.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thermal {
    /// °C.
    pub temperature: f64,
    /// Thermal resistance to ambient, K/W.
    pub resistance: f64,
    /// Time constant, s.
    pub time_constant: f64,
}

impl Thermal {
    pub fn new(ambient: f64, resistance: f64, time_constant: f64) -> Self {
        Thermal {
            temperature: ambient,
            resistance,
            time_constant,
        }
    }

    /// `seconds` of dissipating `power` watts at `ambient` °C.
    pub fn step(&mut self, power: f64, ambient: f64, seconds: f64) {
        let settled = ambient + power * self.resistance;
        let k = (seconds / self.time_constant).min(1.0);
        self.temperature += (settled - self.temperature) * k;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temperature_rises_with_power_and_decays_at_rest() {
        let mut body = Thermal::new(25.0, 4.0, 20.0);
        for _ in 0..100 {
            body.step(10.0, 25.0, 0.1);
        }
        let warm = body.temperature;
        assert!(warm > 35.0 && warm < 65.0, "{warm}");
        for _ in 0..100 {
            body.step(0.0, 25.0, 0.1);
        }
        assert!(body.temperature < warm && body.temperature > 25.0);
    }
}
