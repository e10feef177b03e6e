//! The writer thread: the one connection that writes. It takes every
//! request waiting in its queue, applies them in one transaction (group
//! commit) and answers each only after the commit; a checkpointer beside
//! it copies the write-ahead log back into the database.

use rusqlite::{Connection, params};
use tokio::sync::mpsc;

use super::handle::Job;
use super::outbox;
use crate::config::MachineSpec;
use crate::store::alarms::AlarmChange;
use crate::store::error::StoreError;
use crate::store::outbox::OutboxConfig;
use crate::store::queue::MAX_GROUP;
use crate::store::queue::{Buckets, Outcome, Queued, Request, answer, fold_buckets, gather};
use crate::store::rows::Write;
use crate::store::rows::WriteOutcome;

/// Interval between write-ahead-log checkpoints.
const CHECKPOINT_EVERY: std::time::Duration = std::time::Duration::from_millis(500);

/// Copies the write-ahead log back into the database now and then, off
/// the writer's path. A passive checkpoint never blocks the writer; when
/// no reader holds an old snapshot the log is then reused from its start.
/// Ends with the writer.
pub(super) fn checkpoints(conn: Connection, writer_gone: std::sync::mpsc::Receiver<()>) {
    while let Err(std::sync::mpsc::RecvTimeoutError::Timeout) =
        writer_gone.recv_timeout(CHECKPOINT_EVERY)
    {
        match conn.query_row("PRAGMA wal_checkpoint(PASSIVE)", [], |row| {
            Ok((
                row.get::<_, i64>(0)?,
                row.get::<_, i64>(1)?,
                row.get::<_, i64>(2)?,
            ))
        }) {
            Ok(_) => {}
            Err(e) => tracing::warn!(error = %e, "checkpoint failed"),
        }
    }
}

/// The writer thread: takes every waiting request, commits them together,
/// then answers each.
pub(super) fn writer(
    mut conn: Connection,
    mut queue: mpsc::Receiver<Queued<Job>>,
    outbox: OutboxConfig,
    final_checkpoint: bool,
) {
    let mut group = Vec::with_capacity(MAX_GROUP);
    let mut close = None;
    while close.is_none() {
        let Some(first) = queue.blocking_recv() else {
            break;
        };
        let job;
        (job, close) = gather(first, &mut queue, &mut group);
        commit(&mut conn, &mut group, &outbox);
        if let Some(job) = job {
            job(&mut conn);
        }
    }
    // Later sends fail at once; requests already queued are dropped, and
    // their senders see the store closed.
    queue.close();
    // Whether closed or dropped by every handle: leave no log behind
    // (the server; a command beside it leaves the log to the server).
    if final_checkpoint
        && let Err(e) = conn.query_row("PRAGMA wal_checkpoint(TRUNCATE)", [], |_| Ok(()))
    {
        tracing::warn!(error = %e, "final checkpoint failed");
    }
    if let Some(reply) = close {
        let _ = reply.send(());
    }
}

/// Commits `group` in one transaction and answers each request (emptying
/// the group); if the transaction fails, each request alone.
fn commit(conn: &mut Connection, group: &mut Vec<Request>, outbox: &OutboxConfig) {
    if group.is_empty() {
        return;
    }
    match apply_group(conn, group, outbox) {
        Ok(outcomes) => {
            for (request, outcome) in group.drain(..).zip(outcomes) {
                answer(request, Ok(outcome));
            }
        }
        Err(e) => {
            // One bad request must not fail its neighbours: retry each alone.
            tracing::warn!(error = %e, requests = group.len(), "group commit failed; retrying one by one");
            for request in group.drain(..) {
                let result = apply_group(conn, std::slice::from_ref(&request), outbox)
                    .map(|mut outcomes| outcomes.pop().unwrap_or(Outcome::Put(0)));
                if let Err(e) = &result {
                    tracing::error!(error = %e, "write failed");
                }
                answer(request, result);
            }
        }
    }
}

fn apply_group(
    conn: &mut Connection,
    group: &[Request],
    outbox: &OutboxConfig,
) -> Result<Vec<Outcome>, StoreError> {
    let tx = conn.transaction()?;
    let mut outcomes = Vec::with_capacity(group.len());
    // Bucket extremes of the whole group, upserted once each: with many
    // small writes most of them fall in the same few buckets.
    let mut buckets = Buckets::new();
    for request in group {
        outcomes.push(match request {
            Request::Write(write) => {
                let (outcome, alarms) = apply_write(&tx, write, &mut buckets, outbox)?;
                Outcome::Write(outcome, alarms)
            }
            Request::PutMachine {
                spec,
                snapshot,
                forwarded,
                ..
            } => Outcome::Put(apply_put_machine(&tx, spec, snapshot, *forwarded, outbox)?),
        });
    }
    upsert_buckets(&tx, buckets)?;
    tx.commit()?;
    Ok(outcomes)
}

fn apply_write(
    tx: &rusqlite::Transaction,
    write: &Write,
    buckets: &mut Buckets,
    outbox: &OutboxConfig,
) -> Result<(WriteOutcome, Vec<AlarmChange>), StoreError> {
    let mut outcome = WriteOutcome::default();
    let machine_id = write.machine_id;
    // A site owes its office what it stores of the machines it has told
    // it of; an office forwards nothing on.
    let to_office = outbox.forward && write.forwarded.is_none() && outbox::told(tx, machine_id)?;
    let before = if to_office && !write.readings.is_empty() {
        outbox::last_reading_id(tx)?
    } else {
        0
    };
    let stored = insert_rows(
        tx,
        "INSERT OR IGNORE INTO readings (machine_id, t, sensor, body)",
        4,
        &write.readings,
        |stmt, i, reading| {
            stmt.raw_bind_parameter(i, machine_id)?;
            stmt.raw_bind_parameter(i + 1, reading.t)?;
            stmt.raw_bind_parameter(i + 2, reading.sensor as i64)?;
            stmt.raw_bind_parameter(i + 3, &reading.data)
        },
    )?;
    outcome.stored = stored;
    outcome.duplicates = write.readings.len() - stored;
    if to_office {
        outbox::record_readings(tx, machine_id, before, stored)?;
    }
    // Estimates are a function of the readings: one recomputed after a
    // restart is the same estimate, stored once.
    insert_rows(
        tx,
        "INSERT OR IGNORE INTO estimates (machine_id, engine, t, extreme_a, extreme_b, body, codec)",
        7,
        &write.estimates,
        |stmt, i, estimate| {
            stmt.raw_bind_parameter(i, machine_id)?;
            stmt.raw_bind_parameter(i + 1, estimate.engine.as_str())?;
            stmt.raw_bind_parameter(i + 2, estimate.t)?;
            stmt.raw_bind_parameter(i + 3, estimate.extremes[0])?;
            stmt.raw_bind_parameter(i + 4, estimate.extremes[1])?;
            stmt.raw_bind_parameter(i + 5, &estimate.values)?;
            stmt.raw_bind_parameter(i + 6, estimate.codec)
        },
    )?;
    fold_buckets(write, buckets);
    let mut alarms = super::alarms::apply(tx, machine_id, &write.alarms)?;
    if let Some(forwarded) = &write.forwarded {
        alarms.extend(outbox::apply_forwarded(tx, machine_id, forwarded)?);
    }
    outbox::record_alarms(tx, outbox, to_office, machine_id, &alarms)?;
    if let Some(state) = &write.snapshot {
        save_snapshot(tx, write.machine_id, state)?;
    }
    Ok((outcome, alarms))
}

/// Folds a group's bucket extremes into `estimate_buckets`.
fn upsert_buckets(tx: &rusqlite::Transaction, buckets: Buckets) -> Result<(), StoreError> {
    let mut upsert = tx.prepare_cached(
        "INSERT INTO estimate_buckets VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12) \
         ON CONFLICT DO UPDATE SET \
         t_min_a = CASE WHEN excluded.min_a < min_a THEN excluded.t_min_a ELSE t_min_a END, \
         min_a = min(min_a, excluded.min_a), \
         t_max_a = CASE WHEN excluded.max_a > max_a THEN excluded.t_max_a ELSE t_max_a END, \
         max_a = max(max_a, excluded.max_a), \
         t_min_b = CASE WHEN excluded.min_b < min_b THEN excluded.t_min_b ELSE t_min_b END, \
         min_b = min(min_b, excluded.min_b), \
         t_max_b = CASE WHEN excluded.max_b > max_b THEN excluded.t_max_b ELSE t_max_b END, \
         max_b = max(max_b, excluded.max_b)",
    )?;
    for ((machine_id, engine, width_s, bucket), e) in buckets {
        upsert.execute(params![
            machine_id,
            engine.as_str(),
            width_s,
            bucket,
            e.min_a.0,
            e.min_a.1,
            e.max_a.0,
            e.max_a.1,
            e.min_b.0,
            e.min_b.1,
            e.max_b.0,
            e.max_b.1
        ])?;
    }
    Ok(())
}

/// Rows per multi-row `INSERT`: one statement step stores many rows.
pub(super) const ROWS_PER_INSERT: usize = 64;

/// Inserts `rows` with `head` (`INSERT ... (columns)`) followed by
/// `VALUES (?, ...), ...`, [`ROWS_PER_INSERT`] rows per statement; `bind`
/// binds one row's `columns` values from parameter index `i` on. Returns
/// how many rows were inserted (an `OR IGNORE` skips some).
fn insert_rows<T>(
    tx: &rusqlite::Transaction,
    head: &str,
    columns: usize,
    rows: &[T],
    bind: impl Fn(&mut rusqlite::Statement, usize, &T) -> rusqlite::Result<()>,
) -> Result<usize, StoreError> {
    let mut inserted = 0;
    for chunk in rows.chunks(ROWS_PER_INSERT) {
        let row = format!("({})", vec!["?"; columns].join(","));
        let sql = format!("{head} VALUES {}", vec![row; chunk.len()].join(","));
        let mut stmt = tx.prepare_cached(&sql)?;
        for (k, item) in chunk.iter().enumerate() {
            bind(&mut stmt, 1 + k * columns, item)?;
        }
        inserted += stmt.raw_execute()?;
    }
    Ok(inserted)
}

/// Records `state` as the machine's state after every reading stored so far.
fn save_snapshot(
    tx: &rusqlite::Transaction,
    machine_id: i64,
    state: &str,
) -> Result<(), StoreError> {
    let last_reading_id: i64 = tx
        .prepare_cached("SELECT coalesce(max(id), 0) FROM readings WHERE machine_id = ?1")?
        .query_row([machine_id], |row| row.get(0))?;
    tx.prepare_cached(
        "INSERT INTO snapshots (machine_id, last_reading_id, state) VALUES (?1, ?2, ?3) \
         ON CONFLICT (machine_id) DO UPDATE SET last_reading_id = ?2, state = ?3",
    )?
    .execute(params![machine_id, last_reading_id, state])?;
    Ok(())
}

fn apply_put_machine(
    tx: &rusqlite::Transaction,
    spec: &MachineSpec,
    snapshot: &str,
    forwarded: Option<i64>,
    outbox: &OutboxConfig,
) -> Result<i64, StoreError> {
    let json = serde_json::to_string(spec).map_err(|e| StoreError::Corrupt(e.to_string()))?;
    let id: i64 = tx
        .prepare_cached(
            "INSERT INTO machines (machine, spec) VALUES (?1, ?2) \
             ON CONFLICT (machine) DO UPDATE SET spec = ?2 RETURNING id",
        )?
        .query_row(params![spec.id, json], |row| row.get(0))?;
    save_snapshot(tx, id, snapshot)?;
    match forwarded {
        Some(sequence) => outbox::set_mark(tx, id, &[sequence], sequence)?,
        None if outbox.forward => outbox::record_machine(tx, id, &json, snapshot)?,
        None => {}
    }
    Ok(id)
}
