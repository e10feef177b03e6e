//! The check a rest called by the detector must pass before its
//! zero-velocity update is made (`rest_check`, on by default; issue 33).
//!
//! The detector ([`super::zero_velocity`]) looks at one window of IMU
//! samples. A steady vibration at rest and a steady vibration while the
//! machine glides at constant speed look alike there: constant velocity
//! leaves no trace in an accelerometer. What tells them apart is how the
//! machine got there. It cannot start or stop without accelerating, and an
//! acceleration changes the velocity within a window, which the detector
//! calls moving. So the timeline splits into the detector's runs of rest,
//! separated by motion, and within a run the machine keeps the velocity it
//! had at the run's start. The check books that velocity u (NED) with a
//! covariance Σ_u and judges each run **once**, at its first aligned
//! reading, while the evidence is fresh:
//!
//! 1. **What the INS integrated since the previous run.** With v̂, P_v the
//!    filter's velocity and covariance now and v̂_e, P_e at the last
//!    reading of the previous run,
//!
//!    u = u_prev + (v̂ − v̂_e),  S = Σ_prev + (P_v − P_e) + R (+ c² u_prev u_prevᵀ)
//!
//!    (R = σ_zupt² I; u_prev = 0 and Σ_prev = P_e after an accepted rest;
//!    after a refused run u_prev is its booked velocity, and the last term,
//!    with c = `rest_speed_change`, lets its speed drift by that share
//!    while the detector saw nothing). The drift of the INS *within* a run
//!    never enters: a push of ten minutes is judged on the few seconds of
//!    its stop, not on the metres per second an unaided INS gathers.
//! 2. **A χ² gate**: the run is refused when d₀² = uᵀ S⁻¹ u > γ_χ²
//!    (`rest_gate_chi2`; χ², 3 degrees of freedom: 16.27 refuses 0.1 % of
//!    true rests). A machine that just accelerated to 40 mm/s is not
//!    standing because its vibration is steady.
//! 3. **Still moving or stopped?** After a refused run, the run is also
//!    refused when the log-likelihood ratio of "still moving at u_prev"
//!    over "standing", ½(d₀² − d₁²) with d₁² = (u − u_prev)ᵀ S⁻¹ (u −
//!    u_prev), exceeds `rest_motion_evidence` (3: twenty to one). A stop
//!    decelerates the machine by u_prev, the INS sees it, and u ≈ 0.
//! 4. **Plausible motion only.** The machine advances along its axis, at
//!    up to `max_speed_mps`. A refusal needs u forward along the axis
//!    (within 27°) and no faster than that (plus 3σ); anything else is the
//!    INS gone wrong (a level taken while the machine crept, say), and the
//!    detector decides: its zero-velocity updates bring the INS back.
//! 5. **The odometer**, where there is one, vetoes single readings: a
//!    called rest is refused while the odometer advanced more than
//!    `odometer_rest_m` over the last `odometer_rest_window_s` (counted
//!    from the first reading of the detector's current run at the
//!    earliest, so the end of the push before a true rest does not veto
//!    it), or between its two newest readings (when both lie within that
//!    window): a run the detector starts in the middle of a push is then
//!    refused at once, and a true rest loses at most the one interval
//!    that spans its stop. With a 1 mm counter noise the default 6 mm is
//!    4 standard deviations of a difference of two readings.
//! 6. **The odometer confirms a rest.** A run refused for its velocity
//!    (2 or 3) becomes a rest once the odometer stayed within
//!    `odometer_rest_m` over a whole `odometer_rest_window_s` (its oldest
//!    reading kept at or before the window's start, its newest within the
//!    window's last fifth): the detector and the odometer then agree the
//!    machine stands, whatever velocity was booked (a booking the
//!    odometer's fusion has since corrected, say). Without this a wrong
//!    refusal at the start of a rest held for all of it. A creep slower
//!    than `odometer_rest_m` per window (0.6 mm/s by default) and an
//!    odometer that keeps sending one frozen value are taken for standing
//!    here.
//!
//! A verdict holds until the detector calls moving. An accepted run books
//! the machine standing (u = 0, Σ_u = P_v at its end); a refused one books
//! u. Before alignment only the odometer decides; a navigation reset
//! forgets what was booked. Steady vibration alone therefore neither makes
//! motion "still" (the velocity booked at the run's start says it moves)
//! nor rest "moving" (the detector, on integrated signals with learned rest
//! levels, still finds the rest, and u ≈ 0 there). What the check cannot
//! see: a start or stop too gentle for the detector (below about 2 mm/s
//! within a window), which leaves the booking as it was. `rest_check=false`
//! makes every called rest a zero-velocity update (the paper).

use std::collections::VecDeque;

use nalgebra::Matrix3;
use serde::{Deserialize, Serialize};

use crate::fusion::geometry::V3;

/// The check's parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RestCheckConfig {
    /// γ_χ²: the largest squared Mahalanobis distance of the booked
    /// velocity u from standing.
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
    /// The fastest the machine advances, m/s.
    pub max_speed_mps: f64,
}

/// What the filter knows at a reading: its velocity v̂ (NED, m/s), the
/// covariance P_v, and the machine's forward axis (a unit vector, NED).
#[derive(Debug, Clone, Copy)]
pub struct Velocity<'a> {
    pub velocity_mps: &'a V3,
    pub p_v: &'a Matrix3<f64>,
    pub forward: &'a V3,
}

/// Why a called rest was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Refusal {
    /// v̂ is not plausible for a standing machine.
    Velocity,
    /// v̂ is nearer to the motion known before the call than to standing.
    StillMoving,
    /// The odometer advanced.
    Odometer,
}

/// The verdict on one run of rest the detector called.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
enum Verdict {
    Standing,
    Refused(Refusal),
}

/// The check's memory; see the module documentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct RestCheck {
    /// u: the machine's velocity as the check books it, NED m/s (zero
    /// over an accepted rest, the velocity found at the start of a refused
    /// run over that run), and Σ_u, its covariance without the allowance
    /// for a change of speed.
    booked_mps: V3,
    booked_p: Matrix3<f64>,
    /// Whether the newest run was refused (the machine was moving then).
    booked_is_motion: bool,
    /// v̂ and P_v at the newest reading of a run (its end once the detector
    /// calls moving); `None` before the first aligned reading.
    anchor: Option<(V3, Matrix3<f64>)>,
    /// The verdict on the detector's current run, made at its first
    /// aligned reading and kept until the detector calls moving.
    verdict: Option<Verdict>,
    /// Time of the first reading of the detector's current run of rest.
    run_start_t: Option<f64>,
    /// Odometer readings (t, m), oldest first, over the last window.
    odometer: VecDeque<(f64, f64)>,
}

impl RestCheck {
    /// The detector called a reading moving: its run of rest, if any, has
    /// ended; a rest it accepted books the machine as standing.
    pub fn moving(&mut self) {
        self.run_start_t = None;
        if self.verdict.take() == Some(Verdict::Standing)
            && let Some((_, p_end)) = self.anchor
        {
            self.booked_mps = V3::zeros();
            self.booked_p = p_end;
            self.booked_is_motion = false;
        }
    }

    /// The navigation starts again from nothing (a reset): nothing booked.
    pub fn forget_motion(&mut self) {
        let odometer = std::mem::take(&mut self.odometer);
        *self = RestCheck {
            odometer,
            ..RestCheck::default()
        };
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

    /// Whether the odometer, read within the newest fifth of the window,
    /// stayed within `odometer_advance_m` over the whole window ending at
    /// `t`.
    pub fn odometer_still(&self, config: &RestCheckConfig, t: f64) -> bool {
        let window_s = config.odometer_window_s;
        let (Some(&(oldest_t, _)), Some(&(newest_t, _))) =
            (self.odometer.front(), self.odometer.back())
        else {
            return false;
        };
        let (low, high) = self.odometer.iter().fold(
            (f64::INFINITY, f64::NEG_INFINITY),
            |(low, high), &(_, d)| (low.min(d), high.max(d)),
        );
        oldest_t <= t - window_s
            && newest_t >= t - 0.2 * window_s
            && high - low <= config.odometer_advance_m
    }

    /// Whether the odometer advanced over the window ending at `t`, or
    /// between its two newest readings (when they lie within the window):
    /// a run the detector starts in the middle of a push is refused at
    /// once, a rest costs at most the one interval that spans the stop.
    fn odometer_advanced(&self, config: &RestCheckConfig, t: f64) -> bool {
        let from = (t - config.odometer_window_s).max(self.run_start_t.unwrap_or(t));
        let Some(&(newest_t, newest)) = self.odometer.back() else {
            return false;
        };
        if let Some(&(previous_t, previous)) = self.odometer.iter().rev().nth(1)
            && previous_t >= t - config.odometer_window_s
            && newest_t > previous_t
            && (newest - previous).abs() > config.odometer_advance_m
        {
            return true;
        }
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
        let odometer_advanced = self.odometer_advanced(config, t);
        let Some(Velocity {
            velocity_mps: v,
            p_v,
            forward,
        }) = velocity
        else {
            return odometer_advanced.then_some(Refusal::Odometer);
        };
        let mut verdict = match self.verdict {
            Some(verdict) => verdict,
            None => self.judge_run(config, v, p_v, forward),
        };
        // The detector and the odometer agree the machine stands: a run
        // refused for its velocity is a rest after all once the odometer,
        // read throughout, has not advanced over a whole window.
        if matches!(
            verdict,
            Verdict::Refused(Refusal::Velocity | Refusal::StillMoving)
        ) && self.odometer_still(config, t)
        {
            verdict = Verdict::Standing;
        }
        self.verdict = Some(verdict);
        self.anchor = Some((*v, *p_v));
        match verdict {
            Verdict::Refused(refusal) => Some(refusal),
            Verdict::Standing => odometer_advanced.then_some(Refusal::Odometer),
        }
    }

    /// The verdict on a run from its first aligned reading (module doc).
    fn judge_run(
        &mut self,
        config: &RestCheckConfig,
        v: &V3,
        p_v: &Matrix3<f64>,
        forward: &V3,
    ) -> Verdict {
        // Δ: what the INS integrated since the end of the previous run,
        // with the drift it gathered meanwhile (P_v − P_v,end).
        let (anchor_v, anchor_p) = self.anchor.unwrap_or((*v, *p_v));
        let u = self.booked_mps + (v - anchor_v);
        let r = Matrix3::identity() * config.zupt_variance_mps2;
        // Σ_u of this run, and S with the allowance for a change of speed.
        let sigma_u = self.booked_p + (p_v - anchor_p) + r;
        let mut s = sigma_u;
        if self.booked_is_motion {
            let along = self.booked_mps * config.speed_change;
            s += along * along.transpose();
        }
        let Some(gaussian) =
            Gaussian::new(&s).or_else(|| Gaussian::new(&(self.booked_p + p_v + r)))
        else {
            return Verdict::Standing;
        };
        let d0 = gaussian.distance(&u);
        let refusal = if d0 > config.gate_chi2 {
            Some(Refusal::Velocity)
        } else if self.booked_is_motion
            && 0.5 * (d0 - gaussian.distance(&(u - self.booked_mps))) > config.motion_evidence
        {
            Some(Refusal::StillMoving)
        } else {
            None
        };
        // Motion the machine cannot make (backwards, sideways, faster than
        // it can) is the INS gone wrong: the detector decides, and its
        // zero-velocity updates bring the INS back.
        let along = u.dot(forward);
        let plausible = along > 0.0
            && (u - forward * along).norm() <= 0.5 * along
            && along <= config.max_speed_mps + 3.0 * (forward.transpose() * s * forward)[0].sqrt();
        match refusal.filter(|_| plausible) {
            Some(refusal) => {
                self.booked_mps = u;
                self.booked_p = sigma_u;
                self.booked_is_motion = true;
                Verdict::Refused(refusal)
            }
            None => Verdict::Standing,
        }
    }
}

/// A zero-mean Gaussian of covariance S, by its Cholesky factor.
#[derive(Clone, Copy)]
struct Gaussian {
    cholesky: Matrix3<f64>,
}

impl Gaussian {
    fn new(s: &Matrix3<f64>) -> Option<Gaussian> {
        let cholesky = s.cholesky()?.l();
        (0..3)
            .all(|i| cholesky[(i, i)] > 0.0)
            .then_some(Gaussian { cholesky })
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
        max_speed_mps: 0.15,
    };

    fn p(sigma: f64) -> Matrix3<f64> {
        Matrix3::identity() * sigma * sigma
    }

    const NORTH: V3 = V3::new(1.0, 0.0, 0.0);

    fn at<'a>(v: &'a V3, p_v: &'a Matrix3<f64>) -> Option<Velocity<'a>> {
        Some(Velocity {
            velocity_mps: v,
            p_v,
            forward: &NORTH,
        })
    }

    #[test]
    fn a_run_is_judged_once_on_the_velocity_the_ins_integrated_since_the_last_run() {
        let mut check = RestCheck::default();
        // Aligned standing, σ_v 0.6 mm/s: accepted, booked standing.
        let sigma_rest = p(0.0006);
        assert_eq!(
            check.judge(&CONFIG, 0.0, at(&V3::zeros(), &sigma_rest)),
            None
        );
        check.moving();
        // After a ramp the INS says 40 mm/s north, σ_v 1.4 mm/s: u = 40 mm/s,
        // S = 3.6e-7 + (1.96e-6 − 3.6e-7) + 4e-6 = 5.96e-6 per axis,
        // d² = 1.6e-3 / 5.96e-6 = 268 > 16: refused.
        let v = V3::new(0.040, 0.0, 0.0);
        assert_eq!(
            check.judge(&CONFIG, 2.0, at(&v, &p(0.0014))),
            Some(Refusal::Velocity)
        );
        // Later in the same run P_v has grown to (20 mm/s)² and v̂ drifted
        // to 45 mm/s (d² 5 from standing): the run stays refused.
        let drifted = V3::new(0.045, 0.0, 0.0);
        assert_eq!(
            check.judge(&CONFIG, 30.0, at(&drifted, &p(0.020))),
            Some(Refusal::Velocity)
        );
        check.moving();
        // A blip of motion changes v̂ by nothing: u stays 40 mm/s. Along
        // the motion S = 5.96e-6 (booked) + 4e-6 + (0.3 · 0.04)² =
        // 1.54e-4: d₀² = 10.4, inside the gate, d₁² = 0: evidence 5.2 > 3,
        // still moving.
        assert_eq!(
            check.judge(&CONFIG, 31.0, at(&drifted, &p(0.020))),
            Some(Refusal::StillMoving)
        );
        check.moving();
        // The stop: the INS saw −41 mm/s: u = −1 mm/s; S = 9.96e-6 + 4e-6
        // + 1.44e-4 = 1.58e-4 along: d₀² = 0.006, d₁² = 1.681e-3 / 1.58e-4
        // = 10.6: standing.
        let stopped = V3::new(0.004, 0.0, 0.0);
        assert_eq!(check.judge(&CONFIG, 33.0, at(&stopped, &p(0.020))), None);
        // The rest is booked standing once the detector calls moving.
        check.moving();
        assert_eq!(check.booked_mps, V3::zeros());
        assert!(!check.booked_is_motion);
    }

    /// A check whose first run, standing still, was accepted and ended:
    /// the machine is booked standing.
    fn after_a_rest() -> RestCheck {
        let mut check = RestCheck::default();
        assert_eq!(
            check.judge(&CONFIG, 0.0, at(&V3::zeros(), &p(0.0006))),
            None
        );
        check.moving();
        check
    }

    #[test]
    fn motion_the_machine_cannot_make_leaves_the_call_to_the_detector() {
        let check = after_a_rest();
        // Backwards at 40 mm/s, sideways at 40 mm/s, or forward at 0.3
        // m/s (max 0.15 + 3 · 2.4 mm/s): an INS gone wrong, accepted.
        for v in [
            V3::new(-0.040, 0.0, 0.0),
            V3::new(0.0, 0.040, 0.0),
            V3::new(0.300, 0.0, 0.0),
        ] {
            let mut c = check.clone();
            assert_eq!(c.judge(&CONFIG, 2.0, at(&v, &p(0.0014))), None, "{v:?}");
        }
    }

    /// Odometer readings a second apart from `from` to `to` s, distance
    /// `distance(t)`.
    fn feed(check: &mut RestCheck, from: u32, to: u32, distance: impl Fn(f64) -> f64) {
        for k in from..=to {
            let t = f64::from(k);
            check.odometer(&CONFIG, t, distance(t));
        }
    }

    #[test]
    fn the_odometer_vetoes_runs_in_a_push_at_once_and_spares_rests() {
        // Advancing 10 mm/s until t = 20 s, then standing (window 10 s,
        // 6 mm).
        let push = |t: f64| 0.010 * t.min(20.0);
        // A run called at 5 s: the newest second advanced 10 mm > 6 mm;
        // at 12 s the run itself holds 70 mm.
        let mut gliding = RestCheck::default();
        feed(&mut gliding, 0, 5, push);
        assert_eq!(gliding.judge(&CONFIG, 5.0, None), Some(Refusal::Odometer));
        feed(&mut gliding, 6, 12, push);
        assert_eq!(gliding.judge(&CONFIG, 12.0, None), Some(Refusal::Odometer));
        // A run that starts at the stop (20 s): the second before it still
        // advanced 10 mm, so 20 s is refused; at 21 s the newest second is
        // flat, and so is the run: standing, though the last 10 s hold
        // 90 mm.
        let mut stopped = RestCheck::default();
        feed(&mut stopped, 0, 20, push);
        assert_eq!(stopped.judge(&CONFIG, 20.0, None), Some(Refusal::Odometer));
        feed(&mut stopped, 21, 21, push);
        assert_eq!(stopped.judge(&CONFIG, 21.0, None), None);
        // Called moving at 23 s, a new run at 25 s: flat since 20 s.
        let mut early = RestCheck::default();
        feed(&mut early, 0, 23, push);
        early.moving();
        feed(&mut early, 24, 25, push);
        assert_eq!(early.judge(&CONFIG, 25.0, None), None);
        // Only one reading at or before the window's start is kept.
        feed(&mut stopped, 22, 40, push);
        assert_eq!(stopped.odometer.front().map(|&(t, _)| t), Some(30.0));
    }

    #[test]
    fn a_refused_run_is_a_rest_once_the_odometer_stood_a_whole_window() {
        let mut check = after_a_rest();
        // The INS says 40 mm/s after a ramp (d² = 268, see the first
        // test): refused, though the odometer, read each second from 1 s,
        // stays at 5.000 m.
        let v = V3::new(0.040, 0.0, 0.0);
        let p_v = p(0.0014);
        let moving = at(&v, &p_v);
        for k in 1..=9 {
            check.odometer(&CONFIG, f64::from(k), 5.0);
        }
        assert_eq!(check.judge(&CONFIG, 2.0, moving), Some(Refusal::Velocity));
        // At 10 s the readings cover [1, 10] s, not the whole window of
        // 10 s: still refused.
        check.odometer(&CONFIG, 10.0, 5.0);
        assert_eq!(check.judge(&CONFIG, 10.0, moving), Some(Refusal::Velocity));
        // At 11 s they cover [1, 11]: no advance over a whole window, and
        // the detector calls rest too: standing from here on.
        check.odometer(&CONFIG, 11.0, 5.0);
        assert_eq!(check.judge(&CONFIG, 11.0, moving), None);
        check.moving();
        assert_eq!(check.booked_mps, V3::zeros());
        assert!(!check.booked_is_motion);
    }
}
