//! `tunnelnav replay --engine NAME [--param name=value ...] [--machine ID] FILE|-`, or `tunnelnav replay --machine DECLARATION.json FILE|-`

use std::fs::File;
use std::io::{self, BufReader, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;

use super::CliError;
use crate::config::{MachineDeclaration, MachineSpec};
use crate::fusion::EngineKind;
use crate::fusion::pipeline::Pipeline;
use crate::replay::{ReplayOptions, replay};

#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// Engine to run, and the stages a machine running it has after it
    /// (`zupt`: the `pushes` jacking log). Needed unless `--machine` names
    /// a declaration file.
    #[arg(long, value_enum)]
    pub engine: Option<EngineKind>,
    /// An engine parameter as name=value (repeatable); see `tunnelnav params`.
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Machine id written into the estimates; or a machine declaration,
    /// FILE.json (as `PUT /api/v1/machines/{id}` takes it: engines with
    /// their parameters, geometry, tolerances, start, alignment), whose
    /// engines and stages run, under the id of the file's stem.
    #[arg(long, default_value = "replay", value_name = "ID|FILE.json")]
    pub machine: String,
    /// Seconds readings are held to put them back in time order.
    #[arg(long, default_value_t = 10.0)]
    pub reorder_window_s: f64,
    /// NDJSON readings; - reads standard input.
    pub input: PathBuf,
}

/// The machine a declaration file declares, under its file's stem.
fn declared(path: &Path) -> Result<MachineSpec, CliError> {
    let text = std::fs::read_to_string(path).map_err(|source| CliError::File {
        context: format!("cannot read {}", path.display()),
        source,
    })?;
    let id = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("replay");
    serde_json::from_str::<MachineDeclaration>(&text)
        .map_err(|e| {
            CliError::Refused(format!(
                "{}: not a machine declaration: {e}",
                path.display()
            ))
        })?
        .validate(id)
        .map_err(|e| CliError::Refused(format!("{}: {e}", path.display())))
}

pub fn run(args: ReplayArgs) -> Result<(), CliError> {
    let (mut pipeline, machine) = if args.machine.ends_with(".json") {
        if args.engine.is_some() || !args.params.is_empty() {
            return Err(CliError::Refused(
                "--machine FILE.json declares the engines and their parameters: give no --engine or --param".into(),
            ));
        }
        let spec = declared(Path::new(&args.machine))?;
        (spec.pipeline()?, spec.id)
    } else {
        let kind = args.engine.ok_or_else(|| {
            CliError::Refused(
                "--engine is needed unless --machine names a declaration file (FILE.json)".into(),
            )
        })?;
        let params = kind.params_from_assignments(args.params.iter().map(String::as_str))?;
        (
            Pipeline::with_engines(vec![kind.create(params)?]),
            args.machine,
        )
    };
    let options = ReplayOptions {
        machine,
        reorder_window_s: args.reorder_window_s,
        ..ReplayOptions::default()
    };
    // The estimates are written in 64 KiB chunks by replay's writing thread.
    let out = io::stdout();
    let stderr = io::stderr();
    let mut err = stderr.lock();
    let started = Instant::now();
    let result = if args.input.as_os_str() == "-" {
        let stdin = BufReader::with_capacity(1 << 16, io::stdin());
        replay(stdin, out, &mut err, &mut pipeline, &options)
    } else {
        let file = File::open(&args.input).map_err(|source| CliError::File {
            context: format!("cannot open {}", args.input.display()),
            source,
        })?;
        replay(
            BufReader::with_capacity(1 << 16, file),
            out,
            &mut err,
            &mut pipeline,
            &options,
        )
    };
    let summary = match result {
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => return Ok(()),
        other => other?,
    };
    let elapsed = started.elapsed().as_secs_f64();
    writeln!(
        err,
        "replay summary: {summary}; {:.2} s ({:.0} lines/s)",
        elapsed,
        summary.lines as f64 / elapsed.max(1e-9)
    )?;
    Ok(())
}
