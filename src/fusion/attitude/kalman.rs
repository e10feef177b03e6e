//! The Kalman filter of He et al. 2021, Eq. 1–7, with a state vector in
//! place of the paper's four scalar random walks. One filter runs per tilt
//! axis (pitch, roll); its states are
//!
//! x = [θ, θ̇, b]: the angle, its rate, and the inclinometer's residual
//! bias — what the error model has not explained (pitch) or the mounting
//! offset (roll).
//!
//! Motion over dt (Eq. 3–4 with Φ, Γ Q Γᵀ below): θ ← θ + θ̇·dt; θ̇ is a
//! random walk; θ may also take white steps; b is constant:
//!
//! Φ = [[1, dt, 0], [0, 1, 0], [0, 0, 1]],
//! Q = [[q_θ dt + q_θ̇ dt³/3, q_θ̇ dt²/2, 0], [q_θ̇ dt²/2, q_θ̇ dt, 0], [0, 0, 0]].
//!
//! The bias moves only where something can see it move: the engine grows
//! its variance just before each laser sample ([`TiltFilter::inflate_bias`])
//! by what the roll and the time since the previous one allow. Between
//! laser samples — and through a dropout — a change of the inclinometer is
//! therefore a change of the angle, never a drift of the bias.
//!
//! Measurements (Eq. 5–7, scalar): the corrected inclinometer z = θ + b
//! (H = [1, 0, 1]), the laser y = θ (H = [1, 0, 0]). Eq. 7 is used as
//! corrected in NOTES.md: P = (I − K H) P⁻.
//!
//! Units are the caller's (radians and seconds in the engine).

use serde::{Deserialize, Serialize};

/// Process noise intensities of one axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ProcessNoise {
    /// White steps of the angle, rad²/s.
    pub angle: f64,
    /// Random walk of the rate (white angular acceleration), rad²/s³.
    pub rate: f64,
}

/// Measurement rows H.
pub const H_INCLINOMETER: [f64; 3] = [1.0, 0.0, 1.0];
pub const H_LASER: [f64; 3] = [1.0, 0.0, 0.0];

/// One axis's filter: state and covariance (symmetric, stored whole).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TiltFilter {
    pub x: [f64; 3],
    pub p: [[f64; 3]; 3],
    /// Time of the state; `None` until the first inclinometer reading.
    pub t: Option<f64>,
}

/// The outcome of one measurement update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Innovation {
    /// z − H x̂⁻.
    pub value: f64,
    /// Its predicted variance S = H P⁻ Hᵀ + R.
    pub variance: f64,
}

impl TiltFilter {
    /// A filter that starts at the first inclinometer reading `z`: θ = z − b
    /// with b ~ N(0, `bias_sd`²), θ̇ ~ N(0, `rate_sd`²).
    pub fn start(t: f64, z: f64, r: f64, bias_sd: f64, rate_sd: f64) -> TiltFilter {
        let vb = bias_sd * bias_sd;
        TiltFilter {
            x: [z, 0.0, 0.0],
            p: [
                [vb + r, 0.0, -vb],
                [0.0, rate_sd * rate_sd, 0.0],
                [-vb, 0.0, vb],
            ],
            t: Some(t),
        }
    }

    /// Variance of w·θ + θ̇·`ahead_s` (w: the filter's weight in a blend
    /// with the held laser, 1 without) as a prediction of the angle
    /// `ahead_s` later: [w, a, 0] P [w, a, 0]ᵀ plus the angle's own motion
    /// over `ahead_s` (the Q of the module documentation).
    pub fn predicted_angle_variance(&self, w: f64, ahead_s: f64, q: &ProcessNoise) -> f64 {
        let p = &self.p;
        let a = ahead_s;
        w * w * p[0][0]
            + 2.0 * w * a * p[0][1]
            + a * a * p[1][1]
            + q.angle * a.abs()
            + q.rate * a.abs().powi(3) / 3.0
    }

    /// The angle θ̂.
    pub fn angle(&self) -> f64 {
        self.x[0]
    }

    /// The rate θ̂̇.
    pub fn rate(&self) -> f64 {
        self.x[1]
    }

    /// The bias b̂.
    pub fn bias(&self) -> f64 {
        self.x[2]
    }

    /// Eq. 3–4: the state moved to `t` (no-op for `t` at or before the
    /// state's time).
    #[inline]
    pub fn predict_to(&mut self, t: f64, q: &ProcessNoise) {
        let Some(from) = self.t else {
            return;
        };
        let dt = t - from;
        if dt <= 0.0 {
            return;
        }
        let p = &mut self.p;
        let dt2 = dt * dt;
        // Φ P Φᵀ, written out for Φ = [[1, dt, 0], [0, 1, 0], [0, 0, 1]].
        let p00 = p[0][0] + 2.0 * dt * p[0][1] + dt2 * p[1][1];
        let p01 = p[0][1] + dt * p[1][1];
        let p02 = p[0][2] + dt * p[1][2];
        p[0][0] = p00 + q.angle * dt + q.rate * dt2 * dt / 3.0;
        p[0][1] = p01 + q.rate * dt2 / 2.0;
        p[1][0] = p[0][1];
        p[0][2] = p02;
        p[2][0] = p02;
        p[1][1] += q.rate * dt;
        self.x[0] += self.x[1] * dt;
        self.t = Some(t);
    }

    /// The innovation a measurement would have, without taking it.
    pub fn innovation(&self, h: [f64; 3], z: f64, r: f64) -> Innovation {
        let p = &self.p;
        let mut s = r;
        for i in 0..3 {
            for j in 0..3 {
                s += h[i] * p[i][j] * h[j];
            }
        }
        let predicted = h[0] * self.x[0] + h[1] * self.x[1] + h[2] * self.x[2];
        Innovation {
            value: z - predicted,
            variance: s,
        }
    }

    /// Eq. 5–7 for a scalar measurement `z` = h·x + noise of variance `r`.
    #[inline]
    pub fn update(&mut self, h: [f64; 3], z: f64, r: f64) -> Innovation {
        let p = &self.p;
        // P Hᵀ
        let ph = [
            p[0][0] * h[0] + p[0][1] * h[1] + p[0][2] * h[2],
            p[1][0] * h[0] + p[1][1] * h[1] + p[1][2] * h[2],
            p[2][0] * h[0] + p[2][1] * h[1] + p[2][2] * h[2],
        ];
        let s = h[0] * ph[0] + h[1] * ph[1] + h[2] * ph[2] + r;
        let predicted = h[0] * self.x[0] + h[1] * self.x[1] + h[2] * self.x[2];
        let value = z - predicted;
        if !(s > 0.0 && s.is_finite()) {
            return Innovation { value, variance: s };
        }
        let inv_s = 1.0 / s;
        for (x, phi) in self.x.iter_mut().zip(ph) {
            *x += phi * inv_s * value; // Eq. 6 with K = P Hᵀ / S (Eq. 5)
        }
        // Eq. 7 (corrected): P − K H P = P − P Hᵀ H P / S, kept symmetric.
        for i in 0..3 {
            for j in i..3 {
                let v = self.p[i][j] - ph[i] * ph[j] * inv_s;
                self.p[i][j] = v;
                self.p[j][i] = v;
            }
        }
        for i in 0..3 {
            self.p[i][i] = self.p[i][i].max(0.0);
        }
        Innovation { value, variance: s }
    }

    /// Grows the bias's variance by `var` (it may have moved since the
    /// last laser sample).
    pub fn inflate_bias(&mut self, var: f64) {
        self.p[2][2] += var;
    }

    /// Shifts the bias (the error model changed under it: the corrected
    /// inclinometer moves by `delta`, so does b, and θ stays). Whether the
    /// bias had taken up what the model now explains is not known, so its
    /// variance grows by `delta`²: the laser sets it right if not.
    pub fn shift_bias(&mut self, delta: f64) {
        self.x[2] += delta;
        self.p[2][2] += delta * delta;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_prediction_variance_by_hand() {
        // [1, a, 0] P [1, a, 0]ᵀ + q_θ a + q_θ̇ a³/3 with P = [[4, 1, 0],
        // [1, 2, 0], [0, 0, 1]], a = 2, q_θ = 0.5, q_θ̇ = 3:
        // 4 + 2·2·1 + 4·2 + 0.5·2 + 3·8/3 = 25.
        let f = TiltFilter {
            x: [0.0; 3],
            p: [[4.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 1.0]],
            t: Some(0.0),
        };
        let q = ProcessNoise {
            angle: 0.5,
            rate: 3.0,
        };
        assert!((f.predicted_angle_variance(1.0, 2.0, &q) - 25.0).abs() < 1e-12);
        assert_eq!(f.predicted_angle_variance(1.0, 0.0, &q), 4.0);
    }

    const Q0: ProcessNoise = ProcessNoise {
        angle: 0.0,
        rate: 0.0,
    };

    #[test]
    fn prediction_matches_hand_computation() {
        // P = I, dt = 2: Φ P Φᵀ = [[1 + 4, 2, 0], [2, 1, 0], [0, 0, 1]],
        // Q adds q_θ̇ [8/3, 2, 2] on the rate block and q_θ·2; b stays.
        let mut f = TiltFilter {
            x: [1.0, 0.5, 0.1],
            p: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            t: Some(10.0),
        };
        let q = ProcessNoise {
            angle: 0.25,
            rate: 3.0,
        };
        f.predict_to(12.0, &q);
        assert_eq!(f.x, [2.0, 0.5, 0.1]);
        assert_eq!(f.p[0][0], 5.0 + 0.5 + 8.0);
        assert_eq!(f.p[0][1], 2.0 + 6.0);
        assert_eq!(f.p[1][0], f.p[0][1]);
        assert_eq!(f.p[1][1], 1.0 + 6.0);
        assert_eq!(f.p[2][2], 1.0);
        assert_eq!(f.p[0][2], 0.0);
        f.inflate_bias(0.5);
        assert_eq!(f.p[2][2], 1.5);
    }

    #[test]
    fn update_matches_hand_computation() {
        // P = diag(4, 1, 1), inclinometer H = [1, 0, 1], r = 2:
        // S = 4 + 1 + 2 = 7, K = [4, 0, 1] / 7, innovation 3 − (1 + 0.5) = 1.5.
        let mut f = TiltFilter {
            x: [1.0, 0.0, 0.5],
            p: [[4.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            t: Some(0.0),
        };
        let innovation = f.update(H_INCLINOMETER, 3.0, 2.0);
        assert_eq!(innovation.value, 1.5);
        assert_eq!(innovation.variance, 7.0);
        assert!((f.x[0] - (1.0 + 4.0 / 7.0 * 1.5)).abs() < 1e-15);
        assert!((f.x[2] - (0.5 + 1.0 / 7.0 * 1.5)).abs() < 1e-15);
        // P − P Hᵀ H P / S: p00 = 4 − 16/7, p02 = −4/7, p22 = 1 − 1/7.
        assert!((f.p[0][0] - (4.0 - 16.0 / 7.0)).abs() < 1e-15);
        assert!((f.p[0][2] + 4.0 / 7.0).abs() < 1e-15);
        assert!((f.p[2][2] - 6.0 / 7.0).abs() < 1e-15);
        assert_eq!(f.p[1][1], 1.0);
    }

    #[test]
    fn the_laser_separates_angle_from_bias() {
        // The inclinometer reads 1.3, the laser 1.0: θ → 1.0, b → 0.3
        // (shrunk by the inclinometer's noise: 0.3 σ_b² / (σ_b² + r)).
        let mut f = TiltFilter::start(0.0, 1.3, 1e-4, 0.5, 1e-3);
        f.update(H_LASER, 1.0, 1e-12);
        assert!((f.angle() - 1.0).abs() < 1e-9);
        assert!((f.bias() - 0.3 * 0.25 / (0.25 + 1e-4)).abs() < 1e-9);
        for i in 1..100 {
            f.predict_to(i as f64, &Q0);
            f.update(H_INCLINOMETER, 1.3, 1e-4);
        }
        // The rate's prior lets θ wander by a little: 1e-5 over 100 s.
        assert!((f.angle() - 1.0).abs() < 1e-4, "{}", f.angle());
    }

    #[test]
    fn follows_a_ramp_and_predicts_it() {
        let q = ProcessNoise {
            angle: 0.0,
            rate: 1e-10,
        };
        let mut f = TiltFilter::start(0.0, 0.7, 1e-6, 0.5, 1e-3);
        for i in 1..3000 {
            let t = i as f64;
            let truth = 0.5 + 1e-4 * t;
            f.predict_to(t, &q);
            f.update(H_INCLINOMETER, truth + 0.2, 1e-6);
            if i % 60 == 0 {
                f.update(H_LASER, truth, 1e-6);
            }
        }
        let truth = 0.5 + 1e-4 * 2999.0;
        assert!((f.angle() - truth).abs() < 1e-4);
        assert!((f.rate() - 1e-4).abs() < 1e-6);
        assert!((f.bias() - 0.2).abs() < 1e-4);
    }

    #[test]
    fn shifting_the_bias_leaves_the_angle() {
        let mut f = TiltFilter::start(0.0, 1.0, 1e-4, 0.5, 1e-3);
        f.update(H_LASER, 0.9, 1e-6);
        let before = f;
        f.shift_bias(0.05);
        assert_eq!(f.angle(), before.angle());
        assert_eq!(f.bias(), before.bias() + 0.05);
        assert_eq!(f.p[2][2], before.p[2][2] + 0.05 * 0.05);
        assert_eq!(f.p[0], before.p[0]);
    }
}
