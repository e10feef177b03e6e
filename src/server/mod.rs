//! The HTTP server: the router and `run` (serve until told to stop, then
//! close sockets and snapshot every machine). Shared state is in
//! [`state`], start-up in `boot.rs`, the machines' comings and goings in
//! `fleet.rs`, settings in [`settings`]. Handlers only translate:
//! extract, ask the store or a machine's task, map errors.

mod alarms;
mod alignment;
mod audit;
pub mod auth;
mod boot;
pub mod cluster;
pub mod csv_text;
mod error;
mod feeds;
mod fleet;
pub mod forward;
mod history;
mod ingest;
mod live;
pub(crate) mod machines;
pub mod metrics;
pub mod mqtt;
pub mod notify;
pub(crate) mod openapi;
pub mod pages;
mod report;
mod retention;
mod ring_plan;
pub mod settings;
pub mod signing;
mod site_links;
pub mod sites;
pub mod state;
mod steering;

use std::future::Future;
use std::sync::Arc;

use axum::extract::DefaultBodyLimit;
use axum::handler::Handler;
use axum::routing::get;
use axum::{Extension, Router};
use tokio::net::TcpListener;
use tower_http::trace::TraceLayer;
use utoipa::OpenApi;
use utoipa_axum::router::{OpenApiRouter, UtoipaMethodRouter};
use utoipa_axum::routes;

pub use boot::ServerOptions;
pub use error::{ApiError, Rejected};
pub use ingest::{BatchRules, ParsedBatch, parse_batch};
pub use state::{AppState, ServerError, SharedState};

/// What a route needs of the caller's token (see `auth`).
#[derive(Debug, Clone, Copy)]
enum Role {
    Read,
    /// Read, and acknowledge alarms.
    Operator,
    Ingest,
    Admin,
    /// A site forwarding to this office (a `site` token for the site the
    /// route's `{site}` or `{machine}`'s prefix names).
    Site,
}

impl Role {
    fn as_str(self) -> &'static str {
        match self {
            Role::Read => "read",
            Role::Operator => "operator",
            Role::Ingest => "ingest",
            Role::Admin => "admin",
            Role::Site => "site",
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
    // The token is checked here, then a machine fused by another node is
    // forwarded there.
    let routes = routes.layer(axum::middleware::from_fn_with_state(
        state.clone(),
        cluster::proxy::forward,
    ));
    let routes = match role {
        Role::Read => routes.layer(axum::middleware::from_fn_with_state(state, auth::read)),
        Role::Operator => routes.layer(axum::middleware::from_fn_with_state(
            state,
            auth::acknowledge,
        )),
        Role::Ingest => routes.layer(axum::middleware::from_fn_with_state(state, auth::ingest)),
        Role::Admin => routes.layer(axum::middleware::from_fn_with_state(state, auth::admin)),
        Role::Site => routes.layer(axum::middleware::from_fn_with_state(state, auth::site)),
    };
    (schemas, paths, routes)
}

/// The API's routes, each with its description (`openapi`).
fn api_routes(state: &SharedState) -> OpenApiRouter<SharedState> {
    use Role::{Admin, Ingest, Operator, Read, Site};
    let guard = |role, routes| guarded(state, role, routes);
    OpenApiRouter::with_openapi(openapi::ApiDoc::openapi())
        .routes(guard(Read, routes!(pages::fleet)))
        .routes(guard(Read, routes!(pages::machine)))
        .routes(routes!(metrics::serve::healthz))
        .routes(routes!(openapi::document))
        .routes(guard(Read, routes!(metrics::serve::render)))
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
        .routes(guard(Read, routes!(steering::show)))
        .routes(guard(Read, routes!(ring_plan::show)))
        .routes(guard(Read, routes!(report::show)))
        .routes(guard(Read, routes!(report::as_built::show)))
        .routes(guard(Read, routes!(alarms::list)))
        .routes(guard(Read, routes!(live::alarms_websocket)))
        .routes(guard(Operator, routes!(alarms::ack)))
        .routes(guard(Read, routes!(cluster::api::show)))
        .routes(guard(Site, routes!(sites::forward)))
        .routes(guard(Admin, routes!(sites::reset_mark)))
        .routes(guard(Admin, routes!(audit::list)))
        .routes(guard(Site, routes!(sites::report)))
        .routes(guard(Read, routes!(sites::list)))
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
        .layer(axum::middleware::from_fn(errors_as_json))
        .layer(axum::middleware::from_fn(security_headers))
        .layer(
            TraceLayer::new_for_http()
                .make_span_with(request_span(state.access_log))
                .on_request(())
                .on_response(
                    tower_http::trace::DefaultOnResponse::new()
                        .level(state.access_log)
                        .latency_unit(tower_http::LatencyUnit::Millis),
                ),
        )
        .with_state(state)
}

/// The pages' Content-Security-Policy: scripts only from the service's own
/// files (no inline script, no eval), styles also inline (the printable
/// reports and the API docs' viewer set theirs), no framing by other sites.
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'self'; script-src 'self'; \
style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; media-src 'self' data: blob:; font-src 'self' data:; \
connect-src 'self'; object-src 'none'; base-uri 'self'; form-action 'self'; \
frame-ancestors 'none'";

/// An error the framework answered in plain text (a path that is not
/// UTF-8, a query it cannot read) answered as every error is: JSON naming
/// what was wrong.
async fn errors_as_json(
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::response::IntoResponse;
    let response = next.run(request).await;
    let plain = response
        .headers()
        .get(axum::http::header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("text/plain"));
    if !(plain && (response.status().is_client_error() || response.status().is_server_error())) {
        return response;
    }
    let (parts, body) = response.into_parts();
    // The framework's messages are a line; more is not read.
    let text = match axum::body::to_bytes(body, 64 * 1024).await {
        Ok(bytes) => String::from_utf8_lossy(&bytes).trim().to_string(),
        Err(_) => parts
            .status
            .canonical_reason()
            .unwrap_or("error")
            .to_string(),
    };
    let mut json = (
        parts.status,
        axum::Json(serde_json::json!({ "error": text })),
    )
        .into_response();
    for (name, value) in parts.headers.iter() {
        if name != axum::http::header::CONTENT_TYPE && name != axum::http::header::CONTENT_LENGTH {
            json.headers_mut().insert(name.clone(), value.clone());
        }
    }
    json
}

/// Security headers on every answer (where a handler set none): the
/// Content-Security-Policy, no MIME sniffing, no referrer to other sites,
/// no framing.
async fn security_headers(
    request: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    use axum::http::{HeaderValue, header};
    let mut response = next.run(request).await;
    let headers = response.headers_mut();
    for (name, value) in [
        (header::CONTENT_SECURITY_POLICY, CONTENT_SECURITY_POLICY),
        (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        (header::REFERRER_POLICY, "same-origin"),
        (header::X_FRAME_OPTIONS, "DENY"),
    ] {
        headers
            .entry(name)
            .or_insert(HeaderValue::from_static(value));
    }
    response
}

/// The span of one request, so its one INFO line (on the response: status
/// and latency) names the method, the route as declared (`{machine}` and
/// all, or `unmatched`) and the machine, if the route has one.
fn request_span(
    level: tracing::Level,
) -> impl Fn(&axum::http::Request<axum::body::Body>) -> tracing::Span + Clone {
    move |request| {
        let span = match level {
            tracing::Level::DEBUG => tracing::debug_span!(
                "request",
                method = %request.method(),
                route = tracing::field::Empty,
                machine = tracing::field::Empty,
            ),
            _ => tracing::info_span!(
                "request",
                method = %request.method(),
                route = tracing::field::Empty,
                machine = tracing::field::Empty,
            ),
        };
        describe_request(request, &span);
        span
    }
}

/// Records the route and the machine of `request` in its `span`.
fn describe_request(request: &axum::http::Request<axum::body::Body>, span: &tracing::Span) {
    let route = request
        .extensions()
        .get::<axum::extract::MatchedPath>()
        .map_or("unmatched", |m| m.as_str());
    // The path segment where the route says `{machine}`.
    let machine = route
        .split('/')
        .position(|segment| segment == "{machine}")
        .and_then(|i| request.uri().path().split('/').nth(i));
    span.record("route", tracing::field::display(route));
    if let Some(machine) = machine {
        span.record("machine", tracing::field::display(machine));
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
            stopping.signal_shutdown();
        })
        .await?;
    state.stop().await;
    // Upgraded sockets outlive the HTTP server: give their close frames up
    // to 3 s to go out (a client that reads nothing gets none).
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(3);
    while state.live_sockets_open() > 0 && std::time::Instant::now() < deadline {
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    Ok(())
}
