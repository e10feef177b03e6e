//! Where a request for a machine goes: this node, another live node, or
//! nowhere right now (the view of the others, refreshed every second and
//! when a request names what it has not seen).

use std::time::{Duration, Instant};

use super::{Cluster, LEASE_TTL_S, Route};

impl Cluster {
    /// Reads placements and nodes again.
    pub(super) async fn refresh(&self) -> Result<(), crate::store::StoreError> {
        let placements = self.store.placements().await?;
        let nodes = self.store.nodes(LEASE_TTL_S).await?;
        if let Ok(mut view) = self.view.write() {
            view.placements = placements
                .into_iter()
                .map(|p| (p.machine.clone(), p))
                .collect();
            view.nodes = nodes.into_iter().map(|n| (n.node.clone(), n)).collect();
            view.refreshed = Some(Instant::now());
        }
        Ok(())
    }

    /// Refreshes unless the view is younger than 200 ms (a flood of
    /// unknown names does not become a flood of queries).
    pub(super) async fn refresh_if_stale(&self) {
        let fresh = self
            .view
            .read()
            .ok()
            .and_then(|v| v.refreshed)
            .is_some_and(|at| at.elapsed() < Duration::from_millis(200));
        if !fresh && let Err(e) = self.refresh().await {
            tracing::warn!(error = %e, "cannot read the cluster's placements");
        }
    }

    pub(super) fn lookup(&self, machine: &str) -> Option<Route> {
        let view = self.view.read().ok()?;
        let placement = view.placements.get(machine)?;
        Some(match &placement.holder {
            Some((node, true)) if *node != self.node => match view.nodes.get(node) {
                Some(row) if row.live => Route::Forward(row.url.clone()),
                _ => Route::Moving,
            },
            _ => Route::Moving,
        })
    }

    /// Where a request for `machine` (not running here) goes.
    pub async fn route(&self, machine: &str) -> Route {
        if let Some(route) = self.lookup(machine) {
            return route;
        }
        self.refresh_if_stale().await;
        self.lookup(machine).unwrap_or(Route::Unknown)
    }

    /// Whether `machine` is declared (anywhere).
    pub async fn knows(&self, machine: &str) -> bool {
        !matches!(self.route(machine).await, Route::Unknown)
    }

    /// Whether `machine` was declared when the view was last read.
    pub fn knows_cached(&self, machine: &str) -> bool {
        self.view
            .read()
            .is_ok_and(|v| v.placements.contains_key(machine))
    }
}
