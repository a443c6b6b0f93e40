//! What the HTTP tests against the real `candeck serve` share: starting it on
//! a free port, and one plain HTTP/1.1 request.

#![allow(dead_code)] // Each test crate uses part of it.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

pub(crate) struct Server {
    pub child: Child,
    pub address: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `candeck ARGS --listen 127.0.0.1:0` and reads the address from its
/// first stdout line.
pub(crate) fn start(args: &[&str]) -> (Server, String) {
    start_with_env(args, &[])
}

/// Runs `candeck ARGS` (stderr dropped) and reads the first line it
/// prints, which says where it listens.
fn spawn_and_read_line(args: &[&str], env: &[(&str, &std::path::Path)]) -> (Child, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(args)
        .envs(env.iter().copied())
        .env_remove("CANDECK_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("candeck starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    (child, line)
}

/// [`start`] with environment variables set for the process.
pub(crate) fn start_with_env(args: &[&str], env: &[(&str, &std::path::Path)]) -> (Server, String) {
    let mut all = args.to_vec();
    all.extend(["--listen", "127.0.0.1:0"]);
    let (child, line) = spawn_and_read_line(&all, env);
    let address = line
        .strip_prefix("candeck: serving http://")
        .and_then(|rest| rest.split_once('/'))
        .map(|(address, _)| address.to_string())
        .unwrap_or_else(|| panic!("first line: {line}"));
    (Server { child, address }, line)
}

/// Sends SIGTERM and waits (at most 5 s) for the process to end; its exit
/// code.
pub(crate) async fn terminate(server: &mut Server) -> Option<i32> {
    let pid = server.child.id().to_string();
    let killed = Command::new("kill").args(["-TERM", &pid]).status().unwrap();
    assert!(killed.success());
    for _ in 0..100 {
        if let Some(exit) = server.child.try_wait().unwrap() {
            return exit.code();
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("candeck did not stop within 5 s of SIGTERM");
}

/// A `candeck vbus` child process, killed when dropped.
pub(crate) struct Vbus(pub Child);

impl Drop for Vbus {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `candeck vbus --devices demo` listening on `listen` (port 0: a free
/// one); the process, and the socketcand address and channel it serves
/// (`127.0.0.1:PORT/can0`).
pub(crate) fn vbus(listen: &str) -> (Vbus, String) {
    let (child, line) =
        spawn_and_read_line(&["vbus", "--listen", listen, "--devices", "demo"], &[]);
    // "candeck vbus: socketcand on ADDR channel CHANNEL devices ..."
    let words: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(
        words.get(..3),
        Some(&["candeck", "vbus:", "socketcand"][..]),
        "{line}"
    );
    (Vbus(child), format!("{}/{}", words[4], words[6]))
}

/// A config file (written to `dir`) whose machine description leaves the
/// demo's three nodes as they boot: pre-operational, no heartbeat set, not
/// told to consume the gateway's. For the tests that need the nodes as the
/// devices start (storing parameters, which UniSwarm devices do only in
/// pre-operational; a saved 0x1017 the manager would overwrite).
pub(crate) fn demo_left_alone(dir: &std::path::Path) -> std::path::PathBuf {
    let mut text = String::new();
    for id in 1..=3 {
        text.push_str(&format!(
            "[[nodes]]\nid = {id}\nmandatory = false\nheartbeat_ms = 0\nconsume_manager_heartbeat = false\nstart = false\n\n"
        ));
    }
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join("demo-left-alone.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// What came back from one request.
pub(crate) struct Response {
    pub status: u16,
    /// The `Content-Type` header, empty when there is none.
    pub content_type: String,
    pub body: String,
}

impl Response {
    pub(crate) fn json(&self) -> serde_json::Value {
        serde_json::from_str(&self.body)
            .unwrap_or_else(|err| panic!("no JSON ({err}): {}", self.body))
    }
}

/// One request with a body of `content_type`, `Connection: close`, answered
/// within `timeout`.
pub(crate) async fn request(
    address: &str,
    method: &str,
    path: &str,
    content_type: &str,
    body: Option<&str>,
    timeout: Duration,
) -> Response {
    request_with_headers(address, method, path, content_type, body, timeout, "").await
}

/// [`request`] with more header lines (each ending in `\r\n`).
pub(crate) async fn request_with_headers(
    address: &str,
    method: &str,
    path: &str,
    content_type: &str,
    body: Option<&str>,
    timeout: Duration,
    headers: &str,
) -> Response {
    let mut stream = TcpStream::connect(address).await.unwrap();
    let body = body.unwrap_or("");
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\n{headers}Content-Type: {content_type}\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    );
    stream.write_all(request.as_bytes()).await.unwrap();
    let mut response = String::new();
    tokio::time::timeout(timeout, stream.read_to_string(&mut response))
        .await
        .expect("answer in time")
        .unwrap();
    let status = response
        .strip_prefix("HTTP/1.1 ")
        .and_then(|rest| rest.get(..3))
        .and_then(|code| code.parse().ok())
        .unwrap_or_else(|| panic!("response: {response}"));
    let (head, body) = response.split_once("\r\n\r\n").unwrap();
    let content_type = head
        .lines()
        .find_map(|line| {
            let (name, value) = line.split_once(':')?;
            name.eq_ignore_ascii_case("content-type")
                .then(|| value.trim().to_string())
        })
        .unwrap_or_default();
    Response {
        status,
        content_type,
        body: body.to_string(),
    }
}

/// One request with a JSON body, `Connection: close`, answered within
/// 10 s; returns the status code and body.
pub(crate) async fn http(
    address: &str,
    method: &str,
    path: &str,
    body: Option<&str>,
) -> (u16, String) {
    let response = request(
        address,
        method,
        path,
        "application/json",
        body,
        Duration::from_secs(10),
    )
    .await;
    (response.status, response.body)
}

/// One request whose answer is JSON (every API answer is): status and body.
pub(crate) async fn json(
    address: &str,
    method: &str,
    path: &str,
    body: Option<&str>,
) -> (u16, serde_json::Value) {
    let (status, body) = http(address, method, path, body).await;
    let json = serde_json::from_str(&body).unwrap_or_else(|err| panic!("{path}: {err}: {body}"));
    (status, json)
}

/// Enables the axis at `axis` (`/api/v1/buses/B/nodes/N/axes/A`) and
/// starts the move `body` (JSON text); the move's answer.
pub(crate) async fn enable_and_move(address: &str, axis: &str, body: &str) -> serde_json::Value {
    let (status, answer) = json(
        address,
        "POST",
        &format!("{axis}/state"),
        Some(r#"{"target":"operation_enabled"}"#),
    )
    .await;
    assert_eq!(status, 200, "{answer}");
    assert_eq!(answer["state"], "operation_enabled", "{answer}");
    let (status, answer) = json(address, "POST", &format!("{axis}/move"), Some(body)).await;
    assert_eq!(status, 200, "{answer}");
    answer
}

/// [`json`] with a bearer token.
pub(crate) async fn json_with_token(
    address: &str,
    method: &str,
    path: &str,
    token: &str,
) -> (u16, serde_json::Value) {
    let response = request_with_headers(
        address,
        method,
        path,
        "application/json",
        None,
        Duration::from_secs(30),
        &format!("Authorization: Bearer {token}\r\n"),
    )
    .await;
    (response.status, response.json())
}

/// Polls `GET path` every 50 ms, for at most 10 s, until `done`; the last
/// answer either way.
pub(crate) async fn poll(
    address: &str,
    path: &str,
    done: impl Fn(u16, &serde_json::Value) -> bool,
) -> (u16, serde_json::Value) {
    for _ in 0..200 {
        let (status, body) = json(address, "GET", path, None).await;
        if done(status, &body) {
            return (status, body);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    json(address, "GET", path, None).await
}

/// The path of one of the vendor's EDS files (`file`, e.g.
/// `umc1bds32_v1.0.4.eds`) in the directory named by `CANDECK_VENDOR_EDS`.
/// They are optional test inputs, never part of the repository: when the
/// variable is not set this says on stderr that `test` was skipped and gives
/// `None`. When it is set, the file must be there.
pub(crate) fn vendor_eds(file: &str, test: &str) -> Option<std::path::PathBuf> {
    use std::io::Write as _;
    let Some(dir) = std::env::var_os("CANDECK_VENDOR_EDS") else {
        // Straight to stderr, past the test harness's capture, so that the
        // skip shows in every run.
        let _ = writeln!(
            std::io::stderr(),
            "skipped: {test}: CANDECK_VENDOR_EDS is not set (the directory of the vendor's EDS files; see docs/testing.md)"
        );
        return None;
    };
    let path = std::path::Path::new(&dir).join(file);
    assert!(
        path.is_file(),
        "CANDECK_VENDOR_EDS is set but {} is not a file",
        path.display()
    );
    Some(path)
}
