//! The `attitude` engine's inclinometer monitor (issue 54): two checks of
//! each inclinometer reading before the filters take it.
//!
//! - **Spikes.** The reading's innovation ν against the filters'
//!   prediction, for pitch and roll (the larger counts), in units of the
//!   larger of the filter's √S and the innovations' own recent spread
//!   (1.4826 × the median |ν| of the last [`RECENT`] live readings: a
//!   robust σ learned from the data, which a filter too sure of itself
//!   does not shrink). Beyond [`SPIKE_SIGMAS`] it is not fused: a loose
//!   connector or a blow does not move a TBM. The reading makes no
//!   estimate; the estimates around it are unharmed and stay `ok` (a
//!   flag per spike raised the `integrity` alarm on ordinary drives along
//!   a design axis); the spikes are counted. A change that persists is not a spike: after
//!   [`MAX_REJECTED_IN_A_ROW`] readings rejected in a row the next is
//!   fused (a new zero after a power cycle, a real motion); the laser
//!   monitor judges it at the next sample.
//! - **A frozen sensor.** A run of identical readings (both angles, to the
//!   last bit) improbable at the sensor's learnt repeat rate
//!   ([`FrozenWatch`]). A frozen reading is not fused; the estimate is the last one, its σ widened by
//!   the angle's process noise over the frozen time, `degraded`
//!   (`sensor_frozen`).
//!
//! With honest Gaussian innovations a reading is rejected at z > 5 once in
//! 1.7 million; the rate on the envelope's drives is in
//! docs/engines/attitude.md.

use serde::{Deserialize, Serialize};

use crate::fusion::frozen::FrozenWatch;
use crate::fusion::integrity::{Integrity, IntegrityReason};
use crate::fusion::robust::{MAD_TO_SIGMA, median_in_place};

/// An innovation beyond this many σ is a spike.
pub const SPIKE_SIGMAS: f64 = 8.0;
/// Fused readings whose innovations give the robust σ.
pub const RECENT: usize = 32;
/// Readings rejected in a row before a change counts as real.
pub const MAX_REJECTED_IN_A_ROW: u32 = 3;

/// What a reading is, to the monitor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Screened {
    /// Fuse it.
    Fuse,
    /// A spike: not fused.
    Spike,
    /// The sensor repeats itself: not fused.
    Frozen,
}

/// What the monitor remembers.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct InclinometerMonitor {
    /// The raw angles (degrees, as sent) watched for a frozen sensor;
    /// flattened, so snapshots keep the fields they had.
    #[serde(flatten)]
    frozen: FrozenWatch<(f64, f64)>,
    /// The newest live readings' |ν| for pitch and roll, oldest first.
    recent_abs_innovation: [Vec<f64>; 2],
    /// Their robust σ (1.4826 × the median), pitch and roll; 0 until
    /// half of them are in. Kept, not recomputed at each use.
    #[serde(default)]
    robust: [f64; 2],
    /// Readings rejected as spikes in a row now, and so far.
    rejected_in_a_row: u32,
    pub spikes: u64,
}

impl InclinometerMonitor {
    /// The σ of an innovation on `axis` (0 pitch, 1 roll) whose filter
    /// says `sqrt_s`: that, or the recent innovations' robust spread if
    /// larger.
    pub fn sigma(&self, axis: usize, sqrt_s: f64) -> f64 {
        sqrt_s.max(self.robust[axis]).max(f64::MIN_POSITIVE)
    }

    /// The robust σ of the recent innovations on `axis`.
    fn robust_of(&self, axis: usize) -> f64 {
        let recent = &self.recent_abs_innovation[axis];
        // The newest RECENT at most (a restored snapshot may hold more).
        let n = recent.len().min(RECENT);
        if n < RECENT / 2 {
            return 0.0;
        }
        // The median without a heap copy.
        let mut copy = [0.0; RECENT];
        copy[..n].copy_from_slice(&recent[recent.len() - n..]);
        MAD_TO_SIGMA * median_in_place(&mut copy[..n])
    }

    /// A reading at `t` of `pitch_deg` and `roll_deg` (as sent) with
    /// innovations `(ν, √S)` for pitch and roll (`None` before the
    /// filters start): whether to fuse it.
    pub fn screen(
        &mut self,
        t: f64,
        pitch_deg: f64,
        roll_deg: f64,
        innovations: Option<[(f64, f64); 2]>,
    ) -> Screened {
        if self.frozen.is_frozen(t, (pitch_deg, roll_deg)) {
            return Screened::Frozen;
        }
        let z = innovations.map_or(0.0, |axes| {
            (0..2)
                .map(|k| axes[k].0.abs() / self.sigma(k, axes[k].1))
                .fold(0.0, f64::max)
        });
        // Every live reading's innovation counts for the robust σ, spikes
        // too: the median shrugs off a few.
        if let Some(axes) = innovations {
            for (recent, (innovation, _)) in self.recent_abs_innovation.iter_mut().zip(axes) {
                if recent.len() == RECENT {
                    recent.remove(0);
                }
                recent.push(innovation.abs());
            }
            self.robust = [self.robust_of(0), self.robust_of(1)];
        }
        if z > SPIKE_SIGMAS || !z.is_finite() {
            self.rejected_in_a_row += 1;
            if self.rejected_in_a_row <= MAX_REJECTED_IN_A_ROW {
                self.spikes += 1;
                return Screened::Spike;
            }
        } else {
            self.rejected_in_a_row = 0;
        }
        Screened::Fuse
    }

    /// When the current frozen stretch began, if the sensor is frozen.
    pub fn frozen_since_t(&self) -> Option<f64> {
        self.frozen.frozen_since_t()
    }

    /// The integrity of an estimate on this sensor's account.
    pub fn integrity(&self) -> Integrity {
        if self.frozen.frozen_since_t().is_some() {
            Integrity::degraded(IntegrityReason::SensorFrozen)
        } else {
            Integrity::OK
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frozen_sensor_is_called_after_its_run_and_live_again_at_its_next_change() {
        let mut m = InclinometerMonitor::default();
        for i in 0..1000 {
            m.screen(f64::from(i), f64::from(i), 0.0, None);
        }
        // 999 repeated at t = 1000, 1001, 1002: the third repeat is frozen
        // (a run of 3), from the last live reading.
        assert_eq!(m.screen(1000.0, 999.0, 0.0, None), Screened::Fuse);
        assert_eq!(m.screen(1001.0, 999.0, 0.0, None), Screened::Fuse);
        assert_eq!(m.screen(1002.0, 999.0, 0.0, None), Screened::Frozen);
        assert_eq!(m.frozen_since_t(), Some(1001.0));
        assert_eq!(m.integrity().reason, Some(IntegrityReason::SensorFrozen));
        assert_eq!(m.screen(1003.0, 1003.0, 0.0, None), Screened::Fuse);
        assert!(m.integrity().is_ok());
    }

    #[test]
    fn spikes_are_rejected_but_a_change_that_persists_is_fused_and_flagged() {
        let mut m = InclinometerMonitor::default();
        // Innovations of pitch z σ (√S 1), roll 0.
        let nu = |z: f64| Some([(z, 1.0), (0.0, 1.0)]);
        assert_eq!(m.screen(0.0, 0.0, 0.0, nu(1.0)), Screened::Fuse);
        assert_eq!(m.screen(1.0, 2.0, 0.0, nu(40.0)), Screened::Spike);
        // The spike is not fused: the estimates are unharmed.
        assert!(m.integrity().is_ok());
        assert_eq!(m.screen(2.0, 0.0, 0.0, nu(0.5)), Screened::Fuse);
        // Four in a row: three rejected, the fourth fused.
        for t in 3..6 {
            assert_eq!(m.screen(f64::from(t), 0.3, 0.0, nu(9.0)), Screened::Spike);
        }
        assert_eq!(m.screen(6.0, 0.3, 0.1, nu(9.0)), Screened::Fuse);
        assert!(m.integrity().is_ok());
        assert_eq!(m.spikes, 4);
    }

    #[test]
    fn a_filter_too_sure_of_itself_does_not_make_ordinary_readings_spikes() {
        let mut m = InclinometerMonitor::default();
        // The filter says √S = 0.001 but the innovations run at ±0.01:
        // the robust σ, 1.4826 × 0.01, takes over once 16 are in.
        for i in 0..40 {
            let innovations = Some([(0.01, 0.001), (0.0, 0.001)]);
            let screened = m.screen(f64::from(i), f64::from(i), 0.0, innovations);
            // 10σ of the filter's: three spikes, then a persistent change,
            // fused; from the 16th on the robust σ says 0.67σ.
            let expected = if i >= 3 {
                Screened::Fuse
            } else {
                Screened::Spike
            };
            assert_eq!(screened, expected, "reading {i}");
        }
        // 0.2 is 13 robust σ: a spike.
        assert_eq!(
            m.screen(50.0, 7.0, 0.0, Some([(0.2, 0.001), (0.0, 0.001)])),
            Screened::Spike
        );
    }
}
