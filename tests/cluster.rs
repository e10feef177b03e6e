//! Two server nodes on one PostgreSQL store (issue 37): ten machines
//! shared between them, their gateways posting to either node; one node
//! SIGKILLed under load. Its machines go on on the other within 10 s,
//! every acknowledged reading is stored once, and each machine's estimates
//! equal `replay` of its stored readings.

mod common;

use std::collections::BTreeSet;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use common::postgres::PgCluster;
use common::{
    ServerProcess, all_estimates, drive, exported_readings, put_machine, reading_key, send_ndjson,
};

const MACHINES: usize = 10;

/// `GET /api/v1/cluster` of the node at `base`.
async fn cluster(client: &reqwest::Client, base: &str) -> serde_json::Value {
    common::get_json(client, base, "/api/v1/cluster").await
}

/// The machines node `node` holds, by the report.
fn held(report: &serde_json::Value, node: &str) -> Vec<String> {
    report["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|n| n["node"] == node && n["live"] == true)
        .flat_map(|n| n["machines"].as_array().unwrap().clone())
        .map(|m| m.as_str().unwrap().to_string())
        .collect()
}

/// A cluster key file in `dir` (a 64-character key); its path.
fn cluster_key(dir: &std::path::Path) -> String {
    let path = dir.join("cluster.key");
    std::fs::write(
        &path,
        "# the nodes' shared key\n3f9c2a7be1d04c5a8f6e2b19d7c3a0e54b8f1c6d2e7a9b3f0c5d8e1a4b7c2f60\n",
    )
    .unwrap();
    path.to_str().unwrap().to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_node_killed_under_load_hands_its_machines_over_within_ten_seconds() {
    let Some(pg) = PgCluster::start() else {
        return;
    };
    let url = pg.database("cluster");
    let (dir_a, dir_b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let key = cluster_key(dir_a.path());
    let node = |dir: &std::path::Path, name: &str| {
        ServerProcess::start_with_args(
            dir,
            &["--store", &url, "--node", name, "--cluster-key-file", &key],
        )
    };
    let a = node(dir_a.path(), "a");
    let b = node(dir_b.path(), "b");
    let bases = [a.url(""), b.url("")];
    let client = reqwest::Client::new();
    let names: Vec<String> = (0..MACHINES).map(|i| format!("m{i}")).collect();
    for name in &names {
        put_machine(&client, &bases[0], name).await;
    }
    // Node a declared all ten; it hands half to b, one a second.
    let settled = Instant::now();
    loop {
        let report = cluster(&client, &bases[1]).await;
        let (on_a, on_b) = (held(&report, "a"), held(&report, "b"));
        if on_a.len() == MACHINES / 2 && on_b.len() == MACHINES / 2 {
            break;
        }
        assert!(
            settled.elapsed() < Duration::from_secs(30),
            "the nodes did not share the machines: {report}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let report = cluster(&client, &bases[0]).await;
    let on_a: BTreeSet<String> = held(&report, "a").into_iter().collect();

    // A live socket on node b for a machine node a fuses: it sees every
    // estimate, before the kill and after node b took the machine over.
    let watched = on_a.iter().next().unwrap().clone();
    let (mut socket, _) = tokio_tungstenite::connect_async(format!(
        "ws://{}/api/v1/machines/{watched}/live",
        &bases[1]["http://".len()..]
    ))
    .await
    .unwrap();
    type Frames = (Vec<serde_json::Value>, Vec<String>);
    let frames: Arc<std::sync::Mutex<Frames>> = Arc::default();
    let listening = {
        let frames = frames.clone();
        tokio::spawn(async move {
            use futures_util::StreamExt;
            while let Some(Ok(message)) = socket.next().await {
                if let tokio_tungstenite::tungstenite::Message::Text(text) = message {
                    let value: serde_json::Value = serde_json::from_str(&text).unwrap();
                    let mut frames = frames.lock().unwrap();
                    match value["event"].as_str() {
                        Some(event) => frames.1.push(event.to_string()),
                        None => frames.0.push(value),
                    }
                }
            }
        })
    };

    // Every machine's gateway posts to one node (half of them to the node
    // that does not fuse their machine: forwarded), and on any failure
    // tries the other node with the same chunk.
    let lines: Arc<Vec<Vec<String>>> = Arc::new(
        (0..MACHINES)
            .map(|i| drive(6.0, 40 + i as u64, vec![]))
            .collect(),
    );
    let acknowledged: Arc<Vec<AtomicUsize>> =
        Arc::new((0..MACHINES).map(|_| AtomicUsize::new(0)).collect());
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let killed_at: Arc<std::sync::Mutex<Option<Instant>>> = Arc::default();
    let mut gateways = Vec::new();
    for (g, name) in names.iter().cloned().enumerate() {
        let (client, bases) = (client.clone(), bases.clone());
        let (lines, acknowledged, stop, killed_at) = (
            lines.clone(),
            acknowledged.clone(),
            stop.clone(),
            killed_at.clone(),
        );
        gateways.push(tokio::spawn(async move {
            let mut node = g % 2;
            // The longest wait for an acknowledgement after the kill.
            let mut longest_outage = Duration::ZERO;
            let mut failing_since: Option<Instant> = None;
            while !stop.load(Ordering::SeqCst) {
                let from = acknowledged[g].load(Ordering::SeqCst);
                let chunk = &lines[g][from..(from + 100).min(lines[g].len())];
                if chunk.is_empty() {
                    break;
                }
                let ok = match send_ndjson(&client, &bases[node], &name, chunk).await {
                    Ok(r) if r.status() == 200 => r.bytes().await.is_ok(),
                    _ => false,
                };
                if ok {
                    acknowledged[g].store(from + chunk.len(), Ordering::SeqCst);
                    if let Some(since) = failing_since.take()
                        && killed_at.lock().unwrap().is_some()
                    {
                        longest_outage = longest_outage.max(since.elapsed());
                    }
                    tokio::time::sleep(Duration::from_millis(20)).await;
                } else {
                    failing_since.get_or_insert_with(Instant::now);
                    node = 1 - node;
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            }
            if let Some(since) = failing_since {
                longest_outage = longest_outage.max(since.elapsed());
            }
            longest_outage
        }));
    }
    tokio::time::sleep(Duration::from_secs(3)).await;
    let before: usize = acknowledged.iter().map(|a| a.load(Ordering::SeqCst)).sum();
    a.kill();
    *killed_at.lock().unwrap() = Some(Instant::now());
    tokio::time::sleep(Duration::from_secs(15)).await;
    stop.store(true, Ordering::SeqCst);
    let mut outages = Vec::new();
    for gateway in gateways {
        outages.push(gateway.await.unwrap());
    }

    // Node b holds everything now.
    let report = cluster(&client, &bases[1]).await;
    assert_eq!(held(&report, "b").len(), MACHINES, "{report}");
    let after: usize = acknowledged.iter().map(|a| a.load(Ordering::SeqCst)).sum();
    let mut worst = Duration::ZERO;
    for (g, name) in names.iter().enumerate() {
        let outage = outages[g];
        if on_a.contains(name) {
            worst = worst.max(outage);
            assert!(
                outage <= Duration::from_secs(10),
                "{name} (on the killed node) went unacknowledged for {outage:?}"
            );
        }
        let reach = acknowledged[g].load(Ordering::SeqCst);
        let stored = exported_readings(&client, &bases[1], name).await;
        let keys: BTreeSet<_> = stored.iter().map(|l| reading_key(l)).collect();
        assert_eq!(keys.len(), stored.len(), "{name}: a reading stored twice");
        for line in &lines[g][..reach] {
            assert!(
                keys.contains(&reading_key(line)),
                "{name}: acknowledged {line} lost"
            );
        }
        assert!(stored.len() <= reach + 100, "{name}: more than was sent");
        let served = all_estimates(&client, &bases[1], name).await;
        let replayed = common::replay(name, &stored);
        assert_eq!(served.len(), replayed.len(), "{name}");
        for (i, (s, r)) in served.iter().zip(&replayed).enumerate() {
            assert_eq!(s, r, "{name}: estimate {i}");
        }
    }
    assert!(
        after > before + MACHINES * 500,
        "the load went on after the kill"
    );

    // The socket's estimates are the stored ones over the time it was
    // open, without a gap, across the change of hands.
    tokio::time::sleep(Duration::from_secs(1)).await;
    listening.abort();
    let (live, events) = frames.lock().unwrap().clone();
    assert!(
        !events.iter().any(|e| e == "gap"),
        "the socket fell behind: {events:?}"
    );
    let stored = all_estimates(&client, &bases[1], &watched).await;
    let first = live[0]["t"].as_f64().unwrap();
    let last = live.last().unwrap()["t"].as_f64().unwrap();
    let expected: Vec<&serde_json::Value> = stored
        .iter()
        .filter(|e| (first..=last).contains(&e["t"].as_f64().unwrap()))
        .collect();
    assert_eq!(live.len(), expected.len(), "{watched}: live estimates");
    for (l, e) in live.iter().zip(&expected) {
        assert_eq!(l, *e);
    }
    assert_eq!(
        last,
        stored.last().unwrap()["t"].as_f64().unwrap(),
        "the socket saw the last estimate"
    );
    eprintln!(
        "two nodes, {MACHINES} machines; node a killed with {} of them: the longest wait for an \
         acknowledgement of those was {:.1} s; {after} readings acknowledged ({before} before the \
         kill), all stored once; estimates equal replay; a live socket on node b saw {} estimates \
         of {watched} without a gap across the change of hands",
        on_a.len(),
        worst.as_secs_f64(),
        live.len()
    );
}

/// Creates a token of `scope` named `name` in the store at `url`; its id
/// (from `token list`) and text.
fn token(url: &str, scope: &str, name: &str) -> (i64, String) {
    let program = env!("CARGO_BIN_EXE_tunnelnav");
    let created = std::process::Command::new(program)
        .args([
            "token", "create", "--store", url, "--scope", scope, "--name", name,
        ])
        .output()
        .unwrap();
    assert!(created.status.success(), "{created:?}");
    let text = String::from_utf8(created.stdout)
        .unwrap()
        .trim()
        .to_string();
    let listed = std::process::Command::new(program)
        .args(["token", "list", "--store", url])
        .output()
        .unwrap();
    let list = String::from_utf8(listed.stdout).unwrap();
    let id = list
        .lines()
        .find(|line| line.split_whitespace().any(|word| word == name))
        .and_then(|line| line.split_whitespace().next())
        .and_then(|id| id.parse().ok())
        .unwrap_or_else(|| panic!("token {name} not listed: {list}"));
    (id, text)
}

/// Sends `method path` to `base` signed by `keys` as node `node` for
/// `grant` at `signed_t`; the status and the raw headers it carried.
async fn signed_call(
    keys: &tunnelnav::server::signing::ClusterKeys,
    base: &str,
    (method, path): (reqwest::Method, &str),
    node: &str,
    grant: &tunnelnav::server::signing::Grant,
    signed_t: f64,
) -> (u16, reqwest::header::HeaderMap) {
    let signed = keys
        .sign(
            &tunnelnav::server::signing::Signable {
                to: base,
                method: method.as_str(),
                target: path,
                body: b"",
            },
            node,
            grant,
            signed_t,
        )
        .unwrap();
    let headers: reqwest::header::HeaderMap = signed.into_iter().collect();
    let status = reqwest::Client::new()
        .request(method, format!("{base}{path}"))
        .headers(headers.clone())
        .send()
        .await
        .unwrap()
        .status()
        .as_u16();
    (status, headers)
}

/// Issue 57: a node's request is signed with the cluster key, never the
/// key itself; the database holds only the key's SHA-256, which signs
/// nothing; a replayed or stale request is refused; and the node that
/// serves a request checks the caller's token against its route.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stolen_node_key_signs_nothing_and_the_serving_node_checks_the_role() {
    use reqwest::Method;
    use tunnelnav::server::signing::{ClusterKeys, Grant};
    let Some(pg) = PgCluster::start() else {
        return;
    };
    let url = pg.database("signing");
    let dir = tempfile::tempdir().unwrap();
    let key_file = cluster_key(dir.path());
    let (admin_id, admin) = token(&url, "admin", "office-admin");
    let (reader_id, _reader) = token(&url, "read", "office-reader");
    let node = ServerProcess::start_with_args(
        dir.path(),
        &[
            "--store",
            &url,
            "--node",
            "b",
            "--cluster-key-file",
            &key_file,
        ],
    );
    let base = node.url("");
    let client = reqwest::Client::new();
    // A machine to read, declared with the admin token; the node is live.
    let declared = client
        .put(format!("{base}/api/v1/machines/m1"))
        .bearer_auth(&admin)
        .header("content-type", "application/json")
        .body(r#"{"engines": {"attitude": {}}}"#)
        .send()
        .await
        .unwrap();
    assert_eq!(declared.status(), 201);
    for _ in 0..100 {
        let running = client
            .get(format!("{base}/api/v1/machines/m1"))
            .bearer_auth(&admin)
            .send()
            .await
            .unwrap();
        if running.status() == 200 {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }

    // What the database holds for the node: the key's SHA-256, not a key.
    let (db, connection) = tokio_postgres::connect(&url, tokio_postgres::NoTls)
        .await
        .unwrap();
    tokio::spawn(connection);
    let stored: String = db
        .query_one("SELECT key_sha256 FROM nodes WHERE node = 'b'", &[])
        .await
        .unwrap()
        .get(0);
    let keys = ClusterKeys::load(Some(std::path::Path::new(&key_file))).unwrap();
    assert_eq!(stored, keys.fingerprint());
    assert!(!stored.contains("3f9c2a7be1d04c5a"));

    // The stored value presented as a key (as the old header did): refused.
    let refused = client
        .get(format!("{base}/api/v1/machines"))
        .header("x-tunnelnav-node", "b")
        .header("x-tunnelnav-node-key", &stored)
        .send()
        .await
        .unwrap();
    assert_eq!(refused.status(), 401);
    // The stored value used as the signing key: refused.
    let thief_dir = tempfile::tempdir().unwrap();
    let thief_file = thief_dir.path().join("stolen.key");
    std::fs::write(&thief_file, &stored).unwrap();
    let thief = ClusterKeys::load(Some(&thief_file)).unwrap();
    let now = tunnelnav::clock::wall_clock_s();
    let as_admin = Grant::Token {
        id: admin_id,
        name: "office-admin".into(),
    };
    let (status, _) = signed_call(
        &thief,
        &base,
        (Method::GET, "/api/v1/machines"),
        "b",
        &as_admin,
        now,
    )
    .await;
    assert_eq!(status, 401, "signed with what the database holds");

    // Signed with the cluster key for the reader: served; sent again: a
    // replay, refused; signed a minute ago: refused.
    let as_reader = Grant::Token {
        id: reader_id,
        name: "office-reader".into(),
    };
    let (status, headers) = signed_call(
        &keys,
        &base,
        (Method::GET, "/api/v1/machines/m1"),
        "b",
        &as_reader,
        now,
    )
    .await;
    assert_eq!(status, 200);
    let replayed = client
        .get(format!("{base}/api/v1/machines/m1"))
        .headers(headers)
        .send()
        .await
        .unwrap();
    assert_eq!(replayed.status(), 401, "a replay");
    let (status, _) = signed_call(
        &keys,
        &base,
        (Method::GET, "/api/v1/machines/m1"),
        "b",
        &as_reader,
        now - 60.0,
    )
    .await;
    assert_eq!(status, 401, "outside the replay window");

    // The serving node checks the route: a reader may not declare, a
    // node's own grant may not read, a token not in force is nobody.
    let (status, _) = signed_call(
        &keys,
        &base,
        (Method::PUT, "/api/v1/machines/m2"),
        "b",
        &as_reader,
        now,
    )
    .await;
    assert_eq!(
        status, 403,
        "a reader's request forwarded to an admin route"
    );
    let (status, _) = signed_call(
        &keys,
        &base,
        (Method::GET, "/api/v1/machines/m1"),
        "b",
        &Grant::Node,
        now,
    )
    .await;
    assert_eq!(status, 403, "a node's own grant is for readings only");
    let (status, _) = signed_call(
        &keys,
        &base,
        (Method::GET, "/api/v1/machines/m1"),
        "b",
        &Grant::Token {
            id: 9999,
            name: "nobody".into(),
        },
        now,
    )
    .await;
    assert_eq!(status, 401, "a token not in force");
    // A node not registered: refused.
    let (status, _) = signed_call(
        &keys,
        &base,
        (Method::GET, "/api/v1/machines/m1"),
        "z",
        &as_reader,
        now,
    )
    .await;
    assert_eq!(status, 401, "a node that is not live");
}
