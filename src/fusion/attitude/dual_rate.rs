//! Dual-rate bookkeeping of the slow laser and the fast inclinometer (He
//! et al. 2021, Sec. 2.2 and 3.1): the held laser sample and its age
//! (Eq. 14–15), dropout detection, the blend of Eq. 10/11/19, and the
//! inclinometer history a laser sample is paired with for the pitch error
//! of Eq. 16.
//!
//! The paper assumes the laser arrives every m inclinometer periods. Real
//! readings arrive on their own clocks, so both sensors' periods are
//! observed rather than assumed (docs/papers.md).

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// Intervals remembered for a period estimate.
const PERIOD_INTERVALS: usize = 5;
/// A laser sample within this long of the held one is a re-send of it, not
/// a new measurement: no laser targeting system samples faster.
pub const LASER_REPEAT_S: f64 = 1.0;

/// A sensor's usual period: the median of its recent intervals.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Period {
    intervals_s: VecDeque<f64>,
    /// Assumed until an interval has been observed.
    nominal_s: f64,
    /// The median of `intervals_s`, kept with them (read on every reading).
    #[serde(skip)]
    median_s: Option<f64>,
}

/// The cached median is derived data: equal intervals are equal periods.
impl PartialEq for Period {
    fn eq(&self, other: &Self) -> bool {
        self.intervals_s == other.intervals_s && self.nominal_s == other.nominal_s
    }
}

impl Period {
    /// No interval seen yet; `nominal_s` until one is.
    pub fn new(nominal_s: f64) -> Period {
        Period {
            intervals_s: VecDeque::with_capacity(PERIOD_INTERVALS),
            nominal_s,
            median_s: None,
        }
    }

    /// Records one interval.
    pub fn add(&mut self, interval_s: f64) {
        if self.intervals_s.len() == PERIOD_INTERVALS {
            self.intervals_s.pop_front();
        }
        self.intervals_s.push_back(interval_s);
        self.median_s = Some(self.median());
    }

    /// Sets the period assumed until one is observed (after a restore).
    pub fn set_nominal(&mut self, nominal_s: f64) {
        self.nominal_s = nominal_s;
    }

    /// The median of the recent intervals, or the nominal period. The
    /// median ignores the one long interval that spans a dropout.
    pub fn get(&self) -> f64 {
        match self.median_s {
            Some(median) => median,
            // Not yet computed after a restore: compute it.
            None if !self.intervals_s.is_empty() => self.median(),
            None => self.nominal_s,
        }
    }

    fn median(&self) -> f64 {
        let mut sorted = [0.0; PERIOD_INTERVALS];
        let n = self.intervals_s.len();
        for (slot, &x) in sorted.iter_mut().zip(&self.intervals_s) {
            *slot = x;
        }
        let sorted = &mut sorted[..n];
        sorted.sort_by(f64::total_cmp);
        if n % 2 == 1 {
            sorted[n / 2]
        } else {
            0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
        }
    }
}

/// The held laser sample (Eq. 15: held until the next) and the laser's timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LaserHold {
    /// The newest accepted sample: time, pitch, roll (radians).
    pub last: Option<(f64, f64, f64)>,
    period: Period,
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
            last: None,
            period: Period::new(nominal_period_s),
        }
    }

    /// Sets the period assumed until one is observed (after a restore).
    pub fn set_nominal_period(&mut self, nominal_period_s: f64) {
        self.period.set_nominal(nominal_period_s);
    }

    /// Holds a new laser sample (Eq. 14–15).
    pub fn accept(&mut self, t: f64, pitch_rad: f64, roll_rad: f64) -> Result<(), LaserRefusal> {
        if let Some((last, _, _)) = self.last {
            if t < last {
                return Err(LaserRefusal::Stale);
            }
            if t - last < LASER_REPEAT_S {
                return Err(LaserRefusal::Duplicate);
            }
            self.period.add(t - last);
        }
        self.last = Some((t, pitch_rad, roll_rad));
        Ok(())
    }

    /// The laser's usual period.
    pub fn period_s(&self) -> f64 {
        self.period.get()
    }

    /// Age of the held sample at `t` (0 if the sample is newer than `t`).
    pub fn age_s(&self, t: f64) -> Option<f64> {
        self.last.map(|(last, _, _)| (t - last).max(0.0))
    }

    /// True while the laser is usable at `t`: a sample is held and it is no
    /// older than `dropout_factor` times the usual period.
    pub fn is_ok(&self, t: f64, dropout_factor: f64) -> bool {
        self.age_s(t)
            .is_some_and(|age| age <= dropout_factor * self.period_s())
    }
}

/// Eq. 10, 11 and 19: `gain` · laser + (1 − `gain`) · inclinometer.
pub fn fuse(gain: f64, laser: f64, inclinometer: f64) -> f64 {
    gain * laser + (1.0 - gain) * inclinometer
}

/// One inclinometer reading, remembered for pairing.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct InclPoint {
    pub t: f64,
    /// The inclinometer pitch as read, α_I.
    pub pitch_rad: f64,
    /// The filtered roll, offset-corrected (the laser's frame).
    pub roll_rad: f64,
    pub temp_c: Option<f64>,
}

/// A short history of the inclinometer, so a laser sample can be paired
/// with the inclinometer around its own instant (Eq. 16) even when the two
/// arrive out of step.
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

    /// The points within `half_width_s` of `t`.
    pub fn around(&self, t: f64, half_width_s: f64) -> impl Iterator<Item = &InclPoint> {
        let first = self.points.partition_point(|p| p.t < t - half_width_s);
        self.points
            .range(first..)
            .take_while(move |p| p.t <= t + half_width_s)
    }

    /// The point nearest to `t`.
    pub fn nearest(&self, t: f64) -> Option<&InclPoint> {
        let after = self.points.partition_point(|p| p.t < t);
        let next = self.points.get(after);
        let prev = after.checked_sub(1).and_then(|i| self.points.get(i));
        match (prev, next) {
            (Some(a), Some(b)) => Some(if t - a.t <= b.t - t { a } else { b }),
            (a, b) => a.or(b),
        }
    }
}

/// The value at `t` of the least-squares line through `(t_i, y_i)`; needs
/// a point on each side of `t` (an interpolation, never an extrapolation).
pub fn local_line(t: f64, points: impl Iterator<Item = (f64, f64)>) -> Option<f64> {
    let (mut n, mut st, mut sy, mut stt, mut sty) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let (mut before, mut after) = (false, false);
    for (ti, yi) in points {
        let u = ti - t;
        before |= u <= 0.0;
        after |= u >= 0.0;
        n += 1.0;
        st += u;
        sy += yi;
        stt += u * u;
        sty += u * yi;
    }
    if !(before && after) || n < 1.0 {
        return None;
    }
    let var = stt - st * st / n;
    if var <= 0.0 {
        return Some(sy / n);
    }
    let slope = (sty - st * sy / n) / var;
    // Evaluated at u = 0.
    Some(sy / n - slope * st / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fusion_equation() {
        // Eq. 19 with k_f1 = 0.02: 0.02·1.0 + 0.98·2.0 = 1.98.
        assert!((fuse(0.02, 1.0, 2.0) - 1.98).abs() < 1e-15);
        assert_eq!(fuse(0.0, 1.0, 2.0), 2.0);
    }

    #[test]
    fn laser_period_and_dropout() {
        let mut laser = LaserHold::new(120.0);
        assert!(!laser.is_ok(0.0, 2.5));
        laser.accept(1000.0, 0.0, 0.0).unwrap();
        assert_eq!(laser.period_s(), 120.0);
        for i in 1..=4 {
            laser.accept(1000.0 + 60.0 * i as f64, 0.0, 0.0).unwrap();
        }
        assert_eq!(laser.period_s(), 60.0);
        assert!(laser.is_ok(1240.0 + 150.0, 2.5));
        assert!(!laser.is_ok(1240.0 + 151.0, 2.5));
        // One long interval (a dropout) does not move the median period.
        laser.accept(1240.0 + 2700.0, 0.0, 0.0).unwrap();
        assert_eq!(laser.period_s(), 60.0);
        assert_eq!(
            laser.accept(1240.0 + 2700.0, 0.0, 0.0),
            Err(LaserRefusal::Duplicate)
        );
        assert_eq!(laser.accept(1000.0, 0.0, 0.0), Err(LaserRefusal::Stale));
    }

    #[test]
    fn re_sent_samples_are_duplicates_and_fast_lasers_are_learned() {
        // A gateway re-sending each sample a few ms later: refused, so the
        // laser neither looks like a 5 ms sensor nor counts twice.
        let mut laser = LaserHold::new(120.0);
        for i in 0..6 {
            let t = 1000.0 + 60.0 * i as f64;
            laser.accept(t, 0.0, 0.0).unwrap();
            assert_eq!(
                laser.accept(t + 0.005, 0.0, 0.0),
                Err(LaserRefusal::Duplicate)
            );
        }
        assert_eq!(laser.period_s(), 60.0);
        // A 10 s laser configured as 120 s: the real period is learned and
        // a stop is noticed after 2.5 periods, not 2.5 × 120 s.
        let mut fast = LaserHold::new(120.0);
        for i in 0..6 {
            fast.accept(2000.0 + 10.0 * i as f64, 0.0, 0.0).unwrap();
        }
        assert_eq!(fast.period_s(), 10.0);
        assert!(fast.is_ok(2050.0 + 25.0, 2.5));
        assert!(!fast.is_ok(2050.0 + 26.0, 2.5));
    }

    fn point(t: f64, pitch_rad: f64) -> InclPoint {
        InclPoint {
            t,
            pitch_rad,
            roll_rad: -pitch_rad,
            temp_c: None,
        }
    }

    #[test]
    fn history_windows_and_nearest() {
        let mut h = InclHistory::new(4);
        for (t, p) in [
            (10.0, 1.0),
            (11.0, 2.0),
            (20.0, 3.0),
            (21.0, 4.0),
            (22.0, 5.0),
        ] {
            h.push(point(t, p));
        }
        // Capacity 4: the point at 10 s is gone.
        let ts: Vec<f64> = h.around(15.0, 6.0).map(|p| p.t).collect();
        assert_eq!(ts, vec![11.0, 20.0, 21.0]);
        assert_eq!(h.nearest(14.0).unwrap().t, 11.0);
        assert_eq!(h.nearest(16.0).unwrap().t, 20.0);
        assert_eq!(h.nearest(99.0).unwrap().t, 22.0);
        assert_eq!(h.newest_t(), Some(22.0));
    }

    #[test]
    fn local_line_by_hand() {
        // y = 2 + 0.5 (t − 10) sampled at 8, 9, 11, 13: the line through
        // them is exact, its value at 10 is 2.
        let pts = [8.0, 9.0, 11.0, 13.0].map(|t| (t, 2.0 + 0.5 * (t - 10.0)));
        assert!((local_line(10.0, pts.into_iter()).unwrap() - 2.0).abs() < 1e-12);
        // Noise of ±1 at t = 9 and 11 averages out at 10.
        let pts = [(9.0, 3.0), (11.0, 1.0)];
        assert!((local_line(10.0, pts.into_iter()).unwrap() - 2.0).abs() < 1e-12);
        // All points on one side: no extrapolation.
        assert!(local_line(10.0, [(11.0, 1.0), (12.0, 1.0)].into_iter()).is_none());
    }
}
