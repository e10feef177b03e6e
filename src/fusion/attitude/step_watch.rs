//! The `attitude` engine's step watch (issue 54): a new zero of the
//! inclinometer (a power cycle, a knock) is a step between two readings,
//! which a TBM's pitch and roll, trends of thousandths of a degree a
//! second, do not make.
//!
//! At each reading the last 2W raw readings (the error model's
//! correction changes at a retraining, a step does not) are split in two
//! halves of
//! [`HALF`]; a line is fitted to each, and both are evaluated at the time
//! between them. Their difference δ is the step; its variance is the sum
//! of the two lines' variances there, s²(1/W + (t − t̄)²/Sₜₜ), with s² the
//! larger half's residual variance and at least the inclinometer's noise
//! variance r (coloured noise makes the residuals understate it). Where
//! the step passes [`STEP_SIGMAS`] σ, the residuals' lag-1
//! autocorrelation ρ, measured in the window, inflates that variance by
//! (1 + ρ)/(1 − ρ): readings that follow each other average less than
//! independent ones (a first build called 19 % of a drive with coloured
//! noise, τ 6.6 s on a 0.87 s inclinometer, `unverified`: seed 50). A step
//! still beyond [`STEP_SIGMAS`] σ on pitch or roll is a new zero until a laser
//! sample checks the estimate: the engine's estimates are `degraded`
//! (`unverified`) and their σ grows by the step (as a bound: the estimate
//! is off by anything from nothing, if the machine did move, to the whole
//! step, the error lying uniformly between: |δ|/√3). The readings are
//! then forgotten, so one step is called once. The next [`HALF`]
//! readings show whether it persisted: a line through them, taken back
//! to the step's time, nearer the level before than the step on every
//! axis that called it is no new zero (an excursion of coloured noise, a
//! knock that settled), and the estimates are vouched for again. A window
//! spanning more than [`MAX_WINDOW_S`] is not tested (a slow
//! inclinometer's readings are minutes apart, over which the machine's
//! own motion is no line).
//!
//! Every step tested, called or not, is also kept (the most significant
//! of each sign since the laser last checked) as evidence for the laser
//! dispute ([`StepWatch::explains`]) and, where chance among the places
//! it was the best of does not explain it, in the estimate's σ
//! ([`StepWatch::suspected_rad`]): the estimate may have followed a new
//! zero too small to call.
//!
//! With honest Gaussian noise a step of 6σ is called by chance once in
//! 500 million tests; the rate on the envelope's drives is in
//! docs/engines/attitude.md.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// Readings in each half of the window.
pub const HALF: usize = 16;
/// A step beyond this many σ is a new zero.
pub const STEP_SIGMAS: f64 = 6.0;
/// The chance that noise alone makes the most significant step seen
/// since the laser's last check suspect ([`StepWatch::suspected_rad`]).
pub const SUSPECT_ALPHA: f64 = 0.05;
/// The longest a window may span, s: a TBM's pitch and roll follow a
/// line over two minutes, not over ten (steering, rocking), so a slow
/// inclinometer's readings (one every 4 s or slower) are not tested.
pub const MAX_WINDOW_S: f64 = 120.0;

/// The largest residual autocorrelation the step's σ is inflated for
/// ((1 + ρ)/(1 − ρ) ≤ 39).
const MAX_AUTOCORRELATION: f64 = 0.95;

/// The sums a least-squares line through readings (t, y) needs, in one
/// pass (the watch runs at every inclinometer reading).
#[derive(Debug, Clone, Copy, Default)]
struct LineSums {
    n: f64,
    t: f64,
    tt: f64,
    y: f64,
    yy: f64,
    ty: f64,
}

impl LineSums {
    fn add(&mut self, t: f64, y: f64) {
        self.n += 1.0;
        self.t += t;
        self.tt += t * t;
        self.y += y;
        self.yy += y * y;
        self.ty += t * y;
    }

    /// The means t̄ and ȳ, Sₜₜ and Sₜᵧ, and the slope Sₜᵧ/Sₜₜ (0 without
    /// a spread in t).
    fn centred(&self) -> (f64, f64, f64, f64, f64) {
        let n = self.n;
        let (t_mean, y_mean) = (self.t / n, self.y / n);
        let stt = self.tt - n * t_mean * t_mean;
        let sty = self.ty - n * t_mean * y_mean;
        let slope = if stt > 0.0 { sty / stt } else { 0.0 };
        (t_mean, y_mean, stt, sty, slope)
    }

    /// The line's value at t = 0 and its slope.
    fn line(&self) -> (f64, f64) {
        let (t_mean, y_mean, _, _, slope) = self.centred();
        (y_mean - slope * t_mean, slope)
    }

    /// The line's value at t = 0, that value's variance per unit residual
    /// variance (its leverage, 1/n + t̄²/Sₜₜ), and the residual variance.
    fn at_zero(&self) -> (f64, f64, f64) {
        let n = self.n;
        let (t_mean, y_mean, stt, sty, slope) = self.centred();
        let syy = self.yy - n * y_mean * y_mean;
        let residual = (syy - slope * sty).max(0.0) / (n - 2.0).max(1.0);
        let leverage = 1.0 / n
            + if stt > 0.0 {
                t_mean * t_mean / stt
            } else {
                0.0
            };
        (y_mean - slope * t_mean, leverage, residual)
    }
}

/// What the watch remembers.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct StepWatch {
    /// The newest readings: t, raw pitch and roll (rad), oldest first.
    recent: VecDeque<(f64, f64, f64)>,
    /// The largest step called since the laser last checked the
    /// estimate, pitch and roll, rad (0: none).
    unverified_rad: [f64; 2],
    /// Since the laser last checked the estimate: the most significant
    /// step down and up seen on pitch and roll, each (step, its σ), rad
    /// ((0, 0): none), called or not.
    largest_since_check: [[(f64, f64); 2]; 2],
    /// How many independent places a step could have been seen at since
    /// the laser last checked: a recorded innovation counts one, a tested
    /// window 1/2W (consecutive windows share all but one reading).
    places_since_check: f64,
    /// The newest step called, until the readings after it show whether
    /// it persisted.
    called: Option<CalledStep>,
    /// Steps called so far.
    pub steps: u64,
}

/// A called step awaiting the readings after it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct CalledStep {
    /// Between the two halves it was seen across, s.
    split_t: f64,
    /// The older half's line there, pitch and roll (rad).
    before_rad: [f64; 2],
    /// The step on each axis that called it (0 on one that did not), rad.
    step_rad: [f64; 2],
    /// What awaited the laser before it, rad.
    unverified_before_rad: [f64; 2],
}

impl StepWatch {
    /// A reading at `t` of raw `pitch` and `roll` (rad), with the
    /// inclinometer's noise variances `r` (rad², pitch and roll). Whether
    /// a window was tested.
    pub fn observe(&mut self, t: f64, pitch: f64, roll: f64, r: [f64; 2]) -> bool {
        if self.recent.len() == 2 * HALF {
            self.recent.pop_front();
        }
        self.recent.push_back((t, pitch, roll));
        if self.recent.len() == HALF
            && let Some(called) = self.called.take()
        {
            self.judge_persistence(called);
        }
        if self.recent.len() < 2 * HALF {
            return false;
        }
        let span_s = t - self.recent[0].0;
        if span_s > MAX_WINDOW_S {
            return false;
        }
        let split_t = 0.5 * (self.recent[HALF - 1].0 + self.recent[HALF].0);
        // Times from the split, values from the newest reading's: the sums
        // stay small, so their differences keep their digits.
        let (_, pitch_ref, roll_ref) = self.recent[2 * HALF - 1];
        let refs = [pitch_ref, roll_ref];
        let mut halves = [[LineSums::default(); 2]; 2];
        for (k, &(t, p, q)) in self.recent.iter().enumerate() {
            let half = &mut halves[usize::from(k >= HALF)];
            half[0].add(t - split_t, p - pitch_ref);
            half[1].add(t - split_t, q - roll_ref);
        }
        let mut stepped = false;
        let mut steps = [0.0; 2];
        let mut called = CalledStep {
            split_t,
            before_rad: [0.0; 2],
            step_rad: [0.0; 2],
            unverified_before_rad: self.unverified_rad,
        };
        for (axis, step) in steps.iter_mut().enumerate() {
            let (y_old, lev_old, s_old) = halves[0][axis].at_zero();
            let (y_new, lev_new, s_new) = halves[1][axis].at_zero();
            let residual = s_old.max(s_new).max(r[axis]);
            let mut sigma = (residual * (lev_old + lev_new)).sqrt();
            *step = y_new - y_old;
            if step.abs() > STEP_SIGMAS * sigma {
                // A candidate: readings that follow each other (coloured
                // noise) average less than independent ones would.
                let rho = self.residual_autocorrelation(axis, split_t, refs[axis], &halves);
                sigma *= ((1.0 + rho) / (1.0 - rho)).sqrt();
            }
            if step.abs() > STEP_SIGMAS * sigma {
                stepped = true;
                called.step_rad[axis] = *step;
            }
            called.before_rad[axis] = y_old + refs[axis];
            self.keep_if_largest(axis, *step, sigma);
        }
        self.places_since_check += 1.0 / (2 * HALF) as f64;
        if stepped {
            self.steps += 1;
            for (held, step) in self.unverified_rad.iter_mut().zip(steps) {
                *held = held.max(step.abs());
            }
            self.recent.clear();
            self.called = Some(called);
        }
        true
    }

    /// With [`HALF`] readings after a called step: a line through them,
    /// taken back to the step's time, nearer the level before the step
    /// than the step on every axis that called it means the step did not
    /// persist (an excursion of coloured noise, a knock that settled): the
    /// estimate is vouched for again. One that persisted waits for the
    /// laser.
    fn judge_persistence(&mut self, called: CalledStep) {
        let span_s = self.recent.back().map_or(f64::INFINITY, |n| n.0) - called.split_t;
        if span_s > MAX_WINDOW_S {
            return;
        }
        let mut after = [LineSums::default(); 2];
        for &(t, p, q) in &self.recent {
            after[0].add(t - called.split_t, p - called.before_rad[0]);
            after[1].add(t - called.split_t, q - called.before_rad[1]);
        }
        let persisted = (0..2).any(|axis| {
            let step = called.step_rad[axis];
            let (moved, _) = after[axis].line();
            step != 0.0 && (moved - step).abs() <= moved.abs()
        });
        if !persisted {
            self.unverified_rad = called.unverified_before_rad;
        }
    }

    /// The lag-1 autocorrelation of the two lines' residuals on `axis`
    /// (0 pitch, 1 roll), pooled over the halves, between 0 and
    /// [`MAX_AUTOCORRELATION`]: with AR(1) noise of correlation ρ a mean
    /// of n readings has (1 + ρ)/(1 − ρ) times the variance of n
    /// independent ones, the inflation the caller applies.
    fn residual_autocorrelation(
        &self,
        axis: usize,
        split_t: f64,
        reference: f64,
        halves: &[[LineSums; 2]; 2],
    ) -> f64 {
        let (mut lagged, mut squares) = (0.0, 0.0);
        for (half, sums) in halves.iter().enumerate() {
            let (at_zero, slope) = sums[axis].line();
            let mut previous: Option<f64> = None;
            for &(t, p, q) in self.recent.iter().skip(half * HALF).take(HALF) {
                let y = if axis == 0 { p } else { q } - reference;
                let e = y - (at_zero + slope * (t - split_t));
                if let Some(before) = previous {
                    lagged += e * before;
                }
                squares += e * e;
                previous = Some(e);
            }
        }
        if squares > 0.0 {
            (lagged / squares).clamp(0.0, MAX_AUTOCORRELATION)
        } else {
            0.0
        }
    }

    /// Keeps `step` (σ `sigma`) on `axis` if the most significant of its
    /// sign since the laser last checked.
    fn keep_if_largest(&mut self, axis: usize, step: f64, sigma: f64) {
        let largest = &mut self.largest_since_check[axis][usize::from(step > 0.0)];
        if sigma > 0.0 && step.abs() * largest.1 >= largest.0.abs() * sigma {
            *largest = (step, sigma);
        }
    }

    /// Where no window is tested (readings too far apart, or too few
    /// since the last step): a reading's innovation and its σ, pitch and
    /// roll, rad, as the step since the reading before, for
    /// [`Self::explains`].
    pub fn record(&mut self, innovations: [(f64, f64); 2]) {
        for (axis, (innovation, sigma)) in innovations.into_iter().enumerate() {
            self.keep_if_largest(axis, innovation, sigma);
        }
        self.places_since_check += 1.0;
    }

    /// The variance, rad², a step not yet checked adds to pitch and roll:
    /// a called one's, or one too small to be called that is more
    /// significant than chance explains ([`Self::suspected_rad`]), each
    /// as a bound (|δ|/√3).
    pub fn unverified_variance(&self) -> [f64; 2] {
        let suspected = self.suspected_rad();
        [0, 1].map(|axis| {
            let step = self.unverified_rad[axis].max(suspected[axis]);
            step * step / 3.0
        })
    }

    /// Per axis, the most significant step seen since the laser last
    /// checked (called or not), rad, if it is more significant than the
    /// best of the places it was chosen from would be by chance; else 0.
    /// With N independent places and two signs, the largest of 2N
    /// standard normal |z| passes √(2 ln(2N/α)) with probability about α
    /// ([`SUSPECT_ALPHA`]). Such a step is not called (the estimate stays
    /// vouched for), but the estimate may have followed a new zero that
    /// small: its σ carries the step until the laser checks.
    pub fn suspected_rad(&self) -> [f64; 2] {
        let places = self.places_since_check.max(1.0);
        let threshold = (2.0 * (2.0 * places / SUSPECT_ALPHA).ln()).sqrt();
        self.largest_since_check.map(|signs| {
            signs
                .iter()
                .filter(|(step, sigma)| *sigma > 0.0 && step.abs() > threshold * sigma)
                .map(|(step, _)| step.abs())
                .fold(0.0, f64::max)
        })
    }

    /// Whether a step awaits the laser's check.
    pub fn unverified(&self) -> bool {
        self.unverified_rad.iter().any(|&s| s > 0.0)
    }

    /// A laser sample checked the estimate.
    pub fn laser_checked(&mut self) {
        self.unverified_rad = [0.0; 2];
        self.largest_since_check = [[(0.0, 0.0); 2]; 2];
        self.places_since_check = 0.0;
        self.called = None;
    }

    /// Whether the inclinometer's readings since the laser last checked
    /// explain a laser sample `offset_rad` (laser − estimate, pitch and
    /// roll, rad) better than no step does. Take on each axis the most
    /// significant step seen of the opposite sign (the estimate followed a
    /// new zero), δ with σ; a step of −J there is likelier than none by
    /// the log-likelihood ratio Σ (δ² − (δ + J)²) / 2σ² over the two axes.
    /// With no place preferred a priori, a step at one of N places wins
    /// when that ratio exceeds ln N (the best of N candidates is a
    /// selection: the threshold pays for it). Too small or too noisy to be
    /// called on its own, such a step is still the evidence that tells a
    /// new inclinometer zero from a laser that jumped.
    pub fn explains(&self, offset_rad: [f64; 2]) -> bool {
        let mut log_ratio = 0.0;
        let mut seen = false;
        for (axis, offset) in offset_rad.into_iter().enumerate() {
            let (step, sigma) = self.largest_since_check[axis][usize::from(offset < 0.0)];
            if sigma <= 0.0 {
                continue;
            }
            seen = true;
            log_ratio += (step * step - (step + offset).powi(2)) / (2.0 * sigma * sigma);
        }
        seen && log_ratio > self.places_since_check.max(1.0).ln()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_through_exact_points_has_no_residual_and_its_hand_computed_leverage() {
        // y = 2 + 0.5 t at t = 0, 1, 2, 3, evaluated at t = 3.5 (times
        // from it): t̄ = 1.5, Sₜₜ = 5; 3.75, leverage 1/4 + 4/5 = 1.05.
        let mut sums = LineSums::default();
        for k in 0..4 {
            let t = f64::from(k);
            sums.add(t - 3.5, 2.0 + 0.5 * t);
        }
        let (y, leverage, residual) = sums.at_zero();
        assert!((y - 3.75).abs() < 1e-12);
        assert!((leverage - 1.05).abs() < 1e-12);
        assert!(residual < 1e-24);
    }

    /// Noise of ±0.01° (alternating), a trend of 0.001°/s; a step of
    /// 0.05° in pitch at reading 40.
    fn reading(k: usize) -> (f64, f64, f64) {
        let noise = if k.is_multiple_of(2) { 0.01 } else { -0.01 };
        let step = if k >= 40 { 0.05 } else { 0.0 };
        let t = k as f64;
        (
            t,
            (0.001 * t + noise + step).to_radians(),
            (0.2 + noise).to_radians(),
        )
    }

    #[test]
    fn a_step_is_called_once_and_a_trend_is_not() {
        let r = [0.01f64.to_radians().powi(2); 2];
        let mut watch = StepWatch::default();
        for k in 0..40 {
            let (t, p, q) = reading(k);
            watch.observe(t, p, q, r);
        }
        assert_eq!(watch.steps, 0, "a trend with noise is no step");
        for k in 40..120 {
            let (t, p, q) = reading(k);
            watch.observe(t, p, q, r);
        }
        assert_eq!(watch.steps, 1);
        assert!(watch.unverified());
        // The step found is the step made, within the noise.
        let [pitch, roll] = watch
            .unverified_variance()
            .map(|v| (3.0 * v).sqrt().to_degrees());
        assert!((pitch - 0.05).abs() < 0.01, "{pitch}");
        assert!(roll < 0.01, "{roll}");
        watch.laser_checked();
        assert!(!watch.unverified());
    }

    #[test]
    fn a_seen_step_explains_a_laser_jump_of_its_size_and_opposite_sign_only() {
        let d = f64::to_radians;
        let mut watch = StepWatch::default();
        // Up 0.05° on both axes, σ 0.02°: one place, threshold ln 1 = 0.
        watch.record([(d(0.05), d(0.02)); 2]);
        // A laser 0.05° below the estimate: per axis
        // (0.05² − 0²) / (2 · 0.02²) = 3.125, 6.25 in all.
        assert!(watch.explains([d(-0.05); 2]));
        // Above it: no step down was seen.
        assert!(!watch.explains([d(0.05); 2]));
        // 0.2° below: (0.05² − 0.15²) / (2 · 0.02²) = −25 per axis.
        assert!(!watch.explains([d(-0.2); 2]));
        // The same step as the best of 600 places: ln 600 ≈ 6.4 > 6.25.
        for _ in 0..599 {
            watch.record([(0.0, d(0.02)); 2]);
        }
        assert!(!watch.explains([d(-0.05); 2]));
        watch.laser_checked();
        watch.record([(d(0.05), d(0.02)); 2]);
        assert!(watch.explains([d(-0.05); 2]));
        watch.laser_checked();
        assert!(!watch.explains([d(-0.05); 2]), "nothing seen since");
    }

    #[test]
    fn a_step_too_small_to_call_is_carried_in_the_sigma_if_chance_does_not_explain_it() {
        let d = f64::to_radians;
        let mut watch = StepWatch::default();
        // One place: the threshold is √(2 ln(2/0.05)) = √(2 ln 40) ≈ 2.716.
        // A step of 0.05° with σ 0.02° (2.5σ) is within chance.
        watch.record([(d(0.05), d(0.02)), (0.0, d(0.02))]);
        assert_eq!(watch.suspected_rad(), [0.0; 2]);
        assert_eq!(watch.unverified_variance(), [0.0; 2]);
        // σ 0.016° (3.125σ): suspect on pitch; its variance is δ²/3.
        watch.laser_checked();
        watch.record([(d(-0.05), d(0.016)), (0.0, d(0.016))]);
        assert_eq!(watch.suspected_rad(), [d(0.05), 0.0]);
        let [pitch, roll] = watch.unverified_variance();
        assert!((pitch - d(0.05).powi(2) / 3.0).abs() < 1e-18);
        assert_eq!(roll, 0.0);
        assert!(!watch.unverified(), "suspect is not called");
        // The best of 100 places: √(2 ln 4000) ≈ 4.07 > 3.125.
        for _ in 0..99 {
            watch.record([(0.0, d(0.016)); 2]);
        }
        assert_eq!(watch.suspected_rad(), [0.0; 2]);
    }

    #[test]
    fn a_step_that_does_not_persist_is_vouched_for_again() {
        let r = [0.01f64.to_radians().powi(2); 2];
        let mut watch = StepWatch::default();
        // The readings of `reading`, but the pitch 0.05° up only for
        // readings 40 to 49 (an excursion), then back.
        let mut called_at = None;
        for k in 0..100 {
            let (t, p, q) = reading(k);
            let p = if k >= 50 { p - 0.05f64.to_radians() } else { p };
            watch.observe(t, p, q, r);
            if watch.unverified() && called_at.is_none() {
                called_at = Some(k);
            }
        }
        called_at.expect("the excursion is called a step");
        assert!(!watch.unverified(), "the level came back: no new zero");
        // A step that persists (the first test's) still waits.
        let mut watch = StepWatch::default();
        for k in 0..100 {
            let (t, p, q) = reading(k);
            watch.observe(t, p, q, r);
        }
        assert!(watch.unverified());
    }
}
