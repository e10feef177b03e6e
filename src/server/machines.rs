//! Machine configuration and status: `PUT`, `GET` one, `GET` all.

use axum::Json;
use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde_json::{Map, Value, json};

use super::SharedState;
use super::error::ApiError;
use crate::config::{MachineDeclaration, valid_machine_id};
use crate::machine::MachineHandle;

/// Status summary: sensors' last readings and their age at `now` (server
/// clock), laser state, latest estimate of each engine.
fn status(machine: &MachineHandle, now: f64) -> Value {
    let status = machine.status();
    let sensors: Map<String, Value> = status
        .sensors
        .iter()
        .map(|(sensor, s)| {
            (
                sensor.as_str().to_string(),
                json!({"last_t": s.last_t, "age_s": now - s.last_t, "readings": s.readings}),
            )
        })
        .collect();
    let mut latest = Map::new();
    for (engine, estimate) in &status.latest {
        let value: Value = serde_json::from_str(&estimate.json).unwrap_or(Value::Null);
        latest.insert(engine.as_str().to_string(), value);
    }
    let laser = latest.get("attitude").map(|a| {
        json!({
            "ok": a["laser_ok"],
            "age_s": a["laser_age_s"],
            "dropout": a["laser_ok"] == Value::Bool(false),
        })
    });
    let last_reading_t = status
        .sensors
        .values()
        .map(|s| s.last_t)
        .fold(None, |acc: Option<f64>, t| {
            Some(acc.map_or(t, |a| a.max(t)))
        });
    json!({
        "machine": machine.spec.id,
        "name": machine.spec.name,
        "engines": machine.spec.engines.keys().map(|e| e.as_str()).collect::<Vec<_>>(),
        "last_reading_t": last_reading_t,
        "sensors": sensors,
        "laser": laser,
        "late_readings": status.late,
        "live_clients": machine.live_clients(),
        "latest": latest,
    })
}

/// The server clock's reading and rate (above 1 in the demo), so a page can
/// age what it shows between fetches.
fn clock(state: &SharedState) -> (f64, f64) {
    (state.clock.now_s(), state.clock.rate())
}

/// `GET /api/v1/machines`.
pub async fn list(State(state): State<SharedState>) -> Json<Value> {
    let (now, rate) = clock(&state);
    let machines: Vec<Value> = state
        .all_machines()
        .iter()
        .map(|m| status(m, now))
        .collect();
    Json(json!({ "machines": machines, "server_t": now, "clock_rate": rate }))
}

/// `GET /api/v1/machines/{machine}`.
pub async fn show(
    State(state): State<SharedState>,
    Path(machine): Path<String>,
) -> Result<Json<Value>, ApiError> {
    let machine = state.machine(&machine)?;
    let (now, rate) = clock(&state);
    let mut body = status(&machine, now);
    body["config"] = serde_json::to_value(machine.spec.declaration()).unwrap_or_default();
    body["server_t"] = now.into();
    body["clock_rate"] = rate.into();
    Ok(Json(body))
}

/// `PUT /api/v1/machines/{machine}`: 201 when created, 200 when replaced
/// or unchanged (an identical declaration keeps the learned state).
pub async fn put(
    State(state): State<SharedState>,
    Path(machine): Path<String>,
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
    let body = json!({
        "machine": machine,
        "created": created,
        "changed": changed,
        "config": handle.spec.declaration(),
    });
    let status = if created {
        StatusCode::CREATED
    } else {
        StatusCode::OK
    };
    Ok((status, Json(body)).into_response())
}
