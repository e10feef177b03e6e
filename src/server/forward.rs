//! A site's side of forwarding (`serve --forward-to URL --site NAME`):
//! one task sends the store's outbox to the office, machine by machine,
//! each machine's rows in order, at most [`MAX_READINGS_PER_REQUEST`]
//! readings a request, and deletes rows only once the office has answered
//! that it committed them. A cut line, a refusing or restarting office
//! is retried with back-off, for as long as it takes: the backlog stays
//! in the store, bounded by its size limit (beyond it ingest here answers
//! 503, which the gateways retry), never dropped. Every
//! [`REPORT_EVERY`] the site reports its backlog to the office (the
//! link's heartbeat).

use std::fmt::Write as _;
use std::time::{Duration, Instant};

use tokio::sync::watch;

use crate::store::outbox::{Backlog, OfficeEntry, OfficeItem};
use crate::store::{SqliteStore, Store, StoreError};

/// The office's answer: every row up to `applied` is committed here.
#[derive(Debug, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct ForwardAnswer {
    pub machine: String,
    pub applied: i64,
}

/// A site's report of what it has not sent.
#[derive(Debug, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SiteReport {
    /// Outbox rows not sent.
    pub backlog_items: u64,
    /// Readings in them.
    pub backlog_readings: u64,
    /// Age of the oldest, seconds by the site's clock (0 if none).
    pub oldest_unsent_s: f64,
}

/// Interval between the site's reports to the office.
pub const REPORT_EVERY: Duration = Duration::from_secs(2);
/// Most readings in one request to the office.
pub const MAX_READINGS_PER_REQUEST: u64 = 20_000;
/// Wait between looks at an empty outbox.
const IDLE: Duration = Duration::from_millis(100);
/// First and longest wait after a failed request.
const FIRST_RETRY: Duration = Duration::from_millis(100);
const MAX_RETRY: Duration = Duration::from_millis(500);
/// Longest one request may take (a dead line swallows it unanswered).
const REQUEST_TIMEOUT: Duration = Duration::from_secs(15);
/// Longest a connection may take to open.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// Where and as whom a site forwards.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ForwardOptions {
    /// The office's base URL, `http://HOST:PORT`.
    pub office: String,
    /// This site's name: its machines are `{site}.{machine}` at the office.
    pub site: String,
    /// The office's `site` token for this site, if the office asks for one.
    pub token: Option<String>,
}

/// Why forwarding could not start.
#[derive(Debug, thiserror::Error)]
pub enum ForwardError {
    #[error("--forward-to `{0}` is not an http:// URL with a host ({1})")]
    Url(String, String),
    #[error("--site `{0}` is not a site name: 1 to 64 letters, digits, `-` or `_`")]
    Site(String),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("no HTTP client: {0}")]
    Client(String),
}

impl ForwardOptions {
    /// Checks the URL and the name.
    pub fn validate(&self) -> Result<(), ForwardError> {
        let url = reqwest::Url::parse(&self.office)
            .map_err(|e| ForwardError::Url(self.office.clone(), e.to_string()))?;
        if url.scheme() != "http" || url.host_str().is_none() {
            return Err(ForwardError::Url(
                self.office.clone(),
                "only http:// with a host: put a TLS tunnel or proxy in front for https".into(),
            ));
        }
        if !crate::config::valid_machine_id(&self.site) {
            return Err(ForwardError::Site(self.site.clone()));
        }
        Ok(())
    }
}

/// Starts forwarding the store's outbox: declares to the office every
/// machine it has not been told of yet, then sends as rows are committed.
/// The task ends when `stopping` turns true.
pub async fn start(
    store: &Store,
    stopping: watch::Receiver<bool>,
    options: ForwardOptions,
) -> Result<tokio::task::JoinHandle<()>, ForwardError> {
    options.validate()?;
    let store = store.site_outbox()?.clone();
    store
        .forward_to(options.office.clone(), options.site.clone())
        .await?;
    let client = reqwest::Client::builder()
        .timeout(REQUEST_TIMEOUT)
        .connect_timeout(CONNECT_TIMEOUT)
        .build()
        .map_err(|e| ForwardError::Client(e.to_string()))?;
    super::metrics::forward_link(&options.site, false, 0, 0.0);
    Ok(tokio::spawn(run(stopping, store, client, options)))
}

/// What the loop knows of the link.
struct Link {
    connected: bool,
    /// Wait before the next attempt after a failure.
    retry: Duration,
    last_report: Option<Instant>,
    /// When the last failure was logged (one line a minute at most).
    last_logged: Option<Instant>,
    /// Most readings a request carries (halved while the office answers
    /// 413).
    max_readings: u64,
    /// Machines whose rows the office refused (4xx): when to try again,
    /// how long the wait was, when it was last logged.
    refused: std::collections::HashMap<i64, (Instant, Duration, Option<Instant>)>,
}

/// A request that did not go through.
struct Failure {
    /// The office's answer, if there was one.
    status: Option<reqwest::StatusCode>,
    why: String,
}

impl Failure {
    /// The office refused these rows themselves (not the line, not a
    /// passing overload): trying again at once would fail alike.
    fn refused(&self) -> bool {
        self.status.is_some_and(|status| {
            status.is_client_error()
                && status != reqwest::StatusCode::REQUEST_TIMEOUT
                && status != reqwest::StatusCode::TOO_MANY_REQUESTS
                && status != reqwest::StatusCode::PAYLOAD_TOO_LARGE
        })
    }
}

async fn run(
    mut stopping: watch::Receiver<bool>,
    store: SqliteStore,
    client: reqwest::Client,
    options: ForwardOptions,
) {
    let office = options.office.trim_end_matches('/').to_string();
    let mut link = Link {
        connected: false,
        retry: FIRST_RETRY,
        last_report: None,
        last_logged: None,
        max_readings: MAX_READINGS_PER_REQUEST,
        refused: std::collections::HashMap::new(),
    };
    tracing::info!(%office, site = %options.site, "forwarding to the office");
    loop {
        if *stopping.borrow() {
            return;
        }
        let pause = match round(&store, &client, &office, &options, &mut link).await {
            Ok(true) => Duration::ZERO,
            Ok(false) => IDLE,
            Err(Halt::Retry) => MAX_RETRY,
            Err(Halt::Stop) => return,
        };
        if pause.is_zero() {
            continue;
        }
        tokio::select! {
            _ = tokio::time::sleep(pause) => {}
            _ = stopping.changed() => return,
        }
    }
}

/// Why a pass ended early.
enum Halt {
    /// The store has closed: forwarding ends.
    Stop,
    /// The outbox could not be read or updated: again later.
    Retry,
}

/// One pass: the report if due, then one request per machine with rows
/// owed. `Ok(true)` if there may be more to send at once.
async fn round(
    store: &SqliteStore,
    client: &reqwest::Client,
    office: &str,
    options: &ForwardOptions,
    link: &mut Link,
) -> Result<bool, Halt> {
    if link.last_report.is_none_or(|t| t.elapsed() >= REPORT_EVERY) {
        link.last_report = Some(Instant::now());
        let backlog = blocking(store, |s| s.office_backlog()).await?;
        let outcome = report(client, office, options, &backlog).await;
        settle(link, &options.site, outcome).await;
    }
    let pending = blocking(store, |s| s.office_pending()).await?;
    let mut more = false;
    for (machine_id, machine, acked) in pending {
        if let Some((until, _, _)) = link.refused.get(&machine_id)
            && Instant::now() < *until
        {
            continue;
        }
        let max_readings = link.max_readings;
        let read_at = Instant::now();
        let entries = blocking(store, move |s| s.office_entries(machine_id, max_readings)).await?;
        let read_s = read_at.elapsed().as_secs_f64();
        let Some(last) = entries.last().map(|e| e.sequence) else {
            continue;
        };
        let sent_at = Instant::now();
        let applied = match send(client, office, options, &machine, acked, &entries).await {
            Ok(applied) => applied,
            Err(failure) if failure.status == Some(reqwest::StatusCode::PAYLOAD_TOO_LARGE) => {
                link.max_readings = (link.max_readings / 2).max(1);
                tracing::warn!(%machine, max_readings = link.max_readings, "the office refused a request as too large: sending fewer readings a request");
                more = true;
                continue;
            }
            Err(failure) if failure.refused() => {
                refuse(link, machine_id, &machine, &failure.why);
                continue;
            }
            Err(failure) => {
                settle(link, &options.site, Err(failure.why)).await;
                return Ok(false);
            }
        };
        link.refused.remove(&machine_id);
        settle(link, &options.site, Ok(())).await;
        // The office answers the last sequence it holds for the machine.
        let sent = applied.min(last);
        if sent <= 0 || acked.is_some_and(|acked| sent <= acked) {
            continue;
        }
        let send_s = sent_at.elapsed().as_secs_f64();
        let deleted_at = Instant::now();
        match store.office_sent(machine_id, sent).await {
            Ok(()) => {
                more = true;
                tracing::debug!(%machine, rows = entries.len(), read_s, send_s, delete_s = deleted_at.elapsed().as_secs_f64(), "forwarded");
            }
            Err(StoreError::Closed) => return Err(Halt::Stop),
            Err(e) => {
                tracing::warn!(error = %e, "sent rows not deleted; sent again (the office keeps them once)");
                return Err(Halt::Retry);
            }
        }
    }
    Ok(more)
}

/// The office refused a machine's rows: that machine waits (doubling from
/// 1 s to a minute) while the others go on; logged once a minute.
fn refuse(link: &mut Link, machine_id: i64, machine: &str, why: &str) {
    let now = Instant::now();
    let (_, wait, logged) =
        link.refused
            .get(&machine_id)
            .copied()
            .unwrap_or((now, Duration::from_millis(500), None));
    let wait = (wait * 2).min(Duration::from_secs(60));
    let log = logged.is_none_or(|t| t.elapsed() >= Duration::from_secs(60));
    if log {
        tracing::error!(%machine, reason = %why, retry_in_s = wait.as_secs_f64(), "the office refuses this machine's rows; they stay in the outbox, sent again later");
    }
    link.refused.insert(
        machine_id,
        (now + wait, wait, if log { Some(now) } else { logged }),
    );
}

/// Notes a request's outcome: the link's gauge, and after a failure a
/// wait that doubles up to [`MAX_RETRY`].
async fn settle(link: &mut Link, site: &str, outcome: Result<(), String>) {
    match outcome {
        Ok(()) => {
            if !link.connected {
                tracing::info!("office link up");
            }
            link.connected = true;
            link.retry = FIRST_RETRY;
        }
        Err(why) => {
            if link.connected
                || link
                    .last_logged
                    .is_none_or(|t| t.elapsed() >= Duration::from_secs(60))
            {
                tracing::warn!(reason = %why, retry_in_s = link.retry.as_secs_f64(), "office link down; what it has not committed stays in the outbox");
                link.last_logged = Some(Instant::now());
            }
            link.connected = false;
            tokio::time::sleep(link.retry).await;
            link.retry = (link.retry * 2).min(MAX_RETRY);
        }
    }
    super::metrics::forward_connected(site, link.connected);
}

/// Runs a blocking store read.
async fn blocking<R: Send + 'static>(
    store: &SqliteStore,
    read: impl FnOnce(&SqliteStore) -> Result<R, StoreError> + Send + 'static,
) -> Result<R, Halt> {
    let store = store.clone();
    match tokio::task::spawn_blocking(move || read(&store)).await {
        Ok(Ok(value)) => Ok(value),
        Ok(Err(StoreError::Closed)) | Err(_) => Err(Halt::Stop),
        Ok(Err(e)) => {
            tracing::error!(error = %e, "outbox not readable; trying again");
            Err(Halt::Retry)
        }
    }
}

/// Reports the backlog to the office.
async fn report(
    client: &reqwest::Client,
    office: &str,
    options: &ForwardOptions,
    backlog: &Backlog,
) -> Result<(), String> {
    let oldest_unsent_s = backlog
        .oldest_unsent_t
        .map_or(0.0, |t| (crate::clock::wall_clock_s() - t).max(0.0));
    super::metrics::forward_backlog(&options.site, backlog.readings, oldest_unsent_s);
    let body = SiteReport {
        backlog_items: backlog.items,
        backlog_readings: backlog.readings,
        oldest_unsent_s,
    };
    let request = client
        .put(format!("{office}/api/v1/sites/{}", options.site))
        .header(reqwest::header::CONTENT_TYPE, "application/json")
        .body(json(&body)?);
    answer(authorised(request, options).send().await)
        .await
        .map(|_| ())
        .map_err(|failure| failure.why)
}

/// Sends one machine's rows (`acked`: the last sequence the office has
/// answered for it); the sequence the office has committed up to.
async fn send(
    client: &reqwest::Client,
    office: &str,
    options: &ForwardOptions,
    machine: &str,
    acked: Option<i64>,
    entries: &[OfficeEntry],
) -> Result<i64, Failure> {
    let body = body(&options.site, acked, entries).map_err(|why| Failure { status: None, why })?;
    let request = client
        .post(format!(
            "{office}/api/v1/machines/{}.{machine}/forward",
            options.site
        ))
        .header(reqwest::header::CONTENT_TYPE, "application/json")
        .body(body);
    let bytes = answer(authorised(request, options).send().await).await?;
    let answer: ForwardAnswer = serde_json::from_slice(&bytes).map_err(|e| Failure {
        status: None,
        why: format!("the office's answer is not a forwarding answer: {e}"),
    })?;
    Ok(answer.applied)
}

fn authorised(
    request: reqwest::RequestBuilder,
    options: &ForwardOptions,
) -> reqwest::RequestBuilder {
    match &options.token {
        Some(token) => request.bearer_auth(token),
        None => request,
    }
}

/// The body of a 2xx answer, else why not.
async fn answer(sent: Result<reqwest::Response, reqwest::Error>) -> Result<Vec<u8>, Failure> {
    let response = sent.map_err(|e| Failure {
        status: None,
        why: format!("office not reached: {e}"),
    })?;
    let status = response.status();
    let bytes = response.bytes().await.map_err(|e| Failure {
        status: None,
        why: format!("office's answer cut off: {e}"),
    })?;
    if status.is_success() {
        return Ok(bytes.to_vec());
    }
    Err(Failure {
        status: Some(status),
        why: format!(
            "office answered {status}: {}",
            String::from_utf8_lossy(&bytes[..bytes.len().min(500)])
        ),
    })
}

/// The JSON body of a forwarding ([`super::sites::ForwardBody`]), written
/// directly: readings are by far the most of it.
fn body(site: &str, acked: Option<i64>, entries: &[OfficeEntry]) -> Result<String, String> {
    let mut out = String::with_capacity(256 + entries.len() * 64);
    let _ = write!(
        out,
        "{{\"site\":{},\"after\":{},\"items\":[",
        json(&site)?,
        json(&acked)?
    );
    for (i, entry) in entries.iter().enumerate() {
        if i > 0 {
            out.push(',');
        }
        let _ = write!(out, "{{\"sequence\":{},", entry.sequence);
        match &entry.item {
            OfficeItem::Machine(declared) => {
                let _ = write!(out, "\"machine\":{}", json(declared)?);
            }
            OfficeItem::Alarm(change) => {
                let _ = write!(out, "\"alarm\":{}", json(change)?);
            }
            OfficeItem::Readings(readings) => {
                out.push_str("\"readings\":[");
                for (k, reading) in readings.iter().enumerate() {
                    if k > 0 {
                        out.push(',');
                    }
                    out.push_str(&reading.to_json());
                }
                out.push(']');
            }
        }
        out.push('}');
    }
    out.push_str("]}");
    Ok(out)
}

/// One of the few non-reading parts of a body, as JSON.
fn json<T: serde::Serialize + ?Sized>(value: &T) -> Result<String, String> {
    serde_json::to_string(value).map_err(|e| format!("not serialisable: {e}"))
}
