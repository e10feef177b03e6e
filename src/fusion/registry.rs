//! The engines and stages tunnelnav knows, listed once.
//!
//! Each engine module describes itself in one place by implementing
//! [`EngineDescriptor`] (`src/fusion/descriptor.rs`) and [`StreamValues`]
//! for its estimate; each stage with [`StageDescriptor`]. The `registry!`
//! list at the bottom of this file turns the descriptors into
//! [`EngineKind`] (a `clap::ValueEnum`), [`StageKind`], [`StreamKind`]
//! (engines and stages: what the estimates' `engine` field names),
//! [`EstimateValues`] and [`EngineModel`], whose dispatch (NDJSON, codec,
//! OpenAPI schemas, alarm signals, model reports) the compiler keeps
//! complete. Adding an engine: docs/development.md lists every file it
//! touches.

use serde::{Deserialize, Serialize};

use super::descriptor::{
    EngineDescriptor, ModelReport, SchemaComponent, SignalKind, Signals, StageDescriptor,
    StreamValues,
};
use super::json_fields::JsonFields;
use super::params::{ParamError, ParamSpec, ParamValue, Params, Retired, TypedParams};
use super::reading::SensorKind;
use super::{Declaration, Stage};
use super::{Engine, SnapshotError, attitude, dta, fuzzy, pushes, ring_plan, rings, steer, zupt};

/// Why a stored estimate could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CodecError {
    #[error(
        "a {stream} estimate stored with codec version {found}; this release reads up to {supported}"
    )]
    Newer {
        stream: StreamKind,
        found: u32,
        supported: u32,
    },
    #[error("a {stream} estimate (codec version {version}) does not decode: {reason}")]
    Corrupt {
        stream: StreamKind,
        version: u32,
        reason: String,
    },
}

/// An engine name that tunnelnav does not know.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("unknown engine `{name}` (known: {known})")]
pub struct UnknownEngine {
    pub name: String,
    pub known: String,
}

/// Turns the list of engines and stages into the kinds and their dispatch.
/// An engine may carry `#[cfg(...)]` after its doc comment: every variant,
/// arm and list entry it makes carries it too (the toy engine of the unit
/// tests is listed so).
macro_rules! registry {
    (
        engines { $(
            $(#[doc = $doc:literal])*
            $(#[cfg($cfg:meta)])?
            $Variant:ident = $name:literal => $Descriptor:ty
        ),+ $(,)? }
        stages { $(
            $(#[doc = $sdoc:literal])*
            $Stage:ident = $sname:literal => $SDescriptor:ty
        ),+ $(,)? }
    ) => {
        /// The engines tunnelnav knows.
        #[derive(
            Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord,
            Serialize, Deserialize, clap::ValueEnum,
        )]
        pub enum EngineKind {
            $( $(#[doc = $doc])* $(#[cfg($cfg)])?
               #[serde(rename = $name)] #[value(name = $name)] $Variant ),+
        }

        impl EngineKind {
            /// Every engine, in registry order.
            pub const ALL: &'static [EngineKind] = &[$( $(#[cfg($cfg)])? EngineKind::$Variant ),+];

            /// The protocol name.
            pub fn as_str(self) -> &'static str {
                match self { $( $(#[cfg($cfg)])? EngineKind::$Variant => $name ),+ }
            }

            /// One line on the method.
            pub fn summary(self) -> &'static str {
                match self { $( $(#[cfg($cfg)])? EngineKind::$Variant => <$Descriptor>::SUMMARY ),+ }
            }

            /// The parameters the engine accepts.
            pub fn specs(self) -> &'static [ParamSpec] {
                match self {
                    $( $(#[cfg($cfg)])? EngineKind::$Variant =>
                        <<$Descriptor as EngineDescriptor>::Params as TypedParams>::SPECS ),+
                }
            }

            /// Parameters earlier releases had (see [`EngineDescriptor::RETIRED`]).
            pub fn retired(self) -> &'static [Retired] {
                match self { $( $(#[cfg($cfg)])? EngineKind::$Variant => <$Descriptor>::RETIRED ),+ }
            }

            /// The sensors the engine consumes.
            pub fn sensors(self) -> &'static [SensorKind] {
                match self { $( $(#[cfg($cfg)])? EngineKind::$Variant => <$Descriptor>::SENSORS ),+ }
            }

            /// A fresh engine with these parameters.
            pub fn create(self, params: Params) -> Result<Box<dyn Engine>, ParamError> {
                match self {
                    $( $(#[cfg($cfg)])? EngineKind::$Variant =>
                        Ok(Box::new(<$Descriptor>::create(params)?)) ),+
                }
            }

            /// An engine continuing from an [`Engine::snapshot`].
            pub fn restore(
                self,
                snapshot: serde_json::Value,
            ) -> Result<Box<dyn Engine>, SnapshotError> {
                match self {
                    $( $(#[cfg($cfg)])? EngineKind::$Variant =>
                        Ok(Box::new(<$Descriptor>::restore(snapshot)?)) ),+
                }
            }

            /// `params` read through the engine's typed parameters and
            /// written back: equal to `params` when the engine reads every
            /// value it is given.
            pub fn read_params(self, params: &Params) -> Result<Params, ParamError> {
                match self {
                    $( $(#[cfg($cfg)])? EngineKind::$Variant =>
                        <<$Descriptor as EngineDescriptor>::Params as TypedParams>::from_params(params)
                            .map(|typed| typed.to_params()) ),+
                }
            }

            /// The OpenAPI schema of the engine's model report, if it has one.
            pub fn model_schema(self) -> Option<SchemaComponent> {
                match self {
                    $( $(#[cfg($cfg)])? EngineKind::$Variant =>
                        <<$Descriptor as EngineDescriptor>::Model as ModelReport>::schema() ),+
                }
            }

            /// Every protocol name, comma separated (for messages).
            pub fn names() -> String {
                [$( $(#[cfg($cfg)])? $name ),+].join(", ")
            }
        }

        /// The stages tunnelnav knows: each runs after the engines of the
        /// machines whose declaration calls for it.
        #[derive(
            Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord,
            Serialize, Deserialize,
        )]
        pub enum StageKind {
            $( $(#[doc = $sdoc])* #[serde(rename = $sname)] $Stage ),+
        }

        impl StageKind {
            /// Every stage, in registry order.
            pub const ALL: &'static [StageKind] = &[$(StageKind::$Stage),+];

            /// The protocol name (its stream's `engine`).
            pub fn as_str(self) -> &'static str {
                match self { $( StageKind::$Stage => $sname ),+ }
            }

            /// One line on what the stage derives.
            pub fn summary(self) -> &'static str {
                match self { $( StageKind::$Stage => <$SDescriptor>::SUMMARY ),+ }
            }

            /// Whether a snapshot from before the stage may continue with it
            /// seeded (see [`StageDescriptor::SEEDED`]).
            pub fn seeded(self) -> bool {
                match self { $( StageKind::$Stage => <$SDescriptor>::SEEDED ),+ }
            }

            /// The stage for a machine so declared, if the declaration
            /// calls for it.
            pub fn create(self, declaration: &Declaration) -> Option<Box<dyn Stage>> {
                match self {
                    $( StageKind::$Stage => <$SDescriptor>::create(declaration)
                        .map(|stage| Box::new(stage) as Box<dyn Stage>) ),+
                }
            }

            /// A stage of a machine so declared continuing from its
            /// [`Stage::snapshot`].
            pub fn restore(
                self,
                declaration: &Declaration,
                snapshot: serde_json::Value,
            ) -> Result<Box<dyn Stage>, SnapshotError> {
                match self {
                    $( StageKind::$Stage =>
                        Ok(Box::new(<$SDescriptor>::restore(declaration, snapshot)?)) ),+
                }
            }
        }

        /// What produced a stream of estimates: an engine or a stage. Its
        /// name is the estimates' `engine` field and the API's `engine=`.
        #[derive(
            Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord,
            Serialize, Deserialize,
        )]
        pub enum StreamKind {
            $( $(#[cfg($cfg)])? #[serde(rename = $name)] $Variant, )+
            $( #[serde(rename = $sname)] $Stage, )+
        }

        impl StreamKind {
            /// Every stream, engines first, in registry order.
            pub const ALL: &'static [StreamKind] =
                &[$( $(#[cfg($cfg)])? StreamKind::$Variant, )+ $(StreamKind::$Stage,)+];

            /// The protocol name.
            pub fn as_str(self) -> &'static str {
                match self {
                    $( $(#[cfg($cfg)])? StreamKind::$Variant => $name, )+
                    $( StreamKind::$Stage => $sname, )+
                }
            }

            /// The codec version of the estimates this release stores.
            pub fn codec_version(self) -> u32 {
                match self {
                    $( $(#[cfg($cfg)])? StreamKind::$Variant =>
                        <<$Descriptor as EngineDescriptor>::Estimate as StreamValues>::CODEC_VERSION, )+
                    $( StreamKind::$Stage =>
                        <<$SDescriptor as StageDescriptor>::Output as StreamValues>::CODEC_VERSION, )+
                }
            }

            /// The signals its estimates tell the alarm rules and the status.
            pub fn signals(self) -> &'static [SignalKind] {
                match self {
                    $( $(#[cfg($cfg)])? StreamKind::$Variant =>
                        <<$Descriptor as EngineDescriptor>::Estimate as StreamValues>::SIGNALS, )+
                    $( StreamKind::$Stage =>
                        <<$SDescriptor as StageDescriptor>::Output as StreamValues>::SIGNALS, )+
                }
            }

            /// The OpenAPI schema of the stream's values.
            pub fn schema(self) -> SchemaComponent {
                match self {
                    $( $(#[cfg($cfg)])? StreamKind::$Variant =>
                        SchemaComponent::of::<<$Descriptor as EngineDescriptor>::Estimate>(), )+
                    $( StreamKind::$Stage =>
                        SchemaComponent::of::<<$SDescriptor as StageDescriptor>::Output>(), )+
                }
            }

            /// The engine, if an engine produces this stream.
            pub fn engine(self) -> Option<EngineKind> {
                match self {
                    $( $(#[cfg($cfg)])? StreamKind::$Variant => Some(EngineKind::$Variant), )+
                    _ => None,
                }
            }

            /// Every protocol name, comma separated (for messages).
            pub fn names() -> String {
                [$( $(#[cfg($cfg)])? $name, )+ $($sname,)+].join(", ")
            }
        }

        impl From<EngineKind> for StreamKind {
            fn from(engine: EngineKind) -> StreamKind {
                match engine { $( $(#[cfg($cfg)])? EngineKind::$Variant => StreamKind::$Variant ),+ }
            }
        }

        impl From<StageKind> for StreamKind {
            fn from(stage: StageKind) -> StreamKind {
                match stage { $( StageKind::$Stage => StreamKind::$Stage ),+ }
            }
        }

        /// The stream-specific part of an estimate, tagged by `engine`.
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
        #[serde(tag = "engine")]
        pub enum EstimateValues {
            $( $(#[cfg($cfg)])? #[serde(rename = $name)]
               $Variant(<$Descriptor as EngineDescriptor>::Estimate), )+
            $( #[serde(rename = $sname)] $Stage(<$SDescriptor as StageDescriptor>::Output), )+
        }

        impl EstimateValues {
            /// The stream these values belong to.
            pub fn stream(&self) -> StreamKind {
                match self {
                    $( $(#[cfg($cfg)])? EstimateValues::$Variant(_) => StreamKind::$Variant, )+
                    $( EstimateValues::$Stage(_) => StreamKind::$Stage, )+
                }
            }

            /// The two quantities whose extremes history downsampling keeps,
            /// so a spike stays visible at any zoom.
            pub fn extremes(&self) -> [f64; 2] {
                match self {
                    $( $(#[cfg($cfg)])? EstimateValues::$Variant(e) => e.extremes(), )+
                    $( EstimateValues::$Stage(e) => e.extremes(), )+
                }
            }

            /// What the alarm rules and the status watch in these values.
            pub fn signals(&self) -> Signals {
                match self {
                    $( $(#[cfg($cfg)])? EstimateValues::$Variant(e) => e.signals(), )+
                    $( EstimateValues::$Stage(e) => e.signals(), )+
                }
            }

            /// The fields after `"engine"`, as serde_json writes them.
            pub fn write_fields(&self, fields: &mut JsonFields<'_>) {
                match self {
                    $( $(#[cfg($cfg)])? EstimateValues::$Variant(e) => e.write_fields(fields), )+
                    $( EstimateValues::$Stage(e) => e.write_fields(fields), )+
                }
            }

            /// The stored form, of the stream's [`StreamKind::codec_version`].
            pub fn encode(&self) -> Vec<u8> {
                match self {
                    $( $(#[cfg($cfg)])? EstimateValues::$Variant(e) => e.encode(), )+
                    $( EstimateValues::$Stage(e) => e.encode(), )+
                }
            }

            /// Values of `stream` stored as `bytes` with codec `version`.
            pub fn decode(
                stream: StreamKind,
                version: u32,
                bytes: &[u8],
            ) -> Result<EstimateValues, CodecError> {
                let supported = stream.codec_version();
                if version > supported {
                    return Err(CodecError::Newer { stream, found: version, supported });
                }
                let corrupt = |e: postcard::Error| CodecError::Corrupt {
                    stream,
                    version,
                    reason: e.to_string(),
                };
                match stream {
                    $( $(#[cfg($cfg)])? StreamKind::$Variant =>
                        <<$Descriptor as EngineDescriptor>::Estimate as StreamValues>::decode(version, bytes)
                            .map(EstimateValues::$Variant)
                            .map_err(corrupt), )+
                    $( StreamKind::$Stage =>
                        <<$SDescriptor as StageDescriptor>::Output as StreamValues>::decode(version, bytes)
                            .map(EstimateValues::$Stage)
                            .map_err(corrupt), )+
                }
            }
        }

        /// An engine's model report, as the model endpoint answers it.
        #[derive(Debug, Clone, PartialEq, Serialize)]
        #[serde(untagged)]
        pub enum EngineModel {
            $( $(#[cfg($cfg)])? $Variant(<$Descriptor as EngineDescriptor>::Model) ),+
        }
    };
}

registry! {
    engines {
        /// Laser + inclinometer dual-rate ANFIS fusion (He et al. 2021).
        Attitude = "attitude" => attitude::Attitude,
        /// FOG strapdown INS with zero-velocity updates (Zhang et al. 2024).
        Zupt = "zupt" => zupt::Zupt,
        /// MEMS IMU + magnetometer fused by a fuzzy expert's motion status (Wang 2005).
        Fuzzy = "fuzzy" => fuzzy::Fuzzy,
        /// A toy engine for the unit tests: what adding an engine touches.
        #[cfg(test)]
        Toy = "toy" => crate::toy_engine::Toy,
    }
    stages {
        /// The jacking log: one record per completed push of a `zupt` machine.
        Pushes = "pushes" => pushes::Pushes,
        /// Deviation from the designed tunnel axis (machines with an alignment).
        Dta = "dta" => dta::Dta,
        /// The correction curve back to the axis (machines that declare their steering).
        Steer = "steer" => steer::Steer,
        /// The ring (or pipe) log: one record per `advance` reading.
        Rings = "rings" => rings::Rings,
        /// The built lining and the next rings' key positions (machines that declare their rings).
        RingPlan = "ring_plan" => ring_plan::RingPlan,
    }
}

impl EngineKind {
    /// Defaults with `overrides` on top; a retired name is refused with the
    /// reason it was retired.
    pub fn params(
        self,
        overrides: impl IntoIterator<Item = (String, ParamValue)>,
    ) -> Result<Params, ParamError> {
        let overrides: Vec<(String, ParamValue)> = overrides.into_iter().collect();
        for (name, _) in &overrides {
            super::params::check_retired(self.retired(), name)?;
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
                super::params::check_retired(self.retired(), name.trim())?;
            }
        }
        Params::from_assignments(self.specs(), assignments)
    }
}

impl std::str::FromStr for EngineKind {
    type Err = UnknownEngine;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        EngineKind::ALL
            .iter()
            .copied()
            .find(|k| k.as_str() == name)
            .ok_or_else(|| UnknownEngine {
                name: name.to_string(),
                known: EngineKind::names(),
            })
    }
}

impl std::str::FromStr for StreamKind {
    type Err = UnknownEngine;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        StreamKind::ALL
            .iter()
            .copied()
            .find(|k| k.as_str() == name)
            .ok_or_else(|| UnknownEngine {
                name: name.to_string(),
                known: StreamKind::names(),
            })
    }
}

impl std::fmt::Display for StreamKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::fmt::Display for StageKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::fmt::Display for EngineKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::ValueEnum;

    #[test]
    fn every_engine_has_one_name_everywhere() {
        for &kind in EngineKind::ALL {
            let name = kind.as_str();
            assert_eq!(name.parse::<EngineKind>().unwrap(), kind);
            assert_eq!(kind.to_string(), name);
            assert_eq!(serde_json::to_value(kind).unwrap(), name);
            let possible = kind.to_possible_value().unwrap();
            assert_eq!(possible.get_name(), name);
            assert!(!kind.sensors().is_empty() && !kind.specs().is_empty());
            assert!(StreamKind::from(kind).codec_version() >= 1);
        }
        assert_eq!(EngineKind::value_variants(), EngineKind::ALL);
        let err = "kalman".parse::<EngineKind>().unwrap_err();
        assert_eq!(
            err.to_string(),
            "unknown engine `kalman` (known: attitude, zupt, fuzzy, toy)"
        );
    }
}
