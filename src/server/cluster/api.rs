//! `GET /api/v1/cluster`.

use axum::extract::State;

use super::ClusterReport;
use crate::server::error::ApiError;
use crate::server::state::SharedState;

/// The server nodes and their machines.
///
/// `GET /api/v1/cluster`.
#[utoipa::path(get, path = "/api/v1/cluster", operation_id = "cluster", tag = "machines",
    responses((status = OK, description = "The nodes on this store, live or not, with the machines each fuses, and the machines changing hands (one server on SQLite: no nodes)", body = ClusterReport)))]
pub async fn show(State(state): State<SharedState>) -> Result<axum::Json<ClusterReport>, ApiError> {
    match &state.cluster {
        Some(cluster) => Ok(axum::Json(cluster.report().await?)),
        None => Ok(axum::Json(ClusterReport {
            node: None,
            nodes: Vec::new(),
            unplaced: Vec::new(),
        })),
    }
}
