//! What a CiA 309 request does, through the same gateway as REST (CiA
//! 309-1 §5, the services a gateway offers): SDO transfers on the node's
//! shared channel ([`crate::gateway::sdo::SdoChannel`], the per-node queue
//! REST uses), NMT through REST's own sender, the same checks (a node the
//! registry does not know, a stopped node, a bus that is down), and an
//! audit entry in the history for every write and NMT command, whatever
//! its outcome.
//!
//! Used by the CiA 309-3 connections ([`super::serve`]) and the CiA 309-5
//! routes ([`crate::api::cia309_5`]).

use std::sync::Arc;
use std::time::Duration;

use crate::api::auth::{Guard, Role};
use crate::api::{AppError, AppState, ServedBus};
use crate::can::Timestamp;
use crate::canopen::NodeId;
use crate::canopen::nmt::{NmtCommand, NmtTarget};
use crate::canopen::sdo::{AbortCode, ClientConfig};
use crate::gateway::history::{AuditEntry, History};

use super::command::Nmt;
use super::reply::ErrorCode;

/// Who sends a connection's (or a request's) commands, for the audit log.
/// Authentication fills it in from a token; until then it names the peer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// `ascii:127.0.0.1:54321`, a token's name, ...
    pub who: String,
    /// The role the commands run with (`none` without authentication).
    pub role: String,
    /// The client's address, when there is one.
    pub peer: Option<String>,
    /// The role a token gave the connection (`auth TOKEN`), checked when
    /// the gateway has tokens.
    pub access: Option<Role>,
}

impl Identity {
    /// A client known only by its address.
    pub fn anonymous(protocol: &str, peer: Option<String>) -> Self {
        let who = match &peer {
            Some(peer) => format!("{protocol}:{peer}"),
            None => protocol.to_string(),
        };
        Self {
            who,
            role: "none".to_string(),
            peer,
            access: None,
        }
    }
}

/// Why a request failed, as CiA 309 answers it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Failure {
    /// `ERROR:0x<abort code>`: the device's abort, or the client's
    /// (0x05040000 on a timeout).
    Abort(AbortCode),
    /// `ERROR:<number>`.
    Error(ErrorCode),
}

impl Failure {
    /// A REST error as CiA 309 says it.
    fn of(error: &AppError) -> Self {
        match error {
            AppError::SdoAbort { code, .. } => Self::Abort(*code),
            AppError::SdoProtocol { code, .. } => Self::Abort(*code),
            AppError::SdoTimeout { .. } => Self::Abort(AbortCode::from_raw(0x0504_0000)),
            AppError::WrongNmtState { .. } => Self::Error(ErrorCode::WrongNmtState),
            AppError::UnknownNode { .. } | AppError::InvalidRequest(_) => {
                Self::Error(ErrorCode::UnsupportedNode)
            }
            AppError::UnknownBus(_) => Self::Error(ErrorCode::UnsupportedNet),
            _ => Self::Error(ErrorCode::InternalState),
        }
    }
}

/// A client's own SDO settings (`set sdo_timeout`, `set sdo_block`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TransferOptions {
    /// `None`: the gateway's timeout.
    pub timeout: Option<Duration>,
    /// Block transfers: uploads by block upload, and downloads of more
    /// than [`BLOCK_THRESHOLD`] bytes by block download (CANopenNode's
    /// rule; smaller values go expedited or segmented either way).
    pub block: bool,
}

/// The size up to which block transfers fall back to expedited or
/// segmented ones (CANopenNode's `CO_CONFIG_SDO_CLI_PST`, 21 bytes).
pub const BLOCK_THRESHOLD: u8 = 21;

impl TransferOptions {
    /// The configuration of one transfer: the channel's with these
    /// settings; `None` when they change nothing.
    pub fn apply(&self, base: &ClientConfig) -> Option<ClientConfig> {
        if *self == Self::default() {
            return None;
        }
        let mut config = base.clone();
        if let Some(timeout) = self.timeout {
            config.timeout = timeout;
        }
        if self.block {
            config.use_block_upload = true;
            config.switch_threshold = BLOCK_THRESHOLD;
            config.use_block_download_from = Some(usize::from(BLOCK_THRESHOLD) + 1);
        }
        Some(config)
    }
}

/// How a request was made, for its audit entry.
#[derive(Debug, Clone)]
pub struct Origin<'a> {
    pub identity: &'a Identity,
    /// `ASCII`, or the HTTP method of a 309-5 request.
    pub method: &'a str,
    /// The command line, or the 309-5 path.
    pub path: &'a str,
}

/// The buses by CiA 309 net number, and the history.
#[derive(Clone)]
pub struct Gateway {
    buses: Arc<Vec<Arc<ServedBus>>>,
    history: History,
    /// The tokens and roles of the REST API: the same apply here.
    guard: Arc<Guard>,
}

impl Gateway {
    pub fn new(state: &AppState) -> Self {
        Self {
            buses: Arc::new(state.buses_in_order()),
            history: state.history.clone(),
            guard: state.guard.clone(),
        }
    }

    /// The gateway's tokens and roles.
    pub fn guard(&self) -> &Guard {
        &self.guard
    }

    /// How many nets there are (1 to this).
    pub fn networks(&self) -> u16 {
        self.buses.len().min(u16::MAX.into()) as u16
    }

    /// The buses, net 1 first.
    pub fn buses(&self) -> &[Arc<ServedBus>] {
        &self.buses
    }

    /// The bus of a net, 1-based.
    pub fn bus(&self, net: u16) -> Option<&Arc<ServedBus>> {
        usize::from(net)
            .checked_sub(1)
            .and_then(|at| self.buses.get(at))
    }

    /// Reads an object: the value's bytes.
    pub async fn read(
        &self,
        net: u16,
        node: u8,
        index: u16,
        sub: u8,
        options: TransferOptions,
    ) -> Result<Vec<u8>, Failure> {
        self.upload(net, node, index, sub, options)
            .await
            .map_err(|error| Failure::of(&error))
    }

    async fn upload(
        &self,
        net: u16,
        node: u8,
        index: u16,
        sub: u8,
        options: TransferOptions,
    ) -> Result<Vec<u8>, AppError> {
        let (_, channel) = self.channel(net, node)?;
        let config = options.apply(channel.config());
        // In a task of its own, as REST does: a client that goes away
        // mid-transfer does not cut it halfway.
        tokio::spawn(async move { channel.upload_with(index, sub, config.as_ref()).await })
            .await
            .map_err(|err| AppError::Internal(format!("SDO task: {err}")))?
            .map_err(AppError::from_sdo)
    }

    /// Writes an object, and audits it.
    #[allow(clippy::too_many_arguments)]
    pub async fn write(
        &self,
        origin: Origin<'_>,
        net: u16,
        node: u8,
        index: u16,
        sub: u8,
        data: Vec<u8>,
        summary: String,
        options: TransferOptions,
    ) -> Result<(), Failure> {
        let result = self.download(net, node, index, sub, data, options).await;
        self.audit(
            &origin,
            net,
            Some(node),
            "write object",
            Some(format!("0x{index:04X}:{sub}")),
            Some(summary),
            result.as_ref().err(),
        )
        .await;
        result.map_err(|error| Failure::of(&error))
    }

    async fn download(
        &self,
        net: u16,
        node: u8,
        index: u16,
        sub: u8,
        data: Vec<u8>,
        options: TransferOptions,
    ) -> Result<(), AppError> {
        let (_, channel) = self.channel(net, node)?;
        let config = options.apply(channel.config());
        tokio::spawn(async move {
            channel
                .download_with(index, sub, &data, config.as_ref())
                .await
        })
        .await
        .map_err(|err| AppError::Internal(format!("SDO task: {err}")))?
        .map_err(AppError::from_sdo)
    }

    /// Sends an NMT command (node 0: every node), and audits it.
    pub async fn nmt(
        &self,
        origin: Origin<'_>,
        net: u16,
        node: u8,
        nmt: Nmt,
    ) -> Result<(), Failure> {
        let command = match nmt {
            Nmt::Start => NmtCommand::Start,
            Nmt::Stop => NmtCommand::Stop,
            Nmt::PreOperational => NmtCommand::EnterPreOperational,
            Nmt::ResetNode => NmtCommand::ResetNode,
            Nmt::ResetCommunication => NmtCommand::ResetCommunication,
        };
        let result = self.send_nmt(net, node, command).await;
        let operation = if node == 0 {
            "nmt command to all nodes"
        } else {
            "nmt command"
        };
        self.audit(
            &origin,
            net,
            (node != 0).then_some(node),
            operation,
            None,
            Some(format!("{{\"command\":\"{}\"}}", command.name())),
            result.as_ref().err(),
        )
        .await;
        result.map_err(|error| Failure::of(&error))
    }

    async fn send_nmt(&self, net: u16, node: u8, command: NmtCommand) -> Result<(), AppError> {
        let served = self
            .bus(net)
            .ok_or_else(|| AppError::UnknownBus(net.to_string()))?;
        let target = if node == 0 {
            NmtTarget::All
        } else {
            NmtTarget::Node(
                NodeId::new(node).map_err(|err| AppError::InvalidRequest(err.to_string()))?,
            )
        };
        crate::api::nodes::send_nmt(served, command, target).await
    }

    /// The node's shared SDO channel, after REST's checks.
    fn channel(
        &self,
        net: u16,
        node: u8,
    ) -> Result<(Arc<ServedBus>, crate::gateway::sdo::SdoChannel), AppError> {
        let served = self
            .bus(net)
            .ok_or_else(|| AppError::UnknownBus(net.to_string()))?
            .clone();
        let id = NodeId::new(node).map_err(|err| AppError::InvalidRequest(err.to_string()))?;
        let info = served
            .registry
            .node(id)
            .ok_or_else(|| AppError::UnknownNode {
                bus: served.name.clone(),
                node: node.to_string(),
            })?;
        crate::api::od::check_sdo_allowed(&served, &info)?;
        let channel = served.registry.sdo(id)?;
        Ok((served, channel))
    }

    /// Records a command refused for the connection's role (or for want
    /// of a token), as the REST API's guard records its 401 and 403.
    pub async fn audit_refused(&self, origin: Origin<'_>, net: u16, node: Option<u8>, what: &str) {
        let error = if origin.identity.access.is_some() {
            AppError::Forbidden(format!(
                "{what} needs a higher role than {}",
                origin.identity.role
            ))
        } else {
            AppError::Unauthenticated(format!("{what} needs a token: send 'auth TOKEN' first"))
        };
        let operation = format!("{what} (refused)");
        self.audit(&origin, net, node, &operation, None, None, Some(&error))
            .await;
    }

    #[allow(clippy::too_many_arguments)]
    async fn audit(
        &self,
        origin: &Origin<'_>,
        net: u16,
        node: Option<u8>,
        operation: &str,
        item: Option<String>,
        request: Option<String>,
        error: Option<&AppError>,
    ) {
        let (status, error_code, abort_code) = match error {
            None => (200, None, None),
            Some(error) => {
                let body = error.to_json();
                (
                    error.status().as_u16(),
                    body["code"].as_str().map(str::to_string),
                    body["abort_code"].as_str().map(str::to_string),
                )
            }
        };
        let entry = AuditEntry {
            time: Timestamp::now(),
            who: origin.identity.who.clone(),
            peer: origin.identity.peer.clone(),
            role: origin.identity.role.clone(),
            method: origin.method.to_string(),
            path: origin.path.to_string(),
            operation: operation.to_string(),
            bus: self.bus(net).map(|bus| bus.name.clone()),
            node,
            axis: None,
            item,
            request,
            status,
            error_code,
            abort_code,
        };
        if let Err(err) = self.history.audit(entry).await {
            tracing::error!(
                "audit: {} {}: not recorded: {err}",
                origin.method,
                origin.path
            );
        }
    }
}
