//! Dual-rate fusion of the slow laser and the fast inclinometer (He et al.
//! 2021, Sec. 2.2 and 3.1): the held laser sample and its age (Eq. 14–15),
//! dropout detection, the fusion of Eq. 10/11/19, the one-step prediction of
//! Eq. 12/13, and the pairing of laser instants with the inclinometer for
//! the pitch error of Eq. 16.
//!
//! The paper assumes the laser arrives every m inclinometer periods. Real
//! readings arrive on their own clocks, so the laser is held with its time
//! and its period is observed rather than assumed (NOTES.md).

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use super::kalman::ScalarKalman;

/// Intervals remembered for the laser period estimate.
const PERIOD_INTERVALS: usize = 5;
/// A laser sample within this long of the held one is a re-send of it, not
/// a new measurement: no laser targeting system samples faster.
pub const LASER_REPEAT_S: f64 = 1.0;

/// The held, filtered laser attitude and the laser's timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserHold {
    /// Filtered laser pitch α_L_f.
    pub pitch: ScalarKalman,
    /// Filtered laser roll β_L_f.
    pub roll: ScalarKalman,
    /// Time of the newest accepted laser sample.
    pub last_t: Option<f64>,
    /// Recent intervals between samples, newest last.
    intervals_s: VecDeque<f64>,
    /// Period assumed until an interval has been observed.
    nominal_period_s: f64,
}

/// Why a laser sample was not taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LaserRefusal {
    /// Same time as the held sample, or within [`LASER_REPEAT_S`] after it.
    Duplicate,
    /// Older than the held sample.
    Stale,
}

impl LaserHold {
    /// Nothing held yet; `nominal_period_s` is used until the period is observed.
    pub fn new(nominal_period_s: f64) -> LaserHold {
        LaserHold {
            pitch: ScalarKalman::default(),
            roll: ScalarKalman::default(),
            last_t: None,
            intervals_s: VecDeque::with_capacity(PERIOD_INTERVALS),
            nominal_period_s,
        }
    }

    /// Sets the period assumed until one is observed (after a restore).
    pub fn set_nominal_period(&mut self, nominal_period_s: f64) {
        self.nominal_period_s = nominal_period_s;
    }

    /// Filters and holds a new laser sample (Eq. 1–7 on each laser angle,
    /// then Eq. 15: the value is held until the next sample).
    pub fn accept(
        &mut self,
        t: f64,
        pitch_rad: f64,
        roll_rad: f64,
        noise: &FilterNoise,
    ) -> Result<(), LaserRefusal> {
        let dt_s = match self.last_t {
            Some(last) if t < last => return Err(LaserRefusal::Stale),
            Some(last) if t - last < LASER_REPEAT_S => return Err(LaserRefusal::Duplicate),
            Some(last) => t - last,
            None => 0.0,
        };
        if self.last_t.is_some() {
            if self.intervals_s.len() == PERIOD_INTERVALS {
                self.intervals_s.pop_front();
            }
            self.intervals_s.push_back(dt_s);
        }
        self.pitch
            .step(pitch_rad, noise.q_pitch_per_s * dt_s, noise.r_laser);
        self.roll
            .step(roll_rad, noise.q_roll_per_s * dt_s, noise.r_laser);
        self.last_t = Some(t);
        Ok(())
    }

    /// The laser's usual period: the median of the recent intervals, or the
    /// nominal period before any interval is known. The median ignores the
    /// one long interval that spans a dropout.
    pub fn period_s(&self) -> f64 {
        if self.intervals_s.is_empty() {
            return self.nominal_period_s;
        }
        let mut sorted: Vec<f64> = self.intervals_s.iter().copied().collect();
        sorted.sort_by(f64::total_cmp);
        let n = sorted.len();
        if n % 2 == 1 {
            sorted[n / 2]
        } else {
            0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
        }
    }

    /// Age of the held sample at `t` (0 if the sample is newer than `t`).
    pub fn age_s(&self, t: f64) -> Option<f64> {
        self.last_t.map(|last| (t - last).max(0.0))
    }

    /// True while the laser is usable at `t`: a sample is held and it is no
    /// older than `dropout_factor` times the usual period.
    pub fn is_ok(&self, t: f64, dropout_factor: f64) -> bool {
        self.age_s(t)
            .is_some_and(|age| age <= dropout_factor * self.period_s())
    }
}

/// Process and measurement noise of the filters, in rad² (per second for Q).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FilterNoise {
    pub q_pitch_per_s: f64,
    pub q_roll_per_s: f64,
    pub r_laser: f64,
    pub r_incl: f64,
}

/// Eq. 10, 11 and 19: `gain` · laser + (1 − `gain`) · inclinometer.
pub fn fuse(gain: f64, laser: f64, inclinometer: f64) -> f64 {
    gain * laser + (1.0 - gain) * inclinometer
}

/// Eq. 12/13: α̂(k+1) = α(k) + k_p (α(k) − α(k−1)).
pub fn predict_one_step(current: f64, previous: f64, k_p: f64) -> f64 {
    current + k_p * (current - previous)
}

/// One filtered inclinometer attitude, remembered for pairing.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct InclPoint {
    pub t: f64,
    /// Filtered, uncorrected inclinometer pitch α_I_f.
    pub pitch_rad: f64,
    /// Filtered inclinometer roll β_I_f (before the offset correction).
    pub roll_rad: f64,
}

/// A short history of the filtered inclinometer, so a laser sample can be
/// paired with the inclinometer at its own instant (Eq. 16) even when the
/// two arrive out of step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InclHistory {
    points: VecDeque<InclPoint>,
    capacity: usize,
}

impl InclHistory {
    /// Remembers at most `capacity` points.
    pub fn new(capacity: usize) -> InclHistory {
        InclHistory {
            points: VecDeque::with_capacity(capacity),
            capacity: capacity.max(2),
        }
    }

    /// Sets how many points are kept, forgetting the oldest beyond it.
    pub fn set_capacity(&mut self, capacity: usize) {
        self.capacity = capacity.max(2);
        while self.points.len() > self.capacity {
            self.points.pop_front();
        }
    }

    /// Appends a point (times must increase).
    pub fn push(&mut self, point: InclPoint) {
        if self.points.len() == self.capacity {
            self.points.pop_front();
        }
        self.points.push_back(point);
    }

    /// Time of the newest point.
    pub fn newest_t(&self) -> Option<f64> {
        self.points.back().map(|p| p.t)
    }

    /// The inclinometer at `t`, interpolated linearly between the two points
    /// around it, provided they are at most `max_gap_s` apart. `None` when `t`
    /// is outside the history or falls in a gap.
    pub fn at(&self, t: f64, max_gap_s: f64) -> Option<InclPoint> {
        let after = self.points.partition_point(|p| p.t < t);
        let next = self.points.get(after)?;
        if next.t == t {
            return Some(*next);
        }
        let prev = self.points.get(after.checked_sub(1)?)?;
        let gap = next.t - prev.t;
        if gap > max_gap_s {
            return None;
        }
        let f = (t - prev.t) / gap;
        Some(InclPoint {
            t,
            pitch_rad: prev.pitch_rad + f * (next.pitch_rad - prev.pitch_rad),
            roll_rad: prev.roll_rad + f * (next.roll_rad - prev.roll_rad),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const NOISE: FilterNoise = FilterNoise {
        q_pitch_per_s: 1e-6,
        q_roll_per_s: 1e-6,
        r_laser: 1e-6,
        r_incl: 1e-4,
    };

    #[test]
    fn fusion_and_prediction_equations() {
        // Eq. 19 with k_f1 = 0.02: 0.02·1.0 + 0.98·2.0 = 1.98.
        assert!((fuse(0.02, 1.0, 2.0) - 1.98).abs() < 1e-15);
        assert_eq!(fuse(0.0, 1.0, 2.0), 2.0);
        // Eq. 12 with k_p = 1: 0.5 + (0.5 − 0.4) = 0.6.
        assert!((predict_one_step(0.5, 0.4, 1.0) - 0.6).abs() < 1e-15);
        assert!((predict_one_step(0.5, 0.4, 2.0) - 0.7).abs() < 1e-15);
    }

    #[test]
    fn laser_period_and_dropout() {
        let mut laser = LaserHold::new(120.0);
        assert!(!laser.is_ok(0.0, 2.5));
        laser.accept(1000.0, 0.0, 0.0, &NOISE).unwrap();
        assert_eq!(laser.period_s(), 120.0);
        for i in 1..=4 {
            laser
                .accept(1000.0 + 60.0 * i as f64, 0.0, 0.0, &NOISE)
                .unwrap();
        }
        assert_eq!(laser.period_s(), 60.0);
        assert!(laser.is_ok(1240.0 + 150.0, 2.5));
        assert!(!laser.is_ok(1240.0 + 151.0, 2.5));
        // One long interval (a dropout) does not move the median period.
        laser.accept(1240.0 + 2700.0, 0.0, 0.0, &NOISE).unwrap();
        assert_eq!(laser.period_s(), 60.0);
        assert_eq!(
            laser.accept(1240.0 + 2700.0, 0.0, 0.0, &NOISE),
            Err(LaserRefusal::Duplicate)
        );
        assert_eq!(
            laser.accept(1000.0, 0.0, 0.0, &NOISE),
            Err(LaserRefusal::Stale)
        );
    }

    #[test]
    fn re_sent_samples_are_duplicates_and_fast_lasers_are_learned() {
        // A gateway re-sending each sample a few ms later: refused, so the
        // laser neither looks like a 5 ms sensor nor counts twice.
        let mut laser = LaserHold::new(120.0);
        for i in 0..6 {
            let t = 1000.0 + 60.0 * i as f64;
            laser.accept(t, 0.0, 0.0, &NOISE).unwrap();
            assert_eq!(
                laser.accept(t + 0.005, 0.0, 0.0, &NOISE),
                Err(LaserRefusal::Duplicate)
            );
        }
        assert_eq!(laser.period_s(), 60.0);
        // A 10 s laser configured as 120 s: the real period is learned and
        // a stop is noticed after 2.5 periods, not 2.5 × 120 s.
        let mut fast = LaserHold::new(120.0);
        for i in 0..6 {
            fast.accept(2000.0 + 10.0 * i as f64, 0.0, 0.0, &NOISE)
                .unwrap();
        }
        assert_eq!(fast.period_s(), 10.0);
        assert!(fast.is_ok(2050.0 + 25.0, 2.5));
        assert!(!fast.is_ok(2050.0 + 26.0, 2.5));
    }

    #[test]
    fn history_interpolates_within_gaps_only() {
        let mut h = InclHistory::new(4);
        for (t, p) in [(10.0, 1.0), (11.0, 2.0), (20.0, 3.0)] {
            h.push(InclPoint {
                t,
                pitch_rad: p,
                roll_rad: -p,
            });
        }
        let mid = h.at(10.25, 5.0).unwrap();
        assert!((mid.pitch_rad - 1.25).abs() < 1e-15);
        assert!((mid.roll_rad + 1.25).abs() < 1e-15);
        assert_eq!(h.at(11.0, 5.0).unwrap().pitch_rad, 2.0);
        assert!(h.at(15.0, 5.0).is_none()); // inside a 9 s gap
        assert!(h.at(9.0, 5.0).is_none());
        assert!(h.at(21.0, 5.0).is_none());
    }
}
