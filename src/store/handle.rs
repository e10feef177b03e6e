//! [`Store`]: the one store interface the rest of tunnelnav uses, over
//! whichever [`Backend`] it was opened with — SQLite in the data dir (the
//! default: one site, one file) or PostgreSQL (an office: many machines,
//! several nodes). Every backend keeps the same semantics;
//! `tests/store_conformance.rs` holds them to it.

use std::path::Path;
use std::sync::Arc;

use rusqlite::Connection;

use super::alarms::{AlarmChange, AlarmFilter, StoredAlarm};
use super::backend::{Backend, Office};
use super::error::StoreError;
use super::history::EstimatesPage;
use super::outbox::{AuditEntry, ForwardHeld, OutboxConfig, SiteRecord, WebhookEntry};
use super::postgres::{PgLocation, PgStore};
use super::retention::{Pruned, Retention, Step};
use super::rows::StoredMachine;
use super::rows::StoredSnapshot;
use super::rows::Write;
use super::sqlite::SqliteStore;
use crate::auth::{Scope, Token};
use crate::config::MachineSpec;
use crate::fusion::{EngineOutput, Reading, SensorKind, StreamKind};

/// Cheap, cloneable handle to the store. Writes are async and answered
/// after their commit; reads are blocking calls (async callers run them
/// with `spawn_blocking`).
#[derive(Clone)]
pub struct Store {
    backend: Arc<dyn Backend>,
}

impl Store {
    /// The store kept by `backend`.
    pub fn new(backend: impl Backend) -> Store {
        Store {
            backend: Arc::new(backend),
        }
    }

    /// The SQLite store in `data_dir` (created and migrated).
    pub fn open(data_dir: &Path) -> Result<Store, StoreError> {
        Store::open_capped(data_dir, None)
    }

    /// [`Store::open`] with the database file capped at `max_bytes`.
    pub fn open_capped(data_dir: &Path, max_bytes: Option<u64>) -> Result<Store, StoreError> {
        Store::open_with(data_dir, max_bytes, OutboxConfig::default())
    }

    /// [`Store::open_capped`] recording in its outbox what `outbox` says is
    /// owed (to an office, to webhooks).
    pub fn open_with(
        data_dir: &Path,
        max_bytes: Option<u64>,
        outbox: OutboxConfig,
    ) -> Result<Store, StoreError> {
        Ok(Store::new(SqliteStore::open_with(
            data_dir, max_bytes, outbox,
        )?))
    }

    /// The PostgreSQL store at `location` (migrated), recording in its
    /// outbox what `outbox` says webhooks are owed. Call within a Tokio
    /// runtime.
    pub async fn open_postgres(
        location: &PgLocation,
        outbox: OutboxConfig,
    ) -> Result<Store, StoreError> {
        let store = PgStore::open(location).await?;
        store.set_outbox(outbox);
        Ok(Store::new(store))
    }

    /// The store a command beside a running server uses (`tunnelnav
    /// token`): the SQLite store in `data_dir`, leaving checkpoints to the
    /// server ([`SqliteStore::open_client`]), or the PostgreSQL store at
    /// `postgres` without writers. Either brings the schema to this
    /// release's first. Call within a Tokio runtime.
    pub async fn open_client(
        data_dir: &Path,
        postgres: Option<&PgLocation>,
    ) -> Result<Store, StoreError> {
        match postgres {
            None => Ok(Store::new(SqliteStore::open_client(data_dir)?)),
            Some(location) => Ok(Store::new(PgStore::open_client(location).await?)),
        }
    }

    /// A plain connection to the SQLite store in `data_dir`, for commands
    /// that run beside a server (`backup`, `site`).
    pub fn connect(data_dir: &Path) -> Result<Connection, StoreError> {
        SqliteStore::connect(data_dir)
    }

    /// `sqlite`, `postgres`, …
    pub fn backend_name(&self) -> &'static str {
        self.backend.name()
    }

    /// The SQLite store, if this is one.
    pub fn sqlite(&self) -> Option<&SqliteStore> {
        self.backend.as_any().downcast_ref()
    }

    /// The PostgreSQL store, if this is one (several nodes may share it).
    pub fn postgres(&self) -> Option<&PgStore> {
        self.backend.as_any().downcast_ref()
    }

    /// The office's records, or an error naming the backend that has none.
    fn office(&self) -> Result<&dyn Office, StoreError> {
        self.backend.office().ok_or(StoreError::Unsupported {
            backend: self.backend.name(),
            what: "an office's forwarded machines",
        })
    }

    /// Queues a write; its `reply` is answered after the commit.
    pub async fn write(&self, write: Write) -> Result<(), StoreError> {
        self.backend.write(write).await
    }

    /// Like [`Store::write`], from a blocking thread.
    pub fn write_blocking(&self, write: Write) -> Result<(), StoreError> {
        self.backend.write_blocking(write)
    }

    /// Commits what is queued and stops writing; later writes fail with
    /// [`StoreError::Closed`]. Reads still work.
    pub async fn close(&self) {
        self.backend.close().await
    }

    /// Creates or replaces a machine with a fresh engine snapshot: readings
    /// stored before are kept but not fed to the new engines. Returns its id.
    pub async fn put_machine(
        &self,
        spec: MachineSpec,
        snapshot: String,
    ) -> Result<i64, StoreError> {
        self.backend.put_machine(spec, snapshot, None).await
    }

    /// An office: stores a forwarded machine's declaration, and the site's
    /// sequence of it as the machine's mark, in one commit.
    pub async fn put_forwarded_machine(
        &self,
        spec: MachineSpec,
        snapshot: String,
        sequence: i64,
    ) -> Result<i64, StoreError> {
        self.backend
            .put_machine(spec, snapshot, Some(sequence))
            .await
    }

    /// An office: the last sequence of forwarded machine `machine_id` its
    /// site sent that is committed here.
    pub fn forward_mark(&self, machine_id: i64) -> Result<Option<i64>, StoreError> {
        self.office()?.forward_mark(machine_id)
    }

    /// An office: what this office holds of forwarded machine
    /// `machine_id`'s rows (blocking).
    pub fn forward_held(&self, machine_id: i64) -> Result<ForwardHeld, StoreError> {
        self.office()?.forward_held(machine_id)
    }

    /// An office: sets forwarded machine `machine`'s mark back to
    /// `sequence` (never forward), audited as `actor`'s at `t`; the mark it
    /// had (`None`: not a forwarded machine).
    pub async fn reset_forward_mark(
        &self,
        machine: String,
        sequence: i64,
        actor: String,
        t: f64,
    ) -> Result<Option<i64>, StoreError> {
        self.office()?
            .reset_forward_mark(machine, sequence, actor, t)
            .await
    }

    /// The audit log, oldest first (blocking).
    pub fn audit(&self) -> Result<Vec<AuditEntry>, StoreError> {
        self.office()?.audit()
    }

    /// An office: every site's record (blocking).
    pub fn sites(&self) -> Result<Vec<SiteRecord>, StoreError> {
        self.office()?.sites()
    }

    /// An office: records a site's contact.
    pub async fn put_site(&self, site: SiteRecord) -> Result<(), StoreError> {
        self.office()?.put_site(site).await
    }

    /// Alarm changes owed to the webhook of `severity`, oldest first
    /// (blocking; on PostgreSQL, those this node made).
    pub fn webhook_pending(
        &self,
        severity: &'static str,
        limit: usize,
    ) -> Result<Vec<WebhookEntry>, StoreError> {
        self.backend.webhook_pending(severity, limit)
    }

    /// A webhook's change is done with (delivered or given up).
    pub async fn webhook_done(&self, id: i64) -> Result<(), StoreError> {
        self.backend.webhook_done(id).await
    }

    /// Forgets the changes owed to a webhook no longer configured; how
    /// many.
    pub async fn webhook_dropped(&self, severity: &'static str) -> Result<u64, StoreError> {
        self.backend.webhook_dropped(severity).await
    }

    /// The SQLite store a site's outbox is in (a site's store is SQLite).
    pub fn site_outbox(&self) -> Result<&SqliteStore, StoreError> {
        self.sqlite().ok_or_else(|| {
            StoreError::Location(
                "a site forwarding to an office keeps its outbox in SQLite (--data-dir), \
                 not in PostgreSQL"
                    .into(),
            )
        })
    }

    /// Every stored machine, its parameters made current.
    pub fn machines(&self) -> Result<Vec<StoredMachine>, StoreError> {
        self.backend.machines()
    }

    /// A machine's latest snapshot.
    pub fn snapshot(&self, machine_id: i64) -> Result<Option<StoredSnapshot>, StoreError> {
        self.backend.snapshot(machine_id)
    }

    /// Calls `f` with each reading of the machine that arrived after
    /// `after_id`, in arrival order, without holding them all in memory.
    pub fn readings_since(
        &self,
        machine_id: i64,
        after_id: i64,
        mut f: impl FnMut(Reading) -> Result<(), StoreError>,
    ) -> Result<u64, StoreError> {
        self.backend.readings_since(machine_id, after_id, &mut f)
    }

    /// A machine's estimates of one stream in `[from_t, to_t]`, downsampled
    /// above `max_points` keeping each bucket's extremes.
    pub fn estimates_page(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        max_points: usize,
    ) -> Result<EstimatesPage, StoreError> {
        self.backend
            .estimates_page(machine_id, engine, from_t, to_t, max_points)
    }

    /// Each stored reading in `[from_t, to_t]` (of one sensor, or all), in
    /// time order, to `f` until it answers false.
    pub fn export_readings(
        &self,
        machine_id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
        mut f: impl FnMut(&Reading) -> bool,
    ) -> Result<(), StoreError> {
        self.backend
            .export_readings(machine_id, sensor, from_t, to_t, &mut f)
    }

    /// Each stored estimate of `engine` in `[from_t, to_t]`, in time order,
    /// to `f` until it answers false.
    pub fn export_estimates(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        mut f: impl FnMut(&EngineOutput) -> bool,
    ) -> Result<(), StoreError> {
        self.backend
            .export_estimates(machine_id, engine, from_t, to_t, &mut f)
    }

    /// The newest stored estimate of a stream.
    pub fn latest_estimate(
        &self,
        machine_id: i64,
        engine: StreamKind,
    ) -> Result<Option<EngineOutput>, StoreError> {
        self.backend.latest_estimate(machine_id, engine)
    }

    /// Time of the newest stored reading of a sensor.
    pub fn last_reading_t(
        &self,
        machine_id: i64,
        sensor: SensorKind,
    ) -> Result<Option<f64>, StoreError> {
        self.backend.last_reading_t(machine_id, sensor)
    }

    /// The alarms `filter` asks for, newest first.
    pub fn alarms(&self, filter: &AlarmFilter) -> Result<Vec<StoredAlarm>, StoreError> {
        self.backend.alarms(filter)
    }

    /// Acknowledges alarm `id` by `by` at `t` (the first acknowledgement
    /// stands); the alarm as it now is and whether this call acknowledged
    /// it, or `None` if there is no such alarm. `announce` gets the
    /// acknowledged alarm on the writer, ordered with the alarm changes
    /// commits report.
    pub async fn ack_alarm(
        &self,
        id: i64,
        by: String,
        t: f64,
        announce: impl FnOnce(AlarmChange) + Send + 'static,
    ) -> Result<Option<(StoredAlarm, bool)>, StoreError> {
        self.backend.ack_alarm(id, by, t, Box::new(announce)).await
    }

    /// Bytes the store takes on disk (SQLite: the file and its log;
    /// PostgreSQL: the database).
    pub async fn size_bytes(&self) -> Result<u64, StoreError> {
        self.backend.size_bytes().await
    }

    /// The tokens in force, with their hashes.
    pub async fn active_tokens(&self) -> Result<Vec<(String, Token)>, StoreError> {
        self.backend.active_tokens().await
    }

    /// Stores a new token; its id and text (shown once: only its hash is
    /// kept).
    pub async fn create_token(
        &self,
        name: &str,
        scope: Scope,
        machine: Option<&str>,
        now_t: f64,
    ) -> Result<(i64, String), StoreError> {
        self.backend
            .create_token(name.to_string(), scope, machine.map(str::to_string), now_t)
            .await
    }

    /// Every token, revoked ones included, oldest first.
    pub async fn tokens(&self) -> Result<Vec<Token>, StoreError> {
        self.backend.tokens().await
    }

    /// Revokes a token; the token.
    pub async fn revoke_token(&self, id: i64, now_t: f64) -> Result<Token, StoreError> {
        self.backend.revoke_token(id, now_t).await
    }

    /// The steps of a retention pass of `policy` at `now_t` (blocking).
    pub fn retention_plan(
        &self,
        now_t: f64,
        policy: &Retention,
        batch: usize,
    ) -> Result<Vec<Step>, StoreError> {
        self.backend.retention_plan(now_t, policy, batch)
    }

    /// Does one step of a pass between group commits.
    pub async fn retention_step(&self, step: Step) -> Result<Pruned, StoreError> {
        self.backend.retention_step(step).await
    }
}
