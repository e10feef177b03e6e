//! The horizontal alignment: lines, circular arcs and clothoid spirals,
//! continuous in position and azimuth, in project coordinates (easting,
//! northing; azimuth clockwise from grid north, radians inside).
//!
//! Every element is one formula: the curvature runs linearly from κ₀ to
//! κ₁ over its length L (a line: both 0; an arc: both 1/R; a spiral: any
//! two), + to the right looking along increasing station, so the azimuth is
//! a(s) = a₀ + κ₀·s + (κ₁ − κ₀)·s²/(2L) and the position is
//! E(s) = E₀ + ∫ sin a, N(s) = N₀ + ∫ cos a. Lines and arcs integrate in
//! closed form; a spiral (also one between two arcs of different radius,
//! a piece of a clothoid that does not start at its origin) by
//! Gauss–Legendre quadrature, 8 nodes per panel of at most 10 m: the
//! integrand is a sine of a quadratic, and the rule's error on such a panel
//! is far below a micrometre for any curvature a tunnel has.

use serde::{Deserialize, Serialize};

/// A point with the direction of travel: metres, and radians clockwise
/// from grid north.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub easting_m: f64,
    pub northing_m: f64,
    pub azimuth_rad: f64,
}

/// One horizontal element, placed: where it starts and how its curvature runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Element {
    pub kind: ElementKind,
    pub start: Pose,
    /// Station of its start, m.
    pub start_station_m: f64,
    pub length_m: f64,
    /// Curvature at its start and end, 1/m, + to the right.
    pub curvature_start: f64,
    pub curvature_end: f64,
}

/// What an element is, for messages and export.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ElementKind {
    Line,
    Arc,
    Spiral,
}

/// Gauss–Legendre nodes and weights on [−1, 1], 8 points.
const GL_NODES: [f64; 8] = [
    -0.960_289_856_497_536_3,
    -0.796_666_477_413_626_7,
    -0.525_532_409_916_329,
    -0.183_434_642_495_649_8,
    0.183_434_642_495_649_8,
    0.525_532_409_916_329,
    0.796_666_477_413_626_7,
    0.960_289_856_497_536_3,
];
const GL_WEIGHTS: [f64; 8] = [
    0.101_228_536_290_376_3,
    0.222_381_034_453_374_5,
    0.313_706_645_877_887_3,
    0.362_683_783_378_362,
    0.362_683_783_378_362,
    0.313_706_645_877_887_3,
    0.222_381_034_453_374_5,
    0.101_228_536_290_376_3,
];
/// Longest quadrature panel, m.
const PANEL_M: f64 = 10.0;
/// Below this curvature difference an element's curvature is constant.
const CONSTANT_CURVATURE: f64 = 1e-15;
/// Below this curvature an arc is a line (radius beyond 10¹² m).
const STRAIGHT: f64 = 1e-12;
/// A point this close to an element's end normal lies on it, m.
const ON_THE_NORMAL_M: f64 = 1e-9;

impl Element {
    /// The curvature's rate of change along the element, 1/m².
    fn curvature_rate(&self) -> f64 {
        if self.length_m > 0.0 {
            (self.curvature_end - self.curvature_start) / self.length_m
        } else {
            0.0
        }
    }

    /// Curvature at `s` metres into the element.
    pub fn curvature(&self, s: f64) -> f64 {
        self.curvature_start + self.curvature_rate() * s
    }

    /// Azimuth at `s` metres into the element.
    pub fn azimuth(&self, s: f64) -> f64 {
        self.start.azimuth_rad + self.curvature_start * s + 0.5 * self.curvature_rate() * s * s
    }

    /// The pose `s` metres into the element (`s` may run a little beyond
    /// either end: the same formula continued).
    pub fn pose_at(&self, s: f64) -> Pose {
        let a0 = self.start.azimuth_rad;
        let k = self.curvature_start;
        let (de, dn) = if (self.curvature_end - k).abs() < CONSTANT_CURVATURE {
            if k.abs() < STRAIGHT {
                (s * a0.sin(), s * a0.cos())
            } else {
                let a = a0 + k * s;
                ((a0.cos() - a.cos()) / k, (a.sin() - a0.sin()) / k)
            }
        } else {
            self.integrate(s)
        };
        Pose {
            easting_m: self.start.easting_m + de,
            northing_m: self.start.northing_m + dn,
            azimuth_rad: self.azimuth(s),
        }
    }

    /// ∫₀ˢ (sin a, cos a) du by composite Gauss–Legendre.
    fn integrate(&self, s: f64) -> (f64, f64) {
        let panels = (s.abs() / PANEL_M).ceil().max(1.0);
        let h = s / panels;
        let (mut de, mut dn) = (0.0, 0.0);
        for p in 0..panels as usize {
            let mid = (p as f64 + 0.5) * h;
            for (x, w) in GL_NODES.iter().zip(GL_WEIGHTS) {
                let a = self.azimuth(mid + 0.5 * h * x);
                de += w * a.sin();
                dn += w * a.cos();
            }
        }
        (0.5 * h * de, 0.5 * h * dn)
    }

    /// The pose at the element's end.
    pub fn end(&self) -> Pose {
        self.pose_at(self.length_m)
    }
}

/// The foot of a point on the horizontal alignment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Foot {
    pub station_m: f64,
    /// The axis there.
    pub pose: Pose,
    /// Signed distance from the axis, + to the right, m.
    pub offset_m: f64,
    /// Index of the element the foot lies on.
    pub element: usize,
}

/// Why a point has no foot on the alignment.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProjectionError {
    #[error(
        "the point (E {easting_m:.3}, N {northing_m:.3}) lies before the alignment's start (station {start_station_m:.3})"
    )]
    BeforeStart {
        easting_m: f64,
        northing_m: f64,
        start_station_m: f64,
    },
    #[error(
        "the point (E {easting_m:.3}, N {northing_m:.3}) lies beyond the alignment's end (station {end_station_m:.3})"
    )]
    BeyondEnd {
        easting_m: f64,
        northing_m: f64,
        end_station_m: f64,
    },
    #[error("the alignment has no elements")]
    Empty,
}

/// Along-track component of `(P − X(s))` on the element: zero at the foot.
fn along(element: &Element, s: f64, easting_m: f64, northing_m: f64) -> f64 {
    components(&element.pose_at(s), easting_m, northing_m).0
}

/// `(P − X)` along the axis's direction at `x` and across it, + right.
fn components(x: &Pose, easting_m: f64, northing_m: f64) -> (f64, f64) {
    let (de, dn) = (easting_m - x.easting_m, northing_m - x.northing_m);
    let (sin, cos) = x.azimuth_rad.sin_cos();
    (de * sin + dn * cos, de * cos - dn * sin)
}

/// The foot of (`easting_m`, `northing_m`) on `elements`: the nearest point
/// of the axis whose tangent is perpendicular to the line to it. Solved
/// per element by bisection narrowed with Newton steps (the along-track
/// component changes sign across the foot); where several elements hold a
/// foot (inside a tight curve) the nearest wins.
pub fn project(
    elements: &[Element],
    easting_m: f64,
    northing_m: f64,
) -> Result<Foot, ProjectionError> {
    let first = elements.first().ok_or(ProjectionError::Empty)?;
    let last = elements.last().ok_or(ProjectionError::Empty)?;
    let mut best: Option<Foot> = None;
    for (index, element) in elements.iter().enumerate() {
        let (mut lo, mut hi) = (0.0, element.length_m);
        let (f_lo, f_hi) = (
            along(element, lo, easting_m, northing_m),
            along(element, hi, easting_m, northing_m),
        );
        // Ahead of the start and behind the end: a foot in between (a
        // point on the normal through an end counts, within rounding).
        if !(f_lo >= -ON_THE_NORMAL_M && f_hi <= ON_THE_NORMAL_M) {
            continue;
        }
        let mut s = 0.5 * (lo + hi);
        for _ in 0..100 {
            let (f, right) = components(&element.pose_at(s), easting_m, northing_m);
            if f.abs() < 1e-12 {
                break;
            }
            if f > 0.0 {
                lo = s;
            } else {
                hi = s;
            }
            if hi - lo < 1e-10 {
                break;
            }
            // Newton: d(along)/ds = −1 + κ·(offset to the left).
            let slope = -1.0 - element.curvature(s) * right;
            let newton = s - f / slope;
            s = if slope < 0.0 && newton > lo && newton < hi {
                newton
            } else {
                0.5 * (lo + hi)
            };
        }
        let pose = element.pose_at(s);
        let offset_m = components(&pose, easting_m, northing_m).1;
        let foot = Foot {
            station_m: element.start_station_m + s,
            pose,
            offset_m,
            element: index,
        };
        if best.is_none_or(|b| foot.offset_m.abs() < b.offset_m.abs()) {
            best = Some(foot);
        }
    }
    best.ok_or_else(|| {
        if along(first, 0.0, easting_m, northing_m) < -ON_THE_NORMAL_M {
            ProjectionError::BeforeStart {
                easting_m,
                northing_m,
                start_station_m: first.start_station_m,
            }
        } else {
            ProjectionError::BeyondEnd {
                easting_m,
                northing_m,
                end_station_m: last.start_station_m + last.length_m,
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn element(kind: ElementKind, start: Pose, length_m: f64, k0: f64, k1: f64) -> Element {
        Element {
            kind,
            start,
            start_station_m: 100.0,
            length_m,
            curvature_start: k0,
            curvature_end: k1,
        }
    }

    const ORIGIN: Pose = Pose {
        easting_m: 1000.0,
        northing_m: 5000.0,
        azimuth_rad: 0.0,
    };

    #[test]
    fn a_line_and_an_arc_by_hand() {
        // Azimuth 30°: 40 m go 20 m east, 34.641016 m north.
        let start = Pose {
            azimuth_rad: 30f64.to_radians(),
            ..ORIGIN
        };
        let line = element(ElementKind::Line, start, 40.0, 0.0, 0.0).end();
        assert!((line.easting_m - 1020.0).abs() < 1e-9);
        assert!((line.northing_m - 5_034.641_016_151_378).abs() < 1e-9);
        // Heading north, a right-hand arc of R = 100 m over a quarter
        // circle (157.0796 m) ends 100 m east and 100 m north, heading east.
        let quarter = 100.0 * std::f64::consts::FRAC_PI_2;
        let arc = element(ElementKind::Arc, ORIGIN, quarter, 0.01, 0.01).end();
        assert!((arc.easting_m - 1100.0).abs() < 1e-9, "{arc:?}");
        assert!((arc.northing_m - 5100.0).abs() < 1e-9, "{arc:?}");
        assert!((arc.azimuth_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // The same arc to the left ends 100 m west.
        let left = element(ElementKind::Arc, ORIGIN, quarter, -0.01, -0.01).end();
        assert!((left.easting_m - 900.0).abs() < 1e-9, "{left:?}");
    }

    /// The clothoid from a straight by its series (guidance notes): with
    /// A² = R·L and τ = l²/(2A²), along x = l(1 − τ²/10 + τ⁴/216 − τ⁶/9360)
    /// and across y = l(τ/3 − τ³/42 + τ⁵/1320 − τ⁷/75600).
    fn clothoid_series(l: f64, a2: f64) -> (f64, f64) {
        let tau = l * l / (2.0 * a2);
        let x = l * (1.0 - tau.powi(2) / 10.0 + tau.powi(4) / 216.0 - tau.powi(6) / 9360.0);
        let y = l * (tau / 3.0 - tau.powi(3) / 42.0 + tau.powi(5) / 1320.0 - tau.powi(7) / 75600.0);
        (x, y)
    }

    #[test]
    fn a_spiral_from_a_straight_matches_the_clothoid_series() {
        // Heading north, a 60 m spiral to R = 150 m, right and left.
        let (length, radius) = (60.0, 150.0);
        for (sign, name) in [(1.0, "right"), (-1.0, "left")] {
            let spiral = element(ElementKind::Spiral, ORIGIN, length, 0.0, sign / radius);
            for l in [10.0, 25.0, 47.5, 60.0] {
                let p = spiral.pose_at(l);
                let (x, y) = clothoid_series(l, radius * length);
                // Heading north: along is northing, across (right) easting.
                assert!(
                    (p.northing_m - 5000.0 - x).abs() < 1e-7,
                    "{name} {l}: {p:?}"
                );
                assert!(
                    (p.easting_m - 1000.0 - sign * y).abs() < 1e-7,
                    "{name} {l}: {p:?}"
                );
                let tau = l * l / (2.0 * radius * length);
                assert!((p.azimuth_rad - sign * tau).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn a_spiral_between_two_arcs_is_a_piece_of_one_clothoid() {
        // The clothoid with A² = 150·60 from its origin; its piece from
        // l = 20 m (R = A²/20 = 450 m) to l = 60 m (R = 150 m) placed at
        // its own start pose must follow the same curve.
        let a2 = 150.0 * 60.0;
        let (x0, y0) = clothoid_series(20.0, a2);
        let start = Pose {
            easting_m: 1000.0 + y0,
            northing_m: 5000.0 + x0,
            azimuth_rad: 20.0 * 20.0 / (2.0 * a2),
        };
        let piece = element(ElementKind::Spiral, start, 40.0, 20.0 / a2, 60.0 / a2);
        for l in [20.0, 33.0, 51.0, 60.0] {
            let p = piece.pose_at(l - 20.0);
            let (x, y) = clothoid_series(l, a2);
            assert!((p.northing_m - 5000.0 - x).abs() < 1e-7, "{l}: {p:?}");
            assert!((p.easting_m - 1000.0 - y).abs() < 1e-7, "{l}: {p:?}");
        }
    }

    /// Line, spiral, arc, spiral to a tighter arc, spiral, line, chained
    /// end to start; `sign` +1 turns right, −1 left.
    fn chain(sign: f64) -> Vec<Element> {
        let (k1, k2) = (sign / 300.0, sign / 120.0);
        let specs = [
            (ElementKind::Line, 40.0, 0.0, 0.0),
            (ElementKind::Spiral, 30.0, 0.0, k1),
            (ElementKind::Arc, 50.0, k1, k1),
            (ElementKind::Spiral, 20.0, k1, k2),
            (ElementKind::Arc, 30.0, k2, k2),
            (ElementKind::Spiral, 30.0, k2, 0.0),
            (ElementKind::Line, 50.0, 0.0, 0.0),
        ];
        let mut start = Pose {
            azimuth_rad: 30f64.to_radians(),
            ..ORIGIN
        };
        let mut station = 0.0;
        let mut out = Vec::new();
        for (kind, length_m, k0, k1) in specs {
            let e = Element {
                kind,
                start,
                start_station_m: station,
                length_m,
                curvature_start: k0,
                curvature_end: k1,
            };
            start = e.end();
            station += length_m;
            out.push(e);
        }
        out
    }

    #[test]
    fn points_offset_from_every_element_project_back_to_their_station() {
        for elements in [chain(1.0), chain(-1.0)] {
            for station in [
                0.0, 12.5, 40.0, 55.0, 70.0, 95.5, 120.0, 131.0, 140.0, 155.0, 170.0, 185.0, 200.0,
                225.0, 250.0,
            ] {
                let e = elements
                    .iter()
                    .rev()
                    .find(|e| e.start_station_m <= station)
                    .unwrap();
                let x = e.pose_at(station - e.start_station_m);
                for offset in [-10.0, -2.5, 0.0, 0.7, 10.0] {
                    // `offset` metres to the right of the axis.
                    let p_e = x.easting_m + offset * x.azimuth_rad.cos();
                    let p_n = x.northing_m - offset * x.azimuth_rad.sin();
                    let foot = project(&elements, p_e, p_n).unwrap();
                    assert!(
                        (foot.station_m - station).abs() < 1e-4,
                        "station {station} offset {offset}: {foot:?}"
                    );
                    assert!(
                        (foot.offset_m - offset).abs() < 1e-4,
                        "{station} {offset}: {foot:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_point_outside_the_station_range_is_refused_not_projected() {
        let elements = chain(1.0);
        let start = elements[0].start;
        // 5 m behind the start, on the line's extension.
        let err = project(
            &elements,
            start.easting_m - 5.0 * start.azimuth_rad.sin(),
            start.northing_m - 5.0 * start.azimuth_rad.cos(),
        )
        .unwrap_err();
        assert!(matches!(err, ProjectionError::BeforeStart { .. }), "{err}");
        let end = elements.last().unwrap().end();
        let err = project(
            &elements,
            end.easting_m + 3.0 * end.azimuth_rad.sin(),
            end.northing_m + 3.0 * end.azimuth_rad.cos(),
        )
        .unwrap_err();
        assert!(matches!(err, ProjectionError::BeyondEnd { .. }), "{err}");
        assert!(err.to_string().contains("250.000"), "{err}");
    }
}
