//! A condition made an alarm state: it must hold for a minimum time before
//! the alarm is raised and be gone for a minimum time before it clears, and
//! a value compared with a limit must fall a hysteresis band below it to
//! count as gone, so a value hovering at a limit does not flap.

use serde::{Deserialize, Serialize};

/// A limit with a band below it: exceeded above `limit`; once exceeded,
/// still exceeded until the value falls below `limit − band`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Hysteresis {
    pub limit: f64,
    pub band: f64,
}

impl Hysteresis {
    /// Whether `value` is beyond the limit, given whether it was.
    pub fn exceeded(&self, value: f64, was: bool) -> bool {
        if was {
            value > self.limit - self.band
        } else {
            value > self.limit
        }
    }
}

/// What a debounced condition did at an update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Edge {
    /// Held for the minimum time: active from `onset_t`.
    Raised { onset_t: f64 },
    /// Gone for the minimum time: inactive from `gone_t`.
    Cleared { gone_t: f64 },
}

/// A condition with minimum durations for raising and clearing. Times are
/// the data's (reading or server-clock seconds), never a wall clock.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Debounced {
    /// Raised (and not yet cleared).
    pub active: bool,
    /// When the condition last changed away from `active`, if it has not
    /// changed back since: the start of a pending raise or clear.
    pending_since_t: Option<f64>,
    /// When the active condition began (absent in snapshots from before
    /// it was kept): a clear is never dated before it, even when late data
    /// (a gateway forwarding what it buffered) says the condition ended
    /// earlier than it was seen.
    #[serde(default)]
    onset_t: Option<f64>,
}

/// How long a debounced condition must hold before it is raised, be gone
/// before it clears, and at least how long a raised alarm stays raised
/// (from its onset), s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timing {
    pub raise_s: f64,
    pub clear_s: f64,
    pub hold_s: f64,
}

impl Timing {
    /// The same minimum for raising and clearing, no hold.
    pub fn symmetric(min_s: f64) -> Timing {
        Timing {
            raise_s: min_s,
            clear_s: min_s,
            hold_s: 0.0,
        }
    }
}

impl Debounced {
    /// The condition at `t`: `holds` now. `min_s` is the minimum time for
    /// both raising and clearing (0: at once).
    pub fn update(&mut self, t: f64, holds: bool, min_s: f64) -> Option<Edge> {
        self.update_timed(t, holds, Timing::symmetric(min_s))
    }

    /// The condition at `t` with separate minimum times and a hold: a
    /// raised alarm clears only once the condition has been gone
    /// `clear_s` and `hold_s` have passed since its onset.
    pub fn update_timed(&mut self, t: f64, holds: bool, timing: Timing) -> Option<Edge> {
        if holds == self.active {
            self.pending_since_t = None;
            return None;
        }
        let since = *self.pending_since_t.get_or_insert(t);
        let min_s = if holds {
            timing.raise_s
        } else {
            timing.clear_s
        };
        if t - since < min_s {
            return None;
        }
        if !holds
            && timing.hold_s > 0.0
            && self
                .onset_t
                .is_some_and(|onset_t| t - onset_t < timing.hold_s)
        {
            return None;
        }
        self.active = holds;
        self.pending_since_t = None;
        Some(if holds {
            self.onset_t = Some(since);
            Edge::Raised { onset_t: since }
        } else {
            let onset_t = self.onset_t.take().unwrap_or(since);
            Edge::Cleared {
                gone_t: since.max(onset_t),
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_hovering_at_the_limit_does_not_flap() {
        let limit = Hysteresis {
            limit: 50.0,
            band: 5.0,
        };
        let mut was = false;
        let mut changes = 0;
        // 49.5, 50.5, 49.5, ... : above the limit, then never below 45.
        for i in 0..20 {
            let value = if i % 2 == 0 { 49.5 } else { 50.5 };
            let now = limit.exceeded(value, was);
            changes += usize::from(now != was);
            was = now;
        }
        assert_eq!(changes, 1);
        assert!(limit.exceeded(45.5, true) && !limit.exceeded(44.9, true));
    }

    #[test]
    fn raised_after_the_minimum_time_and_cleared_after_it_again() {
        let mut d = Debounced::default();
        // Holds from t = 10; a 30 s minimum raises it at t = 40, dated 10.
        assert_eq!(d.update(0.0, false, 30.0), None);
        assert_eq!(d.update(10.0, true, 30.0), None);
        assert_eq!(d.update(39.0, true, 30.0), None);
        assert_eq!(
            d.update(40.0, true, 30.0),
            Some(Edge::Raised { onset_t: 10.0 })
        );
        assert!(d.active);
        // A 20 s gap is too short to clear; the pending clear restarts.
        assert_eq!(d.update(50.0, false, 30.0), None);
        assert_eq!(d.update(70.0, true, 30.0), None);
        assert_eq!(d.update(80.0, false, 30.0), None);
        assert_eq!(d.update(109.0, false, 30.0), None);
        assert_eq!(
            d.update(110.0, false, 30.0),
            Some(Edge::Cleared { gone_t: 80.0 })
        );
        assert!(!d.active);
        // Without a minimum, at once.
        assert_eq!(
            d.update(111.0, true, 0.0),
            Some(Edge::Raised { onset_t: 111.0 })
        );
    }

    #[test]
    fn late_data_never_dates_a_clear_before_its_raise() {
        let mut d = Debounced::default();
        assert_eq!(
            d.update(50.0, true, 0.0),
            Some(Edge::Raised { onset_t: 50.0 })
        );
        // A reading stamped 41 s, forwarded late, ends it: cleared at 50 s.
        assert_eq!(
            d.update(41.0, false, 0.0),
            Some(Edge::Cleared { gone_t: 50.0 })
        );
        assert_eq!(
            d.update(60.0, true, 0.0),
            Some(Edge::Raised { onset_t: 60.0 })
        );
        assert_eq!(
            d.update(70.0, false, 0.0),
            Some(Edge::Cleared { gone_t: 70.0 })
        );
    }

    #[test]
    fn a_blip_shorter_than_the_minimum_raises_nothing() {
        let mut d = Debounced::default();
        for (t, holds) in [
            (0.0, true),
            (5.0, true),
            (9.0, false),
            (12.0, true),
            (20.0, false),
        ] {
            assert_eq!(d.update(t, holds, 10.0), None, "{t}");
        }
        assert!(!d.active);
    }

    #[test]
    fn a_raised_alarm_is_held_for_its_minimum_and_clears_by_its_own_minimum() {
        let timing = Timing {
            raise_s: 10.0,
            clear_s: 5.0,
            hold_s: 60.0,
        };
        let mut d = Debounced::default();
        assert_eq!(d.update_timed(0.0, true, timing), None);
        assert_eq!(
            d.update_timed(10.0, true, timing),
            Some(Edge::Raised { onset_t: 0.0 })
        );
        // Gone from t = 20: 5 s would do, but the hold keeps it to t = 60;
        // the clear is dated when the condition went.
        for t in [20.0, 30.0, 59.0] {
            assert_eq!(d.update_timed(t, false, timing), None, "{t}");
        }
        assert_eq!(
            d.update_timed(60.0, false, timing),
            Some(Edge::Cleared { gone_t: 20.0 })
        );
        // Raised again at 70 (dated 60) and gone at 140, past the hold:
        // cleared after 5 s.
        assert_eq!(d.update_timed(60.0, true, timing), None);
        assert_eq!(
            d.update_timed(70.0, true, timing),
            Some(Edge::Raised { onset_t: 60.0 })
        );
        assert_eq!(d.update_timed(140.0, false, timing), None);
        assert_eq!(
            d.update_timed(145.0, false, timing),
            Some(Edge::Cleared { gone_t: 140.0 })
        );
    }
}
