//! Where a stored alarm change goes: live clients (the fleet-wide and the
//! machine sockets, through one broadcast channel) and the webhooks of the
//! server config, each URL served by its own task in order, with retries
//! and back-off. Changes reach the notifier only after their commit, once
//! each (a transition recomputed after a restart is not stored again, so
//! not notified again).

use std::sync::Arc;
use std::time::Duration;

use serde::Deserialize;
use tokio::sync::{broadcast, mpsc};

use crate::store::alarms::AlarmChange;

/// Alarm changes a live client may fall behind by before it is told to
/// fetch the list again.
pub const ALARM_BUFFER: usize = 1024;
/// Changes waiting for one webhook URL; beyond (a receiver down for long
/// while alarms keep changing), new changes are dropped and logged.
pub const WEBHOOK_QUEUE: usize = 1000;

/// Webhooks, one URL per severity (`[webhooks]` in the server config).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WebhookConfig {
    /// Receives the changes of `warn` alarms.
    pub warn: Option<String>,
    /// Receives the changes of `alarm` alarms.
    pub alarm: Option<String>,
    /// Attempts per change before it is given up (logged).
    #[serde(default = "default_attempts")]
    pub attempts: u32,
    /// Wait before the first retry; doubled after each failure.
    #[serde(default = "default_first_retry_s")]
    pub first_retry_s: f64,
    /// Longest wait between attempts.
    #[serde(default = "default_max_retry_s")]
    pub max_retry_s: f64,
    /// How long one attempt may take.
    #[serde(default = "default_timeout_s")]
    pub timeout_s: f64,
}

fn default_attempts() -> u32 {
    8
}
fn default_first_retry_s() -> f64 {
    1.0
}
fn default_max_retry_s() -> f64 {
    60.0
}
fn default_timeout_s() -> f64 {
    10.0
}

impl Default for WebhookConfig {
    fn default() -> Self {
        WebhookConfig {
            warn: None,
            alarm: None,
            attempts: default_attempts(),
            first_retry_s: default_first_retry_s(),
            max_retry_s: default_max_retry_s(),
            timeout_s: default_timeout_s(),
        }
    }
}

/// Why a webhook configuration is refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum WebhookError {
    #[error("webhooks.{severity}: `{url}` is not an http:// URL ({reason})")]
    Url {
        severity: &'static str,
        url: String,
        reason: String,
    },
    #[error("webhooks.{field} must be {rule}, not {value}")]
    Range {
        field: &'static str,
        rule: &'static str,
        value: f64,
    },
}

impl WebhookConfig {
    /// Checks the URLs (plain `http://`: this build has no TLS client; put
    /// a relay or the proxy in front for `https`) and the timings.
    pub fn validate(&self) -> Result<(), WebhookError> {
        for (severity, url) in [("warn", &self.warn), ("alarm", &self.alarm)] {
            let Some(url) = url else { continue };
            let parsed = reqwest::Url::parse(url).map_err(|e| WebhookError::Url {
                severity,
                url: url.clone(),
                reason: e.to_string(),
            })?;
            if parsed.scheme() != "http" || parsed.host_str().is_none() {
                return Err(WebhookError::Url {
                    severity,
                    url: url.clone(),
                    reason: "only http:// with a host is supported".into(),
                });
            }
        }
        if self.attempts == 0 || self.attempts > 100 {
            return Err(WebhookError::Range {
                field: "attempts",
                rule: "1 to 100",
                value: f64::from(self.attempts),
            });
        }
        for (field, value) in [
            ("first_retry_s", self.first_retry_s),
            ("max_retry_s", self.max_retry_s),
            ("timeout_s", self.timeout_s),
        ] {
            if !(value.is_finite() && value > 0.0 && value <= 3600.0) {
                return Err(WebhookError::Range {
                    field,
                    rule: "above 0 and at most 3600 seconds",
                    value,
                });
            }
        }
        Ok(())
    }

    /// The wait after failed attempt `attempt` (1-based): doubling from
    /// `first_retry_s`, at most `max_retry_s`.
    pub fn backoff(&self, attempt: u32) -> Duration {
        let doubled = self.first_retry_s * 2f64.powi(attempt.saturating_sub(1).min(30) as i32);
        Duration::from_secs_f64(doubled.min(self.max_retry_s))
    }
}

/// Hands stored alarm changes to live clients and webhooks.
#[derive(Clone)]
pub struct AlarmNotifier {
    live: broadcast::Sender<Arc<AlarmChange>>,
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
        }
    }

    /// Publishes stored changes, in order.
    pub fn publish(&self, changes: Vec<AlarmChange>) {
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
            let _ = self.live.send(change);
        }
    }

    /// Changes from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Arc<AlarmChange>> {
        self.live.subscribe()
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn back_off_doubles_up_to_its_cap() {
        let config = WebhookConfig {
            first_retry_s: 0.5,
            max_retry_s: 3.0,
            ..WebhookConfig::default()
        };
        let waits: Vec<f64> = (1..=5).map(|a| config.backoff(a).as_secs_f64()).collect();
        assert_eq!(waits, [0.5, 1.0, 2.0, 3.0, 3.0]);
    }

    #[test]
    fn webhook_urls_and_timings_are_checked() {
        let ok = WebhookConfig {
            alarm: Some("http://127.0.0.1:9000/hook".into()),
            ..WebhookConfig::default()
        };
        assert_eq!(ok.validate(), Ok(()));
        let https = WebhookConfig {
            warn: Some("https://example.org/hook".into()),
            ..WebhookConfig::default()
        };
        assert!(matches!(
            https.validate(),
            Err(WebhookError::Url {
                severity: "warn",
                ..
            })
        ));
        let nonsense = WebhookConfig {
            alarm: Some("not a url".into()),
            ..WebhookConfig::default()
        };
        assert!(nonsense.validate().is_err());
        let zero = WebhookConfig {
            attempts: 0,
            ..WebhookConfig::default()
        };
        assert!(matches!(
            zero.validate(),
            Err(WebhookError::Range {
                field: "attempts",
                ..
            })
        ));
        let negative = WebhookConfig {
            timeout_s: -1.0,
            ..WebhookConfig::default()
        };
        assert!(negative.validate().is_err());
    }
}
