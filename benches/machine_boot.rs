//! The network manager bringing up a full bus: 126 virtual UIO1LEDs (node
//! ids 1 to 126; 127 is the gateway's own, its heartbeat on 0x77F), each
//! described in `[[nodes]]` with a 20-entry DCF and a heartbeat of 200 ms,
//! from gateway start (the bus opened, the manager started, the devices
//! booting) to the machine `ready` (every node checked, configured,
//! supervised, started and heard operational). Counted: the frames the
//! gateway sent, the frames on the bus, and the SDO transfers (the
//! manager's, and the registry's identification reads beside them).
//!
//! Run: `cargo bench --bench machine_boot` (both bit rates: the virtual
//! bus without a bit rate, software time only, and at 500 kbit/s). A smoke
//! run (`CANDECK_BENCH_SMOKE`) has 4 nodes. A machine not ready within 60 s
//! ends the run in a panic.

mod common;

use candeck::emulator::RackOf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use candeck::can::spec::BusSpec;
use candeck::canopen::NodeId;
use candeck::canopen::manager::{MachineState, ManagerConfig, NodeDescription};
use candeck::gateway::EdsCatalog;
use candeck::gateway::MachineSettings;
use candeck::gateway::RegistryConfig;
use candeck::sim::products::Product;

/// Node ids 1 to this (`CANDECK_BENCH_NODES` for fewer; 4 in a smoke run).
fn nodes() -> u8 {
    std::env::var("CANDECK_BENCH_NODES")
        .ok()
        .and_then(|n| n.parse().ok())
        .unwrap_or(common::pick(126, 4))
}
const HEARTBEAT_MS: u16 = 200;

/// 20 ParameterValue entries of the UIO1LED: TPDO 1–4 transmission type,
/// inhibit time, event timer, SYNC start value (16), LED type and count of
/// segments 1 and 2 (4).
fn dcf() -> String {
    let mut text = String::from("[DeviceComissioning]\nNodeID=1\n\n");
    let entry = |text: &mut String, index: u16, sub: u8, name: &str, data_type: u8, value: &str| {
        text.push_str(&format!(
            "[{index:04X}sub{sub}]\nParameterName={name}\nObjectType=0x7\nDataType=0x{data_type:04X}\nAccessType=rw\nParameterValue={value}\n\n"
        ));
    };
    for n in 0..4u16 {
        let index = 0x1800 + n;
        text.push_str(&format!(
            "[{index:04X}]\nParameterName=TPDO communication parameter {}\nObjectType=0x9\nSubNumber=5\n\n",
            n + 1
        ));
        entry(&mut text, index, 2, "Transmission_type", 5, "255");
        entry(&mut text, index, 3, "Inhibit_time", 6, "10");
        entry(&mut text, index, 5, "Event_timer", 6, "0");
        entry(&mut text, index, 6, "SYNC_start_value", 5, "0");
    }
    for (index, name, data_type) in [
        (0x6000u16, "s01_Led_type", 5u8),
        (0x6001, "s01_Led_count", 6),
        (0x6100, "s02_Led_type", 5),
        (0x6101, "s02_Led_count", 6),
    ] {
        text.push_str(&format!(
            "[{index:04X}]\nParameterName={name}\nObjectType=0x7\nDataType=0x{data_type:04X}\nAccessType=rw\nParameterValue=0\n\n"
        ));
    }
    text
}

struct Figures {
    to_ready: Duration,
    gateway_frames: u64,
    bus_frames: u64,
    sdo_transfers: u64,
}

async fn run(spec: &str, dcf_path: &std::path::Path) -> Figures {
    let spec: BusSpec = spec.parse().expect("bus spec");
    let catalog = Arc::new(EdsCatalog::builtin().expect("built-in EDS"));
    let described: Vec<NodeDescription> = (1..=nodes())
        .map(|id| {
            let id = NodeId::new(id).expect("node id");
            let mut node = NodeDescription::new(id);
            node.heartbeat_ms = HEARTBEAT_MS;
            node.config = candeck::gateway::load_dcf(dcf_path, id).expect("the bench's DCF");
            assert_eq!(node.config.len(), 20);
            node
        })
        .collect();
    let started = Instant::now();
    let served =
        candeck::emulator::open_bus("bench", &spec, catalog, RegistryConfig::default(), 500_000)
            .await
            .expect("bus")
            .with_machine(
                MachineSettings {
                    manager: ManagerConfig::default(),
                    nodes: described,
                },
                None,
            );
    let rack = served.rack().expect("a virtual bus");
    for id in 1..=nodes() {
        rack.add(Product::Uio1led, NodeId::new(id).expect("node id"))
            .expect("device");
    }
    let machine = served.machine().expect("manager").clone();
    // Every device boots after the gateway listens: no scan to wait for.
    machine.scan_done();
    let status = machine
        .wait_for(MachineState::Ready, Duration::from_secs(60))
        .await;
    let to_ready = started.elapsed();
    assert_eq!(
        status.state,
        MachineState::Ready,
        "not ready within 60 s: {:?}",
        status
    );
    let sdo_transfers = served
        .node_metrics()
        .iter()
        .map(|node| node.sdo.transactions)
        .sum();
    Figures {
        to_ready,
        gateway_frames: served.counters().tx_frames,
        bus_frames: served
            .hub()
            .map_or(0, candeck::can::VirtualHub::frames_total),
        sdo_transfers,
    }
}

fn main() {
    common::announce_smoke("machine_boot");
    // The runtime of the candeck binary: one thread.
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    let dir = std::env::temp_dir().join(format!("candeck-machine-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let dcf_path = dir.join("bench.dcf");
    std::fs::write(&dcf_path, dcf()).expect("DCF");
    println!(
        "{} UIO1LEDs, each a 20-entry DCF and heartbeat {HEARTBEAT_MS} ms; manager node 127, heartbeat 100 ms",
        nodes()
    );
    println!(
        "| bus | start to machine ready | frames sent by the gateway | frames on the bus | SDO transfers |"
    );
    println!("|---|---|---|---|---|");
    for (label, spec) in [
        ("virtual, no bit rate", "virtual:empty?bitrate=unlimited"),
        ("virtual, 500 kbit/s", "virtual:empty?bitrate=500000"),
    ] {
        let figures = runtime.block_on(run(spec, &dcf_path));
        println!(
            "| {label} | {:.0} ms | {} | {} | {} |",
            figures.to_ready.as_secs_f64() * 1000.0,
            figures.gateway_frames,
            figures.bus_frames,
            figures.sdo_transfers
        );
    }
    let _ = std::fs::remove_dir_all(dir);
}
