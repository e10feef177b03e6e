//! The report laid out for people: the summary lines, the tables with
//! their numbers formatted, and the deviation chart's geometry. The HTML
//! page (`templates/report.html`) and the PDF draw the same layout.

use crate::fusion::Integrity;
use askama::Template;
use chrono::{DateTime, Utc};

use super::contents::Report;
use crate::fusion::rings::BACKWARD_JUMP_M;

/// One table: its title, column headings and formatted rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    pub title: &'static str,
    pub headings: Vec<&'static str>,
    pub rows: Vec<Vec<String>>,
    /// Shown instead of an empty table.
    pub empty: &'static str,
}

/// The deviation chart: a panel per plane of the front's deviation
/// against station, each `WIDTH` × `HEIGHT` (y down, as SVG has it), with
/// the declared tolerances as bands and a line broken where the station
/// went back (a new drive) so none runs back in time.
#[derive(Debug, Clone, PartialEq)]
pub struct Chart {
    pub panels: Vec<Panel>,
    /// Gridlines along station: position and chainage.
    pub x_ticks: Vec<(f64, String)>,
    pub x_title: &'static str,
}

/// One plane's panel.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    /// The y axis's title.
    pub title: &'static str,
    /// Its line's colour, `#rrggbb`.
    pub colour: &'static str,
    pub segments: Vec<Vec<(f64, f64)>>,
    pub y_ticks: Vec<(f64, String)>,
    /// Tolerance bands, top and bottom y: within the warn limit (`ok`),
    /// between warn and alarm (`warn`).
    pub bands: Vec<Band>,
    /// The limit lines: y and label (`warn ±50`).
    pub limits: Vec<(f64, String)>,
}

/// A band of the panel between two y.
#[derive(Debug, Clone, PartialEq)]
pub struct Band {
    pub top: f64,
    pub bottom: f64,
    pub kind: &'static str,
}

impl Chart {
    pub const WIDTH: f64 = 720.0;
    pub const HEIGHT: f64 = 120.0;

    /// `points` as SVG's `points` attribute.
    pub fn svg_points(points: &[(f64, f64)]) -> String {
        points
            .iter()
            .map(|(x, y)| format!("{x:.1},{y:.1}"))
            .collect::<Vec<_>>()
            .join(" ")
    }
}

/// The printable report page.
#[derive(Template)]
#[template(path = "report.html")]
pub struct ReportPage {
    pub title: String,
    /// Machine, range.
    pub subtitle: String,
    /// The header block: project, machine, shift, range, generated at.
    pub header: Vec<(&'static str, String)>,
    /// Label and value.
    pub summary: Vec<(&'static str, String)>,
    pub chart: Option<Chart>,
    pub tables: Vec<Table>,
    /// The lines to sign: who.
    pub signatures: Vec<&'static str>,
}

/// A station as chainage, as the dashboard writes it (static/common.js's
/// `chainage`, the same rounding to whole millimetres): kilometres + metres
/// (1234.5 → `1+234.500`, −3 → `−0+003.000`).
pub fn chainage(station_m: f64) -> String {
    if !station_m.is_finite() {
        return "—".to_string();
    }
    let mm = (station_m.abs() * 1000.0).round() as u64;
    // No sign on what rounds to nothing.
    let sign = if station_m < 0.0 && mm > 0 {
        "\u{2212}"
    } else {
        ""
    };
    format!(
        "{sign}{}+{:03}.{:03}",
        mm / 1_000_000,
        mm / 1000 % 1000,
        mm % 1000
    )
}

pub fn chainage_of(value: Option<f64>) -> String {
    value.map_or_else(|| "—".to_string(), chainage)
}

/// UTC, to the second.
pub fn time(t: f64) -> String {
    DateTime::<Utc>::from_timestamp(t.floor() as i64, 0)
        .map(|d| d.format("%Y-%m-%d %H:%M:%S").to_string())
        .unwrap_or_else(|| format!("{t}"))
}

/// `ok`, or the level and its reason (`lost: tilt_disagrees`).
fn integrity(integrity: Integrity) -> String {
    match integrity.reason {
        Some(reason) if !integrity.is_ok() => {
            format!("{}: {}", integrity.level.as_str(), reason.as_str())
        }
        _ => integrity.level.as_str().to_string(),
    }
}

fn fixed(value: Option<f64>, decimals: usize) -> String {
    value.map_or_else(|| "—".to_string(), |v| format!("{v:.decimals$}"))
}

/// A duration as h:mm:ss.
fn duration(seconds: Option<f64>) -> String {
    match seconds {
        Some(s) if s.is_finite() && s >= 0.0 => {
            let s = s.round() as u64;
            format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
        }
        _ => "—".to_string(),
    }
}

impl ReportPage {
    /// The layout of `report`.
    pub fn new(report: &Report) -> ReportPage {
        let a = &report.advance;
        let ring_numbers = if a.ring_numbers.is_empty() {
            "—".to_string()
        } else {
            a.ring_numbers
                .iter()
                .map(|r| match r.first == r.last {
                    true => r.first.to_string(),
                    false => format!("{} to {}", r.first, r.last),
                })
                .collect::<Vec<_>>()
                .join(", then ")
        };
        let stretches = a
            .stretches
            .iter()
            .map(|s| {
                format!(
                    "{} to {}",
                    chainage(s.from_station_m),
                    chainage(s.to_station_m)
                )
            })
            .collect::<Vec<_>>()
            .join(", then ");
        let advance = match (a.advance_m, a.advance_from) {
            (Some(m), Some("rings")) => {
                let known = report
                    .rings
                    .iter()
                    .filter(|r| r.ring.advance_m.is_some_and(|a| a > -BACKWARD_JUMP_M))
                    .count();
                format!(
                    "{m:.3} m over {known} of {} rings with a known advance (stations {stretches})",
                    a.rings
                )
            }
            (Some(m), _) => format!("{m:.3} m (stations {stretches})"),
            (None, _) => "— (no position in the range)".to_string(),
        };
        let mut summary = vec![
            ("Rings completed", a.rings.to_string()),
            ("Ring numbers", ring_numbers),
            ("Advance", advance),
        ];
        if a.pushes > 0 {
            summary.push(("Pushes", format!("{} ({:.3} m)", a.pushes, a.pushed_m)));
        }
        summary.push(("Alarms", report.alarms.len().to_string()));
        summary.push((
            "Laser dropouts",
            match &report.laser_dropouts {
                Some(d) => format!(
                    "{} ({} in all)",
                    d.len(),
                    duration(Some(d.iter().map(|d| d.duration_s).sum()))
                ),
                None => "no laser fused".to_string(),
            },
        ));
        let deviations = Table {
            title: "Largest deviations",
            headings: vec!["point", "plane", "deviation mm", "time (UTC)", "chainage"],
            rows: report
                .deviations
                .iter()
                .map(|d| {
                    vec![
                        d.point.to_string(),
                        d.plane.to_string(),
                        format!("{:+.1}", d.deviation_mm),
                        time(d.t),
                        chainage(d.station_m),
                    ]
                })
                .collect(),
            empty: "No deviation from the axis in the range (no alignment, or no position).",
        };
        let rings = ring_table("Ring log", &report.rings, false);
        let pushes = Table {
            title: "Jacking log",
            headings: vec![
                "push",
                "ended (UTC)",
                "duration",
                "length m",
                "speed mm/s",
                "course °",
                "grade %",
                "integrity",
            ],
            rows: report
                .pushes
                .iter()
                .map(|p| {
                    let q = &p.push;
                    vec![
                        q.push.to_string(),
                        time(q.end_t),
                        duration(Some(q.duration_s)),
                        format!("{:.3}", q.length_m),
                        format!("{:.1}", q.speed_mm_per_s),
                        fixed(q.course_deg, 2),
                        fixed(q.grade_pct, 2),
                        integrity(p.integrity),
                    ]
                })
                .collect(),
            empty: "No push in the range.",
        };
        let alarms = Table {
            title: "Alarms",
            headings: vec![
                "raised (UTC)",
                "cleared (UTC)",
                "kind",
                "severity",
                "acknowledged (UTC)",
                "by",
                "message",
            ],
            rows: report
                .alarms
                .iter()
                .map(|a| {
                    vec![
                        time(a.raised_t),
                        a.cleared_t.map_or_else(|| "active".to_string(), time),
                        if a.subject.is_empty() {
                            a.kind.clone()
                        } else {
                            format!("{} ({})", a.kind, a.subject)
                        },
                        a.severity.clone(),
                        a.acked_t.map_or_else(|| "—".to_string(), time),
                        a.acked_by.clone().unwrap_or_else(|| "—".to_string()),
                        a.message.clone(),
                    ]
                })
                .collect(),
            empty: "No alarm in the range.",
        };
        let dropouts = Table {
            title: "Laser dropouts",
            headings: vec!["from (UTC)", "to (UTC)", "duration"],
            rows: report
                .laser_dropouts
                .iter()
                .flatten()
                .map(|d| vec![time(d.from_t), time(d.to_t), duration(Some(d.duration_s))])
                .collect(),
            empty: "No laser dropout in the range.",
        };
        let mut tables = vec![deviations, rings];
        if !report.pushes.is_empty() {
            tables.push(pushes);
        }
        tables.push(alarms);
        if report.laser_dropouts.is_some() {
            tables.push(dropouts);
        }
        ReportPage {
            title: format!("Shift report: {}", report.name),
            subtitle: format!(
                "machine {}, {} to {} UTC",
                report.machine,
                time(report.from),
                time(report.to)
            ),
            header: vec![
                (
                    "Project",
                    report.project.clone().unwrap_or_else(|| "—".to_string()),
                ),
                ("Machine", format!("{} ({})", report.name, report.machine)),
                (
                    "Shift",
                    format!("{} to {} UTC", time(report.from), time(report.to)),
                ),
                ("Range", duration(Some(report.to - report.from))),
                ("Generated at", format!("{} UTC", time(report.generated_t))),
            ],
            summary,
            chart: chart(&report.chart, report.tolerances),
            tables,
            signatures: vec!["Operator", "Shift engineer (checked)"],
        }
    }
}

/// The ring log as a table (`strokes`: with each ring's strokes).
pub fn ring_table(title: &'static str, rings: &[super::contents::RingRow], strokes: bool) -> Table {
    let mut headings = vec![
        "ring",
        "completed (UTC)",
        "duration",
        "chainage",
        "advance m",
        "front H mm",
        "front V mm",
        "rear H mm",
        "rear V mm",
        "tend. H mm/m",
        "tend. V mm/m",
        "pitch °",
        "roll °",
        "integrity",
    ];
    if strokes {
        headings.push("strokes mm");
    }
    Table {
        title,
        headings,
        rows: rings
            .iter()
            .map(|r| {
                let g = &r.ring;
                let mut row = vec![
                    g.ring.to_string(),
                    time(r.t),
                    duration(g.duration_s),
                    chainage_of(g.station_m),
                    fixed(g.advance_m, 3),
                    fixed(g.front_horizontal_mm, 1),
                    fixed(g.front_vertical_mm, 1),
                    fixed(g.rear_horizontal_mm, 1),
                    fixed(g.rear_vertical_mm, 1),
                    fixed(g.tendency_horizontal_mm_per_m, 2),
                    fixed(g.tendency_vertical_mm_per_m, 2),
                    fixed(g.pitch_deg, 3),
                    fixed(g.roll_deg, 3),
                    integrity(r.integrity),
                ];
                if strokes {
                    row.push(g.strokes_mm.as_ref().map_or_else(
                        || "—".to_string(),
                        |s| {
                            s.iter()
                                .map(|v| format!("{v:.1}"))
                                .collect::<Vec<_>>()
                                .join(" ")
                        },
                    ));
                }
                row
            })
            .collect(),
        empty: "No ring completed in the range.",
    }
}

/// Round steps (1, 2, 5 × 10ⁿ) of at least `span / most` between
/// gridlines.
fn step(span: f64, most: f64) -> f64 {
    let raw = (span / most).max(1e-9);
    let decade = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * decade)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * decade)
}

/// Decimals that show a multiple of `step` exactly (0.2 → 1, 5 → 0).
fn decimals(step: f64) -> usize {
    (-step.log10().floor()).max(0.0) as usize
}

/// The chart of `points` with the `tolerances`' bands; `None` without
/// two points.
pub fn chart(
    points: &[super::contents::ChartPoint],
    tolerances: Option<crate::fusion::declaration::Tolerances>,
) -> Option<Chart> {
    if points.len() < 2 {
        return None;
    }
    let (mut x0, mut x1) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in points {
        x0 = x0.min(p.station_m);
        x1 = x1.max(p.station_m);
    }
    if x1 - x0 < 1.0 {
        x1 = x0 + 1.0;
    }
    let x = |station_m: f64| (station_m - x0) / (x1 - x0) * Chart::WIDTH;
    let x_step = step(x1 - x0, 8.0);
    let x_ticks = (((x0 / x_step).ceil() as i64)..=((x1 / x_step).floor() as i64))
        .map(|k| {
            let tick = k as f64 * x_step;
            (x(tick), chainage(tick))
        })
        .collect();
    let limits = tolerances.map(|t| (t.horizontal_mm, t.vertical_mm));
    let panel = |title,
                 colour,
                 value: &dyn Fn(&super::contents::ChartPoint) -> f64,
                 limit: Option<crate::fusion::declaration::Limits>| {
        // Room for the data and the alarm limit.
        let mut extent = points.iter().fold(10.0_f64, |m, p| m.max(value(p).abs()));
        if let Some(l) = limit {
            extent = extent.max(l.alarm * 1.1);
        }
        let y_step = step(2.0 * extent, 6.0);
        let extent = (extent / y_step).ceil() * y_step;
        let y = |mm: f64| (extent - mm) / (2.0 * extent) * Chart::HEIGHT;
        // A new segment wherever the station went back.
        let mut segments: Vec<Vec<(f64, f64)>> = Vec::new();
        let mut previous: Option<f64> = None;
        for p in points {
            let back = previous.is_some_and(|s| p.station_m < s - BACKWARD_JUMP_M);
            if back || segments.is_empty() {
                segments.push(Vec::new());
            }
            if let Some(segment) = segments.last_mut() {
                segment.push((x(p.station_m), y(value(p))));
            }
            previous = Some(p.station_m);
        }
        let n = (extent / y_step).round() as i64;
        let y_ticks = (-n..=n)
            .map(|k| {
                let tick = k as f64 * y_step;
                let label = match k {
                    0 => "0".to_string(),
                    _ => format!("{tick:+.*}", decimals(y_step)),
                };
                (y(tick), label)
            })
            .collect();
        let (bands, limit_lines) = match limit {
            Some(l) => (
                vec![
                    Band {
                        top: y(l.warn),
                        bottom: y(-l.warn),
                        kind: "ok",
                    },
                    Band {
                        top: y(l.alarm),
                        bottom: y(l.warn),
                        kind: "warn",
                    },
                    Band {
                        top: y(-l.warn),
                        bottom: y(-l.alarm),
                        kind: "warn",
                    },
                ],
                vec![
                    (y(l.warn), format!("warn ±{}", l.warn)),
                    (y(l.alarm), format!("alarm ±{}", l.alarm)),
                    (y(-l.warn), String::new()),
                    (y(-l.alarm), String::new()),
                ],
            ),
            None => (Vec::new(), Vec::new()),
        };
        Panel {
            title,
            colour,
            segments,
            y_ticks,
            bands,
            limits: limit_lines,
        }
    };
    Some(Chart {
        panels: vec![
            panel(
                "horizontal deviation of the front, mm (+ right)",
                "#1f77b4",
                &|p| p.horizontal_mm,
                limits.map(|l| l.0),
            ),
            panel(
                "vertical deviation of the front, mm (+ up)",
                "#d62728",
                &|p| p.vertical_mm,
                limits.map(|l| l.1),
            ),
        ],
        x_ticks,
        x_title: "chainage, km+m",
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gridline_steps_are_round() {
        assert_eq!(step(100.0, 8.0), 20.0);
        assert_eq!(step(7.0, 8.0), 1.0);
        assert_eq!(step(30.0, 6.0), 5.0);
        assert_eq!(step(0.3, 6.0), 0.05);
        assert_eq!((decimals(0.2), decimals(0.05), decimals(5.0)), (1, 2, 0));
    }

    #[test]
    fn stations_read_as_chainage_as_on_the_dashboard() {
        assert_eq!(chainage(1234.5), "1+234.500");
        assert_eq!(chainage(7.0925), "0+007.093");
        assert_eq!(chainage(-3.0), "\u{2212}0+003.000");
        assert_eq!(chainage(999.9996), "1+000.000");
        assert_eq!(chainage(f64::NAN), "—");
        // As static/common.js writes them (node, the same IEEE doubles).
        assert_eq!(chainage(1.0005), "0+001.001");
        assert_eq!(chainage(12.3455), "0+012.346");
        assert_eq!(chainage(1000.0005), "1+000.001");
        assert_eq!(chainage(-0.0004), "0+000.000");
    }

    #[test]
    fn durations_and_times_read_as_a_shift_log_does() {
        assert_eq!(duration(Some(3725.4)), "1:02:05");
        assert_eq!(duration(None), "—");
        assert_eq!(time(1_772_431_200.9), "2026-03-02 06:00:00");
    }
}
