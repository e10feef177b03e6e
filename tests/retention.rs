//! Retention in a running server: raw readings older than the limit go
//! once an engine snapshot covers them, old estimates are thinned to one a
//! minute, and a restart still restores the engines (the readings after
//! the snapshot were kept), which carry on.

mod common;

use std::time::Duration;

use common::{ServerProcess, all_estimates, drive, exported_readings, post_ndjson, put_machine};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn old_history_is_pruned_and_the_engines_still_restore() {
    let dir = tempfile::tempdir().unwrap();
    let client = reqwest::Client::new();
    // The simulated drive is months old: everything is past both limits.
    let args = [
        "--keep-readings-days",
        "30",
        "--keep-estimates-days",
        "30",
        "--retention-every-s",
        "1",
    ];
    let server = ServerProcess::start_with_args(dir.path(), &args);
    let base = server.url("");
    put_machine(&client, &base, "r1").await;
    let lines = drive(12.0, 4, vec![]);
    // 25 000 readings: the engines' snapshot is taken at 20 000.
    for chunk in lines[..25_000].chunks(2500) {
        post_ndjson(&client, &base, "r1", chunk).await;
    }
    let estimates_before = all_estimates(&client, &base, "r1").await.len();
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let kept = exported_readings(&client, &base, "r1").await;
    let estimates = all_estimates(&client, &base, "r1").await;
    assert!(
        kept.len() < 25_000 && kept.len() >= 5_000 - 100,
        "{} readings kept",
        kept.len()
    );
    // The kept readings are the newest ones (after the snapshot).
    assert_eq!(kept[..], lines[25_000 - kept.len()..25_000]);
    // About 24 000 s of drive: one estimate a minute is about 400.
    assert!(
        estimates.len() < 600 && estimates_before > 20_000,
        "{estimates_before} estimates thinned to {}",
        estimates.len()
    );
    assert_eq!(server.terminate().code(), Some(0));

    // A restart restores the engines; more readings give estimates.
    let server = ServerProcess::start_with_args(dir.path(), &args);
    let base = server.url("");
    let ack = post_ndjson(&client, &base, "r1", &lines[25_000..25_100]).await;
    assert_eq!(ack["accepted"], 100, "{ack}");
    let history: serde_json::Value = common::get_json(&client, &base, "/api/v1/machines/r1").await;
    assert_eq!(history["late_readings"], 0, "{history}");
    let newest_inclinometer = lines[25_000..25_100]
        .iter()
        .rev()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|v| v["sensor"] == "inclinometer")
        .unwrap();
    assert_eq!(history["latest"]["attitude"]["t"], newest_inclinometer["t"]);
    server.terminate();
}
