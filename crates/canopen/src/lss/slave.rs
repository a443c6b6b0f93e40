//! The LSS slave (CiA 305 §5, §6): the state a device keeps for LSS and
//! its answers.
//!
//! Three node-IDs (§5.2): the *active* one the device uses on the bus,
//! the *pending* one configure node-ID sets, and the *stored* one store
//! configuration keeps in non-volatile memory (which the device owns: this
//! machine reports [`LssSlaveEvent::Store`]). 0xFF (`None` here) is
//! "unconfigured". A device without an active node-ID takes part in no
//! CANopen service but LSS; when the master switches it back to waiting
//! with a pending node-ID it initialises with that ID
//! ([`LssSlaveEvent::Activate`], §6.3.2), and at every NMT reset
//! communication the pending node-ID becomes the active one
//! ([`LssSlave::reset_communication`]).
//!
//! Fastscan (§6.7) is answered only by a slave in the waiting state whose
//! pending node-ID is unconfigured, as CANopenNode's slave does; a complete
//! match puts it in the configuration state.

use crate::NodeId;
use crate::can::Frame;

use super::{
    AddressPart, ConfigResult, FASTSCAN_CONFIRM, IdentifyPart, Inquiry, LssAddress, LssRequest,
    LssResponse, LssState, UNCONFIGURED,
};

/// What the device must do after a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LssSlaveEvent {
    /// Keep the pending node-ID (`None`: unconfigured) and bit timing index
    /// in non-volatile memory.
    Store {
        node_id: Option<NodeId>,
        bit_timing: Option<u8>,
    },
    /// An unconfigured device got a node-ID: it initialises (reset
    /// communication) with it and sends its boot-up.
    Activate(NodeId),
    /// Switch to the configured bit timing after `delay_ms`, and send
    /// nothing for another `delay_ms`.
    ActivateBitTiming { delay_ms: u16, index: u8 },
}

/// The answer to one frame, and what the device must do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LssSlaveOutput {
    pub reply: Option<Frame>,
    pub event: Option<LssSlaveEvent>,
}

/// See the module documentation.
#[derive(Debug, Clone)]
pub struct LssSlave {
    address: LssAddress,
    state: LssState,
    active: Option<NodeId>,
    pending: Option<NodeId>,
    /// The bit timing index configure bit timing set, not yet activated.
    bit_timing: Option<u8>,
    /// The bit timing indexes of table 0 the device accepts.
    supported_bit_timings: Vec<u8>,
    /// How many parts of switch state selective matched so far.
    selective: usize,
    /// The bounds of identify remote slave received so far, in order.
    identify: Vec<u32>,
    /// The part Fastscan compares next; `None` until a confirm (0x80).
    fastscan_position: Option<u8>,
}

impl LssSlave {
    /// A slave in the waiting state whose active and pending node-ID are
    /// `node` (`None`: unconfigured), as after power-on.
    pub fn new(address: LssAddress, node: Option<NodeId>) -> Self {
        Self {
            address,
            state: LssState::Waiting,
            active: node,
            pending: node,
            bit_timing: None,
            supported_bit_timings: (0..=8).collect(),
            selective: 0,
            identify: Vec::new(),
            fastscan_position: None,
        }
    }

    /// Which bit timing indexes (of the CiA 301 table) are accepted.
    pub fn with_bit_timings(mut self, indexes: impl IntoIterator<Item = u8>) -> Self {
        self.supported_bit_timings = indexes.into_iter().collect();
        self
    }

    pub fn address(&self) -> LssAddress {
        self.address
    }

    pub fn state(&self) -> LssState {
        self.state
    }

    pub fn active(&self) -> Option<NodeId> {
        self.active
    }

    pub fn pending(&self) -> Option<NodeId> {
        self.pending
    }

    /// NMT reset communication: the pending node-ID becomes the active
    /// one (CiA 305 §5.2). Returns the active node-ID.
    pub fn reset_communication(&mut self) -> Option<NodeId> {
        self.active = self.pending;
        self.active
    }

    /// Power-on or NMT reset node: the device's non-volatile node-ID
    /// becomes pending and active, and the slave waits.
    pub fn power_on(&mut self, node: Option<NodeId>) {
        *self = Self {
            supported_bit_timings: std::mem::take(&mut self.supported_bit_timings),
            ..Self::new(self.address, node)
        };
    }

    /// Takes one LSS request (COB-ID 0x7E5); other frames and malformed
    /// requests change nothing and get no answer.
    pub fn handle(&mut self, frame: &Frame) -> LssSlaveOutput {
        let Ok(request) = LssRequest::decode(frame) else {
            return LssSlaveOutput::default();
        };
        let configuring = self.state == LssState::Configuration;
        let reply = |response: LssResponse| LssSlaveOutput {
            reply: Some(response.encode()),
            event: None,
        };
        match request {
            LssRequest::SwitchStateGlobal(LssState::Configuration) => {
                self.state = LssState::Configuration;
                self.selective = 0;
                LssSlaveOutput::default()
            }
            LssRequest::SwitchStateGlobal(LssState::Waiting) => {
                self.state = LssState::Waiting;
                self.selective = 0;
                match (self.active, self.pending) {
                    (None, Some(node)) => {
                        self.active = Some(node);
                        LssSlaveOutput {
                            reply: None,
                            event: Some(LssSlaveEvent::Activate(node)),
                        }
                    }
                    _ => LssSlaveOutput::default(),
                }
            }
            LssRequest::SwitchStateSelective(part, value) => {
                if self.state != LssState::Waiting {
                    return LssSlaveOutput::default();
                }
                // The four parts come in order; any mismatch starts over.
                if part.position() == self.selective && part.of(self.address) == value {
                    self.selective += 1;
                } else {
                    self.selective =
                        usize::from(part == AddressPart::Vendor && part.of(self.address) == value);
                    return LssSlaveOutput::default();
                }
                if self.selective == AddressPart::ALL.len() {
                    self.selective = 0;
                    self.state = LssState::Configuration;
                    return reply(LssResponse::SwitchStateSelective);
                }
                LssSlaveOutput::default()
            }
            LssRequest::ConfigureNodeId(raw) if configuring => {
                let result = match (raw, NodeId::new(raw)) {
                    (UNCONFIGURED, _) => {
                        self.pending = None;
                        ConfigResult::OK
                    }
                    (_, Ok(node)) => {
                        self.pending = Some(node);
                        ConfigResult::OK
                    }
                    (_, Err(_)) => ConfigResult::error(1),
                };
                reply(LssResponse::ConfigureNodeId(result))
            }
            LssRequest::ConfigureBitTiming { table, index } if configuring => {
                let result = if table == 0 && self.supported_bit_timings.contains(&index) {
                    self.bit_timing = Some(index);
                    ConfigResult::OK
                } else {
                    ConfigResult::error(1)
                };
                reply(LssResponse::ConfigureBitTiming(result))
            }
            LssRequest::ActivateBitTiming { delay_ms } if configuring => LssSlaveOutput {
                reply: None,
                event: self
                    .bit_timing
                    .map(|index| LssSlaveEvent::ActivateBitTiming { delay_ms, index }),
            },
            LssRequest::StoreConfiguration if configuring => LssSlaveOutput {
                reply: Some(LssResponse::StoreConfiguration(ConfigResult::OK).encode()),
                event: Some(LssSlaveEvent::Store {
                    node_id: self.pending,
                    bit_timing: self.bit_timing,
                }),
            },
            LssRequest::Inquire(inquiry) if configuring => {
                let value = match inquiry {
                    Inquiry::Address(part) => part.of(self.address),
                    Inquiry::NodeId => u32::from(self.active.map_or(UNCONFIGURED, NodeId::get)),
                };
                reply(LssResponse::Inquired(inquiry, value))
            }
            LssRequest::IdentifyRemoteSlave(part, value) => {
                let position = IdentifyPart::ALL
                    .iter()
                    .position(|p| *p == part)
                    .unwrap_or(0);
                if position == 0 {
                    self.identify.clear();
                }
                if position != self.identify.len() {
                    self.identify.clear();
                    return LssSlaveOutput::default();
                }
                self.identify.push(value);
                if self.identify.len() < IdentifyPart::ALL.len() {
                    return LssSlaveOutput::default();
                }
                let bounds = std::mem::take(&mut self.identify);
                let address = self.address;
                let matches = bounds[0] == address.vendor_id
                    && bounds[1] == address.product_code
                    && (bounds[2]..=bounds[3]).contains(&address.revision)
                    && (bounds[4]..=bounds[5]).contains(&address.serial);
                if matches {
                    reply(LssResponse::IdentifySlave)
                } else {
                    LssSlaveOutput::default()
                }
            }
            LssRequest::IdentifyNonConfigured => {
                if self.active.is_none() {
                    reply(LssResponse::IdentifyNonConfiguredSlave)
                } else {
                    LssSlaveOutput::default()
                }
            }
            LssRequest::Fastscan {
                id_number,
                bit_checked,
                sub,
                next,
            } => {
                if self.state != LssState::Waiting || self.pending.is_some() {
                    return LssSlaveOutput::default();
                }
                if bit_checked == FASTSCAN_CONFIRM {
                    self.fastscan_position = Some(0);
                    return reply(LssResponse::IdentifySlave);
                }
                if self.fastscan_position != Some(sub) {
                    return LssSlaveOutput::default();
                }
                let mask = u32::MAX.checked_shl(u32::from(bit_checked)).unwrap_or(0);
                let own = self.address.parts()[usize::from(sub)];
                if own & mask != id_number & mask {
                    return LssSlaveOutput::default();
                }
                self.fastscan_position = Some(next);
                if bit_checked == 0 && next < sub {
                    // All 128 bits matched.
                    self.fastscan_position = None;
                    self.state = LssState::Configuration;
                }
                reply(LssResponse::IdentifySlave)
            }
            // Configuration services in the waiting state are ignored.
            LssRequest::ConfigureNodeId(_)
            | LssRequest::ConfigureBitTiming { .. }
            | LssRequest::ActivateBitTiming { .. }
            | LssRequest::StoreConfiguration
            | LssRequest::Inquire(_) => LssSlaveOutput::default(),
        }
    }
}
