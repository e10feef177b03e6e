//! `tunnelnav eval attitude [--seed N] ...`

use clap::{Args, Subcommand};

use super::CliError;
use super::simulate::{DriveArgs, PipeJackArgs, VehicleDriveArgs};
use crate::eval::attitude::{
    AttitudeEvalConfig, Drive, KF3_NOISE, ORACLE_NOISE, evaluate, evaluate_all, render_summary,
    render_table, summarise,
};
use crate::eval::kf3::Kf3Noise;
use crate::eval::{fuzzy, fuzzy_envelope, zupt, zupt_envelope};
use crate::fusion::{EngineKind, Params};
use crate::sim::tbm::Dropout;
use crate::sim::tbm_envelope::EnvelopeDrive;

#[derive(Debug, Subcommand)]
pub enum EvalTarget {
    /// The laser + inclinometer engine on a simulated TBM drive.
    Attitude(AttitudeArgs),
    /// The FOG INS with each zero-velocity detector on a simulated pipe-jacking drive.
    Zupt(ZuptArgs),
    /// The MEMS + magnetometer fuzzy expert on a simulated vehicle drive,
    /// against gyro-only, accelerometer-only and raw-compass solutions and
    /// the Madgwick (β tuned with the truth) and Mahony filters.
    Fuzzy(FuzzyArgs),
    /// The fuzzy engine on recorded trials (BROAD-style CSVs made by
    /// tools/broad_to_csv.py) with optical truth, against gyro-only,
    /// accelerometer + compass and Madgwick.
    Recording(RecordingArgs),
    /// The `dta` stream (deviation from the design axis) end to end:
    /// simulated TBM drives along random axes with known deviations,
    /// through the `attitude` engine and the `dta` stage (`--source
    /// laser`), or simulated pipe-jacking field drives along a straight
    /// axis through the `zupt` engine, scored also against the INS's own
    /// σ (`--source zupt`).
    Dta(DtaArgs),
    /// The ring build plan (issue 60) on simulated drives: built axis,
    /// clearance, keys and cost against a brute-force 3-ring look-ahead
    /// and the naive rule (the key that turns toward the axis).
    Rings(RingsArgs),
}

#[derive(Debug, Args)]
pub struct RingsArgs {
    /// First seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Drives, each drawn from its seed, from --seed on.
    #[arg(long, default_value_t = 40)]
    pub seeds: u64,
    /// Print {"summary", "drives"} as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Where the `dta` positions come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DtaSourceArg {
    /// Laser positions turned by the `attitude` engine (TBM drives).
    Laser,
    /// The `zupt` INS's positions from the declared start (pipe jacking).
    Zupt,
}

#[derive(Debug, Args)]
pub struct DtaArgs {
    /// Which source's positions to score.
    #[arg(long, value_enum, default_value_t = DtaSourceArg::Laser)]
    pub source: DtaSourceArg,
    /// First seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Drives, each drawn from its seed, from --seed on.
    #[arg(long, default_value_t = 20)]
    pub seeds: u64,
    /// A parameter of the source's engine (`attitude` or `zupt`) as
    /// name=value (repeatable). The `zupt` machine runs with
    /// odometer_aiding=true unless told; its latitude_deg and
    /// initial_yaw_deg are always the drive's.
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// 1σ of each coordinate of the laser's position, mm (the envelope's
    /// is 1 mm; 0 leaves only the attitude's part of the error). Laser
    /// source only.
    #[arg(long)]
    pub position_sigma_mm: Option<f64>,
    /// Length of each pipe-jacking field drive, hours. Zupt source only
    /// (default 1).
    #[arg(long)]
    pub field_hours: Option<f64>,
    /// Print the scores as JSON instead of a table: a line per drive, then
    /// {"summary": ...}.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct RecordingArgs {
    /// Directory of trial CSVs and their manifest.json.
    #[arg(long)]
    pub dir: std::path::PathBuf,
    /// An engine parameter as name=value (repeatable), on top of what the
    /// documentation (docs/engines/fuzzy.md) tells an installer (window of half a second at the
    /// recording's rate, the site's inclination).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Print the scores as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct FuzzyArgs {
    #[command(flatten)]
    pub drive: VehicleDriveArgs,
    /// Seeds to run from --seed on (each a separate drive; a table each,
    /// then, for more than one, the median and worst over them). Default:
    /// 1, or 40 with --envelope (a line per drive beside the baselines,
    /// the median and worst, the bars).
    #[arg(long)]
    pub seeds: Option<u64>,
    /// An engine parameter as name=value (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Print the scores as JSON instead of a table: a line per seed, then
    /// (for more than one) a line {"summary": ...}; with --envelope one
    /// object {"summary", "drives"}.
    #[arg(long)]
    pub json: bool,
    /// With --envelope: inject this fault into every drive, each fault a
    /// category of its own figures (docs/evaluation.md, "Faults").
    #[arg(long, value_enum, requires = "envelope")]
    pub fault: Option<crate::sim::faults::FaultKind>,
}

#[derive(Debug, Args)]
pub struct ZuptArgs {
    #[command(flatten)]
    pub drive: PipeJackArgs,
    /// Drives drawn from the whole envelope (`simulate pipe-jacking
    /// --envelope`) instead of a case: --seeds of them from --seed on, each
    /// run by the engine, the paper's detector and an oracle fed the true
    /// zero-velocity flags; a line per drive, the median and worst, the bars.
    #[arg(long, conflicts_with_all = ["case", "push_s", "rest_s", "machinery"])]
    pub envelope: bool,
    /// Seeds to run from --seed on (each a separate drive; a table each).
    /// Default: 1, or 40 with --envelope.
    #[arg(long)]
    pub seeds: Option<u64>,
    /// An engine parameter as name=value (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Print the scores as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// With --envelope: inject this fault into every drive, each fault a
    /// category of its own figures (docs/evaluation.md, "Faults").
    #[arg(long, value_enum, requires = "envelope")]
    pub fault: Option<crate::sim::faults::FaultKind>,
}

#[derive(Debug, Args)]
pub struct AttitudeArgs {
    /// The drive; without --dropout, one of 45 min at 7 h.
    #[command(flatten)]
    pub drive: DriveArgs,
    /// Drives drawn from the whole envelope (`simulate tbm --envelope`)
    /// instead of the fixed scenario: --seeds of them from --seed on,
    /// summarised as median and worst beside every baseline.
    #[arg(long, conflicts_with_all = ["hours", "incl_period_s", "laser_period_s", "dropouts"])]
    pub envelope: bool,
    /// How many envelope drives (with --envelope).
    #[arg(long, default_value_t = 40, requires = "envelope")]
    pub seeds: u64,
    /// Hours of learning before scoring starts.
    #[arg(long, default_value_t = 1.0)]
    pub learning_h: f64,
    /// An engine parameter as name=value (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Process noise of the kf3 baseline, deg²/s³ and deg²/s.
    #[arg(long, value_name = "Q_RATE:Q_BIAS", value_parser = parse_noise)]
    pub kf3_noise: Option<Kf3Noise>,
    /// Process noise of the oracle, deg²/s³ and deg²/s.
    #[arg(long, value_name = "Q_RATE:Q_BIAS", value_parser = parse_noise)]
    pub oracle_noise: Option<Kf3Noise>,
    /// Print the scores as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// With --envelope: inject this fault into every drive, each fault a
    /// category of its own figures (docs/evaluation.md, "Faults").
    #[arg(long, value_enum, requires = "envelope")]
    pub fault: Option<crate::sim::faults::FaultKind>,
}

fn parse_noise(text: &str) -> Result<Kf3Noise, String> {
    let (a, b) = text
        .split_once(':')
        .ok_or_else(|| format!("`{text}`: expected Q_RATE:Q_BIAS, e.g. 1e-9:1e-7"))?;
    let number = |s: &str| match s.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 0.0 => Ok(x),
        _ => Err(format!("`{s}` is not a number ≥ 0")),
    };
    Ok(Kf3Noise {
        q_rate: number(a)?,
        q_bias: number(b)?,
    })
}

pub fn run(target: EvalTarget) -> Result<(), CliError> {
    match target {
        EvalTarget::Fuzzy(args) => {
            let params = Params::from_assignments(
                crate::fusion::fuzzy::PARAMS,
                args.params.iter().map(String::as_str),
            )?;
            if args.drive.envelope {
                let seeds: Vec<u64> =
                    envelope_seeds(args.drive.seed, args.seeds.unwrap_or(40)).collect();
                let drives = fuzzy_envelope::evaluate_all_with(
                    &seeds,
                    &params,
                    args.fault,
                    args.drive.category,
                    cores(),
                )?;
                let summary = fuzzy_envelope::summarise(&drives);
                return print_envelope(args.json, &summary, &drives, || {
                    fuzzy_envelope::render(&drives, &summary)
                });
            }
            let mut evaluations = Vec::new();
            each_seed(
                args.drive.seed,
                args.seeds.unwrap_or(1),
                args.json,
                |seed| {
                    let mut scenario = args.drive.scenario();
                    scenario.seed = seed;
                    let evaluation = fuzzy::evaluate(&fuzzy::FuzzyEvalConfig {
                        scenario,
                        params: params.clone(),
                    })?;
                    let table = fuzzy::render_table(&evaluation);
                    let value = serde_json::to_value(&evaluation);
                    evaluations.push(evaluation);
                    Ok((value, table))
                },
            )?;
            if evaluations.len() > 1 {
                let summary = fuzzy::summarise(&evaluations);
                if args.json {
                    let value = serde_json::json!({ "summary": summary });
                    println!(
                        "{}",
                        serde_json::to_string(&value).map_err(std::io::Error::other)?
                    );
                } else {
                    print!("{}", fuzzy::render_summary(&summary));
                }
            }
            Ok(())
        }
        EvalTarget::Rings(args) => {
            let seeds: Vec<u64> = envelope_seeds(args.seed, args.seeds).collect();
            let drives = crate::eval::parallel_map(&seeds, cores(), |&seed| {
                crate::eval::rings::evaluate(seed)
            })
            .into_iter()
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| CliError::Scenario(e.to_string()))?;
            let summary = crate::eval::rings::summarise(&drives);
            print_envelope(args.json, &summary, &drives, || {
                crate::eval::rings::render(&drives, &summary)
            })
        }
        EvalTarget::Dta(args) if args.source == DtaSourceArg::Zupt => run_dta_zupt(&args),
        EvalTarget::Dta(args) => {
            if args.field_hours.is_some() {
                return Err(CliError::Scenario(
                    "--field-hours is for --source zupt".into(),
                ));
            }
            let params = EngineKind::Attitude
                .params_from_assignments(args.params.iter().map(String::as_str))?;
            let mut scores = Vec::new();
            for seed in args.seed..args.seed.saturating_add(args.seeds.max(1)) {
                let mut scenario = crate::sim::axis_drive::AxisDriveScenario::draw(seed);
                if let Some(sigma) = args.position_sigma_mm {
                    scenario.position_sigma_mm = sigma;
                }
                let score =
                    crate::eval::dta::evaluate(&scenario, &params).map_err(CliError::Scenario)?;
                if args.json {
                    println!(
                        "{}",
                        serde_json::to_string(&score).map_err(std::io::Error::other)?
                    );
                }
                scores.push(score);
            }
            let summary = crate::eval::dta::summarise(&scores);
            if args.json {
                let value = serde_json::json!({ "summary": summary });
                println!(
                    "{}",
                    serde_json::to_string(&value).map_err(std::io::Error::other)?
                );
            } else {
                print!("{}", crate::eval::dta::render(&scores, &summary));
            }
            Ok(())
        }
        EvalTarget::Recording(args) => {
            use crate::eval::recording;
            let rate_hz = recording::recording_rate_hz(&args.dir)?;
            let words: Vec<&str> = args.params.iter().map(String::as_str).collect();
            let params = recording::installer_params(rate_hz, &words)?;
            let evaluation = recording::evaluate_recording(&args.dir, &params)?;
            if args.json {
                println!(
                    "{}",
                    serde_json::to_string(&evaluation)
                        .map_err(|e| CliError::Scenario(format!("JSON: {e}")))?
                );
            } else {
                print!("{}", recording::render_table(&evaluation));
            }
            Ok(())
        }
        EvalTarget::Zupt(args) => {
            let params = Params::from_assignments(
                crate::fusion::zupt::PARAMS,
                args.params.iter().map(String::as_str),
            )?;
            if args.envelope {
                let seeds: Vec<u64> =
                    envelope_seeds(args.drive.seed, args.seeds.unwrap_or(40)).collect();
                let drives =
                    zupt_envelope::evaluate_all_with(&seeds, &params, args.fault, cores())?;
                let summary = zupt_envelope::summarise(&drives);
                return print_envelope(args.json, &summary, &drives, || {
                    zupt_envelope::render(&drives, &summary)
                });
            }
            each_seed(
                args.drive.seed,
                args.seeds.unwrap_or(1),
                args.json,
                |seed| {
                    let mut scenario = args.drive.scenario();
                    scenario.seed = seed;
                    let evaluation = zupt::evaluate(&zupt::ZuptEvalConfig {
                        scenario,
                        params: params.clone(),
                    })?;
                    let table = zupt::render_table(&evaluation);
                    Ok((serde_json::to_value(&evaluation), table))
                },
            )
        }
        EvalTarget::Attitude(args) => {
            let params = EngineKind::Attitude
                .params_from_assignments(args.params.iter().map(String::as_str))?;
            let configure = |drive: Drive| AttitudeEvalConfig {
                learning_h: args.learning_h,
                params: params.clone(),
                kf3_noise: args.kf3_noise.unwrap_or(KF3_NOISE),
                oracle_noise: args.oracle_noise.unwrap_or(ORACLE_NOISE),
                fault: args.fault,
                ..AttitudeEvalConfig::on(drive)
            };
            if args.envelope {
                let first = args.drive.seed;
                let configs: Vec<AttitudeEvalConfig> = envelope_seeds(first, args.seeds)
                    .map(|seed| configure(Drive::Envelope(Box::new(EnvelopeDrive::draw(seed)))))
                    .collect();
                let evaluations = evaluate_all(&configs, cores())?;
                let summary = summarise(&evaluations);
                return print_envelope(args.json, &summary, &evaluations, || {
                    let mut text: String = evaluations.iter().map(render_table).collect();
                    text.push_str(&render_summary(&summary, first));
                    text
                });
            }
            let mut scenario = args.drive.scenario();
            if scenario.dropouts.is_empty() {
                scenario.dropouts.push(Dropout {
                    start_h: 7.0,
                    minutes: 45.0,
                });
            }
            let evaluation = evaluate(&configure(Drive::Fixed(scenario)))?;
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

/// `eval dta --source zupt`: each seed's drive through the `zupt` engine
/// and the `dta` stage, a JSON line each or a table at the end.
fn run_dta_zupt(args: &DtaArgs) -> Result<(), CliError> {
    use crate::eval::dta_ins;
    if args.position_sigma_mm.is_some() {
        return Err(CliError::Scenario(
            "--position-sigma-mm is for --source laser".into(),
        ));
    }
    let hours = args
        .field_hours
        .unwrap_or(dta_ins::FIELD_DURATION_S / 3600.0);
    let params = EngineKind::Zupt.params_from_assignments(
        dta_ins::DEFAULT_ASSIGNMENTS
            .into_iter()
            .chain(args.params.iter().map(String::as_str)),
    )?;
    let mut scores = Vec::new();
    for seed in args.seed..args.seed.saturating_add(args.seeds.max(1)) {
        let scenario = dta_ins::ZuptDtaScenario::draw(seed, hours * 3600.0);
        let score = dta_ins::evaluate(&scenario, &params).map_err(CliError::Scenario)?;
        if args.json {
            println!(
                "{}",
                serde_json::to_string(&score).map_err(std::io::Error::other)?
            );
        }
        scores.push(score);
    }
    let summary = dta_ins::summarise(&scores);
    if args.json {
        let value = serde_json::json!({ "summary": summary });
        println!(
            "{}",
            serde_json::to_string(&value).map_err(std::io::Error::other)?
        );
    } else {
        print!("{}", dta_ins::render(&scores, &summary));
    }
    Ok(())
}

/// Runs an evaluation for `seeds` seeds from `first`, printing each as a
/// JSON line or its table.
/// `count` seeds (at least one) from `first` on.
fn envelope_seeds(first: u64, count: u64) -> std::ops::Range<u64> {
    first..first.saturating_add(count.max(1))
}

/// Threads for the evaluations: one per core.
fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, usize::from)
}

/// An envelope evaluation on stdout: `{"summary", "drives"}` as JSON, or
/// the text `table` makes.
fn print_envelope(
    json: bool,
    summary: &impl serde::Serialize,
    drives: &impl serde::Serialize,
    table: impl FnOnce() -> String,
) -> Result<(), CliError> {
    if json {
        let value = serde_json::json!({"summary": summary, "drives": drives});
        println!(
            "{}",
            serde_json::to_string_pretty(&value).map_err(std::io::Error::other)?
        );
    } else {
        print!("{}", table());
    }
    Ok(())
}

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
