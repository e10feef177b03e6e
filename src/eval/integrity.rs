//! How an engine's `integrity` met its errors on a drive with a truth
//! (issue 54's bars): the share of estimates flagged (not `ok`), and the
//! longest run of estimates shown `ok` whose error exceeded five σ and the
//! quantity's floor (misleading). A run is measured from its first
//! misleading estimate to its last, so one estimate alone is 0 s.

use serde::Serialize;

use crate::fusion::{Integrity, IntegrityLevel};

/// Errors beyond this many σ are misleading when shown as `ok`.
pub const MISLEADING_SIGMAS: f64 = 5.0;
/// The bar: no misleading run longer than this, s.
pub const MAX_MISLEADING_RUN_S: f64 = 10.0;
/// The bar on ordinary drives: at most this share flagged.
pub const MAX_FLAGGED_SHARE: f64 = 0.10;

/// Whether an error of `error` with 1σ `sigma` is beyond five σ and
/// `floor` (an estimate without a σ vouches for nothing: beyond the floor
/// is enough).
pub fn misleading(error: f64, sigma: Option<f64>, floor: f64) -> bool {
    let e = error.abs();
    e > floor && sigma.is_none_or(|s| e > MISLEADING_SIGMAS * s)
}

/// One drive's integrity figures.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct IntegrityScore {
    /// Estimates scored.
    pub estimates: u64,
    /// Of them `degraded` and `lost`.
    pub degraded: u64,
    pub lost: u64,
    /// Estimates shown `ok` that were misleading.
    pub misleading_ok: u64,
    /// The longest run of misleading `ok` estimates, s, and when it began.
    pub worst_run_s: f64,
    pub worst_run_from_t: Option<f64>,
    #[serde(skip)]
    run_from_t: Option<f64>,
}

impl IntegrityScore {
    /// Scores one estimate at `t`.
    pub fn add(&mut self, t: f64, integrity: Integrity, misleading: bool) {
        self.estimates += 1;
        match integrity.level {
            IntegrityLevel::Ok => {}
            IntegrityLevel::Degraded => self.degraded += 1,
            IntegrityLevel::Lost => self.lost += 1,
        }
        if misleading && integrity.is_ok() {
            self.misleading_ok += 1;
            let from = *self.run_from_t.get_or_insert(t);
            if t - from >= self.worst_run_s {
                self.worst_run_s = t - from;
                self.worst_run_from_t = Some(from);
            }
        } else {
            self.run_from_t = None;
        }
    }

    /// The share of estimates not `ok`.
    pub fn flagged_share(&self) -> f64 {
        if self.estimates == 0 {
            0.0
        } else {
            (self.degraded + self.lost) as f64 / self.estimates as f64
        }
    }

    /// Whether no misleading run lasted longer than the bar.
    pub fn run_bar_met(&self) -> bool {
        self.worst_run_s <= MAX_MISLEADING_RUN_S
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::IntegrityReason;

    #[test]
    fn a_run_counts_only_misleading_estimates_shown_ok() {
        assert!(misleading(1.1, Some(0.2), 1.0));
        assert!(!misleading(0.9, Some(0.1), 1.0));
        assert!(!misleading(2.0, Some(0.5), 1.0));
        assert!(misleading(-2.0, None, 1.0));
        let mut score = IntegrityScore::default();
        let lost = Integrity::lost(IntegrityReason::TiltDisagrees);
        for i in 0..10 {
            score.add(f64::from(i), Integrity::OK, true);
        }
        // 0 … 9 s: a run of 9 s; a lost estimate ends it.
        score.add(10.0, lost, true);
        score.add(11.0, Integrity::OK, true);
        score.add(
            12.0,
            Integrity::degraded(IntegrityReason::Recovering),
            false,
        );
        assert_eq!(score.worst_run_s, 9.0);
        assert_eq!(score.worst_run_from_t, Some(0.0));
        assert_eq!((score.estimates, score.lost, score.degraded), (13, 1, 1));
        assert_eq!(score.misleading_ok, 11);
        assert!((score.flagged_share() - 2.0 / 13.0).abs() < 1e-12);
        assert!(score.run_bar_met());
    }
}
