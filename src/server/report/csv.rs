//! The report as CSV, for spreadsheets: one table per section, each row's
//! first cell naming its table (`advance`, `ring_run`, `stretch`,
//! `deviation`, `ring`, `chart`, …), the first row of each its column
//! names. Every value is the JSON report's own, written as the JSON writes
//! it (so the CSV equals the API); the advance's lists are tables of their
//! own, the tolerances are the machine's declaration.

use serde_json::Value;

use super::contents::Report;

/// The sections: the table name, the report's field, and whether it is a
/// list of rows (else one object).
const SECTIONS: [(&str, &str, bool); 10] = [
    ("report", "", false),
    ("advance", "advance", false),
    ("ring_run", "ring_numbers", true),
    ("stretch", "stretches", true),
    ("deviation", "deviations", true),
    ("ring", "rings", true),
    ("push", "pushes", true),
    ("alarm", "alarms", true),
    ("laser_dropout", "laser_dropouts", true),
    ("chart", "chart", true),
];

/// The CSV text of `report`.
pub fn write(report: &Report) -> String {
    // Plain structs of numbers and strings: serialising cannot fail.
    let value = serde_json::to_value(report).unwrap_or(Value::Null);
    let mut out = String::new();
    for (table, field, is_list) in SECTIONS {
        // The advance's own lists have tables of their own.
        let list = match table {
            "ring_run" | "stretch" => &value["advance"][field],
            _ => &value[field],
        };
        let rows: Vec<&Value> = match (field, is_list) {
            ("", _) => vec![&value],
            (_, false) => vec![&value[field]],
            (_, true) => list
                .as_array()
                .map(|rows| rows.iter().collect())
                .unwrap_or_default(),
        };
        let columns = columns(table);
        line(&mut out, table, columns.iter().map(|c| c.to_string()));
        for row in rows {
            line(&mut out, table, columns.iter().map(|c| cell(row.get(*c))));
        }
    }
    out
}

/// One table of `rows` (JSON objects) under its columns.
pub(super) fn table(table: &str, rows: &[Value]) -> String {
    let mut out = String::new();
    let columns = columns(table);
    line(&mut out, table, columns.iter().map(|c| c.to_string()));
    for row in rows {
        line(&mut out, table, columns.iter().map(|c| cell(row.get(*c))));
    }
    out
}

/// A table's columns in the order its struct declares its fields (the
/// JSON object's keys are sorted; an empty list has no object to ask).
/// The HTTP test checks them against the JSON's keys.
fn columns(table: &str) -> &'static [&'static str] {
    match table {
        "report" => &["machine", "name", "from", "to", "project", "generated_t"],
        "advance" => &[
            "rings",
            "first_ring",
            "last_ring",
            "start_station_m",
            "end_station_m",
            "advance_m",
            "pushes",
            "pushed_m",
            "advance_from",
        ],
        "ring_run" => &["first", "last"],
        "stretch" => &["from_t", "to_t", "from_station_m", "to_station_m"],
        "deviation" => &["point", "plane", "deviation_mm", "t", "station_m"],
        "ring" => &[
            "ring",
            "t",
            "start_t",
            "duration_s",
            "station_m",
            "advance_m",
            "front_horizontal_mm",
            "front_vertical_mm",
            "rear_horizontal_mm",
            "rear_vertical_mm",
            "tendency_horizontal_mm_per_m",
            "tendency_vertical_mm_per_m",
            "dta_t",
            "pitch_deg",
            "roll_deg",
            "strokes_mm",
            "integrity",
            "integrity_reason",
        ],
        "push" => &[
            "push",
            "t",
            "start_t",
            "end_t",
            "duration_s",
            "length_m",
            "speed_mm_per_s",
            "course_deg",
            "grade_pct",
            "end_position_m",
            "end_position_sigma_m",
            "integrity",
            "integrity_reason",
        ],
        "alarm" => &[
            "id",
            "machine",
            "kind",
            "severity",
            "subject",
            "raised_t",
            "cleared_t",
            "acked_t",
            "acked_by",
            "message",
        ],
        "laser_dropout" => &["from_t", "to_t", "duration_s"],
        "chart" => &["t", "station_m", "horizontal_mm", "vertical_mm"],
        _ => &[],
    }
}

fn line(out: &mut String, table: &str, cells: impl Iterator<Item = String>) {
    out.push_str(table);
    for cell in cells {
        out.push(',');
        out.push_str(&cell);
    }
    out.push('\n');
}

/// Numbers as the JSON has them, nothing for null, text quoted where it
/// must be (quotes doubled) and never read as a formula
/// ([`crate::server::csv_text`]), lists as their numbers separated by
/// spaces.
fn cell(value: Option<&Value>) -> String {
    match value {
        None | Some(Value::Null) => String::new(),
        Some(Value::Number(n)) => n.to_string(),
        Some(Value::Bool(b)) => b.to_string(),
        Some(Value::String(s)) => crate::server::csv_text::text_cell(s, false),
        // A list is text, not a number: "-1.2 3.4" is neutralised too.
        Some(Value::Array(items)) => {
            let joined = items
                .iter()
                .map(|item| cell(Some(item)))
                .collect::<Vec<_>>()
                .join(" ");
            match crate::server::csv_text::could_be_formula(&joined) {
                true => crate::server::csv_text::text_cell(&joined, false),
                false => joined,
            }
        }
        Some(other) => format!("\"{}\"", other.to_string().replace('"', "\"\"")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_written_as_the_json_has_them() {
        let json: Value = serde_json::from_str(
            r#"{"a": 0.1, "b": null, "c": "x, \"y\"", "d": [1.5, 2], "e": 1e-7, "f": "plain"}"#,
        )
        .unwrap();
        let cells: Vec<String> = ["a", "b", "c", "d", "e", "f", "g"]
            .iter()
            .map(|k| cell(json.get(k)))
            .collect();
        assert_eq!(
            cells,
            ["0.1", "", "\"x, \"\"y\"\"\"", "1.5 2", "1e-7", "plain", ""]
        );
    }
}
