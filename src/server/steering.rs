//! `GET /api/v1/machines/{machine}/steering`: the correction curve back to
//! the design axis from the machine's newest `dta` estimate and its
//! declared `steering` (the mathematics: `fusion/steering.rs`).

use axum::Json;
use axum::extract::{Path, State};
use serde::Serialize;

use super::error::ApiError;
use super::openapi::MachinePath;
use super::state::SharedState;
use crate::fusion::StreamKind;
use crate::fusion::steering::{self, CurvePoint, PlaneCurve, Start, SteeringSpec};

/// The correction curve of a machine, as `GET .../steering` answers it.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct SteeringBody {
    pub machine: String,
    /// Time of the `dta` estimate the curve starts from.
    pub t: f64,
    /// Whether a curve within the minimum radius reaches the axis within
    /// 500 m; if not, `steps` and `length_m` are `null`, the points empty
    /// and `reason` says why.
    pub feasible: bool,
    /// Whole steps (rings, pipes) to the axis.
    pub steps: Option<u32>,
    pub length_m: Option<f64>,
    pub horizontal: PlaneCurve,
    pub vertical: PlaneCurve,
    /// The declaration's `steering`.
    pub steering: SteeringSpec,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// The correction curve.
///
/// `GET /api/v1/machines/{machine}/steering`: per plane, where the front
/// should be after each step back to the axis, and the cylinders' stroke
/// difference that steers it there (docs/api.md, "Steering").
#[utoipa::path(get, path = "/api/v1/machines/{machine}/steering", operation_id = "get_steering", tag = "estimates",
    params(MachinePath),
    responses((status = OK, description = "The curve from the newest `dta` estimate", body = SteeringBody),
        (status = NOT_FOUND, description = "No such machine, no `steering` declared, or no `dta` estimate yet", body = super::error::ErrorBody)))]
pub async fn show(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
) -> Result<Json<SteeringBody>, ApiError> {
    let handle = state.machine(&machine)?;
    let Some(spec) = handle.spec.steering else {
        return Err(ApiError::NotFound(format!(
            "machine `{machine}` has no `steering` declared (min_radius_m, step_m, cylinder_circle_m)"
        )));
    };
    let status = handle.status();
    let Some(dta) = status.latest.get(&StreamKind::Dta) else {
        return Err(ApiError::NotFound(format!(
            "machine `{machine}` has no `dta` estimate yet (it needs an alignment, a geometry and a position)"
        )));
    };
    let estimate: serde_json::Value = serde_json::from_str(&dta.json)
        .map_err(|e| ApiError::Internal(format!("the dta estimate: {e}")))?;
    let number = |value: &serde_json::Value, what: &str| {
        value
            .as_f64()
            .ok_or_else(|| ApiError::Internal(format!("the dta estimate has no {what}")))
    };
    let front = &estimate["front"];
    let start = Start {
        station_m: number(&front["station_m"], "front station")?,
        horizontal_mm: number(&front["horizontal_mm"], "front horizontal deviation")?,
        vertical_mm: number(&front["vertical_mm"], "front vertical deviation")?,
        tendency_horizontal_mm_per_m: number(
            &estimate["tendency_horizontal_mm_per_m"],
            "horizontal tendency",
        )?,
        tendency_vertical_mm_per_m: number(
            &estimate["tendency_vertical_mm_per_m"],
            "vertical tendency",
        )?,
    };
    let plane = |deviation_mm: f64, tendency_mm_per_m: f64, points: Vec<CurvePoint>| PlaneCurve {
        deviation_mm,
        tendency_mm_per_m,
        points,
    };
    let body = match steering::correction(&spec, &start) {
        Ok(c) => SteeringBody {
            machine,
            t: dta.t,
            feasible: true,
            steps: Some(c.steps),
            length_m: Some(c.length_m),
            horizontal: c.horizontal,
            vertical: c.vertical,
            steering: spec,
            reason: None,
        },
        Err(why) => SteeringBody {
            machine,
            t: dta.t,
            feasible: false,
            steps: None,
            length_m: None,
            horizontal: plane(
                start.horizontal_mm,
                start.tendency_horizontal_mm_per_m,
                Vec::new(),
            ),
            vertical: plane(
                start.vertical_mm,
                start.tendency_vertical_mm_per_m,
                Vec::new(),
            ),
            steering: spec,
            reason: Some(why.to_string()),
        },
    };
    Ok(Json(body))
}
