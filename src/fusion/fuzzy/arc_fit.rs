//! Magnetometer calibration from a partial arc, aided by the gyros
//! (issue 55): a graded or banked drive without a calibration circle
//! calibrates once the vehicle has turned 90°.
//!
//! Between two readings the Earth's field stays fixed in the level frame;
//! the gyros tell how far the vehicle turned (ψ_g, the engine's integrated
//! heading, bias corrected) and the filter its roll φ and pitch θ. So each
//! raw reading is, with the hard iron b fixed in the body:
//!
//! ```text
//! m = K · G(t)ᵀ · n + b,   G(t) = R_z(ψ_g + d·(t − t̄)) · R_y(θ) · R_x(φ)      (1)
//! n = (cos β, sin β, v)                                                     (2)
//! ```
//!
//! K the inverse of the soft iron (symmetric; its size is the field's
//! horizontal size), n the field in the gyro heading's frame (magnetic
//! north lies at gyro heading β; v = tan I), d what is left of the gyro's
//! drift over the arc and t̄ the samples' mean time: 12 unknowns. The
//! magnetic heading of a calibrated reading is that of K⁻¹(m − b): the
//! correction is S = K⁻¹ (scaled to det 1) and b.
//!
//! Only what the declaration says is assumed (as priors, each one row of
//! the least squares in units of its σ): v = tan I of the declared
//! inclination within [`INCLINATION_PRIOR_RAD`] (the vertical of a level
//! drive is otherwise inseparable from b's), K a multiple k̄ of the
//! identity within [`SOFT_IRON_PRIOR`] per element (k̄ its mean diagonal),
//! d = 0 within the gyro bias's σ now (at least [`MIN_DRIFT_SIGMA_RAD_PER_S`]).
//! ψ_g is taken as the bias now would have made it: each sample keeps the
//! integral of the bias estimate subtracted up to it (about the vertical),
//! so a bias learnt at a later rest (a vehicle never still at the start)
//! corrects the samples taken before, ψ_g,i + ∫₀^tᵢ b̂(τ) dτ − b̂_now·tᵢ.
//! Gauss–Newton with Levenberg damping from the level linear solution
//!
//! ```text
//! m = A · (cos ψ_g, sin ψ_g)ᵀ + c                                            (3)
//! ```
//!
//! (A's upper 2×2 is k·[[cos β, sin β], [sin β, −cos β]]).
//!
//! **Samples**: one per 2° bin of gyro heading (the newest wins), at most
//! [`MAX_AGE_S`] old; a new one when the gyro heading moved 1° or a second
//! passed. **Gates**: the gyro headings span at least [`MIN_ARC_DEG`]
//! (360° less the widest gap), the residual's RMS over the horizontal
//! field is at most [`MAX_RESIDUAL`] (a disturbance met on the arc bends
//! it), the fitted
//! field is one the Earth has, and the heading σ the fit leaves (its
//! covariance carried to the heading of level readings around the circle,
//! RMS) is at most [`MAX_HEADING_SIGMA_RAD`]. A later fit replaces the
//! current one only with a smaller heading σ. The correction's `fit_rms`
//! is the larger of that σ and the relative residual RMS.

use std::collections::VecDeque;

use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion};
use serde::{Deserialize, Serialize};

use super::magcal::{Correction, azimuth_span_deg};
use super::orientation::{angle_difference, magnetic_heading};
use crate::fusion::geometry::{V3, attitude_from_euler};
use crate::fusion::robust::median_in_place;

/// Gyro heading the samples must span, degrees (issue 55).
pub const MIN_ARC_DEG: f64 = 90.0;
/// Samples older than this are dropped, s.
pub const MAX_AGE_S: f64 = 600.0;
/// A fit whose relative residual RMS is larger is refused.
pub const MAX_RESIDUAL: f64 = 0.05;
/// A fit that leaves a larger heading σ is refused, rad (3°).
pub const MAX_HEADING_SIGMA_RAD: f64 = 0.052_36;
/// The declared inclination's σ, rad (3°).
pub const INCLINATION_PRIOR_RAD: f64 = 0.052_36;
/// The soft iron's σ per element of K/k̄ − I.
pub const SOFT_IRON_PRIOR: f64 = 0.1;
/// The residual gyro drift's σ at least, rad/s (0.01 °/s).
pub const MIN_DRIFT_SIGMA_RAD_PER_S: f64 = 0.000_175;
/// Width of a gyro-heading bin, rad (2°).
const BIN_RAD: f64 = 0.034_907;
/// A new sample once the gyro heading moved this much, rad (1°)…
const NEW_SAMPLE_TURN_RAD: f64 = 0.017_453;
/// …or this much time passed, s.
const NEW_SAMPLE_S: f64 = 1.0;
/// Fewest samples a fit takes.
const MIN_SAMPLES: usize = 24;
/// Before a fit is accepted, a new attempt once the arc grew this much
/// (rad, 5°) or this many samples arrived.
const RETRY_TURN_RAD: f64 = 0.087_266;
const RETRY_SAMPLES: u32 = 32;
/// With a fit, a refit after this many new samples.
const REFIT_SAMPLES: u32 = 64;
/// Gauss–Newton iterations at most.
const MAX_ITERATIONS: usize = 12;
/// The residual's floor, µT (a magnetometer's quantisation).
const MIN_RESIDUAL_UT: f64 = 0.05;
/// The plausible horizontal field, µT (magcal.rs's bounds).
const HORIZONTAL_UT: (f64, f64) = (5.0, 70.0);

const PARAMS: usize = 12;
type Vector = SVector<f64, PARAMS>;
type Square = SMatrix<f64, PARAMS, PARAMS>;

/// One raw reading with the gyro heading and the tilt it was taken at.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct ArcSample {
    t: f64,
    field_ut: V3,
    gyro_yaw_rad: f64,
    /// The bias estimate subtracted up to it, integrated about the
    /// vertical, rad.
    bias_integral_rad: f64,
    /// The filter's tilt σ then, rad.
    #[serde(default)]
    tilt_sigma_rad: f64,
    /// Body to level: R_y(θ)·R_x(φ).
    levelling: UnitQuaternion<f64>,
}

impl ArcSample {
    fn bin(&self) -> i64 {
        (self.gyro_yaw_rad.rem_euclid(std::f64::consts::TAU) / BIN_RAD) as i64
    }
}

/// The unknowns of (1): b, K (symmetric), β, v, d.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Model {
    p: Vector,
}

impl Model {
    fn hard_iron(&self) -> V3 {
        V3::new(self.p[0], self.p[1], self.p[2])
    }

    fn soft_inverse(&self) -> Matrix3<f64> {
        let p = &self.p;
        Matrix3::new(p[3], p[6], p[7], p[6], p[4], p[8], p[7], p[8], p[5])
    }

    fn field(&self) -> V3 {
        V3::new(self.p[9].cos(), self.p[9].sin(), self.p[10])
    }

    /// The raw reading (1) predicts for `sample`, with the samples' mean
    /// time `mean_t`.
    fn predict(&self, sample: &ArcSample, mean_t: f64) -> V3 {
        let yaw = sample.gyro_yaw_rad + self.p[11] * (sample.t - mean_t);
        let heading = UnitQuaternion::from_axis_angle(&V3::z_axis(), yaw);
        let body = sample.levelling.inverse() * (heading.inverse() * self.field());
        self.soft_inverse() * body + self.hard_iron()
    }

    /// The prior rows, each in units of its σ.
    fn priors(&self, tan_inclination: f64, sigma_v: f64, sigma_d: f64) -> [f64; 8] {
        let k = self.soft_inverse();
        let mean = k.trace() / 3.0;
        let scale = SOFT_IRON_PRIOR * mean.abs().max(1e-9);
        [
            (self.p[10] - tan_inclination) / sigma_v,
            (k[(0, 0)] - mean) / scale,
            (k[(1, 1)] - mean) / scale,
            k[(0, 1)] / scale,
            k[(0, 2)] / scale,
            k[(1, 2)] / scale,
            (k[(2, 2)] - mean) / scale,
            self.p[11] / sigma_d,
        ]
    }

    fn correction(&self, fit_rms: f64) -> Option<Correction> {
        let inverse = self.soft_inverse().try_inverse()?;
        let det = inverse.determinant();
        if det <= 0.0 || !det.is_finite() {
            return None;
        }
        Some(Correction {
            hard_iron_ut: self.hard_iron(),
            soft_iron: inverse / det.cbrt(),
            fit_rms,
        })
    }
}

/// A fit of (1) and what it leaves.
#[derive(Debug, Clone, Copy)]
struct Fit {
    model: Model,
    /// RMS of |residual| over the horizontal field's size.
    relative_rms: f64,
    /// RMS heading σ over level readings around the circle, rad.
    heading_sigma_rad: f64,
}

/// The engine's gyro heading and tilt σ when a reading is taken.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GyroHeading {
    pub t: f64,
    /// The bias-compensated rate about the vertical, integrated, rad.
    pub yaw_rad: f64,
    /// The bias estimate subtracted from it, integrated, rad.
    pub bias_integral_rad: f64,
    /// The bias about the vertical now and its σ about the vertical,
    /// rad/s.
    pub bias_rad_per_s: f64,
    pub bias_sigma_rad_per_s: f64,
    /// The tilt's σ now, rad.
    pub tilt_sigma_rad: f64,
}

/// Calibration from gyro-aided partial arcs; see the module documentation.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ArcCalibration {
    samples: VecDeque<ArcSample>,
    correction: Option<Correction>,
    /// The accepted fit's heading σ, rad.
    heading_sigma_rad: Option<f64>,
    /// The arc (rad) and the samples at the last attempt.
    arc_at_attempt: f64,
    since_attempt: u32,
    /// Fits refused by a gate.
    refused: u64,
}

impl ArcCalibration {
    /// The current correction, once a fit passed the gates.
    pub fn correction(&self) -> Option<&Correction> {
        self.correction.as_ref()
    }

    /// Fits refused by a gate.
    pub fn refused_fits(&self) -> u64 {
        self.refused
    }

    /// Forgets the samples (the gyro heading restarted); the correction
    /// stays.
    pub fn restart(&mut self) {
        self.samples.clear();
        self.arc_at_attempt = 0.0;
        self.since_attempt = 0;
    }

    /// Gyro heading the samples span, rad.
    pub fn arc_rad(&self) -> f64 {
        azimuth_span_deg(
            self.samples
                .iter()
                .map(|s| (s.gyro_yaw_rad.cos(), s.gyro_yaw_rad.sin())),
        )
        .to_radians()
    }

    /// The calibrated field's median magnitude over the samples, µT.
    pub fn field_magnitude_ut(&self) -> Option<f64> {
        let c = self.correction.as_ref()?;
        let mut magnitudes: Vec<f64> = self
            .samples
            .iter()
            .map(|s| c.apply(&s.field_ut).norm())
            .collect();
        (!magnitudes.is_empty()).then(|| median_in_place(&mut magnitudes))
    }

    /// Adds a raw reading (µT) taken at the filter's roll and pitch with
    /// the gyro heading `gyro`; fits when due. Returns true when the
    /// correction changed.
    pub fn add(
        &mut self,
        field_ut: V3,
        (roll_rad, pitch_rad): (f64, f64),
        gyro: GyroHeading,
        inclination_rad: f64,
    ) -> bool {
        let (t, gyro_yaw_rad) = (gyro.t, gyro.yaw_rad);
        if !field_ut.iter().all(|x| x.is_finite())
            || !gyro_yaw_rad.is_finite()
            || !gyro.bias_integral_rad.is_finite()
        {
            return false;
        }
        if let Some(last) = self.samples.back()
            && (t - last.t) < NEW_SAMPLE_S
            && (gyro_yaw_rad - last.gyro_yaw_rad).abs() < NEW_SAMPLE_TURN_RAD
            && t >= last.t
        {
            return false;
        }
        let sample = ArcSample {
            t,
            field_ut,
            gyro_yaw_rad,
            bias_integral_rad: gyro.bias_integral_rad,
            tilt_sigma_rad: gyro.tilt_sigma_rad,
            levelling: attitude_from_euler(roll_rad, pitch_rad, 0.0),
        };
        let bin = sample.bin();
        self.samples
            .retain(|s| s.bin() != bin && t - s.t <= MAX_AGE_S);
        self.samples.push_back(sample);
        self.since_attempt += 1;
        if self.samples.len() < MIN_SAMPLES {
            return false;
        }
        let arc = self.arc_rad();
        if arc < MIN_ARC_DEG.to_radians() {
            return false;
        }
        let due = match self.correction {
            None => {
                arc >= self.arc_at_attempt + RETRY_TURN_RAD || self.since_attempt >= RETRY_SAMPLES
            }
            Some(_) => self.since_attempt >= REFIT_SAMPLES,
        };
        if !due {
            return false;
        }
        self.arc_at_attempt = arc;
        self.since_attempt = 0;
        // The gyro heading as the bias now would have made it.
        let samples: Vec<ArcSample> = self
            .samples
            .iter()
            .map(|s| ArcSample {
                gyro_yaw_rad: s.gyro_yaw_rad + s.bias_integral_rad
                    - gyro.bias_integral_rad
                    - gyro.bias_rad_per_s * (s.t - t),
                ..*s
            })
            .collect();
        let drift_sigma = gyro.bias_sigma_rad_per_s.max(MIN_DRIFT_SIGMA_RAD_PER_S);
        let passed = fit(&samples, inclination_rad, drift_sigma).filter(|f| {
            let horizontal = f.model.soft_inverse().determinant().abs().cbrt();
            f.relative_rms <= MAX_RESIDUAL
                && f.heading_sigma_rad <= MAX_HEADING_SIGMA_RAD
                && (HORIZONTAL_UT.0..=HORIZONTAL_UT.1).contains(&horizontal)
        });
        let Some((correction, sigma)) = passed.and_then(|f| {
            f.model
                .correction(f.heading_sigma_rad.max(f.relative_rms))
                .map(|c| (c, f.heading_sigma_rad))
        }) else {
            self.refused += 1;
            return false;
        };
        // A refit that passes but is no surer changes nothing (and is no
        // refusal).
        if self
            .heading_sigma_rad
            .is_some_and(|current| sigma >= current)
        {
            return false;
        }
        self.correction = Some(correction);
        self.heading_sigma_rad = Some(sigma);
        true
    }
}

/// The level linear solution (3) as a starting model, or `None` when the
/// headings do not separate its columns.
fn initial_model(samples: &[ArcSample], tan_inclination: f64) -> Option<Model> {
    let mut normal = Matrix3::zeros();
    let mut rhs = Matrix3::zeros();
    for s in samples {
        let x = V3::new(s.gyro_yaw_rad.cos(), s.gyro_yaw_rad.sin(), 1.0);
        normal += x * x.transpose();
        rhs += x * s.field_ut.transpose();
    }
    // Rows of `coefficients`: cos, sin, constant; columns: m_x, m_y, m_z.
    let coefficients = normal.cholesky()?.solve(&rhs);
    let (a00, a01) = (coefficients[(0, 0)], coefficients[(1, 0)]);
    let (a10, a11) = (coefficients[(0, 1)], coefficients[(1, 1)]);
    let k_cos = 0.5 * (a00 - a11);
    let k_sin = 0.5 * (a01 + a10);
    let k = k_cos.hypot(k_sin);
    if k.is_nan() || k <= 0.0 {
        return None;
    }
    let constant = V3::new(
        coefficients[(2, 0)],
        coefficients[(2, 1)],
        coefficients[(2, 2)],
    );
    let b = constant - V3::new(0.0, 0.0, k * tan_inclination);
    let mut p = Vector::zeros();
    p[0] = b.x;
    p[1] = b.y;
    p[2] = b.z;
    p[3] = k;
    p[4] = k;
    p[5] = k;
    p[9] = k_sin.atan2(k_cos);
    p[10] = tan_inclination;
    Some(Model { p })
}

/// Fits (1) to the samples by damped Gauss–Newton (module documentation).
fn fit(samples: &[ArcSample], inclination_rad: f64, sigma_d: f64) -> Option<Fit> {
    let tan_inclination = inclination_rad.tan();
    // σ of v = tan I for the inclination's σ: sec²I·σ_I.
    let sigma_v = INCLINATION_PRIOR_RAD / inclination_rad.cos().powi(2);
    let mean_t = samples.iter().map(|s| s.t).sum::<f64>() / samples.len() as f64;
    let mut model = initial_model(samples, tan_inclination)?;
    let squared_residuals = |m: &Model| -> Vec<f64> {
        samples
            .iter()
            .map(|s| (s.field_ut - m.predict(s, mean_t)).norm_squared())
            .collect()
    };
    let dof = (3 * samples.len()).saturating_sub(PARAMS).max(1) as f64;
    let mut lambda = 1e-3;
    let mut normal = Square::zeros();
    let mut squared = squared_residuals(&model);
    for _ in 0..MAX_ITERATIONS {
        let sigmas = sample_sigmas(&model, samples, &squared, dof);
        // The cost of a model whose squared data residuals are `squared`.
        let cost = |m: &Model, squared: &[f64]| -> f64 {
            squared
                .iter()
                .zip(&sigmas)
                .map(|(r2, sigma)| r2 / (sigma * sigma))
                .sum::<f64>()
                + m.priors(tan_inclination, sigma_v, sigma_d)
                    .iter()
                    .map(|r| r * r)
                    .sum::<f64>()
        };
        let priors = (tan_inclination, sigma_v, sigma_d);
        let (jtj, jtr) = normal_equations(&model, samples, mean_t, &sigmas, priors);
        normal = jtj;
        let before = cost(&model, &squared);
        let mut improved = false;
        for _ in 0..6 {
            let damped = jtj + Square::from_diagonal(&jtj.diagonal()) * lambda;
            let Some(step) = damped.cholesky().map(|c| c.solve(&(-jtr))) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = Model { p: model.p + step };
            let candidate_squared = squared_residuals(&candidate);
            if cost(&candidate, &candidate_squared) < before {
                model = candidate;
                squared = candidate_squared;
                lambda = (lambda * 0.3).max(1e-9);
                improved = step.norm() > 1e-9 * model.p.norm();
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let covariance = normal.try_inverse()?;
    // Relative to the horizontal field, whose direction is the heading.
    let horizontal = model.soft_inverse().determinant().abs().cbrt();
    let relative_rms = (squared.iter().sum::<f64>() / samples.len() as f64).sqrt() / horizontal;
    Some(Fit {
        model,
        relative_rms,
        heading_sigma_rad: heading_sigma_rad(&model, &covariance),
    })
}

/// Each sample's residual σ per axis, µT: the field's noise σ_r and the
/// vertical its tilt's σ may tip into the horizontal, k·|v|·σ_tilt, in
/// quadrature. σ_r² is the mean of what the residuals leave beyond the
/// tilts' share (at least [`MIN_RESIDUAL_UT`]).
fn sample_sigmas(model: &Model, samples: &[ArcSample], squared: &[f64], dof: f64) -> Vec<f64> {
    let tipped = model.soft_inverse().determinant().abs().cbrt() * model.p[10].abs();
    let tilt_share = |s: &ArcSample| (tipped * s.tilt_sigma_rad).powi(2);
    let noise = samples
        .iter()
        .zip(squared)
        .map(|(s, r2)| r2 - 3.0 * tilt_share(s))
        .sum::<f64>()
        / dof;
    let noise = noise.max(MIN_RESIDUAL_UT * MIN_RESIDUAL_UT);
    samples
        .iter()
        .map(|s| (noise + tilt_share(s)).sqrt())
        .collect()
}

/// JᵀJ and Jᵀr of the residuals in units of their σ (data rows over
/// their sample's σ, priors over their own): the data rows' J from (1)
/// differentiated, the priors' by forward differences.
fn normal_equations(
    model: &Model,
    samples: &[ArcSample],
    mean_t: f64,
    sigmas: &[f64],
    (tan_inclination, sigma_v, sigma_d): (f64, f64, f64),
) -> (Square, Vector) {
    let steps: Vector = model.p.map(|x| 1e-6 * x.abs().max(1e-3));
    let shifted: Vec<Model> = (0..PARAMS)
        .map(|j| {
            let mut p = model.p;
            p[j] += steps[j];
            Model { p }
        })
        .collect();
    let (mut jtj, mut jtr) = (Square::zeros(), Vector::zeros());
    let k = model.soft_inverse();
    let (sin_beta, cos_beta) = model.p[9].sin_cos();
    let n = model.field();
    for (s, &sigma) in samples.iter().zip(sigmas) {
        // (1) differentiated: predicted = K·u + b, u = L⁻¹·R_z(ψ)ᵀ·n.
        let dt = s.t - mean_t;
        let yaw = s.gyro_yaw_rad + model.p[11] * dt;
        let (sin, cos) = yaw.sin_cos();
        let level_to_body = s.levelling.inverse();
        let u = level_to_body * V3::new(cos * n.x + sin * n.y, -sin * n.x + cos * n.y, n.z);
        let du_dbeta = level_to_body
            * V3::new(
                -cos * sin_beta + sin * cos_beta,
                sin * sin_beta + cos * cos_beta,
                0.0,
            );
        let du_dv = level_to_body * V3::z();
        let du_dd =
            level_to_body * V3::new(-sin * n.x + cos * n.y, -cos * n.x - sin * n.y, 0.0) * dt;
        let predicted = k * u + model.hard_iron();
        let residual = (s.field_ut - predicted) / sigma;
        let mut rows = SMatrix::<f64, 3, PARAMS>::zeros();
        rows.fixed_view_mut::<3, 3>(0, 0).fill_with_identity();
        let columns = [
            V3::new(u.x, 0.0, 0.0),
            V3::new(0.0, u.y, 0.0),
            V3::new(0.0, 0.0, u.z),
            V3::new(u.y, u.x, 0.0),
            V3::new(u.z, 0.0, u.x),
            V3::new(0.0, u.z, u.y),
            k * du_dbeta,
            k * du_dv,
            k * du_dd,
        ];
        for (j, column) in columns.iter().enumerate() {
            rows.set_column(3 + j, column);
        }
        // d(residual)/dp = −d(predicted)/dp, in units of σ.
        rows /= -sigma;
        jtj += rows.transpose() * rows;
        jtr += rows.transpose() * residual;
    }
    let priors = model.priors(tan_inclination, sigma_v, sigma_d);
    let mut prior_rows = SMatrix::<f64, 8, PARAMS>::zeros();
    for (j, m) in shifted.iter().enumerate() {
        let moved = m.priors(tan_inclination, sigma_v, sigma_d);
        for i in 0..8 {
            prior_rows[(i, j)] = (moved[i] - priors[i]) / steps[j];
        }
    }
    jtj += prior_rows.transpose() * prior_rows;
    jtr += prior_rows.transpose() * SVector::<f64, 8>::from(priors);
    (jtj, jtr)
}

/// The RMS over twelve level headings of the heading σ the parameters'
/// covariance leaves, rad.
fn heading_sigma_rad(model: &Model, covariance: &Square) -> f64 {
    let heading_of = |m: &Model, raw: &V3| -> Option<f64> {
        let body = m.soft_inverse().try_inverse()? * (raw - m.hard_iron());
        Some(magnetic_heading(&body, 0.0, 0.0))
    };
    let mut sum = 0.0;
    let count = 12;
    for k in 0..count {
        let yaw = k as f64 * std::f64::consts::TAU / count as f64;
        let raw = model.soft_inverse()
            * (UnitQuaternion::from_axis_angle(&V3::z_axis(), yaw).inverse() * model.field())
            + model.hard_iron();
        let Some(base) = heading_of(model, &raw) else {
            return f64::INFINITY;
        };
        let mut gradient = Vector::zeros();
        for j in 0..PARAMS {
            let step = 1e-6 * model.p[j].abs().max(1e-3);
            let mut p = model.p;
            p[j] += step;
            let Some(moved) = heading_of(&Model { p }, &raw) else {
                return f64::INFINITY;
            };
            gradient[j] = angle_difference(moved, base) / step;
        }
        sum += (gradient.transpose() * covariance * gradient)[(0, 0)].max(0.0);
    }
    (sum / count as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Time, raw field, (roll, pitch) and gyro heading.
    type Reading = (f64, V3, (f64, f64), f64);

    /// Readings of a vehicle on a grade and a bank turning through
    /// `arc_deg` at 10 °/s, 10 readings a second, its gyro heading the
    /// truth plus `gyro_offset_rad` (the gyro's zero is anywhere), under
    /// hard iron, soft iron and noise-free field of 50 µT at 60°.
    fn arc_readings(arc_deg: f64, gyro_offset_rad: f64) -> (Vec<Reading>, Matrix3<f64>, V3) {
        let inclination = 60f64.to_radians();
        let world = V3::new(inclination.cos(), 0.0, inclination.sin()) * 50.0;
        let soft = Matrix3::new(1.08, 0.04, -0.02, 0.04, 0.95, 0.03, -0.02, 0.03, 1.02);
        let hard = V3::new(18.0, -30.0, 12.0);
        let mut readings = Vec::new();
        let steps = (arc_deg / 10.0 * 10.0) as usize;
        for i in 0..=steps {
            let t = i as f64 * 0.1;
            let heading = (40.0 + t * 10.0).to_radians();
            // A grade of 4° and a bank of 2° that sway as it turns.
            let (roll, pitch) = (
                (2.0 * (0.3 * t).sin()).to_radians(),
                (4.0 + 1.5 * (0.2 * t).cos()).to_radians(),
            );
            let attitude = attitude_from_euler(roll, pitch, heading);
            let raw = soft * (attitude.inverse() * world) + hard;
            readings.push((t, raw, (roll, pitch), heading + gyro_offset_rad));
        }
        (readings, soft, hard)
    }

    fn calibrate(readings: &[Reading]) -> ArcCalibration {
        let mut arc = ArcCalibration::default();
        for &(t, raw, tilt, yaw) in readings {
            let gyro = GyroHeading {
                t,
                yaw_rad: yaw,
                bias_integral_rad: 0.0,
                bias_rad_per_s: 0.0,
                bias_sigma_rad_per_s: 0.0,
                tilt_sigma_rad: 0.001,
            };
            arc.add(raw, tilt, gyro, 60f64.to_radians());
        }
        arc
    }

    #[test]
    fn a_ninety_degree_arc_on_a_grade_recovers_the_heading() {
        let (readings, soft, hard) = arc_readings(100.0, 1.3);
        let arc = calibrate(&readings);
        let c = arc.correction().expect("a 100° arc calibrates");
        assert!((c.hard_iron_ut - hard).norm() < 1.0, "{}", c.hard_iron_ut);
        // The heading of level readings all round, through the correction.
        let inclination = 60f64.to_radians();
        let world = V3::new(inclination.cos(), 0.0, inclination.sin()) * 50.0;
        for k in 0..36 {
            let heading = (k as f64 * 10.0).to_radians();
            let attitude = attitude_from_euler(0.0, 0.0, heading);
            let raw = soft * (attitude.inverse() * world) + hard;
            let body = c.apply(&raw);
            let error = angle_difference(magnetic_heading(&body, 0.0, 0.0), heading);
            assert!(
                error.abs().to_degrees() < 1.0,
                "{k}: {}",
                error.to_degrees()
            );
        }
    }

    #[test]
    fn less_than_ninety_degrees_is_not_enough() {
        let (readings, _, _) = arc_readings(80.0, 0.0);
        assert!(calibrate(&readings).correction().is_none());
    }

    #[test]
    fn a_disturbance_on_the_arc_is_refused() {
        let (mut readings, _, _) = arc_readings(120.0, 0.0);
        // Steel passed by for half the arc: 25 µT along the body's y.
        for r in readings.iter_mut().skip(40).take(60) {
            r.1.y += 25.0;
        }
        let arc = calibrate(&readings);
        assert!(arc.correction().is_none(), "{:?}", arc.correction());
        assert!(arc.refused_fits() > 0);
    }
}
