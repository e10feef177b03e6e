//! The `steer` stage: the correction curve back to the design axis
//! (`fusion/steering.rs`) for a machine that declares its `steering`.
//!
//! It plans a curve from a `dta` estimate's front (its deviation, its
//! tendency and how the machine is curving now, from the tendency's rate
//! over the last shield length of advance) and holds it while the front
//! stays within `hold_margin_mm` of it in both planes: a laser's noise does
//! not move the target every minute, and a machine that follows the curve
//! arrives on the axis. A front that has left the curve by more gets a new
//! one from where it is. Per `dta` estimate it stores the curve's compact
//! form (where it starts, its length, the next step's target, stroke
//! differences, each cylinder group's stroke from the last `advance`'s, the
//! next step in words); `GET .../steering` expands a point per step. A
//! position from which no curve within the machine's limits reaches the
//! axis tells the alarm rules (`steering_infeasible`).

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::alignment::Alignment;
use super::declaration::Tolerances;
use super::descriptor::{SignalKind, Signals, StageDescriptor, StreamValues};
use super::dta::DtaEstimate;
use super::estimate::{EngineOutput, EstimateValues};
use super::json_fields::JsonFields;
use super::reading::{Reading, SensorData, SensorKind};
use super::registry::StageKind;
use super::steering::{self, Front, GroupTarget, Plan, PlaneStart, Start, SteeringSpec};
use super::{Declaration, Stage};

mod response;

use super::{SnapshotError, StreamKind};
use response::{Measured, PlaneFilter};

/// Version of the stage's snapshot. 1: kept nothing (a curve per
/// estimate, issue 39).
pub const STATE_VERSION: u32 = 2;
/// Version of the stored [`SteerEstimate`]. 1: before the held plan, the
/// words and the groups ([`SteerEstimateV1`]).
pub const CODEC_VERSION: u32 = 2;

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
    /// The path's curvature at the front (the axis's and the
    /// correction's), 1/m; `null` without a curve.
    pub curvature_per_m: Option<f64>,
    /// The articulation's angle over the next step, degrees (+ right, up);
    /// `null` without a declared articulation or a curve.
    pub articulation_deg: Option<f64>,
    /// Whether a point of the curve from the front on lies beyond the plane's
    /// warn limit.
    pub outside_warn: bool,
    /// The curvature the machine adds of itself to the one it is steered
    /// (its response filter's), 1/m: the strokes steer against it.
    pub own_curvature_per_m: Option<f64>,
}

/// What the `steer` stage emits per `dta` estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SteerEstimate {
    /// Station of the front, as the stationing reads.
    pub station_m: f64,
    /// Whether a curve within the machine's limits reaches the axis within
    /// 500 m.
    pub feasible: bool,
    /// Whole steps (rings, pipes) from the front to the curve's end;
    /// `null` when not feasible.
    pub steps: Option<u32>,
    /// From the front to the curve's end, m.
    pub length_m: Option<f64>,
    pub horizontal: SteerPlane,
    pub vertical: SteerPlane,
    /// Whether the curve was planned at this estimate (else held from an
    /// earlier one).
    pub replanned: bool,
    /// The next step in words ("steer right 18 mm, down 4 mm over the next
    /// ring; extend more: L +9 mm"), or why there is no curve.
    pub words: String,
    /// Each declared cylinder group's share of the next step.
    pub groups: Vec<GroupTarget>,
    /// Internal station of the front (continuous along the axis).
    #[schema(value_type = f64)]
    pub internal_station_m: f64,
    /// The curve held: where it starts and from what.
    #[schema(value_type = Object)]
    pub plan: Option<Plan>,
}

/// A [`SteerEstimate`] as codec 1 stored it.
#[derive(Deserialize)]
struct SteerEstimateV1 {
    station_m: f64,
    feasible: bool,
    steps: Option<u32>,
    length_m: Option<f64>,
    horizontal: SteerPlaneV1,
    vertical: SteerPlaneV1,
}

#[derive(Deserialize)]
struct SteerPlaneV1 {
    deviation_mm: f64,
    tendency_mm_per_m: f64,
    next_deviation_mm: Option<f64>,
    stroke_difference_mm: Option<f64>,
}

impl From<SteerPlaneV1> for SteerPlane {
    fn from(p: SteerPlaneV1) -> SteerPlane {
        SteerPlane {
            deviation_mm: p.deviation_mm,
            tendency_mm_per_m: p.tendency_mm_per_m,
            next_deviation_mm: p.next_deviation_mm,
            stroke_difference_mm: p.stroke_difference_mm,
            curvature_per_m: None,
            articulation_deg: None,
            outside_warn: false,
            own_curvature_per_m: None,
        }
    }
}

impl From<SteerEstimateV1> for SteerEstimate {
    fn from(e: SteerEstimateV1) -> SteerEstimate {
        SteerEstimate {
            station_m: e.station_m,
            feasible: e.feasible,
            steps: e.steps,
            length_m: e.length_m,
            horizontal: e.horizontal.into(),
            vertical: e.vertical.into(),
            replanned: true,
            words: String::new(),
            groups: Vec::new(),
            internal_station_m: e.station_m,
            plan: None,
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
                w.optional("curvature_per_m", p.curvature_per_m);
                w.optional("articulation_deg", p.articulation_deg);
                w.flag("outside_warn", p.outside_warn);
                w.optional("own_curvature_per_m", p.own_curvature_per_m);
            });
        }
        w.flag("replanned", self.replanned);
        w.text("words", &self.words);
        w.objects("groups", &self.groups, |g, w| {
            w.text("name", &g.name);
            w.number("angle_deg", g.angle_deg);
            w.number("extension_difference_mm", g.extension_difference_mm);
            w.optional("target_stroke_mm", g.target_stroke_mm);
        });
        w.number("internal_station_m", self.internal_station_m);
        match &self.plan {
            Some(plan) => w.object("plan", |w| {
                w.number("start_station_m", plan.start_station_m);
                w.integer("steps", u64::from(plan.steps));
                w.number("length_m", plan.length_m);
                for (key, p) in [
                    ("horizontal", &plan.horizontal),
                    ("vertical", &plan.vertical),
                ] {
                    w.object(key, |w| {
                        w.number("deviation_mm", p.deviation_mm);
                        w.number("tendency_mm_per_m", p.tendency_mm_per_m);
                        w.number("curvature_per_m", p.curvature_per_m);
                    });
                }
            }),
            None => w.null("plan"),
        }
    }

    fn decode(version: u32, bytes: &[u8]) -> Result<SteerEstimate, postcard::Error> {
        match version {
            1 => postcard::from_bytes::<SteerEstimateV1>(bytes).map(SteerEstimate::from),
            CODEC_VERSION => postcard::from_bytes(bytes),
            _ => Err(postcard::Error::DeserializeBadEncoding),
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
    alignment: Arc<Alignment>,
    tolerances: Option<Tolerances>,
    /// Front to rear, m: the shortest curve is two of it, and the
    /// machine's present curvature is taken over one.
    shield_m: f64,
    state: SteerState,
}

/// The stage's snapshot.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
struct SteerState {
    state_version: u32,
    /// The curve being steered.
    plan: Option<Plan>,
    /// What the machine does with what it is told, horizontal and
    /// vertical.
    response: Option<[PlaneFilter; 2]>,
    /// The last `advance`'s strokes, mm.
    strokes_mm: Option<Vec<f64>>,
    /// The front's internal station at the last estimate.
    internal_station_m: Option<f64>,
    /// The curvature against the axis served with the strokes at the last
    /// estimate (the offset for the machine's own included), 1/m.
    served_per_m: [f64; 2],
    /// The curvature against the axis the machine was steered over the
    /// last shield length: (internal station, horizontal, vertical), 1/m,
    /// every quarter step.
    steered: Vec<[f64; 3]>,
}

/// How much the front's heading exceeds the chord from the rear (`shield_m`
/// behind) on a path steered with `steered` curvatures (station, per
/// plane), m/m: (1/ℓ)·∫ (x − s + ℓ)·κ(x) dx over the shield, κ held between
/// samples, 0 before the first.
fn chord_lag(steered: &[[f64; 3]], station_m: f64, shield_m: f64) -> [f64; 2] {
    let from = station_m - shield_m;
    let mut lag = [0.0; 2];
    for pair in steered.windows(2) {
        let (a, b) = (pair[0][0].max(from), pair[1][0].min(station_m));
        if b <= a {
            continue;
        }
        // ∫ₐᵇ (x − from) dx, the curvature of the later sample over it.
        let weight = 0.5 * ((b - from).powi(2) - (a - from).powi(2));
        for i in 0..2 {
            lag[i] += weight * pair[1][i + 1];
        }
    }
    lag.map(|l| if shield_m > 0.0 { l / shield_m } else { 0.0 })
}

impl SteerStage {
    /// The response filters after the front's newest deviation and
    /// tendency at internal station `station_m`, from the advance since
    /// the last on what was served.
    fn follow(&mut self, dta: &DtaEstimate, station_m: f64) -> [PlaneFilter; 2] {
        let spec = &self.spec;
        // What was served since the last estimate, then the chord's lag
        // behind the front's heading over it.
        let from_m = self.state.internal_station_m;
        let served = self.state.served_per_m;
        if let Some(from_m) = from_m.filter(|from| *from < station_m) {
            let quarter = spec.step_m / 4.0;
            let samples = ((station_m - from_m) / quarter).ceil().min(4096.0) as usize;
            for k in 1..=samples {
                let at = (from_m + k as f64 * quarter).min(station_m);
                self.state.steered.push([at, served[0], served[1]]);
            }
        }
        let keep_from = station_m - self.shield_m - spec.step_m;
        self.state
            .steered
            .retain(|p| p[0] >= keep_from && p[0] <= station_m);
        let lag = chord_lag(&self.state.steered, station_m, self.shield_m);
        let front = &dta.front;
        let measured = [
            (
                front.horizontal_mm,
                dta.tendency_horizontal_mm_per_m,
                front.sigma_horizontal_mm,
            ),
            (
                front.vertical_mm,
                dta.tendency_vertical_mm_per_m,
                front.sigma_vertical_mm,
            ),
        ];
        let measured = [0, 1].map(|i| {
            let (deviation_mm, tendency, sigma_mm) = measured[i];
            Measured {
                deviation_m: deviation_mm / 1000.0,
                tendency: tendency / 1000.0,
                chord_lag: lag[i],
                sigma_m: sigma_mm
                    .filter(|s| s.is_finite() && *s > 0.0)
                    .unwrap_or(spec.guidance_sigma_mm)
                    / 1000.0,
            }
        });
        let start = || measured.map(|m| PlaneFilter::start(&m, self.shield_m));
        let advance_m = self.state.internal_station_m.map(|s| (s, station_m - s));
        let Some((mut filters, (_, advance_m))) = self.state.response.clone().zip(advance_m) else {
            return start();
        };
        // A front that moved back, or on by more than a few shields
        // between estimates, is a new start.
        if !(-spec.step_m..=4.0 * self.shield_m.max(spec.step_m)).contains(&advance_m) {
            return start();
        }
        let heading_var_per_m =
            (spec.stroke_sigma_mm / 1000.0 / spec.cylinder_circle_m).powi(2) / spec.step_m;
        for (i, filter) in filters.iter_mut().enumerate() {
            filter.predict(advance_m, served[i], heading_var_per_m);
            if !filter.update(&measured[i], self.shield_m, heading_var_per_m) {
                return start();
            }
        }
        filters
    }

    /// How the machine curves now against the axis, 1/m per plane: what
    /// it is steered (the held curve's) and what it adds of itself, kept
    /// within its own limit.
    fn present_curvature(&self, station_m: f64, filters: &[PlaneFilter; 2]) -> [f64; 2] {
        let axis = steering::Axis::curvatures_per_m(&*self.alignment, station_m);
        let served = self.state.served_per_m;
        let relative = [0, 1].map(|i| served[i] + filters[i].bias_per_m());
        let absolute = [axis[0] + relative[0], axis[1] + relative[1]];
        let size = absolute[0].hypot(absolute[1]);
        let limit = 1.0 / self.spec.min_radius_m;
        if size > limit {
            let scale = limit / size;
            [0, 1].map(|i| absolute[i] * scale - axis[i])
        } else {
            relative
        }
    }

    fn steer(&mut self, dta: &DtaEstimate) -> SteerEstimate {
        let front = &dta.front;
        let internal = self
            .alignment
            .internal_of(front.station_m, self.state.internal_station_m)
            .unwrap_or(front.station_m);
        let filters = self.follow(dta, internal);
        self.state.internal_station_m = Some(internal);
        // Held while the front is within the margin of the curve, now and
        // a shield length ahead on its present heading.
        let margin = self.spec.hold_margin_mm;
        let ahead_m = self.shield_m;
        let held = self.state.plan.filter(|plan| {
            let axis = &*self.alignment;
            let planned = steering::planned_deviation_mm(axis, plan, internal);
            let slope_now = steering::planned_slope(axis, plan, internal);
            internal >= plan.start_station_m - self.spec.step_m
                && (0..2).all(|i| {
                    let off = filters[i].x[0] * 1000.0 - planned[i];
                    let heading_off = (filters[i].x[1] - slope_now[i]) * 1000.0;
                    off.abs() <= margin && (off + heading_off * ahead_m).abs() <= margin
                })
        });
        let replanned = held.is_none();
        let outcome = match held {
            Some(plan) => Ok(plan),
            None => {
                let c = self.present_curvature(internal, &filters);
                let plane = |f: &PlaneFilter, curvature_per_m| PlaneStart {
                    deviation_mm: f.x[0] * 1000.0,
                    tendency_mm_per_m: f.x[1] * 1000.0,
                    curvature_per_m,
                };
                let start = Start {
                    station_m: internal,
                    horizontal: plane(&filters[0], c[0]),
                    vertical: plane(&filters[1], c[1]),
                };
                steering::plan(&self.spec, &*self.alignment, &start, 2.0 * self.shield_m)
            }
        };
        // The strokes steer against what the machine adds of itself while
        // a curve is served.
        let own = filters.each_ref().map(|f| f.bias_per_m());
        self.state.response = Some(filters);
        // Nothing served without a curve: the machine is steered by hand.
        self.state.served_per_m = [0.0; 2];
        self.state.plan = outcome.ok();
        let plane = |deviation_mm, tendency_mm_per_m| SteerPlane {
            deviation_mm,
            tendency_mm_per_m,
            next_deviation_mm: None,
            stroke_difference_mm: None,
            curvature_per_m: None,
            articulation_deg: None,
            outside_warn: false,
            own_curvature_per_m: None,
        };
        let mut estimate = SteerEstimate {
            station_m: front.station_m,
            feasible: false,
            steps: None,
            length_m: None,
            horizontal: plane(front.horizontal_mm, dta.tendency_horizontal_mm_per_m),
            vertical: plane(front.vertical_mm, dta.tendency_vertical_mm_per_m),
            replanned,
            words: String::new(),
            groups: Vec::new(),
            internal_station_m: internal,
            plan: None,
        };
        let plan = match outcome {
            Ok(plan) => plan,
            Err(why) => {
                estimate.words = format!("no curve: {why}");
                return estimate;
            }
        };
        let correction = steering::expand(
            &self.spec,
            &*self.alignment,
            &plan,
            &Front {
                internal_station_m: internal,
                station_m: front.station_m,
                horizontal_mm: front.horizontal_mm,
                vertical_mm: front.vertical_mm,
                tendency_horizontal_mm_per_m: dta.tendency_horizontal_mm_per_m,
                tendency_vertical_mm_per_m: dta.tendency_vertical_mm_per_m,
            },
            self.tolerances.as_ref(),
            own,
        );
        let strokes = [&correction.horizontal, &correction.vertical]
            .map(|c| c.points.first().map_or(0.0, |p| p.stroke_difference_mm));
        // What the strokes steer against the axis over the next step.
        let axis = &*self.alignment;
        let (here, ahead) = (
            steering::Axis::angles_rad(axis, internal),
            steering::Axis::angles_rad(axis, internal + self.spec.step_m),
        );
        self.state.served_per_m = [0, 1].map(|i| {
            (strokes[i] / 1000.0 / self.spec.cylinder_circle_m - (ahead[i] - here[i]))
                / self.spec.step_m
        });
        let articulation = steering::articulation_deg(&self.spec, strokes);
        for (i, (out, curve)) in [
            (&mut estimate.horizontal, &correction.horizontal),
            (&mut estimate.vertical, &correction.vertical),
        ]
        .into_iter()
        .enumerate()
        {
            out.next_deviation_mm = curve.points.get(1).map(|p| p.deviation_mm);
            out.stroke_difference_mm = curve.points.first().map(|p| p.stroke_difference_mm);
            out.curvature_per_m = curve.points.first().map(|p| p.curvature_per_m);
            out.articulation_deg = articulation.map(|a| a[i]);
            out.outside_warn = curve.points.iter().any(|p| p.outside_warn);
            out.own_curvature_per_m = Some(own[i]);
        }
        estimate.groups =
            steering::group_targets(&self.spec, strokes, self.state.strokes_mm.as_deref());
        estimate.words = steering::words(&self.spec, strokes, &estimate.groups);
        estimate.feasible = true;
        estimate.steps = Some(correction.steps);
        estimate.length_m = Some(correction.length_m);
        estimate.plan = Some(plan);
        estimate
    }
}

impl Stage for SteerStage {
    fn kind(&self) -> StageKind {
        StageKind::Steer
    }

    fn reads(&self, sensor: SensorKind) -> bool {
        sensor == SensorKind::Advance
    }

    /// An advance's strokes: the base of the groups' targets.
    fn reading(&mut self, reading: &Reading, _out: &mut Vec<EngineOutput>) {
        if let SensorData::Advance {
            strokes_mm: Some(strokes),
            ..
        } = &reading.data
        {
            self.state.strokes_mm = Some(strokes.clone());
        }
    }

    fn estimate(&mut self, estimate: &EngineOutput, out: &mut Vec<EngineOutput>) {
        let EstimateValues::Dta(dta) = &estimate.values else {
            return;
        };
        let steer = self.steer(dta);
        out.push(EngineOutput {
            t: estimate.t,
            values: EstimateValues::Steer(steer),
            integrity: estimate.integrity.inherited(),
        });
    }

    fn snapshot(&self) -> serde_json::Value {
        // A struct of numbers and vectors always serialises.
        serde_json::to_value(&self.state).unwrap_or_default()
    }
}

/// The `steer` stage as the registry lists it.
pub struct Steer;

impl StageDescriptor for Steer {
    const SUMMARY: &'static str = "the correction curve back to the design axis from each dta estimate, held while followed, for machines that declare their steering";
    type Stage = SteerStage;
    type Output = SteerEstimate;

    fn create(declaration: &Declaration) -> Option<SteerStage> {
        // Only where a dta stage runs: the curve starts from its estimates.
        super::dta::Dta::create(declaration)?;
        let geometry = declaration.geometry?;
        let shield_m = geometry
            .front_m
            .iter()
            .zip(geometry.rear_m)
            .map(|(f, r)| (f - r).powi(2))
            .sum::<f64>()
            .sqrt();
        let spec = declaration.steering.clone()?;
        // Front and rear declared at one point give no tendency: a chord
        // of 10 cm keeps the filter's arithmetic finite.
        let shield_m = shield_m.max(0.1);
        Some(SteerStage {
            spec,
            alignment: declaration.alignment.clone()?,
            tolerances: declaration.tolerances,
            shield_m,
            state: SteerState {
                state_version: STATE_VERSION,
                ..SteerState::default()
            },
        })
    }
    fn restore(
        declaration: &Declaration,
        snapshot: serde_json::Value,
    ) -> Result<SteerStage, SnapshotError> {
        SnapshotError::check_version(StreamKind::Steer, &snapshot, STATE_VERSION)?;
        let state: SteerState = SnapshotError::parse(StreamKind::Steer, snapshot)?;
        let mut stage = Steer::create(declaration).ok_or(SnapshotError::Invalid(
            "a steer snapshot for a machine without a dta stage and a steering".into(),
        ))?;
        stage.state = state;
        Ok(stage)
    }
}

#[cfg(test)]
mod tests;
