//! The outbox: what this server still owes a receiver, kept in its own
//! store and written in the same transaction as what it reports, so
//! nothing committed is lost to a crash, a restart or a cut line.
//!
//! - A **site** (`serve --forward-to`) owes its office every committed
//!   reading batch (a row naming the readings' ids, not a copy), machine
//!   declaration (with its engines' state) and alarm change, in order per
//!   machine. The row's id is the sequence of the idempotency key (site,
//!   machine, sequence); the office keeps the last sequence it committed
//!   per machine (its *mark*, in the same transaction as what it stored),
//!   so a batch sent twice is applied once. A row is deleted only once the
//!   office has answered that it committed it.
//! - Every server owes its webhooks each alarm change of a severity with a
//!   URL: posted after a restart too, with the same idempotency key.
//!
//! Readings a pending batch names are kept by retention until it is sent.

use rusqlite::{Connection, OptionalExtension, params};
use serde::Serialize;

use super::handle::SqliteStore;
use crate::clock::wall_clock_s;
use crate::fusion::Reading;
use crate::store::alarms::{AlarmChange, Change};
use crate::store::error::StoreError;
use crate::store::outbox::{
    AuditEntry, Backlog, Declared, ForwardHeld, Forwarded, OfficeEntry, OfficeItem, OutboxConfig,
    RESET_FORWARD_MARK, SiteRecord, WebhookEntry, mark_moved,
};

fn to_json<T: Serialize>(value: &T) -> Result<String, StoreError> {
    serde_json::to_string(value).map_err(|e| StoreError::Corrupt(format!("outbox body: {e}")))
}

/// The highest reading id stored so far (0 if none).
pub(super) fn last_reading_id(tx: &Connection) -> Result<i64, StoreError> {
    Ok(tx
        .prepare_cached("SELECT coalesce(max(id), 0) FROM readings")?
        .query_row([], |row| row.get(0))?)
}

/// Most readings one outbox row names: a batch of a gateway's (up to
/// 100 000) goes in several rows, so one row always fits a request.
const READINGS_PER_ROW: i64 = 10_000;

/// Whether the office has been told of machine `machine_id` (its
/// declaration is in the outbox or sent): only then do its rows go there.
pub(super) fn told(tx: &Connection, machine_id: i64) -> Result<bool, StoreError> {
    Ok(tx
        .prepare_cached("SELECT 1 FROM forwarding WHERE machine_id = ?1")?
        .query_row([machine_id], |_| Ok(()))
        .optional()?
        .is_some())
}

/// Records a committed batch of `count` readings with ids in
/// `(before, last]` (SQLite gives a transaction's inserts consecutive
/// ids), [`READINGS_PER_ROW`] a row.
pub(super) fn record_readings(
    tx: &Connection,
    machine_id: i64,
    before: i64,
    count: usize,
) -> Result<(), StoreError> {
    if count == 0 {
        return Ok(());
    }
    let last = last_reading_id(tx)?;
    let mut first = before + 1;
    while first <= last {
        let end = (first + READINGS_PER_ROW - 1).min(last);
        tx.prepare_cached(
            "INSERT INTO outbox (destination, machine_id, kind, first_reading_id, last_reading_id, readings, created_t) \
             VALUES ('office', ?1, 'readings', ?2, ?3, ?4, ?5)",
        )?
        .execute(params![machine_id, first, end, end - first + 1, wall_clock_s()])?;
        first = end + 1;
    }
    Ok(())
}

/// Records the alarm changes a commit made, for whoever is owed them
/// (`to_office`: a site's machine the office has been told of).
pub(super) fn record_alarms(
    tx: &Connection,
    config: &OutboxConfig,
    to_office: bool,
    machine_id: i64,
    changes: &[AlarmChange],
) -> Result<(), StoreError> {
    for change in changes {
        let to_webhook = config.webhook(&change.alarm.severity);
        if !(to_office || to_webhook) {
            continue;
        }
        let body = to_json(change)?;
        if to_office {
            tx.prepare_cached(
                "INSERT INTO outbox (destination, machine_id, kind, body, created_t) \
                 VALUES ('office', ?1, 'alarm', ?2, ?3)",
            )?
            .execute(params![machine_id, body, wall_clock_s()])?;
        }
        if to_webhook {
            tx.prepare_cached(
                "INSERT INTO outbox (destination, machine_id, kind, body, created_t) \
                 VALUES ('webhook', ?1, ?2, ?3, ?4)",
            )?
            .execute(params![
                machine_id,
                change.alarm.severity,
                body,
                wall_clock_s()
            ])?;
        }
    }
    Ok(())
}

/// Records a (re)declaration for the office and notes the machine as told.
pub(super) fn record_machine(
    tx: &Connection,
    machine_id: i64,
    spec_json: &str,
    snapshot: &str,
) -> Result<(), StoreError> {
    let spec: serde_json::Value = serde_json::from_str(spec_json)
        .map_err(|e| StoreError::Corrupt(format!("machine {machine_id} spec: {e}")))?;
    let body = to_json(&Declared {
        spec,
        snapshot: snapshot.to_string(),
    })?;
    tx.prepare_cached(
        "INSERT INTO outbox (destination, machine_id, kind, body, created_t) \
         VALUES ('office', ?1, 'machine', ?2, ?3)",
    )?
    .execute(params![machine_id, body, wall_clock_s()])?;
    tx.prepare_cached("INSERT OR IGNORE INTO forwarding (machine_id) VALUES (?1)")?
        .execute([machine_id])?;
    Ok(())
}

/// An office: applies the acknowledgements of a forwarded write and moves
/// the machine's mark to its sequence, if the mark is still where the
/// write expects it. Returns the alarms acknowledged.
pub(super) fn apply_forwarded(
    tx: &rusqlite::Transaction,
    machine_id: i64,
    forwarded: &Forwarded,
) -> Result<Vec<AlarmChange>, StoreError> {
    let stored: Option<i64> = tx
        .prepare_cached("SELECT sequence FROM forward_marks WHERE machine_id = ?1")?
        .query_row([machine_id], |row| row.get(0))
        .optional()?;
    if stored != forwarded.after {
        return Err(mark_moved(machine_id, stored, forwarded.after));
    }
    let mut changes = Vec::new();
    for ack in &forwarded.acks {
        let ids: Vec<i64> = tx
            .prepare_cached(
                "UPDATE alarms SET acked_t = ?6, acked_by = ?7 WHERE machine_id = ?1 AND kind = ?2 \
                 AND severity = ?3 AND subject = ?4 AND raised_t = ?5 AND acked_t IS NULL \
                 RETURNING id",
            )?
            .query_map(
                params![
                    machine_id,
                    ack.kind,
                    ack.severity,
                    ack.subject,
                    ack.raised_t,
                    ack.acked_t,
                    ack.by
                ],
                |r| r.get::<_, i64>(0),
            )?
            .collect::<Result<_, _>>()?;
        for id in ids {
            if let Some(alarm) = super::alarms::by_id(tx, id)? {
                changes.push(AlarmChange {
                    transition: Change::Acknowledged,
                    alarm,
                });
            }
        }
    }
    set_mark(tx, machine_id, &forwarded.applied, forwarded.sequence)?;
    if let Some(confirmed) = forwarded.confirmed {
        tx.prepare_cached("DELETE FROM forward_applied WHERE machine_id = ?1 AND sequence <= ?2")?
            .execute(params![machine_id, confirmed])?;
    }
    Ok(changes)
}

/// An office: sets forwarded machine `machine`'s (its protocol id) mark
/// back to `sequence` (never forward: a higher one leaves it), with a row
/// of the audit log saying `actor` did it at `t`; the mark it had (`None`:
/// no such forwarded machine, nothing done). Its own transaction: the
/// server's writer, or a plain connection beside it (the command line).
pub fn reset_mark(
    conn: &mut Connection,
    machine: &str,
    sequence: i64,
    actor: &str,
    t: f64,
) -> Result<Option<i64>, StoreError> {
    let tx = conn.transaction()?;
    let found: Option<(i64, i64)> = tx
        .query_row(
            "SELECT f.machine_id, f.sequence FROM forward_marks f \
             JOIN machines m ON m.id = f.machine_id WHERE m.machine = ?1",
            [machine],
            |row| Ok((row.get(0)?, row.get(1)?)),
        )
        .optional()?;
    let Some((machine_id, was)) = found else {
        return Ok(None);
    };
    // Back only: a mark set forward would skip rows. What lies above it
    // is applied again when the site sends it (readings are stored once).
    let sequence = sequence.min(was);
    tx.execute(
        "UPDATE forward_marks SET sequence = ?2, trusted_to = min(trusted_to, ?2) \
         WHERE machine_id = ?1",
        params![machine_id, sequence],
    )?;
    tx.execute(
        "DELETE FROM forward_applied WHERE machine_id = ?1 AND sequence > ?2",
        params![machine_id, sequence],
    )?;
    tx.execute(
        "INSERT INTO audit (t, actor, action, subject, detail) VALUES (?1, ?2, ?3, ?4, ?5)",
        params![
            t,
            actor,
            RESET_FORWARD_MARK,
            machine,
            format!("mark {was} -> {sequence}")
        ],
    )?;
    tx.commit()?;
    Ok(Some(was))
}

/// An office: a forwarded machine's mark is `sequence` (never lowered
/// here), and it holds the rows `applied`.
pub(super) fn set_mark(
    tx: &Connection,
    machine_id: i64,
    applied: &[i64],
    sequence: i64,
) -> Result<(), StoreError> {
    let mut hold = tx.prepare_cached(
        "INSERT INTO forward_applied (machine_id, sequence) VALUES (?1, ?2) ON CONFLICT DO NOTHING",
    )?;
    for applied in applied {
        hold.execute(params![machine_id, applied])?;
    }
    tx.prepare_cached(
        "INSERT INTO forward_marks (machine_id, sequence) VALUES (?1, ?2) \
         ON CONFLICT (machine_id) DO UPDATE SET sequence = max(sequence, ?2)",
    )?
    .execute(params![machine_id, sequence])?;
    Ok(())
}

/// Rows read per outbox query.
const PAGE: i64 = 256;

/// An outbox row to the office as stored.
struct Row {
    sequence: i64,
    kind: String,
    first: Option<i64>,
    last: Option<i64>,
    count: i64,
    body: Option<String>,
}

impl SqliteStore {
    /// An office: what this office holds of forwarded machine
    /// `machine_id`'s rows ([`ForwardHeld`]).
    pub fn forward_held(&self, machine_id: i64) -> Result<ForwardHeld, StoreError> {
        self.read(|conn| {
            let mark: Option<(i64, i64)> = conn
                .prepare_cached(
                    "SELECT sequence, trusted_to FROM forward_marks WHERE machine_id = ?1",
                )?
                .query_row([machine_id], |row| Ok((row.get(0)?, row.get(1)?)))
                .optional()?;
            let applied = conn
                .prepare_cached("SELECT sequence FROM forward_applied WHERE machine_id = ?1")?
                .query_map([machine_id], |row| row.get(0))?
                .collect::<Result<_, _>>()?;
            Ok(ForwardHeld::new(mark, applied))
        })
    }

    /// An office: sets forwarded machine `machine`'s mark back to
    /// `sequence` ([`reset_mark`]), on the writing connection.
    pub async fn reset_forward_mark(
        &self,
        machine: String,
        sequence: i64,
        actor: String,
        t: f64,
    ) -> Result<Option<i64>, StoreError> {
        self.maintain(move |conn| reset_mark(conn, &machine, sequence, &actor, t))
            .await
    }

    /// The audit log, oldest first.
    pub fn audit(&self) -> Result<Vec<AuditEntry>, StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached(
                "SELECT id, t, actor, action, subject, detail FROM audit ORDER BY id",
            )?;
            let rows = stmt
                .query_map([], |row| {
                    Ok(AuditEntry {
                        id: row.get(0)?,
                        t: row.get(1)?,
                        actor: row.get(2)?,
                        action: row.get(3)?,
                        subject: row.get(4)?,
                        detail: row.get(5)?,
                    })
                })?
                .collect::<Result<_, _>>()?;
            Ok(rows)
        })
    }

    /// An office: the last sequence of machine `machine_id` its site sent
    /// that is committed here.
    pub fn forward_mark(&self, machine_id: i64) -> Result<Option<i64>, StoreError> {
        self.read(|conn| {
            Ok(conn
                .prepare_cached("SELECT sequence FROM forward_marks WHERE machine_id = ?1")?
                .query_row([machine_id], |row| row.get(0))
                .optional()?)
        })
    }

    /// A site: the machines with rows owed to the office: (id, protocol
    /// id, the last sequence the office answered committed).
    pub fn office_pending(&self) -> Result<Vec<(i64, String, Option<i64>)>, StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached(
                "SELECT m.id, m.machine, f.acked FROM machines m \
                 LEFT JOIN forwarding f ON f.machine_id = m.id WHERE EXISTS \
                 (SELECT 1 FROM outbox o WHERE o.destination = 'office' AND o.machine_id = m.id) \
                 ORDER BY m.id",
            )?;
            let rows = stmt.query_map([], |row| Ok((row.get(0)?, row.get(1)?, row.get(2)?)))?;
            Ok(rows.collect::<Result<_, _>>()?)
        })
    }

    /// A site: machine `machine_id`'s first rows owed to the office, in
    /// order, their readings loaded: at least one row, then as many as
    /// keep the readings within `max_readings`.
    pub fn office_entries(
        &self,
        machine_id: i64,
        max_readings: u64,
    ) -> Result<Vec<OfficeEntry>, StoreError> {
        self.read(|conn| {
            let mut entries = Vec::new();
            let mut readings_taken = 0u64;
            let mut after = i64::MIN;
            loop {
                let mut stmt = conn.prepare_cached(
                    "SELECT id, kind, first_reading_id, last_reading_id, readings, body FROM outbox \
                     WHERE destination = 'office' AND machine_id = ?1 AND id > ?2 ORDER BY id LIMIT ?3",
                )?;
                let rows: Vec<Row> = stmt
                    .query_map(params![machine_id, after, PAGE], |r| {
                        Ok(Row {
                            sequence: r.get(0)?,
                            kind: r.get(1)?,
                            first: r.get(2)?,
                            last: r.get(3)?,
                            count: r.get(4)?,
                            body: r.get(5)?,
                        })
                    })?
                    .collect::<Result<_, _>>()?;
                let page_len = rows.len();
                for Row {
                    sequence,
                    kind,
                    first,
                    last,
                    count,
                    body,
                } in rows
                {
                    let count = count.max(0) as u64;
                    if !entries.is_empty() && readings_taken + count > max_readings {
                        return Ok(entries);
                    }
                    let corrupt =
                        |what: String| StoreError::Corrupt(format!("outbox row {sequence}: {what}"));
                    let item = match kind.as_str() {
                        "readings" => {
                            let (first, last) = first.zip(last).ok_or_else(|| {
                                corrupt("a reading batch without its ids".into())
                            })?;
                            OfficeItem::Readings(readings_between(conn, machine_id, first, last)?)
                        }
                        "machine" => OfficeItem::Machine(
                            serde_json::from_str(body.as_deref().unwrap_or_default())
                                .map_err(|e| corrupt(e.to_string()))?,
                        ),
                        "alarm" => OfficeItem::Alarm(
                            serde_json::from_str(body.as_deref().unwrap_or_default())
                                .map_err(|e| corrupt(e.to_string()))?,
                        ),
                        other => return Err(corrupt(format!("unknown kind `{other}`"))),
                    };
                    readings_taken += count;
                    after = sequence;
                    entries.push(OfficeEntry { sequence, item });
                }
                if page_len < PAGE as usize {
                    return Ok(entries);
                }
            }
        })
    }

    /// A site: what is owed to the office.
    pub fn office_backlog(&self) -> Result<Backlog, StoreError> {
        self.read(|conn| {
            Ok(conn
                .prepare_cached(
                    "SELECT count(*), coalesce(sum(readings), 0), min(created_t) FROM outbox \
                     WHERE destination = 'office'",
                )?
                .query_row([], |r| {
                    Ok(Backlog {
                        items: r.get::<_, i64>(0)?.max(0) as u64,
                        readings: r.get::<_, i64>(1)?.max(0) as u64,
                        oldest_unsent_t: r.get(2)?,
                    })
                })?)
        })
    }

    /// A site: the office has committed machine `machine_id`'s rows up to
    /// `sequence`: they go, and the sequence is remembered (the next
    /// request tells the office, which so finds a gap on its side).
    pub async fn office_sent(&self, machine_id: i64, sequence: i64) -> Result<(), StoreError> {
        self.maintain(move |conn| {
            let tx = conn.transaction()?;
            tx.prepare_cached(
                "DELETE FROM outbox WHERE destination = 'office' AND machine_id = ?1 AND id <= ?2",
            )?
            .execute(params![machine_id, sequence])?;
            tx.prepare_cached(
                "UPDATE forwarding SET acked = max(coalesce(acked, ?2), ?2) WHERE machine_id = ?1",
            )?
            .execute(params![machine_id, sequence])?;
            tx.commit()?;
            Ok(())
        })
        .await
    }

    /// A site starting to forward to `office` as `site`: each machine the
    /// office has not been told of is declared to it with the state its
    /// engines stand in now (call once the machines are restored: their
    /// snapshots then cover every stored reading), its rows still pending
    /// from an earlier time of forwarding superseded. Another office or
    /// site name than last time: every machine is declared afresh. The
    /// sequence is raised to the wall clock in microseconds, so a site
    /// whose database was made anew or restored sends sequences above any
    /// the office has had from it.
    pub async fn forward_to(&self, office: String, site: String) -> Result<(), StoreError> {
        self.maintain(move |conn| {
            let tx = conn.transaction()?;
            let target: Option<(String, String)> = tx
                .query_row("SELECT office, site FROM forward_target WHERE id = 1", [], |r| {
                    Ok((r.get(0)?, r.get(1)?))
                })
                .optional()?;
            if target.as_ref() != Some(&(office.clone(), site.clone())) {
                if target.is_some() {
                    tracing::warn!(%office, %site, "another office or site name than before: every machine is declared to it afresh");
                }
                tx.execute("DELETE FROM forwarding", [])?;
                tx.execute(
                    "INSERT INTO forward_target (id, office, site) VALUES (1, ?1, ?2) \
                     ON CONFLICT (id) DO UPDATE SET office = ?1, site = ?2",
                    params![office, site],
                )?;
            }
            let floor = (wall_clock_s() * 1e6) as i64;
            let raised = tx.execute(
                "UPDATE sqlite_sequence SET seq = max(seq, ?1) WHERE name = 'outbox'",
                [floor],
            )?;
            if raised == 0 {
                tx.execute(
                    "INSERT INTO sqlite_sequence (name, seq) VALUES ('outbox', ?1)",
                    [floor],
                )?;
            }
            let untold: Vec<(i64, String, String)> = tx
                .prepare(
                    "SELECT m.id, m.spec, s.state FROM machines m JOIN snapshots s ON s.machine_id = m.id \
                     WHERE m.id NOT IN (SELECT machine_id FROM forwarding) ORDER BY m.id",
                )?
                .query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))?
                .collect::<Result<_, _>>()?;
            for (machine_id, spec, state) in untold {
                let superseded = tx.execute(
                    "DELETE FROM outbox WHERE destination = 'office' AND machine_id = ?1",
                    [machine_id],
                )?;
                if superseded > 0 {
                    tracing::warn!(machine_id, superseded, "rows from an earlier forwarding superseded by the declaration with the engines' state now");
                }
                record_machine(&tx, machine_id, &spec, &state)?;
            }
            tx.commit()?;
            Ok(())
        })
        .await
    }

    /// A site not forwarding (any more): forgets the office and which
    /// machines it was told of, and drops the rows still owed to it
    /// (forwarding again declares every machine afresh, with the state of
    /// then). Returns how many rows were dropped.
    pub async fn forward_off(&self) -> Result<usize, StoreError> {
        self.maintain(move |conn| {
            let tx = conn.transaction()?;
            let dropped = tx.execute("DELETE FROM outbox WHERE destination = 'office'", [])?;
            tx.execute("DELETE FROM forwarding", [])?;
            tx.execute("DELETE FROM forward_target", [])?;
            tx.commit()?;
            Ok(dropped)
        })
        .await
    }

    /// Alarm changes owed to the webhook of `severity`, oldest first.
    pub fn webhook_pending(
        &self,
        severity: &'static str,
        limit: usize,
    ) -> Result<Vec<WebhookEntry>, StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached(
                "SELECT id, body FROM outbox WHERE destination = 'webhook' AND kind = ?1 \
                 ORDER BY id LIMIT ?2",
            )?;
            let rows: Vec<(i64, String)> = stmt
                .query_map(params![severity, limit as i64], |r| {
                    Ok((r.get(0)?, r.get(1)?))
                })?
                .collect::<Result<_, _>>()?;
            rows.into_iter()
                .map(|(id, body)| {
                    Ok(WebhookEntry {
                        id,
                        change: serde_json::from_str(&body)
                            .map_err(|e| StoreError::Corrupt(format!("outbox row {id}: {e}")))?,
                    })
                })
                .collect()
        })
    }

    /// Forgets the changes owed to a webhook no longer configured.
    pub async fn webhook_dropped(&self, severity: &'static str) -> Result<u64, StoreError> {
        self.maintain(move |conn| {
            Ok(conn
                .prepare_cached("DELETE FROM outbox WHERE destination = 'webhook' AND kind = ?1")?
                .execute([severity])? as u64)
        })
        .await
    }

    /// A webhook change is done with (delivered or given up).
    pub async fn webhook_done(&self, id: i64) -> Result<(), StoreError> {
        self.maintain(move |conn| {
            conn.prepare_cached("DELETE FROM outbox WHERE id = ?1 AND destination = 'webhook'")?
                .execute([id])?;
            Ok(())
        })
        .await
    }

    /// An office: every site's record.
    pub fn sites(&self) -> Result<Vec<SiteRecord>, StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached(
                "SELECT name, last_contact_t, backlog_items, backlog_readings, oldest_unsent_t \
                 FROM sites ORDER BY name",
            )?;
            let rows = stmt.query_map([], |r| {
                Ok(SiteRecord {
                    name: r.get(0)?,
                    last_contact_t: r.get(1)?,
                    backlog: Backlog {
                        items: r.get::<_, i64>(2)?.max(0) as u64,
                        readings: r.get::<_, i64>(3)?.max(0) as u64,
                        oldest_unsent_t: r.get(4)?,
                    },
                })
            })?;
            Ok(rows.collect::<Result<_, _>>()?)
        })
    }

    /// An office: records a site's contact.
    pub async fn put_site(&self, site: SiteRecord) -> Result<(), StoreError> {
        self.maintain(move |conn| {
            conn.prepare_cached(
                "INSERT INTO sites (name, last_contact_t, backlog_items, backlog_readings, oldest_unsent_t) \
                 VALUES (?1, ?2, ?3, ?4, ?5) ON CONFLICT (name) DO UPDATE SET \
                 last_contact_t = ?2, backlog_items = ?3, backlog_readings = ?4, oldest_unsent_t = ?5",
            )?
            .execute(params![
                site.name,
                site.last_contact_t,
                site.backlog.items as i64,
                site.backlog.readings as i64,
                site.backlog.oldest_unsent_t
            ])?;
            Ok(())
        })
        .await
    }
}

/// Machine `machine_id`'s readings with ids in `[first, last]`, in order.
fn readings_between(
    conn: &Connection,
    machine_id: i64,
    first: i64,
    last: i64,
) -> Result<Vec<Reading>, StoreError> {
    let mut stmt = conn.prepare_cached(
        "SELECT t, sensor, body FROM readings WHERE machine_id = ?1 AND id BETWEEN ?2 AND ?3 ORDER BY id",
    )?;
    let mut rows = stmt.query(params![machine_id, first, last])?;
    let mut readings = Vec::new();
    while let Some(row) = rows.next()? {
        readings.push(super::history::reading_row(row)?);
    }
    Ok(readings)
}

#[cfg(test)]
mod tests;
