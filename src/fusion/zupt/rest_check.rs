//! The check a rest called by the detector must pass before its
//! zero-velocity update is made (`rest_check`, issue 33).
//!
//! The detector ([`super::zero_velocity`]) looks at one window of IMU
//! samples. A steady vibration at rest and a steady vibration while the
//! machine glides at constant speed look alike there: constant velocity
//! leaves no trace in an accelerometer. What does tell them apart is
//! evidence from outside the window, and the engine has two sources:
//!
//! 1. **The filter's velocity.** The INS integrated the acceleration that
//!    started the push; the filter carries the velocity v̂ (NED) and its
//!    covariance P_v. A machine that stands has v = 0, so the zero-velocity
//!    innovation v̂ must be plausible under S = P_v + R (R = σ_zupt² I):
//!
//!    d₀² = v̂ᵀ S⁻¹ v̂ ≤ γ_χ²   (`rest_gate_chi2`; χ² with 3 degrees of
//!    freedom, 16.27 refuses 0.1 % of true rests when P_v is honest).
//!
//!    And a called rest must be more likely standing than still moving
//!    as the filter last knew it to: with v_ref the velocity at the newest
//!    reading the detector called moving or the gate above refused, P_ref
//!    the covariance then, and v_ref plainly motion then (v_refᵀ S_ref⁻¹
//!    v_ref > γ_χ²), "still moving" predicts v̂ ~ N(v_ref, S₁) with
//!
//!    S₁ = (P_v − P_ref) + 2R + c² v_ref v_refᵀ
//!
//!    (the INS drift since then, and a change of speed along the motion of
//!    up to a share c, `rest_speed_change`), "standing" predicts v̂ ~ N(0, S₀ = P_v + R). The
//!    call is refused when the log-likelihood ratio
//!
//!    ½(d₀² − d₁²) + ½ ln(|S₀| / |S₁|),  d₁² = (v̂ − v_ref)ᵀ S₁⁻¹ (v̂ − v_ref),
//!
//!    exceeds `rest_motion_evidence` (3: twenty to one). A machine that
//!    stops decelerates, and the INS sees it: v̂ falls from v_ref to about
//!    0, and the rest is accepted. A machine still gliding keeps v̂ near
//!    v_ref (the INS drifts slowly, a speed fluctuates by a fraction), and
//!    the call is refused however long the detector keeps calling rest,
//!    even once P_v has grown so large that 0 is inside the gate: v̂ sits
//!    on the narrow prediction of "still moving". Where the filter cannot
//!    tell (the drift since v_ref as large as the speed: a long push
//!    without aiding, a crawl at 1 mm/s), the ratio is near 1 and the
//!    detector decides.
//!
//! 2. **The odometer**, where there is one: a called rest is refused while
//!    the odometer advanced more than `odometer_rest_m` over the last
//!    `odometer_rest_window_s` (counted from the first reading of the
//!    detector's current run at the earliest, so the end of the push before
//!    a true rest does not veto it). With a 1 mm counter noise the default
//!    6 mm is 4 standard deviations of a difference of two readings.
//!
//! Steady vibration alone therefore neither makes motion "still" (the
//! velocity and the odometer say it moves) nor rest "moving" (the detector,
//! on integrated signals with learned rest levels, still finds the rest,
//! and v̂ ≈ 0 there). `rest_check=false` makes every called rest a
//! zero-velocity update (the paper).

use std::collections::VecDeque;

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use crate::fusion::geometry::V3;

/// The check's parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RestCheckConfig {
    /// γ_χ²: the largest squared Mahalanobis distance of v̂ from standing.
    pub gate_chi2: f64,
    /// Largest odometer advance over the window that still counts as standing, m.
    pub odometer_advance_m: f64,
    /// The window, s.
    pub odometer_window_s: f64,
    /// How much the speed may change within a push, as a share of it.
    pub speed_change: f64,
    /// Evidence (natural log of the likelihood ratio) for "still moving"
    /// over "standing" above which a called rest is refused.
    pub motion_evidence: f64,
    /// R per axis: the variance of the zero-velocity measurement, (m/s)².
    pub zupt_variance_mps2: f64,
}

impl RestCheckConfig {
    /// S = P_v + R.
    fn innovation(&self, p_v: &Matrix3<f64>) -> Option<Gaussian> {
        Gaussian::new(&(p_v + Matrix3::identity() * self.zupt_variance_mps2))
    }
}

/// The filter's velocity v̂ (NED, m/s) and its covariance P_v.
pub type Velocity<'a> = (&'a V3, &'a Matrix3<f64>);

/// Why a called rest was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// v̂ is not plausible for a standing machine.
    Velocity,
    /// v̂ is nearer to the motion known before the call than to standing.
    StillMoving,
    /// The odometer advanced.
    Odometer,
}

/// The check's memory; see the module documentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct RestCheck {
    /// v̂ at the newest reading the detector called moving or the gate
    /// refused, NED m/s, P_v then, and whether it was plainly motion then
    /// (v_refᵀ S⁻¹ v_ref > γ_χ² with that reading's S).
    reference_mps: V3,
    reference_p: Matrix3<f64>,
    reference_is_motion: bool,
    /// Time of the first reading of the detector's current run of rest.
    run_start_t: Option<f64>,
    /// Odometer readings (t, m), oldest first, over the last window.
    odometer: VecDeque<(f64, f64)>,
}

impl RestCheck {
    /// The detector called a reading moving: its run of rest has ended.
    /// With the filter's velocity then (`None` before alignment), that is
    /// the motion the filter knows.
    pub fn moving(&mut self, config: &RestCheckConfig, velocity: Option<Velocity<'_>>) {
        self.run_start_t = None;
        let Some((v, p_v)) = velocity else {
            return;
        };
        self.reference_is_motion = config
            .innovation(p_v)
            .is_some_and(|s| s.distance(v) > config.gate_chi2);
        self.reference_mps = *v;
        self.reference_p = *p_v;
    }

    /// An odometer reading the navigation time has reached.
    pub fn odometer(&mut self, config: &RestCheckConfig, t: f64, distance_m: f64) {
        self.odometer.push_back((t, distance_m));
        // Keep one reading at or before the window's start.
        while self.odometer.len() > 2
            && self
                .odometer
                .get(1)
                .is_some_and(|&(t1, _)| t1 <= t - config.odometer_window_s)
        {
            self.odometer.pop_front();
        }
    }

    /// Whether the odometer advanced over the window ending at `t`.
    fn odometer_advanced(&self, config: &RestCheckConfig, t: f64) -> bool {
        let from = (t - config.odometer_window_s).max(self.run_start_t.unwrap_or(t));
        let Some(&(_, newest)) = self.odometer.back() else {
            return false;
        };
        // The oldest reading within the window (at or after `from`).
        match self.odometer.iter().find(|&&(ti, _)| ti >= from) {
            Some(&(_, first)) => (newest - first).abs() > config.odometer_advance_m,
            None => false,
        }
    }

    /// The detector called the reading at `t` a rest: the verdict, with
    /// the filter's velocity (`None` before alignment: the odometer alone
    /// decides). `None`: standing.
    pub fn judge(
        &mut self,
        config: &RestCheckConfig,
        t: f64,
        velocity: Option<Velocity<'_>>,
    ) -> Option<Refusal> {
        self.run_start_t.get_or_insert(t);
        if self.odometer_advanced(config, t) {
            return Some(Refusal::Odometer);
        }
        let (v, p_v) = velocity?;
        let r = config.zupt_variance_mps2;
        let standing = config.innovation(p_v)?;
        let d0 = standing.distance(v);
        if d0 > config.gate_chi2 {
            // Plainly moving: this is the motion the filter knows.
            self.reference_mps = *v;
            self.reference_p = *p_v;
            self.reference_is_motion = true;
            return Some(Refusal::Velocity);
        }
        if self.reference_is_motion {
            // Still moving as before: v̂ − v_ref is the INS drift since then
            // and a change of speed, along the motion: c² v_ref v_refᵀ.
            let along = self.reference_mps * config.speed_change;
            let s1 = (p_v - self.reference_p)
                + Matrix3::identity() * (2.0 * r)
                + along * along.transpose();
            let moving = Gaussian::new(&s1).unwrap_or(standing);
            let d1 = moving.distance(&(v - self.reference_mps));
            let evidence = 0.5 * (d0 - d1) + 0.5 * (standing.log_det - moving.log_det);
            if evidence > config.motion_evidence {
                return Some(Refusal::StillMoving);
            }
        }
        None
    }
}

/// A zero-mean Gaussian of covariance S: its Cholesky factor and ln |S|.
#[derive(Clone, Copy)]
struct Gaussian {
    cholesky: Matrix3<f64>,
    log_det: f64,
}

impl Gaussian {
    fn new(s: &Matrix3<f64>) -> Option<Gaussian> {
        let cholesky = s.cholesky()?.l();
        let log_det = 2.0 * (0..3).map(|i| cholesky[(i, i)].ln()).sum::<f64>();
        log_det
            .is_finite()
            .then_some(Gaussian { cholesky, log_det })
    }

    /// xᵀ S⁻¹ x.
    fn distance(&self, x: &V3) -> f64 {
        self.cholesky
            .solve_lower_triangular(x)
            .map_or(f64::INFINITY, |y| y.norm_squared())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CONFIG: RestCheckConfig = RestCheckConfig {
        gate_chi2: 16.0,
        odometer_advance_m: 0.006,
        odometer_window_s: 10.0,
        speed_change: 0.3,
        motion_evidence: 3.0,
        zupt_variance_mps2: 4e-6,
    };

    fn p(sigma: f64) -> Matrix3<f64> {
        Matrix3::identity() * sigma * sigma
    }

    #[test]
    fn the_velocity_gate() {
        let mut check = RestCheck::default();
        check.moving(&CONFIG, Some((&V3::zeros(), &p(0.002))));
        // σ_v = 5 mm/s, R = (2 mm/s)²: S = 29e-6 per axis. 20 mm/s north:
        // d² = 4e-4 / 29e-6 = 13.8 < 16, standing; 25 mm/s: 21.6, refused.
        let at = |v: f64| V3::new(v, 0.0, 0.0);
        assert_eq!(
            check.judge(&CONFIG, 0.0, Some((&at(0.020), &p(0.005)))),
            None
        );
        assert_eq!(
            check.judge(&CONFIG, 0.1, Some((&at(0.025), &p(0.005)))),
            Some(Refusal::Velocity)
        );
    }

    #[test]
    fn a_glide_at_the_known_speed_is_refused_and_the_stop_after_it_is_not() {
        let mut check = RestCheck::default();
        // Moving at 40 mm/s when the detector last said so, σ_v 2 mm/s:
        // d² = 0.0016 / 8e-6 = 200, plainly motion.
        check.moving(&CONFIG, Some((&V3::new(0.040, 0.0, 0.0), &p(0.002))));
        // Later σ_v has grown to 12 mm/s: S₀ = 1.48e-4 per axis, and 38
        // mm/s is d₀² = 9.76, inside the gate. Still moving: S₁ = 1.44e-4 −
        // 4e-6 + 8e-6 + (0.3 · 0.04)² = 2.92e-4, d₁² = 0.0137; evidence
        // ½(9.76 − 0.014) + (3/2) ln(1.48 / 2.92) = 3.85 > 3: refused.
        let sigma = p(0.012);
        assert_eq!(
            check.judge(&CONFIG, 20.0, Some((&V3::new(0.038, 0.0, 0.0), &sigma))),
            Some(Refusal::StillMoving)
        );
        // The INS saw the deceleration: v̂ = 5 mm/s, d₀² = 0.17, d₁² = 4.2:
        // the evidence is negative, standing.
        assert_eq!(
            check.judge(&CONFIG, 25.0, Some((&V3::new(0.005, 0.0, 0.0), &sigma))),
            None
        );
        // A reference the filter could not tell from standing decides
        // nothing: 10 mm/s at σ_v 12 mm/s is d² = 0.68.
        check.moving(&CONFIG, Some((&V3::new(0.010, 0.0, 0.0), &sigma)));
        assert_eq!(
            check.judge(&CONFIG, 30.0, Some((&V3::new(0.010, 0.0, 0.0), &sigma))),
            None
        );
    }

    #[test]
    fn the_odometer_vetoes_within_the_run_only() {
        // Advancing 10 mm/s until t = 20 s, then standing; a reading a second.
        let feed = |check: &mut RestCheck, from: u32, to: u32| {
            for k in from..=to {
                let t = f64::from(k);
                check.odometer(&CONFIG, t, 0.010 * t.min(20.0));
            }
        };
        // A run called at 5 s: nothing within it yet; at 12 s, 70 mm.
        let mut gliding = RestCheck::default();
        feed(&mut gliding, 0, 5);
        assert_eq!(gliding.judge(&CONFIG, 5.0, None), None);
        feed(&mut gliding, 6, 12);
        assert_eq!(gliding.judge(&CONFIG, 12.0, None), Some(Refusal::Odometer));
        // A run that starts at the stop (20 s) is not vetoed by the push
        // before it, though the last 10 s hold 100 mm.
        let mut stopped = RestCheck::default();
        feed(&mut stopped, 0, 20);
        assert_eq!(stopped.judge(&CONFIG, 20.0, None), None);
        feed(&mut stopped, 21, 22);
        assert_eq!(stopped.judge(&CONFIG, 22.0, None), None);
        // Called moving at 23 s (before alignment: no velocity), a new run
        // at 25 s starts its window there.
        let mut early = RestCheck::default();
        feed(&mut early, 0, 3);
        assert_eq!(early.judge(&CONFIG, 3.0, None), None);
        feed(&mut early, 4, 23);
        early.moving(&CONFIG, None);
        feed(&mut early, 24, 25);
        assert_eq!(early.judge(&CONFIG, 25.0, None), None);
        // Only one reading at or before the window's start is kept.
        feed(&mut stopped, 23, 40);
        assert_eq!(stopped.odometer.front().map(|&(t, _)| t), Some(30.0));
    }
}
