//! `eval attitude`: runs the `attitude` engine and its baselines over a
//! simulated TBM drive and scores each against the truth; over many drives
//! drawn from the envelope, it reports the median and the worst.
//!
//! Methods scored, all on the same readings:
//! - the engine as configured (ANFIS correction by default);
//! - the engine with `correction=offset` and with `correction=none`
//!   (ablations: what the error model adds);
//! - `kf3`, the textbook 3-state filter ([`super::kf3`]) on the raw
//!   inclinometer and the laser, given the simulator's true measurement
//!   noise;
//! - `oracle`: the same filter fed the inclinometer corrected by the
//!   simulator's *true* error (roll and temperature): what perfect learning
//!   of the error would reach on that drive;
//! - laser zero-order hold: the latest laser sample, as a driver reading the
//!   laser alone sees it;
//! - raw inclinometer;
//! - constant-offset inclinometer: the inclinometer through the `kf3`
//!   filter without the laser, plus the mean laser − inclinometer
//!   difference over the learning period, frozen after it (an installation
//!   calibration).
//!
//! Scores count only after the learning period. "pred" is each one-step
//! prediction (made at one inclinometer reading for the next) against the
//! truth at the next reading; "pred@laser" only those made just before a
//! laser sample. "In a dropout" is from the dropout's start until two laser
//! periods after it ends, to include the recovery. The step excess (how
//! much more an output moves between two readings than the truth does) is
//! taken over the two laser periods after the laser returns, and over the
//! two before the dropout as the ordinary reference.
//!
//! The engine's `integrity` is scored over the whole drive, learning
//! included ([`super::integrity`]): an estimate shown `ok` whose pitch or
//! roll error exceeds 5σ and 0.02° is misleading; the longest run of them
//! and the share of estimates flagged are printed against issue 54's bars.

use serde::Serialize;

use super::ErrorStats;
use super::integrity::{self, FaultSummary, IntegrityScore};
use super::kf3::{Kf3, Kf3Noise};
use crate::fusion::attitude::{AttitudeEngine, PARAMS};
use crate::fusion::{
    AttitudeEstimate, Engine, EngineOutput, ParamError, ParamValue, Params, SensorData,
};
use crate::sim::faults::{FaultInjector, FaultKind, FaultWindow};
use crate::sim::tbm::{Dropout, Phase, TbmDrive, TbmEvent, TbmScenario, TbmTruth};
use crate::sim::tbm_envelope::EnvelopeDrive;

/// A simulated drive to score on: the paper's fixed scenario or one drawn
/// from the envelope.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Drive {
    Fixed(TbmScenario),
    Envelope(Box<EnvelopeDrive>),
}

/// The fixed scenario's inclinometer noise (white and coloured together)
/// while excavating and standing, and its laser noise: see `sim::tbm`.
const FIXED_INCL_NOISE_DEG: (f64, f64) = (0.005_385_164_807_134_504, 0.001);
const FIXED_LASER_NOISE_DEG: f64 = 0.002;

impl Drive {
    /// The drive's seed.
    pub fn seed(&self) -> u64 {
        match self {
            Drive::Fixed(s) => s.seed,
            Drive::Envelope(d) => d.seed,
        }
    }

    fn start_t(&self) -> f64 {
        match self {
            Drive::Fixed(s) => s.start_t,
            Drive::Envelope(d) => d.start_t,
        }
    }

    fn hours(&self) -> f64 {
        match self {
            Drive::Fixed(s) => s.hours,
            Drive::Envelope(d) => d.hours,
        }
    }

    fn incl_period_s(&self) -> f64 {
        match self {
            Drive::Fixed(s) => s.incl_period_s,
            Drive::Envelope(d) => d.incl_period_s,
        }
    }

    fn laser_period_s(&self) -> f64 {
        match self {
            Drive::Fixed(s) => s.laser_period_s,
            Drive::Envelope(d) => d.laser_period_s,
        }
    }

    /// The laser dropouts, in drive order.
    pub fn dropouts(&self) -> &[Dropout] {
        match self {
            Drive::Fixed(s) => &s.dropouts,
            Drive::Envelope(d) => &d.dropouts,
        }
    }

    /// True per-reading inclinometer noise in `phase`, degrees.
    fn incl_noise_deg(&self, phase: Phase) -> f64 {
        match (self, phase) {
            (Drive::Fixed(_), Phase::Excavating) => FIXED_INCL_NOISE_DEG.0,
            (Drive::Fixed(_), Phase::RingBuilding) => FIXED_INCL_NOISE_DEG.1,
            (Drive::Envelope(d), phase) => d.incl_noise_deg(phase),
        }
    }

    fn laser_noise_deg(&self) -> f64 {
        match self {
            Drive::Fixed(_) => FIXED_LASER_NOISE_DEG,
            Drive::Envelope(d) => d.laser_noise_deg,
        }
    }

    fn events(&self) -> Result<Box<dyn Iterator<Item = TbmEvent>>, EvalError> {
        Ok(match self {
            Drive::Fixed(s) => Box::new(TbmDrive::new(s.clone()).map_err(EvalError::Scenario)?),
            Drive::Envelope(d) => Box::new(d.events()),
        })
    }

    /// True for an envelope drive in the easy corner (noise ≤
    /// 0.03°, inclinometer period ≤ 5 s, laser period ≤ 120 s).
    pub fn is_easy(&self) -> bool {
        match self {
            Drive::Fixed(_) => false,
            Drive::Envelope(d) => d.is_easy(),
        }
    }
}

/// Process noise of the `kf3` baseline: the pair with the lowest median
/// pitch RMSE over envelope drives 1–40 on a grid of 10^k (k integer)
/// for each (`eval attitude --envelope --seeds 40 --kf3-noise Q_RATE:Q_BIAS`).
pub const KF3_NOISE: Kf3Noise = Kf3Noise {
    q_rate: 1e-10,
    q_bias: 1e-5,
};
/// Process noise of the `oracle`, chosen the same way for it.
pub const ORACLE_NOISE: Kf3Noise = Kf3Noise {
    q_rate: 1e-11,
    q_bias: 1e-10,
};

/// What to evaluate.
#[derive(Debug, Clone)]
pub struct AttitudeEvalConfig {
    pub drive: Drive,
    /// Hours at the start that are not scored.
    pub learning_h: f64,
    /// Parameters of the engine under test (its ablations change `correction`).
    pub params: Params,
    /// Process noise of the `kf3` baseline and of the `oracle`.
    pub kf3_noise: Kf3Noise,
    pub oracle_noise: Kf3Noise,
    /// A fault injected into the drive's readings (all methods see it).
    pub fault: Option<FaultKind>,
}

impl AttitudeEvalConfig {
    /// The fixed-scenario drive with the engine's default parameters.
    pub fn new(scenario: TbmScenario) -> AttitudeEvalConfig {
        AttitudeEvalConfig::on(Drive::Fixed(scenario))
    }

    /// `drive` with the engine's default parameters.
    pub fn on(drive: Drive) -> AttitudeEvalConfig {
        AttitudeEvalConfig {
            drive,
            learning_h: 1.0,
            params: Params::defaults(PARAMS),
            kf3_noise: KF3_NOISE,
            oracle_noise: ORACLE_NOISE,
            fault: None,
        }
    }
}

/// The scores of one method.
#[derive(Debug, Clone, Serialize)]
pub struct MethodScores {
    pub method: String,
    pub pitch: ErrorStats,
    pub roll: ErrorStats,
    /// One-step prediction error of pitch, every reading.
    pub pitch_pred: ErrorStats,
    /// One-step prediction error of pitch at laser instants.
    pub pitch_pred_at_laser: ErrorStats,
    /// Pitch error through each dropout, in drive order.
    pub pitch_in_dropout: Vec<ErrorStats>,
    /// Largest step between consecutive pitch outputs beyond the true step,
    /// within two laser periods after each dropout ends.
    pub return_step_excess_deg: Vec<f64>,
    /// The same over the two laser periods before each dropout starts: the
    /// ordinary step noise the return is compared with.
    pub steady_step_excess_deg: Vec<f64>,
    /// How often |error| ≤ 2σ, for a method whose estimates carry a σ.
    pub sigma: Option<SigmaCoverage>,
}

/// Estimates within two of their σ of the truth, and all estimates scored.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Coverage {
    pub within_two_sigma: u64,
    pub scored: u64,
}

impl Coverage {
    /// Counts one estimate with `error` and 1σ `sigma` (same unit).
    pub fn add(&mut self, error: f64, sigma: f64) {
        self.scored += 1;
        if error.abs() <= 2.0 * sigma {
            self.within_two_sigma += 1;
        }
    }

    /// The share within 2σ (NaN before any estimate).
    pub fn share(&self) -> f64 {
        self.within_two_sigma as f64 / self.scored as f64
    }

    fn merged(self, other: Coverage) -> Coverage {
        Coverage {
            within_two_sigma: self.within_two_sigma + other.within_two_sigma,
            scored: self.scored + other.scored,
        }
    }
}

/// 2σ coverage of pitch, roll and the pitch prediction (scored like their
/// RMSE) and of pitch inside the dropouts and their recovery windows.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct SigmaCoverage {
    pub pitch: Coverage,
    pub roll: Coverage,
    pub pitch_pred: Coverage,
    pub pitch_in_dropout: Coverage,
}

impl MethodScores {
    /// Largest pitch error in any dropout (0 without dropouts).
    pub fn dropout_max(&self) -> f64 {
        self.pitch_in_dropout
            .iter()
            .map(|d| d.max_abs)
            .fold(0.0, f64::max)
    }
}

/// The scores of every method on one drive.
#[derive(Debug, Clone, Serialize)]
pub struct AttitudeEvaluation {
    pub drive: Drive,
    pub learning_h: f64,
    pub methods: Vec<MethodScores>,
    /// The engine's integrity against its errors, the whole drive.
    pub integrity: IntegrityScore,
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

    /// The simple baselines (not the engine, its ablations, `kf3` or the oracle).
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
pub const KF3: &str = "kf3 (textbook 3-state filter)";
pub const ORACLE: &str = "oracle (kf3, true error removed)";
pub const LASER_HOLD: &str = "laser zero-order hold";
pub const RAW_INCLINOMETER: &str = "raw inclinometer";
pub const CONSTANT_OFFSET: &str = "constant-offset inclinometer";
const BASELINES: [&str; 3] = [LASER_HOLD, RAW_INCLINOMETER, CONSTANT_OFFSET];
const METHODS: [&str; 8] = [
    ENGINE,
    ENGINE_OFFSET,
    ENGINE_NONE,
    KF3,
    ORACLE,
    LASER_HOLD,
    RAW_INCLINOMETER,
    CONSTANT_OFFSET,
];

/// One method's running output and score.
struct Scorer {
    scores: MethodScores,
    /// The pitch the latest output predicts for the next reading, and its σ.
    prediction: Option<(f64, Option<f64>)>,
    /// Set when a laser sample arrived since the latest output.
    laser_since: bool,
    previous_pitch: Option<f64>,
}

impl Scorer {
    fn new(method: &str, dropouts: usize) -> Scorer {
        Scorer {
            scores: MethodScores {
                method: method.to_string(),
                pitch: ErrorStats::default(),
                roll: ErrorStats::default(),
                pitch_pred: ErrorStats::default(),
                pitch_pred_at_laser: ErrorStats::default(),
                pitch_in_dropout: vec![ErrorStats::default(); dropouts],
                return_step_excess_deg: vec![0.0; dropouts],
                steady_step_excess_deg: vec![0.0; dropouts],
                sigma: None,
            },
            prediction: None,
            laser_since: false,
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

/// A pair of `kf3` filters (pitch and roll) and the time of their last reading.
struct Kf3Pair {
    pitch: Kf3,
    roll: Kf3,
    last_t: Option<f64>,
    period_s: f64,
}

/// The roll filters' process noise: roll moves up to 0.5 °/min and the
/// inclinometer's roll offset is a constant.
const KF3_ROLL_NOISE: Kf3Noise = Kf3Noise {
    q_rate: 1e-7,
    q_bias: 1e-12,
};

impl Kf3Pair {
    fn new(noise: Kf3Noise) -> Kf3Pair {
        Kf3Pair {
            pitch: Kf3::new(noise),
            roll: Kf3::new(KF3_ROLL_NOISE),
            last_t: None,
            period_s: 0.0,
        }
    }

    fn inclinometer(&mut self, t: f64, pitch: f64, roll: f64, r: f64) -> ((f64, f64), f64) {
        if let Some(last) = self.last_t {
            self.period_s = t - last;
        }
        self.last_t = Some(t);
        self.pitch.inclinometer(t, pitch, r);
        self.roll.inclinometer(t, roll, r);
        (
            (self.pitch.angle(), self.roll.angle()),
            self.pitch.predict_angle(self.period_s),
        )
    }

    fn laser(&mut self, t: f64, pitch: f64, roll: f64, r: f64) {
        self.pitch.laser(t, pitch, r);
        self.roll.laser(t, roll, r);
    }
}

fn attitude(output: &EngineOutput) -> Option<&AttitudeEstimate> {
    output.values.as_attitude()
}

/// Simulates the drive and scores every method.
pub fn evaluate(config: &AttitudeEvalConfig) -> Result<AttitudeEvaluation, EvalError> {
    let drive = &config.drive;
    if !(config.learning_h.is_finite()
        && config.learning_h >= 0.0
        && config.learning_h < drive.hours())
    {
        return Err(EvalError::Scenario(format!(
            "learning period {} h must be ≥ 0 and shorter than the {} h drive",
            config.learning_h,
            drive.hours()
        )));
    }
    let events = drive.events()?;
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
    let mut scorers: Vec<Scorer> = METHODS
        .iter()
        .map(|n| Scorer::new(n, drive.dropouts().len()))
        .collect();
    let recovery_s = 2.0 * drive.laser_period_s();
    let start_t = drive.start_t();
    let windows = Windows {
        scored_from_t: start_t + config.learning_h * 3600.0,
        dropouts: drive
            .dropouts()
            .iter()
            .map(|d| {
                let start = start_t + d.start_h * 3600.0;
                let end = start + d.minutes * 60.0;
                (start, end, end + recovery_s)
            })
            .collect(),
        recovery_s,
    };
    let mut kf3 = Kf3Pair::new(config.kf3_noise);
    let mut oracle = Kf3Pair::new(config.oracle_noise);
    // The constant-offset baseline: kf3 without the laser, plus offsets
    // (sum of laser − filtered inclinometer, count) frozen after learning.
    let mut inclinometer_only = Kf3Pair::new(config.kf3_noise);
    let mut offset_sums = (0.0, 0.0, 0u32);
    let r_laser = drive.laser_noise_deg().powi(2);
    let mut laser_hold: Option<(f64, f64)> = None;
    let mut outputs = Vec::new();
    let mut previous_truth_pitch: Option<f64> = None;
    let window = config
        .fault
        .map(|kind| FaultWindow::in_drive(kind, start_t, drive.hours() * 3600.0));
    let mut injector = window
        .map(|w| FaultInjector::new(w, crate::fusion::EngineKind::Attitude))
        .transpose()
        .map_err(|e| EvalError::Scenario(e.to_string()))?;
    let mut integrity = IntegrityScore::with_fault(window);

    for mut event in events {
        if let Some(injector) = &mut injector {
            event.reading = injector.apply(event.reading);
        }
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
                kf3.laser(reading.t, pitch_deg, roll_deg, r_laser);
                oracle.laser(reading.t, pitch_deg, roll_deg, r_laser);
                laser_hold = Some((pitch_deg, roll_deg));
                if reading.t < windows.scored_from_t
                    && let Some(last_t) = inclinometer_only.last_t
                    && reading.t - last_t <= 2.0 * drive.incl_period_s()
                {
                    let (p, r, n) = offset_sums;
                    offset_sums = (
                        p + pitch_deg - inclinometer_only.pitch.angle(),
                        r + roll_deg - inclinometer_only.roll.angle(),
                        n + 1,
                    );
                }
                for s in &mut scorers {
                    s.laser_since = true;
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
                let r_incl = drive.incl_noise_deg(truth.phase).powi(2);
                let t = reading.t;
                let mut values: Vec<((f64, f64), f64)> = Vec::new();
                let mut sigmas: Vec<Option<Sigmas>> = Vec::new();
                for a in outputs.iter().filter_map(attitude) {
                    values.push(((a.pitch_deg, a.roll_deg), a.pitch_pred_deg));
                    sigmas.push(
                        match (a.pitch_sigma_deg, a.roll_sigma_deg, a.pitch_pred_sigma_deg) {
                            (Some(pitch), Some(roll), Some(pred)) => {
                                Some(Sigmas { pitch, roll, pred })
                            }
                            _ => None,
                        },
                    );
                }
                values.push(kf3.inclinometer(t, pitch_deg, roll_deg, r_incl));
                let ((oracle_pitch, _), oracle_pred) = oracle.inclinometer(
                    t,
                    pitch_deg + truth.incl_pitch_error_deg,
                    roll_deg,
                    r_incl,
                );
                // Oracle roll: the kf3 roll (its offset is learned alike).
                let kf3_roll = kf3.roll.angle();
                values.push(((oracle_pitch, kf3_roll), oracle_pred));
                if let Some(output) = outputs.first()
                    && let Some(a) = attitude(output)
                {
                    let misleading = integrity::misleading(
                        a.pitch_deg - truth.pitch_deg,
                        a.pitch_sigma_deg,
                        TILT_FLOOR_DEG,
                    ) || integrity::misleading(
                        a.roll_deg - truth.roll_deg,
                        a.roll_sigma_deg,
                        TILT_FLOOR_DEG,
                    );
                    integrity.add(t, output.integrity, misleading);
                }
                let hold = laser_hold.unwrap_or((pitch_deg, roll_deg));
                values.push((hold, hold.0));
                values.push(((pitch_deg, roll_deg), pitch_deg));
                let ((p, r), pred) = inclinometer_only.inclinometer(t, pitch_deg, roll_deg, r_incl);
                let (dp, dr) = match offset_sums {
                    (_, _, 0) => (0.0, 0.0),
                    (sp, sr, n) => (sp / n as f64, sr / n as f64),
                };
                values.push(((p + dp, r + dr), pred + dp));
                for (i, (scorer, (current, prediction))) in
                    scorers.iter_mut().zip(values).enumerate()
                {
                    score(
                        scorer,
                        Output {
                            current,
                            prediction,
                            sigmas: sigmas.get(i).copied().flatten(),
                        },
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
        drive: drive.clone(),
        learning_h: config.learning_h,
        methods: scorers.into_iter().map(|s| s.scores).collect(),
        integrity,
    })
}

/// A pitch or roll error below this is never misleading (issue 54), degrees.
const TILT_FLOOR_DEG: f64 = 0.02;

/// The 1σ of one engine output, degrees.
#[derive(Debug, Clone, Copy)]
struct Sigmas {
    pitch: f64,
    roll: f64,
    pred: f64,
}

/// One method's output at an inclinometer reading.
struct Output {
    current: (f64, f64),
    prediction: f64,
    sigmas: Option<Sigmas>,
}

fn score(
    scorer: &mut Scorer,
    output: Output,
    truth: &TbmTruth,
    previous_truth_pitch: Option<f64>,
    windows: &Windows,
) {
    let Output {
        current,
        prediction,
        sigmas,
    } = output;
    let t = truth.t;
    let pitch_error = current.0 - truth.pitch_deg;
    if t >= windows.scored_from_t {
        if let Some((predicted, predicted_sigma)) = scorer.prediction {
            let error = predicted - truth.pitch_deg;
            scorer.scores.pitch_pred.add(error);
            if scorer.laser_since {
                scorer.scores.pitch_pred_at_laser.add(error);
            }
            if let Some(sigma) = predicted_sigma {
                let coverage = scorer.scores.sigma.get_or_insert_default();
                coverage.pitch_pred.add(error, sigma);
            }
        }
        scorer.scores.pitch.add(pitch_error);
        scorer.scores.roll.add(current.1 - truth.roll_deg);
        if let Some(s) = sigmas {
            let coverage = scorer.scores.sigma.get_or_insert_default();
            coverage.pitch.add(pitch_error, s.pitch);
            coverage.roll.add(current.1 - truth.roll_deg, s.roll);
        }
    }
    scorer.laser_since = false;
    for (i, &(start, end, recovery_end)) in windows.dropouts.iter().enumerate() {
        if t >= start && t < recovery_end {
            scorer.scores.pitch_in_dropout[i].add(pitch_error);
            if let Some(s) = sigmas {
                let coverage = scorer.scores.sigma.get_or_insert_default();
                coverage.pitch_in_dropout.add(pitch_error, s.pitch);
            }
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
    scorer.prediction = Some((prediction, sigmas.map(|s| s.pred)));
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
    let d = &e.drive;
    let mut out = String::new();
    let dropouts: Vec<String> = d
        .dropouts()
        .iter()
        .map(|x| format!("{:.2} h for {:.0} min", x.start_h, x.minutes))
        .collect();
    let kind = match d {
        Drive::Fixed(_) => "seed",
        Drive::Envelope(_) => "envelope seed",
    };
    let _ = writeln!(
        out,
        "attitude evaluation: {kind} {}, {:.1} h drive, inclinometer every {:.3} s, laser every {:.1} s, scored after {:.1} h of learning; dropouts: {}",
        d.seed(),
        d.hours(),
        d.incl_period_s(),
        d.laser_period_s(),
        e.learning_h,
        if dropouts.is_empty() {
            "none".to_string()
        } else {
            dropouts.join(", ")
        }
    );
    let mut header = format!(
        "{:<34} {:>10} {:>9} {:>9} {:>8} {:>9} {:>10}",
        "method (errors in degrees)",
        "pitch RMSE",
        "pitch max",
        "roll RMSE",
        "roll max",
        "pred RMSE",
        "pred@laser"
    );
    for i in 0..d.dropouts().len() {
        let _ = write!(header, " {:>13}", format!("dropout {} max", i + 1));
    }
    let _ = writeln!(out, "{header}");
    for m in &e.methods {
        let mut line = format!(
            "{:<34} {:>10.4} {:>9.4} {:>9.4} {:>8.4} {:>9.4} {:>10.4}",
            m.method,
            m.pitch.rmse(),
            m.pitch.max_abs,
            m.roll.rmse(),
            m.roll.max_abs,
            m.pitch_pred.rmse(),
            m.pitch_pred_at_laser.rmse()
        );
        for x in &m.pitch_in_dropout {
            let _ = write!(line, " {:>13.4}", x.max_abs);
        }
        let _ = writeln!(out, "{line}");
    }
    let i = &e.integrity;
    let _ = writeln!(
        out,
        "engine integrity (whole drive): {:.2} % flagged ({} degraded, {} lost of {}); longest misleading ok run {:.1} s{}",
        100.0 * i.flagged_share(),
        i.degraded,
        i.lost,
        i.estimates,
        i.worst_run_s,
        i.worst_run_from_t
            .map(|t| format!(" from t = {t:.0}"))
            .unwrap_or_default()
    );
    out
}

/// Evaluates `configs` on up to `threads` threads; results in input order.
pub fn evaluate_all(
    configs: &[AttitudeEvalConfig],
    threads: usize,
) -> Result<Vec<AttitudeEvaluation>, EvalError> {
    super::parallel_map(configs, threads, evaluate)
        .into_iter()
        .collect()
}

/// Median and worst of one metric over drives.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Spread {
    pub median: f64,
    pub worst: f64,
}

impl Spread {
    /// Median and largest of `values` (both 0 when empty).
    pub fn of(values: &[f64]) -> Spread {
        Spread::with_worst(values, f64::max)
    }

    /// Median and the smallest of `values`: for ratios where small is bad.
    pub fn of_lowest(values: &[f64]) -> Spread {
        Spread::with_worst(values, f64::min)
    }

    fn with_worst(values: &[f64], pick: fn(f64, f64) -> f64) -> Spread {
        if values.is_empty() {
            return Spread {
                median: 0.0,
                worst: 0.0,
            };
        }
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        let n = sorted.len();
        let median = if n % 2 == 1 {
            sorted[n / 2]
        } else {
            0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
        };
        let worst = sorted[1..].iter().fold(sorted[0], |a, &b| pick(a, b));
        Spread { median, worst }
    }
}

/// One method's metrics over the drives.
#[derive(Debug, Clone, Serialize)]
pub struct MethodSpread {
    pub method: String,
    pub pitch_rmse_deg: Spread,
    pub pitch_max_deg: Spread,
    pub roll_rmse_deg: Spread,
    pub pred_rmse_deg: Spread,
    pub dropout_max_deg: Spread,
}

/// The engine against the yardsticks over the drives, with the bars.
#[derive(Debug, Clone, Serialize)]
pub struct EnvelopeSummary {
    pub drives: usize,
    /// With a fault injected: how the engine met it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fault: Option<FaultSummary>,
    pub methods: Vec<MethodSpread>,
    /// Engine ÷ oracle pitch RMSE per drive (bar: median ≤ 1.5, worst ≤ 3).
    pub rmse_over_oracle: Spread,
    /// Engine ÷ oracle largest dropout error (bar: median ≤ 2).
    pub dropout_over_oracle: Spread,
    /// kf3 ÷ engine pitch RMSE (bar: median ≥ 1.5, never below 1).
    pub kf3_over_engine: Spread,
    /// Drives where the engine's pitch RMSE is above kf3's.
    pub worse_than_kf3: Vec<u64>,
    /// The easy drives: their number and the engine's worst figures.
    pub easy_drives: usize,
    pub easy_pitch_rmse_worst_deg: f64,
    pub easy_dropout_max_worst_deg: f64,
    pub easy_pred_rmse_worst_deg: f64,
    /// The engine's 2σ coverage pooled over every drive.
    pub engine_sigma: SigmaCoverage,
    /// The engine's longest misleading `ok` run per drive, s, and its
    /// share of estimates flagged.
    pub misleading_run_s: Spread,
    pub flagged_share: Spread,
    /// Drives whose longest misleading run is over the bar: "seed (s)".
    pub misleading_drives: Vec<String>,
}

/// The 2σ coverage bar of issue 35: 90–99 % of the errors.
const COVERAGE_BAR: (f64, f64) = (0.90, 0.99);

impl EnvelopeSummary {
    /// The bars of issues 16 and 35 that fail, each as a sentence (empty:
    /// all met).
    pub fn failures(&self) -> Vec<String> {
        let mut out = Vec::new();
        let r = self.rmse_over_oracle;
        if r.median > 1.5 || r.worst > 3.0 {
            out.push(format!(
                "pitch RMSE over the oracle's: median {:.2} (bar 1.5), worst {:.2} (bar 3)",
                r.median, r.worst
            ));
        }
        if self.dropout_over_oracle.median > 2.0 {
            out.push(format!(
                "dropout max over the oracle's: median {:.2} (bar 2)",
                self.dropout_over_oracle.median
            ));
        }
        if self.kf3_over_engine.median < 1.5 {
            out.push(format!(
                "kf3 over engine pitch RMSE: median {:.2} (bar 1.5)",
                self.kf3_over_engine.median
            ));
        }
        if !self.worse_than_kf3.is_empty() {
            out.push(format!(
                "worse than kf3 on drives {:?}",
                self.worse_than_kf3
            ));
        }
        if self.easy_pitch_rmse_worst_deg > 0.010 {
            out.push(format!(
                "easy drives: pitch RMSE {:.4}° (bar 0.010°)",
                self.easy_pitch_rmse_worst_deg
            ));
        }
        if self.easy_dropout_max_worst_deg > 0.03 {
            out.push(format!(
                "easy drives: dropout max {:.4}° (bar 0.03°)",
                self.easy_dropout_max_worst_deg
            ));
        }
        if self.easy_pred_rmse_worst_deg > 0.012 {
            out.push(format!(
                "easy drives: prediction RMSE {:.4}° (bar 0.012°)",
                self.easy_pred_rmse_worst_deg
            ));
        }
        let c = &self.engine_sigma;
        for (name, coverage) in [
            ("pitch", c.pitch),
            ("roll", c.roll),
            ("pitch prediction", c.pitch_pred),
            ("pitch in dropouts", c.pitch_in_dropout),
        ] {
            let share = coverage.share();
            if !(COVERAGE_BAR.0..=COVERAGE_BAR.1).contains(&share) {
                out.push(format!(
                    "2σ covers {:.1} % of the {name} errors (bar 90–99 %)",
                    100.0 * share
                ));
            }
        }
        if !self.misleading_drives.is_empty() {
            out.push(format!(
                "integrity: misleading ok runs over {:.0} s on {} drive(s): {}",
                integrity::MAX_MISLEADING_RUN_S,
                self.misleading_drives.len(),
                self.misleading_drives.join(", ")
            ));
        }
        if let Some(fault) = &self.fault
            && fault.recovered < fault.drives
        {
            out.push(format!(
                "fault {}: recovered on {} of {} drives",
                fault.fault.as_str(),
                fault.recovered,
                fault.drives
            ));
        }
        // A fault drive is not an ordinary one: its share flagged is a
        // figure of the fault.
        if self.fault.is_none() && self.flagged_share.worst > integrity::MAX_FLAGGED_SHARE {
            out.push(format!(
                "integrity: up to {:.1} % of a drive's estimates flagged (bar {:.0} %)",
                100.0 * self.flagged_share.worst,
                100.0 * integrity::MAX_FLAGGED_SHARE
            ));
        }
        out
    }
}

/// Summarises evaluations of the same methods over several drives.
pub fn summarise(evaluations: &[AttitudeEvaluation]) -> EnvelopeSummary {
    let per = |name: &str, metric: fn(&MethodScores) -> f64| -> Vec<f64> {
        evaluations
            .iter()
            .filter_map(|e| e.method(name).map(metric))
            .collect()
    };
    let methods = METHODS
        .iter()
        .map(|&name| MethodSpread {
            method: name.to_string(),
            pitch_rmse_deg: Spread::of(&per(name, |m| m.pitch.rmse())),
            pitch_max_deg: Spread::of(&per(name, |m| m.pitch.max_abs)),
            roll_rmse_deg: Spread::of(&per(name, |m| m.roll.rmse())),
            pred_rmse_deg: Spread::of(&per(name, |m| m.pitch_pred.rmse())),
            dropout_max_deg: Spread::of(&per(name, MethodScores::dropout_max)),
        })
        .collect();
    let ratio = |a: &str, b: &str, metric: fn(&MethodScores) -> f64| -> Vec<f64> {
        evaluations
            .iter()
            .filter_map(|e| {
                let (x, y) = (e.method(a)?, e.method(b)?);
                Some(metric(x) / metric(y).max(1e-12))
            })
            .collect()
    };
    let rmse = |m: &MethodScores| m.pitch.rmse();
    let easy: Vec<&AttitudeEvaluation> = evaluations.iter().filter(|e| e.drive.is_easy()).collect();
    let easy_worst = |metric: fn(&MethodScores) -> f64| {
        easy.iter().map(|e| metric(e.engine())).fold(0.0, f64::max)
    };
    let runs: Vec<f64> = evaluations
        .iter()
        .map(|e| e.integrity.worst_run_s)
        .collect();
    let flagged: Vec<f64> = evaluations
        .iter()
        .map(|e| e.integrity.flagged_share())
        .collect();
    EnvelopeSummary {
        fault: FaultSummary::of(evaluations.iter().map(|e| &e.integrity)),
        misleading_run_s: Spread::of(&runs),
        flagged_share: Spread::of(&flagged),
        misleading_drives: evaluations
            .iter()
            .filter(|e| !e.integrity.run_bar_met())
            .map(|e| format!("{} ({:.0} s)", e.drive.seed(), e.integrity.worst_run_s))
            .collect(),
        drives: evaluations.len(),
        methods,
        rmse_over_oracle: Spread::of(&ratio(ENGINE, ORACLE, rmse)),
        dropout_over_oracle: Spread::of(&ratio(ENGINE, ORACLE, MethodScores::dropout_max)),
        kf3_over_engine: Spread::of_lowest(&ratio(KF3, ENGINE, rmse)),
        worse_than_kf3: evaluations
            .iter()
            .filter(|e| e.method(KF3).is_some_and(|k| rmse(e.engine()) > rmse(k)))
            .map(|e| e.drive.seed())
            .collect(),
        easy_drives: easy.len(),
        easy_pitch_rmse_worst_deg: easy_worst(rmse),
        easy_dropout_max_worst_deg: easy_worst(MethodScores::dropout_max),
        easy_pred_rmse_worst_deg: easy_worst(|m| m.pitch_pred.rmse()),
        engine_sigma: evaluations.iter().filter_map(|e| e.engine().sigma).fold(
            SigmaCoverage::default(),
            |a, b| SigmaCoverage {
                pitch: a.pitch.merged(b.pitch),
                roll: a.roll.merged(b.roll),
                pitch_pred: a.pitch_pred.merged(b.pitch_pred),
                pitch_in_dropout: a.pitch_in_dropout.merged(b.pitch_in_dropout),
            },
        ),
    }
}

/// The summary as a table: median / worst per metric and method, then the
/// ratios the bars are set on.
pub fn render_summary(s: &EnvelopeSummary, first_seed: u64) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "attitude over the envelope: {} drives (envelope seeds {}–{}), scored after 1 h; degrees, median / worst",
        s.drives,
        first_seed,
        first_seed + s.drives as u64 - 1
    );
    let _ = writeln!(
        out,
        "{:<34} {:>15} {:>15} {:>15} {:>15} {:>15}",
        "method", "pitch RMSE", "pitch max", "roll RMSE", "pred RMSE", "dropout max"
    );
    let cell = |x: Spread| format!("{:.4} / {:.4}", x.median, x.worst);
    for m in &s.methods {
        let _ = writeln!(
            out,
            "{:<34} {:>15} {:>15} {:>15} {:>15} {:>15}",
            m.method,
            cell(m.pitch_rmse_deg),
            cell(m.pitch_max_deg),
            cell(m.roll_rmse_deg),
            cell(m.pred_rmse_deg),
            cell(m.dropout_max_deg)
        );
    }
    let _ = writeln!(
        out,
        "engine ÷ oracle, pitch RMSE: median {:.2}, worst {:.2} (bars 1.5, 3); dropout max: median {:.2}, worst {:.2} (bar: median 2)",
        s.rmse_over_oracle.median,
        s.rmse_over_oracle.worst,
        s.dropout_over_oracle.median,
        s.dropout_over_oracle.worst
    );
    let _ = writeln!(
        out,
        "kf3 ÷ engine, pitch RMSE: median {:.2}, lowest {:.2} (bars 1.5, 1); engine worse than kf3 on {} drive(s){}",
        s.kf3_over_engine.median,
        s.kf3_over_engine.worst,
        s.worse_than_kf3.len(),
        if s.worse_than_kf3.is_empty() {
            String::new()
        } else {
            format!(": seeds {:?}", s.worse_than_kf3)
        }
    );
    let _ = writeln!(
        out,
        "easy drives (noise ≤ 0.03°, inclinometer ≤ 5 s, laser ≤ 120 s): {}; worst pitch RMSE {:.4} (bar 0.010), dropout max {:.4} (bar 0.03), pred RMSE {:.4} (bar 0.012)",
        s.easy_drives,
        s.easy_pitch_rmse_worst_deg,
        s.easy_dropout_max_worst_deg,
        s.easy_pred_rmse_worst_deg
    );
    let c = &s.engine_sigma;
    let _ = writeln!(
        out,
        "engine 2σ coverage (bar 90–99 %): pitch {:.1} %, roll {:.1} %, pitch prediction {:.1} %, pitch in dropouts {:.1} % ({} estimates in dropouts)",
        100.0 * c.pitch.share(),
        100.0 * c.roll.share(),
        100.0 * c.pitch_pred.share(),
        100.0 * c.pitch_in_dropout.share(),
        c.pitch_in_dropout.scored
    );
    let _ = writeln!(
        out,
        "engine integrity (whole drive; misleading: ok with error > 5σ and 0.02°): longest misleading ok run median {:.1} s, largest {:.1} s (bar {:.0} s); flagged median {:.2} %, largest {:.2} %",
        s.misleading_run_s.median,
        s.misleading_run_s.worst,
        integrity::MAX_MISLEADING_RUN_S,
        100.0 * s.flagged_share.median,
        100.0 * s.flagged_share.worst
    );
    if let Some(fault) = &s.fault {
        out.push_str(&fault.render());
    }
    let failures = s.failures();
    if failures.is_empty() {
        let _ = writeln!(out, "every bar met");
    } else {
        for f in failures {
            let _ = writeln!(out, "bar not met: {f}");
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spreads_by_hand() {
        let s = Spread::of(&[3.0, 1.0, 2.0, 10.0]);
        assert_eq!((s.median, s.worst), (2.5, 10.0));
        let s = Spread::of_lowest(&[3.0, 1.0, 2.0]);
        assert_eq!((s.median, s.worst), (2.0, 1.0));
    }
}
