//! SDO expedited uploads per second and segmented upload throughput, against
//! one candeck SDO server (the interop test node, tests/data/testnode.eds):
//! - the client and server state machines wired together, no bus (protocol cost);
//! - in-process over the virtual hub (candeck's SdoChannel);
//! - over candeck's socketcand server on loopback (candeck's SdoChannel);
//! - over the same socketcand server, python-canopen's RemoteNode.
//!
//! Run: `scripts/bench` (or `cargo bench --bench sdo` with
//! `CANDECK_PYTHON=.venv/bin/python` for python-canopen).

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use candeck::can::socketcand::{ClientConfig, ServerConfig, SocketcandServer, open_socketcand};
use candeck::can::{Bus, VirtualHub};
use candeck::canopen::NodeId;
use candeck::canopen::eds::read_eds_file;
use candeck::canopen::od::Value;
use candeck::canopen::sdo::{self, ObjectAccess, SdoClient, SdoServer, Step, Transfer};
use candeck::gateway::sdo::SdoChannel;
use candeck::sim::objects::ObjectStore;
use candeck::sim::sdo_node::serve_sdo;

const SEGMENTED_BYTES: usize = 1000;

fn store() -> ObjectStore {
    let eds = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/testnode.eds");
    let dictionary = read_eds_file(&eds).expect("test EDS").dictionary;
    let mut store = ObjectStore::new(dictionary, NodeId::new(5).expect("node")).expect("store");
    store
        .set(0x2007, 0, Value::OctetString(vec![0x5A; SEGMENTED_BYTES]))
        .expect("block data");
    store
}

struct Figures {
    label: &'static str,
    expedited_per_s: f64,
    segmented_bytes_per_s: f64,
}

impl Figures {
    fn print(&self) {
        println!(
            "| {} | {:.0} | {:.0} |",
            self.label, self.expedited_per_s, self.segmented_bytes_per_s
        );
    }
}

/// Client and server machines passing frames to each other directly.
fn state_machines(expedited: u32, segmented: u32) -> Figures {
    let node = NodeId::new(5).expect("node");
    let mut store = store();
    let mut client = SdoClient::new(node, sdo::ClientConfig::default());
    let mut server = SdoServer::new(node, sdo::ServerConfig::default());
    let mut upload = |index: u16, store: &mut dyn ObjectAccess| -> Vec<u8> {
        let now = Instant::now();
        let mut to_server = client.upload(index, 0, now).expect("idle");
        loop {
            let mut step = Step {
                send: Vec::new(),
                done: None,
            };
            for frame in to_server.drain(..) {
                for reply in server.handle_frame(&frame, now, store) {
                    let next = client.handle_frame(&reply, now);
                    step.send.extend(next.send);
                    if next.done.is_some() {
                        step.done = next.done;
                    }
                }
            }
            if let Some(done) = step.done {
                match done.expect("upload") {
                    Transfer::Uploaded(data) => return data,
                    Transfer::Downloaded => unreachable!("an upload"),
                }
            }
            to_server = step.send;
        }
    };
    let start = Instant::now();
    for _ in 0..expedited {
        assert_eq!(upload(0x2003, &mut store).len(), 4);
    }
    let expedited_per_s = f64::from(expedited) / start.elapsed().as_secs_f64();
    let start = Instant::now();
    for _ in 0..segmented {
        assert_eq!(upload(0x2007, &mut store).len(), SEGMENTED_BYTES);
    }
    let segmented_bytes_per_s =
        f64::from(segmented) * SEGMENTED_BYTES as f64 / start.elapsed().as_secs_f64();
    Figures {
        label: "state machines only, no bus",
        expedited_per_s,
        segmented_bytes_per_s,
    }
}

async fn over_channel(label: &'static str, bus: Bus, expedited: u32, segmented: u32) -> Figures {
    let channel = SdoChannel::new(
        bus,
        NodeId::new(5).expect("node"),
        sdo::ClientConfig::default(),
    );
    let start = Instant::now();
    for _ in 0..expedited {
        assert_eq!(channel.upload(0x2003, 0).await.expect("upload").len(), 4);
    }
    let expedited_per_s = f64::from(expedited) / start.elapsed().as_secs_f64();
    let start = Instant::now();
    for _ in 0..segmented {
        assert_eq!(
            channel.upload(0x2007, 0).await.expect("upload").len(),
            SEGMENTED_BYTES
        );
    }
    let segmented_bytes_per_s =
        f64::from(segmented) * SEGMENTED_BYTES as f64 / start.elapsed().as_secs_f64();
    Figures {
        label,
        expedited_per_s,
        segmented_bytes_per_s,
    }
}

fn main() {
    let runtime = tokio::runtime::Runtime::new().expect("runtime");
    println!("| client and path | expedited uploads/s | segmented upload, bytes/s |");
    println!("|---|---|---|");
    state_machines(200_000, 2_000).print();
    runtime.block_on(async {
        let hub = VirtualHub::new("can0");
        let store = Arc::new(Mutex::new(store()));
        let _node = tokio::spawn(serve_sdo(hub.attach(), store, sdo::ServerConfig::default()));
        over_channel(
            "candeck, in-process virtual bus",
            hub.attach(),
            100_000,
            1_000,
        )
        .await
        .print();

        let server = SocketcandServer::bind(
            "127.0.0.1:0".parse().expect("addr"),
            [("can0".to_string(), hub.clone())],
            ServerConfig::default(),
        )
        .await
        .expect("bind")
        .spawn()
        .expect("spawn");
        let port = server.local_addr().port();
        let remote = open_socketcand("can0", ClientConfig::new("127.0.0.1", port, "can0"));
        remote.wait_up(Duration::from_secs(5)).await.expect("up");
        tokio::time::sleep(Duration::from_millis(200)).await;
        over_channel("candeck, socketcand on loopback", remote, 20_000, 300)
            .await
            .print();

        match std::env::var("CANDECK_PYTHON") {
            Ok(python) => {
                let eds = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/testnode.eds");
                let script =
                    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("benches/python_sdo_reader.py");
                let output = tokio::process::Command::new(python)
                    .arg(script)
                    .args(["127.0.0.1", &port.to_string(), "can0", "5"])
                    .arg(eds)
                    .args(["2000", "50"])
                    .output()
                    .await
                    .expect("python runs");
                let text = String::from_utf8_lossy(&output.stdout);
                let numbers: Vec<f64> = text
                    .split_whitespace()
                    .filter_map(|n| n.parse().ok())
                    .collect();
                if let (true, [expedited, segmented]) =
                    (output.status.success(), numbers.as_slice())
                {
                    Figures {
                        label: "python-canopen RemoteNode, socketcand on loopback",
                        expedited_per_s: *expedited,
                        segmented_bytes_per_s: *segmented,
                    }
                    .print();
                } else {
                    println!(
                        "| python-canopen | failed: {} | |",
                        String::from_utf8_lossy(&output.stderr)
                            .lines()
                            .last()
                            .unwrap_or("")
                    );
                }
            }
            Err(_) => println!("| python-canopen | skipped: set CANDECK_PYTHON | |"),
        }
    });
}
