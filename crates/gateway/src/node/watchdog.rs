//! The watchdog stays on (docs/security.md, "Watchdog policy"; issue 30,
//! finding 4): a write to a node's object that would switch off its
//! protection against the gateway's death — the 0x1016 entry watching the
//! network manager's heartbeat, a drive's 0x6007 = 0 ("no action"),
//! 0x1029 sub 1 = 1 ("no state change") — is refused to operators
//! (`watchdog_protected`) and allowed to admins with a warning: the
//! `watchdog_off` event on the stream and the history, and the write's
//! audit row saying so. The table of those objects and values is the
//! profile's ([`crate::profiles::watchdog`]); this is the one place a
//! write asks it ([`NodeHandle::watchdog_check`]).

use crate::canopen::manager::DEFAULT_MANAGER_NODE_ID;
use crate::drive::DriveKind;
use crate::policy::Operation;
use crate::profiles::watchdog::{CONSUMER_HEARTBEAT_TIME, WatchdogObject};
use crate::sdo::SdoChannel;

use super::NodeHandle;
use crate::GatewayError;
use crate::caller::Caller;

/// What a write allowed through [`NodeHandle::watchdog_check`] does to the
/// watchdog.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum WatchdogWrite {
    /// It leaves it on (or is no watchdog object at all).
    KeepsItOn,
    /// An admin switches it off: the warning to give once it is written.
    SwitchesItOff(String),
}

impl NodeHandle {
    /// The network manager's node-ID on this bus (the one a 0x1016 entry
    /// watches).
    pub(crate) fn manager_node_id(&self) -> u8 {
        self.served
            .machine
            .as_ref()
            .map_or(DEFAULT_MANAGER_NODE_ID, |machine| {
                machine.manager().node_id.get()
            })
    }

    /// Whether writing `bytes` to `index`/`sub` switches the watchdog off,
    /// and whether `caller` may: an operator is refused
    /// (`watchdog_protected`), an admin is let through with the warning
    /// to give. A 0x1016 entry is read first: only the one watching the
    /// manager is protected (an entry a drive uses to follow its
    /// neighbour is the operator's to change).
    pub(crate) async fn watchdog_check(
        &self,
        caller: &Caller,
        channel: &SdoChannel,
        index: u16,
        sub: u8,
        bytes: &[u8],
    ) -> Result<WatchdogWrite, GatewayError> {
        let drive = DriveKind::from_profile(self.info.profile).is_some();
        let Some(object) = WatchdogObject::of(index, sub, drive) else {
            return Ok(WatchdogWrite::KeepsItOn);
        };
        let current = if index == CONSUMER_HEARTBEAT_TIME {
            // A node that cannot say what the entry holds is not
            // written to as if it watched nothing.
            let data = channel.upload(index, sub).await?;
            let mut raw = [0u8; 4];
            let len = data.len().min(4);
            raw[..len].copy_from_slice(&data[..len]);
            Some(u32::from_le_bytes(raw))
        } else {
            None
        };
        let manager = self.manager_node_id();
        let Some(why) = object.switched_off(bytes, manager, current) else {
            return Ok(WatchdogWrite::KeepsItOn);
        };
        if self
            .gateway
            .require(caller, Operation::SwitchWatchdogOff)
            .is_err()
        {
            return Err(GatewayError::WatchdogProtected(format!(
                "node {}: {why}; only an admin may switch a device's watchdog off",
                self.id()
            )));
        }
        Ok(WatchdogWrite::SwitchesItOff(format!(
            "{why} (written by {} over {})",
            caller.who, caller.channel
        )))
    }

    /// An admin's write switched the watchdog off: said on the stream and
    /// in the history (`watchdog_off`), and in the log.
    pub(crate) fn warn_watchdog_off(&self, warning: &str) {
        tracing::warn!(
            "bus {} node {}: watchdog switched off: {warning}",
            self.bus_name(),
            self.id()
        );
        self.served
            .registry
            .watchdog_off(self.info.id, warning.to_string());
    }
}

#[cfg(test)]
mod tests;
