//! The engines tunnelnav knows, listed once.
//!
//! Each engine module describes itself by implementing [`EngineDescriptor`]
//! in one place: its sensors, parameter table, how it is created and
//! restored, its estimate type (with that type's NDJSON writer and stored
//! codec) and its model report. Each stage after the engines does the same
//! with [`StageDescriptor`]. The [`registry!`] list at the bottom of this
//! file turns the descriptors into [`EngineKind`] (a `clap::ValueEnum`),
//! [`StageKind`], [`StreamKind`] (engines and stages: what the estimates'
//! `engine` field names), [`EstimateValues`] and [`EngineModel`], whose
//! dispatch the compiler keeps complete. Adding an engine: its module, one
//! line in that list, and its page section and script
//! (`src/server/pages.rs` says where).

use serde::{Deserialize, Serialize};

use super::estimate::JsonFields;
use super::params::{ParamError, ParamSpec, ParamValue, Params, Retired, TypedParams};
use super::reading::SensorKind;
use super::stage::{Declaration, Stage};
use super::{Engine, SnapshotError, attitude, dta, fuzzy, pushes, zupt};

/// What an engine module declares about itself.
pub trait EngineDescriptor {
    /// One line on the method, for help texts.
    const SUMMARY: &'static str;
    /// The sensors the engine consumes; it ignores the others.
    const SENSORS: &'static [SensorKind];
    /// Parameters earlier releases had: stored machines that name them
    /// still load, new declarations that do are refused with the reason.
    const RETIRED: &'static [Retired];
    /// The version of [`EngineDescriptor::Estimate`]'s stored form this
    /// release writes; [`EngineDescriptor::decode`] reads it and every
    /// earlier one.
    const CODEC_VERSION: u32;

    /// The parameters, typed; its table is the engine's parameter specs.
    type Params: TypedParams;
    /// The engine itself.
    type Engine: Engine + 'static;
    /// What the engine emits per estimate.
    type Estimate: Serialize + serde::de::DeserializeOwned + Clone + PartialEq + std::fmt::Debug;
    /// What the model endpoint reports (an uninhabited type if nothing).
    type Model: Serialize + Clone + PartialEq + std::fmt::Debug;

    /// A fresh engine with validated parameters.
    fn create(params: Params) -> Result<Self::Engine, ParamError>;
    /// An engine continuing from its [`Engine::snapshot`].
    fn restore(snapshot: serde_json::Value) -> Result<Self::Engine, SnapshotError>;
    /// The estimate's fields after `"engine"`, byte for byte as serde_json
    /// writes them.
    fn write_fields(estimate: &Self::Estimate, fields: &mut JsonFields<'_>);
    /// The stored form of [`EngineDescriptor::CODEC_VERSION`].
    fn encode(estimate: &Self::Estimate) -> Vec<u8>;
    /// An estimate stored with codec `version` (0: stored before rows
    /// carried a version).
    fn decode(version: u32, bytes: &[u8]) -> Result<Self::Estimate, postcard::Error>;
    /// The two quantities whose extremes history downsampling keeps.
    fn extremes(estimate: &Self::Estimate) -> [f64; 2];
}

/// What a stage module declares about itself (see [`Stage`]).
pub trait StageDescriptor {
    /// One line on what the stage derives.
    const SUMMARY: &'static str;
    /// The version of [`StageDescriptor::Output`]'s stored form.
    const CODEC_VERSION: u32;
    /// The stage itself.
    type Stage: Stage + 'static;
    /// What the stage emits per estimate.
    type Output: Serialize + serde::de::DeserializeOwned + Clone + PartialEq + std::fmt::Debug;

    /// The stage for a machine so declared; `None` when the declaration
    /// does not call for it.
    fn create(declaration: &Declaration) -> Option<Self::Stage>;
    /// A stage of a machine so declared continuing from its [`Stage::snapshot`].
    fn restore(
        declaration: &Declaration,
        snapshot: serde_json::Value,
    ) -> Result<Self::Stage, SnapshotError>;
    /// The output's fields after `"engine"`, as serde_json writes them.
    fn write_fields(output: &Self::Output, fields: &mut JsonFields<'_>);
    /// The stored form of [`StageDescriptor::CODEC_VERSION`]: postcard.
    fn encode(output: &Self::Output) -> Vec<u8> {
        super::estimate::postcard_bytes(output)
    }
    /// An output stored with codec `version`. The default reads a stage
    /// whose stored form has never changed; one that changes keeps its
    /// earlier forms readable here.
    fn decode(version: u32, bytes: &[u8]) -> Result<Self::Output, postcard::Error> {
        if version <= Self::CODEC_VERSION {
            postcard::from_bytes(bytes)
        } else {
            Err(postcard::Error::DeserializeBadEncoding)
        }
    }
    /// The two quantities whose extremes history downsampling keeps.
    fn extremes(output: &Self::Output) -> [f64; 2];
}

/// A model report for engines that have none.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum NoModel {}

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

macro_rules! registry {
    (
        engines { $( $(#[$doc:meta])* $Variant:ident = $name:literal => $Descriptor:ty ),+ $(,)? }
        stages { $( $(#[$sdoc:meta])* $Stage:ident = $sname:literal => $SDescriptor:ty ),+ $(,)? }
    ) => {
        /// The engines tunnelnav knows.
        #[derive(
            Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord,
            Serialize, Deserialize, clap::ValueEnum,
        )]
        pub enum EngineKind {
            $( $(#[$doc])* #[serde(rename = $name)] #[value(name = $name)] $Variant ),+
        }

        impl EngineKind {
            /// Every engine, in registry order.
            pub const ALL: &'static [EngineKind] = &[$(EngineKind::$Variant),+];

            /// The protocol name.
            pub fn as_str(self) -> &'static str {
                match self { $( EngineKind::$Variant => $name ),+ }
            }

            /// One line on the method.
            pub fn summary(self) -> &'static str {
                match self { $( EngineKind::$Variant => <$Descriptor>::SUMMARY ),+ }
            }

            /// The parameters the engine accepts.
            pub fn specs(self) -> &'static [ParamSpec] {
                match self {
                    $( EngineKind::$Variant =>
                        <<$Descriptor as EngineDescriptor>::Params as TypedParams>::SPECS ),+
                }
            }

            /// Parameters earlier releases had (see [`EngineDescriptor::RETIRED`]).
            pub fn retired(self) -> &'static [Retired] {
                match self { $( EngineKind::$Variant => <$Descriptor>::RETIRED ),+ }
            }

            /// The sensors the engine consumes.
            pub fn sensors(self) -> &'static [SensorKind] {
                match self { $( EngineKind::$Variant => <$Descriptor>::SENSORS ),+ }
            }

            /// The codec version of the estimates this release stores.
            pub fn codec_version(self) -> u32 {
                match self { $( EngineKind::$Variant => <$Descriptor>::CODEC_VERSION ),+ }
            }

            /// A fresh engine with these parameters.
            pub fn create(self, params: Params) -> Result<Box<dyn Engine>, ParamError> {
                match self {
                    $( EngineKind::$Variant => Ok(Box::new(<$Descriptor>::create(params)?)) ),+
                }
            }

            /// An engine continuing from an [`Engine::snapshot`].
            pub fn restore(
                self,
                snapshot: serde_json::Value,
            ) -> Result<Box<dyn Engine>, SnapshotError> {
                match self {
                    $( EngineKind::$Variant => Ok(Box::new(<$Descriptor>::restore(snapshot)?)) ),+
                }
            }

            /// `params` read through the engine's typed parameters and
            /// written back: equal to `params` when the engine reads every
            /// value it is given.
            pub fn read_params(self, params: &Params) -> Result<Params, ParamError> {
                match self {
                    $( EngineKind::$Variant =>
                        <<$Descriptor as EngineDescriptor>::Params as TypedParams>::from_params(params)
                            .map(|typed| typed.to_params()) ),+
                }
            }

            /// Every protocol name, comma separated (for messages).
            pub fn names() -> String {
                [$($name),+].join(", ")
            }
        }

        /// The stages tunnelnav knows: each runs after the engines of the
        /// machines whose declaration calls for it.
        #[derive(
            Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord,
            Serialize, Deserialize,
        )]
        pub enum StageKind {
            $( $(#[$sdoc])* #[serde(rename = $sname)] $Stage ),+
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
            $( #[serde(rename = $name)] $Variant, )+
            $( #[serde(rename = $sname)] $Stage, )+
        }

        impl StreamKind {
            /// Every stream, engines first, in registry order.
            pub const ALL: &'static [StreamKind] =
                &[$(StreamKind::$Variant,)+ $(StreamKind::$Stage,)+];

            /// The protocol name.
            pub fn as_str(self) -> &'static str {
                match self {
                    $( StreamKind::$Variant => $name, )+
                    $( StreamKind::$Stage => $sname, )+
                }
            }

            /// The codec version of the estimates this release stores.
            pub fn codec_version(self) -> u32 {
                match self {
                    $( StreamKind::$Variant => <$Descriptor>::CODEC_VERSION, )+
                    $( StreamKind::$Stage => <$SDescriptor>::CODEC_VERSION, )+
                }
            }

            /// The engine, if an engine produces this stream.
            pub fn engine(self) -> Option<EngineKind> {
                match self {
                    $( StreamKind::$Variant => Some(EngineKind::$Variant), )+
                    _ => None,
                }
            }

            /// Every protocol name, comma separated (for messages).
            pub fn names() -> String {
                [$($name,)+ $($sname,)+].join(", ")
            }
        }

        impl From<EngineKind> for StreamKind {
            fn from(engine: EngineKind) -> StreamKind {
                match engine { $( EngineKind::$Variant => StreamKind::$Variant ),+ }
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
            $( #[serde(rename = $name)] $Variant(<$Descriptor as EngineDescriptor>::Estimate), )+
            $( #[serde(rename = $sname)] $Stage(<$SDescriptor as StageDescriptor>::Output), )+
        }

        impl EstimateValues {
            /// The stream these values belong to.
            pub fn stream(&self) -> StreamKind {
                match self {
                    $( EstimateValues::$Variant(_) => StreamKind::$Variant, )+
                    $( EstimateValues::$Stage(_) => StreamKind::$Stage, )+
                }
            }

            /// The two quantities whose extremes history downsampling keeps,
            /// so a spike stays visible at any zoom.
            pub fn extremes(&self) -> [f64; 2] {
                match self {
                    $( EstimateValues::$Variant(e) => <$Descriptor>::extremes(e), )+
                    $( EstimateValues::$Stage(e) => <$SDescriptor>::extremes(e), )+
                }
            }

            /// The fields after `"engine"`, as serde_json writes them.
            pub fn write_fields(&self, fields: &mut JsonFields<'_>) {
                match self {
                    $( EstimateValues::$Variant(e) => <$Descriptor>::write_fields(e, fields), )+
                    $( EstimateValues::$Stage(e) => <$SDescriptor>::write_fields(e, fields), )+
                }
            }

            /// The stored form, of the stream's [`StreamKind::codec_version`].
            pub fn encode(&self) -> Vec<u8> {
                match self {
                    $( EstimateValues::$Variant(e) => <$Descriptor>::encode(e), )+
                    $( EstimateValues::$Stage(e) => <$SDescriptor>::encode(e), )+
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
                    $( StreamKind::$Variant => <$Descriptor>::decode(version, bytes)
                        .map(EstimateValues::$Variant)
                        .map_err(corrupt), )+
                    $( StreamKind::$Stage => <$SDescriptor>::decode(version, bytes)
                        .map(EstimateValues::$Stage)
                        .map_err(corrupt), )+
                }
            }
        }

        /// An engine's model report, as the model endpoint answers it.
        #[derive(Debug, Clone, PartialEq, Serialize)]
        #[serde(untagged)]
        pub enum EngineModel {
            $( $Variant(<$Descriptor as EngineDescriptor>::Model) ),+
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
    }
    stages {
        /// The jacking log: one record per completed push of a `zupt` machine.
        Pushes = "pushes" => pushes::Pushes,
        /// Deviation from the designed tunnel axis (machines with an alignment).
        Dta = "dta" => dta::Dta,
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
            assert!(kind.codec_version() >= 1);
        }
        assert_eq!(EngineKind::value_variants(), EngineKind::ALL);
        let err = "kalman".parse::<EngineKind>().unwrap_err();
        assert_eq!(
            err.to_string(),
            "unknown engine `kalman` (known: attitude, zupt, fuzzy)"
        );
    }
}
