//! `eval fuzzy`: the `fuzzy` engine against simulated truth and against
//! the single-sensor solutions it fuses.
//!
//! Scores:
//! - motion status: the share of IMU readings (from alignment on) whose
//!   `motion` matches the truth (rolling or turning = moving);
//! - pitch and roll RMSE from alignment on; heading RMSE from the first
//!   magnetometer calibration on;
//! - drift: the same RMSEs over the first and the last 5 minutes after
//!   calibration;
//! - baselines, each over the same readings:
//!   - gyro only: the gyros integrated (quaternions) from the true initial
//!     attitude, their bias taken as the mean of the first 10 s (parked);
//!   - accelerometer only: tilt from each reading's specific force;
//!   - raw compass: heading from the uncalibrated magnetometer,
//!     tilt-compensated with the accelerometer tilt, plus declination.

use serde::Serialize;

use super::ErrorStats;
use crate::fusion::angles::{deg, rad};
use crate::fusion::fuzzy::magcal::CalibrationState;
use crate::fusion::fuzzy::orientation::{
    angle_difference, integrate, magnetic_heading, tilt_from_accel,
};
use crate::fusion::fuzzy::{FuzzyEngine, PARAMS};
use crate::fusion::zupt::strapdown::{V3, attitude_from_euler};
use crate::fusion::{
    Engine, EngineOutput, FuzzyEstimate, Motion, ParamError, ParamValue, Params, SensorData,
};
use crate::sim::vehicle::{VehicleDrive, VehicleScenario, VehicleTruth};

/// Seconds of parked readings the gyro-only baseline takes its bias from.
const BASELINE_BIAS_S: f64 = 10.0;
/// Length of the drift windows.
const DRIFT_WINDOW_S: f64 = 300.0;

/// What to evaluate.
#[derive(Debug, Clone)]
pub struct FuzzyEvalConfig {
    pub scenario: VehicleScenario,
    /// Parameters of the engine; `declination_deg` is set from the scenario.
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
    /// The engine over the first and last `DRIFT_WINDOW_S` after calibration.
    pub first_5_min: AttitudeErrors,
    pub last_5_min: AttitudeErrors,
    /// The gyro-only baseline over the same windows (it drifts).
    pub gyro_only_first_5_min: AttitudeErrors,
    pub gyro_only_last_5_min: AttitudeErrors,
    /// Largest |gyro bias error| over the last 5 minutes, °/s.
    pub final_bias_error_dps: f64,
}

impl FuzzyEvaluation {
    /// The best single-sensor baseline per angle (smallest RMSE).
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
    let params = config.params.with_overrides(
        PARAMS,
        [(
            "declination_deg".to_string(),
            ParamValue::Number(scenario.declination_deg),
        )],
    )?;
    let drive = VehicleDrive::new(scenario.clone()).map_err(FuzzyEvalError::Scenario)?;
    let mut engine = FuzzyEngine::new(params)?;
    let declination = rad(scenario.declination_deg);
    let start_t = scenario.start_t;
    let end_t = start_t + scenario.duration_s;

    let mut out: Vec<EngineOutput> = Vec::with_capacity(2);
    let mut imu_readings = 0u64;
    let (mut aligned_at, mut calibrated_at) = (None, None);
    let (mut motion_right, mut motion_total) = (0u64, 0u64);
    let (mut moving_total, mut moving_as_static) = (0u64, 0u64);
    let (mut static_total, mut static_as_moving) = (0u64, 0u64);
    let mut ours = Accumulator::default();
    let (mut first, mut last) = (Accumulator::default(), Accumulator::default());
    let (mut gyro_first, mut gyro_last) = (Accumulator::default(), Accumulator::default());
    let mut gyro_only = Accumulator::default();
    let mut accel_only = Accumulator::default();
    let mut raw_compass = Accumulator::default();
    let mut final_bias_error = 0.0_f64;
    let mut calibration = CalibrationState::Collecting;

    // Gyro-only baseline state.
    let mut baseline_attitude = None;
    let (mut bias_sum, mut bias_count) = (V3::zeros(), 0u32);
    let mut baseline_previous: Option<(f64, V3)> = None;
    let mut newest_field: Option<V3> = None;

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
                let Some(estimate) = out.last().and_then(|o| o.values.as_fuzzy()) else {
                    continue;
                };
                let force = V3::from(*accel_mps2);
                let rate = V3::new(rad(gyro_dps[0]), rad(gyro_dps[1]), rad(gyro_dps[2]));
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
                let (g_roll, g_pitch, g_yaw) = baseline_attitude
                    .map(|q| q.euler_angles())
                    .unwrap_or_default();
                gyro_only.tilt(&truth, deg(g_pitch), deg(g_roll));
                accel_only.tilt(&truth, deg(pitch_a), deg(roll_a));

                if estimate.mag_calibration == CalibrationState::Collecting {
                    continue;
                }
                calibration = estimate.mag_calibration;
                let calibrated = *calibrated_at.get_or_insert(s);
                ours.heading(&truth, estimate.heading_deg);
                gyro_only.heading(&truth, deg(g_yaw));
                if let Some(field) = newest_field {
                    let heading = magnetic_heading(&field, roll_a, pitch_a) + declination;
                    raw_compass.heading(&truth, deg(heading));
                }
                let window = if s - calibrated < DRIFT_WINDOW_S {
                    Some((&mut first, &mut gyro_first))
                } else if reading.t > end_t - DRIFT_WINDOW_S {
                    Some((&mut last, &mut gyro_last))
                } else {
                    None
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
    Ok(FuzzyEvaluation {
        scenario,
        imu_readings,
        aligned_after_s: aligned_at,
        calibrated_after_s: calibrated_at,
        calibration: calibration.as_str().to_string(),
        motion_accuracy: share(motion_right, motion_total),
        moving_called_static: share(moving_as_static, moving_total),
        static_called_moving: share(static_as_moving, static_total),
        engine: ours.rmse(),
        gyro_only: gyro_only.rmse(),
        accel_only_tilt: AttitudeErrors {
            heading_deg: f64::NAN,
            ..accel_only.rmse()
        },
        raw_compass: AttitudeErrors {
            pitch_deg: f64::NAN,
            roll_deg: f64::NAN,
            heading_deg: raw_compass.rmse().heading_deg,
        },
        first_5_min: first.rmse(),
        last_5_min: last.rmse(),
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
    text.push_str(&row("engine, first 5 min", &e.first_5_min));
    text.push_str(&row("engine, last 5 min", &e.last_5_min));
    let best = e.best_baseline();
    text.push_str(&format!(
        "better than the best baseline: pitch {:.1}×, roll {:.1}×, heading {:.1}×; final gyro bias error ≤ {:.4} °/s\n",
        best.pitch_deg / e.engine.pitch_deg,
        best.roll_deg / e.engine.roll_deg,
        best.heading_deg / e.engine.heading_deg,
        e.final_bias_error_dps,
    ));
    text
}
