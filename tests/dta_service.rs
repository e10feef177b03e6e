//! A pipe-jacking machine declared with its design axis, geometry,
//! tolerances and start point over HTTP: its `dta` stream, served across
//! a restart, equals the same engine and stage run over the same readings
//! in this process, and the declaration reads back as declared.

mod common;

use common::{TestServer, declare_machine, get_json, post_ndjson, put_refused, stream_estimates};
use serde_json::{Value, json};
use tunnelnav::config::MachineDeclaration;
use tunnelnav::fusion::{EngineOutput, EstimateValues, Reading};
use tunnelnav::sim::pipejack::{PipeJackDrive, PipeJackScenario};

const MACHINE: &str = "pj-dta-1";

/// The machine: zupt heading north from (2000, 5000, 30.5) along a
/// straight axis that starts 100 m behind it with a 0.5 % grade.
fn declaration() -> Value {
    json!({
        "name": "Pipe jack on the S-2 axis",
        "engines": {"zupt": {"latitude_deg": 30}},
        "geometry": {"front_m": [1.5, 0.0, 0.0], "rear_m": [-1.5, 0.0, 0.0]},
        "tolerances": {"horizontal_mm": {"warn": 50, "alarm": 100},
                       "vertical_mm": {"warn": 30, "alarm": 60}},
        "start": {"easting_m": 2000.0, "northing_m": 5000.0, "height_m": 30.5},
        "alignment": {"name": "S-2", "start_station_m": 1000.0,
            "start": {"easting_m": 2000.0, "northing_m": 4900.0, "azimuth_deg": 0.0},
            "horizontal": [{"type": "line", "length_m": 1000.0}],
            "vertical": {"start_height_m": 30.0, "end_grade_pct": 0.5}}
    })
}

fn readings(seconds: f64) -> Vec<Reading> {
    let drive = PipeJackDrive::new(PipeJackScenario::default()).unwrap();
    let start = drive.scenario().start_t;
    drive
        .take_while(|e| e.reading.t < start + seconds)
        .map(|e| e.reading)
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_dta_stream_is_served_as_the_stage_computes_it_across_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let readings = readings(150.0);
    let lines: Vec<String> = readings.iter().map(Reading::to_json).collect();
    let (first, second) = lines.split_at(lines.len() / 2);

    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    declare_machine(&client, &base, MACHINE, &declaration().to_string()).await;
    let shown = get_json(&client, &base, &format!("/api/v1/machines/{MACHINE}")).await;
    assert_eq!(shown["config"]["alignment"]["name"], "S-2");
    assert_eq!(shown["config"]["geometry"]["front_m"][0], 1.5);
    assert_eq!(shown["config"]["start"]["height_m"], 30.5);
    for chunk in first.chunks(2500) {
        post_ndjson(&client, &base, MACHINE, chunk).await;
    }
    server.stop().await;

    let server = TestServer::start(dir.path()).await;
    let base = server.url("");
    for chunk in second.chunks(2500) {
        post_ndjson(&client, &base, MACHINE, chunk).await;
    }
    let served = stream_estimates(&client, &base, MACHINE, "dta").await;
    let status = get_json(&client, &base, &format!("/api/v1/machines/{MACHINE}")).await;
    server.stop().await;

    // The same engine and stages in this process, fed in order.
    let spec = serde_json::from_value::<MachineDeclaration>(declaration())
        .unwrap()
        .validate(MACHINE)
        .unwrap();
    let mut pipeline = spec.pipeline().unwrap();
    let mut outputs: Vec<EngineOutput> = Vec::new();
    for reading in &readings {
        pipeline.feed(reading, &mut outputs);
    }
    let expected: Vec<Value> = outputs
        .iter()
        .filter(|o| matches!(o.values, EstimateValues::Dta(_)))
        .map(|o| serde_json::to_value(o.for_machine(MACHINE)).unwrap())
        .collect();
    assert!(served.len() > 1000, "{} dta estimates", served.len());
    assert_eq!(served[..], expected[..served.len()]);

    // `replay --machine DECLARATION.json` runs the same engines and stages.
    let file = dir.path().join(format!("{MACHINE}.json"));
    std::fs::write(&file, declaration().to_string()).unwrap();
    let input = dir.path().join("readings.ndjson");
    std::fs::write(&input, lines.join("\n")).unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
        .args(["replay", "--reorder-window-s", "0", "--machine"])
        .arg(&file)
        .arg(&input)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let replayed: Vec<Value> = String::from_utf8(output.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .filter(|e| e["engine"] == "dta")
        .collect();
    assert_eq!(served[..], replayed[..served.len()]);
    let last = served.last().unwrap();
    assert_eq!(last["source"], "zupt");
    // On the axis to within the INS's drift over a few pushes.
    assert!(
        last["front"]["horizontal_mm"].as_f64().unwrap().abs() < 500.0,
        "{last}"
    );
    assert!(
        last["station_m"].as_f64().unwrap() > 1100.0,
        "the start point is at station 1100: {last}"
    );
    // Each point carries the INS's own σ (position and attitude over the
    // lever arm).
    for point in ["front", "rear"] {
        for key in ["sigma_horizontal_mm", "sigma_vertical_mm"] {
            let sigma = last[point][key].as_f64().unwrap_or(f64::NAN);
            assert!(sigma > 0.0 && sigma < 1e4, "{point} {key}: {last}");
        }
    }
    assert_eq!(status["latest"]["dta"]["engine"], "dta");

    // A declaration whose axis is broken is refused naming the element.
    let server = TestServer::start(dir.path()).await;
    let base = server.url("");
    let mut broken = declaration();
    broken["alignment"]["horizontal"][0]["length_m"] = json!(-5);
    let url = format!("{base}/api/v1/machines/pj-dta-2");
    let error = put_refused(&client, &url, None, broken.to_string()).await;
    assert!(
        error.contains("alignment") && error.contains("horizontal element 0 (line)"),
        "{error}"
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_axis_is_set_as_landxml_or_json_and_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let mut machine = declaration();
    machine.as_object_mut().unwrap().remove("alignment");
    declare_machine(&client, &base, "tbm-axis", &machine.to_string()).await;
    let url = format!("{base}/api/v1/machines/tbm-axis/alignment");
    let missing = client.get(&url).send().await.unwrap();
    assert_eq!(missing.status(), 404);

    let fixtures =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/alignment");
    let xml = std::fs::read_to_string(fixtures.join("s1.xml")).unwrap();
    let response = client
        .put(&url)
        .header("content-type", "application/xml")
        .body(xml.clone())
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    let summary: Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
    assert_eq!(summary["name"], "S-1 drive");
    assert_eq!(summary["elements"].as_array().unwrap().len(), 5);
    assert_eq!(summary["elements"][1]["type"], "spiral");
    assert!((summary["length_m"].as_f64().unwrap() - 250.0).abs() < 1e-9);

    // Read back as JSON: the geometry of the JSON twin.
    let shown = get_json(&client, &base, "/api/v1/machines/tbm-axis/alignment").await;
    let twin: Value =
        serde_json::from_str(&std::fs::read_to_string(fixtures.join("s1.json")).unwrap()).unwrap();
    for (a, b) in shown["horizontal"]
        .as_array()
        .unwrap()
        .iter()
        .zip(twin["horizontal"].as_array().unwrap())
    {
        assert_eq!(a["type"], b["type"]);
        for key in ["length_m", "radius_m", "radius_start_m", "radius_end_m"] {
            match (a[key].as_f64(), b[key].as_f64()) {
                (Some(x), Some(y)) => assert!((x - y).abs() < 1e-6, "{key}: {x} {y}"),
                (x, y) => assert_eq!(x, y, "{key}"),
            }
        }
    }
    assert!((shown["start"]["azimuth_deg"].as_f64().unwrap() - 30.0).abs() < 1e-9);
    assert!((shown["vertical"]["end_grade_pct"].as_f64().unwrap() + 0.5).abs() < 1e-9);

    // The same as JSON; a broken LandXML is refused naming the element.
    let response = client
        .put(&url)
        .body(twin.to_string())
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    let broken = xml.replacen(r#"radius="300.000000""#, r#"radius="310.000000""#, 1);
    let error = put_refused(&client, &url, Some("application/xml"), broken).await;
    assert!(
        error.contains("LandXML") && error.contains("element 2 (<Curve>"),
        "{error}"
    );

    // Station equations in the LandXML are read and kept in the JSON.
    let rechained = xml.replacen(
        "<CoordGeom>",
        r#"<StaEquation staBack="100.0" staAhead="1100.0" staInternal="100.0"/><CoordGeom>"#,
        1,
    );
    let response = client
        .put(&url)
        .header("content-type", "application/xml")
        .body(rechained)
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    let shown = get_json(&client, &base, "/api/v1/machines/tbm-axis/alignment").await;
    assert_eq!(
        shown["station_equations"][0]["station_ahead_m"], 1100.0,
        "{shown}"
    );
    let axis = get_json(
        &client,
        &base,
        "/api/v1/machines/tbm-axis/alignment/axis?step_m=50",
    )
    .await;
    let last = axis["points"].as_array().unwrap().last().unwrap().clone();
    assert_eq!(
        (
            last["internal_station_m"].as_f64(),
            last["station_m"].as_f64()
        ),
        (Some(250.0), Some(1250.0))
    );
    let response = client
        .put(&url)
        .body(twin.to_string())
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);

    // The axis sampled for drawing: every 50 m and each element's start
    // (40, 70, 120, 150 m); 25 m along the first line at 30° from
    // (1000, 5000) is (1012.5, 5021.650635), on the 0.5 % grade from 50 m.
    let axis = get_json(
        &client,
        &base,
        "/api/v1/machines/tbm-axis/alignment/axis?step_m=25",
    )
    .await;
    let points = axis["points"].as_array().unwrap();
    let stations: Vec<f64> = points
        .iter()
        .map(|p| p["station_m"].as_f64().unwrap())
        .collect();
    assert_eq!(stations.len(), 14, "{stations:?}");
    assert!((points[1]["easting_m"].as_f64().unwrap() - 1012.5).abs() < 1e-6);
    assert!((points[1]["northing_m"].as_f64().unwrap() - 5_021.650_635).abs() < 1e-6);
    assert!((points[1]["height_m"].as_f64().unwrap() - 50.125).abs() < 1e-9);
    for bad in ["0", "-1", "0.001", "x"] {
        let response = client
            .get(format!("{url}/axis?step_m={bad}"))
            .send()
            .await
            .unwrap();
        assert_eq!(response.status(), 400, "step_m={bad}");
        let body: Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
        assert!(body["error"].as_str().unwrap().contains("step_m"), "{body}");
    }
    server.stop().await;
}

/// A TBM on a straight axis due north from (1000, 5000), level at 50 m:
/// level and square to the world (inclinometer and laser read 0), its
/// reference point at known offsets from the axis and yawed by a known
/// angle, the laser giving its position every 30 s.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn laser_positions_give_the_known_deviations_within_a_millimetre() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let declaration = json!({
        "engines": {"attitude": {}},
        "geometry": {"front_m": [4.2, 0.0, 0.0], "rear_m": [-5.1, 0.0, 0.0]},
        "tolerances": {"horizontal_mm": {"warn": 50, "alarm": 100},
                       "vertical_mm": {"warn": 30, "alarm": 60}},
        "alignment": {"start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 0.0},
            "horizontal": [{"type": "line", "length_m": 500.0}],
            "vertical": {"start_height_m": 50.0, "end_grade_pct": 0.0}}
    });
    declare_machine(&client, &base, "tbm-dta", &declaration.to_string()).await;
    let t0 = 1_772_431_200.0;
    // At laser sample k: 10 + 0.3k m along, dx = 20 + 3k mm right,
    // dz = −10 + 2k mm high, yaw 0.05k° (right).
    let truth = |k: f64| {
        (
            10.0 + 0.3 * k,
            0.020 + 0.003 * k,
            -0.010 + 0.002 * k,
            0.05 * k,
        )
    };
    let mut lines = Vec::new();
    for s in 0..=600u32 {
        let t = t0 + f64::from(s);
        lines.push(
            json!({"t": t, "sensor": "inclinometer", "pitch_deg": 0.0, "roll_deg": 0.0})
                .to_string(),
        );
        if s % 30 == 0 {
            let (along, dx, dz, yaw) = truth(f64::from(s / 30));
            lines.push(
                json!({"t": t, "sensor": "laser", "pitch_deg": 0.0, "roll_deg": 0.0,
                       "yaw_deg": yaw, "easting_m": 1000.0 + dx,
                       "northing_m": 5000.0 + along, "height_m": 50.0 + dz})
                .to_string(),
            );
        }
    }
    post_ndjson(&client, &base, "tbm-dta", &lines).await;
    let served = stream_estimates(&client, &base, "tbm-dta", "dta").await;
    assert_eq!(served.len(), 21);
    for (k, d) in served.iter().enumerate() {
        let (along, dx, dz, yaw) = truth(k as f64);
        let (sin, cos) = yaw.to_radians().sin_cos();
        let mm = |x: f64| x * 1000.0;
        let close = |field: &Value, want: f64| {
            let got = field.as_f64().unwrap();
            assert!(
                (got - want).abs() < 1.0,
                "sample {k}: {got} against {want}: {d}"
            );
        };
        close(&d["front"]["horizontal_mm"], mm(dx + 4.2 * sin));
        close(&d["rear"]["horizontal_mm"], mm(dx - 5.1 * sin));
        close(&d["front"]["vertical_mm"], mm(dz));
        close(&d["rear"]["vertical_mm"], mm(dz));
        close(
            &d["front"]["station_m"],
            (along + 4.2 * cos) * 1000.0 / 1000.0,
        );
        close(&d["station_m"], along);
        close(&d["tendency_horizontal_mm_per_m"], mm(9.3 * sin) / 9.3);
        assert_eq!(d["source"], "laser");
        // Laser positions come without a σ.
        assert!(d["front"]["sigma_horizontal_mm"].is_null(), "{d}");
        let worst_h = mm(dx + 4.2 * sin).abs().max(mm(dx - 5.1 * sin).abs());
        let worst_v = mm(dz).abs();
        let want = if worst_h > 100.0 || worst_v > 60.0 {
            "alarm"
        } else if worst_h > 50.0 || worst_v > 30.0 {
            "warn"
        } else {
            "ok"
        };
        assert_eq!(d["status"], want, "sample {k}: {d}");
    }
    server.stop().await;
}

/// Setting the axis of a running machine keeps its engines where they
/// stood: its attitude estimates stay those of a machine declared with the
/// axis from the start, and its `dta` stream starts at the change.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn setting_the_axis_keeps_the_engines() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let axis = json!({"start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 0.0},
        "horizontal": [{"type": "line", "length_m": 500.0}],
        "vertical": {"start_height_m": 50.0, "end_grade_pct": 0.0}});
    let with_axis = json!({
        "engines": {"attitude": {}},
        "geometry": {"front_m": [4.2, 0.0, 0.0], "rear_m": [-5.1, 0.0, 0.0]},
        "alignment": axis,
    });
    let mut without = with_axis.clone();
    without.as_object_mut().unwrap().remove("alignment");
    declare_machine(&client, &base, "a", &with_axis.to_string()).await;
    declare_machine(&client, &base, "b", &without.to_string()).await;
    let t0 = 1_772_431_200.0;
    let lines: Vec<String> = (0..=1200u32)
        .flat_map(|s| {
            let t = t0 + f64::from(s);
            // A slow pitch and roll sweep, the laser every 60 s.
            let (pitch, roll) = (0.2 * (f64::from(s) / 300.0).sin(), 0.5 * (f64::from(s) / 200.0).cos());
            let mut out = vec![
                json!({"t": t, "sensor": "inclinometer", "pitch_deg": pitch + 0.05, "roll_deg": roll})
                    .to_string(),
            ];
            if s % 60 == 0 {
                out.push(
                    json!({"t": t, "sensor": "laser", "pitch_deg": pitch, "roll_deg": roll,
                           "yaw_deg": 0.3, "easting_m": 1000.01, "northing_m": 5010.0 + 0.01 * f64::from(s),
                           "height_m": 50.02})
                    .to_string(),
                );
            }
            out
        })
        .collect();
    let (first, second) = lines.split_at(lines.len() / 2);
    for machine in ["a", "b"] {
        post_ndjson(&client, &base, machine, first).await;
    }
    let response = client
        .put(format!("{base}/api/v1/machines/b/alignment"))
        .body(axis.to_string())
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    for machine in ["a", "b"] {
        post_ndjson(&client, &base, machine, second).await;
    }
    let attitude = |m: &'static str| stream_estimates(&client, &base, m, "attitude");
    let (a, b) = (attitude("a").await, attitude("b").await);
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        let mut y = y.clone();
        y["machine"] = x["machine"].clone();
        assert_eq!(*x, y);
    }
    let (dta_a, dta_b) = (
        stream_estimates(&client, &base, "a", "dta").await,
        stream_estimates(&client, &base, "b", "dta").await,
    );
    assert!(
        !dta_b.is_empty() && dta_b.len() < dta_a.len(),
        "{} {}",
        dta_b.len(),
        dta_a.len()
    );
    // The new stage's first position comes before it has seen a fused
    // attitude (it turns the points by the laser's own); from the second
    // on, the same as the machine that had the axis all along.
    let from = dta_a.len() - dta_b.len();
    assert_eq!(dta_a[from]["t"], dta_b[0]["t"]);
    for (x, y) in dta_a[from + 1..].iter().zip(&dta_b[1..]) {
        let mut y = y.clone();
        y["machine"] = x["machine"].clone();
        assert_eq!(*x, y);
    }
    server.stop().await;
}

/// Issues 39 and 56: `GET .../steering` answers the curve the machine is
/// steering from its newest `dta` estimate and the declared `steering`;
/// its properties are checked here from the served points alone (finite
/// differences, not the service's formulas).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_correction_curve_is_served_from_the_newest_dta_estimate() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let mut declaration = common::on_an_axis("Steered TBM");
    declaration["steering"] =
        json!({"min_radius_m": 1500.0, "step_m": 1.5, "cylinder_circle_m": 6.0});
    declare_machine(&client, &base, "tbm-steer", &declaration.to_string()).await;
    let refused = client
        .get(format!("{base}/api/v1/machines/tbm-steer/steering"))
        .send()
        .await
        .unwrap();
    assert_eq!(refused.status(), 404, "no dta estimate yet");
    // 50 mm east of the axis (right of it, heading north), level, standing.
    let now = tunnelnav::clock::wall_clock_s().floor();
    post_ndjson(
        &client,
        &base,
        "tbm-steer",
        &common::laser_pairs(now - 40.0, 10, 0.05),
    )
    .await;
    let served = get_json(&client, &base, "/api/v1/machines/tbm-steer/steering").await;
    let dta = stream_estimates(&client, &base, "tbm-steer", "dta").await;
    let steer = stream_estimates(&client, &base, "tbm-steer", "steer").await;
    let newest = dta.last().unwrap();
    assert_eq!(served["t"], newest["t"]);
    assert_eq!(served["t"], steer.last().unwrap()["t"]);
    assert_eq!(served["feasible"], true);
    let d0 = newest["front"]["horizontal_mm"].as_f64().unwrap();
    assert!((d0 - 50.0).abs() < 1.0, "{newest}");
    assert_eq!(served["horizontal"]["deviation_mm"], d0);
    // Held while the machine stands: planned at the first estimate only.
    let replanned: Vec<bool> = steer.iter().map(|s| s["replanned"] == true).collect();
    assert_eq!(replanned.iter().filter(|r| **r).count(), 1, "{replanned:?}");
    let step = 1.5;
    let h: Vec<&serde_json::Value> = served["horizontal"]["points"]
        .as_array()
        .unwrap()
        .iter()
        .collect();
    let v = served["vertical"]["points"].as_array().unwrap();
    let n = h.len() - 1;
    assert_eq!(served["steps"], n);
    let num = |p: &serde_json::Value, key: &str| p[key].as_f64().unwrap();
    // At least two shield lengths (9 m front to rear): 12 rings or more.
    assert!(n >= 12, "{n}");
    assert!((served["length_m"].as_f64().unwrap() - step * n as f64).abs() < 1e-9);
    // Ends: where the front is, on the axis at the end, flat at both.
    assert!((num(h[0], "deviation_mm") - d0).abs() < 0.5, "{}", h[0]);
    assert!(num(h[n], "deviation_mm").abs() < 1e-6, "{}", h[n]);
    let slope = |k: usize| (num(h[k + 1], "deviation_mm") - num(h[k], "deviation_mm")) / step;
    let mean_slope = d0 / (step * n as f64);
    assert!(slope(0).abs() < 0.1 * mean_slope && slope(n - 1).abs() < 0.1 * mean_slope);
    // No overshoot: every point between the start and the axis.
    assert!(
        h.iter()
            .all(|p| (-1e-6..=d0 + 0.5).contains(&num(p, "deviation_mm")))
    );
    // Curvature: the served one is the deviation's second difference
    // (the axis is straight), within the difference's own error h²/12·d⁗
    // (for a 50 mm quintic over 21 m, |d⁗| ≤ 360·0.05/21⁴: 1.8e-5 /m);
    // within the radius, both planes together; none at either end.
    for k in 1..n {
        let second = (num(h[k + 1], "deviation_mm") - 2.0 * num(h[k], "deviation_mm")
            + num(h[k - 1], "deviation_mm"))
            / (step * step)
            / 1000.0;
        let served_k = num(h[k], "curvature_per_m");
        assert!(
            (second - served_k).abs() < 2e-5,
            "{k}: {second} vs {served_k}"
        );
    }
    for (p, q) in h.iter().zip(v) {
        assert!(num(p, "curvature_per_m").hypot(num(q, "curvature_per_m")) <= 1.0 / 1500.0);
        assert_eq!(num(q, "deviation_mm"), 0.0);
    }
    assert!(
        num(h[0], "curvature_per_m").abs() < 1e-12 && num(h[n], "curvature_per_m").abs() < 1e-12
    );
    // Strokes: the turn over each step on the 6 m circle, its mean
    // curvature (trapezoid of the ends, within h³/12·|κ″|·6 m: 0.16 mm)
    // times the step; they sum to the whole turn, none (it starts and
    // ends parallel to the axis).
    let mut total = 0.0;
    for k in 0..n {
        let stroke = num(h[k], "stroke_difference_mm");
        let trapezoid = 6.0
            * step
            * 0.5
            * (num(h[k], "curvature_per_m") + num(h[k + 1], "curvature_per_m"))
            * 1000.0;
        assert!(
            (stroke - trapezoid).abs() < 0.2,
            "{k}: {stroke} vs {trapezoid}"
        );
        total += stroke;
        assert_eq!(
            num(h[k], "station_m"),
            newest["front"]["station_m"].as_f64().unwrap() + step * k as f64
        );
    }
    assert!(total.abs() < 1e-9, "{total}");
    // Back to the left first: the right cylinders extend more, said so.
    assert!(num(h[0], "stroke_difference_mm") <= 0.0);
    let words = served["words"].as_str().unwrap();
    assert!(
        words.starts_with("steer left") || words.starts_with("hold the line"),
        "{words}"
    );
    // A bad declaration is refused, naming the field.
    declaration["steering"]["step_m"] = json!(0.0);
    let refused = client
        .put(format!("{base}/api/v1/machines/tbm-steer"))
        .body(declaration.to_string())
        .send()
        .await
        .unwrap();
    assert_eq!(refused.status(), 400);
    assert!(refused.text().await.unwrap().contains("steering.step_m"));
    server.stop().await;
}
