//! `/api/v1/stream` of the real `candeck serve` over real WebSockets
//! (tokio-tungstenite as the client): an axis topic during a velocity move
//! at the rate asked for, a client that never reads hurting no one, and the
//! endpoint answering plain HTTP with an error.

mod common;

use std::time::Duration;

use common::{enable_and_move, http, json, start};
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value as Json, json};
use tokio::net::TcpStream;
use tokio::time::Instant;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

type Socket = WebSocketStream<MaybeTlsStream<TcpStream>>;

async fn connect(address: &str) -> Socket {
    let (socket, response) =
        tokio_tungstenite::connect_async(format!("ws://{address}/api/v1/stream"))
            .await
            .expect("the stream accepts WebSockets");
    assert_eq!(response.status(), 101);
    socket
}

async fn next_json(socket: &mut Socket) -> Json {
    loop {
        let message = tokio::time::timeout(Duration::from_secs(10), socket.next())
            .await
            .expect("a message within 10 s")
            .expect("the stream is open")
            .expect("a message");
        if let Message::Text(text) = message {
            return serde_json::from_str(&text).unwrap();
        }
    }
}

async fn subscribe(socket: &mut Socket, topics: &[&str], rate: f64) {
    let request = json!({"op": "subscribe", "topics": topics, "max_rate_hz": rate});
    socket
        .send(Message::text(request.to_string()))
        .await
        .unwrap();
    let ack = next_json(socket).await;
    assert_eq!(ack["op"], "subscribed", "{ack}");
    assert_eq!(
        ack["topics"].as_array().unwrap().len(),
        topics.len(),
        "{ack}"
    );
}

/// The demo's UMC axis 1 enabled and turning in velocity mode.
async fn start_moving(address: &str) {
    let axes = "/api/v1/buses/demo/nodes/1/axes";
    for _ in 0..200 {
        if json(address, "GET", axes, None).await.0 == 200 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    enable_and_move(
        address,
        &format!("{axes}/1"),
        r#"{"mode":"velocity","velocity":200}"#,
    )
    .await;
}

/// The axis updates `socket` gets over `window`, after the first: their
/// count and positions.
async fn axis_updates(socket: &mut Socket, topic: &str, window: Duration) -> Vec<i64> {
    // The first sample may be one the topic held before.
    next_json(socket).await;
    let end = Instant::now() + window;
    let mut positions = Vec::new();
    while Instant::now() < end {
        let message = next_json(socket).await;
        assert_eq!(message["topic"], topic, "{message}");
        assert!(message["data"]["error"].is_null(), "{message}");
        positions.push(message["data"]["position"].as_i64().unwrap());
    }
    positions
}

#[tokio::test]
async fn an_axis_topic_during_a_velocity_move_comes_at_the_rate_asked_for() {
    // A lease longer than the test: the motion must not be halted by its
    // lapse while the rate is measured.
    let (server, _) = start(&["--lease-ms", "60000"]);
    let address = server.address.clone();
    start_moving(&address).await;

    let topic = "buses/demo/nodes/1/axes/1";
    let mut socket = connect(&address).await;
    subscribe(&mut socket, &[topic], 20.0).await;
    let window = Duration::from_secs(3);
    let positions = axis_updates(&mut socket, topic, window).await;
    // 20 Hz over 3 s: 60 updates, ±20 %.
    assert!(
        (48..=72).contains(&positions.len()),
        "{} updates in {window:?}",
        positions.len()
    );
    let changes = positions.windows(2).filter(|p| p[0] != p[1]).count();
    assert!(changes * 10 >= positions.len() * 9, "{positions:?}");

    json(&address, "POST", "/api/v1/stop-all", None).await;
}

/// Resident memory of a process, in KiB.
fn rss_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    status
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|value| value.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap()
}

#[tokio::test]
async fn a_client_that_never_reads_slows_no_one_and_costs_bounded_memory() {
    let (server, _) = start(&["--lease-ms", "60000"]);
    let address = server.address.clone();
    start_moving(&address).await;
    let topic = "buses/demo/nodes/1/axes/1";

    // Clients that subscribe to everything at the highest rate and then
    // never read again.
    let mut stuck = Vec::new();
    for _ in 0..4 {
        let mut socket = connect(&address).await;
        subscribe(
            &mut socket,
            &[
                topic,
                "nodes",
                "emcy",
                "buses/demo/frames",
                "buses/demo/nodes/1/values",
            ],
            1000.0,
        )
        .await;
        stuck.push(socket);
    }
    let mut reader = connect(&address).await;
    subscribe(&mut reader, &[topic], 20.0).await;

    let before = rss_kib(server.child.id());
    // Frames keep coming meanwhile: the move's SDO traffic and heartbeats,
    // and a burst of frames posted.
    let burst = tokio::spawn({
        let address = address.clone();
        async move {
            for n in 0..400 {
                let body = format!(r#"{{"id": "0x555", "data": "{n:08X}"}}"#);
                json(&address, "POST", "/api/v1/buses/demo/frames", Some(&body)).await;
            }
        }
    });
    let window = Duration::from_secs(3);
    let positions = axis_updates(&mut reader, topic, window).await;
    burst.await.unwrap();
    assert!(
        (48..=72).contains(&positions.len()),
        "{} updates in {window:?} beside clients that never read",
        positions.len()
    );
    let after = rss_kib(server.child.id());
    // What the stuck clients may hold is bounded by their topics; their
    // socket buffers are the kernel's, not the process's.
    assert!(
        after < before + 32 * 1024,
        "resident memory grew from {before} KiB to {after} KiB"
    );
    drop(stuck);
    json(&address, "POST", "/api/v1/stop-all", None).await;
}

#[tokio::test]
async fn plain_http_to_the_stream_is_refused_in_the_apis_error_shape() {
    let (server, _) = start(&[]);
    let (status, body) = http(&server.address, "GET", "/api/v1/stream", None).await;
    assert_eq!(status, 426, "{body}");
    let body: Json = serde_json::from_str(&body).unwrap();
    assert_eq!(body["error"]["code"], "upgrade_required", "{body}");
}
