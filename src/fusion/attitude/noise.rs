//! Self-tuning: the filters' measurement and process noise estimated from
//! the readings themselves, so that nobody on site tunes Q and R. Every
//! estimate falls back to its prior (the engine's parameter) until it has
//! data behind it, and forgets slowly, so a machine whose vibration or
//! motion changes over a drive is followed.
//!
//! **Motion phase (N1).** Cutting shakes the inclinometer, ring building
//! does not. Each reading's white noise shows in the residual of a straight
//! line through the two readings before it: for readings r = Δt_k/Δt_{k−1}
//! apart, e = z_k − z_{k−1} − r (z_{k−1} − z_{k−2}) has variance
//! (1 + (1 + r)² + r²) σ² (6σ² at equal spacing)                       (N1)
//! which, averaged over pitch and roll and smoothed over [`LEVEL_S`], is
//! the *level*. Two centres on ln(level) (two-means, each following its
//! cluster over [`CENTRE_MEMORY_S`]) split it: a reading is `vibrating`
//! nearer the upper one and `quiet` nearer the lower, with a hysteresis of
//! a tenth of their distance. Nothing tells the engine which phase it is.
//!
//! **Inclinometer noise and fast motion (N2).** Second differences of one
//! axis at lags of k = 1, 2, 4 … 32 readings (h_k apart, up to
//! [`MAX_LAG_S`]), D_k = z(t) − 2 z(t − h_k) + z(t − 2h_k), have
//! E[D_k²] = 6σ_w² + σ_c² (6 − 8ρ^k + 2ρ^{2k}) + 2 q_w h_k + ⅔ q_a h_k³   (N2)
//! for white noise σ_w², coloured (AR(1), ρ = e^{−Δ/τ}) noise σ_c², a
//! random walk q_w of the signal and a random walk q_a of its rate. With
//! q_a at most the laser's (N3, N2c), N2 is fitted by weighted non-negative least
//! squares for each τ of [`COLOUR_TAUS_S`]; colour is kept only if it
//! clearly fits better and is more than a trace. Per phase the result is
//! scaled by that phase's one-lag level E[D₁²]/6.
//!
//! **What the filter must assume (N2b).** A filter averaging n readings
//! sees coloured noise n-fold less reduced than white: the variance per
//! reading it must take is σ_w² + σ_c² g(n) with the AR(1) mean-of-n factor
//! g(n) = (1 + ρ)/(1 − ρ) − 2ρ (1 − ρⁿ) / (n (1 − ρ)²)                  (N2b)
//! and n ≈ min(√(R/(q_w Δ)), (R/(q_a Δ³))^¼), the inverse steady gain.
//!
//! **The laser's walk bounds the lags' (N2c).** N3's q_a is fitted over
//! minutes. A motion smoother than a rate walk (a roll that sways over
//! half an hour) grows like h⁴, not h³, so carried down to the
//! inclinometer's lags ⅔ q_a h³ overstates it and, taken out of E[D²], it
//! left nothing for the noise (on the envelope a 20 s inclinometer's roll
//! noise fitted 0.0001° against 0.037°, and the roll σ followed). The fit
//! therefore takes its own rate walk q_a′ ≤ q_a as a fourth column.
//!
//! **The machine's slow motion (N3).** The inclinometer's lags are too
//! short to see the shield turn; the laser's are long enough. Laser second
//! differences at a lag h ≥ [`CURVATURE_LAG_S`] have
//! E[D²] = ⅔ q_a h³ + 6 σ_L²                                            (N3)
//! which gives q_a for pitch and roll. σ_L² is the engine's prior
//! `r_laser_deg2`: a few laser samples per hour cannot part it from q_a.
//!
//! **The laser bounds the angle's white steps (N3b).** A random walk of
//! the angle, q_w, adds 2 q_w h to the same E[D²], so
//! q_w ≤ (E[D²] − 6 σ_L²) / (2h)                                        (N3b)
//! (equal spacing; q_a taken as 0, so it bounds and does not apportion),
//! with E[D²] at its upper 2σ confidence bound, and N2's q_w is held to
//! it. The inclinometer's lags span seconds, where
//! coloured noise of a time constant between N2's grid points (or beyond
//! them), or a shift of the reading when the vibration changes, grows like
//! a walk; over minutes the laser sees whether the angle really wanders.
//! Motion that reverts within minutes (τ below the lag) shows less at the
//! laser's lag than at the inclinometer's: the confidence bound leaves it
//! room, but a walk the laser cannot see can still be cut. Without the
//! bound a walk taken from the noise makes the filter follow the noise (a
//! filter averaging 6 readings where the oracle averages hundreds).
//!
//! The inclinometer bias's process noise is not estimated here: the engine
//! grows the bias's variance at each laser sample by the excess of the
//! normalised innovations over their expectation ([`RecentMean`] of ν²/S,
//! covariance matching).

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// The phase level is smoothed over this long (at least 4 readings).
pub const LEVEL_S: f64 = 60.0;
/// Readings before the phase is classified.
const LEVEL_READINGS: f64 = 16.0;
/// The phase centres follow their cluster over this long.
const CENTRE_MEMORY_S: f64 = 1800.0;
/// Samples after which running means forget (weight 1/MEMORY).
pub const MEMORY: f64 = 40.0;
/// Samples a [`RecentMean`] averages over.
pub const RECENT: f64 = 8.0;
/// The inclinometer's second differences are taken at these lags, in
/// readings, as far as [`MAX_LAG_S`].
const LAGS: [usize; 6] = [1, 2, 4, 8, 16, 32];
/// Readings in the longest lag's triple.
const LONGEST_TRIPLE: usize = 2 * LAGS[LAGS.len() - 1] + 1;
pub const MAX_LAG_S: f64 = 120.0;
/// The variogram's sums forget over this many differences per lag.
const VARIOGRAM_MEMORY: f64 = 2000.0;
/// Time constants tried for the coloured part of the noise, s (0: none):
/// vibration of seconds. Slower "noise" is indistinguishable from motion
/// over the lags, and is treated as motion.
const COLOUR_TAUS_S: [f64; 6] = [0.0, 0.5, 1.0, 2.0, 4.0, 8.0];
/// A coloured fit must leave this much less residual than the white one to
/// be preferred (it has one more parameter).
const COLOUR_GAIN: f64 = 0.8;
/// Colour below this share of the white variance is a trace, not colour.
const COLOUR_TRACE: f64 = 0.2;
/// The most readings a filter is taken to average (for the colour's share).
const MAX_AVERAGED: f64 = 1000.0;
/// Laser second differences are taken at a lag of at least this long.
pub const CURVATURE_LAG_S: f64 = 240.0;
/// Laser samples kept for them.
const CURVATURE_SAMPLES: usize = 24;
/// Estimates are used once they rest on this many differences.
const MIN_SAMPLES: f64 = 4.0;
/// The angle walk's bound (N3b) takes the laser's E[D²] this many standard
/// errors above its estimate.
const WALK_BOUND_SIGMAS: f64 = 2.0;
/// A lag enters the variogram's fit once it has this many differences (a
/// colour's time constant from a few dozen is a guess).
const MIN_VARIOGRAM_SAMPLES: f64 = 100.0;

/// What the machine is doing, as the inclinometer's vibration shows it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Standing (ring building): the lower noise level.
    Quiet,
    /// Excavating: the higher noise level.
    Vibrating,
}

impl Phase {
    /// 0 for quiet, 1 for vibrating: the index of per-phase arrays.
    pub fn index(self) -> usize {
        match self {
            Phase::Quiet => 0,
            Phase::Vibrating => 1,
        }
    }
}

/// A running mean that averages its first samples equally and then
/// forgets with weight 1/[`MEMORY`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct RunningMean {
    pub mean: f64,
    pub count: f64,
}

impl RunningMean {
    pub fn add(&mut self, x: f64) {
        self.count += 1.0;
        self.mean += (x - self.mean) / self.count.min(MEMORY);
    }
}

/// E[ln χ²₁] = ψ(½) + ln 2: the mean log of a squared standard normal.
const MEAN_LOG_CHI2_1: f64 = -1.270_362_845_461_478;

/// A robust running estimate of a variance from squared zero-mean normal
/// samples x = D²/w: exp(mean ln x − E[ln χ²₁]). A jump (a retrain, a
/// knock) moves one log by a bounded amount instead of dominating a mean
/// of squares.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LogVariance(RunningMean);

impl LogVariance {
    pub fn add(&mut self, square: f64) {
        self.0.add((square + 1e-300).ln());
    }

    /// The variance, once `min_count` samples are in.
    pub fn get(&self, min_count: f64) -> Option<f64> {
        (self.0.count >= min_count).then(|| (self.0.mean - MEAN_LOG_CHI2_1).exp())
    }

    pub fn count(&self) -> f64 {
        self.0.count
    }

    /// An upper confidence bound on the variance, `sigmas` standard errors
    /// of the mean log above it, once `min_count` samples are in. ln χ²₁
    /// has variance π²/2; the running mean forgets with weight 1/[`MEMORY`]
    /// (about 2·MEMORY samples' worth), and overlapping differences (the
    /// laser's lag spans several periods) share readings, so it is taken
    /// to rest on at most MEMORY independent samples.
    pub fn upper(&self, min_count: f64, sigmas: f64) -> Option<f64> {
        self.get(min_count).map(|v| {
            let n = self.0.count.clamp(1.0, MEMORY);
            let spread = (std::f64::consts::PI * std::f64::consts::PI / 2.0 / n).sqrt();
            v * (sigmas * spread).exp()
        })
    }
}

/// A mean over about the last [`RECENT`] samples (equal weights until
/// then, then forgetting).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct RecentMean {
    pub mean: f64,
    pub count: f64,
}

impl RecentMean {
    pub fn add(&mut self, x: f64) {
        self.count += 1.0;
        self.mean += (x - self.mean) / self.count.min(RECENT);
    }
}

/// A mean over about the last [`RECENT`] samples, each weighted by its
/// precision: an estimate of a variance from one innovation, ν² − S, has
/// variance 2S², so a sample taken while the filter still rested on its
/// prior (S large) weighs next to nothing against one taken once it has
/// settled. With equal weights it is [`RecentMean`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct PrecisionMean {
    pub mean: f64,
    weight: f64,
    count: f64,
}

impl PrecisionMean {
    /// Adds `x` with precision `weight` (ignored unless positive and finite).
    pub fn add(&mut self, x: f64, weight: f64) {
        if !(weight > 0.0 && weight.is_finite()) {
            return;
        }
        self.count += 1.0;
        if self.count > RECENT {
            self.weight *= 1.0 - 1.0 / RECENT;
        }
        self.weight += weight;
        self.mean += weight / self.weight * (x - self.mean);
    }
}

/// Classifies readings into motion phases from their white-noise level (N1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhaseDetector {
    /// The two readings before the newest: (t, pitch, roll).
    previous: VecDeque<(f64, f64, f64)>,
    /// Smoothed per-reading white-noise variance.
    level: f64,
    readings: f64,
    /// ln(level) of the quiet and of the vibrating cluster, and the
    /// readings each has taken.
    centres: [f64; 2],
    counts: [f64; 2],
    phase: Phase,
    /// The newest reading's own noise sample lies above the geometric
    /// middle of the two phases' levels (the smoothed level has not yet
    /// followed a phase change).
    #[serde(default)]
    newest_loud: bool,
}

impl Default for PhaseDetector {
    fn default() -> Self {
        PhaseDetector {
            previous: VecDeque::with_capacity(2),
            level: 0.0,
            readings: 0.0,
            centres: [0.0; 2],
            counts: [0.0; 2],
            phase: Phase::Vibrating,
            newest_loud: false,
        }
    }
}

impl PhaseDetector {
    /// Takes a reading (radians) and returns the phase it belongs to.
    pub fn observe(&mut self, t: f64, pitch: f64, roll: f64) -> Phase {
        if let (Some(&(t0, p0, r0)), Some(&(t1, p1, r1))) =
            (self.previous.front(), self.previous.get(1))
            && t1 > t0
            && t > t1
        {
            let r = (t - t1) / (t1 - t0);
            let factor = 1.0 + (1.0 + r) * (1.0 + r) + r * r;
            let e_pitch = pitch - p1 - r * (p1 - p0);
            let e_roll = roll - r1 - r * (r1 - r0);
            let sample = (e_pitch * e_pitch + e_roll * e_roll) / (2.0 * factor);
            // Both phases seen: is this one reading as loud as the middle
            // of their levels? (A quiet reading is, 1 time in e^{Δ/2},
            // Δ the levels' distance in nats: 1 in 3.5 at Δ = 2.5.)
            self.newest_loud = self.counts.iter().all(|c| *c > 0.0)
                && (sample + 1e-300).ln() > 0.5 * (self.centres[0] + self.centres[1]);
            self.readings += 1.0;
            let forget = ((t - t1) / LEVEL_S).min(0.25);
            self.level += (sample - self.level) * (1.0 / self.readings).max(forget);
            if self.readings >= LEVEL_READINGS {
                self.classify(t - t1);
            }
        }
        if self.previous.len() == 2 {
            self.previous.pop_front();
        }
        self.previous.push_back((t, pitch, roll));
        self.phase
    }

    /// Two-means on ln(level): the reading joins the nearer centre (with a
    /// hysteresis of a tenth of their distance), which moves towards it.
    fn classify(&mut self, dt_s: f64) {
        let x = (self.level + 1e-300).ln();
        if self.counts == [0.0; 2] {
            // Half a nat either side: the first phase's own spread parts
            // them, and the other phase, when it comes, pulls one away.
            self.centres = [x - 0.5, x + 0.5];
        }
        let [quiet, vibrating] = self.centres;
        let margin = 0.1 * (vibrating - quiet).abs();
        let (d_quiet, d_vibrating) = ((x - quiet).abs(), (x - vibrating).abs());
        self.phase = match self.phase {
            Phase::Vibrating if d_quiet + margin < d_vibrating => Phase::Quiet,
            Phase::Quiet if d_vibrating + margin < d_quiet => Phase::Vibrating,
            same => same,
        };
        let k = self.phase.index();
        self.counts[k] += 1.0;
        let weight = (1.0 / self.counts[k]).max(dt_s / CENTRE_MEMORY_S);
        self.centres[k] += weight * (x - self.centres[k]);
        if self.centres[0] > self.centres[1] {
            self.centres.swap(0, 1);
            self.counts.swap(0, 1);
            self.phase = match self.phase {
                Phase::Quiet => Phase::Vibrating,
                Phase::Vibrating => Phase::Quiet,
            };
        }
    }

    /// The current phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The phase whose noise the newest reading carries: vibrating while
    /// the phase is, and also for a reading as loud as the middle of the
    /// two levels (the first readings of an excavation, before the
    /// smoothed level follows). The reading is fused with [`phase`]'s
    /// gain; what the louder noise lets in joins the σ
    /// (loud_readings.rs).
    ///
    /// [`phase`]: Self::phase
    pub fn noise_phase(&self) -> Phase {
        if self.newest_loud {
            Phase::Vibrating
        } else {
            self.phase
        }
    }

    /// The smoothed white-noise variance of one reading (rad²), if known.
    pub fn level(&self) -> Option<f64> {
        (self.readings >= 3.0).then_some(self.level)
    }
}

/// The inclinometer's noise and the fast part of the machine's motion from
/// the variogram of second differences at several lags (N2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Variogram {
    /// Recent readings: (t, z, phase), the newest last. Up to twice the
    /// longest triple is kept and the older half dropped at once, so the
    /// per-reading lookups index a plain slice.
    recent: Vec<(f64, f64, Phase)>,
    /// Per lag: E[D²] and the lag h, s.
    d2: Vec<RunningMean>,
    lag_s: Vec<RunningMean>,
    /// E[D₁²]/6 (the one-lag white estimate) per phase.
    one_lag: [RunningMean; 2],
}

impl Default for Variogram {
    fn default() -> Self {
        Variogram {
            recent: Vec::with_capacity(2 * LONGEST_TRIPLE),
            d2: vec![RunningMean::default(); LAGS.len()],
            lag_s: vec![RunningMean::default(); LAGS.len()],
            one_lag: [RunningMean::default(); 2],
        }
    }
}

/// What the variogram says (N2): the per-reading noise variances of its
/// white and coloured parts, the colour's time constant, and the random
/// walk q_w (rad²/s) of the signal.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NoiseFit {
    pub white: f64,
    pub coloured: f64,
    pub tau_s: f64,
    pub q_w: f64,
    /// E[D₁²]/6 over all phases: what the one-lag estimates are relative to.
    pub one_lag: f64,
}

impl NoiseFit {
    /// The variance per reading that a filter averaging about `n` readings
    /// `period_s` apart must take: white plus coloured, the coloured part
    /// grown by the AR(1) sum for the mean of n readings (N2b):
    /// (1 + ρ)/(1 − ρ) − 2ρ (1 − ρⁿ) / (n (1 − ρ)²), ρ = e^{−period/τ}.
    pub fn effective(&self, n: f64, period_s: f64) -> f64 {
        if self.tau_s <= 0.0 || self.coloured <= 0.0 {
            return self.white + self.coloured;
        }
        let rho = (-period_s / self.tau_s).exp();
        let n = n.max(1.0);
        let growth =
            (1.0 + rho) / (1.0 - rho) - 2.0 * rho * (1.0 - rho.powf(n)) / (n * (1.0 - rho).powi(2));
        self.white + self.coloured * growth.max(1.0)
    }

    /// About how many readings a filter with this noise and motion (and
    /// the rate random walk `q_a`) averages: 1/K for the steady gain K of
    /// a random walk, √(R / (q_w Δ)), or of a rate random walk,
    /// (R / (q_a Δ³))^¼, whichever is fewer.
    pub fn readings_averaged(&self, q_a: f64, period_s: f64) -> f64 {
        let r = self.white + self.coloured;
        let walk = if self.q_w > 0.0 {
            (r / (self.q_w * period_s)).sqrt()
        } else {
            f64::INFINITY
        };
        let rate = if q_a > 0.0 {
            (r / (q_a * period_s.powi(3))).powf(0.25)
        } else {
            f64::INFINITY
        };
        walk.min(rate).clamp(1.0, MAX_AVERAGED)
    }
}

impl Variogram {
    /// Takes one reading `z` (radians) of `phase`.
    pub fn observe(&mut self, t: f64, z: f64, phase: Phase) {
        if self.recent.len() >= 2 * LONGEST_TRIPLE {
            self.recent.drain(..self.recent.len() + 1 - LONGEST_TRIPLE);
        }
        self.recent.push((t, z, phase));
        let recent = &self.recent[..];
        let n = recent.len();
        for (i, &k) in LAGS.iter().enumerate() {
            if n < 2 * k + 1 {
                break;
            }
            let (t0, z0, _) = recent[n - 1 - 2 * k];
            let (t1, z1, p1) = recent[n - 1 - k];
            let (h1, h2) = (t1 - t0, t - t1);
            // Evenly spaced triples only (a gap is not a lag).
            if h1 <= 0.0 || (h2 - h1).abs() > 0.2 * h1 || h1 > MAX_LAG_S {
                continue;
            }
            let d = z - 2.0 * z1 + z0;
            let memory = VARIOGRAM_MEMORY;
            let add = |m: &mut RunningMean, x: f64| {
                m.count += 1.0;
                m.mean += (x - m.mean) / m.count.min(memory);
            };
            add(&mut self.d2[i], d * d);
            add(&mut self.lag_s[i], 0.5 * (h1 + h2));
            if i == 0 && p1 == phase {
                add(&mut self.one_lag[phase.index()], d * d / 6.0);
            }
        }
    }

    /// The one-lag estimate of the per-reading noise in `phase`.
    pub fn one_lag(&self, phase: Phase) -> Option<f64> {
        let m = self.one_lag[phase.index()];
        (m.count >= MIN_SAMPLES).then_some(m.mean)
    }

    /// N2 fitted for each τ of [`COLOUR_TAUS_S`] by weighted non-negative
    /// least squares (weights: count over E[D²] squared), the best τ
    /// kept: E[D_k²] = 6σ_w² + σ_c² (6 − 8ρ^k + 2ρ^{2k}) + 2 q_w h_k +
    /// (2/3) q_a h_k³ with ρ^k = e^{−h_k/τ}. `q_a_max` comes from
    /// elsewhere (the laser, over minutes): at these short lags a motion
    /// smoother than a rate walk (a turn that builds over minutes) shows
    /// less than (2/3) q_a h³, so the fit takes its own q_a up to
    /// `q_a_max`; what the lags do not show of the laser's walk is not
    /// taken out of the noise (N2c).
    pub fn fit(&self, q_a_max: f64) -> Option<NoiseFit> {
        let rows: Vec<(f64, f64, f64)> = self
            .d2
            .iter()
            .zip(&self.lag_s)
            .filter(|(d2, _)| d2.count >= MIN_VARIOGRAM_SAMPLES)
            .map(|(d2, h)| {
                let w = d2.count.min(VARIOGRAM_MEMORY) / (d2.mean * d2.mean).max(1e-300);
                (h.mean, d2.mean, w)
            })
            .collect();
        let one = self.d2[0];
        if rows.len() < 3 || one.count < MIN_SAMPLES || one.mean <= 0.0 {
            return None;
        }
        let rate_column = |h: f64| 2.0 / 3.0 * h.powi(3);
        let mut best: Option<(f64, NoiseFit)> = None;
        for &tau in &COLOUR_TAUS_S {
            // Columns: white, coloured (none without colour), random walk,
            // rate walk.
            let columns = |h: f64| {
                let colour = if tau > 0.0 {
                    let rho = (-h / tau).exp();
                    6.0 - 8.0 * rho + 2.0 * rho * rho
                } else {
                    0.0
                };
                [6.0, colour, 2.0 * h, rate_column(h)]
            };
            let mut system: Vec<([f64; 4], f64, f64)> =
                rows.iter().map(|&(h, y, w)| (columns(h), y, w)).collect();
            // The rate walk is free where the lags leave the fit a row to
            // spare (colour has one column more, so it needs five lags;
            // without colour an exact fit of three is allowed: it is the
            // default, and colour must beat it).
            let unknowns = if tau > 0.0 { 4 } else { 3 };
            let free = system.len() > unknowns || (tau == 0.0 && system.len() == unknowns);
            let free_fit = free
                .then(|| nonnegative_least_squares(&system))
                .filter(|(c, _)| c[3] <= q_a_max);
            let (c, residual) = free_fit.unwrap_or_else(|| {
                // Bounded: the rate walk at its bound (a convex fit whose
                // free optimum lies beyond it has its bounded one on it).
                for (x, y, _) in &mut system {
                    *y -= q_a_max * x[3];
                    x[3] = 0.0;
                }
                let (mut c, residual) = nonnegative_least_squares(&system);
                c[3] = q_a_max;
                (c, residual)
            });
            let [white, coloured, q_w, _] = c;
            let fit = NoiseFit {
                white,
                coloured,
                tau_s: tau,
                q_w,
                one_lag: one.mean / 6.0,
            };
            // The white fit (first) stands unless colour clearly does better
            // and is more than a trace.
            let trace = coloured < COLOUR_TRACE * white;
            if tau > 0.0 && trace {
                continue;
            }
            let score = if tau > 0.0 {
                residual / COLOUR_GAIN
            } else {
                residual
            };
            if best.is_none_or(|(r, _)| score < r) {
                best = Some((score, fit));
            }
        }
        best.map(|(_, fit)| fit)
    }
}

/// Weighted least squares y ≈ Σ x_j c_j with every c_j ≥ 0: each subset of
/// the columns is solved and the best fit with no negative coefficient
/// kept (a column of zeros makes its subsets singular, so it stays 0).
/// The normal equations are solved with each column scaled to a unit
/// diagonal (the columns span ten decades: 6 against ⅔h³), and a subset
/// whose pivot falls below [`RELATIVE_PIVOT`] of that is singular.
/// Returns the coefficients and the weighted residual Σ w (y − xᵀc)².
fn nonnegative_least_squares(rows: &[([f64; 4], f64, f64)]) -> ([f64; 4], f64) {
    // The normal equations once: A = Σ w x xᵀ, b = Σ w x y.
    let (mut a, mut b) = ([[0.0; 4]; 4], [0.0; 4]);
    for (x, y, w) in rows {
        for i in 0..4 {
            b[i] += w * x[i] * y;
            for j in 0..4 {
                a[i][j] += w * x[i] * x[j];
            }
        }
    }
    let scale = [0, 1, 2, 3].map(|j| a[j][j].sqrt());
    let residual_of = |c: &[f64; 4]| {
        rows.iter()
            .map(|(x, y, w)| {
                let fitted: f64 = x.iter().zip(c).map(|(x, c)| x * c).sum();
                w * (y - fitted).powi(2)
            })
            .sum::<f64>()
    };
    let mut best = ([0.0; 4], residual_of(&[0.0; 4]));
    for mask in 1..(1u32 << 4) {
        let mut cols = [0usize; 4];
        let mut k = 0;
        for j in 0..4 {
            if mask & (1 << j) != 0 {
                cols[k] = j;
                k += 1;
            }
        }
        if cols[..k]
            .iter()
            .any(|&j| !(scale[j] > 0.0 && scale[j].is_finite()))
        {
            continue;
        }
        let mut m = [[0.0; 5]; 4];
        for r in 0..k {
            for c in 0..k {
                m[r][c] = a[cols[r]][cols[c]] / (scale[cols[r]] * scale[cols[c]]);
            }
            m[r][4] = b[cols[r]] / scale[cols[r]];
        }
        let Some(solution) = solve_small(&mut m, k) else {
            continue;
        };
        let mut c = [0.0; 4];
        for r in 0..k {
            c[cols[r]] = solution[r] / scale[cols[r]];
        }
        if c.iter().any(|c| !(c.is_finite() && *c >= 0.0)) {
            continue;
        }
        let residual = residual_of(&c);
        if residual < best.1 {
            best = (c, residual);
        }
    }
    best
}

/// A pivot below this (of a unit diagonal) is a singular subset.
const RELATIVE_PIVOT: f64 = 1e-12;

/// Gaussian elimination with partial pivoting on the first `k` rows of the
/// augmented matrix `m` (k ≤ 4, scaled to a unit diagonal); `None` if it
/// is singular.
fn solve_small(m: &mut [[f64; 5]; 4], k: usize) -> Option<[f64; 4]> {
    for col in 0..k {
        let pivot = (col..k).max_by(|&x, &y| m[x][col].abs().total_cmp(&m[y][col].abs()))?;
        if m[pivot][col].abs() <= RELATIVE_PIVOT {
            return None;
        }
        m.swap(col, pivot);
        let pivot_row = m[col];
        for row in m.iter_mut().take(k).skip(col + 1) {
            let f = row[col] / pivot_row[col];
            for (value, above) in row.iter_mut().zip(pivot_row).skip(col) {
                *value -= f * above;
            }
        }
    }
    let mut x = [0.0; 4];
    for row in (0..k).rev() {
        let mut v = m[row][4];
        for c in row + 1..k {
            v -= m[row][c] * x[c];
        }
        x[row] = v / m[row][row];
    }
    Some(x)
}

/// How the machine's attitude moves, from the laser's own samples (N3):
/// second differences at a lag of at least [`CURVATURE_LAG_S`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserCurvature {
    /// Recent samples: (t, pitch, roll).
    samples: VecDeque<(f64, f64, f64)>,
    /// E[D²] of pitch and roll, and the lag h they were taken at.
    pitch: LogVariance,
    roll: LogVariance,
    lag_s: RunningMean,
}

impl Default for LaserCurvature {
    fn default() -> Self {
        LaserCurvature {
            samples: VecDeque::with_capacity(CURVATURE_SAMPLES),
            pitch: LogVariance::default(),
            roll: LogVariance::default(),
            lag_s: RunningMean::default(),
        }
    }
}

impl LaserCurvature {
    /// Takes a laser sample (radians); `period_s` is the laser's usual period.
    pub fn observe(&mut self, t: f64, pitch: f64, roll: f64, period_s: f64) {
        if self.samples.len() == CURVATURE_SAMPLES {
            self.samples.pop_front();
        }
        self.samples.push_back((t, pitch, roll));
        let lag = (CURVATURE_LAG_S / period_s).ceil().max(1.0) * period_s;
        // The samples nearest to t − h and t − 2h, if they are near enough
        // (a lost sample or a dropout leaves no triple).
        let near = |target: f64| {
            self.samples
                .iter()
                .min_by(|a, b| (a.0 - target).abs().total_cmp(&(b.0 - target).abs()))
                .copied()
                .filter(|s| (s.0 - target).abs() <= 0.1 * lag)
        };
        if let (Some(mid), Some(first)) = (near(t - lag), near(t - 2.0 * lag)) {
            let (h1, h2) = (mid.0 - first.0, t - mid.0);
            if h1 > 0.0 && h2 > 0.0 {
                let r = h2 / h1;
                let d_pitch = pitch - mid.1 - r * (mid.1 - first.1);
                let d_roll = roll - mid.2 - r * (mid.2 - first.2);
                self.pitch.add(d_pitch * d_pitch);
                self.roll.add(d_roll * d_roll);
                self.lag_s.add(0.5 * (h1 + h2));
            }
        }
    }

    /// The most angle random walk (q_w, white steps of the angle) pitch and
    /// roll can have, given the laser's noise variance (N3b): a walk adds
    /// 2 q_w h to E[D²] at lag h (equal spacing), so
    /// q_w ≤ (E[D²] − 6 σ_L²) / (2h), with E[D²] taken at its upper
    /// confidence bound ([`WALK_BOUND_SIGMAS`] standard errors above the
    /// estimate): a bound, not an estimate, it must not cut a walk the
    /// laser's few samples happened to show less of.
    pub fn angle_walk_max(&self, laser_var_rad2: f64) -> Option<(f64, f64)> {
        let pitch = self.pitch.upper(MIN_SAMPLES, WALK_BOUND_SIGMAS)?;
        let roll = self.roll.upper(MIN_SAMPLES, WALK_BOUND_SIGMAS)?;
        let h = self.lag_s.mean;
        let q = |e: f64| ((e - 6.0 * laser_var_rad2) / (2.0 * h)).max(0.0);
        Some((q(pitch), q(roll)))
    }

    /// The rate random-walk intensities (q_a) of pitch and roll, given the
    /// laser's noise variance: E[D²] = (2/3) q_a h³ + 6 σ_L² for samples h
    /// apart (the second difference of an integrated random walk).
    pub fn rate_noise(&self, laser_var: f64) -> Option<(f64, f64)> {
        let (pitch, roll) = (self.pitch.get(MIN_SAMPLES)?, self.roll.get(MIN_SAMPLES)?);
        let h3 = self.lag_s.mean.powi(3);
        let q = |e: f64| ((e - 6.0 * laser_var) / (2.0 / 3.0 * h3)).max(0.0);
        Some((q(pitch), q(roll)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    #[test]
    fn running_mean_by_hand() {
        let mut m = RunningMean::default();
        for x in [1.0, 2.0, 3.0] {
            m.add(x);
        }
        assert!((m.mean - 2.0).abs() < 1e-15);
        for _ in 0..1000 {
            m.add(10.0);
        }
        assert!((m.mean - 10.0).abs() < 1e-9);
    }

    /// N2c: a 20 s inclinometer's lags (20, 40, 80 s) over white noise
    /// σ² = 10⁻⁷ rad² and a rate walk of 10⁻¹³ rad²/s³, with the laser's
    /// walk (N3) a hundred times larger. Taken out whole, ⅔·10⁻¹¹·80³ =
    /// 3.41·10⁻⁶ would exceed E[D²] at 80 s (6·10⁻⁷ + 3.41·10⁻⁸); fitted
    /// up to its bound, the noise and the walk are found exactly.
    #[test]
    fn the_lags_fit_their_own_rate_walk_up_to_the_lasers() {
        let (white, q_a) = (1e-7_f64, 1e-13_f64);
        let mut v = Variogram::default();
        for (i, h) in [20.0_f64, 40.0, 80.0].into_iter().enumerate() {
            v.d2[i] = RunningMean {
                mean: 6.0 * white + 2.0 / 3.0 * q_a * h.powi(3),
                count: 2000.0,
            };
            v.lag_s[i] = RunningMean {
                mean: h,
                count: 2000.0,
            };
        }
        let fit = v.fit(100.0 * q_a).unwrap();
        assert!((fit.white / white - 1.0).abs() < 1e-9, "{fit:?}");
        assert!(fit.q_w < 1e-9 * white && fit.coloured == 0.0, "{fit:?}");
        // Held at the laser's bound of 0 the walk leaves, at 80 s, E[D²]
        // that a line in h cannot bend to: the noise is no longer exact.
        let held = v.fit(0.0).unwrap();
        assert!((held.white / white - 1.0).abs() > 1e-3, "{held:?}");
    }

    /// White noise of σ on a slow ramp: R is σ², no colour, no walk.
    #[test]
    fn white_noise_is_white() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut v = Variogram::default();
        let sigma = 0.01_f64;
        for k in 0..50_000 {
            let t = k as f64;
            let n: f64 = rng.sample(StandardNormal);
            v.observe(t, 1e-5 * t + sigma * n, Phase::Vibrating);
        }
        let fit = v.fit(0.0).unwrap();
        let r = fit.effective(100.0, 1.0);
        assert!((r / (sigma * sigma) - 1.0).abs() < 0.1, "{fit:?}");
        assert!(fit.q_w < 1e-3 * sigma * sigma, "{fit:?}");
        let one = v.one_lag(Phase::Vibrating).unwrap();
        assert!((one / (sigma * sigma) - 1.0).abs() < 0.1);
        assert!(v.one_lag(Phase::Quiet).is_none());
    }

    /// Half the variance AR(1) with τ = 4 s, read every 0.5 s: the filter
    /// must take σ² (½ + ½ (1 + ρ)/(1 − ρ)), ρ = e^{−1/8}: 8.5 σ².
    #[test]
    fn coloured_noise_gives_its_effective_variance() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut v = Variogram::default();
        let (sigma, dt, tau) = (0.01_f64, 0.5_f64, 4.0_f64);
        let rho = (-dt / tau).exp();
        let mut x = 0.0;
        for k in 0..400_000 {
            let n: [f64; 2] = [rng.sample(StandardNormal), rng.sample(StandardNormal)];
            x = rho * x + sigma * (0.5 * (1.0 - rho * rho)).sqrt() * n[0];
            v.observe(
                k as f64 * dt,
                x + sigma * 0.5_f64.sqrt() * n[1],
                Phase::Vibrating,
            );
        }
        let fit = v.fit(0.0).unwrap();
        let effective = 0.5 + 0.5 * (1.0 + rho) / (1.0 - rho);
        let got = fit.effective(1000.0, dt) / (sigma * sigma);
        assert!(
            (got / effective - 1.0).abs() < 0.25,
            "{got} vs {effective}: {fit:?}"
        );
        // Over 8 readings (one time constant) the colour counts for less.
        assert!(fit.effective(8.0, dt) < 0.7 * fit.effective(1000.0, dt));
        assert!(fit.q_w < 1e-3 * sigma * sigma, "{fit:?}");
    }

    /// White noise on a random walk of known intensity (a shield rocking):
    /// the walk is found and the noise is not taken for it.
    #[test]
    fn a_random_walk_under_white_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let mut v = Variogram::default();
        let (sigma, q_w) = (0.005_f64, 1e-5_f64);
        let mut walk = 0.0;
        for k in 0..100_000 {
            let n: [f64; 2] = [rng.sample(StandardNormal), rng.sample(StandardNormal)];
            walk += q_w.sqrt() * n[0];
            v.observe(k as f64, walk + sigma * n[1], Phase::Vibrating);
        }
        let fit = v.fit(0.0).unwrap();
        assert!((fit.q_w / q_w - 1.0).abs() < 0.2, "{fit:?}");
        assert!((fit.white / (sigma * sigma) - 1.0).abs() < 0.3, "{fit:?}");
    }

    /// A pitch whose rate is a random walk of known intensity, seen by a
    /// laser every 60 s with 0.003° of noise: the curvature finds q_a
    /// within a factor of two.
    #[test]
    fn laser_curvature_of_an_integrated_random_walk() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut curvature = LaserCurvature::default();
        let (q_a, sigma) = (1e-14_f64, 0.003_f64.to_radians());
        let (mut angle, mut rate) = (0.0, 0.0);
        for k in 0..20_000 {
            for _ in 0..60 {
                let w: f64 = rng.sample(StandardNormal);
                rate += q_a.sqrt() * w;
                angle += rate;
            }
            let n: [f64; 2] = [rng.sample(StandardNormal), rng.sample(StandardNormal)];
            curvature.observe(60.0 * k as f64, angle + sigma * n[0], sigma * n[1], 60.0);
        }
        let (fitted, roll) = curvature.rate_noise(sigma * sigma).unwrap();
        assert!(
            fitted > 0.5 * q_a && fitted < 2.0 * q_a,
            "{fitted:e} vs {q_a:e}"
        );
        // The roll stood still: nothing beyond the laser's noise.
        assert!(roll < 0.1 * q_a, "{roll:e}");
    }

    /// An angle that random-walks with q_w, seen by a laser every 60 s
    /// with 0.003° of noise. At the 240 s lag E[D²] = 2 q_w h + 6σ² =
    /// 4.8e-8 + 1.65e-8 rad²; its upper bound (×e^{2√(π²/80)} ≈ 2.0) less
    /// 6σ², over 2h, is about 2.4 q_w: the bound covers the walk without
    /// being loose by an order of magnitude. A roll standing still leaves
    /// only the laser's noise (about 0.35 q_w, often 0). Means over
    /// snapshots every 100 samples (geometric for the pitch), so the test
    /// does not rest on one.
    #[test]
    fn the_laser_bounds_the_angle_walk() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut curvature = LaserCurvature::default();
        let (q_w, sigma) = (1e-10_f64, 0.003_f64.to_radians());
        let mut angle = 0.0;
        let (mut pitch_log, mut roll_sum, mut snapshots) = (0.0, 0.0, 0.0);
        for k in 0..20_000 {
            let w: f64 = rng.sample(StandardNormal);
            angle += (q_w * 60.0).sqrt() * w;
            let n: [f64; 2] = [rng.sample(StandardNormal), rng.sample(StandardNormal)];
            curvature.observe(60.0 * k as f64, angle + sigma * n[0], sigma * n[1], 60.0);
            if k >= 1000 && k % 100 == 0 {
                let (pitch, roll) = curvature.angle_walk_max(sigma * sigma).unwrap();
                pitch_log += pitch.ln();
                roll_sum += roll;
                snapshots += 1.0;
            }
        }
        let pitch = (pitch_log / snapshots).exp();
        let roll = roll_sum / snapshots;
        assert!(
            pitch > 1.5 * q_w && pitch < 4.0 * q_w,
            "{pitch:e} vs {q_w:e}"
        );
        assert!(roll < 0.6 * q_w, "{roll:e} vs {q_w:e}");
    }

    #[test]
    fn a_reading_as_loud_as_an_excavation_carries_its_noise_before_the_phase_follows() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut detector = PhaseDetector::default();
        // Both phases learnt: 0.03 vibrating, then 0.008 quiet.
        for k in 0..6000 {
            let sigma = if k < 3000 { 0.03 } else { 0.008 };
            let n: [f64; 2] = [rng.sample(StandardNormal), rng.sample(StandardNormal)];
            detector.observe(k as f64, sigma * n[0], 1.0 + sigma * n[1]);
        }
        assert_eq!(detector.phase(), Phase::Quiet);
        // One reading 0.1 off on both axes: its second difference is
        // about 0.1, its noise sample (0.1² + 0.1²)/(2·6) = 1.7e-3, far
        // above the middle of the levels (0.008·0.03 = 2.4e-4): vibrating
        // noise for it, while the smoothed phase stays quiet.
        let previous = detector.previous[1];
        detector.observe(6000.0, previous.1 + 0.1, previous.2 + 0.1);
        assert_eq!(detector.phase(), Phase::Quiet);
        assert_eq!(detector.noise_phase(), Phase::Vibrating);
        // The next reading as quiet as the phase: quiet noise again.
        detector.observe(6001.0, previous.1 + 0.2, previous.2 + 0.2);
        assert_eq!(detector.noise_phase(), Phase::Quiet);
    }

    #[test]
    fn two_noise_levels_are_two_phases() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut detector = PhaseDetector::default();
        let mut right = 0;
        let total = 40_000;
        for k in 0..total {
            // 50 min vibrating at 0.03, 25 min quiet at 0.008, repeated.
            let vibrating = (k % 4500) < 3000;
            let sigma = if vibrating { 0.03 } else { 0.008 };
            let n: [f64; 2] = [rng.sample(StandardNormal), rng.sample(StandardNormal)];
            let phase = detector.observe(k as f64, sigma * n[0], 1.0 + sigma * n[1]);
            let truth = if vibrating {
                Phase::Vibrating
            } else {
                Phase::Quiet
            };
            if phase == truth {
                right += 1;
            }
        }
        assert!(right as f64 > 0.97 * total as f64, "{right}");
    }

    #[test]
    fn a_precision_mean_with_equal_weights_is_the_recent_mean_and_ignores_an_imprecise_sample() {
        let mut plain = RecentMean::default();
        let mut weighted = PrecisionMean::default();
        for i in 0..20 {
            let x = f64::from(i * i % 7);
            plain.add(x);
            weighted.add(x, 3.0);
            assert!((plain.mean - weighted.mean).abs() < 1e-12, "{i}");
        }
        // 1.0 (weight 1) then −100 (weight 1e-6, the prior's S): the mean
        // moves by about 1e-4 only.
        let mut m = PrecisionMean::default();
        m.add(1.0, 1.0);
        m.add(-100.0, 1e-6);
        assert!((m.mean - (1.0 - 101.0e-6 / (1.0 + 1e-6))).abs() < 1e-12);
    }
}
