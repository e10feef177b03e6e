//! `kf3`: the textbook baseline of `eval attitude`. One angle, three
//! states — the angle θ, its rate θ̇ and the fast sensor's bias b — in a
//! linear Kalman filter written out with matrices (Simon, *Optimal State
//! Estimation*, 2006, Sec. 5.1):
//!
//! - motion: θ ← θ + θ̇·dt, θ̇ a random walk of intensity `q_rate`
//!   (deg²/s³, the constant-velocity model), b a random walk of intensity
//!   `q_bias` (deg²/s);
//! - inclinometer: z = θ + b + v, var v = R_incl;
//! - laser: y = θ + w, var w = R_laser.
//!
//! It is written independently of the engine (no code shared) and is fed
//! the *true* measurement noise of the simulated sensors; its process
//! noise is fixed, chosen once over the envelope (see `eval attitude`).
//! Degrees throughout.

use nalgebra::{Matrix3, RowVector3, Vector3};

/// The two process noise intensities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kf3Noise {
    /// deg²/s³: white noise on the angular acceleration.
    pub q_rate: f64,
    /// deg²/s: random walk of the inclinometer bias.
    pub q_bias: f64,
}

/// Prior standard deviation of the bias and of the rate at the start.
const PRIOR_BIAS_DEG: f64 = 0.5;
const PRIOR_RATE_DEG_PER_S: f64 = 1e-3;

/// The filter.
#[derive(Debug, Clone)]
pub struct Kf3 {
    noise: Kf3Noise,
    x: Vector3<f64>,
    p: Matrix3<f64>,
    t: Option<f64>,
}

impl Kf3 {
    /// A filter that starts at its first inclinometer reading.
    pub fn new(noise: Kf3Noise) -> Kf3 {
        Kf3 {
            noise,
            x: Vector3::zeros(),
            p: Matrix3::zeros(),
            t: None,
        }
    }

    /// The angle estimate θ̂.
    pub fn angle(&self) -> f64 {
        self.x[0]
    }

    /// θ̂ + θ̇̂·`dt_s`: the prediction `dt_s` ahead.
    pub fn predict_angle(&self, dt_s: f64) -> f64 {
        self.x[0] + self.x[1] * dt_s
    }

    /// The bias estimate b̂.
    pub fn bias(&self) -> f64 {
        self.x[2]
    }

    fn predict_to(&mut self, t: f64) {
        let Some(last) = self.t else {
            return;
        };
        let dt = (t - last).max(0.0);
        let f = Matrix3::new(1.0, dt, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        let qa = self.noise.q_rate;
        let q = Matrix3::new(
            qa * dt.powi(3) / 3.0,
            qa * dt * dt / 2.0,
            0.0,
            qa * dt * dt / 2.0,
            qa * dt,
            0.0,
            0.0,
            0.0,
            self.noise.q_bias * dt,
        );
        self.x = f * self.x;
        self.p = f * self.p * f.transpose() + q;
        self.t = Some(t);
    }

    fn update(&mut self, h: RowVector3<f64>, z: f64, r: f64) {
        let s = (h * self.p * h.transpose())[0] + r;
        let k = self.p * h.transpose() / s;
        let innovation = z - (h * self.x)[0];
        self.x += k * innovation;
        // Joseph form: stays symmetric and positive.
        let i_kh = Matrix3::identity() - k * h;
        self.p = i_kh * self.p * i_kh.transpose() + k * r * k.transpose();
    }

    /// An inclinometer reading `z` of variance `r`.
    pub fn inclinometer(&mut self, t: f64, z: f64, r: f64) {
        if self.t.is_none() {
            // θ = z − b with b ~ N(0, σ_b²): θ and b start anticorrelated.
            let vb = PRIOR_BIAS_DEG * PRIOR_BIAS_DEG;
            self.x = Vector3::new(z, 0.0, 0.0);
            self.p = Matrix3::new(
                vb + r,
                0.0,
                -vb,
                0.0,
                PRIOR_RATE_DEG_PER_S * PRIOR_RATE_DEG_PER_S,
                0.0,
                -vb,
                0.0,
                vb,
            );
            self.t = Some(t);
            return;
        }
        self.predict_to(t);
        self.update(RowVector3::new(1.0, 0.0, 1.0), z, r);
    }

    /// A laser reading `y` of variance `r` (ignored before the first
    /// inclinometer reading).
    pub fn laser(&mut self, t: f64, y: f64, r: f64) {
        if self.t.is_none() {
            return;
        }
        self.predict_to(t);
        self.update(RowVector3::new(1.0, 0.0, 0.0), y, r);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_laser_sample_resolves_the_bias() {
        // The inclinometer reads 1.3 where the laser says 1.0: with a
        // precise laser and no process noise, θ → 1.0 and b → 0.3 shrunk by
        // the inclinometer's own noise: 0.3 · σ_b² / (σ_b² + r).
        let mut f = Kf3::new(Kf3Noise {
            q_rate: 0.0,
            q_bias: 0.0,
        });
        f.inclinometer(0.0, 1.3, 1e-4);
        f.laser(0.0, 1.0, 1e-10);
        assert!((f.angle() - 1.0).abs() < 1e-6, "{}", f.angle());
        let expected = 0.3 * 0.25 / (0.25 + 1e-4);
        assert!((f.bias() - expected).abs() < 1e-6, "{}", f.bias());
        // Later inclinometer readings at 1.3 keep θ at 1.0.
        for i in 1..100 {
            f.inclinometer(i as f64, 1.3, 1e-4);
        }
        assert!((f.angle() - 1.0).abs() < 1e-5);
    }

    #[test]
    fn first_update_matches_hand_computation() {
        // P after init: [[vb+r, 0, −vb], [0, vr, 0], [−vb, 0, vb]], then a
        // laser at the same instant: S = vb + r + rl; K = P hᵀ / S.
        let (r, rl) = (1e-2, 1e-2);
        let mut f = Kf3::new(Kf3Noise {
            q_rate: 0.0,
            q_bias: 0.0,
        });
        f.inclinometer(0.0, 2.0, r);
        f.laser(0.0, 1.0, rl);
        let vb = 0.25;
        let s = vb + r + rl;
        let k0 = (vb + r) / s;
        let k2 = -vb / s;
        assert!((f.angle() - (2.0 + k0 * (1.0 - 2.0))).abs() < 1e-12);
        assert!((f.bias() - k2 * (1.0 - 2.0)).abs() < 1e-12);
    }

    #[test]
    fn tracks_a_ramp_without_lag() {
        let mut f = Kf3::new(Kf3Noise {
            q_rate: 1e-10,
            q_bias: 1e-10,
        });
        for i in 0..2000 {
            let t = i as f64;
            let truth = 0.5 + 1e-4 * t;
            f.inclinometer(t, truth + 0.2, 1e-6);
            if i % 60 == 0 {
                f.laser(t, truth, 1e-6);
            }
        }
        let truth = 0.5 + 1e-4 * 1999.0;
        assert!((f.angle() - truth).abs() < 1e-4, "{}", f.angle() - truth);
        assert!((f.predict_angle(10.0) - (truth + 1e-3)).abs() < 2e-4);
    }
}
