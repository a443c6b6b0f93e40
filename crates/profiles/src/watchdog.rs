//! The objects that keep a device safe when its manager dies (the
//! watchdog): what a device does when the gateway's heartbeat stops, and
//! the values that switch that protection off. The gateway refuses such
//! writes to operators and warns of an admin's (docs/security.md,
//! "Watchdog policy").
//!
//! | object | what it guards | switched off by |
//! |---|---|---|
//! | 0x1016 sub 1–127, consumer heartbeat time (CiA 301) | the entry that watches the manager's heartbeat | a value that no longer watches the manager (its node-ID changed, or its time 0) |
//! | 0x6007, abort connection option code (CiA 402, a drive's; each axis at its offset) | what an enabled drive does when the connection is lost | 0: no action |
//! | 0x1029 sub 1, error behaviour, communication error (CiA 301) | the NMT state a node goes to on a communication error | 1: no state change |
//!
//! 0x6007 is a watchdog object of drives only: a CiA 401 I/O module has its
//! interrupt mask there.

use crate::cia402::objects::ABORT_CONNECTION_OPTION;

/// Consumer heartbeat time (CiA 301 0x1016).
pub const CONSUMER_HEARTBEAT_TIME: u16 = 0x1016;
/// Error behaviour (CiA 301 0x1029).
pub const ERROR_BEHAVIOUR: u16 = 0x1029;
/// 0x1029's sub-index of the communication error.
pub const ERROR_BEHAVIOUR_COMMUNICATION: u8 = 1;
/// 0x1029 sub 1 = 1: no change of NMT state on a communication error.
const NO_STATE_CHANGE: u32 = 1;
/// Distance between two axes' copies of a CiA 402 object.
const AXIS_STEP: u16 = 0x800;

/// A watchdog object a write goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WatchdogObject {
    /// An entry (sub 1–127) of 0x1016.
    ConsumerEntry { sub: u8 },
    /// 0x6007 of `axis` (1-based) of a drive.
    AbortConnection { axis: u8 },
    /// 0x1029 sub 1.
    CommunicationErrorBehaviour,
}

impl WatchdogObject {
    /// The watchdog object `index`/`sub` is, on a drive (`drive`: a CiA
    /// 402 device, whose 0x6007 counts) or not; `None` for any other.
    pub fn of(index: u16, sub: u8, drive: bool) -> Option<Self> {
        match index {
            CONSUMER_HEARTBEAT_TIME if sub >= 1 => Some(Self::ConsumerEntry { sub }),
            ERROR_BEHAVIOUR if sub == ERROR_BEHAVIOUR_COMMUNICATION => {
                Some(Self::CommunicationErrorBehaviour)
            }
            _ if drive
                && (0x6000..=0x9FFF).contains(&index)
                && (index - 0x6000) % AXIS_STEP == ABORT_CONNECTION_OPTION - 0x6000 =>
            {
                let axis = (index - 0x6000) / AXIS_STEP + 1;
                Some(Self::AbortConnection { axis: axis as u8 })
            }
            _ => None,
        }
    }

    /// Why writing `value` (the bytes of the write, little-endian) switches
    /// the watchdog off for a gateway whose network manager has node-ID
    /// `manager`; `None` when it leaves it on. `current` is the entry's
    /// value before the write (0x1016 only: an entry that did not watch
    /// the manager may be changed freely).
    pub fn switched_off(&self, value: &[u8], manager: u8, current: Option<u32>) -> Option<String> {
        let number = unsigned(value)?;
        match *self {
            Self::ConsumerEntry { sub } => {
                let watches = |entry: u32| entry >> 16 & 0xFF == u32::from(manager) && entry & 0xFFFF != 0;
                (current.is_some_and(watches) && !watches(number)).then(|| {
                    format!(
                        "0x1016 sub {sub} watches the gateway's heartbeat (node {manager}); 0x{number:08X} (node {}, {} ms) would stop it: the device would not notice the gateway's death",
                        number >> 16 & 0xFF,
                        number & 0xFFFF
                    )
                })
            }
            Self::AbortConnection { axis } => (number & 0xFFFF == 0).then(|| {
                format!(
                    "0x{:04X} (abort connection option, axis {axis}) = 0 is \"no action\": the drive would go on moving when the gateway is gone",
                    ABORT_CONNECTION_OPTION + AXIS_STEP * u16::from(axis - 1)
                )
            }),
            Self::CommunicationErrorBehaviour => (number == NO_STATE_CHANGE).then(|| {
                "0x1029 sub 1 = 1 is \"no state change\" on a communication error: the device would stay operational when the gateway is gone".to_string()
            }),
        }
    }
}

fn unsigned(data: &[u8]) -> Option<u32> {
    if data.is_empty() || data.len() > 4 {
        return None;
    }
    let mut bytes = [0u8; 4];
    bytes[..data.len()].copy_from_slice(data);
    Some(u32::from_le_bytes(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_watchdog_objects_and_the_values_that_switch_them_off() {
        let entry = WatchdogObject::of(0x1016, 1, false).unwrap();
        let manager_entry = 0x007F_012Cu32;
        // Taken from the manager: refused; kept watching it (a longer
        // time): fine; an entry of another node: fine.
        assert!(
            entry
                .switched_off(&[0, 0, 0, 0], 127, Some(manager_entry))
                .is_some()
        );
        assert!(
            entry
                .switched_off(&0x0001_01F4u32.to_le_bytes(), 127, Some(manager_entry))
                .is_some()
        );
        assert!(
            entry
                .switched_off(&0x007F_0000u32.to_le_bytes(), 127, Some(manager_entry))
                .is_some()
        );
        assert!(
            entry
                .switched_off(&0x007F_03E8u32.to_le_bytes(), 127, Some(manager_entry))
                .is_none()
        );
        assert!(
            entry
                .switched_off(&[0, 0, 0, 0], 127, Some(0x0005_01F4))
                .is_none()
        );
        assert!(entry.switched_off(&[0, 0, 0, 0], 127, None).is_none());
        assert_eq!(WatchdogObject::of(0x1016, 0, false), None);

        let axis_1 = WatchdogObject::of(0x6007, 0, true).unwrap();
        assert_eq!(axis_1, WatchdogObject::AbortConnection { axis: 1 });
        assert!(axis_1.switched_off(&[0, 0], 127, None).is_some());
        assert!(axis_1.switched_off(&[3, 0], 127, None).is_none());
        assert_eq!(
            WatchdogObject::of(0x6807, 0, true),
            Some(WatchdogObject::AbortConnection { axis: 2 })
        );
        // A CiA 401 module's 0x6007 is an interrupt mask.
        assert_eq!(WatchdogObject::of(0x6007, 1, false), None);

        let behaviour = WatchdogObject::of(0x1029, 1, false).unwrap();
        assert!(behaviour.switched_off(&[1], 127, None).is_some());
        assert!(behaviour.switched_off(&[2], 127, None).is_none());
        assert!(behaviour.switched_off(&[0], 127, None).is_none());
        assert_eq!(WatchdogObject::of(0x1029, 2, false), None);
    }
}
