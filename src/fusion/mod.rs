//! The pure fusion core: protocol types, the [`Engine`] trait and one module
//! per engine. Nothing here does IO, spawns tasks or reads a clock: time
//! arrives with each reading, so the server, `replay` and the tests run the
//! very same code and get the very same estimates.

pub mod angles;
pub mod attitude;
pub mod estimate;
pub mod fuzzy;
pub mod params;
pub mod reading;
pub mod reorder;
pub mod zupt;

pub use estimate::{
    AttitudeEstimate, EngineOutput, Estimate, EstimateRef, EstimateValues, FuzzyEstimate, Motion,
    ZuptEstimate,
};
pub use params::{ParamError, ParamKind, ParamSpec, ParamValue, Params, Retired};
pub use reading::{Reading, ReadingError, SensorData, SensorKind, parse_reading};

use serde::{Deserialize, Serialize};

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
    fn model(&self) -> Option<serde_json::Value> {
        None
    }
}

/// Why a snapshot could not be restored.
#[derive(Debug, thiserror::Error)]
pub enum SnapshotError {
    #[error("snapshot does not match the {engine} engine's state: {source}")]
    Shape {
        engine: EngineKind,
        source: serde_json::Error,
    },
    #[error("snapshot holds invalid parameters: {0}")]
    Params(#[from] ParamError),
    #[error("snapshot state is inconsistent: {0}")]
    Invalid(String),
    #[error(
        "snapshot of the {engine} engine has state version {found}, this release reads {expected}"
    )]
    Outdated {
        engine: EngineKind,
        found: u64,
        expected: u64,
    },
}

impl SnapshotError {
    /// Refuses a snapshot whose `state_version` (1 when absent: before
    /// versions existed) is not `expected`, as outdated.
    pub fn check_version(
        engine: EngineKind,
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
                engine,
                found,
                expected: u64::from(expected),
            })
        }
    }

    /// An engine's state deserialised from its snapshot.
    pub fn parse<T: serde::de::DeserializeOwned>(
        engine: EngineKind,
        snapshot: serde_json::Value,
    ) -> Result<T, SnapshotError> {
        serde_json::from_value(snapshot).map_err(|source| SnapshotError::Shape { engine, source })
    }
}

/// The engines tunnelnav knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EngineKind {
    /// Laser + inclinometer dual-rate ANFIS fusion (He et al. 2021).
    Attitude,
    /// FOG strapdown INS with zero-velocity updates (Zhang et al. 2024).
    Zupt,
    /// MEMS IMU + magnetometer fused by a fuzzy expert's motion status (Wang 2005).
    Fuzzy,
}

/// An engine name that tunnelnav does not know.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("unknown engine `{0}` (known: attitude, zupt, fuzzy)")]
pub struct UnknownEngine(pub String);

impl EngineKind {
    /// Every engine.
    pub const ALL: [EngineKind; 3] = [EngineKind::Attitude, EngineKind::Zupt, EngineKind::Fuzzy];

    /// The protocol name.
    pub fn as_str(self) -> &'static str {
        match self {
            EngineKind::Attitude => "attitude",
            EngineKind::Zupt => "zupt",
            EngineKind::Fuzzy => "fuzzy",
        }
    }

    /// The parameters the engine accepts.
    pub fn specs(self) -> &'static [ParamSpec] {
        match self {
            EngineKind::Attitude => attitude::PARAMS,
            EngineKind::Zupt => zupt::PARAMS,
            EngineKind::Fuzzy => fuzzy::PARAMS,
        }
    }

    /// Parameters earlier releases had: stored machines that name them
    /// still load, new declarations that do are refused with the reason.
    pub fn retired(self) -> &'static [Retired] {
        match self {
            EngineKind::Attitude => attitude::RETIRED,
            EngineKind::Fuzzy => fuzzy::RETIRED,
            EngineKind::Zupt => &[],
        }
    }

    /// Defaults with `overrides` on top; a retired name is refused with the
    /// reason it was retired.
    pub fn params(
        self,
        overrides: impl IntoIterator<Item = (String, ParamValue)>,
    ) -> Result<Params, ParamError> {
        let overrides: Vec<(String, ParamValue)> = overrides.into_iter().collect();
        for (name, _) in &overrides {
            params::check_retired(self.retired(), name)?;
        }
        Params::resolve(self.specs(), overrides)
    }

    /// Like [`EngineKind::params`], from `name=value` words.
    pub fn params_from_assignments<'a>(
        self,
        assignments: impl IntoIterator<Item = &'a str>,
    ) -> Result<Params, ParamError> {
        let assignments: Vec<&str> = assignments.into_iter().collect();
        for a in &assignments {
            if let Some((name, _)) = a.split_once('=') {
                params::check_retired(self.retired(), name.trim())?;
            }
        }
        Params::from_assignments(self.specs(), assignments)
    }

    /// The sensors the engine consumes.
    pub fn sensors(self) -> &'static [SensorKind] {
        match self {
            EngineKind::Attitude => &[SensorKind::Laser, SensorKind::Inclinometer],
            EngineKind::Zupt => &[SensorKind::Imu, SensorKind::Level, SensorKind::Odometer],
            EngineKind::Fuzzy => &[SensorKind::Imu, SensorKind::Magnetometer],
        }
    }

    /// A fresh engine with these parameters.
    pub fn create(self, params: Params) -> Result<Box<dyn Engine>, ParamError> {
        match self {
            EngineKind::Attitude => Ok(Box::new(attitude::AttitudeEngine::new(params)?)),
            EngineKind::Zupt => Ok(Box::new(zupt::ZuptEngine::new(params)?)),
            EngineKind::Fuzzy => Ok(Box::new(fuzzy::FuzzyEngine::new(params)?)),
        }
    }

    /// An engine continuing from a [`Engine::snapshot`].
    pub fn restore(self, snapshot: serde_json::Value) -> Result<Box<dyn Engine>, SnapshotError> {
        match self {
            EngineKind::Attitude => Ok(Box::new(attitude::AttitudeEngine::restore(snapshot)?)),
            EngineKind::Zupt => Ok(Box::new(zupt::ZuptEngine::restore(snapshot)?)),
            EngineKind::Fuzzy => Ok(Box::new(fuzzy::FuzzyEngine::restore(snapshot)?)),
        }
    }
}

impl std::str::FromStr for EngineKind {
    type Err = UnknownEngine;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        EngineKind::ALL
            .into_iter()
            .find(|k| k.as_str() == name)
            .ok_or_else(|| UnknownEngine(name.to_string()))
    }
}

impl std::fmt::Display for EngineKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}
