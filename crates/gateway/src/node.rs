//! One node of a bus, as every door reaches it: [`Gateway::node_handle`]
//! finds the node once (the bus, the registry's view of it) and its
//! operations — object reads and writes, NMT, the configuration, PDOs,
//! LEDs, I/O, program download — each do their whole job for a
//! [`Caller`]: the checks, the transfer, the
//! follow-up. A door holds a handle, never the node's SDO channel.
//!
//! The operations live in files by area beside this one; this file holds
//! the handle.

mod axes;
pub(crate) mod config;
pub(crate) mod led;
pub(crate) mod pdo;
pub(crate) mod program;
mod transfer;
mod watchdog;

use std::sync::Arc;

pub(crate) mod objects;

use super::GatewayError;
use super::audit::{AuditRow, AuditTarget};
use super::caller::Caller;
use super::registry::NodeInfo;
use super::service::{Gateway, ServedBus};

/// A node of a bus, found: what its operations act on.
#[derive(Clone)]
pub struct NodeHandle {
    pub(crate) gateway: Gateway,
    pub(crate) served: Arc<ServedBus>,
    pub(crate) info: NodeInfo,
}

impl NodeHandle {
    /// The registry's view of the node when the handle was made.
    pub fn info(&self) -> &NodeInfo {
        &self.info
    }

    /// The bus's name.
    pub fn bus_name(&self) -> &str {
        &self.served.name
    }

    /// The node's id (1–127).
    pub fn id(&self) -> u8 {
        self.info.id.get()
    }

    /// The audit row of `caller`'s `operation` on this node.
    pub(crate) fn audit_row(
        &self,
        caller: &Caller,
        operation: &str,
        item: Option<String>,
        request: Option<String>,
    ) -> AuditRow {
        let target = AuditTarget::new(operation)
            .bus(self.served.name.clone())
            .node(self.id())
            .item(item);
        self.gateway.audit_row(caller, target, request)
    }
}

impl Gateway {
    /// The node `id` of `bus`, as a handle for its operations: an id that
    /// is no node id (1–127) is an invalid request; a bus or node not
    /// known, unknown.
    pub fn node_handle(&self, bus: &str, id: &str) -> Result<NodeHandle, GatewayError> {
        let (served, info) = self.node(bus, id)?;
        Ok(NodeHandle {
            gateway: self.clone(),
            served,
            info,
        })
    }
}
#[cfg(test)]
mod tests;
