//! The PDOs of a node, seen from the master (CiA 301 §7.2.2; parameters
//! §7.5.2.35–38): their configuration read over SDO, the re-mapping
//! procedure of §7.2.2.3, TPDO decoding and RPDO encoding by the mapping and
//! the node's EDS.
//!
//! Which PDOs a node has is its EDS's to say: PDO n exists when the EDS
//! describes both its communication (0x1400/0x1800 + n − 1) and mapping
//! (0x1600/0x1A00 + n − 1) parameters; a mapping holds at most as many
//! entries as the EDS gives its mapping record sub-objects. A node without
//! EDS is assumed to have the predefined connection set's four of each.
//!
//! A request is checked against the EDS in [`plan`] without I/O (every
//! object exists, may be mapped in that direction, fits its bits, at most 64
//! bits in all; a transmission type the PDO may have); [`configure`] then
//! runs the procedure and names the step that failed, if one does.
//! [`TpdoDecoder`] and [`RpdoEncoder`] are sans-I/O: a frame's bytes in,
//! named, typed values out, and back.

use serde_json::Value as Json;

use crate::can::{CanId, Frame};
use crate::canopen::NodeId;
use crate::canopen::eds::Eds;
use crate::canopen::od::{DataType, ObjectDictionary, SubObject, Value, names_match, parse_index};
use crate::canopen::pdo::comm::is_restricted;
use crate::canopen::pdo::{
    MappingEntry, MappingError, PdoCobId, PdoDataError, PdoKind, PdoMapping, TransmissionType,
    sign_extend,
};
use crate::canopen::sdo::{AbortCode, SdoError};
use crate::canopen::sync::COUNTER_MAX;
use crate::sdo::{SdoChannel, SdoRequestError};

/// The PDOs a node without EDS is assumed to have (CiA 301 predefined
/// connection set).
const DEFAULT_PDO_COUNT: u16 = 4;
/// The entries a mapping record has when the EDS does not say.
const DEFAULT_MAX_ENTRIES: u8 = 8;
/// COB-ID bit 31: the PDO is not valid.
const INVALID_BIT: u32 = 1 << 31;

/// Communication parameter sub-indexes (§7.5.2.35, §7.5.2.37).
mod comm_sub {
    pub(super) const COB_ID: u8 = 1;
    pub(super) const TRANSMISSION_TYPE: u8 = 2;
    pub(super) const INHIBIT_TIME: u8 = 3;
    pub(super) const EVENT_TIMER: u8 = 5;
    pub(super) const SYNC_START: u8 = 6;
}

/// One PDO's configuration as read from the node. The optional parameters
/// are `None` where the node's EDS does not describe them (the JMC's PDOs
/// have only a COB-ID and a transmission type).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PdoConfig {
    pub kind: PdoKind,
    pub number: u16,
    /// COB-ID sub-index 1 as read, flags included.
    pub cob_id_raw: u32,
    pub transmission_type: Option<u8>,
    pub inhibit_time_100us: Option<u16>,
    pub event_timer_ms: Option<u16>,
    pub sync_start: Option<u8>,
    /// Entries 1 to sub 0 of the mapping record.
    pub mapping: Vec<MappingEntry>,
}

impl PdoConfig {
    /// The COB-ID's identifier (bits 0–28).
    pub fn can_id(&self) -> u32 {
        self.cob_id_raw & 0x1FFF_FFFF
    }

    /// Valid: COB-ID bit 31 clear.
    pub fn enabled(&self) -> bool {
        self.cob_id_raw & INVALID_BIT == 0
    }

    /// The COB-ID, if it reads as one.
    pub fn cob_id(&self) -> Option<PdoCobId> {
        PdoCobId::from_raw(self.cob_id_raw).ok()
    }

    /// The decoder of this PDO's frames (a TPDO's, or an RPDO's as another
    /// master sends it), or why its mapping is no valid mapping.
    pub fn decoder(&self, dict: Option<&ObjectDictionary>) -> Result<TpdoDecoder, MappingError> {
        let cob_id = self.cob_id().map_or(CanId::Standard(0), |cob_id| cob_id.id);
        Ok(TpdoDecoder::new(
            cob_id,
            PdoMapping::new(self.mapping.clone())?,
            dict,
        ))
    }
}

/// The PDO numbers of `kind` the node has: from the EDS, 1–4 without one.
pub(crate) fn pdo_numbers(dict: Option<&ObjectDictionary>, kind: PdoKind) -> Vec<u16> {
    let Some(dict) = dict else {
        return (1..=DEFAULT_PDO_COUNT).collect();
    };
    (1..=PdoKind::MAX_NUMBER)
        .filter(|&n| {
            let (Some(comm), Some(mapping)) = (kind.comm_index(n), kind.mapping_index(n)) else {
                return false;
            };
            dict.get(comm).is_some() && dict.get(mapping).is_some()
        })
        .collect()
}

/// Whether the node has PDO `number` of `kind`.
pub(crate) fn has_pdo(dict: Option<&ObjectDictionary>, kind: PdoKind, number: u16) -> bool {
    pdo_numbers(dict, kind).contains(&number)
}

/// The most entries PDO `number`'s mapping record takes.
fn max_entries(dict: Option<&ObjectDictionary>, kind: PdoKind, number: u16) -> u8 {
    kind.mapping_index(number)
        .and_then(|index| dict?.get(index))
        .and_then(|object| object.subs.keys().copied().max())
        .unwrap_or(DEFAULT_MAX_ENTRIES)
}

/// Whether the EDS describes communication sub-index `sub` (always assumed
/// without EDS; a device that lacks it then aborts, and the read gives
/// `None`).
fn has_comm_sub(dict: Option<&ObjectDictionary>, kind: PdoKind, number: u16, sub: u8) -> bool {
    match (dict, kind.comm_index(number)) {
        (Some(dict), Some(index)) => dict.sub(index, sub).is_some(),
        (None, _) => sub != comm_sub::SYNC_START || kind == PdoKind::Tpdo,
        _ => false,
    }
}

/// The type a parameter sub-index is written with: the EDS's, else CiA
/// 301's.
fn param_type(dict: Option<&ObjectDictionary>, index: u16, sub: u8, cia: DataType) -> DataType {
    dict.and_then(|dict| dict.sub(index, sub))
        .map_or(cia, |sub| sub.data_type)
}

fn le_u32(data: &[u8]) -> u32 {
    let mut raw = [0u8; 4];
    let n = data.len().min(4);
    raw[..n].copy_from_slice(&data[..n]);
    u32::from_le_bytes(raw)
}

/// Reads a parameter as an unsigned integer; `None` for a sub-index the
/// device says does not exist.
async fn read_optional(
    channel: &SdoChannel,
    index: u16,
    sub: u8,
) -> Result<Option<u32>, SdoRequestError> {
    match channel.upload(index, sub).await {
        Ok(data) => Ok(Some(le_u32(&data))),
        Err(err)
            if matches!(
                err.device_abort(),
                Some(AbortCode::SubIndexDoesNotExist | AbortCode::ObjectDoesNotExist)
            ) =>
        {
            Ok(None)
        }
        Err(err) => Err(err),
    }
}

/// Reads PDO `number`'s communication and mapping parameters.
pub(crate) async fn read_config(
    channel: &SdoChannel,
    dict: Option<&ObjectDictionary>,
    kind: PdoKind,
    number: u16,
) -> Result<PdoConfig, SdoRequestError> {
    let (Some(comm), Some(map)) = (kind.comm_index(number), kind.mapping_index(number)) else {
        return Err(SdoRequestError::Sdo {
            node: channel.node(),
            error: SdoError::ServerAborted(AbortCode::ObjectDoesNotExist),
        });
    };
    let cob_id_raw = le_u32(&channel.upload(comm, comm_sub::COB_ID).await?);
    let optional = async |sub: u8| -> Result<Option<u32>, SdoRequestError> {
        if has_comm_sub(dict, kind, number, sub) {
            read_optional(channel, comm, sub).await
        } else {
            Ok(None)
        }
    };
    let transmission_type = optional(comm_sub::TRANSMISSION_TYPE).await?;
    let inhibit_time = optional(comm_sub::INHIBIT_TIME).await?;
    let event_timer = optional(comm_sub::EVENT_TIMER).await?;
    let sync_start = if kind == PdoKind::Tpdo {
        optional(comm_sub::SYNC_START).await?
    } else {
        None
    };
    let count = le_u32(&channel.upload(map, 0).await?).min(0x40) as u8;
    let mut mapping = Vec::with_capacity(usize::from(count));
    for sub in 1..=count {
        mapping.push(MappingEntry::from_raw(le_u32(
            &channel.upload(map, sub).await?,
        )));
    }
    Ok(PdoConfig {
        kind,
        number,
        cob_id_raw,
        transmission_type: transmission_type.map(|v| v as u8),
        inhibit_time_100us: inhibit_time.map(|v| v as u16),
        event_timer_ms: event_timer.map(|v| v as u16),
        sync_start: sync_start.map(|v| v as u8),
        mapping,
    })
}

/// Reads every PDO of `kind` the node has (see [`pdo_numbers`]). Without
/// EDS, a PDO whose parameters the device does not have is left out.
pub(crate) async fn read_all(
    channel: &SdoChannel,
    dict: Option<&ObjectDictionary>,
    kind: PdoKind,
) -> Result<Vec<PdoConfig>, SdoRequestError> {
    let mut configs = Vec::new();
    for number in pdo_numbers(dict, kind) {
        match read_config(channel, dict, kind, number).await {
            Ok(config) => configs.push(config),
            Err(err)
                if dict.is_none()
                    && matches!(
                        err.device_abort(),
                        Some(AbortCode::ObjectDoesNotExist | AbortCode::SubIndexDoesNotExist)
                    ) => {}
            Err(err) => return Err(err),
        }
    }
    Ok(configs)
}

/// A decoder for each valid TPDO of the node, from its configuration read
/// over SDO and its EDS: what telemetry needs to turn the node's frames into
/// named values. TPDOs whose mapping is no valid mapping are left out.
pub async fn tpdo_decoders(
    channel: &SdoChannel,
    dict: Option<&ObjectDictionary>,
) -> Result<Vec<TpdoDecoder>, SdoRequestError> {
    Ok(read_all(channel, dict, PdoKind::Tpdo)
        .await?
        .iter()
        .filter(|config| config.enabled() && !config.mapping.is_empty())
        .filter_map(|config| config.decoder(dict).ok())
        .collect())
}

/// Why a PDO request cannot be carried out; found before the bus is touched.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum PdoPlanError {
    #[error("the node has no {} {number}{}", .kind.name().to_uppercase(), list_numbers(.available))]
    UnknownPdo {
        kind: PdoKind,
        number: u16,
        available: Vec<u16>,
    },
    /// An entry that names nothing the EDS describes.
    #[error("mapping entry {position}: {detail}")]
    UnknownEntry { position: usize, detail: String },
    #[error("mapping entry {position}: {name} ({entry}) {why}")]
    NotMappable {
        position: usize,
        name: String,
        entry: MappingEntry,
        why: &'static str,
    },
    #[error("mapping entry {position}: {name} is {type_bits} bits wide, not {bits}")]
    Bits {
        position: usize,
        name: String,
        bits: u32,
        type_bits: String,
    },
    #[error(
        "mapping entry {position}: {bits} bits, the device maps in units of {granularity} (EDS Granularity)"
    )]
    Granularity {
        position: usize,
        bits: u8,
        granularity: u8,
    },
    #[error("{0}")]
    Mapping(#[from] MappingError),
    #[error("{count} mapping entries, this PDO takes at most {max}")]
    TooManyEntries { count: usize, max: u8 },
    #[error("transmission type {0} is {1}")]
    TransmissionType(u8, &'static str),
    #[error("COB-ID 0x{raw:X}: {why}")]
    CobId { raw: u32, why: String },
    #[error("this PDO of the node has no {0} (its EDS does not describe it)")]
    NoSuchParameter(&'static str),
    #[error("{0}")]
    Value(String),
}

fn list_numbers(numbers: &[u16]) -> String {
    if numbers.is_empty() {
        " (it has none)".to_string()
    } else {
        format!(
            " (it has {})",
            numbers
                .iter()
                .map(u16::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        )
    }
}

impl PdoPlanError {
    /// A PDO number the node does not have (404), rather than a request
    /// that is wrong in itself (400).
    pub(crate) fn is_unknown_pdo(&self) -> bool {
        matches!(self, Self::UnknownPdo { .. })
    }

    /// A value outside its range, rather than a malformed request.
    pub(crate) fn is_out_of_range(&self) -> bool {
        matches!(self, Self::TransmissionType(..) | Self::Value(_))
    }
}

/// A mapping entry as a request names it: an index (`0x6041`, `6041h`, a
/// number, an EDS name), a sub (number or name; 0 when absent) and a length
/// (the data type's when absent).
#[derive(Debug, Clone, PartialEq)]
pub struct EntryRequest {
    pub index: Json,
    pub sub: Option<Json>,
    pub bits: Option<u32>,
}

/// The name a mapped object goes by: the object's for a VAR, `Object/Sub`
/// for a sub-object of a record or array (as the OD endpoints name them).
pub fn entry_name(dict: &ObjectDictionary, index: u16, sub: u8) -> Option<String> {
    let object = dict.get(index)?;
    let described = object.sub(sub)?;
    Some(if object.object_type.has_sub_objects() {
        format!("{}/{}", object.name, described.name)
    } else {
        object.name.clone()
    })
}

/// Resolves and checks one requested entry (its position counts from 1)
/// for a PDO of `kind`.
fn resolve_entry(
    eds: &Eds,
    kind: PdoKind,
    position: usize,
    request: &EntryRequest,
) -> Result<MappingEntry, PdoPlanError> {
    let entry = resolve_object(eds, kind, position, request)?;
    // CiA 306 Granularity: the unit the device maps in (8: whole bytes).
    let granularity = eds.device_info.granularity.unwrap_or(0);
    if granularity > 1 && entry.bits % granularity != 0 {
        return Err(PdoPlanError::Granularity {
            position,
            bits: entry.bits,
            granularity,
        });
    }
    Ok(entry)
}

fn resolve_object(
    eds: &Eds,
    kind: PdoKind,
    position: usize,
    request: &EntryRequest,
) -> Result<MappingEntry, PdoPlanError> {
    let dict = &eds.dictionary;
    let unknown = |detail: String| PdoPlanError::UnknownEntry { position, detail };
    let sub_json = request.sub.clone().unwrap_or(Json::from(0));
    // A dummy entry (a data type, 0x0001–0x0007) is a gap of that type's
    // width; the EDS need not list the type.
    let numeric = match &request.index {
        Json::String(text) => parse_index(text),
        Json::Number(n) => n.as_u64().and_then(|n| u16::try_from(n).ok()),
        _ => None,
    };
    if let Some(index @ 0x0001..=0x0007) = numeric {
        let type_bits = DataType::from_raw(index).bits().unwrap_or(1);
        let bits = request.bits.unwrap_or(type_bits);
        if bits == 0 || bits > type_bits {
            return Err(PdoPlanError::Bits {
                position,
                name: format!("dummy of type 0x{index:04X}"),
                bits,
                type_bits: type_bits.to_string(),
            });
        }
        if sub_json != 0 && sub_json != "0" {
            return Err(unknown(format!("a dummy entry ({index}) has sub 0")));
        }
        // CiA 306 [DummyUsage]: the types the device takes as dummies.
        if !eds.dummy_usage.is_empty() && !eds.dummy_usage.contains(&index) {
            return Err(PdoPlanError::NotMappable {
                position,
                name: format!("dummy of type 0x{index:04X}"),
                entry: MappingEntry::new(index, 0, bits as u8),
                why: "is a dummy type the device does not take (EDS [DummyUsage])",
            });
        }
        return Ok(MappingEntry::new(index, 0, bits as u8));
    }
    let (object, sub) = dict
        .resolve_json(&request.index, &sub_json)
        .map_err(|err| unknown(format!("{err} (the node's EDS does not describe it)")))?;
    let name = entry_name(dict, object.index, sub.sub_index).unwrap_or_default();
    let entry = |bits: u32| MappingEntry::new(object.index, sub.sub_index, bits as u8);
    let why = not_mappable(sub, kind);
    let type_bits = sub.data_type.bits();
    let bits = request.bits.or(type_bits).unwrap_or(0);
    if let Some(why) = why {
        return Err(PdoPlanError::NotMappable {
            position,
            name,
            entry: entry(bits.min(255)),
            why,
        });
    }
    let fits = type_bits.is_some_and(|type_bits| bits <= type_bits);
    if bits == 0 || bits > 64 || !fits {
        return Err(PdoPlanError::Bits {
            position,
            name,
            bits,
            type_bits: type_bits.map_or("of variable size".to_string(), |b| b.to_string()),
        });
    }
    Ok(entry(bits))
}

/// Why the EDS forbids mapping `sub` into a PDO of `kind`.
fn not_mappable(sub: &SubObject, kind: PdoKind) -> Option<&'static str> {
    if !sub.pdo_mappable {
        return Some("is not PDO-mappable (EDS PDOMapping=0)");
    }
    match kind {
        PdoKind::Tpdo if !sub.access.is_readable() => Some("cannot be read, so no TPDO sends it"),
        PdoKind::Rpdo if !sub.access.is_writable() => Some("cannot be written, so no RPDO sets it"),
        _ => None,
    }
}

/// What a request asks of one PDO; `None` keeps the node's value.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PdoRequest {
    /// The identifier (11 or 29 bits; bit 29 set for 29 bits, as in the
    /// COB-ID entry). Flags other than bit 29 are refused.
    pub cob_id: Option<u32>,
    /// Valid after the procedure; `true` when absent.
    pub enabled: Option<bool>,
    pub transmission_type: Option<u8>,
    pub inhibit_time_100us: Option<u16>,
    pub event_timer_ms: Option<u16>,
    pub sync_start: Option<u8>,
    /// `None` keeps the mapping.
    pub mapping: Option<Vec<EntryRequest>>,
}

/// A checked request: the SDO writes [`configure`] makes, in order.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct RemapPlan {
    pub kind: PdoKind,
    pub number: u16,
    comm_index: u16,
    mapping_index: u16,
    mapping: Option<PdoMapping>,
    /// The new identifier part of the COB-ID (bits 0–29); `None` keeps it.
    cob_id: Option<u32>,
    enabled: bool,
    /// Communication sub-indexes 2, 3, 5, 6 with their typed values.
    comm_writes: Vec<(u8, Value)>,
    /// The types of COB-ID, mapping count and mapping entries.
    cob_id_type: DataType,
    count_type: DataType,
    entry_type: DataType,
}

/// Checks `request` for PDO `number` of `kind` against the node's EDS.
pub(crate) fn plan(
    eds: &Eds,
    kind: PdoKind,
    number: u16,
    request: &PdoRequest,
) -> Result<RemapPlan, PdoPlanError> {
    let dict = &eds.dictionary;
    let dict_opt = Some(dict);
    let (Some(comm_index), Some(mapping_index)) =
        (kind.comm_index(number), kind.mapping_index(number))
    else {
        return Err(PdoPlanError::UnknownPdo {
            kind,
            number,
            available: pdo_numbers(dict_opt, kind),
        });
    };
    if !has_pdo(dict_opt, kind, number) {
        return Err(PdoPlanError::UnknownPdo {
            kind,
            number,
            available: pdo_numbers(dict_opt, kind),
        });
    }
    let mapping = match &request.mapping {
        None => None,
        Some(entries) => {
            let max = max_entries(dict_opt, kind, number);
            if entries.len() > usize::from(max) {
                return Err(PdoPlanError::TooManyEntries {
                    count: entries.len(),
                    max,
                });
            }
            let entries = entries
                .iter()
                .enumerate()
                .map(|(i, entry)| resolve_entry(eds, kind, i + 1, entry))
                .collect::<Result<Vec<_>, _>>()?;
            Some(PdoMapping::new(entries)?)
        }
    };
    if let Some(raw) = request.cob_id {
        check_cob_id(raw)?;
    }
    let mut comm_writes = Vec::new();
    let mut comm = |sub: u8, what: &'static str, value: Option<u32>| {
        let Some(value) = value else {
            return Ok(());
        };
        if !has_comm_sub(dict_opt, kind, number, sub) {
            return Err(PdoPlanError::NoSuchParameter(what));
        }
        let data_type = param_type(dict_opt, comm_index, sub, DataType::Unsigned8);
        let typed = Value::from_i128(data_type, i128::from(value))
            .map_err(|err| PdoPlanError::Value(format!("{what}: {err}")))?;
        comm_writes.push((sub, typed));
        Ok(())
    };
    if let Some(raw) = request.transmission_type {
        let transmission_type = TransmissionType::from_raw(raw);
        if let TransmissionType::Reserved(_) = transmission_type {
            return Err(PdoPlanError::TransmissionType(raw, "reserved (241–251)"));
        }
        if !transmission_type.allowed_for(kind) {
            return Err(PdoPlanError::TransmissionType(
                raw,
                "for TPDOs only (RTR-only)",
            ));
        }
    }
    comm(
        comm_sub::TRANSMISSION_TYPE,
        "transmission type",
        request.transmission_type.map(u32::from),
    )?;
    comm(
        comm_sub::INHIBIT_TIME,
        "inhibit time",
        request.inhibit_time_100us.map(u32::from),
    )?;
    comm(
        comm_sub::EVENT_TIMER,
        "event timer",
        request.event_timer_ms.map(u32::from),
    )?;
    if let Some(start) = request.sync_start {
        if kind == PdoKind::Rpdo {
            return Err(PdoPlanError::NoSuchParameter("SYNC start value"));
        }
        if start > COUNTER_MAX {
            return Err(PdoPlanError::Value(format!(
                "SYNC start value {start} is above 240"
            )));
        }
    }
    comm(
        comm_sub::SYNC_START,
        "SYNC start value",
        request.sync_start.map(u32::from),
    )?;
    Ok(RemapPlan {
        kind,
        number,
        comm_index,
        mapping_index,
        mapping,
        cob_id: request.cob_id,
        enabled: request.enabled.unwrap_or(true),
        comm_writes,
        cob_id_type: param_type(dict_opt, comm_index, comm_sub::COB_ID, DataType::Unsigned32),
        count_type: param_type(dict_opt, mapping_index, 0, DataType::Unsigned8),
        entry_type: param_type(dict_opt, mapping_index, 1, DataType::Unsigned32),
    })
}

/// A COB-ID a request may set: an identifier, bit 29 for 29 bits, no other
/// flag, and none of CiA 301's restricted identifiers.
fn check_cob_id(raw: u32) -> Result<(), PdoPlanError> {
    let refuse = |why: &str| PdoPlanError::CobId {
        raw,
        why: why.to_string(),
    };
    if raw & !0x3FFF_FFFF != 0 {
        return Err(refuse(
            "give the identifier only (use \"enabled\" for bit 31)",
        ));
    }
    match PdoCobId::from_raw(raw) {
        Err(err) => Err(refuse(&err.to_string())),
        Ok(PdoCobId {
            id: CanId::Standard(id),
            ..
        }) if is_restricted(id) => Err(refuse(
            "the identifier is reserved for other services (CiA 301 table 73)",
        )),
        Ok(_) => Ok(()),
    }
}

/// A step of the re-mapping procedure (CiA 301 §7.2.2.3), as the API names
/// the one that failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum RemapStep {
    /// Reading the current COB-ID.
    ReadCobId,
    /// Setting COB-ID bit 31: the PDO is not valid from here on.
    Invalidate,
    /// Mapping sub 0 = 0.
    ClearMappingCount,
    /// Mapping sub n = the entry.
    WriteMappingEntry(u8),
    /// Mapping sub 0 = the number of entries.
    SetMappingCount,
    /// A communication parameter (sub-index).
    WriteCommParameter(u8),
    /// The COB-ID with bit 31 cleared (or set, for a disabled PDO).
    Validate,
    ReadBack,
}

impl std::fmt::Display for RemapStep {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::ReadCobId => f.write_str("read_cob_id"),
            Self::Invalidate => f.write_str("invalidate"),
            Self::ClearMappingCount => f.write_str("clear_mapping_count"),
            Self::WriteMappingEntry(sub) => write!(f, "write_mapping_entry_{sub}"),
            Self::SetMappingCount => f.write_str("set_mapping_count"),
            Self::WriteCommParameter(sub) => write!(f, "write_comm_parameter_{sub}"),
            Self::Validate => f.write_str("validate"),
            Self::ReadBack => f.write_str("read_back"),
        }
    }
}

/// A procedure that stopped half way: at which step, and why.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("step {step}: {error}")]
pub(crate) struct RemapError {
    pub step: RemapStep,
    pub error: SdoRequestError,
}

/// Runs `plan` on the node: invalidate (COB-ID bit 31), clear the mapping
/// count, write the entries, set the count, write the communication
/// parameters, validate; then reads the configuration back. The PDO stays
/// invalid when a step after the first fails (the error names the step).
pub(crate) async fn configure(
    channel: &SdoChannel,
    dict: Option<&ObjectDictionary>,
    plan: &RemapPlan,
) -> Result<PdoConfig, RemapError> {
    let at = |step: RemapStep| move |error: SdoRequestError| RemapError { step, error };
    let (comm, map) = (plan.comm_index, plan.mapping_index);
    let current = le_u32(
        &channel
            .upload(comm, comm_sub::COB_ID)
            .await
            .map_err(at(RemapStep::ReadCobId))?,
    );
    let write = async |index: u16, sub: u8, data_type: DataType, value: u32| {
        // Within the type: the plan checked every value against it.
        let bytes = Value::from_i128(data_type, i128::from(value))
            .map(|value| value.to_bytes())
            .unwrap_or_else(|_| value.to_le_bytes().to_vec());
        channel.download(index, sub, &bytes).await
    };
    write(
        comm,
        comm_sub::COB_ID,
        plan.cob_id_type,
        current | INVALID_BIT,
    )
    .await
    .map_err(at(RemapStep::Invalidate))?;
    if let Some(mapping) = &plan.mapping {
        write(map, 0, plan.count_type, 0)
            .await
            .map_err(at(RemapStep::ClearMappingCount))?;
        for (sub, raw) in (1u8..).zip(mapping.raw()) {
            write(map, sub, plan.entry_type, raw)
                .await
                .map_err(at(RemapStep::WriteMappingEntry(sub)))?;
        }
        write(map, 0, plan.count_type, mapping.len() as u32)
            .await
            .map_err(at(RemapStep::SetMappingCount))?;
    }
    for (sub, value) in &plan.comm_writes {
        channel
            .download(comm, *sub, &value.to_bytes())
            .await
            .map_err(at(RemapStep::WriteCommParameter(*sub)))?;
    }
    let id = plan.cob_id.unwrap_or(current & 0x3FFF_FFFF) | (current & (1 << 30));
    let final_raw = if plan.enabled { id } else { id | INVALID_BIT };
    write(comm, comm_sub::COB_ID, plan.cob_id_type, final_raw)
        .await
        .map_err(at(RemapStep::Validate))?;
    read_config(channel, dict, plan.kind, plan.number)
        .await
        .map_err(at(RemapStep::ReadBack))
}

/// One mapped value of a PDO frame.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedValue {
    pub entry: MappingEntry,
    /// The EDS name (see [`entry_name`]); `None` for a dummy entry or an
    /// object the EDS does not describe.
    pub name: Option<String>,
    /// The value typed by the EDS; `None` without a type.
    pub value: Option<Value>,
    /// The field's bits, zero-extended.
    pub raw: u64,
}

#[derive(Debug, Clone, PartialEq)]
struct Field {
    entry: MappingEntry,
    name: Option<String>,
    data_type: Option<DataType>,
}

fn fields(mapping: &PdoMapping, dict: Option<&ObjectDictionary>) -> Vec<Field> {
    mapping
        .entries()
        .iter()
        .map(|&entry| {
            let described = (!entry.is_dummy())
                .then(|| dict?.sub(entry.index, entry.sub))
                .flatten();
            Field {
                entry,
                name: (!entry.is_dummy())
                    .then(|| entry_name(dict?, entry.index, entry.sub))
                    .flatten(),
                data_type: described.map(|sub| sub.data_type),
            }
        })
        .collect()
}

/// A field's bits as a value of `data_type`. A field narrower than its type
/// (a 16-bit mapping of an INTEGER32) is sign-extended for signed types.
fn typed(data_type: DataType, bits: u32, raw: u64) -> Option<Value> {
    let len = data_type
        .byte_len()
        .unwrap_or_else(|| bits.div_ceil(8) as usize);
    let widened = if data_type.is_signed() {
        sign_extend(raw, bits) as u64
    } else {
        raw
    };
    let bytes = widened.to_le_bytes();
    Value::from_bytes(data_type, bytes.get(..len)?).ok()
}

/// Decodes the frames of one TPDO into named values, by its mapping and
/// the node's EDS. Sans-I/O: the telemetry feeds it frames.
#[derive(Debug, Clone, PartialEq)]
pub struct TpdoDecoder {
    cob_id: CanId,
    mapping: PdoMapping,
    fields: Vec<Field>,
}

impl TpdoDecoder {
    pub fn new(cob_id: CanId, mapping: PdoMapping, dict: Option<&ObjectDictionary>) -> Self {
        Self {
            cob_id,
            fields: fields(&mapping, dict),
            mapping,
        }
    }

    pub fn cob_id(&self) -> CanId {
        self.cob_id
    }

    pub fn mapping(&self) -> &PdoMapping {
        &self.mapping
    }

    /// Every mapped value of a PDO's data, dummies left out. Bytes beyond
    /// the mapping are ignored; fewer than it needs are an error (a device
    /// would signal EMCY 0x8210).
    pub fn decode(&self, data: &[u8]) -> Result<Vec<DecodedValue>, PdoDataError> {
        let values = self.mapping.unpack(data)?;
        Ok(values
            .into_iter()
            .zip(&self.fields)
            .filter(|(mapped, _)| !mapped.entry.is_dummy())
            .map(|(mapped, field)| DecodedValue {
                entry: mapped.entry,
                name: field.name.clone(),
                value: field
                    .data_type
                    .and_then(|t| typed(t, u32::from(mapped.entry.bits), mapped.value)),
                raw: mapped.value,
            })
            .collect())
    }

    /// [`Self::decode`] for a frame on this TPDO's COB-ID; `None` for any
    /// other frame (and remote requests).
    pub fn decode_frame(&self, frame: &Frame) -> Option<Result<Vec<DecodedValue>, PdoDataError>> {
        (frame.id() == self.cob_id && !frame.is_remote()).then(|| self.decode(frame.data()))
    }
}

/// Why values cannot be sent in an RPDO.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum RpdoValueError {
    #[error("no value for {0}: every object the RPDO maps must be given")]
    Missing(String),
    #[error("{0} is not mapped in this RPDO (it maps {1})")]
    NotMapped(String, String),
    #[error("{name}: {detail}")]
    Invalid { name: String, detail: String },
    #[error("{name}: {detail}")]
    OutOfRange { name: String, detail: String },
    #[error("the RPDO maps {0}, which the node's EDS does not describe: its type is unknown")]
    Untyped(MappingEntry),
}

/// Encodes an RPDO's frame from named values, by its mapping and the
/// node's EDS. Sans-I/O.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct RpdoEncoder {
    cob_id: CanId,
    mapping: PdoMapping,
    fields: Vec<Field>,
    node: Option<NodeId>,
}

/// Whether a request's key names this field: its EDS name (see
/// [`names_match`]), `0x6040` for sub 0, or `0x6040:1` / `0x6040sub1`.
fn key_names(key: &str, field: &Field) -> bool {
    if field.name.as_deref().is_some_and(|name| {
        names_match(key, name)
            || name
                .split('/')
                .next()
                .is_some_and(|object| field.entry.sub == 0 && names_match(key, object))
    }) {
        return true;
    }
    let key = key.trim();
    let (index, sub) = match key
        .split_once(':')
        .or_else(|| key.split_once("sub"))
        .or_else(|| key.split_once("SUB"))
    {
        Some((index, sub)) => (index, sub.trim().parse::<u8>().ok()),
        None => (key, Some(0)),
    };
    parse_index(index) == Some(field.entry.index) && sub == Some(field.entry.sub)
}

impl RpdoEncoder {
    pub(crate) fn new(
        cob_id: CanId,
        mapping: PdoMapping,
        dict: Option<&ObjectDictionary>,
        node: Option<NodeId>,
    ) -> Self {
        Self {
            cob_id,
            fields: fields(&mapping, dict),
            mapping,
            node,
        }
    }

    fn mapped_names(&self) -> String {
        self.fields
            .iter()
            .filter(|f| !f.entry.is_dummy())
            .map(|f| f.name.clone().unwrap_or_else(|| f.entry.to_string()))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The frame carrying `values` (keyed as `key_names` says), each
    /// checked against its EDS type and limits; dummy entries are 0.
    pub(crate) fn encode(
        &self,
        values: &serde_json::Map<String, Json>,
        dict: Option<&ObjectDictionary>,
    ) -> Result<(Frame, Vec<DecodedValue>), RpdoValueError> {
        for key in values.keys() {
            if !self.fields.iter().any(|field| key_names(key, field)) {
                return Err(RpdoValueError::NotMapped(key.clone(), self.mapped_names()));
            }
        }
        let mut raws = Vec::with_capacity(self.fields.len());
        let mut decoded = Vec::new();
        for field in &self.fields {
            if field.entry.is_dummy() {
                raws.push(0);
                continue;
            }
            let name = field
                .name
                .clone()
                .unwrap_or_else(|| field.entry.to_string());
            let described = dict
                .and_then(|dict| dict.sub(field.entry.index, field.entry.sub))
                .ok_or(RpdoValueError::Untyped(field.entry))?;
            let json = values
                .iter()
                .find(|(key, _)| key_names(key, field))
                .map(|(_, json)| json)
                .ok_or_else(|| RpdoValueError::Missing(name.clone()))?;
            let value = described.value_from_json(json, self.node).map_err(|err| {
                let detail = err.to_string();
                if err.is_out_of_range() {
                    RpdoValueError::OutOfRange {
                        name: name.clone(),
                        detail,
                    }
                } else {
                    RpdoValueError::Invalid {
                        name: name.clone(),
                        detail,
                    }
                }
            })?;
            let mut bytes = [0u8; 8];
            let wire = value.to_bytes();
            let n = wire.len().min(8);
            bytes[..n].copy_from_slice(&wire[..n]);
            let raw = u64::from_le_bytes(bytes);
            raws.push(raw);
            decoded.push(DecodedValue {
                entry: field.entry,
                name: field.name.clone(),
                value: Some(value),
                raw: raw & low_bits(u32::from(field.entry.bits)),
            });
        }
        let frame =
            self.mapping
                .encode(self.cob_id, &raws)
                .map_err(|err| RpdoValueError::Invalid {
                    name: "values".to_string(),
                    detail: err.to_string(),
                })?;
        Ok((frame, decoded))
    }
}

fn low_bits(width: u32) -> u64 {
    if width >= 64 {
        u64::MAX
    } else {
        (1 << width) - 1
    }
}

#[cfg(test)]
mod tests;
