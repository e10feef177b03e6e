//! The service's clock: how old a sensor's last reading is (the machine
//! layer's silent-sensor alarms) and how far in the future a reading may be
//! (the server's ingest). Engines never see it; their time comes with the
//! readings.
//!
//! Normally the system clock. The demo runs an accelerated clock (a
//! 2-minute laser period every few seconds) and gives the same clock to
//! its simulated gateways, so ages and the future check stay consistent.

use std::time::{SystemTime, UNIX_EPOCH};

/// Unix seconds, possibly accelerated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clock {
    /// Server seconds per real second.
    rate: f64,
    /// The real time at which the clock read `origin_s`.
    origin_wall_s: f64,
    origin_s: f64,
}

impl Clock {
    /// The system clock.
    pub fn system() -> Clock {
        Clock {
            rate: 1.0,
            origin_wall_s: 0.0,
            origin_s: 0.0,
        }
    }

    /// A clock that reads `start_s` now and runs `rate` times faster than
    /// real time. `rate` must be finite and > 0.
    pub fn accelerated(rate: f64, start_s: f64) -> Result<Clock, String> {
        if !(rate.is_finite() && rate > 0.0 && start_s.is_finite()) {
            return Err(format!(
                "clock rate {rate} from {start_s}: need a finite rate > 0"
            ));
        }
        Ok(Clock {
            rate,
            origin_wall_s: wall_clock_s(),
            origin_s: start_s,
        })
    }

    /// Now, Unix seconds.
    pub fn now_s(&self) -> f64 {
        self.origin_s + (wall_clock_s() - self.origin_wall_s) * self.rate
    }

    /// Server seconds per real second (1 for the system clock).
    pub fn rate(&self) -> f64 {
        self.rate
    }

    /// Real seconds until the clock reads `t_s` (≤ 0 if it already has).
    pub fn real_s_until(&self, t_s: f64) -> f64 {
        (t_s - self.now_s()) / self.rate
    }
}

impl Default for Clock {
    fn default() -> Self {
        Clock::system()
    }
}

/// The system clock, Unix seconds.
pub fn wall_clock_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn system_clock_follows_the_wall() {
        let clock = Clock::system();
        let (before, now, after) = (wall_clock_s(), clock.now_s(), wall_clock_s());
        assert!(before <= now && now <= after);
        assert_eq!(clock.rate(), 1.0);
    }

    #[test]
    fn accelerated_clock_starts_where_asked_and_runs_fast() {
        let clock = Clock::accelerated(100.0, 1_000.0).unwrap();
        let start = clock.now_s();
        assert!((1_000.0..1_001.0).contains(&start), "{start}");
        std::thread::sleep(std::time::Duration::from_millis(50));
        let elapsed = clock.now_s() - start;
        // 50 ms real is 5 s on the clock (generous upper bound for a busy host).
        assert!((4.9..60.0).contains(&elapsed), "{elapsed}");
        assert!(clock.real_s_until(start + 1_000.0) < 10.0);
        assert!(Clock::accelerated(0.0, 0.0).is_err());
        assert!(Clock::accelerated(f64::NAN, 0.0).is_err());
    }
}
