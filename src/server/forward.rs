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

use super::sites::{ForwardAnswer, SiteReport};
use super::state::SharedState;
use crate::store::outbox::{Backlog, OfficeEntry, OfficeItem};
use crate::store::{SqliteStore, StoreError};

/// Interval between the site's reports to the office.
pub const REPORT_EVERY: Duration = Duration::from_secs(2);
/// Most readings in one request to the office.
pub const MAX_READINGS_PER_REQUEST: u64 = 20_000;
/// Wait between looks at an empty outbox.
const IDLE: Duration = Duration::from_millis(100);
/// First and longest wait after a failed request.
const FIRST_RETRY: Duration = Duration::from_millis(250);
const MAX_RETRY: Duration = Duration::from_secs(5);
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
pub async fn start(state: SharedState, options: ForwardOptions) -> Result<(), ForwardError> {
    options.validate()?;
    let store = state.store.site_outbox()?.clone();
    store.forwarding(true).await?;
    let client = reqwest::Client::builder()
        .timeout(REQUEST_TIMEOUT)
        .connect_timeout(CONNECT_TIMEOUT)
        .build()
        .map_err(|e| ForwardError::Client(e.to_string()))?;
    super::metrics::forward_link(&options.site, false, 0, 0.0);
    tokio::spawn(run(state, store, client, options));
    Ok(())
}

/// What the loop knows of the link.
struct Link {
    connected: bool,
    /// Wait before the next attempt after a failure.
    retry: Duration,
    last_report: Option<Instant>,
    /// When the last failure was logged (one line a minute at most).
    last_logged: Option<Instant>,
}

async fn run(
    state: SharedState,
    store: SqliteStore,
    client: reqwest::Client,
    options: ForwardOptions,
) {
    let office = options.office.trim_end_matches('/').to_string();
    let mut stopping = state.shutdown_signal();
    let mut link = Link {
        connected: false,
        retry: FIRST_RETRY,
        last_report: None,
        last_logged: None,
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
    for (machine_id, machine) in pending {
        let entries = blocking(store, move |s| {
            s.office_entries(machine_id, MAX_READINGS_PER_REQUEST)
        })
        .await?;
        let Some(last) = entries.last().map(|e| e.sequence) else {
            continue;
        };
        let outcome = send(client, office, options, &machine, &entries).await;
        let applied = match outcome {
            Ok(applied) => applied,
            Err(why) => {
                settle(link, &options.site, Err(why)).await;
                return Ok(false);
            }
        };
        settle(link, &options.site, Ok(())).await;
        // The office answers the last sequence it holds for the machine.
        let sent = applied.min(last);
        match store.office_sent(machine_id, sent).await {
            Ok(()) => more = true,
            Err(StoreError::Closed) => return Err(Halt::Stop),
            Err(e) => {
                tracing::warn!(error = %e, "sent rows not deleted; sent again (the office keeps them once)");
                return Err(Halt::Retry);
            }
        }
    }
    Ok(more)
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
}

/// Sends one machine's rows; the sequence the office has committed up to.
async fn send(
    client: &reqwest::Client,
    office: &str,
    options: &ForwardOptions,
    machine: &str,
    entries: &[OfficeEntry],
) -> Result<i64, String> {
    let body = body(&options.site, entries)?;
    let request = client
        .post(format!(
            "{office}/api/v1/machines/{}.{machine}/forward",
            options.site
        ))
        .header(reqwest::header::CONTENT_TYPE, "application/json")
        .body(body);
    let bytes = answer(authorised(request, options).send().await).await?;
    let answer: ForwardAnswer = serde_json::from_slice(&bytes)
        .map_err(|e| format!("the office's answer is not a forwarding answer: {e}"))?;
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
async fn answer(sent: Result<reqwest::Response, reqwest::Error>) -> Result<Vec<u8>, String> {
    let response = sent.map_err(|e| format!("office not reached: {e}"))?;
    let status = response.status();
    let bytes = response
        .bytes()
        .await
        .map_err(|e| format!("office's answer cut off: {e}"))?;
    if status.is_success() {
        return Ok(bytes.to_vec());
    }
    Err(format!(
        "office answered {status}: {}",
        String::from_utf8_lossy(&bytes[..bytes.len().min(500)])
    ))
}

/// The JSON body of a forwarding ([`super::sites::ForwardBody`]), written
/// directly: readings are by far the most of it.
fn body(site: &str, entries: &[OfficeEntry]) -> Result<String, String> {
    let mut out = String::with_capacity(256 + entries.len() * 64);
    let _ = write!(out, "{{\"site\":{},\"items\":[", json(&site)?);
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
