//! The `zupt` engine's IMU screen (issue 54): two checks of each IMU
//! reading before the detector and the strapdown take it.
//!
//! - **Spikes.** Each of the six channels against the median of the last
//!   [`RECENT`] readings taken, in units of the larger of their robust
//!   spread (1.4826 × the median absolute deviation: the machinery's
//!   vibration, learnt from the readings) and a floor of what a machine of
//!   hundreds of tonnes does within a third of a second
//!   ([`ACCEL_FLOOR_MPS2`], [`GYRO_FLOOR_RAD_PER_S`]). Beyond
//!   [`SPIKE_SIGMAS`] on any channel the reading is not taken: a loose
//!   connector or a hammer blow does not move a pipe jack. The readings
//!   either side are unharmed (the strapdown integrates across the
//!   missing one), so the estimates stay `ok`; the spikes are counted. A
//!   change that persists is not a spike: after [`MAX_REJECTED_IN_A_ROW`]
//!   readings refused in a row the next is taken.
//! - **A frozen sensor** ([`FrozenWatch`]): a run of readings identical in
//!   all six channels, improbable at the sensor's learnt repeat rate. A
//!   frozen reading is not taken: the engine ends the stream as at a gap
//!   and holds its navigation, `lost` (`sensor_frozen`), until the IMU
//!   is live again; the gap's time then widens the covariance and the
//!   position's bound (the machine may have moved).
//!
//! The robust spread is refreshed every [`REFRESH`] readings taken, so the
//! screen costs about two partial sorts of [`RECENT`] values a reading.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use super::ImuSample;
use crate::fusion::frozen::FrozenWatch;
use crate::fusion::robust::{MAD_TO_SIGMA, median_in_place};

/// A channel this many robust σ from its recent median is a spike.
pub const SPIKE_SIGMAS: f64 = 8.0;
/// Readings taken whose channels give the median and the spread.
pub const RECENT: usize = 32;
/// Readings taken between refreshes of the median and the spread.
pub const REFRESH: u32 = 8;
/// Readings refused in a row before a change counts as real.
pub const MAX_REJECTED_IN_A_ROW: u32 = 3;
/// The least robust σ of an accelerometer channel, m/s²: 8 σ is 0.8 m/s²
/// (80 mg), far beyond what a tunnelling machine's body does.
pub const ACCEL_FLOOR_MPS2: f64 = 0.1;
/// The least robust σ of a gyro channel, rad/s (0.1 °/s): 8 σ is 0.8 °/s.
pub const GYRO_FLOOR_RAD_PER_S: f64 = 0.1 * std::f64::consts::PI / 180.0;

/// What the screen makes of a reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Screened {
    /// Take it.
    Take,
    /// A spike: not taken.
    Spike,
    /// The sensor repeats itself: not taken.
    Frozen,
}

/// What the screen remembers.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ImuScreen {
    frozen: FrozenWatch<[f64; 6]>,
    /// The newest readings taken (accelerometer, then gyro), oldest first.
    recent: VecDeque<[f64; 6]>,
    /// Each channel's median and robust σ at the last refresh; `None`
    /// until [`RECENT`] readings were taken.
    centre: Option<[f64; 6]>,
    spread: [f64; 6],
    taken_since_refresh: u32,
    rejected_in_a_row: u32,
}

impl ImuScreen {
    /// Screens `sample`.
    pub fn screen(&mut self, sample: &ImuSample) -> Screened {
        let a = &sample.accel_mps2;
        let g = &sample.gyro_rad_per_s;
        let channels = [a.x, a.y, a.z, g.x, g.y, g.z];
        if self.frozen.is_frozen(sample.t, channels) {
            return Screened::Frozen;
        }
        if let Some(centre) = &self.centre {
            let spike = (0..6).any(|k| {
                let z = (channels[k] - centre[k]).abs() / self.spread[k];
                z > SPIKE_SIGMAS || !z.is_finite()
            });
            if spike {
                self.rejected_in_a_row += 1;
                if self.rejected_in_a_row <= MAX_REJECTED_IN_A_ROW {
                    return Screened::Spike;
                }
                // A change that persists: the window starts afresh from it.
                self.recent.clear();
                self.centre = None;
            }
        }
        self.rejected_in_a_row = 0;
        if self.recent.len() == RECENT {
            self.recent.pop_front();
        }
        self.recent.push_back(channels);
        self.taken_since_refresh += 1;
        if self.recent.len() == RECENT
            && (self.centre.is_none() || self.taken_since_refresh >= REFRESH)
        {
            self.refresh();
        }
        Screened::Take
    }

    /// When the current frozen stretch began, if the IMU is frozen.
    pub fn frozen_since_t(&self) -> Option<f64> {
        self.frozen.frozen_since_t()
    }

    /// Each channel's median and robust σ over the recent readings.
    fn refresh(&mut self) {
        let mut centre = [0.0; 6];
        let mut spread = [0.0; 6];
        let mut values = [0.0; RECENT];
        let n = self.recent.len();
        for k in 0..6 {
            for (value, reading) in values.iter_mut().zip(&self.recent) {
                *value = reading[k];
            }
            let median = median_in_place(&mut values[..n]);
            for value in &mut values[..n] {
                *value = (*value - median).abs();
            }
            let mad = median_in_place(&mut values[..n]);
            let floor = if k < 3 {
                ACCEL_FLOOR_MPS2
            } else {
                GYRO_FLOOR_RAD_PER_S
            };
            centre[k] = median;
            spread[k] = (MAD_TO_SIGMA * mad).max(floor);
        }
        self.centre = Some(centre);
        self.spread = spread;
        self.taken_since_refresh = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::geometry::V3;

    fn sample(t: f64, accel_x: f64, gyro_x: f64) -> ImuSample {
        ImuSample {
            t,
            // A little noise, so no two readings are identical.
            accel_mps2: V3::new(accel_x, 1e-4 * (t * 7.3).sin(), -9.8),
            gyro_rad_per_s: V3::new(gyro_x, 1e-6 * (t * 3.1).cos(), 0.0),
        }
    }

    #[test]
    fn a_spike_is_refused_and_a_change_that_persists_is_taken() {
        let mut screen = ImuScreen::default();
        for k in 0..100 {
            assert_eq!(
                screen.screen(&sample(f64::from(k) * 0.01, 0.0, 0.0)),
                Screened::Take
            );
        }
        // +5 m/s² is 50 floors (0.1 m/s²) from the median 0: refused; so
        // is 30 °/s about x. 0.5 m/s² (5 floors) is taken.
        assert_eq!(screen.screen(&sample(1.00, 5.0, 0.0)), Screened::Spike);
        assert_eq!(
            screen.screen(&sample(1.01, 0.0, 30f64.to_radians())),
            Screened::Spike
        );
        assert_eq!(screen.screen(&sample(1.02, 0.5, 0.0)), Screened::Take);
        // A step of 2 m/s² held: three refused, the fourth taken, and
        // the window starts from it, so the fifth is taken too.
        for k in 0..3 {
            let t = 1.03 + f64::from(k) * 0.01;
            assert_eq!(screen.screen(&sample(t, 2.0, 0.0)), Screened::Spike);
        }
        assert_eq!(screen.screen(&sample(1.06, 2.0, 0.0)), Screened::Take);
        assert_eq!(screen.screen(&sample(1.07, 2.0, 0.0)), Screened::Take);
    }

    #[test]
    fn a_frozen_imu_is_called_after_three_identical_readings() {
        let mut screen = ImuScreen::default();
        for k in 0..1000 {
            screen.screen(&sample(f64::from(k) * 0.01, 0.0, 0.0));
        }
        let stuck = sample(9.99, 0.0, 0.0);
        // The same values at 10.00, 10.01, 10.02: the third repeat frozen.
        for (k, expected) in [Screened::Take, Screened::Take, Screened::Frozen]
            .into_iter()
            .enumerate()
        {
            let again = ImuSample {
                t: 10.0 + k as f64 * 0.01,
                ..stuck
            };
            assert_eq!(screen.screen(&again), expected);
        }
        assert_eq!(screen.frozen_since_t(), Some(10.01));
        assert_eq!(screen.screen(&sample(10.03, 0.0, 0.0)), Screened::Take);
        assert_eq!(screen.frozen_since_t(), None);
    }
}
