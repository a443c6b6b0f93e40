//! What a CiA 309 request does, through the same gateway service as REST
//! (CiA 309-1 §5, the services a gateway offers): SDO transfers on the
//! node's shared channel ([`crate::gateway::sdo::SdoChannel`], the per-node
//! queue REST uses), NMT through the service's sender, the same checks (a
//! node the registry does not know, a stopped node, a bus that is down),
//! and an audit entry in the history for every write and NMT command,
//! whatever its outcome.
//!
//! Used by the CiA 309-3 connections (`candeck ascii`, `--ascii-listen`)
//! and the CiA 309-5 routes of the HTTP server.

use std::sync::Arc;
use std::time::Duration;

use crate::can::Timestamp;
use crate::canopen::NodeId;
use crate::canopen::nmt::{NmtCommand, NmtTarget};
use crate::canopen::sdo::ClientConfig;
use crate::gateway::access::{Role, Tokens, WriteLimiter};
use crate::gateway::history::{AuditEntry, History};
use crate::gateway::registry::NodeInfo;
use crate::gateway::{Gateway, GatewayError, ServedBus, check_sdo_allowed, check_writable};

use super::command::Nmt;
use super::failure::Failure;

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

/// The gateway service's buses by CiA 309 net number, and its history.
#[derive(Clone)]
pub struct Cia309Gateway {
    buses: Arc<Vec<Arc<ServedBus>>>,
    history: History,
    /// The gateway's tokens and roles: the same as REST's.
    tokens: Arc<Tokens>,
    /// The write rate limit per token: the same buckets as REST's.
    writes: Arc<WriteLimiter>,
}

impl Cia309Gateway {
    pub fn new(gateway: &Gateway) -> Self {
        Self {
            buses: Arc::new(gateway.buses_in_order()),
            history: gateway.history.clone(),
            tokens: gateway.tokens.clone(),
            writes: gateway.writes.clone(),
        }
    }

    /// The gateway's tokens and roles.
    pub fn tokens(&self) -> &Tokens {
        &self.tokens
    }

    /// Whether a client holding `held` may send a command that needs
    /// `needed` (anyone may on an open gateway).
    pub fn allows(&self, held: Option<Role>, needed: Role) -> bool {
        self.tokens.allows(held, needed)
    }

    /// Takes one write (an SDO write, an NMT command) of `identity` from
    /// the write rate limit REST applies to the same token; an open gateway
    /// (no tokens) has none.
    pub fn take_write(&self, identity: &Identity) -> Result<(), GatewayError> {
        if !self.tokens.required() {
            return Ok(());
        }
        self.writes.take_or_refuse(&identity.who)
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
    ) -> Result<Vec<u8>, GatewayError> {
        let (_, _, channel) = self.channel(net, node)?;
        let config = options.apply(channel.config());
        // In a task of its own, as REST does: a client that goes away
        // mid-transfer does not cut it halfway.
        tokio::spawn(async move { channel.upload_with(index, sub, config.as_ref()).await })
            .await
            .map_err(|err| GatewayError::Internal(format!("SDO task: {err}")))?
            .map_err(GatewayError::from)
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
    ) -> Result<(), GatewayError> {
        let (_, info, channel) = self.channel(net, node)?;
        check_writable(&info, index, sub)?;
        let config = options.apply(channel.config());
        tokio::spawn(async move {
            channel
                .download_with(index, sub, &data, config.as_ref())
                .await
        })
        .await
        .map_err(|err| GatewayError::Internal(format!("SDO task: {err}")))?
        .map_err(GatewayError::from)
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

    async fn send_nmt(&self, net: u16, node: u8, command: NmtCommand) -> Result<(), GatewayError> {
        let served = self
            .bus(net)
            .ok_or_else(|| GatewayError::UnknownBus(net.to_string()))?;
        let target = if node == 0 {
            NmtTarget::All
        } else {
            NmtTarget::Node(
                NodeId::new(node).map_err(|err| GatewayError::InvalidRequest(err.to_string()))?,
            )
        };
        served.send_nmt(command, target).await
    }

    /// The node and its shared SDO channel, after the gateway's checks.
    fn channel(
        &self,
        net: u16,
        node: u8,
    ) -> Result<(Arc<ServedBus>, NodeInfo, crate::gateway::sdo::SdoChannel), GatewayError> {
        let served = self
            .bus(net)
            .ok_or_else(|| GatewayError::UnknownBus(net.to_string()))?
            .clone();
        let id = NodeId::new(node).map_err(|err| GatewayError::InvalidRequest(err.to_string()))?;
        let info = served
            .registry
            .node(id)
            .ok_or_else(|| GatewayError::UnknownNode {
                bus: served.name.clone(),
                node: node.to_string(),
            })?;
        check_sdo_allowed(&served, &info)?;
        let channel = served.registry.sdo(id)?;
        Ok((served, info, channel))
    }

    /// Records a command refused for the connection's role (or for want
    /// of a token), as the REST API's guard records its 401 and 403.
    pub async fn audit_refused(&self, origin: Origin<'_>, net: u16, node: Option<u8>, what: &str) {
        let error = if origin.identity.access.is_some() {
            GatewayError::Forbidden(format!(
                "{what} needs a higher role than {}",
                origin.identity.role
            ))
        } else {
            GatewayError::Unauthenticated(format!("{what} needs a token: send 'auth TOKEN' first"))
        };
        let operation = format!("{what} (refused)");
        self.audit(&origin, net, node, &operation, None, None, Some(&error))
            .await;
    }

    /// Records a command refused before it ran for `error` (a line the
    /// parser refused, a write over the rate limit); `net` 0 when the
    /// line's net is not known.
    pub async fn audit_rejected(
        &self,
        origin: Origin<'_>,
        net: u16,
        node: Option<u8>,
        what: &str,
        error: &GatewayError,
    ) {
        let operation = format!("{what} (refused)");
        self.audit(&origin, net, node, &operation, None, None, Some(error))
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
        error: Option<&GatewayError>,
    ) {
        let (status, error_code, abort_code) = match error {
            None => (200, None, None),
            Some(error) => {
                if let GatewayError::Internal(detail) = error {
                    tracing::error!("cia309: {detail}");
                }
                (
                    error.audit_status(),
                    Some(error.code().to_string()),
                    error
                        .abort_code()
                        .map(|code| format!("0x{:08X}", code.raw())),
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
