//! Evidence, while moving, that the gyro bias moved since it was last
//! learnt (a power cycle or a temperature shock on the road), and the
//! bias's process noise it calls for (docs/engines/fuzzy.md: a bias that
//! moves while moving).
//!
//! A bias learnt at a rest is sure of itself (small variance P), so the
//! accelerometer's pulls barely move it (bias_feedback.rs) and the tilt σ
//! grows slowly: a new bias then turns the tilt faster than the gated pull
//! takes it back, the residual leaves the gate and every correction is
//! refused because the tilt is already wrong. The evidence against the
//! bias is a tilt error that persists: the window's mean specific force
//! in the world frame, its horizontal part over g, e ≈ the tilt's error
//! (rad) plus the vehicle's horizontal acceleration over g. Linear in the
//! acceleration, its mean over a time T is the change of velocity over T
//! divided by g·T, bounded whatever the vehicle does (a turn included),
//! while the tilt a bias error turns in stays.
//!
//! Over moving readings the engine keeps an exponentially weighted mean ē
//! of e's two horizontal components, time constant T = [`EVIDENCE_TIME_S`],
//! started at 0 after each rest: ē = Σ (w·dt/T)·e·(1 − w·dt/T)^(newer
//! readings), w the reading's weight (how far it moves). For an
//! acceleration a(t) whose speed never exceeds v_max, integrating by parts,
//! g·T·ē = v(t) − v(0)·e^(−t/T) − ∫ v(s)·e^(−(t−s)/T) ds/T, so after t
//! of moving ‖ē‖ ≤ v_max·(2 − e^(−t/T))/(g·T) from a rest (v(0) = 0) and
//! ≤ 2·v_max/(g·T) from a doubt (the vehicle moving), whatever it did (a
//! U-turn at v_max included). The mean is evidence of a bias error when
//!
//! ```text
//! ‖ē‖ − a  >  3·√P·τ,   a = atan(v_max·(2 − e^(−t/T))/(g·T))          (1)
//! ```
//!
//! (from a doubt, a = atan(2·v_max/(g·T))) with v_max = `top_speed_mps`,
//! τ the moving pull's time constant and P
//! the largest of the bias's horizontal variances (a pull holds a bias
//! error δb at a steady residual δb·τ). The accelerometer's noise, a tilt
//! window's mean averaged over T, is far below a (1.5° after a rest, up
//! to 2.9° at 15 m/s). A tilt that runs away at r rad/s after a rest
//! passes a after about √(2·T·a/r) (18 s at 0.55 °/s), a steady residual
//! e once e·(1 − e^(−t/T)) does. A gyro whose bias moved
//! on two axes has likely moved on the third, so the evidence sets on
//! every axis
//!
//! ```text
//! P_k ← max(P_k, (d/τ)²),   σ_tilt ← max(σ_tilt, d),   d = max(‖ē‖, ‖ē₅‖)   (2)
//! ```
//!
//! with ē₅ the same mean over the last [`RECENT_S`] (the 60 s mean lags a
//! tilt that runs away, a reading's own e is the acceleration of the
//! moment too — taking it opened the gate to a hand's to-and-fro on real
//! recordings — and a to-and-fro averages out within seconds), and the
//! pulls learn the bias again (bias_feedback.rs, the compass's for the
//! vertical axis), the widened σ opening the gate to the accelerometer;
//! the mean starts again from 0.

use serde::{Deserialize, Serialize};

use super::STANDARD_GRAVITY_MPS2;
use crate::fusion::geometry::V3;

/// The evidence's time constant T, s.
pub const EVIDENCE_TIME_S: f64 = 60.0;
/// The time constant of the mean that says how far the tilt is off
/// when the evidence is found, s: a tilt running away moves far within
/// it, a hand's or a vehicle's to-and-fro averages out.
pub const RECENT_S: f64 = 5.0;
/// The evidence's threshold in σ of its mean.
pub const EVIDENCE_SIGMAS: f64 = 3.0;

/// What the evidence found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Doubt {
    /// The bias variance per body axis the evidence calls for, (rad/s)².
    pub bias_variance: f64,
    /// The tilt error the residual shows, d in (2), rad.
    pub tilt_off_rad: f64,
}

/// The evidence's state.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct BiasDoubt {
    /// Weighted mean of e's north and east components since the last
    /// rest or doubt, rad.
    mean_rad: [f64; 2],
    /// The same mean over the last [`RECENT_S`] (normalised once that
    /// is covered): how far the tilt is off now, rad.
    recent_rad: [f64; 2],
    /// Moving time (weighted) the mean covers, s.
    covered_s: f64,
    /// The mean started at a rest (the vehicle's speed was 0).
    from_rest: bool,
    /// The evidence called the bias into doubt since the last rest.
    doubted: bool,
    /// Times the evidence called the bias into doubt.
    pub doubts: u64,
}

impl BiasDoubt {
    /// Takes one reading's e, `horizontal_over_g` (the window's mean
    /// force in the world frame over g, rad; its z is ignored), counted
    /// with `weight` ∈ [0, 1] (how far the vehicle moves) over `dt_s`; `top_speed_mps` is v_max in (1), `pull_time_constant_s` τ
    /// and `bias_variance` the bias's P per body axis.
    pub fn observe(
        &mut self,
        horizontal_over_g: &V3,
        weight: f64,
        dt_s: f64,
        top_speed_mps: f64,
        pull_time_constant_s: f64,
        bias_variance: &V3,
    ) -> Option<Doubt> {
        let weight = weight.clamp(0.0, 1.0);
        if weight <= 0.0 || dt_s <= 0.0 || !horizontal_over_g.iter().all(|e| e.is_finite()) {
            return None;
        }
        let alpha = (weight * dt_s / EVIDENCE_TIME_S).min(1.0);
        let recent_alpha = (weight * dt_s / RECENT_S).min(1.0);
        for k in 0..2 {
            self.mean_rad[k] += alpha * (horizontal_over_g[k] - self.mean_rad[k]);
            self.recent_rad[k] += recent_alpha * (horizontal_over_g[k] - self.recent_rad[k]);
        }
        self.covered_s += weight * dt_s;
        let reach = if self.from_rest {
            2.0 - (-self.covered_s / EVIDENCE_TIME_S).exp()
        } else {
            2.0
        };
        let allowance_rad =
            (reach * top_speed_mps / (STANDARD_GRAVITY_MPS2 * EVIDENCE_TIME_S)).atan();
        let tau = pull_time_constant_s.max(f64::EPSILON);
        let sigma = bias_variance.x.max(bias_variance.y).max(0.0).sqrt() * tau;
        let off_rad = self.mean_rad[0].hypot(self.mean_rad[1]);
        let margin_rad = off_rad - allowance_rad - EVIDENCE_SIGMAS * sigma;
        if margin_rad.is_nan() || margin_rad <= 0.0 {
            return None;
        }
        // The mean lags a tilt that runs away: the last seconds' mean
        // shows how far it has gone (a reading's own residual would be
        // the acceleration of the moment, too).
        let off_rad = off_rad.max(self.recent_rad[0].hypot(self.recent_rad[1]));
        *self = BiasDoubt {
            doubts: self.doubts + 1,
            doubted: true,
            ..BiasDoubt::default()
        };
        Some(Doubt {
            bias_variance: (off_rad / tau).powi(2),
            tilt_off_rad: off_rad,
        })
    }

    /// Whether the evidence called the bias into doubt since the last rest
    /// (the pulls then learn it, bias_feedback.rs `variance_after`).
    pub fn doubted(&self) -> bool {
        self.doubted
    }

    /// Starts the evidence again (a rest learnt the bias).
    pub fn restart(&mut self) {
        *self = BiasDoubt {
            doubts: self.doubts,
            from_rest: true,
            ..BiasDoubt::default()
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 0.01;
    /// v_max with v_max/(g·T) = 0.01: the allowance is atan(0.02) =
    /// 0.019997 rad from a doubt, atan(0.01·(2 − e^(−t/T))) from a rest.
    const V_MAX: f64 = 0.01 * STANDARD_GRAVITY_MPS2 * EVIDENCE_TIME_S;

    /// Feeds `residual` for `seconds`, moving (τ 10 s); the last doubt.
    fn feed(doubt: &mut BiasDoubt, residual: V3, seconds: f64, variance: &V3) -> Option<Doubt> {
        let mut found = None;
        for _ in 0..(seconds / DT).round() as usize {
            if let Some(d) = doubt.observe(&residual, 1.0, DT, V_MAX, 10.0, variance) {
                found = Some(d);
            }
        }
        found
    }

    #[test]
    fn a_steady_residual_beyond_the_allowance_doubts_the_bias() {
        // e = 0.05 rad east held, P = 1e-8 (3σ = 3·1e-4·10 = 0.003): the
        // mean 0.05·(1 − e^(−t/60)) passes 0.019997 + 0.003 at t = 36.97 s.
        // Then d = max(0.023, the 5 s mean ≈ 0.05): P = (d/10)² on every
        // axis.
        let east = V3::new(0.0, 0.05, 0.0);
        let sure = V3::repeat(1e-8);
        let mut doubt = BiasDoubt::default();
        assert!(feed(&mut doubt, east, 36.9, &sure).is_none());
        assert!(!doubt.doubted());
        let found = feed(&mut doubt, east, 0.2, &sure).expect("a steady 2.9° residual");
        // d is the 5 s mean after 3697 readings: 0.05·(1 − (1 − 0.002)^3697).
        let recent = 0.05 * (1.0 - (1.0 - DT / RECENT_S).powi(3697));
        assert!((recent - 0.05).abs() < 1e-4);
        assert!(
            (found.bias_variance - (recent / 10.0).powi(2)).abs() < 1e-12,
            "{found:?}"
        );
        assert!((found.tilt_off_rad - recent).abs() < 1e-10);
        assert!(doubt.doubted());
        assert_eq!(doubt.doubts, 1);
        // The mean starts again from 0: 30 s more reach only 0.0197.
        assert!(feed(&mut doubt, east, 30.0, &sure).is_none());
        // From a rest the allowance starts at half: the same residual is
        // evidence after 23.58 s (mean 0.01625 against 0.01325 + 0.003).
        doubt.restart();
        assert!(!doubt.doubted());
        assert_eq!(doubt.doubts, 1);
        assert!(feed(&mut doubt, east, 23.5, &sure).is_none());
        assert!(feed(&mut doubt, east, 0.2, &sure).is_some());
        assert_eq!(doubt.doubts, 2);
    }

    #[test]
    fn what_the_speed_or_an_unsure_bias_explains_is_no_evidence() {
        let sure = V3::repeat(1e-8);
        // The allowance itself, held for 1000 s.
        let mut doubt = BiasDoubt::default();
        assert!(feed(&mut doubt, V3::new(0.02, 0.0, 0.0), 1000.0, &sure).is_none());
        // A bias σ of 0.001 rad/s holds a residual of 0.01 rad in 1σ:
        // 3σ = 0.03, and 0.045 − 0.02 stays within it.
        let mut doubt = BiasDoubt::default();
        let unsure = V3::repeat(1e-6);
        assert!(feed(&mut doubt, V3::new(0.045, 0.0, 0.0), 1000.0, &unsure).is_none());
        // Nothing counts at rest (weight 0).
        let mut doubt = BiasDoubt::default();
        for _ in 0..10_000 {
            assert!(
                doubt
                    .observe(&V3::new(0.5, 0.5, 0.0), 0.0, DT, V_MAX, 10.0, &sure)
                    .is_none()
            );
        }
    }
}
