//! The fast part of a window's spread: what is left of a signal once a
//! cubic in time, fitted over the window by least squares, is taken out
//! (docs/engines/fuzzy.md: motion state).
//!
//! A standing person's sway or a rocking chassis turns the sensor slowly
//! (0.1–1 Hz): over a window of half a second its rates are nearly a
//! cubic, and the fit takes them out (a 1 Hz swing keeps 2 % of its
//! spread, 1.25 Hz 4 %, 0.5 Hz 0.1 %, 0.1 Hz nothing). Road vibration,
//! wheels and engines shake the sensor faster (a 4 Hz swing keeps 91 %,
//! 6 Hz 95 %). White noise of σ per axis leaves a residual sum of
//! squares of 3σ²·(n − 4), and the fast spread √(RSS·(n − 1)/(n·(n − 4)))
//! has the plain spread's expectation 3σ²·(n − 1)/n for it, so the noise
//! floors learnt from it keep their meaning.
//!
//! With j = 0 … n − 1 the readings' places in the window, oldest first,
//! the window keeps the moments M_k = Σ j^k·x_j (k = 0 … 3) per axis and
//! Σ‖x_j‖². The residual sum of squares of the fit is
//!
//!   RSS = Σ‖x_j‖² − Σ_axes mᵀ G⁻¹ m,  G_kl = Σ_j u_j^(k+l),  m_k = Σ_j u_j^k x_j,
//!
//! in the scaled place u_j = j/n (so G stays well conditioned for long
//! windows). When the oldest reading leaves, every place drops by one and
//! the moments follow the binomial expansion of (j − 1)^k (M₀ without the
//! leaver, whose place 0 adds nothing to the others).

use nalgebra::{Matrix4, Vector4};
use serde::{Deserialize, Serialize};

use crate::fusion::geometry::V3;

/// The moments M_k = Σ j^k·x_j, k = 1, 2, 3, of a vector series (M₀, the
/// plain sum, and Σ‖x‖² are kept by the window itself).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TrendMoments {
    moments: [V3; 3],
}

impl TrendMoments {
    /// The oldest reading has left (taken out of `sum_without_leaver`, the
    /// plain sum): every remaining place drops by one, so
    /// M₃ ← M₃ − 3M₂ + 3M₁ − M₀, M₂ ← M₂ − 2M₁ + M₀, M₁ ← M₁ − M₀.
    pub fn shift(&mut self, sum_without_leaver: &V3) {
        let [m1, m2, m3] = self.moments;
        let m0 = *sum_without_leaver;
        self.moments = [m1 - m0, m2 - 2.0 * m1 + m0, m3 - 3.0 * m2 + 3.0 * m1 - m0];
    }

    /// Adds `x` at place `place`.
    pub fn push(&mut self, place: usize, x: &V3) {
        let j = place as f64;
        self.moments[0] += j * x;
        self.moments[1] += j * j * x;
        self.moments[2] += j * j * j * x;
    }

    /// Recomputed from the held series, oldest first.
    pub fn recompute<'a>(series: impl Iterator<Item = &'a V3>) -> TrendMoments {
        let mut moments = TrendMoments::default();
        for (place, x) in series.enumerate() {
            moments.push(place, x);
        }
        moments
    }

    /// √(RSS·(n − 1)/(n·(n − 4))) of the module documentation: the spread
    /// about the fitted cubic, on the plain spread's scale for white noise,
    /// for `n` readings with plain sum `sum` and Σ‖x‖²
    /// `sum_of_squares`; `gram_inverse` is [`scaled_gram_inverse`]`(n)`,
    /// kept by the caller for its full window. With fewer than 5 readings
    /// the fit leaves nothing to judge, and the spread about the mean is
    /// returned.
    pub fn fast_spread(
        &self,
        n: usize,
        sum: &V3,
        sum_of_squares: f64,
        gram_inverse: Option<&Matrix4<f64>>,
    ) -> f64 {
        let count = n as f64;
        let computed;
        let inverse = match gram_inverse {
            Some(inverse) if n >= 5 => inverse,
            _ => match (n >= 5).then(|| scaled_gram_inverse(n)).flatten() {
                Some(inverse) => {
                    computed = inverse;
                    &computed
                }
                None => {
                    let mean = sum / count.max(1.0);
                    return (sum_of_squares / count.max(1.0) - mean.norm_squared())
                        .max(0.0)
                        .sqrt();
                }
            },
        };
        let [m1, m2, m3] = self.moments;
        let mut explained = 0.0;
        for axis in 0..3 {
            let m = Vector4::new(
                sum[axis],
                m1[axis] / count,
                m2[axis] / count.powi(2),
                m3[axis] / count.powi(3),
            );
            explained += m.dot(&(inverse * m));
        }
        // White noise of σ per axis leaves E RSS = 3σ²(n − 4); scaled to
        // the plain spread's 3σ²(n − 1)/n, so the floors keep their meaning.
        let scale = (count - 1.0) / (count * (count - 4.0));
        ((sum_of_squares - explained) * scale).max(0.0).sqrt()
    }
}

/// G⁻¹ of the module documentation for `n` readings (at least 5), through
/// its Cholesky factor.
pub fn scaled_gram_inverse(n: usize) -> Option<Matrix4<f64>> {
    (n >= 5).then(|| scaled_gram(n).cholesky().map(|c| c.inverse()))?
}

/// G_kl = Σ_{j<n} (j/n)^(k+l), from the sums of powers of 0 … n − 1.
fn scaled_gram(n: usize) -> Matrix4<f64> {
    let m = n as f64 - 1.0;
    let m1 = m + 1.0;
    // Σ j^p for j = 0 … m, p = 0 … 6 (Faulhaber).
    let powers = [
        m1,
        m * m1 / 2.0,
        m * m1 * (2.0 * m + 1.0) / 6.0,
        (m * m1 / 2.0).powi(2),
        m * m1 * (2.0 * m + 1.0) * (3.0 * m * m + 3.0 * m - 1.0) / 30.0,
        (m * m1).powi(2) * (2.0 * m * m + 2.0 * m - 1.0) / 12.0,
        m * m1 * (2.0 * m + 1.0) * (3.0 * m.powi(4) + 6.0 * m.powi(3) - 3.0 * m + 1.0) / 42.0,
    ];
    let scale = n as f64;
    Matrix4::from_fn(|k, l| powers[k + l] / scale.powi((k + l) as i32))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Moments, sum and Σ‖x‖² of a series, each from scratch.
    fn spread_of(series: &[V3]) -> f64 {
        let sum: V3 = series.iter().sum();
        let squares: f64 = series.iter().map(|x| x.norm_squared()).sum();
        TrendMoments::recompute(series.iter()).fast_spread(series.len(), &sum, squares, None)
    }

    #[test]
    fn a_cubic_leaves_nothing() {
        let series: Vec<V3> = (0..50)
            .map(|j| {
                let t = f64::from(j) * 0.01;
                V3::new(
                    1.0 + 2.0 * t - 3.0 * t * t,
                    9.81,
                    -0.5 * t * t + 4.0 * t.powi(3),
                )
            })
            .collect();
        // Σ‖x‖² is about 4,800 here: what is left is rounding.
        assert!(spread_of(&series) < 1e-6, "{}", spread_of(&series));
    }

    #[test]
    fn an_alternating_series_keeps_nearly_all_its_spread() {
        // ±1 on one axis: spread about the mean 1; a cubic takes out
        // almost nothing of a sign that flips every reading.
        let series: Vec<V3> = (0..100)
            .map(|j| V3::new(if j % 2 == 0 { 1.0 } else { -1.0 }, 0.0, 0.0))
            .collect();
        // On the plain spread's scale: √(RSS·(n − 1)/(n·(n − 4))) with RSS
        // just under n = 100: about √(99/96) = 1.0155.
        let spread = spread_of(&series);
        assert!(
            (spread - (99.0_f64 / 96.0).sqrt()).abs() < 0.005,
            "{spread}"
        );
    }

    #[test]
    fn a_slow_swing_is_taken_out_and_a_fast_one_kept() {
        // 100 readings over half a second (module documentation: a 1 Hz
        // swing keeps 2 % of its spread, a 6 Hz one 95 %).
        let swing = |hz: f64| -> Vec<V3> {
            (0..100)
                .map(|j| {
                    let t = f64::from(j) * 0.005;
                    V3::new((std::f64::consts::TAU * hz * t + 0.3).sin(), 0.0, 0.0)
                })
                .collect()
        };
        let rms = std::f64::consts::FRAC_1_SQRT_2;
        assert!(spread_of(&swing(1.0)) < 0.03 * rms);
        assert!(spread_of(&swing(0.3)) < 0.001 * rms);
        assert!(spread_of(&swing(6.0)) > 0.9 * rms);
    }

    #[test]
    fn shifting_matches_recomputing() {
        let series: Vec<V3> = (0..80)
            .map(|j| {
                let j = f64::from(j);
                V3::new((0.37 * j).sin(), j * 0.01, (j * 0.11).cos() * 2.0)
            })
            .collect();
        let capacity = 30;
        let mut moments = TrendMoments::default();
        let mut sum = V3::zeros();
        for (i, x) in series.iter().enumerate() {
            if i >= capacity {
                sum -= series[i - capacity];
                moments.shift(&sum);
            }
            moments.push(i.min(capacity - 1), x);
            sum += x;
            if i + 1 >= capacity {
                // The window holds i − capacity + 1 … i.
                let held = &series[i + 1 - capacity..=i];
                let fresh = TrendMoments::recompute(held.iter());
                for (shifted, recomputed) in moments.moments.iter().zip(&fresh.moments) {
                    let size = recomputed.norm().max(1.0);
                    assert!((shifted - recomputed).norm() < 1e-9 * size);
                }
            }
        }
    }
}
