//! The gyro bias as a random walk, estimated by a Kalman filter per axis
//! that is updated at every static reading and only predicted in between,
//! so a bias that warms up while driving is corrected at the next stop,
//! however brief, and its uncertainty is known (docs/engines/fuzzy.md:
//! gyro bias between stops).
//!
//! Per axis, with the bias b and its variance P:
//! - predict over dt:  P ← P + q·dt  (q: the random walk's density, rad²/s³);
//! - static reading ω with per-axis noise variance R and static weight
//!   w ∈ (0, 1]:  K = P / (P + R/w),  b ← b + K (ω − b),  P ← (1 − K) P.
//!
//! A reading that is only partly static counts with the larger variance
//! R/w: the less sure the expert, the less it moves the bias.

use serde::{Deserialize, Serialize};

use crate::fusion::geometry::V3;

/// A static spell shorter than this says too little about the bias, s.
const MIN_SPELL_S: f64 = 3.0;
/// The learnt density averages this many spells at most (then follows).
const MAX_SPELLS_AVERAGED: u32 = 8;
/// The learnt density is at least this fraction of the configured one.
const MIN_DENSITY_FRACTION: f64 = 0.04;

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

/// The random walk's density learnt from the data: how far the bias moved
/// between the ends of successive static spells, less what the filter's
/// own variance explains, q̂ = mean over axes of ((Δb)² − P₁ − P₀)/Δt,
/// averaged over the last spells. A sensor whose bias wanders more than
/// configured (a MEMS gyro warming) gets a larger q̂, so its bias σ, and
/// with it the tilt's and the heading's, grow faster while moving.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct WalkLearner {
    /// Start of the current static spell.
    spell_start_t: Option<f64>,
    /// End time, bias and variance of the last long spell.
    last_spell: Option<(f64, V3, V3)>,
    density: Option<f64>,
    spells: u32,
}

impl WalkLearner {
    /// Takes each reading's time, whether it is static, and the bias
    /// filter after it.
    pub fn observe(&mut self, t: f64, still: bool, bias: &GyroBias) {
        if still {
            self.spell_start_t.get_or_insert(t);
            // While the spell lasts its end is this reading.
            return;
        }
        let Some(start) = self.spell_start_t.take() else {
            return;
        };
        if t - start < MIN_SPELL_S {
            return;
        }
        if let Some((t0, b0, p0)) = self.last_spell
            && t > t0
        {
            let dt = t - t0;
            let sample = (0..3)
                .map(|k| ((bias.bias_rad_per_s[k] - b0[k]).powi(2) - bias.variance[k] - p0[k]) / dt)
                .sum::<f64>()
                / 3.0;
            let sample = sample.max(0.0);
            if sample.is_finite() {
                self.spells = (self.spells + 1).min(MAX_SPELLS_AVERAGED);
                let old = self.density.unwrap_or(sample);
                self.density = Some(old + (sample - old) / f64::from(self.spells));
            }
        }
        self.last_spell = Some((t, bias.bias_rad_per_s, bias.variance));
    }

    /// The density to predict with (rad²/s³): the learnt one once a pair of
    /// spells has been seen, at least `MIN_DENSITY_FRACTION` of
    /// `configured`; `configured` until then.
    pub fn density(&self, configured: f64) -> f64 {
        match self.density {
            Some(d) => d.max(configured * MIN_DENSITY_FRACTION),
            None => configured,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn filter(bias: f64, variance: f64) -> GyroBias {
        GyroBias {
            bias_rad_per_s: V3::repeat(bias),
            variance: V3::repeat(variance),
        }
    }

    #[test]
    fn the_walk_is_learnt_from_the_bias_moves_between_long_spells() {
        let mut walk = WalkLearner::default();
        assert_eq!(walk.density(2e-6), 2e-6);
        // Spell 0–10 s ends with bias 0 (variance 1e-6 per axis).
        walk.observe(0.0, true, &filter(0.0, 1e-6));
        walk.observe(10.0, false, &filter(0.0, 1e-6));
        // A 2 s spell is too short to say anything.
        walk.observe(50.0, true, &filter(0.5, 1e-6));
        walk.observe(52.0, false, &filter(0.5, 1e-6));
        assert_eq!(walk.density(2e-6), 2e-6);
        // Spell 100–110 s ends with bias 0.1: (0.01 − 2e-6)/100 per axis.
        walk.observe(100.0, true, &filter(0.1, 1e-6));
        walk.observe(110.0, false, &filter(0.1, 1e-6));
        assert!((walk.density(2e-6) - 0.009_998 / 100.0).abs() < 1e-12);
        // Then a bias that stays: the mean of 9.998e-5 and 0 (less the
        // variances, clamped at 0), at least 4 % of the configured.
        walk.observe(200.0, true, &filter(0.1, 1e-6));
        walk.observe(210.0, false, &filter(0.1, 1e-6));
        assert!((walk.density(2e-6) - 0.5 * 9.998e-5).abs() < 1e-12);
        assert_eq!(
            WalkLearner {
                density: Some(0.0),
                ..walk
            }
            .density(2e-6),
            0.04 * 2e-6
        );
    }

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
