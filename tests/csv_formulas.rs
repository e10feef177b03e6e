//! Issue 57: no cell of any CSV the service writes is read as a formula by
//! a spreadsheet. A machine whose id and name start as formulas do
//! (`-tbm`, `=2+3`), a token named `@lead` that acknowledges its alarm:
//! every cell of the shift report's, the as-built report's, every
//! stream's and the readings' CSV either starts otherwise or is a number.

mod common;

use common::{TestServer, declare_machine, post_ndjson};
use serde_json::json;

/// The cells of `csv` a spreadsheet would read as a formula: starting with
/// `=`, `+`, `-`, `@`, a tab or a carriage return and not a number.
fn formulas(csv: &str) -> Vec<String> {
    csv.lines()
        .flat_map(common::csv_cells)
        .filter(|c| c.starts_with(['=', '+', '-', '@', '\t', '\r']) && c.parse::<f64>().is_err())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_csv_cell_is_a_formula() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let machine = "-tbm";
    let mut declaration = common::on_an_axis("=2+3");
    declaration["steering"] =
        json!({"min_radius_m": 1500.0, "step_m": 1.5, "cylinder_circle_m": 6.0});
    declare_machine(&client, &base, machine, &declaration.to_string()).await;
    // 120 mm right of the axis (past the 100 mm alarm), rings closed.
    let t0 = (tunnelnav::clock::wall_clock_s() - 300.0).floor();
    let mut lines = common::laser_pairs(t0, 60, 0.12);
    lines.push(
        json!({"t": t0 + 50.5, "sensor": "advance", "ring": 1, "strokes_mm": [1500.0, 1490.0]})
            .to_string(),
    );
    lines.push(json!({"t": t0 + 100.5, "sensor": "advance", "ring": 2}).to_string());
    post_ndjson(&client, &base, machine, &lines).await;
    // The deviation alarm, acknowledged by a token named as a formula.
    let mut alarm = serde_json::Value::Null;
    for _ in 0..50 {
        let listed = common::get_json(&client, &base, "/api/v1/alarms?state=all").await;
        if let Some(a) = listed["alarms"]
            .as_array()
            .unwrap()
            .iter()
            .find(|a| a["machine"] == machine && a["kind"] == "deviation")
        {
            alarm = a.clone();
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    assert!(alarm.is_object(), "the deviation alarm is raised");
    let token = common::operator_token(dir.path(), "@lead");
    tokio::time::sleep(std::time::Duration::from_millis(2100)).await;
    let acked = client
        .post(format!("{base}/api/v1/alarms/{}/ack", alarm["id"]))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    assert_eq!(acked.status(), 200);

    let api = format!("{base}/api/v1/machines/{machine}");
    let range = format!("from={}&to={}", t0 - 10.0, t0 + 400.0);
    let mut urls = vec![
        format!("{api}/report?{range}&format=csv"),
        format!("{api}/as-built?format=csv"),
        format!("{api}/readings?format=csv"),
    ];
    for stream in ["attitude", "dta", "steer", "rings"] {
        urls.push(format!("{api}/estimates?engine={stream}&format=csv"));
    }
    for url in urls {
        let response = client.get(&url).bearer_auth(&token).send().await.unwrap();
        assert_eq!(response.status(), 200, "{url}");
        let csv = response.text().await.unwrap();
        assert!(csv.lines().count() > 1, "{url}: {csv}");
        let found = formulas(&csv);
        assert!(found.is_empty(), "{url}: {found:?}");
    }
    // What was neutralised still reads as itself after the quote.
    let report = client
        .get(format!("{api}/report?{range}&format=csv"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(report.contains(",'-tbm,'=2+3,"), "{report}");
    assert!(report.contains("'@lead"), "{report}");
    server.stop().await;
}
