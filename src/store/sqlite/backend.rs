//! The SQLite store as a [`Backend`]: each method is the store's own,
//! written in the topic file it belongs to.

use std::any::Any;

use async_trait::async_trait;

use super::handle::SqliteStore;
use super::{retention, tokens};
use crate::auth::{Scope, Token};
use crate::config::MachineSpec;
use crate::fusion::{EngineOutput, Reading, SensorKind, StreamKind};
use crate::store::alarms::{AlarmFilter, StoredAlarm};
use crate::store::backend::{Announce, Backend, EachReading, Office};
use crate::store::error::StoreError;
use crate::store::history::EstimatesPage;
use crate::store::outbox::{AuditEntry, ForwardHeld, SiteRecord, WebhookEntry};
use crate::store::retention::{Pruned, Retention, Step};
use crate::store::rows::StoredMachine;
use crate::store::rows::StoredSnapshot;
use crate::store::rows::Write;

#[async_trait]
impl Backend for SqliteStore {
    fn name(&self) -> &'static str {
        "sqlite"
    }

    fn as_any(&self) -> &dyn Any {
        self
    }

    async fn write(&self, write: Write) -> Result<(), StoreError> {
        SqliteStore::write(self, write).await
    }

    fn write_blocking(&self, write: Write) -> Result<(), StoreError> {
        SqliteStore::write_blocking(self, write)
    }

    async fn close(&self) {
        SqliteStore::close(self).await
    }

    async fn put_machine(
        &self,
        spec: MachineSpec,
        snapshot: String,
        forwarded: Option<i64>,
    ) -> Result<i64, StoreError> {
        SqliteStore::put_machine(self, spec, snapshot, forwarded).await
    }

    fn machines(&self) -> Result<Vec<StoredMachine>, StoreError> {
        SqliteStore::machines(self)
    }

    fn snapshot(&self, machine_id: i64) -> Result<Option<StoredSnapshot>, StoreError> {
        SqliteStore::snapshot(self, machine_id)
    }

    fn readings_since(
        &self,
        machine_id: i64,
        after_id: i64,
        each: EachReading<'_>,
    ) -> Result<u64, StoreError> {
        SqliteStore::readings_since(self, machine_id, after_id, each)
    }

    fn estimates_page(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        max_points: usize,
    ) -> Result<EstimatesPage, StoreError> {
        SqliteStore::estimates_page(self, machine_id, engine, from_t, to_t, max_points)
    }

    fn export_readings(
        &self,
        machine_id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
        each: &mut dyn FnMut(&Reading) -> bool,
    ) -> Result<(), StoreError> {
        SqliteStore::export_readings(self, machine_id, sensor, from_t, to_t, each)
    }

    fn export_estimates(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        each: &mut dyn FnMut(&EngineOutput) -> bool,
    ) -> Result<(), StoreError> {
        SqliteStore::export_estimates(self, machine_id, engine, from_t, to_t, each)
    }

    fn latest_estimate(
        &self,
        machine_id: i64,
        engine: StreamKind,
    ) -> Result<Option<EngineOutput>, StoreError> {
        SqliteStore::latest_estimate(self, machine_id, engine)
    }

    fn last_reading_t(
        &self,
        machine_id: i64,
        sensor: SensorKind,
    ) -> Result<Option<f64>, StoreError> {
        SqliteStore::last_reading_t(self, machine_id, sensor)
    }

    fn alarms(&self, filter: &AlarmFilter) -> Result<Vec<StoredAlarm>, StoreError> {
        SqliteStore::alarms(self, filter)
    }

    async fn ack_alarm(
        &self,
        id: i64,
        by: String,
        t: f64,
        announce: Announce,
    ) -> Result<Option<(StoredAlarm, bool)>, StoreError> {
        SqliteStore::ack_alarm(self, id, by, t, announce).await
    }

    async fn active_tokens(&self) -> Result<Vec<(String, Token)>, StoreError> {
        let store = self.clone();
        tokio::task::spawn_blocking(move || store.read(tokens::active))
            .await
            .map_err(|e| StoreError::Corrupt(format!("token read: {e}")))?
    }

    async fn create_token(
        &self,
        name: String,
        scope: Scope,
        machine: Option<String>,
        now_t: f64,
    ) -> Result<(i64, String), StoreError> {
        self.maintain(move |conn| tokens::create(conn, &name, scope, machine.as_deref(), now_t))
            .await
    }

    async fn tokens(&self) -> Result<Vec<Token>, StoreError> {
        let store = self.clone();
        tokio::task::spawn_blocking(move || store.read(tokens::list))
            .await
            .map_err(|e| StoreError::Corrupt(format!("token read: {e}")))?
    }

    async fn revoke_token(&self, id: i64, now_t: f64) -> Result<Token, StoreError> {
        self.maintain(move |conn| tokens::revoke(conn, id, now_t))
            .await
    }

    fn retention_plan(
        &self,
        now_t: f64,
        policy: &Retention,
        batch: usize,
    ) -> Result<Vec<Step>, StoreError> {
        self.read(|conn| retention::plan(conn, now_t, policy, batch))
    }

    async fn retention_step(&self, step: Step) -> Result<Pruned, StoreError> {
        self.maintain(move |conn| retention::apply(conn, &step))
            .await
    }

    async fn size_bytes(&self) -> Result<u64, StoreError> {
        Ok(SqliteStore::size_bytes(self))
    }

    fn webhook_pending(
        &self,
        severity: &'static str,
        limit: usize,
    ) -> Result<Vec<WebhookEntry>, StoreError> {
        SqliteStore::webhook_pending(self, severity, limit)
    }

    async fn webhook_done(&self, id: i64) -> Result<(), StoreError> {
        SqliteStore::webhook_done(self, id).await
    }

    async fn webhook_dropped(&self, severity: &'static str) -> Result<u64, StoreError> {
        SqliteStore::webhook_dropped(self, severity).await
    }

    fn office(&self) -> Option<&dyn Office> {
        Some(self)
    }
}

#[async_trait]
impl Office for SqliteStore {
    fn forward_mark(&self, machine_id: i64) -> Result<Option<i64>, StoreError> {
        SqliteStore::forward_mark(self, machine_id)
    }

    fn forward_held(&self, machine_id: i64) -> Result<ForwardHeld, StoreError> {
        SqliteStore::forward_held(self, machine_id)
    }

    async fn reset_forward_mark(
        &self,
        machine: String,
        sequence: i64,
        actor: String,
        t: f64,
    ) -> Result<Option<i64>, StoreError> {
        SqliteStore::reset_forward_mark(self, machine, sequence, actor, t).await
    }

    fn audit(&self) -> Result<Vec<AuditEntry>, StoreError> {
        SqliteStore::audit(self)
    }

    fn sites(&self) -> Result<Vec<SiteRecord>, StoreError> {
        SqliteStore::sites(self)
    }

    async fn put_site(&self, site: SiteRecord) -> Result<(), StoreError> {
        SqliteStore::put_site(self, site).await
    }
}
