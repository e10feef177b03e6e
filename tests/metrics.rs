//! `/metrics` on a fresh server (a site forwarding to an office, so that
//! its link's series are there too) against the table in `docs/api.md` ("Metrics"):
//! every documented series is there before any reading, with the
//! documented type and labels, and nothing undocumented; `promtool check
//! metrics` (Prometheus's own linter of names and types) finds nothing,
//! when promtool is installed (required in CI).

mod common;

use std::collections::BTreeMap;

use common::{TestServer, declare_machine, get_text};

/// The metrics table of `docs/api.md`: name → (type, labels).
fn documented() -> BTreeMap<String, (String, Vec<String>)> {
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/api.md")).unwrap();
    let section = doc
        .split("\n## Metrics\n")
        .nth(1)
        .and_then(|rest| rest.split("\n## ").next())
        .expect("a Metrics section");
    section
        .lines()
        .filter(|line| line.starts_with("| `"))
        .map(|line| {
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            let name = cells[1].trim_matches('`').to_string();
            let labels = cells[3]
                .split(',')
                .map(|l| l.trim().trim_matches('`').to_string())
                .filter(|l| !l.is_empty())
                .collect();
            (name, (cells[2].to_string(), labels))
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fresh_server_exports_every_documented_series_and_only_those() {
    let documented = documented();
    assert!(documented.len() >= 15, "{documented:?}");
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start_site(
        dir.path(),
        tunnelnav::server::forward::ForwardOptions {
            // No office there: the link is down from the start.
            office: "http://127.0.0.1:9".into(),
            site: "metrics-site".into(),
            token: None,
        },
    )
    .await;
    let client = reqwest::Client::new();
    let base = server.url("");
    declare_machine(
        &client,
        &base,
        "tbm-metrics",
        r#"{"engines": {"attitude": {}}}"#,
    )
    .await;
    let text = get_text(&client, &base, "/metrics").await;

    let types: BTreeMap<&str, &str> = text
        .lines()
        .filter_map(|l| l.strip_prefix("# TYPE "))
        .filter_map(|l| l.split_once(' '))
        .collect();
    for (name, (kind, labels)) in &documented {
        assert_eq!(
            types.get(name.as_str()),
            Some(&kind.as_str()),
            "{name}:\n{text}"
        );
        // One sample at least (a histogram: its _count), with the labels.
        let sample_name = if kind == "histogram" {
            format!("{name}_count")
        } else {
            name.clone()
        };
        let sample = text
            .lines()
            .find(|l| l.starts_with(&sample_name) && l[sample_name.len()..].starts_with(['{', ' ']))
            .unwrap_or_else(|| panic!("no sample of {name}:\n{text}"));
        for label in labels {
            assert!(
                sample.contains(&format!("{label}=\"")),
                "{name} lacks {label}: {sample}"
            );
        }
    }
    for name in types.keys() {
        assert!(
            documented.contains_key(*name),
            "{name} is exported but not documented"
        );
    }
    // The machine's series at zero before its first reading.
    for series in [
        r#"tunnelnav_readings_accepted_total{machine="tbm-metrics",sensor="inclinometer"} 0"#,
        r#"tunnelnav_last_reading_timestamp_seconds{machine="tbm-metrics",sensor="laser"} 0"#,
        r#"tunnelnav_laser_dropout{machine="tbm-metrics"} 0"#,
        r#"tunnelnav_refusals_total{reason="machine_busy"} 0"#,
        r#"tunnelnav_forward_connected{site="metrics-site"} 0"#,
    ] {
        assert!(text.contains(series), "{series} missing:\n{text}");
    }

    // Prometheus's own linter.
    if let Some(output) = common::promtool(&["check", "metrics"], dir.path(), Some(&text)) {
        let said = format!(
            "{}{}",
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        );
        assert!(
            output.status.success() && said.trim().is_empty(),
            "promtool: {said}"
        );
    }
    server.stop().await;
}
