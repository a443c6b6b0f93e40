//! The DCMD commands that move things: an axis's state, halt, fault reset,
//! moves and their motion leases, and an LED controller's segments. The
//! axis commands are parsed here and run by the gateway's motion
//! operations (`crate::gateway::motion`), which REST's drive routes call
//! too: the lease policy is theirs; a segment's by the LED operations
//! (`crate::gateway::led`) that REST's segment routes call.
//!
//! The motion lease as MQTT gives it: a move without an end of its own
//! (velocity, torque, duty cycle), or halt released in such a mode, is
//! taken only with `Axis {n}/Lease` = true (the host's word that it will
//! renew the lease) and `Axis {n}/Lease Id` (the lease's id, of the host's
//! choosing) in the same DCMD. MQTT carries no sender identity and no
//! answer, so the id is the capability: the first grant binds the lease to
//! it, and every later move, halt release, state change, renewal (`Axis
//! {n}/Lease` = true) or give-up (false) on the leased axis must present it,
//! whoever sends it. A halt and a quick stop never need it. When the lease
//! lapses the gateway's supervisor halts the axis (quick stop if it does
//! not come to rest), as for REST.
//!
//! The edge node keeps the ids of the leases granted over MQTT
//! ([`HeldLeases`]) for one purpose: when its connection to the broker is
//! lost (or the primary host goes offline, or the edge node stops) they
//! lapse at once, so that no drive is left moving for a host that can no
//! longer renew. It never presents them for anyone.

use std::collections::BTreeMap;
use std::sync::Mutex;

use super::command::Command;
use crate::gateway::Caller;
use crate::gateway::LeaseClaim;
use crate::gateway::{AxisKey, MotionLease};
use crate::gateway::{Gateway, GatewayError};

/// The ids of the motion leases granted over MQTT, by axis: what lapses
/// when the host can renew nothing any more.
#[derive(Debug, Default)]
pub struct HeldLeases {
    ids: Mutex<BTreeMap<AxisKey, String>>,
}

impl HeldLeases {
    fn ids(&self) -> std::sync::MutexGuard<'_, BTreeMap<AxisKey, String>> {
        self.ids.lock().unwrap_or_else(|poison| poison.into_inner())
    }

    fn granted(&self, lease: Option<&MotionLease>) {
        if let Some(lease) = lease {
            self.ids().insert(lease.axis.clone(), lease.id.clone());
        }
    }

    /// The lease `id` on `axis` is over; another id (a sender that
    /// presented the wrong one) leaves the one kept.
    fn ended(&self, axis: &AxisKey, id: &str) {
        let mut ids = self.ids();
        if ids.get(axis).is_some_and(|held| held == id) {
            ids.remove(axis);
        }
    }

    /// How many are kept (some may have ended since: a stop, a bounded
    /// move; lapsing those again is nothing).
    pub fn len(&self) -> usize {
        self.ids().len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The host can renew nothing any more: every lease granted over MQTT
    /// lapses now, and the gateway stops its axis. Returns how many.
    pub fn lapse_all(&self, gateway: &Gateway, why: &str) -> usize {
        let held: Vec<(AxisKey, String)> = std::mem::take(&mut *self.ids()).into_iter().collect();
        for (axis, id) in &held {
            tracing::warn!("sparkplug: {why}: the motion lease on {axis} lapses now");
            gateway.lapse_lease(id);
        }
        held.len()
    }
}

/// How a host takes a lease, in its words, for a refusal to say.
fn how_to_lease(axis: u8) -> String {
    format!(
        "send Axis {axis}/Lease = true and Axis {axis}/Lease Id (an id of the host's choosing, \
         16 to 128 characters of A-Z, a-z, 0-9, '-', '_', '.', '~') in the same DCMD, and renew \
         it with both within the lease period"
    )
}

/// Runs an axis or segment command on `bus` node `node` for `caller`, the
/// role checked already, and the write rate too for an axis command (a
/// segment's is the LED operation's, as REST's is). The motion operations
/// audit themselves; a segment command is audited by the door.
pub async fn run(
    gateway: &Gateway,
    caller: &Caller,
    held: &HeldLeases,
    bus: &str,
    node: u8,
    command: &Command,
) -> Result<(), GatewayError> {
    let id = node.to_string();
    let key = |axis: u8| AxisKey {
        bus: bus.to_string(),
        node,
        axis,
    };
    let claim = |axis: u8, lease_id: &Option<String>, promised: bool| {
        LeaseClaim::chosen(lease_id.clone(), promised, how_to_lease(axis))
    };
    match command {
        Command::AxisState {
            axis,
            target,
            lease_id,
        } => {
            let done = gateway
                .set_axis_state(
                    caller,
                    (bus, &id, &axis.to_string()),
                    *target,
                    &claim(*axis, lease_id, false),
                )
                .await
                .map_err(|failed| failed.error)?;
            held.granted(done.lease.as_ref());
            Ok(())
        }
        Command::Halt {
            axis,
            halt,
            lease,
            lease_id,
        } => {
            let done = gateway
                .set_axis_halt(
                    caller,
                    (bus, &id, &axis.to_string()),
                    *halt,
                    &claim(*axis, lease_id, *lease),
                )
                .await
                .map_err(|failed| failed.error)?;
            held.granted(done.lease.as_ref());
            Ok(())
        }
        Command::FaultReset { axis } => {
            gateway
                .reset_axis_fault(caller, (bus, &id, &axis.to_string()))
                .await?;
            Ok(())
        }
        Command::Move {
            axis,
            request,
            lease,
            lease_id,
            ..
        } => {
            let done = gateway
                .move_axis(
                    caller,
                    (bus, &id, &axis.to_string()),
                    request,
                    &claim(*axis, lease_id, *lease),
                )
                .await
                .map_err(|failed| failed.error)?;
            held.granted(done.lease.as_ref());
            Ok(())
        }
        Command::Lease {
            axis,
            keep,
            lease_id,
        } => {
            let axis_key = key(*axis);
            let Some(lease_id) = lease_id else {
                return Err(GatewayError::InvalidRequest(format!(
                    "Axis {axis}/Lease presents no lease: send Axis {axis}/Lease Id, the id of \
                     the axis's lease, in the same DCMD"
                )));
            };
            if *keep {
                // A heartbeat: audited the first time and once a minute.
                match gateway.keep_axis_lease(caller, &axis_key, lease_id).await {
                    Ok(_) => Ok(()),
                    Err(error) => {
                        // Lapsed (its axis stopped) or ended by a stop:
                        // nothing of it is held any more.
                        held.ended(&axis_key, lease_id);
                        Err(error)
                    }
                }
            } else {
                gateway
                    .give_up_axis_lease(caller, &axis_key, lease_id)
                    .await?;
                held.ended(&axis_key, lease_id);
                Ok(())
            }
        }
        Command::Segment { segment, update } => {
            gateway
                .node_handle(bus, &id)?
                .led_controller()?
                .write_segment(caller, *segment, update)
                .await
        }
        _ => Err(GatewayError::Internal(format!(
            "{} is not an axis or segment command",
            command.operation()
        ))),
    }
}

#[cfg(test)]
mod tests;
