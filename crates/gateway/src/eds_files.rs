//! The EDS files as operations of the gateway service (CiA 306): files
//! uploaded and deleted while it runs, and a file assigned to a node by
//! hand, for every adapter (REST's `/eds` and `.../nodes/{id}/eds`, the
//! config file's `[[nodes]]` entries).
//!
//! Every bus shares one [`EdsCatalog`]. A file that joins or leaves it
//! makes every registry match its nodes again, so that a node whose product
//! an upload describes is described by it at once. A file assigned to a
//! node by hand cannot be deleted while it is (`eds_conflict`): unassign it
//! first. The assignments last until the gateway stops (the config file's
//! `eds` key makes one for good).
//!
//! Each operation takes its [`Caller`]: uploads and deletes are an
//! admin's ([`Operation::ManageEds`]), assignments an operator's
//! ([`Operation::AssignEds`]); each takes one write of the caller's rate,
//! runs in a task a caller that goes away cannot cut, and writes its own
//! audit row.

use std::sync::Arc;

use crate::canopen::NodeId;

use super::audit::{AuditTarget, spawn_audited};
use super::caller::Caller;
use super::error::GatewayError;
use super::policy::Operation;
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
            CatalogError::Quota(message) => Self::EdsQuota(message),
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

    /// Takes an uploaded EDS file named `name` (see
    /// [`EdsCatalog::upload`]) for `caller` (an admin's: one write of its
    /// rate); every bus matches its nodes again. The file is read and kept
    /// (the data directory's `eds/`) in a task of its own: a caller that
    /// goes away cuts neither.
    ///
    /// Audited as `upload eds`, the file's name its item.
    pub async fn upload_eds<B>(
        &self,
        caller: &Caller,
        name: &str,
        bytes: B,
    ) -> Result<Arc<EdsEntry>, GatewayError>
    where
        B: AsRef<[u8]> + Send + 'static,
    {
        let summary = format!("{} bytes", bytes.as_ref().len());
        let target = AuditTarget::new("upload eds").item(name.to_string());
        let row = self.audit_row(caller, target, Some(summary));
        let (gateway, caller, name) = (self.clone(), caller.clone(), name.to_string());
        spawn_audited(row, async move {
            gateway.admit(&caller, Operation::ManageEds)?;
            // Reading a large file and writing it to disk is blocking work.
            tokio::task::spawn_blocking(move || gateway.keep_upload(&name, bytes.as_ref(), &caller))
                .await
                .map_err(|err| GatewayError::Internal(format!("EDS upload task: {err}")))?
        })
        .await
    }

    fn keep_upload(
        &self,
        name: &str,
        bytes: &[u8],
        caller: &Caller,
    ) -> Result<Arc<EdsEntry>, GatewayError> {
        let catalog = self.catalog_or_refuse()?;
        let entry = catalog.upload(name, bytes)?;
        tracing::info!(
            "EDS {name} uploaded by {} ({}): {} objects, {} warnings{}",
            caller.who,
            caller.channel,
            entry.eds.dictionary.len(),
            entry.eds.warnings.len(),
            if catalog.uploads_dir().is_none() {
                " (kept in memory: no data directory)"
            } else {
                ""
            }
        );
        self.rematch_everywhere();
        Ok(entry)
    }

    /// Deletes the uploaded EDS file `name` for `caller` (an admin's: one
    /// write of its rate), from the data directory too, in a task of its
    /// own: refused (`eds_conflict`) while it is assigned to a node by
    /// hand; nodes matched to it by identity are matched again without it.
    ///
    /// Audited as `delete eds`, the file's name its item.
    pub async fn delete_eds(&self, caller: &Caller, name: &str) -> Result<(), GatewayError> {
        let target = AuditTarget::new("delete eds").item(name.to_string());
        let row = self.audit_row(caller, target, None);
        let (gateway, caller, name) = (self.clone(), caller.clone(), name.to_string());
        spawn_audited(row, async move {
            gateway.admit(&caller, Operation::ManageEds)?;
            gateway.remove_upload(&name, &caller)
        })
        .await
    }

    fn remove_upload(&self, name: &str, caller: &Caller) -> Result<(), GatewayError> {
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
        tracing::info!("EDS {name} deleted by {} ({})", caller.who, caller.channel);
        self.rematch_everywhere();
        Ok(())
    }

    /// A file joined or left the catalog: every registry matches its nodes
    /// again.
    fn rematch_everywhere(&self) {
        for served in self.buses.values() {
            served.registry.rematch();
        }
    }

    /// Describes node `node` of `bus` by the catalog's file `file` from now
    /// on, whatever its identity says (its OD listing, reads and writes by
    /// name, its profile from the file's device type, else the device's);
    /// `None` returns it to matching by identity. An operator's (one write
    /// of the caller's rate). A node id not heard yet takes the file when
    /// it is. Returns the node as it is now, if it is known.
    ///
    /// Audited as `assign eds` (`unassign eds` for `None`).
    pub async fn assign_eds(
        &self,
        caller: &Caller,
        bus: &str,
        node: NodeId,
        file: Option<&str>,
    ) -> Result<Option<NodeInfo>, GatewayError> {
        let words = if file.is_some() {
            "assign eds"
        } else {
            "unassign eds"
        };
        let target = AuditTarget::new(words).bus(bus).node(node.get());
        let summary = file.map(|file| serde_json::json!({ "file": file }).to_string());
        let row = self.audit_row(caller, target, summary);
        let (gateway, caller) = (self.clone(), caller.clone());
        let (bus, file) = (bus.to_string(), file.map(str::to_string));
        spawn_audited(row, async move {
            gateway.admit(&caller, Operation::AssignEds)?;
            gateway.assign(&bus, node, file.as_deref(), &caller)
        })
        .await
    }

    fn assign(
        &self,
        bus: &str,
        node: NodeId,
        file: Option<&str>,
        caller: &Caller,
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
        let who = &caller.who;
        match file {
            Some(name) => tracing::info!("bus {bus} node {node}: EDS {name} assigned by {who}"),
            None => tracing::info!("bus {bus} node {node}: EDS assignment removed by {who}"),
        }
        Ok(info)
    }
}

#[cfg(test)]
pub(crate) mod tests;
