//! A node's PDOs (CiA 301 §7.2.2) as operations of its handle: the
//! configuration read over SDO, the re-mapping procedure checked against
//! the node's EDS before the bus and followed by the TPDO decoders, and an
//! RPDO sent by its mapping. The protocol work is [`crate::pdo`]'s.

use serde_json::Value as Json;

use super::NodeHandle;
use super::transfer::{audited, refused, spawned};
use crate::caller::Caller;
use crate::canopen::nmt::NmtService;
use crate::canopen::pdo::{PdoKind, PdoMapping};
use crate::error::PdoError;
use crate::pdo::{
    self, DecodedValue, PdoConfig, PdoPlanError, PdoRequest, RemapError, RpdoEncoder,
    RpdoValueError,
};
use crate::policy::Operation;
use crate::{GatewayError, check_sdo_allowed};

/// An RPDO frame sent: its identifier, data and the values it carried.
#[derive(Debug, Clone, PartialEq)]
pub struct RpdoFrame {
    pub cob_id: u32,
    pub data: Vec<u8>,
    pub values: Vec<DecodedValue>,
}

impl NodeHandle {
    /// Every PDO of the node, RPDOs then TPDOs, as configured now (those
    /// its EDS describes; 1–4 of each without EDS).
    pub async fn read_pdos(&self, caller: &Caller) -> Result<Vec<PdoConfig>, GatewayError> {
        self.gateway.require(caller, Operation::View)?;
        check_sdo_allowed(&self.served, &self.info)?;
        let channel = self.served.registry.sdo(self.info.id)?;
        let eds = self.info.eds_entry.clone();
        spawned(async move {
            let dict = eds.as_ref().map(|entry| &entry.eds.dictionary);
            let mut configs = pdo::read_all(&channel, dict, PdoKind::Rpdo).await?;
            configs.extend(pdo::read_all(&channel, dict, PdoKind::Tpdo).await?);
            Ok(configs)
        })
        .await
    }

    /// Configures PDO `number` by the CiA 301 re-mapping procedure, checked
    /// against the node's EDS before the bus is touched, and answers with
    /// the configuration read back. When the device refuses a step, the
    /// error names it ([`GatewayError::FailedAt`]). The gateway decodes a
    /// TPDO by its new mapping from then on. Audited, in a task of its own
    /// with its row.
    pub async fn configure_pdo(
        &self,
        caller: &Caller,
        kind: PdoKind,
        number: u16,
        request: &PdoRequest,
    ) -> Result<PdoConfig, GatewayError> {
        let item = format!("{} {number}", kind.name());
        let row = self.audit_row(caller, "configure pdo", Some(item), None);
        if let Err(error) = self.gateway.admit(caller, Operation::ConfigurePdo) {
            return refused(row, error).await;
        }
        let (this, caller, request) = (self.clone(), caller.clone(), request.clone());
        audited(row, async move {
            this.configure(&caller, kind, number, &request).await
        })
        .await
    }

    /// [`NodeHandle::configure_pdo`] as the gateway's own doing (a step
    /// test's sampling TPDO, set up and put back): the same checks,
    /// procedure and follow-up, in a task of its own with its row, by
    /// [`Caller::system`]; the operation that asks for it admitted its
    /// caller already. `summary`: why, for the row.
    pub(crate) async fn configure_pdo_by_gateway(
        &self,
        kind: PdoKind,
        number: u16,
        request: &PdoRequest,
        summary: String,
    ) -> Result<PdoConfig, GatewayError> {
        let caller = Caller::system();
        let item = format!("{} {number}", kind.name());
        let row = self.audit_row(&caller, "configure pdo", Some(item), Some(summary));
        let (this, request) = (self.clone(), request.clone());
        audited(row, async move {
            this.configure(&caller, kind, number, &request).await
        })
        .await
    }

    /// The node's TPDOs as configured now, read for the gateway's own use
    /// (no caller: [`NodeHandle::read_pdos`] is the callers' operation).
    pub(crate) async fn read_tpdos_by_gateway(&self) -> Result<Vec<PdoConfig>, GatewayError> {
        check_sdo_allowed(&self.served, &self.info)?;
        let channel = self.served.registry.sdo(self.info.id)?;
        let eds = self.info.eds_entry.clone();
        spawned(async move {
            let dict = eds.as_ref().map(|entry| &entry.eds.dictionary);
            Ok(pdo::read_all(&channel, dict, PdoKind::Tpdo).await?)
        })
        .await
    }

    async fn configure(
        &self,
        caller: &Caller,
        kind: PdoKind,
        number: u16,
        request: &PdoRequest,
    ) -> Result<PdoConfig, GatewayError> {
        let eds = self.info.eds_entry.clone().ok_or_else(|| {
            PdoError::InvalidMapping(format!(
                "node {} has no EDS: a mapping cannot be checked before the bus",
                self.info.id
            ))
        })?;
        let plan = pdo::plan(&eds.eds, kind, number, request).map_err(plan_error)?;
        check_sdo_allowed(&self.served, &self.info)?;
        let channel = self.served.registry.sdo(self.info.id)?;
        let values = self.served.values.clone();
        let node = self.info.id;
        tracing::info!(
            "node {node} of bus {}: {} {number} re-mapped by {} ({})",
            self.served.name,
            kind.name(),
            caller.who,
            caller.channel
        );
        spawned(async move {
            // Another re-mapping of this node must not interleave its steps.
            let _procedure = channel.procedure().await;
            let config = pdo::configure(&channel, Some(&eds.eds.dictionary), &plan)
                .await
                .map_err(|RemapError { step, error }| GatewayError::FailedAt {
                    step: step.to_string(),
                    source: Box::new(error.into()),
                })?;
            // If reading the new mapping fails, the values keep the old one
            // until the node's next identification; the PDO answer stands.
            if kind == PdoKind::Tpdo
                && let Err(err) = values.refresh(node).await
            {
                tracing::warn!("node {node}: TPDO mappings not read again: {err}");
            }
            Ok(config)
        })
        .await
    }

    /// Sends RPDO `number` with `values` (by the EDS name of each mapped
    /// object, or `"0x6040"`, `"0x6040:0"`): its mapping and COB-ID are
    /// read from the node, and every mapped object must be given a value,
    /// typed and checked by the EDS. A node whose heartbeat says it is not
    /// operational would ignore the frame: refused. Audited, in a task of
    /// its own with its row.
    pub async fn send_rpdo(
        &self,
        caller: &Caller,
        number: u16,
        values: &serde_json::Map<String, Json>,
    ) -> Result<RpdoFrame, GatewayError> {
        let request = serde_json::json!({ "values": values }).to_string();
        let row = self.audit_row(
            caller,
            "send rpdo",
            Some(format!("rpdo {number}")),
            Some(request),
        );
        if let Err(error) = self.gateway.admit(caller, Operation::SendRpdo) {
            return refused(row, error).await;
        }
        let (this, caller, values) = (self.clone(), caller.clone(), values.clone());
        audited(
            row,
            async move { this.send(&caller, number, &values).await },
        )
        .await
    }

    async fn send(
        &self,
        caller: &Caller,
        number: u16,
        values: &serde_json::Map<String, Json>,
    ) -> Result<RpdoFrame, GatewayError> {
        let info = &self.info;
        let eds = info.eds_entry.clone().ok_or_else(|| {
            PdoError::InvalidMapping(format!(
                "node {} has no EDS: the mapped objects' types are unknown",
                info.id
            ))
        })?;
        let dict = &eds.eds.dictionary;
        if !pdo::has_pdo(Some(dict), PdoKind::Rpdo, number) {
            return Err(PdoError::UnknownPdo(format!("the node has no RPDO {number}")).into());
        }
        check_sdo_allowed(&self.served, info)?;
        // The state is current only for a node that sends heartbeats; without
        // them, the last one heard may predate an NMT start.
        if let Some(state) = info
            .nmt
            .filter(|state| info.heartbeat_ms.is_some() && !state.allows(NmtService::Pdo))
        {
            return Err(GatewayError::WrongNmtState {
                node: info.id.get(),
                state,
            });
        }
        let channel = self.served.registry.sdo(info.id)?;
        let task_eds = eds.clone();
        let config = spawned(async move {
            let dict = Some(&task_eds.eds.dictionary);
            Ok(pdo::read_config(&channel, dict, PdoKind::Rpdo, number).await?)
        })
        .await?;
        let cob_id = match config.cob_id() {
            Some(cob_id) if cob_id.valid => cob_id,
            _ => {
                return Err(PdoError::PdoDisabled(format!(
                    "RPDO {number} of node {} is not valid (COB-ID 0x{:08X}): enable it with PUT .../pdos/rpdo/{number}",
                    info.id, config.cob_id_raw
                ))
                .into());
            }
        };
        let mapping = PdoMapping::new(config.mapping.clone()).map_err(|err| {
            PdoError::PdoDisabled(format!("RPDO {number} has no usable mapping: {err}"))
        })?;
        let encoder = RpdoEncoder::new(cob_id.id, mapping, Some(dict), Some(info.id));
        let (frame, values) = encoder
            .encode(values, Some(dict))
            .map_err(rpdo_value_error)?;
        self.served.bus.send(frame).await?;
        tracing::debug!(
            "node {} of bus {}: RPDO {number} sent by {} ({})",
            info.id,
            self.served.name,
            caller.who,
            caller.channel
        );
        Ok(RpdoFrame {
            cob_id: cob_id.id.raw(),
            data: frame.data().to_vec(),
            values,
        })
    }
}

fn plan_error(err: PdoPlanError) -> GatewayError {
    let message = err.to_string();
    if err.is_unknown_pdo() {
        PdoError::UnknownPdo(message).into()
    } else if err.is_out_of_range() {
        GatewayError::ValueOutOfRange(message)
    } else {
        PdoError::InvalidMapping(message).into()
    }
}

fn rpdo_value_error(err: RpdoValueError) -> GatewayError {
    let message = err.to_string();
    match err {
        RpdoValueError::OutOfRange { .. } => GatewayError::ValueOutOfRange(message),
        RpdoValueError::Untyped(_) => PdoError::InvalidMapping(message).into(),
        _ => GatewayError::InvalidValue(message),
    }
}
