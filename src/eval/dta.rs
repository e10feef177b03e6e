//! `eval dta`: the `dta` stream end to end against simulated truth.
//!
//! Laser source: drives from [`AxisDriveScenario::draw`] (random axes with
//! spirals, arcs either way and vertical curves; random shields and
//! laser-target offsets) run through the `attitude` engine and the `dta`
//! stage as a declared machine would; each `dta` estimate is compared with
//! the simulator's own deviations of front and rear at that laser
//! reading. What remains is the laser's position noise and the fused
//! attitude's error over the lever arm.

use serde::Serialize;

use super::ErrorStats;
use crate::fusion::Declaration;
use crate::fusion::pipeline::Pipeline;
use crate::fusion::{EngineKind, EngineOutput, EstimateValues, Params};
use crate::sim::axis_drive::{AxisDrive, AxisDriveScenario, AxisTruth};

/// Errors of one drive, mm (mm/m for the tendency).
#[derive(Debug, Clone, Serialize)]
pub struct DtaScore {
    pub seed: u64,
    pub laser_readings: usize,
    pub estimates: usize,
    pub front_horizontal: ErrorStats,
    pub front_vertical: ErrorStats,
    pub rear_horizontal: ErrorStats,
    pub rear_vertical: ErrorStats,
    /// Front station, mm.
    pub front_station: ErrorStats,
    pub tendency_horizontal: ErrorStats,
    pub tendency_vertical: ErrorStats,
    /// Largest true deviation of the front, mm: how near the tolerances
    /// the drive came.
    pub largest_true_horizontal_mm: f64,
    pub largest_true_vertical_mm: f64,
    /// Estimates whose status disagrees with the truth's against the
    /// tolerances, beyond 2 mm of a limit.
    pub status_mismatches: usize,
}

impl DtaScore {
    /// The largest error of any deviation of the drive, mm.
    pub fn worst_deviation_mm(&self) -> f64 {
        super::largest_abs(&[
            &self.front_horizontal,
            &self.front_vertical,
            &self.rear_horizontal,
            &self.rear_vertical,
        ])
    }
}

/// Runs one drive through a machine declared with the scenario's axis,
/// geometry and tolerances, and the `attitude` engine with `params`.
pub fn evaluate(scenario: &AxisDriveScenario, params: &Params) -> Result<DtaScore, String> {
    let alignment = scenario
        .alignment
        .build()
        .map_err(|e| format!("the scenario's axis: {e}"))?;
    let declaration = Declaration {
        alignment: Some(std::sync::Arc::new(alignment)),
        geometry: Some(scenario.geometry),
        tolerances: Some(scenario.tolerances),
        ..Declaration::of_engines([EngineKind::Attitude])
    };
    let engine = EngineKind::Attitude
        .create(params.clone())
        .map_err(|e| e.to_string())?;
    let mut pipeline = Pipeline::declared(vec![engine], &declaration);
    let mut truths: Vec<AxisTruth> = Vec::new();
    let mut outputs: Vec<EngineOutput> = Vec::new();
    for event in AxisDrive::new(scenario.clone())? {
        if let Some(truth) = event.truth {
            truths.push(truth);
        }
        pipeline.feed(&event.reading, &mut outputs);
    }
    pipeline.flush(&mut outputs);

    let length_m = scenario.geometry.front_m[0] - scenario.geometry.rear_m[0];
    let mut score = DtaScore {
        seed: scenario.seed,
        laser_readings: truths.len(),
        estimates: 0,
        front_horizontal: ErrorStats::default(),
        front_vertical: ErrorStats::default(),
        rear_horizontal: ErrorStats::default(),
        rear_vertical: ErrorStats::default(),
        front_station: ErrorStats::default(),
        tendency_horizontal: ErrorStats::default(),
        tendency_vertical: ErrorStats::default(),
        largest_true_horizontal_mm: 0.0,
        largest_true_vertical_mm: 0.0,
        status_mismatches: 0,
    };
    let mut truth_iter = truths.iter().peekable();
    for output in &outputs {
        let EstimateValues::Dta(d) = &output.values else {
            continue;
        };
        while truth_iter.peek().is_some_and(|t| t.t < output.t) {
            truth_iter.next();
        }
        let Some(truth) = truth_iter.peek().filter(|t| t.t == output.t) else {
            return Err(format!(
                "a dta estimate at t={} has no laser reading",
                output.t
            ));
        };
        score.estimates += 1;
        score
            .front_horizontal
            .add(d.front.horizontal_mm - truth.front.horizontal_mm);
        score
            .front_vertical
            .add(d.front.vertical_mm - truth.front.vertical_mm);
        score
            .rear_horizontal
            .add(d.rear.horizontal_mm - truth.rear.horizontal_mm);
        score
            .rear_vertical
            .add(d.rear.vertical_mm - truth.rear.vertical_mm);
        score
            .front_station
            .add((d.front.station_m - truth.front.station_m) * 1000.0);
        let tendency = |front: f64, rear: f64| (front - rear) / length_m;
        score.tendency_horizontal.add(
            d.tendency_horizontal_mm_per_m
                - tendency(truth.front.horizontal_mm, truth.rear.horizontal_mm),
        );
        score.tendency_vertical.add(
            d.tendency_vertical_mm_per_m
                - tendency(truth.front.vertical_mm, truth.rear.vertical_mm),
        );
        score.largest_true_horizontal_mm = score
            .largest_true_horizontal_mm
            .max(truth.front.horizontal_mm.abs());
        score.largest_true_vertical_mm = score
            .largest_true_vertical_mm
            .max(truth.front.vertical_mm.abs());
        if let Some(status) = d.status
            && let Some(expected) = true_status(scenario, truth)
            && status.as_str() != expected
        {
            score.status_mismatches += 1;
        }
    }
    Ok(score)
}

/// The status the truth calls for, or `None` when a deviation is within
/// 2 mm of a limit (either answer is then fair).
fn true_status(scenario: &AxisDriveScenario, truth: &AxisTruth) -> Option<&'static str> {
    let t = &scenario.tolerances;
    let mut worst = 0;
    for point in [truth.front, truth.rear] {
        for (value, limits) in [
            (point.horizontal_mm.abs(), t.horizontal_mm),
            (point.vertical_mm.abs(), t.vertical_mm),
        ] {
            for limit in [limits.warn, limits.alarm] {
                if (value - limit).abs() < 2.0 {
                    return None;
                }
            }
            let level = if value > limits.alarm {
                2
            } else if value > limits.warn {
                1
            } else {
                0
            };
            worst = worst.max(level);
        }
    }
    Some(["ok", "warn", "alarm"][worst])
}

/// Median and worst over drives of each drive's largest error, mm.
#[derive(Debug, Clone, Serialize)]
pub struct DtaSummary {
    pub drives: usize,
    pub estimates: usize,
    pub median_worst_deviation_mm: f64,
    pub worst_deviation_mm: f64,
    pub median_rms_front_horizontal_mm: f64,
    pub median_rms_front_vertical_mm: f64,
    pub worst_station_mm: f64,
    pub worst_tendency_mm_per_m: f64,
    pub status_mismatches: usize,
}

/// The summary of `scores`.
pub fn summarise(scores: &[DtaScore]) -> DtaSummary {
    let median = super::median;
    let worst = |f: &dyn Fn(&DtaScore) -> f64| scores.iter().map(f).fold(0.0, f64::max);
    DtaSummary {
        drives: scores.len(),
        estimates: scores.iter().map(|s| s.estimates).sum(),
        median_worst_deviation_mm: median(
            scores.iter().map(DtaScore::worst_deviation_mm).collect(),
        ),
        worst_deviation_mm: worst(&DtaScore::worst_deviation_mm),
        median_rms_front_horizontal_mm: median(
            scores.iter().map(|s| s.front_horizontal.rmse()).collect(),
        ),
        median_rms_front_vertical_mm: median(
            scores.iter().map(|s| s.front_vertical.rmse()).collect(),
        ),
        worst_station_mm: worst(&|s| s.front_station.max_abs),
        worst_tendency_mm_per_m: worst(&|s| {
            s.tendency_horizontal
                .max_abs
                .max(s.tendency_vertical.max_abs)
        }),
        status_mismatches: scores.iter().map(|s| s.status_mismatches).sum(),
    }
}

/// One line per drive and the summary, as a table.
pub fn render(scores: &[DtaScore], summary: &DtaSummary) -> String {
    let mut out = String::from(
        "seed  estimates  front H rms/max   front V rms/max   rear H max  rear V max  station max  tendency max  true H/V max   status\n",
    );
    for s in scores {
        out.push_str(&format!(
            "{:>4}  {:>9}  {:>6.2} / {:>6.2}   {:>6.2} / {:>6.2}   {:>10.2}  {:>10.2}  {:>8.1} mm  {:>7.3} mm/m  {:>5.0}/{:<4.0} mm  {}\n",
            s.seed,
            s.estimates,
            s.front_horizontal.rmse(),
            s.front_horizontal.max_abs,
            s.front_vertical.rmse(),
            s.front_vertical.max_abs,
            s.rear_horizontal.max_abs,
            s.rear_vertical.max_abs,
            s.front_station.max_abs,
            s.tendency_horizontal.max_abs.max(s.tendency_vertical.max_abs),
            s.largest_true_horizontal_mm,
            s.largest_true_vertical_mm,
            s.status_mismatches,
        ));
    }
    out.push_str(&format!(
        "\n{} drives, {} estimates: largest deviation error per drive median {:.2} mm, worst {:.2} mm; \
         RMS front H median {:.2} mm, V {:.2} mm; station worst {:.1} mm; tendency worst {:.3} mm/m; \
         status disagreeing with the truth (beyond 2 mm of a limit): {}\n",
        summary.drives,
        summary.estimates,
        summary.median_worst_deviation_mm,
        summary.worst_deviation_mm,
        summary.median_rms_front_horizontal_mm,
        summary.median_rms_front_vertical_mm,
        summary.worst_station_mm,
        summary.worst_tendency_mm_per_m,
        summary.status_mismatches,
    ));
    out
}
