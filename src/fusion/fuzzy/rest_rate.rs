//! The gyro at rest, block by block: what a static spell tells the bias
//! filter, and how far a block's mean rate wanders while the expert calls
//! the sensor static (docs/engines/fuzzy.md: gyro bias between stops).
//!
//! The readings are summed over consecutive blocks of N readings (the
//! motion window's length, about half a second). A block's mean rate m_k
//! and its mean stillness w_k (σ of the module documentation, step 3).
//! A sensor at rest reads its bias plus white noise, so two consecutive
//! static blocks differ only by the noise of their means, and half the
//! square of the difference estimates the variance of one mean:
//!
//!   s²_k = ½ (m_k − m_{k−1})²  (per axis, averaged over the three),
//!   σ̂²_k = σ̂²_{k−1} + α_k (s²_k − σ̂²_{k−1}),  α_k = max(1/k, 1/[`MEMORY`]).
//!
//! A standing person's slow sway or a rocking chassis (0.1–1 Hz) turns the
//! sensor to and fro within a few blocks: its rates are not white, their
//! mean over half a second is the sway, not the bias, and σ̂² grows to its
//! size. The bias filter takes each static block's mean with
//! R = max(R_white/N, σ̂²)/w_k per axis (R_white: the per-reading noise
//! variance), so sway is averaged over many blocks instead of learnt in
//! one; no block updates the bias before [`MIN_DIFFERENCES`] differences
//! have been seen, nor the first block of a spell (it has no predecessor,
//! and may hold the end of a motion). The estimate carries over from one
//! spell to the next. A block is static when its mean stillness is at
//! least [`STATIC_BLOCK`].

use serde::{Deserialize, Serialize};

use crate::fusion::geometry::V3;

/// Blocks over which σ̂² is averaged (10 s of half-second blocks).
pub const MEMORY: f64 = 20.0;
/// Differences seen before the first update.
pub const MIN_DIFFERENCES: u32 = 4;
/// A block whose mean stillness is at least this is static.
pub const STATIC_BLOCK: f64 = 0.5;

/// A static block's mean rate, to update the bias filter with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlockMean {
    /// m_k, rad/s.
    pub rate_rad_per_s: V3,
    /// R per axis, (rad/s)², already divided by the block's stillness.
    pub noise_variance: f64,
}

/// The running blocks and σ̂²; see the module documentation.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct RestRate {
    sum_rate: V3,
    sum_stillness: f64,
    count: u32,
    /// m_{k−1}, if that block was static.
    previous_mean: Option<V3>,
    /// σ̂² per axis, (rad/s)².
    wander_variance: f64,
    differences: u32,
}

impl RestRate {
    /// The per-axis variance of a static block's mean beyond what the
    /// white noise explains, (rad/s)²: 0 before any difference was seen.
    pub fn wander_variance(&self) -> f64 {
        self.wander_variance
    }

    /// A gap in the readings: the current block and spell start afresh.
    pub fn interrupted(&mut self) {
        self.sum_rate = V3::zeros();
        self.sum_stillness = 0.0;
        self.count = 0;
        self.previous_mean = None;
    }

    /// One reading's rate (rad/s) and stillness, in blocks of
    /// `block_readings`; `white_variance` is the per-reading noise variance
    /// per axis. Returns the block's mean when a static block completes
    /// and may update the bias.
    pub fn push(
        &mut self,
        rate: &V3,
        stillness: f64,
        block_readings: usize,
        white_variance: f64,
    ) -> Option<BlockMean> {
        self.sum_rate += rate;
        self.sum_stillness += stillness;
        self.count += 1;
        if (self.count as usize) < block_readings.max(1) {
            return None;
        }
        let n = f64::from(self.count);
        let mean = self.sum_rate / n;
        let still = self.sum_stillness / n;
        self.sum_rate = V3::zeros();
        self.sum_stillness = 0.0;
        self.count = 0;
        if still < STATIC_BLOCK {
            self.previous_mean = None;
            return None;
        }
        let previous = self.previous_mean.replace(mean)?;
        let half_square = 0.5 * (mean - previous).norm_squared() / 3.0;
        self.differences += 1;
        let alpha = (1.0 / f64::from(self.differences)).max(1.0 / MEMORY);
        self.wander_variance += alpha * (half_square - self.wander_variance);
        if self.differences < MIN_DIFFERENCES {
            return None;
        }
        Some(BlockMean {
            rate_rad_per_s: mean,
            noise_variance: (white_variance / n).max(self.wander_variance) / still,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn static_blocks_estimate_how_far_their_means_wander() {
        let mut rest = RestRate::default();
        let white = 1e-6;
        // Blocks of 2 readings; means 0, 0.02, 0, 0.02, ... on x only.
        let mut outputs = Vec::new();
        for k in 0..6 {
            let x = if k % 2 == 0 { 0.0 } else { 0.02 };
            assert!(rest.push(&V3::new(x, 0.0, 0.0), 1.0, 2, white).is_none());
            outputs.push(rest.push(&V3::new(x, 0.0, 0.0), 1.0, 2, white));
        }
        // Every difference is 0.02 on one axis: s² = ½·4e-4/3 each, so the
        // running mean is that from the first difference on.
        let s2 = 0.5 * 4e-4 / 3.0;
        assert!((rest.wander_variance() - s2).abs() < 1e-15);
        // No update on the first block, nor before four differences.
        assert!(outputs[..4].iter().all(Option::is_none));
        let update = outputs[4].expect("the fifth block updates");
        assert_eq!(update.rate_rad_per_s, V3::zeros());
        assert!((update.noise_variance - s2).abs() < 1e-15);
    }

    #[test]
    fn a_quiet_gyro_uses_its_white_noise_and_motion_breaks_the_spell() {
        let mut rest = RestRate::default();
        let white = 1e-4;
        let mut last = None;
        for _ in 0..10 {
            for _ in 0..4 {
                last = rest.push(&V3::new(0.01, 0.0, 0.0), 1.0, 4, white);
            }
        }
        // Identical means: σ̂² = 0, R = white/N.
        assert_eq!(last.unwrap().noise_variance, white / 4.0);
        // A block of mean stillness 0.4 is not static; the next static
        // block has no predecessor.
        for _ in 0..4 {
            assert!(rest.push(&V3::zeros(), 0.4, 4, white).is_none());
        }
        for _ in 0..4 {
            assert!(rest.push(&V3::zeros(), 1.0, 4, white).is_none());
        }
        // The one after it differs from it by nothing: an update again.
        for _ in 0..3 {
            assert!(rest.push(&V3::zeros(), 1.0, 4, white).is_none());
        }
        let update = rest.push(&V3::zeros(), 0.6, 4, white).expect("static");
        // Its stillness, (3·1 + 0.6)/4 = 0.9, divides R.
        assert!((update.noise_variance - white / 4.0 / 0.9).abs() < 1e-18);
    }
}
