//! Running tunnelnav as a service is configured: `serve` takes every flag
//! from `TUNNELNAV_*` environment variables too, the config file's
//! `[limits]` apply, `load` passes its token (flag or `TUNNELNAV_TOKEN`),
//! and the systemd unit in `deploy/` passes `systemd-analyze verify`.

mod common;

use std::process::{Command, Stdio};

use serde_json::json;

fn tunnelnav() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serve_takes_its_settings_from_the_environment_and_limits_from_the_config() {
    let dir = tempfile::tempdir().unwrap();
    let data_dir = dir.path().join("state");
    let config = dir.path().join("tunnelnav.toml");
    std::fs::write(
        &config,
        "[limits]\nmax_readings_per_request = 5\n\n[machines.tbm-env.engines.attitude]\n",
    )
    .unwrap();
    let (mut child, base) = common::spawn_serving(
        tunnelnav()
            .arg("serve")
            .env("TUNNELNAV_LISTEN", "127.0.0.1:0")
            .env("TUNNELNAV_DATA_DIR", &data_dir)
            .env("TUNNELNAV_CONFIG", &config)
            .env("TUNNELNAV_LOG_FORMAT", "json")
            .env("RUST_LOG", "warn")
            .stderr(Stdio::inherit()),
    );
    assert!(data_dir.join("tunnelnav.sqlite3").exists());
    let client = reqwest::Client::new();
    let machine = common::get_json(&client, &base, "/api/v1/machines/tbm-env").await;
    assert_eq!(machine["machine"], "tbm-env");
    let readings: Vec<String> = (0..6)
        .map(|i| {
            json!({"t": 1_772_431_200 + i, "sensor": "inclinometer", "pitch_deg": 0.1, "roll_deg": 0.2})
                .to_string()
        })
        .collect();
    let too_many = common::send_ndjson(&client, &base, "tbm-env", &readings)
        .await
        .unwrap();
    assert_eq!(too_many.status(), 413, "the config's limit of 5 readings");
    let five = common::send_ndjson(&client, &base, "tbm-env", &readings[..5])
        .await
        .unwrap();
    assert_eq!(five.status(), 200);
    let _ = child.kill();
    let _ = child.wait();

    // A bad limit stops the start, naming it.
    std::fs::write(&config, "[limits]\nmachine_queue = 0\n").unwrap();
    let refused = tunnelnav()
        .args(["serve", "--listen", "127.0.0.1:0"])
        .env("TUNNELNAV_DATA_DIR", &data_dir)
        .env("TUNNELNAV_CONFIG", &config)
        .output()
        .unwrap();
    assert!(!refused.status.success());
    let said = String::from_utf8_lossy(&refused.stderr);
    assert!(said.contains("limits.machine_queue"), "{said}");
}

#[test]
fn load_passes_its_token_to_a_server_that_requires_one() {
    let dir = tempfile::tempdir().unwrap();
    let token = {
        let conn = tunnelnav::store::Store::connect(dir.path()).unwrap();
        tunnelnav::store::sqlite::tokens::create(
            &conn,
            "bench",
            tunnelnav::auth::Scope::Admin,
            None,
            0.0,
        )
        .unwrap()
        .1
    };
    let server = common::ServerProcess::start(dir.path());
    let url = server.url("");
    let run = |token: Option<&str>, mode: &str| {
        let mut load = tunnelnav();
        load.args([
            "load",
            "--url",
            &url,
            "--mode",
            mode,
            "--machines",
            "2",
            "--readings",
            "50",
            "--batch",
            "25",
            "--concurrency",
            "2",
            "--rate",
            "20",
            "--seconds",
            "1",
        ]);
        if let Some(token) = token {
            load.env("TUNNELNAV_TOKEN", token);
        }
        load.output().unwrap()
    };
    let refused = run(None, "batch");
    assert!(!refused.status.success(), "no token, no load");
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("401"),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
    for mode in ["batch", "live"] {
        let done = run(Some(&token), mode);
        assert!(
            done.status.success(),
            "{mode}: {}{}",
            String::from_utf8_lossy(&done.stdout),
            String::from_utf8_lossy(&done.stderr)
        );
    }
    server.kill();
}

#[test]
fn the_systemd_unit_verifies() {
    let Ok(version) = Command::new("systemd-analyze").arg("--version").output() else {
        assert!(
            std::env::var("TUNNELNAV_SYSTEMD_TEST").as_deref() != Ok("required"),
            "TUNNELNAV_SYSTEMD_TEST=required but systemd-analyze does not run"
        );
        eprintln!("SKIPPED: systemd-analyze not found");
        return;
    };
    assert!(version.status.success());
    // The unit as shipped, its ExecStart pointed at the binary just built
    // (verify checks that the program exists).
    let unit = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/deploy/systemd/tunnelnav.service"
    ))
    .unwrap();
    assert!(unit.contains("ExecStart=/usr/local/bin/tunnelnav serve"));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tunnelnav.service");
    std::fs::write(
        &path,
        unit.replace("/usr/local/bin/tunnelnav", env!("CARGO_BIN_EXE_tunnelnav")),
    )
    .unwrap();
    let verify = Command::new("systemd-analyze")
        .args(["verify", "--man=no"])
        .arg(&path)
        .output()
        .unwrap();
    let said = format!(
        "{}{}",
        String::from_utf8_lossy(&verify.stdout),
        String::from_utf8_lossy(&verify.stderr)
    );
    // Only lines about this unit count (the host's own units may warn).
    let ours: Vec<&str> = said.lines().filter(|l| l.contains("tunnelnav")).collect();
    assert!(verify.status.success() && ours.is_empty(), "{said}");
}
