//! The motion-status expert: three signals from a short trailing window of
//! IMU readings, fuzzified and combined by a Mamdani rule base into a
//! degree of "static" in [0, 1].
//!
//! Inputs (each with terms `low`, `medium`, `high`; the engine divides
//! each by its sensor's learnt noise floor before inference, so the
//! breakpoints are multiples of the floor):
//! - `accel_dev`: |mean ‖f‖ − g_ref|, the window's specific-force norm
//!   against the norm learnt while static (sustained acceleration, braking);
//! - `accel_activity`: √(mean ‖fᵢ − f̄‖²), the window's specific-force
//!   spread (vibration, jerk, bumps);
//! - `gyro_activity`: √(s² + e²), s the rate's fast spread, about a cubic
//!   in time fitted over the window (shaking; a slow sway of a standing
//!   body, 0.1–1 Hz, is nearly a cubic over half a second and leaves
//!   little: fast_spread.rs), and e the mean rate's distance from the
//!   bias, ‖ω̄ − b̂‖, beyond what the bias's own uncertainty and the wander
//!   of the mean rate at rest allow (turns; a bias that drifted while
//!   driving does not make a stop "moving").
//!
//! Rules (output `static_degree` with terms `moving`, `uncertain`, `static`):
//! 1. IF accel_dev is low AND accel_activity is low AND gyro_activity is low
//!    THEN static
//! 2. IF accel_dev is high OR accel_activity is high OR gyro_activity is high
//!    THEN moving
//! 3. IF (accel_dev is medium OR accel_activity is medium OR gyro_activity is
//!    medium) AND NOT (any is high) THEN uncertain
//!
//! The output terms are triangles centred on 0, 0.5 and 1 with half-width
//! 0.5 over the range [−0.5, 1.5], so one rule firing alone gives exactly
//! 0, 0.5 or 1; the result is clamped to [0, 1].

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use super::fast_spread::{TrendMoments, scaled_gram_inverse};
use super::mamdani::{Antecedent, FuzzyError, Mamdani, Membership, Rule, Scratch, Variable};
use crate::fusion::geometry::V3;

/// Where each input's terms change: `low` falls from 1 at `still` to 0 at
/// `moving`, `high` rises over the same span, `medium` peaks midway.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Breakpoints {
    pub still: f64,
    pub moving: f64,
}

/// The three inputs' breakpoints, as multiples of the noise floors the
/// engine learns (the inputs are divided by them before inference).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MotionConfig {
    pub accel_dev: Breakpoints,
    pub accel_activity: Breakpoints,
    pub gyro_activity: Breakpoints,
    /// Output discretisation (points over [−0.5, 1.5], ends included).
    pub resolution: usize,
}

fn three_terms(name: &str, b: Breakpoints) -> Variable {
    let mid = 0.5 * (b.still + b.moving);
    Variable::new(
        name,
        0.0,
        f64::INFINITY,
        &[
            (
                "low",
                Membership::Trapezoidal {
                    a: f64::NEG_INFINITY,
                    b: f64::NEG_INFINITY,
                    c: b.still,
                    d: b.moving,
                },
            ),
            (
                "medium",
                Membership::Triangular {
                    a: b.still,
                    b: mid,
                    c: b.moving,
                },
            ),
            (
                "high",
                Membership::Trapezoidal {
                    a: b.still,
                    b: b.moving,
                    c: f64::INFINITY,
                    d: f64::INFINITY,
                },
            ),
        ],
    )
}

/// The rule base of the module documentation as a [`Mamdani`] system.
pub fn motion_expert(config: &MotionConfig) -> Result<Mamdani, FuzzyError> {
    let inputs = vec![
        three_terms("accel_dev", config.accel_dev),
        three_terms("accel_activity", config.accel_activity),
        three_terms("gyro_activity", config.gyro_activity),
    ];
    let output = Variable::new(
        "static_degree",
        -0.5,
        1.5,
        &[
            (
                "moving",
                Membership::Triangular {
                    a: -0.5,
                    b: 0.0,
                    c: 0.5,
                },
            ),
            (
                "uncertain",
                Membership::Triangular {
                    a: 0.0,
                    b: 0.5,
                    c: 1.0,
                },
            ),
            (
                "static",
                Membership::Triangular {
                    a: 0.5,
                    b: 1.0,
                    c: 1.5,
                },
            ),
        ],
    );
    let (low, medium, high) = (0, 1, 2);
    let all = |term: usize| -> Vec<Antecedent> {
        (0..3).map(|input| Antecedent::Is { input, term }).collect()
    };
    let rules = vec![
        Rule {
            antecedent: Antecedent::And(all(low)),
            term: output.term("static")?,
        },
        Rule {
            antecedent: Antecedent::Or(all(high)),
            term: output.term("moving")?,
        },
        Rule {
            antecedent: Antecedent::And(vec![
                Antecedent::Or(all(medium)),
                Antecedent::Not(Box::new(Antecedent::Or(all(high)))),
            ]),
            term: output.term("uncertain")?,
        },
    ];
    Mamdani::new(inputs, output, rules, config.resolution)
}

/// The expert's inputs for one window.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct MotionSignals {
    pub accel_dev_mps2: f64,
    pub accel_activity_mps2: f64,
    pub gyro_activity_rad_per_s: f64,
}

/// The static degree where it is decided by the breakpoints alone: 1
/// when every input is fully `low` (rule 1 alone fires, fully), 0 when
/// one is fully `high` (rule 2 alone fires); `None` in between, where the
/// expert must infer. Most readings are one or the other, so the engine
/// spares the centroid there.
pub fn decided_by_breakpoints(config: &MotionConfig, signals: &MotionSignals) -> Option<f64> {
    let inputs = [
        (signals.accel_dev_mps2, config.accel_dev),
        (signals.accel_activity_mps2, config.accel_activity),
        (signals.gyro_activity_rad_per_s, config.gyro_activity),
    ];
    if inputs.iter().any(|(x, b)| *x >= b.moving) {
        Some(0.0)
    } else if inputs.iter().all(|(x, b)| *x <= b.still) {
        Some(1.0)
    } else {
        None
    }
}

/// Runs the expert; `None` only if no rule fires (cannot happen with the
/// built-in rule base, whose three rules cover every input).
pub fn static_degree(
    expert: &Mamdani,
    signals: &MotionSignals,
    scratch: &mut Scratch,
) -> Option<f64> {
    let values = [
        signals.accel_dev_mps2,
        signals.accel_activity_mps2,
        signals.gyro_activity_rad_per_s,
    ];
    expert
        .infer_with(&values, scratch)
        .ok()
        .flatten()
        .map(|s| s.clamp(0.0, 1.0))
}

/// Fewest readings a full window needs for its fast spread (fast_spread.rs):
/// a cubic through fewer leaves too little to judge (8 degrees of freedom
/// per axis at 12).
pub const MIN_FAST_SPREAD_READINGS: usize = 12;

/// Running sums over the newest `capacity` IMU readings, O(1) per reading.
/// The sums are recomputed from the held readings once per `capacity`
/// pushes so rounding cannot accumulate over a long run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionWindow {
    capacity: usize,
    samples: VecDeque<(V3, V3)>,
    sum_force: V3,
    sum_force_sq: f64,
    sum_force_norm: f64,
    sum_rate: V3,
    sum_rate_sq: f64,
    /// Σ j^k·ω, k = 1 … 3, of the rates (fast_spread.rs).
    rate_trend: TrendMoments,
    /// The fit's G⁻¹ for a full window (fast_spread.rs): derived from the
    /// capacity, not stored ([`MotionWindow::prepared`] after a restore).
    #[serde(skip)]
    full_gram_inverse: Option<nalgebra::Matrix4<f64>>,
    pushes_since_refresh: usize,
}

impl MotionWindow {
    /// An empty window of `capacity` readings (at least 1).
    pub fn new(capacity: usize) -> MotionWindow {
        MotionWindow {
            capacity: capacity.max(1),
            samples: VecDeque::with_capacity(capacity.max(1)),
            sum_force: V3::zeros(),
            sum_force_sq: 0.0,
            sum_force_norm: 0.0,
            sum_rate: V3::zeros(),
            sum_rate_sq: 0.0,
            rate_trend: TrendMoments::default(),
            full_gram_inverse: scaled_gram_inverse(capacity.max(1)),
            pushes_since_refresh: 0,
        }
    }

    /// Forgets every reading (after a gap).
    pub fn clear(&mut self) {
        *self = MotionWindow::new(self.capacity);
    }

    /// Readings the window holds when full.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Readings held.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// True when no reading is held.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// True once `capacity` readings are held.
    pub fn is_full(&self) -> bool {
        self.samples.len() == self.capacity
    }

    /// Adds a reading (specific force m/s², rate rad/s), dropping the oldest.
    pub fn push(&mut self, force: V3, rate: V3) {
        if self.samples.len() == self.capacity
            && let Some((old_f, old_w)) = self.samples.pop_front()
        {
            self.sum_force -= old_f;
            self.sum_force_sq -= old_f.norm_squared();
            self.sum_force_norm -= old_f.norm();
            self.sum_rate -= old_w;
            self.sum_rate_sq -= old_w.norm_squared();
            self.rate_trend.shift(&self.sum_rate);
        }
        let place = self.samples.len();
        self.rate_trend.push(place, &rate);
        self.samples.push_back((force, rate));
        self.sum_force += force;
        self.sum_force_sq += force.norm_squared();
        self.sum_force_norm += force.norm();
        self.sum_rate += rate;
        self.sum_rate_sq += rate.norm_squared();
        self.pushes_since_refresh += 1;
        if self.pushes_since_refresh >= self.capacity {
            self.refresh();
        }
    }

    fn refresh(&mut self) {
        self.pushes_since_refresh = 0;
        self.sum_force = V3::zeros();
        self.sum_force_sq = 0.0;
        self.sum_force_norm = 0.0;
        self.sum_rate = V3::zeros();
        self.sum_rate_sq = 0.0;
        self.rate_trend = TrendMoments::recompute(self.samples.iter().map(|(_, w)| w));
        for (f, w) in &self.samples {
            self.sum_force += f;
            self.sum_force_sq += f.norm_squared();
            self.sum_force_norm += f.norm();
            self.sum_rate += w;
            self.sum_rate_sq += w.norm_squared();
        }
    }

    /// Mean specific force, m/s².
    pub fn mean_force(&self) -> V3 {
        self.sum_force / self.samples.len().max(1) as f64
    }

    /// Mean angular rate, rad/s.
    pub fn mean_rate(&self) -> V3 {
        self.sum_rate / self.samples.len().max(1) as f64
    }

    /// Mean specific-force norm, m/s².
    pub fn mean_force_norm(&self) -> f64 {
        self.sum_force_norm / self.samples.len().max(1) as f64
    }

    /// √(mean ‖f − f̄‖²): the specific-force spread, m/s².
    pub fn force_spread(&self) -> f64 {
        let n = self.samples.len().max(1) as f64;
        (self.sum_force_sq / n - self.mean_force().norm_squared())
            .max(0.0)
            .sqrt()
    }

    /// √(mean ‖ω − b‖²) for a bias `b`, rad/s.
    pub fn rate_rms(&self, bias: &V3) -> f64 {
        let n = self.samples.len().max(1) as f64;
        let mean_sq =
            self.sum_rate_sq / n - 2.0 * bias.dot(&self.sum_rate) / n + bias.norm_squared();
        mean_sq.max(0.0).sqrt()
    }

    /// √(mean ‖ω − ω̄‖²): the rate spread, whatever the bias, rad/s.
    pub fn rate_spread(&self) -> f64 {
        let n = self.samples.len().max(1) as f64;
        (self.sum_rate_sq / n - self.mean_rate().norm_squared())
            .max(0.0)
            .sqrt()
    }

    /// The rate's spread about a cubic in time fitted over a full window
    /// of at least [`MIN_FAST_SPREAD_READINGS`] (fast_spread.rs): shaking,
    /// not a slow sway, rad/s. Until then, the plain spread: a cubic
    /// through a few readings takes out nearly everything, fast or slow.
    pub fn fast_rate_spread(&self) -> f64 {
        let n = self.samples.len();
        if n < self.capacity || n < MIN_FAST_SPREAD_READINGS {
            return self.rate_spread();
        }
        self.rate_trend.fast_spread(
            n,
            &self.sum_rate,
            self.sum_rate_sq,
            self.full_gram_inverse.as_ref(),
        )
    }

    /// The window after a restore, with what it derives from its capacity.
    pub fn prepared(mut self) -> MotionWindow {
        self.full_gram_inverse = scaled_gram_inverse(self.capacity);
        self
    }

    /// The expert's inputs, against the static norm `gravity_mps2`, the
    /// gyro bias `bias` and how far the mean rate may be off it at rest,
    /// `rate_tolerance` (rad/s): the rate's fast spread and the mean rate's
    /// excess over the tolerance, √(spread² + max(0, ‖ω̄ − b‖ − tol)²).
    pub fn signals(&self, gravity_mps2: f64, bias: &V3, rate_tolerance: f64) -> MotionSignals {
        let excess = ((self.mean_rate() - bias).norm() - rate_tolerance).max(0.0);
        MotionSignals {
            accel_dev_mps2: (self.mean_force_norm() - gravity_mps2).abs(),
            accel_activity_mps2: self.force_spread(),
            gyro_activity_rad_per_s: self.fast_rate_spread().hypot(excess),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> MotionConfig {
        MotionConfig {
            accel_dev: Breakpoints {
                still: 0.05,
                moving: 0.25,
            },
            accel_activity: Breakpoints {
                still: 0.05,
                moving: 0.2,
            },
            gyro_activity: Breakpoints {
                still: 0.005,
                moving: 0.03,
            },
            resolution: 201,
        }
    }

    fn degree(signals: MotionSignals) -> f64 {
        let expert = motion_expert(&config()).unwrap();
        static_degree(&expert, &signals, &mut Scratch::default()).unwrap()
    }

    #[test]
    fn rule_base_gives_one_zero_and_a_half_at_its_corners() {
        let still = MotionSignals {
            accel_dev_mps2: 0.01,
            accel_activity_mps2: 0.02,
            gyro_activity_rad_per_s: 0.001,
        };
        assert!((degree(still) - 1.0).abs() < 1e-9);
        let shaking = MotionSignals {
            accel_activity_mps2: 0.5,
            ..still
        };
        assert!(degree(shaking).abs() < 1e-9);
        let turning = MotionSignals {
            gyro_activity_rad_per_s: 0.1,
            ..still
        };
        assert!(degree(turning).abs() < 1e-9);
        // Exactly midway on one input: low 0.5, medium 1, high 0.5 → the
        // three rules fire 0.5 (static), 0.5 (moving), 0.5 (uncertain):
        // the symmetric aggregate's centroid is 0.5.
        let midway = MotionSignals {
            accel_dev_mps2: 0.15,
            ..still
        };
        assert!((degree(midway) - 0.5).abs() < 1e-9);
    }

    #[test]
    fn the_breakpoint_shortcut_agrees_with_the_expert() {
        let expert = motion_expert(&config()).unwrap();
        let mut decided = 0;
        for i in 0..=40 {
            for j in 0..=40 {
                let signals = MotionSignals {
                    accel_dev_mps2: 0.01 * f64::from(i),
                    accel_activity_mps2: 0.006 * f64::from(j),
                    gyro_activity_rad_per_s: 0.001 * f64::from((i * j) % 41),
                };
                let inferred = static_degree(&expert, &signals, &mut Scratch::default()).unwrap();
                if let Some(s) = decided_by_breakpoints(&config(), &signals) {
                    decided += 1;
                    assert!(
                        (s - inferred).abs() < 1e-9,
                        "{signals:?}: {s} vs {inferred}"
                    );
                }
            }
        }
        assert!(decided > 400, "{decided}");
    }

    #[test]
    fn static_degree_falls_as_activity_rises() {
        let mut previous = f64::INFINITY;
        for i in 0..=40 {
            let activity = 0.005 * f64::from(i);
            let s = degree(MotionSignals {
                accel_dev_mps2: 0.0,
                accel_activity_mps2: activity,
                gyro_activity_rad_per_s: 0.0,
            });
            assert!((0.0..=1.0).contains(&s));
            assert!(s <= previous + 1e-12, "{activity}: {s} > {previous}");
            previous = s;
        }
        assert!(previous < 1e-9);
    }

    #[test]
    fn the_discretisation_moves_the_static_degree_only_slightly() {
        // 201 points (the default) against 20 001 over the inputs' span:
        // the centroid moves by less than 10⁻⁴ (docs/engines/fuzzy.md: discretisation).
        let coarse = motion_expert(&config()).unwrap();
        let fine = motion_expert(&MotionConfig {
            resolution: 20_001,
            ..config()
        })
        .unwrap();
        let mut worst = 0.0_f64;
        for i in 0..=30 {
            for j in 0..=30 {
                let signals = MotionSignals {
                    accel_dev_mps2: 0.01 * f64::from(i),
                    accel_activity_mps2: 0.008 * f64::from(j),
                    gyro_activity_rad_per_s: 0.001 * f64::from((i + j) % 31),
                };
                let a = static_degree(&coarse, &signals, &mut Scratch::default()).unwrap();
                let b = static_degree(&fine, &signals, &mut Scratch::default()).unwrap();
                worst = worst.max((a - b).abs());
            }
        }
        eprintln!("largest difference: {worst}");
        assert!(worst < 1e-4, "{worst}");
        assert!(worst > 0.0, "the discretisation should show");
    }

    #[test]
    fn a_window_not_yet_full_takes_the_plain_spread() {
        let mut window = MotionWindow::new(20);
        for i in 0..10 {
            let x = f64::from(i);
            window.push(V3::new(0.0, 0.0, -9.8), V3::new((x * 2.1).sin(), 0.0, 0.0));
        }
        assert_eq!(window.fast_rate_spread(), window.rate_spread());
        // A window of fewer readings than a cubic can judge, full or not.
        let mut short = MotionWindow::new(MIN_FAST_SPREAD_READINGS - 1);
        for i in 0..30 {
            short.push(V3::zeros(), V3::new(f64::from(i % 3), 0.0, 0.0));
        }
        assert!(short.is_full());
        assert_eq!(short.fast_rate_spread(), short.rate_spread());
    }

    #[test]
    fn window_sums_match_a_direct_computation() {
        let mut window = MotionWindow::new(15);
        let mut all = Vec::new();
        for i in 0..50 {
            let x = f64::from(i);
            let f = V3::new((x * 0.7).sin(), 0.1 * x.cos(), -9.8 + 0.01 * x);
            let w = V3::new(0.01 * x.sin(), -0.02, 0.003 * x);
            window.push(f, w);
            all.push((f, w));
        }
        let held = &all[all.len() - 15..];
        let bias = V3::new(0.001, -0.01, 0.02);
        let mean_f = held.iter().map(|s| s.0).sum::<V3>() / 15.0;
        let mean_norm = held.iter().map(|s| s.0.norm()).sum::<f64>() / 15.0;
        let spread = (held
            .iter()
            .map(|s| (s.0 - mean_f).norm_squared())
            .sum::<f64>()
            / 15.0)
            .sqrt();
        // The rates' fast spread: residuals of a cubic in the reading's
        // place, fitted per axis by least squares (an SVD, not the
        // window's moments).
        let places = nalgebra::DMatrix::from_fn(15, 4, |j, k| (j as f64).powi(k as i32));
        let svd = places.clone().svd(true, true);
        let mut residual_sq = 0.0;
        for axis in 0..3 {
            let y = nalgebra::DVector::from_iterator(15, held.iter().map(|s| s.1[axis]));
            let fit = svd.solve(&y, 1e-12).unwrap();
            residual_sq += (&y - &places * fit).norm_squared();
        }
        // On the plain spread's scale: RSS·(n − 1)/(n·(n − 4)).
        let fast_spread = (residual_sq * 14.0 / (15.0 * 11.0)).sqrt();
        assert!((window.fast_rate_spread() - fast_spread).abs() < 1e-12);
        let mean_w = held.iter().map(|s| s.1).sum::<V3>() / 15.0;
        let offset = (mean_w - bias).norm();
        let signals = window.signals(9.8, &bias, 0.0);
        assert!((signals.accel_dev_mps2 - (mean_norm - 9.8).abs()).abs() < 1e-12);
        assert!((signals.accel_activity_mps2 - spread).abs() < 1e-9);
        assert!((signals.gyro_activity_rad_per_s - fast_spread.hypot(offset)).abs() < 1e-12);
        // Within the tolerance the mean rate's offset does not count; past
        // it, only its excess.
        let loose = window.signals(9.8, &bias, 2.0 * offset);
        assert!((loose.gyro_activity_rad_per_s - fast_spread).abs() < 1e-12);
        let half = window.signals(9.8, &bias, 0.5 * offset);
        let expected = fast_spread.hypot(0.5 * offset);
        assert!((half.gyro_activity_rad_per_s - expected).abs() < 1e-12);
    }
}
