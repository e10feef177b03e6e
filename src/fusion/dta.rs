//! The `dta` stage: the machine's deviation from the designed tunnel axis
//! at its front (cutterhead) and rear (shield tail), the tendency between
//! them, and their status against the declared tolerances.
//!
//! Its positions come from either source the machine has (both, if it has
//! both): a `laser` reading that carries the reference point's position,
//! turned by the `attitude` engine's fused pitch and roll (the laser's
//! own until the engine has had a laser sample) and the laser's yaw; or a `zupt`
//! estimate once aligned, its position relative to the declared start.
//! Each point is the reference point plus C_nb(yaw, pitch, roll) · its body
//! offset (x forward, y right, z down; NED, so height is minus down), then
//! located against the axis ([`super::alignment`]).

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::alignment::Alignment;
use super::angles::rad;
use super::descriptor::{DeviationSignal, SignalKind, Signals, StageDescriptor, StreamValues};
use super::estimate::{EngineOutput, EstimateValues};
use super::geometry::{V3, attitude_from_euler};
use super::integrity::{Integrity, IntegrityLevel};
use super::json_fields::JsonFields;
use super::reading::{ProjectPoint, Reading, SensorData, SensorKind};
use super::registry::{EngineKind, StageKind};
use super::stage::{Declaration, Stage};
use super::{SnapshotError, StreamKind};

/// Version of the stage's snapshot.
pub const STATE_VERSION: u32 = 1;
/// Version of the stored [`DtaEstimate`]. 1: before the points' σ
/// ([`DtaEstimateV1`]).
pub const CODEC_VERSION: u32 = 2;

/// Where the machine's front and rear points are on it: metres from the
/// navigation reference point in the body frame (x forward, y right, z
/// down).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MachineGeometry {
    pub front_m: [f64; 3],
    pub rear_m: [f64; 3],
}

/// Warn and alarm limits of one deviation, mm (of its magnitude).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    pub warn: f64,
    pub alarm: f64,
}

/// The tolerances the deviations are held to.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Tolerances {
    pub horizontal_mm: Limits,
    pub vertical_mm: Limits,
}

/// Which positions a `dta` estimate comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum DtaSource {
    Laser,
    Zupt,
}

impl DtaSource {
    /// The protocol name.
    pub fn as_str(self) -> &'static str {
        match self {
            DtaSource::Laser => "laser",
            DtaSource::Zupt => "zupt",
        }
    }
}

/// The worst of the four deviations against the tolerances. Stored as the
/// variant's index: new ones are appended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum DtaStatus {
    Ok,
    Warn,
    Alarm,
    /// A deviation's 2σ band crosses a limit, or the position's source
    /// cannot vouch for it: the status cannot be told.
    Unknown,
}

impl DtaStatus {
    /// The protocol name.
    pub fn as_str(self) -> &'static str {
        match self {
            DtaStatus::Ok => "ok",
            DtaStatus::Warn => "warn",
            DtaStatus::Alarm => "alarm",
            DtaStatus::Unknown => "unknown",
        }
    }

    /// Which of two deviations' statuses the estimate shows: a certain
    /// alarm over an unknown, an unknown over a certain warn.
    fn rank(self) -> u8 {
        match self {
            DtaStatus::Ok => 0,
            DtaStatus::Warn => 1,
            DtaStatus::Unknown => 2,
            DtaStatus::Alarm => 3,
        }
    }
}

/// The status of one deviation against its limits: the grade of every
/// value in its 2σ band when they agree, [`DtaStatus::Unknown`] when the
/// band crosses a limit. Without a σ (laser positions) the value's own.
fn grade(value_mm: f64, sigma_mm: Option<f64>, limits: Limits) -> DtaStatus {
    let of = |magnitude: f64| {
        if magnitude > limits.alarm {
            DtaStatus::Alarm
        } else if magnitude > limits.warn {
            DtaStatus::Warn
        } else {
            DtaStatus::Ok
        }
    };
    let two_sigma = 2.0 * sigma_mm.unwrap_or(0.0);
    let (low, high) = (
        of((value_mm.abs() - two_sigma).max(0.0)),
        of(value_mm.abs() + two_sigma),
    );
    if low == high { low } else { DtaStatus::Unknown }
}

/// One point's deviation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PointDeviation {
    pub station_m: f64,
    /// + right of the axis looking along increasing station.
    pub horizontal_mm: f64,
    /// + above the design height at the point's station.
    pub vertical_mm: f64,
    /// 1σ of the horizontal and vertical deviation from the source's own
    /// covariance (tunnelnav extension): the position's σ and the
    /// attitude's σ over the lever arm to the point. `null` for laser
    /// positions, which come without one.
    pub sigma_horizontal_mm: Option<f64>,
    pub sigma_vertical_mm: Option<f64>,
}

/// The source's own uncertainty: 1σ of the reference point's position and
/// of the attitude error about north, east and down.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Uncertainty {
    position_m: [f64; 3],
    attitude_rad: [f64; 3],
}

impl Uncertainty {
    /// σ of the horizontal deviation (across an axis at `azimuth_rad`) and
    /// of the vertical one of a point `lever` (north, east, down, m) from
    /// the reference point. A small attitude error φ moves the point by
    /// φ × lever; the components are taken as independent.
    fn of_point(&self, lever: V3, azimuth_rad: f64) -> (f64, f64) {
        let [sn, se, sd] = self.position_m;
        let [an, ae, ad] = self.attitude_rad;
        let var_n = sn * sn + (ae * lever.z).powi(2) + (ad * lever.y).powi(2);
        let var_e = se * se + (ad * lever.x).powi(2) + (an * lever.z).powi(2);
        let var_d = sd * sd + (an * lever.y).powi(2) + (ae * lever.x).powi(2);
        // Across the axis: (east, north) · (cos a, −sin a).
        let (sin_a, cos_a) = azimuth_rad.sin_cos();
        let horizontal = (cos_a * cos_a * var_e + sin_a * sin_a * var_n).sqrt();
        (horizontal * 1000.0, var_d.sqrt() * 1000.0)
    }
}

/// What the `dta` stage emits per position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DtaEstimate {
    pub source: DtaSource,
    /// Station of the reference point's foot on the axis.
    pub station_m: f64,
    pub front: PointDeviation,
    pub rear: PointDeviation,
    /// (front − rear) deviation per metre of machine length.
    pub tendency_horizontal_mm_per_m: f64,
    pub tendency_vertical_mm_per_m: f64,
    /// Against the declared tolerances; `null` without tolerances.
    pub status: Option<DtaStatus>,
}

impl StreamValues for DtaEstimate {
    const CODEC_VERSION: u32 = CODEC_VERSION;
    const SIGNALS: &'static [SignalKind] = &[SignalKind::Deviation];

    fn write_fields(&self, w: &mut JsonFields<'_>) {
        w.word("source", self.source.as_str());
        w.number("station_m", self.station_m);
        for (key, p) in [("front", &self.front), ("rear", &self.rear)] {
            w.object(key, |w| {
                w.number("station_m", p.station_m);
                w.number("horizontal_mm", p.horizontal_mm);
                w.number("vertical_mm", p.vertical_mm);
                w.optional("sigma_horizontal_mm", p.sigma_horizontal_mm);
                w.optional("sigma_vertical_mm", p.sigma_vertical_mm);
            });
        }
        w.number(
            "tendency_horizontal_mm_per_m",
            self.tendency_horizontal_mm_per_m,
        );
        w.number(
            "tendency_vertical_mm_per_m",
            self.tendency_vertical_mm_per_m,
        );
        match self.status {
            Some(status) => w.word("status", status.as_str()),
            None => w.null("status"),
        }
    }

    fn decode(version: u32, bytes: &[u8]) -> Result<DtaEstimate, postcard::Error> {
        match version {
            0 | 1 => postcard::from_bytes::<DtaEstimateV1>(bytes).map(DtaEstimate::from),
            CODEC_VERSION => postcard::from_bytes(bytes),
            _ => Err(postcard::Error::DeserializeBadEncoding),
        }
    }

    /// The front's horizontal and vertical deviation.
    fn extremes(&self) -> [f64; 2] {
        [self.front.horizontal_mm, self.front.vertical_mm]
    }

    /// The front's and rear's deviations.
    fn signals(&self) -> Signals {
        let mm = |p: &PointDeviation| [p.horizontal_mm, p.vertical_mm];
        let sigma_mm = |p: &PointDeviation| {
            [
                p.sigma_horizontal_mm.unwrap_or(0.0),
                p.sigma_vertical_mm.unwrap_or(0.0),
            ]
        };
        Signals {
            deviation: Some(DeviationSignal {
                front_mm: mm(&self.front),
                rear_mm: mm(&self.rear),
                front_sigma_mm: sigma_mm(&self.front),
                rear_sigma_mm: sigma_mm(&self.rear),
            }),
            ..Signals::default()
        }
    }
}

/// A `dta` estimate as the release before the points' σ stored it (codec
/// version 1).
#[derive(Deserialize)]
struct DtaEstimateV1 {
    source: DtaSource,
    station_m: f64,
    front: PointDeviationV1,
    rear: PointDeviationV1,
    tendency_horizontal_mm_per_m: f64,
    tendency_vertical_mm_per_m: f64,
    status: Option<DtaStatus>,
}

#[derive(Deserialize)]
struct PointDeviationV1 {
    station_m: f64,
    horizontal_mm: f64,
    vertical_mm: f64,
}

impl From<PointDeviationV1> for PointDeviation {
    fn from(p: PointDeviationV1) -> PointDeviation {
        PointDeviation {
            station_m: p.station_m,
            horizontal_mm: p.horizontal_mm,
            vertical_mm: p.vertical_mm,
            sigma_horizontal_mm: None,
            sigma_vertical_mm: None,
        }
    }
}

impl From<DtaEstimateV1> for DtaEstimate {
    fn from(v: DtaEstimateV1) -> DtaEstimate {
        DtaEstimate {
            source: v.source,
            station_m: v.station_m,
            front: v.front.into(),
            rear: v.rear.into(),
            tendency_horizontal_mm_per_m: v.tendency_horizontal_mm_per_m,
            tendency_vertical_mm_per_m: v.tendency_vertical_mm_per_m,
            status: v.status,
        }
    }
}

/// The stage's configuration, from the machine's declaration.
#[derive(Debug, Clone, PartialEq)]
struct Setup {
    alignment: Arc<Alignment>,
    geometry: MachineGeometry,
    tolerances: Option<Tolerances>,
    /// The `zupt` source's start point; `None`: no `zupt` source.
    start: Option<ProjectPoint>,
    /// Whether laser positions are a source (the machine runs `attitude`).
    laser: bool,
}

/// What the stage remembers between readings.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
struct DtaState {
    state_version: u32,
    /// The newest fused pitch and roll, degrees.
    attitude_deg: Option<(f64, f64)>,
    /// Their integrity (`ok` in snapshots from before estimates had one).
    #[serde(default)]
    attitude_integrity: Integrity,
    /// Positions that fell outside the alignment's station range.
    outside: u64,
    /// Laser positions without a yaw (no direction for the points).
    without_yaw: u64,
}

/// The stage.
#[derive(Debug, Clone, PartialEq)]
pub struct DtaStage {
    setup: Setup,
    state: DtaState,
}

impl DtaStage {
    fn setup(declaration: &Declaration) -> Option<Setup> {
        let alignment = declaration.alignment.clone()?;
        let geometry = declaration.geometry?;
        let laser = declaration.runs(EngineKind::Attitude);
        let start = declaration
            .start
            .filter(|_| declaration.runs(EngineKind::Zupt));
        (laser || start.is_some()).then_some(Setup {
            alignment,
            geometry,
            tolerances: declaration.tolerances,
            start,
            laser,
        })
    }

    /// Deviations of the machine with its reference point at `reference`
    /// and attitude (`yaw`, `pitch`, `roll`, degrees); `None` if a point
    /// lies beyond the alignment.
    fn locate(
        &self,
        source: DtaSource,
        reference: ProjectPoint,
        (yaw_deg, pitch_deg, roll_deg): (f64, f64, f64),
        uncertainty: Option<Uncertainty>,
    ) -> Option<DtaEstimate> {
        let c = attitude_from_euler(rad(roll_deg), rad(pitch_deg), rad(yaw_deg));
        let alignment = &self.setup.alignment;
        let point = |body: [f64; 3]| {
            let ned = c * V3::new(body[0], body[1], body[2]);
            let (e, n, h) = (
                reference.easting_m + ned.y,
                reference.northing_m + ned.x,
                reference.height_m - ned.z,
            );
            let d = alignment.deviation(e, n, h).ok()?;
            let sigma = match uncertainty {
                Some(u) => {
                    let (pose, _) = alignment.axis_at(d.internal_station_m)?;
                    let (h, v) = u.of_point(ned, pose.azimuth_rad);
                    (Some(h), Some(v))
                }
                None => (None, None),
            };
            Some((d, sigma))
        };
        let centre = alignment
            .deviation(
                reference.easting_m,
                reference.northing_m,
                reference.height_m,
            )
            .ok()?;
        let (front, rear) = (
            point(self.setup.geometry.front_m)?,
            point(self.setup.geometry.rear_m)?,
        );
        let mm = |(d, sigma): (super::alignment::Deviation, (Option<f64>, Option<f64>))| {
            PointDeviation {
                station_m: d.station_m,
                horizontal_mm: d.horizontal_m * 1000.0,
                vertical_mm: d.vertical_m * 1000.0,
                sigma_horizontal_mm: sigma.0,
                sigma_vertical_mm: sigma.1,
            }
        };
        let (front, rear) = (mm(front), mm(rear));
        let g = self.setup.geometry;
        let length_m = V3::from(g.front_m).metric_distance(&V3::from(g.rear_m));
        let per_m = |a: f64, b: f64| {
            if length_m > 0.0 {
                (a - b) / length_m
            } else {
                0.0
            }
        };
        let status = self.setup.tolerances.map(|t| {
            [
                grade(
                    front.horizontal_mm,
                    front.sigma_horizontal_mm,
                    t.horizontal_mm,
                ),
                grade(
                    rear.horizontal_mm,
                    rear.sigma_horizontal_mm,
                    t.horizontal_mm,
                ),
                grade(front.vertical_mm, front.sigma_vertical_mm, t.vertical_mm),
                grade(rear.vertical_mm, rear.sigma_vertical_mm, t.vertical_mm),
            ]
            .into_iter()
            .max_by_key(|s| s.rank())
            .unwrap_or(DtaStatus::Ok)
        });
        Some(DtaEstimate {
            source,
            station_m: centre.station_m,
            tendency_horizontal_mm_per_m: per_m(front.horizontal_mm, rear.horizontal_mm),
            tendency_vertical_mm_per_m: per_m(front.vertical_mm, rear.vertical_mm),
            front,
            rear,
            status,
        })
    }

    /// Emits `located`, of a source of `integrity`: a source that cannot
    /// vouch for its position leaves the status unknown.
    fn emit(
        &mut self,
        t: f64,
        located: Option<DtaEstimate>,
        integrity: Integrity,
        out: &mut Vec<EngineOutput>,
    ) {
        match located {
            Some(mut estimate) => {
                if integrity.level == IntegrityLevel::Lost && estimate.status.is_some() {
                    estimate.status = Some(DtaStatus::Unknown);
                }
                out.push(EngineOutput {
                    t,
                    values: EstimateValues::Dta(estimate),
                    integrity: integrity.inherited(),
                })
            }
            None => self.state.outside += 1,
        }
    }
}

impl Stage for DtaStage {
    fn kind(&self) -> StageKind {
        StageKind::Dta
    }

    fn reads(&self, sensor: SensorKind) -> bool {
        self.setup.laser && sensor == SensorKind::Laser
    }

    fn reading(&mut self, reading: &Reading, out: &mut Vec<EngineOutput>) {
        let SensorData::Laser {
            pitch_deg,
            roll_deg,
            yaw_deg,
            position: Some(position),
        } = reading.data
        else {
            return;
        };
        if !self.setup.laser {
            return;
        }
        let Some(yaw_deg) = yaw_deg else {
            self.state.without_yaw += 1;
            return;
        };
        // The engine's fused attitude unless it cannot vouch for it: then
        // the laser's own, as before the engine's first laser sample.
        let fused = self
            .state
            .attitude_deg
            .filter(|_| self.state.attitude_integrity.level != IntegrityLevel::Lost);
        let ((pitch, roll), integrity) = match fused {
            Some(attitude) => (attitude, self.state.attitude_integrity),
            None => ((pitch_deg, roll_deg), Integrity::OK),
        };
        let located = self.locate(DtaSource::Laser, position, (yaw_deg, pitch, roll), None);
        self.emit(reading.t, located, integrity, out);
    }

    fn estimate(&mut self, estimate: &EngineOutput, out: &mut Vec<EngineOutput>) {
        match &estimate.values {
            // Only once the engine has had a laser sample: before, its pitch
            // carries the inclinometer's unlearned error (tenths of a degree,
            // centimetres over the shield), and the laser's own is better.
            EstimateValues::Attitude(a) if a.laser_age_s.is_some() => {
                self.state.attitude_deg = Some((a.pitch_deg, a.roll_deg));
                self.state.attitude_integrity = estimate.integrity;
            }
            EstimateValues::Zupt(z) if z.aligned => {
                let Some(start) = self.setup.start else {
                    return;
                };
                let [north, east, down] = z.position_m;
                let reference = ProjectPoint {
                    easting_m: start.easting_m + east,
                    northing_m: start.northing_m + north,
                    height_m: start.height_m - down,
                };
                // With the INS's own σ (estimates stored before it reported
                // its attitude σ: heading σ alone, tilt taken as exact).
                let attitude_sigma_deg = z
                    .attitude_sigma_deg
                    .or(z.yaw_sigma_deg.map(|yaw| [0.0, 0.0, yaw]));
                let uncertainty = attitude_sigma_deg.map(|a| Uncertainty {
                    position_m: z.position_sigma_m,
                    attitude_rad: a.map(rad),
                });
                let located = self.locate(
                    DtaSource::Zupt,
                    reference,
                    (z.yaw_deg, z.pitch_deg, z.roll_deg),
                    uncertainty,
                );
                self.emit(estimate.t, located, estimate.integrity, out);
            }
            _ => {}
        }
    }

    fn snapshot(&self) -> serde_json::Value {
        // Plain numbers: serialising cannot fail.
        serde_json::to_value(&self.state).unwrap_or(serde_json::Value::Null)
    }
}

/// The `dta` stage as the registry lists it.
pub struct Dta;

impl StageDescriptor for Dta {
    const SUMMARY: &'static str = "deviation from the designed tunnel axis at the machine's front and rear, for machines with an alignment";
    type Stage = DtaStage;
    type Output = DtaEstimate;

    fn create(declaration: &Declaration) -> Option<DtaStage> {
        Some(DtaStage {
            setup: DtaStage::setup(declaration)?,
            state: DtaState {
                state_version: STATE_VERSION,
                ..DtaState::default()
            },
        })
    }
    fn restore(
        declaration: &Declaration,
        snapshot: serde_json::Value,
    ) -> Result<DtaStage, SnapshotError> {
        SnapshotError::check_version(StreamKind::Dta, &snapshot, STATE_VERSION)?;
        let state: DtaState = SnapshotError::parse(StreamKind::Dta, snapshot)?;
        let setup = DtaStage::setup(declaration).ok_or(SnapshotError::Invalid(
            "a dta snapshot for a machine without an alignment and geometry".into(),
        ))?;
        Ok(DtaStage { setup, state })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::IntegrityReason;
    use crate::fusion::alignment::AlignmentSpec;

    /// Due north from (1000, 5000) for 100 m, level at 50 m; the front 4 m
    /// ahead of the reference point, the rear 5 m behind.
    fn declaration(engines: &[EngineKind]) -> Declaration {
        let axis = r#"{"start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 0.0},
            "horizontal": [{"type": "line", "length_m": 100.0}],
            "vertical": {"start_height_m": 50.0, "end_grade_pct": 0.0}}"#;
        let spec: AlignmentSpec = serde_json::from_str(axis).unwrap();
        Declaration {
            alignment: Some(Arc::new(spec.build().unwrap())),
            geometry: Some(MachineGeometry {
                front_m: [4.0, 0.0, 0.0],
                rear_m: [-5.0, 0.0, 0.0],
            }),
            tolerances: Some(Tolerances {
                horizontal_mm: Limits {
                    warn: 50.0,
                    alarm: 100.0,
                },
                vertical_mm: Limits {
                    warn: 30.0,
                    alarm: 60.0,
                },
            }),
            start: Some(ProjectPoint {
                easting_m: 1000.0,
                northing_m: 5000.0,
                height_m: 50.0,
            }),
            steering: None,
            engines: engines.to_vec(),
        }
    }

    fn laser(t: f64, yaw_deg: f64, position: ProjectPoint) -> Reading {
        Reading {
            t,
            data: SensorData::Laser {
                pitch_deg: 0.0,
                roll_deg: 0.0,
                yaw_deg: Some(yaw_deg),
                position: Some(position),
            },
        }
    }

    fn dta(out: &[EngineOutput]) -> &DtaEstimate {
        match &out.last().expect("an estimate").values {
            EstimateValues::Dta(d) => d,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_pipeline_offers_the_dta_estimates_to_steer_and_rings() {
        use crate::fusion::pipeline::Pipeline;
        use crate::fusion::steering::SteeringSpec;
        let declaration = Declaration {
            steering: Some(SteeringSpec::new(1500.0, 1.5, 6.0)),
            ..declaration(&[EngineKind::Attitude])
        };
        let engines = vec![
            EngineKind::Attitude
                .create(EngineKind::Attitude.params([]).unwrap())
                .unwrap(),
        ];
        let mut pipeline = Pipeline::declared(engines, &declaration);
        assert_eq!(
            pipeline.stages().collect::<Vec<_>>(),
            [StageKind::Dta, StageKind::Steer, StageKind::Rings]
        );
        assert!(pipeline.uses(SensorKind::Advance));
        let mut out = Vec::new();
        // 50 mm right of the axis, square to it: the laser's reading makes
        // the dta estimate from its position, and the curve from that (the
        // attitude engine waits for its inclinometer).
        let at = ProjectPoint {
            easting_m: 1000.05,
            northing_m: 5010.0,
            height_m: 50.0,
        };
        pipeline.feed(&laser(1.772e9, 0.0, at), &mut out);
        let streams: Vec<StreamKind> = out.iter().map(|o| o.values.stream()).collect();
        assert_eq!(streams, [StreamKind::Dta, StreamKind::Steer]);
        let EstimateValues::Steer(steer) = &out[1].values else {
            panic!("{out:?}")
        };
        // d0 = 50 mm, g0 = 0, R 1500 m, 1.5 m steps, a 9 m shield (at
        // least 18 m): the quintic's largest curvature 10/√3·d0/L² is
        // within 1/1500 from L ≥ 20.8 m, so 14 steps (21 m).
        assert_eq!((steer.steps, steer.station_m), (Some(14), 14.0));
        // A ring closed now logs the dta estimate the pipeline made.
        out.clear();
        let ring = Reading {
            t: 1.772e9 + 60.0,
            data: SensorData::Advance {
                ring: 7,
                strokes_mm: None,
            },
        };
        pipeline.feed(&ring, &mut out);
        let [
            EngineOutput {
                values: EstimateValues::Rings(record),
                ..
            },
        ] = out.as_slice()
        else {
            panic!("{out:?}")
        };
        assert_eq!((record.ring, record.dta_t), (7, Some(1.772e9)));
        assert!((record.front_horizontal_mm.unwrap() - 50.0).abs() < 1e-6);
        assert!((record.station_m.unwrap() - 10.0).abs() < 1e-9);
    }

    #[test]
    fn a_snapshot_from_before_the_ring_log_continues_seeded_as_a_replay_would() {
        use crate::fusion::pipeline::Pipeline;
        let declaration = declaration(&[EngineKind::Attitude]);
        let engines = || {
            vec![
                EngineKind::Attitude
                    .create(EngineKind::Attitude.params([]).unwrap())
                    .unwrap(),
            ]
        };
        let t0 = 1.772e9;
        let at = |east_m: f64| ProjectPoint {
            easting_m: 1000.0 + east_m,
            northing_m: 5010.0,
            height_m: 50.0,
        };
        let inclinometer = |t: f64| Reading {
            t,
            data: SensorData::Inclinometer {
                pitch_deg: 0.01,
                roll_deg: 0.2,
                temp_c: None,
            },
        };
        let mut replayed = Pipeline::declared(engines(), &declaration);
        let mut before = Vec::new();
        for i in 0..20 {
            let t = t0 + f64::from(i);
            replayed.feed(&inclinometer(t), &mut before);
            if i % 5 == 0 {
                replayed.feed(&laser(t + 0.5, 0.0, at(0.001 * f64::from(i))), &mut before);
            }
        }
        // The snapshot as the release before the ring log wrote it, and
        // the newest output of each stream as the store keeps them.
        let mut state = replayed.state();
        assert!(state.stages.remove(&StageKind::Rings).is_some());
        let text = serde_json::to_string(&state).unwrap();
        assert!(matches!(
            Pipeline::restore(serde_json::from_str(&text).unwrap(), &declaration),
            Err(SnapshotError::MissingStage(StageKind::Rings))
        ));
        let newest: Vec<EngineOutput> = [StreamKind::Attitude, StreamKind::Dta]
            .iter()
            .filter_map(|s| {
                before
                    .iter()
                    .rev()
                    .find(|o| o.values.stream() == *s)
                    .cloned()
            })
            .collect();
        let mut seeded =
            Pipeline::restore_seeded(serde_json::from_str(&text).unwrap(), &declaration, &newest)
                .unwrap();
        // A ring closed now is logged alike.
        let ring = Reading {
            t: t0 + 30.0,
            data: SensorData::Advance {
                ring: 12,
                strokes_mm: None,
            },
        };
        let (mut a, mut b) = (Vec::new(), Vec::new());
        replayed.feed(&ring, &mut a);
        seeded.feed(&ring, &mut b);
        assert_eq!(a, b);
        let EstimateValues::Rings(record) = &a[0].values else {
            panic!("{a:?}")
        };
        assert_eq!(record.dta_t, Some(t0 + 15.5));
        assert!(record.pitch_deg.is_some());
    }

    #[test]
    fn front_and_rear_by_hand_from_a_laser_position() {
        let mut stage = Dta::create(&declaration(&[EngineKind::Attitude])).unwrap();
        let mut out = Vec::new();
        // 20 mm right (east) of the axis, 29 mm high, square to it.
        let at = ProjectPoint {
            easting_m: 1000.02,
            northing_m: 5010.0,
            height_m: 50.029,
        };
        stage.reading(&laser(1.0, 0.0, at), &mut out);
        let d = dta(&out);
        assert_eq!(d.source, DtaSource::Laser);
        assert!((d.station_m - 10.0).abs() < 1e-9);
        assert!((d.front.station_m - 14.0).abs() < 1e-9 && (d.rear.station_m - 5.0).abs() < 1e-9);
        for p in [d.front, d.rear] {
            assert!((p.horizontal_mm - 20.0).abs() < 1e-6, "{p:?}");
            assert!((p.vertical_mm - 29.0).abs() < 1e-6, "{p:?}");
        }
        assert!(d.tendency_horizontal_mm_per_m.abs() < 1e-6);
        // Within both tolerances (vertical warns beyond 30 mm).
        assert_eq!(d.status, Some(DtaStatus::Ok));

        // An attitude estimate before the engine's first laser sample (its
        // pitch still carries the inclinometer's error) is not used.
        let attitude = |t: f64, pitch_deg: f64, laser_age_s: Option<f64>| EngineOutput {
            integrity: crate::fusion::Integrity::OK,
            t,
            values: EstimateValues::Attitude(crate::fusion::AttitudeEstimate {
                pitch_deg,
                roll_deg: 0.0,
                pitch_pred_deg: pitch_deg,
                roll_pred_deg: 0.0,
                pred_t: t + 1.0,
                pitch_sigma_deg: None,
                roll_sigma_deg: None,
                pitch_pred_sigma_deg: None,
                laser_ok: laser_age_s.is_some(),
                pitch_correction_deg: 0.0,
                laser_age_s,
                model_version: 0,
                incl_pitch_deg: pitch_deg,
                incl_roll_deg: 0.0,
            }),
        };
        stage.estimate(&attitude(1.2, 5.0, None), &mut out);
        stage.reading(&laser(1.5, 0.0, at), &mut out);
        let flat = dta(&out);
        assert!((flat.front.vertical_mm - 29.0).abs() < 1e-6, "{flat:?}");

        // Yawed 1° right and, from the attitude engine, pitched 1° nose up:
        // the front moves 4·sin 1° right and up, the rear 5·sin 1° left and
        // down; the tendency is 1000·tan 1°-ish mm/m both ways.
        let sin1 = 1f64.to_radians().sin();
        let fused = attitude(2.0, 1.0, Some(1.0));
        stage.estimate(&fused, &mut out);
        stage.reading(&laser(3.0, 1.0, at), &mut out);
        let d = dta(&out);
        let cos1 = 1f64.to_radians().cos();
        // Heading 1° east of north and pitched 1° up: the body x axis is
        // (E, N, up) = (cos1·sin1, cos1·cos1, sin1).
        let front_h = 20.0 + 1000.0 * 4.0 * cos1 * sin1;
        let rear_h = 20.0 - 1000.0 * 5.0 * cos1 * sin1;
        assert!((d.front.horizontal_mm - front_h).abs() < 1e-6, "{d:?}");
        assert!((d.rear.horizontal_mm - rear_h).abs() < 1e-6, "{d:?}");
        assert!(
            (d.front.vertical_mm - (29.0 + 4000.0 * sin1)).abs() < 1e-6,
            "{d:?}"
        );
        assert!(
            (d.rear.vertical_mm - (29.0 - 5000.0 * sin1)).abs() < 1e-6,
            "{d:?}"
        );
        assert!((d.tendency_horizontal_mm_per_m - 1000.0 * cos1 * sin1).abs() < 1e-6);
        assert!((d.tendency_vertical_mm_per_m - 1000.0 * sin1).abs() < 1e-6);
        // Front 29 + 69.8 mm high: beyond the 60 mm alarm.
        assert_eq!(d.status, Some(DtaStatus::Alarm));
    }

    #[test]
    fn a_zupt_position_is_relative_to_the_declared_start() {
        let mut stage = Dta::create(&declaration(&[EngineKind::Zupt])).unwrap();
        let mut out = Vec::new();
        let estimate = |position_m: [f64; 3], aligned| {
            let mut output = crate::fusion::estimate::zupt_for_tests(5.0, None);
            if let EstimateValues::Zupt(z) = &mut output.values {
                (z.zv, z.position_m, z.aligned) = (false, position_m, aligned);
                z.position_sigma_m = [0.01; 3];
                z.yaw_sigma_deg = Some(0.1);
                z.attitude_sigma_deg = Some([0.05, 0.05, 0.1]);
            }
            output
        };
        stage.estimate(&estimate([20.0, -0.07, 0.01], false), &mut out);
        assert!(out.is_empty(), "nothing before alignment");
        // 20 m north, 70 mm west (left), 10 mm down.
        stage.estimate(&estimate([20.0, -0.07, 0.01], true), &mut out);
        let d = dta(&out);
        assert_eq!(d.source, DtaSource::Zupt);
        assert!((d.station_m - 20.0).abs() < 1e-9);
        assert!(
            (d.front.horizontal_mm + 70.0).abs() < 1e-6
                && (d.front.vertical_mm + 10.0).abs() < 1e-6
        );
        // 70 mm left is beyond the 50 mm warning, but its 2σ band (below)
        // reaches back to 70 − 2·12.2 = 45.6 mm: the status cannot be told.
        assert_eq!(d.status, Some(DtaStatus::Unknown));
        // The INS's σ: 10 mm per coordinate, and the attitude's over the
        // lever (4 m ahead, 5 m behind, level, due north): across the axis
        // the heading's 0.1°, vertically the tilt about east, 0.05°:
        // √(10² + (4000·0.1°)²) = 12.1959 mm, √(10² + (4000·0.05°)²) =
        // 10.5917 mm; the rear's over 5 m 13.2723 and 10.9105 mm.
        let close = |a: Option<f64>, b: f64| (a.unwrap() - b).abs() < 1e-3;
        assert!(close(d.front.sigma_horizontal_mm, 12.1959), "{d:?}");
        assert!(close(d.front.sigma_vertical_mm, 10.5917), "{d:?}");
        assert!(close(d.rear.sigma_horizontal_mm, 13.2723), "{d:?}");
        assert!(close(d.rear.sigma_vertical_mm, 10.9105), "{d:?}");
        // Beyond the axis's end: no estimate, counted.
        stage.estimate(&estimate([120.0, 0.0, 0.0], true), &mut out);
        assert_eq!(out.len(), 1);
        assert_eq!(stage.state.outside, 1);
    }

    #[test]
    fn a_deviation_is_graded_only_where_its_two_sigma_band_agrees() {
        let limits = Limits {
            warn: 50.0,
            alarm: 100.0,
        };
        // No σ (a laser position): the value's own grade.
        assert_eq!(grade(49.9, None, limits), DtaStatus::Ok);
        assert_eq!(grade(-50.1, None, limits), DtaStatus::Warn);
        assert_eq!(grade(100.1, None, limits), DtaStatus::Alarm);
        // 30 ± 2·9.9 = 10.2 … 49.8: ok throughout.
        assert_eq!(grade(30.0, Some(9.9), limits), DtaStatus::Ok);
        // 30 ± 2·10.1 reaches 50.2: unknown.
        assert_eq!(grade(30.0, Some(10.1), limits), DtaStatus::Unknown);
        // −75 ± 2·12: 51 … 99, a warning either way.
        assert_eq!(grade(-75.0, Some(12.0), limits), DtaStatus::Warn);
        // 140 ± 2·15: 110 … 170, an alarm either way.
        assert_eq!(grade(140.0, Some(15.0), limits), DtaStatus::Alarm);
        // 90 ± 2·6 crosses the alarm limit.
        assert_eq!(grade(90.0, Some(6.0), limits), DtaStatus::Unknown);
        // The estimate shows a certain alarm over an unknown, an unknown
        // over a certain warning.
        let worst = |a: DtaStatus, b: DtaStatus| [a, b].into_iter().max_by_key(|s| s.rank());
        assert_eq!(
            worst(DtaStatus::Unknown, DtaStatus::Alarm),
            Some(DtaStatus::Alarm)
        );
        assert_eq!(
            worst(DtaStatus::Warn, DtaStatus::Unknown),
            Some(DtaStatus::Unknown)
        );
    }

    #[test]
    fn a_source_that_cannot_vouch_leaves_the_status_unknown_and_is_inherited() {
        let mut stage = Dta::create(&declaration(&[EngineKind::Zupt])).unwrap();
        let mut out = Vec::new();
        let mut output = crate::fusion::estimate::zupt_for_tests(5.0, None);
        if let EstimateValues::Zupt(z) = &mut output.values {
            (z.zv, z.position_m, z.aligned) = (false, [20.0, 0.0, 0.0], true);
        }
        stage.estimate(&output, &mut out);
        assert_eq!(dta(&out).status, Some(DtaStatus::Ok));
        assert_eq!(out[0].integrity, Integrity::OK);
        output.integrity = Integrity::lost(IntegrityReason::TiltDisagrees);
        out.clear();
        stage.estimate(&output, &mut out);
        assert_eq!(dta(&out).status, Some(DtaStatus::Unknown));
        assert_eq!(out[0].integrity, output.integrity);
        output.integrity = Integrity::degraded(IntegrityReason::Innovations);
        out.clear();
        stage.estimate(&output, &mut out);
        assert_eq!(dta(&out).status, Some(DtaStatus::Ok));
        assert_eq!(out[0].integrity, output.integrity);
    }

    #[test]
    fn only_a_declared_axis_and_geometry_make_the_stage() {
        let full = declaration(&[EngineKind::Attitude]);
        assert!(Dta::create(&full).is_some());
        assert!(
            Dta::create(&Declaration {
                alignment: None,
                ..full.clone()
            })
            .is_none()
        );
        assert!(
            Dta::create(&Declaration {
                geometry: None,
                ..full.clone()
            })
            .is_none()
        );
        // A fuzzy machine has no position to locate.
        assert!(Dta::create(&declaration(&[EngineKind::Fuzzy])).is_none());
        // Zupt without a start has none either.
        let zupt = declaration(&[EngineKind::Zupt]);
        assert!(
            Dta::create(&Declaration {
                start: None,
                ..zupt
            })
            .is_none()
        );
    }

    #[test]
    fn an_estimate_stored_before_the_points_sigma_still_reads() {
        // The layout codec 1 stored: points without σ.
        #[derive(Serialize)]
        struct Point(f64, f64, f64);
        #[derive(Serialize)]
        struct V1(DtaSource, f64, Point, Point, f64, f64, Option<DtaStatus>);
        let bytes = postcard::to_allocvec(&V1(
            DtaSource::Laser,
            12.5,
            Point(16.7, 20.0, -3.0),
            Point(7.4, 18.0, -2.0),
            0.215,
            -0.1,
            Some(DtaStatus::Ok),
        ))
        .unwrap();
        let d = DtaEstimate::decode(1, &bytes).unwrap();
        assert_eq!(d.front.horizontal_mm, 20.0);
        assert_eq!(d.rear.vertical_mm, -2.0);
        assert_eq!(d.front.sigma_horizontal_mm, None);
        assert_eq!(d.status, Some(DtaStatus::Ok));
        assert!(DtaEstimate::decode(CODEC_VERSION + 1, &bytes).is_err());
        // This release's form round-trips.
        assert_eq!(DtaEstimate::decode(CODEC_VERSION, &d.encode()).unwrap(), d);
    }
}
