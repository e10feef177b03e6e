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

impl Debounced {
    /// The condition at `t`: `holds` now. `min_s` is the minimum time for
    /// both raising and clearing (0: at once).
    pub fn update(&mut self, t: f64, holds: bool, min_s: f64) -> Option<Edge> {
        if holds == self.active {
            self.pending_since_t = None;
            return None;
        }
        let since = *self.pending_since_t.get_or_insert(t);
        if t - since < min_s {
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
}
