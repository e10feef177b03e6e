//! The dashboard's pages and assets over HTTP (the browser test covers what
//! they do once loaded), and `tunnelnav demo` end to end.

mod common;

use std::process::{Command, Stdio};

use common::{ServerProcess, server_with_machine};
use serde_json::Value;

#[tokio::test]
async fn pages_render_and_assets_are_served_embedded() {
    let dir = tempfile::tempdir().unwrap();
    let (server, client, base) = server_with_machine(dir.path(), "tbm-7").await;
    let get = |path: &str| client.get(format!("{base}{path}")).send();

    let fleet = get("/").await.unwrap();
    assert_eq!(fleet.status(), 200);
    assert!(
        fleet.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/html")
    );
    let html = fleet.text().await.unwrap();
    assert!(html.contains(r#"href="/machines/tbm-7""#), "{html}");
    assert!(html.contains("Test TBM"));
    assert!(html.contains("/static/fleet.js"));

    let page = get("/machines/tbm-7").await.unwrap();
    assert_eq!(page.status(), 200);
    let html = page.text().await.unwrap();
    for needle in [
        r#"data-machine="tbm-7""#,
        r#"id="laser-status""#,
        r#"id="pitch-chart""#,
        r#"id="anfis-chart""#,
        "/static/vendor/uplot/uPlot.iife.min.js",
        "mm/m",
    ] {
        assert!(html.contains(needle), "machine page lacks {needle}");
    }

    // Unknown machine: an HTML 404 a person can read, not JSON.
    let missing = get("/machines/nope").await.unwrap();
    assert_eq!(missing.status(), 404);
    assert!(missing.text().await.unwrap().contains("no machine `nope`"));

    // Names are escaped.
    client
        .put(format!("{base}/api/v1/machines/odd"))
        .body(r#"{"name": "<script>alert(1)</script>", "engines": {"attitude": {}}}"#)
        .send()
        .await
        .unwrap();
    let html = get("/").await.unwrap().text().await.unwrap();
    assert!(!html.contains("<script>alert(1)</script>"));
    assert!(html.contains("&#60;script&#62;") || html.contains("&lt;script&gt;"));

    for (path, content_type) in [
        ("/static/app.css", "text/css"),
        ("/static/common.js", "text/javascript"),
        ("/static/fleet.js", "text/javascript"),
        ("/static/attitude.js", "text/javascript"),
        ("/static/favicon.svg", "image/svg+xml"),
        ("/static/vendor/uplot/uPlot.iife.min.js", "text/javascript"),
        ("/static/vendor/uplot/uPlot.min.css", "text/css"),
        ("/static/vendor/uplot/LICENSE", "text/plain"),
    ] {
        let response = get(path).await.unwrap();
        assert_eq!(response.status(), 200, "{path}");
        let header = response.headers()["content-type"].to_str().unwrap();
        assert!(header.starts_with(content_type), "{path}: {header}");
        let on_disk = std::fs::read(format!("{}{path}", env!("CARGO_MANIFEST_DIR"))).unwrap();
        assert_eq!(response.bytes().await.unwrap(), on_disk, "{path}");
    }
    assert_eq!(get("/static/nope.js").await.unwrap().status(), 404);
    assert_eq!(get("/static/../Cargo.toml").await.unwrap().status(), 404);
    server.stop().await;
}

fn run_demo(data_dir: &std::path::Path, rate: &str, seconds: &str) -> String {
    let output = Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
        .args(["demo", "--listen", "127.0.0.1:0", "--rate", rate])
        .args(["--seconds", seconds, "--data-dir"])
        .arg(data_dir)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .output()
        .expect("tunnelnav demo runs");
    let stdout = String::from_utf8_lossy(&output.stdout).to_string();
    let stderr = String::from_utf8_lossy(&output.stderr).to_string();
    assert!(output.status.success(), "demo failed: {stdout}\n{stderr}");
    assert!(stdout.contains("open http://127.0.0.1:"), "{stdout}");
    // Nothing the gateways sent was refused, and no send failed.
    assert!(!stderr.contains("rejected"), "{stderr}");
    assert!(!stderr.contains("will retry"), "{stderr}");
    stdout
}

async fn json(client: &reqwest::Client, url: String) -> Value {
    let response = client.get(&url).send().await.unwrap();
    assert_eq!(response.status(), 200, "{url}");
    serde_json::from_slice(&response.bytes().await.unwrap()).unwrap()
}

/// The demo at 300× for 8 s is 40 simulated minutes: every machine has
/// history, the blocked laser has had its first dropout (minutes 10–30),
/// the INS machine has moved and rested, the service vehicle has turned
/// its magnetometer into calibration and driven, and a second run on the
/// same data dir continues after the first (the INS's level and odometer
/// too).
#[tokio::test]
async fn demo_posts_five_machines_with_a_dropout_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    run_demo(dir.path(), "300", "8");

    let server = ServerProcess::start(dir.path());
    let client = reqwest::Client::new();
    let list = json(&client, server.url("/api/v1/machines")).await;
    let machines = list["machines"].as_array().unwrap();
    assert_eq!(machines.len(), 5, "{list}");
    let mut first_end = 0.0_f64;
    for machine in machines {
        let id = machine["machine"].as_str().unwrap();
        let engine = match id {
            "pipejack-ins" => "zupt",
            "service-van" => "fuzzy",
            _ => "attitude",
        };
        let history = json(
            &client,
            server.url(&format!(
                "/api/v1/machines/{id}/estimates?engine={engine}&max_points=100000"
            )),
        )
        .await;
        if id != "service-van" {
            let dta = json(
                &client,
                server.url(&format!("/api/v1/machines/{id}/estimates?engine=dta")),
            )
            .await;
            check_dta(id, dta["estimates"].as_array().unwrap());
        }
        let estimates = history["estimates"].as_array().unwrap();
        if id == "pipejack-ins" {
            check_ins(estimates);
            first_end = first_end.max(machine["last_reading_t"].as_f64().unwrap());
            continue;
        }
        if id == "service-van" {
            check_vehicle(estimates);
            first_end = first_end.max(machine["last_reading_t"].as_f64().unwrap());
            continue;
        }
        // About 2400 at 1 Hz; a loaded CI machine may fall a little behind.
        assert!(
            estimates.len() > 1000,
            "{id}: {} estimates",
            estimates.len()
        );
        let dropout = estimates
            .iter()
            .any(|e| e["laser_ok"] == false && e["laser_age_s"].is_number());
        assert_eq!(
            dropout,
            id == "pipejack-3",
            "{id}: dropout seen = {dropout}"
        );
        first_end = first_end.max(machine["last_reading_t"].as_f64().unwrap());
        assert!(
            machine["sensors"]["laser"]["last_t"].is_number(),
            "{machine}"
        );
    }

    // The TBMs close rings (a ring every 12–20 simulated minutes) and
    // steer back: their ring logs and correction curves.
    let rings = |server: &ServerProcess, id: &str| {
        let url = server.url(&format!("/api/v1/machines/{id}/estimates?engine=rings"));
        let client = client.clone();
        async move {
            json(&client, url).await["estimates"]
                .as_array()
                .unwrap()
                .iter()
                .map(|r| r["ring"].as_u64().unwrap())
                .collect::<Vec<u64>>()
        }
    };
    let mut first_rings = Vec::new();
    for id in ["tbm-north", "tbm-south"] {
        let numbers = rings(&server, id).await;
        assert!(!numbers.is_empty(), "{id}: no ring logged");
        assert_eq!(numbers[0], 1, "{id}: {numbers:?}");
        assert!(
            numbers.windows(2).all(|w| w[1] == w[0] + 1),
            "{id}: {numbers:?}"
        );
        first_rings.push(numbers.len());
        let steer = json(
            &client,
            server.url(&format!("/api/v1/machines/{id}/steering")),
        )
        .await;
        assert!(steer["steps"].as_u64() > Some(0), "{id}: {steer}");
    }
    server.terminate();

    run_demo(dir.path(), "300", "3");
    let server = ServerProcess::start(dir.path());
    let list = json(&client, server.url("/api/v1/machines")).await;
    for machine in list["machines"].as_array().unwrap() {
        let end = machine["last_reading_t"].as_f64().unwrap();
        assert!(end > first_end + 60.0, "{machine}: did not continue");
    }
    // The second run starts its drive again: its rings from 1 again.
    for (id, before) in ["tbm-north", "tbm-south"].into_iter().zip(first_rings) {
        let numbers = rings(&server, id).await;
        assert!(
            numbers[before..]
                .iter()
                .enumerate()
                .all(|(i, &n)| n == i as u64 + 1),
            "{id}: {numbers:?} ({before} in the first run)"
        );
    }
    // The INS's second stretch continued the first: the fused height still
    // follows the level (its readings were not refused as a jump).
    let ins = json(&client, server.url("/api/v1/machines/pipejack-ins")).await;
    let latest = &ins["latest"]["zupt"];
    let levels = client
        .get(server.url("/api/v1/machines/pipejack-ins/readings?sensor=level&format=ndjson"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let heights: Vec<f64> = levels
        .lines()
        .map(|l| {
            serde_json::from_str::<Value>(l).unwrap()["height_m"]
                .as_f64()
                .unwrap()
        })
        .collect();
    let steps = heights.windows(2).map(|w| (w[1] - w[0]).abs());
    assert!(
        steps.fold(0.0, f64::max) < 0.01,
        "a level jump between the runs"
    );
    let fused = latest["height_m"].as_f64().unwrap();
    let level = *heights.last().unwrap();
    assert!(
        (fused - level).abs() < 0.02,
        "fused {fused} m, level {level} m"
    );
    server.terminate();
}

/// The INS machine's history: 25 Hz estimates, aligned, with rests and
/// motion, a height that follows the level, an odometer shown.
fn check_vehicle(estimates: &[Value]) {
    // 40 simulated minutes at 25 Hz is 60 000; allow a slow CI machine.
    assert!(
        estimates.len() > 20_000,
        "{} vehicle estimates",
        estimates.len()
    );
    let last = estimates.last().unwrap();
    assert_eq!(last["engine"], "fuzzy");
    assert_eq!(last["aligned"], true, "{last}");
    assert_ne!(last["mag_calibration"], "collecting", "{last}");
    for motion in ["static", "moving"] {
        assert!(estimates.iter().any(|e| e["motion"] == motion), "{motion}");
    }
    assert!(
        last["heading_deg"].is_number() && last["mag_heading_deg"].is_number(),
        "{last}"
    );
}

/// Every demo drive follows a design axis: its `dta` stream comes from
/// the right source, near the axis (the TBMs' simulated deviations stay
/// within 1.8 × the warn limit; the INS machine drives the axis itself).
fn check_dta(id: &str, estimates: &[Value]) {
    let (source, within_mm) = match id {
        "pipejack-ins" => ("zupt", 30.0),
        "tbm-south" => ("laser", 100.0),
        _ => ("laser", 80.0),
    };
    assert!(
        estimates.len() > 5,
        "{id}: {} dta estimates",
        estimates.len()
    );
    for e in estimates {
        assert_eq!(e["source"], source, "{id}: {e}");
        for point in ["front", "rear"] {
            for axis in ["horizontal_mm", "vertical_mm"] {
                let mm = e[point][axis].as_f64().unwrap();
                assert!(mm.abs() < within_mm, "{id}: {point} {axis} {mm}: {e}");
            }
        }
        assert!(e["status"].is_string(), "{id}: {e}");
    }
}

fn check_ins(estimates: &[Value]) {
    // 40 simulated minutes at 25 Hz is 60 000; allow a slow CI machine.
    assert!(
        estimates.len() > 20_000,
        "{} INS estimates",
        estimates.len()
    );
    let last = estimates.last().unwrap();
    assert_eq!(last["engine"], "zupt");
    assert_eq!(last["aligned"], true, "{last}");
    assert!(estimates.iter().any(|e| e["zv"] == true));
    assert!(
        estimates
            .iter()
            .any(|e| e["zv"] == false && e["aligned"] == true)
    );
    assert!(
        last["odometer_m"].is_number() && last["height_m"].is_number(),
        "{last}"
    );
}
