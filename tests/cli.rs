//! The command line as a user runs it: the real binary, real files, pipes.

use std::io::Write;
use std::process::{Command, Stdio};

fn tunnelnav() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
}

fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("tunnelnav-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A one-hour drive with a ten-minute dropout.
const SEVEN: [&str; 8] = [
    "simulate",
    "tbm",
    "--hours",
    "1",
    "--seed",
    "7",
    "--dropout",
    "0.5:10",
];

#[test]
fn simulate_then_replay_gives_one_estimate_per_inclinometer_reading() {
    let dir = temp_dir("pipeline");
    let drive = dir.join("drive.ndjson");
    let truth = dir.join("truth.ndjson");
    let sim = tunnelnav()
        .args(SEVEN)
        .arg("--truth")
        .arg(&truth)
        .output()
        .unwrap();
    assert!(sim.status.success());
    std::fs::write(&drive, &sim.stdout).unwrap();
    let readings = String::from_utf8(sim.stdout).unwrap();
    let incl = readings
        .lines()
        .filter(|l| l.contains("\"inclinometer\""))
        .count();
    assert_eq!(incl, 3600);
    assert_eq!(
        std::fs::read_to_string(&truth).unwrap().lines().count(),
        3600
    );

    let replay = tunnelnav()
        .args(["replay", "--engine", "attitude", "--machine", "tbm-7"])
        .arg(&drive)
        .output()
        .unwrap();
    assert!(replay.status.success());
    let estimates = String::from_utf8(replay.stdout).unwrap();
    assert_eq!(estimates.lines().count(), incl);
    let last: serde_json::Value = serde_json::from_str(estimates.lines().last().unwrap()).unwrap();
    assert_eq!(last["machine"], "tbm-7");
    assert_eq!(last["engine"], "attitude");
    for field in [
        "t",
        "pitch_deg",
        "roll_deg",
        "pitch_pred_deg",
        "roll_pred_deg",
        "pred_t",
        "laser_ok",
        "pitch_correction_deg",
    ] {
        assert!(!last[field].is_null(), "missing {field}");
    }
    let stderr = String::from_utf8(replay.stderr).unwrap();
    assert!(stderr.contains("replay summary:"), "{stderr}");
    assert!(stderr.contains("0 invalid"), "{stderr}");

    // Same seed, same drive.
    let again = tunnelnav().args(SEVEN).output().unwrap();
    assert_eq!(again.stdout, readings.as_bytes());
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn replay_reports_invalid_lines_by_number_and_skips_them() {
    let mut child = tunnelnav()
        .args(["replay", "--engine", "attitude", "-"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(
            b"{\"t\":1772431200,\"sensor\":\"inclinometer\",\"pitch_deg\":0.1,\"roll_deg\":1}\n\
              {\"t\":1772431201,\"sensor\":\"inclinometer\",\"pitch_deg\":\"x\",\"roll_deg\":1}\n\
              {\"t\":1772431202,\"sensor\":\"gyro\"}\n\
              {\"t\":1772431203,\"sensor\":\"inclinometer\",\"pitch_deg\":0.1,\"roll_deg\":1}\n",
        )
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(
        stderr.contains("line 2: field `pitch_deg` must be a number"),
        "{stderr}"
    );
    assert!(stderr.contains("line 3: unknown sensor `gyro`"), "{stderr}");
    assert!(
        stderr.contains("4 lines: 2 readings, 2 invalid"),
        "{stderr}"
    );
    assert_eq!(String::from_utf8(out.stdout).unwrap().lines().count(), 2);
}

#[test]
fn bad_arguments_are_refused_with_a_clear_message() {
    let possible_engines = format!(
        "[possible values: {}]",
        tunnelnav::fusion::EngineKind::names()
    );
    let cases: &[(&[&str], &str)] = &[
        (
            &["replay", "--engine", "kalman", "-"],
            "invalid value 'kalman' for '--engine <ENGINE>'",
        ),
        (&["params", "--engine", "kalman"], possible_engines.as_str()),
        (
            &[
                "replay",
                "--engine",
                "attitude",
                "--param",
                "fusion_gain_pitch=1.5",
                "-",
            ],
            "`fusion_gain_pitch` = 1.5 is out of range",
        ),
        (
            &[
                "replay",
                "--engine",
                "attitude",
                "--param",
                "fusion_gain=0.1",
                "-",
            ],
            "unknown parameter `fusion_gain`",
        ),
        (
            &[
                "replay",
                "--engine",
                "attitude",
                "/nonexistent/drive.ndjson",
            ],
            "cannot open /nonexistent/drive.ndjson",
        ),
        (&["simulate", "tbm", "--hours", "0"], "hours must be > 0"),
        (
            &["simulate", "vehicle", "--minutes", "2"],
            "duration must be 300 s–24 h",
        ),
        (
            &[
                "replay",
                "--engine",
                "fuzzy",
                "--param",
                "gyro_activity_still_factor=5",
                "-",
            ],
            "gyro_activity_moving_factor (3) must be above gyro_activity_still_factor (5)",
        ),
        (
            &[
                "replay",
                "--engine",
                "fuzzy",
                "--param",
                "gyro_activity_still_dps=0.3",
                "-",
            ],
            "parameter `gyro_activity_still_dps` was retired: thresholds are now multiples of the noise floor",
        ),
        (
            &["eval", "attitude", "--hours", "2", "--learning-h", "3"],
            "shorter than the 2 h drive",
        ),
        (
            &[
                "replay",
                "--engine",
                "attitude",
                "--param",
                "correction_slew_deg_per_s=0.001",
                "-",
            ],
            "parameter `correction_slew_deg_per_s` was retired: a retrain now moves",
        ),
    ];
    for (args, message) in cases {
        let out = tunnelnav().args(*args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        let stderr = String::from_utf8(out.stderr).unwrap();
        assert!(stderr.contains(message), "{args:?}: {stderr}");
    }
    let out = tunnelnav()
        .args(["simulate", "tbm", "--dropout", "2h"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8(out.stderr)
            .unwrap()
            .contains("START_H:MINUTES")
    );
}

#[test]
fn eval_prints_the_table_with_every_method() {
    let out = tunnelnav()
        .args(["eval", "attitude", "--hours", "3", "--dropout", "2:20"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let table = String::from_utf8(out.stdout).unwrap();
    for method in [
        "tunnelnav attitude",
        "laser zero-order hold",
        "raw inclinometer",
        "constant-offset inclinometer",
        "kf3 (textbook 3-state filter)",
        "oracle (kf3, true error removed)",
        "dropout 1 max",
    ] {
        assert!(table.contains(method), "{table}");
    }
}

#[test]
fn envelope_drives_are_simulated_and_summarised() {
    let out = tunnelnav()
        .args(["simulate", "tbm", "--envelope", "--seed", "4"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let draw: serde_json::Value =
        serde_json::from_slice(out.stderr.split(|&b| b == b'\n').next().unwrap()).unwrap();
    assert_eq!(draw["seed"], 4);
    let lines = String::from_utf8(out.stdout).unwrap();
    let inclinometer = lines.lines().filter(|l| l.contains("inclinometer")).count() as f64;
    let expected = 12.0 * 3600.0 / draw["incl_period_s"].as_f64().unwrap();
    assert!((inclinometer - expected).abs() <= 2.0, "{inclinometer}");
    let out = tunnelnav()
        .args(["simulate", "tbm", "--envelope", "--hours", "3"])
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(2),
        "--hours conflicts with --envelope"
    );

    let out = tunnelnav()
        .args([
            "eval",
            "attitude",
            "--envelope",
            "--seed",
            "3",
            "--seeds",
            "2",
        ])
        .output()
        .unwrap();
    assert!(out.status.success());
    let table = String::from_utf8(out.stdout).unwrap();
    for line in [
        "attitude evaluation: envelope seed 3",
        "attitude evaluation: envelope seed 4",
        "attitude over the envelope: 2 drives (envelope seeds 3–4)",
        "engine ÷ oracle, pitch RMSE: median",
        "kf3 ÷ engine, pitch RMSE: median",
    ] {
        assert!(table.contains(line), "{line}: {table}");
    }
}

#[test]
fn eval_fuzzy_prints_the_engine_and_its_baselines() {
    let out = tunnelnav()
        .args(["eval", "fuzzy", "--minutes", "6"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let table = String::from_utf8(out.stdout).unwrap();
    for row in [
        "fuzzy engine",
        "gyro only",
        "accelerometer only",
        "raw compass",
        "Madgwick β=",
        "Mahony",
        "VQF",
        "motion status",
        "calibrated (planar)",
    ] {
        assert!(table.contains(row), "{table}");
    }
}

#[test]
fn eval_fuzzy_over_seeds_prints_a_summary() {
    let out = tunnelnav()
        .args(["eval", "fuzzy", "--minutes", "5", "--seeds", "2", "--hard"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let table = String::from_utf8(out.stdout).unwrap();
    for line in [
        "vehicle drive, seed 1",
        "vehicle drive, seed 2",
        "summary over 2 drives (seeds 1–2), median / worst",
        "baseline ÷ engine RMSE",
        "Madgwick β (rad/s) chosen per drive with the truth",
    ] {
        assert!(table.contains(line), "{line}: {table}");
    }
    let out = tunnelnav()
        .args(["eval", "fuzzy", "--minutes", "5", "--seeds", "2", "--json"])
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 3);
    assert_eq!(lines[2]["summary"]["drives"], 2);
    assert!(lines[0]["madgwick_tuned"]["pitch_deg"].is_number());
    assert!(lines[0]["vqf"]["heading_deg"].is_number());
}

#[test]
fn params_lists_every_parameter_with_its_default() {
    let out = tunnelnav()
        .args(["params", "--engine", "attitude"])
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    for spec in tunnelnav::fusion::attitude::PARAMS {
        assert!(text.contains(spec.name), "{} missing", spec.name);
    }
}

#[test]
fn replay_restores_order_and_drops_duplicates() {
    // The same drive, once in order and once as a gateway might deliver it:
    // lines swapped within a few seconds and some sent twice.
    let sim = tunnelnav()
        .args(["simulate", "tbm", "--hours", "1", "--seed", "3"])
        .output()
        .unwrap();
    let ordered = String::from_utf8(sim.stdout).unwrap();
    let mut lines: Vec<&str> = ordered.lines().collect();
    for i in (0..lines.len() - 4).step_by(7) {
        lines.swap(i, i + 3);
    }
    let mut messy = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        messy.push(*line);
        if i % 11 == 0 {
            messy.push(*line);
        }
    }
    let dir = temp_dir("disorder");
    let (a, b) = (dir.join("ordered.ndjson"), dir.join("messy.ndjson"));
    std::fs::write(&a, &ordered).unwrap();
    std::fs::write(&b, messy.join("\n")).unwrap();
    let run = |path: &std::path::Path| {
        tunnelnav()
            .args(["replay", "--engine", "attitude"])
            .arg(path)
            .output()
            .unwrap()
    };
    let (clean, shuffled) = (run(&a), run(&b));
    assert!(clean.status.success() && shuffled.status.success());
    assert!(
        clean.stdout == shuffled.stdout,
        "estimates differ after reordering"
    );
    let summary = String::from_utf8(shuffled.stderr).unwrap();
    let duplicates = messy.len() - lines.len();
    assert!(
        summary.contains(&format!("0 late, {duplicates} duplicates")),
        "{summary}"
    );
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn eval_recording_scores_the_committed_broad_excerpt() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/broad");
    let output = tunnelnav()
        .args(["eval", "recording", "--dir", dir, "--json"])
        .output()
        .unwrap();
    assert!(output.status.success(), "{output:?}");
    let evaluation: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let trials = evaluation["trials"].as_array().unwrap();
    assert_eq!(trials.len(), 1, "{evaluation}");
    // A missing directory is an error naming it.
    let missing = tunnelnav()
        .args(["eval", "recording", "--dir", "/nonexistent/broad"])
        .output()
        .unwrap();
    assert!(!missing.status.success());
    let stderr = String::from_utf8_lossy(&missing.stderr);
    assert!(stderr.contains("/nonexistent/broad"), "{stderr}");
}

/// Issue 54: `simulate … --fault` injects a fault category at 40 % of the
/// drive, as `eval … --envelope --fault` does: an hour's TBM drive with a
/// frozen inclinometer repeats its reading from 1,440 s for 120 s, its
/// truth untouched, and a fault that does not concern the machine's
/// sensors is refused by name.
#[test]
fn simulate_injects_a_fault_and_refuses_one_that_does_not_apply() {
    let sim = tunnelnav()
        .args(["simulate", "tbm", "--hours", "1", "--fault", "frozen"])
        .output()
        .unwrap();
    assert!(sim.status.success());
    let inclinometer: Vec<serde_json::Value> = String::from_utf8(sim.stdout)
        .unwrap()
        .lines()
        .map(|line| serde_json::from_str::<serde_json::Value>(line).unwrap())
        .filter(|r| r["sensor"] == "inclinometer")
        .collect();
    let t0 = inclinometer[0]["t"].as_f64().unwrap();
    let repeated: Vec<f64> = inclinometer
        .windows(2)
        .filter(|pair| {
            pair[0]["pitch_deg"] == pair[1]["pitch_deg"]
                && pair[0]["roll_deg"] == pair[1]["roll_deg"]
        })
        .map(|pair| pair[1]["t"].as_f64().unwrap() - t0)
        .collect();
    // The 1 Hz readings at 1,441 … 1,559 s repeat the one at 1,440 s.
    assert_eq!(repeated.len(), 119, "{repeated:?}");
    assert_eq!(repeated[0], 1441.0);
    assert_eq!(*repeated.last().unwrap(), 1559.0);

    let refused = tunnelnav()
        .args(["simulate", "pipe-jacking", "--fault", "steel"])
        .output()
        .unwrap();
    assert!(!refused.status.success());
    let said = String::from_utf8(refused.stderr).unwrap();
    assert!(
        said.contains("fault `steel` does not apply to `zupt`"),
        "{said}"
    );
}
