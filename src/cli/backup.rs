//! `tunnelnav backup FILE [--data-dir DIR]`: an online copy of the
//! database, while the server runs and ingests.
//!
//! `VACUUM INTO` reads one consistent snapshot of the database (the
//! write-ahead log lets the server's writer go on meanwhile) and writes a
//! compact copy; a half-written copy is never left under FILE's name: the
//! copy goes to FILE.partial and is renamed when complete and checked.

use std::path::PathBuf;

use clap::Args;

use super::CliError;
use crate::store::Store;

#[derive(Debug, Args)]
pub struct BackupArgs {
    /// Where to write the copy (must not exist). Serve it later with
    /// `--data-dir` pointing at a directory holding it as tunnelnav.sqlite3.
    pub file: PathBuf,
    /// The server's data directory.
    #[arg(long, default_value = "data")]
    pub data_dir: PathBuf,
}

pub fn run(args: BackupArgs) -> Result<(), CliError> {
    if args.file.exists() {
        return Err(CliError::Refused(format!(
            "{} exists; a backup does not overwrite",
            args.file.display()
        )));
    }
    let database = args.data_dir.join(crate::store::DB_FILE);
    if !database.exists() {
        return Err(CliError::Refused(format!(
            "there is no database at {}",
            database.display()
        )));
    }
    let partial = args.file.with_extension("partial");
    let _ = std::fs::remove_file(&partial);
    let started = std::time::Instant::now();
    let conn = Store::connect(&args.data_dir)?;
    let target = partial
        .to_str()
        .ok_or_else(|| CliError::Refused(format!("{} is not a UTF-8 path", partial.display())))?;
    conn.execute("VACUUM INTO ?1", [target])
        .map_err(crate::store::StoreError::from)?;
    let copy = rusqlite::Connection::open(&partial).map_err(crate::store::StoreError::from)?;
    let check: String = copy
        .query_row("PRAGMA integrity_check", [], |row| row.get(0))
        .map_err(crate::store::StoreError::from)?;
    if check != "ok" {
        return Err(CliError::Refused(format!(
            "the copy failed its integrity check: {check}; left at {}",
            partial.display()
        )));
    }
    drop(copy);
    std::fs::rename(&partial, &args.file).map_err(|source| CliError::File {
        context: format!(
            "cannot rename {} to {}",
            partial.display(),
            args.file.display()
        ),
        source,
    })?;
    let bytes = std::fs::metadata(&args.file).map(|m| m.len()).unwrap_or(0);
    eprintln!(
        "backup of {} written to {} ({:.1} MB, {:.1} s, integrity ok)",
        args.data_dir.display(),
        args.file.display(),
        bytes as f64 / 1e6,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
