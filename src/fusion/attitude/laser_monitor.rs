//! The `attitude` engine's integrity monitor (issue 54): each laser
//! sample against the estimate the engine showed just before it.
//!
//! Between laser samples the pitch rests on the inclinometer and the
//! learned model of its error; its σ says how far that may have strayed.
//! A laser sample is independent evidence of how far it did: with the
//! shown pitch p̂ (1σ σ̂) and the laser's noise variance r,
//! z = |laser − p̂| / √(σ̂² + r), and likewise for roll; the larger counts. Beyond [`DISAGREE_SIGMAS`] the σ shown
//! did not bound the error: the estimates are `degraded`
//! (`laser_disagrees`) until a sample passes again (z ≤
//! [`AGREE_SIGMAS`]); meanwhile the excess the laser found widens the σ
//! (the engine's precision-weighted laser error). At the start the
//! estimates are `degraded` (`unverified`) until [`VERIFY_SAMPLES`]
//! samples after the first have passed: the first only sets the filter,
//! the ones after it test what the engine carried between samples.
//!
//! With honest Gaussian errors a sample fails at z > 5 once in 1.7 million;
//! the rate on the envelope's drives is in docs/engines/attitude.md.

use serde::{Deserialize, Serialize};

use crate::fusion::integrity::{Integrity, IntegrityReason};

/// A laser sample further than this many σ from the estimate shown fails.
pub const DISAGREE_SIGMAS: f64 = 5.0;
/// A sample within this many σ passes.
pub const AGREE_SIGMAS: f64 = 3.0;
/// Samples after the first that must pass before the engine vouches.
pub const VERIFY_SAMPLES: u32 = 2;

/// What the monitor remembers.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LaserMonitor {
    /// Laser samples checked so far.
    samples: u32,
    /// Of them, passes in a row (the first sample not counted).
    passes_in_a_row: u32,
    /// The newest check failed and none has passed since.
    disagreeing: bool,
    /// [`VERIFY_SAMPLES`] have passed in a row, once.
    verified: bool,
    /// Checks failed so far.
    pub failures: u64,
}

impl LaserMonitor {
    /// A laser sample `normalised_error` (z) from the estimate shown.
    pub fn check(&mut self, normalised_error: f64) {
        self.samples += 1;
        if self.samples == 1 {
            return;
        }
        if normalised_error > DISAGREE_SIGMAS || !normalised_error.is_finite() {
            self.disagreeing = true;
            self.passes_in_a_row = 0;
            self.failures += 1;
        } else if normalised_error <= AGREE_SIGMAS {
            self.disagreeing = false;
            self.passes_in_a_row = self.passes_in_a_row.saturating_add(1);
            self.verified |= self.passes_in_a_row >= VERIFY_SAMPLES;
        }
    }

    /// Laser samples checked so far.
    pub fn checks(&self) -> usize {
        self.samples as usize
    }

    /// Takes back the failures since the last pass: they were the
    /// laser's, held out by the dispute ([`super::laser_dispute`]), not the
    /// estimate's.
    pub fn forgive(&mut self) {
        self.disagreeing = false;
    }

    /// Whether the engine vouches for its estimates: verified, and no
    /// check has failed since the last pass.
    pub fn agreeing(&self) -> bool {
        self.verified && !self.disagreeing
    }

    /// The integrity of the estimates now.
    pub fn integrity(&self) -> Integrity {
        if self.disagreeing {
            Integrity::degraded(IntegrityReason::LaserDisagrees)
        } else if !self.verified {
            Integrity::degraded(IntegrityReason::Unverified)
        } else {
            Integrity::OK
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unverified_until_two_samples_after_the_first_pass_then_degraded_only_while_one_fails() {
        let mut m = LaserMonitor::default();
        let reason = |m: &LaserMonitor| m.integrity().reason;
        assert_eq!(reason(&m), Some(IntegrityReason::Unverified));
        m.check(40.0); // the first: sets the filter, not a test
        assert_eq!(reason(&m), Some(IntegrityReason::Unverified));
        m.check(1.0);
        assert_eq!(reason(&m), Some(IntegrityReason::Unverified));
        m.check(2.9);
        assert_eq!(m.integrity(), Integrity::OK);
        // 4σ: neither fails nor passes; 6σ fails until one passes.
        m.check(4.0);
        assert_eq!(m.integrity(), Integrity::OK);
        m.check(6.0);
        assert_eq!(reason(&m), Some(IntegrityReason::LaserDisagrees));
        m.check(4.0);
        assert_eq!(reason(&m), Some(IntegrityReason::LaserDisagrees));
        m.check(0.5);
        assert_eq!(m.integrity(), Integrity::OK);
        assert_eq!(m.failures, 1);
    }
}
