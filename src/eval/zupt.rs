//! `eval zupt`: the paper's Tables 2 and 3 recomputed on simulated truth.
//! The same simulated drive runs through the `zupt` engine once per
//! detector (TCZVD, MV, ARE, SHOE, MAG) and once with none (pure inertial
//! navigation; level aiding stays on, so only the ZUPTs are missing), and
//! once more with TCZVD and the odometer fused.
//!
//! Scores per run:
//! - zero-velocity precision, recall and F0.5 per IMU reading against the
//!   truth (the machine not moving at all);
//! - final along-track distance error and final 3-D position error, in
//!   metres and in % of the distance travelled;
//! - the share of readings whose position error lies within 3σ of the
//!   filter's own covariance, on each axis (consistency);
//! - the time wrongly declared still while moving, and which rests of 2 min
//!   or more were found at all (the field case asks for both).

use serde::Serialize;

use crate::fusion::zupt::{PARAMS, ZuptEngine};
use crate::fusion::{Engine, EngineOutput, ParamError, ParamValue, Params, Reading};
use crate::sim::pipejack::{Case, PipeJackDrive, PipeJackScenario, PipeJackTruth};

/// What to evaluate.
#[derive(Debug, Clone)]
pub struct ZuptEvalConfig {
    pub scenario: PipeJackScenario,
    /// Parameters of the engine; `detector`, `latitude_deg` and
    /// `initial_yaw_deg` are set per run from the scenario.
    pub params: Params,
}

impl ZuptEvalConfig {
    /// The scenario with the engine's default parameters.
    pub fn new(scenario: PipeJackScenario) -> ZuptEvalConfig {
        ZuptEvalConfig {
            scenario,
            params: Params::defaults(PARAMS),
        }
    }
}

/// The scores of one detector.
#[derive(Debug, Clone, Serialize)]
pub struct DetectorScores {
    pub detector: String,
    pub precision: f64,
    pub recall: f64,
    pub f_half: f64,
    pub distance_error_m: f64,
    pub distance_error_pct: f64,
    pub position_error_m: f64,
    pub position_error_pct: f64,
    /// Share of readings with |error| ≤ 3σ, per axis (north, east, down).
    pub within_3_sigma: [f64; 3],
    /// Seconds declared still while the machine moved.
    pub false_zv_s: f64,
    /// |heading error| at the end of the drive, degrees.
    pub heading_error_deg: f64,
    /// Over every point of the smoothed pushes: how many, and the RMS of
    /// the along-track error within the push (the distance since the
    /// push's first point, against the truth's) of the live estimates at
    /// the same instants and of the smoothed track, m. Both start from the
    /// same point and end at the same one; the error carried in from
    /// earlier pushes is left out.
    pub track_points: usize,
    pub live_track_rms_m: f64,
    pub smoothed_track_rms_m: f64,
    /// Rests of 120 s or more, and how many of them had any zero velocity.
    pub long_rests: usize,
    pub long_rests_found: usize,
}

/// The whole evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct ZuptEvaluation {
    pub scenario: PipeJackScenario,
    pub duration_s: f64,
    pub distance_m: f64,
    pub pushes: usize,
    pub detectors: Vec<DetectorScores>,
}

/// Why an evaluation could not run.
#[derive(Debug, thiserror::Error)]
pub enum ZuptEvalError {
    #[error("invalid scenario: {0}")]
    Scenario(String),
    #[error(transparent)]
    Params(#[from] ParamError),
}

/// The runs: label, detector, odometer aiding. The paper's detectors in
/// its order, then none, then TCZVD with the odometer fused (what a
/// machine with long pushes needs).
pub const RUNS: [(&str, &str, bool); 7] = [
    ("tczvd", "tczvd", false),
    ("mv", "mv", false),
    ("are", "are", false),
    ("shoe", "shoe", false),
    ("mag", "mag", false),
    ("none", "none", false),
    ("tczvd+odo", "tczvd", true),
];

/// Simulates the drive once and scores every run of [`RUNS`] on it.
pub fn evaluate(config: &ZuptEvalConfig) -> Result<ZuptEvaluation, ZuptEvalError> {
    evaluate_runs(config, &RUNS)
}

/// Simulates the drive once and scores the given runs (label, detector,
/// odometer aiding) on it.
pub fn evaluate_runs(
    config: &ZuptEvalConfig,
    runs: &[(&str, &str, bool)],
) -> Result<ZuptEvaluation, ZuptEvalError> {
    let drive = PipeJackDrive::new(config.scenario.clone()).map_err(ZuptEvalError::Scenario)?;
    let duration_s = drive.duration_s();
    let distance_m = drive.total_distance_m();
    let rests = drive.rests_s();
    let pushes = rests.len().saturating_sub(1);
    let mut readings = Vec::new();
    let mut truths = Vec::new();
    for event in drive {
        if let Some(truth) = event.truth {
            truths.push(truth);
        }
        readings.push(event.reading);
    }
    let mut detectors = Vec::new();
    for &(label, detector, odometer) in runs {
        let params = run_params(config, detector, odometer)?;
        let outputs = run(&readings, params)?;
        detectors.push(score(
            label,
            &outputs,
            &truths,
            &rests,
            config.scenario.start_t,
            config.scenario.imu_period_s(),
        ));
    }
    Ok(ZuptEvaluation {
        scenario: config.scenario.clone(),
        duration_s,
        distance_m,
        pushes,
        detectors,
    })
}

/// The engine's parameters for one run: the scenario's site and heading,
/// and the detector.
pub fn run_params(
    config: &ZuptEvalConfig,
    detector: &str,
    odometer_aiding: bool,
) -> Result<Params, ParamError> {
    let mut overrides = vec![
        (
            "latitude_deg".to_string(),
            ParamValue::Number(config.scenario.latitude_deg),
        ),
        (
            "initial_yaw_deg".to_string(),
            ParamValue::Number(config.scenario.heading_deg),
        ),
        ("detector".to_string(), ParamValue::Text(detector.into())),
    ];
    overrides.push((
        "odometer_aiding".to_string(),
        ParamValue::Bool(odometer_aiding),
    ));
    config.params.with_overrides(PARAMS, overrides)
}

/// Runs the engine over time-ordered readings; one output per IMU reading.
pub fn run(readings: &[Reading], params: Params) -> Result<Vec<EngineOutput>, ParamError> {
    let mut engine = ZuptEngine::new(params)?;
    let mut outputs = Vec::with_capacity(readings.len());
    for reading in readings {
        engine.feed(reading, &mut outputs);
    }
    engine.flush(&mut outputs);
    Ok(outputs)
}

/// Zero-velocity decisions per IMU reading against the truth.
#[derive(Debug, Clone, Copy, Default)]
pub struct ZeroVelocityTally {
    /// Called still and still, called still while moving, called moving while still.
    pub true_still: u64,
    pub false_still: u64,
    pub missed_still: u64,
}

impl ZeroVelocityTally {
    /// Adds one reading's decision.
    pub fn add(&mut self, called_still: bool, truly_still: bool) {
        match (called_still, truly_still) {
            (true, true) => self.true_still += 1,
            (true, false) => self.false_still += 1,
            (false, true) => self.missed_still += 1,
            (false, false) => {}
        }
    }

    /// Share of the still calls that were right; `no_calls` when none was made.
    pub fn precision_or(&self, no_calls: f64) -> f64 {
        let calls = self.true_still + self.false_still;
        if calls == 0 {
            no_calls
        } else {
            self.true_still as f64 / calls as f64
        }
    }

    /// Share of the still readings called still (0 when there were none).
    pub fn recall(&self) -> f64 {
        let still = self.true_still + self.missed_still;
        if still == 0 {
            0.0
        } else {
            self.true_still as f64 / still as f64
        }
    }
}

/// Scores one run against the truth (matched by time).
pub fn score(
    detector: &str,
    outputs: &[EngineOutput],
    truths: &[PipeJackTruth],
    rests_s: &[(f64, f64)],
    start_t: f64,
    period_s: f64,
) -> DetectorScores {
    let (mut tally, mut within, mut scored) = (ZeroVelocityTally::default(), [0u64; 3], 0u64);
    let mut last: Option<(&PipeJackTruth, &crate::fusion::ZuptEstimate)> = None;
    let mut found = vec![false; rests_s.len()];
    let mut rest = 0;
    let mut truth_iter = truths.iter().peekable();
    for output in outputs {
        let Some(estimate) = output.values.as_zupt() else {
            continue;
        };
        // Estimates come one per IMU reading, in order: skip truths of
        // readings the engine dropped (none, for simulated input).
        while truth_iter.peek().is_some_and(|t| t.t < output.t) {
            truth_iter.next();
        }
        let Some(truth) = truth_iter.next() else {
            break;
        };
        tally.add(estimate.zv, truth.zv);
        if estimate.zv {
            let s = output.t - start_t;
            while rest + 1 < rests_s.len() && s > rests_s[rest].1 {
                rest += 1;
            }
            if let Some(&(from, to)) = rests_s.get(rest)
                && s >= from
                && s <= to
            {
                found[rest] = true;
            }
        }
        if estimate.aligned {
            scored += 1;
            for (axis, count) in within.iter_mut().enumerate() {
                let error = (estimate.position_m[axis] - truth.position_m[axis]).abs();
                if error <= 3.0 * estimate.position_sigma_m[axis] + 1e-9 {
                    *count += 1;
                }
            }
        }
        last = Some((truth, estimate));
    }
    let (track_points, live_track_rms_m, smoothed_track_rms_m) =
        track_errors(outputs, truths, start_t, period_s);
    let ratio = |a: u64, b: u64| if b == 0 { 0.0 } else { a as f64 / b as f64 };
    let precision = tally.precision_or(0.0);
    let recall = tally.recall();
    let f_half = if precision + recall == 0.0 {
        0.0
    } else {
        1.25 * precision * recall / (0.25 * precision + recall)
    };
    let heading_error_deg = last.map_or(f64::NAN, |(truth, estimate)| {
        super::heading_error_deg(estimate.yaw_deg, truth.yaw_deg)
    });
    let (distance_error_m, position_error_m, travelled) = match last {
        Some((truth, estimate)) => {
            let position_error = (0..3)
                .map(|i| (estimate.position_m[i] - truth.position_m[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            (
                (estimate.distance_m - truth.distance_m).abs(),
                position_error,
                truth.distance_m,
            )
        }
        None => (f64::NAN, f64::NAN, 0.0),
    };
    let pct = |error: f64| {
        if travelled > 0.0 {
            100.0 * error / travelled
        } else {
            f64::NAN
        }
    };
    let long: Vec<usize> = (0..rests_s.len())
        .filter(|&i| rests_s[i].1 - rests_s[i].0 >= 120.0)
        .collect();
    DetectorScores {
        detector: detector.to_string(),
        precision,
        recall,
        f_half,
        distance_error_m,
        distance_error_pct: pct(distance_error_m),
        position_error_m,
        position_error_pct: pct(position_error_m),
        within_3_sigma: within.map(|w| ratio(w, scored)),
        false_zv_s: tally.false_still as f64 * period_s,
        heading_error_deg,
        track_points,
        live_track_rms_m,
        smoothed_track_rms_m,
        long_rests: long.len(),
        long_rests_found: long.iter().filter(|&&i| found[i]).count(),
    }
}

/// The along-track errors within each smoothed push at its points:
/// (points, live RMS, smoothed RMS), m. Truths and live estimates are
/// found by the IMU sample index of the point's time.
fn track_errors(
    outputs: &[EngineOutput],
    truths: &[PipeJackTruth],
    start_t: f64,
    period_s: f64,
) -> (usize, f64, f64) {
    let index = |t: f64| ((t - start_t) / period_s).round() as usize;
    let mut live = vec![None; truths.len()];
    for output in outputs {
        if let Some(estimate) = output.values.as_zupt()
            && let Some(slot) = live.get_mut(index(output.t))
        {
            *slot = Some(estimate.distance_m);
        }
    }
    let (mut n, mut live_sq, mut smoothed_sq) = (0usize, 0.0, 0.0);
    for output in outputs {
        let Some(points) = output
            .values
            .as_zupt()
            .and_then(|e| e.smoothed_push.as_ref())
        else {
            continue;
        };
        let at = |point: &crate::fusion::estimate::TrackPoint| {
            let i = index(point.t);
            match (truths.get(i), live.get(i)) {
                (Some(truth), Some(Some(live_m))) => {
                    Some((truth.distance_m, *live_m, point.distance_m))
                }
                _ => None,
            }
        };
        let Some((truth_0, live_0, smoothed_0)) = points.first().and_then(at) else {
            continue;
        };
        for (truth, live_m, smoothed_m) in points.iter().filter_map(at) {
            let travelled = truth - truth_0;
            n += 1;
            live_sq += (live_m - live_0 - travelled).powi(2);
            smoothed_sq += (smoothed_m - smoothed_0 - travelled).powi(2);
        }
    }
    let rms = |sum: f64| {
        if n == 0 {
            f64::NAN
        } else {
            (sum / n as f64).sqrt()
        }
    };
    (n, rms(live_sq), rms(smoothed_sq))
}

/// The evaluation as a table like the paper's.
pub fn render_table(e: &ZuptEvaluation) -> String {
    use std::fmt::Write;
    let s = &e.scenario;
    let mut out = String::new();
    let case = match s.case {
        Case::Trolley => "trolley",
        Case::Varied => "varied duty cycle",
        Case::Field => "field",
    };
    let _ = writeln!(
        out,
        "zupt evaluation: {case}, seed {}, {:.0} s, {} pushes, {:.2} m travelled, heading {}°, slope {}°, latitude {}°",
        s.seed, e.duration_s, e.pushes, e.distance_m, s.heading_deg, s.slope_deg, s.latitude_deg
    );
    let _ = writeln!(
        out,
        "{:<10} {:>9} {:>8} {:>7} {:>12} {:>8} {:>12} {:>8} {:>10} {:>9} {:>12} {:>11} {:>17}",
        "detector",
        "precision",
        "recall",
        "F0.5",
        "distance m",
        "dist %",
        "position m",
        "pos %",
        "false ZV s",
        "heading °",
        "rests≥2min",
        "≤3σ N/E/D %",
        "track m live/RTS"
    );
    for d in &e.detectors {
        let _ = writeln!(
            out,
            "{:<10} {:>8.2}% {:>7.2}% {:>6.2}% {:>12.3} {:>7.2}% {:>12.3} {:>7.2}% {:>10.1} {:>9.3} {:>12} {:>11} {:>17}",
            d.detector,
            100.0 * d.precision,
            100.0 * d.recall,
            100.0 * d.f_half,
            d.distance_error_m,
            d.distance_error_pct,
            d.position_error_m,
            d.position_error_pct,
            d.false_zv_s,
            d.heading_error_deg,
            format!("{}/{}", d.long_rests_found, d.long_rests),
            format!(
                "{:.0}/{:.0}/{:.0}",
                100.0 * d.within_3_sigma[0],
                100.0 * d.within_3_sigma[1],
                100.0 * d.within_3_sigma[2]
            ),
            if d.track_points > 0 {
                format!("{:.4}/{:.4}", d.live_track_rms_m, d.smoothed_track_rms_m)
            } else {
                "–".to_string()
            },
        );
    }
    out
}
