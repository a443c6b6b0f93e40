//! What a CiA 309 request does, through the same gateway operations as
//! REST (CiA 309-1 §5, the services a gateway offers): object reads and
//! writes and NMT commands of a [`NodeHandle`], which apply the caller's
//! role and write rate and the node's checks (a node the registry does not
//! know, a stopped node, a bus that is down, a read-only object) and run
//! the transfer on the node's shared SDO queue, and write their audit row
//! for every write and NMT command, whatever its outcome (the door adds its
//! method and command line or path, and a value's summary); what no
//! operation audited (a net or node not known, a line refused) is audited
//! here, once.
//!
//! Used by the CiA 309-3 connections (`candeck ascii`, `--ascii-listen`)
//! and the CiA 309-5 routes of the HTTP server.

use std::sync::Arc;
use std::time::Duration;

use crate::canopen::nmt::NmtCommand;
use crate::canopen::sdo::ClientConfig;
use crate::gateway::{AuditTarget, DoorDetail};
use crate::gateway::{Caller, Channel};
use crate::gateway::{Gateway, GatewayError, NodeHandle, ServedBus};
use crate::gateway::{Role, Tokens};
use crate::gateway::{nmt_summary, object_item};

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

    /// Who sends the request, as the gateway's operations take it, with
    /// the method and command line (or path) as the door's words for its
    /// audit row.
    pub fn caller(&self) -> Caller {
        self.caller_with(None)
    }

    /// [`Origin::caller`], with the door's own summary of the request (a
    /// value as `u16 1000`).
    pub fn caller_with(&self, summary: Option<String>) -> Caller {
        let identity = self.identity;
        let detail = DoorDetail::new(self.method, self.path).summary(summary);
        let caller =
            Caller::new(self.channel(), identity.who.clone(), identity.access).with_detail(detail);
        match &identity.peer {
            Some(peer) => caller.with_peer(peer.clone()),
            None => caller,
        }
    }
}

/// The gateway service's buses by CiA 309 net number.
#[derive(Clone)]
pub struct Cia309Gateway {
    gateway: Gateway,
    buses: Arc<Vec<Arc<ServedBus>>>,
}

impl Cia309Gateway {
    pub fn new(gateway: &Gateway) -> Self {
        Self {
            buses: Arc::new(gateway.buses_in_order()),
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

    /// Writes an object for `origin`'s caller. The gateway's write audits
    /// it, with `summary` (the value as the command gave it) as the
    /// request; a net or node not known is audited here.
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
        let caller = origin.caller_with(Some(summary));
        let target = self
            .target(net, Some(node), "write object")
            .item(object_item(index, sub));
        let work = async {
            self.node(net, node)?
                .write_object_with(&caller, index, sub, data, &settings)
                .await
        };
        let result = self
            .gateway
            .audited_by_door(&caller, target, None, work)
            .await;
        log_internal(&result);
        result
    }

    /// Sends an NMT command for `origin`'s caller (node 0: every node). The
    /// gateway's NMT operation audits it; a net or node not known is
    /// audited here.
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
        let (operation, node) = if node == 0 {
            ("nmt command to all nodes", None)
        } else {
            ("nmt command", Some(node))
        };
        let target = self.target(net, node, operation);
        let work = async {
            match (node, self.bus(net)) {
                (_, None) => Err(GatewayError::UnknownBus(net.to_string())),
                (None, Some(served)) => self.gateway.bus_nmt(&caller, served.name(), command).await,
                (Some(node), Some(_)) => self.node(net, node)?.nmt(&caller, command).await,
            }
        };
        let result = self
            .gateway
            .audited_by_door(&caller, target, Some(nmt_summary(command)), work)
            .await;
        log_internal(&result);
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
        let target = self.target(net, node, &format!("{what} (refused)"));
        let result = Err::<(), _>(error.clone());
        log_internal(&result);
        self.gateway
            .door_audit_row(&origin.caller(), target, None)
            .finish(&result)
            .await;
    }

    /// What a command acts on, for its audit row: the bus of `net` (none
    /// when it is not known).
    fn target(&self, net: u16, node: Option<u8>, operation: &str) -> AuditTarget {
        let mut target = AuditTarget::new(operation).node(node);
        target.bus = self.bus(net).map(|bus| bus.name().to_string());
        target
    }
}

/// An internal fault is for the log too (the client hears a generic error).
fn log_internal<T>(result: &Result<T, GatewayError>) {
    if let Err(GatewayError::Internal(detail)) = result {
        tracing::error!("cia309: {detail}");
    }
}
