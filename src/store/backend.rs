//! What a store backend implements. [`Store`](super::handle::Store) holds one as
//! `Arc<dyn Backend>`; the server, the command line and the tests use
//! nothing else (a site's outbox, an office's leases and notifications
//! are the SQLite and PostgreSQL stores' own, reached through
//! [`Backend::as_any`]).
//!
//! The contract each method states is the one `tests/store_conformance.rs`
//! holds every backend to, with the same answers.

use std::any::Any;

use async_trait::async_trait;

use super::alarms::{AlarmChange, AlarmFilter, StoredAlarm};
use super::error::StoreError;
use super::history::EstimatesPage;
use super::outbox::{AuditEntry, ForwardHeld, SiteRecord, WebhookEntry};
use super::retention::{Pruned, Retention, Step};
use super::rows::StoredMachine;
use super::rows::StoredSnapshot;
use super::rows::Write;
use crate::auth::{Scope, Token};
use crate::config::MachineSpec;
use crate::fusion::{EngineOutput, Reading, SensorKind, StreamKind};

/// Called with each reading of [`Backend::readings_since`].
pub type EachReading<'a> = &'a mut dyn FnMut(Reading) -> Result<(), StoreError>;
/// Gets the acknowledged alarm of [`Backend::ack_alarm`], ordered with the
/// alarm changes commits report.
pub type Announce = Box<dyn FnOnce(AlarmChange) + Send>;

/// A store backend. Writes are async and answered after their commit;
/// reads are blocking.
#[async_trait]
pub trait Backend: Send + Sync + 'static {
    /// `sqlite`, `postgres`, …: what the health check and errors name.
    fn name(&self) -> &'static str;

    /// The backend itself, for what only it has (a site's outbox on
    /// SQLite, leases on PostgreSQL).
    fn as_any(&self) -> &dyn Any;

    // Writing.

    /// Queues a write; its `reply` is answered after the commit, which
    /// stores each reading once (same machine, sensor and time) in arrival
    /// order, the estimates, the alarm rows (a raise stored once, a clear
    /// closing the open alarm of its key) and the snapshot, and then runs
    /// `after_commit` with the alarms that changed.
    async fn write(&self, write: Write) -> Result<(), StoreError>;

    /// Like [`Backend::write`], from a blocking thread.
    fn write_blocking(&self, write: Write) -> Result<(), StoreError>;

    /// Commits what is queued and stops writing; later writes fail with
    /// [`StoreError::Closed`]. Reads still work.
    async fn close(&self);

    /// Creates or replaces a machine with a fresh engine snapshot (its
    /// readings kept, not fed to the new engines); its id, kept on
    /// redeclaring. `forwarded`: an office stores the site's sequence of
    /// the declaration as the machine's mark in the same commit (a backend
    /// without an [`Office`] refuses it).
    async fn put_machine(
        &self,
        spec: MachineSpec,
        snapshot: String,
        forwarded: Option<i64>,
    ) -> Result<i64, StoreError>;

    // Machines and history.

    /// Every stored machine, ordered by protocol id (PostgreSQL: in the
    /// database's collation), its parameters made current
    /// ([`super::rows::stored_machine`]).
    fn machines(&self) -> Result<Vec<StoredMachine>, StoreError>;

    /// A machine's latest snapshot.
    fn snapshot(&self, machine_id: i64) -> Result<Option<StoredSnapshot>, StoreError>;

    /// Calls `each` with each reading of the machine stored after reading
    /// id `after_id`, in arrival order, without holding them all; how many.
    fn readings_since(
        &self,
        machine_id: i64,
        after_id: i64,
        each: EachReading<'_>,
    ) -> Result<u64, StoreError>;

    /// A machine's estimates of one stream in `[from_t, to_t]`, downsampled
    /// above `max_points` by [`super::history::estimates_page`].
    fn estimates_page(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        max_points: usize,
    ) -> Result<EstimatesPage, StoreError>;

    /// Each stored reading in `[from_t, to_t]` (of one sensor, or all), in
    /// time order, to `each` until it answers false.
    fn export_readings(
        &self,
        machine_id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
        each: &mut dyn FnMut(&Reading) -> bool,
    ) -> Result<(), StoreError>;

    /// Each stored estimate of `engine` in `[from_t, to_t]`, in time order,
    /// to `each` until it answers false.
    fn export_estimates(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        each: &mut dyn FnMut(&EngineOutput) -> bool,
    ) -> Result<(), StoreError>;

    /// The newest stored estimate of a stream.
    fn latest_estimate(
        &self,
        machine_id: i64,
        engine: StreamKind,
    ) -> Result<Option<EngineOutput>, StoreError>;

    /// Time of the newest stored reading of a sensor.
    fn last_reading_t(
        &self,
        machine_id: i64,
        sensor: SensorKind,
    ) -> Result<Option<f64>, StoreError>;

    // Alarms.

    /// The alarms `filter` asks for, newest first.
    fn alarms(&self, filter: &AlarmFilter) -> Result<Vec<StoredAlarm>, StoreError>;

    /// Acknowledges alarm `id` by `by` at `t` (the first acknowledgement
    /// stands); the alarm as it now is and whether this call acknowledged
    /// it, or `None` if there is no such alarm. `announce` gets the
    /// acknowledged alarm after its commit, before any later commit's
    /// changes are reported.
    async fn ack_alarm(
        &self,
        id: i64,
        by: String,
        t: f64,
        announce: Announce,
    ) -> Result<Option<(StoredAlarm, bool)>, StoreError>;

    // Tokens (their hashing is `crate::auth`'s). SQLite writes them
    // through its writer (so not after `close`); PostgreSQL through its
    // pool, beside its writers.

    /// The tokens in force, with their hashes.
    async fn active_tokens(&self) -> Result<Vec<(String, Token)>, StoreError>;

    /// Stores a new token (checked by `crate::auth::check_new`); its id
    /// and text (shown once; only its hash is kept).
    async fn create_token(
        &self,
        name: String,
        scope: Scope,
        machine: Option<String>,
        now_t: f64,
    ) -> Result<(i64, String), StoreError>;

    /// Every token, revoked ones included, oldest first.
    async fn tokens(&self) -> Result<Vec<Token>, StoreError>;

    /// Revokes a token (revoking twice keeps the first time); the token.
    async fn revoke_token(&self, id: i64, now_t: f64) -> Result<Token, StoreError>;

    // Retention and size.

    /// The steps of a retention pass of `policy` at `now_t`
    /// ([`super::retention::plan_steps`]).
    fn retention_plan(
        &self,
        now_t: f64,
        policy: &Retention,
        batch: usize,
    ) -> Result<Vec<Step>, StoreError>;

    /// Does one step of a pass between group commits; what it deleted. A
    /// reading is deleted only if its machine's snapshot covers it.
    async fn retention_step(&self, step: Step) -> Result<Pruned, StoreError>;

    /// Bytes the store takes on disk.
    async fn size_bytes(&self) -> Result<u64, StoreError>;

    // Webhooks (every server may owe them).

    /// Alarm changes owed to the webhook of `severity`, oldest first.
    fn webhook_pending(
        &self,
        severity: &'static str,
        limit: usize,
    ) -> Result<Vec<WebhookEntry>, StoreError>;

    /// A webhook's change is done with (delivered or given up).
    async fn webhook_done(&self, id: i64) -> Result<(), StoreError>;

    /// Forgets the changes owed to a webhook no longer configured; how
    /// many.
    async fn webhook_dropped(&self, severity: &'static str) -> Result<u64, StoreError>;

    /// What an office keeps of forwarded machines, if this backend can be
    /// an office's store.
    fn office(&self) -> Option<&dyn Office> {
        None
    }
}

/// An office's record of forwarded machines (their marks and the rows
/// held), of its sites and of what an admin changed by hand.
#[async_trait]
pub trait Office: Send + Sync {
    /// The last sequence of forwarded machine `machine_id` its site sent
    /// that is committed here.
    fn forward_mark(&self, machine_id: i64) -> Result<Option<i64>, StoreError>;

    /// What this office holds of forwarded machine `machine_id`'s rows.
    fn forward_held(&self, machine_id: i64) -> Result<ForwardHeld, StoreError>;

    /// Sets forwarded machine `machine`'s mark back to `sequence` (never
    /// forward), audited as `actor`'s at `t`; the mark it had (`None`:
    /// not a forwarded machine).
    async fn reset_forward_mark(
        &self,
        machine: String,
        sequence: i64,
        actor: String,
        t: f64,
    ) -> Result<Option<i64>, StoreError>;

    /// The audit log, oldest first.
    fn audit(&self) -> Result<Vec<AuditEntry>, StoreError>;

    /// Every site's record.
    fn sites(&self) -> Result<Vec<SiteRecord>, StoreError>;

    /// Records a site's contact.
    async fn put_site(&self, site: SiteRecord) -> Result<(), StoreError>;
}
