//! The real binary killed and restarted: acknowledged readings survive
//! SIGKILL, and the engines continue as if the server had never stopped.

mod common;

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::{
    ServerProcess, all_estimates, drive, exported_readings, post_ndjson, put_machine, reading_key,
    replay, send_ndjson,
};
use tunnelnav::sim::tbm::Dropout;

fn times(lines: &[String]) -> Vec<(u64, String)> {
    lines.iter().map(|l| reading_key(l)).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn estimates_continue_across_sigkill_and_sigterm_as_if_never_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let client = reqwest::Client::new();
    // Long enough that the stops fall after snapshots and between them.
    let lines = drive(
        12.0,
        4,
        vec![Dropout {
            start_h: 7.0,
            minutes: 45.0,
        }],
    );
    let cut_a = lines.len() * 45 / 100;
    let cut_b = lines.len() * 80 / 100;

    let server = ServerProcess::start(dir.path());
    let base = server.url("");
    put_machine(&client, &base, "tbm").await;
    for chunk in lines[..cut_a].chunks(1000) {
        post_ndjson(&client, &base, "tbm", chunk).await;
    }
    server.kill();

    let server = ServerProcess::start(dir.path());
    let base = server.url("");
    for chunk in lines[cut_a..cut_b].chunks(1000) {
        post_ndjson(&client, &base, "tbm", chunk).await;
    }
    let status = server.terminate();
    assert!(status.success(), "SIGTERM exits cleanly: {status:?}");

    let server = ServerProcess::start(dir.path());
    let base = server.url("");
    for chunk in lines[cut_b..].chunks(1000) {
        post_ndjson(&client, &base, "tbm", chunk).await;
    }
    let served = all_estimates(&client, &base, "tbm").await;
    let replayed = replay("tbm", &lines);
    assert_eq!(served.len(), replayed.len());
    let first_difference = served.iter().zip(&replayed).position(|(a, b)| a != b);
    assert_eq!(
        first_difference, None,
        "server and uninterrupted replay differ"
    );
    server.kill();
}

/// A machine and the readings of one acknowledged request.
type Acknowledged = (String, Vec<String>);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_acknowledged_reading_survives_sigkill_under_load() {
    let dir = tempfile::tempdir().unwrap();
    let client = reqwest::Client::new();
    let server = ServerProcess::start(dir.path());
    let base = server.url("");
    let lines = drive(48.0, 8, vec![]);
    for machine in ["k0", "k1", "k2", "k3"] {
        put_machine(&client, &base, machine).await;
    }
    // Four gateways post concurrently; each records what was acknowledged.
    let acknowledged: Arc<Mutex<Vec<Acknowledged>>> = Arc::default();
    let mut gateways = Vec::new();
    for (g, machine) in ["k0", "k1", "k2", "k3"].into_iter().enumerate() {
        let (client, base, acknowledged) = (client.clone(), base.clone(), acknowledged.clone());
        let lines = lines.clone();
        gateways.push(tokio::spawn(async move {
            for chunk in lines.chunks(50 + 37 * g) {
                let response = send_ndjson(&client, &base, machine, chunk).await;
                // Only a complete 200 answer is an acknowledgement.
                let complete = match response {
                    Ok(r) if r.status() == 200 => r.bytes().await.is_ok(),
                    _ => false,
                };
                if !complete {
                    return;
                }
                acknowledged
                    .lock()
                    .unwrap()
                    .push((machine.to_string(), chunk.to_vec()));
            }
        }));
    }
    tokio::time::sleep(Duration::from_millis(1000)).await;
    server.kill();
    for gateway in gateways {
        gateway.await.unwrap();
    }
    let acknowledged = acknowledged.lock().unwrap().clone();
    assert!(acknowledged.len() > 10, "the load ran before the kill");
    let acknowledged_readings: usize = acknowledged.iter().map(|(_, c)| c.len()).sum();
    assert!(
        acknowledged_readings < 4 * lines.len(),
        "the kill came before the gateways finished"
    );

    let server = ServerProcess::start(dir.path());
    let base = server.url("");
    let mut total = 0;
    for machine in ["k0", "k1", "k2", "k3"] {
        let stored = exported_readings(&client, &base, machine).await;
        let stored_keys: BTreeSet<_> = times(&stored).into_iter().collect();
        assert_eq!(stored_keys.len(), stored.len(), "each reading stored once");
        for (m, chunk) in &acknowledged {
            if m == machine {
                for key in times(chunk) {
                    assert!(
                        stored_keys.contains(&key),
                        "{machine}: acknowledged {key:?} lost"
                    );
                    total += 1;
                }
            }
        }
        // The restored engines carry on: more readings give more estimates.
        let before = all_estimates(&client, &base, machine).await.len();
        let next: Vec<String> = lines[stored.len()..(stored.len() + 100).min(lines.len())].to_vec();
        post_ndjson(&client, &base, machine, &next).await;
        let after = all_estimates(&client, &base, machine).await.len();
        assert!(after > before);
    }
    eprintln!("{total} acknowledged readings all present after SIGKILL");
    server.kill();
}
