//! Machine definitions: the body of `PUT /api/v1/machines/{machine}` and
//! the config file's `[machines]`, validated. The rest of the config file
//! is the server's (`server::settings`).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use std::sync::Arc;

use crate::fusion::alarms::AlarmConfig;
use crate::fusion::alignment::{Alignment, AlignmentError, AlignmentSpec};
use crate::fusion::declaration::{MachineGeometry, Tolerances};
use crate::fusion::pipeline::Pipeline;
use crate::fusion::reading::ProjectPoint;
use crate::fusion::ring_build::RingSpec;
use crate::fusion::steering::SteeringSpec;
use crate::fusion::{
    Declaration, EngineKind, ParamError, ParamValue, Params, StreamKind, UnknownEngine,
};

/// Longest machine display name, in characters.
pub const MAX_NAME_CHARS: usize = 200;
/// Longest reorder window a machine may ask for: readings are held in memory
/// for this long, and estimates come out this much later.
pub const MAX_REORDER_WINDOW_S: f64 = 600.0;

/// A machine as declared by an operator, before validation: what `PUT`
/// bodies and the config file contain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MachineDeclaration {
    /// Display name; the id when absent.
    #[serde(default)]
    pub name: Option<String>,
    /// Engine name → parameter overrides (docs/engines/ lists each
    /// engine's parameters).
    #[schema(schema_with = engines_schema)]
    pub engines: BTreeMap<String, BTreeMap<String, ParamValue>>,
    /// How long readings are held to restore time order, seconds of reading
    /// time (tunnelnav extension, default 0: fused on arrival; docs/api.md).
    #[serde(default)]
    pub reorder_window_s: Option<f64>,
    /// Where the machine's front and rear are (protocol, "Design axis and
    /// deviation"); with an alignment, the `dta` stream.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry: Option<MachineGeometry>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerances: Option<Tolerances>,
    /// Project coordinates of the reference point at the first reading.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<ProjectPoint>,
    /// The design axis of the machine's drive.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alignment: Option<AlignmentSpec>,
    /// The alarm rules' settings (defaults when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alarms: Option<AlarmConfig>,
    /// How the machine may be steered back to the axis (the correction
    /// curve: `GET .../steering`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steering: Option<SteeringSpec>,
    /// Its universal tapered rings (the ring build plan:
    /// `GET .../rings/plan`, docs/rings.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rings: Option<RingSpec>,
}

/// A validated machine: id, name, engines with complete parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MachineSpec {
    pub id: String,
    pub name: String,
    pub engines: BTreeMap<EngineKind, Params>,
    pub reorder_window_s: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub geometry: Option<MachineGeometry>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerances: Option<Tolerances>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<ProjectPoint>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alignment: Option<AlignmentSpec>,
    /// The alarm rules' settings.
    #[serde(default)]
    pub alarms: AlarmConfig,
    /// How it may be steered (absent in a machine stored before issue 39).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steering: Option<SteeringSpec>,
    /// Its rings (absent in a machine stored before issue 60).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rings: Option<RingSpec>,
    /// `alignment` built (when validated or loaded).
    #[serde(skip)]
    pub built_alignment: Option<Arc<Alignment>>,
}

/// Why a machine declaration or the config file was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("machine id `{0}` is not valid: use 1 to 64 letters, digits, `-` or `_`")]
    MachineId(String),
    #[error("machine `{machine}`: {source}")]
    Engine {
        machine: String,
        source: UnknownEngine,
    },
    #[error("machine `{machine}`, engine `{engine}`: {source}")]
    Params {
        machine: String,
        engine: EngineKind,
        source: ParamError,
    },
    #[error("machine `{machine}` declares no engine (known: {known})")]
    NoEngine { machine: String, known: String },
    #[error("machine `{machine}`: {reason}")]
    Invalid { machine: String, reason: String },
    #[error("config file {path}: {reason}")]
    File { path: String, reason: String },
}

/// The site of a machine an office holds for it (`{site}.{machine}`:
/// only there may an id hold a dot), or `None` for a machine of this
/// server's own.
pub fn forwarded_site(id: &str) -> Option<&str> {
    id.split_once('.').map(|(site, _)| site)
}

/// True for ids matching `[A-Za-z0-9_-]{1,64}` (protocol, "HTTP API").
pub fn valid_machine_id(id: &str) -> bool {
    (1..=64).contains(&id.len())
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
}

/// The schema of a declaration's `engines`, from the engines' parameter
/// tables (what [`MachineDeclaration::validate`] checks them against):
/// at least one engine, each with only its own parameters, in range.
fn engines_schema() -> utoipa::openapi::schema::Schema {
    use crate::fusion::ParamKind;
    use utoipa::openapi::schema::{ObjectBuilder, Type};
    let mut engines = ObjectBuilder::new()
        .schema_type(Type::Object)
        .description(Some(
            "Engine name → its parameter overrides (docs/engines/); the others keep their defaults",
        ))
        .min_properties(Some(1))
        .additional_properties(Some(
            utoipa::openapi::schema::AdditionalProperties::FreeForm(false),
        ));
    for &engine in crate::fusion::EngineKind::ALL {
        let mut params = ObjectBuilder::new()
            .schema_type(Type::Object)
            .additional_properties(Some(
                utoipa::openapi::schema::AdditionalProperties::FreeForm(false),
            ));
        for spec in engine.specs() {
            let unit = if spec.unit.is_empty() {
                String::new()
            } else {
                format!(" ({})", spec.unit)
            };
            let value = match spec.kind {
                ParamKind::Real { default, min, max } => ObjectBuilder::new()
                    .schema_type(Type::Number)
                    .minimum(Some(min))
                    .maximum(Some(max))
                    .default(Some(default.into())),
                ParamKind::Integer { default, min, max } => ObjectBuilder::new()
                    .schema_type(Type::Integer)
                    .minimum(Some(min as f64))
                    .maximum(Some(max as f64))
                    .default(Some(default.into())),
                ParamKind::Bool { default } => ObjectBuilder::new()
                    .schema_type(Type::Boolean)
                    .default(Some(default.into())),
                ParamKind::Choice { default, options } => ObjectBuilder::new()
                    .schema_type(Type::String)
                    .enum_values(Some(options.iter().copied()))
                    .default(Some(default.into())),
            };
            params = params.property(
                spec.name,
                value.description(Some(format!("{}{unit}", spec.doc))),
            );
        }
        engines = engines.property(engine.as_str(), params);
    }
    engines.into()
}

impl MachineDeclaration {
    /// Checks everything an engine would refuse later, naming the culprit.
    pub fn validate(self, id: &str) -> Result<MachineSpec, ConfigError> {
        if !valid_machine_id(id) {
            return Err(ConfigError::MachineId(id.to_string()));
        }
        let invalid = |reason: String| ConfigError::Invalid {
            machine: id.to_string(),
            reason,
        };
        let name = self.name.unwrap_or_else(|| id.to_string());
        if name.chars().count() > MAX_NAME_CHARS || name.chars().any(char::is_control) {
            return Err(invalid(format!(
                "`name` must be at most {MAX_NAME_CHARS} printable characters"
            )));
        }
        let reorder_window_s = self.reorder_window_s.unwrap_or(0.0);
        if !(0.0..=MAX_REORDER_WINDOW_S).contains(&reorder_window_s) {
            return Err(invalid(format!(
                "`reorder_window_s` = {reorder_window_s} is outside [0, {MAX_REORDER_WINDOW_S}]"
            )));
        }
        if self.engines.is_empty() {
            return Err(ConfigError::NoEngine {
                machine: id.to_string(),
                known: EngineKind::names(),
            });
        }
        let mut engines = BTreeMap::new();
        for (engine_name, overrides) in self.engines {
            let engine: EngineKind = engine_name.parse().map_err(|source| ConfigError::Engine {
                machine: id.to_string(),
                source,
            })?;
            let params_error = |source| ConfigError::Params {
                machine: id.to_string(),
                engine,
                source,
            };
            let params = engine.params(overrides).map_err(params_error)?;
            // Creating the engine runs its cross-parameter checks.
            engine.create(params.clone()).map_err(params_error)?;
            engines.insert(engine, params);
        }
        let finite = |xs: &[f64]| xs.iter().all(|x| x.is_finite());
        if let Some(g) = &self.geometry
            && !finite(&[g.front_m, g.rear_m].concat())
        {
            return Err(invalid(
                "`geometry`: front_m and rear_m must be finite numbers".into(),
            ));
        }
        if let Some(t) = &self.tolerances {
            for (what, limits) in [
                ("horizontal_mm", t.horizontal_mm),
                ("vertical_mm", t.vertical_mm),
            ] {
                if !(finite(&[limits.warn, limits.alarm])
                    && 0.0 < limits.warn
                    && limits.warn <= limits.alarm)
                {
                    return Err(invalid(format!(
                        "`tolerances.{what}`: warn must be above 0 and at most alarm"
                    )));
                }
            }
        }
        if let Some(p) = &self.start
            && !finite(&[p.easting_m, p.northing_m, p.height_m])
        {
            return Err(invalid(
                "`start`: easting, northing and height must be finite".into(),
            ));
        }
        // Only a new declaration is held to scale (an axis stored by an
        // earlier release still opens: see `upgraded`).
        if let Some(alignment) = &self.alignment {
            alignment
                .check_scale()
                .map_err(|e| invalid(format!("`alignment`: {e}")))?;
        }
        let built_alignment =
            built(self.alignment.as_ref()).map_err(|e| invalid(format!("`alignment`: {e}")))?;
        let alarms = self.alarms.unwrap_or_default();
        alarms.validate().map_err(invalid)?;
        if let Some(steering) = &self.steering {
            steering.check().map_err(invalid)?;
            // The curve starts from the dta stage's front; the axis may
            // come later (PUT .../alignment), the machine's geometry not.
            if self.geometry.is_none() {
                return Err(invalid(
                    "`steering` needs a `geometry` (the front and rear the curve starts from)"
                        .into(),
                ));
            }
        }
        if let Some(rings) = &self.rings {
            rings.check().map_err(invalid)?;
            if self.geometry.is_none() {
                return Err(invalid(
                    "`rings` needs a `geometry` (its rear point is the tail skin's end)".into(),
                ));
            }
        }
        Ok(MachineSpec {
            id: id.to_string(),
            name,
            engines,
            reorder_window_s,
            geometry: self.geometry,
            tolerances: self.tolerances,
            start: self.start,
            alignment: self.alignment,
            alarms,
            steering: self.steering,
            rings: self.rings,
            built_alignment,
        })
    }
}

/// A declared alignment, built.
fn built(alignment: Option<&AlignmentSpec>) -> Result<Option<Arc<Alignment>>, AlignmentError> {
    alignment.map(|a| a.build().map(Arc::new)).transpose()
}

impl MachineSpec {
    /// Fresh engines with the declared parameters and the stages the
    /// declaration calls for: what a machine runs, served or replayed.
    pub fn pipeline(&self) -> Result<Pipeline, ParamError> {
        let engines = self
            .engines
            .iter()
            .map(|(kind, params)| kind.create(params.clone()))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Pipeline::declared(engines, &self.stage_declaration()))
    }

    /// What the stages read of this declaration.
    pub fn stage_declaration(&self) -> Declaration {
        Declaration {
            alignment: self.built_alignment.clone(),
            geometry: self.geometry,
            tolerances: self.tolerances,
            start: self.start,
            steering: self.steering.clone(),
            rings: self.rings.clone(),
            ..Declaration::of_engines(self.engines.keys().copied())
        }
    }

    /// Every stream of estimates the machine has: its engines', then its
    /// stages' (registry order).
    pub fn streams(&self) -> Vec<StreamKind> {
        self.engines
            .keys()
            .map(|&engine| StreamKind::from(engine))
            .chain(
                self.stage_declaration()
                    .stages()
                    .into_iter()
                    .map(StreamKind::from),
            )
            .collect()
    }

    /// A machine stored by an earlier release made current: retired
    /// parameters dropped, new ones at their defaults (see
    /// [`Params::upgraded`]).
    pub fn upgraded(mut self) -> Result<MachineSpec, ConfigError> {
        for (kind, params) in self.engines.iter_mut() {
            *params = params
                .upgraded(kind.specs(), kind.retired())
                .map_err(|source| ConfigError::Params {
                    machine: self.id.clone(),
                    engine: *kind,
                    source,
                })?;
        }
        self.built_alignment =
            built(self.alignment.as_ref()).map_err(|e| ConfigError::Invalid {
                machine: self.id.clone(),
                reason: format!("stored `alignment`: {e}"),
            })?;
        Ok(self)
    }

    /// The declaration that reproduces this machine, with every parameter
    /// spelled out (what `GET` shows).
    pub fn declaration(&self) -> MachineDeclaration {
        MachineDeclaration {
            name: Some(self.name.clone()),
            engines: self
                .engines
                .iter()
                .map(|(engine, params)| (engine.as_str().to_string(), params.values().clone()))
                .collect(),
            reorder_window_s: Some(self.reorder_window_s),
            geometry: self.geometry,
            tolerances: self.tolerances,
            start: self.start,
            alignment: self.alignment.clone(),
            alarms: (self.alarms != AlarmConfig::default()).then_some(self.alarms),
            steering: self.steering.clone(),
            rings: self.rings.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn machine_ids_follow_the_protocol() {
        assert!(valid_machine_id("tbm-1_A"));
        assert!(valid_machine_id(&"a".repeat(64)));
        assert!(!valid_machine_id(&"a".repeat(65)));
        assert!(!valid_machine_id(""));
        assert!(!valid_machine_id("tbm 1"));
        assert!(!valid_machine_id("tbm/1"));
    }

    #[test]
    fn alarm_settings_are_optional_validated_and_named() {
        let declare = |alarms: serde_json::Value| {
            serde_json::from_value::<MachineDeclaration>(serde_json::json!({
                "engines": {"attitude": {}}, "alarms": alarms
            }))
            .map_err(|e| e.to_string())
            .and_then(|d| d.validate("m").map_err(|e| e.to_string()))
        };
        let spec = declare(serde_json::json!({"laser_dropout_warn_s": 120})).unwrap();
        assert_eq!(spec.alarms.laser_dropout_warn_s, 120.0);
        assert_eq!(
            spec.alarms.stale_periods,
            AlarmConfig::default().stale_periods
        );
        assert_eq!(spec.declaration().alarms, Some(spec.alarms));
        let err = declare(serde_json::json!({"min_duration_s": -1})).unwrap_err();
        assert!(err.contains("alarms.min_duration_s"), "{err}");
        let err = declare(serde_json::json!({"ring_the_bell": true})).unwrap_err();
        assert!(err.contains("ring_the_bell"), "{err}");
        let plain = serde_json::from_value::<MachineDeclaration>(
            serde_json::json!({"engines": {"attitude": {}}}),
        )
        .unwrap()
        .validate("m")
        .unwrap();
        assert_eq!(plain.alarms, AlarmConfig::default());
        assert_eq!(plain.declaration().alarms, None);
    }
}
