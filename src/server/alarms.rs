//! `GET /api/v1/alarms` and `POST /api/v1/alarms/{id}/ack`: the alarms the
//! machines' rules raised (`crate::fusion::alarms`), as stored, and their
//! acknowledgement, recorded with the acknowledging token's name.

use axum::Json;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Extension, Path, Query, State};
use serde::{Deserialize, Serialize};

use super::auth::Caller;
use super::error::ApiError;
use super::state::SharedState;
use crate::fusion::alarms::AlarmKind;
use crate::machine::AlarmSink;
use crate::store::alarms::{AlarmFilter, StoredAlarm};

#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct AlarmsQuery {
    /// Only this machine's alarms.
    #[param(pattern = r"^[A-Za-z0-9_-]{1,64}(\.[A-Za-z0-9_-]{1,64})?$")]
    machine: Option<String>,
    /// An office: only the alarms of this site's machines.
    #[param(pattern = r"^[A-Za-z0-9_-]{1,64}$")]
    site: Option<String>,
    /// `active` (default: not cleared) or `all`.
    #[param(inline, value_type = Option<AlarmsState>)]
    state: Option<String>,
}

/// Which alarms a list holds.
#[derive(utoipa::ToSchema)]
#[schema(rename_all = "lowercase")]
#[allow(
    dead_code,
    reason = "names the values of `state` in the document; parsed as text"
)]
enum AlarmsState {
    Active,
    All,
}

/// The path parameter naming an alarm.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Path)]
pub struct AlarmPath {
    /// The alarm's id, as listed.
    #[param(value_type = i64, example = 1)]
    id: String,
}

/// What `GET /api/v1/alarms` answers, newest first.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct AlarmList {
    pub alarms: Vec<StoredAlarm>,
}

/// The alarms, newest first.
///
/// `GET /api/v1/alarms?machine=&site=&state=active|all`.
#[utoipa::path(get, path = "/api/v1/alarms", operation_id = "list_alarms", tag = "alarms", params(AlarmsQuery),
    responses((status = OK, description = "The alarms, newest first", body = AlarmList),
        (status = NOT_FOUND, description = "`machine` names no machine", body = super::error::ErrorBody)))]
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
    if let Some(machine) = &query.machine
        && !state.knows(machine).await
    {
        return Err(ApiError::UnknownMachine(machine.clone()));
    }
    let filter = AlarmFilter {
        machine: query.machine,
        active_only,
        ..Default::default()
    };
    if let Some(site) = &query.site
        && !crate::config::valid_machine_id(site)
    {
        return Err(ApiError::BadRequest(format!(
            "site `{site}` is not a site name: 1 to 64 letters, digits, `-` or `_`"
        )));
    }
    let mut alarms = stored(&state, filter).await?;
    if let Some(site) = &query.site {
        alarms.retain(|a| crate::config::forwarded_site(&a.machine) == Some(site.as_str()));
    }
    Ok(Json(AlarmList { alarms }))
}

/// The stored alarms `filter` asks for, newest first; an active one of a
/// machine running here with what its quantity reads now.
pub async fn stored(
    state: &SharedState,
    filter: AlarmFilter,
) -> Result<Vec<StoredAlarm>, ApiError> {
    let store = state.store.clone();
    let mut alarms = tokio::task::spawn_blocking(move || store.alarms(&filter))
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))??;
    for alarm in alarms.iter_mut().filter(|a| a.cleared_t.is_none()) {
        let (Ok(machine), Some(kind)) = (
            state.machine(&alarm.machine),
            AlarmKind::from_name(&alarm.kind),
        ) else {
            continue;
        };
        let status = machine.status();
        alarm.now = status
            .alarm_now
            .get(&(kind, alarm.subject.clone()))
            .cloned();
    }
    Ok(alarms)
}

/// Acknowledge an alarm.
///
/// `POST /api/v1/alarms/{id}/ack`: the alarm as acknowledged (the first
/// acknowledgement stands, and only it is announced to live clients and
/// webhooks); 404 for an unknown id.
#[utoipa::path(post, path = "/api/v1/alarms/{id}/ack", operation_id = "ack_alarm", tag = "alarms", params(AlarmPath),
    responses((status = OK, description = "The alarm, acknowledged by the token's name (`anonymous` while access is open); the first acknowledgement stands", body = StoredAlarm),
        (status = NOT_FOUND, description = "No alarm has this id", body = super::error::ErrorBody)))]
pub async fn ack(
    State(state): State<SharedState>,
    Path(AlarmPath { id }): Path<AlarmPath>,
    caller: Option<Extension<Caller>>,
) -> Result<Json<StoredAlarm>, ApiError> {
    let id: i64 = id
        .parse()
        .map_err(|_| ApiError::BadRequest(format!("alarm id `{id}` is not a number")))?;
    let by = Caller::recorded(caller.as_ref().map(|Extension(caller)| caller));
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
