//! Imports run downwards (issue 36): nothing below the server layer —
//! every module of `src/` but `server/`, `cli/` and `main.rs` — names the
//! server or the command line, in code or in doc links; and the server
//! does not name the command line. The exception is `toy_engine.rs`, a
//! unit-test module that follows a toy engine through every layer (the
//! registry lists it in test builds only).

use std::path::{Path, PathBuf};

fn rust_files(path: &Path, out: &mut Vec<PathBuf>) {
    if path.is_dir() {
        let mut entries: Vec<PathBuf> = std::fs::read_dir(path)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        entries.sort();
        for entry in entries {
            rust_files(&entry, out);
        }
    } else if path.extension().is_some_and(|e| e == "rs") {
        out.push(path.to_path_buf());
    }
}

/// Lines of `files` that name a module of `layers` as a path: `crate::X`
/// or `super::X` anywhere, and in code (not comments) `X::` after a
/// path separator, `{` or `,` of a grouped import (`use crate::{X::…}`).
fn naming(files: &[PathBuf], layers: &[&str]) -> Vec<String> {
    let mut found = Vec::new();
    for file in files {
        let text = std::fs::read_to_string(file).unwrap();
        let mut in_use = false;
        for (n, line) in text.lines().enumerate() {
            let trimmed = line.trim_start();
            let comment = trimmed.starts_with("//");
            // lib.rs declares the modules.
            if file.ends_with("lib.rs") && trimmed.starts_with("pub mod ") {
                continue;
            }
            if !comment && trimmed.starts_with("use ") {
                in_use = true;
            }
            let hit = layers.iter().any(|layer| {
                let anywhere = [format!("crate::{layer}"), format!("super::{layer}")];
                let grouped = [format!("{{{layer}::"), format!(", {layer}::")];
                anywhere.iter().any(|p| line.contains(p.as_str()))
                    || (!comment
                        && (grouped.iter().any(|p| line.contains(p.as_str()))
                            || (in_use && trimmed.starts_with(&format!("{layer}::")))))
            });
            if hit {
                found.push(format!("{}:{}: {}", file.display(), n + 1, line.trim()));
            }
            if !comment && line.contains(';') {
                in_use = false;
            }
        }
    }
    found
}

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

#[test]
fn nothing_below_the_server_names_it() {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(src()).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        // toy_engine.rs is a unit-test module that follows a toy engine
        // through every layer (docs/development.md).
        if !["server", "cli", "main.rs", "toy_engine.rs"].contains(&name.as_str()) {
            rust_files(&path, &mut files);
        }
    }
    assert!(files.len() > 50, "only {} files found", files.len());
    let upward = naming(&files, &["server", "cli"]);
    assert!(upward.is_empty(), "upward imports:\n{}", upward.join("\n"));
}

#[test]
fn the_server_does_not_name_the_command_line() {
    let mut files = Vec::new();
    rust_files(&src().join("server"), &mut files);
    let upward = naming(&files, &["cli"]);
    assert!(upward.is_empty(), "upward imports:\n{}", upward.join("\n"));
}

#[test]
fn the_check_finds_each_form_of_import() {
    let dir = std::env::temp_dir().join(format!("tunnelnav-layering-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let forms = [
        "use crate::server::settings::Limits;",
        "use super::server::Limits;",
        "use crate::{config, server::settings};",
        "use crate::{\n    config::MachineSpec,\n    server::settings,\n};",
        "/// See [`crate::server::state`].",
    ];
    for (i, form) in forms.iter().enumerate() {
        let file = dir.join(format!("f{i}.rs"));
        std::fs::write(&file, form).unwrap();
        assert_eq!(naming(&[file], &["server"]).len(), 1, "missed: {form}");
    }
    let clean = dir.join("clean.rs");
    std::fs::write(
        &clean,
        "use crate::store::Store; // the server's store\nlet server = 1;\n",
    )
    .unwrap();
    assert!(naming(&[clean], &["server"]).is_empty());
    std::fs::remove_dir_all(&dir).unwrap();
}
