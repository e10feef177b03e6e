//! Issue 39 over HTTP: a steered TBM on its axis closes rings (`advance`
//! readings), drifts past its tolerance, loses its laser for a while; the
//! `rings` stream logs each ring as the `dta` stream had the machine, the
//! `steer` stream agrees with `GET .../steering`, and the shift report
//! (JSON, CSV, HTML, PDF) holds the numbers recomputed here from the
//! served streams and the posted readings.

mod common;

use common::{TestServer, declare_machine, post_ndjson, stream_estimates};
use serde_json::{Value, json};
use tunnelnav::clock::wall_clock_s;

const MACHINE: &str = "tbm-shift";

/// Laser and inclinometer every 2 s over [`from`, `to`), the machine
/// `east_m` right of the axis and advancing 25 mm/s; no laser in `gap`.
fn drive(from: f64, to: f64, east_m: impl Fn(f64) -> f64, gap: (f64, f64)) -> Vec<Value> {
    let mut lines = Vec::new();
    let mut t = from;
    while t < to {
        if !(gap.0..gap.1).contains(&t) {
            lines.push(
                json!({"t": t, "sensor": "laser", "pitch_deg": 0.0, "roll_deg": 0.0,
                "yaw_deg": 0.0, "easting_m": 1000.0 + east_m(t),
                "northing_m": 5010.0 + 0.025 * (t - from), "height_m": 50.0}),
            );
        }
        lines.push(json!({"t": t + 1.0, "sensor": "inclinometer",
            "pitch_deg": 0.0, "roll_deg": 0.0}));
        t += 2.0;
    }
    lines
}

/// A station as the dashboard's chainage (km+m.mmm), written here anew.
fn chainage(station_m: f64) -> String {
    let mm = (station_m * 1000.0).round() as u64;
    format!(
        "{}+{:03}.{:03}",
        mm / 1_000_000,
        (mm / 1000) % 1000,
        mm % 1000
    )
}

/// The text of the PDF at `path` (`pdftotext -layout`); `None`, said so,
/// without pdftotext unless `TUNNELNAV_PDFTOTEXT_TEST=required`.
fn pdf_text(path: &std::path::Path) -> Option<String> {
    match std::process::Command::new("pdftotext")
        .arg("-layout")
        .arg(path)
        .arg("-")
        .output()
    {
        Ok(out) => {
            assert!(out.status.success());
            Some(String::from_utf8(out.stdout).unwrap())
        }
        Err(e) if std::env::var("TUNNELNAV_PDFTOTEXT_TEST").as_deref() == Ok("required") => {
            panic!("pdftotext (Debian's poppler-utils) is required: {e}")
        }
        Err(e) => {
            eprintln!(
                "SKIPPED reading the PDF back: no pdftotext ({e}); apt-get install poppler-utils"
            );
            None
        }
    }
}

/// A JSON number or null as the CSV writes it.
fn csv_of(value: &Value) -> String {
    match value {
        Value::Null => String::new(),
        // A list is text: one starting as a formula would is neutralised.
        Value::Array(items) => {
            let joined = items.iter().map(csv_of).collect::<Vec<_>>().join(" ");
            match joined.starts_with(['=', '+', '-', '@']) {
                true => format!("'{joined}"),
                false => joined,
            }
        }
        // Text that could start a formula is prefixed with a quote.
        Value::String(s) if s.starts_with(['=', '+', '-', '@', '\t', '\r']) => format!("'{s}"),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// The CSV's rows of `table`, as column name → cell.
fn csv_table(csv: &str, table: &str) -> Vec<Vec<(String, String)>> {
    let mut rows = csv
        .lines()
        .map(common::csv_cells)
        .filter(|cells| cells[0] == table);
    let header: Vec<String> = rows
        .next()
        .unwrap_or_else(|| panic!("no {table} table"))
        .split_off(1);
    rows.map(|mut cells| header.iter().cloned().zip(cells.split_off(1)).collect())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rings_steer_and_the_shift_report_hold_the_streams_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let mut declaration = common::on_an_axis("TBM S-1");
    declaration["steering"] =
        json!({"min_radius_m": 1500.0, "step_m": 1.5, "cylinder_circle_m": 6.0});
    declaration["alarms"] = json!({"laser_dropout_warn_s": 30});
    declare_machine(&client, &base, MACHINE, &declaration.to_string()).await;

    // 400 s: 20 mm right, 120 mm right (past the 100 mm alarm) from 100 s
    // to 200 s, 30 mm from then on; the laser out from 260 s to 320 s;
    // rings closed at 50 s, 150 s (with strokes) and 350 s.
    let t0 = (wall_clock_s() - 600.0).floor();
    let east = move |t: f64| match t - t0 {
        x if (100.0..200.0).contains(&x) => 0.12,
        x if x < 100.0 => 0.02,
        _ => 0.03,
    };
    let gap = (t0 + 260.0, t0 + 320.0);
    let mut lines = drive(t0, t0 + 400.0, east, gap);
    let advances = [
        json!({"t": t0 + 50.5, "sensor": "advance", "ring": 101}),
        json!({"t": t0 + 150.5, "sensor": "advance", "ring": 102,
               "strokes_mm": [1510.5, 1498.0, 1502.25, 1507.0]}),
        json!({"t": t0 + 350.5, "sensor": "advance", "ring": 103}),
    ];
    lines.extend(advances.iter().cloned());
    lines.sort_by(|a, b| {
        a["t"]
            .as_f64()
            .unwrap()
            .total_cmp(&b["t"].as_f64().unwrap())
    });
    let lines: Vec<String> = lines.iter().map(Value::to_string).collect();
    post_ndjson(&client, &base, MACHINE, &lines).await;

    // The ring log: one record per advance, with the newest dta estimate
    // before it.
    let dta = stream_estimates(&client, &base, MACHINE, "dta").await;
    let rings = stream_estimates(&client, &base, MACHINE, "rings").await;
    assert_eq!(rings.len(), 3, "{rings:?}");
    for (ring, advance) in rings.iter().zip(&advances) {
        assert_eq!(ring["t"], advance["t"]);
        assert_eq!(ring["ring"], advance["ring"]);
        let before = dta
            .iter()
            .rfind(|d| d["t"].as_f64() < advance["t"].as_f64())
            .unwrap();
        assert_eq!(ring["dta_t"], before["t"]);
        assert_eq!(ring["station_m"], before["station_m"]);
        assert_eq!(
            ring["front_horizontal_mm"],
            before["front"]["horizontal_mm"]
        );
        assert_eq!(ring["rear_vertical_mm"], before["rear"]["vertical_mm"]);
        assert_eq!(
            ring["tendency_horizontal_mm_per_m"],
            before["tendency_horizontal_mm_per_m"]
        );
    }
    assert_eq!(rings[1]["strokes_mm"], advances[1]["strokes_mm"]);
    assert_eq!(rings[1]["duration_s"], 100.0);
    let advanced =
        rings[2]["station_m"].as_f64().unwrap() - rings[1]["station_m"].as_f64().unwrap();
    assert_eq!(rings[2]["advance_m"].as_f64().unwrap(), advanced);
    // 200 s at 25 mm/s, the dta estimates 2 s apart.
    assert!((advanced - 5.0).abs() < 0.051, "{advanced}");

    // The steer stream's newest is the served curve's first step.
    let steer = stream_estimates(&client, &base, MACHINE, "steer").await;
    assert_eq!(steer.len(), dta.len());
    let newest = steer.last().unwrap();
    let served = common::get_json(
        &client,
        &base,
        &format!("/api/v1/machines/{MACHINE}/steering"),
    )
    .await;
    assert_eq!(newest["t"], served["t"]);
    assert_eq!(newest["steps"], served["steps"]);
    assert_eq!(newest["length_m"], served["length_m"]);
    for plane in ["horizontal", "vertical"] {
        let points = served[plane]["points"].as_array().unwrap();
        assert_eq!(
            newest[plane]["next_deviation_mm"],
            points[1]["deviation_mm"]
        );
        assert_eq!(
            newest[plane]["stroke_difference_mm"],
            points[0]["stroke_difference_mm"]
        );
    }

    // The deviation alarm, acknowledged by a named token.
    let mut deviation = Value::Null;
    for _ in 0..50 {
        let listed = common::get_json(&client, &base, "/api/v1/alarms?state=all").await;
        if let Some(a) = listed["alarms"]
            .as_array()
            .unwrap()
            .iter()
            .find(|a| a["kind"] == "deviation" && a["severity"] == "alarm")
        {
            deviation = a.clone();
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    assert!(deviation.is_object(), "the deviation alarm is raised");
    let token = common::operator_token(dir.path(), "shift-lead");
    // The server reads new tokens within 2 s.
    tokio::time::sleep(std::time::Duration::from_millis(2100)).await;
    let acked = client
        .post(format!("{base}/api/v1/alarms/{}/ack", deviation["id"]))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    assert_eq!(acked.status(), 200);

    let report_url = |format: &str| {
        format!(
            "{base}/api/v1/machines/{MACHINE}/report?from={}&to={}&format={format}",
            t0 - 10.0,
            t0 + 600.0
        )
    };
    let get = |format: &str| client.get(report_url(format)).bearer_auth(&token).send();
    let response = get("json").await.unwrap();
    assert_eq!(response.status(), 200);
    let report: Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();

    // Rings as the stream has them.
    let listed = report["rings"].as_array().unwrap();
    assert_eq!(listed.len(), 3);
    for (row, ring) in listed.iter().zip(&rings) {
        for (key, value) in ring.as_object().unwrap() {
            if key != "machine" && key != "engine" {
                assert_eq!(&row[key], value, "{key}");
            }
        }
    }
    let advance = &report["advance"];
    assert_eq!(
        (
            &advance["rings"],
            &advance["first_ring"],
            &advance["last_ring"]
        ),
        (&json!(3), &json!(101), &json!(103))
    );
    let first_station = dta[0]["station_m"].as_f64().unwrap();
    let last_station = dta.last().unwrap()["station_m"].as_f64().unwrap();
    assert_eq!(advance["start_station_m"], first_station);
    // The advance is the rings' own (the first has none: no ring before).
    let gained: f64 = rings.iter().filter_map(|r| r["advance_m"].as_f64()).sum();
    assert_eq!(
        (&advance["advance_m"], &advance["advance_from"]),
        (&json!(gained), &json!("rings"))
    );
    assert_eq!(
        advance["ring_numbers"],
        json!([{"first": 101, "last": 103}])
    );
    assert_eq!(
        advance["stretches"],
        json!([{"from_t": dta[0]["t"], "to_t": dta.last().unwrap()["t"],
                "from_station_m": first_station, "to_station_m": last_station}])
    );

    // The largest deviations, recomputed from every dta estimate.
    let deviations = report["deviations"].as_array().unwrap();
    assert_eq!(deviations.len(), 4);
    for largest in deviations {
        let (point, plane) = (
            largest["point"].as_str().unwrap(),
            largest["plane"].as_str().unwrap(),
        );
        let key = format!("{plane}_mm");
        let worst = dta
            .iter()
            .max_by(|a, b| {
                let v = |d: &Value| d[point][&key].as_f64().unwrap().abs();
                v(a).total_cmp(&v(b))
            })
            .unwrap();
        assert_eq!(
            largest["deviation_mm"], worst[point][&key],
            "{point} {plane}"
        );
    }
    let front_h = deviations[0]["deviation_mm"].as_f64().unwrap();
    assert!((front_h - 120.0).abs() < 1.0, "{front_h}");

    // The alarms with who acknowledged them; the laser's one dropout,
    // from its last sample before the gap to its first after.
    let alarms = report["alarms"].as_array().unwrap();
    let reported = alarms
        .iter()
        .find(|a| a["id"] == deviation["id"])
        .expect("the deviation alarm");
    assert_eq!(reported["acked_by"], "shift-lead");
    assert!(
        alarms.iter().any(|a| a["kind"] == "laser_dropout"),
        "{alarms:?}"
    );
    assert_eq!(
        report["laser_dropouts"],
        json!([{"from_t": t0 + 258.0, "to_t": t0 + 320.0, "duration_s": 62.0}])
    );
    assert!(report["chart"].as_array().unwrap().len() >= 100);

    // The CSV: every table's cells are the JSON's.
    let csv = get("csv").await.unwrap().text().await.unwrap();
    // Every table, every field of every row: the JSON's values.
    let whole = json!([{"machine": report["machine"], "name": report["name"],
                        "from": report["from"], "to": report["to"],
                        "project": report["project"], "generated_t": report["generated_t"]}]);
    let mut advance_alone = report["advance"].clone();
    let advance_lists = advance_alone.as_object_mut().unwrap();
    let ring_runs = advance_lists.remove("ring_numbers").unwrap();
    let stretches = advance_lists.remove("stretches").unwrap();
    for (table, rows) in [
        ("report", whole),
        ("advance", json!([advance_alone])),
        ("ring_run", ring_runs),
        ("stretch", stretches),
        ("deviation", report["deviations"].clone()),
        ("ring", report["rings"].clone()),
        ("push", report["pushes"].clone()),
        ("alarm", report["alarms"].clone()),
        ("laser_dropout", report["laser_dropouts"].clone()),
        ("chart", report["chart"].clone()),
    ] {
        let csv_rows = csv_table(&csv, table);
        let json_rows = rows.as_array().unwrap();
        assert_eq!(csv_rows.len(), json_rows.len(), "{table}");
        for (row, json_row) in csv_rows.iter().zip(json_rows) {
            let fields = json_row.as_object().unwrap();
            let mut columns: Vec<&String> = row.iter().map(|(c, _)| c).collect();
            columns.sort();
            assert_eq!(
                columns,
                fields.keys().collect::<Vec<_>>(),
                "{table}: every field"
            );
            for (column, cell) in row {
                // Made by a later request than the JSON: a later time.
                if (table, column.as_str()) == ("report", "generated_t") {
                    assert!(cell.parse::<f64>().unwrap() >= json_row[column].as_f64().unwrap());
                    continue;
                }
                assert_eq!(cell, &csv_of(&json_row[column]), "{table} {column}");
            }
        }
    }
    assert!(!report["alarms"].as_array().unwrap().is_empty());

    // The page and the PDF's text hold the report's numbers.
    let numbers = [
        format!("{front_h:+.1}"),
        "101".to_string(),
        "103".to_string(),
        chainage(rings[2]["station_m"].as_f64().unwrap()),
        format!("{:.3}", advance["advance_m"].as_f64().unwrap()),
        "shift-lead".to_string(),
        "0:01:02".to_string(),
        // The header block and the lines to sign.
        "Project".to_string(),
        "Generated at".to_string(),
        "Shift engineer (checked)".to_string(),
        "warn ±100".to_string().replace("100", "50"),
    ];
    let html = get("html").await.unwrap().text().await.unwrap();
    assert!(html.contains("<svg id=\"report-chart\""));
    for number in &numbers {
        assert!(html.contains(number.as_str()), "the page lacks {number}");
    }
    let pdf = get("pdf").await.unwrap();
    assert_eq!(pdf.headers()["content-type"], "application/pdf",);
    let pdf = pdf.bytes().await.unwrap();
    let path = dir.path().join("report.pdf");
    std::fs::write(&path, &pdf).unwrap();
    assert!(pdf.starts_with(b"%PDF-"));
    if let Some(text) = pdf_text(&path) {
        for number in &numbers {
            assert!(
                text.contains(number.as_str()),
                "the PDF lacks {number}:\n{text}"
            );
        }
    }

    // Refusals name what was wrong.
    let bad = client
        .get(format!(
            "{base}/api/v1/machines/{MACHINE}/report?format=doc"
        ))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    assert_eq!(bad.status(), 400);
    assert!(bad.text().await.unwrap().contains("format"));
    let backwards = client
        .get(format!(
            "{base}/api/v1/machines/{MACHINE}/report?from=2000&to=1000"
        ))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    assert_eq!(backwards.status(), 400);
    server.stop().await;
}

/// Issue 56: a report over a new drive begun in its range (the demo
/// started again: stations back at the axis's start, rings numbered from 1)
/// gives the advance the rings made, the ring numbers as logged, no chart
/// line back in time; a long ring log repeats its headings on every page
/// of the PDF.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_report_across_a_new_drive_counts_what_was_built() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let machine = "tbm-again";
    declare_machine(
        &client,
        &base,
        machine,
        &common::on_an_axis("TBM again").to_string(),
    )
    .await;
    // Drive A: from station 10 for 400 s at 25 mm/s, rings 7 and 8.
    // Drive B: from station 2 at t0 + 500 for 600 s (the guidance trusts
    // the laser again after two minutes: a jump of 18 m back is checked),
    // rings 1 to 100 every 4 s from t0 + 700.
    let t0 = (wall_clock_s() - 1500.0).floor();
    let mut lines = drive(t0, t0 + 400.0, |_| 0.01, (0.0, 0.0));
    let mut b = drive(t0 + 500.0, t0 + 1100.0, |_| 0.02, (0.0, 0.0));
    for line in &mut b {
        if let Some(n) = line["northing_m"].as_f64() {
            line["northing_m"] = json!(n - 8.0);
        }
    }
    lines.extend(b);
    lines.push(json!({"t": t0 + 100.5, "sensor": "advance", "ring": 7}));
    lines.push(json!({"t": t0 + 300.5, "sensor": "advance", "ring": 8}));
    for k in 1..=100u64 {
        lines.push(json!({"t": t0 + 700.5 + 4.0 * k as f64, "sensor": "advance", "ring": k}));
    }
    lines.sort_by(|a, b| {
        a["t"]
            .as_f64()
            .unwrap()
            .total_cmp(&b["t"].as_f64().unwrap())
    });
    let lines: Vec<String> = lines.iter().map(Value::to_string).collect();
    post_ndjson(&client, &base, machine, &lines).await;

    let url = |format: &str| {
        format!(
            "{base}/api/v1/machines/{machine}/report?from={}&to={}&format={format}",
            t0 - 10.0,
            t0 + 1200.0
        )
    };
    let report: Value = serde_json::from_slice(
        &client
            .get(url("json"))
            .send()
            .await
            .unwrap()
            .bytes()
            .await
            .unwrap(),
    )
    .unwrap();
    let advance = &report["advance"];
    assert_eq!(
        advance["ring_numbers"],
        json!([{"first": 7, "last": 8}, {"first": 1, "last": 100}])
    );
    assert_eq!(advance["rings"], 102);
    // Ring 8: 200 s at 25 mm/s; ring 1 of drive B is no advance (the
    // station went back 10 m); rings 2 to 100: 4 s each, 0.1 m (the last
    // 0.05 m: the drive's last position is 2 s before it).
    let rings = report["rings"].as_array().unwrap();
    assert_eq!(rings[2]["advance_m"], Value::Null);
    let station = |i: usize| rings[i]["station_m"].as_f64().unwrap();
    let expected = 5.0 + (station(101) - station(2));
    assert!((expected - 14.85).abs() < 1e-6, "{expected}");
    let got = advance["advance_m"].as_f64().unwrap();
    assert!((got - expected).abs() < 1e-6, "{got} vs {expected}");
    assert_eq!(advance["advance_from"], "rings");
    let stretches = advance["stretches"].as_array().unwrap();
    assert_eq!(stretches.len(), 2, "{stretches:?}");
    assert!(
        stretches[1]["from_station_m"].as_f64().unwrap()
            < stretches[0]["to_station_m"].as_f64().unwrap()
    );

    // The page's chart: a line per drive and plane, none back in time.
    let html = client
        .get(url("html"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let horizontal = html.matches("stroke=\"#1f77b4\"").count();
    assert_eq!(horizontal, 2, "one horizontal line per drive");
    assert!(
        html.contains("7 to 8, then 1 to 100"),
        "ring numbers as logged"
    );
    for polyline in html.split("<polyline").skip(1) {
        let points = polyline
            .split("points=\"")
            .nth(1)
            .unwrap()
            .split('"')
            .next()
            .unwrap();
        let xs: Vec<f64> = points
            .split(' ')
            .map(|p| p.split(',').next().unwrap().parse().unwrap())
            .collect();
        assert!(
            xs.windows(2).all(|w| w[1] >= w[0] - 1.0),
            "a line back: {xs:?}"
        );
    }

    // The PDF: the header block, and the ring log's headings again on the
    // page it runs onto.
    let pdf = client
        .get(url("pdf"))
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap();
    let path = dir.path().join("again.pdf");
    std::fs::write(&path, &pdf).unwrap();
    if let Some(text) = pdf_text(&path) {
        for label in [
            "Project",
            "Machine",
            "Shift",
            "Generated at",
            "Operator",
            "Sign-off",
        ] {
            assert!(text.contains(label), "the PDF lacks {label}:\n{text}");
        }
        let pages: Vec<&str> = text.split('\u{c}').collect();
        assert!(pages.len() >= 3, "{} pages", pages.len());
        let continued = pages
            .iter()
            .filter(|p| p.contains("Ring log (continued)"))
            .collect::<Vec<_>>();
        assert!(!continued.is_empty(), "{text}");
        for page in continued {
            let after = page.split("Ring log (continued)").nth(1).unwrap();
            let headings = after.lines().find(|l| !l.trim().is_empty()).unwrap();
            for heading in ["ring", "completed (UTC)", "chainage", "advance m"] {
                assert!(headings.contains(heading), "{headings}");
            }
        }
    }
    server.stop().await;
}

/// Issue 56: the as-built report of a drive of 2,000 rings, every ring in
/// the JSON, the CSV and the PDF (its time printed: the bar is 10 s; a
/// timed assertion would fail on a loaded machine, not on a slow report).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_as_built_report_holds_every_ring() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let machine = "tbm-built";
    declare_machine(
        &client,
        &base,
        machine,
        &common::on_an_axis("TBM built").to_string(),
    )
    .await;
    // 2,000 rings 30 s apart, each after a laser position 1.5 m on, on a
    // 100 m axis: the station cycles (a new drive every 60 rings).
    let t0 = (wall_clock_s() - 2000.0 * 30.0 - 100.0).floor();
    let mut lines = Vec::new();
    for k in 0..2000u64 {
        let t = t0 + 30.0 * k as f64;
        let station = 10.0 + 1.5 * (k % 60) as f64;
        lines.push(json!({"t": t, "sensor": "laser", "pitch_deg": 0.0, "roll_deg": 0.0,
            "yaw_deg": 0.0, "easting_m": 1000.01, "northing_m": 5000.0 + station, "height_m": 50.0}));
        lines.push(
            json!({"t": t + 1.0, "sensor": "inclinometer", "pitch_deg": 0.0, "roll_deg": 0.0}),
        );
        lines.push(json!({"t": t + 2.0, "sensor": "advance", "ring": k + 1,
            "strokes_mm": [1500.0 + (k % 7) as f64, 1500.0, 1500.0, 1500.0]}));
    }
    let lines: Vec<String> = lines.iter().map(Value::to_string).collect();
    for chunk in lines.chunks(3000) {
        post_ndjson(&client, &base, machine, chunk).await;
    }
    let url = |format: &str| format!("{base}/api/v1/machines/{machine}/as-built?format={format}");
    let built: Value = serde_json::from_slice(
        &client
            .get(url("json"))
            .send()
            .await
            .unwrap()
            .bytes()
            .await
            .unwrap(),
    )
    .unwrap();
    let rings = built["rings"].as_array().unwrap();
    assert_eq!(rings.len(), 2000);
    assert_eq!(
        (&rings[0]["ring"], &rings[1999]["ring"]),
        (&json!(1), &json!(2000))
    );
    assert_eq!(
        rings[3]["strokes_mm"],
        json!([1503.0, 1500.0, 1500.0, 1500.0])
    );
    let csv = client
        .get(url("csv"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert_eq!(csv_table(&csv, "ring").len(), 2000);
    let started = std::time::Instant::now();
    let pdf = client.get(url("pdf")).send().await.unwrap();
    assert_eq!(pdf.status(), 200);
    let pdf = pdf.bytes().await.unwrap();
    eprintln!(
        "as-built PDF of 2000 rings: {:.2} s, {} bytes",
        started.elapsed().as_secs_f64(),
        pdf.len()
    );
    let path = dir.path().join("built.pdf");
    std::fs::write(&path, &pdf).unwrap();
    if let Some(text) = pdf_text(&path) {
        assert!(text.contains("As-built report: TBM built"));
        // The last ring with its strokes (k = 1999: 1500 + 1999 mod 7),
        // and its chainage (60 rings a drive: ring 2000 is the 20th of
        // its drive, station 38.5).
        let last = text
            .lines()
            .find(|l| l.trim_start().starts_with("2000 "))
            .expect("ring 2000");
        assert!(
            last.contains("0+038.500") && last.contains("1504.0 1500.0 1500.0 1500.0"),
            "{last}"
        );
    }
    server.stop().await;
}
