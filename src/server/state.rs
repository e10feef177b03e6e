//! The server's shared state: the store, the running machines and what
//! every handler needs (limits, clock, alarm notifier, socket counts), and
//! shutdown. Start-up is `boot.rs`'s; the machines' comings and goings
//! `fleet.rs`'s.

use std::collections::BTreeMap;
use std::sync::{Arc, RwLock};

use tokio::sync::watch;

use super::cluster::Cluster;
use super::settings::Limits;
use super::{auth, notify};
use crate::clock::Clock;
use crate::machine::{MachineError, MachineHandle};
use crate::store::{Store, StoreError};

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
    pub(super) machines: RwLock<BTreeMap<String, Arc<MachineHandle>>>,
    /// Serialises machine (re)declarations.
    pub(super) admin: tokio::sync::Mutex<()>,
    pub limits: Limits,
    pub clock: Clock,
    /// Turns true when the server stops: live sockets close.
    pub(super) shutdown: watch::Sender<bool>,
    /// Access tokens in force.
    pub gate: auth::Gate,
    /// Stored alarm changes to live clients and webhooks.
    pub alarms: notify::AlarmNotifier,
    /// Live sockets open now: shutdown waits (a little) for their close
    /// frames to go out.
    pub(super) live_sockets: Arc<std::sync::atomic::AtomicUsize>,
    /// Fleet alarm sockets open now (at most `Limits::max_alarm_clients`).
    pub(super) alarm_sockets: Arc<std::sync::atomic::AtomicUsize>,
    /// This node's part among several on one PostgreSQL store.
    pub cluster: Option<Arc<Cluster>>,
    /// An office: the sites' links as they last reported.
    pub sites: super::site_links::SiteLinks,
    /// An office: a site's backlog older than this raises `site_link`.
    pub site_backlog_alarm_s: f64,
    /// [`super::ServerOptions::access_log`].
    pub access_log: tracing::Level,
    /// Reports being read and drawn ([`Limits::reports_at_once`] permits):
    /// each holds its rows in memory, so more wait their turn.
    pub reports: Arc<tokio::sync::Semaphore>,
    /// The services' tasks (retention, forwarding, the sites' watch, the
    /// feeds' relay, the cluster's leases), by name: each ends when the
    /// server stops, and [`AppState::stop`] waits for them.
    pub(super) tasks: std::sync::Mutex<Vec<(&'static str, tokio::task::JoinHandle<()>)>>,
}

/// How long [`AppState::stop`] waits for a service's task to end before
/// ending it.
const TASK_STOP: std::time::Duration = std::time::Duration::from_secs(3);

/// Counts an open live socket while it lives.
pub struct LiveSocketGuard(Arc<std::sync::atomic::AtomicUsize>);

impl Drop for LiveSocketGuard {
    fn drop(&mut self) {
        self.0.fetch_sub(1, std::sync::atomic::Ordering::SeqCst);
    }
}

pub type SharedState = Arc<AppState>;

impl AppState {
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

    /// A service's task, ended when the server stops.
    pub(super) fn own(&self, name: &'static str, task: tokio::task::JoinHandle<()>) {
        self.tasks
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push((name, task));
    }

    /// Closes live sockets, stores a final snapshot of every machine,
    /// waits for the services' tasks to end and closes the store.
    pub async fn stop(&self) {
        self.shutdown.send_replace(true);
        for machine in self.all_machines() {
            machine.stop().await;
        }
        if let Some(cluster) = &self.cluster {
            cluster.leave().await;
        }
        let tasks = std::mem::take(&mut *self.tasks.lock().unwrap_or_else(|p| p.into_inner()));
        for (name, task) in tasks {
            let abort = task.abort_handle();
            if tokio::time::timeout(TASK_STOP, task).await.is_err() {
                abort.abort();
                tracing::warn!(task = name, "a service's task did not end in time: ended");
            }
        }
        self.store.close().await;
    }
}
