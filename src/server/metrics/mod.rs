//! The series the service records (the handlers count, the response
//! middleware counts every answer and refusal); [`serve`] shows them at
//! `/metrics`, with `/healthz`. Names follow Prometheus conventions (base
//! units, `_total` for counters, `_seconds`, `_bytes`); every series that
//! can be known at start is registered then, at zero, so alert rules see
//! it before its first event. The list is documented in `docs/api.md`
//! ("Metrics") and checked against a fresh server by `tests/metrics.rs`.

use std::collections::BTreeMap;
use std::sync::OnceLock;
use std::time::Duration;

use axum::extract::{MatchedPath, Request};
use axum::middleware::Next;
use axum::response::Response;
use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusHandle};

use super::error::{Refusal, Rejected};
use crate::config::MachineSpec;
use crate::fusion::descriptor::SignalKind;
use crate::fusion::{Reading, SensorKind};

pub mod serve;

const ACCEPTED: &str = "tunnelnav_readings_accepted_total";
const REJECTED: &str = "tunnelnav_readings_rejected_total";
const INGEST_DURATION: &str = "tunnelnav_ingest_duration_seconds";
const LIVE_CLIENTS: &str = "tunnelnav_live_clients";
const STORE_BYTES: &str = "tunnelnav_store_bytes";
const ALARMS_ACTIVE: &str = "tunnelnav_alarms_active";
const BUILD_INFO: &str = "tunnelnav_build_info";
const REFUSALS: &str = "tunnelnav_refusals_total";
const HTTP_RESPONSES: &str = "tunnelnav_http_responses_total";
const LAST_READING: &str = "tunnelnav_last_reading_timestamp_seconds";
const LASER_DROPOUT: &str = "tunnelnav_laser_dropout";
const MACHINES: &str = "tunnelnav_machines";
const MQTT_MESSAGES: &str = "tunnelnav_mqtt_messages_total";
const MQTT_CONNECTED: &str = "tunnelnav_mqtt_connected";
const MQTT_RECONNECTS: &str = "tunnelnav_mqtt_reconnects_total";
const FORWARD_BACKLOG: &str = "tunnelnav_forward_backlog";
const FORWARD_OLDEST_UNSENT: &str = "tunnelnav_forward_oldest_unsent_seconds";
const FORWARD_CONNECTED: &str = "tunnelnav_forward_connected";
/// What becomes of an MQTT readings message.
const MQTT_OUTCOMES: [&str; 4] = ["received", "acknowledged", "rejected", "refused"];

/// The process-wide recorder (the `metrics` facade has one global recorder;
/// servers started in one test process share it).
fn handle() -> Option<&'static PrometheusHandle> {
    static HANDLE: OnceLock<Option<PrometheusHandle>> = OnceLock::new();
    HANDLE
        .get_or_init(|| {
            let builder = PrometheusBuilder::new()
                .set_buckets_for_metric(
                    Matcher::Full(INGEST_DURATION.to_string()),
                    &[
                        0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0,
                    ],
                )
                .ok()?;
            let handle = builder.install_recorder().ok()?;
            describe();
            Some(handle)
        })
        .as_ref()
}

/// The process's CPU, memory, file descriptors and threads
/// (`process_*`, as Prometheus's own client libraries name them).
fn process() -> &'static metrics_process::Collector {
    static COLLECTOR: OnceLock<metrics_process::Collector> = OnceLock::new();
    COLLECTOR.get_or_init(metrics_process::Collector::default)
}

fn describe() {
    use metrics::Unit;
    metrics::describe_counter!(ACCEPTED, "valid readings stored, per machine and sensor");
    metrics::describe_counter!(
        REJECTED,
        "readings refused as invalid, per machine and sensor"
    );
    metrics::describe_histogram!(
        INGEST_DURATION,
        Unit::Seconds,
        "ingest request time from parsed body to committed"
    );
    metrics::describe_gauge!(LIVE_CLIENTS, "live WebSocket clients per machine");
    metrics::describe_gauge!(STORE_BYTES, Unit::Bytes, "database and WAL size");
    metrics::describe_gauge!(
        ALARMS_ACTIVE,
        "alarms raised and not cleared, per machine, kind and severity"
    );
    metrics::describe_gauge!(BUILD_INFO, "always 1; the running release in `version`");
    metrics::describe_counter!(REFUSALS, "requests answered 503 (retry later), per reason");
    metrics::describe_counter!(
        HTTP_RESPONSES,
        "HTTP responses per declared route, method and status"
    );
    metrics::describe_gauge!(
        LAST_READING,
        Unit::Seconds,
        "Unix time of the newest reading per machine and sensor (reading time)"
    );
    metrics::describe_gauge!(
        LASER_DROPOUT,
        "1 while the machine's laser is in dropout (machines whose engines read the laser)"
    );
    metrics::describe_gauge!(MACHINES, "machines declared");
    metrics::describe_counter!(
        MQTT_MESSAGES,
        "MQTT readings messages: received, acknowledged once stored, rejected (answered with an error and acknowledged), refused for now (store or machine queue full: not acknowledged, retried)"
    );
    metrics::describe_gauge!(MQTT_CONNECTED, "1 while connected to the MQTT broker");
    metrics::describe_counter!(
        MQTT_RECONNECTS,
        "times the MQTT broker could not be reached or the connection was lost"
    );
    metrics::describe_gauge!(
        FORWARD_BACKLOG,
        "readings a site has not sent its office yet, per site (on the site: its own; on the office: as each site last reported)"
    );
    metrics::describe_gauge!(
        FORWARD_OLDEST_UNSENT,
        Unit::Seconds,
        "age of the oldest row a site has not sent its office, per site (on the office, while a site is silent: at least the time since its last contact)"
    );
    metrics::describe_gauge!(
        FORWARD_CONNECTED,
        "1 while a site's link to its office works, per site"
    );
    for outcome in MQTT_OUTCOMES {
        metrics::counter!(MQTT_MESSAGES, "outcome" => outcome).absolute(0);
    }
    metrics::gauge!(MQTT_CONNECTED).set(0.0);
    metrics::counter!(MQTT_RECONNECTS).absolute(0);
    metrics::gauge!(BUILD_INFO, "version" => env!("CARGO_PKG_VERSION")).set(1.0);
    for reason in Refusal::ALL {
        metrics::counter!(REFUSALS, "reason" => reason.as_str()).absolute(0);
    }
    // An empty histogram is rendered too.
    let _ = metrics::histogram!(INGEST_DURATION);
    process().describe();
}

/// One MQTT readings message's `outcome` (one of [`MQTT_OUTCOMES`]).
pub fn mqtt_message(outcome: &'static str) {
    metrics::counter!(MQTT_MESSAGES, "outcome" => outcome).increment(1);
}

/// Whether the MQTT broker is connected.
pub fn mqtt_connected(connected: bool) {
    metrics::gauge!(MQTT_CONNECTED).set(if connected { 1.0 } else { 0.0 });
}

/// The MQTT broker was lost or could not be reached.
pub fn mqtt_reconnect() {
    metrics::counter!(MQTT_RECONNECTS).increment(1);
}

/// A site's link to its office: whether it works, the readings not sent
/// and the age of the oldest row not sent.
pub fn forward_link(site: &str, connected: bool, backlog_readings: u64, oldest_unsent_s: f64) {
    forward_connected(site, connected);
    forward_backlog(site, backlog_readings, oldest_unsent_s);
}

/// A site's backlog: the readings not sent and the age of the oldest row
/// not sent.
pub fn forward_backlog(site: &str, backlog_readings: u64, oldest_unsent_s: f64) {
    metrics::gauge!(FORWARD_BACKLOG, "site" => site.to_string()).set(backlog_readings as f64);
    metrics::gauge!(FORWARD_OLDEST_UNSENT, "site" => site.to_string()).set(oldest_unsent_s);
}

/// Whether a site's link to its office works.
pub fn forward_connected(site: &str, connected: bool) {
    metrics::gauge!(FORWARD_CONNECTED, "site" => site.to_string()).set(if connected {
        1.0
    } else {
        0.0
    });
}

/// Installs the recorder (idempotent); call before serving.
pub fn install() {
    let _ = handle();
}

/// Registers a machine's series at zero (at start and when declared): its
/// readings accepted and rejected and its newest reading's time per
/// sensor its engines use, its live clients and laser dropout (its alarms:
/// see [`serve::render`]).
pub fn register_machine(spec: &MachineSpec) {
    let machine = spec.id.clone();
    let mut sensors: Vec<SensorKind> = spec
        .engines
        .keys()
        .flat_map(|engine| engine.sensors().iter().copied())
        .collect();
    sensors.sort();
    sensors.dedup();
    for sensor in sensors {
        for name in [ACCEPTED, REJECTED] {
            metrics::counter!(name, "machine" => machine.clone(), "sensor" => sensor.as_str())
                .increment(0);
        }
        // 0 until the sensor's first reading: "never", older than any.
        metrics::gauge!(LAST_READING, "machine" => machine.clone(), "sensor" => sensor.as_str())
            .increment(0.0);
    }
    metrics::gauge!(LIVE_CLIENTS, "machine" => machine.clone()).increment(0.0);
    if spec
        .streams()
        .iter()
        .any(|stream| stream.signals().contains(&SignalKind::Laser))
    {
        metrics::gauge!(LASER_DROPOUT, "machine" => machine).increment(0.0);
    }
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
    metrics::histogram!(INGEST_DURATION).record(elapsed.as_secs_f64());
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

/// Records a request answered 503.
fn refused(reason: Refusal) {
    metrics::counter!(REFUSALS, "reason" => reason.as_str()).increment(1);
}

/// Middleware (inside the router, so the route is known): counts every
/// response by declared route, method and status, and each refusal (a
/// 503, its [`Refusal`] carried in the response's extensions) by reason.
pub async fn count_responses(request: Request, next: Next) -> Response {
    let route = request
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_string(), |m| m.as_str().to_string());
    let method = request.method().to_string();
    let response = next.run(request).await;
    if let Some(reason) = response.extensions().get::<Refusal>() {
        refused(*reason);
    }
    metrics::counter!(
        HTTP_RESPONSES,
        "route" => route,
        "method" => method,
        "status" => response.status().as_u16().to_string()
    )
    .increment(1);
    response
}
