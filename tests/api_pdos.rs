//! PDOs and SYNC over real HTTP against `candeck serve` (the demo bus): a
//! TPDO re-mapped and read back, SYNC switched on, an RPDO sent and its
//! value read back over SDO.

mod common;

use common::{http, start};
use std::time::Duration;

use serde_json::{Value as Json, json};

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
    // The node says it is operational in its next heartbeat (the network
    // manager set one): RPDOs are refused until then.
    for _ in 0..100 {
        let (_, node) = call(&address, "GET", "/api/v1/buses/demo/nodes/1", None).await;
        if node["nmt"] == "operational" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
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
