//! How far one rest interval's mean gyro rate can be trusted: the noise of
//! the zero-angular-rate update (ZARU), estimated from the rates
//! themselves.
//!
//! At rest the bias-corrected gyro reads the Earth's rotation, and the
//! ZARU takes each filter interval's mean rate m_k as a measurement of it
//! ([`super::eskf::zaru_matrix`]). The angle random walk alone gives that
//! mean a variance ARW²/T. Machinery running beside a standing machine (a
//! power pack, a pump) adds an angular vibration of a few thousandths of a
//! degree per second; its mean over T = 0.1 s does not average out, and at
//! tens of degrees per hour it is many times the ARW's share. A filter that
//! believes ARW²/T takes that vibration for a gyro bias and, through the
//! bias's correlation with the heading it drove during the last push, turns
//! the heading by up to a degree at the first updates of a rest.
//!
//! The rates tell how large that noise is. The Earth's rate and the biases
//! do not change within a rest, so two consecutive still means differ only
//! by their noise, and half the square of their difference estimates the
//! variance of one:
//!
//!   s²_k = ½ (m_k − m_{k−1})²  (per axis),
//!   σ̂²_k = σ̂²_{k−1} + α_k (s²_k − σ̂²_{k−1}),  α_k = max(1/k, 1/[`MEMORY`]).
//!
//! The update's variance is then R = max(ARW²/T, σ̂²) + σ_settle² per axis
//! (σ_settle: `zaru_sigma_deg_per_h`). No update is made until
//! [`MIN_DIFFERENCES`] differences have been seen, nor on the first still
//! interval of a rest (it has no predecessor to differ from). Vibration that
//! changes over tens of seconds is followed within [`MEMORY`] intervals;
//! the estimate carries over from one rest to the next.

use serde::{Deserialize, Serialize};

use crate::fusion::geometry::V3;

/// Intervals over which σ̂² is averaged (2 s at the default 0.1 s period).
pub const MEMORY: f64 = 20.0;
/// Differences seen before the first update: fewer leave σ̂² too uncertain
/// (with 10, consecutive differences sharing a mean, it is below a third
/// of the truth with probability about 5 %).
pub const MIN_DIFFERENCES: u32 = 10;

/// The running estimate; see the module documentation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct ZaruNoise {
    /// m_{k−1}: the previous interval's mean rate, rad/s, if it was still.
    previous_mean: Option<V3>,
    /// σ̂² per axis, (rad/s)².
    variance: V3,
    /// Differences seen since alignment.
    differences: u32,
}

impl ZaruNoise {
    /// An interval that was not still: the next still one starts afresh.
    pub fn interrupted(&mut self) {
        self.previous_mean = None;
    }

    /// A still interval's mean rate m_k, rad/s (raw: the filter's bias
    /// corrections would otherwise count as noise). Returns the variance per
    /// axis of m_k's noise, (rad/s)², at least `floor` (ARW²/T), when an
    /// update may be made on it.
    pub fn still(&mut self, mean_rate: &V3, floor: f64) -> Option<V3> {
        let previous = self.previous_mean.replace(*mean_rate)?;
        let difference = mean_rate - previous;
        let sample = difference.component_mul(&difference) * 0.5;
        self.differences = self.differences.saturating_add(1);
        let alpha = (1.0 / f64::from(self.differences)).max(1.0 / MEMORY);
        self.variance += (sample - self.variance) * alpha;
        (self.differences >= MIN_DIFFERENCES).then(|| self.variance.map(|v| v.max(floor)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_steady_rate_leaves_the_floor_and_an_alternating_one_is_measured() {
        let mut noise = ZaruNoise::default();
        let floor = 1e-12;
        // The first still interval has nothing to differ from.
        assert_eq!(noise.still(&V3::new(1e-5, 0.0, 0.0), floor), None);
        for k in 1..MIN_DIFFERENCES {
            assert_eq!(noise.still(&V3::new(1e-5, 0.0, 0.0), floor), None, "{k}");
        }
        // Ten differences of zero: the floor.
        let r = noise.still(&V3::new(1e-5, 0.0, 0.0), floor).unwrap();
        assert_eq!(r, V3::repeat(floor));

        // Means alternating ±a about the Earth's rate on one axis: every
        // difference is 2a, so s² = ½(2a)² = 2a²; after many intervals σ̂²
        // approaches 2a² (an overestimate of a² for such a tone, on the
        // safe side).
        let a = 1e-4;
        let mut r = V3::zeros();
        for k in 0..200 {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            r = noise.still(&V3::new(1e-5, 0.0, sign * a), floor).unwrap();
        }
        assert!((r.z - 2.0 * a * a).abs() < 1e-3 * a * a, "{r}");
        assert_eq!(r.y, floor);
    }

    #[test]
    fn an_interruption_waits_for_a_second_still_interval() {
        let mut noise = ZaruNoise::default();
        for _ in 0..=MIN_DIFFERENCES {
            noise.still(&V3::zeros(), 1e-12);
        }
        noise.interrupted();
        // A push in between: the next still mean has no predecessor.
        assert_eq!(noise.still(&V3::repeat(1.0), 1e-12), None);
        // The one after differs from it by 1: s² = ½, weighed by α of the
        // eleventh difference.
        let r = noise.still(&V3::repeat(0.0), 1e-12).unwrap();
        let alpha = (1.0 / f64::from(MIN_DIFFERENCES + 1)).max(1.0 / MEMORY);
        assert!((r.x - 0.5 * alpha).abs() < 1e-12, "{r}");
    }
}
