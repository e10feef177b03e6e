//! The pure fusion core: protocol types, the [`Engine`] trait and one module
//! per engine. Nothing here does IO, spawns tasks or reads a clock: time
//! arrives with each reading, so the server, `replay` and the tests run the
//! very same code and get the very same estimates.

pub mod alarms;
pub mod alignment;
pub mod angles;
pub mod attitude;
pub mod declaration;
pub mod descriptor;
pub mod dta;
pub mod estimate;
pub mod frozen;
pub mod fuzzy;
pub mod geometry;
pub mod integrity;
pub mod json_fields;
pub mod params;
pub mod pipeline;
pub mod pushes;
pub mod reading;
pub mod registry;
pub mod reorder;
pub mod ring_build;
pub mod ring_plan;
pub mod rings;
pub mod robust;
pub mod steer;
pub mod steering;
pub mod zupt;

pub use declaration::Declaration;
pub use descriptor::{
    EngineDescriptor, ModelReport, NoModel, Signals, StageDescriptor, StreamValues,
};
pub use estimate::{
    AttitudeEstimate, EngineOutput, Estimate, EstimateRef, EstimateValues, FuzzyEstimate, Motion,
    ZuptEstimate,
};
pub use integrity::{Integrity, IntegrityLevel, IntegrityReason};
pub use params::{ParamError, ParamKind, ParamSpec, ParamValue, Params, Retired};
pub use reading::{Reading, ReadingError, SensorData, SensorKind, parse_reading};
pub use registry::{CodecError, EngineKind, EngineModel, StageKind, StreamKind, UnknownEngine};

/// A fusion method that turns a machine's readings into estimates.
///
/// Readings are fed in time order (a [`reorder::ReorderBuffer`] in front
/// absorbs small disorder); each engine documents what it does with the rest.
pub trait Engine: Send {
    /// Which engine this is.
    fn kind(&self) -> EngineKind;

    /// Feeds one validated reading; appends the estimates it produces to `out`.
    /// Readings of sensors the engine does not use are ignored.
    fn feed(&mut self, reading: &Reading, out: &mut Vec<EngineOutput>);

    /// The input has ended (end of a replayed file): emits the estimates of
    /// readings the engine was still holding. Engines that answer every
    /// reading at once hold none.
    fn flush(&mut self, _out: &mut Vec<EngineOutput>) {}

    /// The parameters the engine runs with.
    fn params(&self) -> &Params;

    /// The whole state, serialisable: [`EngineKind::restore`] continues
    /// from it exactly.
    fn snapshot(&self) -> serde_json::Value;

    /// Engine-specific model report (the `attitude` engine's learned
    /// pitch-error curve), if the engine has one.
    fn model(&self) -> Option<EngineModel> {
        None
    }
}

/// A stage after the engines: it derives a stream of its own from a
/// machine's declaration, the readings its engines are fed and the
/// estimates they emit (the jacking log from `zupt`'s pushes; the
/// deviation from the design axis from positions and attitude). Pure like
/// the engines: the server's machine actor and `replay` run the same
/// [`pipeline::Pipeline`] and get the same outputs.
pub trait Stage: Send {
    /// Which stage this is.
    fn kind(&self) -> StageKind;

    /// Whether the stage reads readings of `sensor` (a reading no engine
    /// and no stage reads is not fed at all).
    fn reads(&self, _sensor: SensorKind) -> bool {
        false
    }

    /// A reading as the engines are fed it (in time order, after the
    /// reorder buffer); appends what it derives to `out`. Most stages
    /// need only estimates.
    fn reading(&mut self, _reading: &Reading, _out: &mut Vec<EngineOutput>) {}

    /// An engine's estimate, or an earlier stage's output, in the order
    /// they are emitted; appends what it derives to `out` (offered in
    /// turn to the stages after this one).
    fn estimate(&mut self, estimate: &EngineOutput, out: &mut Vec<EngineOutput>);

    /// The whole state, serialisable: [`StageKind::restore`] continues
    /// from it exactly.
    fn snapshot(&self) -> serde_json::Value;
}

/// Why a snapshot could not be restored.
#[derive(Debug, thiserror::Error)]
pub enum SnapshotError {
    #[error("snapshot does not match the {engine} state: {source}")]
    Shape {
        engine: StreamKind,
        source: serde_json::Error,
    },
    #[error("snapshot holds invalid parameters: {0}")]
    Params(#[from] ParamError),
    #[error("snapshot state is inconsistent: {0}")]
    Invalid(String),
    #[error(
        "snapshot of the {engine} state has state version {found}, this release reads {expected}"
    )]
    Outdated {
        engine: StreamKind,
        found: u64,
        expected: u64,
    },
    #[error("snapshot has no state of the {0} stage the machine now runs")]
    MissingStage(StageKind),
}

impl SnapshotError {
    /// Refuses a snapshot whose `state_version` (1 when absent: before
    /// versions existed) is not `expected`, as outdated.
    pub fn check_version(
        engine: impl Into<StreamKind>,
        snapshot: &serde_json::Value,
        expected: u32,
    ) -> Result<(), SnapshotError> {
        let found = snapshot
            .get("state_version")
            .and_then(serde_json::Value::as_u64)
            .unwrap_or(1);
        if found == u64::from(expected) {
            Ok(())
        } else {
            Err(SnapshotError::Outdated {
                engine: engine.into(),
                found,
                expected: u64::from(expected),
            })
        }
    }

    /// An engine's state deserialised from its snapshot.
    pub fn parse<T: serde::de::DeserializeOwned>(
        engine: impl Into<StreamKind>,
        snapshot: serde_json::Value,
    ) -> Result<T, SnapshotError> {
        serde_json::from_value(snapshot).map_err(|source| SnapshotError::Shape {
            engine: engine.into(),
            source,
        })
    }
}
