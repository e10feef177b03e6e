//! The server's shared state: the store, the running machines and what
//! every handler needs (limits, clock, alarm notifier, socket counts), with
//! start-up (restore every machine, start its task) and shutdown.

use std::collections::BTreeMap;
use std::future::Future;
use std::path::PathBuf;
use std::sync::{Arc, RwLock};

use tokio::sync::watch;

use super::cluster::Cluster;
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
    /// How this node joins the others on the PostgreSQL store (`None` on
    /// SQLite: one server).
    pub cluster: Option<super::cluster::ClusterOptions>,
    /// A site: the office it forwards to (`serve --forward-to`).
    pub forward: Option<super::forward::ForwardOptions>,
    /// An office: a site's backlog older than this raises `site_link`.
    pub site_backlog_alarm_s: f64,
    /// The level of the one line per request (`serve`: INFO; the demo,
    /// whose own gateways post dozens a second: DEBUG).
    pub access_log: tracing::Level,
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
    #[error("joining the other nodes: {0}")]
    Cluster(String),
    #[error("forwarding to the office: {0}")]
    Forward(#[from] super::forward::ForwardError),
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
    /// This node's part among several on one PostgreSQL store.
    pub cluster: Option<Arc<Cluster>>,
    /// An office: the sites' links as they last reported.
    pub sites: super::sites::SiteLinks,
    /// An office: a site's backlog older than this raises `site_link`.
    pub site_backlog_alarm_s: f64,
    /// [`ServerOptions::access_log`].
    pub access_log: tracing::Level,
    /// Reports being read and drawn ([`Limits::reports_at_once`] permits):
    /// each holds its rows in memory, so more wait their turn.
    pub reports: Arc<tokio::sync::Semaphore>,
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
    /// machine from its snapshot and starts their tasks (on PostgreSQL: the
    /// machines this node holds, see [`super::cluster`]).
    pub async fn start(options: ServerOptions) -> Result<SharedState, ServerError> {
        let outbox = crate::store::outbox::OutboxConfig {
            forward: options.forward.is_some(),
            webhook_warn: options.webhooks.warn.is_some(),
            webhook_alarm: options.webhooks.alarm.is_some(),
        };
        let store = match &options.postgres {
            Some(_) if options.forward.is_some() => {
                return Err(ServerError::Store(crate::store::StoreError::Location(
                    "a site forwarding to an office keeps its outbox in SQLite (--data-dir): \
                     serve the site without --store"
                        .into(),
                )));
            }
            Some(location) => Store::open_postgres(location, outbox).await?,
            None => Store::open_with(&options.data_dir, options.limits.max_database_bytes, outbox)?,
        };
        let cluster = match (&options.cluster, store.postgres()) {
            (Some(joining), Some(_)) => Some(Arc::new(Cluster::join(&store, joining).await?)),
            (None, Some(_)) => {
                return Err(ServerError::Cluster(
                    "a server on the PostgreSQL store is a node: it needs a name and the URL \
                     the other nodes reach it at"
                        .into(),
                ));
            }
            _ => None,
        };
        let stored = {
            let store = store.clone();
            tokio::task::spawn_blocking(move || store.machines())
                .await
                .map_err(std::io::Error::other)??
        };
        let specs: BTreeMap<String, MachineSpec> = stored
            .into_iter()
            .map(|m| (m.spec.id.clone(), m.spec))
            .collect();
        for spec in options.machines {
            if specs.get(&spec.id).is_some_and(|s| *s == spec) {
                continue;
            }
            if let Some(cluster) = &cluster
                && let super::cluster::Route::Forward(url) = cluster.route(&spec.id).await
            {
                tracing::warn!(machine = %spec.id, node = %url, "the config file declares a machine another node runs: declare it there (PUT), this node leaves it as it is");
                continue;
            }
            let fresh = fresh_snapshot(&spec)?;
            store.put_machine(spec.clone(), fresh).await?;
            tracing::info!(machine = %spec.id, "machine declared by the config file");
        }
        {
            for (severity, url) in [
                ("warn", &options.webhooks.warn),
                ("alarm", &options.webhooks.alarm),
            ] {
                if url.is_none() {
                    let dropped = store.webhook_dropped(severity).await?;
                    if dropped > 0 {
                        tracing::warn!(
                            severity,
                            dropped,
                            "alarm changes owed to a webhook no longer configured: forgotten"
                        );
                    }
                }
            }
        }
        let alarms = notify::AlarmNotifier::start(&options.webhooks, &store);
        let sites = {
            let store = store.clone();
            tokio::task::spawn_blocking(move || {
                let records = store.sites()?;
                let open = store.alarms(&crate::store::alarms::AlarmFilter {
                    machine: None,
                    active_only: true,
                    ..Default::default()
                })?;
                let raised: Vec<String> = open
                    .into_iter()
                    .filter(|a| a.kind == crate::fusion::alarms::AlarmKind::SiteLink.as_str())
                    .map(|a| a.subject)
                    .collect();
                Ok::<_, crate::store::StoreError>(super::sites::SiteLinks::load(records, &raised))
            })
            .await
            .map_err(std::io::Error::other)??
        };
        if !options.retention.keeps_everything() {
            tokio::spawn(apply_retention(
                store.clone(),
                options.retention,
                options.clock,
            ));
        }
        let state = Arc::new(AppState {
            store,
            machines: RwLock::new(BTreeMap::new()),
            admin: tokio::sync::Mutex::new(()),
            reports: Arc::new(tokio::sync::Semaphore::new(options.limits.reports_at_once)),
            limits: options.limits,
            clock: options.clock,
            shutdown: watch::channel(false).0,
            gate: auth::Gate::default(),
            alarms,
            live_sockets: Arc::default(),
            alarm_sockets: Arc::default(),
            cluster: cluster.clone(),
            sites,
            site_backlog_alarm_s: options.site_backlog_alarm_s,
            access_log: options.access_log,
        });
        match cluster {
            Some(cluster) => {
                if let Some(postgres) = state.store.postgres() {
                    tokio::spawn(super::feeds::relay(state.clone(), postgres.listen()));
                }
                super::cluster::start(&state, cluster)
                    .await
                    .map_err(|e| ServerError::Cluster(e.to_string()))?;
            }
            None => {
                for stored in state.stored_machines().await? {
                    state.start_stored(stored, None).await?;
                }
            }
        }
        // The machines are restored (their snapshots cover every stored
        // reading): the office is told of those it does not know yet.
        match options.forward {
            Some(forward) => super::forward::start(state.clone(), forward).await?,
            None => {
                if let Some(sqlite) = state.store.sqlite() {
                    let dropped = sqlite.forward_off().await?;
                    if dropped > 0 {
                        tracing::warn!(
                            dropped,
                            "served without --forward-to: the rows still owed to the office are dropped (forwarding again declares every machine afresh)"
                        );
                    }
                }
            }
        }
        tokio::spawn(super::sites::watch(state.clone()));
        Ok(state)
    }

    /// Restores stored machine `db_id` from its snapshot and the readings
    /// after it, and starts its task (already running under this lease:
    /// nothing). `lease_epoch`: the lease it runs under (several nodes).
    pub async fn start_machine(
        &self,
        db_id: i64,
        lease_epoch: Option<i64>,
    ) -> Result<(), ServerError> {
        let Some(stored) = self
            .stored_machines()
            .await?
            .into_iter()
            .find(|m| m.db_id == db_id)
        else {
            return Err(ServerError::Machine {
                machine: format!("#{db_id}"),
                source: StoreError::Corrupt(format!("machine {db_id} is not stored")).into(),
            });
        };
        self.start_stored(stored, lease_epoch).await
    }

    /// Every stored machine.
    async fn stored_machines(&self) -> Result<Vec<crate::store::StoredMachine>, ServerError> {
        let store = self.store.clone();
        Ok(tokio::task::spawn_blocking(move || store.machines())
            .await
            .map_err(std::io::Error::other)??)
    }

    /// [`AppState::start_machine`] of a machine already read from the store.
    async fn start_stored(
        &self,
        stored: crate::store::StoredMachine,
        lease_epoch: Option<i64>,
    ) -> Result<(), ServerError> {
        let db_id = stored.db_id;
        let _admin = self.admin.lock().await;
        if *self.shutdown.borrow() {
            return Err(ServerError::Cluster("the server is stopping".into()));
        }
        if self
            .all_machines()
            .iter()
            .any(|m| m.db_id == db_id && m.lease_epoch.get() == lease_epoch)
        {
            return Ok(());
        }
        let store = self.store.clone();
        let (spec, core, status, forward_mark) = tokio::task::spawn_blocking(move || {
            let spec = stored.spec;
            let core = machine::recover(&store, &spec, db_id, lease_epoch)
                .map_err(|e| (spec.id.clone(), e))?;
            let status =
                machine::stored_status(&store, &spec, db_id).map_err(|e| (spec.id.clone(), e))?;
            let forward_mark = match crate::config::forwarded_site(&spec.id) {
                Some(_) => store
                    .forward_mark(db_id)
                    .map_err(|e| (spec.id.clone(), e.into()))?,
                None => None,
            };
            Ok((spec, core, status, forward_mark))
        })
        .await
        .map_err(std::io::Error::other)?
        .map_err(|(machine, source)| ServerError::Machine { machine, source })?;
        metrics::register_machine(&spec);
        // The time the machine was not running here is not its sensors'
        // silence.
        let mut core = core;
        core.resumed(self.clock.now_s());
        let handle = machine::spawn(
            self.surroundings(),
            spec.clone(),
            db_id,
            lease_epoch,
            core,
            status,
            forward_mark,
        );
        let replaced = self
            .machines
            .write()
            .ok()
            .and_then(|mut machines| machines.insert(spec.id, Arc::new(handle)));
        // One under an older lease: what it still had queued is refused.
        if let Some(old) = replaced {
            old.stop().await;
        }
        Ok(())
    }

    /// Stops machine `id` here (its final snapshot stored, if this node
    /// may still write it) and forgets it: another node runs it next.
    pub async fn stop_machine(&self, id: &str) {
        let _admin = self.admin.lock().await;
        let handle = self.machines.write().ok().and_then(|mut m| m.remove(id));
        if let Some(handle) = handle {
            handle.stop().await;
        }
    }

    /// What a machine's task is given.
    fn surroundings(&self) -> machine::Surroundings {
        machine::Surroundings {
            store: self.store.clone(),
            queue_len: self.limits.machine_queue,
            clock: self.clock,
            alarm_changes: Arc::new(self.alarms.clone()),
        }
    }

    /// The stored machines other nodes run (none on SQLite).
    pub async fn elsewhere(&self) -> Result<Vec<crate::store::StoredMachine>, ApiError> {
        if self.cluster.is_none() {
            return Ok(Vec::new());
        }
        let store = self.store.clone();
        let stored = tokio::task::spawn_blocking(move || store.machines())
            .await
            .map_err(|e| ApiError::Internal(e.to_string()))??;
        Ok(stored
            .into_iter()
            .filter(|m| self.machine(&m.spec.id).is_err())
            .collect())
    }

    /// Whether machine `id` is declared: running here, or (several
    /// nodes) anywhere.
    pub async fn knows(&self, id: &str) -> bool {
        if self.machine(id).is_ok() {
            return true;
        }
        match &self.cluster {
            Some(cluster) => cluster.knows(id).await,
            None => false,
        }
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

    /// A machine running here; one another node runs (or that is changing
    /// hands) answers 503 `machine_moving`, one never declared 404.
    pub fn machine(&self, id: &str) -> Result<Arc<MachineHandle>, ApiError> {
        if let Some(machine) = self.machines.read().ok().and_then(|m| m.get(id).cloned()) {
            return Ok(machine);
        }
        match &self.cluster {
            Some(cluster) if cluster.knows_cached(id) => Err(super::cluster::moving(
                id,
                "it is not running on this node this moment",
            )),
            _ => Err(ApiError::UnknownMachine(id.to_string())),
        }
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
                    let successor = match self.machine(id) {
                        Ok(successor) => successor,
                        Err(_) if self.cluster.is_some() => {
                            return Err(super::cluster::moving(
                                id,
                                "it was handed to another node",
                            ));
                        }
                        Err(e) => return Err(e),
                    };
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
        if let Some(site) = crate::config::forwarded_site(&spec.id) {
            return Err(ApiError::Conflict(format!(
                "machine `{}` is site `{site}`'s: it is declared there and forwarded here",
                spec.id
            )));
        }
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
        let existing_none = existing.is_none();
        let db_id = self
            .store
            .put_machine(spec.clone(), core.snapshot())
            .await?;
        self.run_declared(spec, db_id, existing, core, None).await?;
        Ok((existing_none, true))
    }

    /// An office: machine `spec.id` (`{site}.{machine}`) was (re)declared
    /// at its site with its engines at `snapshot`, the site's outbox
    /// sequence `sequence`: stores both and the sequence in one commit,
    /// and runs the machine on from there (the site's engines, restored
    /// here). A sequence already committed changes nothing. Returns
    /// whether it was applied.
    pub async fn declare_forwarded(
        &self,
        spec: MachineSpec,
        snapshot: String,
        sequence: i64,
    ) -> Result<bool, ApiError> {
        let _admin = self.admin.lock().await;
        let existing = self.machine(&spec.id).ok();
        // A site on the release before a stage: the stage seeded from what
        // this office stored of the machine (nothing for a new one).
        let core = match MachineCore::restore(&spec, &snapshot) {
            Err(crate::fusion::SnapshotError::MissingStage(_)) => {
                let newest = match &existing {
                    Some(machine) => {
                        let (store, spec, db_id) =
                            (self.store.clone(), spec.clone(), machine.db_id);
                        tokio::task::spawn_blocking(move || {
                            crate::machine::newest_outputs(&store, &spec, db_id)
                        })
                        .await
                        .map_err(|e| ApiError::Internal(e.to_string()))?
                        .map_err(|e| ApiError::Internal(e.to_string()))?
                    }
                    None => Vec::new(),
                };
                MachineCore::restore_seeded(&spec, &snapshot, &newest)
            }
            restored => restored,
        }
        .map_err(|e| {
            ApiError::BadRequest(format!(
                "machine `{}`: the state its site's engines stand in is not readable here: {e}",
                spec.id
            ))
        })?;
        if self
            .forward_mark(&spec.id)
            .await?
            .is_some_and(|mark| mark >= sequence)
        {
            return Ok(false);
        }
        if let Some(existing) = &existing {
            existing.stop().await;
        }
        let db_id = self
            .store
            .put_forwarded_machine(spec.clone(), snapshot, sequence)
            .await?;
        self.run_declared(spec, db_id, existing, core, Some(sequence))
            .await?;
        Ok(true)
    }

    /// An office: the last sequence of forwarded machine `id` its site
    /// sent that is committed here, whether the machine runs on this node
    /// or not (`None`: none, or no such machine).
    pub async fn forward_mark(&self, id: &str) -> Result<Option<i64>, ApiError> {
        let running = self.machine(id).ok().map(|m| m.db_id);
        let (store, id) = (self.store.clone(), id.to_string());
        tokio::task::spawn_blocking(move || {
            let db_id = match running {
                Some(db_id) => Some(db_id),
                None => store
                    .machines()?
                    .into_iter()
                    .find(|m| m.spec.id == id)
                    .map(|m| m.db_id),
            };
            db_id.map_or(Ok(None), |db_id| store.forward_mark(db_id))
        })
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))?
        .map_err(ApiError::from)
    }

    /// Starts the task of a machine just (re)declared as `db_id` with
    /// `core` (the admin lock held), in place of `existing`.
    async fn run_declared(
        &self,
        spec: MachineSpec,
        db_id: i64,
        existing: Option<Arc<MachineHandle>>,
        core: MachineCore,
        forward_mark: Option<i64>,
    ) -> Result<(), ApiError> {
        let lease_epoch = match (&existing, &self.cluster) {
            (Some(existing), _) => existing.lease_epoch.get(),
            (None, Some(cluster)) => match super::cluster::claim(cluster, db_id).await? {
                Some(epoch) => Some(epoch),
                None => {
                    return Err(super::cluster::moving(
                        &spec.id,
                        "another node took it as it was declared",
                    ));
                }
            },
            (None, None) => None,
        };
        metrics::register_machine(&spec);
        // A redeclared machine keeps its history, so its status too.
        let status = existing
            .as_ref()
            .map(|m| (*m.status()).clone())
            .unwrap_or_default();
        let handle = Arc::new(machine::spawn(
            self.surroundings(),
            spec.clone(),
            db_id,
            lease_epoch,
            core,
            status,
            forward_mark,
        ));
        if let Ok(mut machines) = self.machines.write() {
            machines.insert(spec.id, handle);
        }
        Ok(())
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
        if let Some(cluster) = &self.cluster {
            cluster.leave().await;
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
