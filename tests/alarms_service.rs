//! Alarms over HTTP: a machine's rules raise them from its readings and
//! the server clock, `GET /api/v1/alarms` lists them, `POST .../ack`
//! records the acknowledging token's name, and they survive a restart.

mod common;

use common::{TestServer, declare_machine, post_ndjson};
use serde_json::{Value, json};
use tunnelnav::server::wall_clock_s;

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
/// 70 mm right of the axis (beyond the 50 mm warn limit).
fn off_axis(from_t: f64, count: u32) -> Vec<String> {
    (0..count)
        .map(|i| {
            json!({"t": from_t + 2.0 * f64::from(i), "sensor": "laser",
                   "pitch_deg": 0.0, "roll_deg": 0.0, "yaw_deg": 0.0,
                   "easting_m": 1000.07, "northing_m": 5020.0, "height_m": 50.0})
            .to_string()
        })
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
    // the 10 s minimum) and, as the laser's 2 s period times 5 has passed
    // since its last reading, a stale laser.
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
        kinds.contains(&("stale_sensor", "alarm", "laser")),
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
            .contains("+70 mm beyond ±50 mm"),
        "{deviation}"
    );
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

    // A read token acknowledges it: its name is recorded.
    let token = {
        let conn = tunnelnav::store::Store::connect(dir.path()).unwrap();
        tunnelnav::auth::create(
            &conn,
            "shift-lead",
            tunnelnav::auth::Scope::Read,
            None,
            wall_clock_s(),
        )
        .unwrap()
        .1
    };
    tokio::time::sleep(std::time::Duration::from_millis(2100)).await;
    let url = format!("{base}/api/v1/alarms/{}/ack", deviation["id"]);
    let refused = client.post(&url).send().await.unwrap();
    assert_eq!(refused.status(), 401, "a token is now required");
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
