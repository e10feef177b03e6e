//! A `fuzzy` machine served: IMU and magnetometer readings ingested over
//! HTTP give the same estimates as `replay`, one per IMU reading, and a
//! restart (in the middle of the magnetometer's calibration turn)
//! continues exactly where the engine stood.

mod common;

use common::{TestServer, all_estimates, declare_machine, post_ndjson, replay_engine};
use serde_json::json;
use tunnelnav::sim::vehicle::{VehicleDrive, VehicleScenario};

const MACHINE: &str = "van-1";
const PARAMS: [&str; 1] = ["declination_deg=2.5"];

/// The first `seconds` of the simulated vehicle drive, as NDJSON lines.
fn vehicle(seconds: f64) -> Vec<String> {
    let drive = VehicleDrive::new(VehicleScenario::default()).unwrap();
    let start = drive.scenario().start_t;
    drive
        .take_while(|e| e.reading.t < start + seconds)
        .map(|e| e.reading.to_json())
        .collect()
}

async fn post_all(client: &reqwest::Client, base: &str, lines: &[String]) {
    for chunk in lines.chunks(2500) {
        let ack = post_ndjson(client, base, MACHINE, chunk).await;
        assert_eq!(ack["accepted"], chunk.len(), "{ack}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn served_estimates_match_replay_across_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let lines = vehicle(150.0);
    let (first, second) = lines.split_at(lines.len() / 2);

    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let body = json!({
        "name": "Service vehicle",
        "engines": {"fuzzy": {"declination_deg": 2.5}}
    });
    declare_machine(&client, &base, MACHINE, &body.to_string()).await;
    post_all(&client, &base, first).await;
    server.stop().await;

    let server = TestServer::start(dir.path()).await;
    let base = server.url("");
    post_all(&client, &base, second).await;
    let served = all_estimates(&client, &base, MACHINE).await;
    let model: serde_json::Value =
        common::get_json(&client, &base, &format!("/api/v1/machines/{MACHINE}/model")).await;
    for (query, status) in [
        ("engine=zupt", 404),
        ("engine=nope", 400),
        ("engine=fuzzy", 200),
    ] {
        let response = client
            .get(format!("{base}/api/v1/machines/{MACHINE}/model?{query}"))
            .send()
            .await
            .unwrap();
        assert_eq!(response.status(), status, "{query}");
    }
    server.stop().await;

    let imu = lines.iter().filter(|l| l.contains("\"imu\"")).count();
    assert_eq!(served.len(), imu);
    let replayed = replay_engine(MACHINE, "fuzzy", &PARAMS, &lines);
    assert_eq!(replayed.len(), imu);
    for (i, (s, r)) in served.iter().zip(&replayed).enumerate() {
        assert_eq!(s, r, "estimate {i}");
    }
    let last = served.last().unwrap();
    assert_eq!(last["aligned"], true);
    assert_eq!(last["mag_calibration"], "planar", "{last}");
    assert!(served.iter().any(|e| e["motion"] == "moving"));
    assert!(served.iter().any(|e| e["motion"] == "static"));
    assert_eq!(model["mag_calibration"], "planar", "{model}");
    assert!(model["hard_iron_ut"].is_array(), "{model}");
}
