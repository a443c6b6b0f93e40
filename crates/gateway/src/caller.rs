//! Who asks the gateway for something, and through which door: what an
//! operation needs to know of its caller beside the request (a lease's
//! holder, the role a take-over needs), typed, so that every door names it
//! the same way and the audit log is written from it ([`crate::audit`]).

use super::access::Role;
use super::audit::{DoorDetail, DoorRequest};

/// The door a request came through. Its wire name ([`Channel::name`]) is
/// how logs and the audit log spell it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Channel {
    /// The REST API (and the dashboard that uses it).
    Rest,
    /// The WebSocket stream.
    Websocket,
    /// CiA 309-3, the ASCII gateway over TCP.
    Cia309_3,
    /// CiA 309-5, the HTTP gateway.
    Cia309_5,
    /// The Sparkplug B edge node (MQTT).
    Sparkplug,
    /// OPC UA.
    Opcua,
    /// The gateway itself (a lapsed lease's stop, shutdown).
    System,
}

impl Channel {
    /// Every channel, in the order of the enum.
    pub const ALL: [Self; 7] = [
        Self::Rest,
        Self::Websocket,
        Self::Cia309_3,
        Self::Cia309_5,
        Self::Sparkplug,
        Self::Opcua,
        Self::System,
    ];

    /// The channel of a wire name ([`Channel::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|channel| channel.name() == name)
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Rest => "rest",
            Self::Websocket => "websocket",
            Self::Cia309_3 => "cia309_3",
            Self::Cia309_5 => "cia309_5",
            Self::Sparkplug => "sparkplug",
            Self::Opcua => "opcua",
            Self::System => "system",
        }
    }
}

impl std::fmt::Display for Channel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Who asks: the door, the identity (a token's name, `anonymous`,
/// `mqtt:{user}`) and its role (`None`: no valid token, as on a gateway
/// without tokens).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Caller {
    pub channel: Channel,
    pub who: String,
    pub role: Option<Role>,
    /// Where the request came from (`127.0.0.1:51234`), where the door
    /// can know it (not over MQTT).
    pub peer: Option<String>,
    /// The request, as the door that made it knows it (shared by the
    /// caller's clones): its words for the audit row, and whether an
    /// operation audited it (`crate::audit`). `None`: the gateway's own,
    /// or a door that adds nothing.
    pub door: Option<DoorRequest>,
}

impl Caller {
    pub fn new(channel: Channel, who: impl Into<String>, role: Option<Role>) -> Self {
        Self {
            channel,
            who: who.into(),
            role,
            peer: None,
            door: None,
        }
    }

    /// The same caller, seen from `peer`.
    pub fn with_peer(mut self, peer: impl Into<String>) -> Self {
        self.peer = Some(peer.into());
        self
    }

    /// The same caller, making one request of a door (see
    /// [`DoorRequest`]).
    pub fn with_door(mut self, door: DoorRequest) -> Self {
        self.door = Some(door);
        self
    }

    /// The same caller, making one request whose rows the operations
    /// write, with the door's `detail`.
    pub fn with_detail(self, detail: DoorDetail) -> Self {
        self.with_door(DoorRequest::new(detail))
    }

    /// The gateway acting on its own.
    pub fn system() -> Self {
        Self::new(Channel::System, "gateway", None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_names_are_the_audit_logs() {
        let names: Vec<&str> = [
            Channel::Rest,
            Channel::Websocket,
            Channel::Cia309_3,
            Channel::Cia309_5,
            Channel::Sparkplug,
            Channel::Opcua,
            Channel::System,
        ]
        .into_iter()
        .map(Channel::name)
        .collect();
        assert_eq!(
            names,
            [
                "rest",
                "websocket",
                "cia309_3",
                "cia309_5",
                "sparkplug",
                "opcua",
                "system"
            ]
        );
        assert_eq!(Channel::Cia309_5.to_string(), "cia309_5");
        for channel in Channel::ALL {
            assert_eq!(Channel::from_name(channel.name()), Some(channel));
        }
        assert_eq!(Channel::from_name("REST"), None);
    }
}
