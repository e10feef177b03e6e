//! Several server nodes on one PostgreSQL store (issue 37): any node
//! answers the API, each machine is fused by exactly one node at a time.
//!
//! Every second a node renews its leases (`store::postgres::cluster`),
//! stops the machines whose lease it lost, starts the ones it holds but
//! does not run (a restart under the same name), and takes free or lapsed
//! ones up to its share (the declared machines over the live nodes,
//! rounded up); above its share it hands one back per second, after its
//! final snapshot, so a joining node gets its part. A node that dies
//! stops renewing: its leases lapse after [`LEASE_TTL_S`] and the live
//! nodes take its machines within the next second, restored from the
//! snapshot and the readings after it.
//!
//! A request for a machine another node fuses is forwarded to that node
//! (after this node checked the caller's token), signed with the cluster
//! key and naming the caller's token ([`super::signing`]); the other node
//! checks the signature and the token against the route's need itself. A
//! forwarded request is never forwarded again. Readings that arrive by
//! WebSocket or MQTT go on by HTTP the same way. While a machine changes
//! hands, its requests are answered 503 (`machine_moving`): retry.

//!
//! The files: `mod.rs` the node's part (joining, the report, leaving),
//! `routing.rs` where a machine's requests go, `leases.rs` the leases
//! kept and shared out, `proxy.rs` requests forwarded to the node fusing
//! the machine (and checked where they arrive), `api.rs` the route;
//! the signatures are `super::signing`'s.

pub mod api;
pub mod leases;
pub mod proxy;
mod routing;

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

use axum::body::Body;

use super::error::{ApiError, Refusal};
use super::signing::ClusterKeys;
use crate::store::postgres::PgStore;
use crate::store::postgres::cluster::{Membership, NodeRow, Placement};

/// Seconds a lease lasts after its last renewal (and a node counts as
/// live after its last heartbeat).
pub const LEASE_TTL_S: f64 = 5.0;
/// How often a node renews its leases and rebalances.
const TICK: Duration = Duration::from_secs(1);
/// How long a machine that could not be started here waits for the next try.
const START_RETRY: Duration = Duration::from_secs(10);
/// A node that could not renew for this long stops its machines: its
/// leases are about to lapse and another node to take them.
const SELF_FENCE: Duration = Duration::from_secs(4);

/// How a node joins: the name it wants, where the others reach it and
/// the cluster keys it signs and checks requests with.
#[derive(Debug, Clone)]
pub struct ClusterOptions {
    pub node: String,
    pub advertise: String,
    pub keys: Arc<ClusterKeys>,
}

/// What a node knows of the others, refreshed every second and when a
/// request names a machine or node it has not seen.
#[derive(Default)]
struct View {
    placements: HashMap<String, Placement>,
    nodes: HashMap<String, NodeRow>,
    refreshed: Option<Instant>,
}

/// This node's part in the cluster.
pub struct Cluster {
    node: String,
    /// Where the others reach this node (what requests for it are signed
    /// for).
    url: String,
    keys: Arc<ClusterKeys>,
    membership: tokio::sync::Mutex<Membership>,
    store: PgStore,
    view: RwLock<View>,
    /// The leases this node holds: machine id → (epoch, when this node
    /// learnt it), from the last renewal and the takings since.
    held: std::sync::Mutex<BTreeMap<i64, (i64, Instant)>>,
    /// When the last renewal that succeeded began.
    renewed: std::sync::Mutex<Instant>,
    /// Set when the node left: renewals stop.
    left: std::sync::atomic::AtomicBool,
    /// Machines whose start failed here, and when (tried again later).
    failed: std::sync::Mutex<HashMap<i64, Instant>>,
    /// Live feeds of machines other nodes fuse, followed here.
    pub feeds: Arc<super::feeds::Feeds>,
    http: reqwest::Client,
}

/// Where a request for a machine not running here goes.
pub enum Route {
    /// Another live node holds it: its URL.
    Forward(String),
    /// Declared, but no node runs it right now.
    Moving,
    /// Not declared.
    Unknown,
}

/// A node's summary, for `GET /api/v1/cluster`.
#[derive(Debug, serde::Serialize, utoipa::ToSchema)]
pub struct NodeReport {
    pub node: String,
    pub url: String,
    pub live: bool,
    /// The machines it holds.
    pub machines: Vec<String>,
}

/// `GET /api/v1/cluster`: the nodes and their machines.
#[derive(Debug, serde::Serialize, utoipa::ToSchema)]
pub struct ClusterReport {
    /// The node that answered.
    pub node: Option<String>,
    pub nodes: Vec<NodeReport>,
    /// Declared machines no live node holds now (changing hands).
    pub unplaced: Vec<String>,
}

impl Cluster {
    /// Joins the store's nodes.
    pub async fn join(
        store: &crate::store::Store,
        options: &ClusterOptions,
    ) -> Result<Cluster, crate::store::StoreError> {
        let Some(postgres) = store.postgres() else {
            return Err(crate::store::StoreError::Location(
                "several nodes need the PostgreSQL store".into(),
            ));
        };
        if !options.keys.has_key() {
            tracing::warn!(
                "no cluster key (serve --cluster-key-file): this node neither forwards requests \
                 to other nodes nor accepts theirs; give every node the same key file"
            );
        }
        let membership = postgres
            .join(
                &options.node,
                &options.advertise,
                &options.keys.fingerprint(),
            )
            .await?;
        tracing::info!(node = membership.node(), url = %options.advertise, "joined the cluster");
        let http = reqwest::Client::builder()
            .connect_timeout(Duration::from_secs(2))
            .read_timeout(Duration::from_secs(30))
            .build()
            .map_err(|e| crate::store::StoreError::Location(e.to_string()))?;
        Ok(Cluster {
            node: membership.node().to_string(),
            url: options.advertise.clone(),
            keys: options.keys.clone(),
            membership: tokio::sync::Mutex::new(membership),
            store: postgres.clone(),
            view: RwLock::new(View::default()),
            held: std::sync::Mutex::new(BTreeMap::new()),
            renewed: std::sync::Mutex::new(Instant::now()),
            left: std::sync::atomic::AtomicBool::new(false),
            failed: std::sync::Mutex::new(HashMap::new()),
            feeds: Arc::default(),
            http,
        })
    }

    /// The name this node joined under.
    pub fn node(&self) -> &str {
        &self.node
    }

    /// The nodes and their machines.
    pub async fn report(&self) -> Result<ClusterReport, ApiError> {
        self.refresh().await?;
        let view = self
            .view
            .read()
            .map_err(|_| ApiError::Internal("cluster view poisoned".into()))?;
        let mut nodes: Vec<NodeReport> = view
            .nodes
            .values()
            .map(|n| NodeReport {
                node: n.node.clone(),
                url: n.url.clone(),
                live: n.live,
                machines: Vec::new(),
            })
            .collect();
        nodes.sort_by(|a, b| a.node.cmp(&b.node));
        let mut unplaced = Vec::new();
        let mut placements: Vec<&Placement> = view.placements.values().collect();
        placements.sort_by(|a, b| a.machine.cmp(&b.machine));
        for placement in placements {
            match &placement.holder {
                Some((node, true)) => {
                    if let Some(report) = nodes.iter_mut().find(|n| n.node == *node) {
                        report.machines.push(placement.machine.clone());
                    }
                }
                _ => unplaced.push(placement.machine.clone()),
            }
        }
        Ok(ClusterReport {
            node: Some(self.node.clone()),
            nodes,
            unplaced,
        })
    }

    /// Gives every lease up (after the final snapshots): the others take
    /// the machines at once.
    pub async fn leave(&self) {
        self.left.store(true, std::sync::atomic::Ordering::SeqCst);
        if let Err(e) = self.membership.lock().await.leave().await {
            tracing::warn!(error = %e, "could not leave the cluster; the leases lapse by themselves");
        }
    }
}

/// The 503 of a machine changing hands.
pub fn moving(machine: &str, why: &str) -> ApiError {
    ApiError::Unavailable {
        reason: Refusal::MachineMoving,
        message: format!("machine `{machine}` is moving between nodes ({why}); retry"),
    }
}

/// A request's whole body, at most `limit` bytes (413 beyond): what a
/// signature between nodes covers.
pub(super) async fn whole_body(body: Body, limit: usize) -> Result<axum::body::Bytes, ApiError> {
    axum::body::to_bytes(body, limit).await.map_err(|e| {
        ApiError::TooLarge(format!("body larger than {limit} bytes or broken off: {e}"))
    })
}
