//! A small reorder buffer that puts a machine's readings back into time
//! order before they reach the engines.
//!
//! Readings are held until the newest time seen is `window_s` past them,
//! then released oldest first. Order is kept *per sensor*: a reading older
//! than one of the same sensor already released is *late* and dropped; a
//! second reading of the same sensor at the same time is a *duplicate* and
//! dropped (the first one received wins). Both are counted. A reading of
//! one sensor may still be released after a newer reading of another (a
//! laser sample posted by its own gateway a second after the inclinometer's):
//! the engines accept that, and dropping it would lose a rare, valuable
//! sample. Memory is bounded by `max_len`: past it the oldest reading is
//! released early.

use std::cmp::Ordering;
use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use super::SnapshotError;
use super::reading::{Reading, SensorKind, reading_from_value};

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
    /// Release order: time, then arrival. Readings that share a time are
    /// fused in the order they arrived, which the store keeps (its ids)
    /// and the export repeats, so a replay of the export, a restart and
    /// an office fuse them as the server did (docs/protocol.md).
    fn key(&self) -> (f64, u64) {
        (self.reading.t, self.seq)
    }

    fn before(&self, other: &Entry) -> bool {
        let (ta, qa) = self.key();
        let (tb, qb) = other.key();
        ta.total_cmp(&tb).then(qa.cmp(&qb)) == Ordering::Less
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
    /// Time of the newest released reading of each sensor (indexed by
    /// [`SensorKind`] in protocol order), for late and duplicate detection.
    released_t: [f64; SensorKind::ALL.len()],
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
            released_t: [f64::NEG_INFINITY; SensorKind::ALL.len()],
            seq: 0,
            stats: ReorderStats::default(),
        }
    }

    /// Offers a reading.
    pub fn push(&mut self, reading: Reading) -> Admission {
        let released_t = self.released_t[reading.sensor() as usize];
        if reading.t < released_t {
            self.stats.late += 1;
            return Admission::Late;
        }
        if reading.t == released_t {
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
        let released_t = &mut self.released_t[reading.sensor() as usize];
        if reading.t <= *released_t {
            // Only when `max_len` forced an early release past it.
            if reading.t == *released_t {
                self.stats.duplicates += 1;
            } else {
                self.stats.late += 1;
            }
            return;
        }
        *released_t = reading.t;
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

    /// The whole state, serialisable: [`ReorderBuffer::restore`] continues
    /// from it exactly (held readings, what was released, counts).
    pub fn snapshot(&self) -> serde_json::Value {
        let finite = |t: f64| t.is_finite().then_some(t);
        let state = ReorderState {
            window_s: self.window_s,
            max_len: self.max_len,
            held: self
                .held
                .iter()
                .map(|e| serde_json::to_value(&e.reading).unwrap_or_default())
                .collect(),
            newest_t: finite(self.newest_t),
            released_t: self.released_t.map(finite).to_vec(),
            stats: self.stats,
        };
        serde_json::to_value(state).unwrap_or_default()
    }

    /// A buffer continuing from a [`ReorderBuffer::snapshot`].
    pub fn restore(snapshot: serde_json::Value) -> Result<ReorderBuffer, SnapshotError> {
        let state: ReorderState =
            serde_json::from_value(snapshot).map_err(|e| SnapshotError::Invalid(e.to_string()))?;
        let mut buffer = ReorderBuffer::new(state.window_s, state.max_len);
        for value in &state.held {
            let reading = reading_from_value(value)
                .map_err(|e| SnapshotError::Invalid(format!("held reading: {e}")))?;
            buffer.seq += 1;
            buffer.held.push_back(Entry {
                reading,
                seq: buffer.seq,
            });
        }
        buffer.newest_t = state.newest_t.unwrap_or(f64::NEG_INFINITY);
        // A snapshot from before a sensor kind existed has none for it.
        for (released, t) in buffer.released_t.iter_mut().zip(state.released_t) {
            *released = t.unwrap_or(f64::NEG_INFINITY);
        }
        buffer.stats = state.stats;
        Ok(buffer)
    }
}

/// Serialised form of a [`ReorderBuffer`] (`None` for "nothing yet").
#[derive(Serialize, Deserialize)]
struct ReorderState {
    window_s: f64,
    max_len: usize,
    /// Held readings in release order, as protocol JSON.
    held: Vec<serde_json::Value>,
    newest_t: Option<f64>,
    /// Per sensor kind in protocol order.
    released_t: Vec<Option<f64>>,
    stats: ReorderStats,
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
                position: None,
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
        // Same time: in arrival order, the inclinometer first.
        assert_eq!(out, vec![incl(10.0, 1.0), laser(10.0)]);
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
    fn order_is_kept_per_sensor() {
        let mut buf = ReorderBuffer::new(0.0, 100);
        let mut out = Vec::new();
        buf.push(incl(12.0, 0.0));
        buf.pop_ready(&mut out);
        // The laser's own gateway is a second behind: still released.
        assert_eq!(buf.push(laser(11.0)), Admission::Buffered);
        assert_eq!(buf.push(incl(11.5, 0.0)), Admission::Late);
        buf.pop_ready(&mut out);
        assert_eq!(out, vec![incl(12.0, 0.0), laser(11.0)]);
    }

    #[test]
    fn a_restored_buffer_continues_exactly() {
        const T0: f64 = 1.772e9;
        let mut live = ReorderBuffer::new(2.0, 100);
        let mut out = Vec::new();
        for t in [10.0, 12.0, 11.0] {
            live.push(incl(T0 + t, t));
        }
        live.push(laser(T0 + 10.5));
        live.pop_ready(&mut out);
        let mut restored = ReorderBuffer::restore(live.snapshot()).unwrap();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for t in [13.0, 10.0, 11.0, 15.0] {
            let reading = incl(T0 + t, 1.0);
            assert_eq!(live.push(reading.clone()), restored.push(reading), "at {t}");
            live.pop_ready(&mut a);
            restored.pop_ready(&mut b);
        }
        live.drain(&mut a);
        restored.drain(&mut b);
        assert_eq!(a, b);
        assert_eq!(live.stats(), restored.stats());
    }

    #[test]
    fn a_snapshot_from_before_the_advance_sensor_restores() {
        const T0: f64 = 1.772e9;
        let mut live = ReorderBuffer::new(2.0, 100);
        live.push(incl(T0 + 10.0, 1.0));
        live.drain(&mut Vec::new());
        let mut snapshot = live.snapshot();
        // Six sensor kinds then: the inclinometer's release time and five
        // without one.
        snapshot["released_t"] = serde_json::json!([null, T0 + 10.0, null, null, null, null]);
        let mut restored = ReorderBuffer::restore(snapshot).unwrap();
        assert_eq!(restored.push(incl(T0 + 9.0, 1.0)), Admission::Late);
        assert_eq!(restored.push(incl(T0 + 11.0, 1.0)), Admission::Buffered);
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
