//! Streams NDJSON readings through an engine (and the stages after it,
//! as a machine running it has) and writes the estimates as NDJSON.
//! Memory stays constant however long the input: a few batches of lines
//! are in flight, plus the bounded reorder buffer.
//!
//! Three threads share the work, in order and with bounded hand-overs:
//! one reads and parses lines, the caller's thread reorders and fuses
//! (the engines are the same deterministic code the server runs), one
//! formats and writes the estimates. The output is the same bytes as a
//! single thread would write.

use std::io::{self, BufRead, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

use serde::Serialize;

use crate::fusion::Reading;
use crate::fusion::estimate::{EngineOutput, EstimateWriter};
use crate::fusion::parse_reading;
use crate::fusion::pipeline::Pipeline;
use crate::fusion::reorder::{Admission, ReorderBuffer};

/// Estimates are written out in chunks of about this many bytes.
const FLUSH_BYTES: usize = 64 * 1024;
/// Longest input line read; a reading is a few hundred bytes, so a longer
/// line (a JSON array export, a binary file) is reported and skipped
/// without holding it in memory.
pub const MAX_LINE_BYTES: usize = 64 * 1024;
/// Lines parsed, or estimates made, per batch handed to the next thread.
const BATCH_LEN: usize = 256;
/// A batch of parsed lines also goes once its error messages hold this
/// many bytes (a rejected line's message may quote much of it).
const BATCH_MESSAGE_BYTES: usize = 64 * 1024;
/// Batches waiting between two threads; a faster thread waits beyond it.
const BATCHES_IN_FLIGHT: usize = 8;

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

/// One non-blank input line, parsed.
enum Line {
    Reading { number: u64, reading: Reading },
    Rejected { number: u64, why: String },
}

/// What the reading thread hands on: parsed lines, or the error that
/// ended the input early (not to be taken for its end).
type LineBatch = io::Result<Vec<Line>>;

/// Runs `pipeline` over the readings in `input`; estimates go to
/// `output`, one line per rejected input line goes to `errors`.
pub fn replay(
    input: impl BufRead + Send,
    output: impl Write + Send,
    mut errors: impl Write,
    pipeline: &mut Pipeline,
    options: &ReplayOptions,
) -> io::Result<ReplaySummary> {
    // Set when fusing has stopped, so the reading thread stops at its
    // next line rather than at its next full batch.
    let fusing_stopped = AtomicBool::new(false);
    std::thread::scope(|scope| {
        let (lines_tx, lines_rx) = sync_channel(BATCHES_IN_FLIGHT);
        let (outputs_tx, outputs_rx) = sync_channel(BATCHES_IN_FLIGHT);
        let stopped = &fusing_stopped;
        let reader = scope.spawn(move || read_lines(input, lines_tx, stopped));
        let machine = options.machine.as_str();
        let writer = scope.spawn(move || write_estimates(outputs_rx, output, machine));
        let fused = fuse(lines_rx, outputs_tx, &mut errors, pipeline, options);
        fusing_stopped.store(true, Ordering::Relaxed);
        // The writer ends when `fuse` has dropped its sender (or on an
        // error of its own); the reader when the input ends or fusing has
        // stopped.
        let written = writer
            .join()
            .unwrap_or_else(|p| std::panic::resume_unwind(p));
        reader
            .join()
            .unwrap_or_else(|p| std::panic::resume_unwind(p));
        // A failed input ends `fuse` with its error; a failed output ends
        // the writer with its own, and `fuse` with a closed hand-over,
        // its consequence.
        written?;
        let summary = fused?;
        errors.flush()?;
        Ok(summary)
    })
}

/// Reads and parses lines, handing them on in batches; a read error is
/// handed on last. Ends at the end of the input, on a read error, or
/// once fusing has stopped.
fn read_lines(input: impl BufRead, batches: SyncSender<LineBatch>, fusing_stopped: &AtomicBool) {
    let mut batch = Vec::with_capacity(BATCH_LEN);
    let read = parse_lines(input, &mut batch, &batches, fusing_stopped);
    // Nobody may be taking batches any more: then there is no one to tell.
    let _ = match read {
        Ok(()) if batch.is_empty() => Ok(()),
        Ok(()) => batches.send(Ok(batch)),
        Err(e) => batches.send(Ok(batch)).and_then(|()| batches.send(Err(e))),
    };
}

/// [`read_lines`]' loop: fills `batch`, sending it on when full.
fn parse_lines(
    mut input: impl BufRead,
    batch: &mut Vec<Line>,
    batches: &SyncSender<LineBatch>,
    fusing_stopped: &AtomicBool,
) -> io::Result<()> {
    let mut line = Vec::with_capacity(256);
    let mut number: u64 = 0;
    let mut message_bytes = 0;
    while !fusing_stopped.load(Ordering::Relaxed) {
        line.clear();
        let limit = MAX_LINE_BYTES as u64 + 1;
        if io::Read::take(&mut input, limit).read_until(b'\n', &mut line)? == 0 {
            break;
        }
        number += 1;
        let parsed = if line.len() > MAX_LINE_BYTES && line.last() != Some(&b'\n') {
            input.skip_until(b'\n')?;
            Line::Rejected {
                number,
                why: format!("longer than {MAX_LINE_BYTES} bytes, skipped (one reading per line)"),
            }
        } else {
            let text = line.trim_ascii();
            if text.is_empty() {
                continue;
            }
            match parse_reading(text) {
                Ok(reading) => Line::Reading { number, reading },
                Err(e) => Line::Rejected {
                    number,
                    why: e.to_string(),
                },
            }
        };
        if let Line::Rejected { why, .. } = &parsed {
            message_bytes += why.len();
        }
        batch.push(parsed);
        if batch.len() == BATCH_LEN || message_bytes >= BATCH_MESSAGE_BYTES {
            message_bytes = 0;
            let full = std::mem::replace(batch, Vec::with_capacity(BATCH_LEN));
            if batches.send(Ok(full)).is_err() {
                break;
            }
        }
    }
    Ok(())
}

/// Reorders and fuses the parsed lines, handing the estimates on in
/// batches; reports rejected and late lines to `errors`. Ends with the
/// input's error if it failed.
fn fuse(
    lines: Receiver<LineBatch>,
    estimates: SyncSender<Vec<EngineOutput>>,
    errors: &mut impl Write,
    pipeline: &mut Pipeline,
    options: &ReplayOptions,
) -> io::Result<ReplaySummary> {
    let mut summary = ReplaySummary::default();
    let mut reorder = ReorderBuffer::new(options.reorder_window_s, options.reorder_max_len);
    let mut ready = Vec::new();
    let mut batch = Vec::with_capacity(2 * BATCH_LEN);
    let writer_gone = || io::Error::other("the estimate writer stopped");
    for lines in lines {
        // An input that failed ends the replay here: what the engines
        // hold is not flushed as if the input had ended.
        for line in lines? {
            summary.lines += 1;
            let (number, reading) = match line {
                Line::Reading { number, reading } => (number, reading),
                Line::Rejected { number, why } => {
                    summary.invalid += 1;
                    writeln!(errors, "line {number}: {why}")?;
                    continue;
                }
            };
            summary.readings += 1;
            if !pipeline.uses(reading.sensor()) {
                summary.unused += 1;
                continue;
            }
            match reorder.push(reading) {
                Admission::Buffered | Admission::Duplicate => {}
                Admission::Late => writeln!(
                    errors,
                    "line {number}: dropped, older than a reading already fed to the engine"
                )?,
            }
            reorder.pop_ready(&mut ready);
            for reading in ready.drain(..) {
                pipeline.feed(&reading, &mut batch);
            }
            if batch.len() >= BATCH_LEN {
                summary.estimates += batch.len() as u64;
                let full = std::mem::replace(&mut batch, Vec::with_capacity(2 * BATCH_LEN));
                estimates.send(full).map_err(|_| writer_gone())?;
            }
        }
    }
    reorder.drain(&mut ready);
    for reading in ready.drain(..) {
        pipeline.feed(&reading, &mut batch);
    }
    // The end of the input: what the engines still hold comes out too.
    pipeline.flush(&mut batch);
    summary.estimates += batch.len() as u64;
    if !batch.is_empty() {
        estimates.send(batch).map_err(|_| writer_gone())?;
    }
    let stats = reorder.stats();
    summary.late = stats.late;
    summary.duplicates = stats.duplicates;
    Ok(summary)
}

/// Formats the estimates into one buffer and writes it in large chunks.
fn write_estimates(
    batches: Receiver<Vec<EngineOutput>>,
    mut output: impl Write,
    machine: &str,
) -> io::Result<()> {
    let mut writer = EstimateWriter::new(machine);
    let mut pending = Vec::with_capacity(FLUSH_BYTES + 4096);
    for batch in batches {
        for estimate in &batch {
            writer.write_line(estimate, &mut pending);
            if pending.len() >= FLUSH_BYTES {
                output.write_all(&pending)?;
                pending.clear();
            }
        }
    }
    output.write_all(&pending)?;
    output.flush()
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

    /// `count` inclinometer readings a second apart, as NDJSON.
    fn inclinometer_lines(count: u64) -> Vec<u8> {
        let mut input = Vec::new();
        for i in 0..count {
            let pitch = 0.5 + 0.001 * (i % 50) as f64;
            input.extend_from_slice(
                format!(
                    "{{\"t\":{},\"sensor\":\"inclinometer\",\"pitch_deg\":{pitch},\"roll_deg\":1}}\n",
                    1_772_431_200 + i
                )
                .as_bytes(),
            );
        }
        input
    }

    #[test]
    fn many_batches_come_out_in_order_as_one_thread_writes_them() {
        // Far more lines than the batches in flight hold.
        let count = (BATCH_LEN * BATCHES_IN_FLIGHT * 5 + 7) as u64;
        let input = inclinometer_lines(count);
        let mut out = Vec::new();
        let summary = replay(
            &input[..],
            &mut out,
            std::io::sink(),
            &mut engine(),
            &ReplayOptions::default(),
        )
        .unwrap();
        // The same readings fed and written on this thread, one by one.
        let mut pipeline = engine();
        let mut writer = EstimateWriter::new("replay");
        let (mut expected, mut outputs) = (Vec::new(), Vec::new());
        for line in input.split(|&b| b == b'\n').filter(|l| !l.is_empty()) {
            pipeline.feed(&parse_reading(line).unwrap(), &mut outputs);
        }
        pipeline.flush(&mut outputs);
        for output in &outputs {
            writer.write_line(output, &mut expected);
        }
        assert_eq!(summary.lines, count);
        assert_eq!(summary.estimates, outputs.len() as u64);
        assert!(out == expected, "the threaded replay wrote other bytes");
    }

    /// Takes `room` bytes, then refuses as a closed pipe does.
    struct ClosingPipe {
        room: usize,
    }

    impl Write for ClosingPipe {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            if self.room == 0 {
                return Err(io::ErrorKind::BrokenPipe.into());
            }
            let n = buf.len().min(self.room);
            self.room -= n;
            Ok(n)
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn a_closed_output_ends_the_replay_with_its_error() {
        let input = inclinometer_lines((BATCH_LEN * BATCHES_IN_FLIGHT * 8) as u64);
        let error = replay(
            &input[..],
            ClosingPipe { room: 100_000 },
            std::io::sink(),
            &mut engine(),
            &ReplayOptions::default(),
        )
        .unwrap_err();
        assert_eq!(error.kind(), io::ErrorKind::BrokenPipe);
    }

    /// Gives `lines` of input, then fails as a dropped connection does.
    struct FailingInput {
        lines: io::Cursor<Vec<u8>>,
    }

    impl io::Read for FailingInput {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            match self.lines.read(buf)? {
                0 => Err(io::ErrorKind::ConnectionReset.into()),
                n => Ok(n),
            }
        }
    }

    #[test]
    fn a_failing_input_ends_the_replay_with_its_error() {
        let input = io::BufReader::new(FailingInput {
            lines: io::Cursor::new(inclinometer_lines(3000)),
        });
        let error = replay(
            input,
            std::io::sink(),
            std::io::sink(),
            &mut engine(),
            &ReplayOptions::default(),
        )
        .unwrap_err();
        assert_eq!(error.kind(), io::ErrorKind::ConnectionReset);
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
