//! The office store: PostgreSQL, for a company's many machines on one
//! database that several tunnelnav nodes share (issue 37). The semantics
//! are the SQLite store's (`store/sqlite/`): one writer connection with
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
mod handle;
mod history;
mod machines;
pub mod migrate;
mod outbox;
mod retention;
mod schema;
mod tokens;
mod writer;

pub use connect::{PgLocation, redacted};
use connect::{connect, connect_writer, pool};
pub use handle::PgStore;

pub use schema::{PARTITION_S, SCHEMA_VERSION};

use std::sync::Arc;

use tokio::sync::mpsc;

use super::error::StoreError;
use super::queue::QUEUE_LEN;

/// Writing connections, each committing its machines' groups: as many as
/// this host has cores, up to four (one PostgreSQL backend inserting is
/// one core busy; more writers than cores only contend).
fn writer_count() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get().clamp(1, 4))
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
}
