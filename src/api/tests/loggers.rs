//! `/loggers` through the router on the demo bus, on a paused clock (the
//! virtual devices tick on tokio's clock): a logger of a moving axis, its
//! CSV and statistics, TPDO and SDO sources, the errors of bad requests,
//! deletion, the audit, and the `loggers/{id}` topic.

use std::time::Duration;

use axum::Router;
use axum::http::{Method, StatusCode};
use serde_json::{Value as Json, json};

use crate::api::tests::support::{assert_error, call, delete_text, demo, get, post, put, raw_call};
use crate::can::CanId;

const LOGGERS: &str = "/api/v1/loggers";

fn channel(index: impl Into<Json>, sub: impl Into<Json>) -> Json {
    json!({"bus": "demo", "node": 1, "index": index.into(), "sub": sub.into()})
}

fn position_and_velocity(period_ms: u64, duration_s: u64) -> Json {
    json!({
        "channels": [channel("0x6064", 0), channel("0x606C", 0)],
        "period_ms": period_ms,
        "duration_s": duration_s,
    })
}

async fn enable_and_run(app: &Router) {
    let uri = "/api/v1/buses/demo/nodes/1/axes/1";
    let (status, answer) = post(
        app,
        &format!("{uri}/state"),
        json!({"target": "operation_enabled"}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{answer}");
    let (status, answer) = post(
        app,
        &format!("{uri}/move"),
        json!({"mode": "velocity", "velocity": 100}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{answer}");
    for _ in 0..100 {
        let (_, axis) = call(app, Method::GET, uri, None).await;
        if axis["velocity"].as_i64().unwrap_or(0) > 0 {
            return;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    panic!("axis 1 of node 1 never moved");
}

/// The CSV of logger `id`: its header, and its rows as numbers (`None`
/// for an empty cell), the absolute time (`time_utc`, the second column)
/// left out: [`absolute_times`] has it.
async fn csv(app: &Router, id: &Json) -> (Vec<String>, Vec<Vec<Option<f64>>>) {
    let (header, rows) = csv_cells(app, id).await;
    let rows = rows
        .into_iter()
        .map(|cells| {
            cells
                .iter()
                .enumerate()
                .filter(|(n, _)| *n != 1)
                .map(|(_, cell)| (!cell.is_empty()).then(|| cell.parse().unwrap()))
                .collect()
        })
        .collect();
    (header, rows)
}

/// The `time_utc` column of logger `id`'s CSV.
async fn absolute_times(app: &Router, id: &Json) -> Vec<String> {
    let (header, rows) = csv_cells(app, id).await;
    assert_eq!(header[1], "time_utc");
    rows.into_iter().map(|mut cells| cells.remove(1)).collect()
}

/// The CSV of logger `id` as text cells, header first.
async fn csv_cells(app: &Router, id: &Json) -> (Vec<String>, Vec<Vec<String>>) {
    let (status, text, content_type) = raw_call(
        app,
        Method::GET,
        &format!("{LOGGERS}/{id}/data.csv"),
        "",
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{text}");
    assert_eq!(content_type.as_deref(), Some("text/csv; charset=utf-8"));
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|line| line.split(',').map(str::to_string).collect())
        .collect();
    (header, rows)
}

#[tokio::test(start_paused = true)]
async fn a_logger_of_position_and_velocity_follows_a_move() {
    let (app, _) = demo().await;
    enable_and_run(&app).await;
    let (status, created) = post(&app, LOGGERS, position_and_velocity(10, 2)).await;
    assert_eq!(status, StatusCode::CREATED, "{created}");
    let id = created["id"].clone();
    assert_eq!(created["state"], "running", "{created}");
    assert_eq!(
        created["channels"][0]["name"], "demo/1/a1_pc_Position_actual_value",
        "{created}"
    );
    assert_eq!(created["channels"][0]["data_type"], "i32", "{created}");

    tokio::time::sleep(Duration::from_millis(2500)).await;
    let (status, done) = get(&app, &format!("{LOGGERS}/{id}")).await;
    assert_eq!(status, StatusCode::OK, "{done}");
    assert_eq!(done["state"], "done", "{done}");
    let samples = done["samples"].as_u64().unwrap();
    assert!(samples >= 150, "{done}");
    assert_eq!(
        samples + done["missed"].as_u64().unwrap(),
        200,
        "every grid point sampled or missed: {done}"
    );
    for channel in done["channels"].as_array().unwrap() {
        assert_eq!(channel["source"], "sdo", "{done}");
        assert_eq!(channel["sdo_samples"].as_u64(), Some(samples), "{done}");
        assert_eq!(channel["errors"], 0, "{done}");
    }

    let (header, rows) = csv(&app, &id).await;
    // The absolute time beside the relative one; each column's unit as
    // the UMC's manual gives it, in its header (what spreadsheets take as
    // the column's name).
    assert_eq!(
        header,
        [
            "time_ms",
            "time_utc",
            "demo/1/a1_pc_Position_actual_value [increments]",
            "demo/1/a1_pv_Velocity_actual_value [increments/ms]"
        ]
    );
    assert_eq!(done["channels"][0]["unit"], "increments", "{done}");
    // Each row's time_utc is the start plus its time_ms, ISO 8601 UTC to
    // the millisecond.
    let started_ms = done["started_ms"].as_i64().unwrap();
    let utc = absolute_times(&app, &id).await;
    assert_eq!(utc.len(), rows.len());
    for (row, utc) in rows.iter().zip(&utc) {
        let at_us = (started_ms + row[0].unwrap() as i64) * 1000;
        let micros = crate::api::events::rfc3339(at_us);
        // The µs text's last three digits are 0: cut to milliseconds.
        let expected = format!("{}Z", &micros[..micros.len() - 4]);
        assert_eq!(*utc, expected, "{row:?}");
    }
    assert_eq!(rows.len() as u64, samples);
    // On the 10 ms grid, in order.
    assert!(rows.windows(2).all(|pair| {
        let (a, b) = (pair[0][0].unwrap(), pair[1][0].unwrap());
        b > a && (b - a) % 10.0 == 0.0
    }));
    // The position rises with the move, the velocity is the move's.
    let positions: Vec<f64> = rows.iter().map(|row| row[1].unwrap()).collect();
    assert!(
        positions.windows(2).all(|pair| pair[1] >= pair[0]),
        "{positions:?}"
    );
    assert!(positions.last().unwrap() > positions.first().unwrap());
    assert!(rows.iter().all(|row| row[2].unwrap() > 0.0));
}

#[tokio::test(start_paused = true)]
async fn an_object_a_tpdo_carries_is_taken_from_it_without_sdo() {
    let (app, state) = demo().await;
    let (status, pdo) = put(
        &app,
        "/api/v1/buses/demo/nodes/1/pdos/tpdo/1",
        json!({"transmission_type": 255, "event_timer_ms": 10, "mapping": [
            {"index": "a1_Statusword"},
            {"index": "0x6064", "sub": 0},
        ]}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{pdo}");
    let (status, body) = post(
        &app,
        "/api/v1/buses/demo/nodes/1/nmt",
        json!({"command": "start"}),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    enable_and_run(&app).await;

    let mut monitor = state.gateway.bus("demo").unwrap().monitor();
    let (status, created) = post(
        &app,
        LOGGERS,
        json!({"channels": [channel("a1_pc_Position_actual_value", 0)], "period_ms": 10, "duration_s": 1}),
    )
    .await;
    assert_eq!(status, StatusCode::CREATED, "{created}");
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let (_, done) = get(&app, &format!("{LOGGERS}/{}", created["id"])).await;
    assert_eq!(done["state"], "done", "{done}");
    let position = &done["channels"][0];
    assert_eq!(position["source"], "tpdo", "{done}");
    assert_eq!(position["sdo_samples"], 0, "{done}");
    assert_eq!(position["tpdo_samples"], done["samples"], "{done}");
    let mut sdo = 0;
    while let Ok(Some(frame)) = monitor.try_recv() {
        if frame.frame.id() == CanId::Standard(0x601) {
            sdo += 1;
        }
    }
    assert_eq!(sdo, 0, "the logger asked by SDO what a TPDO carries");
    let (_, rows) = csv(&app, &created["id"]).await;
    assert!(rows.len() >= 90, "{}", rows.len());
    let positions: Vec<f64> = rows.iter().map(|row| row[1].unwrap()).collect();
    assert!(positions.last().unwrap() > positions.first().unwrap());
}

#[tokio::test(start_paused = true)]
async fn every_bad_request_is_a_clear_error() {
    let (app, _) = demo().await;
    let many: Vec<Json> = (0..17).map(|_| channel("0x6064", 0)).collect();
    let cases = [
        (
            json!({"channels": many, "period_ms": 10, "duration_s": 1}),
            StatusCode::BAD_REQUEST,
            "too_many_entries",
        ),
        (
            json!({"channels": [], "period_ms": 10, "duration_s": 1}),
            StatusCode::BAD_REQUEST,
            "too_many_entries",
        ),
        (
            position_and_velocity(0, 1),
            StatusCode::BAD_REQUEST,
            "value_out_of_range",
        ),
        (
            position_and_velocity(60_001, 1),
            StatusCode::BAD_REQUEST,
            "value_out_of_range",
        ),
        (
            position_and_velocity(10, 0),
            StatusCode::BAD_REQUEST,
            "value_out_of_range",
        ),
        (
            position_and_velocity(10, 86_401),
            StatusCode::BAD_REQUEST,
            "value_out_of_range",
        ),
        (
            json!({"channels": [{"bus": "nowhere", "node": 1, "index": "0x6064"}], "period_ms": 10, "duration_s": 1}),
            StatusCode::NOT_FOUND,
            "unknown_bus",
        ),
        (
            json!({"channels": [{"bus": "demo", "node": 9, "index": "0x6064"}], "period_ms": 10, "duration_s": 1}),
            StatusCode::NOT_FOUND,
            "unknown_node",
        ),
        (
            json!({"channels": [channel("no_such_object", 0)], "period_ms": 10, "duration_s": 1}),
            StatusCode::NOT_FOUND,
            "unknown_object",
        ),
        (
            json!({"channels": [channel("0x6064", 9)], "period_ms": 10, "duration_s": 1}),
            StatusCode::NOT_FOUND,
            "unknown_sub_object",
        ),
        (
            json!({"channels": [channel(true, 0)], "period_ms": 10, "duration_s": 1}),
            StatusCode::BAD_REQUEST,
            "invalid_index",
        ),
        // Write-only: the key of the UMC's 0x2050.
        (
            json!({"channels": [channel("0x2050", 1)], "period_ms": 10, "duration_s": 1}),
            StatusCode::UNPROCESSABLE_ENTITY,
            "not_loggable",
        ),
        // A string: the manufacturer device name.
        (
            json!({"channels": [channel("0x1008", 0)], "period_ms": 10, "duration_s": 1}),
            StatusCode::UNPROCESSABLE_ENTITY,
            "not_loggable",
        ),
        (
            json!({"channels": [channel("0x6064", 0)], "period_ms": 10, "duration_s": 1, "x": 1}),
            StatusCode::BAD_REQUEST,
            "invalid_request",
        ),
    ];
    for (body, status, code) in cases {
        let response = post(&app, LOGGERS, body.clone()).await;
        assert_error(&response, status, code);
        assert!(
            response.1["error"]["message"]
                .as_str()
                .is_some_and(|m| m.len() > 10),
            "{body}: {}",
            response.1
        );
    }
    let (_, list) = get(&app, LOGGERS).await;
    assert_eq!(list, json!([]), "a refused logger was made");
    assert_error(
        &get(&app, &format!("{LOGGERS}/7")).await,
        StatusCode::NOT_FOUND,
        "unknown_logger",
    );
    assert_error(
        &get(&app, &format!("{LOGGERS}/x/data.csv")).await,
        StatusCode::NOT_FOUND,
        "unknown_logger",
    );
    assert_error(
        &delete_text(&app, &format!("{LOGGERS}/7"), None).await,
        StatusCode::NOT_FOUND,
        "unknown_logger",
    );
}

#[tokio::test(start_paused = true)]
async fn a_deleted_logger_stops_and_is_gone_and_both_are_audited() {
    let (app, _) = demo().await;
    let (status, created) = post(&app, LOGGERS, position_and_velocity(20, 60)).await;
    assert_eq!(status, StatusCode::CREATED, "{created}");
    let id = created["id"].clone();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let (_, list) = get(&app, LOGGERS).await;
    assert_eq!(list.as_array().unwrap().len(), 1, "{list}");
    assert_eq!(list[0]["state"], "running", "{list}");

    let (status, last) = delete_text(&app, &format!("{LOGGERS}/{id}"), None).await;
    assert_eq!(status, StatusCode::OK, "{last}");
    assert_eq!(last["state"], "stopped", "{last}");
    assert!(last["samples"].as_u64().unwrap() > 10, "{last}");
    assert_error(
        &get(&app, &format!("{LOGGERS}/{id}")).await,
        StatusCode::NOT_FOUND,
        "unknown_logger",
    );

    let (_, audit) = get(&app, "/api/v1/events?kind=audit").await;
    assert_eq!(audit[0]["operation"], "start data logger", "{audit}");
    assert_eq!(audit[0]["status"], 201, "{audit}");
    assert_eq!(audit[1]["operation"], "delete data logger", "{audit}");
    assert_eq!(audit[1]["item"], id.to_string(), "{audit}");
}

#[tokio::test(start_paused = true)]
async fn the_topic_carries_every_row_once_in_order() {
    let (app, state) = demo().await;
    let (status, created) = post(&app, LOGGERS, position_and_velocity(10, 1)).await;
    assert_eq!(status, StatusCode::CREATED, "{created}");
    let id = created["id"].to_string();
    let mut reader = state.gateway.loggers().subscribe(&id, 20.0).unwrap();
    let mut next = 0;
    let mut times = Vec::new();
    loop {
        let sample = tokio::time::timeout(Duration::from_secs(3), reader.changed())
            .await
            .expect("a sample")
            .unwrap();
        let data = &sample.data;
        let rows = data["rows"].as_array().unwrap();
        if !rows.is_empty() {
            assert_eq!(data["first"], next, "{data}");
            next += rows.len() as u64;
            times.extend(rows.iter().map(|row| row[0].as_u64().unwrap()));
            assert_eq!(rows[0].as_array().unwrap().len(), 3, "{data}");
        }
        if data["state"] == "done" {
            assert_eq!(data["samples"], next, "{data}");
            break;
        }
    }
    assert!(times.len() >= 75, "{}", times.len());
    assert!(times.windows(2).all(|pair| pair[1] > pair[0]), "{times:?}");
    assert!(state.gateway.loggers().subscribe("99", 1.0).is_err());
}

/// The document describes a channel's `source` as what it is: the schema
/// once shared the name `Source` with the restore's `factory|saved`.
#[tokio::test(start_paused = true)]
async fn the_document_gives_a_channels_source_as_sdo_or_tpdo() {
    let (_, state) = demo().await;
    let (_, doc) = crate::api::routers(state);
    let doc = serde_json::to_value(&doc).unwrap();
    let schemas = &doc["components"]["schemas"];
    let source = &schemas["LoggerChannel"]["properties"]["source"]["oneOf"][0]["$ref"];
    let name = source
        .as_str()
        .and_then(|path| path.strip_prefix("#/components/schemas/"))
        .unwrap_or_else(|| panic!("{source}"));
    assert_eq!(schemas[name]["enum"], json!(["sdo", "tpdo"]), "{name}");
    assert_eq!(schemas["Source"]["enum"], json!(["factory", "saved"]));
}
