//! A `zupt` machine served: IMU, level and odometer readings ingested over
//! HTTP give the same estimates as `replay`, one per IMU reading (each made
//! once its zero-velocity decision is known), and a restart continues
//! exactly where the engine stood, its held readings included.

mod common;

use common::{
    TestServer, all_estimates, declare_machine, post_ndjson, replay_engine, replay_streams,
    stream_estimates,
};
use serde_json::{Value, json};
use tunnelnav::sim::pipejack::{PipeJackDrive, PipeJackScenario};

const MACHINE: &str = "pj-ins-1";
const PARAMS: [&str; 2] = ["latitude_deg=30", "initial_yaw_deg=30"];

/// The first `seconds` of the simulated trolley run, as NDJSON lines.
fn trolley(seconds: f64) -> Vec<String> {
    let drive = PipeJackDrive::new(PipeJackScenario::default()).unwrap();
    let start = drive.scenario().start_t;
    drive
        .take_while(|e| e.reading.t < start + seconds)
        .map(|e| e.reading.to_json())
        .collect()
}

async fn declare(client: &reqwest::Client, base: &str) {
    let body = json!({
        "name": "Pipe jacking, FOG INS",
        "engines": {"zupt": {"latitude_deg": 30, "initial_yaw_deg": 30}}
    });
    declare_machine(client, base, MACHINE, &body.to_string()).await;
}

async fn post_all(client: &reqwest::Client, base: &str, lines: &[String]) {
    for chunk in lines.chunks(2500) {
        let ack = post_ndjson(client, base, MACHINE, chunk).await;
        assert_eq!(ack["accepted"], chunk.len(), "{ack}");
    }
}

fn imu_count(lines: &[String]) -> usize {
    lines.iter().filter(|l| l.contains("\"imu\"")).count()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn served_estimates_match_replay_across_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let lines = trolley(150.0);
    let (first, second) = lines.split_at(lines.len() / 2);

    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    declare(&client, &base).await;
    post_all(&client, &base, first).await;
    let status: Value =
        common::get_json(&client, &base, &format!("/api/v1/machines/{MACHINE}")).await;
    assert_eq!(status["latest"]["zupt"]["engine"], "zupt", "{status}");
    server.stop().await;

    let server = TestServer::start(dir.path()).await;
    let base = server.url("");
    post_all(&client, &base, second).await;
    let served = all_estimates(&client, &base, MACHINE).await;
    let served_pushes = stream_estimates(&client, &base, MACHINE, "pushes").await;
    server.stop().await;

    // Served: every IMU reading but the last few seconds, still held by
    // the zero-velocity decision (and the reorder buffer).
    let imu = imu_count(&lines);
    assert!(
        served.len() < imu && served.len() + 1500 >= imu,
        "{} of {imu}",
        served.len()
    );
    // Replay flushes at the end of its input, so it has them all; the
    // served ones are its prefix, value for value.
    let replayed = replay_engine(MACHINE, "zupt", &PARAMS, &lines);
    assert_eq!(replayed.len(), imu);
    for (i, (s, r)) in served.iter().zip(&replayed).enumerate() {
        assert_eq!(s, r, "estimate {i}");
    }
    // The jacking log after the engine: the same records as replay's
    // (which has closed the last push too), each a stroke.
    let replayed_pushes: Vec<Value> = replay_streams(MACHINE, "zupt", &PARAMS, &lines)
        .into_iter()
        .filter(|e| e["engine"] == "pushes")
        .collect();
    let logged = served_pushes.len();
    assert!(logged >= 2, "{logged} pushes logged");
    assert_eq!(served_pushes[..], replayed_pushes[..logged]);
    for (i, push) in served_pushes.iter().enumerate() {
        assert_eq!(push["push"], i + 1);
        assert!(push["length_m"].as_f64().unwrap() > 0.1, "{push}");
        assert!(push["duration_s"].as_f64().unwrap() > 1.0, "{push}");
    }

    let last = served.last().unwrap();
    assert_eq!(last["aligned"], true);
    assert!(last["distance_m"].as_f64().unwrap() > 1.0, "{last}");
    assert!(last["height_m"].is_number() && last["odometer_m"].is_number());
}
