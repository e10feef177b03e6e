//! The server's shared state: the store, the running machines and what
//! every handler needs (limits, clock, alarm notifier, socket counts), with
//! start-up (restore every machine, start its task) and shutdown.

use std::collections::BTreeMap;
use std::future::Future;
use std::path::PathBuf;
use std::sync::{Arc, RwLock};

use tokio::sync::watch;

use super::error::ApiError;
use super::settings::{Limits, WebhookConfig};
use super::{auth, metrics, notify};
use crate::clock::Clock;
use crate::config::MachineSpec;
use crate::machine::{self, MachineCore, MachineError, MachineHandle};
use crate::store::{Store, StoreError};

/// How to start a server.
#[derive(Debug, Clone)]
pub struct ServerOptions {
    pub data_dir: PathBuf,
    /// The PostgreSQL store; `None`: SQLite in `data_dir`.
    pub postgres: Option<crate::store::postgres::PgLocation>,
    /// Machines declared by the config file: created, or replaced where the
    /// stored declaration differs.
    pub machines: Vec<MachineSpec>,
    pub limits: Limits,
    /// The clock for ages and the future check ([`Clock::system`] but in the demo).
    pub clock: Clock,
    /// What history to keep.
    pub retention: crate::store::retention::Retention,
    /// Where alarm changes are posted.
    pub webhooks: WebhookConfig,
}

/// Why the server could not start.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("machine `{machine}`: {source}")]
    Machine {
        machine: String,
        source: MachineError,
    },
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// What every handler shares.
pub struct AppState {
    pub store: Store,
    machines: RwLock<BTreeMap<String, Arc<MachineHandle>>>,
    /// Serialises machine (re)declarations.
    admin: tokio::sync::Mutex<()>,
    pub limits: Limits,
    pub clock: Clock,
    /// Turns true when the server stops: live sockets close.
    shutdown: watch::Sender<bool>,
    /// Access tokens in force.
    pub gate: auth::Gate,
    /// Stored alarm changes to live clients and webhooks.
    pub alarms: notify::AlarmNotifier,
    /// Live sockets open now: shutdown waits (a little) for their close
    /// frames to go out.
    live_sockets: Arc<std::sync::atomic::AtomicUsize>,
    /// Fleet alarm sockets open now (at most `Limits::max_alarm_clients`).
    alarm_sockets: Arc<std::sync::atomic::AtomicUsize>,
}

/// Counts an open live socket while it lives.
pub struct LiveSocketGuard(Arc<std::sync::atomic::AtomicUsize>);

impl Drop for LiveSocketGuard {
    fn drop(&mut self) {
        self.0.fetch_sub(1, std::sync::atomic::Ordering::SeqCst);
    }
}

pub type SharedState = Arc<AppState>;

impl AppState {
    /// Opens the store, applies the configured machines, restores every
    /// machine from its snapshot and starts their tasks.
    pub async fn start(options: ServerOptions) -> Result<SharedState, ServerError> {
        let store = match &options.postgres {
            Some(location) => Store::open_postgres(location).await?,
            None => Store::open_capped(&options.data_dir, options.limits.max_database_bytes)?,
        };
        let stored = {
            let store = store.clone();
            tokio::task::spawn_blocking(move || store.machines())
                .await
                .map_err(std::io::Error::other)??
        };
        let mut specs: BTreeMap<String, (i64, MachineSpec)> = stored
            .into_iter()
            .map(|m| (m.spec.id.clone(), (m.db_id, m.spec)))
            .collect();
        for spec in options.machines {
            let unchanged = specs.get(&spec.id).is_some_and(|(_, s)| *s == spec);
            if !unchanged {
                let fresh = fresh_snapshot(&spec)?;
                let id = store.put_machine(spec.clone(), fresh).await?;
                tracing::info!(machine = %spec.id, "machine declared by the config file");
                specs.insert(spec.id.clone(), (id, spec));
            }
        }
        let alarms = notify::AlarmNotifier::start(&options.webhooks);
        let mut machines = BTreeMap::new();
        for (id, (db_id, spec)) in specs {
            metrics::register_machine(&spec);
            let (core, status) = {
                let (store, spec) = (store.clone(), spec.clone());
                tokio::task::spawn_blocking(move || {
                    let core = machine::recover(&store, &spec, db_id)?;
                    Ok((core, machine::stored_status(&store, &spec, db_id)?))
                })
                .await
                .map_err(std::io::Error::other)?
                .map_err(|source| ServerError::Machine {
                    machine: id.clone(),
                    source,
                })?
            };
            machines.insert(
                id,
                Arc::new(machine::spawn(
                    machine::Surroundings {
                        store: store.clone(),
                        queue_len: options.limits.machine_queue,
                        clock: options.clock,
                        alarm_changes: Arc::new(alarms.clone()),
                    },
                    spec,
                    db_id,
                    core,
                    status,
                )),
            );
        }
        if !options.retention.keeps_everything() {
            tokio::spawn(apply_retention(
                store.clone(),
                options.retention,
                options.clock,
            ));
        }
        Ok(Arc::new(AppState {
            store,
            machines: RwLock::new(machines),
            admin: tokio::sync::Mutex::new(()),
            limits: options.limits,
            clock: options.clock,
            shutdown: watch::channel(false).0,
            gate: auth::Gate::default(),
            alarms,
            live_sockets: Arc::default(),
            alarm_sockets: Arc::default(),
        }))
    }

    /// Counts a live socket until the guard drops.
    pub fn live_socket(&self) -> LiveSocketGuard {
        self.live_sockets
            .fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        LiveSocketGuard(self.live_sockets.clone())
    }

    /// Counts a fleet alarm socket until the guard drops; `None` when
    /// there are as many as the limit allows.
    pub fn alarm_socket(&self) -> Option<LiveSocketGuard> {
        use std::sync::atomic::Ordering::SeqCst;
        let most = self.limits.max_alarm_clients;
        self.alarm_sockets
            .fetch_update(SeqCst, SeqCst, |open| (open < most).then_some(open + 1))
            .ok()?;
        Some(LiveSocketGuard(self.alarm_sockets.clone()))
    }

    /// A running machine.
    pub fn machine(&self, id: &str) -> Result<Arc<MachineHandle>, ApiError> {
        self.machines
            .read()
            .ok()
            .and_then(|m| m.get(id).cloned())
            .ok_or_else(|| ApiError::UnknownMachine(id.to_string()))
    }

    /// Runs `op` on machine `id`; if a redeclaration stopped that machine
    /// under it, runs it again on its successor once the redeclaration is
    /// done, so a gateway or a reader does not see the restart. A machine
    /// that stopped otherwise (the server shutting down, a failed
    /// redeclaration) answers 503 at once.
    pub async fn on_machine<T, Fut>(
        &self,
        id: &str,
        op: impl Fn(Arc<MachineHandle>) -> Fut,
    ) -> Result<T, ApiError>
    where
        Fut: Future<Output = Result<T, MachineError>>,
    {
        let mut machine = self.machine(id)?;
        // A few successive redeclarations are followed; not more.
        for _ in 0..3 {
            match op(machine.clone()).await {
                Err(MachineError::Stopped(_)) if !*self.shutdown.borrow() => {
                    // A redeclaration holds this until its successor runs.
                    drop(self.admin.lock().await);
                    let successor = self.machine(id)?;
                    if Arc::ptr_eq(&successor, &machine) {
                        break;
                    }
                    machine = successor;
                }
                outcome => return outcome.map_err(ApiError::from),
            }
        }
        Err(MachineError::Stopped(id.to_string()).into())
    }

    /// Every running machine, by id.
    pub fn all_machines(&self) -> Vec<Arc<MachineHandle>> {
        self.machines
            .read()
            .map(|m| m.values().cloned().collect())
            .unwrap_or_default()
    }

    /// Creates or replaces a machine. Returns whether it was created and
    /// whether anything changed (an identical declaration keeps the state).
    pub async fn declare(&self, spec: MachineSpec) -> Result<(bool, bool), ApiError> {
        let _admin = self.admin.lock().await;
        let existing = self.machine(&spec.id).ok();
        let mut kept = None;
        if let Some(existing) = &existing {
            if *existing.spec == spec {
                return Ok((false, false));
            }
            existing.stop().await;
            // Only what the stages read changed (the design axis, say):
            // the engines go on from the snapshot the stop stored.
            let old = &existing.spec;
            if old.engines == spec.engines && old.reorder_window_s == spec.reorder_window_s {
                let (store, db_id) = (self.store.clone(), existing.db_id);
                let snapshot = tokio::task::spawn_blocking(move || store.snapshot(db_id))
                    .await
                    .map_err(|e| ApiError::Internal(e.to_string()))??;
                if let Some(snapshot) = snapshot {
                    kept = Some(
                        MachineCore::redeclared(&spec, &snapshot.state)
                            .map_err(|e| ApiError::Internal(e.to_string()))?,
                    );
                }
            }
        }
        let core = match kept {
            Some(core) => core,
            None => MachineCore::new(&spec).map_err(|e| ApiError::BadRequest(e.to_string()))?,
        };
        let db_id = self
            .store
            .put_machine(spec.clone(), core.snapshot())
            .await?;
        metrics::register_machine(&spec);
        // A redeclared machine keeps its history, so its status too.
        let status = existing
            .as_ref()
            .map(|m| (*m.status()).clone())
            .unwrap_or_default();
        let handle = Arc::new(machine::spawn(
            machine::Surroundings {
                store: self.store.clone(),
                queue_len: self.limits.machine_queue,
                clock: self.clock,
                alarm_changes: Arc::new(self.alarms.clone()),
            },
            spec.clone(),
            db_id,
            core,
            status,
        ));
        if let Ok(mut machines) = self.machines.write() {
            machines.insert(spec.id, handle);
        }
        Ok((existing.is_none(), true))
    }

    /// Tells live sockets the server is stopping: they close.
    pub fn signal_shutdown(&self) {
        self.shutdown.send_replace(true);
    }

    /// Live sockets open now.
    pub fn live_sockets_open(&self) -> usize {
        self.live_sockets.load(std::sync::atomic::Ordering::SeqCst)
    }

    /// A receiver that turns true when the server stops.
    pub fn shutdown_signal(&self) -> watch::Receiver<bool> {
        self.shutdown.subscribe()
    }

    /// Closes live sockets, stores a final snapshot of every machine and
    /// closes the store.
    pub async fn stop(&self) {
        self.shutdown.send_replace(true);
        for machine in self.all_machines() {
            machine.stop().await;
        }
        self.store.close().await;
    }
}

fn fresh_snapshot(spec: &MachineSpec) -> Result<String, ServerError> {
    MachineCore::new(spec)
        .map(|core| core.snapshot())
        .map_err(|e| ServerError::Machine {
            machine: spec.id.clone(),
            source: e.into(),
        })
}

/// Applies the retention policy now and every `every_s`: each pass is
/// planned on a read connection and done step by step on the store's
/// writer between its commits (see `store::retention`).
async fn apply_retention(store: Store, policy: crate::store::retention::Retention, clock: Clock) {
    use crate::store::retention::Pruned;
    let every = std::time::Duration::from_secs_f64(policy.every_s.max(1.0));
    let mut tick = tokio::time::interval(every);
    loop {
        tick.tick().await;
        let now_t = clock.now_s();
        let pass = async {
            let planner = store.clone();
            let steps =
                tokio::task::spawn_blocking(move || planner.retention_plan(now_t, &policy, 5000))
                    .await
                    .map_err(|e| {
                        crate::store::StoreError::Corrupt(format!("retention plan: {e}"))
                    })??;
            let mut pruned = Pruned::default();
            for step in steps {
                loop {
                    let done = store.retention_step(step).await?;
                    pruned.add(done);
                    if !step.again(&done) {
                        break;
                    }
                }
            }
            Ok::<_, crate::store::StoreError>(pruned)
        };
        match pass.await {
            Ok(pruned) => tracing::info!(
                readings = pruned.readings,
                estimates = pruned.estimates,
                "retention pass"
            ),
            Err(e) => tracing::warn!(error = %e, "retention pass failed; next time again"),
        }
    }
}
