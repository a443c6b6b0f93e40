//! Network management, NMT (CiA 301 §7.2.8): the node-control commands a
//! master sends on COB-ID 0x000 (§7.2.8.3.1), the NMT states a node reports in
//! its heartbeat and its boot-up message (§7.2.8.3.2), and the state machine
//! an NMT slave runs (§7.3.2).
//!
//! Which services a node may use in which state follows CiA 301 table 84 as
//! the UniSwarm UMC firmware manual restates it in figure 3.9: PDOs only when
//! operational; SDO, SYNC, EMCY (and TIME) when pre-operational or
//! operational; node guarding and heartbeat in every state but
//! initialisation. [`NmtState::allows`] is that table.
//!
//! A reset is not carried out here: the slave reports it as an
//! [`NmtEvent`] so the device can reload its parameters, and only then calls
//! [`NmtSlave::boot_up`], which sends the boot-up message and enters
//! pre-operational, in the order CiA 301 figure 48 prescribes.

use std::fmt;
use std::str::FromStr;

use super::cob::{Function, NodeId};
use crate::can::{CanId, Frame};

/// The COB-ID of the NMT node-control message (highest priority on the bus).
pub const NMT_COB_ID: u16 = 0x000;

/// An NMT command specifier, byte 0 of the NMT message. The doc of each
/// variant gives its wire value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtCommand {
    /// 0x01: start remote node, enter operational.
    Start,
    /// 0x02: stop remote node, enter stopped.
    Stop,
    /// 0x80: enter pre-operational.
    EnterPreOperational,
    /// 0x81: reset node: application and communication parameters are
    /// reloaded, then the node boots up again.
    ResetNode,
    /// 0x82: reset communication: communication parameters (0x1000–0x1FFF)
    /// are reloaded, then the node boots up again.
    ResetCommunication,
    /// Any other specifier. CiA 301 slaves ignore it.
    Unknown(u8),
}

impl NmtCommand {
    /// The five commands CiA 301 defines, in wire-value order.
    pub const ALL: [NmtCommand; 5] = [
        Self::Start,
        Self::Stop,
        Self::EnterPreOperational,
        Self::ResetNode,
        Self::ResetCommunication,
    ];

    pub fn from_raw(raw: u8) -> Self {
        match raw {
            0x01 => Self::Start,
            0x02 => Self::Stop,
            0x80 => Self::EnterPreOperational,
            0x81 => Self::ResetNode,
            0x82 => Self::ResetCommunication,
            other => Self::Unknown(other),
        }
    }

    pub fn raw(self) -> u8 {
        match self {
            Self::Start => 0x01,
            Self::Stop => 0x02,
            Self::EnterPreOperational => 0x80,
            Self::ResetNode => 0x81,
            Self::ResetCommunication => 0x82,
            Self::Unknown(raw) => raw,
        }
    }

    /// The name the REST API uses: `start`, `stop`, `pre_operational`, `reset_node`,
    /// `reset_communication` (`unknown` for other specifiers).
    pub fn name(self) -> &'static str {
        match self {
            Self::Start => "start",
            Self::Stop => "stop",
            Self::EnterPreOperational => "pre_operational",
            Self::ResetNode => "reset_node",
            Self::ResetCommunication => "reset_communication",
            Self::Unknown(_) => "unknown",
        }
    }

    /// Reads a command name as the REST API (`reset_node`) or the command line
    /// (`reset-node`) spells it.
    pub fn from_name(name: &str) -> Option<Self> {
        let name = name.trim().to_ascii_lowercase().replace('-', "_");
        Self::ALL.into_iter().find(|command| command.name() == name)
    }

    /// The state a node is in right after obeying this command. A reset ends
    /// in [`NmtState::BootUp`]: the node reloads its parameters, sends its
    /// boot-up message and only then is pre-operational. `None` for unknown
    /// commands, which change nothing.
    pub fn target_state(self) -> Option<NmtState> {
        match self {
            Self::Start => Some(NmtState::Operational),
            Self::Stop => Some(NmtState::Stopped),
            Self::EnterPreOperational => Some(NmtState::PreOperational),
            Self::ResetNode | Self::ResetCommunication => Some(NmtState::BootUp),
            Self::Unknown(_) => None,
        }
    }
}

impl fmt::Display for NmtCommand {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Unknown(raw) => write!(f, "unknown (0x{raw:02X})"),
            known => f.write_str(known.name()),
        }
    }
}

impl FromStr for NmtCommand {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        Self::from_name(text).ok_or_else(|| {
            format!(
                "unknown NMT command '{text}': expected start, stop, pre_operational, \
                 reset_node or reset_communication"
            )
        })
    }
}

/// An NMT state as a node reports it: the heartbeat byte, the state bits of a
/// node-guarding reply. The doc of each variant gives its wire value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtState {
    /// 0x00: initialisation finished; only ever seen in the boot-up message.
    BootUp,
    /// 0x04: stopped: only NMT and error control (heartbeat, node guarding).
    Stopped,
    /// 0x05: operational: every service, PDOs included.
    Operational,
    /// 0x7F: pre-operational: everything but PDOs.
    PreOperational,
    /// Any other value (CiA 320's sleep 0x50 and standby 0x60, or garbage).
    Unknown(u8),
}

impl NmtState {
    pub fn from_raw(raw: u8) -> Self {
        match raw {
            0x00 => Self::BootUp,
            0x04 => Self::Stopped,
            0x05 => Self::Operational,
            0x7F => Self::PreOperational,
            other => Self::Unknown(other),
        }
    }

    pub fn raw(self) -> u8 {
        match self {
            Self::BootUp => 0x00,
            Self::Stopped => 0x04,
            Self::Operational => 0x05,
            Self::PreOperational => 0x7F,
            Self::Unknown(raw) => raw,
        }
    }

    /// The name the REST API uses: `boot_up`, `stopped`, `operational`,
    /// `pre_operational`, `unknown`.
    pub fn name(self) -> &'static str {
        match self {
            Self::BootUp => "boot_up",
            Self::Stopped => "stopped",
            Self::Operational => "operational",
            Self::PreOperational => "pre_operational",
            Self::Unknown(_) => "unknown",
        }
    }

    /// Whether a node in this state may use `service` (CiA 301 table 84,
    /// UMC manual figure 3.9). An unknown state allows nothing.
    pub fn allows(self, service: NmtService) -> bool {
        use NmtService as S;
        match self {
            Self::BootUp => matches!(service, S::BootUp),
            Self::PreOperational => !matches!(service, S::Pdo | S::BootUp),
            Self::Operational => !matches!(service, S::BootUp),
            Self::Stopped => matches!(service, S::Nmt | S::NodeGuarding | S::Heartbeat),
            Self::Unknown(_) => false,
        }
    }
}

impl fmt::Display for NmtState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Unknown(raw) => write!(f, "unknown (0x{raw:02X})"),
            known => f.write_str(known.name()),
        }
    }
}

/// The communication services whose use depends on the NMT state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtService {
    /// Process data objects, RPDO and TPDO.
    Pdo,
    /// Service data objects, server and client.
    Sdo,
    /// Producing or consuming SYNC.
    Sync,
    /// Producing EMCY messages.
    Emcy,
    /// The TIME stamp object.
    Time,
    /// Answering or sending node-guarding requests.
    NodeGuarding,
    /// Producing heartbeats.
    Heartbeat,
    /// The boot-up message, sent once at the end of initialisation.
    BootUp,
    /// Obeying NMT node-control commands.
    Nmt,
}

/// Whom an NMT command addresses: byte 1 of the NMT message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtTarget {
    /// 0x00: every node on the bus.
    All,
    /// 0x01–0x7F: one node.
    Node(NodeId),
}

impl NmtTarget {
    pub fn from_raw(raw: u8) -> Result<Self, NmtError> {
        match raw {
            0 => Ok(Self::All),
            id => NodeId::new(id)
                .map(Self::Node)
                .map_err(|_| NmtError::NodeId(id)),
        }
    }

    pub fn raw(self) -> u8 {
        match self {
            Self::All => 0,
            Self::Node(node) => node.get(),
        }
    }

    /// Whether a command to this target is meant for `node`.
    pub fn includes(self, node: NodeId) -> bool {
        match self {
            Self::All => true,
            Self::Node(target) => target == node,
        }
    }
}

/// Why a frame is not a well-formed NMT command.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NmtError {
    #[error("identifier {0} is not the NMT COB-ID 000")]
    NotNmt(CanId),
    #[error("an NMT command is a data frame, not a remote request")]
    Remote,
    #[error("an NMT command has 2 data bytes, not {0}")]
    Length(usize),
    #[error("NMT node id {0} is not 0 (all nodes) or 1 to 127")]
    NodeId(u8),
}

/// One NMT node-control message: COB-ID 0x000, two bytes (command, node id
/// or 0 for all nodes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct NmtMessage {
    pub command: NmtCommand,
    pub target: NmtTarget,
}

impl NmtMessage {
    pub fn new(command: NmtCommand, target: NmtTarget) -> Self {
        Self { command, target }
    }

    pub fn encode(self) -> Frame {
        data_frame(
            CanId::Standard(NMT_COB_ID),
            &[self.command.raw(), self.target.raw()],
        )
    }

    /// Reads an NMT message. The length must be exactly 2, as CANopenNode
    /// checks it too: a longer frame on COB-ID 0 is not an NMT command.
    /// Unknown command specifiers decode (as [`NmtCommand::Unknown`]); the
    /// slave ignores them.
    pub fn decode(frame: &Frame) -> Result<Self, NmtError> {
        if frame.id() != CanId::Standard(NMT_COB_ID) {
            return Err(NmtError::NotNmt(frame.id()));
        }
        if frame.is_remote() {
            return Err(NmtError::Remote);
        }
        let &[command, node] = frame.data() else {
            return Err(NmtError::Length(frame.data().len()));
        };
        Ok(Self {
            command: NmtCommand::from_raw(command),
            target: NmtTarget::from_raw(node)?,
        })
    }
}

/// The boot-up message of `node`: COB-ID 0x700 + node, one byte 0x00.
pub fn boot_up_frame(node: NodeId) -> Frame {
    data_frame(Function::Heartbeat.can_id(node), &[NmtState::BootUp.raw()])
}

/// What an NMT command did to a slave.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum NmtEvent {
    /// The node moved between pre-operational, operational and stopped.
    StateChanged { from: NmtState, to: NmtState },
    /// Reset node: the device reloads the application (0x2000–0x9FFF) and the
    /// communication (0x1000–0x1FFF) parameters from their stored values,
    /// then calls [`NmtSlave::boot_up`].
    ResetNode,
    /// Reset communication: the device reloads the communication parameters
    /// (0x1000–0x1FFF) only, then calls [`NmtSlave::boot_up`].
    ResetCommunication,
}

/// The NMT state machine of a slave (CiA 301 §7.3.2.2, figure 48).
///
/// It starts in initialisation ([`NmtState::BootUp`]); [`boot_up`](Self::boot_up)
/// ends it. While initialising, the node is not on the network yet, so NMT
/// commands are ignored.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NmtSlave {
    node: NodeId,
    state: NmtState,
}

impl NmtSlave {
    /// A slave that is initialising.
    pub fn new(node: NodeId) -> Self {
        Self {
            node,
            state: NmtState::BootUp,
        }
    }

    pub fn node(&self) -> NodeId {
        self.node
    }

    pub fn state(&self) -> NmtState {
        self.state
    }

    /// Whether the node may use `service` in its current state.
    pub fn allows(&self, service: NmtService) -> bool {
        self.state.allows(service)
    }

    /// Ends initialisation: the node enters pre-operational, and the frame
    /// returned is the boot-up message to send.
    #[must_use = "the boot-up message must be sent"]
    pub fn boot_up(&mut self) -> Frame {
        self.state = NmtState::PreOperational;
        boot_up_frame(self.node)
    }

    /// Obeys `message` if it addresses this node. `None` when nothing
    /// happened: another node's command, an unknown command, a command for
    /// the state the node is already in, or any command while initialising.
    pub fn handle(&mut self, message: NmtMessage) -> Option<NmtEvent> {
        if !message.target.includes(self.node) || self.state == NmtState::BootUp {
            return None;
        }
        let to = match message.command {
            NmtCommand::ResetNode => {
                self.state = NmtState::BootUp;
                return Some(NmtEvent::ResetNode);
            }
            NmtCommand::ResetCommunication => {
                self.state = NmtState::BootUp;
                return Some(NmtEvent::ResetCommunication);
            }
            command => command.target_state()?,
        };
        let from = std::mem::replace(&mut self.state, to);
        (from != to).then_some(NmtEvent::StateChanged { from, to })
    }

    /// Takes any received frame: `Ok(None)` for frames that are not on
    /// COB-ID 0x000, an error for a malformed NMT command (which is then
    /// ignored).
    pub fn on_frame(&mut self, frame: &Frame) -> Result<Option<NmtEvent>, NmtError> {
        if frame.id() != CanId::Standard(NMT_COB_ID) {
            return Ok(None);
        }
        Ok(self.handle(NmtMessage::decode(frame)?))
    }
}

fn data_frame(id: CanId, data: &[u8]) -> Frame {
    Frame::new(id, data).expect("NMT messages have at most 2 bytes")
}

#[cfg(test)]
mod tests;
