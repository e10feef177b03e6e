//! The correction curve back to the design axis (issues 39 and 56).
//!
//! The machine's path is the axis plus a correction: per plane
//! (horizontal, vertical) the front's deviation d(x) from the axis, x
//! metres of station ahead of where the curve starts. The path's own
//! direction is the axis's plus d′ (azimuth + right, pitch + up) and its
//! curvature the axis's plus d″, so a machine on a 500 m arc steers the
//! arc's 1/500 even with d ≡ 0 (the offset curve's exact curvature
//! κ/(1 − κ·d) differs from it by κ·d, below 10⁻⁴ of it for any deviation a
//! tunnel tolerates).
//!
//! The correction is a quintic that the machine can drive: it starts at
//! the front's deviation d0 with the machine's tendency g0 and its present
//! curvature against the axis c0, and ends on the axis tangentially with
//! the axis's curvature, d(L) = d′(L) = d″(L) = 0, so the curvature is
//! continuous from the machine's to the axis's (no step in the thrust):
//!
//! d(x) = d0 + g0·x + c0·x²/2 + a3·x³ + a4·x⁴ + a5·x⁵,
//!
//! with R0 = −(d0 + g0·L + c0·L²/2), R1 = −(g0 + c0·L), R2 = −c0:
//! a3 = (20·R0 − 8·R1·L + R2·L²)/(2L³), a4 = (−30·R0 + 14·R1·L − 2·R2·L²)/(2L⁴),
//! a5 = (12·R0 − 6·R1·L + R2·L²)/(2L⁵). From rest on a parallel offset
//! (g0 = c0 = 0) it is d0·(1 − 10u³ + 15u⁴ − 6u⁵), u = x/L: no overshoot.
//!
//! L is the fewest whole steps (rings or pipes, `step_m`; beyond 100
//! candidates within 5 %), at least the declared minimum (two shield
//! lengths), for which the path's curvature
//! of both planes together, √(κh² + κv²), stays within 1/`min_radius_m` at
//! every point (checked every quarter step: the axis's curvature may vary
//! along the curve), and the stroke difference changes by at most
//! `max_stroke_change_mm` from one step to the next (and from the
//! machine's present one).
//!
//! Per step the thrust cylinders on opposite sides differ in stroke by the
//! circle's diameter times the path's turn over the step,
//! `cylinder_circle_m`·(θ(x + step) − θ(x)) (exact, not the curvature at
//! the step's start times its length): the cylinders on the outside of the
//! curve extend more, so a curve to the right or upward is steered with
//! the left or bottom ones (the difference is left less right, bottom less
//! top). A cylinder at angle φ clockwise from the top, looking forward,
//! extends by −(sin φ·Δh + cos φ·Δv)/2 more than the mean, Δ the two
//! differences.
//!
//! Lengths in metres inside; the answer in the protocol's units (mm,
//! mm/m, 1/m).

use serde::{Deserialize, Serialize};

use super::alignment::Alignment;
use super::declaration::Tolerances;

/// The longest correction looked for: a machine that cannot reach the
/// axis within this is told so.
pub const MAX_LENGTH_M: f64 = 500.0;
/// Points per step at which the curvature is checked.
const SAMPLES_PER_STEP: u32 = 4;
/// A bound's rounding must not refuse a curve exactly at the limit.
const ROUNDING: f64 = 1e-9;
/// Below this stroke difference, mm, a plane is said to hold its line.
const SAID_MM: f64 = 0.5;

fn default_hold_margin_mm() -> f64 {
    2.0
}

/// How a machine may be steered: its tightest radius, the length of one
/// ring or pipe, the diameter of the circle of its thrust cylinders, and
/// (optionally) how fast the thrust may change, how far it may leave a
/// curve before a new one is planned, its cylinder groups or its
/// articulation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SteeringSpec {
    /// The tightest curve the machine may steer, metres.
    pub min_radius_m: f64,
    /// One step: a ring's or a pipe's length, metres.
    pub step_m: f64,
    /// Diameter of the circle the thrust cylinders stand on, metres.
    pub cylinder_circle_m: f64,
    /// Largest change of the stroke difference (both planes together) from
    /// one step to the next, mm; `null` (the default): only the radius
    /// limits it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_stroke_change_mm: Option<f64>,
    /// How far the front may leave the curve being steered (either plane)
    /// before a new one is planned from where it is, mm (default 2).
    #[serde(default = "default_hold_margin_mm")]
    pub hold_margin_mm: f64,
    /// The thrust cylinders in groups, for each group's stroke target
    /// (default none: only the stroke differences).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cylinder_groups: Vec<CylinderGroup>,
    /// An articulated shield or a pipe-jacking head, steered by the angle
    /// of its articulation (served per step besides the strokes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub articulation: Option<Articulation>,
    /// What one step is called in words (default `ring`).
    #[serde(default)]
    pub step_name: StepName,
    /// 1σ of the guidance's front and rear deviations, mm (default 1; a
    /// `dta` point that carries its own σ uses that).
    #[serde(default = "default_sigma_mm")]
    pub guidance_sigma_mm: f64,
    /// 1σ of the stroke difference the machine makes against the one it
    /// is given, per step, mm (default 1).
    #[serde(default = "default_sigma_mm")]
    pub stroke_sigma_mm: f64,
}

fn default_sigma_mm() -> f64 {
    1.0
}

/// A group of thrust cylinders that is given one stroke.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct CylinderGroup {
    /// Its name as the driver's panel shows it (e.g. `A`, `top-left`).
    pub name: String,
    /// Where it stands: degrees clockwise from the top, looking forward.
    pub angle_deg: f64,
    /// Its cylinders: positions in the `advance` reading's `strokes_mm`
    /// (from 0).
    pub cylinders: Vec<usize>,
}

/// An articulation between a front and a rear part: the angle between
/// them that follows a curve of curvature κ is κ·(`front_m` + `rear_m`)/2
/// (two chords of a circle meeting at the joint).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Articulation {
    /// From the joint to the cutting face, metres.
    pub front_m: f64,
    /// From the joint to the rear support (the tail or the first pipe's
    /// end), metres.
    pub rear_m: f64,
}

/// What one step is called.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum StepName {
    #[default]
    Ring,
    Pipe,
}

impl SteeringSpec {
    /// A machine of this radius, step and circle, the rest by default.
    pub fn new(min_radius_m: f64, step_m: f64, cylinder_circle_m: f64) -> SteeringSpec {
        SteeringSpec {
            min_radius_m,
            step_m,
            cylinder_circle_m,
            max_stroke_change_mm: None,
            hold_margin_mm: default_hold_margin_mm(),
            cylinder_groups: Vec::new(),
            articulation: None,
            step_name: StepName::Ring,
            guidance_sigma_mm: default_sigma_mm(),
            stroke_sigma_mm: default_sigma_mm(),
        }
    }

    /// Why the numbers cannot steer anything, if they cannot.
    pub fn check(&self) -> Result<(), String> {
        // A step of at least 10 cm keeps the search and the curve's points
        // within 5000 steps of the longest correction.
        let within = |name: &str, v: f64, min: f64, max: f64| {
            if v.is_finite() && v >= min && v <= max {
                Ok(())
            } else {
                Err(format!(
                    "`steering.{name}` must be from {min} to {max}, not {v}"
                ))
            }
        };
        within("min_radius_m", self.min_radius_m, 1.0, 1.0e6)?;
        within("step_m", self.step_m, 0.1, 100.0)?;
        within("cylinder_circle_m", self.cylinder_circle_m, 0.1, 50.0)?;
        if let Some(change) = self.max_stroke_change_mm {
            within("max_stroke_change_mm", change, 0.01, 1000.0)?;
        }
        within("hold_margin_mm", self.hold_margin_mm, 0.1, 1000.0)?;
        within("guidance_sigma_mm", self.guidance_sigma_mm, 0.01, 1000.0)?;
        within("stroke_sigma_mm", self.stroke_sigma_mm, 0.01, 1000.0)?;
        if self.cylinder_groups.len() > 64 {
            return Err("`steering.cylinder_groups`: at most 64 groups".into());
        }
        let mut seen = std::collections::BTreeSet::new();
        for (i, group) in self.cylinder_groups.iter().enumerate() {
            let name = &group.name;
            if name.trim().is_empty() || name.chars().count() > 32 {
                return Err(format!(
                    "`steering.cylinder_groups[{i}].name` must be 1 to 32 characters"
                ));
            }
            if self.cylinder_groups[..i].iter().any(|g| &g.name == name) {
                return Err(format!(
                    "`steering.cylinder_groups[{i}].name` `{name}` is used twice"
                ));
            }
            within(
                &format!("cylinder_groups[{i}].angle_deg"),
                group.angle_deg,
                0.0,
                360.0,
            )?;
            if group.cylinders.is_empty() {
                return Err(format!(
                    "`steering.cylinder_groups[{i}].cylinders` names no cylinder"
                ));
            }
            for &c in &group.cylinders {
                // The advance reading holds at most 64 strokes.
                if c >= 64 || !seen.insert(c) {
                    return Err(format!(
                        "`steering.cylinder_groups[{i}].cylinders`: cylinder {c} is beyond the 64 strokes of an advance or in two groups"
                    ));
                }
            }
        }
        if let Some(a) = self.articulation {
            within("articulation.front_m", a.front_m, 0.1, 100.0)?;
            within("articulation.rear_m", a.rear_m, 0.1, 100.0)?;
        }
        Ok(())
    }

    fn limit_per_m(&self) -> f64 {
        1.0 / self.min_radius_m
    }
}

/// The axis as the curve needs it, in each plane: [horizontal, vertical].
pub trait Axis {
    /// Direction angles at internal station `station_m`: azimuth (+ right)
    /// and pitch (+ up), radians.
    fn angles_rad(&self, station_m: f64) -> [f64; 2];
    /// Their rates along the station, 1/m.
    fn curvatures_per_m(&self, station_m: f64) -> [f64; 2];
}

impl Axis for Alignment {
    fn angles_rad(&self, station_m: f64) -> [f64; 2] {
        let d = self.direction_at(station_m);
        [d.heading_rad, d.pitch_rad]
    }
    fn curvatures_per_m(&self, station_m: f64) -> [f64; 2] {
        let d = self.direction_at(station_m);
        [d.curvature_horizontal_per_m, d.curvature_vertical_per_m]
    }
}

/// Where one plane's correction starts, against the axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlaneStart {
    /// d0, the front's deviation, mm.
    pub deviation_mm: f64,
    /// g0, the machine's tendency, mm/m.
    pub tendency_mm_per_m: f64,
    /// c0, the machine's present curvature less the axis's (the rate of
    /// its tendency), 1/m.
    pub curvature_per_m: f64,
}

/// One plane's quintic back to the axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quintic {
    d0_m: f64,
    g0: f64,
    c0: f64,
    a3: f64,
    a4: f64,
    a5: f64,
    length_m: f64,
}

impl Quintic {
    /// The quintic from `start` onto the axis at `length_m`.
    pub fn new(start: &PlaneStart, length_m: f64) -> Quintic {
        let (d0_m, g0, c0, l) = (
            start.deviation_mm / 1000.0,
            start.tendency_mm_per_m / 1000.0,
            start.curvature_per_m,
            length_m,
        );
        let r0 = -(d0_m + g0 * l + 0.5 * c0 * l * l);
        let r1 = -(g0 + c0 * l);
        let r2 = -c0;
        Quintic {
            d0_m,
            g0,
            c0,
            a3: (20.0 * r0 - 8.0 * r1 * l + r2 * l * l) / (2.0 * l.powi(3)),
            a4: (-30.0 * r0 + 14.0 * r1 * l - 2.0 * r2 * l * l) / (2.0 * l.powi(4)),
            a5: (12.0 * r0 - 6.0 * r1 * l + r2 * l * l) / (2.0 * l.powi(5)),
            length_m,
        }
    }

    /// (d, d′, d″) at `x`: metres, m/m, 1/m; on the axis beyond its end,
    /// before its start the path it started from (its start's curvature
    /// held).
    pub fn at(&self, x: f64) -> (f64, f64, f64) {
        if x >= self.length_m {
            return (0.0, 0.0, 0.0);
        }
        if x < 0.0 {
            let d = self.d0_m + x * (self.g0 + 0.5 * self.c0 * x);
            return (d, self.g0 + self.c0 * x, self.c0);
        }
        let (a3, a4, a5) = (self.a3, self.a4, self.a5);
        let d = self.d0_m + x * (self.g0 + x * (0.5 * self.c0 + x * (a3 + x * (a4 + x * a5))));
        let slope = self.g0 + x * (self.c0 + x * (3.0 * a3 + x * (4.0 * a4 + x * 5.0 * a5)));
        let curvature = self.c0 + x * (6.0 * a3 + x * (12.0 * a4 + x * 20.0 * a5));
        (d, slope, curvature)
    }
}

/// Where the front is against the axis: the `dta` estimate's front
/// deviation and tendency, and how the machine is curving now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Start {
    /// Internal station of the front (continuous along the axis), m.
    pub station_m: f64,
    pub horizontal: PlaneStart,
    pub vertical: PlaneStart,
}

/// A correction planned from a [`Start`]: everything the curve follows
/// from (kept while the machine follows it).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// Internal station where it starts, m.
    pub start_station_m: f64,
    /// Whole steps to the axis.
    pub steps: u32,
    pub length_m: f64,
    pub horizontal: PlaneStart,
    pub vertical: PlaneStart,
}

/// The path a plan makes on an axis.
struct Path<'a, A: Axis + ?Sized> {
    axis: &'a A,
    start_station_m: f64,
    planes: [Quintic; 2],
}

impl<'a, A: Axis + ?Sized> Path<'a, A> {
    fn new(axis: &'a A, plan: &Plan) -> Self {
        Path {
            axis,
            start_station_m: plan.start_station_m,
            planes: [
                Quintic::new(&plan.horizontal, plan.length_m),
                Quintic::new(&plan.vertical, plan.length_m),
            ],
        }
    }

    /// Deviation from the axis per plane at `x` from the start, m.
    fn deviation_m(&self, x: f64) -> [f64; 2] {
        self.planes.map(|q| q.at(x).0)
    }

    /// The path's direction angles at `x`, radians.
    fn angles_rad(&self, x: f64) -> [f64; 2] {
        let axis = self.axis.angles_rad(self.start_station_m + x);
        let [h, v] = self.planes.map(|q| q.at(x).1.atan());
        [axis[0] + h, axis[1] + v]
    }

    /// The path's curvature at `x`, 1/m.
    fn curvatures_per_m(&self, x: f64) -> [f64; 2] {
        let axis = self.axis.curvatures_per_m(self.start_station_m + x);
        let [h, v] = self.planes.map(|q| q.at(x).2);
        [axis[0] + h, axis[1] + v]
    }

    /// The stroke differences over the step from `x` (left less right,
    /// bottom less top), mm: the circle's diameter times the path's turn.
    pub(crate) fn stroke_differences_mm(&self, spec: &SteeringSpec, x: f64) -> [f64; 2] {
        let (a, b) = (self.angles_rad(x), self.angles_rad(x + spec.step_m));
        [0, 1].map(|i| spec.cylinder_circle_m * (b[i] - a[i]) * 1000.0)
    }

    /// Whether the path over `steps` keeps every bound: the radius at
    /// every quarter step, the change of stroke difference from
    /// `present_mm` and step to step, onto the axis after the end.
    fn drivable(&self, spec: &SteeringSpec, steps: u32, present_mm: [f64; 2]) -> bool {
        let limit = spec.limit_per_m() * (1.0 + ROUNDING);
        let samples = steps * SAMPLES_PER_STEP;
        let dx = spec.step_m / f64::from(SAMPLES_PER_STEP);
        let radius_held = (0..=samples).all(|j| {
            let [h, v] = self.curvatures_per_m(f64::from(j) * dx);
            h.hypot(v) <= limit
        });
        if !radius_held {
            return false;
        }
        let Some(change) = spec.max_stroke_change_mm else {
            return true;
        };
        let change = change * (1.0 + ROUNDING) + ROUNDING;
        let mut previous = present_mm;
        (0..=steps).all(|k| {
            let now = self.stroke_differences_mm(spec, f64::from(k) * spec.step_m);
            let held = (now[0] - previous[0]).hypot(now[1] - previous[1]) <= change;
            previous = now;
            held
        })
    }
}

/// Why no curve was given.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum Infeasible {
    /// No curve within `min_radius_m` reaches the axis within
    /// [`MAX_LENGTH_M`].
    #[error(
        "no curve within the machine's minimum radius of {min_radius_m} m and its stroke change reaches the axis within {max_length_m} m"
    )]
    TooFar {
        min_radius_m: f64,
        max_length_m: f64,
    },
    /// The axis itself curves tighter than the machine can.
    #[error(
        "the axis curves with a radius of {radius_m:.0} m at internal station {station_m:.1} m, tighter than the machine's minimum radius of {min_radius_m} m"
    )]
    AxisTooTight {
        radius_m: f64,
        station_m: f64,
        min_radius_m: f64,
    },
}

/// Every whole step from `first` for [`EXACT_STEPS`] candidates, then 5 %
/// longer each (a short step far from the axis would otherwise try
/// thousands of lengths, each sampled along its whole length), `most`
/// last.
fn candidate_steps(first: u32, most: u32) -> impl Iterator<Item = u32> {
    let mut next = Some(first);
    std::iter::from_fn(move || {
        let steps = next?;
        next = (steps < most).then(|| {
            let grown = if steps < first.saturating_add(EXACT_STEPS) {
                steps + 1
            } else {
                (f64::from(steps) * 1.05).ceil() as u32
            };
            grown.min(most)
        });
        Some(steps)
    })
}

/// Candidate lengths tried one step apart before they grow by 5 %.
const EXACT_STEPS: u32 = 100;

/// An axis sampled every `dx_m` from `start_m`: the plan's candidates look
/// at the same stations, each read once; any other station is read from
/// the axis.
struct Sampled<'a, A: Axis + ?Sized> {
    axis: &'a A,
    start_m: f64,
    dx_m: f64,
    angles: Vec<[f64; 2]>,
    curvatures: Vec<[f64; 2]>,
}

impl<'a, A: Axis + ?Sized> Sampled<'a, A> {
    fn new(axis: &'a A, start_m: f64, dx_m: f64, samples: u32) -> Self {
        let at = |j: u32| start_m + f64::from(j) * dx_m;
        Sampled {
            axis,
            start_m,
            dx_m,
            angles: (0..=samples).map(|j| axis.angles_rad(at(j))).collect(),
            curvatures: (0..=samples)
                .map(|j| axis.curvatures_per_m(at(j)))
                .collect(),
        }
    }

    /// The sample at `station_m`, if it is one.
    fn index(&self, station_m: f64) -> Option<usize> {
        let j = (station_m - self.start_m) / self.dx_m;
        let rounded = j.round();
        ((j - rounded).abs() < 1e-6 && rounded >= 0.0).then_some(rounded as usize)
    }
}

impl<A: Axis + ?Sized> Axis for Sampled<'_, A> {
    fn angles_rad(&self, station_m: f64) -> [f64; 2] {
        match self.index(station_m).and_then(|j| self.angles.get(j)) {
            Some(a) => *a,
            None => self.axis.angles_rad(station_m),
        }
    }
    fn curvatures_per_m(&self, station_m: f64) -> [f64; 2] {
        match self.index(station_m).and_then(|j| self.curvatures.get(j)) {
            Some(c) => *c,
            None => self.axis.curvatures_per_m(station_m),
        }
    }
}

/// The shortest correction the machine may be given, m: at least one step
/// and `min_length_m` (two shield lengths), whole steps.
fn first_steps(spec: &SteeringSpec, min_length_m: f64) -> u32 {
    let steps = (min_length_m / spec.step_m - ROUNDING).ceil().max(1.0);
    steps.min(MAX_LENGTH_M / spec.step_m) as u32
}

/// The correction from `start` on `axis` under `spec`: the fewest whole
/// steps, at least `min_length_m`, whose path keeps every bound.
/// `present_stroke_mm` is the stroke difference the machine steers now
/// (its present curvature over a step).
pub fn plan<A: Axis + ?Sized>(
    spec: &SteeringSpec,
    axis: &A,
    start: &Start,
    min_length_m: f64,
) -> Result<Plan, Infeasible> {
    let most = (MAX_LENGTH_M / spec.step_m).floor() as u32;
    let first = first_steps(spec, min_length_m).min(most);
    // The machine's present stroke difference: its present curvature
    // (the axis's and its own against it) over a step.
    let axis_now = axis.curvatures_per_m(start.station_m);
    let present_mm = [
        axis_now[0] + start.horizontal.curvature_per_m,
        axis_now[1] + start.vertical.curvature_per_m,
    ]
    .map(|k| spec.cylinder_circle_m * spec.step_m * k * 1000.0);
    // Every candidate samples the same stations: the axis once for all.
    let sampled = Sampled::new(
        axis,
        start.station_m,
        spec.step_m / f64::from(SAMPLES_PER_STEP),
        (most + 1) * SAMPLES_PER_STEP,
    );
    for steps in candidate_steps(first, most) {
        let length_m = f64::from(steps) * spec.step_m;
        let candidate = Plan {
            start_station_m: start.station_m,
            steps,
            length_m,
            horizontal: start.horizontal,
            vertical: start.vertical,
        };
        if Path::new(&sampled, &candidate).drivable(spec, steps, present_mm) {
            return Ok(candidate);
        }
    }
    // Say why: the axis itself where it is too tight within the shortest
    // curve, else the distance.
    let limit = spec.limit_per_m() * (1.0 + ROUNDING);
    let shortest = f64::from(first) * spec.step_m;
    let samples = first * SAMPLES_PER_STEP;
    let tight = (0..=samples)
        .map(|j| start.station_m + f64::from(j) * shortest / f64::from(samples))
        .find(|&s| {
            let [h, v] = axis.curvatures_per_m(s);
            h.hypot(v) > limit
        });
    Err(match tight {
        Some(station_m) => {
            let [h, v] = axis.curvatures_per_m(station_m);
            Infeasible::AxisTooTight {
                radius_m: 1.0 / h.hypot(v),
                station_m,
                min_radius_m: spec.min_radius_m,
            }
        }
        None => Infeasible::TooFar {
            min_radius_m: spec.min_radius_m,
            max_length_m: MAX_LENGTH_M,
        },
    })
}

/// One step's point of a plane's curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CurvePoint {
    /// Station of the point as the stationing reads: the front's plus k
    /// steps.
    pub station_m: f64,
    /// Where the front should be there, mm off the axis.
    pub deviation_mm: f64,
    /// The path's curvature there (the axis's and the correction's), 1/m.
    pub curvature_per_m: f64,
    /// Stroke of the cylinders on the left (bottom) less the right (top)
    /// over the step from here, mm: `cylinder_circle_m` times the path's
    /// turn over the step. A curve to the right (up) needs the left
    /// (bottom) cylinders to extend more.
    pub stroke_difference_mm: f64,
    /// Whether the point lies beyond the declared warn limit of the plane
    /// (false without tolerances).
    #[serde(default)]
    pub outside_warn: bool,
}

/// One plane's correction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PlaneCurve {
    /// The front's deviation now, mm.
    pub deviation_mm: f64,
    /// The machine's tendency now, mm/m.
    pub tendency_mm_per_m: f64,
    /// A point per step k = 0…steps from the front.
    pub points: Vec<CurvePoint>,
}

/// The correction of both planes from where the front is now.
#[derive(Debug, Clone, PartialEq)]
pub struct Correction {
    /// Whole steps from the front to the curve's end (at least one: on
    /// the axis, the next step).
    pub steps: u32,
    /// From the front to the curve's end, m.
    pub length_m: f64,
    pub horizontal: PlaneCurve,
    pub vertical: PlaneCurve,
}

/// Where the front is now, as the correction is drawn from it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Front {
    /// Internal station, m.
    pub internal_station_m: f64,
    /// As the stationing reads, m.
    pub station_m: f64,
    pub horizontal_mm: f64,
    pub vertical_mm: f64,
    pub tendency_horizontal_mm_per_m: f64,
    pub tendency_vertical_mm_per_m: f64,
}

/// The curve of `plan` on `axis`, a point per step from the front to the
/// curve's end (at least one step). The strokes steer the path's turn less
/// what the machine turns of itself, `own_per_m` per plane (1/m).
pub fn expand<A: Axis + ?Sized>(
    spec: &SteeringSpec,
    axis: &A,
    plan: &Plan,
    front: &Front,
    tolerances: Option<&Tolerances>,
    own_per_m: [f64; 2],
) -> Correction {
    let path = Path::new(axis, plan);
    let from_x = front.internal_station_m - plan.start_station_m;
    let remaining_m = (plan.length_m - from_x).max(0.0);
    let steps = ((remaining_m / spec.step_m) - ROUNDING).ceil().max(1.0) as u32;
    let warn = tolerances.map(|t| [t.horizontal_mm.warn, t.vertical_mm.warn]);
    let points: Vec<_> = (0..=steps)
        .map(|k| {
            let ahead_m = f64::from(k) * spec.step_m;
            let x = from_x + ahead_m;
            let deviation = path.deviation_m(x).map(|d| d * 1000.0);
            let curvature = path.curvatures_per_m(x);
            let turns = path.stroke_differences_mm(spec, x);
            let own = own_per_m.map(|b| spec.cylinder_circle_m * spec.step_m * b * 1000.0);
            let strokes = [turns[0] - own[0], turns[1] - own[1]];
            [0, 1].map(|i| CurvePoint {
                station_m: front.station_m + ahead_m,
                deviation_mm: deviation[i],
                curvature_per_m: curvature[i],
                stroke_difference_mm: strokes[i],
                outside_warn: warn.is_some_and(|w| deviation[i].abs() > w[i]),
            })
        })
        .collect();
    let plane = |i: usize, deviation_mm, tendency_mm_per_m| PlaneCurve {
        deviation_mm,
        tendency_mm_per_m,
        points: points.iter().map(|p| p[i]).collect(),
    };
    Correction {
        steps,
        length_m: remaining_m,
        horizontal: plane(0, front.horizontal_mm, front.tendency_horizontal_mm_per_m),
        vertical: plane(1, front.vertical_mm, front.tendency_vertical_mm_per_m),
    }
}

/// Where the plan wants the front at internal station `station_m`, mm off
/// the axis per plane.
pub fn planned_deviation_mm<A: Axis + ?Sized>(axis: &A, plan: &Plan, station_m: f64) -> [f64; 2] {
    Path::new(axis, plan)
        .deviation_m(station_m - plan.start_station_m)
        .map(|d| d * 1000.0)
}

/// The plan's slope against the axis at internal station `station_m`, per
/// plane.
pub fn planned_slope<A: Axis + ?Sized>(axis: &A, plan: &Plan, station_m: f64) -> [f64; 2] {
    let x = station_m - plan.start_station_m;
    Path::new(axis, plan).planes.map(|q| q.at(x).1)
}

/// One cylinder group's share of the next step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct GroupTarget {
    pub name: String,
    pub angle_deg: f64,
    /// How much more than the mean of all cylinders the group extends over
    /// the next step, mm: −(sin φ·Δh + cos φ·Δv)/2.
    pub extension_difference_mm: f64,
    /// The group's stroke at the end of the next push: its mean stroke at
    /// the last `advance` plus its extension difference (the next ring
    /// laid parallel to the last); `null` without the strokes.
    pub target_stroke_mm: Option<f64>,
}

/// Each declared group's share of the stroke differences
/// `[horizontal, vertical]`, with its target from the last advance's
/// `strokes_mm`.
pub fn group_targets(
    spec: &SteeringSpec,
    stroke_differences_mm: [f64; 2],
    strokes_mm: Option<&[f64]>,
) -> Vec<GroupTarget> {
    let [dh, dv] = stroke_differences_mm;
    spec.cylinder_groups
        .iter()
        .map(|g| {
            let (sin, cos) = g.angle_deg.to_radians().sin_cos();
            let extension_difference_mm = -(sin * dh + cos * dv) / 2.0;
            let measured: Option<Vec<f64>> = strokes_mm
                .map(|s| g.cylinders.iter().map(|&c| s.get(c).copied()).collect())
                .and_then(|v: Option<Vec<f64>>| v);
            let target_stroke_mm = measured
                .filter(|m| !m.is_empty())
                .map(|m| m.iter().sum::<f64>() / m.len() as f64 + extension_difference_mm);
            GroupTarget {
                name: g.name.clone(),
                angle_deg: g.angle_deg,
                extension_difference_mm,
                target_stroke_mm,
            }
        })
        .collect()
}

/// The articulation's angle per plane, degrees, that steers a step whose
/// path turns by `stroke_differences_mm` over the circle.
pub fn articulation_deg(spec: &SteeringSpec, stroke_differences_mm: [f64; 2]) -> Option<[f64; 2]> {
    spec.articulation.map(|a| {
        stroke_differences_mm.map(|d| {
            let turn_rad = d / 1000.0 / spec.cylinder_circle_m;
            (turn_rad / spec.step_m * 0.5 * (a.front_m + a.rear_m)).to_degrees()
        })
    })
}

/// The next step in words: "steer right 18 mm, down 4 mm over the next
/// ring" (stroke differences; an articulation's angles instead where one
/// is declared), then the groups that extend more.
pub fn words(
    spec: &SteeringSpec,
    stroke_differences_mm: [f64; 2],
    groups: &[GroupTarget],
) -> String {
    let step = match spec.step_name {
        StepName::Ring => "ring",
        StepName::Pipe => "pipe",
    };
    let [dh, dv] = stroke_differences_mm;
    let (amount_h, amount_v, unit, held) = match articulation_deg(spec, stroke_differences_mm) {
        Some([ah, av]) => (ah, av, "°", 0.005),
        None => (dh, dv, " mm", SAID_MM),
    };
    let say = |amount: f64, plus: &str, minus: &str, digits: usize| {
        if amount.abs() < held {
            None
        } else {
            let way = if amount > 0.0 { plus } else { minus };
            Some(format!("{way} {:.digits$}{unit}", amount.abs()))
        }
    };
    let digits = if unit == "°" { 2 } else { 0 };
    let parts: Vec<String> = [
        say(amount_h, "right", "left", digits),
        say(amount_v, "up", "down", digits),
    ]
    .into_iter()
    .flatten()
    .collect();
    let mut said = if parts.is_empty() {
        format!("hold the line over the next {step}")
    } else {
        format!("steer {} over the next {step}", parts.join(", "))
    };
    let mut more: Vec<&GroupTarget> = groups
        .iter()
        .filter(|g| g.extension_difference_mm >= SAID_MM)
        .collect();
    more.sort_by(|a, b| {
        b.extension_difference_mm
            .total_cmp(&a.extension_difference_mm)
    });
    if !more.is_empty() {
        let listed: Vec<String> = more
            .iter()
            .map(|g| format!("{} +{:.0} mm", g.name, g.extension_difference_mm))
            .collect();
        said.push_str(&format!("; extend more: {}", listed.join(", ")));
    }
    said
}

#[cfg(test)]
mod tests;
