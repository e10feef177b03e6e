//! `tunnelnav eval attitude [--seed N] ...`

use clap::{Args, Subcommand};

use super::CliError;
use crate::eval::attitude::{AttitudeEvalConfig, evaluate, render_table};
use crate::fusion::Params;
use crate::fusion::attitude::PARAMS;
use crate::sim::tbm::{DEFAULT_START_T, Dropout, TbmScenario};

#[derive(Debug, Subcommand)]
pub enum EvalTarget {
    /// The laser + inclinometer engine on a simulated TBM drive.
    Attitude(AttitudeArgs),
}

#[derive(Debug, Args)]
pub struct AttitudeArgs {
    /// Random seed of the simulated drive.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Length of the drive in hours.
    #[arg(long, default_value_t = 10.0)]
    pub hours: f64,
    /// Inclinometer period in seconds.
    #[arg(long, default_value_t = 1.0)]
    pub incl_period_s: f64,
    /// Laser period in seconds.
    #[arg(long, default_value_t = 120.0)]
    pub laser_period_s: f64,
    /// Laser dropouts as START_H:MINUTES (default: one of 45 min at 7 h).
    #[arg(long = "dropout", value_name = "START_H:MINUTES")]
    pub dropouts: Vec<Dropout>,
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
        EvalTarget::Attitude(args) => {
            let dropouts = if args.dropouts.is_empty() {
                vec![Dropout {
                    start_h: 7.0,
                    minutes: 45.0,
                }]
            } else {
                args.dropouts
            };
            let config = AttitudeEvalConfig {
                scenario: TbmScenario {
                    seed: args.seed,
                    start_t: DEFAULT_START_T,
                    hours: args.hours,
                    incl_period_s: args.incl_period_s,
                    laser_period_s: args.laser_period_s,
                    dropouts,
                },
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
