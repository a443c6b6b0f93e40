//! The store alone: schema, reopening, queries, retention.

use super::*;
use crate::access::Role;

fn entry(time_us: u64, path: &str) -> AuditEntry {
    AuditEntry::new(
        &Caller::new(Channel::Rest, "anonymous", None),
        "write object",
    )
    .at(Timestamp::from_micros(time_us))
    .detail("PUT", path)
    .http_status(200)
}

fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("candeck-history-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

async fn paths(history: &History, query: Query) -> Vec<String> {
    history
        .query(query)
        .await
        .unwrap()
        .into_iter()
        .map(|event| event.fields["path"].as_str().unwrap().to_string())
        .collect()
}

#[tokio::test]
async fn a_file_is_wal_at_the_current_schema_and_keeps_entries_when_reopened() {
    let dir = temp_dir("reopen");
    let history = History::open(&dir).unwrap();
    history.audit(entry(1_000, "/a")).await.unwrap();
    drop(history);
    let history = History::open(&dir).unwrap();
    history.audit(entry(2_000, "/b")).await.unwrap();
    {
        let conn = history.conn.lock().unwrap();
        let mode: String = conn
            .query_row("PRAGMA journal_mode", [], |row| row.get(0))
            .unwrap();
        assert_eq!(mode, "wal");
        let sync: i64 = conn
            .query_row("PRAGMA synchronous", [], |row| row.get(0))
            .unwrap();
        assert_eq!(sync, 2, "FULL");
        let version: i64 = conn
            .query_row("SELECT version FROM schema_version", [], |row| row.get(0))
            .unwrap();
        assert_eq!(version, MIGRATIONS.len() as i64);
        let rows: i64 = conn
            .query_row("SELECT count(*) FROM schema_version", [], |row| row.get(0))
            .unwrap();
        assert_eq!(rows, 1);
    }
    let all = paths(
        &history,
        Query {
            kind: None,
            since_us: None,
            until_us: None,
            channel: None,
            limit: 10,
        },
    )
    .await;
    assert_eq!(all, ["/a", "/b"]);
    drop(history);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test]
async fn a_newer_schema_is_refused() {
    let dir = temp_dir("newer");
    drop(History::open(&dir).unwrap());
    let conn = Connection::open(dir.join(FILE_NAME)).unwrap();
    conn.execute("UPDATE schema_version SET version = 99", [])
        .unwrap();
    drop(conn);
    let err = History::open(&dir).unwrap_err();
    assert!(matches!(err, HistoryError::TooNew(99, _)), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test]
async fn queries_are_oldest_first_from_since_or_the_newest_without() {
    let history = History::in_memory().unwrap();
    for (at, path) in [(30, "/c"), (10, "/a"), (20, "/b"), (40, "/d")] {
        history.audit(entry(at, path)).await.unwrap();
    }
    let newest = paths(
        &history,
        Query {
            kind: Some(EventKind::Audit),
            since_us: None,
            until_us: None,
            channel: None,
            limit: 2,
        },
    )
    .await;
    assert_eq!(newest, ["/c", "/d"]);
    let from = paths(
        &history,
        Query {
            kind: None,
            since_us: Some(20),
            until_us: None,
            channel: None,
            limit: 2,
        },
    )
    .await;
    assert_eq!(from, ["/b", "/c"]);
    let none = paths(
        &history,
        Query {
            kind: Some(EventKind::Emcy),
            since_us: None,
            until_us: None,
            channel: None,
            limit: 10,
        },
    )
    .await;
    assert!(none.is_empty());
    // Paging back: the newest up to a time, and a range.
    let older = paths(
        &history,
        Query {
            kind: None,
            since_us: None,
            until_us: Some(30),
            channel: None,
            limit: 2,
        },
    )
    .await;
    assert_eq!(older, ["/b", "/c"]);
    let range = paths(
        &history,
        Query {
            kind: Some(EventKind::Audit),
            since_us: Some(15),
            until_us: Some(35),
            channel: None,
            limit: 10,
        },
    )
    .await;
    assert_eq!(range, ["/b", "/c"]);
}

#[tokio::test]
async fn retention_prunes_by_age_and_by_count() {
    let history = History::in_memory().unwrap();
    let day = 86_400_000_000u64;
    let now = 100 * day;
    for (at, path) in [
        (now - 40 * day, "/old"),
        (now - 20 * day, "/b"),
        (now - 10 * day, "/c"),
        (now - day, "/d"),
    ] {
        history.audit(entry(at, path)).await.unwrap();
    }
    let keep_all = Retention {
        days: None,
        rows: None,
    };
    assert_eq!(
        history
            .prune(keep_all, Timestamp::from_micros(now))
            .await
            .unwrap(),
        0
    );
    let by_age = Retention {
        days: Some(30),
        rows: None,
    };
    assert_eq!(
        history
            .prune(by_age, Timestamp::from_micros(now))
            .await
            .unwrap(),
        1
    );
    let all = Query {
        kind: None,
        since_us: None,
        until_us: None,
        channel: None,
        limit: 10,
    };
    assert_eq!(paths(&history, all).await, ["/b", "/c", "/d"]);
    let by_rows = Retention {
        days: Some(30),
        rows: Some(2),
    };
    assert_eq!(
        history
            .prune(by_rows, Timestamp::from_micros(now))
            .await
            .unwrap(),
        1
    );
    assert_eq!(paths(&history, all).await, ["/c", "/d"]);
    // Idempotent.
    assert_eq!(
        history
            .prune(by_rows, Timestamp::from_micros(now))
            .await
            .unwrap(),
        0
    );
}

#[tokio::test(start_paused = true)]
async fn the_pruner_prunes_at_start_and_then_periodically() {
    let history = History::in_memory().unwrap();
    let day = 86_400_000_000u64;
    let now = Timestamp::now().as_micros();
    history.audit(entry(now - 3 * day, "/old")).await.unwrap();
    history.audit(entry(now, "/new")).await.unwrap();
    let pruner = history.spawn_pruner(Retention {
        days: Some(2),
        rows: None,
    });
    let all = Query {
        kind: None,
        since_us: None,
        until_us: None,
        channel: None,
        limit: 10,
    };
    let mut left = Vec::new();
    for _ in 0..100 {
        left = paths(&history, all).await;
        if left.len() == 1 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert_eq!(left, ["/new"]);
    // An entry that ages past the limit goes at the next period.
    history.audit(entry(now - 3 * day, "/late")).await.unwrap();
    assert_eq!(paths(&history, all).await, ["/late", "/new"]);
    tokio::time::sleep(PRUNE_PERIOD + Duration::from_secs(1)).await;
    let mut left = Vec::new();
    for _ in 0..100 {
        left = paths(&history, all).await;
        if left.len() == 1 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert_eq!(left, ["/new"]);
    pruner.abort();
}

/// A copy of the database schema version 1 wrote (`tests/data/history`),
/// in a directory of its own: the fixture itself is never opened.
fn v1_copy(name: &str) -> std::path::PathBuf {
    let fixture = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/data/history/v1.sqlite3"
    );
    let dir = temp_dir(name);
    std::fs::copy(fixture, dir.join(FILE_NAME)).unwrap();
    dir
}

fn all_of(kind: EventKind) -> Query {
    Query {
        kind: Some(kind),
        since_us: None,
        until_us: None,
        channel: None,
        limit: 100,
    }
}

fn schema_version(history: &History) -> i64 {
    let conn = history.conn.lock().unwrap();
    conn.query_row("SELECT version FROM schema_version", [], |row| row.get(0))
        .unwrap()
}

fn text<'a>(event: &'a StoredEvent, name: &str) -> Option<&'a str> {
    event.fields.get(name).and_then(serde_json::Value::as_str)
}

#[tokio::test]
async fn the_v1_fixture_migrates() {
    let dir = v1_copy("v1");
    let history = History::open(&dir).unwrap();
    assert_eq!(schema_version(&history), MIGRATIONS.len() as i64);
    let audit = history.query(all_of(EventKind::Audit)).await.unwrap();
    // id: channel, outcome, abort code, and the detail kept.
    type Row = (
        i64,
        &'static str,
        &'static str,
        Option<&'static str>,
        &'static str,
        i64,
    );
    let expected: &[Row] = &[
        (1, "rest", "sdo_abort", Some("0x06010002"), "PUT", 422),
        (2, "rest", "forbidden", None, "POST", 403),
        (3, "rest", "ok", None, "PUT", 200),
        (4, "rest", "rate_limited", None, "PUT", 429),
        (5, "cia309_3", "ok", None, "ASCII", 200),
        (6, "cia309_3", "forbidden", None, "ASCII", 403),
        (7, "cia309_5", "sdo_abort", Some("0x06090030"), "PUT", 422),
        (8, "sparkplug", "ok", None, "DCMD", 200),
        (9, "sparkplug", "lease_conflict", None, "DCMD", 409),
        (10, "websocket", "ok", None, "WS", 200),
        (11, "websocket", "unknown_lease", None, "WS", 404),
        // The lease supervisor's halt had a REST path: its `gateway`
        // caller makes it the system's.
        (12, "system", "ok", None, "POST", 200),
        (13, "system", "sdo_timeout", None, "POST", 504),
        (14, "system", "ok", None, "DELETE", 200),
        (15, "system", "boot_failed", None, "NMT", 502),
        (16, "system", "ok", None, "NMT", 200),
    ];
    assert_eq!(audit.len(), expected.len());
    for (event, &(id, channel, outcome, abort, method, status)) in audit.iter().zip(expected) {
        assert_eq!(event.id, id);
        assert_eq!(text(event, "channel"), Some(channel), "{event:?}");
        assert_eq!(text(event, "outcome"), Some(outcome), "{event:?}");
        assert_eq!(text(event, "abort_code"), abort, "{event:?}");
        assert_eq!(text(event, "method"), Some(method), "{event:?}");
        assert_eq!(event.fields["status"], status, "{event:?}");
        assert!(!event.fields.contains_key("error_code"), "{event:?}");
        // What the row said is kept.
        assert!(text(event, "who").is_some() && text(event, "operation").is_some());
    }
    assert_eq!(text(&audit[0], "item"), Some("0x6040:0"));
    assert_eq!(text(&audit[0], "request"), Some(r#"{"value":6}"#));
    assert_eq!(text(&audit[0], "peer"), Some("127.0.0.1:51234"));
    assert_eq!(text(&audit[0], "role"), Some("operator"));
    assert_eq!(audit[9].fields["axis"], 1);
    // EMCY and NMT rows are untouched.
    let emcy = history.query(all_of(EventKind::Emcy)).await.unwrap();
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].fields["code"], 0x4310);
    assert_eq!(text(&emcy[0], "manufacturer"), Some("0102030405"));
    let nmt = history.query(all_of(EventKind::Nmt)).await.unwrap();
    let events: Vec<&str> = nmt.iter().filter_map(|e| text(e, "event")).collect();
    assert_eq!(
        events,
        ["appeared", "nmt_changed", "heartbeat_written", "offline"]
    );
    // The channel filter reads the migrated rows.
    let sparkplug = history
        .query(Query {
            channel: Some(Channel::Sparkplug),
            ..all_of(EventKind::Audit)
        })
        .await
        .unwrap();
    assert_eq!(sparkplug.iter().map(|e| e.id).collect::<Vec<_>>(), [8, 9]);
    // New rows follow the old ones.
    let caller = Caller::new(Channel::Cia309_3, "ascii:127.0.0.1:40000", None);
    history
        .audit(
            AuditEntry::new(&caller, "write object")
                .target(Some("demo".into()), Some(5), None, Some("0x6040:0".into()))
                .outcome(&Ok::<(), GatewayError>(())),
        )
        .await
        .unwrap();
    drop(history);
    // Opening it again changes nothing.
    let history = History::open(&dir).unwrap();
    assert_eq!(schema_version(&history), MIGRATIONS.len() as i64);
    let again = history.query(all_of(EventKind::Audit)).await.unwrap();
    assert_eq!(again[..audit.len()], audit[..]);
    let new = &again[audit.len()];
    assert_eq!(new.id, 17);
    assert_eq!(text(new, "channel"), Some("cia309_3"));
    assert_eq!(text(new, "outcome"), Some("ok"));
    assert_eq!(text(new, "role"), Some("none"));
    assert!(!new.fields.contains_key("method") && !new.fields.contains_key("status"));
    drop(history);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_v1_failure_without_an_error_code_is_named_by_its_status() {
    let mut conn = Connection::open_in_memory().unwrap();
    conn.execute_batch(MIGRATIONS[0]).unwrap();
    conn.execute_batch(
        "CREATE TABLE schema_version (version INTEGER NOT NULL);
         INSERT INTO schema_version (version) VALUES (1);
         INSERT INTO audit (time_us, who, role, method, path, operation, status)
         VALUES (1, 'anonymous', 'none', 'PATCH', '/api/v1/buses', 'unknown request', 405);",
    )
    .unwrap();
    migrate(&mut conn).unwrap();
    let (channel, outcome): (String, String) = conn
        .query_row("SELECT channel, outcome FROM audit", [], |row| {
            Ok((row.get(0)?, row.get(1)?))
        })
        .unwrap();
    assert_eq!((channel.as_str(), outcome.as_str()), ("rest", "http_405"));
}

#[tokio::test]
async fn a_row_says_what_was_done_whichever_door_asked() {
    use crate::canopen::sdo::AbortCode;
    let history = History::in_memory().unwrap();
    let operator = Caller::new(Channel::Sparkplug, "mqtt:scada", Some(Role::Operator));
    let refused: Result<(), GatewayError> = Err(GatewayError::SdoAbort {
        node: 5,
        code: AbortCode::from_raw(0x0609_0030),
    });
    history
        .audit(
            AuditEntry::new(&operator, "write object")
                .target(Some("demo".into()), Some(5), None, Some("0x1017:0".into()))
                .request(Some("u16 1000".into()))
                .outcome(&refused),
        )
        .await
        .unwrap();
    history
        .audit(
            AuditEntry::new(&Caller::system(), "motion lease lapsed: axis halted").target(
                Some("demo".into()),
                Some(2),
                Some(1),
                None,
            ),
        )
        .await
        .unwrap();
    let rows = history.query(all_of(EventKind::Audit)).await.unwrap();
    let fields = |at: usize| serde_json::Value::Object(rows[at].fields.clone());
    assert_eq!(
        fields(0),
        serde_json::json!({
            "channel": "sparkplug",
            "who": "mqtt:scada",
            "role": "operator",
            "operation": "write object",
            "bus": "demo",
            "node": 5,
            "item": "0x1017:0",
            "request": "u16 1000",
            "outcome": "sdo_abort",
            "abort_code": "0x06090030",
        })
    );
    assert_eq!(
        fields(1),
        serde_json::json!({
            "channel": "system",
            "who": "gateway",
            "role": "system",
            "operation": "motion lease lapsed: axis halted",
            "bus": "demo",
            "node": 2,
            "axis": 1,
            "outcome": "ok",
        })
    );
    let system = history
        .query(Query {
            channel: Some(Channel::System),
            ..all_of(EventKind::Audit)
        })
        .await
        .unwrap();
    assert_eq!(system.len(), 1);
    // A channel belongs to audit rows: asked with another kind, none.
    let none = history
        .query(Query {
            channel: Some(Channel::System),
            ..all_of(EventKind::Emcy)
        })
        .await
        .unwrap();
    assert!(none.is_empty());
}

/// Alarms are written as they change and read back with their history;
/// retention prunes only those back to normal.
#[tokio::test]
async fn alarms_are_read_back_as_written_and_only_normal_ones_are_pruned() {
    use crate::alarms::{AlarmBook, AlarmSource, AlarmState};
    use crate::profiles::alarm::{AlarmKind, Product, describe};
    let history = History::in_memory().unwrap();
    let day = 86_400_000_000i64;
    let now = 100 * day;
    let mut book = AlarmBook::default();
    let old = AlarmSource::new("line", Some(1), Some(2), AlarmKind::Emcy(0x8611));
    let open = AlarmSource::new("line", None, None, AlarmKind::BusOff);
    let text = |kind| move || describe(Product::Umc, kind, Some(2), "Following error");
    let mut changes = Vec::new();
    changes.extend(book.raise(old.clone(), text(AlarmKind::Emcy(0x8611)), now - 40 * day));
    changes.extend(book.clear(&old, now - 40 * day + 1));
    let id = changes[0].alarm.id;
    changes.extend(
        book.acknowledge(id, "alice", Some("seen"), now - 40 * day + 2)
            .unwrap()
            .1,
    );
    changes.extend(book.raise(open.clone(), text(AlarmKind::BusOff), now - 40 * day));
    history.record_alarms(changes).await.unwrap();

    let stored = history.load_alarms().await.unwrap();
    assert_eq!(stored.len(), 2);
    let normal = stored.iter().find(|alarm| alarm.id == id).unwrap();
    assert_eq!(normal, book.get(id).unwrap(), "read back as written");
    assert_eq!(normal.state, AlarmState::Normal);
    assert_eq!(normal.history.len(), 3);
    assert_eq!(normal.history[2].who.as_deref(), Some("alice"));

    let by_age = Retention {
        days: Some(30),
        rows: None,
    };
    let deleted = history
        .prune(by_age, Timestamp::from_micros(now as u64))
        .await
        .unwrap();
    assert_eq!(deleted, 4, "the normal alarm and its three steps");
    let stored = history.load_alarms().await.unwrap();
    assert_eq!(stored.len(), 1, "an active alarm is kept however old");
    assert_eq!(stored[0].state, AlarmState::ActiveUnacknowledged);
}
