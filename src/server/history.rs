//! History: estimates (downsampled in the server), raw readings (streamed
//! as NDJSON or CSV), and the `attitude` engine's learned model.

use axum::body::{Body, Bytes};
use axum::extract::rejection::QueryRejection;
use axum::extract::{Path, Query, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;

use super::error::ApiError;
use super::openapi::{Estimate, MachinePath, query_time};
use super::state::SharedState;
use crate::fusion::reading::{EARLIEST_T_S, LATEST_T_S};
use crate::fusion::{
    EngineKind, EngineModel, EstimateRef, Reading, SensorData, SensorKind, StreamKind,
};

/// Points a history query returns unless told otherwise.
pub const DEFAULT_MAX_POINTS: usize = 2000;
/// Bytes per chunk of a streamed export.
const CHUNK_BYTES: usize = 64 * 1024;

/// The body of an estimates history answer.
#[derive(Serialize, utoipa::ToSchema)]
struct HistoryPage<'a> {
    machine: &'a str,
    engine: StreamKind,
    /// The range asked for, Unix seconds.
    from: f64,
    to: f64,
    /// True when the range held more than `max_points` estimates: then
    /// each of `max_points` buckets keeps its extremes.
    downsampled: bool,
    #[schema(value_type = Vec<Estimate>)]
    estimates: Vec<EstimateRef<'a>>,
}

/// A Unix time above this (the year 5138 in seconds) is read as
/// milliseconds, as Grafana sends them.
pub const MILLISECONDS_ABOVE: f64 = 1e11;

/// Parses a query-string time: Unix seconds (milliseconds above
/// [`MILLISECONDS_ABOVE`]) or RFC 3339.
pub fn parse_time(field: &str, text: &str) -> Result<f64, ApiError> {
    let t = match text.trim().parse::<f64>() {
        Ok(t) if t.is_finite() && t.abs() > MILLISECONDS_ABOVE => t / 1000.0,
        Ok(t) if t.is_finite() => t,
        _ => chrono::DateTime::parse_from_rfc3339(text.trim())
            .map(|d| d.timestamp() as f64 + f64::from(d.timestamp_subsec_nanos()) * 1e-9)
            .map_err(|_| {
                ApiError::BadRequest(format!(
                    "`{field}` = `{text}` is not a time: use Unix seconds or RFC 3339 (2026-03-02T06:00:00Z)"
                ))
            })?,
    };
    Ok(t)
}

fn range(from: Option<&str>, to: Option<&str>) -> Result<(f64, f64), ApiError> {
    let from_t = from
        .map(|t| parse_time("from", t))
        .transpose()?
        .unwrap_or(EARLIEST_T_S);
    let to_t = to
        .map(|t| parse_time("to", t))
        .transpose()?
        .unwrap_or(LATEST_T_S);
    if from_t > to_t {
        return Err(ApiError::BadRequest(format!(
            "`from` ({from_t}) is after `to` ({to_t})"
        )));
    }
    Ok((from_t, to_t))
}

fn query<T>(query: Result<Query<T>, QueryRejection>) -> Result<T, ApiError> {
    query
        .map(|Query(q)| q)
        .map_err(|e| ApiError::BadRequest(format!("bad query string: {}", e.body_text())))
}

#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct EstimatesQuery {
    /// The stream: an engine or stage the machine runs (required when it
    /// runs several).
    #[param(inline, value_type = Option<StreamKind>)]
    engine: Option<String>,
    /// Start of the range (default: the earliest).
    #[param(schema_with = query_time)]
    from: Option<String>,
    /// End of the range (default: the latest); not before `from`.
    #[param(schema_with = query_time)]
    to: Option<String>,
    /// Most estimates in a JSON page (default 2000); above it the range
    /// is downsampled keeping each bucket's extremes.
    #[param(minimum = 1)]
    max_points: Option<usize>,
    /// `json` (default: a page, downsampled above `max_points`), or
    /// `ndjson` / `csv`: every estimate in the range, streamed.
    #[param(inline, value_type = Option<EstimatesFormat>)]
    format: Option<String>,
}

/// How estimates are answered.
#[derive(utoipa::ToSchema)]
#[schema(rename_all = "lowercase")]
#[allow(
    dead_code,
    reason = "names the values of `format` in the document; parsed as text"
)]
enum EstimatesFormat {
    Json,
    Ndjson,
    Csv,
}

/// How readings are answered.
#[derive(utoipa::ToSchema)]
#[schema(rename_all = "lowercase")]
#[allow(
    dead_code,
    reason = "names the values of `format` in the document; parsed as text"
)]
enum ReadingsFormat {
    Ndjson,
    Csv,
}

/// A stream's estimates.
///
/// `GET /api/v1/machines/{machine}/estimates`.
#[utoipa::path(get, path = "/api/v1/machines/{machine}/estimates", operation_id = "get_estimates", tag = "estimates",
    params(MachinePath, EstimatesQuery),
    responses((status = OK, description = "The estimates of one stream in the range: a page (JSON), or every one streamed (NDJSON, CSV)",
        content(
            (HistoryPage = "application/json"),
            (String = "application/x-ndjson", example = json!("{\"t\":1772431200.0,\"machine\":\"tbm-north\",\"engine\":\"attitude\",...}\n")),
            (String = "text/csv")))))]
pub async fn estimates(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    params: Result<Query<EstimatesQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let machine = state.machine(&machine)?;
    let params = query(params)?;
    let engines: Vec<EngineKind> = machine.spec.engines.keys().copied().collect();
    let streams = machine.spec.streams();
    let engine = match params.engine.as_deref() {
        Some(name) => {
            let stream: StreamKind = name
                .parse()
                .map_err(|e: crate::fusion::UnknownEngine| ApiError::BadRequest(e.to_string()))?;
            if !streams.contains(&stream) {
                return Err(ApiError::BadRequest(format!(
                    "machine `{}` has no `{stream}` estimates (it has: {})",
                    machine.spec.id,
                    streams
                        .iter()
                        .map(|s| s.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            }
            stream
        }
        // The machine's one engine; stages are asked for by name.
        None if engines.len() == 1 => engines[0].into(),
        None => {
            return Err(ApiError::BadRequest(
                "`engine` is required: the machine runs several".into(),
            ));
        }
    };
    let (from_t, to_t) = range(params.from.as_deref(), params.to.as_deref())?;
    let csv = match params.format.as_deref() {
        None | Some("json") => None,
        Some("ndjson") => Some(false),
        Some("csv") => Some(true),
        Some(other) => {
            return Err(ApiError::BadRequest(format!(
                "`format` = `{other}`: expected json, ndjson or csv"
            )));
        }
    };
    if let Some(csv) = csv {
        if params.max_points.is_some() {
            return Err(ApiError::BadRequest(
                "`max_points` applies to the JSON page; an ndjson or csv export has every estimate"
                    .into(),
            ));
        }
        return Ok(export_estimates(
            &state, &machine, engine, from_t, to_t, csv,
        ));
    }
    let max_points = params.max_points.unwrap_or(DEFAULT_MAX_POINTS);
    if !(1..=state.limits.max_points_limit).contains(&max_points) {
        return Err(ApiError::BadRequest(format!(
            "`max_points` = {max_points} is outside [1, {}]",
            state.limits.max_points_limit
        )));
    }
    let store = state.store.clone();
    let db_id = machine.db_id;
    let page = tokio::task::spawn_blocking(move || {
        store.estimates_page(db_id, engine, from_t, to_t, max_points)
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))??;
    let machine_id = machine.spec.id.as_str();
    Ok(axum::Json(HistoryPage {
        machine: machine_id,
        engine,
        from: from_t,
        to: to_t,
        downsampled: page.downsampled,
        estimates: page
            .estimates
            .iter()
            .map(|e| e.for_machine(machine_id))
            .collect(),
    })
    .into_response())
}

/// Every estimate of `engine` in the range, streamed as NDJSON (the live
/// stream's objects) or CSV (a column per field of the first estimate;
/// arrays and objects as JSON in one cell).
fn export_estimates(
    state: &SharedState,
    machine: &crate::machine::MachineHandle,
    engine: StreamKind,
    from_t: f64,
    to_t: f64,
    csv: bool,
) -> Response {
    let (store, db_id, machine_id) = (state.store.clone(), machine.db_id, machine.spec.id.clone());
    let content_type = if csv {
        "text/csv; charset=utf-8"
    } else {
        "application/x-ndjson"
    };
    let body = stream_chunks(move |chunk, send| {
        let mut columns: Option<Vec<String>> = None;
        store.export_estimates(db_id, engine, from_t, to_t, |estimate| {
            let Ok(serde_json::Value::Object(fields)) =
                serde_json::to_value(estimate.for_machine(&machine_id))
            else {
                return true;
            };
            if csv {
                let header = columns.get_or_insert_with(|| {
                    let names: Vec<String> = fields.keys().cloned().collect();
                    chunk.push_str(&names.join(","));
                    chunk.push('\n');
                    names
                });
                let cells: Vec<String> = header
                    .iter()
                    .map(|name| csv_cell(fields.get(name)))
                    .collect();
                chunk.push_str(&cells.join(","));
            } else {
                chunk.push_str(&serde_json::Value::Object(fields).to_string());
            }
            chunk.push('\n');
            send(chunk)
        })
    });
    ([(header::CONTENT_TYPE, content_type)], body).into_response()
}

/// One CSV cell: numbers and booleans as they are, nothing for null,
/// strings, arrays and objects quoted (quotes doubled), a string that
/// could start a formula neutralised ([`super::csv_text`]).
fn csv_cell(value: Option<&serde_json::Value>) -> String {
    use serde_json::Value;
    match value {
        None | Some(Value::Null) => String::new(),
        Some(Value::Number(n)) => n.to_string(),
        Some(Value::Bool(b)) => b.to_string(),
        Some(Value::String(s)) => super::csv_text::text_cell(s, true),
        Some(other) => format!("\"{}\"", other.to_string().replace('"', "\"\"")),
    }
}

/// A streamed body filled by `produce` on a blocking thread: it appends to
/// the chunk and calls `send` after each item, which passes the chunk on
/// once it is full and answers false when the client has gone (stop).
fn stream_chunks(
    produce: impl FnOnce(
        &mut String,
        &mut dyn FnMut(&mut String) -> bool,
    ) -> Result<(), crate::store::StoreError>
    + Send
    + 'static,
) -> Body {
    let (chunks, receiver) = mpsc::channel::<Result<Bytes, std::io::Error>>(4);
    tokio::task::spawn_blocking(move || {
        let mut chunk = String::with_capacity(CHUNK_BYTES + 1024);
        let mut send = |chunk: &mut String| {
            if chunk.len() < CHUNK_BYTES {
                return true;
            }
            let full = std::mem::replace(chunk, String::with_capacity(CHUNK_BYTES + 1024));
            // A closed channel means the client went away: stop reading.
            chunks.blocking_send(Ok(Bytes::from(full))).is_ok()
        };
        let result = produce(&mut chunk, &mut send);
        let last = match result {
            Ok(()) => Ok(Bytes::from(chunk)),
            Err(e) => {
                tracing::error!(error = %e, "export failed");
                Err(std::io::Error::other(e.to_string()))
            }
        };
        let _ = chunks.blocking_send(last);
    });
    Body::from_stream(ReceiverStream::new(receiver))
}

#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct ReadingsQuery {
    /// Only this sensor's readings (default: every sensor's).
    #[param(inline, value_type = Option<SensorKind>)]
    sensor: Option<String>,
    /// Start of the range (default: the earliest).
    #[param(schema_with = query_time)]
    from: Option<String>,
    /// End of the range (default: the latest); not before `from`.
    #[param(schema_with = query_time)]
    to: Option<String>,
    /// `ndjson` (default, the protocol's readings) or `csv`.
    #[param(inline, value_type = Option<ReadingsFormat>)]
    format: Option<String>,
}

/// Columns of the CSV export; a reading fills those of its sensor (a
/// laser's position: `easting_m`, `northing_m` and `height_m`; an
/// advance's strokes and a tail clearance's gaps: one cell each, the
/// numbers separated by spaces).
pub const CSV_HEADER: &str = "t,sensor,pitch_deg,roll_deg,yaw_deg,temp_c,\
accel_x_mps2,accel_y_mps2,accel_z_mps2,gyro_x_dps,gyro_y_dps,gyro_z_dps,\
field_x_ut,field_y_ut,field_z_ut,height_m,distance_m,easting_m,northing_m,\
ring,strokes_mm,key,clearance_mm\n";

fn csv_row(reading: &Reading, out: &mut String) {
    use std::fmt::Write;
    let mut cells: [Option<f64>; 18] = [None; 18];
    let mut strokes: &[f64] = &[];
    let mut key = None;
    let mut gaps: &[f64] = &[];
    match &reading.data {
        SensorData::Laser {
            pitch_deg,
            roll_deg,
            yaw_deg,
            position,
        } => {
            (cells[0], cells[1], cells[2]) = (Some(*pitch_deg), Some(*roll_deg), *yaw_deg);
            if let Some(p) = position {
                (cells[13], cells[15], cells[16]) =
                    (Some(p.height_m), Some(p.easting_m), Some(p.northing_m));
            }
        }
        SensorData::Inclinometer {
            pitch_deg,
            roll_deg,
            temp_c,
        } => {
            (cells[0], cells[1], cells[3]) = (Some(*pitch_deg), Some(*roll_deg), *temp_c);
        }
        SensorData::Imu {
            accel_mps2,
            gyro_dps,
        } => {
            for i in 0..3 {
                cells[4 + i] = Some(accel_mps2[i]);
                cells[7 + i] = Some(gyro_dps[i]);
            }
        }
        SensorData::Magnetometer { field_ut } => {
            for i in 0..3 {
                cells[10 + i] = Some(field_ut[i]);
            }
        }
        SensorData::Level { height_m } => cells[13] = Some(*height_m),
        SensorData::Odometer { distance_m } => cells[14] = Some(*distance_m),
        SensorData::Advance {
            ring,
            strokes_mm,
            key: built,
        } => {
            cells[17] = Some(*ring as f64);
            strokes = strokes_mm.as_deref().unwrap_or_default();
            key = *built;
        }
        SensorData::TailClearance { clearance_mm } => gaps = clearance_mm,
    }
    let _ = write!(out, "{},{}", reading.t, reading.sensor());
    for cell in cells {
        out.push(',');
        if let Some(x) = cell {
            let _ = write!(out, "{x}");
        }
    }
    let joined = |out: &mut String, numbers: &[f64]| {
        out.push(',');
        for (i, x) in numbers.iter().enumerate() {
            let _ = write!(out, "{}{x}", if i > 0 { " " } else { "" });
        }
    };
    joined(out, strokes);
    out.push(',');
    if let Some(key) = key {
        let _ = write!(out, "{key}");
    }
    joined(out, gaps);
    out.push('\n');
}

/// Stored readings.
///
/// `GET /api/v1/machines/{machine}/readings`: streamed from the store in
/// chunks; memory stays bounded whatever the range.
#[utoipa::path(get, path = "/api/v1/machines/{machine}/readings", operation_id = "export_readings", tag = "readings",
    params(MachinePath, ReadingsQuery),
    responses((status = OK, description = "The stored readings in the range, in time order, streamed",
        content((String = "application/x-ndjson"), (String = "text/csv")))))]
pub async fn readings(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    params: Result<Query<ReadingsQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let machine = state.machine(&machine)?;
    let params = query(params)?;
    let sensor = params
        .sensor
        .as_deref()
        .map(|name| {
            SensorKind::from_name(name).ok_or_else(|| {
                ApiError::BadRequest(format!(
                    "unknown sensor `{name}` (expected laser, inclinometer, imu, magnetometer, level or odometer)"
                ))
            })
        })
        .transpose()?;
    let (from_t, to_t) = range(params.from.as_deref(), params.to.as_deref())?;
    let csv = match params.format.as_deref() {
        None | Some("ndjson") => false,
        Some("csv") => true,
        Some(other) => {
            return Err(ApiError::BadRequest(format!(
                "`format` = `{other}`: expected ndjson or csv"
            )));
        }
    };
    let (store, db_id) = (state.store.clone(), machine.db_id);
    let body = stream_chunks(move |chunk, send| {
        if csv {
            chunk.push_str(CSV_HEADER);
        }
        store.export_readings(db_id, sensor, from_t, to_t, |reading| {
            if csv {
                csv_row(reading, chunk);
            } else {
                chunk.push_str(&reading.to_json());
                chunk.push('\n');
            }
            send(chunk)
        })
    });
    let content_type = if csv {
        "text/csv; charset=utf-8"
    } else {
        "application/x-ndjson"
    };
    Ok(([(header::CONTENT_TYPE, content_type)], body).into_response())
}

/// The model endpoint's answer: the engine's report and the machine.
#[derive(Serialize, utoipa::ToSchema)]
struct ModelBody<'a> {
    machine: &'a str,
    #[serde(flatten)]
    #[schema(value_type = super::openapi::EngineModelReport)]
    model: EngineModel,
}

/// `?engine=` of the model endpoint.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct ModelQuery {
    /// The engine (default: the machine's first with a model).
    #[param(inline, value_type = Option<EngineKind>)]
    engine: Option<String>,
}

/// An engine's learned model.
///
/// `GET /api/v1/machines/{machine}/model[?engine=]`: the model report of
/// the named engine, or of the machine's first engine (in registry order)
/// that has one: what it has learned (docs/engines/).
#[utoipa::path(get, path = "/api/v1/machines/{machine}/model", operation_id = "get_model", tag = "estimates",
    params(MachinePath, ModelQuery),
    responses((status = OK, description = "The engine's model report, with `machine`", body = ModelBody),
        (status = NOT_FOUND, description = "No such machine, or it has no engine with a model (of that name)", body = super::error::ErrorBody)))]
pub async fn model(
    State(state): State<SharedState>,
    Path(MachinePath { machine }): Path<MachinePath>,
    params: Result<Query<ModelQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let machine = state.machine(&machine)?;
    let params = query(params)?;
    let mut models = state
        .on_machine(
            &machine.spec.id,
            |machine| async move { machine.models().await },
        )
        .await?;
    let with_model = models
        .keys()
        .map(|engine| engine.as_str())
        .collect::<Vec<_>>()
        .join(", ");
    let engine = match params.engine.as_deref() {
        Some(name) => Some(
            name.parse::<EngineKind>()
                .map_err(|e| ApiError::BadRequest(e.to_string()))?,
        ),
        // The first in registry order.
        None => models.keys().next().copied(),
    };
    let model = engine
        .and_then(|engine| models.remove(&engine))
        .ok_or_else(|| {
            let asked = engine.map_or(String::new(), |e| format!("`{e}` "));
            ApiError::NotFound(format!(
                "machine `{}` has no {asked}engine with a model (engines with one here: {})",
                machine.spec.id,
                if with_model.is_empty() {
                    "none"
                } else {
                    &with_model
                }
            ))
        })?;
    Ok(axum::Json(ModelBody {
        machine: &machine.spec.id,
        model,
    })
    .into_response())
}
