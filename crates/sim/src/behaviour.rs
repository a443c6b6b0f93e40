//! What a product does beyond the CANopen device core: the application of a
//! virtual device (CiA 402 drive, LED controller, ...), run by the
//! simulation clock one millisecond at a time.
//!
//! The device core owns the protocol (NMT, SDO, PDO, heartbeat, EMCY
//! sending); a [`Behaviour`] owns what the values mean. It sees the device
//! through a [`DeviceIo`]: the object store (read the parameters a master
//! wrote, set the status values it measures), the NMT state, the simulation
//! time, and the error register with the EMCYs it raises. Like the rest of
//! the simulation it reads no clock: time arrives as [`Behaviour::tick`]s.

use std::fmt;

use crate::canopen::emcy::{ErrorBit, ErrorRegister};
use crate::canopen::nmt::NmtState;
use crate::canopen::od::Value;
use crate::canopen::sdo::AbortCode;

use super::objects::ObjectStore;
use super::pdo::PdoRules;

/// The simulation step: every [`Behaviour::tick`] is this much time.
pub const TICK_MS: u64 = 1;

/// 0x1001: error register.
pub const ERROR_REGISTER: u16 = 0x1001;

/// A fault the simulation can inject (`POST /sim/nodes/{id}/faults`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Fault {
    /// The driver temperature rises past its limit (UMC: 0x2810 high).
    OverTemperature,
    /// The supply voltage drops below its limit (UMC: 0x2041).
    UnderVoltage,
    /// The position error exceeds the following error window (0x6065).
    FollowingError,
    /// The motor current exceeds the drive's limit.
    OverCurrent,
    /// The device stops producing heartbeats (and answering node guarding)
    /// while it goes on running: handled by the device core.
    HeartbeatLoss,
    /// Each frame the device sends meets one bit error and is sent again:
    /// its CAN controller's transmit error counter rises by 7 a frame, error
    /// passive after 19 frames, bus-off at the 37th (the device core's CAN
    /// controller, [`crate::can::fault`]).
    BitErrors,
    /// The device's CAN controller goes bus-off at once; clearing the fault
    /// is the host's recovery request (128 × 11 recessive bits later it is
    /// error active again).
    BusOff,
}

impl Fault {
    pub const ALL: [Fault; 7] = [
        Fault::OverTemperature,
        Fault::UnderVoltage,
        Fault::FollowingError,
        Fault::OverCurrent,
        Fault::HeartbeatLoss,
        Fault::BitErrors,
        Fault::BusOff,
    ];

    /// The name in the HTTP API: `over_temperature`, `under_voltage`,
    /// `following_error`, `over_current`, `heartbeat_loss`, `bit_errors`,
    /// `bus_off`.
    pub fn name(self) -> &'static str {
        match self {
            Fault::OverTemperature => "over_temperature",
            Fault::UnderVoltage => "under_voltage",
            Fault::FollowingError => "following_error",
            Fault::OverCurrent => "over_current",
            Fault::HeartbeatLoss => "heartbeat_loss",
            Fault::BitErrors => "bit_errors",
            Fault::BusOff => "bus_off",
        }
    }

    pub fn from_name(name: &str) -> Option<Fault> {
        Fault::ALL.into_iter().find(|fault| fault.name() == name)
    }
}

impl fmt::Display for Fault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Why a fault cannot be injected or cleared.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FaultError {
    #[error("a {product} has no {fault} fault")]
    NotApplicable { product: &'static str, fault: Fault },
}

/// An EMCY a behaviour raised, sent by the device core with the error
/// register as the behaviour left it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RaisedEmcy {
    pub code: u16,
    pub manufacturer: [u8; 5],
}

/// The device as a [`Behaviour`] sees it during one call.
pub struct DeviceIo<'a> {
    /// The dictionary's current values.
    pub store: &'a mut ObjectStore,
    nmt: NmtState,
    sim_ms: u64,
    raised: &'a mut Vec<RaisedEmcy>,
}

impl<'a> DeviceIo<'a> {
    /// The device core makes one for each call; tests of a behaviour make
    /// their own.
    pub fn new(
        store: &'a mut ObjectStore,
        nmt: NmtState,
        sim_ms: u64,
        raised: &'a mut Vec<RaisedEmcy>,
    ) -> Self {
        Self {
            store,
            nmt,
            sim_ms,
            raised,
        }
    }

    /// The NMT state of the device.
    pub fn nmt(&self) -> NmtState {
        self.nmt
    }

    /// Milliseconds of simulated time since the simulation started.
    pub fn sim_ms(&self) -> u64 {
        self.sim_ms
    }

    /// An integer (or BOOLEAN) value; `None` for an object the dictionary
    /// lacks or that is no integer.
    pub fn int(&self, index: u16, sub: u8) -> Option<i64> {
        self.store.int(index, sub)
    }

    /// A number (integer or real) as a float.
    pub fn real(&self, index: u16, sub: u8) -> Option<f64> {
        self.store.get(index, sub).and_then(Value::as_f64)
    }

    /// Sets an integer object to `value`, clamped to its type's range (a
    /// measured value saturates; it does not wrap). Objects the dictionary
    /// lacks are left alone: a product variant without them is no error.
    pub fn set_int(&mut self, index: u16, sub: u8, value: i64) {
        self.store.set_int_saturating(index, sub, value);
    }

    /// Sets a REAL32/REAL64 object (or an integer one, rounded).
    pub fn set_real(&mut self, index: u16, sub: u8, value: f64) {
        self.store.set_real(index, sub, value);
    }

    /// The error register (0x1001).
    pub fn error_register(&self) -> ErrorRegister {
        ErrorRegister::from_raw(self.int(ERROR_REGISTER, 0).unwrap_or(0) as u8)
    }

    /// Sets or clears a bit of 0x1001; the generic bit follows the others
    /// (set while any is).
    pub fn set_error_bit(&mut self, bit: ErrorBit, on: bool) {
        let register = self.error_register();
        let mut register = if on {
            register.with(bit)
        } else {
            register.without(bit)
        };
        let others = register.without(ErrorBit::Generic);
        register = if others.is_empty() && !(on && bit == ErrorBit::Generic) {
            register.without(ErrorBit::Generic)
        } else {
            register.with(ErrorBit::Generic)
        };
        self.set_int(ERROR_REGISTER, 0, i64::from(register.raw()));
    }

    /// Raises an EMCY: recorded in 0x1003 and sent (in pre-operational and
    /// operational) with 0x1001 as it is when this call returns. Set the
    /// error register bits first. Code 0x0000 is the error reset.
    pub fn emcy(&mut self, code: u16, manufacturer: [u8; 5]) {
        self.raised.push(RaisedEmcy { code, manufacturer });
    }
}

/// The application of a virtual product. Every method runs with the device
/// locked, so it must be quick; none may block. (`Any` lets the simulation's
/// own API reach a product's extras, such as a drive's limit switches.)
pub trait Behaviour: Send + std::any::Any {
    /// The product's name in `--devices` (for messages).
    fn product(&self) -> &'static str;

    /// Power-on and reset node: the store holds the values after the reset
    /// (factory defaults and saved parameters); the application starts
    /// afresh from them.
    fn reset(&mut self, io: &mut DeviceIo<'_>);

    /// A product rule on a write from the bus, checked before the
    /// dictionary's own checks (`size` is the length the client announced,
    /// if it did). The JMC drive, for one, answers a too long value with an
    /// abort of its own.
    fn check_write(
        &self,
        _store: &ObjectStore,
        _index: u16,
        _sub: u8,
        _size: Option<usize>,
    ) -> Result<(), AbortCode> {
        Ok(())
    }

    /// A product rule on the value of a write from the bus, after the
    /// dictionary's checks and before it is stored (a mode the drive does
    /// not support, a set-point FIFO that is full, ...).
    fn check_value(
        &self,
        _store: &ObjectStore,
        _index: u16,
        _sub: u8,
        _data: &[u8],
    ) -> Result<(), AbortCode> {
        Ok(())
    }

    /// How the device guards its PDO parameters while a PDO is in use.
    fn pdo_rules(&self) -> PdoRules {
        PdoRules::Cia301
    }

    /// Whether an RPDO longer than its mapping raises EMCY 0x8220 (CiA 301
    /// leaves it to the device; the UniSwarm manuals list the code).
    fn reports_pdo_length_exceeded(&self) -> bool {
        false
    }

    /// A value written from the bus (SDO download or RPDO) is in the store.
    fn written(&mut self, io: &mut DeviceIo<'_>, index: u16, sub: u8);

    /// One [`TICK_MS`] of simulated time has passed.
    fn tick(&mut self, io: &mut DeviceIo<'_>);

    /// Whether [`Behaviour::tick`] does anything at all; a device without
    /// an application is not woken every millisecond.
    fn ticks(&self) -> bool {
        true
    }

    /// The NMT state changed (a CiA 402 drive reacts to leaving operational
    /// as 0x6007 says).
    fn nmt_changed(&mut self, _io: &mut DeviceIo<'_>, _from: NmtState, _to: NmtState) {}

    /// The device lost its master: a heartbeat it consumes (0x1016) timed
    /// out, or node guarding stopped (life guarding). A CiA 402 drive acts
    /// as its 0x6007 says.
    fn connection_lost(&mut self, _io: &mut DeviceIo<'_>) {}

    /// Injects a fault condition; it lasts until [`Behaviour::clear_fault`].
    fn inject_fault(&mut self, _io: &mut DeviceIo<'_>, fault: Fault) -> Result<(), FaultError> {
        Err(FaultError::NotApplicable {
            product: self.product(),
            fault,
        })
    }

    /// Ends an injected fault condition (the device may still need a fault
    /// reset, as a real one does).
    fn clear_fault(&mut self, _io: &mut DeviceIo<'_>, fault: Fault) -> Result<(), FaultError> {
        Err(FaultError::NotApplicable {
            product: self.product(),
            fault,
        })
    }
}

/// A device with no application: the CANopen core alone (the test node of
/// the interop tests, a generic device).
#[derive(Debug, Clone, Copy, Default)]
pub struct NoBehaviour;

impl Behaviour for NoBehaviour {
    fn product(&self) -> &'static str {
        "generic device"
    }

    fn reset(&mut self, _io: &mut DeviceIo<'_>) {}

    fn written(&mut self, _io: &mut DeviceIo<'_>, _index: u16, _sub: u8) {}

    fn tick(&mut self, _io: &mut DeviceIo<'_>) {}

    fn ticks(&self) -> bool {
        false
    }
}
