//! A calibration judged by the gyro across turns (issue 34): between two
//! calibrated compass headings 90° or more apart by the gyro within
//! `WINDOW_S`, the compass's heading change should be the gyro's. A
//! calibration off by hard iron δb has a heading error e(ψ) ≈ (δb/H)·
//! sin(ψ − φ), so across a turn of 90° the disagreement d = e(ψ₂) − e(ψ₁)
//! has RMS √2 · RMS(e); the newest heading at least 90° back is taken
//! (and used up with the older ones). The calibration's heading
//! σ is then at least √(mean d² / 2): a fit whose radius residual is small
//! but whose centre is off (readings taken through a disturbance, a tilt
//! the levelling got wrong) still says how wrong it is. The gyro's own
//! drift over the window adds to d, so this errs on the cautious side.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use super::orientation::angle_difference;

/// Headings compared at most this far apart, s.
const WINDOW_S: f64 = 30.0;
/// One heading kept per this many seconds.
const SPACING_S: f64 = 0.5;
/// The gyro's turn between two compared headings, at least, rad.
const MIN_TURN_RAD: f64 = std::f64::consts::FRAC_PI_2;
/// Comparisons needed before a σ is given.
const MIN_PAIRS: u64 = 10;

/// Calibrated compass headings against the gyro's integrated yaw.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TurnCheck {
    /// (t, compass heading, gyro yaw), oldest first.
    recent: VecDeque<(f64, f64, f64)>,
    /// Σ d², rad².
    squares_rad2: f64,
    pairs: u64,
}

impl TurnCheck {
    /// Takes a calibrated, undisturbed compass heading (rad) at `t` with
    /// the gyro's integrated yaw (rad, unwrapped); one per `SPACING_S`,
    /// in time order (an older one is ignored).
    pub fn push(&mut self, t: f64, compass_rad: f64, gyro_yaw_rad: f64) {
        if self
            .recent
            .back()
            .is_some_and(|&(last, _, _)| t < last + SPACING_S)
        {
            return;
        }
        while self
            .recent
            .front()
            .is_some_and(|&(old, _, _)| t - old > WINDOW_S)
        {
            self.recent.pop_front();
        }
        // The newest heading the gyro has turned 90° or more from; it and
        // the older ones are used up, so each comparison has its own
        // older end.
        if let Some(index) = self
            .recent
            .iter()
            .rposition(|&(_, _, gyro)| (gyro_yaw_rad - gyro).abs() >= MIN_TURN_RAD)
        {
            let (_, compass, gyro) = self.recent[index];
            let d = angle_difference(compass_rad - compass, gyro_yaw_rad - gyro);
            self.squares_rad2 += d * d;
            self.pairs += 1;
            self.recent.drain(..=index);
        }
        self.recent.push_back((t, compass_rad, gyro_yaw_rad));
    }

    /// The calibration's heading σ the turns show, rad; `None` before
    /// `MIN_PAIRS` comparisons.
    pub fn sigma_rad(&self) -> Option<f64> {
        (self.pairs >= MIN_PAIRS).then(|| (self.squares_rad2 / self.pairs as f64 / 2.0).sqrt())
    }

    /// A new calibration: nothing judged yet.
    pub fn clear(&mut self) {
        *self = TurnCheck::default();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_compass_that_follows_the_gyro_shows_nothing_and_one_off_by_a_sine_shows_it() {
        let mut right = TurnCheck::default();
        let mut wrong = TurnCheck::default();
        // Turning at 10 °/s for 200 s, a heading every 0.5 s.
        let amplitude = 5.0_f64.to_radians();
        for k in 0..400 {
            let t = f64::from(k) * 0.5;
            let yaw = (10.0 * t).to_radians();
            right.push(t, yaw, yaw);
            wrong.push(t, yaw + amplitude * yaw.sin(), yaw);
        }
        assert!(right.sigma_rad().unwrap() < 1e-9);
        // e = A sin ψ has RMS A/√2 = 3.54°; turns of 90–95° show about that.
        let shown = wrong.sigma_rad().unwrap().to_degrees();
        assert!((3.4..4.2).contains(&shown), "{shown}");
        wrong.clear();
        assert_eq!(wrong.sigma_rad(), None);
    }
}
