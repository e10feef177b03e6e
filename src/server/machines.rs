//! Machine configuration and status: `PUT`, `GET` one, `GET` all.

use axum::Json;
use axum::body::Bytes;
use axum::extract::rejection::{BytesRejection, QueryRejection};
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_json::value::RawValue;

use super::error::ApiError;
use super::openapi::MachinePath;
use super::state::SharedState;
use crate::config::{MachineDeclaration, valid_machine_id};
use crate::fusion::{EngineKind, SensorKind, StreamKind};
use crate::machine::{LiveEstimate, MachineHandle};

/// A sensor's last reading, as the status reports it.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct SensorReport {
    /// Time of the newest reading, Unix seconds.
    pub last_t: f64,
    /// Its age at the server clock's now.
    pub age_s: f64,
    /// Readings received since the server started.
    pub readings: u64,
}

/// The laser's state, from the newest estimate of an engine that reads
/// the laser (`attitude`).
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct LaserReport {
    pub ok: bool,
    /// Seconds since the newest laser sample at `t`; `null` before the first.
    pub age_s: Option<f64>,
    pub dropout: bool,
    /// Time of the estimate this report is from, Unix seconds.
    pub t: f64,
}

/// A machine's status: sensors' last readings and their age at `now`
/// (server clock), laser state, latest estimate of each engine and stage;
/// one machine's also its declaration and the clock.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct MachineStatusBody {
    pub machine: String,
    /// An office: the site the machine is forwarded from (`{site}.{machine}`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub site: Option<String>,
    pub name: String,
    pub engines: Vec<EngineKind>,
    /// The newest reading of any sensor; `null` before the first.
    pub last_reading_t: Option<f64>,
    pub sensors: BTreeMap<SensorKind, SensorReport>,
    /// `null` for a machine none of whose engines reads the laser, and
    /// before their first estimate.
    pub laser: Option<LaserReport>,
    /// Readings stored but too late to be fused, since the server started.
    pub late_readings: u64,
    pub live_clients: usize,
    /// The newest estimate of each stream, as the live stream sent it.
    #[schema(value_type = BTreeMap<StreamKind, super::openapi::Estimate>)]
    pub latest: BTreeMap<StreamKind, Box<RawValue>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub config: Option<MachineDeclaration>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub server_t: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clock_rate: Option<f64>,
}

/// `GET /api/v1/machines`: every machine's status and the clock.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct MachineList {
    pub machines: Vec<MachineStatusBody>,
    pub server_t: f64,
    /// Server seconds per wall second (above 1 in the demo).
    pub clock_rate: f64,
}

/// The answer to a declaration.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct Declared {
    pub machine: String,
    pub created: bool,
    pub changed: bool,
    pub config: MachineDeclaration,
}

/// The laser's state from the newest estimates of each stream: the first
/// (in registry order) that tells it, as the alarm rules watch it.
pub(crate) fn laser_report(latest: &BTreeMap<StreamKind, LiveEstimate>) -> Option<LaserReport> {
    latest.values().find_map(|e| {
        e.signals.laser.map(|laser| LaserReport {
            ok: laser.ok,
            age_s: laser.age_s,
            dropout: !laser.ok,
            t: e.t,
        })
    })
}

/// The status of `machine` at `now`.
pub(super) fn status(machine: &MachineHandle, now: f64) -> MachineStatusBody {
    status_of(
        &machine.spec,
        &machine.status(),
        machine.live_clients(),
        now,
    )
}

/// The status body of a machine declared as `spec` that looks like
/// `status`.
fn status_of(
    spec: &crate::config::MachineSpec,
    status: &crate::machine::MachineStatus,
    live_clients: usize,
    now: f64,
) -> MachineStatusBody {
    let sensors = status
        .sensors
        .iter()
        .map(|(&sensor, s)| {
            (
                sensor,
                SensorReport {
                    last_t: s.last_t,
                    age_s: now - s.last_t,
                    readings: s.readings,
                },
            )
        })
        .collect();
    let latest: BTreeMap<StreamKind, Box<RawValue>> = status
        .latest
        .iter()
        .filter_map(|(&stream, e)| Some((stream, RawValue::from_string(e.json.to_string()).ok()?)))
        .collect();
    let laser = laser_report(&status.latest);
    let last_reading_t = status
        .sensors
        .values()
        .map(|s| s.last_t)
        .fold(None, |acc: Option<f64>, t| {
            Some(acc.map_or(t, |a| a.max(t)))
        });
    MachineStatusBody {
        machine: spec.id.clone(),
        site: crate::config::forwarded_site(&spec.id).map(str::to_string),
        name: spec.name.clone(),
        engines: spec.engines.keys().copied().collect(),
        last_reading_t,
        sensors,
        laser,
        late_readings: status.late,
        live_clients,
        latest,
        config: None,
        server_t: None,
        clock_rate: None,
    }
}

/// The server clock's reading and rate (above 1 in the demo), so a page can
/// age what it shows between fetches.
fn clock(state: &SharedState) -> (f64, f64) {
    (state.clock.now_s(), state.clock.rate())
}

/// Which machines a list holds.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct MachinesQuery {
    /// An office: only this site's machines.
    #[param(pattern = r"^[A-Za-z0-9_-]{1,64}$")]
    site: Option<String>,
}

/// Every machine's status.
///
/// `GET /api/v1/machines?site=`.
#[utoipa::path(get, path = "/api/v1/machines", operation_id = "list_machines", tag = "machines", params(MachinesQuery),
    responses((status = OK, description = "Every machine's status (or one site's machines') and the server clock", body = MachineList)))]
pub async fn list(
    State(state): State<SharedState>,
    query: Result<Query<MachinesQuery>, QueryRejection>,
) -> Result<Json<MachineList>, ApiError> {
    let Query(query) =
        query.map_err(|e| ApiError::BadRequest(format!("bad query string: {}", e.body_text())))?;
    if let Some(site) = &query.site
        && !valid_machine_id(site)
    {
        return Err(ApiError::BadRequest(format!(
            "site `{site}` is not a site name: 1 to 64 letters, digits, `-` or `_`"
        )));
    }
    let (now, rate) = clock(&state);
    let mut machines: Vec<MachineStatusBody> = state
        .all_machines()
        .iter()
        .map(|m| status(m, now))
        .collect();
    // Machines other nodes fuse: as their newest stored estimates and
    // readings show them.
    let store = state.store.clone();
    let elsewhere = state.elsewhere().await?;
    let others = tokio::task::spawn_blocking(move || {
        elsewhere
            .into_iter()
            .map(|m| {
                let status = crate::machine::stored_status(&store, &m.spec, m.db_id)?;
                Ok(status_of(&m.spec, &status, 0, now))
            })
            .collect::<Result<Vec<_>, crate::machine::MachineError>>()
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))?
    .map_err(|e| ApiError::Internal(e.to_string()))?;
    machines.extend(others);
    if let Some(site) = &query.site {
        machines.retain(|m| m.site.as_ref() == Some(site));
    }
    machines.sort_by(|a, b| a.machine.cmp(&b.machine));
    Ok(Json(MachineList {
        machines,
        server_t: now,
        clock_rate: rate,
    }))
}

/// A machine's status and declaration.
///
/// `GET /api/v1/machines/{machine}`.
#[utoipa::path(get, path = "/api/v1/machines/{machine}", operation_id = "get_machine", tag = "machines", params(MachinePath),
    responses((status = OK, description = "The machine's status, its declaration and the server clock", body = MachineStatusBody)))]
pub async fn show(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
) -> Result<Json<MachineStatusBody>, ApiError> {
    let machine = state.machine(&machine)?;
    let (now, rate) = clock(&state);
    Ok(Json(MachineStatusBody {
        config: Some(machine.spec.declaration()),
        server_t: Some(now),
        clock_rate: Some(rate),
        ..status(&machine, now)
    }))
}

/// Declare a machine.
///
/// `PUT /api/v1/machines/{machine}`: 201 when created, 200 when replaced
/// or unchanged (an identical declaration keeps the learned state).
#[utoipa::path(put, path = "/api/v1/machines/{machine}", operation_id = "declare_machine", tag = "machines", params(MachinePath),
    request_body(content = MachineDeclaration, description = "The machine: its engines with parameter overrides, and optionally its geometry, tolerances, start point, design axis and alarm settings (docs/protocol.md, \"Machines\")"),
    responses(
        (status = CREATED, description = "Declared", body = Declared),
        (status = OK, description = "Replaced, or unchanged (an identical declaration keeps the learned state)", body = Declared)))]
pub async fn put(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, ApiError> {
    if !valid_machine_id(&machine) {
        return Err(ApiError::BadRequest(format!(
            "machine id `{machine}` is not valid: use 1 to 64 letters, digits, `-` or `_`"
        )));
    }
    let body = body.map_err(|e| ApiError::BadRequest(format!("could not read the body: {e}")))?;
    let declaration: MachineDeclaration = serde_json::from_slice(&body).map_err(|e| {
        ApiError::BadRequest(format!(
            "body is not a machine declaration {{\"name\", \"engines\": {{engine: {{param: value}}}}}}: {e}"
        ))
    })?;
    let spec = declaration.validate(&machine)?;
    let (created, changed) = state.declare(spec).await?;
    let handle = state.machine(&machine)?;
    let body = Declared {
        machine,
        created,
        changed,
        config: handle.spec.declaration(),
    };
    let status = if created {
        StatusCode::CREATED
    } else {
        StatusCode::OK
    };
    Ok((status, Json(body)).into_response())
}
