//! `tunnelnav replay --engine NAME [--param name=value ...] FILE|-`

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Write};
use std::path::PathBuf;
use std::time::Instant;

use clap::Args;

use super::CliError;
use crate::fusion::EngineKind;
use crate::fusion::pipeline::Pipeline;
use crate::replay::{ReplayOptions, replay};

#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// Engine to run; the stages a machine running it has run after it
    /// (`zupt`: the `pushes` jacking log).
    #[arg(long, value_enum)]
    pub engine: EngineKind,
    /// An engine parameter as name=value (repeatable); see `tunnelnav params`.
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Machine id written into the estimates.
    #[arg(long, default_value = "replay")]
    pub machine: String,
    /// Seconds readings are held to put them back in time order.
    #[arg(long, default_value_t = 10.0)]
    pub reorder_window_s: f64,
    /// NDJSON readings; - reads standard input.
    pub input: PathBuf,
}

pub fn run(args: ReplayArgs) -> Result<(), CliError> {
    let kind = args.engine;
    let params = kind.params_from_assignments(args.params.iter().map(String::as_str))?;
    let mut pipeline = Pipeline::with_engines(vec![kind.create(params)?]);
    let options = ReplayOptions {
        machine: args.machine,
        reorder_window_s: args.reorder_window_s,
        ..ReplayOptions::default()
    };
    let stdout = io::stdout();
    let out = BufWriter::with_capacity(1 << 16, stdout.lock());
    let stderr = io::stderr();
    let mut err = stderr.lock();
    let started = Instant::now();
    let result = if args.input.as_os_str() == "-" {
        let stdin = io::stdin();
        replay(stdin.lock(), out, &mut err, &mut pipeline, &options)
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
