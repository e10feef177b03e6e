//! `tunnelnav params --engine NAME [--markdown]`

use std::io::{self, Write};

use clap::Args;

use super::CliError;
use crate::fusion::EngineKind;

#[derive(Debug, Args)]
pub struct ParamsArgs {
    /// Engine whose parameters to list.
    #[arg(long, value_enum)]
    pub engine: EngineKind,
    /// As a Markdown table (the one in docs/engines/).
    #[arg(long)]
    pub markdown: bool,
}

pub fn run(args: ParamsArgs) -> Result<(), CliError> {
    let kind = args.engine;
    let mut out = io::stdout().lock();
    let result = (|| -> io::Result<()> {
        if args.markdown {
            writeln!(out, "| parameter | default | unit | allowed | meaning |")?;
            writeln!(out, "|---|---|---|---|---|")?;
            for spec in kind.specs() {
                writeln!(
                    out,
                    "| `{}` | {} | {} | {} | {} |",
                    spec.name,
                    spec.default_value(),
                    spec.unit,
                    spec.range_text().replace('|', "\\|"),
                    spec.doc
                )?;
            }
            return Ok(());
        }
        writeln!(
            out,
            "{:<30} {:>10} {:<8} {:<28} meaning",
            "parameter", "default", "unit", "allowed"
        )?;
        for spec in kind.specs() {
            writeln!(
                out,
                "{:<30} {:>10} {:<8} {:<28} {}",
                spec.name,
                spec.default_value().to_string(),
                spec.unit,
                spec.range_text(),
                spec.doc
            )?;
        }
        Ok(())
    })();
    match result {
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}
