//! The leases: renewed every second, the machines whose lease this node
//! lost stopped, those it holds started, free or lapsed ones taken up to
//! its share and those above it handed back.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use super::{Cluster, LEASE_TTL_S, SELF_FENCE, START_RETRY, TICK};
use crate::server::error::ApiError;
use crate::server::state::SharedState;

/// Joins the work: renews once, takes this node's share and starts it,
/// then keeps renewing (every second, on its own) and rebalancing (every
/// second) until the node leaves.
pub async fn start(
    state: &SharedState,
    cluster: Arc<Cluster>,
) -> Result<[tokio::task::JoinHandle<()>; 2], ApiError> {
    renew(&cluster).await?;
    balance(state, &cluster).await?;
    Ok([
        tokio::spawn(keep_renewing(state.clone(), cluster.clone())),
        tokio::spawn(keep_balancing(state.clone(), cluster)),
    ])
}

/// Renews this node's leases; the ones it holds are known afterwards
/// (with those taken while the renewal ran).
async fn renew(cluster: &Cluster) -> Result<(), ApiError> {
    let began = Instant::now();
    let renewed = cluster
        .membership
        .lock()
        .await
        .heartbeat(LEASE_TTL_S)
        .await?;
    if let Ok(mut held) = cluster.held.lock() {
        let taken_since: Vec<(i64, (i64, Instant))> = held
            .iter()
            .filter(|(_, (_, at))| *at > began)
            .map(|(&id, &lease)| (id, lease))
            .collect();
        *held = renewed
            .into_iter()
            .map(|(id, epoch)| (id, (epoch, began)))
            .collect();
        held.extend(taken_since);
    }
    if let Ok(mut at) = cluster.renewed.lock() {
        *at = began;
    }
    Ok(())
}

/// Renews every second until the node leaves; a node that could not for
/// [`SELF_FENCE`] stops its machines (their leases are about to lapse).
async fn keep_renewing(state: SharedState, cluster: Arc<Cluster>) {
    let mut tick = tokio::time::interval(TICK);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    while !cluster.left.load(std::sync::atomic::Ordering::SeqCst) {
        tick.tick().await;
        let renewal = tokio::time::timeout(TICK * 2, renew(&cluster)).await;
        let failed = match renewal {
            Ok(Ok(())) => continue,
            Ok(Err(e)) => e.to_string(),
            Err(_) => "no answer within 2 s".to_string(),
        };
        tracing::warn!(error = %failed, "cannot renew this node's leases");
        let since = cluster
            .renewed
            .lock()
            .map(|at| at.elapsed())
            .unwrap_or_default();
        // Alone, nobody can take the machines: they run on, their writes
        // refused until the leases are taken back (each commit checks).
        let others = cluster.view.read().is_ok_and(|view| {
            view.nodes
                .values()
                .any(|n| n.live && n.node != cluster.node)
        });
        if since >= SELF_FENCE && others && !cluster.left.load(std::sync::atomic::Ordering::SeqCst)
        {
            if let Ok(mut held) = cluster.held.lock() {
                held.clear();
            }
            for machine in state.all_machines() {
                tracing::warn!(machine = %machine.spec.id, "stopping: this node's lease is lapsing");
                state.stop_machine(&machine.spec.id).await;
            }
        }
    }
}

/// Rebalances every second until the server stops.
async fn keep_balancing(state: SharedState, cluster: Arc<Cluster>) {
    let mut tick = tokio::time::interval(TICK);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut shutdown = state.shutdown_signal();
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = shutdown.wait_for(|stopping| *stopping) => return,
        }
        if let Err(e) = balance(&state, &cluster).await {
            tracing::warn!(error = %e, "cannot rebalance the machines");
        }
    }
}

/// One round: stop what this node no longer holds (or holds under a newer
/// epoch: taken anew after a lapse), start what it holds, take free or
/// lapsed leases up to its share, or hand one back above it.
async fn balance(state: &SharedState, cluster: &Cluster) -> Result<(), ApiError> {
    if *state.shutdown_signal().borrow() {
        return Ok(());
    }
    cluster.refresh().await?;
    let held: BTreeMap<i64, i64> = cluster
        .held
        .lock()
        .map(|held| held.iter().map(|(&id, &(epoch, _))| (id, epoch)).collect())
        .unwrap_or_default();
    let mut held = held;
    // A running machine whose lease lapsed (the database away, a slow
    // renewal) is taken back; if no node held it meanwhile (the epoch is
    // exactly one more) it runs on.
    let running = state.all_machines();
    let lapsed: Vec<i64> = running
        .iter()
        .filter(|m| !held.contains_key(&m.db_id))
        .map(|m| m.db_id)
        .collect();
    for (id, epoch) in take(cluster, &lapsed).await? {
        if let Some(machine) = running.iter().find(|m| m.db_id == id)
            && machine.lease_epoch.get() == Some(epoch - 1)
        {
            tracing::info!(machine = %machine.spec.id, epoch, "lapsed lease taken back");
            machine.lease_epoch.set(epoch);
        }
        held.insert(id, epoch);
    }
    for machine in running {
        if held.get(&machine.db_id).copied() != machine.lease_epoch.get() {
            tracing::warn!(machine = %machine.spec.id, "no longer held under its lease: stopping");
            state.stop_machine(&machine.spec.id).await;
        }
    }
    for (&id, &epoch) in &held {
        run(state, id, epoch).await;
    }
    let (free, live_nodes, declared) = {
        let view = cluster
            .view
            .read()
            .map_err(|_| ApiError::Internal("cluster view poisoned".into()))?;
        let mut free: Vec<i64> = view
            .placements
            .values()
            .filter(|p| !matches!(p.holder, Some((_, true))) && !held.contains_key(&p.machine_id))
            .map(|p| p.machine_id)
            .collect();
        free.sort_unstable();
        let live = view.nodes.values().filter(|n| n.live).count().max(1);
        (free, live, view.placements.len())
    };
    let share = declared.div_ceil(live_nodes);
    if held.len() < share {
        let wanted: Vec<i64> = free.into_iter().take(share - held.len()).collect();
        for (id, epoch) in take(cluster, &wanted).await? {
            tracing::info!(machine_id = id, epoch, node = %cluster.node, "machine taken over");
            run(state, id, epoch).await;
        }
    } else if held.len() > share && live_nodes > 1 {
        // The newest machine goes: one a round, so the others settle.
        if let Some(machine) = state.all_machines().into_iter().max_by_key(|m| m.db_id) {
            tracing::info!(machine = %machine.spec.id, "handing a machine to another node");
            state.stop_machine(&machine.spec.id).await;
            cluster
                .membership
                .lock()
                .await
                .release(machine.db_id)
                .await?;
            if let Ok(mut held) = cluster.held.lock() {
                held.remove(&machine.db_id);
            }
        }
    }
    Ok(())
}

/// Takes the leases of `machine_ids` that are free; those taken, with
/// their epochs, known as held at once.
async fn take(cluster: &Cluster, machine_ids: &[i64]) -> Result<Vec<(i64, i64)>, ApiError> {
    let taken = cluster
        .membership
        .lock()
        .await
        .acquire(machine_ids, LEASE_TTL_S)
        .await?;
    if let Ok(mut held) = cluster.held.lock() {
        let now = Instant::now();
        for &(id, epoch) in &taken {
            held.insert(id, (epoch, now));
        }
    }
    Ok(taken)
}

/// Runs held machine `id` here under lease `epoch`; one that cannot be
/// restored is logged and left (its requests answered 503) while the
/// others run.
async fn run(state: &SharedState, id: i64, epoch: i64) {
    let Some(cluster) = &state.cluster else {
        return;
    };
    let failed_lately = cluster
        .failed
        .lock()
        .ok()
        .and_then(|failed| failed.get(&id).copied())
        .is_some_and(|at| at.elapsed() < START_RETRY);
    if failed_lately {
        return;
    }
    match state.start_machine(id, Some(epoch)).await {
        Ok(()) => {
            if let Ok(mut failed) = cluster.failed.lock() {
                failed.remove(&id);
            }
        }
        Err(e) => {
            tracing::error!(machine_id = id, error = %e, "cannot start a machine this node holds; trying again in 10 s");
            if let Ok(mut failed) = cluster.failed.lock() {
                failed.insert(id, Instant::now());
            }
        }
    }
}

/// Takes the lease of a machine just declared here; its epoch, or `None`
/// if another node took it first.
pub async fn claim(cluster: &Cluster, machine_id: i64) -> Result<Option<i64>, ApiError> {
    let taken = take(cluster, &[machine_id]).await?;
    cluster.refresh_if_stale().await;
    let epoch = taken
        .into_iter()
        .find(|&(id, _)| id == machine_id)
        .map(|(_, epoch)| epoch)
        // This node's rebalancing took it a moment before.
        .or_else(|| {
            cluster
                .held
                .lock()
                .ok()
                .and_then(|held| held.get(&machine_id).map(|&(epoch, _)| epoch))
        });
    Ok(epoch)
}
