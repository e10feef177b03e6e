//! What tunnelnav publishes to the broker: each machine's estimates (QoS 0,
//! the newest of each stream every `[mqtt] estimates_hz`-th of a second, by
//! default 10 a second at most per stream, whatever the engine's rate), its
//! status (QoS 1, retained, every 5 s) and its alarms (QoS 1, retained
//! while raised).

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::time::Duration;

use rumqttc::{AsyncClient, QoS};
use tokio::sync::broadcast::error::RecvError;
use tokio::task::JoinHandle;

use super::Connected;
use crate::fusion::StreamKind;
use crate::machine::{LiveEstimate, MachineHandle};
use crate::server::state::SharedState;
use crate::store::alarms::{AlarmChange, AlarmFilter, Change};

/// How often each machine's status is published.
pub const STATUS_EVERY: Duration = Duration::from_secs(5);

/// Publishes every machine's estimates and status while the server runs;
/// a machine declared (or redeclared) later is picked up within a second.
pub async fn machines(
    state: SharedState,
    client: AsyncClient,
    connected: Connected,
    estimates_every: Duration,
) {
    let mut shutdown = state.shutdown_signal();
    let mut running: HashMap<String, (Arc<MachineHandle>, JoinHandle<()>)> = HashMap::new();
    let mut look = tokio::time::interval(Duration::from_secs(1));
    loop {
        tokio::select! {
            _ = look.tick() => {}
            _ = shutdown.changed() => break,
        }
        let machines = state.all_machines();
        // A machine stopped here (handed to another node): its task goes.
        running.retain(|id, (_, task)| {
            let here = machines.iter().any(|m| m.spec.id == *id);
            if !here {
                task.abort();
            }
            here
        });
        for machine in machines {
            let current = running
                .get(&machine.spec.id)
                .is_some_and(|(handle, task)| Arc::ptr_eq(handle, &machine) && !task.is_finished());
            if !current {
                let task = tokio::spawn(machine_task(
                    state.clone(),
                    client.clone(),
                    connected.clone(),
                    machine.clone(),
                    estimates_every,
                ));
                if let Some((_, old)) = running.insert(machine.spec.id.clone(), (machine, task)) {
                    old.abort();
                }
            }
        }
    }
    for (_, (_, task)) in running {
        task.abort();
    }
}

/// One machine's estimates and status, until it stops or is redeclared.
async fn machine_task(
    state: SharedState,
    client: AsyncClient,
    connected: Connected,
    machine: Arc<MachineHandle>,
    estimates_every: Duration,
) {
    let id = machine.spec.id.clone();
    let mut live = machine.subscribe();
    // What it made before this task began (at start, or while it was being
    // picked up) is published first: the newest of each stream.
    let mut pending: BTreeMap<StreamKind, LiveEstimate> = machine.status().latest.clone();
    let mut estimates = tokio::time::interval(estimates_every);
    let mut status = tokio::time::interval(STATUS_EVERY);
    loop {
        tokio::select! {
            received = live.recv() => match received {
                Ok(estimate) => {
                    pending.insert(estimate.engine, estimate);
                }
                // Only the newest of each stream is published anyway.
                Err(RecvError::Lagged(_)) => {}
                Err(RecvError::Closed) => break,
            },
            // While the broker is away the newest of each stream waits
            // here (QoS 0: not queued in the client, where it would go
            // stale), and goes when it is back.
            _ = estimates.tick() => {
                if !connected.now() {
                    continue;
                }
                for (stream, estimate) in std::mem::take(&mut pending) {
                    let topic = format!("tunnelnav/v1/{id}/estimates/{stream}");
                    let _ = client.try_publish(
                        topic,
                        QoS::AtMostOnce,
                        false,
                        estimate.json.as_bytes().to_vec(),
                    );
                }
            }
            _ = status.tick() => {
                if !connected.now() {
                    continue;
                }
                let now = state.clock.now_s();
                if let Ok(body) = serde_json::to_vec(&crate::server::machines::status(&machine, now)) {
                    let topic = format!("tunnelnav/v1/{id}/status");
                    let _ = client.try_publish(topic, QoS::AtLeastOnce, true, body);
                }
            }
        }
    }
}

/// The topic of one alarm.
fn alarm_topic(machine: &str, id: i64) -> String {
    format!("tunnelnav/v1/{machine}/alarms/{id}")
}

/// Publishes every alarm change: a raised or acknowledged alarm retained
/// at `tunnelnav/v1/{machine}/alarms/{id}`; a clear published there, then
/// the retained message removed (an empty retained one). At start, and if
/// changes were missed, every active alarm is published again.
pub async fn alarms(state: SharedState, client: AsyncClient) {
    let mut shutdown = state.shutdown_signal();
    let mut changes = state.alarms.subscribe_own();
    republish_active(&state, &client).await;
    loop {
        let change = tokio::select! {
            change = changes.recv() => change,
            _ = shutdown.changed() => break,
        };
        match change {
            Ok(change) => publish_change(&client, &change).await,
            Err(RecvError::Lagged(_)) => republish_active(&state, &client).await,
            Err(RecvError::Closed) => break,
        }
    }
}

async fn publish_change(client: &AsyncClient, change: &AlarmChange) {
    let topic = alarm_topic(&change.alarm.machine, change.alarm.id);
    let Ok(body) = serde_json::to_vec(change) else {
        return;
    };
    let retained = change.transition != Change::Cleared;
    let _ = client
        .publish(topic.as_str(), QoS::AtLeastOnce, retained, body)
        .await;
    if !retained {
        let _ = client
            .publish(topic.as_str(), QoS::AtLeastOnce, true, Vec::new())
            .await;
    }
}

async fn republish_active(state: &SharedState, client: &AsyncClient) {
    let filter = AlarmFilter {
        machine: None,
        active_only: true,
        ..Default::default()
    };
    let Ok(active) = crate::server::alarms::stored(state, filter).await else {
        return;
    };
    for alarm in active {
        let transition = if alarm.acked_t.is_some() {
            Change::Acknowledged
        } else {
            Change::Raised
        };
        publish_change(client, &AlarmChange { transition, alarm }).await;
    }
}
