//! The emulator's wiring: the virtual devices of a `virtual:` bus (the
//! `sim` crate's [`Rack`]), put on the bus when the gateway opens it. The
//! gateway drives them as it drives real devices and does not know them
//! (`gateway` never depends on `sim`); the `/sim` routes and the tests find
//! a bus's rack again through [`RackOf`], and [`devices`] holds the
//! operations on a bus's virtual devices that every door calls.

use std::path::PathBuf;
use std::sync::Arc;

use crate::can::VirtualHub;
use crate::can::spec::BusSpec;
use crate::gateway::EdsCatalog;
use crate::gateway::RegistryConfig;
use crate::gateway::{BusDevices, ServedBus};
use crate::sim::products::parse_devices;
use crate::sim::rack::Rack;

pub mod devices;

/// Opens `spec` as the bus `name`: a `virtual:demo` bus gets the demo
/// devices, `virtual:empty` none, `virtual:LIST` the products it lists
/// ([`parse_devices`]).
pub async fn open_bus(
    name: &str,
    spec: &BusSpec,
    catalog: Arc<EdsCatalog>,
    config: RegistryConfig,
    bitrate: u32,
) -> Result<ServedBus, String> {
    ServedBus::open_with_devices(name, spec, catalog, config, bitrate, &racks(None)).await
}

/// What puts the demo rack on each virtual bus the gateway opens
/// ([`Gateway::start`](crate::gateway::Gateway::start)): each bus's
/// devices keep what they save under `DATA_DIR/sim/BUS`.
pub fn racks(
    data_dir: Option<PathBuf>,
) -> impl Fn(&str, &str, &VirtualHub) -> Result<Option<BusDevices>, String> + Sync {
    move |name: &str, preset: &str, hub: &VirtualHub| {
        let dir = data_dir.as_ref().map(|dir| dir.join("sim").join(name));
        rack_for(name, preset, hub, dir).map(|rack| Some(Arc::new(rack) as BusDevices))
    }
}

/// The rack of the virtual bus `name` with the devices its preset names.
fn rack_for(
    name: &str,
    preset: &str,
    hub: &VirtualHub,
    data_dir: Option<PathBuf>,
) -> Result<Rack, String> {
    let rack = Rack::with_data_dir(hub.clone(), data_dir);
    let devices = parse_devices(preset).map_err(|err| format!("bus '{name}': {err}"))?;
    rack.add_all(&devices).map_err(|err| err.to_string())?;
    Ok(rack)
}

/// The virtual devices of a served bus.
pub trait RackOf {
    /// The bus's rack; `None` for a bus that is not virtual.
    fn rack(&self) -> Option<&Rack>;
}

impl RackOf for ServedBus {
    fn rack(&self) -> Option<&Rack> {
        self.devices().as_ref()?.downcast_ref::<Rack>()
    }
}
