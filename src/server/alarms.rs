//! `GET /api/v1/alarms` and `POST /api/v1/alarms/{id}/ack`: the alarms the
//! machines' rules raised (`crate::fusion::alarms`), as stored, and their
//! acknowledgement, recorded with the acknowledging token's name.

use axum::Json;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Extension, Path, Query, State};
use serde::{Deserialize, Serialize};

use super::SharedState;
use super::auth::Caller;
use super::error::ApiError;
use crate::store::alarms::{AlarmFilter, StoredAlarm};

/// Who acknowledged, while access is open (no tokens exist).
const ANONYMOUS: &str = "anonymous";

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AlarmsQuery {
    machine: Option<String>,
    /// `active` (default: not cleared) or `all`.
    state: Option<String>,
}

/// What `GET /api/v1/alarms` answers, newest first.
#[derive(Debug, Serialize)]
pub struct AlarmList {
    pub alarms: Vec<StoredAlarm>,
}

/// `GET /api/v1/alarms?machine=&state=active|all`.
pub async fn list(
    State(state): State<SharedState>,
    query: Result<Query<AlarmsQuery>, QueryRejection>,
) -> Result<Json<AlarmList>, ApiError> {
    let Query(query) =
        query.map_err(|e| ApiError::BadRequest(format!("bad query string: {}", e.body_text())))?;
    let active_only = match query.state.as_deref() {
        None | Some("active") => true,
        Some("all") => false,
        Some(other) => {
            return Err(ApiError::BadRequest(format!(
                "state `{other}` is not `active` or `all`"
            )));
        }
    };
    if let Some(machine) = &query.machine {
        state.machine(machine)?;
    }
    let filter = AlarmFilter {
        machine: query.machine,
        active_only,
    };
    Ok(Json(AlarmList {
        alarms: stored(&state, filter).await?,
    }))
}

/// The stored alarms `filter` asks for, newest first.
pub async fn stored(
    state: &SharedState,
    filter: AlarmFilter,
) -> Result<Vec<StoredAlarm>, ApiError> {
    let store = state.store.clone();
    Ok(tokio::task::spawn_blocking(move || store.alarms(&filter))
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))??)
}

/// `POST /api/v1/alarms/{id}/ack`: the alarm as acknowledged (the first
/// acknowledgement stands, and only it is announced to live clients and
/// webhooks); 404 for an unknown id.
pub async fn ack(
    State(state): State<SharedState>,
    Path(id): Path<String>,
    caller: Option<Extension<Caller>>,
) -> Result<Json<StoredAlarm>, ApiError> {
    let id: i64 = id
        .parse()
        .map_err(|_| ApiError::BadRequest(format!("alarm id `{id}` is not a number")))?;
    let by = caller
        .and_then(|Extension(Caller(name))| name)
        .unwrap_or_else(|| ANONYMOUS.to_string());
    let notifier = state.alarms.clone();
    let (alarm, _) = state
        .store
        .ack_alarm(id, by, state.clock.now_s(), move |change| {
            notifier.publish(vec![change])
        })
        .await?
        .ok_or_else(|| ApiError::NotFound(format!("there is no alarm {id}")))?;
    Ok(Json(alarm))
}
