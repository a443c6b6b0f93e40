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
mod tests {
    use super::*;

    fn node(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }

    fn nmt(data: &[u8]) -> Frame {
        Frame::new(CanId::Standard(0), data).unwrap()
    }

    #[test]
    fn command_codes_and_names() {
        let table = [
            (NmtCommand::Start, 0x01, "start"),
            (NmtCommand::Stop, 0x02, "stop"),
            (NmtCommand::EnterPreOperational, 0x80, "pre_operational"),
            (NmtCommand::ResetNode, 0x81, "reset_node"),
            (NmtCommand::ResetCommunication, 0x82, "reset_communication"),
        ];
        for (command, raw, name) in table {
            assert_eq!(command.raw(), raw);
            assert_eq!(NmtCommand::from_raw(raw), command);
            assert_eq!(command.name(), name);
            assert_eq!(name.parse::<NmtCommand>(), Ok(command));
            assert_eq!(command.to_string(), name);
        }
        assert_eq!(NmtCommand::from_raw(0x03), NmtCommand::Unknown(0x03));
        assert_eq!(NmtCommand::Unknown(0x03).raw(), 0x03);
        assert_eq!(NmtCommand::Unknown(0x03).to_string(), "unknown (0x03)");
        // The command line spells them with hyphens.
        assert_eq!(
            "reset-communication".parse::<NmtCommand>(),
            Ok(NmtCommand::ResetCommunication)
        );
        assert_eq!(
            "Pre-Operational".parse::<NmtCommand>(),
            Ok(NmtCommand::EnterPreOperational)
        );
        assert!("unknown".parse::<NmtCommand>().is_err());
        assert!("go".parse::<NmtCommand>().unwrap_err().contains("'go'"));
    }

    #[test]
    fn states_and_their_heartbeat_bytes() {
        let table = [
            (NmtState::BootUp, 0x00, "boot_up"),
            (NmtState::Stopped, 0x04, "stopped"),
            (NmtState::Operational, 0x05, "operational"),
            (NmtState::PreOperational, 0x7F, "pre_operational"),
        ];
        for (state, raw, name) in table {
            assert_eq!(state.raw(), raw);
            assert_eq!(NmtState::from_raw(raw), state);
            assert_eq!(state.name(), name);
        }
        assert_eq!(NmtState::from_raw(0x50), NmtState::Unknown(0x50));
        assert_eq!(NmtState::Unknown(0x50).raw(), 0x50);
        assert_eq!(NmtState::Unknown(0x50).name(), "unknown");
        for raw in 0..=u8::MAX {
            assert_eq!(NmtState::from_raw(raw).raw(), raw);
            assert_eq!(NmtCommand::from_raw(raw).raw(), raw);
        }
    }

    #[test]
    fn command_targets_are_the_states_of_figure_48() {
        assert_eq!(
            NmtCommand::Start.target_state(),
            Some(NmtState::Operational)
        );
        assert_eq!(NmtCommand::Stop.target_state(), Some(NmtState::Stopped));
        assert_eq!(
            NmtCommand::EnterPreOperational.target_state(),
            Some(NmtState::PreOperational)
        );
        assert_eq!(NmtCommand::ResetNode.target_state(), Some(NmtState::BootUp));
        assert_eq!(
            NmtCommand::ResetCommunication.target_state(),
            Some(NmtState::BootUp)
        );
        assert_eq!(NmtCommand::Unknown(9).target_state(), None);
    }

    #[test]
    fn services_allowed_per_state_follow_figure_3_9() {
        use NmtService::*;
        let services = [
            Pdo,
            Sdo,
            Sync,
            Emcy,
            Time,
            NodeGuarding,
            Heartbeat,
            BootUp,
            Nmt,
        ];
        let allowed = |state: NmtState| -> Vec<NmtService> {
            services
                .into_iter()
                .filter(|&service| state.allows(service))
                .collect()
        };
        assert_eq!(
            allowed(NmtState::PreOperational),
            [Sdo, Sync, Emcy, Time, NodeGuarding, Heartbeat, Nmt]
        );
        assert_eq!(
            allowed(NmtState::Operational),
            [Pdo, Sdo, Sync, Emcy, Time, NodeGuarding, Heartbeat, Nmt]
        );
        assert_eq!(allowed(NmtState::Stopped), [NodeGuarding, Heartbeat, Nmt]);
        assert_eq!(allowed(NmtState::BootUp), [BootUp]);
        assert_eq!(allowed(NmtState::Unknown(0x50)), []);
    }

    #[test]
    fn nmt_frames_encode_byte_exact() {
        let start_5 = NmtMessage::new(NmtCommand::Start, NmtTarget::Node(node(5))).encode();
        assert_eq!(start_5.to_string(), "000#0105");
        let reset_all = NmtMessage::new(NmtCommand::ResetNode, NmtTarget::All).encode();
        assert_eq!(reset_all.to_string(), "000#8100");
        let pre_127 = NmtMessage::new(NmtCommand::EnterPreOperational, NmtTarget::Node(node(127)));
        assert_eq!(pre_127.encode().to_string(), "000#807F");
        assert_eq!(NmtMessage::decode(&pre_127.encode()), Ok(pre_127));
        assert_eq!(boot_up_frame(node(0x22)).to_string(), "722#00");
    }

    #[test]
    fn nmt_frames_decode_and_reject_malformed_ones() {
        assert_eq!(
            NmtMessage::decode(&nmt(&[0x02, 0x00])),
            Ok(NmtMessage::new(NmtCommand::Stop, NmtTarget::All))
        );
        assert_eq!(
            NmtMessage::decode(&nmt(&[0x82, 0x0A])),
            Ok(NmtMessage::new(
                NmtCommand::ResetCommunication,
                NmtTarget::Node(node(10))
            ))
        );
        assert_eq!(
            NmtMessage::decode(&nmt(&[0x42, 0x01])),
            Ok(NmtMessage::new(
                NmtCommand::Unknown(0x42),
                NmtTarget::Node(node(1))
            ))
        );
        assert_eq!(NmtMessage::decode(&nmt(&[0x01])), Err(NmtError::Length(1)));
        assert_eq!(NmtMessage::decode(&nmt(&[])), Err(NmtError::Length(0)));
        assert_eq!(
            NmtMessage::decode(&nmt(&[0x01, 0x05, 0x00])),
            Err(NmtError::Length(3))
        );
        assert_eq!(
            NmtMessage::decode(&nmt(&[0x01, 0x80])),
            Err(NmtError::NodeId(0x80))
        );
        assert_eq!(
            NmtMessage::decode(&Frame::remote(CanId::Standard(0), 2).unwrap()),
            Err(NmtError::Remote)
        );
        let elsewhere = Frame::new(CanId::Standard(0x001), &[1, 5]).unwrap();
        assert_eq!(
            NmtMessage::decode(&elsewhere),
            Err(NmtError::NotNmt(CanId::Standard(1)))
        );
        let extended = Frame::new(CanId::Extended(0), &[1, 5]).unwrap();
        assert_eq!(
            NmtMessage::decode(&extended),
            Err(NmtError::NotNmt(CanId::Extended(0)))
        );
        assert_eq!(
            NmtError::Length(3).to_string(),
            "an NMT command has 2 data bytes, not 3"
        );
    }

    #[test]
    fn a_slave_boots_into_pre_operational_and_follows_commands() {
        let mut slave = NmtSlave::new(node(5));
        assert_eq!(slave.state(), NmtState::BootUp);
        assert!(slave.allows(NmtService::BootUp));
        // Not on the network yet: commands are ignored while initialising.
        assert_eq!(slave.on_frame(&nmt(&[0x01, 0x05])), Ok(None));
        assert_eq!(slave.boot_up().to_string(), "705#00");
        assert_eq!(slave.state(), NmtState::PreOperational);
        assert!(!slave.allows(NmtService::Pdo));

        assert_eq!(
            slave.on_frame(&nmt(&[0x01, 0x05])),
            Ok(Some(NmtEvent::StateChanged {
                from: NmtState::PreOperational,
                to: NmtState::Operational
            }))
        );
        assert!(slave.allows(NmtService::Pdo));
        // Again: already operational, nothing changes.
        assert_eq!(slave.on_frame(&nmt(&[0x01, 0x00])), Ok(None));
        // Another node's command.
        assert_eq!(slave.on_frame(&nmt(&[0x02, 0x06])), Ok(None));
        assert_eq!(
            slave.on_frame(&nmt(&[0x02, 0x00])),
            Ok(Some(NmtEvent::StateChanged {
                from: NmtState::Operational,
                to: NmtState::Stopped
            }))
        );
        assert!(!slave.allows(NmtService::Sdo));
        assert!(slave.allows(NmtService::Heartbeat));
        // Stopped straight to operational is allowed.
        assert_eq!(
            slave.on_frame(&nmt(&[0x01, 0x05])),
            Ok(Some(NmtEvent::StateChanged {
                from: NmtState::Stopped,
                to: NmtState::Operational
            }))
        );
        assert_eq!(
            slave.on_frame(&nmt(&[0x80, 0x05])),
            Ok(Some(NmtEvent::StateChanged {
                from: NmtState::Operational,
                to: NmtState::PreOperational
            }))
        );
        // Unknown commands change nothing.
        assert_eq!(slave.on_frame(&nmt(&[0x03, 0x05])), Ok(None));
        assert_eq!(slave.state(), NmtState::PreOperational);
    }

    #[test]
    fn resets_are_reported_and_end_in_a_new_boot_up() {
        let mut slave = NmtSlave::new(node(5));
        let _ = slave.boot_up();
        let _ = slave.on_frame(&nmt(&[0x01, 0x00]));
        assert_eq!(
            slave.on_frame(&nmt(&[0x82, 0x05])),
            Ok(Some(NmtEvent::ResetCommunication))
        );
        assert_eq!(slave.state(), NmtState::BootUp);
        assert!(!slave.allows(NmtService::Sdo));
        assert_eq!(slave.boot_up().to_string(), "705#00");
        assert_eq!(slave.state(), NmtState::PreOperational);

        let _ = slave.on_frame(&nmt(&[0x02, 0x00]));
        // A reset is obeyed in stopped too.
        assert_eq!(
            slave.on_frame(&nmt(&[0x81, 0x00])),
            Ok(Some(NmtEvent::ResetNode))
        );
        assert_eq!(slave.state(), NmtState::BootUp);
    }

    #[test]
    fn a_slave_reports_malformed_nmt_frames_and_passes_others() {
        let mut slave = NmtSlave::new(node(5));
        let _ = slave.boot_up();
        assert_eq!(slave.on_frame(&nmt(&[0x01])), Err(NmtError::Length(1)));
        assert_eq!(slave.state(), NmtState::PreOperational);
        let sdo = Frame::new(CanId::Standard(0x605), &[0x40, 0, 0x10, 0, 0, 0, 0, 0]).unwrap();
        assert_eq!(slave.on_frame(&sdo), Ok(None));
    }
}
