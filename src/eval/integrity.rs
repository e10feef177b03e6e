//! How an engine's `integrity` met its errors on a drive with a truth
//! (issue 54's bars): the share of estimates flagged (not `ok`), and the
//! longest run of estimates shown `ok` whose error exceeded five σ and the
//! quantity's floor (misleading). A run is measured from its first
//! misleading estimate to its last, so one estimate alone is 0 s.

use serde::Serialize;

use super::attitude::Spread;
use crate::fusion::{Integrity, IntegrityLevel};
use crate::sim::faults::FaultWindow;

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
    /// With a fault injected: how the engine met it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fault: Option<FaultFigures>,
}

/// A drive counts as recovered from a fault once its estimates are `ok`
/// and not misleading for this long after the fault's end, s.
pub const RECOVERED_AFTER_S: f64 = 60.0;

/// A fault's reach: from its onset to this long after its end, s. An
/// alert or a misleading run that begins in it is the fault's.
pub const REACH_AFTER_S: f64 = 600.0;

/// How an engine met an injected fault (issue 54, item 7).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FaultFigures {
    pub window: FaultWindow,
    /// From the onset to the first estimate not `ok` in the fault's
    /// reach, s; `None`: not flagged in it.
    pub alert_s: Option<f64>,
    /// The longest misleading `ok` run that began in the fault's reach, s.
    pub worst_run_s: f64,
    /// From the fault's end to the start of the first
    /// [`RECOVERED_AFTER_S`] of `ok`, not misleading estimates, s; `None`:
    /// never.
    pub recover_s: Option<f64>,
    /// Estimates from the onset to the end (or to the onset plus
    /// [`RECOVERED_AFTER_S`] for a step), and of them not `ok`.
    pub during: u64,
    pub during_flagged: u64,
    #[serde(skip)]
    calm_from_t: Option<f64>,
    #[serde(skip)]
    run_from_t: Option<f64>,
}

impl FaultFigures {
    /// Figures to collect for `window`.
    pub fn new(window: FaultWindow) -> FaultFigures {
        FaultFigures {
            window,
            alert_s: None,
            worst_run_s: 0.0,
            recover_s: None,
            during: 0,
            during_flagged: 0,
            calm_from_t: None,
            run_from_t: None,
        }
    }

    /// The share of the estimates during the fault not `ok`.
    pub fn flagged_share(&self) -> f64 {
        if self.during == 0 {
            0.0
        } else {
            self.during_flagged as f64 / self.during as f64
        }
    }

    fn add(&mut self, t: f64, integrity: Integrity, misleading: bool) {
        let w = self.window;
        if t < w.from_t {
            return;
        }
        let flagged = !integrity.is_ok();
        let in_reach = t <= w.to_t + REACH_AFTER_S;
        if flagged && in_reach && self.alert_s.is_none() {
            self.alert_s = Some(t - w.from_t);
        }
        if misleading && !flagged {
            match self.run_from_t {
                Some(from) => self.worst_run_s = self.worst_run_s.max(t - from),
                None if in_reach => self.run_from_t = Some(t),
                None => {}
            }
        } else {
            self.run_from_t = None;
        }
        if t <= w.to_t.max(w.from_t + RECOVERED_AFTER_S) {
            self.during += 1;
            self.during_flagged += u64::from(flagged);
        }
        if t < w.to_t || self.recover_s.is_some() {
            return;
        }
        if flagged || misleading {
            self.calm_from_t = None;
        } else {
            let from = *self.calm_from_t.get_or_insert(t);
            if t - from >= RECOVERED_AFTER_S {
                self.recover_s = Some(from - w.to_t);
            }
        }
    }
}

impl IntegrityScore {
    /// A score that also measures how the engine met the fault of
    /// `window`.
    pub fn with_fault(window: Option<FaultWindow>) -> IntegrityScore {
        IntegrityScore {
            fault: window.map(FaultFigures::new),
            ..IntegrityScore::default()
        }
    }

    /// Scores one estimate at `t`.
    pub fn add(&mut self, t: f64, integrity: Integrity, misleading: bool) {
        if let Some(fault) = &mut self.fault {
            fault.add(t, integrity, misleading);
        }
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

/// How the engine met one fault category over an envelope's drives
/// (median and worst of each figure; a drive never alerted or never
/// recovered is counted, not averaged).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FaultSummary {
    pub fault: crate::sim::faults::FaultKind,
    pub drives: usize,
    /// Drives flagged after the onset, and the time to it.
    pub alerted: usize,
    pub alert_s: Spread,
    /// Drives recovered, and the time from the fault's end.
    pub recovered: usize,
    pub recover_s: Spread,
    /// Share of estimates flagged during the fault.
    pub flagged_share: Spread,
    /// The longest misleading `ok` run begun in the fault's reach, s.
    pub misleading_run_s: Spread,
}

impl FaultSummary {
    /// The summary of `scores`, if a fault was injected into them.
    pub fn of<'a>(scores: impl IntoIterator<Item = &'a IntegrityScore>) -> Option<FaultSummary> {
        let scores: Vec<&IntegrityScore> = scores.into_iter().collect();
        let figures: Vec<FaultFigures> = scores.iter().filter_map(|s| s.fault).collect();
        let first = figures.first()?;
        let alerts: Vec<f64> = figures.iter().filter_map(|f| f.alert_s).collect();
        let recoveries: Vec<f64> = figures.iter().filter_map(|f| f.recover_s).collect();
        let flagged: Vec<f64> = figures.iter().map(FaultFigures::flagged_share).collect();
        let runs: Vec<f64> = figures.iter().map(|f| f.worst_run_s).collect();
        Some(FaultSummary {
            fault: first.window.kind,
            drives: figures.len(),
            alerted: alerts.len(),
            alert_s: Spread::of(&alerts),
            recovered: recoveries.len(),
            recover_s: Spread::of(&recoveries),
            flagged_share: Spread::of(&flagged),
            misleading_run_s: Spread::of(&runs),
        })
    }

    /// One line per figure, for the envelope's text.
    pub fn render(&self) -> String {
        let n = self.drives;
        format!(
            "fault {} on {n} drives:\n  \
             time to alert (flagged within {REACH_AFTER_S:.0} s of its end): on {} of {n}, median {:.1} s, longest {:.1} s\n  \
             longest misleading ok run begun then: median {:.1} s, longest {:.1} s\n  \
             flagged during the fault: median {:.1} %, largest {:.1} %\n  \
             time to recover ({RECOVERED_AFTER_S:.0} s ok and right after its end): recovered on {} of {n}, median {:.1} s, longest {:.1} s\n",
            self.fault.as_str(),
            self.alerted,
            self.alert_s.median,
            self.alert_s.worst,
            self.misleading_run_s.median,
            self.misleading_run_s.worst,
            100.0 * self.flagged_share.median,
            100.0 * self.flagged_share.worst,
            self.recovered,
            self.recover_s.median,
            self.recover_s.worst,
        )
    }

    /// The bar on fault drives: every drive recovers.
    pub fn recovery_bar(&self) -> super::Bar {
        super::Bar {
            bar: format!(
                "fault {}: the engine recovers on every drive (no lock-out)",
                self.fault.as_str()
            ),
            measured: format!("recovered on {} of {}", self.recovered, self.drives),
            met: self.recovered == self.drives,
        }
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

    #[test]
    fn a_fault_is_alerted_then_recovered_after_a_calm_minute() {
        use crate::sim::faults::FaultKind;
        let window = FaultWindow {
            kind: FaultKind::Frozen,
            from_t: 100.0,
            to_t: 220.0,
        };
        let mut score = IntegrityScore::with_fault(Some(window));
        let lost = Integrity::lost(IntegrityReason::TiltDisagrees);
        // Ok until 104, lost 104 … 230, then ok but misleading at 240,
        // then calm from 241 on.
        for i in 0..=400 {
            let t = f64::from(i);
            let integrity = if (104.0..=230.0).contains(&t) {
                lost
            } else {
                Integrity::OK
            };
            score.add(t, integrity, t == 240.0);
        }
        let fault = score.fault.expect("figures");
        assert_eq!(fault.alert_s, Some(4.0));
        assert_eq!(fault.worst_run_s, 0.0);
        // Recovered from 241: 21 s after the end.
        assert_eq!(fault.recover_s, Some(21.0));
        // During 100 … 220: 121 estimates, 117 of them lost.
        assert_eq!((fault.during, fault.during_flagged), (121, 117));
    }
}
