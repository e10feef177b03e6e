//! `GET /api/v1/machines/{machine}/rings/plan`: the key positions of the
//! next rings, from the newest `ring_plan` estimate (the stage:
//! `fusion/ring_plan.rs`; the geometry and the plan: `fusion/ring_build/`).

use axum::Json;
use axum::extract::{Path, State};
use serde::Serialize;

use super::error::ApiError;
use super::openapi::MachinePath;
use super::state::SharedState;
use crate::fusion::StreamKind;
use crate::fusion::ring_build::RingSpec;
use crate::fusion::ring_plan::{BuiltRingOut, PlannedRingOut};

/// The ring build plan, as `GET .../rings/plan` answers it.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct RingPlanBody {
    pub machine: String,
    /// Time of the reading (an `advance` or a `tail_clearance`) the plan
    /// was made after.
    pub t: f64,
    /// The next rings, next first: each its key position, its predicted
    /// clearance clockwise from the top and the reason for the key.
    pub rings: Vec<PlannedRingOut>,
    /// The newest ring built, as the lining is tracked.
    pub built: BuiltRingOut,
    /// The plan's cost, mm² (docs/rings.md).
    pub cost: f64,
    /// Whether the rings follow the steer stage's correction curve (else
    /// the axis).
    pub on_correction_curve: bool,
    /// The declaration's `rings`.
    pub declared: RingSpec,
}

/// The next rings' key positions.
///
/// `GET /api/v1/machines/{machine}/rings/plan` (docs/rings.md).
#[utoipa::path(get, path = "/api/v1/machines/{machine}/rings/plan", operation_id = "get_ring_plan", tag = "estimates",
    params(MachinePath),
    responses((status = OK, description = "The plan from the newest `ring_plan` estimate", body = RingPlanBody),
        (status = NOT_FOUND, description = "No such machine, no `rings` declared, or no ring or clearance since the machine had a position", body = super::error::ErrorBody)))]
pub async fn show(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
) -> Result<Json<RingPlanBody>, ApiError> {
    let handle = state.machine(&machine)?;
    let Some(declared) = handle.spec.rings.clone() else {
        return Err(ApiError::NotFound(format!(
            "machine `{machine}` has no `rings` declared (taper_mm, diameter_m, width_m, key_positions, …)"
        )));
    };
    let status = handle.status();
    let Some(latest) = status.latest.get(&StreamKind::RingPlan) else {
        return Err(ApiError::NotFound(format!(
            "machine `{machine}` has no ring plan yet: it needs an alignment, a geometry, a position, and then an `advance` with a `key` or a `tail_clearance`"
        )));
    };
    let estimate: crate::fusion::ring_plan::RingPlanEstimate =
        serde_json::from_str(&latest.json)
            .map_err(|e| ApiError::Internal(format!("the ring_plan estimate: {e}")))?;
    Ok(Json(RingPlanBody {
        machine,
        t: latest.t,
        rings: estimate.rings,
        built: estimate.built,
        cost: estimate.cost,
        on_correction_curve: estimate.on_correction_curve,
        declared,
    }))
}
