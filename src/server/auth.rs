//! Access control at the HTTP edge: every request's token (an
//! `Authorization: Bearer` header, or the dashboard's `tunnelnav_token`
//! cookie set by `POST /login`) is checked against what its route needs:
//! each route in `server::router` declares it with one of the layers here
//! ([`read`], [`ingest`], [`admin`]; none for liveness, static files and
//! the login page). Missing or unknown token: 401; a token without
//! the scope or machine: 403; both with a JSON body. A page request
//! without a token is sent to the login page instead.
//!
//! Enforcement starts with the first token: a server with no tokens is
//! open, which `serve` allows only on a loopback address unless told
//! otherwise ([`Gate::insist`]). Tokens are reread from the store at most
//! every 2 s, so `tunnelnav token create|revoke` takes effect within that.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

use axum::Form;
use axum::extract::{Path, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::Next;
use axum::response::{Html, IntoResponse, Redirect, Response};
use serde::Deserialize;

use super::error::ApiError;
pub use super::openapi::COOKIE;
use super::signing::{self, Grant};
use super::state::SharedState;
use crate::auth::{self, Need, Token};
use crate::store::Store;

/// How long the token list is trusted before it is read again.
const REFRESH: Duration = Duration::from_secs(2);

/// Tokens in force by hash, shared by the requests that check them.
type Tokens = Arc<HashMap<String, Token>>;

/// The server's view of the tokens in force.
pub struct Gate {
    tokens: RwLock<Option<(Instant, Tokens)>>,
    /// Enforce even with no tokens (non-loopback without the override).
    insist: AtomicBool,
}

impl Default for Gate {
    fn default() -> Self {
        Gate {
            tokens: RwLock::new(None),
            insist: AtomicBool::new(false),
        }
    }
}

impl Gate {
    /// Demands a token even while none exist (nobody gets in until one is
    /// created): for a server reachable beyond this host.
    pub fn insist(&self) {
        self.insist.store(true, Ordering::Relaxed);
    }

    /// The tokens in force (hash → token), reread when stale.
    async fn current(&self, store: &Store) -> Result<Tokens, ApiError> {
        if let Ok(guard) = self.tokens.read()
            && let Some((read_at, tokens)) = guard.as_ref()
            && read_at.elapsed() < REFRESH
        {
            return Ok(tokens.clone());
        }
        let tokens: Tokens = Arc::new(store.active_tokens().await?.into_iter().collect());
        if let Ok(mut guard) = self.tokens.write() {
            *guard = Some((Instant::now(), tokens.clone()));
        }
        Ok(tokens)
    }

    /// Whether `presented` (a token text, if any) may do `need`: the
    /// token if it was checked, `None` while access is open.
    async fn check(
        &self,
        store: &Store,
        presented: Option<&str>,
        need: &Need,
    ) -> Result<Option<Token>, ApiError> {
        if *need == Need::Nothing {
            return Ok(None);
        }
        let tokens = self.current(store).await?;
        if tokens.is_empty() && !self.insist.load(Ordering::Relaxed) {
            return Ok(None);
        }
        let Some(presented) = presented else {
            return Err(ApiError::Unauthorized(
                "a token is required: send `Authorization: Bearer <token>`".into(),
            ));
        };
        let Some(token) = tokens.get(&auth::hash(presented)) else {
            return Err(ApiError::Unauthorized(
                "the token is not valid (unknown or revoked)".into(),
            ));
        };
        if token.allows(need) {
            return Ok(Some(token.clone()));
        }
        Err(refused(token, need))
    }

    /// Whether the caller another node vouches for (`grant`, signed) may do
    /// `need` here: its token as this node's store has it (in force, with
    /// its scope), access open here too, or the node itself for ingest.
    async fn check_grant(
        &self,
        store: &Store,
        grant: &Grant,
        need: &Need,
    ) -> Result<Option<Token>, ApiError> {
        match grant {
            Grant::Open => self.check(store, None, need).await,
            Grant::Node if Grant::node_allows(need) => Ok(None),
            Grant::Node => Err(ApiError::Forbidden(
                "a node forwards readings in its own name, nothing else".into(),
            )),
            Grant::Token { id, name } => {
                let tokens = self.current(store).await?;
                let Some(token) = tokens.values().find(|t| t.id == *id) else {
                    return Err(ApiError::Unauthorized(format!(
                        "token `{name}` (#{id}) the forwarding node checked is not in force here"
                    )));
                };
                if token.allows(need) {
                    Ok(Some(token.clone()))
                } else {
                    Err(refused(token, need))
                }
            }
        }
    }
}

/// The 403 of `token`, which does not grant `need`.
fn refused(token: &Token, need: &Need) -> ApiError {
    ApiError::Forbidden(match need {
        Need::Ingest(machine) => format!(
            "token `{}` ({}) may not send readings of machine `{machine}`",
            token.name,
            describe(token)
        ),
        Need::Admin => format!(
            "token `{}` ({}) may not change the configuration: admin scope needed",
            token.name,
            describe(token)
        ),
        Need::Site(site) => format!(
            "token `{}` ({}) may not forward as site `{site}`: a site token for it needed",
            token.name,
            describe(token)
        ),
        Need::Acknowledge => format!(
            "token `{}` ({}) may not acknowledge alarms: operator scope needed (a read \
                 token changes nothing)",
            token.name,
            describe(token)
        ),
        _ => format!(
            "token `{}` ({}) may not read: read scope needed",
            token.name,
            describe(token)
        ),
    })
}

fn describe(token: &Token) -> String {
    match &token.machine {
        Some(machine) => format!("{} for `{machine}`", token.scope.as_str()),
        None => token.scope.as_str().to_string(),
    }
}

/// The token a request carries: the bearer header, else the cookie.
fn presented(headers: &HeaderMap) -> Option<String> {
    if let Some(value) = headers.get(header::AUTHORIZATION)
        && let Ok(text) = value.to_str()
        && let Some(token) = text.strip_prefix("Bearer ")
    {
        return Some(token.trim().to_string());
    }
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|pair| pair.trim().split_once('='))
        .find(|(name, _)| *name == COOKIE)
        .map(|(_, value)| value.to_string())
}

/// True for a browser asking for a page (not the API).
fn wants_page(request: &Request) -> bool {
    !request.uri().path().starts_with("/api/")
        && request
            .headers()
            .get(header::ACCEPT)
            .and_then(|v| v.to_str().ok())
            .is_some_and(|accept| accept.contains("text/html"))
}

/// The route layer of routes that read (pages, history, status, live).
pub async fn read(State(state): State<SharedState>, request: Request, next: Next) -> Response {
    require(&state, Need::Read, request, next).await
}

/// The route layer of routes that send a machine's readings; the machine
/// is the route's `{machine}`.
pub async fn ingest(
    State(state): State<SharedState>,
    Path(machine): Path<String>,
    request: Request,
    next: Next,
) -> Response {
    require(&state, Need::Ingest(machine), request, next).await
}

/// The route layer of a site's routes: the site is the route's `{site}`,
/// or the part of its `{machine}` before the dot (`{site}.{machine}`).
pub async fn site(
    State(state): State<SharedState>,
    Path(name): Path<String>,
    request: Request,
    next: Next,
) -> Response {
    let site = name.split_once('.').map_or(name.as_str(), |(site, _)| site);
    require(&state, Need::Site(site.to_string()), request, next).await
}

/// The route layer of routes that acknowledge alarms.
pub async fn acknowledge(
    State(state): State<SharedState>,
    request: Request,
    next: Next,
) -> Response {
    require(&state, Need::Acknowledge, request, next).await
}

/// The route layer of routes that change the configuration.
pub async fn admin(State(state): State<SharedState>, request: Request, next: Next) -> Response {
    require(&state, Need::Admin, request, next).await
}

/// Who a request came from: the token it carried, `None` while access is
/// open (no tokens) or for a node's own readings. Set by the route layers.
#[derive(Debug, Clone)]
pub struct Caller(pub Option<Token>);

/// Who a record (an acknowledgement, an audit row) names while access is
/// open (no tokens exist).
const ANONYMOUS: &str = "anonymous";

impl Caller {
    /// The token's name, if a token was checked.
    pub fn name(&self) -> Option<&str> {
        self.0.as_ref().map(|t| t.name.as_str())
    }

    /// The name a record gives the request's caller: its token's, or
    /// `anonymous` while access is open.
    pub fn recorded(caller: Option<&Caller>) -> String {
        caller
            .and_then(Caller::name)
            .unwrap_or(ANONYMOUS)
            .to_string()
    }
}

/// Lets the request through if its token grants `need`, telling the
/// handler who it is ([`Caller`]).
async fn require(state: &SharedState, need: Need, mut request: Request, next: Next) -> Response {
    // Signed by another node: its signature, then the caller it vouches
    // for, checked here against this route.
    if let Some(cluster) = &state.cluster
        && request.headers().contains_key(signing::NODE_HEADER)
    {
        return match from_node(state, cluster, &need, request).await {
            Ok(request) => next.run(request).await,
            Err(e) => e.into_response(),
        };
    }
    let token = presented(request.headers());
    match state
        .gate
        .check(&state.store, token.as_deref(), &need)
        .await
    {
        Ok(token) => {
            request.extensions_mut().insert(Caller(token));
            next.run(request).await
        }
        Err(ApiError::Unauthorized(_)) if wants_page(&request) => {
            Redirect::to("/login").into_response()
        }
        Err(e) => {
            let mut response = e.into_response();
            if response.status() == StatusCode::UNAUTHORIZED {
                response.headers_mut().insert(
                    header::WWW_AUTHENTICATE,
                    HeaderValue::from_static("Bearer realm=\"tunnelnav\""),
                );
            }
            response
        }
    }
}

/// A request another node signed, checked (signature, then its caller
/// against `need`) and given back with its body and [`Caller`].
async fn from_node(
    state: &SharedState,
    cluster: &super::cluster::Cluster,
    need: &Need,
    request: Request,
) -> Result<Request, ApiError> {
    let (mut parts, body) = request.into_parts();
    let body = super::cluster::whole_body(body, state.limits.max_body_bytes).await?;
    let target = parts
        .uri
        .path_and_query()
        .map_or("/", |p| p.as_str())
        .to_string();
    let grant = cluster
        .forwarded(&parts.headers, (parts.method.as_str(), &target, &body))
        .await?;
    let token = state.gate.check_grant(&state.store, &grant, need).await?;
    parts.extensions.insert(Caller(token));
    Ok(Request::from_parts(parts, axum::body::Body::from(body)))
}

/// `GET /login`: a form that posts a token (never in a URL).
pub async fn login_page() -> Html<String> {
    Html(LOGIN_PAGE.replace(LOGIN_ERROR, ""))
}

/// Where the login page says why a sign-in failed.
const LOGIN_ERROR: &str = "<!--error-->";

/// The login page again, saying why the token was refused.
fn login_refused(error: &ApiError) -> Response {
    let escaped = error
        .to_string()
        .replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;");
    let page = LOGIN_PAGE.replace(
        LOGIN_ERROR,
        &format!(r#"<p class="login-error" role="alert">Not signed in: {escaped}</p>"#),
    );
    (error.status(), Html(page)).into_response()
}

const LOGIN_PAGE: &str = r#"<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>tunnelnav · sign in</title>
<link rel="icon" href="/static/favicon.svg" type="image/svg+xml">
<link rel="stylesheet" href="/static/app.css"></head>
<body><main class="login"><h1>tunnelnav</h1>
<!--error-->
<form method="post" action="/login">
<label for="token">Access token (read or admin)</label>
<input id="token" name="token" type="password" autocomplete="current-password" required>
<button type="submit">Sign in</button>
</form>
<p class="note">Tokens come from <code>tunnelnav token create</code>. The token is kept in a cookie for this site only; it never appears in a URL.</p>
</main></body></html>"#;

#[derive(Debug, Deserialize)]
pub struct LoginForm {
    token: String,
}

/// `POST /login`: checks the token can read, then keeps it in an
/// HttpOnly, SameSite=Strict cookie and goes to the fleet page.
pub async fn login(State(state): State<SharedState>, Form(form): Form<LoginForm>) -> Response {
    let token = form.token.trim();
    if let Err(e) = state
        .gate
        .check(&state.store, Some(token), &Need::Read)
        .await
    {
        return login_refused(&e);
    }
    let cookie = format!("{COOKIE}={token}; Path=/; HttpOnly; SameSite=Strict");
    match HeaderValue::from_str(&cookie) {
        Ok(value) => {
            let mut response = Redirect::to("/").into_response();
            response.headers_mut().insert(header::SET_COOKIE, value);
            response
        }
        Err(_) => login_refused(&ApiError::BadRequest(
            "the token has characters a cookie cannot hold".into(),
        )),
    }
}

/// `POST /logout`: forgets the cookie.
pub async fn logout() -> Response {
    let mut response = Redirect::to("/login").into_response();
    response.headers_mut().insert(
        header::SET_COOKIE,
        HeaderValue::from_static("tunnelnav_token=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0"),
    );
    response
}
