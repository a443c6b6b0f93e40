//! A node's configuration as operations of its handle: store and restore
//! of its parameters (CiA 301 §7.5.2.13 0x1010 and §7.5.2.14 0x1011, with
//! the UniSwarm subs 5–8 that restore the saved rather than the factory
//! values), and a backup of every parameter as a DCF (CiA 306 §4.6.5) that
//! can be written back to the same or a replacement device. The DCF work
//! is [`crate::dcf`]'s.

use super::NodeHandle;
use super::transfer::{audited, refused, spawned};
use crate::GatewayError;
use crate::caller::Caller;
use crate::canopen::eds::{Action, Eds};
use crate::canopen::od::format_index;
use crate::check_sdo_allowed;
use crate::dcf;
use crate::policy::Operation;
use crate::sdo::SdoChannel;

use super::watchdog::WatchdogWrite;

/// 0x1010: store parameters.
const STORE_PARAMETERS: u16 = 0x1010;
/// 0x1011: restore default parameters.
const RESTORE_PARAMETERS: u16 = 0x1011;
/// The signatures CiA 301 asks for, "save" and "load": written as
/// little-endian UNSIGNED32 (0x65766173, 0x64616F6C), they are the text.
const SAVE: &str = "save";
const LOAD: &str = "load";

/// Which parameters a store or restore is for (the sub-index of 0x1010
/// and 0x1011).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParameterArea {
    All,
    Communication,
    Application,
    Manufacturer,
}

impl ParameterArea {
    fn sub(self) -> u8 {
        match self {
            Self::All => 1,
            Self::Communication => 2,
            Self::Application => 3,
            Self::Manufacturer => 4,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Self::All => "all parameters",
            Self::Communication => "communication parameters",
            Self::Application => "application parameters",
            Self::Manufacturer => "manufacturer parameters",
        }
    }
}

/// What a restore brings back: the factory values (subs 1–4) or the saved
/// ones (UniSwarm's subs 5–8).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum RestoreSource {
    #[default]
    Factory,
    Saved,
}

/// A store or restore the device confirmed: the entry written (its EDS
/// name, when the node has an EDS) and the signature.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParameterCommand {
    pub index: u16,
    pub sub: u8,
    pub name: Option<String>,
    pub signature: &'static str,
}

/// One entry of a DCF restore and what became of it: `None` when the
/// restore stopped before it.
#[derive(Debug, Clone, PartialEq)]
pub struct RestoredEntry {
    pub index: u16,
    pub sub: u8,
    /// `Object` or `Object/Sub`, as the DCF names it.
    pub name: String,
    pub result: Option<Result<(), GatewayError>>,
}

/// A DCF checked against its node, the writes that restore it and the
/// node's SDO channel to make them on.
struct RestorePlan {
    parsed: Eds,
    plan: dcf::Plan,
    channel: SdoChannel,
}

impl NodeHandle {
    /// Stores `area`'s parameters in the device's non-volatile memory
    /// ("save" to 0x1010).
    pub async fn store_parameters(
        &self,
        caller: &Caller,
        area: ParameterArea,
    ) -> Result<ParameterCommand, GatewayError> {
        let row = self.audit_row(caller, "store parameters", None, None);
        if let Err(error) = self.gateway.admit(caller, Operation::StoreRestore) {
            return refused(row, error).await;
        }
        let (this, caller) = (self.clone(), caller.clone());
        audited(row, async move {
            let what = format!("store {}", area.name());
            let entry = (STORE_PARAMETERS, area.sub());
            this.parameter_command(&caller, entry, SAVE, &what, false)
                .await
        })
        .await
    }

    /// Restores `area`'s parameters from `source` ("load" to 0x1011). A
    /// device that restores at once may have other TPDO mappings then: the
    /// gateway decodes by what it has.
    pub async fn restore_parameters(
        &self,
        caller: &Caller,
        area: ParameterArea,
        source: RestoreSource,
    ) -> Result<ParameterCommand, GatewayError> {
        let (sub, from) = match source {
            RestoreSource::Factory => (area.sub(), "factory"),
            RestoreSource::Saved => (area.sub() + 4, "saved"),
        };
        let what = format!("restore the {from} {}", area.name());
        let communication = matches!(area, ParameterArea::All | ParameterArea::Communication);
        let row = self.audit_row(caller, "restore parameters", None, None);
        if let Err(error) = self.gateway.admit(caller, Operation::StoreRestore) {
            return refused(row, error).await;
        }
        let (this, caller) = (self.clone(), caller.clone());
        audited(row, async move {
            let entry = (RESTORE_PARAMETERS, sub);
            this.parameter_command(&caller, entry, LOAD, &what, communication)
                .await
        })
        .await
    }

    /// Writes a signature to `index`/`sub` after checking that the node's
    /// EDS has the sub-object (a node without EDS is asked all the same).
    async fn parameter_command(
        &self,
        caller: &Caller,
        (index, sub): (u16, u8),
        signature: &'static str,
        what: &str,
        refresh_tpdos: bool,
    ) -> Result<ParameterCommand, GatewayError> {
        let info = &self.info;
        let dictionary = info.eds_entry.as_ref().map(|entry| &entry.eds.dictionary);
        let name = match dictionary.map(|dictionary| dictionary.sub(index, sub)) {
            Some(Some(described)) => Some(described.name.clone()),
            Some(None) => {
                return Err(GatewayError::InvalidValue(format!(
                    "node {} cannot {what}: its EDS has no {} sub {sub}",
                    info.id,
                    format_index(index)
                )));
            }
            None => None,
        };
        check_sdo_allowed(&self.served, info)?;
        let channel = self.served.registry.sdo(info.id)?;
        let values = self.served.values.clone();
        let node = info.id;
        tracing::info!(
            "node {node} of bus {}: {what} by {} ({})",
            self.served.name,
            caller.who,
            caller.channel
        );
        spawned(async move {
            channel.download(index, sub, signature.as_bytes()).await?;
            if refresh_tpdos && let Err(err) = values.refresh(node).await {
                tracing::warn!("node {node}: TPDO mappings not read again: {err}");
            }
            Ok(())
        })
        .await?;
        Ok(ParameterCommand {
            index,
            sub,
            name,
            signature,
        })
    }

    /// Every parameter of the node's EDS read from the node, as a DCF; an
    /// entry the device would not give is named in a comment.
    pub async fn backup_dcf(&self, caller: &Caller) -> Result<Eds, GatewayError> {
        self.gateway.require(caller, Operation::View)?;
        let eds = self.eds()?;
        check_sdo_allowed(&self.served, &self.info)?;
        let channel = self.served.registry.sdo(self.info.id)?;
        let node = self.info.id;
        let name = self.info.name.clone();
        let (mut dcf, unread) =
            spawned(async move { Ok(dcf::backup(&channel, &eds, node, name).await?) }).await?;
        for entry in &unread {
            dcf.comments.push(format!(
                "{}sub{:X} not read: {}",
                format_index(entry.index),
                entry.sub,
                entry.abort.text()
            ));
        }
        Ok(dcf)
    }

    /// Writes a DCF's parameters to the node, each entry with its result.
    /// A DCF that cannot be read, that the tolerant reader had to correct,
    /// or that is of another product is refused before anything is
    /// written. An entry that switches the node's watchdog off goes
    /// through the same check as an object write (node/watchdog.rs): the
    /// row says so and, once written, `watchdog_off` is given. The
    /// gateway decodes the TPDOs by the mappings restored. Audited, in a
    /// task of its own with its row.
    pub async fn restore_dcf(
        &self,
        caller: &Caller,
        file: &[u8],
    ) -> Result<Vec<RestoredEntry>, GatewayError> {
        let request = format!("{} bytes of DCF", file.len());
        let mut row = self.audit_row(caller, "restore configuration (DCF)", None, Some(request));
        if let Err(error) = self.gateway.admit(caller, Operation::RestoreConfiguration) {
            return refused(row, error).await;
        }
        let restore = match self.plan_restore(file) {
            Ok(restore) => restore,
            Err(error) => return refused(row, error).await,
        };
        let mut watchdog_off = Vec::new();
        for write in restore.plan.writes.iter().filter(|write| !write.invalidate) {
            let (index, sub) = (write.index, write.sub);
            match self
                .watchdog_check(caller, &restore.channel, index, sub, &write.bytes)
                .await
            {
                Ok(WatchdogWrite::SwitchesItOff(warning)) => {
                    row.note(&format!("WATCHDOG SWITCHED OFF: {warning}"));
                    watchdog_off.push((write.entry, warning));
                }
                Ok(WatchdogWrite::KeepsItOn) => {}
                Err(error) => return refused(row, error).await,
            }
        }
        tracing::info!(
            "node {} of bus {}: DCF restored by {} ({})",
            self.info.id,
            self.served.name,
            caller.who,
            caller.channel
        );
        let this = self.clone();
        audited(
            row,
            async move { this.restore(restore, watchdog_off).await },
        )
        .await
    }

    /// A DCF read and checked against the node, and what writing it takes.
    fn plan_restore(&self, file: &[u8]) -> Result<RestorePlan, GatewayError> {
        let info = &self.info;
        let eds = self.eds()?;
        let parsed =
            Eds::parse_bytes(file, "config.dcf").map_err(|error| GatewayError::InvalidDcf {
                message: error.to_string(),
                line: Some(error.line).filter(|line| *line > 0),
            })?;
        // A restore writes the device: what the tolerant reader had to drop
        // or correct is refused rather than guessed.
        if let Some(warning) = parsed
            .warnings
            .iter()
            .find(|warning| matches!(warning.action, Action::Dropped | Action::Corrected))
        {
            return Err(GatewayError::InvalidDcf {
                message: warning.to_string(),
                line: Some(warning.line),
            });
        }
        let invalid = |message: String| GatewayError::InvalidDcf {
            message,
            line: None,
        };
        let (dcf_device, node_device) = (&parsed.device_info, &eds.device_info);
        if let (Some(a), Some(b)) = (dcf_device.vendor_number, node_device.vendor_number)
            && let (Some(c), Some(d)) = (dcf_device.product_number, node_device.product_number)
            && (a, c) != (b, d)
        {
            return Err(invalid(format!(
                "the DCF is of vendor 0x{a:X} product 0x{c:X}, node {} is vendor 0x{b:X} product 0x{d:X}",
                info.id
            )));
        }
        let plan =
            dcf::plan(&parsed, &eds.dictionary, info.id).map_err(|error| invalid(error.0))?;
        check_sdo_allowed(&self.served, info)?;
        let channel = self.served.registry.sdo(info.id)?;
        Ok(RestorePlan {
            parsed,
            plan,
            channel,
        })
    }

    /// Writes a planned restore; `watchdog_off` are the entries that switch
    /// the watchdog off, each warned of once written.
    async fn restore(
        &self,
        restore: RestorePlan,
        watchdog_off: Vec<((u16, u8), String)>,
    ) -> Result<Vec<RestoredEntry>, GatewayError> {
        let RestorePlan {
            parsed,
            plan: dcf::Plan { entries, writes },
            channel,
        } = restore;
        let values = self.served.values.clone();
        let node = self.info.id;
        let this = self.clone();
        let results = spawned(async move {
            let results = dcf::restore(&channel, &writes).await;
            for (entry, warning) in &watchdog_off {
                if matches!(results.get(entry), Some(Some(Ok(())))) {
                    this.warn_watchdog_off(warning);
                }
            }
            // If reading the restored mappings fails, the old ones stay
            // until the next identification; the restore's report stands.
            let tpdo_written = writes
                .iter()
                .any(|write| (0x1800..=0x1BFF).contains(&write.index));
            if tpdo_written && let Err(err) = values.refresh(node).await {
                tracing::warn!("node {node}: TPDO mappings not read again: {err}");
            }
            Ok(results)
        })
        .await?;
        Ok(entries
            .into_iter()
            .map(|(index, sub)| {
                let name = parsed
                    .dictionary
                    .get(index)
                    .map(|object| match object.sub(sub) {
                        Some(described) if object.object_type.has_sub_objects() => {
                            format!("{}/{}", object.name, described.name)
                        }
                        _ => object.name.clone(),
                    })
                    .unwrap_or_default();
                let result = match results.get(&(index, sub)) {
                    Some(Some(result)) => Some(result.clone().map_err(GatewayError::from)),
                    _ => None,
                };
                RestoredEntry {
                    index,
                    sub,
                    name,
                    result,
                }
            })
            .collect())
    }

    /// The node's EDS, without which its parameters are not known.
    fn eds(&self) -> Result<std::sync::Arc<Eds>, GatewayError> {
        self.info
            .eds_entry
            .as_ref()
            .map(|entry| entry.eds.clone())
            .ok_or_else(|| {
                GatewayError::UnknownObject(format!(
                    "node {} has no EDS: its parameters are not known",
                    self.info.id
                ))
            })
    }
}
