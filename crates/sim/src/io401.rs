//! Virtual `io401`, a CiA 401 generic I/O module written for candeck (its
//! EDS is `eds/io401.eds`): 16 digital inputs, 16 digital outputs, 4
//! analogue inputs and 2 analogue outputs. Its inputs change on their own,
//! every 10 ms of simulated time, in the pattern of docs/virtual-devices.md:
//!
//! - digital inputs: a running light, input `n` (1–16) on during the
//!   `n`-th quarter second of every 4 s, the others off; each 8-bit group
//!   then inverted where its polarity (0x6002) says;
//! - `ai1`: a sine of amplitude 10,000 and period 10 s;
//! - `ai2`: a triangle from 0 to 20,000 and back, period 20 s;
//! - `ai3`: a square wave, +5,000 for a second, −5,000 for the next;
//! - `ai4`: reads back analogue output 1 (0x6411 sub 1), as if wired to it.
//!
//! The outputs (0x6200, 0x6411) are what the bus last wrote; they are read
//! back as written (their polarity, 0x6202, is the module's wiring, not the
//! value). The application runs in every NMT state; the TPDOs carry the
//! inputs in operational.

use crate::behaviour::{Behaviour, DeviceIo};
use crate::profiles::cia401::{
    POLARITY_INPUT_8, READ_ANALOG_INPUT_16, READ_INPUT_8, WRITE_ANALOG_OUTPUT_16,
};

/// The inputs are updated every this many ms.
const UPDATE_MS: u64 = 10;
/// The running light's step and cycle.
const LIGHT_STEP_MS: u64 = 250;
const DIGITAL_INPUTS: u64 = 16;
/// `ai1`'s sine.
const SINE_AMPLITUDE: f64 = 10_000.0;
const SINE_PERIOD_MS: u64 = 10_000;
/// `ai2`'s triangle.
const TRIANGLE_TOP: i64 = 20_000;
const TRIANGLE_PERIOD_MS: u64 = 20_000;
/// `ai3`'s square wave.
const SQUARE_LEVEL: i64 = 5_000;
const SQUARE_HALF_MS: u64 = 1_000;

/// The inputs of an io401 at simulation time `t_ms`, before the input
/// polarity: the 16 digital inputs as two bytes (input 1 is bit 0 of the
/// first) and `ai1`–`ai3` (`ai4` follows the output).
pub fn inputs_at(t_ms: u64) -> ([u8; 2], [i16; 3]) {
    let lit = (t_ms / LIGHT_STEP_MS) % DIGITAL_INPUTS;
    let bits = 1u16 << lit;
    let phase = (t_ms % SINE_PERIOD_MS) as f64 / SINE_PERIOD_MS as f64;
    let sine = (SINE_AMPLITUDE * (phase * std::f64::consts::TAU).sin()).round() as i16;
    let t = (t_ms % TRIANGLE_PERIOD_MS) as i64;
    let half = (TRIANGLE_PERIOD_MS / 2) as i64;
    let triangle = if t < half {
        TRIANGLE_TOP * t / half
    } else {
        TRIANGLE_TOP * (2 * half - t) / half
    } as i16;
    let square = if (t_ms / SQUARE_HALF_MS).is_multiple_of(2) {
        SQUARE_LEVEL
    } else {
        -SQUARE_LEVEL
    } as i16;
    (bits.to_le_bytes(), [sine, triangle, square])
}

/// An io401's application: it keeps nothing but the time of its last
/// update.
#[derive(Debug, Clone, Default)]
pub struct Io401 {
    since_update: u64,
}

impl Io401 {
    pub fn new() -> Self {
        Self::default()
    }

    fn update(&self, io: &mut DeviceIo<'_>) {
        let (digital, analog) = inputs_at(io.sim_ms());
        for (sub, byte) in (1u8..).zip(digital) {
            let polarity = io.int(POLARITY_INPUT_8, sub).unwrap_or(0) as u8;
            io.set_int(READ_INPUT_8, sub, i64::from(byte ^ polarity));
        }
        for (sub, value) in (1u8..).zip(analog) {
            io.set_int(READ_ANALOG_INPUT_16, sub, i64::from(value));
        }
        let loop_back = io.int(WRITE_ANALOG_OUTPUT_16, 1).unwrap_or(0);
        io.set_int(READ_ANALOG_INPUT_16, 4, loop_back);
    }
}

impl Behaviour for Io401 {
    fn product(&self) -> &'static str {
        "io401"
    }

    fn reset(&mut self, io: &mut DeviceIo<'_>) {
        self.since_update = 0;
        self.update(io);
    }

    fn written(&mut self, io: &mut DeviceIo<'_>, index: u16, _sub: u8) {
        // A new polarity or output shows in the inputs at once.
        if matches!(index, POLARITY_INPUT_8 | WRITE_ANALOG_OUTPUT_16) {
            self.update(io);
        }
    }

    fn tick(&mut self, io: &mut DeviceIo<'_>) {
        self.since_update += 1;
        if self.since_update >= UPDATE_MS {
            self.since_update = 0;
            self.update(io);
        }
    }
}

#[cfg(test)]
mod tests;
