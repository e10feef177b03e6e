//! The server's log by convention: one INFO line per request naming the
//! method, the declared route, the machine, the status and the latency;
//! `--log-format json` writes one JSON object per line; colour codes only
//! on a terminal (never into a pipe, file or journald).

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

/// Starts `serve` with `format`, makes two requests, and returns the
/// log lines written meanwhile.
fn log_lines(format: &str) -> Vec<String> {
    let dir = tempfile::tempdir().unwrap();
    let (mut child, base) = common::spawn_serving(
        Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
            .args([
                "serve",
                "--listen",
                "127.0.0.1:0",
                "--log-format",
                format,
                "--data-dir",
            ])
            .arg(dir.path())
            .env("RUST_LOG", "info")
            .stderr(Stdio::piped()),
    );
    let (lines, received) = mpsc::channel();
    let stderr = child.stderr.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if lines.send(line).is_err() {
                break;
            }
        }
    });
    let runtime = tokio::runtime::Runtime::new().unwrap();
    runtime.block_on(async {
        let client = reqwest::Client::new();
        let put = client
            .put(format!("{base}/api/v1/machines/tbm-log"))
            .body(r#"{"engines": {"attitude": {}}}"#)
            .send()
            .await
            .unwrap();
        assert_eq!(put.status(), 201);
        let missing = client
            .get(format!("{base}/api/v1/machines/nope"))
            .send()
            .await
            .unwrap();
        assert_eq!(missing.status(), 404);
    });
    let mut seen = Vec::new();
    while let Ok(line) = received.recv_timeout(Duration::from_secs(2)) {
        seen.push(line);
        if seen.iter().filter(|l| l.contains("nope")).count() >= 1 {
            break;
        }
    }
    let _ = child.kill();
    let _ = child.wait();
    seen
}

#[test]
fn each_request_is_one_info_line_in_json() {
    let lines = log_lines("json");
    let requests: Vec<serde_json::Value> = lines
        .iter()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}")))
        .filter(|v: &serde_json::Value| v["span"]["name"] == "request")
        .collect();
    assert_eq!(requests.len(), 2, "{lines:#?}");
    let put = &requests[0];
    assert_eq!(put["level"], "INFO", "{put}");
    assert_eq!(put["span"]["method"], "PUT");
    assert_eq!(put["span"]["route"], "/api/v1/machines/{machine}");
    assert_eq!(put["span"]["machine"], "tbm-log");
    assert_eq!(put["status"], 201, "{put}");
    assert!(
        put["latency"].as_str().unwrap_or_default().ends_with("ms"),
        "{put}"
    );
    let missing = &requests[1];
    assert_eq!(
        (
            missing["span"]["machine"].as_str(),
            missing["status"].as_u64()
        ),
        (Some("nope"), Some(404)),
        "{missing}"
    );
}

#[test]
fn text_logs_carry_no_colour_codes_into_a_pipe() {
    let lines = log_lines("text");
    let request = lines
        .iter()
        .find(|l| l.contains("tbm-log") && l.contains("status=201"))
        .unwrap_or_else(|| panic!("no request line: {lines:#?}"));
    assert!(request.contains("INFO"), "{request}");
    assert!(
        request.contains("route=/api/v1/machines/{machine}"),
        "{request}"
    );
    assert!(lines.iter().all(|l| !l.contains('\u{1b}')), "{lines:#?}");
}
