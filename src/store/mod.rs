//! The embedded store: one SQLite file (WAL) in the data dir holding
//! machines, readings, estimates and engine snapshots.
//!
//! One thread owns the writing connection. The rest of the program holds a
//! cheap [`Store`] handle: writes are typed requests sent to that thread,
//! which takes every request waiting in its queue, applies them in one
//! transaction (group commit) and answers each only after the commit.
//! Reads use a small pool of read-only connections (WAL lets them run
//! beside the writer) and are blocking calls: async callers run them with
//! `spawn_blocking`.

pub mod codec;
pub mod queries;
pub mod retention;
pub mod schema;

pub use queries::{BUCKET_WIDTHS_S, EstimatesPage, Extremes};

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use rusqlite::{Connection, OpenFlags, OptionalExtension, params};
use tokio::sync::{mpsc, oneshot};

use crate::config::MachineSpec;
use crate::fusion::{EngineOutput, Reading, SensorKind, StreamKind};

/// The database file inside the data dir.
pub const DB_FILE: &str = "tunnelnav.sqlite3";
/// Most requests committed in one transaction.
const MAX_GROUP: usize = 512;
/// Interval between write-ahead-log checkpoints.
const CHECKPOINT_EVERY: std::time::Duration = std::time::Duration::from_millis(500);
/// Requests waiting for the writer before senders wait (backpressure).
const QUEUE_LEN: usize = 1024;

/// Why the store failed.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database: {0}")]
    Sqlite(#[from] rusqlite::Error),
    #[error("cannot create data dir {path}: {source}")]
    DataDir {
        path: String,
        source: std::io::Error,
    },
    #[error("database schema version {found} is newer than this build supports ({supported})")]
    NewerSchema { found: i64, supported: i64 },
    #[error("the store has shut down")]
    Closed,
    #[error("stored data is corrupt: {0}")]
    Corrupt(String),
    #[error("the machine's engines could not be rebuilt after a failed write ({0})")]
    Unrebuilt(String),
}

impl StoreError {
    /// A failure that may pass: the database busy or locked by another
    /// process, the disk full, an I/O error. The server answers 503 for
    /// these and the client retries.
    pub fn is_transient(&self) -> bool {
        use rusqlite::ErrorCode;
        match self {
            StoreError::Sqlite(rusqlite::Error::SqliteFailure(e, _)) => matches!(
                e.code,
                ErrorCode::DatabaseBusy
                    | ErrorCode::DatabaseLocked
                    | ErrorCode::DiskFull
                    | ErrorCode::SystemIoFailure
                    | ErrorCode::CannotOpen
            ),
            StoreError::Unrebuilt(_) => true,
            _ => false,
        }
    }
}

/// A reading to store: its time, sensor and data.
#[derive(Debug, Clone)]
pub struct ReadingRow {
    pub t: f64,
    pub sensor: SensorKind,
    /// The data, encoded by [`codec::encode_reading`].
    pub data: Vec<u8>,
}

impl ReadingRow {
    /// The row that stores `reading`.
    pub fn new(reading: &Reading) -> ReadingRow {
        ReadingRow {
            t: reading.t,
            sensor: reading.sensor(),
            data: codec::encode_reading(&reading.data),
        }
    }
}

/// An estimate to store.
#[derive(Debug, Clone)]
pub struct EstimateRow {
    pub engine: StreamKind,
    pub t: f64,
    /// The two values whose extremes downsampling keeps.
    pub extremes: [f64; 2],
    /// The values, encoded by [`codec::encode_values`] with the engine's
    /// codec version, `codec`.
    pub values: Vec<u8>,
    pub codec: u32,
}

impl EstimateRow {
    /// The row that stores `output`.
    pub fn new(output: &EngineOutput) -> EstimateRow {
        EstimateRow {
            engine: output.values.stream(),
            t: output.t,
            extremes: output.values.extremes(),
            values: codec::encode_values(&output.values),
            codec: output.values.stream().codec_version(),
        }
    }
}

/// Called once the write it belongs to is committed (`true`) or has failed.
pub type AfterCommit = Box<dyn FnOnce(bool) + Send>;

/// One machine's readings and the estimates and snapshot they led to,
/// committed together.
pub struct Write {
    pub machine_id: i64,
    pub readings: Vec<ReadingRow>,
    pub estimates: Vec<EstimateRow>,
    /// A snapshot of the machine's state after every reading written so far
    /// (including these) arrived.
    pub snapshot: Option<String>,
    /// Runs on the writer thread right after the commit (live broadcast).
    pub after_commit: Option<AfterCommit>,
    pub reply: Option<oneshot::Sender<Result<WriteOutcome, StoreError>>>,
}

/// What a committed [`Write`] stored.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WriteOutcome {
    /// Readings newly stored.
    pub stored: usize,
    /// Readings already stored (same machine, sensor and time): kept once.
    pub duplicates: usize,
}

/// A stored machine.
#[derive(Debug, Clone)]
pub struct StoredMachine {
    pub db_id: i64,
    pub spec: MachineSpec,
}

/// A machine's latest snapshot.
#[derive(Debug, Clone)]
pub struct StoredSnapshot {
    pub last_reading_id: i64,
    pub state: String,
}

/// What the writer's queue carries.
enum Queued {
    Request(Request),
    /// Checkpoint the log into the database and stop writing.
    Close(oneshot::Sender<()>),
}

enum Request {
    Write(Write),
    PutMachine {
        spec: MachineSpec,
        /// The fresh state of the (re)declared machine's engines.
        snapshot: String,
        reply: oneshot::Sender<Result<i64, StoreError>>,
    },
}

/// Cheap, cloneable handle to the store.
#[derive(Clone)]
pub struct Store {
    requests: mpsc::Sender<Queued>,
    readers: Arc<ReadPool>,
    path: PathBuf,
}

impl Store {
    /// Opens (creating and migrating) the database in `data_dir` and starts
    /// the writer thread.
    pub fn open(data_dir: &Path) -> Result<Store, StoreError> {
        Store::open_capped(data_dir, None)
    }

    /// [`Store::open`] with the database file capped at `max_bytes`: beyond
    /// it writes fail as on a full disk (`SQLITE_FULL`), and the server
    /// answers 503 until space is made (retention, a larger cap).
    pub fn open_capped(data_dir: &Path, max_bytes: Option<u64>) -> Result<Store, StoreError> {
        std::fs::create_dir_all(data_dir).map_err(|source| StoreError::DataDir {
            path: data_dir.display().to_string(),
            source,
        })?;
        let path = data_dir.join(DB_FILE);
        let mut conn = Connection::open(&path)?;
        conn.pragma_update(None, "journal_mode", "WAL")?;
        // Every commit is fsynced: an acknowledged reading survives a power
        // cut, not only a crash. Group commit keeps the cost per request low.
        conn.pragma_update(None, "synchronous", "FULL")?;
        conn.pragma_update(None, "foreign_keys", true)?;
        // 64 MiB of page cache: the indexes' hot pages stay in memory.
        conn.pragma_update(None, "cache_size", -65_536)?;
        // Checkpoints run on their own thread (below), not inside commits.
        conn.pragma_update(None, "wal_autocheckpoint", 0)?;
        // A burst can grow the log; once checkpointed it is cut back to this.
        conn.pragma_update(None, "journal_size_limit", 64 * 1024 * 1024)?;
        conn.busy_timeout(std::time::Duration::from_secs(5))?;
        // Multi-row inserts of every length up to ROWS_PER_INSERT stay prepared.
        conn.set_prepared_statement_cache_capacity(2 * ROWS_PER_INSERT + 32);
        schema::migrate(&mut conn)?;
        if let Some(max_bytes) = max_bytes {
            let page_bytes: i64 = conn.query_row("PRAGMA page_size", [], |row| row.get(0))?;
            let pages = (max_bytes as i64 / page_bytes.max(1)).max(1);
            conn.query_row(&format!("PRAGMA max_page_count = {pages}"), [], |_| Ok(()))?;
        }
        let checkpointer = Connection::open(&path)?;
        checkpointer.busy_timeout(std::time::Duration::from_secs(5))?;
        // The writer holds `alive`; the checkpointer stops when it ends.
        let (alive, writer_gone) = std::sync::mpsc::channel::<()>();
        std::thread::Builder::new()
            .name("store-checkpoint".into())
            .spawn(move || checkpoints(checkpointer, writer_gone))
            .map_err(|source| StoreError::DataDir {
                path: data_dir.display().to_string(),
                source,
            })?;
        let (requests, queue) = mpsc::channel(QUEUE_LEN);
        std::thread::Builder::new()
            .name("store-writer".into())
            .spawn(move || {
                writer(conn, queue);
                drop(alive);
            })
            .map_err(|source| StoreError::DataDir {
                path: data_dir.display().to_string(),
                source,
            })?;
        Ok(Store {
            requests,
            readers: Arc::new(ReadPool {
                path: path.clone(),
                idle: Mutex::new(Vec::new()),
            }),
            path,
        })
    }

    /// A plain connection to the database in `data_dir` (created and
    /// migrated if need be), for commands that run beside a server, such
    /// as `tunnelnav token`: WAL lets them share the file.
    pub fn connect(data_dir: &Path) -> Result<Connection, StoreError> {
        std::fs::create_dir_all(data_dir).map_err(|source| StoreError::DataDir {
            path: data_dir.display().to_string(),
            source,
        })?;
        let mut conn = Connection::open(data_dir.join(DB_FILE))?;
        conn.pragma_update(None, "journal_mode", "WAL")?;
        conn.pragma_update(None, "synchronous", "FULL")?;
        conn.busy_timeout(std::time::Duration::from_secs(5))?;
        schema::migrate(&mut conn)?;
        Ok(conn)
    }

    /// The database file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Bytes on disk: the database and its write-ahead log.
    pub fn size_bytes(&self) -> u64 {
        let wal = self.path.with_extension("sqlite3-wal");
        [&self.path, &wal]
            .iter()
            .filter_map(|p| std::fs::metadata(p).ok())
            .map(|m| m.len())
            .sum()
    }

    /// Queues a write; its `reply` is answered after the commit.
    pub async fn write(&self, write: Write) -> Result<(), StoreError> {
        self.requests
            .send(Queued::Request(Request::Write(write)))
            .await
            .map_err(|_| StoreError::Closed)
    }

    /// Commits what is queued, copies the write-ahead log into the database
    /// (so the next start has no log to replay) and stops the writer: later
    /// writes fail with [`StoreError::Closed`]. Reads still work.
    pub async fn close(&self) {
        let (reply, done) = oneshot::channel();
        if self.requests.send(Queued::Close(reply)).await.is_ok() {
            let _ = done.await;
        }
    }

    /// Like [`Store::write`], from a blocking thread.
    pub fn write_blocking(&self, write: Write) -> Result<(), StoreError> {
        self.requests
            .blocking_send(Queued::Request(Request::Write(write)))
            .map_err(|_| StoreError::Closed)
    }

    /// Creates or replaces a machine with a fresh engine snapshot: readings
    /// stored before are kept but not fed to the new engines. Returns its id.
    pub async fn put_machine(
        &self,
        spec: MachineSpec,
        snapshot: String,
    ) -> Result<i64, StoreError> {
        let (reply, answer) = oneshot::channel();
        self.requests
            .send(Queued::Request(Request::PutMachine {
                spec,
                snapshot,
                reply,
            }))
            .await
            .map_err(|_| StoreError::Closed)?;
        answer.await.map_err(|_| StoreError::Closed)?
    }

    /// Runs `f` on a pooled read-only connection (blocking).
    pub fn read<R>(
        &self,
        f: impl FnOnce(&Connection) -> Result<R, StoreError>,
    ) -> Result<R, StoreError> {
        self.readers.with(f)
    }

    /// Every stored machine, its parameters made current (a machine
    /// declared by an earlier release loads with its retired parameters
    /// dropped and new ones at their defaults).
    pub fn machines(&self) -> Result<Vec<StoredMachine>, StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached("SELECT id, spec FROM machines ORDER BY machine")?;
            let rows = stmt.query_map([], |row| {
                Ok((row.get::<_, i64>(0)?, row.get::<_, String>(1)?))
            })?;
            let mut machines = Vec::new();
            for row in rows {
                let (db_id, spec) = row?;
                let spec: MachineSpec = serde_json::from_str(&spec)
                    .map_err(|e| StoreError::Corrupt(format!("machine {db_id} spec: {e}")))?;
                let spec = spec
                    .upgraded()
                    .map_err(|e| StoreError::Corrupt(format!("machine {db_id} spec: {e}")))?;
                machines.push(StoredMachine { db_id, spec });
            }
            Ok(machines)
        })
    }

    /// A machine's latest snapshot.
    pub fn snapshot(&self, machine_id: i64) -> Result<Option<StoredSnapshot>, StoreError> {
        self.read(|conn| {
            Ok(conn
                .prepare_cached(
                    "SELECT last_reading_id, state FROM snapshots WHERE machine_id = ?1",
                )?
                .query_row([machine_id], |row| {
                    Ok(StoredSnapshot {
                        last_reading_id: row.get(0)?,
                        state: row.get(1)?,
                    })
                })
                .optional()?)
        })
    }

    /// Calls `f` with each reading of the machine that arrived after
    /// `after_id`, in arrival order, without holding them all in memory.
    pub fn readings_since(
        &self,
        machine_id: i64,
        after_id: i64,
        mut f: impl FnMut(Reading) -> Result<(), StoreError>,
    ) -> Result<u64, StoreError> {
        self.read(|conn| {
            let mut stmt = conn.prepare_cached(
                "SELECT t, sensor, body FROM readings WHERE machine_id = ?1 AND id > ?2 ORDER BY id",
            )?;
            let mut rows = stmt.query(params![machine_id, after_id])?;
            let mut count = 0;
            while let Some(row) = rows.next()? {
                f(queries::reading_row(row)?)?;
                count += 1;
            }
            Ok(count)
        })
    }
}

/// Copies the write-ahead log back into the database now and then, off
/// the writer's path. A passive checkpoint never blocks the writer; when
/// no reader holds an old snapshot the log is then reused from its start.
/// Ends with the writer.
fn checkpoints(conn: Connection, writer_gone: std::sync::mpsc::Receiver<()>) {
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

/// Read-only connections, opened on demand and reused.
struct ReadPool {
    path: PathBuf,
    idle: Mutex<Vec<Connection>>,
}

impl ReadPool {
    fn with<R>(
        &self,
        f: impl FnOnce(&Connection) -> Result<R, StoreError>,
    ) -> Result<R, StoreError> {
        let pooled = self.idle.lock().ok().and_then(|mut idle| idle.pop());
        let conn = match pooled {
            Some(conn) => conn,
            None => {
                let conn = Connection::open_with_flags(
                    &self.path,
                    OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
                )?;
                conn.busy_timeout(std::time::Duration::from_secs(5))?;
                conn
            }
        };
        let result = f(&conn);
        if let Ok(mut idle) = self.idle.lock() {
            idle.push(conn);
        }
        result
    }
}

/// The writer thread: takes every waiting request, commits them together,
/// then answers each.
fn writer(mut conn: Connection, mut queue: mpsc::Receiver<Queued>) {
    let mut group = Vec::with_capacity(MAX_GROUP);
    let mut close = None;
    while close.is_none() {
        let Some(first) = queue.blocking_recv() else {
            break;
        };
        let mut next = Some(first);
        while let Some(request) = next.take() {
            match request {
                Queued::Close(reply) => close = Some(reply),
                Queued::Request(request) => {
                    group.push(request);
                    if group.len() < MAX_GROUP {
                        next = queue.try_recv().ok();
                    }
                }
            }
        }
        if group.is_empty() {
            continue;
        }
        match apply_group(&mut conn, &group) {
            Ok(outcomes) => {
                for (request, outcome) in group.drain(..).zip(outcomes) {
                    answer(request, Ok(outcome));
                }
            }
            Err(e) => {
                // One bad request must not fail its neighbours: retry each alone.
                tracing::warn!(error = %e, requests = group.len(), "group commit failed; retrying one by one");
                for request in group.drain(..) {
                    let result = apply_group(&mut conn, std::slice::from_ref(&request))
                        .map(|mut outcomes| outcomes.pop().unwrap_or(Outcome::Put(0)));
                    if let Err(e) = &result {
                        tracing::error!(error = %e, "write failed");
                    }
                    answer(request, result);
                }
            }
        }
    }
    // Later sends fail at once; requests already queued are dropped, and
    // their senders see the store closed.
    queue.close();
    // Whether closed or dropped by every handle: leave no log behind.
    if let Err(e) = conn.query_row("PRAGMA wal_checkpoint(TRUNCATE)", [], |_| Ok(())) {
        tracing::warn!(error = %e, "final checkpoint failed");
    }
    if let Some(reply) = close {
        let _ = reply.send(());
    }
}

enum Outcome {
    Write(WriteOutcome),
    Put(i64),
}

fn answer(request: Request, result: Result<Outcome, StoreError>) {
    match request {
        Request::Write(write) => {
            if let Some(after_commit) = write.after_commit {
                after_commit(result.is_ok());
            }
            if let Some(reply) = write.reply {
                let _ = reply.send(result.map(|o| match o {
                    Outcome::Write(w) => w,
                    Outcome::Put(_) => WriteOutcome::default(),
                }));
            }
        }
        Request::PutMachine { reply, .. } => {
            let _ = reply.send(result.map(|o| match o {
                Outcome::Put(id) => id,
                Outcome::Write(_) => 0,
            }));
        }
    }
}

fn apply_group(conn: &mut Connection, group: &[Request]) -> Result<Vec<Outcome>, StoreError> {
    let tx = conn.transaction()?;
    let mut outcomes = Vec::with_capacity(group.len());
    // Bucket extremes of the whole group, upserted once each: with many
    // small writes most of them fall in the same few buckets.
    let mut buckets = Buckets::new();
    for request in group {
        outcomes.push(match request {
            Request::Write(write) => Outcome::Write(apply_write(&tx, write, &mut buckets)?),
            Request::PutMachine { spec, snapshot, .. } => {
                Outcome::Put(apply_put_machine(&tx, spec, snapshot)?)
            }
        });
    }
    upsert_buckets(&tx, buckets)?;
    tx.commit()?;
    Ok(outcomes)
}

/// Extremes per (machine, engine, bucket width, bucket).
type Buckets = BTreeMap<(i64, StreamKind, i64, i64), Extremes>;

fn apply_write(
    tx: &rusqlite::Transaction,
    write: &Write,
    buckets: &mut Buckets,
) -> Result<WriteOutcome, StoreError> {
    let mut outcome = WriteOutcome::default();
    let machine_id = write.machine_id;
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
    // Extremes per stored bucket. A recomputed estimate is the stored one
    // again (same time, same values), so folding it in changes nothing.
    for estimate in &write.estimates {
        let point = Extremes::point(estimate.t, estimate.extremes);
        for width_s in BUCKET_WIDTHS_S {
            let bucket = (estimate.t / width_s as f64).floor() as i64;
            buckets
                .entry((machine_id, estimate.engine, width_s, bucket))
                .and_modify(|b| b.merge(&point))
                .or_insert(point);
        }
    }
    if let Some(state) = &write.snapshot {
        save_snapshot(tx, write.machine_id, state)?;
    }
    Ok(outcome)
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
const ROWS_PER_INSERT: usize = 64;

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
) -> Result<i64, StoreError> {
    let json = serde_json::to_string(spec).map_err(|e| StoreError::Corrupt(e.to_string()))?;
    let id: i64 = tx
        .prepare_cached(
            "INSERT INTO machines (machine, spec) VALUES (?1, ?2) \
             ON CONFLICT (machine) DO UPDATE SET spec = ?2 RETURNING id",
        )?
        .query_row(params![spec.id, json], |row| row.get(0))?;
    save_snapshot(tx, id, snapshot)?;
    Ok(id)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MachineDeclaration;

    fn spec(id: &str) -> MachineSpec {
        serde_json::from_value::<MachineDeclaration>(
            serde_json::json!({"engines": {"attitude": {}}}),
        )
        .unwrap()
        .validate(id)
        .unwrap()
    }

    fn reading(t: f64) -> ReadingRow {
        ReadingRow::new(&Reading {
            t,
            data: crate::fusion::SensorData::Level { height_m: t },
        })
    }

    async fn write(
        store: &Store,
        machine_id: i64,
        readings: Vec<ReadingRow>,
        snapshot: Option<&str>,
    ) -> WriteOutcome {
        let (reply, answer) = oneshot::channel();
        store
            .write(Write {
                machine_id,
                readings,
                estimates: Vec::new(),
                snapshot: snapshot.map(str::to_string),
                after_commit: None,
                reply: Some(reply),
            })
            .await
            .unwrap();
        answer.await.unwrap().unwrap()
    }

    #[tokio::test]
    async fn stores_readings_once_and_snapshots_where_they_stopped() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(dir.path()).unwrap();
        let id = store.put_machine(spec("m1"), "fresh".into()).await.unwrap();
        assert_eq!(store.snapshot(id).unwrap().unwrap().last_reading_id, 0);
        let outcome = write(&store, id, vec![reading(1.0), reading(2.0)], None).await;
        assert_eq!(
            outcome,
            WriteOutcome {
                stored: 2,
                duplicates: 0
            }
        );
        let outcome = write(
            &store,
            id,
            vec![reading(2.0), reading(3.0)],
            Some("after 3"),
        )
        .await;
        assert_eq!(
            outcome,
            WriteOutcome {
                stored: 1,
                duplicates: 1
            }
        );
        let snapshot = store.snapshot(id).unwrap().unwrap();
        assert_eq!(snapshot.state, "after 3");
        write(&store, id, vec![reading(4.0)], None).await;
        let mut after = Vec::new();
        store
            .readings_since(id, snapshot.last_reading_id, |reading| {
                after.push(reading.to_json());
                Ok(())
            })
            .unwrap();
        assert_eq!(after, vec![r#"{"t":4.0,"sensor":"level","height_m":4.0}"#]);
        // Closing leaves no log behind and refuses later writes.
        store.close().await;
        let wal = store.path().with_extension("sqlite3-wal");
        assert_eq!(std::fs::metadata(&wal).map(|m| m.len()).unwrap_or(0), 0);
        let (reply, _answer) = oneshot::channel();
        let late = store
            .write(Write {
                machine_id: id,
                readings: vec![reading(5.0)],
                estimates: Vec::new(),
                snapshot: None,
                after_commit: None,
                reply: Some(reply),
            })
            .await;
        assert!(matches!(late, Err(StoreError::Closed)), "{late:?}");
        // Reopening sees the same machine.
        drop(store);
        let store = Store::open(dir.path()).unwrap();
        let machines = store.machines().unwrap();
        assert_eq!(machines.len(), 1);
        assert_eq!(machines[0].spec, spec("m1"));
    }
}
