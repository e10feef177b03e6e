//! `/healthz` and `/metrics` (Prometheus text), and the counters the
//! handlers record.

use std::collections::BTreeMap;
use std::sync::OnceLock;
use std::time::Duration;

use axum::Json;
use axum::extract::State;
use axum::http::header;
use axum::response::IntoResponse;
use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusHandle};

use super::SharedState;
use super::error::Rejected;
use crate::fusion::alarms::{AlarmKind, Severity};
use crate::fusion::{Reading, SensorKind};
use crate::store::alarms::AlarmFilter;

const ACCEPTED: &str = "tunnelnav_readings_accepted_total";
const REJECTED: &str = "tunnelnav_readings_rejected_total";
const INGEST_SECONDS: &str = "tunnelnav_ingest_seconds";
const LIVE_CLIENTS: &str = "tunnelnav_live_clients";
const STORE_BYTES: &str = "tunnelnav_store_bytes";
const ALARMS_ACTIVE: &str = "tunnelnav_alarms_active";

/// The process-wide recorder (the `metrics` facade has one global recorder;
/// servers started in one test process share it).
fn handle() -> Option<&'static PrometheusHandle> {
    static HANDLE: OnceLock<Option<PrometheusHandle>> = OnceLock::new();
    HANDLE
        .get_or_init(|| {
            let builder = PrometheusBuilder::new()
                .set_buckets_for_metric(
                    Matcher::Full(INGEST_SECONDS.to_string()),
                    &[
                        0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0,
                    ],
                )
                .ok()?;
            let handle = builder.install_recorder().ok()?;
            metrics::describe_counter!(ACCEPTED, "valid readings stored, per machine and sensor");
            metrics::describe_counter!(REJECTED, "readings refused, per machine and sensor");
            metrics::describe_histogram!(
                INGEST_SECONDS,
                metrics::Unit::Seconds,
                "ingest request time from parsed body to committed"
            );
            metrics::describe_gauge!(LIVE_CLIENTS, "live WebSocket clients per machine");
            metrics::describe_gauge!(STORE_BYTES, metrics::Unit::Bytes, "database and WAL size");
            metrics::describe_gauge!(
                ALARMS_ACTIVE,
                "alarms raised and not cleared, per machine, kind and severity"
            );
            Some(handle)
        })
        .as_ref()
}

/// Installs the recorder (idempotent); call before serving.
pub fn install() {
    let _ = handle();
}

/// Readings per sensor in a batch.
pub fn count_by_sensor(readings: &[Reading]) -> BTreeMap<SensorKind, u64> {
    let mut counts = BTreeMap::new();
    for reading in readings {
        *counts.entry(reading.sensor()).or_insert(0) += 1;
    }
    counts
}

/// Records readings accepted and the time they took to commit.
pub fn accepted(machine: &str, counts: &BTreeMap<SensorKind, u64>, elapsed: Duration) {
    for (sensor, n) in counts {
        metrics::counter!(ACCEPTED, "machine" => machine.to_string(), "sensor" => sensor.as_str())
            .increment(*n);
    }
    metrics::histogram!(INGEST_SECONDS).record(elapsed.as_secs_f64());
}

/// Records refused readings, by the sensor they claimed (`unknown` when
/// none could be read).
pub fn rejected(machine: &str, rejected: &[Rejected]) {
    for refused in rejected {
        let sensor = refused.sensor.map_or("unknown", SensorKind::as_str);
        metrics::counter!(REJECTED, "machine" => machine.to_string(), "sensor" => sensor)
            .increment(1);
    }
}

/// The liveness answer.
#[derive(Debug, serde::Serialize)]
pub struct Health {
    /// Always `ok`: the server answers.
    pub status: &'static str,
    /// Machines declared.
    pub machines: usize,
}

/// `GET /healthz`.
pub async fn healthz(State(state): State<SharedState>) -> Json<Health> {
    Json(Health {
        status: "ok",
        machines: state.all_machines().len(),
    })
}

/// `GET /metrics`.
pub async fn render(State(state): State<SharedState>) -> impl IntoResponse {
    for machine in state.all_machines() {
        metrics::gauge!(LIVE_CLIENTS, "machine" => machine.spec.id.clone())
            .set(machine.live_clients() as f64);
    }
    metrics::gauge!(STORE_BYTES).set(state.store.size_bytes() as f64);
    // Every machine × kind × severity, zero when none is active, so an
    // alert rule sees the series before the first alarm.
    let active = super::alarms::stored(
        &state,
        AlarmFilter {
            machine: None,
            active_only: true,
        },
    )
    .await;
    match active {
        Ok(active) => {
            for machine in state.all_machines() {
                for kind in AlarmKind::ALL {
                    for severity in Severity::ALL {
                        let count = active
                            .iter()
                            .filter(|a| {
                                a.machine == machine.spec.id
                                    && a.kind == kind.as_str()
                                    && a.severity == severity.as_str()
                            })
                            .count();
                        metrics::gauge!(
                            ALARMS_ACTIVE,
                            "machine" => machine.spec.id.clone(),
                            "kind" => kind.as_str(),
                            "severity" => severity.as_str()
                        )
                        .set(count as f64);
                    }
                }
            }
        }
        Err(e) => tracing::warn!(error = %e, "active alarms not read for /metrics"),
    }
    let text = handle().map(|h| h.render()).unwrap_or_default();
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        text,
    )
}
