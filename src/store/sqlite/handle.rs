//! [`SqliteStore`]: the cheap handle to the SQLite store — writes sent to
//! the writer thread, reads on the pool, maintenance jobs run between
//! group commits. Opening it is `mod.rs`'s.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rusqlite::Connection;
use tokio::sync::{mpsc, oneshot};

use super::read_pool::ReadPool;
use crate::config::MachineSpec;
use crate::store::error::StoreError;
use crate::store::outbox::OutboxConfig;
use crate::store::queue::{Queued, Request};
use crate::store::rows::Write;

/// A job for the writing connection (see [`SqliteStore::maintain`]).
pub(super) type Job = Box<dyn FnOnce(&mut Connection) + Send>;

/// Cheap, cloneable handle to the store.
#[derive(Clone)]
pub struct SqliteStore {
    pub(super) requests: mpsc::Sender<Queued<Job>>,
    pub(super) readers: Arc<ReadPool>,
    pub(super) path: PathBuf,
    /// What the writer records in the outbox.
    pub(super) outbox: OutboxConfig,
}

impl SqliteStore {
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

    /// Like [`SqliteStore::write`], from a blocking thread.
    pub fn write_blocking(&self, write: Write) -> Result<(), StoreError> {
        self.requests
            .blocking_send(Queued::Request(Request::Write(write)))
            .map_err(|_| StoreError::Closed)
    }

    /// Creates or replaces a machine with a fresh engine snapshot: readings
    /// stored before are kept but not fed to the new engines. Returns its id.
    /// An office stores a forwarded machine's declaration with the site's
    /// sequence of it (`forwarded`).
    pub async fn put_machine(
        &self,
        spec: MachineSpec,
        snapshot: String,
        forwarded: Option<i64>,
    ) -> Result<i64, StoreError> {
        let (reply, answer) = oneshot::channel();
        self.requests
            .send(Queued::Request(Request::PutMachine {
                spec: Box::new(spec),
                snapshot,
                forwarded,
                reply,
            }))
            .await
            .map_err(|_| StoreError::Closed)?;
        answer.await.map_err(|_| StoreError::Closed)?
    }

    /// Runs `f` on the writing connection, in the writer thread between
    /// two group commits: maintenance (retention) that must not contend
    /// with the writer for the database lock. Keep `f` short: ingest waits
    /// for it.
    pub async fn maintain<R: Send + 'static>(
        &self,
        f: impl FnOnce(&mut Connection) -> Result<R, StoreError> + Send + 'static,
    ) -> Result<R, StoreError> {
        let (reply, answer) = oneshot::channel();
        let job: Job = Box::new(move |conn| {
            let _ = reply.send(f(conn));
        });
        self.requests
            .send(Queued::Job(job))
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
}
