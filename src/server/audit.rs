//! `GET /api/v1/audit`: the audit log, what an admin changed by hand
//! (a site's machine's mark set back), oldest first.

use axum::Json;
use axum::extract::State;
use serde::Serialize;

use super::error::ApiError;
use super::state::SharedState;
use crate::store::outbox::AuditEntry;

/// `GET /api/v1/audit`.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct AuditLog {
    pub entries: Vec<AuditEntry>,
}

/// The audit log.
///
/// `GET /api/v1/audit`: every change an admin made by hand, with the
/// token's name (`cli` from the command line), oldest first.
#[utoipa::path(get, path = "/api/v1/audit", operation_id = "get_audit", tag = "service",
    responses((status = OK, description = "The audit log, oldest first", body = AuditLog)))]
pub async fn list(State(state): State<SharedState>) -> Result<Json<AuditLog>, ApiError> {
    let store = state.store.clone();
    let entries = tokio::task::spawn_blocking(move || store.audit())
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))??;
    Ok(Json(AuditLog { entries }))
}
