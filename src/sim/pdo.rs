//! The PDOs of a virtual device (CiA 301 §7.2.2, parameters §7.5.2.35–38):
//! built from the communication (0x1400–0x15FF, 0x1800–0x19FF) and mapping
//! (0x1600–0x17FF, 0x1A00–0x1BFF) parameters of its [`ObjectStore`], with the
//! rules of dynamic re-mapping checked on every SDO write to them.
//!
//! TPDOs carry the mapped values packed from the store, sent by the
//! [`TpdoTrigger`] of each: on SYNC, by the event timer, on a change of the
//! packed bytes since the last transmission (event-driven types and type 0),
//! or on a remote frame. RPDOs write their mapped objects into the store, at
//! once or, for synchronous types, at the next SYNC; a frame shorter than its
//! mapping is not applied. The device core runs all this only in NMT
//! operational.

use std::time::{Duration, Instant};

use crate::can::{CanId, Frame};
use crate::canopen::od::Value;
use crate::canopen::pdo::{
    EMCY_PDO_LENGTH_EXCEEDED, MappedValue, MappingEntry, PdoCobId, PdoCommParams, PdoKind,
    PdoMapping, Rpdo, TpdoTrigger, TransmissionType,
};
use crate::canopen::sdo::AbortCode;
use crate::canopen::sync::{SYNC_COB_ID, SyncConsumer};

use super::objects::ObjectStore;

/// 0x1005: COB-ID SYNC message.
const COB_ID_SYNC: u16 = 0x1005;
/// 0x1019: synchronous counter overflow value.
const SYNC_COUNTER_OVERFLOW: u16 = 0x1019;
/// How often mapped values are compared for a change of state: a device's
/// application cycle, short enough for a dashboard, long enough to cost
/// nothing.
const CHANGE_SCAN: Duration = Duration::from_millis(10);

/// How strictly a device guards its PDO parameters against writes while a
/// PDO is in use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PdoRules {
    /// CiA 301 §7.5.2.35–38: the COB-ID and the mapping of a valid PDO are
    /// fixed (0x06090030, 0x06040043); set bit 31 of the COB-ID first.
    #[default]
    Cia301,
    /// The JMC stepper's (its manual's programming routines, appendix): the
    /// COB-ID of a valid PDO may be rewritten, and its mapping re-mapped by
    /// setting sub 0 to 0, writing the entries, then sub 0, each taking
    /// effect at once.
    RemapWhileValid,
}

/// Whether a write to `index` changes what [`DevicePdos`] is built from.
pub fn is_pdo_parameter(index: u16) -> bool {
    PdoKind::from_index(index).is_some() || matches!(index, COB_ID_SYNC | SYNC_COUNTER_OVERFLOW)
}

/// A value's raw bits, little-endian, zero-extended (what a PDO carries).
fn value_bits(value: &Value) -> u64 {
    let bytes = value.to_bytes();
    let mut raw = [0u8; 8];
    let n = bytes.len().min(8);
    raw[..n].copy_from_slice(&bytes[..n]);
    u64::from_le_bytes(raw)
}

fn le_u32(data: &[u8]) -> u32 {
    let mut raw = [0u8; 4];
    let n = data.len().min(4);
    raw[..n].copy_from_slice(&data[..n]);
    u32::from_le_bytes(raw)
}

fn read_u32(store: &ObjectStore, index: u16, sub: u8) -> Option<u32> {
    store.get(index, sub).map(|value| value_bits(value) as u32)
}

/// The communication parameters in the store at `index`; `None` without a
/// readable COB-ID. Sub-indexes the dictionary lacks count as 0.
fn comm_params(store: &ObjectStore, kind: PdoKind, index: u16) -> Option<PdoCommParams> {
    let cob_id = PdoCobId::from_raw(read_u32(store, index, 1)?).ok()?;
    let mut params = PdoCommParams::new(cob_id);
    if let Some(raw) = read_u32(store, index, 2) {
        params.transmission_type = TransmissionType::from_raw(raw as u8);
    }
    params.inhibit_time_100us = read_u32(store, index, 3).unwrap_or(0) as u16;
    params.event_timer_ms = read_u32(store, index, 5).unwrap_or(0) as u16;
    if kind == PdoKind::Tpdo {
        params.sync_start = read_u32(store, index, 6).unwrap_or(0) as u8;
    }
    Some(params)
}

/// The raw entries 1 to sub 0 of the mapping parameter at `index`; `None`
/// when sub 0 names an entry the dictionary lacks.
fn mapping_raw(store: &ObjectStore, index: u16) -> Option<Vec<u32>> {
    let count = read_u32(store, index, 0).unwrap_or(0) as u8;
    (1..=count).map(|sub| read_u32(store, index, sub)).collect()
}

/// The mapping at `index` if every entry may be mapped in a PDO of `kind`.
fn mapping(store: &ObjectStore, kind: PdoKind, index: u16) -> Option<PdoMapping> {
    let raw = mapping_raw(store, index)?;
    raw.iter()
        .all(|&entry| entry != 0 && check_entry(store, kind, entry).is_ok())
        .then(|| PdoMapping::from_raw(&raw).ok())
        .flatten()
}

/// Checks one mapping entry against the dictionary (step 3 of the re-mapping
/// procedure): 0x06020000 for an object that does not exist, 0x06040041 for
/// one that cannot be mapped (not mappable, wrong direction, too many bits).
fn check_entry(store: &ObjectStore, kind: PdoKind, raw: u32) -> Result<(), AbortCode> {
    if raw == 0 {
        return Ok(());
    }
    let entry = MappingEntry::from_raw(raw);
    if entry.bits == 0 {
        return Err(AbortCode::CannotMapToPdo);
    }
    if entry.is_dummy() {
        return if entry.sub == 0 {
            Ok(())
        } else {
            Err(AbortCode::CannotMapToPdo)
        };
    }
    let sub = store
        .dictionary()
        .sub(entry.index, entry.sub)
        .ok_or(AbortCode::ObjectDoesNotExist)?;
    let direction = match kind {
        PdoKind::Rpdo => sub.access.is_writable(),
        PdoKind::Tpdo => sub.access.is_readable(),
    };
    let fits = sub
        .data_type
        .bits()
        .is_some_and(|bits| u32::from(entry.bits) <= bits);
    if !sub.pdo_mappable || !direction || !fits {
        return Err(AbortCode::CannotMapToPdo);
    }
    Ok(())
}

/// The CiA 301 rules for an SDO write to a PDO parameter (`index` in
/// 0x1400–0x1BFF), before the store's own checks. With `data` `None` only
/// what does not depend on the value (for the initiate of a segmented
/// transfer).
///
/// Mapping entries (sub ≥ 1) may only be written while the PDO is not valid
/// (COB-ID bit 31 set) and sub 0 is 0, sub 0 only while the PDO is not
/// valid; both refused with 0x06040043 otherwise. Sub 0 is checked against
/// the entries it enables (0x06040042 beyond 64 bits), the COB-ID may only be
/// made valid over a valid mapping (0x06040043), and the communication
/// parameters follow [`PdoCommParams::write`]. [`PdoRules::RemapWhileValid`]
/// drops the two rules on a valid PDO.
pub fn check_write(
    store: &ObjectStore,
    index: u16,
    sub: u8,
    data: Option<&[u8]>,
    rules: PdoRules,
) -> Result<(), AbortCode> {
    let Some((kind, number)) = PdoKind::from_index(index) else {
        return Ok(());
    };
    let (Some(comm_index), Some(mapping_index)) =
        (kind.comm_index(number), kind.mapping_index(number))
    else {
        return Ok(());
    };
    let mut params = comm_params(store, kind, comm_index);
    if rules == PdoRules::RemapWhileValid
        && let Some(params) = &mut params
    {
        // As if bit 31 had been set first: what a valid PDO forbids, this
        // device allows.
        params.cob_id.valid = false;
    }
    if index == mapping_index {
        if params.is_some_and(|params| params.cob_id.valid) {
            return Err(AbortCode::ParameterIncompatible);
        }
        if sub >= 1 && read_u32(store, index, 0).unwrap_or(0) != 0 {
            return Err(AbortCode::ParameterIncompatible);
        }
        let Some(data) = data else {
            return Ok(());
        };
        let value = le_u32(data);
        if sub >= 1 {
            return check_entry(store, kind, value);
        }
        if value > 0x40 {
            return Err(AbortCode::PdoLengthExceeded);
        }
        let raw: Vec<u32> = (1..=value as u8)
            .map(|sub| read_u32(store, index, sub).ok_or(AbortCode::PdoLengthExceeded))
            .collect::<Result<_, _>>()?;
        for &entry in &raw {
            check_entry(store, kind, entry)?;
        }
        PdoMapping::from_raw(&raw).map_err(|error| AbortCode::from_raw(error.abort_code()))?;
        return Ok(());
    }
    // Sub 0 is read only, sub 4 unused: the store answers for them.
    let (Some(data), Some(mut params), 1..=3 | 5..) = (data, params, sub) else {
        return Ok(());
    };
    let was_valid = params.cob_id.valid;
    params
        .write(kind, sub, le_u32(data))
        .map_err(|error| AbortCode::from_raw(error.abort_code()))?;
    if sub == 1
        && params.cob_id.valid
        && !was_valid
        && mapping(store, kind, mapping_index).is_none()
    {
        return Err(AbortCode::ParameterIncompatible);
    }
    Ok(())
}

/// One TPDO of the device.
#[derive(Debug, Clone)]
struct Tpdo {
    trigger: TpdoTrigger,
    mapping: PdoMapping,
    /// What the last transmission carried, for the change of state.
    last_data: Option<Vec<u8>>,
}

impl Tpdo {
    fn sample(&self, store: &ObjectStore) -> Vec<u8> {
        let values: Vec<u64> = self
            .mapping
            .entries()
            .iter()
            .map(|entry| {
                if entry.is_dummy() {
                    return 0;
                }
                store.get(entry.index, entry.sub).map_or(0, value_bits)
            })
            .collect();
        self.mapping
            .pack(&values)
            .expect("one value per entry of a validated mapping")
    }

    fn send(&mut self, store: &ObjectStore) -> Frame {
        let data = self.sample(store);
        let frame = Frame::new(self.trigger.params().cob_id.id, &data).expect("at most 8 bytes");
        self.last_data = Some(data);
        frame
    }

    /// Types whose transmission a change of the mapped values asks for.
    fn follows_changes(&self) -> bool {
        let params = self.trigger.params();
        params.cob_id.valid
            && (params.transmission_type.is_event_driven()
                || params.transmission_type == TransmissionType::SyncAcyclic)
    }
}

/// The PDOs and SYNC consumer of one device. See the module documentation.
#[derive(Debug, Clone)]
pub struct DevicePdos {
    tpdos: Vec<Tpdo>,
    rpdos: Vec<Rpdo>,
    sync: SyncConsumer,
    /// When mapped values are next compared for a change of state.
    next_scan: Option<Instant>,
    /// EMCY codes of RPDOs of the wrong length, for the device to raise.
    length_errors: Vec<u16>,
}

impl DevicePdos {
    /// The PDOs the store's parameters describe; a PDO whose parameters or
    /// mapping cannot be read is left out.
    pub fn new(store: &ObjectStore, now: Instant) -> Self {
        let dictionary = store.dictionary();
        let mut tpdos = Vec::new();
        let mut rpdos = Vec::new();
        for object in dictionary.objects.values() {
            let Some((kind, number)) = PdoKind::from_index(object.index) else {
                continue;
            };
            if kind.comm_index(number) != Some(object.index) {
                continue;
            }
            let Some(params) = comm_params(store, kind, object.index) else {
                continue;
            };
            let Some(mapping) = kind
                .mapping_index(number)
                .and_then(|index| mapping(store, kind, index))
            else {
                continue;
            };
            match kind {
                PdoKind::Tpdo => tpdos.push(Tpdo {
                    trigger: TpdoTrigger::new(params, now),
                    mapping,
                    last_data: None,
                }),
                PdoKind::Rpdo => rpdos.push(Rpdo::new(params, mapping)),
            }
        }
        let mut sync = match read_u32(store, COB_ID_SYNC, 0) {
            Some(raw) if raw & (1 << 29) != 0 => {
                SyncConsumer::with_cob_id(CanId::Extended(raw & 0x1FFF_FFFF))
            }
            Some(raw) => SyncConsumer::with_cob_id(CanId::Standard((raw & 0x7FF) as u16)),
            None => SyncConsumer::with_cob_id(CanId::Standard(SYNC_COB_ID)),
        };
        if let Some(overflow) = read_u32(store, SYNC_COUNTER_OVERFLOW, 0) {
            // A reserved value leaves the consumer expecting no counter.
            let _ = sync.set_counter_overflow(overflow as u8);
        }
        Self {
            tpdos,
            rpdos,
            sync,
            next_scan: Some(now),
            length_errors: Vec::new(),
        }
    }

    /// Rebuilds from the store after a write to a PDO parameter; a PDO whose
    /// parameters and mapping did not change keeps its state.
    pub fn rebuild(&mut self, store: &ObjectStore, now: Instant) {
        let mut new = Self::new(store, now);
        for tpdo in &mut new.tpdos {
            if let Some(old) = self.tpdos.iter().find(|old| {
                old.trigger.params() == tpdo.trigger.params() && old.mapping == tpdo.mapping
            }) {
                *tpdo = old.clone();
            }
        }
        for rpdo in &mut new.rpdos {
            if let Some(old) = self
                .rpdos
                .iter()
                .find(|old| old.params() == rpdo.params() && old.mapping() == rpdo.mapping())
            {
                *rpdo = old.clone();
            }
        }
        new.next_scan = self.next_scan.or(Some(now));
        *self = new;
    }

    /// Starts over on entering operational: triggers restart, buffered RPDO
    /// values are dropped, and event-driven TPDOs go out once.
    pub fn restart(&mut self, now: Instant) {
        for tpdo in &mut self.tpdos {
            tpdo.trigger.restart(now);
            tpdo.last_data = None;
        }
        for rpdo in &mut self.rpdos {
            rpdo.configure(*rpdo.params(), rpdo.mapping().clone());
        }
        self.next_scan = Some(now);
    }

    /// Takes a frame from the bus (SYNC, RPDO, remote request for a TPDO);
    /// writes received values into `store`, adding each object written to
    /// `written`, and returns the TPDOs to send.
    pub fn handle_frame(
        &mut self,
        frame: &Frame,
        store: &mut ObjectStore,
        now: Instant,
        written: &mut Vec<(u16, u8)>,
    ) -> Vec<Frame> {
        let mut out = Vec::new();
        match self.sync.on_frame(frame) {
            Ok(Some(sync)) => {
                for rpdo in &mut self.rpdos {
                    apply(store, &rpdo.on_sync(), written);
                }
                for tpdo in &mut self.tpdos {
                    if tpdo.trigger.on_sync(sync.counter, now) {
                        out.push(tpdo.send(store));
                    }
                }
                return out;
            }
            Ok(None) => {}
            // A malformed SYNC is not acted on.
            Err(_) => return out,
        }
        if frame.is_remote() {
            for tpdo in &mut self.tpdos {
                if tpdo.trigger.params().cob_id.id == frame.id() && tpdo.trigger.on_rtr(now) {
                    out.push(tpdo.send(store));
                }
            }
            return out;
        }
        for rpdo in &mut self.rpdos {
            // A frame too short for the mapping is not applied (0x8210); a
            // longer one is, and said to be (0x8220) where the device does.
            match rpdo.on_frame(frame, now) {
                Ok(Some(received)) => {
                    apply(store, &received.apply, written);
                    if received.length_exceeded {
                        self.length_errors.push(EMCY_PDO_LENGTH_EXCEEDED);
                    }
                }
                Ok(None) => {}
                Err(error) => self.length_errors.extend(error.emcy_code()),
            }
        }
        out
    }

    /// The EMCY codes of the RPDOs received with the wrong length since the
    /// last call (0x8210 too short, 0x8220 too long).
    pub fn take_length_errors(&mut self) -> Vec<u16> {
        std::mem::take(&mut self.length_errors)
    }

    /// Timers due at `now` (event timers, inhibit times, RPDO deadlines) and
    /// the change-of-state comparison; returns the TPDOs to send.
    pub fn poll(&mut self, store: &ObjectStore, now: Instant) -> Vec<Frame> {
        let mut out = Vec::new();
        for rpdo in &mut self.rpdos {
            let _ = rpdo.poll(now);
        }
        for tpdo in &mut self.tpdos {
            if tpdo.trigger.poll(now) {
                out.push(tpdo.send(store));
            }
        }
        if self.next_scan.is_some_and(|scan| scan <= now) {
            out.extend(self.scan_changes(store, now));
        }
        out
    }

    /// Asks for the transmission of every TPDO whose mapped values differ
    /// from what it last sent.
    fn scan_changes(&mut self, store: &ObjectStore, now: Instant) -> Vec<Frame> {
        let mut out = Vec::new();
        let mut watching = false;
        for tpdo in &mut self.tpdos {
            if !tpdo.follows_changes() {
                continue;
            }
            watching = true;
            if tpdo.last_data.as_deref() != Some(&tpdo.sample(store)[..])
                && tpdo.trigger.on_event(now)
            {
                out.push(tpdo.send(store));
            }
        }
        self.next_scan = watching.then(|| now + CHANGE_SCAN);
        out
    }

    /// When [`DevicePdos::poll`] has work next.
    pub fn deadline(&self) -> Option<Instant> {
        self.tpdos
            .iter()
            .filter_map(|tpdo| tpdo.trigger.deadline())
            .chain(self.rpdos.iter().filter_map(Rpdo::deadline))
            .chain(self.next_scan)
            .min()
    }
}

/// Writes received values into their objects, noting each in `written`; a
/// value the object cannot take is left out.
fn apply(store: &mut ObjectStore, values: &[MappedValue], written: &mut Vec<(u16, u8)>) {
    for mapped in values {
        let entry = mapped.entry;
        let Some(data_type) = store
            .dictionary()
            .sub(entry.index, entry.sub)
            .map(|sub| sub.data_type)
        else {
            continue;
        };
        let Some(len) = data_type.byte_len().filter(|len| *len <= 8) else {
            continue;
        };
        let bytes = mapped.value.to_le_bytes();
        if let Ok(value) = Value::from_bytes(data_type, &bytes[..len])
            && store.set(entry.index, entry.sub, value).is_ok()
        {
            written.push((entry.index, entry.sub));
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use super::*;
    use crate::can::{Bus, VirtualHub};
    use crate::canopen::NodeId;
    use crate::canopen::eds::Eds;
    use crate::canopen::nmt::{NmtCommand, NmtMessage, NmtState, NmtTarget};
    use crate::canopen::od::{AccessType, DataType, ObjectDictionary, SubObject};
    use crate::canopen::sdo::ClientConfig;
    use crate::gateway::sdo::SdoChannel;
    use crate::profiles::builtin::JMC_STEPPER;
    use crate::sim::device::{DeviceCore, run_device};

    const SYNC: CanId = CanId::Standard(0x080);
    const TPDO1: CanId = CanId::Standard(0x185);
    const TPDO2: CanId = CanId::Standard(0x285);
    const RPDO1: CanId = CanId::Standard(0x205);

    fn node() -> NodeId {
        NodeId::new(5).unwrap()
    }

    fn ms(ms: u64) -> Duration {
        Duration::from_millis(ms)
    }

    /// The JMC dictionary, with inhibit time and event timer on TPDO2.
    fn jmc() -> ObjectDictionary {
        let mut dictionary = Eds::parse(JMC_STEPPER, "jmc.eds").unwrap().dictionary;
        let tpdo2 = dictionary.get_mut(0x1801).unwrap();
        tpdo2.insert_sub(SubObject::new(
            3,
            "Inhibit time",
            DataType::Unsigned16,
            AccessType::Rw,
        ));
        tpdo2.insert_sub(SubObject::new(
            5,
            "Event timer",
            DataType::Unsigned16,
            AccessType::Rw,
        ));
        dictionary
    }

    fn sync() -> Frame {
        Frame::new(SYNC, &[]).unwrap()
    }

    fn nmt(command: NmtCommand) -> Frame {
        NmtMessage::new(command, NmtTarget::Node(node())).encode()
    }

    /// A booted device, and the clock it runs on.
    fn device() -> (DeviceCore, Instant) {
        let mut device = DeviceCore::new(jmc(), node()).unwrap();
        let start = Instant::now();
        device.boot(start);
        (device, start)
    }

    fn on(frames: &[Frame], id: CanId) -> Vec<Vec<u8>> {
        frames
            .iter()
            .filter(|frame| frame.id() == id)
            .map(|frame| frame.data().to_vec())
            .collect()
    }

    /// Runs the device's timers from `from` to `to` in 1 ms steps; the frames
    /// on `id` with the ms they went at.
    fn run(device: &mut DeviceCore, from: Instant, to: Instant, id: CanId) -> Vec<u128> {
        let mut sent = Vec::new();
        let mut now = from;
        while now <= to {
            if device.deadline().is_some_and(|deadline| deadline <= now) {
                for frame in device.poll(now) {
                    if frame.id() == id {
                        sent.push(now.duration_since(from).as_millis());
                    }
                }
            }
            now += ms(1);
        }
        sent
    }

    /// Configures TPDO2 as event-driven with `inhibit` (100 µs) and `timer`
    /// (ms), through the dictionary as a configuration tool would.
    fn event_driven(device: &mut DeviceCore, inhibit: u16, timer: u16, now: Instant) {
        let store = device.store_mut();
        store.set(0x1801, 2, Value::Unsigned8(255)).unwrap();
        store.set(0x1801, 3, Value::Unsigned16(inhibit)).unwrap();
        store.set(0x1801, 5, Value::Unsigned16(timer)).unwrap();
        device.pdo_parameters_changed(now);
    }

    #[test]
    fn tpdo1_goes_on_every_sync_once_operational_and_not_before() {
        let (mut device, now) = device();
        assert!(on(&device.handle_frame(&sync(), now), TPDO1).is_empty());
        device.handle_frame(&nmt(NmtCommand::Start), now);
        assert_eq!(device.nmt_state(), NmtState::Operational);
        device
            .store_mut()
            .set(0x6041, 0, Value::Unsigned16(0x0237))
            .unwrap();
        device
            .store_mut()
            .set(0x6064, 0, Value::Integer32(-2))
            .unwrap();
        for _ in 0..3 {
            let out = device.handle_frame(&sync(), now);
            assert_eq!(
                on(&out, TPDO1),
                vec![vec![0x37, 0x02, 0xFE, 0xFF, 0xFF, 0xFF]]
            );
        }
        device.handle_frame(&nmt(NmtCommand::Stop), now);
        assert!(on(&device.handle_frame(&sync(), now), TPDO1).is_empty());
    }

    #[test]
    fn an_event_timer_tpdo_repeats_at_its_period() {
        let (mut device, start) = device();
        event_driven(&mut device, 0, 100, start);
        device.handle_frame(&nmt(NmtCommand::Start), start);
        let sent = run(&mut device, start, start + ms(350), TPDO2);
        // Once on entering operational, then every 100 ms.
        assert_eq!(sent, vec![0, 100, 200, 300]);
    }

    #[test]
    fn a_change_of_state_sends_within_the_inhibit_time() {
        let (mut device, start) = device();
        // 50 ms inhibit time, no event timer.
        event_driven(&mut device, 500, 0, start);
        device.handle_frame(&nmt(NmtCommand::Start), start);
        assert_eq!(run(&mut device, start, start + ms(20), TPDO2), vec![0]);
        // Nothing changes, nothing goes.
        assert!(run(&mut device, start + ms(21), start + ms(200), TPDO2).is_empty());
        // TPDO2 maps 0x606C, velocity actual value (JMC default 0x1A01).
        let from = start + ms(201);
        device
            .store_mut()
            .set(0x606C, 0, Value::Integer32(1))
            .unwrap();
        // Changes are looked for every CHANGE_SCAN, the device's cycle.
        let sent = run(&mut device, from, from + CHANGE_SCAN, TPDO2);
        assert_eq!(sent.len(), 1, "{sent:?}");
        // A second change at once waits for the inhibit time.
        let sent_at = from + ms(sent[0] as u64);
        device
            .store_mut()
            .set(0x606C, 0, Value::Integer32(2))
            .unwrap();
        let again = run(&mut device, sent_at + ms(1), sent_at + ms(100), TPDO2);
        assert_eq!(again.len(), 1, "{again:?}");
        assert!(again[0] + 1 >= 50, "{again:?}");
    }

    #[test]
    fn an_rpdo_writes_its_objects_and_a_short_one_does_not() {
        let (mut device, now) = device();
        // Not before operational.
        let frame = Frame::new(RPDO1, &[0x10, 0, 0, 0, 0x20, 0, 0x30, 0]).unwrap();
        device.handle_frame(&frame, now);
        assert_eq!(device.store().get(0x6081, 0), Some(&Value::Integer32(0)));
        device.handle_frame(&nmt(NmtCommand::Start), now);
        device.handle_frame(&frame, now);
        // 0x1600: 0x6081 (32), 0x6083 (16), 0x6084 (16).
        assert_eq!(device.store().get(0x6081, 0), Some(&Value::Integer32(0x10)));
        assert_eq!(
            device.store().get(0x6083, 0),
            Some(&Value::Unsigned16(0x20))
        );
        let short = Frame::new(RPDO1, &[0x99, 0, 0, 0, 0x20]).unwrap();
        device.handle_frame(&short, now);
        assert_eq!(device.store().get(0x6081, 0), Some(&Value::Integer32(0x10)));
    }

    #[test]
    fn a_sync_rpdo_is_applied_at_the_next_sync() {
        let (mut device, now) = device();
        device
            .store_mut()
            .set(0x1400, 2, Value::Unsigned8(1))
            .unwrap();
        device.pdo_parameters_changed(now);
        device.handle_frame(&nmt(NmtCommand::Start), now);
        let frame = Frame::new(RPDO1, &[7, 0, 0, 0, 0, 0, 0, 0]).unwrap();
        device.handle_frame(&frame, now);
        assert_eq!(device.store().get(0x6081, 0), Some(&Value::Integer32(0)));
        device.handle_frame(&sync(), now);
        assert_eq!(device.store().get(0x6081, 0), Some(&Value::Integer32(7)));
    }

    #[test]
    fn a_remote_frame_asks_for_an_rtr_tpdo() {
        let (mut device, now) = device();
        device
            .store_mut()
            .set(0x1800, 2, Value::Unsigned8(253))
            .unwrap();
        device.pdo_parameters_changed(now);
        device.handle_frame(&nmt(NmtCommand::Start), now);
        assert!(on(&device.handle_frame(&sync(), now), TPDO1).is_empty());
        let rtr = Frame::remote(TPDO1, 6).unwrap();
        assert_eq!(on(&device.handle_frame(&rtr, now), TPDO1).len(), 1);
    }

    async fn send_nmt(master: &Bus, command: NmtCommand) {
        master.send(nmt(command)).await.unwrap();
        tokio::time::sleep(ms(1)).await;
    }

    #[tokio::test(start_paused = true)]
    async fn remapping_through_sdo_follows_cia_301() {
        let hub = VirtualHub::new("test");
        let master = hub.attach();
        let device = Arc::new(Mutex::new(DeviceCore::new(jmc(), node()).unwrap()));
        let task = tokio::spawn(run_device(hub.attach(), device.clone()));
        let config = ClientConfig {
            timeout: ms(200),
            ..ClientConfig::default()
        };
        let sdo = SdoChannel::new(master.clone(), node(), config);
        let abort = |code: u32| Some(AbortCode::from_raw(code));
        // While TPDO1 is valid, neither entries nor sub 0 may change.
        let refused = sdo.download(0x1A00, 1, &0x6064_0020u32.to_le_bytes()).await;
        assert_eq!(refused.unwrap_err().device_abort(), abort(0x0604_0043));
        let refused = sdo.download(0x1A00, 0, &[0]).await;
        assert_eq!(refused.unwrap_err().device_abort(), abort(0x0604_0043));
        // 1. Invalidate; 2. sub 0 = 0.
        sdo.download(0x1800, 1, &0x8000_0185u32.to_le_bytes())
            .await
            .unwrap();
        sdo.download(0x1A00, 0, &[0]).await.unwrap();
        // 3. Entries: not one that does not exist, nor one not mappable.
        let refused = sdo.download(0x1A00, 1, &0x3FFF_0010u32.to_le_bytes()).await;
        assert_eq!(refused.unwrap_err().device_abort(), abort(0x0602_0000));
        let refused = sdo.download(0x1A00, 1, &0x1017_0010u32.to_le_bytes()).await;
        assert_eq!(refused.unwrap_err().device_abort(), abort(0x0604_0041));
        sdo.download(0x1A00, 1, &0x6064_0020u32.to_le_bytes())
            .await
            .unwrap();
        sdo.download(0x1A00, 2, &0x6041_0010u32.to_le_bytes())
            .await
            .unwrap();
        sdo.download(0x1A00, 3, &0x6064_0020u32.to_le_bytes())
            .await
            .unwrap();
        // 4. Sub 0: three entries are 80 bits, too many; two are fine.
        let refused = sdo.download(0x1A00, 0, &[3]).await;
        assert_eq!(refused.unwrap_err().device_abort(), abort(0x0604_0042));
        sdo.download(0x1A00, 0, &[2]).await.unwrap();
        // With sub 0 set, entries are fixed again.
        let refused = sdo.download(0x1A00, 3, &0u32.to_le_bytes()).await;
        assert_eq!(refused.unwrap_err().device_abort(), abort(0x0604_0043));
        // 5. Validate.
        sdo.download(0x1800, 1, &0x0000_0185u32.to_le_bytes())
            .await
            .unwrap();
        {
            let mut device = device.lock().unwrap();
            let store = device.store_mut();
            store.set(0x6064, 0, Value::Integer32(0x0102_0304)).unwrap();
            store.set(0x6041, 0, Value::Unsigned16(0x0506)).unwrap();
        }
        let mut frames = master.subscribe();
        send_nmt(&master, NmtCommand::Start).await;
        master.send(sync()).await.unwrap();
        let tpdo = loop {
            let frame = frames.recv().await.unwrap().frame;
            if frame.id() == TPDO1 {
                break frame;
            }
        };
        assert_eq!(tpdo.data(), &[4, 3, 2, 1, 6, 5]);
        task.abort();
    }

    #[test]
    fn a_cob_id_is_not_made_valid_over_an_invalid_mapping() {
        let (mut device, _) = device();
        let store = device.store_mut();
        store
            .set(0x1800, 1, Value::Unsigned32(0x8000_0185))
            .unwrap();
        // 0x1017 is not mappable; as if the factory mapping were wrong.
        store
            .set(0x1A00, 1, Value::Unsigned32(0x1017_0010))
            .unwrap();
        assert_eq!(
            check_write(
                store,
                0x1800,
                1,
                Some(&0x185u32.to_le_bytes()),
                PdoRules::Cia301
            ),
            Err(AbortCode::ParameterIncompatible)
        );
        store.set(0x1A00, 0, Value::Unsigned8(9)).unwrap();
        assert_eq!(
            check_write(
                store,
                0x1800,
                1,
                Some(&0x185u32.to_le_bytes()),
                PdoRules::Cia301
            ),
            Err(AbortCode::ParameterIncompatible)
        );
    }
}
