//! Text in the service's CSV files, safe to open in a spreadsheet.
//!
//! A cell that a spreadsheet reads as a formula runs it: `=HYPERLINK(…)`
//! in an alarm's message, a machine named `+cmd`, an id `-x`. OWASP's
//! advice (CSV injection): a text cell that begins with `=`, `+`, `-`,
//! `@`, a tab or a carriage return is prefixed with a single quote, which
//! the spreadsheet shows as text; the cell is quoted as RFC 4180 needs.
//! Numbers are written as numbers (`-3.5` stays a number) by the callers:
//! only text passes through here.

/// The characters that make a spreadsheet read a cell as a formula.
const FORMULA_STARTS: [char; 6] = ['=', '+', '-', '@', '\t', '\r'];

/// `text` as one CSV cell: neutralised if it could start a formula, quoted
/// (quotes doubled) if it must be or `always_quote`.
pub fn text_cell(text: &str, always_quote: bool) -> String {
    let neutral = if text.starts_with(FORMULA_STARTS) {
        format!("'{text}")
    } else {
        text.to_string()
    };
    if always_quote || neutral.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", neutral.replace('"', "\"\""))
    } else {
        neutral
    }
}

/// Whether a written cell could be read as a formula: it starts with a
/// formula character and is not a number (the check the tests make).
pub fn could_be_formula(cell: &str) -> bool {
    let unquoted = cell.trim_matches('"');
    unquoted.starts_with(FORMULA_STARTS) && unquoted.parse::<f64>().is_err()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formulas_are_neutralised_and_numbers_stay_numbers() {
        assert_eq!(
            text_cell("=HYPERLINK(\"x\")", false),
            "\"'=HYPERLINK(\"\"x\"\")\""
        );
        assert_eq!(text_cell("+cmd", false), "'+cmd");
        assert_eq!(text_cell("-x", true), "\"'-x\"");
        assert_eq!(text_cell("@SUM(A1)", false), "'@SUM(A1)");
        assert_eq!(text_cell("\tx", false), "'\tx");
        assert_eq!(text_cell("\rx", false), "\"'\rx\"");
        assert_eq!(text_cell("plain, text", false), "\"plain, text\"");
        assert_eq!(text_cell("ok", false), "ok");
        for written in ["'=1+1", "\"'-x\"", "-3.5", "1e-7", "ok", ""] {
            assert!(!could_be_formula(written), "{written}");
        }
        for written in ["=1+1", "\"+cmd\"", "-x", "@a"] {
            assert!(could_be_formula(written), "{written}");
        }
    }
}
