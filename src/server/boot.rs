//! Start-up: the store opened, the configured machines declared, the
//! services started (the cluster's leases, the feeds of machines other
//! nodes run, forwarding to an office, the sites' watch, retention) and
//! every machine this node runs restored.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, RwLock};

use tokio::sync::watch;

use super::cluster::Cluster;
use super::fleet::fresh_snapshot;
use super::settings::{Limits, WebhookConfig};
use super::state::{AppState, ServerError, SharedState};
use super::{auth, notify};
use crate::clock::Clock;
use crate::config::MachineSpec;
use crate::store::Store;

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
                Ok::<_, crate::store::StoreError>(super::site_links::SiteLinks::load(
                    records, &raised,
                ))
            })
            .await
            .map_err(std::io::Error::other)??
        };
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
            tasks: Default::default(),
        });
        match cluster {
            Some(cluster) => {
                if let Some(postgres) = state.store.postgres() {
                    state.own(
                        "feeds",
                        tokio::spawn(super::feeds::relay(
                            state.store.clone(),
                            cluster.node().to_string(),
                            cluster.feeds.clone(),
                            state.alarms.clone(),
                            postgres.listen(),
                            state.shutdown_signal(),
                        )),
                    );
                }
                let [renewing, balancing] = super::cluster::leases::start(&state, cluster)
                    .await
                    .map_err(|e| ServerError::Cluster(e.to_string()))?;
                state.own("leases", renewing);
                state.own("balancing", balancing);
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
            Some(forward) => {
                let forwarding =
                    super::forward::start(&state.store, state.shutdown_signal(), forward).await?;
                state.own("forwarding", forwarding);
            }
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
        state.own("sites", tokio::spawn(super::sites::watch(state.clone())));
        if !options.retention.keeps_everything() {
            state.own(
                "retention",
                tokio::spawn(super::retention::keep(
                    state.store.clone(),
                    options.retention,
                    options.clock,
                    state.shutdown_signal(),
                )),
            );
        }
        Ok(state)
    }
}
