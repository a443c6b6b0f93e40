//! The DCMD commands that move things: an axis's state, halt, fault reset,
//! moves and their motion leases, and an LED controller's segments. Each
//! runs the gateway's operations as REST's drive and segment routes do,
//! with the same checks (`crate::gateway::leases`, `safe_stop`, `drive`).
//!
//! The motion lease rule, as MQTT gives it: a move without an end of its
//! own (velocity, torque, duty cycle), or halt released in such a mode, is
//! taken only with `Axis {n}/Lease` = true in the same DCMD, the host's
//! word that it will renew the lease; it holds a lease of the gateway's
//! period (`--lease-ms`) whose holder is the MQTT identity, renewed by each
//! DCMD `Axis {n}/Lease` = true. When it lapses the gateway's supervisor
//! halts the axis (quick stop if it does not come to rest), as for REST.
//! The edge node keeps the ids of the leases it holds ([`HeldLeases`]):
//! when its connection to the broker is lost (or the primary host goes
//! offline, or the edge node stops) they lapse at once, so that no drive is
//! left moving for a host that can no longer renew.

use std::collections::BTreeMap;
use std::sync::Mutex;

use super::command::{Command, endless};
use super::config::SparkplugConfig;
use crate::gateway::leases::InFlight;
use crate::gateway::motion_lease::AxisKey;
use crate::gateway::{Gateway, GatewayError, check_sdo_allowed};

/// The motion leases the edge node holds, by axis.
#[derive(Debug, Default)]
pub struct HeldLeases {
    ids: Mutex<BTreeMap<AxisKey, String>>,
}

impl HeldLeases {
    fn ids(&self) -> std::sync::MutexGuard<'_, BTreeMap<AxisKey, String>> {
        self.ids.lock().unwrap_or_else(|poison| poison.into_inner())
    }

    /// The id of the lease held on `axis`, if any.
    pub fn get(&self, axis: &AxisKey) -> Option<String> {
        self.ids().get(axis).cloned()
    }

    fn insert(&self, axis: AxisKey, id: String) {
        self.ids().insert(axis, id);
    }

    fn remove(&self, axis: &AxisKey) -> Option<String> {
        self.ids().remove(axis)
    }

    /// How many are held.
    pub fn len(&self) -> usize {
        self.ids().len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The host can renew nothing any more: every lease held lapses now,
    /// and the gateway stops its axis. Returns how many.
    pub fn lapse_all(&self, gateway: &Gateway, why: &str) -> usize {
        let held: Vec<(AxisKey, String)> = std::mem::take(&mut *self.ids()).into_iter().collect();
        for (axis, id) in &held {
            tracing::warn!("sparkplug: {why}: the motion lease on {axis} lapses now");
            gateway.leases.lapse_now(id);
        }
        held.len()
    }
}

/// What an axis or segment command did, for its audit entry.
#[derive(Debug, Default)]
pub struct Outcome {
    /// The audit entry's `item` and `request`.
    pub item: Option<String>,
    pub request: Option<String>,
    /// False: a renewal whose audit is not due (renewals are audited once,
    /// then once a minute, as the stream's are).
    pub audit: bool,
}

/// Runs an axis or segment command on `bus` node `node`, the role and the
/// write rate checked already.
pub async fn run(
    gateway: &Gateway,
    config: &SparkplugConfig,
    held: &HeldLeases,
    bus: &str,
    node: u8,
    command: &Command,
    outcome: &mut Outcome,
) -> Result<(), GatewayError> {
    let id = node.to_string();
    let who = config.who();
    let key = |axis: u8| AxisKey {
        bus: bus.to_string(),
        node,
        axis,
    };
    outcome.audit = true;
    match command {
        Command::AxisState { axis, target } => {
            let target_name = serde_json::to_value(target)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default();
            outcome.request = Some(format!("{{\"target\":\"{target_name}\"}}"));
            let axis_key = key(*axis);
            if *target == crate::gateway::drive::TargetState::QuickStopActive {
                let stopped = gateway.quick_stop_axis(bus, &id, &axis.to_string()).await;
                release(gateway, held, &axis_key);
                return stopped.map(|_| ()).map_err(|failed| failed.error);
            }
            let drive = gateway.drive(bus, &id, &axis.to_string())?;
            let enable = *target == crate::gateway::drive::TargetState::OperationEnabled;
            if enable {
                gateway
                    .leases
                    .check(&axis_key, held.get(&axis_key).as_deref(), &who)?;
                gateway.enabled_axes.insert(bus, &drive);
            }
            let state = target.state();
            spawned(async move { drive.set_state(state).await }).await?;
            if !enable {
                release(gateway, held, &axis_key);
            }
            Ok(())
        }
        Command::Halt { axis, halt, lease } => {
            outcome.request = Some(format!("{{\"halt\":{halt}}}"));
            let axis_key = key(*axis);
            if *halt {
                let halted = gateway.halt_axis(bus, &id, &axis.to_string()).await;
                release(gateway, held, &axis_key);
                return halted.map(|_| ()).map_err(|failed| failed.error);
            }
            let drive = gateway.drive(bus, &id, &axis.to_string())?;
            let presented = held.get(&axis_key);
            gateway
                .leases
                .check(&axis_key, presented.as_deref(), &who)?;
            // Releasing halt resumes the set-point the axis has: in a mode
            // without an end, that needs the host's lease promise first.
            let reading = drive.clone();
            let before = spawned(async move { reading.status().await }).await?;
            let mode = endless_displayed(before.mode.as_deref());
            if let Some(mode) = mode
                && !lease
            {
                return Err(lease_needed(*axis, mode));
            }
            gateway.enabled_axes.insert(bus, &drive);
            let status = spawned(async move { drive.halt(false).await }).await?;
            match endless_displayed(status.mode.as_deref()) {
                Some(mode) if status.state == "operation_enabled" => {
                    let granted = gateway.leases.grant(
                        gateway,
                        axis_key.clone(),
                        presented.as_deref(),
                        &who,
                        mode,
                    )?;
                    held.insert(axis_key, granted.id);
                }
                _ => release(gateway, held, &axis_key),
            }
            Ok(())
        }
        Command::FaultReset { axis } => {
            let drive = gateway.drive(bus, &id, &axis.to_string())?;
            spawned(async move { drive.fault_reset().await }).await?;
            Ok(())
        }
        Command::Move {
            axis,
            request,
            body,
            lease,
        } => {
            outcome.request = Some(body.clone());
            let axis_key = key(*axis);
            let drive = gateway.drive(bus, &id, &axis.to_string())?;
            drive.validate(request)?;
            let mode = request.mode();
            let presented = held.get(&axis_key);
            let leased =
                endless(mode) || mode == crate::gateway::drive::MoveMode::InterpolatedPosition;
            if !leased {
                // A move with an end of its own: the holder may give it
                // (and its lease ends), nobody else.
                gateway
                    .leases
                    .check(&axis_key, presented.as_deref(), &who)?;
                gateway.enabled_axes.insert(bus, &drive);
                let request = request.clone();
                spawned(async move { drive.run_move(&request).await }).await?;
                release(gateway, held, &axis_key);
                return Ok(());
            }
            if endless(mode) && !lease {
                return Err(lease_needed(*axis, mode.name()));
            }
            let granted = gateway.leases.grant(
                gateway,
                axis_key.clone(),
                presented.as_deref(),
                &who,
                mode.name(),
            )?;
            held.insert(axis_key.clone(), granted.id.clone());
            gateway.enabled_axes.insert(bus, &drive);
            let request = request.clone();
            let result = InFlight::new(&gateway.leases, &granted)
                .run(spawned(async move { drive.run_move(&request).await }))
                .await;
            if let Err(error) = result {
                // A failed move halted the axis: nothing is left to lease.
                release(gateway, held, &axis_key);
                return Err(error);
            }
            if !endless(mode) {
                // The interpolated points are all in the buffer.
                release(gateway, held, &axis_key);
                return Ok(());
            }
            gateway.leases.renew(&granted.id, None, None)?;
            Ok(())
        }
        Command::Lease { axis, keep } => {
            let axis_key = key(*axis);
            let Some(lease) = held.get(&axis_key) else {
                return Err(crate::gateway::motion_lease::LeaseError::Unknown(format!(
                    "(none held by {who} on axis {axis})"
                ))
                .into());
            };
            if *keep {
                match gateway.leases.renew_on(&axis_key, &lease, &who) {
                    Ok(_) => {
                        outcome.audit = gateway.leases.renewal_audit_due(&lease);
                        Ok(())
                    }
                    Err(error) => {
                        // Lapsed (its axis stopped) or ended by a stop:
                        // nothing of it is held any more.
                        held.remove(&axis_key);
                        Err(error)
                    }
                }
            } else {
                held.remove(&axis_key);
                gateway.leases.lapse_now(&lease);
                Ok(())
            }
        }
        Command::Segment { segment, writes } => {
            outcome.item = Some(format!("segment {segment}"));
            outcome.request = Some(
                writes
                    .iter()
                    .map(|(index, sub, value)| format!("0x{index:04X}:{sub}={value}"))
                    .collect::<Vec<_>>()
                    .join(" "),
            );
            let (served, info) = gateway.node(bus, &id)?;
            if info.profile != crate::gateway::profile::Profile::Uioled {
                return Err(GatewayError::InvalidRequest(format!(
                    "node {node} is no LED controller (profile {})",
                    info.profile.name()
                )));
            }
            // Every value checked against the EDS before the first write.
            let mut checked = Vec::with_capacity(writes.len());
            for (index, sub, value) in writes {
                let described = info
                    .eds_entry
                    .as_ref()
                    .and_then(|entry| entry.eds.dictionary.sub(*index, *sub))
                    .ok_or_else(|| {
                        GatewayError::InvalidRequest(format!(
                            "the EDS of node {node} does not describe 0x{index:04X} sub {sub}"
                        ))
                    })?;
                let bytes = described
                    .value_from_json(&serde_json::json!(value), Some(info.id))
                    .map_err(|err| GatewayError::ValueOutOfRange(err.to_string()))?
                    .to_bytes();
                checked.push((*index, *sub, bytes));
            }
            check_sdo_allowed(&served, &info)?;
            let channel = served.registry.sdo(info.id)?;
            // The preview follows every write the node confirms by itself.
            tokio::spawn(async move {
                let _procedure = channel.procedure().await;
                for (index, sub, bytes) in checked {
                    channel.download(index, sub, &bytes).await?;
                }
                Ok::<(), crate::gateway::sdo::SdoRequestError>(())
            })
            .await
            .map_err(|err| GatewayError::Internal(format!("SDO task: {err}")))?
            .map_err(GatewayError::from)
        }
        _ => Err(GatewayError::Internal(format!(
            "{} is not an axis or segment command",
            command.operation()
        ))),
    }
}

/// The axis's lease is over (a stop, a bounded move).
fn release(gateway: &Gateway, held: &HeldLeases, axis: &AxisKey) {
    held.remove(axis);
    gateway.leases.release(axis);
}

fn lease_needed(axis: u8, mode: &str) -> GatewayError {
    GatewayError::InvalidRequest(format!(
        "a {mode} motion has no end of its own: send Axis {axis}/Lease = true in the same DCMD \
         and renew it with Axis {axis}/Lease = true within the lease period"
    ))
}

/// The mode an axis displays, when a motion in it needs a lease.
fn endless_displayed(mode: Option<&str>) -> Option<&'static str> {
    match mode? {
        "velocity" | "profile_velocity" => Some("velocity"),
        "torque" | "profile_torque" => Some("torque"),
        "duty_cycle" => Some("duty_cycle"),
        _ => None,
    }
}

/// A drive sequence in a task of its own: nothing cancels it half way.
async fn spawned<T: Send + 'static>(
    work: impl Future<Output = Result<T, crate::gateway::drive::DriveError>> + Send + 'static,
) -> Result<T, GatewayError> {
    tokio::spawn(work)
        .await
        .map_err(|err| GatewayError::Internal(format!("drive task: {err}")))?
        .map_err(GatewayError::from)
}

#[cfg(test)]
mod tests;
