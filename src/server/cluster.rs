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

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

use axum::body::Body;
use axum::extract::{Request, State};
use axum::http::{HeaderMap, HeaderName, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::auth::Caller;
use super::error::{ApiError, Refusal};
use super::signing::{ClusterKeys, Grant, NODE_HEADER, Signable};
use super::state::SharedState;
use crate::fusion::Reading;
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

    /// Reads placements and nodes again.
    async fn refresh(&self) -> Result<(), crate::store::StoreError> {
        let placements = self.store.placements().await?;
        let nodes = self.store.nodes(LEASE_TTL_S).await?;
        if let Ok(mut view) = self.view.write() {
            view.placements = placements
                .into_iter()
                .map(|p| (p.machine.clone(), p))
                .collect();
            view.nodes = nodes.into_iter().map(|n| (n.node.clone(), n)).collect();
            view.refreshed = Some(Instant::now());
        }
        Ok(())
    }

    /// Refreshes unless the view is younger than 200 ms (a flood of
    /// unknown names does not become a flood of queries).
    async fn refresh_if_stale(&self) {
        let fresh = self
            .view
            .read()
            .ok()
            .and_then(|v| v.refreshed)
            .is_some_and(|at| at.elapsed() < Duration::from_millis(200));
        if !fresh && let Err(e) = self.refresh().await {
            tracing::warn!(error = %e, "cannot read the cluster's placements");
        }
    }

    fn lookup(&self, machine: &str) -> Option<Route> {
        let view = self.view.read().ok()?;
        let placement = view.placements.get(machine)?;
        Some(match &placement.holder {
            Some((node, true)) if *node != self.node => match view.nodes.get(node) {
                Some(row) if row.live => Route::Forward(row.url.clone()),
                _ => Route::Moving,
            },
            _ => Route::Moving,
        })
    }

    /// Where a request for `machine` (not running here) goes.
    pub async fn route(&self, machine: &str) -> Route {
        if let Some(route) = self.lookup(machine) {
            return route;
        }
        self.refresh_if_stale().await;
        self.lookup(machine).unwrap_or(Route::Unknown)
    }

    /// Whether `machine` is declared (anywhere).
    pub async fn knows(&self, machine: &str) -> bool {
        !matches!(self.route(machine).await, Route::Unknown)
    }

    /// Whether `machine` was declared when the view was last read.
    pub fn knows_cached(&self, machine: &str) -> bool {
        self.view
            .read()
            .is_ok_and(|v| v.placements.contains_key(machine))
    }

    /// The node and the grant of a request another node signed, or why it
    /// is refused (401): a signature under none of this node's keys, out
    /// of the replay window or replayed, or a node not live in `nodes`.
    pub async fn forwarded(
        &self,
        headers: &HeaderMap,
        (method, target, body): (&str, &str, &[u8]),
    ) -> Result<Grant, ApiError> {
        let request = Signable {
            to: &self.url,
            method,
            target,
            body,
        };
        let (node, grant) = self
            .keys
            .verify(headers, &request, crate::clock::wall_clock_s())?;
        let live = |view: &View| view.nodes.get(&node).is_some_and(|row| row.live);
        let mut known = self.view.read().map(|v| live(&v)).unwrap_or(false);
        if !known {
            self.refresh_if_stale().await;
            known = self.view.read().map(|v| live(&v)).unwrap_or(false);
        }
        if !known {
            return Err(ApiError::Unauthorized(format!(
                "a request signed as node `{node}`, which is not a live node of this store"
            )));
        }
        Ok(grant)
    }

    /// The headers that sign `request` as this node's, for `grant`; an
    /// error without a cluster key.
    fn sign(&self, request: &Signable<'_>, grant: &Grant) -> Result<HeaderMap, ApiError> {
        let signed = self
            .keys
            .sign(request, &self.node, grant, crate::clock::wall_clock_s())
            .ok_or_else(|| ApiError::Unavailable {
                reason: Refusal::MachineMoving,
                message: format!(
                    "node `{}` has no cluster key (serve --cluster-key-file) to reach the node \
                     that fuses this machine with",
                    self.node
                ),
            })?;
        Ok(signed.into_iter().collect())
    }

    /// Sends `readings` of `machine` to the node at `url` (WebSocket and
    /// MQTT ingest for a machine fused elsewhere); its answer, the indices
    /// of what it refused among `readings`.
    pub async fn post_readings(
        &self,
        url: &str,
        machine: &str,
        readings: &[Reading],
    ) -> Result<super::openapi::Ack, ApiError> {
        let mut body = String::new();
        for reading in readings {
            body.push_str(&reading.to_json());
            body.push('\n');
        }
        let target = format!("/api/v1/machines/{machine}/readings");
        let headers = self.sign(
            &Signable {
                to: url,
                method: "POST",
                target: &target,
                body: body.as_bytes(),
            },
            &Grant::Node,
        )?;
        let answer = self
            .http
            .post(format!("{url}{target}"))
            .headers(headers)
            .header("content-type", "application/x-ndjson")
            .body(body)
            .timeout(Duration::from_secs(30))
            .send()
            .await
            .map_err(|e| moving(machine, &format!("its node at {url} did not answer: {e}")))?;
        let status = answer.status();
        let text = answer
            .text()
            .await
            .map_err(|e| moving(machine, &format!("its node at {url} broke off: {e}")))?;
        if status == StatusCode::OK {
            return serde_json::from_str(&text)
                .map_err(|e| ApiError::Internal(format!("node at {url} answered {text}: {e}")));
        }
        let said = serde_json::from_str::<serde_json::Value>(&text)
            .ok()
            .and_then(|v| v["error"].as_str().map(str::to_string))
            .unwrap_or(text);
        Err(match status {
            StatusCode::BAD_REQUEST | StatusCode::PAYLOAD_TOO_LARGE => ApiError::BadRequest(said),
            // Its node changed hands, restarted (a new key) or is full:
            // for now.
            _ => moving(machine, &format!("its node answered {status}: {said}")),
        })
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

/// The server nodes and their machines.
///
/// `GET /api/v1/cluster`.
#[utoipa::path(get, path = "/api/v1/cluster", operation_id = "cluster", tag = "machines",
    responses((status = OK, description = "The nodes on this store, live or not, with the machines each fuses, and the machines changing hands (one server on SQLite: no nodes)", body = ClusterReport)))]
pub async fn show(State(state): State<SharedState>) -> Result<axum::Json<ClusterReport>, ApiError> {
    match &state.cluster {
        Some(cluster) => Ok(axum::Json(cluster.report().await?)),
        None => Ok(axum::Json(ClusterReport {
            node: None,
            nodes: Vec::new(),
            unplaced: Vec::new(),
        })),
    }
}

/// The 503 of a machine changing hands.
pub fn moving(machine: &str, why: &str) -> ApiError {
    ApiError::Unavailable {
        reason: Refusal::MachineMoving,
        message: format!("machine `{machine}` is moving between nodes ({why}); retry"),
    }
}

/// Joins the work: renews once, takes this node's share and starts it,
/// then keeps renewing (every second, on its own) and rebalancing (every
/// second) until the node leaves.
pub async fn start(state: &SharedState, cluster: Arc<Cluster>) -> Result<(), ApiError> {
    renew(&cluster).await?;
    balance(state, &cluster).await?;
    tokio::spawn(keep_renewing(state.clone(), cluster.clone()));
    tokio::spawn(keep_balancing(state.clone(), cluster));
    Ok(())
}

/// Renews this node's leases; the ones it holds are known afterwards
/// (with those taken while the renewal ran).
async fn renew(cluster: &Cluster) -> Result<(), ApiError> {
    let began = Instant::now();
    let renewed = cluster
        .membership
        .lock()
        .await
        .heartbeat(LEASE_TTL_S)
        .await?;
    if let Ok(mut held) = cluster.held.lock() {
        let taken_since: Vec<(i64, (i64, Instant))> = held
            .iter()
            .filter(|(_, (_, at))| *at > began)
            .map(|(&id, &lease)| (id, lease))
            .collect();
        *held = renewed
            .into_iter()
            .map(|(id, epoch)| (id, (epoch, began)))
            .collect();
        held.extend(taken_since);
    }
    if let Ok(mut at) = cluster.renewed.lock() {
        *at = began;
    }
    Ok(())
}

/// Renews every second until the node leaves; a node that could not for
/// [`SELF_FENCE`] stops its machines (their leases are about to lapse).
async fn keep_renewing(state: SharedState, cluster: Arc<Cluster>) {
    let mut tick = tokio::time::interval(TICK);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    while !cluster.left.load(std::sync::atomic::Ordering::SeqCst) {
        tick.tick().await;
        let renewal = tokio::time::timeout(TICK * 2, renew(&cluster)).await;
        let failed = match renewal {
            Ok(Ok(())) => continue,
            Ok(Err(e)) => e.to_string(),
            Err(_) => "no answer within 2 s".to_string(),
        };
        tracing::warn!(error = %failed, "cannot renew this node's leases");
        let since = cluster
            .renewed
            .lock()
            .map(|at| at.elapsed())
            .unwrap_or_default();
        // Alone, nobody can take the machines: they run on, their writes
        // refused until the leases are taken back (each commit checks).
        let others = cluster.view.read().is_ok_and(|view| {
            view.nodes
                .values()
                .any(|n| n.live && n.node != cluster.node)
        });
        if since >= SELF_FENCE && others && !cluster.left.load(std::sync::atomic::Ordering::SeqCst)
        {
            if let Ok(mut held) = cluster.held.lock() {
                held.clear();
            }
            for machine in state.all_machines() {
                tracing::warn!(machine = %machine.spec.id, "stopping: this node's lease is lapsing");
                state.stop_machine(&machine.spec.id).await;
            }
        }
    }
}

/// Rebalances every second until the server stops.
async fn keep_balancing(state: SharedState, cluster: Arc<Cluster>) {
    let mut tick = tokio::time::interval(TICK);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut shutdown = state.shutdown_signal();
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = shutdown.wait_for(|stopping| *stopping) => return,
        }
        if let Err(e) = balance(&state, &cluster).await {
            tracing::warn!(error = %e, "cannot rebalance the machines");
        }
    }
}

/// One round: stop what this node no longer holds (or holds under a newer
/// epoch: taken anew after a lapse), start what it holds, take free or
/// lapsed leases up to its share, or hand one back above it.
async fn balance(state: &SharedState, cluster: &Cluster) -> Result<(), ApiError> {
    if *state.shutdown_signal().borrow() {
        return Ok(());
    }
    cluster.refresh().await?;
    let held: BTreeMap<i64, i64> = cluster
        .held
        .lock()
        .map(|held| held.iter().map(|(&id, &(epoch, _))| (id, epoch)).collect())
        .unwrap_or_default();
    let mut held = held;
    // A running machine whose lease lapsed (the database away, a slow
    // renewal) is taken back; if no node held it meanwhile (the epoch is
    // exactly one more) it runs on.
    let running = state.all_machines();
    let lapsed: Vec<i64> = running
        .iter()
        .filter(|m| !held.contains_key(&m.db_id))
        .map(|m| m.db_id)
        .collect();
    for (id, epoch) in take(cluster, &lapsed).await? {
        if let Some(machine) = running.iter().find(|m| m.db_id == id)
            && machine.lease_epoch.get() == Some(epoch - 1)
        {
            tracing::info!(machine = %machine.spec.id, epoch, "lapsed lease taken back");
            machine.lease_epoch.set(epoch);
        }
        held.insert(id, epoch);
    }
    for machine in running {
        if held.get(&machine.db_id).copied() != machine.lease_epoch.get() {
            tracing::warn!(machine = %machine.spec.id, "no longer held under its lease: stopping");
            state.stop_machine(&machine.spec.id).await;
        }
    }
    for (&id, &epoch) in &held {
        run(state, id, epoch).await;
    }
    let (free, live_nodes, declared) = {
        let view = cluster
            .view
            .read()
            .map_err(|_| ApiError::Internal("cluster view poisoned".into()))?;
        let mut free: Vec<i64> = view
            .placements
            .values()
            .filter(|p| !matches!(p.holder, Some((_, true))) && !held.contains_key(&p.machine_id))
            .map(|p| p.machine_id)
            .collect();
        free.sort_unstable();
        let live = view.nodes.values().filter(|n| n.live).count().max(1);
        (free, live, view.placements.len())
    };
    let share = declared.div_ceil(live_nodes);
    if held.len() < share {
        let wanted: Vec<i64> = free.into_iter().take(share - held.len()).collect();
        for (id, epoch) in take(cluster, &wanted).await? {
            tracing::info!(machine_id = id, epoch, node = %cluster.node, "machine taken over");
            run(state, id, epoch).await;
        }
    } else if held.len() > share && live_nodes > 1 {
        // The newest machine goes: one a round, so the others settle.
        if let Some(machine) = state.all_machines().into_iter().max_by_key(|m| m.db_id) {
            tracing::info!(machine = %machine.spec.id, "handing a machine to another node");
            state.stop_machine(&machine.spec.id).await;
            cluster
                .membership
                .lock()
                .await
                .release(machine.db_id)
                .await?;
            if let Ok(mut held) = cluster.held.lock() {
                held.remove(&machine.db_id);
            }
        }
    }
    Ok(())
}

/// Takes the leases of `machine_ids` that are free; those taken, with
/// their epochs, known as held at once.
async fn take(cluster: &Cluster, machine_ids: &[i64]) -> Result<Vec<(i64, i64)>, ApiError> {
    let taken = cluster
        .membership
        .lock()
        .await
        .acquire(machine_ids, LEASE_TTL_S)
        .await?;
    if let Ok(mut held) = cluster.held.lock() {
        let now = Instant::now();
        for &(id, epoch) in &taken {
            held.insert(id, (epoch, now));
        }
    }
    Ok(taken)
}

/// Runs held machine `id` here under lease `epoch`; one that cannot be
/// restored is logged and left (its requests answered 503) while the
/// others run.
async fn run(state: &SharedState, id: i64, epoch: i64) {
    let Some(cluster) = &state.cluster else {
        return;
    };
    let failed_lately = cluster
        .failed
        .lock()
        .ok()
        .and_then(|failed| failed.get(&id).copied())
        .is_some_and(|at| at.elapsed() < START_RETRY);
    if failed_lately {
        return;
    }
    match state.start_machine(id, Some(epoch)).await {
        Ok(()) => {
            if let Ok(mut failed) = cluster.failed.lock() {
                failed.remove(&id);
            }
        }
        Err(e) => {
            tracing::error!(machine_id = id, error = %e, "cannot start a machine this node holds; trying again in 10 s");
            if let Ok(mut failed) = cluster.failed.lock() {
                failed.insert(id, Instant::now());
            }
        }
    }
}

/// Takes the lease of a machine just declared here; its epoch, or `None`
/// if another node took it first.
pub async fn claim(cluster: &Cluster, machine_id: i64) -> Result<Option<i64>, ApiError> {
    let taken = take(cluster, &[machine_id]).await?;
    cluster.refresh_if_stale().await;
    let epoch = taken
        .into_iter()
        .find(|&(id, _)| id == machine_id)
        .map(|(_, epoch)| epoch)
        // This node's rebalancing took it a moment before.
        .or_else(|| {
            cluster
                .held
                .lock()
                .ok()
                .and_then(|held| held.get(&machine_id).map(|&(epoch, _)| epoch))
        });
    Ok(epoch)
}

/// The machine a path is about: `/api/v1/machines/{m}[/...]` or
/// `/machines/{m}`.
fn machine_of(path: &str) -> Option<String> {
    let rest = path
        .strip_prefix("/api/v1/machines/")
        .or_else(|| path.strip_prefix("/machines/"))?;
    let segment = rest.split('/').next()?;
    let machine = percent_decoded(segment)?;
    (!machine.is_empty()).then_some(machine)
}

/// A path segment as the router's `Path` reads it (`%XX` decoded); `None`
/// if it is not UTF-8 once decoded.
fn percent_decoded(segment: &str) -> Option<String> {
    let bytes = segment.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = |b: u8| (b as char).to_digit(16);
        match (bytes[i], bytes.get(i + 1), bytes.get(i + 2)) {
            (b'%', Some(&h), Some(&l)) if hex(h).is_some() && hex(l).is_some() => {
                out.push((hex(h)? * 16 + hex(l)?) as u8);
                i += 3;
            }
            (b, _, _) => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8(out).ok()
}

/// Headers that belong to one hop, not passed on.
fn hop_by_hop(name: &HeaderName) -> bool {
    matches!(
        name.as_str(),
        "host"
            | "connection"
            | "keep-alive"
            | "proxy-authenticate"
            | "proxy-authorization"
            | "te"
            | "trailer"
            | "transfer-encoding"
            | "upgrade"
            | "content-length"
    )
}

/// The route layer that sends a request for a machine fused by another
/// node to that node (after the caller's token was checked here), and
/// answers 503 while the machine changes hands. WebSocket upgrades stay:
/// their handlers follow a machine wherever it runs.
pub async fn forward(State(state): State<SharedState>, request: Request, next: Next) -> Response {
    let Some(cluster) = state.cluster.clone() else {
        return next.run(request).await;
    };
    let Some(machine) = machine_of(request.uri().path()) else {
        return next.run(request).await;
    };
    if request.headers().contains_key(axum::http::header::UPGRADE)
        || state.machine(&machine).is_ok()
    {
        return next.run(request).await;
    }
    let forwarded = request.headers().contains_key(NODE_HEADER);
    match cluster.route(&machine).await {
        Route::Unknown => next.run(request).await,
        Route::Forward(_) | Route::Moving if forwarded => {
            moving(&machine, "it is not running on the node it was sent to").into_response()
        }
        Route::Moving => moving(&machine, "no node runs it this moment").into_response(),
        Route::Forward(url) => match proxy(&state, &cluster, &url, request).await {
            Ok(response) => response,
            Err(e) => e.into_response(),
        },
    }
}

/// A request's whole body, at most `limit` bytes (413 beyond): what a
/// signature between nodes covers.
pub(super) async fn whole_body(body: Body, limit: usize) -> Result<axum::body::Bytes, ApiError> {
    axum::body::to_bytes(body, limit).await.map_err(|e| {
        ApiError::TooLarge(format!("body larger than {limit} bytes or broken off: {e}"))
    })
}

/// Sends `request` to the node at `url`; its answer, streamed back.
async fn proxy(
    state: &SharedState,
    cluster: &Cluster,
    url: &str,
    request: Request,
) -> Result<Response, ApiError> {
    let (parts, body) = request.into_parts();
    let machine = machine_of(parts.uri.path()).unwrap_or_default();
    let target = format!(
        "{url}{}",
        parts
            .uri
            .path_and_query()
            .map(|p| p.as_str())
            .unwrap_or("/")
    );
    let body = whole_body(body, state.limits.max_body_bytes).await?;
    let mut headers = HeaderMap::new();
    for (name, value) in &parts.headers {
        // A client's own `x-tunnelnav-*` never passes: only this node's.
        // Nor does its token: the signature names it.
        if !hop_by_hop(name)
            && !name.as_str().starts_with("x-tunnelnav-")
            && name != axum::http::header::AUTHORIZATION
            && name != axum::http::header::COOKIE
        {
            headers.append(name.clone(), value.clone());
        }
    }
    // Signed as the URL is sent (its path and query after parsing).
    let sent = reqwest::Url::parse(&target).map_err(|e| ApiError::Internal(e.to_string()))?;
    let sent_target = match sent.query() {
        Some(query) => format!("{}?{query}", sent.path()),
        None => sent.path().to_string(),
    };
    let grant = Grant::of(parts.extensions.get::<Caller>().and_then(|c| c.0.as_ref()));
    headers.extend(cluster.sign(
        &Signable {
            to: url,
            method: parts.method.as_str(),
            target: &sent_target,
            body: &body,
        },
        &grant,
    )?);
    let answer = cluster
        .http
        .request(parts.method.clone(), sent)
        .headers(headers)
        .body(body)
        .send()
        .await
        .map_err(|e| moving(&machine, &format!("its node at {url} did not answer: {e}")))?;
    let mut response = Response::builder().status(answer.status());
    if let Some(out) = response.headers_mut() {
        for (name, value) in answer.headers() {
            if !hop_by_hop(name) {
                out.append(name.clone(), value.clone());
            }
        }
    }
    response
        .body(Body::from_stream(answer.bytes_stream()))
        .map_err(|e| ApiError::Internal(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_machine_of_a_path() {
        let some = |m: &str| Some(m.to_string());
        assert_eq!(machine_of("/api/v1/machines/tbm-1"), some("tbm-1"));
        assert_eq!(machine_of("/api/v1/machines/tbm-1/readings"), some("tbm-1"));
        assert_eq!(machine_of("/machines/tbm-1"), some("tbm-1"));
        assert_eq!(machine_of("/api/v1/machines/m%31/readings"), some("m1"));
        assert_eq!(machine_of("/api/v1/machines/m%3"), some("m%3"));
        assert_eq!(machine_of("/api/v1/machines"), None);
        assert_eq!(machine_of("/api/v1/machines/"), None);
        assert_eq!(machine_of("/api/v1/alarms"), None);
    }
}
