//! The real binary on the PostgreSQL store (issue 37): `serve --store URL`
//! and `[store]` in the config file, tokens made with `token create
//! --store URL` and enforced by the server, a store URL that is not
//! PostgreSQL's refused with the reason. (SIGKILLs under load on
//! PostgreSQL, with estimates equal to replay: tests/kills.rs.)

mod common;

use std::process::Command;

use common::postgres::PgCluster;
use common::{ServerProcess, drive, put_machine, send_ndjson, spawn_serving};

fn tunnelnav() -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_tunnelnav"));
    command.env("RUST_LOG", "warn");
    command
}

#[test]
fn a_store_url_that_is_not_postgres_is_refused_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let out = tunnelnav()
        .args([
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--store",
            "mysql://db/x",
            "--data-dir",
        ])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(
        said.contains("expected postgres://USER@HOST:PORT/DB"),
        "{said}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_made_on_postgres_guard_a_server_on_postgres() {
    let Some(cluster) = PgCluster::start() else {
        return;
    };
    let url = cluster.database("service");
    let dir = tempfile::tempdir().unwrap();

    // Declared and fed with no token yet (loopback, open).
    let server = ServerProcess::start_with_args(dir.path(), &["--store", &url]);
    let client = reqwest::Client::new();
    let base = server.url("");
    put_machine(&client, &base, "tbm-pg").await;
    let lines = drive(0.2, 3, vec![]);
    let response = send_ndjson(&client, &base, "tbm-pg", &lines).await.unwrap();
    assert_eq!(response.status(), 200);
    server.terminate();

    let out = tunnelnav()
        .args([
            "token", "create", "--store", &url, "--scope", "read", "--name", "office",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let token = String::from_utf8_lossy(&out.stdout).trim().to_string();
    let listed = tunnelnav()
        .args(["token", "list", "--store", &url])
        .output()
        .unwrap();
    let listed = String::from_utf8_lossy(&listed.stdout);
    assert!(
        listed.contains("office") && listed.contains("active"),
        "{listed}"
    );

    // The store named by the config file this time; the data dir is empty.
    let config = dir.path().join("office.toml");
    std::fs::write(&config, format!("[store]\nurl = \"{url}\"\n")).unwrap();
    // The key file several nodes of one store share (the second node below).
    let key_file = dir.path().join("cluster.key");
    std::fs::write(
        &key_file,
        "0f1e2d3c4b5a69788796a5b4c3d2e1f00f1e2d3c4b5a6978\n",
    )
    .unwrap();
    let empty = tempfile::tempdir().unwrap();
    let (mut child, base) = spawn_serving(
        tunnelnav()
            .args(["serve", "--listen", "127.0.0.1:0", "--config"])
            .arg(&config)
            .arg("--data-dir")
            .arg(empty.path()),
    );
    let machines = format!("{base}/api/v1/machines/tbm-pg");
    let refused = client.get(&machines).send().await.unwrap();
    assert_eq!(refused.status(), 401);
    let answer = client
        .get(&machines)
        .bearer_auth(&token)
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let status: serde_json::Value = serde_json::from_str(&answer).unwrap();
    assert_eq!(status["machine"], "tbm-pg");
    assert!(status["latest"]["attitude"].is_object(), "{status}");
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        std::fs::read_dir(empty.path()).unwrap().next().is_none(),
        "nothing written to the data dir"
    );

    // Tokens are managed beside a running server: within the gate's 2 s
    // refresh a new one is honoured and a revoked one refused (another
    // stays in force, so the gate does not open for want of tokens).
    let (mut child, base) = spawn_serving(
        tunnelnav()
            .args(["serve", "--listen", "127.0.0.1:0", "--config"])
            .arg(&config)
            .arg("--cluster-key-file")
            .arg(&key_file)
            .arg("--data-dir")
            .arg(empty.path()),
    );
    let out = tunnelnav()
        .args([
            "token", "create", "--store", &url, "--scope", "read", "--name", "night",
        ])
        .output()
        .unwrap();
    assert!(out.status.success());
    let night = String::from_utf8_lossy(&out.stdout).trim().to_string();
    let revoked = tunnelnav()
        .args(["token", "revoke", "--store", &url, "1"])
        .output()
        .unwrap();
    assert!(
        revoked.status.success(),
        "{}",
        String::from_utf8_lossy(&revoked.stderr)
    );
    tokio::time::sleep(std::time::Duration::from_millis(2500)).await;
    let refused = client
        .get(format!("{base}/api/v1/machines/tbm-pg"))
        .bearer_auth(&token)
        .send()
        .await
        .unwrap();
    assert_eq!(refused.status(), 401);
    let honoured = client
        .get(format!("{base}/api/v1/machines/tbm-pg"))
        .bearer_auth(&night)
        .send()
        .await
        .unwrap();
    assert_eq!(honoured.status(), 200);

    // A second server on the same database joins as a second node (the
    // host's name is taken: it gets the next) and leaves the machine where
    // it runs, answering for it all the same.
    let (mut second, second_base) = spawn_serving(
        tunnelnav()
            .args([
                "serve",
                "--listen",
                "127.0.0.1:0",
                "--store",
                &url,
                "--cluster-key-file",
            ])
            .arg(&key_file)
            .arg("--data-dir")
            .arg(empty.path()),
    );
    let report: serde_json::Value = serde_json::from_str(
        &client
            .get(format!("{second_base}/api/v1/cluster"))
            .bearer_auth(&night)
            .send()
            .await
            .unwrap()
            .text()
            .await
            .unwrap(),
    )
    .unwrap();
    let nodes = report["nodes"].as_array().unwrap();
    let live: Vec<&serde_json::Value> = nodes.iter().filter(|n| n["live"] == true).collect();
    assert_eq!(live.len(), 2, "{report}");
    assert_eq!(
        report["node"],
        format!("{}-2", live[0]["node"].as_str().unwrap()),
        "{report}"
    );
    assert_eq!(
        live[0]["machines"],
        serde_json::json!(["tbm-pg"]),
        "{report}"
    );
    let status = client
        .get(format!("{second_base}/api/v1/machines/tbm-pg"))
        .bearer_auth(&night)
        .send()
        .await
        .unwrap();
    assert_eq!(status.status(), 200);
    second.kill().unwrap();
    second.wait().unwrap();
    child.kill().unwrap();
    child.wait().unwrap();
}

/// A site's SQLite store moved into PostgreSQL by `tunnelnav migrate`:
/// every table verified; the office then serves the same readings and
/// estimates, honours the site's token, and carries the machine on exactly
/// (its estimates equal `replay` of everything stored); a second migration
/// into the now full database is refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_site_moves_to_postgres_whole_and_verified() {
    let Some(cluster) = PgCluster::start() else {
        return;
    };
    let url = cluster.database("moved");
    let site = tempfile::tempdir().unwrap();
    let client = reqwest::Client::new();
    let lines = drive(2.0, 5, vec![]);
    let (at_site, at_office) = lines.split_at(lines.len() * 7 / 10);

    let server = ServerProcess::start(site.path());
    let base = server.url("");
    put_machine(&client, &base, "tbm-site").await;
    let sent = send_ndjson(&client, &base, "tbm-site", at_site)
        .await
        .unwrap();
    assert_eq!(sent.status(), 200);
    let readings_before = common::exported_readings(&client, &base, "tbm-site").await;
    let estimates_before = common::all_estimates(&client, &base, "tbm-site").await;
    assert!(!estimates_before.is_empty());
    server.terminate();
    let made = tunnelnav()
        .args([
            "token",
            "create",
            "--scope",
            "admin",
            "--name",
            "site admin",
            "--data-dir",
        ])
        .arg(site.path())
        .output()
        .unwrap();
    assert!(made.status.success());
    let token = String::from_utf8_lossy(&made.stdout).trim().to_string();

    let moved = tunnelnav()
        .args(["migrate", "--to", &url, "--from"])
        .arg(site.path())
        .output()
        .unwrap();
    let report = String::from_utf8_lossy(&moved.stdout);
    assert!(
        moved.status.success(),
        "{}",
        String::from_utf8_lossy(&moved.stderr)
    );
    let rows = |table: &str| -> u64 {
        report
            .lines()
            .find(|l| l.starts_with(&format!("{table} ")))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("{table} in {report}"))
    };
    assert_eq!(rows("machines"), 1);
    assert_eq!(rows("readings"), readings_before.len() as u64);
    assert_eq!(rows("estimates"), estimates_before.len() as u64);
    assert_eq!(rows("tokens"), 1);

    // The office: the site's token, the same history, and on from there.
    let office = tempfile::tempdir().unwrap();
    let server = ServerProcess::start_with_args(office.path(), &["--store", &url]);
    let base = server.url("");
    let mut headers = reqwest::header::HeaderMap::new();
    headers.insert(
        reqwest::header::AUTHORIZATION,
        format!("Bearer {token}").parse().unwrap(),
    );
    let authed = reqwest::Client::builder()
        .default_headers(headers)
        .build()
        .unwrap();
    assert_eq!(
        common::exported_readings(&authed, &base, "tbm-site").await,
        readings_before
    );
    assert_eq!(
        common::all_estimates(&authed, &base, "tbm-site").await,
        estimates_before
    );
    let sent = send_ndjson(&authed, &base, "tbm-site", at_office)
        .await
        .unwrap();
    assert_eq!(sent.status(), 200);
    let stored = common::exported_readings(&authed, &base, "tbm-site").await;
    assert_eq!(stored.len(), lines.len());
    let served = common::all_estimates(&authed, &base, "tbm-site").await;
    assert_eq!(served, common::replay("tbm-site", &stored));
    server.terminate();

    // Into a database that holds machines: refused.
    let again = tunnelnav()
        .args(["migrate", "--to", &url, "--from"])
        .arg(site.path())
        .output()
        .unwrap();
    assert!(!again.status.success());
    let said = String::from_utf8_lossy(&again.stderr);
    assert!(said.contains("holds 1 machines already"), "{said}");
}

/// The database away for longer than a lease (8 s) under a running
/// server: ingest answers 503 meanwhile, and once the database is back the
/// same server takes its lapsed lease back and carries on (no other node
/// held it): every acknowledged reading stored once, the estimates equal
/// replay of what is stored.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_database_away_longer_than_a_lease_is_ridden_out() {
    let Some(cluster) = PgCluster::start() else {
        return;
    };
    let url = cluster.database("outage");
    let dir = tempfile::tempdir().unwrap();
    let server = ServerProcess::start_with_args(dir.path(), &["--store", &url]);
    let base = server.url("");
    let client = reqwest::Client::new();
    put_machine(&client, &base, "tbm-out").await;
    let lines = drive(1.0, 7, vec![]);
    let (before, after) = lines.split_at(lines.len() / 2);
    for chunk in before.chunks(200) {
        let response = send_ndjson(&client, &base, "tbm-out", chunk).await.unwrap();
        assert_eq!(response.status(), 200);
    }
    cluster.stop();
    let refused = send_ndjson(&client, &base, "tbm-out", &after[..10])
        .await
        .unwrap();
    assert_eq!(refused.status(), 503);
    tokio::time::sleep(std::time::Duration::from_secs(8)).await;
    cluster.start_again();
    let back = std::time::Instant::now();
    for chunk in after.chunks(200) {
        loop {
            let response = send_ndjson(&client, &base, "tbm-out", chunk).await.unwrap();
            if response.status() == 200 {
                break;
            }
            assert_eq!(response.status(), 503);
            assert!(
                back.elapsed() < std::time::Duration::from_secs(20),
                "ingest did not resume after the database came back"
            );
            tokio::time::sleep(std::time::Duration::from_millis(200)).await;
        }
    }
    let stored = common::exported_readings(&client, &base, "tbm-out").await;
    assert_eq!(stored.len(), lines.len());
    let served = common::all_estimates(&client, &base, "tbm-out").await;
    let replayed = common::replay("tbm-out", &stored);
    assert_eq!(served, replayed);
    server.kill();
}
