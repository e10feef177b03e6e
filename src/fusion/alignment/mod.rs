//! The designed tunnel axis (DTA): a horizontal alignment of lines, arcs
//! and clothoid spirals ([`horizontal`]) and a vertical profile of grades
//! and parabolic curves ([`vertical`]), and where a point lies against it:
//! station, offset to the right, height above the design.
//!
//! The JSON form is the protocol's ("Design axis and deviation"): project
//! coordinates in metres, azimuth in degrees clockwise from grid north,
//! radius + for a curve to the right looking along increasing station,
//! `null` for straight. Stations are internal (continuous from the
//! start); station equations, if any, turn them into the stationing the
//! drawings use, which is what the `dta` stream reports.

pub mod horizontal;
pub mod landxml;
pub mod vertical;

use serde::{Deserialize, Serialize};

pub use horizontal::{Element, ElementKind, Foot, Pose, ProjectionError};
pub use vertical::{Profile, ProfileError, Pvi};

use crate::fusion::angles::rad;

/// Where the alignment starts, as declared.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StartPose {
    #[schema(minimum = -1.0e7, maximum = 1.0e7)]
    pub easting_m: f64,
    #[schema(minimum = -1.0e7, maximum = 1.0e7)]
    pub northing_m: f64,
    /// Clockwise from grid north.
    #[schema(minimum = -360.0, maximum = 360.0)]
    pub azimuth_deg: f64,
}

/// One horizontal element as declared.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ElementSpec {
    Line {
        #[schema(exclusive_minimum = 0.0, maximum = 100_000.0)]
        length_m: f64,
    },
    /// Radius + for a curve to the right looking along increasing station.
    Arc {
        #[schema(exclusive_minimum = 0.0, maximum = 100_000.0)]
        length_m: f64,
        radius_m: f64,
    },
    /// From one radius to another (`null`: straight); not equal.
    Spiral {
        #[schema(exclusive_minimum = 0.0, maximum = 100_000.0)]
        length_m: f64,
        radius_start_m: Option<f64>,
        radius_end_m: Option<f64>,
    },
}

/// The vertical profile as declared.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ProfileSpec {
    #[schema(minimum = -20_000.0, maximum = 20_000.0)]
    pub start_height_m: f64,
    #[serde(default)]
    pub pvis: Vec<Pvi>,
    /// Percent, + rising.
    #[schema(minimum = -100.0, maximum = 100.0)]
    pub end_grade_pct: f64,
}

/// An alignment as the protocol declares it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct AlignmentSpec {
    #[serde(default)]
    pub name: String,
    #[serde(default)]
    #[schema(minimum = -1.0e7, maximum = 1.0e7)]
    pub start_station_m: f64,
    pub start: StartPose,
    #[schema(min_items = 1)]
    pub horizontal: Vec<ElementSpec>,
    pub vertical: ProfileSpec,
    /// Where the stationing jumps (tunnelnav extension; LandXML's
    /// `StaEquation`), in increasing internal station. Every other station
    /// of the declaration is internal: continuous from `start_station_m`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub station_equations: Vec<StationEquation>,
}

/// A station equation: from `station_internal_m` on, the station reads
/// `station_ahead_m` plus the distance past it (the station back, before
/// the equation, is informative only).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StationEquation {
    pub station_internal_m: f64,
    pub station_ahead_m: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub station_back_m: Option<f64>,
}

/// Why an alignment was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignmentError {
    #[error("the alignment has no horizontal elements")]
    Empty,
    #[error("the start: {0}")]
    Start(String),
    #[error("horizontal element {index} ({kind}): {reason}")]
    Element {
        index: usize,
        kind: &'static str,
        reason: String,
    },
    #[error("vertical profile: {0}")]
    Profile(#[from] ProfileError),
    #[error("station equation {index}: {reason}")]
    Equation { index: usize, reason: String },
    #[error("{0}")]
    Scale(String),
    #[error("`name` must be at most {MAX_NAME_CHARS} printable characters")]
    Name,
}

/// The longest alignment name (a project's drive, printed on reports).
pub const MAX_NAME_CHARS: usize = 200;

/// A validated alignment, its elements placed.
#[derive(Debug, Clone, PartialEq)]
pub struct Alignment {
    pub name: String,
    pub elements: Vec<Element>,
    pub profile: Profile,
    /// In increasing internal station.
    pub equations: Vec<StationEquation>,
}

/// Where a point lies against the axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Deviation {
    /// The station of the perpendicular foot as the stationing reads (its
    /// station equations applied).
    pub station_m: f64,
    /// The same, continuous from the start (what the geometry is in).
    pub internal_station_m: f64,
    /// + right of the axis looking along increasing station, m.
    pub horizontal_m: f64,
    /// + above the design height at that station, m.
    pub vertical_m: f64,
}

/// The axis's direction and curvature at a station.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisDirection {
    /// Azimuth, clockwise from grid north.
    pub heading_rad: f64,
    /// Its rate along the station, + turning right, 1/m.
    pub curvature_horizontal_per_m: f64,
    /// atan of the design grade, + rising.
    pub pitch_rad: f64,
    /// Its rate along the station, + bending upward (a sag), 1/m.
    pub curvature_vertical_per_m: f64,
}

/// A point of the axis, for drawing it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, utoipa::ToSchema)]
pub struct AxisPoint {
    /// As the stationing reads (station equations applied).
    pub station_m: f64,
    pub internal_station_m: f64,
    pub easting_m: f64,
    pub northing_m: f64,
    /// Design height at the station.
    pub height_m: f64,
}

/// Largest magnitude of a project coordinate or station, m (the bound of
/// a reading's easting and northing).
pub const MAX_COORDINATE_M: f64 = 1.0e7;
/// Largest magnitude of a design height, m (the bound of a reading's height).
pub const MAX_HEIGHT_M: f64 = 20_000.0;
/// Longest horizontal element or vertical curve, m.
pub const MAX_ELEMENT_M: f64 = 100_000.0;
/// Smallest radius of a curve, m.
pub const MIN_RADIUS_M: f64 = 1.0;
/// Steepest grade, percent.
pub const MAX_GRADE_PCT: f64 = 100.0;

/// A curvature from a declared radius: `None` is straight.
fn curvature(radius_m: Option<f64>) -> Result<f64, String> {
    match radius_m {
        None => Ok(0.0),
        Some(r) if r.is_finite() && r != 0.0 => Ok(1.0 / r),
        Some(r) => Err(format!(
            "radius {r} is not a radius: a non-zero number of metres, + right, or null for straight"
        )),
    }
}

/// Station equations in increasing internal station strictly inside
/// (`start_m`, `end_m`), their stations finite.
pub fn check_equations(
    equations: &[StationEquation],
    start_m: f64,
    end_m: f64,
) -> Result<(), AlignmentError> {
    let mut previous = start_m;
    for (index, e) in equations.iter().enumerate() {
        let refuse = |reason: String| AlignmentError::Equation { index, reason };
        if ![e.station_internal_m, e.station_ahead_m]
            .iter()
            .all(|x| x.is_finite())
            || e.station_back_m.is_some_and(|b| !b.is_finite())
        {
            return Err(refuse("stations must be finite numbers".into()));
        }
        if e.station_internal_m <= previous || e.station_internal_m >= end_m {
            return Err(refuse(format!(
                "internal station {} is not after the previous equation (or the start, {previous}) and before the end ({end_m})",
                e.station_internal_m
            )));
        }
        previous = e.station_internal_m;
    }
    Ok(())
}

impl AlignmentSpec {
    /// The alignment with its elements placed end to end, or what is wrong.
    pub fn build(&self) -> Result<Alignment, AlignmentError> {
        if self.name.chars().count() > MAX_NAME_CHARS || self.name.chars().any(char::is_control) {
            return Err(AlignmentError::Name);
        }
        if self.horizontal.is_empty() {
            return Err(AlignmentError::Empty);
        }
        let s = &self.start;
        if ![
            s.easting_m,
            s.northing_m,
            s.azimuth_deg,
            self.start_station_m,
        ]
        .iter()
        .all(|x| x.is_finite())
        {
            return Err(AlignmentError::Start(
                "easting, northing, azimuth and station must be finite numbers".into(),
            ));
        }
        let mut pose = Pose {
            easting_m: s.easting_m,
            northing_m: s.northing_m,
            azimuth_rad: rad(s.azimuth_deg),
        };
        let mut station = self.start_station_m;
        let mut elements = Vec::with_capacity(self.horizontal.len());
        for (index, spec) in self.horizontal.iter().enumerate() {
            let (kind, length_m, k0, k1) = match *spec {
                ElementSpec::Line { length_m } => (ElementKind::Line, length_m, Ok(0.0), Ok(0.0)),
                ElementSpec::Arc { length_m, radius_m } => {
                    let k = curvature(Some(radius_m));
                    (ElementKind::Arc, length_m, k.clone(), k)
                }
                ElementSpec::Spiral {
                    length_m,
                    radius_start_m,
                    radius_end_m,
                } => (
                    ElementKind::Spiral,
                    length_m,
                    curvature(radius_start_m),
                    curvature(radius_end_m),
                ),
            };
            let name = match kind {
                ElementKind::Line => "line",
                ElementKind::Arc => "arc",
                ElementKind::Spiral => "spiral",
            };
            let refuse = |reason: String| AlignmentError::Element {
                index,
                kind: name,
                reason,
            };
            if !(length_m.is_finite() && length_m > 0.0) {
                return Err(refuse(format!("length {length_m} m is not positive")));
            }
            let (k0, k1) = (k0.map_err(refuse)?, k1.map_err(refuse)?);
            if kind == ElementKind::Spiral && k0 == k1 {
                return Err(refuse(
                    "its start and end radius are equal: that is an arc or a line, not a spiral"
                        .into(),
                ));
            }
            let element = Element {
                kind,
                start: pose,
                start_station_m: station,
                length_m,
                curvature_start: k0,
                curvature_end: k1,
            };
            pose = element.end();
            station += length_m;
            elements.push(element);
        }
        let profile = Profile {
            start_station_m: self.start_station_m,
            start_height_m: self.vertical.start_height_m,
            pvis: self.vertical.pvis.clone(),
            end_grade: self.vertical.end_grade_pct / 100.0,
        };
        if !profile.start_height_m.is_finite() {
            return Err(AlignmentError::Start("start height must be finite".into()));
        }
        profile.validate()?;
        check_equations(&self.station_equations, self.start_station_m, station)?;
        Ok(Alignment {
            name: self.name.clone(),
            elements,
            profile,
            equations: self.station_equations.clone(),
        })
    }

    /// Holds a new declaration's numbers to project scale (the bounds
    /// above), which [`AlignmentSpec::build`] does not: an axis stored by an
    /// earlier release still opens. Coordinates and stations as a
    /// reading's easting and northing, heights as its height.
    pub fn check_scale(&self) -> Result<(), AlignmentError> {
        let scale = |what: String, value: f64, max_abs: f64, unit: &str| {
            if value.abs() <= max_abs {
                Ok(())
            } else {
                // Absurd values in short form (1e308, not 309 digits).
                let value = if value.abs() < 1e12 {
                    value.to_string()
                } else {
                    format!("{value:e}")
                };
                Err(AlignmentError::Scale(format!(
                    "{what} {value} {unit} is beyond ±{max_abs} {unit} (an axis is held to project scale)"
                )))
            }
        };
        let s = &self.start;
        let zone_hint = |e: AlignmentError| {
            AlignmentError::Scale(format!(
                "{e}; a grid coordinate with its zone number in front? drop the zone number"
            ))
        };
        scale("start easting".into(), s.easting_m, MAX_COORDINATE_M, "m").map_err(zone_hint)?;
        scale("start northing".into(), s.northing_m, MAX_COORDINATE_M, "m").map_err(zone_hint)?;
        scale("start azimuth".into(), s.azimuth_deg, 360.0, "°")?;
        let mut station = self.start_station_m;
        scale("start station".into(), station, MAX_COORDINATE_M, "m")?;
        for (index, element) in self.horizontal.iter().enumerate() {
            let (length_m, radii) = match *element {
                ElementSpec::Line { length_m } => (length_m, [None, None]),
                ElementSpec::Arc { length_m, radius_m } => (length_m, [Some(radius_m), None]),
                ElementSpec::Spiral {
                    length_m,
                    radius_start_m,
                    radius_end_m,
                } => (length_m, [radius_start_m, radius_end_m]),
            };
            let what = |name: &str| format!("horizontal element {index}: {name}");
            scale(what("length"), length_m, MAX_ELEMENT_M, "m")?;
            for radius in radii.into_iter().flatten() {
                if radius.abs() < MIN_RADIUS_M {
                    return Err(AlignmentError::Scale(format!(
                        "{} {radius} m is tighter than {MIN_RADIUS_M} m",
                        what("radius")
                    )));
                }
            }
            station += length_m;
            scale(what("end station"), station, MAX_COORDINATE_M, "m")?;
        }
        let v = &self.vertical;
        scale("start height".into(), v.start_height_m, MAX_HEIGHT_M, "m")?;
        scale("end grade".into(), v.end_grade_pct, MAX_GRADE_PCT, "%")?;
        for (index, pvi) in v.pvis.iter().enumerate() {
            let what = |name: &str| format!("PVI {index}: {name}");
            scale(what("station"), pvi.station_m, MAX_COORDINATE_M, "m")?;
            scale(what("height"), pvi.height_m, MAX_HEIGHT_M, "m")?;
            scale(what("curve length"), pvi.curve_length_m, MAX_ELEMENT_M, "m")?;
        }
        for (index, e) in self.station_equations.iter().enumerate() {
            let what = |name: &str| format!("station equation {index}: {name}");
            scale(
                what("internal station"),
                e.station_internal_m,
                MAX_COORDINATE_M,
                "m",
            )?;
            scale(
                what("station ahead"),
                e.station_ahead_m,
                MAX_COORDINATE_M,
                "m",
            )?;
        }
        Ok(())
    }
}

impl Alignment {
    /// The protocol's JSON of this alignment (of a LandXML import, say).
    pub fn to_spec(&self) -> AlignmentSpec {
        let radius = |k: f64| (k != 0.0).then(|| 1.0 / k);
        let first = self.elements.first().map(|e| e.start);
        AlignmentSpec {
            name: self.name.clone(),
            start_station_m: self.station_range_m().0,
            start: StartPose {
                easting_m: first.map_or(0.0, |p| p.easting_m),
                northing_m: first.map_or(0.0, |p| p.northing_m),
                azimuth_deg: first.map_or(0.0, |p| p.azimuth_rad.to_degrees()),
            },
            horizontal: self
                .elements
                .iter()
                .map(|e| match e.kind {
                    ElementKind::Line => ElementSpec::Line {
                        length_m: e.length_m,
                    },
                    ElementKind::Arc => ElementSpec::Arc {
                        length_m: e.length_m,
                        radius_m: 1.0 / e.curvature_start,
                    },
                    ElementKind::Spiral => ElementSpec::Spiral {
                        length_m: e.length_m,
                        radius_start_m: radius(e.curvature_start),
                        radius_end_m: radius(e.curvature_end),
                    },
                })
                .collect(),
            vertical: ProfileSpec {
                start_height_m: self.profile.start_height_m,
                pvis: self.profile.pvis.clone(),
                end_grade_pct: self.profile.end_grade * 100.0,
            },
            station_equations: self.equations.clone(),
        }
    }

    /// The station as the stationing reads at `internal_m`: past the last
    /// equation at or before it, its station ahead plus the distance since.
    pub fn station_of(&self, internal_m: f64) -> f64 {
        match self
            .equations
            .iter()
            .rev()
            .find(|e| e.station_internal_m <= internal_m)
        {
            Some(e) => e.station_ahead_m + (internal_m - e.station_internal_m),
            None => internal_m,
        }
    }

    /// The internal station that reads `station_m`, nearest to `near_m`
    /// where station equations make a station read twice; `None` for a
    /// station no part of the stationing reads (inside a gap an equation
    /// jumps over).
    pub fn internal_of(&self, station_m: f64, near_m: Option<f64>) -> Option<f64> {
        // Each stretch between equations reads its internal station shifted.
        let mut stretches = vec![(f64::NEG_INFINITY, 0.0)];
        stretches.extend(self.equations.iter().map(|e| {
            (
                e.station_internal_m,
                e.station_ahead_m - e.station_internal_m,
            )
        }));
        let ends: Vec<f64> = stretches
            .iter()
            .skip(1)
            .map(|s| s.0)
            .chain([f64::INFINITY])
            .collect();
        stretches
            .iter()
            .zip(ends)
            .map(|(&(from, shift), to)| (station_m - shift, from, to))
            .filter(|&(internal, from, to)| internal >= from && internal < to)
            .map(|(internal, _, _)| internal)
            .min_by(|a, b| {
                let near = near_m.unwrap_or(a.min(*b));
                (a - near).abs().total_cmp(&(b - near).abs())
            })
    }

    /// The axis's direction and curvature in each plane at internal
    /// station `station_m`: the azimuth and its rate (+ to the right), the
    /// pitch atan(grade) and its rate (+ upward), per metre of station.
    /// Beyond either end the tangent continues (curvature 0).
    pub fn direction_at(&self, station_m: f64) -> AxisDirection {
        let (grade, grade_rate) = self.profile.grade_at(station_m);
        let (heading_rad, curvature_horizontal_per_m) = match (
            self.elements.first(),
            self.elements
                .iter()
                .find(|e| station_m <= e.start_station_m + e.length_m),
        ) {
            (Some(first), _) if station_m < first.start_station_m => (first.start.azimuth_rad, 0.0),
            (_, Some(e)) => {
                let s = station_m - e.start_station_m;
                (e.azimuth(s), e.curvature(s))
            }
            (_, None) => (
                self.elements.last().map_or(0.0, |e| e.end().azimuth_rad),
                0.0,
            ),
        };
        AxisDirection {
            heading_rad,
            curvature_horizontal_per_m,
            pitch_rad: grade.atan(),
            curvature_vertical_per_m: grade_rate / (1.0 + grade * grade),
        }
    }

    /// Internal station of the start and the end.
    pub fn station_range_m(&self) -> (f64, f64) {
        let first = self.elements.first().map_or(0.0, |e| e.start_station_m);
        let last = self
            .elements
            .last()
            .map_or(0.0, |e| e.start_station_m + e.length_m);
        (first, last)
    }

    /// The axis at internal station `station_m`: its pose and design height.
    pub fn axis_at(&self, station_m: f64) -> Option<(Pose, f64)> {
        let element = self
            .elements
            .iter()
            .find(|e| station_m <= e.start_station_m + e.length_m)?;
        if station_m < element.start_station_m {
            return None;
        }
        Some((
            element.pose_at(station_m - element.start_station_m),
            self.profile.height_at(station_m),
        ))
    }

    /// The axis every `step_m` of internal station from its start, at every
    /// element's start and at its end (ascending, none twice).
    pub fn sampled(&self, step_m: f64) -> Vec<AxisPoint> {
        let (start, end) = self.station_range_m();
        let mut stations: Vec<f64> = self.elements.iter().map(|e| e.start_station_m).collect();
        if step_m > 0.0 {
            let steps = ((end - start) / step_m).floor() as usize;
            stations.extend((1..=steps).map(|i| start + i as f64 * step_m));
        }
        stations.push(end);
        stations.sort_by(f64::total_cmp);
        stations.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        stations
            .into_iter()
            .filter_map(|station_m| {
                let (pose, height_m) = self.axis_at(station_m)?;
                Some(AxisPoint {
                    station_m: self.station_of(station_m),
                    internal_station_m: station_m,
                    easting_m: pose.easting_m,
                    northing_m: pose.northing_m,
                    height_m,
                })
            })
            .collect()
    }

    /// Where (`easting_m`, `northing_m`, `height_m`) lies against the axis.
    pub fn deviation(
        &self,
        easting_m: f64,
        northing_m: f64,
        height_m: f64,
    ) -> Result<Deviation, ProjectionError> {
        let foot = horizontal::project(&self.elements, easting_m, northing_m)?;
        Ok(Deviation {
            station_m: self.station_of(foot.station_m),
            internal_station_m: foot.station_m,
            horizontal_m: foot.offset_m,
            vertical_m: height_m - self.profile.height_at(foot.station_m),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The protocol's example.
    const S1: &str = r#"{"name": "S-1 drive", "start_station_m": 0.0,
     "start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 30.0},
     "horizontal": [
       {"type": "line", "length_m": 40.0},
       {"type": "spiral", "length_m": 30.0, "radius_start_m": null, "radius_end_m": 300.0},
       {"type": "arc", "length_m": 50.0, "radius_m": 300.0},
       {"type": "spiral", "length_m": 30.0, "radius_start_m": 300.0, "radius_end_m": null},
       {"type": "line", "length_m": 100.0}],
     "vertical": {"start_height_m": 50.0,
       "pvis": [{"station_m": 120.0, "height_m": 50.6, "curve_length_m": 60.0}],
       "end_grade_pct": -0.5}}"#;

    #[test]
    fn the_protocols_example_builds_and_locates_points() {
        let spec: AlignmentSpec = serde_json::from_str(S1).unwrap();
        let alignment = spec.build().unwrap();
        assert_eq!(alignment.station_range_m(), (0.0, 250.0));
        // On the first line, 20 m in: 10 m east, 17.320508 m north; a
        // point 0.05 m right of it and 0.02 m above the design (50.1 m).
        let (e, n) = (1000.0 + 10.0, 5000.0 + 17.320_508_075_688_77);
        let right = (30f64.to_radians().cos(), -(30f64.to_radians().sin()));
        let d = alignment
            .deviation(e + 0.05 * right.0, n + 0.05 * right.1, 50.12)
            .unwrap();
        assert!((d.station_m - 20.0).abs() < 1e-6, "{d:?}");
        assert!((d.horizontal_m - 0.05).abs() < 1e-6, "{d:?}");
        assert!((d.vertical_m - 0.02).abs() < 1e-9, "{d:?}");
        // The total turn: the two spirals' 30/(2·300) each and the arc's
        // 50/300: 0.26667 rad, so the last line runs at 30° + 15.279°.
        let last = alignment.elements.last().unwrap().start;
        let turned = 0.05 + 50.0 / 300.0 + 0.05;
        assert!((last.azimuth_rad - (30f64.to_radians() + turned)).abs() < 1e-12);
        // The direction along it: in the arc 1/300 to the right, halfway
        // up the first spiral half that (and turned 15/(2·30)·15/300 =
        // 0.0125 rad), past the end straight on; in the vertical curve of
        // 60 m about 120 m from +0.5 % to −0.5 % (by the profile's end
        // grade) the pitch bends down by 0.01/60 per metre.
        let at = |s| alignment.direction_at(s);
        assert!((at(90.0).curvature_horizontal_per_m - 1.0 / 300.0).abs() < 1e-15);
        let spiral = at(55.0);
        assert!((spiral.curvature_horizontal_per_m - 0.5 / 300.0).abs() < 1e-15);
        assert!((spiral.heading_rad - (30f64.to_radians() + 0.0125)).abs() < 1e-12);
        assert_eq!(at(300.0).curvature_horizontal_per_m, 0.0);
        assert!((at(300.0).heading_rad - last.azimuth_rad).abs() < 1e-12);
        let crest = at(120.0);
        assert!(crest.pitch_rad.abs() < 1e-12, "{crest:?}");
        assert!((crest.curvature_vertical_per_m + 0.01 / 60.0).abs() < 1e-12);
    }

    #[test]
    fn a_new_axis_is_held_to_project_scale_and_the_culprit_named() {
        // A real drive in a UTM zone: northing 5.8e6 m, stations 12+345.
        let utm = r#"{"start_station_m": 12345.0,
            "start": {"easting_m": 385000.0, "northing_m": 5800000.0, "azimuth_deg": 350.0},
            "horizontal": [{"type": "line", "length_m": 800.0},
                           {"type": "arc", "length_m": 200.0, "radius_m": -450.0}],
            "vertical": {"start_height_m": -32.0, "end_grade_pct": -3.5,
                         "pvis": [{"station_m": 12700.0, "height_m": -44.0, "curve_length_m": 120.0}]}}"#;
        let spec: AlignmentSpec = serde_json::from_str(utm).unwrap();
        assert_eq!(spec.check_scale(), Ok(()));
        let refused = |edit: &dyn Fn(&mut AlignmentSpec)| {
            let mut spec = spec.clone();
            edit(&mut spec);
            spec.check_scale().unwrap_err().to_string()
        };
        let zone = refused(&|a| a.start.easting_m = 32_385_000.0);
        assert!(
            zone.contains("start easting 32385000 m is beyond ±10000000 m"),
            "{zone}"
        );
        assert!(zone.contains("zone number"), "{zone}");
        let long = refused(&|a| a.horizontal[0] = ElementSpec::Line { length_m: 1e308 });
        assert!(
            long.starts_with("horizontal element 0: length 1e308 m"),
            "{long}"
        );
        let tight = refused(&|a| {
            a.horizontal[1] = ElementSpec::Arc {
                length_m: 200.0,
                radius_m: 0.5,
            }
        });
        assert!(
            tight.contains("element 1: radius 0.5 m is tighter than 1 m"),
            "{tight}"
        );
        let steep = refused(&|a| a.vertical.end_grade_pct = 150.0);
        assert!(
            steep.starts_with("end grade 150 % is beyond ±100 %"),
            "{steep}"
        );
        let deep = refused(&|a| a.vertical.pvis[0].height_m = -25_000.0);
        assert!(deep.starts_with("PVI 0: height -25000 m"), "{deep}");
        // The structural checks alone (what an axis stored by an earlier
        // release is opened with) still take an axis beyond scale.
        let mut old = spec.clone();
        old.start.easting_m = 32_385_000.0;
        assert!(old.build().is_ok());
    }

    #[test]
    fn bad_declarations_name_the_element_and_what_is_wrong() {
        let mut spec: AlignmentSpec = serde_json::from_str(S1).unwrap();
        // A name is bounded as a machine's is (it is printed on reports).
        spec.name = "x".repeat(MAX_NAME_CHARS + 1);
        assert_eq!(spec.build().unwrap_err(), AlignmentError::Name);
        spec.name = "S-1\u{7}".into();
        assert_eq!(spec.build().unwrap_err(), AlignmentError::Name);
        spec.name = "x".repeat(MAX_NAME_CHARS);
        assert!(spec.build().is_ok());
        spec.horizontal[2] = ElementSpec::Arc {
            length_m: 50.0,
            radius_m: 0.0,
        };
        let err = spec.build().unwrap_err().to_string();
        assert!(
            err.contains("horizontal element 2 (arc)") && err.contains("radius 0"),
            "{err}"
        );
        spec.horizontal[2] = ElementSpec::Spiral {
            length_m: 50.0,
            radius_start_m: Some(300.0),
            radius_end_m: Some(300.0),
        };
        let err = spec.build().unwrap_err().to_string();
        assert!(
            err.contains("element 2 (spiral)") && err.contains("equal"),
            "{err}"
        );
        spec.horizontal[2] = ElementSpec::Line { length_m: -1.0 };
        assert!(
            spec.build()
                .unwrap_err()
                .to_string()
                .contains("not positive")
        );
        spec.horizontal.clear();
        assert_eq!(spec.build().unwrap_err(), AlignmentError::Empty);
        let unknown = S1.replace("\"arc\"", "\"helix\"");
        assert!(serde_json::from_str::<AlignmentSpec>(&unknown).is_err());
    }

    #[test]
    fn the_sampled_axis_has_every_step_and_every_element_start() {
        let alignment = serde_json::from_str::<AlignmentSpec>(S1)
            .unwrap()
            .build()
            .unwrap();
        let points = alignment.sampled(25.0);
        let stations: Vec<f64> = points.iter().map(|p| p.station_m).collect();
        // Steps 0, 25, …, 250 and the element starts 40, 70, 120, 150.
        assert_eq!(
            stations,
            [
                0.0, 25.0, 40.0, 50.0, 70.0, 75.0, 100.0, 120.0, 125.0, 150.0, 175.0, 200.0, 225.0,
                250.0
            ]
        );
        // 25 m along the first line at 30°: 12.5 m east, 21.650635 m north;
        // the first grade runs from 50 m to the PVI's 50.6 m at 120 m (0.5 %).
        let p = points[1];
        assert!((p.easting_m - 1012.5).abs() < 1e-9, "{p:?}");
        assert!((p.northing_m - 5_021.650_635_094_61).abs() < 1e-9, "{p:?}");
        assert!((p.height_m - 50.125).abs() < 1e-9, "{p:?}");
    }

    #[test]
    fn station_equations_renumber_the_stationing_after_them() {
        let mut spec: AlignmentSpec = serde_json::from_str(S1).unwrap();
        // Chainage 0+000 to 0+100, then (an overlap) 0+080 onwards, then
        // 1+000 from internal 200.
        spec.station_equations = vec![
            StationEquation {
                station_internal_m: 100.0,
                station_ahead_m: 80.0,
                station_back_m: Some(100.0),
            },
            StationEquation {
                station_internal_m: 200.0,
                station_ahead_m: 1000.0,
                station_back_m: None,
            },
        ];
        let alignment = spec.build().unwrap();
        for (internal, reads) in [
            (0.0, 0.0),
            (99.0, 99.0),
            (100.0, 80.0),
            (150.0, 130.0),
            (200.0, 1000.0),
            (250.0, 1050.0),
        ] {
            assert!(
                (alignment.station_of(internal) - reads).abs() < 1e-12,
                "{internal}"
            );
        }
        let points = alignment.sampled(50.0);
        let last = points.last().unwrap();
        assert_eq!((last.internal_station_m, last.station_m), (250.0, 1050.0));
        // Back from the stationing: 90 reads twice (internal 90 and 110),
        // the nearer one wins; 500 reads nowhere (the jump to 1+000).
        let back = |reads, near| alignment.internal_of(reads, near);
        assert_eq!(back(90.0, None), Some(90.0));
        assert_eq!(back(90.0, Some(108.0)), Some(110.0));
        assert_eq!(back(1050.0, Some(0.0)), Some(250.0));
        assert_eq!(back(500.0, None), None);
        // Round trip through the JSON; a missing field reads as none.
        let json = serde_json::to_string(&alignment.to_spec()).unwrap();
        assert_eq!(
            serde_json::from_str::<AlignmentSpec>(&json)
                .unwrap()
                .build()
                .unwrap(),
            alignment
        );
        assert!(
            serde_json::from_str::<AlignmentSpec>(S1)
                .unwrap()
                .station_equations
                .is_empty()
        );
        // Out of order, at the start, past the end, not a number: refused.
        for internal in [0.0, 260.0, f64::NAN] {
            spec.station_equations[0].station_internal_m = internal;
            let err = spec.build().unwrap_err().to_string();
            assert!(err.starts_with("station equation 0"), "{err}");
        }
        spec.station_equations[0].station_internal_m = 220.0;
        let err = spec.build().unwrap_err().to_string();
        assert!(err.starts_with("station equation 1"), "{err}");
    }
}
