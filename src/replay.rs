//! Streams NDJSON readings through an engine (and the stages after it,
//! as a machine running it has) and writes the estimates as NDJSON. Memory stays constant however long the input: one line is held
//! at a time, plus the bounded reorder buffer.

use std::io::{self, BufRead, Write};

use serde::Serialize;

use crate::fusion::estimate::EstimateWriter;
use crate::fusion::parse_reading;
use crate::fusion::pipeline::Pipeline;
use crate::fusion::reorder::{Admission, ReorderBuffer};

/// Estimates are written out in chunks of about this many bytes.
const FLUSH_BYTES: usize = 64 * 1024;
/// Longest input line read; a reading is a few hundred bytes, so a longer
/// line (a JSON array export, a binary file) is reported and skipped
/// without holding it in memory.
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// How to replay.
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    /// Machine id written into every estimate.
    pub machine: String,
    /// Readings are held this long to restore time order (see [`ReorderBuffer`]).
    pub reorder_window_s: f64,
    /// Most readings held by the reorder buffer.
    pub reorder_max_len: usize,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        ReplayOptions {
            machine: "replay".to_string(),
            reorder_window_s: 10.0,
            reorder_max_len: 100_000,
        }
    }
}

/// What a replay did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct ReplaySummary {
    /// Non-blank lines read.
    pub lines: u64,
    /// Valid readings.
    pub readings: u64,
    /// Lines rejected (reported on the error stream with their number).
    pub invalid: u64,
    /// Readings dropped as older than one already fed.
    pub late: u64,
    /// Readings dropped as a second reading of a sensor at the same time.
    pub duplicates: u64,
    /// Readings of sensors the engine does not use.
    pub unused: u64,
    /// Estimates written.
    pub estimates: u64,
}

impl std::fmt::Display for ReplaySummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} lines: {} readings, {} invalid, {} late, {} duplicates, {} for other engines; {} estimates",
            self.lines,
            self.readings,
            self.invalid,
            self.late,
            self.duplicates,
            self.unused,
            self.estimates
        )
    }
}

/// Runs `pipeline` over the readings in `input`; estimates go to
/// `output`, one line per rejected input line goes to `errors`.
pub fn replay(
    input: impl BufRead,
    mut output: impl Write,
    mut errors: impl Write,
    pipeline: &mut Pipeline,
    options: &ReplayOptions,
) -> io::Result<ReplaySummary> {
    let mut input = input;
    let mut summary = ReplaySummary::default();
    let mut reorder = ReorderBuffer::new(options.reorder_window_s, options.reorder_max_len);
    let mut line = Vec::with_capacity(256);
    let mut line_number: u64 = 0;
    let mut ready = Vec::new();
    let mut outputs = Vec::new();

    // Estimates are formatted into one buffer and written in large chunks.
    let mut pending = Vec::with_capacity(FLUSH_BYTES + 1024);
    let mut writer = EstimateWriter::new(&options.machine);
    let mut feed = |ready: &mut Vec<_>,
                    pipeline: &mut Pipeline,
                    pending: &mut Vec<u8>,
                    summary: &mut ReplaySummary|
     -> io::Result<()> {
        for reading in ready.drain(..) {
            outputs.clear();
            pipeline.feed(&reading, &mut outputs);
            for estimate in &outputs {
                writer.write_line(estimate, pending);
                summary.estimates += 1;
            }
        }
        Ok(())
    };

    loop {
        line.clear();
        let limit = MAX_LINE_BYTES as u64 + 1;
        if io::Read::take(&mut input, limit).read_until(b'\n', &mut line)? == 0 {
            break;
        }
        line_number += 1;
        if line.len() > MAX_LINE_BYTES && line.last() != Some(&b'\n') {
            input.skip_until(b'\n')?;
            summary.lines += 1;
            summary.invalid += 1;
            writeln!(
                errors,
                "line {line_number}: longer than {MAX_LINE_BYTES} bytes, skipped (one reading per line)"
            )?;
            continue;
        }
        let text = line.trim_ascii();
        if text.is_empty() {
            continue;
        }
        summary.lines += 1;
        let reading = match parse_reading(text) {
            Ok(r) => r,
            Err(e) => {
                summary.invalid += 1;
                writeln!(errors, "line {line_number}: {e}")?;
                continue;
            }
        };
        summary.readings += 1;
        if !pipeline.uses(reading.sensor()) {
            summary.unused += 1;
            continue;
        }
        match reorder.push(reading) {
            Admission::Buffered => {}
            Admission::Late => {
                writeln!(
                    errors,
                    "line {line_number}: dropped, older than a reading already fed to the engine"
                )?;
            }
            Admission::Duplicate => {}
        }
        reorder.pop_ready(&mut ready);
        feed(&mut ready, pipeline, &mut pending, &mut summary)?;
        if pending.len() >= FLUSH_BYTES {
            output.write_all(&pending)?;
            pending.clear();
        }
    }
    reorder.drain(&mut ready);
    feed(&mut ready, pipeline, &mut pending, &mut summary)?;
    // The end of the input: what the engines still hold comes out too.
    let mut held = Vec::new();
    pipeline.flush(&mut held);
    for estimate in &held {
        writer.write_line(estimate, &mut pending);
        summary.estimates += 1;
    }
    output.write_all(&pending)?;
    let stats = reorder.stats();
    summary.late = stats.late;
    summary.duplicates = stats.duplicates;
    output.flush()?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::EngineKind;
    use crate::fusion::Params;

    fn engine() -> Pipeline {
        Pipeline::new([(
            EngineKind::Attitude,
            &Params::defaults(EngineKind::Attitude.specs()),
        )])
        .unwrap()
    }

    #[test]
    fn an_overlong_line_is_skipped_without_being_held() {
        let mut input = Vec::new();
        input.extend_from_slice(
            b"{\"t\":1772431200,\"sensor\":\"inclinometer\",\"pitch_deg\":0.5,\"roll_deg\":1}\n[",
        );
        input.resize(input.len() + 3 * MAX_LINE_BYTES, b' ');
        input.extend_from_slice(
            b"]\n{\"t\":1772431201,\"sensor\":\"inclinometer\",\"pitch_deg\":0.5,\"roll_deg\":1}\n",
        );
        let mut err = Vec::new();
        let summary = replay(
            &input[..],
            std::io::sink(),
            &mut err,
            &mut engine(),
            &ReplayOptions::default(),
        )
        .unwrap();
        let err = String::from_utf8(err).unwrap();
        assert!(err.contains("line 2: longer than"), "{err}");
        assert_eq!(
            (summary.lines, summary.invalid, summary.estimates),
            (3, 1, 2)
        );
    }

    #[test]
    fn reports_bad_lines_and_keeps_going() {
        let input = "\
{\"t\":1772431200,\"sensor\":\"inclinometer\",\"pitch_deg\":0.5,\"roll_deg\":1}
not json
{\"t\":1772431201,\"sensor\":\"inclinometer\",\"pitch_deg\":95,\"roll_deg\":1}

{\"t\":1772431202,\"sensor\":\"imu\",\"accel_mps2\":[0,0,-9.8],\"gyro_dps\":[0,0,0]}
{\"t\":1772431203,\"sensor\":\"inclinometer\",\"pitch_deg\":0.5,\"roll_deg\":1}
{\"t\":1772431203,\"sensor\":\"inclinometer\",\"pitch_deg\":0.5,\"roll_deg\":1}
";
        let mut out = Vec::new();
        let mut err = Vec::new();
        let summary = replay(
            input.as_bytes(),
            &mut out,
            &mut err,
            &mut engine(),
            &ReplayOptions::default(),
        )
        .unwrap();
        let err = String::from_utf8(err).unwrap();
        assert!(err.contains("line 2: invalid JSON"), "{err}");
        assert!(err.contains("line 3: field `pitch_deg` = 95"), "{err}");
        assert_eq!(
            summary,
            ReplaySummary {
                lines: 6,
                readings: 4,
                invalid: 2,
                late: 0,
                duplicates: 1,
                unused: 1,
                estimates: 2
            }
        );
        let out = String::from_utf8(out).unwrap();
        assert_eq!(out.lines().count(), 2);
        assert!(out.lines().all(|l| l.contains("\"machine\":\"replay\"")));
    }
}
