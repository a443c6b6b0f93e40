//! Node ids, COB-IDs and the predefined connection set (CiA 301 §7.3.3,
//! table 55): which CAN identifier each service of each node uses by default.

use std::fmt;

use crate::can::CanId;

/// A CANopen node id, 1 to 127.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(u8);

/// A node id outside 1–127.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("node id {0} is not 1 to 127")]
pub struct InvalidNodeId(pub i64);

impl NodeId {
    pub const MIN: u8 = 1;
    pub const MAX: u8 = 127;

    pub fn new(id: u8) -> Result<Self, InvalidNodeId> {
        if (Self::MIN..=Self::MAX).contains(&id) {
            Ok(Self(id))
        } else {
            Err(InvalidNodeId(i64::from(id)))
        }
    }

    pub fn get(self) -> u8 {
        self.0
    }

    /// Every valid node id, 1 to 127.
    pub fn all() -> impl Iterator<Item = NodeId> {
        (Self::MIN..=Self::MAX).map(NodeId)
    }
}

impl TryFrom<i64> for NodeId {
    type Error = InvalidNodeId;

    fn try_from(id: i64) -> Result<Self, InvalidNodeId> {
        u8::try_from(id)
            .ok()
            .and_then(|id| NodeId::new(id).ok())
            .ok_or(InvalidNodeId(id))
    }
}

impl std::str::FromStr for NodeId {
    type Err = String;

    /// Decimal, or hex with `0x`.
    fn from_str(text: &str) -> Result<Self, String> {
        let value = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
            Some(hex) => i64::from_str_radix(hex, 16),
            None => text.parse::<i64>(),
        }
        .map_err(|_| format!("node id '{text}' is not a number"))?;
        NodeId::try_from(value).map_err(|err| err.to_string())
    }
}

impl fmt::Display for NodeId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// The function code: the upper 4 bits of an 11-bit COB-ID in the
/// predefined connection set. The doc of each variant gives its base value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Function {
    /// 0x000: NMT node control (broadcast, no node id).
    Nmt,
    /// 0x080: SYNC (broadcast, no node id).
    Sync,
    /// 0x080 + node: emergency.
    Emcy,
    /// 0x100: TIME (broadcast).
    Time,
    /// 0x180 / 0x280 / 0x380 / 0x480 + node: TPDO 1–4 (sent by the node).
    Tpdo(u8),
    /// 0x200 / 0x300 / 0x400 / 0x500 + node: RPDO 1–4 (received by the node).
    Rpdo(u8),
    /// 0x580 + node: SDO server to client (the node's answer).
    SdoTx,
    /// 0x600 + node: SDO client to server (request to the node).
    SdoRx,
    /// 0x700 + node: heartbeat, boot-up, node-guarding reply.
    Heartbeat,
    /// 0x7E4 / 0x7E5: LSS (CiA 305).
    Lss,
}

impl Function {
    /// The base COB-ID (node id 0).
    pub fn base(self) -> u16 {
        match self {
            Self::Nmt => 0x000,
            Self::Sync | Self::Emcy => 0x080,
            Self::Time => 0x100,
            Self::Tpdo(n) => 0x080 + 0x100 * u16::from(n.clamp(1, 4)),
            Self::Rpdo(n) => 0x100 + 0x100 * u16::from(n.clamp(1, 4)),
            Self::SdoTx => 0x580,
            Self::SdoRx => 0x600,
            Self::Heartbeat => 0x700,
            Self::Lss => 0x7E4,
        }
    }

    /// The COB-ID of this function for `node` in the predefined connection set.
    pub fn cob_id(self, node: NodeId) -> u16 {
        match self {
            Self::Nmt | Self::Sync | Self::Time | Self::Lss => self.base(),
            _ => self.base() + u16::from(node.get()),
        }
    }

    /// The CAN identifier of this function for `node`.
    pub fn can_id(self, node: NodeId) -> CanId {
        CanId::Standard(self.cob_id(node))
    }

    /// Reads a standard identifier by the predefined connection set: the
    /// function and, where it has one, the node. `None` for identifiers the
    /// set does not assign.
    pub fn classify(id: CanId) -> Option<(Function, Option<NodeId>)> {
        let CanId::Standard(raw) = id else {
            return None;
        };
        let node = NodeId::new((raw & 0x7F) as u8).ok();
        let with_node = |function: Function| node.map(|n| (function, Some(n)));
        match raw {
            0x000 => Some((Self::Nmt, None)),
            0x080 => Some((Self::Sync, None)),
            0x100 => Some((Self::Time, None)),
            0x7E4 | 0x7E5 => Some((Self::Lss, None)),
            _ => match raw & 0x780 {
                0x080 => with_node(Self::Emcy),
                0x180 => with_node(Self::Tpdo(1)),
                0x200 => with_node(Self::Rpdo(1)),
                0x280 => with_node(Self::Tpdo(2)),
                0x300 => with_node(Self::Rpdo(2)),
                0x380 => with_node(Self::Tpdo(3)),
                0x400 => with_node(Self::Rpdo(3)),
                0x480 => with_node(Self::Tpdo(4)),
                0x500 => with_node(Self::Rpdo(4)),
                0x580 => with_node(Self::SdoTx),
                0x600 => with_node(Self::SdoRx),
                0x700 => with_node(Self::Heartbeat),
                _ => None,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }

    #[test]
    fn node_ids_are_1_to_127() {
        assert!(NodeId::new(0).is_err());
        assert!(NodeId::new(128).is_err());
        assert_eq!(NodeId::all().count(), 127);
        assert_eq!("0x7F".parse::<NodeId>(), Ok(node(127)));
        assert_eq!("5".parse::<NodeId>(), Ok(node(5)));
        assert_eq!(
            "0".parse::<NodeId>(),
            Err("node id 0 is not 1 to 127".into())
        );
        assert_eq!(
            "x".parse::<NodeId>(),
            Err("node id 'x' is not a number".into())
        );
        assert_eq!(NodeId::try_from(300), Err(InvalidNodeId(300)));
    }

    #[test]
    fn the_predefined_connection_set_of_cia_301() {
        let n = node(0x05);
        let table = [
            (Function::Nmt, 0x000),
            (Function::Sync, 0x080),
            (Function::Emcy, 0x085),
            (Function::Time, 0x100),
            (Function::Tpdo(1), 0x185),
            (Function::Rpdo(1), 0x205),
            (Function::Tpdo(2), 0x285),
            (Function::Rpdo(2), 0x305),
            (Function::Tpdo(3), 0x385),
            (Function::Rpdo(3), 0x405),
            (Function::Tpdo(4), 0x485),
            (Function::Rpdo(4), 0x505),
            (Function::SdoTx, 0x585),
            (Function::SdoRx, 0x605),
            (Function::Heartbeat, 0x705),
        ];
        for (function, cob) in table {
            assert_eq!(function.cob_id(n), cob, "{function:?}");
            let expected_node = match function {
                Function::Nmt | Function::Sync | Function::Time => None,
                _ => Some(n),
            };
            assert_eq!(
                Function::classify(CanId::Standard(cob)),
                Some((function, expected_node)),
                "{cob:#x}"
            );
        }
        assert_eq!(
            Function::classify(CanId::Standard(0x7E5)),
            Some((Function::Lss, None))
        );
        // Node id 0 is no node: 0x580 alone is not an SDO response.
        assert_eq!(Function::classify(CanId::Standard(0x580)), None);
        assert_eq!(Function::classify(CanId::Extended(0x185)), None);
        assert_eq!(Function::classify(CanId::Standard(0x780)), None);
    }
}
