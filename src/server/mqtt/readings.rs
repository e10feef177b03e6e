//! Readings in: one task per machine takes its messages in order, stores
//! and fuses them as `POST .../readings` would (retrying refusals), then
//! publishes the answer and acknowledges the message to the broker.

use std::time::Duration;

use rumqttc::{AsyncClient, Publish, QoS};
use tokio::sync::{mpsc, watch};

use super::super::SharedState;
use super::super::error::ApiError;
use super::super::ingest::{Ack, BatchRules, ingest, parse_batch};
use super::super::metrics;

/// The longest wait before retrying a refused message.
const MAX_RETRY_WAIT: Duration = Duration::from_secs(5);

/// The machine of a readings topic.
pub(super) fn machine_of(topic: &str) -> Option<&str> {
    let mut parts = topic.split('/');
    match (
        parts.next(),
        parts.next(),
        parts.next(),
        parts.next(),
        parts.next(),
    ) {
        (Some("tunnelnav"), Some("v1"), Some(machine), Some("readings"), None) => Some(machine),
        _ => None,
    }
}

/// Handles one machine's messages in order: ingest (retrying refusals),
/// publish the answer, then acknowledge to the broker.
pub(super) async fn serve_machine(
    state: SharedState,
    client: AsyncClient,
    machine: String,
    mut inbox: mpsc::Receiver<Publish>,
) {
    let shutdown = state.shutdown_signal();
    let acks = format!("tunnelnav/v1/{machine}/acks");
    while let Some(publish) = inbox.recv().await {
        let mut wait = Duration::from_millis(50);
        let answer = loop {
            match ingest_message(&state, &machine, &publish.payload).await {
                Err(ApiError::Unavailable { .. }) if !stopping(&shutdown) => {
                    metrics::mqtt_message("refused");
                    tokio::time::sleep(wait).await;
                    wait = (wait * 2).min(MAX_RETRY_WAIT);
                }
                // Not acknowledged: the broker delivers it after the restart.
                Err(ApiError::Unavailable { .. }) => return,
                answer => break answer,
            }
        };
        let body = match &answer {
            Ok(ack) => serde_json::to_vec(ack),
            Err(e) => {
                let mut body = e.body();
                body.status = Some(e.status().as_u16());
                serde_json::to_vec(&body)
            }
        };
        if let Ok(body) = body
            && let Err(e) = client
                .publish(acks.as_str(), QoS::AtLeastOnce, false, body)
                .await
        {
            tracing::warn!(%machine, error = %e, "MQTT: cannot publish the ack");
        }
        if let Err(e) = client.ack(&publish).await {
            tracing::warn!(%machine, error = %e, "MQTT: cannot acknowledge");
            return;
        }
        metrics::mqtt_message(if answer.is_ok() {
            "acknowledged"
        } else {
            "rejected"
        });
    }
}

fn stopping(shutdown: &watch::Receiver<bool>) -> bool {
    *shutdown.borrow()
}

/// A message's readings, stored and fused as `POST .../readings` would.
/// With no content type in MQTT 3.1.1, a body that is not one JSON value is
/// read as NDJSON.
async fn ingest_message(state: &SharedState, machine: &str, body: &[u8]) -> Result<Ack, ApiError> {
    state.machine(machine)?;
    let rules = BatchRules::now(&state.limits, &state.clock);
    let batch = match parse_batch(body, false, &rules) {
        Err(ApiError::BadRequest(_)) if body.contains(&b'\n') => parse_batch(body, true, &rules),
        parsed => parsed,
    }?;
    ingest(state, machine, batch).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_readings_topics_name_a_machine() {
        assert_eq!(machine_of("tunnelnav/v1/tbm-1/readings"), Some("tbm-1"));
        assert_eq!(machine_of("tunnelnav/v1/tbm-1/acks"), None);
        assert_eq!(machine_of("tunnelnav/v1/tbm-1/readings/x"), None);
        assert_eq!(machine_of("other/v1/tbm-1/readings"), None);
    }
}
