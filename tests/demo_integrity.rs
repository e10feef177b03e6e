//! Issue 54, item 9: the demo runs four simulated hours (four of the
//! service vehicle's shifts, each starting with a new turn-on gyro bias,
//! the power cycle that once sent its pitch to 78°), and the vehicle's
//! estimates, read back through the API, are scored against the
//! simulator's truth: no run of estimates shown `ok` whose tilt error
//! exceeds 5σ and 1°, or whose heading error exceeds 5σ and 4°, lasts
//! longer than 10 s.
//!
//! First run with each shift's magnetometer iron drawn afresh (as if the
//! sensor were swapped every hour, which the demo did until this test):
//! from the second shift on the engine believed its old calibration, the
//! heading 38–56° off with a σ of 1–11°, misleading for 645 s at a time.
//! A power cycle changes the gyros' bias, not the van's iron: the demo
//! now keeps the first shift's iron. The engine's blindness to a changed
//! iron is recorded in docs/engines/fuzzy.md.

mod common;

use std::process::{Command, Stdio};

use common::ServerProcess;
use serde_json::Value;
use tunnelnav::cli::demo::VehicleShifts;
use tunnelnav::eval::heading_error_deg;
use tunnelnav::eval::integrity::{IntegrityScore, misleading};
use tunnelnav::fusion::integrity::{Integrity, IntegrityLevel, IntegrityReason};
use tunnelnav::sim::vehicle::VehicleTruth;

/// Four simulated hours at ×1000: 14.4 s of real time, and a margin for
/// the gateways to catch up.
const RATE: &str = "1000";
const SECONDS: &str = "16";
const HOURS: f64 = 4.0;

fn integrity_of(estimate: &Value) -> Integrity {
    let level = match estimate["integrity"].as_str() {
        Some("ok") => IntegrityLevel::Ok,
        Some("degraded") => IntegrityLevel::Degraded,
        Some("lost") => IntegrityLevel::Lost,
        other => panic!("integrity {other:?} in {estimate}"),
    };
    let reason = estimate["integrity_reason"].as_str().map(|code| {
        *IntegrityReason::ALL
            .iter()
            .find(|r| r.as_str() == code)
            .unwrap_or_else(|| panic!("reason {code}"))
    });
    Integrity { level, reason }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn four_demo_hours_of_the_service_vehicle_are_never_confidently_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
        .args(["demo", "--listen", "127.0.0.1:0", "--rate", RATE])
        .args(["--seconds", SECONDS, "--data-dir"])
        .arg(dir.path())
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .output()
        .expect("tunnelnav demo runs");
    assert!(
        output.status.success(),
        "demo failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );

    let server = ServerProcess::start(dir.path());
    let (machine, _) = VehicleShifts::demo_vehicle(0.0).unwrap();
    let url = server.url(&format!(
        "/api/v1/machines/{machine}/estimates?format=ndjson&from=0&to=99999999999"
    ));
    let body = reqwest::get(&url).await.unwrap().text().await.unwrap();
    let estimates: Vec<Value> = body
        .lines()
        .map(|line| serde_json::from_str(line).unwrap())
        .collect();
    let start_t = estimates.first().expect("the vehicle has estimates")["t"]
        .as_f64()
        .unwrap();
    let end_t = start_t + HOURS * 3600.0;
    assert!(
        estimates.last().unwrap()["t"].as_f64().unwrap() >= end_t,
        "the demo reached {} s of {} s",
        estimates.last().unwrap()["t"].as_f64().unwrap() - start_t,
        HOURS * 3600.0
    );

    // The truth of every IMU reading, regenerated as the demo drew it.
    let (_, shifts) = VehicleShifts::demo_vehicle(start_t).unwrap();
    let truths: Vec<VehicleTruth> = shifts
        .map_while(|event| (event.reading.t <= end_t).then_some(event.truth))
        .flatten()
        .collect();
    assert_eq!(
        truths[0].t, start_t,
        "the first estimate is the first reading's"
    );

    let mut score = IntegrityScore::default();
    let mut next = truths.iter().peekable();
    let mut scored = 0_u64;
    for estimate in &estimates {
        let t = estimate["t"].as_f64().unwrap();
        if t > end_t {
            break;
        }
        while next.next_if(|truth| truth.t < t).is_some() {}
        let Some(truth) = next.peek().filter(|truth| truth.t == t) else {
            panic!("no truth at the estimate of {t}");
        };
        let number = |name: &str| estimate[name].as_f64();
        let pitch_error = number("pitch_deg").unwrap() - truth.pitch_deg;
        let roll_error = number("roll_deg").unwrap() - truth.roll_deg;
        let heading_error = heading_error_deg(number("heading_deg").unwrap(), truth.heading_deg);
        let wrong = misleading(pitch_error, number("pitch_sigma_deg"), 1.0)
            || misleading(roll_error, number("roll_sigma_deg"), 1.0)
            || misleading(heading_error, number("heading_sigma_deg"), 4.0);
        score.add(t, integrity_of(estimate), wrong);
        scored += 1;
    }
    eprintln!(
        "{} of the vehicle's estimates over {HOURS} h: {:.2} % flagged, {} misleading ok, longest misleading ok run {:.1} s from {:?}",
        scored,
        100.0 * score.flagged_share(),
        score.misleading_ok,
        score.worst_run_s,
        score.worst_run_from_t.map(|t| t - start_t)
    );
    // Four hours of 25 Hz IMU readings, each with its estimate.
    assert!(scored as f64 >= HOURS * 3600.0 * 25.0 * 0.99, "{scored}");
    assert!(
        score.worst_run_s <= 10.0,
        "a misleading ok run of {:.1} s from {:?} s into the demo",
        score.worst_run_s,
        score.worst_run_from_t.map(|t| t - start_t)
    );
}
