//! candeck's SDO server against python-canopen's RemoteNode (its SDO client),
//! through candeck's socketcand server. The Python peers live in the `.venv`
//! that `scripts/test` makes (or wherever CANDECK_PYTHON points).

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use candeck::can::VirtualHub;
use candeck::can::socketcand::{ServerConfig, SocketcandServer};
use candeck::canopen::NodeId;
use candeck::canopen::eds::read_eds_file;
use candeck::canopen::od::Value;
use candeck::sim::device::{DeviceCore, run_device};

fn manifest_path(relative: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(relative)
}

fn python() -> PathBuf {
    let python = std::env::var_os("CANDECK_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| manifest_path(".venv/bin/python"));
    assert!(
        python.exists(),
        "{} is missing: run scripts/test once (it installs python-can and canopen into .venv)",
        python.display()
    );
    python
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_canopen_remote_node_reads_and_writes_a_candeck_sdo_server() {
    let hub = VirtualHub::new("can0");
    let server = SocketcandServer::bind(
        "127.0.0.1:0".parse().unwrap(),
        [("can0".to_string(), hub.clone())],
        ServerConfig::default(),
    )
    .await
    .unwrap()
    .spawn()
    .unwrap();
    let eds = manifest_path("tests/data/testnode.eds");
    let dictionary = read_eds_file(&eds).unwrap().dictionary;
    let node = NodeId::new(5).unwrap();
    let device = Arc::new(Mutex::new(DeviceCore::new(dictionary, node).unwrap()));
    let sdo_node = tokio::spawn(run_device(hub.attach(), device.clone()));

    let output = tokio::process::Command::new(python())
        .arg(manifest_path("tests/interop/remote_node_client.py"))
        .arg("127.0.0.1")
        .arg(server.local_addr().port().to_string())
        .arg("can0")
        .arg("5")
        .arg(&eds)
        .output()
        .await
        .unwrap();
    sdo_node.abort();
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        output.status.success(),
        "python failed:\n{stdout}\n{stderr}"
    );
    for line in [
        "expedited upload and download: ok",
        "segmented upload and download: ok",
        "block upload and download: ok",
        "aborts: ok",
    ] {
        assert!(
            stdout.contains(line),
            "missing '{line}' in:\n{stdout}\n{stderr}"
        );
    }
    // What python-canopen wrote is what the device holds.
    let device = device.lock().unwrap();
    let store = device.store();
    assert_eq!(store.get(0x2001, 0), Some(&Value::Unsigned8(200)));
    assert_eq!(
        store.get(0x2004, 0),
        Some(&Value::Integer64(-5_000_000_000))
    );
    let mut block = (0..=255u8).collect::<Vec<u8>>().repeat(9);
    block.extend_from_slice(b"tail");
    assert_eq!(store.get(0x2007, 0), Some(&Value::OctetString(block)));
    assert_eq!(store.get(0x2006, 0), Some(&Value::Unsigned32(0xCAFE)));
}
