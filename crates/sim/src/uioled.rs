//! Virtual UniSwarm UIO1LED (UIOLed firmware manual, chapter 1 "Led
//! profile"): ten segments of one LED strip, each with its effect, and the
//! speed controller that adds `sNN_Speed` to `sNN_Value` every millisecond
//! within `sNN_MinValue`..`sNN_MaxValue` (§1.3, 0x6n10–0x6n13).
//!
//! The parameters live twice: in the object store, where the bus reads and
//! writes them, and as [`Segment`]s, which the renderer draws. Each way has
//! one writer. A write from the bus (SDO or RPDO) is copied into its
//! segment's field; the speed controller runs on the segments and writes
//! every Value it moves back to the store in the same millisecond, so an SDO
//! upload, or a TPDO sampled on SYNC, carries the Value of that millisecond
//! as the real controller's would. The controller's step is the renderer's
//! own [`Segment::value_at`]: the Value on the bus and the Value drawn are
//! one computation.
//!
//! The manual has the speed controller run whatever the effect (OFF and FIX
//! ignore Value, but it moves all the same and is read back moving), and in
//! any NMT state (NMT governs communication, not the application).
//!
//! The board (§4) reports live values too, updated every 10 ms: the supply
//! (0x2000.1), which sags with the current the lit LEDs draw, the CPU's
//! temperature (0x2020.1) and its life-cycle counter (0x2021.1).

use crate::behaviour::{Behaviour, DeviceIo};
use crate::board::{AMBIENT, CPU_CYCLES_PER_MS, NOMINAL_SUPPLY, Thermal};
use crate::profiles::uioled::{Effect, Field, Rgbw, SEGMENTS, Segment, address, locate, render};

/// 0x2000.1 Board_voltage_input, UINT16 in 0.01 V.
const BOARD_VOLTAGE: (u16, u8) = (0x2000, 1);
/// 0x2020.1 CPU1_temperature, in 0.1 °C.
const CPU_TEMPERATURE: (u16, u8) = (0x2020, 1);
/// 0x2021.1 CPU1_life_cycle, UINT16 counting CPU cycles.
const CPU_LIFE_CYCLE: (u16, u8) = (0x2021, 1);
/// The board objects are updated every this many ms.
const BOARD_MS: u64 = 10;
/// The supply's internal resistance and the wiring's, Ω.
const SUPPLY_RESISTANCE: f64 = 0.05;
/// What the board itself draws, A.
const BOARD_CURRENT: f64 = 0.05;
/// What one colour channel of one LED draws at full brightness, A (an
/// addressable LED of the WS2812 or SK6812 kind).
const CHANNEL_CURRENT: f64 = 0.02;
/// CPU temperature: K/W to ambient, time constant in s, and the CPU's
/// dissipation in W.
const CPU_THERMAL: (f64, f64, f64) = (20.0, 30.0, 0.3);

/// A UIO1LED: its segments as the store last set them, Values as of
/// `synced_ms`, and its board.
#[derive(Debug, Clone, Default)]
pub struct Uioled {
    /// Segment n at `n − 1`.
    segments: [Segment; SEGMENTS as usize],
    /// The simulation time the segments' Values (in them and in the store)
    /// are of.
    synced_ms: u64,
    board: Board,
}

/// The supply and the CPU (manual §4).
#[derive(Debug, Clone, Copy)]
struct Board {
    cpu: Thermal,
    life_cycle: u16,
    /// Milliseconds since the board objects were last updated.
    since_update: u64,
}

impl Default for Board {
    /// Powered up a while ago: the CPU at its working temperature.
    fn default() -> Self {
        let (resistance, time_constant, power) = CPU_THERMAL;
        Board {
            cpu: Thermal::new(AMBIENT + power * resistance, resistance, time_constant),
            life_cycle: 0,
            since_update: 0,
        }
    }
}

impl Board {
    /// `ms` milliseconds of running with `segments` lit; the objects
    /// written.
    fn update(&mut self, io: &mut DeviceIo<'_>, segments: &[Segment], ms: u64) {
        let seconds = ms as f64 / 1000.0;
        self.cpu.step(CPU_THERMAL.2, AMBIENT, seconds);
        self.life_cycle = self
            .life_cycle
            .wrapping_add((ms as u16).wrapping_mul(CPU_CYCLES_PER_MS));
        let voltage = NOMINAL_SUPPLY - SUPPLY_RESISTANCE * (BOARD_CURRENT + led_current(segments));
        io.set_real(BOARD_VOLTAGE.0, BOARD_VOLTAGE.1, voltage * 100.0);
        io.set_real(
            CPU_TEMPERATURE.0,
            CPU_TEMPERATURE.1,
            self.cpu.temperature * 10.0,
        );
        io.set_int(
            CPU_LIFE_CYCLE.0,
            CPU_LIFE_CYCLE.1,
            i64::from(self.life_cycle),
        );
    }
}

/// What the strip draws, A: each lit segment's LEDs at colour 1 through
/// its dimmer (the effects light at most that much, so a moving effect is
/// counted at its brightest).
fn led_current(segments: &[Segment]) -> f64 {
    segments
        .iter()
        .filter(|segment| segment.effect != Effect::Off)
        .map(|segment| {
            let color = segment.color_1();
            let channels = [color.r, color.g, color.b, color.w]
                .iter()
                .map(|c| f64::from(*c) / 255.0)
                .sum::<f64>();
            f64::from(segment.led_count) * channels * CHANNEL_CURRENT * f64::from(segment.dimmer)
                / 255.0
        })
        .sum()
}

impl Uioled {
    pub fn new() -> Self {
        Self::default()
    }

    /// The ten segments, segment 1 first, with their Values as of the last
    /// tick (or write), the same as the store holds.
    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// Every LED of the strip at simulation time `t_ms` (milliseconds, as
    /// [`DeviceIo::sim_ms`] counts them): segment 1's LEDs first. A time
    /// before the last tick is drawn as of the last tick.
    pub fn pixels(&self, t_ms: u64) -> Vec<Rgbw> {
        render(&self.segments, t_ms.saturating_sub(self.synced_ms))
    }

    /// Runs the speed controller up to the present: every moving Value is
    /// stepped by the milliseconds since the last run (one when ticking, more
    /// when the host skipped ticks) and written to the store.
    fn advance(&mut self, io: &mut DeviceIo<'_>) {
        let now = io.sim_ms();
        let elapsed = now.saturating_sub(self.synced_ms);
        self.synced_ms = now;
        if elapsed == 0 {
            return;
        }
        for (number, segment) in (1..=SEGMENTS).zip(&mut self.segments) {
            if segment.speed == 0 {
                continue;
            }
            let value = segment.value_at(elapsed);
            // A range of one value leaves Value still: no store write.
            if value == segment.value {
                continue;
            }
            segment.value = value;
            if let Some((index, sub)) = address(number, Field::Value) {
                io.set_int(index, sub, i64::from(value));
            }
        }
    }
}

impl Behaviour for Uioled {
    /// The manual's EMCY table (chapter 3 §6.1) lists 0x8220.
    fn reports_pdo_length_exceeded(&self) -> bool {
        true
    }

    fn product(&self) -> &'static str {
        "uio1led"
    }

    fn reset(&mut self, io: &mut DeviceIo<'_>) {
        for (number, segment) in (1..=SEGMENTS).zip(&mut self.segments) {
            // A field our dictionary lacked would keep the device default.
            *segment = Segment::default();
            for field in Field::all() {
                let raw = address(number, field).and_then(|(index, sub)| io.int(index, sub));
                if let Some(raw) = raw {
                    segment.set(field, raw);
                }
            }
        }
        self.synced_ms = io.sim_ms();
        self.board = Board::default();
        self.board.update(io, &self.segments, 0);
    }

    fn written(&mut self, io: &mut DeviceIo<'_>, index: u16, sub: u8) {
        let Some((number, field)) = locate(index, sub) else {
            return;
        };
        let Some(raw) = io.int(index, sub) else {
            return;
        };
        // Every Value up to this moment under the old parameters, so that
        // a new Speed or range applies from now on, not since the last tick.
        self.advance(io);
        self.segments[usize::from(number) - 1].set(field, raw);
        if field == Field::Value {
            // Advancing may have stepped this segment's old Value over the
            // one just written: the written one is where it restarts from.
            io.set_int(index, sub, raw);
        }
    }

    fn tick(&mut self, io: &mut DeviceIo<'_>) {
        self.advance(io);
        self.board.since_update += 1;
        if self.board.since_update == BOARD_MS {
            self.board.since_update = 0;
            self.board.update(io, &self.segments, BOARD_MS);
        }
    }
}

#[cfg(test)]
mod tests;
