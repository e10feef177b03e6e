//! The fleet: the machines this node runs — started from the store,
//! declared and redeclared, forwarded from a site, found, stopped.

use std::future::Future;
use std::sync::Arc;

use super::error::ApiError;
use super::metrics;
use super::state::{AppState, ServerError};
use crate::config::MachineSpec;
use crate::machine::{self, MachineCore, MachineError, MachineHandle};
use crate::store::StoreError;

impl AppState {
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
    pub(super) async fn stored_machines(
        &self,
    ) -> Result<Vec<crate::store::StoredMachine>, ServerError> {
        let store = self.store.clone();
        Ok(tokio::task::spawn_blocking(move || store.machines())
            .await
            .map_err(std::io::Error::other)??)
    }

    /// [`AppState::start_machine`] of a machine already read from the store.
    pub(super) async fn start_stored(
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
            (None, Some(cluster)) => match super::cluster::leases::claim(cluster, db_id).await? {
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
}

pub(super) fn fresh_snapshot(spec: &MachineSpec) -> Result<String, ServerError> {
    MachineCore::new(spec)
        .map(|core| core.snapshot())
        .map_err(|e| ServerError::Machine {
            machine: spec.id.clone(),
            source: e.into(),
        })
}
