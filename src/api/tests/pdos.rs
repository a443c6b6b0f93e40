//! PDOs and SYNC through the REST interface, against the demo devices on
//! `virtual:demo`, called through the router without a socket, on a paused
//! clock.

use crate::emulator::RackOf;
use std::time::Duration;

use axum::Router;
use axum::http::StatusCode;
use serde_json::{Value as Json, json};
use tokio::time::Instant;

use crate::api::AppState;
use crate::api::tests::support::{self, assert_error, demo, get, post, put};
use crate::can::{CanId, FrameReceiver};
use crate::canopen::NodeId;
use crate::canopen::eds::Eds;
use crate::canopen::od::{AccessType, Value};
use crate::canopen::pdo::{MappingEntry, PdoMapping};
use crate::sim::device::DeviceCore;

/// A UMC1BDS32 whose firmware refuses writes to TPDO1's mapping entries,
/// though its EDS (the gateway's) allows them.
const STUBBORN: u8 = 9;

/// The demo bus with every node identified, and a UMC1BDS32 core at node
/// 9 whose 0x1A00 entries are read-only.
async fn demo_with_stubborn() -> (Router, AppState) {
    let served = support::open("demo", "virtual:demo").await;
    let text = include_str!("../../../eds/umc1bds32.eds");
    let mut dictionary = Eds::parse(text, "umc1bds32.eds").unwrap().dictionary;
    for sub in 1..=8 {
        dictionary.sub_mut(0x1A00, sub).unwrap().access = AccessType::Ro;
    }
    let device = DeviceCore::new(dictionary, NodeId::new(STUBBORN).unwrap()).unwrap();
    served.rack().unwrap().add_device(device).unwrap();
    support::serve_scanned(served, 4).await
}

fn tx_frames(state: &AppState) -> u64 {
    state.gateway.bus("demo").unwrap().counters().tx_frames
}

async fn od_value(app: &Router, node: u8, index: &str) -> Json {
    let (status, body) = get(
        app,
        &format!("/api/v1/buses/demo/nodes/{node}/od/{index}/0"),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    body["value"].clone()
}

async fn nmt(app: &Router, node: u8, command: &str) {
    let uri = format!("/api/v1/buses/demo/nodes/{node}/nmt");
    let (status, body) = post(app, &uri, json!({ "command": command })).await;
    assert_eq!(status, StatusCode::OK, "{body}");
}

/// The frames of `receiver` within `window`.
async fn frames_within(receiver: &mut FrameReceiver, window: Duration) -> Vec<crate::can::Frame> {
    let end = Instant::now() + window;
    let mut frames = Vec::new();
    while let Ok(Ok(frame)) = tokio::time::timeout_at(end, receiver.recv()).await {
        frames.push(frame.frame);
    }
    frames
}

fn mapping_of(pdo: &Json) -> Vec<(String, u64, u64)> {
    pdo["mapping"]
        .as_array()
        .unwrap()
        .iter()
        .map(|entry| {
            (
                entry["index"].as_str().unwrap().to_string(),
                entry["sub"].as_u64().unwrap(),
                entry["bits"].as_u64().unwrap(),
            )
        })
        .collect()
}

#[tokio::test(start_paused = true)]
async fn the_pdos_of_each_demo_node_as_their_eds_and_defaults_say() {
    let (app, _) = demo().await;
    let (status, umc) = get(&app, "/api/v1/buses/demo/nodes/1/pdos").await;
    assert_eq!(status, StatusCode::OK, "{umc}");
    assert_eq!(umc["rpdo"].as_array().unwrap().len(), 4);
    assert_eq!(umc["tpdo"].as_array().unwrap().len(), 4);
    let tpdo1 = &umc["tpdo"][0];
    assert_eq!(
        *tpdo1,
        json!({
            "number": 1, "cob_id": 0x181, "enabled": true, "transmission_type": 1,
            "inhibit_time_100us": 0, "event_timer_ms": 0, "sync_start": 0,
            "mapping": [{"index": "0x6041", "sub": 0, "bits": 16, "name": "a1_Statusword"}],
        })
    );
    assert_eq!(umc["rpdo"][2]["cob_id"], 0x401);
    assert_eq!(
        mapping_of(&umc["rpdo"][2]),
        [("0x6040".into(), 0, 16), ("0x607A".into(), 0, 32)]
    );
    assert_eq!(umc["rpdo"][0]["sync_start"], Json::Null);

    // The JMC's PDOs have no inhibit time, event timer or SYNC start.
    let (status, jmc) = get(&app, "/api/v1/buses/demo/nodes/2/pdos").await;
    assert_eq!(status, StatusCode::OK, "{jmc}");
    let tpdo1 = &jmc["tpdo"][0];
    assert_eq!(tpdo1["cob_id"], 0x182);
    assert_eq!(tpdo1["inhibit_time_100us"], Json::Null);
    assert_eq!(
        mapping_of(tpdo1),
        [("0x6041".into(), 0, 16), ("0x6064".into(), 0, 32)]
    );
    assert_eq!(jmc["rpdo"][0]["transmission_type"], 254);

    // The UIO1LED's TPDOs are not valid and map nothing.
    let (status, uio) = get(&app, "/api/v1/buses/demo/nodes/3/pdos").await;
    assert_eq!(status, StatusCode::OK, "{uio}");
    for tpdo in uio["tpdo"].as_array().unwrap() {
        assert_eq!(tpdo["enabled"], false, "{tpdo}");
        assert_eq!(tpdo["mapping"], json!([]), "{tpdo}");
    }
    assert_eq!(uio["tpdo"][1]["cob_id"], 0x283);
}

/// Re-maps the UMC's TPDO1 to statusword and actual position of axis 1,
/// reads it back, and decodes the frames SYNC makes it send.
#[tokio::test(start_paused = true)]
async fn a_remapped_tpdo_answers_sync_with_the_right_values() {
    let (app, state) = demo().await;
    let (status, pdo) = put(
        &app,
        "/api/v1/buses/demo/nodes/1/pdos/tpdo/1",
        json!({"transmission_type": 1, "mapping": [
            {"index": "a1_Statusword"},
            {"index": "0x6064", "sub": 0},
        ]}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{pdo}");
    assert_eq!(pdo["enabled"], true);
    assert_eq!(pdo["cob_id"], 0x181);
    assert_eq!(pdo["mapping"][1]["name"], "a1_pc_Position_actual_value");
    assert_eq!(
        mapping_of(&pdo),
        [("0x6041".into(), 0, 16), ("0x6064".into(), 0, 32)]
    );
    // The node keeps it: read back again through GET.
    let (_, all) = get(&app, "/api/v1/buses/demo/nodes/1/pdos").await;
    assert_eq!(all["tpdo"][0], pdo);

    // Operational, with SYNC every 10 ms: TPDO1 (type 1) goes at each.
    nmt(&app, 1, "start").await;
    let served = state.gateway.bus("demo").unwrap().clone();
    let mut monitor = served.monitor();
    let (status, sync) = put(&app, "/api/v1/buses/demo/sync", json!({"period_ms": 10})).await;
    assert_eq!(status, StatusCode::OK, "{sync}");
    assert_eq!(sync["period_ms"], 10);
    assert_eq!(sync["cob_id"], 0x80);
    let frames = frames_within(&mut monitor, Duration::from_millis(100)).await;
    let syncs = frames
        .iter()
        .filter(|frame| frame.id() == CanId::Standard(0x080))
        .count();
    assert!((9..=11).contains(&syncs), "{syncs} SYNC in 100 ms");
    // The decoders telemetry builds from the node's configuration.
    let node = NodeId::new(1).unwrap();
    let eds = served.node(node).unwrap().eds_entry.unwrap();
    // Read by another master on the bus, as the gateway reads them.
    let channel = crate::gateway::SdoChannel::new(
        served.hub().expect("a virtual bus").attach(),
        node,
        crate::canopen::sdo::ClientConfig::default(),
    );
    let decoders = tokio::spawn(async move {
        crate::gateway::tpdo_decoders(&channel, Some(&eds.eds.dictionary)).await
    })
    .await
    .unwrap()
    .unwrap();
    assert_eq!(decoders.len(), 4);
    let decoder = &decoders[0];
    assert_eq!(decoder.cob_id(), CanId::Standard(0x181));
    assert_eq!(
        decoder.mapping(),
        &PdoMapping::new(vec![
            MappingEntry::new(0x6041, 0, 16),
            MappingEntry::new(0x6064, 0, 32),
        ])
        .unwrap()
    );
    let tpdos: Vec<_> = frames
        .iter()
        .filter_map(|frame| decoder.decode_frame(frame))
        .collect();
    assert!(
        (syncs - 1..=syncs).contains(&tpdos.len()),
        "{} TPDOs for {syncs} SYNCs",
        tpdos.len()
    );
    let last = tpdos.last().unwrap().as_ref().unwrap();
    assert_eq!(last[0].name.as_deref(), Some("a1_Statusword"));
    let statusword = od_value(&app, 1, "0x6041").await;
    let position = od_value(&app, 1, "0x6064").await;
    assert_eq!(
        last[0].value,
        Some(Value::Unsigned16(statusword.as_u64().unwrap() as u16))
    );
    assert_eq!(
        last[1].value,
        Some(Value::Integer32(position.as_i64().unwrap() as i32))
    );
    let (_, sync) = get(&app, "/api/v1/buses/demo/sync").await;
    assert!(sync["sent"].as_u64().unwrap() >= syncs as u64, "{sync}");

    // The gateway decodes them by the new mapping too, which it read again
    // after the PUT: GET .../values.
    let (status, values) = get(&app, "/api/v1/buses/demo/nodes/1/values").await;
    assert_eq!(status, StatusCode::OK, "{values}");
    assert_eq!(values["tpdos"][0]["number"], 1);
    assert_eq!(values["tpdos"][0]["cob_id"], 0x181);
    assert_eq!(
        values["tpdos"][0]["mapping"],
        json!(["0x6041:0", "0x6064:0"])
    );
    let value = |index: &str| {
        values["values"]
            .as_array()
            .unwrap()
            .iter()
            .find(|value| value["index"] == index && value["sub"] == 0)
            .cloned()
            .unwrap_or_else(|| panic!("{index} in {values}"))
    };
    assert_eq!(value("0x6041")["value"], statusword);
    assert_eq!(value("0x6041")["name"], "a1_Statusword");
    assert_eq!(value("0x6064")["value"], position);
    assert_eq!(value("0x6064")["bits"], 32);
    assert!(value("0x6064")["count"].as_u64().unwrap() >= 8, "{values}");

    // SYNC off: no more SYNC, no more TPDO1.
    let (status, _) = put(&app, "/api/v1/buses/demo/sync", json!({"period_ms": 0})).await;
    assert_eq!(status, StatusCode::OK);
    tokio::time::sleep(Duration::from_millis(20)).await;
    let mut monitor = served.monitor();
    let frames = frames_within(&mut monitor, Duration::from_millis(100)).await;
    assert!(
        frames
            .iter()
            .all(|frame| ![0x080, 0x181].contains(&frame.id().raw())),
        "{frames:?}"
    );
}

#[tokio::test(start_paused = true)]
async fn the_jmc_and_an_event_driven_tpdo_re_map_too() {
    let (app, _) = demo().await;
    let (status, pdo) = put(
        &app,
        "/api/v1/buses/demo/nodes/2/pdos/tpdo/3",
        json!({"mapping": [{"name": "Statusword"}], "transmission_type": 255}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{pdo}");
    assert_eq!(mapping_of(&pdo), [("0x6041".into(), 0, 16)]);
    assert_eq!(pdo["transmission_type"], 255);
    assert_eq!(pdo["enabled"], true);
    // A PDO as GET returns it can be PUT back unchanged.
    let (_, pdos) = get(&app, "/api/v1/buses/demo/nodes/1/pdos").await;
    for (kind, pdo) in [("rpdo", &pdos["rpdo"][2]), ("tpdo", &pdos["tpdo"][3])] {
        let uri = format!("/api/v1/buses/demo/nodes/1/pdos/{kind}/{}", pdo["number"]);
        let (status, back) = put(&app, &uri, pdo.clone()).await;
        assert_eq!(status, StatusCode::OK, "{back}");
        assert_eq!(back, *pdo);
    }
    // A disabled PDO, with its mapping kept.
    let (status, pdo) = put(
        &app,
        "/api/v1/buses/demo/nodes/3/pdos/tpdo/1",
        json!({"enabled": false, "event_timer_ms": 100}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{pdo}");
    assert_eq!(
        (pdo["enabled"].clone(), pdo["event_timer_ms"].clone()),
        (json!(false), json!(100))
    );
}

#[tokio::test(start_paused = true)]
async fn requests_the_eds_rules_out_never_reach_the_bus() {
    let (app, state) = demo().await;
    let uri = "/api/v1/buses/demo/nodes/1/pdos/tpdo/1";
    let before = tx_frames(&state);
    // Not mappable (the heartbeat time), not readable in an RPDO direction
    // sense, unknown, over 64 bits, too many entries, a reserved type.
    let cases = [
        (
            uri,
            json!({"mapping": [{"index": "0x1017"}]}),
            "invalid_mapping",
        ),
        (
            "/api/v1/buses/demo/nodes/1/pdos/rpdo/1",
            json!({"mapping": [{"index": "a1_Statusword"}]}),
            "invalid_mapping",
        ),
        (
            uri,
            json!({"mapping": [{"index": "no_such_object"}]}),
            "invalid_mapping",
        ),
        (
            uri,
            json!({"mapping": [{"index": "0x6064"}, {"index": "0x606C"}, {"index": "0x6041"}]}),
            "invalid_mapping",
        ),
        (
            uri,
            json!({"mapping": vec![json!({"index": "0x6060"}); 9]}),
            "invalid_mapping",
        ),
        (
            uri,
            json!({"mapping": [{"index": "0x6041", "bits": 17}]}),
            "invalid_mapping",
        ),
        (uri, json!({"transmission_type": 245}), "value_out_of_range"),
        (uri, json!({"cob_id": 0x601}), "invalid_mapping"),
        (uri, json!({"mapping": [{"sub": 0}]}), "invalid_mapping"),
        (uri, json!({"number": 2}), "invalid_request"),
        (uri, json!({"transmission_type": 256}), "invalid_request"),
    ];
    for (uri, body, code) in cases {
        let response = put(&app, uri, body.clone()).await;
        assert_error(&response, StatusCode::BAD_REQUEST, code);
    }
    let too_long = put(
        &app,
        uri,
        json!({"mapping": [{"index": "0x6064"}, {"index": "0x606C"}, {"index": "0x6041"}]}),
    )
    .await;
    assert!(
        too_long.1["error"]["message"]
            .as_str()
            .unwrap()
            .contains("80 bits"),
        "{}",
        too_long.1
    );
    // PDO numbers and kinds the node does not have.
    for uri in [
        "/api/v1/buses/demo/nodes/1/pdos/tpdo/5",
        "/api/v1/buses/demo/nodes/1/pdos/tpdo/0",
        "/api/v1/buses/demo/nodes/1/pdos/xpdo/1",
    ] {
        let response = put(&app, uri, json!({})).await;
        assert_error(&response, StatusCode::NOT_FOUND, "unknown_pdo");
    }
    let response = post(
        &app,
        "/api/v1/buses/demo/nodes/1/pdos/rpdo/7/send",
        json!({"values": {}}),
    )
    .await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_pdo");
    assert_eq!(tx_frames(&state), before, "a refused request sent frames");
    let response = put(
        &app,
        "/api/v1/buses/demo/sync",
        json!({"period_ms": 5_000_000}),
    )
    .await;
    assert_error(&response, StatusCode::BAD_REQUEST, "value_out_of_range");
    let response = get(&app, "/api/v1/buses/nope/sync").await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_bus");
    let response = get(&app, "/api/v1/buses/demo/nodes/42/pdos").await;
    assert_error(&response, StatusCode::NOT_FOUND, "unknown_node");
}

#[tokio::test(start_paused = true)]
async fn a_stopped_node_is_409() {
    let (app, _) = demo().await;
    nmt(&app, 2, "stop").await;
    // The JMC's heartbeat (1 s) reports the state.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let response = get(&app, "/api/v1/buses/demo/nodes/2/pdos").await;
    assert_error(&response, StatusCode::CONFLICT, "wrong_nmt_state");
    let response = put(
        &app,
        "/api/v1/buses/demo/nodes/2/pdos/tpdo/1",
        json!({"mapping": [{"index": "0x6041"}]}),
    )
    .await;
    assert_error(&response, StatusCode::CONFLICT, "wrong_nmt_state");
    let response = post(
        &app,
        "/api/v1/buses/demo/nodes/2/pdos/rpdo/1/send",
        json!({"values": {}}),
    )
    .await;
    assert_error(&response, StatusCode::CONFLICT, "wrong_nmt_state");
    // Pre-operational by its heartbeat: RPDOs would be ignored.
    nmt(&app, 2, "pre_operational").await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let response = post(
        &app,
        "/api/v1/buses/demo/nodes/2/pdos/rpdo/1/send",
        json!({"values": {"0x6081": 1000, "0x6083": 100, "0x6084": 100}}),
    )
    .await;
    assert_error(&response, StatusCode::CONFLICT, "wrong_nmt_state");
}

/// A device that refuses a step half way: the error names the step and
/// carries the abort; the PDO stays invalid, as the procedure left it.
#[tokio::test(start_paused = true)]
async fn a_step_the_device_refuses_is_named() {
    let (app, _) = demo_with_stubborn().await;
    let response = put(
        &app,
        &format!("/api/v1/buses/demo/nodes/{STUBBORN}/pdos/tpdo/1"),
        json!({"mapping": [{"index": "a1_Statusword"}]}),
    )
    .await;
    assert_error(&response, StatusCode::UNPROCESSABLE_ENTITY, "sdo_abort");
    assert_eq!(response.1["error"]["step"], "write_mapping_entry_1");
    assert_eq!(response.1["error"]["abort_code"], "0x06010002");
    let (_, pdos) = get(&app, &format!("/api/v1/buses/demo/nodes/{STUBBORN}/pdos")).await;
    assert_eq!(pdos["tpdo"][0]["enabled"], false);
    assert_eq!(pdos["tpdo"][0]["mapping"], json!([]));
}

/// RPDO3 of the UMC (controlword, target position; type 1): the values take
/// effect at the next SYNC.
#[tokio::test(start_paused = true)]
async fn an_rpdo_sets_the_values_on_the_device() {
    let (app, state) = demo().await;
    nmt(&app, 1, "start").await;
    let uri = "/api/v1/buses/demo/nodes/1/pdos/rpdo/3/send";
    let before = tx_frames(&state);
    for (values, code) in [
        (json!({"a1_Controlword": 0}), "invalid_value"),
        (
            json!({"a1_Controlword": 0, "0x607A": 1, "extra": 1}),
            "invalid_value",
        ),
        (
            json!({"a1_Controlword": -1, "0x607A": 1}),
            "value_out_of_range",
        ),
    ] {
        let response = post(&app, uri, json!({ "values": values })).await;
        assert_error(&response, StatusCode::BAD_REQUEST, code);
    }
    // The mapping was read (SDO), but no RPDO went out.
    let sent_rpdo = state.gateway.bus("demo").unwrap().counters().tx_frames - before;
    assert!(sent_rpdo > 0);
    let mut monitor = state.gateway.bus("demo").unwrap().monitor();
    let (status, sent) = post(
        &app,
        uri,
        json!({"values": {"a1_Controlword": 0, "a1_pp_Position_target": 12345}}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{sent}");
    assert_eq!(sent["cob_id"], 0x401);
    assert_eq!(sent["data"], "000039300000");
    assert_eq!(sent["values"][1]["value"], 12345);
    let frames = frames_within(&mut monitor, Duration::from_millis(5)).await;
    assert!(
        frames
            .iter()
            .any(|frame| frame.id() == CanId::Standard(0x401)
                && frame.data() == [0, 0, 0x39, 0x30, 0, 0]),
        "{frames:?}"
    );
    // Synchronous: not applied before SYNC.
    assert_ne!(od_value(&app, 1, "0x607A").await, 12345);
    let (status, _) = put(&app, "/api/v1/buses/demo/sync", json!({"period_ms": 10})).await;
    assert_eq!(status, StatusCode::OK);
    tokio::time::sleep(Duration::from_millis(25)).await;
    assert_eq!(od_value(&app, 1, "0x607A").await, 12345);
}
