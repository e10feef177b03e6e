//! `tunnelnav simulate ...`

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::PathBuf;

use clap::{Args, Subcommand};

use super::CliError;
use crate::fusion::SensorKind;
use crate::sim::tbm::{DEFAULT_START_T, Dropout, TbmDrive, TbmScenario};

#[derive(Debug, Subcommand)]
pub enum Scenario {
    /// A TBM drive: excavation and ring building, laser + inclinometer.
    Tbm(TbmArgs),
}

/// The simulated drive: shared by `simulate tbm` and `eval attitude`.
#[derive(Debug, Args)]
pub struct DriveArgs {
    /// Length of the drive in hours.
    #[arg(long, default_value_t = 10.0)]
    pub hours: f64,
    /// Inclinometer period in seconds.
    #[arg(long, default_value_t = 1.0)]
    pub incl_period_s: f64,
    /// Laser period in seconds (the paper's system: 120).
    #[arg(long, default_value_t = 120.0)]
    pub laser_period_s: f64,
    /// A laser dropout as START_H:MINUTES (repeatable), e.g. 7:45.
    #[arg(long = "dropout", value_name = "START_H:MINUTES")]
    pub dropouts: Vec<Dropout>,
    /// Random seed: the same seed gives the same drive.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Unix seconds of the first reading.
    #[arg(long, default_value_t = DEFAULT_START_T)]
    pub start_t: f64,
}

impl DriveArgs {
    /// The scenario these arguments describe.
    pub fn scenario(&self) -> TbmScenario {
        TbmScenario {
            seed: self.seed,
            start_t: self.start_t,
            hours: self.hours,
            incl_period_s: self.incl_period_s,
            laser_period_s: self.laser_period_s,
            dropouts: self.dropouts.clone(),
        }
    }
}

#[derive(Debug, Args)]
pub struct TbmArgs {
    #[command(flatten)]
    pub drive: DriveArgs,
    /// Write the truth (one NDJSON line per inclinometer reading) to this file.
    #[arg(long, value_name = "FILE")]
    pub truth: Option<PathBuf>,
}

pub fn run(scenario: Scenario) -> Result<(), CliError> {
    match scenario {
        Scenario::Tbm(args) => run_tbm(&args),
    }
}

fn run_tbm(args: &TbmArgs) -> Result<(), CliError> {
    let drive = TbmDrive::new(args.drive.scenario()).map_err(CliError::Scenario)?;
    let mut truth = match &args.truth {
        Some(path) => Some(BufWriter::new(File::create(path).map_err(|source| {
            CliError::File {
                context: format!("cannot create truth file {}", path.display()),
                source,
            }
        })?)),
        None => None,
    };
    let stdout = io::stdout();
    let mut out = BufWriter::with_capacity(1 << 16, stdout.lock());
    let result = (|| -> io::Result<()> {
        for event in drive {
            serde_json::to_writer(&mut out, &event.reading)?;
            out.write_all(b"\n")?;
            if let Some(truth) = truth.as_mut()
                && event.reading.sensor() == SensorKind::Inclinometer
            {
                serde_json::to_writer(&mut *truth, &event.truth)?;
                truth.write_all(b"\n")?;
            }
        }
        out.flush()?;
        if let Some(truth) = truth.as_mut() {
            truth.flush()?;
        }
        Ok(())
    })();
    match result {
        // A reader that stops early (`| head`) is not an error.
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}
