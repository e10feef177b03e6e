//! A store backend kept in memory, for tests only: what adding a backend
//! takes (this folder, and one `mod memory_store;` line where it is used),
//! held to the same conformance suite as SQLite and PostgreSQL
//! (`tests/store_conformance.rs`). Nothing survives the process; a
//! "restart" is [`MemoryStore::reopen`], a new handle on the same rows.
//!
//! It keeps no office's records ([`Backend::office`] is `None`: a
//! forwarded write is refused), no leases (a write under a lease epoch is
//! refused) and no site's outbox (`OutboxConfig::forward` is SQLite's
//! alone: a site keeps its outbox there).

// Not every test binary that includes this module uses all of it.
#![allow(dead_code)]

mod history;
mod retention;
mod rows;

use std::any::Any;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use async_trait::async_trait;
use tunnelnav::auth::{Scope, Token, TokenError};
use tunnelnav::config::MachineSpec;
use tunnelnav::fusion::{EngineOutput, Reading, SensorKind, StreamKind};
use tunnelnav::store::alarms::{AlarmChange, AlarmFilter, Change, StoredAlarm};
use tunnelnav::store::outbox::{OutboxConfig, WebhookEntry};
use tunnelnav::store::retention::{Pruned, Retention, Step};
use tunnelnav::store::{
    Announce, Backend, EachReading, EstimatesPage, StoreError, StoredMachine, StoredSnapshot, Write,
};

use rows::Rows;

/// A cheap handle to rows kept in memory.
#[derive(Clone)]
pub struct MemoryStore {
    rows: Arc<Mutex<Rows>>,
    /// Held from a commit (or an acknowledgement) to the end of its
    /// callbacks, so they run in commit order, as a writer thread runs
    /// them; the rows' lock is not held while they run.
    order: Arc<Mutex<()>>,
    /// Cleared by [`Backend::close`]: this handle then refuses writes.
    open: Arc<AtomicBool>,
    /// Writes still to fail, as a busy database fails them: rolled back,
    /// `after_commit(None)` and the error in the reply.
    failing: Arc<AtomicU32>,
}

impl MemoryStore {
    /// An empty store recording the webhooks' changes `outbox` names.
    pub fn new(outbox: OutboxConfig) -> MemoryStore {
        MemoryStore {
            rows: Arc::new(Mutex::new(Rows::new(outbox))),
            order: Arc::default(),
            open: Arc::new(AtomicBool::new(true)),
            failing: Arc::default(),
        }
    }

    /// Fails the next `writes` writes, as a busy database would.
    pub fn fail_next_writes(&self, writes: u32) {
        self.failing.store(writes, Ordering::SeqCst);
    }

    /// A new handle on the same rows, open for writing: the store after
    /// a restart.
    pub fn reopen(&self) -> MemoryStore {
        MemoryStore {
            rows: self.rows.clone(),
            order: self.order.clone(),
            open: Arc::new(AtomicBool::new(true)),
            failing: Arc::default(),
        }
    }

    /// The rows, locked (a panic while they were held leaves them as the
    /// last write left them: each write checks before it changes).
    fn rows(&self) -> MutexGuard<'_, Rows> {
        self.rows
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    fn writable(&self) -> Result<(), StoreError> {
        if self.open.load(Ordering::SeqCst) {
            Ok(())
        } else {
            Err(StoreError::Closed)
        }
    }

    /// Commits `write` (all or nothing) and answers it as a writer
    /// thread does: `after_commit` with the alarms it changed, then the
    /// reply.
    fn commit(&self, mut write: Write) -> Result<(), StoreError> {
        self.writable()?;
        let _in_order = self.order.lock().unwrap_or_else(|p| p.into_inner());
        let fails = self
            .failing
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| n.checked_sub(1))
            .is_ok();
        let result = if fails {
            Err(StoreError::Unavailable(
                "database is locked (injected)".into(),
            ))
        } else {
            self.rows().write(&write)
        };
        let (outcome, changes) = match result {
            Ok((outcome, changes)) => (Ok(outcome), Some(changes)),
            Err(e) => (Err(e), None),
        };
        if let Some(after_commit) = write.after_commit.take() {
            after_commit(changes);
        }
        if let Some(reply) = write.reply.take() {
            let _ = reply.send(outcome);
        }
        Ok(())
    }
}

#[async_trait]
impl Backend for MemoryStore {
    fn name(&self) -> &'static str {
        "memory"
    }

    fn as_any(&self) -> &dyn Any {
        self
    }

    async fn write(&self, write: Write) -> Result<(), StoreError> {
        self.commit(write)
    }

    fn write_blocking(&self, write: Write) -> Result<(), StoreError> {
        self.commit(write)
    }

    async fn close(&self) {
        self.open.store(false, Ordering::SeqCst);
    }

    async fn put_machine(
        &self,
        spec: MachineSpec,
        snapshot: String,
        forwarded: Option<i64>,
    ) -> Result<i64, StoreError> {
        self.writable()?;
        if forwarded.is_some() {
            return Err(StoreError::Unsupported {
                backend: "memory",
                what: "an office's forwarded machines",
            });
        }
        self.rows().put_machine(&spec, snapshot)
    }

    fn machines(&self) -> Result<Vec<StoredMachine>, StoreError> {
        self.rows().machines()
    }

    fn snapshot(&self, machine_id: i64) -> Result<Option<StoredSnapshot>, StoreError> {
        Ok(self.rows().snapshot(machine_id))
    }

    fn readings_since(
        &self,
        machine_id: i64,
        after_id: i64,
        each: EachReading<'_>,
    ) -> Result<u64, StoreError> {
        // Decoded under the lock, handed out after it (`each` may be slow):
        // the rows are all in memory anyway.
        let readings = self.rows().readings_since(machine_id, after_id)?;
        let count = readings.len() as u64;
        for reading in readings {
            each(reading)?;
        }
        Ok(count)
    }

    fn estimates_page(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        max_points: usize,
    ) -> Result<EstimatesPage, StoreError> {
        let rows = self.rows();
        let mut source = history::MemoryHistory {
            rows: &rows,
            machine_id,
            engine,
        };
        tunnelnav::store::history::estimates_page(&mut source, from_t, to_t, max_points)
    }

    fn export_readings(
        &self,
        machine_id: i64,
        sensor: Option<SensorKind>,
        from_t: f64,
        to_t: f64,
        each: &mut dyn FnMut(&Reading) -> bool,
    ) -> Result<(), StoreError> {
        let readings = self
            .rows()
            .readings_between(machine_id, sensor, from_t, to_t)?;
        for reading in &readings {
            if !each(reading) {
                break;
            }
        }
        Ok(())
    }

    fn export_estimates(
        &self,
        machine_id: i64,
        engine: StreamKind,
        from_t: f64,
        to_t: f64,
        each: &mut dyn FnMut(&EngineOutput) -> bool,
    ) -> Result<(), StoreError> {
        let estimates = self
            .rows()
            .estimates_between(machine_id, engine, from_t, to_t)?;
        for estimate in &estimates {
            if !each(estimate) {
                break;
            }
        }
        Ok(())
    }

    fn latest_estimate(
        &self,
        machine_id: i64,
        engine: StreamKind,
    ) -> Result<Option<EngineOutput>, StoreError> {
        self.rows().latest_estimate(machine_id, engine)
    }

    fn last_reading_t(
        &self,
        machine_id: i64,
        sensor: SensorKind,
    ) -> Result<Option<f64>, StoreError> {
        Ok(self.rows().last_reading_t(machine_id, sensor))
    }

    fn alarms(&self, filter: &AlarmFilter) -> Result<Vec<StoredAlarm>, StoreError> {
        Ok(self.rows().alarms(filter))
    }

    async fn ack_alarm(
        &self,
        id: i64,
        by: String,
        t: f64,
        announce: Announce,
    ) -> Result<Option<(StoredAlarm, bool)>, StoreError> {
        self.writable()?;
        let _in_order = self.order.lock().unwrap_or_else(|p| p.into_inner());
        let (alarm, acked) = {
            let mut rows = self.rows();
            let Some((alarm, acked)) = rows.ack_alarm(id, &by, t) else {
                return Ok(None);
            };
            if acked {
                rows.owe_webhook(AlarmChange {
                    transition: Change::Acknowledged,
                    alarm: alarm.clone(),
                });
            }
            (alarm, acked)
        };
        if acked {
            announce(AlarmChange {
                transition: Change::Acknowledged,
                alarm: alarm.clone(),
            });
        }
        Ok(Some((alarm, acked)))
    }

    async fn active_tokens(&self) -> Result<Vec<(String, Token)>, StoreError> {
        Ok(self
            .rows()
            .tokens
            .iter()
            .filter(|(_, token)| token.revoked_t.is_none())
            .cloned()
            .collect())
    }

    async fn create_token(
        &self,
        name: String,
        scope: Scope,
        machine: Option<String>,
        now_t: f64,
    ) -> Result<(i64, String), StoreError> {
        self.writable()?;
        tunnelnav::auth::check_new(scope, machine.as_deref())?;
        let (text, hash) = tunnelnav::auth::generate();
        let mut rows = self.rows();
        let id = rows.tokens.len() as i64 + 1;
        rows.tokens.push((
            hash,
            Token {
                id,
                name,
                scope,
                machine,
                created_t: now_t,
                revoked_t: None,
            },
        ));
        Ok((id, text))
    }

    async fn tokens(&self) -> Result<Vec<Token>, StoreError> {
        Ok(self.rows().tokens.iter().map(|(_, t)| t.clone()).collect())
    }

    async fn revoke_token(&self, id: i64, now_t: f64) -> Result<Token, StoreError> {
        self.writable()?;
        let mut rows = self.rows();
        let (_, token) = rows
            .tokens
            .iter_mut()
            .find(|(_, token)| token.id == id)
            .ok_or(StoreError::Token(TokenError::NoSuchToken(id)))?;
        token.revoked_t.get_or_insert(now_t);
        Ok(token.clone())
    }

    fn retention_plan(
        &self,
        now_t: f64,
        policy: &Retention,
        batch: usize,
    ) -> Result<Vec<Step>, StoreError> {
        retention::plan(&self.rows(), now_t, policy, batch)
    }

    async fn retention_step(&self, step: Step) -> Result<Pruned, StoreError> {
        self.writable()?;
        Ok(retention::apply(&mut self.rows(), &step))
    }

    async fn size_bytes(&self) -> Result<u64, StoreError> {
        Ok(self.rows().bytes())
    }

    fn webhook_pending(
        &self,
        severity: &'static str,
        limit: usize,
    ) -> Result<Vec<WebhookEntry>, StoreError> {
        Ok(self
            .rows()
            .webhooks
            .iter()
            .filter(|entry| entry.change.alarm.severity == severity)
            .take(limit)
            .cloned()
            .collect())
    }

    async fn webhook_done(&self, id: i64) -> Result<(), StoreError> {
        self.writable()?;
        self.rows().webhooks.retain(|entry| entry.id != id);
        Ok(())
    }

    async fn webhook_dropped(&self, severity: &'static str) -> Result<u64, StoreError> {
        self.writable()?;
        let mut rows = self.rows();
        let before = rows.webhooks.len();
        rows.webhooks
            .retain(|entry| entry.change.alarm.severity != severity);
        Ok((before - rows.webhooks.len()) as u64)
    }
}
