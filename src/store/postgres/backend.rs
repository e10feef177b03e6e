//! The PostgreSQL store as a [`Backend`]: each method is the store's own,
//! written in the topic file it belongs to.

use std::any::Any;

use async_trait::async_trait;

use super::handle::PgStore;
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
impl Backend for PgStore {
    fn name(&self) -> &'static str {
        "postgres"
    }

    fn as_any(&self) -> &dyn Any {
        self
    }

    async fn write(&self, write: Write) -> Result<(), StoreError> {
        PgStore::write(self, write).await
    }

    fn write_blocking(&self, write: Write) -> Result<(), StoreError> {
        PgStore::write_blocking(self, write)
    }

    async fn close(&self) {
        PgStore::close(self).await
    }

    async fn put_machine(
        &self,
        spec: MachineSpec,
        snapshot: String,
        forwarded: Option<i64>,
    ) -> Result<i64, StoreError> {
        PgStore::put_machine(self, spec, snapshot, forwarded).await
    }

    fn machines(&self) -> Result<Vec<StoredMachine>, StoreError> {
        PgStore::machines(self)
    }

    fn snapshot(&self, machine_id: i64) -> Result<Option<StoredSnapshot>, StoreError> {
        PgStore::snapshot(self, machine_id)
    }

    fn readings_since(
        &self,
        machine_id: i64,
        after_id: i64,
        each: EachReading<'_>,
    ) -> Result<u64, StoreError> {
        PgStore::readings_since(self, machine_id, after_id, each)
    }

    fn estimates_page(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        max_points: usize,
    ) -> Result<EstimatesPage, StoreError> {
        PgStore::estimates_page(self, machine_id, engine, from_t, to_t, max_points)
    }

    fn export_readings(
        &self,
        machine_id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
        each: &mut dyn FnMut(&Reading) -> bool,
    ) -> Result<(), StoreError> {
        PgStore::export_readings(self, machine_id, sensor, from_t, to_t, each)
    }

    fn export_estimates(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        each: &mut dyn FnMut(&EngineOutput) -> bool,
    ) -> Result<(), StoreError> {
        PgStore::export_estimates(self, machine_id, engine, from_t, to_t, each)
    }

    fn latest_estimate(
        &self,
        machine_id: i64,
        engine: StreamKind,
    ) -> Result<Option<EngineOutput>, StoreError> {
        PgStore::latest_estimate(self, machine_id, engine)
    }

    fn last_reading_t(
        &self,
        machine_id: i64,
        sensor: SensorKind,
    ) -> Result<Option<f64>, StoreError> {
        PgStore::last_reading_t(self, machine_id, sensor)
    }

    fn alarms(&self, filter: &AlarmFilter) -> Result<Vec<StoredAlarm>, StoreError> {
        PgStore::alarms(self, filter)
    }

    async fn ack_alarm(
        &self,
        id: i64,
        by: String,
        t: f64,
        announce: Announce,
    ) -> Result<Option<(StoredAlarm, bool)>, StoreError> {
        PgStore::ack_alarm(self, id, by, t, announce).await
    }

    async fn active_tokens(&self) -> Result<Vec<(String, Token)>, StoreError> {
        PgStore::active_tokens(self).await
    }

    async fn create_token(
        &self,
        name: String,
        scope: Scope,
        machine: Option<String>,
        now_t: f64,
    ) -> Result<(i64, String), StoreError> {
        PgStore::create_token(self, &name, scope, machine.as_deref(), now_t).await
    }

    async fn tokens(&self) -> Result<Vec<Token>, StoreError> {
        PgStore::tokens(self).await
    }

    async fn revoke_token(&self, id: i64, now_t: f64) -> Result<Token, StoreError> {
        PgStore::revoke_token(self, id, now_t).await
    }

    fn retention_plan(
        &self,
        now_t: f64,
        policy: &Retention,
        batch: usize,
    ) -> Result<Vec<Step>, StoreError> {
        PgStore::retention_plan(self, now_t, policy, batch)
    }

    async fn retention_step(&self, step: Step) -> Result<Pruned, StoreError> {
        PgStore::retention_step(self, step).await
    }

    async fn size_bytes(&self) -> Result<u64, StoreError> {
        PgStore::size_bytes(self).await
    }

    fn webhook_pending(
        &self,
        severity: &'static str,
        limit: usize,
    ) -> Result<Vec<WebhookEntry>, StoreError> {
        PgStore::webhook_pending(self, severity, limit)
    }

    async fn webhook_done(&self, id: i64) -> Result<(), StoreError> {
        PgStore::webhook_done(self, id).await
    }

    async fn webhook_dropped(&self, severity: &'static str) -> Result<u64, StoreError> {
        PgStore::webhook_dropped(self, severity).await
    }

    fn office(&self) -> Option<&dyn Office> {
        Some(self)
    }
}

#[async_trait]
impl Office for PgStore {
    fn forward_mark(&self, machine_id: i64) -> Result<Option<i64>, StoreError> {
        PgStore::forward_mark(self, machine_id)
    }

    fn forward_held(&self, machine_id: i64) -> Result<ForwardHeld, StoreError> {
        PgStore::forward_held(self, machine_id)
    }

    async fn reset_forward_mark(
        &self,
        machine: String,
        sequence: i64,
        actor: String,
        t: f64,
    ) -> Result<Option<i64>, StoreError> {
        PgStore::reset_forward_mark(self, machine, sequence, actor, t).await
    }

    fn audit(&self) -> Result<Vec<AuditEntry>, StoreError> {
        PgStore::audit(self)
    }

    fn sites(&self) -> Result<Vec<SiteRecord>, StoreError> {
        PgStore::sites(self)
    }

    async fn put_site(&self, site: SiteRecord) -> Result<(), StoreError> {
        PgStore::put_site(self, site).await
    }
}
