//! What the gateway's own tests start a gateway with: a configuration of
//! the given buses with `candeck serve`'s defaults (a lease of 1 s, no
//! tokens, no write limit, no SYNC), and the demo rack on each virtual bus
//! as the binary wires it; and what the motion and alarm tests do to it
//! alike (an operator, an axis enabled).

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use candeck_sim::products::parse_devices;
use candeck_sim::rack::Rack;

use crate::GatewayConfig;
use crate::access::{Role, Tokens};
use crate::caller::{Caller, Channel};
use crate::can::VirtualHub;
use crate::drive::TargetState;
use crate::history::Retention;
use crate::machine::MachineSettings;
use crate::motion::{LeaseClaim, MotionFailed, MotionOutcome};
use crate::producers::TelemetryConfig;
use crate::service::BusDevices;
use crate::service::Gateway;

/// A configuration of `buses` (name, spec), the rest by default; tests
/// change a field with `GatewayConfig { tokens, ..config(&[…]) }`.
pub(crate) fn config(buses: &[(&str, &str)]) -> GatewayConfig {
    GatewayConfig {
        buses: buses
            .iter()
            .map(|(name, spec)| (name.to_string(), spec.parse().unwrap()))
            .collect(),
        data_dir: None,
        eds_dir: None,
        bitrate: 500_000,
        telemetry: TelemetryConfig::default(),
        retention: Retention::default(),
        recordings_quota: None,
        logger_max_values: 1000,
        lease_period: Duration::from_secs(1),
        tokens: Tokens::default(),
        write_limit: None,
        sync_period: Duration::ZERO,
        machine: MachineSettings::default(),
        machine_nodes: BTreeMap::new(),
        sdo_samples_per_s: crate::DEFAULT_SDO_SAMPLES_PER_S,
    }
}

/// The devices of a virtual bus's preset on a rack, as the binary wires
/// them (`Gateway::start`'s `attach`).
pub(crate) fn rack(_: &str, preset: &str, hub: &VirtualHub) -> Result<Option<BusDevices>, String> {
    let rack = Rack::new(hub.clone());
    rack.add_all(&parse_devices(preset)?)
        .map_err(|err| err.to_string())?;
    Ok(Some(Arc::new(rack) as BusDevices))
}

/// The gateway of `config` on the demo rack, after the 5 s (of the paused
/// clock) its scans take to identify every node.
pub(crate) async fn started(config: GatewayConfig) -> Gateway {
    let gateway = Gateway::start(config, &rack).await.unwrap();
    tokio::time::sleep(Duration::from_secs(5)).await;
    gateway
}

/// An operator named `who`, over REST.
pub(crate) fn operator(who: &str) -> Caller {
    Caller::new(Channel::Rest, who, Some(Role::Operator))
}

/// `axis` (bus, node, axis) put in operation enabled by `caller`, with
/// `claim`.
pub(crate) async fn enable_axis(
    gateway: &Gateway,
    caller: &Caller,
    axis: (&str, &str, &str),
    claim: &LeaseClaim,
) -> Result<MotionOutcome, MotionFailed> {
    gateway
        .set_axis_state(caller, axis, TargetState::OperationEnabled, claim)
        .await
}
