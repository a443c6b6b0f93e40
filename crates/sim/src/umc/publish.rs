//! The status objects an axis keeps up to date (UMC manual chapter 1 §3.2.5
//! 0x4006, §3.5.2 PID statuses; chapter 2 0x6041, 0x6061, 0x6062, 0x6064,
//! 0x606C, 0x6077, ...), each written to the dictionary only when its value
//! changes: a tick of an axis at rest writes nothing.

use crate::behaviour::DeviceIo;
use crate::profiles::umc::axis as ax;
use crate::profiles::umc::drive as d;

/// A status object of an axis, by what it reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Slot {
    Statusword,
    ModeDisplay,
    PositionDemand,
    PositionInternal,
    PositionActual,
    VelocityDemand,
    VelocityActual,
    FollowingErrorActual,
    ControlEffort,
    VlDemand,
    VlActual,
    TorqueDemand,
    TorqueActual,
    CurrentActual,
    DcLinkVoltage,
    DtyDemand,
    MotionError,
    MotorCommand,
    MotorCurrent,
    MotorTorque,
    MotorVelocity,
    MotorPosition,
    MotorError,
    MotorTemperature,
    TorquePidInput,
    TorquePidError,
    TorquePidIntegrator,
    TorquePidOutput,
    TorquePidTarget,
    VelocityPidInput,
    VelocityPidError,
    VelocityPidIntegrator,
    VelocityPidOutput,
    VelocityPidTarget,
    PositionPidInput,
    PositionPidError,
    PositionPidIntegrator,
    PositionPidOutput,
    PositionPidTarget,
    TorqueSensorRaw,
    TorqueSensorValue,
    VelocitySensorRaw,
    VelocitySensorValue,
    PositionSensorRaw,
    PositionSensorValue,
    HallRaw,
    HallPhase,
    ElectricalAngle,
    TorqueSensorFlags,
    VelocitySensorFlags,
    PositionSensorFlags,
    IpBufferSize,
}

/// How many slots there are.
pub const SLOTS: usize = Slot::IpBufferSize as usize + 1;

/// Which area an object is in, for the axis offset.
#[derive(Clone, Copy)]
enum Area {
    /// 0x6000–0x67FF, +0x800 per axis.
    Profile,
    /// 0x4000–0x41FF, +0x200 per axis.
    Manufacturer,
}

/// Axis 1's object of each slot, in [`Slot`] order.
const OBJECTS: [(Area, u16, u8); SLOTS] = {
    use Area::{Manufacturer as M, Profile as P};
    [
        (P, d::STATUSWORD, 0),
        (P, d::MODES_OF_OPERATION_DISPLAY, 0),
        (P, d::POSITION_DEMAND, 0),
        (P, d::POSITION_ACTUAL_INTERNAL, 0),
        (P, d::POSITION_ACTUAL, 0),
        (P, d::VELOCITY_DEMAND, 0),
        (P, d::VELOCITY_ACTUAL, 0),
        (P, d::FOLLOWING_ERROR_ACTUAL, 0),
        (P, d::CONTROL_EFFORT, 0),
        (P, d::VL_DEMAND, 0),
        (P, d::VL_ACTUAL, 0),
        (P, d::TQ_DEMAND, 0),
        (P, d::TQ_ACTUAL, 0),
        (P, d::CURRENT_ACTUAL, 0),
        (P, d::DC_LINK_VOLTAGE, 0),
        (M, ax::DTY_DEMAND, 0),
        (M, ax::MOTION_ERROR.0, ax::MOTION_ERROR.1),
        (M, ax::MOTOR_STATUS, 1),
        (M, ax::MOTOR_STATUS, 2),
        (M, ax::MOTOR_STATUS, 3),
        (M, ax::MOTOR_STATUS, 4),
        (M, ax::MOTOR_STATUS, 5),
        (M, ax::MOTOR_STATUS, 6),
        (M, ax::MOTOR_STATUS, 7),
        (M, ax::TORQUE_PID_STATUS, 1),
        (M, ax::TORQUE_PID_STATUS, 2),
        (M, ax::TORQUE_PID_STATUS, 3),
        (M, ax::TORQUE_PID_STATUS, 4),
        (M, ax::TORQUE_PID_STATUS, 5),
        (M, ax::VELOCITY_PID_STATUS, 1),
        (M, ax::VELOCITY_PID_STATUS, 2),
        (M, ax::VELOCITY_PID_STATUS, 3),
        (M, ax::VELOCITY_PID_STATUS, 4),
        (M, ax::VELOCITY_PID_STATUS, 5),
        (M, ax::POSITION_PID_STATUS, 1),
        (M, ax::POSITION_PID_STATUS, 2),
        (M, ax::POSITION_PID_STATUS, 3),
        (M, ax::POSITION_PID_STATUS, 4),
        (M, ax::POSITION_PID_STATUS, 5),
        (M, ax::TORQUE_SENSOR_STATUS, 1),
        (M, ax::TORQUE_SENSOR_STATUS, 3),
        (M, ax::VELOCITY_SENSOR_STATUS, 1),
        (M, ax::VELOCITY_SENSOR_STATUS, 3),
        (M, ax::POSITION_SENSOR_STATUS, 1),
        (M, ax::POSITION_SENSOR_STATUS, 3),
        (M, ax::BLDC_STATUS, 1),
        (M, ax::BLDC_STATUS, 2),
        (M, ax::BLDC_STATUS, 3),
        (M, ax::TORQUE_SENSOR_STATUS, 2),
        (M, ax::VELOCITY_SENSOR_STATUS, 2),
        (M, ax::POSITION_SENSOR_STATUS, 2),
        (P, d::IP_DATA_CONFIGURATION, 2),
    ]
};

/// The status objects of one axis and the values last written to them.
#[derive(Debug, Clone, PartialEq)]
pub struct Published {
    addresses: [(u16, u8); SLOTS],
    last: [Option<i64>; SLOTS],
}

impl Published {
    /// For the axis whose objects are `offset` (0x6000 area) and
    /// `m_offset` (0x4000 area) above axis 1's.
    pub fn new(offset: u16, m_offset: u16) -> Self {
        let mut addresses = [(0, 0); SLOTS];
        for (address, (area, index, sub)) in addresses.iter_mut().zip(OBJECTS) {
            let shift = match area {
                Area::Profile => offset,
                Area::Manufacturer => m_offset,
            };
            *address = (index + shift, sub);
        }
        Published {
            addresses,
            last: [None; SLOTS],
        }
    }

    /// Where `slot` is.
    pub fn address(&self, slot: Slot) -> (u16, u8) {
        self.addresses[slot as usize]
    }

    /// Writes `value` to `slot` if it is not what is there already.
    pub fn set(&mut self, io: &mut DeviceIo<'_>, slot: Slot, value: i64) {
        let last = &mut self.last[slot as usize];
        if *last != Some(value) {
            let (index, sub) = self.addresses[slot as usize];
            io.set_int(index, sub, value);
            *last = Some(value);
        }
    }

    /// Forgets what was written: the next [`Published::set`] of each slot
    /// writes (after a restore or a master's write into a status object).
    pub fn invalidate(&mut self) {
        self.last = [None; SLOTS];
    }

    /// Forgets one slot.
    pub fn invalidate_slot(&mut self, slot: Slot) {
        self.last[slot as usize] = None;
    }
}
