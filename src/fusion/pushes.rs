//! The `pushes` stage: the jacking log of a pipe-jacking drive. A jack
//! pushes the string forward a stroke at a time and stands still between
//! strokes; crews log every stroke. For a machine running `zupt`, each
//! push the engine has closed (its estimate carrying `smoothed_push`, the
//! push's track smoothed between its two rests) becomes one record: when,
//! how long and how far, how fast, and which way the head went in plan and
//! profile. A push too long for the engine to smooth (its
//! `smooth_max_push_s`; a pipe jacked at 2 mm/s takes ten minutes) is
//! logged from the filter's own estimates at its two rests instead. A
//! "push" of less than [`MIN_ADVANCE_M`] is a moment of motion the detector
//! saw at rest, not a stroke, and is not logged.

use serde::{Deserialize, Serialize};

use super::angles::deg;
use super::descriptor::{SignalKind, Signals, StageDescriptor, StreamValues};
use super::estimate::{EngineOutput, EstimateValues, TrackPoint};
use super::json_fields::JsonFields;
use super::registry::{EngineKind, StageKind};
use super::{Declaration, Stage};
use super::{SnapshotError, StreamKind};

/// Version of the stage's snapshot. 1: before the unsmoothed pushes (no
/// rest kept).
pub const STATE_VERSION: u32 = 2;
/// Version of the stored [`PushRecord`].
pub const CODEC_VERSION: u32 = 1;
/// Below this much plan displacement a push has no direction.
const MIN_DISPLACEMENT_M: f64 = 1e-3;
/// A "push" that advanced less than this along the track is the detector
/// seeing motion for a moment at rest, not a stroke (jack strokes are
/// hundreds of millimetres): it is not logged.
pub const MIN_ADVANCE_M: f64 = 0.005;

/// One completed push.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PushRecord {
    /// Pushes completed since the machine started, this one included.
    pub push: u64,
    /// The last rest before the push, and the first rest after it (the
    /// record's `t`), Unix seconds.
    pub start_t: f64,
    pub end_t: f64,
    pub duration_s: f64,
    /// Along-track distance advanced.
    pub length_m: f64,
    /// Mean speed over the push, mm/s.
    pub speed_mm_per_s: f64,
    /// Direction of the advance in plan, clockwise from north, [0, 360);
    /// `null` for a push that did not move in plan.
    pub course_deg: Option<f64>,
    /// Rise over plan run, percent (+ rising); `null` as `course_deg`.
    pub grade_pct: Option<f64>,
    /// North, east, down of the start point at the push's end (smoothed).
    pub end_position_m: [f64; 3],
    /// 1σ of `end_position_m`.
    pub end_position_sigma_m: [f64; 3],
}

impl PushRecord {
    /// The record of the push whose smoothed track is `points` (from the
    /// last rest before it to the first after), the `number`th.
    pub fn from_track(number: u64, points: &[TrackPoint]) -> Option<PushRecord> {
        let (first, last) = (points.first()?, points.last()?);
        let duration_s = last.t - first.t;
        let length_m = last.distance_m - first.distance_m;
        let [north, east, down] = [0, 1, 2].map(|i| last.position_m[i] - first.position_m[i]);
        let plan_m = north.hypot(east);
        let moved_in_plan = plan_m >= MIN_DISPLACEMENT_M;
        Some(PushRecord {
            push: number,
            start_t: first.t,
            end_t: last.t,
            duration_s,
            length_m,
            speed_mm_per_s: if duration_s > 0.0 {
                length_m / duration_s * 1000.0
            } else {
                0.0
            },
            course_deg: moved_in_plan.then(|| deg(east.atan2(north)).rem_euclid(360.0)),
            grade_pct: moved_in_plan.then(|| -down / plan_m * 100.0),
            end_position_m: last.position_m,
            end_position_sigma_m: last.position_sigma_m,
        })
    }
}

impl StreamValues for PushRecord {
    const CODEC_VERSION: u32 = CODEC_VERSION;
    const SIGNALS: &'static [SignalKind] = &[];

    fn write_fields(&self, w: &mut JsonFields<'_>) {
        w.integer("push", self.push);
        w.number("start_t", self.start_t);
        w.number("end_t", self.end_t);
        w.number("duration_s", self.duration_s);
        w.number("length_m", self.length_m);
        w.number("speed_mm_per_s", self.speed_mm_per_s);
        w.optional("course_deg", self.course_deg);
        w.optional("grade_pct", self.grade_pct);
        w.triple("end_position_m", &self.end_position_m);
        w.triple("end_position_sigma_m", &self.end_position_sigma_m);
    }

    /// A form that has never changed.
    fn decode(version: u32, bytes: &[u8]) -> Result<PushRecord, postcard::Error> {
        if version <= CODEC_VERSION {
            postcard::from_bytes(bytes)
        } else {
            Err(postcard::Error::DeserializeBadEncoding)
        }
    }

    /// Length and speed.
    fn extremes(&self) -> [f64; 2] {
        [self.length_m, self.speed_mm_per_s]
    }

    /// None: no alarm rule watches the jacking log.
    fn signals(&self) -> Signals {
        Signals::default()
    }
}

/// The stage: counts the pushes and logs each.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PushLog {
    state_version: u32,
    /// Pushes logged so far.
    pushes: u64,
    /// The newest still estimate's point: where an unsmoothed push starts.
    rest: Option<TrackPoint>,
    /// Whether the machine moved since `rest`.
    moving: bool,
}

impl PushLog {
    /// A log with no push yet.
    pub fn new() -> PushLog {
        PushLog {
            state_version: STATE_VERSION,
            pushes: 0,
            rest: None,
            moving: false,
        }
    }

    /// Logs the push along `points` if it advanced.
    fn log(
        &mut self,
        t: f64,
        points: &[TrackPoint],
        integrity: super::Integrity,
        out: &mut Vec<EngineOutput>,
    ) {
        let record = PushRecord::from_track(self.pushes + 1, points);
        if let Some(record) = record.filter(|r| r.length_m.abs() >= MIN_ADVANCE_M) {
            self.pushes += 1;
            out.push(EngineOutput {
                t,
                values: EstimateValues::Pushes(record),
                integrity,
            });
        }
    }
}

impl Default for PushLog {
    fn default() -> Self {
        PushLog::new()
    }
}

impl Stage for PushLog {
    fn kind(&self) -> StageKind {
        StageKind::Pushes
    }

    fn estimate(&mut self, estimate: &EngineOutput, out: &mut Vec<EngineOutput>) {
        let EstimateValues::Zupt(zupt) = &estimate.values else {
            return;
        };
        // Before the platform is levelled its position is not navigated.
        if !zupt.aligned {
            return;
        }
        if !zupt.zv {
            self.moving |= self.rest.is_some();
            return;
        }
        let here = TrackPoint {
            t: estimate.t,
            position_m: zupt.position_m,
            distance_m: zupt.distance_m,
            position_sigma_m: zupt.position_sigma_m,
        };
        let integrity = estimate.integrity.inherited();
        match (&zupt.smoothed_push, self.rest.take()) {
            (Some(points), _) => self.log(estimate.t, points, integrity, out),
            // Not smoothed: from the rest before it to this one.
            (None, Some(rest)) if self.moving => {
                self.log(estimate.t, &[rest, here.clone()], integrity, out)
            }
            _ => {}
        }
        self.rest = Some(here);
        self.moving = false;
    }

    fn snapshot(&self) -> serde_json::Value {
        // Integers, a flag and an optional point of numbers: serialising
        // cannot fail.
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }
}

/// The `pushes` stage as the registry lists it.
pub struct Pushes;

impl StageDescriptor for Pushes {
    const SUMMARY: &'static str =
        "the jacking log: one record per completed push of a machine running zupt";
    type Stage = PushLog;
    type Output = PushRecord;

    fn create(declaration: &Declaration) -> Option<PushLog> {
        declaration.runs(EngineKind::Zupt).then(PushLog::new)
    }
    fn restore(_: &Declaration, snapshot: serde_json::Value) -> Result<PushLog, SnapshotError> {
        SnapshotError::check_version(StreamKind::Pushes, &snapshot, STATE_VERSION)?;
        SnapshotError::parse(StreamKind::Pushes, snapshot)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(t: f64, position_m: [f64; 3], distance_m: f64) -> TrackPoint {
        TrackPoint {
            t,
            position_m,
            distance_m,
            position_sigma_m: [0.001, 0.002, 0.003],
        }
    }

    fn zupt_estimate(t: f64, smoothed_push: Option<Vec<TrackPoint>>) -> EngineOutput {
        crate::fusion::estimate::zupt_for_tests(t, smoothed_push)
    }

    #[test]
    fn a_push_is_logged_with_its_length_speed_course_and_grade() {
        // 3 m north, 4 m east, 5 cm up (down −0.05) in 100 s, 5.0002 m
        // along the track: course atan2(4, 3) = 53.130102°, grade
        // 0.05 / 5 = 1 %, speed 5.0002 m / 100 s = 50.002 mm/s.
        let track = vec![
            point(1000.0, [10.0, 20.0, 1.0], 7.0),
            point(1050.0, [11.5, 22.0, 0.975], 9.5),
            point(1100.0, [13.0, 24.0, 0.95], 12.0002),
        ];
        let mut log = PushLog::new();
        let mut out = Vec::new();
        log.estimate(&zupt_estimate(1099.0, None), &mut out);
        assert!(out.is_empty());
        log.estimate(&zupt_estimate(1100.0, Some(track)), &mut out);
        let [output] = out.as_slice() else {
            panic!("{out:?}")
        };
        assert_eq!(output.t, 1100.0);
        let EstimateValues::Pushes(record) = &output.values else {
            panic!()
        };
        assert_eq!(record.push, 1);
        assert_eq!(
            (record.start_t, record.end_t, record.duration_s),
            (1000.0, 1100.0, 100.0)
        );
        assert!((record.length_m - 5.0002).abs() < 1e-12);
        assert!((record.speed_mm_per_s - 50.002).abs() < 1e-9);
        assert!((record.course_deg.unwrap() - 53.130_102_354_155_98).abs() < 1e-9);
        assert!((record.grade_pct.unwrap() - 1.0).abs() < 1e-9);
        assert_eq!(record.end_position_m, [13.0, 24.0, 0.95]);
        assert_eq!(record.end_position_sigma_m, [0.001, 0.002, 0.003]);
    }

    #[test]
    fn pushes_are_numbered_across_a_snapshot_and_a_blip_is_not_logged() {
        // 4 mm: a blip, not logged; 6 mm straight down: logged, no course.
        let blip = vec![
            point(0.0, [1.0, 1.0, 0.0], 0.0),
            point(1.0, [1.004, 1.0, 0.0], 0.004),
        ];
        let standing = vec![
            point(0.0, [1.0, 1.0, 0.0], 0.0),
            point(30.0, [1.0, 1.0, 0.006], 0.006),
        ];
        // Due west, level: course 270°, grade 0.
        let west = vec![
            point(40.0, [0.0, 0.0, 0.0], 0.0),
            point(60.0, [0.0, -2.0, 0.0], 2.0),
        ];
        let mut log = PushLog::new();
        let mut out = Vec::new();
        log.estimate(&zupt_estimate(1.0, Some(blip)), &mut out);
        assert!(out.is_empty());
        log.estimate(&zupt_estimate(30.0, Some(standing)), &mut out);
        let text = serde_json::to_string(&log.snapshot()).unwrap();
        let declaration = Declaration::of_engines([EngineKind::Zupt]);
        let mut log = Pushes::restore(&declaration, serde_json::from_str(&text).unwrap()).unwrap();
        log.estimate(&zupt_estimate(60.0, Some(west)), &mut out);
        let records: Vec<&PushRecord> = out
            .iter()
            .map(|o| match &o.values {
                EstimateValues::Pushes(r) => r,
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(records[0].push, 1);
        assert_eq!((records[0].course_deg, records[0].grade_pct), (None, None));
        assert!((records[0].speed_mm_per_s - 0.2).abs() < 1e-12);
        assert_eq!(records[1].push, 2);
        assert!((records[1].course_deg.unwrap() - 270.0).abs() < 1e-12);
        assert_eq!(records[1].grade_pct, Some(0.0));
        assert!((records[1].speed_mm_per_s - 100.0).abs() < 1e-12);
    }

    #[test]
    fn a_push_too_long_to_smooth_is_logged_from_its_two_rests() {
        // Still at 1.4 m north of the start, then 700 s moving (the
        // engine smooths none: no smoothed_push), still again 1.4 m
        // further: one push of 1.4 m at 2 mm/s, due north, level.
        let at = |t: f64, zv: bool, north: f64| {
            let mut e = zupt_estimate(t, None);
            if let EstimateValues::Zupt(z) = &mut e.values {
                z.zv = zv;
                z.position_m = [north, 0.0, 0.0];
                z.distance_m = north;
                z.position_sigma_m = [0.01, 0.01, 0.002];
            }
            e
        };
        let mut log = PushLog::new();
        let mut out = Vec::new();
        for e in [
            at(0.0, true, 1.4),
            at(10.0, true, 1.4),
            at(20.0, false, 1.41),
            at(400.0, false, 2.17),
            at(710.0, true, 2.8),
            at(720.0, true, 2.8),
        ] {
            log.estimate(&e, &mut out);
        }
        let [
            EngineOutput {
                t,
                values: EstimateValues::Pushes(p),
                ..
            },
        ] = out.as_slice()
        else {
            panic!("{out:?}")
        };
        assert_eq!(*t, 710.0);
        assert_eq!((p.push, p.start_t, p.end_t), (1, 10.0, 710.0));
        assert!((p.length_m - 1.4).abs() < 1e-12 && (p.speed_mm_per_s - 2.0).abs() < 1e-9);
        assert_eq!((p.course_deg, p.grade_pct), (Some(0.0), Some(0.0)));
        assert_eq!(p.end_position_sigma_m, [0.01, 0.01, 0.002]);
    }

    #[test]
    fn only_a_machine_running_zupt_keeps_a_jacking_log() {
        assert!(Pushes::create(&Declaration::of_engines([EngineKind::Zupt])).is_some());
        assert!(Pushes::create(&Declaration::of_engines([EngineKind::Attitude])).is_none());
        assert_eq!(
            Declaration::of_engines([EngineKind::Fuzzy, EngineKind::Zupt]).stages(),
            [StageKind::Pushes, StageKind::Rings]
        );
        let outdated = serde_json::json!({"state_version": 0, "pushes": 3});
        assert!(matches!(
            Pushes::restore(&Declaration::default(), outdated),
            Err(SnapshotError::Outdated { found: 0, .. })
        ));
    }
}
