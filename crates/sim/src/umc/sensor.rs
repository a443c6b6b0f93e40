//! A sensor's conditioning (UMC manual chapter 1 §3.4.4, 0x4025/0x4045/
//! 0x4065, all Q15.16 but the mode): `value = (raw + Pre_offset) · Scale +
//! Post_offset`; a value below Error_min or above Error_max sets the
//! status flags (0x4022.2: −1, −2); Threshold_mode then limits the value
//! to Threshold_min..Threshold_max (1), wraps it into that range (2), or
//! keeps the last valid value while the sensor is in error (3). The
//! velocity and position loops act on the conditioned value, as the
//! firmware's do on their sensors; the sensor selection, divider and filter
//! (0x4023/0x4024) are stored only.

use crate::profiles::umc::from_q15_16;

#[cfg(test)]
mod tests;

/// 0x4025 and its copies, in human numbers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Conditioning {
    pub pre_offset: f64,
    pub scale: f64,
    pub post_offset: f64,
    pub error_min: f64,
    pub error_max: f64,
    pub threshold_min: f64,
    pub threshold_max: f64,
    pub threshold_mode: u8,
}

impl Default for Conditioning {
    /// The manual's defaults: the value is the raw value.
    fn default() -> Self {
        Conditioning {
            pre_offset: 0.0,
            scale: 1.0,
            post_offset: 0.0,
            error_min: from_q15_16(i32::MIN),
            error_max: from_q15_16(i32::MAX),
            threshold_min: from_q15_16(i32::MIN),
            threshold_max: from_q15_16(i32::MAX),
            threshold_mode: 0,
        }
    }
}

impl Conditioning {
    /// From the record's raw subs 1 to 8.
    pub fn from_raw(raw: [i64; 8]) -> Conditioning {
        let q = |value: i64| from_q15_16(value as i32);
        Conditioning {
            pre_offset: q(raw[0]),
            scale: q(raw[1]),
            post_offset: q(raw[2]),
            error_min: q(raw[3]),
            error_max: q(raw[4]),
            threshold_min: q(raw[5]),
            threshold_max: q(raw[6]),
            threshold_mode: raw[7] as u8,
        }
    }
}

/// 0x4022.2 flags: valid, below Error_min, above Error_max.
pub const VALID: i64 = 0;
pub const MIN_ERROR: i64 = -1;
pub const MAX_ERROR: i64 = -2;

/// One sensor: its last value and flags.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sensor {
    pub value: f64,
    pub flags: i64,
    /// The last value that was valid (threshold mode 3).
    last_valid: Option<f64>,
}

impl Sensor {
    /// Conditions `raw`; the value.
    pub fn read(&mut self, config: &Conditioning, raw: f64) -> f64 {
        let value = (raw + config.pre_offset) * config.scale + config.post_offset;
        self.flags = if value < config.error_min {
            MIN_ERROR
        } else if value > config.error_max {
            MAX_ERROR
        } else {
            VALID
        };
        let (low, high) = (config.threshold_min, config.threshold_max);
        self.value = match config.threshold_mode {
            1 if low <= high => value.clamp(low, high),
            2 if low < high => low + (value - low).rem_euclid(high - low),
            3 if self.flags != VALID => self.last_valid.unwrap_or(value),
            _ => value,
        };
        if self.flags == VALID {
            self.last_valid = Some(self.value);
        }
        self.value
    }
}
