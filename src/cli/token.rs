//! `tunnelnav token create|list|revoke --data-dir DIR | --store URL`:
//! access tokens, stored hashed in the server's database (a running server
//! picks changes up within 2 s).

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
    /// The server's data directory (its SQLite store).
    #[arg(long, default_value = "data")]
    pub data_dir: PathBuf,
    /// The server's PostgreSQL store instead, `postgres://USER@HOST:PORT/DB`.
    #[arg(long, env = "TUNNELNAV_STORE", value_name = "URL")]
    pub store: Option<String>,
    /// A file whose first line is the store's password.
    #[arg(long, env = "TUNNELNAV_STORE_PASSWORD_FILE", value_name = "FILE")]
    pub store_password_file: Option<PathBuf>,
    /// The CA (PEM) the store's certificate is checked against (TLS).
    #[arg(long, env = "TUNNELNAV_STORE_CA_FILE", value_name = "FILE")]
    pub store_ca_file: Option<PathBuf>,
}

/// The server's store, where the tokens are (SQLite beside a running
/// server: WAL lets both write), and a runtime to wait on it.
struct Tokens {
    store: Store,
    runtime: tokio::runtime::Runtime,
}

impl Tokens {
    fn open(dir: &DataDir) -> Result<Tokens, CliError> {
        let location = crate::server::settings::store_location(
            dir.store.as_deref(),
            crate::server::settings::StoreFiles {
                password_file: dir.store_password_file.as_deref(),
                ca_file: dir.store_ca_file.as_deref(),
            },
            &Default::default(),
        )?;
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?;
        let store = runtime.block_on(Store::open_client(&dir.data_dir, location.as_ref()))?;
        Ok(Tokens { store, runtime })
    }

    fn create(
        &self,
        name: &str,
        scope: Scope,
        machine: Option<&str>,
    ) -> Result<(i64, String), CliError> {
        let now = wall_clock_s();
        Ok(self
            .runtime
            .block_on(self.store.create_token(name, scope, machine, now))?)
    }

    fn list(&self) -> Result<Vec<auth::Token>, CliError> {
        Ok(self.runtime.block_on(self.store.tokens())?)
    }

    fn revoke(&self, id: i64) -> Result<auth::Token, CliError> {
        let now = wall_clock_s();
        Ok(self.runtime.block_on(self.store.revoke_token(id, now))?)
    }
}

#[derive(Debug, Args)]
pub struct CreateArgs {
    #[command(flatten)]
    pub dir: DataDir,
    /// ingest (one machine's gateway), read (dashboard, history; changes
    /// nothing), operator (read, and acknowledge alarms), admin, or site
    /// (a site server forwarding to this office).
    #[arg(long, value_parser = parse_scope)]
    pub scope: Scope,
    /// The machine an ingest token may send readings for.
    #[arg(long, conflicts_with = "site")]
    pub machine: Option<String>,
    /// The site a site token may forward as (`serve --site` there).
    #[arg(long)]
    pub site: Option<String>,
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
    Scope::from_name(text)
        .ok_or_else(|| format!("`{text}`: expected ingest, read, operator, admin or site"))
}

pub fn run(command: TokenCommand) -> Result<(), CliError> {
    match command {
        TokenCommand::Create(args) => {
            let tokens = Tokens::open(&args.dir)?;
            // A site token names its site where an ingest token names its
            // machine.
            let subject = args.machine.as_ref().or(args.site.as_ref());
            if args.site.is_some() && args.scope != Scope::Site {
                return Err(CliError::Refused(
                    "--site is for `--scope site` tokens".into(),
                ));
            }
            if args.machine.is_some() && args.scope == Scope::Site {
                return Err(CliError::Refused(
                    "a site token names its site with --site, not --machine".into(),
                ));
            }
            let name = if args.name.is_empty() {
                match subject {
                    Some(machine) => format!("{} {machine}", args.scope.as_str()),
                    None => args.scope.as_str().to_string(),
                }
            } else {
                args.name.clone()
            };
            let (id, token) = tokens.create(&name, args.scope, subject.map(String::as_str))?;
            eprintln!(
                "token {id} `{name}` ({}) created; it is shown only now:",
                args.scope.as_str()
            );
            println!("{token}");
            Ok(())
        }
        TokenCommand::List(dir) => {
            let tokens = Tokens::open(&dir)?;
            println!(
                "{:>4}  {:<8} {:<20} {:<24} state",
                "id", "scope", "machine/site", "name"
            );
            for t in tokens.list()? {
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
            let token = Tokens::open(&args.dir)?.revoke(args.id)?;
            eprintln!("token {} `{}` revoked", token.id, token.name);
            Ok(())
        }
    }
}
