//! The `fuzzy` engine (Wang 2005): low-cost MEMS accelerometers and gyros
//! plus a magnetometer, fused according to a fuzzy expert's decision of
//! the motion status. Only the paper's abstract survives, so the design is
//! ours, in its spirit (README: "The fuzzy engine").
//!
//! Per IMU reading:
//! 1. the reading enters a short trailing window ([`motion::MotionWindow`]);
//!    its three signals go through the Mamdani rule base
//!    ([`motion::motion_expert`], [`mamdani`]) to a static degree s ∈ [0, 1];
//!    `motion` is `static` when s ≥ `static_threshold`;
//! 2. the attitude quaternion integrates the bias-compensated gyro
//!    ([`orientation::integrate`]), always;
//! 3. it is then pulled towards the static references in proportion to s:
//!    roll/pitch towards the accelerometer tilt of the window (gain
//!    s·dt/`tilt_time_constant_s`), heading towards the calibrated,
//!    tilt-compensated compass (gain s·dt/`heading_time_constant_s`). At
//!    s = 0 this is pure gyro integration, at s = 1 a first-order lag onto
//!    the static references: the attitude is continuous whatever s does;
//! 4. where s exceeds `static_threshold`, the gyro bias and the static
//!    norm of the specific force are re-estimated (first-order lags with
//!    gain w·dt/τ, w rising from 0 at the threshold to 1 at s = 1).
//!
//! The first full window that is quiet (specific-force spread and rate
//! spread under their `still` breakpoints) aligns the engine: tilt from
//! its mean force, gyro bias from its mean rate, heading from the
//! compass. Magnetometer readings feed the calibration
//! ([`magcal::MagCalibration`]); the newest is used for heading while it
//! is younger than `max_mag_age_s`. Until the calibration exists, heading
//! is the uncalibrated compass at alignment carried on by the gyros.
//!
//! The Earth's rotation (≤ 0.0042 °/s) is below a MEMS gyro's noise and is
//! absorbed into the estimated bias while static.

pub mod magcal;
pub mod mamdani;
pub mod motion;
pub mod orientation;

use nalgebra::UnitQuaternion;
use serde::{Deserialize, Serialize};

use self::magcal::MagCalibration;
use self::mamdani::{Mamdani, Scratch};
use self::motion::{Breakpoints, MotionConfig, MotionSignals, MotionWindow};
use self::orientation::{integrate, magnetic_heading, pull_heading, pull_tilt, tilt_from_accel};
use super::angles::{deg, rad};
use super::estimate::{EngineOutput, EstimateValues, FuzzyEstimate, Motion};
use super::params::{ParamError, ParamSpec, Params, integer, real};
use super::reading::{Reading, SensorData};
use super::zupt::strapdown::{V3, attitude_from_euler};
use super::{Engine, EngineKind, SnapshotError};

/// The `fuzzy` engine's parameters. Breakpoints suit a vehicle-mounted
/// MEMS IMU at 100 Hz (noise ~0.02 m/s² and ~0.05 °/s per sample) whose
/// motion shakes it (README: how to tune).
pub const PARAMS: &[ParamSpec] = &[
    real(
        "declination_deg",
        0.0,
        -180.0,
        180.0,
        "deg",
        "magnetic declination, east positive: true heading = magnetic + declination",
    ),
    integer(
        "window_samples",
        50,
        2,
        10_000,
        "IMU readings in the motion expert's trailing window",
    ),
    real(
        "accel_dev_still_mps2",
        0.05,
        0.0,
        100.0,
        "m/s²",
        "deviation of the window's mean ‖f‖ from g below this is fully `low`",
    ),
    real(
        "accel_dev_moving_mps2",
        0.3,
        0.0,
        100.0,
        "m/s²",
        "deviation of the window's mean ‖f‖ from g above this is fully `high`",
    ),
    real(
        "accel_activity_still_mps2",
        0.06,
        0.0,
        100.0,
        "m/s²",
        "specific-force spread below this is fully `low`",
    ),
    real(
        "accel_activity_moving_mps2",
        0.2,
        0.0,
        100.0,
        "m/s²",
        "specific-force spread above this is fully `high`",
    ),
    real(
        "gyro_activity_still_dps",
        0.25,
        0.0,
        1000.0,
        "deg/s",
        "bias-compensated rate RMS below this is fully `low`",
    ),
    real(
        "gyro_activity_moving_dps",
        1.0,
        0.0,
        1000.0,
        "deg/s",
        "bias-compensated rate RMS above this is fully `high`",
    ),
    integer(
        "defuzzification_points",
        201,
        2,
        100_001,
        "centroid discretisation: points over the output range [−0.5, 1.5], ends included",
    ),
    real(
        "static_threshold",
        0.5,
        0.0,
        1.0,
        "",
        "`motion` is static from this static degree up; bias learning starts above it",
    ),
    real(
        "tilt_time_constant_s",
        4.0,
        0.001,
        1.0e6,
        "s",
        "time constant of the pull towards the accelerometer tilt when fully static",
    ),
    real(
        "heading_time_constant_s",
        2.0,
        0.001,
        1.0e6,
        "s",
        "time constant of the pull towards the compass heading when fully static",
    ),
    real(
        "bias_time_constant_s",
        5.0,
        0.001,
        1.0e6,
        "s",
        "time constant of the gyro-bias (and static g) re-estimation when fully static",
    ),
    real(
        "mag_min_coverage_deg",
        300.0,
        10.0,
        360.0,
        "deg",
        "field azimuth that must be seen before the magnetometer is calibrated",
    ),
    real(
        "mag_inclination_deg",
        60.0,
        -89.0,
        89.0,
        "deg",
        "inclination of the Earth's field at the site, down positive (sizes the vertical of a planar calibration)",
    ),
    real(
        "mag_level_tolerance_deg",
        1.5,
        0.0,
        90.0,
        "deg",
        "magnetometer readings tilted less than this count as level (a planar calibration uses only those)",
    ),
    integer(
        "mag_refit_every",
        50,
        1,
        1_000_000,
        "refit the calibration every this many magnetometer readings",
    ),
    real(
        "max_mag_age_s",
        1.0,
        0.0,
        3600.0,
        "s",
        "an older magnetometer reading gives no heading",
    ),
    real(
        "max_imu_gap_s",
        0.5,
        0.001,
        3600.0,
        "s",
        "longer gaps between IMU readings are not integrated across; the window starts afresh",
    ),
];

/// The engine's parameters in working units (SI, radians).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FuzzyConfig {
    pub declination_rad: f64,
    pub window_samples: usize,
    pub motion: MotionConfig,
    pub static_threshold: f64,
    pub tilt_time_constant_s: f64,
    pub heading_time_constant_s: f64,
    pub bias_time_constant_s: f64,
    pub mag_min_coverage_deg: f64,
    pub mag_inclination_rad: f64,
    pub mag_level_tolerance_rad: f64,
    pub mag_refit_every: u32,
    pub max_mag_age_s: f64,
    pub max_imu_gap_s: f64,
}

fn breakpoints(
    p: &Params,
    still: &'static str,
    moving: &'static str,
) -> Result<Breakpoints, ParamError> {
    let (still_value, moving_value) = (p.real(still)?, p.real(moving)?);
    if still_value >= moving_value {
        return Err(ParamError::Inconsistent(format!(
            "{moving} ({moving_value}) must be above {still} ({still_value})"
        )));
    }
    Ok(Breakpoints {
        still: still_value,
        moving: moving_value,
    })
}

impl FuzzyConfig {
    /// Converts validated parameters; degrees become radians here.
    pub fn from_params(p: &Params) -> Result<FuzzyConfig, ParamError> {
        let gyro = breakpoints(p, "gyro_activity_still_dps", "gyro_activity_moving_dps")?;
        Ok(FuzzyConfig {
            declination_rad: rad(p.real("declination_deg")?),
            window_samples: p.integer("window_samples")? as usize,
            motion: MotionConfig {
                accel_dev_mps2: breakpoints(p, "accel_dev_still_mps2", "accel_dev_moving_mps2")?,
                accel_activity_mps2: breakpoints(
                    p,
                    "accel_activity_still_mps2",
                    "accel_activity_moving_mps2",
                )?,
                gyro_activity_rad_per_s: Breakpoints {
                    still: rad(gyro.still),
                    moving: rad(gyro.moving),
                },
                resolution: p.integer("defuzzification_points")? as usize,
            },
            static_threshold: p.real("static_threshold")?,
            tilt_time_constant_s: p.real("tilt_time_constant_s")?,
            heading_time_constant_s: p.real("heading_time_constant_s")?,
            bias_time_constant_s: p.real("bias_time_constant_s")?,
            mag_min_coverage_deg: p.real("mag_min_coverage_deg")?,
            mag_inclination_rad: rad(p.real("mag_inclination_deg")?),
            mag_level_tolerance_rad: rad(p.real("mag_level_tolerance_deg")?),
            mag_refit_every: p.integer("mag_refit_every")? as u32,
            max_mag_age_s: p.real("max_mag_age_s")?,
            max_imu_gap_s: p.real("max_imu_gap_s")?,
        })
    }
}

/// What the engine has done with its readings.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct FuzzyStats {
    pub imu_used: u64,
    /// IMU readings at or before the newest one.
    pub imu_dropped: u64,
    /// Gaps longer than `max_imu_gap_s`.
    pub imu_gaps: u64,
    pub mag_used: u64,
    /// Calibration fits accepted.
    pub mag_fits: u64,
    /// Times the attitude became non-finite and alignment started again.
    pub resets: u64,
}

/// The attitude solution once aligned.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Solution {
    attitude: UnitQuaternion<f64>,
    gyro_bias_rad_per_s: V3,
    /// ‖f‖ at rest as this accelerometer reads it, m/s².
    static_gravity_mps2: f64,
    /// The previous bias-compensated rate (trapezoidal integration).
    previous_rate_rad_per_s: Option<V3>,
}

/// The `fuzzy` engine; see the module documentation.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FuzzyEngine {
    params: Params,
    #[serde(skip_serializing, default = "placeholder_config")]
    config: FuzzyConfig,
    #[serde(skip_serializing, default = "placeholder_expert")]
    expert: Mamdani,
    window: MotionWindow,
    newest_imu_t: Option<f64>,
    solution: Option<Solution>,
    calibration: MagCalibration,
    /// The newest magnetometer reading: time and raw field, µT.
    magnetometer: Option<(f64, V3)>,
    /// True heading (rad) from the newest magnetometer reading, calibrated
    /// and tilt-compensated with the tilt at its time; `None` before the
    /// calibration.
    compass: Option<(f64, f64)>,
    stats: FuzzyStats,
    /// Set by the first calibration: take the heading from the compass.
    reheading: bool,
    #[serde(skip)]
    scratch: Scratch,
}

/// Used only while deserialising; `restore` rebuilds it from `params`.
fn placeholder_config() -> FuzzyConfig {
    FuzzyConfig::from_params(&Params::defaults(PARAMS)).expect("default parameters are valid")
}

fn placeholder_expert() -> Mamdani {
    motion::motion_expert(&placeholder_config().motion).expect("the default rule base is valid")
}

impl FuzzyEngine {
    /// A fresh engine.
    pub fn new(params: Params) -> Result<FuzzyEngine, ParamError> {
        let config = FuzzyConfig::from_params(&params)?;
        let expert = motion::motion_expert(&config.motion)
            .map_err(|e| ParamError::Inconsistent(format!("motion rule base: {e}")))?;
        Ok(FuzzyEngine {
            params,
            config,
            expert,
            window: MotionWindow::new(config.window_samples),
            newest_imu_t: None,
            solution: None,
            calibration: MagCalibration::new(
                config.mag_min_coverage_deg,
                config.mag_inclination_rad,
                config.mag_level_tolerance_rad,
                config.mag_refit_every,
            ),
            magnetometer: None,
            compass: None,
            stats: FuzzyStats::default(),
            reheading: false,
            scratch: Scratch::default(),
        })
    }

    /// An engine with every parameter at its default.
    pub fn with_defaults() -> FuzzyEngine {
        FuzzyEngine::new(Params::defaults(PARAMS)).expect("default parameters are valid")
    }

    /// Continues from a snapshot taken by [`Engine::snapshot`].
    pub fn restore(snapshot: serde_json::Value) -> Result<FuzzyEngine, SnapshotError> {
        let engine: FuzzyEngine = SnapshotError::parse(EngineKind::Fuzzy, snapshot)?;
        let params = engine.params.revalidated(PARAMS)?;
        let mut fresh = FuzzyEngine::new(params)?;
        if engine.window.capacity() != fresh.config.window_samples {
            return Err(SnapshotError::Invalid(
                "motion window does not match the parameters".into(),
            ));
        }
        fresh.window = engine.window;
        fresh.newest_imu_t = engine.newest_imu_t;
        fresh.solution = engine.solution;
        fresh.calibration = engine.calibration;
        fresh.magnetometer = engine.magnetometer;
        fresh.compass = engine.compass;
        fresh.stats = engine.stats;
        fresh.reheading = engine.reheading;
        Ok(fresh)
    }

    /// The working configuration.
    pub fn config(&self) -> &FuzzyConfig {
        &self.config
    }

    /// What the engine has done with its readings.
    pub fn stats(&self) -> FuzzyStats {
        self.stats
    }

    /// The magnetometer calibration.
    pub fn calibration(&self) -> &MagCalibration {
        &self.calibration
    }

    fn feed_magnetometer(&mut self, t: f64, field_ut: V3) {
        self.stats.mag_used += 1;
        let (roll, pitch) = match &self.solution {
            Some(s) => {
                let (roll, pitch, _) = s.attitude.euler_angles();
                (roll, pitch)
            }
            None => tilt_from_accel(&self.window.mean_force()),
        };
        let was_calibrated = self.calibration.correction().is_some();
        if self.calibration.add(field_ut, roll.abs().max(pitch.abs())) {
            self.stats.mag_fits += 1;
            // The heading so far rests on the raw compass at alignment:
            // the first calibration replaces it at the next IMU reading.
            if !was_calibrated {
                self.reheading = true;
            }
        }
        if self.magnetometer.is_none_or(|(newest, _)| t >= newest) {
            self.magnetometer = Some((t, field_ut));
            self.compass = self.calibration.correction().map(|c| {
                (
                    t,
                    magnetic_heading(&c.apply(&field_ut), roll, pitch)
                        + self.config.declination_rad,
                )
            });
        }
    }

    /// The compass heading (rad) if its reading is young enough at `t`.
    fn fresh_compass(&self, t: f64) -> Option<f64> {
        self.compass
            .filter(|(mag_t, _)| (t - mag_t).abs() <= self.config.max_mag_age_s)
            .map(|(_, heading)| heading)
    }

    /// True heading (rad) at `t` from the newest magnetometer reading, for
    /// this tilt, calibrated if the calibration exists and raw if not: the
    /// best there is at alignment.
    fn any_compass_heading(&self, t: f64, roll: f64, pitch: f64) -> Option<f64> {
        let (_, field) = self
            .magnetometer
            .filter(|(mag_t, _)| (t - mag_t).abs() <= self.config.max_mag_age_s)?;
        let corrected = match self.calibration.correction() {
            Some(c) => c.apply(&field),
            None => field,
        };
        Some(magnetic_heading(&corrected, roll, pitch) + self.config.declination_rad)
    }

    fn feed_imu(&mut self, t: f64, force: V3, rate: V3, out: &mut Vec<EngineOutput>) {
        let dt_s = match self.newest_imu_t {
            Some(newest) if t <= newest => {
                self.stats.imu_dropped += 1;
                return;
            }
            Some(newest) => t - newest,
            None => f64::INFINITY,
        };
        self.newest_imu_t = Some(t);
        self.stats.imu_used += 1;
        let continuous = dt_s <= self.config.max_imu_gap_s;
        if !continuous {
            if dt_s.is_finite() {
                self.stats.imu_gaps += 1;
            }
            self.window.clear();
            if let Some(solution) = &mut self.solution {
                solution.previous_rate_rad_per_s = None;
            }
        }
        self.window.push(force, rate);

        if self.solution.is_none() {
            self.try_align(t);
        }
        let (bias, gravity) = match &self.solution {
            Some(s) => (s.gyro_bias_rad_per_s, s.static_gravity_mps2),
            None => (V3::zeros(), self.window.mean_force_norm()),
        };
        let signals = self.window.signals(gravity, &bias);
        let static_degree =
            motion::static_degree(&self.expert, &signals, &mut self.scratch).unwrap_or(0.0);

        if continuous && let Some(solution) = self.solution {
            let updated = self.advance(solution, t, dt_s, force, rate, static_degree);
            let finite = updated.attitude.coords.iter().all(|x| x.is_finite())
                && updated.gyro_bias_rad_per_s.iter().all(|x| x.is_finite());
            if finite {
                self.solution = Some(updated);
                if self.fresh_compass(t).is_some() {
                    self.reheading = false;
                }
            } else {
                self.stats.resets += 1;
                self.solution = None;
                self.window.clear();
            }
        }
        out.push(self.estimate(t, static_degree, &signals));
    }

    /// Aligns on a quiet full window.
    fn try_align(&mut self, t: f64) {
        let m = &self.config.motion;
        if !self.window.is_full() {
            return;
        }
        let signals = self
            .window
            .signals(self.window.mean_force_norm(), &V3::zeros());
        if signals.accel_activity_mps2 >= m.accel_activity_mps2.still
            || self.window.rate_spread() >= m.gyro_activity_rad_per_s.still
        {
            return;
        }
        let (roll, pitch) = tilt_from_accel(&self.window.mean_force());
        let yaw = self.any_compass_heading(t, roll, pitch).unwrap_or(0.0);
        self.solution = Some(Solution {
            attitude: attitude_from_euler(roll, pitch, yaw),
            gyro_bias_rad_per_s: self.window.mean_rate(),
            static_gravity_mps2: self.window.mean_force_norm(),
            previous_rate_rad_per_s: None,
        });
    }

    /// One step of the module documentation's steps 2–4.
    fn advance(
        &self,
        mut solution: Solution,
        t: f64,
        dt_s: f64,
        force: V3,
        rate: V3,
        static_degree: f64,
    ) -> Solution {
        let c = &self.config;
        let compensated = rate - solution.gyro_bias_rad_per_s;
        let mean_rate = match solution.previous_rate_rad_per_s {
            Some(previous) => (previous + compensated) * 0.5,
            None => compensated,
        };
        solution.attitude = integrate(&solution.attitude, &mean_rate, dt_s);
        solution.previous_rate_rad_per_s = Some(compensated);

        if static_degree > 0.0 {
            let (roll, pitch) = tilt_from_accel(&self.window.mean_force());
            solution.attitude = pull_tilt(
                &solution.attitude,
                roll,
                pitch,
                static_degree * dt_s / c.tilt_time_constant_s,
            );
        }
        if (static_degree > 0.0 || self.reheading)
            && let Some(heading) = self.fresh_compass(t)
        {
            let gain = if self.reheading {
                1.0
            } else {
                static_degree * dt_s / c.heading_time_constant_s
            };
            solution.attitude = pull_heading(&solution.attitude, heading, gain);
        }

        if static_degree > c.static_threshold {
            let weight = if c.static_threshold < 1.0 {
                (static_degree - c.static_threshold) / (1.0 - c.static_threshold)
            } else {
                1.0
            };
            let gain = (weight * dt_s / c.bias_time_constant_s).min(1.0);
            solution.gyro_bias_rad_per_s += (rate - solution.gyro_bias_rad_per_s) * gain;
            solution.static_gravity_mps2 += (force.norm() - solution.static_gravity_mps2) * gain;
        }
        solution
    }

    fn estimate(&self, t: f64, static_degree: f64, signals: &MotionSignals) -> EngineOutput {
        let (attitude, bias, aligned) = match &self.solution {
            Some(s) => (s.attitude, s.gyro_bias_rad_per_s, true),
            None => {
                let (roll, pitch) = tilt_from_accel(&self.window.mean_force());
                let yaw = self.any_compass_heading(t, roll, pitch).unwrap_or(0.0);
                (attitude_from_euler(roll, pitch, yaw), V3::zeros(), false)
            }
        };
        let (roll, pitch, yaw) = attitude.euler_angles();
        let correction = self.calibration.correction();
        EngineOutput {
            t,
            values: EstimateValues::Fuzzy(FuzzyEstimate {
                motion: if static_degree >= self.config.static_threshold {
                    Motion::Static
                } else {
                    Motion::Moving
                },
                static_degree,
                pitch_deg: deg(pitch),
                roll_deg: deg(roll),
                heading_deg: deg(yaw).rem_euclid(360.0),
                gyro_bias_dps: [deg(bias.x), deg(bias.y), deg(bias.z)],
                aligned,
                mag_calibration: self.calibration.state(),
                mag_coverage_deg: self.calibration.coverage_deg(),
                mag_fit_rms: correction.map(|c| c.fit_rms),
                mag_heading_deg: self.fresh_compass(t).map(|h| deg(h).rem_euclid(360.0)),
                accel_dev_mps2: signals.accel_dev_mps2,
                accel_activity_mps2: signals.accel_activity_mps2,
                gyro_activity_dps: deg(signals.gyro_activity_rad_per_s),
            }),
        }
    }
}

impl Engine for FuzzyEngine {
    fn kind(&self) -> EngineKind {
        EngineKind::Fuzzy
    }

    fn feed(&mut self, reading: &Reading, out: &mut Vec<EngineOutput>) {
        match &reading.data {
            SensorData::Imu {
                accel_mps2,
                gyro_dps,
            } => {
                let force = V3::from(*accel_mps2);
                let rate = V3::new(rad(gyro_dps[0]), rad(gyro_dps[1]), rad(gyro_dps[2]));
                self.feed_imu(reading.t, force, rate, out);
            }
            SensorData::Magnetometer { field_ut } => {
                self.feed_magnetometer(reading.t, V3::from(*field_ut));
            }
            _ => {}
        }
    }

    fn params(&self) -> &Params {
        &self.params
    }

    fn snapshot(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }

    fn model(&self) -> Option<serde_json::Value> {
        let correction = self.calibration.correction();
        Some(serde_json::json!({
            "engine": "fuzzy",
            "mag_calibration": self.calibration.state(),
            "mag_coverage_deg": self.calibration.coverage_deg(),
            "hard_iron_ut": correction.map(|c| [c.hard_iron_ut.x, c.hard_iron_ut.y, c.hard_iron_ut.z]),
            "soft_iron": correction.map(|c| {
                [0, 1, 2].map(|i| [c.soft_iron[(i, 0)], c.soft_iron[(i, 1)], c.soft_iron[(i, 2)]])
            }),
            "fit_rms": correction.map(|c| c.fit_rms),
            "stats": self.stats,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const G: f64 = 9.81;

    fn imu(t: f64, force: V3, rate_dps: V3) -> Reading {
        Reading {
            t,
            data: SensorData::Imu {
                accel_mps2: [force.x, force.y, force.z],
                gyro_dps: [rate_dps.x, rate_dps.y, rate_dps.z],
            },
        }
    }

    fn mag(t: f64, field: V3) -> Reading {
        Reading {
            t,
            data: SensorData::Magnetometer {
                field_ut: [field.x, field.y, field.z],
            },
        }
    }

    fn fuzzy(output: &EngineOutput) -> &FuzzyEstimate {
        output.values.as_fuzzy().unwrap()
    }

    /// A still, tilted IMU with a constant gyro bias, and its compass.
    fn still(seconds: f64, bias_dps: V3) -> Vec<Reading> {
        let attitude = attitude_from_euler(rad(1.5), rad(-2.0), rad(40.0));
        let force = attitude.inverse() * V3::new(0.0, 0.0, -G);
        let field = attitude.inverse() * V3::new(20.0, 0.0, 44.0);
        let mut readings = Vec::new();
        for i in 0..(seconds * 100.0) as usize {
            let t = 1.7e9 + i as f64 * 0.01;
            readings.push(imu(t, force, bias_dps));
            if i % 10 == 0 {
                readings.push(mag(t, field));
            }
        }
        readings
    }

    #[test]
    fn still_platform_aligns_levels_and_learns_the_bias() {
        let bias = V3::new(0.4, -0.3, 0.25);
        let mut engine = FuzzyEngine::with_defaults();
        let mut out = Vec::new();
        for r in &still(30.0, bias) {
            engine.feed(r, &mut out);
        }
        assert_eq!(out.len(), 3000);
        let first = fuzzy(&out[0]);
        assert!(!first.aligned);
        let last = fuzzy(out.last().unwrap());
        assert!(last.aligned);
        assert_eq!(last.motion, Motion::Static);
        assert!((last.static_degree - 1.0).abs() < 1e-9);
        assert!((last.roll_deg - 1.5).abs() < 1e-6, "{}", last.roll_deg);
        assert!((last.pitch_deg + 2.0).abs() < 1e-6, "{}", last.pitch_deg);
        // Uncalibrated compass at alignment: the undistorted field here.
        assert!(
            (last.heading_deg - 40.0).abs() < 1e-6,
            "{}",
            last.heading_deg
        );
        for (k, b) in bias.iter().enumerate() {
            assert!((last.gyro_bias_dps[k] - b).abs() < 1e-9);
        }
        assert_eq!(last.mag_calibration, magcal::CalibrationState::Collecting);
    }

    #[test]
    fn a_turn_is_moving_and_integrated_without_euler_rates() {
        let mut engine = FuzzyEngine::with_defaults();
        let mut out = Vec::new();
        for r in &still(5.0, V3::zeros()) {
            engine.feed(r, &mut out);
        }
        // Level turn at 30 °/s for 3 s about the body z axis while tilted:
        // the heading changes by about 90° and the tilt stays.
        let attitude0 = attitude_from_euler(rad(1.5), rad(-2.0), rad(40.0));
        let mut attitude = attitude0;
        let rate_n = V3::new(0.0, 0.0, rad(30.0));
        let t0 = 1.7e9 + 5.0;
        for i in 0..300 {
            let t = t0 + i as f64 * 0.01;
            attitude = UnitQuaternion::from_scaled_axis(rate_n * 0.01) * attitude;
            let rate_b = attitude.inverse() * rate_n;
            let force = attitude.inverse() * V3::new(0.0, 0.0, -G);
            engine.feed(&imu(t, force, rate_b.map(deg)), &mut out);
        }
        let last = fuzzy(out.last().unwrap());
        assert_eq!(last.motion, Motion::Moving);
        // The rate jumps from 0 to 30 °/s in one step: the trapezoid gives
        // that step half, so the engine is 0.15° behind this truth.
        let (roll, pitch, yaw) = attitude.euler_angles();
        let heading_error = last.heading_deg - deg(yaw).rem_euclid(360.0);
        assert!((heading_error + 0.15).abs() < 0.01, "{heading_error}");
        assert!((last.roll_deg - deg(roll)).abs() < 0.01);
        assert!((last.pitch_deg - deg(pitch)).abs() < 0.01);
    }

    #[test]
    fn snapshot_and_restore_continue_exactly() {
        let readings = still(12.0, V3::new(0.1, 0.2, -0.3));
        let mut whole = FuzzyEngine::with_defaults();
        let mut expected = Vec::new();
        for r in &readings {
            whole.feed(r, &mut expected);
        }
        let mut first = FuzzyEngine::with_defaults();
        let mut got = Vec::new();
        for r in &readings[..700] {
            first.feed(r, &mut got);
        }
        let text = serde_json::to_string(&first.snapshot()).unwrap();
        let mut second = FuzzyEngine::restore(serde_json::from_str(&text).unwrap()).unwrap();
        for r in &readings[700..] {
            second.feed(r, &mut got);
        }
        assert_eq!(got, expected);
    }

    #[test]
    fn breakpoints_out_of_order_are_refused() {
        let params = Params::from_assignments(PARAMS, ["gyro_activity_still_dps=2"]);
        let err = params
            .and_then(FuzzyEngine::new)
            .expect_err("still above moving is refused");
        assert!(
            err.to_string().contains("gyro_activity_moving_dps"),
            "{err}"
        );
    }

    #[test]
    fn wild_readings_leave_every_estimate_finite() {
        let mut engine = FuzzyEngine::with_defaults();
        let mut out = Vec::new();
        for r in &still(3.0, V3::zeros()) {
            engine.feed(r, &mut out);
        }
        for i in 0..2000 {
            let x = f64::from(i);
            let t = 1.7e9 + 3.0 + x * 0.01;
            let force = V3::new(150.0 * (x * 0.37).sin(), -150.0, 150.0 * (x * 1.1).cos());
            engine.feed(
                &imu(t, force, V3::new(2000.0, -2000.0, 1999.0 * x.sin())),
                &mut out,
            );
            engine.feed(&mag(t, V3::new(1e4 * x.cos(), -1e4, 0.0)), &mut out);
        }
        for o in &out {
            let f = fuzzy(o);
            assert!(f.pitch_deg.is_finite() && f.roll_deg.is_finite() && f.heading_deg.is_finite());
            assert!((0.0..=1.0).contains(&f.static_degree));
        }
    }
}
