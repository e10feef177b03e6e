//! A sensor's period learned from its readings: the median of its recent
//! intervals, so a site's 1 Hz inclinometer and 100 Hz IMU need no
//! configured rates, and a single late reading does not move it.

use serde::{Deserialize, Serialize};

/// Intervals kept for the median.
const INTERVALS: usize = 31;

/// The newest reading time and the median of the recent intervals.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LearnedPeriod {
    pub last_t: Option<f64>,
    /// The newest intervals, s (a ring of [`INTERVALS`]).
    intervals: Vec<f64>,
    next: usize,
}

impl LearnedPeriod {
    /// A reading at `t` (readings of one sensor come in time order; an
    /// older or repeated one is ignored).
    pub fn add(&mut self, t: f64) {
        if let Some(last) = self.last_t {
            if t <= last {
                return;
            }
            let interval = t - last;
            if self.intervals.len() < INTERVALS {
                self.intervals.push(interval);
            } else {
                self.intervals[self.next] = interval;
            }
            self.next = (self.next + 1) % INTERVALS;
        }
        self.last_t = Some(t);
    }

    /// The median interval, once three are known.
    pub fn period_s(&self) -> Option<f64> {
        if self.intervals.len() < 3 {
            return None;
        }
        let mut sorted = self.intervals.clone();
        sorted.sort_by(f64::total_cmp);
        Some(sorted[sorted.len() / 2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_median_ignores_a_late_reading_and_needs_three_intervals() {
        let mut p = LearnedPeriod::default();
        for t in [0.0, 1.0, 2.0] {
            p.add(t);
        }
        assert_eq!(p.period_s(), None);
        // 1 s readings with one 40 s gap and one repeat.
        for t in [3.0, 43.0, 43.0, 44.0, 45.0] {
            p.add(t);
        }
        assert_eq!(p.period_s(), Some(1.0));
        assert_eq!(p.last_t, Some(45.0));
        // The rate changes to 10 Hz: after the ring turns over, 0.1 s.
        for i in 1..=40 {
            p.add(45.0 + 0.1 * f64::from(i));
        }
        assert!((p.period_s().unwrap() - 0.1).abs() < 1e-9);
    }
}
