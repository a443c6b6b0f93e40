//! The alarms in the history database: each alarm's row as it is now
//! (`alarm`) and the steps of its life (`alarm_event`), written as the
//! book changes and read back at start.

use rusqlite::{Connection, Transaction, params};

use super::{History, HistoryError, Retention};
use crate::alarms::{Alarm, AlarmEvent, AlarmState, AlarmStep, Changed, NORMAL_KEPT};
use crate::profiles::alarm::{AlarmKind, Severity};

impl History {
    /// Writes changes of the alarms in one transaction: each alarm's row
    /// as it is now, and the step that changed it.
    pub(crate) async fn record_alarms(&self, changes: Vec<Changed>) -> Result<(), HistoryError> {
        self.with_conn(move |conn| {
            let tx = conn.transaction()?;
            for change in &changes {
                upsert(&tx, &change.alarm)?;
                insert_event(&tx, change.alarm.id, &change.event)?;
            }
            tx.commit()?;
            Ok(())
        })
        .await
    }

    /// The alarms to start with: every one that is not `normal`, and the
    /// newest [`NORMAL_KEPT`] that are, each with its history.
    pub(crate) async fn load_alarms(&self) -> Result<Vec<Alarm>, HistoryError> {
        self.with_conn(|conn| {
            let mut alarms = select(
                conn,
                "SELECT * FROM alarm WHERE state != 'normal' ORDER BY id",
                params![],
            )?;
            let mut normal = select(
                conn,
                "SELECT * FROM alarm WHERE state = 'normal' ORDER BY id DESC LIMIT ?1",
                params![NORMAL_KEPT as i64],
            )?;
            normal.reverse();
            alarms.extend(normal);
            alarms.sort_by_key(|alarm| alarm.id);
            for alarm in &mut alarms {
                alarm.history = events(conn, alarm.id)?;
            }
            Ok(alarms)
        })
        .await
    }
}

/// Deletes the `normal` alarms (and their steps) `retention` no longer
/// keeps: raised before its days, or beyond its rows.
pub(super) fn prune(
    tx: &Transaction<'_>,
    retention: Retention,
    now_us: i64,
) -> Result<u64, HistoryError> {
    let mut deleted = 0;
    if let Some(days) = retention.days {
        let cutoff = now_us - i64::from(days) * 86_400_000_000;
        deleted += tx.execute(
            "DELETE FROM alarm_event WHERE alarm IN \
             (SELECT id FROM alarm WHERE state = 'normal' AND raised_us < ?1)",
            params![cutoff],
        )?;
        deleted += tx.execute(
            "DELETE FROM alarm WHERE state = 'normal' AND raised_us < ?1",
            params![cutoff],
        )?;
    }
    if let Some(rows) = retention.rows {
        let keep = i64::try_from(rows).unwrap_or(i64::MAX);
        let cut = "(SELECT id FROM alarm ORDER BY id DESC LIMIT 1 OFFSET ?1)";
        deleted += tx.execute(
            &format!(
                "DELETE FROM alarm_event WHERE alarm IN \
                 (SELECT id FROM alarm WHERE state = 'normal' AND id <= {cut})"
            ),
            params![keep],
        )?;
        deleted += tx.execute(
            &format!("DELETE FROM alarm WHERE state = 'normal' AND id <= {cut}"),
            params![keep],
        )?;
    }
    Ok(deleted as u64)
}

fn upsert(conn: &Connection, alarm: &Alarm) -> Result<(), HistoryError> {
    let code = match alarm.kind {
        AlarmKind::Emcy(code) => Some(code),
        _ => None,
    };
    conn.prepare_cached(
        "INSERT INTO alarm (id, bus, node, axis, kind, code, severity, state, text, help, \
         raised_us, cleared_us, acknowledged_by, acknowledged_at_us, comment, count) \
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16) \
         ON CONFLICT(id) DO UPDATE SET state = excluded.state, cleared_us = excluded.cleared_us, \
         acknowledged_by = excluded.acknowledged_by, \
         acknowledged_at_us = excluded.acknowledged_at_us, comment = excluded.comment, \
         count = excluded.count",
    )?
    .execute(params![
        alarm.id as i64,
        alarm.bus,
        alarm.node,
        alarm.axis,
        alarm.kind.name(),
        code,
        alarm.severity.name(),
        alarm.state.name(),
        alarm.text,
        alarm.help,
        alarm.raised_us,
        alarm.cleared_us,
        alarm.acknowledged_by,
        alarm.acknowledged_at_us,
        alarm.comment,
        alarm.count,
    ])?;
    Ok(())
}

fn insert_event(conn: &Connection, alarm: u64, event: &AlarmEvent) -> Result<(), HistoryError> {
    conn.prepare_cached(
        "INSERT INTO alarm_event (alarm, time_us, step, state, who, comment) \
         VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
    )?
    .execute(params![
        alarm as i64,
        event.time_us,
        event.step.name(),
        event.state.name(),
        event.who,
        event.comment,
    ])?;
    Ok(())
}

/// A value the database holds that no candeck wrote.
fn corrupt(what: &str, value: &str) -> rusqlite::Error {
    rusqlite::Error::FromSqlConversionFailure(
        0,
        rusqlite::types::Type::Text,
        format!("alarm {what} {value:?} is none this candeck knows").into(),
    )
}

fn select(
    conn: &Connection,
    sql: &str,
    args: impl rusqlite::Params,
) -> Result<Vec<Alarm>, HistoryError> {
    let mut statement = conn.prepare(sql)?;
    let rows = statement.query_map(args, |row| {
        let kind: String = row.get("kind")?;
        let code: Option<u16> = row.get("code")?;
        let severity: String = row.get("severity")?;
        let state: String = row.get("state")?;
        let id: i64 = row.get("id")?;
        Ok(Alarm {
            id: id as u64,
            bus: row.get("bus")?,
            node: row.get("node")?,
            axis: row.get("axis")?,
            kind: AlarmKind::from_name(&kind, code).ok_or_else(|| corrupt("kind", &kind))?,
            severity: Severity::from_name(&severity)
                .ok_or_else(|| corrupt("severity", &severity))?,
            state: AlarmState::from_name(&state).ok_or_else(|| corrupt("state", &state))?,
            text: row.get("text")?,
            help: row.get("help")?,
            raised_us: row.get("raised_us")?,
            cleared_us: row.get("cleared_us")?,
            acknowledged_by: row.get("acknowledged_by")?,
            acknowledged_at_us: row.get("acknowledged_at_us")?,
            comment: row.get("comment")?,
            count: row.get("count")?,
            history: Vec::new(),
        })
    })?;
    Ok(rows.collect::<Result<_, _>>()?)
}

fn events(conn: &Connection, alarm: u64) -> Result<Vec<AlarmEvent>, HistoryError> {
    let mut statement = conn.prepare_cached(
        "SELECT * FROM (SELECT time_us, step, state, who, comment, id FROM alarm_event \
         WHERE alarm = ?1 ORDER BY id DESC LIMIT ?2) ORDER BY id",
    )?;
    let rows = statement.query_map(
        params![alarm as i64, crate::alarms::HISTORY_KEPT as i64],
        |row| {
            let step: String = row.get(1)?;
            let state: String = row.get(2)?;
            Ok(AlarmEvent {
                time_us: row.get(0)?,
                step: AlarmStep::from_name(&step).ok_or_else(|| corrupt("step", &step))?,
                state: AlarmState::from_name(&state).ok_or_else(|| corrupt("state", &state))?,
                who: row.get(3)?,
                comment: row.get(4)?,
            })
        },
    )?;
    Ok(rows.collect::<Result<_, _>>()?)
}
