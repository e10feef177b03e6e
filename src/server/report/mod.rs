//! `GET /api/v1/machines/{machine}/report`: the shift report. Over a time
//! range, from what the machine's streams stored: the advance (rings,
//! pushes, station gained), the largest deviations from the axis, the
//! ring and push logs, the alarms raised or still active and who
//! acknowledged them, the laser's dropouts, and the deviation chart. As
//! JSON (the numbers), CSV (the same numbers, a table per section), a
//! printable HTML page or a PDF; the page and the PDF lay out the same
//! tables ([`layout`]).

pub mod as_built;
mod contents;
mod csv;
mod layout;
mod pdf;

use askama::Template;
use axum::extract::{Path, Query, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};

use contents::number_runs;
pub use contents::{
    Advance, ChartPoint, Dropout, LargestDeviation, PushRow, Report, RingRow, Stretch,
};

use super::error::ApiError;
use super::history::parse_time;
use super::openapi::MachinePath;
use super::state::SharedState;
use crate::fusion::rings::BACKWARD_JUMP_M;
use crate::fusion::{EngineKind, EstimateValues, SensorKind, StreamKind};
use crate::machine::MachineHandle;
use crate::store::alarms::AlarmFilter;
use crate::store::{Store, StoreError};

/// One shift: the range a report covers when the query names none.
pub const DEFAULT_SPAN_S: f64 = 8.0 * 3600.0;
/// The longest range a report covers: a week of shifts (its deviations
/// are read from every `dta` estimate, its dropouts from every laser and
/// inclinometer reading).
pub const MAX_SPAN_S: f64 = 7.0 * 86_400.0;
/// Points of the deviation chart (the range downsampled, keeping each
/// bucket's extremes).
pub const CHART_POINTS: usize = 400;

/// The report's query.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct ReportQuery {
    /// Start of the shift: Unix seconds or RFC 3339 (default: 8 h before
    /// `to`).
    from: Option<String>,
    /// End of the shift (default: now); after `from`.
    to: Option<String>,
    /// `json` (default), `csv`, `html` or `pdf`.
    #[param(inline, value_type = Option<ReportFormat>)]
    format: Option<String>,
}

/// How the report is answered.
#[derive(Debug, Clone, Copy, PartialEq, utoipa::ToSchema)]
#[schema(rename_all = "lowercase")]
pub enum ReportFormat {
    Json,
    Csv,
    Html,
    Pdf,
}

/// The shift report.
///
/// `GET /api/v1/machines/{machine}/report?from=&to=&format=json|csv|html|pdf`
/// (docs/api.md, "Shift report").
#[utoipa::path(get, path = "/api/v1/machines/{machine}/report", operation_id = "get_report", tag = "estimates",
    params(MachinePath, ReportQuery),
    responses((status = OK, description = "The report over the range",
        content(
            (Report = "application/json"),
            (String = "text/csv"),
            (String = "text/html"),
            (Vec<u8> = "application/pdf"))),
        (status = BAD_REQUEST, description = "A bad time or format", body = super::error::ErrorBody),
        (status = NOT_FOUND, description = "No such machine", body = super::error::ErrorBody),
        (status = PAYLOAD_TOO_LARGE, description = "More rows than a report in this format holds (`[limits] max_report_rows`, `max_printed_report_rows`): the error names the limit; narrow `from` and `to`", body = super::error::ErrorBody)))]
pub async fn show(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    query: Result<Query<ReportQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(query) =
        query.map_err(|e| ApiError::BadRequest(format!("bad query string: {}", e.body_text())))?;
    let format = ReportFormat::parse(query.format.as_deref())?;
    let to = match &query.to {
        Some(text) => parse_time("to", text)?,
        None => state.clock.now_s(),
    };
    let from = match &query.from {
        Some(text) => parse_time("from", text)?,
        None => to - DEFAULT_SPAN_S,
    };
    if from >= to {
        return Err(ApiError::BadRequest(format!(
            "`from` ({from}) is not before `to` ({to})"
        )));
    }
    if to - from > MAX_SPAN_S {
        return Err(ApiError::BadRequest(format!(
            "`from` to `to` spans {:.1} days; a report covers at most 7",
            (to - from) / 86_400.0
        )));
    }
    let handle = state.machine(&machine)?;
    let store = state.store.clone();
    let generated_t = state.clock.now_s();
    let limit = format.row_limit(&state.limits);
    let permit = report_permit(&state).await?;
    // Read, laid out and drawn off the async workers.
    tokio::task::spawn_blocking(move || {
        let _permit = permit;
        let report =
            gather(&store, &handle, from, to, generated_t, limit).map_err(|e| match e {
                GatherError::Store(e) => ApiError::from(e),
                GatherError::TooManyRows => too_many_rows(
                    &format!("the report of `{}` from {from} to {to}", handle.spec.id),
                    "rows (rings, pushes, alarms, laser dropouts)",
                    "narrow `from` and `to`",
                    format,
                    limit,
                ),
            })?;
        let stem = format!("{}-report-{}-{}", report.machine, report.from, report.to);
        respond(
            format,
            &report,
            &stem,
            || csv::write(&report),
            || layout::ReportPage::new(&report),
        )
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))?
}

/// Why a report could not be gathered.
#[derive(Debug)]
enum GatherError {
    Store(StoreError),
    /// More rows than the format's limit.
    TooManyRows,
}

impl From<StoreError> for GatherError {
    fn from(e: StoreError) -> Self {
        GatherError::Store(e)
    }
}

/// The rows a report may still take: [`ReportFormat::row_limit`] in all.
struct RowBudget {
    left: usize,
    exceeded: bool,
}

impl RowBudget {
    fn new(limit: usize) -> RowBudget {
        RowBudget {
            left: limit,
            exceeded: false,
        }
    }

    /// Takes one row; false (and exceeded) when none is left.
    fn take(&mut self) -> bool {
        if self.left == 0 {
            self.exceeded = true;
            return false;
        }
        self.left -= 1;
        true
    }

    /// Takes `n` rows at once.
    fn take_all(&mut self, n: usize) -> Result<(), GatherError> {
        if n > self.left {
            self.exceeded = true;
            return Err(GatherError::TooManyRows);
        }
        self.left -= n;
        Ok(())
    }

    fn check(&self) -> Result<(), GatherError> {
        if self.exceeded {
            Err(GatherError::TooManyRows)
        } else {
            Ok(())
        }
    }
}

/// A permit to read and draw a report ([`Limits::reports_at_once`]):
/// more wait their turn.
///
/// [`Limits::reports_at_once`]: super::settings::Limits::reports_at_once
async fn report_permit(state: &SharedState) -> Result<tokio::sync::OwnedSemaphorePermit, ApiError> {
    state
        .reports
        .clone()
        .acquire_owned()
        .await
        .map_err(|e| ApiError::Internal(format!("the reports' queue: {e}")))
}

/// The 413 of a report (`what`) holding more `rows` than `format` may:
/// it names the limits, the settings and how to narrow it (`narrow`).
fn too_many_rows(
    what: &str,
    rows: &str,
    narrow: &str,
    format: ReportFormat,
    limit: usize,
) -> ApiError {
    let (kind, setting) = match format {
        ReportFormat::Html | ReportFormat::Pdf => ("a page or PDF", "max_printed_report_rows"),
        ReportFormat::Json | ReportFormat::Csv => ("JSON or CSV", "max_report_rows"),
    };
    ApiError::TooLarge(format!(
        "{what} holds more than {limit} {rows}: as {kind} a report holds at most {limit} \
         (`[limits] {setting}`); {narrow}"
    ))
}

impl ReportFormat {
    /// The most rows a report in this format holds under `limits`.
    pub fn row_limit(self, limits: &super::settings::Limits) -> usize {
        match self {
            ReportFormat::Html | ReportFormat::Pdf => limits.max_printed_report_rows,
            ReportFormat::Json | ReportFormat::Csv => limits.max_report_rows,
        }
    }

    /// The `format` query parameter (default `json`).
    pub fn parse(format: Option<&str>) -> Result<ReportFormat, ApiError> {
        match format {
            None | Some("json") => Ok(ReportFormat::Json),
            Some("csv") => Ok(ReportFormat::Csv),
            Some("html") => Ok(ReportFormat::Html),
            Some("pdf") => Ok(ReportFormat::Pdf),
            Some(other) => Err(ApiError::BadRequest(format!(
                "`format` = `{other}`: expected json, csv, html or pdf"
            ))),
        }
    }
}

/// `report` answered as `format`: its JSON, `csv`, or the `page` as HTML
/// or PDF, files named `stem`.
fn respond<T: Serialize>(
    format: ReportFormat,
    report: &T,
    stem: &str,
    csv: impl FnOnce() -> String,
    page: impl FnOnce() -> layout::ReportPage,
) -> Result<Response, ApiError> {
    let attachment = |extension: &str| format!("inline; filename=\"{stem}.{extension}\"");
    Ok(match format {
        ReportFormat::Json => axum::Json(report).into_response(),
        ReportFormat::Csv => (
            [
                (header::CONTENT_TYPE, "text/csv; charset=utf-8".to_string()),
                (header::CONTENT_DISPOSITION, attachment("csv")),
            ],
            csv(),
        )
            .into_response(),
        ReportFormat::Html => {
            let html = page()
                .render()
                .map_err(|e| ApiError::Internal(format!("the report page: {e}")))?;
            ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], html).into_response()
        }
        ReportFormat::Pdf => {
            let bytes = pdf::write(&page())
                .map_err(|e| ApiError::Internal(format!("the report PDF: {e}")))?;
            (
                [
                    (header::CONTENT_TYPE, "application/pdf".to_string()),
                    (header::CONTENT_DISPOSITION, attachment("pdf")),
                ],
                bytes,
            )
                .into_response()
        }
    })
}

/// The report of `machine` over [`from`, `to`], from the store.
fn gather(
    store: &Store,
    machine: &MachineHandle,
    from: f64,
    to: f64,
    generated_t: f64,
    limit: usize,
) -> Result<Report, GatherError> {
    let mut budget = RowBudget::new(limit);
    let spec = &machine.spec;
    let db_id = machine.db_id;
    let streams = spec.streams();
    let runs = |stream: StreamKind| streams.contains(&stream);

    let rings = rows(
        store,
        (db_id, StreamKind::Rings),
        runs(StreamKind::Rings),
        &mut budget,
        from,
        to,
        |e| match &e.values {
            EstimateValues::Rings(ring) => Some(RingRow {
                t: e.t,
                ring: ring.clone(),
                integrity: e.integrity,
            }),
            _ => None,
        },
    )?;
    let pushes = rows(
        store,
        (db_id, StreamKind::Pushes),
        runs(StreamKind::Pushes),
        &mut budget,
        from,
        to,
        |e| match &e.values {
            EstimateValues::Pushes(push) => Some(PushRow {
                t: e.t,
                push: push.clone(),
                integrity: e.integrity,
            }),
            _ => None,
        },
    )?;

    // Every dta estimate of the range: the largest deviations are exact.
    let mut deviations: Vec<LargestDeviation> = Vec::new();
    let mut stations: Option<(f64, f64)> = None;
    let mut stretches: Vec<Stretch> = Vec::new();
    if runs(StreamKind::Dta) {
        store.export_estimates(db_id, StreamKind::Dta, from, to, |e| {
            let EstimateValues::Dta(d) = &e.values else {
                return true;
            };
            stations = Some(match stations {
                Some((first, _)) => (first, d.station_m),
                None => (d.station_m, d.station_m),
            });
            match stretches.last_mut() {
                Some(s) if d.station_m > s.to_station_m - BACKWARD_JUMP_M => {
                    (s.to_t, s.to_station_m) = (e.t, d.station_m);
                }
                _ => stretches.push(Stretch {
                    from_t: e.t,
                    to_t: e.t,
                    from_station_m: d.station_m,
                    to_station_m: d.station_m,
                }),
            }
            let values = [
                (
                    "front",
                    "horizontal",
                    d.front.horizontal_mm,
                    d.front.station_m,
                ),
                ("front", "vertical", d.front.vertical_mm, d.front.station_m),
                ("rear", "horizontal", d.rear.horizontal_mm, d.rear.station_m),
                ("rear", "vertical", d.rear.vertical_mm, d.rear.station_m),
            ];
            if deviations.is_empty() {
                deviations = values
                    .iter()
                    .map(
                        |&(point, plane, deviation_mm, station_m)| LargestDeviation {
                            point,
                            plane,
                            deviation_mm,
                            t: e.t,
                            station_m,
                        },
                    )
                    .collect();
            }
            for (largest, &(_, _, deviation_mm, station_m)) in deviations.iter_mut().zip(&values) {
                if deviation_mm.abs() > largest.deviation_mm.abs() {
                    (largest.deviation_mm, largest.t, largest.station_m) =
                        (deviation_mm, e.t, station_m);
                }
            }
            true
        })?;
    }
    let chart = if runs(StreamKind::Dta) {
        store
            .estimates_page(db_id, StreamKind::Dta, from, to, CHART_POINTS)?
            .estimates
            .iter()
            .filter_map(|e| match &e.values {
                EstimateValues::Dta(d) => Some(ChartPoint {
                    t: e.t,
                    station_m: d.front.station_m,
                    horizontal_mm: d.front.horizontal_mm,
                    vertical_mm: d.front.vertical_mm,
                }),
                _ => None,
            })
            .collect()
    } else {
        Vec::new()
    };

    // Only the range's alarms are read, and one more than the budget.
    let mut alarms = store.alarms(&AlarmFilter {
        machine: Some(spec.id.clone()),
        active_only: false,
        during: Some((from, to)),
        limit: Some(budget.left.saturating_add(1)),
    })?;
    budget.take_all(alarms.len())?;
    alarms.sort_by(|a, b| a.raised_t.total_cmp(&b.raised_t).then(a.id.cmp(&b.id)));

    let laser_dropouts = if spec.engines.contains_key(&EngineKind::Attitude) {
        Some(dropouts(
            store,
            db_id,
            from,
            to,
            spec.alarms.laser_dropout_warn_s,
        )?)
    } else {
        None
    };
    budget.take_all(laser_dropouts.as_ref().map_or(0, Vec::len))?;

    // The rings' own advance where they know it (a ring stored before
    // the backward jump was refused may carry one: not an advance); else
    // the stations'.
    let ring_advances: Vec<f64> = rings
        .iter()
        .filter_map(|r| r.ring.advance_m)
        .filter(|a| *a > -BACKWARD_JUMP_M)
        .collect();
    let (advance_m, advance_from) = if !ring_advances.is_empty() {
        (Some(ring_advances.iter().sum::<f64>()), Some("rings"))
    } else if !stretches.is_empty() {
        let gained = stretches
            .iter()
            .fold(0.0, |sum, s| sum + (s.to_station_m - s.from_station_m));
        (Some(gained), Some("stations"))
    } else {
        (None, None)
    };
    let advance = Advance {
        rings: rings.len() as u64,
        first_ring: rings.first().map(|r| r.ring.ring),
        last_ring: rings.last().map(|r| r.ring.ring),
        start_station_m: stations.map(|s| s.0),
        end_station_m: stations.map(|s| s.1),
        advance_m,
        pushes: pushes.len() as u64,
        // A fold from +0: an empty f64 sum is −0.
        pushed_m: pushes.iter().fold(0.0, |sum, p| sum + p.push.length_m),
        advance_from,
        ring_numbers: number_runs(rings.iter().map(|r| r.ring.ring)),
        stretches,
    };
    Ok(Report {
        machine: spec.id.clone(),
        name: spec.name.clone(),
        from,
        to,
        project: machine
            .spec
            .built_alignment
            .as_ref()
            .map(|a| a.name.clone())
            .filter(|n| !n.is_empty()),
        generated_t,
        tolerances: spec.tolerances,
        advance,
        deviations,
        rings,
        pushes,
        alarms,
        laser_dropouts,
        chart,
    })
}

/// A row per estimate of machine `db_id`'s `stream` in [`from`, `to`)
/// that `row` makes one of, each taken from `budget` (reading stops when
/// it is spent); none if the machine does not run the stream.
fn rows<T>(
    store: &Store,
    (db_id, stream): (i64, StreamKind),
    runs: bool,
    budget: &mut RowBudget,
    from: f64,
    to: f64,
    row: impl Fn(&crate::fusion::EngineOutput) -> Option<T>,
) -> Result<Vec<T>, GatherError> {
    let mut rows = Vec::new();
    if runs {
        store.export_estimates(db_id, stream, from, to, |e| match row(e) {
            // A shift is [from, to): a row at `to` is the next one's.
            _ if e.t >= to => true,
            Some(r) if budget.take() => {
                rows.push(r);
                true
            }
            Some(_) => false,
            None => true,
        })?;
    }
    budget.check()?;
    Ok(rows)
}

/// Stretches of [`from`, `to`] without a laser reading for more than
/// `limit_s` while the machine ran: while its inclinometer (which the
/// `attitude` engine fuses with the laser) read without a gap of more than
/// `limit_s`. Each is the whole gap between two laser readings (or the
/// start or end of the machine's run), clipped to the range. The search
/// starts `limit_s` before `from`, so a range opening in a dropout says so.
fn dropouts(
    store: &Store,
    db_id: i64,
    from: f64,
    to: f64,
    limit_s: f64,
) -> Result<Vec<Dropout>, StoreError> {
    let since = from - limit_s;
    let mut lasers = Vec::new();
    store.export_readings(db_id, Some(SensorKind::Laser), since, to, |r| {
        lasers.push(r.t);
        true
    })?;
    // The machine's runs: its inclinometer's readings without a silence.
    let mut runs: Vec<(f64, f64)> = Vec::new();
    store.export_readings(db_id, Some(SensorKind::Inclinometer), since, to, |r| {
        match runs.last_mut() {
            Some(run) if r.t - run.1 <= limit_s => run.1 = r.t,
            _ => runs.push((r.t, r.t)),
        }
        true
    })?;
    let mut gaps = Vec::new();
    for (start, end) in runs {
        // The newest laser reading before the run, those in it, its end.
        let first = lasers.partition_point(|&t| t < start);
        let last = lasers.partition_point(|&t| t <= end);
        let mut previous = if first > 0 { lasers[first - 1] } else { start };
        for &next in lasers[first..last].iter().chain(std::iter::once(&end)) {
            if next - previous > limit_s {
                let (from_t, to_t) = (previous.max(start).max(from), next.min(to));
                if to_t > from_t {
                    gaps.push(Dropout {
                        from_t,
                        to_t,
                        duration_s: to_t - from_t,
                    });
                }
            }
            previous = next;
        }
    }
    Ok(gaps)
}

#[cfg(test)]
mod tests {
    use super::contents::RingRun;
    use super::*;

    #[test]
    fn ring_numbers_run_as_logged() {
        let pairs = |runs: Vec<RingRun>| runs.iter().map(|r| (r.first, r.last)).collect::<Vec<_>>();
        assert_eq!(
            pairs(number_runs([7, 8, 1, 2, 3, 5])),
            [(7, 8), (1, 3), (5, 5)]
        );
        assert_eq!(
            pairs(number_runs([u64::MAX, 0])),
            [(u64::MAX, u64::MAX), (0, 0)]
        );
        assert!(number_runs([]).is_empty());
    }
}
