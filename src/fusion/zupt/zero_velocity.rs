//! The streaming zero-velocity decision (Zhang et al. 2024, Sec. 3.2):
//! the detector's test over a window centred on each sample, a binary
//! median filter of length L over those decisions, then only runs of
//! zero velocity at least `min_run_s` long are kept (TCZVD: MV ∧ ARE ∧
//! SHOE; the single tests are selectable for comparison).
//!
//! A centred window needs the future, so decisions are made late, never by
//! looking further than this (with W = L = 100 at 100 Hz and a 3 s minimum
//! run, at most 0.99 s + 3 s behind the newest sample):
//! - the test for sample k waits for sample k + W − 1 − ⌊W/2⌋;
//! - its median for k + L − 1 − ⌊L/2⌋ more;
//! - a zero-velocity run is confirmed once it has lasted `min_run_s`;
//!   until then its samples wait (a moving decision is passed on at once).
//!
//! **Thresholds relative to a learned rest level** ([`RestLevel`]). A
//! machine whose pumps run while it stands has a higher floor than a silent
//! one, and no γ fits both. Each statistic's low quantile is tracked online
//! (the level only a twentieth of the samples fall below: a machine rests
//! more than that), and the test uses γ_eff = min(max(γ, κ·level), m·γ):
//! at least the configured γ, κ (`rest_level_factor`) times the learned
//! rest level, at most m (`threshold_max_factor`) times γ, so a machine
//! that never stops cannot teach the test to call its motion rest. The
//! level is a stochastic quantile tracker on ln T: d ln L/dt = (p −
//! 1[T < L]) / (p·τ), rising by e in τ (`rest_level_rise_s`) while every
//! sample is above it and falling twenty times as fast.
//!
//! At the start of a stream (and after a gap, which starts a new one) the
//! windows are truncated to the samples that exist, not shifted; at its
//! end [`ZeroVelocityPipeline::flush`] decides the waiting samples the same
//! way, and an unconfirmed run counts as moving. Median ties count as
//! moving: a false zero-velocity update costs more than a missed one.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use super::detectors::{DetectorNoise, Signals, Statistics, WindowSums};
use crate::fusion::geometry::V3;

crate::fusion::params::choice_enum! {
    /// Which test decides zero velocity (the `detector` parameter).
    pub enum DetectorKind {
        /// MV ∧ ARE ∧ SHOE (the paper's three-condition detector).
        Tczvd = "tczvd",
        Mv = "mv",
        Are = "are",
        Shoe = "shoe",
        Mag = "mag",
        /// Never zero velocity: pure inertial navigation, for comparison.
        None = "none",
    }
}

/// Thresholds γ of the four tests (stationary where T < γ).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Thresholds {
    pub mv: f64,
    pub are: f64,
    pub shoe: f64,
    pub mag: f64,
}

impl Thresholds {
    fn as_array(&self) -> [f64; 4] {
        [self.mv, self.are, self.shoe, self.mag]
    }
}

/// How the thresholds follow the learned rest level (module doc).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Adaptation {
    /// κ: γ_eff ≥ κ × the rest level.
    pub rest_level_factor: f64,
    /// m: γ_eff ≤ m × γ.
    pub max_factor: f64,
    /// τ: the rest level rises by e in this long while every sample is above it, s.
    pub rise_s: f64,
}

/// The share of samples the rest level is the quantile of.
const REST_QUANTILE: f64 = 0.05;

/// Each statistic's learned rest level (module doc).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RestLevel {
    /// L for MV, ARE, SHOE, MAG.
    level: [f64; 4],
    /// The newest sample's time, s.
    t: Option<f64>,
}

impl RestLevel {
    /// Levels at which γ_eff = γ.
    fn new(thresholds: &Thresholds, adaptation: &Adaptation) -> RestLevel {
        RestLevel {
            level: thresholds
                .as_array()
                .map(|g| g / adaptation.rest_level_factor),
            t: None,
        }
    }

    /// Takes one sample's statistics at time `t`.
    fn observe(&mut self, t: f64, statistics: &Statistics, adaptation: &Adaptation) {
        let dt = self.t.map_or(0.0, |last| (t - last).clamp(0.0, 1.0));
        self.t = Some(t);
        if dt <= 0.0 {
            return;
        }
        let values = [
            statistics.mv,
            statistics.are,
            statistics.shoe,
            statistics.mag,
        ];
        let rate = dt / (REST_QUANTILE * adaptation.rise_s);
        for (level, value) in self.level.iter_mut().zip(values) {
            let below = if value < *level { 1.0 } else { 0.0 };
            *level *= ((REST_QUANTILE - below) * rate).exp();
            // Kept where a float can follow it back.
            *level = level.clamp(1e-9, 1e12);
        }
    }

    /// γ_eff for each test.
    pub fn thresholds(&self, base: &Thresholds, adaptation: &Adaptation) -> Thresholds {
        let [mv, are, shoe, mag] = base.as_array();
        let adapt = |gamma: f64, level: f64| {
            (adaptation.rest_level_factor * level)
                .max(gamma)
                .min(adaptation.max_factor * gamma)
        };
        Thresholds {
            mv: adapt(mv, self.level[0]),
            are: adapt(are, self.level[1]),
            shoe: adapt(shoe, self.level[2]),
            mag: adapt(mag, self.level[3]),
        }
    }
}

/// Everything the pipeline needs to decide.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PipelineConfig {
    pub detector: DetectorKind,
    pub thresholds: Thresholds,
    pub noise: DetectorNoise,
    /// The samples or what the window integrates them to.
    pub signals: Signals,
    /// Thresholds that follow the learned rest level; `None`: fixed γ.
    pub adaptation: Option<Adaptation>,
    /// W, samples.
    pub window_samples: usize,
    /// L, samples (1 turns the median filter off).
    pub median_samples: usize,
    /// Shortest zero-velocity run kept, s.
    pub min_run_s: f64,
}

impl PipelineConfig {
    /// The selected test on one window's statistics (before the median),
    /// with thresholds `g`.
    pub fn is_still(&self, s: &Statistics, g: &Thresholds) -> bool {
        match self.detector {
            DetectorKind::Tczvd => s.mv < g.mv && s.are < g.are && s.shoe < g.shoe,
            DetectorKind::Mv => s.mv < g.mv,
            DetectorKind::Are => s.are < g.are,
            DetectorKind::Shoe => s.shoe < g.shoe,
            DetectorKind::Mag => s.mag < g.mag,
            DetectorKind::None => false,
        }
    }

    /// Samples after k that the test and the median filter wait for.
    pub fn lookahead_samples(&self) -> usize {
        lookahead(self.window_samples) + lookahead(self.median_samples)
    }
}

/// Samples after the centre of a centred window of `len`.
fn lookahead(len: usize) -> usize {
    len.max(1) - 1 - len.max(1) / 2
}

/// The decision for one sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Decision {
    /// Zero velocity, after the median filter and the minimum run.
    pub zv: bool,
    /// The test alone on this sample's window.
    pub still: bool,
    pub statistics: Statistics,
    /// The thresholds the test used (γ_eff).
    pub thresholds: Thresholds,
}

/// A sample on its way through the pipeline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Waiting<T> {
    t: f64,
    payload: T,
    statistics: Statistics,
    thresholds: Thresholds,
    still: bool,
}

/// The streaming decision; `T` travels with each sample (the engine's IMU
/// reading) and comes out with its decision, in order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZeroVelocityPipeline<T> {
    config: PipelineConfig,
    sums: WindowSums,
    /// The learned rest level, if the thresholds adapt (kept across
    /// streams: the machine is the same).
    rest_level: Option<RestLevel>,
    /// Samples pushed in this stream.
    pushed: u64,
    /// Samples not yet tested (waiting for their window's future).
    untested: VecDeque<Waiting<T>>,
    /// Tested samples waiting for the median's future.
    unfiltered: VecDeque<Waiting<T>>,
    /// The test decisions in the median window, oldest first, and how
    /// many of them are still.
    median_window: VecDeque<bool>,
    median_still: usize,
    /// Samples tested so far in this stream.
    tested: u64,
    /// Samples given a median decision so far in this stream.
    filtered: u64,
    /// A zero-velocity run not yet `min_run_s` long.
    run: VecDeque<Waiting<T>>,
    /// True while the current run has been confirmed.
    run_confirmed: bool,
}

impl<T> ZeroVelocityPipeline<T> {
    /// An empty pipeline.
    pub fn new(config: PipelineConfig) -> Self {
        ZeroVelocityPipeline {
            config,
            sums: WindowSums::new(config.window_samples),
            rest_level: config
                .adaptation
                .map(|adaptation| RestLevel::new(&config.thresholds, &adaptation)),
            pushed: 0,
            untested: VecDeque::new(),
            unfiltered: VecDeque::new(),
            median_window: VecDeque::new(),
            median_still: 0,
            tested: 0,
            filtered: 0,
            run: VecDeque::new(),
            run_confirmed: false,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    /// Samples inside, not yet decided.
    pub fn waiting(&self) -> usize {
        self.untested.len() + self.unfiltered.len() + self.run.len()
    }

    /// Adds the newest sample (accel m/s², gyro rad/s); `earth_rate_b` is
    /// the Earth's rotation in the body frame, removed by ARE and SHOE.
    /// Decided samples are appended to `out`, oldest first.
    pub fn push(
        &mut self,
        t: f64,
        accel: V3,
        gyro: V3,
        payload: T,
        earth_rate_b: &V3,
        out: &mut Vec<(T, Decision)>,
    ) {
        self.sums.push(accel, gyro);
        self.pushed += 1;
        self.untested.push_back(Waiting {
            t,
            payload,
            statistics: Statistics::default(),
            thresholds: self.config.thresholds,
            still: false,
        });
        // The window now ends at the newest sample: it is centred on the
        // sample `lookahead` back, once that exists.
        let ahead = lookahead(self.config.window_samples) as u64;
        if self.pushed > ahead {
            self.test_oldest(earth_rate_b, out);
        }
    }

    /// Decides every waiting sample with the data there is (end of stream,
    /// or a gap before a new one); the next push starts a new stream.
    pub fn flush(&mut self, earth_rate_b: &V3, out: &mut Vec<(T, Decision)>) {
        let behind = self.config.window_samples - 1 - lookahead(self.config.window_samples);
        while !self.untested.is_empty() {
            // Truncated at the end: drop samples older than the window's
            // trailing edge for this centre.
            let window_start = self.tested.saturating_sub(behind as u64);
            let held_from = self.pushed - self.sums.len() as u64;
            for _ in held_from..window_start {
                self.sums.pop_oldest();
            }
            self.test_oldest(earth_rate_b, out);
        }
        while !self.unfiltered.is_empty() {
            self.filter_oldest(out);
        }
        self.release_run(false, out);
        self.sums.clear();
        self.pushed = 0;
        self.tested = 0;
        self.filtered = 0;
        self.median_window.clear();
        self.median_still = 0;
        self.run_confirmed = false;
    }

    fn test_oldest(&mut self, earth_rate_b: &V3, out: &mut Vec<(T, Decision)>) {
        let Some(mut sample) = self.untested.pop_front() else {
            return;
        };
        if let Some(statistics) =
            self.sums
                .statistics(earth_rate_b, &self.config.noise, self.config.signals)
        {
            sample.statistics = statistics;
        }
        if let (Some(adaptation), Some(level)) = (&self.config.adaptation, &mut self.rest_level) {
            level.observe(sample.t, &sample.statistics, adaptation);
            sample.thresholds = level.thresholds(&self.config.thresholds, adaptation);
        }
        sample.still = self.config.is_still(&sample.statistics, &sample.thresholds);
        self.tested += 1;
        self.median_window.push_back(sample.still);
        self.median_still += usize::from(sample.still);
        self.unfiltered.push_back(sample);
        let ahead = lookahead(self.config.median_samples) as u64;
        if self.tested > ahead {
            self.filter_oldest(out);
        }
    }

    /// Gives the oldest tested sample its median decision.
    fn filter_oldest(&mut self, out: &mut Vec<(T, Decision)>) {
        let len = self.config.median_samples.max(1);
        let behind = (len - 1 - lookahead(len)) as u64;
        // The median window for sample `filtered` is [filtered − behind,
        // filtered + ahead], truncated to the samples tested.
        let window_start = self.filtered.saturating_sub(behind);
        let held_from = self.tested - self.median_window.len() as u64;
        for _ in held_from..window_start {
            if let Some(still) = self.median_window.pop_front() {
                self.median_still -= usize::from(still);
            }
        }
        let Some(sample) = self.unfiltered.pop_front() else {
            return;
        };
        self.filtered += 1;
        let zv = 2 * self.median_still > self.median_window.len();
        self.minimum_run(sample, zv, out);
    }

    fn minimum_run(&mut self, sample: Waiting<T>, zv: bool, out: &mut Vec<(T, Decision)>) {
        if !zv {
            self.release_run(false, out);
            self.run_confirmed = false;
            out.push(decided(sample, false));
            return;
        }
        if self.run_confirmed {
            out.push(decided(sample, true));
            return;
        }
        let start = self.run.front().map_or(sample.t, |first| first.t);
        let long_enough = sample.t - start >= self.config.min_run_s;
        self.run.push_back(sample);
        if long_enough {
            self.run_confirmed = true;
            self.release_run(true, out);
        }
    }

    fn release_run(&mut self, zv: bool, out: &mut Vec<(T, Decision)>) {
        out.extend(self.run.drain(..).map(|s| decided(s, zv)));
    }
}

fn decided<T>(sample: Waiting<T>, zv: bool) -> (T, Decision) {
    (
        sample.payload,
        Decision {
            zv,
            still: sample.still,
            statistics: sample.statistics,
            thresholds: sample.thresholds,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(window: usize, median: usize, min_run_s: f64) -> PipelineConfig {
        PipelineConfig {
            detector: DetectorKind::Mv,
            thresholds: Thresholds {
                mv: 5.0,
                are: 5.0,
                shoe: 5.0,
                mag: 5.0,
            },
            noise: DetectorNoise {
                sigma_accel_mps2: 0.01,
                sigma_gyro_rad_per_s: 0.001,
                gravity_mps2: 9.8,
            },
            signals: Signals::Raw,
            adaptation: None,
            window_samples: window,
            median_samples: median,
            min_run_s,
        }
    }

    /// Feeds samples that are still except where `moving(k)`, at 100 Hz.
    fn run(
        config: PipelineConfig,
        n: usize,
        moving: impl Fn(usize) -> bool,
    ) -> Vec<(usize, Decision)> {
        let mut pipeline = ZeroVelocityPipeline::new(config);
        let mut out = Vec::new();
        let mut max_waiting = 0;
        for k in 0..n {
            let jolt = if moving(k) {
                if k % 2 == 0 { 0.5 } else { -0.5 }
            } else {
                0.0
            };
            pipeline.push(
                k as f64 * 0.01,
                V3::new(jolt, 0.0, -9.8),
                V3::zeros(),
                k,
                &V3::zeros(),
                &mut out,
            );
            max_waiting = max_waiting.max(pipeline.waiting());
        }
        // Latency bound: lookahead + the minimum run.
        let bound = config.lookahead_samples() + (config.min_run_s * 100.0).ceil() as usize + 2;
        assert!(max_waiting <= bound, "{max_waiting} > {bound}");
        pipeline.flush(&V3::zeros(), &mut out);
        let order: Vec<usize> = out.iter().map(|(k, _)| *k).collect();
        assert_eq!(
            order,
            (0..n).collect::<Vec<_>>(),
            "every sample once, in order"
        );
        out
    }

    #[test]
    fn rests_are_detected_and_motion_is_not() {
        // Still 0–4 s, moving 4–6 s, still 6–10 s.
        let out = run(config(20, 20, 1.0), 1000, |k| (400..600).contains(&k));
        for (k, d) in &out {
            let near_edge = (380..420).contains(k) || (580..620).contains(k);
            if !near_edge {
                assert_eq!(d.zv, !(400..600).contains(k), "sample {k}");
            }
            if (400..600).contains(k) {
                assert!(!d.zv, "false zero velocity at {k}");
            }
        }
    }

    #[test]
    fn short_rests_are_not_zero_velocity() {
        // A 0.5 s pause inside motion is shorter than the 1 s minimum run.
        let out = run(config(10, 10, 1.0), 600, |k| !(300..350).contains(&k));
        assert!(out.iter().all(|(_, d)| !d.zv));
        // With a 0.2 s minimum it counts.
        let out = run(config(10, 10, 0.2), 600, |k| !(300..350).contains(&k));
        assert!(out.iter().any(|(_, d)| d.zv));
    }

    #[test]
    fn the_median_removes_isolated_blips() {
        // One jolt in every 5 samples makes the test over pairs (W = 2)
        // flicker, 2 moving in 5; the median of 9 holds zero velocity.
        let out = run(config(2, 9, 0.5), 500, |k| k % 5 == 0);
        let zv = out.iter().filter(|(_, d)| d.zv).count();
        assert!(zv > 480, "{zv}");
        let unfiltered = run(config(2, 1, 0.5), 500, |k| k % 5 == 0);
        assert!(unfiltered.iter().all(|(_, d)| !d.zv));
    }

    #[test]
    fn a_run_at_the_end_of_a_stream_that_never_reached_the_minimum_counts_as_moving() {
        let out = run(config(10, 10, 3.0), 300, |k| k < 150);
        assert!(out.iter().all(|(_, d)| !d.zv));
    }

    #[test]
    fn none_never_declares_zero_velocity() {
        let mut c = config(10, 10, 0.1);
        c.detector = DetectorKind::None;
        let out = run(c, 300, |_| false);
        assert!(out.iter().all(|(_, d)| !d.zv && !d.still));
    }

    #[test]
    fn the_rest_level_lifts_the_thresholds_within_bounds() {
        let adaptation = Adaptation {
            rest_level_factor: 4.0,
            max_factor: 5.0,
            rise_s: 100.0,
        };
        let base = config(10, 1, 0.0).thresholds; // γ = 5
        let mut level = RestLevel::new(&base, &adaptation);
        assert_eq!(level.thresholds(&base, &adaptation), base);
        let at = |mv: f64| Statistics {
            mv,
            are: 1.0,
            shoe: 1.0,
            mag: 1.0,
            mean_accel_mps2: V3::zeros(),
        };
        // Every sample above: the level rises by e per 100 s. From 5/4,
        // 100 s later it is 1.25·e = 3.4, the threshold 13.6.
        for k in 0..=10_000 {
            level.observe(k as f64 * 0.01, &at(50.0), &adaptation);
        }
        let lifted = level.thresholds(&base, &adaptation);
        assert!(
            (lifted.mv - 4.0 * 1.25 * 1f64.exp()).abs() < 0.05,
            "{lifted:?}"
        );
        // A statistic always below its level pulls it down (never below γ).
        assert_eq!(lifted.are, 5.0);
        // Never above m·γ, however long.
        for k in 10_001..200_000 {
            level.observe(k as f64 * 0.01, &at(50.0), &adaptation);
        }
        assert_eq!(level.thresholds(&base, &adaptation).mv, 25.0);
        // Quiet again: it falls twenty times as fast as it rose.
        for k in 200_000..205_000 {
            level.observe(k as f64 * 0.01, &at(1.0), &adaptation);
        }
        assert_eq!(level.thresholds(&base, &adaptation).mv, 5.0);
    }
}
