//! The `steer` stage: the correction curve back to the design axis
//! (`fusion/steering.rs`) from every `dta` estimate of a machine that
//! declares its `steering`. It stores the curve's compact form (where it
//! starts, its length, the next step's target and stroke differences);
//! `GET .../steering` expands the points of every step. A position from
//! which no curve within the minimum radius reaches the axis tells the
//! alarm rules (`steering_infeasible`).

use serde::{Deserialize, Serialize};

use super::descriptor::{SignalKind, Signals, StageDescriptor, StreamValues};
use super::estimate::{EngineOutput, EstimateValues};
use super::json_fields::JsonFields;
use super::registry::StageKind;
use super::stage::{Declaration, Stage};
use super::steering::{self, Start, SteeringSpec};
use super::{SnapshotError, StreamKind};

/// Version of the stage's snapshot.
pub const STATE_VERSION: u32 = 1;
/// Version of the stored [`SteerEstimate`].
pub const CODEC_VERSION: u32 = 1;

/// One plane's part of a [`SteerEstimate`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SteerPlane {
    /// The front's deviation now, mm.
    pub deviation_mm: f64,
    /// The machine's tendency now, mm/m.
    pub tendency_mm_per_m: f64,
    /// Where the front should be after the next step, mm off the axis;
    /// `null` without a curve.
    pub next_deviation_mm: Option<f64>,
    /// Stroke difference of the opposite thrust cylinders (left less
    /// right, bottom less top) over the next step, mm; `null` without a
    /// curve.
    pub stroke_difference_mm: Option<f64>,
}

/// What the `steer` stage emits per `dta` estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SteerEstimate {
    /// Station of the front, where the curve starts.
    pub station_m: f64,
    /// Whether a curve within the minimum radius reaches the axis within
    /// 500 m.
    pub feasible: bool,
    /// Whole steps (rings, pipes) to the axis; `null` when not feasible.
    pub steps: Option<u32>,
    pub length_m: Option<f64>,
    pub horizontal: SteerPlane,
    pub vertical: SteerPlane,
}

impl SteerEstimate {
    /// The curve from `start` under `spec`, compact.
    pub fn new(spec: &SteeringSpec, start: &Start) -> SteerEstimate {
        let correction = steering::correction(spec, start).ok();
        let plane =
            |deviation_mm: f64, tendency_mm_per_m: f64, curve: Option<&steering::PlaneCurve>| {
                // A curve has a point per step k = 0…steps, steps ≥ 1.
                let (now, next) = match curve.map(|c| c.points.as_slice()) {
                    Some([now, next, ..]) => (Some(now), Some(next)),
                    _ => (None, None),
                };
                SteerPlane {
                    deviation_mm,
                    tendency_mm_per_m,
                    next_deviation_mm: next.map(|p| p.deviation_mm),
                    stroke_difference_mm: now.map(|p| p.stroke_difference_mm),
                }
            };
        SteerEstimate {
            station_m: start.station_m,
            feasible: correction.is_some(),
            steps: correction.as_ref().map(|c| c.steps),
            length_m: correction.as_ref().map(|c| c.length_m),
            horizontal: plane(
                start.horizontal_mm,
                start.tendency_horizontal_mm_per_m,
                correction.as_ref().map(|c| &c.horizontal),
            ),
            vertical: plane(
                start.vertical_mm,
                start.tendency_vertical_mm_per_m,
                correction.as_ref().map(|c| &c.vertical),
            ),
        }
    }
}

impl StreamValues for SteerEstimate {
    const CODEC_VERSION: u32 = CODEC_VERSION;
    const SIGNALS: &'static [SignalKind] = &[SignalKind::Steering];

    fn write_fields(&self, w: &mut JsonFields<'_>) {
        w.number("station_m", self.station_m);
        w.flag("feasible", self.feasible);
        match self.steps {
            Some(steps) => w.integer("steps", u64::from(steps)),
            None => w.null("steps"),
        }
        w.optional("length_m", self.length_m);
        for (key, p) in [
            ("horizontal", &self.horizontal),
            ("vertical", &self.vertical),
        ] {
            w.object(key, |w| {
                w.number("deviation_mm", p.deviation_mm);
                w.number("tendency_mm_per_m", p.tendency_mm_per_m);
                w.optional("next_deviation_mm", p.next_deviation_mm);
                w.optional("stroke_difference_mm", p.stroke_difference_mm);
            });
        }
    }

    /// A form that has never changed.
    fn decode(version: u32, bytes: &[u8]) -> Result<SteerEstimate, postcard::Error> {
        if version <= CODEC_VERSION {
            postcard::from_bytes(bytes)
        } else {
            Err(postcard::Error::DeserializeBadEncoding)
        }
    }

    /// The next step's stroke differences (0 without a curve).
    fn extremes(&self) -> [f64; 2] {
        [
            self.horizontal.stroke_difference_mm.unwrap_or(0.0),
            self.vertical.stroke_difference_mm.unwrap_or(0.0),
        ]
    }

    /// Whether the axis can be reached (`steering_infeasible`).
    fn signals(&self) -> Signals {
        Signals {
            steering_feasible: Some(self.feasible),
            ..Signals::default()
        }
    }
}

/// The stage.
#[derive(Debug, Clone, PartialEq)]
pub struct SteerStage {
    spec: SteeringSpec,
}

/// The stage's snapshot: it keeps nothing between estimates.
#[derive(Serialize, Deserialize)]
struct SteerState {
    state_version: u32,
}

impl Stage for SteerStage {
    fn kind(&self) -> StageKind {
        StageKind::Steer
    }

    fn estimate(&mut self, estimate: &EngineOutput, out: &mut Vec<EngineOutput>) {
        let EstimateValues::Dta(dta) = &estimate.values else {
            return;
        };
        let start = Start {
            station_m: dta.front.station_m,
            horizontal_mm: dta.front.horizontal_mm,
            vertical_mm: dta.front.vertical_mm,
            tendency_horizontal_mm_per_m: dta.tendency_horizontal_mm_per_m,
            tendency_vertical_mm_per_m: dta.tendency_vertical_mm_per_m,
        };
        out.push(EngineOutput {
            t: estimate.t,
            values: EstimateValues::Steer(SteerEstimate::new(&self.spec, &start)),
            integrity: estimate.integrity.inherited(),
        });
    }

    fn snapshot(&self) -> serde_json::Value {
        serde_json::json!({ "state_version": STATE_VERSION })
    }
}

/// The `steer` stage as the registry lists it.
pub struct Steer;

impl StageDescriptor for Steer {
    const SUMMARY: &'static str = "the correction curve back to the design axis from each dta estimate, for machines that declare their steering";
    type Stage = SteerStage;
    type Output = SteerEstimate;

    fn create(declaration: &Declaration) -> Option<SteerStage> {
        // Only where a dta stage runs: the curve starts from its estimates.
        super::dta::Dta::create(declaration)?;
        declaration.steering.map(|spec| SteerStage { spec })
    }
    fn restore(
        declaration: &Declaration,
        snapshot: serde_json::Value,
    ) -> Result<SteerStage, SnapshotError> {
        SnapshotError::check_version(StreamKind::Steer, &snapshot, STATE_VERSION)?;
        let _: SteerState = SnapshotError::parse(StreamKind::Steer, snapshot)?;
        Steer::create(declaration).ok_or(SnapshotError::Invalid(
            "a steer snapshot for a machine without a dta stage and a steering".into(),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::dta::{DtaEstimate, DtaSource, PointDeviation};

    fn spec() -> SteeringSpec {
        SteeringSpec {
            min_radius_m: 1500.0,
            step_m: 1.5,
            cylinder_circle_m: 6.0,
        }
    }

    fn dta(front_h_mm: f64, tendency_h: f64) -> EngineOutput {
        let point = |station_m, horizontal_mm| PointDeviation {
            station_m,
            horizontal_mm,
            vertical_mm: 0.0,
            sigma_horizontal_mm: None,
            sigma_vertical_mm: None,
        };
        EngineOutput {
            integrity: crate::fusion::Integrity::OK,
            t: 1000.0,
            values: EstimateValues::Dta(DtaEstimate {
                source: DtaSource::Laser,
                station_m: 1001.0,
                front: point(1004.0, front_h_mm),
                rear: point(995.0, front_h_mm - 9.0 * tendency_h),
                tendency_horizontal_mm_per_m: tendency_h,
                tendency_vertical_mm_per_m: 0.0,
                status: None,
            }),
        }
    }

    #[test]
    fn the_issue_check_values_compact() {
        // d0 = 50 mm, g0 = +2 mm/m, R 1500 m, 1.5 m rings, 6.0 m circle:
        // 19 steps (28.5 m). By hand: a = −(0.15 + 0.114)/812.25 =
        // −3.2502e-4, κ(0) = 2a = −6.5004e-4, stroke 6·1.5·κ = −5.850 mm;
        // b = (0.1 + 0.057)/23149.125 = 6.7822e-6, d(1.5) = 0.05 + 0.003
        // − 7.3130e-4 + 2.2890e-5 = 0.0522916 m.
        let mut stage = SteerStage { spec: spec() };
        let mut out = Vec::new();
        stage.estimate(&dta(50.0, 2.0), &mut out);
        let [
            EngineOutput {
                t,
                values: EstimateValues::Steer(s),
                ..
            },
        ] = out.as_slice()
        else {
            panic!("{out:?}")
        };
        assert_eq!(*t, 1000.0);
        assert!(s.feasible);
        assert_eq!((s.steps, s.station_m), (Some(19), 1004.0));
        assert!((s.length_m.unwrap() - 28.5).abs() < 1e-9);
        let h = s.horizontal;
        assert!(
            (h.stroke_difference_mm.unwrap() + 5.850).abs() < 5e-3,
            "{h:?}"
        );
        assert!(
            (h.next_deviation_mm.unwrap() - 52.2916).abs() < 1e-3,
            "{h:?}"
        );
        assert_eq!((h.deviation_mm, h.tendency_mm_per_m), (50.0, 2.0));
        // The vertical plane is on the axis and stays there.
        assert_eq!(s.vertical.stroke_difference_mm, Some(0.0));
        assert_eq!(s.signals().steering_feasible, Some(true));
    }

    #[test]
    fn a_deviation_no_curve_can_take_back_is_infeasible() {
        // 50 m off with a 1500 m radius: the cubic's κ(0) = 6·d0/L² is
        // within 1/1500 only from L = √(6·50·1500) = 671 m, beyond 500 m.
        let mut stage = SteerStage { spec: spec() };
        let mut out = Vec::new();
        stage.estimate(&dta(50_000.0, 0.0), &mut out);
        let EstimateValues::Steer(s) = &out[0].values else {
            panic!()
        };
        assert!(!s.feasible);
        assert_eq!((s.steps, s.length_m), (None, None));
        assert_eq!(s.horizontal.next_deviation_mm, None);
        assert_eq!(s.horizontal.deviation_mm, 50_000.0);
        assert_eq!(s.signals().steering_feasible, Some(false));
        // Other streams pass by.
        let mut none = Vec::new();
        let other = EngineOutput {
            integrity: crate::fusion::Integrity::OK,
            t: 1.0,
            values: out[0].values.clone(),
        };
        stage.estimate(&other, &mut none);
        assert!(none.is_empty());
    }
}
