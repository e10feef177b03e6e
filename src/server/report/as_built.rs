//! `GET /api/v1/machines/{machine}/as-built`: the whole drive ring by
//! ring, as built: each ring's chainage, the front's and rear's deviations,
//! the tendency, the attitude and the thrust cylinders' strokes, from the
//! machine's `rings` log. As JSON, CSV (one `ring` table, the shift
//! report's columns), a printable HTML page or a PDF with the shift
//! report's header block, chart and lines to sign.

use axum::extract::{Path, Query, State};
use axum::response::Response;
use serde::{Deserialize, Serialize};

use super::layout::{self, ReportPage};
use super::{ChartPoint, ReportFormat, RingRow, csv, report_permit, respond, too_many_rows};
use crate::fusion::declaration::Tolerances;
use crate::fusion::{EstimateValues, StreamKind};
use crate::server::error::ApiError;
use crate::server::history::parse_time;
use crate::server::openapi::MachinePath;
use crate::server::state::SharedState;

/// The as-built report's query.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct AsBuiltQuery {
    /// Only the rings built from this time on: Unix seconds or RFC 3339
    /// (default: the drive's start).
    from: Option<String>,
    /// Only the rings built before this time (default: now).
    to: Option<String>,
    /// `json` (default), `csv`, `html` or `pdf`.
    #[param(inline, value_type = Option<super::ReportFormat>)]
    format: Option<String>,
}

/// The as-built report.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct AsBuilt {
    pub machine: String,
    pub name: String,
    /// The drive: the design axis's name; `null` without an axis.
    pub project: Option<String>,
    pub generated_t: f64,
    #[schema(value_type = Option<Object>)]
    pub tolerances: Option<Tolerances>,
    /// The rings built in [`from`, `to`) (every ring of the drive
    /// without them), in the order built.
    pub rings: Vec<RingRow>,
}

/// The as-built report of the whole drive.
///
/// `GET /api/v1/machines/{machine}/as-built?format=json|csv|html|pdf`
/// (docs/api.md, "As-built report").
#[utoipa::path(get, path = "/api/v1/machines/{machine}/as-built", operation_id = "get_as_built", tag = "estimates",
    params(MachinePath, AsBuiltQuery),
    responses((status = OK, description = "Every ring of the drive",
        content(
            (AsBuilt = "application/json"),
            (String = "text/csv"),
            (String = "text/html"),
            (Vec<u8> = "application/pdf"))),
        (status = BAD_REQUEST, description = "A bad time or format", body = crate::server::error::ErrorBody),
        (status = NOT_FOUND, description = "No such machine", body = crate::server::error::ErrorBody),
        (status = PAYLOAD_TOO_LARGE, description = "More rings than a report in this format holds (`[limits] max_report_rows`, `max_printed_report_rows`): the error names the limit; narrow it with `from` and `to`", body = crate::server::error::ErrorBody)))]
pub async fn show(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    query: Result<Query<AsBuiltQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(query) =
        query.map_err(|e| ApiError::BadRequest(format!("bad query string: {}", e.body_text())))?;
    let format = ReportFormat::parse(query.format.as_deref())?;
    let from = query
        .from
        .as_deref()
        .map(|text| parse_time("from", text))
        .transpose()?;
    let to = query
        .to
        .as_deref()
        .map(|text| parse_time("to", text))
        .transpose()?;
    if let (Some(from), Some(to)) = (from, to)
        && from >= to
    {
        return Err(ApiError::BadRequest(format!(
            "`from` ({from}) is not before `to` ({to})"
        )));
    }
    let handle = state.machine(&machine)?;
    let store = state.store.clone();
    let generated_t = state.clock.now_s();
    let limit = format.row_limit(&state.limits);
    let permit = report_permit(&state).await?;
    // Reading, laying out and drawing all happen off the async workers.
    let answer = tokio::task::spawn_blocking(move || -> Result<Response, ApiError> {
        let _permit = permit;
        let spec = &handle.spec;
        let mut rings = Vec::new();
        let mut too_many = false;
        let (read_from, read_to) = (from.unwrap_or(f64::MIN), to.unwrap_or(f64::MAX));
        if spec.streams().contains(&StreamKind::Rings) {
            store
                .export_estimates(handle.db_id, StreamKind::Rings, read_from, read_to, |e| {
                    if e.t >= read_to {
                        return true;
                    }
                    if let EstimateValues::Rings(ring) = &e.values {
                        if rings.len() == limit {
                            too_many = true;
                            return false;
                        }
                        rings.push(RingRow {
                            t: e.t,
                            ring: ring.clone(),
                            integrity: e.integrity,
                        });
                    }
                    true
                })
                .map_err(ApiError::from)?;
        }
        if too_many {
            return Err(too_many_rows(
                &format!("the as-built report of `{}`", spec.id),
                "rings",
                "narrow it with `from` and `to` (the times the rings were built)",
                format,
                limit,
            ));
        }
        let report = AsBuilt {
            machine: spec.id.clone(),
            name: spec.name.clone(),
            project: spec
                .built_alignment
                .as_ref()
                .map(|a| a.name.clone())
                .filter(|n| !n.is_empty()),
            generated_t,
            tolerances: spec.tolerances,
            rings,
        };
        let stem = format!("{}-as-built", report.machine);
        respond(
            format,
            &report,
            &stem,
            || write_csv(&report),
            || page(&report),
        )
    });
    answer
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))?
}

/// The CSV: the `ring` table of the shift report's CSV, every ring.
fn write_csv(report: &AsBuilt) -> String {
    let rows = serde_json::to_value(&report.rings).unwrap_or_default();
    csv::table("ring", rows.as_array().map(Vec::as_slice).unwrap_or(&[]))
}

/// The page: header block, summary, the chart of the front's deviation
/// at each ring, the rings, the lines to sign.
fn page(report: &AsBuilt) -> ReportPage {
    let stations: Vec<f64> = report
        .rings
        .iter()
        .filter_map(|r| r.ring.station_m)
        .collect();
    let range = match (stations.first(), stations.last()) {
        (Some(first), Some(last)) => {
            format!(
                "{} to {}",
                layout::chainage(*first),
                layout::chainage(*last)
            )
        }
        _ => "—".to_string(),
    };
    let largest = |value: &dyn Fn(&RingRow) -> Option<f64>| {
        report
            .rings
            .iter()
            .filter_map(|r| value(r).map(|v| (v, r.ring.ring)))
            .max_by(|a, b| a.0.abs().total_cmp(&b.0.abs()))
            .map_or_else(
                || "—".to_string(),
                |(v, ring)| format!("{v:+.1} mm at ring {ring}"),
            )
    };
    let points: Vec<ChartPoint> = report
        .rings
        .iter()
        .filter_map(|r| {
            Some(ChartPoint {
                t: r.t,
                station_m: r.ring.station_m?,
                horizontal_mm: r.ring.front_horizontal_mm?,
                vertical_mm: r.ring.front_vertical_mm?,
            })
        })
        .collect();
    let first_t = report.rings.first().map(|r| r.t);
    let last_t = report.rings.last().map(|r| r.t);
    ReportPage {
        title: format!("As-built report: {}", report.name),
        subtitle: format!("machine {}, the whole drive", report.machine),
        header: vec![
            (
                "Project",
                report.project.clone().unwrap_or_else(|| "—".to_string()),
            ),
            ("Machine", format!("{} ({})", report.name, report.machine)),
            (
                "Rings built",
                match (first_t, last_t) {
                    (Some(a), Some(b)) => {
                        format!("{} to {} UTC", layout::time(a), layout::time(b))
                    }
                    _ => "—".to_string(),
                },
            ),
            ("Chainage", range),
            (
                "Generated at",
                format!("{} UTC", layout::time(report.generated_t)),
            ),
        ],
        summary: vec![
            ("Rings", report.rings.len().to_string()),
            ("Largest front H", largest(&|r| r.ring.front_horizontal_mm)),
            ("Largest front V", largest(&|r| r.ring.front_vertical_mm)),
        ],
        chart: layout::chart(&points, report.tolerances),
        tables: vec![layout::ring_table("Rings as built", &report.rings, true)],
        signatures: vec!["Surveyor", "Site engineer (checked)"],
    }
}
