//! The sensors' noise floor, learned from the data: a low quantile of the
//! motion window's spreads, so every activity threshold of the expert is a
//! multiple of what this particular IMU shows at rest (docs/engines/fuzzy.md:
//! no sensor-specific constants).
//!
//! Each floor follows the `QUANTILE` of its statistic x by the
//! multiplicative stochastic approximation
//!   L ← L · exp((q − 1[x < L]) · dt / (q · T_rise)),
//! which falls e-fold in T_rise·q/(1 − q) seconds of quieter windows and
//! rises e-fold in T_rise seconds of louder ones: a stop of a few seconds
//! finds the floor again. While the vehicle rolls (rolling.rs) the engine
//! lets the floor only rise, a hundred times slower: floors come from rest, and
//! a rest louder than the floors is found in time. The
//! first value taken starts it, so alignment can use it at once, and the
//! engine lowers it to the window it aligns on ([`Floor::lower_to`]).

use serde::{Deserialize, Serialize};

/// The quantile followed: the floor sits below nearly every quiet window,
/// and falls e-fold in about T_rise/100 (3 s for 300 s): the first still
/// spell after a long motion finds it within seconds.
const QUANTILE: f64 = 0.01;
/// Largest step taken, s: a gap in the readings does not count as time.
const MAX_STEP_S: f64 = 1.0;

/// One statistic's floor.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Floor {
    level: Option<f64>,
    t: Option<f64>,
}

impl Floor {
    /// No value seen yet.
    pub const fn new() -> Floor {
        Floor {
            level: None,
            t: None,
        }
    }

    /// The floor, once a value has been seen.
    pub fn level(&self) -> Option<f64> {
        self.level
    }

    /// Takes the statistic `value` at time `t`; `rise_s` is T_rise.
    pub fn observe(&mut self, t: f64, value: f64, rise_s: f64) {
        if !value.is_finite() || value < 0.0 {
            return;
        }
        let dt_s = self.t.map_or(0.0, |last| (t - last).clamp(0.0, MAX_STEP_S));
        self.t = Some(t);
        let value = value.max(f64::MIN_POSITIVE);
        let Some(level) = self.level else {
            self.level = Some(value);
            return;
        };
        let below = if value < level { 1.0 } else { 0.0 };
        let step = (QUANTILE - below) * dt_s / (QUANTILE * rise_s);
        // Never past the value that moved it: a single quiet window pulls
        // the floor down to itself, not beyond.
        let moved = level * step.exp();
        self.level = Some(if below > 0.0 {
            moved.max(value)
        } else {
            moved.min(value)
        });
    }
}

impl Floor {
    /// Takes `value` as the floor if it is lower (a window known quiet).
    pub fn lower_to(&mut self, value: f64) {
        if value.is_finite() && value >= 0.0 {
            let value = value.max(f64::MIN_POSITIVE);
            self.level = Some(self.level.map_or(value, |level| level.min(value)));
        }
    }
}

impl Floor {
    /// While the vehicle rolls: only the rise of [`Floor::observe`], at
    /// T_rise `rise_s` (the engine takes a hundred times the floor's own), so a
    /// rest louder than every rest before (an engine started after the
    /// floors were learnt with it off) is found again in time, while a
    /// drive of minutes lifts the floor by a few per cent only.
    pub fn observe_rising(&mut self, t: f64, value: f64, rise_s: f64) {
        if self.level.is_some_and(|level| value < level) {
            self.t = Some(t);
            return;
        }
        self.observe(t, value, rise_s);
    }

    /// Takes `value` as the floor if it is higher (a window known at rest
    /// by events, louder than the rests the floor was learnt at).
    pub fn raise_to(&mut self, value: f64) {
        if value.is_finite() && value >= 0.0 {
            let value = value.max(f64::MIN_POSITIVE);
            self.level = Some(self.level.map_or(value, |level| level.max(value)));
        }
    }
}

impl Default for Floor {
    fn default() -> Self {
        Floor::new()
    }
}

/// The floors of the accelerometer's and the gyro's window spreads.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct NoiseFloor {
    /// Specific-force spread √(mean ‖fᵢ − f̄‖²), m/s².
    pub accel: Floor,
    /// The rate's fast spread about a cubic in time (fast_spread.rs), rad/s.
    pub gyro: Floor,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_floor_starts_at_the_first_value_and_falls_to_a_quieter_one() {
        let mut floor = Floor::new();
        floor.observe(0.0, 2.0, 100.0);
        assert_eq!(floor.level(), Some(2.0));
        // Falling: e-fold per T·q/(1 − q) = 100·0.01/0.99 s, so 0.01 s
        // of a value far below takes it to 2·exp(−0.0099).
        floor.observe(0.01, 0.001, 100.0);
        let expected = 2.0 * (-0.0099_f64).exp();
        assert!((floor.level().unwrap() - expected).abs() < 1e-12);
        // Rising: e-fold per 100 s: 10 s louder multiplies by exp(0.1).
        let before = floor.level().unwrap();
        for i in 1..=1000 {
            floor.observe(0.01 + f64::from(i) * 0.01, 50.0, 100.0);
        }
        assert!((floor.level().unwrap() / before - 0.1_f64.exp()).abs() < 1e-9);
    }

    #[test]
    fn the_floor_sits_at_the_low_quantile_of_a_noisy_statistic() {
        // Uniform on [1, 2] (a deterministic shuffle): the 1 % quantile is 1.01.
        let mut floor = Floor::new();
        let mut x = 0.5_f64;
        for i in 0..400_000 {
            x = (x * 997.0 + 0.123_456_7).fract();
            floor.observe(f64::from(i) * 0.01, 1.0 + x, 60.0);
        }
        let level = floor.level().unwrap();
        assert!((level - 1.01).abs() < 0.01, "{level}");
    }

    #[test]
    fn while_rolling_the_floor_only_rises() {
        let mut floor = Floor::new();
        floor.observe(0.0, 1.0, 10.0);
        // Quieter windows while rolling do not lower it.
        for i in 1..=100 {
            floor.observe_rising(f64::from(i) * 0.01, 0.1, 100.0);
        }
        assert_eq!(floor.level(), Some(1.0));
        // Louder ones lift it e-fold per rise_s: 1 s of them at 100 s.
        for i in 101..=200 {
            floor.observe_rising(f64::from(i) * 0.01, 50.0, 100.0);
        }
        assert!((floor.level().unwrap() - 0.01_f64.exp()).abs() < 1e-9);
    }

    #[test]
    fn a_gap_or_a_bad_value_does_not_move_it() {
        let mut floor = Floor::new();
        floor.observe(0.0, 1.0, 10.0);
        floor.observe(0.1, f64::NAN, 10.0);
        floor.observe(0.2, -1.0, 10.0);
        assert_eq!(floor.level(), Some(1.0));
        // A quiet value after a long gap counts as 1 s, and never beyond itself.
        floor.observe(1000.0, 0.5, 10.0);
        assert_eq!(floor.level(), Some(0.5));
    }
}
