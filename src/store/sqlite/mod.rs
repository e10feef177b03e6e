//! The SQLite store: one file (WAL) in the data dir holding machines,
//! readings, estimates and engine snapshots, alarms, tokens and the
//! outbox.
//!
//! One thread owns the writing connection. The rest of the program holds a
//! cheap [`SqliteStore`] handle: writes are typed requests sent to that thread,
//! which takes every request waiting in its queue, applies them in one
//! transaction (group commit) and answers each only after the commit.
//! Reads use a small pool of read-only connections (WAL lets them run
//! beside the writer) and are blocking calls: async callers run them with
//! `spawn_blocking`.

pub mod alarms;
mod backend;
mod handle;
pub mod history;
mod machines;
pub mod outbox;
mod read_pool;
pub mod retention;
pub mod schema;
pub mod tokens;
mod writer;

pub use handle::SqliteStore;

use read_pool::ReadPool;
use writer::checkpoints;

use std::path::Path;
use std::sync::{Arc, Mutex};

use rusqlite::Connection;
use tokio::sync::mpsc;

use super::error::StoreError;
use super::outbox::OutboxConfig;
use super::queue::QUEUE_LEN;

/// The database file inside the data dir.
pub const DB_FILE: &str = "tunnelnav.sqlite3";

/// Who opens the store: the server, or a command beside it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Server,
    Client,
}

/// Page size of a database this release creates. A commit writes every
/// page it dirtied to the WAL, and each machine's rows dirty their own
/// leaf of every machine-keyed B-tree: with 2 KiB pages a group commit of
/// single readings from fifty machines writes half the bytes it did with
/// SQLite's default 4 KiB (1 M single posts: 8 400–9 600 → 10 200–12 700
/// requests/s, docs/evaluation.md). A database made before keeps its
/// pages: SQLite changes an existing database's page size only by
/// `VACUUM`, and this pragma is then a no-op.
const NEW_PAGE_BYTES: i64 = 2048;

/// Sets [`NEW_PAGE_BYTES`] on a connection to a file that may not exist
/// yet (before WAL mode, which fixes the page size).
fn set_new_page_size(conn: &Connection) -> Result<(), StoreError> {
    conn.pragma_update(None, "page_size", NEW_PAGE_BYTES)?;
    Ok(())
}

impl SqliteStore {
    /// Opens (creating and migrating) the database in `data_dir` and starts
    /// the writer thread.
    pub fn open(data_dir: &Path) -> Result<SqliteStore, StoreError> {
        SqliteStore::open_capped(data_dir, None)
    }

    /// [`SqliteStore::open`] with the database file capped at `max_bytes`: beyond
    /// it writes fail as on a full disk (`SQLITE_FULL`), and the server
    /// answers 503 until space is made (retention, a larger cap).
    pub fn open_capped(data_dir: &Path, max_bytes: Option<u64>) -> Result<SqliteStore, StoreError> {
        SqliteStore::open_with(data_dir, max_bytes, OutboxConfig::default())
    }

    /// [`SqliteStore::open_capped`] recording in the outbox what `outbox`
    /// says is owed (to an office, to webhooks).
    pub fn open_with(
        data_dir: &Path,
        max_bytes: Option<u64>,
        outbox: OutboxConfig,
    ) -> Result<SqliteStore, StoreError> {
        SqliteStore::open_as(data_dir, max_bytes, outbox, Role::Server)
    }

    /// The store in `data_dir` for a command beside a running server
    /// (`tunnelnav token`): its writes go through a writer of its own, as
    /// the server's do, but it leaves the write-ahead log to the server —
    /// no checkpoints, none when it ends — so it never waits for the
    /// server's readers or makes the server's commits wait.
    pub fn open_client(data_dir: &Path) -> Result<SqliteStore, StoreError> {
        SqliteStore::open_as(data_dir, None, OutboxConfig::default(), Role::Client)
    }

    fn open_as(
        data_dir: &Path,
        max_bytes: Option<u64>,
        outbox: OutboxConfig,
        role: Role,
    ) -> Result<SqliteStore, StoreError> {
        std::fs::create_dir_all(data_dir).map_err(|source| StoreError::DataDir {
            path: data_dir.display().to_string(),
            source,
        })?;
        let path = data_dir.join(DB_FILE);
        let mut conn = Connection::open(&path)?;
        set_new_page_size(&conn)?;
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
        conn.set_prepared_statement_cache_capacity(2 * writer::ROWS_PER_INSERT + 32);
        schema::migrate(&mut conn)?;
        if let Some(max_bytes) = max_bytes {
            let page_bytes: i64 = conn.query_row("PRAGMA page_size", [], |row| row.get(0))?;
            let pages = (max_bytes as i64 / page_bytes.max(1)).max(1);
            conn.query_row(&format!("PRAGMA max_page_count = {pages}"), [], |_| Ok(()))?;
        }
        // The writer holds `alive`; the checkpointer stops when it ends.
        let (alive, writer_gone) = std::sync::mpsc::channel::<()>();
        if role == Role::Server {
            let checkpointer = Connection::open(&path)?;
            checkpointer.busy_timeout(std::time::Duration::from_secs(5))?;
            std::thread::Builder::new()
                .name("store-checkpoint".into())
                .spawn(move || checkpoints(checkpointer, writer_gone))
                .map_err(|source| StoreError::DataDir {
                    path: data_dir.display().to_string(),
                    source,
                })?;
        }
        let (requests, queue) = mpsc::channel(QUEUE_LEN);
        let final_checkpoint = role == Role::Server;
        std::thread::Builder::new()
            .name("store-writer".into())
            .spawn(move || {
                writer::writer(conn, queue, outbox, final_checkpoint);
                drop(alive);
            })
            .map_err(|source| StoreError::DataDir {
                path: data_dir.display().to_string(),
                source,
            })?;
        Ok(SqliteStore {
            requests,
            readers: Arc::new(ReadPool {
                path: path.clone(),
                idle: Mutex::new(Vec::new()),
            }),
            path,
            outbox,
        })
    }

    /// A plain connection to the database in `data_dir` (created and
    /// migrated if need be), for commands that run beside a server, such
    /// as `tunnelnav site` and `backup`: WAL lets them share the file.
    pub fn connect(data_dir: &Path) -> Result<Connection, StoreError> {
        std::fs::create_dir_all(data_dir).map_err(|source| StoreError::DataDir {
            path: data_dir.display().to_string(),
            source,
        })?;
        let mut conn = Connection::open(data_dir.join(DB_FILE))?;
        set_new_page_size(&conn)?;
        conn.pragma_update(None, "journal_mode", "WAL")?;
        conn.pragma_update(None, "synchronous", "FULL")?;
        conn.busy_timeout(std::time::Duration::from_secs(5))?;
        schema::migrate(&mut conn)?;
        Ok(conn)
    }
}

#[cfg(test)]
mod tests {
    use tokio::sync::oneshot;

    use super::*;
    use crate::config::{MachineDeclaration, MachineSpec};
    use crate::fusion::Reading;
    use crate::store::{ReadingRow, Store, Write, WriteOutcome};

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
                alarms: Vec::new(),
                readings,
                estimates: Vec::new(),
                snapshot: snapshot.map(str::to_string),
                after_commit: None,
                reply: Some(reply),
                lease_epoch: None,
                forwarded: None,
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
        let wal = store.sqlite().unwrap().path().with_extension("sqlite3-wal");
        assert_eq!(std::fs::metadata(&wal).map(|m| m.len()).unwrap_or(0), 0);
        let (reply, _answer) = oneshot::channel();
        let late = store
            .write(Write {
                machine_id: id,
                alarms: Vec::new(),
                readings: vec![reading(5.0)],
                estimates: Vec::new(),
                snapshot: None,
                after_commit: None,
                reply: Some(reply),
                lease_epoch: None,
                forwarded: None,
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
