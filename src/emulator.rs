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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::umc::Load;

    async fn open(spec: &str) -> Result<ServedBus, String> {
        let spec: BusSpec = spec
            .parse()
            .map_err(|err: crate::can::spec::SpecError| err.to_string())?;
        open_bus(
            "virtual",
            &spec,
            Arc::new(EdsCatalog::builtin().unwrap()),
            RegistryConfig::default(),
            500_000,
        )
        .await
    }

    /// Issue 32: a UMC's load in a `virtual:LIST` bus spec, as `--devices`
    /// takes it (the bus's bit rate after the last device), and a load out
    /// of range refused with what is wrong when the bus opens.
    #[tokio::test(start_paused = true)]
    async fn a_bus_specs_device_list_carries_each_umcs_load() {
        let spec: BusSpec = "virtual:umc1bds32@1?inertia=0.003&friction=0.0002,jmc@2?bitrate=125k"
            .parse()
            .unwrap();
        let BusSpec::Virtual { preset, bitrate } = &spec else {
            panic!("{spec:?}");
        };
        assert_eq!(bitrate.and_then(|b| b.get()), Some(125_000));
        let devices = parse_devices(preset).unwrap();
        assert_eq!(
            devices[0].load,
            Some(Load::new(Some(0.003), Some(0.0002)).unwrap())
        );
        assert_eq!(devices[1].load, None);
        let served = open(&spec.to_string()).await.unwrap();
        assert_eq!(served.rack().unwrap().devices().len(), 2);

        let refused = open("virtual:umc1bds32@1?inertia=5").await.err().unwrap();
        assert!(
            refused.starts_with("bus 'virtual': 'umc1bds32@1?inertia=5': inertia 5 kg·m² is out of range: 0.00002 to 1"),
            "{refused}"
        );
        let refused = open("virtual:umc1bds32@1?friction=-1&bitrate=unlimited")
            .await
            .err()
            .unwrap();
        assert!(
            refused.contains("friction -1 N·m·s is out of range"),
            "{refused}"
        );
        let refused = open("virtual:jmc@2?inertia=0.001").await.err().unwrap();
        assert!(refused.contains("jmc drives no motor"), "{refused}");
    }
}
