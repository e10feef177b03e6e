//! Where a stored alarm change goes: live clients (the fleet-wide and the
//! machine sockets, through one broadcast channel) and the webhooks of the
//! server config, each URL served by its own task in order, with retries
//! and back-off. Changes reach the notifier only after their commit, once
//! each (a transition recomputed after a restart is not stored again, so
//! not notified again).

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{broadcast, mpsc};

use super::settings::WebhookConfig;
use crate::machine::AlarmSink;
use crate::store::alarms::AlarmChange;

/// Alarm changes a live client may fall behind by before it is told to
/// fetch the list again.
pub const ALARM_BUFFER: usize = 1024;
/// Changes waiting for one webhook URL; beyond (a receiver down for long
/// while alarms keep changing), new changes are dropped and logged.
pub const WEBHOOK_QUEUE: usize = 1000;

/// Hands stored alarm changes to live clients and webhooks.
#[derive(Clone)]
pub struct AlarmNotifier {
    live: broadcast::Sender<Arc<AlarmChange>>,
    /// The changes this node made (not those relayed from other nodes).
    own: broadcast::Sender<Arc<AlarmChange>>,
    warn: Option<(String, mpsc::Sender<Arc<AlarmChange>>)>,
    alarm: Option<(String, mpsc::Sender<Arc<AlarmChange>>)>,
}

impl AlarmNotifier {
    /// A notifier; starts one delivery task per configured webhook URL
    /// (call within a tokio runtime).
    pub fn start(webhooks: &WebhookConfig) -> AlarmNotifier {
        let (live, _) = broadcast::channel(ALARM_BUFFER);
        let client = reqwest::Client::builder()
            .timeout(Duration::from_secs_f64(webhooks.timeout_s))
            .build()
            .inspect_err(|e| tracing::error!(error = %e, "no HTTP client: webhooks are off"))
            .ok();
        let spawn = |url: &Option<String>| {
            let (url, client) = (url.clone()?, client.clone()?);
            let (queue, changes) = mpsc::channel(WEBHOOK_QUEUE);
            tokio::spawn(deliver(client, url.clone(), webhooks.clone(), changes));
            Some((url, queue))
        };
        AlarmNotifier {
            warn: spawn(&webhooks.warn),
            alarm: spawn(&webhooks.alarm),
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
            let change = Arc::new(change);
            let webhook = match change.alarm.severity.as_str() {
                "alarm" => &self.alarm,
                _ => &self.warn,
            };
            if let Some((url, queue)) = webhook
                && queue.try_send(change.clone()).is_err()
            {
                tracing::error!(
                    %url, alarm = change.alarm.id, pending = WEBHOOK_QUEUE,
                    "webhook queue full (the receiver has not answered for long): change not posted"
                );
            }
            // No live client is fine.
            let _ = self.own.send(change.clone());
            let _ = self.live.send(change);
        }
    }
}

/// Posts each change to `url` in order: until a 2xx answer or
/// `config.attempts` attempts, waiting [`WebhookConfig::backoff`] between
/// them; a 4xx other than 408/429 is not retried (the receiver refuses
/// it). Each body carries `Idempotency-Key: alarm-{id}-{transition}`, so a
/// receiver can drop the copy an answer lost on the way back would cause.
async fn deliver(
    client: reqwest::Client,
    url: String,
    config: WebhookConfig,
    mut changes: mpsc::Receiver<Arc<AlarmChange>>,
) {
    while let Some(change) = changes.recv().await {
        let body = match serde_json::to_vec(&*change) {
            Ok(body) => body,
            Err(e) => {
                tracing::error!(error = %e, "alarm change not serialisable");
                continue;
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
                .post(&url)
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
}
