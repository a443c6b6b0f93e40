//! The data logger of `candeck serve` over real HTTP: the issue's check, a
//! logger of node 1's position (0x6064) and velocity (0x606C) at 10 ms for
//! 2 s during a velocity move gives a CSV with a header and at least 150
//! rows whose values follow the move.

mod common;

use std::time::Duration;

use common::{enable_and_move, json, poll, request, start};

#[tokio::test]
async fn a_logger_of_position_and_velocity_follows_a_move() {
    // A lease long enough that the move outlasts the logger unrenewed.
    let (server, _) = start(&["--lease-ms", "60000"]);
    let address = server.address.clone();
    let axis = "/api/v1/buses/demo/nodes/1/axes/1";
    let (status, body) = poll(&address, "/api/v1/buses/demo/nodes/1/axes", |status, _| {
        status == 200
    })
    .await;
    assert_eq!(status, 200, "{body}");
    enable_and_move(&address, axis, r#"{"mode":"velocity","velocity":100}"#).await;
    poll(&address, axis, |_, s| {
        s["velocity"].as_i64().is_some_and(|v| v > 0)
    })
    .await;

    let (status, created) = json(
        &address,
        "POST",
        "/api/v1/loggers",
        Some(
            r#"{"channels":[{"bus":"demo","node":1,"index":"0x6064","sub":0},
                            {"bus":"demo","node":1,"index":"0x606C","sub":0}],
                "period_ms":10,"duration_s":2}"#,
        ),
    )
    .await;
    assert_eq!(status, 201, "{created}");
    let id = created["id"].as_u64().unwrap();
    let status_uri = format!("/api/v1/loggers/{id}");
    let (_, done) = poll(&address, &status_uri, |_, s| s["state"] == "done").await;
    assert_eq!(done["state"], "done", "{done}");

    let csv = request(
        &address,
        "GET",
        &format!("/api/v1/loggers/{id}/data.csv"),
        "",
        None,
        Duration::from_secs(10),
    )
    .await;
    assert_eq!(csv.status, 200, "{}", csv.body);
    assert!(
        csv.content_type.starts_with("text/csv"),
        "{}",
        csv.content_type
    );
    let mut lines = csv.body.lines();
    assert_eq!(
        lines.next(),
        Some(
            "time_ms,time_utc,demo/1/a1_pc_Position_actual_value [increments],demo/1/a1_pv_Velocity_actual_value [increments/ms]"
        )
    );
    // The numbers, the absolute time (the second column) left out.
    let rows: Vec<Vec<f64>> = lines
        .map(|line| {
            line.split(',')
                .enumerate()
                .filter(|(n, _)| *n != 1)
                .map(|(_, cell)| cell.parse().unwrap_or_else(|_| panic!("'{line}'")))
                .collect()
        })
        .collect();
    assert!(rows.len() >= 150, "{} rows: {done}", rows.len());
    assert_eq!(rows.len() as u64, done["samples"].as_u64().unwrap());
    // Time goes on, the position rises with the move, the velocity is the
    // move's.
    assert!(rows.windows(2).all(|pair| pair[1][0] > pair[0][0]));
    assert!(
        rows.windows(2).all(|pair| pair[1][1] >= pair[0][1]),
        "the position went back"
    );
    assert!(rows.last().unwrap()[1] > rows[0][1]);
    assert!(rows.iter().all(|row| row[2] > 0.0));
}
