//! What a shift report holds: the advance, the largest deviations, the
//! rings and pushes, the alarms, the laser's dropouts and the chart's
//! points (gathered by `mod.rs`, written by `csv.rs`, `layout.rs` and
//! `pdf.rs`).

use serde::Serialize;

use crate::fusion::Integrity;
use crate::fusion::pushes::PushRecord;
use crate::fusion::rings::RingRecord;
use crate::store::alarms::StoredAlarm;

/// The advance over the range.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Advance {
    /// Rings (or pipes) completed: `advance` readings in the range.
    pub rings: u64,
    pub first_ring: Option<u64>,
    pub last_ring: Option<u64>,
    /// Station of the reference point at the first and the last `dta`
    /// estimate of the range; `null` without one.
    pub start_station_m: Option<f64>,
    pub end_station_m: Option<f64>,
    /// The station gained: the sum of the range's rings' `advance_m`
    /// (those known), or without rings the stretches' lengths.
    pub advance_m: Option<f64>,
    /// Pushes of a jacked string (`pushes` log) and their total length.
    pub pushes: u64,
    pub pushed_m: f64,
    /// What `advance_m` is from: `rings` or `stations`; `null` without
    /// either.
    pub advance_from: Option<&'static str>,
    /// The ring numbers as logged, in runs of consecutive numbers
    /// (`[{"first": 7, "last": 8}, {"first": 1, "last": 9}]`: rings 7 and
    /// 8, then a count from 1 again).
    pub ring_numbers: Vec<RingRun>,
    /// The stations the reference point covered, in stretches split where
    /// the station went back by more than a metre (a new drive, a new
    /// set-up of the guidance).
    pub stretches: Vec<Stretch>,
}

/// A stretch of the range's stations without a step back.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Stretch {
    pub from_t: f64,
    pub to_t: f64,
    pub from_station_m: f64,
    pub to_station_m: f64,
}

/// Consecutive ring numbers as logged.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, utoipa::ToSchema)]
pub struct RingRun {
    pub first: u64,
    pub last: u64,
}

/// Runs of consecutive numbers in `numbers`, as logged.
pub(super) fn number_runs(numbers: impl IntoIterator<Item = u64>) -> Vec<RingRun> {
    let mut runs: Vec<RingRun> = Vec::new();
    for n in numbers {
        match runs.last_mut() {
            Some(run) if run.last.checked_add(1) == Some(n) => run.last = n,
            _ => runs.push(RingRun { first: n, last: n }),
        }
    }
    runs
}

/// The largest deviation of one point in one plane over the range.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct LargestDeviation {
    /// `front` or `rear`.
    pub point: &'static str,
    /// `horizontal` or `vertical`.
    pub plane: &'static str,
    /// The deviation, mm, signed (largest in magnitude).
    pub deviation_mm: f64,
    /// When and where.
    pub t: f64,
    pub station_m: f64,
}

/// A ring of the log, with its completion time.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct RingRow {
    pub t: f64,
    #[serde(flatten)]
    pub ring: RingRecord,
    /// Whether its position and attitude can be trusted.
    #[serde(flatten)]
    pub integrity: Integrity,
}

/// A push of the jacking log, with its time.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct PushRow {
    pub t: f64,
    #[serde(flatten)]
    pub push: PushRecord,
    /// Whether its track can be trusted.
    #[serde(flatten)]
    pub integrity: Integrity,
}

/// A stretch without a laser sample longer than the machine's
/// `laser_dropout_warn_s`.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Dropout {
    pub from_t: f64,
    pub to_t: f64,
    pub duration_s: f64,
}

/// A point of the deviation chart: the front's deviations.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct ChartPoint {
    pub t: f64,
    pub station_m: f64,
    pub horizontal_mm: f64,
    pub vertical_mm: f64,
}

/// The shift report.
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Report {
    pub machine: String,
    pub name: String,
    pub from: f64,
    pub to: f64,
    /// The drive: the design axis's name; `null` without an axis.
    pub project: Option<String>,
    /// When the report was made (the server's clock).
    pub generated_t: f64,
    /// The declared tolerances the chart's bands show; `null` without.
    #[schema(value_type = Option<Object>)]
    pub tolerances: Option<crate::fusion::declaration::Tolerances>,
    pub advance: Advance,
    /// Front and rear, horizontal and vertical: empty without `dta`
    /// estimates in the range.
    pub deviations: Vec<LargestDeviation>,
    pub rings: Vec<RingRow>,
    pub pushes: Vec<PushRow>,
    /// Alarms raised in the range or still active at its start, oldest
    /// first, with who acknowledged them.
    pub alarms: Vec<StoredAlarm>,
    /// `null` for a machine that does not fuse a laser.
    pub laser_dropouts: Option<Vec<Dropout>>,
    /// The front's deviation over the range, at most 400 points.
    pub chart: Vec<ChartPoint>,
}
