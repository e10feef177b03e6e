//! Alarms as stored: one row per raised alarm, cleared and acknowledged in
//! place, so the table is also the audit log (who acknowledged what, when).
//! Rows are written in the same transaction as the readings that raised or
//! cleared them; a transition recomputed after a restart (the same machine,
//! kind, severity, subject and time) is stored once.

use rusqlite::{Connection, OptionalExtension, Row, params};

use super::handle::SqliteStore;
use crate::store::alarms::{AlarmChange, AlarmFilter, AlarmRow, Change, StoredAlarm};
use crate::store::error::StoreError;

/// Writes `rows` of machine `machine_id` in `tx`: a raise inserts (once),
/// a clear closes the open alarm of its key. Returns the alarms that
/// changed (a raise already stored, or a clear with nothing open, changes
/// nothing).
pub(super) fn apply(
    tx: &rusqlite::Transaction,
    machine_id: i64,
    rows: &[AlarmRow],
) -> Result<Vec<AlarmChange>, StoreError> {
    let mut changed = Vec::new();
    // Each alarm as this row left it (a raise and its clear in one write
    // are announced as two states, not twice the cleared one).
    let mut push = |transition, id| -> Result<(), StoreError> {
        if let Some(alarm) = by_id(tx, id)? {
            changed.push(AlarmChange { transition, alarm });
        }
        Ok(())
    };
    for row in rows {
        if row.raised {
            let inserted = tx
                .prepare_cached(
                    "INSERT OR IGNORE INTO alarms (machine_id, kind, severity, subject, message, raised_t) \
                     VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
                )?
                .execute(params![
                    machine_id,
                    row.kind,
                    row.severity,
                    row.subject,
                    row.message,
                    row.t
                ])?;
            if inserted == 1 {
                push(Change::Raised, tx.last_insert_rowid())?;
            }
        } else {
            let ids: Vec<i64> = tx
                .prepare_cached(
                    "UPDATE alarms SET cleared_t = ?5 WHERE machine_id = ?1 AND kind = ?2 \
                     AND severity = ?3 AND subject = ?4 AND cleared_t IS NULL AND raised_t <= ?5 \
                     RETURNING id",
                )?
                .query_map(
                    params![machine_id, row.kind, row.severity, row.subject, row.t],
                    |r| r.get::<_, i64>(0),
                )?
                .collect::<Result<_, _>>()?;
            for id in ids {
                push(Change::Cleared, id)?;
            }
        }
    }
    Ok(changed)
}

const COLUMNS: &str = "a.id, m.machine, a.kind, a.severity, a.subject, a.message, a.raised_t, \
                       a.cleared_t, a.acked_t, a.acked_by";

fn stored(row: &Row) -> rusqlite::Result<StoredAlarm> {
    Ok(StoredAlarm {
        id: row.get(0)?,
        machine: row.get(1)?,
        kind: row.get(2)?,
        severity: row.get(3)?,
        subject: row.get(4)?,
        message: row.get(5)?,
        raised_t: row.get(6)?,
        cleared_t: row.get(7)?,
        acked_t: row.get(8)?,
        acked_by: row.get(9)?,
        now: None,
    })
}

fn list(conn: &Connection, filter: &AlarmFilter) -> Result<Vec<StoredAlarm>, StoreError> {
    let sql = format!(
        "SELECT {COLUMNS} FROM alarms a JOIN machines m ON m.id = a.machine_id \
         WHERE (?1 IS NULL OR m.machine = ?1) AND (?2 = 0 OR a.cleared_t IS NULL) \
         AND (?3 IS NULL OR a.raised_t <= ?3) \
         AND (?4 IS NULL OR a.cleared_t IS NULL OR a.cleared_t >= ?4) \
         ORDER BY a.raised_t DESC, a.id DESC LIMIT ?5"
    );
    let mut stmt = conn.prepare_cached(&sql)?;
    let (from, to) = (filter.during.map(|d| d.0), filter.during.map(|d| d.1));
    // SQLite reads a negative limit as none.
    let limit = filter
        .limit
        .map_or(-1, |n| i64::try_from(n).unwrap_or(i64::MAX));
    let rows = stmt.query_map(
        params![filter.machine, filter.active_only, to, from, limit],
        stored,
    )?;
    Ok(rows.collect::<Result<_, _>>()?)
}

pub(super) fn by_id(conn: &Connection, id: i64) -> Result<Option<StoredAlarm>, StoreError> {
    let sql = format!(
        "SELECT {COLUMNS} FROM alarms a JOIN machines m ON m.id = a.machine_id WHERE a.id = ?1"
    );
    Ok(conn.query_row(&sql, [id], stored).optional()?)
}

impl SqliteStore {
    /// The alarms `filter` asks for, newest first.
    pub fn alarms(&self, filter: &AlarmFilter) -> Result<Vec<StoredAlarm>, StoreError> {
        self.read(|conn| list(conn, filter))
    }

    /// Acknowledges alarm `id` by `by` at `t` (the first acknowledgement
    /// stands); the alarm as it now is and whether this call acknowledged
    /// it, or `None` if there is no such alarm. `announce` gets the
    /// acknowledged alarm on the writer thread right after the update, so
    /// it is ordered with the alarm changes commits report (a clear
    /// committed just after is announced after it) and runs even if the
    /// caller goes away.
    pub async fn ack_alarm(
        &self,
        id: i64,
        by: String,
        t: f64,
        announce: impl FnOnce(AlarmChange) + Send + 'static,
    ) -> Result<Option<(StoredAlarm, bool)>, StoreError> {
        let outbox = self.outbox;
        self.maintain(move |conn| {
            // The acknowledgement and what it owes the office and the
            // webhooks, in one commit.
            let tx = conn.transaction()?;
            let acked = tx.execute(
                "UPDATE alarms SET acked_t = ?2, acked_by = ?3 WHERE id = ?1 AND acked_t IS NULL",
                params![id, t, by],
            )? == 1;
            let alarm = by_id(&tx, id)?;
            let mut change = None;
            if let (true, Some(alarm)) = (acked, &alarm) {
                let acknowledged = AlarmChange {
                    transition: Change::Acknowledged,
                    alarm: alarm.clone(),
                };
                let machine_id: i64 =
                    tx.query_row("SELECT machine_id FROM alarms WHERE id = ?1", [id], |r| {
                        r.get(0)
                    })?;
                let to_office = outbox.forward && super::outbox::told(&tx, machine_id)?;
                super::outbox::record_alarms(
                    &tx,
                    &outbox,
                    to_office,
                    machine_id,
                    std::slice::from_ref(&acknowledged),
                )?;
                change = Some(acknowledged);
            }
            tx.commit()?;
            if let Some(change) = change {
                announce(change);
            }
            Ok(alarm.map(|alarm| (alarm, acked)))
        })
        .await
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MachineDeclaration;
    use crate::store::Store;
    use crate::store::Write;
    use tokio::sync::oneshot;

    fn row(kind: &'static str, subject: &str, raised: bool, t: f64) -> AlarmRow {
        AlarmRow {
            kind,
            severity: "warn",
            subject: subject.into(),
            raised,
            t,
            message: format!("{kind} {raised} at {t}"),
        }
    }

    /// Writes `alarms`; the changes the commit reported, as
    /// (transition, raised_t, cleared_t).
    async fn write(
        store: &Store,
        machine_id: i64,
        alarms: Vec<AlarmRow>,
    ) -> Vec<(Change, f64, Option<f64>)> {
        let (reply, answer) = oneshot::channel();
        let (report, reported) = oneshot::channel();
        store
            .write(Write {
                machine_id,
                alarms,
                readings: Vec::new(),
                estimates: Vec::new(),
                snapshot: None,
                after_commit: Some(Box::new(move |changes| {
                    let _ = report.send(changes);
                })),
                reply: Some(reply),
                lease_epoch: None,
                forwarded: None,
            })
            .await
            .unwrap();
        answer.await.unwrap().unwrap();
        let changes = reported.await.unwrap().expect("committed");
        changes
            .into_iter()
            .map(|c| (c.transition, c.alarm.raised_t, c.alarm.cleared_t))
            .collect()
    }

    #[tokio::test]
    async fn alarms_are_raised_once_cleared_acknowledged_and_kept() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let spec = serde_json::from_value::<MachineDeclaration>(
            serde_json::json!({"engines": {"attitude": {}}}),
        )
        .unwrap();
        let id = store
            .put_machine(spec.clone().validate("m1").unwrap(), "fresh".into())
            .await
            .unwrap();
        let other = store
            .put_machine(spec.validate("m2").unwrap(), "fresh".into())
            .await
            .unwrap();
        // A raise, the same raise again (recomputed after a restart), a
        // stale sensor of the other machine, then the first one cleared.
        // Each change is reported once: the repeated raise and a clear
        // with nothing open change nothing.
        assert_eq!(
            write(&store, id, vec![row("deviation", "", true, 10.0)]).await,
            [(Change::Raised, 10.0, None)]
        );
        assert_eq!(
            write(&store, id, vec![row("deviation", "", true, 10.0)]).await,
            []
        );
        write(
            &store,
            other,
            vec![row("stale_sensor", "laser", true, 12.0)],
        )
        .await;
        assert_eq!(
            write(&store, id, vec![row("deviation", "", false, 40.0)]).await,
            [(Change::Cleared, 10.0, Some(40.0))]
        );
        assert_eq!(
            write(&store, id, vec![row("deviation", "", false, 45.0)]).await,
            []
        );

        let all = store.alarms(&AlarmFilter::default()).unwrap();
        assert_eq!(all.len(), 2, "{all:?}");
        assert_eq!(
            (all[0].machine.as_str(), all[0].subject.as_str()),
            ("m2", "laser")
        );
        assert_eq!((all[1].raised_t, all[1].cleared_t), (10.0, Some(40.0)));
        let active = store
            .alarms(&AlarmFilter {
                machine: None,
                active_only: true,
                ..Default::default()
            })
            .unwrap();
        assert_eq!(active.len(), 1);
        let mine = store
            .alarms(&AlarmFilter {
                machine: Some("m1".into()),
                active_only: false,
                ..Default::default()
            })
            .unwrap();
        assert_eq!(mine.len(), 1);
        // A second raise of the same key after the clear is a new alarm.
        write(&store, id, vec![row("deviation", "", true, 50.0)]).await;
        assert_eq!(store.alarms(&AlarmFilter::default()).unwrap().len(), 3);

        // The first acknowledgement stands; an unknown alarm is None.
        let (acked, first) = store
            .ack_alarm(all[0].id, "shift-lead".into(), 60.0, |_| {})
            .await
            .unwrap()
            .unwrap();
        assert_eq!(
            (acked.acked_t, acked.acked_by.as_deref(), first),
            (Some(60.0), Some("shift-lead"), true)
        );
        let (again, first) = store
            .ack_alarm(all[0].id, "someone".into(), 70.0, |_| {})
            .await
            .unwrap()
            .unwrap();
        assert_eq!(
            (again.acked_by.as_deref(), first),
            (Some("shift-lead"), false)
        );
        assert_eq!(
            store
                .ack_alarm(9999, "x".into(), 1.0, |_| {})
                .await
                .unwrap(),
            None
        );
        store.close().await;

        // Reopened: all still there, as they were.
        let store = Store::open(dir.path()).unwrap();
        let reopened = store.alarms(&AlarmFilter::default()).unwrap();
        assert_eq!(reopened.len(), 3);
        assert!(
            reopened
                .iter()
                .any(|a| a.acked_by.as_deref() == Some("shift-lead"))
        );
        store.close().await;
    }
}
