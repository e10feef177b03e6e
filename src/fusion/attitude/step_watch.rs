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
//! Every step tested, called or not, is also kept (the places of each
//! axis's most significant step of each sign since the laser last
//! checked, with what the other axis did there, and of the jointly most
//! significant) as evidence for the laser dispute
//! ([`StepWatch::explains`]: a new zero is one event, both axes' evidence
//! taken at one place) and, where chance among the places it was the best
//! of does not explain it, in the estimate's σ
//! ([`StepWatch::suspected_rad`]): the estimate may have followed a new
//! zero too small to call. A second, longer test records too (never
//! calls): the line through up to [`LONG_OLD`] older readings carried to
//! the newest [`HALF`] (`extrapolated_test`), about half the short
//! lines' σ.
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
/// The most readings before the newest [`HALF`] that the extrapolated
/// test fits its line to ([`StepWatch::observe`]); at least `2 × HALF`.
pub const LONG_OLD: usize = 64;
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

    /// The variance of the values about their mean (n − 1), 0 for one.
    fn spread_about_mean(&self) -> f64 {
        if self.n < 2.0 {
            return 0.0;
        }
        let mean = self.y / self.n;
        (self.yy - self.n * mean * mean).max(0.0) / (self.n - 1.0)
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
    /// Since the laser last checked the estimate, the places a step was
    /// seen at (called or not), for the suspicion and [`Self::explains`]:
    /// at `2 × axis + sign` (sign 0 down, 1 up) the place of that axis's
    /// most significant step of that sign (with what the other axis did
    /// there), at `4 + 2 × pitch sign + roll sign` the place jointly most
    /// significant (Σ (δ/σ)² over the axes).
    places: [Place; 8],
    /// How many independent places a step could have been seen at since
    /// the laser last checked: a recorded innovation counts one, a tested
    /// window 1/2W (consecutive windows share all but one reading), an
    /// extrapolated test 1/W. It sets the bar of the suspicion and of the
    /// laser dispute's likelihood ratio (ln N) alike.
    places_since_check: f64,
    /// The newest step called, until the readings after it show whether
    /// it persisted.
    called: Option<CalledStep>,
    /// Steps called so far.
    pub steps: u64,
}

/// One place a step was tested at: the step on pitch and roll and their
/// σ, rad (σ 0: no place), where it lies (s) and how far from there
/// another test could see the same step (the readings after the split
/// its test averaged, s).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
struct Place {
    step: [f64; 2],
    sigma: [f64; 2],
    t: f64,
    reach_s: f64,
}

impl Place {
    /// `axis`'s share of the log-likelihood ratio of a new zero here that
    /// the estimate followed (a step of −J) against none, for a laser
    /// sample off by `offset` (J, laser − estimate): (δ² − (δ + J)²) / 2σ².
    fn axis_log_ratio(&self, axis: usize, offset: f64) -> f64 {
        let (step, sigma) = (self.step[axis], self.sigma[axis]);
        (step * step - (step + offset).powi(2)) / (2.0 * sigma * sigma)
    }

    /// Over both axes.
    fn log_ratio(&self, offset: [f64; 2]) -> f64 {
        (0..2)
            .map(|axis| self.axis_log_ratio(axis, offset[axis]))
            .sum()
    }

    /// Whether `other` may have seen the same step.
    fn coincides(&self, other: &Place) -> bool {
        (self.t - other.t).abs() <= self.reach_s.max(other.reach_s)
    }

    /// |δ|/σ on `axis`.
    fn z(&self, axis: usize) -> f64 {
        (self.step[axis] / self.sigma[axis]).abs()
    }

    /// Σ (δ/σ)² over the axes.
    fn significance(&self) -> f64 {
        (0..2).map(|axis| self.z(axis).powi(2)).sum()
    }

    fn is_seen(&self) -> bool {
        self.sigma.iter().all(|&s| s > 0.0)
    }
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
        while self.recent.len() >= LONG_OLD + HALF {
            self.recent.pop_front();
        }
        self.recent.push_back((t, pitch, roll));
        if self.recent.len() == HALF
            && let Some(called) = self.called.take()
        {
            self.judge_persistence(called);
        }
        let len = self.recent.len();
        if len < 2 * HALF {
            return false;
        }
        let base = len - 2 * HALF;
        let span_s = t - self.recent[base].0;
        if span_s > MAX_WINDOW_S {
            return false;
        }
        let split_t = 0.5 * (self.recent[base + HALF - 1].0 + self.recent[base + HALF].0);
        // Times from the split, values from the newest reading's: the sums
        // stay small, so their differences keep their digits.
        let (_, pitch_ref, roll_ref) = self.recent[len - 1];
        let refs = [pitch_ref, roll_ref];
        let mut halves = [[LineSums::default(); 2]; 2];
        for (k, &(t, p, q)) in self.recent.iter().skip(base).enumerate() {
            let half = &mut halves[usize::from(k >= HALF)];
            half[0].add(t - split_t, p - pitch_ref);
            half[1].add(t - split_t, q - roll_ref);
        }
        let mut stepped = false;
        let mut steps = [0.0; 2];
        let mut sigmas = [0.0; 2];
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
            sigmas[axis] = sigma;
        }
        self.keep_place(Place {
            step: steps,
            sigma: sigmas,
            t: split_t,
            reach_s: t - split_t,
        });
        self.places_since_check += 1.0 / (2 * HALF) as f64;
        if stepped {
            self.steps += 1;
            for (held, step) in self.unverified_rad.iter_mut().zip(steps) {
                *held = held.max(step.abs());
            }
            self.recent.clear();
            self.called = Some(called);
        } else {
            self.extrapolated_test(r, refs);
        }
        true
    }

    /// The extrapolated test, for the record only (never a call): the
    /// line through the readings before the newest [`HALF`] (at least
    /// `2 × HALF`, at most [`LONG_OLD`], the whole within
    /// [`MAX_WINDOW_S`]), carried to the newest readings' mean time, and
    /// their mean there. Their difference is a step at the newest
    /// readings' start; its variance s²(1/n_new + 1/n_old + (t̄_new −
    /// t̄_old)²/Sₜₜ), s² the larger of the old line's residual variance,
    /// the newest readings' spread about their mean (which a trend there
    /// only widens) and r, inflated by the old line's residual lag-1
    /// autocorrelation ρ by (1 + ρ)/(1 − ρ). The longer line sees a step the two short ones
    /// miss (about half their σ at 64 readings); the TBM's trend over the
    /// newest readings is the old line's, which the machine keeps over a
    /// minute or two. Each test is a place for 1/[`HALF`] (the newest
    /// readings' tests overlap).
    fn extrapolated_test(&mut self, r: [f64; 2], refs: [f64; 2]) {
        let len = self.recent.len();
        let Some(newest_t) = self.recent.back().map(|n| n.0) else {
            return;
        };
        let first_old = (0..len.saturating_sub(HALF))
            .find(|&k| newest_t - self.recent[k].0 <= MAX_WINDOW_S)
            .unwrap_or(len);
        let n_old = len.saturating_sub(HALF).saturating_sub(first_old);
        if n_old < 2 * HALF {
            return;
        }
        let new_t_mean = self
            .recent
            .iter()
            .skip(len - HALF)
            .map(|n| n.0)
            .sum::<f64>()
            / HALF as f64;
        let mut old = [LineSums::default(); 2];
        let mut new = [LineSums::default(); 2];
        for (k, &(t, p, q)) in self.recent.iter().enumerate().skip(first_old) {
            let side = if k >= len - HALF { &mut new } else { &mut old };
            side[0].add(t - new_t_mean, p - refs[0]);
            side[1].add(t - new_t_mean, q - refs[1]);
        }
        let newest_from_t = self.recent[len - HALF].0;
        let mut place = Place {
            t: newest_from_t,
            reach_s: newest_t - newest_from_t,
            ..Place::default()
        };
        for axis in 0..2 {
            let (old_there, leverage, s_old) = old[axis].at_zero();
            let (_, new_mean, _, _, _) = new[axis].centred();
            let s_new = new[axis].spread_about_mean();
            let rho = self.old_line_autocorrelation(axis, first_old, new_t_mean, refs[axis], &old);
            let variance =
                s_old.max(s_new).max(r[axis]) * (leverage + 1.0 / HALF as f64) * (1.0 + rho)
                    / (1.0 - rho);
            place.step[axis] = new_mean - old_there;
            place.sigma[axis] = variance.sqrt();
        }
        self.keep_place(place);
        self.places_since_check += 1.0 / HALF as f64;
    }

    /// The lag-1 autocorrelation of the old line's residuals on `axis`,
    /// between 0 and [`MAX_AUTOCORRELATION`] (times from `t0`, values
    /// from `reference`, as the sums were built).
    fn old_line_autocorrelation(
        &self,
        axis: usize,
        first_old: usize,
        t0: f64,
        reference: f64,
        old: &[LineSums; 2],
    ) -> f64 {
        let end = self.recent.len() - HALF;
        let (lagged, squares) =
            self.residual_products(first_old..end, axis, t0, reference, old[axis].line());
        clamped_autocorrelation(lagged, squares)
    }

    /// Over the readings in `range`: the sums of their residuals' lag-1
    /// products and of their squares on `axis` about `line` (its value
    /// at `t0` and its slope; values from `reference`).
    fn residual_products(
        &self,
        range: std::ops::Range<usize>,
        axis: usize,
        t0: f64,
        reference: f64,
        (at_zero, slope): (f64, f64),
    ) -> (f64, f64) {
        let (mut lagged, mut squares) = (0.0, 0.0);
        let mut previous: Option<f64> = None;
        for &(t, p, q) in self.recent.range(range) {
            let y = if axis == 0 { p } else { q } - reference;
            let e = y - (at_zero + slope * (t - t0));
            if let Some(before) = previous {
                lagged += e * before;
            }
            squares += e * e;
            previous = Some(e);
        }
        (lagged, squares)
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
            // Nor is it suspect, nor evidence: the places that saw it (the
            // tests whose reach covers its time) go with it.
            let excursion = Place {
                t: called.split_t,
                reach_s: span_s,
                ..Place::default()
            };
            for place in &mut self.places {
                if place.is_seen() && place.coincides(&excursion) {
                    *place = Place::default();
                }
            }
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
        let base = self.recent.len() - 2 * HALF;
        let (mut lagged, mut squares) = (0.0, 0.0);
        for (half, sums) in halves.iter().enumerate() {
            let from = base + half * HALF;
            let (l, q) = self.residual_products(
                from..from + HALF,
                axis,
                split_t,
                reference,
                sums[axis].line(),
            );
            lagged += l;
            squares += q;
        }
        clamped_autocorrelation(lagged, squares)
    }

    /// Keeps `place` where it is the most significant of its kind since
    /// the laser last checked (see `places`).
    fn keep_place(&mut self, place: Place) {
        if !place.is_seen() {
            return;
        }
        let sign = |axis: usize| usize::from(place.step[axis] > 0.0);
        for axis in 0..2 {
            let slot = &mut self.places[2 * axis + sign(axis)];
            if !slot.is_seen() || place.z(axis) >= slot.z(axis) {
                *slot = place;
            }
        }
        let slot = &mut self.places[4 + 2 * sign(0) + sign(1)];
        if !slot.is_seen() || place.significance() >= slot.significance() {
            *slot = place;
        }
    }

    /// Where no window is tested (readings too far apart, or too few
    /// since the last step): a reading's innovation and its σ, pitch and
    /// roll, rad, as the step since the reading before, for
    /// [`Self::explains`].
    pub fn record(&mut self, t: f64, innovations: [(f64, f64); 2]) {
        self.keep_place(Place {
            step: innovations.map(|(innovation, _)| innovation),
            sigma: innovations.map(|(_, sigma)| sigma),
            t,
            reach_s: 0.0,
        });
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
    /// ([`SUSPECT_ALPHA`]) — with white noise: below [`STEP_SIGMAS`] the
    /// short test's σ is not inflated for coloured noise, which passes
    /// more often (only the σ widens; inflating it cost more fault runs
    /// than it saved, docs/engines/attitude.md). Such a step is not called (the estimate stays
    /// vouched for), but the estimate may have followed a new zero that
    /// small: its σ carries the step until the laser checks.
    pub fn suspected_rad(&self) -> [f64; 2] {
        let places = self.places_since_check.max(1.0);
        let threshold = (2.0 * (2.0 * places / SUSPECT_ALPHA).ln()).sqrt();
        [0, 1].map(|axis| {
            self.places[2 * axis..2 * axis + 2]
                .iter()
                .filter(|p| p.is_seen() && p.z(axis) > threshold)
                .map(|p| p.step[axis].abs())
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
        self.places = [Place::default(); 8];
        self.places_since_check = 0.0;
        self.called = None;
    }

    /// Whether the inclinometer's readings since the laser last checked
    /// explain a laser sample `offset_rad` (laser − estimate, pitch and
    /// roll, rad) better than no step does. A new zero is one event: at
    /// one place a step (δ with σ per axis) that the estimate followed
    /// makes a step of −J there likelier than none by the log-likelihood
    /// ratio Σ (δ² − (δ + J)²) / 2σ² over the two axes at that place. The
    /// best of the places kept (`places`: each axis's most
    /// significant step of either sign with what the other axis did there,
    /// and the jointly most significant of each pair of signs) is taken,
    /// and the two axes' own most significant steps together where they
    /// lie within a test's reach of each other (overlapping windows see
    /// one step at neighbouring places).
    /// With no place preferred a priori, a step at one of N places wins
    /// when that ratio exceeds ln N (the best of N candidates is a
    /// selection: the threshold pays for it). Too small or too noisy to be
    /// called on its own, such a step is still the evidence that tells a
    /// new inclinometer zero from a laser that jumped; steps on the two
    /// axes at different places (a sway on one, noise on the other) are
    /// not one new zero.
    pub fn explains(&self, offset_rad: [f64; 2]) -> bool {
        let best = self
            .places
            .iter()
            .filter(|place| place.is_seen())
            .map(|place| place.log_ratio(offset_rad))
            .fold(f64::NEG_INFINITY, f64::max);
        // Each axis's most significant step of the sign that follows the
        // offset (a laser above the estimate: the zero stepped down).
        let [pitch, roll] =
            [0, 1].map(|axis| self.places[2 * axis + usize::from(offset_rad[axis] < 0.0)]);
        let together = if pitch.is_seen() && roll.is_seen() && pitch.coincides(&roll) {
            pitch.axis_log_ratio(0, offset_rad[0]) + roll.axis_log_ratio(1, offset_rad[1])
        } else {
            f64::NEG_INFINITY
        };
        best.max(together) > self.places_since_check.max(1.0).ln()
    }
}

/// Σ eₖeₖ₋₁ / Σ eₖ², between 0 and [`MAX_AUTOCORRELATION`] (0 without
/// residuals).
fn clamped_autocorrelation(lagged: f64, squares: f64) -> f64 {
    if squares > 0.0 {
        (lagged / squares).clamp(0.0, MAX_AUTOCORRELATION)
    } else {
        0.0
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
        watch.record(0.0, [(d(0.05), d(0.02)); 2]);
        // A laser 0.05° below the estimate: per axis
        // (0.05² − 0²) / (2 · 0.02²) = 3.125, 6.25 in all.
        assert!(watch.explains([d(-0.05); 2]));
        // Above it: no step down was seen.
        assert!(!watch.explains([d(0.05); 2]));
        // 0.2° below: (0.05² − 0.15²) / (2 · 0.02²) = −25 per axis.
        assert!(!watch.explains([d(-0.2); 2]));
        // The same step as the best of 600 places: ln 600 ≈ 6.4 > 6.25.
        for _ in 0..599 {
            watch.record(0.0, [(0.0, d(0.02)); 2]);
        }
        assert!(!watch.explains([d(-0.05); 2]));
        watch.laser_checked();
        watch.record(0.0, [(d(0.05), d(0.02)); 2]);
        assert!(watch.explains([d(-0.05); 2]));
        watch.laser_checked();
        assert!(!watch.explains([d(-0.05); 2]), "nothing seen since");
    }

    #[test]
    fn steps_on_the_two_axes_explain_a_laser_jump_together_only_if_one_event_could_make_them() {
        let d = f64::to_radians;
        // Pitch stepped up 0.05° at one reading, roll 100 s later (σ
        // 0.02°): two places, threshold ln 2 ≈ 0.69. For a laser 0.05°
        // below the estimate on both axes, each place explains its own
        // axis ((0.05² − 0²) / (2 · 0.02²) = 3.125) and counts against
        // the other ((0² − 0.05²) / (2 · 0.02²) = −3.125): 0 in all.
        let mut apart = StepWatch::default();
        apart.record(0.0, [(d(0.05), d(0.02)), (0.0, d(0.02))]);
        apart.record(100.0, [(0.0, d(0.02)), (d(0.05), d(0.02))]);
        assert!(!apart.explains([d(-0.05); 2]));
        // The pitch step alone (a laser off on pitch only) is explained.
        assert!(apart.explains([d(-0.05), 0.0]));
        // At one reading: 6.25.
        let mut together = StepWatch::default();
        together.record(0.0, [(0.0, d(0.02)); 2]);
        together.record(100.0, [(d(0.05), d(0.02)); 2]);
        assert!(together.explains([d(-0.05); 2]));
        // Windows reach over the readings after their split (30 s here):
        // the same two steps seen 20 s apart are one event (6.25 > ln 2),
        // 40 s apart two.
        let windows = |apart_s: f64| {
            let mut watch = StepWatch::default();
            for (t, step) in [(0.0, [d(0.05), 0.0]), (apart_s, [0.0, d(0.05)])] {
                watch.keep_place(Place {
                    step,
                    sigma: [d(0.02); 2],
                    t,
                    reach_s: 30.0,
                });
                watch.places_since_check += 1.0;
            }
            watch
        };
        assert!(windows(20.0).explains([d(-0.05); 2]));
        assert!(!windows(40.0).explains([d(-0.05); 2]));
    }

    #[test]
    fn a_step_too_small_to_call_is_carried_in_the_sigma_if_chance_does_not_explain_it() {
        let d = f64::to_radians;
        let mut watch = StepWatch::default();
        // One place: the threshold is √(2 ln(2/0.05)) = √(2 ln 40) ≈ 2.716.
        // A step of 0.05° with σ 0.02° (2.5σ) is within chance.
        watch.record(0.0, [(d(0.05), d(0.02)), (0.0, d(0.02))]);
        assert_eq!(watch.suspected_rad(), [0.0; 2]);
        assert_eq!(watch.unverified_variance(), [0.0; 2]);
        // σ 0.016° (3.125σ): suspect on pitch; its variance is δ²/3.
        watch.laser_checked();
        watch.record(0.0, [(d(-0.05), d(0.016)), (0.0, d(0.016))]);
        assert_eq!(watch.suspected_rad(), [d(0.05), 0.0]);
        let [pitch, roll] = watch.unverified_variance();
        assert!((pitch - d(0.05).powi(2) / 3.0).abs() < 1e-18);
        assert_eq!(roll, 0.0);
        assert!(!watch.unverified(), "suspect is not called");
        // The best of 100 places: √(2 ln 4000) ≈ 4.07 > 3.125.
        for _ in 0..99 {
            watch.record(0.0, [(0.0, d(0.016)); 2]);
        }
        assert_eq!(watch.suspected_rad(), [0.0; 2]);
    }

    #[test]
    fn the_extrapolated_line_sees_a_step_the_two_short_ones_miss() {
        // Readings 1 s apart, ±0.01° alternating noise on a level; from
        // reading 48 the pitch is 0.015° up. The line through the 48
        // older readings, carried to the newest 16's mean time (leverage
        // 1/48 + 32²/9212 ≈ 0.132, plus 1/16), sees it at
        // 0.0158/√(1.067e-4 · 0.1945) ≈ 3.5σ, beyond chance among the
        // ≈ 2.1 places tested (√(2 ln 84) ≈ 2.98); the short lines' best
        // is within their chance (without the longer test nothing is
        // suspect: checked when it was written). Nothing is called.
        let d = f64::to_radians;
        let r = [d(0.01).powi(2); 2];
        let noise = |k: usize| if k.is_multiple_of(2) { 0.01 } else { -0.01 };
        let mut watch = StepWatch::default();
        for k in 0..64 {
            let step = if k >= 48 { 0.015 } else { 0.0 };
            watch.observe(k as f64, d(noise(k) + step), d(noise(k)), r);
        }
        assert_eq!(watch.steps, 0);
        let [pitch, roll] = watch.suspected_rad().map(f64::to_degrees);
        assert!((pitch - 0.0158).abs() < 0.001, "{pitch}");
        assert_eq!(roll, 0.0);
        // The same level without the step: nothing suspect.
        let mut watch = StepWatch::default();
        for k in 0..64 {
            watch.observe(k as f64, d(noise(k)), d(noise(k)), r);
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
