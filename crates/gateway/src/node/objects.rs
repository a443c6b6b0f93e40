//! A node's objects and its NMT state, as every door reaches them: reads
//! and writes over SDO ([`NodeHandle::read_object`],
//! [`NodeHandle::write_object`]) and NMT commands ([`NodeHandle::nmt`],
//! [`Gateway::bus_nmt`]). Each does the whole job for its [`Caller`]: the
//! role (a viewer's to read, an operator's to write or command NMT, as the
//! REST route table has it), a write from the caller's write rate limit
//! ([`crate::policy`]), the node's checks ([`check_sdo_allowed`],
//! [`check_writable`]), and the transfer in a task of its own, so that a
//! client that goes away cannot cut it half way. What follows a write
//! (the TPDO decoder read again after a write to 0x1A00, the producer
//! heartbeat time followed) hangs on the node's SDO channel
//! ([`crate::registry::NodeRegistry::subscribe_writes`]), whoever wrote.
//!
//! Writes and NMT commands write their audit row ([`crate::audit`]),
//! refusals included, in the task of their transfer. The doors parse and
//! type their requests (REST against the EDS, CiA 309 by its datatypes,
//! Sparkplug from its metrics); the item an object is logged as is
//! [`object_item`].

use crate::canopen::nmt::{NmtCommand, NmtTarget};
use crate::canopen::sdo::ClientConfig;
use crate::policy::Operation;

use super::NodeHandle;
use super::transfer::{audited, refused};
use super::watchdog::WatchdogWrite;
use crate::GatewayError;
use crate::audit::AuditTarget;
use crate::caller::Caller;
use crate::service::{Gateway, check_sdo_allowed, check_writable};

/// An object as the audit log names it, whichever door wrote it:
/// `0x1A00:0`.
pub fn object_item(index: u16, sub: u8) -> String {
    format!("0x{index:04X}:{sub}")
}

/// A caller's own settings for one transfer (CiA 309-3's `set
/// sdo_timeout`, `set sdo_block`): the channel's configuration as it
/// should be changed, or `None` to keep it.
pub(crate) type TransferSettings<'a> = &'a (dyn Fn(&ClientConfig) -> Option<ClientConfig> + Sync);

/// The channel's own settings.
fn channel_settings(_: &ClientConfig) -> Option<ClientConfig> {
    None
}

impl NodeHandle {
    /// Reads an object's value bytes (the viewer's).
    pub async fn read_object(
        &self,
        caller: &Caller,
        index: u16,
        sub: u8,
    ) -> Result<Vec<u8>, GatewayError> {
        self.read_object_with(caller, index, sub, &channel_settings)
            .await
    }

    /// [`NodeHandle::read_object`] with the caller's own settings.
    pub async fn read_object_with(
        &self,
        caller: &Caller,
        index: u16,
        sub: u8,
        settings: TransferSettings<'_>,
    ) -> Result<Vec<u8>, GatewayError> {
        self.gateway.require(caller, Operation::View)?;
        check_sdo_allowed(&self.served, &self.info)?;
        if let Some(known) = self.identity_during_download(index, sub) {
            return Ok(known);
        }
        let channel = self.served.registry.sdo(self.info.id)?;
        let config = settings(channel.config());
        super::transfer::spawned(async move {
            channel
                .upload_with(index, sub, config.as_ref())
                .await
                .map_err(GatewayError::from)
        })
        .await
    }

    /// While a program download holds the node's one SDO server channel
    /// (for as long as the image takes: 20 s for 512 KiB at 500 kbit/s;
    /// CiA 301 lets no other transfer into a block download, and the
    /// UniSwarm products have no second server channel, 0x1201), what the
    /// gateway read of the node's identity when it identified it (0x1000,
    /// 0x1018 subs 1 to 4: constants of the device) is answered from the
    /// registry rather than after the download. Anything else waits.
    fn identity_during_download(&self, index: u16, sub: u8) -> Option<Vec<u8>> {
        if !self.served.programs.runs_on(self.info.id) {
            return None;
        }
        let info = self.served.registry.node(self.info.id)?;
        let identity = info.identity.as_ref();
        let value = match (index, sub) {
            (0x1000, 0) => info.device_type,
            (0x1018, 1) => identity.map(|identity| identity.vendor_id),
            (0x1018, 2) => identity.and_then(|identity| identity.product_code),
            (0x1018, 3) => identity.and_then(|identity| identity.revision),
            (0x1018, 4) => identity.and_then(|identity| identity.serial),
            _ => None,
        }?;
        Some(value.to_le_bytes().to_vec())
    }

    /// Writes an object's value bytes (the operator's; one write of the
    /// caller's rate).
    pub async fn write_object(
        &self,
        caller: &Caller,
        index: u16,
        sub: u8,
        bytes: Vec<u8>,
    ) -> Result<(), GatewayError> {
        self.write_object_with(caller, index, sub, bytes, &channel_settings)
            .await
    }

    /// [`NodeHandle::write_object`] with the caller's own settings.
    pub async fn write_object_with(
        &self,
        caller: &Caller,
        index: u16,
        sub: u8,
        bytes: Vec<u8>,
        settings: TransferSettings<'_>,
    ) -> Result<(), GatewayError> {
        self.write(caller, index, sub, bytes, false, settings)
            .await
            .map(|_| ())
    }

    /// [`NodeHandle::write_object`], then the value read back in the same
    /// task (what the device made of it); the bytes written for an object
    /// the EDS describes as write-only.
    pub async fn write_object_read_back(
        &self,
        caller: &Caller,
        index: u16,
        sub: u8,
        bytes: Vec<u8>,
    ) -> Result<Vec<u8>, GatewayError> {
        let readable = self
            .info
            .eds_entry
            .as_ref()
            .and_then(|entry| entry.eds.dictionary.sub(index, sub))
            .is_none_or(|described| described.access.is_readable());
        let read_back = self
            .write(
                caller,
                index,
                sub,
                bytes.clone(),
                readable,
                &channel_settings,
            )
            .await?;
        Ok(read_back.unwrap_or(bytes))
    }

    async fn write(
        &self,
        caller: &Caller,
        index: u16,
        sub: u8,
        bytes: Vec<u8>,
        read_back: bool,
        settings: TransferSettings<'_>,
    ) -> Result<Option<Vec<u8>>, GatewayError> {
        let mut row = self.audit_row(
            caller,
            "write object",
            Some(object_item(index, sub)),
            Some(raw_summary(&bytes)),
        );
        let checked = (|| {
            self.gateway.admit(caller, Operation::WriteObject)?;
            check_sdo_allowed(&self.served, &self.info)?;
            check_writable(&self.info, index, sub)?;
            // Issue 30 (motion authority): an axis's controlword, mode or
            // target goes through the axis's authority and lease rule.
            let motion = self.gateway.motion_write(
                caller,
                &self.served,
                &self.info,
                (index, sub),
                &bytes,
            )?;
            Ok::<_, GatewayError>((self.served.registry.sdo(self.info.id)?, motion))
        })();
        let (channel, motion) = match checked {
            Ok(checked) => checked,
            Err(error) => return refused(row, error).await,
        };
        // Issue 30: a write of the UniSwarm node-ID (0x2040 sub 1) is a
        // renumbering, under the node-ID route's rule (lss.rs).
        let node_id_write = if crate::lss::writes_node_id(&self.info, index, sub) {
            match self
                .gateway
                .before_node_id_write(&self.served, &self.info, &bytes)
                .await
            {
                Ok(write) => Some((self.served.clone(), self.info.id, write)),
                Err(error) => return refused(row, error).await,
            }
        } else {
            None
        };
        // The watchdog stays on (node/watchdog.rs): refused to an
        // operator, an admin's said in the row and on the stream.
        let watchdog = match self
            .watchdog_check(caller, &channel, index, sub, &bytes)
            .await
        {
            Ok(WatchdogWrite::SwitchesItOff(warning)) => {
                row.note(&format!("WATCHDOG SWITCHED OFF: {warning}"));
                Some((self.clone(), warning))
            }
            Ok(WatchdogWrite::KeepsItOn) => None,
            Err(error) => return refused(row, error).await,
        };
        let config = settings(channel.config());
        let gateway = self.gateway.clone();
        // Write and read back in one task, and its audit row: all finish
        // even if the caller goes away.
        audited(row, async move {
            let transfers = async {
                channel
                    .download_with(index, sub, &bytes, config.as_ref())
                    .await?;
                if let Some((served, node, write)) = node_id_write {
                    served.lss.node_id_written(node, write);
                }
                if let Some((node, warning)) = watchdog {
                    node.warn_watchdog_off(&warning);
                }
                if read_back {
                    Ok(Some(
                        channel.upload_with(index, sub, config.as_ref()).await?,
                    ))
                } else {
                    Ok(None)
                }
            };
            motion.send(&gateway, transfers).await
        })
        .await
    }

    /// Sends an NMT command to the node (the operator's; one write of the
    /// caller's rate). NMT is unconfirmed (CiA 301 §7.2.8.2.1): this says
    /// the command was sent; the node's new state shows in the registry
    /// once it reports it.
    pub async fn nmt(&self, caller: &Caller, command: NmtCommand) -> Result<(), GatewayError> {
        let row = self.audit_row(caller, "nmt command", None, Some(nmt_summary(command)));
        let checked = self.gateway.admit(caller, Operation::Nmt);
        if let Err(error) = checked {
            return refused(row, error).await;
        }
        let served = self.served.clone();
        let node = self.info.id;
        audited(row, async move {
            served
                .send_nmt_following_node_ids(command, NmtTarget::Node(node))
                .await
        })
        .await
    }
}

/// A write's request as the operation knows it (a door may have its own
/// summary): the bytes, in hex.
fn raw_summary(bytes: &[u8]) -> String {
    let hex: String = bytes.iter().map(|byte| format!("{byte:02x}")).collect();
    format!("{{\"raw\":\"{hex}\"}}")
}

/// An NMT command's request, as every door gives it.
pub fn nmt_summary(command: NmtCommand) -> String {
    format!("{{\"command\":\"{}\"}}", command.name())
}

impl Gateway {
    /// Sends an NMT command to every node of `bus`, as [`NodeHandle::nmt`]
    /// does to one.
    pub async fn bus_nmt(
        &self,
        caller: &Caller,
        bus: &str,
        command: NmtCommand,
    ) -> Result<(), GatewayError> {
        let target = AuditTarget::new("nmt command to all nodes").bus(bus);
        let row = self.audit_row(caller, target, Some(nmt_summary(command)));
        let checked = self.bus(bus).and_then(|served| {
            self.admit(caller, Operation::Nmt)?;
            Ok(served)
        });
        let served = match checked {
            Ok(served) => served,
            Err(error) => return refused(row, error).await,
        };
        audited(row, async move {
            served
                .send_nmt_following_node_ids(command, NmtTarget::All)
                .await
        })
        .await
    }
}
