//! SDO expedited uploads per second and segmented upload throughput, against
//! one candeck SDO server (the interop test node, tests/data/testnode.eds):
//! - the client and server state machines wired together, no bus (protocol cost);
//! - in-process over the virtual hub (candeck's SdoChannel);
//! - over candeck's socketcand server on loopback (candeck's SdoChannel);
//! - over the same socketcand server, python-canopen's RemoteNode.
//!
//! Run: `scripts/bench` (or `cargo bench --bench sdo`; python-canopen's
//! row uses `.venv` or `CANDECK_PYTHON`, and is skipped without them unless
//! `CANDECK_REQUIRE_PEERS` is set). A smoke run (`CANDECK_BENCH_SMOKE`) does
//! a few hundred uploads a row. A failed python-canopen run ends the run
//! with status 1.

mod common;

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use candeck::can::socketcand::{ClientConfig, ServerConfig, SocketcandServer, open_socketcand};
use candeck::can::{Bus, VirtualHub};
use candeck::canopen::NodeId;
use candeck::canopen::eds::read_eds_file;
use candeck::canopen::od::Value;
use candeck::canopen::sdo::{self, ObjectAccess, SdoClient, SdoServer, Step, Transfer};
use candeck::gateway::SdoChannel;
use candeck::sim::device::{DeviceCore, run_device};

const SEGMENTED_BYTES: usize = 1000;

fn device() -> DeviceCore {
    let eds = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/testnode.eds");
    let dictionary = read_eds_file(&eds).expect("test EDS").dictionary;
    let mut device = DeviceCore::new(dictionary, NodeId::new(5).expect("node")).expect("device");
    device
        .store_mut()
        .set(0x2007, 0, Value::OctetString(vec![0x5A; SEGMENTED_BYTES]))
        .expect("block data");
    device
}

struct Figures {
    label: String,
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
    let mut device = device();
    let store = device.store_mut();
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
        assert_eq!(upload(0x2003, &mut *store).len(), 4);
    }
    let expedited_per_s = f64::from(expedited) / start.elapsed().as_secs_f64();
    let start = Instant::now();
    for _ in 0..segmented {
        assert_eq!(upload(0x2007, &mut *store).len(), SEGMENTED_BYTES);
    }
    let segmented_bytes_per_s =
        f64::from(segmented) * SEGMENTED_BYTES as f64 / start.elapsed().as_secs_f64();
    Figures {
        label: "state machines only, no bus".into(),
        expedited_per_s,
        segmented_bytes_per_s,
    }
}

async fn over_channel(label: &str, bus: Bus, expedited: u32, segmented: u32) -> Figures {
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
        label: label.to_string(),
        expedited_per_s,
        segmented_bytes_per_s,
    }
}

/// The SDO node and the socketcand server on a thread and runtime of their
/// own, as `candeck vbus` is a process of its own: every socketcand client
/// (ours and python-canopen) talks to it across threads alike.
fn spawn_server_thread() -> (u16, std::sync::mpsc::Sender<()>) {
    let (port_tx, port_rx) = std::sync::mpsc::channel();
    let (stop_tx, stop_rx) = std::sync::mpsc::channel::<()>();
    std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        runtime.block_on(async move {
            let hub = VirtualHub::new("can0");
            let _node = tokio::spawn(run_device(hub.attach(), Arc::new(Mutex::new(device()))));
            let server = SocketcandServer::bind(
                "127.0.0.1:0".parse().expect("addr"),
                [("can0".to_string(), hub.clone())],
                ServerConfig::default(),
            )
            .await
            .expect("bind")
            .spawn()
            .expect("spawn");
            port_tx.send(server.local_addr().port()).expect("port");
            while stop_rx.try_recv().is_err() {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        });
    });
    (port_rx.recv().expect("server thread"), stop_tx)
}

/// The in-process row (client and node on one runtime) and the socketcand
/// row (the server on its own thread) for one kind of client runtime.
fn bus_rows(runtime: &tokio::runtime::Runtime, flavour: &str, port: u16) {
    runtime.block_on(async {
        let hub = VirtualHub::new("can0");
        let _node = tokio::spawn(run_device(hub.attach(), Arc::new(Mutex::new(device()))));
        over_channel(
            &format!("candeck, in-process virtual bus, {flavour}"),
            hub.attach(),
            common::pick(100_000, 500),
            common::pick(1_000, 10),
        )
        .await
        .print();

        let remote = open_socketcand("can0", ClientConfig::new("127.0.0.1", port, "can0"));
        remote.wait_up(Duration::from_secs(5)).await.expect("up");
        tokio::time::sleep(Duration::from_millis(200)).await;
        over_channel(
            &format!("candeck, socketcand on loopback, {flavour}"),
            remote,
            common::pick(20_000, 200),
            common::pick(300, 5),
        )
        .await
        .print();
    });
}

/// python-canopen's row; why it failed, if it did.
async fn python_row(port: u16) -> Result<(), String> {
    let Some(python) = common::peers::python("sdo, python-canopen row") else {
        println!("| python-canopen | skipped: no Python peers | |");
        return Ok(());
    };
    let eds = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/testnode.eds");
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("benches/python_sdo_reader.py");
    let counts = common::pick(["2000", "50"], ["100", "5"]);
    let output = tokio::process::Command::new(&python)
        .arg(script)
        .args(["127.0.0.1", &port.to_string(), "can0", "5"])
        .arg(eds)
        .args(counts)
        .output()
        .await
        .map_err(|err| format!("{}: {err}", python.display()))?;
    let text = String::from_utf8_lossy(&output.stdout);
    let numbers: Vec<f64> = text
        .split_whitespace()
        .filter_map(|n| n.parse().ok())
        .collect();
    if let (true, [expedited, segmented]) = (output.status.success(), numbers.as_slice()) {
        Figures {
            label: "python-canopen RemoteNode, socketcand on loopback (same server)".into(),
            expedited_per_s: *expedited,
            segmented_bytes_per_s: *segmented,
        }
        .print();
        Ok(())
    } else {
        println!("| python-canopen | failed | |");
        Err(format!(
            "python-canopen ({}): {}{}",
            output.status,
            text,
            String::from_utf8_lossy(&output.stderr)
        ))
    }
}

/// The floor of any request/response over TCP on this machine: a 30-byte
/// ping-pong between two threads, each blocking on its socket.
fn tcp_round_trips(count: u32) -> f64 {
    use std::io::{Read, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("addr");
    let echo = std::thread::spawn(move || {
        let (mut stream, _) = listener.accept().expect("accept");
        stream.set_nodelay(true).expect("nodelay");
        let mut buf = [0u8; 64];
        while let Ok(n) = stream.read(&mut buf) {
            if n == 0 || stream.write_all(&buf[..n]).is_err() {
                break;
            }
        }
    });
    let mut stream = std::net::TcpStream::connect(addr).expect("connect");
    stream.set_nodelay(true).expect("nodelay");
    let message = [b'x'; 30];
    let mut buf = [0u8; 64];
    let start = Instant::now();
    for _ in 0..count {
        stream.write_all(&message).expect("write");
        let mut got = 0;
        while got < message.len() {
            got += stream.read(&mut buf).expect("read");
        }
    }
    let rate = f64::from(count) / start.elapsed().as_secs_f64();
    drop(stream);
    let _ = echo.join();
    rate
}

fn main() {
    common::announce_smoke("sdo");
    println!(
        "TCP round trips between two threads on loopback (the floor of one SDO exchange): {:.0}/s",
        tcp_round_trips(common::pick(20_000, 500))
    );
    println!();
    println!("| client and path | expedited uploads/s | segmented upload, bytes/s |");
    println!("|---|---|---|");
    state_machines(common::pick(200_000, 1_000), common::pick(2_000, 10)).print();
    let (port, stop) = spawn_server_thread();
    let current = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    bus_rows(&current, "current-thread runtime (the binary's)", port);
    let python = current.block_on(python_row(port));
    let multi = tokio::runtime::Runtime::new().expect("runtime");
    bus_rows(&multi, "tokio multi-thread runtime", port);
    let _ = stop.send(());
    common::exit_on_failures("sdo", &python.err().into_iter().collect::<Vec<_>>());
}
