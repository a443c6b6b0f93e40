//! The virtual UniSwarm UMC motion controllers (UMC firmware manual): the
//! UMC1BDS32 with two axes, the UMC1BD90 with one, each axis a CiA 402
//! drive (chapter 2) at the manual's index offsets, on a board whose supply,
//! bridges and CPUs report live values (chapter 1 §2).
//!
//! # Layout
//!
//! - [`axis`]: one axis: the PDS, the modes' statusword bits, stops, the
//!   control loops, the supervision that raises faults.
//! - [`modes`]: the set-point generators of DTY, TQ, VL, PP and CP.
//! - [`ip`]: interpolated position, its 32-entry FIFO.
//! - [`trajectory`]: the trapezoidal profile of the position modes.
//! - [`motor`]: the DC motor, its load and the thermal model.
//! - [`faults`]: the fault conditions, their EMCY codes and register bits.
//! - [`params`]: an axis's parameters, read when written.
//! - [`pid`]: one PID of the cascade (§3.5), as its configuration reads.
//! - [`sensor`]: a sensor's conditioning (§3.4.4).
//! - [`publish`]: the status objects, written when they change.
//!
//! The board (this module): the supply 0x2000 against 0x2041, the driver
//! bridges' temperatures 0x2801 against 0x2810, currents, duty cycles and
//! back-EMF per bridge (0x2802, 0x2804, 0x2805), the CPUs' temperatures and
//! life-cycle counters (0x2020, 0x2021); these change slowly or are
//! diagnostics, so they are updated every 10 ms.

pub mod axis;
pub mod faults;
pub mod ip;
pub mod modes;
pub mod motor;
pub mod params;
pub mod pid;
pub mod publish;
pub mod sensor;
pub mod trajectory;

#[cfg(test)]
mod tests;

use crate::behaviour::{Behaviour, DeviceIo, Fault, FaultError};
use crate::canopen::emcy::ErrorBit;
use crate::canopen::nmt::NmtState;
use crate::canopen::sdo::AbortCode;
use crate::objects::ObjectStore;
use crate::profiles::cia402::Mode;
use crate::profiles::umc::drive as d;
use crate::profiles::umc::{self, board};

use self::axis::{Axis, AxisNews, SUPPORTED_MODES, Supply};
use self::faults::{Condition, schmitt};
pub use self::motor::Load;
use self::motor::MotorModel;
use crate::board::{AMBIENT, CPU_CYCLES_PER_MS, NOMINAL_SUPPLY, Thermal};

/// The supply's internal resistance, Ω: the board voltage sags under load.
const SUPPLY_RESISTANCE: f64 = 0.05;
/// On-resistance of a bridge leg, Ω.
const BRIDGE_RESISTANCE: f64 = 0.02;
/// A driven bridge's switching loss, W.
const SWITCHING_LOSS: f64 = 0.1;
/// Bridge temperature: K/W to ambient and time constant, s.
const BRIDGE_THERMAL: (f64, f64) = (4.0, 20.0);
/// Motor winding temperature: K/W to ambient and time constant, s.
const WINDING_THERMAL: (f64, f64) = (3.0, 60.0);
/// CPU temperature: K/W to ambient and time constant, s.
const CPU_THERMAL: (f64, f64) = (20.0, 30.0);
/// CPU dissipation, W: idle, and what each driven axis adds.
const CPU_POWER: (f64, f64) = (0.5, 0.1);
/// The board objects are updated every this many ms.
const SLOW_MS: u64 = 10;
/// And every status object rewritten every this many ms (a restore may
/// have put factory values over them).
const REPUBLISH_MS: u64 = 1000;
/// The register bits the axes' faults use.
const FAULT_BITS: [ErrorBit; 5] = [
    ErrorBit::Current,
    ErrorBit::Voltage,
    ErrorBit::Temperature,
    ErrorBit::DeviceProfile,
    ErrorBit::Manufacturer,
];

/// A UMC with `axes` axes.
///
/// [`Behaviour::inject_fault`] puts a condition on the whole board, so every
/// axis faults (each sends its EMCY, its axis number in the first
/// manufacturer byte); [`Umc::inject_axis_fault`] gives one axis a following
/// error or an over-current.
pub struct Umc {
    axes: Vec<Axis>,
    board: Board,
    ms: u64,
}

impl Umc {
    /// Two axes for the UMC1BDS32 (bridges A–D, two per axis), one for the
    /// UMC1BD90 (bridges A–C).
    pub fn new(axes: u8) -> Umc {
        Self::with_load(axes, Load::DEFAULT)
    }

    /// The same, each axis's motor driving `load`.
    pub fn with_load(axes: u8, load: Load) -> Umc {
        let count = axes.clamp(1, 2);
        Umc {
            axes: (1..=count)
                .map(|n| Axis::new(n, MotorModel::with_load(load)))
                .collect(),
            board: Board::new(if count > 1 { 4 } else { 3 }),
            ms: 0,
        }
    }

    /// Axis `number` (1-based).
    pub fn axis(&self, number: u8) -> Option<&Axis> {
        self.axes.get(usize::from(number).checked_sub(1)?)
    }

    /// Injects `fault` into one axis only (following error and over-current
    /// are an axis's; temperature and voltage are the board's).
    pub fn inject_axis_fault(
        &mut self,
        io: &mut DeviceIo<'_>,
        number: u8,
        fault: Fault,
    ) -> Result<(), FaultError> {
        self.set_axis_fault(io, Some(number), fault, true)
    }

    /// Ends a fault injected with [`Umc::inject_axis_fault`].
    pub fn clear_axis_fault(
        &mut self,
        io: &mut DeviceIo<'_>,
        number: u8,
        fault: Fault,
    ) -> Result<(), FaultError> {
        self.set_axis_fault(io, Some(number), fault, false)
    }

    fn not_applicable(&self, fault: Fault) -> FaultError {
        FaultError::NotApplicable {
            product: self.product(),
            fault,
        }
    }

    fn set_axis_fault(
        &mut self,
        io: &mut DeviceIo<'_>,
        only: Option<u8>,
        fault: Fault,
        on: bool,
    ) -> Result<(), FaultError> {
        let condition = Condition::of_fault(fault).ok_or_else(|| self.not_applicable(fault))?;
        let board_wide = matches!(
            condition,
            Condition::OverTemperature | Condition::UnderVoltage
        );
        if only.is_some() && board_wide {
            return Err(self.not_applicable(fault));
        }
        match condition {
            Condition::OverTemperature => self.board.heated = on,
            Condition::UnderVoltage => self.board.drained = on,
            _ => {
                for axis in &mut self.axes {
                    if only.is_some_and(|n| n != axis.number) {
                        continue;
                    }
                    axis.injected = axis.injected.set(condition, on);
                    if condition == Condition::FollowingError {
                        // The load seizes: the axis cannot follow.
                        axis.motor.jammed = on;
                    }
                }
            }
        }
        self.board
            .apply_injections(condition == Condition::OverTemperature && !on);
        self.board.update(io, &mut self.axes, 0.0);
        let supply = self.board.supply_state();
        for axis in &mut self.axes {
            axis.see_supply(supply);
            axis.supervise(io);
        }
        Ok(())
    }

    /// A fault reset ended a fault: the register keeps the bits other
    /// faults still hold, and the error reset EMCY goes out.
    fn news(&mut self, io: &mut DeviceIo<'_>, number: u8, news: AxisNews) {
        if news.fault_reset {
            for bit in FAULT_BITS {
                let held = self.axes.iter().any(|axis| axis.holds_error_bit(bit));
                io.set_error_bit(bit, held);
            }
            io.emcy(0x0000, [number, 0, 0, 0, 0]);
        }
    }
}

impl Behaviour for Umc {
    /// The manual's EMCY table (chapter 3 §6.1) lists 0x8220.
    fn reports_pdo_length_exceeded(&self) -> bool {
        true
    }

    fn product(&self) -> &'static str {
        if self.axes.len() > 1 {
            "umc1bds32"
        } else {
            "umc1bd90"
        }
    }

    fn reset(&mut self, io: &mut DeviceIo<'_>) {
        self.ms = 0;
        let count = self.board.bridge_count;
        self.board = Board::new(count);
        self.board.read_limits(io);
        self.board.update(io, &mut self.axes, 0.0);
        let supply = self.board.supply_state();
        for axis in &mut self.axes {
            axis.reset(io, supply);
        }
    }

    fn check_value(
        &self,
        _store: &ObjectStore,
        index: u16,
        sub: u8,
        data: &[u8],
    ) -> Result<(), AbortCode> {
        let Some((number, base)) = umc::index_axis(index) else {
            return Ok(());
        };
        let Some(axis) = self.axis(number) else {
            return Ok(());
        };
        match (base, sub) {
            // A value of the wrong length is the dictionary's to refuse.
            (d::MODES_OF_OPERATION, 0) if data.len() == 1 => {
                let mode = Mode::from_raw(data[0] as i8);
                if mode != Mode::NoMode && !SUPPORTED_MODES.contains(&mode) {
                    return Err(AbortCode::InvalidValue);
                }
            }
            (d::IP_DATA_RECORD, 1) if axis.ip.is_full() => {
                return Err(AbortCode::CannotStoreDeviceState);
            }
            // Table 2.11 has no 3 and 4 (current and voltage limit).
            (d::QUICK_STOP_OPTION, 0) if matches!(data, [3 | 4, 0]) => {
                return Err(AbortCode::InvalidValue);
            }
            _ => {}
        }
        Ok(())
    }

    fn written(&mut self, io: &mut DeviceIo<'_>, index: u16, sub: u8) {
        match umc::index_axis(index) {
            Some((number, base)) => {
                let Some(axis) = self.axes.get_mut(usize::from(number) - 1) else {
                    return;
                };
                let news = axis.written(io, base, sub);
                self.news(io, number, news);
            }
            None if index == board::UNDERVOLTAGE.0 || index == board::TEMPERATURE_LOW.0 => {
                self.board.read_limits(io);
                self.board.update(io, &mut self.axes, 0.0);
                let supply = self.board.supply_state();
                for axis in &mut self.axes {
                    axis.see_supply(supply);
                    axis.supervise(io);
                    axis.publish(io, true);
                }
            }
            None => {}
        }
    }

    fn tick(&mut self, io: &mut DeviceIo<'_>) {
        self.ms += 1;
        let slow = self.ms.is_multiple_of(SLOW_MS);
        if slow {
            if self.ms.is_multiple_of(REPUBLISH_MS) {
                self.board.published = [None; BOARD_SLOTS];
                for axis in &mut self.axes {
                    axis.republish();
                }
            }
            self.board
                .update(io, &mut self.axes, SLOW_MS as f64 / 1000.0);
        }
        let supply = self.board.supply_state();
        for axis in &mut self.axes {
            axis.tick(io, supply, slow);
        }
    }

    fn nmt_changed(&mut self, io: &mut DeviceIo<'_>, from: NmtState, to: NmtState) {
        // 0x6007: an NMT change away from operational loses the master.
        if from == NmtState::Operational && to != NmtState::Operational {
            for axis in &mut self.axes {
                axis.connection_lost(io);
            }
        }
    }

    fn connection_lost(&mut self, io: &mut DeviceIo<'_>) {
        for axis in &mut self.axes {
            axis.connection_lost(io);
        }
    }

    fn inject_fault(&mut self, io: &mut DeviceIo<'_>, fault: Fault) -> Result<(), FaultError> {
        self.set_axis_fault(io, None, fault, true)
    }

    fn clear_fault(&mut self, io: &mut DeviceIo<'_>, fault: Fault) -> Result<(), FaultError> {
        self.set_axis_fault(io, None, fault, false)
    }
}

/// The board objects written when they change: 0x2000.1, 0x2020.1–2,
/// 0x2021.1–2, then 0x2801, 0x2802, 0x2804, 0x2805 sub 1–4.
const BOARD_SLOTS: usize = 5 + 4 * 4;

/// The board: supply, bridges, CPUs.
struct Board {
    /// 4 on the UMC1BDS32, 3 on the UMC1BD90.
    bridge_count: usize,
    bridges: [Thermal; 4],
    /// Each bridge's over-temperature trigger.
    bridge_hot: [bool; 4],
    windings: [Thermal; 2],
    cpus: [Thermal; 2],
    life_cycles: [u16; 2],
    /// The source voltage, V.
    source: f64,
    /// The board voltage after the supply's resistance, V.
    voltage: f64,
    /// 0x2041.1 and .2, V.
    under_limit: f64,
    over_limit: f64,
    /// 0x2810.1 and .2, °C.
    temperature_low: f64,
    temperature_high: f64,
    /// An injected over-temperature: the bridges are heated from outside.
    heated: bool,
    /// An injected under-voltage: the source sags below 0x2041.1.
    drained: bool,
    /// Per bridge: current (A), duty (−1 to 1, `None` floating), back-EMF (V).
    bridge_state: [(f64, Option<f64>, f64); 4],
    published: [Option<i64>; BOARD_SLOTS],
}

impl Board {
    fn new(bridge_count: usize) -> Board {
        let (r, tau) = BRIDGE_THERMAL;
        let (wr, wtau) = WINDING_THERMAL;
        let (cr, ctau) = CPU_THERMAL;
        Board {
            bridge_count,
            bridges: [Thermal::new(AMBIENT, r, tau); 4],
            bridge_hot: [false; 4],
            windings: [Thermal::new(AMBIENT, wr, wtau); 2],
            cpus: [Thermal::new(AMBIENT + CPU_POWER.0 * cr, cr, ctau); 2],
            life_cycles: [0; 2],
            source: NOMINAL_SUPPLY,
            voltage: NOMINAL_SUPPLY,
            under_limit: 11.0,
            over_limit: 60.0,
            temperature_low: 75.0,
            temperature_high: 80.0,
            heated: false,
            drained: false,
            bridge_state: [(0.0, None, 0.0); 4],
            published: [None; BOARD_SLOTS],
        }
    }

    fn read_limits(&mut self, io: &DeviceIo<'_>) {
        let read = |(index, sub): (u16, u8), default: f64| io.real(index, sub).unwrap_or(default);
        self.under_limit = read(board::UNDERVOLTAGE, 1100.0) / 100.0;
        self.over_limit = read(board::OVERVOLTAGE, 6000.0) / 100.0;
        self.temperature_low = read(board::TEMPERATURE_LOW, 750.0) / 10.0;
        self.temperature_high = read(board::TEMPERATURE_HIGH, 800.0) / 10.0;
        self.apply_injections(false);
    }

    /// What the injected conditions do to the board; `cooled` when one was
    /// just removed (the bridges are cooled below the low trigger, the
    /// source is back).
    fn apply_injections(&mut self, cooled: bool) {
        if self.heated {
            for bridge in &mut self.bridges {
                bridge.temperature = bridge.temperature.max(self.temperature_high + 2.0);
            }
        } else if cooled {
            for bridge in &mut self.bridges {
                bridge.temperature = bridge.temperature.min(self.temperature_low - 1.0);
            }
        }
        self.source = if self.drained {
            (self.under_limit - 1.0).max(0.0)
        } else {
            NOMINAL_SUPPLY
        };
    }

    fn supply_state(&self) -> Supply {
        Supply {
            voltage: self.voltage,
            under_voltage: self.voltage < self.under_limit,
            over_voltage: self.voltage > self.over_limit,
        }
    }

    /// `seconds` of heating and cooling (0 only re-evaluates), then the
    /// board objects and each axis's temperature flags.
    fn update(&mut self, io: &mut DeviceIo<'_>, axes: &mut [Axis], seconds: f64) {
        let mut drawn = 0.0;
        let mut enabled = 0.0;
        for (k, axis) in axes.iter_mut().enumerate() {
            let motor = &axis.motor;
            drawn += motor.duty * motor.current;
            if motor.driven {
                enabled += 1.0;
            }
            // A DC axis drives two bridges as an H-bridge; the BLDC axis of
            // the UMC1BD90 drives two of its three at a time, the third
            // floating (trapezoidal commutation).
            let first = 2 * k;
            let legs = if self.bridge_count == 3 { 3 } else { 2 };
            let emf = motor.back_emf();
            for leg in 0..legs {
                let bridge = first + leg;
                if bridge >= self.bridge_count {
                    break;
                }
                let sign = if leg == 0 { 1.0 } else { -1.0 };
                let state = if !motor.driven || leg > 1 {
                    (0.0, None, if leg > 1 { 0.0 } else { sign * emf / 2.0 })
                } else {
                    (
                        sign * motor.current,
                        Some(0.5 + sign * motor.duty / 2.0),
                        sign * emf / 2.0,
                    )
                };
                self.bridge_state[bridge] = state;
                let loss = if motor.driven && leg < 2 {
                    motor.current * motor.current * BRIDGE_RESISTANCE + SWITCHING_LOSS
                } else {
                    0.0
                };
                self.bridges[bridge].step(loss, AMBIENT, seconds);
            }
            let winding_loss = motor.current * motor.current * motor.model.resistance;
            self.windings[k].step(winding_loss, AMBIENT, seconds);
            axis.motor_temperature = self.windings[k].temperature;
        }
        let cpu_power = CPU_POWER.0 + CPU_POWER.1 * enabled;
        for cpu in &mut self.cpus {
            cpu.step(cpu_power, AMBIENT, seconds);
        }
        let cycles = (seconds * 1000.0) as u16 * CPU_CYCLES_PER_MS;
        for life in &mut self.life_cycles {
            *life = life.wrapping_add(cycles);
        }
        self.apply_injections(false);
        self.voltage = (self.source - SUPPLY_RESISTANCE * drawn).max(0.0);
        let (low, high) = (self.temperature_low, self.temperature_high);
        for bridge in 0..self.bridge_count {
            let t = self.bridges[bridge].temperature;
            self.bridge_hot[bridge] = schmitt(self.bridge_hot[bridge], t, low, high);
        }
        for (k, axis) in axes.iter_mut().enumerate() {
            let mine = if self.bridge_count == 3 {
                0..3
            } else {
                2 * k..2 * k + 2
            };
            axis.over_temperature = mine.clone().any(|b| self.bridge_hot[b]);
            axis.warm = mine.into_iter().any(|b| self.bridges[b].temperature > low);
        }
        self.publish(io);
    }

    fn publish(&mut self, io: &mut DeviceIo<'_>) {
        let mut values = [(0u16, 0u8, 0i64); BOARD_SLOTS];
        let mut n = 0;
        let mut push = |index: u16, sub: u8, value: f64| {
            values[n] = (index, sub, value.round() as i64);
            n += 1;
        };
        push(board::VOLTAGE.0, board::VOLTAGE.1, self.voltage * 100.0);
        for (k, cpu) in self.cpus.iter().enumerate() {
            push(board::CPU_TEMPERATURE, k as u8 + 1, cpu.temperature * 10.0);
        }
        for (k, life) in self.life_cycles.iter().enumerate() {
            push(board::CPU_LIFE_CYCLE, k as u8 + 1, f64::from(*life));
        }
        for k in 0..4 {
            let sub = k as u8 + 1;
            let (current, duty, emf) = self.bridge_state[k];
            push(
                board::DRIVER_TEMPERATURE,
                sub,
                self.bridges[k].temperature * 10.0,
            );
            push(board::CURRENTS_HL, sub, current * 100.0);
            push(board::PWM, sub, duty.map_or(-1.0, |d| d * 32768.0));
            push(board::BACK_EMF, sub, emf * 10.0);
        }
        for (slot, (index, sub, value)) in values.into_iter().enumerate() {
            if self.published[slot] != Some(value) {
                // The UMC1BD90 has no bridge D: the write finds no object.
                io.set_int(index, sub, value);
                self.published[slot] = Some(value);
            }
        }
    }
}
