//! The limits of `candeck serve`'s listeners against a real process
//! (issue 19, point 4): idle clients cannot keep `/health` and STOP ALL
//! out, and half-sent requests and idle clients are closed after their
//! timeouts, on the HTTP port and on the CiA 309-3 port.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use common::Server;

/// `candeck serve ARGS --listen 127.0.0.1:0` run by `sh` under a soft
/// file-descriptor limit of `nofile` (1,024 is what a process gets by
/// default, under systemd too); its HTTP address and its other stdout
/// lines up to the one that starts with `until`.
fn start_limited(nofile: u32, args: &[&str], until: &str) -> (Server, String, Vec<String>) {
    start_limited_with_tokens(nofile, args, until, None)
}

/// [`start_limited`] with `CANDECK_TOKENS` set when given.
fn start_limited_with_tokens(
    nofile: u32,
    args: &[&str],
    until: &str,
    tokens: Option<&str>,
) -> (Server, String, Vec<String>) {
    let mut command = Command::new("sh");
    if let Some(tokens) = tokens {
        command.env("CANDECK_TOKENS", tokens);
    } else {
        command.env_remove("CANDECK_TOKENS");
    }
    let mut child = command
        .arg("-c")
        .arg(format!("ulimit -n {nofile} && exec \"$0\" \"$@\""))
        .arg(env!("CARGO_BIN_EXE_candeck"))
        .arg("serve")
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        .env_remove("CANDECK_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("candeck starts");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let first = lines.next().unwrap().unwrap();
    let address = first
        .strip_prefix("candeck: serving http://")
        .and_then(|rest| rest.split_once('/'))
        .map(|(address, _)| address.to_string())
        .unwrap_or_else(|| panic!("first line: {first}"));
    let mut more = Vec::new();
    if !until.is_empty() {
        for line in lines.by_ref() {
            let line = line.unwrap();
            let done = line.starts_with(until);
            more.push(line);
            if done {
                break;
            }
        }
    }
    (Server { child, address }, first, more)
}

/// Raises this process's own soft file-descriptor limit to its hard one:
/// the test holds more than 1,024 sockets.
#[allow(unsafe_code)] // the one FFI call of the test suite
fn raise_nofile(wanted: u64) {
    // SAFETY: getrlimit and setrlimit only read and write the struct given.
    unsafe {
        let mut limit = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit), 0);
        if limit.rlim_cur < wanted {
            assert!(
                limit.rlim_max >= wanted,
                "the hard limit of open files ({}) is below the {wanted} this test needs",
                limit.rlim_max
            );
            limit.rlim_cur = limit.rlim_max;
            assert_eq!(libc::setrlimit(libc::RLIMIT_NOFILE, &limit), 0);
        }
    }
}

/// Reads until the server closes the connection; what it sent. Panics when
/// it is still open after `bound` (far above the timeouts under test).
async fn closed_by_server(stream: &mut TcpStream, bound: Duration) -> Vec<u8> {
    let mut received = Vec::new();
    match tokio::time::timeout(bound, stream.read_to_end(&mut received)).await {
        Ok(_) => received,
        Err(_) => panic!(
            "the connection is still open after {bound:?}; received {:?}",
            String::from_utf8_lossy(&received)
        ),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_connections_do_not_keep_health_and_stop_all_out() {
    const IDLE: usize = 1_100;
    raise_nofile(IDLE as u64 + 200);
    // The defaults, under the default limit of open files: more idle
    // clients than the gateway has file descriptors.
    let (server, _, _) = start_limited(1024, &[], "");
    let mut idle = Vec::with_capacity(IDLE);
    for _ in 0..IDLE {
        let stream =
            tokio::time::timeout(Duration::from_secs(10), TcpStream::connect(&server.address))
                .await
                .expect("connected within 10 s")
                .unwrap();
        idle.push(stream);
    }
    // Every one of them still open on this side: they sit on the socket.
    assert_eq!(idle.len(), IDLE);
    for (method, path) in [("GET", "/api/v1/health"), ("POST", "/api/v1/stop-all")] {
        let answer = tokio::time::timeout(
            Duration::from_secs(20),
            common::request(
                &server.address,
                method,
                path,
                "application/json",
                Some("{}").filter(|_| method == "POST"),
                Duration::from_secs(20),
            ),
        )
        .await
        .unwrap_or_else(|_| panic!("{method} {path}: no answer within 20 s"));
        assert_eq!(answer.status, 200, "{method} {path}: {}", answer.body);
    }
    drop(idle);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn half_sent_requests_and_idle_clients_are_closed_after_their_timeouts() {
    let (server, _, lines) = start_limited(
        1024,
        &[
            "--header-timeout-ms",
            "300",
            "--idle-timeout-ms",
            "300",
            "--ascii-listen",
            "127.0.0.1:0",
            "--ascii-idle-timeout-ms",
            "300",
            "--ascii-max-connections",
            "2",
        ],
        "candeck: CiA 309-3 ASCII gateway on ",
    );
    let ascii = lines
        .last()
        .and_then(|line| line.strip_prefix("candeck: CiA 309-3 ASCII gateway on "))
        .and_then(|rest| rest.split_whitespace().next())
        .unwrap_or_else(|| panic!("{lines:?}"))
        .to_string();
    let bound = Duration::from_secs(30);

    // A request whose head never ends.
    let mut half = TcpStream::connect(&server.address).await.unwrap();
    half.write_all(b"GET /api/v1/health HTTP/1.1\r\nHost: localhost\r\nX-Slow: 1")
        .await
        .unwrap();
    assert!(closed_by_server(&mut half, bound).await.is_empty());
    // A client that connects and sends nothing.
    let mut silent = TcpStream::connect(&server.address).await.unwrap();
    assert!(closed_by_server(&mut silent, bound).await.is_empty());
    // A kept-alive connection, idle after its answer.
    let mut kept = TcpStream::connect(&server.address).await.unwrap();
    kept.write_all(b"GET /api/v1/health HTTP/1.1\r\nHost: localhost\r\n\r\n")
        .await
        .unwrap();
    let answer = closed_by_server(&mut kept, bound).await;
    assert!(answer.starts_with(b"HTTP/1.1 200"), "{answer:?}");
    // The gateway still answers.
    let (status, _) = common::http(&server.address, "GET", "/api/v1/health", None).await;
    assert_eq!(status, 200);

    // CiA 309-3: two connections at most; a third one is closed at once.
    let mut first = TcpStream::connect(&ascii).await.unwrap();
    first.write_all(b"[1] 1 r 0x1000 0 u32\n").await.unwrap();
    let mut reply = [0u8; 64];
    let n = tokio::time::timeout(bound, first.read(&mut reply))
        .await
        .expect("a reply")
        .unwrap();
    assert!(reply[..n].starts_with(b"[1] "), "{:?}", &reply[..n]);
    let mut second = TcpStream::connect(&ascii).await.unwrap();
    // A third one takes the place of the second, which sent nothing yet
    // (issue 30): the second is closed, the third answered.
    let mut third = TcpStream::connect(&ascii).await.unwrap();
    third.write_all(b"[2] 1 r 0x1000 0 u32\n").await.unwrap();
    let n = tokio::time::timeout(bound, third.read(&mut reply))
        .await
        .expect("a reply")
        .unwrap();
    assert!(reply[..n].starts_with(b"[2] "), "{:?}", &reply[..n]);
    assert!(closed_by_server(&mut second, bound).await.is_empty());
    // Both places in use: a fourth is closed at once, without an answer.
    let mut fourth = TcpStream::connect(&ascii).await.unwrap();
    fourth.write_all(b"[3] 1 r 0x1000 0 u32\n").await.ok();
    let refused = closed_by_server(&mut fourth, bound).await;
    assert!(
        refused.is_empty(),
        "{:?}",
        String::from_utf8_lossy(&refused)
    );
    // And clients that send nothing are closed after the idle timeout.
    closed_by_server(&mut first, bound).await;
    closed_by_server(&mut third, bound).await;
}

const ADMIN_TOKEN: &str = "admin-token-0123456789abcdef";

/// `Authorization: Bearer` of [`ADMIN_TOKEN`], as a header line.
fn admin() -> String {
    format!("Authorization: Bearer {ADMIN_TOKEN}\r\n")
}

/// Issue 30, finding 6: clients without a token that send a request head
/// announcing a large body and then stall are answered 401 at once, their
/// bodies never read; they hold no connection, and `/health`, STOP ALL and
/// a token holder's read go on being answered.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stalled_bodies_without_a_token_do_not_hold_connections() {
    const STALLED: usize = 500;
    raise_nofile(STALLED as u64 + 200);
    let tokens = format!("ops:admin:{ADMIN_TOKEN}");
    let (server, _, _) = start_limited_with_tokens(1024, &[], "", Some(&tokens));
    let head = format!(
        "PUT /api/v1/buses/demo/nodes/1/od/0x2000/0 HTTP/1.1\r\nHost: {}\r\n\
         Content-Type: application/json\r\nContent-Length: 1000000\r\n\r\n{{",
        server.address
    );
    let mut stalled = Vec::with_capacity(STALLED);
    for _ in 0..STALLED {
        let mut stream =
            tokio::time::timeout(Duration::from_secs(10), TcpStream::connect(&server.address))
                .await
                .expect("connected within 10 s")
                .unwrap();
        stream.write_all(head.as_bytes()).await.unwrap();
        stalled.push(stream);
    }
    // Each answered 401 without its body, and closed.
    for stream in stalled.iter_mut().step_by(50) {
        let answer = closed_by_server(stream, Duration::from_secs(10)).await;
        assert!(
            answer.starts_with(b"HTTP/1.1 401"),
            "{:?}",
            String::from_utf8_lossy(&answer)
        );
    }
    for (method, path, body) in [
        ("GET", "/api/v1/health", None),
        ("POST", "/api/v1/stop-all", Some("{}")),
        ("GET", "/api/v1/buses", None),
    ] {
        let answer = tokio::time::timeout(
            Duration::from_secs(10),
            common::request_with_headers(
                &server.address,
                method,
                path,
                "application/json",
                body,
                Duration::from_secs(10),
                &admin(),
            ),
        )
        .await
        .unwrap_or_else(|_| panic!("{method} {path}: no answer within 10 s"));
        assert_eq!(answer.status, 200, "{method} {path}: {}", answer.body);
    }
    drop(stalled);
}

/// Issue 30, finding 6: a token holder's request whose body stalls is
/// closed after the idle timeout, as an idle connection is.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_request_body_is_closed_after_the_idle_timeout() {
    let tokens = format!("ops:admin:{ADMIN_TOKEN}");
    let (server, _, _) =
        start_limited_with_tokens(1024, &["--idle-timeout-ms", "300"], "", Some(&tokens));
    let mut stream = TcpStream::connect(&server.address).await.unwrap();
    let head = format!(
        "PUT /api/v1/buses/demo/nodes/1/od/0x2000/0 HTTP/1.1\r\nHost: {}\r\n{}\
         Content-Type: application/json\r\nContent-Length: 1000\r\n\r\n{{\"value\"",
        server.address,
        admin()
    );
    stream.write_all(head.as_bytes()).await.unwrap();
    closed_by_server(&mut stream, Duration::from_secs(30)).await;
    let (status, _) = common::http(&server.address, "GET", "/api/v1/health", None).await;
    assert_eq!(status, 200);
}

/// Issue 30, finding 6: `--max-connections 5000` under a limit of 256 open
/// files is lowered to what the limit leaves (with a warning), so that the
/// reserve still answers `/health` and STOP ALL with more idle clients
/// than the process may open files; too little room is refused at start.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn max_connections_is_lowered_to_what_the_open_file_limit_leaves() {
    const IDLE: usize = 300;
    raise_nofile(IDLE as u64 + 200);
    let (server, _, _) = start_limited(256, &["--max-connections", "5000"], "");
    let mut idle = Vec::with_capacity(IDLE);
    for _ in 0..IDLE {
        let stream =
            tokio::time::timeout(Duration::from_secs(10), TcpStream::connect(&server.address))
                .await
                .expect("connected within 10 s")
                .unwrap();
        idle.push(stream);
    }
    for (method, path) in [("GET", "/api/v1/health"), ("POST", "/api/v1/stop-all")] {
        let answer = tokio::time::timeout(
            Duration::from_secs(10),
            common::request(
                &server.address,
                method,
                path,
                "application/json",
                Some("{}").filter(|_| method == "POST"),
                Duration::from_secs(10),
            ),
        )
        .await
        .unwrap_or_else(|_| panic!("{method} {path}: no answer within 10 s"));
        assert_eq!(answer.status, 200, "{method} {path}: {}", answer.body);
    }
    drop(idle);

    // Under 70 open files, fewer than the reserve and one more are left.
    let refused = Command::new("sh")
        .arg("-c")
        .arg("ulimit -n 70 && exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_candeck"))
        .args(["serve", "--listen", "127.0.0.1:0"])
        .env_remove("CANDECK_TOKENS")
        .output()
        .unwrap();
    assert!(!refused.status.success());
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(stderr.contains("raise the limit of open files"), "{stderr}");
}
