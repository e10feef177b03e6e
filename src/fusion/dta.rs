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
use super::declaration::{Limits, MachineGeometry, Tolerances};
use super::descriptor::{DeviationSignal, SignalKind, Signals, StageDescriptor, StreamValues};
use super::estimate::{EngineOutput, EstimateValues};
use super::geometry::{V3, attitude_from_euler};
use super::integrity::{Integrity, IntegrityLevel};
use super::json_fields::JsonFields;
use super::reading::{ProjectPoint, Reading, SensorData, SensorKind};
use super::registry::{EngineKind, StageKind};
use super::{Declaration, Stage};
use super::{SnapshotError, StreamKind};

/// Version of the stage's snapshot.
pub const STATE_VERSION: u32 = 1;
/// Version of the stored [`DtaEstimate`]. 1: before the points' σ
/// ([`DtaEstimateV1`]).
pub const CODEC_VERSION: u32 = 2;

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
mod tests;
