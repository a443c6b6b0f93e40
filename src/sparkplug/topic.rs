//! Sparkplug B topic names (Eclipse Sparkplug 3.0 §4.1, "Topic Namespace
//! Elements"): `spBv1.0/{group_id}/{message_type}/{edge_node_id}[/{device_id}]`,
//! and the primary host's `spBv1.0/STATE/{host_id}` (§4.1.3).

use std::fmt;

/// The namespace of Sparkplug B (the first element of every topic).
pub const NAMESPACE: &str = "spBv1.0";

/// A message type (§4.1.1.3), as the topic names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MessageType {
    /// `NBIRTH`: the edge node's birth certificate.
    NBirth,
    /// `NDEATH`: the edge node's death certificate (its MQTT will).
    NDeath,
    /// `NDATA`: the edge node's own metrics that changed.
    NData,
    /// `NCMD`: a command to the edge node.
    NCmd,
    /// `DBIRTH`: a device's birth certificate.
    DBirth,
    /// `DDEATH`: a device's death certificate.
    DDeath,
    /// `DDATA`: a device's metrics that changed.
    DData,
    /// `DCMD`: a command to a device.
    DCmd,
}

impl MessageType {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::NBirth => "NBIRTH",
            Self::NDeath => "NDEATH",
            Self::NData => "NDATA",
            Self::NCmd => "NCMD",
            Self::DBirth => "DBIRTH",
            Self::DDeath => "DDEATH",
            Self::DData => "DDATA",
            Self::DCmd => "DCMD",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "NBIRTH" => Self::NBirth,
            "NDEATH" => Self::NDeath,
            "NDATA" => Self::NData,
            "NCMD" => Self::NCmd,
            "DBIRTH" => Self::DBirth,
            "DDEATH" => Self::DDeath,
            "DDATA" => Self::DData,
            "DCMD" => Self::DCmd,
            _ => return None,
        })
    }

    /// Whether a topic of this type names a device.
    pub fn is_device(self) -> bool {
        matches!(self, Self::DBirth | Self::DDeath | Self::DData | Self::DCmd)
    }
}

/// A topic of an edge node or one of its devices.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Topic {
    pub group: String,
    pub kind: MessageType,
    pub edge_node: String,
    /// Present exactly for the device message types.
    pub device: Option<String>,
}

impl Topic {
    /// A topic of the edge node itself (`NBIRTH`, `NDATA`, ...).
    pub fn node(group: &str, kind: MessageType, edge_node: &str) -> Self {
        Self {
            group: group.to_string(),
            kind,
            edge_node: edge_node.to_string(),
            device: None,
        }
    }

    /// A topic of one of its devices (`DBIRTH`, `DDATA`, ...).
    pub fn device(group: &str, kind: MessageType, edge_node: &str, device: &str) -> Self {
        Self {
            device: Some(device.to_string()),
            ..Self::node(group, kind, edge_node)
        }
    }

    /// Reads a topic; `None` for one outside the namespace, of an unknown
    /// message type, or whose device element does not match its type.
    pub fn parse(text: &str) -> Option<Self> {
        let mut parts = text.split('/');
        if parts.next()? != NAMESPACE {
            return None;
        }
        let group = parts.next()?;
        let kind = MessageType::from_name(parts.next()?)?;
        let edge_node = parts.next()?;
        let device = parts.next();
        if parts.next().is_some() || device.is_some() != kind.is_device() {
            return None;
        }
        if [group, edge_node].iter().any(|part| part.is_empty()) || device == Some("") {
            return None;
        }
        Some(Self {
            group: group.to_string(),
            kind,
            edge_node: edge_node.to_string(),
            device: device.map(str::to_string),
        })
    }
}

impl fmt::Display for Topic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{NAMESPACE}/{}/{}/{}",
            self.group,
            self.kind.as_str(),
            self.edge_node
        )?;
        if let Some(device) = &self.device {
            write!(f, "/{device}")?;
        }
        Ok(())
    }
}

/// The primary host application's state topic (§4.1.3, Sparkplug 3.0).
pub fn state_topic(host_id: &str) -> String {
    format!("{NAMESPACE}/STATE/{host_id}")
}

/// What a primary host's `STATE` message says (§7.5, a JSON object
/// `{"online": bool, "timestamp": ms}`), `None` for a payload that is no
/// such object.
pub fn parse_host_state(payload: &[u8]) -> Option<HostState> {
    let json: serde_json::Value = serde_json::from_slice(payload).ok()?;
    Some(HostState {
        online: json.get("online")?.as_bool()?,
        timestamp: json.get("timestamp").and_then(serde_json::Value::as_u64),
    })
}

/// A primary host application's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HostState {
    pub online: bool,
    /// When the host said so (its clock, milliseconds since 1970).
    pub timestamp: Option<u64>,
}

/// What a STATE message of the primary host means to the edge node
/// ([`PrimaryHost::on_state`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HostVerdict {
    /// Older than the newest STATE seen (a replayed message, or the late
    /// will of a host session already replaced): nothing changes.
    Stale,
    /// The host came online: births, then the queued data.
    CameOnline,
    /// Online again while online (a duplicate, a retained copy): nothing
    /// changes, no rebirth.
    StillOnline,
    /// A valid offline: NDEATH, disconnect, and wait for the host on the
    /// next connection (Sparkplug 3.0 §5, "Edge Node Session
    /// Termination").
    WentOffline,
    /// Offline while not online: nothing to end.
    StillOffline,
}

/// The primary host application as the edge node follows it, sans I/O:
/// the newest STATE timestamp wins (Sparkplug 3.0: a STATE older than the
/// previous one is ignored; with none before, it is taken as it is).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PrimaryHost {
    /// The timestamp of the newest STATE taken; kept across connections,
    /// so that a retained stale offline cannot silence the next session.
    newest: Option<u64>,
    online: bool,
}

impl PrimaryHost {
    /// Whether the host's newest STATE said online (and the current
    /// connection has seen it).
    pub fn online(&self) -> bool {
        self.online
    }

    /// A STATE message: what it means, given those before it. A STATE
    /// without a timestamp (not Sparkplug 3.0) is taken as older than any
    /// other once one with a timestamp came.
    pub fn on_state(&mut self, state: HostState) -> HostVerdict {
        let timestamp = state.timestamp.unwrap_or(0);
        if self.newest.is_some_and(|newest| timestamp < newest) {
            return HostVerdict::Stale;
        }
        self.newest = Some(timestamp);
        match (self.online, state.online) {
            (false, true) => {
                self.online = true;
                HostVerdict::CameOnline
            }
            (true, true) => HostVerdict::StillOnline,
            (true, false) => {
                self.online = false;
                HostVerdict::WentOffline
            }
            (false, false) => HostVerdict::StillOffline,
        }
    }

    /// The connection is gone: the host's state is learnt anew on the next
    /// one (its retained STATE), against the newest timestamp seen.
    pub fn connection_lost(&mut self) {
        self.online = false;
    }
}

/// Whether a name is fit to be a topic element: not empty, and none of
/// MQTT's separator and wildcards (`/`, `+`, `#`).
pub fn valid_element(name: &str) -> bool {
    !name.is_empty() && !name.contains(['/', '+', '#'])
}
