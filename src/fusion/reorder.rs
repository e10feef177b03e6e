//! A small reorder buffer that puts a machine's readings back into time
//! order before they reach the engines.
//!
//! Readings are held until the newest time seen is `window_s` past them,
//! then released oldest first. A reading older than one already released
//! is *late* and dropped; a second reading of the same sensor at the same
//! time is a *duplicate* and dropped (the first one received wins). Both are
//! counted. Memory is bounded by `max_len`: past it the oldest reading is
//! released early.

use std::cmp::Ordering;
use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use super::reading::{Reading, SensorKind};

/// Counts of what the buffer did.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ReorderStats {
    /// Readings released in time order.
    pub released: u64,
    /// Readings dropped because a later one had already been released.
    pub late: u64,
    /// Readings dropped because the same sensor already had a reading at that time.
    pub duplicates: u64,
}

/// What happened to a pushed reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admission {
    /// Buffered; it will come out of [`ReorderBuffer::pop_ready`].
    Buffered,
    /// Older than a reading already released: dropped.
    Late,
    /// Same sensor and time as a reading already released: dropped.
    Duplicate,
}

#[derive(Debug, Clone)]
struct Entry {
    reading: Reading,
    /// Arrival order, so ties keep the first received first.
    seq: u64,
}

impl Entry {
    /// Release order: time, then sensor (protocol order), then arrival.
    fn key(&self) -> (f64, SensorKind, u64) {
        (self.reading.t, self.reading.sensor(), self.seq)
    }

    fn before(&self, other: &Entry) -> bool {
        let (ta, sa, qa) = self.key();
        let (tb, sb, qb) = other.key();
        ta.total_cmp(&tb).then(sa.cmp(&sb)).then(qa.cmp(&qb)) == Ordering::Less
    }
}

/// Time-orders readings within a sliding window.
#[derive(Debug, Clone)]
pub struct ReorderBuffer {
    window_s: f64,
    max_len: usize,
    /// Held readings in release order. Streams are mostly in order, so a
    /// new reading usually goes at the back.
    held: VecDeque<Entry>,
    newest_t: f64,
    /// Time and sensors of the most recently released instant, for
    /// duplicate detection.
    released_t: f64,
    released_sensors: Vec<SensorKind>,
    seq: u64,
    stats: ReorderStats,
}

impl ReorderBuffer {
    /// A buffer holding readings for `window_s` seconds, at most `max_len` of them.
    pub fn new(window_s: f64, max_len: usize) -> ReorderBuffer {
        ReorderBuffer {
            window_s: window_s.max(0.0),
            max_len: max_len.max(1),
            held: VecDeque::new(),
            newest_t: f64::NEG_INFINITY,
            released_t: f64::NEG_INFINITY,
            released_sensors: Vec::new(),
            seq: 0,
            stats: ReorderStats::default(),
        }
    }

    /// Offers a reading.
    pub fn push(&mut self, reading: Reading) -> Admission {
        if reading.t < self.released_t {
            self.stats.late += 1;
            return Admission::Late;
        }
        if reading.t == self.released_t && self.released_sensors.contains(&reading.sensor()) {
            self.stats.duplicates += 1;
            return Admission::Duplicate;
        }
        self.newest_t = self.newest_t.max(reading.t);
        self.seq += 1;
        let entry = Entry {
            reading,
            seq: self.seq,
        };
        match self.held.back() {
            Some(last) if entry.before(last) => {
                let at = self.held.partition_point(|e| e.before(&entry));
                self.held.insert(at, entry);
            }
            _ => self.held.push_back(entry),
        }
        Admission::Buffered
    }

    /// Releases, in time order, every reading whose window has passed.
    pub fn pop_ready(&mut self, out: &mut Vec<Reading>) {
        let horizon = self.newest_t - self.window_s;
        while let Some(first) = self.held.front() {
            if first.reading.t <= horizon || self.held.len() > self.max_len {
                self.release_top(out);
            } else {
                break;
            }
        }
    }

    /// Releases everything still held (end of input).
    pub fn drain(&mut self, out: &mut Vec<Reading>) {
        while !self.held.is_empty() {
            self.release_top(out);
        }
    }

    fn release_top(&mut self, out: &mut Vec<Reading>) {
        let Some(entry) = self.held.pop_front() else {
            return;
        };
        let reading = entry.reading;
        let sensor = reading.sensor();
        if reading.t == self.released_t {
            if self.released_sensors.contains(&sensor) {
                self.stats.duplicates += 1;
                return;
            }
        } else {
            self.released_t = reading.t;
            self.released_sensors.clear();
        }
        self.released_sensors.push(sensor);
        self.stats.released += 1;
        out.push(reading);
    }

    /// Readings currently held.
    pub fn len(&self) -> usize {
        self.held.len()
    }

    /// True when nothing is held.
    pub fn is_empty(&self) -> bool {
        self.held.is_empty()
    }

    /// What the buffer has done so far.
    pub fn stats(&self) -> ReorderStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::reading::SensorData;

    fn incl(t: f64, pitch_deg: f64) -> Reading {
        Reading {
            t,
            data: SensorData::Inclinometer {
                pitch_deg,
                roll_deg: 0.0,
                temp_c: None,
            },
        }
    }

    fn laser(t: f64) -> Reading {
        Reading {
            t,
            data: SensorData::Laser {
                pitch_deg: 0.0,
                roll_deg: 0.0,
                yaw_deg: None,
            },
        }
    }

    fn times(out: &[Reading]) -> Vec<f64> {
        out.iter().map(|r| r.t).collect()
    }

    #[test]
    fn restores_order_within_window() {
        let mut buf = ReorderBuffer::new(2.0, 100);
        let mut out = Vec::new();
        for t in [10.0, 12.0, 11.0, 13.0, 15.0, 14.0] {
            buf.push(incl(t, t));
            buf.pop_ready(&mut out);
        }
        assert_eq!(times(&out), vec![10.0, 11.0, 12.0, 13.0]);
        buf.drain(&mut out);
        assert_eq!(times(&out), vec![10.0, 11.0, 12.0, 13.0, 14.0, 15.0]);
    }

    #[test]
    fn drops_late_and_duplicates_keeping_first() {
        let mut buf = ReorderBuffer::new(1.0, 100);
        let mut out = Vec::new();
        buf.push(incl(10.0, 1.0));
        buf.push(incl(10.0, 2.0)); // duplicate, still buffered
        buf.push(laser(10.0)); // same time, other sensor: kept
        buf.push(incl(12.0, 3.0));
        buf.pop_ready(&mut out);
        // Same time: sensors in protocol order, laser first.
        assert_eq!(out, vec![laser(10.0), incl(10.0, 1.0)]);
        assert_eq!(buf.push(incl(10.0, 4.0)), Admission::Duplicate);
        assert_eq!(buf.push(incl(9.0, 4.0)), Admission::Late);
        buf.drain(&mut out);
        assert_eq!(times(&out), vec![10.0, 10.0, 12.0]);
        assert_eq!(
            buf.stats(),
            ReorderStats {
                released: 3,
                late: 1,
                duplicates: 2
            }
        );
    }

    #[test]
    fn bounded_memory_releases_early() {
        let mut buf = ReorderBuffer::new(1.0e9, 3);
        let mut out = Vec::new();
        for t in 0..10 {
            buf.push(incl(1.0e9 + t as f64, 0.0));
            buf.pop_ready(&mut out);
            assert!(buf.len() <= 3);
        }
        assert_eq!(out.len(), 7);
    }
}
