//! The example alert rules in `deploy/prometheus/` against Prometheus's
//! own checker: `promtool check rules` and `promtool test rules` (the
//! rules fire and clear as the test file says), and the alarm gauge they
//! use as a real server exports it.
//!
//! Skipped (and says so) without `promtool` (Debian's `prometheus`
//! package), unless `TUNNELNAV_PROMTOOL_TEST=required` (set by `.ci/run`).

mod common;

use std::path::Path;

use common::{TestServer, declare_machine};

fn examples() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/prometheus")
}

#[test]
fn the_example_alert_rules_pass_promtool_and_its_unit_tests() {
    for args in [
        &["check", "rules", "tunnelnav-alerts.yml"][..],
        &["test", "rules", "tunnelnav-alerts.test.yml"][..],
    ] {
        let Some(output) = common::promtool(args, &examples(), None) else {
            return;
        };
        assert!(
            output.status.success(),
            "promtool {args:?}:\n{}{}",
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        );
    }
}

#[test]
fn the_example_scrape_configuration_passes_promtool() {
    // promtool checks that the token file exists: a copy with one.
    let dir = tempfile::tempdir().unwrap();
    for file in ["prometheus.yml", "tunnelnav-alerts.yml"] {
        std::fs::copy(examples().join(file), dir.path().join(file)).unwrap();
    }
    std::fs::write(dir.path().join("tunnelnav.token"), "tnv_example\n").unwrap();
    let Some(output) = common::promtool(&["check", "config", "prometheus.yml"], dir.path(), None)
    else {
        return;
    };
    assert!(
        output.status.success(),
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_alarm_gauge_is_exported_for_every_kind_and_severity_from_the_start() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    declare_machine(
        &client,
        &base,
        "tbm-gauge",
        r#"{"engines": {"attitude": {}}}"#,
    )
    .await;
    let text = common::get_text(&client, &base, "/metrics").await;
    assert!(
        text.contains("# TYPE tunnelnav_alarms_active gauge"),
        "{text}"
    );
    for kind in [
        "deviation",
        "laser_dropout",
        "stale_sensor",
        "ins_uncertainty",
        "engine_reset",
        "attitude_uncertainty",
    ] {
        for severity in ["warn", "alarm"] {
            let series = format!(
                "tunnelnav_alarms_active{{machine=\"tbm-gauge\",kind=\"{kind}\",severity=\"{severity}\"}} 0"
            );
            assert!(text.contains(&series), "{series} missing:\n{text}");
        }
    }
    server.stop().await;
}
