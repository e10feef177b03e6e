//! The `attitude` engine's lag watch (issue 54): a filter too slow for the
//! shield's motion, seen in its inclinometer innovations.
//!
//! The filters carry pitch and roll with a rate that changes only as fast
//! as the process noise allows. When the shield turns harder than that (a
//! roll the cutterhead torque starts), the estimate lags the readings, and
//! its σ, which knows nothing of the lag, stays small until the next laser
//! sample: on the envelope the roll fell 0.044° behind with σ 0.0065°
//! (seed 1). The innovations say so first: while the estimate lags, they
//! share a sign. Over the last [`WINDOW`] readings their mean m has,
//! under no lag, the standard error s/√W (s the innovations' σ, the
//! inclinometer monitor's: the filter's √S or their own robust spread if
//! larger). Beyond [`LAG_SIGMAS`] standard errors the mean is a lag of
//! about m, and m² joins the estimate's variance. The estimate itself is
//! left as the paper's filter makes it; only its σ is honest about it.
//!
//! With Gaussian innovations a window's mean passes 3 standard errors
//! by chance in 0.27 % of windows, which then widen σ by about 3s/√W.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// Readings whose innovations are averaged.
pub const WINDOW: usize = 8;
/// A mean beyond this many standard errors is a lag.
pub const LAG_SIGMAS: f64 = 3.0;

/// What the watch remembers: the newest innovations and their σ, pitch
/// and roll, rad.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LagWatch {
    recent: [VecDeque<(f64, f64)>; 2],
}

impl LagWatch {
    /// A fused reading's innovations `(ν, σ)`, pitch and roll (rad).
    pub fn observe(&mut self, innovations: [(f64, f64); 2]) {
        for (recent, innovation) in self.recent.iter_mut().zip(innovations) {
            if recent.len() == WINDOW {
                recent.pop_front();
            }
            recent.push_back(innovation);
        }
    }

    /// What the lag adds to the variance of pitch and roll, rad²: the
    /// window's mean innovation squared where it is a lag, else 0.
    pub fn variance(&self) -> [f64; 2] {
        [0, 1].map(|axis| {
            let recent = &self.recent[axis];
            if recent.len() < WINDOW {
                return 0.0;
            }
            let n = recent.len() as f64;
            let mean = recent.iter().map(|(nu, _)| nu).sum::<f64>() / n;
            let variance = recent.iter().map(|(_, s)| s * s).sum::<f64>() / n;
            let standard_error = (variance / n).sqrt();
            if mean.abs() > LAG_SIGMAS * standard_error {
                mean * mean
            } else {
                0.0
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mean_beyond_three_standard_errors_is_a_lag_and_its_square_joins_the_variance() {
        let mut watch = LagWatch::default();
        // Seven readings: no window yet.
        for _ in 0..7 {
            watch.observe([(0.02, 0.01), (0.01, 0.01)]);
        }
        assert_eq!(watch.variance(), [0.0, 0.0]);
        watch.observe([(0.02, 0.01), (0.01, 0.01)]);
        // Standard error 0.01/√8 = 0.003536: a mean of 0.02 is 5.66 of
        // them (a lag: 0.02² added), one of 0.01 is 2.83 (none).
        let [pitch, roll] = watch.variance();
        assert!((pitch - 4e-4).abs() < 1e-15, "{pitch}");
        assert_eq!(roll, 0.0);
        // Innovations that alternate in sign average to nothing.
        for k in 0..8 {
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            watch.observe([(0.02 * sign, 0.01), (0.0, 0.01)]);
        }
        assert_eq!(watch.variance(), [0.0, 0.0]);
    }
}
