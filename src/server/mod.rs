//! The HTTP server: routes, shared state, start-up and shutdown. Handlers
//! only translate: extract, ask the store or a machine's task, map errors.

mod alarms;
mod alignment;
pub mod auth;
mod clock;
mod error;
mod history;
mod ingest;
mod live;
mod machines;
pub mod metrics;
pub mod mqtt;
pub mod notify;
mod openapi;
pub mod pages;

use std::collections::BTreeMap;
use std::future::Future;
use std::path::PathBuf;
use std::sync::{Arc, RwLock};

use axum::extract::DefaultBodyLimit;
use axum::handler::Handler;
use axum::routing::get;
use axum::{Extension, Router};
use tokio::net::TcpListener;
use tokio::sync::watch;
use tower_http::trace::TraceLayer;
use utoipa::OpenApi;
use utoipa_axum::router::{OpenApiRouter, UtoipaMethodRouter};
use utoipa_axum::routes;

pub use clock::{Clock, wall_clock_s};
pub use error::{ApiError, Rejected};
pub use ingest::{BatchRules, ParsedBatch, parse_batch};

use crate::config::MachineSpec;
use crate::machine::{self, MachineCore, MachineError, MachineHandle};
use crate::store::{Store, StoreError};

/// Limits on what clients may send.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Largest request body (413 beyond).
    pub max_body_bytes: usize,
    /// Most readings in one request or WebSocket frame (413 beyond).
    pub max_readings_per_request: usize,
    /// Largest WebSocket message.
    pub max_frame_bytes: usize,
    /// Most points a history query returns.
    pub max_points_limit: usize,
    /// Interval between `ping` events on live sockets (at most 15 s).
    pub live_ping_interval: std::time::Duration,
    /// How far ahead of the server clock a reading's time may be.
    pub max_future_s: f64,
    /// Ingest requests waiting for one machine; beyond, 503 with
    /// `Retry-After` instead of buffering.
    pub machine_queue: usize,
    /// Live sockets per machine (503 beyond).
    pub max_live_clients_per_machine: usize,
    /// Fleet alarm sockets (every dashboard page opens one; 503 beyond).
    pub max_alarm_clients: usize,
    /// Longest a request may take to be answered (beyond: 408 if its body
    /// had not arrived, else 503); streamed
    /// bodies and open WebSockets are not cut.
    pub request_timeout: std::time::Duration,
    /// Cap on the database file (a small card on a site computer): beyond
    /// it ingest answers 503 as on a full disk. `None`: the disk's size.
    pub max_database_bytes: Option<u64>,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_body_bytes: 16 * 1024 * 1024,
            max_readings_per_request: 100_000,
            max_frame_bytes: 4 * 1024 * 1024,
            max_points_limit: 100_000,
            live_ping_interval: std::time::Duration::from_secs(10),
            max_future_s: 600.0,
            machine_queue: 64,
            max_live_clients_per_machine: 100,
            max_alarm_clients: 1000,
            request_timeout: std::time::Duration::from_secs(30),
            max_database_bytes: None,
        }
    }
}

/// How to start a server.
#[derive(Debug, Clone)]
pub struct ServerOptions {
    pub data_dir: PathBuf,
    /// Machines declared by the config file: created, or replaced where the
    /// stored declaration differs.
    pub machines: Vec<MachineSpec>,
    pub limits: Limits,
    /// The clock for ages and the future check ([`Clock::system`] but in the demo).
    pub clock: Clock,
    /// What history to keep.
    pub retention: crate::store::retention::Retention,
    /// Where alarm changes are posted.
    pub webhooks: notify::WebhookConfig,
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
        let store = Store::open_capped(&options.data_dir, options.limits.max_database_bytes)?;
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
                        alarm_changes: alarms.clone(),
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
                alarm_changes: self.alarms.clone(),
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

/// What a route needs of the caller's token (see `auth`).
#[derive(Debug, Clone, Copy)]
enum Role {
    Read,
    Ingest,
    Admin,
}

impl Role {
    fn as_str(self) -> &'static str {
        match self {
            Role::Read => "read",
            Role::Ingest => "ingest",
            Role::Admin => "admin",
        }
    }
}

/// `routes` behind the check of `role`, which their operations in the
/// document name as their security requirement: the check and its
/// description come from this one place.
fn guarded(
    state: &SharedState,
    role: Role,
    (schemas, mut paths, routes): UtoipaMethodRouter<SharedState>,
) -> UtoipaMethodRouter<SharedState> {
    use utoipa::openapi::security::SecurityRequirement;
    let requirement = vec![
        SecurityRequirement::new("bearer", [role.as_str()]),
        SecurityRequirement::new("session", [role.as_str()]),
    ];
    for item in paths.paths.values_mut() {
        for operation in openapi::operations_mut(item) {
            operation.security = Some(requirement.clone());
        }
    }
    let state = state.clone();
    let routes = match role {
        Role::Read => routes.layer(axum::middleware::from_fn_with_state(state, auth::read)),
        Role::Ingest => routes.layer(axum::middleware::from_fn_with_state(state, auth::ingest)),
        Role::Admin => routes.layer(axum::middleware::from_fn_with_state(state, auth::admin)),
    };
    (schemas, paths, routes)
}

/// The API's routes, each with its description (`openapi`).
fn api_routes(state: &SharedState) -> OpenApiRouter<SharedState> {
    use Role::{Admin, Ingest, Read};
    let guard = |role, routes| guarded(state, role, routes);
    OpenApiRouter::with_openapi(openapi::ApiDoc::openapi())
        .routes(guard(Read, routes!(pages::fleet)))
        .routes(guard(Read, routes!(pages::machine)))
        .routes(routes!(metrics::healthz))
        .routes(routes!(openapi::document))
        .routes(guard(Read, routes!(metrics::render)))
        .routes(guard(Read, routes!(machines::list)))
        .routes(guard(Read, routes!(machines::show)))
        .routes(guard(Admin, routes!(machines::put)))
        .routes(guard(Read, routes!(history::readings)))
        .routes(guard(Ingest, routes!(ingest::post_readings)))
        .routes(guard(Ingest, routes!(ingest::websocket)))
        .routes(guard(Read, routes!(live::websocket)))
        .routes(guard(Read, routes!(history::estimates)))
        .routes(guard(Read, routes!(history::model)))
        .routes(guard(Read, routes!(alignment::show)))
        .routes(guard(Admin, routes!(alignment::put)))
        .routes(guard(Read, routes!(alignment::axis)))
        .routes(guard(Read, routes!(alarms::list)))
        .routes(guard(Read, routes!(live::alarms_websocket)))
        .routes(guard(Read, routes!(alarms::ack)))
}

/// The application's routes (used by `serve` and by the tests).
pub fn router(state: SharedState) -> Router {
    let limit = state.limits.max_body_bytes;
    let (api, document) = api_routes(&state).split_for_parts();
    let document = openapi::finish(document);
    // Serialising a document of plain maps and strings cannot fail.
    let json = document.to_json().unwrap_or_default();
    // Static files, the docs page and the login page need no token.
    let read = axum::middleware::from_fn_with_state(state.clone(), auth::read);
    api.route("/static/{*path}", get(pages::asset))
        .route("/api/docs", get(openapi::page))
        .route("/login", get(auth::login_page).post(auth::login))
        .route("/logout", axum::routing::post(auth::logout))
        .layer(Extension(openapi::Document(json.into())))
        // Unknown routes and methods answer only those who may read.
        .fallback(not_found.layer(read.clone()))
        .method_not_allowed_fallback(method_not_allowed.layer(read))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            answer_in_time,
        ))
        .layer(DefaultBodyLimit::max(limit))
        .layer(axum::middleware::from_fn(metrics::count_responses))
        .layer(
            TraceLayer::new_for_http()
                .make_span_with(request_span)
                .on_request(())
                .on_response(
                    tower_http::trace::DefaultOnResponse::new()
                        .level(tracing::Level::INFO)
                        .latency_unit(tower_http::LatencyUnit::Millis),
                ),
        )
        .with_state(state)
}

/// The span of one request, so its one INFO line (on the response: status
/// and latency) names the method, the route as declared (`{machine}` and
/// all, or `unmatched`) and the machine, if the route has one.
fn request_span(request: &axum::http::Request<axum::body::Body>) -> tracing::Span {
    let route = request
        .extensions()
        .get::<axum::extract::MatchedPath>()
        .map_or("unmatched", |m| m.as_str());
    // The path segment where the route says `{machine}`.
    let machine = route
        .split('/')
        .position(|segment| segment == "{machine}")
        .and_then(|i| request.uri().path().split('/').nth(i));
    let span = tracing::info_span!(
        "request",
        method = %request.method(),
        route = %route,
        machine = tracing::field::Empty,
    );
    if let Some(machine) = machine {
        span.record("machine", tracing::field::display(machine));
    }
    span
}

/// Applies the retention policy now and every `every_s`: each pass is
/// planned on a read connection and done step by step on the store's
/// writer between its commits (see `store::retention`).
async fn apply_retention(store: Store, policy: crate::store::retention::Retention, clock: Clock) {
    use crate::store::retention::{Pruned, plan};
    let every = std::time::Duration::from_secs_f64(policy.every_s.max(1.0));
    let mut tick = tokio::time::interval(every);
    loop {
        tick.tick().await;
        let now_t = clock.now_s();
        let pass = async {
            let planner = store.clone();
            let steps = tokio::task::spawn_blocking(move || {
                planner.read(|conn| plan(conn, now_t, &policy, 5000))
            })
            .await
            .map_err(|e| crate::store::StoreError::Corrupt(format!("retention plan: {e}")))??;
            let mut pruned = Pruned::default();
            for step in steps {
                loop {
                    let done = store.maintain(move |conn| step.apply(conn)).await?;
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

/// Answers a request not answered within the limit: 408 when its body
/// had not all arrived (the client is slow), else 503 with `Retry-After`
/// (the server is stalled: a stuck store, an overload). A streamed body or
/// an open WebSocket, once answered, is not cut.
async fn answer_in_time(
    axum::extract::State(state): axum::extract::State<SharedState>,
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::body::HttpBody;
    use axum::response::IntoResponse;
    use futures_util::StreamExt;
    use std::sync::atomic::{AtomicBool, Ordering};
    let limit = state.limits.request_timeout;
    // Whether the whole body has been read (an empty one at once).
    let received = Arc::new(AtomicBool::new(request.body().is_end_stream()));
    let request = {
        let received = received.clone();
        request.map(|body| {
            let end = futures_util::stream::once(async move {
                received.store(true, Ordering::SeqCst);
                Ok::<_, axum::Error>(axum::body::Bytes::new())
            });
            axum::body::Body::from_stream(body.into_data_stream().chain(end))
        })
    };
    match tokio::time::timeout(limit, next.run(request)).await {
        Ok(response) => response,
        Err(_) if !received.load(Ordering::SeqCst) => ApiError::Timeout(format!(
            "the request's body did not arrive within {} s; if it was a post, retry it (duplicates are stored once)",
            limit.as_secs_f64()
        ))
        .into_response(),
        Err(_) => ApiError::Unavailable {
            reason: error::Refusal::Stalled,
            message: format!(
                "the server did not answer within {} s (overloaded or its store stuck); retry \
                 (a post's duplicates are stored once)",
                limit.as_secs_f64()
            ),
        }
        .into_response(),
    }
}

async fn method_not_allowed(method: axum::http::Method) -> ApiError {
    ApiError::MethodNotAllowed {
        method: method.to_string(),
    }
}

async fn not_found(uri: axum::http::Uri) -> ApiError {
    ApiError::NotFound(format!("no such endpoint: {}", uri.path()))
}

/// Serves until `shutdown` resolves, then closes live sockets, lets
/// in-flight requests finish and snapshots every machine.
pub async fn run(
    listener: TcpListener,
    state: SharedState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServerError> {
    let app = router(state.clone());
    let stopping = state.clone();
    axum::serve(listener, app)
        .with_graceful_shutdown(async move {
            shutdown.await;
            // Live sockets never end by themselves: tell them first.
            stopping.shutdown.send_replace(true);
        })
        .await?;
    state.stop().await;
    // Upgraded sockets outlive the HTTP server: give their close frames up
    // to 3 s to go out (a client that reads nothing gets none).
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(3);
    while state.live_sockets.load(std::sync::atomic::Ordering::SeqCst) > 0
        && std::time::Instant::now() < deadline
    {
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    Ok(())
}
