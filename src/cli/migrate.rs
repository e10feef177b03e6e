//! `tunnelnav migrate --from DATA_DIR --to postgres://USER@HOST:PORT/DB`:
//! a site's SQLite store moved into an empty PostgreSQL database, verified
//! table by table (rows and a SHA-256 over them) before it is committed.
//! Stop the site's server first: rows it writes meanwhile are not moved.

use std::path::PathBuf;

use clap::Args;

use super::CliError;
use crate::store::postgres::migrate;

#[derive(Debug, Args)]
pub struct MigrateArgs {
    /// The site's data directory (its SQLite store).
    #[arg(long, value_name = "DATA_DIR")]
    pub from: PathBuf,
    /// The empty PostgreSQL database, `postgres://USER@HOST:PORT/DB`.
    #[arg(long, value_name = "URL")]
    pub to: String,
    /// A file whose first line is the database's password.
    #[arg(long, value_name = "FILE")]
    pub to_password_file: Option<PathBuf>,
    /// The CA (PEM) the database's certificate is checked against when the
    /// URL asks for TLS (`sslmode=require`).
    #[arg(long, value_name = "FILE")]
    pub to_ca_file: Option<PathBuf>,
}

pub fn run(args: MigrateArgs) -> Result<(), CliError> {
    let Some(target) = crate::server::settings::store_location(
        Some(&args.to),
        crate::server::settings::StoreFiles {
            password_file: args.to_password_file.as_deref(),
            ca_file: args.to_ca_file.as_deref(),
        },
        &Default::default(),
    )?
    else {
        return Err(CliError::Refused(
            "--to names no PostgreSQL database".into(),
        ));
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let started = std::time::Instant::now();
    let reports = runtime.block_on(migrate::from_sqlite(&args.from, &target))?;
    println!("{:<18} {:>12}  sha256 (equal in both)", "table", "rows");
    for report in &reports {
        println!(
            "{:<18} {:>12}  {}",
            report.table, report.rows, report.sha256
        );
    }
    eprintln!(
        "moved {} into {} in {:.1} s; every table verified, then committed",
        args.from.display(),
        target.redacted_url(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
