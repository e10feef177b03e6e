//! [`PgStore`]: the cheap handle to the PostgreSQL store — writes sent to
//! the writer tasks, reads on the pool, maintenance jobs run between group
//! commits, the node's membership. Opening it is `mod.rs`'s.

use std::sync::Arc;

use deadpool_postgres::Pool;
use tokio::sync::{mpsc, oneshot};
use tokio_postgres::Client;

use super::cluster;
use super::connect::Endpoint;
use crate::store::error::StoreError;
use crate::store::queue::{Queued, Request};
use crate::store::rows::Write;

/// Work on the writer's connection between two group commits
/// (acknowledgements, retention), so it is ordered with the commits.
pub(super) type Job =
    Box<dyn for<'c> FnOnce(&'c mut Client) -> futures_util::future::BoxFuture<'c, ()> + Send>;

/// Cheap, cloneable handle to the PostgreSQL store.
#[derive(Clone)]
pub struct PgStore {
    /// The writers' queues: a machine's writes go to one of them (by its
    /// id), jobs and declarations to the first.
    pub(super) writers: Arc<[mpsc::Sender<Queued<Job>>]>,
    pub(super) endpoint: Arc<Endpoint>,
    /// Set when this store serves a node of several: the node's name. The
    /// writers then commit a machine's rows only while the node holds its
    /// lease.
    pub(super) fence: Arc<std::sync::OnceLock<String>>,
    /// What the writers record in the outbox (the webhooks' changes), set
    /// once by the server before it writes.
    pub(super) outbox: Arc<std::sync::OnceLock<crate::store::outbox::OutboxConfig>>,
    pub(super) readers: Pool,
    pub(super) runtime: tokio::runtime::Handle,
}

impl PgStore {
    /// Queues a write; its `reply` is answered after the commit.
    pub async fn write(&self, write: Write) -> Result<(), StoreError> {
        self.writer_of(write.machine_id)
            .send(Queued::Request(Request::Write(write)))
            .await
            .map_err(|_| StoreError::Closed)
    }

    /// Like [`PgStore::write`], from a blocking thread.
    pub fn write_blocking(&self, write: Write) -> Result<(), StoreError> {
        self.writer_of(write.machine_id)
            .blocking_send(Queued::Request(Request::Write(write)))
            .map_err(|_| StoreError::Closed)
    }

    /// Commits what is queued and stops the writer: later writes fail
    /// with [`StoreError::Closed`]. Reads still work.
    pub async fn close(&self) {
        for writer in self.writers.iter() {
            let (reply, done) = oneshot::channel();
            if writer.send(Queued::Close(reply)).await.is_ok() {
                let _ = done.await;
            }
        }
    }

    /// Joins the database's nodes as `wanted` (or a free variant of it),
    /// answering at `url`, signing with the cluster key whose SHA-256 is
    /// `key_sha256`; from then on a machine's rows are committed only
    /// while this node holds its lease.
    pub async fn join(
        &self,
        wanted: &str,
        url: &str,
        key_sha256: &str,
    ) -> Result<cluster::Membership, StoreError> {
        let membership =
            cluster::Membership::join((*self.endpoint).clone(), wanted, url, key_sha256).await?;
        if self.fence.set(membership.node().to_string()).is_err() {
            return Err(StoreError::Location(
                "this store already serves a node".into(),
            ));
        }
        Ok(membership)
    }

    /// Every declared machine and the node holding its lease, if any.
    pub async fn placements(&self) -> Result<Vec<cluster::Placement>, StoreError> {
        cluster::placements(&**self.pooled().await?).await
    }

    /// Every registered node; live if its heartbeat is younger than `ttl_s`.
    pub async fn nodes(&self, ttl_s: f64) -> Result<Vec<cluster::NodeRow>, StoreError> {
        cluster::nodes(&**self.pooled().await?, ttl_s).await
    }

    /// Other nodes' commits, as they happen (see [`cluster::listen`]).
    pub fn listen(&self) -> mpsc::Receiver<cluster::Notice> {
        cluster::listen((*self.endpoint).clone())
    }

    /// The writer of machine `machine_id`: always the same one, so its
    /// writes commit in the order made.
    pub(super) fn writer_of(&self, machine_id: i64) -> &mpsc::Sender<Queued<Job>> {
        &self.writers[machine_id.unsigned_abs() as usize % self.writers.len()]
    }

    /// Runs `read` with a pooled connection, blocking this thread (not a
    /// runtime worker: call from `spawn_blocking` or a plain thread).
    pub(super) fn read<R>(
        &self,
        read: impl AsyncFnOnce(&deadpool_postgres::Client) -> Result<R, StoreError>,
    ) -> Result<R, StoreError> {
        self.runtime.block_on(async {
            let client = self
                .readers
                .get()
                .await
                .map_err(|e| StoreError::Unavailable(e.to_string()))?;
            read(&client).await
        })
    }

    /// A pooled connection, for a blocking read of several queries.
    pub(super) fn reader(&self) -> Result<deadpool_postgres::Client, StoreError> {
        self.runtime
            .block_on(self.readers.get())
            .map_err(|e| StoreError::Unavailable(e.to_string()))
    }

    /// Runs `job` on the writer's connection between two group commits.
    pub(super) async fn maintain<R: Send + 'static>(
        &self,
        job: impl for<'c> FnOnce(
            &'c mut tokio_postgres::Client,
        ) -> futures_util::future::BoxFuture<'c, Result<R, StoreError>>
        + Send
        + 'static,
    ) -> Result<R, StoreError> {
        let (reply, answer) = oneshot::channel();
        let job: Job = Box::new(move |client| {
            Box::pin(async move {
                let _ = reply.send(job(client).await);
            })
        });
        self.writers[0]
            .send(Queued::Job(job))
            .await
            .map_err(|_| StoreError::Closed)?;
        answer.await.map_err(|_| StoreError::Closed)?
    }

    /// The database's size on disk, bytes.
    pub async fn size_bytes(&self) -> Result<u64, StoreError> {
        let client = self.pooled().await?;
        let bytes: i64 = client
            .query_one("SELECT pg_database_size(current_database())", &[])
            .await?
            .get(0);
        Ok(bytes.max(0) as u64)
    }

    /// What the writers record in the outbox from now on (set once, before
    /// the first write).
    pub fn set_outbox(&self, config: crate::store::outbox::OutboxConfig) {
        let _ = self.outbox.set(config);
    }

    /// A pooled connection (async).
    pub(super) async fn pooled(&self) -> Result<deadpool_postgres::Client, StoreError> {
        self.readers
            .get()
            .await
            .map_err(|e| StoreError::Unavailable(e.to_string()))
    }
}
