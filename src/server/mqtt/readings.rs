//! Readings in: one task per machine takes its messages in order, stores
//! and fuses them as `POST .../readings` would (retrying refusals), then
//! publishes the answer and acknowledges the message to the broker.

use std::collections::VecDeque;
use std::time::Duration;

use rumqttc::{AsyncClient, Publish, QoS};
use tokio::sync::{mpsc, watch};

use crate::server::error::ApiError;
use crate::server::ingest::{Ack, BatchRules, ingest, parse_batch};
use crate::server::metrics;
use crate::server::state::SharedState;

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

/// What a machine's task has handed, or has still to hand, to the client.
enum Outgoing {
    /// The answer, published to `tunnelnav/v1/{machine}/acks`.
    Answer(Vec<u8>),
    /// The PUBACK of a message whose readings are committed.
    Puback(Publish, &'static str),
}

/// Handles one machine's messages in order: ingest (retrying refusals),
/// publish the answer, then acknowledge to the broker.
///
/// The answer and the PUBACK are handed to the client without waiting:
/// the connection's loop may itself be waiting for room in this task's
/// inbox, and the client's request queue is drained only by that loop, so
/// a task that waited for the queue could wait for ever. What the queue
/// cannot take yet is kept, in order, and handed over as it drains.
pub(super) async fn serve_machine(
    state: SharedState,
    client: AsyncClient,
    machine: String,
    mut inbox: mpsc::Receiver<Publish>,
) {
    let shutdown = state.shutdown_signal();
    let acks = format!("tunnelnav/v1/{machine}/acks");
    let mut unsent: VecDeque<Outgoing> = VecDeque::new();
    loop {
        hand_over(&client, &acks, &mut unsent);
        let next = if unsent.is_empty() {
            inbox.recv().await
        } else {
            match tokio::time::timeout(HAND_OVER_RETRY, inbox.recv()).await {
                Ok(next) => next,
                Err(_elapsed) if stopping(&shutdown) => return,
                Err(_elapsed) => continue,
            }
        };
        let Some(publish) = next else { return };
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
        match body {
            Ok(body) => unsent.push_back(Outgoing::Answer(body)),
            Err(e) => tracing::warn!(%machine, error = %e, "MQTT: cannot write the ack"),
        }
        let outcome = if answer.is_ok() {
            "acknowledged"
        } else {
            "rejected"
        };
        unsent.push_back(Outgoing::Puback(publish, outcome));
    }
}

/// How long a task with something the client's queue could not take waits
/// for its next message before trying again.
const HAND_OVER_RETRY: Duration = Duration::from_millis(10);

/// Hands `unsent` to the client in order, as far as its queue takes it.
fn hand_over(client: &AsyncClient, acks: &str, unsent: &mut VecDeque<Outgoing>) {
    while let Some(next) = unsent.pop_front() {
        let handed = match &next {
            Outgoing::Answer(body) => {
                client.try_publish(acks, QoS::AtLeastOnce, false, body.clone())
            }
            Outgoing::Puback(publish, _) => client.try_ack(publish),
        };
        match handed {
            Ok(()) => {
                if let Outgoing::Puback(_, outcome) = next {
                    metrics::mqtt_message(outcome);
                }
            }
            Err(_full) => {
                unsent.push_front(next);
                return;
            }
        }
    }
}

fn stopping(shutdown: &watch::Receiver<bool>) -> bool {
    *shutdown.borrow()
}

/// A message's readings, stored and fused as `POST .../readings` would.
/// With no content type in MQTT 3.1.1, a body that is not one JSON value is
/// read as NDJSON.
/// A machine another node fuses goes on to it (`ingest`), so a message
/// is acknowledged only once some node stored it.
async fn ingest_message(state: &SharedState, machine: &str, body: &[u8]) -> Result<Ack, ApiError> {
    if !state.knows(machine).await {
        return Err(ApiError::UnknownMachine(machine.to_string()));
    }
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
