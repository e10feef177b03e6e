//! The real binary killed with SIGKILL 25 times (20 on the PostgreSQL
//! store) at random moments while
//! four gateways post concurrently, restarted each time on the same data
//! dir. Each gateway resends what was not acknowledged (as a real one
//! does). At the end: every acknowledged reading is stored exactly once,
//! and each machine's stored estimates are exactly what `replay` makes of
//! its stored readings, so the engines were restored after every kill as
//! if the server had never stopped.

mod common;

use std::collections::BTreeSet;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use common::{
    ServerProcess, drive, exported_readings, put_machine, reading_key, replay_engine, send_ndjson,
};

const MACHINES: [&str; 4] = ["k0", "k1", "k2", "k3"];

/// Every stored estimate of a machine, fetched in windows of 20 000 s so
/// that none is downsampled.
async fn estimates_in_windows(
    client: &reqwest::Client,
    base: &str,
    machine: &str,
) -> Vec<serde_json::Value> {
    let mut all = Vec::new();
    let mut from = 1_772_431_200.0_f64 - 10.0;
    loop {
        let to = from + 20_000.0;
        let response = client
            .get(format!(
                "{base}/api/v1/machines/{machine}/estimates?from={from}&to={to}&max_points=100000"
            ))
            .send()
            .await
            .unwrap();
        assert_eq!(response.status(), 200);
        let body: serde_json::Value =
            serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
        assert_eq!(body["downsampled"], false);
        let page = body["estimates"].as_array().unwrap();
        // `to` is inclusive: drop an estimate at the boundary seen twice.
        for e in page {
            if all
                .last()
                .is_none_or(|l: &serde_json::Value| l["t"].as_f64() < e["t"].as_f64())
            {
                all.push(e.clone());
            }
        }
        if page.is_empty() && from > 1_772_431_200.0 + 48.0 * 3600.0 {
            return all;
        }
        from = to;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn twenty_five_sigkills_under_load_lose_nothing_and_change_nothing() {
    let dir = tempfile::tempdir().unwrap();
    sigkills_under_load(25, dir.path(), &[]).await;
}

/// The same on the PostgreSQL store (issue 37): 20 SIGKILLs of the server
/// (PostgreSQL itself keeps running, as an office database does).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn twenty_sigkills_under_load_on_postgres_lose_nothing_and_change_nothing() {
    let Some(cluster) = common::postgres::PgCluster::start() else {
        return;
    };
    let url = cluster.database("kills");
    let dir = tempfile::tempdir().unwrap();
    sigkills_under_load(20, dir.path(), &["--store", &url]).await;
}

/// `kills` SIGKILLs at random moments while four gateways post, the
/// server started with `args` each time; then every acknowledged reading
/// is stored once and the estimates equal replay.
async fn sigkills_under_load(kills_wanted: usize, dir: &std::path::Path, args: &[&str]) {
    let client = reqwest::Client::new();
    let lines = Arc::new(drive(48.0, 21, vec![]));
    // How far each gateway's acknowledged readings reach (in its lines).
    let acknowledged: Arc<Vec<AtomicUsize>> =
        Arc::new(MACHINES.iter().map(|_| AtomicUsize::new(0)).collect());
    // A fixed pseudo-random sequence of kill moments (200–700 ms).
    let mut state = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next_delay = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        200 + state % 500
    };

    let mut kills = 0;
    let mut load_ms = 0;
    for cycle in 0..=kills_wanted {
        let server = ServerProcess::start_with_args(dir, args);
        let base = server.url("");
        if cycle == 0 {
            for machine in MACHINES {
                put_machine(&client, &base, machine).await;
            }
        }
        if cycle == kills_wanted {
            // The last start: check everything.
            let mut total = 0;
            for (g, machine) in MACHINES.into_iter().enumerate() {
                let reach = acknowledged[g].load(Ordering::SeqCst);
                let stored = exported_readings(&client, &base, machine).await;
                let keys: BTreeSet<_> = stored.iter().map(|l| reading_key(l)).collect();
                assert_eq!(
                    keys.len(),
                    stored.len(),
                    "{machine}: a reading stored twice"
                );
                for line in &lines[..reach] {
                    assert!(
                        keys.contains(&reading_key(line)),
                        "{machine}: acknowledged {line} lost"
                    );
                }
                // Nothing beyond what was sent (at most one unacknowledged chunk).
                assert!(stored.len() >= reach && stored.len() <= reach + 400);
                total += reach;
                let served = estimates_in_windows(&client, &base, machine).await;
                let replayed = replay_engine(machine, "attitude", &[], &stored);
                assert_eq!(served.len(), replayed.len(), "{machine}");
                for (i, (s, r)) in served.iter().zip(&replayed).enumerate() {
                    assert_eq!(s, r, "{machine}: estimate {i}");
                }
            }
            eprintln!(
                "{kills} SIGKILLs under load; {total} acknowledged readings all present once \
                 ({:.0} readings/s acknowledged over {:.1} s of load between kills); estimates equal replay",
                total as f64 / (load_ms as f64 / 1000.0),
                load_ms as f64 / 1000.0
            );
            server.kill();
            break;
        }

        let mut gateways = Vec::new();
        for (g, machine) in MACHINES.into_iter().enumerate() {
            let (client, base) = (client.clone(), base.clone());
            let (lines, acknowledged) = (lines.clone(), acknowledged.clone());
            gateways.push(tokio::spawn(async move {
                let chunk_len = 50 + 97 * g;
                loop {
                    let from = acknowledged[g].load(Ordering::SeqCst);
                    if from >= lines.len() {
                        return;
                    }
                    let chunk = &lines[from..(from + chunk_len).min(lines.len())];
                    let complete = match send_ndjson(&client, &base, machine, chunk).await {
                        Ok(r) if r.status() == 200 => r.bytes().await.is_ok(),
                        _ => false,
                    };
                    if !complete {
                        return; // the server is gone: resend next time
                    }
                    acknowledged[g].store(from + chunk.len(), Ordering::SeqCst);
                    // A gateway's pace (and the drive outlasts the kills).
                    tokio::time::sleep(Duration::from_millis(10)).await;
                }
            }));
        }
        let delay = next_delay();
        tokio::time::sleep(Duration::from_millis(delay)).await;
        load_ms += delay;
        server.kill();
        kills += 1;
        for gateway in gateways {
            gateway.await.unwrap();
        }
    }
    assert_eq!(kills, kills_wanted);
    let reached: usize = acknowledged.iter().map(|a| a.load(Ordering::SeqCst)).sum();
    assert!(reached > 4 * 20_000, "the load ran: {reached} readings");
    assert!(reached < 4 * lines.len(), "the kills came before the end");
}

/// SIGTERM under load, with a live client: requests in flight are
/// answered, the live socket gets a close frame, the process exits 0
/// within a few seconds, and a restart carries on exactly (estimates equal
/// replay).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn sigterm_under_load_answers_in_flight_requests_and_exits_cleanly() {
    use futures_util::StreamExt;
    use tokio_tungstenite::tungstenite::Message;

    let dir = tempfile::tempdir().unwrap();
    let client = reqwest::Client::new();
    let lines = Arc::new(drive(24.0, 31, vec![]));
    let server = ServerProcess::start(dir.path());
    let base = server.url("");
    put_machine(&client, &base, "t0").await;
    let live_url = server
        .url("/api/v1/machines/t0/live")
        .replace("http://", "ws://");
    let (mut live, _) = tokio_tungstenite::connect_async(live_url.as_str())
        .await
        .unwrap();
    // A dashboard reads its live socket all along.
    let reader = tokio::spawn(async move {
        let mut estimates = 0;
        loop {
            match live.next().await {
                Some(Ok(Message::Close(frame))) => return (estimates, frame.is_some()),
                Some(Ok(_)) => estimates += 1,
                other => {
                    panic!("expected a close frame, got {other:?} after {estimates} estimates")
                }
            }
        }
    });
    let acknowledged = Arc::new(AtomicUsize::new(0));
    let gateway = {
        let (client, base) = (client.clone(), base.clone());
        let (lines, acknowledged) = (lines.clone(), acknowledged.clone());
        tokio::spawn(async move {
            let mut refused = 0;
            loop {
                let from = acknowledged.load(Ordering::SeqCst);
                if from == lines.len() {
                    return;
                }
                let chunk = &lines[from..(from + 300).min(lines.len())];
                match send_ndjson(&client, &base, "t0", chunk).await {
                    Ok(r) if r.status() == 200 => {
                        r.bytes().await.unwrap();
                        acknowledged.store(from + chunk.len(), Ordering::SeqCst);
                    }
                    // A request that got an answer other than 200 while
                    // stopping would be a lost in-flight request.
                    Ok(r) => panic!("in flight at shutdown: {}", r.status()),
                    Err(_) => {
                        refused += 1;
                        if refused > 20 {
                            return;
                        }
                        tokio::time::sleep(Duration::from_millis(20)).await;
                    }
                }
            }
        })
    };
    // Stop it mid-drive, while the gateway keeps sending.
    while acknowledged.load(Ordering::SeqCst) < 3000 {
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let asked = std::time::Instant::now();
    let status = server.terminate();
    let took = asked.elapsed();
    assert_eq!(status.code(), Some(0));
    assert!(took < Duration::from_secs(5), "stopping took {took:?}");
    let (estimates, closed) = reader.await.unwrap();
    assert!(closed, "the close frame says why");
    assert!(
        estimates > 100,
        "{estimates} live estimates before the close"
    );
    gateway.await.unwrap();
    let reached = acknowledged.load(Ordering::SeqCst);
    assert!(reached > 1000, "{reached}");

    let server = ServerProcess::start(dir.path());
    let base = server.url("");
    let stored = exported_readings(&client, &base, "t0").await;
    assert_eq!(stored[..], lines[..stored.len()]);
    assert!(stored.len() >= reached);
    let served = estimates_in_windows(&client, &base, "t0").await;
    let replayed = replay_engine("t0", "attitude", &[], &stored);
    assert_eq!(served, replayed);
    eprintln!(
        "SIGTERM answered in {took:?} with {reached} readings acknowledged; estimates equal replay"
    );
    server.kill();
}
