//! The planar calibration of a ground vehicle's magnetometer: 2-D hard and
//! soft iron in the body x–y plane, the vertical offset sized by the
//! site's inclination.
//!
//! A vehicle turns about its vertical axis, so its field traces a circle
//! whose vertical part barely changes; the vertical soft iron is
//! unobservable and keeps unit scale. Two fits:
//! - [`fit_planar`], the conic [x² y² 2xy 2x 2y]·p = 1 through readings
//!   taken level (linear least squares); the vertical offset makes the
//!   mean vertical field R·tan I, R the corrected horizontal radius.
//! - [`fit_levelled`] (issue 34), through readings taken at any tilt:
//!   each is levelled by the filter's roll and pitch when it was taken,
//!   l = C (S (m − b)), C = R_y(θ) R_x(φ), and the model asks the levelled
//!   field to have the horizontal radius H and the vertical H·tan I:
//!   minimise Σ (‖l_xy‖ − H)² + (l_z − H·tan I)² over the 3-D hard iron b,
//!   the soft iron S = [[exp K, 0], [cᵀ, 1]] with K symmetric and
//!   traceless (det exp K = 1) and c the vertical's coupling to the two
//!   horizontal axes, and H: eight unknowns, by Levenberg–Marquardt
//!   (steps (JᵀJ + λ·diag JᵀJ) δ = −Jᵀr, λ divided by 10 after a step
//!   that lowers the cost, multiplied by 10 until one does) from the conic through the
//!   levelled raw readings (and from the circle through them: the better
//!   end is kept). On a graded road (a calibration circle on a
//!   5° slope) a level-only fit has no readings; a fit that ignored the
//!   tilt would take the vertical field's share in the body x–y plane,
//!   sin 5° × H·tan 60° ≈ 15 % of H, for hard iron.

use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector2};

use super::magcal::{Correction, Tilted, magnitude, normaliser, radius_rms, sqrt_spd2};
use crate::fusion::geometry::V3;

/// Levenberg–Marquardt iterations at most.
const MAX_ITERATIONS: usize = 50;
/// Stop when an iteration lowers the cost by less than this fraction.
const CONVERGED: f64 = 1e-12;

/// Least-squares conic fit through readings taken level (module
/// documentation).
pub fn fit_planar(samples: &[V3], inclination_rad: f64) -> Option<Correction> {
    if samples.len() < 5 {
        return None;
    }
    let (mean, _) = normaliser(samples);
    let n = samples.len() as f64;
    let scale = (samples
        .iter()
        .map(|s| (s.x - mean.x).powi(2) + (s.y - mean.y).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    if scale <= 0.0 {
        return None;
    }
    let mut normal = SMatrix::<f64, 5, 5>::zeros();
    let mut rhs = SVector::<f64, 5>::zeros();
    for s in samples {
        let (x, y) = ((s.x - mean.x) / scale, (s.y - mean.y) / scale);
        let row = SVector::<f64, 5>::from([x * x, y * y, 2.0 * x * y, 2.0 * x, 2.0 * y]);
        normal += row * row.transpose();
        rhs += row;
    }
    let v = normal.cholesky()?.solve(&rhs);
    let q = Matrix2::new(v[0], v[2], v[2], v[1]);
    let u = Vector2::new(v[3], v[4]);
    let centre = -(q.try_inverse()? * u);
    let k = 1.0 + centre.dot(&(q * centre));
    if k <= 0.0 {
        return None;
    }
    let root = sqrt_spd2(&(q / k))?;
    let det = root.determinant();
    if det <= 0.0 {
        return None;
    }
    let soft_iron = planar_soft_iron(&(root / det.sqrt()));
    let horizontal = |m: &V3, hard_iron: &V3| (soft_iron * (m - hard_iron)).xy().norm();
    let mut hard_iron_ut = V3::new(mean.x + centre.x * scale, mean.y + centre.y * scale, 0.0);
    let radius = samples
        .iter()
        .map(|m| horizontal(m, &hard_iron_ut))
        .sum::<f64>()
        / n;
    hard_iron_ut.z = mean.z - radius * inclination_rad.tan();
    let fit_rms = radius_rms(samples, |m| horizontal(m, &hard_iron_ut));
    Some(Correction {
        hard_iron_ut,
        soft_iron,
        fit_rms,
    })
}

/// The least-squares circle x² + y² = 2a·x + 2b·y + c through readings
/// taken level (hard iron only), its vertical offset as [`fit_planar`]'s.
fn fit_circle(samples: &[V3], inclination_rad: f64) -> Option<Correction> {
    if samples.len() < 3 {
        return None;
    }
    let (mean, _) = normaliser(samples);
    let mut normal = Matrix3::<f64>::zeros();
    let mut rhs = V3::zeros();
    for s in samples {
        let (x, y) = (s.x - mean.x, s.y - mean.y);
        let row = V3::new(2.0 * x, 2.0 * y, 1.0);
        normal += row * row.transpose();
        rhs += row * (x * x + y * y);
    }
    let v = normal.cholesky()?.solve(&rhs);
    let radius_squared = v.z + v.x * v.x + v.y * v.y;
    if radius_squared <= 0.0 {
        return None;
    }
    let radius = radius_squared.sqrt();
    let hard_iron_ut = V3::new(
        mean.x + v.x,
        mean.y + v.y,
        mean.z - radius * inclination_rad.tan(),
    );
    let fit_rms = radius_rms(samples, |m| (m - hard_iron_ut).xy().norm());
    Some(Correction {
        hard_iron_ut,
        soft_iron: Matrix3::identity(),
        fit_rms,
    })
}

/// How many unknowns the levelled fit has.
const UNKNOWNS: usize = 8;
/// Where H is among them.
const RADIUS: usize = 7;
/// The unknowns of the levelled fit: hard iron (µT), the two entries of
/// K, the vertical's coupling to the two horizontal axes, and the
/// horizontal radius H (µT).
type Unknowns = SVector<f64, UNKNOWNS>;

/// diag(S2, 1).
fn planar_soft_iron(s2: &Matrix2<f64>) -> Matrix3<f64> {
    let mut soft_iron = Matrix3::identity();
    soft_iron.fixed_view_mut::<2, 2>(0, 0).copy_from(s2);
    soft_iron
}

/// exp K for K = [[k1, k2], [k2, −k1]]: cosh r·I + sinh r / r·K with
/// r = √(k1² + k2²) (K² = r² I), symmetric with determinant 1.
fn exp_traceless(k1: f64, k2: f64) -> Matrix2<f64> {
    let r = k1.hypot(k2);
    let shr = if r > 1e-12 { r.sinh() / r } else { 1.0 };
    let c = r.cosh();
    Matrix2::new(c + shr * k1, shr * k2, shr * k2, c - shr * k1)
}

/// (k1, k2) with exp K = `s2` (symmetric, positive definite, det 1).
fn log_traceless(s2: &Matrix2<f64>) -> Option<(f64, f64)> {
    let eigen = nalgebra::SymmetricEigen::new(*s2);
    if eigen
        .eigenvalues
        .iter()
        .any(|&l| l <= 0.0 || !l.is_finite())
    {
        return None;
    }
    let v = eigen.eigenvectors;
    let k = v * Matrix2::from_diagonal(&eigen.eigenvalues.map(f64::ln)) * v.transpose();
    Some((0.5 * (k[(0, 0)] - k[(1, 1)]), k[(0, 1)]))
}

/// The correction the unknowns stand for (its `fit_rms` not yet known).
fn correction(x: &Unknowns) -> Correction {
    let mut soft_iron = planar_soft_iron(&exp_traceless(x[3], x[4]));
    soft_iron[(2, 0)] = x[5];
    soft_iron[(2, 1)] = x[6];
    Correction {
        hard_iron_ut: V3::new(x[0], x[1], x[2]),
        soft_iron,
        fit_rms: f64::NAN,
    }
}

/// The horizontal and vertical residuals of every reading, µT.
fn residuals(readings: &[Tilted], tan_inclination: f64, x: &Unknowns, out: &mut Vec<f64>) {
    let c = correction(x);
    out.clear();
    for r in readings {
        let level = r.seen(Some(&c), true);
        out.push(level.xy().norm() - x[RADIUS]);
        out.push(level.z - x[RADIUS] * tan_inclination);
    }
}

fn cost(residuals: &[f64]) -> f64 {
    residuals.iter().map(|r| r * r).sum()
}

/// Rounds of refitting without the readings far off the fit.
const OUTLIER_ROUNDS: usize = 3;
/// A reading off the fit by less than this share of H is never an outlier.
const MIN_OUTLIER_ERROR: f64 = 0.03;

/// The levelled fit through readings at any tilt (module documentation),
/// refitted up to `OUTLIER_ROUNDS` times without the readings whose
/// residual (horizontal and vertical together) is over three times the
/// RMS, at least `MIN_OUTLIER_ERROR` of H: readings taken next to a
/// magnet before any calibration could tell them must not bend it. At
/// least half the readings are kept. `fit_rms` is the levelled
/// horizontal radius's relative RMS on the readings kept. `None` when
/// neither the conic nor the circle starts it, or the result is not
/// finite or has no positive radius.
pub fn fit_levelled(readings: &[Tilted], inclination_rad: f64) -> Option<Correction> {
    if readings.len() < 8 {
        return None;
    }
    let tan_inclination = inclination_rad.tan();
    // Two starts, the better end kept: the conic through the levelled raw
    // readings, and the circle through them (no soft iron; an ellipse
    // through a partial arc can be far off), each centre taken back to
    // the body by the mean levelling.
    let levelled: Vec<V3> = readings.iter().map(|r| r.levelling * r.field_ut).collect();
    let mean_levelling = readings.iter().fold(Matrix3::zeros(), |m, r| {
        m + r.levelling.to_rotation_matrix().into_inner()
    }) / readings.len() as f64;
    let mut x = [
        fit_planar(&levelled, inclination_rad),
        fit_circle(&levelled, inclination_rad),
    ]
    .into_iter()
    .flatten()
    .filter_map(|first| {
        let hard_iron = mean_levelling.transpose() * first.hard_iron_ut;
        let (k1, k2) = log_traceless(&first.soft_iron.fixed_view::<2, 2>(0, 0).into_owned())?;
        let radius = levelled
            .iter()
            .map(|m| first.apply(m).xy().norm())
            .sum::<f64>()
            / levelled.len() as f64;
        let start = Unknowns::from([
            hard_iron.x,
            hard_iron.y,
            hard_iron.z,
            k1,
            k2,
            0.0,
            0.0,
            radius,
        ]);
        Some(levenberg_marquardt(readings, tan_inclination, start))
    })
    .min_by(|a, b| a.1.total_cmp(&b.1))?
    .0;
    let mut kept: Vec<Tilted> = readings.to_vec();
    let mut errors = reading_errors(&kept, tan_inclination, &x);
    for _ in 0..OUTLIER_ROUNDS {
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        let limit = (3.0 * rms).max(MIN_OUTLIER_ERROR * x[RADIUS].abs());
        let inliers: Vec<Tilted> = kept
            .iter()
            .zip(&errors)
            .filter(|(_, e)| **e <= limit)
            .map(|(r, _)| *r)
            .collect();
        if inliers.len() == kept.len() || inliers.len() < readings.len() / 2 {
            break;
        }
        kept = inliers;
        x = levenberg_marquardt(&kept, tan_inclination, x).0;
        errors = reading_errors(&kept, tan_inclination, &x);
    }
    if !x.iter().all(|v| v.is_finite()) || x[RADIUS] <= 0.0 {
        return None;
    }
    let mut fitted = correction(&x);
    fitted.fit_rms = radius_rms(&kept, |r| magnitude(r, Some(&fitted), true));
    Some(fitted)
}

/// Each reading's residual, horizontal and vertical together, µT.
fn reading_errors(readings: &[Tilted], tan_inclination: f64, x: &Unknowns) -> Vec<f64> {
    let mut r = Vec::with_capacity(2 * readings.len());
    residuals(readings, tan_inclination, x, &mut r);
    r.chunks(2).map(|pair| pair[0].hypot(pair[1])).collect()
}

/// Levenberg–Marquardt from `start`: the unknowns with the least sum of
/// squared residuals it reaches, and that sum.
fn levenberg_marquardt(
    readings: &[Tilted],
    tan_inclination: f64,
    start: Unknowns,
) -> (Unknowns, f64) {
    let mut x = start;
    let mut r = Vec::with_capacity(2 * readings.len());
    residuals(readings, tan_inclination, &x, &mut r);
    let mut current = cost(&r);
    let mut damping = 1e-3;
    let (mut plus, mut minus) = (Vec::new(), Vec::new());
    let mut columns = vec![vec![0.0; r.len()]; UNKNOWNS];
    for _ in 0..MAX_ITERATIONS {
        // The Jacobian by central differences: µT-sized steps for the
        // offsets and the radius, small ones for K.
        for (j, column) in columns.iter_mut().enumerate() {
            let step = if (3..RADIUS).contains(&j) {
                1e-6
            } else {
                1e-6 * x[RADIUS].abs().max(1.0)
            };
            let mut shifted = x;
            shifted[j] += step;
            residuals(readings, tan_inclination, &shifted, &mut plus);
            shifted[j] -= 2.0 * step;
            residuals(readings, tan_inclination, &shifted, &mut minus);
            for ((c, p), m) in column.iter_mut().zip(&plus).zip(&minus) {
                *c = (p - m) / (2.0 * step);
            }
        }
        let mut normal = SMatrix::<f64, UNKNOWNS, UNKNOWNS>::zeros();
        let mut gradient = Unknowns::zeros();
        for i in 0..UNKNOWNS {
            gradient[i] = columns[i].iter().zip(&r).map(|(a, b)| a * b).sum();
            for j in i..UNKNOWNS {
                let v: f64 = columns[i].iter().zip(&columns[j]).map(|(a, b)| a * b).sum();
                normal[(i, j)] = v;
                normal[(j, i)] = v;
            }
        }
        // Damped steps until one lowers the cost.
        let mut improved = None;
        while damping < 1e12 {
            let mut damped = normal;
            for i in 0..UNKNOWNS {
                damped[(i, i)] += damping * normal[(i, i)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|c| c.solve(&-gradient)) else {
                damping *= 10.0;
                continue;
            };
            let candidate = x + step;
            residuals(readings, tan_inclination, &candidate, &mut plus);
            let candidate_cost = cost(&plus);
            if candidate_cost.is_finite() && candidate_cost < current {
                improved = Some((candidate, candidate_cost));
                damping = (damping * 0.1).max(1e-12);
                break;
            }
            damping *= 10.0;
        }
        let Some((candidate, candidate_cost)) = improved else {
            break;
        };
        let gain = (current - candidate_cost) / current.max(f64::MIN_POSITIVE);
        x = candidate;
        current = candidate_cost;
        std::mem::swap(&mut r, &mut plus);
        if gain < CONVERGED {
            break;
        }
    }
    (x, current)
}
