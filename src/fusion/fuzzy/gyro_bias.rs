//! The gyro bias as a random walk, estimated by a Kalman filter per axis
//! that is updated at every static reading and only predicted in between,
//! so a bias that warms up while driving is corrected at the next stop,
//! however brief, and its uncertainty is known (README: "The fuzzy
//! engine", gyro bias between stops).
//!
//! Per axis, with the bias b and its variance P:
//! - predict over dt:  P ← P + q·dt  (q: the random walk's density, rad²/s³);
//! - static reading ω with per-axis noise variance R and static weight
//!   w ∈ (0, 1]:  K = P / (P + R/w),  b ← b + K (ω − b),  P ← (1 − K) P.
//!
//! A reading that is only partly static counts with the larger variance
//! R/w: the less sure the expert, the less it moves the bias.

use serde::{Deserialize, Serialize};

use crate::fusion::zupt::strapdown::V3;

/// Bias, rad/s, and its variance per axis, rad²/s².
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GyroBias {
    pub bias_rad_per_s: V3,
    pub variance: V3,
}

impl GyroBias {
    /// Starts from a mean rate and the variance of that mean.
    pub fn new(bias_rad_per_s: V3, variance: f64) -> GyroBias {
        GyroBias {
            bias_rad_per_s,
            variance: V3::repeat(variance),
        }
    }

    /// Lets the bias wander for `dt_s` at `walk_density` (q, rad²/s³).
    pub fn predict(&mut self, dt_s: f64, walk_density: f64) {
        self.variance.add_scalar_mut(walk_density * dt_s);
    }

    /// One static reading `rate` (rad/s) with per-axis noise variance
    /// `noise_variance` (rad²/s²), counted with weight `weight` ∈ (0, 1].
    pub fn update(&mut self, rate: &V3, noise_variance: f64, weight: f64) {
        if weight <= 0.0 || noise_variance <= 0.0 {
            return;
        }
        let r = noise_variance / weight.min(1.0);
        for axis in 0..3 {
            let p = self.variance[axis];
            let gain = p / (p + r);
            self.bias_rad_per_s[axis] += gain * (rate[axis] - self.bias_rad_per_s[axis]);
            self.variance[axis] = (1.0 - gain) * p;
        }
    }

    /// One-sigma uncertainty per axis, rad/s.
    pub fn sigma_rad_per_s(&self) -> V3 {
        self.variance.map(|p| p.max(0.0).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_update_weighs_prior_and_reading_by_their_variances() {
        // P = 4, R = 1: K = 0.8, b = 0 + 0.8·(1 − 0) = 0.8, P = 0.8.
        let mut bias = GyroBias::new(V3::zeros(), 4.0);
        bias.update(&V3::new(1.0, 2.0, -1.0), 1.0, 1.0);
        assert!((bias.bias_rad_per_s - V3::new(0.8, 1.6, -0.8)).norm() < 1e-12);
        assert!((bias.variance - V3::repeat(0.8)).norm() < 1e-12);
        // Half static: R/w = 2, K = 0.8/2.8.
        bias.update(&V3::new(0.8 + 2.8, 0.0, 0.0), 1.0, 0.5);
        assert!((bias.bias_rad_per_s.x - 1.6).abs() < 1e-12);
    }

    #[test]
    fn a_still_gyro_averages_its_noise_and_the_walk_reopens_the_variance() {
        // n readings of a constant from an uninformative prior: the mean,
        // with variance R/n.
        let mut bias = GyroBias::new(V3::zeros(), 1e6);
        for _ in 0..100 {
            bias.update(&V3::new(0.01, 0.0, 0.0), 1e-4, 1.0);
        }
        assert!((bias.bias_rad_per_s.x - 0.01).abs() < 1e-9);
        assert!((bias.variance.x - 1e-6).abs() < 1e-9);
        bias.predict(60.0, 1e-8);
        assert!((bias.variance.x - (1e-6 + 6e-7)).abs() < 1e-12);
        assert!((bias.sigma_rad_per_s().x - 1.6e-6_f64.sqrt()).abs() < 1e-9);
    }
}
