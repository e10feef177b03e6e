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

/// An office and site `north` forwarding to it, with machine `tbm`
/// declared at the site: their directories and processes.
async fn office_and_site(
    client: &reqwest::Client,
) -> (
    tempfile::TempDir,
    ServerProcess,
    tempfile::TempDir,
    ServerProcess,
) {
    let office_dir = tempfile::tempdir().unwrap();
    let office = ServerProcess::start(office_dir.path());
    let site_dir = tempfile::tempdir().unwrap();
    let site = ServerProcess::start_with_args(
        site_dir.path(),
        &["--forward-to", &office.url(""), "--site", "north"],
    );
    declare_machine(
        client,
        &site.url(""),
        "tbm",
        r#"{"engines": {"attitude": {}}}"#,
    )
    .await;
    (office_dir, office, site_dir, site)
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
    let (_office_dir, office, _site_dir, site) = office_and_site(&client).await;
    let (office_base, site_base) = (office.url(""), site.url(""));
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

/// The `forward_refused` alarms of `machine` at the office now active.
async fn refused_alarms(client: &reqwest::Client, base: &str, machine: &str) -> Vec<Value> {
    let list = common::get_json(
        client,
        base,
        &format!("/api/v1/alarms?machine={machine}&state=active"),
    )
    .await;
    list["alarms"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["kind"] == "forward_refused")
        .cloned()
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_forged_mark_refuses_the_sites_rows_with_an_alarm_until_an_admin_sets_it_back() {
    let client = reqwest::Client::new();
    let (office_dir, office, _site_dir, site) = office_and_site(&client).await;
    let (office_base, site_base) = (office.url(""), site.url(""));
    let t0 = (wall_clock_s() - 3600.0).floor();
    post_ndjson(&client, &site_base, "tbm", &readings(t0, 10)).await;
    office_holds(
        &client,
        &office_base,
        "north.tbm",
        10,
        Duration::from_secs(60),
    )
    .await;

    // A sequence a second ahead of the clock: within the bound, above
    // every sequence the site has issued. Applied (the office cannot tell
    // it yet), so the mark moves past the site's next rows.
    let forged = (wall_clock_s() * 1e6) as i64 + 1_000_000;
    let (status, answer) = forge(
        &client,
        &office_base,
        json!({"site": "north", "items": [{"sequence": forged, "readings": [
            {"t": t0 + 500.0, "sensor": "inclinometer", "pitch_deg": 45.0, "roll_deg": 0.0}]}]}),
    )
    .await;
    assert_eq!(status, 200, "{answer}");

    // The site's next rows lie below the mark: not claimed as applied but
    // refused, with an alarm naming the mark to set back to.
    post_ndjson(&client, &site_base, "tbm", &readings(t0 + 10.0, 5)).await;
    let deadline = Instant::now() + Duration::from_secs(30);
    let alarm = loop {
        if let Some(alarm) = refused_alarms(&client, &office_base, "north.tbm")
            .await
            .pop()
        {
            break alarm;
        }
        assert!(Instant::now() < deadline, "no forward_refused alarm");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert_eq!(alarm["subject"], "north");
    assert_eq!(alarm["severity"], "alarm");
    // The 10 readings and the forged one; none of the 5 claimed.
    assert_eq!(
        office_readings(&client, &office_base, "north.tbm").await,
        11
    );
    let message = alarm["message"].as_str().unwrap();
    let back_to: i64 = message
        .split("{\"sequence\": ")
        .nth(1)
        .and_then(|rest| rest.split('}').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no sequence to set back to in: {message}"));
    assert!(back_to < forged, "{message}");

    // Never forward; then back to the site's confirmed sequence: the 5
    // arrive, the alarm clears, the audit log says who did it.
    let mark_url = format!("{office_base}/api/v1/machines/north.tbm/forward-mark");
    let forward = client
        .put(&mark_url)
        .header("content-type", "application/json")
        .body(json!({"sequence": forged + 1}).to_string())
        .send()
        .await
        .unwrap();
    assert_eq!(forward.status(), 400);
    let reset = client
        .put(&mark_url)
        .header("content-type", "application/json")
        .body(json!({"sequence": back_to}).to_string())
        .send()
        .await
        .unwrap();
    assert_eq!(reset.status(), 200);
    let reset: Value = serde_json::from_slice(&reset.bytes().await.unwrap()).unwrap();
    assert_eq!(
        (reset["was"].as_i64(), reset["sequence"].as_i64()),
        (Some(forged), Some(back_to))
    );
    let set_back = Instant::now();
    office_holds(
        &client,
        &office_base,
        "north.tbm",
        16,
        Duration::from_secs(60),
    )
    .await;
    eprintln!(
        "after the mark was set back, the site's refused rows reached the office in {:.1} s",
        set_back.elapsed().as_secs_f64()
    );
    assert!(
        refused_alarms(&client, &office_base, "north.tbm")
            .await
            .is_empty()
    );
    site.kill();
    // The command line does the same, audited as `cli`.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
        .args([
            "site",
            "reset-mark",
            "north.tbm",
            "--to",
            &back_to.to_string(),
            "--data-dir",
        ])
        .arg(office_dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    let conn = rusqlite::Connection::open(office_dir.path().join("tunnelnav.sqlite3")).unwrap();
    let audit: Vec<(String, String, String, String)> = conn
        .prepare("SELECT actor, action, subject, detail FROM audit ORDER BY id")
        .unwrap()
        .query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)))
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(audit.len(), 2, "{audit:?}");
    assert_eq!(audit[0].0, "anonymous");
    assert_eq!(audit[0].1, "reset_forward_mark");
    assert_eq!(audit[0].2, "north.tbm");
    assert!(
        audit[0].3.starts_with(&format!("mark {forged} -> ")),
        "{audit:?}"
    );
    assert_eq!(audit[1].0, "cli");
    // The same log over HTTP.
    let served = common::get_json(&client, &office_base, "/api/v1/audit").await;
    let entries = served["entries"].as_array().unwrap();
    assert_eq!(entries.len(), 2, "{served}");
    assert_eq!(entries[1]["actor"], "cli");
    assert_eq!(entries[0]["subject"], "north.tbm");
}
