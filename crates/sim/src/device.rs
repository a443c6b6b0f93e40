//! The device core every virtual product shares (CiA 301): the NMT slave
//! with its boot-up message, the heartbeat producer configured by 0x1017, and
//! the SDO server over the device's [`ObjectStore`], each running only in the
//! NMT states that allow it (the UniSwarm manual's figure 3.9). Resets reload
//! parameters: reset node the whole dictionary, reset communication the
//! communication area 0x1000–0x1FFF, each from the saved values where there
//! are any and from the factory defaults otherwise.
//!
//! Store and restore follow the UMC manual (§9.1.8, §9.1.9): writing the
//! signature `save` (0x65766173) to 0x1010 sub 1–4 saves the writable
//! parameters of all areas, the communication area (0x1000–0x1FFF), the
//! standardized area (0x6000–0x9FFF) or the manufacturer area
//! (0x2000–0x5FFF); writing `load` (0x64616F6C) to 0x1011 sub 1–4 brings back
//! the factory values of those areas, to sub 5–8 the saved values. Both only
//! in pre-operational (abort 0x08000021 otherwise); another value is refused
//! with 0x08000020.
//!
//! The core also runs the product's [`Behaviour`] on the simulation clock
//! (one tick per simulated millisecond, [`DeviceCore::tick_to`]), tells it of
//! every value written from the bus, and sends the EMCYs it raises (CiA 301
//! §7.2.7: COB-ID 0x1014, inhibit time 0x1015, error register 0x1001, the
//! pre-defined error field 0x1003). Node guarding requests are answered
//! (§7.2.8.3.2.1) while 0x1017 is 0, with life guarding from 0x100C and
//! 0x100D.
//!
//! Its CAN controller keeps fault confinement ([`FaultConfinement`],
//! ISO 11898-1): the runner asks it for each frame the device sends
//! ([`DeviceCore::transmit`]), and it hears every frame. Error passive, the
//! device sends EMCY 0x8120 "CAN in error passive mode" with the
//! communication bit (bit 4) of the error register; back to error active,
//! an error reset. Bus-off, it neither sends nor hears anything, so its
//! heartbeat stops; it is a communication error (0x1029 sub 1, and a CiA
//! 402 drive's abort connection option 0x6007). Recovered, it sends EMCY
//! 0x8140 "recovered from bus-off", then an error reset (CiA 301 table 21;
//! the UMC and UIO1LED manuals' EMCY tables).
//!
//! Like the protocol layer it does no I/O: frames and the current time go in,
//! frames and a deadline come out. [`run_device`] drives one on a bus, the
//! [`Rack`](super::rack::Rack) many.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use crate::can::fault::{ErrorState, FaultConfinement, RECOVERY_BITS, Transition};
use crate::can::{Bitrate, Bus, CanId, Frame, FrameReceiver, RecvError};
use crate::canopen::NodeId;
use crate::canopen::cob::Function;
use crate::canopen::emcy::{Emcy, EmcyProducer, ErrorBit, ErrorHistory, ErrorRegister};
use crate::canopen::heartbeat::{
    ConsumerTime, HeartbeatConsumer, HeartbeatEvent, HeartbeatProducer, LifeGuard, LifeGuardEvent,
    heartbeat_node,
};
use crate::canopen::lss::slave::LssSlaveOutput;
use crate::canopen::lss::{LssAddress, LssSlave, LssSlaveEvent, is_lss_request};
use crate::canopen::nmt::{
    NmtCommand, NmtEvent, NmtMessage, NmtService, NmtSlave, NmtState, NmtTarget,
};
use crate::canopen::od::{ObjectDictionary, Value};
use crate::canopen::pdo::EMCY_PDO_LENGTH_EXCEEDED;
use crate::canopen::sdo::{AbortCode, ObjectAccess, SdoServer, ServerConfig};

use super::behaviour::{
    Behaviour, DeviceIo, ERROR_REGISTER, Fault, FaultError, NoBehaviour, RaisedEmcy, TICK_MS,
};
use super::objects::{ObjectStore, StoreError};
use super::pdo::{self, DevicePdos};
use super::program::{PROGRAM_CONTROL, PROGRAM_DATA, ProgramMemory};

/// 0x1017: producer heartbeat time, in ms.
const PRODUCER_HEARTBEAT_TIME: u16 = 0x1017;
/// 0x1010: store parameters.
const STORE_PARAMETERS: u16 = 0x1010;
/// 0x1011: restore default parameters.
const RESTORE_PARAMETERS: u16 = 0x1011;
/// 0x1003: pre-defined error field.
const PREDEFINED_ERROR_FIELD: u16 = 0x1003;
/// 0x1016: consumer heartbeat time, sub 1–n: node id in bits 16–23, time
/// in ms in bits 0–15.
const CONSUMER_HEARTBEAT_TIME: u16 = 0x1016;
/// 0x100C: guard time, in ms.
const GUARD_TIME: u16 = 0x100C;
/// 0x100D: life time factor.
const LIFE_TIME_FACTOR: u16 = 0x100D;
/// 0x1029: error behaviour, sub 1 communication error.
const ERROR_BEHAVIOUR: u16 = 0x1029;
/// 0x1014: COB-ID EMCY.
const COB_ID_EMCY: u16 = 0x1014;
/// 0x1015: inhibit time EMCY, in 100 µs.
const INHIBIT_TIME_EMCY: u16 = 0x1015;
/// EMCY 0x8130: life guard error or heartbeat error (CiA 301 table 21);
/// the same code for both, as the standard has it.
const LIFE_GUARD_ERROR: u16 = 0x8130;
/// EMCY 0x8120: CAN in error passive mode (CiA 301 table 21).
pub const CAN_ERROR_PASSIVE: u16 = 0x8120;
/// EMCY 0x8140: recovered from bus-off (CiA 301 table 21).
pub const CAN_BUS_OFF_RECOVERED: u16 = 0x8140;
/// How much simulated time one [`DeviceCore::tick_to`] catches up at most;
/// beyond it (a stalled host) the simulation skips rather than runs a burst.
const MAX_CATCH_UP_TICKS: u64 = 1000;
/// 0x2040: UniSwarm's communication configuration, sub 1 the node-ID the
/// device boots with once saved (UMC manual §2.3, UIO1LED manual §4.2).
const COMMUNICATION_CONFIG: u16 = 0x2040;
/// EMCY 0x8110: CAN overrun (objects lost), CiA 301 table 21.
const CAN_OVERRUN: u16 = 0x8110;
/// 0x1005: COB-ID SYNC.
const COB_ID_SYNC: u16 = 0x1005;
/// 0x1006: communication cycle period, which a SYNC producer has.
const CYCLE_PERIOD: u16 = 0x1006;
/// 0x1018: identity; sub 4 the serial number.
const IDENTITY: u16 = 0x1018;
/// "save" as a little-endian UNSIGNED32.
const SAVE_SIGNATURE: [u8; 4] = *b"save";
/// "load" as a little-endian UNSIGNED32.
const LOAD_SIGNATURE: [u8; 4] = *b"load";

/// The parameter areas of store and restore, by sub-index 1–4.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Area {
    All,
    Communication,
    Standardized,
    Manufacturer,
}

impl Area {
    fn of_sub(sub: u8) -> Option<Area> {
        match sub {
            1 => Some(Area::All),
            2 => Some(Area::Communication),
            3 => Some(Area::Standardized),
            4 => Some(Area::Manufacturer),
            _ => None,
        }
    }

    fn contains(self, index: u16) -> bool {
        match self {
            Area::All => true,
            Area::Communication => (0x1000..=0x1FFF).contains(&index),
            Area::Standardized => (0x6000..=0x9FFF).contains(&index),
            Area::Manufacturer => (0x2000..=0x5FFF).contains(&index),
        }
    }
}

/// What [`DeviceCore::transmit`] made of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Transmitted {
    /// It met a bit error first: the others see an error frame.
    pub error_frame: bool,
    /// It crossed the bus (false: the controller is bus-off).
    pub crossed: bool,
}

/// Saved parameter values, by index and sub-index.
pub type SavedValues = BTreeMap<(u16, u8), Value>;

/// What LSS store configuration kept in the device's non-volatile memory
/// (CiA 305 §6.4.5): the node-ID (`None`: unconfigured) and bit timing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LssStored {
    pub node_id: Option<NodeId>,
    pub bit_timing: Option<u8>,
}

/// One virtual CANopen node. See the module documentation.
pub struct DeviceCore {
    behaviour: Box<dyn Behaviour>,
    emcy: EmcyProducer,
    /// 0x1014 bit 31: EMCYs are recorded but not sent.
    emcy_enabled: bool,
    guard: LifeGuard,
    /// The heartbeats 0x1016 asks to watch, and the nodes and timeouts it
    /// was built from.
    consumer: HeartbeatConsumer,
    consumed: Vec<(NodeId, std::time::Duration)>,
    /// The injected heartbeat loss: no heartbeat, no guarding reply.
    silent: bool,
    /// Its CAN controller's error counters and state.
    controller: FaultConfinement,
    /// Injected: each frame it sends meets one bit error.
    bit_errors: bool,
    /// The bus's bit rate, for the time a bus-off recovery takes.
    bitrate: Bitrate,
    /// When a requested bus-off recovery has seen its 128 × 11 recessive
    /// bits.
    recovery_due: Option<Instant>,
    /// A communication error in operational waits for 0x1029's reaction,
    /// which the next poll applies once its EMCY is out.
    communication_error: Option<Instant>,
    /// It answers LSS requests (CiA 305); see [`DeviceCore::without_lss`].
    answers_lss: bool,
    /// The last receive overrun, until its error reset.
    rx_overrun: Option<Instant>,
    /// An RPDO of the wrong length was reported (0x8210/0x8220) and no
    /// RPDO has been processed without one since.
    pdo_length_error: bool,
    /// Milliseconds of simulated time, and the instant they were reached.
    sim_ms: u64,
    last_tick: Option<Instant>,
    /// Ticks skipped because the host fell too far behind.
    skipped_ticks: u64,
    /// The EMCYs the behaviour raised and the core has not queued yet (a
    /// buffer reused from call to call).
    raised: Vec<RaisedEmcy>,
    /// Reused for the objects one frame wrote.
    written: Vec<(u16, u8)>,
    /// The factory values.
    defaults: ObjectStore,
    /// What 0x1010 saved; a reset loads these over the factory values.
    saved: SavedValues,
    /// Changes whenever `saved` does, so that a runner knows to persist it.
    saved_version: u64,
    store: ObjectStore,
    nmt: NmtSlave,
    heartbeat: HeartbeatProducer,
    heartbeat_ms: u16,
    sdo: SdoServer,
    sdo_request: CanId,
    guard_request: CanId,
    pdos: DevicePdos,
    /// The LSS slave (CiA 305): its active node-ID is the one the device
    /// uses; without one the device answers nothing but LSS.
    lss: LssSlave,
    /// The node-ID the device has from the factory (its place in the device
    /// list); `None` for an unconfigured (`@lss`) device.
    factory_node: Option<NodeId>,
    /// What LSS store configuration kept.
    lss_stored: Option<LssStored>,
    /// The program memory of CiA 302-3 (0x1F50 ff.), when the dictionary
    /// lists it.
    program: ProgramMemory,
}

impl DeviceCore {
    /// A node with no application (the CANopen core alone) that has not
    /// booted yet (see [`DeviceCore::boot`]).
    pub fn new(
        dictionary: impl Into<Arc<ObjectDictionary>>,
        node: NodeId,
    ) -> Result<Self, StoreError> {
        Self::with_behaviour(dictionary, node, Box::new(NoBehaviour))
    }

    /// A node running `behaviour`, not booted yet.
    pub fn with_behaviour(
        dictionary: impl Into<Arc<ObjectDictionary>>,
        node: NodeId,
        behaviour: Box<dyn Behaviour>,
    ) -> Result<Self, StoreError> {
        let defaults = ObjectStore::new(dictionary, node)?;
        let pdos = DevicePdos::new(&defaults, Instant::now());
        let program = ProgramMemory::new(&defaults);
        let address = identity(&defaults);
        let history_len = defaults
            .dictionary()
            .get(PREDEFINED_ERROR_FIELD)
            .and_then(|object| object.subs.keys().max().copied())
            .unwrap_or(1);
        Ok(Self {
            behaviour,
            emcy: EmcyProducer::new(node, history_len),
            emcy_enabled: true,
            guard: LifeGuard::new(node),
            consumer: HeartbeatConsumer::new(),
            consumed: Vec::new(),
            silent: false,
            controller: FaultConfinement::new(),
            bit_errors: false,
            bitrate: Bitrate::Unlimited,
            recovery_due: None,
            communication_error: None,
            pdo_length_error: false,
            rx_overrun: None,
            answers_lss: true,
            sim_ms: 0,
            last_tick: None,
            skipped_ticks: 0,
            raised: Vec::new(),
            written: Vec::new(),
            store: defaults.clone(),
            defaults,
            saved: SavedValues::new(),
            saved_version: 0,
            nmt: NmtSlave::new(node),
            heartbeat: HeartbeatProducer::new(node),
            heartbeat_ms: 0,
            sdo: SdoServer::new(node, ServerConfig::default()),
            sdo_request: Function::SdoRx.can_id(node),
            guard_request: Function::Heartbeat.can_id(node),
            pdos,
            lss: LssSlave::new(address, Some(node)),
            factory_node: Some(node),
            lss_stored: None,
            program,
        })
    }

    /// The node-ID the device was built for, or last used. See
    /// [`DeviceCore::active_node`] for the one it has on the bus.
    pub fn node(&self) -> NodeId {
        self.nmt.node()
    }

    /// The node-ID the device uses on the bus; `None` while it is an
    /// unconfigured LSS slave (node-ID 0xFF), which sends nothing and
    /// answers only LSS.
    pub fn active_node(&self) -> Option<NodeId> {
        self.lss.active()
    }

    /// Its LSS address: 0x1018 sub 1 to 4.
    pub fn lss_address(&self) -> LssAddress {
        self.lss.address()
    }

    /// Sets the serial number (0x1018 sub 4), before the device boots.
    pub fn set_serial(&mut self, serial: u32) {
        for store in [&mut self.defaults, &mut self.store] {
            let _ = store.set(IDENTITY, 4, Value::Unsigned32(serial));
        }
        self.lss = LssSlave::new(identity(&self.defaults), self.factory_node);
    }

    /// Makes the device one that answers no LSS master (a product whose
    /// manual has no LSS: its node-ID is set otherwise).
    pub fn without_lss(&mut self) {
        self.answers_lss = false;
    }

    /// Makes the device an unconfigured LSS slave (`PRODUCT@lss`), before it
    /// boots: it waits for a node-ID from an LSS master.
    pub fn unconfigure(&mut self) {
        self.factory_node = None;
        self.lss.power_on(None);
    }

    /// What LSS store configuration kept (to keep it across a restart).
    pub fn lss_stored(&self) -> Option<LssStored> {
        self.lss_stored
    }

    /// Takes what LSS stored before a restart; in force from the next boot.
    pub fn load_lss_stored(&mut self, stored: Option<LssStored>) {
        self.lss_stored = stored;
    }

    /// The node-ID the device initialises with at power-on and reset node:
    /// a saved 0x2040 sub 1 (UniSwarm), else the node-ID LSS stored, else
    /// the factory one.
    fn boot_node(&self) -> Option<NodeId> {
        if let Some(Value::Unsigned8(raw)) = self.saved.get(&(COMMUNICATION_CONFIG, 1))
            && let Ok(node) = NodeId::new(*raw)
        {
            return Some(node);
        }
        match self.lss_stored {
            Some(stored) => stored.node_id,
            None => self.factory_node,
        }
    }

    /// Gives the device another node-ID: the values that follow the node-ID
    /// (`$NODEID` in the EDS, the COB-IDs) follow it, in the factory values,
    /// the saved ones and the current ones; the protocol state starts over.
    /// The caller reloads parameters and boots.
    fn renumber(&mut self, node: NodeId, now: Instant) {
        if node == self.node() {
            return;
        }
        let Ok(mut defaults) = ObjectStore::new(self.defaults.shared_dictionary(), node) else {
            // The dictionary built for one node-ID builds for any.
            return;
        };
        // The serial number is the device's, not the EDS's.
        let serial = self.lss.address().serial;
        let _ = defaults.set(IDENTITY, 4, Value::Unsigned32(serial));
        let mut translated = false;
        for (key, value) in self.saved.iter_mut() {
            let (old, new) = (self.defaults.get(key.0, key.1), defaults.get(key.0, key.1));
            if old == Some(value)
                && new != old
                && let Some(new) = new
            {
                *value = new.clone();
                translated = true;
            }
        }
        if translated {
            self.saved_version += 1;
        }
        let mut store = defaults.clone();
        for object in self.store.dictionary().objects.values() {
            for sub in object.subs.keys() {
                let (old, new) = (
                    self.defaults.get(object.index, *sub),
                    defaults.get(object.index, *sub),
                );
                if let Some(value) = self.store.get(object.index, *sub)
                    && (old != Some(value) || old == new)
                {
                    let _ = store.set(object.index, *sub, value.clone());
                }
            }
        }
        if store.get(COMMUNICATION_CONFIG, 1).is_some() {
            let _ = store.set(COMMUNICATION_CONFIG, 1, Value::Unsigned8(node.get()));
        }
        let history = self.emcy.history().clone();
        self.emcy = EmcyProducer::new(node, history.capacity());
        *self.emcy.history_mut() = history;
        self.defaults = defaults;
        self.store = store;
        self.guard = LifeGuard::new(node);
        self.nmt = NmtSlave::new(node);
        self.heartbeat = HeartbeatProducer::new(node);
        self.sdo = SdoServer::new(node, ServerConfig::default());
        self.sdo_request = Function::SdoRx.can_id(node);
        self.guard_request = Function::Heartbeat.can_id(node);
        self.pdos = DevicePdos::new(&self.store, now);
    }

    /// An LSS request: the answer, and what the slave asks of the device.
    fn handle_lss(&mut self, frame: &Frame, now: Instant) -> Vec<Frame> {
        let LssSlaveOutput { reply, event } = self.lss.handle(frame);
        let mut out: Vec<Frame> = reply.into_iter().collect();
        match event {
            Some(LssSlaveEvent::Store {
                node_id,
                bit_timing,
            }) => {
                self.lss_stored = Some(LssStored {
                    node_id,
                    bit_timing,
                });
                // On a UniSwarm device the LSS store and 0x2040 are one.
                if self.store.get(COMMUNICATION_CONFIG, 1).is_some() {
                    match node_id {
                        Some(node) => {
                            self.saved
                                .insert((COMMUNICATION_CONFIG, 1), Value::Unsigned8(node.get()));
                        }
                        None => {
                            self.saved.remove(&(COMMUNICATION_CONFIG, 1));
                        }
                    }
                }
                self.saved_version += 1;
            }
            Some(LssSlaveEvent::Activate(node)) => {
                self.renumber(node, now);
                self.reload_communication_area();
                out.extend(self.start_communication(now));
            }
            // One bit rate on a virtual bus: nothing to switch.
            Some(LssSlaveEvent::ActivateBitTiming { .. }) | None => {}
        }
        out
    }

    pub fn nmt_state(&self) -> NmtState {
        self.nmt.state()
    }

    pub fn store(&self) -> &ObjectStore {
        &self.store
    }

    pub fn store_mut(&mut self) -> &mut ObjectStore {
        &mut self.store
    }

    /// The product's application.
    pub fn behaviour(&self) -> &dyn Behaviour {
        self.behaviour.as_ref()
    }

    /// The product's application as what it is, for its extras (a drive's
    /// limit switches, an LED strip's pixels); `None` for another product.
    pub fn behaviour_mut<T: Behaviour>(&mut self) -> Option<&mut T> {
        let behaviour: &mut dyn std::any::Any = self.behaviour.as_mut();
        behaviour.downcast_mut::<T>()
    }

    /// Runs `f` on the product's application with the device's values, and
    /// sends what it raised; for the simulation's own controls.
    pub fn with_application<R>(
        &mut self,
        now: Instant,
        f: impl FnOnce(&mut dyn Behaviour, &mut DeviceIo<'_>) -> R,
    ) -> R {
        let mut io = DeviceIo::new(
            &mut self.store,
            self.nmt.state(),
            self.sim_ms,
            &mut self.raised,
        );
        let result = f(self.behaviour.as_mut(), &mut io);
        self.take_raised(now);
        result
    }

    /// Injects a fault: heartbeat loss into the core, the rest into the
    /// product's application.
    pub fn inject_fault(&mut self, fault: Fault, now: Instant) -> Result<(), FaultError> {
        match fault {
            Fault::HeartbeatLoss => {
                self.silent = true;
                return Ok(());
            }
            Fault::BitErrors => {
                self.bit_errors = true;
                return Ok(());
            }
            Fault::BusOff => {
                if let Some(transition) = self.controller.force_bus_off() {
                    self.can_state_changed(transition, now);
                }
                return Ok(());
            }
            _ => {}
        }
        self.with_application(now, |behaviour, io| behaviour.inject_fault(io, fault))
    }

    /// Ends an injected fault condition.
    pub fn clear_fault(&mut self, fault: Fault, now: Instant) -> Result<(), FaultError> {
        match fault {
            Fault::BitErrors => {
                self.bit_errors = false;
                return Ok(());
            }
            Fault::BusOff => {
                self.request_recovery(now);
                return Ok(());
            }
            _ => {}
        }
        if fault == Fault::HeartbeatLoss {
            if self.silent {
                self.silent = false;
                // The heartbeat comes back from now on, not in a burst.
                self.heartbeat.set_period_ms(self.heartbeat_ms, now);
            }
            return Ok(());
        }
        self.with_application(now, |behaviour, io| behaviour.clear_fault(io, fault))
    }

    /// The bit rate of the bus the device is on (a bus-off recovery lasts
    /// 128 × 11 bit times of it; none when unlimited).
    pub fn set_bitrate(&mut self, bitrate: Bitrate) {
        self.bitrate = bitrate;
    }

    /// Its CAN controller's error counters and state.
    pub fn controller(&self) -> &FaultConfinement {
        &self.controller
    }

    /// The host asks the bus-off controller to recover: it is error active
    /// again after 128 × 11 recessive bits (at [`DeviceCore::poll`]).
    pub fn request_recovery(&mut self, now: Instant) {
        if self.controller.state() != ErrorState::BusOff || self.recovery_due.is_some() {
            return;
        }
        self.controller.request_recovery();
        let bits = u32::try_from(RECOVERY_BITS).unwrap_or(u32::MAX);
        self.recovery_due = Some(now + self.bitrate.duration_of(bits));
    }

    /// What the CAN controller makes of one frame the device sends: whether
    /// it met a bit error first (the others see an error frame) and whether
    /// it crossed. A bus-off controller sends nothing.
    pub fn transmit(&mut self, now: Instant) -> Transmitted {
        if !self.controller.can_transmit() {
            return Transmitted::default();
        }
        let mut error_frame = false;
        if self.bit_errors {
            error_frame = true;
            if let Some(transition) = self.controller.transmit_error() {
                self.can_state_changed(transition, now);
            }
            if !self.controller.can_transmit() {
                return Transmitted {
                    error_frame,
                    crossed: false,
                };
            }
        }
        if let Some(transition) = self.controller.transmit_ok() {
            self.can_state_changed(transition, now);
        }
        Transmitted {
            error_frame,
            crossed: true,
        }
    }

    /// The frames one frame the device sends puts on the bus: an error
    /// frame if it met a bit error, then the frame if it crossed.
    pub fn on_the_wire(&mut self, frame: Frame, now: Instant) -> [Option<Frame>; 2] {
        let sent = self.transmit(now);
        [
            sent.error_frame.then(crate::can::hub::bit_error_frame),
            sent.crossed.then_some(frame),
        ]
    }

    /// The device's receive queue overflowed: frames were lost before it
    /// could read them. EMCY 0x8110 "CAN overrun" with the communication
    /// bit (CiA 301 table 21), as CANopenNode reports a receive buffer
    /// overflow, once per overrun; the error reset follows a cycle after
    /// the last one.
    pub fn receive_overrun(&mut self, now: Instant) {
        if self.lss.active().is_none() || !self.controller.can_transmit() {
            return;
        }
        let first = self.rx_overrun.is_none();
        self.rx_overrun = Some(now);
        if first {
            self.with_application(now, |_, io| {
                io.set_error_bit(ErrorBit::Communication, true);
                io.emcy(CAN_OVERRUN, [0; 5]);
            });
        }
    }

    /// A communication error other than an RPDO's length: a lost master
    /// (guarding, a consumed heartbeat) or a controller not error active.
    fn other_communication_error(&self) -> bool {
        self.guard.is_lost()
            || self.rx_overrun.is_some()
            || self.controller.state() != ErrorState::ErrorActive
            || self
                .consumed
                .iter()
                .any(|(node, _)| self.consumer.is_lost(*node))
    }

    /// The reaction to a change of the CAN controller's error state (see
    /// the module documentation).
    fn can_state_changed(&mut self, transition: Transition, now: Instant) {
        let other_loss = self.guard.is_lost()
            || self.pdo_length_error
            || self
                .consumed
                .iter()
                .any(|(node, _)| self.consumer.is_lost(*node));
        match (transition.from, transition.to) {
            (ErrorState::ErrorActive, ErrorState::ErrorPassive) => {
                self.with_application(now, |_, io| {
                    io.set_error_bit(ErrorBit::Communication, true);
                    io.emcy(CAN_ERROR_PASSIVE, [0; 5]);
                });
            }
            (ErrorState::ErrorPassive, ErrorState::ErrorActive) => {
                self.with_application(now, |_, io| {
                    if !other_loss {
                        io.set_error_bit(ErrorBit::Communication, false);
                    }
                    io.emcy(0x0000, [0; 5]);
                });
            }
            (_, ErrorState::BusOff) => {
                self.with_application(now, |behaviour, io| {
                    io.set_error_bit(ErrorBit::Communication, true);
                    behaviour.connection_lost(io);
                });
                if self.nmt.state() == NmtState::Operational {
                    self.communication_error = Some(now);
                }
            }
            (ErrorState::BusOff, _) => {
                self.with_application(now, |_, io| {
                    io.set_error_bit(ErrorBit::Communication, true);
                    io.emcy(CAN_BUS_OFF_RECOVERED, [0; 5]);
                });
                self.with_application(now, |_, io| {
                    if !other_loss {
                        io.set_error_bit(ErrorBit::Communication, false);
                    }
                    io.emcy(0x0000, [0; 5]);
                });
                // The heartbeat comes back from now on, not in a burst.
                self.heartbeat.set_period_ms(self.heartbeat_ms, now);
            }
            _ => {}
        }
    }

    /// Milliseconds of simulated time the application has run.
    pub fn sim_ms(&self) -> u64 {
        self.sim_ms
    }

    /// Simulated milliseconds skipped because the host could not keep up.
    pub fn skipped_ticks(&self) -> u64 {
        self.skipped_ticks
    }

    /// Runs the application up to `now`, one tick per whole millisecond
    /// since the last (at most 1000 at once; a longer stall is skipped and
    /// counted in [`DeviceCore::skipped_ticks`]). The first
    /// call only starts the clock.
    pub fn tick_to(&mut self, now: Instant) {
        let step = std::time::Duration::from_millis(TICK_MS);
        let Some(mut last) = self.last_tick else {
            self.last_tick = Some(now);
            return;
        };
        if !self.behaviour.ticks() {
            // Nothing to run: the clock follows without ticking.
            let elapsed = now.saturating_duration_since(last).as_millis() as u64 / TICK_MS;
            self.sim_ms += elapsed * TICK_MS;
            self.last_tick = Some(last + step * elapsed as u32);
            return;
        }
        let mut ticks = 0;
        while last + step <= now {
            if ticks == MAX_CATCH_UP_TICKS {
                let behind = now.saturating_duration_since(last).as_millis() as u64 / TICK_MS;
                self.skipped_ticks += behind;
                self.sim_ms += behind * TICK_MS;
                last += step * behind as u32;
                break;
            }
            last += step;
            self.sim_ms += TICK_MS;
            ticks += 1;
            let mut io = DeviceIo::new(
                &mut self.store,
                self.nmt.state(),
                self.sim_ms,
                &mut self.raised,
            );
            self.behaviour.tick(&mut io);
        }
        self.last_tick = Some(last);
        self.take_raised(now);
    }

    /// When the application next ticks; `None` for a device without one.
    pub fn next_tick(&self) -> Option<Instant> {
        if !self.behaviour.ticks() {
            return None;
        }
        self.last_tick
            .map(|last| last + std::time::Duration::from_millis(TICK_MS))
    }

    /// The EMCYs the application raised: recorded in 0x1003 and queued with
    /// the error register as the application left it.
    fn take_raised(&mut self, now: Instant) {
        if self.raised.is_empty() {
            return;
        }
        let register =
            ErrorRegister::from_raw(self.store.int(ERROR_REGISTER, 0).unwrap_or(0) as u8);
        for raised in self.raised.drain(..) {
            let emcy = Emcy {
                code: raised.code,
                register,
                manufacturer: raised.manufacturer,
            };
            self.emcy.raise(emcy, now);
        }
        self.sync_error_field();
    }

    /// The pre-defined error field (0x1003) in the store, from the history.
    fn sync_error_field(&mut self) {
        let history = self.emcy.history();
        let count = history.count();
        let _ = self
            .store
            .set_int_saturating(PREDEFINED_ERROR_FIELD, 0, count.into());
        for sub in 1..=history.capacity() {
            let entry = history.read(sub).unwrap_or(0);
            let _ = self
                .store
                .set_int_saturating(PREDEFINED_ERROR_FIELD, sub, entry.into());
        }
    }

    /// A life guarding event: the master is lost (or back).
    fn life_guard_event(&mut self, event: LifeGuardEvent, now: Instant) {
        self.master_lost(event == LifeGuardEvent::Lost, now);
    }

    /// The master went silent (life guarding, or a consumed heartbeat):
    /// EMCY 0x8130 with the communication bit, and the application told; or
    /// it is back: the error reset once nothing is lost any more.
    fn master_lost(&mut self, lost: bool, now: Instant) {
        let still_lost = self.guard.is_lost()
            || self.pdo_length_error
            || self
                .consumed
                .iter()
                .any(|(node, _)| self.consumer.is_lost(*node));
        self.with_application(now, |behaviour, io| {
            if lost {
                io.set_error_bit(ErrorBit::Communication, true);
                io.emcy(LIFE_GUARD_ERROR, [0; 5]);
                behaviour.connection_lost(io);
            } else if !still_lost {
                io.set_error_bit(ErrorBit::Communication, false);
                io.emcy(0x0000, [0; 5]);
            }
        });
        if lost && self.nmt.state() == NmtState::Operational {
            // After the EMCY has gone out (none is sent in stopped).
            self.communication_error = Some(now);
        }
    }

    /// A communication error in operational (CiA 301 §7.2.8.2.1.1; UMC
    /// manual chapter 3 §6.1.2, Table 3.11): 0x1029.1 says where the node
    /// goes, 0 pre-operational, 1 nowhere, 2 stopped. A device without
    /// 0x1029 (the JMC) stays where it is.
    fn apply_error_behaviour(&mut self, now: Instant) {
        self.communication_error = None;
        if self.nmt.state() != NmtState::Operational {
            return;
        }
        let command = match self.store.int(ERROR_BEHAVIOUR, 1) {
            Some(0) => NmtCommand::EnterPreOperational,
            Some(2) => NmtCommand::Stop,
            _ => return,
        };
        let message = NmtMessage::new(command, NmtTarget::Node(self.node()));
        if let Some(NmtEvent::StateChanged { from, to }) = self.nmt.handle(message) {
            self.with_application(now, |behaviour, io| behaviour.nmt_changed(io, from, to));
        }
    }

    /// A heartbeat (or boot-up) of a node 0x1016 watches.
    fn consume_heartbeat(&mut self, frame: &Frame, now: Instant) {
        let watched = heartbeat_node(frame.id())
            .is_some_and(|node| self.consumed.iter().any(|(watched, _)| *watched == node));
        if !watched || frame.is_remote() {
            return;
        }
        // A malformed heartbeat is ignored, as devices do.
        let events = self.consumer.on_frame(frame, now).unwrap_or_default();
        for event in events {
            if matches!(event, HeartbeatEvent::Recovered { .. }) {
                self.master_lost(false, now);
            }
        }
    }

    /// Rebuilds the PDOs after the device itself changed their parameters in
    /// [`DeviceCore::store_mut`] (an SDO write does so by itself).
    pub fn pdo_parameters_changed(&mut self, now: Instant) {
        self.pdos.rebuild(&self.store, now);
    }

    /// The values 0x1010 saved (to keep them across a restart).
    pub fn saved(&self) -> &SavedValues {
        &self.saved
    }

    /// A number that changes whenever [`DeviceCore::saved`] or the
    /// program image ([`DeviceCore::program`]) does.
    pub fn saved_version(&self) -> u64 {
        self.saved_version + self.program.version()
    }

    /// The program memory of CiA 302-3 (see [`super::program`]).
    pub fn program(&self) -> &ProgramMemory {
        &self.program
    }

    /// Takes a program image kept before a restart; it runs from the next
    /// boot, as after a power cycle.
    pub fn load_program(&mut self, image: Option<Vec<u8>>) {
        self.program.load(image);
    }

    /// Takes values saved before a restart; they are in force from the next
    /// boot, as after a power cycle.
    pub fn load_saved(&mut self, saved: SavedValues) {
        self.saved = saved;
        self.store = self.defaults.clone();
        self.apply_saved(Area::All);
        self.program.sync(&mut self.store);
        self.pdos = DevicePdos::new(&self.store, Instant::now());
    }

    /// Power-on: the application starts from the store's values, then
    /// initialisation ends with the boot-up message and pre-operational, the
    /// heartbeat of 0x1017 running.
    pub fn boot(&mut self, now: Instant) -> Vec<Frame> {
        self.power_on_node(now);
        self.reset_application(now);
        self.start_communication(now)
    }

    /// The node-ID of power-on and reset node: pending and active in the
    /// LSS slave, and the device renumbered to it.
    fn power_on_node(&mut self, now: Instant) {
        let node = self.boot_node();
        self.lss.power_on(node);
        if let Some(node) = node
            && node != self.node()
        {
            self.renumber(node, now);
            self.store = self.defaults.clone();
            self.apply_saved(Area::All);
            self.pdos = DevicePdos::new(&self.store, now);
        }
    }

    /// The application starts afresh: error register and error history
    /// cleared, then the product's reset.
    fn reset_application(&mut self, now: Instant) {
        self.emcy = EmcyProducer::new(self.node(), self.emcy.history().capacity());
        let _ = self.store.set_int_saturating(ERROR_REGISTER, 0, 0);
        self.sync_error_field();
        // The stored program starts, with the version its image names.
        self.program.boot();
        self.program.sync(&mut self.store);
        self.with_application(now, |behaviour, io| behaviour.reset(io));
    }

    /// The end of initialisation, after power-on and after either reset.
    fn start_communication(&mut self, now: Instant) -> Vec<Frame> {
        if self.lss.active().is_none() {
            // An unconfigured LSS slave does not leave initialisation.
            return Vec::new();
        }
        let boot_up = self.nmt.boot_up();
        self.program.sync(&mut self.store);
        self.pdos = DevicePdos::new(&self.store, now);
        self.guard.reset();
        self.communication_error = None;
        // The producer restarts from 0x1017 as the reset left it, whatever
        // period ran before (comparing with the old one would keep it).
        self.heartbeat_ms = self.heartbeat_period();
        self.heartbeat.set_period_ms(self.heartbeat_ms, now);
        self.follow_communication_parameters(now);
        if self.silent {
            return Vec::new();
        }
        vec![boot_up]
    }

    /// Takes a frame from the bus; returns the frames to send.
    pub fn handle_frame(&mut self, frame: &Frame, now: Instant) -> Vec<Frame> {
        if !self.controller.can_transmit() {
            // Bus-off: off the bus, it hears nothing.
            return Vec::new();
        }
        if frame.is_error() {
            if let Some(transition) = self.controller.receive_error() {
                self.can_state_changed(transition, now);
            }
            return Vec::new();
        }
        if self.controller.rec() > 0
            && let Some(transition) = self.controller.receive_ok()
        {
            self.can_state_changed(transition, now);
        }
        if is_lss_request(frame) {
            return if self.silent || !self.answers_lss {
                Vec::new()
            } else {
                self.handle_lss(frame, now)
            };
        }
        if self.lss.active().is_none() {
            return Vec::new();
        }
        let before = self.nmt.state();
        match self.nmt.on_frame(frame) {
            Ok(Some(NmtEvent::ResetNode)) => {
                self.power_on_node(now);
                self.store = self.defaults.clone();
                self.apply_saved(Area::All);
                self.reset_application(now);
                return self.start_communication(now);
            }
            Ok(Some(NmtEvent::ResetCommunication)) => {
                // CiA 305 §5.2: the pending node-ID becomes active.
                if let Some(node) = self.lss.reset_communication() {
                    self.renumber(node, now);
                }
                self.reload_communication_area();
                let boot_up = self.start_communication(now);
                // UMC manual §1.4.8, CiA 402: reset communication is an
                // abort connection event, as a change of state is; the
                // application runs on through it, so 0x6007 decides.
                self.with_application(now, |behaviour, io| {
                    behaviour.nmt_changed(io, before, NmtState::PreOperational)
                });
                return boot_up;
            }
            Ok(Some(NmtEvent::StateChanged { from, to })) => {
                if to == NmtState::Operational {
                    self.pdos.restart(now);
                }
                self.with_application(now, |behaviour, io| behaviour.nmt_changed(io, from, to));
                return Vec::new();
            }
            Ok(None) => {}
            // A malformed NMT frame is ignored, as devices do.
            Err(_) => return Vec::new(),
        }
        if frame.is_remote() && frame.id() == self.guard_request {
            return self.guarding_request(frame, now);
        }
        if heartbeat_node(frame.id()).is_some() {
            self.consume_heartbeat(frame, now);
            return Vec::new();
        }
        let mut written = std::mem::take(&mut self.written);
        let out = if frame.id() == self.sdo_request && self.nmt.allows(NmtService::Sdo) {
            let mut access = DeviceAccess {
                state: self.nmt.state(),
                store: &mut self.store,
                defaults: &self.defaults,
                saved: &mut self.saved,
                saved_version: &mut self.saved_version,
                behaviour: self.behaviour.as_ref(),
                history: self.emcy.history_mut(),
                written: &mut written,
                pdo_changed: false,
                program: &mut self.program,
            };
            let replies = self.sdo.handle_frame(frame, now, &mut access);
            // A restore (0x1011) brings back communication parameters too.
            let restored = access.pdo_changed;
            // A program command, or a restore that reloaded 0x1F51 ff.
            self.program.sync(&mut self.store);
            if restored {
                self.pdos.rebuild(&self.store, now);
            }
            if restored || written.iter().any(|(index, _)| is_communication(*index)) {
                self.follow_communication_parameters(now);
            }
            replies
        } else if self.nmt.allows(NmtService::Pdo) {
            let out = self
                .pdos
                .handle_frame(frame, &mut self.store, now, &mut written);
            let exceeded_too = self.behaviour.reports_pdo_length_exceeded();
            let mut reported = false;
            for code in self.pdos.take_length_errors() {
                if code != EMCY_PDO_LENGTH_EXCEEDED || exceeded_too {
                    // A communication error (CiA 301 table 21, CANopenNode's
                    // register 0x11 for them), until an RPDO is right again.
                    self.pdo_length_error = true;
                    reported = true;
                    self.with_application(now, |_, io| {
                        io.set_error_bit(ErrorBit::Communication, true);
                        io.emcy(code, [0; 5]);
                    });
                }
            }
            if self.pdos.take_rpdo_processed() && !reported && self.pdo_length_error {
                self.pdo_length_error = false;
                let other = self.other_communication_error();
                self.with_application(now, |_, io| {
                    if !other {
                        io.set_error_bit(ErrorBit::Communication, false);
                    }
                    io.emcy(0x0000, [0; 5]);
                });
            }
            out
        } else {
            Vec::new()
        };
        if !written.is_empty() {
            self.with_application(now, |behaviour, io| {
                for &(index, sub) in &written {
                    behaviour.written(io, index, sub);
                }
            });
            written.clear();
        }
        self.written = written;
        out
    }

    /// A node guarding request: the reply, unless the heartbeat is in use
    /// (it takes precedence, UMC manual §4.2) or the device is silenced.
    fn guarding_request(&mut self, frame: &Frame, now: Instant) -> Vec<Frame> {
        if self.silent || self.heartbeat_ms != 0 {
            return Vec::new();
        }
        let output = self.guard.on_frame(frame, now, self.nmt.state());
        if let Some(event) = output.event {
            self.life_guard_event(event, now);
        }
        output.reply.into_iter().collect()
    }

    /// Timers due at `now`: SDO timeouts, heartbeats, life guarding, EMCYs
    /// and PDOs. The application's ticks are [`DeviceCore::tick_to`]'s.
    pub fn poll(&mut self, now: Instant) -> Vec<Frame> {
        let mut out = Vec::new();
        if self.recovery_due.is_some_and(|due| due <= now) {
            self.recovery_due = None;
            if let Some(transition) = self.controller.recessive_bits(RECOVERY_BITS) {
                self.can_state_changed(transition, now);
            }
        }
        if self.lss.active().is_none() {
            return out;
        }
        if self.sdo.deadline().is_some_and(|d| d <= now) {
            out.extend(self.sdo.handle_timeout(now));
        }
        // The overrun is over once a cycle has passed without another.
        if self.rx_overrun.is_some_and(|at| now > at) {
            self.rx_overrun = None;
            let other = self.pdo_length_error || self.other_communication_error();
            self.with_application(now, |_, io| {
                if !other {
                    io.set_error_bit(ErrorBit::Communication, false);
                }
                io.emcy(0x0000, [0; 5]);
            });
        }
        if self.nmt.allows(NmtService::Heartbeat)
            && let Some(frame) = self.heartbeat.poll(now, self.nmt.state())
            && !self.silent
        {
            out.push(frame);
        }
        if let Some(event) = self.guard.poll(now) {
            self.life_guard_event(event, now);
        }
        if self.consumer.deadline().is_some_and(|d| d <= now) {
            for event in self.consumer.poll(now) {
                if matches!(event, HeartbeatEvent::Lost { .. }) {
                    self.master_lost(true, now);
                }
            }
        }
        if self.nmt.allows(NmtService::Emcy) {
            while let Some(frame) = self.emcy.poll(now) {
                // With 0x1014 bit 31 set EMCYs are recorded, not sent.
                if self.emcy_enabled {
                    out.push(frame);
                }
            }
        }
        if self.communication_error.is_some_and(|at| at <= now) {
            self.apply_error_behaviour(now);
        }
        if self.nmt.allows(NmtService::Pdo) {
            out.extend(self.pdos.poll(&self.store, now));
        }
        out
    }

    /// When [`DeviceCore::poll`] (or [`DeviceCore::tick_to`]) has work next.
    pub fn deadline(&self) -> Option<Instant> {
        if self.lss.active().is_none() {
            return self.next_tick();
        }
        let pdos = self
            .nmt
            .allows(NmtService::Pdo)
            .then(|| self.pdos.deadline())
            .flatten();
        let emcy = self
            .nmt
            .allows(NmtService::Emcy)
            .then(|| self.emcy.deadline())
            .flatten();
        [
            self.sdo.deadline(),
            self.heartbeat.deadline(),
            self.guard.deadline(),
            self.consumer.deadline(),
            emcy,
            pdos,
            self.communication_error,
            self.recovery_due,
            self.next_tick(),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Writes to 0x1017 (heartbeat), 0x100C/0x100D (guarding) and
    /// 0x1014/0x1015 (EMCY) take effect at once.
    fn follow_communication_parameters(&mut self, now: Instant) {
        self.follow_heartbeat_time(now);
        let guard_time = self.store.int(GUARD_TIME, 0).unwrap_or(0) as u16;
        let life_factor = self.store.int(LIFE_TIME_FACTOR, 0).unwrap_or(0) as u8;
        let life_time = u64::from(guard_time) * u64::from(life_factor);
        if self
            .guard
            .life_time()
            .map(|t| t.as_millis() as u64)
            .unwrap_or(0)
            != life_time
        {
            self.guard.configure(guard_time, life_factor, now);
        }
        let consumed: Vec<_> = (1..=u8::MAX)
            .map_while(|sub| self.store.int(CONSUMER_HEARTBEAT_TIME, sub))
            .filter_map(|raw| ConsumerTime::from_raw(raw as u32).monitored())
            .collect();
        if consumed != self.consumed {
            // A new configuration starts afresh: each timeout runs from the
            // watched node's next heartbeat.
            self.consumer = HeartbeatConsumer::new();
            for (node, timeout) in &consumed {
                self.consumer.monitor(*node, *timeout);
            }
            self.consumed = consumed;
        }
        let default_cob = u32::from(Function::Emcy.cob_id(self.node()));
        let cob = self
            .store
            .int(COB_ID_EMCY, 0)
            .map_or(default_cob, |raw| raw as u32);
        self.emcy_enabled = cob & 0x8000_0000 == 0;
        let id = if cob & (1 << 29) != 0 {
            CanId::Extended(cob & 0x1FFF_FFFF)
        } else {
            CanId::Standard((cob & 0x7FF) as u16)
        };
        if id != self.emcy.cob_id() {
            let mut emcy = EmcyProducer::with_cob_id(id, self.emcy.history().capacity());
            *emcy.history_mut() = self.emcy.history().clone();
            self.emcy = emcy;
        }
        self.emcy
            .set_inhibit_time_100us(self.store.int(INHIBIT_TIME_EMCY, 0).unwrap_or(0) as u16);
    }

    /// A write to 0x1017 changes the heartbeat from the next period on.
    fn follow_heartbeat_time(&mut self, now: Instant) {
        let period = self.heartbeat_period();
        if period != self.heartbeat_ms {
            self.heartbeat_ms = period;
            self.heartbeat.set_period_ms(period, now);
        }
    }

    /// 0x1017 as it is in the store, in ms.
    fn heartbeat_period(&self) -> u16 {
        match self.store.get(PRODUCER_HEARTBEAT_TIME, 0) {
            Some(Value::Unsigned16(ms)) => *ms,
            _ => 0,
        }
    }

    fn reload_communication_area(&mut self) {
        copy_area(&self.defaults, &mut self.store, Area::Communication);
        self.apply_saved(Area::Communication);
        self.pdos = DevicePdos::new(&self.store, Instant::now());
    }

    fn apply_saved(&mut self, area: Area) {
        for ((index, sub), value) in &self.saved {
            if area.contains(*index) {
                let _ = self.store.set(*index, *sub, value.clone());
            }
        }
    }
}

/// The LSS address a store's 0x1018 gives.
fn identity(store: &ObjectStore) -> LssAddress {
    let part = |sub| store.int(IDENTITY, sub).unwrap_or(0) as u32;
    LssAddress {
        vendor_id: part(1),
        product_code: part(2),
        revision: part(3),
        serial: part(4),
    }
}

/// Whether `index` is in the communication area, whose parameters the core
/// itself acts on.
fn is_communication(index: u16) -> bool {
    Area::Communication.contains(index)
}

/// Copies every value of `area` from `from` to `to`.
fn copy_area(from: &ObjectStore, to: &mut ObjectStore, area: Area) {
    for object in from.dictionary().objects.values() {
        if !area.contains(object.index) {
            continue;
        }
        for sub in object.subs.keys() {
            if let Some(value) = from.get(object.index, *sub) {
                let _ = to.set(object.index, *sub, value.clone());
            }
        }
    }
}

/// The dictionary as the SDO server of a device sees it: the store, with
/// 0x1010 and 0x1011 acting instead of storing what is written, and the
/// re-mapping rules of CiA 301 on the PDO parameters (see [`pdo::check_write`]).
struct DeviceAccess<'a> {
    state: NmtState,
    store: &'a mut ObjectStore,
    defaults: &'a ObjectStore,
    saved: &'a mut SavedValues,
    saved_version: &'a mut u64,
    /// The product's rules on writes.
    behaviour: &'a dyn Behaviour,
    /// 0x1003, which a write of 0 to sub 0 clears.
    history: &'a mut ErrorHistory,
    /// The objects written, for the product's application.
    written: &'a mut Vec<(u16, u8)>,
    /// A PDO or SYNC parameter changed: the device rebuilds its PDOs.
    pdo_changed: bool,
    /// 0x1F50 and 0x1F51 act on the program memory (CiA 302-3).
    program: &'a mut ProgramMemory,
}

impl DeviceAccess<'_> {
    fn is_command(index: u16, sub: u8) -> bool {
        matches!(index, STORE_PARAMETERS | RESTORE_PARAMETERS) && sub >= 1
    }

    /// CiA 301 §7.5.2.16: bits 0–29 of 0x1014 do not change while the
    /// EMCY exists (bit 31 clear): 0x06090030.
    fn check_emcy_cob_id(&self, before: Option<&Value>, data: &[u8]) -> Result<(), AbortCode> {
        let (Some(old), Ok(new)) = (before.and_then(Value::as_i128), <[u8; 4]>::try_from(data))
        else {
            return Ok(());
        };
        let (old, new) = (old as u32, u32::from_le_bytes(new));
        const ID_AND_FORMAT: u32 = 0x3FFF_FFFF;
        if old & 0x8000_0000 == 0 && old & ID_AND_FORMAT != new & ID_AND_FORMAT {
            return Err(AbortCode::InvalidValue);
        }
        Ok(())
    }

    /// What every device refuses of a value its dictionary would take
    /// (0x06090030):
    /// - 0x1005 (CiA 301 §7.5.2.6): bit 30, generate SYNC, on a device
    ///   that cannot produce SYNC (no 0x1006, communication cycle period);
    ///   and bits 0–29 changed while bit 30 is set.
    /// - 0x2040 sub 1 Node_ID (UMC manual §2.3.1, UIO1LED manual §4.2): a
    ///   node-ID the device could not boot with (CiA 301: 1–127).
    fn check_core_value(&self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        match (index, sub) {
            (COB_ID_SYNC, 0) => {
                let Ok(bytes) = <[u8; 4]>::try_from(data) else {
                    return Ok(());
                };
                let new = u32::from_le_bytes(bytes);
                const GENERATE: u32 = 1 << 30;
                const ID_AND_FORMAT: u32 = 0x3FFF_FFFF;
                if new & GENERATE != 0 && self.store.dictionary().get(CYCLE_PERIOD).is_none() {
                    return Err(AbortCode::InvalidValue);
                }
                let old = self.store.int(COB_ID_SYNC, 0).unwrap_or(0) as u32;
                if old & GENERATE != 0 && old & ID_AND_FORMAT != new & ID_AND_FORMAT {
                    return Err(AbortCode::InvalidValue);
                }
            }
            (COMMUNICATION_CONFIG, 1) if matches!(data, [0] | [128..=255]) => {
                return Err(AbortCode::InvalidValue);
            }
            _ => {}
        }
        Ok(())
    }

    fn save(&mut self, area: Area) {
        *self.saved_version += 1;
        self.saved.retain(|(index, _), _| !area.contains(*index));
        for object in self.store.dictionary().objects.values() {
            if !area.contains(object.index) {
                continue;
            }
            for (sub, entry) in &object.subs {
                // Parameters are what can be written; status values are not saved.
                // Neither are program download and control.
                let is_command = Self::is_command(object.index, *sub)
                    || matches!(object.index, PROGRAM_DATA | PROGRAM_CONTROL);
                if entry.access.is_writable()
                    && !is_command
                    && let Some(value) = self.store.get(object.index, *sub)
                {
                    self.saved.insert((object.index, *sub), value.clone());
                }
            }
        }
    }

    fn restore_factory(&mut self, area: Area) {
        *self.saved_version += 1;
        self.saved.retain(|(index, _), _| !area.contains(*index));
        copy_area(self.defaults, self.store, area);
    }

    fn restore_saved(&mut self, area: Area) {
        for ((index, sub), value) in self.saved.iter() {
            if area.contains(*index) {
                let _ = self.store.set(*index, *sub, value.clone());
            }
        }
    }
}

impl ObjectAccess for DeviceAccess<'_> {
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
        self.store.read(index, sub)
    }

    fn check_write(&mut self, index: u16, sub: u8, size: Option<usize>) -> Result<(), AbortCode> {
        self.behaviour.check_write(self.store, index, sub, size)?;
        self.store.check_write(index, sub, size)?;
        pdo::check_write(self.store, index, sub, None, self.behaviour.pdo_rules())?;
        if self.program.handles(index, sub) {
            self.program.check_write(index, size)?;
        }
        if Self::is_command(index, sub) && self.state != NmtState::PreOperational {
            return Err(AbortCode::CannotStoreLocalControl);
        }
        Ok(())
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        if self.program.handles(index, sub) {
            self.store.check_write(index, sub, Some(data.len()))?;
            // The image is kept in the program memory, not the store.
            return self.program.write(index, data);
        }
        if !Self::is_command(index, sub) {
            self.behaviour
                .check_write(self.store, index, sub, Some(data.len()))?;
            if index == PREDEFINED_ERROR_FIELD {
                self.store.check_write(index, sub, Some(data.len()))?;
                let value = data
                    .iter()
                    .rev()
                    .fold(0u32, |value, byte| value << 8 | u32::from(*byte));
                self.history
                    .write(sub, value)
                    .map_err(|error| AbortCode::from_raw(error.abort_code()))?;
                // The count goes to 0; the entries read 0 from now on.
                for entry in 0..=self.history.capacity() {
                    self.store.set_int_saturating(index, entry, 0);
                }
                return Ok(());
            }
            self.check_core_value(index, sub, data)?;
            if pdo::is_pdo_parameter(index) {
                self.store.check_write(index, sub, Some(data.len()))?;
                self.behaviour.check_value(self.store, index, sub, data)?;
                pdo::check_write(
                    self.store,
                    index,
                    sub,
                    Some(data),
                    self.behaviour.pdo_rules(),
                )?;
                self.store.write(index, sub, data)?;
                self.pdo_changed = true;
                return Ok(());
            }
            self.behaviour.check_value(self.store, index, sub, data)?;
            let before = self.store.get(index, sub).cloned();
            self.store.write(index, sub, data)?;
            if index == COB_ID_EMCY
                && let Err(abort) = self.check_emcy_cob_id(before.as_ref(), data)
            {
                // Within the dictionary's limits, but not allowed now.
                if let Some(before) = before {
                    let _ = self.store.set(index, sub, before);
                }
                return Err(abort);
            }
            self.written.push((index, sub));
            return Ok(());
        }
        self.check_write(index, sub, Some(data.len()))?;
        // A restore brings back PDO parameters too.
        self.pdo_changed = true;
        match (index, data) {
            (STORE_PARAMETERS, signature) if signature == SAVE_SIGNATURE => {
                let area = Area::of_sub(sub).ok_or(AbortCode::SubIndexDoesNotExist)?;
                self.save(area);
                Ok(())
            }
            (RESTORE_PARAMETERS, signature) if signature == LOAD_SIGNATURE => {
                match (Area::of_sub(sub), sub.checked_sub(4).and_then(Area::of_sub)) {
                    (Some(area), _) => self.restore_factory(area),
                    (None, Some(area)) => self.restore_saved(area),
                    (None, None) => return Err(AbortCode::SubIndexDoesNotExist),
                }
                Ok(())
            }
            // 0 and 1 configure the automatic restore of 0x1011 (table 3.22).
            (RESTORE_PARAMETERS, [0 | 1, 0, 0, 0]) => self.store.write(index, sub, data),
            _ => Err(AbortCode::CannotStore),
        }
    }

    fn fixed_size(&mut self, index: u16, sub: u8) -> Option<usize> {
        self.store.fixed_size(index, sub)
    }
}

/// Runs `device` on `bus` until the bus closes: boots it, then answers and
/// produces. The device stays shared so that its behaviour (or a test)
/// changes it while it runs. It listens from the moment this is called.
pub fn run_device(bus: Bus, device: Arc<Mutex<DeviceCore>>) -> impl Future<Output = ()> + Send {
    let frames = bus.subscribe();
    drive(bus, frames, device)
}

async fn drive(bus: Bus, mut frames: FrameReceiver, device: Arc<Mutex<DeviceCore>>) {
    let now = || tokio::time::Instant::now().into_std();
    let boot = lock(&device).boot(now());
    send_all(&bus, boot).await;
    loop {
        let deadline = lock(&device).deadline().map(tokio::time::Instant::from_std);
        let out = tokio::select! {
            received = frames.recv() => match received {
                Ok(frame) => lock(&device).handle_frame(&frame.frame, now()),
                // Requests lost in an overrun end as timeouts, as on a real bus.
                Err(RecvError::Lagged(_)) => continue,
                Err(RecvError::Closed) => return,
            },
            _ = sleep_until(deadline) => {
                let mut device = lock(&device);
                device.tick_to(now());
                device.poll(now())
            }
        };
        let out: Vec<Frame> = {
            let mut device = lock(&device);
            let now = now();
            out.into_iter()
                .flat_map(|frame| device.on_the_wire(frame, now))
                .flatten()
                .collect()
        };
        send_all(&bus, out).await;
    }
}

async fn send_all(bus: &Bus, frames: Vec<Frame>) {
    for frame in frames {
        if let Err(err) = bus.send(frame).await {
            tracing::debug!("virtual device: frame not sent: {err}");
        }
    }
}

fn lock(device: &Mutex<DeviceCore>) -> MutexGuard<'_, DeviceCore> {
    device
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

async fn sleep_until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(deadline) => tokio::time::sleep_until(deadline).await,
        None => std::future::pending().await,
    }
}

#[cfg(test)]
mod tests;
