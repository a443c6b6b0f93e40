//! The gateway's life: [`Gateway::start`] opens what it keeps (the data
//! directory, the history, the EDS catalog), every bus with its network
//! manager, and the work that runs beside the doors (history and
//! recordings pruning, the data loggers, each bus's first scan);
//! [`Gateway::shutdown`] leaves no drive moving and nothing half written.
//! The command line parses its arguments into a [`GatewayConfig`] and calls
//! them; the doors are started on the gateway it gets back.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::can::spec::BusSpec;
use crate::canopen::manager::NodeDescription;

use super::access::{RateLimit, Tokens};
use super::history::{History, Retention};
use super::logger::{LoggerConfig, Loggers};
use super::machine::MachineSettings;
use super::producers::TelemetryConfig;
use super::profile::EdsCatalog;
use super::recording::{RecordingState, RecordingsQuota};
use super::registry::RegistryConfig;
use super::safe_stop::StopReport;
use super::service::{AttachDevices, Gateway, ServedBus};

/// How long the first scan of a bus waits for the bus to come up (a
/// socketcand bus is still connecting when the gateway starts).
pub(crate) const FIRST_SCAN_WAIT: Duration = Duration::from_secs(30);

/// How often the kept recordings are checked against their quota.
const RECORDINGS_PRUNE_PERIOD: Duration = Duration::from_secs(60);

/// What the gateway is started with.
#[derive(Debug, Clone)]
pub struct GatewayConfig {
    /// The buses to serve, by name, in order (CiA 309 net 1 is the first).
    pub buses: Vec<(String, BusSpec)>,
    /// Where the history, uploaded EDS files, recordings, loggers and the
    /// virtual devices' saved values are kept (made `0700`); `None`: in
    /// memory and temporary files, lost on exit.
    pub data_dir: Option<PathBuf>,
    /// EDS files besides the built-in ones (`--eds-dir`).
    pub eds_dir: Option<PathBuf>,
    /// The bit rate of the buses (a virtual bus's wire, the load meter).
    pub bitrate: u32,
    pub telemetry: TelemetryConfig,
    pub retention: Retention,
    /// The kept recordings' quota in bytes (with a data directory only).
    pub recordings_quota: Option<u64>,
    /// Values one data logger keeps in memory.
    pub logger_max_values: usize,
    /// The motion leases' period (`--lease-ms`).
    pub lease_period: Duration,
    /// The tokens and their roles; none: the gateway is open.
    pub tokens: Tokens,
    /// The write rate limit of every token, whichever door its writes take.
    pub write_limit: Option<RateLimit>,
    /// The SYNC producer's period on every bus; zero: off.
    pub sync_period: Duration,
    /// The network manager of every bus, and the nodes described for each
    /// (by bus name).
    pub machine: MachineSettings,
    pub machine_nodes: BTreeMap<String, Vec<NodeDescription>>,
    /// The SDO samples a second per node that sampled objects may take
    /// ([`Gateway::sample_objects`]), whichever door asks them.
    pub sdo_samples_per_s: u32,
}

/// Why the gateway could not start: one line naming the setting.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct StartError(pub String);

/// The gateway's own tasks, ended by [`Gateway::shutdown`].
#[derive(Debug, Default)]
pub(crate) struct BackgroundTasks(Mutex<Vec<tokio::task::JoinHandle<()>>>);

impl BackgroundTasks {
    fn push(&self, task: tokio::task::JoinHandle<()>) {
        self.0
            .lock()
            .unwrap_or_else(|poison| poison.into_inner())
            .push(task);
    }

    fn abort_all(&self) {
        let tasks = std::mem::take(&mut *self.0.lock().unwrap_or_else(|p| p.into_inner()));
        for task in tasks {
            task.abort();
        }
    }
}

impl Gateway {
    /// Starts the gateway: the data directory made (`0700`), the history
    /// opened before the buses (so that their first events are kept), the
    /// EDS catalog, each bus opened (a virtual bus with the devices
    /// `attach` puts on it) with its SYNC period and its network manager,
    /// then the pruners, the loggers a run before kept, and each bus's
    /// first scan (nodes that booted before the gateway listened, nodes
    /// without heartbeat); the doors may answer meanwhile.
    pub async fn start(
        config: GatewayConfig,
        attach: AttachDevices<'_>,
    ) -> Result<Gateway, StartError> {
        if !(1..=super::sampling::MAX_SDO_SAMPLES_PER_S).contains(&config.sdo_samples_per_s) {
            return Err(StartError(format!(
                "sdo_samples_per_s {} is not between 1 and {}",
                config.sdo_samples_per_s,
                super::sampling::MAX_SDO_SAMPLES_PER_S
            )));
        }
        if let Some(dir) = &config.data_dir {
            // 0700 when candeck makes it (docs/security.md, "Files").
            super::files::create_private_dir(dir)
                .map_err(|err| StartError(format!("--data-dir {}: {err}", dir.display())))?;
        }
        let history = match &config.data_dir {
            Some(dir) => History::open(dir),
            None => History::in_memory(),
        }
        .map_err(|err| StartError(err.to_string()))?;
        let catalog = match &config.eds_dir {
            Some(dir) => EdsCatalog::with_dir(dir),
            None => EdsCatalog::builtin(),
        }
        .map_err(|err| StartError(err.to_string()))?;
        // Uploaded EDS files are kept in DATA/eds; without a data
        // directory, in memory.
        let catalog = match &config.data_dir {
            Some(dir) => catalog.with_uploads(dir.join("eds")),
            None => Ok(catalog),
        }
        .map_err(|err| StartError(err.to_string()))?;
        let catalog = Arc::new(catalog);
        let mut served = Vec::with_capacity(config.buses.len());
        for (name, spec) in &config.buses {
            served.push(open_bus(&config, name, spec, catalog.clone(), &history, attach).await?);
        }
        let mut gateway = Gateway::with_history(served, history.clone())
            .with_lease_period(config.lease_period)
            .with_tokens(config.tokens.clone())
            .with_write_limit(config.write_limit)
            .with_sdo_samples_per_s(config.sdo_samples_per_s)
            .with_loggers(Loggers::load(LoggerConfig {
                max_values: config.logger_max_values,
                dir: config.data_dir.as_ref().map(|dir| dir.join("loggers")),
            }));
        if let (Some(dir), Some(bytes)) = (&config.data_dir, config.recordings_quota) {
            gateway = gateway.with_recordings_quota(RecordingsQuota {
                dir: dir.join("recordings"),
                bytes,
            });
        }
        // The network manager stops an enabled axis before it writes the
        // node's motion objects (machine.rs).
        for (name, bus) in gateway.buses.iter() {
            if let (Some(machine), Some(stopper)) =
                (&bus.machine, super::machine::motion_stopper(&gateway, name))
            {
                machine.set_motion_stopper(stopper);
            }
        }
        gateway
            .background
            .push(history.spawn_pruner(config.retention));
        gateway
            .background
            .push(gateway.spawn_recordings_pruner(RECORDINGS_PRUNE_PERIOD));
        for bus in gateway.buses.values() {
            gateway
                .background
                .push(tokio::spawn(first_scan(bus.clone())));
        }
        Ok(gateway)
    }

    /// The gateway's end: every axis it enabled stopped (whatever a door
    /// is still doing), a running recording ended with all it received
    /// written, and its own tasks ended. What could not be stopped is in
    /// the report. The doors should be closed first: a request finished
    /// after this could set an axis moving again.
    pub async fn shutdown(&self) -> StopReport {
        let report = self.stop_enabled_axes().await;
        for bus in self.buses.values() {
            if bus.recorder.status().state == RecordingState::Recording {
                let _ = bus.recorder.stop().await;
            }
        }
        self.background.abort_all();
        report
    }
}

/// Opens one bus of `config` as the gateway serves it.
async fn open_bus(
    config: &GatewayConfig,
    name: &str,
    spec: &BusSpec,
    catalog: Arc<EdsCatalog>,
    history: &History,
    attach: AttachDevices<'_>,
) -> Result<ServedBus, StartError> {
    // No expected node at the gateway's own node-ID, before the bus opens.
    super::machine::check_descriptions(
        name,
        &MachineSettings {
            nodes: config.machine_nodes.get(name).cloned().unwrap_or_default(),
            ..config.machine.clone()
        },
    )
    .map_err(StartError)?;
    let registry = RegistryConfig {
        telemetry: config.telemetry.clone(),
        // The network manager's supervision, timed by the registry's one
        // supervisor.
        consumer_factor: config.machine.manager.consumer_factor,
        ..RegistryConfig::default()
    };
    let mut opened =
        ServedBus::open_with_devices(name, spec, catalog, registry, config.bitrate, attach)
            .await
            .map_err(|err| StartError(format!("bus {name}: {err}")))?;
    if let Some(dir) = &config.data_dir {
        opened = opened.with_recordings_dir(dir.join("recordings"));
    }
    // What PUT /buses/{bus}/sync would set, from the start.
    opened.sync.set_period(config.sync_period);
    // The network manager (CiA 302-2): the gateway's heartbeat, and every
    // node booted, supervised and started.
    let machine = MachineSettings {
        nodes: config.machine_nodes.get(name).cloned().unwrap_or_default(),
        ..config.machine.clone()
    };
    // A description's `eds` describes its node from the start, before it
    // is heard, as assigning the file by hand would.
    for node in &machine.nodes {
        if let Some(file) = &node.eds {
            let entry = opened.registry.catalog().find(file).ok_or_else(|| {
                StartError(format!(
                    "config: [[nodes]] bus {name} id {}: eds \"{file}\" is no file of the EDS catalog (built-in, --eds-dir or uploaded; `candeck eds check` tells why a file is left out)",
                    node.id
                ))
            })?;
            opened.registry.assign_eds(node.id, Some(entry));
        }
    }
    Ok(opened.with_machine(machine, Some(history.clone())))
}

/// The first scan of a bus, once it is up; then the expected nodes it did
/// not find are missing.
async fn first_scan(bus: Arc<ServedBus>) {
    let name = &bus.name;
    if let Err(err) = bus.bus.wait_up(FIRST_SCAN_WAIT).await {
        tracing::warn!("bus {name}: not up for the first scan ({err}); POST /scan later");
    } else {
        match bus.registry.scan().await {
            Ok(nodes) => tracing::info!("bus {name}: {} nodes found", nodes.len()),
            Err(err) => tracing::warn!("bus {name}: first scan failed: {err}"),
        }
    }
    if let Some(machine) = &bus.machine {
        machine.scan_done();
    }
}

#[cfg(test)]
mod tests;
