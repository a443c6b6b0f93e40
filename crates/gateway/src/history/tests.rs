//! The store alone: schema, reopening, queries, retention.

use super::*;

fn entry(time_us: u64, path: &str) -> AuditEntry {
    AuditEntry {
        time: Timestamp::from_micros(time_us),
        who: "anonymous".into(),
        role: "none".into(),
        method: "PUT".into(),
        path: path.into(),
        operation: "write object".into(),
        status: 200,
        ..AuditEntry::default()
    }
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
