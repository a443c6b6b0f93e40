//! UniSwarm UMC motion controllers (UMC firmware manual): where each axis's
//! objects are (§1.3.1 "Multi-axis", Table 1.5; chapter 2 §1.1, Table 2.1),
//! the board and axis objects a master or a virtual device reads, and the
//! units the manual uses (Q15.16, tenths of a degree, hundredths of a volt
//! or an ampere, the interpolation period of 0x60C2).
//!
//! The manual documents axis 1; axis `n` (1–8) finds the CiA 402 objects
//! at `index + 0x800 * (n - 1)` and the manufacturer axis objects at
//! `index + 0x200 * (n - 1)`. The constants below are axis 1's.

/// 0x2040 Communication_config (§2.3): sub 1 Node_ID, sub 2 Bit_rate.
/// A new value takes effect once stored (0x1010) and the node restarted;
/// the UIO1LED has the same object (its manual §4.2).
pub const COMMUNICATION_CONFIG: u16 = 0x2040;
/// Index step of the standardized profile area (0x6000–0x9FFF) per axis
/// (Table 2.1: axis 2 at 0x6800–0x6FFF).
pub const PROFILE_AXIS_STEP: u16 = 0x800;
/// Index step of the manufacturer axis area (0x4000–0x4FFF) per axis
/// (Table 1.5: axis 2 at 0x4200–0x43FF).
pub const MANUFACTURER_AXIS_STEP: u16 = 0x200;
/// The most axes one device addresses (Tables 1.5 and 2.1).
pub const MAX_AXES: u8 = 8;
/// First index of the standardized profile area.
const PROFILE_AREA: u16 = 0x6000;
/// First index of the manufacturer axis area.
const MANUFACTURER_AXIS_AREA: u16 = 0x4000;

/// Axis `axis`'s copy of the axis-1 object `index`: shifted by
/// [`PROFILE_AXIS_STEP`] in 0x6000–0x9FFF, by [`MANUFACTURER_AXIS_STEP`] in
/// 0x4000–0x4FFF, unchanged elsewhere (board and communication objects
/// are shared). `None` for an axis outside 1–8.
pub fn axis_index(axis: u8, index: u16) -> Option<u16> {
    if !(1..=MAX_AXES).contains(&axis) {
        return None;
    }
    let n = u16::from(axis - 1);
    Some(match index {
        0x6000..=0x67FF => index + PROFILE_AXIS_STEP * n,
        0x4000..=0x41FF => index + MANUFACTURER_AXIS_STEP * n,
        _ => index,
    })
}

/// The axis (1–8) an index belongs to and the axis-1 index it is the copy
/// of; `None` for an index outside both axis areas.
pub fn index_axis(index: u16) -> Option<(u8, u16)> {
    match index {
        PROFILE_AREA..=0x9FFF => {
            let offset = index - PROFILE_AREA;
            let axis = offset / PROFILE_AXIS_STEP;
            Some((axis as u8 + 1, index - axis * PROFILE_AXIS_STEP))
        }
        MANUFACTURER_AXIS_AREA..=0x4FFF => {
            let offset = index - MANUFACTURER_AXIS_AREA;
            let axis = offset / MANUFACTURER_AXIS_STEP;
            Some((axis as u8 + 1, index - axis * MANUFACTURER_AXIS_STEP))
        }
        _ => None,
    }
}

/// The axis (1–8) an EMCY belongs to: the UMC's axis faults carry their
/// axis number in the first manufacturer byte (the virtual UMC sends them
/// so, docs/virtual-devices.md); a 0 there, or a number outside 1–8, is a
/// board or communication EMCY that belongs to no axis in particular.
pub fn emcy_axis(manufacturer: &[u8; 5]) -> Option<u8> {
    (1..=MAX_AXES)
        .contains(&manufacturer[0])
        .then_some(manufacturer[0])
}

/// Q15.16, the manual's fixed-point type: a signed 32-bit value in
/// 1/65536ths.
pub const Q15_16_ONE: f64 = 65536.0;

/// A number as Q15.16, saturating at the type's range.
pub fn to_q15_16(value: f64) -> i32 {
    // `as` saturates (and maps NaN to 0), which a measurement wants.
    (value * Q15_16_ONE).round() as i32
}

/// A Q15.16 value as a number.
pub fn from_q15_16(raw: i32) -> f64 {
    f64::from(raw) / Q15_16_ONE
}

/// A Q15.16 value as it travels in an SDO or a PDO: four bytes, little
/// endian (CiA 301 INTEGER32).
pub fn q15_16_to_le_bytes(value: f64) -> [u8; 4] {
    to_q15_16(value).to_le_bytes()
}

/// The number four little-endian bytes of Q15.16 hold; `None` unless
/// there are exactly four.
pub fn q15_16_from_le_bytes(bytes: &[u8]) -> Option<f64> {
    let raw: [u8; 4] = bytes.try_into().ok()?;
    Some(from_q15_16(i32::from_le_bytes(raw)))
}

/// The interpolation cycle time of 0x60C2 (eq. 2.5: `units * 10^index`
/// seconds) in milliseconds; `None` for a zero period (no interpolation).
pub fn ip_period_ms(time_units: u8, time_index: i8) -> Option<f64> {
    let seconds = f64::from(time_units) * 10f64.powi(i32::from(time_index));
    (seconds > 0.0 && seconds.is_finite()).then_some(seconds * 1000.0)
}

/// Board objects (chapter 1 §2): shared by all axes.
pub mod board {
    /// 0x2000.1 Board_voltage_input, UINT16 in 0.01 V (§2.1: used for
    /// under/over-voltage detection).
    pub const VOLTAGE: (u16, u8) = (0x2000, 1);
    /// 0x2020.n CPU_temperature, INT16 in 0.1 °C, one per CPU (sub 1, 2).
    pub const CPU_TEMPERATURE: u16 = 0x2020;
    /// 0x2021.n CPU_life_cycle, UINT16 counting CPU cycles (sub 1, 2).
    pub const CPU_LIFE_CYCLE: u16 = 0x2021;
    /// 0x2041.1 Undervoltage, UINT16 in 0.01 V (default 1100).
    pub const UNDERVOLTAGE: (u16, u8) = (0x2041, 1);
    /// 0x2041.2 Overvoltage, UINT16 in 0.01 V (default 6000).
    pub const OVERVOLTAGE: (u16, u8) = (0x2041, 2);
    /// 0x2801.n Driver_temperature, INT16 in 0.1 °C, one per bridge
    /// (A–D, sub 1–4; three on the UMC1BD90).
    pub const DRIVER_TEMPERATURE: u16 = 0x2801;
    /// 0x2802.n Currents_HL, INT16 in 0.01 A, per bridge.
    pub const CURRENTS_HL: u16 = 0x2802;
    /// 0x2804.n PWM, INT16, 0–32768 = 0–100 %, −1 for a floating bridge.
    pub const PWM: u16 = 0x2804;
    /// 0x2805.n Back_EMF, INT16 in 0.1 V, per bridge.
    pub const BACK_EMF: u16 = 0x2805;
    /// 0x2810.1 Protection_schmitt_triggers_low, INT16 in 0.1 °C: below
    /// it an over-temperature ends (default 750).
    pub const TEMPERATURE_LOW: (u16, u8) = (0x2810, 1);
    /// 0x2810.2 Protection_schmitt_triggers_high, INT16 in 0.1 °C: above
    /// it the driver is over-temperature (default 800).
    pub const TEMPERATURE_HIGH: (u16, u8) = (0x2810, 2);
}

/// Axis-1 manufacturer objects (chapter 1 §3); axis `n` at
/// `+ 0x200 * (n - 1)` ([`axis_index`]).
pub mod axis {
    /// 0x4000.1 a1_Motion_status Error, UINT16 bit field (Figure 1.2).
    pub const MOTION_ERROR: (u16, u8) = (0x4000, 1);
    /// 0x4006 a1_Motor_status: 1 Command (INT16 duty, ±32768 = ±100 %),
    /// 2 Current (INT16, 0.01 A), 3 Torque (Q15.16 N·m), 4 Velocity
    /// (Q15.16), 5 Position (Q15.16), 6 Error (UINT16, Figure 1.3),
    /// 7 Temperature (INT16, 0.1 °C).
    pub const MOTOR_STATUS: u16 = 0x4006;
    /// 0x4007 a1_Motor_config: 2 Peak_current, 3 Burst_current,
    /// 5 Sustained_current (UINT16, 0.01 A), 4 Burst_duration (ms),
    /// 6 Current_constant (Q15.16 N·m/A), 7 Max_velocity (rpm).
    pub const MOTOR_CONFIG: u16 = 0x4007;
    /// 0x4008 a1_BLDC_status: 1 Hall_raw_value (INT8, 3 bits), 2
    /// Hall_phase (INT8), 3 Electrical_angle (INT16, degrees).
    pub const BLDC_STATUS: u16 = 0x4008;
    /// 0x4009.1 a1_BLDC_config Pole_pair, UINT8.
    pub const POLE_PAIRS: (u16, u8) = (0x4009, 1);
    /// 0x4020 a1_Torque_PID_status: 1 Input, 2 Error, 3 Integrator,
    /// 4 Output (Q15.16).
    pub const TORQUE_PID_STATUS: u16 = 0x4020;
    /// 0x4040 a1_Velocity_PID_status, as 0x4020.
    pub const VELOCITY_PID_STATUS: u16 = 0x4040;
    /// 0x4060 a1_Position_PID_status, as 0x4020.
    pub const POSITION_PID_STATUS: u16 = 0x4060;
    /// 0x4021 a1_Torque_PID_config (§3.5.3), see [`super::pid`].
    pub const TORQUE_PID_CONFIG: u16 = 0x4021;
    /// 0x4041 a1_Velocity_PID_config, as 0x4021.
    pub const VELOCITY_PID_CONFIG: u16 = 0x4041;
    /// 0x4061 a1_Position_PID_config, as 0x4021.
    pub const POSITION_PID_CONFIG: u16 = 0x4061;
    /// 0x4022 a1_Torque_sensor_status: 1 Raw_data, 2 Flags, 3 Value
    /// (Q15.16).
    pub const TORQUE_SENSOR_STATUS: u16 = 0x4022;
    /// 0x4042 a1_Velocity_sensor_status, as 0x4022.
    pub const VELOCITY_SENSOR_STATUS: u16 = 0x4042;
    /// 0x4062 a1_Position_sensor_status, as 0x4022.
    pub const POSITION_SENSOR_STATUS: u16 = 0x4062;
    /// 0x41F0 a1_cp_target, INT32: the continuous position set point.
    pub const CP_TARGET: u16 = 0x41F0;
    /// 0x41FA a1_dty_target, INT16.
    pub const DTY_TARGET: u16 = 0x41FA;
    /// 0x41FB a1_dty_demand, INT16.
    pub const DTY_DEMAND: u16 = 0x41FB;
    /// 0x41FC a1_dty_max, UINT16.
    pub const DTY_MAX: u16 = 0x41FC;
    /// 0x41FD a1_dty_slope, UINT16 per second.
    pub const DTY_SLOPE: u16 = 0x41FD;

    /// Motor error bits of 0x4006.6 (Figure 1.3).
    pub mod motor_error {
        /// b0 OC: over-current.
        pub const OVER_CURRENT: u16 = 1 << 0;
        /// b1 OS: over-speed.
        pub const OVER_SPEED: u16 = 1 << 1;
        /// b2 DOT: driver over-temperature.
        pub const DRIVER_OVER_TEMPERATURE: u16 = 1 << 2;
    }

    /// Motion error bits of 0x4000.1 (Figure 1.2).
    pub mod motion_error {
        /// b0 Brd: error from the board.
        pub const BOARD: u16 = 1 << 0;
        /// b1 Mot: error from the motor.
        pub const MOTOR: u16 = 1 << 1;
        /// b7 PosC: error from the position controller.
        pub const POSITION_CONTROLLER: u16 = 1 << 7;
    }
}

/// The control loops of an axis (§3.5): three PIDs in cascade, position
/// into velocity into torque (current), each with a status record (§3.5.2:
/// 1 Input, 2 Error, 3 Integrator, 4 Output) and a configuration record
/// (§3.5.3), every number in Q15.16.
///
/// The manual leaves the loops' units to the firmware; candeck reads them
/// as the status objects report them: the position loop takes revolutions
/// and gives rpm, the velocity loop takes rpm and gives amperes, the torque
/// loop takes amperes and gives volts across the winding. I is per second
/// of integrated error, D per unit of error change per second.
pub mod pid {
    use super::axis;
    use super::{from_q15_16, to_q15_16};

    /// 0x4021.8 PID_flags bit 0 ANTI_REVERSE (Table 1.15): "prevent output
    /// with sign that differ with target".
    pub const ANTI_REVERSE: u16 = 0x0001;

    /// Sub-indices of a PID configuration record (§3.5.3).
    pub const P: u8 = 1;
    pub const I: u8 = 2;
    pub const D: u8 = 3;
    pub const MIN: u8 = 4;
    pub const MAX: u8 = 5;
    pub const THRESHOLD: u8 = 6;
    pub const FREQUENCY_DIVIDER: u8 = 7;
    pub const FLAGS: u8 = 8;
    /// Sub-indices of a PID status record (§3.5.2).
    pub const INPUT: u8 = 1;
    pub const ERROR: u8 = 2;
    pub const INTEGRATOR: u8 = 3;
    pub const OUTPUT: u8 = 4;

    /// One of an axis's three control loops.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
    pub enum Loop {
        /// 0x4020/0x4021: current, A in, V out.
        Torque,
        /// 0x4040/0x4041: rpm in, A out.
        Velocity,
        /// 0x4060/0x4061: revolutions in, rpm out.
        Position,
    }

    impl Loop {
        pub const ALL: [Loop; 3] = [Loop::Torque, Loop::Velocity, Loop::Position];

        /// Its name in the API: `torque`, `velocity`, `position`.
        pub fn name(self) -> &'static str {
            match self {
                Loop::Torque => "torque",
                Loop::Velocity => "velocity",
                Loop::Position => "position",
            }
        }

        pub fn from_name(name: &str) -> Option<Loop> {
            Loop::ALL.into_iter().find(|l| l.name() == name)
        }

        /// Axis 1's status record.
        pub fn status_index(self) -> u16 {
            match self {
                Loop::Torque => axis::TORQUE_PID_STATUS,
                Loop::Velocity => axis::VELOCITY_PID_STATUS,
                Loop::Position => axis::POSITION_PID_STATUS,
            }
        }

        /// Axis 1's configuration record.
        pub fn config_index(self) -> u16 {
            match self {
                Loop::Torque => axis::TORQUE_PID_CONFIG,
                Loop::Velocity => axis::VELOCITY_PID_CONFIG,
                Loop::Position => axis::POSITION_PID_CONFIG,
            }
        }

        /// The unit of the loop's input and error.
        pub fn input_unit(self) -> &'static str {
            match self {
                Loop::Torque => "A",
                Loop::Velocity => "rpm",
                Loop::Position => "rev",
            }
        }

        /// The unit of the loop's output, integrator, Min and Max.
        pub fn output_unit(self) -> &'static str {
            match self {
                Loop::Torque => "V",
                Loop::Velocity => "A",
                Loop::Position => "rpm",
            }
        }
    }

    /// A PID configuration record in human numbers.
    #[derive(Debug, Clone, Copy, PartialEq, Default)]
    pub struct PidConfig {
        pub p: f64,
        pub i: f64,
        pub d: f64,
        pub min: f64,
        pub max: f64,
        /// Errors within ±threshold count as none (a dead band).
        pub threshold: f64,
        /// The loop runs every this many board cycles (0 counts as 1).
        pub frequency_divider: u16,
        pub flags: u16,
    }

    impl PidConfig {
        /// From the record's raw values, subs 1 to 8 in order (Q15.16 for
        /// 1–6, UINT16 for 7 and 8).
        pub fn from_raw(raw: [i64; 8]) -> PidConfig {
            let q = |value: i64| from_q15_16(value as i32);
            PidConfig {
                p: q(raw[0]),
                i: q(raw[1]),
                d: q(raw[2]),
                min: q(raw[3]),
                max: q(raw[4]),
                threshold: q(raw[5]),
                frequency_divider: raw[6] as u16,
                flags: raw[7] as u16,
            }
        }

        /// The raw values of subs 1 to 8.
        pub fn to_raw(&self) -> [i64; 8] {
            let q = |value: f64| i64::from(to_q15_16(value));
            [
                q(self.p),
                q(self.i),
                q(self.d),
                q(self.min),
                q(self.max),
                q(self.threshold),
                i64::from(self.frequency_divider),
                i64::from(self.flags),
            ]
        }

        pub fn anti_reverse(&self) -> bool {
            self.flags & ANTI_REVERSE != 0
        }
    }
}

/// Axis-1 CiA 402 objects (chapter 2) as the UMC has them, with the units
/// of [`units`]; axis `n` at `+ 0x800 * (n - 1)` ([`axis_index`]).
pub mod drive {
    use crate::cia402::objects;

    /// 0x6007: INT16, Table 2.10.
    pub const ABORT_CONNECTION_OPTION: u16 = objects::ABORT_CONNECTION_OPTION;
    /// 0x6040: UINT16, Figure 2.4.
    pub const CONTROLWORD: u16 = objects::CONTROLWORD;
    /// 0x6041: UINT16, Tables 2.7 and 2.8.
    pub const STATUSWORD: u16 = objects::STATUSWORD;
    /// 0x6042: INT16, velocity units.
    pub const VL_TARGET: u16 = objects::VL_TARGET;
    /// 0x6043: INT16.
    pub const VL_DEMAND: u16 = objects::VL_DEMAND;
    /// 0x6044: INT16.
    pub const VL_ACTUAL: u16 = objects::VL_ACTUAL;
    /// 0x6046: UINT32 sub 1 min, 2 max.
    pub const VL_MIN_MAX: u16 = objects::VL_MIN_MAX;
    /// 0x6048: sub 1 delta speed, sub 2 delta time (ms).
    pub const VL_ACCELERATION: u16 = objects::VL_ACCELERATION;
    /// 0x6049: as 0x6048.
    pub const VL_DECELERATION: u16 = objects::VL_DECELERATION;
    /// 0x604A: as 0x6048.
    pub const VL_QUICK_STOP: u16 = objects::VL_QUICK_STOP;
    /// 0x604B: INT16 sub 1 numerator, 2 denominator.
    pub const VL_SET_POINT_FACTOR: u16 = objects::VL_SET_POINT_FACTOR;
    /// 0x604C: INT32 sub 1 numerator, 2 denominator: increments/ms per unit.
    pub const VL_DIMENSION_FACTOR: u16 = objects::VL_DIMENSION_FACTOR;
    /// 0x605A: INT16, Table 2.11.
    pub const QUICK_STOP_OPTION: u16 = objects::QUICK_STOP_OPTION;
    /// 0x605B: INT16, Table 2.12.
    pub const SHUTDOWN_OPTION: u16 = objects::SHUTDOWN_OPTION;
    /// 0x605C: INT16, Table 2.13.
    pub const DISABLE_OPERATION_OPTION: u16 = objects::DISABLE_OPERATION_OPTION;
    /// 0x605D: INT16, Table 2.14.
    pub const HALT_OPTION: u16 = objects::HALT_OPTION;
    /// 0x605E: INT16, Table 2.15.
    pub const FAULT_REACTION_OPTION: u16 = objects::FAULT_REACTION_OPTION;
    /// 0x6060: INT8, Figure 2.5.
    pub const MODES_OF_OPERATION: u16 = objects::MODES_OF_OPERATION;
    /// 0x6061: INT8.
    pub const MODES_OF_OPERATION_DISPLAY: u16 = objects::MODES_OF_OPERATION_DISPLAY;
    /// 0x6062: INT32, increments.
    pub const POSITION_DEMAND: u16 = objects::POSITION_DEMAND;
    /// 0x6063: INT32, increments.
    pub const POSITION_ACTUAL_INTERNAL: u16 = objects::POSITION_ACTUAL_INTERNAL;
    /// 0x6064: INT32, increments.
    pub const POSITION_ACTUAL: u16 = objects::POSITION_ACTUAL;
    /// 0x6065: UINT32, increments; 0xFFFFFFFF switches detection off.
    pub const FOLLOWING_ERROR_WINDOW: u16 = objects::FOLLOWING_ERROR_WINDOW;
    /// 0x6066: UINT16, ms.
    pub const FOLLOWING_ERROR_TIME_OUT: u16 = objects::FOLLOWING_ERROR_TIME_OUT;
    /// 0x6067: UINT32, increments.
    pub const POSITION_WINDOW: u16 = objects::POSITION_WINDOW;
    /// 0x6068: UINT16, ms.
    pub const POSITION_WINDOW_TIME: u16 = objects::POSITION_WINDOW_TIME;
    /// 0x606B: INT32, increments/ms.
    pub const VELOCITY_DEMAND: u16 = objects::VELOCITY_DEMAND;
    /// 0x606C: INT32, increments/ms.
    pub const VELOCITY_ACTUAL: u16 = objects::VELOCITY_ACTUAL;
    /// 0x6071: INT16, per mille of rated torque.
    pub const TQ_TARGET: u16 = objects::TQ_TARGET;
    /// 0x6072: UINT16, per mille of rated torque.
    pub const TQ_MAX: u16 = objects::TQ_MAX;
    /// 0x6073: UINT16, per mille of rated current (0: the peak current).
    pub const MAX_CURRENT: u16 = objects::MAX_CURRENT;
    /// 0x6074: INT16, per mille of rated torque.
    pub const TQ_DEMAND: u16 = objects::TQ_DEMAND;
    /// 0x6075: UINT32, mA (0: the sustained current 0x4007.5).
    pub const RATED_CURRENT: u16 = objects::RATED_CURRENT;
    /// 0x6077: INT16, per mille of rated torque.
    pub const TQ_ACTUAL: u16 = objects::TQ_ACTUAL;
    /// 0x6078: INT16, per mille of rated current.
    pub const CURRENT_ACTUAL: u16 = objects::CURRENT_ACTUAL;
    /// 0x6079: UINT32, mV.
    pub const DC_LINK_VOLTAGE: u16 = objects::DC_LINK_VOLTAGE;
    /// 0x607A: INT32, increments.
    pub const TARGET_POSITION: u16 = objects::TARGET_POSITION;
    /// 0x607D: INT32 sub 1 min, 2 max; both 0 switch them off.
    pub const SOFTWARE_POSITION_LIMIT: u16 = objects::SOFTWARE_POSITION_LIMIT;
    /// 0x607F: UINT32, increments/ms.
    pub const MAX_PROFILE_VELOCITY: u16 = objects::MAX_PROFILE_VELOCITY;
    /// 0x6080: UINT32, increments/ms.
    pub const MAX_MOTOR_SPEED: u16 = objects::MAX_MOTOR_SPEED;
    /// 0x6081: UINT32, increments/ms.
    pub const PROFILE_VELOCITY: u16 = objects::PROFILE_VELOCITY;
    /// 0x6083: UINT32, increments/ms².
    pub const PROFILE_ACCELERATION: u16 = objects::PROFILE_ACCELERATION;
    /// 0x6084: UINT32, increments/ms².
    pub const PROFILE_DECELERATION: u16 = objects::PROFILE_DECELERATION;
    /// 0x6085: UINT32, increments/ms².
    pub const QUICK_STOP_DECELERATION: u16 = objects::QUICK_STOP_DECELERATION;
    /// 0x6087: UINT32, per mille of rated torque per second.
    pub const TQ_SLOPE: u16 = objects::TQ_SLOPE;
    /// 0x60C1: INT32 sub 1: a set-point into the FIFO.
    pub const IP_DATA_RECORD: u16 = objects::IP_DATA_RECORD;
    /// 0x60C2: sub 1 units (UINT8), sub 2 index (INT8): units × 10^index s.
    pub const IP_TIME_PERIOD: u16 = objects::IP_TIME_PERIOD;
    /// 0x60C4: sub 1 maximum, 2 actual buffer size, 6 buffer clear (0 clears).
    pub const IP_DATA_CONFIGURATION: u16 = objects::IP_DATA_CONFIGURATION;
    /// 0x60C5: UINT32, increments/ms².
    pub const MAX_ACCELERATION: u16 = objects::MAX_ACCELERATION;
    /// 0x60C6: UINT32, increments/ms².
    pub const MAX_DECELERATION: u16 = objects::MAX_DECELERATION;
    /// 0x60F4: INT32, increments.
    pub const FOLLOWING_ERROR_ACTUAL: u16 = objects::FOLLOWING_ERROR_ACTUAL;
    /// 0x60FA: INT32: the velocity loop's command, increments/ms.
    pub const CONTROL_EFFORT: u16 = objects::CONTROL_EFFORT;
    /// 0x6502: UINT32, Figure 2.6.
    pub const SUPPORTED_DRIVE_MODES: u16 = objects::SUPPORTED_DRIVE_MODES;
}

/// The units the virtual UMC gives its user-defined units (the manual
/// leaves them to the configuration; 0x604C says velocities are "LSB per
/// millisecond" inside): positions in increments of 1/65536 revolution
/// (so 0x6064 and the Q15.16 revolutions of 0x4006.5 are the same number),
/// velocities in increments per millisecond, accelerations in increments
/// per millisecond squared.
pub mod units {
    /// Position increments per motor revolution.
    pub const INCREMENTS_PER_REV: f64 = 65536.0;
    /// What the position objects (0x6064, 0x607A, 0x607D) count.
    pub const POSITION_UNIT: &str = "increments";
    /// What the profile velocities (0x606C, 0x6081, 0x607F, 0x6080) count.
    pub const VELOCITY_UNIT: &str = "increments/ms";
    /// What the profile accelerations (0x6083, 0x6084) count.
    pub const ACCELERATION_UNIT: &str = "increments/ms²";
    /// What the VL objects (0x6042, 0x6044, 0x6046) count: increments/ms
    /// times the dimension factor 0x604C (§4.2.13, equation 2.4).
    pub const VL_VELOCITY_UNIT: &str = "vl units";

    /// Revolutions per second of 1 increment/ms.
    pub fn rps_per_increment_per_ms() -> f64 {
        1000.0 / INCREMENTS_PER_REV
    }

    /// A velocity in increments/ms as rpm.
    pub fn rpm_from_increments_per_ms(velocity: f64) -> f64 {
        velocity * 1000.0 * 60.0 / INCREMENTS_PER_REV
    }

    /// A velocity in rpm as increments/ms.
    pub fn increments_per_ms_from_rpm(rpm: f64) -> f64 {
        rpm * INCREMENTS_PER_REV / (1000.0 * 60.0)
    }

    /// A velocity in increments/ms as rad/s.
    pub fn rad_per_s_from_increments_per_ms(velocity: f64) -> f64 {
        velocity * 1000.0 * std::f64::consts::TAU / INCREMENTS_PER_REV
    }
}

/// What the commissioning pages of a UMC show (UMC manual chapter 1 §2
/// board, §3.2 motor, §3.3 brake, §3.4 sensors): each object with its
/// manual name, unit, scale and meaning, and whether a master may write it.
/// Axis 1's indices; [`axis_index`] moves the axis objects.
pub mod commissioning {
    /// How a raw value is shown.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub enum Kind {
        /// An integer times `scale` (0.01 A per unit: 0.01).
        Scaled(f64),
        /// Q15.16.
        Q15_16,
        /// A code or a bit field, shown in hexadecimal.
        Code,
    }

    /// One object of a page.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Object {
        pub index: u16,
        pub sub: u8,
        pub name: &'static str,
        pub kind: Kind,
        pub unit: &'static str,
        pub writable: bool,
        pub meaning: &'static str,
    }

    /// One commissioning page.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Page {
        /// Its path segment: `board`, `motor`, `brake`, `sensors`.
        pub slug: &'static str,
        pub title: &'static str,
        /// The manual's sections.
        pub sections: &'static str,
        pub objects: &'static [Object],
    }

    const fn o(
        index: u16,
        sub: u8,
        name: &'static str,
        kind: Kind,
        unit: &'static str,
        writable: bool,
        meaning: &'static str,
    ) -> Object {
        Object {
            index,
            sub,
            name,
            kind,
            unit,
            writable,
            meaning,
        }
    }

    use Kind::{Code, Q15_16, Scaled};
    const ONE: Kind = Scaled(1.0);
    const CENTI: Kind = Scaled(0.01);
    const DECI: Kind = Scaled(0.1);

    pub const BOARD: Page = Page {
        slug: "board",
        title: "Board status",
        sections: "§2.1–2.5",
        objects: &[
            o(
                0x2000,
                1,
                "Board_voltage_input",
                CENTI,
                "V",
                false,
                "Input power voltage, used for under/over-voltage detection",
            ),
            o(
                0x2041,
                1,
                "Undervoltage",
                CENTI,
                "V",
                true,
                "Below it, an under-voltage fault",
            ),
            o(
                0x2041,
                2,
                "Overvoltage",
                CENTI,
                "V",
                true,
                "Above it, an over-voltage fault",
            ),
            o(
                0x2020,
                1,
                "CPU1_temperature",
                DECI,
                "°C",
                false,
                "CPU temperature",
            ),
            o(
                0x2021,
                1,
                "CPU1_life_cycle",
                ONE,
                "cycles",
                false,
                "Counts the CPU's cycles (wraps at 65536)",
            ),
            o(
                0x2801,
                1,
                "Temperature_A",
                DECI,
                "°C",
                false,
                "Driver bridge A temperature",
            ),
            o(
                0x2801,
                2,
                "Temperature_B",
                DECI,
                "°C",
                false,
                "Driver bridge B temperature",
            ),
            o(
                0x2801,
                3,
                "Temperature_C",
                DECI,
                "°C",
                false,
                "Driver bridge C temperature",
            ),
            o(
                0x2810,
                1,
                "Protection_schmitt_triggers_low",
                DECI,
                "°C",
                true,
                "Below it an over-temperature ends",
            ),
            o(
                0x2810,
                2,
                "Protection_schmitt_triggers_high",
                DECI,
                "°C",
                true,
                "Above it a bridge is over-temperature",
            ),
            o(
                0x2802,
                1,
                "Current_A",
                CENTI,
                "A",
                false,
                "Bridge A current",
            ),
            o(
                0x2802,
                2,
                "Current_B",
                CENTI,
                "A",
                false,
                "Bridge B current",
            ),
            o(
                0x2804,
                1,
                "PWM_A",
                Scaled(100.0 / 32768.0),
                "%",
                false,
                "Bridge A duty cycle (−1: floating)",
            ),
            o(
                0x2804,
                2,
                "PWM_B",
                Scaled(100.0 / 32768.0),
                "%",
                false,
                "Bridge B duty cycle (−1: floating)",
            ),
            o(
                0x2805,
                1,
                "Back_EMF_A",
                DECI,
                "V",
                false,
                "Bridge A back-EMF",
            ),
            o(
                0x2805,
                2,
                "Back_EMF_B",
                DECI,
                "V",
                false,
                "Bridge B back-EMF",
            ),
        ],
    };

    pub const MOTOR: Page = Page {
        slug: "motor",
        title: "Motor",
        sections: "§3.2",
        objects: &[
            o(
                0x4007,
                1,
                "Type",
                Code,
                "",
                true,
                "0x0000 no motor, 0x0101 DC, 0x0201 BLDC trapezoidal with hall, 0x0202 BLDC sinusoidal with hall",
            ),
            o(
                0x4007,
                2,
                "Peak_current",
                CENTI,
                "A",
                true,
                "Hardware comparator: above it every bridge opens",
            ),
            o(
                0x4007,
                3,
                "Burst_current",
                CENTI,
                "A",
                true,
                "Software limit: above it for Burst_duration, an over-current fault",
            ),
            o(
                0x4007,
                4,
                "Burst_duration",
                ONE,
                "ms",
                true,
                "How long the burst current may last",
            ),
            o(
                0x4007,
                5,
                "Sustained_current",
                CENTI,
                "A",
                true,
                "Continuous phase current (the rated current unless 0x6075 says)",
            ),
            o(
                0x4007,
                6,
                "Current_constant",
                Q15_16,
                "N·m/A",
                true,
                "Torque reported per ampere",
            ),
            o(
                0x4007,
                7,
                "Max_velocity",
                ONE,
                "rpm",
                true,
                "Above it, an over-speed fault (0: unwatched)",
            ),
            o(
                0x4007,
                8,
                "Velocity_constant",
                Q15_16,
                "rpm/V",
                true,
                "Velocity from back-EMF, for specific motors",
            ),
            o(
                0x4007,
                9,
                "Flags",
                Code,
                "",
                true,
                "b0 Rd: reverse motor direction",
            ),
            o(
                0x4009,
                1,
                "Pole_pair",
                ONE,
                "",
                true,
                "Pole pairs, BLDC motors only",
            ),
            o(
                0x4006,
                1,
                "Command",
                Scaled(100.0 / 32768.0),
                "%",
                false,
                "Duty cycle sent to the power stage",
            ),
            o(
                0x4006,
                2,
                "Current",
                CENTI,
                "A",
                false,
                "Average phase current",
            ),
            o(
                0x4006,
                3,
                "Torque",
                Q15_16,
                "N·m",
                false,
                "Current times the current constant",
            ),
            o(
                0x4006,
                4,
                "Velocity",
                Q15_16,
                "rpm",
                false,
                "Motor velocity",
            ),
            o(
                0x4006,
                5,
                "Position",
                Q15_16,
                "rev",
                false,
                "Motor position",
            ),
            o(
                0x4006,
                6,
                "Error",
                Code,
                "",
                false,
                "b0 OC over-current, b1 OS over-speed, b2 DOT driver over-temperature, b3 MOT motor over-temperature, b7 Cfg, b8 HI hall",
            ),
            o(
                0x4006,
                7,
                "Temperature",
                DECI,
                "°C",
                false,
                "Motor temperature",
            ),
        ],
    };

    pub const BRAKE: Page = Page {
        slug: "brake",
        title: "Brake",
        sections: "§3.3",
        objects: &[
            o(
                0x4082,
                1,
                "Brake_mode",
                Code,
                "",
                true,
                "0 disabled; 2/3 open drain, 4/5 open source, 6/7 push-pull (even: normally closed, odd: normally open)",
            ),
            o(
                0x4082,
                2,
                "Brake_excitation_time_ms",
                ONE,
                "ms",
                true,
                "Excitation duration (0: none)",
            ),
            o(
                0x4082,
                3,
                "Brake_excitation_duty",
                Scaled(100.0 / 65535.0),
                "%",
                true,
                "Duty cycle during excitation",
            ),
            o(
                0x4082,
                4,
                "Brake_activated_duty",
                Scaled(100.0 / 65535.0),
                "%",
                true,
                "Duty cycle after excitation",
            ),
        ],
    };

    pub const SENSORS: Page = Page {
        slug: "sensors",
        title: "Sensors",
        sections: "§3.4",
        objects: &[
            o(
                0x4023,
                1,
                "Torque Sensor_select",
                Code,
                "",
                true,
                "0x1100 TORQUE_FROM_MOTOR, 0x3101 QEI_CH1, 0x4001 ANALOG_CH1, …",
            ),
            o(
                0x4023,
                2,
                "Torque Frequency_divider",
                ONE,
                "",
                true,
                "The sensor is read every n cycles",
            ),
            o(
                0x4022,
                1,
                "Torque Raw_data",
                Q15_16,
                "A",
                false,
                "Raw value from the sensor",
            ),
            o(
                0x4022,
                3,
                "Torque Value",
                Q15_16,
                "A",
                false,
                "After filtering and conditioning",
            ),
            o(
                0x4043,
                1,
                "Velocity Sensor_select",
                Code,
                "",
                true,
                "0x1200 VELOCITY_FROM_MOTOR, 0x2300 VELOCITY_FROM_POSITION, …",
            ),
            o(
                0x4043,
                2,
                "Velocity Frequency_divider",
                ONE,
                "",
                true,
                "The sensor is read every n cycles",
            ),
            o(
                0x4042,
                1,
                "Velocity Raw_data",
                Q15_16,
                "rpm",
                false,
                "Raw value from the sensor",
            ),
            o(
                0x4042,
                3,
                "Velocity Value",
                Q15_16,
                "rpm",
                false,
                "After filtering and conditioning",
            ),
            o(
                0x4045,
                2,
                "Velocity Scale",
                Q15_16,
                "",
                true,
                "Conditioning: (raw + pre-offset) × scale + post-offset",
            ),
            o(
                0x4063,
                1,
                "Position Sensor_select",
                Code,
                "",
                true,
                "0x1300 POSITION_FROM_MOTOR, 0x2200 POSITION_FROM_VELOCITY, 0x3101 QEI_CH1, 0x3201 SSI_CH1, …",
            ),
            o(
                0x4063,
                2,
                "Position Frequency_divider",
                ONE,
                "",
                true,
                "The sensor is read every n cycles",
            ),
            o(
                0x4062,
                1,
                "Position Raw_data",
                Q15_16,
                "rev",
                false,
                "Raw value from the sensor",
            ),
            o(
                0x4062,
                3,
                "Position Value",
                Q15_16,
                "rev",
                false,
                "After filtering and conditioning",
            ),
            o(
                0x4064,
                1,
                "Position Filter_select",
                Code,
                "",
                true,
                "0x0000 no filter, 0x2000 averaging of N samples",
            ),
            o(
                0x4065,
                2,
                "Position Scale",
                Q15_16,
                "",
                true,
                "Conditioning: (raw + pre-offset) × scale + post-offset",
            ),
            o(
                0x4065,
                8,
                "Position Threshold_mode",
                Code,
                "",
                true,
                "0 none, 1 min-max, 2 modulo, 3 last valid value",
            ),
        ],
    };

    pub const PAGES: [Page; 4] = [BOARD, MOTOR, BRAKE, SENSORS];

    /// The page of a path segment.
    pub fn page(slug: &str) -> Option<Page> {
        PAGES.into_iter().find(|page| page.slug == slug)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_emcy_belongs_to_the_axis_in_its_first_manufacturer_byte() {
        assert_eq!(emcy_axis(&[2, 0, 0, 0, 0]), Some(2));
        assert_eq!(emcy_axis(&[1, 9, 9, 9, 9]), Some(1));
        assert_eq!(emcy_axis(&[8, 0, 0, 0, 0]), Some(8));
        assert_eq!(emcy_axis(&[0, 0, 0, 0, 0]), None);
        assert_eq!(emcy_axis(&[9, 0, 0, 0, 0]), None);
    }

    #[test]
    fn axes_are_at_the_manuals_offsets() {
        assert_eq!(axis_index(1, 0x6040), Some(0x6040));
        assert_eq!(axis_index(2, 0x6040), Some(0x6840));
        assert_eq!(axis_index(8, 0x6041), Some(0x9841));
        assert_eq!(axis_index(2, 0x4006), Some(0x4206));
        assert_eq!(axis_index(2, 0x41FA), Some(0x43FA));
        assert_eq!(axis_index(2, 0x2801), Some(0x2801));
        assert_eq!(axis_index(0, 0x6040), None);
        assert_eq!(axis_index(9, 0x6040), None);
        assert_eq!(index_axis(0x6840), Some((2, 0x6040)));
        assert_eq!(index_axis(0x6FFF), Some((2, 0x67FF)));
        assert_eq!(index_axis(0x43FA), Some((2, 0x41FA)));
        assert_eq!(index_axis(0x4006), Some((1, 0x4006)));
        assert_eq!(index_axis(0x2810), None);
    }

    #[test]
    fn q15_16_round_trips_and_saturates() {
        assert_eq!(to_q15_16(1.0), 65536);
        assert_eq!(to_q15_16(-0.5), -32768);
        assert_eq!(from_q15_16(98304), 1.5);
        assert_eq!(to_q15_16(40000.0), i32::MAX);
    }

    #[test]
    fn q15_16_travels_as_four_little_endian_bytes() {
        assert_eq!(q15_16_to_le_bytes(1.0), [0x00, 0x00, 0x01, 0x00]);
        assert_eq!(q15_16_to_le_bytes(-1.0), [0x00, 0x00, 0xFF, 0xFF]);
        assert_eq!(q15_16_to_le_bytes(3000.0), [0x00, 0x00, 0xB8, 0x0B]);
        assert_eq!(q15_16_to_le_bytes(0.015), [0xD7, 0x03, 0x00, 0x00]);
        assert_eq!(q15_16_to_le_bytes(-0.5), [0x00, 0x80, 0xFF, 0xFF]);
        assert_eq!(q15_16_from_le_bytes(&[0x00, 0x80, 0x01, 0x00]), Some(1.5));
        assert_eq!(
            q15_16_from_le_bytes(&[0xFF, 0xFF, 0xFF, 0x7F]),
            Some(32767.0 + 65535.0 / 65536.0)
        );
        assert_eq!(
            q15_16_from_le_bytes(&[0x00, 0x00, 0x00, 0x80]),
            Some(-32768.0)
        );
        // Truncated and over-long values are not Q15.16.
        assert_eq!(q15_16_from_le_bytes(&[0x00, 0x00, 0x01]), None);
        assert_eq!(q15_16_from_le_bytes(&[0, 0, 1, 0, 0]), None);
        assert_eq!(q15_16_from_le_bytes(&[]), None);
    }

    #[test]
    fn a_pid_record_round_trips_through_its_raw_values() {
        use pid::{Loop, PidConfig};
        let raw = [983, 13_107, 0, -2_097_152, 2_097_152, 655, 2, 1];
        let config = PidConfig::from_raw(raw);
        assert_eq!(config.p, 983.0 / 65536.0);
        assert_eq!(config.min, -32.0);
        assert_eq!(config.max, 32.0);
        assert_eq!(config.frequency_divider, 2);
        assert!(config.anti_reverse());
        assert_eq!(config.to_raw(), raw);
        assert_eq!(Loop::from_name("velocity"), Some(Loop::Velocity));
        assert_eq!(Loop::from_name("speed"), None);
        assert_eq!(axis_index(2, Loop::Position.config_index()), Some(0x4261));
    }

    #[test]
    fn every_commissioning_object_is_in_the_umc_edses() {
        for eds in [crate::builtin::UMC1BDS32, crate::builtin::UMC1BD90] {
            let dictionary = crate::canopen::eds::Eds::parse(eds, "x")
                .unwrap()
                .dictionary;
            for page in commissioning::PAGES {
                for object in page.objects {
                    // The UMC1BD90 has three bridges and one CPU.
                    let present = dictionary.sub(object.index, object.sub).is_some();
                    assert!(
                        present,
                        "{} 0x{:04X}.{}",
                        page.slug, object.index, object.sub
                    );
                }
            }
        }
        assert_eq!(commissioning::page("motor").unwrap().title, "Motor");
        assert!(commissioning::page("nothing").is_none());
    }

    #[test]
    fn the_interpolation_period_is_units_times_ten_to_the_index() {
        assert_eq!(ip_period_ms(4, -3), Some(4.0));
        assert_eq!(ip_period_ms(1, 0), Some(1000.0));
        assert_eq!(ip_period_ms(0, -3), None);
    }
}
