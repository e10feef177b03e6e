//! LandXML 1.2 alignments, as design tools export them: `Alignment` →
//! `CoordGeom` with `Line` (Start, End), `Curve` (rot, radius, length;
//! Start, Center, End, PI) and `Spiral` (spiType clothoid, rot, length,
//! radiusStart, radiusEnd, either `INF`; Start, PI, End), and `Profile` →
//! `ProfAlign` with `PVI`, `ParaCurve` and `CircCurve`. Coordinates are
//! written northing first.
//!
//! The elements are rebuilt from their lengths, radii and rotation, each
//! from where the one before ends; the points the file gives must agree
//! (continuity of position and azimuth, and each element's own end): the
//! error names the element that breaks it and by how much. A `CircCurve`
//! in the profile is taken as the parabola of its length (for tunnel grades
//! the two differ by far less than a millimetre).

use roxmltree::{Document, Node};

use super::horizontal::{Element, ElementKind, Pose};
use super::vertical::{Profile, Pvi};
use super::{Alignment, AlignmentError};

/// How far a point the file gives may lie from the rebuilt geometry, m.
const POSITION_TOLERANCE_M: f64 = 0.001;
/// How far a direction the file implies may lie from the rebuilt one, rad
/// (about 2 seconds of arc).
const AZIMUTH_TOLERANCE_RAD: f64 = 1e-5;

/// Why a LandXML file was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LandXmlError {
    #[error("not XML: {0}")]
    Xml(String),
    #[error("{0}")]
    Missing(String),
    #[error("{element}: {reason}")]
    Element { element: String, reason: String },
    #[error(transparent)]
    Alignment(#[from] AlignmentError),
}

fn local<'a>(node: &Node<'a, '_>) -> &'a str {
    node.tag_name().name()
}

fn children<'a, 'i>(node: Node<'a, 'i>, name: &'static str) -> impl Iterator<Item = Node<'a, 'i>> {
    node.children()
        .filter(move |c| c.is_element() && c.tag_name().name() == name)
}

/// "northing easting" text as (easting, northing).
fn point(node: Node, what: &str, element: &str) -> Result<(f64, f64), LandXmlError> {
    let text = node.text().unwrap_or("");
    let numbers: Vec<f64> = text
        .split_whitespace()
        .map(str::parse)
        .collect::<Result<_, _>>()
        .map_err(|_| LandXmlError::Element {
            element: element.to_string(),
            reason: format!("{what} `{text}` is not \"northing easting\""),
        })?;
    match numbers.as_slice() {
        [n, e, ..] if n.is_finite() && e.is_finite() => Ok((*e, *n)),
        _ => Err(LandXmlError::Element {
            element: element.to_string(),
            reason: format!("{what} `{text}` is not \"northing easting\""),
        }),
    }
}

fn child_point(
    node: Node,
    name: &'static str,
    element: &str,
) -> Result<Option<(f64, f64)>, LandXmlError> {
    children(node, name)
        .next()
        .map(|c| point(c, name, element))
        .transpose()
}

fn attribute(node: Node, name: &str, element: &str) -> Result<Option<f64>, LandXmlError> {
    match node.attribute(name) {
        None => Ok(None),
        Some(text) => text
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .map(Some)
            .ok_or_else(|| LandXmlError::Element {
                element: element.to_string(),
                reason: format!("{name}=\"{text}\" is not a number"),
            }),
    }
}

/// A radius attribute as a curvature magnitude: `INF` (or absent) is 0.
fn inverse_radius(node: Node, name: &str, element: &str) -> Result<f64, LandXmlError> {
    match node.attribute(name).map(str::trim) {
        None => Ok(0.0),
        Some(text) if text.eq_ignore_ascii_case("INF") => Ok(0.0),
        Some(_) => match attribute(node, name, element)? {
            Some(r) if r > 0.0 => Ok(1.0 / r),
            other => Err(LandXmlError::Element {
                element: element.to_string(),
                reason: format!("{name} {other:?} is not a radius"),
            }),
        },
    }
}

/// Direction from `a` to `b`, clockwise from north.
fn azimuth(a: (f64, f64), b: (f64, f64)) -> f64 {
    (b.0 - a.0).atan2(b.1 - a.1)
}

/// The difference of two azimuths, wrapped to (−π, π].
fn turn(a: f64, b: f64) -> f64 {
    let d = (b - a).rem_euclid(std::f64::consts::TAU);
    if d > std::f64::consts::PI {
        d - std::f64::consts::TAU
    } else {
        d
    }
}

/// The first `Alignment` of a LandXML 1.2 document.
pub fn parse(text: &str) -> Result<Alignment, LandXmlError> {
    let document = Document::parse(text).map_err(|e| LandXmlError::Xml(e.to_string()))?;
    let alignment = document
        .descendants()
        .find(|n| n.is_element() && local(n) == "Alignment")
        .ok_or_else(|| LandXmlError::Missing("no <Alignment> element".into()))?;
    let name = alignment.attribute("name").unwrap_or("").to_string();
    let coord_geom = children(alignment, "CoordGeom")
        .next()
        .ok_or_else(|| LandXmlError::Missing("<Alignment> has no <CoordGeom>".into()))?;
    let start_station = attribute(alignment, "staStart", "<Alignment>")?.unwrap_or(0.0);
    let elements = coord_geom_elements(coord_geom, start_station)?;
    let profile = profile(alignment, start_station)?;
    profile.validate().map_err(AlignmentError::from)?;
    let equations = station_equations(alignment)?;
    let alignment = Alignment {
        name,
        elements,
        profile,
        equations,
    };
    let (start, end) = alignment.station_range_m();
    crate::fusion::alignment::check_equations(&alignment.equations, start, end)?;
    Ok(alignment)
}

/// The alignment's `StaEquation`s (`staInternal`, `staAhead`, `staBack`),
/// in increasing internal station as LandXML lists them.
fn station_equations(
    alignment: Node,
) -> Result<Vec<crate::fusion::alignment::StationEquation>, LandXmlError> {
    children(alignment, "StaEquation")
        .enumerate()
        .map(|(index, node)| {
            let label = format!("<StaEquation> {index}");
            let required = |name: &str| {
                attribute(node, name, &label)?.ok_or_else(|| LandXmlError::Element {
                    element: label.clone(),
                    reason: format!("no {name}"),
                })
            };
            Ok(crate::fusion::alignment::StationEquation {
                station_internal_m: required("staInternal")?,
                station_ahead_m: required("staAhead")?,
                station_back_m: attribute(node, "staBack", &label)?,
            })
        })
        .collect()
}

fn coord_geom_elements(coord_geom: Node, start_station: f64) -> Result<Vec<Element>, LandXmlError> {
    let mut elements: Vec<Element> = Vec::new();
    let mut pose: Option<Pose> = None;
    let mut station = start_station;
    for (index, node) in coord_geom.children().filter(Node::is_element).enumerate() {
        let tag = local(&node);
        let label = format!(
            "<CoordGeom> element {index} (<{tag}>{})",
            node.attribute("staStart")
                .map(|s| format!(" staStart {s}"))
                .unwrap_or_default()
        );
        let refuse = |reason: String| LandXmlError::Element {
            element: label.clone(),
            reason,
        };
        let start =
            child_point(node, "Start", &label)?.ok_or_else(|| refuse("no <Start>".into()))?;
        let end = child_point(node, "End", &label)?.ok_or_else(|| refuse("no <End>".into()))?;
        let pi = child_point(node, "PI", &label)?;
        let (kind, length_m, k0, k1, declared_azimuth) = match tag {
            "Line" => {
                let chord = (end.0 - start.0).hypot(end.1 - start.1);
                let length = attribute(node, "length", &label)?.unwrap_or(chord);
                (
                    ElementKind::Line,
                    length,
                    0.0,
                    0.0,
                    Some(azimuth(start, end)),
                )
            }
            "Curve" | "Spiral" => {
                let sign = match node.attribute("rot") {
                    Some("cw") => 1.0,
                    Some("ccw") => -1.0,
                    other => {
                        return Err(refuse(format!("rot {other:?}: expected \"cw\" or \"ccw\"")));
                    }
                };
                let length =
                    attribute(node, "length", &label)?.ok_or_else(|| refuse("no length".into()))?;
                let tangent = pi.map(|pi| azimuth(start, pi));
                if tag == "Curve" {
                    let k = sign * inverse_radius(node, "radius", &label)?;
                    if k == 0.0 {
                        return Err(refuse("a curve needs a finite radius".into()));
                    }
                    (ElementKind::Arc, length, k, k, tangent)
                } else {
                    if let Some(kind) = node.attribute("spiType")
                        && kind != "clothoid"
                    {
                        return Err(refuse(format!(
                            "spiType \"{kind}\": only clothoids are read"
                        )));
                    }
                    let k0 = sign * inverse_radius(node, "radiusStart", &label)?;
                    let k1 = sign * inverse_radius(node, "radiusEnd", &label)?;
                    if k0 == k1 {
                        return Err(refuse(
                            "radiusStart equals radiusEnd: that is not a spiral".into(),
                        ));
                    }
                    (ElementKind::Spiral, length, k0, k1, tangent)
                }
            }
            other => return Err(refuse(format!("<{other}> is not a horizontal element"))),
        };
        if !(length_m.is_finite() && length_m > 0.0) {
            return Err(refuse(format!("length {length_m} is not positive")));
        }
        let start_pose = match pose {
            Some(previous) => {
                let gap = (start.0 - previous.easting_m).hypot(start.1 - previous.northing_m);
                if gap > POSITION_TOLERANCE_M {
                    return Err(refuse(format!(
                        "its <Start> is {gap:.4} m from where the element before it ends"
                    )));
                }
                if let Some(a) = declared_azimuth {
                    let kink = turn(previous.azimuth_rad, a).abs();
                    if kink > AZIMUTH_TOLERANCE_RAD {
                        return Err(refuse(format!(
                            "its start direction differs from where the element before it ends by {:.5}°",
                            kink.to_degrees()
                        )));
                    }
                }
                previous
            }
            None => Pose {
                easting_m: start.0,
                northing_m: start.1,
                azimuth_rad: declared_azimuth.ok_or_else(|| {
                    refuse(
                        "the first element needs a <PI> (or to be a <Line>) to give its direction"
                            .into(),
                    )
                })?,
            },
        };
        if let Some(declared) = attribute(node, "staStart", &label)?
            && (declared - station).abs() > POSITION_TOLERANCE_M
        {
            return Err(refuse(format!(
                "staStart {declared} but the elements before it end at station {station}"
            )));
        }
        let element = Element {
            kind,
            start: start_pose,
            start_station_m: station,
            length_m,
            curvature_start: k0,
            curvature_end: k1,
        };
        let computed = element.end();
        let miss = (end.0 - computed.easting_m).hypot(end.1 - computed.northing_m);
        if miss > POSITION_TOLERANCE_M {
            return Err(refuse(format!(
                "its <End> is {miss:.4} m from where its length, radii and rotation lead"
            )));
        }
        pose = Some(computed);
        station += length_m;
        elements.push(element);
    }
    if elements.is_empty() {
        return Err(AlignmentError::Empty.into());
    }
    Ok(elements)
}

/// "station elevation" text.
fn station_height(node: Node, element: &str) -> Result<(f64, f64), LandXmlError> {
    // Same two numbers as a point, in the order station, elevation.
    let (second, first) = point(node, "station elevation", element)?;
    Ok((first, second))
}

fn profile(alignment: Node, start_station: f64) -> Result<Profile, LandXmlError> {
    let prof_align = children(alignment, "Profile")
        .flat_map(|p| children(p, "ProfAlign"))
        .next()
        .ok_or_else(|| LandXmlError::Missing("<Alignment> has no <Profile>/<ProfAlign>".into()))?;
    let mut points = Vec::new();
    for (index, node) in prof_align.children().filter(Node::is_element).enumerate() {
        let tag = local(&node);
        let label = format!("<ProfAlign> element {index} (<{tag}>)");
        let (station_m, height_m) = station_height(node, &label)?;
        let curve_length_m = match tag {
            "PVI" => 0.0,
            "ParaCurve" | "CircCurve" => {
                attribute(node, "length", &label)?.ok_or_else(|| LandXmlError::Element {
                    element: label.clone(),
                    reason: "no length".into(),
                })?
            }
            other => {
                return Err(LandXmlError::Element {
                    element: label,
                    reason: format!("<{other}> is not a profile element"),
                });
            }
        };
        points.push(Pvi {
            station_m,
            height_m,
            curve_length_m,
        });
    }
    let (first, rest) = points
        .split_first()
        .ok_or_else(|| LandXmlError::Missing("<ProfAlign> has no points".into()))?;
    if (first.station_m - start_station).abs() > POSITION_TOLERANCE_M || first.curve_length_m > 0.0
    {
        return Err(LandXmlError::Element {
            element: "<ProfAlign> element 0".into(),
            reason: format!(
                "the profile must begin with a <PVI> at the alignment's start station {start_station}"
            ),
        });
    }
    let (last, middle) = rest.split_last().ok_or_else(|| {
        LandXmlError::Missing("<ProfAlign> needs a start and an end point".into())
    })?;
    let before_last = middle.last().unwrap_or(first);
    let end_grade =
        (last.height_m - before_last.height_m) / (last.station_m - before_last.station_m);
    Ok(Profile {
        start_station_m: first.station_m,
        start_height_m: first.height_m,
        pvis: middle.to_vec(),
        end_grade,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::alignment::AlignmentSpec;

    /// The S-1 drive as a design tool exports it; its points were computed
    /// apart from this code (the clothoid series, closed-form arcs).
    const S1_XML: &str = include_str!("../../../tests/fixtures/alignment/s1.xml");
    /// Its JSON twin.
    const S1_JSON: &str = include_str!("../../../tests/fixtures/alignment/s1.json");

    #[test]
    fn a_design_tool_export_imports_to_the_geometry_of_its_json_twin() {
        let xml = parse(S1_XML).unwrap();
        let json = serde_json::from_str::<AlignmentSpec>(S1_JSON)
            .unwrap()
            .build()
            .unwrap();
        assert_eq!(xml.name, "S-1 drive");
        assert_eq!(xml.elements.len(), json.elements.len());
        for (a, b) in xml.elements.iter().zip(&json.elements) {
            assert_eq!(a.kind, b.kind);
            assert!((a.start_station_m - b.start_station_m).abs() < 1e-9);
            assert!((a.length_m - b.length_m).abs() < 1e-9);
            assert!(
                (a.start.easting_m - b.start.easting_m).abs() < 1e-6,
                "{a:?} {b:?}"
            );
            assert!((a.start.northing_m - b.start.northing_m).abs() < 1e-6);
            assert!((a.start.azimuth_rad - b.start.azimuth_rad).abs() < 1e-9);
            assert!((a.curvature_start - b.curvature_start).abs() < 1e-12);
            assert!((a.curvature_end - b.curvature_end).abs() < 1e-12);
        }
        // The same deviations for points around the whole drive.
        for station in (0..=50).map(|i| f64::from(i) * 5.0) {
            let (pose, _) = json.axis_at(station).unwrap();
            for offset in [-4.0, 0.0, 3.0] {
                let e = pose.easting_m + offset * pose.azimuth_rad.cos();
                let n = pose.northing_m - offset * pose.azimuth_rad.sin();
                let (a, b) = (
                    xml.deviation(e, n, 50.0).unwrap(),
                    json.deviation(e, n, 50.0).unwrap(),
                );
                assert!((a.station_m - b.station_m).abs() < 1e-4, "{station}");
                assert!((a.horizontal_m - b.horizontal_m).abs() < 1e-4, "{station}");
                assert!((a.vertical_m - b.vertical_m).abs() < 1e-4, "{station}");
            }
        }
    }

    #[test]
    fn station_equations_are_read_and_the_stationing_follows_them() {
        // Re-chained at internal station 100: from there it reads 1100.
        let with = S1_XML.replacen(
            "<CoordGeom>",
            r#"<StaEquation staBack="100.000" staAhead="1100.000" staInternal="100.000" desc="re-chainage"/>
      <CoordGeom>"#,
            1,
        );
        let alignment = parse(&with).unwrap();
        assert_eq!(alignment.equations.len(), 1);
        assert_eq!(alignment.equations[0].station_back_m, Some(100.0));
        let (pose, _) = alignment.axis_at(130.0).unwrap();
        let d = alignment
            .deviation(pose.easting_m, pose.northing_m, 50.0)
            .unwrap();
        assert!((d.internal_station_m - 130.0).abs() < 1e-6, "{d:?}");
        assert!((d.station_m - 1130.0).abs() < 1e-6, "{d:?}");
        let before = alignment.axis_at(60.0).unwrap().0;
        let d = alignment
            .deviation(before.easting_m, before.northing_m, 50.0)
            .unwrap();
        assert!((d.station_m - 60.0).abs() < 1e-6, "{d:?}");
        // The JSON twin carries them.
        assert_eq!(
            alignment.to_spec().build().unwrap().equations,
            alignment.equations
        );

        let no_ahead = with.replacen(r#" staAhead="1100.000""#, "", 1);
        let err = parse(&no_ahead).unwrap_err().to_string();
        assert!(
            err.contains("<StaEquation> 0") && err.contains("staAhead"),
            "{err}"
        );
        let beyond = with.replacen(r#"staInternal="100.000""#, r#"staInternal="400.000""#, 1);
        let err = parse(&beyond).unwrap_err().to_string();
        assert!(
            err.contains("station equation 0") && err.contains("400"),
            "{err}"
        );
    }

    #[test]
    fn broken_files_are_refused_naming_the_element() {
        // A spiral mirrored (rot applied the wrong way): its End is far
        // from where it leads.
        let mirrored = S1_XML.replacen(
            r#"radiusStart="INF" radiusEnd="300.000000" rot="cw""#,
            r#"radiusStart="INF" radiusEnd="300.000000" rot="ccw""#,
            1,
        );
        let err = parse(&mirrored).unwrap_err().to_string();
        assert!(err.contains("element 1 (<Spiral> staStart 40"), "{err}");
        assert!(err.contains("<End>"), "{err}");
        // A radius that does not fit the points.
        let radius = S1_XML.replacen(r#"radius="300.000000""#, r#"radius="310.000000""#, 1);
        let err = parse(&radius).unwrap_err().to_string();
        assert!(err.contains("element 2 (<Curve>"), "{err}");
        // A gap of 5 cm before the last element.
        let start_of_last = S1_XML
            .split("<Line staStart=\"150.000000\"")
            .nth(1)
            .and_then(|rest| rest.split("<Start>").nth(1))
            .and_then(|rest| rest.split("</Start>").next())
            .unwrap()
            .to_string();
        let numbers: Vec<f64> = start_of_last
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect();
        let moved = format!("{:.10} {:.10}", numbers[0] + 0.05, numbers[1]);
        let err = parse(&S1_XML.replacen(
            &format!("<Start>{start_of_last}</Start>"),
            &format!("<Start>{moved}</Start>"),
            1,
        ))
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("element 4 (<Line> staStart 150") && err.contains("<Start>"),
            "{err}"
        );
        // INF as an arc radius, a non-clothoid, text that is not XML.
        let inf = S1_XML.replacen(r#"radius="300.000000""#, r#"radius="INF""#, 1);
        assert!(
            parse(&inf)
                .unwrap_err()
                .to_string()
                .contains("finite radius")
        );
        let cubic = S1_XML.replacen("spiType=\"clothoid\"", "spiType=\"cubic\"", 1);
        assert!(parse(&cubic).unwrap_err().to_string().contains("cubic"));
        assert!(matches!(parse("<LandXML"), Err(LandXmlError::Xml(_))));
        assert!(
            parse("<LandXML/>")
                .unwrap_err()
                .to_string()
                .contains("no <Alignment>")
        );
    }
}
