//! PDOs and SYNC over real HTTP against `candeck serve` (the demo bus): a
//! TPDO re-mapped and read back, SYNC switched on, an RPDO sent and its
//! value read back over SDO.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use serde_json::{Value as Json, json};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

struct Server {
    child: Child,
    address: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `candeck ARGS --listen 127.0.0.1:0` and reads the address from its
/// first stdout line.
fn start(args: &[&str]) -> (Server, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        .env_remove("CANDECK_LOG")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("candeck starts");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let address = line
        .strip_prefix("candeck: serving http://")
        .and_then(|rest| rest.split_once('/'))
        .map(|(address, _)| address.to_string())
        .unwrap_or_else(|| panic!("first line: {line}"));
    (Server { child, address }, line)
}

/// One request, `Connection: close`; returns the status code and body.
async fn http(address: &str, method: &str, path: &str, body: Option<&str>) -> (u16, String) {
    let mut stream = TcpStream::connect(address).await.unwrap();
    let body = body.unwrap_or("");
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    );
    stream.write_all(request.as_bytes()).await.unwrap();
    let mut response = String::new();
    tokio::time::timeout(
        Duration::from_secs(10),
        stream.read_to_string(&mut response),
    )
    .await
    .expect("answer in time")
    .unwrap();
    let status = response
        .strip_prefix("HTTP/1.1 ")
        .and_then(|rest| rest.get(..3))
        .and_then(|code| code.parse().ok())
        .unwrap_or_else(|| panic!("response: {response}"));
    let (_, body) = response.split_once("\r\n\r\n").unwrap();
    (status, body.to_string())
}

async fn call(address: &str, method: &str, path: &str, body: Option<Json>) -> (u16, Json) {
    let body = body.map(|body| body.to_string());
    let (status, text) = http(address, method, path, body.as_deref()).await;
    let json = serde_json::from_str(&text).unwrap_or_else(|err| panic!("{path}: {err}: {text}"));
    (status, json)
}

async fn wait_for_demo_nodes(address: &str) {
    for _ in 0..100 {
        let (_, nodes) = call(address, "GET", "/api/v1/buses/demo/nodes", None).await;
        let done = nodes
            .as_array()
            .unwrap()
            .iter()
            .filter(|n| n["identification"]["state"] == "done")
            .count();
        if done == 3 {
            return;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("the demo nodes were not identified");
}

#[tokio::test]
async fn remap_sync_and_rpdo_over_http() {
    let (server, _) = start(&[]);
    let address = server.address.clone();
    wait_for_demo_nodes(&address).await;

    let (status, pdos) = call(&address, "GET", "/api/v1/buses/demo/nodes/1/pdos", None).await;
    assert_eq!(status, 200, "{pdos}");
    assert_eq!(pdos["tpdo"][0]["mapping"][0]["name"], "a1_Statusword");

    let (status, pdo) = call(
        &address,
        "PUT",
        "/api/v1/buses/demo/nodes/1/pdos/tpdo/1",
        Some(json!({"mapping": [{"index": "a1_Statusword"}, {"index": "a1_pc_Position_actual_value"}]})),
    )
    .await;
    assert_eq!(status, 200, "{pdo}");
    assert_eq!(pdo["mapping"][1]["index"], "0x6064");
    assert_eq!(pdo["enabled"], true);

    let (status, error) = call(
        &address,
        "PUT",
        "/api/v1/buses/demo/nodes/1/pdos/tpdo/1",
        Some(json!({"mapping": [{"index": "0x1017"}]})),
    )
    .await;
    assert_eq!(status, 400, "{error}");
    assert_eq!(error["error"]["code"], "invalid_mapping");

    let (status, _) = call(
        &address,
        "POST",
        "/api/v1/buses/demo/nodes/1/nmt",
        Some(json!({"command": "start"})),
    )
    .await;
    assert_eq!(status, 200);
    let (status, sent) = call(
        &address,
        "POST",
        "/api/v1/buses/demo/nodes/1/pdos/rpdo/3/send",
        Some(json!({"values": {"a1_Controlword": 0, "a1_pp_Position_target": -4321}})),
    )
    .await;
    assert_eq!(status, 200, "{sent}");
    assert_eq!(sent["data"], "00001fefffff");

    let (status, sync) = call(
        &address,
        "PUT",
        "/api/v1/buses/demo/sync",
        Some(json!({"period_ms": 10})),
    )
    .await;
    assert_eq!(status, 200, "{sync}");
    // The RPDO (type 1) is applied at the first SYNC.
    let mut target = Json::Null;
    for _ in 0..50 {
        let (_, value) = call(
            &address,
            "GET",
            "/api/v1/buses/demo/nodes/1/od/0x607A/0",
            None,
        )
        .await;
        target = value["value"].clone();
        if target == -4321 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert_eq!(target, -4321);
    let (_, sync) = call(&address, "GET", "/api/v1/buses/demo/sync", None).await;
    assert_eq!(sync["period_ms"], 10);
    assert!(sync["sent"].as_u64().unwrap() > 0, "{sync}");
    let (status, sync) = call(
        &address,
        "PUT",
        "/api/v1/buses/demo/sync",
        Some(json!({"period_ms": 0})),
    )
    .await;
    assert_eq!((status, sync["period_ms"].clone()), (200, json!(0)));
}
