//! The report as a PDF (krilla: Typst's PDF writer, maintained, with
//! fonts embedded and subset and their text extractable). A4 landscape,
//! DejaVu Sans Mono throughout (`assets/fonts`, its licence beside it):
//! one font whose every glyph has the same advance lays the tables out in
//! columns without measuring text. The pages are first placed as
//! [`Mark`]s, then drawn.

use krilla::Document;
use krilla::color::rgb;
use krilla::geom::{PathBuilder, Point};
use krilla::page::PageSettings;
use krilla::paint::{Fill, LineCap, LineJoin, Stroke};
use krilla::text::{Font, TextDirection};

use super::layout::{Chart, ReportPage, Table};

static FONT: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSansMono.ttf");

/// A4 landscape, points.
const PAGE_W: f32 = 842.0;
const PAGE_H: f32 = 595.0;
const MARGIN: f32 = 36.0;
/// DejaVu Sans Mono's advance: 1233/2048 of the size.
const ADVANCE: f32 = 1233.0 / 2048.0;
const TABLE_SIZE: f32 = 7.5;
const TEXT_SIZE: f32 = 9.5;

/// Why no PDF was made.
#[derive(Debug, thiserror::Error)]
pub enum PdfError {
    #[error("the embedded font does not load")]
    Font,
    #[error("krilla: {0:?}")]
    Krilla(krilla::error::KrillaError),
}

/// Something placed on a page (y down from the top, as krilla has it).
#[derive(Debug, Clone, PartialEq)]
enum Mark {
    /// Text from its baseline's left end.
    Text {
        x: f32,
        y: f32,
        size: f32,
        colour: (u8, u8, u8),
        text: String,
    },
    /// A polyline.
    Line {
        points: Vec<(f32, f32)>,
        width: f32,
        colour: (u8, u8, u8),
    },
}

const BLACK: (u8, u8, u8) = (0, 0, 0);
const GREY: (u8, u8, u8) = (110, 110, 110);
const GRID: (u8, u8, u8) = (215, 215, 215);
const HORIZONTAL: (u8, u8, u8) = (31, 119, 180);
const VERTICAL: (u8, u8, u8) = (214, 39, 40);

/// Pages of marks, and where the next line goes.
struct Pages {
    pages: Vec<Vec<Mark>>,
    y: f32,
}

impl Pages {
    fn new() -> Pages {
        Pages {
            pages: vec![Vec::new()],
            y: MARGIN,
        }
    }

    /// Room for `height` more on this page, or a new page.
    fn room(&mut self, height: f32) {
        if self.y + height > PAGE_H - MARGIN {
            self.pages.push(Vec::new());
            self.y = MARGIN;
        }
    }

    fn mark(&mut self, mark: Mark) {
        if let Some(page) = self.pages.last_mut() {
            page.push(mark);
        }
    }

    /// A line of text at the left margin.
    fn line(&mut self, size: f32, colour: (u8, u8, u8), text: String) {
        let height = size * 1.45;
        self.room(height);
        self.y += height;
        self.mark(Mark::Text {
            x: MARGIN,
            y: self.y,
            size,
            colour,
            text,
        });
    }
}

/// Characters that fit across the page at `size`.
fn columns_across(size: f32) -> usize {
    ((PAGE_W - 2.0 * MARGIN) / (size * ADVANCE)).floor() as usize
}

/// The table's lines: headings and rows in columns as wide as their
/// widest cell; a last cell too long for the page (an alarm's message)
/// goes on over continuation lines under its column.
fn table_lines(table: &Table, across: usize) -> Vec<String> {
    let mut widths: Vec<usize> = table.headings.iter().map(|h| h.chars().count()).collect();
    for row in &table.rows {
        for (width, cell) in widths.iter_mut().zip(row) {
            *width = (*width).max(cell.chars().count());
        }
    }
    // Where the last column starts, and what is left of the line for it.
    let count = widths.len();
    let indent: usize = widths[..count.saturating_sub(1)]
        .iter()
        .map(|w| w + 2)
        .sum();
    let room = across.saturating_sub(indent).max(MIN_LAST_COLUMN);
    let mut lines = Vec::new();
    for cells in std::iter::once(table.headings.clone()).chain(
        table
            .rows
            .iter()
            .map(|row| row.iter().map(String::as_str).collect()),
    ) {
        let mut line = String::new();
        for (i, (cell, width)) in cells.iter().zip(&widths).enumerate().take(count - 1) {
            if i > 0 {
                line.push_str("  ");
            }
            line.push_str(cell);
            line.extend(std::iter::repeat_n(' ', width - cell.chars().count()));
        }
        if count > 1 {
            line.push_str("  ");
        }
        let mut pieces = wrap(cells.get(count - 1).copied().unwrap_or(""), room).into_iter();
        line.push_str(&pieces.next().unwrap_or_default());
        lines.push(line);
        for piece in pieces {
            lines.push(format!("{:indent$}{piece}", ""));
        }
    }
    lines
}

/// `text` in lines of at most `room` characters, broken between words
/// (a number stays whole), a word longer than a line cut.
fn wrap(text: &str, room: usize) -> Vec<String> {
    let mut lines = vec![String::new()];
    for word in text.split(' ') {
        let mut word: Vec<char> = word.chars().collect();
        loop {
            let line = lines.last_mut().expect("one line at least");
            let used = line.chars().count();
            let gap = usize::from(used > 0);
            if used + gap + word.len() <= room {
                if gap > 0 {
                    line.push(' ');
                }
                line.extend(word.iter());
                break;
            }
            if used == 0 {
                // Longer than a line: cut.
                line.extend(word.drain(..room));
                lines.push(String::new());
                continue;
            }
            lines.push(String::new());
        }
    }
    lines
}

/// The narrowest the last column is made, characters.
const MIN_LAST_COLUMN: usize = 20;

/// The chart at the current line, scaled from its layout box.
fn chart(pages: &mut Pages, chart: &Chart) {
    let label_w = 7.0 * TABLE_SIZE * ADVANCE;
    let width = (PAGE_W - 2.0 * MARGIN - label_w) as f64;
    let height = 170.0_f64;
    pages.room(height as f32 + 40.0);
    let (left, top) = (MARGIN + label_w, pages.y + 12.0);
    let sx = width / Chart::WIDTH;
    let sy = height / Chart::HEIGHT;
    let at = |(x, y): (f64, f64)| (left + (x * sx) as f32, top + (y * sy) as f32);
    for (y, label) in &chart.y_ticks {
        let (_, py) = at((0.0, *y));
        pages.mark(Mark::Line {
            points: vec![(left, py), (left + width as f32, py)],
            width: 0.5,
            colour: GRID,
        });
        pages.mark(Mark::Text {
            x: MARGIN,
            y: py + TABLE_SIZE * 0.35,
            size: TABLE_SIZE,
            colour: GREY,
            text: label.clone(),
        });
    }
    for (x, label) in &chart.x_ticks {
        let (px, _) = at((*x, 0.0));
        pages.mark(Mark::Line {
            points: vec![(px, top), (px, top + height as f32)],
            width: 0.5,
            colour: GRID,
        });
        pages.mark(Mark::Text {
            x: px - label.len() as f32 * TABLE_SIZE * ADVANCE / 2.0,
            y: top + height as f32 + TABLE_SIZE * 1.4,
            size: TABLE_SIZE,
            colour: GREY,
            text: label.clone(),
        });
    }
    for (points, colour) in [(&chart.horizontal, HORIZONTAL), (&chart.vertical, VERTICAL)] {
        pages.mark(Mark::Line {
            points: points.iter().map(|p| at(*p)).collect(),
            width: 1.2,
            colour,
        });
    }
    pages.y = top + height as f32 + TABLE_SIZE * 1.6;
    pages.line(
        TABLE_SIZE,
        GREY,
        "front deviation, mm, against station, m:  horizontal (blue, + right)  vertical (red, + up)"
            .into(),
    );
}

/// Places the report's layout on pages.
fn place(page: &ReportPage) -> Vec<Vec<Mark>> {
    let mut pages = Pages::new();
    pages.line(16.0, BLACK, page.title.clone());
    pages.line(TEXT_SIZE, GREY, page.subtitle.clone());
    pages.y += 6.0;
    let label_w = page.summary.iter().map(|(l, _)| l.len()).max().unwrap_or(0);
    for (label, value) in &page.summary {
        pages.line(TEXT_SIZE, BLACK, format!("{label:<label_w$}  {value}"));
    }
    if let Some(c) = &page.chart {
        pages.y += 6.0;
        pages.line(11.0, BLACK, "Deviation of the front".into());
        chart(&mut pages, c);
    }
    let across = columns_across(TABLE_SIZE);
    for table in &page.tables {
        pages.y += 8.0;
        pages.room(11.0 * 1.45 + 3.0 * TABLE_SIZE * 1.45);
        pages.line(11.0, BLACK, table.title.into());
        if table.rows.is_empty() {
            pages.line(TABLE_SIZE, GREY, table.empty.into());
            continue;
        }
        for (i, line) in table_lines(table, across).into_iter().enumerate() {
            pages.line(TABLE_SIZE, if i == 0 { GREY } else { BLACK }, line);
        }
    }
    pages.pages
}

/// The PDF of the report's layout.
pub fn write(page: &ReportPage) -> Result<Vec<u8>, PdfError> {
    let font = Font::new(FONT.into(), 0).ok_or(PdfError::Font)?;
    let mut document = Document::new();
    let settings = PageSettings::from_wh(PAGE_W, PAGE_H).ok_or(PdfError::Font)?;
    let placed = place(page);
    let count = placed.len();
    for (number, marks) in placed.into_iter().enumerate() {
        let mut pdf_page = document.start_page_with(settings.clone());
        let mut surface = pdf_page.surface();
        let mut footer = marks;
        footer.push(Mark::Text {
            x: PAGE_W - MARGIN - 12.0 * TABLE_SIZE * ADVANCE,
            y: PAGE_H - MARGIN / 2.0,
            size: TABLE_SIZE,
            colour: GREY,
            text: format!("page {} of {count}", number + 1),
        });
        for mark in footer {
            match mark {
                Mark::Text {
                    x,
                    y,
                    size,
                    colour,
                    text,
                } => {
                    surface.set_stroke(None);
                    surface.set_fill(Some(Fill {
                        paint: rgb::Color::new(colour.0, colour.1, colour.2).into(),
                        ..Default::default()
                    }));
                    surface.draw_text(
                        Point::from_xy(x, y),
                        font.clone(),
                        size,
                        &text,
                        false,
                        TextDirection::Auto,
                    );
                }
                Mark::Line {
                    points,
                    width,
                    colour,
                } => {
                    let mut path = PathBuilder::new();
                    for (i, (x, y)) in points.iter().enumerate() {
                        if i == 0 {
                            path.move_to(*x, *y);
                        } else {
                            path.line_to(*x, *y);
                        }
                    }
                    let Some(path) = path.finish() else { continue };
                    surface.set_fill(None);
                    surface.set_stroke(Some(Stroke {
                        paint: rgb::Color::new(colour.0, colour.1, colour.2).into(),
                        width,
                        line_cap: LineCap::Round,
                        line_join: LineJoin::Round,
                        ..Default::default()
                    }));
                    surface.draw_path(&path);
                }
            }
        }
        surface.finish();
        pdf_page.finish();
    }
    document.finish().map_err(PdfError::Krilla)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(rows: usize) -> Table {
        Table {
            title: "Ring log",
            headings: vec!["ring", "station m"],
            rows: (0..rows)
                .map(|i| {
                    vec![
                        format!("{}", 100 + i),
                        format!("{:.3}", 1000.0 + i as f64 * 1.5),
                    ]
                })
                .collect(),
            empty: "none",
        }
    }

    #[test]
    fn columns_are_as_wide_as_their_widest_cell_and_a_long_last_cell_continues() {
        let lines = table_lines(&table(2), 200);
        assert_eq!(
            lines,
            ["ring  station m", "100   1000.000", "101   1001.500"]
        );
        // 26 characters across: 20 for the last column, a long cell
        // continues under it.
        let mut long = table(1);
        long.rows[0][1] = "deviation past the tolerance: front +120 mm".into();
        let wrapped = table_lines(&long, 26);
        assert_eq!(
            wrapped,
            [
                "ring  station m",
                "100   deviation past the",
                "      tolerance: front",
                "      +120 mm",
            ]
        );
        assert_eq!(wrap("abcdefghij klm", 4), ["abcd", "efgh", "ij", "klm"]);
    }

    #[test]
    fn a_long_log_runs_onto_more_pages_and_the_pdf_is_made() {
        let page = ReportPage {
            title: "Shift report: TBM".into(),
            subtitle: "machine tbm".into(),
            summary: vec![("Rings completed", "80".into())],
            chart: None,
            tables: vec![table(80)],
        };
        let pages = place(&page);
        assert_eq!(pages.len(), 2, "80 rows of 10.9 pt do not fit 523 pt");
        let bytes = write(&page).unwrap();
        assert!(bytes.starts_with(b"%PDF-"));
    }
}
