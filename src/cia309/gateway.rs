//! What a CiA 309 request does, through the same gateway operations as
//! REST (CiA 309-1 §5, the services a gateway offers): object reads and
//! writes and NMT commands of a [`NodeHandle`], which apply the caller's
//! role and write rate and the node's checks (a node the registry does not
//! know, a stopped node, a bus that is down, a read-only object) and run
//! the transfer on the node's shared SDO queue; and an audit entry in the
//! history for every write and NMT command, whatever its outcome.
//!
//! Used by the CiA 309-3 connections (`candeck ascii`, `--ascii-listen`)
//! and the CiA 309-5 routes of the HTTP server.

use std::sync::Arc;
use std::time::Duration;

use crate::canopen::nmt::NmtCommand;
use crate::canopen::sdo::ClientConfig;
use crate::gateway::access::{Role, Tokens};
use crate::gateway::caller::{Caller, Channel};
use crate::gateway::history::{AuditEntry, History};
use crate::gateway::node::objects::object_item;
use crate::gateway::{Gateway, GatewayError, NodeHandle, ServedBus};

use super::command::Nmt;

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
    /// `ASCII` (CiA 309-3), or the HTTP method of a 309-5 request.
    pub method: &'a str,
    /// The command line, or the 309-5 path.
    pub path: &'a str,
}

impl Origin<'_> {
    /// The door: `ASCII` lines are CiA 309-3's, HTTP requests 309-5's.
    pub fn channel(&self) -> Channel {
        if self.method == "ASCII" {
            Channel::Cia309_3
        } else {
            Channel::Cia309_5
        }
    }

    /// Who sends the request, as the gateway's operations take it.
    pub fn caller(&self) -> Caller {
        let identity = self.identity;
        let caller = Caller::new(self.channel(), identity.who.clone(), identity.access);
        match &identity.peer {
            Some(peer) => caller.with_peer(peer.clone()),
            None => caller,
        }
    }
}

/// The gateway service's buses by CiA 309 net number, and its history.
#[derive(Clone)]
pub struct Cia309Gateway {
    gateway: Gateway,
    buses: Arc<Vec<Arc<ServedBus>>>,
    history: History,
}

impl Cia309Gateway {
    pub fn new(gateway: &Gateway) -> Self {
        Self {
            buses: Arc::new(gateway.buses_in_order()),
            history: gateway.history().clone(),
            gateway: gateway.clone(),
        }
    }

    /// The gateway's tokens and roles.
    pub fn tokens(&self) -> &Tokens {
        self.gateway.tokens()
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

    /// The node `node` of net `net`, as a handle for its operations.
    fn node(&self, net: u16, node: u8) -> Result<NodeHandle, GatewayError> {
        let served = self
            .bus(net)
            .ok_or_else(|| GatewayError::UnknownBus(net.to_string()))?;
        self.gateway.node_handle(served.name(), &node.to_string())
    }

    /// Reads an object for `origin`'s caller: the value's bytes.
    pub async fn read(
        &self,
        origin: Origin<'_>,
        net: u16,
        node: u8,
        index: u16,
        sub: u8,
        options: TransferOptions,
    ) -> Result<Vec<u8>, GatewayError> {
        let settings = move |base: &ClientConfig| options.apply(base);
        self.node(net, node)?
            .read_object_with(&origin.caller(), index, sub, &settings)
            .await
    }

    /// Writes an object for `origin`'s caller, and audits it.
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
    ) -> Result<(), GatewayError> {
        let settings = move |base: &ClientConfig| options.apply(base);
        let result = match self.node(net, node) {
            Ok(handle) => {
                handle
                    .write_object_with(&origin.caller(), index, sub, data, &settings)
                    .await
            }
            Err(error) => Err(error),
        };
        self.audit(
            &origin,
            net,
            Some(node),
            "write object",
            Some(object_item(index, sub)),
            Some(summary),
            result.as_ref().err(),
        )
        .await;
        result
    }

    /// Sends an NMT command for `origin`'s caller (node 0: every node),
    /// and audits it.
    pub async fn nmt(
        &self,
        origin: Origin<'_>,
        net: u16,
        node: u8,
        nmt: Nmt,
    ) -> Result<(), GatewayError> {
        let command = match nmt {
            Nmt::Start => NmtCommand::Start,
            Nmt::Stop => NmtCommand::Stop,
            Nmt::PreOperational => NmtCommand::EnterPreOperational,
            Nmt::ResetNode => NmtCommand::ResetNode,
            Nmt::ResetCommunication => NmtCommand::ResetCommunication,
        };
        let caller = origin.caller();
        let result = if node == 0 {
            match self.bus(net) {
                Some(served) => self.gateway.bus_nmt(&caller, served.name(), command).await,
                None => Err(GatewayError::UnknownBus(net.to_string())),
            }
        } else {
            match self.node(net, node) {
                Ok(handle) => handle.nmt(&caller, command).await,
                Err(error) => Err(error),
            }
        };
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
        result
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
        if let Some(GatewayError::Internal(detail)) = error {
            tracing::error!("cia309: {detail}");
        }
        // 309-3 sends command lines; 309-5 is HTTP.
        let channel = if origin.method == "ASCII" {
            Channel::Cia309_3
        } else {
            Channel::Cia309_5
        };
        let identity = origin.identity;
        let mut caller = Caller::new(channel, identity.who.clone(), identity.access);
        caller.peer = identity.peer.clone();
        let mut entry = AuditEntry::new(&caller, operation)
            .target(
                self.bus(net).map(|bus| bus.name().to_string()),
                node,
                None,
                item,
            )
            .request(request)
            .detail(origin.method, origin.path);
        if let Some(error) = error {
            entry = entry.error(error);
        }
        if let Err(err) = self.history.audit(entry).await {
            tracing::error!(
                "audit: {} {}: not recorded: {err}",
                origin.method,
                origin.path
            );
        }
    }
}
