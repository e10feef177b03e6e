//! The office store: PostgreSQL, for a company's many machines on one
//! database that several tunnelnav nodes share (issue 37). The semantics
//! are the SQLite store's (`store/mod.rs`): one writer connection with
//! group commit answering each request only after the commit; readings
//! stored once per (machine, sensor, time) with their arrival order;
//! estimates with their codec version; snapshots after a known reading.
//!
//! The driver is `tokio-postgres` (async) with a `deadpool-postgres` pool
//! for reads. Reads are blocking calls, as on SQLite (async callers run
//! them with `spawn_blocking`): they run on the runtime the store was
//! opened on.
//!
//! The files are the SQLite store's topics: `connect.rs` (where the
//! database is, TLS, the pools), `machines.rs`, `history.rs`, `alarms.rs`,
//! `outbox.rs` (webhooks and an office's records), `tokens.rs`,
//! `retention.rs`, `writer.rs` and `schema.rs`; `cluster.rs` (leases,
//! nodes, notifications) and `migrate.rs` (from SQLite) are PostgreSQL's
//! own.

mod alarms;
mod backend;
pub mod cluster;
mod connect;
mod history;
mod machines;
pub mod migrate;
mod outbox;
mod retention;
mod schema;
mod tokens;
mod writer;

use connect::{Endpoint, connect, connect_writer, pool, with_causes};
pub use connect::{PgLocation, redacted};

pub use schema::{PARTITION_S, SCHEMA_VERSION};

use std::sync::Arc;

use deadpool_postgres::Pool;
use tokio::sync::{mpsc, oneshot};

use super::queue::{Queued, Request};
use super::{QUEUE_LEN, StoreError, Write};

/// Connections the read pool keeps.
const READERS: usize = 4;

/// Writing connections, each committing its machines' groups: as many as
/// this host has cores, up to four (one PostgreSQL backend inserting is
/// one core busy; more writers than cores only contend).
fn writer_count() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get().clamp(1, 4))
}

/// Cheap, cloneable handle to the PostgreSQL store.
#[derive(Clone)]
pub struct PgStore {
    /// The writers' queues: a machine's writes go to one of them (by its
    /// id), jobs and declarations to the first.
    writers: Arc<[mpsc::Sender<Queued<writer::Job>>]>,
    endpoint: Arc<Endpoint>,
    /// Set when this store serves a node of several: the node's name. The
    /// writers then commit a machine's rows only while the node holds its
    /// lease.
    fence: Arc<std::sync::OnceLock<String>>,
    /// What the writers record in the outbox (the webhooks' changes), set
    /// once by the server before it writes.
    outbox: Arc<std::sync::OnceLock<crate::store::outbox::OutboxConfig>>,
    readers: Pool,
    runtime: tokio::runtime::Handle,
}

impl PgStore {
    /// Connects to the database at `location`, brings its schema to this
    /// release's (under an advisory lock: nodes may start together) and
    /// starts the writer. Call within a Tokio runtime: reads and the writer
    /// run on it.
    pub async fn open(location: &PgLocation) -> Result<PgStore, StoreError> {
        let endpoint = location.endpoint()?;
        let mut migrator = connect(&endpoint).await?;
        schema::migrate(&mut migrator).await?;
        drop(migrator);
        let fence = Arc::new(std::sync::OnceLock::new());
        let outbox = Arc::new(std::sync::OnceLock::new());
        let mut writers = Vec::with_capacity(writer_count());
        for _ in 0..writer_count() {
            let client = connect_writer(&endpoint).await?;
            let (requests, queue) = mpsc::channel(QUEUE_LEN);
            tokio::spawn(writer::writer(
                client,
                endpoint.clone(),
                queue,
                fence.clone(),
                outbox.clone(),
            ));
            writers.push(requests);
        }
        Ok(PgStore {
            writers: writers.into(),
            readers: pool(&endpoint)?,
            endpoint: Arc::new(endpoint),
            fence,
            outbox,
            runtime: tokio::runtime::Handle::current(),
        })
    }

    /// The database at `location` for commands beside a running server
    /// (`tunnelnav token`): its schema brought current and a read pool, no
    /// writer (writes fail with [`StoreError::Closed`]).
    pub async fn open_client(location: &PgLocation) -> Result<PgStore, StoreError> {
        let endpoint = location.endpoint()?;
        let mut migrator = connect(&endpoint).await?;
        schema::migrate(&mut migrator).await?;
        drop(migrator);
        let (requests, _) = mpsc::channel(1);
        Ok(PgStore {
            writers: Arc::new([requests]),
            readers: pool(&endpoint)?,
            endpoint: Arc::new(endpoint),
            fence: Arc::default(),
            outbox: Arc::default(),
            runtime: tokio::runtime::Handle::current(),
        })
    }

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
    fn writer_of(&self, machine_id: i64) -> &mpsc::Sender<Queued<writer::Job>> {
        &self.writers[machine_id.unsigned_abs() as usize % self.writers.len()]
    }

    /// Runs `read` with a pooled connection, blocking this thread (not a
    /// runtime worker: call from `spawn_blocking` or a plain thread).
    fn read<R>(
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
    fn reader(&self) -> Result<deadpool_postgres::Client, StoreError> {
        self.runtime
            .block_on(self.readers.get())
            .map_err(|e| StoreError::Unavailable(e.to_string()))
    }

    /// Runs `job` on the writer's connection between two group commits.
    async fn maintain<R: Send + 'static>(
        &self,
        job: impl for<'c> FnOnce(
            &'c mut tokio_postgres::Client,
        ) -> futures_util::future::BoxFuture<'c, Result<R, StoreError>>
        + Send
        + 'static,
    ) -> Result<R, StoreError> {
        let (reply, answer) = oneshot::channel();
        let job: writer::Job = Box::new(move |client| {
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
    async fn pooled(&self) -> Result<deadpool_postgres::Client, StoreError> {
        self.readers
            .get()
            .await
            .map_err(|e| StoreError::Unavailable(e.to_string()))
    }
}
