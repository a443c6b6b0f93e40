//! Each node's `Identification/HardwareRevision` (0x1009, manufacturer
//! hardware version) and `SoftwareRevision` (0x100A, manufacturer software
//! version): the registry's identification reads 0x1000, 0x1008 and
//! 0x1018, not these, so the door reads them itself, over SDO through the
//! gateway, once per identification (a node is identified again after each
//! boot-up, when a new program may run). An object the device does not
//! have (its SDO abort) leaves the revision empty; a read that failed
//! otherwise (no answer) is tried again at the next identification.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use tokio::sync::broadcast::error::RecvError;

use super::browse::NodePath;
use crate::canopen::od::{DataType, Value};
use crate::gateway::{Caller, Channel, Gateway, Identification, NodeEvent, Role, ServedBus};

/// The manufacturer hardware version object.
pub const HARDWARE_VERSION: u16 = 0x1009;
/// The manufacturer software version object.
pub const SOFTWARE_VERSION: u16 = 0x100A;

/// A node's two version strings (empty where the device has none).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Revision {
    pub hardware: String,
    pub software: String,
}

/// The revisions read so far, by node.
#[derive(Default)]
pub struct Revisions {
    known: Mutex<HashMap<NodePath, Revision>>,
}

/// The text of a version object as the device sent it, by the type its
/// EDS gives it (some declare a UNICODE_STRING), else as a VISIBLE_STRING
/// (CiA 301's type for both); padding NULs and spaces trimmed.
pub fn version_text(data_type: Option<DataType>, bytes: &[u8]) -> String {
    let text = match data_type.map(|data_type| Value::from_bytes(data_type, bytes)) {
        Some(Ok(Value::VisibleString(text) | Value::UnicodeString(text))) => text,
        _ => String::from_utf8_lossy(bytes).into_owned(),
    };
    text.trim_end_matches('\0').trim().to_string()
}

impl Revisions {
    fn known(&self) -> std::sync::MutexGuard<'_, HashMap<NodePath, Revision>> {
        self.known
            .lock()
            .unwrap_or_else(|poison| poison.into_inner())
    }

    /// What is known of `node` (empty until read).
    pub fn of(&self, node: &NodePath) -> Revision {
        self.known().get(node).cloned().unwrap_or_default()
    }

    /// Reads both objects of `node` now and keeps what it got.
    pub async fn read(&self, gateway: &Gateway, node: &NodePath) {
        // The door's own read of what identifies a node, as a viewer
        // would (reads are not audited).
        let caller = Caller::new(Channel::Opcua, "opcua", Some(Role::Viewer));
        let mut revision = Revision::default();
        for (index, into) in [
            (HARDWARE_VERSION, &mut revision.hardware),
            (SOFTWARE_VERSION, &mut revision.software),
        ] {
            let read = match gateway.node_handle(&node.bus, &node.node.to_string()) {
                Ok(handle) => {
                    let data_type = handle.info().eds_entry.as_ref().and_then(|entry| {
                        entry.eds.dictionary.sub(index, 0).map(|sub| sub.data_type)
                    });
                    handle
                        .read_object(&caller, index, 0)
                        .await
                        .map(|bytes| (data_type, bytes))
                }
                Err(error) => Err(error),
            };
            match read {
                Ok((data_type, bytes)) => *into = version_text(data_type, &bytes),
                Err(error) => tracing::debug!(
                    "opcua: 0x{index:04X} of {}/{}: {error}",
                    node.bus,
                    node.node
                ),
            }
        }
        self.known().insert(node.clone(), revision);
    }

    /// Reads the revisions of every node of `bus` identified now, then of
    /// each node as it is identified (again), until dropped.
    pub async fn follow(self: Arc<Self>, gateway: Gateway, bus: Arc<ServedBus>) {
        let mut events = bus.node_events();
        let path = |id: u8| NodePath {
            bus: bus.name().to_string(),
            node: id,
        };
        let identified = |bus: &ServedBus| -> Vec<u8> {
            bus.nodes()
                .into_iter()
                .filter(|info| info.identification == Identification::Done)
                .map(|info| info.id.get())
                .collect()
        };
        for id in identified(&bus) {
            self.read(&gateway, &path(id)).await;
        }
        loop {
            match events.recv().await {
                Ok(NodeEvent::Identified { node, .. }) => {
                    self.read(&gateway, &path(node.get())).await;
                }
                Ok(_) => {}
                // Events were missed: read every identified node again.
                Err(RecvError::Lagged(_)) => {
                    for id in identified(&bus) {
                        self.read(&gateway, &path(id)).await;
                    }
                }
                Err(RecvError::Closed) => return,
            }
        }
    }

    /// [`Revisions::follow`] on every bus of the gateway.
    pub fn spawn(self: &Arc<Self>, gateway: &Gateway) -> Vec<tokio::task::JoinHandle<()>> {
        gateway
            .buses_in_order()
            .into_iter()
            .map(|bus| tokio::spawn(self.clone().follow(gateway.clone(), bus)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_version_is_read_by_its_eds_type_without_its_padding() {
        let visible = Some(DataType::VisibleString);
        assert_eq!(version_text(visible, b"1.2.0\0\0"), "1.2.0");
        assert_eq!(version_text(visible, b"HW rev B  "), "HW rev B");
        assert_eq!(version_text(None, b"2.1.0"), "2.1.0");
        assert_eq!(version_text(visible, b""), "");
        // The UMC's EDS declares 0x1009 a UNICODE_STRING (UTF-16LE).
        let utf16: Vec<u8> = "v01.02".encode_utf16().flat_map(u16::to_le_bytes).collect();
        assert_eq!(
            version_text(Some(DataType::UnicodeString), &utf16),
            "v01.02"
        );
    }
}
