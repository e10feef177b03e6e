//! What an engine or a stage declares about itself: the one seam between
//! a method's module and the rest of tunnelnav.
//!
//! An engine implements [`EngineDescriptor`] (sensors, parameters, how it
//! is created and restored) and its estimate type implements
//! [`StreamValues`] (NDJSON fields, stored codec, OpenAPI schema, the
//! [`Signals`] the alarm rules and the status watch); a stage does the
//! same with [`StageDescriptor`]. The `registry!` list
//! (`src/fusion/registry.rs`) turns the descriptors into the kinds and
//! every dispatch. This module names no engine and no stage.

use std::borrow::Cow;

use serde::Serialize;
use serde::de::DeserializeOwned;
use utoipa::openapi::{RefOr, Schema};

use super::json_fields::JsonFields;
use super::params::{ParamError, Params, Retired, TypedParams};
use super::reading::SensorKind;
use super::{Declaration, Engine, SnapshotError, Stage};

/// What an engine module declares about itself.
pub trait EngineDescriptor {
    /// One line on the method, for help texts.
    const SUMMARY: &'static str;
    /// The sensors the engine consumes; it ignores the others.
    const SENSORS: &'static [SensorKind];
    /// Parameters earlier releases had: stored machines that name them
    /// still load, new declarations that do are refused with the reason.
    const RETIRED: &'static [Retired];

    /// The parameters, typed; its table is the engine's parameter specs.
    type Params: TypedParams;
    /// The engine itself.
    type Engine: Engine + 'static;
    /// What the engine emits per estimate.
    type Estimate: StreamValues;
    /// What the model endpoint reports ([`NoModel`] if nothing).
    type Model: ModelReport;

    /// A fresh engine with validated parameters.
    fn create(params: Params) -> Result<Self::Engine, ParamError>;
    /// An engine continuing from its [`Engine::snapshot`].
    fn restore(snapshot: serde_json::Value) -> Result<Self::Engine, SnapshotError>;
}

/// What a stage module declares about itself (see [`Stage`]).
pub trait StageDescriptor {
    /// One line on what the stage derives.
    const SUMMARY: &'static str;
    /// The stage itself.
    type Stage: Stage + 'static;
    /// What the stage emits per estimate.
    type Output: StreamValues;

    /// Whether a machine's snapshot from before the stage existed may
    /// continue with it seeded from the newest stored output of each of
    /// the machine's streams (see [`Pipeline::restore_seeded`]): true only
    /// where that is the state a replay of the stored readings would reach
    /// (no reading the stage itself reads could be stored before it).
    ///
    /// [`Pipeline::restore_seeded`]: super::pipeline::Pipeline::restore_seeded
    const SEEDED: bool = false;

    /// The stage for a machine so declared; `None` when the declaration
    /// does not call for it.
    fn create(declaration: &Declaration) -> Option<Self::Stage>;
    /// A stage of a machine so declared continuing from its [`Stage::snapshot`].
    fn restore(
        declaration: &Declaration,
        snapshot: serde_json::Value,
    ) -> Result<Self::Stage, SnapshotError>;
}

/// The values of one stream's estimates (an engine's estimate, a stage's
/// output): how they are written, stored, described and watched.
pub trait StreamValues:
    Serialize + DeserializeOwned + Clone + PartialEq + std::fmt::Debug + utoipa::ToSchema
{
    /// The version of the stored form this release writes;
    /// [`StreamValues::decode`] reads it and every earlier one.
    const CODEC_VERSION: u32;
    /// The signals [`StreamValues::signals`] tells (empty: none).
    const SIGNALS: &'static [SignalKind];

    /// The fields after `"engine"`, byte for byte as serde_json writes them.
    fn write_fields(&self, fields: &mut JsonFields<'_>);
    /// The stored form of [`StreamValues::CODEC_VERSION`]: postcard.
    fn encode(&self) -> Vec<u8> {
        super::estimate::postcard_bytes(self)
    }
    /// Values stored with codec `version` (0: stored before rows carried
    /// a version). Each type keeps its earlier forms readable here.
    fn decode(version: u32, bytes: &[u8]) -> Result<Self, postcard::Error>;
    /// The two quantities whose extremes history downsampling keeps.
    fn extremes(&self) -> [f64; 2];
    /// What the alarm rules and the machine's status watch in these
    /// values. Required: a new stream says what it offers, or that it
    /// offers nothing, rather than being silently left out of the rules.
    fn signals(&self) -> Signals;
}

/// What an engine's model endpoint reports.
pub trait ModelReport: Serialize + Clone + PartialEq + std::fmt::Debug {
    /// The report's OpenAPI schema, `None` for [`NoModel`].
    fn schema() -> Option<SchemaComponent>;
}

impl<T> ModelReport for T
where
    T: Serialize + Clone + PartialEq + std::fmt::Debug + utoipa::ToSchema,
{
    fn schema() -> Option<SchemaComponent> {
        Some(SchemaComponent::of::<T>())
    }
}

/// A model report for engines that have none.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum NoModel {}

impl ModelReport for NoModel {
    fn schema() -> Option<SchemaComponent> {
        None
    }
}

/// A named OpenAPI schema and how to collect the schemas it refers to.
pub struct SchemaComponent {
    pub name: Cow<'static, str>,
    pub schema: RefOr<Schema>,
    referred: fn(&mut Vec<(String, RefOr<Schema>)>),
}

impl SchemaComponent {
    /// The component of `T`.
    pub fn of<T: utoipa::ToSchema>() -> SchemaComponent {
        SchemaComponent {
            name: T::name(),
            schema: T::schema(),
            referred: T::schemas,
        }
    }

    /// Adds it, and what it refers to, to `schemas`.
    pub fn collect(self, schemas: &mut Vec<(String, RefOr<Schema>)>) {
        schemas.push((self.name.into(), self.schema));
        (self.referred)(schemas);
    }
}

/// What the alarm rules (`src/fusion/alarms/`) and the machine's status
/// read of one estimate; `None` where the stream does not tell. A machine
/// has one of each rule: where several of its streams tell the same
/// signal, the first in registry order is watched.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Signals {
    /// The laser targeting system (`laser_dropout`, the status's `laser`).
    pub laser: Option<LaserSignal>,
    /// Pitch 1σ, degrees, once the pitch rests on an absolute reference
    /// (`attitude_uncertainty`).
    pub pitch_sigma_deg: Option<f64>,
    /// An inertial navigation solution (`ins_uncertainty`, `engine_reset`).
    pub navigation: Option<Navigation>,
    /// Deviation from the design axis (`deviation`).
    pub deviation: Option<DeviationSignal>,
    /// Whether a correction curve within the machine's minimum radius
    /// reaches the axis (`steering_infeasible`).
    pub steering_feasible: Option<bool>,
}

/// A signal a stream may tell: one per field of [`Signals`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum SignalKind {
    Laser,
    PitchSigma,
    Navigation,
    Deviation,
    Steering,
}

impl Signals {
    /// The signals told here.
    pub fn kinds(&self) -> Vec<SignalKind> {
        [
            (self.laser.is_some(), SignalKind::Laser),
            (self.pitch_sigma_deg.is_some(), SignalKind::PitchSigma),
            (self.navigation.is_some(), SignalKind::Navigation),
            (self.deviation.is_some(), SignalKind::Deviation),
            (self.steering_feasible.is_some(), SignalKind::Steering),
        ]
        .into_iter()
        .filter_map(|(told, kind)| told.then_some(kind))
        .collect()
    }
}

/// The laser's state as an engine that reads it sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserSignal {
    /// A sample recent enough to rest the estimate on.
    pub ok: bool,
    /// Seconds since the newest sample; `None` before the first.
    pub age_s: Option<f64>,
}

/// An inertial navigation solution's state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Navigation {
    /// Aligned: positions hold, with this horizontal 1σ, mm.
    Aligned { horizontal_sigma_mm: f64 },
    /// Aligning (at the start or after losing the solution).
    Aligning,
}

/// Deviations from the design axis, mm: `[horizontal, vertical]`, with
/// their 1σ (0 where the stream states none).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviationSignal {
    pub front_mm: [f64; 2],
    pub rear_mm: [f64; 2],
    pub front_sigma_mm: [f64; 2],
    pub rear_sigma_mm: [f64; 2],
}
