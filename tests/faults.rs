//! Back-pressure and a busy database: while another process holds the
//! database's write lock, ingest answers 503 with `Retry-After` (the
//! machine's queue full, or the store unable to commit) instead of
//! buffering; once the lock goes, gateways that retry get everything in,
//! each reading stored exactly once, nothing acknowledged lost, and the
//! engines carry on. Also: live clients per machine are capped, and a
//! request not answered in time gets a JSON 408.

mod common;

use std::collections::BTreeMap;
use std::time::Duration;

use common::{TestServer, declare_machine, exported_readings, send_ndjson};
use tunnelnav::server::settings::Limits;

const MACHINE: &str = "tbm-busy";

/// A test server with these limits and the attitude machine declared.
async fn server_with(
    dir: &std::path::Path,
    limits: Limits,
) -> (TestServer, reqwest::Client, String) {
    let server = TestServer::start_with(dir, limits).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    declare_machine(
        &client,
        &base,
        MACHINE,
        r#"{"name": "TBM", "engines": {"attitude": {}}}"#,
    )
    .await;
    (server, client, base)
}

fn reading(i: usize) -> String {
    format!(
        r#"{{"t": {}, "sensor": "inclinometer", "pitch_deg": {:.4}, "roll_deg": 1.0}}"#,
        1_772_431_200 + i,
        0.5 + (i as f64) * 1e-4
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_busy_database_gets_503_and_loses_nothing_acknowledged() {
    let dir = tempfile::tempdir().unwrap();
    let (server, client, base) = server_with(
        dir.path(),
        Limits {
            machine_queue: 4,
            ..Limits::default()
        },
    )
    .await;

    // Another process takes the write lock for 12 s: longer than two of
    // the store's 5 s busy waits, so the group commit fails and so does at
    // least the first request retried alone (503 for certain, not only
    // when the machine's queue happens to fill).
    let db = dir.path().join("tunnelnav.sqlite3");
    let (locked_tx, locked_rx) = std::sync::mpsc::channel();
    let holder = std::thread::spawn(move || {
        let conn = rusqlite::Connection::open(db).unwrap();
        conn.execute_batch("BEGIN IMMEDIATE").unwrap();
        locked_tx.send(()).unwrap();
        std::thread::sleep(Duration::from_secs(12));
        conn.execute_batch("COMMIT").unwrap();
    });
    locked_rx.recv().unwrap();

    // 100 gateway requests of 10 readings each, all at once.
    let batches: Vec<Vec<String>> = (0..100)
        .map(|b| (0..10).map(|i| reading(b * 10 + i)).collect())
        .collect();
    let mut outcome: BTreeMap<usize, u16> = BTreeMap::new();
    let mut pending: Vec<usize> = (0..batches.len()).collect();
    let mut rounds = 0;
    let mut saw_503 = 0;
    while !pending.is_empty() {
        rounds += 1;
        assert!(
            rounds < 60,
            "still refused after {rounds} rounds: {pending:?}"
        );
        let answers = futures_util::future::join_all(pending.iter().map(|&b| {
            let (client, base, lines) = (client.clone(), base.clone(), batches[b].clone());
            async move {
                let response = send_ndjson(&client, &base, MACHINE, &lines).await.unwrap();
                let status = response.status().as_u16();
                let retry = response
                    .headers()
                    .get("retry-after")
                    .map(|v| v.to_str().unwrap().to_string());
                let body: serde_json::Value =
                    serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
                (b, status, retry, body)
            }
        }))
        .await;
        pending.clear();
        for (b, status, retry, body) in answers {
            match status {
                200 => {
                    assert_eq!(
                        body["accepted"].as_u64().unwrap() + body["duplicates"].as_u64().unwrap(),
                        10,
                        "{body}"
                    );
                    outcome.insert(b, status);
                }
                503 => {
                    saw_503 += 1;
                    assert_eq!(retry.as_deref(), Some("1"), "{body}");
                    assert!(body["error"].is_string(), "{body}");
                    pending.push(b);
                }
                other => panic!("batch {b}: {other} {body}"),
            }
        }
        if !pending.is_empty() {
            tokio::time::sleep(Duration::from_millis(500)).await;
        }
    }
    holder.join().unwrap();
    assert!(saw_503 > 0, "the busy database was never reported");

    // Every reading once, and the engines fused them all.
    let stored = exported_readings(&client, &base, MACHINE).await;
    assert_eq!(stored.len(), 1000, "{} readings stored", stored.len());
    let mut times: Vec<f64> = stored
        .iter()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["t"]
                .as_f64()
                .unwrap()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times.dedup();
    assert_eq!(times.len(), 1000);
    // The engines carry on: later readings are fused. (The retried
    // batches came back in any order; with no reorder window a reading
    // older than one already fused is stored but not fused, and counted.)
    let later: Vec<String> = (1000..1010).map(reading).collect();
    common::post_ndjson(&client, &base, MACHINE, &later).await;
    let estimates = common::all_estimates(&client, &base, MACHINE).await;
    let status: serde_json::Value =
        common::get_json(&client, &base, &format!("/api/v1/machines/{MACHINE}")).await;
    let late = status["late_readings"].as_u64().unwrap() as usize;
    assert_eq!(
        estimates.len() + late,
        1010,
        "{} estimates, {late} late",
        estimates.len()
    );
    let last_t = estimates.last().unwrap()["t"].as_f64().unwrap();
    assert_eq!(last_t, (1_772_431_200 + 1009) as f64);
    eprintln!("503 answers: {saw_503}, rounds: {rounds}");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn live_clients_are_capped_per_machine() {
    let dir = tempfile::tempdir().unwrap();
    let (server, _, _) = server_with(
        dir.path(),
        Limits {
            max_live_clients_per_machine: 2,
            ..Limits::default()
        },
    )
    .await;
    let url = server.ws_url(&format!("/api/v1/machines/{MACHINE}/live"));
    let first = tokio_tungstenite::connect_async(url.as_str())
        .await
        .unwrap();
    let second = tokio_tungstenite::connect_async(url.as_str())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;
    match tokio_tungstenite::connect_async(url.as_str()).await {
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
            assert_eq!(response.status(), 503);
            let body = String::from_utf8(response.body().clone().unwrap_or_default()).unwrap();
            assert!(body.contains("live clients"), "{body}");
        }
        other => panic!("a third live client was let in: {other:?}"),
    }
    // Counted by reason.
    let metrics = common::get_text(&reqwest::Client::new(), &server.url(""), "/metrics").await;
    let refused = metrics
        .lines()
        .find_map(|l| l.strip_prefix(r#"tunnelnav_refusals_total{reason="too_many_clients"} "#))
        .and_then(|n| n.parse::<f64>().ok());
    assert!(refused >= Some(1.0), "{metrics}");
    drop((first, second));
    server.stop().await;
}

/// A full disk (the database capped at 1 MB): ingest answers 503 with
/// `Retry-After` and a clear error, everything acknowledged stays; with
/// room again (a larger cap after a restart) the gateway's resends all go
/// in, and the estimates are exactly what `replay` makes of the readings.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_gets_503_and_recovers_when_space_returns() {
    let dir = tempfile::tempdir().unwrap();
    let client = reqwest::Client::new();
    let lines = common::drive(6.0, 9, vec![]);
    let server = common::ServerProcess::start_with_args(dir.path(), &["--max-database-mb", "1"]);
    let base = server.url("");
    common::put_machine(&client, &base, "full").await;
    let mut acknowledged = 0;
    let mut full = None;
    for chunk in lines.chunks(500) {
        let response = send_ndjson(&client, &base, "full", chunk).await.unwrap();
        match response.status().as_u16() {
            200 => acknowledged += chunk.len(),
            503 => {
                assert_eq!(response.headers()["retry-after"], "1");
                full = Some(response.text().await.unwrap());
                break;
            }
            other => panic!("{other}: {}", response.text().await.unwrap()),
        }
    }
    let full = full.expect("the capped database filled up");
    assert!(full.contains("full"), "{full}");
    assert!(acknowledged > 1000, "{acknowledged} readings went in first");
    // Still full: the same answer, nothing changes, the server is healthy.
    let again = send_ndjson(
        &client,
        &base,
        "full",
        &lines[acknowledged..acknowledged + 500],
    )
    .await
    .unwrap();
    assert_eq!(again.status(), 503);
    let health = client.get(server.url("/healthz")).send().await.unwrap();
    assert_eq!(health.status(), 200);
    assert_eq!(server.terminate().code(), Some(0));

    // Space returns.
    let server = common::ServerProcess::start_with_args(dir.path(), &["--max-database-mb", "100"]);
    let base = server.url("");
    for chunk in lines[acknowledged..].chunks(2000) {
        common::post_ndjson(&client, &base, "full", chunk).await;
    }
    let stored = exported_readings(&client, &base, "full").await;
    assert_eq!(stored, lines, "every reading once, in order");
    let served = common::all_estimates(&client, &base, "full").await;
    let replayed = common::replay_engine("full", "attitude", &[], &lines);
    assert_eq!(served, replayed);
    eprintln!(
        "full after {acknowledged} readings; all {} in after space returned",
        lines.len()
    );
    server.terminate();
}

/// A request that is not answered in time (here: a body that never
/// finishes arriving) gets a JSON 408, and the server carries on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_request_gets_408_in_time() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let dir = tempfile::tempdir().unwrap();
    let (server, client, base) = server_with(
        dir.path(),
        Limits {
            request_timeout: Duration::from_millis(500),
            ..Limits::default()
        },
    )
    .await;
    let mut stream = tokio::net::TcpStream::connect(server.address)
        .await
        .unwrap();
    let head = format!(
        "POST /api/v1/machines/{MACHINE}/readings HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 1000\r\n\r\n{{\"t\": 17"
    );
    stream.write_all(head.as_bytes()).await.unwrap();
    let started = std::time::Instant::now();
    let mut answer = Vec::new();
    let mut buffer = [0u8; 4096];
    while !String::from_utf8_lossy(&answer).contains("}") {
        let n = tokio::time::timeout(Duration::from_secs(5), stream.read(&mut buffer))
            .await
            .expect("answered in time")
            .unwrap();
        if n == 0 {
            break;
        }
        answer.extend_from_slice(&buffer[..n]);
    }
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");
    assert!(
        answer.contains("body did not arrive within 0.5 s"),
        "{answer}"
    );
    assert!(started.elapsed() < Duration::from_secs(3));
    // Others are served meanwhile and after.
    let health = client.get(format!("{base}/healthz")).send().await.unwrap();
    assert_eq!(health.status(), 200);
    server.stop().await;
}
