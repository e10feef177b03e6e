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

    let revoked = tunnelnav()
        .args(["token", "revoke", "--store", &url, "1"])
        .output()
        .unwrap();
    assert!(
        revoked.status.success(),
        "{}",
        String::from_utf8_lossy(&revoked.stderr)
    );
}
