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
//! opened on. This first step stores and reads what a machine needs to
//! run and restart; the rest of the store's operations follow.

mod backend;
pub mod cluster;
pub mod migrate;
mod schema;
mod writer;

pub use schema::{PARTITION_S, SCHEMA_VERSION};

use std::path::Path;
use std::str::FromStr;
use std::sync::Arc;

use deadpool_postgres::{Manager, ManagerConfig, Pool, RecyclingMethod};
use tokio::sync::{mpsc, oneshot};
use tokio_postgres::GenericClient;
use tokio_postgres_rustls::MakeRustlsConnect;

use super::alarms::{AlarmChange, AlarmFilter, Change, StoredAlarm};
use super::history::{self, EstimatesPage, Extremes, HistorySource};
use super::queue::{Queued, Request};
use super::retention::{self, Pruned, Retention, Step};
use super::{QUEUE_LEN, StoreError, StoredMachine, StoredSnapshot, Write};
use crate::auth::{Scope, Token, TokenError};
use crate::config::MachineSpec;
use crate::fusion::{EngineOutput, Reading, SensorKind, StreamKind};

/// Connections the read pool keeps.
const READERS: usize = 4;

/// Writing connections, each committing its machines' groups: as many as
/// this host has cores, up to four (one PostgreSQL backend inserting is
/// one core busy; more writers than cores only contend).
fn writer_count() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get().clamp(1, 4))
}

/// Where the office database is: a `postgres://USER@HOST:PORT/DB` URL and,
/// if the password is not in it, the file holding it.
#[derive(Debug, Clone, PartialEq)]
pub struct PgLocation {
    pub url: String,
    pub password_file: Option<std::path::PathBuf>,
    /// The CA the server's certificate is checked against (TLS), if not
    /// the system's roots.
    pub ca_file: Option<std::path::PathBuf>,
}

/// Where and how to connect: the driver's configuration and the TLS
/// connector (used when the URL's `sslmode` is `require` or `prefer`, or
/// a CA file is named).
#[derive(Clone)]
pub(crate) struct Endpoint {
    config: tokio_postgres::Config,
    tls: MakeRustlsConnect,
}

impl PgLocation {
    /// The URL without its password, for messages.
    pub fn redacted_url(&self) -> String {
        redacted(&self.url)
    }

    /// The URL parsed, the password read, TLS as asked: `sslmode=require`
    /// (or a CA file) checks the server's certificate against the CA file
    /// or the system's roots and its name against the URL's host.
    fn endpoint(&self) -> Result<Endpoint, StoreError> {
        use tokio_postgres::config::SslMode;
        let mut config = self.config()?;
        let asked = ["disable", "prefer", "require"]
            .into_iter()
            .find(|mode| self.url.contains(&format!("sslmode={mode}")));
        let wanted = match (asked, &self.ca_file) {
            (Some("prefer"), _) => {
                return Err(StoreError::Location(
                    "sslmode=prefer is not supported (a connection that may fall back to plain \
                     text is not checked): use sslmode=require, or leave sslmode out for plain"
                        .into(),
                ));
            }
            (Some("disable"), Some(_)) => {
                return Err(StoreError::Location(
                    "a CA file with sslmode=disable: drop one of the two".into(),
                ));
            }
            (Some("require"), _) | (None, Some(_)) => true,
            _ => false,
        };
        if wanted {
            config.ssl_mode(SslMode::Require);
        }
        let roots = if wanted {
            crate::tls::roots(self.ca_file.as_deref())
                .map_err(|e| StoreError::Location(format!("TLS to PostgreSQL: {e}")))?
        } else {
            // Never used: the connection is plain.
            config.ssl_mode(SslMode::Disable);
            rustls::RootCertStore::empty()
        };
        let tls = crate::tls::builder()
            .map_err(|e| StoreError::Location(e.to_string()))?
            .with_root_certificates(roots)
            .with_no_client_auth();
        Ok(Endpoint {
            config,
            tls: MakeRustlsConnect::new(tls),
        })
    }

    /// The driver's configuration: the URL parsed, the password read.
    fn config(&self) -> Result<tokio_postgres::Config, StoreError> {
        let mut config = tokio_postgres::Config::from_str(&self.url)
            .map_err(|e| StoreError::Location(format!("{}: {e}", redacted(&self.url))))?;
        if let Some(file) = &self.password_file {
            config.password(read_password(file)?);
        }
        config.application_name("tunnelnav");
        // A host that drops packets is given up on, not waited for.
        config.connect_timeout(std::time::Duration::from_secs(10));
        config.keepalives_idle(std::time::Duration::from_secs(30));
        config.tcp_user_timeout(std::time::Duration::from_secs(30));
        Ok(config)
    }
}

/// The URL without its password, for messages (also a URL that does not
/// parse: whatever stands between `user:` and `@` is hidden).
pub fn redacted(url: &str) -> String {
    let Some((scheme, rest)) = url.split_once("://") else {
        return url.to_string();
    };
    match rest.rsplit_once('@') {
        Some((userinfo, host)) => match userinfo.split_once(':') {
            Some((user, _)) => format!("{scheme}://{user}:***@{host}"),
            None => url.to_string(),
        },
        None => url.to_string(),
    }
}

/// The first line of `file`, the password.
fn read_password(file: &Path) -> Result<String, StoreError> {
    let text = std::fs::read_to_string(file)
        .map_err(|e| StoreError::Location(format!("password file {}: {e}", file.display())))?;
    Ok(text.lines().next().unwrap_or("").to_string())
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

    /// Creates or replaces a machine with a fresh engine snapshot; returns
    /// its id.
    pub async fn put_machine(
        &self,
        spec: MachineSpec,
        snapshot: String,
        forwarded: Option<i64>,
    ) -> Result<i64, StoreError> {
        let (reply, answer) = oneshot::channel();
        self.writers[0]
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

    /// Every stored machine, its parameters made current.
    pub fn machines(&self) -> Result<Vec<StoredMachine>, StoreError> {
        self.read(async |client| {
            let rows = client
                .query("SELECT id, spec FROM machines ORDER BY machine", &[])
                .await?;
            rows.iter()
                .map(|row| super::stored_machine(row.get(0), row.get(1)))
                .collect()
        })
    }

    /// A machine's latest snapshot.
    pub fn snapshot(&self, machine_id: i64) -> Result<Option<StoredSnapshot>, StoreError> {
        self.read(async |client| {
            Ok(client
                .query_opt(
                    "SELECT last_reading_id, state FROM snapshots WHERE machine_id = $1",
                    &[&machine_id],
                )
                .await?
                .map(|row| StoredSnapshot {
                    last_reading_id: row.get(0),
                    state: row.get(1),
                }))
        })
    }

    /// Calls `f` with each reading of the machine that arrived after
    /// `after_id`, in arrival order, a batch at a time.
    pub fn readings_since(
        &self,
        machine_id: i64,
        after_id: i64,
        mut f: impl FnMut(Reading) -> Result<(), StoreError>,
    ) -> Result<u64, StoreError> {
        const BATCH: i64 = 10_000;
        let mut after = after_id;
        let mut count = 0;
        loop {
            let rows = self.read(async |client| {
                Ok(client
                    .query(
                        "SELECT id, t, sensor, body FROM readings WHERE machine_id = $1 AND id > $2 \
                         ORDER BY id LIMIT $3",
                        &[&machine_id, &after, &BATCH],
                    )
                    .await?)
            })?;
            for row in &rows {
                after = row.get(0);
                f(reading(row.get(1), row.get(2), row.get(3))?)?;
                count += 1;
            }
            if (rows.len() as i64) < BATCH {
                return Ok(count);
            }
        }
    }

    /// The newest stored estimate of a stream.
    pub fn latest_estimate(
        &self,
        machine_id: i64,
        engine: StreamKind,
    ) -> Result<Option<EngineOutput>, StoreError> {
        self.read(async |client| {
            client
                .query_opt(
                    "SELECT t, body, codec FROM estimates WHERE machine_id = $1 AND engine = $2 \
                     ORDER BY t DESC LIMIT 1",
                    &[&machine_id, &engine.as_str()],
                )
                .await?
                .map(|row| output(engine, &row))
                .transpose()
        })
    }

    /// Time of the newest stored reading of a sensor.
    pub fn last_reading_t(
        &self,
        machine_id: i64,
        sensor: SensorKind,
    ) -> Result<Option<f64>, StoreError> {
        self.read(async |client| {
            Ok(client
                .query_opt(
                    "SELECT t FROM readings WHERE machine_id = $1 AND sensor = $2 \
                     ORDER BY t DESC LIMIT 1",
                    &[&machine_id, &(sensor as i16)],
                )
                .await?
                .map(|row| row.get(0)))
        })
    }

    /// The alarms `filter` asks for, newest first.
    pub fn alarms(&self, filter: &AlarmFilter) -> Result<Vec<StoredAlarm>, StoreError> {
        self.read(async |client| {
            let sql = format!(
                "SELECT {ALARM_COLUMNS} FROM alarms a JOIN machines m ON m.id = a.machine_id \
                 WHERE ($1::text IS NULL OR m.machine = $1) AND (NOT $2 OR a.cleared_t IS NULL) \
                 AND ($3::float8 IS NULL OR a.raised_t <= $3) \
                 AND ($4::float8 IS NULL OR a.cleared_t IS NULL OR a.cleared_t >= $4) \
                 ORDER BY a.raised_t DESC, a.id DESC LIMIT $5"
            );
            let (from, to) = (filter.during.map(|d| d.0), filter.during.map(|d| d.1));
            // PostgreSQL reads a null limit as none.
            let limit = filter.limit.map(|n| i64::try_from(n).unwrap_or(i64::MAX));
            let rows = client
                .query(
                    &sql,
                    &[&filter.machine, &filter.active_only, &to, &from, &limit],
                )
                .await?;
            Ok(rows.iter().map(writer::stored_alarm).collect())
        })
    }
}

impl PgStore {
    /// A pooled connection, for a blocking read of several queries.
    fn reader(&self) -> Result<deadpool_postgres::Client, StoreError> {
        self.runtime
            .block_on(self.readers.get())
            .map_err(|e| StoreError::Unavailable(e.to_string()))
    }

    /// A machine's estimates of one stream in `[from_t, to_t]`, downsampled
    /// above `max_points` as on SQLite ([`queries::estimates_page`]).
    pub fn estimates_page(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        max_points: usize,
    ) -> Result<EstimatesPage, StoreError> {
        let client = self.reader()?;
        let mut source = PgHistory {
            runtime: &self.runtime,
            client: &client,
            machine_id,
            engine,
        };
        history::estimates_page(&mut source, from_t, to_t, max_points)
    }

    /// Calls `f` with each stored reading of the machine in `[from_t, to_t]`
    /// (of one sensor, or all), in time order, a batch read at a time;
    /// stops early when `f` returns false.
    pub fn export_readings(
        &self,
        machine_id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
        mut f: impl FnMut(&Reading) -> bool,
    ) -> Result<(), StoreError> {
        let sensor = sensor.map(|s| s as i16);
        // Resume after the last (t, id) sent: within a time, the order
        // the readings were stored in (arrival).
        let mut after: (f64, i64) = (f64::NEG_INFINITY, -1);
        loop {
            // A connection per batch: a slow reader holds none between them.
            let client = self.reader()?;
            let rows = self.runtime.block_on(client.query(
                "SELECT t, sensor, body, id FROM readings WHERE machine_id = $1 AND t >= $2 \
                 AND t <= $3 AND ($4::int2 IS NULL OR sensor = $4) AND t >= $5 AND (t, id) > ($5, $6) \
                 ORDER BY t, id LIMIT $7",
                &[
                    &machine_id,
                    &from_t,
                    &to_t,
                    &sensor,
                    &after.0,
                    &after.1,
                    &EXPORT_BATCH,
                ],
            ))?;
            drop(client);
            for row in &rows {
                after = (row.get(0), row.get(3));
                if !f(&reading(row.get(0), row.get(1), row.get(2))?) {
                    return Ok(());
                }
            }
            if (rows.len() as i64) < EXPORT_BATCH {
                return Ok(());
            }
        }
    }

    /// Every stored estimate of `engine` in `[from_t, to_t]`, in time
    /// order, to `f` until it answers false (blocking).
    pub fn export_estimates(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        mut f: impl FnMut(&EngineOutput) -> bool,
    ) -> Result<(), StoreError> {
        let mut after = f64::NEG_INFINITY;
        loop {
            let client = self.reader()?;
            let rows = self.runtime.block_on(client.query(
                "SELECT t, body, codec FROM estimates WHERE machine_id = $1 AND engine = $2 \
                 AND t >= $3 AND t <= $4 AND t > $5 ORDER BY t LIMIT $6",
                &[
                    &machine_id,
                    &engine.as_str(),
                    &from_t,
                    &to_t,
                    &after,
                    &EXPORT_BATCH,
                ],
            ))?;
            drop(client);
            for row in &rows {
                let estimate = output(engine, row)?;
                after = estimate.t;
                if !f(&estimate) {
                    return Ok(());
                }
            }
            if (rows.len() as i64) < EXPORT_BATCH {
                return Ok(());
            }
        }
    }
}

impl PgStore {
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

    /// Acknowledges alarm `id` by `by` at `t`, as
    /// [`Store::ack_alarm`](super::Store::ack_alarm) does.
    pub async fn ack_alarm(
        &self,
        id: i64,
        by: String,
        t: f64,
        announce: impl FnOnce(AlarmChange) + Send + 'static,
    ) -> Result<Option<(StoredAlarm, bool)>, StoreError> {
        let node = self.fence.get().cloned();
        let outbox = self.outbox.get().copied().unwrap_or_default();
        self.maintain(move |client| {
            Box::pin(async move {
                // The acknowledgement and what it owes the webhooks, in
                // one commit.
                let tx = client.transaction().await?;
                let acked = tx
                    .execute(
                        "UPDATE alarms SET acked_t = $2, acked_by = $3 WHERE id = $1 AND acked_t IS NULL",
                        &[&id, &t, &by],
                    )
                    .await?
                    == 1;
                let alarm = alarm_by_id(&tx, id).await?;
                let mut change = None;
                if let (true, Some(alarm)) = (acked, &alarm) {
                    let acknowledged = AlarmChange {
                        transition: Change::Acknowledged,
                        alarm: alarm.clone(),
                    };
                    if let Some(node) = &node {
                        cluster::notify_alarm(&tx, node, &acknowledged).await?;
                        let machine_id: i64 = tx
                            .query_one("SELECT machine_id FROM alarms WHERE id = $1", &[&id])
                            .await?
                            .get(0);
                        writer::record_webhooks(
                            &tx,
                            &outbox,
                            node,
                            machine_id,
                            std::slice::from_ref(&acknowledged),
                        )
                        .await?;
                    }
                    change = Some(acknowledged);
                }
                tx.commit().await?;
                if let Some(change) = change {
                    announce(change);
                }
                Ok(alarm.map(|alarm| (alarm, acked)))
            })
        })
        .await
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

    /// Alarm changes this node owes the webhook of `severity`, oldest
    /// first.
    pub fn webhook_pending(
        &self,
        severity: &'static str,
        limit: usize,
    ) -> Result<Vec<crate::store::outbox::WebhookEntry>, StoreError> {
        let node = self.fence.get().cloned().unwrap_or_default();
        self.read(async |client| {
            client
                .query(
                    "SELECT id, body FROM outbox WHERE node = $1 AND kind = $2 ORDER BY id LIMIT $3",
                    &[&node, &severity, &(limit as i64)],
                )
                .await?
                .iter()
                .map(|row| {
                    let (id, body): (i64, String) = (row.get(0), row.get(1));
                    Ok(crate::store::outbox::WebhookEntry {
                        id,
                        change: serde_json::from_str(&body).map_err(|e| {
                            StoreError::Corrupt(format!("outbox row {id}: {e}"))
                        })?,
                    })
                })
                .collect()
        })
    }

    /// A webhook change is done with (delivered or given up).
    pub async fn webhook_done(&self, id: i64) -> Result<(), StoreError> {
        self.pooled()
            .await?
            .execute("DELETE FROM outbox WHERE id = $1", &[&id])
            .await?;
        Ok(())
    }

    /// Forgets the changes this node owes a webhook no longer configured.
    pub async fn webhook_dropped(&self, severity: &'static str) -> Result<u64, StoreError> {
        let node = self.fence.get().cloned().unwrap_or_default();
        Ok(self
            .pooled()
            .await?
            .execute(
                "DELETE FROM outbox WHERE node = $1 AND kind = $2",
                &[&node, &severity],
            )
            .await?)
    }

    /// An office: the last sequence of machine `machine_id` its site sent
    /// that is committed here.
    pub fn forward_mark(&self, machine_id: i64) -> Result<Option<i64>, StoreError> {
        self.read(async |client| {
            Ok(client
                .query_opt(
                    "SELECT sequence FROM forward_marks WHERE machine_id = $1",
                    &[&machine_id],
                )
                .await?
                .map(|row| row.get(0)))
        })
    }

    /// An office: every site's record.
    pub fn sites(&self) -> Result<Vec<crate::store::outbox::SiteRecord>, StoreError> {
        use crate::store::outbox::{Backlog, SiteRecord};
        self.read(async |client| {
            Ok(client
                .query(
                    "SELECT name, last_contact_t, backlog_items, backlog_readings, oldest_unsent_t \
                     FROM sites ORDER BY name",
                    &[],
                )
                .await?
                .iter()
                .map(|r| SiteRecord {
                    name: r.get(0),
                    last_contact_t: r.get(1),
                    backlog: Backlog {
                        items: r.get::<_, i64>(2).max(0) as u64,
                        readings: r.get::<_, i64>(3).max(0) as u64,
                        oldest_unsent_t: r.get(4),
                    },
                })
                .collect())
        })
    }

    /// An office: what this office holds of forwarded machine
    /// `machine_id`'s rows, as on SQLite.
    pub fn forward_held(
        &self,
        machine_id: i64,
    ) -> Result<crate::store::outbox::ForwardHeld, StoreError> {
        self.read(async |client| {
            let mark = client
                .query_opt(
                    "SELECT sequence, trusted_to FROM forward_marks WHERE machine_id = $1",
                    &[&machine_id],
                )
                .await?
                .map(|row| (row.get::<_, i64>(0), row.get::<_, i64>(1)));
            let applied = client
                .query(
                    "SELECT sequence FROM forward_applied WHERE machine_id = $1",
                    &[&machine_id],
                )
                .await?
                .iter()
                .map(|row| row.get(0))
                .collect();
            Ok(crate::store::outbox::ForwardHeld::new(mark, applied))
        })
    }

    /// An office: sets forwarded machine `machine`'s mark back to
    /// `sequence` (never forward), with an audit row, as on SQLite
    /// ([`crate::store::outbox::reset_mark`]); the mark it had.
    pub async fn reset_forward_mark(
        &self,
        machine: String,
        sequence: i64,
        actor: String,
        t: f64,
    ) -> Result<Option<i64>, StoreError> {
        let mut client = self.pooled().await?;
        let tx = client.transaction().await?;
        let Some((machine_id, was)) = tx
            .query_opt(
                "SELECT f.machine_id, f.sequence FROM forward_marks f \
                 JOIN machines m ON m.id = f.machine_id WHERE m.machine = $1 FOR UPDATE OF f",
                &[&machine],
            )
            .await?
            .map(|row| (row.get::<_, i64>(0), row.get::<_, i64>(1)))
        else {
            return Ok(None);
        };
        // Back only: a mark set forward would skip rows. What lies above
        // it is applied again when the site sends it (readings are stored
        // once).
        let sequence = sequence.min(was);
        tx.execute(
            "UPDATE forward_marks SET sequence = $2, trusted_to = least(trusted_to, $2) \
             WHERE machine_id = $1",
            &[&machine_id, &sequence],
        )
        .await?;
        tx.execute(
            "DELETE FROM forward_applied WHERE machine_id = $1 AND sequence > $2",
            &[&machine_id, &sequence],
        )
        .await?;
        tx.execute(
            "INSERT INTO audit (t, actor, action, subject, detail) VALUES ($1, $2, $3, $4, $5)",
            &[
                &t,
                &actor,
                &crate::store::outbox::RESET_FORWARD_MARK,
                &machine,
                &format!("mark {was} -> {sequence}"),
            ],
        )
        .await?;
        tx.commit().await?;
        Ok(Some(was))
    }

    /// The audit log, oldest first.
    pub fn audit(&self) -> Result<Vec<crate::store::outbox::AuditEntry>, StoreError> {
        self.read(async |client| {
            Ok(client
                .query(
                    "SELECT id, t, actor, action, subject, detail FROM audit ORDER BY id",
                    &[],
                )
                .await?
                .iter()
                .map(|row| crate::store::outbox::AuditEntry {
                    id: row.get(0),
                    t: row.get(1),
                    actor: row.get(2),
                    action: row.get(3),
                    subject: row.get(4),
                    detail: row.get(5),
                })
                .collect())
        })
    }

    /// An office: records a site's contact.
    pub async fn put_site(&self, site: crate::store::outbox::SiteRecord) -> Result<(), StoreError> {
        let client = self.pooled().await?;
        client
            .execute(
                "INSERT INTO sites (name, last_contact_t, backlog_items, backlog_readings, oldest_unsent_t) \
                 VALUES ($1, $2, $3, $4, $5) ON CONFLICT (name) DO UPDATE SET \
                 last_contact_t = $2, backlog_items = $3, backlog_readings = $4, oldest_unsent_t = $5",
                &[
                    &site.name,
                    &site.last_contact_t,
                    &(site.backlog.items as i64),
                    &(site.backlog.readings as i64),
                    &site.backlog.oldest_unsent_t,
                ],
            )
            .await?;
        Ok(())
    }

    /// The tokens in force, with their hashes.
    pub async fn active_tokens(&self) -> Result<Vec<(String, Token)>, StoreError> {
        let client = self.pooled().await?;
        let rows = client
            .query(
                "SELECT id, name, scope, machine, created_t, revoked_t, hash FROM tokens \
                 WHERE revoked_t IS NULL",
                &[],
            )
            .await?;
        Ok(rows.iter().map(|row| (row.get(6), token(row))).collect())
    }

    /// Stores a new token; its id and text (shown once), as
    /// [`crate::store::tokens::create`] does on SQLite.
    pub async fn create_token(
        &self,
        name: &str,
        scope: Scope,
        machine: Option<&str>,
        now_t: f64,
    ) -> Result<(i64, String), StoreError> {
        crate::auth::check_new(scope, machine)?;
        let (token, hash) = crate::auth::generate();
        let client = self.pooled().await?;
        let id: i64 = client
            .query_one(
                "INSERT INTO tokens (name, scope, machine, hash, created_t) \
                 VALUES ($1, $2, $3, $4, $5) RETURNING id",
                &[&name, &scope.as_str(), &machine, &hash, &now_t],
            )
            .await
            .map_err(StoreError::from)?
            .get(0);
        Ok((id, token))
    }

    /// Every token, revoked ones included, oldest first.
    pub async fn tokens(&self) -> Result<Vec<Token>, StoreError> {
        let client = self.pooled().await?;
        let rows = client
            .query(
                "SELECT id, name, scope, machine, created_t, revoked_t FROM tokens ORDER BY id",
                &[],
            )
            .await?;
        Ok(rows.iter().map(token).collect())
    }

    /// Revokes a token.
    pub async fn revoke_token(&self, id: i64, now_t: f64) -> Result<Token, StoreError> {
        let client = self.pooled().await?;
        client
            .execute(
                "UPDATE tokens SET revoked_t = $2 WHERE id = $1 AND revoked_t IS NULL",
                &[&id, &now_t],
            )
            .await
            .map_err(StoreError::from)?;
        client
            .query_opt(
                "SELECT id, name, scope, machine, created_t, revoked_t FROM tokens WHERE id = $1",
                &[&id],
            )
            .await
            .map_err(StoreError::from)?
            .map(|row| token(&row))
            .ok_or(StoreError::Token(TokenError::NoSuchToken(id)))
    }

    /// A pooled connection (async).
    async fn pooled(&self) -> Result<deadpool_postgres::Client, StoreError> {
        self.readers
            .get()
            .await
            .map_err(|e| StoreError::Unavailable(e.to_string()))
    }

    /// The steps of a retention pass of `policy` at `now_t` (blocking).
    pub fn retention_plan(
        &self,
        now_t: f64,
        policy: &Retention,
        batch: usize,
    ) -> Result<Vec<Step>, StoreError> {
        let client = self.reader()?;
        let oldest = |machine: i64, stream: StreamKind| -> Result<Option<f64>, StoreError> {
            Ok(self
                .runtime
                .block_on(client.query_one(
                    "SELECT min(t) FROM estimates WHERE machine_id = $1 AND engine = $2",
                    &[&machine, &stream.as_str()],
                ))?
                .get(0))
        };
        let machines: Vec<i64> = self
            .runtime
            .block_on(client.query("SELECT id FROM machines", &[]))?
            .iter()
            .map(|row| row.get(0))
            .collect();
        retention::plan_steps(now_t, policy, batch, &machines, oldest)
    }

    /// Does one step of a pass on the writer's connection. Readings go by
    /// whole day partitions where every reading in them is older than the
    /// cut and covered by its machine's snapshot, then row by row.
    pub async fn retention_step(&self, step: Step) -> Result<Pruned, StoreError> {
        self.maintain(move |client| Box::pin(async move { apply_step(client, step).await }))
            .await
    }
}

/// One retention step on PostgreSQL.
async fn apply_step(client: &mut tokio_postgres::Client, step: Step) -> Result<Pruned, StoreError> {
    match step {
        Step::Readings { cut, batch } => {
            let mut readings = 0;
            // Whole partitions first: their end at or before the cut, none
            // of their readings after its machine's snapshot.
            let days: Vec<i64> = schema::partitions(client)
                .await?
                .into_iter()
                .filter(|(table, day)| {
                    table == "readings" && (*day + 1) as f64 * PARTITION_S <= cut
                })
                .map(|(_, day)| day)
                .collect();
            for day in days {
                let (_, name) = schema::partition("readings", day as f64 * PARTITION_S);
                let uncovered: i64 = client
                    .query_one(
                        &format!(
                            "SELECT count(*) FROM {name} r LEFT JOIN snapshots s \
                             ON s.machine_id = r.machine_id \
                             WHERE s.last_reading_id IS NULL OR r.id > s.last_reading_id"
                        ),
                        &[],
                    )
                    .await?
                    .get(0);
                if uncovered > 0 {
                    continue;
                }
                let tx = client.transaction().await?;
                let rows: i64 = tx
                    .query_one(&format!("SELECT count(*) FROM {name}"), &[])
                    .await?
                    .get(0);
                tx.batch_execute(&format!("DROP TABLE {name}")).await?;
                tx.commit().await?;
                readings += rows as u64;
            }
            // Then what is left, a batch at a time.
            readings += client
                .execute(
                    "DELETE FROM readings WHERE t < $1 AND (machine_id, id) IN ( \
                         SELECT r.machine_id, r.id FROM readings r \
                         JOIN snapshots s ON s.machine_id = r.machine_id \
                         WHERE r.t < $1 AND r.id <= s.last_reading_id LIMIT $2)",
                    &[&cut, &(batch as i64)],
                )
                .await?;
            Ok(Pruned {
                readings,
                estimates: 0,
            })
        }
        Step::Thin {
            machine,
            stream,
            from,
            to,
        } => {
            let estimates = client
                .execute(
                    "DELETE FROM estimates WHERE machine_id = $1 AND engine = $2 AND t >= $3 AND t < $4 \
                     AND t NOT IN (SELECT min(t) FROM estimates \
                     WHERE machine_id = $1 AND engine = $2 AND t >= $3 AND t < $4 \
                     GROUP BY floor(t / $5))",
                    &[&machine, &stream.as_str(), &from, &to, &retention::THIN_TO_S],
                )
                .await?;
            Ok(Pruned {
                readings: 0,
                estimates,
            })
        }
    }
}

/// A token from a row of (id, name, scope, machine, created_t, revoked_t).
fn token(row: &tokio_postgres::Row) -> Token {
    let scope: String = row.get(2);
    Token {
        id: row.get(0),
        name: row.get(1),
        // The table's CHECK constraint admits only the three names.
        scope: Scope::from_name(&scope).unwrap_or(Scope::Read),
        machine: row.get(3),
        created_t: row.get(4),
        revoked_t: row.get(5),
    }
}

/// Rows an export reads per query.
const EXPORT_BATCH: i64 = 5000;

/// One machine's estimates of one stream in PostgreSQL; each query blocks
/// on the store's runtime (history reads run on blocking threads).
struct PgHistory<'a> {
    runtime: &'a tokio::runtime::Handle,
    client: &'a deadpool_postgres::Client,
    machine_id: i64,
    engine: StreamKind,
}

impl PgHistory<'_> {
    fn query(
        &self,
        sql: &str,
        params: &[&(dyn tokio_postgres::types::ToSql + Sync)],
    ) -> Result<Vec<tokio_postgres::Row>, StoreError> {
        Ok(self.runtime.block_on(self.client.query(sql, params))?)
    }
}

impl HistorySource for PgHistory<'_> {
    fn count_upto(&mut self, from_t: f64, to_t: f64, limit: i64) -> Result<i64, StoreError> {
        let rows = self.query(
            "SELECT count(*) FROM (SELECT 1 FROM estimates \
             WHERE machine_id = $1 AND engine = $2 AND t >= $3 AND t <= $4 LIMIT $5) AS upto",
            &[
                &self.machine_id,
                &self.engine.as_str(),
                &from_t,
                &to_t,
                &limit,
            ],
        )?;
        Ok(rows.first().map_or(0, |row| row.get(0)))
    }

    fn all(&mut self, from_t: f64, to_t: f64) -> Result<Vec<EngineOutput>, StoreError> {
        self.query(
            "SELECT t, body, codec FROM estimates \
             WHERE machine_id = $1 AND engine = $2 AND t >= $3 AND t <= $4 ORDER BY t",
            &[&self.machine_id, &self.engine.as_str(), &from_t, &to_t],
        )?
        .iter()
        .map(|row| output(self.engine, row))
        .collect()
    }

    fn end(&mut self, from_t: f64, to_t: f64, last: bool) -> Result<f64, StoreError> {
        let order = if last { "DESC" } else { "ASC" };
        let rows = self.query(
            &format!(
                "SELECT t FROM estimates WHERE machine_id = $1 AND engine = $2 \
                 AND t >= $3 AND t <= $4 ORDER BY t {order} LIMIT 1"
            ),
            &[&self.machine_id, &self.engine.as_str(), &from_t, &to_t],
        )?;
        rows.first()
            .map(|row| row.get(0))
            .ok_or_else(|| StoreError::Corrupt("estimates counted but not found".into()))
    }

    fn points(
        &mut self,
        lo: f64,
        hi: f64,
        out: &mut dyn FnMut(Extremes),
    ) -> Result<(), StoreError> {
        for row in self.query(
            "SELECT t, extreme_a, extreme_b FROM estimates \
             WHERE machine_id = $1 AND engine = $2 AND t >= $3 AND t < $4",
            &[&self.machine_id, &self.engine.as_str(), &lo, &hi],
        )? {
            out(Extremes::point(row.get(0), [row.get(1), row.get(2)]));
        }
        Ok(())
    }

    fn buckets(
        &mut self,
        width_s: i64,
        first: i64,
        end: i64,
        out: &mut dyn FnMut(Extremes),
    ) -> Result<(), StoreError> {
        for row in self.query(
            "SELECT min_a, t_min_a, max_a, t_max_a, min_b, t_min_b, max_b, t_max_b \
             FROM estimate_buckets WHERE machine_id = $1 AND engine = $2 \
             AND width_s = $3 AND bucket >= $4 AND bucket < $5",
            &[
                &self.machine_id,
                &self.engine.as_str(),
                &width_s,
                &first,
                &end,
            ],
        )? {
            out(Extremes {
                min_a: (row.get(0), row.get(1)),
                max_a: (row.get(2), row.get(3)),
                min_b: (row.get(4), row.get(5)),
                max_b: (row.get(6), row.get(7)),
            });
        }
        Ok(())
    }

    fn at(&mut self, t: f64) -> Result<Option<EngineOutput>, StoreError> {
        self.query(
            "SELECT t, body, codec FROM estimates WHERE machine_id = $1 AND engine = $2 AND t = $3",
            &[&self.machine_id, &self.engine.as_str(), &t],
        )?
        .first()
        .map(|row| output(self.engine, row))
        .transpose()
    }
}

/// The columns of a stored alarm, `a` the alarm and `m` its machine.
const ALARM_COLUMNS: &str = "a.id, m.machine, a.kind, a.severity, a.subject, a.message, \
                             a.raised_t, a.cleared_t, a.acked_t, a.acked_by";

/// The alarm with this id.
async fn alarm_by_id(
    client: &impl GenericClient,
    id: i64,
) -> Result<Option<StoredAlarm>, StoreError> {
    let sql = format!(
        "SELECT {ALARM_COLUMNS} FROM alarms a JOIN machines m ON m.id = a.machine_id WHERE a.id = $1"
    );
    Ok(client
        .query_opt(&sql, &[&id])
        .await?
        .map(|row| writer::stored_alarm(&row)))
}

/// The pool of reading connections.
fn pool(endpoint: &Endpoint) -> Result<Pool, StoreError> {
    let manager = Manager::from_config(
        endpoint.config.clone(),
        endpoint.tls.clone(),
        ManagerConfig {
            recycling_method: RecyclingMethod::Fast,
        },
    );
    Pool::builder(manager)
        .max_size(READERS)
        .runtime(deadpool_postgres::Runtime::Tokio1)
        .wait_timeout(Some(std::time::Duration::from_secs(10)))
        .create_timeout(Some(std::time::Duration::from_secs(10)))
        .build()
        .map_err(|e| StoreError::Location(e.to_string()))
}

/// A connection, its driver task spawned on the current runtime. Not
/// reaching the server (refused, timed out) is [`StoreError::Unavailable`];
/// what the server answers (a wrong password, no such database) is its error.
async fn connect(endpoint: &Endpoint) -> Result<tokio_postgres::Client, StoreError> {
    let (client, connection) = endpoint
        .config
        .connect(endpoint.tls.clone())
        .await
        .map_err(|e| {
            if e.code().is_some() {
                StoreError::Postgres(e)
            } else {
                StoreError::Unavailable(format!("cannot reach PostgreSQL: {}", with_causes(&e)))
            }
        })?;
    tokio::spawn(async move {
        if let Err(e) = connection.await {
            tracing::warn!(error = %e, "PostgreSQL connection ended");
        }
    });
    Ok(client)
}

/// An error with what caused it (a TLS handshake's reason, say).
pub(super) fn with_causes(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(inner) = cause {
        text.push_str(": ");
        text.push_str(&inner.to_string());
        cause = inner.source();
    }
    text
}

/// A writing connection: [`connect`], and a transaction left idle for
/// 10 s (its host paused) is ended, so the leases it checked are not held
/// for ever.
async fn connect_writer(endpoint: &Endpoint) -> Result<tokio_postgres::Client, StoreError> {
    let client = connect(endpoint).await?;
    client
        .batch_execute("SET idle_in_transaction_session_timeout = '10s'")
        .await?;
    Ok(client)
}

/// A stored reading's row.
fn reading(t: f64, sensor: i16, body: Vec<u8>) -> Result<Reading, StoreError> {
    let sensor = usize::try_from(sensor)
        .ok()
        .and_then(|i| SensorKind::ALL.get(i).copied())
        .ok_or_else(|| StoreError::Corrupt(format!("sensor number {sensor}")))?;
    super::codec::decode_reading(t, sensor, &body)
}

/// A stored estimate's row (`t`, `body`, `codec`).
fn output(engine: StreamKind, row: &tokio_postgres::Row) -> Result<EngineOutput, StoreError> {
    let body: Vec<u8> = row.get(1);
    let codec: i32 = row.get(2);
    super::codec::decode_output(engine, row.get(0), codec as u32, &body)
}
