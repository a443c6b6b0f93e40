//! Configuration backup and restore as a DCF (CiA 306 §4.6.5, the device
//! configuration file): every readable and writable parameter of a node
//! read over SDO into `ParameterValue`s of its EDS, and a DCF's values
//! written back, PDOs by the re-mapping procedure of CiA 301 §7.5.2.35
//! and §7.5.2.36.
//!
//! A value that equals the EDS default of the node it was read from, where
//! that default depends on the node id (`$NODEID+0x180`), is written as the
//! default's text: restored onto another node it resolves to that node's
//! COB-ID, not to the first node's, so a backup serves as a template for a
//! replacement device at another address.
//!
//! What is not configuration stays out of the backup: the commands 0x1010
//! (store) and 0x1011 (restore), the error history 0x1003 (writing it
//! clears it), DOMAINs, entries whose `ObjFlags` refuse read or download,
//! and of every CiA 402 axis the controlword (a restore must never enable
//! a drive) and the interpolation buffer (set-points and fill level).

use std::collections::BTreeMap;

use crate::canopen::NodeId;
use crate::canopen::eds::{DeviceCommissioning, Eds};
use crate::canopen::od::{AccessType, DataType, ObjectDictionary, SubObject, Value};
use crate::canopen::sdo::AbortCode;
use crate::sdo::{SdoChannel, SdoRequestError};

/// 0x1003: the pre-defined error field.
const ERROR_HISTORY: u16 = 0x1003;
/// 0x1010 and 0x1011: store and restore commands.
const STORE: u16 = 0x1010;
const RESTORE: u16 = 0x1011;
/// COB-ID bit 31: the PDO does not exist (is invalid).
const PDO_INVALID: u32 = 0x8000_0000;
/// ObjFlags bit 0: refuse write on download; bit 1: refuse read on scan.
const REFUSE_WRITE: u32 = 0x1;
const REFUSE_READ: u32 = 0x2;

/// The PDO parameter ranges (CiA 301 §7.5.2.35–38): RPDO communication,
/// RPDO mapping, TPDO communication, TPDO mapping, each 0x200 objects.
const RPDO_COMM: u16 = 0x1400;
const RPDO_MAP: u16 = 0x1600;
const TPDO_COMM: u16 = 0x1800;
const TPDO_MAP: u16 = 0x1A00;
const PDO_AREA: u16 = 0x200;

/// What a PDO parameter object is: a communication or mapping object of
/// PDO `n` (0-based, per direction).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum PdoObject {
    Comm { tpdo: bool, n: u16 },
    Map { tpdo: bool, n: u16 },
}

fn pdo_object(index: u16) -> Option<PdoObject> {
    let within = |base: u16| (base..base + PDO_AREA).contains(&index);
    if within(RPDO_COMM) {
        Some(PdoObject::Comm {
            tpdo: false,
            n: index - RPDO_COMM,
        })
    } else if within(RPDO_MAP) {
        Some(PdoObject::Map {
            tpdo: false,
            n: index - RPDO_MAP,
        })
    } else if within(TPDO_COMM) {
        Some(PdoObject::Comm {
            tpdo: true,
            n: index - TPDO_COMM,
        })
    } else if within(TPDO_MAP) {
        Some(PdoObject::Map {
            tpdo: true,
            n: index - TPDO_MAP,
        })
    } else {
        None
    }
}

/// CiA 402 objects of axis 1 to 8 (at 0x6000 + 0x800 × n) that are
/// commands or process state rather than configuration: the controlword
/// (0x6040), the interpolation data record (0x60C1, set-points) and the
/// interpolation buffer's state (0x60C4: its fill level, position, clear).
fn is_drive_command(index: u16) -> bool {
    (0x6000..=0x9FFF).contains(&index) && matches!((index - 0x6000) % 0x800, 0x40 | 0xC1 | 0xC4)
}

/// Whether an entry is a parameter a backup keeps (see the module docs).
pub(crate) fn is_parameter(index: u16, sub: &SubObject) -> bool {
    let flags = sub.obj_flags.unwrap_or(0);
    sub.access.is_readable()
        && sub.access.is_writable()
        && !matches!(sub.access, AccessType::Wo)
        && !matches!(index, ERROR_HISTORY | STORE | RESTORE)
        && !is_drive_command(index)
        && !matches!(sub.data_type, DataType::Domain)
        && flags & (REFUSE_WRITE | REFUSE_READ) == 0
}

/// Every parameter entry of a dictionary, in index order.
pub(crate) fn parameters(dictionary: &ObjectDictionary) -> Vec<(u16, u8)> {
    dictionary
        .objects
        .values()
        .flat_map(|object| {
            object
                .subs
                .values()
                .filter(|sub| is_parameter(object.index, sub))
                .map(|sub| (object.index, sub.sub_index))
        })
        .collect()
}

/// A parameter the backup could not read (an abort): left out of the DCF.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Unread {
    pub index: u16,
    pub sub: u8,
    pub abort: AbortCode,
}

/// Reads every parameter of `eds` from the node and returns the DCF, with
/// the entries the device refused to read (left without a value). A
/// failure other than a device abort (timeout, bus) ends the backup.
pub(crate) async fn backup(
    channel: &SdoChannel,
    eds: &Eds,
    node: NodeId,
    node_name: Option<String>,
) -> Result<(Eds, Vec<Unread>), SdoRequestError> {
    // No re-mapping (or restore) of the node half done while it is read.
    let _procedure = channel.procedure().await;
    let mut values = BTreeMap::new();
    let mut unread = Vec::new();
    for (index, sub) in parameters(&eds.dictionary) {
        let Some(described) = eds.dictionary.sub(index, sub) else {
            continue;
        };
        match channel.upload(index, sub).await {
            Ok(raw) => match Value::from_bytes(described.data_type, &raw) {
                Ok(value) => {
                    values.insert((index, sub), value);
                }
                // Bytes that are no value of the type are no value to
                // restore.
                Err(_) => unread.push(Unread {
                    index,
                    sub,
                    abort: AbortCode::LengthMismatch,
                }),
            },
            Err(error) => match error.device_abort() {
                Some(abort) => unread.push(Unread { index, sub, abort }),
                None => return Err(error),
            },
        }
    }
    let commissioning = DeviceCommissioning {
        node_id: Some(node.get()),
        node_name,
        ..DeviceCommissioning::default()
    };
    let mut dcf = eds
        .to_dcf(commissioning, &values)
        .map_err(|_| SdoRequestError::Sdo {
            node,
            error: crate::canopen::sdo::SdoError::Protocol {
                code: AbortCode::LengthMismatch,
                detail: "a value read does not fit the EDS".into(),
            },
        })?;
    // Node-relative values back in their node-relative form.
    for object in dcf.dictionary.objects.values_mut() {
        for sub in object.subs.values_mut() {
            let (Some(default), Some(_)) = (&sub.default, &sub.parameter_value) else {
                continue;
            };
            if sub.uses_node_id()
                && default.to_ascii_uppercase().contains("$NODEID")
                && sub.default_value(Some(node)).ok().flatten()
                    == sub.parameter_value(Some(node)).ok().flatten()
            {
                sub.parameter_value = Some(default.clone());
            }
        }
    }
    dcf.file_info.file_name = Some(format!("node{}.dcf", node.get()));
    dcf.file_info.description = Some(format!(
        "Configuration of node {} read by candeck {}",
        node.get(),
        env!("CARGO_PKG_VERSION")
    ));
    dcf.file_info.created_by = Some("candeck".into());
    Ok((dcf, unread))
}

/// One write of a restore.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Write {
    pub index: u16,
    pub sub: u8,
    pub bytes: Vec<u8>,
    /// The DCF entry whose result this write decides (the invalidation of
    /// a PDO counts for its COB-ID entry).
    pub entry: (u16, u8),
    /// Read the current COB-ID and write it with bit 31 set, rather than
    /// `bytes`: the first step of re-configuring a PDO.
    pub invalidate: bool,
}

/// What a restore writes: the DCF entries with a value, in index order,
/// and the writes that set them, in the order they are made.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Plan {
    pub entries: Vec<(u16, u8)>,
    pub writes: Vec<Write>,
}

/// A PDO parameter of a DCF: its object, sub-index and value bytes.
type PdoEntry = (PdoObject, u8, Vec<u8>);

/// An entry of a DCF whose value cannot be written to this node: the DCF
/// is refused as a whole before anything is written.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct PlanError(pub String);

/// The values of `dcf` for a node described by `dictionary` (its EDS), with
/// `$NODEID` resolved for `node`, in the order they are written: every
/// other parameter in index order, then each PDO by the CiA 301 procedure
/// (COB-ID invalid, mapping count 0, mapping entries, mapping count, the
/// other communication parameters, the COB-ID as given).
pub(crate) fn plan(
    dcf: &Eds,
    dictionary: &ObjectDictionary,
    node: NodeId,
) -> Result<Plan, PlanError> {
    let mut entries = Vec::new();
    let mut plain = Vec::new();
    // By direction and number: each entry's object, sub-index and bytes.
    let mut pdos: BTreeMap<(bool, u16), Vec<PdoEntry>> = BTreeMap::new();
    for object in dcf.dictionary.objects.values() {
        for sub in object.subs.values() {
            if sub.parameter_value.is_none() {
                continue;
            }
            let (index, sub_index) = (object.index, sub.sub_index);
            let name = format!("0x{index:04X} sub {sub_index} ({})", sub.name);
            let target = dictionary.sub(index, sub_index).ok_or_else(|| {
                PlanError(format!("{name}: the node's dictionary has no such entry"))
            })?;
            if target.data_type != sub.data_type {
                return Err(PlanError(format!(
                    "{name}: a {} in the DCF, a {} in the node's dictionary",
                    sub.data_type, target.data_type
                )));
            }
            if !target.access.is_writable() {
                return Err(PlanError(format!(
                    "{name}: {} in the node's dictionary, so it cannot be written",
                    target.access
                )));
            }
            let value = sub
                .parameter_value(Some(node))
                .map_err(|error| PlanError(format!("{name}: {error}")))?
                .ok_or_else(|| PlanError(format!("{name}: no value")))?;
            target
                .check(&value, Some(node))
                .map_err(|error| PlanError(format!("{name}: {error}")))?;
            entries.push((index, sub_index));
            let bytes = value.to_bytes();
            match pdo_object(index) {
                Some(pdo @ (PdoObject::Comm { tpdo, n } | PdoObject::Map { tpdo, n })) => pdos
                    .entry((tpdo, n))
                    .or_default()
                    .push((pdo, sub_index, bytes)),
                None => plain.push(Write {
                    index,
                    sub: sub_index,
                    bytes,
                    entry: (index, sub_index),
                    invalidate: false,
                }),
            }
        }
    }
    let mut writes = plain;
    for ((tpdo, n), items) in pdos {
        let comm = if tpdo { TPDO_COMM } else { RPDO_COMM } + n;
        let map = if tpdo { TPDO_MAP } else { RPDO_MAP } + n;
        let find = |object: PdoObject, sub: u8| {
            items
                .iter()
                .find(|(o, s, _)| *o == object && *s == sub)
                .map(|(_, _, bytes)| bytes.clone())
        };
        let write = |index: u16, sub: u8, bytes: Vec<u8>| Write {
            index,
            sub,
            bytes,
            entry: (index, sub),
            invalidate: false,
        };
        let comm_object = PdoObject::Comm { tpdo, n };
        let map_object = PdoObject::Map { tpdo, n };
        let cob_id = find(comm_object, 1);
        if cob_id.is_some() {
            writes.push(Write {
                invalidate: true,
                ..write(comm, 1, Vec::new())
            });
        }
        let count = find(map_object, 0);
        if count.is_some() {
            writes.push(write(map, 0, vec![0]));
        }
        for (object, sub, bytes) in &items {
            if *object == map_object && *sub != 0 {
                writes.push(write(map, *sub, bytes.clone()));
            }
        }
        if let Some(count) = count {
            writes.push(write(map, 0, count));
        }
        for (object, sub, bytes) in &items {
            if *object == comm_object && *sub != 1 {
                writes.push(write(comm, *sub, bytes.clone()));
            }
        }
        if let Some(cob_id) = cob_id {
            writes.push(write(comm, 1, cob_id));
        }
    }
    Ok(Plan { entries, writes })
}

/// The result of one write of a restore.
pub(crate) type WriteResult = Result<(), SdoRequestError>;

/// Runs `writes` in order; the first failure of each DCF entry is its
/// result. A failure other than a device abort (timeout, bus down) stops
/// the restore: the writes not made are `None`.
pub(crate) async fn restore(
    channel: &SdoChannel,
    writes: &[Write],
) -> BTreeMap<(u16, u8), Option<WriteResult>> {
    // One procedure on the node at a time: no PDO re-mapping between ours.
    let _procedure = channel.procedure().await;
    let mut results: BTreeMap<(u16, u8), Option<WriteResult>> = BTreeMap::new();
    let mut stopped = false;
    for write in writes {
        if stopped {
            // Not made: the entry's value is not in the device.
            let slot = results.entry(write.entry).or_insert(None);
            if matches!(slot, Some(Ok(()))) {
                *slot = None;
            }
            continue;
        }
        let outcome = if write.invalidate {
            match channel.upload(write.index, write.sub).await {
                Ok(raw) if raw.len() == 4 => {
                    let current = u32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]);
                    if current & PDO_INVALID != 0 {
                        Ok(())
                    } else {
                        let invalid = (current | PDO_INVALID).to_le_bytes();
                        channel.download(write.index, write.sub, &invalid).await
                    }
                }
                // Not a COB-ID as expected: the final write will say more.
                Ok(_) => Ok(()),
                Err(error) => Err(error),
            }
        } else {
            channel.download(write.index, write.sub, &write.bytes).await
        };
        if let Err(error) = &outcome
            && error.device_abort().is_none()
        {
            stopped = true;
        }
        let slot = results.entry(write.entry).or_insert(Some(Ok(())));
        if let (Some(Ok(())), Err(_)) = (&slot, &outcome) {
            *slot = Some(outcome);
        }
    }
    results
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profiles::builtin;

    fn umc() -> Eds {
        Eds::parse(builtin::UMC1BDS32, "umc1bds32.eds").unwrap()
    }

    fn node(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }

    #[test]
    fn a_backup_keeps_configuration_and_leaves_out_commands() {
        let eds = umc();
        let entries = parameters(&eds.dictionary);
        for kept in [
            (0x1017, 0),
            (0x1800, 1),
            (0x1A00, 0),
            (0x6083, 0),
            (0x2041, 1),
        ] {
            assert!(entries.contains(&kept), "{kept:04X?}");
        }
        for left_out in [
            (0x1010, 1),
            (0x1011, 1),
            (0x1003, 0),
            (0x6040, 0),
            (0x6840, 0),
            (0x60C4, 2),
            (0x6041, 0),
            (0x1018, 1),
            (0x2050, 1),
        ] {
            assert!(!entries.contains(&left_out), "{left_out:04X?}");
        }
    }

    #[test]
    fn a_restore_writes_pdos_by_the_cia301_procedure_for_the_target_node() {
        let mut dcf = umc();
        let values = [
            (0x1801, 1, Value::Unsigned32(0x281)),
            (0x1801, 5, Value::Unsigned16(10)),
            (0x1A01, 0, Value::Unsigned8(2)),
            (0x1A01, 1, Value::Unsigned32(0x6041_0010)),
            (0x1A01, 2, Value::Unsigned32(0x6064_0020)),
            (0x1017, 0, Value::Unsigned16(100)),
        ];
        for (index, sub, value) in &values {
            dcf.dictionary
                .set_parameter_value(*index, *sub, value)
                .unwrap();
        }
        // Node-relative, as a backup writes it.
        dcf.dictionary
            .objects
            .get_mut(&0x1801)
            .unwrap()
            .subs
            .get_mut(&1)
            .unwrap()
            .parameter_value = Some("$NODEID+0x280".into());
        let plan = plan(&dcf, &umc().dictionary, node(4)).unwrap();
        assert_eq!(
            plan.entries,
            [
                (0x1017, 0),
                (0x1801, 1),
                (0x1801, 5),
                (0x1A01, 0),
                (0x1A01, 1),
                (0x1A01, 2)
            ]
        );
        let steps: Vec<(u16, u8, Vec<u8>, bool)> = plan
            .writes
            .iter()
            .map(|w| (w.index, w.sub, w.bytes.clone(), w.invalidate))
            .collect();
        assert_eq!(
            steps,
            [
                (0x1017, 0, vec![100, 0], false),
                (0x1801, 1, vec![], true),
                (0x1A01, 0, vec![0], false),
                (0x1A01, 1, 0x6041_0010u32.to_le_bytes().to_vec(), false),
                (0x1A01, 2, 0x6064_0020u32.to_le_bytes().to_vec(), false),
                (0x1A01, 0, vec![2], false),
                (0x1801, 5, vec![10, 0], false),
                (0x1801, 1, 0x284u32.to_le_bytes().to_vec(), false),
            ]
        );
    }

    #[test]
    fn a_dcf_of_another_dictionary_is_refused_before_any_write() {
        let led = Eds::parse(builtin::UIO1LED, "uio1led.eds").unwrap();
        let mut dcf = led.clone();
        dcf.dictionary
            .set_parameter_value(0x6025, 0, &Value::Unsigned8(9))
            .unwrap();
        let error = plan(&dcf, &umc().dictionary, node(1)).unwrap_err();
        assert!(error.0.contains("0x6025"), "{error:?}");
        // A value outside the node's limits (0x1A00 count is 0 to 8).
        let mut dcf = umc();
        dcf.dictionary
            .set_parameter_value(0x1A00, 0, &Value::Unsigned8(9))
            .unwrap();
        let error = plan(&dcf, &umc().dictionary, node(1)).unwrap_err();
        assert!(error.0.contains("0x1A00"), "{error:?}");
    }
}
