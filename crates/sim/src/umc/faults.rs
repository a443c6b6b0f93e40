//! The faults an axis detects and how it reports them (UMC manual chapter 2
//! §1.5 "Emergency error codes", Table 2.16; chapter 3 §6.1.1, Table 3.10,
//! the error register; chapter 1 §2.1.7 0x2041 and §2.5.2 0x2810, the
//! thresholds; Figures 1.2 and 1.3, the motion and motor error bits).

use crate::behaviour::Fault;
use crate::canopen::emcy::ErrorBit;
use crate::profiles::umc::axis::{motion_error, motor_error};

/// A fault condition of one axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Condition {
    /// A driver bridge of the axis passed 0x2810.2; ends below 0x2810.1.
    OverTemperature,
    /// The board voltage 0x2000.1 is below 0x2041.1.
    UnderVoltage,
    /// The board voltage 0x2000.1 is above 0x2041.2.
    OverVoltage,
    /// The position error stayed beyond 0x6065 longer than 0x6066.
    FollowingError,
    /// The motor current stayed above the burst current 0x4007.3 longer
    /// than 0x4007.4.
    OverCurrent,
    /// The motor turned faster than 0x4007.7 Max_velocity ("if this
    /// velocity is exceeded, a motor fault is generated").
    OverSpeed,
    /// The master went away (0x6007: NMT change of status, heartbeat or
    /// guarding) while the drive function was enabled, and the option was
    /// the fault signal. Never present: it lasts until the fault reset.
    ConnectionLost,
}

impl Condition {
    pub const ALL: [Condition; 7] = [
        Condition::OverTemperature,
        Condition::UnderVoltage,
        Condition::OverVoltage,
        Condition::FollowingError,
        Condition::OverCurrent,
        Condition::OverSpeed,
        Condition::ConnectionLost,
    ];

    /// The EMCY error code (Table 2.16): 0x4310 excess temperature drive,
    /// 0x3220 DC link under-voltage, 0x3210 DC link over-voltage (the board
    /// input feeds the bridges directly), 0x8611 following error, 0x2310
    /// continuous over current (device output side), 0x8400 velocity
    /// controller (the speed monitoring's deviation); 0x8100 communication
    /// generic (CiA 301 table 21) for a lost connection, which Table 2.16
    /// has no code for.
    pub fn emcy_code(self) -> u16 {
        match self {
            Condition::OverTemperature => 0x4310,
            Condition::UnderVoltage => 0x3220,
            Condition::OverVoltage => 0x3210,
            Condition::FollowingError => 0x8611,
            Condition::OverCurrent => 0x2310,
            Condition::OverSpeed => 0x8400,
            Condition::ConnectionLost => 0x8100,
        }
    }

    /// The bit of 0x1001 (Table 3.10) the condition sets.
    pub fn error_bit(self) -> ErrorBit {
        match self {
            Condition::OverTemperature => ErrorBit::Temperature,
            Condition::UnderVoltage | Condition::OverVoltage => ErrorBit::Voltage,
            Condition::FollowingError => ErrorBit::DeviceProfile,
            Condition::OverCurrent => ErrorBit::Current,
            // A motor error of 0x4006.6: the manufacturer's.
            Condition::OverSpeed => ErrorBit::Manufacturer,
            // A reaction of the drive profile (the communication bit is the
            // core's, for as long as the master stays lost).
            Condition::ConnectionLost => ErrorBit::DeviceProfile,
        }
    }

    /// The bits of 0x4006.6 (Figure 1.3).
    pub fn motor_error(self) -> u16 {
        match self {
            Condition::OverTemperature => motor_error::DRIVER_OVER_TEMPERATURE,
            Condition::OverCurrent => motor_error::OVER_CURRENT,
            Condition::OverSpeed => motor_error::OVER_SPEED,
            _ => 0,
        }
    }

    /// The bits of 0x4000.1 (Figure 1.2).
    pub fn motion_error(self) -> u16 {
        match self {
            Condition::OverTemperature | Condition::UnderVoltage | Condition::OverVoltage => {
                motion_error::BOARD
            }
            Condition::FollowingError => motion_error::POSITION_CONTROLLER,
            Condition::OverCurrent | Condition::OverSpeed => motion_error::MOTOR,
            Condition::ConnectionLost => 0,
        }
    }

    /// The condition an injected fault creates (heartbeat loss is the
    /// device core's).
    pub fn of_fault(fault: Fault) -> Option<Condition> {
        match fault {
            Fault::OverTemperature => Some(Condition::OverTemperature),
            Fault::UnderVoltage => Some(Condition::UnderVoltage),
            Fault::FollowingError => Some(Condition::FollowingError),
            Fault::OverCurrent => Some(Condition::OverCurrent),
            Fault::HeartbeatLoss | Fault::BitErrors | Fault::BusOff => None,
        }
    }

    fn mask(self) -> u8 {
        1 << (self as u8)
    }
}

/// A set of conditions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Conditions(u8);

impl Conditions {
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }

    pub fn contains(self, condition: Condition) -> bool {
        self.0 & condition.mask() != 0
    }

    pub fn with(self, condition: Condition) -> Self {
        Conditions(self.0 | condition.mask())
    }

    pub fn without(self, condition: Condition) -> Self {
        Conditions(self.0 & !condition.mask())
    }

    pub fn set(self, condition: Condition, on: bool) -> Self {
        if on {
            self.with(condition)
        } else {
            self.without(condition)
        }
    }

    pub fn union(self, other: Conditions) -> Self {
        Conditions(self.0 | other.0)
    }

    /// Those of `self` not in `other`.
    pub fn minus(self, other: Conditions) -> Self {
        Conditions(self.0 & !other.0)
    }

    pub fn iter(self) -> impl Iterator<Item = Condition> {
        Condition::ALL
            .into_iter()
            .filter(move |condition| self.contains(*condition))
    }

    /// 0x4006.6 for these conditions.
    pub fn motor_error(self) -> u16 {
        self.iter().fold(0, |bits, c| bits | c.motor_error())
    }

    /// 0x4000.1 for these conditions.
    pub fn motion_error(self) -> u16 {
        self.iter().fold(0, |bits, c| bits | c.motion_error())
    }
}

/// A schmitt trigger (0x2810: "to pass in over-temp state, bridge
/// temperature needs to exceed the trigger high. A temperature that fall
/// below trigger low will clear this fault").
pub fn schmitt(active: bool, value: f64, low: f64, high: f64) -> bool {
    if active { value >= low } else { value > high }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_condition_has_a_table_2_16_code_and_a_register_bit() {
        let codes: Vec<u16> = Condition::ALL.iter().map(|c| c.emcy_code()).collect();
        assert_eq!(
            codes,
            [0x4310, 0x3220, 0x3210, 0x8611, 0x2310, 0x8400, 0x8100]
        );
        for condition in Condition::ALL {
            use crate::canopen::emcy::codes::{DRIVE_CODES, GENERAL_CODES};
            assert!(
                DRIVE_CODES
                    .iter()
                    .chain(GENERAL_CODES)
                    .any(|(code, _)| *code == condition.emcy_code()),
                "{condition:?}"
            );
            assert_ne!(condition.error_bit(), ErrorBit::Generic);
        }
    }

    #[test]
    fn the_temperature_trigger_has_hysteresis() {
        assert!(!schmitt(false, 79.0, 75.0, 80.0));
        assert!(schmitt(false, 80.5, 75.0, 80.0));
        assert!(schmitt(true, 76.0, 75.0, 80.0));
        assert!(!schmitt(true, 74.9, 75.0, 80.0));
    }

    #[test]
    fn sets_hold_what_is_put_in() {
        let set = Conditions::default()
            .with(Condition::OverCurrent)
            .with(Condition::OverTemperature);
        assert!(set.contains(Condition::OverCurrent));
        assert!(!set.contains(Condition::UnderVoltage));
        assert_eq!(set.iter().count(), 2);
        assert_eq!(set.without(Condition::OverCurrent).iter().count(), 1);
        assert_eq!(set.motor_error(), 0b101);
        assert!(set.minus(set).is_empty());
    }
}
