//! The `attitude` engine's loud readings (issue 54): what a reading fused
//! with a quiet phase's noise leaves in the angle when it was as loud as
//! an excavation.
//!
//! Each reading is fused with the noise of the phase the detector has
//! settled on (noise.rs, N1), whose level is smoothed over a minute. The
//! first readings of an excavation are still fused as quiet ones: with a
//! slow inclinometer (a reading every 25 s) several of them, each pulling
//! the estimate by the gain K of the quiet noise r_q while the reading's
//! noise is the vibrating r_v. On the envelope this put the pitch 0.03–
//! 0.04° off with a σ of 0.005° (seed 28). The estimate is left as the
//! paper's filter makes it; its σ takes what the gain let in.
//!
//! A reading is loud when its own noise sample is above the geometric
//! middle of the two phases' levels (`PhaseDetector::noise_phase`). Its
//! gain took in K²·(r_v − r_q) more variance than the filter's covariance
//! knows (Joseph's form with the true noise); each later reading keeps
//! (1 − K)² of what is left, as it keeps of any error in the angle:
//! v ← (1 − K)²·v + K²·(r_v − r_q), the second term 0 unless loud.

use serde::{Deserialize, Serialize};

/// The variance loud readings left in pitch and roll, rad².
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LoudReadings {
    variance: [f64; 2],
}

impl LoudReadings {
    /// A reading fused on `axis` (0 pitch, 1 roll) with the angle's gain
    /// `gain`; `missed_variance` is the noise its gain did not allow for
    /// (rad², 0 for a reading as loud as its phase).
    pub fn fused(&mut self, axis: usize, gain: f64, missed_variance: f64) {
        let left = &mut self.variance[axis];
        *left = (1.0 - gain).powi(2) * *left + gain * gain * missed_variance.max(0.0);
    }

    /// The variance to add to pitch and roll, rad².
    pub fn variance(&self) -> [f64; 2] {
        self.variance
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_loud_reading_leaves_its_gain_squared_times_the_missed_noise_and_later_ones_wear_it_off() {
        let mut loud = LoudReadings::default();
        // Gain 0.5, quiet noise 1, vibrating 10: 0.25 × 9 = 2.25.
        loud.fused(0, 0.5, 10.0 - 1.0);
        assert_eq!(loud.variance(), [2.25, 0.0]);
        // An ordinary reading with gain 0.2 keeps 0.64 of it: 1.44.
        loud.fused(0, 0.2, 0.0);
        assert!((loud.variance()[0] - 1.44).abs() < 1e-12);
        // A reading quieter than its phase takes nothing back.
        loud.fused(1, 0.5, -3.0);
        assert_eq!(loud.variance()[1], 0.0);
    }
}
