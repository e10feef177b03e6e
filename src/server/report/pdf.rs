//! The report as a PDF (krilla: Typst's PDF writer, maintained, with
//! fonts embedded and subset and their text extractable). A4 landscape,
//! DejaVu Sans Condensed and its bold (`assets/fonts`, their licence
//! beside them), text measured with the font's own advances (skrifa, the
//! reader krilla uses) so the tables' columns fit their widest cell. A
//! header block (project, machine, shift, range, generated at), the
//! summary, the chart with its tolerance bands and axis titles, the
//! tables with their headings again on every page they run onto, and the
//! lines to sign. The pages are first placed as [`Mark`]s, then drawn.

use krilla::Document;
use krilla::color::rgb;
use krilla::geom::{PathBuilder, Point, Rect};
use krilla::page::PageSettings;
use krilla::paint::{Fill, LineCap, LineJoin, Stroke, StrokeDash};
use krilla::text::{Font, TextDirection};
use skrifa::instance::{LocationRef, Size};
use skrifa::{FontRef, MetadataProvider};

use super::layout::{Chart, Panel, ReportPage, Table};

static REGULAR: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSansCondensed.ttf");
static BOLD: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSansCondensed-Bold.ttf");

/// A4 landscape, points.
const PAGE_W: f32 = 842.0;
const PAGE_H: f32 = 595.0;
const MARGIN: f32 = 36.0;
const TABLE_SIZE: f32 = 7.5;
const TEXT_SIZE: f32 = 9.5;
/// Space between table columns, points.
const GAP: f32 = 8.0;
/// Line height over the size.
const LEADING: f32 = 1.45;

/// Why no PDF was made.
#[derive(Debug, thiserror::Error)]
pub enum PdfError {
    #[error("the embedded font does not load")]
    Font,
    #[error("krilla: {0:?}")]
    Krilla(krilla::error::KrillaError),
}

/// Text widths in the report's fonts.
struct Measure {
    regular: skrifa::metrics::GlyphMetrics<'static>,
    regular_map: skrifa::charmap::Charmap<'static>,
    bold: skrifa::metrics::GlyphMetrics<'static>,
    bold_map: skrifa::charmap::Charmap<'static>,
}

impl Measure {
    fn new() -> Result<Measure, PdfError> {
        let regular = FontRef::new(REGULAR).map_err(|_| PdfError::Font)?;
        let bold = FontRef::new(BOLD).map_err(|_| PdfError::Font)?;
        // Advances at size 1: in ems.
        let size = Size::new(1.0);
        Ok(Measure {
            regular: regular.glyph_metrics(size, LocationRef::default()),
            regular_map: regular.charmap(),
            bold: bold.glyph_metrics(size, LocationRef::default()),
            bold_map: bold.charmap(),
        })
    }

    /// The width of `text` at `size`, points.
    fn width(&self, text: &str, size: f32, bold: bool) -> f32 {
        let (metrics, map) = match bold {
            true => (&self.bold, &self.bold_map),
            false => (&self.regular, &self.regular_map),
        };
        let ems: f32 = text
            .chars()
            .map(|c| {
                map.map(c)
                    .and_then(|g| metrics.advance_width(g))
                    // A character the font lacks is drawn as its .notdef.
                    .unwrap_or(0.6)
            })
            .sum();
        ems * size
    }
}

/// Something placed on a page (y down from the top, as krilla has it).
#[derive(Debug, Clone, PartialEq)]
enum Mark {
    /// Text from its baseline's left end.
    Text {
        x: f32,
        y: f32,
        size: f32,
        bold: bool,
        colour: (u8, u8, u8),
        text: String,
    },
    /// A polyline, dashed or not.
    Line {
        points: Vec<(f32, f32)>,
        width: f32,
        colour: (u8, u8, u8),
        dashed: bool,
    },
    /// A filled rectangle.
    Rect {
        x: f32,
        y: f32,
        w: f32,
        h: f32,
        colour: (u8, u8, u8),
    },
}

const BLACK: (u8, u8, u8) = (0, 0, 0);
const GREY: (u8, u8, u8) = (90, 90, 90);
const GRID: (u8, u8, u8) = (215, 215, 215);
const RULE: (u8, u8, u8) = (150, 150, 150);
const LIMIT: (u8, u8, u8) = (179, 107, 0);
const BAND_OK: (u8, u8, u8) = (232, 245, 233);
const BAND_WARN: (u8, u8, u8) = (255, 243, 224);

/// `#rrggbb` as a colour (black if it is not one).
fn colour(hex: &str) -> (u8, u8, u8) {
    let byte = |i: usize| {
        hex.get(i..i + 2)
            .and_then(|h| u8::from_str_radix(h, 16).ok())
            .unwrap_or(0)
    };
    (byte(1), byte(3), byte(5))
}

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

    /// Room for `height` more on this page, or a new page: true if one
    /// was begun.
    fn room(&mut self, height: f32) -> bool {
        if self.y + height > PAGE_H - MARGIN {
            self.pages.push(Vec::new());
            self.y = MARGIN;
            true
        } else {
            false
        }
    }

    fn mark(&mut self, mark: Mark) {
        if let Some(page) = self.pages.last_mut() {
            page.push(mark);
        }
    }

    fn text(&mut self, x: f32, size: f32, bold: bool, colour: (u8, u8, u8), text: String) {
        self.mark(Mark::Text {
            x,
            y: self.y,
            size,
            bold,
            colour,
            text,
        });
    }

    /// A line of text at the left margin.
    fn line(&mut self, size: f32, bold: bool, colour: (u8, u8, u8), text: String) {
        let height = size * LEADING;
        self.room(height);
        self.y += height;
        self.text(MARGIN, size, bold, colour, text);
    }

    fn rule(&mut self, y: f32) {
        self.mark(Mark::Line {
            points: vec![(MARGIN, y), (PAGE_W - MARGIN, y)],
            width: 0.5,
            colour: RULE,
            dashed: false,
        });
    }
}

/// A table's columns: their widths and whether they hold numbers (set
/// right), and the size the table is set in.
struct Columns {
    widths: Vec<f32>,
    numeric: Vec<bool>,
    size: f32,
}

/// The smallest size a table is set in to fit across the page, points.
const MIN_TABLE_SIZE: f32 = 5.0;

/// Whether a cell reads as a number, a time or a chainage.
fn numeric(cell: &str) -> bool {
    !cell.is_empty()
        && cell
            .chars()
            .all(|c| c.is_ascii_digit() || "+-−.:— ".contains(c))
}

/// The columns of `table`: as wide as the widest cell at `size`, the last
/// one (an alarm's message) narrowed to what the page leaves it; a table
/// still wider than the page is set smaller (down to [`MIN_TABLE_SIZE`])
/// until it fits.
fn columns(table: &Table, measure: &Measure, size: f32) -> Columns {
    let count = table.headings.len();
    // Widths at size 1: the table's widths scale with its size.
    let mut ems: Vec<f32> = table
        .headings
        .iter()
        .map(|h| measure.width(h, 1.0, true))
        .collect();
    let mut numeric_cells = vec![true; count];
    for row in &table.rows {
        for (i, cell) in row.iter().enumerate().take(count) {
            ems[i] = ems[i].max(measure.width(cell, 1.0, false));
            numeric_cells[i] &= numeric(cell) || cell == "—";
        }
    }
    let across = PAGE_W - 2.0 * MARGIN;
    let last = count.saturating_sub(1);
    // The columns before the last at `size`, and what the last needs.
    let before = |size: f32| -> f32 { ems[..last].iter().map(|w| w * size + GAP).sum() };
    let last_needs =
        |size: f32| (ems.get(last).copied().unwrap_or(0.0) * size).min(MIN_LAST_COLUMN);
    let mut size = size;
    while size > MIN_TABLE_SIZE && before(size) + last_needs(size) > across {
        size = (size - 0.25).max(MIN_TABLE_SIZE);
    }
    let mut widths: Vec<f32> = ems.iter().map(|w| w * size).collect();
    if count > 0 {
        let room = (across - before(size)).max(last_needs(size));
        widths[last] = widths[last].min(room);
    }
    Columns {
        widths,
        numeric: numeric_cells,
        size,
    }
}

/// `text` in lines no wider than `room` at `size`, broken between words,
/// a word wider than a line cut; linear in the text's length.
fn wrap(text: &str, room: f32, measure: &Measure, size: f32) -> Vec<String> {
    let space = measure.width(" ", size, false);
    let mut lines = Vec::new();
    let mut line = String::new();
    let mut used = 0.0;
    for word in text.split(' ') {
        let width = measure.width(word, size, false);
        let gap = if used > 0.0 { space } else { 0.0 };
        if used + gap + width <= room {
            if gap > 0.0 {
                line.push(' ');
            }
            line.push_str(word);
            used += gap + width;
            continue;
        }
        if used > 0.0 {
            lines.push(std::mem::take(&mut line));
            used = 0.0;
        }
        // Character by character: what fits, then a new line.
        for c in word.chars() {
            let w = measure.width(c.encode_utf8(&mut [0; 4]), size, false);
            if used + w > room && used > 0.0 {
                lines.push(std::mem::take(&mut line));
                used = 0.0;
            }
            line.push(c);
            used += w;
        }
    }
    lines.push(line);
    lines
}

/// The narrowest the last column is made, points.
const MIN_LAST_COLUMN: f32 = 120.0;

/// One row of cells at the current line, `bold` for the headings; the
/// last cell wrapped over as many lines as it needs.
fn row(
    pages: &mut Pages,
    cells: &[&str],
    columns: &Columns,
    measure: &Measure,
    bold: bool,
    colour: (u8, u8, u8),
) {
    let count = columns.widths.len();
    let height = columns.size * LEADING;
    let last_lines = cells
        .get(count.saturating_sub(1))
        .map(|c| wrap(c, columns.widths[count - 1], measure, columns.size))
        .unwrap_or_default();
    pages.y += height;
    let mut x = MARGIN;
    for (i, width) in columns.widths.iter().enumerate() {
        let text = match i + 1 == count {
            true => last_lines.first().cloned().unwrap_or_default(),
            false => cells.get(i).map(|c| c.to_string()).unwrap_or_default(),
        };
        let at = if columns.numeric[i] {
            x + width - measure.width(&text, columns.size, bold)
        } else {
            x
        };
        pages.text(at, columns.size, bold, colour, text);
        x += width + GAP;
    }
    let indent: f32 = columns.widths[..count.saturating_sub(1)]
        .iter()
        .map(|w| w + GAP)
        .sum();
    for piece in last_lines.into_iter().skip(1) {
        pages.y += height;
        pages.text(MARGIN + indent, columns.size, bold, colour, piece);
    }
}

/// A table: its title, its headings, its rows, the headings again at the
/// top of every page it runs onto.
fn table(pages: &mut Pages, table: &Table, measure: &Measure) {
    let line = TABLE_SIZE * LEADING;
    pages.y += 8.0;
    pages.room(11.0 * LEADING + 3.0 * line);
    pages.line(11.0, true, BLACK, table.title.into());
    if table.rows.is_empty() {
        pages.line(TABLE_SIZE, false, GREY, table.empty.into());
        return;
    }
    let columns = columns(table, measure, TABLE_SIZE);
    let line = columns.size * LEADING;
    let headings = |pages: &mut Pages| {
        row(pages, &table.headings, &columns, measure, true, GREY);
        let y = pages.y + 2.5;
        pages.rule(y);
        pages.y += 1.0;
    };
    headings(pages);
    for cells in &table.rows {
        let cells: Vec<&str> = cells.iter().map(String::as_str).collect();
        // The whole row (its wrapped last cell too) on one page.
        let lines = cells
            .get(columns.widths.len().saturating_sub(1))
            .map(|c| {
                wrap(
                    c,
                    *columns.widths.last().unwrap_or(&0.0),
                    measure,
                    columns.size,
                )
                .len()
            })
            .unwrap_or(1);
        if pages.room(lines as f32 * line) {
            pages.line(11.0, true, BLACK, format!("{} (continued)", table.title));
            headings(pages);
        }
        row(pages, &cells, &columns, measure, false, BLACK);
    }
}

/// One panel of the chart at `top`: bands, gridlines, limits, the line.
fn panel(pages: &mut Pages, chart: &Chart, panel: &Panel, top: f32, measure: &Measure) {
    let left = MARGIN + 44.0;
    let width = PAGE_W - MARGIN - left;
    let height = 110.0_f32;
    let sx = width / Chart::WIDTH as f32;
    let sy = height / Chart::HEIGHT as f32;
    let at = |(x, y): (f64, f64)| (left + x as f32 * sx, top + y as f32 * sy);
    pages.mark(Mark::Text {
        x: left,
        y: top - 4.0,
        size: TABLE_SIZE + 0.5,
        bold: true,
        colour: BLACK,
        text: panel.title.to_string(),
    });
    for band in &panel.bands {
        let (_, y0) = at((0.0, band.top));
        let (_, y1) = at((0.0, band.bottom));
        pages.mark(Mark::Rect {
            x: left,
            y: y0,
            w: width,
            h: y1 - y0,
            colour: if band.kind == "ok" {
                BAND_OK
            } else {
                BAND_WARN
            },
        });
    }
    for (y, label) in &panel.y_ticks {
        let (_, py) = at((0.0, *y));
        pages.mark(Mark::Line {
            points: vec![(left, py), (left + width, py)],
            width: 0.4,
            colour: GRID,
            dashed: false,
        });
        pages.mark(Mark::Text {
            x: left - 4.0 - measure.width(label, TABLE_SIZE, false),
            y: py + TABLE_SIZE * 0.35,
            size: TABLE_SIZE,
            bold: false,
            colour: GREY,
            text: label.clone(),
        });
    }
    for (x, label) in &chart.x_ticks {
        let (px, _) = at((*x, 0.0));
        pages.mark(Mark::Line {
            points: vec![(px, top), (px, top + height)],
            width: 0.4,
            colour: GRID,
            dashed: false,
        });
        pages.mark(Mark::Text {
            x: px - measure.width(label, TABLE_SIZE, false) / 2.0,
            y: top + height + TABLE_SIZE * 1.4,
            size: TABLE_SIZE,
            bold: false,
            colour: GREY,
            text: label.clone(),
        });
    }
    for (y, label) in &panel.limits {
        let (_, py) = at((0.0, *y));
        pages.mark(Mark::Line {
            points: vec![(left, py), (left + width, py)],
            width: 0.7,
            colour: LIMIT,
            dashed: true,
        });
        if !label.is_empty() {
            pages.mark(Mark::Text {
                x: left + width - measure.width(label, TABLE_SIZE, false) - 2.0,
                y: py - 2.0,
                size: TABLE_SIZE,
                bold: false,
                colour: LIMIT,
                text: label.clone(),
            });
        }
    }
    for segment in &panel.segments {
        pages.mark(Mark::Line {
            points: segment.iter().map(|p| at(*p)).collect(),
            width: 1.1,
            colour: colour(panel.colour),
            dashed: false,
        });
    }
}

/// The chart from the current line: a panel per plane, the station's
/// title under them.
fn chart(pages: &mut Pages, chart: &Chart, measure: &Measure) {
    let per_panel = 110.0 + 34.0;
    pages.room(per_panel * chart.panels.len() as f32 + 30.0);
    for p in &chart.panels {
        let top = pages.y + 16.0;
        panel(pages, chart, p, top, measure);
        pages.y = top + per_panel - 16.0;
    }
    pages.line(TABLE_SIZE + 0.5, true, BLACK, chart.x_title.to_string());
    pages.line(
        TABLE_SIZE,
        false,
        GREY,
        "green: within the warn limit; amber: between warn and alarm; a line broken where the station went back (a new drive)"
            .into(),
    );
}

/// The header block: a box of label and value pairs in two columns.
fn header(pages: &mut Pages, page: &ReportPage, measure: &Measure) {
    let line = TEXT_SIZE * LEADING;
    let rows = page.header.len().div_ceil(2);
    let top = pages.y + 4.0;
    let half = (PAGE_W - 2.0 * MARGIN) / 2.0;
    let label_w = page
        .header
        .iter()
        .map(|(l, _)| measure.width(l, TEXT_SIZE, true))
        .fold(0.0, f32::max)
        + 10.0;
    for (i, (label, value)) in page.header.iter().enumerate() {
        let x = MARGIN + 6.0 + if i % 2 == 0 { 0.0 } else { half };
        let y = top + line * (1 + i / 2) as f32;
        pages.mark(Mark::Text {
            x,
            y,
            size: TEXT_SIZE,
            bold: true,
            colour: GREY,
            text: label.to_string(),
        });
        pages.mark(Mark::Text {
            x: x + label_w,
            y,
            size: TEXT_SIZE,
            bold: false,
            colour: BLACK,
            text: value.clone(),
        });
    }
    let bottom = top + line * rows as f32 + 6.0;
    pages.mark(Mark::Line {
        points: vec![
            (MARGIN, top - 6.0),
            (PAGE_W - MARGIN, top - 6.0),
            (PAGE_W - MARGIN, bottom),
            (MARGIN, bottom),
            (MARGIN, top - 6.0),
        ],
        width: 0.7,
        colour: RULE,
        dashed: false,
    });
    pages.y = bottom + 4.0;
}

/// The lines to sign at the end.
fn signatures(pages: &mut Pages, page: &ReportPage, measure: &Measure) {
    let line = 26.0;
    pages.y += 10.0;
    pages.room(11.0 * LEADING + line * page.signatures.len() as f32 + 10.0);
    pages.line(11.0, true, BLACK, "Sign-off".into());
    let fields = ["name", "date", "signature"];
    let role_w = page
        .signatures
        .iter()
        .map(|r| measure.width(r, TEXT_SIZE, false))
        .fold(0.0, f32::max)
        + 16.0;
    let field_w = (PAGE_W - 2.0 * MARGIN - role_w) / fields.len() as f32;
    for who in &page.signatures {
        pages.y += line;
        pages.text(MARGIN, TEXT_SIZE, false, BLACK, who.to_string());
        for (i, field) in fields.iter().enumerate() {
            let x = MARGIN + role_w + i as f32 * field_w;
            pages.text(x, TABLE_SIZE, false, GREY, format!("{field}:"));
            let start = x + measure.width(field, TABLE_SIZE, false) + 8.0;
            let y = pages.y + 1.0;
            pages.mark(Mark::Line {
                points: vec![(start, y), (x + field_w - 12.0, y)],
                width: 0.6,
                colour: BLACK,
                dashed: false,
            });
        }
    }
}

/// Places the report's layout on pages.
fn place(page: &ReportPage, measure: &Measure) -> Vec<Vec<Mark>> {
    let mut pages = Pages::new();
    pages.line(16.0, true, BLACK, page.title.clone());
    pages.y += 8.0;
    header(&mut pages, page, measure);
    pages.y += 4.0;
    let label_w = page
        .summary
        .iter()
        .map(|(l, _)| measure.width(l, TEXT_SIZE, true))
        .fold(0.0, f32::max)
        + 12.0;
    let room = PAGE_W - 2.0 * MARGIN - label_w;
    for (label, value) in &page.summary {
        pages.line(TEXT_SIZE, true, GREY, label.to_string());
        for (i, piece) in wrap(value, room, measure, TEXT_SIZE)
            .into_iter()
            .enumerate()
        {
            if i > 0 {
                pages.room(TEXT_SIZE * LEADING);
                pages.y += TEXT_SIZE * LEADING;
            }
            pages.text(MARGIN + label_w, TEXT_SIZE, false, BLACK, piece);
        }
    }
    if let Some(c) = &page.chart {
        pages.y += 8.0;
        pages.line(11.0, true, BLACK, "Deviation of the front".into());
        chart(&mut pages, c, measure);
    }
    for t in &page.tables {
        table(&mut pages, t, measure);
    }
    signatures(&mut pages, page, measure);
    pages.pages
}

/// The PDF of the report's layout.
pub fn write(page: &ReportPage) -> Result<Vec<u8>, PdfError> {
    let measure = Measure::new()?;
    let regular = Font::new(REGULAR.into(), 0).ok_or(PdfError::Font)?;
    let bold = Font::new(BOLD.into(), 0).ok_or(PdfError::Font)?;
    let mut document = Document::new();
    let settings = PageSettings::from_wh(PAGE_W, PAGE_H).ok_or(PdfError::Font)?;
    let placed = place(page, &measure);
    let count = placed.len();
    for (number, marks) in placed.into_iter().enumerate() {
        let mut pdf_page = document.start_page_with(settings.clone());
        let mut surface = pdf_page.surface();
        let mut marks = marks;
        let footer = format!("{} · page {} of {count}", page.subtitle, number + 1);
        marks.push(Mark::Text {
            x: PAGE_W - MARGIN - measure.width(&footer, TABLE_SIZE, false),
            y: PAGE_H - MARGIN / 2.0,
            size: TABLE_SIZE,
            bold: false,
            colour: GREY,
            text: footer,
        });
        for mark in marks {
            match mark {
                Mark::Text {
                    x,
                    y,
                    size,
                    bold: is_bold,
                    colour,
                    text,
                } => {
                    surface.set_stroke(None);
                    surface.set_fill(Some(Fill {
                        paint: rgb::Color::new(colour.0, colour.1, colour.2).into(),
                        ..Default::default()
                    }));
                    let font = if is_bold {
                        bold.clone()
                    } else {
                        regular.clone()
                    };
                    surface.draw_text(
                        Point::from_xy(x, y),
                        font,
                        size,
                        &text,
                        false,
                        TextDirection::Auto,
                    );
                }
                Mark::Rect { x, y, w, h, colour } => {
                    let Some(rect) = Rect::from_xywh(x, y, w, h) else {
                        continue;
                    };
                    let mut path = PathBuilder::new();
                    path.push_rect(rect);
                    let Some(path) = path.finish() else { continue };
                    surface.set_stroke(None);
                    surface.set_fill(Some(Fill {
                        paint: rgb::Color::new(colour.0, colour.1, colour.2).into(),
                        ..Default::default()
                    }));
                    surface.draw_path(&path);
                }
                Mark::Line {
                    points,
                    width,
                    colour,
                    dashed,
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
                        dash: dashed.then(|| StrokeDash {
                            array: vec![3.0, 2.5],
                            offset: 0.0,
                        }),
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
            headings: vec!["ring", "chainage", "message"],
            rows: (0..rows)
                .map(|i| {
                    vec![
                        format!("{}", 100 + i),
                        format!("1+{:07.3}", i as f64 * 1.5),
                        "ok".to_string(),
                    ]
                })
                .collect(),
            empty: "none",
        }
    }

    fn page(tables: Vec<Table>) -> ReportPage {
        ReportPage {
            title: "Shift report: TBM".into(),
            subtitle: "machine tbm".into(),
            header: vec![("Project", "S-1".into()), ("Machine", "TBM (tbm)".into())],
            summary: vec![("Rings completed", "80".into())],
            chart: None,
            tables,
            signatures: vec!["Operator"],
        }
    }

    #[test]
    fn text_is_measured_in_the_proportional_font_and_wrapped_by_width() {
        let m = Measure::new().unwrap();
        // DejaVu Sans Condensed: "i" is narrower than "W", digits are all
        // alike (tabular).
        assert!(m.width("iiii", 10.0, false) < m.width("WWWW", 10.0, false) / 2.0);
        assert_eq!(m.width("0", 10.0, false), m.width("8", 10.0, false));
        assert!(m.width("ring", 10.0, true) > m.width("ring", 10.0, false));
        // Words kept whole where they fit, a word wider than a line cut.
        let room = m.width("deviation past", 7.5, false) + 0.01;
        let lines = wrap("deviation past the tolerance", room, &m, 7.5);
        assert_eq!(lines, ["deviation past", "the tolerance"]);
        let cut = wrap("abcdefghij", m.width("abcd", 7.5, false) + 0.01, &m, 7.5);
        assert_eq!(cut, ["abcd", "efgh", "ij"]);
        assert!(numeric("1+234.500") && numeric("−3.2") && !numeric("ok"));
    }

    #[test]
    fn a_table_wider_than_the_page_is_set_smaller_to_fit() {
        let m = Measure::new().unwrap();
        let wide = Table {
            title: "Rings as built",
            headings: (0..16).map(|_| "a heading").collect(),
            rows: vec![(0..16).map(|_| "degraded: laser".to_string()).collect()],
            empty: "none",
        };
        let c = columns(&wide, &m, TABLE_SIZE);
        assert!(c.size < TABLE_SIZE, "{}", c.size);
        let total: f32 = c.widths.iter().map(|w| w + GAP).sum::<f32>() - GAP;
        assert!(
            total <= PAGE_W - 2.0 * MARGIN + 0.01,
            "{total} at {}",
            c.size
        );
        // A table that fits keeps its size.
        assert_eq!(columns(&table(3), &m, TABLE_SIZE).size, TABLE_SIZE);
    }

    #[test]
    fn a_long_log_runs_onto_more_pages_with_its_headings_again() {
        let m = Measure::new().unwrap();
        let page = page(vec![table(120)]);
        let pages = place(&page, &m);
        assert!(pages.len() >= 3, "{}", pages.len());
        // Every page the log runs onto begins with its headings.
        for marks in &pages[1..] {
            let texts: Vec<&str> = marks
                .iter()
                .filter_map(|mark| match mark {
                    Mark::Text { text, .. } => Some(text.as_str()),
                    _ => None,
                })
                .collect();
            let at = texts.iter().position(|t| *t == "Ring log (continued)");
            if let Some(at) = at {
                assert_eq!(&texts[at + 1..at + 4], ["ring", "chainage", "message"]);
            }
        }
        let continued = pages
            .iter()
            .filter(|marks| {
                marks.iter().any(
                    |mark| matches!(mark, Mark::Text { text, .. } if text == "Ring log (continued)"),
                )
            })
            .count();
        assert!(continued >= 1);
        let bytes = write(&page).unwrap();
        assert!(bytes.starts_with(b"%PDF-"));
    }
}
