//! The `candeck` binary as a user meets it: bad input gives one clear line on
//! stderr and a non-zero exit, never a panic or a backtrace.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

fn candeck(args: &[&str]) -> (i32, String, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(args)
        .env_remove("CANDECK_LOG")
        .output()
        .expect("candeck runs");
    (
        output.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

fn assert_one_clear_line(stderr: &str, expected: &str) {
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "expected one line, got: {stderr}");
    assert!(lines[0].starts_with("candeck: error: "), "{stderr}");
    assert!(lines[0].contains(expected), "'{expected}' not in: {stderr}");
    assert!(
        !stderr.contains("panicked") && !stderr.contains("RUST_BACKTRACE"),
        "{stderr}"
    );
}

#[test]
fn bad_arguments_give_one_line_and_status_2() {
    let cases: &[(&[&str], &str)] = &[
        (&["frobnicate"], "unrecognized subcommand 'frobnicate'"),
        (&["dump"], "--bus <SPEC>"),
        (&["dump", "--bus", "can0"], "bus spec 'can0' is not one of"),
        (
            &["dump", "--bus", "socketcand:host/can0"],
            "expected socketcand:HOST:PORT/CHANNEL",
        ),
        (
            &["dump", "--bus", "socketcand:h:70000/can0"],
            "port '70000' is not 1 to 65535",
        ),
        (
            &["dump", "--bus", "virtual:empty", "--count", "many"],
            "invalid value 'many'",
        ),
        (
            &["vbus", "--listen", "localhost"],
            "invalid value 'localhost'",
        ),
    ];
    for (args, expected) in cases {
        let (code, _, stderr) = candeck(args);
        assert_eq!(code, 2, "{args:?}: {stderr}");
        assert_one_clear_line(&stderr, expected);
    }
}

#[test]
fn failures_while_running_give_one_line_and_status_1() {
    // Find a port nobody listens on.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let spec = format!("socketcand:127.0.0.1:{port}/can0");
    let cases: Vec<(Vec<String>, String)> = vec![
        (
            vec![
                "dump".into(),
                "--bus".into(),
                spec,
                "--connect-timeout".into(),
                "0.5".into(),
            ],
            "cannot connect to socketcand at 127.0.0.1:".into(),
        ),
        (
            vec![
                "dump".into(),
                "--bus".into(),
                "replay:/nonexistent/line.log".into(),
            ],
            "/nonexistent/line.log".into(),
        ),
        (
            vec![
                "dump".into(),
                "--bus".into(),
                "virtual:empty".into(),
                "--seconds=-1".into(),
            ],
            "--seconds -1: expected a number of seconds".into(),
        ),
    ];
    for (args, expected) in cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (code, _, stderr) = candeck(&args);
        assert_eq!(code, 1, "{args:?}: {stderr}");
        assert_one_clear_line(&stderr, &expected);
    }
}

#[test]
fn a_port_in_use_is_reported_in_one_line() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let (code, _, stderr) = candeck(&["vbus", "--listen", &addr]);
    assert_eq!(code, 1, "{stderr}");
    assert_one_clear_line(&stderr, &format!("cannot listen on {addr}"));
}

#[test]
fn vbus_names_its_address_and_dump_prints_what_crosses_it() {
    let mut vbus = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args([
            "vbus",
            "--listen",
            "127.0.0.1:0",
            "--devices",
            "none",
            "--log",
            "warn",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(vbus.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    let addr = first
        .split_whitespace()
        .nth(4)
        .unwrap_or_else(|| panic!("no address in {first:?}"))
        .to_string();
    assert!(
        first.starts_with("candeck vbus: socketcand on 127.0.0.1:"),
        "{first}"
    );
    assert!(
        // The bus runs at 500 kbit/s unless told.
        first
            .trim_end()
            .ends_with("channel can0 devices none bitrate 500000"),
        "{first}"
    );

    let runtime = tokio::runtime::Runtime::new().unwrap();
    let dump = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args([
            "dump",
            "--bus",
            &format!("socketcand:{addr}/can0"),
            "--count",
            "3",
            "--log",
            "warn",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    runtime.block_on(async {
        use candeck::can::{CanId, Frame, socketcand};
        let port: u16 = addr.rsplit(':').next().unwrap().parse().unwrap();
        let bus = socketcand::open_socketcand(
            "can0",
            socketcand::ClientConfig::new("127.0.0.1", port, "can0"),
        );
        bus.wait_up(Duration::from_secs(5)).await.unwrap();
        // Give the dump time to connect and pass the server's settle pause.
        tokio::time::sleep(Duration::from_millis(1500)).await;
        bus.send(Frame::new(CanId::Standard(0x123), &[0x11, 0x22]).unwrap())
            .await
            .unwrap();
        bus.send(Frame::new(CanId::Extended(0x1ABCDEF), &[]).unwrap())
            .await
            .unwrap();
        // A node-guarding request: a remote frame crosses socketcand as
        // `< sendrtr 701 1 >` one way and `< rtr 701 SECS.USECS 1 >` the
        // other (python-can's socketcand client can neither send nor show
        // one: it writes every frame as `< send >`, and skips `< rtr >`).
        bus.send(Frame::remote(CanId::Standard(0x701), 1).unwrap())
            .await
            .unwrap();
        bus.close().await;
    });
    let output = dump.wait_with_output().unwrap();
    let _ = vbus.kill();
    let _ = vbus.wait();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let stdout = String::from_utf8(output.stdout).unwrap();
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 3, "{stdout}");
    assert!(
        lines[0].starts_with('(') && lines[0].ends_with(") can0 123#1122"),
        "{stdout}"
    );
    assert!(lines[1].ends_with(") can0 01ABCDEF#"), "{stdout}");
    assert!(lines[2].ends_with(") can0 701#R1"), "{stdout}");
}

#[test]
fn virtual_demo_carries_the_demo_devices_for_every_command() {
    // Vendor ids (0x1018 sub 1): UniSwarm 0x4A2 at 1 and 3, JMC 0x2D9 at 2.
    for (node, vendor) in [("1", "1186"), ("2", "729"), ("3", "1186")] {
        let (code, stdout, stderr) = candeck(&[
            "od",
            "read",
            "--bus",
            "virtual:demo",
            "--node",
            node,
            "0x1018",
            "1",
            "--type",
            "u32",
        ]);
        assert_eq!(code, 0, "node {node}: {stderr}");
        assert_eq!(stdout.trim(), vendor, "node {node}");
    }
    let (code, _, stderr) = candeck(&[
        "od",
        "write",
        "--bus",
        "virtual:demo",
        "--node",
        "2",
        "0x6081",
        "0",
        "50",
        "--type",
        "u32",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let (code, _, stderr) = candeck(&["nmt", "--bus", "virtual:demo", "--node", "all", "start"]);
    assert_eq!(code, 0, "{stderr}");
}

#[test]
fn a_socketcand_share_beyond_loopback_needs_its_own_flag_even_with_tokens() {
    // Raw bus access that no token guards: tokens do not open it.
    let output = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(["serve", "--share", "0.0.0.0:0"])
        .env_remove("CANDECK_LOG")
        .env("CANDECK_TOKENS", "plc:operator:3f9c2a7be81d4c06a5e9")
        .output()
        .expect("candeck runs");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert_one_clear_line(
        &stderr,
        "refusing --share 0.0.0.0:0: a socketcand share is raw bus access",
    );
    assert!(stderr.contains("--share-public"), "{stderr}");
}

#[test]
fn serving_beyond_loopback_without_tokens_is_refused() {
    let (code, stdout, stderr) = candeck(&["serve", "--listen", "0.0.0.0:0"]);
    assert_eq!(code, 1, "{stdout}{stderr}");
    assert_one_clear_line(&stderr, "refusing to listen on 0.0.0.0:0 without tokens");
    assert!(stderr.contains("--insecure"), "{stderr}");
    // Every listener: the CiA 309-3 port moves motors as the API does.
    let (code, stdout, stderr) = candeck(&["serve", "--ascii-listen", "0.0.0.0:0"]);
    assert_eq!(code, 1, "{stdout}{stderr}");
    assert_one_clear_line(&stderr, "refusing --ascii-listen 0.0.0.0:0 without tokens");
    assert!(stderr.contains("--insecure"), "{stderr}");
    let (code, _, stderr) = candeck(&["serve", "--config", "/nonexistent/candeck.toml"]);
    assert_eq!(code, 1);
    assert_one_clear_line(&stderr, "/nonexistent/candeck.toml");
}

/// A server whose stdout reader went away before it printed its lines
/// (`candeck serve --share … | head -0`, a closed pipe) keeps serving:
/// `println!` panicked on the broken pipe and took the gateway down.
#[test]
fn a_closed_stdout_does_not_stop_the_server() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let listen = format!("127.0.0.1:{port}");
    let mut child = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(["serve", "--listen", &listen, "--share", "127.0.0.1:0"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The reader goes away before the server says anything.
    drop(child.stdout.take());
    let mut answered = false;
    for _ in 0..200 {
        if let Some(status) = child.try_wait().unwrap() {
            let mut stderr = String::new();
            std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
            panic!("the server exited ({status}) with its stdout closed:\n{stderr}");
        }
        if let Ok(mut stream) = std::net::TcpStream::connect(&listen) {
            use std::io::{Read, Write};
            stream
                .write_all(
                    b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n",
                )
                .unwrap();
            let mut reply = String::new();
            let _ = stream.read_to_string(&mut reply);
            if reply.starts_with("HTTP/1.1 200") {
                answered = true;
                break;
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(answered, "no answer from /api/v1/health");
    assert!(child.try_wait().unwrap().is_none(), "the server exited");
    child.kill().unwrap();
    child.wait().unwrap();
}
