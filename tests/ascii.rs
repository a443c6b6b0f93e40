//! CiA 309-3 over TCP (`candeck serve --ascii-listen`) and on stdin/stdout
//! (`candeck ascii`), and CiA 309-5 over HTTP, against the demo devices
//! (UMC node 1, JMC node 2, UIO1LED node 3): every command and data type,
//! the errors in CANopenNode's reply forms, and the event lines.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader as TokioBufReader};
use tokio::net::TcpStream;
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};

use common::{Server, json};

/// `candeck serve --ascii-listen 127.0.0.1:0`: the server, its HTTP and
/// its ASCII addresses (from its first two stdout lines).
fn start() -> (Server, String, String) {
    start_with_tokens(None)
}

/// [`start`], with `CANDECK_TOKENS` set when given.
fn start_with_tokens(tokens: Option<&str>) -> (Server, String, String) {
    start_with(tokens, &[])
}

/// [`start_with_tokens`], with more arguments of `candeck serve`.
fn start_with(tokens: Option<&str>, more: &[&str]) -> (Server, String, String) {
    let mut command = Command::new(env!("CARGO_BIN_EXE_candeck"));
    if let Some(tokens) = tokens {
        command.env("CANDECK_TOKENS", tokens);
    }
    let mut child = command
        .args([
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--ascii-listen",
            "127.0.0.1:0",
        ])
        .args(more)
        .env_remove("CANDECK_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("candeck starts");
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    stdout.read_line(&mut first).unwrap();
    let mut second = String::new();
    stdout.read_line(&mut second).unwrap();
    let http = first
        .strip_prefix("candeck: serving http://")
        .and_then(|rest| rest.split_once('/'))
        .map(|(address, _)| address.to_string())
        .unwrap_or_else(|| panic!("first line: {first}"));
    let ascii = second
        .strip_prefix("candeck: CiA 309-3 ASCII gateway on ")
        .and_then(|rest| rest.split_once(' '))
        .map(|(address, _)| address.to_string())
        .unwrap_or_else(|| panic!("second line: {second}"));
    let address = http.clone();
    let server = Server { child, address };
    wait_identified(&http, tokens);
    (server, http, ascii)
}

/// Waits (at most 10 s) until the gateway has identified the three demo
/// nodes: on a bus with a bit rate the identification takes a few
/// milliseconds of wire time, and a command sent before it finds a node
/// without its EDS. With tokens, asks with the first one.
fn wait_identified(http: &str, tokens: Option<&str>) {
    use std::io::{Read as _, Write as _};
    let secret = tokens
        .and_then(|tokens| tokens.split(',').next())
        .and_then(|token| token.split(':').nth(2));
    for _ in 0..200 {
        let mut stream = std::net::TcpStream::connect(http).expect("the gateway listens");
        let auth = secret
            .map(|secret| format!("authorization: Bearer {secret}\r\n"))
            .unwrap_or_default();
        write!(
            stream,
            "GET /api/v1/buses/demo/nodes HTTP/1.1\r\nhost: {http}\r\n{auth}connection: close\r\n\r\n"
        )
        .unwrap();
        let mut answer = String::new();
        stream.read_to_string(&mut answer).unwrap();
        if answer.matches(r#""state":"done""#).count() >= 3 {
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    panic!("the demo nodes were not identified within 10 s");
}

/// A CiA 309-3 client: replies (lines starting with `[`) apart from the
/// unsolicited event lines.
struct Client {
    reader: TokioBufReader<OwnedReadHalf>,
    writer: OwnedWriteHalf,
    events: Vec<String>,
}

impl Client {
    async fn connect(address: &str) -> Self {
        let stream = TcpStream::connect(address).await.unwrap();
        let (reader, writer) = stream.into_split();
        Self {
            reader: TokioBufReader::new(reader),
            writer,
            events: Vec::new(),
        }
    }

    async fn line(&mut self) -> String {
        let mut line = String::new();
        tokio::time::timeout(Duration::from_secs(10), self.reader.read_line(&mut line))
            .await
            .expect("a line within 10 s")
            .unwrap();
        line
    }

    /// Sends `command` with `\r\n`; the reply line, `\r\n` included.
    async fn send(&mut self, command: &str) -> String {
        self.writer
            .write_all(format!("{command}\r\n").as_bytes())
            .await
            .unwrap();
        loop {
            let line = self.line().await;
            if line.starts_with('[') || line == "\r\n" || line == "\n" {
                return line;
            }
            self.events.push(line);
        }
    }

    /// Waits (at most 10 s) for an event line that starts with `prefix`.
    async fn event(&mut self, prefix: &str) -> String {
        if let Some(at) = self.events.iter().position(|e| e.starts_with(prefix)) {
            return self.events.remove(at);
        }
        loop {
            let line = self.line().await;
            if line.starts_with(prefix) {
                return line;
            }
            self.events.push(line);
        }
    }
}

#[tokio::test]
async fn every_command_and_datatype_against_the_demo() {
    let (_server, http, ascii) = start();
    let mut c = Client::connect(&ascii).await;

    // Strings, identity, and reads without a type (hex).
    assert_eq!(
        c.send("[1] 1 r 0x1008 0 vs").await,
        "[1] \"UMC1BDS32 motion controller\"\r\n"
    );
    assert_eq!(
        c.send("[2] 2 read 0x1008 0 VS").await,
        "[2] \"AMA CANopen Motor Driver\"\r\n"
    );
    assert_eq!(c.send("[3] 1 r 0x1018 1 x32").await, "[3] 0x000004A2\r\n");
    assert_eq!(c.send("[4] 1 r 0x1018 1 u32").await, "[4] 1186\r\n");
    assert_eq!(c.send("[5] 1 r 0x1018 1").await, "[5] A2 04 00 00\r\n");
    assert_eq!(c.send("[6] 1 r 0x1018 1 hex").await, "[6] A2 04 00 00\r\n");
    // 0x1009 is a UNICODE_STRING in the UMC's EDS: base64 of its bytes.
    let us = c.send("[7] 1 r 0x1009 0 us").await;
    assert!(us.starts_with("[7] ") && us.ends_with("\r\n"), "{us}");
    // A length that is not the type's is written as hex.
    assert_eq!(c.send("[8] 1 r 0x1018 1 u64").await, "[8] A2 04 00 00\r\n");
    assert_eq!(c.send("[9] 1 r 0x1018 1 r64").await, "[9] A2 04 00 00\r\n");
    assert_eq!(
        c.send("[10] 1 r 0x1018 1 i64").await,
        "[10] A2 04 00 00\r\n"
    );

    // u16 (heartbeat period of the UIO1LED), write and read back.
    assert_eq!(c.send("[11] 3 w 0x1017 0 u16 1500").await, "[11] OK\r\n");
    assert_eq!(c.send("[12] 3 r 0x1017 0 u16").await, "[12] 1500\r\n");
    assert_eq!(c.send("[13] 3 r 0x1017 0 x16").await, "[13] 0x05DC\r\n");
    // u8, x8, b (UMC life time factor).
    assert_eq!(c.send("[14] 1 w 0x100D 0 u8 3").await, "[14] OK\r\n");
    assert_eq!(c.send("[15] 1 r 0x100D 0 u8").await, "[15] 3\r\n");
    assert_eq!(c.send("[16] 1 w 0x100D 0 x8 0x0A").await, "[16] OK\r\n");
    assert_eq!(c.send("[17] 1 r 0x100D 0 x8").await, "[17] 0x0A\r\n");
    assert_eq!(c.send("[18] 1 w 0x100D 0 b 1").await, "[18] OK\r\n");
    assert_eq!(c.send("[19] 1 r 0x100D 0 b").await, "[19] 1\r\n");
    // i8 (UMC phase advance), i16 (JMC quick stop option code), i32 (JMC
    // target position).
    assert_eq!(c.send("[20] 1 w 0x4009 2 i8 -5").await, "[20] OK\r\n");
    assert_eq!(c.send("[21] 1 r 0x4009 2 i8").await, "[21] -5\r\n");
    assert_eq!(c.send("[22] 2 w 0x605A 0 i16 2").await, "[22] OK\r\n");
    assert_eq!(c.send("[23] 2 r 0x605A 0 i16").await, "[23] 2\r\n");
    assert_eq!(c.send("[24] 2 w 0x607A 0 i32 -123456").await, "[24] OK\r\n");
    assert_eq!(c.send("[25] 2 r 0x607A 0 i32").await, "[25] -123456\r\n");
    assert_eq!(c.send("[26] 2 r 0x607A 0 x32").await, "[26] 0xFFFE1DC0\r\n");
    // The demo has no REAL32, octet string or domain object: their bytes
    // go to a 4-byte object and come back in their form.
    assert_eq!(c.send("[27] 2 w 0x607A 0 r32 1.5").await, "[27] OK\r\n");
    assert_eq!(c.send("[28] 2 r 0x607A 0 r32").await, "[28] 1.5\r\n");
    assert_eq!(c.send("[29] 2 w 0x607A 0 os AQIDBA==").await, "[29] OK\r\n");
    assert_eq!(c.send("[30] 2 r 0x607A 0 os").await, "[30] AQIDBA==\r\n");
    assert_eq!(c.send("[31] 2 r 0x607A 0 i32").await, "[31] 67305985\r\n");
    assert_eq!(c.send("[32] 2 w 0x607A 0 d BQYHCA==").await, "[32] OK\r\n");
    assert_eq!(c.send("[33] 2 r 0x607A 0 d").await, "[33] BQYHCA==\r\n");
    assert_eq!(
        c.send("[34] 2 w 0x607A 0 hex 0a 0b 0c 0d").await,
        "[34] OK\r\n"
    );
    assert_eq!(c.send("[35] 2 r 0x607A 0").await, "[35] 0A 0B 0C 0D\r\n");
    assert_eq!(c.send("[36] 2 w 0x607A 0 us AQAAAA==").await, "[36] OK\r\n");
    assert_eq!(c.send("[37] 2 r 0x607A 0 u32").await, "[37] 1\r\n");

    // 8-byte values on a 4-byte object: the device refuses the length.
    for (seq, command) in [
        (38, "w 0x607A 0 i64 -1"),
        (39, "w 0x607A 0 u64 1"),
        (40, "w 0x607A 0 x64 1"),
        (41, "w 0x607A 0 r64 2.5"),
    ] {
        let reply = c.send(&format!("[{seq}] 2 {command}")).await;
        assert!(
            reply.starts_with(&format!("[{seq}] ERROR:0x0607001")),
            "{command}: {reply}"
        );
    }

    // Aborts, with CANopenNode's text.
    assert_eq!(
        c.send("[42] 1 r 0x9999 0").await,
        "[42] ERROR:0x06020000 #Object does not exist.\r\n"
    );
    assert_eq!(
        c.send("[43] 1 w 0x1008 0 vs \"new name\"").await,
        "[43] ERROR:0x06010002 #Attempt to write a read only object.\r\n"
    );

    // Internal errors.
    assert_eq!(
        c.send("[44] 1 frobnicate").await,
        "[44] ERROR:100 #Request not supported.\r\n"
    );
    assert_eq!(
        c.send("[45] 1 r 0x1000 0 u24").await,
        "[45] ERROR:101 #Syntax error.\r\n"
    );
    assert_eq!(
        c.send("[46] 1 w 0x1017 0 u16 70000").await,
        "[46] ERROR:101 #Syntax error.\r\n"
    );
    assert_eq!(
        c.send("[47] r 0x1000 0").await,
        "[47] ERROR:105 #No default node set.\r\n"
    );
    assert_eq!(
        c.send("[48] 200 r 0x1000 0").await,
        "[48] ERROR:107 #Unsupported node.\r\n"
    );
    assert_eq!(
        c.send("[49] 2 1 r 0x1000 0").await,
        "[49] ERROR:106 #Unsupported net.\r\n"
    );
    // No sequence: the previous one answers, as in CANopenNode.
    assert_eq!(
        c.send("1 r 0x1000 0").await,
        "[49] ERROR:101 #Syntax error.\r\n"
    );
    // A node the gateway never heard.
    assert_eq!(
        c.send("[50] 99 r 0x1000 0").await,
        "[50] ERROR:107 #Unsupported node.\r\n"
    );
    // Comments and blank lines.
    assert_eq!(c.send("# just a comment").await, "\r\n");
    assert_eq!(
        c.send("[51] 1 r 0x1000 0 u32 # device type").await,
        "[51] 402\r\n"
    );

    // Defaults.
    assert_eq!(c.send("[52] set network 1").await, "[52] OK\r\n");
    assert_eq!(c.send("[53] set node 1").await, "[53] OK\r\n");
    assert_eq!(c.send("[54] r 0x1000 0 u32").await, "[54] 402\r\n");
    assert_eq!(c.send("[55] 1 1 r 0x1000 0 u32").await, "[55] 402\r\n");
    assert_eq!(c.send("[56] set sdo_block 1").await, "[56] OK\r\n");
    assert_eq!(
        c.send("[57] 1 r 0x1008 0 vs").await,
        "[57] \"UMC1BDS32 motion controller\"\r\n"
    );
    assert_eq!(c.send("[58] set sdo_block 0").await, "[58] OK\r\n");
    assert_eq!(c.send("[59] set sdo_timeout 200").await, "[59] OK\r\n");

    // help: CANopenNode's framing, without sequence.
    c.writer.write_all(b"[60] help datatype\r\n").await.unwrap();
    let mut help = String::new();
    loop {
        let line = c.line().await;
        help.push_str(&line);
        if line.ends_with("\r\n") {
            break;
        }
    }
    assert!(help.starts_with("\nDatatypes:\n"), "{help}");
    assert!(help.contains("x8, x16, x32, x64"));

    // NMT: stop, then SDO is refused from the state the node reported.
    assert_eq!(c.send("[61] 3 stop").await, "[61] OK\r\n");
    let (_, refused) = common::poll(&http, "/api/v1/buses/demo/nodes/3", |_, node| {
        node["nmt"] == "stopped"
    })
    .await;
    assert_eq!(refused["nmt"], "stopped");
    assert_eq!(
        c.send("[62] 3 r 0x1000 0").await,
        "[62] ERROR:204 #Wrong NMT state.\r\n"
    );
    assert_eq!(c.send("[63] 3 start").await, "[63] OK\r\n");
    assert_eq!(c.send("[64] 3 preop").await, "[64] OK\r\n");
    assert_eq!(c.send("[65] 3 preoperational").await, "[65] OK\r\n");
    assert_eq!(c.send("[66] 0 start").await, "[66] OK\r\n");
    // A reset: the node boots again, and says so.
    assert_eq!(c.send("[67] 2 reset node").await, "[67] OK\r\n");
    assert_eq!(c.event("1 2 BOOT_UP").await, "1 2 BOOT_UP\r\n");
    assert_eq!(c.send("[68] 3 reset comm").await, "[68] OK\r\n");
    assert_eq!(c.event("1 3 BOOT_UP").await, "1 3 BOOT_UP\r\n");

    // An EMCY: a fault injected into the UMC.
    let (status, body) = common::http(
        &http,
        "POST",
        "/api/v1/buses/demo/sim/nodes/1/faults",
        Some(r#"{"kind":"over_temperature"}"#),
    )
    .await;
    assert!((200..300).contains(&status), "{status} {body}");
    let emcy = c.event("1 1 EMCY ").await;
    assert!(emcy.starts_with("1 1 EMCY 0x4"), "{emcy}");
    assert!(emcy.ends_with("\r\n"));

    // Time-out: the LED controller unplugged, a short timeout.
    let (status, body) =
        common::http(&http, "DELETE", "/api/v1/buses/demo/sim/nodes/3", None).await;
    assert!((200..300).contains(&status), "{status} {body}");
    assert_eq!(c.send("[69] set sdo_timeout 50").await, "[69] OK\r\n");
    assert_eq!(
        c.send("[70] 3 r 0x1000 0 u32").await,
        "[70] ERROR:0x05040000 #SDO protocol timed out.\r\n"
    );

    // Writes and NMT commands are in the audit log, as REST's are.
    let (_, events) = json(&http, "GET", "/api/v1/events?kind=audit&limit=500", None).await;
    let text = events.to_string();
    assert!(text.contains("ascii:127.0.0.1:"), "{text}");
    assert!(text.contains("[11] 3 w 0x1017 0 u16 1500"), "{text}");
    assert!(text.contains("[67] 2 reset node"), "{text}");
    assert!(text.contains("0x06010002"), "{text}");
}

#[tokio::test]
async fn cia309_5_read_and_write_round_trip() {
    let (_server, http, _) = start();
    let (status, answer) = json(
        &http,
        "PUT",
        "/cia309-5/1.0/7/1/3/w/0x1017/0",
        Some(r#"{"value":"1200","datatype":"u16"}"#),
    )
    .await;
    assert_eq!(status, 200);
    assert_eq!(
        answer,
        serde_json::json!({"sequence": "7", "response": "OK"})
    );
    let (status, answer) = json(&http, "GET", "/cia309-5/1.0/8/1/3/r/0x1017/0", None).await;
    assert_eq!(status, 200);
    assert_eq!(
        answer,
        serde_json::json!({"sequence": "8", "response": "OK", "data": "0x04b0", "length": 2})
    );
    let (_, answer) = json(
        &http,
        "GET",
        "/cia309-5/1.0/9/default/1/read/0x9999/0",
        None,
    )
    .await;
    assert_eq!(
        answer,
        serde_json::json!({"sequence": "9", "response": "ERROR:0x06020000"})
    );
    let (_, answer) = json(
        &http,
        "PUT",
        "/cia309-5/1.0/10/1/3/w/0x1017/0",
        Some(r#"{"value":"1","datatype":"u24"}"#),
    )
    .await;
    assert_eq!(answer["response"], "ERROR:100");
    let (_, answer) = json(&http, "POST", "/cia309-5/1.0/11/1/3/start", None).await;
    assert_eq!(
        answer,
        serde_json::json!({"sequence": "11", "response": "OK"})
    );
    let (_, answer) = json(&http, "POST", "/cia309-5/1.0/12/1/2/reset/comm", None).await;
    assert_eq!(answer["response"], "OK");
    let (_, answer) = json(&http, "GET", "/cia309-5/1.0/13/5/1/r/0x1000/0", None).await;
    assert_eq!(answer["response"], "ERROR:106");
    let (_, events) = json(&http, "GET", "/api/v1/events?kind=audit", None).await;
    let text = events.to_string();
    assert!(text.contains("/cia309-5/1.0/7/1/3/w/0x1017/0"), "{text}");
}

#[tokio::test]
async fn stdin_stdout_mode() {
    let mut child = tokio::process::Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(["ascii", "--bus", "virtual:demo"])
        .env_remove("CANDECK_LOG")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .kill_on_drop(true)
        .spawn()
        .expect("candeck ascii starts");
    let mut stdin = child.stdin.take().unwrap();
    stdin
        .write_all(b"[1] 1 r 0x1018 1 x32\r\n[2] 3 w 0x1017 0 u16 900\n[3] 3 r 0x1017 0 u16\r\n[4] bogus\r\n")
        .await
        .unwrap();
    drop(stdin);
    let output = tokio::time::timeout(Duration::from_secs(30), child.wait_with_output())
        .await
        .expect("ends with its input")
        .unwrap();
    assert!(output.status.success());
    let text = String::from_utf8(output.stdout).unwrap();
    let replies: Vec<&str> = text
        .split_inclusive("\r\n")
        .filter(|line| line.starts_with('['))
        .collect();
    assert_eq!(
        replies,
        [
            "[1] 0x000004A2\r\n",
            "[2] OK\r\n",
            "[3] 900\r\n",
            "[4] ERROR:100 #Request not supported.\r\n"
        ]
    );
}

const VIEWER_TOKEN: &str = "viewer-token-0123456789abcdef";
const OPERATOR_TOKEN: &str = "operator-token-0123456789abcdef";

#[tokio::test]
async fn with_tokens_a_connection_needs_auth_and_the_role_of_the_rest_api() {
    let tokens = format!("scada:viewer:{VIEWER_TOKEN},plc:operator:{OPERATOR_TOKEN}");
    let (_server, http, ascii) = start_with_tokens(Some(&tokens));
    let mut client = Client::connect(&ascii).await;
    // Nothing before a token, but help and the settings of the connection.
    assert_eq!(
        client.send("[1] 1 r 0x1018 1 u32").await,
        "[1] ERROR:102 #Request not processed due to internal state.\r\n"
    );
    assert_eq!(client.send("[2] set sdo_timeout 500").await, "[2] OK\r\n");
    assert_eq!(
        client.send("[3] auth wrong-token-0123456789").await,
        "[3] ERROR:102 #Request not processed due to internal state.\r\n"
    );
    // A viewer reads, and may not write or command NMT.
    assert_eq!(
        client.send(&format!("[4] auth {VIEWER_TOKEN}")).await,
        "[4] OK\r\n"
    );
    assert_eq!(
        client.send("[5] 1 r 0x1018 1 u32").await,
        format!("[5] {}\r\n", client_vendor(&http).await)
    );
    assert_eq!(
        client.send("[6] 3 w 0x1017 0 u16 0").await,
        "[6] ERROR:102 #Request not processed due to internal state.\r\n"
    );
    assert_eq!(
        client.send("[7] 2 preop").await,
        "[7] ERROR:102 #Request not processed due to internal state.\r\n"
    );
    // An operator writes; the audit log names its token.
    assert_eq!(
        client.send(&format!("[8] auth {OPERATOR_TOKEN}")).await,
        "[8] OK\r\n"
    );
    assert_eq!(client.send("[9] 3 w 0x1017 0 u16 0").await, "[9] OK\r\n");
    let (status, audit) = common::json_with_token(
        &http,
        "GET",
        "/api/v1/events?kind=audit&limit=10",
        OPERATOR_TOKEN,
    )
    .await;
    assert_eq!(status, 200, "{audit}");
    let write = audit
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["channel"] == "cia309_3" && e["outcome"] == "ok")
        .unwrap_or_else(|| panic!("no ASCII entry in {audit}"));
    // The viewer's refused write and NMT command are in the log too.
    let refused: Vec<_> = audit
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["channel"] == "cia309_3" && e["outcome"] == "forbidden")
        .collect();
    assert_eq!(refused.len(), 2, "{audit}");
    assert!(refused.iter().all(|e| e["who"] == "scada"), "{audit}");
    assert_eq!(write["who"], "plc", "{write}");
    assert_eq!(write["role"], "operator", "{write}");

    // CiA 309-5 takes the bearer token of every HTTP request: a viewer
    // may not write, an operator may, and the log names it.
    let body = r#"{"value":"0","datatype":"u16"}"#;
    let path = "/cia309-5/1.0/20/1/3/w/0x1017/0";
    let put = |token: &'static str| {
        let http = http.clone();
        async move {
            common::request_with_headers(
                &http,
                "PUT",
                path,
                "application/json",
                Some(body),
                Duration::from_secs(30),
                &format!("Authorization: Bearer {token}\r\n"),
            )
            .await
        }
    };
    assert_eq!(put(VIEWER_TOKEN).await.status, 403);
    let answer = put(OPERATOR_TOKEN).await;
    assert_eq!(answer.status, 200, "{}", answer.body);
    assert_eq!(answer.json()["response"], "OK", "{}", answer.body);
    let (_, audit) = common::json_with_token(
        &http,
        "GET",
        "/api/v1/events?kind=audit&limit=10",
        OPERATOR_TOKEN,
    )
    .await;
    let entry = audit
        .as_array()
        .unwrap()
        .iter()
        .find(|e| {
            e["path"].as_str().is_some_and(|p| p.contains("/cia309-5/")) && e["outcome"] == "ok"
        })
        .unwrap_or_else(|| panic!("no 309-5 entry in {audit}"));
    assert_eq!(entry["who"], "plc", "{entry}");
    assert_eq!(entry["channel"], "cia309_5", "{entry}");
    // The viewer's refused write is in the log too.
    let refused = audit
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["path"] == path && e["outcome"] == "forbidden")
        .unwrap_or_else(|| panic!("no refused 309-5 entry in {audit}"));
    assert_eq!(refused["who"], "scada", "{refused}");
    assert_eq!(refused["error_code"], "forbidden", "{refused}");
    // Refused by the guard before its handler, it is still 309-5's.
    assert_eq!(refused["channel"], "cia309_5", "{refused}");
}

/// The UMC's vendor id (0x1018:1) as the u32 reply writes it.
async fn client_vendor(http: &str) -> String {
    let (_, body) = common::json_with_token(
        http,
        "GET",
        "/api/v1/buses/demo/nodes/1/od/0x1018/1",
        VIEWER_TOKEN,
    )
    .await;
    body["value"]
        .as_u64()
        .unwrap_or_else(|| panic!("no vendor id in {body}"))
        .to_string()
}

const INTERNAL_STATE: &str = "ERROR:102 #Request not processed due to internal state.\r\n";

/// `auth` with words after the token is a syntax error, and a failed
/// `auth` leaves the connection without the token it had before (it used
/// to keep it).
#[tokio::test]
async fn a_failed_or_malformed_auth_drops_the_earlier_token() {
    let tokens = format!("scada:viewer:{VIEWER_TOKEN},plc:operator:{OPERATOR_TOKEN}");
    let (_server, _http, ascii) = start_with_tokens(Some(&tokens));
    let mut client = Client::connect(&ascii).await;
    assert_eq!(
        client
            .send(&format!("[1] auth {OPERATOR_TOKEN} extra"))
            .await,
        "[1] ERROR:101 #Syntax error.\r\n"
    );
    assert_eq!(
        client.send("[2] 3 w 0x1017 0 u16 0").await,
        format!("[2] {INTERNAL_STATE}")
    );
    assert_eq!(
        client.send(&format!("[3] auth {OPERATOR_TOKEN}")).await,
        "[3] OK\r\n"
    );
    assert_eq!(client.send("[4] 3 w 0x1017 0 u16 0").await, "[4] OK\r\n");
    // A re-auth with a wrong token, or a malformed one, drops the operator.
    for (n, line) in [
        "auth wrong-token-0123456789".to_string(),
        format!("auth {OPERATOR_TOKEN} {OPERATOR_TOKEN}"),
        "auth".to_string(),
    ]
    .iter()
    .enumerate()
    {
        let sequence = 10 + 2 * n;
        let answer = client.send(&format!("[{sequence}] {line}")).await;
        assert!(
            answer.starts_with(&format!("[{sequence}] ERROR:10")),
            "{answer}"
        );
        assert_eq!(
            client
                .send(&format!("[{}] 3 w 0x1017 0 u16 0", sequence + 1))
                .await,
            format!("[{}] {INTERNAL_STATE}", sequence + 1),
            "after {line}"
        );
        assert_eq!(
            client
                .send(&format!("[{sequence}] auth {OPERATOR_TOKEN}"))
                .await,
            format!("[{sequence}] OK\r\n")
        );
    }
}

/// A token's CiA 309-3 writes and NMT commands draw on its write rate,
/// the same bucket as its REST writes: over it, 102 (they used to pass,
/// 200 of 200), and the refusal is audited.
#[tokio::test]
async fn writes_share_the_token_write_rate_with_rest() {
    let tokens = format!("scada:viewer:{VIEWER_TOKEN},plc:operator:{OPERATOR_TOKEN}");
    // A bucket of 4 that refills once in 1000 s: none during the test.
    let (_server, http, ascii) = start_with(
        Some(&tokens),
        &["--write-burst", "4", "--write-rate", "0.001"],
    );
    let mut client = Client::connect(&ascii).await;
    assert_eq!(
        client.send(&format!("[1] auth {OPERATOR_TOKEN}")).await,
        "[1] OK\r\n"
    );
    assert_eq!(client.send("[2] 3 w 0x1017 0 u16 1000").await, "[2] OK\r\n");
    assert_eq!(client.send("[3] 3 start").await, "[3] OK\r\n");
    // One through REST, with the same token.
    let response = common::request_with_headers(
        &http,
        "PUT",
        "/api/v1/buses/demo/nodes/3/od/0x1017/0",
        "application/json",
        Some(r#"{"value":1000}"#),
        Duration::from_secs(30),
        &format!("Authorization: Bearer {OPERATOR_TOKEN}\r\n"),
    )
    .await;
    assert_eq!(response.status, 200, "{}", response.body);
    assert_eq!(client.send("[4] 3 w 0x1017 0 u16 1000").await, "[4] OK\r\n");
    // The bucket is empty: writes and NMT are refused, reads are not.
    assert_eq!(
        client.send("[5] 3 w 0x1017 0 u16 1000").await,
        format!("[5] {INTERNAL_STATE}")
    );
    assert_eq!(
        client.send("[6] 3 preop").await,
        format!("[6] {INTERNAL_STATE}")
    );
    assert_eq!(client.send("[7] 3 r 0x1017 0 u16").await, "[7] 1000\r\n");
    // REST gives the same token 429 now.
    let response = common::request_with_headers(
        &http,
        "PUT",
        "/api/v1/buses/demo/nodes/3/od/0x1017/0",
        "application/json",
        Some(r#"{"value":1000}"#),
        Duration::from_secs(30),
        &format!("Authorization: Bearer {OPERATOR_TOKEN}\r\n"),
    )
    .await;
    assert_eq!(response.status, 429, "{}", response.body);
    // Another token has a bucket of its own (a viewer may read).
    let mut other = Client::connect(&ascii).await;
    other.send(&format!("[1] auth {VIEWER_TOKEN}")).await;
    assert_eq!(other.send("[2] 3 r 0x1017 0 u16").await, "[2] 1000\r\n");
    let (_, audit) = common::json_with_token(
        &http,
        "GET",
        "/api/v1/events?kind=audit&limit=20",
        VIEWER_TOKEN,
    )
    .await;
    let limited: Vec<_> = audit
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["channel"] == "cia309_3" && e["outcome"] == "rate_limited")
        .collect();
    assert_eq!(limited.len(), 2, "{audit}");
    assert!(
        limited
            .iter()
            .all(|e| e["who"] == "plc" && e["error_code"] == "rate_limited"),
        "{audit}"
    );
}

/// Writes and NMT commands the parser refuses (`ERROR:101` and the like)
/// are in the audit log, as REST's 400s are; reads and settings are not.
#[tokio::test]
async fn write_lines_the_parser_refuses_are_audited() {
    let (_server, http, ascii) = start();
    let mut client = Client::connect(&ascii).await;
    assert_eq!(
        client.send("[1] 3 w 0x1017 0 u16 70000").await,
        "[1] ERROR:101 #Syntax error.\r\n"
    );
    assert_eq!(
        client.send("[2] 200 w 0x1017 0 u16 1").await,
        "[2] ERROR:107 #Unsupported node.\r\n"
    );
    assert_eq!(
        client.send("[3] 3 start now").await,
        "[3] ERROR:101 #Syntax error.\r\n"
    );
    assert_eq!(
        client.send("[4] 3 r 0x1017 0 u99").await,
        "[4] ERROR:101 #Syntax error.\r\n"
    );
    assert_eq!(
        client.send("[5] set node 0").await,
        "[5] ERROR:101 #Syntax error.\r\n"
    );
    let (status, audit) = common::json(&http, "GET", "/api/v1/events?kind=audit", None).await;
    assert_eq!(status, 200, "{audit}");
    let seen: Vec<(String, String, String)> = audit
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["channel"] == "cia309_3")
        .map(|e| {
            (
                e["path"].as_str().unwrap().to_string(),
                e["operation"].as_str().unwrap().to_string(),
                e["outcome"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    let refused = |path: &str, operation: &str| {
        (
            path.to_string(),
            operation.to_string(),
            "invalid_request".to_string(),
        )
    };
    let mut expected = vec![
        refused("[1] 3 w 0x1017 0 u16 70000", "SDO write (refused)"),
        refused("[2] 200 w 0x1017 0 u16 1", "SDO write (refused)"),
        refused("[3] 3 start now", "NMT command (refused)"),
    ];
    let mut seen = seen;
    seen.sort();
    expected.sort();
    assert_eq!(seen, expected, "{audit:#}");
    assert!(
        audit
            .as_array()
            .unwrap()
            .iter()
            .all(|e| e["channel"] != "cia309_3"
                || (e["who"].as_str().unwrap().starts_with("ascii:")
                    && e["method"] == "ASCII"
                    && e.get("status").is_none()
                    && e["error_code"] == "invalid_request")),
        "{audit:#}"
    );
}

/// Issue 30, finding 6: 32 idle connections without a token (as many as
/// the listener takes) do not lock out a client with one: it takes the
/// place of the oldest of them, authenticates and is answered; and a
/// connection without a token is closed after the short
/// `ascii_unauthenticated_timeout_ms` while one with a token stays.
#[tokio::test]
async fn idle_connections_without_a_token_do_not_lock_out_one_with_a_token() {
    let tokens = format!("scada:viewer:{VIEWER_TOKEN}");
    let (_server, http, ascii) = start_with(
        Some(&tokens),
        &["--ascii-unauthenticated-timeout-ms", "2000"],
    );
    let mut idle = Vec::new();
    for _ in 0..32 {
        idle.push(TcpStream::connect(&ascii).await.unwrap());
    }
    let mut client = Client::connect(&ascii).await;
    // Today's main closed it at once: the reply is read without `send`,
    // which would read past the end of the input.
    client
        .writer
        .write_all(format!("[1] auth {VIEWER_TOKEN}\r\n").as_bytes())
        .await
        .unwrap();
    assert_eq!(client.line().await, "[1] OK\r\n");
    assert_eq!(
        client.send("[2] 1 r 0x1018 1 u32").await,
        format!("[2] {}\r\n", client_vendor(&http).await)
    );
    // The oldest idle connection gave its place; the others are closed
    // after the short timeout, the authenticated client is not.
    use tokio::io::AsyncReadExt;
    let mut byte = [0u8; 1];
    for stream in &mut idle {
        let read = tokio::time::timeout(Duration::from_secs(20), stream.read(&mut byte))
            .await
            .expect("closed within 20 s");
        assert!(matches!(read, Ok(0) | Err(_)), "{read:?}");
    }
    assert_eq!(
        client.send("[3] 1 r 0x1018 1 u32").await.get(..4),
        Some("[3] ")
    );
}
