//! The command line: one file per subcommand, each with a `run`.

pub mod backup;
pub mod demo;
pub mod eval;
pub mod load;
pub mod migrate;
pub mod params;
pub mod replay;
pub mod serve;
pub mod simulate;
pub mod site;
pub mod token;

use clap::{Parser, Subcommand};

/// Live attitude and position fusion for tunnel boring and pipe-jacking machines.
#[derive(Debug, Parser)]
#[command(name = "tunnelnav", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Simulate a drive: protocol NDJSON readings on stdout, truth to a file.
    #[command(subcommand)]
    Simulate(simulate::Scenario),
    /// Run an engine over NDJSON readings (a file or - for stdin); estimates on stdout.
    Replay(replay::ReplayArgs),
    /// Simulate, run an engine and its baselines, and score them against the truth.
    #[command(subcommand)]
    Eval(eval::EvalTarget),
    /// List an engine's parameters with their defaults and ranges.
    Params(params::ParamsArgs),
    /// Run the HTTP server: ingest, fusion, history, live stream.
    Serve(serve::ServeArgs),
    /// Load a server with concurrent gateways; report throughput and latency.
    Load(load::LoadArgs),
    /// The server with simulated machines and gateways at an accelerated clock.
    Demo(demo::DemoArgs),
    /// An online copy of the database, while the server runs.
    Backup(backup::BackupArgs),
    /// Access tokens: create, list, revoke.
    #[command(subcommand)]
    Token(token::TokenCommand),
    /// Move a site's SQLite store into an empty PostgreSQL database, verified.
    Migrate(migrate::MigrateArgs),
    /// An office's sites: set a site's machine's mark back (audited).
    #[command(subcommand)]
    Site(site::SiteCommand),
}

/// Why a command failed.
#[derive(Debug, thiserror::Error)]
pub enum CliError {
    #[error("{0}")]
    Io(#[from] std::io::Error),
    #[error("{context}: {source}")]
    File {
        context: String,
        source: std::io::Error,
    },
    #[error(transparent)]
    Params(#[from] crate::fusion::ParamError),
    #[error(transparent)]
    Eval(#[from] crate::eval::attitude::EvalError),
    #[error(transparent)]
    EvalZupt(#[from] crate::eval::zupt::ZuptEvalError),
    #[error(transparent)]
    EvalFuzzy(#[from] crate::eval::fuzzy::FuzzyEvalError),
    #[error(transparent)]
    EvalRecording(#[from] crate::eval::recording::RecordingError),
    #[error("{0}")]
    Scenario(String),
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    #[error(transparent)]
    Settings(#[from] crate::server::settings::SettingsError),
    #[error(transparent)]
    Server(#[from] crate::server::ServerError),
    #[error(transparent)]
    Store(#[from] crate::store::StoreError),
    #[error(transparent)]
    ClusterKey(#[from] crate::server::signing::KeyFileError),
    #[error("{0}")]
    Refused(String),
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> Result<(), CliError> {
    match cli.command {
        Command::Simulate(scenario) => simulate::run(scenario),
        Command::Replay(args) => replay::run(args),
        Command::Eval(target) => eval::run(target),
        Command::Params(args) => params::run(args),
        Command::Serve(args) => serve::run(args),
        Command::Load(args) => load::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Token(command) => token::run(command),
        Command::Backup(args) => backup::run(args),
        Command::Migrate(args) => migrate::run(args),
        Command::Site(command) => site::run(command),
    }
}
