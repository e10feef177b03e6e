//! `tunnelnav token create|list|revoke --data-dir DIR`: access tokens,
//! stored hashed in the server's database (a running server picks changes
//! up within 2 s).

use std::path::PathBuf;

use clap::{Args, Subcommand};

use super::CliError;
use crate::auth::{self, Scope};
use crate::clock::wall_clock_s;
use crate::store::Store;

#[derive(Debug, Subcommand)]
pub enum TokenCommand {
    /// Create a token and print it (once: only its hash is kept).
    Create(CreateArgs),
    /// List the tokens (never the tokens themselves).
    List(DataDir),
    /// Revoke a token by its id.
    Revoke(RevokeArgs),
}

#[derive(Debug, Args)]
pub struct DataDir {
    /// The server's data directory.
    #[arg(long, default_value = "data")]
    pub data_dir: PathBuf,
}

#[derive(Debug, Args)]
pub struct CreateArgs {
    #[command(flatten)]
    pub dir: DataDir,
    /// ingest (one machine's gateway), read (dashboard, history) or admin.
    #[arg(long, value_parser = parse_scope)]
    pub scope: Scope,
    /// The machine an ingest token may send readings for.
    #[arg(long)]
    pub machine: Option<String>,
    /// A name to recognise it by (who holds it).
    #[arg(long, default_value = "")]
    pub name: String,
}

#[derive(Debug, Args)]
pub struct RevokeArgs {
    #[command(flatten)]
    pub dir: DataDir,
    /// The token's id (from `token list`).
    pub id: i64,
}

fn parse_scope(text: &str) -> Result<Scope, String> {
    Scope::from_name(text).ok_or_else(|| format!("`{text}`: expected ingest, read or admin"))
}

pub fn run(command: TokenCommand) -> Result<(), CliError> {
    match command {
        TokenCommand::Create(args) => {
            let conn = Store::connect(&args.dir.data_dir)?;
            let name = if args.name.is_empty() {
                match &args.machine {
                    Some(machine) => format!("{} {machine}", args.scope.as_str()),
                    None => args.scope.as_str().to_string(),
                }
            } else {
                args.name.clone()
            };
            let (id, token) = auth::create(
                &conn,
                &name,
                args.scope,
                args.machine.as_deref(),
                wall_clock_s(),
            )?;
            eprintln!(
                "token {id} `{name}` ({}) created; it is shown only now:",
                args.scope.as_str()
            );
            println!("{token}");
            Ok(())
        }
        TokenCommand::List(dir) => {
            let conn = Store::connect(&dir.data_dir)?;
            println!(
                "{:>4}  {:<8} {:<20} {:<24} state",
                "id", "scope", "machine", "name"
            );
            for t in auth::list(&conn)? {
                println!(
                    "{:>4}  {:<8} {:<20} {:<24} {}",
                    t.id,
                    t.scope.as_str(),
                    t.machine.as_deref().unwrap_or("—"),
                    t.name,
                    if t.revoked_t.is_some() {
                        "revoked"
                    } else {
                        "active"
                    }
                );
            }
            Ok(())
        }
        TokenCommand::Revoke(args) => {
            let conn = Store::connect(&args.dir.data_dir)?;
            let token = auth::revoke(&conn, args.id, wall_clock_s())?;
            eprintln!("token {} `{}` revoked", token.id, token.name);
            Ok(())
        }
    }
}
