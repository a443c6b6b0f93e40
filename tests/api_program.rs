//! Program download (CiA 302-3) through `candeck serve` over real HTTP: the
//! issue's check, a 64 KiB image downloaded to the demo's UIO1LED (node 3)
//! gives 0x1F56 sub 1 = its CRC-32, and the device runs it (0x100A the
//! version its header names).

mod common;

use std::time::Duration;

use candeck::canopen::crc32::crc32;
use common::{json, poll, start};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// POSTs `body` as `application/octet-stream`; status and JSON answer.
async fn post_bytes(address: &str, path: &str, body: &[u8]) -> (u16, serde_json::Value) {
    let mut stream = TcpStream::connect(address).await.unwrap();
    let head = format!(
        "POST {path} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\nContent-Type: application/octet-stream\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes()).await.unwrap();
    stream.write_all(body).await.unwrap();
    let mut response = String::new();
    tokio::time::timeout(
        Duration::from_secs(60),
        stream.read_to_string(&mut response),
    )
    .await
    .expect("answer in time")
    .unwrap();
    let status = response[9..12].parse().unwrap();
    let (_, body) = response.split_once("\r\n\r\n").unwrap();
    (
        status,
        serde_json::from_str(body).unwrap_or_else(|err| panic!("{err}: {body}")),
    )
}

#[tokio::test]
async fn a_64_kib_image_downloaded_to_the_uio1led_gives_its_crc_in_0x1f56() {
    let (server, _) = start(&[]);
    let address = server.address.clone();
    let (status, body) = poll(&address, "/api/v1/buses/demo/nodes/3", |status, _| {
        status == 200
    })
    .await;
    assert_eq!(status, 200, "{body}");
    let mut image = b"CDKI\x067.8.9x".to_vec();
    image.extend((0..64 * 1024 - 11u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8));
    assert_eq!(image.len(), 64 * 1024);

    let (status, answer) = post_bytes(&address, "/api/v1/buses/demo/nodes/3/program", &image).await;
    assert_eq!(status, 200, "{answer}");
    assert_eq!(answer["crc32"], crc32(&image), "{answer}");
    assert_eq!(answer["verified"], true);
    eprintln!(
        "program download: {} bytes in {} ms ({} bytes/s over the virtual bus)",
        answer["bytes"], answer["download_ms"], answer["bytes_per_s"]
    );

    // The program's start resets the device: its values are typed by its
    // EDS once the gateway has identified it again.
    let (_, node) = poll(&address, "/api/v1/buses/demo/nodes/3", |_, node| {
        node["identification"]["state"] == "done" && !node["eds"].is_null()
    })
    .await;
    assert_eq!(node["identification"]["state"], "done", "{node}");
    let (status, value) = json(
        &address,
        "GET",
        "/api/v1/buses/demo/nodes/3/od/0x1F56/1",
        None,
    )
    .await;
    assert_eq!(status, 200, "{value}");
    // Its bytes on the wire, as the value's type does not matter here.
    let expected: String = crc32(&image)
        .to_le_bytes()
        .iter()
        .map(|byte| format!("{byte:02x}"))
        .collect();
    assert_eq!(value["raw"], expected, "{value}");
    let (_, version) = json(
        &address,
        "GET",
        "/api/v1/buses/demo/nodes/3/od/0x100A/0",
        None,
    )
    .await;
    assert_eq!(version["value"], "7.8.9x", "{version}");
    let (_, control) = json(
        &address,
        "GET",
        "/api/v1/buses/demo/nodes/3/od/0x1F51/1",
        None,
    )
    .await;
    assert_eq!(control["value"], 1, "{control}");
}
