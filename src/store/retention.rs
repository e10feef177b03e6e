//! Retention: raw readings kept for a number of days, estimates at full
//! rate for a number of days and then thinned to one a minute (the
//! per-bucket extremes stay, so history over old ranges still shows every
//! spike).
//!
//! A pass is planned ([`plan_steps`], `Backend::retention_plan`) and done
//! step by step between the writer's group commits
//! (`Backend::retention_step`): each step a short transaction of at most
//! `batch` rows or one thinning window, so ingest waits for a few
//! milliseconds at a time and nothing else writes. A reading is deleted only if its machine's latest snapshot already
//! covers it: restart re-feeds the readings after the snapshot, and those
//! are never pruned. A gateway resending a pruned reading gets it stored
//! again, as a late reading (stored, not fused).

use super::error::StoreError;
use crate::fusion::StreamKind;

/// What to keep, and how often the server applies it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Retention {
    /// Raw readings older than this (s, against reading time) are deleted.
    pub keep_readings_s: Option<f64>,
    /// Estimates older than this (s) are thinned to one per minute.
    pub full_estimates_s: Option<f64>,
    /// Seconds between passes.
    pub every_s: f64,
}

impl Default for Retention {
    /// Keep everything; a pass an hour once a policy is set.
    fn default() -> Self {
        Retention {
            keep_readings_s: None,
            full_estimates_s: None,
            every_s: 3600.0,
        }
    }
}

impl Retention {
    /// True when the policy deletes nothing.
    pub fn keeps_everything(&self) -> bool {
        self.keep_readings_s.is_none() && self.full_estimates_s.is_none()
    }
}

/// What a pass deleted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Pruned {
    pub readings: u64,
    pub estimates: u64,
}

/// Width of the windows estimates are thinned in, s.
const THIN_WINDOW_S: f64 = 600.0;
/// One estimate kept per this many seconds.
pub const THIN_TO_S: f64 = 60.0;

/// One unit of a pass, its own short transaction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Step {
    /// Delete up to `batch` readings older than `cut` that their
    /// machine's snapshot covers; again while a full batch went
    /// ([`Step::again`]).
    Readings { cut: f64, batch: usize },
    /// Thin one machine's estimates of one stream in `[from, to)`.
    Thin {
        machine: i64,
        stream: StreamKind,
        from: f64,
        to: f64,
    },
}

/// The steps of a pass of `policy` at `now_t` over `machines`, `oldest`
/// answering the time of a machine's oldest estimate of a stream.
pub fn plan_steps(
    now_t: f64,
    policy: &Retention,
    batch: usize,
    machines: &[i64],
    mut oldest: impl FnMut(i64, StreamKind) -> Result<Option<f64>, StoreError>,
) -> Result<Vec<Step>, StoreError> {
    let mut steps = Vec::new();
    if let Some(keep_s) = policy.keep_readings_s {
        steps.push(Step::Readings {
            cut: now_t - keep_s,
            batch,
        });
    }
    if let Some(full_s) = policy.full_estimates_s {
        let cut = now_t - full_s;
        for &machine in machines {
            for &stream in StreamKind::ALL {
                let Some(oldest) = oldest(machine, stream)? else {
                    continue;
                };
                let mut from = (oldest / THIN_WINDOW_S).floor() * THIN_WINDOW_S;
                while from < cut {
                    let to = (from + THIN_WINDOW_S).min(cut);
                    steps.push(Step::Thin {
                        machine,
                        stream,
                        from,
                        to,
                    });
                    from = to;
                }
            }
        }
    }
    Ok(steps)
}

impl Step {
    /// Whether the step has more to do after deleting `pruned`.
    pub fn again(&self, pruned: &Pruned) -> bool {
        matches!(*self, Step::Readings { batch, .. } if pruned.readings >= batch as u64)
    }
}

impl Pruned {
    /// Adds what another step deleted.
    pub fn add(&mut self, other: Pruned) {
        self.readings += other.readings;
        self.estimates += other.estimates;
    }
}
