//! `eval fuzzy`: the `fuzzy` engine against simulated truth and against
//! the single-sensor solutions it fuses.
//!
//! Scores:
//! - motion status: the share of IMU readings (from alignment on) whose
//!   `motion` matches the truth (rolling or turning = moving);
//! - pitch and roll RMSE from alignment on; heading RMSE from the first
//!   magnetometer calibration on;
//! - drift: the same RMSEs over the first and the last 5 minutes after
//!   the first planar or full calibration (not a partial arc's, issue 55:
//!   the windows are those the drift test was written with);
//! - baselines, each over the same readings:
//!   - gyro only: the gyros integrated (quaternions) from the true initial
//!     attitude, their bias taken as the mean of the first 10 s (parked);
//!   - accelerometer only: tilt from each reading's specific force;
//!   - raw compass: heading from the uncalibrated magnetometer,
//!     tilt-compensated with the accelerometer tilt, plus declination;
//! - standard AHRS baselines ([`super::ahrs`]), started from the first
//!   still reading ([`initial_attitude`]), updated at every IMU reading
//!   with the newest raw (uncalibrated) magnetometer reading held between
//!   readings, heading plus declination, scored over the same readings as
//!   the engine:
//!   - tuned Madgwick (MARG): run for each β of [`MADGWICK_BETAS`] and
//!     reported with the β of the smallest pitch + roll + heading RMSE on
//!     this drive. That choice is made with the truth, which no filter in
//!     the field has: an optimistic yardstick;
//!   - Mahony: fixed gains [`MAHONY_KP`], [`MAHONY_KI`];
//!   - VQF ([`super::ahrs::Vqf`], issue 55) with its defaults, its
//!     filters set for the IMU's rate, the held magnetometer reading fed
//!     at every IMU reading (a sample-and-hold magnetometer).
//!
//! An engine that never aligns (or never calibrates) has an infinite RMSE
//! for the angles it never estimated (`never` in the table, null in JSON),
//! and the baselines are then scored from 10 s (tilt) and 150 s (heading).
//!
//! Over several seeds, [`summarise`] gives the median and worst of each
//! metric per method and the median of baseline ÷ engine per angle.

use serde::Serialize;

use super::ErrorStats;
use super::ahrs::{Madgwick, Mahony, Vqf, initial_attitude};
use super::attitude::Spread;
use crate::fusion::angles::{deg, rad};
use crate::fusion::fuzzy::magcal::CalibrationState;
use crate::fusion::fuzzy::orientation::{
    angle_difference, integrate, magnetic_heading, tilt_from_accel,
};
use crate::fusion::fuzzy::{FuzzyEngine, PARAMS};
use crate::fusion::geometry::{V3, attitude_from_euler};
use crate::fusion::{
    Engine, EngineOutput, FuzzyEstimate, Motion, ParamError, ParamValue, Params, SensorData,
};
use crate::sim::vehicle::{VehicleDrive, VehicleScenario, VehicleTruth};

/// Seconds of parked readings the gyro-only baseline takes its bias from.
const BASELINE_BIAS_S: f64 = 10.0;
/// Length of the drift windows.
const DRIFT_WINDOW_S: f64 = 300.0;
/// When the engine never calibrates, the baselines are scored from these
/// times instead (tilt, heading; the calibration turn ends by 118 s).
const FALLBACK_TILT_S: f64 = BASELINE_BIAS_S;
const FALLBACK_HEADING_S: f64 = 150.0;
/// The Madgwick gains (rad/s) tried on each drive; the best is reported.
pub const MADGWICK_BETAS: [f64; 7] = [0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5];
/// The Mahony baseline's proportional (rad/s) and integral (rad/s²) gains.
pub const MAHONY_KP: f64 = 0.5;
pub const MAHONY_KI: f64 = 0.05;

/// What to evaluate.
#[derive(Debug, Clone)]
pub struct FuzzyEvalConfig {
    pub scenario: VehicleScenario,
    /// Parameters of the engine; `declination_deg` and `mag_inclination_deg`
    /// are set from the scenario.
    pub params: Params,
}

impl FuzzyEvalConfig {
    /// The scenario with the engine's default parameters.
    pub fn new(scenario: VehicleScenario) -> FuzzyEvalConfig {
        FuzzyEvalConfig {
            scenario,
            params: Params::defaults(PARAMS),
        }
    }
}

/// RMSE of pitch, roll and heading, degrees.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct AttitudeErrors {
    pub pitch_deg: f64,
    pub roll_deg: f64,
    pub heading_deg: f64,
}

impl AttitudeErrors {
    /// Pitch + roll + heading RMSE: what the Madgwick β is chosen by.
    fn total(&self) -> f64 {
        self.pitch_deg + self.roll_deg + self.heading_deg
    }
}

/// The Madgwick baseline with one β.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BetaScore {
    pub beta: f64,
    pub errors: AttitudeErrors,
}

#[derive(Debug, Clone, Copy, Default)]
struct Accumulator {
    pitch: ErrorStats,
    roll: ErrorStats,
    heading: ErrorStats,
}

impl Accumulator {
    fn tilt(&mut self, truth: &VehicleTruth, pitch_deg: f64, roll_deg: f64) {
        self.pitch.add(pitch_deg - truth.pitch_deg);
        self.roll.add(roll_deg - truth.roll_deg);
    }

    fn heading(&mut self, truth: &VehicleTruth, heading_deg: f64) {
        self.heading.add(deg(angle_difference(
            rad(heading_deg),
            rad(truth.heading_deg),
        )));
    }

    fn rmse(&self) -> AttitudeErrors {
        AttitudeErrors {
            pitch_deg: self.pitch.rmse(),
            roll_deg: self.roll.rmse(),
            heading_deg: self.heading.rmse(),
        }
    }

    /// Scores an attitude estimate (magnetic heading) from alignment, and
    /// its heading (plus `declination`, rad) from calibration.
    fn attitude(
        &mut self,
        truth: &VehicleTruth,
        q: &nalgebra::UnitQuaternion<f64>,
        declination: f64,
        heading_too: bool,
    ) {
        let (roll, pitch, yaw) = q.euler_angles();
        self.tilt(truth, deg(pitch), deg(roll));
        if heading_too {
            self.heading(truth, deg(yaw + declination));
        }
    }
}

/// The standard AHRS baselines on one drive.
struct AhrsBaselines {
    madgwick: Vec<Madgwick>,
    mahony: Mahony,
    vqf: Vqf,
    previous_t: f64,
}

impl AhrsBaselines {
    fn start(t: f64, force: &V3, field: &V3, imu_period_s: f64) -> AhrsBaselines {
        let q = initial_attitude(force, Some(field));
        let mut vqf = Vqf::new(imu_period_s, imu_period_s);
        vqf.update_imu(&V3::zeros(), force, 0.0);
        vqf.update_mag(field);
        AhrsBaselines {
            vqf,
            madgwick: MADGWICK_BETAS
                .iter()
                .map(|&beta| Madgwick::new(beta, q))
                .collect(),
            mahony: Mahony::new(MAHONY_KP, MAHONY_KI, q),
            previous_t: t,
        }
    }

    fn update(&mut self, t: f64, rate: &V3, force: &V3, field: &V3) {
        let dt = t - self.previous_t;
        self.previous_t = t;
        for filter in &mut self.madgwick {
            filter.update(rate, force, Some(field), dt);
        }
        self.mahony.update(rate, force, Some(field), dt);
        self.vqf.update_imu(rate, force, dt);
        self.vqf.update_mag(field);
    }
}

/// What the baselines estimate at one IMU reading.
struct BaselineEstimates<'a> {
    gyro_only: nalgebra::UnitQuaternion<f64>,
    /// Roll and pitch from the accelerometer, rad.
    accel_tilt: (f64, f64),
    /// Raw compass heading (true), rad.
    compass: Option<f64>,
    ahrs: Option<&'a AhrsBaselines>,
}

/// The baselines' scores over one window.
#[derive(Default)]
struct BaselineScores {
    gyro_only: Accumulator,
    accel_only: Accumulator,
    raw_compass: Accumulator,
    madgwick: Vec<Accumulator>,
    mahony: Accumulator,
    vqf: Accumulator,
}

impl BaselineScores {
    /// Scores tilt, and heading when `heading_too`.
    fn score(
        &mut self,
        truth: &VehicleTruth,
        b: &BaselineEstimates,
        declination: f64,
        heading_too: bool,
    ) {
        // The gyro-only attitude starts from the truth (true north).
        self.gyro_only
            .attitude(truth, &b.gyro_only, 0.0, heading_too);
        self.accel_only
            .tilt(truth, deg(b.accel_tilt.1), deg(b.accel_tilt.0));
        if heading_too && let Some(heading) = b.compass {
            self.raw_compass.heading(truth, deg(heading));
        }
        if let Some(ahrs) = b.ahrs {
            self.madgwick
                .resize(ahrs.madgwick.len(), Accumulator::default());
            for (filter, scores) in ahrs.madgwick.iter().zip(&mut self.madgwick) {
                scores.attitude(truth, &filter.attitude(), declination, heading_too);
            }
            self.mahony
                .attitude(truth, &ahrs.mahony.attitude(), declination, heading_too);
            self.vqf
                .attitude(truth, &ahrs.vqf.attitude(), declination, heading_too);
        }
    }
}

/// An RMSE over no readings is infinite: the engine gave no estimate.
fn rmse_or_never(a: &Accumulator) -> AttitudeErrors {
    let never = |e: &ErrorStats, x: f64| if e.count == 0 { f64::INFINITY } else { x };
    let r = a.rmse();
    AttitudeErrors {
        pitch_deg: never(&a.pitch, r.pitch_deg),
        roll_deg: never(&a.roll, r.roll_deg),
        heading_deg: never(&a.heading, r.heading_deg),
    }
}

/// The whole evaluation of one drive.
#[derive(Debug, Clone, Serialize)]
pub struct FuzzyEvaluation {
    pub scenario: VehicleScenario,
    pub imu_readings: u64,
    /// Seconds from the start to alignment and to the first calibration.
    pub aligned_after_s: Option<f64>,
    pub calibrated_after_s: Option<f64>,
    pub calibration: String,
    /// True when the engine never calibrated and the baselines are scored
    /// over the fallback windows (module doc).
    pub baselines_on_fallback_windows: bool,
    /// Share of readings with the right motion status, and the share of
    /// truly moving readings the engine called static (and the reverse).
    pub motion_accuracy: f64,
    pub moving_called_static: f64,
    pub static_called_moving: f64,
    /// The engine: pitch and roll from alignment, heading from calibration.
    pub engine: AttitudeErrors,
    pub gyro_only: AttitudeErrors,
    pub accel_only_tilt: AttitudeErrors,
    pub raw_compass: AttitudeErrors,
    /// Madgwick (MARG, raw magnetometer) with the β of the smallest total
    /// RMSE on this drive, chosen with the truth; and every β tried.
    pub madgwick_tuned: AttitudeErrors,
    pub madgwick_beta: f64,
    pub madgwick_by_beta: Vec<BetaScore>,
    /// Mahony (raw magnetometer, fixed gains).
    pub mahony: AttitudeErrors,
    /// VQF (raw magnetometer, defaults).
    pub vqf: AttitudeErrors,
    /// The engine over the first and last `DRIFT_WINDOW_S` after the
    /// first planar or full calibration.
    pub first_5_min: AttitudeErrors,
    pub last_5_min: AttitudeErrors,
    /// The gyro-only baseline over the same windows (it drifts).
    pub gyro_only_first_5_min: AttitudeErrors,
    pub gyro_only_last_5_min: AttitudeErrors,
    /// Largest |gyro bias error| over the last 5 minutes, °/s.
    pub final_bias_error_dps: f64,
}

impl FuzzyEvaluation {
    /// The best single-sensor baseline per angle (smallest RMSE): gyro
    /// only, accelerometer only and raw compass (not the AHRS filters).
    pub fn best_baseline(&self) -> AttitudeErrors {
        let b = [self.gyro_only, self.accel_only_tilt];
        AttitudeErrors {
            pitch_deg: b.iter().map(|e| e.pitch_deg).fold(f64::INFINITY, f64::min),
            roll_deg: b.iter().map(|e| e.roll_deg).fold(f64::INFINITY, f64::min),
            heading_deg: self.gyro_only.heading_deg.min(self.raw_compass.heading_deg),
        }
    }
}

/// Why an evaluation could not run.
#[derive(Debug, thiserror::Error)]
pub enum FuzzyEvalError {
    #[error("invalid scenario: {0}")]
    Scenario(String),
    #[error(transparent)]
    Params(#[from] ParamError),
}

/// Runs the drive through the engine and the baselines.
pub fn evaluate(config: &FuzzyEvalConfig) -> Result<FuzzyEvaluation, FuzzyEvalError> {
    let scenario = config.scenario.clone();
    // What an installer sets for the site: declination and inclination.
    let params = config.params.with_overrides(
        PARAMS,
        [
            (
                "declination_deg".to_string(),
                ParamValue::Number(scenario.declination_deg),
            ),
            (
                "mag_inclination_deg".to_string(),
                ParamValue::Number(scenario.inclination_deg),
            ),
        ],
    )?;
    let drive = VehicleDrive::new(scenario.clone()).map_err(FuzzyEvalError::Scenario)?;
    let mut engine = FuzzyEngine::new(params)?;
    let declination = rad(scenario.declination_deg);
    let start_t = scenario.start_t;
    let end_t = start_t + scenario.duration_s;

    let mut out: Vec<EngineOutput> = Vec::with_capacity(2);
    let mut imu_readings = 0u64;
    let (mut aligned_at, mut calibrated_at) = (None, None);
    // The first calibration other than a partial arc's: the drift
    // windows start there.
    let mut fully_calibrated_at: Option<f64> = None;
    let (mut motion_right, mut motion_total) = (0u64, 0u64);
    let (mut moving_total, mut moving_as_static) = (0u64, 0u64);
    let (mut static_total, mut static_as_moving) = (0u64, 0u64);
    let mut ours = Accumulator::default();
    let (mut first, mut last) = (Accumulator::default(), Accumulator::default());
    let (mut gyro_first, mut gyro_last) = (Accumulator::default(), Accumulator::default());
    // The baselines over the engine's windows, and over the fallback ones.
    let mut same = BaselineScores::default();
    let mut fallback = BaselineScores::default();
    let mut final_bias_error = 0.0_f64;
    let mut calibration = CalibrationState::Collecting;

    // Gyro-only baseline state.
    let mut baseline_attitude = None;
    let (mut bias_sum, mut bias_count) = (V3::zeros(), 0u32);
    let mut baseline_previous: Option<(f64, V3)> = None;
    let mut newest_field: Option<V3> = None;
    let mut ahrs: Option<AhrsBaselines> = None;

    for event in drive {
        let reading = event.reading;
        match (&reading.data, event.truth) {
            (SensorData::Magnetometer { field_ut }, _) => {
                newest_field = Some(V3::from(*field_ut));
                engine.feed(&reading, &mut out);
            }
            (
                SensorData::Imu {
                    accel_mps2,
                    gyro_dps,
                },
                Some(truth),
            ) => {
                imu_readings += 1;
                out.clear();
                engine.feed(&reading, &mut out);
                let force = V3::from(*accel_mps2);
                let rate = V3::new(rad(gyro_dps[0]), rad(gyro_dps[1]), rad(gyro_dps[2]));
                if let Some(field) = &newest_field {
                    match &mut ahrs {
                        Some(filters) => filters.update(reading.t, &rate, &force, field),
                        None => {
                            ahrs = Some(AhrsBaselines::start(
                                reading.t,
                                &force,
                                field,
                                1.0 / scenario.imu_rate_hz,
                            ))
                        }
                    }
                }
                let Some(estimate) = out.last().and_then(|o| o.values.as_fuzzy()) else {
                    continue;
                };
                let s = reading.t - start_t;

                // Baselines.
                let (roll_a, pitch_a) = tilt_from_accel(&force);
                let attitude = *baseline_attitude.get_or_insert_with(|| {
                    attitude_from_euler(
                        rad(truth.roll_deg),
                        rad(truth.pitch_deg),
                        rad(truth.heading_deg),
                    )
                });
                if s < BASELINE_BIAS_S {
                    bias_sum += rate;
                    bias_count += 1;
                } else {
                    let bias = bias_sum / f64::from(bias_count.max(1));
                    if let Some((previous_t, previous_rate)) = baseline_previous {
                        let mean = (previous_rate + rate) * 0.5 - bias;
                        baseline_attitude =
                            Some(integrate(&attitude, &mean, reading.t - previous_t));
                    }
                }
                baseline_previous = Some((reading.t, rate));
                // The gyro-only attitude integrated to this reading.
                let gyro_attitude = baseline_attitude.unwrap_or(attitude);
                let baselines = BaselineEstimates {
                    gyro_only: gyro_attitude,
                    accel_tilt: (roll_a, pitch_a),
                    compass: newest_field
                        .map(|field| magnetic_heading(&field, roll_a, pitch_a) + declination),
                    ahrs: ahrs.as_ref(),
                };
                if s >= FALLBACK_TILT_S {
                    fallback.score(&truth, &baselines, declination, s >= FALLBACK_HEADING_S);
                }

                if !estimate.aligned {
                    continue;
                }
                aligned_at.get_or_insert(s);
                score_motion(estimate, &truth, &mut motion_right, &mut motion_total);
                if truth.moving {
                    moving_total += 1;
                    moving_as_static += u64::from(estimate.motion == Motion::Static);
                } else {
                    static_total += 1;
                    static_as_moving += u64::from(estimate.motion == Motion::Moving);
                }
                ours.tilt(&truth, estimate.pitch_deg, estimate.roll_deg);
                let calibrating = estimate.mag_calibration == CalibrationState::Collecting;
                same.score(&truth, &baselines, declination, !calibrating);
                if calibrating {
                    continue;
                }
                calibration = estimate.mag_calibration;
                calibrated_at.get_or_insert(s);
                ours.heading(&truth, estimate.heading_deg);
                if calibration != CalibrationState::Arc {
                    fully_calibrated_at.get_or_insert(s);
                }
                let (g_roll, g_pitch, g_yaw) = gyro_attitude.euler_angles();
                let window = match fully_calibrated_at {
                    Some(calibrated) if s - calibrated < DRIFT_WINDOW_S => {
                        Some((&mut first, &mut gyro_first))
                    }
                    Some(_) if reading.t > end_t - DRIFT_WINDOW_S => {
                        Some((&mut last, &mut gyro_last))
                    }
                    _ => None,
                };
                if let Some((engine_window, gyro_window)) = window {
                    engine_window.tilt(&truth, estimate.pitch_deg, estimate.roll_deg);
                    engine_window.heading(&truth, estimate.heading_deg);
                    gyro_window.tilt(&truth, deg(g_pitch), deg(g_roll));
                    gyro_window.heading(&truth, deg(g_yaw));
                }
                if reading.t > end_t - DRIFT_WINDOW_S {
                    for k in 0..3 {
                        final_bias_error = final_bias_error
                            .max((estimate.gyro_bias_dps[k] - truth.gyro_bias_dps[k]).abs());
                    }
                }
            }
            _ => engine.feed(&reading, &mut out),
        }
    }
    let share = |part: u64, whole: u64| {
        if whole == 0 {
            0.0
        } else {
            part as f64 / whole as f64
        }
    };
    let on_fallback = calibrated_at.is_none();
    let baselines = if on_fallback { fallback } else { same };
    let madgwick_by_beta: Vec<BetaScore> = baselines
        .madgwick
        .iter()
        .zip(MADGWICK_BETAS)
        .map(|(scores, beta)| BetaScore {
            beta,
            errors: scores.rmse(),
        })
        .collect();
    let tuned = madgwick_by_beta
        .iter()
        .min_by(|a, b| a.errors.total().total_cmp(&b.errors.total()))
        .copied()
        .unwrap_or(BetaScore {
            beta: f64::NAN,
            errors: AttitudeErrors::default(),
        });
    Ok(FuzzyEvaluation {
        scenario,
        imu_readings,
        aligned_after_s: aligned_at,
        calibrated_after_s: calibrated_at,
        calibration: calibration.as_str().to_string(),
        baselines_on_fallback_windows: on_fallback,
        motion_accuracy: share(motion_right, motion_total),
        moving_called_static: share(moving_as_static, moving_total),
        static_called_moving: share(static_as_moving, static_total),
        engine: rmse_or_never(&ours),
        gyro_only: baselines.gyro_only.rmse(),
        accel_only_tilt: AttitudeErrors {
            heading_deg: f64::NAN,
            ..baselines.accel_only.rmse()
        },
        raw_compass: AttitudeErrors {
            pitch_deg: f64::NAN,
            roll_deg: f64::NAN,
            heading_deg: baselines.raw_compass.rmse().heading_deg,
        },
        madgwick_tuned: tuned.errors,
        madgwick_beta: tuned.beta,
        madgwick_by_beta,
        mahony: baselines.mahony.rmse(),
        vqf: baselines.vqf.rmse(),
        first_5_min: rmse_or_never(&first),
        last_5_min: rmse_or_never(&last),
        gyro_only_first_5_min: gyro_first.rmse(),
        gyro_only_last_5_min: gyro_last.rmse(),
        final_bias_error_dps: final_bias_error,
    })
}

fn score_motion(estimate: &FuzzyEstimate, truth: &VehicleTruth, right: &mut u64, total: &mut u64) {
    *total += 1;
    let called_moving = estimate.motion == Motion::Moving;
    *right += u64::from(called_moving == truth.moving);
}

/// The evaluation as a text table.
pub fn render_table(e: &FuzzyEvaluation) -> String {
    let mut text = String::new();
    let seconds = |x: Option<f64>| x.map_or("never".to_string(), |s| format!("{s:.1} s"));
    text.push_str(&format!(
        "vehicle drive, seed {}: {:.0} s, {} IMU readings; aligned after {}, magnetometer calibrated ({}) after {}\n",
        e.scenario.seed,
        e.scenario.duration_s,
        e.imu_readings,
        seconds(e.aligned_after_s),
        e.calibration,
        seconds(e.calibrated_after_s),
    ));
    text.push_str(&format!(
        "motion status: {:.2} % right (moving called static {:.2} %, static called moving {:.2} %)\n",
        100.0 * e.motion_accuracy,
        100.0 * e.moving_called_static,
        100.0 * e.static_called_moving,
    ));
    text.push_str("RMSE, degrees            pitch     roll  heading\n");
    let row = |name: &str, a: &AttitudeErrors| {
        let cell = |x: f64| {
            if x.is_nan() {
                "       —".to_string()
            } else if x.is_infinite() {
                "   never".to_string()
            } else {
                format!("{x:8.3}")
            }
        };
        format!(
            "{name:<22} {} {} {}\n",
            cell(a.pitch_deg),
            cell(a.roll_deg),
            cell(a.heading_deg)
        )
    };
    text.push_str(&row("fuzzy engine", &e.engine));
    text.push_str(&row("gyro only", &e.gyro_only));
    text.push_str(&row("accelerometer only", &e.accel_only_tilt));
    text.push_str(&row("raw compass", &e.raw_compass));
    text.push_str(&row(
        &format!("Madgwick β={}*", e.madgwick_beta),
        &e.madgwick_tuned,
    ));
    text.push_str(&row("Mahony", &e.mahony));
    text.push_str(&row("VQF", &e.vqf));
    if e.baselines_on_fallback_windows {
        text.push_str(
            "(the engine never calibrated: baselines scored from 10 s, heading from 150 s)\n",
        );
    }
    text.push_str(&row("engine, first 5 min", &e.first_5_min));
    text.push_str(&row("engine, last 5 min", &e.last_5_min));
    let best = e.best_baseline();
    text.push_str(&format!(
        "* β of {:?} rad/s with the smallest total RMSE, chosen with the truth; Mahony k_P {MAHONY_KP}, k_I {MAHONY_KI}; VQF its defaults; all three with the raw magnetometer\n",
        MADGWICK_BETAS
    ));
    text.push_str(&format!(
        "better than the best single-sensor baseline: pitch {:.1}×, roll {:.1}×, heading {:.1}×; final gyro bias error ≤ {:.4} °/s\n",
        best.pitch_deg / e.engine.pitch_deg,
        best.roll_deg / e.engine.roll_deg,
        best.heading_deg / e.engine.heading_deg,
        e.final_bias_error_dps,
    ));
    text
}

/// Median and worst of one method's RMSE per angle over drives (`None`
/// for an angle the method does not give), and the median and lowest of
/// its RMSE ÷ the engine's on the same drive (for the baselines; over the
/// drives where the engine gave that angle, `None` if it never did).
#[derive(Debug, Clone, Serialize)]
pub struct MethodSummary {
    pub method: String,
    pub pitch_deg: Option<Spread>,
    pub roll_deg: Option<Spread>,
    pub heading_deg: Option<Spread>,
    pub pitch_over_engine: Option<Spread>,
    pub roll_over_engine: Option<Spread>,
    pub heading_over_engine: Option<Spread>,
}

/// The engine and the baselines over several drives.
#[derive(Debug, Clone, Serialize)]
pub struct FuzzySummary {
    pub drives: usize,
    pub seeds: Vec<u64>,
    /// Median and lowest share of right motion statuses.
    pub motion_accuracy: Spread,
    /// Median and latest alignment and calibration, s (never: infinite,
    /// null in JSON).
    pub aligned_after_s: Spread,
    pub calibrated_after_s: Spread,
    /// Drives on which the engine never aligned, never calibrated.
    pub engine_never_aligned: usize,
    pub engine_never_calibrated: usize,
    /// The Madgwick β chosen on each drive, in seed order.
    pub madgwick_betas: Vec<f64>,
    /// The engine first, then the baselines.
    pub methods: Vec<MethodSummary>,
}

/// How to read one method's errors from an evaluation.
type MethodErrors = fn(&FuzzyEvaluation) -> AttitudeErrors;

/// The methods of the summary and how to read each from an evaluation.
const SUMMARY_METHODS: [(&str, MethodErrors); 7] = [
    ("fuzzy engine", |e| e.engine),
    ("gyro only", |e| e.gyro_only),
    ("accelerometer only", |e| e.accel_only_tilt),
    ("raw compass", |e| e.raw_compass),
    ("Madgwick, tuned β", |e| e.madgwick_tuned),
    ("Mahony", |e| e.mahony),
    ("VQF", |e| e.vqf),
];

/// Summarises evaluations of several drives.
pub fn summarise(evaluations: &[FuzzyEvaluation]) -> FuzzySummary {
    let spread =
        |values: Vec<f64>| (!values.iter().any(|x| x.is_nan())).then(|| Spread::of(&values));
    let ratio = |values: Vec<f64>| {
        (!values.is_empty() && !values.iter().any(|x| x.is_nan()))
            .then(|| Spread::of_lowest(&values))
    };
    let methods = SUMMARY_METHODS
        .iter()
        .enumerate()
        .map(|(k, &(name, errors))| {
            let angle = |pick: fn(&AttitudeErrors) -> f64| -> Vec<f64> {
                evaluations.iter().map(|e| pick(&errors(e))).collect()
            };
            let over = |pick: fn(&AttitudeErrors) -> f64| -> Option<Spread> {
                if k == 0 {
                    return None;
                }
                ratio(
                    evaluations
                        .iter()
                        .filter(|e| pick(&e.engine).is_finite())
                        .map(|e| pick(&errors(e)) / pick(&e.engine).max(1e-12))
                        .collect(),
                )
            };
            MethodSummary {
                method: name.to_string(),
                pitch_deg: spread(angle(|a| a.pitch_deg)),
                roll_deg: spread(angle(|a| a.roll_deg)),
                heading_deg: spread(angle(|a| a.heading_deg)),
                pitch_over_engine: over(|a| a.pitch_deg),
                roll_over_engine: over(|a| a.roll_deg),
                heading_over_engine: over(|a| a.heading_deg),
            }
        })
        .collect();
    let seconds = |pick: fn(&FuzzyEvaluation) -> Option<f64>| {
        Spread::of(
            &evaluations
                .iter()
                .map(|e| pick(e).unwrap_or(f64::INFINITY))
                .collect::<Vec<_>>(),
        )
    };
    FuzzySummary {
        drives: evaluations.len(),
        seeds: evaluations.iter().map(|e| e.scenario.seed).collect(),
        motion_accuracy: Spread::of_lowest(
            &evaluations
                .iter()
                .map(|e| e.motion_accuracy)
                .collect::<Vec<_>>(),
        ),
        aligned_after_s: seconds(|e| e.aligned_after_s),
        calibrated_after_s: seconds(|e| e.calibrated_after_s),
        engine_never_aligned: evaluations
            .iter()
            .filter(|e| e.aligned_after_s.is_none())
            .count(),
        engine_never_calibrated: evaluations
            .iter()
            .filter(|e| e.calibrated_after_s.is_none())
            .count(),
        madgwick_betas: evaluations.iter().map(|e| e.madgwick_beta).collect(),
        methods,
    }
}

/// The summary as text: median / worst per metric and method, then each
/// baseline's RMSE over the engine's, median (lowest).
pub fn render_summary(s: &FuzzySummary) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let seeds = match (s.seeds.first(), s.seeds.last()) {
        (Some(a), Some(b)) => format!("seeds {a}–{b}"),
        _ => "no seeds".to_string(),
    };
    let time = |x: f64| {
        if x.is_finite() {
            format!("{x:.1} s")
        } else {
            "never".to_string()
        }
    };
    let _ = writeln!(
        out,
        "summary over {} drives ({seeds}), median / worst:",
        s.drives
    );
    let _ = writeln!(
        out,
        "motion status right {:.2} % / {:.2} %; aligned after {} / {}; calibrated after {} / {}",
        100.0 * s.motion_accuracy.median,
        100.0 * s.motion_accuracy.worst,
        time(s.aligned_after_s.median),
        time(s.aligned_after_s.worst),
        time(s.calibrated_after_s.median),
        time(s.calibrated_after_s.worst),
    );
    let number = |x: f64, digits: usize| {
        if x.is_finite() {
            format!("{x:.digits$}")
        } else {
            "never".to_string()
        }
    };
    let cell = |x: Option<Spread>, digits: usize| {
        x.map_or("—".to_string(), |x| {
            format!("{} / {}", number(x.median, digits), number(x.worst, digits))
        })
    };
    let _ = writeln!(
        out,
        "RMSE, degrees          {:>17} {:>17} {:>17}",
        "pitch", "roll", "heading"
    );
    for m in &s.methods {
        let _ = writeln!(
            out,
            "{:<22} {:>17} {:>17} {:>17}",
            m.method,
            cell(m.pitch_deg, 3),
            cell(m.roll_deg, 3),
            cell(m.heading_deg, 3)
        );
    }
    if s.engine_never_aligned + s.engine_never_calibrated > 0 {
        let _ = writeln!(
            out,
            "the engine never aligned on {} drive(s) and never calibrated on {} (RMSE never; baselines there scored from 10 s, heading from 150 s)",
            s.engine_never_aligned, s.engine_never_calibrated
        );
    }
    let _ = writeln!(
        out,
        "baseline ÷ engine RMSE, median / lowest over the drives the engine gave the angle on:"
    );
    for m in s.methods.iter().skip(1) {
        let _ = writeln!(
            out,
            "{:<22} {:>17} {:>17} {:>17}",
            m.method,
            cell(m.pitch_over_engine, 2),
            cell(m.roll_over_engine, 2),
            cell(m.heading_over_engine, 2)
        );
    }
    let mut betas: Vec<(f64, usize)> = Vec::new();
    for &b in &s.madgwick_betas {
        match betas.iter_mut().find(|(x, _)| x.total_cmp(&b).is_eq()) {
            Some((_, n)) => *n += 1,
            None => betas.push((b, 1)),
        }
    }
    betas.sort_by(|a, b| a.0.total_cmp(&b.0));
    let chosen: Vec<String> = betas.iter().map(|(b, n)| format!("{b} ×{n}")).collect();
    let _ = writeln!(
        out,
        "Madgwick β (rad/s) chosen per drive with the truth: {}",
        chosen.join(", ")
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn evaluation(seed: u64, engine: f64, madgwick: f64, aligned: Option<f64>) -> FuzzyEvaluation {
        let errors = |x: f64| AttitudeErrors {
            pitch_deg: x,
            roll_deg: 2.0 * x,
            heading_deg: 10.0 * x,
        };
        FuzzyEvaluation {
            scenario: VehicleScenario {
                seed,
                ..VehicleScenario::default()
            },
            imu_readings: 100,
            aligned_after_s: aligned,
            calibrated_after_s: Some(100.0 + seed as f64),
            calibration: "calibrated".into(),
            baselines_on_fallback_windows: false,
            motion_accuracy: 1.0 - 0.01 * seed as f64,
            moving_called_static: 0.0,
            static_called_moving: 0.0,
            engine: errors(engine),
            gyro_only: errors(1.0),
            accel_only_tilt: AttitudeErrors {
                heading_deg: f64::NAN,
                ..errors(0.5)
            },
            raw_compass: AttitudeErrors {
                pitch_deg: f64::NAN,
                roll_deg: f64::NAN,
                heading_deg: 3.0,
            },
            madgwick_tuned: errors(madgwick),
            madgwick_beta: 0.05,
            madgwick_by_beta: Vec::new(),
            mahony: errors(0.3),
            vqf: errors(0.3),
            first_5_min: errors(engine),
            last_5_min: errors(engine),
            gyro_only_first_5_min: errors(1.0),
            gyro_only_last_5_min: errors(1.0),
            final_bias_error_dps: 0.0,
        }
    }

    #[test]
    fn the_ahrs_baselines_are_scored_beside_the_engine() {
        let e = evaluate(&FuzzyEvalConfig::new(VehicleScenario {
            duration_s: 300.0,
            ..VehicleScenario::default()
        }))
        .unwrap();
        assert!(!e.baselines_on_fallback_windows);
        assert_eq!(e.madgwick_by_beta.len(), MADGWICK_BETAS.len());
        let best = e
            .madgwick_by_beta
            .iter()
            .map(|b| b.errors.total())
            .fold(f64::INFINITY, f64::min);
        assert_eq!(e.madgwick_tuned.total(), best);
        assert!(MADGWICK_BETAS.contains(&e.madgwick_beta));
        for a in [e.madgwick_tuned, e.mahony, e.vqf] {
            for x in [a.pitch_deg, a.roll_deg, a.heading_deg] {
                // Scored, and not absurd for filters fed a raw compass.
                assert!(x > 0.0 && x < 45.0, "{e:?}");
            }
        }
    }

    #[test]
    fn the_summary_by_hand() {
        let drives = [
            evaluation(1, 0.1, 0.2, Some(10.0)),
            evaluation(2, 0.2, 0.2, Some(12.0)),
            evaluation(3, 0.4, 0.2, None),
        ];
        let s = summarise(&drives);
        assert_eq!(s.drives, 3);
        assert_eq!(s.seeds, vec![1, 2, 3]);
        let engine = &s.methods[0];
        let pitch = engine.pitch_deg.unwrap();
        assert_eq!((pitch.median, pitch.worst), (0.2, 0.4));
        assert!(engine.pitch_over_engine.is_none());
        // Madgwick ÷ engine: 2, 1, 0.5.
        let madgwick = &s.methods[4];
        let over = madgwick.heading_over_engine.unwrap();
        assert!((over.median - 1.0).abs() < 1e-12 && (over.worst - 0.5).abs() < 1e-12);
        // Angles a baseline does not give.
        assert!(s.methods[2].heading_deg.is_none() && s.methods[3].pitch_deg.is_none());
        assert!(s.methods[3].heading_over_engine.is_some());
        // Motion: the lowest is the worst; alignment: never is the worst.
        assert!((s.motion_accuracy.worst - 0.97).abs() < 1e-12);
        assert_eq!(s.aligned_after_s.median, 12.0);
        assert!(s.aligned_after_s.worst.is_infinite());
        let text = render_summary(&s);
        for line in [
            "summary over 3 drives (seeds 1–3)",
            "aligned after 12.0 s / never",
            "Madgwick, tuned β",
            "Madgwick β (rad/s) chosen per drive with the truth: 0.05 ×3",
        ] {
            assert!(text.contains(line), "{line}: {text}");
        }
        // An engine that never aligned: RMSE never, left out of the ratios.
        let mut never = evaluation(4, 0.1, 0.2, None);
        never.engine = AttitudeErrors {
            pitch_deg: f64::INFINITY,
            roll_deg: f64::INFINITY,
            heading_deg: f64::INFINITY,
        };
        never.calibrated_after_s = None;
        let with_never = summarise(&[drives[0].clone(), never]);
        assert_eq!(
            (
                with_never.engine_never_aligned,
                with_never.engine_never_calibrated
            ),
            (1, 1)
        );
        let over = with_never.methods[4].pitch_over_engine.unwrap();
        assert_eq!((over.median, over.worst), (2.0, 2.0));
        assert!(render_summary(&with_never).contains("never aligned on 1 drive(s)"));
        // JSON: infinity is null.
        let json = serde_json::to_value(&s).unwrap();
        assert!(json["aligned_after_s"]["worst"].is_null());
    }
}
