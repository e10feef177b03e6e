//! Retention as a service: a pass of the policy now and every
//! `every_s`, until the server stops.

use tokio::sync::watch;

use crate::clock::Clock;
use crate::store::Store;
use crate::store::retention::{Pruned, Retention};

/// Applies the retention policy now and every `every_s`: each pass is
/// planned on a read connection and done step by step on the store's
/// writer between its commits (see `store::retention`).
/// Ends when `stopping` turns true (a pass under way is ended by
/// `AppState::stop` if it does not finish in time).
pub async fn keep(
    store: Store,
    policy: Retention,
    clock: Clock,
    mut stopping: watch::Receiver<bool>,
) {
    let every = std::time::Duration::from_secs_f64(policy.every_s.max(1.0));
    let mut tick = tokio::time::interval(every);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = stopping.wait_for(|stopping| *stopping) => return,
        }
        let now_t = clock.now_s();
        let pass = async {
            let planner = store.clone();
            let steps =
                tokio::task::spawn_blocking(move || planner.retention_plan(now_t, &policy, 5000))
                    .await
                    .map_err(|e| {
                        crate::store::StoreError::Corrupt(format!("retention plan: {e}"))
                    })??;
            let mut pruned = Pruned::default();
            for step in steps {
                loop {
                    let done = store.retention_step(step).await?;
                    pruned.add(done);
                    if !step.again(&done) {
                        break;
                    }
                }
            }
            Ok::<_, crate::store::StoreError>(pruned)
        };
        match pass.await {
            Ok(pruned) => tracing::info!(
                readings = pruned.readings,
                estimates = pruned.estimates,
                "retention pass"
            ),
            Err(e) => tracing::warn!(error = %e, "retention pass failed; next time again"),
        }
    }
}
