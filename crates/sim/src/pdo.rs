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
    /// An RPDO was processed since [`DevicePdos::take_rpdo_processed`].
    rpdo_processed: bool,
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
            rpdo_processed: false,
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
                    self.rpdo_processed = true;
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

    /// Whether an RPDO was processed (applied) since the last call.
    pub fn take_rpdo_processed(&mut self) -> bool {
        std::mem::take(&mut self.rpdo_processed)
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
mod tests;
