//! The design axis of a machine's drive: `PUT` as the protocol's JSON or
//! as LandXML 1.2 (`Content-Type: application/xml`), `GET` as JSON.
//! Setting it redeclares the machine with it; as only what the stages
//! read changes, the engines go on where they stood and the `dta` stage
//! derives from here on.

use axum::Json;
use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, header};
use serde::{Deserialize, Serialize};

use super::error::ApiError;
use super::openapi::MachinePath;
use super::state::SharedState;
use crate::fusion::alignment::{AlignmentSpec, AxisPoint, ElementKind, landxml};

/// One element of the summary.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct ElementSummary {
    #[serde(rename = "type")]
    pub kind: ElementKind,
    pub start_station_m: f64,
    pub length_m: f64,
}

/// What a `PUT` answers: the parsed axis in brief.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct AlignmentSummary {
    pub machine: String,
    pub name: String,
    pub start_station_m: f64,
    pub end_station_m: f64,
    pub length_m: f64,
    pub elements: Vec<ElementSummary>,
    /// Points of vertical intersection between the start and the end.
    pub pvis: usize,
}

fn is_xml(headers: &HeaderMap) -> bool {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|t| t.contains("xml"))
}

/// Set the design axis.
///
/// `PUT /api/v1/machines/{machine}/alignment`.
#[utoipa::path(put, path = "/api/v1/machines/{machine}/alignment", operation_id = "put_alignment", tag = "alignment",
    params(MachinePath),
    request_body(description = "The design axis: the protocol's JSON, or LandXML 1.2 (`Content-Type: application/xml`, or any type naming xml such as `text/xml`; the first alignment with its profile)",
        content((AlignmentSpec = "application/json"), (String = "application/xml"))),
    responses((status = OK, description = "Set: the machine is redeclared with it and its `dta` stream derives from here on", body = AlignmentSummary)))]
pub async fn put(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Result<Json<AlignmentSummary>, ApiError> {
    let handle = state.machine(&machine)?;
    let body = body.map_err(|e| ApiError::BadRequest(format!("could not read the body: {e}")))?;
    let spec = if is_xml(&headers) {
        let text = std::str::from_utf8(&body)
            .map_err(|_| ApiError::BadRequest("the LandXML is not UTF-8 text".into()))?;
        landxml::parse(text)
            .map_err(|e| ApiError::BadRequest(format!("LandXML: {e}")))?
            .to_spec()
    } else {
        serde_json::from_slice::<AlignmentSpec>(&body).map_err(|e| {
            ApiError::BadRequest(format!(
                "body is not an alignment (the protocol's JSON, or LandXML with Content-Type: application/xml): {e}"
            ))
        })?
    };
    let mut declaration = handle.spec.declaration();
    declaration.alignment = Some(spec);
    let spec = declaration.validate(&machine)?;
    let built = spec
        .built_alignment
        .clone()
        .ok_or_else(|| ApiError::Internal("a validated alignment was not built".into()))?;
    state.declare(spec).await?;
    let (start, end) = built.station_range_m();
    Ok(Json(AlignmentSummary {
        machine,
        name: built.name.clone(),
        start_station_m: start,
        end_station_m: end,
        length_m: end - start,
        elements: built
            .elements
            .iter()
            .map(|e| ElementSummary {
                kind: e.kind,
                start_station_m: e.start_station_m,
                length_m: e.length_m,
            })
            .collect(),
        pvis: built.profile.pvis.len(),
    }))
}

/// The design axis as declared.
///
/// `GET /api/v1/machines/{machine}/alignment`: as JSON; 404 without one.
#[utoipa::path(get, path = "/api/v1/machines/{machine}/alignment", operation_id = "get_alignment", tag = "alignment",
    params(MachinePath),
    responses((status = OK, description = "The declared design axis", body = AlignmentSpec),
        (status = NOT_FOUND, description = "No such machine, or it has no alignment", body = super::error::ErrorBody)))]
pub async fn show(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
) -> Result<Json<AlignmentSpec>, ApiError> {
    let handle = state.machine(&machine)?;
    handle
        .spec
        .alignment
        .clone()
        .map(Json)
        .ok_or_else(|| ApiError::NotFound(format!("machine `{machine}` has no alignment declared")))
}

/// The most points `GET .../alignment/axis` answers.
const MAX_AXIS_POINTS: f64 = 20_000.0;

#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct AxisQuery {
    /// Station spacing, m (default 5); at most 20 000 points.
    #[param(exclusive_minimum = 0.0)]
    step_m: Option<f64>,
}

/// What `GET .../alignment/axis` answers: the axis sampled for drawing.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct AxisBody {
    pub machine: String,
    pub step_m: f64,
    pub points: Vec<AxisPoint>,
}

/// The design axis sampled for drawing.
///
/// `GET /api/v1/machines/{machine}/alignment/axis?step_m=5`: points of the
/// axis (easting, northing, design height) every `step_m` of station and
/// at each element's start, for plan and profile drawings.
#[utoipa::path(get, path = "/api/v1/machines/{machine}/alignment/axis", operation_id = "get_axis", tag = "alignment",
    params(MachinePath, AxisQuery),
    responses((status = OK, description = "Points of the axis for drawing", body = AxisBody),
        (status = NOT_FOUND, description = "No such machine, or it has no alignment", body = super::error::ErrorBody)))]
pub async fn axis(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    query: Result<Query<AxisQuery>, QueryRejection>,
) -> Result<Json<AxisBody>, ApiError> {
    let handle = state.machine(&machine)?;
    let Query(query) =
        query.map_err(|e| ApiError::BadRequest(format!("bad query string: {}", e.body_text())))?;
    let alignment = handle.spec.built_alignment.as_ref().ok_or_else(|| {
        ApiError::NotFound(format!("machine `{machine}` has no alignment declared"))
    })?;
    let step_m = query.step_m.unwrap_or(5.0);
    let (start, end) = alignment.station_range_m();
    if !(step_m.is_finite() && step_m > 0.0) || (end - start) / step_m > MAX_AXIS_POINTS {
        return Err(ApiError::BadRequest(format!(
            "step_m {step_m} is not a spacing for this axis: a positive number of metres, at least {:.3} for its {:.1} m",
            (end - start) / MAX_AXIS_POINTS,
            end - start
        )));
    }
    Ok(Json(AxisBody {
        machine,
        step_m,
        points: alignment.sampled(step_m),
    }))
}
