//! `eval dta --source zupt`: the `dta` stream from the FOG INS end to end.
//!
//! Each drive is a simulated pipe-jacking field drive
//! ([`crate::sim::pipejack`], a straight line at the scenario's heading and
//! slope) run through the `zupt` engine and the `dta` stage of a machine
//! declared with a start point, a straight design axis and a geometry. The
//! axis is drawn per seed so the machine follows it with a known offset
//! and a small angle: it starts 20 m behind the machine, displaced
//! sideways by up to ±40 mm, turned by up to ±0.02°, its height off by up
//! to ±20 mm and its grade by up to ±0.05 %.
//!
//! The truth is this module's own: the simulator's position and attitude
//! at the estimate's IMU reading, the front and rear points turned with a
//! rotation written out here, and located on the straight axis by plane
//! vector maths (nothing from the engine's geometry or the alignment
//! module). The errors are also scored against the INS's own 1σ: the
//! `zupt` estimate's position σ projected on the axis's normal
//! (horizontal) and its down σ (vertical). That σ is the reference
//! point's; the attitude's error over the lever arm to the front and rear
//! is not in it, so the reference point's own consistency and the lever
//! arm's share are scored beside it.

use std::collections::VecDeque;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use super::{ErrorStats, median};
use crate::fusion::Declaration;
use crate::fusion::alignment::{AlignmentSpec, ElementSpec, ProfileSpec, StartPose};
use crate::fusion::declaration::MachineGeometry;
use crate::fusion::dta::DtaSource;
use crate::fusion::pipeline::Pipeline;
use crate::fusion::reading::ProjectPoint;
use crate::fusion::{EngineKind, EngineOutput, EstimateValues, ParamValue, Params};
use crate::sim::pipejack::{Case, PipeJackDrive, PipeJackScenario, PipeJackTruth};

/// How long each drive lasts unless told, s.
pub const FIELD_DURATION_S: f64 = 3600.0;
/// How far behind the machine's start the axis begins, m.
const AXIS_LEAD_M: f64 = 20.0;

/// The engine's parameters the machine is declared with unless told: a
/// field drive's pushes last 10–20 min, longer than the INS holds its
/// position without the odometer (`eval zupt --case field`).
pub const DEFAULT_ASSIGNMENTS: [&str; 1] = ["odometer_aiding=true"];

/// A straight design axis: where it starts, its azimuth (degrees
/// clockwise from grid north), its height at the start and one grade.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StraightAxis {
    pub easting_m: f64,
    pub northing_m: f64,
    pub azimuth_deg: f64,
    pub height_m: f64,
    pub grade_pct: f64,
    pub length_m: f64,
}

/// Where a point lies against a [`StraightAxis`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisOffset {
    pub station_m: f64,
    /// + right looking along increasing station.
    pub right_m: f64,
    /// + above the design height at the station.
    pub above_m: f64,
}

impl StraightAxis {
    /// The axis as the protocol declares it: one line, one grade.
    pub fn spec(&self) -> AlignmentSpec {
        AlignmentSpec {
            name: "eval dta zupt".into(),
            start_station_m: 0.0,
            start: StartPose {
                easting_m: self.easting_m,
                northing_m: self.northing_m,
                azimuth_deg: self.azimuth_deg,
            },
            horizontal: vec![ElementSpec::Line {
                length_m: self.length_m,
            }],
            vertical: ProfileSpec {
                start_height_m: self.height_m,
                pvis: Vec::new(),
                end_grade_pct: self.grade_pct,
            },
            station_equations: Vec::new(),
        }
    }

    /// The unit vectors along the axis and to its right, (east, north).
    pub fn directions(&self) -> ([f64; 2], [f64; 2]) {
        let (s, c) = self.azimuth_deg.to_radians().sin_cos();
        ([s, c], [c, -s])
    }

    /// Where (`easting_m`, `northing_m`, `height_m`) lies against the axis.
    pub fn locate(&self, easting_m: f64, northing_m: f64, height_m: f64) -> AxisOffset {
        let (along, right) = self.directions();
        let (de, dn) = (easting_m - self.easting_m, northing_m - self.northing_m);
        let station_m = de * along[0] + dn * along[1];
        AxisOffset {
            station_m,
            right_m: de * right[0] + dn * right[1],
            above_m: height_m - (self.height_m + self.grade_pct / 100.0 * station_m),
        }
    }
}

/// The body's axes (x forward, y right, z down) as (east, north, up) unit
/// vectors, for a yaw (clockwise from north), pitch (nose up) and roll
/// (right side down) applied in that order, degrees.
pub fn body_axes_enu(yaw_deg: f64, pitch_deg: f64, roll_deg: f64) -> [[f64; 3]; 3] {
    let (sy, cy) = yaw_deg.to_radians().sin_cos();
    let (sp, cp) = pitch_deg.to_radians().sin_cos();
    let (sr, cr) = roll_deg.to_radians().sin_cos();
    // Forward: along the heading, tilted up by the pitch.
    let x = [cp * sy, cp * cy, sp];
    // Right: horizontal to the right when level; the roll takes it down.
    let y = [cr * cy + sr * sp * sy, -cr * sy + sr * sp * cy, -sr * cp];
    // Down: x × y in a right-handed body, written out.
    let z = [-sr * cy + cr * sp * sy, sr * sy + cr * sp * cy, -cr * cp];
    [x, y, z]
}

/// A point on the machine at `body` (m, x forward, y right, z down from
/// the reference point) with the reference point at (`easting`,
/// `northing`, `height`) and the attitude given, degrees: (east, north,
/// height).
pub fn machine_point(
    reference: [f64; 3],
    yaw_deg: f64,
    pitch_deg: f64,
    roll_deg: f64,
    body: [f64; 3],
) -> [f64; 3] {
    let axes = body_axes_enu(yaw_deg, pitch_deg, roll_deg);
    std::array::from_fn(|i| {
        reference[i] + axes[0][i] * body[0] + axes[1][i] * body[1] + axes[2][i] * body[2]
    })
}

/// One drive: the simulated machine, its declared start, axis and geometry.
#[derive(Debug, Clone, Serialize)]
pub struct ZuptDtaScenario {
    pub seed: u64,
    pub drive: PipeJackScenario,
    pub start: ProjectPoint,
    pub geometry: MachineGeometry,
    /// Drawn: the axis's sideways displacement at the machine's start (+
    /// right of it looking along the heading), m; its turn from the
    /// heading, degrees; its height at the machine's start above the
    /// machine's line, m; its grade less the machine's, %.
    pub axis_offset_m: f64,
    pub axis_turn_deg: f64,
    pub axis_height_m: f64,
    pub axis_grade_pct: f64,
}

impl ZuptDtaScenario {
    /// The drive of `seed`: a field drive of `field_duration_s` at a
    /// heading of 0–360° and a slope of ±2°, a geometry of a pipe-jacking
    /// head (front 1.5–3 m ahead, rear 1–2.5 m behind, both up to 0.2 m
    /// aside and 0–0.6 m below the reference point), and the axis's
    /// offsets.
    pub fn draw(seed: u64, field_duration_s: f64) -> ZuptDtaScenario {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(20);
        let drive = PipeJackScenario {
            case: Case::Field,
            seed,
            heading_deg: rng.random_range(0.0..360.0),
            slope_deg: rng.random_range(-2.0..2.0),
            field_duration_s,
            ..PipeJackScenario::default()
        };
        let (aside, below) = (rng.random_range(-0.2..0.2), rng.random_range(0.0..0.6));
        let geometry = MachineGeometry {
            front_m: [rng.random_range(1.5..3.0), aside, below],
            rear_m: [rng.random_range(-2.5..-1.0), aside, below],
        };
        ZuptDtaScenario {
            seed,
            start: ProjectPoint {
                easting_m: 512_000.0,
                northing_m: 3_400_000.0,
                // The level reads absolute height.
                height_m: drive.start_height_m,
            },
            drive,
            geometry,
            axis_offset_m: rng.random_range(-0.04..0.04),
            axis_turn_deg: rng.random_range(-0.02..0.02),
            axis_height_m: rng.random_range(-0.02..0.02),
            axis_grade_pct: rng.random_range(-0.05..0.05),
        }
    }

    /// The design axis, long enough for a drive of `distance_m`.
    pub fn axis(&self, distance_m: f64) -> StraightAxis {
        let (s, c) = self.drive.heading_deg.to_radians().sin_cos();
        let grade = self.drive.slope_deg.to_radians().tan();
        StraightAxis {
            easting_m: self.start.easting_m - AXIS_LEAD_M * s + self.axis_offset_m * c,
            northing_m: self.start.northing_m - AXIS_LEAD_M * c - self.axis_offset_m * s,
            azimuth_deg: self.drive.heading_deg + self.axis_turn_deg,
            height_m: self.start.height_m - AXIS_LEAD_M * grade + self.axis_height_m,
            grade_pct: 100.0 * grade + self.axis_grade_pct,
            length_m: distance_m + AXIS_LEAD_M + 60.0,
        }
    }
}

/// How the errors compare with the σ they are scored against: |error|/σ.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Consistency {
    pub count: usize,
    pub median: f64,
    pub p95: f64,
    pub max: f64,
    /// Shares of |error| ≤ 1σ, 2σ, 3σ (a consistent filter: ≈ 68/95/99.7 %).
    pub within: [f64; 3],
}

impl Consistency {
    /// Of these normalised errors.
    pub fn of(mut ratios: Vec<f64>) -> Consistency {
        if ratios.is_empty() {
            return Consistency::default();
        }
        ratios.sort_by(f64::total_cmp);
        let n = ratios.len();
        let share = |k: f64| ratios.partition_point(|&r| r <= k) as f64 / n as f64;
        Consistency {
            count: n,
            median: ratios[n / 2],
            p95: ratios[((0.95 * n as f64).ceil() as usize).clamp(1, n) - 1],
            max: ratios[n - 1],
            within: [share(1.0), share(2.0), share(3.0)],
        }
    }
}

/// Errors of one drive, mm.
#[derive(Debug, Clone, Serialize)]
pub struct ZuptDtaScore {
    pub seed: u64,
    pub heading_deg: f64,
    pub slope_deg: f64,
    pub duration_s: f64,
    pub distance_m: f64,
    /// Aligned `zupt` estimates, and the `dta` estimates scored (one per
    /// IMU reading once aligned).
    pub aligned_estimates: usize,
    pub estimates: usize,
    pub front_horizontal: ErrorStats,
    pub front_vertical: ErrorStats,
    pub rear_horizontal: ErrorStats,
    pub rear_vertical: ErrorStats,
    pub front_station: ErrorStats,
    /// Largest true deviation of the front, mm.
    pub largest_true_horizontal_mm: f64,
    pub largest_true_vertical_mm: f64,
    /// Front and rear errors against the INS's σ.
    pub horizontal: Consistency,
    pub vertical: Consistency,
    /// Front and rear errors against the `dta` estimate's own σ (the
    /// INS's position σ and its attitude σ over the lever arm).
    pub own_horizontal: Consistency,
    pub own_vertical: Consistency,
    /// The reference point's own error (the INS's position against the
    /// truth, on the axis's normal and in height) against the same σ.
    pub reference_horizontal: Consistency,
    pub reference_vertical: Consistency,
    /// The part of the front's and rear's errors beyond the reference
    /// point's: the attitude's error over the lever arm, mm.
    pub lever_horizontal: ErrorStats,
    pub lever_vertical: ErrorStats,
    /// Largest |heading error| and |pitch error|, degrees.
    pub max_yaw_error_deg: f64,
    pub max_pitch_error_deg: f64,
    /// Median of the INS's σ, mm.
    pub median_sigma_horizontal_mm: f64,
    pub median_sigma_vertical_mm: f64,
}

impl ZuptDtaScore {
    /// The largest error of any deviation of the drive, mm.
    pub fn worst_deviation_mm(&self) -> f64 {
        super::largest_abs(&[
            &self.front_horizontal,
            &self.front_vertical,
            &self.rear_horizontal,
            &self.rear_vertical,
        ])
    }
}

/// The `zupt` parameters of `scenario`'s machine: `base` with the site's
/// latitude and the drive's heading.
pub fn engine_params(scenario: &ZuptDtaScenario, base: &Params) -> Result<Params, String> {
    base.with_overrides(
        crate::fusion::zupt::PARAMS,
        [
            (
                "latitude_deg".to_string(),
                ParamValue::Number(scenario.drive.latitude_deg),
            ),
            (
                "initial_yaw_deg".to_string(),
                ParamValue::Number(scenario.drive.heading_deg),
            ),
        ],
    )
    .map_err(|e| e.to_string())
}

/// Runs one drive through the declared machine and scores every `dta`
/// estimate; `base` are the `zupt` engine's parameters.
pub fn evaluate(scenario: &ZuptDtaScenario, base: &Params) -> Result<ZuptDtaScore, String> {
    let drive = PipeJackDrive::new(scenario.drive.clone())?;
    let (duration_s, distance_m) = (drive.duration_s(), drive.total_distance_m());
    let axis = scenario.axis(distance_m);
    let alignment = axis
        .spec()
        .build()
        .map_err(|e| format!("the drawn axis: {e}"))?;
    let declaration = Declaration {
        alignment: Some(std::sync::Arc::new(alignment)),
        geometry: Some(scenario.geometry),
        start: Some(scenario.start),
        ..Declaration::of_engines([EngineKind::Zupt])
    };
    let params = engine_params(scenario, base)?;
    let engine = EngineKind::Zupt.create(params).map_err(|e| e.to_string())?;
    let mut pipeline = Pipeline::declared(vec![engine], &declaration);
    let mut scorer = Scorer::new(scenario, axis);
    let mut outputs: Vec<EngineOutput> = Vec::new();
    for event in drive {
        if let Some(truth) = event.truth {
            scorer.truths.push_back(truth);
        }
        pipeline.feed(&event.reading, &mut outputs);
        for output in outputs.drain(..) {
            scorer.output(&output)?;
        }
    }
    pipeline.flush(&mut outputs);
    for output in &outputs {
        scorer.output(output)?;
    }
    Ok(scorer.finish(duration_s, distance_m))
}

/// What a `zupt` estimate said that its `dta` estimate is scored with.
#[derive(Debug, Clone, Copy)]
struct InsEstimate {
    t: f64,
    position_m: [f64; 3],
    position_sigma_m: [f64; 3],
    yaw_deg: f64,
    pitch_deg: f64,
}

/// Scores a drive's outputs as they come, against its truths (both in
/// time order; a truth is kept until the estimates have passed its time).
struct Scorer<'a> {
    scenario: &'a ZuptDtaScenario,
    axis: StraightAxis,
    truths: VecDeque<PipeJackTruth>,
    latest: Option<InsEstimate>,
    score: ZuptDtaScore,
    horizontal: Vec<f64>,
    vertical: Vec<f64>,
    own_horizontal: Vec<f64>,
    own_vertical: Vec<f64>,
    reference_h: Vec<f64>,
    reference_v: Vec<f64>,
    sigma_h: Vec<f64>,
    sigma_v: Vec<f64>,
}

impl<'a> Scorer<'a> {
    fn new(scenario: &'a ZuptDtaScenario, axis: StraightAxis) -> Scorer<'a> {
        Scorer {
            scenario,
            axis,
            truths: VecDeque::new(),
            latest: None,
            score: ZuptDtaScore {
                seed: scenario.seed,
                heading_deg: scenario.drive.heading_deg,
                slope_deg: scenario.drive.slope_deg,
                duration_s: 0.0,
                distance_m: 0.0,
                aligned_estimates: 0,
                estimates: 0,
                front_horizontal: ErrorStats::default(),
                front_vertical: ErrorStats::default(),
                rear_horizontal: ErrorStats::default(),
                rear_vertical: ErrorStats::default(),
                front_station: ErrorStats::default(),
                largest_true_horizontal_mm: 0.0,
                largest_true_vertical_mm: 0.0,
                horizontal: Consistency::default(),
                vertical: Consistency::default(),
                own_horizontal: Consistency::default(),
                own_vertical: Consistency::default(),
                reference_horizontal: Consistency::default(),
                reference_vertical: Consistency::default(),
                lever_horizontal: ErrorStats::default(),
                lever_vertical: ErrorStats::default(),
                max_yaw_error_deg: 0.0,
                max_pitch_error_deg: 0.0,
                median_sigma_horizontal_mm: f64::NAN,
                median_sigma_vertical_mm: f64::NAN,
            },
            horizontal: Vec::new(),
            vertical: Vec::new(),
            own_horizontal: Vec::new(),
            own_vertical: Vec::new(),
            reference_h: Vec::new(),
            reference_v: Vec::new(),
            sigma_h: Vec::new(),
            sigma_v: Vec::new(),
        }
    }

    /// One output of the pipeline.
    fn output(&mut self, output: &EngineOutput) -> Result<(), String> {
        let d = match &output.values {
            EstimateValues::Zupt(z) => {
                if z.aligned {
                    self.score.aligned_estimates += 1;
                }
                self.latest = Some(InsEstimate {
                    t: output.t,
                    position_m: z.position_m,
                    position_sigma_m: z.position_sigma_m,
                    yaw_deg: z.yaw_deg,
                    pitch_deg: z.pitch_deg,
                });
                return Ok(());
            }
            EstimateValues::Dta(d) => d,
            _ => return Ok(()),
        };
        let Some(z) = self.latest.filter(|z| z.t == output.t) else {
            return Err(format!(
                "a dta estimate at t={} without a zupt estimate at its time",
                output.t
            ));
        };
        if d.source != DtaSource::Zupt {
            return Err(format!("a {} dta estimate", d.source.as_str()));
        }
        while self.truths.front().is_some_and(|t| t.t < output.t) {
            self.truths.pop_front();
        }
        let Some(truth) = self.truths.front().filter(|t| t.t == output.t) else {
            return Err(format!("a dta estimate at t={} has no truth", output.t));
        };
        let (scenario, axis, s) = (self.scenario, &self.axis, &mut self.score);
        s.estimates += 1;

        // The truth, by this module's own maths.
        let start = scenario.start;
        let [north, east, down] = truth.position_m;
        let reference = [
            start.easting_m + east,
            start.northing_m + north,
            start.height_m - down,
        ];
        let locate = |body: [f64; 3]| {
            let [e, n, h] = machine_point(
                reference,
                truth.yaw_deg,
                truth.pitch_deg,
                truth.roll_deg,
                body,
            );
            axis.locate(e, n, h)
        };
        let geometry = scenario.geometry;
        let (front, rear) = (locate(geometry.front_m), locate(geometry.rear_m));

        // The INS's σ on the axis's normal and in height, mm.
        let (_, normal) = axis.directions();
        let [sigma_n, sigma_e, sigma_d] = z.position_sigma_m;
        let sigma_horizontal =
            1000.0 * ((normal[1] * sigma_n).powi(2) + (normal[0] * sigma_e).powi(2)).sqrt();
        let sigma_vertical = 1000.0 * sigma_d;
        self.sigma_h.push(sigma_horizontal);
        self.sigma_v.push(sigma_vertical);

        // The reference point's own error, mm.
        let error = |i: usize| z.position_m[i] - truth.position_m[i];
        let reference_error_h = 1000.0 * (normal[1] * error(0) + normal[0] * error(1));
        let reference_error_v = -1000.0 * error(2);
        self.reference_h
            .push(reference_error_h.abs() / sigma_horizontal);
        self.reference_v
            .push(reference_error_v.abs() / sigma_vertical);

        for (estimated, truth_point, stats_h, stats_v) in [
            (
                d.front,
                front,
                &mut s.front_horizontal,
                &mut s.front_vertical,
            ),
            (d.rear, rear, &mut s.rear_horizontal, &mut s.rear_vertical),
        ] {
            let error_h = estimated.horizontal_mm - 1000.0 * truth_point.right_m;
            let error_v = estimated.vertical_mm - 1000.0 * truth_point.above_m;
            stats_h.add(error_h);
            stats_v.add(error_v);
            self.horizontal.push(error_h.abs() / sigma_horizontal);
            self.vertical.push(error_v.abs() / sigma_vertical);
            // Against the estimate's own σ.
            let (Some(own_h), Some(own_v)) =
                (estimated.sigma_horizontal_mm, estimated.sigma_vertical_mm)
            else {
                return Err(format!(
                    "a zupt dta estimate at t={} without its σ",
                    output.t
                ));
            };
            self.own_horizontal.push(error_h.abs() / own_h);
            self.own_vertical.push(error_v.abs() / own_v);
            s.lever_horizontal.add(error_h - reference_error_h);
            s.lever_vertical.add(error_v - reference_error_v);
        }
        s.front_station
            .add(1000.0 * (d.front.station_m - front.station_m));
        s.largest_true_horizontal_mm = s
            .largest_true_horizontal_mm
            .max(1000.0 * front.right_m.abs());
        s.largest_true_vertical_mm = s.largest_true_vertical_mm.max(1000.0 * front.above_m.abs());
        let yaw_error = super::heading_error_deg(z.yaw_deg, truth.yaw_deg);
        s.max_yaw_error_deg = s.max_yaw_error_deg.max(yaw_error);
        s.max_pitch_error_deg = s
            .max_pitch_error_deg
            .max((z.pitch_deg - truth.pitch_deg).abs());
        Ok(())
    }

    /// The score of the drive of `duration_s` and `distance_m`.
    fn finish(self, duration_s: f64, distance_m: f64) -> ZuptDtaScore {
        ZuptDtaScore {
            duration_s,
            distance_m,
            horizontal: Consistency::of(self.horizontal),
            vertical: Consistency::of(self.vertical),
            own_horizontal: Consistency::of(self.own_horizontal),
            own_vertical: Consistency::of(self.own_vertical),
            reference_horizontal: Consistency::of(self.reference_h),
            reference_vertical: Consistency::of(self.reference_v),
            median_sigma_horizontal_mm: median(self.sigma_h),
            median_sigma_vertical_mm: median(self.sigma_v),
            ..self.score
        }
    }
}

/// Median and worst over drives.
#[derive(Debug, Clone, Serialize)]
pub struct ZuptDtaSummary {
    pub drives: usize,
    pub estimates: usize,
    pub median_worst_deviation_mm: f64,
    pub worst_deviation_mm: f64,
    pub median_rms_front_horizontal_mm: f64,
    pub median_rms_front_vertical_mm: f64,
    pub worst_station_mm: f64,
    /// Shares within 2σ (front and rear): median and the lowest.
    pub median_within_2_sigma_horizontal: f64,
    pub lowest_within_2_sigma_horizontal: f64,
    pub median_within_2_sigma_vertical: f64,
    pub lowest_within_2_sigma_vertical: f64,
    /// The same against the `dta` estimate's own σ.
    pub median_within_own_2_sigma_horizontal: f64,
    pub lowest_within_own_2_sigma_horizontal: f64,
    pub median_within_own_2_sigma_vertical: f64,
    pub lowest_within_own_2_sigma_vertical: f64,
    /// Largest |error|/σ of any drive.
    pub worst_normalised_horizontal: f64,
    pub worst_normalised_vertical: f64,
}

/// The summary of `scores`.
pub fn summarise(scores: &[ZuptDtaScore]) -> ZuptDtaSummary {
    let of = |f: &dyn Fn(&ZuptDtaScore) -> f64| scores.iter().map(f).collect::<Vec<_>>();
    let worst = |f: &dyn Fn(&ZuptDtaScore) -> f64| of(f).into_iter().fold(0.0, f64::max);
    let lowest = |f: &dyn Fn(&ZuptDtaScore) -> f64| of(f).into_iter().fold(1.0, f64::min);
    ZuptDtaSummary {
        drives: scores.len(),
        estimates: scores.iter().map(|s| s.estimates).sum(),
        median_worst_deviation_mm: median(of(&ZuptDtaScore::worst_deviation_mm)),
        worst_deviation_mm: worst(&ZuptDtaScore::worst_deviation_mm),
        median_rms_front_horizontal_mm: median(of(&|s| s.front_horizontal.rmse())),
        median_rms_front_vertical_mm: median(of(&|s| s.front_vertical.rmse())),
        worst_station_mm: worst(&|s| s.front_station.max_abs),
        median_within_2_sigma_horizontal: median(of(&|s| s.horizontal.within[1])),
        lowest_within_2_sigma_horizontal: lowest(&|s| s.horizontal.within[1]),
        median_within_2_sigma_vertical: median(of(&|s| s.vertical.within[1])),
        lowest_within_2_sigma_vertical: lowest(&|s| s.vertical.within[1]),
        median_within_own_2_sigma_horizontal: median(of(&|s| s.own_horizontal.within[1])),
        lowest_within_own_2_sigma_horizontal: lowest(&|s| s.own_horizontal.within[1]),
        median_within_own_2_sigma_vertical: median(of(&|s| s.own_vertical.within[1])),
        lowest_within_own_2_sigma_vertical: lowest(&|s| s.own_vertical.within[1]),
        worst_normalised_horizontal: worst(&|s| s.horizontal.max),
        worst_normalised_vertical: worst(&|s| s.vertical.max),
    }
}

/// One line per drive, where the error comes from, and the summary.
pub fn render(scores: &[ZuptDtaScore], summary: &ZuptDtaSummary) -> String {
    let consistency = |c: &Consistency| {
        format!(
            "{:>4.2}/{:>4.2}/{:>5.2}  {:>3.0}/{:>3.0}/{:>3.0}",
            c.median,
            c.p95,
            c.max,
            100.0 * c.within[0],
            100.0 * c.within[1],
            100.0 * c.within[2],
        )
    };
    let mut out = String::from(
        "seed  heading  slope  dist m  estimates  front H rms/max   front V rms/max   rear H max  rear V max  \
         H |e|/σ med/p95/max ≤1/2/3σ %   V |e|/σ med/p95/max ≤1/2/3σ %\n",
    );
    for s in scores {
        out.push_str(&format!(
            "{:>4}  {:>6.1}°  {:>4.2}°  {:>6.2}  {:>9}  {:>6.2} / {:>6.2}   {:>6.2} / {:>6.2}   {:>10.2}  {:>10.2}  {}   {}\n",
            s.seed,
            s.heading_deg,
            s.slope_deg,
            s.distance_m,
            s.estimates,
            s.front_horizontal.rmse(),
            s.front_horizontal.max_abs,
            s.front_vertical.rmse(),
            s.front_vertical.max_abs,
            s.rear_horizontal.max_abs,
            s.rear_vertical.max_abs,
            consistency(&s.horizontal),
            consistency(&s.vertical),
        ));
    }
    out.push_str(
        "\nwhere the error comes from: the INS's own σ (median), its reference point against it, \
         and the attitude's error over the lever arm (not in the σ)\n\
         seed  σ H/V mm     ref H |e|/σ med/p95/max ≤1/2/3σ %   ref V |e|/σ med/p95/max ≤1/2/3σ %   \
         lever H rms/max   lever V rms/max   yaw/pitch err max °   dta's own σ: H ≤2σ, V ≤2/3σ %\n",
    );
    for s in scores {
        out.push_str(&format!(
            "{:>4}  {:>5.2}/{:<5.2}  {}       {}       {:>6.2} / {:>6.2}   {:>6.2} / {:>6.2}   {:.3}/{:.3}           {:>3.0}/{:>3.0}/{:>3.0}\n",
            s.seed,
            s.median_sigma_horizontal_mm,
            s.median_sigma_vertical_mm,
            consistency(&s.reference_horizontal),
            consistency(&s.reference_vertical),
            s.lever_horizontal.rmse(),
            s.lever_horizontal.max_abs,
            s.lever_vertical.rmse(),
            s.lever_vertical.max_abs,
            s.max_yaw_error_deg,
            s.max_pitch_error_deg,
            100.0 * s.own_horizontal.within[1],
            100.0 * s.own_vertical.within[1],
            100.0 * s.own_vertical.within[2],
        ));
    }
    out.push_str(&format!(
        "\n{} drives, {} estimates: largest deviation error per drive median {:.2} mm, worst {:.2} mm; \
         RMS front H median {:.2} mm, V {:.2} mm; station worst {:.1} mm; \
         within the INS's 2σ: H median {:.1} %, lowest {:.1} %, V median {:.1} %, lowest {:.1} %; \
         within the dta estimate's own 2σ: H median {:.1} %, lowest {:.1} %, V median {:.1} %, lowest {:.1} %; \
         |e|/σ worst H {:.2}, V {:.2}\n",
        summary.drives,
        summary.estimates,
        summary.median_worst_deviation_mm,
        summary.worst_deviation_mm,
        summary.median_rms_front_horizontal_mm,
        summary.median_rms_front_vertical_mm,
        summary.worst_station_mm,
        100.0 * summary.median_within_2_sigma_horizontal,
        100.0 * summary.lowest_within_2_sigma_horizontal,
        100.0 * summary.median_within_2_sigma_vertical,
        100.0 * summary.lowest_within_2_sigma_vertical,
        100.0 * summary.median_within_own_2_sigma_horizontal,
        100.0 * summary.lowest_within_own_2_sigma_horizontal,
        100.0 * summary.median_within_own_2_sigma_vertical,
        100.0 * summary.lowest_within_own_2_sigma_vertical,
        summary.worst_normalised_horizontal,
        summary.worst_normalised_vertical,
    ));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::ZuptEstimate;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-9
    }

    #[test]
    fn a_point_against_an_axis_by_hand() {
        // Due east from (1000, 5000) at 50 m, rising 1 %: a point 1 m
        // along, 30 mm south (right, looking east) and 10 mm above the
        // design's 50.01 m.
        let axis = StraightAxis {
            easting_m: 1000.0,
            northing_m: 5000.0,
            azimuth_deg: 90.0,
            height_m: 50.0,
            grade_pct: 1.0,
            length_m: 100.0,
        };
        let p = axis.locate(1001.0, 4999.97, 50.02);
        assert!(close(p.station_m, 1.0), "{p:?}");
        assert!(close(p.right_m, 0.03), "{p:?}");
        assert!(close(p.above_m, 0.01), "{p:?}");
    }

    #[test]
    fn body_axes_by_hand() {
        let near = |a: [f64; 3], b: [f64; 3]| (0..3).all(|i| close(a[i], b[i]));
        // Heading east, level: forward east, right south, down down.
        let [x, y, z] = body_axes_enu(90.0, 0.0, 0.0);
        assert!(near(x, [1.0, 0.0, 0.0]) && near(y, [0.0, -1.0, 0.0]));
        assert!(near(z, [0.0, 0.0, -1.0]));
        // Heading north, nose 90° up: forward up, down points north.
        let [x, y, z] = body_axes_enu(0.0, 90.0, 0.0);
        assert!(near(x, [0.0, 0.0, 1.0]) && near(y, [1.0, 0.0, 0.0]));
        assert!(near(z, [0.0, 1.0, 0.0]));
        // Heading north, rolled 90° right side down: right points down,
        // down points west.
        let [_, y, z] = body_axes_enu(0.0, 0.0, 90.0);
        assert!(near(y, [0.0, 0.0, -1.0]) && near(z, [-1.0, 0.0, 0.0]));
        // A head 2 m forward, 0.3 m below the reference, heading east.
        let p = machine_point([10.0, 20.0, 5.0], 90.0, 0.0, 0.0, [2.0, 0.0, 0.3]);
        assert!(near(p, [12.0, 20.0, 4.7]), "{p:?}");
    }

    /// The stage fed a `zupt` estimate equal to the truth agrees with this
    /// module's truth, at any attitude: the two are written independently.
    #[test]
    fn the_stage_agrees_with_the_truth_on_an_exact_position() {
        let scenario = ZuptDtaScenario::draw(7, FIELD_DURATION_S);
        let axis = scenario.axis(10.0);
        let declaration = Declaration {
            alignment: Some(std::sync::Arc::new(axis.spec().build().unwrap())),
            geometry: Some(scenario.geometry),
            start: Some(scenario.start),
            ..Declaration::of_engines([EngineKind::Zupt])
        };
        let mut stage = crate::fusion::registry::StageKind::Dta
            .create(&declaration)
            .unwrap();
        let (s, c) = scenario.drive.heading_deg.to_radians().sin_cos();
        for (along, aside, up, yaw, pitch, roll) in [
            (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            (3.0, 0.05, -0.02, 1.5, -2.0, 3.0),
            (7.5, -0.03, 0.04, -4.0, 5.0, -8.0),
        ] {
            let truth = PipeJackTruth {
                t: 1.0,
                zv: false,
                position_m: [along * c - aside * s, along * s + aside * c, -up],
                velocity_mps: [0.0; 3],
                distance_m: along,
                pitch_deg: pitch,
                roll_deg: roll,
                yaw_deg: (scenario.drive.heading_deg + yaw).rem_euclid(360.0),
            };
            let zupt = EngineOutput {
                integrity: crate::fusion::Integrity::OK,
                t: truth.t,
                values: EstimateValues::Zupt(ZuptEstimate {
                    zv: false,
                    position_m: truth.position_m,
                    distance_m: along,
                    velocity_mps: [0.0; 3],
                    pitch_deg: truth.pitch_deg,
                    roll_deg: truth.roll_deg,
                    yaw_deg: truth.yaw_deg,
                    aligned: true,
                    position_sigma_m: [0.01; 3],
                    height_m: None,
                    odometer_m: None,
                    mv_ratio: 0.0,
                    are_ratio: 0.0,
                    shoe_ratio: 0.0,
                    mag_ratio: 0.0,
                    yaw_sigma_deg: Some(0.1),
                    attitude_sigma_deg: Some([0.05, 0.05, 0.1]),
                    pitch_sigma_deg: None,
                    roll_sigma_deg: None,
                    smoothed_push: None,
                    odometer_scale: None,
                    odometer_scale_sigma: None,
                }),
            };
            let mut outputs = vec![zupt.clone()];
            stage.estimate(&zupt, &mut outputs);
            let mut scorer = Scorer::new(&scenario, axis);
            scorer.truths.push_back(truth);
            for output in &outputs {
                scorer.output(output).unwrap();
            }
            let score = scorer.finish(0.0, 0.0);
            assert_eq!(score.estimates, 1);
            assert!(score.worst_deviation_mm() < 1e-6, "{score:?}");
            assert!(score.front_station.max_abs < 1e-6, "{score:?}");
        }
    }

    /// A short drive end to end: every IMU reading after alignment gives a
    /// `dta` estimate, a few centimetres at most off the truth, the
    /// reference point's height within the INS's 2σ.
    #[test]
    fn a_short_drive_end_to_end() {
        let scenario = ZuptDtaScenario::draw(3, 900.0);
        let params = EngineKind::Zupt
            .params_from_assignments(DEFAULT_ASSIGNMENTS)
            .unwrap();
        let score = evaluate(&scenario, &params).unwrap();
        assert!(score.distance_m > 1.0, "{score:?}");
        assert!(score.estimates > 0 && score.estimates == score.aligned_estimates);
        assert!(score.worst_deviation_mm() < 50.0, "{score:?}");
        assert!(score.reference_vertical.within[1] > 0.9, "{score:?}");
    }
}
