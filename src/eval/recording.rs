//! `eval recording`: the `fuzzy` engine on recorded trials with optical
//! truth, in the shape of BROAD (Berlin Robust Orientation estimation
//! Assessment Dataset, Laidig et al. 2021, CC BY 4.0): a hand-held MEMS IMU
//! and magnetometer at 2000/7 ≈ 285.7 Hz, optical motion capture as truth.
//!
//! # Input
//! A directory made by `tools/broad_to_csv.py`: one CSV per trial with the
//! header `t_s,ax,ay,az,gx,gy,gz,mx,my,mz,qw,qx,qy,qz` (seconds; m/s², rad/s,
//! µT in the sensor's frame; truth quaternion `nan` where the cameras saw
//! nothing) and a `manifest.json` naming the trials with their rate and
//! the sample ranges BROAD scores (`movement`). Without a manifest every
//! `*.csv` is a trial, scored wherever it has truth.
//!
//! # Frames (verified on the data: `tests/recordings.rs`)
//! BROAD's sensor frame has z up (a flat sensor reads +9.8 m/s² on z) and
//! its truth is the sensor-to-ENU rotation, the ENU frame aligned to
//! magnetic north. Ours: body x forward, y right, z down; attitude
//! body-to-NED. So every sensor vector maps (x, y, z) → (x, −y, −z) (a half
//! turn about x, [`SENSOR_FROM_BODY`]), and the truth becomes
//! q_NED←body = q_NED←ENU ⊗ q_ENU←sensor ⊗ q_sensor←body, q_NED←ENU being
//! the half turn about (1, 1, 0)/√2 that swaps east and north and flips up.
//!
//! # Scores (over the `movement` samples that have truth)
//! With the error in the Earth frame, q_e = q_est ⊗ q_true⁻¹ (BROAD's
//! `calculateErrorQuatEarth`):
//! - tilt ("inclination") error: the angle between the true and the
//!   estimated direction of gravity in the body, 2 acos √(w² + z²);
//! - heading error: q_e's turn about the vertical, 2 atan2(z, w), after
//!   removing the trial's constant heading offset δ between the reference
//!   frame and the estimator's north, δ the circular mean of that turn over
//!   the scored samples (the reference turned by δ about the vertical).
//!   BROAD's own code removes nothing (its reference is already aligned to
//!   magnetic north); that variant is kept as `heading_raw_deg`;
//! - total error: the whole angle of q_e, 2 acos |w|, after (and, `raw`,
//!   before) the same offset removal.
//!
//! Each trial gives RMSEs; pooled figures are their mean over trials
//! (BROAD's averaging, and the independent evaluation's) and their RMS
//! over trials.
//!
//! # Estimators
//! - the `fuzzy` engine, fed each sample's magnetometer reading and then
//!   its IMU reading (t = [`EPOCH_T_S`] + t_s), attitude rebuilt from the
//!   estimate's roll, pitch and heading;
//! - gyro only: the gyros integrated (q ← q ⊗ exp(ω̄ dt), ω̄ the mean of
//!   the step's two samples) from the true attitude at the first sample
//!   with truth, raw and with the mean rate of the initial rest (before the
//!   first movement sample) subtracted;
//! - accelerometer + compass per sample, no memory: tilt from the specific
//!   force, heading from the raw (uncalibrated: BROAD's field is already
//!   calibrated) magnetometer levelled with that tilt. What a static
//!   solution gives while the sensor moves;
//! - Madgwick's MARG filter ([`crate::eval::ahrs::Madgwick`]) started, as
//!   BROAD starts it, from the first sample's accelerometer and
//!   magnetometer, over a grid of β ([`MADGWICK_BETAS`]): reported at the
//!   common default β = 0.041 rad/s and at the β with the lowest mean raw
//!   total error over the trials (BROAD's criterion for its "TAGP"; tuned
//!   with the truth: a bound, not a setting a user could know).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::ErrorStats;
use super::ahrs::{Madgwick, initial_attitude};
use crate::fusion::angles::{deg, rad};
use crate::fusion::fuzzy::{FuzzyEngine, FuzzyParams};
use crate::fusion::params::TypedParams;
use crate::fusion::{
    Engine, EngineKind, EngineOutput, FuzzyEstimate, Motion, ParamError, Params, Reading,
    SensorData,
};

type V3 = Vector3<f64>;

/// Readings carry t = `EPOCH_T_S` + the trial's seconds (2020-09-13), so
/// they are valid protocol times.
pub const EPOCH_T_S: f64 = 1_600_000_000.0;
/// Inclination of the Earth's field in Berlin (WMM: about 68°, down).
pub const BERLIN_INCLINATION_DEG: f64 = 68.0;
/// The motion expert's window, seconds (docs/engines/fuzzy.md: "keep the window at about
/// half a second").
pub const WINDOW_S: f64 = 0.5;
/// The CSV header.
pub const COLUMNS: [&str; 14] = [
    "t_s", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz", "qw", "qx", "qy", "qz",
];
/// A truth quaternion whose norm is further than this from 1 is refused.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// q_sensor←body: a half turn about x, (x, y, z)_body → (x, −y, −z)_sensor.
pub const SENSOR_FROM_BODY: Quaternion<f64> = Quaternion::new(0.0, 1.0, 0.0, 0.0);

/// q_NED←ENU: the half turn about (1, 1, 0)/√2 (east ↔ north, up → −down).
pub fn ned_from_enu() -> UnitQuaternion<f64> {
    let s = std::f64::consts::FRAC_1_SQRT_2;
    UnitQuaternion::new_unchecked(Quaternion::new(0.0, s, s, 0.0))
}

/// A BROAD sensor-frame vector (z up) in our body frame (z down).
pub fn body_from_sensor(v: &V3) -> V3 {
    V3::new(v.x, -v.y, -v.z)
}

/// BROAD's truth (sensor-to-ENU) as our body-to-NED attitude.
pub fn ned_attitude_from_broad(q_enu_sensor: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    ned_from_enu() * q_enu_sensor * UnitQuaternion::new_unchecked(SENSOR_FROM_BODY)
}

/// One sample of a trial, in our conventions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Seconds from the start of the trial.
    pub t_s: f64,
    /// Specific force, body frame (z down), m/s².
    pub accel_mps2: V3,
    /// Angular rate, body frame, rad/s.
    pub gyro_rad_per_s: V3,
    /// Magnetic field, body frame, µT.
    pub field_ut: V3,
    /// True body-to-NED attitude, where the optical system had one.
    pub truth: Option<UnitQuaternion<f64>>,
}

impl Sample {
    /// The sample as the engine's readings: magnetometer, then IMU.
    pub fn readings(&self) -> [Reading; 2] {
        let t = EPOCH_T_S + self.t_s;
        let g = self.gyro_rad_per_s;
        [
            Reading {
                t,
                data: SensorData::Magnetometer {
                    field_ut: self.field_ut.into(),
                },
            },
            Reading {
                t,
                data: SensorData::Imu {
                    accel_mps2: self.accel_mps2.into(),
                    gyro_dps: [deg(g.x), deg(g.y), deg(g.z)],
                },
            },
        ]
    }
}

/// Why a recording could not be read or evaluated. Every variant names
/// the file; parse errors name the line (1-based, the header is line 1)
/// and the column.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}, line {line}, column `{column}`: {message}", path.display())]
    Parse {
        path: PathBuf,
        line: usize,
        column: String,
        message: String,
    },
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    #[error(transparent)]
    Params(#[from] ParamError),
}

fn parse_error(path: &Path, line: usize, column: &str, message: String) -> RecordingError {
    RecordingError::Parse {
        path: path.to_path_buf(),
        line,
        column: column.to_string(),
        message,
    }
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> RecordingError + '_ {
    move |source| RecordingError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Reads one trial's CSV into samples in our conventions.
pub fn load_csv(path: &Path) -> Result<Vec<Sample>, RecordingError> {
    let text = std::fs::read_to_string(path).map_err(io_error(path))?;
    parse_csv(path, &text)
}

/// Parses a trial's CSV text (`path` only names it in errors).
pub fn parse_csv(path: &Path, text: &str) -> Result<Vec<Sample>, RecordingError> {
    let mut lines = text.lines().enumerate();
    let header: Vec<&str> = match lines.next() {
        Some((_, h)) => h.split(',').map(str::trim).collect(),
        None => {
            return Err(RecordingError::Invalid {
                path: path.to_path_buf(),
                message: "empty file (expected a header)".into(),
            });
        }
    };
    if header != COLUMNS {
        return Err(parse_error(
            path,
            1,
            "header",
            format!(
                "expected `{}`, found `{}`",
                COLUMNS.join(","),
                header.join(",")
            ),
        ));
    }
    let mut samples = Vec::with_capacity(text.len() / 120);
    let mut values = [0.0_f64; 14];
    for (index, line) in lines {
        let line_no = index + 1;
        if line.trim().is_empty() {
            continue;
        }
        let mut count = 0;
        for (k, field) in line.split(',').enumerate() {
            let Some(column) = COLUMNS.get(k) else {
                return Err(parse_error(
                    path,
                    line_no,
                    "-",
                    format!("more than {} fields", COLUMNS.len()),
                ));
            };
            let field = field.trim();
            values[k] = field.parse::<f64>().map_err(|_| {
                parse_error(path, line_no, column, format!("`{field}` is not a number"))
            })?;
            if k < 10 && !values[k].is_finite() {
                return Err(parse_error(
                    path,
                    line_no,
                    column,
                    format!("`{field}`: sensor values and time must be finite"),
                ));
            }
            count += 1;
        }
        if count != COLUMNS.len() {
            return Err(parse_error(
                path,
                line_no,
                COLUMNS[count.min(COLUMNS.len() - 1)],
                format!("{count} fields, expected {}", COLUMNS.len()),
            ));
        }
        if let Some(previous) = samples.last().map(|s: &Sample| s.t_s)
            && values[0] <= previous
        {
            return Err(parse_error(
                path,
                line_no,
                "t_s",
                format!("time {} does not follow {previous}", values[0]),
            ));
        }
        let v = |k: usize| V3::new(values[k], values[k + 1], values[k + 2]);
        samples.push(Sample {
            t_s: values[0],
            accel_mps2: body_from_sensor(&v(1)),
            gyro_rad_per_s: body_from_sensor(&v(4)),
            field_ut: body_from_sensor(&v(7)),
            truth: truth_from_row(path, line_no, &values[10..14])?,
        });
    }
    if samples.is_empty() {
        return Err(RecordingError::Invalid {
            path: path.to_path_buf(),
            message: "no samples".into(),
        });
    }
    Ok(samples)
}

fn truth_from_row(
    path: &Path,
    line: usize,
    wxyz: &[f64],
) -> Result<Option<UnitQuaternion<f64>>, RecordingError> {
    let finite = wxyz.iter().filter(|x| x.is_finite()).count();
    if finite == 0 {
        return Ok(None);
    }
    if let Some(k) = wxyz.iter().position(|x| !x.is_finite()) {
        return Err(parse_error(
            path,
            line,
            COLUMNS[10 + k],
            "truth quaternion partly missing (all four or none)".into(),
        ));
    }
    let q = Quaternion::new(wxyz[0], wxyz[1], wxyz[2], wxyz[3]);
    if (q.norm() - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(parse_error(
            path,
            line,
            "qw",
            format!("truth quaternion norm {} is not 1", q.norm()),
        ));
    }
    Ok(Some(ned_attitude_from_broad(
        &UnitQuaternion::from_quaternion(q),
    )))
}

/// One trial as the manifest lists it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrialInfo {
    pub name: String,
    /// The CSV, relative to the directory in the manifest.
    pub file: PathBuf,
    /// Sampling rate, Hz; from the time stamps when absent.
    #[serde(default)]
    pub rate_hz: Option<f64>,
    #[serde(default)]
    pub groups: Vec<String>,
    #[serde(default)]
    pub source: String,
    /// Scored sample ranges [first, end); every sample with truth when absent.
    #[serde(default)]
    pub movement: Option<Vec<[usize; 2]>>,
}

#[derive(Debug, Deserialize)]
struct Manifest {
    trials: Vec<TrialInfo>,
}

/// The trials of a directory: those of its `manifest.json`, else every
/// `*.csv` in name order. File paths come back joined to `dir`.
pub fn list_trials(dir: &Path) -> Result<Vec<TrialInfo>, RecordingError> {
    let manifest_path = dir.join("manifest.json");
    let mut trials = if manifest_path.exists() {
        let text = std::fs::read_to_string(&manifest_path).map_err(io_error(&manifest_path))?;
        let manifest: Manifest =
            serde_json::from_str(&text).map_err(|e| RecordingError::Invalid {
                path: manifest_path.clone(),
                message: e.to_string(),
            })?;
        manifest.trials
    } else {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io_error(dir))?
            .filter_map(|entry| entry.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "csv"))
            .collect();
        files.sort();
        files
            .into_iter()
            .map(|file| TrialInfo {
                name: file
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default(),
                file,
                rate_hz: None,
                groups: Vec::new(),
                source: String::new(),
                movement: None,
            })
            .collect()
    };
    if trials.is_empty() {
        return Err(RecordingError::Invalid {
            path: dir.to_path_buf(),
            message: "no trials (expected manifest.json or *.csv files)".into(),
        });
    }
    for t in &mut trials {
        if t.file.is_relative() {
            t.file = dir.join(&t.file);
        }
    }
    Ok(trials)
}

/// The sampling rate of a directory's recordings, Hz: the manifest's
/// (median over trials), else from the first trial's time stamps.
pub fn recording_rate_hz(dir: &Path) -> Result<f64, RecordingError> {
    let trials = list_trials(dir)?;
    let mut rates: Vec<f64> = trials.iter().filter_map(|t| t.rate_hz).collect();
    if rates.is_empty() {
        let samples = load_csv(&trials[0].file)?;
        return rate_from_times(&trials[0].file, &samples);
    }
    rates.sort_by(f64::total_cmp);
    Ok(rates[rates.len() / 2])
}

fn rate_from_times(path: &Path, samples: &[Sample]) -> Result<f64, RecordingError> {
    match (samples.first(), samples.last()) {
        (Some(a), Some(b)) if samples.len() > 1 => Ok((samples.len() - 1) as f64 / (b.t_s - a.t_s)),
        _ => Err(RecordingError::Invalid {
            path: path.to_path_buf(),
            message: "one sample gives no rate".into(),
        }),
    }
}

/// The engine's parameters as docs/engines/fuzzy.md tells an installer to set them
/// for this recording: defaults, `window_samples` half a second of samples
/// at `rate_hz`, `mag_inclination_deg` for Berlin (declination left at 0:
/// the heading offset is removed), then `assignments` (`name=value`) on top.
pub fn installer_params(rate_hz: f64, assignments: &[&str]) -> Result<Params, ParamError> {
    let window = (WINDOW_S * rate_hz).round().max(2.0);
    let base = [
        format!("window_samples={window}"),
        format!("mag_inclination_deg={BERLIN_INCLINATION_DEG}"),
    ];
    EngineKind::Fuzzy.params_from_assignments(
        base.iter()
            .map(String::as_str)
            .chain(assignments.iter().copied()),
    )
}

/// The kind of trial, from its name (BROAD's disturbance groups).
pub fn trial_group(name: &str) -> &'static str {
    const GROUPS: [(&str, &str); 7] = [
        ("undisturbed", "undisturbed"),
        ("tapping", "tapping"),
        ("vibration", "vibration"),
        ("stationary_magnet", "stationary magnet"),
        ("attached_magnet", "attached magnet"),
        ("office", "office"),
        ("mixed", "mixed"),
    ];
    GROUPS
        .iter()
        .find(|(key, _)| name.contains(key))
        .map_or("other", |(_, group)| group)
}

/// RMS errors of one estimator on one trial (or pooled), degrees.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct OrientationErrors {
    /// Angle between the true and estimated gravity directions.
    pub tilt_deg: f64,
    /// Heading error after removing the constant offset.
    pub heading_deg: f64,
    /// Whole rotation error after removing the constant offset.
    pub total_deg: f64,
    /// Heading and total error without removing it (BROAD's definition).
    pub heading_raw_deg: f64,
    pub total_raw_deg: f64,
    /// The removed offset: estimator's north minus the reference's,
    /// clockwise, degrees (`null` when pooled).
    pub heading_offset_deg: Option<f64>,
}

/// Collects the Earth-frame error quaternions of one estimator on one trial.
#[derive(Debug, Clone, Default)]
pub struct ErrorSeries {
    errors: Vec<UnitQuaternion<f64>>,
}

impl ErrorSeries {
    /// Adds one estimate against the truth.
    pub fn add(&mut self, estimate: &UnitQuaternion<f64>, truth: &UnitQuaternion<f64>) {
        self.errors.push(estimate * truth.inverse());
    }

    /// Number of samples scored.
    pub fn len(&self) -> usize {
        self.errors.len()
    }

    /// True when nothing was scored.
    pub fn is_empty(&self) -> bool {
        self.errors.is_empty()
    }

    /// The RMS errors, the heading offset removed as the module explains.
    pub fn summary(&self) -> OrientationErrors {
        if self.errors.is_empty() {
            return OrientationErrors {
                tilt_deg: f64::NAN,
                heading_deg: f64::NAN,
                total_deg: f64::NAN,
                heading_raw_deg: f64::NAN,
                total_raw_deg: f64::NAN,
                heading_offset_deg: None,
            };
        }
        let (mut sin, mut cos) = (0.0, 0.0);
        for q in &self.errors {
            let turn = heading_turn(q);
            sin += turn.sin();
            cos += turn.cos();
        }
        let offset = f64::atan2(sin, cos);
        let unturn = UnitQuaternion::from_axis_angle(&V3::z_axis(), -offset);
        let mut sums = [0.0_f64; 5];
        for q in &self.errors {
            let turn = heading_turn(q);
            let corrected = q * unturn;
            let e = [
                tilt_error(q),
                wrap(turn - offset),
                corrected.angle(),
                wrap(turn),
                q.angle(),
            ];
            for (s, x) in sums.iter_mut().zip(e) {
                *s += x * x;
            }
        }
        let rms = |s: f64| deg((s / self.errors.len() as f64).sqrt());
        OrientationErrors {
            tilt_deg: rms(sums[0]),
            heading_deg: rms(sums[1]),
            total_deg: rms(sums[2]),
            heading_raw_deg: rms(sums[3]),
            total_raw_deg: rms(sums[4]),
            heading_offset_deg: Some(deg(offset)),
        }
    }
}

/// The signed turn of an Earth-frame error about the vertical, rad.
pub fn heading_turn(error: &UnitQuaternion<f64>) -> f64 {
    let q = error.quaternion();
    let s = if q.w < 0.0 { -1.0 } else { 1.0 };
    wrap(2.0 * f64::atan2(s * q.k, s * q.w))
}

/// The angle between the directions of gravity an Earth-frame error
/// relates, rad: 2 acos √(w² + z²).
pub fn tilt_error(error: &UnitQuaternion<f64>) -> f64 {
    let q = error.quaternion();
    2.0 * (q.w * q.w + q.k * q.k).sqrt().min(1.0).acos()
}

fn wrap(angle: f64) -> f64 {
    let a = (angle + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU);
    a - std::f64::consts::PI
}

/// `attitude` turned by the body rate `rate_rad_per_s` held over `dt_s`
/// (the engine's own integration step: this is a baseline of it).
pub use crate::fusion::fuzzy::orientation::integrate as integrate_rate;

/// Attitude from one sample's specific force and field alone (body-to-NED,
/// yaw from the field's north): roll = atan2(−f_y, −f_z), pitch =
/// atan2(f_x, √(f_y² + f_z²)), yaw = atan2(−h_y, h_x) with h the field
/// turned level by that roll and pitch.
pub fn accel_compass_attitude(force_mps2: &V3, field_ut: &V3) -> UnitQuaternion<f64> {
    let f = force_mps2;
    let roll = (-f.y).atan2(-f.z);
    let pitch = f.x.atan2(f.y.hypot(f.z));
    let level = UnitQuaternion::from_euler_angles(roll, pitch, 0.0) * field_ut;
    UnitQuaternion::from_euler_angles(roll, pitch, (-level.y).atan2(level.x))
}

/// Gyro-only integration from a first attitude, with a fixed bias removed.
#[derive(Debug, Clone)]
struct GyroOnly {
    bias: V3,
    state: Option<(f64, V3, UnitQuaternion<f64>)>,
}

impl GyroOnly {
    fn new(bias: V3) -> GyroOnly {
        GyroOnly { bias, state: None }
    }

    /// The attitude at `sample`, starting from its truth at the first
    /// sample that has one.
    fn step(&mut self, sample: &Sample) -> Option<UnitQuaternion<f64>> {
        let rate = sample.gyro_rad_per_s - self.bias;
        let next = match (self.state, sample.truth) {
            (Some((t, previous, q)), _) => {
                integrate_rate(&q, &((previous + rate) * 0.5), sample.t_s - t)
            }
            (None, Some(truth)) => truth,
            (None, None) => return None,
        };
        self.state = Some((sample.t_s, rate, next));
        Some(next)
    }
}

/// What the engine did on a trial (the reasons behind its errors).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct EngineDiagnostics {
    /// Seconds from the trial's start to the first aligned estimate.
    pub aligned_after_s: Option<f64>,
    /// Share of the scored samples whose estimate was aligned.
    pub aligned_share: f64,
    /// Seconds to the first magnetometer calibration, and the state at the end.
    pub calibrated_after_s: Option<f64>,
    /// Azimuth coverage and fit residual reported when it first calibrated.
    pub coverage_at_calibration_deg: Option<f64>,
    pub fit_rms_at_calibration: Option<f64>,
    pub final_calibration: String,
    /// Magnetometer calibrations that changed the state's kind (planar ↔
    /// ellipsoid ↔ collecting), a sign of refits on changing data.
    pub calibration_changes: u64,
    pub final_mag_coverage_deg: f64,
    pub final_mag_fit_rms: Option<f64>,
    /// Means of the expert's inputs over the initial rest (before the
    /// first movement sample, after one full window) and over the scored samples.
    pub rest: ExpertInputs,
    pub moving: ExpertInputs,
    /// Largest |engine gyro bias − initial-rest mean rate| at the end, °/s.
    pub final_bias_error_dps: f64,
    /// Heading RMSE, degrees, over the scored samples with the truth's
    /// |pitch| < 60°: of the engine's own compass (`mag_heading_deg`:
    /// its calibration and its tilt), and of the raw field levelled with
    /// the true tilt (the field's own disturbance). Against the reference
    /// as it is (already aligned to magnetic north), no offset removed.
    pub engine_compass_rmse_deg: Option<f64>,
    pub raw_compass_true_tilt_rmse_deg: Option<f64>,
}

/// Mean motion-expert inputs and the share of `static` calls.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ExpertInputs {
    pub samples: u64,
    pub accel_dev_mps2: f64,
    pub accel_activity_mps2: f64,
    pub gyro_activity_dps: f64,
    pub static_share: f64,
}

#[derive(Debug, Clone, Copy, Default)]
struct ExpertSums {
    n: u64,
    dev: f64,
    activity: f64,
    gyro: f64,
    statics: u64,
}

impl ExpertSums {
    fn add(&mut self, e: &FuzzyEstimate) {
        self.n += 1;
        self.dev += e.accel_dev_mps2;
        self.activity += e.accel_activity_mps2;
        self.gyro += e.gyro_activity_dps;
        self.statics += u64::from(e.motion == Motion::Static);
    }

    fn mean(&self) -> ExpertInputs {
        let n = self.n.max(1) as f64;
        ExpertInputs {
            samples: self.n,
            accel_dev_mps2: self.dev / n,
            accel_activity_mps2: self.activity / n,
            gyro_activity_dps: self.gyro / n,
            static_share: self.statics as f64 / n,
        }
    }
}

/// Madgwick's β tried, rad/s; the common default first.
pub const MADGWICK_BETAS: [f64; 12] = [
    0.041, 0.005, 0.01, 0.02, 0.03, 0.06, 0.08, 0.1, 0.12, 0.15, 0.2, 0.3,
];
/// The β commonly used as a default, rad/s.
pub const MADGWICK_DEFAULT_BETA: f64 = 0.041;

/// The estimators compared, in table order.
pub const ENGINE: &str = "fuzzy engine";
pub const GYRO_RAW: &str = "gyro only, raw";
pub const GYRO_REST_BIAS: &str = "gyro only, rest bias";
pub const ACCEL_COMPASS: &str = "accel + compass";
pub const MADGWICK_DEFAULT: &str = "Madgwick β=0.041";
pub const MADGWICK_TUNED: &str = "Madgwick, tuned with truth";

/// One trial's scores.
#[derive(Debug, Clone, Serialize)]
pub struct TrialEvaluation {
    pub name: String,
    pub group: String,
    pub source: String,
    pub rate_hz: f64,
    pub samples: u64,
    pub duration_s: f64,
    /// Samples in the movement phase with truth: those scored.
    pub scored: u64,
    /// Errors per estimator (names as in [`RecordingEvaluation::methods`]).
    pub errors: BTreeMap<String, OrientationErrors>,
    /// Madgwick's errors for each β of [`MADGWICK_BETAS`].
    pub madgwick_grid: Vec<(f64, OrientationErrors)>,
    pub engine: EngineDiagnostics,
}

/// Pooled errors of every estimator over a set of trials.
#[derive(Debug, Clone, Serialize)]
pub struct GroupSummary {
    pub group: String,
    pub trials: usize,
    /// Mean over the trials of each RMSE (BROAD's averaging).
    pub mean: BTreeMap<String, OrientationErrors>,
    /// RMS over the trials of each RMSE.
    pub rms: BTreeMap<String, OrientationErrors>,
}

/// The whole evaluation of a directory of recordings.
#[derive(Debug, Clone, Serialize)]
pub struct RecordingEvaluation {
    pub dir: PathBuf,
    pub params: Params,
    /// Estimator names in table order.
    pub methods: Vec<String>,
    /// The β of the "tuned with truth" Madgwick row: lowest mean raw total error.
    pub madgwick_tuned_beta: f64,
    pub trials: Vec<TrialEvaluation>,
    /// "all" first, then each group in the order trials name them.
    pub groups: Vec<GroupSummary>,
}

/// Runs every trial of `dir` through the engine (with `params`, see
/// [`installer_params`]) and the baselines, and scores them.
pub fn evaluate_recording(
    dir: &Path,
    params: &Params,
) -> Result<RecordingEvaluation, RecordingError> {
    let infos = list_trials(dir)?;
    let mut trials = Vec::with_capacity(infos.len());
    for info in &infos {
        let samples = load_csv(&info.file)?;
        trials.push(evaluate_trial(info, &samples, params)?);
    }
    let madgwick_tuned_beta = best_beta(&trials);
    for t in &mut trials {
        let pick = |beta: f64| {
            t.madgwick_grid
                .iter()
                .find(|(b, _)| *b == beta)
                .map(|(_, e)| *e)
        };
        if let (Some(default), Some(tuned)) =
            (pick(MADGWICK_DEFAULT_BETA), pick(madgwick_tuned_beta))
        {
            t.errors.insert(MADGWICK_DEFAULT.to_string(), default);
            t.errors.insert(MADGWICK_TUNED.to_string(), tuned);
        }
    }
    let methods: Vec<String> = [
        ENGINE,
        GYRO_RAW,
        GYRO_REST_BIAS,
        ACCEL_COMPASS,
        MADGWICK_DEFAULT,
        MADGWICK_TUNED,
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let groups = summarise(&trials, &methods);
    Ok(RecordingEvaluation {
        dir: dir.to_path_buf(),
        params: params.clone(),
        methods,
        madgwick_tuned_beta,
        trials,
        groups,
    })
}

/// The β of [`MADGWICK_BETAS`] with the lowest mean raw total error over
/// trials (BROAD's choice of its common parameters).
fn best_beta(trials: &[TrialEvaluation]) -> f64 {
    let mean_total = |beta: f64| {
        let totals: Vec<f64> = trials
            .iter()
            .flat_map(|t| t.madgwick_grid.iter().filter(|(b, _)| *b == beta))
            .map(|(_, e)| e.total_raw_deg)
            .collect();
        totals.iter().sum::<f64>() / totals.len().max(1) as f64
    };
    MADGWICK_BETAS
        .into_iter()
        .min_by(|a, b| mean_total(*a).total_cmp(&mean_total(*b)))
        .unwrap_or(MADGWICK_DEFAULT_BETA)
}

/// Scores one trial's samples.
pub fn evaluate_trial(
    info: &TrialInfo,
    samples: &[Sample],
    params: &Params,
) -> Result<TrialEvaluation, RecordingError> {
    let rate_hz = match info.rate_hz {
        Some(r) => r,
        None => rate_from_times(&info.file, samples)?,
    };
    let scored_mask = movement_mask(info, samples);
    let rest_end = info
        .movement
        .as_ref()
        .and_then(|m| m.first().map(|r| r[0]))
        .unwrap_or(0)
        .min(samples.len());
    let rest_bias = if rest_end > 0 {
        samples[..rest_end]
            .iter()
            .map(|s| s.gyro_rad_per_s)
            .sum::<V3>()
            / rest_end as f64
    } else {
        V3::zeros()
    };

    let mut engine = FuzzyEngine::new(params.clone())?;
    let window = FuzzyParams::from_params(params)?.window_samples;
    let mut out: Vec<EngineOutput> = Vec::with_capacity(4);
    let mut engine_errors = ErrorSeries::default();
    let mut gyro_raw = (GyroOnly::new(V3::zeros()), ErrorSeries::default());
    let mut gyro_rest = (GyroOnly::new(rest_bias), ErrorSeries::default());
    let mut accel_compass = ErrorSeries::default();
    let mut madgwick: Vec<(f64, Option<Madgwick>, ErrorSeries)> = MADGWICK_BETAS
        .iter()
        .map(|b| (*b, None, ErrorSeries::default()))
        .collect();
    let mut previous_t = None;
    let mut diagnostics = EngineDiagnostics::default();
    let (mut rest_sums, mut moving_sums) = (ExpertSums::default(), ExpertSums::default());
    let mut aligned_scored = 0u64;
    let mut last_calibration = None;
    let (mut engine_compass, mut raw_compass) = (ErrorStats::default(), ErrorStats::default());
    let mut last: Option<FuzzyEstimate> = None;
    let t0 = samples.first().map_or(0.0, |s| s.t_s);

    for (i, sample) in samples.iter().enumerate() {
        out.clear();
        for reading in sample.readings() {
            engine.feed(&reading, &mut out);
        }
        let estimate = out.iter().rev().find_map(|o| o.values.as_fuzzy()).cloned();
        let gyro = [gyro_raw.0.step(sample), gyro_rest.0.step(sample)];
        for (beta, filter, _) in &mut madgwick {
            match (filter.as_mut(), previous_t) {
                (Some(f), Some(t)) => f.update(
                    &sample.gyro_rad_per_s,
                    &sample.accel_mps2,
                    Some(&sample.field_ut),
                    sample.t_s - t,
                ),
                _ => {
                    let start = initial_attitude(&sample.accel_mps2, Some(&sample.field_ut));
                    *filter = Some(Madgwick::new(*beta, start));
                }
            }
        }
        previous_t = Some(sample.t_s);
        let Some(estimate) = estimate else { continue };
        let since_start = sample.t_s - t0;
        if estimate.aligned {
            diagnostics.aligned_after_s.get_or_insert(since_start);
        }
        let calibration = estimate.mag_calibration.as_str();
        if calibration != "collecting" && diagnostics.calibrated_after_s.is_none() {
            diagnostics.calibrated_after_s = Some(since_start);
            diagnostics.coverage_at_calibration_deg = Some(estimate.mag_coverage_deg);
            diagnostics.fit_rms_at_calibration = estimate.mag_fit_rms;
        }
        if last_calibration.is_some_and(|c| c != calibration) {
            diagnostics.calibration_changes += 1;
        }
        last_calibration = Some(calibration);
        if i < rest_end && i >= window {
            rest_sums.add(&estimate);
        }
        if scored_mask[i]
            && let Some(truth) = sample.truth
        {
            moving_sums.add(&estimate);
            let (roll, pitch, yaw) = truth.euler_angles();
            if pitch.abs() < rad(60.0) {
                if let Some(h) = estimate.mag_heading_deg {
                    engine_compass.add(deg(wrap(rad(h) - yaw)));
                }
                let level = UnitQuaternion::from_euler_angles(roll, pitch, 0.0) * sample.field_ut;
                raw_compass.add(deg(wrap((-level.y).atan2(level.x) - yaw)));
            }
            aligned_scored += u64::from(estimate.aligned);
            engine_errors.add(&estimated_attitude(&estimate), &truth);
            accel_compass.add(
                &accel_compass_attitude(&sample.accel_mps2, &sample.field_ut),
                &truth,
            );
            for (_, filter, series) in &mut madgwick {
                if let Some(f) = filter {
                    series.add(&f.attitude(), &truth);
                }
            }
            for (series, attitude) in [&mut gyro_raw.1, &mut gyro_rest.1].into_iter().zip(gyro) {
                if let Some(q) = attitude {
                    series.add(&q, &truth);
                }
            }
        }
        last = Some(estimate);
    }

    let scored = engine_errors.len() as u64;
    diagnostics.aligned_share = aligned_scored as f64 / scored.max(1) as f64;
    diagnostics.rest = rest_sums.mean();
    diagnostics.moving = moving_sums.mean();
    let rmse = |e: ErrorStats| (e.count > 0).then(|| e.rmse());
    diagnostics.engine_compass_rmse_deg = rmse(engine_compass);
    diagnostics.raw_compass_true_tilt_rmse_deg = rmse(raw_compass);
    if let Some(e) = &last {
        diagnostics.final_calibration = e.mag_calibration.as_str().to_string();
        diagnostics.final_mag_coverage_deg = e.mag_coverage_deg;
        diagnostics.final_mag_fit_rms = e.mag_fit_rms;
        diagnostics.final_bias_error_dps = (0..3)
            .map(|k| (e.gyro_bias_dps[k] - deg(rest_bias[k])).abs())
            .fold(0.0, f64::max);
    }
    let mut errors = BTreeMap::new();
    errors.insert(ENGINE.to_string(), engine_errors.summary());
    errors.insert(GYRO_RAW.to_string(), gyro_raw.1.summary());
    errors.insert(GYRO_REST_BIAS.to_string(), gyro_rest.1.summary());
    errors.insert(ACCEL_COMPASS.to_string(), accel_compass.summary());
    Ok(TrialEvaluation {
        name: info.name.clone(),
        group: trial_group(&info.name).to_string(),
        source: info.source.clone(),
        rate_hz,
        samples: samples.len() as u64,
        duration_s: samples.last().map_or(0.0, |s| s.t_s) - t0,
        scored,
        errors,
        madgwick_grid: madgwick
            .iter()
            .map(|(beta, _, series)| (*beta, series.summary()))
            .collect(),
        engine: diagnostics,
    })
}

/// Which samples are scored: the manifest's movement ranges, or all.
fn movement_mask(info: &TrialInfo, samples: &[Sample]) -> Vec<bool> {
    match &info.movement {
        None => vec![true; samples.len()],
        Some(ranges) => {
            let mut mask = vec![false; samples.len()];
            for [first, end] in ranges {
                let end = (*end).min(samples.len());
                for m in mask.iter_mut().take(end).skip(*first) {
                    *m = true;
                }
            }
            mask
        }
    }
}

/// The engine's attitude rebuilt from its estimate (declination 0, so the
/// heading is the yaw from magnetic north).
pub fn estimated_attitude(e: &FuzzyEstimate) -> UnitQuaternion<f64> {
    UnitQuaternion::from_euler_angles(rad(e.roll_deg), rad(e.pitch_deg), rad(e.heading_deg))
}

/// Mean and RMS over trials of each estimator's RMSEs, for all trials and
/// per group.
fn summarise(trials: &[TrialEvaluation], methods: &[String]) -> Vec<GroupSummary> {
    let mut names: Vec<String> = vec!["all".to_string()];
    for t in trials {
        if !names.contains(&t.group) {
            names.push(t.group.clone());
        }
    }
    names
        .into_iter()
        .map(|group| {
            let members: Vec<&TrialEvaluation> = trials
                .iter()
                .filter(|t| group == "all" || t.group == group)
                .collect();
            let (mut mean, mut rms) = (BTreeMap::new(), BTreeMap::new());
            for m in methods {
                let per_trial: Vec<OrientationErrors> = members
                    .iter()
                    .filter_map(|t| t.errors.get(m).copied())
                    .collect();
                mean.insert(m.clone(), pool(&per_trial, Pooling::Mean));
                rms.insert(m.clone(), pool(&per_trial, Pooling::Rms));
            }
            GroupSummary {
                group,
                trials: members.len(),
                mean,
                rms,
            }
        })
        .collect()
}

/// How per-trial RMSEs are pooled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pooling {
    Mean,
    Rms,
}

/// Each figure pooled over trials (trials without a figure left out).
pub fn pool(trials: &[OrientationErrors], how: Pooling) -> OrientationErrors {
    let rms = |f: fn(&OrientationErrors) -> f64| {
        let values: Vec<f64> = trials.iter().map(f).filter(|x| x.is_finite()).collect();
        let n = values.len() as f64;
        match how {
            _ if values.is_empty() => f64::NAN,
            Pooling::Mean => values.iter().sum::<f64>() / n,
            Pooling::Rms => (values.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
        }
    };
    OrientationErrors {
        tilt_deg: rms(|e| e.tilt_deg),
        heading_deg: rms(|e| e.heading_deg),
        total_deg: rms(|e| e.total_deg),
        heading_raw_deg: rms(|e| e.heading_raw_deg),
        total_raw_deg: rms(|e| e.total_raw_deg),
        heading_offset_deg: None,
    }
}

/// The evaluation as text: pooled errors per group and estimator, then
/// one line per trial with the engine's diagnostics.
pub fn render_table(e: &RecordingEvaluation) -> String {
    let mut text = String::new();
    let param = |name: &str| {
        e.params
            .values()
            .get(name)
            .map_or("?".to_string(), |v| v.to_string())
    };
    text.push_str(&format!(
        "{} trials in {}; engine window_samples={}, mag_inclination_deg={}; Madgwick tuned with truth: β={}\n",
        e.trials.len(),
        e.dir.display(),
        param("window_samples"),
        param("mag_inclination_deg"),
        e.madgwick_tuned_beta,
    ));
    text.push_str(
        "RMSE over the movement phases, degrees, pooled as BROAD does (mean over trials; \
         last column: RMS over trials); heading and total after removing each trial's mean \
         heading offset, raw: without\n",
    );
    let cell = |x: f64| {
        if x.is_finite() {
            format!("{x:8.2}")
        } else {
            "       —".to_string()
        }
    };
    text.push_str(&format!(
        "{:<24} {:<27} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}\n",
        "group (trials)", "estimator", "tilt", "heading", "total", "head.raw", "tot.raw", "rms tot"
    ));
    for g in &e.groups {
        for (k, m) in e.methods.iter().enumerate() {
            let Some(r) = g.mean.get(m) else { continue };
            let rms_total = g.rms.get(m).map_or(f64::NAN, |r| r.total_deg);
            let label = if k == 0 {
                format!("{} ({})", g.group, g.trials)
            } else {
                String::new()
            };
            text.push_str(&format!(
                "{label:<24} {m:<27} {} {} {} {} {} {}\n",
                cell(r.tilt_deg),
                cell(r.heading_deg),
                cell(r.total_deg),
                cell(r.heading_raw_deg),
                cell(r.total_raw_deg),
                cell(rms_total),
            ));
        }
    }
    text.push_str("\nper trial: total RMSE per estimator; the engine's tilt, heading (offset) and what it did\n");
    text.push_str(&format!("{:<46}", "trial"));
    for m in &e.methods {
        text.push_str(&format!(" {:>8}", abbreviate(m)));
    }
    text.push_str(&format!(
        " {:>6} {:>15} {:>7} {:>17} {:>13} {:>17} {:>17}\n",
        "tilt",
        "heading(offset)",
        "aligned",
        "calibrated(cover)",
        "compass e/raw",
        "rest act/gyr/st",
        "moving act/gyr/st"
    ));
    for t in &e.trials {
        text.push_str(&format!("{:<46}", t.name));
        for m in &e.methods {
            text.push_str(&format!(
                " {}",
                cell(t.errors.get(m).map_or(f64::NAN, |r| r.total_deg))
            ));
        }
        let d = &t.engine;
        let ours = t.errors.get(ENGINE).copied().unwrap_or_default();
        let seconds = |s: Option<f64>| s.map_or("never".to_string(), |s| format!("{s:.1} s"));
        text.push_str(&format!(
            " {:6.2} {:>15} {:>7} {:>17} {:>13} {:>17} {:>17}\n",
            ours.tilt_deg,
            format!(
                "{:.2} ({:+.1})",
                ours.heading_deg,
                ours.heading_offset_deg.unwrap_or(f64::NAN)
            ),
            seconds(d.aligned_after_s),
            format!(
                "{} {} ({:.0})",
                short_state(&d.final_calibration),
                seconds(d.calibrated_after_s),
                d.coverage_at_calibration_deg.unwrap_or(f64::NAN)
            ),
            format!(
                "{:.0}/{:.0}",
                d.engine_compass_rmse_deg.unwrap_or(f64::NAN),
                d.raw_compass_true_tilt_rmse_deg.unwrap_or(f64::NAN)
            ),
            expert(&d.rest),
            expert(&d.moving),
        ));
    }
    text
}

fn abbreviate(method: &str) -> String {
    match method {
        ENGINE => "engine".into(),
        GYRO_RAW => "gyro raw".into(),
        GYRO_REST_BIAS => "gyro bias".into(),
        ACCEL_COMPASS => "acc+mag".into(),
        MADGWICK_DEFAULT => "mw 0.041".into(),
        MADGWICK_TUNED => "mw tuned".into(),
        other => other.chars().take(8).collect(),
    }
}

fn short_state(state: &str) -> &str {
    match state {
        "collecting" => "coll",
        "planar" => "plan",
        "ellipsoid" => "ell",
        other => other,
    }
}

fn expert(e: &ExpertInputs) -> String {
    if e.samples == 0 {
        "—".to_string()
    } else {
        format!(
            "{:.3}/{:.2}/{:.0}%",
            e.accel_activity_mps2,
            e.gyro_activity_dps,
            100.0 * e.static_share
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str = "t_s,ax,ay,az,gx,gy,gz,mx,my,mz,qw,qx,qy,qz";

    fn parse(text: &str) -> Result<Vec<Sample>, RecordingError> {
        parse_csv(Path::new("trial.csv"), text)
    }

    #[test]
    fn a_flat_sensor_reads_our_level_body() {
        let text = format!(
            "{HEADER}\n0,0,0,9.81,0.1,0.2,0.3,20,0,-44,1,0,0,0\n0.01,0,0,9.81,0,0,0,20,0,-44,nan,nan,nan,nan\n"
        );
        let samples = parse(&text).unwrap();
        assert_eq!(samples.len(), 2);
        let s = samples[0];
        assert_eq!(s.accel_mps2, V3::new(0.0, 0.0, -9.81));
        assert_eq!(s.gyro_rad_per_s, V3::new(0.1, -0.2, -0.3));
        assert_eq!(s.field_ut, V3::new(20.0, 0.0, 44.0));
        // Flat, x east in ENU: in NED the body points east (yaw 90°), level.
        let (roll, pitch, yaw) = s.truth.unwrap().euler_angles();
        assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12, "{roll} {pitch}");
        assert!((deg(yaw) - 90.0).abs() < 1e-9, "{}", deg(yaw));
        assert!(samples[1].truth.is_none());
    }

    #[test]
    fn truth_and_sensors_agree_for_any_attitude() {
        // A sensor at attitude q (sensor-to-ENU) reads the ENU "up" as
        // specific force and the ENU field in its own frame; mapped, both
        // must match our body-to-NED truth.
        let q_enu = UnitQuaternion::from_euler_angles(0.3, -0.7, 2.1);
        let up_sensor = q_enu.inverse() * V3::new(0.0, 0.0, 9.81);
        let field_enu = V3::new(0.5, 18.0, -42.0);
        let field_sensor = q_enu.inverse() * field_enu;
        let q = ned_attitude_from_broad(&q_enu);
        let force = body_from_sensor(&up_sensor);
        assert!((q * force - V3::new(0.0, 0.0, -9.81)).norm() < 1e-9);
        let field_ned = q * body_from_sensor(&field_sensor);
        assert!((field_ned - V3::new(18.0, 0.5, 42.0)).norm() < 1e-9);
    }

    #[test]
    fn accelerometer_and_compass_recover_an_attitude() {
        let q = UnitQuaternion::from_euler_angles(-0.4, 0.9, -2.5);
        let force = q.inverse() * V3::new(0.0, 0.0, -9.81);
        let field = q.inverse() * V3::new(18.0, 0.0, 42.0);
        assert!(accel_compass_attitude(&force, &field).angle_to(&q) < 1e-9);
    }

    #[test]
    fn errors_name_file_line_and_column() {
        let bad_number = format!(
            "{HEADER}\n0,0,0,9.81,0,0,0,20,0,-44,1,0,0,0\n0.1,0,x,9.81,0,0,0,20,0,-44,1,0,0,0\n"
        );
        let message = parse(&bad_number).unwrap_err().to_string();
        assert_eq!(
            message,
            "trial.csv, line 3, column `ay`: `x` is not a number"
        );
        let short = format!("{HEADER}\n0,0,0,9.81,0,0,0,20,0,-44,1,0\n");
        let message = parse(&short).unwrap_err().to_string();
        assert!(
            message.contains("line 2") && message.contains("12 fields"),
            "{message}"
        );
        let nan_sensor = format!("{HEADER}\n0,0,0,9.81,nan,0,0,20,0,-44,1,0,0,0\n");
        let message = parse(&nan_sensor).unwrap_err().to_string();
        assert!(message.contains("column `gx`"), "{message}");
        let half_truth = format!("{HEADER}\n0,0,0,9.81,0,0,0,20,0,-44,1,0,nan,0\n");
        let message = parse(&half_truth).unwrap_err().to_string();
        assert!(message.contains("column `qy`"), "{message}");
        let backwards = format!(
            "{HEADER}\n1,0,0,9.81,0,0,0,20,0,-44,1,0,0,0\n0.5,0,0,9.81,0,0,0,20,0,-44,1,0,0,0\n"
        );
        let message = parse(&backwards).unwrap_err().to_string();
        assert!(message.contains("line 3, column `t_s`"), "{message}");
        let header = "t,ax\n0,1\n";
        let message = parse(header).unwrap_err().to_string();
        assert!(message.contains("line 1, column `header`"), "{message}");
        assert!(parse("").is_err());
        assert!(parse(&format!("{HEADER}\n")).is_err());
    }

    #[test]
    fn heading_offset_is_removed_and_tilt_kept() {
        // Estimates off by a constant 10° of heading plus a 2° tilt on half
        // the samples: heading error 0 once the offset goes, tilt 2° RMS √½.
        let mut series = ErrorSeries::default();
        for k in 0..100 {
            let truth = UnitQuaternion::from_euler_angles(0.1, 0.2, 0.03 * f64::from(k));
            let tilt = if k % 2 == 0 { rad(2.0) } else { 0.0 };
            // Tilted about the Earth's north axis, turned about its vertical.
            let estimate = UnitQuaternion::from_axis_angle(&V3::z_axis(), rad(10.0))
                * UnitQuaternion::from_axis_angle(&V3::x_axis(), tilt)
                * truth;
            series.add(&estimate, &truth);
        }
        let e = series.summary();
        assert!((e.heading_offset_deg.unwrap() - 10.0).abs() < 1e-9, "{e:?}");
        assert!((e.tilt_deg - 2.0 / 2f64.sqrt()).abs() < 1e-9, "{e:?}");
        assert!(e.heading_deg < 1e-9, "{e:?}");
        assert!((e.total_deg - 2.0 / 2f64.sqrt()).abs() < 1e-9, "{e:?}");
        assert!((e.heading_raw_deg - 10.0).abs() < 1e-9, "{e:?}");
    }

    #[test]
    fn installer_parameters_follow_the_rate() {
        let p = installer_params(2000.0 / 7.0, &["tilt_time_constant_s=8"]).unwrap();
        assert_eq!(p.real("window_samples").unwrap(), 143.0);
        assert_eq!(p.real("mag_inclination_deg").unwrap(), 68.0);
        assert_eq!(p.real("tilt_time_constant_s").unwrap(), 8.0);
        let p = installer_params(100.0, &["window_samples=20"]).unwrap();
        assert_eq!(p.real("window_samples").unwrap(), 20.0);
        assert!(installer_params(100.0, &["no_such=1"]).is_err());
    }
}
