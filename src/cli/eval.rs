//! `tunnelnav eval attitude [--seed N] ...`

use clap::{Args, Subcommand};

use super::CliError;
use super::simulate::{DriveArgs, PipeJackArgs, VehicleDriveArgs};
use crate::eval::attitude::{AttitudeEvalConfig, evaluate, render_table};
use crate::eval::{fuzzy, zupt};
use crate::fusion::Params;
use crate::fusion::attitude::PARAMS;
use crate::sim::tbm::Dropout;

#[derive(Debug, Subcommand)]
pub enum EvalTarget {
    /// The laser + inclinometer engine on a simulated TBM drive.
    Attitude(AttitudeArgs),
    /// The FOG INS with each zero-velocity detector on a simulated pipe-jacking drive.
    Zupt(ZuptArgs),
    /// The MEMS + magnetometer fuzzy expert on a simulated vehicle drive,
    /// against gyro-only, accelerometer-only and raw-compass solutions.
    Fuzzy(FuzzyArgs),
}

#[derive(Debug, Args)]
pub struct FuzzyArgs {
    #[command(flatten)]
    pub drive: VehicleDriveArgs,
    /// Seeds to run from --seed on (each a separate drive; a table each).
    #[arg(long, default_value_t = 1)]
    pub seeds: u64,
    /// An engine parameter as name=value (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Print the scores as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ZuptArgs {
    #[command(flatten)]
    pub drive: PipeJackArgs,
    /// Seeds to run from --seed on (each a separate drive; a table each).
    #[arg(long, default_value_t = 1)]
    pub seeds: u64,
    /// An engine parameter as name=value (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Print the scores as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct AttitudeArgs {
    /// The drive; without --dropout, one of 45 min at 7 h.
    #[command(flatten)]
    pub drive: DriveArgs,
    /// Hours of learning before scoring starts.
    #[arg(long, default_value_t = 1.0)]
    pub learning_h: f64,
    /// An engine parameter as name=value (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Print the scores as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(target: EvalTarget) -> Result<(), CliError> {
    match target {
        EvalTarget::Fuzzy(args) => {
            let params = Params::from_assignments(
                crate::fusion::fuzzy::PARAMS,
                args.params.iter().map(String::as_str),
            )?;
            each_seed(args.drive.seed, args.seeds, args.json, |seed| {
                let mut scenario = args.drive.scenario();
                scenario.seed = seed;
                let evaluation = fuzzy::evaluate(&fuzzy::FuzzyEvalConfig {
                    scenario,
                    params: params.clone(),
                })?;
                let table = fuzzy::render_table(&evaluation);
                Ok((serde_json::to_value(&evaluation), table))
            })
        }
        EvalTarget::Zupt(args) => {
            let params = Params::from_assignments(
                crate::fusion::zupt::PARAMS,
                args.params.iter().map(String::as_str),
            )?;
            each_seed(args.drive.seed, args.seeds, args.json, |seed| {
                let mut scenario = args.drive.scenario();
                scenario.seed = seed;
                let evaluation = zupt::evaluate(&zupt::ZuptEvalConfig {
                    scenario,
                    params: params.clone(),
                })?;
                let table = zupt::render_table(&evaluation);
                Ok((serde_json::to_value(&evaluation), table))
            })
        }
        EvalTarget::Attitude(args) => {
            let mut scenario = args.drive.scenario();
            if scenario.dropouts.is_empty() {
                scenario.dropouts.push(Dropout {
                    start_h: 7.0,
                    minutes: 45.0,
                });
            }
            let config = AttitudeEvalConfig {
                scenario,
                learning_h: args.learning_h,
                params: Params::from_assignments(PARAMS, args.params.iter().map(String::as_str))?,
            };
            let evaluation = evaluate(&config)?;
            if args.json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&evaluation).map_err(std::io::Error::other)?
                );
            } else {
                print!("{}", render_table(&evaluation));
            }
            Ok(())
        }
    }
}

/// Runs an evaluation for `seeds` seeds from `first`, printing each as a
/// JSON line or its table.
fn each_seed(
    first: u64,
    seeds: u64,
    json: bool,
    mut evaluate: impl FnMut(u64) -> Result<(serde_json::Result<serde_json::Value>, String), CliError>,
) -> Result<(), CliError> {
    for seed in first..first.saturating_add(seeds.max(1)) {
        let (value, table) = evaluate(seed)?;
        if json {
            println!("{}", value.map_err(std::io::Error::other)?);
        } else {
            print!("{table}");
        }
    }
    Ok(())
}
