//! `eval attitude`: runs the `attitude` engine and its baselines over a
//! simulated TBM drive and scores each against the truth.
//!
//! Methods scored, all on the same readings:
//! - the engine as configured (ANFIS correction by default);
//! - the engine with `correction=offset` and with `correction=none`
//!   (ablations: what the ANFIS adds);
//! - laser zero-order hold: the latest laser sample, as a driver reading the
//!   laser alone sees it;
//! - raw inclinometer;
//! - constant-offset inclinometer: the inclinometer through the same Kalman
//!   filter, plus the mean laser − inclinometer difference over the learning
//!   period, frozen after it (an installation calibration).
//!
//! Scores count only after the learning period. "At laser instants" is the
//! one-step prediction made just before each laser sample, compared with the
//! truth at the time it predicts. "Through a dropout" is from the dropout's
//! start until two laser periods after it ends, to include the recovery.
//! The step excess (how much more an output moves between two readings than
//! the truth does) is taken over the two laser periods after the laser
//! returns, and over the two before the dropout as the ordinary reference.

use crate::fusion::attitude::kalman::ScalarKalman;
use crate::fusion::attitude::{AttitudeConfig, AttitudeEngine, PARAMS};
use crate::fusion::{
    AttitudeEstimate, Engine, EngineOutput, ParamError, ParamValue, Params, SensorData,
};
use crate::sim::tbm::{TbmDrive, TbmScenario};

use super::ErrorStats;
use serde::Serialize;

/// What to evaluate.
#[derive(Debug, Clone)]
pub struct AttitudeEvalConfig {
    pub scenario: TbmScenario,
    /// Hours at the start that are not scored.
    pub learning_h: f64,
    /// Parameters of the engine under test (its ablations change `correction`).
    pub params: Params,
}

impl AttitudeEvalConfig {
    /// The default drive with the engine's default parameters.
    pub fn new(scenario: TbmScenario) -> AttitudeEvalConfig {
        AttitudeEvalConfig {
            scenario,
            learning_h: 1.0,
            params: Params::defaults(PARAMS),
        }
    }
}

/// The scores of one method.
#[derive(Debug, Clone, Serialize)]
pub struct MethodScores {
    pub method: String,
    pub pitch: ErrorStats,
    pub roll: ErrorStats,
    /// One-step prediction error of pitch at laser instants.
    pub pitch_pred_at_laser: ErrorStats,
    /// Pitch error through each dropout, in scenario order.
    pub pitch_in_dropout: Vec<ErrorStats>,
    /// Largest step between consecutive pitch outputs beyond the true step,
    /// within two laser periods after each dropout ends.
    pub return_step_excess_deg: Vec<f64>,
    /// The same over the two laser periods before each dropout starts: the
    /// ordinary step noise the return is compared with.
    pub steady_step_excess_deg: Vec<f64>,
}

/// The scores of every method on one drive.
#[derive(Debug, Clone, Serialize)]
pub struct AttitudeEvaluation {
    pub scenario: TbmScenario,
    pub learning_h: f64,
    pub methods: Vec<MethodScores>,
}

impl AttitudeEvaluation {
    /// The scores of the method called `name`.
    pub fn method(&self, name: &str) -> Option<&MethodScores> {
        self.methods.iter().find(|m| m.method == name)
    }

    /// The engine as configured.
    pub fn engine(&self) -> &MethodScores {
        &self.methods[0]
    }

    /// The baselines (not the engine or its ablations).
    pub fn baselines(&self) -> impl Iterator<Item = &MethodScores> {
        self.methods
            .iter()
            .filter(|m| BASELINES.contains(&m.method.as_str()))
    }
}

/// Method names.
pub const ENGINE: &str = "tunnelnav attitude";
pub const ENGINE_OFFSET: &str = "  ablation: correction=offset";
pub const ENGINE_NONE: &str = "  ablation: correction=none";
pub const LASER_HOLD: &str = "laser zero-order hold";
pub const RAW_INCLINOMETER: &str = "raw inclinometer";
pub const CONSTANT_OFFSET: &str = "constant-offset inclinometer";
const BASELINES: [&str; 3] = [LASER_HOLD, RAW_INCLINOMETER, CONSTANT_OFFSET];

/// One method's running output and score.
struct Scorer {
    scores: MethodScores,
    /// The pitch the latest output predicts for the next step.
    prediction: Option<f64>,
    /// A prediction made before a laser instant, waiting for the next truth.
    pending_check: Option<f64>,
    previous_pitch: Option<f64>,
}

impl Scorer {
    fn new(method: &str, dropouts: usize) -> Scorer {
        Scorer {
            scores: MethodScores {
                method: method.to_string(),
                pitch: ErrorStats::default(),
                roll: ErrorStats::default(),
                pitch_pred_at_laser: ErrorStats::default(),
                pitch_in_dropout: vec![ErrorStats::default(); dropouts],
                return_step_excess_deg: vec![0.0; dropouts],
                steady_step_excess_deg: vec![0.0; dropouts],
            },
            prediction: None,
            pending_check: None,
            previous_pitch: None,
        }
    }
}

/// Where in the drive an instant falls, for scoring.
struct Windows {
    scored_from_t: f64,
    /// (start, end, recovery end) of each dropout.
    dropouts: Vec<(f64, f64, f64)>,
    /// Length of the recovery window (and of the steady window before).
    recovery_s: f64,
}

/// The constant-offset baseline: filtered inclinometer plus a frozen offset.
struct ConstantOffset {
    pitch: ScalarKalman,
    roll: ScalarKalman,
    last_t: Option<f64>,
    sums: (f64, f64, u32),
    calibrated_until_t: f64,
}

impl ConstantOffset {
    fn offsets(&self) -> (f64, f64) {
        let (p, r, n) = self.sums;
        if n == 0 {
            (0.0, 0.0)
        } else {
            (p / n as f64, r / n as f64)
        }
    }
}

fn attitude(output: &EngineOutput) -> Option<&AttitudeEstimate> {
    output.values.as_attitude()
}

/// Simulates the drive and scores every method.
pub fn evaluate(config: &AttitudeEvalConfig) -> Result<AttitudeEvaluation, EvalError> {
    let scenario = &config.scenario;
    if !(config.learning_h.is_finite()
        && config.learning_h >= 0.0
        && config.learning_h < scenario.hours)
    {
        return Err(EvalError::Scenario(format!(
            "learning period {} h must be ≥ 0 and shorter than the {} h drive",
            config.learning_h, scenario.hours
        )));
    }
    let drive = TbmDrive::new(scenario.clone()).map_err(EvalError::Scenario)?;
    let with_correction = |word: &str| {
        let correction = ("correction".to_string(), ParamValue::Text(word.into()));
        config
            .params
            .with_overrides(PARAMS, [correction])
            .and_then(AttitudeEngine::new)
    };
    let mut engines: Vec<AttitudeEngine> = vec![
        AttitudeEngine::new(config.params.clone())?,
        with_correction("offset")?,
        with_correction("none")?,
    ];
    let engine_config = AttitudeConfig::from_params(&config.params)?;
    let names = [
        ENGINE,
        ENGINE_OFFSET,
        ENGINE_NONE,
        LASER_HOLD,
        RAW_INCLINOMETER,
        CONSTANT_OFFSET,
    ];
    let mut scorers: Vec<Scorer> = names
        .iter()
        .map(|n| Scorer::new(n, scenario.dropouts.len()))
        .collect();
    let recovery_s = 2.0 * scenario.laser_period_s;
    let windows = Windows {
        scored_from_t: scenario.start_t + config.learning_h * 3600.0,
        dropouts: scenario
            .dropouts
            .iter()
            .map(|d| {
                let start = scenario.start_t + d.start_h * 3600.0;
                let end = start + d.minutes * 60.0;
                (start, end, end + recovery_s)
            })
            .collect(),
        recovery_s,
    };
    let mut offset = ConstantOffset {
        pitch: ScalarKalman::default(),
        roll: ScalarKalman::default(),
        last_t: None,
        sums: (0.0, 0.0, 0),
        calibrated_until_t: windows.scored_from_t,
    };
    let mut laser_hold: Option<(f64, f64)> = None;
    let mut outputs = Vec::new();
    let mut previous_truth_pitch: Option<f64> = None;

    for event in drive {
        let reading = &event.reading;
        let truth = event.truth;
        match reading.data {
            SensorData::Laser {
                pitch_deg,
                roll_deg,
                ..
            } => {
                for engine in &mut engines {
                    engine.feed(reading, &mut outputs);
                }
                laser_hold = Some((pitch_deg, roll_deg));
                if reading.t < offset.calibrated_until_t
                    && let Some(last_t) = offset.last_t
                    && reading.t - last_t <= 2.0 * scenario.incl_period_s
                {
                    let (p, r, n) = offset.sums;
                    offset.sums = (
                        p + pitch_deg - offset.pitch.x.to_degrees(),
                        r + roll_deg - offset.roll.x.to_degrees(),
                        n + 1,
                    );
                }
                if reading.t >= windows.scored_from_t {
                    for s in &mut scorers {
                        s.pending_check = s.prediction;
                    }
                }
            }
            SensorData::Inclinometer {
                pitch_deg,
                roll_deg,
                ..
            } => {
                outputs.clear();
                for engine in &mut engines {
                    engine.feed(reading, &mut outputs);
                }
                let dt_s = offset.last_t.map_or(0.0, |last| reading.t - last);
                offset.last_t = Some(reading.t);
                let noise = engine_config.noise;
                offset.pitch.step(
                    pitch_deg.to_radians(),
                    noise.q_pitch_per_s * dt_s,
                    noise.r_incl,
                );
                offset.roll.step(
                    roll_deg.to_radians(),
                    noise.q_roll_per_s * dt_s,
                    noise.r_incl,
                );
                let (dp, dr) = offset.offsets();
                let mut values: Vec<((f64, f64), f64)> = outputs
                    .iter()
                    .filter_map(attitude)
                    .map(|a| ((a.pitch_deg, a.roll_deg), a.pitch_pred_deg))
                    .collect();
                let hold = laser_hold.unwrap_or((pitch_deg, roll_deg));
                values.push((hold, hold.0));
                values.push(((pitch_deg, roll_deg), pitch_deg));
                let filtered = (
                    offset.pitch.x.to_degrees() + dp,
                    offset.roll.x.to_degrees() + dr,
                );
                values.push((filtered, filtered.0));
                for (scorer, (current, prediction)) in scorers.iter_mut().zip(values) {
                    score(
                        scorer,
                        current,
                        prediction,
                        &truth,
                        previous_truth_pitch,
                        &windows,
                    );
                }
                previous_truth_pitch = Some(truth.pitch_deg);
            }
            _ => {}
        }
    }
    Ok(AttitudeEvaluation {
        scenario: scenario.clone(),
        learning_h: config.learning_h,
        methods: scorers.into_iter().map(|s| s.scores).collect(),
    })
}

fn score(
    scorer: &mut Scorer,
    current: (f64, f64),
    prediction: f64,
    truth: &crate::sim::tbm::TbmTruth,
    previous_truth_pitch: Option<f64>,
    windows: &Windows,
) {
    let t = truth.t;
    if let Some(predicted) = scorer.pending_check.take() {
        scorer
            .scores
            .pitch_pred_at_laser
            .add(predicted - truth.pitch_deg);
    }
    if t >= windows.scored_from_t {
        scorer.scores.pitch.add(current.0 - truth.pitch_deg);
        scorer.scores.roll.add(current.1 - truth.roll_deg);
    }
    for (i, &(start, end, recovery_end)) in windows.dropouts.iter().enumerate() {
        if t >= start && t < recovery_end {
            scorer.scores.pitch_in_dropout[i].add(current.0 - truth.pitch_deg);
        }
        let Some((prev, prev_truth)) = scorer.previous_pitch.zip(previous_truth_pitch) else {
            continue;
        };
        let excess = (current.0 - prev).abs() - (truth.pitch_deg - prev_truth).abs();
        if t >= end && t < recovery_end {
            let slot = &mut scorer.scores.return_step_excess_deg[i];
            *slot = slot.max(excess);
        }
        if t >= start - windows.recovery_s && t < start {
            let slot = &mut scorer.scores.steady_step_excess_deg[i];
            *slot = slot.max(excess);
        }
    }
    scorer.prediction = Some(prediction);
    scorer.previous_pitch = Some(current.0);
}

/// Why an evaluation could not run.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error("invalid scenario: {0}")]
    Scenario(String),
    #[error(transparent)]
    Params(#[from] ParamError),
}

/// The evaluation as a table like the paper's, degrees throughout.
pub fn render_table(e: &AttitudeEvaluation) -> String {
    use std::fmt::Write;
    let s = &e.scenario;
    let mut out = String::new();
    let dropouts: Vec<String> = s
        .dropouts
        .iter()
        .map(|d| format!("{:.2} h for {:.0} min", d.start_h, d.minutes))
        .collect();
    let _ = writeln!(
        out,
        "attitude evaluation: seed {}, {:.1} h drive, inclinometer every {} s, laser every {} s, scored after {:.1} h of learning; dropouts: {}",
        s.seed,
        s.hours,
        s.incl_period_s,
        s.laser_period_s,
        e.learning_h,
        if dropouts.is_empty() {
            "none".to_string()
        } else {
            dropouts.join(", ")
        }
    );
    let mut header = format!(
        "{:<32} {:>11} {:>10} {:>10} {:>9} {:>14}",
        "method (errors in degrees)",
        "pitch RMSE",
        "pitch max",
        "roll RMSE",
        "roll max",
        "pred@laser RMS"
    );
    for i in 0..s.dropouts.len() {
        let _ = write!(header, " {:>13}", format!("dropout {} max", i + 1));
    }
    let _ = writeln!(out, "{header}");
    for m in &e.methods {
        let mut line = format!(
            "{:<32} {:>11.4} {:>10.4} {:>10.4} {:>9.4} {:>14.4}",
            m.method,
            m.pitch.rmse(),
            m.pitch.max_abs,
            m.roll.rmse(),
            m.roll.max_abs,
            m.pitch_pred_at_laser.rmse()
        );
        for d in &m.pitch_in_dropout {
            let _ = write!(line, " {:>13.4}", d.max_abs);
        }
        let _ = writeln!(out, "{line}");
    }
    out
}
