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

/// A JSON number or null as the CSV writes it.
fn csv_of(value: &Value) -> String {
    match value {
        Value::Null => String::new(),
        Value::Array(items) => items.iter().map(csv_of).collect::<Vec<_>>().join(" "),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// One CSV line's cells (quoted cells with doubled quotes).
fn csv_cells(line: &str) -> Vec<String> {
    let (mut cells, mut cell, mut quoted) = (Vec::new(), String::new(), false);
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                cell.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => cells.push(std::mem::take(&mut cell)),
            _ => cell.push(c),
        }
    }
    cells.push(cell);
    cells
}

/// The CSV's rows of `table`, as column name → cell.
fn csv_table(csv: &str, table: &str) -> Vec<Vec<(String, String)>> {
    let mut rows = csv.lines().map(csv_cells).filter(|cells| cells[0] == table);
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
    let token = common::read_token(dir.path(), "shift-lead");
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
    assert_eq!(advance["advance_m"], last_station - first_station);

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
                        "from": report["from"], "to": report["to"]}]);
    let one = |field: &str| json!([report[field].clone()]);
    for (table, rows) in [
        ("report", whole),
        ("advance", one("advance")),
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
        format!("{:.3}", rings[2]["station_m"].as_f64().unwrap()),
        format!("{:.3}", advance["advance_m"].as_f64().unwrap()),
        "shift-lead".to_string(),
        "0:01:02".to_string(),
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
    match std::process::Command::new("pdftotext")
        .arg("-layout")
        .arg(&path)
        .arg("-")
        .output()
    {
        Ok(text) => {
            assert!(text.status.success());
            let text = String::from_utf8(text.stdout).unwrap();
            for number in &numbers {
                assert!(
                    text.contains(number.as_str()),
                    "the PDF lacks {number}:\n{text}"
                );
            }
        }
        Err(e) if std::env::var("TUNNELNAV_PDFTOTEXT_TEST").as_deref() == Ok("required") => {
            panic!("pdftotext (Debian's poppler-utils) is required: {e}")
        }
        Err(e) => eprintln!(
            "SKIPPED reading the PDF back: no pdftotext ({e}); apt-get install poppler-utils"
        ),
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
