//! Alarms over HTTP: a machine's rules raise them from its readings and
//! the server clock, `GET /api/v1/alarms` lists them, `POST .../ack`
//! records the acknowledging token's name, and they survive a restart.

mod common;

use common::{TestServer, declare_machine, post_ndjson};
use serde_json::{Value, json};
use tunnelnav::clock::wall_clock_s;

/// An attitude machine on a straight axis due north from (1000, 5000),
/// level at 50 m, ±50/100 mm horizontal tolerances.
fn declaration() -> Value {
    json!({
        "name": "TBM alarms",
        "engines": {"attitude": {}},
        "geometry": {"front_m": [4.0, 0.0, 0.0], "rear_m": [-5.0, 0.0, 0.0]},
        "tolerances": {"horizontal_mm": {"warn": 50, "alarm": 100},
                       "vertical_mm": {"warn": 30, "alarm": 60}},
        "alignment": {"name": "straight", "start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 0.0},
                      "horizontal": [{"type": "line", "length_m": 100.0}],
                      "vertical": {"start_height_m": 50.0, "end_grade_pct": 0.0}}
    })
}

/// Laser readings every 2 s from `from_t`, `count` of them, the machine
/// 70 mm right of the axis (beyond the 50 mm warn limit), each followed by
/// an inclinometer reading a second later.
fn off_axis(from_t: f64, count: u32) -> Vec<String> {
    (0..count)
        .flat_map(|i| {
            let t = from_t + 2.0 * f64::from(i);
            [
                json!({"t": t, "sensor": "laser",
                       "pitch_deg": 0.0, "roll_deg": 0.0, "yaw_deg": 0.0,
                       "easting_m": 1000.07, "northing_m": 5020.0, "height_m": 50.0}),
                json!({"t": t + 1.0, "sensor": "inclinometer", "pitch_deg": 0.0, "roll_deg": 0.0}),
            ]
        })
        .map(|reading| reading.to_string())
        .collect()
}

async fn alarms(
    client: &reqwest::Client,
    base: &str,
    query: &str,
    token: Option<&str>,
) -> Vec<Value> {
    let mut request = client.get(format!("{base}/api/v1/alarms{query}"));
    if let Some(token) = token {
        request = request.bearer_auth(token);
    }
    let response = request.send().await.unwrap();
    assert_eq!(response.status(), 200);
    let body: Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
    body["alarms"].as_array().unwrap().clone()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn alarms_are_raised_listed_acknowledged_by_name_and_kept_across_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    declare_machine(&client, &base, "tbm-alarms", &declaration().to_string()).await;

    // 40 s off the axis, ending 20 s ago: a deviation warning (held over
    // the 10 s minimum) and, as the inclinometer's 2 s period times 5 has
    // passed since its last reading, a stale inclinometer.
    let from_t = (wall_clock_s() - 60.0).floor();
    post_ndjson(&client, &base, "tbm-alarms", &off_axis(from_t, 21)).await;
    let mut listed = Vec::new();
    for _ in 0..50 {
        listed = alarms(&client, &base, "", None).await;
        if listed.len() >= 2 {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    let kinds: Vec<(&str, &str, &str)> = listed
        .iter()
        .map(|a| {
            (
                a["kind"].as_str().unwrap(),
                a["severity"].as_str().unwrap(),
                a["subject"].as_str().unwrap(),
            )
        })
        .collect();
    assert!(kinds.contains(&("deviation", "warn", "")), "{listed:?}");
    assert!(
        kinds.contains(&("stale_sensor", "alarm", "inclinometer")),
        "{listed:?}"
    );
    assert_eq!(listed.len(), 2, "each raised once: {listed:?}");
    let deviation = listed
        .iter()
        .find(|a| a["kind"] == "deviation")
        .unwrap()
        .clone();
    assert_eq!(deviation["machine"], "tbm-alarms");
    assert_eq!(deviation["raised_t"], from_t);
    assert!(deviation["cleared_t"].is_null() && deviation["acked_by"].is_null());
    assert!(
        deviation["message"]
            .as_str()
            .unwrap()
            .contains("horizontal +70 mm (±50 mm)"),
        "{deviation}"
    );
    // The Prometheus gauge counts them.
    let metrics = common::get_text(&client, &base, "/metrics").await;
    for series in [
        r#"tunnelnav_alarms_active{machine="tbm-alarms",kind="deviation",severity="warn"} 1"#,
        r#"tunnelnav_alarms_active{machine="tbm-alarms",kind="stale_sensor",severity="alarm"} 1"#,
        r#"tunnelnav_alarms_active{machine="tbm-alarms",kind="deviation",severity="alarm"} 0"#,
    ] {
        assert!(metrics.contains(series), "{series} missing:\n{metrics}");
    }
    // Filters and refusals.
    assert_eq!(
        alarms(&client, &base, "?machine=tbm-alarms&state=all", None)
            .await
            .len(),
        2
    );
    let bad = client
        .get(format!("{base}/api/v1/alarms?state=some"))
        .send()
        .await
        .unwrap();
    assert_eq!(bad.status(), 400);
    let unknown = client
        .get(format!("{base}/api/v1/alarms?machine=nope"))
        .send()
        .await
        .unwrap();
    assert_eq!(unknown.status(), 404);

    // A read token changes nothing; an operator token acknowledges it:
    // its name is recorded.
    let reader = common::read_token(dir.path(), "visitor");
    let token = common::operator_token(dir.path(), "shift-lead");
    tokio::time::sleep(std::time::Duration::from_millis(2100)).await;
    let url = format!("{base}/api/v1/alarms/{}/ack", deviation["id"]);
    let refused = client.post(&url).send().await.unwrap();
    assert_eq!(refused.status(), 401, "a token is now required");
    let read_only = client.post(&url).bearer_auth(&reader).send().await.unwrap();
    assert_eq!(read_only.status(), 403);
    let why = read_only.text().await.unwrap();
    assert!(why.contains("operator scope needed"), "{why}");
    let acked = client.post(&url).bearer_auth(&token).send().await.unwrap();
    assert_eq!(acked.status(), 200);
    let acked: Value = serde_json::from_slice(&acked.bytes().await.unwrap()).unwrap();
    assert_eq!(acked["acked_by"], "shift-lead");
    assert!(acked["acked_t"].as_f64().unwrap() > from_t);
    let missing = client
        .post(format!("{base}/api/v1/alarms/99999/ack"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    assert_eq!(missing.status(), 404);
    server.stop().await;

    // After a restart: the same two alarms, the acknowledgement kept, no
    // alarm raised twice by the readings fed again.
    let server = TestServer::start(dir.path()).await;
    let base = server.url("");
    tokio::time::sleep(std::time::Duration::from_millis(1500)).await;
    let after = alarms(&client, &base, "?state=all", Some(&token)).await;
    assert_eq!(after.len(), 2, "{after:?}");
    let kept = after.iter().find(|a| a["kind"] == "deviation").unwrap();
    assert_eq!(kept["acked_by"], "shift-lead");
    let status = get_json_with(&client, &base, "/api/v1/machines/tbm-alarms", &token).await;
    assert_eq!(status["machine"], "tbm-alarms");
    server.stop().await;
}

/// A server's own downtime is not a sensor's silence: an inclinometer that
/// read every second until the server stopped is not stale the moment the
/// server is back 10 s later (it was raised and cleared within
/// milliseconds before), only once it has been silent 10 s of the new
/// run; and then it is.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restart_is_not_a_sensors_silence() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    declare_machine(&client, &base, "tbm-down", &declaration().to_string()).await;
    let last_t = wall_clock_s().floor() - 2.0;
    let readings: Vec<String> = (0..8)
        .map(|i| {
            json!({"t": last_t - f64::from(7 - i), "sensor": "inclinometer",
                   "pitch_deg": 0.0, "roll_deg": 0.0})
            .to_string()
        })
        .collect();
    post_ndjson(&client, &base, "tbm-down", &readings).await;
    server.stop().await;
    tokio::time::sleep(std::time::Duration::from_secs(10)).await;

    let server = TestServer::start(dir.path()).await;
    let base = server.url("");
    let restarted_t = wall_clock_s();
    assert!(restarted_t - last_t > 11.0);
    tokio::time::sleep(std::time::Duration::from_secs(3)).await;
    let early = alarms(&client, &base, "?state=all", None).await;
    assert!(early.is_empty(), "raised at the restart: {early:?}");
    let mut stale = Vec::new();
    for _ in 0..100 {
        stale = alarms(&client, &base, "?state=all", None).await;
        if !stale.is_empty() {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    }
    assert_eq!(stale.len(), 1, "{stale:?}");
    assert_eq!(stale[0]["kind"], "stale_sensor");
    assert!(stale[0]["cleared_t"].is_null());
    let raised_t = stale[0]["raised_t"].as_f64().unwrap();
    assert!(
        raised_t >= restarted_t + 9.0,
        "raised {raised_t}, restarted {restarted_t}"
    );
    server.stop().await;
}

async fn get_json_with(client: &reqwest::Client, base: &str, path: &str, token: &str) -> Value {
    let response = client
        .get(format!("{base}{path}"))
        .bearer_auth(token)
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200, "{path}");
    serde_json::from_slice(&response.bytes().await.unwrap()).unwrap()
}

/// What the local webhook receiver saw: each request's path,
/// `Idempotency-Key` and body, and how many it refused so far.
#[derive(Default)]
struct Received {
    requests: Vec<(String, String, Value)>,
    refused: usize,
    /// Refuse every request while set (a receiver that is down).
    down: bool,
}

/// A webhook receiver on a free port that answers 500 to the first
/// `refuse` requests, then 200.
async fn receiver(
    refuse: usize,
) -> (
    String,
    std::sync::Arc<std::sync::Mutex<Received>>,
    tokio::task::JoinHandle<()>,
) {
    use axum::http::{HeaderMap, StatusCode, Uri};
    let seen = std::sync::Arc::new(std::sync::Mutex::new(Received::default()));
    let state = seen.clone();
    let app = axum::Router::new().fallback(
        move |uri: Uri, headers: HeaderMap, body: axum::body::Bytes| {
            let state = state.clone();
            async move {
                let mut seen = state.lock().unwrap();
                if seen.down || seen.refused < refuse {
                    seen.refused += 1;
                    return StatusCode::INTERNAL_SERVER_ERROR;
                }
                let key = headers
                    .get("idempotency-key")
                    .and_then(|v| v.to_str().ok())
                    .unwrap_or_default()
                    .to_string();
                let body: Value = serde_json::from_slice(&body).unwrap_or(Value::Null);
                seen.requests.push((uri.path().to_string(), key, body));
                StatusCode::OK
            }
        },
    );
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap();
    let task = tokio::spawn(async move {
        axum::serve(listener, app).await.unwrap();
    });
    (format!("http://{address}"), seen, task)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn webhooks_get_each_transition_once_per_severity_retried_after_a_500() {
    let (hooks, seen, receiving) = receiver(1).await;
    let dir = tempfile::tempdir().unwrap();
    let webhooks = tunnelnav::server::settings::WebhookConfig {
        warn: Some(format!("{hooks}/warn")),
        alarm: Some(format!("{hooks}/alarm")),
        first_retry_s: 0.2,
        ..Default::default()
    };
    let server = common::TestServer::start_configured(
        dir.path(),
        tunnelnav::server::settings::Limits::default(),
        webhooks,
    )
    .await;
    let client = reqwest::Client::new();
    let base = server.url("");
    declare_machine(&client, &base, "tbm-hooks", &declaration().to_string()).await;

    // A deviation warning and a stale inclinometer (an alarm), as above.
    let from_t = (wall_clock_s() - 60.0).floor();
    post_ndjson(&client, &base, "tbm-hooks", &off_axis(from_t, 21)).await;
    let wait_for = |n: usize| {
        let seen = seen.clone();
        async move {
            for _ in 0..100 {
                if seen.lock().unwrap().requests.len() >= n {
                    return;
                }
                tokio::time::sleep(std::time::Duration::from_millis(100)).await;
            }
            panic!("fewer than {n} webhook deliveries");
        }
    };
    wait_for(2).await;
    let listed = alarms(&client, &base, "", None).await;
    let deviation = listed.iter().find(|a| a["kind"] == "deviation").unwrap();
    // Acknowledged twice: one more delivery.
    for _ in 0..2 {
        let url = format!("{base}/api/v1/alarms/{}/ack", deviation["id"]);
        assert_eq!(client.post(&url).send().await.unwrap().status(), 200);
    }
    wait_for(3).await;
    // Back on the axis: the deviation clears (a fourth delivery).
    let on_axis: Vec<String> = (0..12)
        .map(|i| {
            json!({"t": from_t + 60.0 + 2.0 * f64::from(i), "sensor": "laser",
                   "pitch_deg": 0.0, "roll_deg": 0.0, "yaw_deg": 0.0,
                   "easting_m": 1000.0, "northing_m": 5020.0, "height_m": 50.0})
            .to_string()
        })
        .collect();
    post_ndjson(&client, &base, "tbm-hooks", &on_axis).await;
    wait_for(4).await;
    // Nothing more comes (no delivery twice).
    tokio::time::sleep(std::time::Duration::from_millis(1500)).await;
    let seen = std::mem::take(&mut *seen.lock().unwrap());
    assert_eq!(
        seen.refused, 1,
        "the first attempt was refused, then retried"
    );
    // In order per URL: the warn URL got raise, acknowledgement, clear.
    let warn_order: Vec<&str> = seen
        .requests
        .iter()
        .filter(|(path, _, _)| path == "/warn")
        .map(|(_, _, body)| body["transition"].as_str().unwrap_or_default())
        .collect();
    assert_eq!(warn_order, ["raised", "acknowledged", "cleared"]);
    let mut got: Vec<(String, String, String, String)> = seen
        .requests
        .iter()
        .map(|(path, key, body)| {
            (
                path.clone(),
                body["kind"].as_str().unwrap_or_default().to_string(),
                body["transition"].as_str().unwrap_or_default().to_string(),
                key.clone(),
            )
        })
        .collect();
    got.sort();
    let id = |kind: &str| listed.iter().find(|a| a["kind"] == kind).unwrap()["id"].clone();
    assert_eq!(
        got,
        [
            (
                "/alarm".to_string(),
                "stale_sensor".to_string(),
                "raised".to_string(),
                format!("alarm-{}-raised", id("stale_sensor"))
            ),
            (
                "/warn".into(),
                "deviation".into(),
                "acknowledged".into(),
                format!("alarm-{}-acknowledged", id("deviation"))
            ),
            (
                "/warn".into(),
                "deviation".into(),
                "cleared".into(),
                format!("alarm-{}-cleared", id("deviation"))
            ),
            (
                "/warn".into(),
                "deviation".into(),
                "raised".into(),
                format!("alarm-{}-raised", id("deviation"))
            ),
        ],
        "{:#?}",
        seen.requests
    );
    let cleared = seen
        .requests
        .iter()
        .find(|(_, key, _)| key.ends_with("cleared"))
        .unwrap();
    assert_eq!(cleared.2["machine"], "tbm-hooks");
    assert_eq!(cleared.2["acked_by"], "anonymous");
    assert!(cleared.2["cleared_t"].as_f64().unwrap() >= from_t + 60.0);
    server.stop().await;
    receiving.abort();
}

/// Issue 38: a webhook change not delivered when the server is SIGKILLed
/// (its receiver refusing) is posted after the restart, once, with the
/// same idempotency key: the change waits in the store's outbox, not in
/// memory.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_webhook_pending_at_sigkill_is_delivered_once_after_the_restart() {
    pending_at_sigkill(&[]).await;
}

/// The same on the PostgreSQL store: the node that made the change posts
/// it once it runs again under its name.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_webhook_pending_at_sigkill_on_postgres_is_delivered_once_after_the_restart() {
    let Some(cluster) = common::postgres::PgCluster::start() else {
        return;
    };
    let url = cluster.database("hooks");
    pending_at_sigkill(&["--store", &url, "--node", "hooks-1"]).await;
}

/// A webhook change pending when a server started with `args` is
/// SIGKILLed is posted once after the restart, with its key.
async fn pending_at_sigkill(args: &[&str]) {
    // Down until the server has been killed.
    let (hooks, seen, receiving) = receiver(0).await;
    seen.lock().unwrap().down = true;
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("tunnelnav.toml");
    std::fs::write(
        &config,
        format!("[webhooks]\nwarn = \"{hooks}/warn\"\nfirst_retry_s = 0.2\nmax_retry_s = 0.5\n"),
    )
    .unwrap();
    let config = config.to_str().unwrap().to_string();
    let data = dir.path().join("data");
    let mut with_config = vec!["--config", config.as_str()];
    with_config.extend_from_slice(args);
    let server = common::ServerProcess::start_with_args(&data, &with_config);
    let client = reqwest::Client::new();
    let base = server.url("");
    declare_machine(&client, &base, "tbm-outbox", &declaration().to_string()).await;
    let from_t = (wall_clock_s() - 60.0).floor();
    post_ndjson(&client, &base, "tbm-outbox", &off_axis(from_t, 21)).await;
    // Attempted (and refused) at least once: the change is pending.
    for _ in 0..100 {
        if seen.lock().unwrap().refused >= 1 {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    assert!(
        seen.lock().unwrap().refused >= 1,
        "the webhook was attempted"
    );
    server.kill();
    assert!(seen.lock().unwrap().requests.is_empty());
    // The receiver is back; so is the server.
    seen.lock().unwrap().down = false;
    let server = common::ServerProcess::start_with_args(&data, &with_config);
    let base = server.url("");
    for _ in 0..100 {
        if !seen.lock().unwrap().requests.is_empty() {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    // Nothing more comes.
    tokio::time::sleep(std::time::Duration::from_millis(1500)).await;
    let listed = alarms(&client, &base, "?state=all", None).await;
    let deviation = listed.iter().find(|a| a["kind"] == "deviation").unwrap();
    let requests = seen.lock().unwrap().requests.clone();
    assert_eq!(requests.len(), 1, "{requests:#?}");
    assert_eq!(requests[0].0, "/warn");
    assert_eq!(
        requests[0].1,
        format!("alarm-{}-raised", deviation["id"]),
        "the idempotency key of the change before the kill"
    );
    assert_eq!(requests[0].2["transition"], "raised");
    server.kill();
    receiving.abort();
}
