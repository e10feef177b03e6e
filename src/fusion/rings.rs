//! The `rings` stage: the ring (or pipe) log. An `advance` reading closes
//! a ring, or a pipe of a jacked string; the stage logs, per ring, where
//! the machine stood at its completion: the station and the front's and
//! rear's deviations and tendency of the newest `dta` estimate, the pitch
//! and roll of the newest engine estimate, the time since the previous
//! ring, and the thrust cylinders' strokes if the reading carries them.
//! The surveyor signs this protocol off ring by ring, so every number is
//! one the machine's streams already served (the `dta` estimate's time is
//! logged with it).

use serde::{Deserialize, Serialize};

use super::integrity::Integrity;

use super::descriptor::{SignalKind, Signals, StageDescriptor, StreamValues};
use super::estimate::{EngineOutput, EstimateValues};
use super::json_fields::JsonFields;
use super::reading::{Reading, SensorData, SensorKind};
use super::registry::StageKind;
use super::{Declaration, Stage};
use super::{SnapshotError, StreamKind};

/// A station this far behind the last ring's is no advance, m (a machine
/// never backs a metre).
pub const BACKWARD_JUMP_M: f64 = 1.0;

/// Version of the stage's snapshot.
pub const STATE_VERSION: u32 = 1;
/// Version of the stored [`RingRecord`].
pub const CODEC_VERSION: u32 = 1;

/// One completed ring (or pipe).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RingRecord {
    /// The ring's or pipe's number, as the `advance` reading gave it.
    pub ring: u64,
    /// The previous ring's completion, Unix seconds; `null` for the first
    /// ring the machine logged.
    pub start_t: Option<f64>,
    /// Since the previous ring's completion, s.
    pub duration_s: Option<f64>,
    /// Station of the machine's reference point (newest `dta` estimate);
    /// `null` without one (no alignment or no position yet).
    pub station_m: Option<f64>,
    /// Station gained since the last ring completed with a station;
    /// `null` for the first, and where the station went back by more than
    /// [`BACKWARD_JUMP_M`] (a new drive, a new set-up of the guidance).
    pub advance_m: Option<f64>,
    /// Deviations from the axis at completion, mm.
    pub front_horizontal_mm: Option<f64>,
    pub front_vertical_mm: Option<f64>,
    pub rear_horizontal_mm: Option<f64>,
    pub rear_vertical_mm: Option<f64>,
    pub tendency_horizontal_mm_per_m: Option<f64>,
    pub tendency_vertical_mm_per_m: Option<f64>,
    /// Time of the `dta` estimate the station and deviations are from.
    pub dta_t: Option<f64>,
    /// Attitude at completion, degrees (newest estimate of the first of
    /// the machine's engines, in registry order, that has told one).
    pub pitch_deg: Option<f64>,
    pub roll_deg: Option<f64>,
    /// The thrust cylinders' strokes, mm, as the reading gave them.
    pub strokes_mm: Option<Vec<f64>>,
}

impl StreamValues for RingRecord {
    const CODEC_VERSION: u32 = CODEC_VERSION;
    const SIGNALS: &'static [SignalKind] = &[];

    fn write_fields(&self, w: &mut JsonFields<'_>) {
        w.integer("ring", self.ring);
        w.optional("start_t", self.start_t);
        w.optional("duration_s", self.duration_s);
        w.optional("station_m", self.station_m);
        w.optional("advance_m", self.advance_m);
        w.optional("front_horizontal_mm", self.front_horizontal_mm);
        w.optional("front_vertical_mm", self.front_vertical_mm);
        w.optional("rear_horizontal_mm", self.rear_horizontal_mm);
        w.optional("rear_vertical_mm", self.rear_vertical_mm);
        w.optional(
            "tendency_horizontal_mm_per_m",
            self.tendency_horizontal_mm_per_m,
        );
        w.optional(
            "tendency_vertical_mm_per_m",
            self.tendency_vertical_mm_per_m,
        );
        w.optional("dta_t", self.dta_t);
        w.optional("pitch_deg", self.pitch_deg);
        w.optional("roll_deg", self.roll_deg);
        match &self.strokes_mm {
            Some(strokes) => w.numbers("strokes_mm", strokes),
            None => w.null("strokes_mm"),
        }
    }

    /// A form that has never changed.
    fn decode(version: u32, bytes: &[u8]) -> Result<RingRecord, postcard::Error> {
        if version <= CODEC_VERSION {
            postcard::from_bytes(bytes)
        } else {
            Err(postcard::Error::DeserializeBadEncoding)
        }
    }

    /// The front's deviations (0 without them).
    fn extremes(&self) -> [f64; 2] {
        [
            self.front_horizontal_mm.unwrap_or(0.0),
            self.front_vertical_mm.unwrap_or(0.0),
        ]
    }

    /// None: the `dta` stream's own deviations are watched.
    fn signals(&self) -> Signals {
        Signals::default()
    }
}

/// The newest `dta` estimate's part the log keeps.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Position {
    t: f64,
    station_m: f64,
    front_mm: [f64; 2],
    rear_mm: [f64; 2],
    tendency_mm_per_m: [f64; 2],
    /// The estimate's integrity (`ok` in snapshots from before it).
    #[serde(default)]
    integrity: Integrity,
}

/// Pitch and roll, degrees, and the stream that told them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
struct Attitude {
    stream: StreamKind,
    pitch_deg: f64,
    roll_deg: f64,
    /// The estimate's integrity (`ok` in snapshots from before it).
    #[serde(default)]
    integrity: Integrity,
}

/// What the stage remembers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RingLog {
    state_version: u32,
    /// The previous ring's completion time.
    previous_t: Option<f64>,
    /// The station of the last ring completed with one.
    previous_station_m: Option<f64>,
    position: Option<Position>,
    attitude: Option<Attitude>,
}

impl RingLog {
    /// A log with no ring yet.
    pub fn new() -> RingLog {
        RingLog {
            state_version: STATE_VERSION,
            previous_t: None,
            previous_station_m: None,
            position: None,
            attitude: None,
        }
    }
}

impl Default for RingLog {
    fn default() -> Self {
        RingLog::new()
    }
}

impl Stage for RingLog {
    fn kind(&self) -> StageKind {
        StageKind::Rings
    }

    fn reads(&self, sensor: SensorKind) -> bool {
        sensor == SensorKind::Advance
    }

    fn reading(&mut self, reading: &Reading, out: &mut Vec<EngineOutput>) {
        let SensorData::Advance {
            ring, strokes_mm, ..
        } = &reading.data
        else {
            return;
        };
        let position = self.position;
        let station_m = position.map(|p| p.station_m);
        let start_t = self.previous_t;
        let record = RingRecord {
            ring: *ring,
            start_t,
            duration_s: start_t.map(|start| reading.t - start),
            station_m,
            // A station far behind the last ring's is a new drive or a new
            // set-up of the guidance, not an advance: unknown.
            advance_m: station_m
                .zip(self.previous_station_m)
                .map(|(now, then)| now - then)
                .filter(|gained| *gained > -BACKWARD_JUMP_M),
            front_horizontal_mm: position.map(|p| p.front_mm[0]),
            front_vertical_mm: position.map(|p| p.front_mm[1]),
            rear_horizontal_mm: position.map(|p| p.rear_mm[0]),
            rear_vertical_mm: position.map(|p| p.rear_mm[1]),
            tendency_horizontal_mm_per_m: position.map(|p| p.tendency_mm_per_m[0]),
            tendency_vertical_mm_per_m: position.map(|p| p.tendency_mm_per_m[1]),
            dta_t: position.map(|p| p.t),
            pitch_deg: self.attitude.map(|a| a.pitch_deg),
            roll_deg: self.attitude.map(|a| a.roll_deg),
            strokes_mm: strokes_mm.clone(),
        };
        self.previous_t = Some(reading.t);
        self.previous_station_m = station_m.or(self.previous_station_m);
        // The worse of the position's and the attitude's it records.
        let integrity = [
            position.map(|p| p.integrity),
            self.attitude.map(|a| a.integrity),
        ]
        .into_iter()
        .flatten()
        .fold(Integrity::OK, Integrity::worst);
        out.push(EngineOutput {
            t: reading.t,
            values: EstimateValues::Rings(record),
            integrity: integrity.inherited(),
        });
    }

    fn estimate(&mut self, estimate: &EngineOutput, _out: &mut Vec<EngineOutput>) {
        let stream = estimate.values.stream();
        if let EstimateValues::Dta(d) = &estimate.values {
            self.position = Some(Position {
                t: estimate.t,
                station_m: d.station_m,
                front_mm: [d.front.horizontal_mm, d.front.vertical_mm],
                rear_mm: [d.rear.horizontal_mm, d.rear.vertical_mm],
                tendency_mm_per_m: [d.tendency_horizontal_mm_per_m, d.tendency_vertical_mm_per_m],
                integrity: estimate.integrity,
            });
            return;
        }
        let Some((pitch_deg, roll_deg)) = estimate.values.pitch_roll_deg() else {
            return;
        };
        // The first engine in registry order that tells an attitude.
        if self.attitude.is_none_or(|a| stream <= a.stream) {
            self.attitude = Some(Attitude {
                stream,
                pitch_deg,
                roll_deg,
                integrity: estimate.integrity,
            });
        }
    }

    fn snapshot(&self) -> serde_json::Value {
        // Plain numbers: serialising cannot fail.
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }
}

/// The `rings` stage as the registry lists it.
pub struct Rings;

impl StageDescriptor for Rings {
    const SUMMARY: &'static str = "the ring (or pipe) log: one record per advance reading, with the machine's station, deviations, tendency and attitude at the ring's completion";
    type Stage = RingLog;
    type Output = RingRecord;
    /// A store from before the stage holds no `advance` reading: a replay
    /// of it leaves no previous ring, the newest `dta` estimate and the
    /// newest attitude of the first engine that tells one, which the
    /// newest stored output of each stream gives.
    const SEEDED: bool = true;

    fn create(_: &Declaration) -> Option<RingLog> {
        Some(RingLog::new())
    }
    fn restore(_: &Declaration, snapshot: serde_json::Value) -> Result<RingLog, SnapshotError> {
        SnapshotError::check_version(StreamKind::Rings, &snapshot, STATE_VERSION)?;
        SnapshotError::parse(StreamKind::Rings, snapshot)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::dta::{DtaEstimate, DtaSource, PointDeviation};

    fn advance(t: f64, ring: u64, strokes_mm: Option<Vec<f64>>) -> Reading {
        Reading {
            t,
            data: SensorData::Advance {
                ring,
                strokes_mm,
                key: None,
            },
        }
    }

    fn dta(t: f64, station_m: f64, front_h_mm: f64) -> EngineOutput {
        let point = |station_m, horizontal_mm, vertical_mm| PointDeviation {
            station_m,
            horizontal_mm,
            vertical_mm,
            sigma_horizontal_mm: None,
            sigma_vertical_mm: None,
        };
        EngineOutput {
            integrity: crate::fusion::Integrity::OK,
            t,
            values: EstimateValues::Dta(DtaEstimate {
                source: DtaSource::Laser,
                station_m,
                front: point(station_m + 4.0, front_h_mm, -3.0),
                rear: point(station_m - 5.0, 10.0, -1.0),
                tendency_horizontal_mm_per_m: (front_h_mm - 10.0) / 9.0,
                tendency_vertical_mm_per_m: -2.0 / 9.0,
                status: None,
            }),
        }
    }

    fn records(out: &[EngineOutput]) -> Vec<&RingRecord> {
        out.iter()
            .filter_map(|o| match &o.values {
                EstimateValues::Rings(r) => Some(r),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn a_ring_logs_the_newest_position_and_the_time_and_advance_since_the_last() {
        let mut log = RingLog::new();
        let mut out = Vec::new();
        // Before any position: the ring number and strokes alone.
        log.reading(&advance(100.0, 41, None), &mut out);
        log.estimate(&dta(150.0, 1000.0, 28.0), &mut out);
        log.estimate(&dta(160.0, 1001.5, 19.0), &mut out);
        // Snapshot and restore in between: the log continues.
        let text = serde_json::to_string(&log.snapshot()).unwrap();
        let mut log = Rings::restore(
            &Declaration::default(),
            serde_json::from_str(&text).unwrap(),
        )
        .unwrap();
        log.reading(&advance(1900.0, 42, Some(vec![1510.0, 1498.5])), &mut out);
        let rings = records(&out);
        assert_eq!(rings.len(), 2);
        assert_eq!((rings[0].ring, rings[0].start_t), (41, None));
        assert_eq!((rings[0].station_m, rings[0].pitch_deg), (None, None));
        let r = rings[1];
        assert_eq!(r.ring, 42);
        assert_eq!((r.start_t, r.duration_s), (Some(100.0), Some(1800.0)));
        // The first ring had no station: no advance yet.
        assert_eq!((r.station_m, r.advance_m), (Some(1001.5), None));
        assert_eq!(
            (r.front_horizontal_mm, r.front_vertical_mm),
            (Some(19.0), Some(-3.0))
        );
        assert_eq!(
            (r.rear_horizontal_mm, r.rear_vertical_mm),
            (Some(10.0), Some(-1.0))
        );
        assert_eq!(r.tendency_horizontal_mm_per_m, Some(1.0));
        assert_eq!(r.dta_t, Some(160.0));
        assert_eq!(r.strokes_mm.as_deref(), Some(&[1510.0, 1498.5][..]));
        // The next ring: 1.5 m on.
        log.estimate(&dta(3500.0, 1003.0, 12.0), &mut out);
        log.reading(&advance(3600.0, 43, None), &mut out);
        let r = *records(&out).last().unwrap();
        assert_eq!(
            (r.ring, r.duration_s, r.advance_m),
            (43, Some(1700.0), Some(1.5))
        );
        // A new drive from the axis's start (its rings numbered from 1):
        // no advance, not −1001 m; the next ring's is known again.
        log.estimate(&dta(3700.0, 2.0, 0.0), &mut out);
        log.reading(&advance(3800.0, 1, None), &mut out);
        assert_eq!(records(&out).last().unwrap().advance_m, None);
        log.estimate(&dta(4700.0, 3.5, 0.0), &mut out);
        log.reading(&advance(4800.0, 2, None), &mut out);
        assert_eq!(records(&out).last().unwrap().advance_m, Some(1.5));
    }

    #[test]
    fn the_attitude_is_the_newest_of_the_first_engine_that_tells_one() {
        let zupt = |t: f64, pitch_deg: f64| {
            let mut e = crate::fusion::estimate::zupt_for_tests(t, None);
            if let EstimateValues::Zupt(z) = &mut e.values {
                (z.pitch_deg, z.roll_deg) = (pitch_deg, 0.5);
            }
            e
        };
        let mut log = RingLog::new();
        let mut out = Vec::new();
        log.estimate(&zupt(1.0, 0.25), &mut out);
        log.estimate(&zupt(2.0, 0.75), &mut out);
        log.reading(&advance(3.0, 1, None), &mut out);
        assert_eq!(records(&out)[0].pitch_deg, Some(0.75));
        assert_eq!(records(&out)[0].roll_deg, Some(0.5));
        // A later stream (a stage's values) does not displace the engine's.
        assert!(StreamKind::Zupt < StreamKind::Rings);
    }
}
