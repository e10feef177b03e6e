//! What the service shows about itself: `GET /healthz` and `GET /metrics`
//! (the counters as recorded, the gauges read now from the fleet and the
//! store).

use crate::fusion::alarms::{AlarmKind, Severity};
use crate::server::state::SharedState;
use crate::store::alarms::AlarmFilter;
use axum::Json;
use axum::extract::State;
use axum::http::header;
use axum::response::IntoResponse;

use super::{
    ALARMS_ACTIVE, LASER_DROPOUT, LAST_READING, LIVE_CLIENTS, MACHINES, STORE_BYTES, handle,
    process,
};

/// The liveness answer.
#[derive(Debug, serde::Serialize, utoipa::ToSchema)]
pub struct Health {
    /// Always `ok`: the server answers.
    pub status: &'static str,
    /// Machines declared.
    pub machines: usize,
}

/// Liveness.
///
/// `GET /healthz`.
#[utoipa::path(get, path = "/healthz", operation_id = "healthz", tag = "service",
    responses((status = OK, description = "The server answers", body = Health)))]
pub async fn healthz(State(state): State<SharedState>) -> Json<Health> {
    Json(Health {
        status: "ok",
        machines: state.all_machines().len(),
    })
}

/// Prometheus metrics.
///
/// `GET /metrics`: the counters as recorded, and the gauges read now.
#[utoipa::path(get, path = "/metrics", operation_id = "metrics", tag = "service",
    responses((status = OK, description = "Prometheus text exposition (docs/api.md, \"Metrics\")", content_type = "text/plain", body = String)))]
pub async fn render(State(state): State<SharedState>) -> impl IntoResponse {
    let now = state.clock.now_s();
    let machines = state.all_machines();
    metrics::gauge!(MACHINES).set(machines.len() as f64);
    for machine in &machines {
        let id = machine.spec.id.clone();
        let status = crate::server::machines::status(machine, now);
        metrics::gauge!(LIVE_CLIENTS, "machine" => id.clone()).set(status.live_clients as f64);
        for (sensor, report) in &status.sensors {
            metrics::gauge!(LAST_READING, "machine" => id.clone(), "sensor" => sensor.as_str())
                .set(report.last_t);
        }
        if let Some(laser) = &status.laser {
            metrics::gauge!(LASER_DROPOUT, "machine" => id.clone()).set(if laser.dropout {
                1.0
            } else {
                0.0
            });
        }
    }
    match state.store.size_bytes().await {
        Ok(bytes) => metrics::gauge!(STORE_BYTES).set(bytes as f64),
        Err(e) => tracing::warn!(error = %e, "store size unknown"),
    }
    set_active_alarms(&state).await;
    process().collect();
    let text = handle().map(|h| h.render()).unwrap_or_default();
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        text,
    )
}

/// Every machine × kind × severity, zero when none is active, so an alert
/// rule sees the series before the first alarm.
async fn set_active_alarms(state: &SharedState) {
    let filter = AlarmFilter {
        machine: None,
        active_only: true,
        ..Default::default()
    };
    let active = match crate::server::alarms::stored(state, filter).await {
        Ok(active) => active,
        Err(e) => {
            tracing::warn!(error = %e, "active alarms not read for /metrics");
            return;
        }
    };
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
