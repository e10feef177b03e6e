//! What the machine does with what it is told. Per plane a Kalman filter
//! of the front's deviation d (m), its slope at the front g and the
//! curvature b (1/m) the machine adds of itself to the one it is steered
//! (the ground, its weight: a machine that dives, a face that pushes it
//! aside), from each `dta` estimate's front deviation and tendency:
//!
//! - between estimates the front advances Δs on the curvature served with
//!   the strokes, κₛ against the axis (a push steers one stroke
//!   difference: a constant curvature), and its own:
//!   d += g·Δs + (κₛ + b)·Δs²/2, g += (κₛ + b)·Δs, with the thrust's
//!   scatter (`stroke_sigma_mm` per step over the cylinder circle) as a
//!   random curvature, and b a slow random walk;
//! - the front's deviation measures d, the tendency the slope of the chord
//!   from the rear: g less the chord's lag behind the front's heading from
//!   what was served under the shield, less b·ℓ/2 over the shield length
//!   ℓ; both with the guidance's σ (`guidance_sigma_mm`, or the estimate's
//!   own), correlated through the front, the chord also with the thrust's
//!   scatter under the shield.
//!
//! It gives the curve its start (d, g and the machine's present curvature
//! against the axis, κₛ + b) and the strokes their offset (b̂, steered
//! against). A front that jumps against the filter (a new set-up of the
//! guidance) restarts it.

use nalgebra::{Matrix2, Matrix2x3, Matrix3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// 1σ of the machine's own curvature before it is seen, 1/m (a 10 km
/// radius).
const BIAS_PRIOR_PER_M: f64 = 1e-4;
/// How fast it may wander, 1/m per √m: 1e-4 /m over 100 m of advance.
const BIAS_WALK: f64 = 1e-5;
/// Normalised innovation beyond which the filter restarts (χ², 2 degrees
/// of freedom, 10⁻⁴).
const RESTART_NIS: f64 = 18.4;

/// One plane's filter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlaneFilter {
    /// d (m), g, b (1/m).
    pub x: Vector3<f64>,
    pub p: Matrix3<f64>,
}

/// One plane's measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measured {
    pub deviation_m: f64,
    /// The chord's slope (the `dta` tendency), m/m.
    pub tendency: f64,
    /// How much the front's heading exceeds the chord's slope by what
    /// was served under the shield, m/m; the machine's own curvature adds
    /// b·ℓ/2.
    pub chord_lag: f64,
    pub sigma_m: f64,
}

impl PlaneFilter {
    /// Started from a measurement.
    pub fn start(m: &Measured, shield_m: f64) -> PlaneFilter {
        let var = m.sigma_m * m.sigma_m;
        PlaneFilter {
            x: Vector3::new(m.deviation_m, m.tendency + m.chord_lag, 0.0),
            p: Matrix3::from_diagonal(&Vector3::new(
                var,
                2.0 * var / (shield_m * shield_m),
                BIAS_PRIOR_PER_M * BIAS_PRIOR_PER_M,
            )),
        }
    }

    /// Advance `ds_m` on the served curvature `served_per_m` (against the
    /// axis); `heading_var_per_m` the thrust's scatter as heading variance
    /// per metre.
    pub fn predict(&mut self, ds_m: f64, served_per_m: f64, heading_var_per_m: f64) {
        if ds_m <= 0.0 {
            return;
        }
        let f = Matrix3::new(1.0, ds_m, 0.5 * ds_m * ds_m, 0.0, 1.0, ds_m, 0.0, 0.0, 1.0);
        self.x =
            f * self.x + Vector3::new(0.5 * served_per_m * ds_m * ds_m, served_per_m * ds_m, 0.0);
        let q = heading_var_per_m;
        let noise = Matrix3::new(
            q * ds_m.powi(3) / 3.0,
            q * ds_m * ds_m / 2.0,
            0.0,
            q * ds_m * ds_m / 2.0,
            q * ds_m,
            0.0,
            0.0,
            0.0,
            BIAS_WALK * BIAS_WALK * ds_m,
        );
        self.p = f * self.p * f.transpose() + noise;
    }

    /// Corrects with `m`; false if it departs so far that the filter
    /// should restart. The thrust's scatter `heading_var_per_m` also bends
    /// the path under the shield: the chord's slope is off the front's
    /// heading by its integral, variance q·ℓ/3 (the mean of a random walk's
    /// increments over ℓ).
    pub fn update(&mut self, m: &Measured, shield_m: f64, heading_var_per_m: f64) -> bool {
        let half = 0.5 * shield_m;
        let h = Matrix2x3::new(1.0, 0.0, 0.0, 0.0, 1.0, -half);
        let predicted = Vector2::new(self.x[0], self.x[1] - m.chord_lag - half * self.x[2]);
        let innovation = Vector2::new(m.deviation_m, m.tendency) - predicted;
        let var = m.sigma_m * m.sigma_m;
        let r = Matrix2::new(
            var,
            var / shield_m,
            var / shield_m,
            2.0 * var / (shield_m * shield_m) + heading_var_per_m * shield_m / 3.0,
        );
        let s = h * self.p * h.transpose() + r;
        let Some(s_inv) = s.try_inverse() else {
            return false;
        };
        let nis = (innovation.transpose() * s_inv * innovation)[0];
        if !nis.is_finite() || nis > RESTART_NIS {
            return false;
        }
        let k = self.p * h.transpose() * s_inv;
        self.x += k * innovation;
        // Joseph form: stays symmetric and positive.
        let i_kh = Matrix3::identity() - k * h;
        self.p = i_kh * self.p * i_kh.transpose() + k * r * k.transpose();
        true
    }

    /// The machine's own curvature, 1/m.
    pub fn bias_per_m(&self) -> f64 {
        self.x[2]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_machine_that_dives_is_seen_and_its_curvature_learnt() {
        // Told to go straight, the machine bends down by 1e-4 /m of itself
        // (a 10 km radius): after 30 steps of 1.5 m its deviation is
        // −1e-4·45²/2 = −101 mm. Measured exactly every step, the filter
        // learns b within a tenth.
        let shield = 9.0;
        let truth = |s: f64| -1e-4 * s * s / 2.0;
        let slope = |s: f64| -1e-4 * s;
        let measured = |s: f64| Measured {
            deviation_m: truth(s),
            // The chord from s − 9 to s.
            tendency: (truth(s) - truth(s - shield)) / shield,
            chord_lag: 0.0,
            sigma_m: 0.001,
        };
        let mut f = PlaneFilter::start(&measured(0.0), shield);
        // The first chord (on the same parabola behind s = 0): the filter
        // starts from it as the slope.
        assert!((f.x[1] - measured(0.0).tendency).abs() < 1e-12);
        for k in 1..=30 {
            let s = f64::from(k) * 1.5;
            f.predict(1.5, 0.0, 1e-9);
            assert!(f.update(&measured(s), shield, 1e-9), "{k}");
        }
        assert!((f.bias_per_m() + 1e-4).abs() < 1e-5, "{f:?}");
        assert!((f.x[0] - truth(45.0)).abs() < 1e-3, "{f:?}");
        assert!((f.x[1] - slope(45.0)).abs() < 1e-4, "{f:?}");
        // A jump of half a metre (a new set-up) is not believed.
        f.predict(1.5, 0.0, 1e-9);
        let mut jumped = measured(46.5);
        jumped.deviation_m += 0.5;
        assert!(!f.update(&jumped, shield, 1e-9));
    }
}
