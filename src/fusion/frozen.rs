//! A frozen sensor (issue 54): a gateway that re-sends a stale register,
//! a sensor that hangs. A live sensor's noise makes two readings identical
//! (every value, to the last bit) only as often as its resolution allows;
//! the watch learns that share p from the readings themselves and calls a
//! run of k identical readings frozen once pᵏ < [`FROZEN_PROBABILITY`]
//! (and k ≥ [`MIN_FROZEN_RUN`]). Used by the `attitude` engine's
//! inclinometer monitor and the `zupt` engine's IMU screen.

use serde::{Deserialize, Serialize};

/// A run of identical readings this improbable for the sensor is frozen.
pub const FROZEN_PROBABILITY: f64 = 1e-6;
/// The shortest run called frozen (readings identical to the first).
pub const MIN_FROZEN_RUN: u32 = 3;

/// What the watch remembers of a sensor whose readings are `V`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FrozenWatch<V> {
    /// The previous reading's values, as sent.
    last: Option<V>,
    /// Consecutive pairs of readings seen live, and of them identical.
    pairs: u64,
    repeats: u64,
    /// Readings identical to the one before, in a row now.
    repeat_run: u32,
    /// When the current frozen stretch began (the last live reading's t).
    frozen_from_t: Option<f64>,
    live_t: Option<f64>,
}

impl<V: PartialEq + Copy> FrozenWatch<V> {
    /// The shortest run of identical readings called frozen, from the
    /// share of identical pairs seen so far (Laplace's rule: one repeat
    /// in two pairs before any are seen).
    pub fn frozen_run(&self) -> u32 {
        let p = (self.repeats as f64 + 1.0) / (self.pairs as f64 + 2.0);
        let run = (FROZEN_PROBABILITY.ln() / p.ln()).ceil();
        if run.is_finite() {
            (run as u32).max(MIN_FROZEN_RUN)
        } else {
            u32::MAX
        }
    }

    /// A reading at `t` of `values`: whether the sensor is frozen.
    pub fn is_frozen(&mut self, t: f64, values: V) -> bool {
        let same = self.last == Some(values);
        self.last = Some(values);
        self.repeat_run = if same { self.repeat_run + 1 } else { 0 };
        if self.repeat_run >= self.frozen_run() {
            self.frozen_from_t.get_or_insert(self.live_t.unwrap_or(t));
            return true;
        }
        if self.frozen_from_t.take().is_none() && self.live_t.is_some() {
            // Pairs inside a frozen stretch say nothing of the live sensor.
            self.pairs += 1;
            self.repeats += u64::from(same);
        }
        self.live_t = Some(t);
        false
    }

    /// When the current frozen stretch began, if the sensor is frozen.
    pub fn frozen_since_t(&self) -> Option<f64> {
        self.frozen_from_t
    }

    /// Takes `pairs` live pairs of which `repeats` were identical as seen
    /// (tests).
    #[cfg(test)]
    pub fn seen(&mut self, pairs: u64, repeats: u64) {
        self.pairs = pairs;
        self.repeats = repeats;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_frozen_run_follows_the_share_of_identical_pairs() {
        let mut watch = FrozenWatch::<f64>::default();
        // No pairs yet: p = 1/2, 2^−20 < 1e−6: a run of 20.
        assert_eq!(watch.frozen_run(), 20);
        // 998 live pairs, none identical: p = 1/1000, 3 readings (1e−9).
        for i in 0..999 {
            assert!(!watch.is_frozen(f64::from(i), f64::from(i)));
        }
        assert_eq!(watch.frozen_run(), MIN_FROZEN_RUN);
        // A sensor that repeats one pair in ten: p = 101/1002 ≈ 0.1008,
        // p⁶ ≈ 1.05e−6: a run of 7.
        watch.seen(1000, 100);
        assert_eq!(watch.frozen_run(), 7);
    }

    #[test]
    fn a_frozen_sensor_is_called_after_its_run_and_live_again_at_its_next_change() {
        let mut watch = FrozenWatch::<[f64; 2]>::default();
        for i in 0..1000 {
            assert!(!watch.is_frozen(f64::from(i), [f64::from(i), 0.0]));
        }
        // 999 repeated at t = 1000, 1001, 1002: the third repeat is frozen
        // (a run of 3), from the last live reading.
        assert!(!watch.is_frozen(1000.0, [999.0, 0.0]));
        assert!(!watch.is_frozen(1001.0, [999.0, 0.0]));
        assert!(watch.is_frozen(1002.0, [999.0, 0.0]));
        assert_eq!(watch.frozen_since_t(), Some(1001.0));
        assert!(!watch.is_frozen(1003.0, [1003.0, 0.0]));
        assert_eq!(watch.frozen_since_t(), None);
        // The frozen pairs did not count: 999 live pairs, none identical
        // but the two before the run was called.
        assert_eq!(watch.frozen_run(), MIN_FROZEN_RUN);
    }
}
