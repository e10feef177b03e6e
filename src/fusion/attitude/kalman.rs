//! The Kalman filter of He et al. 2021, Eq. 1–7, with a state vector in
//! place of the paper's four scalar random walks. One filter runs per tilt
//! axis (pitch, roll); its states are
//!
//! x = [θ, θ̇, b, s]: the angle, its rate, the inclinometer's residual
//! bias — what the error model has not explained (pitch) or the mounting
//! offset (roll) — and, beyond the roll the error model was trained on,
//! by how much the error's slope there differs from the model's tangent
//! at the edge (pitch only; the roll's inclinometer row never reaches it).
//!
//! Motion over dt (Eq. 3–4 with Φ, Γ Q Γᵀ below): θ ← θ + θ̇·dt; θ̇ is a
//! random walk; θ may also take white steps; b and s are constant:
//!
//! Φ = I + dt·e_θ e_θ̇ᵀ; Q has q_θ dt + q_θ̇ dt³/3, q_θ̇ dt²/2 and q_θ̇ dt
//! in the (θ, θ̇) block and 0 elsewhere.
//!
//! The bias moves only where something can see it move: the engine grows
//! its variance just before each laser sample ([`TiltFilter::inflate_bias`])
//! by what the roll and the time since the previous one allow. Between
//! laser samples — and through a dropout — a change of the inclinometer is
//! therefore a change of the angle or, where the roll is d beyond the
//! trained range, of the error by s·d: the filter weighs the two by θ̇'s
//! random walk against s's prior, and tells them apart where the roll
//! moves back and forth faster than the angle turns.
//!
//! Measurements (Eq. 5–7, scalar): the corrected inclinometer
//! z = θ + b + s·d (H = [1, 0, 1, d], [`inclinometer_row`]; d = 0 within
//! the trained roll range), the laser y = θ (H = [1, 0, 0, 0]). Eq. 7 is
//! used as corrected (docs/papers.md): P = (I − K H) P⁻.
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

/// The number of states: θ, θ̇, b, s.
pub const N: usize = 4;
const BIAS: usize = 2;
const SLOPE: usize = 3;

/// Measurement rows H: the inclinometer within the trained roll range, the laser.
pub const H_INCLINOMETER: [f64; N] = [1.0, 0.0, 1.0, 0.0];
pub const H_LASER: [f64; N] = [1.0, 0.0, 0.0, 0.0];

/// The inclinometer's row with the roll `beyond_rad` past the range the
/// error model was trained on (signed; 0 within it): [1, 0, 1, d].
pub fn inclinometer_row(beyond_rad: f64) -> [f64; N] {
    [1.0, 0.0, 1.0, beyond_rad]
}

/// One axis's filter: state and covariance (symmetric, stored whole).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TiltFilter {
    pub x: [f64; N],
    pub p: [[f64; N]; N],
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
    /// with b ~ N(0, `bias_sd`²), θ̇ ~ N(0, `rate_sd`²); s = 0 with no
    /// variance until a model gives it one ([`Self::restart_slope`]).
    pub fn start(t: f64, z: f64, r: f64, bias_sd: f64, rate_sd: f64) -> TiltFilter {
        let vb = bias_sd * bias_sd;
        TiltFilter {
            x: {
                let mut x = [0.0; N];
                x[0] = z;
                x
            },
            p: {
                let mut p = [[0.0; N]; N];
                p[0][0] = vb + r;
                p[0][BIAS] = -vb;
                p[BIAS][0] = -vb;
                p[1][1] = rate_sd * rate_sd;
                p[BIAS][BIAS] = vb;
                p
            },
            t: Some(t),
        }
    }

    /// A value shown with `variance` (rad, rad²) carried `dt_s` on by the
    /// filter's rate, its variance grown as the prediction's over `dt_s`.
    pub fn carry(&self, (value, variance): (f64, f64), dt_s: f64, q: &ProcessNoise) -> (f64, f64) {
        let growth = self.predicted_angle_variance(1.0, dt_s, q) - self.p[0][0];
        (
            value + self.rate() * dt_s,
            variance.max(0.0) + growth.max(0.0),
        )
    }

    /// Variance of w·θ + θ̇·`ahead_s` (w: the filter's weight in a blend
    /// with the held laser, 1 without) as a prediction of the angle
    /// `ahead_s` later: [w, a, 0, 0] P [w, a, 0, 0]ᵀ plus the angle's
    /// own motion over `ahead_s` (the Q of the module documentation).
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
        // Φ P Φᵀ, written out for Φ = I + dt·e₀e₁ᵀ (θ takes dt·θ̇).
        let p00 = p[0][0] + 2.0 * dt * p[0][1] + dt2 * p[1][1];
        let p01 = p[0][1] + dt * p[1][1];
        // θ's covariance with b and s takes dt times θ̇'s.
        let rate_row = p[1];
        for (k, rate_k) in rate_row.iter().enumerate().skip(BIAS) {
            let v = p[0][k] + dt * rate_k;
            p[0][k] = v;
            p[k][0] = v;
        }
        p[0][0] = p00 + q.angle * dt + q.rate * dt2 * dt / 3.0;
        p[0][1] = p01 + q.rate * dt2 / 2.0;
        p[1][0] = p[0][1];
        p[1][1] += q.rate * dt;
        self.x[0] += self.x[1] * dt;
        self.t = Some(t);
    }

    /// The combination h·x of the states and its variance h P hᵀ.
    pub fn combination(&self, h: [f64; N]) -> (f64, f64) {
        let p = &self.p;
        let mut variance = 0.0;
        for i in 0..N {
            for j in 0..N {
                variance += h[i] * p[i][j] * h[j];
            }
        }
        ((0..N).map(|i| h[i] * self.x[i]).sum(), variance)
    }

    /// The gain a measurement h·x of noise variance `r` would give the
    /// angle (Eq. 5's first row: (P Hᵀ)₀ / S).
    pub fn angle_gain(&self, h: [f64; N], r: f64) -> f64 {
        let (_, variance) = self.combination(h);
        let s = variance + r;
        if !(s > 0.0 && s.is_finite()) {
            return 0.0;
        }
        (0..N).map(|j| self.p[0][j] * h[j]).sum::<f64>() / s
    }

    /// The innovation a measurement would have, without taking it.
    pub fn innovation(&self, h: [f64; N], z: f64, r: f64) -> Innovation {
        let (predicted, variance) = self.combination(h);
        Innovation {
            value: z - predicted,
            variance: variance + r,
        }
    }

    /// Eq. 5–7 for a scalar measurement `z` = h·x + noise of variance `r`.
    #[inline]
    pub fn update(&mut self, h: [f64; N], z: f64, r: f64) -> Innovation {
        let p = &self.p;
        // P Hᵀ
        let ph: [f64; N] = std::array::from_fn(|i| (0..N).map(|j| p[i][j] * h[j]).sum());
        let s = (0..N).map(|i| h[i] * ph[i]).sum::<f64>() + r;
        let predicted: f64 = (0..N).map(|i| h[i] * self.x[i]).sum();
        let value = z - predicted;
        if !(s > 0.0 && s.is_finite()) {
            return Innovation { value, variance: s };
        }
        let inv_s = 1.0 / s;
        for (x, phi) in self.x.iter_mut().zip(ph) {
            *x += phi * inv_s * value; // Eq. 6 with K = P Hᵀ / S (Eq. 5)
        }
        // Eq. 7 (corrected): P − K H P = P − P Hᵀ H P / S, kept symmetric.
        for i in 0..N {
            for j in i..N {
                let v = self.p[i][j] - ph[i] * ph[j] * inv_s;
                self.p[i][j] = v;
                self.p[j][i] = v;
            }
        }
        for i in 0..N {
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

    /// By how much the error's slope beyond the trained roll differs
    /// from the model's tangent there, ŝ.
    pub fn slope(&self) -> f64 {
        self.x[SLOPE]
    }

    /// A new model with its own trained range, the roll now `beyond_rad`
    /// past the old one: what s took up there goes to the bias (b ← b + s·d:
    /// θ and what the inclinometer is expected to read stay), and s starts
    /// again from 0 with the variance `slope_var`, uncorrelated.
    pub fn restart_slope(&mut self, beyond_rad: f64, slope_var: f64) {
        let d = beyond_rad;
        let p = &mut self.p;
        // x ← T x with T = I + d e_b e_sᵀ; P ← T P Tᵀ.
        self.x[BIAS] += d * self.x[SLOPE];
        for row in p.iter_mut() {
            row[BIAS] += d * row[SLOPE];
        }
        let from = p[SLOPE];
        for (to, v) in p[BIAS].iter_mut().zip(from) {
            *to += d * v;
        }
        self.x[SLOPE] = 0.0;
        for row in p.iter_mut() {
            row[SLOPE] = 0.0;
        }
        p[SLOPE] = [0.0; N];
        p[SLOPE][SLOPE] = slope_var;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A diagonal covariance.
    fn diag(v: [f64; N]) -> [[f64; N]; N] {
        std::array::from_fn(|i| std::array::from_fn(|j| if i == j { v[i] } else { 0.0 }))
    }

    #[test]
    fn the_angle_gain_by_hand() {
        // H = [1, 0, 1, 0] (angle + bias), P = diag(4, 2, 1, 1) with
        // p_θb = −1: (P Hᵀ)₀ = 4 − 1 = 3, H P Hᵀ = 4 + 1 − 2 = 3, r = 1:
        // gain 3 / (3 + 1) = 0.75, and the update moves the angle by it.
        let mut f = TiltFilter {
            x: [0.0; N],
            p: {
                let mut p = diag([4.0, 2.0, 1.0, 1.0]);
                (p[0][BIAS], p[BIAS][0]) = (-1.0, -1.0);
                p
            },
            t: Some(0.0),
        };
        assert_eq!(f.angle_gain(H_INCLINOMETER, 1.0), 0.75);
        f.update(H_INCLINOMETER, 2.0, 1.0);
        assert!((f.angle() - 1.5).abs() < 1e-12);
    }

    #[test]
    fn the_prediction_variance_by_hand() {
        // [1, a, 0, 0] P [1, a, 0, 0]ᵀ + q_θ a + q_θ̇ a³/3 with P = diag(4,
        // 2, 1, 1) and p_θθ̇ = 1, a = 2, q_θ = 0.5, q_θ̇ = 3:
        // 4 + 2·2·1 + 4·2 + 0.5·2 + 3·8/3 = 25.
        let f = TiltFilter {
            x: [0.0; N],
            p: {
                let mut p = diag([4.0, 2.0, 1.0, 1.0]);
                (p[0][1], p[1][0]) = (1.0, 1.0);
                p
            },
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
        // P = I plus p_θ̇s = 0.5, dt = 2: Φ P Φᵀ adds 4 to p_θθ, 2 to p_θθ̇
        // and 2·0.5 to p_θs; Q adds q_θ̇ [8/3, 2, 2] on the rate block and
        // q_θ·2; b and s stay.
        let mut f = TiltFilter {
            x: [1.0, 0.5, 0.1, 0.2],
            p: {
                let mut p = diag([1.0; N]);
                (p[1][3], p[3][1]) = (0.5, 0.5);
                p
            },
            t: Some(10.0),
        };
        let q = ProcessNoise {
            angle: 0.25,
            rate: 3.0,
        };
        f.predict_to(12.0, &q);
        assert_eq!(f.x, [2.0, 0.5, 0.1, 0.2]);
        assert_eq!(f.p[0][0], 5.0 + 0.5 + 8.0);
        assert_eq!(f.p[0][1], 2.0 + 6.0);
        assert_eq!(f.p[1][0], f.p[0][1]);
        assert_eq!(f.p[1][1], 1.0 + 6.0);
        assert_eq!(f.p[2][2], 1.0);
        assert_eq!(f.p[0][2], 0.0);
        assert_eq!(
            (f.p[0][3], f.p[3][0], f.p[1][3], f.p[3][3]),
            (1.0, 1.0, 0.5, 1.0)
        );
        f.inflate_bias(0.5);
        assert_eq!(f.p[2][2], 1.5);
    }

    #[test]
    fn update_matches_hand_computation() {
        // P = diag(4, 1, 1, 0), inclinometer H = [1, 0, 1, 0], r = 2:
        // S = 4 + 1 + 2 = 7, K = [4, 0, 1] / 7, innovation 3 − (1 + 0.5) = 1.5.
        let mut f = TiltFilter {
            x: [1.0, 0.0, 0.5, 0.0],
            p: diag([4.0, 1.0, 1.0, 0.0]),
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
    #[test]
    fn beyond_the_trained_roll_the_row_reaches_the_slope() {
        // P = diag(4, 1, 1, 9), z = θ + b + s·d with d = 0.5, r = 2:
        // H P Hᵀ = 4 + 1 + 0.25·9 = 7.25, S = 9.25, and s takes
        // 0.5·9 / 9.25 of the innovation 1, θ 4 / 9.25.
        let mut f = TiltFilter {
            x: [0.0; N],
            p: diag([4.0, 1.0, 1.0, 9.0]),
            t: Some(0.0),
        };
        let innovation = f.update(inclinometer_row(0.5), 1.0, 2.0);
        assert_eq!(innovation.variance, 9.25);
        assert!((f.slope() - 4.5 / 9.25).abs() < 1e-15);
        assert!((f.angle() - 4.0 / 9.25).abs() < 1e-15);
        // Within the range the row is the plain inclinometer's.
        assert_eq!(inclinometer_row(0.0), H_INCLINOMETER);
    }

    #[test]
    fn restarting_the_slope_hands_what_it_took_to_the_bias() {
        // At d = 2 with s = 0.3: b ← 0.1 + 2·0.3 = 0.7, and P ← T P Tᵀ for
        // T = I + 2 e_b e_sᵀ (multiplied out below, independently of the
        // in-place form), then s's row and column cleared and its variance
        // set anew. Hand values: P_bb ← P_bb + 4 P_bs + 4 P_ss = 1 + 0.8 + 2
        // = 3.8; P_θb ← P_θb + 2 P_θs = 0.2; P_θ̇b ← 0 + 2·0.3 = 0.6.
        let mut p = diag([2.0, 1.0, 1.0, 0.5]);
        (p[0][2], p[2][0]) = (0.1, 0.1);
        (p[0][3], p[3][0]) = (0.05, 0.05);
        (p[1][3], p[3][1]) = (0.3, 0.3);
        (p[2][3], p[3][2]) = (0.2, 0.2);
        let mut f = TiltFilter {
            x: [1.0, 0.0, 0.1, 0.3],
            p,
            t: Some(0.0),
        };
        let read = |f: &TiltFilter, h: [f64; N]| (0..N).map(|i| h[i] * f.x[i]).sum::<f64>();
        let before = read(&f, inclinometer_row(2.0));
        f.restart_slope(2.0, 7.0);
        let mut t = diag([1.0; N]);
        t[2][3] = 2.0;
        let product = |a: &[[f64; N]; N], b: &[[f64; N]; N]| -> [[f64; N]; N] {
            std::array::from_fn(|i| {
                std::array::from_fn(|j| (0..N).map(|k| a[i][k] * b[k][j]).sum())
            })
        };
        let transposed: [[f64; N]; N] = std::array::from_fn(|i| std::array::from_fn(|j| t[j][i]));
        let mut expected = product(&product(&t, &p), &transposed);
        for row in expected.iter_mut() {
            row[3] = 0.0;
        }
        expected[3] = [0.0, 0.0, 0.0, 7.0];
        for (i, (row, expected_row)) in f.p.iter().zip(expected).enumerate() {
            for (j, (v, e)) in row.iter().zip(expected_row).enumerate() {
                assert!((v - e).abs() < 1e-12, "P[{i}][{j}] {v}, expected {e}");
            }
        }
        assert!((f.p[2][2] - 3.8).abs() < 1e-12);
        assert!((f.p[0][2] - 0.2).abs() < 1e-12);
        assert!((f.p[1][2] - 0.6).abs() < 1e-12);
        assert!((f.bias() - 0.7).abs() < 1e-15);
        assert_eq!(f.slope(), 0.0);
        assert_eq!((f.p[0][0], f.x[0]), (2.0, 1.0));
        // What the inclinometer is expected to read there is unchanged.
        assert!((read(&f, inclinometer_row(2.0)) - before).abs() < 1e-15);
    }

    #[test]
    fn a_roll_swinging_beyond_the_range_reveals_the_slope_without_a_laser() {
        // The angle climbs at 1e-5 /s, known from the laser, and then, with
        // the laser gone, twice as fast (q_θ̇ lets its rate wander that
        // much); the error beyond the trained range is 0.05·d where the
        // model says 0. Where the roll swings 0–1 beyond the range every
        // 600 s the swing can only be the error: s finds it and the angle
        // stays right. Where the roll runs one way at a steady rate
        // (d = t/3600) the error's growth and the faster climb look alike:
        // s takes some of the climb, and neither is found.
        let angle_at = |t: f64| 0.3 + 1e-5 * t + 1e-5 * (t - 600.0).max(0.0);
        let run = |d_at: &dyn Fn(f64) -> f64| {
            let q = ProcessNoise {
                angle: 0.0,
                rate: 1e-12,
            };
            let mut f = TiltFilter::start(0.0, 0.3, 1e-6, 1e-3, 1e-5);
            for i in 0..600 {
                let t = f64::from(i);
                f.predict_to(t, &q);
                f.update(H_INCLINOMETER, angle_at(t), 1e-6);
                if i % 60 == 0 {
                    f.update(H_LASER, angle_at(t), 1e-8);
                }
            }
            f.restart_slope(0.0, 0.01);
            for i in 600..4200 {
                let t = f64::from(i);
                let d = d_at(t - 600.0);
                f.predict_to(t, &q);
                f.update(inclinometer_row(d), angle_at(t) + 0.05 * d, 1e-6);
            }
            (f.slope(), f.angle() - angle_at(4199.0))
        };
        let swing = |t: f64| 0.5 - 0.5 * (std::f64::consts::TAU * t / 600.0).cos();
        let (slope, angle_error) = run(&swing);
        assert!((slope - 0.05).abs() < 2e-3, "swinging: s {slope}");
        assert!(
            angle_error.abs() < 2e-3,
            "swinging: angle off by {angle_error}"
        );
        let (slope, angle_error) = run(&|t| t / 3600.0);
        assert!((slope - 0.05).abs() > 0.01, "one way: s {slope}");
        assert!(
            angle_error.abs() > 0.01,
            "one way: angle off by {angle_error}"
        );
    }
}
