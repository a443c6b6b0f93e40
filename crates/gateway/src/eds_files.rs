//! The EDS files as operations of the gateway service (CiA 306): files
//! uploaded and deleted while it runs, and a file assigned to a node by
//! hand, for every adapter (REST's `/eds` and `.../nodes/{id}/eds`, the
//! config file's `[[nodes]]` entries).
//!
//! Every bus shares one [`EdsCatalog`]. A file that joins or leaves it
//! makes every registry match its nodes again, so that a node whose product
//! an upload describes is described by it at once. A file assigned to a
//! node by hand cannot be deleted while it is (409): unassign it first. The
//! assignments last until the gateway stops (the config file's `eds` key
//! makes one for good).

use std::sync::Arc;

use crate::canopen::NodeId;

use super::error::GatewayError;
use super::profile::{CatalogError, EdsCatalog, EdsEntry};
use super::registry::NodeInfo;
use super::service::Gateway;

/// A node that an EDS file describes.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct EdsUser {
    pub bus: String,
    #[serde(serialize_with = "node_number")]
    pub node: NodeId,
    /// Assigned by hand, rather than matched by the node's identity.
    pub assigned: bool,
}

fn node_number<S: serde::Serializer>(id: &NodeId, serializer: S) -> Result<S::Ok, S::Error> {
    serializer.serialize_u8(id.get())
}

impl From<CatalogError> for GatewayError {
    fn from(error: CatalogError) -> Self {
        match error {
            CatalogError::InvalidName(message) => Self::InvalidRequest(message),
            CatalogError::NotEds(error) => Self::InvalidEds {
                message: error.to_string(),
                line: Some(error.line).filter(|&line| line > 0),
            },
            CatalogError::Exists(message) | CatalogError::NotUploaded(message) => {
                Self::EdsConflict(message)
            }
            CatalogError::Unknown(name) => Self::UnknownEds(name),
            CatalogError::Io(message) => Self::Internal(message),
        }
    }
}

impl Gateway {
    /// The EDS catalog every bus shares; `None` for a gateway with no bus.
    pub fn eds_catalog(&self) -> Option<Arc<EdsCatalog>> {
        self.buses
            .values()
            .next()
            .map(|served| served.registry.catalog().clone())
    }

    fn catalog_or_refuse(&self) -> Result<Arc<EdsCatalog>, GatewayError> {
        self.eds_catalog().ok_or_else(|| {
            GatewayError::InvalidRequest("the gateway serves no bus: it has no EDS catalog".into())
        })
    }

    /// The nodes that `name` describes, on every bus.
    pub fn eds_users(&self, name: &str) -> Vec<EdsUser> {
        let mut users = Vec::new();
        for served in self.buses_in_order() {
            for node in served.registry.nodes() {
                if node.eds.as_deref() == Some(name) {
                    users.push(EdsUser {
                        bus: served.name.clone(),
                        node: node.id,
                        assigned: node.eds_assigned,
                    });
                }
            }
            // Assigned to a node not heard yet.
            for (node, file) in served.registry.assignments() {
                if file == name && !users.iter().any(|u| u.bus == served.name && u.node == node) {
                    users.push(EdsUser {
                        bus: served.name.clone(),
                        node,
                        assigned: true,
                    });
                }
            }
        }
        users
    }

    /// Takes an uploaded EDS file (see [`EdsCatalog::upload`]); every bus
    /// matches its nodes again. `who` names the client in the log.
    pub fn upload_eds(
        &self,
        name: &str,
        bytes: &[u8],
        who: &str,
    ) -> Result<Arc<EdsEntry>, GatewayError> {
        let catalog = self.catalog_or_refuse()?;
        let entry = catalog.upload(name, bytes)?;
        tracing::info!(
            "EDS {name} uploaded by {who}: {} objects, {} warnings{}",
            entry.eds.dictionary.len(),
            entry.eds.warnings.len(),
            if catalog.uploads_dir().is_none() {
                " (kept in memory: no data directory)"
            } else {
                ""
            }
        );
        for served in self.buses.values() {
            served.registry.rematch();
        }
        Ok(entry)
    }

    /// Deletes an uploaded EDS file: refused (409) while it is assigned to
    /// a node by hand; nodes matched to it by identity are matched again
    /// without it.
    pub fn delete_eds(&self, name: &str, who: &str) -> Result<(), GatewayError> {
        let catalog = self.catalog_or_refuse()?;
        let assigned: Vec<String> = self
            .eds_users(name)
            .into_iter()
            .filter(|user| user.assigned)
            .map(|user| format!("{} node {}", user.bus, user.node))
            .collect();
        if !assigned.is_empty() {
            return Err(GatewayError::EdsConflict(format!(
                "{name} is assigned to {}: unassign it first (DELETE .../nodes/{{id}}/eds)",
                assigned.join(", ")
            )));
        }
        catalog.remove(name)?;
        tracing::info!("EDS {name} deleted by {who}");
        for served in self.buses.values() {
            served.registry.rematch();
        }
        Ok(())
    }

    /// Describes node `node` of `bus` by the catalog's file `file` from now
    /// on, whatever its identity says (its OD listing, reads and writes by
    /// name, its profile from the file's device type, else the device's);
    /// `None` returns it to matching by identity. A node id not heard yet
    /// takes the file when it is. `who` names the client (or the config
    /// file) in the log. Returns the node as it is now, if it is known.
    pub fn assign_eds(
        &self,
        bus: &str,
        node: NodeId,
        file: Option<&str>,
        who: &str,
    ) -> Result<Option<NodeInfo>, GatewayError> {
        let served = self.bus(bus)?;
        let entry = match file {
            Some(name) => Some(
                served
                    .registry
                    .catalog()
                    .find(name)
                    .ok_or_else(|| GatewayError::UnknownEds(name.to_string()))?,
            ),
            None => None,
        };
        let info = served.registry.assign_eds(node, entry);
        match file {
            Some(name) => tracing::info!("bus {bus} node {node}: EDS {name} assigned by {who}"),
            None => tracing::info!("bus {bus} node {node}: EDS assignment removed by {who}"),
        }
        Ok(info)
    }
}
