//! The scalar Kalman filter run on each of the four angles (He et al. 2021,
//! Eq. 1–7) with Φ = Γ = H = 1: the angle is modelled as a random walk.

use serde::{Deserialize, Serialize};

/// One angle's filter state. Units are the caller's (radians in the engine).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ScalarKalman {
    /// Filtered value X̂(k|k).
    pub x: f64,
    /// Its variance P(k|k).
    pub p: f64,
    /// False until the first measurement, which initialises X̂ and P.
    pub initialised: bool,
}

impl ScalarKalman {
    /// Time update over one step whose process noise variance is `q`.
    pub fn predict(&mut self, q: f64) {
        // Eq. 3: X̂(k+1|k) = Φ X̂(k|k) with Φ = 1, so x is unchanged.
        // Eq. 4: P(k+1|k) = Φ P Φᵀ + Γ Q Γᵀ.
        self.p += q;
    }

    /// Measurement update with observation `y` of variance `r` (> 0).
    /// Returns the gain K used, 1 for the initialising measurement.
    pub fn update(&mut self, y: f64, r: f64) -> f64 {
        if !self.initialised {
            self.x = y;
            self.p = r;
            self.initialised = true;
            return 1.0;
        }
        let k = self.p / (self.p + r); // Eq. 5
        self.x += k * (y - self.x); // Eq. 6, ε = y − H X̂(k+1|k)
        self.p *= 1.0 - k; // Eq. 7 corrected to (I − K H) P⁻ (NOTES.md)
        k
    }

    /// Predict then update: one filter step.
    pub fn step(&mut self, y: f64, q: f64, r: f64) -> f64 {
        self.predict(q);
        self.update(y, r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_measurement_initialises() {
        let mut f = ScalarKalman::default();
        assert_eq!(f.step(2.0, 0.1, 0.5), 1.0);
        assert_eq!((f.x, f.p), (2.0, 0.5));
    }

    #[test]
    fn matches_hand_computed_steps() {
        // P⁻ = 0.5 + 0.1 = 0.6; K = 0.6 / 1.1; x = 2 + K (3 − 2); P = (1 − K) 0.6.
        let mut f = ScalarKalman::default();
        f.step(2.0, 0.1, 0.5);
        let k = f.step(3.0, 0.1, 0.5);
        assert!((k - 0.545_454_545_454_545_4).abs() < 1e-15);
        assert!((f.x - 2.545_454_545_454_545).abs() < 1e-15);
        assert!((f.p - 0.272_727_272_727_272_7).abs() < 1e-15);
    }

    #[test]
    fn variance_converges_with_corrected_eq7() {
        // The paper's printed (I + K H) would make P grow without bound.
        let (q, r) = (1e-4, 1e-2);
        let mut f = ScalarKalman::default();
        for _ in 0..1000 {
            f.step(0.0, q, r);
        }
        // Steady state of P⁻ solves P⁻² − q P⁻ − q r = 0.
        let p_prior = (q + (q * q + 4.0 * q * r).sqrt()) / 2.0;
        let p_post = p_prior * r / (p_prior + r);
        assert!((f.p - p_post).abs() < 1e-12, "{} vs {}", f.p, p_post);
    }
}
