//! The parameters of one axis as its modes use them (UMC manual chapter 2
//! §2.2–§7.2 "Definition of parameters", chapter 1 §3.2.7 0x4007), read
//! from the dictionary when a master writes one and when operation is
//! enabled, so that a tick reads none.

use crate::profiles::umc::drive as d;
use crate::profiles::umc::pid::{Loop, PidConfig};

use super::sensor::Conditioning;
use crate::behaviour::DeviceIo;
use crate::profiles::umc::{self, axis as ax};

/// The parameters, in the units the modes compute in (increments,
/// increments/ms, increments/ms², amperes, per mille, ms).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Params {
    /// 0x6081, capped by 0x607F and 0x6080.
    pub profile_velocity: f64,
    /// min(0x607F, 0x6080): the fastest any position mode may go.
    pub max_velocity: f64,
    /// 0x6083, capped by 0x60C5.
    pub profile_acceleration: f64,
    /// 0x6084, capped by 0x60C6.
    pub profile_deceleration: f64,
    /// 0x6085, capped by 0x60C6.
    pub quick_stop_deceleration: f64,
    /// 0x607D.1 and .2; both 0 disables them (§5.2.9).
    pub software_limits: Option<(f64, f64)>,
    /// 0x6067.
    pub position_window: f64,
    /// 0x6068, ms.
    pub position_window_time: u32,
    /// 0x6065; 0xFFFFFFFF switches following error detection off.
    pub following_window: Option<f64>,
    /// 0x6066, ms.
    pub following_timeout: u32,
    /// 0x6046.1 and .2, in velocity set-point units.
    pub vl_min: f64,
    pub vl_max: f64,
    /// 0x6048, 0x6049 (0x6048 where its delta speed is 0), 0x604A: per ms.
    pub vl_acceleration: f64,
    pub vl_deceleration: f64,
    pub vl_quick_stop: f64,
    /// 0x604B numerator / denominator.
    pub vl_set_point_factor: f64,
    /// 0x604C numerator / denominator: increments/ms per velocity unit.
    pub vl_dimension_factor: f64,
    /// 0x6072, per mille of rated torque.
    pub max_torque: f64,
    /// 0x6087, per mille per ms.
    pub torque_slope: f64,
    /// 0x6075 (mA) where set, else the sustained current 0x4007.5: A.
    pub rated_current: f64,
    /// 0x41FC.
    pub dty_max: f64,
    /// 0x41FD, per ms.
    pub dty_slope: f64,
    /// 0x4007.2, A.
    pub peak_current: f64,
    /// 0x4007.3, A.
    pub burst_current: f64,
    /// 0x4007.4, ms.
    pub burst_duration: u32,
    /// 0x4009.1, pole pairs (at least 1).
    pub pole_pairs: f64,
    /// 0x4007.7, rpm; 0 leaves the speed unwatched.
    pub max_motor_rpm: f64,
    /// 0x4007.6, N·m/A: what the firmware multiplies the current by to
    /// report a torque.
    pub current_constant: f64,
    /// The current the loops may ask for: 0x6073 (per mille of rated
    /// current) where set, capped by the peak current.
    pub current_limit: f64,
    /// 0x60C2, ms; `None` for a zero period.
    pub ip_period: Option<f64>,
    /// 0x4021, 0x4041, 0x4061: the torque, velocity and position loops.
    pub torque_pid: PidConfig,
    pub velocity_pid: PidConfig,
    pub position_pid: PidConfig,
    /// 0x4025, 0x4045, 0x4065: the torque, velocity and position sensors'
    /// conditioning.
    pub torque_sensor: Conditioning,
    pub velocity_sensor: Conditioning,
    pub position_sensor: Conditioning,
}

impl Params {
    /// The parameters of the axis whose 0x6000-area objects are `offset`
    /// above axis 1's and whose 0x4000-area ones are `m_offset` above.
    pub fn read(io: &DeviceIo<'_>, offset: u16, m_offset: u16) -> Params {
        let p = |index: u16, sub: u8| io.real(index + offset, sub).unwrap_or(0.0);
        let m = |index: u16, sub: u8| io.real(index + m_offset, sub).unwrap_or(0.0);
        let ratio = |num: f64, den: f64| if den != 0.0 { num / den } else { 1.0 };
        let max_velocity = p(d::MAX_PROFILE_VELOCITY, 0).min(p(d::MAX_MOTOR_SPEED, 0));
        let limits = (
            p(d::SOFTWARE_POSITION_LIMIT, 1),
            p(d::SOFTWARE_POSITION_LIMIT, 2),
        );
        let following = p(d::FOLLOWING_ERROR_WINDOW, 0);
        let vl_deceleration_speed = p(d::VL_DECELERATION, 1);
        let vl_acceleration = ratio(p(d::VL_ACCELERATION, 1), p(d::VL_ACCELERATION, 2));
        let sustained = m(ax::MOTOR_CONFIG, 5) / 100.0;
        let rated_current = match p(d::RATED_CURRENT, 0) {
            rated if rated > 0.0 => rated / 1000.0,
            _ => sustained,
        };
        let peak_current = m(ax::MOTOR_CONFIG, 2) / 100.0;
        let current_limit = match p(d::MAX_CURRENT, 0) {
            max if max > 0.0 => (max / 1000.0 * rated_current).min(peak_current),
            _ => peak_current,
        };
        let ip_period = umc::ip_period_ms(
            io.int(d::IP_TIME_PERIOD + offset, 1).unwrap_or(0) as u8,
            io.int(d::IP_TIME_PERIOD + offset, 2).unwrap_or(0) as i8,
        );
        Params {
            profile_velocity: p(d::PROFILE_VELOCITY, 0).min(max_velocity),
            max_velocity,
            profile_acceleration: p(d::PROFILE_ACCELERATION, 0).min(p(d::MAX_ACCELERATION, 0)),
            profile_deceleration: p(d::PROFILE_DECELERATION, 0).min(p(d::MAX_DECELERATION, 0)),
            quick_stop_deceleration: p(d::QUICK_STOP_DECELERATION, 0)
                .min(p(d::MAX_DECELERATION, 0)),
            software_limits: (limits != (0.0, 0.0)).then_some(limits),
            position_window: p(d::POSITION_WINDOW, 0),
            position_window_time: p(d::POSITION_WINDOW_TIME, 0) as u32,
            following_window: (following < f64::from(u32::MAX)).then_some(following),
            following_timeout: p(d::FOLLOWING_ERROR_TIME_OUT, 0) as u32,
            vl_min: p(d::VL_MIN_MAX, 1),
            vl_max: p(d::VL_MIN_MAX, 2),
            vl_acceleration,
            vl_deceleration: if vl_deceleration_speed > 0.0 {
                ratio(vl_deceleration_speed, p(d::VL_DECELERATION, 2))
            } else {
                vl_acceleration
            },
            vl_quick_stop: match p(d::VL_QUICK_STOP, 1) {
                speed if speed > 0.0 => ratio(speed, p(d::VL_QUICK_STOP, 2)),
                _ => vl_acceleration,
            },
            vl_set_point_factor: ratio(p(d::VL_SET_POINT_FACTOR, 1), p(d::VL_SET_POINT_FACTOR, 2)),
            vl_dimension_factor: ratio(p(d::VL_DIMENSION_FACTOR, 1), p(d::VL_DIMENSION_FACTOR, 2)),
            max_torque: p(d::TQ_MAX, 0),
            torque_slope: p(d::TQ_SLOPE, 0) / 1000.0,
            rated_current,
            dty_max: m(ax::DTY_MAX, 0),
            dty_slope: m(ax::DTY_SLOPE, 0) / 1000.0,
            peak_current,
            burst_current: m(ax::MOTOR_CONFIG, 3) / 100.0,
            burst_duration: m(ax::MOTOR_CONFIG, 4) as u32,
            max_motor_rpm: m(ax::MOTOR_CONFIG, 7),
            pole_pairs: m(ax::POLE_PAIRS.0, ax::POLE_PAIRS.1).max(1.0),
            current_constant: umc::from_q15_16(
                io.int(ax::MOTOR_CONFIG + m_offset, 6).unwrap_or(0) as i32
            ),
            current_limit,
            ip_period,
            torque_pid: pid_config(io, Loop::Torque, m_offset),
            velocity_pid: pid_config(io, Loop::Velocity, m_offset),
            position_pid: pid_config(io, Loop::Position, m_offset),
            torque_sensor: conditioning(io, 0x4025 + m_offset),
            velocity_sensor: conditioning(io, 0x4045 + m_offset),
            position_sensor: conditioning(io, 0x4065 + m_offset),
        }
    }

    /// 0x607D applied to a target.
    pub fn limit_position(&self, position: f64) -> f64 {
        match self.software_limits {
            Some((min, max)) if min <= max => position.clamp(min, max),
            _ => position,
        }
    }
}

/// A sensor's conditioning record; the manual's defaults where the
/// dictionary lacks it.
fn conditioning(io: &DeviceIo<'_>, index: u16) -> Conditioning {
    let mut raw = [0i64; 8];
    for (sub, value) in (1u8..).zip(raw.iter_mut()) {
        match io.int(index, sub) {
            Some(read) => *value = read,
            None => return Conditioning::default(),
        }
    }
    Conditioning::from_raw(raw)
}

/// A loop's configuration record as the dictionary holds it.
fn pid_config(io: &DeviceIo<'_>, which: Loop, m_offset: u16) -> PidConfig {
    let index = which.config_index() + m_offset;
    let mut raw = [0i64; 8];
    for (sub, value) in (1u8..).zip(raw.iter_mut()) {
        *value = io.int(index, sub).unwrap_or(0);
    }
    PidConfig::from_raw(raw)
}
