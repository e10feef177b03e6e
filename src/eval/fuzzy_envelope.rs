//! `eval fuzzy --envelope`: the `fuzzy` engine over drives drawn from the
//! whole envelope (`simulate vehicle --envelope`, issue 34), beside fair
//! baselines run on the same readings.
//!
//! The engine is set up as an installer would: the site's declination and
//! inclination, and a window of half a second of readings (these replace
//! any `--param` given for them). The baselines:
//! - `madgwick`: Madgwick's MARG filter with β = [`MADGWICK_BETA`] (the
//!   value his report derives for MARG), fed the magnetometer **calibrated
//!   with the truth's own hard and soft iron**, m_c = S⁻¹(m − b);
//! - `vqf`: VQF (Laidig and Seel 2023) with its defaults, the best open
//!   filter (issue 55), fed the same calibrated magnetometer;
//! - `mahony`: Mahony's complementary filter (k_P 0.5, k_I 0.05), fed the
//!   same calibrated magnetometer;
//! - `gyro`: the gyros integrated from the true initial attitude, their
//!   bias the mean of the parked start (none when the drive starts rolling).
//!
//! All start at the first reading (the filters from that reading's force
//! and field). Scores per drive:
//! - motion status: the share of IMU readings from the first full window
//!   on whose `motion` matches the truth (rolling or turning: moving;
//!   standing, swaying or not: static);
//! - pitch and roll RMSE from [`SCORE_FROM_S`] on; the drive's tilt RMSE
//!   is the larger of the two;
//! - heading RMSE from the reading at which the vehicle has turned through
//!   [`TURNED_FOR_HEADING_DEG`] (the true heading's unwrapped range; a
//!   magnetometer cannot be calibrated before the vehicle has turned;
//!   none of the baselines needs to, since they are given the
//!   calibration), and the largest error;
//! - the engine's 2σ coverage: the share of scored estimates with |error|
//!   ≤ 2σ (`pitch_sigma_deg`, `roll_sigma_deg`, `heading_sigma_deg`); an
//!   estimate without a σ counts as not covered.

use serde::Serialize;

use super::ahrs::{Madgwick, Mahony, Vqf, initial_attitude};
use super::attitude::Spread;
use super::integrity::{self, FaultSummary, IntegrityScore};
use super::{Bar, ErrorStats, parallel_map};
use crate::fusion::angles::{deg, rad};
use crate::fusion::fuzzy::PARAMS;
use crate::fusion::fuzzy::orientation::{angle_difference, integrate};
use crate::fusion::geometry::{V3, attitude_from_euler};
use crate::fusion::{EngineKind, EngineOutput, Motion, ParamError, ParamValue, Params, SensorData};
use crate::sim::faults::{FAULT_AT, FaultInjector, FaultKind, FaultWindow};
use crate::sim::vehicle::{VehicleDrive, VehicleScenario, VehicleTruth};
use crate::sim::vehicle_envelope::{VehicleCategory, VehicleEnvelope};

/// Madgwick's β for MARG, rad/s: √(3/4)·ω̃ with a gyro error ω̃ of
/// 2.7 °/s (Madgwick 2010, section 7).
pub const MADGWICK_BETA: f64 = 0.041;
/// The Mahony baseline's gains, as in `eval fuzzy`.
const MAHONY_KP: f64 = 0.5;
const MAHONY_KI: f64 = 0.05;
/// Tilt is scored from this many seconds after the first reading.
pub const SCORE_FROM_S: f64 = 10.0;
/// Heading is scored once the vehicle has turned through this much,
/// degrees (issue 55: a calibration from 90° of turning).
pub const TURNED_FOR_HEADING_DEG: f64 = 90.0;
/// Issue 55's bars on every drive: heading RMSE (drives that turned
/// [`TURNED_FOR_HEADING_DEG`]) and tilt RMSE, degrees.
pub const MAX_HEADING_RMSE_DEG: f64 = 4.0;
pub const MAX_TILT_RMSE_DEG: f64 = 1.0;
/// The engine's window: half a second of readings (docs/engines/fuzzy.md).
const WINDOW_S: f64 = 0.5;
/// The methods, in table order.
pub const METHODS: [&str; 5] = ["engine", "madgwick", "vqf", "mahony", "gyro"];

/// One method's errors on one drive, degrees.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct MethodScores {
    pub pitch_rmse_deg: f64,
    pub roll_rmse_deg: f64,
    /// NaN when the drive never turned enough to score heading.
    pub heading_rmse_deg: f64,
    pub heading_max_deg: f64,
}

impl MethodScores {
    /// The larger of pitch and roll RMSE.
    pub fn tilt_rmse_deg(&self) -> f64 {
        self.pitch_rmse_deg.max(self.roll_rmse_deg)
    }
}

/// Scored estimates and how many of them 2σ covered: pitch, roll, heading.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Coverage {
    pub estimates: [u64; 3],
    pub covered: [u64; 3],
    /// Estimates without a σ (counted as not covered).
    pub without_sigma: [u64; 3],
}

impl Coverage {
    fn add(&mut self, k: usize, error_deg: f64, sigma_deg: Option<f64>) {
        self.estimates[k] += 1;
        match sigma_deg {
            Some(sigma) => self.covered[k] += u64::from(error_deg.abs() <= 2.0 * sigma),
            None => self.without_sigma[k] += 1,
        }
    }

    /// The shares covered (NaN where nothing was scored).
    pub fn shares(&self) -> [f64; 3] {
        std::array::from_fn(|k| self.covered[k] as f64 / self.estimates[k] as f64)
    }

    fn merge(&mut self, other: &Coverage) {
        for k in 0..3 {
            self.estimates[k] += other.estimates[k];
            self.covered[k] += other.covered[k];
            self.without_sigma[k] += other.without_sigma[k];
        }
    }
}

/// Everything measured on one drive.
#[derive(Debug, Clone, Serialize)]
pub struct DriveScores {
    pub seed: u64,
    pub scenario: VehicleScenario,
    pub duration_s: f64,
    /// Share of readings with the right motion status, and the share of
    /// moving readings called static (and the reverse).
    pub motion_accuracy: f64,
    pub moving_called_static: f64,
    pub static_called_moving: f64,
    /// Seconds to the engine's alignment; `None`: never.
    pub aligned_after_s: Option<f64>,
    /// Seconds to the engine's first calibration; `None`: never.
    pub calibrated_after_s: Option<f64>,
    /// Seconds from which heading is scored; `None`: never.
    pub heading_scored_from_s: Option<f64>,
    /// Per method, in [`METHODS`] order.
    pub methods: Vec<MethodScores>,
    pub coverage: Coverage,
    /// The engine's integrity against its errors (eval/integrity.rs):
    /// misleading is a tilt error beyond 5σ and [`TILT_FLOOR_DEG`], or a
    /// scored heading error beyond 5σ and [`HEADING_FLOOR_DEG`].
    pub integrity: IntegrityScore,
    /// The fault injected, if any.
    pub fault: Option<FaultKind>,
    /// The category the drive was drawn in.
    pub category: VehicleCategory,
}

/// A tilt error is misleading beyond this, degrees (and 5σ).
pub const TILT_FLOOR_DEG: f64 = 1.0;
/// A heading error is misleading beyond this, degrees (and 5σ).
pub const HEADING_FLOOR_DEG: f64 = 4.0;

impl DriveScores {
    /// The scores of the method called `label`.
    pub fn method(&self, label: &str) -> Option<&MethodScores> {
        METHODS
            .iter()
            .position(|m| *m == label)
            .and_then(|i| self.methods.get(i))
    }
}

#[derive(Default)]
struct Errors {
    pitch: ErrorStats,
    roll: ErrorStats,
    heading: ErrorStats,
}

impl Errors {
    fn scores(&self) -> MethodScores {
        let rmse = |e: &ErrorStats| if e.count == 0 { f64::NAN } else { e.rmse() };
        MethodScores {
            pitch_rmse_deg: rmse(&self.pitch),
            roll_rmse_deg: rmse(&self.roll),
            heading_rmse_deg: rmse(&self.heading),
            heading_max_deg: if self.heading.count == 0 {
                f64::NAN
            } else {
                self.heading.max_abs
            },
        }
    }
}

/// Signed heading error, degrees, the short way round.
fn heading_error_deg(estimate_deg: f64, truth_deg: f64) -> f64 {
    deg(angle_difference(rad(estimate_deg), rad(truth_deg)))
}

/// The engine's parameters for a drive: `params`, then what an installer
/// sets for the site and the IMU rate.
pub fn installer_params(scenario: &VehicleScenario, params: &Params) -> Result<Params, ParamError> {
    let window = (WINDOW_S * scenario.imu_rate_hz).round().max(2.0);
    params.with_overrides(
        PARAMS,
        [
            ("declination_deg", scenario.declination_deg),
            ("mag_inclination_deg", scenario.inclination_deg),
            ("window_samples", window),
        ]
        .map(|(name, value)| (name.to_string(), ParamValue::Number(value))),
    )
}

/// Runs one envelope drive through the engine and the baselines.
pub fn evaluate_drive(seed: u64, params: &Params) -> Result<DriveScores, ParamError> {
    evaluate_drive_with(seed, params, None, VehicleCategory::Ordinary)
}

/// Like [`evaluate_drive`], with a fault injected, drawn in a category.
pub fn evaluate_drive_with(
    seed: u64,
    params: &Params,
    fault: Option<FaultKind>,
    category: VehicleCategory,
) -> Result<DriveScores, ParamError> {
    let mut scenario = VehicleEnvelope::draw_in(seed, category).scenario;
    let window =
        fault.map(|kind| FaultWindow::in_drive(kind, scenario.start_t, scenario.duration_s));
    let mut injector = window
        .map(|w| FaultInjector::new(w, EngineKind::Fuzzy))
        .transpose()
        .map_err(|e| ParamError::Inconsistent(e.to_string()))?;
    if injector.as_ref().is_some_and(FaultInjector::by_simulator) {
        // A power cycle: the simulator's IMU comes up with a new turn-on
        // bias.
        scenario.power_cycles_s = vec![FAULT_AT * scenario.duration_s];
    }
    let mut engine = EngineKind::Fuzzy.create(installer_params(&scenario, params)?)?;
    let drive = VehicleDrive::new(scenario.clone()).map_err(ParamError::Inconsistent)?;
    let declination = rad(scenario.declination_deg);
    let calibration = scenario.iron.map(|iron| {
        let soft = nalgebra::Matrix3::from_fn(|i, j| iron.soft_iron[i][j]);
        let inverse = soft
            .try_inverse()
            .unwrap_or_else(nalgebra::Matrix3::identity);
        (inverse, V3::from(iron.hard_iron_ut))
    });
    let calibrate = |m: V3| match &calibration {
        Some((inverse, hard)) => inverse * (m - hard),
        None => m,
    };
    let parked_s = scenario.manoeuvres.map_or(0.0, |m| m.parked_start_s);
    let window_s = WINDOW_S;

    let mut out: Vec<EngineOutput> = Vec::with_capacity(2);
    let mut errors: Vec<Errors> = METHODS.iter().map(|_| Errors::default()).collect();
    let mut coverage = Coverage::default();
    let mut integrity = IntegrityScore::with_fault(window);
    let (mut right, mut total) = (0u64, 0u64);
    let (mut moving, mut moving_as_static, mut still, mut still_as_moving) = (0u64, 0, 0u64, 0);
    let (mut aligned_after, mut calibrated_after, mut heading_from) = (None, None, None);
    // The true heading unwrapped, and its range so far.
    let mut turned: Option<(f64, f64, f64)> = None;
    let mut field: Option<V3> = None;
    let mut filters: Option<(Madgwick, Vqf, Mahony)> = None;
    let mut gyro: Option<nalgebra::UnitQuaternion<f64>> = None;
    let (mut bias_sum, mut bias_n) = (V3::zeros(), 0u32);
    let mut previous: Option<(f64, V3)> = None;
    let start_t = scenario.start_t;

    for event in drive {
        let reading = match &mut injector {
            Some(injector) => injector.apply(event.reading),
            None => event.reading,
        };
        let (
            SensorData::Imu {
                accel_mps2,
                gyro_dps,
            },
            Some(truth),
        ) = (&reading.data, event.truth)
        else {
            if let SensorData::Magnetometer { field_ut } = &reading.data {
                let calibrated = calibrate(V3::from(*field_ut));
                if let Some((_, vqf, _)) = &mut filters {
                    vqf.update_mag(&calibrated);
                }
                field = Some(calibrated);
            }
            engine.feed(&reading, &mut out);
            continue;
        };
        out.clear();
        engine.feed(&reading, &mut out);
        let s = reading.t - start_t;
        let force = V3::from(*accel_mps2);
        let rate = V3::from(*gyro_dps).map(rad);
        // The baselines.
        let dt = previous.map_or(0.0, |(t, _)| reading.t - t);
        match &mut filters {
            Some((madgwick, vqf, mahony)) => {
                madgwick.update(&rate, &force, field.as_ref(), dt);
                vqf.update_imu(&rate, &force, dt);
                mahony.update(&rate, &force, field.as_ref(), dt);
            }
            None => {
                let q = initial_attitude(&force, field.as_ref());
                let mut vqf = Vqf::new(1.0 / scenario.imu_rate_hz, 1.0 / scenario.mag_rate_hz);
                vqf.update_imu(&rate, &force, 0.0);
                if let Some(field) = &field {
                    vqf.update_mag(field);
                }
                filters = Some((
                    Madgwick::new(MADGWICK_BETA, q),
                    vqf,
                    Mahony::new(MAHONY_KP, MAHONY_KI, q),
                ));
            }
        }
        let true_attitude = attitude_from_euler(
            rad(truth.roll_deg),
            rad(truth.pitch_deg),
            rad(truth.heading_deg) - declination,
        );
        if s < parked_s {
            bias_sum += rate;
            bias_n += 1;
        }
        let bias = if bias_n > 0 {
            bias_sum / f64::from(bias_n)
        } else {
            V3::zeros()
        };
        let q = gyro.get_or_insert(true_attitude);
        if let Some((t, previous_rate)) = previous {
            *q = integrate(q, &((previous_rate + rate) * 0.5 - bias), reading.t - t);
        }
        previous = Some((reading.t, rate));

        let Some(output) = out.last() else {
            continue;
        };
        let Some(estimate) = output.values.as_fuzzy() else {
            continue;
        };
        if estimate.aligned {
            aligned_after.get_or_insert(s);
        }
        if estimate.mag_calibration != crate::fusion::fuzzy::magcal::CalibrationState::Collecting {
            calibrated_after.get_or_insert(s);
        }
        if s >= window_s {
            score_motion(estimate.motion, &truth, &mut right, &mut total);
            if truth.moving {
                moving += 1;
                moving_as_static += u64::from(estimate.motion == Motion::Static);
            } else {
                still += 1;
                still_as_moving += u64::from(estimate.motion == Motion::Moving);
            }
        }
        let (unwrapped, lowest, highest) = match turned {
            None => (truth.heading_deg, truth.heading_deg, truth.heading_deg),
            Some((last, lowest, highest)) => {
                let now = last + heading_error_deg(truth.heading_deg, last);
                (now, lowest.min(now), highest.max(now))
            }
        };
        turned = Some((unwrapped, lowest, highest));
        if heading_from.is_none() && highest - lowest >= TURNED_FOR_HEADING_DEG {
            heading_from = Some(s);
        }
        if s < SCORE_FROM_S {
            continue;
        }
        let score_heading = heading_from.is_some();
        let (Some((madgwick, vqf, mahony)), Some(gyro_q)) = (&filters, &gyro) else {
            continue;
        };
        let attitudes = [
            madgwick.attitude(),
            vqf.attitude(),
            mahony.attitude(),
            *gyro_q,
        ];
        for (k, q) in attitudes.iter().enumerate() {
            let (roll, pitch, yaw) = q.euler_angles();
            let e = &mut errors[k + 1];
            e.pitch.add(deg(pitch) - truth.pitch_deg);
            e.roll.add(deg(roll) - truth.roll_deg);
            if score_heading {
                e.heading
                    .add(heading_error_deg(deg(yaw + declination), truth.heading_deg));
            }
        }
        let pitch_error = estimate.pitch_deg - truth.pitch_deg;
        let roll_error = estimate.roll_deg - truth.roll_deg;
        errors[0].pitch.add(pitch_error);
        errors[0].roll.add(roll_error);
        coverage.add(0, pitch_error, estimate.pitch_sigma_deg);
        coverage.add(1, roll_error, estimate.roll_sigma_deg);
        let mut misleading =
            integrity::misleading(pitch_error, estimate.pitch_sigma_deg, TILT_FLOOR_DEG)
                || integrity::misleading(roll_error, estimate.roll_sigma_deg, TILT_FLOOR_DEG);
        if score_heading {
            let heading_error = heading_error_deg(estimate.heading_deg, truth.heading_deg);
            errors[0].heading.add(heading_error);
            coverage.add(2, heading_error, estimate.heading_sigma_deg);
            misleading |=
                integrity::misleading(heading_error, estimate.heading_sigma_deg, HEADING_FLOOR_DEG);
        }
        integrity.add(reading.t, output.integrity, misleading);
    }
    let share = |part: u64, whole: u64| {
        if whole == 0 {
            0.0
        } else {
            part as f64 / whole as f64
        }
    };
    Ok(DriveScores {
        seed,
        duration_s: scenario.duration_s,
        scenario,
        motion_accuracy: share(right, total),
        moving_called_static: share(moving_as_static, moving),
        static_called_moving: share(still_as_moving, still),
        aligned_after_s: aligned_after,
        calibrated_after_s: calibrated_after,
        heading_scored_from_s: heading_from,
        methods: errors.iter().map(Errors::scores).collect(),
        coverage,
        integrity,
        fault,
        category,
    })
}

fn score_motion(motion: Motion, truth: &VehicleTruth, right: &mut u64, total: &mut u64) {
    *total += 1;
    *right += u64::from((motion == Motion::Moving) == truth.moving);
}

/// Every seed of `seeds` on up to `threads` threads, in seed order.
pub fn evaluate_all(
    seeds: &[u64],
    params: &Params,
    threads: usize,
) -> Result<Vec<DriveScores>, ParamError> {
    evaluate_all_with(seeds, params, None, VehicleCategory::Ordinary, threads)
}

/// Like [`evaluate_all`], with a fault injected into every drive, each
/// drawn in `category`.
pub fn evaluate_all_with(
    seeds: &[u64],
    params: &Params,
    fault: Option<FaultKind>,
    category: VehicleCategory,
    threads: usize,
) -> Result<Vec<DriveScores>, ParamError> {
    parallel_map(seeds, threads, |&seed| {
        evaluate_drive_with(seed, params, fault, category)
    })
    .into_iter()
    .collect()
}

/// One method's figures over the drives: median and worst (largest).
#[derive(Debug, Clone, Serialize)]
pub struct MethodSpread {
    pub method: String,
    pub pitch_rmse_deg: Spread,
    pub roll_rmse_deg: Spread,
    pub heading_rmse_deg: Spread,
}

/// Everything over the drives.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub drives: usize,
    /// The category the drives were drawn in (issue 55).
    pub category: VehicleCategory,
    /// Drives on which heading was scored (the truth turned enough).
    pub drives_with_heading: usize,
    /// Motion accuracy: median and lowest.
    pub motion_accuracy: Spread,
    pub methods: Vec<MethodSpread>,
    /// Pooled over every scored estimate: pitch, roll, heading.
    pub coverage_2_sigma: [f64; 3],
    /// Share of estimates flagged (not `ok`): median and largest.
    pub flagged_share: Spread,
    /// The longest misleading `ok` run, s: median and largest.
    pub misleading_run_s: Spread,
    /// With a fault injected: how the engine met it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fault: Option<FaultSummary>,
    pub bars: Vec<Bar>,
}

/// The values of `f` over the drives where it is a number.
fn finite(drives: &[DriveScores], f: impl Fn(&DriveScores) -> f64) -> Vec<f64> {
    drives.iter().map(f).filter(|x| x.is_finite()).collect()
}

/// Seeds as "1, 5, 12".
fn seed_list(seeds: &[u64]) -> String {
    seeds
        .iter()
        .map(u64::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

/// The spread of every method and the bars.
pub fn summarise(drives: &[DriveScores]) -> Summary {
    let methods = METHODS
        .iter()
        .map(|&label| {
            let of = |f: fn(&MethodScores) -> f64| {
                Spread::of(&finite(drives, |d| d.method(label).map_or(f64::NAN, f)))
            };
            MethodSpread {
                method: label.to_string(),
                pitch_rmse_deg: of(|m| m.pitch_rmse_deg),
                roll_rmse_deg: of(|m| m.roll_rmse_deg),
                heading_rmse_deg: of(|m| m.heading_rmse_deg),
            }
        })
        .collect();
    let motion_accuracy = Spread::of_lowest(&finite(drives, |d| d.motion_accuracy));
    let mut pooled = Coverage::default();
    for d in drives {
        pooled.merge(&d.coverage);
    }
    let coverage = pooled.shares();
    let engine =
        |d: &DriveScores, f: fn(&MethodScores) -> f64| d.method("engine").map_or(f64::NAN, f);
    // The same median as the table's (of an even count, the mean of the
    // middle two).
    let headings = finite(drives, |d| engine(d, |m| m.heading_rmse_deg));
    let heading_scored = headings.len();
    let heading = Spread::of(&headings);
    let tilt = Spread::of(&finite(drives, |d| engine(d, MethodScores::tilt_rmse_deg)));
    // The drives whose heading the engine has worse than `label`'s.
    let worse_than = |label: &str| -> Vec<u64> {
        drives
            .iter()
            .filter(|d| {
                let ours = engine(d, |m| m.heading_rmse_deg);
                let theirs = d.method(label).map_or(f64::NAN, |m| m.heading_rmse_deg);
                ours.is_finite() && theirs.is_finite() && ours > theirs
            })
            .map(|d| d.seed)
            .collect()
    };
    // The drives over a per-drive bar, or the worst when none.
    let over_on = |value: &dyn Fn(&DriveScores) -> f64, limit: f64, worst: f64| -> String {
        let over: Vec<String> = drives
            .iter()
            .filter(|d| value(d) > limit)
            .map(|d| format!("{} ({:.2}°)", d.seed, value(d)))
            .collect();
        if over.is_empty() {
            format!("worst {worst:.3}°")
        } else {
            format!("over on {} drives: seeds {}", over.len(), over.join(", "))
        }
    };
    let worse_than_madgwick = worse_than("madgwick");
    let worse_than_vqf = worse_than("vqf");
    let mut bars = vec![
        Bar {
            bar: "motion accuracy ≥ 0.98 at the median".into(),
            measured: format!("{:.4}", motion_accuracy.median),
            met: motion_accuracy.median >= 0.98,
        },
        Bar {
            bar: "motion accuracy ≥ 0.97 on every drive".into(),
            measured: format!("lowest {:.4}", motion_accuracy.worst),
            met: motion_accuracy.worst >= 0.97,
        },
        Bar {
            bar: "heading never worse than the calibrated Madgwick".into(),
            measured: if heading_scored == 0 {
                "no drive turned enough to score heading".into()
            } else if worse_than_madgwick.is_empty() {
                "on no drive".into()
            } else {
                format!(
                    "worse on {} drives: seeds {}",
                    worse_than_madgwick.len(),
                    seed_list(&worse_than_madgwick)
                )
            },
            met: heading_scored > 0 && worse_than_madgwick.is_empty(),
        },
        Bar {
            bar: "heading worse than the calibrated VQF on at most a tenth of the drives".into(),
            measured: format!(
                "worse on {} of {heading_scored}{}",
                worse_than_vqf.len(),
                if worse_than_vqf.is_empty() {
                    String::new()
                } else {
                    format!(": seeds {}", seed_list(&worse_than_vqf))
                }
            ),
            met: heading_scored > 0 && 10 * worse_than_vqf.len() <= heading_scored,
        },
        Bar {
            bar: format!(
                "heading RMSE ≤ {MAX_HEADING_RMSE_DEG}° on every drive that turned {TURNED_FOR_HEADING_DEG}°"
            ),
            measured: over_on(
                &|d| engine(d, |m| m.heading_rmse_deg),
                MAX_HEADING_RMSE_DEG,
                heading.worst,
            ),
            met: heading_scored > 0 && heading.worst <= MAX_HEADING_RMSE_DEG,
        },
        Bar {
            bar: format!("tilt RMSE ≤ {MAX_TILT_RMSE_DEG}° on every drive"),
            measured: over_on(
                &|d| engine(d, MethodScores::tilt_rmse_deg),
                MAX_TILT_RMSE_DEG,
                tilt.worst,
            ),
            met: !drives.is_empty() && tilt.worst <= MAX_TILT_RMSE_DEG,
        },
        Bar {
            bar: "heading RMSE ≤ 2° at the median".into(),
            measured: format!("{:.3}° over {heading_scored} drives", heading.median),
            met: heading_scored > 0 && heading.median <= 2.0,
        },
        Bar {
            bar: "tilt RMSE ≤ 0.5° at the median (the larger of pitch and roll)".into(),
            measured: format!("{:.3}°", tilt.median),
            met: !drives.is_empty() && tilt.median <= 0.5,
        },
    ];
    let flagged_share = Spread::of(&finite(drives, |d| d.integrity.flagged_share()));
    let misleading_run_s = Spread::of(&finite(drives, |d| d.integrity.worst_run_s));
    let long_runs: Vec<String> = drives
        .iter()
        .filter(|d| !d.integrity.run_bar_met())
        .map(|d| format!("{} ({:.0} s)", d.seed, d.integrity.worst_run_s))
        .collect();
    bars.push(Bar {
        bar: format!(
            "no run of |error| > 5σ (tilt > {TILT_FLOOR_DEG}°, heading > {HEADING_FLOOR_DEG}°) shown ok longer than {} s, on every drive",
            integrity::MAX_MISLEADING_RUN_S
        ),
        measured: if long_runs.is_empty() {
            format!("longest {:.1} s", misleading_run_s.worst)
        } else {
            format!("longer on seeds {}", long_runs.join(", "))
        },
        met: long_runs.is_empty(),
    });
    if drives.iter().all(|d| d.fault.is_none()) {
        bars.push(Bar {
            bar: format!(
                "at most {:.0} % of estimates flagged on every ordinary drive",
                100.0 * integrity::MAX_FLAGGED_SHARE
            ),
            measured: format!(
                "median {:.2} %, largest {:.2} %",
                100.0 * flagged_share.median,
                100.0 * flagged_share.worst
            ),
            met: flagged_share.worst <= integrity::MAX_FLAGGED_SHARE,
        });
    }
    let fault = FaultSummary::of(drives.iter().map(|d| &d.integrity));
    bars.extend(fault.as_ref().map(FaultSummary::recovery_bar));
    for (k, name) in ["pitch", "roll", "heading"].iter().enumerate() {
        bars.push(Bar {
            bar: format!("2σ covers 90–99 % of {name} errors"),
            measured: format!(
                "{:.1} % ({} of {} estimates without σ)",
                100.0 * coverage[k],
                pooled.without_sigma[k],
                pooled.estimates[k]
            ),
            met: (0.90..=0.99).contains(&coverage[k]),
        });
    }
    Summary {
        drives: drives.len(),
        category: drives
            .first()
            .map_or(VehicleCategory::Ordinary, |d| d.category),
        drives_with_heading: drives
            .iter()
            .filter(|d| d.heading_scored_from_s.is_some())
            .count(),
        motion_accuracy,
        methods,
        coverage_2_sigma: coverage,
        flagged_share,
        misleading_run_s,
        fault,
        bars,
    }
}

/// The drives one line each, then the spread and the bars.
pub fn render(drives: &[DriveScores], summary: &Summary) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "fuzzy envelope: {} {} drives ({} turned enough to score heading); RMSE in degrees; tilt is the larger of pitch and roll",
        summary.drives,
        summary.category.as_str(),
        summary.drives_with_heading
    );
    let _ = writeln!(
        out,
        "{:>5} {:>4} {:>4} {:>5} {:>5} {:>5} {:>4} {:>3} {:>4} | {:>6} {:>7} {:>7} | {:>7} {:>7} {:>7} {:>7} {:>7} | {:>6} {:>6} {:>6} {:>6} | {:>6} {:>6}",
        "seed",
        "min",
        "Hz",
        "bias",
        "incl",
        "hard",
        "circ",
        "dst",
        "park",
        "motion",
        "align s",
        "calib s",
        "hdg eng",
        "madgw",
        "vqf",
        "mahony",
        "gyro",
        "tilt e",
        "madgw",
        "vqf",
        "gyro",
        "flag%",
        "run s"
    );
    for d in drives {
        let s = &d.scenario;
        let m = s.manoeuvres;
        let horizontal = s.field_ut * rad(s.inclination_deg).cos();
        let hard = s.iron.map_or(0.0, |i| V3::from(i.hard_iron_ut).norm()) / horizontal;
        let method = |label: &str, f: fn(&MethodScores) -> f64| d.method(label).map_or(f64::NAN, f);
        let seconds = |x: Option<f64>| x.map_or("never".to_string(), |s| format!("{s:.0}"));
        let _ = writeln!(
            out,
            "{:>5} {:>4.0} {:>4.0} {:>5.2} {:>5.0} {:>5.2} {:>4} {:>3} {:>4.0} | {:>6.4} {:>7} {:>7} | {:>7.3} {:>7.3} {:>7.3} {:>7.3} {:>7.3} | {:>6.3} {:>6.3} {:>6.3} {:>6.3} | {:>6.2} {:>6.1}",
            d.seed,
            d.duration_s / 60.0,
            s.imu_rate_hz,
            s.imu.gyro_bias_dps,
            s.inclination_deg,
            hard,
            if m.is_some_and(|m| m.calibration_circle_dps.is_some()) {
                "yes"
            } else {
                "no"
            },
            s.disturbances.len(),
            m.map_or(0.0, |m| m.parked_start_s),
            d.motion_accuracy,
            seconds(d.aligned_after_s),
            seconds(d.calibrated_after_s),
            method("engine", |m| m.heading_rmse_deg),
            method("madgwick", |m| m.heading_rmse_deg),
            method("vqf", |m| m.heading_rmse_deg),
            method("mahony", |m| m.heading_rmse_deg),
            method("gyro", |m| m.heading_rmse_deg),
            method("engine", MethodScores::tilt_rmse_deg),
            method("madgwick", MethodScores::tilt_rmse_deg),
            method("vqf", MethodScores::tilt_rmse_deg),
            method("gyro", MethodScores::tilt_rmse_deg),
            100.0 * d.integrity.flagged_share(),
            d.integrity.worst_run_s,
        );
    }
    let _ = writeln!(
        out,
        "\n{:<9} {:>17} {:>17} {:>17}",
        "method", "pitch med/max", "roll med/max", "heading med/max"
    );
    for m in &summary.methods {
        let _ = writeln!(
            out,
            "{:<9} {:>8.3}/{:<8.3} {:>8.3}/{:<8.3} {:>8.3}/{:<8.3}",
            m.method,
            m.pitch_rmse_deg.median,
            m.pitch_rmse_deg.worst,
            m.roll_rmse_deg.median,
            m.roll_rmse_deg.worst,
            m.heading_rmse_deg.median,
            m.heading_rmse_deg.worst,
        );
    }
    let c = summary
        .coverage_2_sigma
        .map(|x| format!("{:.1}", 100.0 * x));
    let _ = writeln!(
        out,
        "motion accuracy median {:.4}, lowest {:.4}; engine 2σ coverage pitch/roll/heading {} %",
        summary.motion_accuracy.median,
        summary.motion_accuracy.worst,
        c.join("/")
    );
    let _ = writeln!(
        out,
        "integrity{}: flagged median {:.2} %, largest {:.2} %; longest misleading ok run median {:.1} s, largest {:.1} s\n",
        match drives.first().and_then(|d| d.fault) {
            Some(fault) => format!(" (fault: {})", fault.as_str()),
            None => String::new(),
        },
        100.0 * summary.flagged_share.median,
        100.0 * summary.flagged_share.worst,
        summary.misleading_run_s.median,
        summary.misleading_run_s.worst,
    );
    if let Some(fault) = &summary.fault {
        out.push_str(&fault.render());
        out.push('\n');
    }
    Bar::render_all(&summary.bars, &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_counts_by_hand() {
        let mut c = Coverage::default();
        c.add(0, 0.3, Some(0.2)); // 0.3 ≤ 0.4: covered
        c.add(0, -0.5, Some(0.2)); // 0.5 > 0.4: not
        c.add(0, 0.0, None); // no σ: not
        c.add(2, 3.0, Some(1.5)); // 3.0 ≤ 3.0: covered
        assert_eq!(c.estimates, [3, 0, 1]);
        assert_eq!(c.covered, [1, 0, 1]);
        assert_eq!(c.without_sigma, [1, 0, 0]);
        let shares = c.shares();
        assert!((shares[0] - 1.0 / 3.0).abs() < 1e-12 && shares[1].is_nan() && shares[2] == 1.0);
    }

    #[test]
    fn the_installer_sets_the_site_and_half_a_second_of_readings() {
        let scenario = VehicleEnvelope::draw(3).scenario;
        let given =
            Params::from_assignments(PARAMS, ["window_samples=7", "heading_gate_deg=5"]).unwrap();
        let params = installer_params(&scenario, &given).unwrap();
        let number = |name: &'static str| params.real(name).unwrap();
        assert_eq!(
            number("window_samples"),
            (scenario.imu_rate_hz / 2.0).round()
        );
        assert_eq!(number("declination_deg"), scenario.declination_deg);
        assert_eq!(number("mag_inclination_deg"), scenario.inclination_deg);
        assert_eq!(number("heading_gate_deg"), 5.0);
    }
}
