//! A PostgreSQL writer: a task and its connection that take every
//! request waiting in its queue, apply them in one transaction (group
//! commit) and answer each only after the commit — the SQLite writer's
//! semantics (`store/sqlite/writer.rs`), in SQL that moves a whole write in a few
//! statements (arrays unnested server-side).

use std::collections::BTreeSet;
use std::sync::{Arc, OnceLock};

use tokio::sync::mpsc;
use tokio_postgres::binary_copy::BinaryCopyInWriter;
use tokio_postgres::error::SqlState;
use tokio_postgres::types::{ToSql, Type};
use tokio_postgres::{Client, Transaction};

use super::connect::{Endpoint, connect_writer};
use super::handle::Job;
use super::schema;
use crate::config::MachineSpec;
use crate::store::alarms::{AlarmChange, AlarmRow, Change, StoredAlarm};
use crate::store::error::StoreError;
use crate::store::outbox::{Forwarded, OutboxConfig};
use crate::store::queue::MAX_GROUP;
use crate::store::queue::{Buckets, Outcome, Queued, Request, answer, fold_buckets, gather};
use crate::store::rows::Write;
use crate::store::rows::WriteOutcome;

/// The writer task: takes every waiting request, commits them together,
/// then answers each. A lost connection is made again (with `config`)
/// before the next group; while it cannot be, each group is answered
/// with the reason (transient: the server answers 503). Ends when closed
/// or when every handle is gone.
pub(super) async fn writer(
    mut client: Client,
    endpoint: Endpoint,
    mut queue: mpsc::Receiver<Queued<Job>>,
    fence: Arc<OnceLock<String>>,
    outbox: Arc<OnceLock<OutboxConfig>>,
) {
    let mut partitions = match schema::partitions(&client).await {
        Ok(found) => found.into_iter().collect::<BTreeSet<_>>(),
        Err(e) => {
            tracing::error!(error = %e, "cannot list the partitions; making them as needed");
            BTreeSet::new()
        }
    };
    let mut group = Vec::with_capacity(MAX_GROUP);
    let mut close = None;
    while close.is_none() {
        let Some(first) = queue.recv().await else {
            break;
        };
        let job;
        (job, close) = gather(first, &mut queue, &mut group);
        if client.is_closed() {
            match connect_writer(&endpoint).await {
                Ok(fresh) => {
                    tracing::info!("PostgreSQL connection made again");
                    client = fresh;
                }
                Err(e) => {
                    tracing::warn!(error = %e, "PostgreSQL unreachable");
                    for request in group.drain(..) {
                        answer(request, Err(StoreError::Unavailable(e.to_string())));
                    }
                    // A job runs on the closed connection and fails with
                    // it (transient), answering its caller.
                    if let Some(job) = job {
                        job(&mut client).await;
                    }
                    continue;
                }
            }
        }
        let outbox = outbox.get().copied().unwrap_or_default();
        commit(
            &mut client,
            &mut partitions,
            &mut group,
            fence.get(),
            &outbox,
        )
        .await;
        if let Some(job) = job {
            job(&mut client).await;
            // A job may drop partitions (retention): know them afresh.
            if let Ok(found) = schema::partitions(&client).await {
                partitions = found.into_iter().collect();
            }
        }
    }
    queue.close();
    if let Some(reply) = close {
        let _ = reply.send(());
    }
}

/// Commits `group` in one transaction and answers each request (emptying
/// the group); if the transaction fails, each request alone.
async fn commit(
    client: &mut Client,
    partitions: &mut BTreeSet<(String, i64)>,
    group: &mut Vec<Request>,
    node: Option<&String>,
    outbox: &OutboxConfig,
) {
    if group.is_empty() {
        return;
    }
    let result = match ensure_partitions(client, partitions, group).await {
        Ok(()) => apply_group(client, group, node, outbox).await,
        Err(e) => Err(e),
    };
    match result {
        Ok(outcomes) => {
            for (request, outcome) in group.drain(..).zip(outcomes) {
                answer(request, Ok(outcome));
            }
        }
        Err(e) => {
            tracing::warn!(error = %e, requests = group.len(), "group commit failed; retrying one by one");
            // A partition may have gone (another node's retention): the
            // retries make what they need again.
            partitions.clear();
            for request in group.drain(..) {
                let alone = std::slice::from_ref(&request);
                let result = match ensure_partitions(client, partitions, alone).await {
                    Ok(()) => apply_group(client, alone, node, outbox)
                        .await
                        .map(|mut outcomes| outcomes.pop().unwrap_or(Outcome::Put(0))),
                    Err(e) => Err(e),
                };
                if let Err(e) = &result {
                    tracing::error!(error = %e, "write failed");
                }
                answer(request, result);
            }
        }
    }
}

/// Makes the day partitions the group's rows fall in, each in its own
/// short transaction before the group's (a partition is made once).
async fn ensure_partitions(
    client: &Client,
    known: &mut BTreeSet<(String, i64)>,
    group: &[Request],
) -> Result<(), StoreError> {
    let mut needed = BTreeSet::new();
    for request in group {
        if let Request::Write(write) = request {
            for reading in &write.readings {
                needed.insert(("readings", schema::partition("readings", reading.t).0));
            }
            for estimate in &write.estimates {
                needed.insert(("estimates", schema::partition("estimates", estimate.t).0));
            }
        }
    }
    for (table, day) in needed {
        let key = (table.to_string(), day);
        if !known.contains(&key) {
            schema::create_partition(client, table, day).await?;
            known.insert(key);
        }
    }
    Ok(())
}

async fn apply_group(
    client: &mut Client,
    group: &[Request],
    node: Option<&String>,
    outbox: &OutboxConfig,
) -> Result<Vec<Outcome>, StoreError> {
    let mut tx = client.transaction().await?;
    let writes = || {
        group.iter().filter_map(|request| match request {
            Request::Write(write) => Some(write),
            Request::PutMachine { .. } => None,
        })
    };
    if let Some(node) = node {
        check_leases(
            &tx,
            node,
            writes().map(|w| (w.machine_id, w.lease_epoch)).collect(),
        )
        .await?;
    }
    let copied = Copied {
        readings: copy_readings(&mut tx, writes()).await?,
        estimates: copy_estimates(&mut tx, writes()).await?,
    };
    let mut outcomes = Vec::with_capacity(group.len());
    let mut buckets = Buckets::new();
    for request in group {
        outcomes.push(match request {
            Request::Write(write) => {
                let (outcome, alarms) = apply_write(&tx, write, copied, &mut buckets).await?;
                if let Some(node) = node {
                    for change in &alarms {
                        super::cluster::notify_alarm(&tx, node, change).await?;
                    }
                    record_webhooks(&tx, outbox, node, write.machine_id, &alarms).await?;
                }
                Outcome::Write(outcome, alarms)
            }
            Request::PutMachine {
                spec,
                snapshot,
                forwarded,
                ..
            } => {
                let id = apply_put_machine(&tx, spec, snapshot, node).await?;
                if let Some(sequence) = forwarded {
                    set_mark(&tx, id, &[*sequence], *sequence).await?;
                }
                Outcome::Put(id)
            }
        });
    }
    upsert_buckets(&tx, buckets).await?;
    if node.is_some() {
        // Live sockets on the other nodes fetch what this commit adds.
        let with_estimates: BTreeSet<i64> = writes()
            .filter(|w| !w.estimates.is_empty())
            .map(|w| w.machine_id)
            .collect();
        super::cluster::notify_estimates(&tx, with_estimates).await?;
    }
    tx.commit().await?;
    Ok(outcomes)
}

/// Records the alarm changes a commit made that a webhook is owed, as
/// this node's to post (`store/outbox.rs` does the same on SQLite).
pub(super) async fn record_webhooks(
    tx: &Transaction<'_>,
    outbox: &OutboxConfig,
    node: &str,
    machine_id: i64,
    changes: &[AlarmChange],
) -> Result<(), StoreError> {
    for change in changes.iter().filter(|c| outbox.webhook(&c.alarm.severity)) {
        let body = serde_json::to_string(change)
            .map_err(|e| StoreError::Corrupt(format!("outbox body: {e}")))?;
        tx.execute(
            "INSERT INTO outbox (node, kind, machine_id, body, created_t) VALUES ($1, $2, $3, $4, $5)",
            &[
                &node,
                &change.alarm.severity,
                &machine_id,
                &body,
                &crate::clock::wall_clock_s(),
            ],
        )
        .await?;
    }
    Ok(())
}

/// Fails unless `node` holds the lease of every machine written, in
/// force and with the epoch the write was made under, and keeps those
/// leases from changing hands until this transaction ends (`FOR KEY
/// SHARE`: a taking locks the row `FOR UPDATE` first and waits; a renewal
/// changes no key and does not). A node that lost a machine, or took it
/// anew after a lapse, stores nothing its earlier run still had queued.
async fn check_leases(
    tx: &Transaction<'_>,
    node: &str,
    wanted: BTreeSet<(i64, Option<i64>)>,
) -> Result<(), StoreError> {
    if wanted.is_empty() {
        return Ok(());
    }
    let ids: Vec<i64> = wanted.iter().map(|&(id, _)| id).collect();
    let held: std::collections::BTreeMap<i64, i64> = tx
        .query(
            "SELECT machine_id, epoch FROM leases WHERE node = $1 AND machine_id = ANY($2) \
             AND expires_at > now() FOR KEY SHARE",
            &[&node, &ids],
        )
        .await?
        .iter()
        .map(|row| (row.get(0), row.get(1)))
        .collect();
    for (id, epoch) in wanted {
        if epoch.is_none() || held.get(&id).copied() != epoch {
            return Err(StoreError::Unavailable(format!(
                "machine {id} is no longer fused by node `{node}` under this lease: it lapsed \
                 or moved"
            )));
        }
    }
    Ok(())
}

/// A group's rows below this go in by `INSERT` alone: a `COPY` and its
/// savepoint cost more round trips than they save.
const COPY_FROM_ROWS: usize = 64;

/// Which of a group's rows its `COPY`s already stored (all of that kind).
#[derive(Clone, Copy)]
struct Copied {
    readings: bool,
    estimates: bool,
}

/// Stores every reading of the group's writes by one binary `COPY`, in
/// their order (the ids are the arrival order), if none is already
/// stored; `false` (nothing stored, the transaction usable) when one is,
/// or when the group is small: each write then goes in by `INSERT ... ON
/// CONFLICT DO NOTHING`, stored once.
async fn copy_readings<'w>(
    tx: &mut Transaction<'_>,
    writes: impl Iterator<Item = &'w Write> + Clone,
) -> Result<bool, StoreError> {
    let rows: usize = writes.clone().map(|w| w.readings.len()).sum();
    if rows < COPY_FROM_ROWS {
        return Ok(false);
    }
    let savepoint = tx.savepoint("copy_readings").await?;
    let sink = savepoint
        .copy_in("COPY readings (machine_id, t, sensor, body) FROM STDIN (FORMAT binary)")
        .await?;
    let types = [Type::INT8, Type::FLOAT8, Type::INT2, Type::BYTEA];
    let copied = async {
        let mut copy = std::pin::pin!(BinaryCopyInWriter::new(sink, &types));
        for write in writes {
            for reading in &write.readings {
                let sensor = reading.sensor as i16;
                let row: [&(dyn ToSql + Sync); 4] = [
                    &write.machine_id,
                    &reading.t,
                    &sensor,
                    &reading.data.as_slice(),
                ];
                copy.as_mut().write(&row).await?;
            }
        }
        copy.finish().await.map(|_| ())
    };
    settle(savepoint, copied.await).await
}

/// [`copy_readings`] for the group's estimates: `false` when one is
/// already stored (recomputed after a restart) or the group is small.
async fn copy_estimates<'w>(
    tx: &mut Transaction<'_>,
    writes: impl Iterator<Item = &'w Write> + Clone,
) -> Result<bool, StoreError> {
    let rows: usize = writes.clone().map(|w| w.estimates.len()).sum();
    if rows < COPY_FROM_ROWS {
        return Ok(false);
    }
    let savepoint = tx.savepoint("copy_estimates").await?;
    let sink = savepoint
        .copy_in(
            "COPY estimates (machine_id, engine, t, extreme_a, extreme_b, body, codec) \
             FROM STDIN (FORMAT binary)",
        )
        .await?;
    let types = [
        Type::INT8,
        Type::TEXT,
        Type::FLOAT8,
        Type::FLOAT8,
        Type::FLOAT8,
        Type::BYTEA,
        Type::INT4,
    ];
    let copied = async {
        let mut copy = std::pin::pin!(BinaryCopyInWriter::new(sink, &types));
        for write in writes {
            for estimate in &write.estimates {
                let codec = estimate.codec as i32;
                let row: [&(dyn ToSql + Sync); 7] = [
                    &write.machine_id,
                    &estimate.engine.as_str(),
                    &estimate.t,
                    &estimate.extremes[0],
                    &estimate.extremes[1],
                    &estimate.values.as_slice(),
                    &codec,
                ];
                copy.as_mut().write(&row).await?;
            }
        }
        copy.finish().await.map(|_| ())
    };
    settle(savepoint, copied.await).await
}

/// Ends a `COPY`'s savepoint: kept if it stored everything, rolled back
/// (`false`) if a row was already there; any other error is the group's.
async fn settle(
    savepoint: Transaction<'_>,
    copied: Result<(), tokio_postgres::Error>,
) -> Result<bool, StoreError> {
    match copied {
        Ok(()) => {
            savepoint.commit().await?;
            Ok(true)
        }
        Err(e) if e.code() == Some(&SqlState::UNIQUE_VIOLATION) => {
            savepoint.rollback().await?;
            Ok(false)
        }
        Err(e) => Err(e.into()),
    }
}

async fn apply_write(
    tx: &Transaction<'_>,
    write: &Write,
    copied: Copied,
    buckets: &mut Buckets,
) -> Result<(WriteOutcome, Vec<AlarmChange>), StoreError> {
    let machine_id = write.machine_id;
    let mut outcome = WriteOutcome::default();
    if copied.readings {
        outcome.stored = write.readings.len();
    } else if !write.readings.is_empty() {
        let t: Vec<f64> = write.readings.iter().map(|r| r.t).collect();
        let sensor: Vec<i16> = write.readings.iter().map(|r| r.sensor as i16).collect();
        let body: Vec<&[u8]> = write.readings.iter().map(|r| r.data.as_slice()).collect();
        // In the order given: the ids are the arrival order.
        let stored = tx
            .execute(
                "INSERT INTO readings (machine_id, t, sensor, body) \
                 SELECT $1, r.t, r.sensor, r.body \
                 FROM unnest($2::float8[], $3::int2[], $4::bytea[]) WITH ORDINALITY AS r(t, sensor, body, n) \
                 ORDER BY r.n ON CONFLICT DO NOTHING",
                &[&machine_id, &t, &sensor, &body],
            )
            .await? as usize;
        outcome.stored = stored;
        outcome.duplicates = write.readings.len() - stored;
    }
    if !copied.estimates && !write.estimates.is_empty() {
        let engine: Vec<&str> = write.estimates.iter().map(|e| e.engine.as_str()).collect();
        let t: Vec<f64> = write.estimates.iter().map(|e| e.t).collect();
        let a: Vec<f64> = write.estimates.iter().map(|e| e.extremes[0]).collect();
        let b: Vec<f64> = write.estimates.iter().map(|e| e.extremes[1]).collect();
        let body: Vec<&[u8]> = write
            .estimates
            .iter()
            .map(|e| e.values.as_slice())
            .collect();
        let codec: Vec<i32> = write.estimates.iter().map(|e| e.codec as i32).collect();
        // Estimates are a function of the readings: one recomputed after a
        // restart is the same estimate, stored once.
        tx.execute(
            "INSERT INTO estimates (machine_id, engine, t, extreme_a, extreme_b, body, codec) \
             SELECT $1, e.* FROM unnest($2::text[], $3::float8[], $4::float8[], $5::float8[], \
             $6::bytea[], $7::int4[]) AS e ON CONFLICT DO NOTHING",
            &[&machine_id, &engine, &t, &a, &b, &body, &codec],
        )
        .await?;
    }
    fold_buckets(write, buckets);
    let mut alarms = apply_alarms(tx, machine_id, &write.alarms).await?;
    if let Some(forwarded) = &write.forwarded {
        alarms.extend(apply_forwarded(tx, machine_id, forwarded).await?);
    }
    if let Some(state) = &write.snapshot {
        save_snapshot(tx, machine_id, state).await?;
    }
    Ok((outcome, alarms))
}

/// Folds a group's bucket extremes into `estimate_buckets`, in one statement.
async fn upsert_buckets(tx: &Transaction<'_>, buckets: Buckets) -> Result<(), StoreError> {
    if buckets.is_empty() {
        return Ok(());
    }
    let mut columns: [Vec<f64>; 8] = Default::default();
    let (mut machine, mut engine, mut width, mut bucket) = (vec![], vec![], vec![], vec![]);
    for ((machine_id, stream, width_s, number), e) in buckets {
        machine.push(machine_id);
        engine.push(stream.as_str());
        width.push(width_s);
        bucket.push(number);
        let values = [
            e.min_a.0, e.min_a.1, e.max_a.0, e.max_a.1, e.min_b.0, e.min_b.1, e.max_b.0, e.max_b.1,
        ];
        for (column, value) in columns.iter_mut().zip(values) {
            column.push(value);
        }
    }
    let [
        min_a,
        t_min_a,
        max_a,
        t_max_a,
        min_b,
        t_min_b,
        max_b,
        t_max_b,
    ] = &columns;
    tx.execute(
        "INSERT INTO estimate_buckets AS old \
         SELECT * FROM unnest($1::int8[], $2::text[], $3::int8[], $4::int8[], $5::float8[], \
         $6::float8[], $7::float8[], $8::float8[], $9::float8[], $10::float8[], $11::float8[], \
         $12::float8[]) \
         ON CONFLICT (machine_id, engine, width_s, bucket) DO UPDATE SET \
         t_min_a = CASE WHEN excluded.min_a < old.min_a THEN excluded.t_min_a ELSE old.t_min_a END, \
         min_a = least(old.min_a, excluded.min_a), \
         t_max_a = CASE WHEN excluded.max_a > old.max_a THEN excluded.t_max_a ELSE old.t_max_a END, \
         max_a = greatest(old.max_a, excluded.max_a), \
         t_min_b = CASE WHEN excluded.min_b < old.min_b THEN excluded.t_min_b ELSE old.t_min_b END, \
         min_b = least(old.min_b, excluded.min_b), \
         t_max_b = CASE WHEN excluded.max_b > old.max_b THEN excluded.t_max_b ELSE old.t_max_b END, \
         max_b = greatest(old.max_b, excluded.max_b)",
        &[
            &machine, &engine, &width, &bucket, min_a, t_min_a, max_a, t_max_a, min_b, t_min_b,
            max_b, t_max_b,
        ],
    )
    .await?;
    Ok(())
}

/// Writes alarm transitions as `store/alarms.rs` does: a raise inserts
/// (once), a clear closes the open alarm of its key. Returns the alarms
/// that changed, each as this row left it.
async fn apply_alarms(
    tx: &Transaction<'_>,
    machine_id: i64,
    rows: &[AlarmRow],
) -> Result<Vec<AlarmChange>, StoreError> {
    let mut changed = Vec::new();
    for row in rows {
        let (transition, ids): (Change, Vec<i64>) = if row.raised {
            let inserted = tx
                .query(
                    "INSERT INTO alarms (machine_id, kind, severity, subject, message, raised_t) \
                     VALUES ($1, $2, $3, $4, $5, $6) ON CONFLICT DO NOTHING RETURNING id",
                    &[
                        &machine_id,
                        &row.kind,
                        &row.severity,
                        &row.subject,
                        &row.message,
                        &row.t,
                    ],
                )
                .await?;
            (Change::Raised, inserted.iter().map(|r| r.get(0)).collect())
        } else {
            let cleared = tx
                .query(
                    "UPDATE alarms SET cleared_t = $5 WHERE machine_id = $1 AND kind = $2 \
                     AND severity = $3 AND subject = $4 AND cleared_t IS NULL AND raised_t <= $5 \
                     RETURNING id",
                    &[&machine_id, &row.kind, &row.severity, &row.subject, &row.t],
                )
                .await?;
            (Change::Cleared, cleared.iter().map(|r| r.get(0)).collect())
        };
        for id in ids {
            if let Some(alarm) = super::alarms::alarm_by_id(tx, id).await? {
                changed.push(AlarmChange { transition, alarm });
            }
        }
    }
    Ok(changed)
}

/// An office: applies a forwarded write's acknowledgements (by the
/// alarm's natural key) and moves the machine's mark if it is still where
/// the write expects it, as `store/outbox.rs` does.
async fn apply_forwarded(
    tx: &Transaction<'_>,
    machine_id: i64,
    forwarded: &Forwarded,
) -> Result<Vec<AlarmChange>, StoreError> {
    let stored: Option<i64> = tx
        .query_opt(
            "SELECT sequence FROM forward_marks WHERE machine_id = $1 FOR UPDATE",
            &[&machine_id],
        )
        .await?
        .map(|row| row.get(0));
    if stored != forwarded.after {
        return Err(crate::store::outbox::mark_moved(
            machine_id,
            stored,
            forwarded.after,
        ));
    }
    let mut changed = Vec::new();
    for ack in &forwarded.acks {
        let ids = tx
            .query(
                "UPDATE alarms SET acked_t = $6, acked_by = $7 WHERE machine_id = $1 AND kind = $2 \
                 AND severity = $3 AND subject = $4 AND raised_t = $5 AND acked_t IS NULL \
                 RETURNING id",
                &[
                    &machine_id,
                    &ack.kind,
                    &ack.severity,
                    &ack.subject,
                    &ack.raised_t,
                    &ack.acked_t,
                    &ack.by,
                ],
            )
            .await?;
        for row in ids {
            if let Some(alarm) = super::alarms::alarm_by_id(tx, row.get(0)).await? {
                changed.push(AlarmChange {
                    transition: Change::Acknowledged,
                    alarm,
                });
            }
        }
    }
    set_mark(tx, machine_id, &forwarded.applied, forwarded.sequence).await?;
    if let Some(confirmed) = forwarded.confirmed {
        tx.execute(
            "DELETE FROM forward_applied WHERE machine_id = $1 AND sequence <= $2",
            &[&machine_id, &confirmed],
        )
        .await?;
    }
    Ok(changed)
}

/// An office: a forwarded machine's mark is `sequence` (never lowered
/// here), and it holds the rows `applied`.
async fn set_mark(
    tx: &Transaction<'_>,
    machine_id: i64,
    applied: &[i64],
    sequence: i64,
) -> Result<(), StoreError> {
    tx.execute(
        "INSERT INTO forward_applied (machine_id, sequence) SELECT $1, unnest($2::bigint[]) \
         ON CONFLICT DO NOTHING",
        &[&machine_id, &applied],
    )
    .await?;
    tx.execute(
        "INSERT INTO forward_marks (machine_id, sequence) VALUES ($1, $2) \
         ON CONFLICT (machine_id) DO UPDATE SET sequence = greatest(forward_marks.sequence, $2)",
        &[&machine_id, &sequence],
    )
    .await?;
    Ok(())
}

/// Records `state` as the machine's state after every reading stored so far.
async fn save_snapshot(
    tx: &Transaction<'_>,
    machine_id: i64,
    state: &str,
) -> Result<(), StoreError> {
    tx.execute(
        "INSERT INTO snapshots (machine_id, last_reading_id, state) \
         SELECT $1, coalesce(max(id), 0), $2 FROM readings WHERE machine_id = $1 \
         ON CONFLICT (machine_id) DO UPDATE SET last_reading_id = excluded.last_reading_id, \
         state = excluded.state",
        &[&machine_id, &state],
    )
    .await?;
    Ok(())
}

async fn apply_put_machine(
    tx: &Transaction<'_>,
    spec: &MachineSpec,
    snapshot: &str,
    node: Option<&String>,
) -> Result<i64, StoreError> {
    // Several nodes: a machine another node runs is declared there (its
    // state is not reset from here).
    if let Some(node) = node {
        let elsewhere: Option<String> = tx
            .query_opt(
                "SELECT l.node FROM leases l JOIN machines m ON m.id = l.machine_id \
                 WHERE m.machine = $1 AND l.node <> $2 AND l.expires_at > now() FOR KEY SHARE",
                &[&spec.id, node],
            )
            .await?
            .map(|row| row.get(0));
        if let Some(other) = elsewhere {
            return Err(StoreError::Unavailable(format!(
                "machine `{}` is fused by node `{other}`: declare it there",
                spec.id
            )));
        }
    }
    let json = serde_json::to_string(spec).map_err(|e| StoreError::Corrupt(e.to_string()))?;
    let id: i64 = tx
        .query_one(
            "INSERT INTO machines (machine, spec) VALUES ($1, $2) \
             ON CONFLICT (machine) DO UPDATE SET spec = excluded.spec RETURNING id",
            &[&spec.id, &json],
        )
        .await?
        .get(0);
    save_snapshot(tx, id, snapshot).await?;
    Ok(id)
}

/// A stored alarm from a row of `ALARM_COLUMNS` (`alarms.rs`).
pub(super) fn stored_alarm(row: &tokio_postgres::Row) -> StoredAlarm {
    StoredAlarm {
        id: row.get(0),
        machine: row.get(1),
        kind: row.get(2),
        severity: row.get(3),
        subject: row.get(4),
        message: row.get(5),
        raised_t: row.get(6),
        cleared_t: row.get(7),
        acked_t: row.get(8),
        acked_by: row.get(9),
        now: None,
    }
}
