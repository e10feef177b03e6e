//! The `ring_plan` stage: the built lining and the next rings' key
//! positions, for a machine that declares its `rings` (the geometry and
//! the plan: `fusion/ring_build/`).
//!
//! It follows the machine through the `dta` stage's estimates (front and
//! rear, the rear being the tail skin's end), takes the correction curve
//! the `steer` stage holds as the target (the axis without one), adds a
//! ring to the lining per `advance` reading with a `key`, and corrects the
//! lining per `tail_clearance` reading. After each of those readings it
//! emits the newest ring as known and the plan for the next
//! [`LOOK_AHEAD`] rings, next first, each with its key, its predicted
//! clearance and the reason for it.

use serde::{Deserialize, Serialize};

use super::alignment::Alignment;
use super::descriptor::{SignalKind, Signals, StageDescriptor, StreamValues};
use super::estimate::{EngineOutput, EstimateValues};
use super::integrity::Integrity;
use super::json_fields::JsonFields;
use super::reading::{Reading, SensorData, SensorKind};
use super::registry::StageKind;
use super::ring_build::builder::GUIDANCE_SIGMA_MM;
use super::ring_build::chain;
use super::ring_build::plan::{BEAM, LOOK_AHEAD, Plan};
use super::ring_build::{BuiltRing, MachineAt, RingBuilder, RingSpec};
use super::steering;
use super::{Declaration, SnapshotError, Stage, StreamKind};

/// Version of the stage's snapshot.
pub const STATE_VERSION: u32 = 1;
/// Version of the stored [`RingPlanEstimate`].
pub const CODEC_VERSION: u32 = 1;

/// The newest ring as the stage knows it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct BuiltRingOut {
    /// Its number (the `advance` reading's); `null` before any `advance`.
    pub ring: Option<u64>,
    /// Its key position; `null` where the lining was started from a
    /// clearance (the ring in the tail, its key not known).
    pub key: Option<u32>,
    /// Station of its centre, as the stationing reads.
    pub station_m: f64,
    /// Its centre off the design axis, mm (+ right, up).
    pub horizontal_mm: f64,
    pub vertical_mm: f64,
    /// 1σ of those, mm.
    pub sigma_horizontal_mm: f64,
    pub sigma_vertical_mm: f64,
}

/// One ring of the plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct PlannedRingOut {
    /// The ring's number: the newest's plus one, two, …
    pub ring: Option<u64>,
    /// The key position to build it with.
    pub key: u32,
    /// Its clearance at each point, clockwise from the top, when the
    /// tail's end passes its centre, mm.
    pub predicted_clearance_mm: Vec<f64>,
    /// Its centre off the target (the correction curve, or the axis), mm.
    pub off_target_horizontal_mm: f64,
    pub off_target_vertical_mm: f64,
    /// Why this key.
    pub reason: String,
}

/// What the `ring_plan` stage emits per `advance` and `tail_clearance`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct RingPlanEstimate {
    /// The newest ring as known now.
    pub built: BuiltRingOut,
    /// The next rings, next first.
    pub rings: Vec<PlannedRingOut>,
    /// The plan's cost (`docs/rings.md`), mm².
    pub cost: f64,
    /// Whether the target is the steer stage's correction curve (else the
    /// axis).
    pub on_correction_curve: bool,
}

impl StreamValues for RingPlanEstimate {
    const CODEC_VERSION: u32 = CODEC_VERSION;
    const SIGNALS: &'static [SignalKind] = &[];

    fn write_fields(&self, w: &mut JsonFields<'_>) {
        w.object("built", |w| {
            let b = &self.built;
            match b.ring {
                Some(ring) => w.integer("ring", ring),
                None => w.null("ring"),
            }
            match b.key {
                Some(key) => w.integer("key", u64::from(key)),
                None => w.null("key"),
            }
            w.number("station_m", b.station_m);
            w.number("horizontal_mm", b.horizontal_mm);
            w.number("vertical_mm", b.vertical_mm);
            w.number("sigma_horizontal_mm", b.sigma_horizontal_mm);
            w.number("sigma_vertical_mm", b.sigma_vertical_mm);
        });
        w.objects("rings", &self.rings, |r, w| {
            match r.ring {
                Some(ring) => w.integer("ring", ring),
                None => w.null("ring"),
            }
            w.integer("key", u64::from(r.key));
            w.numbers("predicted_clearance_mm", &r.predicted_clearance_mm);
            w.number("off_target_horizontal_mm", r.off_target_horizontal_mm);
            w.number("off_target_vertical_mm", r.off_target_vertical_mm);
            w.text("reason", &r.reason);
        });
        w.number("cost", self.cost);
        w.flag("on_correction_curve", self.on_correction_curve);
    }

    fn decode(version: u32, bytes: &[u8]) -> Result<RingPlanEstimate, postcard::Error> {
        if version <= CODEC_VERSION {
            postcard::from_bytes(bytes)
        } else {
            Err(postcard::Error::DeserializeBadEncoding)
        }
    }

    /// The built ring's centre off the axis.
    fn extremes(&self) -> [f64; 2] {
        [self.built.horizontal_mm, self.built.vertical_mm]
    }

    fn signals(&self) -> Signals {
        Signals::default()
    }
}

/// What the stage keeps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct RingPlanState {
    state_version: u32,
    builder: RingBuilder,
    /// The steer stage's newest correction curve.
    target: Option<steering::Plan>,
    /// The newest `dta` estimate's integrity and internal station.
    integrity: Integrity,
    internal_station_m: Option<f64>,
}

/// The stage.
pub struct RingPlanStage {
    spec: RingSpec,
    alignment: std::sync::Arc<Alignment>,
    state: RingPlanState,
}

impl RingPlanStage {
    /// The correction curve's offset at `station_m`, m (its start's before
    /// it starts).
    fn target(&self) -> Option<impl Fn(f64) -> [f64; 2] + '_> {
        let plan = self.state.target?;
        Some(move |station_m: f64| {
            steering::planned_deviation_mm(
                &*self.alignment,
                &plan,
                station_m.max(plan.start_station_m),
            )
            .map(|mm| mm / 1000.0)
        })
    }

    /// The plan from the lining now, as emitted.
    fn emit(&self, t: f64, built: BuiltRing, out: &mut Vec<EngineOutput>) {
        let axis = &*self.alignment;
        let target = self.target();
        let target_ref = target.as_ref().map(|f| f as &dyn Fn(f64) -> [f64; 2]);
        let Some(plan) = self
            .state
            .builder
            .plan(axis, &self.spec, target_ref, LOOK_AHEAD, BEAM)
        else {
            return;
        };
        let rings = self.planned(&plan, built.ring);
        let estimate = RingPlanEstimate {
            built: BuiltRingOut {
                ring: built.ring,
                key: self.state.builder.newest_key(),
                station_m: self.alignment.station_of(built.centre.station_m),
                horizontal_mm: built.centre.offset_m[0] * 1000.0,
                vertical_mm: built.centre.offset_m[1] * 1000.0,
                sigma_horizontal_mm: built.sigma_mm[0],
                sigma_vertical_mm: built.sigma_mm[1],
            },
            rings,
            cost: plan.cost,
            on_correction_curve: self.state.target.is_some(),
        };
        out.push(EngineOutput {
            t,
            values: EstimateValues::RingPlan(estimate),
            integrity: self.state.integrity.inherited(),
        });
    }

    /// The plan's rings with their numbers and reasons.
    fn planned(&self, plan: &Plan, newest: Option<u64>) -> Vec<PlannedRingOut> {
        plan.rings
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let least = r
                    .predicted_clearance_mm
                    .iter()
                    .copied()
                    .fold(f64::INFINITY, f64::min);
                let turn = chain::turn_rad(&self.spec, r.ring.key);
                let side = |v: f64, plus: &'static str, minus: &'static str| {
                    if v >= 0.0 { plus } else { minus }
                };
                let mut reason = format!(
                    "turns the lining {} {:.1} mm/m and {} {:.1} mm/m; its centre {:.0} mm {} and {:.0} mm {} of the {}; least clearance {:.0} mm",
                    side(turn[0], "right", "left"),
                    turn[0].abs() * 1000.0,
                    side(turn[1], "up", "down"),
                    turn[1].abs() * 1000.0,
                    r.off_target_mm[0].abs(),
                    side(r.off_target_mm[0], "right", "left"),
                    r.off_target_mm[1].abs(),
                    side(r.off_target_mm[1], "above", "below"),
                    if self.state.target.is_some() {
                        "correction curve"
                    } else {
                        "axis"
                    },
                    least,
                );
                if least < self.spec.min_clearance_mm {
                    reason.push_str(&format!(
                        " (below the least allowed {:.0} mm: no key keeps it)",
                        self.spec.min_clearance_mm
                    ));
                }
                PlannedRingOut {
                    ring: newest.map(|n| n + 1 + i as u64),
                    key: r.ring.key,
                    predicted_clearance_mm: r.predicted_clearance_mm.clone(),
                    off_target_horizontal_mm: r.off_target_mm[0],
                    off_target_vertical_mm: r.off_target_mm[1],
                    reason,
                }
            })
            .collect()
    }

    /// Where a `dta` estimate puts the machine, at internal stations.
    fn machine_at(&mut self, dta: &super::dta::DtaEstimate) -> Option<MachineAt> {
        let near = self.state.internal_station_m;
        let internal = |station_m: f64| self.alignment.internal_of(station_m, near);
        let front_station_m = internal(dta.front.station_m)?;
        let rear_station_m = internal(dta.rear.station_m)?;
        self.state.internal_station_m = Some(front_station_m);
        Some(MachineAt {
            front_station_m,
            front_m: [dta.front.horizontal_mm, dta.front.vertical_mm].map(|mm| mm / 1000.0),
            rear_station_m,
            rear_m: [dta.rear.horizontal_mm, dta.rear.vertical_mm].map(|mm| mm / 1000.0),
            rear_sigma_mm: [
                dta.rear.sigma_horizontal_mm.unwrap_or(GUIDANCE_SIGMA_MM),
                dta.rear.sigma_vertical_mm.unwrap_or(GUIDANCE_SIGMA_MM),
            ],
        })
    }
}

impl Stage for RingPlanStage {
    fn kind(&self) -> StageKind {
        StageKind::RingPlan
    }

    fn reads(&self, sensor: SensorKind) -> bool {
        matches!(sensor, SensorKind::Advance | SensorKind::TailClearance)
    }

    fn reading(&mut self, reading: &Reading, out: &mut Vec<EngineOutput>) {
        let axis = self.alignment.clone();
        let built = match &reading.data {
            SensorData::Advance { ring, key, .. } => {
                // A key beyond the declared positions is no key.
                let key = key.filter(|k| *k < self.spec.key_positions);
                self.state.builder.advance(&*axis, &self.spec, *ring, key)
            }
            SensorData::TailClearance { clearance_mm } => {
                self.state
                    .builder
                    .clearance(&*axis, &self.spec, clearance_mm)
            }
            _ => None,
        };
        if let Some(built) = built {
            self.emit(reading.t, built, out);
        }
    }

    fn estimate(&mut self, estimate: &EngineOutput, _out: &mut Vec<EngineOutput>) {
        match &estimate.values {
            EstimateValues::Dta(dta) => {
                if let Some(at) = self.machine_at(dta) {
                    self.state.builder.machine(at);
                    self.state.integrity = estimate.integrity;
                }
            }
            EstimateValues::Steer(steer) => self.state.target = steer.plan,
            _ => {}
        }
    }

    fn snapshot(&self) -> serde_json::Value {
        // Numbers, vectors and options: serialising cannot fail.
        serde_json::to_value(&self.state).unwrap_or_default()
    }
}

/// The `ring_plan` stage as the registry lists it.
pub struct RingPlan;

impl StageDescriptor for RingPlan {
    const SUMMARY: &'static str = "the built lining ring by ring and the key positions of the next rings, for machines that declare their rings";
    type Stage = RingPlanStage;
    type Output = RingPlanEstimate;

    fn create(declaration: &Declaration) -> Option<RingPlanStage> {
        // The machine's position comes from the dta stage.
        super::dta::Dta::create(declaration)?;
        Some(RingPlanStage {
            spec: declaration.rings.clone()?,
            alignment: declaration.alignment.clone()?,
            state: RingPlanState {
                state_version: STATE_VERSION,
                builder: RingBuilder::default(),
                target: None,
                integrity: Integrity::OK,
                internal_station_m: None,
            },
        })
    }

    fn restore(
        declaration: &Declaration,
        snapshot: serde_json::Value,
    ) -> Result<RingPlanStage, SnapshotError> {
        SnapshotError::check_version(StreamKind::RingPlan, &snapshot, STATE_VERSION)?;
        let state: RingPlanState = SnapshotError::parse(StreamKind::RingPlan, snapshot)?;
        let mut stage = RingPlan::create(declaration).ok_or(SnapshotError::Invalid(
            "a ring_plan snapshot for a machine without a dta stage and rings".into(),
        ))?;
        stage.state = state;
        Ok(stage)
    }
}
