//! candeck's SDO server against python-canopen's RemoteNode (its SDO client),
//! through candeck's socketcand server. The Python peers live in the `.venv`
//! that `scripts/test` makes (or wherever CANDECK_PYTHON points); without
//! them the test says `skipped: ...` on stderr and passes, unless
//! CANDECK_REQUIRE_PEERS is set (`tests/common/peers.rs`, whose rule is
//! tested here too).

#[path = "common/peers.rs"]
mod peers;

use std::ffi::OsStr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use candeck::can::VirtualHub;
use candeck::can::socketcand::{ServerConfig, SocketcandServer};
use candeck::canopen::NodeId;
use candeck::canopen::eds::read_eds_file;
use candeck::canopen::od::Value;
use candeck::sim::device::{DeviceCore, run_device};
use peers::{Decision, decide, flag, mosquitto_location, python_location};

fn manifest_path(relative: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(relative)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_canopen_remote_node_reads_and_writes_a_candeck_sdo_server() {
    let Some(python) =
        peers::python("python_canopen_remote_node_reads_and_writes_a_candeck_sdo_server")
    else {
        return;
    };
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

    let output = tokio::process::Command::new(&python)
        .arg(manifest_path("tests/interop/remote_node_client.py"))
        .arg("127.0.0.1")
        .arg(server.local_addr().port().to_string())
        .arg("can0")
        .arg("5")
        .arg(&eds)
        .output()
        .await
        .unwrap_or_else(|err| panic!("{}: {err}", python.display()));
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

// The rule of `peers`: which peer runs, which is skipped, which
// fails.

#[test]
fn a_yes_or_no_variable_says_yes_with_any_value_but_empty_and_zero() {
    assert!(!flag(None));
    assert!(!flag(Some(OsStr::new(""))));
    assert!(!flag(Some(OsStr::new("0"))));
    assert!(flag(Some(OsStr::new("1"))));
    assert!(flag(Some(OsStr::new("yes"))));
}

#[test]
fn a_missing_peer_is_skipped_unless_peers_are_required() {
    let found = || Ok(PathBuf::from("/opt/python"));
    let missing = || Err("no Python peers".to_string());
    assert_eq!(
        decide(found(), false),
        Decision::Run(PathBuf::from("/opt/python"))
    );
    assert_eq!(
        decide(found(), true),
        Decision::Run(PathBuf::from("/opt/python"))
    );
    assert_eq!(
        decide(missing(), false),
        Decision::Skip("no Python peers".to_string())
    );
    let Decision::Fail(message) = decide(missing(), true) else {
        panic!("a required peer that is missing must fail");
    };
    assert!(
        message.starts_with("no Python peers; CANDECK_REQUIRE_PEERS is set"),
        "{message}"
    );
}

#[test]
fn candeck_python_wins_over_the_venv_which_is_used_only_when_it_exists() {
    let dir = std::env::temp_dir().join(format!("candeck-peers-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let venv = dir.join("python");
    let absent = dir.join("absent");
    std::fs::write(&venv, "").unwrap();
    let set = Some(OsStr::new("/elsewhere/python"));
    assert_eq!(
        python_location(set, &venv),
        Ok(PathBuf::from("/elsewhere/python"))
    );
    assert_eq!(
        python_location(set, &absent),
        Ok(PathBuf::from("/elsewhere/python"))
    );
    assert_eq!(python_location(None, &venv), Ok(venv.clone()));
    assert_eq!(
        python_location(Some(OsStr::new("")), &venv),
        Ok(venv.clone())
    );
    let reason = python_location(None, &absent).unwrap_err();
    assert!(reason.contains("CANDECK_PYTHON is not set"), "{reason}");
    assert!(reason.contains(&absent.display().to_string()), "{reason}");
    assert_eq!(
        mosquitto_location(&[absent.as_path(), venv.as_path()]),
        Ok(venv.clone())
    );
    assert!(mosquitto_location(&[absent.as_path()]).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}
