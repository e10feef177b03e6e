//! `tunnelnav site reset-mark MACHINE --to SEQUENCE --data-dir DIR | --store
//! URL`: an office's mark of a site's machine set back (never forward),
//! after a `forward_refused` alarm, recorded in the audit log as done from
//! the command line. For an office that is stopped: a running one keeps
//! the mark its machine holds until it restarts; use `PUT
//! /api/v1/machines/{site}.{machine}/forward-mark` there, which takes
//! effect at once.

use clap::{Args, Subcommand};

use super::CliError;
use super::token::DataDir;
use crate::clock::wall_clock_s;
use crate::store::Store;
use crate::store::postgres::PgStore;

/// Who the audit log names for a change made here.
const ACTOR: &str = "cli";

#[derive(Debug, Subcommand)]
pub enum SiteCommand {
    /// Set an office's mark of a site's machine back (after `forward_refused`).
    ResetMark(ResetMarkArgs),
}

#[derive(Debug, Args)]
pub struct ResetMarkArgs {
    #[command(flatten)]
    pub dir: DataDir,
    /// The site's machine, `{site}.{machine}`.
    pub machine: String,
    /// The sequence the mark goes back to: the site's last confirmed one,
    /// as the `forward_refused` alarm names it.
    #[arg(long)]
    pub to: i64,
}

pub fn run(command: SiteCommand) -> Result<(), CliError> {
    match command {
        SiteCommand::ResetMark(args) => reset_mark(&args),
    }
}

fn reset_mark(args: &ResetMarkArgs) -> Result<(), CliError> {
    if !args.machine.contains('.') {
        return Err(CliError::Refused(format!(
            "`{}` is not a site's machine: forwarded machines are named `{{site}}.{{machine}}`",
            args.machine
        )));
    }
    if args.to < 0 {
        return Err(CliError::Refused(format!(
            "--to {}: a sequence is 0 or more",
            args.to
        )));
    }
    let location = crate::server::settings::store_location(
        args.dir.store.as_deref(),
        crate::server::settings::StoreFiles {
            password_file: args.dir.store_password_file.as_deref(),
            ca_file: args.dir.store_ca_file.as_deref(),
        },
        &Default::default(),
    )?;
    let now = wall_clock_s();
    let was = match location {
        None => {
            let mut conn = Store::connect(&args.dir.data_dir)?;
            crate::store::sqlite::outbox::reset_mark(&mut conn, &args.machine, args.to, ACTOR, now)?
        }
        Some(location) => {
            let runtime = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()?;
            runtime.block_on(async {
                let store = PgStore::open_client(&location).await?;
                store
                    .reset_forward_mark(args.machine.clone(), args.to, ACTOR.into(), now)
                    .await
            })?
        }
    };
    let Some(was) = was else {
        return Err(CliError::Refused(format!(
            "`{}` has no mark here: no such forwarded machine",
            args.machine
        )));
    };
    let now_mark = args.to.min(was);
    println!(
        "{}: mark {was} -> {now_mark} (audited){}",
        args.machine,
        if args.to > was {
            " — never set forward"
        } else {
            ""
        }
    );
    Ok(())
}
