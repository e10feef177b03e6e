//! The correction curve back to the design axis (issue 39): per plane
//! (horizontal, vertical) a cubic in the distance x ahead of the front,
//!
//! d(x) = d0 + g0·x + a·x² + b·x³,
//!
//! starting at the front's deviation d0 with the machine's tendency g0 and
//! ending on the axis tangentially, d(L) = 0 and d′(L) = 0:
//!
//! a = −(3·d0 + 2·g0·L)/L², b = (2·d0 + g0·L)/L³.
//!
//! Its curvature κ(x) = d″(x) = 2a + 6b·x is linear in x, so largest at an
//! end. L is the fewest whole steps (a ring or a pipe, `step_m`) for which
//! the curvature of both planes together, √(κh² + κv²), is within
//! 1/`min_radius_m` at both ends; per step the thrust cylinders on opposite
//! sides must differ in stroke by `cylinder_circle_m`·`step_m`·κ: the
//! cylinders on the outside of the curve extend more, so a curve to the
//! right or upward (κ > 0) is steered with the left or bottom ones (the
//! difference is left less right, bottom less top). With d0 positive
//! (right of or above the axis) the curve bends back first (κ(0) < 0: the
//! right or top cylinders extend more) and straightens out onto the axis
//! (κ(L) > 0).
//!
//! Lengths in metres inside; the answer in the protocol's units (mm,
//! mm/m, 1/m).

use serde::{Deserialize, Serialize};

/// The longest correction looked for: a machine that cannot reach the
/// axis within this is told so.
pub const MAX_LENGTH_M: f64 = 500.0;

/// How a machine may be steered: its tightest radius, the length of one
/// ring or pipe, and the diameter of the circle of its thrust cylinders.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SteeringSpec {
    /// The tightest curve the machine may steer, metres.
    pub min_radius_m: f64,
    /// One step: a ring's or a pipe's length, metres.
    pub step_m: f64,
    /// Diameter of the circle the thrust cylinders stand on, metres.
    pub cylinder_circle_m: f64,
}

impl SteeringSpec {
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
        within("cylinder_circle_m", self.cylinder_circle_m, 0.1, 50.0)
    }
}

/// One plane's cubic back to the axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cubic {
    /// d0, metres.
    pub d0_m: f64,
    /// g0, metres per metre.
    pub g0: f64,
    /// a, 1/m.
    pub a: f64,
    /// b, 1/m².
    pub b: f64,
}

impl Cubic {
    /// The cubic from `d0_m` with slope `g0` onto the axis at `length_m`.
    pub fn new(d0_m: f64, g0: f64, length_m: f64) -> Cubic {
        let l = length_m;
        Cubic {
            d0_m,
            g0,
            a: -(3.0 * d0_m + 2.0 * g0 * l) / (l * l),
            b: (2.0 * d0_m + g0 * l) / (l * l * l),
        }
    }

    /// d(x), metres.
    pub fn deviation_m(&self, x: f64) -> f64 {
        self.d0_m + x * (self.g0 + x * (self.a + x * self.b))
    }

    /// d′(x), metres per metre.
    pub fn slope(&self, x: f64) -> f64 {
        self.g0 + x * (2.0 * self.a + 3.0 * self.b * x)
    }

    /// κ(x) = d″(x) = 2a + 6b·x, 1/m.
    pub fn curvature_per_m(&self, x: f64) -> f64 {
        2.0 * self.a + 6.0 * self.b * x
    }
}

/// One step's point of a plane's curve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CurvePoint {
    /// Station of the point: the front's plus k steps.
    pub station_m: f64,
    /// Where the front should be there, mm off the axis.
    pub deviation_mm: f64,
    /// The curve's curvature there, 1/m.
    pub curvature_per_m: f64,
    /// Stroke of the cylinders on the left (bottom) less the right (top)
    /// over the step from here, mm: `cylinder_circle_m`·`step_m`·κ. A
    /// curve to the right (κ > 0) needs the left cylinders to extend more.
    pub stroke_difference_mm: f64,
}

/// One plane's correction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PlaneCurve {
    /// The front's deviation now, mm.
    pub deviation_mm: f64,
    /// The machine's tendency now, mm/m.
    pub tendency_mm_per_m: f64,
    /// A point per step k = 0…steps.
    pub points: Vec<CurvePoint>,
}

/// The correction of both planes.
#[derive(Debug, Clone, PartialEq)]
pub struct Correction {
    /// Whole steps to the axis.
    pub steps: u32,
    pub length_m: f64,
    pub horizontal: PlaneCurve,
    pub vertical: PlaneCurve,
}

/// Where the front is against the axis: the `dta` estimate's front
/// deviation and tendency.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Start {
    /// Station of the front, metres.
    pub station_m: f64,
    pub horizontal_mm: f64,
    pub vertical_mm: f64,
    pub tendency_horizontal_mm_per_m: f64,
    pub tendency_vertical_mm_per_m: f64,
}

/// Why no curve was given.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum Infeasible {
    /// No curve within `min_radius_m` reaches the axis within
    /// [`MAX_LENGTH_M`].
    #[error(
        "no curve within the machine's minimum radius of {min_radius_m} m reaches the axis within {max_length_m} m"
    )]
    TooFar {
        min_radius_m: f64,
        max_length_m: f64,
    },
}

/// Both planes' curvature together at `x`, 1/m.
fn combined(h: &Cubic, v: &Cubic, x: f64) -> f64 {
    h.curvature_per_m(x).hypot(v.curvature_per_m(x))
}

/// The correction from `start` under `spec`: the fewest whole steps whose
/// curve keeps within the minimum radius at both ends (so everywhere).
pub fn correction(spec: &SteeringSpec, start: &Start) -> Result<Correction, Infeasible> {
    let limit = 1.0 / spec.min_radius_m;
    let most = (MAX_LENGTH_M / spec.step_m).floor() as u32;
    let (dh, gh) = (
        start.horizontal_mm / 1000.0,
        start.tendency_horizontal_mm_per_m / 1000.0,
    );
    let (dv, gv) = (
        start.vertical_mm / 1000.0,
        start.tendency_vertical_mm_per_m / 1000.0,
    );
    // A bound's rounding must not refuse a curve exactly at the limit.
    let within = |k: f64| k <= limit * (1.0 + 1e-12);
    for steps in 1..=most {
        let length_m = f64::from(steps) * spec.step_m;
        let (h, v) = (Cubic::new(dh, gh, length_m), Cubic::new(dv, gv, length_m));
        if within(combined(&h, &v, 0.0)) && within(combined(&h, &v, length_m)) {
            let plane = |cubic: &Cubic, deviation_mm: f64, tendency_mm_per_m: f64| PlaneCurve {
                deviation_mm,
                tendency_mm_per_m,
                points: (0..=steps)
                    .map(|k| {
                        let x = f64::from(k) * spec.step_m;
                        let curvature_per_m = cubic.curvature_per_m(x);
                        CurvePoint {
                            station_m: start.station_m + x,
                            deviation_mm: cubic.deviation_m(x) * 1000.0,
                            curvature_per_m,
                            stroke_difference_mm: spec.cylinder_circle_m
                                * spec.step_m
                                * curvature_per_m
                                * 1000.0,
                        }
                    })
                    .collect(),
            };
            return Ok(Correction {
                steps,
                length_m,
                horizontal: plane(&h, start.horizontal_mm, start.tendency_horizontal_mm_per_m),
                vertical: plane(&v, start.vertical_mm, start.tendency_vertical_mm_per_m),
            });
        }
    }
    Err(Infeasible::TooFar {
        min_radius_m: spec.min_radius_m,
        max_length_m: MAX_LENGTH_M,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The machine: 1500 m minimum radius, 1.5 m rings, thrust
    /// cylinders on a 6.0 m circle.
    fn rings() -> SteeringSpec {
        SteeringSpec {
            min_radius_m: 1500.0,
            step_m: 1.5,
            cylinder_circle_m: 6.0,
        }
    }

    fn close(a: f64, b: f64, tolerance: f64) -> bool {
        (a - b).abs() <= tolerance
    }

    #[test]
    fn the_cubic_ends_on_the_axis_tangentially() {
        // Hand-computed: d0 = 50 mm, g0 = 0, L = 30 m: a = −3·0.05/900 =
        // −1.6667e-4, b = 2·0.05/27000 = 3.7037e-6.
        let c = Cubic::new(0.050, 0.0, 30.0);
        assert!(close(c.a, -1.666_667e-4, 1e-9), "{c:?}");
        assert!(close(c.b, 3.703_704e-6, 1e-11), "{c:?}");
        assert!(close(c.deviation_m(30.0), 0.0, 1e-15));
        assert!(close(c.slope(30.0), 0.0, 1e-15));
        // The check values: κ(0) = −κ(L) = 3.333·10⁻⁴ /m in
        // size (bending back first: negative at the start for d0 > 0),
        // and d(15 m) = 25.000 mm.
        assert!(close(c.curvature_per_m(0.0), -3.333_333e-4, 1e-9));
        assert!(close(c.curvature_per_m(30.0), 3.333_333e-4, 1e-9));
        assert!(close(c.deviation_m(15.0) * 1000.0, 25.000, 1e-9));
        // With a tendency the start's slope is g0.
        let c = Cubic::new(0.050, 0.002, 28.5);
        assert!(close(c.slope(0.0), 0.002, 1e-15));
        assert!(close(c.deviation_m(28.5), 0.0, 1e-15));
    }

    #[test]
    fn the_fewest_steps_within_the_minimum_radius() {
        // The second check, one plane: d0 = 50 mm, g0 = +2 mm/m,
        // R_min = 1500 m, 1.5 m rings, cylinders on a 6.0 m circle: 19
        // rings (28.5 m); end radii 1538 m and 1962 m, stroke differences
        // 5.85 mm and 4.59 mm. Hand-computed: at L = 28.5 m,
        // a = −(0.15 + 0.114)/812.25 = −3.2502e-4, κ(0) = −6.5004e-4
        // (R 1538.4 m); b = 0.157/23149.125 = 6.7821e-6,
        // κ(L) = −6.5004e-4 + 6·6.7821e-6·28.5 = 5.0970e-4 (R 1961.9 m);
        // 18 rings (27 m) would need κ(0) = −2·0.258/729 = −7.078e-4,
        // beyond 1/1500 = 6.667e-4.
        let spec = rings();
        let start = Start {
            station_m: 1000.0,
            horizontal_mm: 50.0,
            vertical_mm: 0.0,
            tendency_horizontal_mm_per_m: 2.0,
            tendency_vertical_mm_per_m: 0.0,
        };
        let c = correction(&spec, &start).unwrap();
        assert_eq!((c.steps, c.length_m), (19, 28.5));
        let points = &c.horizontal.points;
        assert_eq!(points.len(), 20);
        let (first, last) = (points[0], points[19]);
        assert!(
            close(1.0 / first.curvature_per_m.abs(), 1538.4, 0.1),
            "{first:?}"
        );
        assert!(close(1.0 / last.curvature_per_m, 1961.9, 0.1), "{last:?}");
        assert!(
            close(first.stroke_difference_mm, -5.850, 0.001),
            "{first:?}"
        );
        assert!(close(last.stroke_difference_mm, 4.587, 0.001), "{last:?}");
        assert_eq!((first.station_m, last.station_m), (1000.0, 1028.5));
        assert!(close(first.deviation_mm, 50.0, 1e-12) && close(last.deviation_mm, 0.0, 1e-9));
        // The vertical plane is on the axis already: it stays there.
        assert!(c.vertical.points.iter().all(|p| p.deviation_mm == 0.0));
    }

    #[test]
    fn both_planes_share_the_radius_and_a_lost_machine_is_told_so() {
        let spec = rings();
        // The same 50 mm in both planes needs a longer curve than in one:
        // at the 19 rings of one plane the two together curve √2 times
        // as much.
        let both = Start {
            station_m: 0.0,
            horizontal_mm: 50.0,
            vertical_mm: 50.0,
            tendency_horizontal_mm_per_m: 2.0,
            tendency_vertical_mm_per_m: 2.0,
        };
        let c = correction(&spec, &both).unwrap();
        assert!(c.steps > 19, "{}", c.steps);
        let k = |p: &CurvePoint, q: &CurvePoint| p.curvature_per_m.hypot(q.curvature_per_m);
        let (h, v) = (&c.horizontal.points, &c.vertical.points);
        assert!(k(&h[0], &v[0]) <= 1.0 / 1500.0 + 1e-15);
        assert!(k(h.last().unwrap(), v.last().unwrap()) <= 1.0 / 1500.0 + 1e-15);
        // 3 m off and heading away at 10 %: even at L = 500 m,
        // κ(0) = −6·3/500² − 4·0.1/500 = −8.72e-4, beyond 1/1500.
        let lost = Start {
            station_m: 0.0,
            horizontal_mm: 3000.0,
            vertical_mm: 0.0,
            tendency_horizontal_mm_per_m: 100.0,
            tendency_vertical_mm_per_m: 0.0,
        };
        assert!(matches!(
            correction(&spec, &lost),
            Err(Infeasible::TooFar { .. })
        ));
        assert!(
            SteeringSpec {
                step_m: 0.0,
                ..spec
            }
            .check()
            .is_err()
        );
        assert!(spec.check().is_ok());
    }
}
