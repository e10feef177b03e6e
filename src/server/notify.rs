//! Where a stored alarm change goes: live clients (the fleet-wide and the
//! machine sockets, through one broadcast channel) and the webhooks of the
//! server config, each URL served by its own task in order, with retries
//! and back-off. Changes reach the notifier only after their commit, once
//! each (a transition recomputed after a restart is not stored again, so
//! not notified again).
//!
//! A change owed to a webhook is in the store's outbox, written in the
//! commit that made it: the URL's task posts what the outbox holds and
//! deletes it once answered (or given up), so a change not yet posted
//! when the server stops or is killed is posted after the restart, with
//! the same idempotency key (on PostgreSQL by the node that made it, once
//! it runs again under its name).

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::broadcast;

use super::settings::WebhookConfig;
use crate::machine::AlarmSink;
use crate::store::alarms::{AlarmChange, Change};

/// Alarm changes a live client may fall behind by before it is told to
/// fetch the list again.
pub const ALARM_BUFFER: usize = 1024;

/// Hands stored alarm changes to live clients and webhooks.
#[derive(Clone)]
pub struct AlarmNotifier {
    live: broadcast::Sender<Arc<AlarmChange>>,
    /// The changes this node made (not those relayed from other nodes).
    own: broadcast::Sender<Arc<AlarmChange>>,
    /// Wakes the task of the URL of `warn` (`alarm`) changes when one is
    /// committed.
    warn: Option<Arc<tokio::sync::Notify>>,
    alarm: Option<Arc<tokio::sync::Notify>>,
}

impl AlarmNotifier {
    /// A notifier; starts one delivery task per configured webhook URL,
    /// posting from `store`'s outbox (call within a tokio runtime).
    pub fn start(webhooks: &WebhookConfig, store: &crate::store::Store) -> AlarmNotifier {
        let (live, _) = broadcast::channel(ALARM_BUFFER);
        let client = reqwest::Client::builder()
            .timeout(Duration::from_secs_f64(webhooks.timeout_s))
            .build()
            .inspect_err(|e| tracing::error!(error = %e, "no HTTP client: webhooks are off"))
            .ok();
        let spawn = |url: &Option<String>, severity: &'static str| {
            let (url, client) = (url.clone()?, client.clone()?);
            let wake = Arc::new(tokio::sync::Notify::new());
            tokio::spawn(deliver(
                client,
                url,
                webhooks.clone(),
                store.clone(),
                severity,
                wake.clone(),
            ));
            Some(wake)
        };
        AlarmNotifier {
            warn: spawn(&webhooks.warn, "warn"),
            alarm: spawn(&webhooks.alarm, "alarm"),
            live,
            own: broadcast::channel(ALARM_BUFFER).0,
        }
    }

    /// Changes from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Arc<AlarmChange>> {
        self.live.subscribe()
    }

    /// The changes this node made, for what only one node may publish (the
    /// MQTT alarm topics).
    pub fn subscribe_own(&self) -> broadcast::Receiver<Arc<AlarmChange>> {
        self.own.subscribe()
    }
}

impl AlarmNotifier {
    /// An alarm change another node made (and posts the webhooks of): to
    /// this node's live sockets only.
    pub fn relay(&self, change: AlarmChange) {
        let _ = self.live.send(Arc::new(change));
    }
}

impl AlarmSink for AlarmNotifier {
    /// Publishes stored changes, in order.
    fn publish(&self, changes: Vec<AlarmChange>) {
        for change in changes {
            log_change(&change);
            let change = Arc::new(change);
            let webhook = match change.alarm.severity.as_str() {
                "alarm" => &self.alarm,
                _ => &self.warn,
            };
            if let Some(wake) = webhook {
                wake.notify_one();
            }
            // No live client is fine.
            let _ = self.own.send(change.clone());
            let _ = self.live.send(change);
        }
    }
}

/// One line on the console per alarm change: a raise at WARN, a clear or
/// an acknowledgement at INFO.
fn log_change(change: &AlarmChange) {
    let a = &change.alarm;
    match change.transition {
        Change::Raised => tracing::warn!(
            machine = %a.machine, kind = %a.kind, severity = %a.severity, id = a.id,
            "alarm raised: {}", a.message
        ),
        Change::Cleared => tracing::info!(
            machine = %a.machine, kind = %a.kind, severity = %a.severity, id = a.id,
            "alarm cleared: {}", a.message
        ),
        Change::Acknowledged => tracing::info!(
            machine = %a.machine, kind = %a.kind, severity = %a.severity, id = a.id,
            by = a.acked_by.as_deref().unwrap_or(""),
            "alarm acknowledged"
        ),
    }
}

/// Posts what the outbox owes the webhook of `severity`, oldest first,
/// deleting each once answered or given up; waits for `wake` (or a
/// second) when nothing is owed.
async fn deliver(
    client: reqwest::Client,
    url: String,
    config: WebhookConfig,
    store: crate::store::Store,
    severity: &'static str,
    wake: Arc<tokio::sync::Notify>,
) {
    use crate::store::StoreError;
    loop {
        let reader = store.clone();
        let owed = tokio::task::spawn_blocking(move || reader.webhook_pending(severity, 100)).await;
        let owed = match owed {
            Ok(Ok(owed)) => owed,
            Ok(Err(StoreError::Closed)) | Err(_) => return,
            Ok(Err(e)) => {
                tracing::error!(%url, error = %e, "webhook outbox not readable; trying again");
                tokio::time::sleep(Duration::from_secs(5)).await;
                continue;
            }
        };
        if owed.is_empty() {
            let _ = tokio::time::timeout(Duration::from_secs(1), wake.notified()).await;
            continue;
        }
        for entry in owed {
            post(&client, &url, &config, &entry.change).await;
            match store.webhook_done(entry.id).await {
                Ok(()) => {}
                Err(StoreError::Closed) => return,
                Err(e) => {
                    tracing::warn!(%url, error = %e, "posted webhook change not deleted: it will be posted again, with the same key");
                }
            }
        }
    }
}

/// Posts one change to `url`: until a 2xx answer or
/// `config.attempts` attempts, waiting [`WebhookConfig::backoff`] between
/// them; a 4xx other than 408/429 is not retried (the receiver refuses
/// it). Each body carries `Idempotency-Key: alarm-{id}-{transition}`, so a
/// receiver can drop the copy an answer lost on the way back would cause.
async fn post(client: &reqwest::Client, url: &str, config: &WebhookConfig, change: &AlarmChange) {
    let body = match serde_json::to_vec(change) {
        Ok(body) => body,
        Err(e) => {
            tracing::error!(error = %e, "alarm change not serialisable");
            return;
        }
    };
    let key = format!(
        "alarm-{}-{}",
        change.alarm.id,
        serde_json::to_value(change.transition)
            .ok()
            .and_then(|v| v.as_str().map(str::to_owned))
            .unwrap_or_default()
    );
    for attempt in 1..=config.attempts {
        let sent = client
            .post(url)
            .header(reqwest::header::CONTENT_TYPE, "application/json")
            .header("Idempotency-Key", &key)
            .body(body.clone())
            .send()
            .await;
        let (retry, why) = match sent {
            Ok(answer) if answer.status().is_success() => {
                tracing::info!(%url, key, attempt, "alarm webhook delivered");
                break;
            }
            Ok(answer) => {
                let status = answer.status();
                let retry = status.is_server_error()
                    || status == reqwest::StatusCode::REQUEST_TIMEOUT
                    || status == reqwest::StatusCode::TOO_MANY_REQUESTS;
                (retry, format!("answered {status}"))
            }
            Err(e) => (true, e.to_string()),
        };
        if !retry || attempt == config.attempts {
            tracing::error!(%url, key, attempt, reason = %why, "alarm webhook given up");
            break;
        }
        let wait = config.backoff(attempt);
        tracing::warn!(%url, key, attempt, reason = %why, retry_in_s = wait.as_secs_f64(), "alarm webhook failed; retrying");
        tokio::time::sleep(wait).await;
    }
}
