//! The persisted history of the gateway: the audit log of the operations
//! that change (or tried to change) a device or the gateway, and each bus's
//! EMCY (CiA 301 §7.2.7) and NMT/supervision events (CiA 301 §7.2.8), in
//! SQLite.
//!
//! An audit row says what was done, not which request did it: the door it
//! came through ([`Channel`]), who (name, role, peer), the operation in
//! words, its target (bus, node, axis, item), the request summarised, and
//! the outcome (`ok`, or the error's code as [`GatewayError::code`] names
//! it) with the SDO abort code. A door may add its own words for the
//! request (REST's method, path and status) as detail; the gateway's own
//! rows ([`Caller::system`]) have none.
//!
//! With a data directory the database is `DIR/history.sqlite3` in WAL mode
//! with `synchronous=FULL`: a commit returns once its WAL frame is on the
//! disk, so an audit entry written before its response survives a crash of
//! candeck *and* of the machine. `NORMAL` would only survive the former
//! (the WAL is synced at checkpoints): cheaper, but an audit log that loses
//! its last entries on a power cut is the one nobody can trust, and
//! state-changing requests are few (people and PLC scripts, not the bus).
//! Without a data directory the database lives in memory and is lost on exit.
//!
//! SQLite blocks, so every call runs in [`tokio::task::spawn_blocking`],
//! never on a runtime thread. One connection behind a mutex serialises the
//! writers, as SQLite would anyway. Events are written in batches (whatever
//! arrived while the last batch was written, one transaction).
//!
//! The schema carries its version in `schema_version`; `MIGRATIONS` is the
//! list of steps from an empty file, each applied once, in order. A file
//! written by a newer candeck (a higher version) is refused, never
//! touched.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rusqlite::{Connection, OptionalExtension, params};
use serde::Serialize;
use tokio::sync::broadcast;

use crate::access::Role;
use crate::caller::{Caller, Channel};
use crate::can::Timestamp;
use crate::error::GatewayError;
use crate::registry::NodeEvent;

/// The file under `--data-dir`.
pub(crate) const FILE_NAME: &str = "history.sqlite3";

/// Each step takes the schema from version `i` to `i + 1`.
const MIGRATIONS: &[&str] = &[
    // 1: the three tables, each ordered by time.
    "CREATE TABLE audit (
        id INTEGER PRIMARY KEY,
        time_us INTEGER NOT NULL,
        who TEXT NOT NULL,
        peer TEXT,
        role TEXT NOT NULL,
        method TEXT NOT NULL,
        path TEXT NOT NULL,
        operation TEXT NOT NULL,
        bus TEXT,
        node INTEGER,
        axis INTEGER,
        item TEXT,
        request TEXT,
        status INTEGER NOT NULL,
        error_code TEXT,
        abort_code TEXT
    );
    CREATE INDEX audit_time ON audit(time_us);
    CREATE TABLE emcy (
        id INTEGER PRIMARY KEY,
        time_us INTEGER NOT NULL,
        bus TEXT NOT NULL,
        node INTEGER NOT NULL,
        code INTEGER NOT NULL,
        text TEXT NOT NULL,
        register INTEGER NOT NULL,
        manufacturer TEXT NOT NULL
    );
    CREATE INDEX emcy_time ON emcy(time_us);
    CREATE TABLE nmt (
        id INTEGER PRIMARY KEY,
        time_us INTEGER NOT NULL,
        bus TEXT NOT NULL,
        node INTEGER,
        event TEXT NOT NULL,
        from_state TEXT,
        to_state TEXT,
        reason TEXT
    );
    CREATE INDEX nmt_time ON nmt(time_us);",
    // 2: audit rows name their channel and outcome; method, path and
    // status become a door's optional detail (SQLite cannot drop NOT NULL,
    // so the table is copied). Older rows get both from what they were:
    // the gateway's own rows (`gateway`, role `system`), the stream's
    // (`WS`), CiA 309-3's (`ASCII`), CiA 309-5's and Sparkplug's by their
    // path's or topic's shape, REST's the rest; a 2xx is `ok`, a failure
    // its error code (`http_<status>` when it had none). `error_code` is
    // the outcome of a failure now: it goes.
    "CREATE TABLE audit_v2 (
        id INTEGER PRIMARY KEY,
        time_us INTEGER NOT NULL,
        channel TEXT NOT NULL,
        who TEXT NOT NULL,
        peer TEXT,
        role TEXT NOT NULL,
        operation TEXT NOT NULL,
        bus TEXT,
        node INTEGER,
        axis INTEGER,
        item TEXT,
        request TEXT,
        outcome TEXT NOT NULL,
        abort_code TEXT,
        method TEXT,
        path TEXT,
        status INTEGER
    );
    INSERT INTO audit_v2 (id, time_us, channel, who, peer, role, operation, bus, node, axis,
        item, request, outcome, abort_code, method, path, status)
    SELECT id, time_us,
        CASE
            WHEN who = 'gateway' AND role = 'system' THEN 'system'
            WHEN method = 'WS' THEN 'websocket'
            WHEN method = 'ASCII' THEN 'cia309_3'
            WHEN path GLOB '/cia309-5/*' THEN 'cia309_5'
            WHEN path GLOB 'spBv1.0/*' THEN 'sparkplug'
            ELSE 'rest'
        END,
        who, peer, role, operation, bus, node, axis, item, request,
        CASE
            WHEN status BETWEEN 200 AND 299 THEN 'ok'
            WHEN error_code IS NOT NULL THEN error_code
            ELSE 'http_' || status
        END,
        abort_code, method, path, status
    FROM audit;
    DROP TABLE audit;
    ALTER TABLE audit_v2 RENAME TO audit;
    CREATE INDEX audit_time ON audit(time_us);
    CREATE INDEX audit_channel ON audit(channel, time_us);",
    // 3: the alarms (`crate::alarms`): each alarm as it is now, and each
    // step of its life.
    "CREATE TABLE alarm (
        id INTEGER PRIMARY KEY,
        bus TEXT NOT NULL,
        node INTEGER,
        axis INTEGER,
        kind TEXT NOT NULL,
        code INTEGER,
        severity TEXT NOT NULL,
        state TEXT NOT NULL,
        text TEXT NOT NULL,
        help TEXT NOT NULL,
        raised_us INTEGER NOT NULL,
        cleared_us INTEGER,
        acknowledged_by TEXT,
        acknowledged_at_us INTEGER,
        comment TEXT,
        count INTEGER NOT NULL
    );
    CREATE INDEX alarm_state ON alarm(state, raised_us);
    CREATE TABLE alarm_event (
        id INTEGER PRIMARY KEY,
        alarm INTEGER NOT NULL,
        time_us INTEGER NOT NULL,
        step TEXT NOT NULL,
        state TEXT NOT NULL,
        who TEXT,
        comment TEXT
    );
    CREATE INDEX alarm_event_alarm ON alarm_event(alarm, id);",
    // 4: an EMCY row names the axis it belongs to, where the product says
    // (the UMC: its first manufacturer byte); older rows have none.
    "ALTER TABLE emcy ADD COLUMN axis INTEGER;",
];

/// The outcome of an operation that succeeded.
pub const OK: &str = "ok";

/// Why the history failed: the database, not the request.
#[derive(Debug, thiserror::Error)]
pub enum HistoryError {
    #[error("history database: {0}")]
    Sqlite(#[from] rusqlite::Error),
    #[error("history database {path}: {source}")]
    Open {
        path: String,
        source: rusqlite::Error,
    },
    /// Its file could not be made private (0600).
    #[error("history database {path}: {source}")]
    File {
        path: String,
        source: std::io::Error,
    },
    /// The database was written by a newer candeck.
    #[error(
        "history database is at schema version {0}, newer than this candeck knows ({1}): \
         a newer candeck wrote it; run that one, or move the file away to start a new history"
    )]
    TooNew(i64, usize),
    #[error("history database: the worker stopped ({0})")]
    Worker(String),
}

/// How long the history keeps entries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Retention {
    /// Entries older than this many days go; `None` keeps them by age.
    pub days: Option<u32>,
    /// At most this many entries of each kind (audit, emcy, nmt), the
    /// newest; `None`: no limit by count.
    pub rows: Option<u64>,
}

impl Default for Retention {
    fn default() -> Self {
        Self {
            days: Some(DEFAULT_RETENTION_DAYS),
            rows: Some(DEFAULT_RETENTION_ROWS),
        }
    }
}

pub const DEFAULT_RETENTION_DAYS: u32 = 90;
pub const DEFAULT_RETENTION_ROWS: u64 = 1_000_000;
/// How often the history is pruned (and once at start).
pub(crate) const PRUNE_PERIOD: Duration = Duration::from_secs(600);

/// One audit entry: an operation that changed (or tried to change) a
/// device or the gateway, whichever door asked for it.
///
/// Built from its caller: `AuditEntry::new(&caller, "write object")
/// .target(bus, node, None, item).request(summary).outcome(&result)`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AuditEntry {
    pub time: Timestamp,
    /// The door it came through.
    pub channel: Channel,
    /// The token's name, `anonymous`, `mqtt:{user}`, `gateway`.
    pub who: String,
    /// The client's address, when the door knows it.
    pub peer: Option<String>,
    /// The caller's role, `none` without one, `system` for the gateway.
    pub role: String,
    /// What was done, in words (`write object`, `nmt command`).
    pub operation: String,
    pub bus: Option<String>,
    pub node: Option<u8>,
    pub axis: Option<u8>,
    /// The object (`0x6040:0`), PDO (`tpdo 1`), segment or fault named.
    pub item: Option<String>,
    /// The request, summarised (bounded, secrets masked).
    pub request: Option<String>,
    /// [`OK`], or the error's code (`sdo_abort`, `forbidden`).
    pub outcome: String,
    /// `0x06090030`, when the device refused.
    pub abort_code: Option<String>,
    /// The door's own words for the request, where it has them: REST's
    /// and CiA 309-5's HTTP method, CiA 309-3's `ASCII`, Sparkplug's
    /// message type (`DCMD`).
    pub method: Option<String>,
    /// The HTTP path, the CiA 309-3 command line, the Sparkplug topic.
    pub path: Option<String>,
    /// The HTTP status REST answered.
    pub status: Option<u16>,
}

impl AuditEntry {
    /// An entry of `caller`'s `operation`, now, succeeded until
    /// [`outcome`](Self::outcome) says otherwise.
    pub fn new(caller: &Caller, operation: impl Into<String>) -> Self {
        Self {
            time: Timestamp::now(),
            channel: caller.channel,
            who: caller.who.clone(),
            peer: caller.peer.clone(),
            role: role_name(caller).to_string(),
            operation: operation.into(),
            bus: None,
            node: None,
            axis: None,
            item: None,
            request: None,
            outcome: OK.to_string(),
            abort_code: None,
            method: None,
            path: None,
            status: None,
        }
    }

    /// At `time` rather than now (when the operation started).
    pub fn at(mut self, time: Timestamp) -> Self {
        self.time = time;
        self
    }

    /// What it acted on.
    pub fn target(
        mut self,
        bus: Option<String>,
        node: Option<u8>,
        axis: Option<u8>,
        item: Option<String>,
    ) -> Self {
        self.bus = bus;
        self.node = node;
        self.axis = axis;
        self.item = item;
        self
    }

    /// The request, summarised.
    pub fn request(mut self, summary: Option<String>) -> Self {
        self.request = summary;
        self
    }

    /// The outcome of `result`: `ok`, or the error's code and, for an SDO
    /// abort, its abort code.
    pub fn outcome<T>(self, result: &Result<T, GatewayError>) -> Self {
        match result {
            Ok(_) => Self {
                outcome: OK.to_string(),
                abort_code: None,
                ..self
            },
            Err(error) => self.error(error),
        }
    }

    /// The outcome of an operation that failed with `error`.
    pub fn error(self, error: &GatewayError) -> Self {
        let abort = error
            .abort_code()
            .map(|code| format!("0x{:08X}", code.raw()));
        self.failed(error.code(), abort)
    }

    /// The outcome named by its code (`ok`, `boot_failed`), for the
    /// outcomes that are no [`GatewayError`] (a door's own refusals, the
    /// network manager's events).
    pub fn failed(mut self, code: impl Into<String>, abort_code: Option<String>) -> Self {
        self.outcome = code.into();
        self.abort_code = abort_code;
        self
    }

    /// The door's own words for the request (method, path or topic).
    pub fn detail(mut self, method: impl Into<String>, path: impl Into<String>) -> Self {
        self.method = Some(method.into());
        self.path = Some(path.into());
        self
    }

    /// The HTTP status REST answered.
    pub fn http_status(mut self, status: u16) -> Self {
        self.status = Some(status);
        self
    }
}

/// How the audit log names a caller's role: the role, `system` for the
/// gateway itself, `none` without one.
fn role_name(caller: &Caller) -> &'static str {
    match (caller.role, caller.channel) {
        (Some(role), _) => Role::name(role),
        (None, Channel::System) => "system",
        (None, _) => "none",
    }
}

/// Which table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    Audit,
    Emcy,
    Nmt,
}

impl EventKind {
    pub const ALL: [Self; 3] = [Self::Audit, Self::Emcy, Self::Nmt];

    fn table(self) -> &'static str {
        match self {
            Self::Audit => "audit",
            Self::Emcy => "emcy",
            Self::Nmt => "nmt",
        }
    }
}

/// One entry read back: its kind, id (increasing within a kind), time, and
/// the fields of its kind as JSON (nulls left out).
#[derive(Debug, Clone, PartialEq)]
pub struct StoredEvent {
    pub kind: EventKind,
    pub id: i64,
    pub time_us: i64,
    pub fields: serde_json::Map<String, serde_json::Value>,
}

/// What [`History::query`] returns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Query {
    /// None: every kind.
    pub kind: Option<EventKind>,
    /// At or after this time (µs since the Unix epoch); `None`: the newest.
    pub since_us: Option<i64>,
    /// At or before this time (µs since the Unix epoch): with `since_us`
    /// it bounds the range; alone, the newest entries up to it, which is
    /// how a client pages back through older entries.
    pub until_us: Option<i64>,
    /// Only audit rows of this channel (no EMCY or NMT rows).
    pub channel: Option<Channel>,
    pub limit: usize,
}

/// The history store; clones share one database.
#[derive(Clone)]
pub struct History {
    conn: Arc<Mutex<Connection>>,
    /// The file, or `None` in memory.
    path: Option<Arc<str>>,
}

impl std::fmt::Debug for History {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("History").field("path", &self.path).finish()
    }
}

impl History {
    /// Opens (or creates) `DIR/history.sqlite3`, in WAL mode, migrated to
    /// the current schema. Blocking: call before serving, or in
    /// `spawn_blocking`.
    pub fn open(dir: &Path) -> Result<Self, HistoryError> {
        let path = dir.join(FILE_NAME);
        let open_error = |source| HistoryError::Open {
            path: path.display().to_string(),
            source,
        };
        // Only the gateway's user reads the audit log: the file is made
        // 0600 before SQLite opens it (its -wal and -shm take its mode),
        // and tightened if an older gateway made it 0644.
        let file_error = |path: &Path| {
            let path = path.display().to_string();
            move |source| HistoryError::File { path, source }
        };
        crate::files::private_file_options()
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(file_error(&path))?;
        for suffix in ["", "-wal", "-shm"] {
            let mut side = path.clone().into_os_string();
            side.push(suffix);
            let side = Path::new(&side);
            crate::files::tighten(side).map_err(file_error(side))?;
        }
        let conn = Connection::open(&path).map_err(open_error)?;
        // Another process (a backup, sqlite3 on the command line) may hold
        // the lock for a moment.
        conn.busy_timeout(Duration::from_secs(5))
            .map_err(open_error)?;
        let mode: String = conn
            .query_row("PRAGMA journal_mode=WAL", [], |row| row.get(0))
            .map_err(open_error)?;
        if !mode.eq_ignore_ascii_case("wal") {
            tracing::warn!("history: journal mode is {mode}, not WAL");
        }
        conn.pragma_update(None, "synchronous", "FULL")
            .map_err(open_error)?;
        Self::ready(conn, Some(path.display().to_string()))
    }

    /// A history in memory, lost when the process ends.
    pub fn in_memory() -> Result<Self, HistoryError> {
        Self::ready(Connection::open_in_memory()?, None)
    }

    fn ready(mut conn: Connection, path: Option<String>) -> Result<Self, HistoryError> {
        migrate(&mut conn)?;
        Ok(Self {
            conn: Arc::new(Mutex::new(conn)),
            path: path.map(Arc::from),
        })
    }

    /// The database file, `None` in memory.
    pub fn path(&self) -> Option<&str> {
        self.path.as_deref()
    }

    /// Runs `work` on the connection on a blocking thread.
    async fn with_conn<T, F>(&self, work: F) -> Result<T, HistoryError>
    where
        T: Send + 'static,
        F: FnOnce(&mut Connection) -> Result<T, HistoryError> + Send + 'static,
    {
        let conn = self.conn.clone();
        tokio::task::spawn_blocking(move || {
            // A panic while holding the lock leaves the connection usable:
            // SQLite rolls back an unfinished transaction.
            let mut conn = conn.lock().unwrap_or_else(|poison| poison.into_inner());
            work(&mut conn)
        })
        .await
        .map_err(|err| HistoryError::Worker(err.to_string()))?
    }

    /// Writes one audit entry; returns once it is committed.
    pub async fn audit(&self, entry: AuditEntry) -> Result<(), HistoryError> {
        self.with_conn(move |conn| insert_audit(conn, &entry)).await
    }

    /// Writes a batch of one bus's registry events in one transaction.
    pub async fn record_events(
        &self,
        bus: Arc<str>,
        events: Vec<(Timestamp, NodeEvent)>,
    ) -> Result<(), HistoryError> {
        self.with_conn(move |conn| {
            let tx = conn.transaction()?;
            for (time, event) in &events {
                insert_event(&tx, &bus, *time, event)?;
            }
            tx.commit()?;
            Ok(())
        })
        .await
    }

    /// A row in the `nmt` table saying that `lost` events of `bus` were
    /// not recorded (the recorder fell behind the registry).
    pub async fn record_lost(&self, bus: Arc<str>, lost: u64) -> Result<(), HistoryError> {
        self.with_conn(move |conn| {
            conn.execute(
                "INSERT INTO nmt (time_us, bus, node, event, reason) VALUES (?1, ?2, NULL, 'lost', ?3)",
                params![micros(Timestamp::now()), &*bus, format!("{lost} events not recorded")],
            )?;
            Ok(())
        })
        .await
    }

    /// Entries of `query.kind` (or all kinds) at or after `since_us` and
    /// at or before `until_us`, oldest first: the first `limit` of them;
    /// without `since_us`, the newest `limit`.
    pub async fn query(&self, query: Query) -> Result<Vec<StoredEvent>, HistoryError> {
        self.with_conn(move |conn| {
            let kinds: Vec<EventKind> = match (query.kind, query.channel) {
                // A channel is an audit row's: no EMCY or NMT has one.
                (Some(EventKind::Audit) | None, Some(_)) => vec![EventKind::Audit],
                (Some(_), Some(_)) => Vec::new(),
                (Some(kind), None) => vec![kind],
                (None, None) => EventKind::ALL.to_vec(),
            };
            let mut all = Vec::new();
            for kind in kinds {
                all.extend(select(conn, kind, &query)?);
            }
            all.sort_by_key(|event| (event.time_us, event.kind.table(), event.id));
            if query.since_us.is_some() {
                all.truncate(query.limit);
            } else {
                let cut = all.len().saturating_sub(query.limit);
                all.drain(..cut);
            }
            Ok(all)
        })
        .await
    }

    /// Deletes what `retention` no longer keeps, as of `now`; the number
    /// of rows deleted.
    pub async fn prune(&self, retention: Retention, now: Timestamp) -> Result<u64, HistoryError> {
        self.with_conn(move |conn| {
            let mut deleted = 0;
            let tx = conn.transaction()?;
            for kind in EventKind::ALL {
                let table = kind.table();
                if let Some(days) = retention.days {
                    let cutoff = micros(now) - i64::from(days) * 86_400_000_000;
                    deleted += tx.execute(
                        &format!("DELETE FROM {table} WHERE time_us < ?1"),
                        params![cutoff],
                    )?;
                }
                if let Some(rows) = retention.rows {
                    let keep = i64::try_from(rows).unwrap_or(i64::MAX);
                    deleted += tx.execute(
                        &format!(
                            "DELETE FROM {table} WHERE id <= \
                             (SELECT id FROM {table} ORDER BY id DESC LIMIT 1 OFFSET ?1)"
                        ),
                        params![keep],
                    )?;
                }
            }
            deleted += alarms::prune(&tx, retention, micros(now))? as usize;
            tx.commit()?;
            Ok(deleted as u64)
        })
        .await
    }

    /// Prunes now and every `PRUNE_PERIOD`, while the returned task runs.
    pub fn spawn_pruner(&self, retention: Retention) -> tokio::task::JoinHandle<()> {
        let history = self.clone();
        tokio::spawn(async move {
            let mut ticks = tokio::time::interval(PRUNE_PERIOD);
            loop {
                ticks.tick().await;
                match history.prune(retention, Timestamp::now()).await {
                    Ok(0) => {}
                    Ok(n) => tracing::info!("history: {n} old entries pruned"),
                    Err(err) => tracing::warn!("history: pruning failed: {err}"),
                }
            }
        })
    }

    /// Records `bus`'s registry events from `events` until the registry
    /// closes: every EMCY in `emcy`, the other events in `nmt`. Each write
    /// takes whatever arrived meanwhile (up to 256) in one transaction. A
    /// receiver that lagged writes a `lost` row: never dropped silently.
    pub fn spawn_recorder(
        &self,
        bus: &str,
        mut events: broadcast::Receiver<NodeEvent>,
    ) -> tokio::task::JoinHandle<()> {
        use broadcast::error::{RecvError, TryRecvError};
        let history = self.clone();
        let bus: Arc<str> = Arc::from(bus);
        tokio::spawn(async move {
            loop {
                let first = match events.recv().await {
                    Ok(event) => event,
                    Err(RecvError::Lagged(n)) => {
                        if let Err(err) = history.record_lost(bus.clone(), n).await {
                            tracing::warn!("history: bus {bus}: {err}");
                        }
                        continue;
                    }
                    Err(RecvError::Closed) => return,
                };
                // Stamped when read: the registry's events carry no time
                // (an EMCY carries its frame's, used instead).
                let mut batch = vec![(Timestamp::now(), first)];
                let mut lost = 0;
                while batch.len() < 256 {
                    match events.try_recv() {
                        Ok(event) => batch.push((Timestamp::now(), event)),
                        Err(TryRecvError::Lagged(n)) => lost += n,
                        Err(_) => break,
                    }
                }
                if let Err(err) = history.record_events(bus.clone(), batch).await {
                    tracing::warn!("history: bus {bus}: {err}");
                }
                if lost > 0
                    && let Err(err) = history.record_lost(bus.clone(), lost).await
                {
                    tracing::warn!("history: bus {bus}: {err}");
                }
            }
        })
    }
}

fn migrate(conn: &mut Connection) -> Result<(), HistoryError> {
    conn.execute_batch("CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)")?;
    let version: i64 = conn
        .query_row("SELECT version FROM schema_version", [], |row| row.get(0))
        .optional()?
        .unwrap_or(0);
    if version > MIGRATIONS.len() as i64 {
        return Err(HistoryError::TooNew(version, MIGRATIONS.len()));
    }
    for (step, sql) in MIGRATIONS.iter().enumerate().skip(version as usize) {
        let tx = conn.transaction()?;
        tx.execute_batch(sql)?;
        tx.execute("DELETE FROM schema_version", [])?;
        tx.execute(
            "INSERT INTO schema_version (version) VALUES (?1)",
            params![step as i64 + 1],
        )?;
        tx.commit()?;
    }
    Ok(())
}

fn micros(time: Timestamp) -> i64 {
    i64::try_from(time.as_micros()).unwrap_or(i64::MAX)
}

fn insert_audit(conn: &Connection, entry: &AuditEntry) -> Result<(), HistoryError> {
    conn.prepare_cached(
        "INSERT INTO audit (time_us, channel, who, peer, role, operation, bus, node, axis, \
         item, request, outcome, abort_code, method, path, status) \
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16)",
    )?
    .execute(params![
        micros(entry.time),
        entry.channel.name(),
        entry.who,
        entry.peer,
        entry.role,
        entry.operation,
        entry.bus,
        entry.node,
        entry.axis,
        entry.item,
        entry.request,
        entry.outcome,
        entry.abort_code,
        entry.method,
        entry.path,
        entry.status,
    ])?;
    Ok(())
}

fn insert_event(
    conn: &Connection,
    bus: &str,
    time: Timestamp,
    event: &NodeEvent,
) -> Result<(), HistoryError> {
    let node = event.node().get();
    let nmt = |name: &str, from: Option<&str>, to: Option<&str>, reason: Option<String>| {
        conn.prepare_cached(
            "INSERT INTO nmt (time_us, bus, node, event, from_state, to_state, reason) \
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
        )?
        .execute(params![micros(time), bus, node, name, from, to, reason])
    };
    match event {
        NodeEvent::Emcy { emcy, .. } => {
            conn.prepare_cached(
                "INSERT INTO emcy (time_us, bus, node, code, text, register, manufacturer, axis) \
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)",
            )?
            .execute(params![
                micros(emcy.timestamp),
                bus,
                node,
                emcy.code,
                emcy.text,
                emcy.register,
                emcy.manufacturer_hex(),
                emcy.axis
            ])?;
        }
        NodeEvent::Appeared { .. } => {
            nmt("appeared", None, None, None)?;
        }
        NodeEvent::Identified { profile, eds, .. } => {
            let reason = format!("{profile}, EDS {}", eds.as_deref().unwrap_or("none"));
            nmt("identified", None, None, Some(reason))?;
        }
        NodeEvent::IdentificationFailed { error, .. } => {
            nmt("identification_failed", None, None, Some(error.clone()))?;
        }
        NodeEvent::NmtChanged { from, to, .. } => {
            nmt(
                "nmt_changed",
                Some(from.map_or("unknown", |state| state.name())),
                Some(to.name()),
                None,
            )?;
        }
        NodeEvent::Offline { reason, .. } => {
            let reason = serde_json::to_value(reason)
                .ok()
                .and_then(|value| value.as_str().map(str::to_string));
            nmt("offline", None, None, reason)?;
        }
        NodeEvent::Online { .. } => {
            nmt("online", None, None, None)?;
        }
        NodeEvent::HeartbeatWritten { heartbeat_ms, .. } => {
            nmt(
                "heartbeat_written",
                None,
                None,
                Some(format!("{heartbeat_ms} ms")),
            )?;
        }
        NodeEvent::WatchdogOff { warning, .. } => {
            nmt("watchdog_off", None, None, Some(warning.clone()))?;
        }
        NodeEvent::MotionEnded {
            axis,
            reason,
            detail,
            ..
        } => {
            nmt(
                "motion_ended",
                None,
                None,
                Some(format!("axis {axis}, {reason}: {detail}")),
            )?;
        }
    }
    Ok(())
}

fn select(
    conn: &Connection,
    kind: EventKind,
    query: &Query,
) -> Result<Vec<StoredEvent>, HistoryError> {
    let table = kind.table();
    let Query {
        since_us, until_us, ..
    } = *query;
    let limit = i64::try_from(query.limit).unwrap_or(i64::MAX);
    // Only the audit table has channels (`query` asks no other for one).
    let channel = match kind {
        EventKind::Audit => query.channel.map(Channel::name),
        _ => None,
    };
    let by_channel = match kind {
        EventKind::Audit => "(?4 IS NULL OR channel = ?4)",
        _ => "?4 IS NULL",
    };
    // Oldest first from `since`; newest first without it (reversed by the
    // caller's sort).
    let sql = match since_us {
        Some(_) => {
            format!(
                "SELECT * FROM {table} WHERE time_us >= ?1 AND (?3 IS NULL OR time_us <= ?3) \
                 AND {by_channel} ORDER BY time_us, id LIMIT ?2"
            )
        }
        None => format!(
            "SELECT * FROM {table} WHERE ?1 IS NULL AND (?3 IS NULL OR time_us <= ?3) \
             AND {by_channel} ORDER BY time_us DESC, id DESC LIMIT ?2"
        ),
    };
    let mut statement = conn.prepare_cached(&sql)?;
    let names: Vec<String> = statement
        .column_names()
        .map(|name| name.to_string())
        .collect();
    let rows = statement.query_map(params![since_us, limit, until_us, channel], |row| {
        let mut fields = serde_json::Map::new();
        let mut id = 0;
        let mut time_us = 0;
        for (at, name) in names.iter().enumerate() {
            use rusqlite::types::ValueRef;
            let value = match row.get_ref(at)? {
                ValueRef::Null => continue,
                ValueRef::Integer(n) => serde_json::Value::from(n),
                ValueRef::Real(x) => serde_json::Value::from(x),
                ValueRef::Text(text) | ValueRef::Blob(text) => {
                    serde_json::Value::from(String::from_utf8_lossy(text).into_owned())
                }
            };
            match name.as_str() {
                "id" => id = value.as_i64().unwrap_or(0),
                "time_us" => time_us = value.as_i64().unwrap_or(0),
                _ => {
                    fields.insert(name.clone(), value);
                }
            }
        }
        Ok(StoredEvent {
            kind,
            id,
            time_us,
            fields,
        })
    })?;
    Ok(rows.collect::<Result<_, _>>()?)
}

mod alarms;
#[cfg(test)]
mod tests;
