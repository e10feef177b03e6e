//! `tunnelnav backup` while a gateway posts: ingest goes on during the
//! copy, the copy passes SQLite's integrity check, and a server started
//! on it has every reading acknowledged before the backup began, its
//! machines and their engines, which carry on.

mod common;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;

use common::{ServerProcess, drive, exported_readings, post_ndjson, put_machine, send_ndjson};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_online_backup_does_not_stop_ingest_and_restores() {
    let dir = tempfile::tempdir().unwrap();
    let client = reqwest::Client::new();
    let server = ServerProcess::start(dir.path());
    let base = server.url("");
    put_machine(&client, &base, "b1").await;
    let lines = Arc::new(drive(24.0, 5, vec![]));
    // A first part, then a gateway that keeps posting.
    for chunk in lines[..20_000].chunks(2000) {
        post_ndjson(&client, &base, "b1", chunk).await;
    }
    let acknowledged = Arc::new(AtomicUsize::new(20_000));
    let stop = Arc::new(AtomicBool::new(false));
    let gateway = {
        let (client, base, lines) = (client.clone(), base.clone(), lines.clone());
        let (acknowledged, stop) = (acknowledged.clone(), stop.clone());
        tokio::spawn(async move {
            while !stop.load(Ordering::SeqCst) {
                let from = acknowledged.load(Ordering::SeqCst);
                let chunk = &lines[from..(from + 200).min(lines.len())];
                if chunk.is_empty() {
                    return;
                }
                let response = send_ndjson(&client, &base, "b1", chunk).await.unwrap();
                assert_eq!(response.status(), 200);
                acknowledged.store(from + chunk.len(), Ordering::SeqCst);
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
        })
    };
    tokio::time::sleep(Duration::from_millis(300)).await;
    let before = acknowledged.load(Ordering::SeqCst);
    let file = dir.path().join("copy.sqlite3");
    let data_dir = dir.path().to_path_buf();
    let out = tokio::task::spawn_blocking({
        let file = file.clone();
        move || {
            std::process::Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
                .args(["backup"])
                .arg(&file)
                .arg("--data-dir")
                .arg(&data_dir)
                .output()
                .unwrap()
        }
    })
    .await
    .unwrap();
    let after = acknowledged.load(Ordering::SeqCst);
    tokio::time::sleep(Duration::from_millis(300)).await;
    stop.store(true, Ordering::SeqCst);
    gateway.await.unwrap();
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("integrity ok"), "{stderr}");
    assert!(
        acknowledged.load(Ordering::SeqCst) > after,
        "ingest went on after the backup"
    );
    eprintln!("acknowledged {before} before the backup, {after} when it ended: {stderr}");
    server.terminate();

    // A second backup to the same name is refused.
    let again = std::process::Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
        .args(["backup"])
        .arg(&file)
        .arg("--data-dir")
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(!again.status.success());

    // Serve the copy.
    let restored = tempfile::tempdir().unwrap();
    std::fs::copy(&file, restored.path().join("tunnelnav.sqlite3")).unwrap();
    let server = ServerProcess::start(restored.path());
    let base = server.url("");
    let stored = exported_readings(&client, &base, "b1").await;
    assert!(
        stored.len() >= before && stored.len() <= after,
        "{} readings in the copy; {before} acknowledged before, {after} after",
        stored.len()
    );
    assert_eq!(stored[..], lines[..stored.len()]);
    // The engines carry on from the copy.
    let next = &lines[stored.len()..stored.len() + 100];
    let ack = post_ndjson(&client, &base, "b1", next).await;
    assert_eq!(ack["accepted"], 100, "{ack}");
    server.terminate();
}
