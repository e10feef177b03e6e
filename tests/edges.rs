//! The edges integrators meet: Grafana's millisecond epochs, NDJSON sent
//! without its content type, a stalled server (503, not 408), estimates
//! exported as NDJSON and CSV, and a failed sign-in shown as a page.

mod common;

use std::time::Duration;

use common::{TestServer, get_json, get_text, post_ndjson, put_machine, send_ndjson};
use serde_json::{Value, json};
use tunnelnav::server::settings::Limits;

const T0: i64 = 1_772_431_200;

/// A TBM's pitch changes slowly (0.001° a second here): a step of 0.1° a
/// second is a spike to the inclinometer monitor, not fused until it has
/// held for four readings.
fn inclinometer(i: i64) -> String {
    json!({"t": T0 + i, "sensor": "inclinometer", "pitch_deg": 0.001 * i as f64, "roll_deg": 0.2})
        .to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn millisecond_epochs_ndjson_hints_and_estimate_exports() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    put_machine(&client, &base, "tbm-edges").await;
    let lines: Vec<String> = (0..20).map(inclinometer).collect();
    post_ndjson(&client, &base, "tbm-edges", &lines).await;

    // Grafana's milliseconds mean the same range as seconds.
    let api = "/api/v1/machines/tbm-edges/estimates";
    let seconds = get_json(
        &client,
        &base,
        &format!("{api}?from={}&to={}", T0 + 5, T0 + 9),
    )
    .await;
    let millis = get_json(
        &client,
        &base,
        &format!("{api}?from={}&to={}", (T0 + 5) * 1000, (T0 + 9) * 1000),
    )
    .await;
    assert_eq!(seconds["estimates"].as_array().unwrap().len(), 5);
    assert_eq!(seconds["estimates"], millis["estimates"]);
    assert_eq!(millis["from"], (T0 + 5) as f64);

    // NDJSON posted as JSON: a hint, nothing stored.
    let more: Vec<String> = (20..23).map(inclinometer).collect();
    let response = client
        .post(format!("{base}/api/v1/machines/tbm-edges/readings"))
        .header("content-type", "application/json")
        .body(more.join("\n"))
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 400);
    let error: Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
    let said = error["error"].as_str().unwrap();
    assert!(
        said.contains("looks like NDJSON (3 lines") && said.contains("application/x-ndjson"),
        "{said}"
    );

    // Estimates exported: NDJSON (the page's estimates, every one) and CSV.
    let page = get_json(&client, &base, &format!("{api}?max_points=1000")).await;
    let estimates = page["estimates"].as_array().unwrap();
    assert_eq!(estimates.len(), 20);
    let ndjson = client
        .get(format!("{base}{api}?format=ndjson"))
        .send()
        .await
        .unwrap();
    assert_eq!(
        ndjson.headers()["content-type"].to_str().unwrap(),
        "application/x-ndjson"
    );
    let exported: Vec<Value> = ndjson
        .text()
        .await
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(&exported, estimates);
    let csv = get_text(
        &client,
        &base,
        &format!("{api}?format=csv&from={}", T0 + 10),
    )
    .await;
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 1 + 10, "{csv}");
    let header: Vec<&str> = rows[0].split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (t, pitch, machine) = (column("t"), column("pitch_deg"), column("machine"));
    let first: Vec<&str> = rows[1].split(',').collect();
    assert_eq!(first[t].parse::<f64>().unwrap(), (T0 + 10) as f64);
    assert_eq!(first[machine], "\"tbm-edges\"");
    let pitch_deg: f64 = first[pitch].parse().unwrap();
    let expected = estimates[10]["pitch_deg"].as_f64().unwrap();
    assert_eq!(pitch_deg, expected);
    // Refusals name what was wrong.
    for (query, word) in [
        ("format=xml", "format"),
        ("format=csv&max_points=10", "max_points"),
    ] {
        let refused = client
            .get(format!("{base}{api}?{query}"))
            .send()
            .await
            .unwrap();
        assert_eq!(refused.status(), 400, "{query}");
        assert!(refused.text().await.unwrap().contains(word), "{query}");
    }
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_server_answers_503_not_408() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start_with(
        dir.path(),
        Limits {
            request_timeout: Duration::from_secs(1),
            ..Limits::default()
        },
    )
    .await;
    let client = reqwest::Client::new();
    let base = server.url("");
    put_machine(&client, &base, "tbm-stall").await;
    // The store's writer is held up for 3 s (as by a stuck disk).
    let store = server.state.store.sqlite().unwrap().clone();
    let stuck = tokio::spawn(async move {
        store
            .maintain(|_| {
                std::thread::sleep(Duration::from_secs(3));
                Ok(())
            })
            .await
    });
    tokio::time::sleep(Duration::from_millis(100)).await;
    let response = send_ndjson(&client, &base, "tbm-stall", &[inclinometer(0)])
        .await
        .unwrap();
    assert_eq!(response.status(), 503);
    assert_eq!(response.headers()["retry-after"], "1");
    let said = response.text().await.unwrap();
    assert!(said.contains("did not answer within 1 s"), "{said}");
    stuck.await.unwrap().unwrap();
    let metrics = get_text(&client, &base, "/metrics").await;
    assert!(
        metrics.contains(r#"tunnelnav_refusals_total{reason="stalled"} 1"#),
        "{metrics}"
    );
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failed_sign_in_is_shown_as_the_login_page() {
    let dir = tempfile::tempdir().unwrap();
    {
        let conn = tunnelnav::store::Store::connect(dir.path()).unwrap();
        tunnelnav::store::sqlite::tokens::create(
            &conn,
            "reader",
            tunnelnav::auth::Scope::Read,
            None,
            0.0,
        )
        .unwrap();
    }
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let response = client
        .post(server.url("/login"))
        .header("content-type", "application/x-www-form-urlencoded")
        .body("token=tnv_not-a-token%3Cscript%3E")
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 401);
    assert!(
        response.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/html")
    );
    let page = response.text().await.unwrap();
    assert!(
        page.contains(r#"<p class="login-error" role="alert">Not signed in:"#),
        "{page}"
    );
    assert!(page.contains(r#"<form method="post" action="/login">"#));
    assert!(
        !page.contains("<script>"),
        "nothing the client sent is echoed raw"
    );
    let blank = client.get(server.url("/login")).send().await.unwrap();
    assert!(!blank.text().await.unwrap().contains("login-error"));
    server.stop().await;
}
