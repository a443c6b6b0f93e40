//! The logger's rows: bounded memory, the CSV both ways, what the topic
//! publishes, and loggers kept in a directory loaded again.

use super::*;

fn status(channels: usize) -> LoggerStatus {
    LoggerStatus {
        id: 3,
        state: LoggerState::Running,
        period_ms: 10,
        duration_s: 1,
        started_ms: 0,
        samples: 0,
        missed: 0,
        dropped: 0,
        rows: 0,
        persisted: false,
        channels: (0..channels)
            .map(|n| ChannelInfo {
                bus: "demo".into(),
                node: 1,
                index: "0x6064".into(),
                sub: 0,
                name: format!("demo/1/channel {n}"),
                data_type: Some("i32".into()),
                unit: None,
                source: None,
                sdo_samples: 0,
                tpdo_samples: 0,
                errors: 0,
                last_error: None,
            })
            .collect(),
    }
}

fn logger(channels: usize, max_rows: usize) -> Logger {
    Logger {
        status: status(channels),
        rows: VecDeque::new(),
        max_rows,
        topic: ValueTopic::new(),
    }
}

#[test]
fn a_logger_keeps_its_newest_rows_and_counts_what_it_dropped() {
    let mut logger = logger(2, 3);
    for n in 0..5u64 {
        let failed = (
            Err("node 1 did not answer in time".to_string()),
            Source::Sdo,
        );
        let second = if n == 2 {
            failed
        } else {
            (Ok(-(n as f64)), Source::Tpdo)
        };
        logger.push(n * 10, vec![(Ok(n as f64), Source::Sdo), second], 1);
    }
    assert_eq!(logger.status.samples, 5);
    assert_eq!(logger.status.dropped, 2);
    assert_eq!(logger.status.missed, 5);
    assert_eq!(logger.status.rows, 3);
    let times: Vec<u64> = logger.rows.iter().map(|row| row.time_ms).collect();
    assert_eq!(times, [20, 30, 40]);
    let [first, second] = &logger.status.channels[..] else {
        panic!()
    };
    assert_eq!((first.sdo_samples, first.source), (5, Some(Source::Sdo)));
    assert_eq!((second.tpdo_samples, second.errors), (4, 1));
    assert_eq!(
        second.last_error.as_deref(),
        Some("node 1 did not answer in time")
    );
    assert_eq!(logger.rows[0].values, [Some(2.0), None]);
}

#[test]
fn the_csv_has_a_header_and_a_row_per_sample_and_reads_back() {
    let mut logger = logger(2, 10);
    // Started 0.995 s into a second: the second row's absolute time is in
    // the next one.
    logger.status.started_ms = 1_795_000_000_995;
    logger.status.channels[0].unit = Some("increments".into());
    logger.status.channels[1].name = "demo/1/a \"quoted\", name".into();
    logger.push(0, vec![(Ok(1.5), Source::Sdo), (Ok(-7.0), Source::Sdo)], 0);
    logger.push(
        10,
        vec![(Ok(2.0), Source::Sdo), (Err("x".into()), Source::Sdo)],
        0,
    );
    let text = to_csv(&logger.status, logger.rows.iter());
    assert_eq!(
        text,
        "time_ms,time_utc,demo/1/channel 0 [increments],\"demo/1/a \"\"quoted\"\", name\"\n\
         0,2026-11-18T11:06:40.995Z,1.5,-7\n\
         10,2026-11-18T11:06:41.005Z,2,\n"
    );
    let rows = from_csv(&text.replace("\"demo/1/a \"\"quoted\"\", name\"", "b"), 2).unwrap();
    assert_eq!(rows, logger.rows.iter().cloned().collect::<Vec<_>>());
    // A file kept before the time_utc column reads back too.
    let kept = from_csv("time_ms,a,b\n0,1.5,-7\n10,2,\n", 2).unwrap();
    assert_eq!(kept, rows);
    assert!(from_csv("time_ms,a\n0,1,2\n", 1).is_err());
    assert!(from_csv("time_ms,a\n0,x\n", 1).is_err());
    assert!(from_csv("time_ms,time_utc,a\n0\n", 1).is_err());
}

#[test]
fn absolute_times_are_iso_8601_utc_to_the_millisecond() {
    assert_eq!(iso8601_ms(0), "1970-01-01T00:00:00.000Z");
    assert_eq!(iso8601_ms(951_782_400_007), "2000-02-29T00:00:00.007Z");
    assert_eq!(iso8601_ms(1_798_761_599_999), "2026-12-31T23:59:59.999Z");
}

#[test]
fn a_drive_s_positions_velocities_and_torques_have_their_manual_s_units() {
    let umc = DriveKind::Umc.units();
    assert_eq!(drive_unit(&umc, 0x6064, 2).as_deref(), Some("increments"));
    // Axis 2's actual velocity, 0x800 on.
    assert_eq!(
        drive_unit(&umc, 0x686C, 2).as_deref(),
        Some("increments/ms")
    );
    // Beyond the drive's axes, or no quantity: none.
    assert_eq!(drive_unit(&umc, 0x7064, 2), None);
    assert_eq!(drive_unit(&umc, 0x6041, 2), None);
    assert_eq!(drive_unit(&umc, 0x2000, 2), None);
    let jmc = DriveKind::Jmc.units();
    assert_eq!(drive_unit(&jmc, 0x6064, 1).as_deref(), Some("steps"));
    assert_eq!(drive_unit(&jmc, 0x6081, 1).as_deref(), Some("0.1 rps"));
    assert_eq!(drive_unit(&jmc, 0x6864, 1), None);
    assert_eq!(drive_unit(&jmc, 0x6042, 1), None);
}

#[test]
fn the_topic_gives_the_rows_since_the_last_publish_even_after_drops() {
    let mut logger = logger(1, 4);
    for n in 0..3u64 {
        logger.push(n, vec![(Ok(n as f64), Source::Sdo)], 0);
    }
    assert_eq!(logger.publish(0), 3);
    let first = logger.topic.latest().unwrap();
    assert_eq!(first.data["first"], 0);
    assert_eq!(first.data["rows"], json!([[0, 0.0], [1, 1.0], [2, 2.0]]));
    for n in 3..9u64 {
        logger.push(n, vec![(Ok(n as f64), Source::Sdo)], 0);
    }
    // Rows 3 and 4 were dropped before they were published: the topic
    // says where it starts again.
    assert_eq!(logger.publish(3), 9);
    let second = logger.topic.latest().unwrap();
    assert_eq!(second.data["first"], 5);
    assert_eq!(second.data["rows"].as_array().unwrap().len(), 4);
}

#[tokio::test]
async fn kept_loggers_are_loaded_again_as_finished() {
    let path = std::env::temp_dir().join(format!("candeck-logger-kept-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&path);
    let dir = Scratch(path);
    let mut logger = logger(1, 10);
    logger.push(0, vec![(Ok(4.0), Source::Sdo)], 0);
    logger.push(10, vec![(Ok(5.0), Source::Sdo)], 0);
    // Killed while it ran: it comes back stopped.
    keep(
        dir.0.as_path(),
        &logger.status,
        &to_csv(&logger.status, logger.rows.iter()),
    )
    .unwrap();
    std::fs::write(dir.0.as_path().join("logger-9.json"), "not json").unwrap();
    let config = LoggerConfig {
        max_values: 1000,
        dir: Some(dir.0.as_path().to_path_buf()),
    };
    let loggers = Loggers::load(config);
    let list = loggers.list();
    assert_eq!(list.len(), 1, "{list:?}");
    assert_eq!(list[0].id, 3);
    assert_eq!(list[0].state, LoggerState::Stopped);
    assert_eq!(
        loggers.csv("3").unwrap(),
        "time_ms,time_utc,demo/1/channel 0\n0,1970-01-01T00:00:00.000Z,4\n10,1970-01-01T00:00:00.010Z,5\n"
    );
    assert!(loggers.subscribe("3", 1.0).is_ok());
    // A new one follows the kept ones' ids; deleting a kept one removes
    // its files.
    assert_eq!(lock(&loggers.state).next_id, 4);
    loggers.delete("3").unwrap();
    assert!(!dir.0.as_path().join("logger-3.csv").exists());
    assert!(!dir.0.as_path().join("logger-3.json").exists());
    assert!(matches!(loggers.status("3"), Err(LoggerError::Unknown(_))));
}

/// A directory removed at the end of the test.
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The operations of the gateway: started and deleted by an operator, one
/// write of the caller's rate and one audit row each.
mod operations {
    use super::*;
    use crate::caller::Channel;
    use crate::eds_files::tests::{caller, guarded_demo, row, rows_when};

    fn position() -> LoggerRequest {
        LoggerRequest {
            channels: vec![ChannelRequest {
                bus: "demo".into(),
                node: 1,
                index: json!("0x6064"),
                sub: None,
            }],
            period_ms: 100,
            duration_s: 60,
        }
    }

    #[tokio::test(start_paused = true)]
    async fn loggers_are_an_operators_and_each_request_is_one_row() {
        let gateway = guarded_demo(100).await;
        let hmi = caller(Channel::Cia309_5, "hmi");
        let refused = gateway.start_logger(&hmi, position()).await.unwrap_err();
        assert_eq!(refused.code(), "forbidden", "{refused}");
        assert!(gateway.loggers().list().is_empty(), "a refused logger runs");

        let plc = caller(Channel::Rest, "plc");
        let started = gateway.start_logger(&plc, position()).await.unwrap();
        assert_eq!(started.state, LoggerState::Running);
        let id = started.id.to_string();
        let refused = gateway.delete_logger(&hmi, &id).await.unwrap_err();
        assert_eq!(refused.code(), "forbidden", "{refused}");
        assert_eq!(gateway.loggers().list().len(), 1);
        let last = gateway.delete_logger(&plc, &id).await.unwrap();
        assert_eq!(last.state, LoggerState::Stopped);
        let gone = gateway.delete_logger(&plc, &id).await.unwrap_err();
        assert_eq!(gone.code(), "unknown_logger", "{gone}");
        let bad = LoggerRequest {
            period_ms: 0,
            ..position()
        };
        let refused = gateway.start_logger(&plc, bad).await.unwrap_err();
        assert_eq!(refused.code(), "value_out_of_range", "{refused}");

        let want = [
            row("start data logger", "", "", "", "forbidden"),
            row("start data logger", "", "", "", "ok"),
            row("delete data logger", "", "", &id, "forbidden"),
            row("delete data logger", "", "", &id, "ok"),
            row("delete data logger", "", "", &id, "unknown_logger"),
            row("start data logger", "", "", "", "value_out_of_range"),
        ];
        assert_eq!(rows_when(&gateway, want.len()).await, want);
    }

    #[tokio::test(start_paused = true)]
    async fn a_flood_of_logger_requests_is_refused_for_the_rate() {
        let gateway = guarded_demo(2).await;
        let plc = caller(Channel::Rest, "plc");
        let started = gateway.start_logger(&plc, position()).await.unwrap();
        gateway
            .delete_logger(&plc, &started.id.to_string())
            .await
            .unwrap();
        let flood = gateway.start_logger(&plc, position()).await.unwrap_err();
        assert_eq!(flood.code(), "rate_limited", "{flood}");
        assert!(gateway.loggers().list().is_empty(), "a refused logger runs");
        assert_eq!(
            rows_when(&gateway, 3).await[2],
            row("start data logger", "", "", "", "rate_limited")
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_logger_starts_for_a_caller_that_went_away() {
        let gateway = guarded_demo(100).await;
        let plc = caller(Channel::Rest, "plc");
        // Polled once, then dropped: the caller is gone.
        let dropped =
            tokio::time::timeout(Duration::ZERO, gateway.start_logger(&plc, position())).await;
        assert!(dropped.is_err(), "it ended within its first poll");
        assert_eq!(
            rows_when(&gateway, 1).await,
            [row("start data logger", "", "", "", "ok")]
        );
        let list = gateway.loggers().list();
        assert_eq!(list.len(), 1);
        assert_eq!(list[0].state, LoggerState::Running);
    }
}
