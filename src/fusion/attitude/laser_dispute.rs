//! The `attitude` engine's wrong-prism test (issue 54): a laser sample
//! that jumps away from the inclinometer's continuity.
//!
//! Between two laser samples the estimate rests on the inclinometer. When
//! a sample fails the laser monitor's check (more than [`DISAGREE_SIGMAS`]
//! σ from the estimate carried to it, its σ grown by the time since,
//! dropouts included) although the engine vouched for that estimate (the
//! monitor agreeing, the error model past its learning, no step called
//! by the step watch and none seen that explains the jump), something
//! changed in a step that the inclinometer did not follow: the laser (a
//! wrong prism, a knocked station) or the inclinometer's zero (a step
//! too slow or too small for the step watch to see). Pitch and roll
//! alone cannot tell which. The engine keeps the
//! inclinometer's continuity, holds the sample out (it is neither fused
//! nor paired for training), and covers the other case in σ: the disputed
//! offset J (laser − estimate) adds J² to the variance, and the estimates
//! are `degraded` (`laser_disagrees`, from the laser monitor).
//!
//! Each later sample is classed by which case it lies nearer, in units of
//! its σ (the carried estimate's, with the laser's noise): the continuity
//! (the laser is back: the dispute closes and the sample is fused) or the
//! offset (the dispute holds; the sample is held out, and the larger of
//! its offset and J widens σ). A sample near
//! neither, or a dispute the estimate's own σ has come to cover
//! (|J| ≤ [`AGREE_SIGMAS`] σ on both axes: the inclinometer has been
//! carried so long that its continuity no longer outweighs the laser),
//! closes the dispute and the sample is fused: the paper's reference wins.
//! So does the first sample after the declared `laser_dispute_max_s`: a
//! new inclinometer zero that no reading showed looks like a laser that
//! jumped for as long as it lasts, and the engine must not ignore its
//! reference for the rest of a drive (the operator has been warned by
//! the integrity alarm meanwhile).

use serde::{Deserialize, Serialize};

pub use super::laser_monitor::{AGREE_SIGMAS, DISAGREE_SIGMAS};

/// What to do with a laser sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LaserVerdict {
    /// Fuse it (and pair it for training) as usual.
    Fuse,
    /// Hold it out: its jump is disputed.
    HoldOut,
    /// Fuse it: the laser came back to the estimate, so the samples held
    /// out were the laser's fault, not the estimate's.
    LaserBack,
}

/// An open dispute.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Open {
    /// When the jump was first seen.
    since_t: f64,
    /// The disputed offset, laser − estimate, pitch and roll, rad.
    offset_rad: [f64; 2],
    /// The carried estimate's variance then, rad².
    carried_variance: [f64; 2],
    /// The newest held sample's offset, rad.
    latest_rad: [f64; 2],
}

/// What the test remembers.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LaserDispute {
    open: Option<Open>,
    /// Disputes opened so far.
    pub disputes: u64,
    /// Laser samples held out so far.
    pub held_out: u64,
}

/// The larger of the two axes' |x| / √v.
fn sigmas(x: [f64; 2], v: [f64; 2]) -> f64 {
    (0..2)
        .map(|axis| x[axis].abs() / v[axis].max(f64::MIN_POSITIVE).sqrt())
        .fold(0.0, f64::max)
}

impl LaserDispute {
    /// A laser sample at `t`, `offset_rad` (laser − the estimate carried
    /// to it, pitch and roll) where the carried estimate has
    /// `carried_variance` and the laser `laser_variance` (rad²).
    /// `continuity` is whether the inclinometer vouches for the estimate
    /// (the laser monitor agrees, the step watch neither called nor saw a
    /// step that explains the jump, the error model is past its
    /// learning). A dispute lasts `max_hold_s` at most (0: none opens).
    ///
    /// Two samples of one jump differ by at most the two estimates'
    /// errors and the laser's noise twice (taken as independent: the part
    /// of the estimates' errors they share would cancel).
    pub fn judge(
        &mut self,
        t: f64,
        offset_rad: [f64; 2],
        carried_variance: [f64; 2],
        laser_variance: f64,
        continuity: bool,
        max_hold_s: f64,
    ) -> LaserVerdict {
        let variance = carried_variance.map(|v| v + laser_variance);
        let from_estimate = sigmas(offset_rad, variance);
        let Some(open) = self.open else {
            if continuity && max_hold_s > 0.0 && from_estimate > DISAGREE_SIGMAS {
                self.open = Some(Open {
                    since_t: t,
                    offset_rad,
                    carried_variance,
                    latest_rad: offset_rad,
                });
                self.disputes += 1;
                self.held_out += 1;
                return LaserVerdict::HoldOut;
            }
            return LaserVerdict::Fuse;
        };
        let from_jump = sigmas(
            [0, 1].map(|axis| offset_rad[axis] - open.offset_rad[axis]),
            [0, 1].map(|axis| variance[axis] + open.carried_variance[axis] + laser_variance),
        );
        let covered = sigmas(open.offset_rad, variance) <= AGREE_SIGMAS;
        let back = from_estimate <= DISAGREE_SIGMAS && from_estimate < from_jump;
        // Near the jump, or at least twice as near it as the estimate (a
        // sample off by the laser's own scatter beyond its σ still keeps
        // the jump; one that has wandered half as far again does not).
        let consistent = from_jump <= DISAGREE_SIGMAS.max(0.5 * from_estimate);
        let expired = t - open.since_t >= max_hold_s;
        if back || covered || !consistent || expired {
            self.open = None;
            return if back {
                LaserVerdict::LaserBack
            } else {
                LaserVerdict::Fuse
            };
        }
        self.open = Some(Open {
            latest_rad: offset_rad,
            ..open
        });
        self.held_out += 1;
        LaserVerdict::HoldOut
    }

    /// Whether a dispute is open.
    pub fn is_open(&self) -> bool {
        self.open.is_some()
    }

    /// When the open dispute began.
    pub fn since_t(&self) -> Option<f64> {
        self.open.map(|o| o.since_t)
    }

    /// What the open dispute adds to the estimate's variance, pitch and
    /// roll, rad²: J², the case that the laser was right (the larger of
    /// the first held sample's offset and the newest's).
    pub fn variance(&self) -> [f64; 2] {
        self.open.map_or([0.0; 2], |o| {
            [0, 1].map(|axis| o.offset_rad[axis].powi(2).max(o.latest_rad[axis].powi(2)))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // The carried estimate's variance and the laser's: σ = 1e-4 rad in all
    // on each axis, the laser's part 0.5e-8 rad².
    const V: [f64; 2] = [0.5e-8, 0.5e-8];
    const R: f64 = 0.5e-8;
    const HOLD: f64 = 3600.0;

    #[test]
    fn a_jump_the_inclinometer_vouches_against_is_held_out_until_the_laser_comes_back() {
        let mut d = LaserDispute::default();
        // 4σ: no dispute.
        assert_eq!(
            d.judge(0.0, [4e-4, 0.0], V, R, true, HOLD),
            LaserVerdict::Fuse
        );
        // 30σ with continuity: held out, J² added.
        assert_eq!(
            d.judge(60.0, [3e-3, 0.0], V, R, true, HOLD),
            LaserVerdict::HoldOut
        );
        assert_eq!(d.variance(), [9e-6, 0.0]);
        // The same offset again (1σ from it, 31σ from the estimate): held.
        assert_eq!(
            d.judge(120.0, [3.1e-3, 0.0], V, R, true, HOLD),
            LaserVerdict::HoldOut
        );
        assert_eq!(d.since_t(), Some(60.0));
        // Back within 5σ of the estimate and nearer it than the jump.
        assert_eq!(
            d.judge(180.0, [2e-4, 0.0], V, R, true, HOLD),
            LaserVerdict::LaserBack
        );
        assert!(!d.is_open());
        assert_eq!(d.variance(), [0.0, 0.0]);
        assert_eq!((d.disputes, d.held_out), (1, 2));
    }

    #[test]
    fn no_dispute_without_the_inclinometer_vouching() {
        let mut d = LaserDispute::default();
        assert_eq!(
            d.judge(0.0, [3e-3, 0.0], V, R, false, HOLD),
            LaserVerdict::Fuse
        );
        assert!(!d.is_open());
    }

    #[test]
    fn a_sample_near_neither_case_or_a_covered_jump_closes_the_dispute() {
        let mut d = LaserDispute::default();
        assert_eq!(
            d.judge(0.0, [0.0, 3e-3], V, R, true, HOLD),
            LaserVerdict::HoldOut
        );
        // 15σ from the estimate and 15σ/√2 ≈ 10.6σ from the jump: neither.
        assert_eq!(
            d.judge(60.0, [0.0, 1.5e-3], V, R, true, HOLD),
            LaserVerdict::Fuse
        );
        assert!(!d.is_open());

        assert_eq!(
            d.judge(100.0, [0.0, 3e-3], V, R, true, HOLD),
            LaserVerdict::HoldOut
        );
        // The estimate's σ has grown to 1e-3 rad: the 3e-3 jump is 3σ.
        let grown = [1e-6 - R, 1e-6 - R];
        assert_eq!(
            d.judge(900.0, [0.0, 3e-3], grown, R, true, HOLD),
            LaserVerdict::Fuse
        );
        assert!(!d.is_open());
    }

    #[test]
    fn a_dispute_ends_at_the_declared_hold_and_none_opens_with_none_declared() {
        let mut d = LaserDispute::default();
        assert_eq!(
            d.judge(0.0, [3e-3, 0.0], V, R, true, 600.0),
            LaserVerdict::HoldOut
        );
        assert_eq!(
            d.judge(599.0, [3e-3, 0.0], V, R, true, 600.0),
            LaserVerdict::HoldOut
        );
        assert_eq!(
            d.judge(600.0, [3e-3, 0.0], V, R, true, 600.0),
            LaserVerdict::Fuse
        );
        assert!(!d.is_open());
        assert_eq!(
            d.judge(700.0, [6e-3, 0.0], V, R, true, 0.0),
            LaserVerdict::Fuse
        );
        assert!(!d.is_open());
    }
}
