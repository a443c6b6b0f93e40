//! What the benchmarks that run `candeck` processes share: a free port, a
//! child killed when dropped, the lines a child prints, a process's CPU
//! time and resident memory from `/proc`, and a plain HTTP/1.1 request.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

pub(crate) fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|listener| listener.local_addr())
        .map(|addr| addr.port())
        .expect("a free port")
}

/// A child process, killed when dropped.
pub(crate) struct Killed(pub Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `candeck vbus --bitrate unlimited` with virtual UMC1BDS32 drives at node
/// IDs 1 to `nodes`, run in `dir` and logging to `dir/log`, shared over
/// socketcand: the process and its port, once it says it is listening.
pub(crate) fn umc_vbus(dir: &Path, log: &str, nodes: u8) -> (Killed, u16) {
    let share = free_port();
    let devices: Vec<String> = (1..=nodes).map(|id| format!("umc1bds32@{id}")).collect();
    let mut vbus = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args([
            "vbus",
            "--listen",
            &format!("127.0.0.1:{share}"),
            "--bitrate",
            "unlimited",
            "--devices",
            &devices.join(","),
        ])
        .current_dir(dir)
        .env("CANDECK_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(dir.join(log)).unwrap())
        .spawn()
        .expect("candeck vbus starts");
    lines_until(&mut vbus, "");
    (Killed(vbus), share)
}

/// The lines a child prints on stdout up to the first that starts with
/// `prefix` (that one included); its later lines are read too (a closed
/// pipe would end it). Panics when stdout ends first.
pub(crate) fn lines_until(child: &mut Child, prefix: &str) -> Vec<String> {
    let mut stdout = BufReader::new(child.stdout.take().expect("stdout piped"));
    let mut lines = Vec::new();
    loop {
        let mut line = String::new();
        let read = stdout
            .read_line(&mut line)
            .expect("read the child's stdout");
        assert!(
            read > 0,
            "the child ended before saying '{prefix}': {lines:?}"
        );
        let found = line.starts_with(prefix);
        lines.push(line);
        if found {
            break;
        }
    }
    std::thread::spawn(move || std::io::copy(&mut stdout, &mut std::io::sink()));
    lines
}

/// User and system CPU seconds the process `pid` has used so far.
pub(crate) fn cpu_seconds(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
    let fields: Vec<&str> = after.split_whitespace().collect();
    // utime and stime: fields 14 and 15 of stat, 12 and 13 after the ')'.
    let ticks: f64 = [11, 12]
        .iter()
        .filter_map(|at| fields.get(*at).and_then(|v| v.parse::<f64>().ok()))
        .sum();
    ticks / 100.0
}

/// The resident memory of process `pid` (`VmRSS`), in MiB.
pub(crate) fn rss_mib(pid: u32) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .unwrap_or_default()
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|kb| kb.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}

/// The value after `name` on the command line, or `default`.
pub(crate) fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|arg| arg == name)
        .and_then(|at| args.get(at + 1))
        .and_then(|n| n.parse().ok())
        .unwrap_or(default)
}

/// One request to the REST API at `addr` (`/api/v1` + `path`),
/// `Connection: close`: the status and the body.
pub(crate) fn http(addr: &str, method: &str, path: &str, body: Option<&str>) -> (u16, String) {
    let mut stream = TcpStream::connect(addr).expect("connect to the gateway");
    stream
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    let body = body.unwrap_or("");
    write!(
        stream,
        "{method} /api/v1{path} HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    )
    .unwrap();
    // The server may reset the connection once it has answered: what was
    // read is the answer.
    let mut bytes = Vec::new();
    let mut buf = [0u8; 8192];
    while let Ok(n) = stream.read(&mut buf) {
        if n == 0 {
            break;
        }
        bytes.extend_from_slice(&buf[..n]);
    }
    let answer = String::from_utf8_lossy(&bytes).into_owned();
    let status = answer
        .split(' ')
        .nth(1)
        .and_then(|code| code.parse().ok())
        .unwrap_or(0);
    let body = answer
        .split_once("\r\n\r\n")
        .map(|(_, body)| body.to_string())
        .unwrap_or_default();
    (status, body)
}

/// One HTTP/1.1 connection to the REST API kept open for request after
/// request, as a client that polls does.
pub(crate) struct KeepAlive {
    reader: BufReader<TcpStream>,
}

impl KeepAlive {
    pub(crate) fn connect(addr: &str) -> std::io::Result<Self> {
        let stream = TcpStream::connect(addr)?;
        stream.set_read_timeout(Some(Duration::from_secs(30)))?;
        stream.set_nodelay(true)?;
        Ok(Self {
            reader: BufReader::new(stream),
        })
    }

    /// `GET /api/v1` + `path`: the status and the body; an error when the
    /// connection fails or the answer has no `Content-Length`.
    pub(crate) fn get(&mut self, path: &str) -> Result<(u16, String), String> {
        write!(
            self.reader.get_mut(),
            "GET /api/v1{path} HTTP/1.1\r\nHost: localhost\r\n\r\n"
        )
        .map_err(|err| format!("send: {err}"))?;
        let mut status = 0;
        let mut length = None;
        loop {
            let mut line = String::new();
            let read = self
                .reader
                .read_line(&mut line)
                .map_err(|err| format!("read: {err}"))?;
            if read == 0 {
                return Err("the connection closed".to_string());
            }
            let line = line.trim_end();
            if line.is_empty() {
                break;
            }
            if status == 0 {
                status = line
                    .split(' ')
                    .nth(1)
                    .and_then(|code| code.parse().ok())
                    .unwrap_or(0);
            } else if let Some((name, value)) = line.split_once(':')
                && name.eq_ignore_ascii_case("content-length")
            {
                length = value.trim().parse::<usize>().ok();
            }
        }
        let length = length.ok_or("an answer without Content-Length")?;
        let mut body = vec![0; length];
        self.reader
            .read_exact(&mut body)
            .map_err(|err| format!("read the body: {err}"))?;
        Ok((status, String::from_utf8_lossy(&body).into_owned()))
    }
}
