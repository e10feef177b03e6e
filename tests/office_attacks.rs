//! Issue 57: what a stolen site token can and cannot do at the office.
//! Real processes: an office and a site forwarding to it; the attacker
//! posts forged rows to the office with the site's name.

mod common;

use std::time::{Duration, Instant};

use common::{ServerProcess, declare_machine, post_ndjson};
use serde_json::{Value, json};
use tunnelnav::clock::wall_clock_s;

/// The office's readings of `machine` (none until it is declared there).
async fn office_readings(client: &reqwest::Client, base: &str, machine: &str) -> usize {
    let response = client
        .get(format!("{base}/api/v1/machines/{machine}/readings"))
        .send()
        .await
        .unwrap();
    if response.status() != 200 {
        return 0;
    }
    response.text().await.unwrap().lines().count()
}

/// Waits (at most `within`) until the office holds `count` readings of
/// `machine`.
async fn office_holds(
    client: &reqwest::Client,
    base: &str,
    machine: &str,
    count: usize,
    within: Duration,
) {
    let deadline = Instant::now() + within;
    loop {
        let there = office_readings(client, base, machine).await;
        if there == count {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "the office holds {there} readings of {machine}, not {count}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

/// Inclinometer readings from `t0`, one a second.
fn readings(t0: f64, count: usize) -> Vec<String> {
    (0..count)
        .map(|k| {
            json!({"t": t0 + k as f64, "sensor": "inclinometer", "pitch_deg": 0.1, "roll_deg": 0.0})
                .to_string()
        })
        .collect()
}

/// POSTs a forged forwarding of `north.tbm` to the office.
async fn forge(client: &reqwest::Client, office: &str, body: Value) -> (u16, String) {
    let response = client
        .post(format!("{office}/api/v1/machines/north.tbm/forward"))
        .header("content-type", "application/json")
        .body(body.to_string())
        .send()
        .await
        .unwrap();
    let status = response.status().as_u16();
    (status, response.text().await.unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_forged_sequence_or_alarm_text_is_refused_and_the_site_goes_on() {
    let client = reqwest::Client::new();
    let office_dir = tempfile::tempdir().unwrap();
    let office = ServerProcess::start(office_dir.path());
    let office_base = office.url("");
    let site_dir = tempfile::tempdir().unwrap();
    let site = ServerProcess::start_with_args(
        site_dir.path(),
        &["--forward-to", &office_base, "--site", "north"],
    );
    let site_base = site.url("");
    declare_machine(
        &client,
        &site_base,
        "tbm",
        r#"{"engines": {"attitude": {}}}"#,
    )
    .await;
    let t0 = (wall_clock_s() - 3600.0).floor();
    post_ndjson(&client, &site_base, "tbm", &readings(t0, 100)).await;
    office_holds(
        &client,
        &office_base,
        "north.tbm",
        100,
        Duration::from_secs(60),
    )
    .await;

    // A sequence no site can have issued (2^63 - 1): refused, naming why.
    let forged_reading =
        json!({"t": t0 + 500.0, "sensor": "inclinometer", "pitch_deg": 45.0, "roll_deg": 0.0});
    let (status, error) = forge(
        &client,
        &office_base,
        json!({"site": "north", "items": [{"sequence": i64::MAX, "readings": [forged_reading]}]}),
    )
    .await;
    assert_eq!(status, 400, "{error}");
    assert!(
        error.contains("beyond any a site can have issued"),
        "{error}"
    );

    // An alarm with a 40,000-character message: refused, naming the field.
    let long_alarm = json!({"transition": "raised", "id": 1, "machine": "tbm",
        "kind": "deviation", "severity": "alarm", "subject": "front",
        "message": "x".repeat(40_000), "raised_t": t0 + 10.0, "cleared_t": null,
        "acked_t": null, "acked_by": null});
    let (status, error) = forge(
        &client,
        &office_base,
        json!({"site": "north", "items": [{"sequence": 1, "alarm": long_alarm}]}),
    )
    .await;
    assert_eq!(status, 400, "{error}");
    assert!(
        error.contains("`message` has 40000 characters; at most 1000"),
        "{error}"
    );

    // The site's later rows still reach the office (the bar: within 60 s).
    post_ndjson(&client, &site_base, "tbm", &readings(t0 + 100.0, 50)).await;
    let sent = Instant::now();
    office_holds(
        &client,
        &office_base,
        "north.tbm",
        150,
        Duration::from_secs(60),
    )
    .await;
    eprintln!(
        "the site's rows after the forgeries reached the office in {:.1} s",
        sent.elapsed().as_secs_f64()
    );
    site.kill();
}
