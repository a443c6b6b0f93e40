//! LED segments, store and restore, and DCF backup and restore, through the
//! router on the demo bus (node 1 UMC1BDS32, node 2 JMC, node 3 UIO1LED),
//! on a paused clock.

use crate::emulator::RackOf;
use std::collections::BTreeMap;
use std::time::Duration;

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Value as Json, json};

use crate::api::AppState;
use crate::api::tests::support::{assert_error, demo, get, post, put, raw_call};
use crate::can::CanId;
use crate::canopen::NodeId;
use crate::canopen::eds::Eds;
use crate::sim::products::Product;

fn ok(response: (StatusCode, Json)) -> Json {
    assert_eq!(response.0, StatusCode::OK, "{}", response.1);
    response.1
}

const SEGMENTS: &str = "/api/v1/buses/demo/nodes/3/segments";

fn rgbw(r: u8, g: u8, b: u8, w: u8) -> Json {
    json!({"r": r, "g": g, "b": b, "w": w})
}

#[tokio::test(start_paused = true)]
async fn a_scene_is_applied_read_back_and_its_preview_moves() {
    let (app, _) = demo().await;
    let scene = json!({"segments": [
        {"segment": 1, "led_count": 10, "effect": "flow", "colors": ["#ff0000", "#000020"],
         "min_value": 0, "max_value": 999, "value": 0, "speed": 1},
        {"segment": 2, "led_count": 5, "effect": "FIX", "colors": [{"r": 0, "g": 255, "b": 0, "w": 0}],
         "dimmer": 128},
    ], "others": "off"});
    let applied = ok(put(&app, SEGMENTS, scene).await);
    let segments = applied.as_array().unwrap();
    assert_eq!(segments.len(), 10);
    let first = &segments[0];
    assert_eq!(first["segment"], 1);
    assert_eq!(first["led_count"], 10);
    assert_eq!(first["effect"], "flow");
    assert_eq!(first["colors"][0], rgbw(255, 0, 0, 0));
    assert_eq!(first["colors"][1], rgbw(0, 0, 32, 0));
    assert_eq!(first["colors"][2], rgbw(0, 0, 0, 0));
    assert_eq!(
        (
            &first["min_value"],
            &first["max_value"],
            &first["speed"],
            &first["dimmer"]
        ),
        (&json!(0), &json!(999), &json!(1), &json!(255))
    );
    assert_eq!(segments[1]["effect"], "fix");
    assert_eq!(segments[1]["dimmer"], 128);
    assert_eq!(segments[2]["effect"], "off");

    // Read back by GET: the same parameters (Value moves: compare the rest).
    let listed = ok(get(&app, SEGMENTS).await);
    let without_value = |segment: &Json| {
        let mut segment = segment.clone();
        segment["value"] = Json::Null;
        segment
    };
    for (a, b) in listed.as_array().unwrap().iter().zip(segments) {
        assert_eq!(without_value(a), without_value(b));
    }

    let before = ok(get(&app, &format!("{SEGMENTS}/preview")).await);
    assert_eq!(before["led_count"], 15);
    assert_eq!(before["segments"][1]["start"], 10);
    assert_eq!(before["segments"][1]["led_count"], 5);
    let pixels = before["pixels"].as_array().unwrap();
    assert_eq!(pixels.len(), 15);
    // Segment 2: green at half the dimmer.
    for pixel in &pixels[10..] {
        assert_eq!(*pixel, rgbw(0, 128, 0, 0));
    }
    // Segment 1: one red head on the background colour.
    let head = |pixels: &[Json]| {
        let heads: Vec<usize> = (0..10)
            .filter(|led| pixels[*led] == rgbw(255, 0, 0, 0))
            .collect();
        assert_eq!(heads.len(), 1, "{pixels:?}");
        assert!(
            (0..10)
                .filter(|led| *led != heads[0])
                .all(|led| pixels[led] == rgbw(0, 0, 32, 0))
        );
        heads[0]
    };
    let head_before = head(pixels);

    // Value moves 1 per ms over 0..=999: 500 ms on, the head is 5 LEDs on.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let after = ok(get(&app, &format!("{SEGMENTS}/preview")).await);
    let head_after = head(after["pixels"].as_array().unwrap());
    // Each read is an SDO exchange on the 500 kbit/s wire, a millisecond
    // or so: the head moved 5 LEDs, give or take the one a read straddles.
    let moved = (head_after + 10 - head_before) % 10;
    assert!((4..=6).contains(&moved), "{moved}: {before} {after}");
    assert_ne!(before["pixels"], after["pixels"]);
}

/// The SDO downloads to node 3 seen on the bus: (index, sub) of each.
fn downloads(frames: &mut crate::can::FrameReceiver) -> Vec<(u16, u8)> {
    let mut seen = Vec::new();
    while let Ok(Some(frame)) = frames.try_recv() {
        let frame = frame.frame;
        let data = frame.data();
        // Initiate download: command specifier 1 in bits 5–7.
        if frame.id() == CanId::Standard(0x603) && data.len() == 8 && data[0] >> 5 == 1 {
            seen.push((u16::from_le_bytes([data[1], data[2]]), data[3]));
        }
    }
    seen
}

#[tokio::test(start_paused = true)]
async fn a_partial_put_writes_only_the_fields_given() {
    let (app, state) = demo().await;
    let segment = ok(put(
        &app,
        &format!("{SEGMENTS}/3"),
        json!({"led_count": 4, "effect": "breathing", "colors": ["#10203040"], "dimmer": 200}),
    )
    .await);
    assert_eq!(segment["segment"], 3);
    assert_eq!(segment["effect"], "breathing");
    assert_eq!(segment["colors"][0], rgbw(0x10, 0x20, 0x30, 0x40));

    let mut frames = state.gateway.bus("demo").unwrap().monitor();
    let segment = ok(put(&app, &format!("{SEGMENTS}/3"), json!({"dimmer": 50})).await);
    assert_eq!(downloads(&mut frames), [(0x6225, 0)]);
    assert_eq!(segment["dimmer"], 50);
    assert_eq!(segment["led_count"], 4);
    assert_eq!(segment["effect"], "breathing");
    assert_eq!(segment["colors"][0], rgbw(0x10, 0x20, 0x30, 0x40));

    // One channel of colour 2; colour 1 left as it is (null).
    let segment = ok(put(
        &app,
        &format!("{SEGMENTS}/3"),
        json!({"segment": 3, "colors": [null, {"g": 9}]}),
    )
    .await);
    assert_eq!(downloads(&mut frames), [(0x6231, 2)]);
    assert_eq!(segment["colors"][0], rgbw(0x10, 0x20, 0x30, 0x40));
    assert_eq!(segment["colors"][1], rgbw(0, 9, 0, 0));
    assert_eq!(segment["dimmer"], 50);
    // The other segments are untouched.
    let all = ok(get(&app, SEGMENTS).await);
    assert_eq!(all[1]["effect"], "off");
    assert_eq!(all[1]["led_count"], 0);
}

#[tokio::test(start_paused = true)]
async fn segment_errors_are_found_before_anything_is_written() {
    let (app, state) = demo().await;
    assert_error(
        &put(&app, &format!("{SEGMENTS}/11"), json!({"dimmer": 1})).await,
        StatusCode::NOT_FOUND,
        "unknown_segment",
    );
    assert_error(
        &put(&app, &format!("{SEGMENTS}/0"), json!({"dimmer": 1})).await,
        StatusCode::NOT_FOUND,
        "unknown_segment",
    );
    assert_error(
        &put(&app, &format!("{SEGMENTS}/first"), json!({"dimmer": 1})).await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    assert_error(
        &put(
            &app,
            SEGMENTS,
            json!({"segments": [{"segment": 12, "dimmer": 1}]}),
        )
        .await,
        StatusCode::NOT_FOUND,
        "unknown_segment",
    );
    for node in [1, 2] {
        let uri = format!("/api/v1/buses/demo/nodes/{node}/segments");
        assert_error(
            &get(&app, &uri).await,
            StatusCode::NOT_FOUND,
            "not_an_led_controller",
        );
    }
    assert_error(
        &get(&app, "/api/v1/buses/demo/nodes/9/segments/preview").await,
        StatusCode::NOT_FOUND,
        "unknown_node",
    );

    let mut frames = state.gateway.bus("demo").unwrap().monitor();
    let uri = format!("{SEGMENTS}/1");
    let cases = [
        (
            json!({"dimmer": 10, "colors": ["#zz0000"]}),
            "invalid_value",
        ),
        (json!({"dimmer": 10, "colors": ["#ff00"]}), "invalid_value"),
        (
            json!({"dimmer": 10, "colors": [{"r": 300}]}),
            "value_out_of_range",
        ),
        (
            json!({"dimmer": 10, "colors": [{"red": 3}]}),
            "invalid_value",
        ),
        (
            json!({"dimmer": 10, "colors": [1, 2, 3, 4]}),
            "invalid_value",
        ),
        (json!({"dimmer": 256}), "value_out_of_range"),
        (json!({"speed": 40000}), "value_out_of_range"),
        (json!({"dimmer": 10, "effect": "sparkle"}), "invalid_value"),
        (json!({"dimmer": 10, "segment": 2}), "invalid_value"),
        (json!({"dimmer": 10, "dimer": 3}), "invalid_request"),
    ];
    for (body, code) in cases {
        let response = put(&app, &uri, body.clone()).await;
        assert_error(&response, StatusCode::BAD_REQUEST, code);
    }
    assert_error(
        &put(
            &app,
            SEGMENTS,
            json!({"segments": [{"segment": 1, "dimmer": 3}, {"segment": 1}]}),
        )
        .await,
        StatusCode::BAD_REQUEST,
        "invalid_value",
    );
    assert_error(
        &put(
            &app,
            SEGMENTS,
            json!({"segments": [{"segment": 1, "dimmer": 3}], "others": "dark"}),
        )
        .await,
        StatusCode::BAD_REQUEST,
        "invalid_value",
    );
    assert_eq!(downloads(&mut frames), []);
    let segment = ok(get(&app, SEGMENTS).await);
    assert_eq!(segment[0]["dimmer"], 255);
}

/// Node `node`'s object read over SDO, as a JSON value.
async fn read(app: &Router, node: u8, index: &str, sub: u8) -> Json {
    let uri = format!("/api/v1/buses/demo/nodes/{node}/od/{index}/{sub}");
    ok(get(app, &uri).await)["value"].clone()
}

async fn write(app: &Router, node: u8, index: &str, sub: u8, value: Json) {
    let uri = format!("/api/v1/buses/demo/nodes/{node}/od/{index}/{sub}");
    ok(put(app, &uri, json!({ "value": value })).await);
}

async fn nmt(app: &Router, node: u8, command: &str) {
    let uri = format!("/api/v1/buses/demo/nodes/{node}/nmt");
    ok(post(app, &uri, json!({ "command": command })).await);
    // Boot-up and the registry's view of it.
    tokio::time::sleep(Duration::from_millis(200)).await;
}

#[tokio::test(start_paused = true)]
async fn stored_values_come_back_after_a_change_and_a_restore_or_reset() {
    let (app, _) = demo().await;
    let store = "/api/v1/buses/demo/nodes/3/store";
    let restore = "/api/v1/buses/demo/nodes/3/restore";
    // s01_Dimmer (0x6025) and the producer heartbeat time (0x1017).
    nmt(&app, 3, "pre_operational").await;
    write(&app, 3, "0x6025", 0, json!(100)).await;
    write(&app, 3, "0x1017", 0, json!(700)).await;
    let done = ok(post(&app, store, json!({"what": "all"})).await);
    assert_eq!(
        done,
        json!({"what": "all", "index": "0x1010", "sub": 1, "name": "Save_all_parameters", "signature": "save"})
    );

    write(&app, 3, "0x6025", 0, json!(20)).await;
    let done = ok(post(
        &app,
        restore,
        json!({"what": "application", "source": "saved"}),
    )
    .await);
    assert_eq!(
        (&done["sub"], &done["source"]),
        (&json!(7), &json!("saved"))
    );
    assert_eq!(read(&app, 3, "0x6025", 0).await, 100);

    // A reset loads the stored values over the changed ones.
    write(&app, 3, "0x6025", 0, json!(20)).await;
    write(&app, 3, "0x1017", 0, json!(900)).await;
    nmt(&app, 3, "reset_node").await;
    assert_eq!(read(&app, 3, "0x6025", 0).await, 100);
    assert_eq!(read(&app, 3, "0x1017", 0).await, 700);

    // The factory values, then a reset: the stored ones are gone.
    let done = ok(post(&app, restore, json!({"what": "all"})).await);
    assert_eq!(
        (&done["sub"], &done["source"]),
        (&json!(1), &json!("factory"))
    );
    nmt(&app, 3, "reset_node").await;
    assert_eq!(read(&app, 3, "0x6025", 0).await, 255);

    // Errors: an area that is none, a field too many, an area the node's
    // EDS lacks (the JMC has no sub 4), a state the device refuses in.
    for body in [
        json!({"what": "everything"}),
        json!({"what": "all", "when": "now"}),
        json!({}),
    ] {
        assert_error(
            &post(&app, store, body).await,
            StatusCode::BAD_REQUEST,
            "invalid_request",
        );
    }
    assert_error(
        &post(&app, restore, json!({"what": "all", "source": "backup"})).await,
        StatusCode::BAD_REQUEST,
        "invalid_request",
    );
    assert_error(
        &post(
            &app,
            "/api/v1/buses/demo/nodes/2/store",
            json!({"what": "manufacturer"}),
        )
        .await,
        StatusCode::BAD_REQUEST,
        "invalid_value",
    );
    nmt(&app, 3, "start").await;
    let refused = post(&app, store, json!({"what": "all"})).await;
    assert_error(&refused, StatusCode::UNPROCESSABLE_ENTITY, "sdo_abort");
    assert_eq!(refused.1["error"]["abort_code"], "0x08000021");
}

/// A DCF's `ParameterValue`s by index and sub-index.
fn parameter_values(text: &str) -> BTreeMap<(u16, u8), String> {
    let dcf = Eds::parse(text, "x.dcf").unwrap();
    let mut values = BTreeMap::new();
    for object in dcf.dictionary.objects.values() {
        for sub in object.subs.values() {
            if let Some(value) = &sub.parameter_value {
                values.insert((object.index, sub.sub_index), value.clone());
            }
        }
    }
    values
}

async fn backup(app: &Router, node: u8) -> String {
    let uri = format!("/api/v1/buses/demo/nodes/{node}/config.dcf");
    let (status, text, content_type) = raw_call(app, Method::GET, &uri, "", None).await;
    assert_eq!(status, StatusCode::OK, "{text}");
    assert!(content_type.unwrap().starts_with("text/plain"));
    text
}

async fn restore_dcf(app: &Router, node: u8, text: &str) -> (StatusCode, Json) {
    let uri = format!("/api/v1/buses/demo/nodes/{node}/config.dcf");
    let (status, body, _) =
        raw_call(app, Method::PUT, &uri, "text/plain", Some(text.to_string())).await;
    (status, serde_json::from_str(&body).unwrap())
}

#[tokio::test(start_paused = true)]
async fn a_dcf_backup_of_a_umc_restored_onto_a_second_umc_gives_identical_parameters() {
    let (app, state) = demo().await;
    // Node 1 configured away from its defaults: heartbeat, a TPDO's event
    // timer and mapping, profile and manufacturer parameters.
    write(&app, 1, "0x1017", 0, json!(250)).await;
    write(&app, 1, "0x1800", 5, json!(40)).await;
    write(&app, 1, "0x6083", 0, json!(12345)).await;
    write(&app, 1, "0x2041", 1, json!(1200)).await;
    // TPDO2 re-mapped (CiA 301: invalid, count 0, entry, count, valid):
    // the restore has to run the same procedure on node 4.
    write(&app, 1, "0x1801", 1, json!(0x8000_0281u32)).await;
    write(&app, 1, "0x1A01", 0, json!(0)).await;
    write(&app, 1, "0x1A01", 2, json!(0x6064_0020u32)).await;
    write(&app, 1, "0x1A01", 0, json!(2)).await;
    write(&app, 1, "0x1801", 1, json!(0x281)).await;
    let dcf = backup(&app, 1).await;
    assert!(dcf.contains("[DeviceComissioning]"), "{dcf}");
    assert!(dcf.contains("NodeID=1"), "{dcf}");
    let values = parameter_values(&dcf);
    assert_eq!(values[&(0x1017, 0)], "250");
    assert_eq!(values[&(0x6083, 0)], "12345");
    // Node-relative COB-IDs stay node-relative.
    assert!(
        values[&(0x1800, 1)].to_uppercase().contains("$NODEID"),
        "{values:?}"
    );
    assert!(!values.contains_key(&(0x1010, 1)));
    assert!(!values.contains_key(&(0x6040, 0)));

    let served = &state.gateway.bus("demo").unwrap();
    served
        .rack()
        .unwrap()
        .add(Product::Umc1bds32, NodeId::new(4).unwrap())
        .unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    served.settle().await;
    // Node 4 is known and answers.
    assert!(read(&app, 4, "0x1000", 0).await.is_number());
    assert_ne!(read(&app, 4, "0x6083", 0).await, 12345);

    // What the gateway decodes of node 4's TPDO2: the factory mapping.
    let tpdo2 = |state: &AppState| {
        let tpdos = state
            .gateway
            .bus("demo")
            .unwrap()
            .values()
            .tpdos(NodeId::new(4).unwrap());
        tpdos.and_then(|tpdos| {
            let (_, decoder) = tpdos.decoders.into_iter().find(|(n, _)| *n == 2)?;
            Some(
                decoder
                    .mapping()
                    .entries()
                    .iter()
                    .map(|entry| (entry.index, entry.sub))
                    .collect::<Vec<_>>(),
            )
        })
    };
    assert_ne!(tpdo2(&state), Some(vec![(0x6041, 0), (0x6064, 0)]));
    let (status, report) = restore_dcf(&app, 4, &dcf).await;
    assert_eq!(status, StatusCode::OK, "{report}");
    let failures: Vec<&Json> = report["entries"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|entry| entry["ok"] != true)
        .collect();
    assert!(failures.is_empty(), "{failures:?}");
    assert_eq!(report["failed"], 0);
    assert_eq!(report["written"].as_u64().unwrap() as usize, values.len());

    let restored = backup(&app, 4).await;
    assert!(restored.contains("NodeID=4"));
    assert_eq!(parameter_values(&restored), values);
    assert_eq!(read(&app, 4, "0x6083", 0).await, 12345);
    assert_eq!(read(&app, 4, "0x1800", 1).await, json!(0x184));
    assert_eq!(read(&app, 4, "0x1800", 5).await, 40);
    assert_eq!(read(&app, 4, "0x1801", 1).await, json!(0x284));
    assert_eq!(read(&app, 4, "0x1A01", 2).await, json!(0x6064_0020u32));
    assert_eq!(read(&app, 4, "0x2041", 1).await, 1200);
    assert_eq!(read(&app, 4, "0x2040", 1).await, 4);
    // And the gateway decodes node 4's TPDO2 by the mapping restored.
    assert_eq!(tpdo2(&state), Some(vec![(0x6041, 0), (0x6064, 0)]));
}

#[tokio::test(start_paused = true)]
async fn a_malformed_or_foreign_dcf_is_refused_and_nothing_written() {
    let (app, state) = demo().await;
    let dcf = backup(&app, 1).await;
    let mut frames = state.gateway.bus("demo").unwrap().monitor();
    let umc_downloads = |frames: &mut crate::can::FrameReceiver| {
        let mut count = 0;
        while let Ok(Some(frame)) = frames.try_recv() {
            let data = frame.frame.data().to_vec();
            if frame.frame.id() == CanId::Standard(0x601)
                && data.first().is_some_and(|b| b >> 5 == 1)
            {
                count += 1;
            }
        }
        count
    };

    // A value that is no number of its type, on a line of its own.
    let broken = dcf.replacen("ParameterValue=250", "ParameterValue=fast", 1);
    let broken = if broken == dcf {
        dcf.replacen("ParameterValue=", "ParameterValue=fast", 1)
    } else {
        broken
    };
    let (status, body) = restore_dcf(&app, 1, &broken).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert_eq!(body["error"]["code"], "invalid_dcf");
    let line = body["error"]["line"].as_u64().unwrap() as usize;
    assert!(
        broken.lines().nth(line - 1).unwrap().contains("=fast"),
        "line {line}: {body}"
    );

    let junk = "[1017]\nParameterName=Heartbeat\nDataType=0x0006\nAccessType=rw\njunk\n";
    let (status, body) = restore_dcf(&app, 1, junk).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert_eq!(body["error"]["line"], 5);

    // The UIO1LED's configuration is not the UMC's.
    let led = backup(&app, 3).await;
    let (status, body) = restore_dcf(&app, 1, &led).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert_eq!(body["error"]["code"], "invalid_dcf");
    assert_eq!(umc_downloads(&mut frames), 0);
}
