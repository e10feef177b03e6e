//! `GET /api/v1/machines/{machine}/steering`: the correction curve the
//! machine is steering, a point per step from its front, from the newest
//! `steer` estimate (the curve held by the stage: `fusion/steer.rs`; the
//! mathematics: `fusion/steering.rs`).

use axum::Json;
use axum::extract::{Path, State};
use serde::Serialize;

use super::error::ApiError;
use super::openapi::MachinePath;
use super::state::SharedState;
use crate::fusion::StreamKind;
use crate::fusion::steering::{self, Front, GroupTarget, Plan, PlaneCurve, SteeringSpec};

/// The correction curve of a machine, as `GET .../steering` answers it.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct SteeringBody {
    pub machine: String,
    /// Time of the `dta` estimate the curve is drawn from.
    pub t: f64,
    /// Whether a curve within the machine's limits reaches the axis within
    /// 500 m; if not, `steps` and `length_m` are `null`, the points empty
    /// and `reason` says why.
    pub feasible: bool,
    /// Whole steps (rings, pipes) from the front to the curve's end.
    pub steps: Option<u32>,
    /// From the front to the curve's end, m.
    pub length_m: Option<f64>,
    pub horizontal: PlaneCurve,
    pub vertical: PlaneCurve,
    /// The next step in words.
    pub words: String,
    /// Each declared cylinder group's share of the next step.
    pub groups: Vec<GroupTarget>,
    /// Whether the curve was planned at this estimate (else held).
    pub replanned: bool,
    /// The declaration's `steering`.
    pub steering: SteeringSpec,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// The correction curve.
///
/// `GET /api/v1/machines/{machine}/steering`: per plane, where the front
/// should be after each step back to the axis, the path's curvature and
/// the cylinders' stroke difference that steers it there (docs/api.md,
/// "Steering").
#[utoipa::path(get, path = "/api/v1/machines/{machine}/steering", operation_id = "get_steering", tag = "estimates",
    params(MachinePath),
    responses((status = OK, description = "The curve from the newest `steer` estimate", body = SteeringBody),
        (status = NOT_FOUND, description = "No such machine, no `steering` declared, or no `dta` estimate yet", body = super::error::ErrorBody)))]
pub async fn show(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
) -> Result<Json<SteeringBody>, ApiError> {
    let handle = state.machine(&machine)?;
    let Some(spec) = handle.spec.steering.clone() else {
        return Err(ApiError::NotFound(format!(
            "machine `{machine}` has no `steering` declared (min_radius_m, step_m, cylinder_circle_m)"
        )));
    };
    let status = handle.status();
    let (Some(steer), Some(alignment)) = (
        status.latest.get(&StreamKind::Steer),
        handle.spec.built_alignment.as_ref(),
    ) else {
        return Err(ApiError::NotFound(format!(
            "machine `{machine}` has no `dta` estimate yet (it needs an alignment, a geometry and a position)"
        )));
    };
    let estimate: serde_json::Value = serde_json::from_str(&steer.json)
        .map_err(|e| ApiError::Internal(format!("the steer estimate: {e}")))?;
    let number = |value: &serde_json::Value, what: &str| {
        value
            .as_f64()
            .ok_or_else(|| ApiError::Internal(format!("the steer estimate has no {what}")))
    };
    let (h, v) = (&estimate["horizontal"], &estimate["vertical"]);
    let station_m = number(&estimate["station_m"], "front station")?;
    let front = Front {
        internal_station_m: estimate["internal_station_m"].as_f64().unwrap_or(station_m),
        station_m,
        horizontal_mm: number(&h["deviation_mm"], "horizontal deviation")?,
        vertical_mm: number(&v["deviation_mm"], "vertical deviation")?,
        tendency_horizontal_mm_per_m: number(&h["tendency_mm_per_m"], "horizontal tendency")?,
        tendency_vertical_mm_per_m: number(&v["tendency_mm_per_m"], "vertical tendency")?,
    };
    let plan: Option<Plan> = serde_json::from_value(estimate["plan"].clone())
        .map_err(|e| ApiError::Internal(format!("the steer estimate's plan: {e}")))?;
    let groups: Vec<GroupTarget> =
        serde_json::from_value(estimate["groups"].clone()).unwrap_or_default();
    let words = estimate["words"].as_str().unwrap_or_default().to_string();
    let replanned = estimate["replanned"].as_bool().unwrap_or(true);
    let empty = |deviation_mm: f64, tendency_mm_per_m: f64| PlaneCurve {
        deviation_mm,
        tendency_mm_per_m,
        points: Vec::new(),
    };
    let feasible = estimate["feasible"].as_bool().unwrap_or(plan.is_some());
    let body = match plan {
        // A curve stored by a release before the held plan (codec 1):
        // feasible, its points drawn from the next position.
        None if feasible => SteeringBody {
            machine,
            t: steer.t,
            feasible: true,
            steps: estimate["steps"].as_u64().and_then(|s| u32::try_from(s).ok()),
            length_m: estimate["length_m"].as_f64(),
            horizontal: empty(front.horizontal_mm, front.tendency_horizontal_mm_per_m),
            vertical: empty(front.vertical_mm, front.tendency_vertical_mm_per_m),
            words,
            groups,
            replanned,
            steering: spec,
            reason: Some(
                "the newest curve was stored by an earlier release without its points: the next position plans it again"
                    .into(),
            ),
        },
        Some(plan) => {
            let c = steering::expand(
                &spec,
                &**alignment,
                &plan,
                &front,
                handle.spec.tolerances.as_ref(),
                [h, v].map(|p| p["own_curvature_per_m"].as_f64().unwrap_or(0.0)),
            );
            SteeringBody {
                machine,
                t: steer.t,
                feasible: true,
                steps: Some(c.steps),
                length_m: Some(c.length_m),
                horizontal: c.horizontal,
                vertical: c.vertical,
                words,
                groups,
                replanned,
                steering: spec,
                reason: None,
            }
        }
        None => SteeringBody {
            machine,
            t: steer.t,
            feasible: false,
            steps: None,
            length_m: None,
            horizontal: empty(front.horizontal_mm, front.tendency_horizontal_mm_per_m),
            vertical: empty(front.vertical_mm, front.tendency_vertical_mm_per_m),
            reason: Some(
                words
                    .strip_prefix("no curve: ")
                    .unwrap_or(&words)
                    .to_string(),
            ),
            words,
            groups,
            replanned,
            steering: spec,
        },
    };
    Ok(Json(body))
}
