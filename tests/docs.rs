//! The documentation a fresh clone has: every relative link in the README
//! and in `docs/` resolves inside the repository, and every `#anchor` names
//! a heading of its target (GitHub's slugs); every code block is closed.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// README.md and every Markdown file under docs/.
fn documents() -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(&path, out);
            } else if path.extension().is_some_and(|e| e == "md") {
                out.push(path);
            }
        }
    }
    let mut out = vec![root().join("README.md")];
    walk(&root().join("docs"), &mut out);
    out.sort();
    out
}

/// The lines outside fenced code blocks; panics on an unclosed one.
fn prose(path: &Path, text: &str) -> Vec<String> {
    let mut fenced = false;
    let mut out = Vec::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        } else if !fenced {
            out.push(line.to_string());
        }
    }
    assert!(!fenced, "{}: a code block is never closed", path.display());
    out
}

/// GitHub's anchor of a heading: lower case, punctuation dropped except
/// `-` and `_`, spaces to `-`.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || matches!(c, ' ' | '-' | '_'))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

fn anchors(path: &Path) -> BTreeSet<String> {
    let text = std::fs::read_to_string(path).unwrap();
    prose(path, &text)
        .iter()
        .filter_map(|l| l.strip_prefix('#'))
        .map(|l| slug(l.trim_start_matches('#')))
        .collect()
}

/// `[text](target)` targets in a line of prose.
fn links(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = line;
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        match after.find(')') {
            Some(j) => {
                out.push(after[..j].to_string());
                rest = &after[j..];
            }
            None => break,
        }
    }
    out
}

#[test]
fn every_relative_link_resolves_inside_the_repository() {
    let mut checked = 0;
    for document in documents() {
        let text = std::fs::read_to_string(&document).unwrap();
        let dir = document.parent().unwrap();
        for line in prose(&document, &text) {
            for target in links(&line) {
                if target.starts_with("http://")
                    || target.starts_with("https://")
                    || target.starts_with("mailto:")
                {
                    continue;
                }
                let (file, anchor) = match target.split_once('#') {
                    Some((file, anchor)) => (file, Some(anchor)),
                    None => (target.as_str(), None),
                };
                let resolved = if file.is_empty() {
                    document.clone()
                } else {
                    dir.join(file)
                };
                let inside = resolved
                    .canonicalize()
                    .unwrap_or_else(|_| panic!("{}: `{target}` does not exist", document.display()))
                    .starts_with(root().canonicalize().unwrap());
                assert!(
                    inside,
                    "{}: `{target}` leaves the repository",
                    document.display()
                );
                if let Some(anchor) = anchor {
                    assert!(
                        anchors(&resolved).contains(anchor),
                        "{}: `{target}`: no heading with that anchor",
                        document.display()
                    );
                }
                checked += 1;
            }
        }
    }
    assert!(checked >= 15, "only {checked} links found");
}

#[test]
fn github_slugs_are_computed_as_github_does() {
    assert_eq!(
        slug("Limits, faults, retention, backup"),
        "limits-faults-retention-backup"
    );
    assert_eq!(
        slug("The `attitude` engine (after He et al. 2021)"),
        "the-attitude-engine-after-he-et-al-2021"
    );
    assert_eq!(
        slug("Design axis and deviation (`dta`)"),
        "design-axis-and-deviation-dta"
    );
}
