//! The report laid out for people: the summary lines, the tables with
//! their numbers formatted, and the deviation chart's geometry. The HTML
//! page (`templates/report.html`) and the PDF draw the same layout.

use crate::fusion::Integrity;
use askama::Template;
use chrono::{DateTime, Utc};

use super::Report;

/// One table: its title, column headings and formatted rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    pub title: &'static str,
    pub headings: Vec<&'static str>,
    pub rows: Vec<Vec<String>>,
    /// Shown instead of an empty table.
    pub empty: &'static str,
}

/// The deviation chart: the front's horizontal and vertical deviation
/// against station, in a `WIDTH` × `HEIGHT` box (y down, as SVG has it).
#[derive(Debug, Clone, PartialEq)]
pub struct Chart {
    pub horizontal: Vec<(f64, f64)>,
    pub vertical: Vec<(f64, f64)>,
    /// Gridlines: position and label.
    pub x_ticks: Vec<(f64, String)>,
    pub y_ticks: Vec<(f64, String)>,
}

impl Chart {
    pub const WIDTH: f64 = 720.0;
    pub const HEIGHT: f64 = 200.0;

    /// `points` as SVG's `points` attribute.
    pub fn svg_points(points: &[(f64, f64)]) -> String {
        points
            .iter()
            .map(|(x, y)| format!("{x:.1},{y:.1}"))
            .collect::<Vec<_>>()
            .join(" ")
    }

    pub fn horizontal_points(&self) -> String {
        Chart::svg_points(&self.horizontal)
    }

    pub fn vertical_points(&self) -> String {
        Chart::svg_points(&self.vertical)
    }
}

/// The printable report page.
#[derive(Template)]
#[template(path = "report.html")]
pub struct ReportPage {
    pub title: String,
    /// Machine, range.
    pub subtitle: String,
    /// Label and value.
    pub summary: Vec<(&'static str, String)>,
    pub chart: Option<Chart>,
    pub tables: Vec<Table>,
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
        let mut summary = vec![
            ("Rings completed", a.rings.to_string()),
            (
                "Ring numbers",
                match (a.first_ring, a.last_ring) {
                    (Some(first), Some(last)) => format!("{first} to {last}"),
                    _ => "—".to_string(),
                },
            ),
            (
                "Advance",
                format!(
                    "{} m (station {} m to {} m)",
                    fixed(a.advance_m, 3),
                    fixed(a.start_station_m, 3),
                    fixed(a.end_station_m, 3)
                ),
            ),
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
            headings: vec!["point", "plane", "deviation mm", "time (UTC)", "station m"],
            rows: report
                .deviations
                .iter()
                .map(|d| {
                    vec![
                        d.point.to_string(),
                        d.plane.to_string(),
                        format!("{:+.1}", d.deviation_mm),
                        time(d.t),
                        format!("{:.3}", d.station_m),
                    ]
                })
                .collect(),
            empty: "No deviation from the axis in the range (no alignment, or no position).",
        };
        let rings = Table {
            title: "Ring log",
            headings: vec![
                "ring",
                "completed (UTC)",
                "duration",
                "station m",
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
            ],
            rows: report
                .rings
                .iter()
                .map(|r| {
                    let g = &r.ring;
                    vec![
                        g.ring.to_string(),
                        time(r.t),
                        duration(g.duration_s),
                        fixed(g.station_m, 3),
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
                    ]
                })
                .collect(),
            empty: "No ring completed in the range.",
        };
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
            summary,
            chart: chart(report),
            tables,
        }
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

/// The chart of the report's points; `None` without two.
fn chart(report: &Report) -> Option<Chart> {
    let points = &report.chart;
    if points.len() < 2 {
        return None;
    }
    let (mut x0, mut x1) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut y_extent = 10.0_f64;
    for p in points {
        x0 = x0.min(p.station_m);
        x1 = x1.max(p.station_m);
        y_extent = y_extent.max(p.horizontal_mm.abs()).max(p.vertical_mm.abs());
    }
    if x1 - x0 < 1.0 {
        x1 = x0 + 1.0;
    }
    let y_step = step(2.0 * y_extent, 6.0);
    let y_extent = (y_extent / y_step).ceil() * y_step;
    let x = |station_m: f64| (station_m - x0) / (x1 - x0) * Chart::WIDTH;
    let y = |mm: f64| (y_extent - mm) / (2.0 * y_extent) * Chart::HEIGHT;
    let line = |value: &dyn Fn(&super::ChartPoint) -> f64| {
        points
            .iter()
            .map(|p| (x(p.station_m), y(value(p))))
            .collect()
    };
    let x_step = step(x1 - x0, 8.0);
    let x_ticks = (((x0 / x_step).ceil() as i64)..=((x1 / x_step).floor() as i64))
        .map(|k| {
            let tick = k as f64 * x_step;
            (x(tick), format!("{tick:.*}", decimals(x_step)))
        })
        .collect();
    let n = (y_extent / y_step).round() as i64;
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
    Some(Chart {
        horizontal: line(&|p| p.horizontal_mm),
        vertical: line(&|p| p.vertical_mm),
        x_ticks,
        y_ticks,
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
    fn durations_and_times_read_as_a_shift_log_does() {
        assert_eq!(duration(Some(3725.4)), "1:02:05");
        assert_eq!(duration(None), "—");
        assert_eq!(time(1_772_431_200.9), "2026-03-02 06:00:00");
    }
}
